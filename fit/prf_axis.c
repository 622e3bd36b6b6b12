/* prf_axis.c — a table PRF as the product of two 1-D operators (issue 12).
 *
 * Why: the phase grid (fit/prf_cache.c) renders the table exactly at
 * (os·(Gb+3))² node phases, with derivatives, and at G² cell centres for its
 * bound: 27 % of the 47 Tuc 256² fit task with the Tiny Tim ×4 table, each
 * render the whole table's damped-sinc shift (paper §3.1).  Every step of
 * that render acts on one axis only — the shift is a product of 1-D kernels,
 * the block-sum and the five-point derivative (§3.2) are per axis, a DRF
 * uniform over the pixel is a scale — so the render is Y·T·Xᵀ with X, Y
 * banded (a pixel reads os + 2hw + 4 elements).  X depends on the star's x
 * phase only: A = T·Xᵀ is formed once per x node and every y node is then
 * Y·A on detector columns, os·(2hw+1)/(os+2hw+4) times fewer operations per
 * node than the shift of the table, and the derivatives come from the same
 * A (∂/∂x: T·X'ᵀ; ∂/∂y: Y'·A).  The values are render_table's up to the
 * order of the sums (test_prf_cache checks them to 1e-12 of the peak). */
#include <math.h>
#include <stdlib.h>
#include <string.h>
#include "fit/prf_axis.h"

void mp_prf_axis_geom(int n, int os, double x, double xr, long *n0, double *delta, long *p0,
                      int *w)
{
    double c0 = (n - 1) / 2 + 0.5 + os * (0.5 - x);
    *n0 = lround((n - 1) / 2 + 0.5 + os * (0.5 - xr));
    *delta = c0 - (double)*n0;
    /* Table index m ↔ g = m − n0; pixel p = floor(g/os) + 1. */
    long g0 = -*n0, g1 = (long)(n - 1) - *n0;
    long a = (long)floor((double)g0 / os) + 1, b = (long)floor((double)g1 / os) + 1;
    *p0 = a;
    *w = (int)(b - a + 1);
}

void mp_prf_axis_free(mp_prf_axis *a)
{
    if (!a)
        return;
    free(a->lo);
    free(a->len);
    free(a->v);
    free(a->vf);
    memset(a, 0, sizeof *a);
}

int mp_prf_axes_apply(const mp_prf_model *m)
{
    return !m->drf || m->drf->k == 0;
}

int mp_prf_separable(const mp_prf_model *m)
{
    return m->psf->kind == MP_PSF_TABLE && !m->psf->field && mp_prf_axes_apply(m);
}

/* c·S[j] added to a pixel's row, S the shifted table (zero beyond [0, n)):
 * S[j] = Σ_k T[j+k]·wt[k+h] over the taps inside the table. */
static void add_shifted(double *row, long lo, long j, double c, const double *wt, int h, int n)
{
    if (j < 0 || j >= n)
        return;
    for (int k = -h; k <= h; k++)
        if (j + k >= 0 && j + k < n)
            row[j + k - lo] += c * wt[k + h];
}

/* Grow a's arrays to w pixels of bw weights (and the derivative's). */
static int reserve(mp_prf_axis *a, int w, int bw, int deriv)
{
    size_t nw = w > 0 ? (size_t)w : 1, nv = 2 * nw * (size_t)bw;
    if (nw > a->capw) {
        long *lo = realloc(a->lo, nw * sizeof *lo);
        if (lo)
            a->lo = lo;
        int *len = realloc(a->len, nw * sizeof *len);
        if (len)
            a->len = len;
        if (!lo || !len)
            return 1;
        a->capw = nw;
    }
    if (nv > a->capv) {
        double *v = realloc(a->v, nv * sizeof *v);
        if (!v)
            return 1;
        a->v = v;
        a->capv = nv;
    }
    a->bwf = (bw + MP_PRF_LANES - 1) / MP_PRF_LANES * MP_PRF_LANES;
    size_t nf = 2 * nw * (size_t)a->bwf;
    if (nf > a->capf) {
        float *vf = realloc(a->vf, nf * sizeof *vf);
        if (!vf)
            return 1;
        a->vf = vf;
        a->capf = nf;
    }
    a->d = deriv ? a->v + nw * (size_t)bw : NULL;
    a->df = deriv ? a->vf + nw * (size_t)a->bwf : NULL;
    if (w <= 0) {           /* no pixel: the one row there is, zero */
        memset(a->v, 0, (size_t)bw * sizeof *a->v);
        if (a->d)
            memset(a->d, 0, (size_t)bw * sizeof *a->d);
    }
    return 0;
}

/* Each pixel's run of weights cut to where they are not zero: without
 * the derivative, the two elements a side its five-point stencil reads
 * weigh nothing (2 of a 22-tap ×2 row's 26 each side).  Leading zeros go
 * in pairs, so every weight keeps its place's parity and the two-lane
 * sums of mp_prf_axis_rows add the same terms in the same lanes; a zero
 * term added to a sum leaves it as it was (a sum from +0 is never −0),
 * so every render and adjoint keeps its bits. */
static void trim_zeros(mp_prf_axis *a)
{
    for (int q = 0; q < a->w; q++) {
        double *v = a->v + (size_t)q * a->bw;
        int lead = 0, len = a->len[q];
        while (lead + 2 <= len && v[lead] == 0.0 && v[lead + 1] == 0.0)
            lead += 2;
        if (lead > 0) {
            memmove(v, v + lead, (size_t)(len - lead) * sizeof *v);
            memset(v + len - lead, 0, (size_t)lead * sizeof *v);
            a->lo[q] += lead;
            len -= lead;
        }
        while (len > 0 && v[len - 1] == 0.0)
            len--;
        a->len[q] = len;
    }
}

/* a's weights in single precision (vf, df), each pixel's run zero beyond
 * its len to the row's end (mp_prf_axis_rows_single reads whole lanes). */
static void single_weights(mp_prf_axis *a)
{
    for (int q = 0; q < a->w; q++) {
        const double *v = a->v + (size_t)q * a->bw;
        float *f = a->vf + (size_t)q * a->bwf;
        for (int i = 0; i < a->bwf; i++)
            f[i] = i < a->len[q] ? (float)v[i] : 0.0f;
        if (!a->d)
            continue;
        v = a->d + (size_t)q * a->bw;
        f = a->df + (size_t)q * a->bwf;
        for (int i = 0; i < a->bwf; i++)
            f[i] = i < a->len[q] ? (float)v[i] : 0.0f;
    }
}

/* Whether a's operator was last refilled with these arguments. */
static int same_refill(const mp_prf_axis *a, int n, int os, double offset, double x, double xr,
                       long wp0, long ww, int hw, int deriv)
{
    return a->last.made && a->last.n == n && a->last.os == os && a->last.hw == hw &&
           a->last.deriv == deriv && a->last.offset == offset && a->last.x == x &&
           a->last.xr == xr && a->last.wp0 == wp0 && a->last.ww == ww;
}

int mp_prf_axis_refill(int n, int os, double offset, double x, double xr, long wp0, long ww,
                       int hw, int deriv, mp_prf_axis *a)
{
    if (same_refill(a, n, os, offset, x, xr, wp0, ww, hw, deriv))
        return 0;
    a->last.made = 0;
    int hw_given = hw;
    long n0, bp0;
    double delta;
    int bwid;
    mp_prf_axis_geom(n, os, x - offset, xr - offset, &n0, &delta, &bp0, &bwid);
    long p0 = bp0 > wp0 ? bp0 : wp0, p1 = bp0 + bwid < wp0 + ww ? bp0 + bwid : wp0 + ww;
    a->p0 = p0;
    a->w = p1 > p0 ? (int)(p1 - p0) : 0;
    hw = hw > 0 ? (hw < 64 ? hw : 64) : 0;
    int h = mp_shift_on_grid(delta) || hw == 0 ? 0 : hw;
    double wt[2 * 64 + 1] = {1.0};
    for (int k = -h; k <= h && h > 0; k++)
        wt[k + h] = mp_damped_sinc((double)k - delta);
    a->bw = os + 2 * h + 4;
    if (reserve(a, a->w, a->bw, deriv))
        return 1;
    /* The five-point derivative's weights on S[m−2..m+2] (render_table:
     * the table index moves by −os per +1 px of the star). */
    static const int dd[4] = {-2, -1, 1, 2};
    const double cd[4] = {-os / 12.0, 8.0 * os / 12.0, -8.0 * os / 12.0, os / 12.0};
    /* A pixel whose elements and taps all lie inside the table has the
     * same weights as any other such pixel (they depend on the element's
     * place within the pixel only): computed for the first, copied to the
     * rest, bit for bit the same sums. */
    int have = -1;
    for (int q = 0; q < a->w; q++) {
        long mb0 = (p0 + q - 1) * os + n0;      /* the pixel's first element */
        long lo = mb0 - h - 2 < 0 ? 0 : mb0 - h - 2, hi = mb0 + os + h + 2;
        int inner = mb0 - h - 2 >= 0 && hi <= n;
        hi = hi > n ? n : hi;
        a->lo[q] = lo;
        a->len[q] = hi > lo ? (int)(hi - lo) : 0;
        double *v = a->v + (size_t)q * a->bw;
        if (inner && have >= 0) {
            memcpy(v, a->v + (size_t)have * a->bw, (size_t)a->bw * sizeof *v);
            if (deriv)
                memcpy(a->d + (size_t)q * a->bw, a->d + (size_t)have * a->bw,
                       (size_t)a->bw * sizeof *v);
            continue;
        }
        /* a pixel's weights are sums from zero (its row cleared here, not
         * the whole array: most rows are copies) */
        memset(v, 0, (size_t)a->bw * sizeof *v);
        if (deriv)
            memset(a->d + (size_t)q * a->bw, 0, (size_t)a->bw * sizeof *v);
        for (long m = mb0 < 0 ? 0 : mb0; m < mb0 + os && m < n; m++) {
            add_shifted(v, lo, m, 1.0, wt, h, n);
            for (int t = 0; deriv && t < 4; t++)
                add_shifted(a->d + (size_t)q * a->bw, lo, m + dd[t], cd[t], wt, h, n);
        }
        if (inner)
            have = q;
    }
    if (!deriv)
        trim_zeros(a);
    single_weights(a);
    a->last.n = n;
    a->last.os = os;
    a->last.hw = hw_given;
    a->last.deriv = deriv;
    a->last.offset = offset;
    a->last.x = x;
    a->last.xr = xr;
    a->last.wp0 = wp0;
    a->last.ww = ww;
    a->last.made = 1;
    return 0;
}

int mp_prf_axis_build(int n, int os, double offset, double x, double xr, long wp0, long ww,
                      int hw, mp_prf_axis *a)
{
    memset(a, 0, sizeof *a);
    if (mp_prf_axis_refill(n, os, offset, x, xr, wp0, ww, hw, 1, a)) {
        mp_prf_axis_free(a);
        return 1;
    }
    return 0;
}

double mp_prf_axis_ops(int nx, int ny, int os, int hw, int derivs, double w, double h, int sep)
{
    double taps = 2.0 * hw + 1.0;
    if (!sep) {
        double ex = fmin(w * os + 4.0, (double)nx), ey = fmin(h * os + 4.0, (double)ny);
        double ty = fmin(ey + 2.0 * hw, (double)ny);
        return ex * (ty + ey) * taps + ex * ey * (derivs ? 9.0 : 1.0);
    }
    /* the weights of a pixel inside the table once per axis, of the rest
     * copied (mp_prf_axis_refill); the rows T·Xᵀ; the columns Y·A */
    double bw = os + 2.0 * hw + 4.0, rows = fmin(h * os + bw, (double)ny);
    w = fmin(w, nx / (double)os + 2.0);
    h = fmin(h, ny / (double)os + 2.0);
    return 2.0 * os * taps * (derivs ? 5.0 : 1.0) + (w + h) * bw * (derivs ? 2.0 : 1.0) +
           rows * w * bw * (derivs ? 2.0 : 1.0) + h * w * bw * (derivs ? 3.0 : 1.0);
}

/* Σ t0[i]·v[i] and Σ t1[i]·v[i] (i < len) into *a0, *a1, each summed as
 * a two-lane vector reduction sums it (the even and the odd terms apart,
 * an odd count's last term into the even sum, then 0 + even + odd): the
 * order `omp simd` gave this loop, kept so that the tables stay the same
 * bits, while two rows share the weights' loads and run two chains of
 * additions at once (a row's sums waited on the last addition). */
static void rows_pair(const double *t0, const double *t1, const double *v, int len, double *a0,
                      double *a1)
{
    double e0 = 0.0, o0 = 0.0, e1 = 0.0, o1 = 0.0;
    int i = 0;
    for (; i + 1 < len; i += 2) {
        e0 += t0[i] * v[i];
        o0 += t0[i + 1] * v[i + 1];
        e1 += t1[i] * v[i];
        o1 += t1[i + 1] * v[i + 1];
    }
    if (i < len) {
        e0 = t0[i] * v[i] + e0;
        e1 = t1[i] * v[i] + e1;
    }
    *a0 = (e0 + 0.0) + o0;
    *a1 = (e1 + 0.0) + o1;
}

void mp_prf_axis_rows(const double *T, int nx, long j0, long j1, const mp_prf_axis *ax,
                      double *A, double *Ad)
{
    if (!Ad) {
        for (long j = j0; j < j1; j += 2) {
            long j2 = j + 1 < j1 ? j + 1 : j;    /* an odd last row: twice */
            const double *r0 = T + (size_t)j * nx, *r1 = T + (size_t)j2 * nx;
            double *a = A + (size_t)(j - j0) * ax->w, *b = A + (size_t)(j2 - j0) * ax->w;
            for (int q = 0; q < ax->w; q++)
                rows_pair(r0 + ax->lo[q], r1 + ax->lo[q], ax->v + (size_t)q * ax->bw, ax->len[q],
                          &a[q], &b[q]);
        }
        return;
    }
    for (long j = j0; j < j1; j++) {
        const double *row = T + (size_t)j * nx;
        double *a = A + (size_t)(j - j0) * ax->w, *ad = Ad + (size_t)(j - j0) * ax->w;
        for (int q = 0; q < ax->w; q++) {
            const double *t = row + ax->lo[q], *v = ax->v + (size_t)q * ax->bw;
            const double *d = ax->d + (size_t)q * ax->bw;
            double sv = 0.0, sd = 0.0;
#pragma omp simd reduction(+ : sv, sd)
            for (int i = 0; i < ax->len[q]; i++) {
                sv += t[i] * v[i];
                sd += t[i] * d[i];
            }
            a[q] = sv;
            ad[q] = sd;
        }
    }
}

void mp_prf_axis_cols(const mp_prf_axis *ay, int deriv, const double *A, long row0, int ax_w,
                      double scale, double *out, long oy, long ox, long ostride)
{
    const double *W = deriv ? ay->d : ay->v;
    for (int q = 0; q < ay->w; q++) {
        double *o = out + (size_t)(oy + q) * ostride + ox;
        const double *w = W + (size_t)q * ay->bw;
        const double *a0 = A + (size_t)(ay->lo[q] - row0) * ax_w;
        /* eight outputs at a time summed in registers, each over k in
         * order as before (its bits unchanged): the sums were read and
         * written back at every k */
        int i = 0;
        for (; i + 8 <= ax_w; i += 8) {
            double s[8] = {0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0};
            for (int k = 0; k < ay->len[q]; k++) {
                const double *a = a0 + (size_t)k * ax_w + i;
                double c = w[k];
                for (int u = 0; u < 8; u++)
                    s[u] += c * a[u];
            }
            for (int u = 0; u < 8; u++)
                o[i + u] = s[u] * scale;
        }
        for (; i < ax_w; i++) {
            double s = 0.0;
            for (int k = 0; k < ay->len[q]; k++)
                s += w[k] * a0[(size_t)k * ax_w + i];
            o[i] = s * scale;
        }
    }
}

/* MP_PRF_LANES floats, as one vector (GNU C's vector extension, which gcc
 * and clang share: the lanes' sums stay in their lanes, so the order of
 * every addition is the code's, not the vectoriser's). */
typedef float lanes __attribute__((vector_size(MP_PRF_LANES * sizeof(float))));

static inline lanes lanes_at(const float *p)
{
    lanes x;
    memcpy(&x, p, sizeof x);
    return x;
}

/* A vector's lanes summed, in one order: (0 + 2) + (1 + 3). */
static inline float lanes_sum(lanes x)
{
    return (x[0] + x[2]) + (x[1] + x[3]);
}

/* Σ t0[i]·v[i] and Σ t1[i]·v[i] over i < len rounded up to MP_PRF_LANES
 * (v zero beyond len) into *a0, *a1, in lanes; two rows share the
 * weights' loads and run two chains of additions at once. */
static void rows_pair_single(const float *t0, const float *t1, const float *v, int len,
                             float *a0, float *a1)
{
    lanes s0 = {0}, s1 = {0};
    for (int i = 0; i < len; i += MP_PRF_LANES) {
        lanes w = lanes_at(v + i);
        s0 += lanes_at(t0 + i) * w;
        s1 += lanes_at(t1 + i) * w;
    }
    *a0 = lanes_sum(s0);
    *a1 = lanes_sum(s1);
}

/* Σ t[i]·v[i] and Σ t[i]·d[i] (as rows_pair_single) into *a, *ad. */
static void row_deriv(const float *t, const float *v, const float *d, int len, float *a, float *ad)
{
    lanes sv = {0}, sd = {0};
    for (int i = 0; i < len; i += MP_PRF_LANES) {
        lanes x = lanes_at(t + i);
        sv += x * lanes_at(v + i);
        sd += x * lanes_at(d + i);
    }
    *a = lanes_sum(sv);
    *ad = lanes_sum(sd);
}

/* Table row r's elements [c0, c1) into tf at the same places, zero from c1
 * for a lane's room (the padded runs read up to MP_PRF_LANES − 1 past it). */
static void row_single(const double *r, long c0, long c1, float *tf)
{
    for (long i = c0; i < c1; i++)
        tf[i] = (float)r[i];
    for (int k = 0; k < MP_PRF_LANES; k++)
        tf[c1 + k] = 0.0f;
}

void mp_prf_axis_rows_single(const double *T, int nx, long j0, long j1, const mp_prf_axis *ax,
                             float *A, float *Ad, float *tf)
{
    if (ax->w <= 0)
        return;
    long c0 = ax->lo[0], c1 = ax->lo[ax->w - 1] + ax->len[ax->w - 1];
    if (!Ad) {
        float *t1 = tf + MP_PRF_AXIS_TF(nx) / 2;
        for (long j = j0; j < j1; j += 2) {
            long j2 = j + 1 < j1 ? j + 1 : j;    /* an odd last row: twice */
            row_single(T + (size_t)j * nx, c0, c1, tf);
            row_single(T + (size_t)j2 * nx, c0, c1, t1);
            float *a = A + (size_t)(j - j0) * ax->w, *b = A + (size_t)(j2 - j0) * ax->w;
            for (int q = 0; q < ax->w; q++)
                rows_pair_single(tf + ax->lo[q], t1 + ax->lo[q], ax->vf + (size_t)q * ax->bwf,
                                 ax->len[q], &a[q], &b[q]);
        }
        return;
    }
    for (long j = j0; j < j1; j++) {
        row_single(T + (size_t)j * nx, c0, c1, tf);
        float *a = A + (size_t)(j - j0) * ax->w, *ad = Ad + (size_t)(j - j0) * ax->w;
        for (int q = 0; q < ax->w; q++)
            row_deriv(tf + ax->lo[q], ax->vf + (size_t)q * ax->bwf, ax->df + (size_t)q * ax->bwf,
                      ax->len[q], &a[q], &ad[q]);
    }
}

void mp_prf_axis_cols_single(const mp_prf_axis *ay, int deriv, const float *A, long row0,
                             int ax_w, double scale, double *out, long oy, long ox, long ostride)
{
    const float *W = deriv ? ay->df : ay->vf;
    for (int q = 0; q < ay->w; q++) {
        double *o = out + (size_t)(oy + q) * ostride + ox;
        const float *w = W + (size_t)q * ay->bwf;
        const float *a0 = A + (size_t)(ay->lo[q] - row0) * ax_w;
        /* eight outputs at a time summed in registers, each over k in
         * order (the sums were read and written back at every k) */
        int i = 0;
        for (; i + 2 * MP_PRF_LANES <= ax_w; i += 2 * MP_PRF_LANES) {
            lanes s0 = {0}, s1 = {0};
            for (int k = 0; k < ay->len[q]; k++) {
                const float *a = a0 + (size_t)k * ax_w + i;
                float c = w[k];
                s0 += c * lanes_at(a);
                s1 += c * lanes_at(a + MP_PRF_LANES);
            }
            for (int u = 0; u < MP_PRF_LANES; u++) {
                o[i + u] = (double)s0[u] * scale;
                o[i + MP_PRF_LANES + u] = (double)s1[u] * scale;
            }
        }
        for (; i < ax_w; i++) {
            float s = 0.0f;
            for (int k = 0; k < ay->len[q]; k++)
                s += w[k] * a0[(size_t)k * ax_w + i];
            o[i] = (double)s * scale;
        }
    }
}
