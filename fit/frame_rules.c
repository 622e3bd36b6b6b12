/* frame_rules.c — economy's choices for each group of a frame: the
 * coarsest table, the shortest sinc kernel and the phase grid its
 * brightest star allows, from flux limits found once per sky level. */

#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include "fit/frame_priv.h"

/* Economy's own cost: n bound evaluations of a table of that kind. */
static void charge(mp_frame_report *r, long n, const void *table, int kind)
{
    r->kbounds += n;
    r->ops_tables += (double)n * mp_econ_eval_ops(table, kind);
}

/* Whether the phase grid serves a group whose brightest star has flux e. */
int ff_grid_serves(const frame_rules *R, const mp_prf_cache *g, double e,
                       mp_frame_report *cost)
{
    if (!g || !(e > 0))
        return 0;
    if (!isnan(R->gemax))
        return e <= R->gemax;
    charge(cost, 1, g, ECON_LIM_GRID);
    return mp_prf_cache_serves(g, e, R->gsky, R->gron, R->gfrac);
}

const mp_prf_cache *ff_group_grid(const frame_rules *R, const mp_prf_cache *g, int l, double e,
                                  double *emax, mp_prf_tiers *tiers, mp_frame_report *cost)
{
    const mp_prf_cache *t = l >= R->nss ? g : R->lgrid[l];
    double lim = l >= R->nss ? R->gemax : R->lgemax[l];
    *emax = INFINITY;
    memset(tiers, 0, sizeof *tiers);
    if (!t || !(e > 0))
        return NULL;
    if (!isnan(lim)) {          /* per star: the brighter ones exactly */
        *emax = lim;
        *tiers = l >= R->nss ? R->gtiers : R->lgtiers[l];
        return lim > 0 ? t : NULL;
    }
    charge(cost, 1, t, ECON_LIM_GRID);
    return mp_prf_cache_serves(t, e, R->gsky, R->gron, R->gfrac) ? t : NULL;
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
        /* The cubic's and the bilinear's limits; the core tiers' are the
         * bins' alone, no pixel summed (not charged). */
        emax[0] = mp_prf_cache_limit(c, sky, ron, frac);
        emax[1] = mp_prf_cache_limit_lin(c, sky, ron, frac);
        for (int k = 0; k < MP_PRF_NCORE; k++)
            emax[2 + k] = mp_prf_cache_limit_core(c, k, sky, ron, frac);
        charge(cost, 2 * MP_SINC_LIMITS_EVALS, c, kind);
    } else {
        mp_sinc_choice_limits(c, sky, ron, frac, emax);
        charge(cost, (long)((const mp_sinc_choice *)c)->hwmax * MP_SINC_LIMITS_EVALS, c, kind);
    }
}

/* The entry of the first n of cache for these arguments, or NULL. */
static double *find_limits(const mp_econ_cache *cache, int n, const void *c, int kind,
                           double sky, double ron, double frac)
{
    for (int i = 0; i < n; i++)
        if (cache->e[i].c == c && cache->e[i].kind == kind && cache->e[i].sky == sky &&
            cache->e[i].ron == ron && cache->e[i].frac == frac)
            return cache->e[i].emax;
    return NULL;
}

/* The flux limits for these arguments, computed once a run.  Every group
 * fit asks (about three times): the entries published are read without a
 * lock (an entry is filled before the count that shows it is stored, both
 * under the lock), and only a miss takes it — the lock on every call was
 * 33 000 entries a 2048² run, from every thread (bench/SCALING.md). */
static double *cached_limits(mp_econ_cache *cache, const void *c, int kind, double sky,
                             double ron, double frac, mp_frame_report *cost)
{
    size_t n = kind == ECON_LIM_SINC   ? (size_t)((const mp_sinc_choice *)c)->hwmax
               : kind == ECON_LIM_GRID ? 2 + MP_PRF_NCORE
                                       : 1;
    int shown;
#pragma omp atomic read seq_cst
    shown = cache->n;
    double *emax = find_limits(cache, shown, c, kind, sky, ron, frac);
    if (emax)
        return emax;
#pragma omp critical(mp_econ_limits)
    {
        emax = find_limits(cache, cache->n, c, kind, sky, ron, frac);
        if (!emax && cache->n < MP_ECON_CACHE_MAX &&
            (emax = malloc(n * sizeof *emax))) {
            fill_limits(c, kind, sky, ron, frac, emax, cost);
            int i = cache->n;
            cache->e[i].c = c;
            cache->e[i].kind = kind;
            cache->e[i].sky = sky;
            cache->e[i].ron = ron;
            cache->e[i].frac = frac;
            cache->e[i].emax = emax;
#pragma omp atomic write seq_cst
            cache->n = i + 1;
        }
    }
    return emax;
}

/* The run cache's sky level: the sky rounded down to a quarter octave. */
static double cache_sky(double sky)
{
    return sky > 1.0 ? exp2(floor(4.0 * log2(sky)) / 4.0) : 0.0;
}

int mp_econ_grid_limits(mp_econ_cache *cache, const mp_prf_cache *g, double sky, double ron,
                        double frac, double *emax, mp_prf_tiers *tiers)
{
    mp_frame_report cost;
    memset(&cost, 0, sizeof cost);
    const double *e = cache && g ? cached_limits(cache, g, ECON_LIM_GRID, cache_sky(sky), ron,
                                                 frac, &cost)
                                 : NULL;
    if (!e)
        return 1;
    if (emax)
        *emax = e[0];
    if (tiers) {
        tiers->lin = e[1];
        memcpy(tiers->core, e + 2, sizeof tiers->core);
    }
    return 0;
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
 * (and neighbours are painted exactly); *tiers the cheaper modes' (zeroed
 * with NaN). */
static double grid_limit(const mp_prf_cache *g, double sky, double ron, double frac, size_t ng,
                         mp_econ_cache *cache, double runfits, mp_frame_report *cost,
                         mp_prf_tiers *tiers)
{
    memset(tiers, 0, sizeof *tiers);
    if (!g)
        return 0.0;
    if (cache && runfits > MP_SINC_LIMITS_EVALS) {
        const double *e = cached_limits(cache, g, ECON_LIM_GRID, cache_sky(sky), ron, frac, cost);
        if (e) {
            tiers->lin = e[1];
            memcpy(tiers->core, e + 2, sizeof tiers->core);
            return e[0];
        }
    }
    if (ng > MP_SINC_LIMITS_EVALS) {
        charge(cost, 2 * MP_SINC_LIMITS_EVALS, g, ECON_LIM_GRID);
        mp_prf_cache_tiers(g, sky, ron, frac, 1, tiers);
        return mp_prf_cache_limit(g, sky, ron, frac);
    }
    return NAN;
}

/* Whether the level serves a group whose brightest star has flux e (≤ 0
 * or NaN: unknown, it does not); cost counts criterion evaluations. */
int ff_level_serves(const level_rule *k, double e, mp_frame_report *cost)
{
    if (!k->lv || !(e > 0))
        return 0;
    if (!isnan(k->emax))
        return e <= k->emax;
    charge(cost, 1, k->lv, ECON_LIM_LEVEL);
    return mp_ss_level_serves(k->lv, e, k->sky, k->ron, k->frac);
}

void ff_rules_free(frame_rules *R)
{
    for (int l = 0; l <= MP_SS_MAXLEVELS; l++)
        if (R->kern[l].owned)
            free(R->kern[l].emax);
}

/* The half-width for a group whose brightest star has flux e (≤ 0 or NaN:
 * unknown, the full kernel); cost counts bound evaluations. */
int ff_kernel_for(const kernel_rule *k, int hwfull, double e, mp_frame_report *cost)
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
    double med = k ? mp_select_kth(v, k, k / 2) : 0.0;   /* serial: no sort (issue 14) */
    free(v);
    return med;
}

/* The frame's economy rules for the tables o points at (fit_group_local):
 * the coarser levels' and kernels' choices and the phase grid's limit on
 * the stars' median start sky.  Nonzero when out of memory. */
int ff_rules_setup(frame_rules *R, const mp_frame *f, const mp_frame_opts *o,
                       const star_state *st, size_t n, size_t ng, double runfits,
                       mp_frame_report *rep)
{
    ff_rules_free(R);
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
    int lgrids = 0;
    for (int l = 0; l < R->nss; l++) {
        const mp_prf_cache *g = R->ss[l].grid;
        R->lgrid[l] = ((o->ss_grid >> l) & 1) && g && g->G > 0 ? g : NULL;
        lgrids |= R->lgrid[l] != NULL;
    }
    R->gsky = o->grid || lgrids ? median_sky(st, n) : 0.0;
    R->gron = f->rdnoise;
    R->gfrac = o->sincfrac;
    R->gemax = grid_limit(o->grid, R->gsky, f->rdnoise, o->sincfrac, ng, o->cache, runfits, rep,
                          &R->gtiers);
    for (int l = 0; l < R->nss; l++)
        R->lgemax[l] = grid_limit(R->lgrid[l], R->gsky, f->rdnoise, o->sincfrac, ng, o->cache,
                                  runfits, rep, &R->lgtiers[l]);
    return nomem;
}

/* Economy in a sequential run: add ops (exact-render work just done) to
 * the run's count and, when more groups follow (more), point oc at the
 * tables that now pay, the rules renewed when they changed.  Nonzero with
 * err on failure. */
int ff_learn_and_choose(const mp_frame *f, const mp_frame_opts *o, mp_frame_opts *oc,
                            frame_rules *R, const star_state *st, size_t n, size_t ng,
                            double runfits, double ops, int more, mp_frame_report *rep, char *err)
{
    mp_econ_learn(o->cache, ops);
    if (!more)
        return 0;
    const void *had[3] = {oc->sinc, oc->ss, oc->grid};
    int had_bits = oc->ss_grid;
    double sp = 0.0;
    if (mp_econ_choose(o->cache, runfits, oc->fit.fitrad, oc, &sp, err))
        return 1;
    rep->ops_tables += sp;
    if ((had[0] != oc->sinc || had[1] != oc->ss || had[2] != oc->grid ||
         had_bits != oc->ss_grid) &&
        ff_rules_setup(R, f, oc, st, n, ng, runfits, rep)) {
        snprintf(err, MP_ERRLEN, "out of memory");
        return 1;
    }
    return 0;
}
