/* setup.c — the fit's parameters (fit.par, shared by the pipeline) turned
 * into a PSF, a DRF, a model and options, once for every image. */
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include "fit/fit.h"

void mp_fit_setup_free(mp_fit_setup *s)
{
    mp_psf_free(&s->psf);
    mp_drf_free(&s->drf);
}

/* Paper §5.4: a discrete PSF needs β ≥ 21 in its own (super)pixels, or
 * bright stars alias.  β·V² = 1/sharpness keeps the test independent of
 * the detector's efficiency. */
static void warn_undersampled(const mp_fit_setup *s)
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

int mp_fit_setup_read(const mp_parset *ps, mp_fit_setup *s, char *err)
{
    memset(s, 0, sizeof *s);
    const char *psf = mp_par_string(ps, "psf");
    int norm = 0;
    mp_par_bool(ps, "psfnorm", &norm);
    char warn[MP_ERRLEN];
    if (psf[0]) {
        int hos = MP_PAR_INDEF_INT;
        mp_par_int(ps, "oversamp", &hos);
        if (mp_psf_read(psf, norm, hos == MP_PAR_INDEF_INT ? 0 : hos, &s->psf, warn, err))
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
    warn_undersampled(s);
    return 0;
}
