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
    int rc = mp_epsf_tablerad(f, f->im.pix, px, py, np, bx, by, nb, &ro, out, err);
    free(bx);
    free(by);
    return rc;
}
