/* stiff_common.h — helpers shared by tests/unit/test_stiff_*.c and other
 * unit tests: frames in memory, simulated Gaussian stars (sim/, exact
 * pixel integrals, never the fitter's shifter), tables of start positions
 * and of fitted stars, and sampling statistics.
 * Every helper is static; each test file uses a subset. */
#ifndef MATPHOT_STIFF_COMMON_H
#define MATPHOT_STIFF_COMMON_H

#include <math.h>
#include <stdint.h>
#include <stdlib.h>
#include <string.h>
#include <time.h>

#include "catalog/catalog.h"
#include "fit/fit.h"
#include "io/io.h"
#include "sim/sim.h"

#define FWHM_SIGMA 2.3548200450309493   /* FWHM / sigma of a Gaussian */

/* A frame in memory: nx×ny, gain 1, read noise ron, no saturation. */
static inline void sf_frame_make(mp_frame *f, long nx, long ny, double ron)
{
    memset(f, 0, sizeof *f);
    f->im.nx = nx;
    f->im.ny = ny;
    f->im.pix = calloc((size_t)(nx * ny), sizeof *f->im.pix);
    f->mask = calloc((size_t)(nx * ny), 1);
    assert_non_null(f->im.pix);
    assert_non_null(f->mask);
    f->gain = 1.0;
    f->rdnoise = ron;
    f->saturate = INFINITY;
    f->exptime = 1.0;
}

static inline void sf_frame_drop(mp_frame *f)
{
    free(f->im.pix);
    free(f->mask);
    memset(f, 0, sizeof *f);
}

/* Fill with sky B, add Gaussian (FWHM fwhm) stars, then noise (ron < 0:
 * noiseless). */
static inline void sf_render(mp_frame *f, double B, double fwhm, const double *x,
                             const double *y, const double *E, int n, mp_rng *r, double ron)
{
    size_t np = (size_t)(f->im.nx * f->im.ny);
    for (size_t i = 0; i < np; i++)
        f->im.pix[i] = B;
    mp_sim_prf sp = {.kind = MP_SIM_GAUSS, .sigma = fwhm / FWHM_SIGMA, .volume = 1.0};
    for (int k = 0; k < n; k++)
        assert_int_equal(mp_sim_add_star_float(&sp, x[k], y[k], E[k], f->im.pix, f->im.nx,
                                         f->im.ny), 0);
    if (ron >= 0)
        mp_sim_add_noise_float(r, f->im.pix, (long)np, ron);
}

/* A start table: X_IMAGE, Y_IMAGE, GROUP_ID (gid ≤ 0: none), FLUX (NaN:
 * none). */
static inline void sf_table(mp_table *t, const double *x, const double *y, const double *E,
                            int n, int gid)
{
    mp_table_init(t);
    int cn = mp_table_add_col(t, "NUMBER"), cx = mp_table_add_col(t, "X_IMAGE");
    int cy = mp_table_add_col(t, "Y_IMAGE");
    int cg = gid > 0 ? mp_table_add_col(t, "GROUP_ID") : -1;
    int cf = E ? mp_table_add_col(t, "FLUX") : -1;
    assert_true(cn >= 0 && cx >= 0 && cy >= 0);
    for (int k = 0; k < n; k++) {
        long r = mp_table_add_row(t);
        assert_true(r >= 0);
        mp_table_set(t, (size_t)r, cn, k + 1);
        mp_table_set(t, (size_t)r, cx, x[k]);
        mp_table_set(t, (size_t)r, cy, y[k]);
        if (cg >= 0)
            mp_table_set(t, (size_t)r, cg, gid);
        if (cf >= 0)
            mp_table_set(t, (size_t)r, cf, E[k]);
    }
}

/* A fitted-star table, as the pipeline hands it on: XPSF_IMAGE,
 * YPSF_IMAGE, FLUX_PSF (E NULL: none) and SKY_PSF (sky NaN: none). */
static inline void sf_fitted_table(mp_table *t, const double *x, const double *y, const double *E,
                                   double sky, int n)
{
    mp_table_init(t);
    int cx = mp_table_add_col(t, "XPSF_IMAGE"), cy = mp_table_add_col(t, "YPSF_IMAGE");
    int cf = E ? mp_table_add_col(t, "FLUX_PSF") : -1;
    int cs = isfinite(sky) ? mp_table_add_col(t, "SKY_PSF") : -1;
    assert_true(cx >= 0 && cy >= 0);
    for (int k = 0; k < n; k++) {
        long r = mp_table_add_row(t);
        assert_true(r >= 0);
        mp_table_set(t, (size_t)r, cx, x[k]);
        mp_table_set(t, (size_t)r, cy, y[k]);
        if (cf >= 0)
            mp_table_set(t, (size_t)r, cf, E[k]);
        if (cs >= 0)
            mp_table_set(t, (size_t)r, cs, sky);
    }
}

static inline double sf_get(const mp_table *t, size_t row, const char *name)
{
    int c = mp_table_col(t, name);
    assert_true(c >= 0);
    return mp_table_get(t, row, c);
}

/* Every value of every row finite (MAG_PSF may be the 99 of a
 * non-positive flux, which is finite). */
static inline void sf_assert_all_finite(const mp_table *t)
{
    for (size_t i = 0; i < t->nrow * t->ncol; i++)
        assert_true(isfinite(t->v[i]));
}

static inline int sf_cmp_d(const void *a, const void *b)
{
    double x = *(const double *)a, y = *(const double *)b;
    return (x > y) - (x < y);
}

static inline double sf_median(double *v, size_t n)
{
    qsort(v, n, sizeof *v, sf_cmp_d);
    return n % 2 ? v[n / 2] : 0.5 * (v[n / 2 - 1] + v[n / 2]);
}

static inline double sf_robust_sigma(double *v, size_t n)
{
    qsort(v, n, sizeof *v, sf_cmp_d);
    return (v[(3 * n) / 4] - v[n / 4]) / 1.349;
}

static inline double sf_now(void)
{
    struct timespec ts;
    clock_gettime(CLOCK_MONOTONIC, &ts);
    return (double)ts.tv_sec + 1e-9 * (double)ts.tv_nsec;
}

#endif
