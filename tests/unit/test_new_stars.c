/* test_new_stars.c — the round's new stars (pipeline/new_stars.c,
 * mp_pl_add_new_stars): the grid that finds a detection's known
 * neighbours, whatever its cells' size (issue 14 made them one star's
 * area, not matchrad's), adds exactly the detections a search of every
 * star adds. */
#include <setjmp.h>
#include <stdarg.h>
#include <stddef.h>
#include <cmocka.h>
#include <math.h>
#include <stdlib.h>
#include "pipeline/pipeline_priv.h"
#include "sim/sim.h"

enum { NX = 500, NY = 400 };

/* n random positions (and S/N, NUMBER 1..n) in a fresh table. */
static void random_table(mp_table *t, size_t n, mp_rng *r, int snr)
{
    mp_table_init(t);
    int cn = mp_table_add_col(t, "NUMBER"), cx = mp_table_add_col(t, "X_IMAGE");
    int cy = mp_table_add_col(t, "Y_IMAGE"), cs = snr ? mp_table_add_col(t, MP_PL_SNR_COL) : 0;
    assert_true(cn >= 0 && cx >= 0 && cy >= 0 && cs >= 0);
    for (size_t i = 0; i < n; i++) {
        long row = mp_table_add_row(t);
        assert_true(row >= 0);
        mp_table_set(t, (size_t)row, cn, (double)(i + 1));
        mp_table_set(t, (size_t)row, cx, 0.5 + NX * mp_rng_uniform(r));
        mp_table_set(t, (size_t)row, cy, 0.5 + NY * mp_rng_uniform(r));
        if (snr)
            mp_table_set(t, (size_t)row, cs, 10.0 * mp_rng_uniform(r));
    }
}

/* Detections beside the first n stars of t, within ±d on each axis: some
 * nearer than matchrad, some not, whatever the density. */
static void add_beside(mp_table *found, const mp_table *t, size_t n, double d, mp_rng *r)
{
    int tx = mp_table_col(t, "X_IMAGE"), ty = mp_table_col(t, "Y_IMAGE");
    int fx = mp_table_col(found, "X_IMAGE"), fy = mp_table_col(found, "Y_IMAGE");
    int fs = mp_table_col(found, MP_PL_SNR_COL);
    for (size_t i = 0; i < n && i < t->nrow; i++) {
        long row = mp_table_add_row(found);
        assert_true(row >= 0);
        mp_table_set(found, (size_t)row, fx, mp_table_get(t, i, tx) + d * (2 * mp_rng_uniform(r) - 1));
        mp_table_set(found, (size_t)row, fy, mp_table_get(t, i, ty) + d * (2 * mp_rng_uniform(r) - 1));
        mp_table_set(found, (size_t)row, fs, 10.0 * mp_rng_uniform(r));
    }
}

/* Is (x, y) nearer than r to a row of t among its first n? */
static int near_any(const mp_table *t, size_t n, double x, double y, double r)
{
    int cx = mp_table_col(t, "X_IMAGE"), cy = mp_table_col(t, "Y_IMAGE");
    for (size_t i = 0; i < n; i++)
        if (hypot(mp_table_get(t, i, cx) - x, mp_table_get(t, i, cy) - y) < r)
            return 1;
    return 0;
}

/* Dense (1e-2 a pixel: cells of 4.5 px) and sparse (cells of 141 px) known
 * stars, matchrad 1.5 and 30 px (wider than a dense cell): the added rows
 * are those the search of every star selects, in found's order.  With
 * cells narrower than matchrad the grid would miss neighbours. */
static void test_new_stars_grid(void **state)
{
    (void)state;
    const struct { size_t nt, ngone, nfound; double matchrad; } cs[] = {
        {2000, 50, 3000, 1.5}, {10, 5, 500, 1.5}, {2000, 50, 400, 30.0}};
    mp_rng r;
    mp_rng_seed(&r, 9090);
    for (size_t c = 0; c < sizeof cs / sizeof cs[0]; c++) {
        mp_table t, gone, found;
        random_table(&t, cs[c].nt, &r, 0);
        random_table(&gone, cs[c].ngone, &r, 0);
        random_table(&found, cs[c].nfound, &r, 1);
        add_beside(&found, &t, 200, 1.5 * cs[c].matchrad, &r);
        double closerad = 0.4 * cs[c].matchrad, closesnr = 5.0;
        int fx = mp_table_col(&found, "X_IMAGE"), fy = mp_table_col(&found, "Y_IMAGE");
        int fs = mp_table_col(&found, MP_PL_SNR_COL);
        long want = 0, got = mp_pl_add_new_stars(&t, &gone, &found, NX, NY, cs[c].matchrad,
                                                 closerad, closesnr);
        int tx = mp_table_col(&t, "X_IMAGE"), tn = mp_table_col(&t, "NUMBER");
        for (size_t i = 0; i < found.nrow; i++) {
            double x = mp_table_get(&found, i, fx), y = mp_table_get(&found, i, fy);
            if (near_any(&gone, gone.nrow, x, y, cs[c].matchrad))
                continue;
            if (near_any(&t, cs[c].nt, x, y, cs[c].matchrad) &&
                (!(mp_table_get(&found, i, fs) >= closesnr) ||
                 near_any(&t, cs[c].nt, x, y, closerad)))
                continue;
            size_t row = cs[c].nt + (size_t)want++;
            assert_true(row < t.nrow);
            assert_true(mp_table_get(&t, row, tx) == x);
            assert_true(mp_table_get(&t, row, tn) == (double)row + 1.0);
        }
        assert_int_equal(got, want);
        assert_int_equal(t.nrow, cs[c].nt + (size_t)want);
        assert_true(want > 0 && (size_t)want < found.nrow);   /* both outcomes met */
        mp_table_free(&t);
        mp_table_free(&gone);
        mp_table_free(&found);
    }
}

int main(void)
{
    const struct CMUnitTest tests[] = {
        cmocka_unit_test(test_new_stars_grid),
    };
    return cmocka_run_group_tests(tests, NULL, NULL);
}
