/* prf.c — the PRF of a star on detector pixels: PSF shifted (damped sinc at
 * the table's own sampling), weighted by the DRF, block-summed (paper §3,
 * design.md §5); or the pixel-integrated analytic Gaussian. */
#include <math.h>
#include <stdlib.h>
#include <string.h>
#include "fit/prf_axis.h"

/* The axis operators of render_table's separable path. */
struct mp_prf_axes_s {
    mp_prf_axis x, y;
};

void mp_prf_work_free(mp_prf_work *w)
{
    if (!w)
        return;
    if (w->axes) {
        mp_prf_axis_free(&w->axes->x);
        mp_prf_axis_free(&w->axes->y);
        free(w->axes);
    }
    free(w->a);
    free(w->b);
    free(w->c);
    free(w->d);
    free(w->e);
    free(w->f);
    memset(w, 0, sizeof *w);
}

/* w->f grown to n floats (kept, as work_reserve's); nonzero when out of
 * memory. */
static int single_reserve(mp_prf_work *w, size_t n)
{
    if (w->nf >= n)
        return 0;
    float *f = realloc(w->f, n * sizeof *f);
    if (!f)
        return 1;
    w->f = f;
    w->nf = n;
    return 0;
}

static int work_reserve(mp_prf_work *w, size_t n)
{
    if (w->n >= n)
        return 0;
    long nshift = w->nshift, nskip = w->nskip;    /* the counts outlive a regrowth */
    double ops = w->ops;
    free(w->a);
    free(w->b);
    free(w->c);
    free(w->d);
    w->a = w->b = w->c = w->d = NULL;
    w->n = 0;
    w->nshift = nshift;
    w->nskip = nskip;
    w->ops = ops;
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

/* The table a star at (x, y) is shifted from: the model's, or, with a
 * field, the field evaluated at the star on the elements the shift reads
 * (rows [j0, j1), columns [i0, i1)); NULL when out of memory or when the
 * field's geometry is not the table's. */
static const double *star_table(const mp_prf_model *m, double x, double y, long i0, long i1,
                                long j0, long j1, mp_prf_work *w)
{
    const mp_psf *p = m->psf;
    const mp_psf_field *f = p->field;
    if (!f)
        return p->t;
    if (f->nx != p->nx || f->ny != p->ny || f->os != p->os)
        return NULL;
    size_t n = (size_t)p->nx * p->ny;
    if (w->ne < n) {
        free(w->e);
        w->ne = 0;
        if (!(w->e = malloc(n * sizeof *w->e)))
            return NULL;
        w->ne = n;
    }
    mp_psf_field_eval_rect(f, x, y, i0, i1, j0, j1, w->e);
    return w->e;
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

static axis_geom table_axis_ref(int n, int os, double x, double xr)
{
    axis_geom a;
    mp_prf_axis_geom(n, os, x, xr, &a.n0, &a.delta, &a.p0, &a.w);
    return a;
}

static axis_geom table_axis(int n, int os, double x)
{
    return table_axis_ref(n, os, x, x);
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

/* A detector box [x0, x0+w) × [y0, y0+h), 1-based. */
typedef struct { long x0, y0, w, h; } box;

/* The box of mp_prf_box for a star at (x, y). */
static box box_of(const mp_prf_model *m, double x, double y)
{
    box b;
    int bw, bh;
    mp_prf_box(m, x, y, &b.x0, &b.y0, &bw, &bh);
    b.w = bw;
    b.h = bh;
    return b;
}

/* The damped sinc's half-width a table render uses (0: no shift; at most
 * 64 taps a side). */
static int sinc_halfwidth(const mp_prf_model *m)
{
    return m->sinc_hw > 0 ? (m->sinc_hw < 64 ? m->sinc_hw : 64) : 0;
}

/* Whether render_table shifts the table element by element (shift_rows,
 * shift_cols) for box bx: the axis operators cost more, or do not apply
 * (a DRF that varies within the pixel is not a product of two axes). */
static int shifts_elements(const mp_prf_model *m, box bx, int deriv)
{
    const mp_psf *p = m->psf;
    int hw = sinc_halfwidth(m);
    return !(mp_prf_axes_apply(m) &&
             mp_prf_axis_ops(p->nx, p->ny, p->os, hw, deriv, (double)bx.w, (double)bx.h, 1) <
                 mp_prf_axis_ops(p->nx, p->ny, p->os, hw, deriv, (double)bx.w, (double)bx.h, 0));
}

/* The part of box a inside box b (possibly empty). */
static box box_and(box a, const box *b)
{
    if (!b)
        return a;
    long x1 = a.x0 + a.w, y1 = a.y0 + a.h;
    long bx1 = b->x0 + b->w, by1 = b->y0 + b->h;
    box r = {a.x0 > b->x0 ? a.x0 : b->x0, a.y0 > b->y0 ? a.y0 : b->y0, 0, 0};
    r.w = (x1 < bx1 ? x1 : bx1) - r.x0;
    r.h = (y1 < by1 ? y1 : by1) - r.y0;
    if (r.w < 0 || r.h < 0)
        r.w = r.h = 0;
    return r;
}

static int render_gauss(const mp_prf_model *m, double x, double y, box bx,
                        double *prf, double *ddx, double *ddy, mp_prf_work *w)
{
    const mp_psf *p = m->psf;
    /* With a DRF the pixel is cut into k×k cells, each integrated exactly. */
    int k = (m->drf && m->drf->k) ? m->drf->k : 1;
    size_t nx = (size_t)bx.w * k, ny = (size_t)bx.h * k;
    if (work_reserve(w, 2 * (nx + ny) + 1))
        return 1;
    double *ex = w->a, *dex = w->a + nx, *ey = w->b, *dey = w->b + ny;
    for (int pass = 0; pass < 2; pass++) {
        double c = pass ? y : x;
        long o = pass ? bx.y0 : bx.x0;
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
    for (long j = 0; j < bx.h; j++)
        for (long i = 0; i < bx.w; i++) {
            double v = 0, gx = 0, gy = 0;
            for (int sy = 0; sy < k; sy++)
                for (int sx = 0; sx < k; sx++) {
                    double q = (m->drf && m->drf->k) ? m->drf->qe[sy * k + sx] : vol;
                    size_t ix = (size_t)i * k + sx, iy = (size_t)j * k + sy;
                    v += q * ex[ix] * ey[iy];
                    gx += q * dex[ix] * ey[iy];
                    gy += q * ex[ix] * dey[iy];
                }
            size_t o = (size_t)j * bx.w + i;
            prf[o] = v;
            if (ddx)
                ddx[o] = gx;
            if (ddy)
                ddy[o] = gy;
        }
    return 0;
}

/* Damped-sinc weights for taps −hw..hw (paper eq. dampedsinc). */
static void weights(double shift, int hw, double *wt)
{
    for (int k = -hw; k <= hw; k++)
        wt[k + hw] = mp_damped_sinc((double)k - shift);
}

/* render_table by the axis operators (fit/prf_axis.c): the x operator on
 * the table rows the y operator reads (A = T·Xᵀ, and T·X'ᵀ for ∂/∂x), then
 * the y operator on A's columns (Y·A, Y·(T·X'ᵀ), Y'·A).  The same values up
 * to the order of the sums; a DRF uniform over the pixel is a scale. */
static int render_sep(const mp_prf_model *m, double x, double y, double xr, double yr, box bx,
                      int hw, double *prf, double *ddx, double *ddy, mp_prf_work *w)
{
    const mp_psf *p = m->psf;
    int nx = p->nx, deriv = ddx || ddy;
    if (!w->axes && !(w->axes = calloc(1, sizeof *w->axes)))
        return 1;
    mp_prf_axis *ax = &w->axes->x, *ay = &w->axes->y;
    if (mp_prf_axis_refill(nx, p->os, p->offset, x, xr, bx.x0, bx.w, hw, ddx != NULL, ax) ||
        mp_prf_axis_refill(p->ny, p->os, p->offset, y, yr, bx.y0, bx.h, hw, ddy != NULL, ay))
        return 1;
    if (ax->w == 0 || ay->w == 0)
        return 0;
    /* The rows Y reads and the columns X reads (lo and lo + len never
     * decrease along an axis). */
    long j0 = ay->lo[0], j1 = ay->lo[ay->w - 1] + ay->len[ay->w - 1];
    long i0 = ax->lo[0], i1 = ax->lo[ax->w - 1] + ax->len[ax->w - 1];
    if (j1 <= j0 || i1 <= i0)
        return 0;
    size_t na = (size_t)(j1 - j0) * ax->w;
    if (work_reserve(w, na > (size_t)nx * p->ny ? na : (size_t)nx * p->ny) ||
        (w->single && single_reserve(w, 2 * na + MP_PRF_AXIS_TF(nx))))
        return 1;
    const double *T = star_table(m, x, y, i0, i1, j0, j1, w);
    if (!T)
        return 1;
    w->ops += mp_prf_axis_ops(nx, p->ny, p->os, hw, deriv, (double)ax->w, (double)ay->w, 1);
    double scale = drf_weight(m->drf, p->os, 0, 0);
    long oy = ay->p0 - bx.y0, ox = ax->p0 - bx.x0;
    w->nskip += (ax->bw == p->os + 4) + (ay->bw == p->os + 4);   /* shifts on the grid */
    if (w->single) {
        float *A = w->f, *Ad = A + na;
        mp_prf_axis_rows_single(T, nx, j0, j1, ax, A, ddx ? Ad : NULL, Ad + na);
        mp_prf_axis_cols_single(ay, 0, A, j0, ax->w, scale, prf, oy, ox, bx.w);
        if (ddx)
            mp_prf_axis_cols_single(ay, 0, Ad, j0, ax->w, scale, ddx, oy, ox, bx.w);
        if (ddy)
            mp_prf_axis_cols_single(ay, 1, A, j0, ax->w, scale, ddy, oy, ox, bx.w);
        return 0;
    }
    double *A = w->c, *Ad = w->d;
    mp_prf_axis_rows(T, nx, j0, j1, ax, A, ddx ? Ad : NULL);
    mp_prf_axis_cols(ay, 0, A, j0, ax->w, scale, prf, oy, ox, bx.w);
    if (ddx)
        mp_prf_axis_cols(ay, 0, Ad, j0, ax->w, scale, ddx, oy, ox, bx.w);
    if (ddy)
        mp_prf_axis_cols(ay, 1, A, j0, ax->w, scale, ddy, oy, ox, bx.w);
    return 0;
}

/* The element ranges of one render of the table (nx × ny, stride nx):
 * [mi0, mi1) × [mj0, mj1) land in the box; [si0, si1) × [sj0, sj1) are
 * shifted (two more a side for the five-point derivative); the x-pass
 * reads rows [tj0, tj1) (hw more a side, for the y-pass). */
typedef struct { long mi0, mi1, mj0, mj1, si0, si1, sj0, sj1, tj0, tj1; } table_span;

/* The x-pass of the damped-sinc shift by delta, T into tmp over rows
 * [tj0, tj1) and columns [si0, si1) (a copy for a shift on the grid,
 * where the sinc is the identity: mp_shift_on_grid).  Tap by tap over the
 * row, so the inner loop runs over contiguous elements; each element sums
 * its taps in the order k = −hw..hw, so the values are those of a
 * per-element sum, bit for bit.  gcc 12 at -O2 left these loops scalar
 * until told (omp simd: no element depends on another, and T and tmp are
 * distinct buffers). */
static void shift_rows(const double *T, double *tmp, long nx, const table_span *r, int hw,
                       double delta)
{
    if (mp_shift_on_grid(delta) || hw == 0) {
        for (long j = r->tj0; j < r->tj1; j++)
            memcpy(tmp + (size_t)j * nx + r->si0, T + (size_t)j * nx + r->si0,
                   (size_t)(r->si1 - r->si0) * sizeof *tmp);
        return;
    }
    double wt[2 * 64 + 1];
    weights(delta, hw, wt);
    for (long j = r->tj0; j < r->tj1; j++) {
        const double *src = T + (size_t)j * nx;
        double *dst = tmp + (size_t)j * nx;
        for (long i = r->si0; i < r->si1; i++)
            dst[i] = 0.0;
        for (long k = -hw; k <= hw; k++) {
            long ia = r->si0 > -k ? r->si0 : -k, ib = r->si1 < nx - k ? r->si1 : nx - k;
            double c = wt[k + hw];
#pragma omp simd
            for (long i = ia; i < ib; i++)
                dst[i] += src[i + k] * c;
        }
    }
}

/* The y-pass, tmp into S over rows [sj0, sj1), as shift_rows. */
static void shift_cols(const double *tmp, double *S, long nx, long ny, const table_span *r,
                       int hw, double delta)
{
    if (mp_shift_on_grid(delta) || hw == 0) {
        for (long j = r->sj0; j < r->sj1; j++)
            memcpy(S + (size_t)j * nx + r->si0, tmp + (size_t)j * nx + r->si0,
                   (size_t)(r->si1 - r->si0) * sizeof *S);
        return;
    }
    double wt[2 * 64 + 1];
    weights(delta, hw, wt);
    for (long j = r->sj0; j < r->sj1; j++) {
        long k0 = j - hw < 0 ? -j : -hw, k1 = j + hw > ny - 1 ? ny - 1 - j : hw;
        double *dst = S + (size_t)j * nx;
        for (long i = r->si0; i < r->si1; i++)
            dst[i] = 0.0;
        for (long k = k0; k <= k1; k++) {
            const double *src = tmp + (size_t)(j + k) * nx;
            double c = wt[k + hw];
#pragma omp simd
            for (long i = r->si0; i < r->si1; i++)
                dst[i] += src[i] * c;
        }
    }
}

/* The shifted table S block-summed into the box's pixels through the DRF,
 * and the five-point derivatives (paper §3.2) on it, zero beyond its
 * edge.  The table index moves by −os per +1 px of the star, hence the
 * factor −os. */
static void block_sum(const mp_prf_model *m, const double *S, const table_span *r, long n0x,
                      long n0y, box bx, double *prf, double *ddx, double *ddy)
{
    long os = m->psf->os, nx = m->psf->nx, ny = m->psf->ny;
    for (long mj = r->mj0; mj < r->mj1; mj++) {
        long fj = mj - n0y - (bx.y0 - 1) * os;     /* fine row within the box */
        long bj = fj / os;
        int sy = (int)(fj % os);
        const double *Sr = S + (size_t)mj * nx;
        for (long mi = r->mi0; mi < r->mi1; mi++) {
            long fi = mi - n0x - (bx.x0 - 1) * os;
            long bi = fi / os;
            int sx = (int)(fi % os);
            double q = drf_weight(m->drf, (int)os, sx, sy);
            size_t o = (size_t)bj * bx.w + (size_t)bi;
            prf[o] += q * Sr[mi];
            if (ddx) {
                double f2 = mi >= 2 ? Sr[mi - 2] : 0.0, f1 = mi >= 1 ? Sr[mi - 1] : 0.0;
                double g1 = mi + 1 < nx ? Sr[mi + 1] : 0.0, g2 = mi + 2 < nx ? Sr[mi + 2] : 0.0;
                ddx[o] -= q * os * (f2 - 8.0 * f1 + 8.0 * g1 - g2) / 12.0;
            }
            if (ddy) {
                double f2 = mj >= 2 ? S[(size_t)(mj - 2) * nx + mi] : 0.0;
                double f1 = mj >= 1 ? S[(size_t)(mj - 1) * nx + mi] : 0.0;
                double g1 = mj + 1 < ny ? S[(size_t)(mj + 1) * nx + mi] : 0.0;
                double g2 = mj + 2 < ny ? S[(size_t)(mj + 2) * nx + mi] : 0.0;
                ddy[o] -= q * os * (f2 - 8.0 * f1 + 8.0 * g1 - g2) / 12.0;
            }
        }
    }
}

/* The element ranges a render of box bx reads (table_span); 0 when no
 * element lands in the box.  Table elements that land in the box: fine
 * g = os(p − 1) + s ↔ m = g + n0; only they are block-summed. */
static int span_of(const mp_psf *p, box bx, long n0x, long n0y, int hw, table_span *r)
{
    long os = p->os, nx = p->nx, ny = p->ny;
    r->mi0 = (bx.x0 - 1) * os + n0x;
    r->mi1 = r->mi0 + bx.w * os;
    r->mj0 = (bx.y0 - 1) * os + n0y;
    r->mj1 = r->mj0 + bx.h * os;
    r->mi0 = r->mi0 < 0 ? 0 : r->mi0;
    r->mj0 = r->mj0 < 0 ? 0 : r->mj0;
    r->mi1 = r->mi1 > nx ? nx : r->mi1;
    r->mj1 = r->mj1 > ny ? ny : r->mj1;
    if (r->mi0 >= r->mi1 || r->mj0 >= r->mj1)
        return 0;
    r->si0 = r->mi0 - 2 < 0 ? 0 : r->mi0 - 2;
    r->si1 = r->mi1 + 2 > nx ? nx : r->mi1 + 2;
    r->sj0 = r->mj0 - 2 < 0 ? 0 : r->mj0 - 2;
    r->sj1 = r->mj1 + 2 > ny ? ny : r->mj1 + 2;
    r->tj0 = r->sj0 - hw < 0 ? 0 : r->sj0 - hw;
    r->tj1 = r->sj1 + hw > ny ? ny : r->sj1 + hw;
    return 1;
}

/* The table aligned as for a star at (xr, yr), shifted to (x, y): the
 * natural render has xr = x, yr = y (|delta| ≤ ½); prf_cache.c renders the
 * phases just past a branch's ends with its alignment (branch below). */
static int render_table(const mp_prf_model *m, double x, double y, double xr, double yr, box bx,
                        double *prf, double *ddx, double *ddy, mp_prf_work *w)
{
    const mp_psf *p = m->psf;
    int os = p->os, nx = p->nx, ny = p->ny;
    int hw = sinc_halfwidth(m);
    size_t nb = (size_t)bx.w * bx.h;
    memset(prf, 0, nb * sizeof *prf);
    if (ddx)
        memset(ddx, 0, nb * sizeof *ddx);
    if (ddy)
        memset(ddy, 0, nb * sizeof *ddy);
    if (nb == 0)
        return 0;
    /* The axis operators where they cost less than the shift of the
     * table's elements (OVERSAMP ≥ 2 on all but the smallest boxes). */
    if (!shifts_elements(m, bx, ddx || ddy)) {
        w->nshift += 2;
        return render_sep(m, x, y, xr, yr, bx, hw, prf, ddx, ddy, w);
    }
    if (work_reserve(w, (size_t)nx * ny))
        return 1;
    /* The central element sits at the star minus the table's offset. */
    axis_geom ax = table_axis_ref(nx, os, x - p->offset, xr - p->offset);
    axis_geom ay = table_axis_ref(ny, os, y - p->offset, yr - p->offset);
    table_span r;
    if (!span_of(p, bx, ax.n0, ay.n0, hw, &r))
        return 0;
    double *S = w->a, *tmp = w->b;          /* both laid out with stride nx */
    const double *T = star_table(m, x, y, r.si0 - hw < 0 ? 0 : r.si0 - hw,
                                 r.si1 + hw > nx ? nx : r.si1 + hw, r.tj0, r.tj1, w);
    if (!T)
        return 1;
    /* The work, for economy's plan (fit/econ_plan.c), and the shifts on
     * the grid skipped (counted for the report). */
    w->ops += (double)(r.si1 - r.si0) * (double)((r.tj1 - r.tj0) + (r.sj1 - r.sj0)) *
                  (2.0 * hw + 1.0) +
              (double)(r.mi1 - r.mi0) * (double)(r.mj1 - r.mj0) * (ddx || ddy ? 9.0 : 1.0);
    w->nshift += 2;
    w->nskip += (mp_shift_on_grid(ax.delta) || hw == 0) + (mp_shift_on_grid(ay.delta) || hw == 0);
    shift_rows(T, tmp, nx, &r, hw, ax.delta);
    shift_cols(tmp, S, nx, ny, &r, hw, ay.delta);
    block_sum(m, S, &r, ax.n0, ay.n0, bx, prf, ddx, ddy);
    return 0;
}

/* g += Yᵀ·RX: each table row R of g summed over the pixel rows q that
 * read it (lo and lo + len never decrease: a run of q), in q's order as
 * a loop over q then its rows adds them (the same bits), eight elements
 * at a time in registers: g's rows were read and written once per q. */
static void adjoint_cols(const mp_prf_axis *ay, const double *RX, int nx, long i0, long i1,
                         double *g)
{
    long R1 = ay->lo[ay->w - 1] + ay->len[ay->w - 1];
    int qa = 0, qb = 0;
    for (long R = ay->lo[0]; R < R1; R++) {
        while (qa < ay->w && ay->lo[qa] + ay->len[qa] <= R)
            qa++;
        while (qb < ay->w && ay->lo[qb] <= R)
            qb++;
        double *dst = g + (size_t)R * nx;
        long i = i0;
        for (; i + 8 <= i1; i += 8) {
            double s[8] = {0.0};
            for (int q = qa; q < qb; q++) {
                const double *rx = RX + (size_t)q * nx + i;
                double c = ay->v[(size_t)q * ay->bw + (R - ay->lo[q])];
                for (int u = 0; u < 8; u++)
                    s[u] += c * rx[u];
            }
            for (int u = 0; u < 8; u++)
                dst[i + u] = s[u];
        }
        for (; i < i1; i++) {
            double s = 0.0;
            for (int q = qa; q < qb; q++)
                s += ay->v[(size_t)q * ay->bw + (R - ay->lo[q])] * RX[(size_t)q * nx + i];
            dst[i] = s;
        }
    }
}

/* g (nx × ny) zeroed outside rows [r0, r1) × columns [c0, c1), the
 * rectangle adjoint_cols writes whole (clearing all of g first was 0.7 %
 * of frame B built's instructions, the SIRT's projections at ×4). */
static void clear_outside(double *g, int nx, int ny, long r0, long r1, long c0, long c1)
{
    memset(g, 0, (size_t)r0 * nx * sizeof *g);
    for (long R = r0; R < r1; R++) {
        memset(g + (size_t)R * nx, 0, (size_t)c0 * sizeof *g);
        memset(g + (size_t)R * nx + c1, 0, (size_t)(nx - c1) * sizeof *g);
    }
    memset(g + (size_t)r1 * nx, 0, (size_t)(ny - r1) * nx * sizeof *g);
}

/* mp_prf_adjoint by the axis operators: RX = R·X on the rows Y reads, then
 * g = Yᵀ·RX (fit/prf_axis.c; a DRF uniform over the pixel is a scale). */
static int adjoint_sep(const mp_prf_model *m, double x, double y, box bx, const double *r,
                       double *g, mp_prf_work *w)
{
    const mp_psf *p = m->psf;
    int nx = p->nx, hw = sinc_halfwidth(m);
    if (!w->axes && !(w->axes = calloc(1, sizeof *w->axes)))
        return 1;
    mp_prf_axis *ax = &w->axes->x, *ay = &w->axes->y;
    if (mp_prf_axis_refill(nx, p->os, p->offset, x, x, bx.x0, bx.w, hw, 0, ax) ||
        mp_prf_axis_refill(p->ny, p->os, p->offset, y, y, bx.y0, bx.h, hw, 0, ay) ||
        work_reserve(w, (size_t)(ay->w > 0 ? ay->w : 1) * nx))
        return 1;
    size_t nel = (size_t)nx * p->ny;
    if (ax->w == 0 || ay->w == 0) {
        memset(g, 0, nel * sizeof *g);
        return 0;
    }
    long i0 = ax->lo[0], i1 = ax->lo[ax->w - 1] + ax->len[ax->w - 1];
    clear_outside(g, nx, p->ny, ay->lo[0], ay->lo[ay->w - 1] + ay->len[ay->w - 1], i0, i1);
    double scale = drf_weight(m->drf, p->os, 0, 0);
    for (int q = 0; q < ay->w; q++) {
        const double *rq = r + (size_t)(ay->p0 - bx.y0 + q) * bx.w + (ax->p0 - bx.x0);
        double *rx = w->c + (size_t)q * nx;
        memset(rx + i0, 0, (size_t)(i1 - i0) * sizeof *rx);
        for (int c = 0; c < ax->w; c++) {
            double v = scale * rq[c];
            if (v == 0.0)
                continue;
            const double *wt = ax->v + (size_t)c * ax->bw;
            double *dst = rx + ax->lo[c];
#pragma omp simd
            for (int i = 0; i < ax->len[c]; i++)
                dst[i] += v * wt[i];
        }
    }
    adjoint_cols(ay, w->c, nx, i0, i1, g);
    w->ops += (double)ay->w * ax->w * ax->bw + (double)ay->w * ay->bw * (double)(i1 - i0);
    return 0;
}

int mp_prf_adjoint(const mp_prf_model *m, double x, double y, long x0, long y0, int w, int h,
                   const double *r, double *g, mp_prf_work *work)
{
    const mp_psf *p = m->psf;
    if (p->kind != MP_PSF_TABLE)
        return 1;
    int os = p->os, nx = p->nx, ny = p->ny;
    size_t nel = (size_t)nx * ny;
    box bx = {x0, y0, w, h};
    if (mp_prf_axes_apply(m))
        return adjoint_sep(m, x, y, bx, r, g, work);
    memset(g, 0, nel * sizeof *g);
    /* A DRF with a QE map: each pixel's value spread over its block with
     * the subpixels' QE, then shifted by the transpose of the render's
     * shift (the damped sinc is even: the shift by −δ). */
    if (work_reserve(work, nel))
        return 1;
    double *U = work->a;
    memset(U, 0, nel * sizeof *U);
    axis_geom ax = table_axis_ref(nx, os, x - p->offset, x - p->offset);
    axis_geom ay = table_axis_ref(ny, os, y - p->offset, y - p->offset);
    for (int j = 0; j < h; j++)
        for (int i = 0; i < w; i++) {
            double v = r[(size_t)j * w + i];
            for (int sy = 0; v != 0.0 && sy < os; sy++) {
                long my = os * (y0 + j - 1) + sy + ay.n0;
                for (int sx = 0; my >= 0 && my < ny && sx < os; sx++) {
                    long mx = os * (x0 + i - 1) + sx + ax.n0;
                    if (mx >= 0 && mx < nx)
                        U[(size_t)my * nx + mx] += drf_weight(m->drf, os, sx, sy) * v;
                }
            }
        }
    mp_shift_table(U, nx, ny, -ax.delta, -ay.delta, m->sinc_hw, g, work->b);
    return 0;
}

static int render(const mp_prf_model *m, double x, double y, box bx,
                  double *prf, double *ddx, double *ddy, mp_prf_work *w)
{
    if (m->psf->kind == MP_PSF_GAUSS)
        return render_gauss(m, x, y, bx, prf, ddx, ddy, w);
    if (w && mp_prf_cache_usable(w->grid, m) &&    /* economy: the phase grid (prf_cache.c) */
        mp_prf_cache_covers(w->grid, m, x, y))
        return mp_prf_cache_render(w->grid, m, x, y, bx.x0, bx.y0, (int)bx.w, (int)bx.h, prf,
                                   ddx, ddy, w->grid_mode);
    return render_table(m, x, y, x, y, bx, prf, ddx, ddy, w);
}

int mp_prf_render_branch(const mp_prf_model *m, double x, double y, double xr, double yr,
                         long wx0, long wy0, long ww, long wh, long *x0, long *y0, int *w,
                         int *h, double *prf, double *ddx, double *ddy, mp_prf_work *work)
{
    box win = {wx0, wy0, ww, wh}, b = box_and(box_of(m, xr, yr), &win);
    *x0 = b.x0;
    *y0 = b.y0;
    *w = (int)b.w;
    *h = (int)b.h;
    if (m->psf->kind != MP_PSF_TABLE)
        return render(m, x, y, b, prf, ddx, ddy, work);
    return render_table(m, x, y, xr, yr, b, prf, ddx, ddy, work);
}

int mp_prf_render(const mp_prf_model *m, double x, double y,
                  double *prf, double *dprf_dx, double *dprf_dy, mp_prf_work *w)
{
    return render(m, x, y, box_of(m, x, y), prf, dprf_dx, dprf_dy, w);
}

int mp_prf_render_window(const mp_prf_model *m, double x, double y,
                         long wx0, long wy0, long ww, long wh,
                         long *x0, long *y0, int *w, int *h,
                         double *prf, double *dprf_dx, double *dprf_dy, mp_prf_work *work)
{
    box win = {wx0, wy0, ww, wh}, b = box_and(box_of(m, x, y), &win);
    *x0 = b.x0;
    *y0 = b.y0;
    *w = (int)b.w;
    *h = (int)b.h;
    return render(m, x, y, b, prf, dprf_dx, dprf_dy, work);
}

double mp_prf_phase(double c, int k, int n)
{
    return n > 1 ? c + (double)k / (n - 1) - 0.5 : c;
}

/* The n phases of column a (x = xa) of mp_prf_render_phases by the
 * element shifts: one x-pass over every row the y-passes may read, then
 * each phase's y-pass and block-sum (render_table's steps). */
static void phase_column(const mp_prf_model *m, const double *T, double xa, double y, int a,
                         int n, double *const *out, mp_prf_work *w)
{
    const mp_psf *p = m->psf;
    int hw = sinc_halfwidth(m);
    axis_geom ax = table_axis(p->nx, p->os, xa - p->offset), ay[64];
    table_span r[64];
    box bx[64];
    int any = 0;
    for (int b = 0; b < n; b++) {
        double yb = mp_prf_phase(y, b, n);
        bx[b] = box_of(m, xa, yb);
        ay[b] = table_axis(p->ny, p->os, yb - p->offset);
        memset(out[b * n + a], 0, (size_t)bx[b].w * (size_t)bx[b].h * sizeof *out[0]);
        if (bx[b].w > 0 && bx[b].h > 0 && span_of(p, bx[b], ax.n0, ay[b].n0, hw, &r[b]))
            any = 1;
        else
            r[b].mi0 = -1;
    }
    if (!any)
        return;
    table_span rows = {0};
    for (int b = 0; b < n; b++)
        if (r[b].mi0 >= 0)
            rows = r[b];            /* the columns: the same for every b */
    rows.tj0 = 0;
    rows.tj1 = p->ny;
    shift_rows(T, w->b, p->nx, &rows, hw, ax.delta);
    for (int b = 0; b < n; b++) {
        if (r[b].mi0 < 0)
            continue;
        shift_cols(w->b, w->a, p->nx, p->ny, &r[b], hw, ay[b].delta);
        block_sum(m, w->a, &r[b], ax.n0, ay[b].n0, bx[b], out[b * n + a], NULL, NULL);
    }
}

int mp_prf_render_phases(const mp_prf_model *m, double x, double y, int n, double *const *out,
                         mp_prf_work *w)
{
    const mp_psf *p = m->psf;
    if (p->kind != MP_PSF_TABLE || n < 1 || n > 64) {
        for (int k = 0; k < n * n; k++)
            if (mp_prf_render(m, mp_prf_phase(x, k % n, n), mp_prf_phase(y, k / n, n), out[k],
                              NULL, NULL, w))
                return 1;
        return 0;
    }
    if (work_reserve(w, (size_t)p->nx * p->ny))
        return 1;
    const double *T = star_table(m, x, y, 0, p->nx, 0, p->ny, w);
    if (!T)
        return 1;
    /* the table at (x, y) for every phase (w->e holds a field's) */
    mp_psf fz = *p;
    fz.t = (double *)T;
    fz.field = NULL;
    mp_prf_model mf = *m;
    mf.psf = &fz;
    if (!shifts_elements(&mf, box_of(&mf, x, y), 0)) {
        for (int k = 0; k < n * n; k++) {
            double xa = mp_prf_phase(x, k % n, n), yb = mp_prf_phase(y, k / n, n);
            if (render_table(&mf, xa, yb, xa, yb, box_of(&mf, xa, yb), out[k], NULL, NULL, w))
                return 1;
        }
        return 0;
    }
    for (int a = 0; a < n; a++)
        phase_column(&mf, T, mp_prf_phase(x, a, n), y, a, n, out, w);
    return 0;
}

/* The largest QE a subpixel can have relative to a perfect detector. */
static double drf_max(const mp_drf *d)
{
    if (!d)
        return 1.0;
    if (d->k == 0)
        return d->volume > 1.0 ? d->volume : 1.0;
    double q = 1.0;
    for (int i = 0; i < d->k * d->k; i++)
        q = d->qe[i] > q ? d->qe[i] : q;
    return q;
}

/* The Gaussian's envelope: a pixel's integral is at most the density at
 * its nearest point, which lies within √½ px of its centre. */
static double *gauss_envelope(const mp_prf_model *m, int *nr)
{
    double qmax = drf_max(m->drf), s = m->psf->sigma;
    int n = (int)ceil(M_SQRT2 * gauss_halfbox(s)) + 2;
    double *env = malloc((size_t)n * sizeof *env);
    if (!env)
        return NULL;
    for (int r = 0; r < n; r++) {
        double rho = r - M_SQRT1_2 > 0 ? r - M_SQRT1_2 : 0.0;
        env[r] = qmax * exp(-0.5 * rho * rho / (s * s)) / (2.0 * M_PI * s * s);
    }
    *nr = n;
    return env;
}

/* The field's point q of 3 × 3: its origin and the points ±POLSCAL/2
 * from it, on a pixel's centre. */
static double place_x(const mp_psf_field *fd, int q)
{
    return floor(fd->x0 + (q % 3 - 1) * 0.5 * fd->xscale);
}

static double place_y(const mp_psf_field *fd, int q)
{
    return floor(fd->y0 + (q / 3 - 1) * 0.5 * fd->yscale);
}

/* The largest |PRF| per whole-pixel distance bin (nb bins, the last
 * holding all beyond) over 5×5 subpixel phases (steps of ¼ px) at one
 * point, or, for a variable PSF, at its origin and the eight points
 * ±POLSCAL/2 from it (PSFEx's and matphot's scale is the PSF stars'
 * range, so these are the field's corners and edge midpoints); a render
 * holds cap values at most.  The 25 phases of a point are rendered
 * together (mp_prf_render_phases: a field evaluated and the x-passes made
 * once, where they were a quarter of the DECam cutout's run one by one).
 * Nonzero when a render fails or memory runs out. */
#define ENV_NPH 5
static int phase_maxima(const mp_prf_model *m, size_t cap, double *bin, int nb)
{
    const mp_psf_field *fd = m->psf->field;
    int npt = fd && fd->order > 0 ? 9 : 1, bad = 0;
    /* The points in parallel, each thread's largest merged after: a
     * maximum is the same in any order (the renders were 0.6 % of 47 Tuc
     * built, serial, bench/SCALING.md). */
#pragma omp parallel reduction(| : bad)
    {
        mp_prf_work w = {0};
        double *prf[ENV_NPH * ENV_NPH], *mine = calloc((size_t)nb, sizeof *mine);
        bad = !mine;
        for (int k = 0; k < ENV_NPH * ENV_NPH; k++)
            bad |= !(prf[k] = malloc(cap * sizeof *prf[k]));
#pragma omp for schedule(dynamic)
        for (int q = 0; q < npt; q++) {
            double cx = npt > 1 ? place_x(fd, q) : 100.0;
            double cy = npt > 1 ? place_y(fd, q) : 100.0;
            for (int k = 0; k < ENV_NPH * ENV_NPH && !bad; k++) {
                long x0, y0;
                int bw, bh;
                mp_prf_box(m, mp_prf_phase(cx, k % ENV_NPH, ENV_NPH),
                           mp_prf_phase(cy, k / ENV_NPH, ENV_NPH), &x0, &y0, &bw, &bh);
                bad = (size_t)bw * bh > cap;
            }
            if (bad || (bad = mp_prf_render_phases(m, cx, cy, ENV_NPH, prf, &w)))
                continue;
            for (int k = 0; k < ENV_NPH * ENV_NPH; k++) {
                double x = mp_prf_phase(cx, k % ENV_NPH, ENV_NPH);
                double y = mp_prf_phase(cy, k / ENV_NPH, ENV_NPH);
                long x0, y0;
                int bw, bh;
                mp_prf_box(m, x, y, &x0, &y0, &bw, &bh);
                for (int j = 0; j < bh; j++)
                    for (int i = 0; i < bw; i++) {
                        int b = (int)hypot(x0 + i - x, y0 + j - y);
                        double v = fabs(prf[k][(size_t)j * bw + i]);
                        b = b < nb ? b : nb - 1;
                        mine[b] = v > mine[b] ? v : mine[b];
                    }
            }
        }
#pragma omp critical(mp_prf_phase_maxima)
        for (int b = 0; mine && b < nb; b++)
            bin[b] = mine[b] > bin[b] ? mine[b] : bin[b];
        for (int k = 0; k < ENV_NPH * ENV_NPH; k++)
            free(prf[k]);
        free(mine);
        mp_prf_work_free(&w);
    }
    return bad;
}

double *mp_prf_envelope(const mp_prf_model *m, int *nr)
{
    if (m->psf->kind == MP_PSF_GAUSS)
        return gauss_envelope(m, nr);
    /* Table: measured (phase_maxima); env[r] is twice the largest beyond
     * r − 1 px.  The slack covers the phases between the grid's (a
     * quarter pixel moves a pixel's distance by a quarter pixel, and the
     * value by far less than 2× where it matters); the sinc shift's
     * ringing (paper §3.1) is in the renders, so it is bounded too — a
     * worst-case bound on it from the taps alone would be orders of
     * magnitude above what a smooth table rings. */
    long x0, y0;
    int bw, bh;
    mp_prf_box(m, 100.0, 100.0, &x0, &y0, &bw, &bh);
    int nb = (int)ceil(hypot(bw, bh)) + 2, n = nb + 2;
    size_t cap = (size_t)(bw + 2) * (bh + 2);
    double *bin = calloc((size_t)nb, sizeof *bin), *env = malloc((size_t)n * sizeof *env);
    int bad = !bin || !env || phase_maxima(m, cap, bin, nb);
    if (bad) {
        free(bin);
        free(env);
        return NULL;
    }
    for (int b = nb - 2; b >= 0; b--)       /* suffix maximum: beyond b */
        bin[b] = bin[b + 1] > bin[b] ? bin[b + 1] : bin[b];
    for (int r = 0; r < n; r++) {
        int b = r - 1 < 0 ? 0 : r - 1;
        env[r] = b < nb ? 2.0 * bin[b] : 0.0;
    }
    free(bin);
    *nr = n;
    return env;
}

int mp_prf_crop_init(const mp_prf_model *m, double frac, double ron, mp_prf_crop *c)
{
    memset(c, 0, sizeof *c);
    c->frac = frac;
    c->ron2 = ron * ron;
    if (!(frac > 0))
        return 0;
    return !(c->env = mp_prf_envelope(m, &c->nr));
}

void mp_prf_crop_free(mp_prf_crop *c)
{
    if (!c)
        return;
    free(c->env);
    memset(c, 0, sizeof *c);
}

double mp_prf_crop_radius(const mp_prf_crop *c, double E, double sky)
{
    if (!c || !c->env || !(c->frac > 0))
        return INFINITY;
    double b = isfinite(sky) && sky > 0 ? sky : 0.0;
    double level = c->frac * sqrt(c->ron2 + b) / fabs(E);
    if (!(level > 0))
        return INFINITY;
    for (int r = 0; r < c->nr; r++)
        if (c->env[r] < level)
            return (double)r;
    return INFINITY;
}
