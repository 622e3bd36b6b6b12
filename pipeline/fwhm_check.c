/* fwhm_check.c — the given fwhm checked against the frame's stars
 * (mp_pl_check_fwhm, pipeline_priv.h).
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
 * error when the build finds too few stars. */
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "pipeline/pipeline_priv.h"
#include "psf/build.h"

#define NMEASURE 25         /* stars measured at most */
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

/* Whether m measured a FWHM more than 3 σ of the measure off fwhm. */
static int off(const mp_stars_fwhm *m, double fwhm)
{
    return m->n >= MP_PL_FWHM_NEED && fabs(fwhm - m->fwhm) > 3.0 * m->err;
}

int mp_pl_check_fwhm(const mp_frame *f, const mp_table *t, double fwhm, mp_stars_fwhm *mo,
                     char *why, size_t nwhy, char *err)
{
    why[0] = '\0';
    if (mp_epsf_stars_fwhm(f, t, NMEASURE, mo, err))
        return 1;
    mp_stars_fwhm m = *mo;
    if (m.n < MP_PL_FWHM_NEED) {
        snprintf(why, nwhy, "the stars' FWHM not measured (%d lone, clean detections of %d "
                 "needed)", m.n, MP_PL_FWHM_NEED);
        return 0;
    }
    double g2 = s2(fwhm), bias = 2.0 * g2 / (g2 + s2(m.fwhm)) - 1.0;
    double e = median_rel_err(f, t, m.fwhm);
    snprintf(why, nwhy, "the stars' FWHM %.3g +- %.2g px (a Gaussian fitted to each of %d lone "
             "detections; fwhm %g puts a Gaussian star's flux %+.1f %% off, the median "
             "detection's error %.1f %%)", m.fwhm, m.err, m.n, fwhm, 100.0 * bias, 100.0 * e);
    if (off(&m, fwhm) && fabs(bias) > e) {
        snprintf(err, MP_ERRLEN, "fwhm=%g is not the stars': %d lone stars measure FWHM %.3g "
                 "+- %.2g px, and the Gaussian of fwhm=%g puts their fluxes %+.0f %% off, "
                 "more than the median star's error (%.1f %%); give fwhm=%.3g (INDEF: "
                 "measured on each frame), or build the PSF (psf= empty)", fwhm, m.n, m.fwhm,
                 m.err, fwhm,
                 100.0 * bias, 100.0 * e, m.fwhm);
        return 2;
    }
    return 0;
}

/* The stars of f measured on find's detections with a kernel of FWHM
 * w and the given options' other settings, shape cuts open (a kernel
 * far off the stars' would cut them). */
static int measure_with(const mp_frame *f, const mp_bkg *b, const mp_find_opts *fo, double w,
                        mp_stars_fwhm *m, char *err)
{
    mp_find_opts o = *fo;
    o.fwhm = w;
    o.sharplo = o.sharphi = o.roundlo = o.roundhi = NAN;
    mp_table t;
    mp_table_init(&t);
    int rc = mp_find_stars(f, b, &o, &t, err) || mp_epsf_stars_fwhm(f, &t, NMEASURE, m, err);
    mp_table_free(&t);
    return rc;
}

int mp_pl_frame_fwhm(const char *image, const mp_pipeline_opts *o, mp_stars_fwhm *m, char *err)
{
    /* The kernels tried in turn: the parameter file's default, then wider
     * (a narrow kernel breaks a wide star's top into peaks no test calls
     * lone). */
    static const double kernels[] = {3.0, 12.0, 48.0};
    mp_frame f;
    mp_bkg b;
    memset(&b, 0, sizeof b);
    memset(m, 0, sizeof *m);
    if (mp_frame_read(image, &o->fit.dp, &f, err))
        return 1;
    int rc = mp_bkg_estimate(&f, o->mesh, o->filter, &b, err);
    for (size_t k = 0; !rc && m->n < MP_PL_FWHM_NEED && k < sizeof kernels / sizeof *kernels; k++)
        rc = measure_with(&f, &b, &o->find, kernels[k], m, err);
    if (!rc && m->n < MP_PL_FWHM_NEED) {
        snprintf(err, MP_ERRLEN, "fwhm: INDEF, and %s has too few stars to measure it (%d lone "
                 "stars of S/N >= 20, %d needed): give fwhm", image, m->n, MP_PL_FWHM_NEED);
        rc = 1;
    }
    mp_bkg_free(&b);
    mp_frame_free(&f);
    return rc;
}
