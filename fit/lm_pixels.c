/* lm_pixels.c — a group fit's pixels: which are fitted (and the flags they
 * set), packed row by row with their data and sky basis. */

#include <math.h>
#include <stddef.h>
#include <stdlib.h>
#include <string.h>
#include "fit/lm_group.h"

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
    G->modt = malloc(N * sizeof *G->modt);
    G->var = malloc(N * sizeof *G->var);
    G->rv = malloc(N * sizeof *G->rv);
    G->wt = malloc(N * sizeof *G->wt);
    G->wres = malloc(N * sizeof *G->wres);
    G->basis = malloc(6 * N * sizeof *G->basis);
    if (!G->rj || !G->ri0 || !G->ri1 || !G->rp || !G->spans || !G->soff || !G->rrow || !G->prow ||
        !G->dat || !G->mod || !G->modt || !G->var || !G->rv || !G->wt || !G->wres || !G->basis)
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

/* The pixels within r of (x, y) on the frame, and of them those not
 * saturated, into *all and *open. */
static void disc_count(const mp_frame *f, double x, double y, double r, long *all, long *open)
{
    long nx = f->im.nx, ny = f->im.ny;
    *all = *open = 0;
    for (long Y = (long)ceil(y - r); Y <= (long)floor(y + r); Y++)
        for (long X = (long)ceil(x - r); X <= (long)floor(x + r); X++) {
            double dx = X - x, dy = Y - y;
            if (X < 1 || Y < 1 || X > nx || Y > ny || dx * dx + dy * dy > r * r)
                continue;
            (*all)++;
            *open += !(f->mask[(size_t)(Y - 1) * nx + (size_t)(X - 1)] & MP_MASK_SATURATED);
        }
}

/* Star s's fitting radius in G: fitrad r; for a saturated star (its
 * centre's pixel saturated) the smallest radius (in steps of half a pixel,
 * at most half its PRF's box) whose disc holds as many pixels not saturated
 * as the fitrad disc holds in all.  Its flux comes from its wings (paper
 * §5's stars are not saturated; ALLSTAR leaves such a star out), and a
 * plateau that covers the fitrad disc left it no pixel of its own: with
 * fitrad = FWHM the segmented scene (V) kept 1 of its 8 saturated stars,
 * and the fits of the stars beside them, which then held their light, ran
 * to fluxes of 10⁹ e⁻ and more traded against the sky.  Not a star beside
 * a plateau: its disc grown into a saturated star's wings took in their
 * misfit (the segmented scene at the default fitrad 5, three draws: 13
 * fewer stars found with its PSF built). */
static double star_radius(const group *G, const mp_star *s, double r)
{
    const mp_frame *f = G->f;
    long all, open, px = lround(s->x), py = lround(s->y);
    if (!f->mask || px < 1 || py < 1 || px > f->im.nx || py > f->im.ny ||
        !(f->mask[(size_t)(py - 1) * f->im.nx + (size_t)(px - 1)] & MP_MASK_SATURATED))
        return r;
    long bx, by;
    int bw, bh;
    mp_prf_box(G->m, s->x, s->y, &bx, &by, &bw, &bh);
    double rmax = fmax(r, 0.5 * (bw < bh ? bw : bh));
    disc_count(f, s->x, s->y, r, &all, &open);
    long want = all;
    double q = r;
    while (open < want && q + 0.5 <= rmax) {
        q += 0.5;
        long a2;
        disc_count(f, s->x, s->y, q, &a2, &open);
    }
    return q;
}

/* Choose the fitted pixels and set the flags that depend on them. */
int lm_select_pixels(group *G, const mp_fit_opts *o, mp_star *st)
{
    const mp_frame *f = G->f;
    long nx = f->im.nx, ny = f->im.ny;
    double r = o->fitrad;
    int whole = !isfinite(r);
    if (!whole && !(G->rk = malloc(((size_t)G->n + 1) * sizeof *G->rk)))
        return 2;
    if (whole) {
        G->bx0 = G->by0 = 1;
        G->bw = (int)nx;
        G->bh = (int)ny;
    } else {
        double xa = INFINITY, xb = -INFINITY, ya = INFINITY, yb = -INFINITY;
        for (int k = 0; k < G->n; k++) {
            double rk = G->rk[k] = star_radius(G, &st[k], r);
            xa = fmin(xa, st[k].x - rk);
            xb = fmax(xb, st[k].x + rk);
            ya = fmin(ya, st[k].y - rk);
            yb = fmax(yb, st[k].y + rk);
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
                if (dx * dx + dy * dy <= G->rk[k] * G->rk[k]) {
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
