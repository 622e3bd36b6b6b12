/* test_psf_star_model.c — psf/star_model.c: the PSF stars' fits inside the
 * build drawn from the phase grid (within its bias bound) give the table
 * the exact renders give, to well inside the table's own noise; the grid
 * is built only when the fits pay for it.
 *
 * Frame: 64 stars drawn by sim/ (exact block-sums of a ×6 Gaussian table
 * at positions on its grid, no fitter code), Poisson + read noise, fixed
 * seed; the build at ×2, order 0. */
#include <math.h>
#include <setjmp.h>
#include <stdarg.h>
#include <stddef.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include <cmocka.h>

#include "fit/fit.h"
#include "psf/build.h"
#include "psf/build_priv.h"
#include "sim/sim.h"

#define NX 240
#define NSTAR 64
#define FOS 6
#define BOS 2
#define SKY 100.0
#define RON 3.0
#define RAD 6.0

typedef struct { double x, y, f; } tstar;

/* A round Gaussian of σ 1.1 px at ×FOS over ±RAD px, sum 1. */
static double *truth_fine(int *n)
{
    int h = (int)ceil(RAD * FOS), m = 2 * h + 1;
    double *t = malloc(sizeof(double) * m * m), sum = 0;
    assert_non_null(t);
    for (int j = 0; j < m; j++)
        for (int i = 0; i < m; i++) {
            double x = (double)(i - h) / FOS, y = (double)(j - h) / FOS;
            t[j * m + i] = exp(-0.5 * (x * x + y * y) / 1.21);
            sum += t[j * m + i];
        }
    for (int i = 0; i < m * m; i++)
        t[i] /= sum;
    *n = m;
    return t;
}

static void make_frame(uint64_t seed, mp_frame *f, tstar *ts)
{
    mp_rng r;
    mp_rng_seed(&r, seed);
    memset(f, 0, sizeof *f);
    f->im.nx = f->im.ny = NX;
    f->im.pix = calloc((size_t)NX * NX, sizeof *f->im.pix);
    f->mask = calloc((size_t)NX * NX, 1);
    assert_non_null(f->im.pix);
    assert_non_null(f->mask);
    f->gain = 1.0;
    f->rdnoise = RON;
    f->saturate = INFINITY;
    f->exptime = 1.0;
    for (size_t i = 0; i < (size_t)NX * NX; i++)
        f->im.pix[i] = SKY;
    int n, side = 8;
    double *tab = truth_fine(&n), cell = (NX - 2 * RAD) / side;
    for (int k = 0; k < NSTAR; k++) {
        double x = RAD + (k % side + 0.3 + 0.4 * mp_rng_uniform(&r)) * cell;
        double y = RAD + (k / side + 0.3 + 0.4 * mp_rng_uniform(&r)) * cell;
        double flux = 2e4 * pow(20.0, mp_rng_uniform(&r));
        mp_sim_prf p = {MP_SIM_TABLE, 0, tab, n, n, FOS, NULL, 0, 1.0, 0.0};
        mp_sim_snap(&p, &x, &y);
        assert_int_equal(mp_sim_add_star_float(&p, x, y, flux, f->im.pix, NX, NX), 0);
        ts[k] = (tstar){x, y, flux};
    }
    free(tab);
    mp_sim_add_noise_float(&r, f->im.pix, (long)NX * NX, RON);
}

static mp_epsf_star *stars_of(const mp_frame *f, const tstar *ts, const mp_epsf_opts *o)
{
    double x[NSTAR], y[NSTAR], fl[NSTAR], sk[NSTAR];
    for (int k = 0; k < NSTAR; k++) {
        x[k] = ts[k].x + 0.2;     /* a little off, as find would start */
        y[k] = ts[k].y - 0.15;
        fl[k] = ts[k].f;
        sk[k] = SKY;
    }
    mp_epsf_star *s;
    char err[MP_ERRLEN];
    assert_int_equal(mp_epsf_cutouts(f, f->im.pix, x, y, fl, sk, NSTAR, o->psfrad, &s, err), 0);
    return s;
}

/* χ² per pixel of PRF a against PRF b (pixels within 2.5 px of a star at
 * two phases), each pixel's variance that of a table estimated from the
 * NSTAR stars at one of BOS² phases (test_psf_build.c's prf_chi2):
 * var_i = BOS² / Σ_k F_k²/(F_k P_i + SKY + RON²).  Two independent
 * builds would differ by χ² ≈ 2 per pixel. */
static double prf_chi2(const mp_psf *a, const mp_psf *b, const tstar *ts)
{
    double chi2 = 0;
    int np = 0;
    for (int ph = 0; ph < 2; ph++) {
        double x = 30.0 + 0.5 * ph, y = 30.0 + 0.25 * ph;
        mp_prf_model ma = {a, NULL, 10}, mb = {b, NULL, 10};
        long ax, ay, bx, by;
        int aw, ah, bw, bh;
        mp_prf_box(&ma, x, y, &ax, &ay, &aw, &ah);
        mp_prf_box(&mb, x, y, &bx, &by, &bw, &bh);
        assert_true(ax == bx && ay == by && aw == bw && ah == bh);
        double *pa = malloc(sizeof(double) * aw * ah), *pb = malloc(sizeof(double) * bw * bh);
        assert_non_null(pa);
        assert_non_null(pb);
        mp_prf_work w;
        memset(&w, 0, sizeof w);
        assert_int_equal(mp_prf_render(&ma, x, y, pa, NULL, NULL, &w), 0);
        assert_int_equal(mp_prf_render(&mb, x, y, pb, NULL, NULL, &w), 0);
        for (int j = 0; j < ah; j++)
            for (int i = 0; i < aw; i++) {
                if (hypot(ax + i - x, ay + j - y) > 2.5)
                    continue;
                double P = pb[j * aw + i], info = 0;
                for (int k = 0; k < NSTAR; k++)
                    info += ts[k].f * ts[k].f / (ts[k].f * P + SKY + RON * RON);
                double d = pa[j * aw + i] - P;
                chi2 += d * d * info / (BOS * BOS);
                np++;
            }
        free(pa);
        free(pb);
        mp_prf_work_free(&w);
    }
    return chi2 / np;
}

/* The same stars built with the grid forced (grid=1) and with exact
 * renders (grid=-1): the grid serves the fits (their bias bound holds for
 * these stars), and the two tables differ by far less than the table's
 * noise.  Each star's fitted parameters move by at most 0.1 σ
 * (MP_EPSF_GRID_FRAC), so the table they build moves by about 0.1 of its
 * noise (χ² ~ 0.01 per pixel); 0.25 leaves room for a SIRT step taken in
 * one build and not the other (its stop rule is discrete), and is 8×
 * below the χ² of 2 of an independent rebuild. */
static void test_grid_same_table(void **state)
{
    (void)state;
    mp_frame f;
    tstar ts[NSTAR];
    make_frame(21, &f, ts);
    mp_epsf_opts o;
    mp_epsf_opts_default(2.6, NX, NX, &o);
    o.psfrad = RAD;
    o.fitrad = 4.0;
    mp_epsf e[2];
    mp_psf t[2];
    memset(e, 0, sizeof e);
    memset(t, 0, sizeof t);
    char err[MP_ERRLEN];
    for (int g = 0; g < 2; g++) {
        o.grid = g ? 1 : -1;
        mp_epsf_star *s = stars_of(&f, ts, &o);
        assert_int_equal(mp_epsf_build(s, NSTAR, &o, BOS, 0, &e[g], err), 0);
        assert_int_equal(mp_epsf_table(&e[g], o.x0, o.y0, &t[g], err), 0);
        mp_epsf_stars_free(s, NSTAR);
    }
    double c = prf_chi2(&t[1], &t[0], ts);
    printf("# grid: %ld of %ld star fits from the grid; exact %ld of %ld; chi2/pix grid vs "
           "exact %.3g\n", e[1].fits_grid, e[1].fits, e[0].fits_grid, e[0].fits, c);
    assert_int_equal(e[0].fits_grid, 0);
    assert_true(e[0].fits > 0);
    assert_true(e[1].fits_grid >= e[1].fits * 9 / 10);
    assert_true(c < 0.25);
    for (int g = 0; g < 2; g++) {
        mp_psf_free(&t[g]);
        mp_epsf_free(&e[g]);
    }
    free(f.im.pix);
    free(f.mask);
}

/* By default (grid=0) the grid is built only when the fits need more
 * renders than it costs: 64 lone stars, MP_ECON_RENDERS_PER_FIT = 4
 * renders each, 256 renders a step, against the ×2 table's coarsest grid,
 * (2·(4 + 3))² nodes + 8² measured cells = 260 renders: exact renders.
 * 40 stars with a neighbour each: fitted beside them, 4 renders of both
 * a fit, 320: the grid; held, 4 for the star and the neighbour's one,
 * 200: none. */
static void test_grid_only_when_it_pays(void **state)
{
    (void)state;
    mp_frame f;
    tstar ts[NSTAR];
    make_frame(22, &f, ts);
    mp_epsf_opts o;
    mp_epsf_opts_default(2.6, NX, NX, &o);
    o.psfrad = RAD;
    o.fitrad = 4.0;
    assert_int_equal(o.grid, 0);
    mp_epsf_star *s = stars_of(&f, ts, &o);
    mp_epsf e;
    memset(&e, 0, sizeof e);
    char err[MP_ERRLEN];
    assert_int_equal(mp_epsf_build(s, NSTAR, &o, BOS, 0, &e, err), 0);
    printf("# lone stars: %ld star fits, %ld from the grid\n", e.fits, e.fits_grid);
    assert_true(e.fits > 0);
    assert_int_equal(e.fits_grid, 0);
    /* With neighbours to fit beside each star, the same fits pay for it. */
    for (int k = 0; k < NSTAR; k++)
        s[k].nnb = 1;
    mp_epsf_fitter z;
    memset(&z, 0, sizeof z);
    assert_int_equal(mp_epsf_fitter_set(&z, &e, s, NSTAR, 0, err), 0);
    assert_true(z.grid.G > 0);
    mp_epsf_fitter_free(&z);
    for (int k = 0; k < NSTAR; k++) {
        s[k].used = k < 40;
        s[k].nbf[0] = s[k].flux;
    }
    for (int hold = 0; hold < 2; hold++) {
        memset(&z, 0, sizeof z);
        assert_int_equal(mp_epsf_fitter_set(&z, &e, s, NSTAR, hold, err), 0);
        assert_int_equal(z.grid.G > 0, !hold);
        mp_epsf_fitter_free(&z);
    }
    mp_epsf_free(&e);
    mp_epsf_stars_free(s, NSTAR);
    free(f.im.pix);
    free(f.mask);
}

int main(void)
{
    const struct CMUnitTest tests[] = {
        cmocka_unit_test(test_grid_same_table),
        cmocka_unit_test(test_grid_only_when_it_pays),
    };
    return cmocka_run_group_tests(tests, NULL, NULL);
}
