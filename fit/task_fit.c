/* task_fit.c — the `matphot fit` task: IMAGE COORDS psf=… → table of fits.
 * IMAGE and COORDS may be @lists that pair line by line (IRAF); outputs are
 * then output=@list or named after each image (frame.fits → frame.fit). */
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <time.h>
#include "catalog/catalog.h"
#include "fit/fit.h"
#include "params/params.h"

/* What the task's parameters say, resolved once for every image. */
typedef struct {
    mp_psf psf;
    mp_drf drf;
    int have_drf;
    mp_prf_model model;
    mp_frame_opts opts;
    mp_datapars dp;
    mp_table_format fmt;
} fit_setup;

static void setup_free(fit_setup *s)
{
    mp_psf_free(&s->psf);
    mp_drf_free(&s->drf);
}

static int setup_of(const mp_parset *ps, fit_setup *s, char *err)
{
    memset(s, 0, sizeof *s);
    const char *psf = mp_par_string(ps, "psf");
    int norm = 0;
    mp_par_bool(ps, "psfnorm", &norm);
    char warn[MP_ERRLEN];
    if (psf[0]) {
        if (mp_psf_read(psf, norm, &s->psf, warn, err))
            return 1;
        if (warn[0])
            fprintf(stderr, "matphot fit: warning: %s\n", warn);
        int os = MP_PAR_INDEF_INT;
        mp_par_int(ps, "psfos", &os);
        if (os != MP_PAR_INDEF_INT && os != s->psf.os) {
            mp_psf coarse;
            if (s->psf.os % os) {
                snprintf(err, MP_ERRLEN, "psfos: %d does not divide the table's OVERSAMP %d",
                         os, s->psf.os);
                return 1;
            }
            if (mp_psf_rebin(&s->psf, s->psf.os / os, &coarse, err))
                return 1;
            mp_psf_free(&s->psf);
            s->psf = coarse;
        }
    } else {
        double fwhm;
        mp_par_real(ps, "fwhm", &fwhm);
        mp_psf_gauss(fwhm, &s->psf);
    }
    const char *drf = mp_par_string(ps, "drf");
    double vol = 1.0;
    mp_par_real(ps, "volume", &vol);
    if (drf[0]) {
        if (mp_drf_read(drf, s->psf.os, &s->drf, err))
            return 1;
    } else {
        mp_drf_uniform(vol, &s->drf);
    }
    mp_frame_opts_default(&s->opts);
    mp_par_real(ps, "fitrad", &s->opts.fit.fitrad);   /* INDEF (NaN): whole image */
    s->opts.fit.sky_order = strcmp(mp_par_string(ps, "skymodel"), "plane") == 0;
    mp_par_real(ps, "tol", &s->opts.fit.tol);
    mp_par_int(ps, "maxiter", &s->opts.fit.maxiter);
    mp_par_real(ps, "mergerad", &s->opts.mergerad);
    mp_par_real(ps, "minsnr", &s->opts.minsnr);
    mp_par_int(ps, "passes", &s->opts.passes);
    int hw = 10;
    mp_par_int(ps, "sinchw", &hw);
    s->model.psf = &s->psf;
    s->model.drf = &s->drf;
    s->model.sinc_hw = hw;
    mp_par_real(ps, "magzero", &s->opts.magzero);
    mp_par_real(ps, "gain", &s->dp.gain);
    mp_par_real(ps, "rdnoise", &s->dp.rdnoise);
    mp_par_real(ps, "saturate", &s->dp.saturate);
    mp_par_real(ps, "exptime", &s->dp.exptime);
    if (mp_table_format_parse(mp_par_string(ps, "format"), &s->fmt)) {
        snprintf(err, MP_ERRLEN, "format: unknown table format '%s'", mp_par_string(ps, "format"));
        return 1;
    }
    return 0;
}

/* Paper §5.4: a discrete PSF needs β ≥ 21 in its own (super)pixels, or
 * bright stars alias.  β·V² = 1/sharpness keeps the test independent of
 * the detector's efficiency. */
static void warn_undersampled(const fit_setup *s)
{
    if (s->psf.kind != MP_PSF_TABLE)
        return;
    long x0, y0;
    int w, h;
    mp_prf_box(&s->model, 1000.0, 1000.0, &x0, &y0, &w, &h);
    double *p = malloc((size_t)w * h * sizeof *p);
    mp_prf_work wk = {0};
    if (p && !mp_prf_render(&s->model, 1000.0, 1000.0, p, NULL, NULL, &wk)) {
        mp_prf_stats st;
        mp_prf_stats_of(p, (size_t)w * h, &st);
        double b = st.sharp > 0 ? 1.0 / st.sharp : 0.0, bs = b * s->psf.os * s->psf.os;
        if (b < 21.0 && bs < 21.0)
            fprintf(stderr, "matphot fit: warning: PSF undersampled: beta = %.1f px^2 < 21, "
                    "and its OVERSAMP %d gives %.1f < 21 table px^2; bright stars will alias "
                    "(use a table supersampled %dx or more)\n",
                    b, s->psf.os, bs, (int)ceil(sqrt(21.0 / b)));
    }
    free(p);
    mp_prf_work_free(&wk);
}

/* image.fits → image<ext>; "-" stays "-". */
static char *named_after(const char *image, const char *ext)
{
    const char *br = strchr(image, '[');
    size_t n = br ? (size_t)(br - image) : strlen(image);
    const char *dot = NULL;
    for (size_t i = 0; i < n; i++)
        if (image[i] == '.')
            dot = image + i;
        else if (image[i] == '/')
            dot = NULL;
    if (dot && (strncmp(dot, ".fits", 5) == 0 || strncmp(dot, ".fit", 4) == 0 || strncmp(dot, ".fts", 4) == 0))
        n = (size_t)(dot - image);
    char *s = malloc(n + strlen(ext) + 1);
    if (s) {
        memcpy(s, image, n);
        strcpy(s + n, ext);
    }
    return s;
}

/* Fit one image with one coordinate table; write the table and residual. */
static int fit_one(const fit_setup *s, const char *image, const char *coords,
                   const char *output, const char *residual, char *err)
{
    mp_frame f;
    memset(&f, 0, sizeof f);
    mp_table t;
    mp_table_init(&t);
    int rc = 1;
    double *res = NULL;
    if (mp_frame_read(image, &s->dp, &f, err))
        goto done;
    if (mp_table_read(coords, &t, err))
        goto done;
    char e[MP_ERRLEN];
    mp_frame_report rep;
    struct timespec t0, t1;
    clock_gettime(CLOCK_MONOTONIC, &t0);
    if (mp_fit_table(&f, &s->model, &s->opts, &t, &rep, e)) {
        snprintf(err, MP_ERRLEN, "%.200s: %.300s", coords, e);
        goto done;
    }
    clock_gettime(CLOCK_MONOTONIC, &t1);
    fprintf(stderr, "matphot fit: %s: %ld stars in %ld groups, %ld merged, %ld rejected, "
            "%ld not converged, %.2f s\n", image, rep.nstars, rep.ngroups, rep.merged,
            rep.rejected, rep.noconv, (double)(t1.tv_sec - t0.tv_sec) + 1e-9 * (t1.tv_nsec - t0.tv_nsec));
    if (residual && residual[0]) {
        res = malloc((size_t)f.im.nx * f.im.ny * sizeof *res);
        if (!res) {
            snprintf(err, MP_ERRLEN, "%s: out of memory for the residual", residual);
            goto done;
        }
        if (mp_fit_residual(&f, &s->model, &t, res, err))
            goto done;
        for (long i = 0; i < f.im.nx * f.im.ny; i++)
            res[i] /= f.gain;                   /* back to ADU, as the input */
        mp_card cards[2] = {{"GAIN", f.gain, NULL, "e-/ADU"}, {"RDNOISE", f.rdnoise, NULL, "e-"}};
        if (mp_image_write(residual, res, f.im.nx, f.im.ny, -32, cards, 2, err))
            goto done;
    }
    if (mp_table_write(output, &t, s->fmt, err))
        goto done;
    rc = 0;
done:
    free(res);
    mp_table_free(&t);
    mp_frame_free(&f);
    return rc;
}

/* Expand a list argument; a single word stands for itself. */
static int expand(const char *arg, char ***v, size_t *n, char *err)
{
    if (!arg || !arg[0]) {
        *v = NULL;
        *n = 0;
        return 0;
    }
    return mp_params_list(arg, v, n, err);
}

int mp_task_fit(int argc, char **argv)
{
    mp_parset ps;
    int b = mp_task_begin("fit", argc, argv, &ps);
    if (b)
        return b;
    char err[MP_ERRLEN] = "";
    fit_setup s;
    char **im = NULL, **co = NULL, **out = NULL, **rs = NULL;
    size_t nim = 0, nco = 0, nout = 0, nrs = 0;
    int rc = 1;
    if (setup_of(&ps, &s, err))
        goto done;
    warn_undersampled(&s);
    if (expand(mp_par_string(&ps, "image"), &im, &nim, err) ||
        expand(mp_par_string(&ps, "coords"), &co, &nco, err) ||
        expand(mp_par_string(&ps, "output"), &out, &nout, err) ||
        expand(mp_par_string(&ps, "residual"), &rs, &nrs, err))
        goto done;
    if (nco != nim || (nout && nout != nim) || (nrs && nrs != nim)) {
        snprintf(err, MP_ERRLEN, "coords: %zu coordinate tables, output %zu, residual %zu "
                 "for %zu images: lists must pair line by line", nco, nout, nrs, nim);
        goto done;
    }
    for (size_t i = 0; i < nim; i++) {
        char *named = NULL;
        const char *o = nout ? out[i] : "-";
        if (!nout && nim > 1) {
            if (!(named = named_after(im[i], ".fit"))) {
                snprintf(err, MP_ERRLEN, "out of memory");
                goto done;
            }
            o = named;
        }
        int r = fit_one(&s, im[i], co[i], o, nrs ? rs[i] : NULL, err);
        free(named);
        if (r)
            goto done;
    }
    rc = 0;
done:
    if (rc)
        fprintf(stderr, "matphot fit: %s\n", err);
    mp_list_free(im, nim);
    mp_list_free(co, nco);
    mp_list_free(out, nout);
    mp_list_free(rs, nrs);
    setup_free(&s);
    mp_params_free(&ps);
    return rc;
}
