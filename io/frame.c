/* frame.c — mp_frame_read (io.h): an image in electrons with its mask and
 * the detector numbers in force. */
#include "io/io.h"

#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

/* One detector number: datapars when set (not NaN), else the header
 * keyword, else the default.  A keyword that is there but not a number is
 * an error rather than silently the default. */
static int resolve(const char *name, const mp_image *im, double dp, const char *key,
                   double def, double *out, int *from_header, char *err)
{
    *from_header = 0;
    if (!isnan(dp)) {
        *out = dp;
        return 0;
    }
    double v;
    switch (mp_header_double(im, key, &v)) {
    case 0:
        *out = v;
        *from_header = 1;
        return 0;
    case 1:
        *out = def;
        return 0;
    default: {
        char s[81] = "";
        mp_header_string(im, key, s, sizeof s);
        snprintf(err, MP_ERRLEN, "%s: header keyword %s = '%s' is not a number",
                 name, key, s);
        return 1;
    }
    }
}

int mp_frame_read(const char *name, const mp_datapars *dp, mp_frame *f, char *err)
{
    memset(f, 0, sizeof *f);
    const mp_datapars none = {NAN, NAN, NAN, NAN};
    if (!dp)
        dp = &none;
    if (mp_image_read(name, &f->im, err))
        return 1;

    int hg, hr, hs, he;
    if (resolve(name, &f->im, dp->gain, "GAIN", 1.0, &f->gain, &hg, err) ||
        resolve(name, &f->im, dp->rdnoise, "RDNOISE", 0.0, &f->rdnoise, &hr, err) ||
        resolve(name, &f->im, dp->saturate, "SATURATE", INFINITY, &f->saturate, &hs, err) ||
        resolve(name, &f->im, dp->exptime, "EXPTIME", 1.0, &f->exptime, &he, err))
        goto fail;
    /* Name where a bad value came from: the header or the parameter. */
    if (!(f->gain > 0) || !isfinite(f->gain)) {
        if (hg)
            snprintf(err, MP_ERRLEN, "%s: header GAIN = %g; the gain must be positive "
                     "(set gain= to override)", name, f->gain);
        else
            snprintf(err, MP_ERRLEN, "gain: %g is not a positive number of e-/ADU", f->gain);
        goto fail;
    }
    if (!(f->rdnoise >= 0) || !isfinite(f->rdnoise)) {
        if (hr)
            snprintf(err, MP_ERRLEN, "%s: header RDNOISE = %g; the read noise must be >= 0 "
                     "(set rdnoise= to override)", name, f->rdnoise);
        else
            snprintf(err, MP_ERRLEN, "rdnoise: %g is not a read noise >= 0 e-", f->rdnoise);
        goto fail;
    }
    (void)hs;
    (void)he;

    size_t n = (size_t)f->im.nx * (size_t)f->im.ny;
    f->mask = calloc(n ? n : 1, 1);
    if (!f->mask) {
        snprintf(err, MP_ERRLEN, "%s: out of memory for the mask", name);
        goto fail;
    }
    for (size_t i = 0; i < n; i++) {
        double adu = f->im.pix[i];
        if (!isfinite(adu)) {
            f->mask[i] = MP_MASK_BAD;
            f->im.pix[i] = 0.0;
            f->nbad++;
            continue;
        }
        /* Saturation is judged in ADU, as SATURATE is given. */
        if (adu >= f->saturate) {
            f->mask[i] = MP_MASK_SATURATED;
            f->nsat++;
        }
        f->im.pix[i] = adu * f->gain;
    }
    return 0;

fail:
    mp_frame_free(f);
    return 1;
}

void mp_frame_free(mp_frame *f)
{
    if (!f)
        return;
    mp_image_free(&f->im);
    free(f->mask);
    f->mask = NULL;
    f->nbad = f->nsat = 0;
}
