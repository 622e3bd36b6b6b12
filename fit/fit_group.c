/* fit_group.c — mp_fit_group: one group of stars and its sky fitted
 * (design.md §5): the start, the fit (levmar.c), the sky order
 * (sky_test.c), the covariance and the stars' outputs. */

#include <lapacke.h>
#include <math.h>
#include <stddef.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include "fit/lm_group.h"
#include "fit/spd.h"

void mp_fit_opts_default(mp_fit_opts *o)
{
    o->sky_order = MP_SKY_AUTO;
    o->fitrad = NAN;
    o->tol = 1e-3;
    o->maxiter = 50;
    o->stop_pair = 0.0;
    o->fit_sky = 1;
    o->crop = NULL;
    o->grid = NULL;
    o->grid_emax = INFINITY;
    memset(&o->grid_tiers, 0, sizeof o->grid_tiers);
    o->work = NULL;
    o->exact_lm = 0;
    o->weak_pairs = 1;
    o->settle = 1;
    o->refresh_movers = 1;
    o->reuse_pairs = 1;
    o->warm_sky = 0;
    o->stats = 1;
    o->sky_known = NAN;
}

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
    free(G->modt);
    free(G->var);
    free(G->rv);
    free(G->wt);
    free(G->wres);
    free(G->basis);
    free(G->spans);
    free(G->soff);
    free(G->fx);
    free(G->ongrid);
    free(G->dwhole);
    free(G->settled);
    free(G->moved);
    free(G->calm);
    free(G->fy);
    free(G->scr);
    free(G->pk);
    free(G->pl);
    free(G->tail);
    free(G->pfull);
    free(G->pk2);
    free(G->ppos);
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
            free(r[k].dp0);
            free(r[k].dp1);
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
    free(G->psave);
    free(G->sx);
    free(G->rk);
    mp_prf_work_free(&G->work);
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
    /* (The row-major upper triangle is the column-major lower one: no
     * transposed copy, as in levmar.c's lm_step; fit/spd.h.) */
    if (mp_spd_inverse(G->M, np) != 0) {
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

/* The median of the group's data, the upper one for even n (v[n/2] of
 * the sorted values), by selection: a sort was 1 % of 47 Tuc's CPU. */
static double start_sky(const group *G)
{
    double *v = malloc((G->npix ? G->npix : 1) * sizeof *v);
    if (!v)
        return 0.0;
    size_t n = G->npix;
    memcpy(v, G->dat, n * sizeof *v);
    double s = n ? mp_select_kth(v, n, n / 2) : 0.0;
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
            r[k].dp0 = malloc(((size_t)G->bh + 1) * sizeof(int));
            r[k].dp1 = malloc(((size_t)G->bh + 1) * sizeof(int));
            r[k].pn = malloc(((size_t)G->bh + 1) * sizeof(int));
            r[k].pb = malloc(((size_t)G->bh + 1) * sizeof(int));
            if (!r[k].prf || !r[k].dx || !r[k].dy || !r[k].pp || !r[k].pn || !r[k].pb ||
                !r[k].dp0 || !r[k].dp1)
                return 1;
        }
    }
    /* Room for the quadratic sky whatever the order: the order may rise. */
    size_t np = (size_t)G->npmax;
    G->p = calloc(np, sizeof *G->p);
    G->pt = calloc(np, sizeof *G->pt);
    G->stail = calloc((size_t)G->n * 27, sizeof *G->stail);
    G->fx = malloc((size_t)G->n * sizeof *G->fx);
    G->ongrid = calloc((size_t)G->n, 1);
    G->dwhole = calloc((size_t)G->n, 1);
    G->settled = calloc((size_t)G->n, 1);
    G->moved = calloc((size_t)G->n, 1);
    G->calm = calloc((size_t)G->n, sizeof *G->calm);
    G->fy = malloc((size_t)G->n * sizeof *G->fy);
    G->cx0 = malloc((size_t)G->n * sizeof *G->cx0);
    G->cx1 = malloc((size_t)G->n * sizeof *G->cx1);
    G->cy0 = malloc((size_t)G->n * sizeof *G->cy0);
    G->cy1 = malloc((size_t)G->n * sizeof *G->cy1);
    G->A = malloc(np * np * sizeof *G->A);
    G->M = malloc(np * np * sizeof *G->M);
    G->g = malloc(np * sizeof *G->g);
    G->step = malloc(np * sizeof *G->step);
    G->psave = malloc(np * sizeof *G->psave);
    G->sx = malloc(np * sizeof *G->sx);
    return !G->psave || !G->sx || !G->scr || !G->ongrid || !G->dwhole || !G->settled || !G->moved || !G->calm || !G->stail || !G->fx || !G->fy || !G->cx0 || !G->cx1 || !G->cy0 || !G->cy1 || !G->p || !G->pt || !G->A || !G->M || !G->g || !G->step;
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

/* The lowest sky the members carry (an earlier fit's SKY_PSF, else
 * find's BACKGROUND), the star light of a crowded group left out; NaN
 * when no member has one.  For the sky's floor a frame fit gives the sky
 * its stars were found on instead (mp_fit_opts.sky_known): a blend's
 * fitted sky errs high. */
static double known_sky(const mp_star *st, int n)
{
    double s = INFINITY;
    for (int k = 0; k < n; k++)
        if (isfinite(st[k].sky) && st[k].sky < s)
            s = st[k].sky;
    return isfinite(s) ? s : NAN;
}

/* The sky order to fit first: the one asked for; under auto, constant,
 * or with o->warm_sky the highest its stars were last fitted with (a star
 * never fitted reads 0).  Not when a star's last fit did not converge:
 * it starts again from constant (a fit cut short on a close pair is not
 * one of those: frame_group.c clears the flag for the fit after it).  A
 * saturated star's group once started from constant as well, so that a
 * saturated core's fragments merged
 * (session 20: the segmented scene with its PSF built, 54 false entries,
 * ~100 when such groups kept their order); since the plateau is kept as
 * one star from the first detection (pipeline/prescreen.c, session 21)
 * there are no fragments to merge, and the warm start leaves that
 * scene's false entries where they were (beside a saturated star 231 →
 * 232 over its nine runs) while 47 Tuc's refits stopped climbing from
 * constant every time (bench/PROFILE.md, session 46). */
static int first_order(const mp_fit_opts *o, const mp_star *st, int n)
{
    if (o->sky_order == MP_SKY_AUTO) {
        int w = 0, warm = o->warm_sky && o->fit_sky;
        for (int k = 0; k < n && warm; k++) {
            if (st[k].flags & MP_FLAG_NOCONV)
                return 0;
            w = st[k].sky_order > w && st[k].sky_order <= MP_SKY_MAXORDER ? st[k].sky_order : w;
        }
        return w;
    }
    return o->sky_order < 0 ? 0 : (o->sky_order > MP_SKY_MAXORDER ? MP_SKY_MAXORDER : o->sky_order);
}

/* Σ (d − m)²/V over the group's fitted pixels within r of (x, y) (all
 * of them when r is not finite), as a reduced χ² with n − 3 degrees of
 * freedom (the star's flux and position; the sky is the group's): the
 * star's own χ², DAOPHOT's CHI².  0 and 0 with 3 pixels or fewer. */
static void own_disc_chi2(const group *G, double r, double x, double y, double *chi2, int *dof)
{
    double c = 0.0;
    long n = 0;
    for (int q = 0; q < G->nrun; q++) {
        double dy = (double)(G->by0 + G->rj[q]) - y;
        for (int i = G->ri0[q]; i < G->ri1[q]; i++) {
            double dx = (double)(G->bx0 + i) - x;
            if (isfinite(r) && dx * dx + dy * dy > r * r)
                continue;
            size_t o = (size_t)G->rp[q] + (size_t)(i - G->ri0[q]);
            double d = G->dat[o] - G->mod[o];
            c += d * d / G->var[o];
            n++;
        }
    }
    *dof = n > 3 ? (int)(n - 3) : 0;
    *chi2 = *dof > 0 ? c / *dof : 0.0;
}

/* Star k's outputs from the converged state and the covariance in G->M:
 * its values, errors, χ² of the group (chi2f over dof), the performance
 * model's prediction and the flags.  Nonzero when out of memory. */
static int store_star(group *G, int k, mp_star *s, int converged, int cv, double chi2f, int dof,
                      int iter, int order, double fitrad)
{
    int n = G->n, np = G->np;
    double out[6] = {G->p[3 * k + 1], G->p[3 * k + 2], G->p[3 * k],
                     sqrt(G->M[(size_t)(3 * k + 1) * np + 3 * k + 1]),
                     sqrt(G->M[(size_t)(3 * k + 2) * np + 3 * k + 2]),
                     sqrt(G->M[(size_t)(3 * k) * np + 3 * k])};
    double skyv = sky_at(G, G->p, out[0], out[1]);
    double c[6], vs = 0.0;
    sky_basis(G, out[0], out[1], c);
    for (int a = 0; a < G->nsky; a++)
        for (int b = 0; b < G->nsky; b++)
            vs += c[a] * c[b] * G->M[(size_t)(3 * n + a) * np + 3 * n + b];
    s->npix = (int)G->npix;
    if (!converged)
        s->flags |= MP_FLAG_NOCONV;
    if (cv)
        s->flags |= MP_FLAG_MERGED;
    if (!all_finite(out, 6) || !isfinite(skyv) || !isfinite(vs) || !isfinite(chi2f)) {
        s->flags |= MP_FLAG_NOCONV;
        return 0;                 /* keep the start values */
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
    own_disc_chi2(G, fitrad, s->x, s->y, &s->chi2star, &s->dofstar);
    s->niter = iter;
    s->sky_order = order;
    /* The performance model wants the whole PRF, not the fitted window. */
    if (G->stats)
        return mp_star_model_errors(G->m, G->f->rdnoise, s, &G->work);
    memset(&s->st, 0, sizeof s->st);
    s->fluxerr_model = s->poserr_model = 0.0;
    return 0;
}

/* The start: fluxes, positions and the sky in G->p, the renders of every
 * star there, and a flux from the data for a star that has none.
 * Nonzero when out of memory. */
static int start_state(group *G, const mp_star *stars, double sky)
{
    int n = G->n;
    for (int k = 0; k < n; k++) {
        G->p[3 * k] = stars[k].flux;
        G->p[3 * k + 1] = stars[k].x;
        G->p[3 * k + 2] = stars[k].y;
    }
    G->p[3 * n] = sky;
    for (int a = 3 * n + 1; a < G->npmax; a++)
        G->p[a] = 0.0;
    if (lm_render_all(G, G->p, G->cur, RENDER_ALL))
        return 1;
    /* A start flux the fit could not take (none, not positive, or beyond
     * the largest it allows, emax: a table's FLUX of 1e30 on a 5e4 e-
     * star ended rejected, 1e200 overflowed its normal equations) is the
     * data's own. */
    for (int k = 0; k < n; k++)
        if (!(isfinite(G->p[3 * k]) && G->p[3 * k] > 0 && G->p[3 * k] <= G->emax))
            G->p[3 * k] = start_flux(G, &G->cur[k], sky);
    return 0;
}

/* A warm start's sky (o->warm_sky, order above constant): the polynomial
 * through its stars' last fitted sky values at their positions, by least
 * squares, when at least as many stars as terms carry one (a group fitted
 * before at this order gets its own polynomial back, so the LM need not
 * find the higher terms again from zero).  Else, or when that sky
 * leaves the bounds a step must keep somewhere on the group's pixels (a
 * polynomial through a few stars, far off between them), the start stays
 * a constant. */
static void warm_sky_start(group *G, const mp_star *st)
{
    int n = G->n, ns = G->nsky, m = 0;
    double N[36] = {0}, b[6] = {0}, c[6];
    for (int k = 0; k < n; k++) {
        if (!isfinite(st[k].sky))
            continue;
        sky_basis(G, st[k].x, st[k].y, c);
        for (int a = 0; a < ns; a++) {
            b[a] += c[a] * st[k].sky;
            for (int e = 0; e < ns; e++)
                N[a * ns + e] += c[a] * c[e];
        }
        m++;
    }
    if (m < ns || mp_spd_solve(N, ns, b) != 0 ||
        !all_finite(b, ns))
        return;
    double c0[6];
    memcpy(c0, G->p + 3 * n, (size_t)ns * sizeof *c0);
    memcpy(G->p + 3 * n, b, (size_t)ns * sizeof *b);
    lm_model_of(G, G->p, G->cur);
    if (!lm_sky_in_bounds(G))
        memcpy(G->p + 3 * n, c0, (size_t)ns * sizeof *c0);
}

/* The sky order set: its terms counted, the new ones at zero when it
 * rises (the buffers swap with the trial state, whose slots past the old
 * order were never written). */
static void set_order(group *G, int order)
{
    int n = G->n;
    for (int a = 3 * n + G->nsky; a < 3 * n + nsky_of(order); a++)
        G->p[a] = 0.0;
    G->nsky = nsky_of(order);
    G->np = 3 * n + G->nsky;
}

/* The fit at the first sky order, then, under MP_SKY_AUTO, the order
 * raised while the score test at the converged lower-order fit says the
 * extra terms are needed, going on from the current state (the new terms
 * start at zero, so the model does not change).
 *
 * A sky order whose loop stalls on the sky's bounds (levmar.c,
 * LM_SKY_STALL: D still falls as the polynomial leaves the data's range
 * at some fitted pixel, so no minimum lies within them and the step test
 * can never be met) is not kept: the group goes back to the converged
 * lower-order state it rose from, or, when the stalled order was a warm
 * start's, starts again from a constant sky below it (47 Tuc 256², PSF
 * built from the frame: 2 groups of 26 and 42 stars crawled to maxiter
 * with λ at 1e5-1e8; GLIMPSE: one of 53).  A loop that ends on a close
 * pair (G->paired, o->stop_pair) ends the fit there: the frame fit merges
 * the pair and fits the group again.  Nonzero when out of memory. */
static int fit_orders(group *G, const mp_fit_opts *o, const mp_star *stars, double sky,
                      int *order, int *iter, int *converged)
{
    int cap = MP_SKY_MAXORDER;
    if (lm_levmar(G, o, 0, iter, converged))
        return 1;
    if (G->paired)
        return 0;               /* the caller merges the pair and fits again */
    if (!*converged && G->skystall && *order > 0) {
        cap = *order - 1;
        *order = 0;
        set_order(G, 0);
        if (start_state(G, stars, sky) || lm_levmar(G, o, 0, iter, converged))
            return 1;
    }
    while (o->fit_sky && o->sky_order == MP_SKY_AUTO && *converged && *order < cap) {
        int to;
        if (lm_higher_order(G, *order, o->fitrad, &to))
            return 1;
        if (to < 0)
            break;
        int from = *order;
        memcpy(G->psave, G->p, (size_t)G->np * sizeof *G->psave);
        set_order(G, to);
        *order = to;
        if (lm_levmar(G, o, o->reuse_pairs, iter, converged))
            return 1;
        if (G->paired)
            return 0;
        if (*converged || !G->skystall)
            continue;
        *order = from;
        set_order(G, from);
        memcpy(G->p, G->psave, (size_t)G->np * sizeof *G->p);
        if (lm_render_all(G, G->p, G->cur, RENDER_ALL) || lm_levmar(G, o, 0, iter, converged))
            return 1;
        break;
    }
    return 0;
}

/* A fit that stopped unconverged with stars drawn bilinearly (or beyond
 * a cubic core), continued from where it stopped with every star drawn
 * cubically: the bilinear PRF bends at every grid phase (its derivatives
 * are the grid's, smooth), which can keep LM's last steps from meeting
 * tol (GLIMPSE built: a 28-star group at maxiter that converged
 * cubically).  Nonzero when out of memory. */
static int cubic_again(group *G, const mp_fit_opts *o, int *iter, int *converged)
{
    if (*converged || G->paired)
        return 0;
    int lin = 0;
    for (int k = 0; k < G->n; k++)
        if (G->ongrid[k] > GRID_CUBIC) {    /* bilinear, or beyond a core */
            G->ongrid[k] = GRID_CUBIC;
            lin = 1;
        }
    if (!lin)
        return 0;
    return lm_render_all(G, G->p, G->cur, RENDER_ALL) || lm_levmar(G, o, 0, iter, converged);
}

/* G set up for n stars of model m on frame f, its sky at the given
 * order (the options' crop, grid and statistics; its parameter counts). */
static void group_setup(group *G, const mp_frame *f, const mp_prf_model *m, const mp_fit_opts *o,
                        int n, int order)
{
    memset(G, 0, sizeof *G);
    G->f = f;
    G->m = m;
    G->crop = isfinite(o->fitrad) ? o->crop : NULL;
    G->work.grid = o->grid;     /* every render of the group through G->work */
    G->stats = o->stats;
    G->weak_pairs = o->weak_pairs;
    G->crop_min = o->fitrad + 1.0;
    G->core_hw = G->crop_min;   /* NaN (whole frame): every pass exact */
    G->n = n;
    G->nsky = o->fit_sky ? nsky_of(order) : 0;
    G->np = 3 * n + (G->nsky ? G->nsky : 1);   /* a fixed sky still has a slot */
    G->npmax = 3 * n + nsky_of(MP_SKY_MAXORDER);
    G->ron2 = f->rdnoise * f->rdnoise > 1e-2 ? f->rdnoise * f->rdnoise : 1e-2;
}

/* A group with too few pixels to fit: every star flagged not converged
 * and at the edge, its errors and χ² zero, a NaN flux or sky zero. */
static void flag_unfitted(mp_star *stars, int n)
{
    for (int k = 0; k < n; k++) {
        mp_star *s = &stars[k];
        s->flags |= MP_FLAG_NOCONV | MP_FLAG_EDGE;
        s->ex = s->ey = s->eflux = s->esky = 0.0;
        s->chi2 = s->chi2star = 0.0;
        s->dof = s->dofstar = 0;
        if (!isfinite(s->flux))
            s->flux = 0.0;
        if (!isfinite(s->sky))
            s->sky = 0.0;
    }
}

/* The fit of G's stars from their start (sky0, or the group's own), its
 * covariance, and every star's results stored.  Nonzero when out of
 * memory. */
static int fit_and_store(group *G, const mp_fit_opts *o, mp_star *stars, double sky0, int order)
{
    int n = G->n;
    double sky = isfinite(sky0) ? sky0 : start_sky(G);
    /* S of the variance function, and the sky's lower bound: a group's own
     * median is neither (in a crowded group it sits well above the sky,
     * and a floor above the sky reweights every sky pixel).  The bound
     * from the sky the stars were found on when the caller knows it
     * (mp_fit_opts.sky_known); S stays the members' own: from BACKGROUND
     * too, GLIMPSE with IRAC's table had 58 catalog stars with a second
     * entry within 1.5 px against 53, its flux rσ 0.087 against 0.081,
     * and from BACKGROUND where a member had no sky of its own, 47 Tuc
     * built 20 stars not converged against none. */
    double own = known_sky(stars, n);
    G->sknown = isfinite(o->sky_known) ? o->sky_known : own;
    G->vfloor = own > 0 ? own : 0.0;
    int converged = 0, iter = 0;
    /* Economy: a star brighter than the grid's bound is drawn exactly
     * (its own bias bound, fit/prf_cache.c), the others from the grid. */
    G->tiers = o->grid_tiers;
    for (int k = 0; k < n; k++)
        G->ongrid[k] = fabs(stars[k].flux) > o->grid_emax ||
                               !mp_prf_cache_covers(o->grid, G->m, stars[k].x, stars[k].y)
                           ? 0
                           : (uint8_t)(1 + mp_prf_tier_mode(&G->tiers, stars[k].flux));
    if (start_state(G, stars, sky))
        return 1;
    if (order > 0 && o->warm_sky)
        warm_sky_start(G, stars);
    if (fit_orders(G, o, stars, sky, &order, &iter, &converged) ||
        (!converged && cubic_again(G, o, &iter, &converged)))
        return 1;
    int cv = covariance(G);
    if (cv == 2)
        return 1;
    double chi2f = lm_chi2_with(G, G->var);
    int dof = (int)G->npix - (3 * n + G->nsky);
    for (int k = 0; k < n; k++)
        if (store_star(G, k, &stars[k], converged, cv, chi2f, dof, iter, order, o->fitrad))
            return 1;
    return 0;
}

int mp_fit_group(const mp_frame *f, const mp_prf_model *m, const mp_fit_opts *o,
                 double sky0, mp_star *stars, int n, char *err)
{
    group G;
    int order = first_order(o, stars, n);
    group_setup(&G, f, m, o, n, order);
    for (int k = 0; k < n; k++) {
        stars[k].flags = 0;
        stars[k].niter = 0;
        stars[k].chi2star = 0.0;
        stars[k].dofstar = 0;
        stars[k].sky_order = order;
    }
    int rc = 0;
    int sp = lm_select_pixels(&G, o, stars);
    data_range(&G);
    if (sp == 2 || alloc_stars(&G))
        rc = 1;
    else if (sp == 1 || G.npix <= (size_t)(3 * n + G.nsky))
        flag_unfitted(stars, n);
    else
        rc = fit_and_store(&G, o, stars, sky0, order);
    if (rc)
        snprintf(err, MP_ERRLEN, "fit: out of memory for a group of %d stars", n);
    if (o->work)
        *o->work += G.work.ops;     /* the exact renders' work (economy's plan) */
    group_free(&G);
    return rc;
}
