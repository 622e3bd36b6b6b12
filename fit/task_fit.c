/* task_fit.c — the `matphot fit` task: IMAGE COORDS psf=… → table of fits.
 * IMAGE and COORDS may be @lists that pair line by line (IRAF); outputs are
 * then output=@list or named after each image (frame.fits → frame.fit). */
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <time.h>
#include "catalog/catalog.h"
#include "find/find.h"
#include "fit/fit.h"
#include "params/params.h"
#include "psf/build.h"

/* The residual of t's fits on f written to residual, in ADU as the input
 * (GAIN and RDNOISE in its header).  Nonzero with err on failure. */
static int write_residual(const mp_frame *f, const mp_fit_setup *s, const mp_table *t,
                          const char *residual, char *err)
{
    float *res = malloc((size_t)f->im.nx * f->im.ny * sizeof *res);
    if (!res) {
        snprintf(err, MP_ERRLEN, "%s: out of memory for the residual", residual);
        return 1;
    }
    int rc = mp_fit_residual(f, &s->model, t, s->opts.cropfrac, res, err);
    if (!rc) {
        for (long i = 0; i < f->im.nx * f->im.ny; i++)
            res[i] /= f->gain;                  /* back to ADU, as the input */
        mp_card cards[2] = {{"GAIN", f->gain, NULL, "e-/ADU"}, {"RDNOISE", f->rdnoise, NULL, "e-"}};
        rc = mp_image_write_float(residual, res, f->im.nx, f->im.ny, cards, 2, err);
    }
    free(res);
    return rc;
}

/* The model against the width of the listed stars (psf/model_check.c),
 * when the list is find's (X_IMAGE, Y_IMAGE, FLUX, BACKGROUND; a truth or
 * hand list is taken as it is): psf=gauss with a fwhm far off them, or a
 * table read at the wrong OVERSAMP, is an error naming the parameter. */
static int check_model_width(const mp_fit_setup *s, const mp_frame *f, const mp_table *t,
                             const char *image, char *err)
{
    static const char *const cols[] = {"X_IMAGE", "Y_IMAGE", "FLUX", "BACKGROUND"};
    for (size_t k = 0; k < sizeof cols / sizeof *cols; k++)
        if (mp_table_col(t, cols[k]) < 0)
            return 0;
    mp_stars_fwhm m;
    char why[400] = "", e[MP_ERRLEN];
    int rc = mp_epsf_stars_fwhm(f, t, MP_EPSF_FWHM_STARS, &m, e) ||
             mp_epsf_model_verdict(f, t, &s->model, &m, why, sizeof why, e);
    if (rc)
        snprintf(err, MP_ERRLEN, "%s: %.400s%s", image, e,
                 mp_epsf_model_is_gauss(&s->model) ? ", or give the PSF as a table (psf=)" : "");
    return rc != 0;
}

/* The frame and its stars, refused when they hold no usable star (bad
 * input: an unusable frame, an empty table) or a model far off the
 * stars' width. */
static int read_inputs(const mp_fit_setup *s, const char *image, const char *coords,
                       mp_frame *f, mp_table *t, char *err)
{
    char why[320];
    if (mp_frame_read(image, &s->dp, f, err))
        return 1;
    if (mp_find_why_none(f, NULL, 0, why, sizeof why)) {
        snprintf(err, MP_ERRLEN, "%.180s: no usable star: %.310s", image, why);
        return 1;
    }
    if (mp_table_read(coords, t, err))
        return 1;
    if (t->nrow == 0) {
        snprintf(err, MP_ERRLEN, "%.400s: no star to fit (the table has no row)", coords);
        return 1;
    }
    return check_model_width(s, f, t, image, err);
}

/* The run report, beside a named output as frame.report (a piped run
 * reports on stderr). */
static int report_fit(const mp_fit_setup *s, const mp_table *t, const mp_frame_report *rep,
                      mp_run_report *run, const char *output, char *err)
{
    char *report = NULL;
    run->nstars = (long)t->nrow;
    mp_report_counts(rep, run);
    char tables[512];
    mp_econ_summary(s->cache, rep->ops_render, tables, sizeof tables);
    run->tables = tables;
    mp_report_from_table(t, run);
    mp_report_parts(&s->model, &s->opts, rep, run);
    run->decisions = s->decisions;
    run->ndecisions = s->ndecisions;
    if (output && output[0] && strcmp(output, "-") != 0 && !(report = mp_name_after(output, ".report"))) {
        snprintf(err, MP_ERRLEN, "out of memory");
        return 1;
    }
    int rc = mp_report_write(report, "fit", run, err);
    free(report);
    return rc;
}

/* Fit one image with one coordinate table; write the table and residual.
 * nframes: the run's frames, so that economy plans its tables for the
 * whole @list (this table's stars in every frame, fit/econ_plan.c). */
static int fit_one(const mp_fit_setup *s, const char *image, const char *coords,
                   const char *output, const char *residual, size_t nframes, char *err)
{
    mp_frame f;
    memset(&f, 0, sizeof f);
    mp_table t;
    mp_table_init(&t);
    int rc = 1;
    mp_run_report run;
    memset(&run, 0, sizeof run);
    run.image = image;
    double t0 = mp_seconds();
    if (read_inputs(s, image, coords, &f, &t, err))
        goto done;
    size_t given = t.nrow;
    run.t_read = mp_seconds() - t0;
    char e[MP_ERRLEN];
    mp_frame_report rep;
    mp_frame_opts fo = s->opts;
    fo.fits = (double)t.nrow * (double)nframes;
    /* An @list: the plan knows the whole list; what the frames already
     * rendered would count the same fits twice (and come too late to
     * pay).  One frame: its fits' exact-render work counts too, as a
     * pipeline frame's does (issue 12: the plan's 4 renders a fit against
     * 47 Tuc's ~17 iterations of crowded groups never paid for the phase
     * grid, which serves every group there). */
    fo.learn = nframes == 1;
    t0 = mp_seconds();
    if (mp_fit_table(&f, &s->model, &fo, &t, &rep, e)) {
        snprintf(err, MP_ERRLEN, "%.200s: %.300s", coords, e);
        goto done;
    }
    run.t_fit = mp_seconds() - t0;
    if (t.nrow == 0) {          /* a frame with no usable star: bad input */
        snprintf(err, MP_ERRLEN, "%.160s: no usable star: all %zu stars of %.160s rejected by "
                 "their fits (S/N FLUX_PSF/FLUXERR_PSF < minsnr %g) or merged", image, given,
                 coords, s->opts.minsnr);
        goto done;
    }
    t0 = mp_seconds();
    if ((residual && residual[0] && write_residual(&f, s, &t, residual, err)) ||
        mp_table_write(output, &t, s->fmt, err))
        goto done;
    run.t_write = mp_seconds() - t0;
    rc = report_fit(s, &t, &rep, &run, output, err);
done:
    mp_table_free(&t);
    mp_frame_free(&f);
    return rc;
}

int mp_task_fit(int argc, char **argv)
{
    mp_parset ps;
    int b = mp_task_begin("fit", argc, argv, &ps);
    if (b)
        return b;
    char err[MP_ERRLEN] = "";
    mp_fit_setup s;
    char **im = NULL, **co = NULL, **out = NULL, **rs = NULL;
    size_t nim = 0, nco = 0, nout = 0, nrs = 0;
    int rc = 1;
    /* Killed runs' temporaries: each output directory swept once. */
    mp_sweeps *sw = mp_sweeps_new();
    mp_inputs *ins = NULL;
    if (mp_fit_setup_read(&ps, &s, err))
        goto done;
    mp_fit_setup_warn(&s, "fit");
    if (mp_params_list(mp_par_string(&ps, "image"), &im, &nim, err) ||
        mp_params_list(mp_par_string(&ps, "coords"), &co, &nco, err) ||
        mp_params_list(mp_par_string(&ps, "output"), &out, &nout, err) ||
        mp_params_list(mp_par_string(&ps, "residual"), &rs, &nrs, err))
        goto done;
    if (nco != nim || (nout && nout != nim) || (nrs && nrs != nim)) {
        snprintf(err, MP_ERRLEN, "coords: %zu coordinate tables, output %zu, residual %zu "
                 "for %zu images: lists must pair line by line", nco, nout, nrs, nim);
        goto done;
    }
    for (size_t i = 0; i < nrs; i++)
        if (mp_out_fits_named("residual", rs[i], err))
            goto done;
    /* every frame and table of the lists: an output of the first may be
     * the input of a later one */
    int bad = !(ins = mp_inputs_of((const char *const *)im, nim));
    for (size_t i = 0; i < nco && !bad; i++)
        bad = mp_inputs_add(ins, co[i]);
    if (bad) {
        snprintf(err, MP_ERRLEN, "out of memory");
        goto done;
    }
    if (mp_fit_setup_inputs(&ps, &s, ins, err))
        goto done;
    int failed = 0;
    for (size_t i = 0; i < nim; i++) {
        char *named = NULL;
        const char *o = nout ? out[i] : "-";
        if (!nout && nim > 1) {
            if (!(named = mp_name_after(im[i], ".fit"))) {
                snprintf(err, MP_ERRLEN, "out of memory");
                goto done;
            }
            o = named;
        }
        int r = mp_out_overwrites(ins, o, err) || (nrs && mp_out_overwrites(ins, rs[i], err));
        if (!r) {
            mp_tmp_sweep(sw, o);
            if (nrs)
                mp_tmp_sweep(sw, rs[i]);
            r = fit_one(&s, im[i], co[i], o, nrs ? rs[i] : NULL, nim, err);
        }
        free(named);
        if (r)      /* its own line: the list's other frames go on (pipeline's) */
            fprintf(stderr, "matphot fit: %s\n", err);
        failed |= r;
    }
    rc = failed;
    err[0] = '\0';             /* each said where it happened */
done:
    if (rc && err[0])
        fprintf(stderr, "matphot fit: %s\n", err);
    mp_list_free(im, nim);
    mp_list_free(co, nco);
    mp_list_free(out, nout);
    mp_list_free(rs, nrs);
    mp_sweeps_free(sw);
    mp_inputs_free(ins);
    mp_fit_setup_free(&s);
    mp_params_free(&ps);
    return rc;
}
