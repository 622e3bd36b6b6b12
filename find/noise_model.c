/* noise_model.c — mp_bkg_noise_from_model (find.h): the noise map of a
 * fit's residual from the Poisson model of the fitted frame. */
#include "find/find.h"

#include <math.h>
#include <stdlib.h>
#include <string.h>

static int cmp_double(const void *a, const void *b)
{
    double x = *(const double *)a, y = *(const double *)b;
    return (x > y) - (x < y);
}

/* Median of v[0..n-1] (reorders v). */
static double median_of(double *v, size_t n)
{
    qsort(v, n, sizeof *v, cmp_double);
    return n % 2 ? v[n / 2] : 0.5 * (v[n / 2 - 1] + v[n / 2]);
}

/* Variance [e-²] the Poisson model gives pixel i: sky + stars + RON². */
static double model_var(const mp_bkg *b, const mp_frame *f, const double *res, size_t i)
{
    return fmax(b->sky[i], 0.0) + fmax(f->im.pix[i] - res[i], 0.0) + f->rdnoise * f->rdnoise;
}

int mp_bkg_noise_from_model(mp_bkg *b, const mp_frame *f, const double *res, double *scale,
                            char *err)
{
    *scale = NAN;
    size_t npix = (size_t)f->im.nx * (size_t)f->im.ny;
    /* A regular subsample keeps the sort cheap on large frames; 2·10⁵
     * pixels pin the scale to ~0.2 % (MAD efficiency 37 %). */
    size_t step = npix / 200000 + 1, nz = 0;
    double *z = malloc((npix / step + 1) * sizeof *z);
    if (!z) {
        snprintf(err, MP_ERRLEN, "out of memory for the residual noise map");
        return 1;
    }
    for (size_t i = 0; i < npix; i += step) {
        double v = model_var(b, f, res, i);
        if (!f->mask[i] && v > 0 && isfinite(res[i]))
            z[nz++] = (res[i] - b->sky[i]) / sqrt(v);
    }
    if (nz >= 10) {
        double med = median_of(z, nz);
        for (size_t k = 0; k < nz; k++)
            z[k] = fabs(z[k] - med);
        /* 1.4826·MAD: σ of a Gaussian; robust to the stars not yet found. */
        double k = 1.482602218505602 * median_of(z, nz);
        if (k > 0 && isfinite(k)) {
            *scale = k;
            for (size_t i = 0; i < npix; i++)
                b->rms[i] = k * sqrt(model_var(b, f, res, i));
        }
    }
    free(z);
    return 0;
}
