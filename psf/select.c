/* select.c — PSF stars from a find table (DAOPHOT pstselect, build.h):
 * bright but unsaturated, clean, star-like, alone, spread over the frame. */
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include "psf/build_priv.h"

typedef struct { size_t row; double flux; int cell; } cand;

static int by_flux(const void *a, const void *b)
{
    double x = ((const cand *)a)->flux, y = ((const cand *)b)->flux;
    return (x < y) - (x > y);
}

/* No masked or saturated pixel within r of (x, y), and the star's whole
 * table box inside the frame. */
static int clean_around(const mp_frame *f, double x, double y, double r)
{
    long x0 = (long)floor(x - r), x1 = (long)ceil(x + r);
    long y0 = (long)floor(y - r), y1 = (long)ceil(y + r);
    if (x0 < 1 || y0 < 1 || x1 > f->im.nx || y1 > f->im.ny)
        return 0;
    for (long j = y0; j <= y1; j++)
        for (long i = x0; i <= x1; i++)
            if (f->mask[(size_t)(j - 1) * f->im.nx + (size_t)(i - 1)] &&
                hypot(i - x, j - y) <= r)
                return 0;
    return 1;
}

/* Median and robust σ (1.4826 MAD) of v[0..n). */
static void robust(double *v, size_t n, double *med, double *sig)
{
    *med = mp_epsf_median(v, n);
    for (size_t k = 0; k < n; k++)
        v[k] = fabs(v[k] - *med);
    *sig = 1.4826 * mp_epsf_median(v, n);
}

int mp_epsf_select(const mp_frame *f, const mp_table *t, const mp_epsf_opts *o, size_t *idx,
                   size_t *nout, char *err)
{
    *nout = 0;
    int cx = mp_table_col(t, "X_IMAGE"), cy = mp_table_col(t, "Y_IMAGE");
    int cf = mp_table_col(t, "FLUX"), cb = mp_table_col(t, "BACKGROUND");
    int cs = mp_table_col(t, "SHARPNESS"), cr = mp_table_col(t, "ROUNDNESS");
    int cg = mp_table_col(t, "FLAGS");
    if (cx < 0 || cy < 0 || cf < 0) {
        snprintf(err, MP_ERRLEN, "psf select: the star table needs X_IMAGE, Y_IMAGE, FLUX");
        return 1;
    }
    size_t n = t->nrow;
    cand *c = malloc((n + 1) * sizeof *c);
    double *v = malloc((n + 1) * sizeof *v);
    if (!c || !v) {
        free(c);
        free(v);
        snprintf(err, MP_ERRLEN, "psf select: out of memory");
        return 1;
    }
    /* Bright enough to shape the table: S/N ≥ 20 on its fitting region. */
    double area = M_PI * o->fitrad * o->fitrad, ron2 = f->rdnoise * f->rdnoise;
    size_t m = 0;
    for (size_t k = 0; k < n; k++) {
        double x = mp_table_get(t, k, cx), y = mp_table_get(t, k, cy);
        double F = mp_table_get(t, k, cf), B = cb >= 0 ? mp_table_get(t, k, cb) : 0.0;
        int flags = cg >= 0 && isfinite(mp_table_get(t, k, cg)) ? (int)mp_table_get(t, k, cg) : 0;
        if (!isfinite(x) || !isfinite(y) || !(F > 0) || flags)
            continue;
        if (F / sqrt(F + area * (fmax(B, 0.0) + ron2)) < 20.0)
            continue;
        if (!clean_around(f, x, y, o->psfrad))
            continue;
        c[m++] = (cand){k, F, 0};
    }
    /* Star-like: sharpness and roundness within 3 robust σ of the
     * candidates' (a galaxy, a blend or a cosmic ray stands out). */
    for (int q = 0; q < 2 && m >= 5; q++) {
        int col = q ? cr : cs;
        if (col < 0)
            continue;
        for (size_t k = 0; k < m; k++)
            v[k] = mp_table_get(t, c[k].row, col);
        double med, sig;
        robust(v, m, &med, &sig);
        size_t kept = 0;
        for (size_t k = 0; k < m; k++) {
            double s = mp_table_get(t, c[k].row, col);
            if (!(sig > 0) || fabs(s - med) <= 3.0 * sig)
                c[kept++] = c[k];
        }
        m = kept;
    }
    /* Alone: no brighter detection within fitrad, where star and
     * neighbour would be one blend.  Beyond it a neighbour, brighter or
     * fainter, is fitted with the star at every fit of the build and its
     * model taken out (mp_epsf_neighbours, mp_epsf_clean), and what it
     * leaves is masked (mp_epsf_sirt_dilate): DAOPHOT's psfrad rule left
     * ~100 of a crowded frame's 400 stars, too few for an order-3 field
     * (MP_EPSF_PER_TERM). */
    size_t kept = 0;
    for (size_t k = 0; k < m; k++) {
        double x = mp_table_get(t, c[k].row, cx), y = mp_table_get(t, c[k].row, cy);
        int alone = 1;
        for (size_t q = 0; q < n && alone; q++) {
            if (q == c[k].row)
                continue;
            double dx = mp_table_get(t, q, cx) - x, dy = mp_table_get(t, q, cy) - y;
            if (fabs(dx) > o->fitrad || fabs(dy) > o->fitrad)
                continue;       /* beyond fitrad on an axis: beyond it (hypot's cost) */
            if (hypot(dx, dy) <= o->fitrad && !(mp_table_get(t, q, cf) < c[k].flux))
                alone = 0;
        }
        if (alone)
            c[kept++] = c[k];
    }
    m = kept;
    /* Spread: a grid of about maxnpsf/4 cells; the brightest of each
     * cell in turn until maxnpsf. */
    int g = (int)ceil(sqrt(o->maxnpsf / 4.0));
    g = g < 1 ? 1 : g;
    for (size_t k = 0; k < m; k++) {
        double x = mp_table_get(t, c[k].row, cx), y = mp_table_get(t, c[k].row, cy);
        int gx = (int)((x - 0.5) / f->im.nx * g), gy = (int)((y - 0.5) / f->im.ny * g);
        gx = gx < 0 ? 0 : gx >= g ? g - 1 : gx;
        gy = gy < 0 ? 0 : gy >= g ? g - 1 : gy;
        c[k].cell = gy * g + gx;
    }
    qsort(c, m, sizeof *c, by_flux);
    int *taken = calloc((size_t)g * g, sizeof *taken);
    char *done = calloc(m + 1, 1);
    if (!taken || !done) {
        free(taken);
        free(done);
        free(c);
        free(v);
        snprintf(err, MP_ERRLEN, "psf select: out of memory");
        return 1;
    }
    size_t out = 0;
    for (int round = 0; out < (size_t)o->maxnpsf && out < m; round++) {
        memset(taken, 0, (size_t)g * g * sizeof *taken);
        for (size_t k = 0; k < m && out < (size_t)o->maxnpsf; k++)
            if (!done[k] && !taken[c[k].cell]) {
                taken[c[k].cell] = 1;
                done[k] = 1;
                idx[out++] = c[k].row;
            }
    }
    *nout = out;
    free(taken);
    free(done);
    free(c);
    free(v);
    return 0;
}
