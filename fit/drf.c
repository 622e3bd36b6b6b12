/* drf.c — detector response functions: subpixel QE maps (paper §5.7). */
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include "fit/fit.h"

void mp_drf_uniform(double volume, mp_drf *d)
{
    memset(d, 0, sizeof *d);
    d->volume = volume;
}

void mp_drf_free(mp_drf *d)
{
    if (!d)
        return;
    free(d->qe);
    memset(d, 0, sizeof *d);
}

int mp_drf_read(const char *name, int psf_os, mp_drf *d, char *err)
{
    memset(d, 0, sizeof *d);
    mp_image im = {0};
    if (mp_image_read(name, &im, err))
        return 1;
    int rc = 1;
    if (im.nx != im.ny) {
        snprintf(err, MP_ERRLEN, "%s: DRF is %ldx%ld; it must be square (k x k subpixels)",
                 name, im.nx, im.ny);
        goto done;
    }
    int k = (int)im.nx;
    if (psf_os % k) {
        snprintf(err, MP_ERRLEN, "%s: DRF has %d subpixels a side, which does not divide "
                 "the PSF's OVERSAMP %d", name, k, psf_os);
        goto done;
    }
    double s = 0.0;
    for (int i = 0; i < k * k; i++) {
        double q = im.pix[i];
        if (!isfinite(q) || q < 0 || q > 1) {
            snprintf(err, MP_ERRLEN, "%s: DRF value %g outside 0..1", name, q);
            goto done;
        }
        s += q;
    }
    if (!(s > 0)) {
        snprintf(err, MP_ERRLEN, "%s: DRF is zero everywhere", name);
        goto done;
    }
    d->k = k;
    d->qe = im.pix;
    im.pix = NULL;
    d->volume = s / (k * k);
    rc = 0;
done:
    mp_image_free(&im);
    return rc;
}
