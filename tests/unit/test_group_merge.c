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
 * code before, stopped after six fits with eight rows, four merged.)
 * The run report counts the two refits as after merges (fit.h
 * MP_REFIT_*); a candidate on empty sky beside a star, rejected, as one
 * after a rejection. */
#include <setjmp.h>
#include <stdarg.h>
#include <stddef.h>
#include <cmocka.h>
#include <math.h>
#include <stdio.h>

#include "tests/unit/stiff_common.h"

#define FWHM 3.0
#define NTRUE 7

/* The stars of t fitted on f with a Gaussian table of FWHM, one pass;
 * minsnr > 0 replaces the default's. */
static void fit_once(mp_frame *f, mp_table *t, double minsnr, mp_frame_report *rep)
{
    mp_psf p;
    mp_psf_gauss(FWHM, &p);
    mp_prf_model m = {&p, NULL, 10};
    mp_frame_opts fo;
    mp_frame_opts_default(&fo);
    fo.passes = 1;
    if (minsnr > 0)
        fo.minsnr = minsnr;
    char err[MP_ERRLEN];
    assert_int_equal(mp_fit_table(f, &m, &fo, t, rep, err), 0);
}

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
    mp_table t;
    sf_table(&t, x, y, e, 2 * NTRUE, 1);
    mp_frame_report rep;
    fit_once(&f, &t, 0.0, &rep);
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
    assert_int_equal(rep.refits[MP_REFIT_MERGE], 2);
    assert_int_equal(rep.refits[MP_REFIT_REJECT] + rep.refits[MP_REFIT_DECIDE] +
                         rep.refits[MP_REFIT_UNSTOPPED], 0);
    /* the first fit moves the halves of each pair: it has steps of its own */
    assert_true(rep.refit_steps[MP_REFIT_MERGE] < rep.iterations);
    mp_table_free(&t);
    sf_frame_drop(&f);
}

/* One star (S/N ~100) and a candidate 8 px from it on empty sky: the
 * candidate's flux is 0 ± its σ, below minsnr 5 but with probability
 * 3·10⁻⁷, so it is rejected and the star fitted again once. */
static void test_rejection_refit_counted(void **state)
{
    (void)state;
    double x[2] = {20.3, 28.3}, y[2] = {20.4, 20.4}, e[2] = {2e4, 500.0}, one_e = 2e4;
    mp_frame f;
    sf_frame_make(&f, 48, 40, 3.0);
    mp_rng r;
    mp_rng_seed(&r, 72);
    sf_render(&f, 100.0, FWHM, x, y, &one_e, 1, &r, 3.0);
    mp_table t;
    sf_table(&t, x, y, e, 2, 1);
    mp_frame_report rep;
    fit_once(&f, &t, 5.0, &rep);    /* the pipeline's minsnr (the default's: 2) */
    print_message("%zu rows, %ld rejected, %ld LM fits, refits %ld/%ld/%ld/%ld\n", t.nrow,
                  rep.rejected, rep.kcalls, rep.refits[MP_REFIT_MERGE],
                  rep.refits[MP_REFIT_REJECT], rep.refits[MP_REFIT_DECIDE],
                  rep.refits[MP_REFIT_UNSTOPPED]);
    assert_int_equal(t.nrow, 1);
    assert_int_equal(rep.rejected, 1);
    assert_int_equal(rep.refits[MP_REFIT_REJECT], 1);
    assert_int_equal(rep.refits[MP_REFIT_MERGE] + rep.refits[MP_REFIT_UNSTOPPED], 0);
    assert_int_equal(rep.kcalls, 1 + rep.refits[MP_REFIT_REJECT] + rep.refits[MP_REFIT_DECIDE]);
    mp_table_free(&t);
    sf_frame_drop(&f);
}

int main(void)
{
    const struct CMUnitTest tests[] = {
        cmocka_unit_test(test_separated_pairs_merge_together),
        cmocka_unit_test(test_rejection_refit_counted),
    };
    return cmocka_run_group_tests(tests, NULL, NULL);
}
