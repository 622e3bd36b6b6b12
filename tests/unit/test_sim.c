/* test_sim.c — sim/: the generator against its reference vectors, the
 * distributions against theory, and star rendering against exact sums.
 *
 * Statistical checks use fixed seeds and tolerances of Z_TOL standard
 * errors of the statistic for the sample size used; with Z_TOL = 5 a
 * correct generator fails such a check with probability 5.7e-7 per check
 * (two-sided normal tail), i.e. never in practice, while the bounds are
 * still tight enough to catch a wrong mean or variance at the 1e-3 level. */
#include <math.h>
#include <setjmp.h>
#include <stdarg.h>
#include <stddef.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/stat.h>
#include <unistd.h>

#include <cmocka.h>

#include "catalog/catalog.h"
#include "io/io.h"
#include "sim/sim.h"

#define Z_TOL 5.0
#define NSAMP 1000000
static const double PI = 3.14159265358979323846;

/* ---------- generator ---------- */

static void test_xoshiro_reference(void **state)
{
    (void)state;
    /* Outputs of the authors' xoshiro256** for the state {1, 2, 3, 4}. */
    mp_rng r = {{1, 2, 3, 4}};
    assert_true(mp_rng_next(&r) == 11520u);
    assert_true(mp_rng_next(&r) == 0u);
    assert_true(mp_rng_next(&r) == 1509978240u);
    /* splitmix64 from 0: its well-known first output seeds s[0]. */
    mp_rng_seed(&r, 0);
    assert_true(r.s[0] == 0xe220a8397b1dcdafULL);
}

static void test_seed_reproducible(void **state)
{
    (void)state;
    mp_rng a, b, c;
    mp_rng_seed(&a, 42);
    mp_rng_seed(&b, 42);
    mp_rng_seed(&c, 43);
    int same = 1, differ = 0;
    for (int i = 0; i < 100; i++) {
        uint64_t x = mp_rng_next(&a), y = mp_rng_next(&b), z = mp_rng_next(&c);
        same &= x == y;
        differ += x != z;
    }
    assert_true(same);
    assert_true(differ > 95);
}

static void test_uniform(void **state)
{
    (void)state;
    mp_rng r;
    mp_rng_seed(&r, 1);
    double s = 0, s2 = 0, lo = 1, hi = 0;
    for (int i = 0; i < NSAMP; i++) {
        double u = mp_rng_uniform(&r);
        s += u;
        s2 += u * u;
        lo = fmin(lo, u);
        hi = fmax(hi, u);
    }
    assert_true(lo >= 0.0 && hi < 1.0);
    double mean = s / NSAMP, var = s2 / NSAMP - mean * mean;
    /* sd(mean) = sqrt(1/12/N); sd(var) = sqrt((1/80 - 1/144)/N). */
    assert_true(fabs(mean - 0.5) < Z_TOL * sqrt(1.0 / 12 / NSAMP));
    assert_true(fabs(var - 1.0 / 12) < Z_TOL * sqrt((1.0 / 80 - 1.0 / 144) / NSAMP));
}

static void test_normal_moments(void **state)
{
    (void)state;
    mp_rng r;
    mp_rng_seed(&r, 2);
    double m1 = 0, m2 = 0, m3 = 0, m4 = 0;
    for (int i = 0; i < NSAMP; i++) {
        double z = mp_rng_normal(&r);
        m1 += z;
        m2 += z * z;
        m3 += z * z * z;
        m4 += z * z * z * z;
    }
    m1 /= NSAMP; m2 /= NSAMP; m3 /= NSAMP; m4 /= NSAMP;
    /* Standard errors for N(0,1): mean 1/√N, E[z²] √(2/N), E[z³] √(15/N),
     * E[z⁴] √(96/N). */
    double n = NSAMP;
    assert_true(fabs(m1) < Z_TOL * sqrt(1 / n));
    assert_true(fabs(m2 - 1) < Z_TOL * sqrt(2 / n));
    assert_true(fabs(m3) < Z_TOL * sqrt(15 / n));
    assert_true(fabs(m4 - 3) < Z_TOL * sqrt(96 / n));
}

/* ---------- Poisson ---------- */

/* Sample mean and variance of n deviates; the deviates must be integers. */
static void poisson_moments(double mu, uint64_t seed, int n, double *mean, double *var)
{
    mp_rng r;
    mp_rng_seed(&r, seed);
    double s = 0, s2 = 0;
    int integral = 1;
    for (int i = 0; i < n; i++) {
        double k = mp_rng_poisson(&r, mu);
        integral &= k >= 0 && k == floor(k);
        /* Centre on mu so the sums keep their precision at large means. */
        s += k - mu;
        s2 += (k - mu) * (k - mu);
    }
    assert_true(integral);
    *mean = mu + s / n;
    *var = s2 / n - (s / n) * (s / n);
}

static void check_poisson_mean_var(double mu)
{
    double mean, var;
    poisson_moments(mu, 1000 + (uint64_t)mu, NSAMP, &mean, &var);
    /* Poisson: sd(mean) = √(μ/N); sd(var) = √((μ + 2μ²)/N) since the
     * fourth central moment is μ(1 + 3μ). */
    double n = NSAMP;
    double tm = Z_TOL * sqrt(mu / n), tv = Z_TOL * sqrt((mu + 2 * mu * mu) / n);
    if (fabs(mean - mu) >= tm || fabs(var - mu) >= tv)
        print_error("mu %g: mean %.6g (tol %.3g) var %.6g (tol %.3g)\n", mu, mean, tm, var, tv);
    assert_true(fabs(mean - mu) < tm);
    assert_true(fabs(var - mu) < tv);
}

static void test_poisson_moments(void **state)
{
    (void)state;
    /* 0.5 and 5: inversion; 50 and 5000: PTRS; 9.99/10: either side of
     * the switch; 1e7: PTRS far out. */
    const double mus[] = {0.5, 5, 9.99, 10, 50, 5000, 1e7};
    for (size_t i = 0; i < sizeof mus / sizeof mus[0]; i++)
        check_poisson_mean_var(mus[i]);
}

static void test_poisson_edge_means(void **state)
{
    (void)state;
    mp_rng r;
    mp_rng_seed(&r, 3);
    assert_true(mp_rng_poisson(&r, 0) == 0);
    assert_true(mp_rng_poisson(&r, -4) == 0);
    assert_true(isnan(mp_rng_poisson(&r, NAN)));
}

/* Upper 1e-6 quantile of χ²(df) by Wilson–Hilferty (z = 4.753). */
static double chi2_crit(int df)
{
    double a = 2.0 / (9.0 * df);
    return df * pow(1 - a + 4.753 * sqrt(a), 3);
}

/* χ² goodness of fit of N deviates to the Poisson(μ) pmf, with bins
 * k = 0..kmax-1 holding at least 20 expected counts and one tail bin. */
static void check_poisson_chi2(double mu, uint64_t seed)
{
    enum { KMAX = 200 };
    double expct[KMAX + 1];
    long count[KMAX + 1] = {0};
    int kmax = 0;
    for (int k = 0; k < KMAX; k++) {
        double p = exp(k * log(mu) - mu - lgamma(k + 1.0));
        /* Start binning once counts are large enough; the low tail below
         * that is merged into the first bin. */
        expct[k] = p * NSAMP;
        if (k > mu && expct[k] < 20) {
            kmax = k;
            break;
        }
    }
    assert_true(kmax > 0);
    int klo = 0;
    while (expct[klo] < 20) klo++;
    mp_rng r;
    mp_rng_seed(&r, seed);
    for (int i = 0; i < NSAMP; i++) {
        int k = (int)mp_rng_poisson(&r, mu);
        count[k < klo ? klo : (k >= kmax ? kmax : k)]++;
    }
    double below = 0;
    for (int k = 0; k < klo; k++)
        below += expct[k];
    expct[klo] += below;
    double inside = 0;
    for (int k = klo; k < kmax; k++)
        inside += expct[k];
    expct[kmax] = NSAMP - inside;
    double chi2 = 0;
    for (int k = klo; k <= kmax; k++)
        chi2 += (count[k] - expct[k]) * (count[k] - expct[k]) / expct[k];
    int df = kmax - klo;      /* bins − 1 */
    if (chi2 >= chi2_crit(df))
        print_error("mu %g: chi2 %.2f on %d dof (limit %.2f)\n", mu, chi2, df, chi2_crit(df));
    assert_true(chi2 < chi2_crit(df));
}

static void test_poisson_chi2(void **state)
{
    (void)state;
    check_poisson_chi2(0.5, 11);   /* inversion */
    check_poisson_chi2(3.0, 12);   /* inversion */
    check_poisson_chi2(10.0, 13);  /* PTRS at its lowest mean */
    check_poisson_chi2(12.5, 14);  /* PTRS: rejection step exercised */
    check_poisson_chi2(60.0, 15);
}

/* ---------- Gaussian stars ---------- */

static const double FWHM_TO_SIGMA = 0.42466090014400952;   /* 1/(2√(2 ln 2)) */

/* ∫ N(t; c, σ) over [a, b] (reference, written independently of render.c). */
static double gint(double a, double b, double c, double sigma)
{
    return 0.5 * (erf((b - c) / (sigma * sqrt(2.0))) - erf((a - c) / (sigma * sqrt(2.0))));
}

static double sum_image(const double *img, long n)
{
    double s = 0;
    for (long i = 0; i < n; i++)
        s += img[i];
    return s;
}

static void test_gauss_sum_is_flux(void **state)
{
    (void)state;
    enum { NX = 60, NY = 60 };
    double *img = calloc(NX * NY, sizeof *img);
    assert_non_null(img);
    mp_sim_prf p = {.kind = MP_SIM_GAUSS, .sigma = 3.0 * FWHM_TO_SIGMA, .volume = 1.0};
    assert_int_equal(mp_sim_add_star(&p, 30.37, 29.81, 1e6, img, NX, NY), 0);
    assert_true(fabs(sum_image(img, NX * NY) - 1e6) < 1e-9 * 1e6);
    /* The peak pixel is the one holding the centre. */
    long best = 0;
    for (long i = 1; i < NX * NY; i++)
        if (img[i] > img[best]) best = i;
    assert_int_equal(best, (30 - 1) * NX + (30 - 1));
    /* Volume scales the light. */
    memset(img, 0, NX * NY * sizeof *img);
    p.volume = 1.0 / 9;
    assert_int_equal(mp_sim_add_star(&p, 30.37, 29.81, 9e6, img, NX, NY), 0);
    assert_true(fabs(sum_image(img, NX * NY) - 1e6) < 1e-9 * 1e6);
    free(img);
}

static void test_gauss_vs_midpoint(void **state)
{
    (void)state;
    /* Brute force: midpoint rule on an M×M grid per pixel.  Its error per
     * axis is ≤ (h²/24)·|f'(b) − f'(a)| ≤ h²·0.0202/σ² of the flux, so
     * with h = 1/M = 0.01 and σ = 1.27 the 2-D error is below 3e-6. */
    enum { NX = 15, NY = 15, M = 100 };
    const double sigma = 3.0 * FWHM_TO_SIGMA, x0 = 8.23, y0 = 7.61;
    double img[NX * NY] = {0};
    mp_sim_prf p = {.kind = MP_SIM_GAUSS, .sigma = sigma, .volume = 1.0};
    assert_int_equal(mp_sim_add_star(&p, x0, y0, 1.0, img, NX, NY), 0);
    double worst = 0;
    for (int py = 5; py <= 11; py++)
        for (int px = 5; px <= 11; px++) {
            double s = 0;
            for (int j = 0; j < M; j++)
                for (int i = 0; i < M; i++) {
                    double x = px - 0.5 + (i + 0.5) / M, y = py - 0.5 + (j + 0.5) / M;
                    double r2 = ((x - x0) * (x - x0) + (y - y0) * (y - y0)) / (sigma * sigma);
                    s += exp(-0.5 * r2);
                }
            s /= 2 * PI * sigma * sigma * M * M;
            worst = fmax(worst, fabs(s - img[(py - 1) * NX + px - 1]));
        }
    assert_true(worst < 3e-6);
}

static void test_gauss_drf(void **state)
{
    (void)state;
    enum { NX = 40, NY = 40 };
    double img[NX * NY];
    const double sigma = 1.5 * FWHM_TO_SIGMA, x0 = 20.3, y0 = 19.6;
    /* A uniform DRF of 0.5 halves the light. */
    const double half[4] = {0.5, 0.5, 0.5, 0.5};
    mp_sim_prf p = {.kind = MP_SIM_GAUSS, .sigma = sigma, .drf = half, .dk = 2, .volume = 1};
    memset(img, 0, sizeof img);
    assert_int_equal(mp_sim_add_star(&p, x0, y0, 1000.0, img, NX, NY), 0);
    assert_true(fabs(sum_image(img, NX * NY) - 500.0) < 1e-9 * 1000);
    /* Only subpixel (0,0) — low x, low y — is live: each pixel holds the
     * light of its lower-left quarter. */
    const double corner[4] = {1, 0, 0, 0};
    p.drf = corner;
    memset(img, 0, sizeof img);
    assert_int_equal(mp_sim_add_star(&p, x0, y0, 1.0, img, NX, NY), 0);
    double worst = 0;
    for (int py = 17; py <= 23; py++)
        for (int px = 17; px <= 23; px++) {
            double ref = gint(px - 0.5, px, x0, sigma) * gint(py - 0.5, py, y0, sigma);
            worst = fmax(worst, fabs(ref - img[(py - 1) * NX + px - 1]));
        }
    assert_true(worst < 1e-14);
    /* A 3×3 DRF with only the centre live sees the middle ninth. */
    const double mid[9] = {0, 0, 0, 0, 1, 0, 0, 0, 0};
    p.drf = mid;
    p.dk = 3;
    memset(img, 0, sizeof img);
    assert_int_equal(mp_sim_add_star(&p, x0, y0, 1.0, img, NX, NY), 0);
    double ref = gint(20 - 1.0 / 6, 20 + 1.0 / 6, x0, sigma) * gint(20 - 1.0 / 6, 20 + 1.0 / 6, y0, sigma);
    assert_true(fabs(img[19 * NX + 19] - ref) < 1e-14);
}

static void test_gauss_edges(void **state)
{
    (void)state;
    enum { NX = 20, NY = 20 };
    double img[NX * NY] = {0};
    mp_sim_prf p = {.kind = MP_SIM_GAUSS, .sigma = 1.0, .volume = 1};
    /* Centred on the corner of the image: a quarter of the light lands. */
    assert_int_equal(mp_sim_add_star(&p, 0.5, 0.5, 4.0, img, NX, NY), 0);
    assert_true(fabs(sum_image(img, NX * NY) - 1.0) < 1e-12);
    /* Far outside: nothing, and no error. */
    assert_int_equal(mp_sim_add_star(&p, -1e6, 5, 1.0, img, NX, NY), 0);
    assert_int_equal(mp_sim_add_star(&p, 5, 1e9, 1.0, img, NX, NY), 0);
    assert_true(fabs(sum_image(img, NX * NY) - 1.0) < 1e-12);
    /* Invalid PRFs are refused. */
    p.sigma = 0;
    assert_int_not_equal(mp_sim_add_star(&p, 5, 5, 1.0, img, NX, NY), 0);
    p.sigma = 1;
    assert_int_not_equal(mp_sim_add_star(&p, NAN, 5, 1.0, img, NX, NY), 0);
}

/* ---------- table stars ---------- */

static double *random_table(int n, uint64_t seed)
{
    double *t = malloc((size_t)n * n * sizeof *t);
    assert_non_null(t);
    mp_rng r;
    mp_rng_seed(&r, seed);
    for (int i = 0; i < n * n; i++)
        t[i] = mp_rng_uniform(&r) * 1e-3;
    return t;
}

static void test_snap(void **state)
{
    (void)state;
    mp_sim_prf g = {.kind = MP_SIM_GAUSS, .sigma = 1, .volume = 1};
    double x = 3.21, y = 4.56;
    mp_sim_snap(&g, &x, &y);
    assert_true(x == 3.21 && y == 4.56);

    double tab[9] = {0};
    mp_sim_prf p = {.kind = MP_SIM_TABLE, .tab = tab, .tnx = 3, .tny = 3, .volume = 1};
    /* Allowed positions: ½ + (m + ½)/tos. */
    struct { int tos; double in, out; } cases[] = {
        {1, 30.4, 30.0}, {1, 30.6, 31.0}, {2, 30.1, 30.25}, {2, 29.9, 29.75},
        {2, 30.0, 30.25}, {3, 30.2, 30 + 1.0 / 3}, {3, 30.1, 30.0}, {4, 30.0, 30.125},
        {4, 30.3, 30.375}, {5, 30.05, 30.0}, {5, 30.15, 30.2},
    };
    for (size_t i = 0; i < sizeof cases / sizeof cases[0]; i++) {
        p.tos = cases[i].tos;
        x = cases[i].in;
        y = cases[i].in;
        mp_sim_snap(&p, &x, &y);
        assert_true(fabs(x - cases[i].out) < 1e-12 && fabs(y - cases[i].out) < 1e-12);
        /* Snapped: drawable, and snapping again changes nothing. */
        double img[64 * 64] = {0};
        assert_int_equal(mp_sim_add_star(&p, x, y, 1, img, 64, 64), 0);
        double x2 = x, y2 = y;
        mp_sim_snap(&p, &x2, &y2);
        assert_true(x2 == x && y2 == y);
        /* Off the grid by 1e-6: refused. */
        assert_int_not_equal(mp_sim_add_star(&p, x + 1e-6, y, 1, img, 64, 64), 0);
    }
}

static void test_table_block_sum(void **state)
{
    (void)state;
    enum { NX = 60, NY = 60, T = 21 };
    double *tab = random_table(T, 5), tsum = 0;
    for (int i = 0; i < T * T; i++)
        tsum += tab[i];
    double *img = calloc(NX * NY, sizeof *img);
    assert_non_null(img);
    mp_sim_prf p = {.kind = MP_SIM_TABLE, .tab = tab, .tnx = T, .tny = T, .tos = 2,
                    .volume = 0.7};
    /* X = 30.25: the central element (10) is the upper half of pixel 30,
     * element 9 its lower half.  Y = 29.75: element 10 is the lower half of
     * pixel 30, element 11 its upper half. */
    assert_int_equal(mp_sim_add_star(&p, 30.25, 29.75, 2.0, img, NX, NY), 0);
    assert_true(fabs(sum_image(img, NX * NY) - 2.0 * 0.7 * tsum) < 1e-12 * tsum);
    double pix = 2.0 * 0.7 * (tab[10 * T + 9] + tab[10 * T + 10] + tab[11 * T + 9] + tab[11 * T + 10]);
    assert_true(fabs(img[29 * NX + 29] - pix) < 1e-15);

    /* tos = 1 at an integer position: the table itself, element for pixel. */
    memset(img, 0, NX * NY * sizeof *img);
    p.tos = 1;
    p.volume = 1;
    assert_int_equal(mp_sim_add_star(&p, 20, 33, 1.0, img, NX, NY), 0);
    for (int j = 0; j < T; j++)
        for (int i = 0; i < T; i++)
            assert_true(img[(33 - 10 + j - 1) * NX + (20 - 10 + i - 1)] == tab[j * T + i]);

    /* A uniform DRF of 0.5 halves the light; a DRF not dividing OVERSAMP
     * and an even table are refused. */
    const double half[4] = {0.5, 0.5, 0.5, 0.5};
    p.tos = 4;
    p.drf = half;
    p.dk = 2;
    memset(img, 0, NX * NY * sizeof *img);
    assert_int_equal(mp_sim_add_star(&p, 30.125, 30.375, 1.0, img, NX, NY), 0);
    assert_true(fabs(sum_image(img, NX * NY) - 0.5 * tsum) < 1e-12 * tsum);
    p.dk = 3;
    const double nine[9] = {0};
    p.drf = nine;
    assert_int_not_equal(mp_sim_add_star(&p, 30.125, 30.375, 1.0, img, NX, NY), 0);
    p.drf = NULL;
    p.tnx = 20;
    assert_int_not_equal(mp_sim_add_star(&p, 30.125, 30.375, 1.0, img, NX, NY), 0);
    free(img);
    free(tab);
}

static void test_table_drf_weighting(void **state)
{
    (void)state;
    /* tos = 4, dk = 2: fine elements s = 0,1 of a pixel fall in DRF
     * subpixel 0, s = 2,3 in subpixel 1.  A DRF live only at (1,0) (high
     * x, low y) keeps, in each pixel, the elements with s_x ≥ 2, s_y < 2. */
    enum { NX = 30, NY = 30, T = 13 };
    double *tab = random_table(T, 9);
    const double drf[4] = {0, 1, 0, 0};
    mp_sim_prf p = {.kind = MP_SIM_TABLE, .tab = tab, .tnx = T, .tny = T, .tos = 4,
                    .drf = drf, .dk = 2, .volume = 1};
    double *img = calloc(NX * NY, sizeof *img);
    assert_non_null(img);
    /* X = 15.125: m = X·4 − 2.5 = 58; central element 6 at fine index 58
     * (pixel 15, s = 2), so element i is at fine index 52 + i. */
    const double x = 15.125, y = 15.125;
    assert_int_equal(mp_sim_add_star(&p, x, y, 1.0, img, NX, NY), 0);
    for (int py = 13; py <= 17; py++)
        for (int px = 13; px <= 17; px++) {
            double ref = 0;
            for (int j = 0; j < T; j++)
                for (int i = 0; i < T; i++) {
                    int gx = 52 + i, gy = 52 + j;
                    if (gx / 4 + 1 != px || gy / 4 + 1 != py)
                        continue;
                    if (gx % 4 >= 2 && gy % 4 < 2)
                        ref += tab[j * T + i];
                }
            assert_true(fabs(img[(py - 1) * NX + px - 1] - ref) < 1e-15);
        }
    free(img);
    free(tab);
}

/* A table made by integrating the Gaussian over its fine elements, block
 * summed at an on-grid position, is the directly integrated Gaussian star:
 * the two modes of the simulator agree. */
static void test_table_matches_gauss(void **state)
{
    (void)state;
    enum { NX = 40, NY = 40, TOS = 3, T = 3 * 24 + 1 };
    const double sigma = 2.0 * FWHM_TO_SIGMA;
    double *tab = malloc(T * T * sizeof *tab);
    assert_non_null(tab);
    const int c = (T - 1) / 2;
    for (int j = 0; j < T; j++)
        for (int i = 0; i < T; i++)
            tab[j * T + i] = gint((i - c - 0.5) / TOS, (i - c + 0.5) / TOS, 0, sigma) *
                             gint((j - c - 0.5) / TOS, (j - c + 0.5) / TOS, 0, sigma);
    const double drf[9] = {0.9, 0.8, 0.7, 1.0, 0.95, 0.6, 0.5, 0.85, 0.75};
    mp_sim_prf pt = {.kind = MP_SIM_TABLE, .tab = tab, .tnx = T, .tny = T, .tos = TOS,
                     .drf = drf, .dk = 3, .volume = 1};
    mp_sim_prf pg = {.kind = MP_SIM_GAUSS, .sigma = sigma, .drf = drf, .dk = 3, .volume = 1};
    double x = 20.3, y = 19.4;
    mp_sim_snap(&pt, &x, &y);
    double *a = calloc(NX * NY, sizeof *a), *b = calloc(NX * NY, sizeof *b);
    assert_non_null(a);
    assert_non_null(b);
    assert_int_equal(mp_sim_add_star(&pt, x, y, 1000.0, a, NX, NY), 0);
    assert_int_equal(mp_sim_add_star(&pg, x, y, 1000.0, b, NX, NY), 0);
    double worst = 0;
    for (int i = 0; i < NX * NY; i++)
        worst = fmax(worst, fabs(a[i] - b[i]));
    /* The table reaches 12 px = 14σ; the Gaussian mode's 8σ window drops
     * ~3e-15 of the light, so the two agree far below 1e-10. */
    assert_true(worst < 1e-10);
    free(a);
    free(b);
    free(tab);
}

/* ---------- noise ---------- */

static void test_add_noise(void **state)
{
    (void)state;
    const long n = NSAMP;
    double *img = malloc((size_t)n * sizeof *img);
    assert_non_null(img);
    for (long i = 0; i < n; i++)
        img[i] = 100.0;
    mp_rng r;
    mp_rng_seed(&r, 21);
    mp_sim_add_noise(&r, img, n, 3.0);
    double s = 0, s2 = 0;
    for (long i = 0; i < n; i++) {
        s += img[i] - 100;
        s2 += (img[i] - 100) * (img[i] - 100);
    }
    double mean = 100 + s / n, var = s2 / n - (s / n) * (s / n);
    /* Poisson(100) + N(0, 9): variance 109, fourth central moment
     * μ(1+3μ) + 6μ·9 + 3·81 = 35743, so sd(var) = √((35743 − 109²)/N). */
    assert_true(fabs(mean - 100) < Z_TOL * sqrt(109.0 / n));
    assert_true(fabs(var - 109) < Z_TOL * sqrt((35743.0 - 109.0 * 109.0) / n));

    /* Without read noise: integer photon counts; m <= 0 gives none. */
    double small[4] = {0.5, 0.0, -3.0, 7.25};
    mp_sim_add_noise(&r, small, 4, 0.0);
    for (int i = 0; i < 4; i++)
        assert_true(small[i] >= 0 && small[i] == floor(small[i]));
    assert_true(small[1] == 0 && small[2] == 0);
    free(img);
}

/* ---------- the task ---------- */

static int run_sim(const char *const *words)
{
    char *argv[32];
    int argc = 0;
    argv[argc++] = (char *)"sim";
    for (; *words && argc < 31; words++)
        argv[argc++] = (char *)*words;
    argv[argc] = NULL;
    return mp_task_sim(argc, argv);
}

static int file_exists(const char *path)
{
    struct stat sb;
    return stat(path, &sb) == 0;
}

static void test_task(void **state)
{
    (void)state;
    const char *tmp = getenv("TMPDIR");
    char dir[512], out[600], truth[600], arg[700], cmd[600];
    snprintf(dir, sizeof dir, "%s/test_sim.XXXXXX", tmp && *tmp ? tmp : "/tmp");
    assert_non_null(mkdtemp(dir));
    snprintf(out, sizeof out, "%s/s.fits", dir);
    snprintf(truth, sizeof truth, "%s/s.truth", dir);
    snprintf(arg, sizeof arg, "output=%s", out);

    /* Noiseless, gain 2, volume 0.5: the frame sums to (sky·npix + E·V)/gain
     * in ADU, and the truth holds E and its magnitude. */
    const char *ok[] = {arg, "noise=no", "magmin=-10", "magmax=-10", "sky=10", "gain=2",
                        "volume=0.5", "nx=50", "ny=40", "seed=9", NULL};
    assert_int_equal(run_sim(ok), 0);
    mp_image im;
    char err[MP_ERRLEN];
    assert_int_equal(mp_image_read(out, &im, err), 0);
    assert_int_equal(im.nx, 50);
    assert_int_equal(im.ny, 40);
    double sum = 0, v;
    for (long i = 0; i < im.nx * im.ny; i++)
        sum += im.pix[i];
    assert_true(fabs(sum - (10.0 * 2000 + 1e4 * 0.5) / 2) < 1e-6);
    assert_int_equal(mp_header_double(&im, "GAIN", &v), 0);
    assert_true(v == 2);
    assert_int_equal(mp_header_double(&im, "RDNOISE", &v), 0);
    assert_int_equal(mp_header_double(&im, "SEED", &v), 0);
    assert_true(v == 9);
    assert_int_equal(mp_header_double(&im, "SATURATE", &v), 1);
    mp_image_free(&im);
    mp_table t;
    assert_int_equal(mp_table_read(truth, &t, err), 0);
    assert_int_equal(t.nrow, 1);
    int cx = mp_table_col(&t, "X_IMAGE"), cf = mp_table_col(&t, "FLUX_TRUE");
    int cm = mp_table_col(&t, "MAG_TRUE"), cs = mp_table_col(&t, "SKY_TRUE");
    assert_true(cx >= 0 && cf >= 0 && cm >= 0 && cs >= 0 && mp_table_col(&t, "NUMBER") >= 0);
    assert_true(fabs(mp_table_get(&t, 0, cx) - 25.5) <= 0.5);      /* near the centre */
    assert_true(fabs(mp_table_get(&t, 0, cf) - 1e4) < 1e-6);
    assert_true(fabs(mp_table_get(&t, 0, cm) + 10) < 1e-8);
    assert_true(mp_table_get(&t, 0, cs) == 10);
    mp_table_free(&t);
    remove(out);
    remove(truth);

    /* Bad parameters: exit 1 and no files. */
    const char *bad1[] = {arg, "magmin=-5", "magmax=-10", NULL};
    const char *bad2[] = {arg, "psf=/nonexistent/psf.fits", NULL};
    const char *bad3[] = {arg, "gain=0", NULL};
    assert_int_equal(run_sim(bad1), 1);
    assert_int_equal(run_sim(bad2), 1);
    assert_int_equal(run_sim(bad3), 1);
    assert_false(file_exists(out));
    assert_false(file_exists(truth));
    snprintf(cmd, sizeof cmd, "rm -rf '%s'", dir);
    assert_int_equal(system(cmd), 0);
}

int main(void)
{
    const struct CMUnitTest tests[] = {
        cmocka_unit_test(test_xoshiro_reference),
        cmocka_unit_test(test_seed_reproducible),
        cmocka_unit_test(test_uniform),
        cmocka_unit_test(test_normal_moments),
        cmocka_unit_test(test_poisson_moments),
        cmocka_unit_test(test_poisson_edge_means),
        cmocka_unit_test(test_poisson_chi2),
        cmocka_unit_test(test_gauss_sum_is_flux),
        cmocka_unit_test(test_gauss_vs_midpoint),
        cmocka_unit_test(test_gauss_drf),
        cmocka_unit_test(test_gauss_edges),
        cmocka_unit_test(test_snap),
        cmocka_unit_test(test_table_block_sum),
        cmocka_unit_test(test_table_drf_weighting),
        cmocka_unit_test(test_table_matches_gauss),
        cmocka_unit_test(test_add_noise),
        cmocka_unit_test(test_task),
    };
    return cmocka_run_group_tests(tests, NULL, NULL);
}
