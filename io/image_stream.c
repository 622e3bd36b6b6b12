/* image_stream.c — an image written a rectangle at a time (io.h:
 * mp_image_out_*), under a temporary name renamed at the end, so a frame
 * reduced in tiles never holds its whole residual in memory; and
 * mp_image_size, a frame's size without its pixels. */
#include "io/io.h"

#include <errno.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <unistd.h>
#include <fitsio.h>

#include "io/fitserr.h"
#include "io/section.h"

struct mp_image_out {
    fitsfile *fp;
    char *path, *tmp;
    long nx, ny;
};

int mp_image_size(const char *name, long *nx, long *ny, char *err)
{
    char *n = mp_section_name(name);
    if (!n) {
        snprintf(err, MP_ERRLEN, "%s: out of memory", name);
        return 1;
    }
    if (mp_fits_guard_named(n, name, err)) {
        free(n);
        return 1;
    }
    fitsfile *fp = NULL;
    int status = 0, naxis = 0;
    long ax[3] = {0, 0, 0};
    fits_open_image(&fp, n, READONLY, &status);
    fits_get_img_dim(fp, &naxis, &status);
    fits_get_img_size(fp, 3, ax, &status);
    if (fp)
        fits_close_file(fp, &status);
    free(n);
    if (status) {
        mp_fits_error(name, "read", status, err);
        return 1;
    }
    if (naxis < 2 || (naxis > 2 && ax[2] > 1)) {
        snprintf(err, MP_ERRLEN, "%s: not a 2-D image", name);
        return 1;
    }
    *nx = ax[0];
    *ny = ax[1];
    return 0;
}

static void out_free(mp_image_out *o)
{
    if (o->tmp)
        mp_tmp_unregister(o->tmp);
    free(o->tmp);
    free(o->path);
    free(o);
}

int mp_image_out_open(const char *path, long nx, long ny, const mp_card *cards, int ncards,
                      mp_image_out **op, char *err)
{
    *op = NULL;
    mp_image_out *o = calloc(1, sizeof *o);
    if (!o || !(o->path = strdup(path)) || !(o->tmp = mp_tmp_name(path))) {
        snprintf(err, MP_ERRLEN, "%s: out of memory", path);
        if (o)
            out_free(o);
        return 1;
    }
    o->nx = nx;
    o->ny = ny;
    unlink(o->tmp);
    (void)mp_tmp_register(o->tmp);
    int status = 0;
    long naxes[2] = {nx, ny};
    if (fits_create_diskfile(&o->fp, o->tmp, &status)) {
        fits_clear_errmsg();
        snprintf(err, MP_ERRLEN, "%s: cannot create: %s", path, errno ? strerror(errno) : "cfitsio");
        out_free(o);
        return 1;
    }
    fits_create_img(o->fp, FLOAT_IMG, 2, naxes, &status);
    if (!status)
        mp_fits_write_cards(o->fp, cards, ncards, &status);
    if (status) {
        mp_fits_error(path, "write", status, err);
        return mp_image_out_close(o, 0, err) || 1;
    }
    *op = o;
    return 0;
}

int mp_image_out_put(mp_image_out *o, long x1, long y1, long w, long h, const double *pix,
                     char *err)
{
    if (x1 < 1 || y1 < 1 || w < 1 || h < 1 || x1 + w - 1 > o->nx || y1 + h - 1 > o->ny) {
        snprintf(err, MP_ERRLEN, "%s: rectangle [%ld:%ld,%ld:%ld] outside the image", o->path,
                 x1, x1 + w - 1, y1, y1 + h - 1);
        return 1;
    }
    int status = 0;
    long fp[2] = {x1, y1}, lp[2] = {x1 + w - 1, y1 + h - 1};
    fits_write_subset(o->fp, TDOUBLE, fp, lp, (void *)pix, &status);
    if (status) {
        mp_fits_error(o->path, "write", status, err);
        return 1;
    }
    return 0;
}

int mp_image_out_close(mp_image_out *o, int commit, char *err)
{
    if (!o)
        return 0;
    int status = 0, rc = 0;
    fits_close_file(o->fp, &status);
    if (commit && status) {
        mp_fits_error(o->path, "write", status, err);
        rc = 1;
    } else if (commit && mp_out_place(o->tmp, o->path, err) != 0) {
        rc = 1;
    }
    if (!commit || rc)
        unlink(o->tmp);
    out_free(o);
    return rc;
}
