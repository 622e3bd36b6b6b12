/* table.c — PSF tables: read from FITS, made from a Gaussian, block-summed. */
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include "psf/psf.h"

void mp_psf_free(mp_psf *p)
{
    if (!p)
        return;
    free(p->t);
    memset(p, 0, sizeof *p);
}

static double table_sum(const double *t, size_t n)
{
    double s = 0.0;
    for (size_t i = 0; i < n; i++)
        s += t[i];
    return s;
}

int mp_psf_read(const char *name, int normalize, int oversamp, mp_psf *p, char *warn,
                char *err)
{
    memset(p, 0, sizeof *p);
    if (warn)
        warn[0] = '\0';
    mp_image im = {0};
    if (mp_image_read(name, &im, err))
        return 1;
    int rc = 1;
    double os = oversamp > 0 ? oversamp : 1.0;
    int hk = mp_header_double(&im, "OVERSAMP", &os);
    if (hk == 2 || (hk == 0 && (os != floor(os) || os < 1 || os > 8))) {
        snprintf(err, MP_ERRLEN, "%s: OVERSAMP must be an integer 1..8", name);
        goto done;
    }
    if (im.nx % 2 == 0 || im.ny % 2 == 0) {
        snprintf(err, MP_ERRLEN, "%s: PSF table is %ldx%ld; its sizes must be odd "
                 "(star at the centre of the central element)", name, im.nx, im.ny);
        goto done;
    }
    size_t n = (size_t)im.nx * (size_t)im.ny;
    size_t nneg = 0;
    double peak = 0.0;
    for (size_t i = 0; i < n; i++) {
        if (!isfinite(im.pix[i])) {
            snprintf(err, MP_ERRLEN, "%s: PSF table holds NaN or infinite values", name);
            goto done;
        }
        if (im.pix[i] < 0)
            nneg++;
        if (im.pix[i] > peak)
            peak = im.pix[i];
    }
    double sum = table_sum(im.pix, n);
    if (!(peak > 0) || !(sum > 0)) {
        snprintf(err, MP_ERRLEN, "%s: PSF table is zero or negative everywhere", name);
        goto done;
    }
    if (!normalize && sum > 1.01) {
        snprintf(err, MP_ERRLEN, "%s: PSF table sums to %.6g > 1.01; it must hold "
                 "the fraction of the star's light (use psfnorm=yes to rescale)", name, sum);
        goto done;
    }
    if (nneg && warn)
        snprintf(warn, MP_ERRLEN, "%s: %zu negative PSF elements", name, nneg);
    p->kind = MP_PSF_TABLE;
    p->nx = (int)im.nx;
    p->ny = (int)im.ny;
    p->os = (int)os;
    p->t = im.pix;
    im.pix = NULL;
    if (normalize) {
        for (size_t i = 0; i < n; i++)
            p->t[i] /= sum;
        sum = 1.0;
    }
    p->sum = sum;
    rc = 0;
done:
    mp_image_free(&im);
    return rc;
}

/* ∫ of a unit Gaussian over [u − h, u + h] (sigma units), accurate in the
 * tails (erfc of the far side). */
static double gauss_cell(double u, double h)
{
    double a = (u - h) / M_SQRT2, b = (u + h) / M_SQRT2;
    if (a > 0)
        return 0.5 * (erfc(a) - erfc(b));
    if (b < 0)
        return 0.5 * (erfc(-b) - erfc(-a));
    return 0.5 * (2.0 - erfc(b) - erfc(-a));
}

int mp_psf_gauss_table(double fwhm, int os, double radius, mp_psf *p, char *err)
{
    memset(p, 0, sizeof *p);
    if (!(fwhm > 0) || os < 1 || os > 8 || !(radius > 0)) {
        snprintf(err, MP_ERRLEN, "gaussian table: bad fwhm %g, oversamp %d or radius %g",
                 fwhm, os, radius);
        return 1;
    }
    double sigma = fwhm / (2.0 * sqrt(2.0 * log(2.0)));
    int nh = (int)ceil(radius * os);
    int n = 2 * nh + 1;
    double *g = malloc((size_t)n * sizeof *g);
    p->t = malloc((size_t)n * (size_t)n * sizeof *p->t);
    if (!g || !p->t) {
        free(g);
        mp_psf_free(p);
        snprintf(err, MP_ERRLEN, "gaussian table: out of memory");
        return 1;
    }
    /* Element i's centre sits (i − nh)/os px from the star; it spans 1/os px. */
    for (int i = 0; i < n; i++)
        g[i] = gauss_cell((double)(i - nh) / os / sigma, 0.5 / os / sigma);
    for (int j = 0; j < n; j++)
        for (int i = 0; i < n; i++)
            p->t[(size_t)j * n + i] = g[i] * g[j];
    free(g);
    p->kind = MP_PSF_TABLE;
    p->nx = p->ny = n;
    p->os = os;
    p->sigma = sigma;
    p->sum = table_sum(p->t, (size_t)n * n);
    return 0;
}

void mp_psf_gauss(double fwhm, mp_psf *p)
{
    memset(p, 0, sizeof *p);
    p->kind = MP_PSF_GAUSS;
    p->os = 1;
    p->sigma = fwhm / (2.0 * sqrt(2.0 * log(2.0)));
    p->sum = 1.0;
}

int mp_psf_rebin(const mp_psf *in, int factor, mp_psf *out, char *err)
{
    memset(out, 0, sizeof *out);
    if (in->kind != MP_PSF_TABLE || factor < 1 || in->os % factor) {
        snprintf(err, MP_ERRLEN, "psf rebin: factor %d does not divide OVERSAMP %d",
                 factor, in->os);
        return 1;
    }
    /* Output element J holds input elements start + f·J … start + f·J + f − 1,
     * chosen so the central output block is centred on the input centre (odd
     * f) or half an input element below it (even f). */
    int f = factor;
    int cxi = (in->nx - 1) / 2, cyi = (in->ny - 1) / 2;
    int hx = (cxi + f) / f, hy = (cyi + f) / f;
    int nx = 2 * hx + 1, ny = 2 * hy + 1;
    int sx = cxi - f / 2 - f * hx, sy = cyi - f / 2 - f * hy;
    out->t = calloc((size_t)nx * (size_t)ny, sizeof *out->t);
    if (!out->t) {
        snprintf(err, MP_ERRLEN, "psf rebin: out of memory");
        return 1;
    }
    for (int j = 0; j < in->ny; j++) {
        int J = (j - sy) / f;   /* j − sy ≥ 0 by construction */
        for (int i = 0; i < in->nx; i++) {
            int I = (i - sx) / f;
            out->t[(size_t)J * nx + I] += in->t[(size_t)j * in->nx + i];
        }
    }
    out->kind = MP_PSF_TABLE;
    out->nx = nx;
    out->ny = ny;
    out->os = in->os / f;
    out->sum = in->sum;
    out->sigma = in->sigma;
    out->offset = in->offset + ((f % 2) ? 0.0 : 0.5 / in->os);
    out->field = in->field;
    return 0;
}
