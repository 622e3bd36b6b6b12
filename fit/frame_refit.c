/* frame_refit.c — a group fitted on a local copy of its pixels with its
 * neighbours' light subtracted, and refitted only when that light changed
 * (economy, issue 5; the change's bound: frame_bound.c). */

#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include "fit/frame_priv.h"

/* After a group's fit: each fitted star's bound starts again from 0 (its
 * fit saw the light it is fitted against) — from infinity after a loose
 * fit (mp_frame_opts.loosetol: not converged to the run's tol, so never
 * kept) — and a star whose light changed (its paint: position, flux,
 * sky; or its death) holds that change for ff_update_bounds, from its
 * values before (old). */
static void note_fitted(star_state *sub, const mp_star *old, int n, int loose)
{
    for (int k = 0; k < n; k++) {
        star_state *s = &sub[k];
        s->bound = loose ? INFINITY : 0.0;
        if (s->alive && s->s.x == old[k].x && s->s.y == old[k].y && s->s.flux == old[k].flux &&
            ff_same_value(s->s.sky, old[k].sky))
            continue;
        if (!s->moved) {
            s->ox = old[k].x, s->oy = old[k].y, s->oflux = old[k].flux, s->osky = old[k].sky;
            s->olight = 1;           /* a fitted star was alive: painted */
            s->moved = MOVED_FIT;
        }
    }
}

/* Whether a group may keep its fit: the sum over its live members of
 * their bounds squared below refittol² (the group's pixels are its
 * members' regions, and its sky is shared; overlaps counted twice:
 * conservative).  One star that must be refitted refits its whole group:
 * a part refitted with the rest held (and its own sky) does not find the
 * joint fit (tried: 90th percentile of the flux change 1.5 σ on the dense
 * bench frame, against 0.1 σ for whole groups). */
static int group_kept(const star_state *st, int n, double refittol)
{
    double q2 = 0.0;
    for (int k = 0; k < n; k++)
        if (st[k].alive)
            q2 += st[k].bound * st[k].bound;
    return q2 < refittol * refittol;
}

/* L: the window (x0, y0, w × h) of f less every other star's light: the
 * data less all, with the group's own stars sub[0..n-1] painted back
 * with the crop all_stars took them off with, so it cancels exactly.
 * The light taken off stays in the pixels' noise: its Poisson variance
 * (data − L, clipped at 0) joins L's xvar, as the halo's and the lookup's
 * do (pipeline/halo.c), so a pixel under a bright neighbour's wing is
 * weighed by all the light it holds — without it the group's weights
 * counted only its own model, and beside a bright star a lump of the
 * neighbour's noise could pass minsnr as a star (issue 13).
 * Nonzero when out of memory. */
static int local_frame(const mp_frame *f, const mp_prf_model *m, const crop_rule *crop,
                       const float *all, const star_state *sub, int n, long x0, long y0, long w,
                       long h, mp_frame *L, mp_prf_work *wk, double **buf, size_t *cap)
{
    L->im.nx = w;
    L->im.ny = h;
    L->im.pix = malloc((size_t)(w * h) * sizeof *L->im.pix);
    L->mask = malloc((size_t)(w * h));
    L->xvar = f->xvar || all ? malloc((size_t)(w * h) * sizeof *L->xvar) : NULL;
    if (!L->im.pix || !L->mask || ((f->xvar || all) && !L->xvar))
        return 1;
    for (long j = 0; j < h; j++)
        for (long i = 0; i < w; i++) {
            size_t g = (size_t)(y0 - 1 + j) * f->im.nx + (size_t)(x0 - 1 + i);
            L->im.pix[j * w + i] = (float)(f->im.pix[g] - (all ? (double)all[g] : 0.0));
            L->mask[j * w + i] = f->mask ? f->mask[g] : 0;
            if (L->xvar)
                L->xvar[j * w + i] = f->xvar ? f->xvar[g] : 0.0f;
        }
    for (int k = 0; all && k < n; k++)
        if (sub[k].alive && ff_paint(m, &sub[k].s, +1.0, ff_crop_radius(crop, &sub[k].s),
                                     L->im.pix, x0, y0, w, h, wk, buf, cap, NULL))
            return 1;
    for (long j = 0; all && j < h; j++)
        for (long i = 0; i < w; i++) {
            size_t g = (size_t)(y0 - 1 + j) * f->im.nx + (size_t)(x0 - 1 + i);
            double off = (double)f->im.pix[g] - (double)L->im.pix[j * w + i];
            if (off > 0.0)
                L->xvar[j * w + i] += (float)off;
        }
    return 0;
}

/* Fit one group on a local frame: data − (the light of every other star)
 * = data − all + own.  With economy (may_keep) the group keeps its fit when
 * no live member's surroundings changed by o->refittol or more since it
 * was fitted (by the members' bounds, frame_bound.c); rep counts group
 * fits (fits) and groups left alone (kept).  With economy, the fitted
 * stars' bounds start again and their changes are noted (note_fitted). */
int ff_fit_group_local(const mp_frame *f, const mp_prf_model *m, const mp_frame_opts *o,
                       double mergerad, const frame_rules *R, const float *all,
                       const crop_rule *crop, star_state *st, int n, int may_keep, int economy,
                       mp_frame_report *rep, char *err)
{
    double r = o->fit.fitrad;
    if (may_keep && all && isfinite(r) && group_kept(st, n, o->refittol)) {
        rep->kept++;
        return 0;
    }
    mp_prf_work wk = {0};
    wk.grid = o->grid;
    wk.grid_emax = R->gemax;
    wk.grid_tiers = R->gtiers;
    double *buf = NULL;
    size_t cap = 0;
    star_state *sub = malloc((size_t)n * sizeof *sub);
    int *idx = malloc((size_t)n * sizeof *idx);
    mp_star *old = malloc((size_t)n * sizeof *old);
    mp_frame L = *f;
    L.im.pix = NULL;
    L.mask = NULL;
    L.xvar = NULL;
    int rc = 1, nact = 0;
    if (!sub || !idx || !old) {
        snprintf(err, MP_ERRLEN, "out of memory");
        goto done;
    }
    for (int k = 0; k < n; k++)
        if (st[k].alive) {
            idx[nact] = k;
            sub[nact] = st[k];
            old[nact++] = st[k].s;
        }
    if (nact == 0) {
        rep->kept++;
        rc = 0;
        goto done;
    }
    rep->fits++;
    long x0, y0, w, h;
    /* The sky-order test reads the background around the group too. */
    double rw = o->fit.sky_order == MP_SKY_AUTO && o->fit.fit_sky ? MP_SKY_TEST_RADIUS * r : r;
    ff_group_window(f, sub, nact, rw, &x0, &y0, &w, &h);
    if (w == 0 || h == 0 || (!all && x0 == 1 && y0 == 1 && w == f->im.nx && h == f->im.ny)) {
        rc = ff_fit_one_group(f, m, o, mergerad, R, sub, nact, 0.0, 0.0, rep, err);
    } else if (local_frame(f, m, crop, all, sub, nact, x0, y0, w, h, &L, &wk, &buf, &cap)) {
        snprintf(err, MP_ERRLEN, "out of memory");
        goto done;
    } else {
        rc = ff_fit_one_group(&L, m, o, mergerad, R, sub, nact, (double)(x0 - 1),
                              (double)(y0 - 1), rep, err);
    }
    if (!rc && economy && all && isfinite(r))
        note_fitted(sub, old, nact, o->loosetol > o->fit.tol);
    for (int k = 0; k < nact; k++)
        st[idx[k]] = sub[k];
done:
    free(L.im.pix);
    free(L.mask);
    free(L.xvar);
    free(sub);
    free(idx);
    free(old);
    free(buf);
    mp_prf_work_free(&wk);
    return rc;
}
