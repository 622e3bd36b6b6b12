/* bright_stars.c — the fitted stars brightest first, and their median sky,
 * for the models of the light the PSF table leaves out (halo.c, lookup.c)
 * and of the error it makes around them (mp_pl_star_excess). */
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include "pipeline/pipeline_priv.h"

static int by_flux_desc(const void *a, const void *b)
{
    double x = ((const mp_pl_star *)a)->e, y = ((const mp_pl_star *)b)->e;
    return (x < y) - (x > y);
}

mp_pl_star *mp_pl_stars_by_flux(const mp_table *t, long skipflags, size_t *n)
{
    int cx = mp_table_col(t, "XPSF_IMAGE"), cy = mp_table_col(t, "YPSF_IMAGE"),
        ce = mp_table_col(t, "FLUX_PSF"), cf = mp_table_col(t, "FLAGS"),
        cs = mp_table_col(t, "SKY_PSF");
    mp_pl_star *s = malloc((t->nrow ? t->nrow : 1) * sizeof *s);
    *n = 0;
    if (!s || cx < 0 || cy < 0 || ce < 0)
        return s;
    for (size_t r = 0; r < t->nrow; r++) {
        long fl = cf >= 0 ? (long)mp_table_get(t, r, cf) : 0;
        mp_pl_star h = {mp_table_get(t, r, cx), mp_table_get(t, r, cy),
                        mp_table_get(t, r, ce), fl, cs >= 0 ? mp_table_get(t, r, cs) : NAN};
        if (isfinite(h.x) && isfinite(h.y) && h.e > 0 && !(fl & skipflags))
            s[(*n)++] = h;
    }
    qsort(s, *n, sizeof *s, by_flux_desc);
    return s;
}

double mp_pl_median_sky(const mp_table *t)
{
    int c = mp_table_col(t, "SKY_PSF");
    double *v = malloc((t->nrow ? t->nrow : 1) * sizeof *v), m = 0.0;
    size_t n = 0;
    for (size_t r = 0; v && c >= 0 && r < t->nrow; r++)
        if (isfinite(mp_table_get(t, r, c)))
            v[n++] = mp_table_get(t, r, c);
    if (v && n)
        m = mp_epsf_median(v, n);
    free(v);
    return m;
}

double mp_pl_median_positive(const mp_table *t, const char *name)
{
    int c = mp_table_col(t, name);
    double *v = malloc((t->nrow + 1) * sizeof *v), m = 0.0;
    size_t k = 0;
    for (size_t r = 0; v && c >= 0 && r < t->nrow; r++) {
        double b = mp_table_get(t, r, c);
        if (isfinite(b) && b > 0)
            v[k++] = b;
    }
    if (k)
        m = mp_select_kth(v, k, k / 2);      /* the upper median, unsorted */
    free(v);
    return m;
}

int mp_pl_star_excess(const mp_frame *f, mp_bkg *b, const mp_table *t, const mp_prf_model *m,
                      int *nring, size_t *nkept, char *err)
{
    *nring = 0;
    *nkept = 0;
    size_t n;
    mp_pl_star *s = mp_pl_stars_by_flux(t, 0, &n);
    double *x = malloc((3 * n + 1) * sizeof *x);
    int *cls = malloc((n + 1) * sizeof *cls);
    unsigned char *usable = malloc(n + 1);
    if (!s || !x || !cls || !usable) {
        free(s);
        free(x);
        free(cls);
        free(usable);
        snprintf(err, MP_ERRLEN, "out of memory for the residual noise map");
        return 1;
    }
    double *y = x + n, *F = x + 2 * n;
    for (size_t k = 0; k < n; k++) {
        x[k] = s[k].x - 1.0;            /* FITS pixels to 0-based */
        y[k] = s[k].y - 1.0;
        F[k] = s[k].e;
        /* a fit without its saturated pixels: a flux from the wings */
        cls[k] = (s[k].flags & MP_FLAG_SATURATED) != 0;
        /* a fit flagged not converged, or merged/degenerate (a blend
         * fitted as one), misfits on its own account */
        usable[k] = !(s[k].flags & (MP_FLAG_NOCONV | MP_FLAG_MERGED));
    }
    /* as far as a star's model reaches: the table's half-size and the
     * pixel a shift and a block sum add */
    double rmax = 0.5 * (double)(m->psf->nx - 1) / m->psf->os + 1.0;
    int rc = mp_bkg_star_excess(b, f, x, y, F, cls, usable, n, 2, MP_BKG_EXCESS_NSTAR, rmax,
                                nring, nkept, err);
    free(cls);
    free(usable);
    free(s);
    free(x);
    return rc;
}
