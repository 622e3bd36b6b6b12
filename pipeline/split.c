/* split.c — one star or two (issue 13): a score test (Rao's) of a second
 * star beside each fitted star.  A blend closer than a FWHM leaves no peak
 * of its own on the residual (a pair 0.5 FWHM apart fitted as one leaves
 * two faint lobes that find does not take), so the test asks the residual
 * directly: at trial places on rings around the star, the χ² that a second
 * star there would take away once the first star's flux, position and the
 * sky have readjusted,
 *     Δχ² = (Pᵀ W r)² / (Pᵀ W P),   P, r projected off span{P0, ∂P0/∂x, ∂P0/∂y, 1},
 * W the inverse variance of the fitted model (the residual's noise map,
 * with its profile error).  The best place goes to the fit as a candidate
 * when Δχ² ≥ minsnr²: for a single star, χ²(1) > 25 has probability 6e-7
 * at one place, ~1e-5 over the rings' ~20 independent places; the fit of
 * both then keeps the pair only when both reach minsnr and their
 * separation is significant.
 *
 * Economy (issue 12): a star within the phase grid's flux limit, the one
 * its group's fit draws from the grid by, is tested on PRFs drawn from the
 * grid (fit/prf_cache.c) — 37 renders a star, each ~60x cheaper than the
 * exact shift of a x4 table.  The grid's error is below 0.1 sigma of the
 * star's own fit, so the shape error it puts into sqrt(dchi2) is below
 * that fraction of the star's S/N divided by its flux: far below the
 * test's own noise of 1 (measured on 47 Tuc: bench/PROFILE.md).  The trial
 * stars are drawn from the grid by their own flux (best_second): beside a
 * star too bright for the grid, a second one is mostly not (the segmented
 * scene of make validate: the exact trials were 10 % of its CPU). */
#include <math.h>
#include <stdlib.h>
#include <string.h>
#include "pipeline/pipeline_priv.h"

#define NANG 12           /* trial places per ring */
#define NRING 3

typedef struct {
    long x0, y0, w, h;    /* the window: pixels within fitrad of the star */
    double *p0, *dx, *dy, *pt, *wt, *r;
    /* the window's weighted pixels (wt > 0), in its order: nc of them,
     * as ns spans of frame pixels, at box index idx[i] */
    mp_span *sp;
    size_t *idx;
    float *rms;           /* a row's noise (weighted_pixels) */
    int lin;              /* the trials from the grid bilinearly */
    unsigned char *in;    /* a row's pixels within fitrad */
    int ns, nc;
    mp_prf_work wk;       /* the renders' (wk.grid: the phase grid, or NULL) */
} split_work;

/* Solve the 4×4 symmetric system G a = b by Gauss–Jordan with partial
 * pivoting; nonzero when singular. */
static int solve4(double G[4][4], double b[4], double a[4])
{
    double M[4][5];
    for (int i = 0; i < 4; i++) {
        memcpy(M[i], G[i], sizeof G[i]);
        M[i][4] = b[i];
    }
    for (int c = 0; c < 4; c++) {
        int p = c;
        for (int i = c + 1; i < 4; i++)
            if (fabs(M[i][c]) > fabs(M[p][c]))
                p = i;
        if (!(fabs(M[p][c]) > 1e-300))
            return 1;
        for (int j = 0; j < 5; j++) {
            double t = M[c][j];
            M[c][j] = M[p][j];
            M[p][j] = t;
        }
        for (int i = 0; i < 4; i++) {
            if (i == c)
                continue;
            double f = M[i][c] / M[c][c];
            for (int j = c; j < 5; j++)
                M[i][j] -= f * M[c][j];
        }
    }
    for (int i = 0; i < 4; i++)
        a[i] = M[i][4] / M[i][i];
    return 0;
}

/* Render the PRF of a star at (x, y) (and its derivatives, when dx, dy)
 * into the window's w×h arrays (zero where the PRF box does not reach). */
static int render(const mp_prf_model *m, double x, double y, const split_work *s, double *p,
                  double *dx, double *dy, double *buf, double *bdx, double *bdy, mp_prf_work *wk)
{
    long rx0, ry0;
    int rw, rh;
    if (mp_prf_render_window(m, x, y, s->x0, s->y0, s->w, s->h, &rx0, &ry0, &rw, &rh, buf,
                             dx ? bdx : NULL, dy ? bdy : NULL, wk))
        return 1;
    size_t n = (size_t)(s->w * s->h);
    memset(p, 0, n * sizeof *p);
    if (dx)
        memset(dx, 0, n * sizeof *dx);
    if (dy)
        memset(dy, 0, n * sizeof *dy);
    for (int j = 0; j < rh; j++)
        for (int i = 0; i < rw; i++) {
            size_t k = (size_t)((ry0 + j - s->y0) * s->w + (rx0 + i - s->x0));
            p[k] = buf[(size_t)j * rw + i];
            if (dx)
                dx[k] = bdx[(size_t)j * rw + i];
            if (dy)
                dy[k] = bdy[(size_t)j * rw + i];
        }
    return 0;
}

/* The weights of the window's pixels (those within fitrad of (x, y),
 * unmasked, with a noise) and the residual there, the pixels weighted
 * gathered as spans and indices (s->sp, s->idx), and the star's PRF and
 * derivatives, the weights and the residual packed onto them, in the
 * window's order (the zero weights' terms of every sum left out: the
 * sums are those over the whole window bit for bit). */
static void weighted_pixels(const mp_frame *f, const mp_bkg *b, const float *res, double x,
                            double y, double fitrad, split_work *s)
{
    s->ns = s->nc = 0;
    for (long j = 0; j < s->h; j++) {
        long gy = s->y0 + j, lo = s->w, hi = -1;
        for (long i = 0; i < s->w; i++) {
            s->in[i] = mp_within((double)(s->x0 + i) - x, (double)gy - y, fitrad);
            lo = s->in[i] && i < lo ? i : lo;
            hi = s->in[i] ? i : hi;
        }
        /* the noise of the row's pixels within fitrad, a span at once */
        if (hi >= lo)
            mp_bkg_rms_span(b, gy - 1, s->x0 + lo - 1, s->x0 + hi, s->rms);
        int open = 0;
        for (long i = 0; i < s->w; i++) {
            size_t k = (size_t)(j * s->w + i);
            long gx = s->x0 + i;
            size_t g = (size_t)(gy - 1) * (size_t)f->im.nx + (size_t)(gx - 1);
            float rms = 0.0f;
            int ok = s->in[i] && !f->mask[g] && isfinite(res[g]) && (rms = s->rms[i - lo]) > 0;
            s->wt[k] = ok ? 1.0 / (rms * rms) : 0.0;
            s->r[k] = ok ? res[g] : 0.0;
            if (!ok) {
                open = 0;
                continue;
            }
            if (!open)
                s->sp[s->ns++] = (mp_span){gx, gy, 0};
            s->sp[s->ns - 1].n++;
            open = 1;
            s->idx[s->nc++] = k;
        }
    }
    for (int q = 0; q < s->nc; q++) {     /* packed in place: idx[q] >= q */
        size_t k = s->idx[q];
        s->p0[q] = s->p0[k];
        s->dx[q] = s->dx[k];
        s->dy[q] = s->dy[k];
        s->wt[q] = s->wt[k];
        s->r[q] = s->r[k];
    }
}

/* A trial star's PRF at (px, py) on the weighted pixels, packed (s->pt):
 * from s->wk's phase grid on their spans when it serves m (the same values
 * as a render of the window, pixel for pixel), else rendered on the window
 * and packed. */
static int trial_prf(const mp_prf_model *m, double px, double py, split_work *s,
                     double *scratch)
{
    mp_prf_work *wk = &s->wk;
    if (mp_prf_cache_usable(wk->grid, m) && mp_prf_cache_covers(wk->grid, m, px, py))
        return mp_prf_cache_render_at(wk->grid, m, px, py, s->sp, NULL, s->ns, s->pt, NULL, NULL,
                                      s->lin);
    size_t n = (size_t)(s->w * s->h);
    double *full = scratch + 3 * n;
    if (render(m, px, py, s, full, NULL, NULL, scratch, scratch + n, scratch + 2 * n, wk))
        return 1;
    for (int q = 0; q < s->nc; q++)
        s->pt[q] = full[s->idx[q]];
    return 0;
}

/* The peak of a star's PRF at (px, py) over the window. */
static double window_peak(const mp_prf_model *m, double px, double py, split_work *s,
                          double *scratch)
{
    size_t n = (size_t)(s->w * s->h);
    double *full = scratch + 3 * n, pk = 0.0;
    if (render(m, px, py, s, full, NULL, NULL, scratch, scratch + n, scratch + 2 * n, &s->wk))
        return NAN;
    for (size_t k = 0; k < n; k++)
        pk = fmax(pk, full[k]);
    return pk;
}

/* The trials of best_second on the rings around (x, y), their PRFs drawn
 * through s->wk (the phase grid when it holds one), from the sums of the
 * star's own terms G, Br: the best place, Δχ² and linear flux (Δχ² NaN
 * when none could be tried). */
static double trials(const mp_prf_model *m, double x, double y, const double *rings,
                     split_work *s, double *scratch, double G[4][4], const double Br[4],
                     double *bx, double *by, double *bflux)
{
    double best = NAN, a[4];
    for (int q = 0; q < NRING; q++)
        for (int t = 0; t < NANG; t++) {
            double ang = 2.0 * M_PI * (t + 0.5 * (q % 2)) / NANG;
            double px = x + rings[q] * cos(ang), py = y + rings[q] * sin(ang);
            if (trial_prf(m, px, py, s, scratch))
                return NAN;
            double c[4] = {0}, pp = 0, pr = 0;
            for (int k = 0; k < s->nc; k++) {
                double wp = s->wt[k] * s->pt[k];
                c[0] += wp * s->p0[k];
                c[1] += wp * s->dx[k];
                c[2] += wp * s->dy[k];
                c[3] += wp;
                pp += wp * s->pt[k];
                pr += wp * s->r[k];
            }
            double G2[4][4];
            memcpy(G2, G, sizeof G2);
            if (solve4(G2, c, a))
                continue;
            double norm = pp, u = pr;
            for (int i = 0; i < 4; i++) {
                norm -= c[i] * a[i];
                u -= a[i] * Br[i];
            }
            if (!(norm > 0) || !(u > 0))
                continue;
            double d2 = u * u / norm;
            if (!(d2 <= best)) {
                best = d2;
                *bx = px;
                *by = py;
                *bflux = u / norm;
            }
        }
    return best;
}

/* Whether no trial can reach Δχ² = snrmin2: a trial's Δχ² is
 * (P̃ᵀW r̃)² / (P̃ᵀW P̃), P̃ and r̃ projected off the star's own terms, so
 * by Cauchy–Schwarz it is at most r̃ᵀW r̃ = rᵀW r − Brᵀ G⁻¹ Br, the
 * residual's χ² left over them in the window (a margin of 1e-9 of rᵀW r
 * for the rounding).  Where the window holds few pixels more than that
 * χ² (fitrad ≈ FWHM) most stars end here, before their 36 trials. */
static int below_any_trial(const split_work *s, double G[4][4], const double Br[4],
                           double snrmin2)
{
    double rwr = 0.0, a[4], G2[4][4], b[4];
    for (int k = 0; k < s->nc; k++)
        rwr += s->wt[k] * s->r[k] * s->r[k];
    memcpy(G2, G, sizeof G2);
    memcpy(b, Br, sizeof b);
    if (solve4(G2, b, a))
        return 0;
    double left = rwr;
    for (int i = 0; i < 4; i++)
        left -= a[i] * Br[i];
    return left + 1e-9 * rwr < snrmin2;
}

/* The best second star beside the star at (x, y) of flux e: its place,
 * Δχ², linear flux and peak; Δχ² NaN when none could be tried.  The star
 * itself is drawn from the phase grid when e is within its limit gemax,
 * the trial stars when theirs is: a trial's error enters √Δχ², its own
 * S/N, as the grid's bound at its own flux (below 0.1 within the limit),
 * so the trials beside a star too bright for the grid are drawn from it
 * too, and all of them again exactly when the best one's flux is beyond
 * the limit.  scratch holds 4 n. */
static double best_second(const mp_frame *f, const mp_bkg *b, const float *res,
                          const mp_prf_model *m, double x, double y, double e, double fitrad,
                          const double *rings, split_work *s, double *scratch,
                          const mp_prf_cache *grid, double gemax, double glemax,
                          double snrmin2, double *bx, double *by, double *bflux, double *bpeak)
{
    size_t n = (size_t)(s->w * s->h);
    double *buf = scratch, *bdx = scratch + n, *bdy = scratch + 2 * n;
    mp_prf_work *wk = &s->wk;
    wk->grid = grid && e <= gemax ? grid : NULL;
    if (render(m, x, y, s, s->p0, s->dx, s->dy, buf, bdx, bdy, wk))
        return NAN;
    weighted_pixels(f, b, res, x, y, fitrad, s);
    double G[4][4] = {{0}}, Br[4] = {0};
    for (int k = 0; k < s->nc; k++) {
        double v[4] = {s->p0[k], s->dx[k], s->dy[k], 1.0};
        for (int i = 0; i < 4; i++) {
            Br[i] += s->wt[k] * v[i] * s->r[k];
            for (int j = 0; j < 4; j++)
                G[i][j] += s->wt[k] * v[i] * v[j];
        }
    }
    if (below_any_trial(s, G, Br, snrmin2))
        return NAN;
    wk->grid = mp_prf_cache_usable(grid, m) ? grid : NULL;
    s->lin = wk->grid && glemax > 0;
    double best = trials(m, x, y, rings, s, scratch, G, Br, bx, by, bflux);
    if (s->lin && isfinite(best) && !(*bflux <= glemax)) {
        s->lin = 0;             /* bilinear beyond its limit: cubic */
        best = trials(m, x, y, rings, s, scratch, G, Br, bx, by, bflux);
    }
    s->lin = 0;
    if (wk->grid && isfinite(best) && !(*bflux <= gemax)) {
        wk->grid = NULL;        /* the trials were from the grid: exactly */
        best = trials(m, x, y, rings, s, scratch, G, Br, bx, by, bflux);
    }
    if (isfinite(best))
        *bpeak = *bflux * window_peak(m, *bx, *by, s, scratch);
    return best;
}

/* A thread's scratch for boxes of n pixels (split_work's arrays, and
 * best_second's four more after them); NULL when out of memory. */
static double *work_alloc(split_work *s, size_t n)
{
    s->wk = (mp_prf_work){0};
    double *mem = malloc(10 * n * sizeof *mem);
    s->sp = malloc(n * sizeof *s->sp);
    s->idx = malloc(n * sizeof *s->idx);
    s->rms = malloc(n * sizeof *s->rms);
    s->in = malloc(n);
    if (!mem || !s->sp || !s->idx || !s->rms || !s->in) {
        free(mem);
        free(s->sp);
        free(s->idx);
        free(s->rms);
        free(s->in);
        s->sp = NULL;
        s->idx = NULL;
        s->rms = NULL;
        s->in = NULL;
        return NULL;
    }
    s->p0 = mem;
    s->dx = mem + n;
    s->dy = mem + 2 * n;
    s->pt = mem + 3 * n;
    s->wt = mem + 4 * n;
    s->r = mem + 5 * n;
    return mem;
}

static void work_free(split_work *s, double *mem)
{
    free(mem);
    free(s->sp);
    free(s->idx);
    free(s->rms);
    free(s->in);
    mp_prf_work_free(&s->wk);
}

/* The second stars proposed (cs[r] finite: their S/N; place, flux, peak)
 * added to found as find's rows: the sky under each, no shape measured
 * (sharpness, roundness 0), flags 0.  Returns how many, −1 when out of
 * memory. */
static long add_proposed(const mp_frame *f, const mp_bkg *b, const double *cx, const double *cy,
                         const double *cf, const double *cs, const double *cp, long nrow,
                         mp_table *found)
{
    int fx = mp_table_add_col(found, "X_IMAGE"), fy = mp_table_add_col(found, "Y_IMAGE");
    int ff = mp_table_add_col(found, "FLUX"), fs = mp_table_add_col(found, MP_PL_SNR_COL);
    int fm = mp_table_add_col(found, "FLUX_MAX"), fb = mp_table_add_col(found, "BACKGROUND");
    int fsh = mp_table_add_col(found, "SHARPNESS"), fro = mp_table_add_col(found, "ROUNDNESS");
    int ffl = mp_table_add_col(found, "FLAGS");
    if (fx < 0 || fy < 0 || ff < 0 || fs < 0 || fm < 0 || fb < 0 || fsh < 0 || fro < 0 || ffl < 0)
        return -1;
    long added = 0;
    for (long r = 0; r < nrow; r++) {
        if (!isfinite(cs[r]))
            continue;
        long row = mp_table_add_row(found);
        if (row < 0)
            return -1;
        mp_table_set(found, (size_t)row, fx, cx[r]);
        mp_table_set(found, (size_t)row, fy, cy[r]);
        mp_table_set(found, (size_t)row, ff, cf[r]);
        mp_table_set(found, (size_t)row, fs, cs[r]);
        long px = lround(cx[r]), py = lround(cy[r]);
        size_t g = (size_t)(py - 1) * (size_t)f->im.nx + (size_t)(px - 1);
        mp_table_set(found, (size_t)row, fm, cp[r]);
        mp_table_set(found, (size_t)row, fb, mp_bkg_sky(b, g));
        mp_table_set(found, (size_t)row, fsh, 0.0);
        mp_table_set(found, (size_t)row, fro, 0.0);
        mp_table_set(found, (size_t)row, ffl, 0.0);
        added++;
    }
    return added;
}

long mp_pl_split_candidates(const mp_frame *f, const mp_bkg *b, const float *res,
                            const mp_prf_model *m, const mp_prf_cache *grid, double gemax,
                            double glemax, const mp_table *t, double fitrad, double rmin,
                            double rmax, double snrmin, mp_table *found)
{
    int tx = mp_table_col(t, "XPSF_IMAGE"), ty = mp_table_col(t, "YPSF_IMAGE");
    int tf = mp_table_col(t, "FLUX_PSF"), te = mp_table_col(t, "FLUXERR_PSF");
    if (tx < 0 || ty < 0 || tf < 0 || te < 0 || !(snrmin > 0) || t->nrow == 0)
        return 0;
    const double rings[NRING] = {rmin, 0.5 * (rmin + rmax), rmax};
    long side = 2 * (long)ceil(fitrad) + 3, nrow = (long)t->nrow;
    if (side > f->im.nx || side > f->im.ny)
        return 0;               /* no window fits: every star is left to find */
    size_t n = (size_t)(side * side);
    double *cx = malloc((size_t)nrow * sizeof *cx), *cy = malloc((size_t)nrow * sizeof *cy);
    double *cf = malloc((size_t)nrow * sizeof *cf), *cs = malloc((size_t)nrow * sizeof *cs);
    double *cp = malloc((size_t)nrow * sizeof *cp);
    int failed = !cx || !cy || !cf || !cs || !cp;
#pragma omp parallel if (!failed) reduction(| : failed)
    {
        split_work s;
        double *mem = work_alloc(&s, n);
        failed |= !mem;
#pragma omp for schedule(dynamic, 32)
        for (long r = 0; r < nrow; r++) {
            cs[r] = NAN;
            double x = mp_table_get(t, (size_t)r, tx), y = mp_table_get(t, (size_t)r, ty);
            double e = mp_table_get(t, (size_t)r, tf), se = mp_table_get(t, (size_t)r, te);
            /* two stars of S/N ≥ snrmin make one of S/N ≥ √2·snrmin or so */
            if (!mem || !isfinite(x) || !isfinite(y) || !(se > 0) || !(e / se >= M_SQRT2 * snrmin))
                continue;
            s.x0 = (long)ceil(x - fitrad) - 1;
            s.y0 = (long)ceil(y - fitrad) - 1;
            s.w = s.h = side;
            if (s.x0 < 1 || s.y0 < 1 || s.x0 + side - 1 > f->im.nx || s.y0 + side - 1 > f->im.ny)
                continue;       /* at the frame's edge: left to find */
            double d2 = best_second(f, b, res, m, x, y, e, fitrad, rings, &s, mem + 6 * n, grid,
                                    gemax, glemax, snrmin * snrmin, &cx[r], &cy[r], &cf[r],
                                    &cp[r]);
            cs[r] = d2 >= snrmin * snrmin ? sqrt(d2) : NAN;
        }
        work_free(&s, mem);
    }
    long added = failed ? -1 : add_proposed(f, b, cx, cy, cf, cs, cp, nrow, found);
    free(cx);
    free(cy);
    free(cf);
    free(cs);
    free(cp);
    return added;
}
