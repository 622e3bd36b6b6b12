/* econ_plan.c — economy's tables built only when they pay (issue 10).
 *
 * Why: each economy table is measured on the PSF before it can be used —
 * the sinc kernel's error at every half-width (fit/sinc_choice.c), each
 * coarser sampling's bias (fit/ss_choice.c), the phase grid
 * (fit/prf_cache.c) — and that costs PSF renders: the phase grid of a ×2
 * table alone is 22² renders with derivatives and 16² without, 150 times
 * the whole fit of one 60×60 frame.  Built up front, economy=yes cost 0.08
 * s against 0.01 s on one frame.  So a table is built only when the work it
 * can save on the star fits the run expects exceeds the work it costs, a
 * count decided before building:
 *
 *     fits · MP_ECON_RENDERS_PER_FIT · (saved per render) ≥ build + decisions
 *
 * all in multiply-adds of the damped-sinc shifts and bound sums
 * (render_ops below).  The saving is an upper bound (every star served by
 * the table's cheapest option), so a table that cannot pay is never built;
 * the run report counts what the tables cost and what they saved.  fits is
 * the run's (an @list's stars, mp_frame_opts.fits) or the frame's own; in
 * a pipeline frame (mp_frame_opts.learn: its rounds and passes) the
 * exact-render work its fits have already done counts too, times the
 * fraction of a render the table saves (mp_econ_learn, after each pass),
 * so a run whose fits take many iterations and wide windows (real frames
 * at χ²/dof ≫ 1, crowded groups) builds its tables once they would have
 * paid — never more than twice the work of knowing its length in advance.  Frames fitted in parallel
 * (fakes) plan on their count alone, so that no fit depends on the order
 * threads reach it.  Once built, a table is kept for the run. */
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include "fit/econ_state.h"
#include "fit/prf_axis.h"

#define NPH 16                  /* phases the bound tables measure (4×4) */

mp_econ_cache *mp_econ_cache_new(void)
{
    return calloc(1, sizeof(mp_econ_cache));
}

void mp_econ_cache_free(mp_econ_cache *c)
{
    if (!c)
        return;
    for (int i = 0; i < c->n; i++)
        free(c->e[i].emax);
    mp_sinc_choice_free(&c->sinc);
    for (int l = 0; l < MP_SS_MAXLEVELS; l++)
        mp_ss_level_free(&c->ss[l]);
    mp_prf_cache_free(&c->grid);
    mp_prf_cache_free(&c->spare);
    free(c->env);
    free(c);
}

double *mp_econ_envelope(mp_econ_cache *c, const mp_prf_model *m, int *nr)
{
    /* The cache's own model only: a local view (a section's field) or
     * another model is measured afresh. */
    if (!c || !c->offered || m->psf != c->psf || m->drf != c->model0.drf ||
        m->sinc_hw != c->model0.sinc_hw)
        return mp_prf_envelope(m, nr);
    int have;
#pragma omp critical(mp_econ_cache)
    have = c->env != NULL;
    if (!have) {
        /* Measured outside the lock (its renders run in parallel); a
         * thread that lost the race frees its own. */
        int n;
        double *e = mp_prf_envelope(m, &n);
        if (!e)
            return NULL;
#pragma omp critical(mp_econ_cache)
        if (!c->env) {
            c->env = e;
            c->env_nr = n;
            e = NULL;
        }
        free(e);
    }
    double *copy = NULL;
#pragma omp critical(mp_econ_cache)
    if ((copy = malloc((size_t)c->env_nr * sizeof *copy))) {
        memcpy(copy, c->env, (size_t)c->env_nr * sizeof *copy);
        *nr = c->env_nr;
    }
    return copy;
}

void mp_econ_cache_hand_grid(mp_econ_cache *from, mp_econ_cache *to)
{
    if (!from || !to || from->grid_state != ECON_BUILT)
        return;
    mp_prf_cache_free(&to->spare);
    to->spare = from->grid;
    memset(&from->grid, 0, sizeof from->grid);
    from->grid_state = ECON_UNASKED;
}

/* Multiply-adds of one render of a table of nx × ny elements (OVERSAMP
 * os) with half-width hw over a window of side W detector px (INFINITY:
 * the whole box), by the cheaper of render_table's two ways (sep: the
 * model's DRF allows the axis operators; fit/prf_axis.c mp_prf_axis_ops). */
static double render_ops(int nx, int ny, int os, int hw, int derivs, double W, int sep)
{
    double d = mp_prf_axis_ops(nx, ny, os, hw, derivs, W, W, 0);
    return sep ? fmin(d, mp_prf_axis_ops(nx, ny, os, hw, derivs, W, W, 1)) : d;
}

static double psf_ops(const mp_psf *p, int hw, int derivs, double W, int sep)
{
    return render_ops(p->nx, p->ny, p->os, hw, derivs, W, sep);
}

/* Multiply-adds of a variable PSF's evaluation at a star (fit/prf.c's
 * star_table): every term over the table elements a window of side W
 * reads (0 for a constant PSF). */
static double field_ops(const mp_psf *p, const mp_psf_field *f, int hw, double W)
{
    if (!f)
        return 0.0;
    double side = W * p->os + 2.0 * hw + 1.0;
    return (double)f->nterms * fmin(side, (double)p->nx) * fmin(side, (double)p->ny);
}

/* Whether the run's renders may take the axis operators. */
#define RSEP(c) mp_prf_axes_apply(&(c)->model0)

/* The coarser level's table size (mp_psf_rebin: ceil, kept odd). */
static void level_size(const mp_psf *p, int factor, int *nx, int *ny)
{
    *nx = (p->nx + factor - 1) / factor;
    *ny = (p->ny + factor - 1) / factor;
    *nx += !(*nx & 1);
    *ny += !(*ny & 1);
}

/* Detector pixels of the PSF's box (one more per axis for the phase). */
static double box_pixels(const mp_psf *p)
{
    double bx = ceil((double)p->nx / p->os) + 1.0, by = ceil((double)p->ny / p->os) + 1.0;
    return bx * by;
}

double mp_econ_eval_ops(const void *table, int kind)
{
    if (kind == ECON_LIM_SINC) {
        const mp_sinc_choice *s = table;
        return 3.0 * (double)s->nph * (double)s->npix;
    }
    if (kind == ECON_LIM_LEVEL) {
        const mp_ss_level *lv = table;
        return 22.0 * (double)lv->bias.nph * (double)lv->bias.npix;
    }
    const mp_prf_cache *g = table;
    return 3.0 * (double)g->nph * (double)g->npix;
}

int mp_econ_offer(mp_econ_cache *c, const mp_prf_model *m, int nlev, const int *lev_os,
                  int sinc, int grid_g)
{
    if (!c || m->psf->kind != MP_PSF_TABLE)
        return 0;
    c->offered = 1;
    c->psf = m->psf;
    c->field = m->psf->field;
    c->psf0 = *m->psf;              /* shares the table: measured at the origin */
    c->psf0.field = NULL;
    c->model0 = *m;
    c->model0.psf = &c->psf0;
    c->want_sinc = sinc && m->sinc_hw > 0;
    c->nlev = nlev < MP_SS_MAXLEVELS ? nlev : MP_SS_MAXLEVELS;
    for (int l = 0; l < c->nlev; l++)
        c->lev_os[l] = lev_os[l];
    c->grid_g = grid_g;
    return 0;
}

/* ---- What each table costs and can save ---------------------------------- */

typedef struct {
    double build, decide, save;   /* multiply-adds: once, per run, per LM render */
    double real;                  /* the build's own cost, where build prices it
                                   * higher (cost_grid) */
} econ_cost;

static double min_evals(double fits, double limits)
{
    return fits < limits ? fits : limits;
}

/* The kernel choice of a table: 16 phases × (the full render and every
 * shorter half-width). */
static double sinc_build_ops(int nx, int ny, int os, int hw, int sep)
{
    double s = 0.0;
    for (int h = 0; h <= hw; h++)
        s += render_ops(nx, ny, os, h, 0, INFINITY, sep);
    return NPH * s;
}

/* The kernel choice of table p (the model's, or a coarser level's). */
static econ_cost cost_sinc(const mp_psf *p, int hw, double fits, double W, int sep)
{
    econ_cost k;
    k.build = k.real = sinc_build_ops(p->nx, p->ny, p->os, hw, sep);
    k.decide = min_evals(fits, MP_SINC_LIMITS_EVALS) * hw * 3.0 * NPH * box_pixels(p);
    k.save = psf_ops(p, hw, 1, W, sep) - psf_ops(p, 0, 1, W, sep);
    return k;
}

/* A coarser level's bias table: what fitting with it saves against the
 * model's table at the full kernel (its own kernel choice is decided as
 * the model's is, on its own table: cost_sinc). */
static econ_cost cost_level(const mp_econ_cache *c, int l, double fits, double W)
{
    const mp_psf *p = &c->psf0;
    int f = p->os / c->lev_os[l], hw = c->model0.sinc_hw, nx, ny;
    level_size(p, f, &nx, &ny);
    int os = c->lev_os[l];
    double npix = box_pixels(p) + 2.0 * sqrt(box_pixels(p)) + 1.0;
    econ_cost k;
    int sep = RSEP(c);
    k.build = NPH * (psf_ops(p, hw, 1, INFINITY, sep) +
                     render_ops(nx, ny, os, hw, 0, INFINITY, sep));
    k.real = k.build;
    k.decide = min_evals(fits, MP_SS_LIMITS_EVALS) * 22.0 * NPH * npix;
    k.save = psf_ops(p, hw, 1, W, sep) - render_ops(nx, ny, os, hw, 1, W, sep);
    return k;
}

/* The phase grid of table p (the model's, or a coarser level's).  Its
 * nodes and cells are drawn by the axis operators (fit/prf_axis.c) when
 * sep — per x node the rows T·Xᵀ, T·X'ᵀ, per node three products on the
 * box, bw = os + 2hw + 4 taps a pixel — else by full renders: real.  The
 * up-front plan prices the build at full renders either way (build): its
 * saving is an upper bound that every table of the run claims for the
 * same fits (the coarser levels take most of them), and at the separable
 * price a 200-frame run built a ×2 grid its own fits did not pay for
 * (test_tables_pay_for_themselves: 644 renders spent, 572 saved).  Work
 * the run has done (learned) is set against the real price (pays). */
/* Whether the run's grids are drawn by the axis operators. */
#define SEP(c) mp_prf_separable(&(c)->model0)

static econ_cost cost_grid(const mp_psf *p, int sep, int rsep, int G, int hw, double fits,
                           double W, const mp_psf_field *f)
{
    int nt = f ? f->nterms : 1;
    int os = p->os, gb = (G + os - 1) / os;
    double na = (double)os * (gb + 3), ng = (double)os * gb, npix = box_pixels(p);
    double w2 = fmin(W * W, npix), bw = os + 2.0 * hw + 4.0, side = sqrt(npix);
    econ_cost k;
    k.build = na * na * psf_ops(p, hw, 1, INFINITY, rsep) +
              ng * ng * (psf_ops(p, hw, 0, INFINITY, rsep) + 16.0 * npix);
    k.real = !sep ? k.build
                  : na * 2.0 * p->ny * side * bw + na * na * 3.0 * npix * bw +
                        ng * p->ny * side * bw + ng * ng * (npix * bw + 16.0 * npix);
    k.decide = min_evals(fits, MP_SINC_LIMITS_EVALS) * 3.0 * ng * ng * npix;
    k.save = psf_ops(p, hw, 1, W, rsep) + field_ops(p, f, hw, W) - 48.0 * w2 * nt;
    /* A variable PSF's: a grid per term, a star drawn from each, and the
     * exact render's evaluation of the field saved. */
    k.build *= nt;
    k.real *= nt;
    return k;
}

/* learned: the exact-render work already done in a sequential run, of
 * which the table would have saved the fraction save/full; painted: what
 * the exact paints already done would have saved (paint_saved: the
 * model's phase grid only, 0 for every other table). */
static int pays(econ_cost k, double fits, double learned, double full, double painted)
{
    double save = k.save > 0 ? k.save : 0.0;
    double plan = fits * MP_ECON_RENDERS_PER_FIT * save, done = painted;
    if (learned > 0 && full > 0)
        done += learned * save / full;
    return (save > 0 || painted > 0) &&
           (plan + done >= k.build + k.decide || done >= k.real + k.decide);
}

/* What the model's phase grid would have saved on the exact paints the
 * run has done (mp_econ_learn_paint): a paint draws no derivatives and
 * reads 16 of the grid's values a pixel (ff_paint, cubic), against an
 * exact render of the whole box (the crop cuts both alike).  The
 * neighbours' light is painted on every star's whole crop radius, far
 * beyond the fit's window: on frame S at fitrad = FWHM (compare_daophot.sh)
 * the exact paints were half the run's samples, and the fits alone, on
 * coarser tables, never paid for the grid. */
static double paint_saved(const mp_econ_cache *c, int hw)
{
    if (!(c->paint_done > 0))
        return 0.0;
    int rs = RSEP(c);
    double full = psf_ops(&c->psf0, hw, 0, INFINITY, rs) +
                  field_ops(&c->psf0, c->field, hw, INFINITY);
    double grid = 16.0 * box_pixels(&c->psf0) * (c->field ? c->field->nterms : 1);
    return full > grid ? c->paint_done * (full - grid) / full : 0.0;
}

/* ---- Building ------------------------------------------------------------ */

static int build_sinc(mp_econ_cache *c, char *err)
{
    if (c->sinc_state)
        return c->sinc_state < 0;
    int rc = mp_sinc_choice_build(&c->model0, &c->sinc, err);
    c->sinc_state = rc ? ECON_FAILED : ECON_BUILT;
    if (!rc)
        c->spent += sinc_build_ops(c->psf0.nx, c->psf0.ny, c->psf0.os, c->model0.sinc_hw, RSEP(c));
    return rc;
}

/* Level l: the table block-summed, its bias table (fit/ss_choice.c) and,
 * for a variable PSF, the field block-summed alike (the fit reads it at
 * each star, frame_group.c). */
static int build_level(mp_econ_cache *c, int l, char *err)
{
    mp_ss_level *lv = &c->ss[l];
    int hw = c->model0.sinc_hw;
    if (c->lev_state[l])
        return c->lev_state[l] < 0;
    int f = c->psf0.os / c->lev_os[l];
    int rc = mp_ss_level_build(&c->model0, f, 0, lv, err);
    if (!rc && c->field) {
        rc = mp_psf_field_rebin(c->field, f, &lv->field, err);
        lv->psf.field = rc ? NULL : &lv->field;
    }
    if (rc) {
        c->lev_state[l] = ECON_FAILED;
        return 1;
    }
    lv->os = c->lev_os[l];
    c->lev_state[l] = ECON_BUILT;
    c->spent += NPH * (psf_ops(&c->psf0, hw, 1, INFINITY, RSEP(c)) +
                       psf_ops(&lv->psf, hw, 0, INFINITY, RSEP(c)));
    return 0;
}

/* Level l's own kernel choice, measured on its table at the origin (field
 * off), as a run given that table (psfos) would measure it. */
static int build_level_sinc(mp_econ_cache *c, int l, char *err)
{
    mp_ss_level *lv = &c->ss[l];
    if (lv->sinc.d2 || lv->sinc.hwmax > 0)
        return 0;
    mp_prf_model mo = lv->model;
    mp_psf po = lv->psf;
    po.field = NULL;
    mo.psf = &po;
    if (mp_sinc_choice_build(&mo, &lv->sinc, err))
        return 1;
    c->spent += sinc_build_ops(lv->psf.nx, lv->psf.ny, lv->psf.os, c->model0.sinc_hw, RSEP(c));
    return 0;
}

/* The box the fit draws a star's derivatives within, measured on grid g
 * of model m for fitting radius fitrad (none when it is not finite). */
static int deriv_box(mp_prf_cache *g, const mp_prf_model *m, double fitrad, char *err)
{
    return isfinite(fitrad) && mp_prf_cache_deriv_box(g, m, fitrad, MP_DBOX_SHARE, err);
}

static int build_grid(mp_econ_cache *c, double fitrad, char *err)
{
    if (c->grid_state)
        return c->grid_state < 0;
    /* Built for the model's own PSF (mp_prf_cache_usable checks it). */
    mp_prf_model m = c->model0;
    m.psf = c->psf;
    int rc = mp_prf_cache_build_reusing(&m, c->grid_g, &c->grid, &c->spare, err) ||
             deriv_box(&c->grid, &m, fitrad, err);
    mp_prf_cache_free(&c->spare);
    c->grid_state = rc ? ECON_FAILED : ECON_BUILT;
    if (!rc)
        c->spent +=
            cost_grid(&c->psf0, SEP(c), RSEP(c), c->grid_g, c->model0.sinc_hw, 0.0, INFINITY, c->field)
                .real;
    return rc;
}

/* Level l's own phase grid, on its table as the fit uses it (for a
 * variable PSF, on its field block-summed: a grid per term). */
static int build_level_grid(mp_econ_cache *c, int l, double fitrad, char *err)
{
    mp_ss_level *lv = &c->ss[l];
    if (lv->grid)
        return 0;
    if (!(lv->grid = calloc(1, sizeof *lv->grid))) {
        snprintf(err, MP_ERRLEN, "out of memory for a phase grid");
        return 1;
    }
    if (mp_prf_cache_build(&lv->model, c->grid_g, lv->grid, err) ||
        deriv_box(lv->grid, &lv->model, fitrad, err)) {
        mp_prf_cache_free(lv->grid);
        free(lv->grid);
        lv->grid = NULL;
        return 1;
    }
    c->spent +=
        cost_grid(&lv->psf, SEP(c), RSEP(c), c->grid_g, c->model0.sinc_hw, 0.0, INFINITY, c->field)
            .real;
    return 0;
}

/* Under the lock: decide and build (see the top of the file). */
static int choose_locked(mp_econ_cache *c, double fits, double fitrad, mp_frame_opts *o,
                         char *err)
{
    /* The windows the frame measured (a lone star's box when it did not). */
    double W = o->win > 0 ? o->win : (isfinite(fitrad) ? 2.0 * ceil(fitrad) + 3.0 : INFINITY);
    /* What the run has already rendered counts too (a sequential run's own
     * history: deterministic). */
    int rs = RSEP(c);
    double learned = o->learn ? c->ops_done : 0.0;
    double full = psf_ops(&c->psf0, c->model0.sinc_hw, 1, W, rs) +
                  field_ops(&c->psf0, c->field, c->model0.sinc_hw, W);
    c->fits_max = fits > c->fits_max ? fits : c->fits_max;
    int hw = c->model0.sinc_hw;
    if (c->want_sinc && !o->sinc &&
        pays(cost_sinc(&c->psf0, hw, fits, W, rs), fits, learned, full, 0.0)) {
        if (build_sinc(c, err))
            return 1;
        o->sinc = c->sinc.nph > 0 ? &c->sinc : NULL;
    }
    /* The model's phase grid first: a group it serves whole is drawn from
     * it (fit/frame_group.c fit_live), so the coarser levels serve only
     * the groups too bright for it.  How many those are the plan cannot
     * tell; the exact renders the run has done for them (learned) can, so
     * with the grid built a level and its tables pay on those alone
     * (47 Tuc with Tiny Tim's table: every group served by the grid, the
     * levels' tables 15 % of the run and 110 MB for nothing). */
    if (!o->grid && c->grid_g > 0 &&
        pays(cost_grid(&c->psf0, SEP(c), rs, c->grid_g, hw, fits, W, c->field), fits, learned,
             full, o->learn ? paint_saved(c, hw) : 0.0)) {
        if (build_grid(c, fitrad, err))
            return 1;
        o->grid = c->grid.G > 0 ? &c->grid : NULL;
    }
    double lfits = o->grid ? 0.0 : fits;    /* the fits the levels can claim in advance */
    /* Coarsest first: a coarser level saves more and costs less than a
     * finer one, so the levels that pay are a prefix.  Each level's
     * kernel choice pays or not on its own table, as the model's does. */
    if (!o->ss && c->nlev > 0) {
        int n = 0, bits = 0;
        while (n < c->nlev && pays(cost_level(c, n, fits, W), lfits, learned, full, 0.0)) {
            if (build_level(c, n, err))
                return 1;
            /* Decided for this frame, like every table: one built for an
             * earlier frame serves only where this frame's count pays. */
            if (c->want_sinc &&
                pays(cost_sinc(&c->ss[n].psf, hw, fits, W, rs), lfits, learned, full, 0.0)) {
                if (build_level_sinc(c, n, err))
                    return 1;
                bits |= 1 << n;
            }
            n++;
        }
        o->ss = n ? c->ss : NULL;
        o->nss = n;
        o->ss_sinc = bits;
        o->ss_grid = 0;
    }
    /* Each level's own phase grid, as the model's: the levels that fit
     * with a coarser table render it exactly otherwise (issue 12: 1660 of
     * 1975 LM fits of 47 Tuc with the PSF built from the frame). */
    for (int l = 0; o->ss == c->ss && l < o->nss && c->grid_g > 0; l++)
        if (!((o->ss_grid >> l) & 1) &&
            pays(cost_grid(&c->ss[l].psf, SEP(c), rs, c->grid_g, hw, fits, W, c->field), lfits,
                 learned, full, 0.0)) {
            if (build_level_grid(c, l, fitrad, err))
                return 1;
            o->ss_grid |= (c->ss[l].grid->G > 0) << l;
        }
    return 0;
}

int mp_econ_choose(mp_econ_cache *c, double fits, double fitrad, mp_frame_opts *o,
                   double *spent, char *err)
{
    if (spent)
        *spent = 0.0;
    if (!c || !c->offered)
        return 0;
    int rc;
#pragma omp critical(mp_econ_cache)
    {
        double before = c->spent;
        rc = choose_locked(c, fits, fitrad, o, err);
        if (spent)
            *spent = c->spent - before;
    }
    return rc;
}

void mp_econ_learn(mp_econ_cache *c, double ops)
{
    if (!c || !(ops > 0))
        return;
#pragma omp critical(mp_econ_cache)
    c->ops_done += ops;
}

void mp_econ_learn_paint(mp_econ_cache *c, double ops)
{
    if (!c || !(ops > 0))
        return;
#pragma omp critical(mp_econ_cache)
    c->paint_done += ops;
}

void mp_econ_forget(mp_econ_cache *c)
{
    if (!c)
        return;
#pragma omp critical(mp_econ_cache)
    {
        c->ops_done = 0.0;
        c->paint_done = 0.0;
    }
}

double mp_econ_render_ops(const mp_prf_model *m, int hw, double fitrad)
{
    if (m->psf->kind != MP_PSF_TABLE)
        return 0.0;
    double W = isfinite(fitrad) ? 2.0 * ceil(fitrad) + 3.0 : INFINITY;
    return psf_ops(m->psf, hw, 1, W, mp_prf_axes_apply(m)) + field_ops(m->psf, m->psf->field, hw, W);
}

double mp_econ_grid_render_ops(const mp_prf_model *m, double fitrad)
{
    double W = isfinite(fitrad) ? 2.0 * ceil(fitrad) + 3.0 : INFINITY;
    const mp_psf *p = m->psf;
    return 48.0 * fmin(W * W, box_pixels(p)) * (p->field ? p->field->nterms : 1);
}

/* A phase grid's derivatives' box for the summary, "; ..." ("" when none). */
static const char *dbox_note(const mp_prf_cache *g, char *s, size_t n)
{
    if (!(g->dbox_hw > 0))
        snprintf(s, n, "; derivatives on whole windows");
    else if (isinf(g->dbox_u))
        snprintf(s, n, "; derivatives within %.0f px for every flux", g->dbox_hw);
    else
        snprintf(s, n, "; derivatives within %.0f px up to E/(B+RON^2) = %.3g", g->dbox_hw,
                 g->dbox_u);
    return s;
}

void mp_econ_summary(const mp_econ_cache *c, double ops_render, char *buf, size_t n)
{
    buf[0] = '\0';
    if (!c || !c->offered || n == 0)
        return;
    size_t k = 0;
#define ADD(...) do { if (k < n) k += (size_t)snprintf(buf + k, n - k, __VA_ARGS__); } while (0)
    ADD("planned for up to %.0f star fits; built:", c->fits_max);
    int any = 0;
    if (c->sinc_state > 0) {
        ADD(" the sinc kernel's error table");
        any = 1;
    }
    for (int l = 0; l < c->nlev; l++)
        if (c->lev_state[l] > 0) {
            ADD("%s the x%d table's bias table", any ? "," : "", c->lev_os[l]);
            any = 1;
        }
    char d[96];
    if (c->grid_state > 0 && c->grid.G > 0) {
        ADD("%s the phase grid (%d per pixel%s)", any ? "," : "", c->grid.G,
            dbox_note(&c->grid, d, sizeof d));
        any = 1;
    }
    for (int l = 0; l < c->nlev; l++)
        if (c->lev_state[l] > 0 && c->ss[l].grid && c->ss[l].grid->G > 0) {
            ADD("%s the x%d table's phase grid (%s)", any ? "," : "", c->lev_os[l],
                dbox_note(c->ss[l].grid, d, sizeof d) + 2);
            any = 1;
        }
    if (!any)
        ADD(" none (none could pay for its build)");
    if (ops_render > 0)
        ADD("; their cost %.0f renders of the model", c->spent / ops_render);
#undef ADD
}
