/* test_grouped_rows.c — root.grp written each round (its values past
 * mp_pipeline_opts.grp_hold: pipeline/run.c keep_grouped, taken by frames
 * of more than ~32 000 stars) is the same file as root.grp held and
 * written with the other products, and the products beside it are the
 * same bytes: root.fit copies root.grp's text of the stars the last round
 * did not refit only when root.grp was held, and writes them itself when
 * it was not.  A frame of 60 Gaussian stars (FWHM 3 px) on 128², sky
 * 100 e-, RON 3, gain 1, a fixed seed; the pipeline's defaults (three
 * rounds), once each way.  Deterministic: a difference is a defect. */
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

#define N 128
#define NSTAR 60
#define SKY 100.0
#define RON 3.0

static const char *const products[] = {".coo", ".grp", ".fit", ".cat", ".res.fits"};
#define NPRODUCT (sizeof products / sizeof *products)

typedef struct {
    char dir[64], image[96];
} scratch;

static int write_frame(const char *path)
{
    double *img = malloc(sizeof(double) * N * N);
    char err[MP_ERRLEN];
    if (!img)
        return -1;
    for (int i = 0; i < N * N; i++)
        img[i] = SKY;
    mp_sim_prf prf = {.kind = MP_SIM_GAUSS, .sigma = 3.0 / 2.3548200450309493, .volume = 1.0};
    mp_rng r;
    mp_rng_seed(&r, 20261207);
    int rc = 0;
    for (int k = 0; k < NSTAR && !rc; k++) {
        double x = 6.0 + (N - 11.0) * mp_rng_uniform(&r), y = 6.0 + (N - 11.0) * mp_rng_uniform(&r);
        rc = mp_sim_add_star(&prf, x, y, 2e3 * pow(100.0, mp_rng_uniform(&r)), img, N, N);
    }
    for (int i = 0; i < N * N && !rc; i++)
        img[i] = mp_rng_poisson(&r, img[i]) + RON * mp_rng_normal(&r);
    mp_card c[2] = {{"GAIN", 1.0, NULL, ""}, {"RDNOISE", RON, NULL, ""}};
    rc = rc || mp_image_write(path, img, N, N, -32, c, 2, err);
    free(img);
    return rc ? -1 : 0;
}

static int setup(void **state)
{
    scratch *s = calloc(1, sizeof *s);
    if (!s)
        return -1;
    snprintf(s->dir, sizeof s->dir, "/tmp/test_grouped_rows.XXXXXX");
    if (!mkdtemp(s->dir))
        return -1;
    snprintf(s->image, sizeof s->image, "%s/f.fits", s->dir);
    *state = s;
    return write_frame(s->image);
}

static int teardown(void **state)
{
    scratch *s = *state;
    char path[160];
    for (int held = 0; held < 2; held++)
        for (size_t k = 0; k < MP_PL_NPRODUCT; k++) {
            snprintf(path, sizeof path, "%s/%c%s", s->dir, held ? 'h' : 'w', mp_pl_products[k]);
            unlink(path);
        }
    unlink(s->image);
    rmdir(s->dir);
    free(s);
    return 0;
}

/* The pipeline on s's frame into root dir/<name>, root.grp held up to
 * hold bytes. */
static void run(const scratch *s, char name, double hold)
{
    mp_parset ps;
    mp_pipeline_opts o;
    mp_pipeline_report rep;
    char err[MP_ERRLEN], root[96];
    snprintf(root, sizeof root, "%s/%c", s->dir, name);
    if (mp_params_defaults("pipeline", &ps, err) || mp_params_set(&ps, "psf", "gauss", err) ||
        mp_params_set(&ps, "fwhm", "3", err) || mp_pl_opts_read(&ps, &o, err))
        fail_msg("%s", err);
    o.grp_hold = hold;
    int rc = mp_pipeline_run(s->image, root, &o, &rep, err);
    mp_fit_setup_free(&o.fit);
    mp_params_free(&ps);
    if (rc)
        fail_msg("%s", err);
    assert_true(rep.rounds >= 2);     /* root.grp written more than once */
}

/* The bytes of dir/<name><ext>, its length into *n. */
static char *slurp(const scratch *s, char name, const char *ext, size_t *n)
{
    char path[160];
    snprintf(path, sizeof path, "%s/%c%s", s->dir, name, ext);
    FILE *fp = fopen(path, "rb");
    if (!fp)
        fail_msg("%s: not written", path);
    char *b = NULL;
    *n = 0;
    size_t cap = 0, k;
    char buf[65536];
    while ((k = fread(buf, 1, sizeof buf, fp)) > 0) {
        if (*n + k > cap && !(b = realloc(b, cap = 2 * (*n + k))))
            fail_msg("out of memory");
        memcpy(b + *n, buf, k);
        *n += k;
    }
    fclose(fp);
    return b;
}

static void test_written_each_round_is_held(void **state)
{
    const scratch *s = *state;
    run(s, 'h', 8.0 * 1024 * 1024);
    run(s, 'w', 0.0);
    for (size_t k = 0; k < NPRODUCT; k++) {
        size_t nh, nw;
        char *h = slurp(s, 'h', products[k], &nh), *w = slurp(s, 'w', products[k], &nw);
        /* a FITS residual's header names no root: the same bytes too */
        if (nh != nw || memcmp(h, w, nh) != 0)
            fail_msg("root%s: %zu bytes held, %zu written each round, not the same", products[k],
                     nh, nw);
        if (k == 1)
            assert_true(nh > 1000);   /* a table of the stars, not an empty file */
        free(h);
        free(w);
    }
}

int main(void)
{
    const struct CMUnitTest tests[] = {
        cmocka_unit_test_setup_teardown(test_written_each_round_is_held, setup, teardown),
    };
    return cmocka_run_group_tests(tests, NULL, NULL);
}
