/* test_psf_stars.c — the PSF stars used are in the PSF file (issue 11:
 * "the PSF stars used"; README, PSF-file layout: the PSFSTARS extension),
 * read back by mp_psf_field_read, from each writer: `matphot psf` with one
 * pass and with two, and the pipeline's build (mp_pl_psf_on, as a whole
 * run and as a tile whose pixel (1, 1) is not the frame's).
 *
 * The frame: 128 × 128 px, 36 stars of a round Gaussian (FWHM 3 px) on a
 * 6 × 6 grid 20 px apart (no neighbour within the 12 px PSF radius), 10⁴
 * to 4·10⁴ e−, sky 100 e−, read noise 3 e−, one fixed noise draw.  What
 * must hold: the file lists at least 10 stars, as many used as its
 * PSFNSTAR says; every listed star lies within 0.2 px of a true star
 * (σ_X of these stars is ≤ 0.02 px: 10 σ) in the frame's coordinates, and
 * its flux (total, on the table's PSFSUM scale) within 5 % of the truth
 * (σ_E/E ≤ 1.2 %: 4 σ).  No false failure at these margins. */
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
#include "psf/build.h"
#include "sim/sim.h"

#define N 128
#define NG 6
#define FWHM 3.0
#define SKY 100.0
#define RON 3.0

typedef struct {
    char dir[512], frame[600];
    double x[NG * NG], y[NG * NG], e[NG * NG];
} fixture;

static int setup(void **state)
{
    fixture *s = calloc(1, sizeof *s);
    if (!s)
        return 1;
    const char *tmp = getenv("TMPDIR");
    snprintf(s->dir, sizeof s->dir, "%s/test_psf_stars.XXXXXX", tmp && *tmp ? tmp : "/tmp");
    if (!mkdtemp(s->dir))
        return free(s), 1;
    double *img = malloc(sizeof *img * N * N);
    if (!img)
        return free(s), 1;
    for (int i = 0; i < N * N; i++)
        img[i] = SKY;
    mp_sim_prf prf = {.kind = MP_SIM_GAUSS, .sigma = FWHM / 2.3548200450309493, .volume = 1.0};
    for (int k = 0; k < NG * NG; k++) {
        s->x[k] = 14.3 + 20.0 * (k % NG) + 0.37 * (k % 3);
        s->y[k] = 13.8 + 20.0 * (k / NG) + 0.29 * (k % 4);
        s->e[k] = 1e4 * pow(4.0, (double)((k * 7) % 11) / 10.0);
        if (mp_sim_add_star(&prf, s->x[k], s->y[k], s->e[k], img, N, N))
            return free(img), free(s), 1;
    }
    mp_rng r;
    mp_rng_seed(&r, 1107);
    mp_sim_add_noise(&r, img, (long)N * N, RON);
    mp_card c[2] = {{"GAIN", 1.0, NULL, "e-/ADU"}, {"RDNOISE", RON, NULL, "e-"}};
    char err[MP_ERRLEN];
    snprintf(s->frame, sizeof s->frame, "%s/f.fits", s->dir);
    int rc = mp_image_write(s->frame, img, N, N, -32, c, 2, err);
    free(img);
    if (rc)
        return fprintf(stderr, "setup: %s\n", err), free(s), 1;
    *state = s;
    return 0;
}

static int teardown(void **state)
{
    fixture *s = *state;
    char cmd[600];
    snprintf(cmd, sizeof cmd, "rm -rf '%s'", s->dir);
    int rc = system(cmd);
    free(s);
    return rc != 0;
}

/* The file's PSFSTARS against the truth (see the top). */
static void check_stars(const fixture *s, const char *path)
{
    char err[MP_ERRLEN], warn[MP_ERRLEN] = "";
    mp_psf_field f;
    mp_psf_star *st = NULL;
    int n = -1;
    if (mp_psf_field_read(path, 0, 0, &f, &st, &n, warn, err))
        fail_msg("%s: %s", path, err);
    if (n < 10 || !st)
        fail_msg("%s: %d PSF stars listed", path, n);
    int used = 0;
    for (int q = 0; q < n; q++) {
        used += st[q].used != 0;
        int best = 0;
        for (int k = 1; k < NG * NG; k++)
            if (hypot(st[q].x - s->x[k], st[q].y - s->y[k]) <
                hypot(st[q].x - s->x[best], st[q].y - s->y[best]))
                best = k;
        double d = hypot(st[q].x - s->x[best], st[q].y - s->y[best]);
        if (d > 0.2)
            fail_msg("%s: PSF star %d at (%.2f, %.2f): %.2f px from the nearest true star", path,
                     q + 1, st[q].x, st[q].y, d);
        if (st[q].used && fabs(st[q].flux / s->e[best] - 1.0) > 0.05)
            fail_msg("%s: PSF star %d: flux %.1f against %.1f", path, q + 1, st[q].flux,
                     s->e[best]);
    }
    if (used != f.nstar || used < 10)
        fail_msg("%s: %d stars marked used, PSFNSTAR %d", path, used, f.nstar);
    free(st);
    mp_psf_field_free(&f);
}

/* `matphot psf` with passes=P. */
static void psf_task(void **state, const char *passes)
{
    const fixture *s = *state;
    char out[700], oarg[720], parg[32];
    snprintf(out, sizeof out, "%s/p%s.psf.fits", s->dir, passes);
    snprintf(oarg, sizeof oarg, "output=%s", out);
    snprintf(parg, sizeof parg, "passes=%s", passes);
    char *argv[] = {"psf", (char *)s->frame, oarg, parg, "fwhm=3", "oversamp=2", "varorder=0"};
    assert_int_equal(mp_task_psf(7, argv), 0);
    check_stars(s, out);
}

static void test_psf_one_pass(void **state) { psf_task(state, "1"); }
static void test_psf_two_passes(void **state) { psf_task(state, "2"); }

/* The pipeline's build, on the whole frame and on its right part as a
 * tile (pixel (1, 1) = frame pixel (41, 1)): the stars in frame pixels. */
static void pipeline_build(void **state, int tile)
{
    const fixture *s = *state;
    char err[MP_ERRLEN], root[700], img[700], path[720];
    mp_parset ps;
    mp_pipeline_opts o;
    memset(&o, 0, sizeof o);
    if (mp_params_defaults("pipeline", &ps, err) || mp_params_set(&ps, "varorder", "0", err) ||
        mp_pl_opts_read(&ps, &o, err))
        fail_msg("options: %s", err);
    snprintf(root, sizeof root, "%s/%s", s->dir, tile ? "tile" : "whole");
    snprintf(img, sizeof img, tile ? "%s[41:128,1:128]" : "%s", s->frame);
    int built = 0;
    if (mp_pl_psf_on(img, root, &o, tile ? 40 : 0, 0, N, N, &built, err))
        fail_msg("mp_pl_psf_on: %s", err);
    assert_true(built);
    snprintf(path, sizeof path, "%s.psf.fits", root);
    check_stars(s, path);
    mp_fit_setup_free(&o.fit);
    mp_params_free(&ps);
}

static void test_pipeline_whole(void **state) { pipeline_build(state, 0); }
static void test_pipeline_tile(void **state) { pipeline_build(state, 1); }

int main(void)
{
    const struct CMUnitTest tests[] = {
        cmocka_unit_test(test_psf_one_pass),
        cmocka_unit_test(test_psf_two_passes),
        cmocka_unit_test(test_pipeline_whole),
        cmocka_unit_test(test_pipeline_tile),
    };
    return cmocka_run_group_tests(tests, setup, teardown);
}
