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

#ifdef _OPENMP
#include <omp.h>
#endif

void mp_find_opts_default(mp_find_opts *o)
{
    o->fwhm = 3.0;
    o->threshold = 4.0;
    o->nsigma = 1.5;
    o->sharplo = 0.2;
    o->sharphi = 1.0;
    o->roundlo = -1.0;
    o->roundhi = 1.0;
    o->sharpsig = 0.0;
    o->sky_known = 0;
    o->sieve = NULL;
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

/* A detection strip: the rows [y0, y1) searched, h over [h0, h1) (y0 − nh
 * .. y1 + nh within the image), and hu, the known sky's h, the same (NULL
 * unless the sky is known), the sky over [s0, s1) (h's rows ± nh) and the
 * rms over [y0, y1); each buffer row-major from its first row. */
typedef struct {
    long y0, y1, h0, h1, s0, s1;
    float *h, *hu, *sky, *rms;
} strip;

/* Whether pixel x of the strip's row y is above threshold in its noise,
 * in hs (the strip's h or hu, of kernel k), for every x of the row into
 * pass[] (one pass without branches the compiler vectorises: most pixels
 * end here).  A noiseless frame has rms 0: there h must still beat the
 * roundoff of subtracting the sky (a single-precision map: FLT_EPSILON of
 * it through the kernel's weights, and h's own rounding), or every flat
 * pixel would be a star. */
static void above_noise(const strip *st, const float *hs, const mpf_kernel *k, double thresh,
                        long nx, long y, unsigned char *restrict pass)
{
    const float *h = hs + (size_t)(y - st->h0) * (size_t)nx;
    const float *rms = st->rms + (size_t)(y - st->y0) * (size_t)nx;
    const float *skyr = st->sky + (size_t)(y - st->s0) * (size_t)nx;
    for (long x = 0; x < nx; x++) {
        double hv = h[x], sky = fabs(skyr[x]);
        pass[x] = (hv > 4.0 * FLT_EPSILON * (1.0 + sky) * (k->klsum + 1.0)) &
                  !(hv < thresh * rms[x] * k->relerr);
    }
}

/* Is pixel (x, y) of the strip, above threshold in its noise
 * (above_noise), a candidate: the maximum of hs (the strip's h or hu, of
 * kernel k) over its footprint (ties to the first in raster order), and
 * no saturated pixel within it (that star is found as its plateau)? */
static int is_candidate(const mp_frame *f, const strip *st, const float *hs,
                        const mpf_kernel *k, double thresh, long x, long y)
{
    long nx = f->im.nx, ny = f->im.ny;
    size_t p = (size_t)y * (size_t)nx + (size_t)x;
    size_t sp = (size_t)(y - st->y0) * (size_t)nx + (size_t)x;
    double hv = hs[(size_t)(y - st->h0) * (size_t)nx + (size_t)x];
    float rms = st->rms[sp];
    for (int t = 0; t < k->n; t++) {
        long qx = x + k->dx[t], qy = y + k->dy[t];
        if (qx < 0 || qx >= nx || qy < 0 || qy >= ny || (qx == x && qy == y))
            continue;
        size_t q = (size_t)qy * (size_t)nx + (size_t)qx;
        float hq = hs[(size_t)(qy - st->h0) * (size_t)nx + (size_t)qx];
        if (hq > hv || (hq == hv && q < p))
            return 0;
    }
    if (mpf_bad(f, p))
        return 0;
    mpf_foot fp;
    mpf_footprint(f, k, x, y, &fp, NULL);
    if (fp.sat || fp.denom <= 0.0)
        return 0;
    /* A cut footprint has a noisier h (relerr grows as taps are lost). */
    if ((fp.edge || fp.masked) && hv < thresh * rms / sqrt(fp.denom))
        return 0;
    return 1;
}

/* Does DAOFIND's h stay below threshold over the footprint of kernel k
 * about pixel (x, y) of the strip, in the pixel's own noise?  There a
 * peak of the known sky's hu is a star the lowered kernel does not see,
 * not one it finds beside (a real frame's residual: 47 Tuc's round 1 gave
 * 1400 new stars on hu alone, 1687 on h). */
static int quiet_footprint(const mp_frame *f, const strip *st, const mpf_kernel *k,
                           double thresh, double relerr, long x, long y)
{
    long nx = f->im.nx, ny = f->im.ny;
    double lim = thresh * st->rms[(size_t)(y - st->y0) * (size_t)nx + (size_t)x] * relerr;
    for (int t = 0; t < k->n; t++) {
        long qx = x + k->dx[t], qy = y + k->dy[t];
        if (qx >= 0 && qx < nx && qy >= 0 && qy < ny &&
            !(st->h[(size_t)(qy - st->h0) * (size_t)nx + (size_t)qx] < lim))
            return 0;
    }
    return 1;
}

/* Is hu at pixel (x, y) of the strip above threshold in its noise with
 * the model's own errors taken whole?  The residual's variance there is
 * white, from pixel to pixel (mp_bkg_white_var), and the model's errors
 * (its profile error, a bright star's misfit), smooth over a footprint.
 * DAOFIND's zero-sum h cancels a constant error; hu, whose weights w have
 * one sign, takes it whole, so its noise is bounded as if that error were
 * one value over the footprint: σ² = white·Σw² + rest·(Σw)², Σw the
 * kernel's klsum (its weights positive).  (Counted as white, as h's is,
 * hu offered 13 more false entries on the segmented scene built, on its
 * bright stars' features.) */
static int above_model_errors(const mp_bkg *b, const strip *st, const mpf_kernel *ku,
                              double thresh, long nx, long x, long y)
{
    size_t sp = (size_t)(y - st->y0) * (size_t)nx + (size_t)x;
    float sky = st->sky[(size_t)(y - st->s0) * (size_t)nx + (size_t)x];
    double rms = st->rms[sp], white = mp_bkg_white_var(b, (size_t)y * (size_t)nx + (size_t)x, sky);
    double rest = fmax(rms * rms - white, 0.0);
    double hv = st->hu[(size_t)(y - st->h0) * (size_t)nx + (size_t)x];
    return hv >= thresh * sqrt(white * ku->relerr * ku->relerr + rest * ku->klsum * ku->klsum);
}

/* A candidate: its pixel and h there. */
typedef struct {
    long p;
    float h;
} cand;

typedef struct {
    cand *v;
    size_t n, cap;
} cand_list;

static int push_cand(cand_list *l, long p, float h)
{
    if (l->n == l->cap) {
        size_t cap = l->cap ? 2 * l->cap : 256;
        cand *v = realloc(l->v, cap * sizeof *v);
        if (!v)
            return 1;
        l->v = v;
        l->cap = cap;
    }
    l->v[l->n].p = p;
    l->v[l->n++].h = h;
    return 0;
}

/* Is pixel x of row y a candidate: DAOFIND's (h above threshold, its
 * footprint's maximum), or, with ku (the sky known), hu's where h stays
 * below threshold over the footprint (quiet_footprint) and above the
 * model's own errors (above_model_errors)?  pass, passu: above_noise of
 * h and hu on the row. */
static int candidate_at(const mp_frame *f, const mp_bkg *b, const strip *st,
                        const mpf_kernel *k, const mpf_kernel *ku, double thresh,
                        const unsigned char *pass, const unsigned char *passu, long x, long y)
{
    if (pass[x])
        return is_candidate(f, st, st->h, k, thresh, x, y);
    return ku && passu[x] && is_candidate(f, st, st->hu, ku, thresh, x, y) &&
           quiet_footprint(f, st, ku, thresh, k->relerr, x, y) &&
           above_model_errors(b, st, ku, thresh, f->im.nx, x, y);
}

/* The strip's candidates, appended to out in raster order: each thread
 * takes its own block of rows, in thread order, so their lists follow one
 * another in raster order (merged under a lock and sorted, they were a
 * serial part of every strip: 1.4 % of a 2048² run on 16 threads).  A
 * candidate carries DAOFIND's h, which measures it (mpf_measure). */
static int find_candidates(const mp_frame *f, const mp_bkg *b, const strip *st,
                           const mpf_kernel *k, const mpf_kernel *ku, double thresh,
                           cand_list *out)
{
    long nx = f->im.nx, rows = st->y1 - st->y0;
    int nt = 1, used = 1;
#ifdef _OPENMP
    nt = omp_get_max_threads();
#endif
    cand_list *mine = calloc((size_t)nt, sizeof *mine);
    int nomem = 0;
    if (!mine)
        return 1;
#pragma omp parallel num_threads(nt)
    {
        int t = 0, T = 1;
#ifdef _OPENMP
        t = omp_get_thread_num();
        T = omp_get_num_threads();
#endif
        if (t == 0)
            used = T;
        unsigned char *pass = malloc(2 * (size_t)nx), *passu = pass ? pass + nx : NULL;
        if (!pass) {
#pragma omp atomic write
            nomem = 1;
        }
        for (long y = st->y0 + rows * t / T; pass && y < st->y0 + rows * (t + 1) / T; y++) {
            above_noise(st, st->h, k, thresh, nx, y, pass);
            if (ku)
                above_noise(st, st->hu, ku, thresh, nx, y, passu);
            for (long x = 0; x < nx; x++)
                if ((pass[x] || (ku && passu[x])) &&
                    candidate_at(f, b, st, k, ku, thresh, pass, passu, x, y) &&
                    push_cand(&mine[t], y * nx + x,
                              st->h[(size_t)(y - st->h0) * (size_t)nx + (size_t)x])) {
#pragma omp atomic write
                    nomem = 1;
                }
        }
        free(pass);
    }
    for (int t = 0; t < used && !nomem; t++)
        for (size_t i = 0; i < mine[t].n && !nomem; i++)
            nomem = push_cand(out, mine[t].v[i].p, mine[t].v[i].h);
    for (int t = 0; t < nt; t++)
        free(mine[t].v);
    free(mine);
    return nomem;
}

/* Room for strips of `rows` rows (and the kernel's margins) of nx pixels,
 * hu's too when known. */
static int strip_alloc(strip *st, long rows, long nh, long nx, int known, size_t *bytes)
{
    size_t w = (size_t)nx, hr = (size_t)(rows + 2 * nh), sr = (size_t)(rows + 4 * nh);
    st->h = malloc(hr * w * sizeof *st->h);
    st->hu = known ? malloc(hr * w * sizeof *st->hu) : NULL;
    st->sky = malloc(sr * w * sizeof *st->sky);
    st->rms = malloc((size_t)rows * w * sizeof *st->rms);
    *bytes = ((known ? 2 : 1) * hr + sr + (size_t)rows) * w * sizeof(float);
    return !st->h || (known && !st->hu) || !st->sky || !st->rms;
}

static void strip_free(strip *st)
{
    free(st->h);
    free(st->hu);
    free(st->sky);
    free(st->rms);
}

/* One strip: its rows [y0, y0 + rows), their h (and the margins'), the
 * candidates among them appended to out. */
static int strip_search(const mp_frame *f, const mp_bkg *b, const mpf_kernel *k,
                        const mpf_kernel *ku, int bad, double thresh, long y0, long rows,
                        strip *st, cand_list *out, char *err)
{
    long ny = f->im.ny, nh = k->nh, nx = f->im.nx;
    st->y0 = y0;
    st->y1 = y0 + rows < ny ? y0 + rows : ny;
    st->h0 = st->y0 - nh > 0 ? st->y0 - nh : 0;
    st->h1 = st->y1 + nh < ny ? st->y1 + nh : ny;
    st->s0 = st->h0 - nh > 0 ? st->h0 - nh : 0;
    st->s1 = st->h1 + nh < ny ? st->h1 + nh : ny;
    /* The sky of every row, its rms too on the strip's own: one team,
     * rows dealt in turn (an rms row costs more), each sky row once (the
     * strip's rows were drawn twice, without and with their rms). */
#pragma omp parallel for schedule(static, 1)
    for (long y = st->s0; y < st->s1; y++)
        mp_bkg_rows(b, y, y + 1, st->sky + (size_t)(y - st->s0) * (size_t)nx,
                    y >= st->y0 && y < st->y1 ? st->rms + (size_t)(y - st->y0) * (size_t)nx
                                              : NULL);
    if (mpf_convolve_rows(f, st->sky, st->s0, k, bad, st->h0, st->h1, st->h, err) ||
        (ku && mpf_convolve_rows(f, st->sky, st->s0, ku, bad, st->h0, st->h1, st->hu, err)))
        return 1;
    if (find_candidates(f, b, st, k, ku, thresh, out)) {
        snprintf(err, MP_ERRLEN, "out of memory for the candidates");
        return 1;
    }
    return 0;
}

#define SEEN(i) (seen[(i) >> 3] & (1u << ((i) & 7)))
#define MARK(i) (seen[(i) >> 3] |= (unsigned char)(1u << ((i) & 7)))

/* The 8-connected regions of saturated pixels, each measured as one star;
 * *stars grows by one per region. */
static int find_plateaus(const mp_frame *f, const mp_bkg *b, const mpf_kernel *k,
                         mpf_star **stars, long **keys, size_t *n)
{
    long nx = f->im.nx, ny = f->im.ny;
    size_t npix = (size_t)nx * (size_t)ny;
    size_t first = npix;      /* the first saturated pixel, in parallel */
#pragma omp parallel for schedule(static) reduction(min : first) if (npix > 65536)
    for (size_t i = 0; i < npix; i++)
        if (i < first && mpf_sat(f, i))
            first = i;
    if (first == npix)
        return 0;
    /* one bit a pixel: saturated frames are the big ones (issue 14) */
    unsigned char *seen = calloc(npix / 8 + 1, 1);
    idx_list reg = {0};
    size_t cap = *n;
    int rc = 1;
    if (!seen)
        return 1;
    for (size_t s = first; s < npix; s++) {
        if (SEEN(s) || !mpf_sat(f, s))
            continue;
        reg.n = 0;
        MARK(s);
        if (push(&reg, (long)s))
            goto done;
        for (size_t head = 0; head < reg.n; head++) {
            long x = reg.v[head] % nx, y = reg.v[head] / nx;
            for (long j = y - 1; j <= y + 1; j++)
                for (long i = x - 1; i <= x + 1; i++) {
                    if (i < 0 || i >= nx || j < 0 || j >= ny)
                        continue;
                    size_t q = (size_t)j * (size_t)nx + (size_t)i;
                    if (SEEN(q) || !mpf_sat(f, q))
                        continue;
                    MARK(q);
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

static int append(mp_table *t, const ordered *o, size_t n, const char *snrcol, char *err)
{
    int c[NCOLS], cs = -1;
    for (int i = 0; i < NCOLS; i++)
        if ((c[i] = mp_table_add_col(t, columns[i])) < 0) {
            snprintf(err, MP_ERRLEN, "out of memory for the table");
            return 1;
        }
    if (snrcol && (cs = mp_table_add_col(t, snrcol)) < 0) {
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
        if (cs >= 0)
            mp_table_set(t, (size_t)r, cs, s->snr);
    }
    return 0;
}

int mp_find_stars(const mp_frame *f, const mp_bkg *b, const mp_find_opts *o,
                  mp_table *t, char *err)
{
    return mpf_find_stars_strips(f, b, o, MPF_STRIP, t, NULL, err);
}

/* The detections kept so far (measured, past the shape cuts), in raster
 * order of their peak pixels, and room for a strip's measures. */
typedef struct {
    mpf_star *stars, *meas;
    long *keys;
    size_t n, cap, mcap;
} kept_list;

static void kept_free(kept_list *l)
{
    free(l->stars);
    free(l->meas);
    free(l->keys);
}

/* Measure the strip's candidates (in parallel) and keep those that pass
 * the shape cuts: only the kept are held past their strip (on a deep
 * search of a residual most candidates fail, issue 14). */
static int measure_and_cut(const mp_frame *f, const mp_bkg *b, const mpf_kernel *k,
                           const mp_find_opts *o, const cand_list *c, kept_list *l)
{
    size_t nc = c->n;
    long nx = f->im.nx;
    if (nc > l->mcap) {
        free(l->meas);
        if (!(l->meas = malloc(nc * sizeof *l->meas)))
            return 1;
        l->mcap = nc;
    }
    int nomem = 0;
    /* Chunks of 64 candidates, fewer when a strip has not eight a thread
     * (with 64 always, few chunks a strip left threads idle: detection's
     * strips waited 3.5 % of a 2048² run's wall time on 16 threads). */
    int nt = 1;
#ifdef _OPENMP
    nt = omp_get_max_threads();
#endif
    size_t per = nc / (8 * (size_t)nt);
    int chunk = per >= 64 ? 64 : per < 1 ? 1 : (int)per;
#pragma omp parallel
    {
        double *w = malloc((size_t)k->n * sizeof *w);
        if (!w) {
#pragma omp atomic write
            nomem = 1;
        }
#pragma omp for schedule(dynamic, chunk)
        for (size_t i = 0; i < nc; i++)
            if (w)
                mpf_measure(f, b, k, c->v[i].p % nx, c->v[i].p / nx, c->v[i].h, w, &l->meas[i]);
        free(w);
    }
    size_t n0 = l->n;
    for (size_t i = 0; i < nc && !nomem; i++) {
        const mpf_star *s = &l->meas[i];
        double lo = o->sharplo - (o->sharpsig > 0.0 ? o->sharpsig * s->sharp_sd : 0.0);
        if (!s->ok || !within(s->sharp, lo, o->sharphi) ||
            !within(s->round, o->roundlo, o->roundhi))
            continue;
        if (l->n == l->cap) {
            size_t cap = l->cap ? 2 * l->cap : 256;
            mpf_star *ns = realloc(l->stars, cap * sizeof *ns);
            if (ns)
                l->stars = ns;
            long *nk = ns ? realloc(l->keys, cap * sizeof *nk) : NULL;
            if (!nk)
                return 1;
            l->keys = nk;
            l->cap = cap;
        }
        l->stars[l->n] = *s;
        l->stars[l->n].snr = NAN;
        l->keys[l->n++] = c->v[i].p;
    }
    return nomem || mpf_sieve(o, l->stars, l->keys, n0, &l->n);
}

/* The strips of rows searched (strip_search; ku: the known sky's kernel,
 * or NULL) and their candidates measured and cut (measure_and_cut) into
 * kl; *most: the peak bytes held.  0, 1 with err, or 2 when out of
 * memory. */
static int search_strips(const mp_frame *f, const mp_bkg *b, const mpf_kernel *k,
                         const mpf_kernel *ku, const mp_find_opts *o, long rows, kept_list *kl,
                         size_t *most, char *err)
{
    long nx = f->im.nx, ny = f->im.ny;
    cand_list cand = {0};
    size_t bytes = 0;
    /* The convolved image in strips of rows, never whole, and only the
     * kept detections held across strips (issue 14). */
    strip st = {0};
    int rc = strip_alloc(&st, rows, k->nh, nx, ku != NULL, &bytes) ? 2 : 0;
    int bad = mpf_any_bad(f);
    for (long y0 = 0; !rc && y0 < ny; y0 += rows) {
        cand.n = 0;
        if (strip_search(f, b, k, ku, bad, o->threshold, y0, rows, &st, &cand, err))
            rc = 1;
        else if (measure_and_cut(f, b, k, o, &cand, kl))
            rc = 2;
        size_t now = bytes + cand.cap * sizeof *cand.v + kl->mcap * sizeof *kl->meas +
                     kl->cap * (sizeof *kl->stars + sizeof *kl->keys);
        *most = now > *most ? now : *most;
    }
    strip_free(&st);
    free(cand.v);
    return rc;
}

/* The n kept stars appended to t in the order of their keys (the frame's
 * raster order, whatever the strips).  0, 1 with err, or 2 when out of
 * memory. */
static int append_ordered(mp_table *t, mpf_star *stars, const long *keys, size_t n,
                          const mp_find_opts *o, char *err)
{
    ordered *ord = malloc((n ? n : 1) * sizeof *ord);
    if (!ord)
        return 2;
    for (size_t i = 0; i < n; i++) {
        ord[i].key = keys[i];
        ord[i].s = &stars[i];
    }
    qsort(ord, n, sizeof *ord, cmp_ordered);
    int rc = append(t, ord, n, o->sieve ? o->sieve->col : NULL, err) ? 1 : 0;
    free(ord);
    return rc;
}

int mpf_find_stars_strips(const mp_frame *f, const mp_bkg *b, const mp_find_opts *o,
                          long rows, mp_table *t, size_t *work, char *err)
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
    if (b->nx != f->im.nx || b->ny != f->im.ny || !b->vals) {
        snprintf(err, MP_ERRLEN, "background map is %ld x %ld pixels, the image %ld x %ld",
                 b->nx, b->ny, f->im.nx, f->im.ny);
        return 1;
    }
    mpf_kernel k, ku = {0};
    if (mpf_kernel_make(o->fwhm, o->nsigma, 0, &k, err))
        return 1;
    if (o->sky_known && mpf_kernel_make(o->fwhm, o->nsigma, 1, &ku, err)) {
        mpf_kernel_free(&k);
        return 1;
    }
    rows = rows < 1 ? 1 : rows > f->im.ny ? f->im.ny : rows;
    kept_list kl = {0};
    size_t most = 0;
    int rc = search_strips(f, b, &k, o->sky_known ? &ku : NULL, o, rows, &kl, &most, err);
    free(kl.meas);
    kl.meas = NULL;
    if (!rc) {
        /* Plateaus come after the shape cuts (they have none). */
        size_t n = kl.n;
        mpf_star *stars = kl.stars;
        long *keys = kl.keys;
        int prc = find_plateaus(f, b, &k, &stars, &keys, &n);
        kl.stars = stars;
        kl.keys = keys;
        rc = prc || mpf_sieve(o, stars, keys, kl.n, &n) ? 2
                                                        : append_ordered(t, stars, keys, n, o, err);
    }
    if (rc == 2)
        snprintf(err, MP_ERRLEN, "out of memory for detection (%ld x %ld pixels)", f->im.nx,
                 f->im.ny);
    mpf_kernel_free(&k);
    mpf_kernel_free(&ku);
    kept_free(&kl);
    if (work)
        *work = most;
    return rc != 0;
}
