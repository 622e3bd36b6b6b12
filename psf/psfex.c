/* psfex.c — PSFEx models: the classic .psf (PSF_DATA table, PSF_MASK cube,
 * POL* and PSF_SAMP in the header) and legacypipe's merged one-row table
 * (the same quantities as lowercase columns).  PSFEx's basis is
 * 1, x, x², y, x·y, y² with x = (X_IMAGE − POLZERO1)/POLSCAL1 (PSFEx
 * manual eq. 14; GalSim's DES_PSFEx reads it so), which is psf.h's order. */
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include "psf/psf_priv.h"

int psf_has_column(fitsfile *fp, const char *col)
{
    int status = 0, cn;
    fits_get_colnum(fp, CASEINSEN, (char *)col, &cn, &status);
    fits_clear_errmsg();
    return status == 0;
}

/* A number from the header, else from the one row's column of that name
 * (legacypipe).  0 found, 1 absent. */
static int num(fitsfile *fp, const char *key, double *v)
{
    int status = 0, cn;
    if (!mp_fits_key_number(fp, key, v, &status))
        return 0;
    status = 0;
    fits_clear_errmsg();
    fits_get_colnum(fp, CASEINSEN, (char *)key, &cn, &status);
    fits_read_col(fp, TDOUBLE, cn, 1, 1, 1, NULL, v, NULL, &status);
    fits_clear_errmsg();
    return status != 0;
}

typedef struct {
    double ax[3], polnaxis, polngrp, deg, zero[2], scal[2], samp;
} psfex_keys;

static int read_keys(fitsfile *fp, const char *name, psfex_keys *k, char *err)
{
    static const char *need[] = {"PSFAXIS1", "PSFAXIS2", "PSFAXIS3", "PSF_SAMP"};
    double *dst[] = {&k->ax[0], &k->ax[1], &k->ax[2], &k->samp};
    for (int i = 0; i < 4; i++)
        if (num(fp, need[i], dst[i])) {
            snprintf(err, MP_ERRLEN, "%s: PSFEx model without %s", name, need[i]);
            return 1;
        }
    k->polnaxis = 0;
    num(fp, "POLNAXIS", &k->polnaxis);
    k->polngrp = 1;
    k->deg = 0;
    k->zero[0] = k->zero[1] = 0;
    k->scal[0] = k->scal[1] = 1;
    if (k->polnaxis == 0)
        return 0;
    num(fp, "POLNGRP", &k->polngrp);
    if (k->polnaxis != 2 || k->polngrp != 1) {
        snprintf(err, MP_ERRLEN, "%s: PSFEx model with POLNAXIS %g, POLNGRP %g: only one "
                 "group of the two image coordinates is supported", name, k->polnaxis, k->polngrp);
        return 1;
    }
    static const char *pk[] = {"POLDEG1", "POLZERO1", "POLZERO2", "POLSCAL1", "POLSCAL2"};
    double *pd[] = {&k->deg, &k->zero[0], &k->zero[1], &k->scal[0], &k->scal[1]};
    for (int i = 0; i < 5; i++)
        if (num(fp, pk[i], pd[i]) || !isfinite(*pd[i])) {
            snprintf(err, MP_ERRLEN, "%s: PSFEx model without a valid %s", name, pk[i]);
            return 1;
        }
    return 0;
}

/* The keys make sense, and say what matphot can evaluate. */
static int check_keys(const char *name, const psfex_keys *k, char *err)
{
    if (!(k->deg >= 0 && k->deg <= MP_PSF_MAXORDER && k->deg == floor(k->deg))) {
        snprintf(err, MP_ERRLEN, "%s: PSFEx polynomial degree %g; matphot evaluates 0 to %d",
                 name, k->deg, MP_PSF_MAXORDER);
        return 1;
    }
    int deg = (int)k->deg;
    if (k->ax[2] != mp_psf_nterms(deg)) {
        snprintf(err, MP_ERRLEN, "%s: PSFAXIS3 %g does not match degree %d (%d terms)", name,
                 k->ax[2], deg, mp_psf_nterms(deg));
        return 1;
    }
    for (int i = 0; i < 2; i++)
        if (!(k->ax[i] >= 1 && k->ax[i] <= 4095 && k->ax[i] == floor(k->ax[i]))) {
            snprintf(err, MP_ERRLEN, "%s: PSFAXIS%d %g is not a size 1..4095", name, i + 1,
                     k->ax[i]);
            return 1;
        }
    if (!(k->samp >= 0.05 && k->samp <= 20) ||
        (deg > 0 && !mp_psf_field_origin_ok(k->zero[0], k->zero[1], k->scal[0], k->scal[1]))) {
        snprintf(err, MP_ERRLEN, "%s: PSF_SAMP %g, POLZERO %g, %g or POLSCAL %g, %g out of range "
                 "(|POLZERO| <= %g px, %g <= POLSCAL <= %g px)", name, k->samp, k->zero[0],
                 k->zero[1], k->scal[0], k->scal[1], MP_PSF_MAXPOS, MP_PSF_MINSCALE,
                 MP_PSF_MAXPOS);
        return 1;
    }
    return 0;
}

/* The PSF_MASK cube of the (only) row, term-major, x fastest. */
static double *read_mask(fitsfile *fp, const char *name, const psfex_keys *k, char *err)
{
    int status = 0, cn;
    long nrow = 0;
    fits_get_colnum(fp, CASEINSEN, "PSF_MASK", &cn, &status);
    fits_get_num_rows(fp, &nrow, &status);
    if (status || nrow != 1) {
        if (status)
            psf_fits_msg(name, "PSF_MASK", status, err);
        else
            snprintf(err, MP_ERRLEN, "%s: PSFEx table of %ld rows; choose one with a row filter, "
                     "e.g. \"%s[1][ccdname=='N2']\"", name, nrow, name);
        return NULL;
    }
    int typecode;
    long repeat, width;
    fits_get_coltype(fp, cn, &typecode, &repeat, &width, &status);
    long n = (long)(k->ax[0] * k->ax[1] * k->ax[2]);
    if (status || repeat != n) {
        snprintf(err, MP_ERRLEN, "%s: PSF_MASK holds %ld values, PSFAXIS1-3 say %ld", name,
                 repeat, n);
        return NULL;
    }
    double *m = malloc((size_t)n * sizeof *m);
    if (!m) {
        snprintf(err, MP_ERRLEN, "%s: out of memory for PSF_MASK", name);
        return NULL;
    }
    fits_read_col(fp, TDOUBLE, cn, 1, 1, n, NULL, m, NULL, &status);
    for (long i = 0; i < n && !status; i++)
        if (!isfinite(m[i]))
            status = NUM_OVERFLOW;
    if (status) {
        psf_fits_msg(name, "PSF_MASK", status, err);
        free(m);
        return NULL;
    }
    return m;
}

/* Round trip of plane 0 to OVERSAMP 1 and back: rms and largest
 * difference over its peak, what the resampling costs (both passes). */
static void resample_cost(const double *p, int nx, int ny, double s, const mp_psf_field *f,
                          double *rms, double *maxd)
{
    *rms = *maxd = NAN;
    double *back = calloc((size_t)nx * ny, sizeof *back);
    double *tmp = malloc((size_t)nx * (ny > f->ny ? ny : f->ny) * sizeof *tmp);
    if (back && tmp) {
        psf_resample(f->planes, f->nx, f->ny, 1.0, back, nx, ny, s, tmp);
        double peak = 0, ss = 0, mx = 0;
        for (long i = 0; i < (long)nx * ny; i++)
            peak = fabs(p[i]) > peak ? fabs(p[i]) : peak;
        /* Compare inside the part the resampled table covers. */
        int cx = nx / 2, cy = ny / 2;
        int hx = (int)floor(((f->nx - 1) / 2) / s) - 3, hy = (int)floor(((f->ny - 1) / 2) / s) - 3;
        hx = hx > cx ? cx : hx < 0 ? 0 : hx;
        hy = hy > cy ? cy : hy < 0 ? 0 : hy;
        long cnt = 0;
        for (int j = cy - hy; j <= cy + hy && j < ny; j++)
            for (int i = cx - hx; i <= cx + hx && i < nx; i++) {
                double d = fabs(back[(long)j * nx + i] - p[(long)j * nx + i]);
                ss += d * d;
                mx = d > mx ? d : mx;
                cnt++;
            }
        if (peak > 0 && cnt > 0) {
            *rms = sqrt(ss / cnt) / peak;
            *maxd = mx / peak;
        }
    }
    free(back);
    free(tmp);
}

/* The planes onto the detector grid (OVERSAMP 1): PSFEx's model is the
 * PSF as the image shows it (already pixel-convolved), sampled every
 * PSF_SAMP px, so its samples at whole-pixel steps are a ×1 table exactly;
 * a finer matphot table would be block-summed over the pixel a second
 * time by the renderer. */
static int to_grid(const char *name, const psfex_keys *k, const double *mask, mp_psf_field *f,
                   char *warn, char *err)
{
    int nx = (int)k->ax[0], ny = (int)k->ax[1], nt = (int)k->ax[2];
    double s = k->samp;
    int same = fabs(s - 1.0) < 1e-9 && nx % 2 && ny % 2;
    /* The target reaches as far as the source's centre-to-edge span. */
    int hx = same ? (nx - 1) / 2 : (int)floor(((nx - 1) / 2) * s + 1e-9);
    int hy = same ? (ny - 1) / 2 : (int)floor(((ny - 1) / 2) * s + 1e-9);
    if (mp_psf_field_new((int)k->deg, 2 * hx + 1, 2 * hy + 1, 1, k->zero[0], k->zero[1],
                         k->scal[0], k->scal[1], f, err))
        return 1;
    size_t plane = (size_t)f->nx * f->ny, splane = (size_t)nx * ny;
    if (same) {
        memcpy(f->planes, mask, plane * nt * sizeof *mask);
        return 0;
    }
    double *tmp = malloc((size_t)nx * f->ny * sizeof *tmp);
    if (!tmp) {
        snprintf(err, MP_ERRLEN, "%s: out of memory resampling the PSF", name);
        return 1;
    }
    for (int t = 0; t < nt; t++)
        psf_resample(mask + t * splane, nx, ny, s, f->planes + t * plane, f->nx, f->ny, 1.0, tmp);
    free(tmp);
    double rms, mx;
    resample_cost(mask, nx, ny, s, f, &rms, &mx);
    if (warn)
        snprintf(warn, MP_ERRLEN, "%s: PSFEx PSF_SAMP %.6g resampled to OVERSAMP 1 (Lanczos-3): "
                 "round-trip error rms %.2g, largest %.2g of the peak", name, s, rms, mx);
    return 0;
}

int psfex_read(fitsfile *fp, const char *name, mp_psf_field *f, char *warn, char *err)
{
    psfex_keys k;
    if (read_keys(fp, name, &k, err) || check_keys(name, &k, err))
        return 1;
    double *mask = read_mask(fp, name, &k, err);
    if (!mask)
        return 1;
    int rc = to_grid(name, &k, mask, f, warn, err);
    free(mask);
    if (rc)
        return 1;
    /* PSFEx normalises its model to unit flux in its vignette (SExtractor's
     * FLUX_PSF assumes so); the table at the origin is made to sum to 1. */
    size_t plane = (size_t)f->nx * f->ny;
    double sum = 0.0;
    for (size_t i = 0; i < plane; i++)
        sum += f->planes[i];
    if (!(sum > 0)) {
        snprintf(err, MP_ERRLEN, "%s: PSFEx model sums to %g at its origin", name, sum);
        return 1;
    }
    for (size_t i = 0; i < plane * f->nterms; i++)
        f->planes[i] /= sum;
    f->sum = 1.0;
    return 0;
}
