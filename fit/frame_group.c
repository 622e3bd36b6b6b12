/* frame_group.c — one group of a frame fitted as ALLSTAR does: close
 * pairs merged, insignificant stars rejected, the group refitted after
 * each change (anchors.md §1.6). */

#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include "fit/frame_priv.h"

double mp_prf_fwhm(const mp_prf_model *m)
{
    mp_prf_stats st;
    /* A variable PSF: its FWHM at the field's origin. */
    const mp_psf_field *fd = m->psf->field;
    int var = fd && fd->order > 0;
    double cx = var ? round(fd->x0) : 100.0, cy = var ? round(fd->y0) : 100.0;
    if (mp_prf_stats_at(m, cx, cy, &st, NULL) || !(st.lscale > 0))
        return 3.0;      /* out of memory: DAOPHOT's usual FWHM keeps find and merge going */
    return 2.0 * sqrt(2.0 * log(2.0)) * st.lscale;
}

double mp_merge_sig(double minsnr)
{
    return minsnr > 0 ? fmax(minsnr, 2.0) : INFINITY;
}

/* Two stars to merge: not significantly separated (d < 2 σ of their
 * separation), or closer than mergerad unless their separation is
 * significant at the level the one-or-two test proposes a second star at
 * (d ≥ sig·σ: Δχ² ≥ minsnr², pipeline/split.c; σ widened by the discs'
 * misfit).  A pair that well resolved is two stars, whatever the merge
 * radius: on the segmented scene of make validate (CROWDED.md) a
 * 0.58-FWHM pair of −13.6 and −12.8 mag, separated by 67 σ, was merged
 * (mergerad is 0.4 of the PSF's noise-equivalent width, which its rings
 * and spikes widen), and the merged star's residual was taken for a star
 * 6 px away. */
typedef struct { int a, b; double d; } merge_pair;

static int by_distance(const void *p, const void *q)
{
    double x = ((const merge_pair *)p)->d, y = ((const merge_pair *)q)->d;
    return (x > y) - (x < y);
}

/* Merge pair (a, b): the brighter survives at the flux-weighted mean
 * position with the summed flux. */
static void merge_pair_into(mp_star *s, int *alive, int a, int b)
{
    if (s[b].flux > s[a].flux) {
        int t = a;
        a = b;
        b = t;
    }
    double fa = fmax(s[a].flux, 0.0), fb = fmax(s[b].flux, 0.0), ft = fa + fb;
    if (ft > 0) {
        s[a].x = (fa * s[a].x + fb * s[b].x) / ft;
        s[a].y = (fa * s[a].y + fb * s[b].y) / ft;
    }
    s[a].flux = s[a].flux + s[b].flux;
    s[a].flags |= MP_FLAG_MERGED;
    alive[b] = 0;
}

/* The pairs to merge, closest first; *np of them (NULL when there are
 * none or out of memory: *np then says which, 0 or -1). */
static merge_pair *merge_candidates(const mp_star *s, const int *alive, int n, double mergerad,
                                    double sig, double slack, int *np)
{
    merge_pair *p = NULL;
    int m = 0, cap = 0;
    *np = 0;
    for (int i = 0; i < n; i++)
        for (int j = i + 1; j < n; j++) {
            if (!alive[i] || !alive[j])
                continue;
            double es = sqrt(s[i].ex * s[i].ex + s[i].ey * s[i].ey + s[j].ex * s[j].ex +
                             s[j].ey * s[j].ey);
            double d = hypot(s[i].x - s[j].x, s[i].y - s[j].y) + slack * es;
            /* Within mergerad the separation's σ is widened by the misfit
             * of the pair's own discs, as least squares does (√(χ²/dof)
             * when above 1): a companion that only takes up a PSF's error
             * is not kept by its formal σ. */
            double phi = fmax(1.0, fmax(s[i].chi2star, s[j].chi2star));
            if (!(d < 2.0 * es || (d < mergerad && !(d >= sig * es * sqrt(phi)))))
                continue;
            if (m == cap) {
                cap = cap ? 2 * cap : 8;
                merge_pair *q = realloc(p, (size_t)cap * sizeof *q);
                if (!q) {
                    free(p);
                    *np = -1;
                    return NULL;
                }
                p = q;
            }
            p[m++] = (merge_pair){i, j, d};
        }
    if (m > 1)      /* (p is NULL when there is none: qsort's pointer must not be) */
        qsort(p, (size_t)m, sizeof *p, by_distance);
    *np = m;
    return p;
}

/* Merge the group's close pairs; the number merged.  The closest pair
 * goes first (ALLSTAR's order), and with it, in the same step, every
 * other pair whose stars lie sepind [px] or more from the stars of every
 * pair merged before it — as reject_low does, for the same reason: beyond
 * sepind (2 FWHM) a merge leaves the other pair's fit as it was, and a
 * group's fit with a pair about to merge does not converge (frame C of
 * compare_daophot.sh, one merge a refit: a group of 58 fitted 13 times,
 * the first 7 stopped at maxiter 50; its round 2 took 22.5 s, 9.7 s
 * now).  Pairs nearer a merge wait for the refit. */
static int merge_close(mp_star *s, int *alive, int n, double mergerad, double sig, double sepind)
{
    int np;
    merge_pair *p = merge_candidates(s, alive, n, mergerad, sig, 0.0, &np);
    int *locked = p ? calloc((size_t)n, sizeof *locked) : NULL;
    if (np > 0 && !locked) {    /* out of memory: the closest pair alone */
        merge_pair_into(s, alive, p[0].a, p[0].b);
        free(p);
        return 1;
    }
    int nm = 0;
    double x[2], y[2];
    for (int k = 0; k < np; k++) {
        int a = p[k].a, b = p[k].b;
        if (locked[a] || locked[b])
            continue;
        x[0] = s[a].x;
        y[0] = s[a].y;
        x[1] = s[b].x;
        y[1] = s[b].y;
        for (int i = 0; i < n; i++)
            for (int e = 0; e < 2; e++)
                locked[i] |= hypot(s[i].x - x[e], s[i].y - y[e]) < sepind;
        merge_pair_into(s, alive, a, b);
        nm++;
    }
    free(locked);
    free(p);
    return nm;
}

/* A star's S/N.  One without an error was not fitted (its group had too
 * few pixels: off the frame or masked, fit_group.c flag_unfitted): it has
 * no S/N, so it is below any cut.  (As +inf, it had passed every cut:
 * GLIMPSE kept a star 7 px beyond the frame's edge, found from a
 * truncated profile, at 3.5e5 e- with every error 0.) */
static double snr_of(const mp_star *s)
{
    return s->eflux > 0 ? s->flux / s->eflux : -INFINITY;
}

/* Whether a fit stopped at tol (× each parameter's σ) may leave a merge
 * or a rejection that the fit to its end would not make: a star whose
 * S/N lies within tol below minsnr (its flux may still move by tol σ), a
 * pair that merge_close merges but not with its separation tol of its σ
 * wider (out of memory: yes). */
static int decision_pending(const mp_star *s, const int *alive, int n, double mergerad,
                            double sig, double minsnr, double tol)
{
    for (int i = 0; minsnr > 0 && i < n; i++)
        if (alive[i] && snr_of(&s[i]) < minsnr && snr_of(&s[i]) >= minsnr - tol)
            return 1;
    if (!(mergerad > 0))
        return 0;
    int np, nsure;
    free(merge_candidates(s, alive, n, mergerad, sig, 0.0, &np));
    free(merge_candidates(s, alive, n, mergerad, sig, tol, &nsure));
    return np < 0 || nsure < 0 || nsure < np;
}

/* Flag merged (16) the live star nearest to star w within 2·mergerad: a
 * star rejected beside a neighbour was most likely half of an unresolved
 * blend whose light the neighbour now carries. */
static void flag_blend_partner(mp_star *s, const int *alive, int n, int w, double mergerad)
{
    int near = -1;
    double best = 2.0 * mergerad;
    for (int i = 0; i < n; i++) {
        double d = hypot(s[i].x - s[w].x, s[i].y - s[w].y);
        if (alive[i] && d < best) {
            best = d;
            near = i;
        }
    }
    if (near >= 0)
        s[near].flags |= MP_FLAG_MERGED;
}

/* Reject the stars below minsnr; the number rejected.  Deep detection
 * hands the fit many candidates below the cut, so they go in one step
 * rather than one refit each (a 2-sigma find: 9188 rejections, fit 104 s
 * -> see the commit): a below-cut star goes when no less significant
 * below-cut star lies within sepind [px] of it.  Beyond sepind (2 FWHM)
 * their PRFs barely overlap, so removing one leaves the other's S/N as
 * it was; within it, only the worse goes, and the other is judged again
 * after the refit (half of a split star may climb above the cut). */
static int reject_low(mp_star *s, int *alive, int n, double minsnr, double mergerad,
                      double sepind)
{
    int *gone = calloc((size_t)n, sizeof *gone), nr = 0;
    for (int i = 0; i < n; i++) {
        if (!alive[i])
            continue;
        double si = snr_of(&s[i]);
        if (!(si < minsnr))
            continue;
        int worst = 1;
        for (int j = 0; j < n && worst; j++) {
            if (j == i || !alive[j] || hypot(s[i].x - s[j].x, s[i].y - s[j].y) >= sepind)
                continue;
            double sj = snr_of(&s[j]);
            worst = !(sj < si || (sj == si && j < i));
        }
        if (!gone) {            /* out of memory: one at a time, as before */
            if (worst) {
                alive[i] = 0;
                flag_blend_partner(s, alive, n, i, mergerad);
                return 1;
            }
            continue;
        }
        gone[i] = worst;
    }
    for (int i = 0; gone && i < n; i++)
        if (gone[i]) {
            alive[i] = 0;
            nr++;
        }
    for (int i = 0; gone && i < n; i++)
        if (gone[i])
            flag_blend_partner(s, alive, n, i, mergerad);
    free(gone);
    return nr;
}

/* Whether the fit of s[0..n) may have stopped on a pair within r
 * (mp_fit_opts.stop_pair): a star did not converge and two lie closer
 * than r. */
static int stopped_on_pair(const mp_star *s, int n, double r)
{
    int noconv = 0;
    for (int k = 0; k < n; k++)
        noconv |= (s[k].flags & MP_FLAG_NOCONV) != 0;
    for (int a = 0; noconv && a < n; a++)
        for (int b = a + 1; b < n; b++)
            if (hypot(s[a].x - s[b].x, s[a].y - s[b].y) < r)
                return 1;
    return 0;
}

/* Economy's choices for a group whose brightest star has flux e: the
 * table (level l, R->nss for the model's own), its sinc half-width, and
 * the phase grid with its per-star flux limit and tiers. */
typedef struct {
    double e;               /* the flux they were made for */
    int l, hw;
    const mp_prf_cache *grid;
    double gemax;
    mp_prf_tiers tiers;
} group_choice;

static group_choice choice_for(const mp_prf_model *m, const mp_frame_opts *o, const frame_rules *R,
                               double e, mp_frame_report *rep)
{
    group_choice c;
    c.e = e;
    /* A group the model's phase grid serves whole is drawn from it: as
     * cheap as a coarser level's grid, and from the finer table.  The
     * coarser levels are for the brighter groups. */
    c.l = ff_grid_serves(R, o->grid, e, rep) ? R->nss : 0;
    while (c.l < R->nss && !ff_level_serves(&R->level[c.l], e, rep))
        c.l++;
    c.hw = ff_kernel_for(&R->kern[c.l], c.l < R->nss ? R->ss[c.l].model.sinc_hw : m->sinc_hw, e,
                         rep);
    c.grid = ff_group_grid(R, o->grid, c.l, e, &c.gemax, &c.tiers, rep);
    return c;
}

/* Whether the fit of live[0..nl-1] (from start[map[k]]) ended with a star
 * brighter than the choices it was fitted with (used) hold: its fitted
 * flux would choose a finer table, a longer kernel or exact renders, or a
 * star drawn from the grid ended above the grid's limit.  Each choice's bias
 * bound holds for the flux it was made for only, and a start flux can be
 * far off: on frame V of validate/CROWDED.md stars found at 1e4 e- on a
 * saturated star's wings were fitted to 5e8 e- with a 7-tap kernel from
 * the grid.  *e takes the brightest fitted flux, if brighter. */
static int beyond_choice(const mp_prf_model *m, const mp_frame_opts *o, const frame_rules *R,
                         const group_choice *used, const mp_star *start, const int *map,
                         const mp_star *live, int nl, double *e, mp_frame_report *rep)
{
    int beyond = 0;
    double e1 = 0.0;
    for (int k = 0; k < nl; k++) {
        double a = fabs(start[map[k]].flux), b = fabs(live[k].flux);
        e1 = isfinite(b) && b > e1 ? b : e1;
        beyond |= used->grid && !(a > used->gemax) && b > used->gemax;
    }
    *e = e1 > *e ? e1 : *e;
    if (!(e1 > used->e))
        return beyond;
    /* More exact only: a group fitted with no start flux had the safe
     * side's choices (the table as given, the full kernel, no grid). */
    group_choice c = choice_for(m, o, R, e1, rep);
    return beyond || c.l > used->l ||
           (c.l == used->l && (c.hw > used->hw || (used->grid && !c.grid)));
}

/* A group's merge-and-reject loop (ff_fit_one_group): its rules and
 * where it stands. */
typedef struct {
    double mergerad, sig, sepind, minsnr;
    double tol, decide;     /* the fits' tol now; the deciding one */
    int paired;             /* the last fit stopped on a close pair */
    int unstopped;          /* fitted on past one */
    double ebright;         /* the brightest flux a fit of it reached */
    int nbright;            /* fits again for it (beyond_choice) */
    double skyfound;        /* the lowest sky its members were found on
                             * (mp_fit_opts.sky_known) */
} group_loop;

/* One LM fit of the live stars live[0..nl-1] of a group (on f, whose
 * coordinates are the frame's shifted by (dx, dy)), with economy's
 * choices for its brightest star (at least L's ebright): the coarsest
 * table and the shortest sinc kernel its bias bound allows, and the phase
 * grid when the bound serves it (choice_for; *used receives them);
 * stopped on a pair within mergerad unless L's unstopped; to L's tol, on
 * the sky its members were found on.  What it did is added to rep.
 * Nonzero with err on failure. */
static int fit_live(const mp_frame *f, const mp_prf_model *m, const mp_frame_opts *o,
                    double mergerad, const group_loop *L, const frame_rules *R, mp_star *live,
                    int nl, double dx, double dy, group_choice *used, mp_frame_report *rep,
                    char *err)
{
    double sky0 = nl == 1 ? live[0].sky : NAN;
    double e = L->ebright;
    for (int k = 0; k < nl; k++)
        e = isfinite(live[k].flux) && live[k].flux > e ? live[k].flux : e;
    *used = choice_for(m, o, R, e, rep);
    int l = used->l;
    mp_prf_model mh = l < R->nss ? R->ss[l].model : *m;
    /* The group is fitted on a sub-image offset by (dx, dy): a variable
     * PSF must still be read at each star's frame position (a run's
     * coarser level also at the sub-frame's, o->psfdx). */
    mp_psf lp;
    mp_psf_field lf;
    if (mh.psf->field) {    /* (a constant table keeps its pointer: the cache's key) */
        double ox = l < R->nss ? o->psfdx : 0.0, oy = l < R->nss ? o->psfdy : 0.0;
        mp_psf_local(mh.psf, dx + ox, dy + oy, &lp, &lf);
        mh.psf = &lp;
    }
    mh.sinc_hw = used->hw;
    rep->kcoarse += l < R->nss;
    mp_fit_opts fo = o->fit;
    fo.tol = L->tol;
    fo.stop_pair = mergerad > 0 && !L->unstopped ? mergerad : 0.0;   /* merged by the caller */
    fo.sky_known = L->skyfound;
    fo.grid = used->grid;
    fo.grid_emax = used->gemax;
    fo.grid_tiers = used->tiers;
    int cached = mp_prf_cache_usable(fo.grid, &mh);
    rep->kcache += cached;
    rep->kcalls++;
    rep->khw += mh.sinc_hw;
    rep->kshort += mh.sinc_hw < m->sinc_hw;
    double gops = 0.0;
    fo.work = &gops;
    if (mp_fit_group(f, &mh, &fo, sky0, live, nl, err))
        return 1;
    rep->iterations += live[0].niter;
    rep->render_ops += gops;
    rep->kstars += nl;
    for (int k = 0; cached && k < nl; k++) {
        int mode = mp_prf_tier_mode(&fo.grid_tiers, live[k].flux);
        rep->klin += mode == MP_PRF_BILINEAR;
        rep->kcore += mode >= MP_PRF_CORE(0);
    }
    /* What economy saved on this fit's renders (the plan's unit). */
    if (R->ops_full > 0) {
        double used = cached ? mp_econ_grid_render_ops(m, o->fit.fitrad)
                             : mp_econ_render_ops(&mh, mh.sinc_hw, o->fit.fitrad);
        rep->ops_saved += (live[0].niter + 1.0) * fmax(R->ops_full - used, 0.0) * nl;
    }
    return 0;
}

/* The live stars of s[0..n) copied into live (their indices in map);
 * returns how many. */
static int live_of(const mp_star *s, const int *alive, int n, mp_star *live, int *map)
{
    int nl = 0;
    for (int k = 0; k < n; k++)
        if (alive[k]) {
            live[nl] = s[k];
            map[nl++] = k;
        }
    return nl;
}

/* The group's stars back into the frame's states, in frame coordinates;
 * the live ones not converged counted in rep. */
static void store_back(star_state *st, const mp_star *s, const int *alive, int n, double dx,
                       double dy, mp_frame_report *rep)
{
    for (int k = 0; k < n; k++) {
        st[k].s = s[k];
        st[k].s.x += dx;
        st[k].s.y += dy;
        st[k].alive = alive[k];
        if (alive[k] && (s[k].flags & MP_FLAG_NOCONV))
            rep->noconv++;
    }
}

/* The lowest sky the live members st[map[0..nl-1]] were found on, NaN
 * when none was (fit_group.c known_sky). */
static double found_sky(const star_state *st, const int *map, int nl)
{
    double s = INFINITY;
    for (int k = 0; k < nl; k++)
        s = st[map[k]].sky_found < s ? st[map[k]].sky_found : s;
    return isfinite(s) ? s : NAN;
}

/* What follows a fit of the group's stars s[0..n): the fit again — to
 * the deciding tol, after merges, after rejections, or past a close pair
 * — its cause returned (MP_REFIT_*, with alive, L and rep's merges and
 * rejections updated), or −1: the group is done. */
static int next_fit(group_loop *L, mp_star *s, int *alive, int n, mp_frame_report *rep)
{
    /* A merge or a rejection is for good (the pipeline never adds a
     * star again where one went): a fit stopped at a tol above the
     * deciding one (a loose round's, o->loosetol, or the steps' own,
     * fit.tol above o->decidetol) that leaves one a fit to the end
     * might not make is fitted on first (decided at the loose tol,
     * the crowded frames lost 1-3 stars of 4 600 each; fitted on for
     * every merge and rejection, 47 Tuc kept 1/8 of the gain). */
    if (L->tol > L->decide && !L->paired &&
        decision_pending(s, alive, n, L->mergerad, L->sig, L->minsnr, L->tol)) {
        L->tol = L->decide;
        return MP_REFIT_DECIDE;
    }
    int nmerged = L->mergerad > 0 ? merge_close(s, alive, n, L->mergerad, L->sig, L->sepind) : 0;
    if (nmerged > 0) {
        rep->merged += nmerged;
        return MP_REFIT_MERGE;
    }
    int nrej = L->minsnr > 0 ? reject_low(s, alive, n, L->minsnr, L->mergerad, L->sepind) : 0;
    if (nrej > 0) {
        rep->rejected += nrej;
        return MP_REFIT_REJECT;
    }
    /* The fit stopped on a pair within mergerad (fit_live's stop_pair) that is
     * two stars after all (separated by sig σ or more): fitted again
     * to the end, once.  A group not converged for another reason
     * stays as it was (refitting those as well took GLIMPSE built's
     * LM iterations up 11 %, against 4 % for these alone, before the
     * misfit widening left it none). */
    if (L->paired) {
        L->unstopped = 1;
        return MP_REFIT_UNSTOPPED;
    }
    return -1;
}

/* Fit one group (members st[0..n-1]) on frame f: merge/reject until
 * stable.  Local copies of the stars move in the frame's coordinates
 * shifted by (dx, dy). */
int ff_fit_one_group(const mp_frame *f, const mp_prf_model *m, const mp_frame_opts *o,
                         double mergerad, const frame_rules *R, star_state *st, int n, double dx, double dy,
                         mp_frame_report *rep, char *err)
{
    mp_star *s = malloc((size_t)n * sizeof *s), *live = malloc((size_t)n * sizeof *live);
    int *alive = malloc((size_t)n * sizeof *alive), *map = malloc((size_t)n * sizeof *map);
    int rc = 1;
    if (!s || !live || !alive || !map) {
        snprintf(err, MP_ERRLEN, "out of memory");
        goto done;
    }
    for (int k = 0; k < n; k++) {
        s[k] = st[k].s;
        s[k].x -= dx;
        s[k].y -= dy;
        alive[k] = st[k].alive;     /* merged or rejected in an earlier pass: stays out */
    }
    group_loop L = {
        .mergerad = mergerad,
        .sig = mp_merge_sig(o->minsnr),
        /* 2 FWHM: 5 default merge radii (0.4 FWHM), or from the PSF
         * when merging is off */
        .sepind = mergerad > 0 ? 5.0 * mergerad : 2.0 * mp_prf_fwhm(m),
        .minsnr = o->minsnr,
        .tol = fmax(o->fit.tol, o->loosetol),
        .decide = o->decidetol > 0 ? fmin(o->fit.tol, o->decidetol) : o->fit.tol,
    };
    /* Each round removes a star or ends (one more may refit unstopped,
     * one more to the run's tol, two more fitted brighter), so n + 5
     * rounds suffice. */
    int cause = -1;                 /* why this fit is one again (MP_REFIT_*) */
    for (int round = 0; round <= n + 4; round++) {
        int nl = live_of(s, alive, n, live, map);
        if (nl == 0)
            break;
        L.skyfound = found_sky(st, map, nl);
        /* A fit cut short on a close pair was not a failed one: the fit
         * after it (the pair merged, a star rejected, or unstopped) starts
         * at the sky order it had, not from constant (fit_group.c
         * first_order).  From
         * constant, each climbed again to the order it had left (47 Tuc
         * built: ~200 such refits a run, 13 LM steps each). */
        for (int k = 0; L.paired && k < nl; k++)
            live[k].flags &= ~MP_FLAG_NOCONV;
        long steps = rep->iterations;
        group_choice used;
        if (fit_live(f, m, o, mergerad, &L, R, live, nl, dx, dy, &used, rep, err))
            goto done;
        if (cause >= 0) {
            rep->refits[cause]++;
            rep->refit_steps[cause] += rep->iterations - steps;
        }
        /* Fitted brighter than its choices hold: again, with the fitted
         * flux's (each more exact; twice at most), before any merge or
         * rejection is decided on it. */
        int again = beyond_choice(m, o, R, &used, s, map, live, nl, &L.ebright, rep) &&
                    L.nbright < 2;
        L.paired = mergerad > 0 && !L.unstopped && stopped_on_pair(live, nl, mergerad);
        for (int k = 0; k < nl; k++) {
            int keep = s[map[k]].flags & MP_FLAG_MERGED;
            s[map[k]] = live[k];
            s[map[k]].flags |= keep;
        }
        if (again) {
            L.nbright++;
            cause = MP_REFIT_BRIGHTER;
            continue;
        }
        if ((cause = next_fit(&L, s, alive, n, rep)) < 0)
            break;
    }
    store_back(st, s, alive, n, dx, dy, rep);
    rc = 0;
done:
    free(s);
    free(live);
    free(alive);
    free(map);
    return rc;
}

/* The window a group's fit reads: its stars ± fitrad, one pixel of margin
 * (so the fitter's edge test sees only the frame's real edges), clipped. */
void ff_group_window(const mp_frame *f, const star_state *st, int n, double r,
                         long *x0, long *y0, long *w, long *h)
{
    if (!isfinite(r)) {
        *x0 = *y0 = 1;
        *w = f->im.nx;
        *h = f->im.ny;
        return;
    }
    double xa = INFINITY, xb = -INFINITY, ya = INFINITY, yb = -INFINITY;
    for (int k = 0; k < n; k++) {
        xa = fmin(xa, st[k].s.x);
        xb = fmax(xb, st[k].s.x);
        ya = fmin(ya, st[k].s.y);
        yb = fmax(yb, st[k].s.y);
    }
    long a = (long)floor(xa - r) - 1, b = (long)ceil(xb + r) + 1;
    long c = (long)floor(ya - r) - 1, d = (long)ceil(yb + r) + 1;
    a = a < 1 ? 1 : a;
    c = c < 1 ? 1 : c;
    b = b > f->im.nx ? f->im.nx : b;
    d = d > f->im.ny ? f->im.ny : d;
    *x0 = a;
    *y0 = c;
    *w = b >= a ? b - a + 1 : 0;
    *h = d >= c ? d - c + 1 : 0;
}
