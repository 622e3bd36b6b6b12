/* lm_render.c — a group fit's renders: each star's PRF and derivatives on
 * the fitted pixels of its window (or of its core while the wings are
 * frozen), from the phase grid or exactly (issue 12); its derivatives on
 * its core alone where the grid's measured bound allows it
 * (fit/prf_deriv_box.c). */

#include <math.h>
#include <stddef.h>
#include <stdlib.h>
#include <string.h>
#include "fit/lm_group.h"

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

/* Star r's box b — columns [b[0], b[1]) and rows [b[2], b[3]) of the
 * group box, clipped to its window in c — as spans of frame pixels in
 * G->spans, each with its index in r's arrays in G->soff; returns the
 * number of spans. */
int lm_box_rows(group *G, const rstar *r, const int b[4], int c[4])
{
    int ns = 0;
    c[0] = b[0] > r->i0 ? b[0] : r->i0;
    c[1] = b[1] < r->i1 ? b[1] : r->i1;
    c[2] = b[2] > r->j0 ? b[2] : r->j0;
    c[3] = b[3] < r->j1 ? b[3] : r->j1;
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

int lm_core_rows(group *G, const rstar *r, int c[4])
{
    const int b[4] = {r->ci0, r->ci1, r->cj0, r->cj1};
    return lm_box_rows(G, r, b, c);
}

/* The mode star k of p is drawn from the grid in: its own while its flux
 * stays within that mode's limit (its bias bound, fit/prf_cache.c); a
 * star found brighter moves to the next mode that holds it, to the fit's
 * end, so that its model changes at most a few times, each more exact. */
static int grid_mode(group *G, const double *p, int k)
{
    int mode = G->ongrid[k] - 1, now = mp_prf_tier_mode_from(&G->tiers, p[3 * k], mode);
    G->ongrid[k] = (uint8_t)(1 + now);
    return now;
}

/* render_all while the wings are frozen: each star on its core only. */
static int render_core(group *G, const double *p, rstar *r, int what)
{
    int usable = mp_prf_cache_usable(G->work.grid, G->m);
    for (int k = 0; k < G->n; k++) {
        double x = p[3 * k + 1], y = p[3 * k + 2];
        int grid = usable && G->ongrid[k];
        if ((!grid && what == RENDER_DERIVS) || G->settled[k])
            continue;       /* the exact render drew them with the PRF */
        int c[4], ns = lm_core_rows(G, &r[k], c);
        if (ns == 0)
            continue;
        int rc = grid ? mp_prf_cache_render_at(G->work.grid, G->m, x, y, G->spans, G->soff, ns,
                                               what == RENDER_DERIVS ? NULL : r[k].prf,
                                               what == RENDER_PRF ? NULL : r[k].dx,
                                               what == RENDER_PRF ? NULL : r[k].dy,
                                               grid_mode(G, p, k))
                      : render_exact(G, x, y, c[0], c[1], c[2], c[3], &r[k], ns, G->soff);
        if (rc)
            return 1;
    }
    return 0;
}

/* Star r's derivatives drawn on box columns [i0, i1) and rows [j0, j1)
 * of its window: that box's packed pixels row by row (rstar.dp0, dp1;
 * empty rows at the row's end). */
static void deriv_rows(const group *G, rstar *r, int i0, int i1, int j0, int j1)
{
    for (int t = 0; t < r->j1 - r->j0; t++) {
        int j = r->j0 + t, e = r->pp[t] + r->pn[t];
        if (j < j0 || j >= j1 || i0 >= i1) {
            r->dp0[t] = r->dp1[t] = e;
            continue;
        }
        int a = i0 <= r->i0 ? r->pp[t] : packed_at(G, j, i0);
        int b = i1 >= r->i1 ? e : packed_at(G, j, i1);
        r->dp0[t] = a < r->pp[t] ? r->pp[t] : a > e ? e : a;
        r->dp1[t] = b < r->dp0[t] ? r->dp0[t] : b > e ? e : b;
    }
}

/* Whether star k of p has its position derivatives drawn within its core
 * box alone (issue 12): when the phase grid measured, for a box no larger,
 * that the pixels beyond hold at most MP_DBOX_SHARE of an isolated star's
 * information on x and y at its E/(B + RON²) (mp_prf_cache_deriv_box; B
 * the group's sky at the star, RON² without the error plane's extra
 * variance, which only lowers the share).  The fit then solves the normal
 * equations of that Jacobian, an estimating equation as unbiased, with a
 * position σ at most 1/sqrt(1 − MP_DBOX_SHARE) of the whole window's (the
 * covariance it reports is its own).  A star found brighter than that is
 * drawn whole to the fit's end, so its Jacobian changes at most once. */
static int deriv_in_box(group *G, const double *p, int k)
{
    const mp_prf_cache *c = G->work.grid;
    if (G->dwhole[k] || !(c->dbox_hw > 0) || !(c->dbox_hw <= lm_box_halfwidth(G)))
        return 0;
    double B = sky_at(G, p, p[3 * k + 1], p[3 * k + 2]);
    if (fabs(p[3 * k]) <= c->dbox_u * ((B > 0 ? B : 0.0) + G->ron2))
        return 1;
    G->dwhole[k] = 1;
    return 0;
}

/* Star r drawn from the grid at (x, y) on the ns spans of its window (set
 * in G->spans): its PRF there (unless what is RENDER_DERIVS), its
 * derivatives on its core box alone (taken as zero beyond, where nothing
 * reads them: rstar.dp0, dp1). */
static int render_in_box(group *G, double x, double y, rstar *rk, int ns, int what, int mode)
{
    int b[4], c[4];
    if (what != RENDER_DERIVS && mp_prf_cache_render_at(G->work.grid, G->m, x, y, G->spans, NULL,
                                                        ns, rk->prf, NULL, NULL, mode))
        return 1;
    lm_box_at(G, x, y, b);
    int nb = lm_box_rows(G, rk, b, c);
    deriv_rows(G, rk, c[0], c[1], c[2], c[3]);
    return nb > 0 && mp_prf_cache_render_at(G->work.grid, G->m, x, y, G->spans, G->soff, nb,
                                            NULL, rk->dx, rk->dy, mode);
}

/* Star k of p rendered into r[k] on the fitted pixels of its whole
 * window (what as lm_render_all's); nonzero when the window overflows. */
static int render_window(group *G, const double *p, rstar *r, int k, int what, int grid)
{
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
     * of the noise (frame_paint.c subtracts neighbours the same way). */
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
    if (ns <= 0)
        return ns < 0;
    int mode = grid ? grid_mode(G, p, k) : MP_PRF_CUBIC;
    if (grid && what != RENDER_PRF && deriv_in_box(G, p, k))
        return render_in_box(G, x, y, rk, ns, what, mode);
    if (what != RENDER_PRF || !grid)        /* an exact render draws them all */
        deriv_rows(G, rk, rk->i0, rk->i1, rk->j0, rk->j1);
    return grid ? mp_prf_cache_render_at(G->work.grid, G->m, x, y, G->spans, NULL, ns,
                                         what == RENDER_DERIVS ? NULL : rk->prf,
                                         what == RENDER_PRF ? NULL : rk->dx,
                                         what == RENDER_PRF ? NULL : rk->dy, mode)
                : render_exact(G, x, y, rk->i0, rk->i1, rk->j0, rk->j1, rk, ns, NULL);
}

int lm_render_all(group *G, const double *p, rstar *r, int what)
{
    if (G->frozen)
        return render_core(G, p, r, what);
    int usable = mp_prf_cache_usable(G->work.grid, G->m);
    for (int k = 0; k < G->n; k++) {
        int grid = usable && G->ongrid[k];
        if ((!grid && what == RENDER_DERIVS) || G->settled[k])
            continue;       /* the exact render drew them with the PRF;
                             * a settled star is drawn in both buffers */
        if (render_window(G, p, r, k, what, grid))
            return 1;
    }
    return 0;
}

int lm_render_star(group *G, const double *p, rstar *r, int k)
{
    int grid = mp_prf_cache_usable(G->work.grid, G->m) && G->ongrid[k];
    return render_window(G, p, r, k, RENDER_ALL, grid);
}

/* A render copied: the struct, and the contents of its arrays into dst's
 * own. */
void lm_render_copy(rstar *dst, const rstar *src)
{
    int *pp = dst->pp, *pn = dst->pn, *pb = dst->pb, *dp0 = dst->dp0, *dp1 = dst->dp1;
    double *prf = dst->prf, *dx = dst->dx, *dy = dst->dy;
    *dst = *src;
    dst->pp = pp;
    dst->pn = pn;
    dst->pb = pb;
    dst->dp0 = dp0;
    dst->dp1 = dp1;
    dst->prf = prf;
    dst->dx = dx;
    dst->dy = dy;
    int rows = src->j1 - src->j0;
    size_t len = rows > 0 ? (size_t)(src->pb[rows - 1] + src->pn[rows - 1]) : 0;
    if (rows > 0) {
        memcpy(pp, src->pp, (size_t)rows * sizeof *pp);
        memcpy(pn, src->pn, (size_t)rows * sizeof *pn);
        memcpy(pb, src->pb, (size_t)rows * sizeof *pb);
        memcpy(dp0, src->dp0, (size_t)rows * sizeof *dp0);
        memcpy(dp1, src->dp1, (size_t)rows * sizeof *dp1);
    }
    memcpy(prf, src->prf, len * sizeof *prf);
    memcpy(dx, src->dx, len * sizeof *dx);
    memcpy(dy, src->dy, len * sizeof *dy);
}
