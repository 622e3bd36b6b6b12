/*
 * frame_priv.h — inside fit/ only: what fitting a table on a frame
 * (mp_fit_table_mem, fit_frame.c) shares among its files: frame_rules.c
 * (economy's per-group choices), frame_paint.c (stars painted on the
 * frame), frame_group.c (one group, merges and rejections),
 * frame_refit.c (a group against its neighbours' light, refitted when it
 * changed), frame_memory.c (across calls), frame_columns.c (outputs).
 */
#ifndef MATPHOT_FIT_FRAME_PRIV_H
#define MATPHOT_FIT_FRAME_PRIV_H

#include "fit/econ_state.h"

/* The state of one star through the passes. */
typedef struct {
    mp_star s;          /* current estimate (global coordinates) */
    double id;          /* group id */
    long row;
    double number;      /* NUMBER (the memory's key across calls), or row */
    double sky_found;   /* BACKGROUND: the sky find saw it on (NaN: none) */
    int alive;
    /* Economy (frame_bound.c): an upper bound of √Σ((others' light now −
     * then)/σ)² over its fitting region (the frame's pixels within fitrad
     * of it) since it was last fitted; INFINITY: not fitted yet.  A bound,
     * not the light seen then: 8 bytes a star where the disc of that light
     * was ~330, held for every star between rounds (issue 14). */
    double bound;
    /* Its light changed since the bounds were last brought up to date:
     * MOVED_FIT by its group's fit, MOVED_CALL between calls (0: not);
     * from (ox, oy, oflux, osky), or from none when !olight. */
    unsigned char moved, olight;
    double ox, oy, oflux, osky;
} star_state;

enum { MOVED_FIT = 1, MOVED_CALL = 2 };

/* The paint the bounds hold for (ff_all_stars'): its phase grid and flux
 * limits (from the grid up to gemax, in its cheaper modes up to tiers');
 * set: 0 until the bounds hold for one. */
typedef struct {
    const struct mp_prf_cache_s *grid;
    double gemax;
    mp_prf_tiers tiers;
    int set;
} paint_rule;

typedef mp_prf_crop crop_rule;

/* The sky order a star's group may start at when it is fitted again
 * (warm_sky): its last one, unless that fit did not converge (as
 * first_order in fit_group.c rules for a group). */
static inline int ff_warm_order(int flags, int order)
{
    return flags & MP_FLAG_NOCONV ? 0 : order;
}

/* Equal, NaN equal to NaN (a star's sky may be NaN: none measured). */
static inline int ff_same_value(double a, double b)
{
    return a == b || (a != a && b != b);
}

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
    const mp_prf_cache *lgrid[MP_SS_MAXLEVELS];  /* ss[l]'s own phase grid (NULL:
                                 * its groups render exactly) */
    double lgemax[MP_SS_MAXLEVELS];  /* its flux limit, as gemax */
    mp_prf_tiers gtiers, lgtiers[MP_SS_MAXLEVELS];  /* the same of the
                                 * bilinear interpolation and the core tiers
                                 * (zeroed: cubic) */
    double ops_full;            /* a render of the model as given (economy's unit) */
} frame_rules;

/* A star's last fit, by NUMBER, across calls: what its table row does
 * not hold (the row holds the rest of its mp_star, as ff_write_columns
 * wrote it: ff_recall reads it back), its refit bound, and its position,
 * flux and sky, by which a row still holding that fit is known (and its
 * light then painted when it does not).  Issue 14: the whole mp_star
 * here was 200 bytes a star held between rounds, the disc of the light
 * it saw ~330 more. */
typedef struct {
    double x, y, flux, sky;
    double bound;        /* star_state.bound as the call ended */
    uint32_t number;     /* its NUMBER (ff_max_number: below 1e8) */
    int dofstar, sky_order, flags;
} star_memo;

/* The stars remembered, dense, and where each NUMBER's is: NUMBERs run to
 * ~3x the stars kept (find numbers its candidates before the screen), so
 * an array of entries indexed by NUMBER was 3x the room (issue 14). */
struct mp_fit_memory {
    star_memo *s;        /* ns entries */
    size_t ns;
    uint32_t *at;        /* by NUMBER: 1 + its entry in s, or 0 */
    size_t nat;
    paint_rule paint;    /* the paint the entries' bounds hold for */
    int forgot;          /* mp_fit_memory_forget: only the sky orders hold */
    float *scratch;      /* lent: room for the model of every star */
    size_t nscratch;
};

/* frame_rules.c.  ff_rules_setup: the frame's rules for the tables o
 * points at, on the stars' median start sky; nonzero when out of memory.
 * ff_rules_free: frees them.  ff_learn_and_choose: in a sequential run,
 * the exact-render work ops counted and oc pointed at the tables that now
 * pay (when more groups follow); nonzero with err on failure.
 * ff_level_serves, ff_grid_serves: whether a coarser level, the phase
 * grid, serves a group whose brightest star has flux e; ff_kernel_for: its
 * sinc half-width (hwfull the model's).  Each charges its bound
 * evaluations to cost. */
int ff_rules_setup(frame_rules *R, const mp_frame *f, const mp_frame_opts *o,
                   const star_state *st, size_t n, size_t ng, double runfits,
                   mp_frame_report *rep);
void ff_rules_free(frame_rules *R);
int ff_learn_and_choose(const mp_frame *f, const mp_frame_opts *o, mp_frame_opts *oc,
                        frame_rules *R, const star_state *st, size_t n, size_t ng,
                        double runfits, double ops, int more, mp_frame_report *rep, char *err);
int ff_level_serves(const level_rule *k, double e, mp_frame_report *cost);
int ff_grid_serves(const frame_rules *R, const mp_prf_cache *g, double e, mp_frame_report *cost);
/* ff_group_grid: the phase grid a group fitted with ss[l] (l = nss: the
 * model's table, whose grid is g) draws its PRF from, or NULL (exact
 * renders), and in *emax the largest start flux of a star it serves (the
 * others are drawn exactly); with the frame's flux limit, any group with
 * a star of flux e > 0; without it (few groups), the group whose brightest
 * star e passes the bound, *emax INFINITY; in *tiers the limits of its
 * cheaper modes (zeroed without the frame's limit).  Charges as
 * ff_grid_serves. */
const mp_prf_cache *ff_group_grid(const frame_rules *R, const mp_prf_cache *g, int l, double e,
                                  double *emax, mp_prf_tiers *tiers, mp_frame_report *cost);
int ff_kernel_for(const kernel_rule *k, int hwfull, double e, mp_frame_report *cost);

/* frame_paint.c.  ff_crop_init: the crop rule of cropfrac, its envelope
 * cache's (mp_econ_envelope; NULL: measured here; nonzero when out of
 * memory).  ff_crop_radius: how far star s is painted.
 * ff_paint: star s times sign added to img (a window at (x0, y0), w × h)
 * out to rad; ff_painted: whether it paints anything at all (a finite,
 * nonzero flux at a sane place).  ff_all_stars: every live star with a flux painted on one
 * image (lent, or allocated; NULL when out of memory), the cropped
 * paints counted in *cut. */
int ff_crop_init(const mp_frame *f, const mp_prf_model *m, double cropfrac, mp_econ_cache *cache,
                 crop_rule *c);
double ff_crop_radius(const crop_rule *c, const mp_star *s);
int ff_painted(const mp_star *s);
int ff_paint(const mp_prf_model *m, const mp_star *s, double sign, double rad, float *img,
             long x0, long y0, long w, long h, mp_prf_work *wk, double **buf, size_t *cap,
             int *cut);
float *ff_all_stars(const mp_frame *f, const mp_prf_model *m, const star_state *st, size_t n,
                    const crop_rule *crop, const mp_frame_opts *o, const frame_rules *R,
                    float *lent, long *ncut);

/* frame_group.c.  ff_fit_one_group: members st[0..n-1] fitted on f (their
 * positions shifted by (dx, dy)), merged and rejected until stable;
 * nonzero with err on failure.  ff_group_window: the window a group's fit
 * reads (its stars ± r and a pixel), clipped to the frame. */
int ff_fit_one_group(const mp_frame *f, const mp_prf_model *m, const mp_frame_opts *o,
                     double mergerad, const frame_rules *R, star_state *st, int n, double dx,
                     double dy, mp_frame_report *rep, char *err);
void ff_group_window(const mp_frame *f, const star_state *st, int n, double r, long *x0,
                     long *y0, long *w, long *h);

/* frame_refit.c: one group fitted on a local copy of its pixels with
 * every other star's light (all) subtracted, or kept when that light has
 * not changed since its last fit (may_keep, economy); nonzero with err on
 * failure. */
int ff_fit_group_local(const mp_frame *f, const mp_prf_model *m, const mp_frame_opts *o,
                       double mergerad, const frame_rules *R, const float *all,
                       const crop_rule *crop, star_state *st, int n, int may_keep, int economy,
                       mp_frame_report *rep, char *err);

/* frame_bound.c.  ff_update_bounds: every star's refit bound brought up
 * to date for the neighbours' model painted with rule now (ff_all_stars'):
 * each pending change of a star j's light (star_state.moved) adds its
 * norm over star k's fitting region (radius r) to k's bound, unless j
 * changed in k's own group fit (that fit saw it); the changes are then
 * cleared; so are the changes gone[0..ngone-1] (stars no longer in the
 * table: their light gone).  When now does not paint these stars as the
 * rule the bounds hold for (*held) did — another grid, or a flux limit
 * that draws one of them another way — every bound is INFINITY instead,
 * and *held becomes now.  A bound at or above tol (refittol) refits its
 * group whatever is added to it (group_kept): it becomes INFINITY and
 * takes no more (a change that reaches only such stars is not painted), so
 * every bound ends below tol, exactly as summed, or INFINITY.  Stars
 * sorted by group as gs says (ng groups).  *ops adds the exact renders'
 * work of the changes painted (economy learns it, mp_econ_learn_paint).
 * Nonzero when out of memory. */
int ff_update_bounds(const mp_frame *f, const mp_prf_model *m, const crop_rule *crop,
                     const paint_rule *now, paint_rule *held, double r, double tol,
                     star_state *st, size_t n, const size_t *gs, size_t ng,
                     const star_state *gone, size_t ngone, double *ops);

/* frame_memory.c.  ff_max_number: the table's largest NUMBER, or -1 when
 * it has none (or one not a whole number ≥ 0).  ff_recall: each star's
 * last fit and refit bound from mem and its row of t (the fit's columns);
 * a star whose row no longer holds that fit gets the change of its light
 * pending (MOVED_CALL), a star new to mem its light; the stars mem holds
 * that t does not come back in *gone (*ngone of them, their light gone:
 * the caller frees it); mem is then emptied, and *held gets the rule its
 * bounds hold for.  Nonzero when out of memory.  ff_remember: every live
 * star's fit and bound kept in mem, for the rule held (nonzero when out of
 * memory). */
double ff_max_number(const mp_table *t);
int ff_recall(mp_fit_memory *mem, const mp_table *t, star_state *st, size_t n,
              paint_rule *held, star_state **gone, size_t *ngone);
int ff_remember(mp_fit_memory *mem, const star_state *st, size_t n, double maxnum,
                const paint_rule *held);

/* frame_columns.c: the fitted columns of the live stars written into t
 * (MAG_PSF with magzero); nonzero with err on failure. */
int ff_write_columns(mp_table *t, const star_state *st, size_t n, double magzero, char *err);

#endif
