/* fit_frame.c — fitting every star of a table on one frame as ALLSTAR does
 * (anchors.md §1.6): groups fitted simultaneously, in parallel, each on a
 * local copy of its pixels from which the light of every other star has
 * been subtracted; close pairs merged and insignificant stars rejected, the
 * group refitted after each change. */
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include "fit/econ_state.h"

void mp_frame_opts_default(mp_frame_opts *o)
{
    mp_fit_opts_default(&o->fit);
    o->fit.fitrad = 5.0;
    o->magzero = 0.0;
    o->mergerad = NAN;
    o->minsnr = 2.0;
    o->passes = 2;
    o->cropfrac = 0.02;
    o->refittol = 0.1;
    o->sinc = NULL;
    o->sincfrac = 0.1;
    o->grid = NULL;
    o->ss = NULL;
    o->nss = 0;
    o->ss_sinc = ~0;
    o->ssfrac = 0.1;
    o->cache = NULL;
    o->fits = 0.0;
    o->learn = 0;
    o->psfdx = o->psfdy = 0.0;
}

/* Column of a table by the first name present, -1 if none. */
static int col_any(const mp_table *t, const char *a, const char *b)
{
    int c = mp_table_col(t, a);
    return c >= 0 ? c : (b ? mp_table_col(t, b) : -1);
}

/* The state of one star through the passes. */
typedef struct {
    mp_star s;          /* current estimate (global coordinates) */
    double id;          /* group id */
    long row;
    double number;      /* NUMBER (the memory's key across calls), or row */
    int alive;
    /* Economy: the light of every other star on the pixels around this one
     * (its fitting region and a pixel more) when it was last fitted, a
     * square of side sw at (sx0, sy0); NULL: not fitted yet. */
    float *seen;        /* single precision, as the frame (issue 14) */
    long sx0, sy0;
    int sw;
} star_state;

static int cmp_group(const void *a, const void *b)
{
    const star_state *x = a, *y = b;
    if (x->id != y->id)
        return (x->id > y->id) - (x->id < y->id);
    return (x->row > y->row) - (x->row < y->row);
}

typedef mp_prf_crop crop_rule;

/* Economy's kernel choice on one frame (fit/sinc_choice.c): each group gets
 * the shortest half-width whose bound at its brightest star is ≤ frac on
 * the frame's sky.  With many groups the flux limits of every half-width
 * are found once (emax, MP_SINC_LIMITS_EVALS bound evaluations each);
 * with few, each group evaluates the bound itself (≤ hwmax evaluations),
 * so the choice never costs more bound evaluations than
 * min(groups, MP_SINC_LIMITS_EVALS) · hwmax per pass. */
typedef struct {
    const mp_sinc_choice *c;   /* NULL: every group with the model's sinc_hw */
    double *emax;              /* the limits, or NULL: evaluate per group */
    int owned;                 /* emax is this rule's (else the cache's) */
    double sky, ron, frac;
} kernel_rule;

/* The table's choice (fit/ss_choice.c): whether a coarser sampling serves
 * the group's brightest star, from its flux limit on the frame's sky (found
 * once, as the kernel's) or, with few groups, evaluated per group. */
typedef struct {
    const mp_ss_level *lv;     /* NULL: never serves */
    double emax;               /* the limit, or NAN: evaluate per group */
    double sky, ron, frac;
} level_rule;

/* level[l] says whether ss[l] serves a flux, kern[l] is the kernel choice
 * of ss[l]'s model, kern[nss] that of the model as given. */
typedef struct {
    const mp_ss_level *ss;
    int nss;
    level_rule level[MP_SS_MAXLEVELS];
    kernel_rule kern[MP_SS_MAXLEVELS + 1];
    double gemax;               /* the phase grid's flux limit (o->grid); NaN:
                                 * each group evaluates the bound */
    double gsky, gron, gfrac;   /* the grid's bound: sky, read noise, fraction */
    double ops_full;            /* a render of the model as given (economy's unit) */
} frame_rules;

/* Economy's own cost: n bound evaluations of a table of that kind. */
static void charge(mp_frame_report *r, long n, const void *table, int kind)
{
    r->kbounds += n;
    r->ops_tables += (double)n * mp_econ_eval_ops(table, kind);
}

/* Whether the phase grid serves a group whose brightest star has flux e. */
static int grid_serves(const frame_rules *R, const mp_prf_cache *g, double e,
                       mp_frame_report *cost)
{
    if (!g || !(e > 0))
        return 0;
    if (!isnan(R->gemax))
        return e <= R->gemax;
    charge(cost, 1, g, ECON_LIM_GRID);
    return mp_prf_cache_bound(g, e, R->gsky, R->gron) <= R->gfrac;
}

/* The limits of c on sky level sky (already rounded), computed on a miss:
 * an mp_sinc_choice's hwmax limits, an mp_ss_level's one or an
 * mp_prf_cache's one; NULL when the cache is full or out of memory. */
static void fill_limits(const void *c, int kind, double sky, double ron, double frac,
                        double *emax, mp_frame_report *cost)
{
    if (kind == ECON_LIM_LEVEL) {
        emax[0] = mp_ss_level_emax(c, sky, ron, frac);
        charge(cost, MP_SS_LIMITS_EVALS, c, kind);
    } else if (kind == ECON_LIM_GRID) {
        emax[0] = mp_prf_cache_limit(c, sky, ron, frac);
        charge(cost, MP_SINC_LIMITS_EVALS, c, kind);
    } else {
        mp_sinc_choice_limits(c, sky, ron, frac, emax);
        charge(cost, (long)((const mp_sinc_choice *)c)->hwmax * MP_SINC_LIMITS_EVALS, c, kind);
    }
}

static double *cached_limits(mp_econ_cache *cache, const void *c, int kind, double sky,
                             double ron, double frac, mp_frame_report *cost)
{
    size_t n = kind != ECON_LIM_SINC ? 1 : (size_t)((const mp_sinc_choice *)c)->hwmax;
    double *emax = NULL;
#pragma omp critical(mp_econ_limits)
    {
        for (int i = 0; i < cache->n && !emax; i++)
            if (cache->e[i].c == c && cache->e[i].kind == kind && cache->e[i].sky == sky &&
                cache->e[i].ron == ron && cache->e[i].frac == frac)
                emax = cache->e[i].emax;
        if (!emax && cache->n < MP_ECON_CACHE_MAX &&
            (emax = malloc(n * sizeof *emax))) {
            fill_limits(c, kind, sky, ron, frac, emax, cost);
            int i = cache->n++;
            cache->e[i].c = c;
            cache->e[i].kind = kind;
            cache->e[i].sky = sky;
            cache->e[i].ron = ron;
            cache->e[i].frac = frac;
            cache->e[i].emax = emax;
        }
    }
    return emax;
}

/* The run cache's sky level: the sky rounded down to a quarter octave. */
static double cache_sky(double sky)
{
    return sky > 1.0 ? exp2(floor(4.0 * log2(sky)) / 4.0) : 0.0;
}

/* A rule on the frame's sky: the limits from the run's cache (the sky
 * rounded down) when the run's fits (runfits: its groups, at most) number
 * more than the limits cost evaluations, else the frame's own limits table
 * when the frame has that many groups, else each group evaluates the
 * bound.  Nonzero when out of memory. */
static int rule_init(kernel_rule *k, const mp_sinc_choice *c, double sky, double ron, double frac,
                     size_t ng, mp_econ_cache *cache, double runfits, mp_frame_report *cost)
{
    memset(k, 0, sizeof *k);
    if (!c || c->hwmax <= 0 || !c->d2)
        return 0;
    *k = (kernel_rule){c, NULL, 0, sky, ron, frac};
    if (cache && runfits > MP_SINC_LIMITS_EVALS &&
        (k->emax = cached_limits(cache, c, ECON_LIM_SINC, cache_sky(sky), ron, frac, cost)))
        return 0;
    if (ng <= MP_SINC_LIMITS_EVALS)
        return 0;
    if (!(k->emax = malloc((size_t)c->hwmax * sizeof *k->emax)))
        return 1;
    k->owned = 1;
    mp_sinc_choice_limits(c, sky, ron, frac, k->emax);
    charge(cost, (long)c->hwmax * MP_SINC_LIMITS_EVALS, c, ECON_LIM_SINC);
    return 0;
}

/* The same for a coarser table (lv NULL: a rule that never serves). */
static int level_init(level_rule *k, const mp_ss_level *lv, double sky, double ron, double frac,
                      size_t ng, mp_econ_cache *cache, double runfits, mp_frame_report *cost)
{
    *k = (level_rule){lv && lv->bias.p ? lv : NULL, NAN, sky, ron, frac};
    if (!k->lv)
        return 0;
    if (cache && runfits > MP_SS_LIMITS_EVALS) {
        const double *e = cached_limits(cache, lv, ECON_LIM_LEVEL, cache_sky(sky), ron, frac, cost);
        if (e) {
            k->emax = e[0];
            return 0;
        }
    }
    if (ng > MP_SS_LIMITS_EVALS) {
        k->emax = mp_ss_level_emax(lv, sky, ron, frac);
        charge(cost, MP_SS_LIMITS_EVALS, lv, ECON_LIM_LEVEL);
    }
    return 0;
}

/* The phase grid's flux limit on the frame's sky, as the kernel's: from
 * the run's cache, the frame's own, or NaN: each group evaluates its bound
 * (and neighbours are painted exactly). */
static double grid_limit(const mp_prf_cache *g, double sky, double ron, double frac, size_t ng,
                         mp_econ_cache *cache, double runfits, mp_frame_report *cost)
{
    if (!g)
        return 0.0;
    if (cache && runfits > MP_SINC_LIMITS_EVALS) {
        const double *e = cached_limits(cache, g, ECON_LIM_GRID, cache_sky(sky), ron, frac, cost);
        if (e)
            return e[0];
    }
    if (ng > MP_SINC_LIMITS_EVALS) {
        charge(cost, MP_SINC_LIMITS_EVALS, g, ECON_LIM_GRID);
        return mp_prf_cache_limit(g, sky, ron, frac);
    }
    return NAN;
}

/* Whether the level serves a group whose brightest star has flux e (≤ 0
 * or NaN: unknown, it does not); cost counts criterion evaluations. */
static int level_serves(const level_rule *k, double e, mp_frame_report *cost)
{
    if (!k->lv || !(e > 0))
        return 0;
    if (!isnan(k->emax))
        return e <= k->emax;
    charge(cost, 1, k->lv, ECON_LIM_LEVEL);
    return mp_ss_level_serves(k->lv, e, k->sky, k->ron, k->frac);
}

static void rules_free(frame_rules *R)
{
    for (int l = 0; l <= MP_SS_MAXLEVELS; l++)
        if (R->kern[l].owned)
            free(R->kern[l].emax);
}

/* The half-width for a group whose brightest star has flux e (≤ 0 or NaN:
 * unknown, the full kernel); cost counts bound evaluations. */
static int kernel_for(const kernel_rule *k, int hwfull, double e, mp_frame_report *cost)
{
    if (!k->c)
        return hwfull;
    if (k->emax)
        return mp_sinc_choice_pick(k->emax, k->c->hwmax, e > 0 ? e : INFINITY);
    if (!(e > 0))
        return k->c->hwmax;
    int hw = mp_sinc_choice_hw(k->c, e, k->sky, k->ron, k->frac);
    charge(cost, hw < k->c->hwmax ? hw + 1 : k->c->hwmax, k->c, ECON_LIM_SINC);
    return hw;
}

static double crop_radius(const crop_rule *c, const mp_star *s)
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

static int paint(const mp_prf_model *m, const mp_star *s, double sign, double rad, float *img,
                 long x0, long y0, long w, long h, mp_prf_work *wk, double **buf, size_t *cap,
                 int *cut)
{
    if (!isfinite(s->flux) || !isfinite(s->x) || !isfinite(s->y) || s->flux == 0.0)
        return 0;
    /* Economy: from the phase grid when the star is within its bound. */
    const struct mp_prf_cache_s *grid = wk->grid;
    if (grid && !(fabs(s->flux) <= wk->grid_emax))
        wk->grid = NULL;
    int rc = paint_window(m, s, sign, rad, img, x0, y0, w, h, wk, buf, cap, cut);
    wk->grid = grid;
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
        *cap = need;
        if (!(*buf = malloc(*cap * sizeof **buf)))
            return 1;
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

/* Merge the closest pair of the group that is closer than mergerad or not
 * significantly separated: the brighter survives at the flux-weighted mean
 * position with the summed flux.  Returns 1 if a pair was merged. */
static int merge_one(mp_star *s, int *alive, int n, double mergerad)
{
    int a = -1, b = -1;
    double best = INFINITY;
    for (int i = 0; i < n; i++)
        for (int j = i + 1; j < n; j++) {
            if (!alive[i] || !alive[j])
                continue;
            double d = hypot(s[i].x - s[j].x, s[i].y - s[j].y);
            double es = sqrt(s[i].ex * s[i].ex + s[i].ey * s[i].ey + s[j].ex * s[j].ex + s[j].ey * s[j].ey);
            if ((d < mergerad || d < 2.0 * es) && d < best) {
                best = d;
                a = i;
                b = j;
            }
        }
    if (a < 0)
        return 0;
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
    return 1;
}

static double snr_of(const mp_star *s)
{
    return s->eflux > 0 ? s->flux / s->eflux : (s->flux > 0 ? INFINITY : -INFINITY);
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

/* Fit one group (members st[0..n-1]) on frame f: merge/reject until
 * stable.  Local copies of the stars move in the frame's coordinates
 * shifted by (dx, dy). */
static int fit_one_group(const mp_frame *f, const mp_prf_model *m, const mp_frame_opts *o,
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
    /* Each round removes a star or ends, so n + 1 rounds suffice. */
    for (int round = 0; round <= n; round++) {
        int nl = 0;
        for (int k = 0; k < n; k++)
            if (alive[k]) {
                live[nl] = s[k];
                map[nl++] = k;
            }
        if (nl == 0)
            break;
        double sky0 = nl == 1 ? live[0].sky : NAN;
        /* Economy: the coarsest table and the shortest kernel the
         * group's brightest star allows. */
        double e = 0.0;
        for (int k = 0; k < nl; k++)
            e = isfinite(live[k].flux) && live[k].flux > e ? live[k].flux : e;
        int l = 0;
        while (l < R->nss && !level_serves(&R->level[l], e, rep))
            l++;
        mp_prf_model mh = l < R->nss ? R->ss[l].model : *m;
        /* The group is fitted on a sub-image offset by (dx, dy): a
         * variable PSF must still be read at each star's frame position
         * (a run's coarser level also at the sub-frame's, o->psfdx). */
        mp_psf lp;
        mp_psf_field lf;
        if (mh.psf->field) {    /* (a constant table keeps its pointer: the cache's key) */
            double ox = l < R->nss ? o->psfdx : 0.0, oy = l < R->nss ? o->psfdy : 0.0;
            mp_psf_local(mh.psf, dx + ox, dy + oy, &lp, &lf);
            mh.psf = &lp;
        }
        mh.sinc_hw = kernel_for(&R->kern[l], mh.sinc_hw, e, rep);
        rep->kcoarse += l < R->nss;
        /* Economy: the phase grid of the table as given, when its bound
         * allows the brightest star (a star without a flux: the exact render). */
        mp_fit_opts fo = o->fit;
        fo.grid = l == R->nss && grid_serves(R, o->grid, e, rep) ? o->grid : NULL;
        int cached = mp_prf_cache_usable(fo.grid, &mh);
        rep->kcache += cached;
        rep->kcalls++;
        rep->khw += mh.sinc_hw;
        rep->kshort += mh.sinc_hw < m->sinc_hw;
        double gops = 0.0;
        fo.work = &gops;
        if (mp_fit_group(f, &mh, &fo, sky0, live, nl, err))
            goto done;
        rep->iterations += live[0].niter;
        rep->render_ops += gops;
        /* What economy saved on this fit's renders (the plan's unit). */
        if (R->ops_full > 0) {
            double used = cached ? mp_econ_grid_render_ops(m, o->fit.fitrad)
                                 : mp_econ_render_ops(&mh, mh.sinc_hw, o->fit.fitrad);
            rep->ops_saved += (live[0].niter + 1.0) * fmax(R->ops_full - used, 0.0) * nl;
        }
        for (int k = 0; k < nl; k++) {
            int keep = s[map[k]].flags & MP_FLAG_MERGED;
            s[map[k]] = live[k];
            s[map[k]].flags |= keep;
        }
        if (mergerad > 0 && merge_one(s, alive, n, mergerad)) {
            rep->merged++;
            continue;
        }
        /* 2 FWHM: 5 default merge radii (0.4 FWHM), or from the PSF when
         * merging is off */
        double sepind = mergerad > 0 ? 5.0 * mergerad : 2.0 * mp_prf_fwhm(m);
        int nrej = o->minsnr > 0 ? reject_low(s, alive, n, o->minsnr, mergerad, sepind) : 0;
        if (nrej > 0) {
            rep->rejected += nrej;
            continue;
        }
        break;
    }
    for (int k = 0; k < n; k++) {
        st[k].s = s[k];
        st[k].s.x += dx;
        st[k].s.y += dy;
        st[k].alive = alive[k];
        if (alive[k] && (s[k].flags & MP_FLAG_NOCONV))
            rep->noconv++;
    }
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
static void group_window(const mp_frame *f, const star_state *st, int n, double r,
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

/* ---- What each star was fitted against (economy, issue 5) --------------- */

/* A star's last fit, by NUMBER, across calls. */
typedef struct {
    mp_star s;
    float *seen;
    long sx0, sy0;
    int sw;
} star_seen;

struct mp_fit_memory {
    star_seen *s;        /* indexed by NUMBER */
    size_t ns;
    float *scratch;      /* lent: room for the model of every star */
    size_t nscratch;
};

void mp_fit_memory_scratch(mp_fit_memory *mem, float *buf, size_t n)
{
    mem->scratch = buf;
    mem->nscratch = buf ? n : 0;
}

mp_fit_memory *mp_fit_memory_new(void)
{
    return calloc(1, sizeof(mp_fit_memory));
}

void mp_fit_memory_free(mp_fit_memory *mem)
{
    if (!mem)
        return;
    for (size_t i = 0; i < mem->ns; i++)
        free(mem->s[i].seen);
    free(mem->s);
    free(mem);
}

/* The square of pixels whose centres lie within r + 1 of (x, y), clipped
 * to the frame; side 0 when off it. */
static void patch_of(const mp_frame *f, double x, double y, double r, long *x0, long *y0, int *side,
                     long *h)
{
    long a = (long)ceil(x - r - 1), b = (long)ceil(y - r - 1);
    long c = (long)floor(x + r + 1), d = (long)floor(y + r + 1);
    a = a < 1 ? 1 : a;
    b = b < 1 ? 1 : b;
    c = c > f->im.nx ? f->im.nx : c;
    d = d > f->im.ny ? f->im.ny : d;
    *x0 = a;
    *y0 = b;
    *side = c >= a ? (int)(c - a + 1) : 0;
    *h = d >= b ? d - b + 1 : 0;
}

/* The light of every star but k on k's patch: img (a window at wx0, wy0,
 * width ww, holding the patch) minus k's own light.  out holds sw*sw. */
static int others_on_patch(const mp_prf_model *m, const crop_rule *crop, const star_state *k,
                           const float *img, long wx0, long wy0, long ww, long px0, long py0,
                           int pw, long ph, float *out, mp_prf_work *wk, double **buf, size_t *cap)
{
    for (long j = 0; j < ph; j++)
        for (long i = 0; i < pw; i++)
            out[j * pw + i] = img[(py0 + j - wy0) * ww + (px0 + i - wx0)];
    return paint(m, &k->s, -1.0, crop_radius(crop, &k->s), out, px0, py0, pw, ph, wk, buf, cap, NULL);
}

/* √Σ((others − seen)/σ)² over the star's fitting region (unmasked pixels
 * within fitrad), σ² = max(data, 0) + RON²: by Cauchy–Schwarz, refitting
 * the star against the light of the others now instead of then moves none
 * of its parameters by more than this many of its own σ (to first order).
 * INFINITY when it was never fitted or its region left the patch. */
static double light_change(const mp_frame *f, const mp_prf_model *m, const crop_rule *crop,
                           const star_state *k, double r, const float *all, float *tmp,
                           mp_prf_work *wk, double **buf, size_t *cap, int *nomem)
{
    if (!k->seen)
        return INFINITY;
    long ph = k->sw;
    if (others_on_patch(m, crop, k, all, 1, 1, f->im.nx, k->sx0, k->sy0, k->sw, ph, tmp, wk, buf,
                        cap)) {
        *nomem = 1;
        return INFINITY;
    }
    double ron2 = f->rdnoise * f->rdnoise, q = 0.0;
    long a = (long)ceil(k->s.x - r), b = (long)ceil(k->s.y - r);
    long c = (long)floor(k->s.x + r), d = (long)floor(k->s.y + r);
    for (long Y = b; Y <= d; Y++)
        for (long X = a; X <= c; X++) {
            double dx = X - k->s.x, dy = Y - k->s.y;
            if (X < 1 || Y < 1 || X > f->im.nx || Y > f->im.ny || dx * dx + dy * dy > r * r)
                continue;
            size_t g = (size_t)(Y - 1) * f->im.nx + (size_t)(X - 1);
            if (f->mask && f->mask[g])
                continue;
            long i = X - k->sx0, j = Y - k->sy0;
            if (i < 0 || j < 0 || i >= k->sw || j >= k->sw)
                return INFINITY;
            double v = (f->im.pix[g] > 0 ? f->im.pix[g] : 0.0) + ron2;
            double dd = tmp[j * k->sw + i] - k->seen[j * k->sw + i];
            q += dd * dd / (v > 1e-2 ? v : 1e-2);
        }
    return sqrt(q);
}

/* After a fit of the stars sub[0..n-1] (their values before it in old):
 * every survivor's patch of the light of all other stars, from all (the
 * pass's model, with the old values) with the fitted stars' old light
 * replaced by their new. */
static int remember_patches(const mp_frame *f, const mp_prf_model *m, const crop_rule *crop,
                            double r, const float *all, const mp_star *old, star_state *sub,
                            int n, mp_prf_work *wk, double **buf, size_t *cap)
{
    /* The window holding every patch. */
    long x0 = f->im.nx, y0 = f->im.ny, x1 = 1, y1 = 1;
    for (int k = 0; k < n; k++) {
        if (!sub[k].alive)
            continue;
        long px, py, ph;
        int pw;
        patch_of(f, sub[k].s.x, sub[k].s.y, r, &px, &py, &pw, &ph);
        if (pw == 0 || ph == 0)
            continue;
        x0 = px < x0 ? px : x0;
        y0 = py < y0 ? py : y0;
        x1 = px + pw - 1 > x1 ? px + pw - 1 : x1;
        y1 = py + ph - 1 > y1 ? py + ph - 1 : y1;
    }
    for (int k = 0; k < n; k++) {
        free(sub[k].seen);
        sub[k].seen = NULL;
    }
    if (x1 < x0 || y1 < y0)
        return 0;
    long w = x1 - x0 + 1, h = y1 - y0 + 1;
    float *img = malloc((size_t)(w * h) * sizeof *img);
    if (!img)
        return 1;
    for (long j = 0; j < h; j++)
        memcpy(img + j * w, all + (size_t)(y0 - 1 + j) * f->im.nx + (size_t)(x0 - 1),
               (size_t)w * sizeof *img);
    int rc = 0;
    for (int k = 0; k < n && !rc; k++) {
        rc = paint(m, &old[k], -1.0, crop_radius(crop, &old[k]), img, x0, y0, w, h, wk, buf, cap,
                   NULL);
        if (!rc && sub[k].alive)
            rc = paint(m, &sub[k].s, +1.0, crop_radius(crop, &sub[k].s), img, x0, y0, w, h, wk, buf,
                       cap, NULL);
    }
    for (int k = 0; k < n && !rc; k++) {
        if (!sub[k].alive)
            continue;
        long px, py, ph;
        int pw;
        patch_of(f, sub[k].s.x, sub[k].s.y, r, &px, &py, &pw, &ph);
        if (pw == 0 || ph != pw)
            continue;                /* cut by the frame's edge: refitted every time */
        if (!(sub[k].seen = malloc((size_t)pw * pw * sizeof *sub[k].seen))) {
            rc = 1;
            break;
        }
        sub[k].sx0 = px;
        sub[k].sy0 = py;
        sub[k].sw = pw;
        rc = others_on_patch(m, crop, &sub[k], img, x0, y0, w, px, py, pw, ph, sub[k].seen, wk,
                             buf, cap);
    }
    free(img);
    return rc;
}

/* Fit one group on a local frame: data − (the light of every other star)
 * = data − all + own.  With economy (may_keep) the group keeps its fit when
 * no live member's surroundings changed by o->refittol or more since it
 * was fitted (light_change); rep counts group fits (fits) and groups left
 * alone (kept).  With economy, every survivor's patch is remembered. */
static int fit_group_local(const mp_frame *f, const mp_prf_model *m, const mp_frame_opts *o,
                           double mergerad, const frame_rules *R, const float *all,
                           const crop_rule *crop,
                           star_state *st, int n, int may_keep, int economy,
                           mp_frame_report *rep, char *err)
{
    double r = o->fit.fitrad;
    mp_prf_work wk = {0};
    wk.grid = o->grid;
    wk.grid_emax = R->gemax;
    double *buf = NULL;
    float *tmp = NULL;
    size_t cap = 0;
    star_state *sub = malloc((size_t)n * sizeof *sub);
    int *act = calloc((size_t)n, sizeof *act), *idx = malloc((size_t)n * sizeof *idx);
    mp_star *old = malloc((size_t)n * sizeof *old);
    mp_frame L = *f;
    L.im.pix = NULL;
    L.mask = NULL;
    L.xvar = NULL;
    int rc = 1, nomem = 0;
    if (!sub || !act || !idx || !old) {
        snprintf(err, MP_ERRLEN, "out of memory");
        goto done;
    }
    int nact = 0;
    for (int k = 0; k < n; k++)
        act[k] = st[k].alive;
    if (may_keep && all && isfinite(r)) {
        int side = (int)(2 * r + 3) + 1;
        if (!(tmp = malloc((size_t)side * side * sizeof *tmp))) {
            snprintf(err, MP_ERRLEN, "out of memory");
            goto done;
        }
        /* The group's pixels are its members' regions, and its sky is
         * shared: the bound is on the sum over the members (overlaps
         * counted twice: conservative). */
        double q2 = 0.0;
        for (int k = 0; k < n; k++)
            act[k] = 0;
        for (int k = 0; k < n && q2 < o->refittol * o->refittol; k++)
            if (st[k].alive) {
                double q = st[k].sw <= side ? light_change(f, m, crop, &st[k], r, all, tmp, &wk,
                                                           &buf, &cap, &nomem) : INFINITY;
                q2 += q * q;
            }
        int any = !(q2 < o->refittol * o->refittol);
        if (nomem) {
            snprintf(err, MP_ERRLEN, "out of memory");
            goto done;
        }
        /* One star that must be refitted refits its whole group: a part
         * refitted with the rest held (and its own sky) does not find the
         * joint fit (tried: 90th percentile of the flux change 1.5 σ on the
         * dense bench frame, against 0.1 σ for whole groups). */
        for (int k = 0; k < n && any; k++)
            act[k] = st[k].alive;
    }
    for (int k = 0; k < n; k++)
        if (act[k]) {
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
    group_window(f, sub, nact, rw, &x0, &y0, &w, &h);
    if (w == 0 || h == 0 || (!all && x0 == 1 && y0 == 1 && w == f->im.nx && h == f->im.ny)) {
        rc = fit_one_group(f, m, o, mergerad, R, sub, nact, 0.0, 0.0, rep, err);
    } else {
        L.im.nx = w;
        L.im.ny = h;
        L.im.pix = malloc((size_t)(w * h) * sizeof *L.im.pix);
        L.mask = malloc((size_t)(w * h));
        L.xvar = f->xvar ? malloc((size_t)(w * h) * sizeof *L.xvar) : NULL;
        if (!L.im.pix || !L.mask || (f->xvar && !L.xvar)) {
            snprintf(err, MP_ERRLEN, "out of memory");
            goto done;
        }
        for (long j = 0; j < h; j++)
            for (long i = 0; i < w; i++) {
                size_t g = (size_t)(y0 - 1 + j) * f->im.nx + (size_t)(x0 - 1 + i);
                L.im.pix[j * w + i] = (float)(f->im.pix[g] - (all ? (double)all[g] : 0.0));
                L.mask[j * w + i] = f->mask ? f->mask[g] : 0;
                if (L.xvar)
                    L.xvar[j * w + i] = f->xvar[g];
            }
        /* The fitted stars' own light comes back with the same crop
         * all_stars took it off with, so it cancels exactly. */
        if (all)
            for (int k = 0; k < nact; k++)
                if (sub[k].alive && paint(m, &sub[k].s, +1.0, crop_radius(crop, &sub[k].s), L.im.pix,
                                          x0, y0, w, h, &wk, &buf, &cap, NULL)) {
                    snprintf(err, MP_ERRLEN, "out of memory");
                    goto done;
                }
        rc = fit_one_group(&L, m, o, mergerad, R, sub, nact, (double)(x0 - 1), (double)(y0 - 1), rep,
                           err);
    }
    if (!rc && economy && all && isfinite(r) &&
        remember_patches(f, m, crop, r, all, old, sub, nact, &wk, &buf, &cap)) {
        snprintf(err, MP_ERRLEN, "out of memory");
        rc = 1;
    }
    for (int k = 0; k < nact; k++)
        st[idx[k]] = sub[k];    /* the patches move with the stars */
done:
    free(L.im.pix);
    free(L.mask);
    free(L.xvar);
    free(sub);
    free(act);
    free(idx);
    free(old);
    free(tmp);
    free(buf);
    mp_prf_work_free(&wk);
    return rc;
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
 * counts the stars the crop cut.  Returns 1 when out of memory. */
static int paint_frame(const mp_prf_model *m, const mp_star *const *s, size_t n,
                       const crop_rule *crop, double sign, const mp_prf_work *proto, float *img,
                       long nx, long ny, long *ncut)
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
        rad[k] = crop_radius(crop, p);
        if (isfinite(p->flux) && p->flux != 0.0 && fabs(p->x) < 1e9 && fabs(p->y) < 1e9)
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
#pragma omp parallel if (!nomem)
    {
        mp_prf_work wk = {0};
        wk.grid = proto->grid;
        wk.grid_emax = proto->grid_emax;
        double *buf = NULL;
        size_t cap = 0;
#pragma omp for schedule(dynamic)
        for (long b = 0; b < nb; b++) {
            long y0 = 1 + b * PAINT_BAND, h = ny - y0 + 1 < PAINT_BAND ? ny - y0 + 1 : PAINT_BAND;
            for (size_t q = cnt[b]; q < cnt[b + 1]; q++) {
                size_t k = idx[q];
                int c = 0;
                if (paint(m, s[k], sign, rad[k], img + (size_t)(y0 - 1) * (size_t)nx, 1, y0, nx,
                          h, &wk, &buf, &cap, &c)) {
#pragma omp atomic write
                    nomem = 1;
                }
                if (c && b == b0[k])
                    cut[k] = 1;    /* counted by the star's first band only */
            }
        }
        free(buf);
        mp_prf_work_free(&wk);
    }
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
static float *all_stars(const mp_frame *f, const mp_prf_model *m, const star_state *st, size_t n,
                        const crop_rule *crop, const mp_frame_opts *o, const frame_rules *R,
                        float *lent, long *ncut)
{
    size_t npix = (size_t)f->im.nx * (size_t)f->im.ny;
    float *all = lent ? memset(lent, 0, npix * sizeof *lent) : calloc(npix, sizeof *all);
    const mp_star **live = malloc((n ? n : 1) * sizeof *live);
    size_t nl = 0;
    for (size_t k = 0; live && k < n; k++)
        if (st[k].alive)
            live[nl++] = &st[k].s;
    mp_prf_work proto = {0};
    proto.grid = o->grid;
    proto.grid_emax = R->gemax;
    if (all && (!live || paint_frame(m, live, nl, crop, +1.0, &proto, all, f->im.nx, f->im.ny,
                                     ncut))) {
        if (!lent)
            free(all);
        all = NULL;
    }
    free(live);
    return all;
}

/* The crop rule of a frame: no envelope (whole boxes) when cropfrac is 0. */
static int crop_init(const mp_frame *f, const mp_prf_model *m, double cropfrac, crop_rule *c)
{
    return mp_prf_crop_init(m, cropfrac, f->rdnoise, c);
}

/* Write the fit's columns; drop rows of merged-away or rejected stars. */
static int write_columns(mp_table *t, const star_state *st, size_t n, double magzero, char *err)
{
    static const char *const names[] = {
        "XPSF_IMAGE", "YPSF_IMAGE", "ERRX_PSF", "ERRY_PSF", "FLUX_PSF", "FLUXERR_PSF",
        "MAG_PSF", "MAGERR_PSF", "SKY_PSF", "SKYERR_PSF", "CHI2_PSF", "DOF_PSF",
        "NITER_PSF", "BETA_PSF", "SHARP_PRF", "LSCALE_PRF", "VOLUME_PRF",
        "FLUXERR_MODEL", "POSERR_MODEL", "FLAGS"};
    enum { NCOL = sizeof names / sizeof names[0] };
    int c[NCOL];
    int cflags0 = mp_table_col(t, "FLAGS");
    for (int k = 0; k < NCOL; k++)
        if ((c[k] = mp_table_add_col(t, names[k])) < 0) {
            snprintf(err, MP_ERRLEN, "out of memory");
            return 1;
        }
    unsigned char *keep = calloc(t->nrow ? t->nrow : 1, 1);
    if (!keep) {
        snprintf(err, MP_ERRLEN, "out of memory");
        return 1;
    }
    for (size_t i = 0; i < n; i++) {
        const mp_star *s = &st[i].s;
        size_t r = (size_t)st[i].row;
        keep[r] = (unsigned char)st[i].alive;
        int ok = s->flux > 0;
        /* Flags from earlier stages (find's saturation, group's split)
         * stay; the fit's own (edge, not converged, merged, masked) are
         * this fit's, not a previous round's: a star flagged not converged
         * in round 1 and converged in round 2 is not flagged. */
        double before = cflags0 >= 0 ? mp_table_get(t, r, c[NCOL - 1]) : 0.0;
        int carried = isfinite(before) ? (int)before & (MP_FLAG_SATURATED | MP_FLAG_SPLIT) : 0;
        int fl = s->flags | carried;
        double v[NCOL] = {
            s->x, s->y, s->ex, s->ey, s->flux, s->eflux,
            ok ? -2.5 * log10(s->flux) + magzero : 99.0,
            ok ? 2.5 / log(10.0) * s->eflux / s->flux : 99.0,
            s->sky, s->esky, s->chi2, s->dof, s->niter,
            s->st.beta, s->st.sharp, s->st.lscale, s->st.volume,
            s->fluxerr_model, s->poserr_model, fl};
        for (int k = 0; k < NCOL; k++)
            mp_table_set(t, r, c[k], v[k]);
    }
    size_t out = 0;
    for (size_t r = 0; r < t->nrow; r++)
        if (keep[r]) {
            if (out != r)
                memmove(t->v + out * t->ncol, t->v + r * t->ncol, t->ncol * sizeof *t->v);
            out++;
        }
    t->nrow = out;
    free(keep);
    return 0;
}

/* Numbers of the rows (NUMBER) when every row has a distinct-looking
 * whole one the memory can index, else −1 (no memory across calls). */
static double max_number(const mp_table *t)
{
    int cn = mp_table_col(t, "NUMBER");
    if (cn < 0)
        return -1.0;
    double mx = 0.0;
    for (size_t r = 0; r < t->nrow; r++) {
        double v = mp_table_get(t, r, cn);
        if (!(v >= 0 && v < 1e8 && v == floor(v)))
            return -1.0;
        mx = v > mx ? v : mx;
    }
    return mx;
}

/* Give back to the stars of the table their last fits from mem (the
 * pipeline's earlier rounds): a star whose row still holds that fit's
 * values gets its errors and its patch back, so it need not be refitted
 * when its surroundings have not changed. */
static void recall(mp_fit_memory *mem, star_state *st, size_t n)
{
    for (size_t i = 0; i < n; i++) {
        size_t k = (size_t)st[i].number;
        if (k >= mem->ns || !mem->s[k].seen)
            continue;
        star_seen *r = &mem->s[k];
        if (r->s.x != st[i].s.x || r->s.y != st[i].s.y || r->s.flux != st[i].s.flux)
            continue;
        st[i].s = r->s;
        st[i].seen = r->seen;
        st[i].sx0 = r->sx0;
        st[i].sy0 = r->sy0;
        st[i].sw = r->sw;
        r->seen = NULL;
    }
}

/* Keep every live star's fit and patch in mem, by NUMBER. */
static int remember(mp_fit_memory *mem, star_state *st, size_t n, double maxnum)
{
    size_t ns = (size_t)maxnum + 1;
    if (ns > mem->ns) {
        star_seen *s = realloc(mem->s, ns * sizeof *s);
        if (!s)
            return 1;
        memset(s + mem->ns, 0, (ns - mem->ns) * sizeof *s);
        mem->s = s;
        mem->ns = ns;
    }
    for (size_t i = 0; i < n; i++) {
        star_seen *r = &mem->s[(size_t)st[i].number];
        free(r->seen);
        r->seen = NULL;
        if (!st[i].alive)
            continue;
        r->s = st[i].s;
        r->seen = st[i].seen;
        r->sx0 = st[i].sx0;
        r->sy0 = st[i].sy0;
        r->sw = st[i].sw;
        st[i].seen = NULL;
    }
    return 0;
}

int mp_fit_table(const mp_frame *f, const mp_prf_model *m, const mp_frame_opts *o,
                 mp_table *t, mp_frame_report *rep, char *err)
{
    return mp_fit_table_mem(f, m, o, t, NULL, rep, err);
}

static int cmp_double(const void *a, const void *b)
{
    double x = *(const double *)a, y = *(const double *)b;
    return (x > y) - (x < y);
}

/* Median of the finite, positive start skies of the stars [e-]; 0 when
 * none (the kernel choice's safe side: less sky, less noise). */
static double median_sky(const star_state *st, size_t n)
{
    double *v = malloc((n ? n : 1) * sizeof *v);
    size_t k = 0;
    if (!v)
        return 0.0;
    for (size_t i = 0; i < n; i++)
        if (isfinite(st[i].s.sky) && st[i].s.sky > 0)
            v[k++] = st[i].s.sky;
    double med = 0.0;
    if (k) {
        qsort(v, k, sizeof *v, cmp_double);
        med = v[k / 2];
    }
    free(v);
    return med;
}

/* The frame's economy rules for the tables o points at (fit_group_local):
 * the coarser levels' and kernels' choices and the phase grid's limit on
 * the stars' median start sky.  Nonzero when out of memory. */
static int rules_setup(frame_rules *R, const mp_frame *f, const mp_frame_opts *o,
                       const star_state *st, size_t n, size_t ng, double runfits,
                       mp_frame_report *rep)
{
    rules_free(R);
    double keep = R->ops_full;
    memset(R, 0, sizeof *R);
    R->ops_full = keep;
    double bsky = o->sinc || o->nss ? median_sky(st, n) : 0.0;
    R->ss = o->ss;
    R->nss = o->ss ? (o->nss < MP_SS_MAXLEVELS ? o->nss : MP_SS_MAXLEVELS) : 0;
    int nomem = rule_init(&R->kern[R->nss], o->sinc, bsky, f->rdnoise, o->sincfrac, ng, o->cache,
                          runfits, rep);
    for (int l = 0; l < R->nss; l++)
        nomem |= level_init(&R->level[l], &R->ss[l], bsky, f->rdnoise, o->ssfrac, ng, o->cache,
                            runfits, rep) ||
                 rule_init(&R->kern[l],
                           ((o->ss_sinc >> l) & 1) && R->ss[l].sinc.d2 ? &R->ss[l].sinc : NULL, bsky,
                           f->rdnoise, o->sincfrac, ng, o->cache, runfits, rep);
    /* Economy: the largest flux the phase grid serves within the kernel's
     * bound, on the same sky. */
    R->gsky = o->grid ? median_sky(st, n) : 0.0;
    R->gron = f->rdnoise;
    R->gfrac = o->sincfrac;
    R->gemax = grid_limit(o->grid, R->gsky, f->rdnoise, o->sincfrac, ng, o->cache, runfits, rep);
    return nomem;
}

/* Economy in a sequential run: add ops (exact-render work just done) to
 * the run's count and, when more groups follow (more), point oc at the
 * tables that now pay, the rules renewed when they changed.  Nonzero with
 * err on failure. */
static int learn_and_choose(const mp_frame *f, const mp_frame_opts *o, mp_frame_opts *oc,
                            frame_rules *R, const star_state *st, size_t n, size_t ng,
                            double runfits, double ops, int more, mp_frame_report *rep, char *err)
{
    mp_econ_learn(o->cache, ops);
    if (!more)
        return 0;
    const void *had[3] = {oc->sinc, oc->ss, oc->grid};
    double sp = 0.0;
    if (mp_econ_choose(o->cache, runfits, oc->fit.fitrad, oc, &sp, err))
        return 1;
    rep->ops_tables += sp;
    if ((had[0] != oc->sinc || had[1] != oc->ss || had[2] != oc->grid) &&
        rules_setup(R, f, oc, st, n, ng, runfits, rep)) {
        snprintf(err, MP_ERRLEN, "out of memory");
        return 1;
    }
    return 0;
}

int mp_fit_table_mem(const mp_frame *f, const mp_prf_model *m, const mp_frame_opts *o,
                     mp_table *t, mp_fit_memory *mem, mp_frame_report *rep, char *err)
{
    mp_frame_report dummy;
    if (!rep)
        rep = &dummy;
    memset(rep, 0, sizeof *rep);
    int cx = col_any(t, "XPSF_IMAGE", "X_IMAGE"), cy = col_any(t, "YPSF_IMAGE", "Y_IMAGE");
    if (cx < 0 || cy < 0) {
        snprintf(err, MP_ERRLEN, "table has no X_IMAGE/Y_IMAGE or XPSF_IMAGE/YPSF_IMAGE columns");
        return 1;
    }
    int cf = col_any(t, "FLUX_PSF", "FLUX"), cs = col_any(t, "SKY_PSF", "BACKGROUND");
    int cg = mp_table_col(t, "GROUP_ID"), cn = mp_table_col(t, "NUMBER");
    int whole = !isfinite(o->fit.fitrad);
    double maxnum = mem ? max_number(t) : -1.0;
    size_t n = t->nrow;
    star_state *st = calloc(n ? n : 1, sizeof *st);
    size_t *gs = malloc((n + 1) * sizeof *gs);
    float *all = NULL;
    /* The model image: in the caller's lent buffer when there is one. */
    size_t npix = (size_t)f->im.nx * (size_t)f->im.ny;
    float *lent = mem && mem->scratch && mem->nscratch >= npix ? mem->scratch : NULL;
    frame_rules R;
    memset(&R, 0, sizeof R);
    crop_rule crop = {0};
    int rc = 1;
    if (!st || !gs) {
        snprintf(err, MP_ERRLEN, "out of memory");
        goto done;
    }
    for (size_t i = 0; i < n; i++) {
        st[i].row = (long)i;
        st[i].alive = 1;
        st[i].s.x = mp_table_get(t, i, cx);
        st[i].s.y = mp_table_get(t, i, cy);
        if (!isfinite(st[i].s.x) || !isfinite(st[i].s.y)) {
            snprintf(err, MP_ERRLEN, "row %zu: position is not a finite number", i + 1);
            goto done;
        }
        st[i].s.flux = cf >= 0 ? mp_table_get(t, i, cf) : NAN;
        st[i].s.sky = cs >= 0 ? mp_table_get(t, i, cs) : NAN;
        st[i].number = maxnum >= 0 ? mp_table_get(t, i, cn) : (double)i;
        double g = cg >= 0 ? mp_table_get(t, i, cg) : NAN;
        st[i].id = whole ? 0.0 : (isfinite(g) ? g : -1.0 - (double)i);
    }
    qsort(st, n, sizeof *st, cmp_group);
    size_t ng = 0;
    for (size_t i = 0; i < n; i++)
        if (i == 0 || st[i].id != st[i - 1].id)
            gs[ng++] = i;
    gs[ng] = n;
    rep->nstars = (long)n;
    rep->ngroups = (long)ng;
    double mergerad = isfinite(o->mergerad) ? o->mergerad : 0.4 * mp_prf_fwhm(m);
    /* Economy: the table and kernel choices on the frame's median start
     * sky (0, the safe side, when no star has one); the limits tables only
     * when cheaper than each group's own evaluation (rule_init). */
    /* Economy: the tables that pay for this run's star fits (the run's
     * planned count or this frame's stars), built on first need. */
    mp_frame_opts oe = *o;
    double runfits = o->fits > (double)n ? o->fits : (double)n;
    if (mp_econ_choose(o->cache, runfits, o->fit.fitrad, &oe, &rep->ops_tables, err))
        goto done;
    o = &oe;
    R.ops_full = o->cache ? mp_econ_render_ops(m, m->sinc_hw, o->fit.fitrad) : 0.0;
    rep->ops_render = R.ops_full;
    if (rules_setup(&R, f, o, st, n, ng, runfits, rep)) {
        snprintf(err, MP_ERRLEN, "out of memory");
        goto done;
    }
    int passes = o->passes < 1 ? 1 : o->passes;
    /* One group (a whole-frame fit, or one star): nobody else's light to
     * subtract, so neither the neighbours' model nor its crop envelope is
     * built (economy's crop would cost a PSF render per ¼-px phase per
     * frame and save nothing). */
    int alone = ng <= 1;
    if (alone)
        passes = 1;
    if (!alone && crop_init(f, m, o->cropfrac, &crop)) {
        snprintf(err, MP_ERRLEN, "out of memory");
        goto done;
    }
    rep->envelopes += crop.env != NULL;
    /* The group fits render each star as far as it is subtracted. */
    mp_frame_opts oc = *o;
    oc.fit.crop = crop.env ? &crop : NULL;
    o = &oc;
    /* Economy: a star refitted only when its surroundings changed
     * (o->refittol); never in whole-frame fits. */
    int economy = o->refittol > 0 && !whole && ng > 1;
    if (economy && maxnum >= 0)
        recall(mem, st, n);
    for (int pass = 0; pass < passes; pass++) {
        /* Neighbours are subtracted with the latest values; in the first
         * pass only those with a start flux (find's FLUX) can be. */
        if (!lent)
            free(all);
        all = NULL;
        if (!alone && !(all = all_stars(f, m, st, n, &crop, o, &R, lent, &rep->cropped))) {
            snprintf(err, MP_ERRLEN, "out of memory for the model image");
            goto done;
        }
        mp_frame_report pr = {0};
        /* Economy in a sequential run: the groups in chunks (the first
         * sixteenth, the first quarter, the rest), and after each the
         * exact-render work done counts toward the run's tables; a table
         * that now pays serves the groups after it.  The chunks' ends and
         * the work (sums of whole numbers) do not depend on the threads. */
        int learn = o->cache && o->learn;
        for (size_t g0 = 0, g1; g0 < ng; g0 = g1) {
            g1 = !learn ? ng : (g0 < ng / 16 ? ng / 16 : (g0 < ng / 4 ? ng / 4 : ng));
            g1 = g1 > g0 ? g1 : g0 + 1;
            double before = pr.render_ops;
            int failed = 0;
            char ferr[MP_ERRLEN] = "";
#pragma omp parallel for schedule(dynamic) reduction(+ : failed)
            for (size_t g = g0; g < g1; g++) {
                char e[MP_ERRLEN];
                mp_frame_report r = {0};
                int k = (int)(gs[g + 1] - gs[g]);
                if (fit_group_local(f, m, o, mergerad, &R, all, &crop, st + gs[g], k, economy,
                                    economy, &r, e)) {
                    failed++;
#pragma omp critical(fit_table_error)
                    snprintf(ferr, sizeof ferr, "%s", e);
                }
#pragma omp critical(fit_table_report)
                {
                    pr.merged += r.merged;
                    pr.rejected += r.rejected;
                    pr.iterations += r.iterations;
                    pr.fits += r.fits;
                    pr.kcalls += r.kcalls;
                    pr.kshort += r.kshort;
                    pr.khw += r.khw;
                    pr.kept += r.kept;
                    pr.kbounds += r.kbounds;
                    pr.kcoarse += r.kcoarse;
                    pr.kcache += r.kcache;
                    pr.ops_tables += r.ops_tables;
                    pr.ops_saved += r.ops_saved;
                    pr.render_ops += r.render_ops;
                }
            }
            if (failed) {
                snprintf(err, MP_ERRLEN, "%s", ferr);
                goto done;
            }
            if (learn && learn_and_choose(f, o, &oc, &R, st, n, ng, runfits, pr.render_ops - before,
                                          g1 < ng || pass + 1 < passes, &pr, err))
                goto done;
        }
        rep->merged += pr.merged;
        rep->rejected += pr.rejected;
        rep->iterations += pr.iterations;
        rep->fits += pr.fits;
        rep->kcalls += pr.kcalls;
        rep->kshort += pr.kshort;
        rep->khw += pr.khw;
        rep->kept += pr.kept;
        rep->kbounds += pr.kbounds;
        rep->kcoarse += pr.kcoarse;
        rep->kcache += pr.kcache;
        rep->ops_tables += pr.ops_tables;
        rep->ops_saved += pr.ops_saved;
        rep->render_ops += pr.render_ops;
        /* No group refitted: every later pass would see the same light. */
        if (economy && pr.fits == 0) {
            rep->kept += (long)ng * (passes - pass - 1);
            break;
        }
    }
    for (size_t i = 0; i < n; i++)
        if (st[i].alive && (st[i].s.flags & MP_FLAG_NOCONV))
            rep->noconv++;
    /* Each group's sky order as it stands (kept groups keep theirs). */
    for (size_t g = 0; g < ng; g++)
        for (size_t i = gs[g]; i < gs[g + 1]; i++)
            if (st[i].alive) {
                int so = st[i].s.sky_order;
                rep->sky_groups[so > 0 && so <= MP_SKY_MAXORDER ? so : 0]++;
                break;
            }
    if (mem && maxnum >= 0 && remember(mem, st, n, maxnum)) {
        snprintf(err, MP_ERRLEN, "out of memory");
        goto done;
    }
    rc = write_columns(t, st, n, o->magzero, err);
done:
    for (size_t i = 0; st && i < n; i++)
        free(st[i].seen);
    if (!lent)
        free(all);
    rules_free(&R);
    free(st);
    free(gs);
    free(crop.env);
    return rc;
}

int mp_fit_residual(const mp_frame *f, const mp_prf_model *m, const mp_table *t,
                    double cropfrac, float *res, char *err)
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
    int rc = !st || !ps || crop_init(f, m, cropfrac, &crop);
    for (size_t r = 0; !rc && r < n; r++) {
        st[r] = (mp_star){.x = mp_table_get(t, r, cx), .y = mp_table_get(t, r, cy),
                          .flux = mp_table_get(t, r, cf),
                          .sky = cs >= 0 ? mp_table_get(t, r, cs) : NAN};
        ps[r] = &st[r];
    }
    mp_prf_work none = {0};
    long ncut = 0;
    rc = rc || paint_frame(m, ps, n, &crop, -1.0, &none, res, nx, ny, &ncut);
    free(st);
    free(ps);
    free(crop.env);
    if (rc)
        snprintf(err, MP_ERRLEN, "residual: out of memory");
    return rc;
}
