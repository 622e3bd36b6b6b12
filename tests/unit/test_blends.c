/* test_blends.c — one star or two (issue 13): the pipeline's reduction
 * (mp_pipeline_reduce with the defaults: find at 2σ, matchrad 0.5 FWHM,
 * the score test of a second star beside each fitted star (split.c), the
 * fit merging a pair whose separation is not significant and rejecting
 * stars below S/N 5) on 48×48 frames of a Gaussian PSF (FWHM 3 px, fitted
 * with the analytic Gaussian), sky 100 e-, read noise 3 e-, Poisson noise,
 * NSEED fixed noise draws each:
 *   - pairs at 2 and 1 FWHM, 10⁴ and 4·10³ e- (S/N ≈ 60 and 30): two
 *     stars, each within 0.3 px of its true place, on every draw (their
 *     separation is many times its fitted σ);
 *   - a pair at 0.5 FWHM, 4·10⁴ and 1.6·10⁴ e- (S/N ≈ 190 and 110): the
 *     same.  (30 draws of each pair: 30/30 resolved; at 0.5 FWHM and the
 *     fainter 10⁴ + 4·10³ e- the pair is at the edge of what the data
 *     tell, and 19/30 come out as two.)
 *   - a single star of 5·10⁴ e-: one star on every draw (a false split
 *     needs Δχ² ≥ 25 from noise: χ²(1) > 25 has probability 6e-7 per
 *     place tried, ~1e-5 over the 36 places).
 * A failure is a defect, not chance: nothing here is near its threshold.
 * And the test itself drawn from the phase grid (economy, issue 12) on a
 * x2 table against exact renders: the same place proposed, √Δχ² the same
 * to 1e-4 (the grid's error bound, 0.1 σ of a star within its limit,
 * moves √Δχ² by less than 0.1·σ_E/E ≈ 1e-3 of it here; measured 4e-7);
 * and with the star beyond the grid's limit but its second within it
 * (the trials from the grid), the same; both beyond: exact, bit for bit. */
#include <setjmp.h>
#include <stdarg.h>
#include <stddef.h>
#include <cmocka.h>
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include "pipeline/pipeline_priv.h"
#include "sim/sim.h"

#define N 48
#define FWHM 3.0
#define SKY 100.0
#define RON 3.0
#define NSEED 8

typedef struct {
    mp_parset ps;
    mp_pipeline_opts o;
} setup;

static int setup_opts(void **state)
{
    setup *s = calloc(1, sizeof *s);
    char err[MP_ERRLEN];
    if (!s || mp_params_defaults("pipeline", &s->ps, err) ||
        mp_params_set(&s->ps, "psf", "gauss", err) || mp_pl_opts_read(&s->ps, &s->o, err)) {
        fprintf(stderr, "setup: %s\n", err);
        return -1;
    }
    *state = s;
    return 0;
}

static int teardown_opts(void **state)
{
    setup *s = *state;
    mp_fit_setup_free(&s->o.fit);
    mp_params_free(&s->ps);
    free(s);
    return 0;
}

/* The frame of n stars (x, y, E) with noise from seed; reduced; the
 * number of stars found, and how many of the true ones have a found star
 * within 0.3 px. */
static int reduce(const setup *s, const double (*st)[3], int n, uint64_t seed, int *near)
{
    mp_frame f;
    memset(&f, 0, sizeof f);
    f.im.nx = f.im.ny = N;
    f.im.pix = malloc(sizeof *f.im.pix * N * N);
    f.mask = calloc(N * N, 1);
    assert_non_null(f.im.pix);
    assert_non_null(f.mask);
    f.gain = 1.0;
    f.rdnoise = RON;
    f.saturate = INFINITY;
    f.exptime = 1.0;
    for (int i = 0; i < N * N; i++)
        f.im.pix[i] = SKY;
    mp_sim_prf prf = {.kind = MP_SIM_GAUSS, .sigma = FWHM / 2.3548200450309493, .volume = 1.0};
    for (int k = 0; k < n; k++)
        assert_int_equal(mp_sim_add_star_float(&prf, st[k][0], st[k][1], st[k][2], f.im.pix, N, N), 0);
    mp_rng r;
    mp_rng_seed(&r, seed);
    mp_sim_add_noise_float(&r, f.im.pix, N * N, RON);
    mp_table t;
    char err[MP_ERRLEN];
    if (mp_pipeline_reduce(&f, &s->o, &t, NULL, err))
        fail_msg("mp_pipeline_reduce: %s", err);
    int cx = mp_table_col(&t, "XPSF_IMAGE"), cy = mp_table_col(&t, "YPSF_IMAGE");
    *near = 0;
    for (int k = 0; k < n; k++)
        for (size_t j = 0; j < t.nrow; j++)
            if (hypot(mp_table_get(&t, j, cx) - st[k][0], mp_table_get(&t, j, cy) - st[k][1]) < 0.3) {
                (*near)++;
                break;
            }
    int found = (int)t.nrow;
    mp_table_free(&t);
    free(f.im.pix);
    free(f.mask);
    return found;
}

/* A pair sep FWHM apart (at 30° to the axes), 10⁴ and 4·10³ e-. */
static void pair_at(void **state, double sep, double e1)
{
    const setup *s = *state;
    double d = sep * FWHM, x0 = 24.3 - 0.5 * d * cos(M_PI / 6), y0 = 23.8 - 0.5 * d * sin(M_PI / 6);
    double st[2][3] = {{x0, y0, e1}, {x0 + d * cos(M_PI / 6), y0 + d * sin(M_PI / 6), 0.4 * e1}};
    for (int k = 0; k < NSEED; k++) {
        int near, found = reduce(s, (const double (*)[3])st, 2, 1000 + (uint64_t)k, &near);
        if (found != 2 || near != 2)
            fail_msg("pair at %.1f FWHM, seed %d: %d stars found, %d of 2 within 0.3 px", sep,
                     1000 + k, found, near);
    }
}

static void test_pair_2fwhm(void **state) { pair_at(state, 2.0, 1e4); }
static void test_pair_1fwhm(void **state) { pair_at(state, 1.0, 1e4); }
static void test_pair_half_fwhm(void **state) { pair_at(state, 0.5, 4e4); }

/* Inside the merge radius (0.4 FWHM = 1.2 px): a pair 0.35 FWHM apart,
 * 4·10⁵ and 1.6·10⁵ e- (S/N ≈ 600 and 390).  Its separation, 1.05 px, is
 * some 20 times its fitted σ, far above mp_merge_sig's 5: two stars, not
 * one (the merge radius alone merged them before 2026-12-01). */
static void test_pair_inside_mergerad(void **state) { pair_at(state, 0.35, 4e5); }

static void test_single_star(void **state)
{
    const setup *s = *state;
    double st[1][3] = {{24.2, 23.7, 5e4}};
    for (int k = 0; k < NSEED; k++) {
        int near, found = reduce(s, (const double (*)[3])st, 1, 2000 + (uint64_t)k, &near);
        if (found != 1 || near != 1)
            fail_msg("single star, seed %d: %d stars found, %d within 0.3 px", 2000 + k, found, near);
    }
}

/* The one-or-two test (split.c) on the residual of an unresolved pair
 * (0.6 FWHM, 4·10⁴ + 1.6·10⁴ e-) less one star at its light's centre, with
 * a x2 Gaussian table: from the phase grid and exact, the same answer. */
static void test_split_from_grid(void **state)
{
    (void)state;
    char err[MP_ERRLEN];
    mp_psf p;
    assert_int_equal(mp_psf_gauss_table(FWHM, 2, 8.0, &p, err), 0);
    mp_prf_model m = {&p, NULL, 10};
    mp_prf_cache c;
    assert_int_equal(mp_prf_cache_build(&m, 16, &c, err), 0);
    assert_true(c.G > 0);
    mp_frame f;
    memset(&f, 0, sizeof f);
    f.im.nx = f.im.ny = N;
    f.im.pix = malloc(sizeof *f.im.pix * N * N);
    f.mask = calloc(N * N, 1);
    assert_true(f.im.pix && f.mask);
    f.rdnoise = RON;
    double d = 0.6 * FWHM, x1 = 24.3, y1 = 23.8, x2 = x1 + d * 0.8, y2 = y1 + d * 0.6;
    double e1 = 4e4, e2 = 1.6e4, E = e1 + e2;
    double xc = (e1 * x1 + e2 * x2) / E, yc = (e1 * y1 + e2 * y2) / E;
    mp_sim_prf prf = {.kind = MP_SIM_GAUSS, .sigma = FWHM / 2.3548200450309493, .volume = 1.0};
    for (int i = 0; i < N * N; i++)
        f.im.pix[i] = SKY;
    /* the weights: the sky's noise, measured on the star-free frame */
    mp_rng r;
    mp_rng_seed(&r, 77);
    mp_sim_add_noise_float(&r, f.im.pix, N * N, RON);
    mp_bkg b;
    memset(&b, 0, sizeof b);
    assert_int_equal(mp_bkg_estimate(&f, N, 1, &b, err), 0);
    mp_rng_seed(&r, 78);
    for (int i = 0; i < N * N; i++)
        f.im.pix[i] = SKY;
    assert_int_equal(mp_sim_add_star_float(&prf, x1, y1, e1, f.im.pix, N, N), 0);
    assert_int_equal(mp_sim_add_star_float(&prf, x2, y2, e2, f.im.pix, N, N), 0);
    mp_sim_add_noise_float(&r, f.im.pix, N * N, RON);
    assert_int_equal(mp_sim_add_star_float(&prf, xc, yc, -E, f.im.pix, N, N), 0);
    mp_table t;
    mp_table_init(&t);
    int cx = mp_table_add_col(&t, "XPSF_IMAGE"), cy = mp_table_add_col(&t, "YPSF_IMAGE");
    int cf = mp_table_add_col(&t, "FLUX_PSF"), ce = mp_table_add_col(&t, "FLUXERR_PSF");
    assert_true(mp_table_add_row(&t) == 0);
    mp_table_set(&t, 0, cx, xc);
    mp_table_set(&t, 0, cy, yc);
    mp_table_set(&t, 0, cf, E);
    mp_table_set(&t, 0, ce, 300.0);
    double gemax = mp_prf_cache_limit(&c, SKY, RON, 0.1);
    assert_true(E <= gemax);          /* else the grid is not used: no test */
    mp_table fe, fg;
    mp_table_init(&fe);
    mp_table_init(&fg);
    assert_int_equal(mp_pl_split_candidates(&f, &b, f.im.pix, &m, NULL, 0.0, 0.0, &t, 5.0, 0.4 * FWHM,
                                            0.75 * FWHM, 5.0, &fe), 1);
    assert_int_equal(mp_pl_split_candidates(&f, &b, f.im.pix, &m, &c, gemax, 0.0, &t, 5.0, 0.4 * FWHM,
                                            0.75 * FWHM, 5.0, &fg), 1);
    int sx = mp_table_col(&fe, "X_IMAGE"), sy = mp_table_col(&fe, "Y_IMAGE");
    int ss = mp_table_col(&fe, MP_PL_SNR_COL);
    assert_true(mp_table_get(&fe, 0, sx) == mp_table_get(&fg, 0, sx));
    assert_true(mp_table_get(&fe, 0, sy) == mp_table_get(&fg, 0, sy));
    double se = mp_table_get(&fe, 0, ss), sg = mp_table_get(&fg, 0, ss);
    assert_true(se >= 5.0);
    assert_true(fabs(sg - se) <= 1e-4 * se);
    assert_true(sg != se);            /* the grid drew it: not the exact renders */
    /* The star beyond the limit (gemax below E), its second within it
     * (above 1.6·10⁴ e-): the star exact, the trials from the grid, the
     * same answer; the second beyond it too: all exact, bit for bit. */
    mp_table fb, fx;
    mp_table_init(&fb);
    mp_table_init(&fx);
    assert_int_equal(mp_pl_split_candidates(&f, &b, f.im.pix, &m, &c, 0.5 * E, 0.0, &t, 5.0, 0.4 * FWHM,
                                            0.75 * FWHM, 5.0, &fb), 1);
    assert_int_equal(mp_pl_split_candidates(&f, &b, f.im.pix, &m, &c, 0.1 * e2, 0.0, &t, 5.0,
                                            0.4 * FWHM, 0.75 * FWHM, 5.0, &fx), 1);
    double sb = mp_table_get(&fb, 0, ss);
    print_message("split: exact %.9g, grid %.9g, grid trials %.9g\n", se, sg, sb);
    assert_true(mp_table_get(&fb, 0, sx) == mp_table_get(&fe, 0, sx));
    assert_true(mp_table_get(&fb, 0, sy) == mp_table_get(&fe, 0, sy));
    assert_true(fabs(sb - se) <= 1e-4 * se);
    assert_true(sb != se);            /* the trials from the grid */
    assert_true(mp_table_get(&fx, 0, ss) == se);
    assert_true(mp_table_get(&fx, 0, sx) == mp_table_get(&fe, 0, sx));
    /* The trials bilinearly within the bilinear limit: the same place,
     * √Δχ² within 0.1 (the limit's bound at frac 0.1); a limit below the
     * best trial's flux: cubic again, as without (bit for bit). */
    double glemax = mp_prf_cache_limit_lin(&c, SKY, RON, 0.1);
    assert_true(glemax >= e2);        /* else bilinear is never used: no test */
    mp_table fl, fc;
    mp_table_init(&fl);
    mp_table_init(&fc);
    assert_int_equal(mp_pl_split_candidates(&f, &b, f.im.pix, &m, &c, gemax, glemax, &t, 5.0,
                                            0.4 * FWHM, 0.75 * FWHM, 5.0, &fl), 1);
    assert_int_equal(mp_pl_split_candidates(&f, &b, f.im.pix, &m, &c, gemax, 0.1 * e2, &t, 5.0,
                                            0.4 * FWHM, 0.75 * FWHM, 5.0, &fc), 1);
    double sl = mp_table_get(&fl, 0, ss);
    print_message("split: bilinear trials %.9g\n", sl);
    assert_true(mp_table_get(&fl, 0, sx) == mp_table_get(&fe, 0, sx));
    assert_true(mp_table_get(&fl, 0, sy) == mp_table_get(&fe, 0, sy));
    assert_true(fabs(sl - se) <= 0.1);
    assert_true(sl != sg);            /* bilinear drew them */
    assert_true(mp_table_get(&fc, 0, ss) == sg);
    mp_table_free(&fl);
    mp_table_free(&fc);
    mp_table_free(&fb);
    mp_table_free(&fx);
    mp_table_free(&fe);
    mp_table_free(&fg);
    mp_table_free(&t);
    mp_bkg_free(&b);
    free(f.im.pix);
    free(f.mask);
    mp_prf_cache_free(&c);
    mp_psf_free(&p);
}

int main(void)
{
    const struct CMUnitTest tests[] = {
        cmocka_unit_test(test_single_star),
        cmocka_unit_test(test_pair_2fwhm),
        cmocka_unit_test(test_pair_1fwhm),
        cmocka_unit_test(test_pair_half_fwhm),
        cmocka_unit_test(test_pair_inside_mergerad),
        cmocka_unit_test(test_split_from_grid),
    };
    return cmocka_run_group_tests(tests, setup_opts, teardown_opts);
}
