/* test_bleed.c — no detection on a saturated star's own features (issue
 * 13): a star far brighter than the full well, whose charge spills along
 * its column (a CCD's bleed trail: the run of full pixels ends in one
 * partly filled pixel at each end) and whose pixels at SATURATE are
 * clipped, is reduced by the pipeline with the defaults as `matphot
 * pipeline` reads a frame (mp_frame_read, datapars satgrow 1) and must
 * come out as one star, with FLAGS 1, and nothing else within the reach of
 * its trail.  The partly filled end pixels hold up to a full well of
 * charge the PSF cannot explain: with satgrow=0 they (and the ring of
 * spilled charge around the core) were fitted as stars (here: 3 entries
 * within 40 px on the short trail's first draw; the segmented
 * crowded frame of validate/CROWDED.md: 37 false entries beside its 8
 * saturated stars, 0 with satgrow 1).  Frames: 64×96 px, Gaussian FWHM 3
 * fitted with the analytic Gaussian, sky 100 e-, RON 3, gain 1, full well
 * 62000 e-, SATURATE 60000; NSEED noise draws, two brightnesses (trails of
 * about 10 and 30 px).  Nothing here is near a threshold: the star's S/N
 * is > 10³, a noise peak of S/N 5 has probability ~3e-7 per place. */
#include <setjmp.h>
#include <stdarg.h>
#include <stddef.h>
#include <cmocka.h>
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <unistd.h>
#include "io/io.h"
#include "pipeline/pipeline_priv.h"
#include "sim/sim.h"

#define NX 64
#define NY 96
#define FWHM 3.0
#define SKY 100.0
#define RON 3.0
#define FULLWELL 62000.0
#define SATURATE 60000.0
#define NSEED 3

typedef struct {
    mp_parset ps;
    mp_pipeline_opts o;
    char dir[64];
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
    snprintf(s->dir, sizeof s->dir, "/tmp/test_bleed.XXXXXX");
    if (!mkdtemp(s->dir))
        return -1;
    *state = s;
    return 0;
}

static int teardown_opts(void **state)
{
    setup *s = *state;
    char path[128];
    snprintf(path, sizeof path, "%s/f.fits", s->dir);
    unlink(path);
    rmdir(s->dir);
    mp_fit_setup_free(&s->o.fit);
    mp_params_free(&s->ps);
    free(s);
    return 0;
}

/* Charge above the full well in each column's runs spills half up, half
 * down the column, filling pixel after pixel (segmented.c's bleed). */
static void bleed(double *img)
{
    for (long x = 0; x < NX; x++)
        for (long y = 0; y < NY; y++) {
            if (img[y * NX + x] <= FULLWELL)
                continue;
            long y1 = y;
            double ex = 0;
            for (; y1 < NY && img[y1 * NX + x] > FULLWELL; y1++) {
                ex += img[y1 * NX + x] - FULLWELL;
                img[y1 * NX + x] = FULLWELL;
            }
            double up = 0.5 * ex, dn = 0.5 * ex;
            for (long j = y1; j < NY && up > 0; j++) {
                double t = fmin(fmax(FULLWELL - img[j * NX + x], 0.0), up);
                img[j * NX + x] += t;
                up -= t;
            }
            for (long j = y - 1; j >= 0 && dn > 0; j--) {
                double t = fmin(fmax(FULLWELL - img[j * NX + x], 0.0), dn);
                img[j * NX + x] += t;
                dn -= t;
            }
            y = y1;
        }
}

/* The frame with the star of E electrons at (x, y), written and read as
 * the pipeline reads it, reduced; *near: entries within 1 px of the star,
 * *flags its FLAGS; returns the entries within 40 px (the trail's reach). */
static int reduce(const setup *s, double x, double y, double E, uint64_t seed, int *near,
                  int *flags, int *trail)
{
    double *img = malloc(sizeof(double) * NX * NY);
    assert_non_null(img);
    for (int i = 0; i < NX * NY; i++)
        img[i] = SKY;
    mp_sim_prf prf = {.kind = MP_SIM_GAUSS, .sigma = FWHM / 2.3548200450309493, .volume = 1.0};
    assert_int_equal(mp_sim_add_star(&prf, x, y, E, img, NX, NY), 0);
    mp_rng r;
    mp_rng_seed(&r, seed);
    for (int i = 0; i < NX * NY; i++)
        img[i] = mp_rng_poisson(&r, img[i]);
    bleed(img);
    *trail = 0;
    for (int i = 0; i < NX * NY; i++) {
        *trail += img[i] >= FULLWELL;
        img[i] = fmin(img[i] + RON * mp_rng_normal(&r), SATURATE);
    }
    char path[128], err[MP_ERRLEN];
    snprintf(path, sizeof path, "%s/f.fits", s->dir);
    mp_card c[3] = {{"GAIN", 1.0, NULL, ""}, {"RDNOISE", RON, NULL, ""},
                    {"SATURATE", SATURATE, NULL, ""}};
    unlink(path);
    if (mp_image_write(path, img, NX, NY, -32, c, 3, err))
        fail_msg("%s", err);
    free(img);
    mp_frame f;
    mp_table t;
    if (mp_frame_read(path, &s->o.fit.dp, &f, err) || mp_pipeline_reduce(&f, &s->o, &t, NULL, err))
        fail_msg("%s", err);
    int cx = mp_table_col(&t, "XPSF_IMAGE"), cy = mp_table_col(&t, "YPSF_IMAGE");
    int cf = mp_table_col(&t, "FLAGS"), within = 0;
    *near = 0;
    *flags = -1;
    for (size_t j = 0; j < t.nrow; j++) {
        double d = hypot(mp_table_get(&t, j, cx) - x, mp_table_get(&t, j, cy) - y);
        within += d < 40.0;
        if (d < 1.0) {
            (*near)++;
            *flags = (int)mp_table_get(&t, j, cf);
        }
    }
    mp_table_free(&t);
    mp_frame_free(&f);
    return within;
}

static void one_star(void **state, double E)
{
    const setup *s = *state;
    for (int k = 0; k < NSEED; k++) {
        int near, flags, trail;
        int n = reduce(s, 32.3, 48.2, E, 3000 + (uint64_t)k, &near, &flags, &trail);
        if (n != 1 || near != 1 || !(flags & 1))
            fail_msg("E = %.0f e-, seed %d (%d full pixels): %d entries within 40 px, %d within "
                     "1 px, FLAGS %d", E, 3000 + k, trail, n, near, flags);
    }
}

static void test_short_trail(void **state) { one_star(state, 3e6); }
static void test_long_trail(void **state) { one_star(state, 1e7); }

int main(void)
{
    const struct CMUnitTest tests[] = {
        cmocka_unit_test(test_short_trail),
        cmocka_unit_test(test_long_trail),
    };
    return cmocka_run_group_tests(tests, setup_opts, teardown_opts);
}
