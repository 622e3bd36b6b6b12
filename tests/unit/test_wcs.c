/*
 * test_wcs.c — catalog/wcs.c: sky positions through WCSLIB.
 *
 *   - the FITS WCS registry reference points (TAN-SIP, TPV, TNX) from
 *     ../shared/data/real/wcs_registry_samples/wcs_reference_points.csv:
 *     pixel -> sky within 1 mas, sky -> pixel round trip within 1e-6 px;
 *     and the other real frames' WCS (Galactic CAR with CRPIX2 < 0, DECam
 *     TPV in an extension, HRC TAN-SIP with an alternate WCS, ISAAC TAN).
 *     The real data are found at $MP_REAL_DATA, else ../shared/data/real
 *     (the tests run from the repository top); skipped when absent.
 *   - synthetic headers built in memory with exact answers: TAN (gnomonic
 *     formula), TAN-SIP (the SIP polynomial by hand), a cube header, a
 *     Galactic header; headers without (celestial) WCS give clean errors;
 *   - the same results from many OpenMP threads at once;
 *   - mp_table_add_sky: the columns, their unit, NaN handling, errors.
 */
#include <stdarg.h>
#include <stddef.h>
#include <stdint.h>
#include <setjmp.h>
#include <cmocka.h>

#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "catalog/catalog.h"
#include "io/io.h"

#define D2R_ (3.14159265358979323846 / 180.0)
#define MAS_PER_DEG 3.6e6

/* ---- helpers ------------------------------------------------------------ */

/* Where the real data live: $MP_REAL_DATA, else ../shared/data/real. */
static const char *real_dir(void)
{
    const char *d = getenv("MP_REAL_DATA");
    return d && *d ? d : "../shared/data/real";
}

/* Open dir/rel; NULL (and no failure) when absent. */
static FILE *open_real(const char *rel)
{
    char p[1024];
    snprintf(p, sizeof p, "%s/%s", real_dir(), rel);
    return fopen(p, "r");
}

static int have_real(const char *rel)
{
    FILE *fp = open_real(rel);
    if (!fp)
        return 0;
    fclose(fp);
    return 1;
}

static void read_real(const char *rel, mp_image *im)
{
    char p[1024], err[MP_ERRLEN];
    snprintf(p, sizeof p, "%s/%s", real_dir(), rel);
    memset(im, 0, sizeof *im);
    if (mp_image_read(p, im, err) != 0)
        fail_msg("%s", err);
}

/* An in-memory "image" whose header is the given cards (each padded to 80
 * characters); the pixels are not needed by the WCS code. */
static void header_image(mp_image *im, long nx, long ny, const char *const *cards, int n)
{
    memset(im, 0, sizeof *im);
    im->nx = nx;
    im->ny = ny;
    im->hdr = malloc((size_t)n * 80 + 1);
    assert_non_null(im->hdr);
    for (int i = 0; i < n; i++) {
        assert_true(strlen(cards[i]) <= 80);
        snprintf(im->hdr + (size_t)i * 80, 81, "%-80s", cards[i]);
    }
    im->hdr[(size_t)n * 80] = '\0';
    im->nkeys = n;
}

/* Angular distance in mas between two positions (degrees). */
static double sep_mas(double ra1, double dec1, double ra2, double dec2)
{
    double da = remainder(ra1 - ra2, 360.0) * cos(0.5 * (dec1 + dec2) * D2R_);
    double dd = dec1 - dec2;
    return hypot(da, dd) * MAS_PER_DEG;
}

static mp_wcs *open_ok(const mp_image *im)
{
    mp_wcs *w = NULL;
    char err[MP_ERRLEN] = "";
    if (mp_wcs_open(im, &w, err) != 0)
        fail_msg("mp_wcs_open: %s", err);
    assert_non_null(w);
    return w;
}

static void p2s(const mp_wcs *w, double x, double y, double *a, double *d)
{
    char err[MP_ERRLEN];
    if (mp_wcs_pix2sky(w, x, y, a, d, err) != 0)
        fail_msg("pix2sky(%g, %g): %s", x, y, err);
}

static void s2p(const mp_wcs *w, double a, double d, double *x, double *y)
{
    char err[MP_ERRLEN];
    if (mp_wcs_sky2pix(w, a, d, x, y, err) != 0)
        fail_msg("sky2pix(%.9f, %.9f): %s", a, d, err);
}

/* Largest pixel -> sky -> pixel error over a grid covering the image. */
static double grid_round_trip(const mp_wcs *w, long nx, long ny)
{
    double worst = 0;
    for (double y = 0.5; y <= ny + 0.5; y += ny / 9.0)
        for (double x = 0.5; x <= nx + 0.5; x += nx / 9.0) {
            double a, d, x2, y2;
            p2s(w, x, y, &a, &d);
            s2p(w, a, d, &x2, &y2);
            double e = hypot(x2 - x, y2 - y);
            if (e > worst)
                worst = e;
        }
    return worst;
}

/* ---- the registry reference points ------------------------------------- */

static void test_reference_points(void **state)
{
    (void)state;
    const char *csv = "wcs_registry_samples/wcs_reference_points.csv";
    FILE *fp = open_real(csv);
    if (!fp) {
        print_message("real data not found under %s (set MP_REAL_DATA)\n", real_dir());
        skip();
    }
    char line[1024], cur[256] = "";
    mp_image im = {0};
    mp_wcs *w = NULL;
    double max_mas = 0, max_rt = 0, max_ref = 0;
    int nrow = 0, nfile = 0;
    char done[4][32] = {"", "", "", ""};   /* the ctypes seen */

    for (;;) {
        int eof = !fgets(line, sizeof line, fp);
        char file[256] = "", ctype[32] = "";
        double ra = 0, dec = 0, x = 0, y = 0, pixval = 0;
        if (!eof) {
            if (line[0] == '#' || strncmp(line, "file,", 5) == 0 || line[0] == '\n')
                continue;
            /* file,ctype1,ra_hms,dec_dms,ra_deg,dec_deg,x_fits,y_fits,pixel_value */
            char *f[9];
            int nf = 0;
            for (char *tok = strtok(line, ",\n"); tok && nf < 9; tok = strtok(NULL, ",\n"))
                f[nf++] = tok;
            assert_int_equal(nf, 9);
            snprintf(file, sizeof file, "%s", f[0]);
            snprintf(ctype, sizeof ctype, "%s", f[1]);
            ra = atof(f[4]);
            dec = atof(f[5]);
            x = atof(f[6]);
            y = atof(f[7]);
            pixval = atof(f[8]);
        }
        if (eof || strcmp(file, cur) != 0) {
            if (w) {
                max_rt = grid_round_trip(w, im.nx, im.ny);
                print_message("%-40s max |pix->sky - ref| = %.4f mas, "
                              "sky(ref)->pix off by %.2e px, grid round trip %.2e px\n",
                              cur, max_mas, max_ref, max_rt);
                assert_true(max_mas < 1.0);
                assert_true(max_rt < 1e-6);
                mp_wcs_close(w);
                mp_image_free(&im);
                w = NULL;
            }
            if (eof)
                break;
            snprintf(cur, sizeof cur, "%s", file);
            read_real(file, &im);
            w = open_ok(&im);
            max_mas = max_ref = 0;
            if (nfile < 4)
                snprintf(done[nfile], sizeof done[nfile], "%s", ctype);
            nfile++;
        }
        /* The convention check the manifest describes. */
        double v = im.pix[(size_t)(y - 1) * (size_t)im.nx + (size_t)(x - 1)];
        assert_true(fabs(v - pixval) <= 1e-4 * fabs(pixval) + 1e-4);

        double a, d, x2, y2;
        p2s(w, x, y, &a, &d);
        double e = sep_mas(a, d, ra, dec);
        if (e > max_mas)
            max_mas = e;
        s2p(w, a, d, &x2, &y2);                  /* exact round trip */
        assert_true(hypot(x2 - x, y2 - y) < 1e-6);
        s2p(w, ra, dec, &x2, &y2);               /* the reference itself */
        e = hypot(x2 - x, y2 - y);
        if (e > max_ref)
            max_ref = e;
        assert_true(e < 0.01);
        nrow++;
    }
    fclose(fp);
    assert_int_equal(nrow, 6);
    assert_int_equal(nfile, 3);
    int sip = 0, tpv = 0, tnx = 0;
    for (int i = 0; i < 3; i++) {
        sip |= strcmp(done[i], "RA---TAN-SIP") == 0;
        tpv |= strcmp(done[i], "RA---TPV") == 0;
        tnx |= strcmp(done[i], "RA---TNX") == 0;
    }
    assert_true(sip && tpv && tnx);
}

/* ---- the other real frames ---------------------------------------------- */

/* rows of a CSV with (lng, lat) in columns ilng, ilat and x_fits, y_fits in
 * columns ix, iy: sky -> pixel within tol px (the CSV's x, y are astropy's,
 * printed to 1e-3 px), and back. */
static double check_csv(const mp_wcs *w, const char *rel, int ilng, int ilat, int ix, int iy)
{
    FILE *fp = open_real(rel);
    assert_non_null(fp);
    char line[2048];
    double worst = 0;
    int n = 0;
    while (fgets(line, sizeof line, fp)) {
        if (line[0] == '#' || !(line[0] == '-' || line[0] == '.' || (line[0] >= '0' && line[0] <= '9')
                                || strncmp(line, "gaia", 4) == 0))
            continue;
        char *f[32];
        int nf = 0;
        for (char *tok = strtok(line, ",\n"); tok && nf < 32; tok = strtok(NULL, ",\n"))
            f[nf++] = tok;
        assert_true(nf > ilng && nf > ilat && nf > ix && nf > iy);
        double lng = atof(f[ilng]), lat = atof(f[ilat]), x = atof(f[ix]), y = atof(f[iy]);
        double x2, y2, a, d;
        s2p(w, lng, lat, &x2, &y2);
        double e = hypot(x2 - x, y2 - y);
        if (e > worst)
            worst = e;
        p2s(w, x2, y2, &a, &d);
        assert_true(sep_mas(a, d, lng, lat) < 1e-3);
        n++;
    }
    fclose(fp);
    assert_true(n > 0);
    return worst;
}

static void test_real_frames(void **state)
{
    (void)state;
    const char *glimpse = "spitzer_irac_glimpse/spitzer_example_image.fits";
    const char *decam = "decam_legacypipe_tc4/c4d_170316_062107_ooi_z_ls9.N2.fits";
    const char *hrc = "hst_acs_hrc_47tuc/j8bt06nyq_flt_sip_crop512.fits";
    const char *isaac = "vlt_isaac_raw/ISAAC.2006-04-13T06_32_38.944_crop512.fits";
    if (!have_real(glimpse) || !have_real(decam) || !have_real(hrc) || !have_real(isaac))
        skip();
    mp_image im;
    mp_wcs *w;
    char name[512];

    /* Galactic CAR, reference pixel outside the image (CRPIX2 = -388.5). */
    read_real(glimpse, &im);
    w = open_ok(&im);
    assert_string_equal(mp_wcs_frame(w), "galactic");
    double e = check_csv(w, "spitzer_irac_glimpse/glimpse_catalog_subset.csv", 0, 1, 8, 9);
    print_message("GLIMPSE GLON-CAR: max |sky2pix - astropy| = %.2e px (CSV has 1e-3 px)\n", e);
    assert_true(e < 1e-3);
    assert_true(grid_round_trip(w, im.nx, im.ny) < 1e-6);
    mp_wcs_close(w);
    mp_image_free(&im);

    /* DECam TPV in extension 1. */
    snprintf(name, sizeof name, "%s[1]", decam);
    read_real(name, &im);
    w = open_ok(&im);
    e = check_csv(w, "decam_legacypipe_tc4/gaia_dr2_in_frame.csv", 2, 3, 8, 9);
    print_message("DECam TPV: max |sky2pix - astropy| = %.2e px\n", e);
    assert_true(e < 1e-3);
    assert_true(grid_round_trip(w, im.nx, im.ny) < 1e-6);
    mp_wcs_close(w);
    mp_image_free(&im);

    /* HRC TAN-SIP with an alternate WCS 'O': the primary one is used, so
     * CRPIX maps to CRVAL (SIP vanishes there), not CRPIX1O to CRVAL1O. */
    snprintf(name, sizeof name, "%s[SCI]", hrc);
    const char *tan_files[2] = { name, isaac };
    for (int k = 0; k < 2; k++) {
        read_real(tan_files[k], &im);
        w = open_ok(&im);
        double c1, c2, v1, v2, a, d;
        assert_int_equal(mp_header_double(&im, "CRPIX1", &c1), 0);
        assert_int_equal(mp_header_double(&im, "CRPIX2", &c2), 0);
        assert_int_equal(mp_header_double(&im, "CRVAL1", &v1), 0);
        assert_int_equal(mp_header_double(&im, "CRVAL2", &v2), 0);
        p2s(w, c1, c2, &a, &d);
        assert_true(sep_mas(a, d, v1, v2) < 1e-3);
        assert_true(grid_round_trip(w, im.nx, im.ny) < 1e-6);
        mp_wcs_close(w);
        mp_image_free(&im);
    }
}

/* ---- synthetic headers -------------------------------------------------- */

/* The gnomonic projection by hand: intermediate world coordinates (xi, eta)
 * in degrees -> (ra, dec) for tangent point (a0, d0). */
static void gnomonic(double a0, double d0, double xi, double eta, double *ra, double *dec)
{
    double x = xi * D2R_, y = eta * D2R_, c = cos(d0 * D2R_), s = sin(d0 * D2R_);
    double den = c - y * s;
    *ra = a0 + atan2(x, den) / D2R_;
    *ra = fmod(*ra + 360.0, 360.0);
    *dec = atan2(y * c + s, hypot(x, den)) / D2R_;
}

static const char *const tan_cards[] = {
    "SIMPLE  =                    T",
    "BITPIX  =                  -32",
    "NAXIS   =                    2",
    "NAXIS1  =                  200",
    "NAXIS2  =                  300",
    "CTYPE1  = 'RA---TAN'",
    "CTYPE2  = 'DEC--TAN'",
    "CRPIX1  =                100.5",
    "CRPIX2  =                150.5",
    "CRVAL1  =          359.9900000",
    "CRVAL2  =          -45.0000000",
    "CD1_1   =         -2.500000E-4",
    "CD1_2   =          4.330127E-4",
    "CD2_1   =          4.330127E-4",
    "CD2_2   =          2.500000E-4",
    "RADESYS = 'FK5     '",
    "EQUINOX =               2000.0",
    "END",
};

static void test_synthetic_tan(void **state)
{
    (void)state;
    mp_image im;
    header_image(&im, 200, 300, tan_cards, (int)(sizeof tan_cards / sizeof *tan_cards));
    mp_wcs *w = open_ok(&im);
    assert_string_equal(mp_wcs_frame(w), "fk5");
    assert_true(mp_wcs_equinox(w) == 2000.0);

    const double cd[4] = { -2.5e-4, 4.330127e-4, 4.330127e-4, 2.5e-4 };
    double worst = 0;
    for (double y = -50; y <= 350; y += 23.7)
        for (double x = -50; x <= 250; x += 17.3) {
            double dx = x - 100.5, dy = y - 150.5, ra, dec, a, d, x2, y2;
            gnomonic(359.99, -45.0, cd[0] * dx + cd[1] * dy, cd[2] * dx + cd[3] * dy, &ra, &dec);
            p2s(w, x, y, &a, &d);
            assert_true(a >= 0.0 && a < 360.0);
            double e = sep_mas(a, d, ra, dec);
            if (e > worst)
                worst = e;
            s2p(w, a, d, &x2, &y2);
            assert_true(hypot(x2 - x, y2 - y) < 1e-9);
        }
    print_message("synthetic TAN: max error %.2e mas\n", worst);
    assert_true(worst < 1e-6);

    /* The reference pixel is the reference value exactly. */
    double a, d;
    p2s(w, 100.5, 150.5, &a, &d);
    assert_true(fabs(a - 359.99) < 1e-12 && fabs(d + 45.0) < 1e-12);

    /* NaN in, and a sky position on the far side of the sphere. */
    char err[MP_ERRLEN] = "";
    assert_int_equal(mp_wcs_pix2sky(w, NAN, 3.0, &a, &d, err), MP_WCS_BADCOORD);
    assert_true(isnan(a) && isnan(d));
    assert_non_null(strstr(err, "not a finite number"));
    double x, y;
    assert_int_equal(mp_wcs_sky2pix(w, 179.99, 45.0, &x, &y, err), MP_WCS_BADCOORD);
    assert_true(isnan(x) && isnan(y));
    assert_non_null(strstr(err, "no valid pixel position"));
    assert_int_equal(mp_wcs_sky2pix(w, 10.0, 91.0, &x, &y, err), MP_WCS_BADCOORD);

    /* J2000: FK5 J2000 is taken as it is. */
    double a2, d2;
    assert_int_equal(mp_wcs_pix2j2000(w, 12.0, 34.0, &a2, &d2, err), 0);
    p2s(w, 12.0, 34.0, &a, &d);
    assert_true(a2 == a && d2 == d);

    mp_wcs_close(w);
    mp_image_free(&im);
}

/* TAN-SIP by hand: u, v offsets from CRPIX, u' = u + sum A_pq u^p v^q. */
static const char *const sip_cards[] = {
    "SIMPLE  =                    T",
    "NAXIS   =                    2",
    "NAXIS1  =                  256",
    "NAXIS2  =                  256",
    "CTYPE1  = 'RA---TAN-SIP'",
    "CTYPE2  = 'DEC--TAN-SIP'",
    "CRPIX1  =                128.0",
    "CRPIX2  =                120.0",
    "CRVAL1  =          202.4823228",
    "CRVAL2  =           47.1751189",
    "CD1_1   =      0.0002497568803",
    "CD1_2   =      0.0002301778097",
    "CD2_1   =      0.0002304285193",
    "CD2_2   =     -0.0002499657706",
    "RADESYS = 'ICRS'",
    "A_ORDER =                    3",
    "A_0_2   =            2.0E-5",
    "A_1_1   =           -1.5E-5",
    "A_2_0   =            3.0E-5",
    "A_3_0   =            1.0E-7",
    "A_0_3   =           -2.0E-7",
    "B_ORDER =                    3",
    "B_0_2   =           -1.0E-5",
    "B_1_1   =            2.5E-5",
    "B_2_0   =            1.2E-5",
    "B_1_2   =            3.0E-7",
    "B_2_1   =           -1.0E-7",
    "END",
};

static void sip_by_hand(double x, double y, double *ra, double *dec)
{
    double u = x - 128.0, v = y - 120.0;
    double up = u + 2.0e-5 * v * v - 1.5e-5 * u * v + 3.0e-5 * u * u + 1.0e-7 * u * u * u
                - 2.0e-7 * v * v * v;
    double vp = v - 1.0e-5 * v * v + 2.5e-5 * u * v + 1.2e-5 * u * u + 3.0e-7 * u * v * v
                - 1.0e-7 * u * u * v;
    gnomonic(202.4823228, 47.1751189,
             0.0002497568803 * up + 0.0002301778097 * vp,
             0.0002304285193 * up - 0.0002499657706 * vp, ra, dec);
}

static void test_synthetic_sip(void **state)
{
    (void)state;
    mp_image im;
    header_image(&im, 256, 256, sip_cards, (int)(sizeof sip_cards / sizeof *sip_cards));
    mp_wcs *w = open_ok(&im);
    assert_string_equal(mp_wcs_frame(w), "icrs");
    assert_true(isnan(mp_wcs_equinox(w)));
    double worst = 0, worst_rt = 0;
    for (double y = 1; y <= 256; y += 15.1)
        for (double x = 1; x <= 256; x += 13.7) {
            double ra, dec, a, d, x2, y2;
            sip_by_hand(x, y, &ra, &dec);
            p2s(w, x, y, &a, &d);
            double e = sep_mas(a, d, ra, dec);
            if (e > worst)
                worst = e;
            s2p(w, a, d, &x2, &y2);   /* no AP/BP: WCSLIB iterates from scratch */
            e = hypot(x2 - x, y2 - y);
            if (e > worst_rt)
                worst_rt = e;
        }
    print_message("synthetic TAN-SIP: max error %.2e mas, round trip %.2e px\n", worst, worst_rt);
    assert_true(worst < 1e-6);
    assert_true(worst_rt < 1e-6);
    mp_wcs_close(w);
    mp_image_free(&im);
}

/* A cube header: the celestial axes are axes 1 and 2, a velocity axis 3. */
static void test_cube_header(void **state)
{
    (void)state;
    static const char *const cards[] = {
        "SIMPLE  =                    T",
        "NAXIS   =                    3",
        "NAXIS1  =                   64",
        "NAXIS2  =                   64",
        "NAXIS3  =                   10",
        "CTYPE1  = 'RA---SIN'",
        "CTYPE2  = 'DEC--SIN'",
        "CTYPE3  = 'VRAD'",
        "CUNIT3  = 'm/s'",
        "CRPIX1  =                 32.0",
        "CRPIX2  =                 33.0",
        "CRPIX3  =                  1.0",
        "CRVAL1  =                 83.8",
        "CRVAL2  =                 -5.4",
        "CRVAL3  =               1000.0",
        "CDELT1  =              -0.0010",
        "CDELT2  =               0.0010",
        "CDELT3  =               500.0",
        "END",
    };
    mp_image im;
    header_image(&im, 64, 64, cards, (int)(sizeof cards / sizeof *cards));
    mp_wcs *w = open_ok(&im);
    double a, d;
    p2s(w, 32.0, 33.0, &a, &d);
    assert_true(fabs(a - 83.8) < 1e-12 && fabs(d + 5.4) < 1e-12);
    assert_true(grid_round_trip(w, 64, 64) < 1e-9);
    mp_wcs_close(w);
    mp_image_free(&im);

    /* Celestial axes on axes 2 and 3: not the image's two axes. */
    static const char *const bad[] = {
        "NAXIS   =                    3",
        "CTYPE1  = 'FREQ'",
        "CTYPE2  = 'RA---TAN'",
        "CTYPE3  = 'DEC--TAN'",
        "CRVAL1  =             1.42E9",
        "CRVAL2  =                 10.0",
        "CRVAL3  =                 20.0",
        "CDELT1  =                1.0E3",
        "CDELT2  =              -0.0010",
        "CDELT3  =               0.0010",
        "END",
    };
    header_image(&im, 64, 64, bad, (int)(sizeof bad / sizeof *bad));
    char err[MP_ERRLEN] = "";
    static int dummy;
    w = (mp_wcs *)(void *)&dummy;   /* must be reset to NULL */
    assert_int_not_equal(mp_wcs_open(&im, &w, err), 0);
    assert_null(w);
    print_message("celestial axes 2, 3: %s\n", err);
    assert_non_null(strstr(err, "celestial"));
    mp_image_free(&im);
}

/* Headers without a usable celestial WCS. */
static void expect_open_error(const char *const *cards, int n, const char *want)
{
    mp_image im;
    header_image(&im, 10, 10, cards, n);
    mp_wcs *w = NULL;
    char err[MP_ERRLEN] = "";
    assert_int_equal(mp_wcs_open(&im, &w, err), MP_WCS_FAIL);
    assert_null(w);
    print_message("  -> %s\n", err);
    if (!strstr(err, want))
        fail_msg("error '%s' does not say '%s'", err, want);
    mp_image_free(&im);
}

static void test_no_wcs(void **state)
{
    (void)state;
    static const char *const none[] = {
        "SIMPLE  =                    T", "BITPIX  =                  -32",
        "NAXIS   =                    2", "NAXIS1  =                   10",
        "NAXIS2  =                   10", "GAIN    =                  2.0", "END",
    };
    expect_open_error(none, 7, "no WCS in the header");

    static const char *const linear[] = {
        "NAXIS   =                    2",
        "CTYPE1  = 'LINEAR'", "CTYPE2  = 'LINEAR'",
        "CRPIX1  =                  1.0", "CRPIX2  =                  1.0",
        "CRVAL1  =                  0.0", "CRVAL2  =                  0.0",
        "CDELT1  =                  1.0", "CDELT2  =                  1.0", "END",
    };
    expect_open_error(linear, 10, "no celestial WCS");

    static const char *const singular[] = {
        "NAXIS   =                    2",
        "CTYPE1  = 'RA---TAN'", "CTYPE2  = 'DEC--TAN'",
        "CRPIX1  =                  1.0", "CRPIX2  =                  1.0",
        "CRVAL1  =                 10.0", "CRVAL2  =                 20.0",
        "CD1_1   =                  1.0", "CD1_2   =                  2.0",
        "CD2_1   =                  2.0", "CD2_2   =                  4.0", "END",
    };
    expect_open_error(singular, 12, "singular");
    static const char *const zero_row[] = {
        "NAXIS   =                    2",
        "CTYPE1  = 'RA---TAN'", "CTYPE2  = 'DEC--TAN'",
        "CRPIX1  =                  1.0", "CRPIX2  =                  1.0",
        "CRVAL1  =                 10.0", "CRVAL2  =                 20.0",
        "CD1_1   =               1.0E-4", "CD1_2   =               2.0E-4",
        "CD2_1   =                  0.0", "CD2_2   =                  0.0", "END",
    };
    expect_open_error(zero_row, 12, "singular");

    static const char *const badproj[] = {
        "NAXIS   =                    2",
        "CTYPE1  = 'RA---QQQ'", "CTYPE2  = 'DEC--QQQ'",
        "CRVAL1  =                 10.0", "CRVAL2  =                 20.0",
        "CDELT1  =              -1.0E-4", "CDELT2  =               1.0E-4", "END",
    };
    expect_open_error(badproj, 8, "unusable WCS");

    /* No cards at all, and null arguments. */
    mp_image im = {0};
    mp_wcs *w = NULL;
    char err[MP_ERRLEN] = "";
    assert_int_equal(mp_wcs_open(&im, &w, err), MP_WCS_FAIL);
    assert_null(w);
    assert_non_null(strstr(err, "no header"));
    assert_int_equal(mp_wcs_open(NULL, &w, err), MP_WCS_FAIL);
    mp_wcs_close(NULL);
}

/* Galactic: the conversion to ICRS. */
static const char *const gal_cards[] = {
    "NAXIS   =                    2",
    "CTYPE1  = 'GLON-CAR'",
    "CTYPE2  = 'GLAT-CAR'",
    "CRPIX1  =                 51.0",
    "CRPIX2  =                 51.0",
    "CRVAL1  =                  0.0",
    "CRVAL2  =                  0.0",
    "CDELT1  =              -0.0100",
    "CDELT2  =               0.0100",
    "END",
};

static void test_galactic(void **state)
{
    (void)state;
    mp_image im;
    header_image(&im, 100, 100, gal_cards, (int)(sizeof gal_cards / sizeof *gal_cards));
    mp_wcs *w = open_ok(&im);
    assert_string_equal(mp_wcs_frame(w), "galactic");
    double l, b, a, d;
    char err[MP_ERRLEN];
    p2s(w, 51.0, 51.0, &l, &b);
    assert_true(fabs(l) < 1e-12 && fabs(b) < 1e-12);
    assert_int_equal(mp_wcs_pix2j2000(w, 51.0, 51.0, &a, &d, err), 0);
    /* astropy 5: SkyCoord(l=0, b=0, frame='galactic').icrs */
    double e = sep_mas(a, d, 266.4049882865447, -28.93617776179147);
    print_message("Galactic centre -> ICRS (%.9f, %.9f), %.1f mas from astropy's\n", a, d, e);
    assert_true(e < 50.0);
    mp_wcs_close(w);
    mp_image_free(&im);

    /* The Galactic pole, and the ICRS pole in Galactic coordinates, exactly. */
    static const char *const pole[] = {
        "NAXIS   =                    2",
        "CTYPE1  = 'GLON-TAN'", "CTYPE2  = 'GLAT-TAN'",
        "CRPIX1  =                  1.0", "CRPIX2  =                  1.0",
        "CRVAL1  =            122.93192", "CRVAL2  =             27.12825",
        "CDELT1  =              -1.0E-4", "CDELT2  =               1.0E-4", "END",
    };
    header_image(&im, 10, 10, pole, 10);
    w = open_ok(&im);
    assert_int_equal(mp_wcs_pix2j2000(w, 1.0, 1.0, &a, &d, err), 0);
    assert_true(fabs(d - 90.0) < 1e-9);
    mp_wcs_close(w);
    mp_image_free(&im);
}

/* ---- threads ------------------------------------------------------------ */

static void same_from_threads(const mp_wcs *w, long nx, long ny)
{
    enum { N = 48 };
    static double ra[N * N], dec[N * N], xs[N * N], ys[N * N];
    for (int k = 0; k < N * N; k++) {
        double x = 0.5 + (k % N) * (double)nx / (N - 1), y = 0.5 + (k / N) * (double)ny / (N - 1);
        p2s(w, x, y, &ra[k], &dec[k]);
        s2p(w, ra[k], dec[k], &xs[k], &ys[k]);
    }
    int bad = 0;
    for (int rep = 0; rep < 20; rep++) {
#pragma omp parallel for num_threads(8) schedule(dynamic, 7) reduction(+ : bad)
        for (int k = 0; k < N * N; k++) {
            double x = 0.5 + (k % N) * (double)nx / (N - 1), y = 0.5 + (k / N) * (double)ny / (N - 1);
            double a, d, x2, y2;
            char err[MP_ERRLEN];
            if (mp_wcs_pix2sky(w, x, y, &a, &d, err) != 0
                || mp_wcs_sky2pix(w, a, d, &x2, &y2, err) != 0)
                bad++;
            else if (a != ra[k] || d != dec[k] || x2 != xs[k] || y2 != ys[k])
                bad++;
        }
    }
    assert_int_equal(bad, 0);
}

static void test_threads(void **state)
{
    (void)state;
    mp_image im;
    header_image(&im, 256, 256, sip_cards, (int)(sizeof sip_cards / sizeof *sip_cards));
    mp_wcs *w = open_ok(&im);
    same_from_threads(w, 256, 256);
    mp_wcs_close(w);
    mp_image_free(&im);

    /* The sequent distortions (TPV, TNX) too, when the data are here. */
    const char *files[] = { "wcs_registry_samples/tpv.fits", "ctio_mosaic2_bulge/tnx.fits" };
    for (int i = 0; i < 2; i++) {
        if (!have_real(files[i]))
            continue;
        read_real(files[i], &im);
        w = open_ok(&im);
        same_from_threads(w, im.nx, im.ny);
        mp_wcs_close(w);
        mp_image_free(&im);
    }
}

/* ---- mp_table_add_sky --------------------------------------------------- */

static void test_add_sky(void **state)
{
    (void)state;
    mp_image im;
    header_image(&im, 256, 256, sip_cards, (int)(sizeof sip_cards / sizeof *sip_cards));
    mp_wcs *w = open_ok(&im);
    char err[MP_ERRLEN] = "";

    mp_table t;
    mp_table_init(&t);
    int cn = mp_table_add_col(&t, "NUMBER");
    int cx = mp_table_add_col(&t, "X_IMAGE"), cy = mp_table_add_col(&t, "Y_IMAGE");
    int px = mp_table_add_col(&t, "XPSF_IMAGE"), py = mp_table_add_col(&t, "YPSF_IMAGE");
    const int nrow = 1000;
    for (int r = 0; r < nrow; r++) {
        long k = mp_table_add_row(&t);
        assert_int_equal(k, r);
        mp_table_set(&t, (size_t)r, cn, r + 1);
        mp_table_set(&t, (size_t)r, cx, 1.0 + (r * 37) % 256);
        mp_table_set(&t, (size_t)r, cy, 1.0 + (r * 91) % 256);
        mp_table_set(&t, (size_t)r, px, 1.25 + (r * 37) % 256);
        mp_table_set(&t, (size_t)r, py, 0.75 + (r * 91) % 256);
    }
    mp_table_set(&t, 3, px, NAN);   /* a star the fit lost */
    assert_int_equal(mp_table_add_sky(&t, &im, err), 0);
    assert_int_equal((int)t.ncol, 9);
    int ca = mp_table_col(&t, "ALPHAPSF_J2000"), cd = mp_table_col(&t, "DELTAPSF_J2000");
    int ca2 = mp_table_col(&t, "ALPHA_J2000"), cd2 = mp_table_col(&t, "DELTA_J2000");
    assert_true(ca >= 0 && cd >= 0 && ca2 >= 0 && cd2 >= 0);
    assert_string_equal(t.cols[ca].unit, "deg");
    assert_string_equal(t.cols[cd].unit, "deg");
    assert_string_equal(t.cols[ca2].unit, "deg");
    assert_string_equal(t.cols[cd2].unit, "deg");
    for (int r = 0; r < nrow; r++) {
        double a, d;
        if (r == 3) {
            assert_true(isnan(mp_table_get(&t, 3, ca)) && isnan(mp_table_get(&t, 3, cd)));
        } else {
            p2s(w, mp_table_get(&t, (size_t)r, px), mp_table_get(&t, (size_t)r, py), &a, &d);
            assert_true(mp_table_get(&t, (size_t)r, ca) == a);
            assert_true(mp_table_get(&t, (size_t)r, cd) == d);
        }
        p2s(w, mp_table_get(&t, (size_t)r, cx), mp_table_get(&t, (size_t)r, cy), &a, &d);
        assert_true(mp_table_get(&t, (size_t)r, ca2) == a);
        assert_true(mp_table_get(&t, (size_t)r, cd2) == d);
        assert_true(mp_table_get(&t, (size_t)r, cn) == r + 1);   /* untouched */
    }
    /* Again: the columns are overwritten, not duplicated. */
    assert_int_equal(mp_table_add_sky(&t, &im, err), 0);
    assert_int_equal((int)t.ncol, 9);
    mp_table_free(&t);

    /* Only the fitted positions: only ALPHAPSF/DELTAPSF. */
    mp_table_init(&t);
    px = mp_table_add_col(&t, "XPSF_IMAGE");
    py = mp_table_add_col(&t, "YPSF_IMAGE");
    mp_table_add_row(&t);
    mp_table_set(&t, 0, px, 10.0);
    mp_table_set(&t, 0, py, 20.0);
    assert_int_equal(mp_table_add_sky(&t, &im, err), 0);
    assert_int_equal((int)t.ncol, 4);
    assert_int_equal(mp_table_col(&t, "ALPHA_J2000"), -1);
    mp_table_free(&t);

    /* An empty table gets the columns. */
    mp_table_init(&t);
    mp_table_add_col(&t, "X_IMAGE");
    mp_table_add_col(&t, "Y_IMAGE");
    assert_int_equal(mp_table_add_sky(&t, &im, err), 0);
    assert_int_equal((int)t.ncol, 4);
    assert_int_equal(mp_table_col(&t, "ALPHA_J2000"), 2);
    mp_table_free(&t);

    /* Errors leave the table as it was. */
    mp_table_init(&t);
    mp_table_add_col(&t, "XPSF_IMAGE");     /* no YPSF_IMAGE */
    mp_table_add_col(&t, "FLUX_PSF");
    mp_table_add_row(&t);
    assert_int_equal(mp_table_add_sky(&t, &im, err), MP_WCS_FAIL);
    assert_non_null(strstr(err, "neither XPSF_IMAGE/YPSF_IMAGE nor X_IMAGE/Y_IMAGE"));
    assert_int_equal((int)t.ncol, 2);
    mp_table_add_col(&t, "YPSF_IMAGE");
    mp_image none;
    static const char *const nowcs[] = { "NAXIS   =                    2", "END" };
    header_image(&none, 10, 10, nowcs, 2);
    assert_int_equal(mp_table_add_sky(&t, &none, err), MP_WCS_FAIL);
    assert_non_null(strstr(err, "no WCS"));
    assert_int_equal((int)t.ncol, 3);
    mp_image_free(&none);

    static const char *const fk4[] = {
        "NAXIS   =                    2",
        "CTYPE1  = 'RA---TAN'", "CTYPE2  = 'DEC--TAN'",
        "CRPIX1  =                  1.0", "CRPIX2  =                  1.0",
        "CRVAL1  =                 10.0", "CRVAL2  =                 20.0",
        "CDELT1  =              -1.0E-4", "CDELT2  =               1.0E-4",
        "EQUINOX =               1950.0", "END",
    };
    header_image(&none, 10, 10, fk4, 11);
    assert_int_equal(mp_table_add_sky(&t, &none, err), MP_WCS_FAIL);
    print_message("FK4 B1950: %s\n", err);
    assert_non_null(strstr(err, "fk4"));
    assert_int_equal((int)t.ncol, 3);
    mp_image_free(&none);
    mp_table_free(&t);

    /* Galactic header: the columns are ICRS. */
    mp_image gal;
    header_image(&gal, 100, 100, gal_cards, (int)(sizeof gal_cards / sizeof *gal_cards));
    mp_table_init(&t);
    px = mp_table_add_col(&t, "XPSF_IMAGE");
    py = mp_table_add_col(&t, "YPSF_IMAGE");
    mp_table_add_row(&t);
    mp_table_set(&t, 0, px, 51.0);
    mp_table_set(&t, 0, py, 51.0);
    assert_int_equal(mp_table_add_sky(&t, &gal, err), 0);
    assert_true(sep_mas(mp_table_get(&t, 0, 2), mp_table_get(&t, 0, 3),
                        266.4049882865447, -28.93617776179147) < 50.0);
    mp_table_free(&t);
    mp_image_free(&gal);

    mp_wcs_close(w);
    mp_image_free(&im);
}

int main(void)
{
    const struct CMUnitTest tests[] = {
        cmocka_unit_test(test_reference_points),
        cmocka_unit_test(test_real_frames),
        cmocka_unit_test(test_synthetic_tan),
        cmocka_unit_test(test_synthetic_sip),
        cmocka_unit_test(test_cube_header),
        cmocka_unit_test(test_no_wcs),
        cmocka_unit_test(test_galactic),
        cmocka_unit_test(test_threads),
        cmocka_unit_test(test_add_sky),
    };
    return cmocka_run_group_tests(tests, NULL, NULL);
}
