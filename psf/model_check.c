/* model_check.c — the fit's model checked against the width of the
 * frame's stars (mp_epsf_model_verdict, build.h),
 * by the pipeline (pipeline/fwhm_check.c) and `matphot fit`.
 *
 * With psf=gauss the Gaussian of fwhm is the model every star is fitted
 * with; a wrong one ran to the end and wrote a catalog of wrong fluxes
 * (fwhm=20 on stars of FWHM 3: 26 stars, 9712 pixels masked as cosmic
 * rays, exit 0).  Fitting a star of Gaussian σm with one of σg, on a flat
 * sky-limited noise, gives its flux times 2 sg²/(sg² + sm²), s² = σ² +
 * 1/12 for the pixel (least squares of one Gaussian on another).  That
 * bias is set against the flux error of the median detection, √(F + β
 * (B + RON²)) / F with β = 4π sm² (the paper's §2 effective background
 * area of a Gaussian): beyond it and beyond 3 σ of the measure, most of
 * the catalog's error bars would not cover their stars' bias, and the
 * run stops naming fwhm.  With the PSF built from the frame fwhm is only
 * where the build starts: the measure is said in the report, and in the
 * error when the build finds too few stars.
 *
 * A table given is the user's PSF, whose shape no Gaussian judges; its
 * scale is another matter.  Read at the wrong OVERSAMP (a file without
 * the card: Tiny Tim's ×4 table read as ×1 on 47 Tuc gave 146 stars for
 * 2175, errors × 30, exit 0) its stars are that factor too wide or
 * narrow, and OVERSAMP factors are whole numbers, most often powers of
 * two.  So the table's width (its noiseless star measured as the frame's
 * are) is set against the stars': nearer in log to twice or half of it,
 * or beyond, than to it, and beyond 3 σ of the measure, the run stops
 * naming oversamp with the power of two the widths give.  A true table
 * is not the stars' width to the percent (Tiny Tim's ×4 star on 47 Tuc
 * is 0.82 of theirs, IRAC's on GLIMPSE and legacypipe's PSFEx model on
 * the DECam cutout are given in the README): only a factor of √2 or
 * more is an error. */
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "psf/build_priv.h"

#define FWHM_SIGMA 2.3548200450309493

/* s² of a pixel-integrated Gaussian of FWHM w: σ² + 1/12. */
static double s2(double w)
{
    double s = w / FWHM_SIGMA;
    return s * s + 1.0 / 12.0;
}

/* The median over t's detections of their flux's relative error with a
 * Gaussian of FWHM w (NaN: none). */
static double median_rel_err(const mp_frame *f, const mp_table *t, double w)
{
    int cf = mp_table_col(t, "FLUX"), cb = mp_table_col(t, "BACKGROUND");
    double *v = malloc((t->nrow + 1) * sizeof *v), beta = 4.0 * M_PI * s2(w);
    double ron2 = f->rdnoise * f->rdnoise, med = NAN;
    if (!v || cf < 0)
        goto done;
    size_t n = 0;
    for (size_t q = 0; q < t->nrow; q++) {
        double F = mp_table_get(t, q, cf), B = cb >= 0 ? mp_table_get(t, q, cb) : 0.0;
        if (F > 0 && isfinite(B))
            v[n++] = sqrt(F + beta * (fmax(B, 0.0) + ron2)) / F;
    }
    if (n)
        med = mp_epsf_median(v, n);
done:
    free(v);
    return med;
}

/* psf=gauss's verdict: 2 with err naming fwhm when the Gaussian of fwhm
 * is off the stars and its flux bias on them exceeds the median
 * detection's flux error; the bias added to why. */
static int gauss_verdict(const mp_frame *f, const mp_table *t, double fwhm,
                         const mp_stars_fwhm *m, char *why, size_t nwhy, char *err)
{
    if (m->n < MP_EPSF_FWHM_NEED)
        return 0;
    double g2 = s2(fwhm), bias = 2.0 * g2 / (g2 + s2(m->fwhm)) - 1.0;
    double e = median_rel_err(f, t, m->fwhm);
    size_t l = strlen(why);
    if (l < nwhy)
        snprintf(why + l, nwhy - l, "; fwhm %g puts a Gaussian star's flux %+.1f %% off, the "
                 "median detection's error %.2g %%", fwhm, 100.0 * bias, 100.0 * e);
    if (!(mp_epsf_fwhm_off(m, fwhm) && fabs(bias) > e))
        return 0;
    snprintf(err, MP_ERRLEN, "fwhm=%g is not the stars': %d lone stars measure FWHM %.3g +- %.2g "
             "px, and the Gaussian of fwhm=%g puts their fluxes %+.0f %% off, more than the "
             "median star's error (%.2g %%); give fwhm=%.3g", fwhm, m->n, m->fwhm, m->err,
             fwhm, 100.0 * bias, 100.0 * e, m->fwhm);
    return 2;
}

/* A table's verdict: 2 with err naming oversamp when its own star (at
 * (x, y), read at OVERSAMP os) is off the stars and nearer in log to
 * twice or half their width than to it; 1 when it cannot be measured;
 * its width added to why. */
static int table_verdict(const mp_prf_model *model, int os, double x, double y,
                         const mp_stars_fwhm *m, char *why, size_t nwhy, char *err)
{
    if (m->n < MP_EPSF_FWHM_NEED)
        return 0;
    double wt;
    if (mp_epsf_model_fwhm(model, x, y, &wt, err))
        return 1;
    double ratio = wt / m->fwhm;
    size_t l = strlen(why);
    if (l < nwhy)
        snprintf(why + l, nwhy - l, "; the table's own star %.3g px, %.3g times as wide", wt,
                 ratio);
    if (!(mp_epsf_fwhm_off(m, wt) && fabs(log2(ratio)) > 0.5))
        return 0;
    /* The power of two the widths' ratio is nearest (a table sharper
     * than the stars by a fifth, as Tiny Tim's on 47 Tuc, still names
     * ×4 when read at ×1: ratio 3.3). */
    double k = ldexp((double)os, (int)lround(log2(ratio)));
    snprintf(err, MP_ERRLEN, "oversamp: the table read at OVERSAMP %d makes stars of FWHM %.3g "
             "px, %.2g times the frame's (%.3g +- %.2g px, %d lone stars); is its OVERSAMP %g "
             "(oversamp=%g)?", os, wt, ratio, m->fwhm, m->err, m->n, k, k);
    return 2;
}

int mp_epsf_model_verdict(const mp_frame *f, const mp_table *t, const mp_prf_model *model,
                          const mp_stars_fwhm *m, char *why, size_t nwhy, char *err)
{
    const mp_psf *p = model->psf;
    if (mp_epsf_model_is_gauss(model))
        return gauss_verdict(f, t, FWHM_SIGMA * p->sigma, m, why, nwhy, err);
    return table_verdict(model, p->os, 0.5 * (double)(f->im.nx + 1),
                         0.5 * (double)(f->im.ny + 1), m, why, nwhy, err);
}

int mp_epsf_model_is_gauss(const mp_prf_model *model)
{
    return model->psf && model->psf->kind == MP_PSF_GAUSS && !model->psf->field;
}
