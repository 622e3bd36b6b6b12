/* test_prf_cache.c — the PRF drawn from a grid of subpixel phases (issue 12,
 * fit/prf_cache.c): within what its own measurement says, the grid's PRF
 * and derivatives are the exact render's; the measured error falls as the
 * cubic's h⁴ when the grid is refined; a grid is used only for the model it
 * was built for.  Deterministic: fixed positions, no noise. */
#include <setjmp.h>
#include <stdarg.h>
#include <stddef.h>
#include <cmocka.h>
#include <float.h>
#include <math.h>
#include <stdlib.h>
#include <string.h>

#include "fit/fit.h"
#include "fit/prf_axis.h"
#include "tests/unit/stiff_common.h"

/* A Gaussian table, FWHM 2.5 px, ×2, ±8 px: smooth, so the cubic's error
 * term sets the grid's error. */
static void table(mp_psf *p)
{
    char err[MP_ERRLEN];
    assert_int_equal(mp_psf_gauss_table(2.5, 2, 8.0, p, err), 0);
}

/* The largest |δP| the grid measured at its cell centres: of its cubic
 * interpolation, or (lin) its bilinear one. */
static double measured_max(const mp_prf_cache *c, int lin)
{
    const float *d2 = lin ? c->d2l : c->d2;
    double m = 0.0;
    for (size_t i = 0; i < (size_t)c->nph * c->npix; i++)
        m = d2[i] > m ? d2[i] : m;
    return sqrt(m);
}

/* The largest differences between the exact render and the grid's, PRF
 * (*worst) and derivatives (*worstd), at 60 positions spread over all
 * phases: the grid's drawn through a render's work (mp_prf_render_window,
 * cubic) or, with lin, by mp_prf_cache_render_at bilinearly on the box's
 * rows. */
static void against_exact(const mp_prf_model *m, const mp_prf_cache *c, int lin, double *worst,
                          double *worstd)
{
    mp_prf_work we = {0}, wg = {0};
    wg.grid = c;
    size_t cap = (size_t)c->uw * c->uh;
    double *a = malloc(3 * cap * sizeof *a), *b = malloc(3 * cap * sizeof *b);
    mp_span *sp = malloc((size_t)c->uh * sizeof *sp);
    assert_true(a && b && sp);
    *worst = *worstd = 0.0;
    for (int k = 0; k < 60; k++) {
        double x = 50.0 + 0.0173 * k * 7.0, y = 40.0 + 0.0291 * k * 5.0;
        long x0, y0, x1, y1;
        int w0, h0, w1, h1;
        assert_int_equal(mp_prf_render_window(m, x, y, 1, 1, 200, 200, &x0, &y0, &w0, &h0, a,
                                              a + cap, a + 2 * cap, &we), 0);
        size_t n = (size_t)w0 * h0;
        if (lin) {
            for (int j = 0; j < h0; j++)
                sp[j] = (mp_span){x0, y0 + j, w0};
            assert_int_equal(mp_prf_cache_render_at(c, m, x, y, sp, NULL, h0, b, b + cap,
                                                    b + 2 * cap, 1), 0);
        } else {
            assert_int_equal(mp_prf_render_window(m, x, y, 1, 1, 200, 200, &x1, &y1, &w1, &h1, b,
                                                  b + cap, b + 2 * cap, &wg), 0);
            assert_true(x0 == x1 && y0 == y1 && w0 == w1 && h0 == h1);
        }
        for (size_t i = 0; i < n; i++) {
            *worst = fmax(*worst, fabs(a[i] - b[i]));
            *worstd = fmax(*worstd, fmax(fabs(a[cap + i] - b[cap + i]), fabs(a[2 * cap + i] - b[2 * cap + i])));
        }
    }
    free(a);
    free(b);
    free(sp);
    mp_prf_work_free(&we);
    mp_prf_work_free(&wg);
}

/* At 60 positions spread over all phases, the grid's PRF is the exact one
 * within twice the largest error measured at the cell centres (the cubic's
 * error term (f+1)f(f−1)(f−2) is largest there; the factor 2 covers the
 * fourth derivative's change across a cell), and its derivatives (the
 * five-point ones interpolated) within the same bound scaled by the
 * derivative's own size against the PRF's (3 /px for this FWHM, generous). */
static void test_grid_matches_exact(void **state)
{
    (void)state;
    char err[MP_ERRLEN];
    mp_psf p;
    table(&p);
    mp_prf_model m = {&p, NULL, 10};
    mp_prf_cache c;
    assert_int_equal(mp_prf_cache_build(&m, 16, &c, err), 0);
    assert_int_equal(c.G, 16);
    double tol = 2.0 * measured_max(&c, 0), worst, worstd;
    assert_true(tol > 0 && tol < 1e-4);
    against_exact(&m, &c, 0, &worst, &worstd);
    assert_true(worst <= tol);
    assert_true(worstd <= 3.0 * tol);
    mp_prf_cache_free(&c);
    mp_psf_free(&p);
}

/* Halving the phase step divides the cubic's error by about 2⁴: the measured
 * bound of a 10⁶ e⁻ star falls by more than 8 from G = 8 to G = 16 (16
 * expected; 8 leaves room for the error term's own variation), and the
 * flux limit at 0.1 σ rises. */
static void test_bound_falls_as_h4(void **state)
{
    (void)state;
    char err[MP_ERRLEN];
    mp_psf p;
    table(&p);
    mp_prf_model m = {&p, NULL, 10};
    mp_prf_cache c8, c16;
    assert_int_equal(mp_prf_cache_build(&m, 8, &c8, err), 0);
    assert_int_equal(mp_prf_cache_build(&m, 16, &c16, err), 0);
    double q8 = mp_prf_cache_bound(&c8, 1e6, 100.0, 3.0), q16 = mp_prf_cache_bound(&c16, 1e6, 100.0, 3.0);
    assert_true(q16 > 0 && q8 / q16 > 8.0);
    double e8 = mp_prf_cache_limit(&c8, 100.0, 3.0, 0.1), e16 = mp_prf_cache_limit(&c16, 100.0, 3.0, 0.1);
    assert_true(e8 > 0 && e16 > e8);
    assert_true(mp_prf_cache_bound(&c16, e16, 100.0, 3.0) <= 0.1);
    /* the largest such flux by the full bound, to the bisection's 0.25 %
     * (its undecided steps sum only the cells that could be the largest) */
    assert_true(mp_prf_cache_bound(&c16, 1.005 * e16, 100.0, 3.0) > 0.1);
    double el = mp_prf_cache_limit_lin(&c16, 100.0, 3.0, 0.1);
    assert_true(mp_prf_cache_bound_lin(&c16, el, 100.0, 3.0) <= 0.1);
    assert_true(mp_prf_cache_bound_lin(&c16, 1.005 * el, 100.0, 3.0) > 0.1);
    mp_prf_cache_free(&c8);
    mp_prf_cache_free(&c16);
    mp_psf_free(&p);
}

/* The bilinear interpolation (mp_prf_cache_render_at with lin) at 60
 * positions over all phases: its PRF within twice the largest error
 * measured at the cell centres (its error term f(1 − f)·h²·P''/2 peaks
 * there; 2 covers P'''s change across a cell), its derivatives within 3
 * times that (their own scale against the PRF's, 3 /px here), and that
 * error above the cubic's (else the limits below say nothing). */
static void test_bilinear_matches_exact(void **state)
{
    (void)state;
    char err[MP_ERRLEN];
    mp_psf p;
    table(&p);
    mp_prf_model m = {&p, NULL, 10};
    mp_prf_cache c;
    assert_int_equal(mp_prf_cache_build(&m, 16, &c, err), 0);
    double tol = 2.0 * measured_max(&c, 1), worst, worstd;
    assert_true(tol > 4.0 * measured_max(&c, 0) && tol < 1e-3);
    against_exact(&m, &c, 1, &worst, &worstd);
    assert_true(worst <= tol);
    assert_true(worstd <= 3.0 * tol);
    mp_prf_cache_free(&c);
    mp_psf_free(&p);
}

/* Halving the phase step divides the bilinear interpolation's error by
 * about 2²: its bound for a 10⁶ e⁻ star falls by 3 to 5.3 from G = 8 to
 * G = 16 (4 expected; the cubic's falls by more than 8), it stays above
 * the cubic's, and its flux limit is below the cubic's and meets its
 * bound. */
static void test_bilinear_bound_falls_as_h2(void **state)
{
    (void)state;
    char err[MP_ERRLEN];
    mp_psf p;
    table(&p);
    mp_prf_model m = {&p, NULL, 10};
    mp_prf_cache c8, c16;
    assert_int_equal(mp_prf_cache_build(&m, 8, &c8, err), 0);
    assert_int_equal(mp_prf_cache_build(&m, 16, &c16, err), 0);
    double q8 = mp_prf_cache_bound_lin(&c8, 1e6, 100.0, 3.0);
    double q16 = mp_prf_cache_bound_lin(&c16, 1e6, 100.0, 3.0);
    assert_true(q16 > 0 && q8 / q16 > 3.0 && q8 / q16 < 5.3);
    assert_true(q16 > mp_prf_cache_bound(&c16, 1e6, 100.0, 3.0));
    double el = mp_prf_cache_limit_lin(&c16, 100.0, 3.0, 0.1);
    assert_true(el > 0 && el < mp_prf_cache_limit(&c16, 100.0, 3.0, 0.1));
    assert_true(mp_prf_cache_bound_lin(&c16, el, 100.0, 3.0) <= 0.1);
    assert_true(mp_prf_cache_bound_lin(&c16, 1.01 * el, 100.0, 3.0) > 0.1);
    mp_prf_cache_free(&c8);
    mp_prf_cache_free(&c16);
    mp_psf_free(&p);
}

/* A noiseless star of flux E at the bilinear limit on sky B, fitted with
 * its PRF drawn bilinearly (grid_tiers.lin ∞) and cubically (zeroed tiers)
 * from the grid, and exactly (no grid), which returns the truth: each
 * grid fit's flux, x and y lie within its bound (0.1 σ, the σ the exact
 * fit reports) of the exact fit's, plus the fits' tolerance (2·tol σ),
 * and the bilinear fit's offset is the larger (it was drawn bilinearly),
 * at each of 8 subpixel positions off the grid's nodes (on a node both
 * interpolations are exact, and only the fits' tolerance would differ). */
static void test_bilinear_fit_within_bound(void **state)
{
    (void)state;
    enum { NP = 31 };
    const double B = 100.0, RON = 3.0;
    char err[MP_ERRLEN];
    mp_psf p;
    table(&p);
    mp_prf_model m = {&p, NULL, 10};
    mp_prf_cache c;
    assert_int_equal(mp_prf_cache_build(&m, 16, &c, err), 0);
    double E = mp_prf_cache_limit_lin(&c, B, RON, 0.1);
    assert_true(E > 1e3 && E < mp_prf_cache_limit(&c, B, RON, 0.1));
    mp_frame f;
    sf_frame_make(&f, NP, NP, RON);
    mp_prf_work w = {0};
    long x0, y0;
    int bw, bh;
    mp_prf_box(&m, 16.0, 16.0, &x0, &y0, &bw, &bh);
    double *buf = malloc((size_t)(bw + 2) * (bh + 2) * sizeof *buf);
    assert_non_null(buf);
    mp_fit_opts o;
    mp_fit_opts_default(&o);
    o.fitrad = 4.0;
    o.sky_order = 0;
    o.tol = 1e-4;
    double worse = 0.0;
    for (int k = 0; k < 8; k++) {
        double X = 16.03 + 0.13 * k, Y = 16.02 + 0.29 * (k % 3) + 0.05 * k;
        for (long i = 0; i < NP * NP; i++)
            f.im.pix[i] = (float)B;
        mp_prf_box(&m, X, Y, &x0, &y0, &bw, &bh);
        assert_int_equal(mp_prf_render(&m, X, Y, buf, NULL, NULL, &w), 0);
        for (int j = 0; j < bh; j++)
            for (int i = 0; i < bw; i++) {
                long XX = x0 + i, YY = y0 + j;
                if (XX >= 1 && YY >= 1 && XX <= NP && YY <= NP)
                    f.im.pix[(YY - 1) * NP + XX - 1] += (float)(E * buf[(size_t)j * bw + i]);
            }
        mp_star st[3];
        for (int v = 0; v < 3; v++) {
            st[v] = (mp_star){.x = X + 0.2, .y = Y - 0.1, .flux = 0.8 * E};
            o.grid = v < 2 ? &c : NULL;
            memset(&o.grid_tiers, 0, sizeof o.grid_tiers);
            o.grid_tiers.lin = v == 0 ? INFINITY : 0.0;
            assert_int_equal(mp_fit_group(&f, &m, &o, B, &st[v], 1, err), 0);
            assert_int_equal(st[v].flags & MP_FLAG_NOCONV, 0);
        }
        const mp_star *ex = &st[2];
        double off[2];
        for (int v = 0; v < 2; v++) {
            const double d[3] = {(st[v].flux - ex->flux) / ex->eflux, (st[v].x - ex->x) / ex->ex,
                                 (st[v].y - ex->y) / ex->ey};
            off[v] = 0.0;
            for (int a = 0; a < 3; a++) {
                assert_true(fabs(d[a]) <= 0.1 + 2.0 * o.tol);
                off[v] = fmax(off[v], fabs(d[a]));
            }
        }
        worse += off[0] > off[1];
    }
    assert_true(worse == 8);
    free(buf);
    sf_frame_drop(&f);
    mp_prf_work_free(&w);
    mp_prf_cache_free(&c);
    mp_psf_free(&p);
}

/* A grid serves only the psf and drf it was built for; an analytic PSF gets
 * none. */
static void test_grid_only_for_its_model(void **state)
{
    (void)state;
    char err[MP_ERRLEN];
    mp_psf p, q, g;
    table(&p);
    table(&q);
    mp_psf_gauss(2.5, &g);
    mp_prf_model m = {&p, NULL, 10}, other = {&q, NULL, 10}, gm = {&g, NULL, 10};
    mp_drf d;
    mp_drf_uniform(0.9, &d);
    mp_prf_model withdrf = {&p, &d, 10};
    mp_prf_cache c, cg;
    assert_int_equal(mp_prf_cache_build(&m, 4, &c, err), 0);
    assert_true(mp_prf_cache_usable(&c, &m));
    assert_false(mp_prf_cache_usable(&c, &other));
    assert_false(mp_prf_cache_usable(&c, &withdrf));
    assert_false(mp_prf_cache_usable(NULL, &m));
    assert_int_equal(mp_prf_cache_build(&gm, 16, &cg, err), 0);
    assert_int_equal(cg.G, 0);
    assert_false(mp_prf_cache_usable(&cg, &gm));
    mp_prf_cache_free(&c);
    mp_prf_cache_free(&cg);
    mp_drf_free(&d);
    mp_psf_free(&p);
    mp_psf_free(&q);
}

/* The separable build (fit/prf_axis.c: the render as Y·T·Xᵀ) against the
 * render of every node and cell by fit/prf.c, on a lopsided table (a
 * Gaussian plus an off-centre one, so that no symmetry hides a sign), ×3
 * and ×2, with and without a uniform DRF.  The build's nodes are summed in
 * single precision (mp_prf_axis_rows_single), the exact ones in double:
 * each node within single_bound of the other (and one rounding of its
 * float, FLT_EPSILON·peak); the cells' P, rendered in double by both, the
 * same or one rounding apart; the measured δP, read through 16 Lagrange
 * weights (Σ|L| ≤ 1.6 an axis), within 2.56 nodes' bounds and
 * 4·FLT_EPSILON·peak; and the flux limit at 0.1 σ within 1 %. */
static void lopsided(int os, mp_psf *p)
{
    char err[MP_ERRLEN];
    assert_int_equal(mp_psf_gauss_table(2.2, os, 7.0, p, err), 0);
    int c = (p->nx - 1) / 2;
    for (int j = 0; j < p->ny; j++)
        for (int i = 0; i < p->nx; i++) {
            double dx = (i - c - 1.3 * os) / os, dy = (j - c + 0.7 * os) / os;
            p->t[(size_t)j * p->nx + i] += 0.2 * exp(-0.5 * (dx * dx + dy * dy) / 1.1) / os / os;
        }
}

/* The largest error of a render in single precision (fit/prf_axis.h:
 * (l_x + l_y + 4)·2⁻²⁴ of |Y|·|T|·|X|ᵀ, l ≤ os + 2hw + 4 a run) on table
 * p, half-width hw: |T| ≤ max|T|, and a pixel's weights sum in |·| to at
 * most os·S (os elements, each S = the most Σ|damped sinc| over the 2hw +
 * 1 taps takes at any shift), or 1.5·os²·S for the five-point derivative's
 * (|−1, 8, −8, 1|·os/12 of four shifted rows); deriv: a derivative plane. */
static double single_bound(const mp_psf *p, int hw, int deriv)
{
    double S = 0.0, tmax = 0.0;
    for (int i = 0; i <= 100; i++) {
        double a = 0.0;
        for (int k = -hw; k <= hw; k++)
            a += fabs(mp_damped_sinc(k - i / 100.0));
        S = fmax(S, a);
    }
    for (size_t i = 0; i < (size_t)p->nx * p->ny; i++)
        tmax = fmax(tmax, fabs(p->t[i]));
    double l = p->os + 2.0 * hw + 4.0, gamma = (2.0 * l + 4.0) * ldexp(1.0, -24);
    double wx = p->os * S, wd = 1.5 * p->os * p->os * S;
    return gamma * tmax * wx * (deriv ? wd : wx);
}

static double peak_of(const float *v, size_t n)
{
    double m = 0.0;
    for (size_t i = 0; i < n; i++)
        m = fmax(m, fabs(v[i]));
    return m;
}

static void test_separable_build_is_exact(void **state)
{
    (void)state;
    char err[MP_ERRLEN];
    mp_drf d;
    mp_drf_uniform(0.9, &d);
    for (int t = 0; t < 3; t++) {
        mp_psf p;
        lopsided(t == 1 ? 2 : 3, &p);
        mp_prf_model m = {&p, t == 2 ? &d : NULL, 10};
        mp_prf_cache a, b;
        assert_int_equal(mp_prf_cache_build(&m, 8, &a, err), 0);
        assert_int_equal(mp_prf_cache_build_exact(&m, 8, &b, err), 0);
        assert_true(a.G == b.G && a.npix == b.npix && a.nph == b.nph && a.G > 0);
        int NA = a.os * (a.gb + 3);
        size_t ni = 3 * (size_t)NA * NA * a.npix, nc = (size_t)a.nph * a.npix;
        double peak = peak_of(b.img, ni), dimg[2] = {0.0, 0.0}, dp = 0.0, dd = 0.0;
        for (size_t i = 0; i < ni; i++) {
            int deriv = (i / a.npix) % 3 != 0;       /* a node's planes: P, ∂x, ∂y */
            dimg[deriv] = fmax(dimg[deriv], fabs((double)a.img[i] - b.img[i]));
        }
        for (size_t i = 0; i < nc; i++) {
            dp = fmax(dp, fabs((double)a.p[i] - b.p[i]));
            dd = fmax(dd, fabs(sqrt((double)a.d2[i]) - sqrt((double)b.d2[i])));
        }
        double scale = t == 2 ? d.volume : 1.0, e0 = scale * single_bound(&p, 10, 0);
        assert_true(peak > 0);
        assert_true(dimg[0] <= e0 + FLT_EPSILON * peak);
        assert_true(dimg[1] <= scale * single_bound(&p, 10, 1) + FLT_EPSILON * peak);
        assert_true(dp <= FLT_EPSILON * peak);
        assert_true(dd <= 2.56 * e0 + 4.0 * FLT_EPSILON * peak);
        print_message("separable build, table %d: nodes %.2g (bound %.2g) of the peak\n", t,
                      dimg[0] / peak, e0 / peak);
        double ea = mp_prf_cache_limit(&a, 100.0, 3.0, 0.1), eb = mp_prf_cache_limit(&b, 100.0, 3.0, 0.1);
        assert_true(eb > 0 && fabs(ea / eb - 1.0) <= 0.01);
        mp_prf_cache_free(&a);
        mp_prf_cache_free(&b);
        mp_psf_free(&p);
    }
    mp_drf_free(&d);
}

/* Whether grids a and b hold the same values, byte for byte. */
static int same_grid(const mp_prf_cache *a, const mp_prf_cache *b)
{
    int NA = a->os * (a->gb + 3);
    size_t ni = 3 * (size_t)NA * NA * a->npix, nc = (size_t)a->nph * a->npix;
    return a->G == b->G && a->npix == b->npix && a->nph == b->nph &&
           !memcmp(a->img, b->img, ni * sizeof *a->img) &&
           !memcmp(a->p, b->p, nc * sizeof *a->p) && !memcmp(a->d2, b->d2, nc * sizeof *a->d2) &&
           !memcmp(a->d2l, b->d2l, nc * sizeof *a->d2l) &&
           !memcmp(a->d2bin, b->d2bin, (size_t)a->nph * MP_PRF_CACHE_NBIN * sizeof *a->d2bin);
}

/* A grid built into the blocks of a spare one (the PSF build's rounds,
 * psf/star_model.c) is the fresh build, byte for byte: a spare of the
 * same size, built for another table (the last round's) and so holding
 * other values, gives its blocks up (taken, its pointers NULL); one of
 * another size keeps them, and the build is still the fresh one. */
static void test_rebuild_in_spare_blocks(void **state)
{
    (void)state;
    char err[MP_ERRLEN];
    mp_psf p, q, r;
    lopsided(2, &p);
    assert_int_equal(mp_psf_gauss_table(2.5, 2, 7.0, &q, err), 0);
    lopsided(3, &r);
    assert_true(p.nx == q.nx && p.ny == q.ny && p.os == q.os);
    mp_prf_model m = {&p, NULL, 10}, mq = {&q, NULL, 10}, mr = {&r, NULL, 10};
    mp_prf_cache fresh, spare, c;
    assert_int_equal(mp_prf_cache_build(&m, 8, &fresh, err), 0);
    assert_int_equal(mp_prf_cache_build(&mq, 8, &spare, err), 0);
    assert_true(fresh.npix == spare.npix && !same_grid(&fresh, &spare));
    const float *img = spare.img, *pp = spare.p;
    assert_int_equal(mp_prf_cache_build_reusing(&m, 8, &c, &spare, err), 0);
    assert_true(c.img == img && c.p == pp && !spare.img && !spare.p && !spare.d2 && !spare.d2l);
    assert_true(same_grid(&c, &fresh));
    mp_prf_cache_free(&spare);
    /* another size: the spare keeps its blocks */
    assert_int_equal(mp_prf_cache_build(&mr, 8, &spare, err), 0);
    mp_prf_cache d;
    img = spare.img;
    assert_true(spare.npix != fresh.npix || spare.os != fresh.os);
    assert_int_equal(mp_prf_cache_build_reusing(&m, 8, &d, &spare, err), 0);
    assert_true(spare.img == img && d.img != img && same_grid(&d, &fresh));
    mp_prf_cache_free(&fresh);
    mp_prf_cache_free(&spare);
    mp_prf_cache_free(&c);
    mp_prf_cache_free(&d);
    mp_psf_free(&p);
    mp_psf_free(&q);
    mp_psf_free(&r);
}

/* An order-1 field about (60, 40), scale 50, whose planes are p's table
 * and two scrambled copies of it; p->field points to it. */
static void lopsided_field(mp_psf *p, mp_psf_field *f)
{
    char err[MP_ERRLEN];
    assert_int_equal(mp_psf_field_new(1, p->nx, p->ny, p->os, 60.0, 40.0, 50.0, 50.0, f, err), 0);
    size_t nel = (size_t)p->nx * p->ny;
    for (size_t i = 0; i < nel; i++) {
        f->planes[i] = p->t[i];
        f->planes[nel + i] = 0.1 * p->t[(i * 7) % nel];
        f->planes[2 * nel + i] = -0.05 * p->t[(i * 3) % nel];
    }
    p->field = f;
}

/* mp_prf_render_phases against mp_prf_render at each phase of the same
 * table: the element shifts (×1) with the x-pass shared, the axis
 * operators (×2, ×4) one by one, and a variable PSF's table evaluated
 * once at the centre.  The same sums in the same order wherever the same
 * path renders a phase: equal to rounding (1e-12 of the peak, ~10⁴
 * times a double's sum of 21 taps). */
static void test_render_phases_as_one_by_one(void **state)
{
    (void)state;
    char err[MP_ERRLEN];
    for (int t = 0; t < 4; t++) {
        mp_psf p, tab;
        lopsided(t < 3 ? 1 << t : 1, &p);
        mp_psf_field f;
        double x = 50.3, y = 40.7;
        mp_prf_model m = {&p, NULL, 10}, mt = m;
        if (t == 3) {           /* a field, and its table at (x, y) */
            lopsided_field(&p, &f);
            assert_int_equal(mp_psf_field_eval(&f, x, y, &tab, err), 0);
            mt.psf = &tab;
        }
        for (int n = 1; n <= 5; n += 4) {
            double *out[25], peak = 0.0, worst = 0.0;
            size_t cap = (size_t)(p.nx + 4) * (p.ny + 4);
            for (int k = 0; k < n * n; k++)
                assert_non_null(out[k] = malloc(cap * sizeof *out[k]));
            double *one = malloc(cap * sizeof *one);
            assert_non_null(one);
            mp_prf_work w = {0}, w1 = {0};
            assert_int_equal(mp_prf_render_phases(&m, x, y, n, out, &w), 0);
            for (int k = 0; k < n * n; k++) {
                double xa = mp_prf_phase(x, k % n, n), yb = mp_prf_phase(y, k / n, n);
                long x0, y0;
                int bw, bh;
                mp_prf_box(&mt, xa, yb, &x0, &y0, &bw, &bh);
                assert_int_equal(mp_prf_render(&mt, xa, yb, one, NULL, NULL, &w1), 0);
                for (int i = 0; i < bw * bh; i++) {
                    peak = fmax(peak, fabs(one[i]));
                    worst = fmax(worst, fabs(out[k][i] - one[i]));
                }
            }
            assert_true(peak > 0.0);
            assert_true(worst <= 1e-12 * peak);
            for (int k = 0; k < n * n; k++)
                free(out[k]);
            free(one);
            mp_prf_work_free(&w);
            mp_prf_work_free(&w1);
        }
        if (t == 3) {
            mp_psf_free(&tab);
            mp_psf_field_free(&f);
        }
        p.field = NULL;
        mp_psf_free(&p);
    }
}

/* fit/prf.c's two exact renders: the table's elements shifted then
 * block-summed, and the axis operators (Y·T·Xᵀ), which render_table takes
 * where they cost fewer multiply-adds (a DRF with a QE map forces the
 * first: one QE of 1 a pixel is the perfect detector).  On the lopsided
 * table at ×2, ×3, ×4, constant and as an order-1 field, whole and through
 * a window cut at the star, with and without the derivatives: the values
 * agree to 1e-12 of the peak (the order of the sums), and the axis path
 * was taken (its counted work is less).  In single precision
 * (mp_prf_work.single) the axis path's values are within single_bound of
 * them, derivatives too (the constant tables: a field's local table is
 * not p's). */
static void test_render_paths_agree(void **state)
{
    (void)state;
    double one = 1.0;
    mp_drf d1 = {1, &one, 1.0};
    for (int t = 0; t < 4; t++) {
        mp_psf p;
        lopsided(t < 3 ? t + 2 : 4, &p);
        mp_psf_field f;
        if (t == 3)
            lopsided_field(&p, &f);
        mp_prf_model ms = {&p, NULL, 10}, md = {&p, &d1, 10};
        size_t cap = (size_t)(p.nx + 4) * (p.ny + 4);
        double *a = malloc(3 * cap * sizeof *a), *b = malloc(3 * cap * sizeof *b);
        assert_non_null(a);
        assert_non_null(b);
        double *c = malloc(3 * cap * sizeof *c);
        assert_non_null(c);
        double worst = 0.0, peak = 0.0, wsingle[2] = {0.0, 0.0};
        int nsep = 0;
        for (int k = 0; k < 24; k++) {
            double x = 50.0 + 0.137 * k, y = 40.0 + 0.291 * k;
            int deriv = k % 2, cut = (k / 2) % 2;
            long wx0 = cut ? (long)x - 1 : 1, wy0 = cut ? (long)y - 2 : 1, ww = cut ? 5 : 200;
            long x0, y0, x1, y1;
            int w0, h0, w1, h1;
            mp_prf_work ws = {0}, wd = {0};
            assert_int_equal(mp_prf_render_window(&ms, x, y, wx0, wy0, ww, ww, &x0, &y0, &w0, &h0,
                                                  a, deriv ? a + cap : NULL,
                                                  deriv ? a + 2 * cap : NULL, &ws), 0);
            assert_int_equal(mp_prf_render_window(&md, x, y, wx0, wy0, ww, ww, &x1, &y1, &w1, &h1,
                                                  b, deriv ? b + cap : NULL,
                                                  deriv ? b + 2 * cap : NULL, &wd), 0);
            assert_true(x0 == x1 && y0 == y1 && w0 == w1 && h0 == h1 && w0 > 0 && h0 > 0);
            /* the path render_table's count chose on this box */
            int sep = mp_prf_axis_ops(p.nx, p.ny, p.os, 10, deriv, w0, h0, 1) <
                      mp_prf_axis_ops(p.nx, p.ny, p.os, 10, deriv, w0, h0, 0);
            assert_true(sep ? ws.ops < wd.ops : ws.ops == wd.ops);
            nsep += sep;
            mp_prf_work wf = {.single = 1};
            assert_int_equal(mp_prf_render_window(&ms, x, y, wx0, wy0, ww, ww, &x1, &y1, &w1, &h1,
                                                  c, deriv ? c + cap : NULL,
                                                  deriv ? c + 2 * cap : NULL, &wf), 0);
            mp_prf_work_free(&wf);
            for (int pl = 0; pl < (deriv ? 3 : 1); pl++)
                for (size_t i = 0; i < (size_t)w0 * h0; i++) {
                    worst = fmax(worst, fabs(a[pl * cap + i] - b[pl * cap + i]));
                    wsingle[pl > 0] = fmax(wsingle[pl > 0], fabs(c[pl * cap + i] - b[pl * cap + i]));
                    peak = fmax(peak, fabs(b[i]));
                }
            mp_prf_work_free(&ws);
            mp_prf_work_free(&wd);
        }
        assert_true(peak > 0.01);
        assert_true(worst <= 1e-12 * peak);
        assert_true(nsep >= 6);
        if (t < 3) {
            assert_true(wsingle[0] <= single_bound(&p, 10, 0) + 1e-12 * peak);
            assert_true(wsingle[1] <= single_bound(&p, 10, 1) + 1e-12 * peak);
            assert_true(wsingle[0] > 0.0);          /* the single path ran */
        }
        free(a);
        free(b);
        free(c);
        if (t == 3)
            mp_psf_field_free(&f);
        mp_psf_free(&p);
    }
}

/* mp_prf_cache_serves decides as the summed bound does, over 10 decades
 * of flux (faint stars served and bright ones refused by its shortcuts,
 * the ones between by the sum), three skies and three thresholds, on a
 * table with negative elements (the lopsided one less a ring). */
static void test_serves_as_the_bound(void **state)
{
    (void)state;
    char err[MP_ERRLEN];
    mp_psf p;
    lopsided(2, &p);
    int c0 = (p.nx - 1) / 2;
    for (int j = 0; j < p.ny; j++)
        for (int i = 0; i < p.nx; i++) {
            double r = hypot(i - c0, j - c0) / p.os;
            p.t[(size_t)j * p.nx + i] -= 2e-3 * exp(-0.5 * (r - 4.0) * (r - 4.0));
        }
    mp_prf_model m = {&p, NULL, 10};
    mp_prf_cache c;
    assert_int_equal(mp_prf_cache_build(&m, 16, &c, err), 0);
    assert_true(c.pmin < 0 && c.pmax > 0 && c.d2bin);
    const double sky[3] = {0.0, 10.0, 1000.0}, frac[3] = {0.01, 0.1, 1.0};
    int yes = 0, no = 0;
    for (int b = 0; b < 3; b++)
        for (int f = 0; f < 3; f++)
            for (int k = 0; k <= 200; k++) {
                double E = pow(10.0, k / 20.0);
                int want = mp_prf_cache_bound(&c, E, sky[b], 3.0) <= frac[f];
                assert_int_equal(mp_prf_cache_serves(&c, E, sky[b], 3.0, frac[f]), want);
                yes += want;
                no += !want;
            }
    assert_true(yes > 100 && no > 100);
    assert_false(mp_prf_cache_serves(NULL, 1.0, 1.0, 1.0, 1.0));
    mp_prf_cache_free(&c);
    mp_psf_free(&p);
}

/* mp_prf_adjoint is the render's transpose: for any image r on a star's
 * box, Σ r·render(T) = Σ adjoint(r)·T, at ×2 and ×4, with no DRF (the
 * axis operators), a QE map of 1 and one of four unequal subpixels (the
 * spread-and-shift path), at phases on and off the table's grid; r and T
 * pseudo-random, so no symmetry hides a transposed index.  The two sides
 * agree to 1e-12 of Σ|r·render(T)|, with g NaN before each call (an
 * element left unwritten fails), also on a part of the star's box. */
static void test_adjoint_is_transpose(void **state)
{
    (void)state;
    double one = 1.0, qe4[4] = {0.8, 1.1, 0.95, 1.15};
    mp_drf d1 = {1, &one, 1.0}, d2 = {2, qe4, 1.0};
    const mp_drf *drfs[3] = {NULL, &d1, &d2};
    unsigned long long z = 12345;
    for (int t = 0; t < 6; t++) {
        mp_psf p;
        lopsided(t % 2 ? 4 : 2, &p);
        for (size_t i = 0; i < (size_t)p.nx * p.ny; i++) {
            z = z * 6364136223846793005ULL + 1442695040888963407ULL;
            p.t[i] += 1e-3 * ((double)(z >> 11) / 9007199254740992.0 - 0.5);
        }
        mp_prf_model m = {&p, drfs[t / 2], 10};
        size_t nel = (size_t)p.nx * p.ny;
        double *g = malloc(nel * sizeof *g);
        assert_non_null(g);
        for (int k = 0; k < 4; k++) {
            double x = 30.0 + (k == 0 ? 0.0 : 0.137 * k), y = 20.0 + (k == 0 ? 0.0 : 0.311 * k);
            long x0, y0;
            int w, h;
            mp_prf_box(&m, x, y, &x0, &y0, &w, &h);
            double *prf = malloc((size_t)w * h * sizeof *prf), *r = malloc((size_t)w * h * sizeof *r);
            assert_non_null(prf);
            assert_non_null(r);
            for (size_t i = 0; i < (size_t)w * h; i++) {
                z = z * 6364136223846793005ULL + 1442695040888963407ULL;
                r[i] = (double)(z >> 11) / 9007199254740992.0 - 0.5;
            }
            mp_prf_work wk = {0};
            assert_int_equal(mp_prf_render(&m, x, y, prf, NULL, NULL, &wk), 0);
            for (size_t i = 0; i < nel; i++)
                g[i] = NAN;             /* every element is the adjoint's to write */
            /* the last position on a part of the box (a star at the
             * frame's edge): r zero beyond it */
            int cx = k == 3 ? w / 3 : 0, cy = k == 3 ? h / 3 : 0, cw = w - 2 * cx, ch = h - 2 * cy;
            double *rc = malloc((size_t)cw * ch * sizeof *rc);
            assert_non_null(rc);
            for (int j = 0; j < ch; j++)
                for (int i = 0; i < cw; i++)
                    rc[(size_t)j * cw + i] = r[(size_t)(j + cy) * w + (i + cx)];
            assert_int_equal(mp_prf_adjoint(&m, x, y, x0 + cx, y0 + cy, cw, ch, rc, g, &wk), 0);
            free(rc);
            double lhs = 0.0, rhs = 0.0, mag = 0.0;
            for (int j = cy; j < cy + ch; j++)
                for (int i = cx; i < cx + cw; i++) {
                    lhs += r[(size_t)j * w + i] * prf[(size_t)j * w + i];
                    mag += fabs(r[(size_t)j * w + i] * prf[(size_t)j * w + i]);
                }
            for (size_t i = 0; i < nel; i++)
                rhs += g[i] * p.t[i];
            assert_true(mag > 0.1);
            assert_true(fabs(lhs - rhs) <= 1e-12 * mag);
            mp_prf_work_free(&wk);
            free(prf);
            free(r);
        }
        free(g);
        mp_psf_free(&p);
    }
}

/* A variable PSF's grid (a grid per term of its field): an order-2 field
 * over a 200² frame (origin 100, 100, scales 100), its planes the ×2
 * Gaussian of FWHM 2.5 and five differences of Gaussians, so that the
 * FWHM changes by ~±15 % over the frame.  At cell centres (where the bound
 * is measured) at nine places within the scales, Σ (grid − exact)² over
 * the window is at most the bound's Σ δP² of that cell (|δP| ≤ Σ_t |δP_t|
 * pixel by pixel when every term is at most 1); its flux limit is at most
 * the origin's table's own grid's (the field's P is bounded below, its
 * δP above; so for this table, whose P is nowhere negative — a table whose
 * sinc ringing is, skips those pixels in its own bound); a view of the field at a sub-image (mp_psf_local) is served
 * and draws the same PRF at the same frame place; another field's grid is
 * not used; a place beyond the scales is not covered. */
static void field_planes(mp_psf_field *f)
{
    char err[MP_ERRLEN];
    static const double fw[6] = {2.5, 2.9, 2.2, 2.7, 3.0, 2.3};
    static const double amp[6] = {1.0, 0.8, 0.5, 0.8, 0.3, 0.4};
    mp_psf g0, g;
    assert_int_equal(mp_psf_gauss_table(fw[0], 2, 8.0, &g0, err), 0);
    assert_int_equal(mp_psf_field_new(2, g0.nx, g0.ny, 2, 100.0, 100.0, 100.0, 100.0, f, err),
                     0);
    size_t n = (size_t)g0.nx * g0.ny;
    memcpy(f->planes, g0.t, n * sizeof *g0.t);
    for (int t = 1; t < 6; t++) {
        assert_int_equal(mp_psf_gauss_table(fw[t], 2, 8.0, &g, err), 0);
        assert_true(g.nx == g0.nx && g.ny == g0.ny);
        for (size_t i = 0; i < n; i++)
            f->planes[(size_t)t * n + i] = amp[t] * (g.t[i] - g0.t[i]);
        mp_psf_free(&g);
    }
    f->sum = g0.sum;
    mp_psf_free(&g0);
}

/* Σ over the window of (grid − exact)² for a star at (x, y) of model m. */
static double field_err2(const mp_prf_model *m, const mp_prf_cache *c, double x, double y)
{
    mp_prf_work we = {0}, wg = {0};
    wg.grid = c;
    size_t cap = (size_t)c->uw * c->uh;
    double *a = malloc(cap * sizeof *a), *b = malloc(cap * sizeof *b);
    assert_true(a && b);
    long x0, y0, x1, y1;
    int w0, h0, w1, h1;
    assert_int_equal(mp_prf_render_window(m, x, y, -100, -100, 400, 400, &x0, &y0, &w0, &h0, a,
                                          NULL, NULL, &we), 0);
    assert_int_equal(mp_prf_render_window(m, x, y, -100, -100, 400, 400, &x1, &y1, &w1, &h1, b,
                                          NULL, NULL, &wg), 0);
    assert_true(x0 == x1 && y0 == y1 && w0 == w1 && h0 == h1);
    double s = 0.0;
    for (size_t i = 0; i < (size_t)w0 * h0; i++)
        s += (a[i] - b[i]) * (a[i] - b[i]);
    free(a);
    free(b);
    mp_prf_work_free(&we);
    mp_prf_work_free(&wg);
    return s;
}

static void test_field_grid_within_bound(void **state)
{
    (void)state;
    char err[MP_ERRLEN];
    mp_psf_field f, f2;
    field_planes(&f);
    field_planes(&f2);
    mp_psf p, p2, p0;
    assert_int_equal(mp_psf_field_eval(&f, f.x0, f.y0, &p, err), 0);
    assert_int_equal(mp_psf_field_eval(&f2, f2.x0, f2.y0, &p2, err), 0);
    assert_int_equal(mp_psf_field_eval(&f, f.x0, f.y0, &p0, err), 0);
    p.field = &f;
    p2.field = &f2;
    mp_prf_model m = {&p, NULL, 10}, other = {&p2, NULL, 10}, m0 = {&p0, NULL, 10};
    mp_prf_cache c, c0;
    assert_int_equal(mp_prf_cache_build(&m, 16, &c, err), 0);
    assert_int_equal(mp_prf_cache_build(&m0, 16, &c0, err), 0);
    assert_int_equal(c.G, 16);
    assert_int_equal(c.nt, 6);
    assert_true(c.img == NULL && c.term != NULL);
    assert_true(mp_prf_cache_usable(&c, &m));
    assert_false(mp_prf_cache_usable(&c, &other));
    assert_false(mp_prf_cache_usable(&c, &m0));
    assert_false(mp_prf_cache_usable(&c0, &m));
    assert_true(mp_prf_cache_covers(&c, &m, 150.0, 20.0));
    assert_false(mp_prf_cache_covers(&c, &m, 201.0, 100.0));
    assert_true(mp_prf_cache_limit(&c, 50.0, 5.0, 0.1) <= mp_prf_cache_limit(&c0, 50.0, 5.0, 0.1));
    int ng = c.G, checked = 0;
    for (int q = 0; q < 9; q++)
        for (int ph = 0; ph < c.nph; ph += 37) {
            int ix = ph % ng, iy = ph / ng;
            double x = 10.0 + 90.0 * (q % 3) + 0.5 + (ix + 0.5) / ng;
            double y = 10.0 + 90.0 * (q / 3) + 0.5 + (iy + 0.5) / ng;
            double bound = 0.0;
            for (size_t i = 0; i < c.npix; i++)
                bound += c.d2[(size_t)ph * c.npix + i];
            double e2 = field_err2(&m, &c, x, y);
            assert_true(bound > 0);
            assert_true(e2 <= bound * (1.0 + 1e-5) + 1e-20);
            checked++;
        }
    assert_true(checked >= 9 * 6);
    /* A sub-image whose pixel (1, 1) is frame (51, 31): the same PRF. */
    mp_psf lp;
    mp_psf_field lf;
    mp_psf_local(&p, 50.0, 30.0, &lp, &lf);
    mp_prf_model ml = {&lp, NULL, 10};
    assert_true(mp_prf_cache_usable(&c, &ml));
    size_t cap = (size_t)c.uw * c.uh;
    double *a = malloc(cap * sizeof *a), *b = malloc(cap * sizeof *b);
    assert_true(a && b);
    mp_span sp[64];
    long bx, by;
    int bw, bh;
    mp_prf_box(&m, 123.3, 77.8, &bx, &by, &bw, &bh);
    assert_true(bh <= 64);
    for (int j = 0; j < bh; j++)
        sp[j] = (mp_span){bx, by + j, bw};
    assert_int_equal(mp_prf_cache_render_at(&c, &m, 123.3, 77.8, sp, NULL, bh, a, NULL, NULL, 0),
                     0);
    for (int j = 0; j < bh; j++)
        sp[j] = (mp_span){bx - 50, by - 30 + j, bw};
    assert_int_equal(mp_prf_cache_render_at(&c, &ml, 73.3, 47.8, sp, NULL, bh, b, NULL, NULL, 0),
                     0);
    for (size_t i = 0; i < (size_t)bw * bh; i++)
        assert_true(fabs(a[i] - b[i]) <= 1e-12);
    free(a);
    free(b);
    mp_prf_cache_free(&c);
    mp_prf_cache_free(&c0);
    mp_psf_free(&p);
    mp_psf_free(&p2);
    mp_psf_free(&p0);
    mp_psf_field_free(&f);
    mp_psf_field_free(&f2);
}

/* The pixel offset a core is measured from: the star's whole pixel kq of
 * fit/prf_cache.c, ⌊x − offset − ½⌋. */
static long star_pixel(const mp_psf *p, double x)
{
    return (long)floor(x - p->offset - 0.5);
}

/* table()'s model *m and its grid at 16 phases a pixel into *c. */
static void gauss_grid(mp_psf *p, mp_prf_model *m, mp_prf_cache *c)
{
    char err[MP_ERRLEN];
    table(p);
    *m = (mp_prf_model){p, NULL, 10};
    assert_int_equal(mp_prf_cache_build(m, 16, c, err), 0);
}

/* Each core tier's render, at 12 positions over all phases, is the cubic
 * render on the pixels whose offsets from the star's whole pixel lie
 * within [−r, r + 1] on both axes and the bilinear render elsewhere, bit
 * for bit, PRF and derivatives: drawn on spans cut at varying columns and
 * laid out in the outputs out of order (at), as a group fit's core
 * renders are; and a variable PSF's, whose later terms are added. */
static void test_core_tiers_compose(void **state)
{
    (void)state;
    char err[MP_ERRLEN];
    mp_psf p;
    mp_prf_model m;
    mp_prf_cache c;
    gauss_grid(&p, &m, &c);
    enum { W = 19, H = 19 };
    double ref[2][3][W * H], got[3][W * H];
    mp_span sp[2 * H];
    size_t at[2 * H];
    long checked = 0;
    for (int q = 0; q < 12; q++) {
        double x = 30.0 + 0.083 * q, y = 40.0 + 0.171 * q;
        long x0 = star_pixel(&p, x) - 9, y0 = star_pixel(&p, y) - 9;
        for (int v = 0; v < 2; v++)
            assert_int_equal(mp_prf_cache_render(&c, &m, x, y, x0, y0, W, H, ref[v][0], ref[v][1],
                                                 ref[v][2], v ? MP_PRF_BILINEAR : MP_PRF_CUBIC),
                             0);
        for (int k = 0; k < MP_PRF_NCORE; k++) {
            int r = mp_prf_cache_core_radius(k), ns = 0;
            assert_true(r >= 0);
            for (int j = H - 1; j >= 0; j--) {      /* rows last to first */
                int cut = (j * 7 + q + k) % W;
                if (cut > 0) {
                    sp[ns] = (mp_span){x0, y0 + j, cut};
                    at[ns++] = (size_t)j * W;
                }
                sp[ns] = (mp_span){x0 + cut, y0 + j, W - cut};
                at[ns++] = (size_t)j * W + (size_t)cut;
            }
            for (int a = 0; a < 3; a++)
                for (int i = 0; i < W * H; i++)
                    got[a][i] = NAN;
            assert_int_equal(mp_prf_cache_render_at(&c, &m, x, y, sp, at, ns, got[0], got[1],
                                                    got[2], MP_PRF_CORE(k)),
                             0);
            for (int j = 0; j < H; j++)
                for (int i = 0; i < W; i++) {
                    long ox = x0 + i - star_pixel(&p, x), oy = y0 + j - star_pixel(&p, y);
                    int in = ox >= -r && ox <= r + 1 && oy >= -r && oy <= r + 1;
                    for (int a = 0; a < 3; a++)
                        assert_true(got[a][j * W + i] == ref[!in][a][j * W + i]);
                    checked++;
                }
        }
    }
    assert_true(checked == 12L * MP_PRF_NCORE * W * H);
    mp_prf_cache_free(&c);
    mp_psf_free(&p);

    /* A variable PSF: Σ c_t·grid_t, each term in the star's mode. */
    mp_psf_field f;
    field_planes(&f);
    mp_psf pf;
    assert_int_equal(mp_psf_field_eval(&f, f.x0, f.y0, &pf, err), 0);
    pf.field = &f;
    mp_prf_model mf = {&pf, NULL, 10};
    assert_int_equal(mp_prf_cache_build(&mf, 16, &c, err), 0);
    assert_true(c.nt == 6);
    double x = 131.37, y = 62.81;
    long x0 = star_pixel(&pf, x) - 9, y0 = star_pixel(&pf, y) - 9;
    for (int v = 0; v < 2; v++)
        assert_int_equal(mp_prf_cache_render(&c, &mf, x, y, x0, y0, W, H, ref[v][0], NULL, NULL,
                                             v ? MP_PRF_BILINEAR : MP_PRF_CUBIC),
                         0);
    assert_int_equal(mp_prf_cache_render(&c, &mf, x, y, x0, y0, W, H, got[0], NULL, NULL,
                                         MP_PRF_CORE(1)),
                     0);
    int r = mp_prf_cache_core_radius(1), differ = 0;
    for (int j = 0; j < H; j++)
        for (int i = 0; i < W; i++) {
            long ox = x0 + i - star_pixel(&pf, x), oy = y0 + j - star_pixel(&pf, y);
            int in = ox >= -r && ox <= r + 1 && oy >= -r && oy <= r + 1;
            assert_true(got[0][j * W + i] == ref[!in][0][j * W + i]);
            differ += ref[0][0][j * W + i] != ref[1][0][j * W + i];
        }
    assert_true(differ > W * H / 2);        /* the two interpolations do differ */
    mp_prf_cache_free(&c);
    mp_psf_free(&pf);
    mp_psf_field_free(&f);
}

/* Each core tier's bound is what its render makes of the exact PRF: at
 * every cell's centre, Σ (drawn − exact)²/(E·exact + B + RON²) over the
 * union box, the largest of them, gives mp_prf_cache_bound_core (within
 * the float storage of the grid's P and δP², 1e-4), as the cubic's gives
 * mp_prf_cache_bound — a core placed one pixel off the render's would
 * not.  Each tier's limit holds its bound, within the bins' factor where
 * their last bin (P down to 0) holds little of the variance: the bound at
 * twice the limit is above it (q² grows at least as E). */
static void test_core_tiers_bound(void **state)
{
    (void)state;
    const double E = 2e5, B = 100.0, RON = 3.0;
    mp_psf p;
    mp_prf_model m;
    mp_prf_cache c;
    gauss_grid(&p, &m, &c);
    size_t n = c.npix;
    double *ex = malloc(n * sizeof *ex), *buf = malloc(n * sizeof *buf), *dr = malloc(n * sizeof *dr);
    assert_true(ex && buf && dr);
    mp_prf_work w = {0};
    int tight = 0;
    for (int k = -1; k < MP_PRF_NCORE; k++) {
        int mode = k < 0 ? MP_PRF_CUBIC : MP_PRF_CORE(k);
        double worst = 0.0;
        for (int ph = 0; ph < c.nph; ph++) {
            int ix = ph % c.G, iy = ph / c.G;
            double x = 40.0 + p.offset + 0.5 + (ix + 0.5) / c.G;
            double y = 50.0 + p.offset + 0.5 + (iy + 0.5) / c.G;
            long bx = star_pixel(&p, x) + c.ux0, by = star_pixel(&p, y) + c.uy0, rx, ry;
            int rw, rh;
            assert_int_equal(mp_prf_render_window(&m, x, y, bx, by, c.uw, c.uh, &rx, &ry, &rw, &rh,
                                                  buf, NULL, NULL, &w), 0);
            memset(ex, 0, n * sizeof *ex);
            for (int j = 0; j < rh; j++)
                for (int i = 0; i < rw; i++)
                    ex[(size_t)(ry - by + j) * c.uw + (size_t)(rx - bx + i)] = buf[(size_t)j * rw + i];
            assert_int_equal(mp_prf_cache_render(&c, &m, x, y, bx, by, c.uw, c.uh, dr, NULL, NULL,
                                                 mode), 0);
            double s = 0.0;
            for (size_t i = 0; i < n; i++) {
                double v = E * ex[i] + B + RON * RON;
                if (v > 0)
                    s += (dr[i] - ex[i]) * (dr[i] - ex[i]) / v;
            }
            worst = fmax(worst, s);
        }
        double q = E * sqrt(worst);
        double b = k < 0 ? mp_prf_cache_bound(&c, E, B, RON) : mp_prf_cache_bound_core(&c, k, E, B, RON);
        assert_true(q > 0 && fabs(b - q) <= 1e-4 * q);
        if (k >= 0) {
            double L = mp_prf_cache_limit_core(&c, k, B, RON, 0.1);
            assert_true(L > 0 && isfinite(L));
            assert_true(mp_prf_cache_bound_core(&c, k, L, B, RON) <= 0.1);
            assert_true(k == 0 || L >= 0.5 * mp_prf_cache_limit_core(&c, k - 1, B, RON, 0.1));
            /* where the last bin (P down to 0) spreads the variance little */
            if (2.01 * L * c.pmax * exp2(2 - MP_PRF_CACHE_NBIN) <= 0.1 * (B + RON * RON)) {
                assert_true(mp_prf_cache_bound_core(&c, k, 2.01 * L, B, RON) > 0.1);
                tight++;
            }
        }
    }
    assert_true(tight >= 4);
    free(ex);
    free(buf);
    free(dr);
    mp_prf_work_free(&w);
    mp_prf_cache_free(&c);
    mp_psf_free(&p);
}

/* A star's mode: the cheapest whose limit holds its flux, and from a
 * mode, never a cheaper one. */
static void test_tier_modes(void **state)
{
    (void)state;
    mp_prf_tiers t = {10.0, {20.0, 15.0, 40.0, 0.0, 80.0, 0.0, 0.0, 0.0}};
    assert_int_equal(mp_prf_tier_mode(&t, 0.0), MP_PRF_BILINEAR);
    assert_int_equal(mp_prf_tier_mode(&t, -10.0), MP_PRF_BILINEAR);
    assert_int_equal(mp_prf_tier_mode(&t, 12.0), MP_PRF_CORE(0));
    assert_int_equal(mp_prf_tier_mode(&t, 30.0), MP_PRF_CORE(2));
    assert_int_equal(mp_prf_tier_mode(&t, 50.0), MP_PRF_CORE(4));
    assert_int_equal(mp_prf_tier_mode(&t, 81.0), MP_PRF_CUBIC);
    assert_int_equal(mp_prf_tier_mode_from(&t, 5.0, MP_PRF_CORE(1)), MP_PRF_CORE(1));
    assert_int_equal(mp_prf_tier_mode_from(&t, 18.0, MP_PRF_CORE(1)), MP_PRF_CORE(2));
    assert_int_equal(mp_prf_tier_mode_from(&t, 5.0, MP_PRF_CUBIC), MP_PRF_CUBIC);
    assert_int_equal(mp_prf_tier_mode(NULL, 1.0), MP_PRF_CUBIC);
    mp_prf_tiers z = {0};
    assert_int_equal(mp_prf_tier_mode(&z, 1.0), MP_PRF_CUBIC);
    assert_int_equal(mp_prf_tier_mode(&z, 0.0), MP_PRF_BILINEAR);
}

/* The run's cache of a grid's flux limits (mp_econ_grid_limits): each on
 * the sky rounded down to a quarter octave, the same limits the grid's own
 * functions find there, no higher than on the sky itself; found once
 * (the second ask gives the same); no cache, no limits. */
/* Whether two axis operators are the same, bit for bit. */
static int same_axis(const mp_prf_axis *a, const mp_prf_axis *b)
{
    if (a->p0 != b->p0 || a->w != b->w || a->bw != b->bw || !a->d != !b->d)
        return 0;
    size_t nv = (size_t)(a->w > 0 ? a->w : 1) * (size_t)a->bw;
    for (int q = 0; q < a->w; q++)
        if (a->lo[q] != b->lo[q] || a->len[q] != b->len[q])
            return 0;
    return memcmp(a->v, b->v, nv * sizeof *a->v) == 0 &&
           (!a->d || memcmp(a->d, b->d, nv * sizeof *a->d) == 0);
}

/* The axis operator of arguments a (n, os, offset, x, xr, wp0, ww, hw,
 * deriv) into ax. */
static void refill_with(const double *a, mp_prf_axis *ax)
{
    assert_int_equal(mp_prf_axis_refill((int)a[0], (int)a[1], a[2], a[3], a[4], (long)a[5],
                                        (long)a[6], (int)a[7], (int)a[8], ax), 0);
}

/* mp_prf_axis_refill keeps the last operator when its arguments are the
 * same (the SIRT renders each star at one place a run): with each
 * argument changed in turn (each change gives another operator, checked:
 * the window lies inside the table, none clipped), a refill after the
 * base's is the fresh build's operator, and so is the base's after it. */
static void test_axis_refill_kept_only_when_same(void **state)
{
    (void)state;
    const double base[9] = {37, 4, 0.0, 20.37, 20.37, 18, 4, 10, 1};
    const double other[9] = {41, 2, 0.5, 20.61, 20.12, 19, 3, 6, 0};
    mp_prf_axis kept = {0}, b = {0};
    refill_with(base, &b);
    for (int k = 0; k < 9; k++) {
        double a[9];
        memcpy(a, base, sizeof a);
        a[k] = other[k];
        mp_prf_axis fresh = {0};
        refill_with(a, &fresh);
        assert_false(same_axis(&fresh, &b));
        refill_with(base, &kept);
        refill_with(a, &kept);
        assert_true(same_axis(&kept, &fresh));
        refill_with(base, &kept);
        assert_true(same_axis(&kept, &b));
        mp_prf_axis_free(&fresh);
    }
    mp_prf_axis_free(&kept);
    mp_prf_axis_free(&b);
}

/* Without the derivative an operator's runs leave out the zeros at their
 * ends (the five-point stencil's margins: 2 a side): every run no longer
 * than with the derivative, the inner ones 4 shorter, and the rows and
 * the columns it gives the bits the full runs give (d set aside, so
 * both go through the same two-lane sums).  A run cut one weight short
 * fails it. */
static void test_axis_trimmed_same_bits(void **state)
{
    (void)state;
    enum { N = 41, NY = N };      /* the table square: both axes' operator */
    const double a[9] = {N, 2, 0.0, 20.37, 20.37, 12, 14, 10, 0};
    double b[9];
    memcpy(b, a, sizeof b);
    b[8] = 1;
    mp_prf_axis t = {0}, full = {0};
    refill_with(a, &t);
    refill_with(b, &full);
    assert_int_equal(t.w, full.w);
    int shorter = 0;
    for (int q = 0; q < t.w; q++) {
        assert_true(t.lo[q] >= full.lo[q]);
        assert_true(t.lo[q] + t.len[q] <= full.lo[q] + full.len[q]);
        shorter += t.len[q] == full.len[q] - 4;
    }
    assert_true(shorter > 0);
    double *d = full.d, T[N * NY], At[NY * 16], Af[NY * 16], ot[16 * 16], of[16 * 16];
    full.d = NULL;
    for (int k = 0; k < N * NY; k++)
        T[k] = sin(0.37 * k) + 0.1 * cos(1.3 * k);
    mp_prf_axis_rows(T, N, 0, NY, &t, At, NULL);
    mp_prf_axis_rows(T, N, 0, NY, &full, Af, NULL);
    assert_memory_equal(At, Af, sizeof(double) * NY * (size_t)t.w);
    mp_prf_axis_cols(&t, 0, At, 0, t.w, 1.0, ot, 0, 0, t.w);
    mp_prf_axis_cols(&full, 0, Af, 0, t.w, 1.0, of, 0, 0, t.w);
    assert_memory_equal(ot, of, sizeof(double) * (size_t)t.w * (size_t)t.w);
    full.d = d;
    mp_prf_axis_free(&t);
    mp_prf_axis_free(&full);
}

static void test_grid_limits_cached(void **state)
{
    (void)state;
    const double B = 150.0, RON = 3.0;
    mp_psf p;
    mp_prf_model m;
    mp_prf_cache c;
    gauss_grid(&p, &m, &c);
    mp_econ_cache *cache = mp_econ_cache_new();
    assert_non_null(cache);
    double e1 = -1, e2 = -1, Bq = exp2(floor(4.0 * log2(B)) / 4.0);
    assert_true(Bq <= B && Bq > 0.8 * B);
    mp_prf_tiers t1, t2;
    assert_int_equal(mp_econ_grid_limits(cache, &c, B, RON, 0.1, &e1, &t1), 0);
    assert_true(e1 == mp_prf_cache_limit(&c, Bq, RON, 0.1));
    assert_true(e1 <= mp_prf_cache_limit(&c, B, RON, 0.1));
    assert_true(t1.lin == mp_prf_cache_limit_lin(&c, Bq, RON, 0.1));
    for (int k = 0; k < MP_PRF_NCORE; k++)
        assert_true(t1.core[k] == mp_prf_cache_limit_core(&c, k, Bq, RON, 0.1));
    assert_int_equal(mp_econ_grid_limits(cache, &c, B * 1.01, RON, 0.1, &e2, &t2), 0);
    assert_true(e2 == e1);
    assert_memory_equal(&t1, &t2, sizeof t1);
    assert_int_not_equal(mp_econ_grid_limits(NULL, &c, B, RON, 0.1, &e2, NULL), 0);
    mp_econ_cache_free(cache);
    mp_prf_cache_free(&c);
    mp_psf_free(&p);
}

int main(void)
{
    const struct CMUnitTest tests[] = {
        cmocka_unit_test(test_grid_matches_exact),
        cmocka_unit_test(test_bound_falls_as_h4),
        cmocka_unit_test(test_bilinear_matches_exact),
        cmocka_unit_test(test_bilinear_bound_falls_as_h2),
        cmocka_unit_test(test_bilinear_fit_within_bound),
        cmocka_unit_test(test_grid_only_for_its_model),
        cmocka_unit_test(test_separable_build_is_exact),
        cmocka_unit_test(test_rebuild_in_spare_blocks),
        cmocka_unit_test(test_render_paths_agree),
        cmocka_unit_test(test_render_phases_as_one_by_one),
        cmocka_unit_test(test_serves_as_the_bound),
        cmocka_unit_test(test_adjoint_is_transpose),
        cmocka_unit_test(test_field_grid_within_bound),
        cmocka_unit_test(test_core_tiers_compose),
        cmocka_unit_test(test_core_tiers_bound),
        cmocka_unit_test(test_tier_modes),
        cmocka_unit_test(test_grid_limits_cached),
        cmocka_unit_test(test_axis_refill_kept_only_when_same),
        cmocka_unit_test(test_axis_trimmed_same_bits),
    };
    return cmocka_run_group_tests(tests, NULL, NULL);
}
