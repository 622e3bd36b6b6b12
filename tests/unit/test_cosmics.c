/* test_cosmics.c — cosmic rays masked as the pixels no sum of stars can
 * make (pipeline crmask=yes, pipeline/cosmics.c): the PSF's sharpness
 * bound against its definition, the threshold's tail, a crowded frame of
 * stars (up to 1e7 e-) where nothing may be flagged, and the same frame
 * with cosmic rays, every one of which must be. */
#include <setjmp.h>
#include <stdarg.h>
#include <stddef.h>
#include <cmocka.h>
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include "pipeline/pipeline_priv.h"
#include "tests/unit/stiff_common.h"

enum { N = 200, NSTAR = 160, NCR = 40 };
static const double FWHM = 2.0, SKY = 100.0, RON = 5.0;

/* The pixel-integrated Gaussian's 1-D share of pixel i for a star at
 * phase f (pixel centres at integers). */
static double share(double sigma, double i, double f)
{
    double a = (i - 0.5 - f) / (sigma * M_SQRT2), b = (i + 0.5 - f) / (sigma * M_SQRT2);
    return 0.5 * (erf(b) - erf(a));
}

/* s: the least (side neighbours' sum) / pixel over the pixels holding at
 * least MP_PL_CR_CORE of the peak, from the definition, over 41 × 41
 * phases (a star at any place in its pixel).  mp_pl_cr_bound samples 5 × 5
 * and must stay under it (a bound), yet within 5 % of it (else the test
 * loses cosmic rays it could see). */
static void test_bound_is_its_definition(void **state)
{
    (void)state;
    double sigma = FWHM / FWHM_SIGMA, want = 4.0;
    for (int ph = 0; ph < 41 * 41; ph++) {
        double fx = (ph % 41) / 40.0 - 0.5, fy = (ph / 41) / 40.0 - 0.5;
        double peak = 0.0;
        for (int j = -6; j <= 6; j++)
            for (int i = -6; i <= 6; i++)
                peak = fmax(peak, share(sigma, i, fx) * share(sigma, j, fy));
        for (int j = -5; j <= 5; j++)
            for (int i = -5; i <= 5; i++) {
                double v = share(sigma, i, fx) * share(sigma, j, fy);
                double nb = share(sigma, i - 1, fx) * share(sigma, j, fy) +
                            share(sigma, i + 1, fx) * share(sigma, j, fy) +
                            share(sigma, i, fx) * share(sigma, j - 1, fy) +
                            share(sigma, i, fx) * share(sigma, j + 1, fy);
                if (v >= MP_PL_CR_CORE * peak)
                    want = fmin(want, nb / v);
            }
    }
    mp_psf p;
    mp_psf_gauss(FWHM, &p);
    mp_prf_model m = {&p, NULL, 10};
    double s, D;
    char err[MP_ERRLEN];
    assert_int_equal(mp_pl_cr_bound(&m, N, N, &s, &D, err), 0);
    printf("s %.6f (definition %.6f), D %.3g per e-\n", s, want, D);
    assert_true(s <= want && s > 0.95 * want);
    assert_true(D >= 0.0 && D < 0.05);
}

/* The threshold: npix · Q(k) = rate, against tabulated normal tails
 * (Q(5.612) = 1.0e-8, Q(4.753) = 1.0e-6). */
static void test_threshold_tail(void **state)
{
    (void)state;
    assert_true(fabs(mp_pl_cr_sigma(1e6, 0.01) - 5.612) < 2e-3);
    assert_true(fabs(mp_pl_cr_sigma(1e4, 0.01) - 4.753) < 2e-3);
}

/* A crowded frame of Gaussian stars (fluxes 1e2..1e7 e-, log-uniform, at
 * any phase), Poisson and read noise, the stars' true places and fluxes
 * for the wings' allowance; the generator left for what a test adds. */
typedef struct {
    mp_rng r;
    double x[NSTAR], y[NSTAR], E[NSTAR];
    mp_frame f;
} scene;

static void scene_make(scene *sc)
{
    mp_rng_seed(&sc->r, 20261202);
    sf_frame_make(&sc->f, N, N, RON);
    for (int k = 0; k < NSTAR; k++) {
        sc->x[k] = 4.0 + (N - 7.0) * mp_rng_uniform(&sc->r);
        sc->y[k] = 4.0 + (N - 7.0) * mp_rng_uniform(&sc->r);
        sc->E[k] = pow(10.0, 2.0 + 5.0 * mp_rng_uniform(&sc->r));
    }
    sf_render(&sc->f, SKY, FWHM, sc->x, sc->y, sc->E, NSTAR, &sc->r, RON);
}

/* The pipeline's test on f (n stars at x, y of flux E) with the model of
 * FWHM fwhm; sharp: s scaled by the stars' own sharpness, or those stars
 * guarded (mp_pl_cr_sharpness, as the pipeline). */
static long mask_frame(mp_frame *f, const double *x, const double *y, const double *E, int n,
                       double fwhm, int sharp, long *cores)
{
    mp_psf p;
    mp_psf_gauss(fwhm, &p);
    mp_prf_model m = {&p, NULL, 10};
    mp_pl_cr_test ct = {.grow = 1, .side = 64};
    char err[MP_ERRLEN];
    assert_int_equal(mp_pl_cr_bound(&m, N, N, &ct.s, &ct.D, err), 0);
    ct.k = mp_pl_cr_sigma((double)N * N, MP_PL_CR_RATE);
    mp_bkg b;
    assert_int_equal(mp_bkg_estimate(f, 64, 3, &b, err), 0);
    mp_table t;                 /* as round 1's fit hands the stars on */
    sf_fitted_table(&t, x, y, E, SKY, n);
    mp_pl_cr_stars st = {.reach = 8.0};
    mp_pl_star *stars = mp_pl_stars_by_flux(&t, 0, &st.n);
    assert_non_null(stars);
    st.s = stars;
    size_t guard[MP_PL_CR_NSHARP];
    if (sharp) {
        double a = mp_pl_cr_sharpness(f, &m, &st, guard, &ct.nguard);
        ct.guard = guard;
        printf("model FWHM %.2f for stars of %.2f: s x %.3f, %zu guarded\n", fwhm, FWHM, a,
               ct.nguard);
        ct.s *= a;
    }
    long masked = mp_pl_mask_cosmics(f, &b, NULL, &st, &ct, cores);
    mp_bkg_free(&b);
    free(stars);
    mp_table_free(&t);
    return masked;
}

/* Starlight alone: nothing flagged.  The stars cannot be (the bound);
 * noise flags a pixel with probability 0.01 a frame (MP_PL_CR_RATE), so
 * this fails by chance once in a hundred seeds, and not at this one. */
static void test_stars_never_flagged(void **state)
{
    (void)state;
    scene sc;
    scene_make(&sc);
    long cores;
    long masked = mask_frame(&sc.f, sc.x, sc.y, sc.E, NSTAR, FWHM, 1, &cores);
    printf("stars alone: %ld flagged, %ld masked\n", cores, masked);
    assert_int_equal(cores, 0);
    assert_int_equal(masked, 0);
    sf_frame_drop(&sc.f);
}

/* The same frame with cosmic rays: single pixels and two-pixel tracks of
 * 1500..20000 e- a pixel, anywhere but within 3 px of a star brighter
 * than 1e5 e- (whose core may hide one: its own excess is negative).
 * At 1500 e- on this sky a hit's T is ~35 σ_T (s ≈ 1.95, σ_T ≈ 80 e-)
 * against a threshold of 5.3, so every one is flagged, and with growth 1
 * every hit pixel is masked; no pixel farther than 1 px from a hit is.
 * The star list the test is given holds five of the hits as bright stars,
 * as a first round that took them for stars hands it on: the stars'
 * sharpness must not follow them (their ratio is a hit's, near 0). */
static void test_cosmic_rays_flagged(void **state)
{
    (void)state;
    scene sc;
    scene_make(&sc);
    uint8_t *hit = calloc((size_t)N * N, 1);
    assert_non_null(hit);
    long placed = 0;
    while (placed < NCR) {
        long cx = 3 + (long)((N - 6) * mp_rng_uniform(&sc.r));
        long cy = 3 + (long)((N - 6) * mp_rng_uniform(&sc.r));
        int near = 0;
        for (int k = 0; k < NSTAR; k++)
            near |= sc.E[k] > 1e5 && fabs(sc.x[k] - 1.0 - cx) < 3.0 &&
                    fabs(sc.y[k] - 1.0 - cy) < 3.0;
        for (long j = cy - 3; j <= cy + 3; j++)
            for (long i = cx - 3; i <= cx + 3; i++)
                near |= hit[j * N + i];
        if (near)
            continue;
        if (placed < 5) {                      /* taken for a star */
            sc.x[placed] = (double)cx + 1.0;
            sc.y[placed] = (double)cy + 1.0;
            sc.E[placed] = 1e6;
        }
        int len = placed % 4 == 0 ? 2 : 1;     /* every fourth a track */
        for (int a = 0; a < len; a++) {
            sc.f.im.pix[cy * N + cx + a] += (float)(1500.0 + 18500.0 * mp_rng_uniform(&sc.r));
            hit[cy * N + cx + a] = 1;
        }
        placed++;
    }
    long cores;
    long masked = mask_frame(&sc.f, sc.x, sc.y, sc.E, NSTAR, FWHM, 1, &cores);
    printf("cosmic rays: %ld placed, %ld flagged, %ld masked\n", placed, cores, masked);
    long missed = 0, stray = 0;
    for (long j = 0; j < N; j++)
        for (long i = 0; i < N; i++) {
            missed += hit[j * N + i] && !(sc.f.mask[j * N + i] & MP_MASK_BAD);
            int by = 0;
            for (long b = j - 1; b <= j + 1; b++)
                for (long a = i - 1; a <= i + 1; a++)
                    by |= b >= 0 && b < N && a >= 0 && a < N && hit[b * N + a];
            stray += (sc.f.mask[j * N + i] & MP_MASK_BAD) && !by;
        }
    assert_int_equal(missed, 0);
    assert_int_equal(stray, 0);
    assert_true(cores >= NCR);
    free(hit);
    sf_frame_drop(&sc.f);
}

/* A model broader than the stars (FWHM 2.4 for stars of 2.0: a table
 * smoothed more than they are) puts its s above their cores' ratio, so
 * bright cores pass for hits; scaled by the stars' own sharpness none
 * does (and the scale is below 1). */
static void test_broad_model_scaled(void **state)
{
    (void)state;
    scene sc;
    scene_make(&sc);
    long cores_raw, cores;
    mask_frame(&sc.f, sc.x, sc.y, sc.E, NSTAR, 2.4, 0, &cores_raw);
    memset(sc.f.mask, 0, (size_t)N * N);
    long masked = mask_frame(&sc.f, sc.x, sc.y, sc.E, NSTAR, 2.4, 1, &cores);
    printf("broad model: %ld stars' pixels flagged unscaled, %ld scaled (%ld masked)\n",
           cores_raw, cores, masked);
    assert_true(cores_raw > 0);
    assert_int_equal(cores, 0);
    sf_frame_drop(&sc.f);
}

/* A sparse frame: six bright stars (too few to check the model on) and
 * ten hits of 2000..20000 e-, the model broader than the stars.  Unscaled
 * and unguarded the stars' cores pass for hits; with the six guarded
 * (the pixels within MP_PL_CR_GUARD of them untested) only the hits are
 * flagged, every one of them (each ~45 σ_T above the threshold). */
static void test_sparse_guarded(void **state)
{
    (void)state;
    enum { NS = 6, NH = 10 };
    double x[NS] = {40.2, 100.7, 160.4, 40.9, 100.1, 160.6};
    double y[NS] = {60.3, 60.8, 60.1, 140.6, 140.2, 140.9};
    double E[NS] = {1e5, 2e5, 4e5, 6e5, 8e5, 1e6};
    mp_rng r;
    mp_rng_seed(&r, 20261202);
    mp_frame f;
    sf_frame_make(&f, N, N, RON);
    sf_render(&f, SKY, FWHM, x, y, E, NS, &r, RON);
    for (int h = 0; h < NH; h++)            /* a row of hits at y = 101 */
        f.im.pix[100 * N + 10 + 18 * h] += (float)(2000.0 + 18000.0 * mp_rng_uniform(&r));
    long raw, cores;
    mask_frame(&f, x, y, E, NS, 2.4, 0, &raw);
    memset(f.mask, 0, (size_t)N * N);
    long masked = mask_frame(&f, x, y, E, NS, 2.4, 1, &cores);
    long on_hits = 0;
    for (int h = 0; h < NH; h++)
        on_hits += (f.mask[100 * N + 10 + 18 * h] & MP_MASK_BAD) != 0;
    printf("sparse: %ld flagged unguarded, %ld guarded (%ld masked, %ld of %d hits)\n", raw,
           cores, masked, on_hits, NH);
    assert_true(raw > NH);
    assert_int_equal(cores, NH);
    assert_int_equal(on_hits, NH);
    assert_int_equal(masked, 9 * NH);
    sf_frame_drop(&f);
}

int main(void)
{
    const struct CMUnitTest tests[] = {
        cmocka_unit_test(test_bound_is_its_definition),
        cmocka_unit_test(test_threshold_tail),
        cmocka_unit_test(test_stars_never_flagged),
        cmocka_unit_test(test_cosmic_rays_flagged),
        cmocka_unit_test(test_broad_model_scaled),
        cmocka_unit_test(test_sparse_guarded),
    };
    return cmocka_run_group_tests(tests, NULL, NULL);
}
