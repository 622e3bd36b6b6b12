/* test_psf_field.c — spatially variable PSF tables (psf/field.c,
 * psf/field_io.c) and the fit evaluating them at each star. */
#include <setjmp.h>
#include <stdarg.h>
#include <stddef.h>
#include <cmocka.h>
#include <fitsio.h>
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <unistd.h>
#include "fit/fit.h"
#include "sim/sim.h"

/* |a − b| ≤ eps (eps 0: equal). */
#define assert_near(a, b, eps) assert_true(fabs((double)(a) - (double)(b)) <= (eps))

typedef struct {
    char dir[512];
} fixture;

static int setup(void **state)
{
    fixture *s = calloc(1, sizeof *s);
    if (!s)
        return 1;
    const char *tmp = getenv("TMPDIR");
    snprintf(s->dir, sizeof s->dir, "%s/test_psf_field.XXXXXX", tmp && *tmp ? tmp : "/tmp");
    if (!mkdtemp(s->dir)) {
        free(s);
        return 1;
    }
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

static const char *path_in(const fixture *s, const char *name, char *buf, size_t n)
{
    snprintf(buf, n, "%s/%s", s->dir, name);
    return buf;
}

/* An order-2 field of 5×3 elements whose planes are distinct numbers, so
 * that any mix-up of terms shows. */
static void small_field(mp_psf_field *f)
{
    char err[MP_ERRLEN];
    assert_int_equal(mp_psf_field_new(2, 5, 3, 2, 101.0, 51.0, 200.0, 100.0, f, err), 0);
    size_t plane = 15;
    for (int k = 0; k < 6; k++)
        for (size_t i = 0; i < plane; i++)
            f->planes[k * plane + i] = (k == 0 ? 0.05 : 0.001 * (k + 1)) + 1e-4 * (double)i;
    f->sum = 0.0;
    for (size_t i = 0; i < plane; i++)
        f->sum += f->planes[i];
}

/* The format's definition, written out: T = P0 + P1 dx + P2 dx² + P3 dy +
 * P4 dx dy + P5 dy², dx = (x − POLZERO1)/POLSCAL1, dy likewise. */
static void test_eval_is_the_polynomial(void **state)
{
    (void)state;
    mp_psf_field f;
    small_field(&f);
    char err[MP_ERRLEN];
    const double xs[3] = {101.0, 17.3, 260.9}, ys[3] = {51.0, 140.2, 3.5};
    for (int c = 0; c < 3; c++) {
        mp_psf t;
        assert_int_equal(mp_psf_field_eval(&f, xs[c], ys[c], &t, err), 0);
        double dx = (xs[c] - 101.0) / 200.0, dy = (ys[c] - 51.0) / 100.0;
        double mono[6] = {1, dx, dx * dx, dy, dx * dy, dy * dy};
        double sum = 0.0;
        for (int i = 0; i < 15; i++) {
            double want = 0.0;
            for (int k = 0; k < 6; k++)
                want += f.planes[k * 15 + i] * mono[k];
            assert_near(t.t[i], want, 1e-15);
            sum += want;
        }
        assert_near(t.sum, sum, 1e-14);
        assert_int_equal(t.nx, 5);
        assert_int_equal(t.ny, 3);
        assert_int_equal(t.os, 2);
        mp_psf_free(&t);
    }
    /* Order 1: 1, dx, dy. */
    mp_psf_field g;
    assert_int_equal(mp_psf_field_new(1, 1, 1, 1, 10.0, 20.0, 4.0, 8.0, &g, err), 0);
    double terms[MP_PSF_MAXTERMS];
    mp_psf_field_terms(&g, 12.0, 16.0, terms);
    assert_near(terms[0], 1.0, 0);
    assert_near(terms[1], 0.5, 0);
    assert_near(terms[2], -0.5, 0);
    mp_psf_field_free(&g);
    /* Order 3 (README): 1, dx, dx², dx³, dy, dx·dy, dx²·dy, dy², dx·dy², dy³. */
    assert_int_equal(mp_psf_field_new(3, 1, 1, 1, 10.0, 20.0, 4.0, 8.0, &g, err), 0);
    assert_int_equal(g.nterms, 10);
    mp_psf_field_terms(&g, 18.0, 16.0, terms);      /* dx 2, dy −0.5 */
    const double want3[10] = {1, 2, 4, 8, -0.5, -1, -2, 0.25, 0.5, -0.125};
    for (int k = 0; k < 10; k++)
        assert_near(terms[k], want3[k], 0);
    mp_psf_field_free(&g);
    mp_psf_field_free(&f);
}

/* Block-summing is linear: the rebinned field at (x, y) is the rebinned
 * table of the field at (x, y) (to rounding). */
static void test_rebin_commutes(void **state)
{
    (void)state;
    char err[MP_ERRLEN];
    mp_psf a, b;
    assert_int_equal(mp_psf_gauss_table(2.5, 4, 6.0, &a, err), 0);
    assert_int_equal(mp_psf_gauss_table(3.5, 4, 6.0, &b, err), 0);
    mp_psf_field f, r;
    assert_int_equal(mp_psf_field_new(1, a.nx, a.ny, 4, 50.0, 50.0, 40.0, 40.0, &f, err), 0);
    size_t n = (size_t)a.nx * a.ny;
    for (size_t i = 0; i < n; i++) {
        f.planes[i] = 0.5 * (a.t[i] + b.t[i]);
        f.planes[n + i] = 0.5 * (b.t[i] - a.t[i]);
        f.planes[2 * n + i] = 0.1 * a.t[i];
    }
    assert_int_equal(mp_psf_field_rebin(&f, 2, &r, err), 0);
    mp_psf t, tr, rt;
    assert_int_equal(mp_psf_field_eval(&f, 73.2, 31.0, &t, err), 0);
    assert_int_equal(mp_psf_rebin(&t, 2, &tr, err), 0);
    assert_int_equal(mp_psf_field_eval(&r, 73.2, 31.0, &rt, err), 0);
    assert_int_equal(rt.nx, tr.nx);
    assert_int_equal(rt.os, 2);
    assert_near(rt.offset, tr.offset, 0);
    for (size_t i = 0; i < (size_t)rt.nx * rt.ny; i++)
        assert_near(rt.t[i], tr.t[i], 1e-15);
    mp_psf_free(&t), mp_psf_free(&tr), mp_psf_free(&rt), mp_psf_free(&a), mp_psf_free(&b);
    mp_psf_field_free(&f), mp_psf_field_free(&r);
}

static void test_write_read_round_trip(void **state)
{
    fixture *s = *state;
    char path[600], err[MP_ERRLEN], warn[MP_ERRLEN];
    mp_psf_field f, g;
    small_field(&f);
    f.nstar = 2;
    snprintf(f.why, sizeof f.why, "order 2: the quadratic terms lower chi2 by 812 for 10 dof "
             "(p < 1e-100), a reason longer than one FITS card can hold");
    mp_psf_star st[2] = {{10.5, 20.25, 1e5, 1}, {30.0, 40.0, 2e4, 0}}, *back;
    int nb;
    path_in(s, "field.fits", path, sizeof path);
    assert_int_equal(mp_psf_field_write(path, &f, st, 2, err), 0);
    assert_int_equal(mp_psf_field_read(path, 0, 0, &g, &back, &nb, warn, err), 0);
    assert_int_equal(g.order, 2);
    assert_int_equal(g.nterms, 6);
    assert_int_equal(g.os, 2);
    assert_near(g.x0, 101.0, 0);
    assert_near(g.yscale, 100.0, 0);
    assert_int_equal(g.nstar, 2);
    assert_string_equal(g.why, f.why);
    assert_near(g.sum, f.sum, 1e-15);
    for (int i = 0; i < 90; i++)
        assert_near(g.planes[i], f.planes[i], 0);
    assert_int_equal(nb, 2);
    assert_near(back[1].y, 40.0, 0);
    assert_int_equal(back[0].used, 1);
    assert_int_equal(back[1].used, 0);
    free(back);
    mp_psf_field_free(&g);
    /* Without the optional parts, and an order-0 field as a plain 2-D table
     * that mp_psf_read reads too. */
    mp_psf t;
    mp_psf_field z;
    assert_int_equal(mp_psf_gauss_table(3.0, 2, 5.0, &t, err), 0);
    assert_int_equal(mp_psf_field_from_table(&t, &z, err), 0);
    path_in(s, "plain.fits", path, sizeof path);
    assert_int_equal(mp_psf_field_write(path, &z, NULL, 0, err), 0);
    assert_int_equal(mp_psf_field_read(path, 0, 0, &g, &back, &nb, warn, err), 0);
    assert_int_equal(g.order, 0);
    assert_null(back);
    assert_int_equal(nb, 0);
    mp_psf p;
    assert_int_equal(mp_psf_read(path, 0, 0, &p, NULL, err), 0);
    assert_int_equal(p.os, 2);
    for (int i = 0; i < p.nx * p.ny; i++)
        assert_near(g.planes[i], t.t[i], 0);
    mp_psf_free(&p), mp_psf_free(&t);
    mp_psf_field_free(&g), mp_psf_field_free(&z), mp_psf_field_free(&f);
    /* No temporary left beside the outputs. */
    char cmd[700];
    snprintf(cmd, sizeof cmd, "ls -A '%s' | grep -q tmp", s->dir);
    assert_int_not_equal(system(cmd), 0);
}

/* A cube written by hand with the given keywords; NULL value leaves it out. */
static void write_cube(const char *path, long nx, long ny, long nt, const char *order,
                       const char *scal1, double bad)
{
    fitsfile *fp;
    int st = 0;
    long ax[3] = {nx, ny, nt};
    unlink(path);
    fits_create_file(&fp, path, &st);
    fits_create_img(fp, DOUBLE_IMG, 3, ax, &st);
    double z = 30.0, sc = 20.0;
    if (order) {
        int o = atoi(order);
        fits_write_key(fp, TINT, "PSFORDER", &o, "", &st);
    }
    fits_write_key(fp, TDOUBLE, "POLZERO1", &z, "", &st);
    fits_write_key(fp, TDOUBLE, "POLZERO2", &z, "", &st);
    if (scal1) {
        double v = atof(scal1);
        fits_write_key(fp, TDOUBLE, "POLSCAL1", &v, "", &st);
    }
    fits_write_key(fp, TDOUBLE, "POLSCAL2", &sc, "", &st);
    size_t n = (size_t)(nx * ny * nt);
    double *v = calloc(n, sizeof *v);
    assert_non_null(v);
    v[(ny / 2) * nx + nx / 2] = 0.9;
    v[n - 1] = bad;
    long f1[3] = {1, 1, 1};
    fits_write_pix(fp, TDOUBLE, f1, (LONGLONG)n, v, &st);
    fits_close_file(fp, &st);
    free(v);
    assert_int_equal(st, 0);
}

static void expect_error(const char *path, const char *want)
{
    char err[MP_ERRLEN] = "", warn[MP_ERRLEN];
    mp_psf_field f;
    assert_int_not_equal(mp_psf_field_read(path, 0, 0, &f, NULL, NULL, warn, err), 0);
    assert_non_null(strstr(err, path));
    if (!strstr(err, want))
        fail_msg("error '%s' does not say '%s'", err, want);
    assert_null(strchr(err, '\n'));
    assert_null(f.planes);
}

static void test_bad_cubes(void **state)
{
    fixture *s = *state;
    char p[600];
    path_in(s, "c.fits", p, sizeof p);
    write_cube(p, 5, 5, 3, "1", "20", 0.0);
    char err[MP_ERRLEN], warn[MP_ERRLEN];
    mp_psf_field f;
    assert_int_equal(mp_psf_field_read(p, 0, 0, &f, NULL, NULL, warn, err), 0);
    assert_int_equal(f.order, 1);
    mp_psf_field_free(&f);
    write_cube(p, 5, 5, 3, NULL, "20", 0.0);          /* order from the planes */
    assert_int_equal(mp_psf_field_read(p, 0, 0, &f, NULL, NULL, warn, err), 0);
    assert_int_equal(f.order, 1);
    mp_psf_field_free(&f);
    write_cube(p, 5, 5, 10, NULL, "20", 0.0);         /* 10 planes: order 3 */
    assert_int_equal(mp_psf_field_read(p, 0, 0, &f, NULL, NULL, warn, err), 0);
    assert_int_equal(f.order, 3);
    mp_psf_field_free(&f);
    write_cube(p, 5, 5, 15, "4", "20", 0.0);
    expect_error(p, "PSFORDER must be 0 .. 3");
    write_cube(p, 5, 5, 4, NULL, "20", 0.0);
    expect_error(p, "4 planes");
    write_cube(p, 5, 5, 3, "2", "20", 0.0);
    expect_error(p, "3 planes");
    write_cube(p, 5, 5, 3, "1", NULL, 0.0);
    expect_error(p, "POLSCAL1 missing");
    write_cube(p, 5, 5, 3, "1", "0", 0.0);
    expect_error(p, "POLSCAL1 invalid");
    /* A scale so fine that the polynomial overflows a few pixels from the
     * origin (a fuzz finding: a non-finite PRF from an accepted file). */
    write_cube(p, 5, 5, 3, "1", "1e-200", 0.0);
    expect_error(p, "POLSCAL1/2 1e-200, 20 out of range");
    write_cube(p, 5, 5, 3, "1", "0.01", 0.0);         /* the finest accepted */
    assert_int_equal(mp_psf_field_read(p, 0, 0, &f, NULL, NULL, warn, err), 0);
    mp_psf_field_free(&f);
    write_cube(p, 5, 5, 3, "1", "20", NAN);
    expect_error(p, "NaN");
    write_cube(p, 4, 5, 3, "1", "20", 0.0);
    expect_error(p, "odd");
    write_cube(p, 5, 5, 3, "1", "20", 0.0);
    FILE *fp = fopen(p, "r+b");                        /* truncated */
    assert_non_null(fp);
    assert_int_equal(ftruncate(fileno(fp), 2880 + 100), 0);
    fclose(fp);
    expect_error(p, "");
    expect_error(path_in(s, "missing.fits", p, sizeof p), "");
}

/* ---- The fit with a linearly varying PSF ------------------------------------ */

enum { NSIDE = 200, NGRID = 9 };

/* Truth: PSF(x) = (1 − a) G(FWHM 2.5) + a G(FWHM 3.5), a = (x − 20)/160,
 * drawn by the simulator (exact erf pixel integrals, not the fitter's
 * shifter).  The matching field: P0 = (G1 + G2)/2, P1 = (G2 − G1)/2 with
 * dx = (x − 100)/80, exact at every x. */
static void linear_truth(mp_psf_field *f)
{
    char err[MP_ERRLEN];
    mp_psf g1, g2;
    assert_int_equal(mp_psf_gauss_table(2.5, 2, 8.0, &g1, err), 0);
    assert_int_equal(mp_psf_gauss_table(3.5, 2, 8.0, &g2, err), 0);
    assert_int_equal(mp_psf_field_new(1, g1.nx, g1.ny, 2, 100.0, 100.0, 80.0, 80.0, f, err), 0);
    size_t n = (size_t)g1.nx * g1.ny;
    f->sum = 0.0;
    for (size_t i = 0; i < n; i++) {
        f->planes[i] = 0.5 * (g1.t[i] + g2.t[i]);
        f->planes[n + i] = 0.5 * (g2.t[i] - g1.t[i]);
        f->sum += f->planes[i];
    }
    mp_psf_free(&g1), mp_psf_free(&g2);
}

/* The z-score of the mean flux error on each side of the field (x < 60 and
 * x > 140), over NGRID² stars of E = 2e4 e- on B = 100, RON 3. */
static void fit_sides(const mp_frame *fr, const mp_prf_model *m, const double *tx,
                      const double *ty, double E, double z[2], double *pos)
{
    mp_fit_opts o;
    mp_fit_opts_default(&o);
    o.sky_order = 0;
    o.fitrad = 8.0;
    double sum[2] = {0, 0};
    int cnt[2] = {0, 0};
    double pmax = 0.0;
    char err[MP_ERRLEN];
    for (int k = 0; k < NGRID * NGRID; k++) {
        mp_star s = {.x = tx[k] + 0.1, .y = ty[k] - 0.1, .flux = 0.8 * E};
        assert_int_equal(mp_fit_group(fr, m, &o, NAN, &s, 1, err), 0);
        int side = tx[k] < 60 ? 0 : tx[k] > 140 ? 1 : -1;
        double dp = fabs(s.x - tx[k]) / s.ex;
        pmax = dp > pmax ? dp : pmax;
        if (side < 0)
            continue;
        sum[side] += (s.flux - E) / s.eflux;
        cnt[side]++;
    }
    for (int h = 0; h < 2; h++)
        z[h] = sum[h] / sqrt(cnt[h]);
    *pos = pmax;
}

/* The frame of linear_truth's PSF: NGRID² stars of E e- 20 px apart on
 * B = 100 e-, RON 3 e- (seed fixed); their positions into tx, ty. */
static void linear_frame(mp_frame *fr, double E, double *tx, double *ty)
{
    const double B = 100.0, RON = 3.0;
    memset(fr, 0, sizeof *fr);
    fr->im.nx = fr->im.ny = NSIDE;
    fr->im.pix = calloc((size_t)NSIDE * NSIDE, sizeof *fr->im.pix);
    fr->mask = calloc((size_t)NSIDE * NSIDE, 1);
    assert_non_null(fr->im.pix);
    assert_non_null(fr->mask);
    fr->gain = 1.0;
    fr->rdnoise = RON;
    fr->saturate = INFINITY;
    fr->exptime = 1.0;
    mp_rng r;
    mp_rng_seed(&r, 20261124);
    for (size_t i = 0; i < (size_t)NSIDE * NSIDE; i++)
        fr->im.pix[i] = B;
    for (int k = 0; k < NGRID * NGRID; k++) {
        tx[k] = 20.0 + 20.0 * (k % NGRID) + mp_rng_uniform(&r) - 0.5;
        ty[k] = 20.0 + 20.0 * (k / NGRID) + mp_rng_uniform(&r) - 0.5;
        double a = (tx[k] - 20.0) / 160.0;
        double s1 = 2.5 / (2.0 * sqrt(2.0 * log(2.0))), s2 = 3.5 / (2.0 * sqrt(2.0 * log(2.0)));
        mp_sim_prf p1 = {.kind = MP_SIM_GAUSS, .sigma = s1, .volume = 1.0};
        mp_sim_prf p2 = {.kind = MP_SIM_GAUSS, .sigma = s2, .volume = 1.0};
        assert_int_equal(mp_sim_add_star_float(&p1, tx[k], ty[k], (1 - a) * E, fr->im.pix, NSIDE, NSIDE), 0);
        assert_int_equal(mp_sim_add_star_float(&p2, tx[k], ty[k], a * E, fr->im.pix, NSIDE, NSIDE), 0);
    }
    mp_sim_add_noise_float(&r, fr->im.pix, (long)NSIDE * NSIDE, RON);
}

/* A frame whose PSF widens linearly along x, fitted with the true order-1
 * field and with its order-0 table (the field at its origin).  With the
 * field each side's mean flux error is N(0, 1) in units of its standard
 * error: |z| < 4 fails by chance 6e-5 of the time per side.  The order-0
 * table is 3.0 px wide where the stars are 2.5–2.75 or 3.25–3.5: the flux
 * of a star fitted with a wider (narrower) PSF is biased high (low) by
 * several % against a 1 % σ, so |z| ≫ 4 on both sides, with opposite
 * signs (measured: z ≈ +32 and −37; with the field −1.6 and +1.1). */
static void test_linear_variation_fit(void **state)
{
    (void)state;
    const double E = 2e4;
    mp_frame fr;
    double tx[NGRID * NGRID], ty[NGRID * NGRID];
    linear_frame(&fr, E, tx, ty);
    mp_psf_field f;
    linear_truth(&f);
    char err[MP_ERRLEN];
    mp_psf origin;
    assert_int_equal(mp_psf_field_eval(&f, f.x0, f.y0, &origin, err), 0);
    mp_psf plain = origin;
    plain.field = NULL;
    origin.field = &f;
    mp_prf_model m1 = {&origin, NULL, 10}, m0 = {&plain, NULL, 10};
    double z1[2], z0[2], p1, p0;
    fit_sides(&fr, &m1, tx, ty, E, z1, &p1);
    fit_sides(&fr, &m0, tx, ty, E, z0, &p0);
    print_message("order 1: z = %.2f, %.2f; order 0: z = %.2f, %.2f; max |dx|/ex %.2f, %.2f\n",
                  z1[0], z1[1], z0[0], z0[1], p1, p0);
    assert_true(fabs(z1[0]) < 4.0 && fabs(z1[1]) < 4.0);
    /* Left: stars narrower than the table, flux high; right: wider, low. */
    assert_true(z0[0] > 4.0 && z0[1] < -4.0);
    /* Positions: the PSF is symmetric about the star whatever its width,
     * so neither model biases them; 81 |Δx|/σ all below 4.5 (false failure
     * 81 × 7e-6). */
    assert_true(p1 < 4.5);
    mp_psf_free(&origin);
    mp_psf_field_free(&f);
    free(fr.im.pix);
    free(fr.mask);
}

/* The frame fitter (mp_fit_table) fits each group on a sub-image cut
 * around it; a variable PSF must still be read at the star's frame
 * position, not at its place on the sub-image (which put every star at
 * the field's lower-left corner: the narrow side, so right-hand stars,
 * 3.25–3.5 px wide, were fitted with a 2.4 px table).  As
 * test_linear_variation_fit: each side's mean flux error over its
 * standard error is N(0, 1) with the right PSF, |z| < 4 fails by chance
 * 6e-5 per side; before the fix z = −21 (left) and −126 (right). */
static void test_frame_fit_reads_field_at_star(void **state)
{
    (void)state;
    const double E = 2e4;
    mp_frame fr;
    double tx[NGRID * NGRID], ty[NGRID * NGRID];
    linear_frame(&fr, E, tx, ty);
    mp_psf_field f;
    linear_truth(&f);
    char err[MP_ERRLEN];
    mp_psf origin;
    assert_int_equal(mp_psf_field_eval(&f, f.x0, f.y0, &origin, err), 0);
    origin.field = &f;
    mp_prf_model m = {&origin, NULL, 10};
    mp_table t;
    mp_table_init(&t);
    const char *c[5] = {"NUMBER", "X_IMAGE", "Y_IMAGE", "GROUP_ID", "FLUX"};
    int col[5];
    for (int i = 0; i < 5; i++)
        assert_true((col[i] = mp_table_add_col(&t, c[i])) >= 0);
    for (int k = 0; k < NGRID * NGRID; k++) {
        long r = mp_table_add_row(&t);
        assert_true(r >= 0);
        double v[5] = {k + 1, tx[k] + 0.1, ty[k] - 0.1, k + 1, 0.8 * E};
        for (int i = 0; i < 5; i++)
            mp_table_set(&t, (size_t)r, col[i], v[i]);
    }
    mp_frame_opts o;
    mp_frame_opts_default(&o);
    o.fit.sky_order = 0;
    o.fit.fitrad = 8.0;
    assert_int_equal(mp_fit_table(&fr, &m, &o, &t, NULL, err), 0);
    assert_int_equal((int)t.nrow, NGRID * NGRID);
    int cn = mp_table_col(&t, "NUMBER"), cf = mp_table_col(&t, "FLUX_PSF");
    int ce = mp_table_col(&t, "FLUXERR_PSF");
    assert_true(cn >= 0 && cf >= 0 && ce >= 0);
    double sum[2] = {0, 0};
    int cnt[2] = {0, 0};
    for (size_t r = 0; r < t.nrow; r++) {
        int k = (int)mp_table_get(&t, r, cn) - 1;
        assert_true(k >= 0 && k < NGRID * NGRID);
        int side = tx[k] < 60 ? 0 : tx[k] > 140 ? 1 : -1;
        if (side < 0)
            continue;
        sum[side] += (mp_table_get(&t, r, cf) - E) / mp_table_get(&t, r, ce);
        cnt[side]++;
    }
    double z0 = sum[0] / sqrt(cnt[0]), z1 = sum[1] / sqrt(cnt[1]);
    print_message("frame fit with the field: z = %.2f (left), %.2f (right)\n", z0, z1);
    assert_true(fabs(z0) < 4.0 && fabs(z1) < 4.0);
    mp_table_free(&t);
    mp_psf_free(&origin);
    mp_psf_field_free(&f);
    free(fr.im.pix);
    free(fr.mask);
}

/* The crop envelope of a variable PSF bounds every star's PRF: it is the
 * largest over the field's corners, so no lower than the origin's. */
static void test_envelope_covers_field(void **state)
{
    (void)state;
    mp_psf_field f;
    linear_truth(&f);
    char err[MP_ERRLEN];
    mp_psf origin;
    assert_int_equal(mp_psf_field_eval(&f, f.x0, f.y0, &origin, err), 0);
    mp_psf plain = origin;
    plain.field = NULL;
    origin.field = &f;
    mp_prf_model m1 = {&origin, NULL, 10}, m0 = {&plain, NULL, 10};
    int n1, n0;
    double *e1 = mp_prf_envelope(&m1, &n1), *e0 = mp_prf_envelope(&m0, &n0);
    assert_non_null(e1);
    assert_non_null(e0);
    assert_int_equal(n1, n0);
    int wider = 0;
    for (int r = 0; r < n0; r++) {
        assert_true(e1[r] >= e0[r]);
        wider += e1[r] > 1.01 * e0[r];
    }
    assert_true(wider > 0);      /* the wide corner's wings reach further */
    free(e1), free(e0);
    mp_psf_free(&origin);
    mp_psf_field_free(&f);
}

int main(void)
{
    const struct CMUnitTest tests[] = {
        cmocka_unit_test(test_eval_is_the_polynomial),
        cmocka_unit_test(test_rebin_commutes),
        cmocka_unit_test_setup_teardown(test_write_read_round_trip, setup, teardown),
        cmocka_unit_test_setup_teardown(test_bad_cubes, setup, teardown),
        cmocka_unit_test(test_linear_variation_fit),
        cmocka_unit_test(test_frame_fit_reads_field_at_star),
        cmocka_unit_test(test_envelope_covers_field),
    };
    return cmocka_run_group_tests(tests, NULL, NULL);
}
