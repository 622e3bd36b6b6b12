/* test_fit.c — the fit engine against what the paper and theory predict. */
#include <setjmp.h>
#include <stdarg.h>
#include <stddef.h>
#include <cmocka.h>
#include <math.h>
#include <stdlib.h>
#include <string.h>
#include <omp.h>
#include "fit/fit.h"
#include "sim/sim.h"

static int cmp_d(const void *a, const void *b)
{
    double x = *(const double *)a, y = *(const double *)b;
    return (x > y) - (x < y);
}

static double median(double *v, size_t n)
{
    qsort(v, n, sizeof *v, cmp_d);
    return n % 2 ? v[n / 2] : 0.5 * (v[n / 2 - 1] + v[n / 2]);
}

static double robust_sigma(double *v, size_t n)
{
    qsort(v, n, sizeof *v, cmp_d);
    return (v[(3 * n) / 4] - v[n / 4]) / 1.349;
}

/* Paper §5.3, Fig. 8: a 1× FWHM 1.5 Gaussian table shifted half a pixel by
 * the damped sinc rings with a biggest negative side lobe of about −0.0006. */
static void test_sinc_side_lobe(void **state)
{
    (void)state;
    char err[MP_ERRLEN];
    mp_psf p;
    assert_int_equal(mp_psf_gauss_table(1.5, 1, 10.0, &p, err), 0);
    size_t n = (size_t)p.nx * p.ny;
    double *out = malloc(n * sizeof *out), *tmp = malloc(n * sizeof *tmp);
    assert_non_null(out);
    assert_non_null(tmp);
    mp_shift_table(p.t, p.nx, p.ny, 0.5, 0.0, 10, out, tmp);
    double mn = 0.0;
    for (size_t i = 0; i < n; i++)
        mn = fmin(mn, out[i]);
    /* "about −0.0006": the paper quotes one significant figure. */
    assert_true(mn < -0.00055 && mn > -0.00065);
    /* A zero shift is the identity. */
    mp_shift_table(p.t, p.nx, p.ny, 0.0, 0.0, 10, out, tmp);
    for (size_t i = 0; i < n; i++)
        assert_true(out[i] == p.t[i]);
    free(out);
    free(tmp);
    mp_psf_free(&p);
}

/* Fit-model derivatives of a ×4 table (five-point formula on the shifted
 * table) against the analytic derivatives of the pixel-integrated Gaussian.
 * The five-point error is h⁴ f⁽⁵⁾/30 with h = 1/4 px; a Gaussian's |f⁽⁵⁾|
 * peaks near 6.6/σ⁵ of its height and |f'| at 0.607/σ, so the error is at
 * most h⁴·0.36/σ⁴ of the derivative's peak (5e-4 here); the test allows
 * twice that for the sinc's own interpolation error. */
static void test_five_point_vs_analytic(void **state)
{
    (void)state;
    char err[MP_ERRLEN];
    mp_psf tab, gau;
    assert_int_equal(mp_psf_gauss_table(3.0, 4, 12.0, &tab, err), 0);
    mp_psf_gauss(3.0, &gau);
    mp_prf_model mt = {&tab, NULL, 10}, mg = {&gau, NULL, 10};
    mp_prf_work w = {0};
    double h = 0.25, sg = gau.sigma;
    double bound = 2.0 * pow(h, 4) * (6.6 / 30.0) / 0.607 / pow(sg, 4);
    const double xs[3] = {30.0, 30.37, 29.81}, ys[3] = {30.0, 29.62, 30.5};
    for (int c = 0; c < 3; c++) {
        long tx0, ty0, gx0, gy0;
        int tw, th, gw, gh;
        mp_prf_box(&mt, xs[c], ys[c], &tx0, &ty0, &tw, &th);
        mp_prf_box(&mg, xs[c], ys[c], &gx0, &gy0, &gw, &gh);
        size_t nt = (size_t)tw * th, ng = (size_t)gw * gh;
        double *tp = malloc(3 * nt * sizeof *tp), *gp = malloc(3 * ng * sizeof *gp);
        assert_non_null(tp);
        assert_non_null(gp);
        assert_int_equal(mp_prf_render(&mt, xs[c], ys[c], tp, tp + nt, tp + 2 * nt, &w), 0);
        assert_int_equal(mp_prf_render(&mg, xs[c], ys[c], gp, gp + ng, gp + 2 * ng, &w), 0);
        double peak = 0, worst = 0, vworst = 0;
        for (int j = 0; j < gh; j++)
            for (int i = 0; i < gw; i++) {
                long X = gx0 + i, Y = gy0 + j;
                if (X < tx0 || X >= tx0 + tw || Y < ty0 || Y >= ty0 + th)
                    continue;
                size_t g = (size_t)j * gw + i, t = (size_t)(Y - ty0) * tw + (size_t)(X - tx0);
                for (int a = 1; a <= 2; a++) {
                    peak = fmax(peak, fabs(gp[a * ng + g]));
                    worst = fmax(worst, fabs(gp[a * ng + g] - tp[a * nt + t]));
                }
                vworst = fmax(vworst, fabs(gp[g] - tp[t]));
            }
        assert_true(peak > 0.02);
        assert_true(worst < bound * peak);
        assert_true(vworst < 1e-4);
        free(tp);
        free(gp);
    }
    mp_prf_work_free(&w);
    mp_psf_free(&tab);
}

/* Median PRF statistics over uniform positions in a pixel for the paper's
 * PSFs: β = 21.44 (FWHM 3), 13.62 (FWHM 2.35482), 6.17 (FWHM 1.5, 2× table),
 * 1736.8 (FWHM 3, V = 1/9); each within 1 %. */
static void stats_median(const mp_prf_model *m, mp_prf_stats *out)
{
    enum { N = 401 };
    double b[N], s[N], l[N], v[N];
    mp_rng r;
    mp_rng_seed(&r, 7);
    mp_prf_work w = {0};
    for (int k = 0; k < N; k++) {
        double x = 30 + mp_rng_uniform(&r), y = 30 + mp_rng_uniform(&r);
        long x0, y0;
        int bw, bh;
        mp_prf_box(m, x, y, &x0, &y0, &bw, &bh);
        double *p = malloc((size_t)bw * bh * sizeof *p);
        assert_non_null(p);
        assert_int_equal(mp_prf_render(m, x, y, p, NULL, NULL, &w), 0);
        mp_prf_stats st;
        mp_prf_stats_of(p, (size_t)bw * bh, &st);
        b[k] = st.beta;
        s[k] = st.sharp;
        l[k] = st.lscale;
        v[k] = st.volume;
        free(p);
    }
    out->beta = median(b, N);
    out->sharp = median(s, N);
    out->lscale = median(l, N);
    out->volume = median(v, N);
    mp_prf_work_free(&w);
}

static void test_paper_prf_stats(void **state)
{
    (void)state;
    char err[MP_ERRLEN];
    struct { double fwhm; int os; double vol, beta; } c[4] = {
        {3.0, 0, 1.0, 21.44}, {2.35482, 0, 1.0, 13.62}, {1.5, 2, 1.0, 6.17}, {3.0, 1, 1.0 / 9, 1736.8}};
    for (int k = 0; k < 4; k++) {
        mp_psf p;
        if (c[k].os)
            assert_int_equal(mp_psf_gauss_table(c[k].fwhm, c[k].os, 15.0, &p, err), 0);
        else
            mp_psf_gauss(c[k].fwhm, &p);
        mp_drf d;
        mp_drf_uniform(c[k].vol, &d);
        mp_prf_model m = {&p, &d, 10};
        mp_prf_stats st;
        stats_median(&m, &st);
        assert_true(fabs(st.beta / c[k].beta - 1) < 0.01);
        assert_true(fabs(st.volume / c[k].vol - 1) < 0.01);
        /* β = 1/(V² sharpness), L = sqrt(β V²/4π) (paper eqs. beta2, cssl). */
        double sharp = 1.0 / (c[k].beta * c[k].vol * c[k].vol);
        assert_true(fabs(st.sharp / sharp - 1) < 0.01);
        assert_true(fabs(st.lscale / sqrt(c[k].beta * c[k].vol * c[k].vol / (4 * M_PI)) - 1) < 0.01);
        mp_psf_free(&p);
    }
}

/* A frame in memory: n×n, gain 1, read noise ron. */
static void frame_make(mp_frame *f, long n, double ron)
{
    memset(f, 0, sizeof *f);
    f->im.nx = f->im.ny = n;
    f->im.pix = calloc((size_t)(n * n), sizeof *f->im.pix);
    f->mask = calloc((size_t)(n * n), 1);
    assert_non_null(f->im.pix);
    assert_non_null(f->mask);
    f->gain = 1.0;
    f->rdnoise = ron;
    f->saturate = INFINITY;
    f->exptime = 1.0;
}

static void frame_drop(mp_frame *f)
{
    free(f->im.pix);
    free(f->mask);
}

/* A short FWHM-3 run on the Cramér–Rao bound: NS single-star 60×60 frames,
 * discrete 1× table, B = 100, RON = 3, mags uniform in [−15, −6].  Tolerances
 * are 3.5σ of each statistic's sampling error (false-failure rate ≈ 5e-4
 * each): the median of |Δ|/σ for a normal variable has relative standard
 * error 1.166/√N, a Rayleigh median 0.721/√N, an IQR-based σ 1.166/√N, and a
 * median of N(0,1) 1.2533/√N. */
static void test_crlb_short_run(void **state)
{
    (void)state;
    enum { NS = 600, NP = 60 };
    const double B = 100.0, RON = 3.0;
    char err[MP_ERRLEN];
    mp_psf tab, gau;
    assert_int_equal(mp_psf_gauss_table(3.0, 1, 15.0, &tab, err), 0);
    mp_psf_gauss(3.0, &gau);
    mp_prf_model fitm = {&tab, NULL, 10}, exact = {&gau, NULL, 10};
    mp_sim_prf sp = {.kind = MP_SIM_GAUSS, .sigma = gau.sigma, .volume = 1.0};
    double *rm = malloc(NS * sizeof *rm), *rr = malloc(NS * sizeof *rr);
    double *ze = malloc(NS * sizeof *ze), *zx = malloc(NS * sizeof *zx);
    double *pr = calloc(3 * NP * NP, sizeof *pr);
    assert_non_null(rm);
    assert_non_null(pr);
    mp_frame f;
    frame_make(&f, NP, RON);
    mp_prf_work w = {0};
    mp_fit_opts o;
    mp_fit_opts_default(&o);
    o.sky_order = 0;        /* the bound is for (E, X, Y, B): a constant sky */
    mp_rng r;
    for (int s = 0; s < NS; s++) {
        mp_rng_seed(&r, 1000 + (uint64_t)s);
        double mag = -6.0 - 9.0 * mp_rng_uniform(&r), E = pow(10.0, -0.4 * mag);
        double x = 30.0 + mp_rng_uniform(&r), y = 30.0 + mp_rng_uniform(&r);
        for (long i = 0; i < NP * NP; i++)
            f.im.pix[i] = B;
        assert_int_equal(mp_sim_add_star_float(&sp, x, y, E, f.im.pix, NP, NP), 0);
        mp_sim_add_noise_float(&r, f.im.pix, NP * NP, RON);
        /* The exact CRLB of this star (design.md §6). */
        long x0, y0;
        int bw, bh;
        mp_prf_box(&exact, x, y, &x0, &y0, &bw, &bh);
        double *b = malloc(3 * (size_t)bw * bh * sizeof *b);
        assert_non_null(b);
        size_t nb = (size_t)bw * bh;
        mp_prf_render(&exact, x, y, b, b + nb, b + 2 * nb, &w);
        memset(pr, 0, 3 * NP * NP * sizeof *pr);
        for (int j = 0; j < bh; j++)
            for (int i = 0; i < bw; i++) {
                long X = x0 + i, Y = y0 + j;
                if (X < 1 || Y < 1 || X > NP || Y > NP)
                    continue;
                for (int a = 0; a < 3; a++)
                    pr[a * NP * NP + (Y - 1) * NP + (X - 1)] = b[a * nb + (size_t)j * bw + i];
            }
        free(b);
        double sd[4];
        assert_int_equal(mp_crlb(pr, pr + NP * NP, pr + 2 * NP * NP, NP * NP, E, B, RON, sd), 0);
        mp_star st = {.x = x + 0.2, .y = y - 0.15, .flux = NAN};
        assert_int_equal(mp_fit_group(&f, &fitm, &o, NAN, &st, 1, err), 0);
        assert_true(isfinite(st.flux) && isfinite(st.x) && isfinite(st.eflux));
        assert_int_equal(st.flags & MP_FLAG_NOCONV, 0);
        assert_int_equal(st.dof, NP * NP - 4);
        rm[s] = fabs(st.flux - E) / sd[0];
        rr[s] = hypot(st.x - x, st.y - y) / sd[1];
        ze[s] = (st.flux - E) / st.eflux;
        zx[s] = (st.x - x) / st.ex;
    }
    double k = 3.5 / sqrt((double)NS);
    assert_true(fabs(median(rm, NS) / 0.6745 - 1) < k * 1.166);
    assert_true(fabs(median(rr, NS) / 1.1774 - 1) < k * 0.721);
    assert_true(fabs(median(ze, NS)) < k * 1.2533);
    assert_true(fabs(robust_sigma(ze, NS) - 1) < k * 1.166);
    assert_true(fabs(median(zx, NS)) < k * 1.2533);
    assert_true(fabs(robust_sigma(zx, NS) - 1) < k * 1.166);
    mp_prf_work_free(&w);
    frame_drop(&f);
    free(rm);
    free(rr);
    free(ze);
    free(zx);
    free(pr);
    mp_psf_free(&tab);
}

/* A frame with nothing in it, or nothing but NaN-masked pixels: the fit ends
 * with finite numbers and a flag, never NaN. */
static void test_no_nan_on_empty_frames(void **state)
{
    (void)state;
    char err[MP_ERRLEN];
    mp_psf p;
    mp_psf_gauss(3.0, &p);
    mp_prf_model m = {&p, NULL, 10};
    mp_fit_opts o;
    mp_fit_opts_default(&o);
    mp_frame f;
    frame_make(&f, 30, 0.0);
    for (int pass = 0; pass < 2; pass++) {
        if (pass)
            memset(f.mask, MP_MASK_BAD, 900);
        mp_star st = {.x = 15.0, .y = 15.0, .flux = NAN};
        assert_int_equal(mp_fit_group(&f, &m, &o, NAN, &st, 1, err), 0);
        assert_true(isfinite(st.x) && isfinite(st.y) && isfinite(st.flux));
        assert_true(isfinite(st.ex) && isfinite(st.eflux) && isfinite(st.sky));
        if (pass)
            assert_true(st.flags & MP_FLAG_NOCONV);
    }
    frame_drop(&f);
}

/* A gate-structure DRF (paper §5.7) in the model recovers the true intensity
 * of a bright star to within its error; ignoring the DRF does not. */
static void test_gate_drf_recovers_flux(void **state)
{
    (void)state;
    char err[MP_ERRLEN];
    mp_psf tab;
    assert_int_equal(mp_psf_gauss_table(2.0, 4, 10.0, &tab, err), 0);
    double qe[16];
    for (int j = 0; j < 4; j++)
        for (int i = 0; i < 4; i++)
            qe[j * 4 + i] = (i == 0 || j == 0) ? 0.0 : 1.0;
    mp_drf d = {4, qe, 0.5625};
    mp_sim_prf sp = {.kind = MP_SIM_TABLE, .tab = tab.t, .tnx = tab.nx, .tny = tab.ny,
                     .tos = 4, .drf = qe, .dk = 4, .volume = 1.0};
    mp_frame f;
    frame_make(&f, 40, 3.0);
    mp_rng r;
    mp_rng_seed(&r, 99);
    double x = 20.3, y = 19.8, E = pow(10.0, 0.4 * 13);
    mp_sim_snap(&sp, &x, &y);
    for (long i = 0; i < 1600; i++)
        f.im.pix[i] = 56.25;
    assert_int_equal(mp_sim_add_star_float(&sp, x, y, E, f.im.pix, 40, 40), 0);
    mp_sim_add_noise_float(&r, f.im.pix, 1600, 3.0);
    mp_fit_opts o;
    mp_fit_opts_default(&o);
    mp_prf_model m = {&tab, &d, 10};
    mp_star st = {.x = x + 0.1, .y = y + 0.1, .flux = NAN};
    assert_int_equal(mp_fit_group(&f, &m, &o, NAN, &st, 1, err), 0);
    /* 4σ: a false failure about once in 16000 runs. */
    assert_true(fabs(st.flux - E) < 4 * st.eflux);
    mp_prf_model plain = {&tab, NULL, 10};
    mp_star s2 = {.x = x + 0.1, .y = y + 0.1, .flux = NAN};
    assert_int_equal(mp_fit_group(&f, &plain, &o, NAN, &s2, 1, err), 0);
    assert_true(fabs(s2.flux - E) > 20 * s2.eflux);
    frame_drop(&f);
    mp_psf_free(&tab);
}

/* A ×4 table block-summed to ×2 (an even factor moves the star off the
 * central element's centre; the table's offset records it) renders the
 * same PRF as a ×2 table made directly: both are exact pixel integrals of
 * one Gaussian, so they differ only by the sinc's interpolation error. */
static void test_rebin_keeps_position(void **state)
{
    (void)state;
    char err[MP_ERRLEN];
    mp_psf t4, t2, r2;
    assert_int_equal(mp_psf_gauss_table(3.0, 4, 12.0, &t4, err), 0);
    assert_int_equal(mp_psf_gauss_table(3.0, 2, 12.0, &t2, err), 0);
    assert_int_equal(mp_psf_rebin(&t4, 2, &r2, err), 0);
    assert_int_equal(r2.os, 2);
    assert_true(fabs(r2.offset - 0.125) < 1e-15);
    assert_true(fabs(r2.sum - t4.sum) < 1e-12);
    mp_prf_model a = {&t2, NULL, 10}, b = {&r2, NULL, 10};
    mp_prf_work w = {0};
    double x = 30.3, y = 29.9;
    long ax0, ay0, bx0, by0;
    int aw, ah, bw, bh;
    mp_prf_box(&a, x, y, &ax0, &ay0, &aw, &ah);
    mp_prf_box(&b, x, y, &bx0, &by0, &bw, &bh);
    double *pa = calloc((size_t)aw * ah, sizeof *pa), *pb = calloc((size_t)bw * bh, sizeof *pb);
    assert_non_null(pa);
    assert_non_null(pb);
    mp_prf_render(&a, x, y, pa, NULL, NULL, &w);
    mp_prf_render(&b, x, y, pb, NULL, NULL, &w);
    double worst = 0.0, peak = 0.0;
    for (int j = 0; j < ah; j++)
        for (int i = 0; i < aw; i++) {
            long X = ax0 + i, Y = ay0 + j;
            double va = pa[(size_t)j * aw + i], vb = 0.0;
            if (X >= bx0 && X < bx0 + bw && Y >= by0 && Y < by0 + bh)
                vb = pb[(size_t)(Y - by0) * bw + (size_t)(X - bx0)];
            peak = fmax(peak, va);
            worst = fmax(worst, fabs(va - vb));
        }
    /* A quarter-pixel error in position would change the peak pixel by
     * ~10 % of the peak; interpolation of a 6-element FWHM is good to 1e-4. */
    assert_true(worst < 1e-4 * peak);
    free(pa);
    free(pb);
    mp_prf_work_free(&w);
    mp_psf_free(&t4);
    mp_psf_free(&t2);
    mp_psf_free(&r2);
}

/* A windowed render is the full render cut to the window, exactly: the
 * window only saves the shifting of table elements that fall outside it. */
static void test_window_render_is_exact(void **state)
{
    (void)state;
    char err[MP_ERRLEN];
    mp_psf tab, gau;
    assert_int_equal(mp_psf_gauss_table(2.5, 4, 10.0, &tab, err), 0);
    mp_psf_gauss(2.5, &gau);
    double qe[4] = {0.9, 0.8, 1.0, 0.7};
    mp_drf d = {2, qe, 0.85};
    mp_prf_model ms[3] = {{&tab, &d, 10}, {&tab, NULL, 10}, {&gau, NULL, 10}};
    mp_prf_work w = {0};
    for (int c = 0; c < 3; c++) {
        double x = 40.37, y = 39.81;
        long x0, y0, wx0, wy0;
        int bw, bh, ww, wh;
        mp_prf_box(&ms[c], x, y, &x0, &y0, &bw, &bh);
        size_t nb = (size_t)bw * bh;
        double *full = malloc(3 * nb * sizeof *full), *part = malloc(3 * nb * sizeof *part);
        assert_non_null(full);
        assert_non_null(part);
        assert_int_equal(mp_prf_render(&ms[c], x, y, full, full + nb, full + 2 * nb, &w), 0);
        assert_int_equal(mp_prf_render_window(&ms[c], x, y, 37, 36, 7, 9, &wx0, &wy0, &ww, &wh,
                                               part, part + nb, part + 2 * nb, &w), 0);
        assert_int_equal(wx0, 37);
        assert_int_equal(wy0, 36);
        assert_int_equal(ww, 7);
        assert_int_equal(wh, 9);
        for (int j = 0; j < wh; j++)
            for (int i = 0; i < ww; i++) {
                size_t f = (size_t)(wy0 + j - y0) * bw + (size_t)(wx0 + i - x0);
                size_t p = (size_t)j * ww + i;
                for (int a = 0; a < 3; a++)
                    assert_true(fabs(full[a * nb + f] - part[a * nb + p]) <= 1e-15);
            }
        free(full);
        free(part);
    }
    mp_prf_work_free(&w);
    mp_psf_free(&tab);
}

/* mp_fit_residual paints the stars by bands of rows, in parallel (issue
 * 14): the residual must be every star's whole PRF subtracted once —
 * stars across the bands' edges (rows 64/65, 128/129) and the frame's
 * included — and the same bytes with 1 thread or 3.  The reference is
 * drawn star by star in double from mp_prf_render; the float residual
 * differs from it by rounding only: at most a few ulp (2^-24 = 6e-8) of
 * the largest value per overlapping star, so 1e-6 of it bounds it. */
static void test_residual_bands(void **state)
{
    (void)state;
    enum { NX = 90, NY = 150, NS = 40 };
    char err[MP_ERRLEN];
    mp_psf tab;
    assert_int_equal(mp_psf_gauss_table(2.5, 2, 8.0, &tab, err), 0);
    mp_prf_model m = {&tab, NULL, 10};
    mp_frame f;
    memset(&f, 0, sizeof f);
    f.im.nx = NX;
    f.im.ny = NY;
    f.im.pix = malloc(NX * NY * sizeof *f.im.pix);
    f.mask = calloc(NX * NY, 1);
    float *r1 = malloc(NX * NY * sizeof *r1), *r3 = malloc(NX * NY * sizeof *r3);
    double *ref = malloc(NX * NY * sizeof *ref), *p = NULL;
    assert_true(f.im.pix && f.mask && r1 && r3 && ref);
    f.gain = 1.0;
    f.rdnoise = 3.0;
    for (int i = 0; i < NX * NY; i++)
        f.im.pix[i] = 100.0f;
    f.mask[77] = f.mask[NX * 64 + 5] = MP_MASK_BAD;
    mp_table t;
    mp_table_init(&t);
    int cx = mp_table_add_col(&t, "XPSF_IMAGE"), cy = mp_table_add_col(&t, "YPSF_IMAGE");
    int cf = mp_table_add_col(&t, "FLUX_PSF");
    assert_true(cx >= 0 && cy >= 0 && cf >= 0);
    const double edge[] = {0.7, 1.2, 63.9, 64.5, 65.1, 128.6, 129.4, 149.8, 150.3};
    for (int k = 0; k < NS; k++) {
        long r = mp_table_add_row(&t);
        assert_true(r >= 0);
        double y = k < 9 ? edge[k] : 1.0 + 149.0 * ((k * 37) % 101) / 101.0;
        mp_table_set(&t, (size_t)r, cx, 2.0 + 86.0 * ((k * 53) % 97) / 97.0);
        mp_table_set(&t, (size_t)r, cy, y);
        mp_table_set(&t, (size_t)r, cf, 500.0 + 97.0 * k);
    }
    for (int i = 0; i < NX * NY; i++)
        ref[i] = 100.0;
    mp_prf_work w = {0};
    for (int k = 0; k < NS; k++) {
        double x = mp_table_get(&t, k, cx), y = mp_table_get(&t, k, cy), E = mp_table_get(&t, k, cf);
        long x0, y0;
        int bw, bh;
        mp_prf_box(&m, x, y, &x0, &y0, &bw, &bh);
        p = realloc(p, (size_t)bw * bh * sizeof *p);
        assert_non_null(p);
        assert_int_equal(mp_prf_render(&m, x, y, p, NULL, NULL, &w), 0);
        for (int j = 0; j < bh; j++)
            for (int i = 0; i < bw; i++)
                if (x0 + i >= 1 && x0 + i <= NX && y0 + j >= 1 && y0 + j <= NY)
                    ref[(y0 + j - 1) * NX + (x0 + i - 1)] -= E * p[j * bw + i];
    }
    int nt = omp_get_max_threads();
    omp_set_num_threads(1);
    assert_int_equal(mp_fit_residual(&f, &m, &t, 0.0, r1, err), 0);
    omp_set_num_threads(3);
    assert_int_equal(mp_fit_residual(&f, &m, &t, 0.0, r3, err), 0);
    omp_set_num_threads(nt);
    assert_memory_equal(r1, r3, NX * NY * sizeof *r1);
    double big = 0.0;
    for (int i = 0; i < NX * NY; i++)
        big = fmax(big, fabs(ref[i]));
    for (int i = 0; i < NX * NY; i++) {
        if (f.mask[i]) {
            assert_true(isnan(r1[i]));
            continue;
        }
        assert_true(fabs(r1[i] - ref[i]) <= 1e-6 * big);
    }
    mp_prf_work_free(&w);
    mp_table_free(&t);
    mp_psf_free(&tab);
    free(p);
    free(ref);
    free(r1);
    free(r3);
    free(f.im.pix);
    free(f.mask);
}

int main(void)
{
    const struct CMUnitTest tests[] = {
        cmocka_unit_test(test_sinc_side_lobe),
        cmocka_unit_test(test_five_point_vs_analytic),
        cmocka_unit_test(test_paper_prf_stats),
        cmocka_unit_test(test_crlb_short_run),
        cmocka_unit_test(test_no_nan_on_empty_frames),
        cmocka_unit_test(test_gate_drf_recovers_flux),
        cmocka_unit_test(test_rebin_keeps_position),
        cmocka_unit_test(test_window_render_is_exact),
        cmocka_unit_test(test_residual_bands),
    };
    return cmocka_run_group_tests_name("fit", tests, NULL, NULL);
}
