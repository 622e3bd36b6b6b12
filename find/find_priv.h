/*
 * find_priv.h — what the files of find/ share among themselves (not for
 * other folders: they call find/find.h).
 */
#ifndef MATPHOT_FIND_PRIV_H
#define MATPHOT_FIND_PRIV_H

#include <math.h>
#include <stddef.h>
#include <stdint.h>

#include "find/find.h"

/* ---- mesh_stats.c --------------------------------------------------------- */

/* mpf_mesh_stats: sort the finite values v[0..n) in place and return
 * SExtractor's clipped mode and the clipped rms divided by shrink
 * (mpf_clip_shrink(3)); work holds 2n; nonzero when n == 0. */
int mpf_mesh_stats(double *v, size_t n, double shrink, uint64_t *work, double *mode,
                   double *rms);

/* mpf_clip_shrink: the factor by which iterated ±k·σ clipping about the
 * median shrinks the σ of Gaussian noise at convergence (0.9846 for k = 3). */
double mpf_clip_shrink(double k);

/* mpf_median_small: median of v[0..n) (n ≥ 1), sorting v in place. */
double mpf_median_small(double *v, size_t n);

/* ---- spline.c ------------------------------------------------------------- */

/* mpf_spline_init: second derivatives d2[0..n) of the natural cubic spline
 * through (x[i], y[i]), x strictly increasing; work holds n doubles.  With
 * n ≤ 2 the spline is the constant or the line through the points. */
void mpf_spline_init(const double *x, const double *y, int n, double *d2, double *work);

/* mpf_spline_eval: the spline at t; continued linearly (with its end
 * slope) outside [x[0], x[n-1]].  *k is an interval hint (start at 0): a
 * sequence of increasing t costs O(n + count) in all. */
double mpf_spline_eval(const double *x, const double *y, const double *d2, int n,
                       double t, int *k);

/* mpf_spline_row: out[t] = the spline at t = 0, 1, …, count − 1, in
 * single precision, clamped at ≥ 0 when clamp0 (a map's values). */
void mpf_spline_row(const double *x, const double *y, const double *d2, int n,
                    float *out, long count, int clamp0);

/* Values mp_bkg_star_excess keeps a star: x, y, F², class, reach². */
#define MP_BKG_XS 5

/* mp_bkg_excess_span: the variance b's flux-squared model error adds
 * (mp_bkg_star_excess; star_excess.c) at pixels [x0, x1) of row y
 * (0-based), into v[0 .. x1 − x0): every star of the nine cells around
 * a pixel's, each visiting only the pixels its reach covers on the row
 * (a pixel at a time, testing every star of the nine cells at every
 * pixel, was 5.6 % of a 1024² simulated frame's run). */
void mp_bkg_excess_span(const mp_bkg *b, long y, long x0, long x1, double *v);

/* mp_bkg_white_var: the part of pixel i's variance (its sky given) that
 * is independent from pixel to pixel: k²·(sky + M + RON²) of the
 * residual's noise model (bkg_eval.c rms_with), all of it for a mesh map.
 * The rest of rms² is the model's own error (ε²M², the stars'
 * flux-squared error), smooth over a star's few pixels. */
double mp_bkg_white_var(const mp_bkg *b, size_t i, float sky);

/* mpf_spline_at: out[t] of mpf_spline_row for one t, bit for bit. */
float mpf_spline_at(const double *x, const double *y, const double *d2, int n, long t,
                    int clamp0);

/* ---- kernel.c ------------------------------------------------------------- */

/* Largest kernel box half-width [pixel]. */
#define MPF_MAX_HALF 256

/* The DAOFIND kernel: taps (dx[t], dy[t]) with r ≤ radius, in raster
 * order, Gaussian values g[t]; over the full footprint its mean gbar and
 * denom = Σ (g − gbar)², and the lowered, normalised weights
 * kl[t] = (g[t] − gbar)/denom; relerr = 1/sqrt(denom).  With known set
 * (the sky map is the sky itself, mp_find_opts.sky_known) the kernel is
 * not lowered: gbar = 0, denom = Σ g², kl[t] = g[t]/denom, the
 * least-squares amplitude of a Gaussian star with no constant beside it. */
typedef struct {
    double sigma, radius;
    int nh;                  /* box half-width: floor(radius) */
    int n;                   /* taps */
    int known;               /* not lowered: the sky is known */
    int *dx, *dy;
    double *g, *kl;
    double gbar, denom, relerr;
    double klsum;            /* Σ |kl[t]|: h's roundoff per unit error of the sky */
    int nmin;                /* good taps a footprint needs: ceil(n/2) */
} mpf_kernel;

/* mpf_kernel_make: the kernel of a Gaussian of fwhm [px] out to nsigma σ
 * (at least 2 px), lowered unless known.  Errors: fwhm or nsigma not
 * positive, a kernel wider than MPF_MAX_HALF, out of memory. */
int mpf_kernel_make(double fwhm, double nsigma, int known, mpf_kernel *k, char *err);
void mpf_kernel_free(mpf_kernel *k);

/* mpf_kernel_response: Σ_t w[t]·P_t with P the pixel-integrated Gaussian
 * of unit flux and the kernel's σ centred at (ox, oy) from the central
 * pixel's centre; w = kl (or the footprint's own lowered weights). */
double mpf_kernel_response(const mpf_kernel *k, const double *w, double ox, double oy);

/* One footprint on a frame: which taps are usable. */
typedef struct {
    int ngood;               /* taps inside the image and not MP_MASK_BAD */
    int edge, masked, sat;   /* some tap outside / bad / saturated */
    double gbar, denom;      /* of the good taps (denom 0 when < 2 good) */
} mpf_foot;

/* mpf_footprint: the footprint of the kernel centred on pixel (px, py)
 * (0-based); when w is not NULL, w[t] receives the kernel's weights over
 * the good taps ((g − gbar)/denom, lowered unless k->known; 0 for
 * unusable taps). */
void mpf_footprint(const mp_frame *f, const mpf_kernel *k, long px, long py,
                   mpf_foot *fp, double *w);

/* ---- convolve.c ----------------------------------------------------------- */

/* Value of h where the footprint has too few good pixels. */
#define MPF_NO_H (-HUGE_VAL)

/* mpf_convolve_rows: h of the rows [y0, y1) (the kernel's amplitude of
 * the background-subtracted frame, MPF_NO_H where undefined) into
 * h[(y − y0)·nx + x]; sky holds the sky map's rows from s0 (row y at
 * sky + (y − s0)·nx), at least [y0 − nh, y1 + nh) within the image; bad:
 * mpf_any_bad(f).  A row's h depends on nothing else, so a frame done in
 * strips of rows equals one done whole, bit for bit. */
int mpf_convolve_rows(const mp_frame *f, const float *sky, long s0, const mpf_kernel *k,
                      int bad, long y0, long y1, float *h, char *err);

/* mpf_any_bad: does f hold a pixel bad for detection (mpf_bad)? */
int mpf_any_bad(const mp_frame *f);

/* Rows of a detection strip (mp_find_stars): the strips' working set is
 * about (3·MPF_STRIP + 8·nh) rows of 4 bytes a pixel, not the frame's
 * 4 bytes a pixel (issue 14). */
#define MPF_STRIP 128

/* mpf_find_stars_strips: mp_find_stars in strips of `strip` rows (≥ 1);
 * *work (when not NULL) receives the bytes of its largest working set
 * beside the table (the strips' buffers, the candidates, the measures). */
int mpf_find_stars_strips(const mp_frame *f, const mp_bkg *b, const mp_find_opts *o,
                          long strip, mp_table *t, size_t *work, char *err);

/* ---- centroid.c ----------------------------------------------------------- */

typedef struct {
    double x, y;             /* 1-based centroid */
    double flux_max, background, sharp, round, flux;
    int flags;
    int ok;                  /* passed the fits (shape cuts not yet applied) */
    double snr;              /* a sieve's (mp_find_opts.sieve), else NaN */
    double sharp_sd;         /* σ of sharp from the pixels' noise (find.h step 6) */
} mpf_star;

/* mpf_sieve: stars[n0..*n-1] (and their keys) offered to o->sieve (none:
 * nothing done), the kept moved down in order, *n their new end; nonzero
 * when out of memory (sieve.c). */
int mpf_sieve(const mp_find_opts *o, mpf_star *stars, long *keys, size_t n0, size_t *n);

/* mpf_measure: centroid, sharpness, roundness and fluxes of the candidate
 * at pixel (px, py) (0-based) whose convolved height is h; w is scratch of
 * k->n doubles. */
void mpf_measure(const mp_frame *f, const mp_bkg *b, const mpf_kernel *k,
                 long px, long py, double h, double *w, mpf_star *s);

/* mpf_measure_plateau: a saturated star from the pixels idx[0..n) of one
 * connected saturated region. */
void mpf_measure_plateau(const mp_frame *f, const mp_bkg *b, const mpf_kernel *k,
                         const long *idx, size_t n, mpf_star *s);

/* Bad for detection: MP_MASK_BAD, or not a finite number in a frame built
 * without a mask (saturated pixels keep their values). */
static inline int mpf_bad(const mp_frame *f, size_t i)
{
    return (f->mask && (f->mask[i] & MP_MASK_BAD)) || !isfinite(f->im.pix[i]);
}

static inline int mpf_sat(const mp_frame *f, size_t i)
{
    return f->mask && (f->mask[i] & MP_MASK_SATURATED) && !mpf_bad(f, i);
}

/* mpf_nonneg: fmax(x, 0.0) as glibc returns it (x when x >= 0, −0 kept;
 * 0 for a negative or NaN x), inline: the noise model's calls to libm's
 * fmax were 0.5 % of frame B built's instructions. */
static inline double mpf_nonneg(double x)
{
    return x >= 0.0 ? x : 0.0;
}

#endif
