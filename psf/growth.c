/* growth.c — the table's share of a star's light (build.h): the fit with
 * a table of sum 1 gives the light the table holds; the light beyond it
 * out to rbig around the brightest stars, stacked, the rest (nearly). */
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include "psf/build_priv.h"

/* Stars the light beyond the table is stacked over at most (the brightest). */
#define MP_EPSF_NGROWTH 10

typedef struct { size_t k; double flux; } bright;

static int by_flux(const void *a, const void *b)
{
    double x = ((const bright *)a)->flux, y = ((const bright *)b)->flux;
    return (x < y) - (x > y);
}

/* v = img + own at frame pixel (px, py) (own: on the box ox, oy, ow, oh);
 * NaN where masked, not finite or off the frame. */
static double value_at(const mp_frame *f, const float *img, const double *own, long ox, long oy,
                       int ow, int oh, long px, long py)
{
    if (px < 1 || py < 1 || px > f->im.nx || py > f->im.ny)
        return NAN;
    size_t o = (size_t)(py - 1) * f->im.nx + (size_t)(px - 1);
    double v = img[o];
    if (own && px >= ox && px < ox + ow && py >= oy && py < oy + oh)
        v += own[(size_t)(py - oy) * ow + (size_t)(px - ox)];
    return f->mask[o] || !isfinite(v) ? NAN : v;
}

/* The light the star's model leaves out, per unit flux, at the offsets
 * (i, j) within ±hw px of the star's own position (x, y), into u
 * ((2hw+1)²; NaN where a pixel it needs is masked or off the frame, or
 * outside rin < |offset| ≤ rbig): v = img + own (own: the star's light put
 * back less its model) interpolated bilinearly at (x + i, y + j), so that
 * every star's offsets are its true distances, less the sky (the median
 * of the pixels rbig..rbig+4 px away), over the star's flux F.  Returns 1
 * when the rings leave the frame or the sky ring has fewer than half its
 * pixels; buf holds the box's pixels. */
static int outer_image(const mp_frame *f, const float *img, const double *own, long ox,
                       long oy, int ow, int oh, double x, double y, double F, double rin,
                       double rbig, int hw, double *u, double *buf)
{
    double r1 = rbig + 4.0;
    long x0 = (long)floor(x - r1), x1 = (long)ceil(x + r1);
    long y0 = (long)floor(y - r1), y1 = (long)ceil(y + r1);
    if (x0 < 1 || y0 < 1 || x1 > f->im.nx || y1 > f->im.ny || !(rbig > rin))
        return 1;
    size_t ns = 0, all = 0;
    for (long j = y0; j <= y1; j++)
        for (long i = x0; i <= x1; i++) {
            double r = hypot(i - x, j - y);
            if (r <= rbig || r > r1)
                continue;
            all++;
            double v = value_at(f, img, own, ox, oy, ow, oh, i, j);
            if (isfinite(v))
                buf[ns++] = v;
        }
    if (ns < 8 || 2 * ns < all)
        return 1;
    double sky = mp_epsf_median(buf, ns);
    int w = 2 * hw + 1;
    for (int j = -hw; j <= hw; j++)
        for (int i = -hw; i <= hw; i++) {
            double r = hypot(i, j), px = x + i, py = y + j, val = NAN;
            if (r > rin && r <= rbig) {
                long ix = (long)floor(px), iy = (long)floor(py);
                double ax = px - ix, ay = py - iy;
                val = (1 - ax) * (1 - ay) * value_at(f, img, own, ox, oy, ow, oh, ix, iy) +
                      ax * (1 - ay) * value_at(f, img, own, ox, oy, ow, oh, ix + 1, iy) +
                      (1 - ax) * ay * value_at(f, img, own, ox, oy, ow, oh, ix, iy + 1) +
                      ax * ay * value_at(f, img, own, ox, oy, ow, oh, ix + 1, iy + 1);
            }
            u[(size_t)(j + hw) * w + (size_t)(i + hw)] = (val - sky) / F;
        }
    return 0;
}

/* The stars' light beyond the table per unit flux, ℓ, and its error:
 * the median over the nst star images u (nst × w², w = 2hw+1) per
 * offset — a neighbour or a faint star lies in one star's image, a
 * spike or a ring in all — then per 1-px ring the mean over its
 * measured offsets times the ring's offsets (so a narrow spike counts
 * with its own light, where a ring's median over azimuth drops it). */
static void stacked_light(const double *u, int nst, int hw, double rin, double rbig,
                          double *col, double *l, double *lerr)
{
    int w = 2 * hw + 1, nring = (int)ceil(rbig) + 1;
    double sum[256] = {0}, var[256] = {0};
    int cnt[256] = {0}, all[256] = {0};
    nring = nring > 256 ? 256 : nring;
    for (int j = 0; j < w; j++)
        for (int i = 0; i < w; i++) {
            double r = hypot(i - hw, j - hw);
            int q = (int)r;
            if (r <= rin || r > rbig || q >= nring)
                continue;
            all[q]++;
            size_t m = 0, e = (size_t)j * w + i;
            for (int k = 0; k < nst; k++)
                if (isfinite(u[(size_t)k * w * w + e]))
                    col[m++] = u[(size_t)k * w * w + e];
            if (m < 3)
                continue;
            double med = mp_median_select(col, m);
            for (size_t k = 0; k < m; k++)
                col[k] = fabs(col[k] - med);
            double se = 1.2533 * 1.4826 * mp_median_select(col, m) / sqrt((double)m);
            sum[q] += med;
            var[q] += se * se;
            cnt[q]++;
        }
    *l = 0.0;
    double v = 0.0;
    for (int q = 0; q < nring; q++)
        if (cnt[q]) {
            double s = (double)all[q] / cnt[q];
            *l += sum[q] * s;
            v += var[q] * s * s;
        }
    /* Each star's own sum over the annulus: what its sky and flux errors
     * shift, on every pixel of its image at once, the per-pixel errors
     * above treat as independent.  The error is the larger of the two
     * (the median of nst stars: 1.2533 × robust σ / √nst). */
    double ls[MP_EPSF_NGROWTH];
    for (int k = 0; k < nst && k < MP_EPSF_NGROWTH; k++) {
        ls[k] = 0.0;
        for (int j = 0; j < w; j++)
            for (int i = 0; i < w; i++) {
                double r = hypot(i - hw, j - hw), x = u[(size_t)k * w * w + (size_t)j * w + i];
                if (r > rin && r <= rbig && (int)r < nring && isfinite(x))
                    ls[k] += x * (double)all[(int)r] / fmax(cnt[(int)r], 1);
            }
    }
    int n = nst < MP_EPSF_NGROWTH ? nst : MP_EPSF_NGROWTH;
    double med = mp_epsf_median(memcpy(col, ls, (size_t)n * sizeof *col), (size_t)n);
    for (int k = 0; k < n; k++)
        ls[k] = fabs(ls[k] - med);
    double es = 1.2533 * 1.4826 * mp_epsf_median(ls, (size_t)n) / sqrt((double)n);
    *lerr = fmax(sqrt(v), es);
}

/* own += F × the PRF of model m at frame position (x, y), on the box
 * (ox, oy, ow, oh) of frame pixels. */
static int add_model(const mp_prf_model *m, double x, double y, double F, long ox, long oy,
                     int ow, int oh, double *own, mp_prf_work *w)
{
    long bx, by;
    int bw, bh;
    mp_prf_box(m, x, y, &bx, &by, &bw, &bh);
    double *p = malloc((size_t)bw * bh * sizeof *p);
    if (!p || mp_prf_render(m, x, y, p, NULL, NULL, w)) {
        free(p);
        return 1;
    }
    for (int j = 0; j < bh; j++)
        for (int i = 0; i < bw; i++) {
            long px = bx + i - ox, py = by + j - oy;
            if (px >= 0 && px < ow && py >= 0 && py < oh)
                own[(size_t)py * ow + (size_t)px] += F * p[(size_t)j * bw + i];
        }
    free(p);
    return 0;
}

/* own = what img lacks of the star's data and its neighbours' (their
 * rows of t, put back with m as the residual took them: none when t is
 * NULL) less their models by table e at their fitted fluxes: so that
 * img + own is the light the table does not describe. */
static int own_light(const mp_table *t, const mp_prf_model *m, const mp_epsf *e,
                     const mp_epsf_star *st, long ox, long oy, int ow, int oh, double *own,
                     mp_psf *tab, mp_prf_work *w)
{
    memset(own, 0, (size_t)ow * oh * sizeof *own);
    int cx = t ? mp_table_col(t, "XPSF_IMAGE") : -1, cy = t ? mp_table_col(t, "YPSF_IMAGE") : -1;
    int cf = t ? mp_table_col(t, "FLUX_PSF") : -1;
    int back = m && cx >= 0 && cy >= 0 && cf >= 0;
    for (size_t r = 0; back && r < t->nrow; r++) {
        double x = mp_table_get(t, r, cx), y = mp_table_get(t, r, cy), F = mp_table_get(t, r, cf);
        if (isfinite(F) && mp_within(x - st->xf, y - st->yf, 1.0) &&
            add_model(m, x, y, F, ox, oy, ow, oh, own, w))
            return 1;
    }
    for (int j = 0; back && j < st->nnb; j++) {
        size_t r = st->nbrow[j];
        if (add_model(m, mp_table_get(t, r, cx), mp_table_get(t, r, cy), mp_table_get(t, r, cf),
                      ox, oy, ow, oh, own, w))
            return 1;
    }
    char err[MP_ERRLEN];
    if (mp_epsf_table(e, st->x, st->y, tab, err))
        return 1;
    mp_prf_model me = {tab, NULL, 10};
    if (add_model(&me, st->x, st->y, -st->flux, ox, oy, ow, oh, own, w))
        return 1;
    for (int j = 0; j < st->nnb; j++)
        if (add_model(&me, st->nbx[j], st->nby[j], -st->nbf[j], ox, oy, ow, oh, own, w))
            return 1;
    return 0;
}

double mp_epsf_growth_rin(const mp_epsf_opts *o)
{
    return o->support > 0 && o->support < o->psfrad ? o->support : o->psfrad;
}

int mp_epsf_growth(const mp_frame *f, const float *img, const mp_table *fitted,
                   const mp_prf_model *m, const mp_epsf_star *s, size_t n, double rin,
                   double rbig, mp_epsf *e, char *err)
{
    e->sum = 1.0;
    e->sum_err = 0.0;
    e->ngrowth = 0;
    bright *b = malloc((n + 1) * sizeof *b);
    long r1 = (long)ceil(rbig + 4.0);
    int ow = (int)(2 * r1 + 3), oh = ow, hw = (int)ceil(rbig), w = 2 * hw + 1;
    double *buf = malloc((size_t)ow * oh * sizeof *buf);
    double *own = malloc((size_t)ow * oh * sizeof *own);
    double *u = malloc((size_t)MP_EPSF_NGROWTH * w * w * sizeof *u);
    mp_prf_work wk;
    memset(&wk, 0, sizeof wk);
    wk.single = 1;              /* light taken off and held (fit/prf_axis.h) */
    mp_psf tab;
    memset(&tab, 0, sizeof tab);
    int rc = 1;
    if (!b || !buf || !own || !u || ceil(rbig) >= 255)
        goto oom;
    size_t nu = 0;
    for (size_t k = 0; k < n; k++)
        if (s[k].used)
            b[nu++] = (bright){k, s[k].flux};
    qsort(b, nu, sizeof *b, by_flux);
    int nr = 0;
    /* From the band the table's edge only partly covers (its elements
     * reach psfrad − 0.5 px; a pixel's block ±0.7 px more). */
    double r0 = fmax(rin - 1.5, 0.0);
    for (size_t q = 0; q < nu && nr < MP_EPSF_NGROWTH; q++) {
        const mp_epsf_star *st = &s[b[q].k];
        long ox = (long)floor(st->x) - r1 - 1, oy = (long)floor(st->y) - r1 - 1;
        if (!(st->flux > 0))
            continue;
        if (own_light(fitted, m, e, st, ox, oy, ow, oh, own, &tab, &wk))
            goto oom;
        if (!outer_image(f, img, own, ox, oy, ow, oh, st->x, st->y, st->flux, r0, rbig, hw,
                         u + (size_t)nr * w * w, buf))
            nr++;
    }
    e->ngrowth = nr;
    if (nr >= 3) {
        double l, le;
        stacked_light(u, nr, hw, r0, rbig, buf, &l, &le);
        double ratio = 1.0 / (1.0 + l);
        e->sum_err = le * ratio * ratio;
        /* Only a deficit significant at 3 σ: a crowded frame's unfound
         * stars still bias the stack's light up a little. */
        if (ratio < 1.0 - 3.0 * e->sum_err && ratio > 0.2)
            e->sum = ratio;
    }
    rc = 0;
    goto done;
oom:
    snprintf(err, MP_ERRLEN, "psf build: out of memory");
done:
    free(own);
    free(b);
    free(buf);
    free(u);
    mp_psf_free(&tab);
    mp_prf_work_free(&wk);
    return rc;
}
