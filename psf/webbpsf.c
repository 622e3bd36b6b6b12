/* webbpsf.c — WebbPSF/STPSF files (the OVERSAMP HDU: the optical PSF on a
 * grid OVERSAMP times finer than the detector, which WebbPSF itself
 * block-sums into DET_SAMP, exactly what matphot's renderer does), and
 * gridded PSFs: WebbPSF's GriddedPSFModel cube (DET_YXn) and Anderson's
 * STDPSF cube (NXPSFS/NYPSFS, IPSFXnn/JPSFYnn). */
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include "psf/psf_priv.h"

/* The image HDU's planes (nx × ny × nz doubles, malloc'ed). */
static double *read_cube(fitsfile *fp, const char *name, long nx, long ny, long nz, char *err)
{
    if (nx < 1 || ny < 1 || nz < 1 || nx > 4096 || ny > 4096 || nz > MP_PSF_MAXTERMS ||
        nx * ny * nz > (1L << 25)) {
        snprintf(err, MP_ERRLEN, "%s: PSF data of %ldx%ldx%ld elements is out of range", name,
                 nx, ny, nz);
        return NULL;
    }
    double *v = malloc((size_t)(nx * ny * nz) * sizeof *v);
    if (!v) {
        snprintf(err, MP_ERRLEN, "%s: out of memory", name);
        return NULL;
    }
    int st = 0;
    long f1[3] = {1, 1, 1};
    fits_read_pix(fp, TDOUBLE, f1, nx * ny * nz, NULL, v, NULL, &st);
    for (long i = 0; !st && i < nx * ny * nz; i++)
        if (!isfinite(v[i]))
            st = NUM_OVERFLOW;
    if (st) {
        psf_fits_msg(name, "cannot read the PSF data", st, err);
        free(v);
        return NULL;
    }
    return v;
}

/* A table whose star sits at its geometric centre, (n−1)/2 on both axes:
 * an even size is padded by one zero element at the low end, which puts
 * the star half an element above the central element (offset 0.5/os,
 * as mp_psf_rebin records it).  Both axes even or both odd. */
static int pad_sizes(const char *name, long nx, long ny, int *mx, int *my, int *pad, char *err)
{
    if (nx < 1 || ny < 1 || nx > 4096 || ny > 4096) {
        snprintf(err, MP_ERRLEN, "%s: PSF of %ldx%ld elements; sizes must be 1..4096", name, nx,
                 ny);
        return 1;
    }
    if (nx % 2 != ny % 2) {
        snprintf(err, MP_ERRLEN, "%s: PSF of %ldx%ld elements: one size odd, one even, so the "
                 "star is not on one element's centre or corner", name, nx, ny);
        return 1;
    }
    *pad = nx % 2 == 0;
    *mx = (int)nx + *pad;
    *my = (int)ny + *pad;
    return 0;
}

static void copy_padded(const double *src, long nx, long ny, int pad, double *dst, int mx)
{
    for (long j = 0; j < ny; j++)
        memcpy(dst + (size_t)(j + pad) * mx + pad, src + (size_t)j * nx, (size_t)nx * sizeof *src);
}

static int oversamp_of(fitsfile *fp, const char *name, int *os, char *err)
{
    int st = 0;
    double v = 1.0;
    mp_fits_key_number(fp, "OVERSAMP", &v, &st);
    fits_clear_errmsg();
    if (st || v != floor(v) || v < 1 || v > 8) {
        snprintf(err, MP_ERRLEN, "%s: OVERSAMP %s; it must be an integer 1..8", name,
                 st ? "missing" : "out of range");
        return 1;
    }
    *os = (int)v;
    return 0;
}

int webbpsf_read(fitsfile *fp, const char *name, long nx, long ny, mp_psf_field *f, char *warn,
                 char *err)
{
    int os, mx, my, pad;
    if (oversamp_of(fp, name, &os, err) || pad_sizes(name, nx, ny, &mx, &my, &pad, err))
        return 1;
    double *v = read_cube(fp, name, nx, ny, 1, err);
    if (!v)
        return 1;
    int rc = mp_psf_field_new(0, mx, my, os, 0, 0, 1, 1, f, err);
    if (!rc) {
        copy_padded(v, nx, ny, pad, f->planes, mx);
        f->offset = pad ? 0.5 / os : 0.0;
        double s = 0.0;
        for (long i = 0; i < (long)mx * my; i++)
            s += f->planes[i];
        f->sum = s;
        if (pad && warn)
            snprintf(warn, MP_ERRLEN, "%s: WebbPSF table %ldx%ld (even): padded to %dx%d, the "
                     "star half an element (%.4g px) above the central element", name, nx, ny,
                     mx, my, 0.5 / os);
    }
    free(v);
    return rc;
}

/* ---- Grids ------------------------------------------------------------------- */

/* "(y, x)" of DET_YXk, 0-based detector pixels. */
static int det_yx(fitsfile *fp, int k, double *x, double *y)
{
    char key[16], val[FLEN_VALUE];
    int st = 0;
    snprintf(key, sizeof key, "DET_YX%d", k);
    fits_read_key(fp, TSTRING, key, val, NULL, &st);
    fits_clear_errmsg();
    return st || sscanf(val, " ( %lf , %lf )", y, x) != 2;
}

/* The sorted distinct values of v[0..n−1] into g; how many. */
static int distinct(const double *v, int n, double *g, int max)
{
    int m = 0;
    for (int i = 0; i < n; i++) {
        int seen = 0;
        for (int k = 0; k < m; k++)
            seen |= g[k] == v[i];
        if (seen)
            continue;
        if (m == max)
            return -1;
        int k = m++;
        while (k > 0 && g[k - 1] > v[i]) {
            g[k] = g[k - 1];
            k--;
        }
        g[k] = v[i];
    }
    return m;
}

static int index_of(const double *g, int n, double v)
{
    for (int k = 0; k < n; k++)
        if (g[k] == v)
            return k;
    return -1;
}

/* Where each of the nz tables sits: WebbPSF (DET_YXk, 0-based, so +1) or
 * STDPSF (IPSFXnn/JPSFYnn, table k = j·NXPSFS + i, taken as 1-based). */
static int grid_positions(fitsfile *fp, const char *name, int stdpsf, long nz, double *px,
                          double *py, char *err)
{
    if (!stdpsf) {
        for (int k = 0; k < nz; k++)
            if (det_yx(fp, k, &px[k], &py[k])) {
                snprintf(err, MP_ERRLEN, "%s: DET_YX%d missing or not \"(y, x)\" for one of "
                         "%ld PSFs", name, k, nz);
                return 1;
            } else {
                px[k] += 1.0, py[k] += 1.0;
            }
        return 0;
    }
    int st = 0;
    double gnx = 0.0, gny = 0.0;
    mp_fits_key_number(fp, "NXPSFS", &gnx, &st);
    mp_fits_key_number(fp, "NYPSFS", &gny, &st);
    if (st || !(gnx >= 1 && gnx <= MP_PSF_MAXGRID && gnx == floor(gnx)) ||
        !(gny >= 1 && gny <= MP_PSF_MAXGRID && gny == floor(gny)) || gnx * gny != (double)nz) {
        fits_clear_errmsg();
        snprintf(err, MP_ERRLEN, "%s: NXPSFS x NYPSFS (%g x %g) does not match the %ld PSFs",
                 name, gnx, gny, nz);
        return 1;
    }
    int nxp = (int)gnx, nyp = (int)gny;
    double gx[MP_PSF_MAXGRID], gy[MP_PSF_MAXGRID];
    for (int i = 0; i < nxp + nyp && !st; i++) {
        char key[16];
        snprintf(key, sizeof key, i < nxp ? "IPSFX%02d" : "JPSFY%02d", i < nxp ? i + 1 : i - nxp + 1);
        mp_fits_key_number(fp, key, i < nxp ? &gx[i] : &gy[i - nxp], &st);
    }
    if (st) {
        fits_clear_errmsg();
        snprintf(err, MP_ERRLEN, "%s: STDPSF grid keywords IPSFXnn/JPSFYnn missing", name);
        return 1;
    }
    for (int k = 0; k < nz; k++)
        px[k] = gx[k % nxp], py[k] = gy[k / nxp];
    return 0;
}

/* An STDPSF's sampling (OVERSAMP, default 4) as *step, and the ×1 table's
 * sizes mx × my its whole-pixel samples make.  Nonzero with err when the
 * sizes are even or the sampling outside 1..8. */
static int stdpsf_sizes(fitsfile *fp, const char *name, long nx, long ny, int *step, int *mx,
                        int *my, char *err)
{
    int st = 0;
    double o = 4.0;
    mp_fits_key_number(fp, "OVERSAMP", &o, &st);
    fits_clear_errmsg();
    if (!(o >= 1 && o <= 8 && o == floor(o)) || nx % 2 == 0 || ny % 2 == 0 || nx > 4096 ||
        ny > 4096) {
        snprintf(err, MP_ERRLEN, "%s: STDPSF of %ldx%ld elements at %g per pixel: sizes must "
                 "be odd, sampling 1..8", name, nx, ny, o);
        return 1;
    }
    *step = (int)o;
    *mx = 2 * (int)(((nx - 1) / 2) / *step) + 1;
    *my = 2 * (int)(((ny - 1) / 2) / *step) + 1;
    return 0;
}

/* Plane k of the cube v (nx × ny each) into its grid point's plane of f
 * (mx × my): an STDPSF's whole-pixel samples (every step-th element
 * about the centre), else the table padded by pad. */
static void fill_plane(mp_psf_field *f, const double *v, long k, long nx, long ny, int stdpsf,
                       int step, int pad, int i, int j, int ngx)
{
    int mx = f->nx, my = f->ny;
    double *dst = f->planes + (size_t)(j * ngx + i) * mx * my;
    const double *src = v + (size_t)k * nx * ny;
    if (!stdpsf) {
        copy_padded(src, nx, ny, pad, dst, mx);
        return;
    }
    int cx = (int)(nx - 1) / 2, cy = (int)(ny - 1) / 2, hx = mx / 2, hy = my / 2;
    for (int b = -hy; b <= hy; b++)
        for (int a = -hx; a <= hx; a++)
            dst[(b + hy) * mx + a + hx] = src[(cy + b * step) * nx + cx + a * step];
}

/* f's light (its first plane's sum) into f->sum; photutils' ePSF
 * convention scales an oversampled table to sum os², matphot's sums to
 * the light it holds: such a grid is divided by os² (returns 1). */
static int grid_sum(mp_psf_field *f, int os, long nz)
{
    size_t nel = (size_t)f->nx * f->ny;
    double s = 0.0;
    for (size_t i = 0; i < nel; i++)
        s += f->planes[i];
    int rescaled = os > 1 && s > 0.5 * os * os;
    if (rescaled) {
        for (size_t i = 0; i < nel * (size_t)nz; i++)
            f->planes[i] /= (double)os * os;
        s /= (double)os * os;
    }
    f->sum = s;
    return rescaled;
}

int grid_read(fitsfile *fp, const char *name, int stdpsf, const long naxes[3], mp_psf_field *f,
              char *warn, char *err)
{
    long nx = naxes[0], ny = naxes[1], nz = naxes[2];
    int os = 1, mx, my, pad = 0, step = 1;
    if (nz > MP_PSF_MAXTERMS) {
        snprintf(err, MP_ERRLEN, "%s: %ld PSFs in the grid; at most %d", name, nz, MP_PSF_MAXTERMS);
        return 1;
    }
    /* Anderson's ePSF: the pixel-convolved PSF point-sampled every 1/4 px
     * (or 1/OVERSAMP), its centre at element (n−1)/2.  Its samples at
     * whole-pixel steps are a ×1 table exactly; finer, matphot's
     * block-sum would convolve with the pixel a second time. */
    if (stdpsf ? stdpsf_sizes(fp, name, nx, ny, &step, &mx, &my, err)
               : oversamp_of(fp, name, &os, err) || pad_sizes(name, nx, ny, &mx, &my, &pad, err))
        return 1;
    double *px = malloc((size_t)nz * sizeof *px), *py = malloc((size_t)nz * sizeof *py);
    double gx[MP_PSF_MAXGRID], gy[MP_PSF_MAXGRID];
    double *v = NULL;
    int rc = 1, ngx, ngy;
    if (!px || !py) {
        snprintf(err, MP_ERRLEN, "%s: out of memory", name);
        goto done;
    }
    if (grid_positions(fp, name, stdpsf, nz, px, py, err))
        goto done;
    ngx = distinct(px, (int)nz, gx, MP_PSF_MAXGRID);
    ngy = distinct(py, (int)nz, gy, MP_PSF_MAXGRID);
    if (ngx < 1 || ngy < 1 || (long)ngx * ngy != nz) {
        snprintf(err, MP_ERRLEN, "%s: the %ld PSF positions do not form a full rectangular grid "
                 "(%d x %d distinct x, y)", name, nz, ngx, ngy);
        goto done;
    }
    if (!(v = read_cube(fp, name, nx, ny, nz, err)))
        goto done;
    char e2[MP_ERRLEN];
    if (mp_psf_field_new_grid(ngx, ngy, gx, gy, mx, my, os, f, e2)) {
        snprintf(err, MP_ERRLEN, "%s: %.400s", name, e2);   /* positions beyond ±1e7 px too */
        goto done;
    }
    f->offset = pad ? 0.5 / os : 0.0;
    for (long k = 0; k < nz; k++)
        fill_plane(f, v, k, nx, ny, stdpsf, step, pad, index_of(gx, ngx, px[k]),
                   index_of(gy, ngy, py[k]), ngx);
    int rescaled = grid_sum(f, os, nz);
    if (warn && stdpsf)
        snprintf(warn, MP_ERRLEN, "%s: STDPSF grid %dx%d: the ePSFs sampled at whole pixels "
                 "(OVERSAMP 1, %dx%d), interpolated bilinearly between grid points", name, ngx,
                 ngy, mx, my);
    else if (warn)
        snprintf(warn, MP_ERRLEN, "%s: gridded PSF %dx%d of %dx%d tables, interpolated "
                 "bilinearly between grid points%s", name, ngx, ngy, mx, my,
                 rescaled ? "; divided by OVERSAMP^2 (photutils' ePSF normalisation)" : "");
    rc = 0;
done:
    free(px);
    free(py);
    free(v);
    return rc;
}
