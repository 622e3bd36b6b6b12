/* tablerad.c — the built table's radius for a frame (tablerad=INDEF):
 * psf/tablerad.c's rule on the PSF stars and the frame's bright ones. */
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include "pipeline/pipeline_priv.h"

/* Bright stars: the saturated ones, as the centroids of the frame's
 * connected regions of saturated pixels (the find table's screen may
 * have dropped them: a clipped core fits no PSF), and the rows of the
 * find table t brighter by FLUX than every PSF star (fluxes pf); at most
 * MAXBRIGHT in all. */
#define MAXBRIGHT 200

/* The centroid of the region of saturated pixels holding pixel o (0-based
 * index), marking it in seen; q: a stack of nx*ny entries. */
static void region(const mp_frame *f, size_t o, uint8_t *seen, size_t *q, double *x, double *y)
{
    size_t nq = 0, n = 0;
    double sx = 0.0, sy = 0.0;
    long nx = f->im.nx, ny = f->im.ny;
    seen[o] = 1;
    q[nq++] = o;
    while (nq) {
        size_t k = q[--nq];
        long i = (long)(k % (size_t)nx), j = (long)(k / (size_t)nx);
        sx += (double)i;
        sy += (double)j;
        n++;
        for (int d = 0; d < 4; d++) {
            long a = i + (d == 0) - (d == 1), b = j + (d == 2) - (d == 3);
            size_t m = (size_t)b * (size_t)nx + (size_t)a;
            if (a < 0 || b < 0 || a >= nx || b >= ny || seen[m] ||
                !(f->mask[m] & MP_MASK_SATURATED))
                continue;
            seen[m] = 1;
            q[nq++] = m;
        }
    }
    *x = sx / (double)n + 1.0;
    *y = sy / (double)n + 1.0;
}

static int bright_list(const mp_frame *f, const mp_table *t, const double *pf, size_t np,
                       double *bx, double *by, size_t *nbo)
{
    size_t npix = (size_t)f->im.nx * (size_t)f->im.ny, nb = 0;
    *nbo = 0;
    if (f->nsat > 0) {
        uint8_t *seen = calloc(npix, 1);
        size_t *q = malloc(npix * sizeof *q);
        if (!seen || !q) {
            free(seen);
            free(q);
            return 1;
        }
        for (size_t o = 0; o < npix && nb < MAXBRIGHT; o++)
            if ((f->mask[o] & MP_MASK_SATURATED) && !seen[o]) {
                region(f, o, seen, q, &bx[nb], &by[nb]);
                nb++;
            }
        free(seen);
        free(q);
    }
    int cx = mp_table_col(t, "X_IMAGE"), cy = mp_table_col(t, "Y_IMAGE");
    int cf = mp_table_col(t, "FLUX");
    double fp = 0.0;
    for (size_t k = 0; k < np; k++)
        fp = isfinite(pf[k]) ? fmax(fp, pf[k]) : fp;
    for (size_t r = 0; cx >= 0 && cy >= 0 && cf >= 0 && r < t->nrow && nb < MAXBRIGHT; r++)
        if (fp > 0 && mp_table_get(t, r, cf) > fp) {
            bx[nb] = mp_table_get(t, r, cx);
            by[nb++] = mp_table_get(t, r, cy);
        }
    *nbo = nb;
    return 0;
}

/* The disc of radius r around (x, y) (1-based) set to NaN in img, or
 * copied back from the frame (restore). */
static void disc_set(const mp_frame *f, float *img, double x, double y, double r, int restore)
{
    long x0 = (long)floor(x - r), x1 = (long)ceil(x + r);
    long y0 = (long)floor(y - r), y1 = (long)ceil(y + r);
    for (long j = y0 < 1 ? 1 : y0; j <= y1 && j <= f->im.ny; j++)
        for (long i = x0 < 1 ? 1 : x0; i <= x1 && i <= f->im.nx; i++)
            if (mp_within((double)i - x, (double)j - y, r)) {
                size_t o = (size_t)(j - 1) * (size_t)f->im.nx + (size_t)(i - 1);
                img[o] = restore ? f->im.pix[o] : NAN;
            }
}

/* Whether (x, y) is within d of one of the n points (ax, ay). */
static int near_any(double x, double y, const double *ax, const double *ay, size_t n, double d)
{
    for (size_t k = 0; k < n; k++)
        if (fabs(ax[k] - x) <= d && fabs(ay[k] - y) <= d && hypot(ax[k] - x, ay[k] - y) <= d)
            return 1;
    return 0;
}

/* The frame with every other detection's core blanked (NaN), for the
 * stack: in a crowded frame the median over stars at a pixel offset holds
 * neighbours' light (frame C of the DAOPHOT comparison, 0.011 stars a
 * px²: ~40 detections in each star's 61² box), which reads as PSF wings to
 * the cap, 10 fwhm, and comes out in the table (fluxes 1.1 % high, 4.7x
 * the CPU of a 12-px table).  A detection's core is the disc where its
 * light, a Gaussian of fwhm with find's FLUX, is above half the noise of
 * a sky pixel (its BACKGROUND and the read noise), at least 1.5 fwhm; the
 * PSF and bright stars themselves (any detection within a fwhm of one)
 * are not blanked, nor is any pixel within 2 fwhm of them (the stack's
 * normalisation, which needs every pixel there: a star with a hole there
 * is left out of the stack). */
static float *neighbours_blanked(const mp_frame *f, const mp_table *t, const double *px,
                                 const double *py, size_t np, const double *bx,
                                 const double *by, size_t nb, double fwhm)
{
    size_t npix = (size_t)f->im.nx * (size_t)f->im.ny;
    float *img = malloc((npix ? npix : 1) * sizeof *img);
    if (!img)
        return NULL;
    memcpy(img, f->im.pix, npix * sizeof *img);
    int cx = mp_table_col(t, "X_IMAGE"), cy = mp_table_col(t, "Y_IMAGE");
    int cf = mp_table_col(t, "FLUX"), cb = mp_table_col(t, "BACKGROUND");
    if (cx < 0 || cy < 0 || !(fwhm > 0))
        return img;
    double s = fwhm / 2.3548, rcap = 0.5 * (double)(f->im.nx < f->im.ny ? f->im.nx : f->im.ny);
    for (size_t r = 0; r < t->nrow; r++) {
        double x = mp_table_get(t, r, cx), y = mp_table_get(t, r, cy);
        if (!isfinite(x) || !isfinite(y) || near_any(x, y, px, py, np, fwhm) ||
            near_any(x, y, bx, by, nb, fwhm))
            continue;
        double F = cf >= 0 ? mp_table_get(t, r, cf) : NAN;
        double sky = cb >= 0 ? mp_table_get(t, r, cb) : NAN;
        double noise = 0.5 * sqrt(fmax(isfinite(sky) ? sky : 0.0, 0.0) + f->rdnoise * f->rdnoise);
        double peak = F / (2.0 * M_PI * s * s), rad = 1.5 * fwhm;
        if (peak > noise && noise > 0)
            rad = fmax(rad, s * sqrt(2.0 * log(peak / noise)));
        disc_set(f, img, x, y, fmin(rad, rcap), 0);
    }
    /* + 1 px: the stack centres each star on its nearest pixel. */
    for (size_t k = 0; k < np; k++)
        disc_set(f, img, px[k], py[k], 2.0 * fwhm + 1.0, 1);
    for (size_t k = 0; k < nb; k++)
        disc_set(f, img, bx[k], by[k], 2.0 * fwhm + 1.0, 1);
    return img;
}

int mp_pl_tablerad(const mp_frame *f, const mp_table *t, const double *px, const double *py,
                   const double *pf, size_t np, const mp_epsf_opts *po, mp_epsf_rad *out,
                   char *err)
{
    double *bx = malloc(MAXBRIGHT * sizeof *bx), *by = malloc(MAXBRIGHT * sizeof *by);
    if (!bx || !by) {
        free(bx);
        free(by);
        snprintf(err, MP_ERRLEN, "out of memory");
        return 1;
    }
    size_t nb = 0;
    if (bright_list(f, t, pf, np, bx, by, &nb)) {
        free(bx);
        free(by);
        snprintf(err, MP_ERRLEN, "out of memory");
        return 1;
    }
    /* The cap: 10 fwhm (the build's cost grows as the table's area),
     * and an eighth of the frame's smaller side (stars that far from
     * every edge to stack).  The floor: the fixed radius before (4 fwhm),
     * so the rule only ever reaches further — on a 200² section of the
     * segmented scene (48 PSF stars) it measured 7 px where the whole
     * frame's 100 stars measure 17, a shortfall not yet understood. */
    long side = f->im.nx < f->im.ny ? f->im.nx : f->im.ny;
    mp_epsf_radopts ro = {
        .frac = 0.02, .fwhm = po->fwhm, .rmin = po->psfrad,
        .rmax = fmax(fmin(10.0 * po->fwhm, (double)side / 8.0), po->psfrad),
        .rdefault = po->psfrad};
    float *img = neighbours_blanked(f, t, px, py, np, bx, by, nb, po->fwhm);
    if (!img) {
        free(bx);
        free(by);
        snprintf(err, MP_ERRLEN, "out of memory");
        return 1;
    }
    int rc = mp_epsf_tablerad(f, img, px, py, np, bx, by, nb, &ro, out, err);
    free(img);
    free(bx);
    free(by);
    return rc;
}
