/* sharp_limits.c — find's sharpness limits made to fit the PSF in use
 * (mp_pl_sharp_limits, pipeline_priv.h).
 *
 * DAOFIND's limits (0.2 .. 1.0) are set for stars of the kernel's own
 * Gaussian, whose SHARPNESS across subpixel phases lies well inside them.
 * An undersampled PSF is sharper than any Gaussian of its equivalent FWHM
 * at the phases where its core falls on one pixel: on GLIMPSE (IRAC ch2,
 * the PSF built from the frame) 661 of 11152 peaks were cut by sharphi =
 * 1, 74 of them above 1000 e⁻, noise or not (session 24). */
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "pipeline/pipeline_priv.h"

#define PHASES 8            /* per axis: offsets −1/2, −3/8, …, 3/8 px */

/* How far from the star's pixel the kernel's peak is sought: it lies
 * within a pixel of a centred PSF's own.  Up to FWHM 4.7 px (nsigma 1.5)
 * that is the whole window, as before; a wider kernel scanned its whole
 * window at the cost of its area a pixel (fwhm=200: hours). */
#define PEAK_REACH 8

/* The range [*lo, *hi] of SHARPNESS of m's noiseless star at (x, y) plus
 * every phase.  Only a window of the star is drawn (mp_prf_render_window:
 * the values of the whole render there): the kernel's footprint around
 * the peak and as much again, not the table's wings (a Tiny Tim ×4
 * table's whole box made this 0.13 s a call).  1: out of memory; 2: find
 * cannot measure it (err says why). */
static int sharpness_range(const mp_prf_model *m, double x, double y, const mp_find_opts *o,
                           double *lo, double *hi, char *err)
{
    int hw = 2 * (int)ceil(fmax(2.0, o->nsigma * o->fwhm / 2.3548200450309493)) + 4;
    long side = 2 * hw + 1;
    double *prf = malloc((size_t)(side * side) * sizeof *prf);
    double *img = malloc((size_t)(side * side) * sizeof *img);
    mp_prf_work w;
    memset(&w, 0, sizeof w);
    int rc = !prf || !img;
    if (rc)
        snprintf(err, MP_ERRLEN, "out of memory for the PSF's sharpness");
    for (int j = 0; j < PHASES * PHASES && !rc; j++) {
        double sx = x + (j % PHASES) / (double)PHASES - 0.5;
        double sy = y + (j / PHASES) / (double)PHASES - 0.5;
        long wx0 = lround(sx) - hw, wy0 = lround(sy) - hw, x0, y0;
        int pw, ph;
        if (mp_prf_render_window(m, sx, sy, wx0, wy0, side, side, &x0, &y0, &pw, &ph, prf, NULL,
                                 NULL, &w)) {
            snprintf(err, MP_ERRLEN, "PSF's sharpness: no render at (%g, %g)", sx, sy);
            rc = 1;
            break;
        }
        memset(img, 0, (size_t)(side * side) * sizeof *img);
        for (int v = 0; v < ph; v++)
            for (int u = 0; u < pw; u++)
                img[(y0 - wy0 + v) * side + x0 - wx0 + u] = prf[v * pw + u];
        double s;
        if (mp_find_sharpness(img, side, side, o, PEAK_REACH, &s, err)) {
            rc = 2;             /* not measurable: the limits stay */
            break;
        }
        *lo = j ? fmin(*lo, s) : s;
        *hi = j ? fmax(*hi, s) : s;
    }
    mp_prf_work_free(&w);
    free(prf);
    free(img);
    return rc;
}

int mp_pl_sharp_limits(const mp_prf_model *m, long nx, long ny, mp_find_opts *o, char *why,
                       size_t nwhy, char *err)
{
    mp_psf g;
    mp_psf_gauss(o->fwhm, &g);
    mp_prf_model gm = {&g, NULL, m->sinc_hw};
    double cx = 0.5 * (double)(nx + 1), cy = 0.5 * (double)(ny + 1);
    double g0, g1, p0, p1;
    int rc = sharpness_range(&gm, cx, cy, o, &g0, &g1, err);
    rc = rc ? rc : sharpness_range(m, cx, cy, o, &p0, &p1, err);
    /* A variable PSF: its range over the frame (centre and the quarter
     * points). */
    for (int q = 0; q < 4 && !rc && m->psf->field; q++) {
        double a, b;
        rc = sharpness_range(m, (q & 1 ? 0.75 : 0.25) * (double)nx,
                             (q & 2 ? 0.75 : 0.25) * (double)ny, o, &a, &b, err);
        p0 = rc ? p0 : fmin(p0, a);
        p1 = rc ? p1 : fmax(p1, b);
    }
    if (rc == 2) {              /* a kernel or PSF find cannot measure */
        snprintf(why, nwhy, "sharpness %g..%g as given (the PSF's own not measured: %.100s)",
                 o->sharplo, o->sharphi, err);
        err[0] = '\0';
        return 0;
    }
    if (rc)
        return 1;
    double lo = o->sharplo, hi = o->sharphi;
    if (isfinite(lo) && lo < g0)
        o->sharplo = fmin(lo, p0 - (g0 - lo));
    if (isfinite(hi) && hi > g1)
        o->sharphi = fmax(hi, p1 + (hi - g1));
    snprintf(why, nwhy, "sharpness %.2f..%.2f (the PSF's own %.2f..%.2f over subpixel phases, "
             "the kernel's Gaussian's %.2f..%.2f, given %g..%g)", o->sharplo, o->sharphi, p0, p1,
             g0, g1, lo, hi);
    return 0;
}
