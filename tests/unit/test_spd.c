/* test_spd.c — fit/spd.c, the small positive-definite solves the fit makes
 * in every thread, against LAPACK (OpenBLAS) on the same matrices.
 *
 * Matrices A = B Bᵀ/n + I, B standard normal (seeded): eigenvalues within
 * [1, ~5], condition < 10, so any backward-stable Cholesky agrees with
 * LAPACK to a few hundred ε in the solution; the tolerance 1e-11 is about 45 000 ε
 * relative to the solution's norm (no false failure: the bound is
 * deterministic, n ≤ 100 gives errors ≤ ~n κ ε ≈ 2e-13). */
#include <setjmp.h>
#include <stdarg.h>
#include <stddef.h>
#include <stdint.h>
#include <cmocka.h>
#include <lapacke.h>
#include <math.h>
#include <stdlib.h>
#include <string.h>
#include "fit/spd.h"
#include "sim/sim.h"

/* A (column-major lower and upper: symmetric) of order n. */
static double *spd_matrix(mp_rng *r, int n)
{
    double *b = malloc(sizeof(double) * n * n), *a = malloc(sizeof(double) * n * n);
    assert_non_null(b);
    assert_non_null(a);
    for (int i = 0; i < n * n; i++)
        b[i] = mp_rng_normal(r);
    for (int i = 0; i < n; i++)
        for (int j = 0; j < n; j++) {
            double s = i == j ? 1.0 : 0.0;
            for (int k = 0; k < n; k++)
                s += b[i * n + k] * b[j * n + k] / n;
            a[(size_t)j * n + i] = s;
        }
    free(b);
    return a;
}

static double rel_diff(const double *x, const double *y, int n)
{
    double d = 0, s = 0;
    for (int i = 0; i < n; i++) {
        d = fmax(d, fabs(x[i] - y[i]));
        s = fmax(s, fabs(y[i]));
    }
    return d / s;
}

/* Solve and inverse against LAPACKE_dposv and dpotrf + dpotri, n 1..100;
 * and the upper triangle is never read (filled with NaN). */
static void test_solve_and_inverse_match_lapack(void **state)
{
    (void)state;
    mp_rng r;
    mp_rng_seed(&r, 20261130);
    double worst_x = 0, worst_inv = 0;
    for (int n = 1; n <= 100; n += (n < 12 ? 1 : 11)) {
        double *a = spd_matrix(&r, n), *l = malloc(sizeof(double) * n * n);
        double *m = malloc(sizeof(double) * n * n), *x = malloc(sizeof(double) * n);
        double *y = malloc(sizeof(double) * n);
        assert_true(l && m && x && y);
        for (int i = 0; i < n; i++)
            x[i] = y[i] = mp_rng_normal(&r);
        memcpy(l, a, sizeof(double) * n * n);
        memcpy(m, a, sizeof(double) * n * n);
        assert_int_equal(LAPACKE_dposv(LAPACK_COL_MAJOR, 'L', n, 1, l, n, y, n), 0);
        for (int j = 0; j < n; j++)
            for (int i = 0; i < j; i++)
                m[(size_t)j * n + i] = NAN;
        double *mi = malloc(sizeof(double) * n * n);
        assert_non_null(mi);
        memcpy(mi, m, sizeof(double) * n * n);
        assert_int_equal(mp_spd_solve(m, n, x), 0);
        worst_x = fmax(worst_x, rel_diff(x, y, n));
        assert_int_equal(mp_spd_inverse(mi, n), 0);
        memcpy(l, a, sizeof(double) * n * n);
        assert_int_equal(LAPACKE_dpotrf(LAPACK_COL_MAJOR, 'L', n, l, n), 0);
        assert_int_equal(LAPACKE_dpotri(LAPACK_COL_MAJOR, 'L', n, l, n), 0);
        for (int j = 0; j < n; j++)
            for (int i = j; i < n; i++) {
                double want = l[(size_t)j * n + i];
                worst_inv = fmax(worst_inv, fabs(mi[(size_t)j * n + i] - want));
                worst_inv = fmax(worst_inv, fabs(mi[(size_t)i * n + j] - want));
            }
        free(a);
        free(l);
        free(m);
        free(mi);
        free(x);
        free(y);
    }
    print_message("largest difference from LAPACK: solution %.2g (relative), inverse %.2g\n",
                  worst_x, worst_inv);
    assert_true(worst_x < 1e-11);
    assert_true(worst_inv < 1e-11);
}

/* One factor, several right-hand sides solved in turn (coupling.c's use:
 * its three columns), against LAPACKE_dpotrs on all of them at once. */
static void test_several_right_hand_sides(void **state)
{
    (void)state;
    mp_rng r;
    mp_rng_seed(&r, 7);
    int n = 5, k = 3;
    double *a = spd_matrix(&r, n), l[25], B[15], X[15];
    memcpy(l, a, sizeof l);
    for (int i = 0; i < n * k; i++)
        B[i] = X[i] = mp_rng_normal(&r);
    assert_int_equal(mp_spd_factor(a, n), 0);
    for (int c = 0; c < k; c++)
        mp_spd_solve_factored(a, n, X + (size_t)c * n);
    assert_int_equal(LAPACKE_dpotrf(LAPACK_COL_MAJOR, 'L', n, l, n), 0);
    assert_int_equal(LAPACKE_dpotrs(LAPACK_COL_MAJOR, 'L', n, k, l, n, B, n), 0);
    assert_true(rel_diff(X, B, n * k) < 1e-11);
    free(a);
}

/* Not positive definite: the order of the first leading minor that is not
 * positive, as dpotrf's info; a NaN on the diagonal fails too; b is left
 * as it was. */
static void test_not_positive_definite(void **state)
{
    (void)state;
    mp_rng r;
    mp_rng_seed(&r, 11);
    int n = 6;
    for (int bad = 0; bad < n; bad++) {
        double *a = spd_matrix(&r, n), l[36], b[6] = {1, 2, 3, 4, 5, 6};
        a[(size_t)bad * n + bad] -= 20.0;      /* the minor of order bad+1 turns negative */
        memcpy(l, a, sizeof l);
        int want = LAPACKE_dpotrf(LAPACK_COL_MAJOR, 'L', n, l, n);
        assert_int_equal(want, bad + 1);
        assert_int_equal(mp_spd_solve(a, n, b), want);
        assert_true(b[0] == 1 && b[5] == 6);
        free(a);
    }
    double *a = spd_matrix(&r, n);
    a[2 * n + 2] = NAN;
    assert_int_not_equal(mp_spd_factor(a, n), 0);
    free(a);
}

int main(void)
{
    const struct CMUnitTest tests[] = {
        cmocka_unit_test(test_solve_and_inverse_match_lapack),
        cmocka_unit_test(test_several_right_hand_sides),
        cmocka_unit_test(test_not_positive_definite),
    };
    return cmocka_run_group_tests(tests, NULL, NULL);
}
