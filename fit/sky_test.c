/* sky_test.c — the sky model's order from the data (MP_SKY_AUTO): the
 * score test of higher sky terms at a converged fit, on the fitted pixels
 * the stars leave dark and a ring around the group. */

#include <math.h>
#include <stddef.h>
#include <stdlib.h>
#include <string.h>
#include "fit/lm_group.h"
#include "fit/spd.h"

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
    if (mp_spd_solve(M, np, y) != 0)
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

/* The octant 0..7 of (dx, dy), counter-clockwise from +x (no atan2: the
 * ring's pixels are many and the fit of a lone star is short). */
static int octant(double dx, double dy)
{
    int near_x = fabs(dx) >= fabs(dy);
    if (dy >= 0)
        return dx >= 0 ? (near_x ? 0 : 1) : (near_x ? 3 : 2);
    return dx >= 0 ? (near_x ? 7 : 6) : (near_x ? 4 : 5);
}

/* The ring's box [x0, x1) × [y0, y1) (the window grown by R − fitrad + 1,
 * clipped to the frame), its scratch, and the cells' sums. */
typedef struct {
    double R, rmid;
    long x0, y0, x1, y1, w, h;
    double *light, *buf, *res;          /* w × h each */
    int *cell;
    double sumc[RING_CELLS][6], sumv[RING_CELLS];
    size_t cnt[RING_CELLS];
} ring;

/* The group's own stars over the ring into r->light, from their fitted
 * values, with a 5-tap kernel: only light below a pixel's σ is used,
 * where a few per cent of it is far below the noise of a cell's median,
 * and the ring is several times the window, so the full kernel would cost
 * more than the fit (bench isolated scene: +45 % CPU per star).  Nonzero
 * when out of memory. */
static int ring_light(group *G, ring *r)
{
    mp_prf_model mr = *G->m;
    mr.sinc_hw = mr.sinc_hw < 2 ? mr.sinc_hw : 2;
    for (int k = 0; k < G->n; k++) {
        long sx, sy, kx0, ky0, kx1, ky1;    /* the ring's part within R of star k */
        int sw, sh;
        double xk = G->p[3 * k + 1], yk = G->p[3 * k + 2];
        kx0 = (long)floor(xk - r->R);
        ky0 = (long)floor(yk - r->R);
        kx1 = (long)ceil(xk + r->R) + 1;
        ky1 = (long)ceil(yk + r->R) + 1;
        kx0 = kx0 < r->x0 ? r->x0 : kx0;
        ky0 = ky0 < r->y0 ? r->y0 : ky0;
        kx1 = kx1 > r->x1 ? r->x1 : kx1;
        ky1 = ky1 > r->y1 ? r->y1 : ky1;
        if (kx1 <= kx0 || ky1 <= ky0)
            continue;
        if (mp_prf_render_window(&mr, xk, yk, kx0, ky0, kx1 - kx0, ky1 - ky0, &sx, &sy, &sw, &sh,
                                 r->buf, NULL, NULL, &G->work))
            return 1;
        for (int j = 0; j < sh; j++)
            for (int i = 0; i < sw; i++)
                r->light[(sy - r->y0 + j) * r->w + (sx - r->x0 + i)] +=
                    G->p[3 * k] * r->buf[(size_t)j * sw + i];
    }
    return 0;
}

/* Each pixel of the ring's box its cell (−1: a fitted pixel, masked,
 * beyond R of every star, or where the stars' light is above its σ) and
 * its residual; the cells' basis and variance sums. */
static void ring_cells(group *G, ring *r)
{
    long nx = G->f->im.nx;
    const uint8_t *mask = G->f->mask;
    for (long Y = r->y0; Y < r->y1; Y++)
        for (long X = r->x0; X < r->x1; X++) {
            size_t q = (size_t)((Y - r->y0) * r->w + (X - r->x0));
            long i = X - G->bx0, j = Y - G->by0;
            r->cell[q] = -1;
            if (i >= 0 && i < G->bw && j >= 0 && j < G->bh && G->sel[(size_t)j * G->bw + i])
                continue;                       /* a fitted pixel: window_sums */
            if (mask && mask[(size_t)(Y - 1) * nx + (size_t)(X - 1)])
                continue;
            double d2 = INFINITY;
            for (int k = 0; k < G->n; k++) {
                double dx = X - G->p[3 * k + 1], dy = Y - G->p[3 * k + 2];
                d2 = fmin(d2, dx * dx + dy * dy);
            }
            double sky = sky_at(G, G->p, (double)X, (double)Y), star = r->light[q];
            double v = (sky + star > G->vfloor ? sky + star : G->vfloor) + ron2_at(G, X, Y);
            if (d2 > r->R * r->R || star * star > v)
                continue;
            int cl = octant((double)X - G->xc, (double)Y - G->yc) +
                     (d2 > r->rmid * r->rmid ? RING_SECTORS : 0);
            double c[6];
            sky_basis(G, (double)X, (double)Y, c);
            for (int a = 0; a < 6; a++)
                r->sumc[cl][a] += c[a];
            r->sumv[cl] += v;
            r->cnt[cl]++;
            r->cell[q] = cl;
            r->res[q] = pixel(G, X, Y) - sky - star;
        }
}

/* Each cell's median residual into S, at the mean of its basis, with
 * variance π/2 times its mean V over its count. */
static void ring_terms(const ring *r, sky_sums *S)
{
    size_t nb = (size_t)(r->w * r->h);
    for (int cl = 0; cl < RING_CELLS; cl++) {
        if (r->cnt[cl] < RING_MIN)
            continue;
        size_t n = 0;
        for (size_t q = 0; q < nb; q++)
            if (r->cell[q] == cl)
                r->buf[n++] = r->res[q];
        double med = mp_median_select(r->buf, n), c[6];     /* a sort's median, by selection */
        for (int a = 0; a < 6; a++)
            c[a] = r->sumc[cl][a] / (double)n;
        add_sky_term(S, c, med, 0.5 * M_PI * r->sumv[cl] / ((double)n * (double)n));
    }
}

/* The ring's cells (see above) into S.  Nonzero: out of memory. */
static int ring_sums(group *G, double fitrad, sky_sums *S)
{
    ring r;
    memset(&r, 0, sizeof r);
    r.R = MP_SKY_TEST_RADIUS * fitrad;
    r.rmid = 0.5 * (fitrad + r.R);
    if (!isfinite(r.R) || !(r.R > fitrad))
        return 0;
    long nx = G->f->im.nx, ny = G->f->im.ny, pad = (long)ceil(r.R - fitrad) + 1;
    r.x0 = G->bx0 - pad;
    r.y0 = G->by0 - pad;
    r.x1 = G->bx0 + G->bw + pad;
    r.y1 = G->by0 + G->bh + pad;
    r.x0 = r.x0 < 1 ? 1 : r.x0;
    r.y0 = r.y0 < 1 ? 1 : r.y0;
    r.x1 = r.x1 > nx + 1 ? nx + 1 : r.x1;
    r.y1 = r.y1 > ny + 1 ? ny + 1 : r.y1;
    r.w = r.x1 - r.x0;
    r.h = r.y1 - r.y0;
    if (r.w <= 0 || r.h <= 0)
        return 0;
    size_t nb = (size_t)(r.w * r.h);
    r.light = calloc(nb, sizeof *r.light);
    r.buf = malloc(nb * sizeof *r.buf);
    r.res = malloc(nb * sizeof *r.res);
    r.cell = malloc(nb * sizeof *r.cell);
    int rc = !r.light || !r.buf || !r.res || !r.cell || ring_light(G, &r);
    if (!rc) {
        ring_cells(G, &r);
        ring_terms(&r, S);
    }
    free(r.light);
    free(r.buf);
    free(r.res);
    free(r.cell);
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

/* MP_SKY_AUTO, at a converged fit of order 0 or 1: the higher order the
 * data ask for in *to, or -1; nonzero when out of memory.  From constant,
 * the plane's two terms (χ²(2)) and the quadratic's five (χ²(5), a curved
 * sky the plane test cannot see) are tested, so a flat sky leaves
 * constant with probability at most 2·MP_SKY_ALPHA; from a plane, the
 * three quadratic terms (χ²(3)). */
int lm_higher_order(group *G, int order, double fitrad, int *to)
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
