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
    mp_sinc_choice_free(&s->sinc);
    mp_prf_cache_free(&s->cache);
}

/* Paper §5.4: a discrete PSF needs β ≥ 21 in its own (super)pixels, or
 * bright stars alias.  β·V² = 1/sharpness keeps the test independent of
 * the detector's efficiency. */
static void warn_undersampled(const mp_fit_setup *s)
{
    mp_prf_stats st;
    if (s->psf.kind != MP_PSF_TABLE || mp_prf_stats_at(&s->model, 1000.0, 1000.0, &st, NULL))
        return;
    double b = st.sharp > 0 ? 1.0 / st.sharp : 0.0, bs = b * s->psf.os * s->psf.os;
    if (b < 21.0 && bs < 21.0)
        fprintf(stderr, "matphot fit: warning: PSF undersampled: beta = %.1f px^2 < 21, "
                "and its OVERSAMP %d gives %.1f < 21 table px^2; bright stars will alias "
                "(use a table supersampled %dx or more)\n",
                b, s->psf.os, bs, (int)ceil(sqrt(21.0 / b)));
}

/* Note one economy decision and its reason for the run report. */
static void decide(mp_fit_setup *s, const char *what)
{
    size_t k = strlen(s->decisions);
    snprintf(s->decisions + k, sizeof s->decisions - k, "%s%s", k ? "; " : "", what);
    s->ndecisions++;
}

/* 1/sharpness of the PRF at a pixel centre: β·V², the paper's β for V = 1. */
static double beta_normalised(const mp_prf_model *m)
{
    mp_prf_stats st;
    if (mp_prf_stats_at(m, 1000.0, 1000.0, &st, NULL) || !(st.sharp > 0))
        return 0.0;
    return 1.0 / st.sharp;
}

/* economy=yes: leave out what cannot change the answer (issue 5); every
 * decision, to drop a part or to keep it, is logged with its reason.
 *  - A DRF map whose subpixels are all equal is the scalar V.
 *  - A supersampled table is block-summed to the coarsest sampling s at
 *    which β·V²·s² ≥ 21 px² (paper §5.4; s = 1 when the data are
 *    oversampled, validate cases 2 and 3) when no DRF map needs the
 *    subpixels, unless the user asked for a sampling with psfos. */
static int economize(mp_fit_setup *s, int psfos_given, char *err)
{
    char why[256];
    if (s->drf.k > 0) {
        int uniform = 1;
        double lo = s->drf.qe[0], hi = s->drf.qe[0];
        for (int i = 1; i < s->drf.k * s->drf.k; i++) {
            uniform &= s->drf.qe[i] == s->drf.qe[0];
            lo = s->drf.qe[i] < lo ? s->drf.qe[i] : lo;
            hi = s->drf.qe[i] > hi ? s->drf.qe[i] : hi;
        }
        if (uniform) {
            double v = s->drf.qe[0];
            snprintf(why, sizeof why, "DRF: the %dx%d map is uniform, used as the scalar V = %.6g",
                     s->drf.k, s->drf.k, v);
            mp_drf_free(&s->drf);
            mp_drf_uniform(v, &s->drf);
        } else {
            snprintf(why, sizeof why, "DRF: the %dx%d map varies (QE %.3g to %.3g), kept",
                     s->drf.k, s->drf.k, lo, hi);
        }
        decide(s, why);
    }
    if (s->psf.kind != MP_PSF_TABLE || s->psf.os <= 1)
        return 0;
    int os = s->psf.os;
    if (psfos_given) {
        snprintf(why, sizeof why, "supersampling: psfos given, the x%d table used as asked", os);
        decide(s, why);
        return 0;
    }
    if (s->drf.k > 0) {
        snprintf(why, sizeof why, "supersampling: the %dx%d DRF map needs the x%d subpixels, kept",
                 s->drf.k, s->drf.k, os);
        decide(s, why);
        return 0;
    }
    /* The coarsest sampling s (a divisor of the table's) at which the
     * table holds β·s² ≥ 21 px² (paper §5.4: 1× tables are on the CRLB
     * from β = 21 on, and a 2× table of an undersampled PSF, β·4 ≥ 21, is;
     * validate cases 2, 5, 6b). */
    double b = beta_normalised(&s->model);
    int want = os;
    for (int k = 1; k < os; k++)
        if (os % k == 0 && b * k * k >= 21.0) {
            want = k;
            break;
        }
    if (want < os) {
        mp_psf coarse;
        if (mp_psf_rebin(&s->psf, os / want, &coarse, err))
            return 1;
        mp_psf_free(&s->psf);
        s->psf = coarse;
        snprintf(why, sizeof why, "supersampling: beta = %.1f px^2 at detector sampling, "
                 "%.1f >= 21 at x%d (paper 5.4), the x%d table block-summed to x%d", b,
                 b * want * want, want, os, want);
    } else {
        snprintf(why, sizeof why, "supersampling: beta = %.1f px^2 < 21 at detector sampling "
                 "(paper 5.4) and no coarser sampling reaches 21, the x%d table kept", b, os);
    }
    decide(s, why);
    return 0;
}

/* skymodel: an explicit order is honoured; auto chooses per group from the
 * data under economy=yes, and economy=no switches every part of the model
 * on, so auto fits the quadratic sky everywhere. */
static int sky_order_of(const char *v, int economy)
{
    if (!strcmp(v, "constant"))
        return 0;
    if (!strcmp(v, "plane"))
        return 1;
    if (!strcmp(v, "quadratic"))
        return 2;
    return economy ? MP_SKY_AUTO : 2;
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
    mp_datapars_read(ps, &s->dp);
    if (mp_table_format_parse(mp_par_string(ps, "format"), &s->fmt)) {
        snprintf(err, MP_ERRLEN, "format: unknown table format '%s'", mp_par_string(ps, "format"));
        return 1;
    }
    int economy = 1;
    mp_par_bool(ps, "economy", &economy);
    /* Under auto, the per-group choices are counted in the run report
     * (mp_report_parts) as one more economy decision. */
    s->opts.fit.sky_order = sky_order_of(mp_par_string(ps, "skymodel"), economy);
    int psfos = MP_PAR_INDEF_INT;
    mp_par_int(ps, "psfos", &psfos);
    if (economy && economize(s, psfos != MP_PAR_INDEF_INT, err))
        return 1;
    if (economy) {
        char why[256];
        /* The kernel choice is measured on the model as it now stands (after
         * any block-summing above). */
        if (mp_sinc_choice_build(&s->model, &s->sinc, err))
            return 1;
        if (s->sinc.nph > 0) {
            s->opts.sinc = &s->sinc;
            snprintf(why, sizeof why, "sinc kernel: per group, the shortest half-width <= %d "
                     "whose bias stays below %.2g of its brightest star's sigma "
                     "(fit/sinc_choice.c)", s->sinc.hwmax, s->opts.sincfrac);
            decide(s, why);
        }
        /* The phase grid, built from the model as it now stands (exact,
         * full kernel), last: nothing above renders through it. */
        int grid = MP_PRF_CACHE_G;
        mp_par_int(ps, "phasegrid", &grid);
        if (grid > 0 && mp_prf_cache_build(&s->model, grid, &s->cache, err))
            return 1;
        if (s->cache.G > 0) {
            s->model.cache = &s->cache;
            snprintf(why, sizeof why, "PRF from a grid of %dx%d subpixel phases (cubic "
                     "interpolation) for groups whose brightest star's bias bound stays below "
                     "%.2g sigma, exact renders for the others (fit/prf_cache.c)",
                     s->cache.G, s->cache.G, s->opts.sincfrac);
            decide(s, why);
        }
        snprintf(why, sizeof why, "neighbour light: painted out to where it falls below %.2g of a "
                 "sky pixel's sigma (residual too)", s->opts.cropfrac);
        decide(s, why);
        snprintf(why, sizeof why, "refits: a group is refitted only when its members or its "
                 "neighbours' light changed (sqrt(sum (dlight/sigma)^2) >= %.2g, which bounds "
                 "every parameter's change to that many sigma)", s->opts.refittol);
        decide(s, why);
    } else {
        decide(s, "economy=no: every part of the model forced on");
        s->opts.cropfrac = 0.0;     /* economy=no: the full work, to compare */
        s->opts.refittol = 0.0;
    }
    warn_undersampled(s);
    return 0;
}
