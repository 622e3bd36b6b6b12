/* test_error_scale.c — the fit's errors widened by what the residual holds
 * at the PSF's scale (pipeline/error_scale.c).
 *
 * A residual of Poisson noise on a 100 e- sky (RON 3, the analytic
 * Gaussian of FWHM 3, fitrad 5: windows 11 px apart, 40² places on a 440²
 * frame): each place's flux, x and y over their σ are N(0, 1), so their
 * robust σ is 1 within Z_TOL of its sampling error (1.166/√n relative, the
 * places' windows being disjoint), and the errors stay as they are (the
 * gate's false rate 2.7e-3 a component; fixed seed).  The same deviations
 * doubled (the data noisier than its Poisson model, or structure the
 * stars do not describe): 2, and the errors doubled.  Places within 1
 * FWHM of a listed star are left out, as many as the test counts from the
 * definition.  The columns are scaled as stated.  On a frame of 8² places,
 * fewer than MP_PL_ESCALE_MINPLACES, neither error is scaled, the doubled
 * noise is said (mp_pl_escale_unused) and Poisson noise is not. */
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

#define N 440
#define SKY 100.0
#define RON 3.0
#define FWHM 3.0
#define FITRAD 5.0
#define Z_TOL 5.0

typedef struct {
    mp_frame f;
    float *res;
    mp_psf psf;
    mp_prf_model m;
} scene;

/* Data = residual = sky + scale × Poisson noise (no star: the model is
 * the sky alone, whose Poisson variance the noise exceeds scale² times). */
static void scene_make_n(scene *s, long n, double scale, uint64_t seed)
{
    memset(s, 0, sizeof *s);
    sf_frame_make(&s->f, n, n, RON);
    s->res = malloc(sizeof(float) * (size_t)(n * n));
    assert_non_null(s->res);
    for (long i = 0; i < n * n; i++)
        s->f.im.pix[i] = (float)SKY;
    mp_rng r;
    mp_rng_seed(&r, seed);
    mp_sim_add_noise_float(&r, s->f.im.pix, (size_t)(n * n), RON);
    for (long i = 0; i < n * n; i++) {
        s->f.im.pix[i] = (float)(SKY + scale * (s->f.im.pix[i] - SKY));
        s->res[i] = s->f.im.pix[i];
    }
    mp_psf_gauss(FWHM, &s->psf);
    s->m = (mp_prf_model){&s->psf, NULL, 10};
}

static void scene_make(scene *s, double scale, uint64_t seed)
{
    scene_make_n(s, N, scale, seed);
}

static void scene_drop(scene *s)
{
    sf_frame_drop(&s->f);
    free(s->res);
}

static void test_noise_and_doubled(void **state)
{
    (void)state;
    const double scales[2] = {1.0, 2.0};
    for (int c = 0; c < 2; c++) {
        scene s;
        scene_make(&s, scales[c], 77 + (uint64_t)c);
        mp_table t;
        sf_fitted_table(&t, NULL, NULL, NULL, NAN, 0);
        mp_pl_escale e;
        char err[MP_ERRLEN];
        assert_int_equal(mp_pl_error_scale(&s.f, s.res, &t, &s.m, FITRAD, FWHM, &e, err), 0);
        assert_int_equal(e.nplace, 40 * 40);
        double se = 1.166 / sqrt((double)e.nplace);
        printf("# scale %g: raw %.4f %.4f %.4f (+- %.4f), k %.4f %.4f\n", scales[c], e.raw[0],
               e.raw[1], e.raw[2], se * scales[c], e.k[0], e.k[1]);
        for (int p = 0; p < 3; p++)
            assert_true(fabs(e.raw[p] / scales[c] - 1.0) < Z_TOL * se);
        if (c == 0) {
            assert_true(e.k[0] == 1.0);
            assert_true(e.k[1] == 1.0);
        } else {
            assert_true(e.k[0] == e.raw[0]);
            assert_true(fabs(e.k[1] - sqrt(0.5 * (e.raw[1] * e.raw[1] + e.raw[2] * e.raw[2]))) <
                        1e-12);
        }
        mp_table_free(&t);
        scene_drop(&s);
    }
}

/* 8² places (an 88² frame), fewer than MP_PL_ESCALE_MINPLACES: the
 * errors stay the fit's for x and y as for the flux (the position's k,
 * over 128 values, was applied before), and the doubled noise is said. */
static void test_too_few_places(void **state)
{
    (void)state;
    const double scales[2] = {1.0, 2.0};
    for (int c = 0; c < 2; c++) {
        scene s;
        scene_make_n(&s, 88, scales[c], 177 + (uint64_t)c);
        mp_table t;
        sf_fitted_table(&t, NULL, NULL, NULL, NAN, 0);
        mp_pl_escale e;
        char err[MP_ERRLEN];
        assert_int_equal(mp_pl_error_scale(&s.f, s.res, &t, &s.m, FITRAD, FWHM, &e, err), 0);
        printf("# 88^2, scale %g: %zu places, raw %.4f %.4f %.4f, k %.4f %.4f, unused %d\n",
               scales[c], e.nplace, e.raw[0], e.raw[1], e.raw[2], e.k[0], e.k[1],
               mp_pl_escale_unused(&e));
        assert_int_equal(e.nplace, 64);
        assert_true(e.k[0] == 1.0 && e.k[1] == 1.0);
        assert_int_equal(mp_pl_escale_unused(&e), c == 1);
        mp_table_free(&t);
        scene_drop(&s);
    }
}

static void test_places_near_stars_left_out(void **state)
{
    (void)state;
    scene s;
    scene_make(&s, 1.0, 5);
    double xs[60], ys[60];
    mp_rng r;
    mp_rng_seed(&r, 9);
    for (int k = 0; k < 60; k++) {
        xs[k] = 1.0 + (N - 1) * mp_rng_uniform(&r);
        ys[k] = 1.0 + (N - 1) * mp_rng_uniform(&r);
    }
    mp_table t;
    sf_fitted_table(&t, xs, ys, NULL, NAN, 60);
    /* the windows' centres (11 px apart, 1-based 6, 17, ...) farther than
     * MP_PL_ESCALE_REX FWHM from every star */
    size_t want = 0;
    for (int j = 0; j < 40; j++)
        for (int i = 0; i < 40; i++) {
            double cx = 11.0 * i + 6.0, cy = 11.0 * j + 6.0, dmin = INFINITY;
            for (int k = 0; k < 60; k++)
                dmin = fmin(dmin, hypot(cx - xs[k], cy - ys[k]));
            want += dmin > MP_PL_ESCALE_REX * FWHM;
        }
    mp_pl_escale e;
    char err[MP_ERRLEN];
    assert_int_equal(mp_pl_error_scale(&s.f, s.res, &t, &s.m, FITRAD, FWHM, &e, err), 0);
    printf("# %zu of 1600 places away from 60 stars (%zu expected)\n", e.nplace, want);
    assert_true(want < 1600);
    assert_int_equal(e.nplace, want);
    mp_table_free(&t);
    scene_drop(&s);
}

static void test_columns_scaled(void **state)
{
    (void)state;
    mp_table t;
    mp_table_init(&t);
    const char *names[5] = {"FLUXERR_PSF", "MAGERR_PSF", "ERRX_PSF", "ERRY_PSF", "FLUX_PSF"};
    const double v[5] = {2.0, 0.1, 0.3, 0.4, 1000.0}, want[5] = {3.0, 0.15, 0.6, 0.8, 1000.0};
    int c[5];
    for (int k = 0; k < 5; k++)
        assert_true((c[k] = mp_table_add_col(&t, names[k])) >= 0);
    long r = mp_table_add_row(&t);
    assert_true(r >= 0);
    for (int k = 0; k < 5; k++)
        mp_table_set(&t, (size_t)r, c[k], v[k]);
    mp_pl_escale e = {{1.5, 2.0}, {1.5, 2.0, 2.0}, 100};
    mp_pl_apply_error_scale(&t, &e);
    for (int k = 0; k < 5; k++)
        assert_true(fabs(mp_table_get(&t, (size_t)r, c[k]) - want[k]) < 1e-12 * want[k]);
    mp_table_free(&t);
}

int main(void)
{
    const struct CMUnitTest tests[] = {
        cmocka_unit_test(test_noise_and_doubled),
        cmocka_unit_test(test_too_few_places),
        cmocka_unit_test(test_places_near_stars_left_out),
        cmocka_unit_test(test_columns_scaled),
    };
    return cmocka_run_group_tests(tests, NULL, NULL);
}
