/* levmar.c — fitting a group of stars and its sky by Levenberg–Marquardt
 * (design.md §5).
 *
 * The answer is the root of the unbiased estimating equation
 * Σ (d − m)/V(m) ∂m/∂p = 0 with the variance function V(m) = max(m, S) + RON²
 * from the model, not the data (S, the lowest sky the group's stars were
 * found on, or 0: no pixel carries less light than the sky, and a model
 * dipping below it
 * — a table's negative wings, a neighbour over-subtracted — must not weigh
 * a pixel at 1/RON², which with RON = 0 made one negative pixel outweigh a
 * star; minimising a χ² whose weights move with the
 * parameters would bias faint fluxes by about β/2 electrons).  That root is
 * the minimum of one fixed objective, the quasi-likelihood deviance
 * D = 2 Σ ∫_d^m (t − d)/V(t) dt (McCullagh & Nelder, Generalized Linear
 * Models, §9.2: its gradient is −2× the estimating equation, its expected
 * Hessian 2 JᵀV⁻¹J, the normal matrix).  A step is accepted only when it
 * lowers D: comparing χ² under weights refreshed after every step follows
 * no fixed objective, and on a large crowded group with sky and fluxes
 * nearly degenerate it walked off (sky −5.7e5 e⁻, fluxes 10⁷× the truth).
 * Steps are also bounded (positions 1 px, fluxes ×10 up, sky a few σ of a
 * pixel), and a fit that stalls or runs out of iterations before its steps
 * are below tol·σ keeps its best (last accepted) state and is flagged. */
#include <lapacke.h>
#include <math.h>
#include <stddef.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include "fit/fit.h"

void mp_fit_opts_default(mp_fit_opts *o)
{
    o->sky_order = MP_SKY_AUTO;
    o->fitrad = NAN;
    o->tol = 1e-3;
    o->maxiter = 50;
    o->fit_sky = 1;
    o->crop = NULL;
    o->grid = NULL;
    o->work = NULL;
    o->exact_lm = 0;
}

/* One star's rendered PRF and derivatives on the fitted pixels of its
 * window, rows [j0, j1) and columns [i0, i1) of the group box: row j0 + t
 * holds the packed pixels [pp[t], pp[t] + pn[t]) (the fitted pixels of a
 * row within a column range are consecutive in the packing), at
 * prf[pb[t] ...]. */
typedef struct {
    int i0, i1, j0, j1;
    int ci0, ci1, cj0, cj1;     /* its core while the wings are frozen (levmar) */
    int *pp, *pn, *pb;          /* bh each */
    double *prf, *dx, *dy;      /* cap each */
} rstar;

/* Everything one group fit needs; freed in one place. */
typedef struct {
    const mp_frame *f;
    const mp_prf_model *m;
    const mp_prf_crop *crop;    /* NULL: every star on its whole box */
    double crop_min;            /* never cropped inside its fitting region */
    int n, nsky, np;            /* nsky sky terms fitted (0: sky held fixed) */
    int npmax;                  /* parameters the arrays hold: 3n + 6 */
    long bx0, by0;              /* group box, 1-based, and size */
    int bw, bh;
    double xc, yc, hx, hy;      /* sky basis: u = (x − xc)/hx, v = (y − yc)/hy */
    double dlo, dhi, emax;      /* data range over the fitted pixels, and the
                                 * largest flux any star may take there */
    double ron2;                /* RON², at least 1e-2 so V > 0 */
    double vfloor;              /* S of V(m) = max(m, S) + RON², ≥ 0 */
    double sknown;              /* the sky the stars were found on, or NaN */
    double skylo, skyhi;        /* a plane or quadratic sky's range over the
                                 * fitted pixels, as model_of last drew it */
    uint8_t *sel;               /* bw*bh: pixel fitted */
    /* The fitted pixels packed row by row (issue 12: every per-pixel sum
     * and render runs over them only, not the box around them, which
     * holds about twice as many): runs of consecutive fitted pixels, run
     * r in box row rj[r], columns [ri0[r], ri1[r]), packed from rp[r];
     * row j's runs are rrow[j] .. rrow[j + 1] − 1, its first packed pixel
     * prow[j] (both bh + 1). */
    size_t npix;
    int nrun;
    int *rj, *ri0, *ri1, *rp, *rrow, *prow;
    double *dat, *mod, *var;    /* npix: data, model, V(m) */
    double *rv;                 /* npix: RON² + the error plane's extra
                                 * variance (mp_frame.xvar), the r of V */
    double *wt, *wres;          /* npix: 1/V, and 1/V·(d − m), for the
                                 * normal equations */
    double *basis;              /* 6 × npix: the sky basis at every pixel */
    mp_span *spans;             /* nrun: the spans a star is rendered on */
    size_t *soff;               /* nrun: where each span's values go (core renders) */
    /* Frozen wings (levmar): while set, a render redraws each star on its
     * core only, the rest of its window keeping the values drawn at
     * (fx, fy) — both buffers alike. */
    int freezing, frozen;       /* this fit freezes; frozen now */
    double *fx, *fy;            /* n each */
    /* Star pairs between exact normal equations (normal_equations): the
     * pairs whose windows meet, each pair's sums outside its core (9 a
     * pair, unscaled), and each star's core, [cx0, cx1) × [cy0, cy1) of
     * the box (n each); core_hw ≤ 0: every pass exact. */
    int npair, cappair, ne_exact;
    int *pk, *pl;
    double *tail;
    double *stail;              /* 27 a star: its sky and self sums outside its core */
    int *cx0, *cx1, *cy0, *cy1;
    double core_hw;
    size_t cap;                 /* per-star capacity (packed pixels) */
    size_t boxcap;              /* an exact render's box (scr: 3 of them) */
    double *scr;
    rstar *cur, *trial;
    double *p, *pt, *A, *g, *M, *step;
    mp_prf_work work;
} group;

static void group_free(group *G)
{
    free(G->sel);
    free(G->rj);
    free(G->ri0);
    free(G->ri1);
    free(G->rp);
    free(G->rrow);
    free(G->prow);
    free(G->dat);
    free(G->mod);
    free(G->var);
    free(G->rv);
    free(G->wt);
    free(G->wres);
    free(G->basis);
    free(G->spans);
    free(G->soff);
    free(G->fx);
    free(G->fy);
    free(G->scr);
    free(G->pk);
    free(G->pl);
    free(G->tail);
    free(G->stail);
    free(G->cx0);
    free(G->cx1);
    free(G->cy0);
    free(G->cy1);
    for (int s = 0; s < 2; s++) {
        rstar *r = s ? G->trial : G->cur;
        if (!r)
            continue;
        for (int k = 0; k < G->n; k++) {
            free(r[k].prf);
            free(r[k].dx);
            free(r[k].dy);
            free(r[k].pp);
            free(r[k].pn);
            free(r[k].pb);
        }
        free(r);
    }
    free(G->p);
    free(G->pt);
    free(G->A);
    free(G->g);
    free(G->M);
    free(G->step);
    mp_prf_work_free(&G->work);
}

static double pixel(const group *G, long x, long y)
{
    return G->f->im.pix[(size_t)(y - 1) * G->f->im.nx + (size_t)(x - 1)];
}

/* RON² plus what the frame's error plane holds beyond it and the Poisson
 * noise, at pixel (x, y). */
static double ron2_at(const group *G, long x, long y)
{
    const float *xv = G->f->xvar;
    return G->ron2 + (xv ? (double)xv[(size_t)(y - 1) * G->f->im.nx + (size_t)(x - 1)] : 0.0);
}

/* The packed index of the first fitted pixel at or after column i of box
 * row j. */
static int packed_at(const group *G, int j, int i)
{
    for (int q = G->rrow[j]; q < G->rrow[j + 1]; q++) {
        if (i <= G->ri0[q])
            return G->rp[q];
        if (i < G->ri1[q])
            return G->rp[q] + (i - G->ri0[q]);
    }
    return G->prow[j + 1];
}

/* Star r's window (box coordinates, set) as packed rows, and the spans of
 * frame pixels to render; returns the number of spans. */
static int window_rows(group *G, rstar *r)
{
    int ns = 0, len = 0;
    for (int j = r->j0; j < r->j1; j++) {
        int t = j - r->j0, a = packed_at(G, j, r->i0), b = packed_at(G, j, r->i1);
        r->pp[t] = a;
        r->pn[t] = b - a;
        r->pb[t] = len;
        len += b - a;
        if ((size_t)len > G->cap)
            return -1;
        for (int q = G->rrow[j]; q < G->rrow[j + 1] && b > a; q++) {
            int s = G->ri0[q] > r->i0 ? G->ri0[q] : r->i0, e = G->ri1[q] < r->i1 ? G->ri1[q] : r->i1;
            if (s < e)
                G->spans[ns++] = (mp_span){G->bx0 + s, G->by0 + j, e - s};
        }
    }
    return ns;
}

/* An exact render (no phase grid for this model) of box columns [i0, i1)
 * and rows [j0, j1) into G->scr, gathered onto the ns spans of G->spans,
 * span k's values from r's index at[k] (at NULL: one after the other). */
static int render_exact(group *G, double x, double y, int i0, int i1, int j0, int j1,
                        const rstar *r, int ns, const size_t *at)
{
    long wx0 = G->bx0 + i0, wy0 = G->by0 + j0, rx0, ry0;
    int rw, rh;
    double *s0 = G->scr, *s1 = G->scr + G->boxcap, *s2 = G->scr + 2 * G->boxcap;
    if ((size_t)(i1 - i0) * (size_t)(j1 - j0) > G->boxcap)
        return 1;
    if (mp_prf_render_window(G->m, x, y, wx0, wy0, i1 - i0, j1 - j0, &rx0, &ry0, &rw, &rh, s0, s1,
                             s2, &G->work))
        return 1;
    size_t o = 0;
    for (int k = 0; k < ns; k++) {
        const mp_span *sp = &G->spans[k];
        o = at ? at[k] : o;
        for (int i = 0; i < sp->n; i++, o++) {
            long X = sp->x0 + i - rx0, Y = sp->y - ry0;
            int in = X >= 0 && X < rw && Y >= 0 && Y < rh;
            size_t t = in ? (size_t)Y * rw + (size_t)X : 0;
            r->prf[o] = in ? s0[t] : 0.0;
            r->dx[o] = in ? s1[t] : 0.0;
            r->dy[o] = in ? s2[t] : 0.0;
        }
    }
    return 0;
}

/* Render every star of parameter vector p into r, on the fitted pixels of
 * its window only (the group's box, the star's PRF box and its crop
 * radius): the fit pays for its fitting region, not for the PSF's wings,
 * nor for the pixels between the stars' fitting radii.  what: RENDER_ALL,
 * or, from the phase grid, RENDER_PRF (a trial step: D needs the PRF
 * only, and a third of the trials are refused) and RENDER_DERIVS (the
 * derivatives of a step taken, whose PRF is there); exact renders always
 * draw all three. */
enum { RENDER_ALL, RENDER_PRF, RENDER_DERIVS };

/* Star r's core — its box [ci0, ci1) × [cj0, cj1) within its window — as
 * spans of frame pixels in G->spans, each with its index in r's arrays in
 * G->soff, and the core's box clipped to the window in c; returns the
 * number of spans. */
static int core_rows(group *G, const rstar *r, int c[4])
{
    int ns = 0;
    c[0] = r->ci0 > r->i0 ? r->ci0 : r->i0;
    c[1] = r->ci1 < r->i1 ? r->ci1 : r->i1;
    c[2] = r->cj0 > r->j0 ? r->cj0 : r->j0;
    c[3] = r->cj1 < r->j1 ? r->cj1 : r->j1;
    for (int j = c[2]; j < c[3] && c[0] < c[1]; j++) {
        int t = j - r->j0;
        for (int q = G->rrow[j]; q < G->rrow[j + 1] && r->pn[t] > 0; q++) {
            int a = G->ri0[q] > c[0] ? G->ri0[q] : c[0], e = G->ri1[q] < c[1] ? G->ri1[q] : c[1];
            if (a >= e)
                continue;
            G->spans[ns] = (mp_span){G->bx0 + a, G->by0 + j, e - a};
            G->soff[ns++] = (size_t)(r->pb[t] + G->rp[q] + (a - G->ri0[q]) - r->pp[t]);
        }
    }
    return ns;
}

/* render_all while the wings are frozen: each star on its core only. */
static int render_core(group *G, const double *p, rstar *r, int what)
{
    int grid = mp_prf_cache_usable(G->work.grid, G->m);
    if (!grid && what == RENDER_DERIVS)
        return 0;
    for (int k = 0; k < G->n; k++) {
        double x = p[3 * k + 1], y = p[3 * k + 2];
        int c[4], ns = core_rows(G, &r[k], c);
        if (ns == 0)
            continue;
        int rc = grid ? mp_prf_cache_render_at(G->work.grid, G->m, x, y, G->spans, G->soff, ns,
                                               what == RENDER_DERIVS ? NULL : r[k].prf,
                                               what == RENDER_PRF ? NULL : r[k].dx,
                                               what == RENDER_PRF ? NULL : r[k].dy)
                      : render_exact(G, x, y, c[0], c[1], c[2], c[3], &r[k], ns, G->soff);
        if (rc)
            return 1;
    }
    return 0;
}

static int render_all(group *G, const double *p, rstar *r, int what)
{
    if (G->frozen)
        return render_core(G, p, r, what);
    int grid = mp_prf_cache_usable(G->work.grid, G->m);
    if (!grid && what == RENDER_DERIVS)
        return 0;
    for (int k = 0; k < G->n; k++) {
        double x = p[3 * k + 1], y = p[3 * k + 2];
        long x0, y0;
        int w, h;
        mp_prf_box(G->m, x, y, &x0, &y0, &w, &h);
        long wx0 = G->bx0, wy0 = G->by0, wx1 = G->bx0 + G->bw, wy1 = G->by0 + G->bh;
        wx0 = x0 > wx0 ? x0 : wx0;
        wy0 = y0 > wy0 ? y0 : wy0;
        wx1 = x0 + w < wx1 ? x0 + w : wx1;
        wy1 = y0 + h < wy1 ? y0 + h : wy1;
        /* Economy: only out to where the star's light is below a fraction
         * of the noise (fit_frame.c subtracts neighbours the same way). */
        double rad = mp_prf_crop_radius(G->crop, p[3 * k], p[3 * G->n]);
        if (isfinite(rad)) {
            rad = rad > G->crop_min ? rad : G->crop_min;
            long a = (long)ceil(x - rad), b = (long)ceil(y - rad);
            long c = (long)floor(x + rad) + 1, d = (long)floor(y + rad) + 1;
            wx0 = a > wx0 ? a : wx0;
            wy0 = b > wy0 ? b : wy0;
            wx1 = c < wx1 ? c : wx1;
            wy1 = d < wy1 ? d : wy1;
        }
        rstar *rk = &r[k];
        rk->i0 = (int)(wx0 - G->bx0);
        rk->j0 = (int)(wy0 - G->by0);
        rk->i1 = wx1 > wx0 ? (int)(wx1 - G->bx0) : rk->i0;
        rk->j1 = wy1 > wy0 && wx1 > wx0 ? (int)(wy1 - G->by0) : rk->j0;
        int ns = window_rows(G, rk);
        if (ns < 0)
            return 1;
        if (ns == 0)
            continue;
        int rc = grid ? mp_prf_cache_render_spans(G->work.grid, G->m, x, y, G->spans, ns,
                                                  what == RENDER_DERIVS ? NULL : rk->prf,
                                                  what == RENDER_PRF ? NULL : rk->dx,
                                                  what == RENDER_PRF ? NULL : rk->dy)
                      : render_exact(G, x, y, rk->i0, rk->i1, rk->j0, rk->j1, rk, ns, NULL);
        if (rc)
            return 1;
    }
    return 0;
}

/* Sky terms of order 0, 1, 2: 1, 3, 6. */
static int nsky_of(int order)
{
    return order <= 0 ? 1 : (order == 1 ? 3 : 6);
}

/* The sky basis at (x, y): 1, u, v, u² − 1/3, uv, v² − 1/3, with u, v the
 * offsets from the box centre scaled to [−1, 1].  Scaled and centred (u²
 * has mean about 1/3 over the box) so the normal equations stay well
 * conditioned and one bound fits every coefficient's step. */
static void sky_basis(const group *G, double x, double y, double c[6])
{
    double u = (x - G->xc) / G->hx, v = (y - G->yc) / G->hy;
    c[0] = 1.0;
    c[1] = u;
    c[2] = v;
    c[3] = u * u - 1.0 / 3.0;
    c[4] = u * v;
    c[5] = v * v - 1.0 / 3.0;
}

static double sky_at(const group *G, const double *p, double x, double y)
{
    if (G->nsky <= 1)
        return p[3 * G->n];      /* constant, or fixed (kept in the first sky slot) */
    double c[6], s = 0.0;
    sky_basis(G, x, y, c);
    for (int a = 0; a < G->nsky; a++)
        s += p[3 * G->n + a] * c[a];
    return s;
}

static void model_of(group *G, const double *p, const rstar *r)
{
    size_t N = G->npix;
    if (G->nsky <= 1)
        for (size_t o = 0; o < N; o++)
            G->mod[o] = p[3 * G->n];
    else {
        G->skylo = INFINITY;
        G->skyhi = -INFINITY;
        for (size_t o = 0; o < N; o++) {
            double b = 0.0;
            for (int a = 0; a < G->nsky; a++)
                b += p[3 * G->n + a] * G->basis[(size_t)a * N + o];
            G->mod[o] = b;
            G->skylo = b < G->skylo ? b : G->skylo;
            G->skyhi = b > G->skyhi ? b : G->skyhi;
        }
    }
    for (int k = 0; k < G->n; k++) {
        const rstar *rk = &r[k];
        double E = p[3 * k];
        for (int t = 0; t < rk->j1 - rk->j0; t++) {
            const double *pr = rk->prf + rk->pb[t];
            double *mr = G->mod + rk->pp[t];
            for (int i = 0; i < rk->pn[t]; i++)
                mr[i] += E * pr[i];
        }
    }
}

/* Weights from the model: σ² = V(m) = max(m, S) + RON² (+ the error
 * plane's extra variance), RON² at least 1e-2 so a zero model and sky
 * with no read noise cannot give an infinite weight. */
static void variance_of(group *G)
{
    for (size_t i = 0; i < G->npix; i++)
        G->var[i] = (G->mod[i] > G->vfloor ? G->mod[i] : G->vfloor) + G->rv[i];
}

/* ∫_a^b (t − d)/V(t) dt for 0 ≤ a ≤ b, where V(t) = t + r. */
static double dev_positive(double a, double b, double d, double r)
{
    return (b - a) - (d + r) * log1p((b - a) / (a + r));
}

/* One pixel's deviance 2 ∫_d^m (t − d)/V(t) dt, V(t) = max(t, s) + r with
 * s ≥ 0: zero at m = d and growing on both sides, whatever the sign of d.
 * For m, d ≥ s it is the Poisson deviance of d + r about m + r, written
 * with log1p so it keeps its precision near m = d, where the fit ends;
 * below s, V is constant and the deviance a parabola. */
static double pixel_deviance(double m, double d, double s, double r)
{
    if (m >= s && d >= s) {
        double x = (m - d) / (d + r);
        return 2.0 * (d + r) * (x - log1p(x));
    }
    double lo = m < d ? m : d, hi = m < d ? d : m, sum = 0.0;
    if (lo < s) {
        double b = hi < s ? hi : s;
        sum += (b - lo) * (0.5 * (lo + b) - d) / (s + r);
    }
    if (hi > s)
        sum += dev_positive(lo > s ? lo : s, hi, d, r);
    return 2.0 * (m >= d ? sum : -sum);
}

/* The objective every step must lower (see the top of the file). */
static double deviance_of(const group *G)
{
    double D = 0.0;
    for (size_t o = 0; o < G->npix; o++)
        D += pixel_deviance(G->mod[o], G->dat[o], G->vfloor, G->rv[o]);
    return D;
}

static double chi2_with(const group *G, const double *var)
{
    double c = 0.0;
    for (size_t o = 0; o < G->npix; o++) {
        double r = G->dat[o] - G->mod[o];
        c += r * r / var[o];
    }
    return c;
}

/* The weights, the data term and the sky's block of the normal equations,
 * over all fitted pixels. */
static void ne_sky(group *G)
{
    int np = G->np, s0 = 3 * G->n, ns = G->nsky;
    size_t N = G->npix;
    for (size_t o = 0; o < N; o++) {
        double w = 1.0 / G->var[o];
        G->wt[o] = w;
        G->wres[o] = w * (G->dat[o] - G->mod[o]);
    }
    for (int a = 0; a < ns; a++) {
        const double *ca = G->basis + (size_t)a * N;
        double ga = 0.0;
        for (size_t o = 0; o < N; o++)
            ga += ca[o] * G->wres[o];
        G->g[s0 + a] = ga;
        for (int b = a; b < ns; b++) {
            const double *cb = G->basis + (size_t)b * N;
            double s = 0.0;
            for (size_t o = 0; o < N; o++)
                s += G->wt[o] * ca[o] * cb[o];
            G->A[(size_t)(s0 + a) * np + s0 + b] = s;
        }
    }
}

/* Star r's sums over the fitted pixels of its window within box columns
 * [x0, x1) and rows [y0, y1), added in: with g, its data terms Σ wres·J
 * (unscaled); with a, its coupling with the sky Σ w·J·c_b. */
static void star_sky_sums(const group *G, const rstar *rk, int x0, int x1, int y0, int y1,
                          double g[3], double a[3][6])
{
    int ns = G->nsky, full = x0 <= rk->i0 && x1 >= rk->i1;
    size_t N = G->npix;
    int j0 = rk->j0 > y0 ? rk->j0 : y0, j1 = rk->j1 < y1 ? rk->j1 : y1;
    for (int j = j0; j < j1; j++) {
        int t = j - rk->j0, o = rk->pp[t], e = o + rk->pn[t];
        if (!full) {
            int q0 = packed_at(G, j, x0), q1 = packed_at(G, j, x1);
            o = o > q0 ? o : q0;
            e = e < q1 ? e : q1;
        }
        if (o >= e)
            continue;
        size_t u = (size_t)(rk->pb[t] + o - rk->pp[t]);
        const double *jk[3] = {rk->prf + u, rk->dx + u, rk->dy + u};
        const double *wr = G->wres + o, *w = G->wt + o;
        int m = e - o;
        for (int c = 0; c < 3; c++) {
            if (g) {
                double q = 0.0;
                for (int i = 0; i < m; i++)
                    q += wr[i] * jk[c][i];
                g[c] += q;
            }
            for (int b = 0; a && b < ns; b++) {
                const double *cb = G->basis + (size_t)b * N + o;
                double q = 0.0;
                for (int i = 0; i < m; i++)
                    q += w[i] * jk[c][i] * cb[i];
                a[c][b] += q;
            }
        }
    }
}

/* Σ w J_k,a J_l,b over the fitted pixels where the windows of stars k and
 * l meet, within box columns [x0, x1) and rows [y0, y1); s is 3×3, only
 * b ≥ a when k == l.  Nonzero when they meet there at all. */
static int pair_sums(const group *G, const rstar *rk, const rstar *rl, int same, int x0, int x1,
                     int y0, int y1, double s[3][3])
{
    int j0 = rk->j0 > rl->j0 ? rk->j0 : rl->j0, j1 = rk->j1 < rl->j1 ? rk->j1 : rl->j1;
    int c0 = rk->i0 > rl->i0 ? rk->i0 : rl->i0, c1 = rk->i1 < rl->i1 ? rk->i1 : rl->i1;
    int full = x0 <= c0 && x1 >= c1;
    j0 = j0 > y0 ? j0 : y0;
    j1 = j1 < y1 ? j1 : y1;
    memset(s, 0, 9 * sizeof s[0][0]);
    if (j0 >= j1 || c0 >= c1 || x0 >= c1 || x1 <= c0)
        return 0;
    for (int j = j0; j < j1; j++) {
        int tk = j - rk->j0, tl = j - rl->j0;
        int a0 = rk->pp[tk] > rl->pp[tl] ? rk->pp[tk] : rl->pp[tl];
        int a1 = rk->pp[tk] + rk->pn[tk], e1 = rl->pp[tl] + rl->pn[tl];
        a1 = a1 < e1 ? a1 : e1;
        if (!full) {
            int q0 = packed_at(G, j, x0), q1 = packed_at(G, j, x1);
            a0 = a0 > q0 ? a0 : q0;
            a1 = a1 < q1 ? a1 : q1;
        }
        if (a0 >= a1)
            continue;
        size_t u = (size_t)(rk->pb[tk] + a0 - rk->pp[tk]);
        size_t v = (size_t)(rl->pb[tl] + a0 - rl->pp[tl]);
        const double *jk[3] = {rk->prf + u, rk->dx + u, rk->dy + u};
        const double *jl[3] = {rl->prf + v, rl->dx + v, rl->dy + v};
        const double *w = G->wt + a0;
        int m = a1 - a0;
        for (int a = 0; a < 3; a++)
            for (int b = (same ? a : 0); b < 3; b++) {
                double q = 0.0;
                for (int i = 0; i < m; i++)
                    q += w[i] * jk[a][i] * jl[b][i];
                s[a][b] += q;
            }
    }
    return 1;
}

/* The core of a pair: the box around both stars' cores when they lie
 * within two core half-widths of each other (else empty, x0 = x1). */
static void pair_core(const group *G, int k, int l, int *x0, int *x1, int *y0, int *y1)
{
    *x0 = G->cx0[k] < G->cx0[l] ? G->cx0[k] : G->cx0[l];
    *x1 = G->cx1[k] > G->cx1[l] ? G->cx1[k] : G->cx1[l];
    *y0 = G->cy0[k] < G->cy0[l] ? G->cy0[k] : G->cy0[l];
    *y1 = G->cy1[k] > G->cy1[l] ? G->cy1[k] : G->cy1[l];
    int span = (int)ceil(4.0 * G->core_hw) + 2;
    if (*x1 - *x0 > span || *y1 - *y0 > span)
        *x1 = *x0;
}

static void put_pair(group *G, const double *p, int k, int l, double s[3][3])
{
    int np = G->np;
    double sk[3] = {1.0, p[3 * k], p[3 * k]}, sl[3] = {1.0, p[3 * l], p[3 * l]};
    for (int a = 0; a < 3; a++)
        for (int b = (l == k ? a : 0); b < 3; b++)
            G->A[(size_t)(3 * k + a) * np + 3 * l + b] = sk[a] * sl[b] * s[a][b];
}

/* Each star's core for the pair and self sums between exact passes: the
 * box within G->core_hw px of where it is at an exact pass. */
static void set_cores(group *G, const double *p)
{
    double h = G->core_hw;
    for (int k = 0; k < G->n && h > 0; k++) {
        G->cx0[k] = (int)floor(p[3 * k + 1] - h) - (int)G->bx0;
        G->cx1[k] = (int)ceil(p[3 * k + 1] + h) + 1 - (int)G->bx0;
        G->cy0[k] = (int)floor(p[3 * k + 2] - h) - (int)G->by0;
        G->cy1[k] = (int)ceil(p[3 * k + 2] + h) + 1 - (int)G->by0;
    }
}

/* The exact pass's pairs: every pair whose windows meet, its sums outside
 * its core kept in G->tail (the cores as set_cores fixed them).  Nonzero
 * when out of memory. */
static int pairs_exact(group *G, const double *p, const rstar *r)
{
    int n = G->n;
    double h = G->core_hw;
    G->npair = 0;
    for (int k = 0; k < n; k++)
        for (int l = k + 1; l < n; l++) {
            double s[3][3], c[3][3];
            if (!pair_sums(G, &r[k], &r[l], 0, 0, G->bw, 0, G->bh, s))
                continue;
            put_pair(G, p, k, l, s);
            if (!(h > 0))
                continue;
            if (G->npair == G->cappair) {
                int cap = G->cappair ? 2 * G->cappair : 64;
                int *a = realloc(G->pk, (size_t)cap * sizeof *a);
                if (a)
                    G->pk = a;
                int *b = realloc(G->pl, (size_t)cap * sizeof *b);
                if (b)
                    G->pl = b;
                double *t = realloc(G->tail, (size_t)cap * 9 * sizeof *t);
                if (t)
                    G->tail = t;
                if (!a || !b || !t)
                    return 1;
                G->cappair = cap;
            }
            int x0, x1, y0, y1;
            pair_core(G, k, l, &x0, &x1, &y0, &y1);
            pair_sums(G, &r[k], &r[l], 0, x0, x1, y0, y1, c);
            double *t = G->tail + (size_t)G->npair * 9;
            for (int a = 0; a < 9; a++)
                t[a] = s[a / 3][a % 3] - c[a / 3][a % 3];
            G->pk[G->npair] = k;
            G->pl[G->npair++] = l;
        }
    return 0;
}

/* Between exact passes: each pair's core summed afresh, its tail as the
 * exact pass left it. */
static void pairs_core(group *G, const double *p, const rstar *r)
{
    for (int q = 0; q < G->npair; q++) {
        int k = G->pk[q], l = G->pl[q], x0, x1, y0, y1;
        double s[3][3];
        const double *t = G->tail + (size_t)q * 9;
        pair_core(G, k, l, &x0, &x1, &y0, &y1);
        pair_sums(G, &r[k], &r[l], 0, x0, x1, y0, y1, s);
        for (int a = 0; a < 9; a++)
            s[a / 3][a % 3] += t[a];
        put_pair(G, p, k, l, s);
    }
}

/* Star k's rows of g and A: its data terms, its coupling with the sky and
 * with itself.  While the wings are frozen (levmar) the couplings are
 * summed over the star's core only between exact passes, the rest (its
 * wings, whose values are frozen: only their weights move) kept from the
 * last exact pass in G->stail (every exact pass keeps it: the wings are
 * frozen right after one); g is summed over the whole window always. */
static void star_terms(group *G, const double *p, const rstar *rk, int k, int exact)
{
    int np = G->np, s0 = 3 * G->n, ns = G->nsky, bw = G->bw, bh = G->bh;
    double gk[3] = {0}, sk[3][6] = {{0}}, ss[3][3], *tl = G->stail + (size_t)k * 27;
    int x0 = G->cx0[k], x1 = G->cx1[k], y0 = G->cy0[k], y1 = G->cy1[k];
    if (exact || !G->frozen) {
        star_sky_sums(G, rk, 0, bw, 0, bh, gk, sk);
        pair_sums(G, rk, rk, 1, 0, bw, 0, bh, ss);
        if (exact && G->freezing) {
            double ck[3][6] = {{0}}, cs[3][3];
            star_sky_sums(G, rk, x0, x1, y0, y1, NULL, ck);
            pair_sums(G, rk, rk, 1, x0, x1, y0, y1, cs);
            for (int a = 0; a < 18; a++)
                tl[a] = sk[a / 6][a % 6] - ck[a / 6][a % 6];
            for (int a = 0; a < 9; a++)
                tl[18 + a] = ss[a / 3][a % 3] - cs[a / 3][a % 3];
        }
    } else {
        star_sky_sums(G, rk, 0, bw, 0, bh, gk, NULL);
        star_sky_sums(G, rk, x0, x1, y0, y1, NULL, sk);
        pair_sums(G, rk, rk, 1, x0, x1, y0, y1, ss);
        for (int a = 0; a < 18; a++)
            sk[a / 6][a % 6] += tl[a];
        for (int a = 0; a < 9; a++)
            ss[a / 3][a % 3] += tl[18 + a];
    }
    double sc[3] = {1.0, p[3 * k], p[3 * k]};
    for (int a = 0; a < 3; a++) {
        G->g[3 * k + a] = sc[a] * gk[a];
        for (int b = 0; b < ns; b++)
            G->A[(size_t)(3 * k + a) * np + s0 + b] = sc[a] * sk[a][b];
    }
    put_pair(G, p, k, k, ss);
}

enum { NE_STEER, NE_EXACT, NE_STARS };

/* Normal equations A = JᵀWJ and g = JᵀW(d − m) at the current model.
 * Block-sparse (issue 12): a star's columns meet the sky's over its own
 * window and another star's only where their windows overlap, so each
 * pair is summed over its windows' intersection alone, and only over the
 * fitted pixels (packed: contiguous rows, branch-free inner loops).
 * Between the steps of a fit (exact = 0) a pair of stars is summed only
 * over its core — within G->core_hw px of either star, when they lie
 * that close — and keeps its sums over the rest (the stars' far wings,
 * where both are faint and the coupling barely moves with a step) from
 * the last exact pass: A only steers the steps, so the root the fit
 * converges to (g = 0, always exact) does not change, and every fit ends
 * on an exact pass, from which its covariance comes.  In a big group the
 * pairs were most of the work (47 Tuc, 60 stars: 2.1e6 pixel-pairs a pass
 * against 1.1e5 pixels in the stars' windows).  g, the diagonal blocks and
 * the sky's, which set the steps' σ and the bounds, are exact every time.
 * Nonzero when out of memory. */
static int normal_equations(group *G, const double *p, const rstar *r, int exact)
{
    /* exact: NE_EXACT, or NE_STEER between steps; NE_STARS (every star's
     * own terms exact, its pairs' as between steps) was tried for the
     * refreshes of frozen wings: 47 Tuc 256² 10 % less CPU, but 51 fits
     * not converged against 21 (the first step after a refresh, steered
     * by stale pair sums, missed tol) */
    int np = G->np, n = G->n;
    memset(G->A, 0, (size_t)np * np * sizeof *G->A);
    memset(G->g, 0, (size_t)np * sizeof *G->g);
    ne_sky(G);
    int full = exact == NE_EXACT || !(G->core_hw > 0);
    if (full)
        set_cores(G, p);
    for (int k = 0; k < n; k++)
        star_terms(G, p, &r[k], k, full || exact == NE_STARS);
    if (full) {
        if (pairs_exact(G, p, r))
            return 1;
    } else
        pairs_core(G, p, r);
    G->ne_exact = full;
    for (int a = 0; a < np; a++)           /* mirror the upper triangle */
        for (int b = 0; b < a; b++)
            G->A[(size_t)a * np + b] = G->A[(size_t)b * np + a];
    /* Without a fitted sky the sky slot is held fixed: the slot gets a unit,
     * uncoupled row, so the step solves the star block only. */
    if (!G->nsky) {
        int s = 3 * n;
        for (int a = 0; a < np; a++)
            G->A[(size_t)a * np + s] = G->A[(size_t)s * np + a] = 0.0;
        G->A[(size_t)s * np + s] = 1.0;
        G->g[s] = 0.0;
    }
    return 0;
}

/* Solve (A + λ diag A) δ = g by Cholesky; nonzero when not positive definite. */
static int lm_step(group *G, double lambda)
{
    int np = G->np;
    memcpy(G->M, G->A, (size_t)np * np * sizeof *G->M);
    for (int a = 0; a < np; a++) {
        double d = G->A[(size_t)a * np + a];
        G->M[(size_t)a * np + a] = d * (1.0 + lambda) + (d > 0 ? 0.0 : 1e-300);
    }
    memcpy(G->step, G->g, (size_t)np * sizeof *G->step);
    return LAPACKE_dposv(LAPACK_ROW_MAJOR, 'U', np, 1, G->M, np, G->step, 1) != 0;
}

/* The sky's lower bound (bound_step, sky_in_bounds): 10 σ below the sky
 * the stars were found on.  Not the lowest pixel: a bright star's wings
 * can fill its window, so its lowest pixel sits far above the sky (Tiny
 * Tim, 10⁶ e⁻, fitrad 5: 140 e⁻ over a sky of 100; a sky held there was
 * flag 8 for 6 % of the bench's ugly scene); and a neighbour painted out
 * with too much light leaves data far below the sky, which a bound from
 * the data lets the sky follow (GLIMPSE near its hollow saturated cores:
 * −7·10⁴ e⁻, the group's fluxes to 10⁹, and on through the next rounds
 * until every residual pixel was off).  Without a known sky, one data
 * range below the lowest pixel. */
static double sky_floor(const group *G)
{
    double base = isfinite(G->sknown) ? G->sknown : G->dlo - (G->dhi - G->dlo);
    return base - 10.0 * sqrt(fmax(base, 0.0) + G->ron2);
}

/* Whether the plane or quadratic sky of the last model_of stays within
 * [sky_floor, dhi] on every fitted pixel (model_of keeps its range).
 * Bounding the coefficients one by one does not: each within its own
 * bound, their sum can still go far below the floor at the box's corners
 * (GLIMPSE's left quarter, 3 rounds: without this 5 stars ended on a
 * negative sky and 3 with CHI2_PSF > 1e4, with it none).  A trial step
 * outside is refused as one that raises D is. */
static int sky_in_bounds(const group *G)
{
    if (G->nsky <= 1)
        return 1;                /* the constant: bound_step */
    return G->skylo >= sky_floor(G) && G->skyhi <= G->dhi;
}

/* Cut the step to what one iteration may do, so a step the local
 * linearisation cannot vouch for is not even tried: positions by at most
 * 1 px (DAOPHOT does the same: a start far off cannot fling a star across
 * the group); a flux by at most ×10 up and 90 % down, plus 3 of its σ so
 * faint stars can cross zero (a start of 1 e⁻ reaches 10⁶ e⁻ in five
 * steps); each sky coefficient (the basis is scaled to ±1 on the box) by
 * 3 σ of a sky pixel or half the sky, whichever is larger.  Returns 1 when
 * something was cut. */
static int bound_step(group *G)
{
    int n = G->n, np = G->np, cut = 0;
    for (int k = 0; k < n; k++) {
        double E = fabs(G->p[3 * k]), aee = G->A[(size_t)(3 * k) * np + 3 * k];
        double se = aee > 0 ? 3.0 / sqrt(aee) : INFINITY;
        double lim[3][2] = {{-(0.9 * E + se), 9.0 * E + se}, {-1.0, 1.0}, {-1.0, 1.0}};
        for (int a = 0; a < 3; a++) {
            double *d = &G->step[3 * k + a];
            if (*d < lim[a][0] || *d > lim[a][1]) {
                *d = *d < lim[a][0] ? lim[a][0] : lim[a][1];
                cut = 1;
            }
        }
    }
    /* Absolute bounds, whatever D does: a flux beyond emax or a sky outside
     * the data's range is no answer but a walk along a degenerate direction
     * (a table with negative wings lets huge fluxes trade against a huge
     * negative sky: GLIMPSE's IRAC PSF, sky −2.8e13, fluxes 1e17). */
    for (int k = 0; k < n; k++) {
        double *d = &G->step[3 * k], E = G->p[3 * k];
        if (fabs(E + *d) > G->emax) {
            *d = (E + *d > 0 ? G->emax : -G->emax) - E;
            cut = 1;
        }
    }
    if (G->nsky) {
        double B0 = G->p[3 * n], lo = sky_floor(G);
        if (B0 + G->step[3 * n] < lo || B0 + G->step[3 * n] > G->dhi) {
            G->step[3 * n] = (B0 + G->step[3 * n] < lo ? lo : G->dhi) - B0;
            cut = 1;
        }
        for (int a = 1; a < G->nsky; a++) {
            double *d = &G->step[3 * n + a], c = G->p[3 * n + a], span = G->dhi - lo;
            if (fabs(c + *d) > span) {
                *d = (c + *d > 0 ? span : -span) - c;
                cut = 1;
            }
        }
    }
    if (G->nsky) {
        double B = G->p[3 * n];
        double lim = fmax(3.0 * sqrt((B > 0 ? B : 0.0) + G->ron2), 0.5 * fabs(B));
        for (int a = 0; a < G->nsky; a++) {
            double *d = &G->step[3 * n + a];
            if (fabs(*d) > lim) {
                *d = *d > 0 ? lim : -lim;
                cut = 1;
            }
        }
    }
    return cut;
}

/* The largest step of a fitted parameter in units of its σ, 1/sqrt(A_aa)
 * (the conditional σ; the fit's stopping rule compares it with tol). */
static double step_sigmas(const group *G)
{
    int np = G->np, npar = 3 * G->n + G->nsky;
    double z = 0.0;
    for (int a = 0; a < npar; a++) {
        double d = G->A[(size_t)a * np + a];
        double v = d > 0 ? fabs(G->step[a]) * sqrt(d) : 0.0;
        z = v > z ? v : z;
    }
    return z;
}

/* The resolution of D [σ]: the position derivatives are the five-point
 * formula on the shifted table (paper §3.2), not the exact derivatives of
 * the rendered model, so the root the normal equations point to lies a
 * little off D's own minimum, and within that distance a step can raise D
 * although the quadratic model says it should not (measured on 600
 * single-star fits, FWHM 3 px, 1× table, at the first refused step: median
 * 0.003 σ, 99th percentile 0.2 σ, largest 0.26 σ; faint stars, whose
 * weight sits in the wings, have the largest).  On steps this small the
 * model is otherwise quadratic to high accuracy, so a step below
 * LM_RESOLVE_SIGMAS (undamped) that cannot lower D even when damped means
 * the fit is as close as D can tell: it has converged. */
#define LM_RESOLVE_SIGMAS 0.5

/* The quasi-likelihood dispersion φ = D/dof of deviance D, floored at 1
 * (a model that fits keeps the Fisher σ). */
static double dispersion(const group *G, double D)
{
    double dof = (double)G->npix - (double)(3 * G->n + G->nsky);
    return dof > 0 && D / dof > 1.0 ? D / dof : 1.0;
}

/* Frozen wings (issue 12).  A star's window reaches as far as its light
 * matters to the model (its crop radius: 47 Tuc, 1240 fitted px a star on
 * average, against 80 in its own fitting disc), yet between two steps the
 * light of its wings barely moves.  So the LM iterates with each star
 * redrawn on its core only — the box LM_CORE px beyond G->core_hw around
 * where it stood when the wings were last drawn — and its wings (values
 * and derivatives) as they were then, scaled by its current flux; it
 * redraws everything (a refresh) when a star has moved LM_MOVE px from
 * there, and when the steps have converged on that model.  A fit is
 * converged only when the first step from a refreshed state is below tol:
 * the same test on the same exact normal equations as without freezing,
 * so the answer is the same to within tol; the frozen model only steers
 * the way there. */
#define LM_CORE 1.0
#define LM_MOVE 0.5

/* Freeze every star's wings where it is now: its core box, and the trial
 * buffers as the current ones (the same windows and wing values). */
static void core_box(group *G, int k)
{
    double h = G->core_hw + LM_CORE, x = G->p[3 * k + 1], y = G->p[3 * k + 2];
    rstar *c = &G->cur[k];
    c->ci0 = (int)floor(x - h) - (int)G->bx0;
    c->ci1 = (int)ceil(x + h) + 1 - (int)G->bx0;
    c->cj0 = (int)floor(y - h) - (int)G->by0;
    c->cj1 = (int)ceil(y + h) + 1 - (int)G->by0;
}

/* Whether freezing pays: the stars' windows hold LM_PAYS times the
 * pixels of their cores (a PSF with faint wings, or a Gaussian's small
 * crop radius, leaves nothing to save but the refreshes' cost: the crowded
 * Gaussian scene of make validate ran 28 % slower frozen). */
#define LM_PAYS 2.0

static int freezing_pays(group *G)
{
    double win = 0.0, core = 0.0;
    for (int k = 0; k < G->n; k++) {
        rstar *c = &G->cur[k];
        int b[4], ns;
        core_box(G, k);
        ns = core_rows(G, c, b);
        for (int t = 0; t < c->j1 - c->j0; t++)
            win += c->pn[t];
        for (int q = 0; q < ns; q++)
            core += G->spans[q].n;
    }
    return win > LM_PAYS * core;
}

static void freeze(group *G)
{
    for (int k = 0; k < G->n; k++) {
        rstar *c = &G->cur[k], *t = &G->trial[k];
        G->fx[k] = G->p[3 * k + 1];
        G->fy[k] = G->p[3 * k + 2];
        core_box(G, k);
        int *pp = t->pp, *pn = t->pn, *pb = t->pb;
        double *prf = t->prf, *dx = t->dx, *dy = t->dy;
        *t = *c;
        t->pp = pp;
        t->pn = pn;
        t->pb = pb;
        t->prf = prf;
        t->dx = dx;
        t->dy = dy;
        int rows = c->j1 - c->j0;
        size_t len = rows > 0 ? (size_t)(c->pb[rows - 1] + c->pn[rows - 1]) : 0;
        if (rows > 0) {
            memcpy(pp, c->pp, (size_t)rows * sizeof *pp);
            memcpy(pn, c->pn, (size_t)rows * sizeof *pn);
            memcpy(pb, c->pb, (size_t)rows * sizeof *pb);
        }
        memcpy(prf, c->prf, len * sizeof *prf);
        memcpy(dx, c->dx, len * sizeof *dx);
        memcpy(dy, c->dy, len * sizeof *dy);
    }
    G->frozen = 1;
}

/* Whether a star has moved LM_MOVE px from where its wings were drawn. */
static int moved_far(const group *G)
{
    for (int k = 0; k < G->n; k++)
        if (fabs(G->p[3 * k + 1] - G->fx[k]) > LM_MOVE || fabs(G->p[3 * k + 2] - G->fy[k]) > LM_MOVE)
            return 1;
    return 0;
}

/* Everything redrawn at G->p (whole windows), its deviance in *D, exact
 * normal equations; frozen again there when again is set.  Nonzero when
 * out of memory. */
static int refresh(group *G, double *D, int again)
{
    G->frozen = 0;
    if (render_all(G, G->p, G->cur, RENDER_ALL))
        return 1;
    model_of(G, G->p, G->cur);
    variance_of(G);
    *D = deviance_of(G);
    if (normal_equations(G, G->p, G->cur, NE_EXACT))
        return 1;
    if (again)
        freeze(G);
    return 0;
}

/* Levenberg–Marquardt from G->p at the current sky order.  A step is taken
 * only when it lowers D.  Converged (*converged = 1) when a step taken is
 * below tol·σ·√φ in every parameter (φ the dispersion, below) (scaled back by 1 + λ, so damping cannot
 * fake it), or when the first, least damped step tried from the current
 * state was already below LM_RESOLVE_SIGMAS and it took 1000× more damping
 * to lower D, or that did not help either.  Not converged when the damping
 * blows up (λ > 1e8) from a larger step, or after maxiter steps; the state
 * is then the best one reached.  Accepted steps are added to *iter.
 * Nonzero: out of memory. */
static int lm_loop(group *G, const mp_fit_opts *o, int freeze_ok, int *iter, int *converged)
{
    G->freezing = freeze_ok && G->core_hw > 0 && G->crop && freezing_pays(G);
    model_of(G, G->p, G->cur);
    variance_of(G);
    if (normal_equations(G, G->p, G->cur, 1))
        return 1;
    double D = deviance_of(G), lambda = 1e-3, zfirst = INFINITY, lfirst = lambda;
    int it = 0, trials = 0, np = G->np, fresh = 1, since = 0;
    if (G->freezing)
        freeze(G);
    /* Steps are judged in σ of the data as they scatter: the quasi-
     * likelihood dispersion φ = D/dof (McCullagh & Nelder §9.2.4) scales
     * every σ by √φ when the model misses the data (a PSF sharper than the
     * stars, χ²/dof ≫ 1); φ is floored at 1, so a model that fits keeps
     * the Fisher σ. */
    double rphi = 1.0 / sqrt(dispersion(G, D));
    *converged = 0;
    while (it < o->maxiter && trials < 4 * o->maxiter) {
        trials++;
        if (lm_step(G, lambda)) {
            lambda *= 10.0;
            if (lambda > 1e12)
                break;
            continue;
        }
        int cut = bound_step(G);
        double z = cut ? INFINITY : step_sigmas(G) * rphi;
        if (fresh) {
            zfirst = z * (1.0 + lambda);
            lfirst = lambda;
        }
        fresh = 0;
        for (int a = 0; a < np; a++)
            G->pt[a] = G->p[a] + G->step[a];
        if (render_all(G, G->pt, G->trial, RENDER_PRF))
            return 1;
        model_of(G, G->pt, G->trial);
        double Dt = sky_in_bounds(G) ? deviance_of(G) : INFINITY;
        if (!(Dt < D)) {
            model_of(G, G->p, G->cur);
            lambda *= 10.0;
            if (zfirst < LM_RESOLVE_SIGMAS && lambda > 1e3 * lfirst) {
                if (G->frozen && since > 0) {    /* on the frozen model: see */
                    if (refresh(G, &D, 1))
                        return 1;
                    since = 0;
                    fresh = 1;
                    lambda = lfirst;
                    rphi = 1.0 / sqrt(dispersion(G, D));
                    continue;
                }
                *converged = 1;      /* damped 1000×: nothing left D can see */
                break;
            }
            if (lambda > 1e8)
                break;
            continue;
        }
        it++;
        since++;
        /* Taken: converged when the step, undamped, was below tol, or when
         * only 1000× damping made progress from a state whose undamped step
         * was within D's resolution (creeping on D's noise floor). */
        int done = z * (1.0 + lambda) < o->tol ||
                   (zfirst < LM_RESOLVE_SIGMAS && lambda > 1e3 * lfirst * (1.0 - 1e-9));
        double *tp = G->p;
        G->p = G->pt;
        G->pt = tp;
        rstar *tr = G->cur;
        G->cur = G->trial;
        G->trial = tr;
        D = Dt;
        rphi = 1.0 / sqrt(dispersion(G, D));
        fresh = 1;
        lambda = lambda / 10.0 > 1e-7 ? lambda / 10.0 : 1e-7;
        variance_of(G);
        if (G->frozen && (done || moved_far(G))) {
            /* Converged from a refreshed state (the step was computed
             * from exact sums there): the same test as unfrozen. */
            int real = done && since == 1;
            if (refresh(G, &D, !real))
                return 1;
            since = 0;
            rphi = 1.0 / sqrt(dispersion(G, D));
            if (real) {
                *converged = 1;
                break;
            }
            continue;
        }
        if (render_all(G, G->p, G->cur, RENDER_DERIVS) ||
            normal_equations(G, G->p, G->cur, done))
            return 1;
        if (done) {
            *converged = 1;
            break;
        }
    }
    *iter += it;
    /* The covariance and the next sky order start from exact sums on
     * whole windows. */
    if (G->frozen) {
        if (since > 0 && refresh(G, &D, 0))
            return 1;
        G->frozen = 0;
    }
    if (!G->ne_exact && normal_equations(G, G->p, G->cur, 1))
        return 1;
    return 0;
}

/* A fit that did not converge with frozen wings goes on from its best
 * state without them (with its own maxiter): frozen, a few more fits end
 * unconverged (47 Tuc 256², PSF built from the frame: 38 of 588 stars
 * flagged 8 against 1). */
static int levmar(group *G, const mp_fit_opts *o, int *iter, int *converged)
{
    if (lm_loop(G, o, !o->exact_lm, iter, converged))
        return 1;
    if (*converged || !G->freezing)
        return 0;
    if (render_all(G, G->p, G->cur, RENDER_ALL))
        return 1;
    return lm_loop(G, o, 0, iter, converged);
}

/* gᵀA⁻¹g for the np×np matrix A (row stride np), by Cholesky of the
 * equilibrated D⁻¹AD⁻¹ (D² = diag A) in M; x (np) is scratch.  NaN when A
 * is not positive definite. */
static double inverse_quad_form(const double *A, const double *g, int np, double *M, double *x)
{
    for (int a = 0; a < np; a++) {
        double d = A[(size_t)a * np + a];
        if (!(d > 0))
            return NAN;
    }
    for (int a = 0; a < np; a++)
        for (int b = 0; b < np; b++)
            M[(size_t)a * np + b] = A[(size_t)a * np + b] /
                                    sqrt(A[(size_t)a * np + a] * A[(size_t)b * np + b]);
    for (int a = 0; a < np; a++)
        x[a] = g[a] / sqrt(A[(size_t)a * np + a]);
    double *y = x + np;
    memcpy(y, x, (size_t)np * sizeof *y);
    if (LAPACKE_dposv(LAPACK_ROW_MAJOR, 'U', np, 1, M, np, y, 1) != 0)
        return NAN;
    double q = 0.0;
    for (int a = 0; a < np; a++)
        q += x[a] * y[a];
    return q;
}

double mp_chi2_sf(int k, double x)
{
    if (k < 1)
        return NAN;
    if (!(x > 0))
        return 1.0;
    double h = 0.5 * x, e = exp(-h);
    if (k % 2 == 0) {            /* e^{−x/2} Σ_{j<k/2} (x/2)^j / j! */
        double t = 1.0, s = 1.0;
        for (int j = 1; j < k / 2; j++)
            s += (t *= h / j);
        return e * s;
    }
    /* erfc(√(x/2)) + e^{−x/2} Σ_{j=1}^{(k−1)/2} (x/2)^{j−1/2} / Γ(j + 1/2) */
    double t = sqrt(h) / (0.5 * sqrt(M_PI)), s = 0.0;
    for (int j = 1; j <= (k - 1) / 2; j++) {
        s += t;
        t *= h / (j + 0.5);
    }
    return erfc(sqrt(h)) + e * s;
}

/* The score (Lagrange-multiplier) test of the sky terms [nsky, next) at the
 * converged fit (Rao 1948), in the quasi-likelihood form: with the
 * gradient g = Σ c (d − m)/V and the information I = Σ c cᵀ/V of the sky
 * basis c, T = gᵀI⁻¹g (all next terms) − gᵀI⁻¹g (the current nsky), the
 * score of the extra terms in the metric of their covariance.  Under a sky
 * of the current order T ~ χ²(next − nsky).  It reads the background only,
 * where the group's stars put less than a pixel's σ: residuals of a PSF
 * that does not quite fit a bright core (paper §5.4) are concentrated and
 * large, and a smooth polynomial would partly absorb them, but they are
 * not sky.  That is the fitted pixels so lit, and the ring around the
 * group out to MP_SKY_TEST_RADIUS·fitrad: inside a 5-px window alone a
 * slope that shifts a faint star by 1 σ is itself only about 3 σ
 * significant, and around a bright star nearly no pixel is unlit (bench
 * gradient scene: 21 % of the stars raised, astrometry 1.25× the CRLB
 * against 1.08× with the quadratic forced), while the ring out to twice
 * fitrad holds about 15× the information on a slope.  The ring is read
 * robustly, as SExtractor's meshes are: cut into 16 cells (8 sectors
 * around the group × 2 distances), each cell counts once with the median
 * of its residuals (variance π/2·V/n), so a star nobody has found yet in
 * the ring moves one cell's median a little instead of looking like a
 * slope.  T is divided by the dispersion φ = max(1, χ²/dof) of what was
 * read under the larger model, as quasi-likelihood tests are. */
typedef struct {
    double A[36], g[6], chi2;   /* Σ c cᵀ/V, Σ c (d − m)/V, Σ (d − m)²/V */
    size_t m;                   /* pixels and cells read */
} sky_sums;

static void add_sky_term(sky_sums *S, const double c[6], double r, double v)
{
    for (int a = 0; a < 6; a++) {
        S->g[a] += c[a] * r / v;
        for (int b = a; b < 6; b++)
            S->A[a * 6 + b] += c[a] * c[b] / v;
    }
    S->chi2 += r * r / v;
    S->m++;
}

/* The fitted pixels the stars leave dark. */
static void window_sums(const group *G, sky_sums *S)
{
    for (int q = 0; q < G->nrun; q++)
        for (int i = G->ri0[q]; i < G->ri1[q]; i++) {
            size_t o = (size_t)(G->rp[q] + i - G->ri0[q]);
            double X = (double)(G->bx0 + i), Y = (double)(G->by0 + G->rj[q]), c[6];
            double star = G->mod[o] - sky_at(G, G->p, X, Y), v = G->var[o];
            if (star * star > v)
                continue;
            sky_basis(G, X, Y, c);
            add_sky_term(S, c, G->dat[o] - G->mod[o], v);
        }
}

enum { RING_SECTORS = 8, RING_CELLS = 2 * RING_SECTORS, RING_MIN = 5 };   /* octants × 2 */

static int cmp_double(const void *a, const void *b);

/* The octant 0..7 of (dx, dy), counter-clockwise from +x (no atan2: the
 * ring's pixels are many and the fit of a lone star is short). */
static int octant(double dx, double dy)
{
    int near_x = fabs(dx) >= fabs(dy);
    if (dy >= 0)
        return dx >= 0 ? (near_x ? 0 : 1) : (near_x ? 3 : 2);
    return dx >= 0 ? (near_x ? 7 : 6) : (near_x ? 4 : 5);
}

/* The ring's cells (see above): each cell's median residual, at the mean
 * of its basis, with variance π/2 times its mean V over its count.
 * Nonzero: out of memory. */
static int ring_sums(group *G, double fitrad, sky_sums *S)
{
    double R = MP_SKY_TEST_RADIUS * fitrad, rmid = 0.5 * (fitrad + R);
    if (!isfinite(R) || !(R > fitrad))
        return 0;
    long nx = G->f->im.nx, ny = G->f->im.ny, pad = (long)ceil(R - fitrad) + 1;
    long x0 = G->bx0 - pad, y0 = G->by0 - pad, x1 = G->bx0 + G->bw + pad, y1 = G->by0 + G->bh + pad;
    x0 = x0 < 1 ? 1 : x0;
    y0 = y0 < 1 ? 1 : y0;
    x1 = x1 > nx + 1 ? nx + 1 : x1;
    y1 = y1 > ny + 1 ? ny + 1 : y1;
    long w = x1 - x0, h = y1 - y0;
    if (w <= 0 || h <= 0)
        return 0;
    size_t nb = (size_t)(w * h);
    double *light = calloc(nb, sizeof *light), *buf = malloc(nb * sizeof *buf);
    double *res = malloc(nb * sizeof *res);
    int *cell = malloc(nb * sizeof *cell);
    int rc = 1;
    if (!light || !buf || !res || !cell)
        goto done;
    /* The group's own stars over the ring, from their fitted values, with
     * a 5-tap kernel: only light below a pixel's σ is used, where a few
     * per cent of it is far below the noise of a cell's median, and the
     * ring is several times the window, so the full kernel would cost
     * more than the fit (bench isolated scene: +45 % CPU per star). */
    mp_prf_model mr = *G->m;
    mr.sinc_hw = mr.sinc_hw < 2 ? mr.sinc_hw : 2;
    for (int k = 0; k < G->n; k++) {
        long sx, sy, kx0, ky0, kx1, ky1;    /* the ring's part within R of star k */
        int sw, sh;
        double xk = G->p[3 * k + 1], yk = G->p[3 * k + 2];
        kx0 = (long)floor(xk - R);
        ky0 = (long)floor(yk - R);
        kx1 = (long)ceil(xk + R) + 1;
        ky1 = (long)ceil(yk + R) + 1;
        kx0 = kx0 < x0 ? x0 : kx0;
        ky0 = ky0 < y0 ? y0 : ky0;
        kx1 = kx1 > x1 ? x1 : kx1;
        ky1 = ky1 > y1 ? y1 : ky1;
        if (kx1 <= kx0 || ky1 <= ky0)
            continue;
        if (mp_prf_render_window(&mr, xk, yk, kx0, ky0, kx1 - kx0, ky1 - ky0, &sx, &sy, &sw, &sh, buf,
                                 NULL, NULL, &G->work))
            goto done;
        for (int j = 0; j < sh; j++)
            for (int i = 0; i < sw; i++)
                light[(sy - y0 + j) * w + (sx - x0 + i)] += G->p[3 * k] * buf[(size_t)j * sw + i];
    }
    double sumc[RING_CELLS][6] = {{0}}, sumv[RING_CELLS] = {0};
    size_t cnt[RING_CELLS] = {0};
    const uint8_t *mask = G->f->mask;
    for (long Y = y0; Y < y1; Y++)
        for (long X = x0; X < x1; X++) {
            size_t q = (size_t)((Y - y0) * w + (X - x0));
            long i = X - G->bx0, j = Y - G->by0;
            cell[q] = -1;
            if (i >= 0 && i < G->bw && j >= 0 && j < G->bh && G->sel[(size_t)j * G->bw + i])
                continue;                       /* a fitted pixel: window_sums */
            if (mask && mask[(size_t)(Y - 1) * nx + (size_t)(X - 1)])
                continue;
            double d2 = INFINITY;
            for (int k = 0; k < G->n; k++) {
                double dx = X - G->p[3 * k + 1], dy = Y - G->p[3 * k + 2];
                d2 = fmin(d2, dx * dx + dy * dy);
            }
            double sky = sky_at(G, G->p, (double)X, (double)Y), star = light[q];
            double v = (sky + star > G->vfloor ? sky + star : G->vfloor) + ron2_at(G, X, Y);
            if (d2 > R * R || star * star > v)
                continue;
            int cl = octant((double)X - G->xc, (double)Y - G->yc) + (d2 > rmid * rmid ? RING_SECTORS : 0);
            double c[6];
            sky_basis(G, (double)X, (double)Y, c);
            for (int a = 0; a < 6; a++)
                sumc[cl][a] += c[a];
            sumv[cl] += v;
            cnt[cl]++;
            cell[q] = cl;
            res[q] = pixel(G, X, Y) - sky - star;
        }
    for (int cl = 0; cl < RING_CELLS; cl++) {
        if (cnt[cl] < RING_MIN)
            continue;
        size_t n = 0;
        for (size_t q = 0; q < nb; q++)
            if (cell[q] == cl)
                buf[n++] = res[q];
        qsort(buf, n, sizeof *buf, cmp_double);
        double med = n % 2 ? buf[n / 2] : 0.5 * (buf[n / 2 - 1] + buf[n / 2]), c[6];
        for (int a = 0; a < 6; a++)
            c[a] = sumc[cl][a] / (double)n;
        add_sky_term(S, c, med, 0.5 * M_PI * sumv[cl] / ((double)n * (double)n));
    }
    rc = 0;
done:
    free(light);
    free(buf);
    free(res);
    free(cell);
    return rc;
}

/* The p-value of the test above from the sums (1 without enough pixels or
 * with a singular matrix: no evidence). */
static double sky_score_pvalue(const sky_sums *S, int n0, int next)
{
    double A1[36], A0[36], M[36], x[12];
    if (S->m <= (size_t)(2 * next))
        return 1.0;
    for (int a = 0; a < next; a++)
        for (int b = 0; b < next; b++) {
            A1[a * next + b] = S->A[(a < b ? a : b) * 6 + (a < b ? b : a)];
            if (a < n0 && b < n0)
                A0[a * n0 + b] = A1[a * next + b];
        }
    double s1 = inverse_quad_form(A1, S->g, next, M, x), s0 = inverse_quad_form(A0, S->g, n0, M, x);
    if (!isfinite(s0) || !isfinite(s1))
        return 1.0;
    /* φ from what the larger model leaves (χ² − s1 over m − next): from the
     * current order's residuals the very slope tested would inflate it. */
    double phi = (S->chi2 - s1) / (double)(S->m - (size_t)next);
    double T = (s1 > s0 ? s1 - s0 : 0.0) / (phi > 1.0 ? phi : 1.0);
    return mp_chi2_sf(next - n0, T);
}

/* Covariance = A⁻¹ into G->M.  Cholesky first; when A is singular or
 * nearly so, the eigen pseudo-inverse (small eigenvalues dropped) and a
 * return of 1 so the stars are flagged degenerate. */
static int covariance(group *G)
{
    int np = G->np;
    /* Equilibrate: C = D⁻¹ (D⁻¹ A D⁻¹)⁻¹ D⁻¹ with D = sqrt(diag A). */
    double *d = G->step;
    for (int a = 0; a < np; a++) {
        double v = G->A[(size_t)a * np + a];
        d[a] = v > 0 ? sqrt(v) : 1.0;
    }
    for (int a = 0; a < np; a++)
        for (int b = 0; b < np; b++)
            G->M[(size_t)a * np + b] = G->A[(size_t)a * np + b] / (d[a] * d[b]);
    int rc = 0;
    if (LAPACKE_dpotrf(LAPACK_ROW_MAJOR, 'U', np, G->M, np) == 0 &&
        LAPACKE_dpotri(LAPACK_ROW_MAJOR, 'U', np, G->M, np) == 0) {
        for (int a = 0; a < np; a++)
            for (int b = 0; b < a; b++)
                G->M[(size_t)a * np + b] = G->M[(size_t)b * np + a];
    } else {
        rc = 1;
        double *ev = malloc((size_t)np * sizeof *ev), *V = malloc((size_t)np * np * sizeof *V);
        if (!ev || !V) {
            free(ev);
            free(V);
            return 2;
        }
        for (int a = 0; a < np; a++)
            for (int b = 0; b < np; b++)
                V[(size_t)a * np + b] = G->A[(size_t)a * np + b] / (d[a] * d[b]);
        if (LAPACKE_dsyev(LAPACK_ROW_MAJOR, 'V', 'U', np, V, np, ev) != 0) {
            free(ev);
            free(V);
            return 2;
        }
        double emax = ev[np - 1];
        memset(G->M, 0, (size_t)np * np * sizeof *G->M);
        for (int e = 0; e < np; e++) {
            if (!(ev[e] > emax * 1e-12))
                continue;
            for (int a = 0; a < np; a++)
                for (int b = 0; b < np; b++)
                    G->M[(size_t)a * np + b] += V[(size_t)a * np + e] * V[(size_t)b * np + e] / ev[e];
        }
        free(ev);
        free(V);
    }
    for (int a = 0; a < np; a++)
        for (int b = 0; b < np; b++)
            G->M[(size_t)a * np + b] /= d[a] * d[b];
    return rc;
}

static int cmp_double(const void *a, const void *b)
{
    double x = *(const double *)a, y = *(const double *)b;
    return (x > y) - (x < y);
}

/* Whole-frame fits have no fitting radius: flag a star whose PRF footprint
 * (mp_prf_box) holds a masked (32) or saturated (1) pixel or crosses the
 * frame's edge (4).  Without this a whole-frame fit never set 32 or 1 and
 * set 4 only for a centre off the frame (found by tests/unit/test_stiff_fit.c). */
static void flag_footprint(const group *G, mp_star *s)
{
    const mp_frame *f = G->f;
    long nx = f->im.nx, ny = f->im.ny, x0, y0;
    int w, h;
    mp_prf_box(G->m, s->x, s->y, &x0, &y0, &w, &h);
    if (x0 < 1 || y0 < 1 || x0 + w - 1 > nx || y0 + h - 1 > ny)
        s->flags |= MP_FLAG_EDGE;
    if (!f->mask)
        return;
    for (long Y = y0 > 1 ? y0 : 1; Y <= y0 + h - 1 && Y <= ny; Y++)
        for (long X = x0 > 1 ? x0 : 1; X <= x0 + w - 1 && X <= nx; X++) {
            uint8_t mk = f->mask[(size_t)(Y - 1) * nx + (size_t)(X - 1)];
            if (mk & MP_MASK_BAD)
                s->flags |= MP_FLAG_MASKED;
            if (mk & MP_MASK_SATURATED)
                s->flags |= MP_FLAG_SATURATED;
        }
}

/* The fitted pixels of G->sel packed row by row: the runs, the data and
 * the sky basis at each.  2 when out of memory. */
static int pack_pixels(group *G)
{
    size_t N = G->npix ? G->npix : 1;
    int nrun = 0;
    for (int j = 0; j < G->bh; j++)
        for (int i = 0; i < G->bw; i++)
            nrun += G->sel[(size_t)j * G->bw + i] && (i == 0 || !G->sel[(size_t)j * G->bw + i - 1]);
    size_t nr = nrun ? (size_t)nrun : 1;
    G->rj = malloc(nr * sizeof *G->rj);
    G->ri0 = malloc(nr * sizeof *G->ri0);
    G->ri1 = malloc(nr * sizeof *G->ri1);
    G->rp = malloc(nr * sizeof *G->rp);
    G->spans = malloc(nr * sizeof *G->spans);
    G->soff = malloc(nr * sizeof *G->soff);
    G->rrow = malloc(((size_t)G->bh + 1) * sizeof *G->rrow);
    G->prow = malloc(((size_t)G->bh + 1) * sizeof *G->prow);
    G->dat = malloc(N * sizeof *G->dat);
    G->mod = malloc(N * sizeof *G->mod);
    G->var = malloc(N * sizeof *G->var);
    G->rv = malloc(N * sizeof *G->rv);
    G->wt = malloc(N * sizeof *G->wt);
    G->wres = malloc(N * sizeof *G->wres);
    G->basis = malloc(6 * N * sizeof *G->basis);
    if (!G->rj || !G->ri0 || !G->ri1 || !G->rp || !G->spans || !G->soff || !G->rrow || !G->prow ||
        !G->dat || !G->mod || !G->var || !G->rv || !G->wt || !G->wres || !G->basis)
        return 2;
    int q = 0, o = 0;
    for (int j = 0; j < G->bh; j++) {
        G->rrow[j] = q;
        G->prow[j] = o;
        for (int i = 0; i < G->bw; i++) {
            if (!G->sel[(size_t)j * G->bw + i])
                continue;
            if (i == 0 || !G->sel[(size_t)j * G->bw + i - 1]) {
                G->rj[q] = j;
                G->ri0[q] = i;
                G->rp[q] = o;
                q++;
            }
            G->ri1[q - 1] = i + 1;
            double c[6];
            sky_basis(G, (double)(G->bx0 + i), (double)(G->by0 + j), c);
            for (int a = 0; a < 6; a++)
                G->basis[(size_t)a * N + (size_t)o] = c[a];
            G->rv[o] = ron2_at(G, G->bx0 + i, G->by0 + j);
            G->dat[o++] = pixel(G, G->bx0 + i, G->by0 + j);
        }
    }
    G->rrow[G->bh] = q;
    G->prow[G->bh] = o;
    G->nrun = nrun;
    return 0;
}

/* Choose the fitted pixels and set the flags that depend on them. */
static int select_pixels(group *G, const mp_fit_opts *o, mp_star *st)
{
    const mp_frame *f = G->f;
    long nx = f->im.nx, ny = f->im.ny;
    double r = o->fitrad;
    int whole = !isfinite(r);
    if (whole) {
        G->bx0 = G->by0 = 1;
        G->bw = (int)nx;
        G->bh = (int)ny;
    } else {
        double xa = INFINITY, xb = -INFINITY, ya = INFINITY, yb = -INFINITY;
        for (int k = 0; k < G->n; k++) {
            xa = fmin(xa, st[k].x - r);
            xb = fmax(xb, st[k].x + r);
            ya = fmin(ya, st[k].y - r);
            yb = fmax(yb, st[k].y + r);
        }
        long x0 = (long)ceil(xa), x1 = (long)floor(xb), y0 = (long)ceil(ya), y1 = (long)floor(yb);
        x0 = x0 < 1 ? 1 : x0;
        y0 = y0 < 1 ? 1 : y0;
        x1 = x1 > nx ? nx : x1;
        y1 = y1 > ny ? ny : y1;
        if (x1 < x0 || y1 < y0)
            return 1;
        G->bx0 = x0;
        G->by0 = y0;
        G->bw = (int)(x1 - x0 + 1);
        G->bh = (int)(y1 - y0 + 1);
    }
    size_t nb = (size_t)G->bw * G->bh;
    G->sel = calloc(nb, 1);
    if (!G->sel)
        return 2;
    G->npix = 0;
    for (int j = 0; j < G->bh; j++)
        for (int i = 0; i < G->bw; i++) {
            long X = G->bx0 + i, Y = G->by0 + j;
            uint8_t mk = f->mask ? f->mask[(size_t)(Y - 1) * nx + (size_t)(X - 1)] : 0;
            int inside = whole;
            for (int k = 0; k < G->n && !whole; k++) {
                double dx = X - st[k].x, dy = Y - st[k].y;
                if (dx * dx + dy * dy <= r * r) {
                    inside = 1;
                    if (mk & MP_MASK_BAD)
                        st[k].flags |= MP_FLAG_MASKED;
                    if (mk & MP_MASK_SATURATED)
                        st[k].flags |= MP_FLAG_SATURATED;
                }
            }
            if (inside && !mk) {
                G->sel[(size_t)j * G->bw + i] = 1;
                G->npix++;
            }
        }
    for (int k = 0; k < G->n; k++) {
        double rr = whole ? 0.0 : r;
        if (st[k].x - rr < 0.5 || st[k].y - rr < 0.5 || st[k].x + rr > nx + 0.5 || st[k].y + rr > ny + 0.5)
            st[k].flags |= MP_FLAG_EDGE;
        if (whole)
            flag_footprint(G, &st[k]);
    }
    G->xc = G->bx0 + 0.5 * (G->bw - 1);
    G->yc = G->by0 + 0.5 * (G->bh - 1);
    G->hx = G->bw > 2 ? 0.5 * (G->bw - 1) : 1.0;
    G->hy = G->bh > 2 ? 0.5 * (G->bh - 1) : 1.0;
    return pack_pixels(G);
}

static double start_sky(const group *G)
{
    double *v = malloc((G->npix ? G->npix : 1) * sizeof *v);
    if (!v)
        return 0.0;
    size_t n = G->npix;
    memcpy(v, G->dat, n * sizeof *v);
    qsort(v, n, sizeof *v, cmp_double);
    double s = n ? v[n / 2] : 0.0;
    free(v);
    return s;
}

static int alloc_stars(group *G)
{
    long x0, y0;
    int w, h;
    /* The box can grow by one pixel a side as a star moves within a pixel;
     * it is cut to the group's box. */
    mp_prf_box(G->m, 0.0, 0.0, &x0, &y0, &w, &h);
    w = w + 2 < G->bw ? w + 2 : G->bw;
    h = h + 2 < G->bh ? h + 2 : G->bh;
    G->boxcap = (size_t)w * h;
    G->cap = G->boxcap < G->npix ? G->boxcap : G->npix;
    G->cap = G->cap ? G->cap : 1;
    G->scr = malloc((3 * G->boxcap + 1) * sizeof *G->scr);
    G->cur = calloc((size_t)G->n, sizeof *G->cur);
    G->trial = calloc((size_t)G->n, sizeof *G->trial);
    if (!G->cur || !G->trial)
        return 1;
    for (int s = 0; s < 2; s++) {
        rstar *r = s ? G->trial : G->cur;
        for (int k = 0; k < G->n; k++) {
            r[k].prf = malloc(G->cap * sizeof(double));
            r[k].dx = malloc(G->cap * sizeof(double));
            r[k].dy = malloc(G->cap * sizeof(double));
            r[k].pp = malloc(((size_t)G->bh + 1) * sizeof(int));
            r[k].pn = malloc(((size_t)G->bh + 1) * sizeof(int));
            r[k].pb = malloc(((size_t)G->bh + 1) * sizeof(int));
            if (!r[k].prf || !r[k].dx || !r[k].dy || !r[k].pp || !r[k].pn || !r[k].pb)
                return 1;
        }
    }
    /* Room for the quadratic sky whatever the order: the order may rise. */
    size_t np = (size_t)G->npmax;
    G->p = calloc(np, sizeof *G->p);
    G->pt = calloc(np, sizeof *G->pt);
    G->stail = calloc((size_t)G->n * 27, sizeof *G->stail);
    G->fx = malloc((size_t)G->n * sizeof *G->fx);
    G->fy = malloc((size_t)G->n * sizeof *G->fy);
    G->cx0 = malloc((size_t)G->n * sizeof *G->cx0);
    G->cx1 = malloc((size_t)G->n * sizeof *G->cx1);
    G->cy0 = malloc((size_t)G->n * sizeof *G->cy0);
    G->cy1 = malloc((size_t)G->n * sizeof *G->cy1);
    G->A = malloc(np * np * sizeof *G->A);
    G->M = malloc(np * np * sizeof *G->M);
    G->g = malloc(np * sizeof *G->g);
    G->step = malloc(np * sizeof *G->step);
    return !G->scr || !G->stail || !G->fx || !G->fy || !G->cx0 || !G->cx1 || !G->cy0 || !G->cy1 || !G->p || !G->pt || !G->A || !G->M || !G->g || !G->step;
}

/* The data's range over the fitted pixels and the largest flux a star may
 * take: 1000 times all the light above the lowest pixel, over the smallest
 * fraction (1 %) of a PSF a fitted star keeps inside its window. */
static void data_range(group *G)
{
    double lo = INFINITY, hi = -INFINITY, sum = 0.0;
    for (size_t o = 0; G->dat && o < G->npix; o++) {
        double d = G->dat[o];
        lo = d < lo ? d : lo;
        hi = d > hi ? d : hi;
        sum += d;
    }
    if (!isfinite(lo)) {
        G->dlo = -INFINITY;
        G->dhi = G->emax = INFINITY;
        return;
    }
    G->dlo = lo;
    G->dhi = hi;
    double above = sum - lo * (double)G->npix;
    G->emax = 1e5 * (above > 1.0 ? above : 1.0);
}

/* First flux guess: data above the sky over the star's box, over the PRF. */
static double start_flux(const group *G, const rstar *r, double sky)
{
    double s = 0.0, q = 0.0;
    for (int t = 0; t < r->j1 - r->j0; t++)
        for (int i = 0; i < r->pn[t]; i++) {
            s += G->dat[r->pp[t] + i] - sky;
            q += r->prf[r->pb[t] + i];
        }
    return q > 0 && s > 0 ? s / q : 1.0;
}

static int all_finite(const double *v, int n)
{
    for (int i = 0; i < n; i++)
        if (!isfinite(v[i]))
            return 0;
    return 1;
}

/* The lowest sky the members were found on (find's BACKGROUND, an earlier
 * fit's SKY_PSF), the star light of a crowded group left out, so it errs
 * low; NaN when no member has one. */
static double known_sky(const mp_star *st, int n)
{
    double s = INFINITY;
    for (int k = 0; k < n; k++)
        if (isfinite(st[k].sky) && st[k].sky < s)
            s = st[k].sky;
    return isfinite(s) ? s : NAN;
}

/* The sky order to fit first: the one asked for, or constant under auto. */
static int first_order(const mp_fit_opts *o)
{
    if (o->sky_order == MP_SKY_AUTO)
        return 0;
    return o->sky_order < 0 ? 0 : (o->sky_order > MP_SKY_MAXORDER ? MP_SKY_MAXORDER : o->sky_order);
}

/* MP_SKY_AUTO, at a converged fit of order 0 or 1: the higher order the
 * data ask for in *to, or -1; nonzero when out of memory.  From constant,
 * the plane's two terms (χ²(2)) and the quadratic's five (χ²(5), a curved
 * sky the plane test cannot see) are tested, so a flat sky leaves
 * constant with probability at most 2·MP_SKY_ALPHA; from a plane, the
 * three quadratic terms (χ²(3)). */
static int higher_order(group *G, int order, double fitrad, int *to)
{
    sky_sums S;
    memset(&S, 0, sizeof S);
    *to = -1;
    window_sums(G, &S);
    if (ring_sums(G, fitrad, &S))
        return 1;
    int n0 = nsky_of(order);
    if (order == 0 && sky_score_pvalue(&S, n0, nsky_of(1)) < MP_SKY_ALPHA)
        *to = 1;
    else if (order <= 1 && sky_score_pvalue(&S, n0, nsky_of(2)) < MP_SKY_ALPHA)
        *to = 2;
    if (*to >= 0 && G->npix <= (size_t)(3 * G->n + nsky_of(*to)))
        *to = -1;
    return 0;
}

int mp_fit_group(const mp_frame *f, const mp_prf_model *m, const mp_fit_opts *o,
                 double sky0, mp_star *stars, int n, char *err)
{
    group G;
    memset(&G, 0, sizeof G);
    G.f = f;
    G.m = m;
    G.crop = isfinite(o->fitrad) ? o->crop : NULL;
    G.work.grid = o->grid;      /* every render of the group through G.work */
    G.crop_min = o->fitrad + 1.0;
    G.core_hw = G.crop_min;     /* NaN (whole frame): every pass exact */
    G.n = n;
    int order = first_order(o);
    G.nsky = o->fit_sky ? nsky_of(order) : 0;
    G.np = 3 * n + (G.nsky ? G.nsky : 1);   /* a fixed sky still has a slot */
    G.npmax = 3 * n + nsky_of(MP_SKY_MAXORDER);
    G.ron2 = f->rdnoise * f->rdnoise > 1e-2 ? f->rdnoise * f->rdnoise : 1e-2;
    int rc = 1;
    for (int k = 0; k < n; k++) {
        stars[k].flags = 0;
        stars[k].niter = 0;
        stars[k].sky_order = order;
    }
    int sp = select_pixels(&G, o, stars);
    data_range(&G);
    if (sp == 2 || alloc_stars(&G)) {
        snprintf(err, MP_ERRLEN, "fit: out of memory for a group of %d stars", n);
        goto done;
    }
    if (sp == 1 || G.npix <= (size_t)(3 * n + G.nsky)) {
        for (int k = 0; k < n; k++)
            stars[k].flags |= MP_FLAG_NOCONV | MP_FLAG_EDGE;
        rc = 0;
        goto finish_flagged;
    }
    double sky = isfinite(sky0) ? sky0 : start_sky(&G);
    /* S of the variance function, and the sky's lower bound: a group's own
     * median is neither (in a crowded group it sits well above the sky,
     * and a floor above the sky reweights every sky pixel). */
    G.sknown = known_sky(stars, n);
    G.vfloor = G.sknown > 0 ? G.sknown : 0.0;
    for (int k = 0; k < n; k++) {
        G.p[3 * k] = stars[k].flux;
        G.p[3 * k + 1] = stars[k].x;
        G.p[3 * k + 2] = stars[k].y;
    }
    G.p[3 * n] = sky;
    for (int a = 3 * n + 1; a < G.npmax; a++)
        G.p[a] = 0.0;
    if (render_all(&G, G.p, G.cur, RENDER_ALL))
        goto nomem;
    for (int k = 0; k < n; k++)
        if (!(isfinite(G.p[3 * k]) && G.p[3 * k] > 0))
            G.p[3 * k] = start_flux(&G, &G.cur[k], sky);

    int converged = 0, iter = 0;
    if (levmar(&G, o, &iter, &converged))
        goto nomem;
    /* The sky order from the data: raise it while the score test at the
     * converged lower-order fit says the extra terms are needed, and go on
     * from the current state (the new terms start at zero, so the model
     * does not change). */
    while (o->fit_sky && o->sky_order == MP_SKY_AUTO && converged && order < MP_SKY_MAXORDER) {
        int to;
        if (higher_order(&G, order, o->fitrad, &to))
            goto nomem;
        if (to < 0)
            break;
        /* The new terms start at zero (the buffers swap with the trial
         * state, whose slots past the old order were never written). */
        for (int a = 3 * n + G.nsky; a < 3 * n + nsky_of(to); a++)
            G.p[a] = 0.0;
        order = to;
        G.nsky = nsky_of(order);
        G.np = 3 * n + G.nsky;
        if (levmar(&G, o, &iter, &converged))
            goto nomem;
    }
    int np = G.np, npar = 3 * n + G.nsky;

    int cv = covariance(&G);
    if (cv == 2)
        goto nomem;
    double chi2f = chi2_with(&G, G.var);
    int dof = (int)G.npix - npar;
    for (int k = 0; k < n; k++) {
        mp_star *s = &stars[k];
        double out[6] = {G.p[3 * k + 1], G.p[3 * k + 2], G.p[3 * k],
                         sqrt(G.M[(size_t)(3 * k + 1) * np + 3 * k + 1]),
                         sqrt(G.M[(size_t)(3 * k + 2) * np + 3 * k + 2]),
                         sqrt(G.M[(size_t)(3 * k) * np + 3 * k])};
        double skyv = sky_at(&G, G.p, out[0], out[1]);
        double c[6], vs = 0.0;
        sky_basis(&G, out[0], out[1], c);
        for (int a = 0; a < G.nsky; a++)
            for (int b = 0; b < G.nsky; b++)
                vs += c[a] * c[b] * G.M[(size_t)(3 * n + a) * np + 3 * n + b];
        /* The performance model wants the whole PRF, not the fitted window. */
        if (!isfinite(out[0]) || !isfinite(out[1]))
            memset(&s->st, 0, sizeof s->st);
        else if (mp_prf_stats_at(G.m, out[0], out[1], &s->st, &G.work))
            goto nomem;
        double se, sx;
        double E = out[2] > 1.0 ? out[2] : 1.0;
        mp_perf_model(&s->st, E, skyv > 0 ? skyv : 0.0, f->rdnoise, (double)G.npix, &se, &sx);
        if (!converged)
            s->flags |= MP_FLAG_NOCONV;
        if (cv)
            s->flags |= MP_FLAG_MERGED;
        if (!all_finite(out, 6) || !isfinite(skyv) || !isfinite(vs) || !isfinite(chi2f)) {
            s->flags |= MP_FLAG_NOCONV;
            continue;             /* keep the start values */
        }
        s->x = out[0];
        s->y = out[1];
        s->flux = out[2];
        s->ex = out[3];
        s->ey = out[4];
        s->eflux = out[5];
        s->sky = skyv;
        s->esky = sqrt(vs > 0 ? vs : 0.0);
        s->chi2 = dof > 0 ? chi2f / dof : 0.0;
        s->dof = dof;
        s->niter = iter;
        s->sky_order = order;
        s->fluxerr_model = isfinite(se) ? se : 0.0;
        s->poserr_model = isfinite(sx) ? sx : 0.0;
    }
    rc = 0;
    goto done;

nomem:
    snprintf(err, MP_ERRLEN, "fit: out of memory for a group of %d stars", n);
    rc = 1;
    goto done;
finish_flagged:
    for (int k = 0; k < n; k++) {
        mp_star *s = &stars[k];
        s->ex = s->ey = s->eflux = s->esky = 0.0;
        s->chi2 = 0.0;
        s->dof = 0;
        if (!isfinite(s->flux))
            s->flux = 0.0;
        if (!isfinite(s->sky))
            s->sky = 0.0;
    }
done:
    if (o->work)
        *o->work += G.work.ops;     /* the exact renders' work (economy's plan) */
    group_free(&G);
    return rc;
}
