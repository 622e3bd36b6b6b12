/* image_write.c — mp_image_write (io.h): a float image written under a
 * temporary name and renamed, so readers never see half a file. */
#include "io/io.h"

#include <errno.h>
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <unistd.h>
#include <fitsio.h>

#include "io/fitserr.h"

/* Shortest %G that reads back to the same double, so headers stay legible
 * (GAIN = 2.5, not 2.50000000000000E+00). */
static int card_decimals(double v)
{
    char buf[40];
    snprintf(buf, sizeof buf, "%.15G", v);
    return strtod(buf, NULL) == v ? -15 : -17;
}

int mp_fits_write_cards(void *vfp, const mp_card *cards, int ncards, int *status)
{
    fitsfile *fp = vfp;
    for (int i = 0; i < ncards && !*status; i++) {
        const mp_card *c = &cards[i];
        if (!c->key)
            continue;
        if (c->str) {
            fits_update_key_str(fp, c->key, c->str, c->comment, status);
        } else if (isfinite(c->value)) {
            double v = c->value;
            if (v == floor(v) && fabs(v) < 1e15)
                fits_update_key_lng(fp, c->key, (LONGLONG)v, c->comment, status);
            else
                fits_update_key_dbl(fp, c->key, v, card_decimals(v), c->comment, status);
        }
        /* A non-finite number has no FITS form: the card is left out, and
         * readers fall back to their default (e.g. no SATURATE). */
    }
    return *status;
}

/* Either writer: pix of cfitsio type datatype (TDOUBLE or TFLOAT). */
static int write_typed(const char *path, int datatype, const void *pix, long nx, long ny,
                       int bitpix, const mp_card *cards, int ncards, char *err)
{
    if (!path || !*path) {
        snprintf(err, MP_ERRLEN, "(no name): no output image name given");
        return 1;
    }
    if (bitpix != FLOAT_IMG && bitpix != DOUBLE_IMG) {
        snprintf(err, MP_ERRLEN, "%s: cannot write BITPIX %d (only -32 or -64)", path, bitpix);
        return 1;
    }
    if (nx < 1 || ny < 1 || !pix) {
        snprintf(err, MP_ERRLEN, "%s: no pixels to write (%ld x %ld)", path, nx, ny);
        return 1;
    }
    char *tmp = mp_tmp_name(path);
    if (!tmp) {
        snprintf(err, MP_ERRLEN, "%s: out of memory", path);
        return 1;
    }
    /* The disk-file driver takes the name literally: no extended-name
     * parsing of brackets in user paths. */
    unlink(tmp);
    (void)mp_tmp_register(tmp);   /* an interrupt removes it (cleanup.c) */
    errno = 0;
    fitsfile *fp = NULL;
    int status = 0;
    long naxes[2] = {nx, ny};
    long fpix[2] = {1, 1};
    if (fits_create_diskfile(&fp, tmp, &status)) {
        int e = errno;
        fits_clear_errmsg();
        snprintf(err, MP_ERRLEN, "%s: cannot create: %s", path,
                 e ? strerror(e) : "cfitsio could not create the file");
        mp_tmp_unregister(tmp);
        free(tmp);
        return 1;
    }
    fits_create_img(fp, bitpix, 2, naxes, &status);
    mp_fits_write_cards(fp, cards, ncards, &status);
    fits_write_pix(fp, datatype, fpix, (LONGLONG)nx * ny, (void *)pix, &status);
    fits_close_file(fp, &status);
    if (status) {
        mp_fits_error(path, "write", status, err);
        unlink(tmp);
        mp_tmp_unregister(tmp);
        free(tmp);
        return 1;
    }
    if (mp_out_place(tmp, path, err) != 0) {
        unlink(tmp);
        mp_tmp_unregister(tmp);
        free(tmp);
        return 1;
    }
    mp_tmp_unregister(tmp);
    free(tmp);
    return 0;
}

int mp_image_write(const char *path, const double *pix, long nx, long ny,
                   int bitpix, const mp_card *cards, int ncards, char *err)
{
    return write_typed(path, TDOUBLE, pix, nx, ny, bitpix, cards, ncards, err);
}

int mp_image_write_float(const char *path, const float *pix, long nx, long ny,
                         const mp_card *cards, int ncards, char *err)
{
    return write_typed(path, TFLOAT, pix, nx, ny, FLOAT_IMG, cards, ncards, err);
}
