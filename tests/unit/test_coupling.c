/* test_coupling.c — κ, the coupling of two stars' fits (fit/coupling.c),
 * against its definition computed here independently: the Fisher
 * information of the analytic pixel-integrated Gaussian (P = ΔΦx·ΔΦy,
 * its position derivatives from the Gaussian at the pixel edges) over the
 * pixels of both fitting discs, weights 1/(B + RON² + Ea Pa + Eb Pb), and
 * the largest canonical correlation by power iteration on
 * Iaa⁻¹ Iab Ibb⁻¹ Iba (3×3 inverses by cofactors, not LAPACK). */
#include <setjmp.h>
#include <stdarg.h>
#include <stddef.h>
#include <cmocka.h>
#include <math.h>
#include <stdlib.h>
#include <string.h>
#include "fit/fit.h"

#define SIG (3.0 / 2.3548200450309493)
#define FITRAD 3.0
#define CRIT 5.0
#define SKY 100.0
#define RON 3.0

static double Phi(double t)
{
    return 0.5 * erfc(-t / M_SQRT2);
}

static double phi(double t)
{
    return exp(-0.5 * t * t) / sqrt(2.0 * M_PI);
}

/* P, ∂P/∂x0, ∂P/∂y0 of a unit star at (x0, y0) in pixel (X, Y). */
static void gauss_px(double x0, double y0, long X, long Y, double g[3])
{
    double ax = (X - 0.5 - x0) / SIG, bx = (X + 0.5 - x0) / SIG;
    double ay = (Y - 0.5 - y0) / SIG, by = (Y + 0.5 - y0) / SIG;
    double px = Phi(bx) - Phi(ax), py = Phi(by) - Phi(ay);
    g[0] = px * py;
    g[1] = -(phi(bx) - phi(ax)) / SIG * py;
    g[2] = -(phi(by) - phi(ay)) / SIG * px;
}

static void inv3(const double a[9], double r[9])
{
    double c[9] = {a[4] * a[8] - a[5] * a[7], a[2] * a[7] - a[1] * a[8], a[1] * a[5] - a[2] * a[4],
                   a[5] * a[6] - a[3] * a[8], a[0] * a[8] - a[2] * a[6], a[2] * a[3] - a[0] * a[5],
                   a[3] * a[7] - a[4] * a[6], a[1] * a[6] - a[0] * a[7], a[0] * a[4] - a[1] * a[3]};
    double det = a[0] * c[0] + a[1] * c[3] + a[2] * c[6];
    for (int i = 0; i < 9; i++)
        r[i] = c[i] / det;
}

static void mul3(const double a[9], const double b[9], double r[9])
{
    for (int i = 0; i < 3; i++)
        for (int j = 0; j < 3; j++)
            r[3 * i + j] = a[3 * i] * b[j] + a[3 * i + 1] * b[3 + j] + a[3 * i + 2] * b[6 + j];
}

/* κ of stars at (xa, ya) and (xb, yb) with fluxes ea, eb on a sky and
 * read noise of B + RON² = beff. */
static double kappa_exact_on(double beff, double xa, double ya, double xb, double yb, double ea,
                             double eb)
{
    double I[6][6] = {{0}};
    for (long Y = (long)ya - 12; Y <= (long)ya + 12; Y++)
        for (long X = (long)xa - 12; X <= (long)xa + 12; X++) {
            if (hypot(X - xa, Y - ya) > FITRAD && hypot(X - xb, Y - yb) > FITRAD)
                continue;
            double g[6];
            gauss_px(xa, ya, X, Y, g);
            gauss_px(xb, yb, X, Y, g + 3);
            double w = 1.0 / (beff + ea * g[0] + eb * g[3]);
            for (int r = 0; r < 6; r++)
                for (int c = 0; c < 6; c++)
                    I[r][c] += w * g[r] * g[c];
        }
    double aa[9], bb[9], ab[9], ba[9], ia[9], ib[9], t1[9], t2[9], M[9];
    for (int r = 0; r < 3; r++)
        for (int c = 0; c < 3; c++) {
            aa[3 * r + c] = I[r][c];
            bb[3 * r + c] = I[r + 3][c + 3];
            ab[3 * r + c] = I[r][c + 3];
            ba[3 * r + c] = I[r + 3][c];
        }
    inv3(aa, ia);
    inv3(bb, ib);
    mul3(ia, ab, t1);
    mul3(t1, ib, t2);
    mul3(t2, ba, M);
    double v[3] = {1.0, 0.7, 0.3}, lam = 0.0;
    for (int it = 0; it < 200; it++) {
        double u[3], n = 0.0;
        for (int i = 0; i < 3; i++) {
            u[i] = M[3 * i] * v[0] + M[3 * i + 1] * v[1] + M[3 * i + 2] * v[2];
            n += u[i] * u[i];
        }
        n = sqrt(n);
        if (!(n > 0))
            return 0.0;
        lam = n / sqrt(v[0] * v[0] + v[1] * v[1] + v[2] * v[2]);
        for (int i = 0; i < 3; i++)
            v[i] = u[i] / n;
    }
    return sqrt(fmin(lam, 1.0));
}

/* The largest κ over the table's eight directions at node separation d,
 * on beff. */
static double kappa_dirs_on(double beff, double d, double ea, double eb)
{
    double k = 0.0;
    for (int dir = 0; dir < 8; dir++) {
        double th = 2.0 * M_PI * dir / 8;
        k = fmax(k, kappa_exact_on(beff, 100.0, 100.0, 100.0 + d * cos(th), 100.0 + d * sin(th),
                                   ea, eb));
    }
    return k;
}

static double kappa_dirs(double d, double ea, double eb)
{
    return kappa_dirs_on(SKY + RON * RON, d, ea, eb);
}

/* The table of the analytic Gaussian of FWHM 3 px (mp_psf_gauss). */
static void gauss_table(mp_coupling *c)
{
    mp_psf p;
    mp_psf_gauss(3.0, &p);
    mp_prf_model m = {&p, NULL, 10};
    char err[MP_ERRLEN];
    assert_int_equal(mp_coupling_build(&m, FITRAD, CRIT, SKY, RON, c, err), 0);
}

/* At the nodes the table holds the exact κ made conservative: at least
 * the exact value there, and at most the largest exact value over the
 * nodes it stands for (the same or fainter fluxes, the same or larger
 * separations).  The table sums over a PSF rendered by the fit's own code
 * (damped sinc and all) where this test integrates the Gaussian; 2e-3
 * allows for their difference. */
static void test_kappa_at_nodes(void **state)
{
    (void)state;
    mp_coupling c;
    gauss_table(&c);
    assert_true(c.nd >= 10 && c.na >= 5);
    const int na = c.na, fl[] = {0, c.na / 2, c.na - 1};
    double *ex = malloc((size_t)c.nd * na * na * sizeof *ex);
    assert_non_null(ex);
    for (int id = 0; id < c.nd; id++)
        for (int ia = 0; ia < na; ia++)
            for (int ib = 0; ib < na; ib++)
                ex[(id * na + ia) * na + ib] =
                    kappa_dirs(id * c.dstep, c.beff * pow(10.0, c.a0 + c.astep * ia),
                               c.beff * pow(10.0, c.a0 + c.astep * ib));
    for (int id = 0; id * c.dstep < CRIT; id++)     /* from crit on: 0 */
        for (int u = 0; u < 3; u++)
            for (int v = 0; v < 3; v++) {
                int ia = fl[u], ib = fl[v];
                double Ea = c.beff * pow(10.0, c.a0 + c.astep * ia);
                double Eb = c.beff * pow(10.0, c.a0 + c.astep * ib);
                double got = mp_coupling_kappa(&c, id * c.dstep, Ea * (1 - 1e-9), Eb * (1 - 1e-9));
                double env = 0.0;
                for (int jd = id; jd < c.nd; jd++)
                    for (int ja = 0; ja <= ia; ja++)
                        for (int jb = 0; jb <= ib; jb++)
                            env = fmax(env, ex[(jd * na + ja) * na + jb]);
                assert_true(got >= ex[(id * na + ia) * na + ib] - 2e-3);
                assert_true(got <= env + 2e-3);
            }
    /* A star on itself is fully coupled; beyond crit not at all. */
    assert_true(mp_coupling_kappa(&c, 0.0, 1e3, 1e3) > 0.99);
    assert_true(mp_coupling_kappa(&c, CRIT, 1e3, 1e3) == 0.0);
    assert_true(mp_coupling_kappa(&c, NAN, 1e3, 1e3) == 1.0);
    free(ex);
    mp_coupling_free(&c);
}

/* A lookup between the nodes bounds the exact κ there in the directions
 * tabulated: κ falls with separation and the table rounds the separation
 * down and each flux up.  n off-node separations and fluxes (units of c's
 * B + RON²) of seed s; the exact values at the table's eight directions. */
static void lookups_bound_exact(const mp_coupling *c, unsigned s, int n)
{
    for (int k = 0; k < n; k++) {
        s = s * 1103515245u + 12345u;
        double d = 0.3 + (CRIT - 0.4) * ((s >> 8) & 0xffff) / 65536.0;
        s = s * 1103515245u + 12345u;
        double Ea = c->beff * pow(10.0, 6.0 * ((s >> 8) & 0xffff) / 65536.0);
        s = s * 1103515245u + 12345u;
        double Eb = c->beff * pow(10.0, 6.0 * ((s >> 8) & 0xffff) / 65536.0);
        assert_true(mp_coupling_kappa(c, d, Ea, Eb) >= kappa_dirs_on(c->beff, d, Ea, Eb) - 2e-3);
    }
}

static void test_kappa_between_nodes(void **state)
{
    (void)state;
    mp_coupling c;
    gauss_table(&c);
    lookups_bound_exact(&c, 12345u, 40);
    mp_coupling_free(&c);
}

/* One table serves every sky (mp_coupling_at; the pipeline keeps it from
 * round to round): κ depends on the fluxes only through E/(B + RON²), so
 * a table made on another sky is the same table, and moved to a sky 30
 * times brighter its lookups bound the exact κ there as a table made
 * there would. */
static void test_kappa_any_sky(void **state)
{
    (void)state;
    mp_coupling c, d2;
    gauss_table(&c);
    mp_psf p;
    mp_psf_gauss(3.0, &p);
    mp_prf_model m = {&p, NULL, 10};
    char err[MP_ERRLEN];
    const double sky2 = 30.0 * SKY;
    assert_int_equal(mp_coupling_build(&m, FITRAD, CRIT, sky2, RON, &d2, err), 0);
    assert_int_equal(c.nd, d2.nd);
    assert_int_equal(memcmp(c.k, d2.k, (size_t)c.nd * c.na * c.na * sizeof *c.k), 0);
    mp_coupling_at(&c, sky2, RON);
    assert_true(c.beff == d2.beff);
    lookups_bound_exact(&c, 777u, 20);
    mp_coupling_free(&c);
    mp_coupling_free(&d2);
}

int main(void)
{
    const struct CMUnitTest tests[] = {
        cmocka_unit_test(test_kappa_at_nodes),
        cmocka_unit_test(test_kappa_between_nodes),
        cmocka_unit_test(test_kappa_any_sky),
    };
    return cmocka_run_group_tests(tests, NULL, NULL);
}
