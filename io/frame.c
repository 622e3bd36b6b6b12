/* frame.c — mp_frame_read (io.h): an image in electrons with its mask and
 * the detector numbers in force. */
#include "io/io.h"
#include "params/params.h"

#include <fitsio.h>
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

void mp_datapars_read(const mp_parset *ps, mp_datapars *dp)
{
    *dp = (mp_datapars){NAN, NAN, NAN, NAN, "", 0, 0, 0, "", 0, 0};
    mp_par_real(ps, "gain", &dp->gain);
    mp_par_real(ps, "rdnoise", &dp->rdnoise);
    mp_par_real(ps, "saturate", &dp->saturate);
    mp_par_real(ps, "exptime", &dp->exptime);
    /* Tasks without the DQ parameters (older @files) simply have none. */
    const char *dq = mp_par_string(ps, "dqmask");
    snprintf(dp->dqmask, sizeof dp->dqmask, "%s", dq ? dq : "");
    int v = 0;
    if (!mp_par_int(ps, "dqsat", &v) && v > 0)
        dp->dqsat = v;
    v = 0;
    if (!mp_par_int(ps, "dqbad", &v) && v > 0)
        dp->dqbad = v;
    v = 0;
    if (!mp_par_int(ps, "satgrow", &v) && v > 0)
        dp->satgrow = v;
    v = 0;
    if (!mp_par_int(ps, "bleedgrow", &v) && v > 0)
        dp->bleedgrow = v;
    v = 0;
    if (!mp_par_int(ps, "badgrow", &v) && v > 0)
        dp->badgrow = v;
    const char *ep = mp_par_string(ps, "errplane");
    snprintf(dp->errplane, sizeof dp->errplane, "%s", ep ? ep : "");
}

/* The DQ image's name: "[EXT]" is an extension of the frame's own file
 * (the frame's own extension dropped), and a section of the frame
 * ("[1:128,1:128]", any bracket group with a ':') applies to the DQ image
 * too, so the two stay pixel for pixel.  Caller frees. */
static char *dq_name(const char *image, const char *dq)
{
    size_t n = dq[0] == '[' ? strcspn(image, "[") : 0, len = strlen(image);
    char *s = malloc(n + strlen(dq) + len + 1);
    if (!s)
        return NULL;
    memcpy(s, image, n);
    strcpy(s + n, dq);
    for (const char *g = strchr(image, '['); g; g = strchr(g + 1, '[')) {
        const char *e = strchr(g, ']');
        if (!e)
            break;
        if (memchr(g, ':', (size_t)(e - g)))
            strncat(s, g, (size_t)(e - g + 1));
    }
    return s;
}

/* An auxiliary plane of the frame (dqmask, errplane), read and checked
 * for size; *got is set when aux must be freed. */
static int read_aux(const char *name, const char *par, const char *aux, const mp_frame *f,
                    mp_image *im, int *got, char *err)
{
    *got = 0;
    char *an = dq_name(name, aux);
    if (!an) {
        snprintf(err, MP_ERRLEN, "%s: out of memory", name);
        return 1;
    }
    int rc = mp_image_read(an, im, err);
    *got = !rc;
    if (!rc && (im->nx != f->im.nx || im->ny != f->im.ny)) {
        snprintf(err, MP_ERRLEN, "%s: %s is %ldx%ld, the frame %s is %ldx%ld", par, an, im->nx,
                 im->ny, name, f->im.nx, f->im.ny);
        rc = 1;
    }
    free(an);
    return rc;
}

/* errplane=auto: does the frame's own file hold an image extension named
 * ERR (HST FLT/FLC/DRZ, JWST)?  Any failure to tell is no: the frame's own
 * read reports a broken file.  Asked after that read, whose header guard
 * walked every HDU of this file (io.h): walked again here, a gzipped
 * frame was inflated once more for nothing. */
static int has_err_ext(const char *name)
{
    size_t n = strcspn(name, "[");
    char *base = malloc(n + 1);
    if (!base)
        return 0;
    memcpy(base, name, n);
    base[n] = '\0';
    fitsfile *fp = NULL;
    int status = 0, found = 0;
    fits_open_file(&fp, base, READONLY, &status);
    if (!status) {
        fits_movnam_hdu(fp, IMAGE_HDU, "ERR", 0, &status);
        found = !status;
    }
    if (fp) {
        int s2 = 0;
        fits_close_file(fp, &s2);
    }
    free(base);
    return found;
}

/* The error plane's variance beyond the Poisson noise and RON² (io.h,
 * mp_frame.xvar), after the pixels are in electrons and masked.  An
 * infinite or NaN error (cfitsio reads an IEEE infinity as NaN), or one
 * whose variance overflows a float, is no weight: the pixel is masked
 * bad. */
static int apply_err(const char *name, const mp_datapars *dp, mp_frame *f, char *err)
{
    mp_image e;
    int got, rc = read_aux(name, "errplane", dp->errplane, f, &e, &got, err);
    size_t n = (size_t)f->im.nx * (size_t)f->im.ny;
    if (!rc && !(f->xvar = malloc((n ? n : 1) * sizeof *f->xvar))) {
        snprintf(err, MP_ERRLEN, "%s: out of memory for the error plane", name);
        rc = 1;
    }
    double ron2 = f->rdnoise * f->rdnoise;
    for (size_t i = 0; !rc && i < n; i++) {
        double s = e.pix[i] * f->gain, d = f->im.pix[i];
        f->xvar[i] = 0.0f;
        if (f->mask[i] & MP_MASK_BAD)
            continue;
        double x = s * s - (d > 0 ? d : 0.0) - ron2;
        if (s < 0) {
            snprintf(err, MP_ERRLEN, "errplane: %.400s: pixel (%ld, %ld) holds %g, not an error >= 0",
                     dp->errplane, (long)(i % (size_t)f->im.nx) + 1,
                     (long)(i / (size_t)f->im.nx) + 1, e.pix[i]);
            rc = 1;
        } else if (!isfinite((float)x)) {   /* also a variance beyond a float's range */
            f->nsat -= (f->mask[i] & MP_MASK_SATURATED) != 0;
            f->mask[i] = MP_MASK_BAD;
            f->im.pix[i] = 0.0;
            f->nbad++;
        } else {
            f->xvar[i] = x > 0 ? (float)x : 0.0f;
        }
    }
    if (got)
        mp_image_free(&e);
    return rc;
}

/* The DQ plane's bad pixels grown by g (datapars badgrow): a pixel within
 * g (in x and in y) of one is bad too, unless saturated.  Called before
 * any other masking, so every bad pixel then is the DQ plane's.  From a
 * copy, so that the growth does not feed on itself. */
static int grow_bad(mp_frame *f, int g, const char *name, char *err)
{
    long nx = f->im.nx, ny = f->im.ny, n = nx * ny;
    uint8_t *m0 = malloc(n > 0 ? (size_t)n : 1);
    if (!m0) {
        snprintf(err, MP_ERRLEN, "%s: out of memory for the DQ mask", name);
        return 1;
    }
    memcpy(m0, f->mask, n > 0 ? (size_t)n : 0);
    for (long y = 0; y < ny; y++)
        for (long x = 0; x < nx; x++) {
            if (!(m0[y * nx + x] & MP_MASK_BAD))
                continue;
            for (long j = y - g > 0 ? y - g : 0; j <= y + g && j < ny; j++)
                for (long i = x - g > 0 ? x - g : 0; i <= x + g && i < nx; i++)
                    if (!f->mask[j * nx + i])
                        f->mask[j * nx + i] = MP_MASK_BAD;
        }
    free(m0);
    return 0;
}

/* Apply the DQ image's bits to the mask (before any other masking, so the
 * counts stay those of the final mask). */
static int apply_dq(const char *name, const mp_datapars *dp, mp_frame *f, char *err)
{
    mp_image dq;
    int got, rc = read_aux(name, "dqmask", dp->dqmask, f, &dq, &got, err);
    for (size_t i = 0, n = (size_t)f->im.nx * (size_t)f->im.ny; !rc && i < n; i++) {
        double v = dq.pix[i];
        long bits = isfinite(v) && v >= 0 && v < 2147483648.0 ? (long)v : 0;
        /* Saturation first: a saturated core that another bit flags too
         * (AstroDrizzle marks them as cosmic rays, 4096: ACS DQ 6400 =
         * 4096|2048|256) is still saturated, so satgrow grows it and its
         * stars keep FLAGS 1. */
        if (bits & dp->dqsat)
            f->mask[i] |= MP_MASK_SATURATED;
        else if (bits & dp->dqbad)
            f->mask[i] |= MP_MASK_BAD;
    }
    if (got)
        mp_image_free(&dq);
    return rc || (dp->badgrow > 0 && grow_bad(f, dp->badgrow, name, err));
}

/* The saturated pixels grown by g (datapars satgrow): a pixel within g
 * (in x and in y) of one saturated by SATURATE or the DQ plane is
 * saturated too, unless it is bad already.  From a copy, so that the
 * growth does not feed on itself. */
static int grow_saturated(mp_frame *f, int g, const char *name, char *err)
{
    long nx = f->im.nx, ny = f->im.ny, n = nx * ny;
    uint8_t *m0 = malloc(n > 0 ? (size_t)n : 1);
    if (!m0) {
        snprintf(err, MP_ERRLEN, "%s: out of memory for the saturation mask", name);
        return 1;
    }
    memcpy(m0, f->mask, n > 0 ? (size_t)n : 0);
    for (long y = 0; y < ny; y++)
        for (long x = 0; x < nx; x++) {
            if (!(m0[y * nx + x] & MP_MASK_SATURATED))
                continue;
            for (long j = y - g > 0 ? y - g : 0; j <= y + g && j < ny; j++)
                for (long i = x - g > 0 ? x - g : 0; i <= x + g && i < nx; i++)
                    if (!f->mask[j * nx + i]) {
                        f->mask[j * nx + i] = MP_MASK_SATURATED;
                        f->nsat++;
                    }
        }
    free(m0);
    return 0;
}

/* A bleed trail's ends (datapars bleedgrow): a run of two or more
 * saturated pixels along a column is a bleed, and the g pixels beyond each
 * end of it are saturated too (charge spilled along the column past where
 * the DQ plane stops flagging it), unless bad already.  From a copy. */
static int grow_bleeds(mp_frame *f, int g, const char *name, char *err)
{
    long nx = f->im.nx, ny = f->im.ny;
    uint8_t *m0 = malloc(nx * ny > 0 ? (size_t)(nx * ny) : 1);
    if (!m0) {
        snprintf(err, MP_ERRLEN, "%s: out of memory for the saturation mask", name);
        return 1;
    }
    memcpy(m0, f->mask, nx * ny > 0 ? (size_t)(nx * ny) : 0);
    for (long x = 0; x < nx; x++)
        for (long y = 0; y < ny;) {
            long y1 = y;
            while (y1 < ny && (m0[y1 * nx + x] & MP_MASK_SATURATED))
                y1++;
            if (y1 - y >= 2)
                for (long k = 1; k <= g; k++)
                    for (int e = 0; e < 2; e++) {
                        long j = e ? y1 - 1 + k : y - k;
                        if (j >= 0 && j < ny && !f->mask[j * nx + x]) {
                            f->mask[j * nx + x] = MP_MASK_SATURATED;
                            f->nsat++;
                        }
                    }
            y = y1 > y ? y1 : y + 1;
        }
    free(m0);
    return 0;
}

/* Gain, read noise, saturation and exposure time: the parameter's, else
 * the header's, else the default; a bad value named by where it came
 * from (the header or the parameter). */
static int resolve_datapars(const char *name, const mp_datapars *dp, mp_frame *f, char *err)
{
    mp_image hv = mp_fimage_header(&f->im);
    int hg, hr, hs, he;
    if (resolve(name, &hv, dp->gain, "GAIN", 1.0, &f->gain, &hg, err) ||
        resolve(name, &hv, dp->rdnoise, "RDNOISE", 0.0, &f->rdnoise, &hr, err) ||
        resolve(name, &hv, dp->saturate, "SATURATE", INFINITY, &f->saturate, &hs, err) ||
        resolve(name, &hv, dp->exptime, "EXPTIME", 1.0, &f->exptime, &he, err))
        return 1;
    if (!(f->gain > 0) || !isfinite(f->gain)) {
        if (hg)
            snprintf(err, MP_ERRLEN, "%s: header GAIN = %g; the gain must be positive "
                     "(set gain= to override)", name, f->gain);
        else
            snprintf(err, MP_ERRLEN, "gain: %g is not a positive number of e-/ADU", f->gain);
        return 1;
    }
    if (!(f->rdnoise >= 0) || !isfinite(f->rdnoise)) {
        if (hr)
            snprintf(err, MP_ERRLEN, "%s: header RDNOISE = %g; the read noise must be >= 0 "
                     "(set rdnoise= to override)", name, f->rdnoise);
        else
            snprintf(err, MP_ERRLEN, "rdnoise: %g is not a read noise >= 0 e-", f->rdnoise);
        return 1;
    }
    return 0;
}

/* The mask: the DQ plane's flags, non-finite pixels bad (and zero; so are
 * those whose electrons overflow a float), the pixels at SATURATE (judged
 * in ADU, as it is given) saturated, grown along bleeds and around; the
 * pixels scaled to electrons. */
static int mask_pixels(const char *name, const mp_datapars *dp, mp_frame *f, char *err)
{
    size_t n = (size_t)f->im.nx * (size_t)f->im.ny;
    f->mask = calloc(n ? n : 1, 1);
    if (!f->mask) {
        snprintf(err, MP_ERRLEN, "%s: out of memory for the mask", name);
        return 1;
    }
    /* A mask named with no bit of it selected did nothing, said nothing:
     * the frame was reduced unmasked (dqmask= of a file that does not
     * exist ran to exit 0). */
    if (dp->dqmask[0] && !dp->dqsat && !dp->dqbad) {
        snprintf(err, MP_ERRLEN, "dqmask: %.300s is given, but dqbad and dqsat select no bit of "
                 "it (dqbad=BITS marks bad pixels, dqsat=BITS saturated ones)", dp->dqmask);
        return 1;
    }
    if (dp->dqmask[0] && apply_dq(name, dp, f, err))
        return 1;
    /* In parallel, each pixel its own (serial, this loop was 1.7 % of a
     * 2048² run's wall time on 16 threads; cfitsio's read 1.1 % more). */
    long nbad = 0, nsat = 0;
#pragma omp parallel for schedule(static) reduction(+ : nbad, nsat) if (n > 65536)
    for (size_t i = 0; i < n; i++) {
        double adu = f->im.pix[i];
        /* a value whose electrons a float cannot hold is no number either */
        if (!isfinite((float)(adu * f->gain)) || (f->mask[i] & MP_MASK_BAD)) {
            f->mask[i] = MP_MASK_BAD;
            f->im.pix[i] = 0.0;
            nbad++;
            continue;
        }
        if (adu >= f->saturate)
            f->mask[i] = MP_MASK_SATURATED;
        nsat += f->mask[i] == MP_MASK_SATURATED;
        f->im.pix[i] = adu * f->gain;
    }
    f->nbad += nbad;
    f->nsat += nsat;
    return (dp->bleedgrow > 0 && f->nsat && grow_bleeds(f, dp->bleedgrow, name, err)) ||
           (dp->satgrow > 0 && f->nsat && grow_saturated(f, dp->satgrow, name, err));
}

int mp_frame_read(const char *name, const mp_datapars *dp, mp_frame *f, char *err)
{
    memset(f, 0, sizeof *f);
    const mp_datapars none = {NAN, NAN, NAN, NAN, "", 0, 0, 0, "", 0, 0};
    if (!dp)
        dp = &none;
    if (mp_fimage_read(name, &f->im, err))
        return 1;
    if (resolve_datapars(name, dp, f, err) || mask_pixels(name, dp, f, err))
        goto fail;
    mp_datapars dpe = *dp;
    if (strcmp(dp->errplane, "auto") == 0)
        snprintf(dpe.errplane, sizeof dpe.errplane, "%s", has_err_ext(name) ? "[ERR]" : "");
    if (strcmp(dpe.errplane, "none") == 0)
        dpe.errplane[0] = '\0';
    if (dpe.errplane[0] && apply_err(name, &dpe, f, err))
        goto fail;
    return 0;

fail:
    mp_frame_free(f);
    return 1;
}

void mp_frame_free(mp_frame *f)
{
    if (!f)
        return;
    mp_fimage_free(&f->im);
    free(f->mask);
    f->mask = NULL;
    free(f->xvar);
    f->xvar = NULL;
    f->nbad = f->nsat = 0;
}
