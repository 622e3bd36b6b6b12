/* star_excess.c — mp_bkg_star_excess (find.h): the residual's variance
 * beyond its noise model around the brightest stars, per ring of
 * distance, as F²·v(r), and its evaluation at a pixel. */
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "find/find_priv.h"

/* The trim: z² above its 0.9 quantile is left out, |z| ≤ a for noise. */
#define TRIM_Q 0.9
#define TRIM_A 1.6448536269514722

/* The first star of b->xs (sorted by y) with y ≥ y0. */
static size_t first_at_or_above(const mp_bkg *b, double y0)
{
    size_t lo = 0, hi = b->nxs;
    while (lo < hi) {
        size_t mid = lo + (hi - lo) / 2;
        if (b->xs[4 * mid + 1] < y0)
            lo = mid + 1;
        else
            hi = mid;
    }
    return lo;
}

double mp_bkg_excess_var(const mp_bkg *b, double x, double y)
{
    double r = (double)b->nxv, add = 0.0;
    for (size_t s = first_at_or_above(b, y - r); s < b->nxs && b->xs[4 * s + 1] < y + r; s++) {
        const double *st = b->xs + 4 * s;
        double d = hypot(x - st[0], y - st[1]);
        if (d < r)
            add += st[2] * b->xv[(size_t)st[3] * (size_t)b->nxv + (size_t)d];
    }
    return add;
}

/* A ring's pixels: z² and F²/σ² each. */
typedef struct {
    double *z2, *w;
    size_t n, cap;
} ring;

static int ring_push(ring *g, double z2, double w)
{
    if (g->n == g->cap) {
        size_t cap = g->cap ? 2 * g->cap : 64;
        double *a = realloc(g->z2, cap * sizeof *a);
        if (!a)
            return 1;
        g->z2 = a;
        if (!(a = realloc(g->w, cap * sizeof *a)))
            return 1;
        g->w = a;
        g->cap = cap;
    }
    g->z2[g->n] = z2;
    g->w[g->n++] = w;
    return 0;
}

/* The unmasked pixels around one star, by ring. */
static int ring_pixels(const mp_bkg *b, const mp_frame *f, double xs, double ys, double F,
                       int nr, ring *g)
{
    long nx = f->im.nx, ny = f->im.ny;
    long x0 = (long)floor(xs - nr), x1 = (long)ceil(xs + nr);
    long y0 = (long)floor(ys - nr), y1 = (long)ceil(ys + nr);
    for (long y = y0 > 0 ? y0 : 0; y <= y1 && y < ny; y++)
        for (long x = x0 > 0 ? x0 : 0; x <= x1 && x < nx; x++) {
            double d = hypot((double)x - xs, (double)y - ys);
            size_t i = (size_t)y * (size_t)nx + (size_t)x;
            if (d >= nr || f->mask[i] || !isfinite(b->res[i]))
                continue;
            double rms = mp_bkg_rms(b, i);
            if (!(rms > 0))
                continue;
            double z = (b->res[i] - mp_bkg_sky(b, i)) / rms;
            if (ring_push(&g[(int)d], z * z, F * F / (rms * rms)))
                return 1;
        }
    return 0;
}

/* v of one ring (0 unless significant): the trimmed moment estimate. */
static double ring_excess(ring *g, double *tmp)
{
    if (g->n < 10)
        return 0.0;
    memcpy(tmp, g->z2, g->n * sizeof *tmp);
    size_t k = (size_t)(TRIM_Q * (double)g->n);
    double cut = mp_select_kth(tmp, g->n, k < g->n ? k : g->n - 1);
    /* noise alone: E[z²], E[z⁴] of a normal z given |z| ≤ a */
    double phi = exp(-0.5 * TRIM_A * TRIM_A) / sqrt(2.0 * M_PI);
    double c1 = (TRIM_Q - 2.0 * TRIM_A * phi) / TRIM_Q;
    double c2 = (3.0 * TRIM_Q - 2.0 * phi * (TRIM_A * TRIM_A * TRIM_A + 3.0 * TRIM_A)) / TRIM_Q;
    double S = 0.0, A = 0.0, m = 0.0;
    for (size_t i = 0; i < g->n; i++)
        if (g->z2[i] <= cut) {
            S += g->z2[i] - c1;
            A += g->w[i];
            m += 1.0;
        }
    return A > 0 && S > 3.0 * sqrt(m * (c2 - c1 * c1)) ? S / A : 0.0;
}

static int by_y(const void *a, const void *b)
{
    double u = ((const double *)a)[1], w = ((const double *)b)[1];
    return (u > w) - (u < w);
}

/* The stars whose F²·max v of their class reaches MP_BKG_EXCESS_FLOOR of
 * their sky pixel's variance, as (x, y, F², class) sorted by y into b. */
static int keep_stars(mp_bkg *b, const mp_frame *f, const double *x, const double *y,
                      const double *F, const int *cls, size_t n, const double *vmax)
{
    double *xs = malloc((4 * n + 1) * sizeof *xs);
    if (!xs)
        return 1;
    size_t m = 0;
    for (size_t s = 0; s < n; s++) {
        long px = lround(x[s]), py = lround(y[s]);
        if (!isfinite(F[s]) || px < 0 || py < 0 || px >= f->im.nx || py >= f->im.ny)
            continue;
        size_t i = (size_t)py * (size_t)f->im.nx + (size_t)px;
        double var = b->k * b->k * (fmax(mp_bkg_sky(b, i), 0.0) + b->ron2);
        if (F[s] * F[s] * vmax[cls[s]] >= MP_BKG_EXCESS_FLOOR * var) {
            double *st = xs + 4 * m++;
            st[0] = x[s];
            st[1] = y[s];
            st[2] = F[s] * F[s];
            st[3] = (double)cls[s];
        }
    }
    qsort(xs, m, 4 * sizeof *xs, by_y);
    b->xs = xs;
    b->nxs = m;
    return 0;
}

/* v of class c into v[0..nr-1]; its rings kept. */
static int class_excess(const mp_bkg *b, const mp_frame *f, const double *x, const double *y,
                        const double *F, const int *cls, size_t n, int c, size_t nb, int nr,
                        double *v, int *kept)
{
    ring *g = calloc((size_t)nr, sizeof *g);
    int rc = !g;
    size_t used = 0;
    for (size_t s = 0; !rc && s < n && used < nb; s++)
        if (cls[s] == c && F[s] > 0) {
            rc = ring_pixels(b, f, x[s], y[s], F[s], nr, g);
            used++;
        }
    size_t big = 0;
    for (int r = 0; !rc && r < nr; r++)
        big = g[r].n > big ? g[r].n : big;
    double *tmp = rc ? NULL : malloc((big + 1) * sizeof *tmp);
    rc = rc || !tmp;
    *kept = 0;
    for (int r = 0; !rc && r < nr; r++) {
        v[r] = ring_excess(&g[r], tmp);
        *kept += v[r] > 0;
    }
    for (int r = 0; g && r < nr; r++) {
        free(g[r].z2);
        free(g[r].w);
    }
    free(g);
    free(tmp);
    return rc;
}

int mp_bkg_star_excess(mp_bkg *b, const mp_frame *f, const double *x, const double *y,
                       const double *F, const int *cls, size_t n, int ncls, size_t nb,
                       double rmax, int *nring, size_t *nkept, char *err)
{
    *nring = 0;
    *nkept = 0;
    int nr = (int)ceil(rmax);
    if (!b->model || nr < 1 || n == 0 || ncls < 1)
        return 0;
    free(b->xv);
    free(b->xs);
    b->xv = NULL, b->xs = NULL, b->nxv = 0, b->nxs = 0;
    double *v = calloc((size_t)ncls * (size_t)nr, sizeof *v);
    double *vmax = calloc((size_t)ncls, sizeof *vmax);
    int rc = !v || !vmax;
    for (int c = 0; !rc && c < ncls; c++) {
        int kept;
        rc = class_excess(b, f, x, y, F, cls, n, c, nb, nr, v + (size_t)c * nr, &kept);
        *nring += kept;
        for (int r = 0; r < nr; r++)
            vmax[c] = fmax(vmax[c], v[(size_t)c * nr + r]);
    }
    if (!rc && *nring > 0) {
        b->xv = v;
        b->nxv = nr;
        v = NULL;
        rc = keep_stars(b, f, x, y, F, cls, n, vmax);
        *nkept = b->nxs;
    }
    free(v);
    free(vmax);
    if (rc)
        snprintf(err, MP_ERRLEN, "out of memory for the residual noise map");
    return rc;
}
