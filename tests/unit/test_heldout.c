/* test_heldout.c — the held-out stars' verdict on the PSF's next order
 * (pipeline/heldout.c, varorder=auto's last step): which stars are held
 * out, the paired comparison matched by NUMBER whatever the rows' order,
 * and its z calibrated under the null (no table better: the log ratios
 * centred on 0). */
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

static mp_table catalog_of(const char *const *cols, int ncol)
{
    mp_table t;
    mp_table_init(&t);
    int idx[8];
    assert_true(ncol <= 8);
    assert_int_equal(mp_table_add_cols(&t, cols, ncol, idx), 0);
    return t;
}

static void add_star(mp_table *t, double x, double y, double F, double E, double flags)
{
    long r = mp_table_add_row(t);
    assert_true(r >= 0);
    double v[5] = {x, y, F, E, flags};
    for (int c = 0; c < 5; c++)
        mp_table_set(t, (size_t)r, c, v[c]);
}

/* The held-out stars: FLAGS 0, S/N at least MP_PL_HELDOUT_SNR, not within
 * 1 px of a PSF star; the brightest max of them. */
static void test_rows_held_out(void **state)
{
    (void)state;
    static const char *const cols[] = {"X_IMAGE", "Y_IMAGE", "FLUX_PSF", "FLUXERR_PSF", "FLAGS"};
    mp_table t = catalog_of(cols, 5);
    double E = 100.0, s = MP_PL_HELDOUT_SNR;
    add_star(&t, 10, 10, (s - 0.01) * E, E, 0);   /* 0: S/N just short */
    add_star(&t, 20, 10, s * E, E, 0);            /* 1: S/N just enough */
    add_star(&t, 30, 10, 9e5, E, 1);              /* 2: flagged */
    add_star(&t, 40.5, 10, 8e5, E, 0);            /* 3: 0.5 px from a PSF star */
    add_star(&t, 41.5, 10, 7e5, E, 0);            /* 4: 1.5 px from it */
    add_star(&t, 50, 10, 6e5, E, 0);              /* 5 */
    add_star(&t, 60, 10, 5e5, E, 0);              /* 6 */
    add_star(&t, 70, 10, 5e5, 0.0, 0);            /* 7: no error */
    double px[1] = {40.0}, py[1] = {10.0};
    unsigned char sel[8];
    assert_int_equal(mp_pl_heldout_rows(&t, px, py, 1, 10, sel), 4);
    static const unsigned char all[8] = {0, 1, 0, 0, 1, 1, 1, 0};
    assert_memory_equal(sel, all, 8);
    assert_int_equal(mp_pl_heldout_rows(&t, px, py, 1, 2, sel), 2);   /* the brightest 2 */
    static const unsigned char two[8] = {0, 0, 0, 0, 1, 1, 0, 0};
    assert_memory_equal(sel, two, 8);
    mp_table o;
    assert_int_equal(mp_pl_rows_of(&t, sel, 0, &o), 0);
    assert_int_equal((int)o.nrow, 6);
    assert_true(mp_table_get(&o, 4, 0) == 60.0);   /* order kept */
    mp_table_free(&o);
    assert_int_equal(mp_pl_rows_of(&t, sel, 1, &o), 0);
    assert_int_equal((int)o.nrow, 2);
    assert_true(mp_table_get(&o, 0, 0) == 41.5 && mp_table_get(&o, 1, 0) == 50.0);
    mp_table_free(&o);
    /* the whole table (one block copy): every value, and rows append after */
    assert_int_equal(mp_pl_rows_of(&t, NULL, 1, &o), 0);
    assert_int_equal((int)o.nrow, 8);
    assert_int_equal((int)o.ncol, 5);
    for (size_t r = 0; r < 8; r++)
        for (int c = 0; c < 5; c++) {
            double a = mp_table_get(&t, r, c), b = mp_table_get(&o, r, c);
            assert_true(a == b || (isnan(a) && isnan(b)));
        }
    assert_int_equal(mp_table_add_row(&o), 8);
    assert_true(isnan(mp_table_get(&o, 8, 0)) && mp_table_get(&o, 7, 0) == 70.0);
    mp_table_free(&o);
    mp_table_free(&t);
}

/* Two fits of the same stars: b's rows reversed, a star only in b, one
 * whose χ² is 0 in a and one NaN in b left out; the mean and z are those
 * of the paired log ratios, computed here from their definition. */
static void test_compare_paired_by_number(void **state)
{
    (void)state;
    static const char *const cols[] = {"NUMBER", "CHI2STAR_PSF"};
    enum { N = 60 };
    mp_table a = catalog_of(cols, 2), b = catalog_of(cols, 2);
    mp_rng r;
    mp_rng_seed(&r, 20261202);
    double l[N], ca[N];
    for (int i = 0; i < N; i++) {
        l[i] = -0.02 + 0.1 * mp_rng_normal(&r);
        ca[i] = i == 7 ? 0.0 : 0.5 + 3.0 * mp_rng_uniform(&r);
        long k = mp_table_add_row(&a);
        mp_table_set(&a, (size_t)k, 0, 100.0 + i);
        mp_table_set(&a, (size_t)k, 1, ca[i]);
    }
    for (int i = N - 1; i >= 0; i--) {
        long k = mp_table_add_row(&b);
        mp_table_set(&b, (size_t)k, 0, 100.0 + i);
        mp_table_set(&b, (size_t)k, 1, i == 11 ? NAN : ca[i] * exp(l[i]));
    }
    long k = mp_table_add_row(&b);
    mp_table_set(&b, (size_t)k, 0, 999.0);
    mp_table_set(&b, (size_t)k, 1, 1.0);
    double s = 0.0, ss = 0.0;
    int n = 0;
    for (int i = 0; i < N; i++)
        if (i != 7 && i != 11) {
            s += l[i];
            n++;
        }
    double m = s / n;
    for (int i = 0; i < N; i++)
        if (i != 7 && i != 11)
            ss += (l[i] - m) * (l[i] - m);
    double z = m / sqrt(ss / (n - 1) / n);
    mp_pl_heldout h;
    assert_int_equal(mp_pl_heldout_compare(&a, &b, &h), 0);
    assert_int_equal((int)h.n, n);
    assert_true(fabs(h.mean - m) < 1e-12);
    assert_true(fabs(h.z - z) < 1e-9 * fabs(z));
    mp_table_free(&a);
    mp_table_free(&b);
}

/* Under the null — each star's log ratio drawn from one normal of mean 0
 * (neither table better), 50 stars — z < −MP_PL_HELDOUT_Z is Student's
 * t(49) tail at 1.645: 0.0532.  Over 6000 draws that is 319 ± 17.4
 * (binomial); the test allows 4.5 σ (a false failure once in ~1.5e5 runs),
 * so a z scaled wrongly by 10 % either way (rates 0.0368, 0.0706: 98 and
 * 104 draws off) fails. */
static void test_z_calibrated_under_null(void **state)
{
    (void)state;
    static const char *const cols[] = {"NUMBER", "CHI2STAR_PSF"};
    enum { NS = 50, NDRAW = 6000 };
    mp_rng r;
    mp_rng_seed(&r, 43);
    int low = 0;
    for (int d = 0; d < NDRAW; d++) {
        mp_table a = catalog_of(cols, 2), b = catalog_of(cols, 2);
        double spread = 0.02 + 0.2 * mp_rng_uniform(&r);   /* any scale */
        for (int i = 0; i < NS; i++) {
            long ka = mp_table_add_row(&a), kb = mp_table_add_row(&b);
            mp_table_set(&a, (size_t)ka, 0, i);
            mp_table_set(&b, (size_t)kb, 0, i);
            mp_table_set(&a, (size_t)ka, 1, 1.0);
            mp_table_set(&b, (size_t)kb, 1, exp(spread * mp_rng_normal(&r)));
        }
        mp_pl_heldout h;
        assert_int_equal(mp_pl_heldout_compare(&a, &b, &h), 0);
        low += h.z < -MP_PL_HELDOUT_Z;
        mp_table_free(&a);
        mp_table_free(&b);
    }
    double want = 0.0532 * NDRAW, sd = sqrt(want * (1.0 - 0.0532));
    printf("# null: z < -%.3f in %d of %d draws (%.0f +- %.1f expected)\n", MP_PL_HELDOUT_Z, low,
           NDRAW, want, sd);
    assert_true(fabs(low - want) < 4.5 * sd);
}

int main(void)
{
    const struct CMUnitTest tests[] = {
        cmocka_unit_test(test_rows_held_out),
        cmocka_unit_test(test_compare_paired_by_number),
        cmocka_unit_test(test_z_calibrated_under_null),
    };
    return cmocka_run_group_tests(tests, NULL, NULL);
}
