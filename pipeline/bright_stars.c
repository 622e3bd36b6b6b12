/* bright_stars.c — the fitted stars brightest first, and their median sky,
 * for the models of the light the PSF table leaves out (halo.c, lookup.c). */
#include <math.h>
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
        ce = mp_table_col(t, "FLUX_PSF"), cf = mp_table_col(t, "FLAGS");
    mp_pl_star *s = malloc((t->nrow ? t->nrow : 1) * sizeof *s);
    *n = 0;
    if (!s || cx < 0 || cy < 0 || ce < 0)
        return s;
    for (size_t r = 0; r < t->nrow; r++) {
        long fl = cf >= 0 ? (long)mp_table_get(t, r, cf) : 0;
        mp_pl_star h = {mp_table_get(t, r, cx), mp_table_get(t, r, cy),
                        mp_table_get(t, r, ce), fl};
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
