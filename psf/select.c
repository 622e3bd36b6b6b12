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

/* The table's columns the selection reads (−1: absent). */
typedef struct { int x, y, f, b, s, r, g; } cols;

/* Bright enough to shape the table (S/N ≥ 20 on its fitting region),
 * unflagged, and clean within psfrad (clean_around): the candidates into
 * c; returns how many. */
static size_t bright_clean(const mp_frame *f, const mp_table *t, const cols *k,
                           const mp_epsf_opts *o, cand *c)
{
    double area = M_PI * o->fitrad * o->fitrad, ron2 = f->rdnoise * f->rdnoise;
    size_t m = 0;
    for (size_t q = 0; q < t->nrow; q++) {
        double x = mp_table_get(t, q, k->x), y = mp_table_get(t, q, k->y);
        double F = mp_table_get(t, q, k->f), B = k->b >= 0 ? mp_table_get(t, q, k->b) : 0.0;
        int flags = k->g >= 0 && isfinite(mp_table_get(t, q, k->g)) ? (int)mp_table_get(t, q, k->g)
                                                                     : 0;
        if (!isfinite(x) || !isfinite(y) || !(F > 0) || flags)
            continue;
        if (F / sqrt(F + area * (fmax(B, 0.0) + ron2)) < 20.0)
            continue;
        if (!clean_around(f, x, y, o->psfrad))
            continue;
        c[m++] = (cand){q, F, 0};
    }
    return m;
}

/* Star-like: sharpness and roundness within 3 robust σ of the
 * candidates' (a galaxy, a blend or a cosmic ray stands out); v is
 * scratch for m values.  Returns the candidates kept, first in c. */
static size_t star_like(const mp_table *t, const cols *k, cand *c, size_t m, double *v)
{
    for (int q = 0; q < 2 && m >= 5; q++) {
        int col = q ? k->r : k->s;
        if (col < 0)
            continue;
        for (size_t i = 0; i < m; i++)
            v[i] = mp_table_get(t, c[i].row, col);
        double med, sig;
        robust(v, m, &med, &sig);
        size_t kept = 0;
        for (size_t i = 0; i < m; i++) {
            double s = mp_table_get(t, c[i].row, col);
            if (!(sig > 0) || fabs(s - med) <= 3.0 * sig)
                c[kept++] = c[i];
        }
        m = kept;
    }
    return m;
}

/* A table's rows by X, for the neighbour searches of alone. */
typedef struct { double x; size_t row; } by_x;

static int by_x_order(const void *a, const void *b)
{
    double x = ((const by_x *)a)->x, y = ((const by_x *)b)->x;
    return (x > y) - (x < y);
}

/* The first of o[0..n) (ascending x) with x >= v. */
static size_t first_at_least(const by_x *o, size_t n, double v)
{
    size_t lo = 0, hi = n;
    while (lo < hi) {
        size_t mid = lo + (hi - lo) / 2;
        if (o[mid].x < v)
            lo = mid + 1;
        else
            hi = mid;
    }
    return lo;
}

/* Alone: no brighter detection within fitrad, where star and neighbour
 * would be one blend.  Beyond it a neighbour, brighter or fainter, is
 * fitted with the star at every fit of the build and its model taken out
 * (mp_epsf_neighbours, mp_epsf_clean), and what it leaves is masked
 * (mp_epsf_sirt_dilate): DAOPHOT's psfrad rule left ~100 of a crowded
 * frame's 400 stars, too few for an order-3 field (MP_EPSF_PER_TERM).
 * The rows are searched by X (o: the rows of finite X, sorted; a row of
 * another X passes no test below), from a pixel beyond fitrad on either
 * side: every candidate against every row was 1 % of frame B built
 * (tests/bench/daophot).  Returns the candidates kept, first in c. */
static size_t alone(const mp_table *t, const cols *k, double fitrad, cand *c, size_t m, by_x *o)
{
    size_t no = 0;
    for (size_t q = 0; q < t->nrow; q++) {
        double x = mp_table_get(t, q, k->x);
        if (isfinite(x))
            o[no++] = (by_x){x, q};
    }
    qsort(o, no, sizeof *o, by_x_order);
    size_t kept = 0;
    for (size_t i = 0; i < m; i++) {
        double x = mp_table_get(t, c[i].row, k->x), y = mp_table_get(t, c[i].row, k->y);
        int lone = 1;
        for (size_t a = first_at_least(o, no, x - fitrad - 1.0);
             a < no && o[a].x <= x + fitrad + 1.0 && lone; a++) {
            size_t q = o[a].row;
            if (q == c[i].row)
                continue;
            if (mp_within(o[a].x - x, mp_table_get(t, q, k->y) - y, fitrad) &&
                !(mp_table_get(t, q, k->f) < c[i].flux))
                lone = 0;
        }
        if (lone)
            c[kept++] = c[i];
    }
    return kept;
}

/* Spread: a grid of about maxnpsf/4 cells; the brightest of each cell in
 * turn until maxnpsf, their rows into idx.  Returns how many, or −1 when
 * out of memory. */
static long spread(const mp_frame *f, const mp_table *t, const cols *k, int maxnpsf, cand *c,
                   size_t m, size_t *idx)
{
    int g = (int)ceil(sqrt(maxnpsf / 4.0));
    g = g < 1 ? 1 : g;
    for (size_t i = 0; i < m; i++) {
        double x = mp_table_get(t, c[i].row, k->x), y = mp_table_get(t, c[i].row, k->y);
        int gx = (int)((x - 0.5) / f->im.nx * g), gy = (int)((y - 0.5) / f->im.ny * g);
        gx = gx < 0 ? 0 : gx >= g ? g - 1 : gx;
        gy = gy < 0 ? 0 : gy >= g ? g - 1 : gy;
        c[i].cell = gy * g + gx;
    }
    qsort(c, m, sizeof *c, by_flux);
    int *taken = calloc((size_t)g * g, sizeof *taken);
    char *done = calloc(m + 1, 1);
    if (!taken || !done) {
        free(taken);
        free(done);
        return -1;
    }
    size_t out = 0;
    while (out < (size_t)maxnpsf && out < m) {
        memset(taken, 0, (size_t)g * g * sizeof *taken);
        for (size_t i = 0; i < m && out < (size_t)maxnpsf; i++)
            if (!done[i] && !taken[c[i].cell]) {
                taken[c[i].cell] = 1;
                done[i] = 1;
                idx[out++] = c[i].row;
            }
    }
    free(taken);
    free(done);
    return (long)out;
}

int mp_epsf_select(const mp_frame *f, const mp_table *t, const mp_epsf_opts *o, size_t *idx,
                   size_t *nout, char *err)
{
    *nout = 0;
    cols k = {mp_table_col(t, "X_IMAGE"),    mp_table_col(t, "Y_IMAGE"),
              mp_table_col(t, "FLUX"),       mp_table_col(t, "BACKGROUND"),
              mp_table_col(t, "SHARPNESS"),  mp_table_col(t, "ROUNDNESS"),
              mp_table_col(t, "FLAGS")};
    if (k.x < 0 || k.y < 0 || k.f < 0) {
        snprintf(err, MP_ERRLEN, "psf select: the star table needs X_IMAGE, Y_IMAGE, FLUX");
        return 1;
    }
    cand *c = malloc((t->nrow + 1) * sizeof *c);
    double *v = malloc((t->nrow + 1) * sizeof *v);
    by_x *ox = malloc((t->nrow + 1) * sizeof *ox);
    long out = -1;
    if (c && v && ox) {
        size_t m = bright_clean(f, t, &k, o, c);
        m = star_like(t, &k, c, m, v);
        m = alone(t, &k, o->fitrad, c, m, ox);
        out = spread(f, t, &k, o->maxnpsf, c, m, idx);
    }
    free(c);
    free(v);
    free(ox);
    if (out < 0) {
        snprintf(err, MP_ERRLEN, "psf select: out of memory");
        return 1;
    }
    *nout = (size_t)out;
    return 0;
}
