/* test_sharp_limits.c — find's sharpness limits fitted to the PSF
 * (pipeline/sharp_limits.c, mp_pl_sharp_limits): a PSF of the kernel's
 * own shape leaves DAOPHOT's limits as they are; an undersampled one
 * widens them just enough that a noiseless star of it, at the phase where
 * it is sharpest, is detected where DAOPHOT's limits cut it. */
#include <setjmp.h>
#include <stdarg.h>
#include <stddef.h>
#include <cmocka.h>
#include <math.h>
#include <stdlib.h>
#include <string.h>
#include "pipeline/pipeline_priv.h"
#include "sim/sim.h"

#define FWHM_PER_SIGMA 2.3548200450309493

/* Detections of find (opts o) on a noiseless 64² frame: sky 100 and one
 * pixel-integrated Gaussian star of fwhm centred on pixel (32, 31). */
static size_t found_on_frame(double fwhm, const mp_find_opts *o)
{
    enum { N = 64 };
    mp_frame f;
    memset(&f, 0, sizeof f);
    f.im.nx = f.im.ny = N;
    f.im.pix = malloc(N * N * sizeof *f.im.pix);
    f.mask = calloc(N * N, 1);
    assert_true(f.im.pix && f.mask);
    for (long i = 0; i < N * N; i++)
        f.im.pix[i] = 100.0f;
    f.gain = f.exptime = 1.0;
    f.saturate = INFINITY;
    mp_sim_prf p;
    memset(&p, 0, sizeof p);
    p.kind = MP_SIM_GAUSS;
    p.sigma = fwhm / FWHM_PER_SIGMA;
    p.volume = 1.0;
    assert_int_equal(mp_sim_add_star_float(&p, 32.0, 31.0, 2e4, f.im.pix, N, N), 0);
    char err[MP_ERRLEN];
    mp_bkg b;
    mp_table t;
    mp_table_init(&t);
    assert_int_equal(mp_bkg_estimate(&f, 32, 3, &b, err), 0);
    assert_int_equal(mp_find_stars(&f, &b, o, &t, err), 0);
    size_t n = t.nrow;
    mp_table_free(&t);
    mp_bkg_free(&b);
    free(f.im.pix);
    free(f.mask);
    return n;
}

static void limits_for(double fwhm, mp_find_opts *o, char *why)
{
    mp_psf g;
    mp_psf_gauss(fwhm, &g);
    mp_prf_model m = {&g, NULL, 10};
    char err[MP_ERRLEN];
    mp_find_opts_default(o);
    assert_int_equal(mp_pl_sharp_limits(&m, 300, 200, o, why, 200, err), 0);
}

static void test_kernel_shape_unchanged(void **state)
{
    (void)state;
    mp_find_opts o;
    char why[200];
    limits_for(3.0, &o, why);
    assert_true(fabs(o.sharplo - 0.2) < 1e-12 && fabs(o.sharphi - 1.0) < 1e-12);
    assert_non_null(strstr(why, "sharpness"));
}

/* FWHM 0.9 px under the kernel of 3: at phase 0 SHARPNESS is above 1
 * (cut by DAOPHOT's limit, asserted); the widened limit keeps it. */
static void test_undersampled_widened(void **state)
{
    (void)state;
    mp_find_opts def, o;
    char why[200];
    mp_find_opts_default(&def);
    assert_int_equal(found_on_frame(0.9, &def), 0);
    limits_for(0.9, &o, why);
    assert_true(o.sharphi > 1.0 && fabs(o.sharplo - 0.2) < 1e-12);
    assert_int_equal(found_on_frame(0.9, &o), 1);
    /* A NaN limit (none) stays none. */
    mp_psf g;
    mp_psf_gauss(0.9, &g);
    mp_prf_model m = {&g, NULL, 10};
    char err[MP_ERRLEN];
    mp_find_opts_default(&o);
    o.sharphi = NAN;
    assert_int_equal(mp_pl_sharp_limits(&m, 300, 200, &o, why, sizeof why, err), 0);
    assert_true(isnan(o.sharphi));
    /* What find cannot measure (here a kernel it refuses) keeps the
     * limits as given and says so: the run goes on. */
    mp_find_opts_default(&o);
    o.nsigma = -1.0;
    assert_int_equal(mp_pl_sharp_limits(&m, 300, 200, &o, why, sizeof why, err), 0);
    assert_true(o.sharplo == 0.2 && o.sharphi == 1.0);
    assert_non_null(strstr(why, "as given"));
}

int main(void)
{
    const struct CMUnitTest tests[] = {
        cmocka_unit_test(test_kernel_shape_unchanged),
        cmocka_unit_test(test_undersampled_widened),
    };
    return cmocka_run_group_tests(tests, NULL, NULL);
}
