/* fit_frame.c — fitting every star of a table on one frame as ALLSTAR does
 * (anchors.md §1.6): groups fitted simultaneously, in parallel, each on a
 * local copy of its pixels from which the light of every other star has
 * been subtracted; close pairs merged and insignificant stars rejected, the
 * group refitted after each change. */
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include "fit/frame_priv.h"

void mp_frame_opts_default(mp_frame_opts *o)
{
    mp_fit_opts_default(&o->fit);
    o->fit.fitrad = 5.0;
    o->fit.warm_sky = 1;
    o->magzero = 0.0;
    o->mergerad = NAN;
    o->minsnr = 2.0;
    o->passes = 2;
    o->loosetol = 0.0;
    o->decidetol = MP_DECIDE_TOL;
    o->cropfrac = 0.02;
    o->refittol = 0.1;
    o->couplefrac = 0.1;
    o->sinc = NULL;
    o->sincfrac = 0.1;
    o->grid = NULL;
    o->ss = NULL;
    o->nss = 0;
    o->ss_sinc = ~0;
    o->ss_grid = ~0;
    o->ssfrac = 0.1;
    o->cache = NULL;
    o->fits = 0.0;
    o->learn = 0;
    o->win = 0.0;
    o->psfdx = o->psfdy = 0.0;
}

/* Column of a table by the first name present, -1 if none. */
static int col_any(const mp_table *t, const char *a, const char *b)
{
    int c = mp_table_col(t, a);
    return c >= 0 ? c : (b ? mp_table_col(t, b) : -1);
}

/* A star's place in the fit's order: by group, then by row. */
typedef struct {
    double id;
    long row;
} group_key;

static int cmp_group(const void *a, const void *b)
{
    const group_key *x = a, *y = b;
    if (x->id != y->id)
        return (x->id > y->id) - (x->id < y->id);
    return (x->row > y->row) - (x->row < y->row);
}

int mp_fit_table(const mp_frame *f, const mp_prf_model *m, const mp_frame_opts *o,
                 mp_table *t, mp_frame_report *rep, char *err)
{
    return mp_fit_table_mem(f, m, o, t, NULL, rep, err);
}

/* Row i's sky order as an earlier fit wrote it (SKYORD_PSF, column co):
 * under warm_sky its group starts there, as from the fit's memory in a
 * pipeline's later rounds (frame_memory.c), so that `fit` of a pipeline's
 * catalog goes on from the pipeline's last pass instead of from a
 * constant sky (47 Tuc 512² built: 8.5 % of the stars moved by more than
 * 1 sigma without it).  0 where there is none, or where the star's fit
 * did not converge (FLAGS, column cf: ff_warm_order). */
static int table_sky_order(const mp_table *t, size_t i, int co, int cf)
{
    double v = co >= 0 ? mp_table_get(t, i, co) : NAN;
    double fl = cf >= 0 ? mp_table_get(t, i, cf) : 0.0;
    if (!(v >= 1.0 && v <= MP_SKY_MAXORDER) || !isfinite(fl))
        return 0;
    return ff_warm_order((int)fl, (int)v);
}

/* The stars of t into st (n rows, 0-based row order kept in row), sorted
 * by group, and each group's first index in gs (ng + 1 entries, the
 * count in *ng): one group for a whole-frame fit, one per GROUP_ID, a
 * star without one alone.  Nonzero with err on a bad table. */
static int read_stars(const mp_table *t, int whole, double maxnum, star_state *st, size_t *gs,
                      size_t *ng, char *err)
{
    int cx = col_any(t, "XPSF_IMAGE", "X_IMAGE"), cy = col_any(t, "YPSF_IMAGE", "Y_IMAGE");
    if (cx < 0 || cy < 0) {
        snprintf(err, MP_ERRLEN, "table has no X_IMAGE/Y_IMAGE or XPSF_IMAGE/YPSF_IMAGE columns");
        return 1;
    }
    int cf = col_any(t, "FLUX_PSF", "FLUX"), cs = col_any(t, "SKY_PSF", "BACKGROUND");
    int cb = mp_table_col(t, "BACKGROUND");
    int cg = mp_table_col(t, "GROUP_ID"), cn = mp_table_col(t, "NUMBER");
    int co = mp_table_col(t, "SKYORD_PSF"), cfl = mp_table_col(t, "FLAGS");
    size_t n = t->nrow;
    /* The keys sorted, not the states (232 B each: the sort was a sixth
     * of the fit's serial time, issue 14). */
    group_key *key = malloc((n ? n : 1) * sizeof *key);
    if (!key) {
        snprintf(err, MP_ERRLEN, "out of memory");
        return 1;
    }
    for (size_t i = 0; i < n; i++) {
        if (!isfinite(mp_table_get(t, i, cx)) || !isfinite(mp_table_get(t, i, cy))) {
            snprintf(err, MP_ERRLEN, "row %zu: position is not a finite number", i + 1);
            free(key);
            return 1;
        }
        double g = cg >= 0 ? mp_table_get(t, i, cg) : NAN;
        key[i].id = whole ? 0.0 : (isfinite(g) ? g : -1.0 - (double)i);
        key[i].row = (long)i;
    }
    qsort(key, n, sizeof *key, cmp_group);
    /* In parallel: the first touch of the states' pages (calloc's) was
     * most of what read_stars cost. */
#pragma omp parallel for schedule(static)
    for (size_t k = 0; k < n; k++) {
        size_t i = (size_t)key[k].row;
        st[k].row = key[k].row;
        st[k].id = key[k].id;
        st[k].alive = 1;
        st[k].s.x = mp_table_get(t, i, cx);
        st[k].s.y = mp_table_get(t, i, cy);
        st[k].s.flux = cf >= 0 ? mp_table_get(t, i, cf) : NAN;
        st[k].s.sky = cs >= 0 ? mp_table_get(t, i, cs) : NAN;
        st[k].sky_found = cb >= 0 ? mp_table_get(t, i, cb) : NAN;
        st[k].s.sky_order = table_sky_order(t, i, co, cfl);
        st[k].number = maxnum >= 0 ? mp_table_get(t, i, cn) : (double)i;
        st[k].bound = INFINITY;          /* not fitted yet */
    }
    free(key);
    *ng = 0;
    for (size_t i = 0; i < n; i++)
        if (i == 0 || st[i].id != st[i - 1].id)
            gs[(*ng)++] = i;
    gs[*ng] = n;
    return 0;
}

void mp_frame_report_add(mp_frame_report *d, const mp_frame_report *r)
{
    d->merged += r->merged;
    d->rejected += r->rejected;
    d->iterations += r->iterations;
    d->fits += r->fits;
    d->kcalls += r->kcalls;
    for (int c = 0; c < MP_REFIT_CAUSES; c++) {
        d->refits[c] += r->refits[c];
        d->refit_steps[c] += r->refit_steps[c];
    }
    d->kshort += r->kshort;
    d->khw += r->khw;
    d->kept += r->kept;
    d->kbounds += r->kbounds;
    d->kcoarse += r->kcoarse;
    d->kcache += r->kcache;
    d->klin += r->klin;
    d->kcore += r->kcore;
    d->kstars += r->kstars;
    d->cropped += r->cropped;
    d->envelopes += r->envelopes;
    d->ops_tables += r->ops_tables;
    d->ops_saved += r->ops_saved;
    d->render_ops += r->render_ops;
}

/* by[0 .. g1 − g0): the groups g0..g1 of gs, largest first (ties in
 * order).  Handed out so (schedule dynamic), the long fits start first
 * and a pass does not wait on one started last: 47 Tuc built's twelve
 * passes, their group fits timed on one thread and handed greedily to 16,
 * take 0.269 s so against 0.309 s in index order (the bound, the largest
 * fit or the sum over 16 a pass, 0.268 s).  Which group a thread takes
 * does not change its fit, so neither does this order. */
static void largest_first(const size_t *gs, size_t g0, size_t g1, mp_work_item *by)
{
    for (size_t g = g0; g < g1; g++)
        by[g - g0] = (mp_work_item){gs[g + 1] - gs[g], g};
    mp_costliest_first(by, g1 - g0);
}

/* One pass over the ng groups (gs, ff_fit_group_local), in parallel,
 * each against the light of every other star in all; its counts in pr.
 * Economy in a sequential run (oc->learn): the groups in chunks (the
 * first sixteenth, the first quarter, the rest), and after each the
 * exact-render work done counts toward the run's tables; a table that
 * now pays serves the groups after it (ff_learn_and_choose, more: a
 * later pass follows).  The chunks' ends and the work (sums of whole
 * numbers) do not depend on the threads.  Nonzero with err on failure. */
static int fit_pass(const mp_frame *f, const mp_prf_model *m, mp_frame_opts *oc, frame_rules *R,
                    const float *all, const crop_rule *crop, star_state *st, size_t n,
                    const size_t *gs, size_t ng, double mergerad, int economy, double runfits,
                    int more, mp_frame_report *pr, char *err)
{
    int learn = oc->cache && oc->learn;
    mp_work_item *by = malloc((ng ? ng : 1) * sizeof *by);
    if (!by) {
        snprintf(err, MP_ERRLEN, "out of memory");
        return 1;
    }
    for (size_t g0 = 0, g1; g0 < ng; g0 = g1) {
        g1 = !learn ? ng : (g0 < ng / 16 ? ng / 16 : (g0 < ng / 4 ? ng / 4 : ng));
        g1 = g1 > g0 ? g1 : g0 + 1;
        largest_first(gs, g0, g1, by);
        double before = pr->render_ops;
        int failed = 0;
        char ferr[MP_ERRLEN] = "";
        /* Each thread sums its groups' counts, then adds them once: a
         * lock per group was 9 600 entries a 2048² run from every thread. */
#pragma omp parallel reduction(+ : failed)
        {
            mp_frame_report mine = {0};
#pragma omp for schedule(dynamic)
            for (size_t q = 0; q < g1 - g0; q++) {
                char e[MP_ERRLEN];
                mp_frame_report r = {0};
                size_t g = by[q].i;
                int k = (int)by[q].cost;           /* its stars */
                if (ff_fit_group_local(f, m, oc, mergerad, R, all, crop, st + gs[g], k, economy,
                                       economy, &r, e)) {
                    failed++;
#pragma omp critical(fit_table_error)
                    snprintf(ferr, sizeof ferr, "%s", e);
                }
                mp_frame_report_add(&mine, &r);
            }
#pragma omp critical(fit_table_report)
            mp_frame_report_add(pr, &mine);
        }
        if (failed) {
            snprintf(err, MP_ERRLEN, "%s", ferr);
            free(by);
            return 1;
        }
        if (learn && ff_learn_and_choose(f, oc, oc, R, st, n, ng, runfits, pr->render_ops - before,
                                         g1 < ng || more, pr, err)) {
            free(by);
            return 1;
        }
    }
    free(by);
    return 0;
}

/* What the report says of the fit as it ends: the live stars not
 * converged, and each group's sky order as it stands (kept groups keep
 * theirs). */
static void final_counts(const star_state *st, size_t n, const size_t *gs, size_t ng,
                         mp_frame_report *rep)
{
    for (size_t i = 0; i < n; i++)
        if (st[i].alive && (st[i].s.flags & MP_FLAG_NOCONV))
            rep->noconv++;
    for (size_t g = 0; g < ng; g++)
        for (size_t i = gs[g]; i < gs[g + 1]; i++)
            if (st[i].alive) {
                int so = st[i].s.sky_order;
                rep->sky_groups[so > 0 && so <= MP_SKY_MAXORDER ? so : 0]++;
                break;
            }
}

/* One star's render window in its group's fit, in px²: the group's box
 * (its stars ± r, cut to the frame, as lm_pixels.c draws it) ∩ the star's
 * PSF box ∩ its crop radius (at least r + 1), as lm_render.c renders it. */
static double star_window(const mp_frame *f, const mp_prf_model *m, const crop_rule *crop,
                          const star_state *s, const double box[4], double r)
{
    long px0, py0;
    int pw, ph;
    mp_prf_box(m, s->s.x, s->s.y, &px0, &py0, &pw, &ph);
    double rad = crop->env ? ff_crop_radius(crop, &s->s) : INFINITY;
    rad = rad > r + 1.0 ? rad : r + 1.0;
    double x0 = fmax(fmax(ceil(box[0] - r), 1.0), fmax((double)px0, ceil(s->s.x - rad)));
    double x1 = fmin(fmin(floor(box[1] + r), (double)f->im.nx),
                     fmin((double)(px0 + pw - 1), floor(s->s.x + rad)));
    double y0 = fmax(fmax(ceil(box[2] - r), 1.0), fmax((double)py0, ceil(s->s.y - rad)));
    double y1 = fmin(fmin(floor(box[3] + r), (double)f->im.ny),
                     fmin((double)(py0 + ph - 1), floor(s->s.y + rad)));
    return x1 >= x0 && y1 >= y0 ? (x1 - x0 + 1.0) * (y1 - y0 + 1.0) : 0.0;
}

/* Economy's window (mp_frame_opts.win): the side of the square of the
 * mean render window of the frame's stars, from their start values; 0
 * for whole-frame fits (the plan's own INFINITY). */
static double plan_window(const mp_frame *f, const mp_prf_model *m, const crop_rule *crop,
                          const star_state *st, const size_t *gs, size_t ng, double r)
{
    double sum = 0.0;
    size_t cnt = 0;
    for (size_t g = 0; g < ng && isfinite(r); g++) {
        double box[4] = {INFINITY, -INFINITY, INFINITY, -INFINITY};
        for (size_t i = gs[g]; i < gs[g + 1]; i++) {
            box[0] = fmin(box[0], st[i].s.x);
            box[1] = fmax(box[1], st[i].s.x);
            box[2] = fmin(box[2], st[i].s.y);
            box[3] = fmax(box[3], st[i].s.y);
        }
        for (size_t i = gs[g]; i < gs[g + 1]; i++, cnt++)
            sum += star_window(f, m, crop, &st[i], box, r);
    }
    return cnt ? sqrt(sum / (double)cnt) : 0.0;
}

/* What one frame fit shares among its steps (mp_fit_table_mem). */
typedef struct {
    const mp_frame *f;
    const mp_prf_model *m;
    mp_frame_opts oc;            /* the options with economy's tables and the crop */
    frame_rules R;
    crop_rule crop;
    star_state *st;              /* n stars, sorted by group */
    size_t n, *gs, ng;           /* group g: st[gs[g] .. gs[g + 1]) */
    double mergerad, runfits, maxnum;
    int passes, alone, economy;
    paint_rule held;             /* the paint the refit bounds hold for */
    star_state *gone;            /* stars mem held that the table does not */
    size_t ngone;
    float *all, *lent;           /* the model image, in the caller's buffer when lent */
} frame_fit;

/* The economy tables that pay for this run's star fits (the run's planned
 * count or this frame's stars), built on first need; the table and kernel
 * choices on the frame's median start sky (0, the safe side, when no star
 * has one); the limits tables only when cheaper than each group's own
 * evaluation (rule_init); the crop the group fits render each star to.
 * One group (a whole-frame fit, or one star) has nobody else's light to
 * subtract, so neither the neighbours' model nor its crop envelope is
 * built (economy's crop would cost a PSF render per ¼-px phase per frame
 * and save nothing).  Nonzero with err on failure. */
static int set_rules(frame_fit *F, const mp_frame_opts *o, mp_frame_report *rep, char *err)
{
    F->alone = F->ng <= 1;
    F->passes = F->alone ? 1 : (o->passes < 1 ? 1 : o->passes);
    if (!F->alone && ff_crop_init(F->f, F->m, o->cropfrac, o->cache, &F->crop)) {
        snprintf(err, MP_ERRLEN, "out of memory");
        return 1;
    }
    rep->envelopes += F->crop.env != NULL;
    mp_frame_opts oe = *o;
    if (o->cache && !(oe.win > 0))
        oe.win = plan_window(F->f, F->m, &F->crop, F->st, F->gs, F->ng, o->fit.fitrad);
    rep->win = oe.win;
    F->runfits = o->fits > (double)F->n ? o->fits : (double)F->n;
    if (mp_econ_choose(o->cache, F->runfits, o->fit.fitrad, &oe, &rep->ops_tables, err))
        return 1;
    F->R.ops_full = oe.cache ? mp_econ_render_ops(F->m, F->m->sinc_hw, oe.fit.fitrad) : 0.0;
    rep->ops_render = F->R.ops_full;
    if (ff_rules_setup(&F->R, F->f, &oe, F->st, F->n, F->ng, F->runfits, rep)) {
        snprintf(err, MP_ERRLEN, "out of memory");
        return 1;
    }
    F->oc = oe;
    F->oc.fit.crop = F->crop.env ? &F->crop : NULL;
    F->oc.fit.stats = 0;        /* once, at the end (model_errors) */
    return 0;
}

/* The refit bounds brought up to date for the neighbours' model as
 * ff_all_stars paints it now (F's grid and flux limit), the stars gone
 * from the table counted once.  Nonzero with err when out of memory. */
static int bounds_now(frame_fit *F, char *err)
{
    paint_rule now = {F->oc.grid, F->R.gemax, F->R.gtiers, 1};
    double ops = 0.0;
    int rc = ff_update_bounds(F->f, F->m, &F->crop, &now, &F->held, F->oc.fit.fitrad,
                              F->oc.refittol, F->st, F->n, F->gs, F->ng, F->gone, F->ngone, &ops);
    mp_econ_learn_paint(F->oc.cache, ops);
    free(F->gone);
    F->gone = NULL;
    F->ngone = 0;
    if (rc)
        snprintf(err, MP_ERRLEN, "out of memory");
    return rc;
}

/* The passes: each subtracts every neighbour with its latest values (in
 * the first only those with a start flux, find's FLUX, can be) and fits
 * the groups; economy ends them when no group was refitted (every later
 * pass would see the same light).  Nonzero with err on failure. */
/* Each live star fitted in this call (the passes leave its PRF statistics
 * unset: mp_fit_opts.stats) given them and its model errors, once, on
 * the model's own table: a star fitted in several passes was rendered
 * whole, for them alone, after each (47 Tuc 512² with Tiny Tim's table:
 * 19 462 renders of the ±40 px PRF for 7 130 stars over three rounds,
 * 5.7 % of the instructions).  Nonzero with err when out of memory. */
static int model_errors(frame_fit *F, char *err)
{
    int nomem = 0;
#pragma omp parallel
    {
        mp_prf_work wk = {0};
        wk.grid = F->oc.grid;
#pragma omp for schedule(dynamic, 16)
        for (size_t i = 0; i < F->n; i++) {
            mp_star *s = &F->st[i].s;
            if (F->st[i].alive && s->npix > 0 && s->st.volume == 0.0 &&
                mp_star_model_errors(F->m, F->f->rdnoise, s, &wk)) {
#pragma omp atomic write
                nomem = 1;
            }
        }
        mp_prf_work_free(&wk);
    }
    if (nomem)
        snprintf(err, MP_ERRLEN, "out of memory");
    return nomem;
}

static int run_passes(frame_fit *F, mp_frame_report *rep, char *err)
{
    for (int pass = 0; pass < F->passes; pass++) {
        if (!F->lent)
            free(F->all);
        F->all = NULL;
        if (!F->alone && !(F->all = ff_all_stars(F->f, F->m, F->st, F->n, &F->crop, &F->oc, &F->R,
                                                 F->lent, &rep->cropped))) {
            snprintf(err, MP_ERRLEN, "out of memory for the model image");
            return 1;
        }
        if (F->economy && bounds_now(F, err))
            return 1;
        mp_frame_report pr = {0};
        if (fit_pass(F->f, F->m, &F->oc, &F->R, F->all, &F->crop, F->st, F->n, F->gs, F->ng,
                     F->mergerad, F->economy, F->runfits, pass + 1 < F->passes, &pr, err))
            return 1;
        mp_frame_report_add(rep, &pr);
        if (F->economy && pr.fits == 0) {
            rep->kept += (long)F->ng * (F->passes - pass - 1);
            break;
        }
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
    frame_fit F;
    memset(&F, 0, sizeof F);
    F.f = f;
    F.m = m;
    F.n = t->nrow;
    F.maxnum = mem ? ff_max_number(t) : -1.0;
    F.st = calloc(F.n ? F.n : 1, sizeof *F.st);
    F.gs = malloc((F.n + 1) * sizeof *F.gs);
    size_t npix = (size_t)f->im.nx * (size_t)f->im.ny;
    F.lent = mem && mem->scratch && mem->nscratch >= npix ? mem->scratch : NULL;
    int whole = !isfinite(o->fit.fitrad), rc = 1;
    if (!F.st || !F.gs) {
        snprintf(err, MP_ERRLEN, "out of memory");
        goto done;
    }
    if (read_stars(t, whole, F.maxnum, F.st, F.gs, &F.ng, err))
        goto done;
    rep->nstars = (long)F.n;
    rep->ngroups = (long)F.ng;
    F.mergerad = isfinite(o->mergerad) ? o->mergerad : 0.4 * mp_prf_fwhm(m);
    if (set_rules(&F, o, rep, err))
        goto done;
    /* Economy: a star refitted only when its surroundings changed
     * (refittol); never in whole-frame fits. */
    F.economy = F.oc.refittol > 0 && !whole && F.ng > 1;
    int memory = mem && F.maxnum >= 0;
    if (F.economy && memory && ff_recall(mem, t, F.st, F.n, &F.held, &F.gone, &F.ngone)) {
        snprintf(err, MP_ERRLEN, "out of memory");
        goto done;
    }
    if (run_passes(&F, rep, err) || model_errors(&F, err))
        goto done;
    final_counts(F.st, F.n, F.gs, F.ng, rep);
    /* The last pass's changes too: the next call starts from them. */
    if (F.economy && memory && bounds_now(&F, err))
        goto done;
    if (memory && ff_remember(mem, F.st, F.n, F.maxnum, &F.held)) {
        snprintf(err, MP_ERRLEN, "out of memory");
        goto done;
    }
    rep->grid = F.oc.grid;
    rc = ff_write_columns(t, F.st, F.n, F.oc.magzero, err);
done:
    free(F.gone);
    if (!F.lent)
        free(F.all);
    ff_rules_free(&F.R);
    free(F.st);
    free(F.gs);
    free(F.crop.env);
    return rc;
}
