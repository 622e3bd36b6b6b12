/*
 * test_merge.c — catalog/merge*.c: the survey merge (catalog.h).
 *
 *   - the tangent-plane geometry: offsets and back within 1e-9 arcsec at
 *     RA = 0 (the wrap) and at the pole;
 *   - the match rule on hand-built catalogs with exact answers: a star
 *     3 sigma off joins its source, 6 sigma off does not (nsigma = 5);
 *     two stars of one frame never share a source, however close; the
 *     weighted means and their errors equal the formulas worked by hand;
 *   - the pixel scale derived from a catalog's own sky positions;
 *   - errors: a missing column; too few stars without pixscale.
 */
#include <stdarg.h>
#include <stddef.h>
#include <stdint.h>
#include <setjmp.h>
#include <cmocka.h>

#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "catalog/merge_priv.h"

static const char *const names[] = {"NUMBER", "XPSF_IMAGE", "YPSF_IMAGE", "ERRX_PSF", "ERRY_PSF",
                                    "ALPHAPSF_J2000", "DELTAPSF_J2000", "MAG_PSF", "MAGERR_PSF"};

/* A catalog row: a star at (ra, dec) [deg] with position error e [px] in
 * both axes, magnitude mag ± merr. */
static void row(mp_table *t, double num, double ra, double dec, double e, double mag, double merr)
{
    if (t->ncol == 0)
        for (int i = 0; i < 9; i++)
            assert_int_equal(mp_table_add_col(t, names[i]), i);
    long r = mp_table_add_row(t);
    assert_true(r >= 0);
    double v[9] = {num, 100 + num, 100, e, e, ra, dec, mag, merr};
    for (int i = 0; i < 9; i++)
        mp_table_set(t, (size_t)r, i, v[i]);
}

/* (ra, dec) moved by (xi, eta) arcsec in the tangent plane. */
static void offset(double ra, double dec, double xi, double eta, double *ro, double *dco)
{
    double u[3], p[3];
    mg_unit(ra, dec, u);
    mg_untangent(u, xi, eta, p);
    mg_radec(p, ro, dco);
}

static void test_geometry(void **state)
{
    (void)state;
    const double pts[][2] = {{359.9999, 0.0}, {0.0001, -0.5}, {123.4, 89.99999}, {10, -90}};
    for (int k = 0; k < 4; k++) {
        double u[3], p[3], xi, eta, ra, dec;
        mg_unit(pts[k][0], pts[k][1], u);
        mg_untangent(u, 1.234, -5.678, p);
        assert_int_equal(mg_tangent(u, p, &xi, &eta), 0);
        assert_true(fabs(xi - 1.234) < 1e-9 && fabs(eta + 5.678) < 1e-9);
        mg_radec(u, &ra, &dec);
        assert_true(ra >= 0 && ra < 360);
        if (fabs(pts[k][1]) < 89)
            assert_true(fabs(ra - pts[k][0]) < 1e-9 && fabs(dec - pts[k][1]) < 1e-9);
    }
}

static const mp_merge_opts OPTS = {.nsigma = 5, .syserr = 0, .maxrad = 10, .pixscale = 1.0};

/* Frame 1: A at RA 359.9999 (beside the wrap), B 20" north, C and D
 * 0.02" apart.  Frame 2: A 3 sigma east (joins), B 6 sigma north (does
 * not: the combined sigma of two 0.1" detections is 0.1414"). */
static void test_match_rule(void **state)
{
    (void)state;
    const double ra = 359.9999, dec = 0.0, s2 = 0.1 * sqrt(2.0);
    double ra2, dec2;
    mp_table t1, t2;
    mp_table_init(&t1);
    mp_table_init(&t2);
    row(&t1, 1, ra, dec, 0.1, 10.0, 0.1);
    offset(ra, dec, 0, 20, &ra2, &dec2);
    row(&t1, 2, ra2, dec2, 0.1, 11.0, 0.1);
    offset(ra, dec, 0, -30, &ra2, &dec2);
    row(&t1, 3, ra2, dec2, 0.1, 12.0, 0.1);
    offset(ra, dec, 0.02, -30, &ra2, &dec2);
    row(&t1, 4, ra2, dec2, 0.1, 12.0, 0.1);
    offset(ra, dec, 3 * s2, 0, &ra2, &dec2);
    row(&t2, 1, ra2, dec2, 0.1, 10.3, 0.2);
    offset(ra, dec, 0, 20 + 6 * s2, &ra2, &dec2);
    row(&t2, 2, ra2, dec2, 0.1, 11.0, 0.1);

    mp_merge *m = mp_merge_new(&OPTS);
    assert_non_null(m);
    char err[MP_ERRLEN];
    long skipped = -1;
    assert_int_equal(mp_merge_add(m, &t1, "t1", &skipped, err), 0);
    assert_int_equal(skipped, 0);
    assert_int_equal(mp_merge_add(m, &t2, "t2", NULL, err), 0);
    mp_table src, det;
    assert_int_equal(mp_merge_tables(m, &src, &det, err), 0);
    assert_int_equal(src.nrow, 5);     /* A, B, C, D, B' */
    assert_int_equal(det.nrow, 6);
    int nd = mp_table_col(&src, "NDET"), mm = mp_table_col(&src, "MAG_MEAN");
    assert_int_equal((int)mp_table_get(&src, 0, nd), 2);
    for (size_t i = 1; i < 5; i++)
        assert_int_equal((int)mp_table_get(&src, i, nd), 1);
    /* A: equal position weights, the midpoint 1.5 sigma east; magnitudes
     * 10.0 ± 0.1 and 10.3 ± 0.2: mean (100·10 + 25·10.3)/125 = 10.06, error
     * 1/sqrt(125), chi2 100·0.06² + 25·0.24² = 1.8 with 1 dof. */
    double mra, mdec, xi, eta, u[3], p[3];
    offset(ra, dec, 1.5 * s2, 0, &mra, &mdec);
    mg_unit(mra, mdec, u);
    mg_unit(mp_table_get(&src, 0, mp_table_col(&src, "ALPHA_J2000")),
            mp_table_get(&src, 0, mp_table_col(&src, "DELTA_J2000")), p);
    assert_int_equal(mg_tangent(u, p, &xi, &eta), 0);
    assert_true(hypot(xi, eta) < 1e-6);     /* arcsec: the same tangent plane */
    assert_true(fabs(mp_table_get(&src, 0, mm) - 10.06) < 1e-12);
    assert_true(fabs(mp_table_get(&src, 0, mp_table_col(&src, "MAGERR_MEAN")) - 1 / sqrt(125.0)) < 1e-12);
    assert_true(fabs(mp_table_get(&src, 0, mp_table_col(&src, "MAG_CHI2")) - 1.8) < 1e-9);
    assert_true(fabs(mp_table_get(&src, 0, mp_table_col(&src, "ERRRA_ARCSEC")) - 0.1 / sqrt(2.0)) < 1e-12);
    /* Detections sorted by source then frame; frame 2's B is source 5. */
    int ds = mp_table_col(&det, "SOURCE_ID"), df = mp_table_col(&det, "FRAME");
    const double want[6][2] = {{1, 1}, {1, 2}, {2, 1}, {3, 1}, {4, 1}, {5, 2}};
    for (size_t i = 0; i < 6; i++) {
        assert_int_equal((int)mp_table_get(&det, i, ds), (int)want[i][0]);
        assert_int_equal((int)mp_table_get(&det, i, df), (int)want[i][1]);
    }
    mp_table_free(&src);
    mp_table_free(&det);
    mp_merge_free(m);
    mp_table_free(&t1);
    mp_table_free(&t2);
}

/* Three stars on a 0.2"/px grid rotated 30 degrees: the Jacobian from
 * their own positions turns 0.5 px errors into 0.1" east and north. */
static void test_pixel_scale(void **state)
{
    (void)state;
    mp_table t;
    mp_table_init(&t);
    const double c = cos(M_PI / 6), s = sin(M_PI / 6), px[3][2] = {{10, 10}, {90, 20}, {30, 80}};
    for (int k = 0; k < 3; k++) {
        double xi = 0.2 * (c * px[k][0] - s * px[k][1]), eta = 0.2 * (s * px[k][0] + c * px[k][1]);
        double r, d;
        offset(180, 45, xi, eta, &r, &d);
        row(&t, k + 1, r, d, 0.5, 10, 0.1);
        mp_table_set(&t, (size_t)k, 1, px[k][0]);
        mp_table_set(&t, (size_t)k, 2, px[k][1]);
    }
    mg_det *d;
    size_t n;
    char err[MP_ERRLEN];
    assert_int_equal(mg_frame_dets(&t, "t", 1, 0.0, NAN, &d, &n, err), 0);
    assert_int_equal(n, 3);
    for (size_t k = 0; k < n; k++)   /* (0.2·0.5)² (c² + s²): 0.1" each way */
        assert_true(fabs(d[k].se - 0.1) < 1e-6 && fabs(d[k].sn - 0.1) < 1e-6);
    free(d);
    mp_table_free(&t);
}

static void test_errors(void **state)
{
    (void)state;
    mp_table t;
    mp_table_init(&t);
    row(&t, 1, 10, 10, 0.1, 10, 0.1);
    mg_det *d;
    size_t n;
    char err[MP_ERRLEN];
    assert_int_not_equal(mg_frame_dets(&t, "one.cat", 1, 0.0, NAN, &d, &n, err), 0);
    assert_non_null(strstr(err, "pixscale"));
    int c = mp_table_col(&t, "ERRY_PSF");
    snprintf(t.cols[c].name, sizeof t.cols[c].name, "ERRY_OTHER");
    assert_int_not_equal(mg_frame_dets(&t, "one.cat", 1, 0.0, 1.0, &d, &n, err), 0);
    assert_non_null(strstr(err, "one.cat: no ERRY_PSF column"));
    mp_table_free(&t);
}

int main(void)
{
    const struct CMUnitTest tests[] = {
        cmocka_unit_test(test_geometry),
        cmocka_unit_test(test_match_rule),
        cmocka_unit_test(test_pixel_scale),
        cmocka_unit_test(test_errors),
    };
    return cmocka_run_group_tests(tests, NULL, NULL);
}
