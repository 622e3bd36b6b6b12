/* detect.c — mp_find_stars (find.h): DAOFIND's candidates (threshold on
 * the lowered-kernel amplitude, local maxima over the footprint), one
 * detection per saturated plateau, the measurements and the shape cuts,
 * appended to a table. */
#include <float.h>
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "find/find_priv.h"

void mp_find_opts_default(mp_find_opts *o)
{
    o->fwhm = 3.0;
    o->threshold = 4.0;
    o->nsigma = 1.5;
    o->sharplo = 0.2;
    o->sharphi = 1.0;
    o->roundlo = -1.0;
    o->roundhi = 1.0;
}

/* A growable list of pixel indices. */
typedef struct {
    long *v;
    size_t n, cap;
} idx_list;

static int push(idx_list *l, long i)
{
    if (l->n == l->cap) {
        size_t cap = l->cap ? 2 * l->cap : 256;
        long *v = realloc(l->v, cap * sizeof *v);
        if (!v)
            return 1;
        l->v = v;
        l->cap = cap;
    }
    l->v[l->n++] = i;
    return 0;
}

static int cmp_long(const void *a, const void *b)
{
    long x = *(const long *)a, y = *(const long *)b;
    return (x > y) - (x < y);
}

/* Is pixel p (h there = hv) a candidate: above threshold in the noise of
 * its own footprint, the maximum of h over the footprint (ties to the
 * first in raster order), and no saturated pixel within it (that star is
 * found as its plateau)? */
static int is_candidate(const mp_frame *f, const mp_bkg *b, const mpf_kernel *k,
                        const float *h, double thresh, long x, long y)
{
    long nx = f->im.nx, ny = f->im.ny;
    size_t p = (size_t)y * (size_t)nx + (size_t)x;
    double hv = h[p];
    /* A noiseless frame has rms 0: there h must still beat the roundoff
     * of subtracting the sky (a single-precision map: FLT_EPSILON of it
     * through the kernel's weights, and h's own rounding), or every flat
     * pixel would be a star. */
    double sky = fabs(b->sky[p]);
    if (!(hv > 4.0 * FLT_EPSILON * (1.0 + sky) * (k->klsum + 1.0)) ||
        hv < thresh * b->rms[p] * k->relerr)
        return 0;
    for (int t = 0; t < k->n; t++) {
        long qx = x + k->dx[t], qy = y + k->dy[t];
        if (qx < 0 || qx >= nx || qy < 0 || qy >= ny || (qx == x && qy == y))
            continue;
        size_t q = (size_t)qy * (size_t)nx + (size_t)qx;
        if (h[q] > hv || (h[q] == hv && q < p))
            return 0;
    }
    if (mpf_bad(f, p))
        return 0;
    mpf_foot fp;
    mpf_footprint(f, k, x, y, &fp, NULL);
    if (fp.sat || fp.denom <= 0.0)
        return 0;
    /* A cut footprint has a noisier h (relerr grows as taps are lost). */
    if ((fp.edge || fp.masked) && hv < thresh * b->rms[p] / sqrt(fp.denom))
        return 0;
    return 1;
}

static int find_candidates(const mp_frame *f, const mp_bkg *b, const mpf_kernel *k,
                           const float *h, double thresh, idx_list *out)
{
    long nx = f->im.nx, ny = f->im.ny;
    int nomem = 0;
#pragma omp parallel
    {
        idx_list mine = {0};
#pragma omp for schedule(static)
        for (long y = 0; y < ny; y++)
            for (long x = 0; x < nx; x++)
                if (is_candidate(f, b, k, h, thresh, x, y) && push(&mine, y * nx + x)) {
#pragma omp atomic write
                    nomem = 1;
                }
#pragma omp critical(find_merge)
        for (size_t i = 0; i < mine.n && !nomem; i++)
            if (push(out, mine.v[i]))
                nomem = 1;
        free(mine.v);
    }
    if (!nomem && out->n)
        qsort(out->v, out->n, sizeof *out->v, cmp_long);
    return nomem;
}

/* The 8-connected regions of saturated pixels, each measured as one star;
 * *stars grows by one per region. */
static int find_plateaus(const mp_frame *f, const mp_bkg *b, const mpf_kernel *k,
                         mpf_star **stars, long **keys, size_t *n)
{
    long nx = f->im.nx, ny = f->im.ny;
    size_t npix = (size_t)nx * (size_t)ny;
    size_t first = 0;
    while (first < npix && !mpf_sat(f, first))
        first++;
    if (first == npix)
        return 0;
    unsigned char *seen = calloc(npix, 1);
    idx_list reg = {0};
    size_t cap = *n;
    int rc = 1;
    if (!seen)
        return 1;
    for (size_t s = first; s < npix; s++) {
        if (seen[s] || !mpf_sat(f, s))
            continue;
        reg.n = 0;
        seen[s] = 1;
        if (push(&reg, (long)s))
            goto done;
        for (size_t head = 0; head < reg.n; head++) {
            long x = reg.v[head] % nx, y = reg.v[head] / nx;
            for (long j = y - 1; j <= y + 1; j++)
                for (long i = x - 1; i <= x + 1; i++) {
                    if (i < 0 || i >= nx || j < 0 || j >= ny)
                        continue;
                    size_t q = (size_t)j * (size_t)nx + (size_t)i;
                    if (seen[q] || !mpf_sat(f, q))
                        continue;
                    seen[q] = 1;
                    if (push(&reg, (long)q))
                        goto done;
                }
        }
        if (*n == cap) {
            cap = cap ? 2 * cap : 64;
            mpf_star *ns = realloc(*stars, cap * sizeof *ns);
            if (!ns)
                goto done;
            *stars = ns;
            long *nk = realloc(*keys, cap * sizeof *nk);
            if (!nk)
                goto done;
            *keys = nk;
        }
        mpf_star *st = *stars + *n;
        mpf_measure_plateau(f, b, k, reg.v, reg.n, st);
        (*keys)[*n] = (lround(st->y) - 1) * nx + (lround(st->x) - 1);
        (*n)++;
    }
    rc = 0;
done:
    free(seen);
    free(reg.v);
    return rc;
}

static int within(double v, double lo, double hi)
{
    return (isnan(lo) || v >= lo) && (isnan(hi) || v <= hi);
}

/* Detections in raster order of their key pixel. */
typedef struct {
    long key;
    const mpf_star *s;
} ordered;

static int cmp_ordered(const void *a, const void *b)
{
    long x = ((const ordered *)a)->key, y = ((const ordered *)b)->key;
    return (x > y) - (x < y);
}

static const char *const columns[] = {
    "NUMBER", "X_IMAGE", "Y_IMAGE", "FLUX_MAX", "BACKGROUND", "SHARPNESS", "ROUNDNESS",
    "FLUX", "FLAGS"};
enum { NCOLS = sizeof columns / sizeof columns[0] };

static int append(mp_table *t, const ordered *o, size_t n, char *err)
{
    int c[NCOLS];
    for (int i = 0; i < NCOLS; i++)
        if ((c[i] = mp_table_add_col(t, columns[i])) < 0) {
            snprintf(err, MP_ERRLEN, "out of memory for the table");
            return 1;
        }
    double number = 0.0;
    for (size_t r = 0; r < t->nrow; r++) {
        double v = mp_table_get(t, r, c[0]);
        if (isfinite(v) && v > number)
            number = floor(v);
    }
    size_t nrow0 = t->nrow;
    for (size_t i = 0; i < n; i++) {
        long r = mp_table_add_row(t);
        if (r < 0) {
            t->nrow = nrow0;
            snprintf(err, MP_ERRLEN, "out of memory for the table");
            return 1;
        }
        const mpf_star *s = o[i].s;
        double v[NCOLS] = {number + 1.0 + (double)i, s->x, s->y, s->flux_max, s->background,
                           s->sharp, s->round, s->flux, (double)s->flags};
        for (int j = 0; j < NCOLS; j++)
            mp_table_set(t, (size_t)r, c[j], isfinite(v[j]) ? v[j] : 0.0);
    }
    return 0;
}

int mp_find_stars(const mp_frame *f, const mp_bkg *b, const mp_find_opts *o,
                  mp_table *t, char *err)
{
    mp_find_opts def;
    if (!o) {
        mp_find_opts_default(&def);
        o = &def;
    }
    if (!(o->threshold >= 0.0) || !isfinite(o->threshold)) {
        snprintf(err, MP_ERRLEN, "threshold: %g must be a number of sigma >= 0", o->threshold);
        return 1;
    }
    if (b->nx != f->im.nx || b->ny != f->im.ny || !b->sky || !b->rms) {
        snprintf(err, MP_ERRLEN, "background map is %ld x %ld pixels, the image %ld x %ld",
                 b->nx, b->ny, f->im.nx, f->im.ny);
        return 1;
    }
    mpf_kernel k;
    if (mpf_kernel_make(o->fwhm, o->nsigma, &k, err))
        return 1;
    long nx = f->im.nx, ny = f->im.ny;
    size_t npix = (size_t)nx * (size_t)ny;
    int rc = 1, nomem = 0;
    idx_list cand = {0};
    mpf_star *stars = NULL;
    long *keys = NULL;
    ordered *ord = NULL;
    float *h = malloc((npix ? npix : 1) * sizeof *h);
    if (!h)
        goto nomem;
    if (mpf_convolve(f, b, &k, h, err))
        goto done;
    if (find_candidates(f, b, &k, h, o->threshold, &cand))
        goto nomem;
    size_t nc = cand.n;
    stars = malloc((nc ? nc : 1) * sizeof *stars);
    keys = malloc((nc ? nc : 1) * sizeof *keys);
    if (!stars || !keys)
        goto nomem;
#pragma omp parallel
    {
        double *w = malloc((size_t)k.n * sizeof *w);
        if (!w) {
#pragma omp atomic write
            nomem = 1;
        }
#pragma omp for schedule(dynamic, 64)
        for (size_t i = 0; i < nc; i++) {
            keys[i] = cand.v[i];
            if (w)
                mpf_measure(f, b, &k, cand.v[i] % nx, cand.v[i] / nx, h[cand.v[i]], w, &stars[i]);
        }
        free(w);
    }
    if (nomem)
        goto nomem;
    /* Shape cuts apply to ordinary detections only; plateaus come after. */
    size_t n = 0;
    for (size_t i = 0; i < nc; i++)
        if (stars[i].ok && within(stars[i].sharp, o->sharplo, o->sharphi) &&
            within(stars[i].round, o->roundlo, o->roundhi)) {
            stars[n] = stars[i];
            keys[n++] = keys[i];
        }
    if (find_plateaus(f, b, &k, &stars, &keys, &n))
        goto nomem;
    ord = malloc((n ? n : 1) * sizeof *ord);
    if (!ord)
        goto nomem;
    for (size_t i = 0; i < n; i++) {
        ord[i].key = keys[i];
        ord[i].s = &stars[i];
    }
    qsort(ord, n, sizeof *ord, cmp_ordered);
    if (append(t, ord, n, err))
        goto done;
    rc = 0;
    goto done;
nomem:
    snprintf(err, MP_ERRLEN, "out of memory for detection (%ld x %ld pixels)", nx, ny);
done:
    mpf_kernel_free(&k);
    free(h);
    free(cand.v);
    free(stars);
    free(keys);
    free(ord);
    return rc;
}
