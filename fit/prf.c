/* prf.c — the PRF of a star on detector pixels: PSF shifted (damped sinc at
 * the table's own sampling), weighted by the DRF, block-summed (paper §3,
 * design.md §5); or the pixel-integrated analytic Gaussian. */
#include <math.h>
#include <stdlib.h>
#include <string.h>
#include "fit/fit.h"

void mp_prf_work_free(mp_prf_work *w)
{
    if (!w)
        return;
    free(w->a);
    free(w->b);
    free(w->c);
    free(w->d);
    memset(w, 0, sizeof *w);
}

static int work_reserve(mp_prf_work *w, size_t n)
{
    if (w->n >= n)
        return 0;
    mp_prf_work_free(w);
    w->a = malloc(n * sizeof *w->a);
    w->b = malloc(n * sizeof *w->b);
    w->c = malloc(n * sizeof *w->c);
    w->d = malloc(n * sizeof *w->d);
    if (!w->a || !w->b || !w->c || !w->d) {
        mp_prf_work_free(w);
        return 1;
    }
    w->n = n;
    return 0;
}

/* Half-size of the analytic Gaussian's box [px]: light beyond it < 1e-12. */
static int gauss_halfbox(double sigma)
{
    return (int)ceil(7.5 * sigma + 1.0);
}

/* Geometry of a table star along one axis.  Global fine index g (0-based
 * over the detector, g = os·(p−1) + s for pixel p, subpixel s) has its centre
 * at ½ + (g+½)/os.  The table element at that point is g + c0 with
 * c0 = c + ½ + os(½ − x), c the central element; split c0 = n0 + δ with
 * |δ| ≤ ½ so that, with S the table shifted by δ, fine g holds S[g + n0]. */
typedef struct { long n0; double delta; long p0; int w; } axis_geom;

static axis_geom table_axis(int n, int os, double x)
{
    axis_geom a;
    double c0 = (n - 1) / 2 + 0.5 + os * (0.5 - x);
    a.n0 = lround(c0);
    a.delta = c0 - (double)a.n0;
    /* Table index m ↔ g = m − n0; pixel p = floor(g/os) + 1. */
    long g0 = -a.n0, g1 = (long)(n - 1) - a.n0;
    long p0 = (long)floor((double)g0 / os) + 1;
    long p1 = (long)floor((double)g1 / os) + 1;
    a.p0 = p0;
    a.w = (int)(p1 - p0 + 1);
    return a;
}

void mp_prf_box(const mp_prf_model *m, double x, double y,
                long *x0, long *y0, int *w, int *h)
{
    const mp_psf *p = m->psf;
    if (p->kind == MP_PSF_GAUSS) {
        int r = gauss_halfbox(p->sigma);
        *x0 = lround(x) - r;
        *y0 = lround(y) - r;
        *w = *h = 2 * r + 1;
        return;
    }
    axis_geom ax = table_axis(p->nx, p->os, x - p->offset), ay = table_axis(p->ny, p->os, y - p->offset);
    *x0 = ax.p0;
    *y0 = ay.p0;
    *w = ax.w;
    *h = ay.w;
}

/* QE of fine subpixel (sx, sy) of a pixel, or the uniform volume. */
static double drf_weight(const mp_drf *d, int os, int sx, int sy)
{
    if (!d)
        return 1.0;
    if (d->k == 0)
        return d->volume;
    return d->qe[(sy * d->k / os) * d->k + (sx * d->k / os)];
}

/* ∫ of the unit Gaussian over [a, b] (in px, centred on 0) and the value of
 * the density at a and b (for the derivative). */
static double cell(double a, double b, double sigma)
{
    double u = a / (sigma * M_SQRT2), v = b / (sigma * M_SQRT2);
    if (u > 0)
        return 0.5 * (erfc(u) - erfc(v));
    if (v < 0)
        return 0.5 * (erfc(-v) - erfc(-u));
    return 0.5 * (2.0 - erfc(v) - erfc(-u));
}

static double dens(double a, double sigma)
{
    double z = a / sigma;
    return exp(-0.5 * z * z) / (sigma * sqrt(2.0 * M_PI));
}

static int render_gauss(const mp_prf_model *m, double x, double y,
                        double *prf, double *ddx, double *ddy, mp_prf_work *w)
{
    const mp_psf *p = m->psf;
    long x0, y0;
    int bw, bh;
    mp_prf_box(m, x, y, &x0, &y0, &bw, &bh);
    /* With a DRF the pixel is cut into k×k cells, each integrated exactly. */
    int k = (m->drf && m->drf->k) ? m->drf->k : 1;
    size_t nx = (size_t)bw * k, ny = (size_t)bh * k;
    if (work_reserve(w, 2 * (nx + ny)))
        return 1;
    double *ex = w->a, *dex = w->a + nx, *ey = w->b, *dey = w->b + ny;
    for (int pass = 0; pass < 2; pass++) {
        double c = pass ? y : x;
        long o = pass ? y0 : x0;
        size_t n = pass ? ny : nx;
        double *e = pass ? ey : ex, *de = pass ? dey : dex;
        for (size_t i = 0; i < n; i++) {
            long pix = o + (long)(i / k);
            int s = (int)(i % k);
            double lo = pix - 0.5 + (double)s / k - c, hi = lo + 1.0 / k;
            e[i] = cell(lo, hi, p->sigma);
            /* d/dc of ∫_{lo}^{hi} φ = φ(lo) − φ(hi) (both bounds move by −dc). */
            de[i] = dens(lo, p->sigma) - dens(hi, p->sigma);
        }
    }
    double vol = (m->drf && m->drf->k == 0) ? m->drf->volume : 1.0;
    for (int j = 0; j < bh; j++)
        for (int i = 0; i < bw; i++) {
            double v = 0, gx = 0, gy = 0;
            for (int sy = 0; sy < k; sy++)
                for (int sx = 0; sx < k; sx++) {
                    double q = (m->drf && m->drf->k) ? m->drf->qe[sy * k + sx] : vol;
                    size_t ix = (size_t)i * k + sx, iy = (size_t)j * k + sy;
                    v += q * ex[ix] * ey[iy];
                    gx += q * dex[ix] * ey[iy];
                    gy += q * ex[ix] * dey[iy];
                }
            size_t o = (size_t)j * bw + i;
            prf[o] = v;
            if (ddx)
                ddx[o] = gx;
            if (ddy)
                ddy[o] = gy;
        }
    return 0;
}

static int render_table(const mp_prf_model *m, double x, double y,
                        double *prf, double *ddx, double *ddy, mp_prf_work *w)
{
    const mp_psf *p = m->psf;
    int os = p->os, nx = p->nx, ny = p->ny;
    size_t nt = (size_t)nx * ny;
    if (work_reserve(w, nt))
        return 1;
    /* The central element sits at the star minus the table's offset. */
    axis_geom ax = table_axis(nx, os, x - p->offset), ay = table_axis(ny, os, y - p->offset);
    int hw = m->sinc_hw > 0 ? m->sinc_hw : 0;
    double *S = w->a;
    mp_shift_table(p->t, nx, ny, ax.delta, ay.delta, hw, S, w->b);
    int want_d = ddx || ddy;
    if (want_d) {
        mp_five_point(S, nx, ny, 0, w->c);
        mp_five_point(S, nx, ny, 1, w->d);
    }
    size_t nb = (size_t)ax.w * ay.w;
    memset(prf, 0, nb * sizeof *prf);
    if (ddx)
        memset(ddx, 0, nb * sizeof *ddx);
    if (ddy)
        memset(ddy, 0, nb * sizeof *ddy);
    /* Block-sum: table element (mi, mj) lies in fine (gi, gj) = (mi − n0x, mj − n0y),
     * i.e. pixel offset floor(g/os) − (p0 − 1), subpixel g mod os. */
    long gx0 = -ax.n0, gy0 = -ay.n0;
    long pbx = (ax.p0 - 1) * (long)os, pby = (ay.p0 - 1) * (long)os;
    for (int mj = 0; mj < ny; mj++) {
        long fj = gy0 + mj - pby;          /* fine index within the box, ≥ 0 */
        int bj = (int)(fj / os), sy = (int)(fj % os);
        const double *Sr = S + (size_t)mj * nx;
        double *pr = prf + (size_t)bj * ax.w;
        for (int mi = 0; mi < nx; mi++) {
            long fi = gx0 + mi - pbx;
            int bi = (int)(fi / os), sx = (int)(fi % os);
            double q = drf_weight(m->drf, os, sx, sy);
            pr[bi] += q * Sr[mi];
            if (want_d) {
                size_t t = (size_t)mj * nx + mi;
                /* The table index moves by −os per +1 px of the star. */
                if (ddx)
                    ddx[(size_t)bj * ax.w + bi] -= q * os * w->c[t];
                if (ddy)
                    ddy[(size_t)bj * ax.w + bi] -= q * os * w->d[t];
            }
        }
    }
    return 0;
}

int mp_prf_render(const mp_prf_model *m, double x, double y,
                  double *prf, double *dprf_dx, double *dprf_dy, mp_prf_work *w)
{
    if (m->psf->kind == MP_PSF_GAUSS)
        return render_gauss(m, x, y, prf, dprf_dx, dprf_dy, w);
    return render_table(m, x, y, prf, dprf_dx, dprf_dy, w);
}
