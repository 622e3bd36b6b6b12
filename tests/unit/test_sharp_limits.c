/* test_sharp_limits.c — find's sharpness limits fitted to the PSF
 * (pipeline/sharp_limits.c, mp_pl_sharp_limits): a PSF of the kernel's
 * own shape leaves DAOPHOT's limits as they are; an undersampled one
 * widens them just enough that a noiseless star of it, at the phase where
 * it is sharpest, is detected where DAOPHOT's limits cut it; and a run
 * that builds its PSF searches its residual with that PSF's limits, not
 * its start's (the limits are kept per model, run_state.sharp_known). */
#include <setjmp.h>
#include <stdarg.h>
#include <stddef.h>
#include <cmocka.h>
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include "io/io.h"
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

/* The limits are measured once per PSF model (run_state.sharp_known) and
 * measured again when the model changes (adopt_psf).  A run that builds
 * its PSF from a frame of Moffat stars (β 2.5, FWHM 3: a sharper core
 * than the start's Gaussian of fwhm 3) searches the residual with the
 * built PSF, and the report's sharpness line must be that PSF's: exactly
 * mp_pl_sharp_limits on the written root.psf.fits.  Were the limits kept
 * across the change, the line would be the start Gaussian's, which the
 * test first shows to differ from the built PSF's. */
#define NM 192
#define NGM 7

static void add_moffat(float *img, double x, double y, double e)
{
    const double beta = 2.5, fwhm = 3.0, rcut = 15.0;
    double a = fwhm / (2.0 * sqrt(pow(2.0, 1.0 / beta) - 1.0));
    double norm = (beta - 1.0) / (M_PI * a * a);   /* unit integral (to infinity) */
    for (long j = (long)(y - rcut); j <= (long)(y + rcut); j++)
        for (long i = (long)(x - rcut); i <= (long)(x + rcut); i++) {
            double r2 = (i - x) * (i - x) + (j - y) * (j - y);
            if (i >= 1 && j >= 1 && i <= NM && j <= NM && r2 <= rcut * rcut)
                img[(size_t)(j - 1) * NM + (size_t)(i - 1)] +=
                    (float)(e * norm * pow(1.0 + r2 / (a * a), -beta));
        }
}

/* The report's sharpness line the model in psf (a file, or "gauss") gives
 * with the pipeline's find options, into why. */
static void limits_of(const char *psf, char *why, size_t n)
{
    char err[MP_ERRLEN];
    mp_parset ps;
    mp_pipeline_opts o;
    memset(&o, 0, sizeof o);
    if (mp_params_defaults("pipeline", &ps, err) || mp_params_set(&ps, "psf", psf, err) ||
        mp_pl_opts_read(&ps, &o, err))
        fail_msg("options: %s", err);
    mp_find_opts fo = o.find;
    fo.fwhm = mp_prf_fwhm(&o.fit.model);
    assert_int_equal(mp_pl_sharp_limits(&o.fit.model, NM, NM, &fo, why, n, err), 0);
    mp_fit_setup_free(&o.fit);
    mp_params_free(&ps);
}

static void test_limits_follow_the_built_psf(void **state)
{
    (void)state;
    char dir[512], img[600], root[600], path[620], err[MP_ERRLEN];
    const char *tmp = getenv("TMPDIR");
    snprintf(dir, sizeof dir, "%s/test_sharp_limits.XXXXXX", tmp && *tmp ? tmp : "/tmp");
    assert_non_null(mkdtemp(dir));
    float *pix = malloc((size_t)NM * NM * sizeof *pix);
    assert_non_null(pix);
    for (size_t k = 0; k < (size_t)NM * NM; k++)
        pix[k] = 100.0f;
    for (int k = 0; k < NGM * NGM; k++)
        add_moffat(pix, 18.3 + 26.0 * (k % NGM) + 0.37 * (k % 3),
                   17.8 + 26.0 * (k / NGM) + 0.29 * (k % 4), 2e4 * (1.0 + (k * 7) % 5));
    mp_rng r;
    mp_rng_seed(&r, 2025);
    mp_sim_add_noise_float(&r, pix, (long)NM * NM, 3.0);
    double *d = malloc((size_t)NM * NM * sizeof *d);
    assert_non_null(d);
    for (size_t k = 0; k < (size_t)NM * NM; k++)
        d[k] = pix[k];
    mp_card c[2] = {{"GAIN", 1.0, NULL, "e-/ADU"}, {"RDNOISE", 3.0, NULL, "e-"}};
    snprintf(img, sizeof img, "%s/m.fits", dir);
    assert_int_equal(mp_image_write(img, d, NM, NM, -32, c, 2, err), 0);
    free(d);
    free(pix);

    mp_parset ps;
    mp_pipeline_opts o;
    memset(&o, 0, sizeof o);
    if (mp_params_defaults("pipeline", &ps, err) || mp_params_set(&ps, "varorder", "0", err) ||
        mp_pl_opts_read(&ps, &o, err))
        fail_msg("options: %s", err);
    snprintf(root, sizeof root, "%s/m", dir);
    mp_pipeline_report rep;
    if (mp_pipeline_run(img, root, &o, &rep, err))
        fail_msg("pipeline: %s", err);
    mp_fit_setup_free(&o.fit);
    mp_params_free(&ps);

    char built[200], start[200];
    snprintf(path, sizeof path, "%s.psf.fits", root);
    limits_of(path, built, sizeof built);
    limits_of("gauss", start, sizeof start);
    fprintf(stderr, "report: %s\nbuilt:  %s\nstart:  %s\n", rep.sharp, built, start);
    assert_string_not_equal(built, start);
    assert_string_equal(rep.sharp, built);
    char cmd[600];
    snprintf(cmd, sizeof cmd, "rm -rf '%s'", dir);
    assert_int_equal(system(cmd), 0);
}

int main(void)
{
    const struct CMUnitTest tests[] = {
        cmocka_unit_test(test_kernel_shape_unchanged),
        cmocka_unit_test(test_undersampled_widened),
        cmocka_unit_test(test_limits_follow_the_built_psf),
    };
    return cmocka_run_group_tests(tests, NULL, NULL);
}
