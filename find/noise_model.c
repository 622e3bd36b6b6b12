/* noise_model.c — mp_bkg_noise_from_model (find.h): the noise map of a
 * fit's residual from the Poisson model of the fitted frame. */
#include "find/find.h"
#include "find/find_priv.h"

#include <math.h>
#include <stdlib.h>
#include <string.h>

/* The q-quantile (0..1, nearest rank) of v[0..n-1], n > 0 (reorders v). */
static double quantile_of(double *v, size_t n, double q)
{
    size_t i = (size_t)(q * (double)(n - 1) + 0.5);
    return mp_select_kth(v, n, i < n ? i : n - 1);
}

/* Poisson variance [e-²] of pixel i of sky level sky: sky + stars + RON²
 * (the sky given: the map's spline is read once a pixel). */
static double poisson_var(const mp_frame *f, const float *res, size_t i, double sky)
{
    return mpf_nonneg(sky) + mpf_nonneg(f->im.pix[i] - res[i]) + f->rdnoise * f->rdnoise;
}

/* A kernel tap's terms at pixel q of sky level sky: the residual less
 * the sky d (in single precision), the Poisson variance v, the stars'
 * light m and whether the pixel is usable. */
typedef struct {
    float d;
    double v, m;
    int ok;
} tap_terms;

static tap_terms pixel_terms(const mp_frame *f, const float *res, size_t q, float sky)
{
    double v = poisson_var(f, res, q, sky);
    return (tap_terms){res[q] - sky, v, mpf_nonneg(f->im.pix[q] - res[q]),
                       !f->mask[q] && v > 0 && isfinite(res[q])};
}

/* The sampled pixels, as residual r (sky removed), Poisson variance p and
 * star model m. */
typedef struct {
    double *r, *p, *m, *z;
    size_t n;
} samples;

/* A kernel tap's terms at each pixel of the 2·nh + 1 rows a footprint
 * spans, kept as a thread's samples move down the frame: the residual
 * less the sky d, the Poisson variance v, the stars' light m and whether
 * the pixel is usable ok, each formed once a pixel (its row's sky from
 * one spline evaluation of the row, mp_bkg_rows), not once per footprint
 * it falls in (~n/2 of them, every other pixel a sample: noise_scale
 * 319 -> 154·10⁶ instructions on a 512² frame, where it was 15 % of the
 * run with the PSF given).  It pays where the samples are
 * dense: every row is formed whole, npix pixels, against nsel·taps (a
 * 4096² frame's 2·10⁵ samples are 84 px apart).  sky NULL: each tap
 * forms its own (kernel_sample), as it does at the frame's edges. */
typedef struct {
    float *sky, *d;
    double *v, *m;
    unsigned char *ok;
    long *y;
    long nrow, nx;
} pixel_rows;

/* Row y's slot of c, its pixels' terms (pixel_terms, as kernel_sample's
 * own taps form them) formed there when not yet. */
static size_t pixel_row(const mp_bkg *b, const mp_frame *f, const float *res, pixel_rows *c,
                        long y)
{
    size_t slot = (size_t)(y % c->nrow), o = slot * (size_t)c->nx;
    if (c->y[slot] == y)
        return o;
    float *sky = c->sky + o;
    mp_bkg_rows(b, y, y + 1, sky, NULL);
    size_t q0 = (size_t)y * (size_t)c->nx;
    for (long x = 0; x < c->nx; x++) {
        tap_terms p = pixel_terms(f, res, q0 + (size_t)x, sky[x]);
        c->d[o + (size_t)x] = p.d;
        c->v[o + (size_t)x] = p.v;
        c->m[o + (size_t)x] = p.m;
        c->ok[o + (size_t)x] = (unsigned char)p.ok;
    }
    c->y[slot] = y;
    return o;
}

static void pixel_rows_free(pixel_rows *c)
{
    free(c->sky);
    free(c->d);
    free(c->v);
    free(c->m);
    free(c->ok);
    free(c->y);
    c->sky = NULL;
}

/* Room for the rows of a kernel of half-width nh on a frame nx wide
 * when use; c->sky NULL when not, or when there is none (the taps then
 * form their own). */
static void pixel_rows_init(pixel_rows *c, int nh, long nx, int use)
{
    memset(c, 0, sizeof *c);
    c->nrow = 2L * nh + 1;
    c->nx = nx;
    if (!use)
        return;
    size_t n = (size_t)c->nrow * (size_t)nx;
    c->sky = malloc(n * sizeof *c->sky);
    c->d = malloc(n * sizeof *c->d);
    c->v = malloc(n * sizeof *c->v);
    c->m = malloc(n * sizeof *c->m);
    c->ok = malloc(n);
    c->y = malloc((size_t)c->nrow * sizeof *c->y);
    if (!c->sky || !c->d || !c->v || !c->m || !c->ok || !c->y) {
        pixel_rows_free(c);
        return;
    }
    for (long r = 0; r < c->nrow; r++)
        c->y[r] = -1;
}

/* kernel_sample of a footprint inside the frame from c's rows: every
 * tap's terms summed, ok when all are usable (where one is not, the
 * sample is dropped, its sums unread: the same samples as the taps' own
 * loop, which stops there). */
static void inner_sample(const mp_bkg *b, const mp_frame *f, const float *res,
                         const mpf_kernel *k, pixel_rows *c, long x0, long y0, samples *s,
                         size_t j)
{
    size_t row[2 * 64 + 1];
    for (int d = -k->nh; d <= k->nh; d++)
        row[d + k->nh] = pixel_row(b, f, res, c, y0 + d) + (size_t)x0;
    double h = 0.0, vh = 0.0, sp = 0.0, sm = 0.0;
    unsigned char ok = 1;
    for (int t = 0; t < k->n; t++) {
        size_t o = row[k->dy[t] + k->nh] + (size_t)(long)k->dx[t];
        double v = c->v[o];
        ok &= c->ok[o];
        h += k->kl[t] * c->d[o];
        vh += k->kl[t] * k->kl[t] * v;
        sp += v;
        sm += c->m[o];
    }
    s->r[j] = h;
    s->p[j] = ok ? vh : -1.0;
    s->m[j] = ok ? sm / sqrt(sp) : 0.0;
}

/* Pixel (x, y) = (i mod nx, i / nx) as sample j of s through the
 * detection kernel k: r its amplitude h = Σ kl·(residual − sky) there,
 * p h's Poisson variance Σ kl²·v, m the stars' light over its noise in
 * the footprint; p = −1 where the footprint leaves the frame or holds a
 * masked or unusable pixel.  A footprint inside the frame from c's rows
 * (inner_sample), else each tap's own terms (mp_bkg_sky: the values of
 * mp_bkg_rows, bit for bit). */
static void kernel_sample(const mp_bkg *b, const mp_frame *f, const float *res,
                          const mpf_kernel *k, pixel_rows *c, size_t i, samples *s, size_t j)
{
    long nx = f->im.nx, ny = f->im.ny, x0 = (long)(i % (size_t)nx), y0 = (long)(i / (size_t)nx);
    if (c->sky && k->nh <= 64 && x0 >= k->nh && x0 + k->nh < nx && y0 >= k->nh &&
        y0 + k->nh < ny) {
        inner_sample(b, f, res, k, c, x0, y0, s, j);
        return;
    }
    double h = 0.0, vh = 0.0, sp = 0.0, sm = 0.0;
    int ok = 1;
    for (int t = 0; ok && t < k->n; t++) {
        long x = x0 + k->dx[t], y = y0 + k->dy[t];
        ok = x >= 0 && x < nx && y >= 0 && y < ny;
        if (!ok)
            break;
        size_t q = (size_t)y * (size_t)nx + (size_t)x;
        tap_terms p = pixel_terms(f, res, q, mp_bkg_sky(b, q));
        ok = p.ok;
        h += k->kl[t] * p.d;
        vh += k->kl[t] * k->kl[t] * p.v;
        sp += p.v;
        sm += p.m;
    }
    s->r[j] = h;
    s->p[j] = ok ? vh : -1.0;
    s->m[j] = ok ? sm / sqrt(sp) : 0.0;   /* star light over its noise */
}

/* Pixel i as sample j of s when the stars' light there is above 3
 * k-scaled σ (else p = −1). */
static void star_sample(const mp_bkg *b, const mp_frame *f, const float *res, size_t i, double k,
                        samples *s, size_t j)
{
    tap_terms p = pixel_terms(f, res, i, mp_bkg_sky(b, i));
    int ok = p.ok && p.m * p.m > 9.0 * k * k * p.v;
    s->r[j] = ok ? p.d : 0.0;
    s->p[j] = ok ? p.v : -1.0;
    s->m[j] = p.m;
}

/* The usable samples of the first n (p ≥ 0) moved to the front, in
 * order; their count. */
static size_t compact(samples *s, size_t n)
{
    size_t kept = 0;
    for (size_t i = 0; i < n; i++)
        if (s->p[i] >= 0) {
            s->r[kept] = s->r[i];
            s->p[kept] = s->p[i];
            s->m[kept++] = s->m[i];
        }
    return kept;
}

/* Robust σ of r/sqrt(k²p + ε²m²) over the samples. */
static double normalised_sigma(samples *s, double k, double eps)
{
#pragma omp parallel for schedule(static) if (s->n > 10000)
    for (size_t i = 0; i < s->n; i++)
        s->z[i] = s->r[i] / sqrt(k * k * s->p[i] + eps * eps * s->m[i] * s->m[i]);
    return mp_mad_sigma(s->z, s->n);   /* robust to the stars not yet found */
}

/* k from the detection kernel's amplitude at every step-th pixel where
 * the stars' light in its footprint is below its Poisson noise (a profile
 * error cannot show there); all holds room for cap samples.  The
 * amplitude is what detection thresholds, so k describes the noise as
 * detection sees it: noise correlated between neighbouring pixels
 * (resampled mosaics) counts as the kernel weighs it; structure smoother
 * than the kernel (a sky the local fits leave, the crowd's unresolved
 * light) does not, as the lowered kernel sums to zero (47 Tuc's core:
 * 3×3 block sums, which see that structure, read 6.5, the kernel 1.4).
 * NaN with fewer than 10 usable samples. */
static double noise_scale(const mp_bkg *b, const mp_frame *f, const float *res,
                          const mpf_kernel *k, size_t step, samples *all, size_t cap)
{
    size_t npix = (size_t)f->im.nx * (size_t)f->im.ny;
    size_t nsel = (npix + step - 1) / step;
    if (nsel > cap)
        nsel = cap;
    /* Every step-th pixel into its own slot, in parallel; the unusable
     * ones (p < 0) then dropped in order, so the samples do not depend on
     * the threads. */
#pragma omp parallel
    {
        pixel_rows c;
        pixel_rows_init(&c, k->nh, f->im.nx, npix < nsel * (size_t)k->n);
#pragma omp for schedule(static)
        for (size_t j = 0; j < nsel; j++)
            kernel_sample(b, f, res, k, &c, j * step, all, j);
        pixel_rows_free(&c);
    }
    all->n = compact(all, nsel);
    /* The samples whose star light is below its noise; in a field so
     * crowded that fewer than a quarter are, the quarter with the least
     * (47 Tuc's core: star light everywhere). */
    if (all->n >= 10) {
        memcpy(all->z, all->m, all->n * sizeof *all->z);
        double q25 = quantile_of(all->z, all->n, 0.25), cut = q25 > 1.0 ? q25 : 1.0;
        size_t kept = 0;
        for (size_t i = 0; i < all->n; i++)
            if (all->m[i] <= cut) {
                all->r[kept] = all->r[i];
                all->p[kept] = all->p[i];
                all->m[kept++] = 0.0;
            }
        all->n = kept;
    }
    return all->n >= 10 ? normalised_sigma(all, 1.0, 0.0) : NAN;
}

/* ε: the profile error (DAOPHOT's proferr, here measured) that makes the
 * normalised residual's robust σ 1 where the stars' light dominates (the
 * star samples); 0 for an exact PSF.  Only a significant excess counts:
 * the robust σ's own sampling error is 1.166/√n (3 of them: false alarm
 * ~1e-3). */
static double profile_error(samples *star, double k)
{
    if (!(k > 0) || !isfinite(k) || star->n < 10 ||
        !(normalised_sigma(star, k, 0.0) > 1.0 + 3.0 * 1.166 / sqrt((double)star->n)))
        return 0.0;
    double lo = 0.0, hi = 1.0;
    if (normalised_sigma(star, k, hi) > 1.0)
        lo = hi;                       /* worse than 100 %: cap */
    for (int it = 0; it < 30 && hi - lo > 1e-4; it++) {
        double mid = 0.5 * (lo + hi);
        if (normalised_sigma(star, k, mid) > 1.0)
            lo = mid;
        else
            hi = mid;
    }
    return 0.5 * (lo + hi);
}

/* b's rms taken from the model (k, eps) from now on: no map, each pixel's
 * noise formed where it is used (find.h). */
static void adopt_model(mp_bkg *b, const mp_frame *f, const float *res, double k, double eps)
{
    b->model = 1;
    b->k = k;
    b->eps = eps;
    b->ron2 = f->rdnoise * f->rdnoise;
    b->pix = f->im.pix;
    b->res = res;
    /* The mesh rms rows (the second half of vals) are no longer read:
     * given back (issue 14: 16 bytes a pixel / mesh, 8.4 MB at 4096²). */
    double *v = realloc(b->vals, 2 * (size_t)b->ny * (size_t)b->nbx * sizeof *v);
    if (v)
        b->vals = v;
}

int mp_bkg_noise_from_model(mp_bkg *b, const mp_frame *f, const float *res, double fwhm,
                            double nsigma, double *scale, double *proferr, char *err)
{
    *scale = NAN;
    *proferr = 0.0;
    size_t npix = (size_t)f->im.nx * (size_t)f->im.ny;
    mpf_kernel kern;
    if (mpf_kernel_make(fwhm, nsigma, 0, &kern, err))
        return 1;
    /* A regular subsample keeps the sorts cheap on large frames; 2·10⁵
     * pixels pin k to ~0.3 % (the MAD's relative error 1.166/√n). */
    size_t step = npix / 200000 + 1, cap = npix / step + 1;
    samples all = {0}, star = {0};
    double *buf = malloc(4 * cap * sizeof *buf);
    if (!buf) {
        mpf_kernel_free(&kern);
        snprintf(err, MP_ERRLEN, "out of memory for the residual noise map");
        return 1;
    }
    /* The star samples are drawn once k is known: the same room. */
    all.r = buf, all.p = buf + cap, all.m = buf + 2 * cap, all.z = buf + 3 * cap;
    star.r = all.r, star.p = all.p, star.m = all.m, star.z = all.z;
    double k = noise_scale(b, f, res, &kern, step, &all, cap);
    /* Those where the stars' light is above 3 k-scaled σ measure ε (where
     * a profile error shows, above the noise that k describes). */
    size_t nstar = k > 0 ? (npix + step - 1) / step : 0;
#pragma omp parallel for schedule(static)
    for (size_t j = 0; j < nstar; j++)
        star_sample(b, f, res, j * step, k, &star, j);
    star.n = compact(&star, nstar);
    double eps = profile_error(&star, k);
    if (k > 0 && isfinite(k)) {
        *scale = k;
        *proferr = eps;
        adopt_model(b, f, res, k, eps);
    }
    free(buf);
    mpf_kernel_free(&kern);
    return 0;
}
