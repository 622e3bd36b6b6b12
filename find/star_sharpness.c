/* star_sharpness.c — DAOFIND's SHARPNESS of a noiseless star image: what
 * the shape cut sees of a PSF itself (mp_find_sharpness, find.h). */
#include <math.h>
#include <stdio.h>

#include "find/find_priv.h"

/* h at pixel (px, py) and, through *sharp, SHARPNESS there (mpf_measure's
 * definitions with every tap good). */
static double height_at(const double *img, long nx, const mpf_kernel *k, long px, long py,
                        double *sharp)
{
    double h = 0.0, others = 0.0;
    for (int t = 0; t < k->n; t++) {
        double v = img[(py + k->dy[t]) * nx + px + k->dx[t]];
        h += k->kl[t] * v;
        if (k->dx[t] || k->dy[t])
            others += v;
    }
    *sharp = (img[py * nx + px] - others / (k->n - 1)) / h;
    return h;
}

int mp_find_sharpness(const double *img, long nx, long ny, const mp_find_opts *o, long reach,
                      double *sharp, char *err)
{
    mpf_kernel k;
    if (mpf_kernel_make(o->fwhm, o->nsigma, 0, &k, err))
        return 1;
    double hmax = -HUGE_VAL;
    *sharp = NAN;
    long x0 = k.nh, x1 = nx - k.nh, y0 = k.nh, y1 = ny - k.nh;
    if (reach > 0) {
        x0 = x0 > nx / 2 - reach ? x0 : nx / 2 - reach;
        x1 = x1 < nx / 2 + reach + 1 ? x1 : nx / 2 + reach + 1;
        y0 = y0 > ny / 2 - reach ? y0 : ny / 2 - reach;
        y1 = y1 < ny / 2 + reach + 1 ? y1 : ny / 2 + reach + 1;
    }
    for (long py = y0; py < y1; py++)
        for (long px = x0; px < x1; px++) {
            double s, h = height_at(img, nx, &k, px, py, &s);
            if (h > hmax) {
                hmax = h;
                *sharp = s;
            }
        }
    mpf_kernel_free(&k);
    if (!(hmax > 0.0) || !isfinite(*sharp)) {
        snprintf(err, MP_ERRLEN, "sharpness: the %ld x %ld image holds no star the kernel "
                 "of fwhm %g sees whole", nx, ny, o->fwhm);
        return 1;
    }
    return 0;
}
