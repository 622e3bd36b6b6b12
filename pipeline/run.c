/* run.c — the pipeline of one frame: find → group → fit, then rounds of
 * find on the residual → add the new stars → group → fit (DAOPHOT's
 * practice, anchors.md §1.1), then the catalog.  mp_pipeline_run reads as
 * its list of steps; each step is a function of the run's state below. */
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <unistd.h>
#include "pipeline/run_state.h"

static int state_init(run_state *s, const char *image, const char *root,
                      const mp_pipeline_opts *o, mp_pipeline_report *rep, char *err)
{
    memset(s, 0, sizeof *s);
    memset(rep, 0, sizeof *rep);
    s->image = image;
    s->root = root;
    s->o = o;
    s->rep = rep;
    mp_table_init(&s->t);
    mp_table_init(&s->found);
    mp_table_init(&s->gone);
    mp_table_init(&s->before);
    mp_table_init(&s->grp);
    s->fit = &o->fit;
    s->fwhm = mp_prf_fwhm(&o->fit.model);
    /* Economy learns within this frame only: an @list's frame reduces as
     * its own job would (tools/slurm, survey_jobs.sh). */
    if (o->fit.opts.learn)
        mp_econ_forget(o->fit.cache);
    return (s->mem = mp_fit_memory_new()) ? 0 : oom(err);
}

static void state_free(run_state *s)
{
    if (s->have_own)
        mp_fit_setup_free(&s->own);
    mp_epsf_free(&s->psf);
    free(s->px);
    free(s->py);
    free(s->pf);
    mp_fit_memory_free(s->mem);
    free(s->res);
    mp_table_free(&s->t);
    mp_table_free(&s->found);
    mp_table_free(&s->gone);
    mp_table_free(&s->before);
    mp_table_free(&s->grp);
    mp_bkg_free(&s->bkg);
    mp_coupling_free(&s->coupling);
    mp_frame_free(&s->f);
}

/* run_state.written's bits: mp_pl_products'. */
void mp_run_writes(run_state *s, const char *ext)
{
    for (size_t i = 0; i < MP_PL_NPRODUCT; i++)
        if (!strcmp(ext, mp_pl_products[i]))
            s->written |= 1u << i;
}

/* A failed run leaves none of the products it began to write: bad input
 * found late (no usable PSF star, after root.coo was written) left
 * root.coo behind.  The file of that name a previous run wrote goes too:
 * this one was replacing it. */
static void remove_products(const run_state *s)
{
    for (size_t i = 0; i < MP_PL_NPRODUCT; i++) {
        char *p = (s->written >> i & 1u) ? mp_name_after(s->root, mp_pl_products[i]) : NULL;
        if (p)
            unlink(p);
        free(p);
    }
}

/* The frame. */
static int read_frame(run_state *s, char *err)
{
    double t0 = mp_seconds();
    if (mp_frame_read(s->image, &s->o->fit.dp, &s->f, err))
        return 1;
    s->rep->t_read = mp_seconds() - t0;
    s->rep->rdnoise = s->f.rdnoise;
    return 0;
}

/* Room for the residual, taken when the first fit needs it (not while the
 * first detection holds its maps), and lent to the fit for its model of
 * every star until mp_fit_residual draws the residual into it: the peak
 * is then the frame, its mask and one more image (issue 14). */
static int need_residual(run_state *s, char *err)
{
    size_t npix = (size_t)s->f.im.nx * (size_t)s->f.im.ny;
    if (!s->res && !(s->res = malloc((npix ? npix : 1) * sizeof *s->res))) {
        snprintf(err, MP_ERRLEN, "%s: out of memory for the residual", s->image);
        return 1;
    }
    mp_fit_memory_scratch(s->mem, s->res, npix);
    return 0;
}

/* Deep detection: candidates from find (threshold, well below the cut)
 * screened by a linear fit on data (the frame or the residual) before the
 * full fit judges them by minsnr.  (Leaving the candidates within 1.5
 * FWHM of a fitted star unscreened, for blends, found 9 more stars of
 * 5000 at 3x the fit's time: not done.) */
static int screen(run_state *s, const mp_frame *on, const float *data, mp_table *cand)
{
    double cut = s->fit->opts.minsnr - MP_PL_SCREEN_SLACK;
    if (!(cut > 0) || cand->nrow == 0)
        return 0;
    long n = mp_pl_prescreen(on, &s->bkg, data, &s->fit->model, s->fit->opts.fit.fitrad,
                             cut, cand);
    if (n < 0)
        return 1;
    s->rep->screened += n;
    return 0;
}

/* find's options for stars of the model now fitted: its kernel of the
 * model's FWHM (DAOPHOT's fwhmpsf; with the PSF built from the frame, the
 * built one's, not the fwhm it started from: 47 Tuc 256² CHI2_PSF 3.75 ->
 * 3.65, the residual near DAOPHOT's stars 0.679 -> 0.673 of DAOPHOT's) and
 * sharpness limits that keep this PSF's own stars (sharp_limits.c). */
static int find_opts_for_model(run_state *s, mp_find_opts *fo, char *err)
{
    *fo = s->o->find;
    fo->fwhm = s->fwhm;
    if (!s->sharp_known) {
        if (mp_pl_sharp_limits(&s->fit->model, s->f.im.nx, s->f.im.ny, fo, s->rep->sharp,
                               sizeof s->rep->sharp, err))
            return 1;
        s->sharp_known = 1;
        s->sharplo = fo->sharplo;
        s->sharphi = fo->sharphi;
    }
    fo->sharplo = s->sharplo;
    fo->sharphi = s->sharphi;
    return 0;
}

/* The first detection's stars' FWHM (s->stars_fwhm; fo: the first
 * detection's options, s->bkg its maps), in the report's words. */
static int measure_stars(run_state *s, const mp_find_opts *fo, char *err)
{
    if (mp_epsf_stars_fwhm_found(&s->f, &s->bkg, fo, &s->t, MP_EPSF_FWHM_STARS, &s->stars_fwhm,
                                 err))
        return 1;
    mp_pl_stars_why(&s->stars_fwhm, s->rep->stars_fwhm, sizeof s->rep->stars_fwhm);
    return 0;
}

/* The model checked against the stars' width (psf/model_check.c), said
 * in the report: the Gaussian of fwhm where it is the model (psf=gauss: one far
 * off is an error naming fwhm) or where the build starts (an error only
 * when the build falls back on it, run_psf.c); a table given, read at an
 * OVERSAMP that makes its stars twice or half as wide or more (an error
 * naming oversamp). */
static int check_fwhm(run_state *s, const mp_find_opts *fo, char *err)
{
    int gauss = mp_epsf_model_is_gauss(&s->fit->model);
    if (!s->fit->model.psf || (!gauss && s->o->build_psf))
        return 0;               /* a table built here, from these stars */
    if (measure_stars(s, fo, err))
        return 1;
    int rc = mp_epsf_model_verdict(&s->f, &s->t, &s->fit->model, &s->stars_fwhm,
                                   s->rep->stars_fwhm, sizeof s->rep->stars_fwhm, s->gauss_wrong);
    size_t l = strlen(s->gauss_wrong);
    if (rc == 2 && gauss && l < sizeof s->gauss_wrong)     /* (building, it is the start) */
        snprintf(s->gauss_wrong + l, sizeof s->gauss_wrong - l, " (INDEF: measured on each "
                 "frame)%s", s->o->build_psf ? "" : ", or build the PSF (psf= empty)");
    if (rc == 1 || (rc == 2 && !(gauss && s->o->build_psf))) {
        snprintf(err, MP_ERRLEN, "%s: %.400s", s->image, s->gauss_wrong);
        return 1;
    }
    if (rc != 2)
        s->gauss_wrong[0] = '\0';
    return 0;
}

/* Sky and noise maps, the first detection, root.coo. */
static int find_stars(run_state *s, char *err)
{
    double t0 = mp_seconds();
    if (mp_bkg_estimate(&s->f, s->o->mesh, s->o->filter, &s->bkg, err))
        return 1;
    s->rep->t_bkg = mp_seconds() - t0;
    t0 = mp_seconds();
    mp_find_opts fo;
    if (find_opts_for_model(s, &fo, err) || mp_find_stars(&s->f, &s->bkg, &fo, &s->t, err))
        return 1;
    s->rep->threshold = s->o->find.threshold;
    if (s->t.nrow == 0)          /* said should no later round find one */
        mp_find_why_none(&s->f, &s->bkg, fo.threshold, s->none_why, sizeof s->none_why);
    if (screen(s, &s->f, s->f.im.pix, &s->t))
        return oom(err);
    mp_pl_drop_unset(&s->t);
    if (check_fwhm(s, &fo, err))
        return 1;
    mp_bkg_free(&s->bkg);        /* the fit needs no map: memory for its model */
    if (mp_table_shrink(&s->t))  /* the candidates' rows given back (issue 14) */
        return oom(err);
    s->rep->t_find += mp_seconds() - t0;
    s->rep->found = (long)s->t.nrow;
    /* Written first: a failed write is the run's only stderr line. */
    if (s->quiet)
        return 0;
    mp_run_writes(s, ".coo");
    if (mp_pl_write_named(s->root, ".coo", &s->t, s->o->fit.fmt, NULL, NULL, err))
        return 1;
    fprintf(stderr, "matphot pipeline: %s: %zu stars found (%ld candidates below the screen's "
            "S/N %g)\n", s->image, s->t.nrow, s->rep->screened,
            s->o->fit.opts.minsnr - MP_PL_SCREEN_SLACK);
    return 0;
}

/* One round's frame-fit counts added to the run's; its groups, stars not
 * converged, sky orders and render unit stand for the run. */
static void count_fit(mp_pipeline_report *rep, const mp_frame_report *fr, size_t nrow)
{
    mp_frame_report_add(&rep->fit, fr);
    rep->fit.noconv = fr->noconv;
    rep->fit.ngroups = fr->ngroups;
    memcpy(rep->fit.sky_groups, fr->sky_groups, sizeof rep->fit.sky_groups);
    rep->fit.ops_render = fr->ops_render;
    rep->fitted = (long)nrow;
}

/* The phase grid the fit draws its groups' PRFs from — the one the last
 * fit used (mp_frame_report.grid), else economy's own decision for this
 * run (mp_econ_choose with the fit's count of star fits) — and its flux
 * limit on the stars' median sky, as the fit sets it (fit/frame_rules.c).
 * The residual and the one-or-two test draw the stars within that limit
 * from it, as the fit's paints of the neighbours do (issue 12: 15 % of 47
 * Tuc's CPU was the test's exact renders).  NULL (exact renders) without
 * economy or a grid.  Economy's own decision is priced on the render
 * windows the last fit measured (mp_frame_report.win, ~40 px a side on 47
 * Tuc), as the fit's was: on fitrad's windows it declines the grid (47
 * Tuc with Tiny Tim's table: every star of the test rendered exactly, ~36
 * s a round against the fit's 37; after the PSF's second pass, with no
 * fit yet on the new table, the 256² crop's search 0.24 → 1.32 s). */

const mp_prf_cache *mp_run_phase_grid(run_state *s, double *gemax, double *glemax,
                                      mp_prf_tiers *tiers)
{
    char err[MP_ERRLEN];         /* a failed build leaves the exact renders */
    *gemax = 0.0;
    if (glemax)
        *glemax = 0.0;
    if (tiers)
        memset(tiers, 0, sizeof *tiers);
    mp_frame_opts oe = s->fit->opts;
    if (!oe.cache)
        return NULL;
    oe.grid = s->grid;
    oe.win = s->win > 0 ? s->win : oe.win;
    if (!oe.grid || !mp_prf_cache_usable(oe.grid, &s->fit->model)) {
        double fits = oe.fits > (double)s->t.nrow ? oe.fits : (double)s->t.nrow;
        oe.grid = NULL;
        if (mp_econ_choose(oe.cache, fits, oe.fit.fitrad, &oe, NULL, err) || !oe.grid ||
            !mp_prf_cache_usable(oe.grid, &s->fit->model))
            return NULL;
    }
    double sky = mp_pl_median_positive(&s->t, "SKY_PSF");
    mp_prf_tiers t;
    if (mp_econ_grid_limits(oe.cache, oe.grid, sky, s->f.rdnoise, oe.sincfrac, gemax, &t)) {
        *gemax = mp_prf_cache_limit(oe.grid, sky, s->f.rdnoise, oe.sincfrac);
        mp_prf_cache_tiers(oe.grid, sky, s->f.rdnoise, oe.sincfrac, glemax != NULL, &t);
    }
    if (glemax)
        *glemax = t.lin;
    if (tiers)
        *tiers = t;
    return oe.grid;
}

/* root.grp's rows, the grouped table: held (s->grp) and written once
 * with the other products when its values take up to o->grp_hold
 * bytes (8 MiB), else
 * written now, each round (the last round's stands).  Held, the copy
 * cost ~280 bytes a star at the run's peak: 67 MiB of the 8192² frame's
 * (3.7·10⁻³ stars a pixel: a quarter of its floats, where the goal is 3
 * times them; bench/SCALING.md, 2026-12-07); written each round, it
 * costs that run ~3 % more (its writes 3.7 -> 6.6 s of ~95). */
static int keep_grouped(run_state *s, char *err)
{
    mp_table_free(&s->grp);
    if ((double)s->t.nrow * (double)s->t.ncol * sizeof *s->t.v <= s->o->grp_hold)
        return mp_pl_rows_of(&s->t, NULL, 1, &s->grp) ? oom(err) : 0;
    double t0 = mp_seconds();
    mp_run_writes(s, ".grp");
    int rc = mp_pl_write_named(s->root, ".grp", &s->t, s->o->fit.fmt, NULL, NULL, err);
    s->rep->t_write += mp_seconds() - t0;
    return rc;
}

/* Group the stars (root.grp: keep_grouped), fit every group, and draw
 * the residual.
 * once: in one pass, not the fit's passes, where a later fit takes the
 * groups up again (the fit's memory refits every group whose neighbours'
 * light changed since): with the first pass's PSF, whose fit only places
 * the neighbours the second pass takes off and draws the residual
 * searched next, and in a round another follows, whose first pass refits
 * what this one's second would have, with the new stars' groups.  47 Tuc
 * 512² built: group fits 740 / 493 / 391 → 375 / 254 / 435 by round, ~10 %
 * of the run's CPU (psfreal_notes.md, session 41).  With the PSF's first
 * pass it also stops at MP_PL_ROUND_TOL, loose: the second pass's table
 * comes with a fit memory forgotten, so every group is fitted again. */
int mp_run_group_and_fit(run_state *s, int round, int once, char *err)
{
    const mp_pipeline_opts *o = s->o;
    double t0 = mp_seconds();
    long close, coupled;
    double cf = o->groupcut_median ? 0.0 : s->fit->opts.couplefrac;
    if (mp_pl_group(&s->t, &o->group, &s->fit->model, cf, cf > 0 ? o->couplebudget : 0.0,
                    s->f.rdnoise, &s->coupling, &close, &coupled, err))
        return 1;
    s->rep->pairs_close += close;
    s->rep->pairs_coupled += coupled;
    s->rep->t_group += mp_seconds() - t0;
    if (!s->quiet && keep_grouped(s, err))
        return 1;
    t0 = mp_seconds();
    mp_frame_report fr;
    if (mp_pl_positions_of(&s->t, &s->before))
        return oom(err);
    if (need_residual(s, err))
        return 1;
    mp_frame_opts fo = s->fit->opts;
    if (once) {
        fo.passes = 1;
        if (s->psf_pass == 1)       /* the second pass's table refits every group */
            fo.loosetol = MP_PL_ROUND_TOL;
    }
    s->last_partial = fo.passes < s->fit->opts.passes || fo.loosetol > fo.fit.tol;
    if (mp_fit_table_mem(&s->f, &s->fit->model, &fo, &s->t, s->mem, &fr, err))
        return 1;
    s->grid = fr.grid;
    s->win = fr.win;
    if (mp_pl_note_gone(&s->gone, &s->before, &s->t))
        return oom(err);
    mp_table_free(&s->before);   /* not held through the residual (issue 14) */
    mp_table_init(&s->before);
    double gemax;
    mp_prf_tiers tiers;
    const mp_prf_cache *grid = mp_run_phase_grid(s, &gemax, NULL, &tiers);
    if (mp_fit_residual_grid(&s->f, &s->fit->model, &s->t, s->fit->opts.cropfrac,
                             s->fit->opts.cache, grid, gemax, &tiers, s->res, err))
        return 1;
    s->rep->t_fit += mp_seconds() - t0;
    count_fit(s->rep, &fr, s->t.nrow);
    if (!s->quiet)
        fprintf(stderr, "matphot pipeline: %s: round %d: %ld stars fitted in %ld groups "
            "(%ld merged, %ld rejected; %ld group fits, %ld kept), %.2f s\n", s->image, round,
            fr.nstars - fr.merged - fr.rejected, fr.ngroups, fr.merged, fr.rejected, fr.fits,
            fr.kept, mp_seconds() - t0);
    return 0;
}

/* The residual's noise model as detection measured it (find/noise_model.c,
 * mp_pl_star_excess), for the round's line. */
typedef struct {
    double kscale, proferr;  /* × Poisson (NaN: the residual's mesh map); profile error */
    int nring;               /* rings of the flux-squared error */
    size_t nexcess;          /* stars it is added around */
    int ndir;                /* direction cells above their rings (mp_bkg.nxd) */
} residual_noise;

/* The round's line on stderr: the new stars, the noise they were found on. */
static void say_new_stars(const run_state *s, int round, long added, const residual_noise *nz)
{
    if (isfinite(nz->kscale))
        fprintf(stderr, "matphot pipeline: %s: round %d: %ld new stars on the residual "
                "(noise: %.3f x Poisson, profile error %.1f %%, the error growing as flux "
                "squared on %d rings and %d direction cells above them around %zu stars)\n",
                s->image, round, added, nz->kscale, 100.0 * nz->proferr, nz->nring, nz->ndir,
                nz->nexcess);
    else
        fprintf(stderr, "matphot pipeline: %s: round %d: %ld new stars on the residual "
                "(noise: the residual's mesh map)\n", s->image, round, added);
}

/* The residual R's detections into s->found: find with the model's
 * sharpness limits, the low one taken at MP_PL_SHARP_SIGMA of each
 * candidate's own sharpness noise (at find's threshold that noise is
 * ~0.2 around the PSF's 0.44: sharplo 0.2 took 10 of frame X's 116 lost
 * stars), the roundness relaxed (a star half-hidden by a neighbour's fit
 * leaves a lopsided residual peak; the fit then keeps or rejects what was
 * found, by its significance), the sky known (the
 * fitted one: DAOFIND's kernel, which fits a constant too, lost stars of
 * S/N 9-16 isolated on frame X's residual), and the screen as detection
 * goes (its candidates never all held), its PRFs from the phase grid the
 * fit drew from, as the one-or-two test's.  Nonzero with err. */
static int residual_detections(run_state *s, const mp_frame *R, const mp_prf_cache *grid,
                               double gemax, char *err)
{
    mp_find_opts ro;
    if (find_opts_for_model(s, &ro, err))
        return 1;
    ro.roundlo = fmin(ro.roundlo, -2.0);
    ro.roundhi = fmax(ro.roundhi, 2.0);
    ro.sharpsig = MP_PL_SHARP_SIGMA;
    ro.sky_known = 1;
    double cut = s->fit->opts.minsnr - MP_PL_SCREEN_SLACK;
    mp_pl_screen sc = {.f = R, .b = &s->bkg, .res = s->res, .m = &s->fit->model,
                       .fitrad = s->fit->opts.fit.fitrad, .snrmin = cut, .grid = grid,
                       .gemax = gemax};
    struct mp_find_sieve sv = {mp_pl_screen_sieve, &sc, MP_PL_SNR_COL};
    ro.sieve = cut > 0 ? &sv : NULL;
    int frc = mp_find_stars(R, &s->bkg, &ro, &s->found, err);
    s->rep->screened += sc.dropped;
    return frc;
}

/* The one-or-two test's second stars added to s->found, and the new
 * detections added to the star list (*added of them).  Nonzero with err
 * when out of memory. */
static int split_and_add(run_state *s, const mp_prf_cache *grid, double gemax, double glemax,
                         long *added, char *err)
{
    const mp_pipeline_opts *o = s->o;
    /* Half a FWHM: a detection beyond it goes to the fit, which keeps the
     * pair when their separation is significant and both reach minsnr
     * (frame_group.c), else merges it.  At 1 FWHM the companions of close
     * pairs were never offered (issue 13, validate frame: members of
     * 0.5-0.75 FWHM pairs found 0.67x as often as field stars -> 0.94x). */
    double matchrad = isfinite(o->matchrad) ? o->matchrad : 0.5 * s->fwhm;
    /* One star or two: a detection nearer a star than matchrad becomes a
     * second star when the linear fit of its flux on the residual takes
     * away χ² ≥ minsnr² (its screen S/N ≥ minsnr: for one star, a chance
     * of ≈ 6e-7 per independent position, χ²(1) > 25) and it lies beyond
     * the merge radius; the fit of both then keeps the pair only if both
     * reach minsnr and their separation is significant (frame_group.c). */
    double mergerad = isfinite(s->fit->opts.mergerad) ? s->fit->opts.mergerad : 0.4 * s->fwhm;
    /* The test's own false-split rate stays ~1e-5 a star whatever minsnr
     * is: at minsnr 2 a Δχ² of 4 proposed noise (validate frame: 142 false
     * detections against 30 from find alone). */
    double splitsnr = fmax(s->fit->opts.minsnr, MP_PL_SPLIT_MINSNR);
    if (s->fit->opts.minsnr > 0 &&
        mp_pl_split_candidates(&s->f, &s->bkg, s->res, &s->fit->model, grid, gemax, glemax,
                               &s->t, o->fit.opts.fit.fitrad, 1.05 * mergerad,
                               fmax(matchrad, 1.1 * mergerad), splitsnr, &s->found) < 0)
        return oom(err);
    mp_bkg_free(&s->bkg);        /* as after the first detection */
    *added = mp_pl_add_new_stars(&s->t, &s->gone, &s->found, s->f.im.nx, s->f.im.ny, matchrad,
                                 mergerad, s->fit->opts.minsnr > 0 ? splitsnr : INFINITY);
    mp_table_free(&s->found);    /* not held through the next fit (issue 14) */
    mp_table_init(&s->found);
    if (*added < 0 || mp_table_shrink(&s->t))
        return oom(err);
    return 0;
}

/* Detect on the residual and add what is new; *added gets how many.
 *
 * The residual keeps the sky.  Its sky is measured anew (the star light is
 * gone from the boxes) and its noise map comes from the fitted model: in a
 * crowded frame the first map's boxes average star light into the rms
 * (frame C of the DAOPHOT comparison: 13.4 e- against the sky's 10.4),
 * which hides faint stars in the gaps and under-states the noise on bright
 * stars, all the more when the PSF does not match them (GLIMPSE: spurious
 * companions at 0.7 FWHM taking 15-40 % of bright stars' light). */
static int find_on_residual(run_state *s, int round, long *added, char *err)
{
    const mp_pipeline_opts *o = s->o;
    double t0 = mp_seconds();
    mp_frame R = s->f;
    R.im.pix = s->res;
    size_t npix = (size_t)s->f.im.nx * s->f.im.ny;
    for (size_t i = 0; i < npix; i++)
        if (!isfinite(s->res[i]))
            s->res[i] = 0.0;
    mp_table_free(&s->found);
    mp_table_init(&s->found);
    mp_bkg_free(&s->bkg);
    residual_noise nz = {NAN, 0.0, 0, 0, 0};
    if (mp_bkg_estimate(&R, o->mesh, o->filter, &s->bkg, err) ||
        mp_bkg_noise_from_model(&s->bkg, &s->f, s->res, s->fwhm, o->find.nsigma,
                                &nz.kscale, &nz.proferr, err) ||
        mp_pl_star_excess(&s->f, &s->bkg, &s->t, &s->fit->model, &nz.nring, &nz.nexcess, err))
        return 1;
    nz.ndir = s->bkg.nxd;
    double gemax, glemax;
    const mp_prf_cache *grid = mp_run_phase_grid(s, &gemax, &glemax, NULL);
    if (residual_detections(s, &R, grid, gemax, err) ||
        split_and_add(s, grid, gemax, glemax, added, err))
        return 1;
    s->rep->added += *added;
    /* the one-or-two test and the new stars' bookkeeping are detection's
     * too (they were counted in no stage: 47 Tuc with Tiny Tim's table,
     * ~40 of its ~350 s fell outside the report's seconds) */
    s->rep->t_find += mp_seconds() - t0;
    if (!s->quiet)
        say_new_stars(s, round, *added, &nz);
    return 0;
}

/* The fit's errors widened by what the last residual holds at the PSF's
 * scale (pipeline/error_scale.c), said on stderr and in the report. */
static int honest_errors(run_state *s, char *err)
{
    double t0 = mp_seconds();
    const double *given = s->o->escale;
    mp_pl_escale e = {{given[0], given[1]}, {NAN, NAN, NAN}, 0};
    if (!(given[0] > 0 && given[1] > 0) &&
        mp_pl_error_scale(&s->f, s->res, &s->t, &s->fit->model, s->fit->opts.fit.fitrad, s->fwhm,
                          &e, err))
        return 1;
    mp_pl_apply_error_scale(&s->t, &e);
    memcpy(s->rep->escale, e.k, sizeof e.k);
    memcpy(s->rep->escale_raw, e.raw, sizeof e.raw);
    s->rep->escale_places = (long)e.nplace;
    s->rep->t_fit += mp_seconds() - t0;
    if (!s->quiet)
        fprintf(stderr, "matphot pipeline: %s: errors x %.3g (flux), %.3g (position): the "
                "residual fitted as a star at %zu places away from the stars scatters by %.3g "
                "(flux), %.3g, %.3g (x, y) of its sigma (used when beyond %.0f of its sampling "
                "errors), %.2f s\n", s->image, e.k[0], e.k[1], e.nplace, e.raw[0], e.raw[1],
                e.raw[2], MP_PL_ESCALE_Z, mp_seconds() - t0);
    /* Below its model the noise cannot be, in electrons: k < 1 is the
     * frame's calibration (a flux scale of k² in the fit's weights). */
    if (!s->quiet && e.k[0] < 1.0)
        fprintf(stderr, "matphot pipeline: %s: warning: away from the stars the residual "
                "scatters by %.3g of its noise model (flux; %.3g, %.3g on x, y), below it: is the "
                "bias subtracted, the gain the frame's (the noise says about %.2g, not %g), "
                "the frame not resampled (correlated pixels)?  The catalog's errors are scaled "
                "by it\n", s->image, e.raw[0], e.raw[1], e.raw[2],
                s->f.gain / (e.raw[0] * e.raw[0]), s->f.gain);
    if (!s->quiet && mp_pl_escale_unused(&e)) {
        char why[320];
        mp_pl_escale_unused_why(&e, why, sizeof why);
        fprintf(stderr, "matphot pipeline: %s: warning: %s (is the frame's noise its model's? "
                "gain, rdnoise, errplane)\n", s->image, why);
    }
    return 0;
}

/* root.grp (but in a tile), root.fit (its rows root.grp holds the same,
 * the stars the last round did not refit, copied: mp_table_write_kept),
 * root.res.fits, root.cat (+ .reg), then the run report. */
static int write_products(run_state *s, char *err)
{
    double t0 = mp_seconds();
    mp_text_kept *grp_text = NULL, *fit_text = NULL;
    const char *ext[] = {s->quiet ? "" : ".grp", ".fit", ".res.fits", ".cat",
                         s->o->regions ? ".reg" : "", ".report"};
    for (size_t i = 0; i < sizeof ext / sizeof *ext; i++)
        mp_run_writes(s, ext[i]);
    int rc = (!s->quiet && s->grp.ncol > 0 &&
              mp_pl_write_named(s->root, ".grp", &s->grp, s->o->fit.fmt, NULL, &grp_text, err)) ||
             mp_pl_write_named(s->root, ".fit", &s->t, s->o->fit.fmt, grp_text, &fit_text, err);
    mp_text_kept_free(grp_text);
    rc = rc || mp_pl_write_residual(s->root, &s->f, s->res, err) ||
         mp_pl_write_catalog(s->root, &s->f, &s->t, s->o, fit_text, err);
    mp_text_kept_free(fit_text);
    if (rc)
        return 1;
    s->rep->t_write += mp_seconds() - t0;
    return mp_pl_write_report(s->image, s->root, s->fit, s->rep, &s->t, err);
}

/* The bright stars' light beyond the table (halo=yes, pipeline/halo.c),
 * measured on the first round's residual and taken off the frame; every
 * group is then fitted afresh (after the PSF's second pass when the PSF is
 * built, which then sees the frame without it). */
static int take_halo(run_state *s, char *err)
{
    char what[MP_ERRLEN];
    double t0 = mp_seconds(), z;
    if (mp_pl_halo(&s->f, s->res, &s->t, s->fwhm, &z, &s->halo_light, what, sizeof what, err))
        return 1;
    if (!s->quiet)
        fprintf(stderr, "matphot pipeline: %s: %s, %.2f s\n", s->image, what, mp_seconds() - t0);
    if (!(z > MP_PL_HALO_Z))
        return 0;                       /* nothing taken off: the fit stands */
    mp_fit_memory_forget(s->mem);
    s->rep->t_fit += mp_seconds() - t0;
    return s->o->build_psf ? 0 : mp_run_group_and_fit(s, 1, 0, err);
}

/* Cosmic rays and hot pixels (crmask=yes, pipeline/cosmics.c): the pixels
 * no sum of stars can make, tested once round 1's fit gives every star's
 * flux (their wings' allowance), masked on the frame and the residual; the
 * next fit refits every group. */
static int mask_cosmics(run_state *s, char *err)
{
    if (!s->o->crmask || s->borrowed)
        return 0;
    double t0 = mp_seconds();
    const mp_prf_model *m = &s->fit->model;
    mp_pl_cr_test ct = {.grow = s->o->crgrow, .side = s->o->mesh};
    long nx = s->f.im.nx, ny = s->f.im.ny, bx, by, cores = 0;
    int w, h;
    if (mp_pl_cr_bound(m, nx, ny, &ct.s, &ct.D, err))
        return 1;
    ct.k = mp_pl_cr_sigma((double)nx * (double)ny, MP_PL_CR_RATE);
    mp_prf_box(m, 0.5 * (double)nx, 0.5 * (double)ny, &bx, &by, &w, &h);
    mp_pl_cr_stars st = {.reach = 0.5 * (w > h ? w : h) + 1.0};
    mp_pl_star *stars = mp_pl_stars_by_flux(&s->t, 0, &st.n);
    if (!stars)
        return oom(err);
    st.s = stars;
    size_t guard[MP_PL_CR_NSHARP];
    double sharp = mp_pl_cr_sharpness(&s->f, m, &st, guard, &ct.nguard);
    ct.s *= sharp;
    ct.guard = guard;
    /* the mesh sky of the residual (the frame less every fitted star) caps
     * the sky from below (cosmics.c): a sky set high would pass starlight
     * as excess, by (4 − s) times the error, so not the frame's own mesh,
     * which a crowd raises (the residual is NaN only where masked, which
     * the estimate skips) */
    mp_frame R = s->f;
    R.im.pix = s->res;
    mp_bkg b;
    memset(&b, 0, sizeof b);
    long masked = -2;
    if (!mp_bkg_estimate(&R, s->o->mesh, s->o->filter, &b, err))
        masked = mp_pl_mask_cosmics(&s->f, &b, s->res, &st, &ct, &cores);
    mp_bkg_free(&b);
    free(stars);
    if (masked < 0)
        return masked == -1 ? oom(err) : 1;
    s->rep->cr_cores += cores;
    s->rep->cr_masked += masked;
    s->rep->cr_s = ct.s;
    s->rep->cr_D = ct.D;
    s->rep->cr_k = ct.k;
    if (masked > 0)
        mp_fit_memory_forget(s->mem);
    if (!s->quiet)
        fprintf(stderr, "matphot pipeline: %s: cosmic rays: %ld pixels masked around %ld that no "
                "sum of stars makes (side-neighbour ratio s %.3g: the PSF's x %.3g, %s; wings "
                "%.2g per e-; k %.2f sigma: %g false a frame), %.2f s\n", s->image, masked,
                cores, ct.s, sharp, ct.nguard ? "too few stars to check it on, kept out"
                                               : "its brightest stars' against it",
                ct.D, ct.k, MP_PL_CR_RATE, mp_seconds() - t0);
    s->rep->t_fit += mp_seconds() - t0;
    return 0;
}

/* What the PSF leaves around bright stars (lookup=yes, pipeline/lookup.c),
 * measured on the first round's last residual (after the PSF's second
 * pass) and taken off the frame; every group is then fitted afresh, so
 * that the stars the first fit put on a bright star's features lose their
 * light (and minsnr rejects them) before the residual is searched. */
static int take_lookup(run_state *s, char *err)
{
    char what[MP_ERRLEN];
    double t0 = mp_seconds();
    if (mp_pl_lookup(&s->f, s->res, &s->t, &s->fit->model, s->fit->opts.cropfrac, s->fwhm,
                     s->fwhm, what, sizeof what, err))
        return 1;
    if (!s->quiet)
        fprintf(stderr, "matphot pipeline: %s: %s, %.2f s\n", s->image, what, mp_seconds() - t0);
    mp_fit_memory_forget(s->mem);
    s->rep->t_fit += mp_seconds() - t0;
    return mp_run_group_and_fit(s, 1, 0, err);
}

/* The residual drawn again from the table's fitted stars with the model
 * now in s->fit (the PSF's second pass), without fitting them.  Their
 * fluxes were fitted with a table of sum sum1: with the new table's (its
 * PSFSUM may count light beyond it, the halo's) they are restated to put
 * the same light in the table, E·sum1/sum, or the residual keeps a share
 * 1 − sum/sum1 of every star (47 Tuc with halo=yes: 7 %). */
static int redraw_residual(run_state *s, double sum1, char *err)
{
    double gemax, t0 = mp_seconds();
    int cf = mp_table_col(&s->t, "FLUX_PSF");
    if (cf >= 0 && sum1 > 0 && s->psf.sum > 0 && s->psf.sum != sum1)
        for (size_t r = 0; r < s->t.nrow; r++)
            mp_table_set(&s->t, r, cf, mp_table_get(&s->t, r, cf) * sum1 / s->psf.sum);
    mp_prf_tiers tiers;
    const mp_prf_cache *grid = mp_run_phase_grid(s, &gemax, NULL, &tiers);
    s->grid = grid;             /* the residual search's, as a fit's would be */
    int rc = mp_fit_residual_grid(&s->f, &s->fit->model, &s->t, s->fit->opts.cropfrac,
                                  s->fit->opts.cache, grid, gemax, &tiers, s->res, err);
    s->rep->t_fit += mp_seconds() - t0;
    return rc;
}

/* Whether round 1 is fitted again after the PSF's second pass before its
 * residual is searched.  DAOPHOT's chain fits once with its final PSF
 * (allstar), searches that residual and fits again; here the next round
 * fits every star afresh with the second pass's PSF anyway (the fit's
 * memory is cleared with the PSF), so round 1's refit only warmed its
 * start.  Without it the residual is drawn again with the new PSF at
 * round 1's fitted stars (redraw_residual, a fraction of a second) and
 * searched.  The refit stays where no round follows, or where the look-up
 * took light off the frame after round 1 (its stars on a bright star's
 * features must lose their light before the search).  The halo's light,
 * taken off too, does not need it: it lies beyond the cores the stars'
 * fluxes come from, and redraw_residual restates them for the table's
 * new PSFSUM.  Measured against
 * the refit (bench/PROFILE.md, session of 2026-11-30 18:41): 47 Tuc with
 * its PSF built 0.86-0.94 of the CPU in three sequential pairs, 2513
 * stars (2510); GLIMPSE 0.89 (one pair), flux scatter against its
 * catalog 0.0375 (0.0375), 13 839 stars (13 981); PSFBUILD's scenes the
 * same completeness and precision within their noise. */
static int refit_after_second_pass(const run_state *s, int round)
{
    const mp_pipeline_opts *o = s->o;
    return round == o->niter || (s->own_frame && o->lookup);
}

/* The rounds: group and fit, find on the residual, until nothing new is
 * found or niter rounds are done. */
static int rounds(run_state *s, char *err)
{
    const mp_pipeline_opts *o = s->o;
    int rc = 0;
    for (int round = 1; !rc && round <= o->niter; round++) {
        s->rep->rounds = round;
        long added = 0;
        rc = mp_run_group_and_fit(s, round, round < o->niter || s->psf_pass == 1, err);
        if (!rc && round == 1)
            rc = mask_cosmics(s, err);
        if (!rc && round == 1 && s->rep->cr_masked > 0 && o->niter == 1 && !o->build_psf)
            rc = mp_run_group_and_fit(s, round, 0, err);    /* no later fit to take them */
        if (!rc && round == 1 && o->halo && s->own_frame)
            rc = take_halo(s, err);
        /* DAOPHOT's second pass: the PSF again with every neighbour gone;
         * the stars are fitted with it now or in the next round. */
        int stale = 0;
        if (!rc && round == 1 && o->build_psf) {
            double sum1 = s->psf.sum;
            rc = mp_run_build_psf(s, 2, err);
            stale = !rc && !refit_after_second_pass(s, round);
            if (!rc)
                rc = stale ? redraw_residual(s, sum1, err) : mp_run_group_and_fit(s, round, 0, err);
        }
        if (!rc && round == 1 && o->lookup && s->own_frame)
            rc = take_lookup(s, err);
        if (rc || round == o->niter)
            break;
        rc = find_on_residual(s, round, &added, err);
        /* No next round: the last PSF, all passes. */
        if (!rc && added == 0 && (stale || s->last_partial))
            rc = mp_run_group_and_fit(s, round, 0, err);
        if (added == 0)
            break;           /* nothing new: the last fit and residual stand */
    }
    return rc;
}

void mp_pl_warn_whole_frame_only(const mp_pipeline_opts *o, const char *task, const char *image,
                                 const char *where)
{
    int halo = o->halo == MP_PL_HALO_ASKED;     /* halo=auto: silently */
    if (halo || o->lookup)
        fprintf(stderr, "matphot %s: %s: warning: %s%s%s not applied %s (they are measured on "
                "the whole frame's residual)\n", task, image, halo ? "halo=yes" : "",
                halo && o->lookup ? " and " : "", o->lookup ? "lookup=yes" : "", where);
}

int mp_pipeline_run(const char *image, const char *root, const mp_pipeline_opts *o,
                    mp_pipeline_report *rep, char *err)
{
    run_state s;
    if (state_init(&s, image, root, o, rep, err)) {
        state_free(&s);
        return 1;
    }
    s.own_frame = 1;
    mp_tmp_sweep(o->sweeps, root);   /* every output is root.*: one directory */
    int rc = read_frame(&s, err) || find_stars(&s, err) || (o->build_psf && mp_run_build_psf(&s, 1, err));
    if (!rc)
        rc = rounds(&s, err) || mp_run_heldout_order(&s, err) || honest_errors(&s, err);
    if (!rc && s.t.nrow == 0)
        rc = mp_pl_no_star(image, &s.f, s.none_why, s.fwhm, o, rep, err);
    if (!rc)
        rc = write_products(&s, err);
    if (rc)
        remove_products(&s);
    state_free(&s);
    return rc;
}

int mp_pipeline_reduce(const mp_frame *f, const mp_pipeline_opts *o, mp_table *t,
                       mp_pipeline_report *out, char *err)
{
    run_state s;
    mp_pipeline_report rep;
    mp_table_init(t);
    if (o->build_psf) {
        snprintf(err, MP_ERRLEN, "psf: a PSF is needed (the reduction in memory builds none)");
        return 1;
    }
    int rc = state_init(&s, "(in memory)", NULL, o, &rep, err);
    s.quiet = 1;
    s.borrowed = 1;
    s.f = *f;                    /* borrowed: not freed below */
    if (!rc)
        rc = find_stars(&s, err) || rounds(&s, err) || honest_errors(&s, err);
    if (!rc) {
        *t = s.t;
        mp_table_init(&s.t);
    }
    if (out)
        *out = rep;
    memset(&s.f, 0, sizeof s.f);
    state_free(&s);
    return rc;
}

int mp_pl_reduce(const char *image, const mp_pipeline_opts *o, mp_pipeline_report *rep,
                 mp_pl_done_fn done, void *ctx, char *err)
{
    run_state s;
    int rc = state_init(&s, image, NULL, o, rep, err);
    s.quiet = 1;                 /* no root.coo, root.grp: the tiles' driver writes */
    if (!rc)
        rc = read_frame(&s, err) || find_stars(&s, err) || rounds(&s, err) ||
             honest_errors(&s, err) || done(ctx, &s.f, &s.t, s.res, err);
    state_free(&s);
    return rc;
}

int mp_pl_psf_on(const char *section, const char *root, const mp_pipeline_opts *o, long offx,
                 long offy, long fnx, long fny, int *built, char *err)
{
    run_state s;
    mp_pipeline_report rep;
    *built = 0;
    int rc = state_init(&s, section, root, o, &rep, err);
    s.quiet = 1;                 /* no root.coo, root.grp: the tiles write theirs */
    s.offx = offx;
    s.offy = offy;
    s.fnx = fnx;
    s.fny = fny;
    mp_tmp_sweep(o->sweeps, root);   /* root.psf.fits */
    if (!rc)
        rc = read_frame(&s, err) || find_stars(&s, err) || mp_run_build_psf(&s, 1, err);
    /* Pass 2 as a whole run makes it: every neighbour fitted and gone;
     * then, where the PSF varies, the held-out stars' verdict on the next
     * order, on the section fitted with it (PSFORDWH says which). */
    if (!rc && s.have_own)
        rc = mp_run_group_and_fit(&s, 1, s.psf_pass == 1, err) || mp_run_build_psf(&s, 2, err);
    if (!rc && s.have_own && mp_run_heldout_applies(&s))
        rc = mp_run_group_and_fit(&s, 1, 0, err) || mp_run_heldout_order(&s, err);
    *built = !rc && s.have_own;
    if (rc)
        remove_products(&s);
    state_free(&s);
    return rc;
}
