/* star_fwhm.c — the FWHM of a frame's stars, measured on the brightest
 * lone detections (mp_epsf_stars_fwhm, build.h): what a DAOPHOT user reads
 * off imexam before setting fwhmpsf, and PSFEx off SExtractor's
 * FWHM_IMAGE.  Each star is fitted alone with a pixel-integrated Gaussian
 * (psf=gauss's model, psf/table.c) and a flat sky by Levenberg–Marquardt;
 * the start is the star's half-maximum width read off the pixels, so the
 * measure does not lean on the fwhm it is to check. */
#include <lapacke.h>
#include <math.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include "psf/build_priv.h"

#define NPAR 5              /* flux, x, y, sigma, sky */
#define TRIED 400           /* candidates looked at, brightest first */
#define WALK 100            /* the half-maximum walk's reach [px] */
#define RMAX 60             /* the fit window's radius at most [px] */
#define LONE 0.1            /* a detection within the window brighter than
                             * this of the star's flux spoils it */

static double pix(const mp_frame *f, long i, long j)
{
    return (double)f->im.pix[(size_t)(j - 1) * (size_t)f->im.nx + (size_t)(i - 1)];
}

static int usable(const mp_frame *f, long i, long j)
{
    return i >= 1 && j >= 1 && i <= f->im.nx && j <= f->im.ny &&
           !f->mask[(size_t)(j - 1) * (size_t)f->im.nx + (size_t)(i - 1)];
}

/* From (*i, *j) uphill to a local maximum of usable pixels (a detection
 * of a wide kernel may lie a few pixels off its star's peak).  0 when
 * one is reached within WALK steps. */
static int climb(const mp_frame *f, long *i, long *j)
{
    if (!usable(f, *i, *j))
        return 1;
    for (int step = 0; step < WALK; step++) {
        long bi = *i, bj = *j;
        for (long dj = -1; dj <= 1; dj++)
            for (long di = -1; di <= 1; di++)
                if (usable(f, *i + di, *j + dj) && pix(f, *i + di, *j + dj) > pix(f, bi, bj))
                    bi = *i + di, bj = *j + dj;
        if (bi == *i && bj == *j)
            return 0;
        *i = bi, *j = bj;
    }
    return 1;
}

/* Half the peak's height above sky reached from (i, j) along (di, dj):
 * the distance [px], interpolated between pixels; −1 when a masked pixel
 * or the frame's edge comes first. */
static double half_reach(const mp_frame *f, long i, long j, int di, int dj, double sky)
{
    double half = 0.5 * (pix(f, i, j) - sky), prev = 2.0 * half;
    for (int k = 1; k <= WALK; k++) {
        if (!usable(f, i + k * di, j + k * dj))
            return -1.0;
        double v = pix(f, i + k * di, j + k * dj) - sky;
        if (v <= half)
            return (k - 1) + (prev - half) / (prev - v);
        prev = v;
    }
    return -1.0;
}

/* The star's half-maximum width [px] at its peak (i, j) above sky: the
 * mean of its two diameters along the axes, into *w0.  Nonzero when a
 * walk meets a masked pixel or the frame's edge first. */
static int half_width(const mp_frame *f, long i, long j, double sky, double *w0)
{
    double r[4] = {half_reach(f, i, j, 1, 0, sky), half_reach(f, i, j, -1, 0, sky),
                   half_reach(f, i, j, 0, 1, sky), half_reach(f, i, j, 0, -1, sky)};
    if (r[0] < 0 || r[1] < 0 || r[2] < 0 || r[3] < 0)
        return 1;
    *w0 = 0.5 * (r[0] + r[1] + r[2] + r[3]);
    return 0;
}

/* The fit window's radius for a star of half-maximum width w0: twice
 * it, 3 px at least. */
static long window_radius(double w0)
{
    return (long)ceil(fmax(3.0, 2.0 * w0));
}

/* The pixel-integrated unit Gaussian along one axis at pixel i (centre
 * x, σ s): g, and its derivatives by x and by s. */
static void gauss_pixel(long i, double x, double s, double *g, double *gx, double *gs)
{
    double up = (i + 0.5 - x) / s, lo = (i - 0.5 - x) / s;
    double pu = exp(-0.5 * up * up) / sqrt(2.0 * M_PI), pl = exp(-0.5 * lo * lo) / sqrt(2.0 * M_PI);
    *g = 0.5 * (erf(up / M_SQRT2) - erf(lo / M_SQRT2));
    *gx = -(pu - pl) / s;
    *gs = -(up * pu - lo * pl) / s;
}

#define MAXNB 64            /* fainter detections masked in a window at most */

/* One star's window: pixels [x0, x1] × [y0, y1], less discs of radius
 * rnb around the fainter detections in it (their light would widen the
 * star: frame C, FWHM 3.03 for 3.00 with them). */
typedef struct {
    const mp_frame *f;
    long x0, x1, y0, y1;
    int nnb;
    double nbx[MAXNB], nby[MAXNB], rnb;
} window;

static int in_window(const window *w, long i, long j)
{
    if (!usable(w->f, i, j))
        return 0;
    for (int k = 0; k < w->nnb; k++)
        if (mp_within((double)i - w->nbx[k], (double)j - w->nby[k], w->rnb))
            return 0;
    return 1;
}

/* χ² of p on the window, and when a is not NULL its normal equations
 * (a: NPAR² row-major, b: NPAR), each pixel weighted by its Poisson and
 * read noise from the data. */
static double normal_eq(const window *w, const double *p, double *a, double *b)
{
    double chi2 = 0.0, ron2 = w->f->rdnoise * w->f->rdnoise;
    if (a) {
        memset(a, 0, NPAR * NPAR * sizeof *a);
        memset(b, 0, NPAR * sizeof *b);
    }
    double gx[2 * RMAX + 1], gxx[2 * RMAX + 1], gxs[2 * RMAX + 1];
    for (long i = w->x0; i <= w->x1; i++)
        gauss_pixel(i, p[1], p[3], &gx[i - w->x0], &gxx[i - w->x0], &gxs[i - w->x0]);
    for (long j = w->y0; j <= w->y1; j++) {
        double gy, gyy, gys;
        gauss_pixel(j, p[2], p[3], &gy, &gyy, &gys);
        for (long i = w->x0; i <= w->x1; i++) {
            if (!in_window(w, i, j))
                continue;
            long u0 = i - w->x0;
            double d = pix(w->f, i, j);
            double r = d - (p[0] * gx[u0] * gy + p[4]), wt = 1.0 / (fmax(d, 0.0) + ron2 + 1.0);
            chi2 += wt * r * r;
            if (!a)
                continue;
            double J[NPAR] = {gx[u0] * gy, p[0] * gxx[u0] * gy, p[0] * gx[u0] * gyy,
                              p[0] * (gxs[u0] * gy + gx[u0] * gys), 1.0};
            for (int u = 0; u < NPAR; u++) {
                b[u] += wt * J[u] * r;
                for (int v = 0; v <= u; v++)
                    a[u * NPAR + v] += wt * J[u] * J[v];
            }
        }
    }
    return chi2;
}

/* Levenberg–Marquardt from p; 0 with p the fit when it converged with a
 * positive flux and σ within the window. */
static int fit_star(const window *w, double *p)
{
    double a[NPAR * NPAR], b[NPAR], m[NPAR * NPAR], q[NPAR], lambda = 1e-3;
    double chi2 = normal_eq(w, p, a, b);
    for (int it = 0; it < 100; it++) {
        memcpy(m, a, sizeof m);
        memcpy(q, b, sizeof q);
        for (int u = 0; u < NPAR; u++)
            m[u * NPAR + u] *= 1.0 + lambda;
        if (LAPACKE_dposv(LAPACK_ROW_MAJOR, 'L', NPAR, 1, m, NPAR, q, 1) != 0)
            return 1;
        double t[NPAR];
        for (int u = 0; u < NPAR; u++)
            t[u] = p[u] + q[u];
        double c = t[3] > 0.05 && t[0] > 0 ? normal_eq(w, t, NULL, NULL) : INFINITY;
        if (c <= chi2) {
            int small = fabs(q[3]) < 1e-6 * p[3] && fabs(q[1]) < 1e-5 && fabs(q[2]) < 1e-5;
            memcpy(p, t, sizeof t);
            chi2 = normal_eq(w, p, a, b);
            lambda = fmax(lambda * 0.1, 1e-9);
            if (small)
                return !(p[3] < 0.5 * (double)(w->x1 - w->x0));
        } else if ((lambda *= 10.0) > 1e9) {
            return 1;
        }
    }
    return 1;
}

/* The star at peak (i, j) fitted on w from its half-maximum width w0,
 * flux F0 and sky: p = (flux, x, y, σ, sky); fit_star's verdict. */
static int fit_from(const window *w, long i, long j, double w0, double F0, double sky,
                    double *p)
{
    p[0] = F0, p[1] = (double)i, p[2] = (double)j;
    p[3] = fmax(w0, 0.5) / 2.3548200450309493, p[4] = sky;
    return fit_star(w, p);
}

/* The table's columns this reads (−1: absent). */
typedef struct { int x, y, f, b, g; } cols;

/* Row q's star alone in w: no other detection of at least LONE of its
 * flux within the window's radius r, none within rnb of it, and at most
 * MAXNB fainter ones, which go into w's masked discs. */
static int lone(const mp_table *t, const cols *k, size_t q, double r, window *w)
{
    double x = mp_table_get(t, q, k->x), y = mp_table_get(t, q, k->y);
    double F = mp_table_get(t, q, k->f);
    w->nnb = 0;
    for (size_t o = 0; o < t->nrow; o++) {
        double dx = mp_table_get(t, o, k->x) - x, dy = mp_table_get(t, o, k->y) - y;
        if (o == q || !mp_within(dx, dy, r + w->rnb))
            continue;
        if ((mp_within(dx, dy, r) && mp_table_get(t, o, k->f) >= LONE * F) ||
            mp_within(dx, dy, w->rnb) || w->nnb == MAXNB)
            return 0;
        w->nbx[w->nnb] = x + dx, w->nby[w->nnb] = y + dy, w->nnb++;
    }
    return 1;
}

/* The star of row q measured: its Gaussian σ into *sigma.  0 when it is
 * a lone, unmasked star whose fit converged. */
static int measure_row(const mp_frame *f, const mp_table *t, const cols *k, size_t q,
                       double *sigma)
{
    double x = mp_table_get(t, q, k->x), y = mp_table_get(t, q, k->y);
    double sky = k->b >= 0 ? mp_table_get(t, q, k->b) : NAN;
    long i = lround(x), j = lround(y);
    if (!isfinite(x) || !isfinite(y) || !isfinite(sky) || climb(f, &i, &j))
        return 1;
    double w0, p[NPAR];
    if (half_width(f, i, j, sky, &w0))
        return 1;
    long R = window_radius(w0);
    window w = {f, i - R, i + R, j - R, j + R, 0, {0}, {0}, fmax(w0, 1.5)};
    if (R > RMAX || !lone(t, k, q, (double)R, &w))
        return 1;
    if (w.x0 < 1 || w.y0 < 1 || w.x1 > f->im.nx || w.y1 > f->im.ny)
        return 1;
    double s0 = fmax(w0, 0.5) / 2.3548200450309493;
    if (fit_from(&w, i, j, w0, (pix(f, i, j) - sky) * 2.0 * M_PI * (s0 * s0 + 1.0 / 12.0), sky,
                 p))
        return 1;
    /* S/N ≥ 20 by its fit, as a PSF star's (select.c): a fainter peak's
     * width is noise (the DECam cutout: widths of 0.1–2 px among its
     * stars' 3.6–4.3 from the detections of S/N 3–10). */
    double ron2 = f->rdnoise * f->rdnoise;
    double beta = 4.0 * M_PI * (p[3] * p[3] + 1.0 / 12.0);
    if (!(p[0] / sqrt(p[0] + beta * (fmax(p[4], 0.0) + ron2)) >= 20.0))
        return 1;
    *sigma = p[3];
    return 0;
}

static int ascending(const void *a, const void *b)
{
    double x = *(const double *)a, y = *(const double *)b;
    return (x > y) - (x < y);
}

/* The half-sample mode of v[0..n), sorted here (Bickel & Frühwirth
 * 2006): the densest half, then its densest half, down to two or three
 * values.  Light a star's window holds beyond its own only widens it, so
 * the widths lean to one side (frame C: median 3.03 for 3.00, the mode
 * 3.00), and their mode is the stars' width. */
static double half_sample_mode(double *v, size_t n)
{
    qsort(v, n, sizeof *v, ascending);
    size_t lo = 0;
    while (n > 3) {
        size_t h = (n + 1) / 2, best = lo;
        for (size_t i = lo; i + h <= lo + n; i++)
            if (v[i + h - 1] - v[i] < v[best + h - 1] - v[best])
                best = i;
        lo = best, n = h;
    }
    if (n == 3) {
        double a = v[lo + 1] - v[lo], b = v[lo + 2] - v[lo + 1];
        return a < b   ? 0.5 * (v[lo] + v[lo + 1])
               : a > b ? 0.5 * (v[lo + 1] + v[lo + 2])
                       : v[lo + 1];
    }
    return n == 2 ? 0.5 * (v[lo] + v[lo + 1]) : v[lo];
}

/* The mode's error: the standard deviation of the mode of 200 bootstrap
 * resamples of v[0..n) (a fixed-seed generator: the same frame, the same
 * error); b: scratch of n. */
static double mode_error(const double *v, size_t n, double *b)
{
    uint64_t r = 0x9E3779B97F4A7C15u;
    double s1 = 0.0, s2 = 0.0;
    const int NBOOT = 200;
    for (int k = 0; k < NBOOT; k++) {
        for (size_t q = 0; q < n; q++) {
            r = r * 6364136223846793005u + 1442695040888963407u;
            b[q] = v[(r >> 33) % n];
        }
        double m = half_sample_mode(b, n);
        s1 += m, s2 += m * m;
    }
    s1 /= NBOOT;
    return sqrt(fmax(s2 / NBOOT - s1 * s1, 0.0));
}

static int by_flux(const void *a, const void *b)
{
    double x = ((const double *)a)[0], y = ((const double *)b)[0];
    return (x < y) - (x > y);
}

int mp_epsf_stars_fwhm(const mp_frame *f, const mp_table *t, int nmax, mp_stars_fwhm *out,
                       char *err)
{
    memset(out, 0, sizeof *out);
    cols k = {mp_table_col(t, "X_IMAGE"), mp_table_col(t, "Y_IMAGE"), mp_table_col(t, "FLUX"),
              mp_table_col(t, "BACKGROUND"), mp_table_col(t, "FLAGS")};
    if (k.x < 0 || k.y < 0 || k.f < 0 || k.b < 0) {
        snprintf(err, MP_ERRLEN, "stars' FWHM: the star table needs X_IMAGE, Y_IMAGE, FLUX, "
                 "BACKGROUND");
        return 1;
    }
    double *order = malloc((2 * t->nrow + 2) * sizeof *order);   /* (flux, row) pairs */
    double *w = malloc((2 * (size_t)nmax + 2) * sizeof *w);    /* widths, then scratch */
    if (!order || !w) {
        free(order);
        free(w);
        snprintf(err, MP_ERRLEN, "stars' FWHM: out of memory");
        return 1;
    }
    size_t m = 0;
    for (size_t q = 0; q < t->nrow; q++) {
        double F = mp_table_get(t, q, k.f), g = k.g >= 0 ? mp_table_get(t, q, k.g) : 0.0;
        if (F > 0 && !(isfinite(g) && g != 0.0))
            order[2 * m] = F, order[2 * m + 1] = (double)q, m++;
    }
    qsort(order, m, 2 * sizeof *order, by_flux);
    int n = 0;
    for (size_t c = 0; c < m && c < TRIED && n < nmax; c++) {
        double s;
        if (!measure_row(f, t, &k, (size_t)order[2 * c + 1], &s))
            w[n++] = 2.3548200450309493 * s;
    }
    out->n = n;
    if (n > 0) {
        out->err = n > 1 ? mode_error(w, (size_t)n, w + n) : INFINITY;
        out->fwhm = half_sample_mode(w, (size_t)n);
    }
    free(order);
    free(w);
    return 0;
}

int mp_epsf_model_fwhm(const mp_prf_model *m, double x, double y, double *fwhm, char *err)
{
    /* A noiseless star of 1e6 e- on a sky of 0 (read noise 1 e-: the
     * weights the stars' fits give) at four subpixel phases; the window
     * twice the half-maximum width the first render shows, as a star's. */
    enum { HW = RMAX, SIDE = 2 * RMAX + 1 };
    const double E = 1e6;
    float *pix = malloc((size_t)SIDE * SIDE * sizeof *pix);
    uint8_t *mask = calloc((size_t)SIDE * SIDE, 1);
    double *prf = malloc((size_t)SIDE * SIDE * sizeof *prf);
    mp_prf_work wk;
    memset(&wk, 0, sizeof wk);
    int rc = !pix || !mask || !prf, n = 0;
    double sum = 0.0;
    if (rc)
        snprintf(err, MP_ERRLEN, "the PSF's FWHM: out of memory");
    mp_frame f;
    memset(&f, 0, sizeof f);
    f.im.nx = f.im.ny = SIDE, f.im.pix = pix, f.mask = mask, f.rdnoise = 1.0, f.gain = 1.0;
    long wx0 = lround(x) - HW, wy0 = lround(y) - HW;    /* the window's pixel (1, 1) */
    for (int ph = 0; !rc && ph < 4; ph++) {
        long x0, y0;
        int pw, phh;
        memset(pix, 0, (size_t)SIDE * SIDE * sizeof *pix);
        if (mp_prf_render_window(m, x + 0.5 * (ph & 1), y + 0.5 * (ph >> 1), wx0, wy0, SIDE, SIDE,
                                 &x0, &y0, &pw, &phh, prf, NULL, NULL, &wk)) {
            snprintf(err, MP_ERRLEN, "the PSF's FWHM: no render at (%g, %g)", x, y);
            rc = 1;
            break;
        }
        for (int v = 0; v < phh; v++)
            for (int u = 0; u < pw; u++)
                pix[(size_t)(y0 - wy0 + v) * SIDE + (size_t)(x0 - wx0 + u)] =
                    (float)(E * prf[v * pw + u]);
        long i = HW + 1, j = HW + 1;
        double w0, p[NPAR];
        if (climb(&f, &i, &j) || half_width(&f, i, j, 0.0, &w0))
            continue;
        long R = window_radius(w0);
        window w = {&f, i - R, i + R, j - R, j + R, 0, {0}, {0}, 1.0};
        if (R <= HW && !fit_from(&w, i, j, w0, E, 0.0, p))
            sum += 2.3548200450309493 * p[3], n++;
    }
    mp_prf_work_free(&wk);
    free(pix);
    free(mask);
    free(prf);
    if (!rc && n == 0) {
        snprintf(err, MP_ERRLEN, "the PSF's FWHM: no Gaussian fits its core within %d px", HW);
        rc = 1;
    }
    *fwhm = rc ? NAN : sum / n;
    return rc;
}

int mp_epsf_stars_fwhm_kernel(const mp_frame *f, const mp_bkg *b, const mp_find_opts *fo,
                              double kernel, int nmax, mp_stars_fwhm *m, char *err)
{
    mp_find_opts o = *fo;
    o.fwhm = kernel;
    o.sharplo = o.sharphi = o.roundlo = o.roundhi = NAN;
    mp_table t;
    mp_table_init(&t);
    int rc = mp_find_stars(f, b, &o, &t, err) || mp_epsf_stars_fwhm(f, &t, nmax, m, err);
    mp_table_free(&t);
    return rc;
}

int mp_epsf_frame_fwhm(const mp_frame *f, const mp_bkg *b, const mp_find_opts *fo,
                       const char *image, mp_stars_fwhm *m, char *err)
{
    static const double kernels[] = {3.0, 12.0, 48.0};
    memset(m, 0, sizeof *m);
    int rc = 0;
    for (size_t k = 0; !rc && m->n < MP_EPSF_FWHM_NEED && k < sizeof kernels / sizeof *kernels; k++)
        rc = mp_epsf_stars_fwhm_kernel(f, b, fo, kernels[k], MP_EPSF_FWHM_STARS, m, err);
    if (!rc && m->n < MP_EPSF_FWHM_NEED) {
        snprintf(err, MP_ERRLEN, "fwhm: INDEF, and %s has too few stars to measure it (%d lone "
                 "stars of S/N >= 20, %d needed): give fwhm", image, m->n, MP_EPSF_FWHM_NEED);
        rc = 1;
    }
    return rc;
}

int mp_epsf_stars_fwhm_found(const mp_frame *f, const mp_bkg *b, const mp_find_opts *fo,
                             const mp_table *t, int nmax, mp_stars_fwhm *m, char *err)
{
    int rc = mp_epsf_stars_fwhm(f, t, nmax, m, err);
    for (double k = 0.25 * fo->fwhm; !rc && m->n < MP_EPSF_FWHM_NEED && k >= 1.0; k *= 0.25)
        rc = mp_epsf_stars_fwhm_kernel(f, b, fo, k, nmax, m, err);
    return rc;
}

int mp_epsf_fwhm_off(const mp_stars_fwhm *m, double fwhm)
{
    return m->n >= MP_EPSF_FWHM_NEED && fabs(fwhm - m->fwhm) > 3.0 * m->err;
}
