/* kernel.c — a detector-level kernel (charge diffusion: light of a pixel
 * shared with its neighbours after the PSF is block-summed to pixels), read
 * from a FITS table or from Tiny Tim's header COMMENT cards, and folded
 * into a supersampled table.
 *
 * Why folding is exact: the renderer makes P = B(W · S_δ(T)) — T shifted
 * by the damped sinc S_δ, weighted by the DRF's subpixel QE W (periodic
 * with the pixel, period os elements), block-summed by B.  Let K↑ be the
 * kernel K placed on the fine grid at whole-pixel steps (os elements).
 * S_δ and the five-point derivative are convolutions on the fine grid, so
 * they commute with K↑; W is periodic with period os, so
 * W·(X ∗ K↑) = (W·X) ∗ K↑; and B(X ∗ K↑) = B(X) ∗ K on detector pixels.
 * Hence B(W · S_δ(T ∗ K↑)) = P ∗ K: the kernel applied after the block-sum,
 * for every shift and DRF, once the table is padded by os·r elements a
 * side (r the kernel's half-size) so that T ∗ K↑ is whole — up to what the
 * shift sends beyond the table's edge, which the renderer drops either way
 * (tests/unit/test_psf_readers.c: equal to 4e-16 of the peak).  The same holds
 * for every plane of a variable PSF (the fold is linear), and block-summing
 * by a factor f dividing os commutes with it too. */
#include <ctype.h>
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include "psf/psf.h"

/* Numbers of one COMMENT card's text; how many (up to max). */
static int card_numbers(const char *txt, size_t len, double *v, int max)
{
    char buf[81];
    size_t n = len < 80 ? len : 80;
    memcpy(buf, txt, n);
    buf[n] = '\0';
    int k = 0;
    char *p = buf, *end;
    while (k < max) {
        while (*p && isspace((unsigned char)*p))
            p++;
        if (!*p)
            break;
        double x = strtod(p, &end);
        if (end == p)
            return -1;          /* not a row of numbers */
        v[k++] = x;
        p = end;
    }
    return k;
}

/* The card after Tiny Tim's "…convolve it with the following kernel :"
 * (its kernel, one COMMENT card a row), or -1 when the header has none. */
static int header_kernel_start(const mp_image *im)
{
    for (int c = 0; c < im->nkeys; c++) {
        const char *card = im->hdr + (size_t)c * 80;
        char buf[81];
        memcpy(buf, card, 80);
        buf[80] = '\0';
        if (!strncmp(buf, "COMMENT", 7) && strstr(buf, "following kernel"))
            return c + 1;
    }
    return -1;
}

/* Tiny Tim's kernel from the COMMENT cards from start on. */
static int kernel_from_header(const mp_image *im, int start, const char *name, mp_psf *k,
                              char *err)
{
    double v[9][9];
    int rows = 0, cols = 0;
    for (int c = start; c < im->nkeys && rows < 9; c++) {
        const char *card = im->hdr + (size_t)c * 80;
        if (strncmp(card, "COMMENT", 7))
            break;
        int n = card_numbers(card + 8, 72, v[rows], 9);
        if (n <= 0)
            break;
        if (rows && n != cols)
            break;
        cols = n;
        rows++;
    }
    if (rows == 0 || rows != cols || rows % 2 == 0) {
        snprintf(err, MP_ERRLEN, "%s: psfkernel=header: the kernel in the COMMENT cards is "
                 "%dx%d, not square of odd size", name, cols, rows);
        return 1;
    }
    k->t = malloc((size_t)rows * rows * sizeof *k->t);
    if (!k->t) {
        snprintf(err, MP_ERRLEN, "%s: out of memory", name);
        return 1;
    }
    for (int j = 0; j < rows; j++)
        for (int i = 0; i < rows; i++)
            k->t[j * rows + i] = v[j][i];
    k->nx = k->ny = rows;
    return 0;
}

/* A kernel read (k->t, nx, ny) checked finite with a positive sum and
 * made an OVERSAMP-1 table; freed with 1 and err when not. */
static int kernel_checked(const char *name, mp_psf *k, char *err)
{
    double s = 0.0;
    int rc = 0;
    for (int i = 0; !rc && i < k->nx * k->ny; i++) {
        if (!isfinite(k->t[i])) {
            snprintf(err, MP_ERRLEN, "%s: detector kernel holds NaN or infinite values", name);
            rc = 1;
        }
        s += k->t[i];
    }
    if (!rc && !(s > 0)) {
        snprintf(err, MP_ERRLEN, "%s: detector kernel sums to %g", name, s);
        rc = 1;
    }
    if (rc) {
        mp_psf_free(k);
        return 1;
    }
    k->kind = MP_PSF_TABLE;
    k->os = 1;
    k->sum = s;
    return 0;
}

/* Tiny Tim's kernel from psfname's header (psfkernel=header; auto: none,
 * k->t NULL, when the header has no kernel or the file does not open as an
 * image — a PSFEx table, whose PSF was read before). */
static int kernel_header(const char *psfname, int need, mp_psf *k, char *err)
{
    if (!psfname || !psfname[0]) {
        if (need)
            snprintf(err, MP_ERRLEN, "psfkernel: header: there is no PSF file to read it from");
        return need;
    }
    mp_image im = {0};
    char e2[MP_ERRLEN];
    if (mp_image_header_read(psfname, &im, need ? err : e2))
        return need;
    int start = header_kernel_start(&im), rc = 0;
    if (start >= 0) {
        rc = kernel_from_header(&im, start, psfname, k, err);
    } else if (need) {
        snprintf(err, MP_ERRLEN, "%s: psfkernel=header: no kernel in the header's COMMENT "
                 "cards (Tiny Tim's \"convolve it with the following kernel\")", psfname);
        rc = 1;
    }
    mp_image_free(&im);
    return rc;
}

/* A kernel given as a FITS image (odd sizes ≤ 99). */
static int kernel_file(const char *name, mp_psf *k, char *err)
{
    mp_image im = {0};
    if (mp_image_read(name, &im, err))
        return 1;
    int rc = 0;
    if (im.nx % 2 == 0 || im.ny % 2 == 0 || im.nx > 99 || im.ny > 99) {
        snprintf(err, MP_ERRLEN, "%s: detector kernel is %ldx%ld; its sizes must be odd, at "
                 "most 99", name, im.nx, im.ny);
        rc = 1;
    } else {
        k->t = im.pix;
        im.pix = NULL;
        k->nx = (int)im.nx;
        k->ny = (int)im.ny;
    }
    mp_image_free(&im);
    return rc;
}

mp_kernel_spec mp_psf_kernel_spec(const char *spec)
{
    return !spec || !spec[0] || !strcmp(spec, "none") ? MP_KERNEL_NONE
           : !strcmp(spec, "auto")                    ? MP_KERNEL_AUTO
           : !strcmp(spec, "header")                  ? MP_KERNEL_HEADER
                                                      : MP_KERNEL_FILE;
}

int mp_psf_kernel_read(const char *spec, const char *psfname, mp_psf *k, char *err)
{
    memset(k, 0, sizeof *k);
    mp_kernel_spec ks = mp_psf_kernel_spec(spec);
    if (ks == MP_KERNEL_NONE)
        return 0;
    int rc = ks == MP_KERNEL_FILE ? kernel_file(spec, k, err)
                                  : kernel_header(psfname, ks == MP_KERNEL_HEADER, k, err);
    if (rc)
        mp_psf_free(k);
    if (rc || !k->t)
        return rc;
    return kernel_checked(ks == MP_KERNEL_FILE ? spec : psfname, k, err);
}

/* out (nx + 2·os·rx) × (ny + 2·os·ry) = in ∗ K↑. */
static void fold_plane(const double *in, int nx, int ny, int os, const mp_psf *k, double *out)
{
    int rx = k->nx / 2, ry = k->ny / 2, mx = nx + 2 * os * rx, my = ny + 2 * os * ry;
    memset(out, 0, (size_t)mx * my * sizeof *out);
    for (int q = 0; q < k->ny; q++)
        for (int p = 0; p < k->nx; p++) {
            double w = k->t[q * k->nx + p];
            if (w == 0.0)
                continue;
            /* In element (i, j) lands at (i + os·p, j + os·q) of out. */
            for (int j = 0; j < ny; j++) {
                const double *src = in + (size_t)j * nx;
                double *dst = out + (size_t)(j + os * q) * mx + os * p;
                for (int i = 0; i < nx; i++)
                    dst[i] += w * src[i];
            }
        }
}

int mp_psf_field_fold_kernel(mp_psf_field *f, const mp_psf *k, char *err)
{
    int rx = k->nx / 2, ry = k->ny / 2;
    int mx = f->nx + 2 * f->os * rx, my = f->ny + 2 * f->os * ry;
    size_t in_plane = (size_t)f->nx * f->ny, out_plane = (size_t)mx * my;
    double *pl = malloc(out_plane * f->nterms * sizeof *pl);
    if (!pl) {
        snprintf(err, MP_ERRLEN, "detector kernel: out of memory");
        return 1;
    }
    for (int t = 0; t < f->nterms; t++)
        fold_plane(f->planes + t * in_plane, f->nx, f->ny, f->os, k, pl + t * out_plane);
    free(f->planes);
    f->planes = pl;
    f->nx = mx;
    f->ny = my;
    f->sum *= k->sum;
    return 0;
}

int mp_psf_table_fold_kernel(double **t, int *nx, int *ny, int os, const mp_psf *k, char *err)
{
    int mx = *nx + 2 * os * (k->nx / 2), my = *ny + 2 * os * (k->ny / 2);
    double *out = malloc((size_t)mx * my * sizeof *out);
    if (!out) {
        snprintf(err, MP_ERRLEN, "detector kernel: out of memory");
        return 1;
    }
    fold_plane(*t, *nx, *ny, os, k, out);
    free(*t);
    *t = out;
    *nx = mx;
    *ny = my;
    return 0;
}
