/* test_psf_readers.c — other programs' PSF files (psf/psfex.c) and the
 * detector kernel (psf/kernel.c).  The real files are in
 * ../shared/data/real; those tests skip when it is absent. */
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

#define REAL "../shared/data/real/"
#define LEGACY REAL "decam_legacypipe_tc4/c4d_170316_062107_ooi_z_ls9-psfex.fits"
#define DES REAL "psfex_des/DECam_00154912_12_psfcat.psf"
#define TINYTIM REAL "hst_acs_hrc_47tuc/tinytim_acs_hrc_f606w_x512y512_sub4.fits"
#define WEBBPSF REAL "webbpsf_wfirst/webbpsf_wfirst_wfi_sca01_z087_psf.fits"
#define NIRCAM REAL "psf_format_mocks/nircam_nrca1_f200w_fovp101_samp4_npsf4_mock.fits"
#define STDPSF REAL "psf_format_mocks/STDPSF_WFC3UV_F814W_mock.fits"

static int have(const char *path)
{
    if (access(path, R_OK) == 0)
        return 1;
    print_message("skipped: %s is absent\n", path);
    return 0;
}

/* ---- An independent evaluation of a PSFEx model, from the format's
 * definition: PSF_MASK is a (PSFAXIS1, PSFAXIS2, PSFAXIS3) cube, x
 * fastest; the model at (x, y) is Σ_k mask_k · basis_k with the basis
 * 1, u, u², v, u·v, v² (degree 2), u = (x − POLZERO1)/POLSCAL1,
 * v = (y − POLZERO2)/POLSCAL2 (PSFEx manual eq. 14). ---- */

typedef struct {
    long n1, n2, n3;
    int deg;
    double z1, z2, s1, s2, samp;
    double *mask;
} raw_psfex;

/* A number from the header or, legacypipe's layout, the row's column. */
static double raw_num(fitsfile *fp, const char *key)
{
    int st = 0, cn;
    double v = NAN;
    fits_read_key(fp, TDOUBLE, key, &v, NULL, &st);
    if (!st)
        return v;
    st = 0;
    fits_get_colnum(fp, CASEINSEN, (char *)key, &cn, &st);
    fits_read_col(fp, TDOUBLE, cn, 1, 1, 1, NULL, &v, NULL, &st);
    assert_int_equal(st, 0);
    return v;
}

static void raw_read(const char *path, raw_psfex *r)
{
    fitsfile *fp;
    int st = 0, cn;
    fits_open_file(&fp, path, READONLY, &st);
    fits_movabs_hdu(fp, 2, NULL, &st);
    assert_int_equal(st, 0);
    r->n1 = (long)raw_num(fp, "PSFAXIS1");
    r->n2 = (long)raw_num(fp, "PSFAXIS2");
    r->n3 = (long)raw_num(fp, "PSFAXIS3");
    r->deg = (int)raw_num(fp, "POLDEG1");
    r->z1 = raw_num(fp, "POLZERO1");
    r->z2 = raw_num(fp, "POLZERO2");
    r->s1 = raw_num(fp, "POLSCAL1");
    r->s2 = raw_num(fp, "POLSCAL2");
    r->samp = raw_num(fp, "PSF_SAMP");
    long n = r->n1 * r->n2 * r->n3;
    r->mask = malloc((size_t)n * sizeof *r->mask);
    assert_non_null(r->mask);
    fits_get_colnum(fp, CASEINSEN, "PSF_MASK", &cn, &st);
    fits_read_col(fp, TDOUBLE, cn, 1, 1, n, NULL, r->mask, NULL, &st);
    fits_close_file(fp, &st);
    assert_int_equal(st, 0);
}

/* The model at (x, y) on PSFEx's own grid. */
static void raw_eval(const raw_psfex *r, double x, double y, double *out)
{
    double u = (x - r->z1) / r->s1, v = (y - r->z2) / r->s2, b[6];
    int k = 0;
    for (int j = 0; j <= r->deg; j++)
        for (int i = 0; i + j <= r->deg; i++)
            b[k++] = pow(u, i) * pow(v, j);
    assert_int_equal(k, r->n3);
    long plane = r->n1 * r->n2;
    for (long e = 0; e < plane; e++) {
        out[e] = 0.0;
        for (int t = 0; t < k; t++)
            out[e] += b[t] * r->mask[t * plane + e];
    }
}

static const double XS[4] = {1.0, 245.0, 120.3, 1024.0}, YS[4] = {1.0, 251.0, 130.7, 2048.0};

/* legacypipe's merged table, PSF_SAMP 1: the reader's table at every
 * position is the independent evaluation divided by its sum at the origin
 * (the reader normalises there), to rounding. */
static void test_psfex_legacypipe(void **state)
{
    (void)state;
    if (!have(LEGACY))
        skip();
    raw_psfex r;
    raw_read(LEGACY, &r);
    assert_true(r.samp == 1.0);
    char err[MP_ERRLEN], warn[MP_ERRLEN];
    mp_psf_field f;
    assert_int_equal(mp_psf_field_read(LEGACY, 0, 0, &f, NULL, NULL, warn, err), 0);
    assert_int_equal(f.order, 2);
    assert_int_equal(f.nx, r.n1);
    assert_int_equal(f.os, 1);
    long plane = r.n1 * r.n2;
    double *ind = malloc((size_t)plane * sizeof *ind), s0 = 0.0, peak = 0.0;
    assert_non_null(ind);
    raw_eval(&r, r.z1, r.z2, ind);
    for (long e = 0; e < plane; e++)
        s0 += ind[e], peak = fmax(peak, ind[e]);
    for (int c = 0; c < 4; c++) {
        raw_eval(&r, XS[c], YS[c], ind);
        mp_psf t;
        assert_int_equal(mp_psf_field_eval(&f, XS[c], YS[c], &t, err), 0);
        double dmax = 0.0;
        for (long e = 0; e < plane; e++)
            dmax = fmax(dmax, fabs(t.t[e] - ind[e] / s0));
        /* float32 data summed in another order: 1e-12 of the peak. */
        assert_true(dmax <= 1e-12 * peak / s0);
        mp_psf_free(&t);
    }
    free(ind);
    free(r.mask);
    mp_psf_field_free(&f);
}

/* Moments of a table: sum, centroid and second moment about it
 * [elements of step px]. */
static void moments(const double *t, int nx, int ny, double step, double m[4])
{
    double s = 0, sx = 0, sy = 0, sr = 0;
    for (int j = 0; j < ny; j++)
        for (int i = 0; i < nx; i++) {
            double v = t[j * nx + i], x = (i - nx / 2) * step, y = (j - ny / 2) * step;
            s += v, sx += v * x, sy += v * y, sr += v * (x * x + y * y);
        }
    m[0] = s, m[1] = sx / s, m[2] = sy / s, m[3] = sr / s - (sx * sx + sy * sy) / (s * s);
}

/* The DES .psf, PSF_SAMP 0.9756: resampled to whole pixels, so compared
 * through what resampling keeps: the flux ratio between positions (to the
 * light beyond the resampled table's edge, < 1e-3 here), the centroid (to
 * 0.01 px) and the second moment in detector px² (to 1 %: Lanczos-3 of a
 * FWHM-4.6 px PSF sampled at ~1 px). */
static void test_psfex_des(void **state)
{
    (void)state;
    if (!have(DES))
        skip();
    raw_psfex r;
    raw_read(DES, &r);
    char err[MP_ERRLEN], warn[MP_ERRLEN];
    mp_psf_field f;
    assert_int_equal(mp_psf_field_read(DES, 0, 0, &f, NULL, NULL, warn, err), 0);
    assert_non_null(strstr(warn, "PSF_SAMP 0.975561 resampled to OVERSAMP 1"));
    assert_int_equal(f.order, 2);
    assert_int_equal(f.os, 1);
    long plane = r.n1 * r.n2;
    double *ind = malloc((size_t)plane * sizeof *ind), m0[4], mi[4], mr[4], mr0[4];
    assert_non_null(ind);
    raw_eval(&r, r.z1, r.z2, ind);
    moments(ind, (int)r.n1, (int)r.n2, r.samp, m0);
    mp_psf t0;
    assert_int_equal(mp_psf_field_eval(&f, r.z1, r.z2, &t0, err), 0);
    moments(t0.t, t0.nx, t0.ny, 1.0, mr0);
    for (int c = 0; c < 4; c++) {
        raw_eval(&r, XS[c], YS[c], ind);
        moments(ind, (int)r.n1, (int)r.n2, r.samp, mi);
        mp_psf t;
        assert_int_equal(mp_psf_field_eval(&f, XS[c], YS[c], &t, err), 0);
        moments(t.t, t.nx, t.ny, 1.0, mr);
        assert_true(fabs(mr[0] / mr0[0] - mi[0] / m0[0]) < 1e-3);
        assert_true(fabs(mr[1] - mi[1]) < 0.01 && fabs(mr[2] - mi[2]) < 0.01);
        assert_true(fabs(mr[3] / mi[3] - 1.0) < 0.01);
        mp_psf_free(&t);
    }
    mp_psf_free(&t0);
    free(ind);
    free(r.mask);
    mp_psf_field_free(&f);
}

/* ---- Synthetic PSFEx files, written here, for the errors ---------------- */

static void write_psfex(const char *path, int deg, int nt, int rows, double samp)
{
    int st = 0, n = 7;
    fitsfile *fp;
    unlink(path);
    fits_create_file(&fp, path, &st);
    fits_create_img(fp, 8, 0, NULL, &st);
    char tform[16];
    snprintf(tform, sizeof tform, "%dE", n * n * nt);
    char *tt[] = {"PSF_MASK"}, *tf[] = {tform}, *tu[] = {""};
    fits_create_tbl(fp, BINARY_TBL, rows, 1, tt, tf, tu, "PSF_DATA", &st);
    int two = 2, one = 1;
    double z = 50.0, sc = 100.0;
    fits_write_key(fp, TINT, "POLNAXIS", &two, "", &st);
    fits_write_key(fp, TINT, "POLNGRP", &one, "", &st);
    fits_write_key(fp, TINT, "POLDEG1", &deg, "", &st);
    fits_write_key(fp, TDOUBLE, "POLZERO1", &z, "", &st);
    fits_write_key(fp, TDOUBLE, "POLZERO2", &z, "", &st);
    fits_write_key(fp, TDOUBLE, "POLSCAL1", &sc, "", &st);
    fits_write_key(fp, TDOUBLE, "POLSCAL2", &sc, "", &st);
    fits_write_key(fp, TDOUBLE, "PSF_SAMP", &samp, "", &st);
    fits_write_key(fp, TINT, "PSFAXIS1", &n, "", &st);
    fits_write_key(fp, TINT, "PSFAXIS2", &n, "", &st);
    fits_write_key(fp, TINT, "PSFAXIS3", &nt, "", &st);
    float *m = calloc((size_t)(n * n * nt), sizeof *m);
    assert_non_null(m);
    m[(n / 2) * n + n / 2] = 1.0f;
    m[n * n + (n / 2) * n + n / 2 + 1] = 0.25f;   /* dx plane: light moves right */
    for (int r = 1; r <= rows; r++)
        fits_write_col(fp, TFLOAT, 1, r, 1, n * n * nt, m, &st);
    fits_close_file(fp, &st);
    free(m);
    assert_int_equal(st, 0);
}

static void expect_error(const char *path, const char *want)
{
    char err[MP_ERRLEN] = "", warn[MP_ERRLEN];
    mp_psf_field f;
    assert_int_not_equal(mp_psf_field_read(path, 0, 0, &f, NULL, NULL, warn, err), 0);
    if (!strstr(err, want) || !strstr(err, path) || strchr(err, '\n'))
        fail_msg("error '%s' does not say '%s'", err, want);
}

static void test_psfex_synthetic(void **state)
{
    (void)state;
    char path[256], err[MP_ERRLEN], warn[MP_ERRLEN];
    const char *tmp = getenv("TMPDIR");
    snprintf(path, sizeof path, "%s/test_psf_readers_%ld.psf", tmp && *tmp ? tmp : "/tmp",
             (long)getpid());
    write_psfex(path, 1, 3, 1, 1.0);
    mp_psf_field f;
    assert_int_equal(mp_psf_field_read(path, 0, 0, &f, NULL, NULL, warn, err), 0);
    assert_int_equal(f.order, 1);
    /* At x = 150 (u = 1): centre 1, its right neighbour 0.25. */
    mp_psf t;
    assert_int_equal(mp_psf_field_eval(&f, 150.0, 50.0, &t, err), 0);
    assert_true(fabs(t.t[3 * 7 + 3] - 1.0) < 1e-15 && fabs(t.t[3 * 7 + 4] - 0.25) < 1e-15);
    mp_psf_free(&t);
    mp_psf_field_free(&f);
    /* Degree 3 (10 planes, PSFEx order as matphot's): read, evaluated. */
    write_psfex(path, 3, 10, 1, 1.0);
    assert_int_equal(mp_psf_field_read(path, 0, 0, &f, NULL, NULL, warn, err), 0);
    assert_int_equal(f.order, 3);
    assert_int_equal(mp_psf_field_eval(&f, 150.0, 50.0, &t, err), 0);
    assert_true(fabs(t.t[3 * 7 + 3] - 1.0) < 1e-15 && fabs(t.t[3 * 7 + 4] - 0.25) < 1e-15);
    mp_psf_free(&t);
    mp_psf_field_free(&f);
    write_psfex(path, 4, 15, 1, 1.0);
    expect_error(path, "degree 4");
    write_psfex(path, 2, 3, 1, 1.0);
    expect_error(path, "PSFAXIS3 3 does not match degree 2");
    write_psfex(path, 1, 3, 2, 1.0);
    expect_error(path, "2 rows; choose one with a row filter");
    write_psfex(path, 1, 3, 1, 0.0);
    expect_error(path, "PSF_SAMP 0");
    unlink(path);
}

/* ---- The detector kernel -------------------------------------------------- */

/* Tiny Tim's kernel, read from its COMMENT cards: the numbers in the file
 * (MANIFEST: 0.018701 0.064409 0.018701 / 0.064409 0.667562 0.064409 / …). */
static void test_kernel_tinytim_header(void **state)
{
    (void)state;
    if (!have(TINYTIM))
        skip();
    char err[MP_ERRLEN];
    mp_psf k;
    assert_int_equal(mp_psf_kernel_read("header", TINYTIM, &k, err), 0);
    assert_int_equal(k.nx, 3);
    assert_int_equal(k.ny, 3);
    const double want[9] = {0.018701, 0.064409, 0.018701, 0.064409, 0.667562,
                            0.064409, 0.018701, 0.064409, 0.018701};
    for (int i = 0; i < 9; i++)
        assert_true(k.t[i] == want[i]);
    assert_true(fabs(k.sum - 1.0) < 1e-5);
    mp_psf_free(&k);
    /* A header without one. */
    assert_int_not_equal(mp_psf_kernel_read("header", REAL "hst_acs_hrc_47tuc/"
                                            "tinytim_acs_hrc_f606w_x512y512_sub1.fits", &k, err), 0);
    assert_non_null(strstr(err, "no kernel in the header"));
}

/* psfkernel=auto (the default): the same kernel, from the same cards, when
 * the header carries it (a section of the sub4 file keeps its header, as
 * the pipeline's runs name it); none, and no error, for Tiny Tim's sub1
 * table (its kernel already applied: no cards), for a PSFEx file (no image
 * to hold a header) and for "none". */
static void test_kernel_auto(void **state)
{
    (void)state;
    char err[MP_ERRLEN], psfex[256];
    const char *tmp = getenv("TMPDIR");
    mp_psf k, h;
    snprintf(psfex, sizeof psfex, "%s/test_kernel_auto_%ld.psf", tmp && *tmp ? tmp : "/tmp",
             (long)getpid());
    write_psfex(psfex, 1, 3, 1, 1.0);
    assert_int_equal(mp_psf_kernel_read("auto", psfex, &k, err), 0);
    assert_null(k.t);
    assert_int_not_equal(mp_psf_kernel_read("header", psfex, &k, err), 0);
    unlink(psfex);
    if (!have(TINYTIM))
        skip();
    assert_int_equal(mp_psf_kernel_read("auto", TINYTIM "[132:452,132:452]", &k, err), 0);
    assert_int_equal(mp_psf_kernel_read("header", TINYTIM, &h, err), 0);
    assert_int_equal(k.nx, 3);
    assert_memory_equal(k.t, h.t, 9 * sizeof *k.t);
    mp_psf_free(&k);
    mp_psf_free(&h);
    assert_int_equal(mp_psf_kernel_read("auto", REAL "hst_acs_hrc_47tuc/"
                                        "tinytim_acs_hrc_f606w_x512y512_sub1.fits", &k, err), 0);
    assert_null(k.t);
    assert_int_equal(mp_psf_kernel_read("none", TINYTIM, &k, err), 0);
    assert_null(k.t);
}

/* Folding is exact (psf/kernel.c): the PRF of the folded table equals the
 * unfolded PRF convolved with the kernel on detector pixels, at any
 * subpixel position and with a non-uniform DRF, to rounding. */
static void test_kernel_fold_is_exact(void **state)
{
    (void)state;
    char err[MP_ERRLEN];
    mp_psf p, kf = {0};
    /* Radius 9 px: the table's edge holds e^-46 of its peak, so what the
     * sinc shift drops beyond the edge (folded or not) is below rounding. */
    assert_int_equal(mp_psf_gauss_table(2.2, 4, 9.0, &p, err), 0);
    mp_psf_field f;
    assert_int_equal(mp_psf_field_from_table(&p, &f, err), 0);
    double kv[9] = {0.01, 0.05, 0.02, 0.07, 0.7, 0.06, 0.015, 0.045, 0.03};
    mp_psf k = {.kind = MP_PSF_TABLE, .nx = 3, .ny = 3, .os = 1, .t = kv, .sum = 1.0};
    assert_int_equal(mp_psf_field_fold_kernel(&f, &k, err), 0);
    assert_int_equal(f.nx, p.nx + 8);
    assert_int_equal(mp_psf_field_eval(&f, 0, 0, &kf, err), 0);
    double qe[4] = {0.9, 0.7, 0.8, 1.0};
    mp_drf d = {.k = 2, .qe = qe, .volume = 0.85};
    mp_prf_model m = {&p, &d, 10}, mk = {&kf, &d, 10};
    mp_prf_work w = {0};
    const double xs[3] = {30.0, 30.37, 29.81}, ys[3] = {30.0, 29.62, 30.5};
    for (int c = 0; c < 3; c++) {
        long x0, y0, kx0, ky0;
        int bw, bh, kw, kh;
        mp_prf_box(&m, xs[c], ys[c], &x0, &y0, &bw, &bh);
        mp_prf_box(&mk, xs[c], ys[c], &kx0, &ky0, &kw, &kh);
        assert_true(kx0 == x0 - 1 && ky0 == y0 - 1 && kw == bw + 2 && kh == bh + 2);
        double *a = calloc((size_t)bw * bh, sizeof *a), *b = calloc((size_t)kw * kh, sizeof *b);
        assert_non_null(a);
        assert_non_null(b);
        assert_int_equal(mp_prf_render(&m, xs[c], ys[c], a, NULL, NULL, &w), 0);
        assert_int_equal(mp_prf_render(&mk, xs[c], ys[c], b, NULL, NULL, &w), 0);
        double dmax = 0.0, peak = 0.0;
        for (int j = 0; j < kh; j++)
            for (int i = 0; i < kw; i++) {
                /* (a ∗ K) at pixel (i, j) of b's box: a's pixel (i−1−p+1…). */
                double v = 0.0;
                for (int q = -1; q <= 1; q++)
                    for (int pp = -1; pp <= 1; pp++) {
                        int ai = i - 1 - pp, aj = j - 1 - q;
                        if (ai >= 0 && ai < bw && aj >= 0 && aj < bh)
                            v += kv[(q + 1) * 3 + pp + 1] * a[aj * bw + ai];
                    }
                dmax = fmax(dmax, fabs(v - b[j * kw + i]));
                peak = fmax(peak, v);
            }
        print_message("phase %d: largest difference %.3g of the peak\n", c, dmax / peak);
        assert_true(dmax < 1e-13 * peak);
        free(a);
        free(b);
    }
    mp_prf_work_free(&w);
    mp_psf_free(&p);
    mp_psf_free(&kf);
    mp_psf_field_free(&f);
}

/* ---- WebbPSF and gridded PSFs ------------------------------------------------ */

/* The WebbPSF file's OVERSAMP HDU (180² at ×4, even: padded, offset
 * 0.125 px) rendered for a star at a pixel centre is its DET_SAMP HDU
 * (WebbPSF block-sums OVERSAMP into it): the central element then sits
 * on the fine grid, no sinc shift is made, and the two agree to rounding. */
static void test_webbpsf(void **state)
{
    (void)state;
    if (!have(WEBBPSF))
        skip();
    char err[MP_ERRLEN], warn[MP_ERRLEN];
    mp_psf_field f;
    assert_int_equal(mp_psf_field_read(WEBBPSF, 0, 0, &f, NULL, NULL, warn, err), 0);
    assert_int_equal(f.os, 4);
    assert_int_equal(f.nx, 181);
    assert_true(f.offset == 0.125);
    assert_non_null(strstr(warn, "padded to 181x181"));
    mp_psf t, det;
    assert_int_equal(mp_psf_field_eval(&f, 0, 0, &t, err), 0);
    assert_int_equal(mp_psf_read(WEBBPSF "[DET_SAMP]", 0, 0, &det, NULL, err), 0);
    assert_int_equal(det.nx, 45);
    mp_prf_model m = {&t, NULL, 10};
    long x0, y0;
    int w, h;
    const double X = 50.0, Y = 60.0;
    mp_prf_box(&m, X, Y, &x0, &y0, &w, &h);
    double *prf = calloc((size_t)w * h, sizeof *prf);
    mp_prf_work wk = {0};
    assert_non_null(prf);
    assert_int_equal(mp_prf_render(&m, X, Y, prf, NULL, NULL, &wk), 0);
    assert_int_equal(wk.nskip, 2);      /* both axes on the grid: no shift */
    double dmax = 0.0, peak = 0.0;
    for (int j = 0; j < 45; j++)
        for (int i = 0; i < 45; i++) {
            long px = (long)X - 22 + i, py = (long)Y - 22 + j;
            double v = det.t[j * 45 + i], r = 0.0;
            if (px >= x0 && px < x0 + w && py >= y0 && py < y0 + h)
                r = prf[(py - y0) * w + (px - x0)];
            dmax = fmax(dmax, fabs(r - v));
            peak = fmax(peak, v);
        }
    print_message("WebbPSF: rendered vs DET_SAMP: largest difference %.3g of the peak\n",
                  dmax / peak);
    assert_true(dmax < 1e-12 * peak);
    free(prf);
    mp_prf_work_free(&wk);
    mp_psf_free(&t);
    mp_psf_free(&det);
    mp_psf_field_free(&f);
}

/* A raw table of a cube, by an independent read. */
static double *raw_plane(const char *path, int k, long *nx, long *ny)
{
    fitsfile *fp;
    int st = 0, naxis;
    long ax[3];
    fits_open_file(&fp, path, READONLY, &st);
    fits_get_img_dim(fp, &naxis, &st);
    fits_get_img_size(fp, 3, ax, &st);
    double *v = malloc((size_t)(ax[0] * ax[1]) * sizeof *v);
    assert_non_null(v);
    long f1[3] = {1, 1, k + 1};
    fits_read_pix(fp, TDOUBLE, f1, ax[0] * ax[1], NULL, v, NULL, &st);
    fits_close_file(fp, &st);
    assert_int_equal(st, 0);
    *nx = ax[0], *ny = ax[1];
    return v;
}

/* WebbPSF's GriddedPSFModel mock (header real, pixels fake): the grid
 * from DET_YXn ('(y, x)', 0-based), each table at its own grid point, the
 * mean of all four at the middle. */
static void test_grid_webbpsf_mock(void **state)
{
    (void)state;
    if (!have(NIRCAM))
        skip();
    char err[MP_ERRLEN], warn[MP_ERRLEN];
    mp_psf_field f;
    assert_int_equal(mp_psf_field_read(NIRCAM, 1, 0, &f, NULL, NULL, warn, err), 0);
    assert_int_equal(f.order, MP_PSF_GRID);
    assert_int_equal(f.ngx, 2);
    assert_int_equal(f.ngy, 2);
    assert_true(f.gx[0] == 1.0 && f.gx[1] == 2048.0 && f.gy[0] == 1.0 && f.gy[1] == 2048.0);
    assert_int_equal(f.os, 4);
    long nx, ny;
    double *p0 = raw_plane(NIRCAM, 0, &nx, &ny), s0 = 0.0;
    for (long i = 0; i < nx * ny; i++)
        s0 += p0[i];
    /* DET_YX1 = (2047, 0): x = 1, y = 2048 (1-based). */
    const double gxs[4] = {1, 1, 2048, 2048}, gys[4] = {1, 2048, 1, 2048};
    double *mid = calloc((size_t)(nx * ny), sizeof *mid);
    assert_non_null(mid);
    for (int k = 0; k < 4; k++) {
        long a, b;
        double *pk = raw_plane(NIRCAM, k, &a, &b);
        mp_psf t;
        assert_int_equal(mp_psf_field_eval(&f, gxs[k], gys[k], &t, err), 0);
        for (long i = 0; i < nx * ny; i++) {
            assert_true(fabs(t.t[i] - pk[i] / s0) < 1e-15);
            mid[i] += 0.25 * pk[i] / s0;
        }
        mp_psf_free(&t);
        free(pk);
    }
    mp_psf t;
    assert_int_equal(mp_psf_field_eval(&f, 1024.5, 1024.5, &t, err), 0);
    for (long i = 0; i < nx * ny; i++)
        assert_true(fabs(t.t[i] - mid[i]) < 1e-15);
    mp_psf_free(&t);
    /* Outside the grid: the edge's table, not an extrapolation. */
    assert_int_equal(mp_psf_field_eval(&f, -500.0, 1.0, &t, err), 0);
    for (long i = 0; i < nx * ny; i++)
        assert_true(fabs(t.t[i] - p0[i] / s0) < 1e-15);
    mp_psf_free(&t);
    free(mid);
    free(p0);
    mp_psf_field_free(&f);
}

/* Anderson's STDPSF mock (header real, pixels fake): 7×8 grid from
 * NXPSFS/IPSFXnn, table k = j·NXPSFS + i; the ePSF's whole-pixel samples
 * (here its central one, the mock is 5×5 at ×4). */
static void test_grid_stdpsf_mock(void **state)
{
    (void)state;
    if (!have(STDPSF))
        skip();
    char err[MP_ERRLEN], warn[MP_ERRLEN];
    mp_psf_field f;
    assert_int_equal(mp_psf_field_read(STDPSF, 0, 0, &f, NULL, NULL, warn, err), 0);
    assert_int_equal(f.order, MP_PSF_GRID);
    assert_int_equal(f.ngx, 7);
    assert_int_equal(f.ngy, 8);
    assert_int_equal(f.os, 1);
    assert_int_equal(f.nx, 1);
    assert_non_null(strstr(warn, "sampled at whole pixels"));
    for (int k = 0; k < 56; k += 13) {
        long nx, ny;
        double *pk = raw_plane(STDPSF, k, &nx, &ny);
        mp_psf t;
        assert_int_equal(mp_psf_field_eval(&f, f.gx[k % 7], f.gy[k / 7], &t, err), 0);
        assert_true(fabs(t.t[0] - pk[(ny / 2) * nx + nx / 2]) < 1e-15);
        mp_psf_free(&t);
        free(pk);
    }
    mp_psf_field_free(&f);
}

/* An image with DAOPHOT's PSF keywords (FUNCTION, PSFHEIGH, PSFRAD 3)
 * of side n, Gaussian values scaled as a star of 10⁵ counts. */
static void write_daophot(const char *path, long n)
{
    fitsfile *fp;
    int st = 0;
    long ax[2] = {n, n};
    double *v = malloc((size_t)(n * n) * sizeof *v), rad = 3.0, h = 2e4;
    assert_non_null(v);
    for (long j = 0; j < n; j++)
        for (long i = 0; i < n; i++)
            v[j * n + i] = h * exp(-0.5 * ((i - n / 2) * (i - n / 2) + (j - n / 2) * (j - n / 2)) /
                                   1.6);
    unlink(path);
    fits_create_file(&fp, path, &st);
    fits_create_img(fp, DOUBLE_IMG, 2, ax, &st);
    fits_write_key_str(fp, "FUNCTION", "gauss", "", &st);
    fits_write_key_dbl(fp, "PSFHEIGH", h, -8, "", &st);
    fits_write_key_dbl(fp, "PSFRAD", rad, -8, "", &st);
    fits_write_img(fp, TDOUBLE, 1, (LONGLONG)(n * n), v, &st);
    fits_close_file(fp, &st);
    assert_int_equal(st, 0);
    free(v);
}

/* IRAF DAOPHOT's PSF file (its look-up table, 2 (2 PSFRAD + 1) + 1 a
 * side) is refused naming seepsf; what seepsf renders of it (2 PSFRAD + 1
 * a side, counts of a PSFMAG star) is an ×1 table summing to 1.  Read
 * as a plain table, the first was taken for a PSF with psfnorm=yes. */
static void test_daophot_psf(void **state)
{
    (void)state;
    char path[] = "/tmp/test_psf_readers_daophot.fits", err[MP_ERRLEN], warn[MP_ERRLEN];
    mp_psf_field f;
    write_daophot(path, 15);
    expect_error(path, "an IRAF DAOPHOT PSF");
    assert_int_not_equal(mp_psf_field_read(path, 1, 0, &f, NULL, NULL, warn, err), 0);
    write_daophot(path, 7);
    assert_int_equal(mp_psf_field_read(path, 0, 0, &f, NULL, NULL, warn, err), 0);
    assert_int_equal(f.os, 1);
    assert_int_equal(f.nx, 7);
    double s = 0;
    for (int i = 0; i < 49; i++)
        s += f.planes[i];
    assert_true(fabs(s - 1.0) < 1e-12);
    mp_psf_field_free(&f);
    unlink(path);
}

int main(void)
{
    const struct CMUnitTest tests[] = {
        cmocka_unit_test(test_daophot_psf),
        cmocka_unit_test(test_psfex_legacypipe),
        cmocka_unit_test(test_psfex_des),
        cmocka_unit_test(test_psfex_synthetic),
        cmocka_unit_test(test_kernel_tinytim_header),
        cmocka_unit_test(test_kernel_auto),
        cmocka_unit_test(test_kernel_fold_is_exact),
        cmocka_unit_test(test_webbpsf),
        cmocka_unit_test(test_grid_webbpsf_mock),
        cmocka_unit_test(test_grid_stdpsf_mock),
    };
    return cmocka_run_group_tests(tests, NULL, NULL);
}
