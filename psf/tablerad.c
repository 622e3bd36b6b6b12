/* tablerad.c — how far the built table must reach (build.h): as far as
 * the frame's stars show PSF light, spikes included, and the brightest
 * star's light per pixel is above the economy's painting level. */
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include "psf/build_priv.h"
#include "sim/sim.h"

/* A stack: per offset (dx, dy) within ±hw px of the stars' nearest
 * pixel, the median over stars of their light per unit flux, and the
 * error of that median. */
typedef struct {
    int hw, w, n;          /* half-width, 2hw+1, stars stacked */
    double *med, *sig;     /* w*w each; NaN where fewer than 3 stars */
    mp_epsf_ringnull nz;   /* what noise alone gives its rings (small_stack_null) */
} stack;

static int cmp_d(const void *a, const void *b)
{
    double x = *(const double *)a, y = *(const double *)b;
    return (x > y) - (x < y);
}

/* The p quantile of v[0..m) (sorted here), interpolated between order
 * statistics. */
static double quantile_of(double *v, size_t m, double p)
{
    qsort(v, m, sizeof *v, cmp_d);
    double t = p * (double)(m - 1);
    size_t i0 = (size_t)t;
    return i0 + 1 < m ? v[i0] + (t - (double)i0) * (v[i0 + 1] - v[i0]) : v[m - 1];
}

static void stack_free(stack *s)
{
    free(s->med);
    free(s->sig);
}

/* The median of the pixels of img within [r0, r1) px of the pixel (cx,
 * cy) (1-based), unmasked, on the frame and finite; NaN when fewer than
 * half of the ring's pixels are on the frame and unmasked, or fewer than
 * 8 usable.  (A NaN in img is a neighbour blanked by the caller: it
 * thins the ring, it does not cut it as an edge does.)  tmp: (2r1+1)²
 * values. */
static double ring_median(const mp_frame *f, const float *img, long cx, long cy, double r0,
                          double r1, double *tmp, size_t *nused)
{
    long h = (long)ceil(r1);
    size_t m = 0, all = 0, avail = 0;
    for (long j = cy - h; j <= cy + h; j++)
        for (long i = cx - h; i <= cx + h; i++) {
            double r = hypot((double)(i - cx), (double)(j - cy));
            if (r < r0 || r >= r1)
                continue;
            all++;
            if (i < 1 || j < 1 || i > f->im.nx || j > f->im.ny)
                continue;
            size_t o = (size_t)(j - 1) * f->im.nx + (size_t)(i - 1);
            if (f->mask[o])
                continue;
            avail++;
            if (isfinite(img[o]))
                tmp[m++] = img[o];
        }
    if (nused)
        *nused = m;
    return m >= 8 && 2 * avail >= all ? mp_median_select(tmp, m) : NAN;
}

/* The room ring_median needs for a ring out to r1 px, or least values
 * when more: a table of half-width 0-3 px has fewer than (2 r1 + 1)²
 * elements at 4 or 5 a pixel (fwhm=0.1 wrote past its work array). */
static size_t ring_room(double r1, size_t least)
{
    size_t s = 2 * (size_t)ceil(r1) + 1;
    return s * s > least ? s * s : least;
}

/* One star's light per unit flux around the pixel (cx, cy) into v (w*w,
 * NaN where masked or off the frame): (img − sky)/F. */
static void star_image(const mp_frame *f, const float *img, long cx, long cy, double sky,
                       double F, int hw, double *v)
{
    int w = 2 * hw + 1;
    for (int j = 0; j < w; j++)
        for (int i = 0; i < w; i++) {
            long x = cx + i - hw, y = cy + j - hw;
            double u = NAN;
            if (x >= 1 && y >= 1 && x <= f->im.nx && y <= f->im.ny) {
                size_t o = (size_t)(y - 1) * f->im.nx + (size_t)(x - 1);
                if (!f->mask[o] && isfinite(img[o]))
                    u = (img[o] - sky) / F;
            }
            v[(size_t)j * w + i] = u;
        }
}

/* The median of x[0..m) (m ≥ 3) into *med, and its error, returned:
 * 1.2533 × 1.4826 MAD / √m, the median of m normal values' (x is left
 * holding the absolute deviations).  The stack's per offset, and the
 * small-stack Monte Carlo's (draw_median), which must read its errors as
 * the stack gives them. */
static double median_error(double *x, size_t m, double *med)
{
    *med = mp_median_select(x, m);
    for (size_t q = 0; q < m; q++)
        x[q] = fabs(x[q] - *med);
    return 1.2533 * 1.4826 * mp_median_select(x, m) / sqrt((double)m);
}

/* The median over the n star images (n × w*w) per offset, and its error
 * (median_error). */
static int stack_combine(const double *im, int n, stack *s)
{
    size_t nel = (size_t)s->w * s->w;
    s->med = malloc(nel * sizeof *s->med);
    s->sig = malloc(nel * sizeof *s->sig);
    if (!s->med || !s->sig)
        return 1;
    int failed = 0;
    /* The offsets in parallel, each its own (the measured table radius
     * was 0.9 % of 47 Tuc built, serial, bench/SCALING.md). */
#pragma omp parallel reduction(| : failed)
    {
        double *col = malloc(((size_t)n + 1) * sizeof *col);
        failed = !col;
#pragma omp for schedule(static)
        for (size_t e = 0; e < nel; e++) {
            if (!col)
                continue;
            size_t m = 0;
            for (int k = 0; k < n; k++)
                if (isfinite(im[(size_t)k * nel + e]))
                    col[m++] = im[(size_t)k * nel + e];
            s->med[e] = s->sig[e] = NAN;
            if (m >= 3)
                s->sig[e] = median_error(col, m, &s->med[e]);
        }
        free(col);
    }
    s->n = n;
    return failed;
}

/* The small-stack Monte Carlo (small_stack_null): draws of one offset's
 * median, rings of such medians and their size, and its seed. */
#define NOISE_NDRAW 4000
#define NOISE_NQUANT 20000
#define NOISE_NRING 400
#define NOISE_RING 64
#define NOISE_SEED 20261205u

/* The median of m draws of N(0, sd[k]²) into *med and its error as the
 * stack gives it (median_error) into *err; x: m values. */
static void draw_median(mp_rng *r, const double *sd, int m, double *x, double *med, double *err)
{
    for (int k = 0; k < m; k++)
        x[k] = sd[k] * mp_rng_normal(r);
    *err = median_error(x, (size_t)m, med);
}

/* Whether the stack's errors understate its medians' scatter for m stars
 * of noise sd[0..m): NOISE_NDRAW medians drawn into med, their sd over
 * the median of their errors (as the ring test reads them, *me) above 1
 * by 3 of its own sampling errors (an sd's from N draws 1/√(2N), a
 * median's 1.2533 × spread/√N).  A large stack's ratio is 1 + ~0.5/m, so
 * this is few stars' case.  err: NOISE_NDRAW values, x: m. */
static int errors_run_low(mp_rng *r, const double *sd, int m, double *med, double *err,
                          double *x, double *me)
{
    double ss = 0.0, se = 0.0, se2 = 0.0;
    for (int d = 0; d < NOISE_NDRAW; d++) {
        draw_median(r, sd, m, x, &med[d], &err[d]);
        ss += med[d] * med[d];
        se += err[d];
        se2 += err[d] * err[d];
    }
    double mean = se / NOISE_NDRAW, spread = sqrt(fmax(se2 / NOISE_NDRAW - mean * mean, 0.0));
    *me = mp_median_select(err, NOISE_NDRAW);
    double f = sqrt(ss / NOISE_NDRAW) / *me;
    double rel = sqrt(0.5 / NOISE_NDRAW + pow(1.2533 * spread / *me, 2) / NOISE_NDRAW);
    return *me > 0 && f > 1.0 + 3.0 * rel * f;
}

/* Over NOISE_NRING rings of NOISE_RING medians of m stars of noise sd,
 * each ring with its own sky errors N(0, skysd[k]²): the spread of the
 * ring's 0.9 quantile without them (*sq) and of what they add to it
 * (*sd0).  ra, rb: NOISE_RING values each; x, y, off: m. */
static void ring_spreads(mp_rng *r, const double *sd, const double *skysd, int m, double *ra,
                         double *rb, double *x, double *y, double *off, double *sq, double *sd0)
{
    double s1 = 0, s2 = 0, d1 = 0, d2 = 0;
    for (int k = 0; k < NOISE_NRING; k++) {
        for (int j = 0; j < m; j++)
            off[j] = skysd[j] * mp_rng_normal(r);
        for (int i = 0; i < NOISE_RING; i++) {
            for (int j = 0; j < m; j++) {
                x[j] = sd[j] * mp_rng_normal(r);
                y[j] = x[j] + off[j];
            }
            ra[i] = mp_median_select(x, (size_t)m);
            rb[i] = mp_median_select(y, (size_t)m);
        }
        double qa = quantile_of(ra, NOISE_RING, 0.9), qb = quantile_of(rb, NOISE_RING, 0.9);
        s1 += qa;
        s2 += qa * qa;
        d1 += qb - qa;
        d2 += (qb - qa) * (qb - qa);
    }
    double qm = s1 / NOISE_NRING, dm = d1 / NOISE_NRING;
    *sq = sqrt(fmax(s2 / NOISE_NRING - qm * qm, 0.0));
    *sd0 = sqrt(fmax(d2 / NOISE_NRING - dm * dm, 0.0));
}

/* What noise alone gives the ring test (mp_epsf_ringnull) for m stars of
 * noise sd[0..m) per unit flux (a sky pixel's) whose skies are off by
 * N(0, skysd[k]²).  Normal theory (MP_EPSF_RING_NORMAL) holds for many
 * stars.  Few break it: their MAD runs low (Croux & Rousseeuw 1992: ×1.36
 * at 4 stars of equal noise), stars of unequal flux give the median
 * heavier tails, each star's sky error moves every offset of its image
 * (an error the ring's values share), and the ring's own median error s,
 * noisy itself, makes z a t-like statistic with heavier tails still.  On
 * the DECam cutout's 4 stars normal theory read noise rings 18–30 px at z
 * up to 4.7 and took the table to the cap, 30 px.  So where the errors
 * run low (errors_run_low), a seeded Monte Carlo sets them, in units of
 * the median error me the draws give: kq from the 0.9 quantile of
 * NOISE_NQUANT medians (the population's, as 1.2816 is), kz and k0 from
 * ring_spreads (kz ×√NOISE_RING), and sfloor = me.
 * tmp: NOISE_NQUANT + NOISE_NDRAW + 3m values. */
static void small_stack_null(const double *sd, const double *skysd, int m, double *tmp,
                             mp_epsf_ringnull *nz)
{
    *nz = MP_EPSF_RING_NORMAL;
    if (m < 3)
        return;
    double *med = tmp, *err = tmp + NOISE_NQUANT, *x = tmp + NOISE_NQUANT + NOISE_NDRAW;
    double *y = x + m, *off = y + m, me, e, sq, sd0;
    mp_rng r;
    mp_rng_seed(&r, NOISE_SEED);
    if (!errors_run_low(&r, sd, m, med, err, x, &me))
        return;
    for (int d = NOISE_NDRAW; d < NOISE_NQUANT; d++)
        draw_median(&r, sd, m, x, &med[d], &e);
    /* err's room, read, for the rings' medians */
    ring_spreads(&r, sd, skysd, m, err, err + NOISE_RING, x, y, off, &sq, &sd0);
    nz->kq = quantile_of(med, NOISE_NQUANT, 0.9) / me;
    nz->kz = sq * sqrt((double)NOISE_RING) / me;
    nz->k0 = sd0 / me;
    nz->sfloor = me;
}

/* One PSF star's image into v (w² elements, w = 2 hw + 1) normalised by
 * its light within ra px: *A that light (NaN: not usable), its sky the
 * median of the ring hw..hw+4 px into *sky over *nsk pixels. */
static void normalised_star(const mp_frame *f, const float *img, double x, double y, int hw,
                            double ra, double *tmp, double *v, double *A, double *sky,
                            size_t *nsk)
{
    int w = 2 * hw + 1;
    long cx = lround(x), cy = lround(y);
    *A = NAN;
    *nsk = 0;
    *sky = tmp ? ring_median(f, img, cx, cy, hw, hw + 4.0, tmp, nsk) : NAN;
    if (!isfinite(*sky))
        return;
    star_image(f, img, cx, cy, *sky, 1.0, hw, v);
    double a = 0.0;
    int bad = 0;
    for (int j = 0; j < w; j++)
        for (int i = 0; i < w; i++)
            if (mp_within(i - hw, j - hw, ra)) {
                double u = v[(size_t)j * w + i];
                bad |= !isfinite(u);
                a += u;
            }
    if (bad || !(a > 0))
        return;
    for (size_t e = 0; e < (size_t)w * w; e++)
        v[e] /= a;
    *A = a;
}

/* The ring test's constants for the stack's ns stars' noise (s->nz): a
 * sky pixel's per unit flux each, and their sky's (the median of nsky
 * pixels).  1 when out of memory. */
static int stack_noise(const mp_frame *f, const double *skies, const double *area,
                       const double *nsky, int ns, stack *s)
{
    double *tmp = malloc((NOISE_NQUANT + NOISE_NDRAW + 5 * (size_t)ns + 1) * sizeof *tmp);
    if (!tmp)
        return 1;
    double *sd = tmp + NOISE_NQUANT + NOISE_NDRAW + 3 * (size_t)ns, *skysd = sd + ns;
    for (int k = 0; k < ns; k++) {
        sd[k] = sqrt(fmax(skies[k], 0.0) + f->rdnoise * f->rdnoise) / area[k];
        skysd[k] = 1.2533 * sd[k] / sqrt(fmax(nsky[k], 1.0));
    }
    small_stack_null(sd, skysd, ns, tmp, &s->nz);
    free(tmp);
    return 0;
}

/* The PSF stars' stack: each normalised by its light within 2 fwhm (its
 * sky the median of the ring hw..hw+4 px). */
static int psf_stack(const mp_frame *f, const float *img, const double *x, const double *y,
                     size_t n, double fwhm, stack *s, double *fbig, double *skymed)
{
    size_t nel = (size_t)s->w * s->w;
    double *im = malloc((n + 1) * nel * sizeof *im), *skies = malloc((n + 1) * sizeof *skies);
    double *area = malloc((n + 1) * sizeof *area), *nsky = malloc((n + 1) * sizeof *nsky);
    int ns = 0, rc = 1, failed = 0;
    *fbig = 0.0;
    if (!im || !skies || !area || !nsky)
        goto done;
    /* Each star into its own slot in parallel (area NaN: not usable),
     * then the usable ones packed in order. */
#pragma omp parallel reduction(| : failed)
    {
        double *tmp = malloc(ring_room(s->hw + 4.0, nel * 4) * sizeof *tmp);
        failed = !tmp;
#pragma omp for schedule(dynamic)
        for (size_t k = 0; k < n; k++) {
            size_t nsk;
            normalised_star(f, img, x[k], y[k], s->hw, 2.0 * fwhm, tmp, im + k * nel, &area[k],
                            &skies[k], &nsk);
            nsky[k] = (double)nsk;
        }
        free(tmp);
    }
    if (failed)
        goto done;
    for (size_t k = 0; k < n; k++)
        if (!isnan(area[k])) {
            if ((size_t)ns != k)
                memcpy(im + (size_t)ns * nel, im + k * nel, nel * sizeof *im);
            *fbig = fmax(*fbig, area[k]);
            area[ns] = area[k];
            nsky[ns] = nsky[k];
            skies[ns++] = skies[k];
        }
    *skymed = ns ? mp_epsf_median(skies, (size_t)ns) : NAN;
    rc = stack_combine(im, ns, s) || stack_noise(f, skies, area, nsky, ns, s);
done:
    free(im);
    free(skies);
    free(area);
    free(nsky);
    return rc;
}

/* The flux of a bright (saturated) star in the PSF stack's units, by its
 * wings: the median over its first four usable 1-px rings (≥ 3/4
 * unmasked, the stack's ring median there > 5 of its errors) of the
 * star's ring median over the stack's.  NaN when none is usable. */
static double wing_flux(const mp_frame *f, const float *img, long cx, long cy, double sky,
                        const stack *p, double *tmp)
{
    double ratio[4];
    int nr = 0;
    double *sv = tmp + (size_t)p->w * p->w * 4;
    for (int r = 2; r < p->hw && nr < 4; r++) {
        size_t m = 0, all = 0, ms = 0;
        double se = 0.0;
        /* the ring's pixels, r ≤ d < r + 1, in its own box and by d²
         * (integers: exact), in the box's order as before */
        int a = p->hw - r - 1 > 0 ? p->hw - r - 1 : 0, b = p->hw + r + 2 < p->w ? p->hw + r + 2 : p->w;
        for (int j = a; j < b; j++)
            for (int i = a; i < b; i++) {
                int d2 = (i - p->hw) * (i - p->hw) + (j - p->hw) * (j - p->hw);
                if (d2 < r * r || d2 >= (r + 1) * (r + 1))
                    continue;
                all++;
                long xx = cx + i - p->hw, yy = cy + j - p->hw;
                size_t e = (size_t)j * p->w + i;
                if (isfinite(p->med[e])) {
                    sv[ms++] = p->med[e];
                    se += p->sig[e] * p->sig[e];
                }
                if (xx < 1 || yy < 1 || xx > f->im.nx || yy > f->im.ny)
                    continue;
                size_t o = (size_t)(yy - 1) * f->im.nx + (size_t)(xx - 1);
                if (!f->mask[o] && isfinite(img[o]))
                    tmp[m++] = img[o] - sky;
            }
        if (4 * m < 3 * all || ms < 8)
            continue;
        double sm = mp_epsf_median(sv, ms), sme = 1.2533 * sqrt(se) / (double)ms;
        if (!(sm > 5.0 * sme))
            continue;
        ratio[nr++] = mp_epsf_median(tmp, m) / sm;
    }
    return nr ? mp_epsf_median(ratio, (size_t)nr) : NAN;
}

/* The largest wing flux of the bright stars (their cores are clipped),
 * and how many had one. */
static int bright_flux(const mp_frame *f, const float *img, const double *x, const double *y,
                       size_t n, const stack *p, double *fbig, int *nb)
{
    size_t nel = (size_t)p->w * p->w;
    int failed = 0, count = 0;
    double big = *fbig;
#pragma omp parallel reduction(| : failed) reduction(+ : count) reduction(max : big)
    {
        double *tmp = malloc(ring_room(p->hw + 4.0, nel * 5) * sizeof *tmp);
        failed = !tmp;
#pragma omp for schedule(dynamic)
        for (size_t k = 0; k < n; k++) {
            if (!tmp)
                continue;
            long cx = lround(x[k]), cy = lround(y[k]);
            double sky = ring_median(f, img, cx, cy, p->hw, p->hw + 4.0, tmp, NULL);
            double F = isfinite(sky) ? wing_flux(f, img, cx, cy, sky, p, tmp) : NAN;
            if (F > 0) {
                big = F > big ? F : big;
                count++;
            }
        }
        free(tmp);
    }
    *fbig = big;
    *nb = count;
    return failed;
}

int mp_epsf_profile_hi(const double *med, const double *sig, int hw, const mp_epsf_ringnull *nz,
                       double *q, double *z)
{
    int w = 2 * hw + 1;
    double *v = malloc((size_t)w * w * sizeof *v), *e = malloc((size_t)w * w * sizeof *e);
    if (!v || !e) {
        free(v);
        free(e);
        return 1;
    }
    for (int r = 0; r <= hw; r++) {
        size_t m = 0;
        /* ring r's elements in its own box, by d² (integers: exact) */
        int a = hw - r - 1 > 0 ? hw - r - 1 : 0, b = hw + r + 2 < w ? hw + r + 2 : w;
        for (int j = a; j < b; j++)
            for (int i = a; i < b; i++) {
                int d2 = (i - hw) * (i - hw) + (j - hw) * (j - hw);
                size_t o = (size_t)j * w + i;
                if (d2 >= r * r && d2 < (r + 1) * (r + 1) && isfinite(med[o]) && isfinite(sig[o])) {
                    v[m] = med[o];
                    e[m++] = sig[o];
                }
            }
        if (m < 8) {
            q[r] = z[r] = NAN;
            continue;
        }
        /* The ring's 0.9 quantile less what noise alone gives it, over
         * that quantile's sampling error for noise alone (nz; normal
         * theory: 1.2816 σ, 1.709 σ/√m). */
        double s = fmax(mp_epsf_median(e, m), nz->sfloor);
        double q9 = quantile_of(v, m, 0.9);
        q[r] = q9 - nz->kq * s;
        double err = nz->k0 > 0 ? s * sqrt(nz->kz * nz->kz / (double)m + nz->k0 * nz->k0)
                                : nz->kz * s / sqrt((double)m);
        z[r] = s > 0 ? q[r] / err : (q[r] > 0 ? INFINITY : 0.0);
    }
    free(v);
    free(e);
    return 0;
}

/* Whether ring r's light, at z or more of its error, reaches the level
 * for a star of flux fmax. */
static int ring_passes(const double *q, const double *z, int r, double zmin, double fmax,
                       double level)
{
    return isfinite(q[r]) && z[r] >= zmin && fmax * q[r] >= level;
}

double mp_epsf_radius_rule(const double *q, const double *z, int nr, double fmax, double level)
{
    int last = nr - 1;
    while (last >= 0 && !ring_passes(q, z, last, MP_EPSF_RADZ, fmax, level))
        last--;
    if (last < 0)
        return 0.0;
    while (last + 1 < nr && ring_passes(q, z, last + 1, MP_EPSF_RADKEEP, fmax, level))
        last++;
    return (double)(last + 1);
}

/* The rule on one stack: the radius, 0 when it has none. */
static int stack_radius(const stack *s, double fmax, double level, double *rad)
{
    *rad = 0.0;
    if (s->n < 3)
        return 0;
    double *q = malloc(((size_t)s->hw + 1) * sizeof *q), *z = malloc(((size_t)s->hw + 1) * sizeof *z);
    int rc = !q || !z || mp_epsf_profile_hi(s->med, s->sig, s->hw, &s->nz, q, z);
    if (!rc)
        *rad = mp_epsf_radius_rule(q, z, s->hw + 1, fmax, level);

    free(q);
    free(z);
    return rc;
}

int mp_epsf_tablerad(const mp_frame *f, const float *img, const double *x, const double *y,
                     size_t n, const double *bx, const double *by, size_t nb,
                     const mp_epsf_radopts *o, mp_epsf_rad *out, char *err)
{
    memset(out, 0, sizeof *out);
    out->rad = o->rdefault;
    stack p = {0};
    p.hw = (int)ceil(o->rmax);
    p.w = 2 * p.hw + 1;
    double fp = 0.0, fb = 0.0, sky = NAN, r = 0.0;
    int rc = psf_stack(f, img, x, y, n, o->fwhm, &p, &fp, &sky) ||
             (p.n >= 3 && bright_flux(f, img, bx, by, nb, &p, &fb, &out->nbright));
    if (!rc) {
        out->npsf = p.n;
        out->fmax = fmax(fp, fb);
        out->level = o->frac * sqrt(fmax(sky, 0.0) + f->rdnoise * f->rdnoise);
        rc = stack_radius(&p, out->fmax, out->level, &r);
    }
    if (rc) {
        snprintf(err, MP_ERRLEN, "psf build: out of memory");
    } else if (p.n < 3) {
        snprintf(out->why, sizeof out->why, "tablerad %.1f px (%d PSF stars to measure it: "
                 "too few, the default)", out->rad, p.n);
    } else {
        out->rad = fmin(fmax(r, o->rmin), o->rmax);
        out->reach = r;
        snprintf(out->why, sizeof out->why,
                 "tablerad %.1f px (PSF light per pixel, 0.9 quantile over azimuth of %d PSF "
                 "stars, measured (z >= %.2f, then the rings after at z >= %.0f%s) and above "
                 "%.2g sigma of a sky pixel for the brightest star (%.3g e- within 2 fwhm%s): "
                 "to %.0f px; within %.1f..%.1f px)",
                 out->rad, p.n, MP_EPSF_RADZ, MP_EPSF_RADKEEP,
                 p.nz.sfloor > 0 ? "; the stack's noise by Monte Carlo" : "", o->frac,
                 out->fmax, fb > fp ? ", by its wings" : "", r, o->rmin, o->rmax);
    }
    stack_free(&p);
    return rc;
}
