/* run_psf.c — the run's PSF steps (pipeline/run.c's list): the PSF stars
 * and the table's radius, the PSF built from the frame and adopted as the
 * fit's, and varorder=auto's last step, the next order judged by the stars
 * held out of the build (pipeline/heldout.c). */
#include <math.h>
#include <stdarg.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include "pipeline/run_state.h"

/* The fewest PSF stars a table is built from: an order-0 build's 2 + 1
 * (psf/frame_build.c built_verdict). */
enum { PL_PSF_MIN_STARS = 3 };

/* The PSF's stars, picked from the first detections (psf/build.h).  A
 * frame that holds fewer fit to be PSF stars than a table needs (a sparse
 * field's one or two bright stars) is reduced as one that holds none:
 * with the Gaussian of fwhm (mp_run_build_psf), not refused; fewer
 * because maxnpsf allows no more stays the build's error. */
static int psf_stars(run_state *s, char *err)
{
    size_t *idx = malloc((size_t)(s->o->psfb.maxnpsf + 1) * sizeof *idx);
    if (!idx)
        return oom(err);
    mp_epsf_opts po = s->o->psfb;
    int rc = mp_epsf_select(&s->f, &s->t, &po, idx, &s->np, err);
    if (!rc && s->np < PL_PSF_MIN_STARS && s->np < (size_t)po.maxnpsf) {
        s->np_few = s->np;
        s->np = 0;
    }
    if (!rc && s->np == 0) {
        free(idx);
        return 0;
    }
    if (!rc) {
        s->px = malloc(s->np * sizeof *s->px);
        s->py = malloc(s->np * sizeof *s->py);
        s->pf = malloc(s->np * sizeof *s->pf);
        if (!s->px || !s->py || !s->pf)
            rc = oom(err);
    }
    int cx = mp_table_col(&s->t, "X_IMAGE"), cy = mp_table_col(&s->t, "Y_IMAGE");
    int cf = mp_table_col(&s->t, "FLUX");
    for (size_t k = 0; !rc && k < s->np; k++) {
        s->px[k] = mp_table_get(&s->t, idx[k], cx);
        s->py[k] = mp_table_get(&s->t, idx[k], cy);
        s->pf[k] = cf >= 0 ? mp_table_get(&s->t, idx[k], cf) : NAN;
    }
    free(idx);
    return rc;
}

/* tablerad=INDEF: the table's radius measured on the PSF stars and the
 * bright ones (pipeline/tablerad.c), said on stderr; kept for pass 2. */
static int table_radius(run_state *s, char *err)
{
    if (!s->o->tablerad_auto || s->np == 0)
        return 0;
    mp_epsf_rad r;
    if (mp_pl_tablerad(&s->f, &s->t, s->px, s->py, s->pf, s->np, &s->o->psfb, &r, err))
        return 1;
    s->tabrad = r.rad;
    /* Short of the floor, the table is zero past what was measured, and
     * ends a pixel later (what a shift and a block sum reach past it);
     * the floor's extra rings would hold zeros only. */
    s->tabsupport = r.reach > 0 && r.reach < r.rad ? r.reach : 0.0;
    int l = snprintf(s->tabwhy, sizeof s->tabwhy, "%s", r.why);
    if (s->tabsupport > 0) {
        s->tabrad = ceil(s->tabsupport) + 1.0;
        if (l > 0 && (size_t)l < sizeof s->tabwhy)
            snprintf(s->tabwhy + l, sizeof s->tabwhy - (size_t)l,
                     "; zero beyond %.0f px, its light in PSFSUM, so %.0f px", s->tabsupport,
                     s->tabrad);
    }
    if (!s->quiet)
        fprintf(stderr, "matphot pipeline: %s: %s\n", s->image, s->tabwhy);
    return 0;
}

/* A PSF built here (e) written to path, it and its PSF stars used[0..np)
 * in frame coordinates (the field's origin; used itself stays in this
 * image's).  Nonzero with err on failure. */
static int write_psf_file(run_state *s, const mp_epsf *e, const mp_psf_star *used,
                          const char *path, char *err)
{
    mp_psf_star *inf = malloc((s->np + 1) * sizeof *inf);
    if (!inf)
        return oom(err);
    for (size_t k = 0; k < s->np; k++) {
        inf[k] = used[k];
        inf[k].x += (double)s->offx;
        inf[k].y += (double)s->offy;
    }
    mp_psf_field fld;
    mp_epsf inframe = *e;
    inframe.x0 += (double)s->offx;
    inframe.y0 += (double)s->offy;
    int rc = mp_epsf_field(&inframe, &fld, err);
    if (!rc) {
        rc = mp_psf_field_write(path, &fld, inf, (int)s->np, err);
        mp_psf_field_free(&fld);
    }
    free(inf);
    return rc;
}

/* A decision of the run's own (the PSF it built, its order), as printf
 * would format it, added to the report's economy decisions: on the setup
 * it adopted, and on the view the fit reads when the PSF varies
 * (mp_fit_setup_local copies them at adoption). */
static void note_decision(run_state *s, const char *fmt, ...)
{
    size_t l = strlen(s->own.decisions);
    if (l && l + 2 < sizeof s->own.decisions)
        strcat(s->own.decisions, "; "), l += 2;
    va_list ap;
    va_start(ap, fmt);
    vsnprintf(s->own.decisions + l, sizeof s->own.decisions - l, fmt, ap);
    va_end(ap);
    s->own.ndecisions++;
    if (s->fit == &s->local) {
        memcpy(s->local.decisions, s->own.decisions, sizeof s->local.decisions);
        s->local.ndecisions = s->own.ndecisions;
    }
}

/* The fit set up as `fit psf=PATH` sets it up (economy's decisions
 * measured on this table) and taken as the run's; psf is then empty
 * again for the next image.  Nonzero with err on failure. */
static int adopt_psf(run_state *s, const char *path, char *err)
{
    const mp_pipeline_opts *o = s->o;
    /* The last setup kept until the new one is read: its phase grid's
     * blocks go to the new one's (page faults, bench/SCALING.md). */
    mp_fit_setup old;
    int had = s->have_own;
    if (had) {
        old = s->own;
        memset(&s->own, 0, sizeof s->own);
        s->have_own = 0;
        s->grid = NULL;         /* it was the old setup's */
    }
    int rc = mp_params_set(o->ps, "psf", path, err);
    if (!rc) {
        rc = mp_fit_setup_read(o->ps, &s->own, err);
        if (!rc && !o->groupcut_median)
            mp_pl_group_decision(&s->own, o->couplebudget, o->group.weakgroup);
        s->have_own = !rc;
        char e3[MP_ERRLEN];
        mp_params_set(o->ps, "psf", "", e3);
    }
    if (had) {
        if (s->have_own)
            mp_econ_cache_hand_grid(old.cache, s->own.cache);
        mp_fit_setup_free(&old);
    }
    if (!rc) {
        s->fit = mp_fit_setup_local(&s->own, (double)s->offx, (double)s->offy, &s->local);
        s->fwhm = mp_prf_fwhm(&s->own.model);
        s->sharp_known = 0;
        mp_fit_memory_forget(s->mem);
        mp_coupling_free(&s->coupling);     /* the last model's */
    }
    return rc;
}

/* A table built on a frame the halo was taken off (pass 2) holds a
 * star's light less E·H (H = s->halo_light per e-); its growth curve
 * measured the light beyond it without the halo too.  So that fluxes stay
 * total, its PSFSUM S (core over core and the rest) becomes 1/(1/S + H):
 * E·H more light a star for E·S in the table.  Without it every flux came
 * out H low (the segmented scene: 0.8 %, its flux errors 1.66 of the
 * bound against 1.04 without halo=yes). */
static void count_halo_light(const run_state *s, mp_epsf *e, mp_epsf_report *rep,
                             mp_psf_star *used)
{
    double H = s->halo_light, S = e->sum;
    if (!(H > 0) || !(S > 0))
        return;
    double S2 = 1.0 / (1.0 / S + H);
    e->sum_err *= (S2 / S) * (S2 / S);
    e->sum = S2;
    for (size_t k = 0; used && k < s->np; k++)
        used[k].flux *= S / S2;     /* total fluxes: over PSFSUM */
    size_t l = strlen(rep->what);
    snprintf(rep->what + l, sizeof rep->what - l, "; PSFSUM %.4f with the halo's light "
             "(%.4f per e- taken off)", S2, H);
}

/* The build's options for this frame: the pipeline's, with the
 * polynomial's origin and scales the whole frame's, in this image's pixels
 * (a section's: mp_pl_psf_on), and the measured table radius. */
static mp_epsf_opts pass_opts(const run_state *s)
{
    mp_epsf_opts po = s->o->psfb;
    long nx = s->fnx ? s->fnx : s->f.im.nx, ny = s->fny ? s->fny : s->f.im.ny;
    po.x0 = 0.5 * (double)(nx + 1) - (double)s->offx;
    po.y0 = 0.5 * (double)(ny + 1) - (double)s->offy;
    po.xs = nx > 1 ? 0.5 * (double)nx : 1.0;
    po.ys = ny > 1 ? 0.5 * (double)ny : 1.0;
    if (s->tabrad > 0)
        po.psfrad = s->tabrad;
    po.support = s->tabsupport;
    return po;
}

/* A first build that failed (too few PSF stars): when the stars' FWHM
 * measured on the first detection (s->stars_fwhm) is more than 3 σ off
 * fwhm, err says so, naming fwhm: a start far off the stars' (fwhm=12 on
 * stars of FWHM 3) leaves too few alone, and one far below them (0.1)
 * fits none.  And when the selection among these detections would have
 * found enough stars with it (its fitrad 2 fwhm, and its psfrad 4 fwhm
 * unless tablerad was given), how many (a kernel far too wide, fwhm=50,
 * found blends, which no selection makes stars). */
static void fwhm_hint(const run_state *s, char *err)
{
    const mp_stars_fwhm *m = &s->stars_fwhm;
    mp_epsf_opts po = s->o->psfb;
    if (!mp_epsf_fwhm_off(m, po.fwhm))
        return;
    po.fitrad = 2.0 * m->fwhm;
    if (s->o->tablerad_auto)
        po.psfrad = 4.0 * m->fwhm;
    size_t *idx = malloc((size_t)(po.maxnpsf + 1) * sizeof *idx), n = 0;
    char e2[MP_ERRLEN];
    int rc = !idx || mp_epsf_select(&s->f, &s->t, &po, idx, &n, e2);
    free(idx);
    size_t l = strlen(err);
    if (l < MP_ERRLEN)
        l += (size_t)snprintf(err + l, MP_ERRLEN - l, "; the stars' FWHM is %.3g +- %.1g px "
                              "(measured on %d lone stars), not fwhm=%g", m->fwhm, m->err, m->n,
                              po.fwhm);
    if (!rc && n >= 3 && l < MP_ERRLEN)     /* an order-0 PSF's 2 + 1 (epsf_build.c) */
        snprintf(err + l, MP_ERRLEN - l, ": with fwhm=%.3g, %zu PSF stars are selected",
                 m->fwhm, n);
}

/* Build (pass 1: the frame as it is) or rebuild (pass 2: every fitted
 * star but the PSF stars' own subtracted) the PSF, write root.psf.fits,
 * and set the fit up from it as `fit psf=root.psf.fits` would be; every
 * group is then fitted afresh. */
int mp_run_build_psf(run_state *s, int pass, char *err)
{
    double t0 = mp_seconds();
    if (pass == 1 && (psf_stars(s, err) || table_radius(s, err)))
        return 1;
    mp_epsf_opts po = pass_opts(s);
    po.first_pass = pass == 1;       /* the second always follows */
    /* A frame with no star fit to shape a PSF (an empty or tiny frame, a
     * crowd of saturated stars) is still reduced: with the Gaussian of
     * fwhm, as psf=gauss, said on stderr and in the report. */
    if (s->np == 0) {
        char few[96] = "no usable PSF star";
        if (s->np_few)
            snprintf(few, sizeof few, "only %zu usable PSF star%s (a table needs %d)", s->np_few,
                     s->np_few == 1 ? "" : "s", PL_PSF_MIN_STARS);
        if (pass == 1 && s->gauss_wrong[0]) {    /* that Gaussian is far off the stars' */
            snprintf(err, MP_ERRLEN, "%s: %s, and %.400s", s->image, few, s->gauss_wrong);
            return 1;
        }
        if (pass == 1 && s->t.nrow > 0)
            fprintf(stderr, "matphot pipeline: %s: warning: %s among %zu detections; fitting "
                    "with the Gaussian of fwhm (psf=gauss)\n", s->image, few, s->t.nrow);
        return 0;
    }
    mp_epsf_report rep;
    memset(&rep, 0, sizeof rep);
    char e2[MP_ERRLEN];
    mp_psf_star *used = NULL;        /* the file's PSFSTARS */
    if (mp_epsf_pass(&s->f, pass == 1 ? s->f.im.pix : s->res, pass > 1, &s->t, &s->fit->model,
                     s->px, s->py, s->pf, s->np, &po, &s->psf, &rep, &used, e2)) {
        snprintf(err, MP_ERRLEN, "%s: PSF: %.300s", s->image, e2);
        if (pass == 1)
            fwhm_hint(s, err);
        return 1;
    }
    if (pass > 1)
        count_halo_light(s, &s->psf, &rep, used);
    char *path = mp_name_after(s->root, ".psf.fits");
    mp_run_writes(s, ".psf.fits");
    int rc = !path ? oom(err)
                   : write_psf_file(s, &s->psf, used, path, err) || adopt_psf(s, path, err);
    if (!rc) {
        s->psf_pass = pass;
        note_decision(s, "PSF built from the frame (pass %d, %s): %s%s%s", pass, path, s->tabwhy,
                      s->tabwhy[0] ? "; " : "", rep.what);
        fprintf(stderr, "matphot pipeline: %s: PSF pass %d: %s, %.2f s\n", s->image, pass, rep.what,
                mp_seconds() - t0);
    }
    s->rep->t_fit += mp_seconds() - t0;
    free(used);
    free(path);
    return rc;
}

/* ---- varorder=auto's last step: the next order judged by held-out stars */

/* Whether the held-out test runs: the PSF built here at varorder=auto, in
 * its second pass, found variable by the residual test (order ≥ 1).  It
 * does not decide whether the PSF varies at all: its frame is the data
 * less every other star's model, and where the crowding changes across
 * the frame (47 Tuc's crop, the cluster's centre off it) the misfit of
 * that model does too, which a table varying with position takes up
 * (psfbuild_notes.md, session 39: it raised 47 Tuc to order 2 and worsened
 * every star's fit).  The residual test, calibrated by its permuted null,
 * decides that; once the PSF varies, the held-out stars judge whether the
 * next order's shape is the PSF's. */
int mp_run_heldout_applies(const run_state *s)
{
    const mp_pipeline_opts *o = s->o;
    return o->build_psf && o->psfb.order < 0 && !s->borrowed && s->psf_pass == 2 &&
           s->psf.order >= 1 && s->psf.order < MP_PSF_MAXORDER && s->np > 0;
}

/* The two tables compared, both built from the final residual (so that
 * neither is favoured by cleaner data): [0] order k as it stands, [1]
 * order k + 1 from it (mp_epsf_opts.raise); their PSF stars, and each
 * written to its temporary file. */
typedef struct {
    mp_epsf e[2];
    mp_psf_star *used[2];
    char *path[2];
    char what[2][512];       /* the build's line (mp_epsf_report.what) */
} table_pair;

static void table_pair_free(table_pair *tp)
{
    for (int i = 0; i < 2; i++) {
        mp_epsf_free(&tp->e[i]);
        free(tp->used[i]);
        if (tp->path[i]) {
            remove(tp->path[i]);
            mp_tmp_unregister(tp->path[i]);
        }
        free(tp->path[i]);
    }
}

/* Table i of tp built (from tp->e[i] as set by the caller) and written to
 * its temporary file beside path.  Nonzero with err on failure. */
static int pair_build(run_state *s, table_pair *tp, int i, const char *path, char *err)
{
    mp_epsf_opts po = pass_opts(s);
    po.order = s->psf.order;
    po.raise = i;
    mp_epsf_report rep;
    memset(&rep, 0, sizeof rep);
    char e2[MP_ERRLEN];
    if (mp_epsf_pass(&s->f, s->res, 1, &s->t, &s->fit->model, s->px, s->py, s->pf, s->np, &po,
                     &tp->e[i], &rep, &tp->used[i], e2)) {
        snprintf(err, MP_ERRLEN, "%s: PSF (held-out test): %.400s", s->image, e2);
        return 1;
    }
    count_halo_light(s, &tp->e[i], &rep, tp->used[i]);
    snprintf(tp->what[i], sizeof tp->what[i], "%s", rep.what);
    /* temporaries of root.psfk.fits and root.psf.fits (which the raised
     * table becomes), so a killed run's are swept as any others */
    char *base = i ? NULL : mp_name_after(s->root, ".psfk.fits");
    if ((!i && !base) || !(tp->path[i] = mp_tmp_name(i ? path : base))) {
        free(base);
        return oom(err);
    }
    free(base);
    mp_tmp_register(tp->path[i]);    /* full: the write goes on unprotected */
    return write_psf_file(s, &tp->e[i], tp->used[i], tp->path[i], err);
}

/* The frame less every fitted star but the held-out ones (rest: the
 * others), drawn with the run's model, into pix (bad pixels 0, as a frame
 * holds them). */
static int held_out_frame(run_state *s, const mp_table *rest, float *pix, char *err)
{
    double gemax;
    mp_prf_tiers tiers;
    const mp_prf_cache *grid = mp_run_phase_grid(s, &gemax, NULL, &tiers);
    if (mp_fit_residual_grid(&s->f, &s->fit->model, rest, s->fit->opts.cropfrac,
                             s->fit->opts.cache, grid, gemax, &tiers, pix, err))
        return 1;
    size_t npix = (size_t)s->f.im.nx * (size_t)s->f.im.ny;
    for (size_t i = 0; i < npix; i++)
        if (isnan(pix[i]))
            pix[i] = 0.0f;
    return 0;
}

/* The held-out stars (sel) fitted with both tables of tp on the frame
 * less the others; their comparison into *h. */
static int compare_on_held(run_state *s, const unsigned char *sel, const table_pair *tp,
                           mp_pl_heldout *h, char *err)
{
    size_t npix = (size_t)s->f.im.nx * (size_t)s->f.im.ny;
    float *pix = malloc((npix ? npix : 1) * sizeof *pix);
    mp_table held, rest, fit[2];
    mp_table_init(&held);
    mp_table_init(&rest);
    mp_table_init(&fit[0]);
    mp_table_init(&fit[1]);
    mp_frame hf = s->f;
    hf.im.pix = pix;
    int rc = (!pix || mp_pl_rows_of(&s->t, sel, 1, &held) || mp_pl_rows_of(&s->t, sel, 0, &rest))
                 ? oom(err)
                 : held_out_frame(s, &rest, pix, err);
    for (int i = 0; i < 2 && !rc; i++)
        rc = mp_pl_heldout_fit(&hf, &held, s->o->ps, tp->path[i], &s->o->group, &fit[i], err);
    if (!rc && mp_pl_heldout_compare(&fit[0], &fit[1], h))
        rc = oom(err);
    for (int i = 0; i < 2; i++)
        mp_table_free(&fit[i]);
    mp_table_free(&held);
    mp_table_free(&rest);
    free(pix);
    return rc;
}

/* The raised table (tp->e[1], its PSFORDWH now with the verdict) made the
 * run's: written to path, the fit set up from it (the report's decisions
 * told how it was built), every group fitted afresh. */
static int adopt_raised(run_state *s, table_pair *tp, const char *path, char *err)
{
    mp_epsf_free(&s->psf);
    s->psf = tp->e[1];
    memset(&tp->e[1], 0, sizeof tp->e[1]);
    if (write_psf_file(s, &s->psf, tp->used[1], path, err) || adopt_psf(s, path, err))
        return 1;
    note_decision(s, "PSF built from the frame (the held-out step, %s): %s%s%s", path, s->tabwhy,
                  s->tabwhy[0] ? "; " : "", tp->what[1]);
    return mp_run_group_and_fit(s, s->rep->rounds, 0, err);
}

/* varorder=auto's last step (heldout_applies): order k + 1 built on the
 * final residual and kept when the stars held out of the build fit it
 * better than order k built on the same residual (z < −MP_PL_HELDOUT_Z);
 * then every group is fitted again with it.  The verdict goes into the
 * run report's decisions either way. */
int mp_run_heldout_order(run_state *s, char *err)
{
    if (!mp_run_heldout_applies(s))
        return 0;
    double t0 = mp_seconds();
    int k = s->psf.order, need = MP_EPSF_PER_TERM * mp_psf_nterms(k + 1);
    unsigned char *sel = malloc(s->t.nrow + 1);
    char *path = mp_name_after(s->root, ".psf.fits"), why[300];
    table_pair tp;
    memset(&tp, 0, sizeof tp);
    long nh = sel ? mp_pl_heldout_rows(&s->t, s->px, s->py, s->np, 2 * s->np, sel) : -1;
    int rc = nh < 0 || !path ? oom(err) : 0, up = 0;
    mp_pl_heldout h = {0, 0.0, 0.0};
    if (!rc && nh < need)
        snprintf(why, sizeof why, "held out %d->%d: %ld stars < %d, not run", k, k + 1, nh,
                 need);
    else if (!rc) {
        /* the step only ever raises: where it cannot run, order k stands,
         * and the report says why */
        char e2[MP_ERRLEN];
        int failed =
            (mp_epsf_copy(&s->psf, &tp.e[0]) ? oom(e2) : pair_build(s, &tp, 0, path, e2)) ||
            (mp_epsf_copy(&tp.e[0], &tp.e[1]) ? oom(e2) : pair_build(s, &tp, 1, path, e2)) ||
            compare_on_held(s, sel, &tp, &h, e2);
        up = !failed && h.z < -MP_PL_HELDOUT_Z;
        if (failed)
            snprintf(why, sizeof why, "held out %d->%d: not run (%.200s)", k, k + 1, e2);
        else
            snprintf(why, sizeof why, "held out %d->%d: mean log chi2 ratio %.3g (z %.2f, %zu "
                     "stars S/N >= %.0f) %s -%.3f", k, k + 1, h.mean, h.z, h.n,
                     MP_PL_HELDOUT_SNR, up ? "<" : ">=", MP_PL_HELDOUT_Z);
        if (up) {
            size_t l = strlen(tp.e[1].why);
            snprintf(tp.e[1].why + l, sizeof tp.e[1].why - l, "; %.150s", why);
        }
    }
    if (!rc && up)
        rc = adopt_raised(s, &tp, path, err);
    if (!rc) {
        note_decision(s, "PSF order (varorder auto, the stars held out of the build): %s: order "
                      "%d", why, s->psf.order);
        if (!s->quiet)
            fprintf(stderr, "matphot pipeline: %s: PSF order: %s: order %d, %.2f s\n", s->image,
                    why, s->psf.order, mp_seconds() - t0);
    }
    s->rep->t_fit += mp_seconds() - t0;
    table_pair_free(&tp);
    free(sel);
    free(path);
    return rc;
}
