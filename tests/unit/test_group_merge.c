/* test_group_merge.c — fit/frame_group.c merges a group's close pairs as
 * ALLSTAR does, but those 2 FWHM or more apart in one refit (issue 12:
 * groups of ~50 stars in a crowded frame were refitted once per merge,
 * each refit stopped at maxiter by the pairs still to merge).
 *
 * One group: five stars 12 px apart (4 FWHM) and two 4 px apart (within
 * the 2 FWHM a merge may disturb), each given twice to the fit, 0.3 px
 * apart (an unresolvable pair: merged by either rule, distance or
 * significance).  The fit must end with the seven stars, each flagged
 * merged, at their true positions; the five separated pairs go in the
 * first merge step with one of the two close ones, the other in the next,
 * so the group is fitted exactly three times.  (One merge a refit, the
 * code before, stopped after six fits with eight rows, four merged.) */
#include <setjmp.h>
#include <stdarg.h>
#include <stddef.h>
#include <cmocka.h>
#include <math.h>
#include <stdio.h>

#include "tests/unit/stiff_common.h"

#define FWHM 3.0
#define NTRUE 7

static void test_separated_pairs_merge_together(void **state)
{
    (void)state;
    const double tx[NTRUE] = {10.2, 22.4, 34.1, 46.3, 58.45, 70.3, 74.2}, ty = 20.35, E = 2e4;
    double x[2 * NTRUE], y[2 * NTRUE], e[2 * NTRUE];
    for (int k = 0; k < NTRUE; k++)
        for (int h = 0; h < 2; h++) {
            x[2 * k + h] = tx[k] + (h ? 0.15 : -0.15);
            y[2 * k + h] = ty;
            e[2 * k + h] = E / 2;
        }
    mp_frame f;
    sf_frame_make(&f, 90, 40, 3.0);
    mp_rng r;
    mp_rng_seed(&r, 71);
    double one_y[NTRUE], one_e[NTRUE];
    for (int k = 0; k < NTRUE; k++) {
        one_y[k] = ty;
        one_e[k] = E;
    }
    sf_render(&f, 100.0, FWHM, tx, one_y, one_e, NTRUE, &r, 3.0);
    mp_psf p;
    mp_psf_gauss(FWHM, &p);
    mp_prf_model m = {&p, NULL, 10};
    mp_frame_opts fo;
    mp_frame_opts_default(&fo);
    fo.passes = 1;
    mp_table t;
    sf_table(&t, x, y, e, 2 * NTRUE, 1);
    mp_frame_report rep;
    char err[MP_ERRLEN];
    assert_int_equal(mp_fit_table(&f, &m, &fo, &t, &rep, err), 0);
    print_message("%zu rows, %ld merged, %ld LM fits of the group\n", t.nrow, rep.merged,
                  rep.kcalls);
    assert_int_equal(t.nrow, NTRUE);
    assert_int_equal(rep.merged, NTRUE);
    for (size_t i = 0; i < t.nrow; i++) {
        double X = sf_get(&t, i, "XPSF_IMAGE"), d = INFINITY;
        for (int k = 0; k < NTRUE; k++)
            d = fmin(d, fabs(X - tx[k]));
        /* S/N ~100 and FWHM 3: a position's σ ~0.015 px; 0.1 px is 6 σ. */
        assert_true(d < 0.1);
        assert_true(fabs(sf_get(&t, i, "YPSF_IMAGE") - ty) < 0.1);
        assert_true((int)sf_get(&t, i, "FLAGS") & MP_FLAG_MERGED);
    }
    assert_int_equal(rep.kcalls, 3);
    mp_table_free(&t);
    sf_frame_drop(&f);
}

int main(void)
{
    const struct CMUnitTest tests[] = {
        cmocka_unit_test(test_separated_pairs_merge_together),
    };
    return cmocka_run_group_tests(tests, NULL, NULL);
}
