/* test_new_stars.c — the round's new stars (pipeline/new_stars.c,
 * mp_pl_add_new_stars): the grid that finds a detection's known
 * neighbours, whatever its cells' size (issue 14 made them one star's
 * area, not matchrad's), adds exactly the detections a search of every
 * star adds.  And the first detection's screen (pipeline/prescreen.c):
 * a saturated plateau is kept whatever its S/N there. */
#include <setjmp.h>
#include <stdarg.h>
#include <stddef.h>
#include <cmocka.h>
#include <math.h>
#include <stdlib.h>
#include <string.h>
#include "pipeline/pipeline_priv.h"
#include "sim/sim.h"
#include "stiff_common.h"

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

/* The screen on a frame of sky and read noise with one bright star whose
 * core (r < 2.5 px) is masked: rows at the star and at an empty place,
 * each as a plain detection and as a saturated plateau (find's FLAGS 1).
 * The empty place's linear S/N is noise (|S/N| > 3 has probability
 * 0.003; this seed's draw is asserted below 3): its plain row is dropped,
 * its plateau row kept with FLUX NaN (the fit's own start; find's plateau
 * flux extrapolates a Gaussian, 1.3e10 e- for a 5e6 e- star of the
 * segmented scene).  The star's rows are kept with their fitted flux. */
static void test_prescreen_plateau(void **state)
{
    (void)state;
    enum { M = 48 };
    const double sky = 100.0, ron = 3.0, fwhm = 3.0, e = 1e6, xs = 24.3, ys = 23.8;
    char err[MP_ERRLEN];
    mp_psf p;
    assert_int_equal(mp_psf_gauss_table(fwhm, 2, 8.0, &p, err), 0);
    mp_prf_model m = {&p, NULL, 10};
    mp_frame f;
    sf_frame_make(&f, M, M, ron);
    mp_rng r;
    mp_rng_seed(&r, 4242);
    sf_render(&f, sky, fwhm, NULL, NULL, NULL, 0, &r, ron);
    mp_bkg b;
    memset(&b, 0, sizeof b);
    assert_int_equal(mp_bkg_estimate(&f, M, 1, &b, err), 0);
    mp_sim_prf prf = {.kind = MP_SIM_GAUSS, .sigma = fwhm / FWHM_SIGMA, .volume = 1.0};
    assert_int_equal(mp_sim_add_star_float(&prf, xs, ys, e, f.im.pix, M, M), 0);
    for (int j = 0; j < M; j++)
        for (int i = 0; i < M; i++)
            f.mask[j * M + i] = hypot(i + 1.0 - xs, j + 1.0 - ys) < 2.5;
    mp_table t;
    mp_table_init(&t);
    int cx = mp_table_add_col(&t, "X_IMAGE"), cy = mp_table_add_col(&t, "Y_IMAGE");
    int cf = mp_table_add_col(&t, "FLUX"), cl = mp_table_add_col(&t, "FLAGS");
    assert_true(cx >= 0 && cy >= 0 && cf >= 0 && cl >= 0);
    const double row[4][3] = {{xs, ys, 0}, {xs, ys, 1}, {36.0, 12.0, 0}, {36.0, 12.0, 1}};
    for (int k = 0; k < 4; k++) {
        long q = mp_table_add_row(&t);
        assert_true(q >= 0);
        mp_table_set(&t, (size_t)q, cx, row[k][0]);
        mp_table_set(&t, (size_t)q, cy, row[k][1]);
        mp_table_set(&t, (size_t)q, cf, 1.3e10);
        mp_table_set(&t, (size_t)q, cl, row[k][2]);
    }
    long dropped = mp_pl_prescreen(&f, &b, f.im.pix, &m, 5.0, 3.0, &t);
    int cs = mp_table_col(&t, MP_PL_SNR_COL);
    assert_true(cs >= 0);
    assert_true(mp_table_get(&t, 2, cs) < 3.0 && mp_table_get(&t, 3, cs) < 3.0);
    assert_int_equal(dropped, 1);
    for (int k = 0; k < 2; k++) {   /* the star: kept, its flux fitted */
        double fl = mp_table_get(&t, (size_t)k, cf);
        assert_true(isfinite(mp_table_get(&t, (size_t)k, cx)));
        assert_true(fl > 0.5 * e && fl < 2.0 * e);
    }
    assert_true(isnan(mp_table_get(&t, 2, cx)));    /* noise: dropped */
    assert_true(isfinite(mp_table_get(&t, 3, cx))); /* a plateau: kept */
    assert_true(isnan(mp_table_get(&t, 3, cf)));
    mp_table_free(&t);
    mp_bkg_free(&b);
    mp_psf_free(&p);
    sf_frame_drop(&f);
}

/* The residual search's screen with the fit's phase grid: a candidate's
 * PRF from the grid moves its S/N by at most the grid's bias bound (0.1
 * of the flux's σ, mp_prf_cache_limit) where the screen decides — faint
 * candidates, whose own light adds little to the noise — so the kept set
 * differs only within that of the cut; brighter candidates beyond the
 * grid's limit are rendered exactly, as without it. */
static void test_screen_from_grid(void **state)
{
    (void)state;
    enum { M = 96, NS = 40 };
    const double sky = 100.0, ron = 3.0, fwhm = 3.0, frac = 0.1, cut = 3.0;
    char err[MP_ERRLEN];
    mp_psf p;
    assert_int_equal(mp_psf_gauss_table(fwhm, 2, 8.0, &p, err), 0);
    mp_prf_model m = {&p, NULL, 10};
    mp_prf_cache c;
    assert_int_equal(mp_prf_cache_build(&m, 16, &c, err), 0);
    /* the grid's own limit, lowered so that bright candidates meet it */
    double gemax = fmin(mp_prf_cache_limit(&c, sky, ron, frac), 3000.0);
    mp_frame f;
    sf_frame_make(&f, M, M, ron);
    mp_rng r;
    mp_rng_seed(&r, 917);
    mp_find_cand a[NS], b[NS];
    double xs[NS], ys[NS], es[NS];
    for (int k = 0; k < NS; k++) {  /* a star every other candidate, S/N ~1..300 */
        xs[k] = 8.0 + (M - 16) * mp_rng_uniform(&r);
        ys[k] = 8.0 + (M - 16) * mp_rng_uniform(&r);
        es[k] = k % 2 ? 0.0 : 40.0 * pow(10.0, 3.0 * mp_rng_uniform(&r));
        a[k] = (mp_find_cand){.x = xs[k], .y = ys[k], .flux = NAN, .snr = NAN, .keep = 1};
    }
    sf_render(&f, sky, fwhm, xs, ys, es, NS, &r, ron);
    for (int i = 0; i < M * M; i++)         /* Poisson, as a Gaussian */
        f.im.pix[i] += (float)(sqrt(fmax(f.im.pix[i], 0.0)) * mp_rng_normal(&r));
    mp_bkg bk;
    memset(&bk, 0, sizeof bk);
    assert_int_equal(mp_bkg_estimate(&f, 32, 1, &bk, err), 0);
    memcpy(b, a, sizeof a);
    mp_pl_screen exact = {.f = &f, .b = &bk, .res = f.im.pix, .m = &m, .fitrad = 5.0,
                          .snrmin = cut};
    mp_pl_screen grid = exact;
    grid.grid = &c;
    grid.gemax = gemax;
    assert_int_equal(mp_pl_screen_sieve(&exact, a, NS), 0);
    assert_int_equal(mp_pl_screen_sieve(&grid, b, NS), 0);
    int near = 0, served = 0, beyond = 0;
    for (int k = 0; k < NS; k++) {
        assert_true(isfinite(a[k].snr) && isfinite(b[k].snr));
        if (fabs(a[k].snr) < 10.0) {        /* where the screen decides */
            assert_true(fabs(a[k].snr - b[k].snr) <= frac);
            near++;
        }
        if (b[k].keep && fabs(b[k].flux) > gemax) {     /* beyond the grid: exact */
            assert_true(a[k].snr == b[k].snr);
            beyond++;
        }
        served += a[k].snr != b[k].snr;
        if (a[k].keep != b[k].keep)
            assert_true(fabs(a[k].snr - cut) <= frac);
    }
    print_message("%d candidates near the cut, %d drawn from the grid, %d beyond it\n", near,
                  served, beyond);
    assert_true(near >= 10 && served >= 10 && beyond >= 5);    /* every case met */
    mp_bkg_free(&bk);
    mp_prf_cache_free(&c);
    mp_psf_free(&p);
    sf_frame_drop(&f);
}

int main(void)
{
    const struct CMUnitTest tests[] = {
        cmocka_unit_test(test_new_stars_grid),
        cmocka_unit_test(test_prescreen_plateau),
        cmocka_unit_test(test_screen_from_grid),
    };
    return cmocka_run_group_tests(tests, NULL, NULL);
}
