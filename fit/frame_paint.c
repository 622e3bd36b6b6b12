/* frame_paint.c — stars painted onto the frame: one star's light on a
 * window, every star's in parallel bands (the neighbours' model the groups
 * are fitted against), and the residual image. */

#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include "fit/frame_priv.h"

double ff_crop_radius(const crop_rule *c, const mp_star *s)
{
    return mp_prf_crop_radius(c, s->flux, s->sky);
}

/* Add (sign +1) or subtract E·PRF of one star to an image window
 * [x0, x0+w) × [y0, y0+h) (1-based global), row stride w, out to radius
 * rad (INFINITY: the whole PRF box).  Only the window's part is rendered.
 * Returns 1 when out of memory; *cut is set when the crop left part of the
 * box out. */
static int paint_window(const mp_prf_model *m, const mp_star *s, double sign, double rad,
                        float *img, long x0, long y0, long w, long h, mp_prf_work *wk,
                        double **buf, size_t *cap, int *cut);

int ff_painted(const mp_star *s)
{
    return isfinite(s->flux) && s->flux != 0.0 && fabs(s->x) < 1e9 && fabs(s->y) < 1e9;
}

int ff_paint(const mp_prf_model *m, const mp_star *s, double sign, double rad, float *img,
                 long x0, long y0, long w, long h, mp_prf_work *wk, double **buf, size_t *cap,
                 int *cut)
{
    if (!ff_painted(s))
        return 0;
    /* Economy: from the phase grid when the star is within its bound, and
     * bilinearly within that one's (a quarter of the reads): either moves
     * a neighbour fitted under this light by at most that bound's σ. */
    const struct mp_prf_cache_s *grid = wk->grid;
    if (grid && !(fabs(s->flux) <= wk->grid_emax))
        wk->grid = NULL;
    wk->grid_mode = wk->grid ? mp_prf_tier_mode(&wk->grid_tiers, s->flux) : MP_PRF_CUBIC;
    int rc = paint_window(m, s, sign, rad, img, x0, y0, w, h, wk, buf, cap, cut);
    wk->grid = grid;
    wk->grid_mode = MP_PRF_CUBIC;
    return rc;
}

static int paint_window(const mp_prf_model *m, const mp_star *s, double sign, double rad,
                        float *img, long x0, long y0, long w, long h, mp_prf_work *wk,
                        double **buf, size_t *cap, int *cut)
{
    long wx0 = x0, wy0 = y0, wx1 = x0 + w, wy1 = y0 + h;   /* [wx0, wx1) */
    if (isfinite(rad)) {
        /* pixels whose centres lie within rad on either axis */
        long a = (long)ceil(s->x - rad), b = (long)ceil(s->y - rad);
        long c = (long)floor(s->x + rad) + 1, d = (long)floor(s->y + rad) + 1;
        long bx, by;
        int bw, bh;
        mp_prf_box(m, s->x, s->y, &bx, &by, &bw, &bh);
        if (cut && (a > bx || b > by || c < bx + bw || d < by + bh))
            *cut = 1;
        wx0 = a > wx0 ? a : wx0;
        wy0 = b > wy0 ? b : wy0;
        wx1 = c < wx1 ? c : wx1;
        wy1 = d < wy1 ? d : wy1;
        if (wx1 <= wx0 || wy1 <= wy0)
            return 0;
    }
    size_t need = (size_t)(wx1 - wx0) * (size_t)(wy1 - wy0);
    if (need > *cap) {
        free(*buf);
        *cap = 0;                   /* a failed malloc leaves no room behind */
        if (!(*buf = malloc(need * sizeof **buf)))
            return 1;
        *cap = need;
    }
    long rx0, ry0;
    int rw, rh;
    if (mp_prf_render_window(m, s->x, s->y, wx0, wy0, wx1 - wx0, wy1 - wy0, &rx0, &ry0, &rw, &rh,
                             *buf, NULL, NULL, wk))
        return 1;
    for (int j = 0; j < rh; j++) {
        float *row = img + (ry0 + j - y0) * w + (rx0 - x0);
        const double *src = *buf + (size_t)j * rw;
        for (int i = 0; i < rw; i++)
            row[i] = (float)(row[i] + sign * s->flux * src[i]);
    }
    return 0;
}

/* ---- Painting every star onto the frame, in parallel (issue 14) -------- */

/* Rows of a band: each band is painted by one thread. */
#define PAINT_BAND 64

/* The rows [*r0, *r1] star s reaches out to radius rad, within 1..ny. */
static void star_rows(const mp_prf_model *m, const mp_star *s, double rad, long ny, long *r0,
                      long *r1)
{
    long bx, by;
    int bw, bh;
    mp_prf_box(m, s->x, s->y, &bx, &by, &bw, &bh);
    long a = by, b = by + bh - 1;
    if (rad < (double)bh) {          /* a crop inside the box (NaN: none) */
        long c = (long)ceil(s->y - rad), d = (long)floor(s->y + rad);
        a = c > a ? c : a;
        b = d < b ? d : b;
    }
    *r0 = a < 1 ? 1 : a;
    *r1 = b > ny ? ny : b;
}

/* Add sign·E·PRF of the stars s[0..n-1] (each out to crop's radius) to
 * the nx × ny image img.  Once the residual's and the model's painting
 * was the largest serial part of a round (bench/SCALING.md): the frame is
 * cut into bands of PAINT_BAND rows, threads take bands, and a band
 * paints in list order every star that reaches it, clipped to its rows.
 * Every pixel so gets its stars in the same order whatever the number of
 * threads: the image does not depend on it.  A star across a band's edge
 * is rendered once per band, clipped (as the crop clips it).  proto: the
 * phase grid to use (its grid and grid_emax; may be zeroed).  *ncut
 * counts the stars the crop cut, *ops adds the exact renders' work
 * (multiply-adds, whole numbers: the sum does not depend on the threads).
 * Returns 1 when out of memory. */
static int paint_frame(const mp_prf_model *m, const mp_star *const *s, size_t n,
                       const crop_rule *crop, double sign, const mp_prf_work *proto, float *img,
                       long nx, long ny, long *ncut, double *ops)
{
    long nb = (ny + PAINT_BAND - 1) / PAINT_BAND;
    size_t *cnt = calloc((size_t)nb + 1, sizeof *cnt), *idx = NULL;
    double *rad = malloc((n ? n : 1) * sizeof *rad);
    long *b0 = malloc((n ? n : 1) * sizeof *b0), *b1 = malloc((n ? n : 1) * sizeof *b1);
    unsigned char *cut = calloc(n ? n : 1, 1);
    int nomem = !cnt || !rad || !b0 || !b1 || !cut;
    size_t tot = 0;
    for (size_t k = 0; !nomem && k < n; k++) {
        long r0 = 1, r1 = 0;         /* none: what paint leaves undrawn */
        const mp_star *p = s[k];
        rad[k] = ff_crop_radius(crop, p);
        if (ff_painted(p))
            star_rows(m, p, rad[k], ny, &r0, &r1);
        b0[k] = r1 >= r0 ? (r0 - 1) / PAINT_BAND : 1;
        b1[k] = r1 >= r0 ? (r1 - 1) / PAINT_BAND : 0;
        for (long b = b0[k]; b <= b1[k]; b++, tot++)
            cnt[b + 1]++;
    }
    /* Each band's stars, in list order (counts to offsets, then filled). */
    if (!nomem && !(idx = malloc((tot ? tot : 1) * sizeof *idx)))
        nomem = 1;
    for (long b = 0; !nomem && b < nb; b++)
        cnt[b + 1] += cnt[b];
    size_t *fill = nomem ? NULL : malloc(((size_t)nb + 1) * sizeof *fill);
    nomem = nomem || !fill;
    if (!nomem) {
        memcpy(fill, cnt, ((size_t)nb + 1) * sizeof *fill);
        for (size_t k = 0; k < n; k++)
            for (long b = b0[k]; b <= b1[k]; b++)
                idx[fill[b]++] = k;
    }
    double work = 0.0;
#pragma omp parallel if (!nomem) reduction(+ : work)
    {
        mp_prf_work wk = {0};
        wk.grid = proto->grid;
        wk.grid_emax = proto->grid_emax;
        wk.grid_tiers = proto->grid_tiers;
        wk.single = 1;          /* light painted and held (fit/prf_axis.h) */
        double *buf = NULL;
        size_t cap = 0;
#pragma omp for schedule(dynamic)
        for (long b = 0; b < nb; b++) {
            long y0 = 1 + b * PAINT_BAND, h = ny - y0 + 1 < PAINT_BAND ? ny - y0 + 1 : PAINT_BAND;
            for (size_t q = cnt[b]; q < cnt[b + 1]; q++) {
                size_t k = idx[q];
                int c = 0;
                if (ff_paint(m, s[k], sign, rad[k], img + (size_t)(y0 - 1) * (size_t)nx, 1, y0, nx,
                          h, &wk, &buf, &cap, &c)) {
#pragma omp atomic write
                    nomem = 1;
                }
                if (c && b == b0[k])
                    cut[k] = 1;    /* counted by the star's first band only */
            }
        }
        free(buf);
        work += wk.ops;
        mp_prf_work_free(&wk);
    }
    *ops += work;
    for (size_t k = 0; !nomem && k < n; k++)
        *ncut += cut[k];
    free(cnt);
    free(idx);
    free(fill);
    free(rad);
    free(b0);
    free(b1);
    free(cut);
    return nomem;
}

/* The model of every live star on the whole frame, each out to its crop
 * radius; *ncut counts the stars cropped. */
float *ff_all_stars(const mp_frame *f, const mp_prf_model *m, const star_state *st, size_t n,
                        const crop_rule *crop, const mp_frame_opts *o, const frame_rules *R,
                        float *lent, long *ncut)
{
    size_t npix = (size_t)f->im.nx * (size_t)f->im.ny;
    float *all = lent ? lent : malloc(npix * sizeof *all);
    /* Zeroed in parallel: serial, with its first touch of the pages, it
     * was a third of the fit's serial time (issue 14, bench/SCALING.md). */
    long nx = f->im.nx, ny = all ? f->im.ny : 0;
#pragma omp parallel for schedule(static)
    for (long j = 0; j < ny; j++)
        memset(all + (size_t)j * (size_t)nx, 0, (size_t)nx * sizeof *all);
    const mp_star **live = malloc((n ? n : 1) * sizeof *live);
    size_t nl = 0;
    for (size_t k = 0; live && k < n; k++)
        if (st[k].alive)
            live[nl++] = &st[k].s;
    mp_prf_work proto = {0};
    proto.grid = o->grid;
    proto.grid_emax = R->gemax;
    proto.grid_tiers = R->gtiers;
    double ops = 0.0;
    if (all && (!live || paint_frame(m, live, nl, crop, +1.0, &proto, all, f->im.nx, f->im.ny,
                                     ncut, &ops))) {
        if (!lent)
            free(all);
        all = NULL;
    }
    mp_econ_learn_paint(o->cache, ops);
    free(live);
    return all;
}

/* The crop rule of a frame: no envelope (whole boxes) when cropfrac is 0;
 * else the rule's fields as mp_prf_crop_init sets them, its envelope the
 * cache's. */
int ff_crop_init(const mp_frame *f, const mp_prf_model *m, double cropfrac, mp_econ_cache *cache,
                 crop_rule *c)
{
    if (mp_prf_crop_init(m, 0.0, f->rdnoise, c) || !(cropfrac > 0))
        return 0;
    c->frac = cropfrac;
    return !(c->env = mp_econ_envelope(cache, m, &c->nr));
}

int mp_fit_residual(const mp_frame *f, const mp_prf_model *m, const mp_table *t,
                    double cropfrac, float *res, char *err)
{
    return mp_fit_residual_grid(f, m, t, cropfrac, NULL, NULL, 0.0, NULL, res, err);
}

int mp_fit_residual_grid(const mp_frame *f, const mp_prf_model *m, const mp_table *t,
                         double cropfrac, mp_econ_cache *cache, const mp_prf_cache *grid,
                         double gemax, const mp_prf_tiers *tiers, float *res, char *err)
{
    long nx = f->im.nx, ny = f->im.ny;
    int cx = mp_table_col(t, "XPSF_IMAGE"), cy = mp_table_col(t, "YPSF_IMAGE");
    int cf = mp_table_col(t, "FLUX_PSF"), cs = mp_table_col(t, "SKY_PSF");
    if (cx < 0 || cy < 0 || cf < 0) {
        snprintf(err, MP_ERRLEN, "residual: table has no fitted columns");
        return 1;
    }
#pragma omp parallel for schedule(static)
    for (long i = 0; i < nx * ny; i++)
        res[i] = (f->mask && (f->mask[i] & MP_MASK_BAD)) ? NAN : f->im.pix[i];
    size_t n = t->nrow;
    mp_star *st = malloc((n ? n : 1) * sizeof *st);
    const mp_star **ps = malloc((n ? n : 1) * sizeof *ps);
    crop_rule crop = {0};
    int rc = !st || !ps || ff_crop_init(f, m, cropfrac, cache, &crop);
    for (size_t r = 0; !rc && r < n; r++) {
        st[r] = (mp_star){.x = mp_table_get(t, r, cx), .y = mp_table_get(t, r, cy),
                          .flux = mp_table_get(t, r, cf),
                          .sky = cs >= 0 ? mp_table_get(t, r, cs) : NAN};
        ps[r] = &st[r];
    }
    mp_prf_work proto = {0};       /* economy: the grid as the fit's paints use it */
    proto.grid = grid;
    proto.grid_emax = gemax;
    if (tiers)
        proto.grid_tiers = *tiers;
    long ncut = 0;
    double ops = 0.0;
    rc = rc || paint_frame(m, ps, n, &crop, -1.0, &proto, res, nx, ny, &ncut, &ops);
    mp_econ_learn_paint(cache, ops);
    free(st);
    free(ps);
    free(crop.env);
    if (rc)
        snprintf(err, MP_ERRLEN, "residual: out of memory");
    return rc;
}
