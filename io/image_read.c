/* image_read.c — mp_image_read and mp_image_free (io.h). */
#include "io/io.h"

#include <limits.h>
#include <math.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <fitsio.h>

#include "io/fitserr.h"
#include "io/section.h"

/* Keep a malloc'd copy of the HDU's header so callers free one way only. */
static int copy_header(fitsfile *fp, char **hdr, int *nkeys_out, int *status)
{
    char *h = NULL;
    int nkeys = 0;
    if (fits_hdr2str(fp, 0, NULL, 0, &h, &nkeys, status))
        return *status;
    size_t n = (size_t)nkeys * 80;
    *hdr = malloc(n + 1);
    if (!*hdr) {
        fits_free_memory(h, status);
        return *status = MEMORY_ALLOCATION;
    }
    memcpy(*hdr, h, n);
    (*hdr)[n] = '\0';
    *nkeys_out = nkeys;
    fits_free_memory(h, status);
    return *status;
}

/* What both readers fill: the pixels in the type asked for (TDOUBLE or
 * TFLOAT), the size and the header. */
typedef struct {
    long nx, ny;
    void *pix;
    char *hdr;
    int nkeys;
} raw_image;

static void raw_free(raw_image *im)
{
    free(im->pix);
    free(im->hdr);
    memset(im, 0, sizeof *im);
}

/* Open the image HDU NAME names (section syntax allowed), after the
 * header guard; on failure *fp is closed and ERR says why. */
static int open_image(const char *name, fitsfile **fp, char *err)
{
    *fp = NULL;
    char *cname = mp_section_name(name);
    if (!cname) {
        snprintf(err, MP_ERRLEN, "%s: out of memory", name);
        return 1;
    }
    int status = 0;
    if (mp_fits_guard_named(cname, name, err)) {
        free(cname);
        return 1;
    }
    fits_open_image(fp, cname, READONLY, &status);
    free(cname);
    if (status) {
        mp_fits_error(name, "open", status, err);
        /* cfitsio 4.2 can fail inside the header parse with the file
         * already open and fp set (a card without "= "): close it, or the
         * descriptor and its buffers leak (found by tests/fuzz). */
        if (*fp) {
            int s2 = 0;
            fits_close_file(*fp, &s2);
            *fp = NULL;
        }
        return 1;
    }
    return 0;
}

/* The "give a 2-D plane" message for a cube: the plane syntax goes after
 * the HDU part of the name ("f.fits[SCI][*,*,1]"), dropping a section
 * already there. */
static void plane_hint(const char *name, int naxis, char *err)
{
    const char *b = strrchr(name, '[');
    int blen = b && strchr(b, ',') ? (int)(b - name) : (int)strlen(name);
    char extra[40] = "";
    for (int j = 3; j < naxis; j++)
        strcat(extra, ",1");
    snprintf(err, MP_ERRLEN, "%s: %d-D image; give a 2-D section like %.*s[*,*,1%s]",
             name, naxis, blen, name, extra);
}

/* BITPIX, NAXIS and NAXISn of the open HDU, checked to be a 2-D image
 * (trailing axes of length 1 allowed) of a size that can be held. */
static int image_shape(fitsfile *fp, const char *name, int *bitpix, int *naxis, long naxes[9],
                       char *err)
{
    int status = 0;
    fits_get_img_type(fp, bitpix, &status);
    fits_get_img_dim(fp, naxis, &status);
    if (status)
        return mp_fits_error(name, "read", status, err), 1;
    int bp = *bitpix, na = *naxis;
    if (bp != 8 && bp != 16 && bp != 32 && bp != 64 && bp != -32 && bp != -64) {
        snprintf(err, MP_ERRLEN, "%s: unsupported BITPIX %d", name, bp);
        return 1;
    }
    if (na == 0 && !strchr(name, '[')) {
        /* opened as an image, the file's first image HDU: there is none */
        snprintf(err, MP_ERRLEN, "%s: holds no image (its primary HDU is empty and none of its "
                 "extensions is an image)", name);
        return 1;
    }
    if (na == 0) {
        snprintf(err, MP_ERRLEN, "%s: no image here (NAXIS = 0); name an image extension",
                 name);
        return 1;
    }
    if (na > 9) {
        snprintf(err, MP_ERRLEN, "%s: %d-D image; matphot reads 2-D images", name, na);
        return 1;
    }
    fits_get_img_size(fp, na, naxes, &status);
    if (status)
        return mp_fits_error(name, "read", status, err), 1;
    for (int k = 2; k < na; k++)
        if (naxes[k] != 1)
            return plane_hint(name, na, err), 1;
    long nx = naxes[0], ny = na > 1 ? naxes[1] : 1;
    if (nx < 1 || ny < 1) {
        snprintf(err, MP_ERRLEN, "%s: empty image (%ld x %ld)", name, nx, ny);
        return 1;
    }
    if ((uint64_t)nx > SIZE_MAX / sizeof(double) / (uint64_t)ny) {
        snprintf(err, MP_ERRLEN, "%s: image too large (%ld x %ld)", name, nx, ny);
        return 1;
    }
    return 0;
}

/* The bytes of the HDU's pixels as its header sizes them (a
 * tile-compressed image, whose data are a table's, is refused before:
 * mp_fits_refuse_tiled). */
static LONGLONG data_bytes(int bitpix, int naxis, const long naxes[9])
{
    LONGLONG nbytes = (LONGLONG)(bitpix < 0 ? -bitpix : bitpix) / 8;
    for (int k = 0; k < naxis; k++)
        nbytes *= naxes[k];
    return nbytes;
}

/* cfitsio's tile decoders do not hold a corrupt tile to its bytes: its
 * RICE_1 decoder reads on past one while it meets zero bytes (a crash in
 * fits_rdecomp_short), its GZIP path grows its buffer for as long as a
 * corrupt tile's stream says (20 s and more) and leaks it on zlib's
 * error; HCOMPRESS_1 and PLIO_1 are hand-written decoders of the same
 * kind (the frame fuzzer, 2026-12-07).  Bad input must end in an error,
 * so no tile-compressed image is expanded (io.h). */
int mp_fits_refuse_tiled(void *vfp, const char *name, char *err)
{
    fitsfile *fp = vfp;
    int status = 0;
    if (!fits_is_compressed_image(fp, &status))
        return 0;
    char cmp[FLEN_VALUE] = "";
    fits_read_key_str(fp, "ZCMPTYPE", cmp, NULL, &status);
    fits_clear_errmsg();
    snprintf(err, MP_ERRLEN, "%s: tile-compressed (%s), which matphot does not expand "
             "(cfitsio's decoders can read past a corrupt tile): funpack it first", name,
             status ? "no ZCMPTYPE" : cmp);
    return 1;
}

/* A file cut short inside its data: say so before reading, since cfitsio
 * would otherwise convert bytes past the end of the file. */
static int check_complete(fitsfile *fp, const char *name, int bitpix, int naxis,
                          const long naxes[9], char *err)
{
    if (mp_fits_refuse_tiled(fp, name, err))
        return 1;
    int status = 0;
    LONGLONG hstart, dstart, dend;
    fits_get_hduaddrll(fp, &hstart, &dstart, &dend, &status);
    LONGLONG nbytes = data_bytes(bitpix, naxis, naxes);
    if (!status && dstart + nbytes > fp->Fptr->logfilesize) {
        snprintf(err, MP_ERRLEN, "%s: truncated FITS file (the data end before the header says)",
                 name);
        return 1;
    }
    return 0;
}

/* The pixels, in DATATYPE, and a copy of the header. BLANK pixels of
 * integer images and NaN of float images both come back as NaN, so
 * callers test one thing. */
static int read_pixels(fitsfile *fp, const char *name, int datatype, raw_image *im, char *err)
{
    size_t esize = datatype == TFLOAT ? sizeof(float) : sizeof(double);
    im->pix = malloc((size_t)im->nx * (size_t)im->ny * esize);
    if (!im->pix) {
        snprintf(err, MP_ERRLEN, "%s: out of memory for %ld x %ld pixels", name, im->nx, im->ny);
        return 1;
    }
    long fpix[9] = {1, 1, 1, 1, 1, 1, 1, 1, 1};
    double nulval = NAN;
    float fnulval = NAN;
    int anynul = 0, status = 0;
    fits_read_pix(fp, datatype, fpix, (LONGLONG)im->nx * im->ny,
                  datatype == TFLOAT ? (void *)&fnulval : (void *)&nulval, im->pix, &anynul,
                  &status);
    if (status)
        return mp_fits_error(name, "read", status, err), 1;
    if (copy_header(fp, &im->hdr, &im->nkeys, &status))
        return mp_fits_error(name, "read the header of", status, err), 1;
    return 0;
}

static int read_raw(const char *name, int datatype, raw_image *im, char *err)
{
    memset(im, 0, sizeof *im);
    if (!name || !*name) {
        snprintf(err, MP_ERRLEN, "(no name): no image file given");
        return 1;
    }
    fitsfile *fp;
    if (open_image(name, &fp, err))
        return 1;
    int bitpix = 0, naxis = 0, status = 0;
    long naxes[9] = {0};
    if (image_shape(fp, name, &bitpix, &naxis, naxes, err) ||
        check_complete(fp, name, bitpix, naxis, naxes, err))
        goto fail;
    im->nx = naxes[0];
    im->ny = naxis > 1 ? naxes[1] : 1;
    if (read_pixels(fp, name, datatype, im, err))
        goto fail;
    fits_close_file(fp, &status);
    if (status) {
        mp_fits_error(name, "close", status, err);
        raw_free(im);
        return 1;
    }
    return 0;

fail:
    status = 0;
    fits_close_file(fp, &status);
    fits_clear_errmsg();
    raw_free(im);
    return 1;
}

int mp_image_read(const char *name, mp_image *im, char *err)
{
    raw_image r;
    int rc = read_raw(name, TDOUBLE, &r, err);
    *im = (mp_image){r.nx, r.ny, r.pix, r.hdr, r.nkeys};
    return rc;
}

int mp_fimage_read(const char *name, mp_fimage *im, char *err)
{
    raw_image r;
    int rc = read_raw(name, TFLOAT, &r, err);
    *im = (mp_fimage){r.nx, r.ny, r.pix, r.hdr, r.nkeys};
    return rc;
}

void mp_fimage_free(mp_fimage *im)
{
    if (!im)
        return;
    free(im->pix);
    free(im->hdr);
    memset(im, 0, sizeof *im);
}

mp_image mp_fimage_header(const mp_fimage *im)
{
    return (mp_image){im->nx, im->ny, NULL, im->hdr, im->nkeys};
}

void mp_image_free(mp_image *im)
{
    if (!im)
        return;
    free(im->pix);
    free(im->hdr);
    im->pix = NULL;
    im->hdr = NULL;
    im->nx = im->ny = 0;
    im->nkeys = 0;
}

int mp_image_header_read(const char *name, mp_image *im, char *err)
{
    memset(im, 0, sizeof *im);
    fitsfile *fp;
    if (!name || !*name) {
        snprintf(err, MP_ERRLEN, "(no name): no image file given");
        return 1;
    }
    if (open_image(name, &fp, err))
        return 1;
    int status = 0;
    if (copy_header(fp, &im->hdr, &im->nkeys, &status))
        mp_fits_error(name, "read the header of", status, err);
    int s2 = 0;
    fits_close_file(fp, &s2);
    fits_clear_errmsg();
    if (status) {
        mp_image_free(im);
        return 1;
    }
    return 0;
}
