/* test_deriv_box.c — a star's position derivatives drawn within its core
 * box alone (issue 12, fit/prf_deriv_box.c, fit/lm_render.c): the limit is
 * the share of information the box's outside holds, as measured here
 * independently; a fit within that limit reports a position σ no more than
 * 1/sqrt(1 − MP_DBOX_SHARE) of the whole window's, and lands within the
 * spread that σ difference allows. */
#include <setjmp.h>
#include <stdarg.h>
#include <stddef.h>
#include <cmocka.h>
#include <math.h>
#include <stdlib.h>
#include <string.h>

#include "fit/fit.h"
#include "sim/sim.h"
#include "tests/unit/stiff_common.h"

/* A core with a halo: 0.9 of a FWHM 2.5 px Gaussian and 0.1 of a FWHM
 * 8 px one, ×2, ±12 px — wings that hold position information several
 * pixels out, as a real PSF's do. */
static void halo_table(mp_psf *p)
{
    char err[MP_ERRLEN];
    mp_psf h;
    assert_int_equal(mp_psf_gauss_table(2.5, 2, 12.0, p, err), 0);
    assert_int_equal(mp_psf_gauss_table(8.0, 2, 12.0, &h, err), 0);
    assert_int_equal(p->nx, h.nx);
    for (int i = 0; i < p->nx * p->ny; i++)
        p->t[i] = 0.9 * p->t[i] + 0.1 * h.t[i];
    p->sum = 0.9 * p->sum + 0.1 * h.sum;
    mp_psf_free(&h);
}

/* The lost share max(I_out/(I_disc + I_out)) over x and y at u for a star
 * at (X, Y), summed directly over the grid's render. */
static double lost_share(const mp_prf_model *m, mp_prf_work *w, double X, double Y, double hw,
                         double rd, double u)
{
    long x0, y0;
    int bw, bh;
    mp_prf_box(m, X, Y, &x0, &y0, &bw, &bh);
    size_t n = (size_t)bw * bh;
    double *b = malloc(3 * n * sizeof *b), in[2] = {0}, out[2] = {0};
    assert_non_null(b);
    assert_int_equal(mp_prf_render(m, X, Y, b, b + n, b + 2 * n, w), 0);
    for (int j = 0; j < bh; j++)
        for (int i = 0; i < bw; i++) {
            double x = (double)(x0 + i), y = (double)(y0 + j), P = b[(size_t)j * bw + i];
            double v = 1.0 / ((P > 0 ? P : 0.0) + 1.0 / u);
            int far = x < floor(X - hw) || x > ceil(X + hw) || y < floor(Y - hw) || y > ceil(Y + hw);
            int disc = hypot(x - X, y - Y) <= rd;
            for (int a = 0; a < 2; a++) {
                double g = b[(size_t)(a + 1) * n + (size_t)j * bw + i];
                in[a] += disc ? v * g * g : 0.0;
                out[a] += far ? v * g * g : 0.0;
            }
        }
    free(b);
    return fmax(out[0] / (in[0] + out[0]), out[1] / (in[1] + out[1]));
}

/* At the limit every one of the 16 phases loses at most MP_DBOX_SHARE; at
 * the next u of its grid (8 a decade) one loses more: the limit is that
 * share, to the grid's step. */
static void test_limit_is_the_share(void **state)
{
    (void)state;
    char err[MP_ERRLEN];
    mp_psf p;
    halo_table(&p);
    mp_prf_model m = {&p, NULL, 10};
    mp_prf_cache c;
    const double fitrad = 3.0;
    assert_int_equal(mp_prf_cache_build(&m, 16, &c, err), 0);
    assert_int_equal(mp_prf_cache_deriv_box(&c, &m, fitrad, MP_DBOX_SHARE, err), 0);
    double hw = mp_fit_core_halfwidth(fitrad), u = c.dbox_u;
    assert_true(c.dbox_hw == hw);
    assert_true(u > 0 && isfinite(u));
    mp_prf_work w = {0};
    w.grid = &c;
    double at = 0.0, above = 0.0;
    for (int b = 0; b < 16; b++) {
        double X = 1000.0 + (b % 4) / 4.0, Y = 1000.0 + (b / 4) / 4.0;
        at = fmax(at, lost_share(&m, &w, X, Y, hw, fitrad - 1.0, u));
        above = fmax(above, lost_share(&m, &w, X, Y, hw, fitrad - 1.0, u * pow(10.0, 0.125)));
    }
    assert_true(at <= MP_DBOX_SHARE);
    assert_true(above > MP_DBOX_SHARE);
    /* No fitting radius, no box. */
    assert_int_equal(mp_prf_cache_deriv_box(&c, &m, NAN, MP_DBOX_SHARE, err), 0);
    assert_true(c.dbox_u == 0.0);
    mp_prf_work_free(&w);
    mp_prf_cache_free(&c);
    mp_psf_free(&p);
}

/* Two stars 7 px apart, fitting radius 3 (box ±5 px): the bright one's
 * window reaches the faint one's disc, beyond its box.  Fitted with its
 * derivatives in the box (at half the limit's flux) and on its whole
 * window, over NF noisy frames.  The box's fit loses at most the share s
 * = MP_DBOX_SHARE of the information, so its position variance is at
 * most 1/(1 − s) of the whole window's (the efficient one), and the two
 * estimates differ by a σ of at most σ_whole·sqrt(1/(1 − s) − 1) (the
 * difference's own variance, Var_box − Var_whole, as the whole window's is
 * efficient): they must agree within 4.5 of that (a false failure in about
 * 1e-5 a comparison, 2e-3 over the test) plus each fit's tolerance,
 * 2·tol·σ.  The σ each fit reports (the inverse of its own normal
 * matrix, not the sandwich) agrees with the whole window's within the
 * same factor, and differs for the bright star: the box was used. */
static void test_fit_within_bound(void **state)
{
    (void)state;
    enum { NF = 40, NP = 40 };
    const double B = 100.0, RON = 3.0, fitrad = 3.0;
    char err[MP_ERRLEN];
    mp_psf p;
    halo_table(&p);
    mp_prf_model m = {&p, NULL, 10};
    mp_prf_cache cb, cw;
    assert_int_equal(mp_prf_cache_build(&m, 16, &cb, err), 0);
    assert_int_equal(mp_prf_cache_deriv_box(&cb, &m, fitrad, MP_DBOX_SHARE, err), 0);
    cw = cb;
    cw.dbox_u = 0.0;            /* the same grid, derivatives on whole windows */
    double E1 = 0.5 * cb.dbox_u * (B + RON * RON), E2 = 2e4;
    assert_true(E1 > 1e4 && isfinite(E1));
    mp_frame f;
    sf_frame_make(&f, NP, NP, RON);
    mp_fit_opts o;
    mp_fit_opts_default(&o);
    o.fitrad = fitrad;
    o.sky_order = 0;
    mp_prf_work w = {0};
    long x0, y0;
    int bw, bh;
    mp_prf_box(&m, 0.0, 0.0, &x0, &y0, &bw, &bh);
    double *buf = malloc((size_t)(bw + 2) * (bh + 2) * sizeof *buf);
    assert_non_null(buf);
    int grew = 0;
    mp_rng r;
    for (int s = 0; s < NF; s++) {
        mp_rng_seed(&r, 4200 + (uint64_t)s);
        double xs[2] = {17.0 + mp_rng_uniform(&r), 0.0}, ys[2] = {20.0 + mp_rng_uniform(&r), 0.0};
        xs[1] = xs[0] + 7.0;
        ys[1] = ys[0] + 0.3;
        const double Es[2] = {E1, E2};
        for (long i = 0; i < NP * NP; i++)
            f.im.pix[i] = (float)B;
        for (int k = 0; k < 2; k++) {
            mp_prf_box(&m, xs[k], ys[k], &x0, &y0, &bw, &bh);
            assert_int_equal(mp_prf_render(&m, xs[k], ys[k], buf, NULL, NULL, &w), 0);
            for (int j = 0; j < bh; j++)
                for (int i = 0; i < bw; i++) {
                    long X = x0 + i, Y = y0 + j;
                    if (X >= 1 && Y >= 1 && X <= NP && Y <= NP)
                        f.im.pix[(Y - 1) * NP + X - 1] += (float)(Es[k] * buf[(size_t)j * bw + i]);
                }
        }
        mp_sim_add_noise_float(&r, f.im.pix, NP * NP, RON);
        mp_star sb[2], sw[2];
        for (int k = 0; k < 2; k++)
            sb[k] = (mp_star){.x = xs[k] + 0.1, .y = ys[k] - 0.1, .flux = Es[k]};
        memcpy(sw, sb, sizeof sb);
        o.grid = &cb;
        assert_int_equal(mp_fit_group(&f, &m, &o, B, sb, 2, err), 0);
        o.grid = &cw;
        assert_int_equal(mp_fit_group(&f, &m, &o, B, sw, 2, err), 0);
        for (int k = 0; k < 2; k++) {
            assert_int_equal((sb[k].flags | sw[k].flags) & MP_FLAG_NOCONV, 0);
            const double eb[2] = {sb[k].ex, sb[k].ey}, ew[2] = {sw[k].ex, sw[k].ey};
            const double vb[2] = {sb[k].x, sb[k].y}, vw[2] = {sw[k].x, sw[k].y};
            for (int a = 0; a < 2; a++) {
                double q = 1.0 / sqrt(1.0 - MP_DBOX_SHARE), sd = ew[a] * sqrt(q * q - 1.0);
                assert_true(eb[a] <= ew[a] * q && eb[a] >= ew[a] / q);
                assert_true(fabs(vb[a] - vw[a]) <= 4.5 * sd + 2.0 * o.tol * (eb[a] + ew[a]));
            }
        }
        grew += fabs(sb[0].ex / sw[0].ex - 1.0) > 1e-7;
    }
    assert_true(grew == NF);
    free(buf);
    sf_frame_drop(&f);
    mp_prf_work_free(&w);
    mp_prf_cache_free(&cb);
    mp_psf_free(&p);
}

int main(void)
{
    const struct CMUnitTest tests[] = {
        cmocka_unit_test(test_limit_is_the_share),
        cmocka_unit_test(test_fit_within_bound),
    };
    return cmocka_run_group_tests(tests, NULL, NULL);
}
