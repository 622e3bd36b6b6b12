/* bench_fit.c — fit throughput (stars per CPU-second) for the FWHM-3
 * discrete case of design.md §6, as the median of repeated runs, with the
 * analytic-Gaussian fit of the same frames as the in-run baseline. */
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <time.h>
#include "fit/fit.h"
#include "sim/sim.h"

enum { NP = 60 };

static double cpu_seconds(void)
{
    struct timespec ts;
    clock_gettime(CLOCK_PROCESS_CPUTIME_ID, &ts);
    return ts.tv_sec + 1e-9 * ts.tv_nsec;
}

static int cmp_d(const void *a, const void *b)
{
    double x = *(const double *)a, y = *(const double *)b;
    return (x > y) - (x < y);
}

/* Fit every frame once; return CPU seconds. */
static double run(const mp_prf_model *m, float **frames, const double *truth, int n)
{
    char err[MP_ERRLEN];
    mp_fit_opts o;
    mp_fit_opts_default(&o);
    mp_frame f;
    memset(&f, 0, sizeof f);
    f.im.nx = f.im.ny = NP;
    f.gain = 1.0;
    f.rdnoise = 3.0;
    f.saturate = INFINITY;
    uint8_t mask[NP * NP] = {0};
    f.mask = mask;
    double t0 = cpu_seconds();
    for (int s = 0; s < n; s++) {
        f.im.pix = frames[s];
        mp_star st = {.x = truth[2 * s] + 0.1, .y = truth[2 * s + 1] - 0.1, .flux = NAN};
        if (mp_fit_group(&f, m, &o, NAN, &st, 1, err)) {
            fprintf(stderr, "bench: %s\n", err);
            exit(1);
        }
    }
    return cpu_seconds() - t0;
}

int main(int argc, char **argv)
{
    int n = argc > 1 ? atoi(argv[1]) : 400, reps = argc > 2 ? atoi(argv[2]) : 7;
    mp_blas_single_thread();
    if (n < 1 || reps < 1)
        return 2;
    char err[MP_ERRLEN];
    mp_psf tab, gau;
    if (mp_psf_gauss_table(3.0, 1, 15.0, &tab, err)) {
        fprintf(stderr, "bench: %s\n", err);
        return 1;
    }
    mp_psf_gauss(3.0, &gau);
    mp_sim_prf sp = {.kind = MP_SIM_GAUSS, .sigma = gau.sigma, .volume = 1.0};
    float **frames = malloc((size_t)n * sizeof *frames);
    double *truth = malloc(2 * (size_t)n * sizeof *truth);
    if (!frames || !truth)
        return 1;
    mp_rng r;
    mp_rng_seed(&r, 20261122);
    for (int s = 0; s < n; s++) {
        frames[s] = malloc(NP * NP * sizeof **frames);
        if (!frames[s])
            return 1;
        for (int i = 0; i < NP * NP; i++)
            frames[s][i] = 100.0;
        double mag = -6.0 - 9.0 * mp_rng_uniform(&r);
        truth[2 * s] = 30.0 + mp_rng_uniform(&r);
        truth[2 * s + 1] = 30.0 + mp_rng_uniform(&r);
        mp_sim_add_star_float(&sp, truth[2 * s], truth[2 * s + 1], pow(10, -0.4 * mag), frames[s], NP, NP);
        mp_sim_add_noise_float(&r, frames[s], NP * NP, 3.0);
    }
    mp_prf_model md = {&tab, NULL, 10}, ma = {&gau, NULL, 10};
    double *td = malloc((size_t)reps * sizeof *td), *ta = malloc((size_t)reps * sizeof *ta);
    if (!td || !ta)
        return 1;
    for (int k = 0; k < reps; k++) {   /* interleaved, so machine noise hits both */
        td[k] = run(&md, frames, truth, n);
        ta[k] = run(&ma, frames, truth, n);
    }
    qsort(td, (size_t)reps, sizeof *td, cmp_d);
    qsort(ta, (size_t)reps, sizeof *ta, cmp_d);
    double d = td[reps / 2], a = ta[reps / 2];
    printf("fit throughput, FWHM 3, 60x60 single-star frames, %d stars x %d runs (median):\n", n, reps);
    printf("  discrete 1x table : %8.1f stars/CPU-s  (%.3f ms/star)\n", n / d, 1e3 * d / n);
    printf("  analytic Gaussian : %8.1f stars/CPU-s  (%.3f ms/star)  [baseline]\n", n / a, 1e3 * a / n);
    printf("  ratio discrete/analytic throughput: %.3f\n", a / d);
    for (int s = 0; s < n; s++)
        free(frames[s]);
    free(frames);
    free(truth);
    free(td);
    free(ta);
    mp_psf_free(&tab);
    return 0;
}
