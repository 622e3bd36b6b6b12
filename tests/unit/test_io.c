/* test_io.c — io/: image read/write round trips, sections and HDUs,
 * header look-ups, frames (gain, NaN and saturation masks), the errors for
 * bad files, and atomic output files.  Fixtures live in a mkdtemp
 * directory under $TMPDIR, removed at the end. */
#include <math.h>
#include <setjmp.h>
#include <stdarg.h>
#include <stddef.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/stat.h>
#include <sys/wait.h>
#include <unistd.h>

#include <cmocka.h>
#include <fitsio.h>

#include "io/io.h"

typedef struct {
    char dir[512];
    char path[640];
} scratch;

static int setup(void **state)
{
    scratch *s = calloc(1, sizeof *s);
    if (!s)
        return -1;
    const char *tmp = getenv("TMPDIR");
    /* Not "test_io.XXXXXX": a random suffix starting with Z would put
     * ".Z" in the gzip test's path (io/fits_guard.c compressed_name_ok). */
    snprintf(s->dir, sizeof s->dir, "%s/test_io_XXXXXX", tmp && *tmp ? tmp : "/tmp");
    if (!mkdtemp(s->dir)) {
        free(s);
        return -1;
    }
    *state = s;
    return 0;
}

static int teardown(void **state)
{
    scratch *s = *state;
    char cmd[600];
    snprintf(cmd, sizeof cmd, "rm -rf '%s'", s->dir);
    int rc = system(cmd);
    free(s);
    return rc == 0 ? 0 : -1;
}

static const char *in_dir(scratch *s, const char *name)
{
    snprintf(s->path, sizeof s->path, "%s/%s", s->dir, name);
    return s->path;
}

static int exists(const char *path)
{
    struct stat sb;
    return stat(path, &sb) == 0;
}

/* Number of entries in the scratch directory (to spot leftover temporaries). */
static int count_files(const scratch *s)
{
    char cmd[600];
    snprintf(cmd, sizeof cmd, "ls -A '%s' | wc -l", s->dir);
    FILE *p = popen(cmd, "r");
    int n = -1;
    if (p) {
        if (fscanf(p, "%d", &n) != 1)
            n = -1;
        pclose(p);
    }
    return n;
}

/* A 7×5 test pattern: value 100·y + x, so every pixel says where it is. */
enum { NX = 7, NY = 5 };
static void pattern(double *pix)
{
    for (int y = 1; y <= NY; y++)
        for (int x = 1; x <= NX; x++)
            pix[(y - 1) * NX + (x - 1)] = 100.0 * y + x;
}

/* Write an image with cfitsio directly (for layouts mp_image_write does
 * not make: integer BITPIX with BLANK, cubes, extensions). */
static void write_raw(const char *path, int bitpix, int naxis, const long *naxes,
                      const double *pix, int blank, const char *extname)
{
    fitsfile *fp;
    int st = 0;
    char name[700];
    snprintf(name, sizeof name, "!%s", path);
    fits_create_file(&fp, name, &st);
    long n = 1;
    for (int k = 0; k < naxis; k++)
        n *= naxes[k];
    if (extname) {
        fits_create_img(fp, 8, 0, NULL, &st);      /* empty primary */
        fits_create_img(fp, bitpix, naxis, (long *)naxes, &st);
        fits_update_key_str(fp, "EXTNAME", extname, NULL, &st);
    } else {
        fits_create_img(fp, bitpix, naxis, (long *)naxes, &st);
    }
    if (blank) {
        long b = -999;
        fits_update_key_lng(fp, "BLANK", b, NULL, &st);
        fits_set_imgnull(fp, b, &st);
    }
    long fpix[9] = {1, 1, 1, 1, 1, 1, 1, 1, 1};
    /* NaN marks blank pixels; integer images hold the BLANK value there. */
    double *v = malloc((size_t)n * sizeof *v);
    assert_non_null(v);
    for (long i = 0; i < n; i++)
        v[i] = blank && isnan(pix[i]) ? -999.0 : pix[i];
    fits_write_pix(fp, TDOUBLE, fpix, n, v, &st);
    free(v);
    fits_close_file(fp, &st);
    assert_int_equal(st, 0);
}

/* ---------- round trip, header ---------- */

static void test_round_trip(void **state)
{
    scratch *s = *state;
    double pix[NX * NY];
    pattern(pix);
    pix[3] = NAN;
    const mp_card cards[] = {
        {"GAIN", 2.5, NULL, "[e-/ADU]"},
        {"RDNOISE", 4, NULL, "[e-]"},
        {"SKY", 0.1, NULL, NULL},
        {"OBJECT", 0, "it's a test", NULL},
        {"SATURATE", INFINITY, NULL, "not finite: left out"},
    };
    const char *path = in_dir(s, "rt.fits");
    char err[MP_ERRLEN];
    assert_int_equal(mp_image_write(path, pix, NX, NY, -64, cards, 5, err), 0);
    assert_int_equal(count_files(s), 1);      /* no temporary left */

    mp_image im;
    assert_int_equal(mp_image_read(path, &im, err), 0);
    assert_int_equal(im.nx, NX);
    assert_int_equal(im.ny, NY);
    for (int i = 0; i < NX * NY; i++)
        assert_true(i == 3 ? isnan(im.pix[i]) : im.pix[i] == pix[i]);
    double v;
    assert_int_equal(mp_header_double(&im, "GAIN", &v), 0);
    assert_true(v == 2.5);
    assert_int_equal(mp_header_double(&im, "RDNOISE", &v), 0);
    assert_true(v == 4);
    assert_int_equal(mp_header_double(&im, "SKY", &v), 0);
    assert_true(v == 0.1);                        /* exact: shortest round trip */
    assert_int_equal(mp_header_double(&im, "gain", &v), 0);   /* case-blind */
    assert_int_equal(mp_header_double(&im, "SATURATE", &v), 1);
    assert_int_equal(mp_header_double(&im, "NOSUCH", &v), 1);
    assert_int_equal(mp_header_double(&im, "OBJECT", &v), 2);
    char str[32];
    assert_int_equal(mp_header_string(&im, "OBJECT", str, sizeof str), 0);
    assert_string_equal(str, "it's a test");
    assert_int_equal(mp_header_string(&im, "GAIN", str, sizeof str), 2);
    mp_image_free(&im);
    mp_image_free(&im);                           /* safe twice */

    /* BITPIX -32: values as float. */
    assert_int_equal(mp_image_write(path, pix, NX, NY, -32, NULL, 0, err), 0);
    assert_int_equal(mp_image_read(path, &im, err), 0);
    for (int i = 0; i < NX * NY; i++)
        assert_true(i == 3 ? isnan(im.pix[i]) : im.pix[i] == (double)(float)pix[i]);
    mp_image_free(&im);
    /* Other BITPIX values are refused. */
    assert_int_not_equal(mp_image_write(path, pix, NX, NY, 16, NULL, 0, err), 0);
}

static void test_header_parsing(void **state)
{
    (void)state;
    /* Hand-made cards: D exponent, HIERARCH, undefined value, comment slash,
     * quotes and trailing blanks, logical. */
    const char *cards[] = {
        "EXPTIME =               1.5D+2 / exposure",
        "HIERARCH ESO DET OUT1 GAIN = 2.25 / e-/ADU",
        "UNDEF   =                      / nothing",
        "FILTER  = 'V       '           / band",
        "QUOTE   = 'O''Hara'",
        "FLAG    =                    T",
        "GAIN    = 3.0",
    };
    int n = (int)(sizeof cards / sizeof cards[0]);
    char *hdr = malloc((size_t)n * 80 + 1);
    assert_non_null(hdr);
    for (int k = 0; k < n; k++)
        snprintf(hdr + k * 80, 81, "%-80s", cards[k]);
    mp_image im = {.hdr = hdr, .nkeys = n};
    double v;
    char s[16];
    assert_int_equal(mp_header_double(&im, "EXPTIME", &v), 0);
    assert_true(v == 150.0);
    assert_int_equal(mp_header_double(&im, "ESO DET OUT1 GAIN", &v), 0);
    assert_true(v == 2.25);
    assert_int_equal(mp_header_double(&im, "UNDEF", &v), 2);
    assert_int_equal(mp_header_string(&im, "FILTER", s, sizeof s), 0);
    assert_string_equal(s, "V");
    assert_int_equal(mp_header_string(&im, "QUOTE", s, sizeof s), 0);
    assert_string_equal(s, "O'Hara");
    assert_int_equal(mp_header_string(&im, "QUOTE", s, 3), 0);   /* truncated */
    assert_string_equal(s, "O'");
    assert_int_equal(mp_header_double(&im, "FLAG", &v), 2);
    /* "GAIN" must not match the HIERARCH card that ends in GAIN. */
    assert_int_equal(mp_header_double(&im, "GAIN", &v), 0);
    assert_true(v == 3.0);
    free(hdr);
}

/* ---------- sections, HDUs, integer images ---------- */

static void test_sections_and_hdus(void **state)
{
    scratch *s = *state;
    double pix[NX * NY];
    pattern(pix);
    char err[MP_ERRLEN], name[700];
    const char *path = in_dir(s, "sec.fits");
    assert_int_equal(mp_image_write(path, pix, NX, NY, -64, NULL, 0, err), 0);

    mp_image im;
    snprintf(name, sizeof name, "%s[2:5,3:7]", path);
    /* NY is 5: rows 3..7 run off the image, an error naming the file. */
    assert_int_not_equal(mp_image_read(name, &im, err), 0);
    assert_non_null(strstr(err, "sec.fits"));
    snprintf(name, sizeof name, "%s[2:5,2:4]", path);
    assert_int_equal(mp_image_read(name, &im, err), 0);
    assert_int_equal(im.nx, 4);
    assert_int_equal(im.ny, 3);
    for (int y = 1; y <= 3; y++)
        for (int x = 1; x <= 4; x++)
            assert_true(im.pix[(y - 1) * 4 + (x - 1)] == 100.0 * (y + 1) + (x + 1));
    mp_image_free(&im);

    /* A taller image so that [2:5,3:7] as in the brief fits. */
    enum { TX = 8, TY = 9 };
    double tall[TX * TY];
    for (int i = 0; i < TX * TY; i++)
        tall[i] = 100.0 * (i / TX + 1) + (i % TX + 1);
    const char *tpath = in_dir(s, "f.fits");
    assert_int_equal(mp_image_write(tpath, tall, TX, TY, -32, NULL, 0, err), 0);
    snprintf(name, sizeof name, "%s[2:5,3:7]", tpath);
    assert_int_equal(mp_image_read(name, &im, err), 0);
    assert_int_equal(im.nx, 4);
    assert_int_equal(im.ny, 5);
    for (int y = 1; y <= 5; y++)
        for (int x = 1; x <= 4; x++)
            assert_true(im.pix[(y - 1) * 4 + (x - 1)] == 100.0 * (y + 2) + (x + 1));
    mp_image_free(&im);

    /* An image extension by name and number; integer pixels with BLANK
     * come back as NaN. */
    const char *mef = in_dir(s, "mef.fits");
    long ax[2] = {NX, NY};
    double ipix[NX * NY];
    pattern(ipix);
    ipix[10] = NAN;
    write_raw(mef, 16, 2, ax, ipix, 1, "SCI");
    const char *names[] = {"%s[SCI]", "%s[1]", "%s"};
    for (int k = 0; k < 3; k++) {
        snprintf(name, sizeof name, names[k], mef);
        assert_int_equal(mp_image_read(name, &im, err), 0);
        assert_int_equal(im.nx, NX);
        assert_true(isnan(im.pix[10]));
        assert_true(im.pix[11] == ipix[11]);
        char ext[16];
        assert_int_equal(mp_header_string(&im, "EXTNAME", ext, sizeof ext), 0);
        assert_string_equal(ext, "SCI");
        mp_image_free(&im);
    }
    snprintf(name, sizeof name, "%s[3]", mef);
    assert_int_not_equal(mp_image_read(name, &im, err), 0);
    assert_non_null(strstr(err, "mef.fits"));
    snprintf(name, sizeof name, "%s[ERR]", mef);
    assert_int_not_equal(mp_image_read(name, &im, err), 0);
    assert_non_null(strstr(err, "no such HDU"));
}

/* ---------- bad inputs ---------- */

static void expect_read_error(const char *name, const char *file, const char *words)
{
    mp_image im;
    char err[MP_ERRLEN] = "";
    assert_int_not_equal(mp_image_read(name, &im, err), 0);
    if (!strstr(err, file) || (words && !strstr(err, words)))
        print_error("unexpected message: %s (name %s)\n", err, name);
    assert_non_null(strstr(err, file));
    if (words)
        assert_non_null(strstr(err, words));
    assert_null(strchr(err, '\n'));              /* one line */
    assert_null(im.pix);
    assert_null(im.hdr);
}

/* A tile-compressed image (fpack's .fz: RICE_1 is its default) written
 * with codec cmp, its header's EXTNAME SCI; v its 120 x 90 pixels. */
static void write_tiles(const char *path, int cmp, short *v)
{
    int status = 0;
    fitsfile *fp;
    long naxes[2] = {120, 90};
    for (int i = 0; i < 120 * 90; i++)
        v[i] = (short)((i * 37) % 5000 - 1000);
    unlink(path);
    fits_create_file(&fp, path, &status);
    fits_create_img(fp, SHORT_IMG, 0, NULL, &status);
    fits_set_compression_type(fp, cmp, &status);
    fits_create_img(fp, SHORT_IMG, 2, naxes, &status);
    fits_write_key_str(fp, "EXTNAME", "SCI", NULL, &status);
    fits_write_img(fp, TSHORT, 1, 120 * 90, v, &status);
    fits_close_file(fp, &status);
    assert_int_equal(status, 0);
}

/* The value of path's ZTILE1 card set to 0 in place (the frame fuzzer's
 * ztile-zero-divides.fits). */
static void zero_ztile1(const char *path)
{
    FILE *fp = fopen(path, "r+b");
    assert_non_null(fp);
    static char b[4 * 2880];
    size_t n = fread(b, 1, sizeof b, fp);
    size_t k = 0;
    while (k + 80 <= n && memcmp(b + k, "ZTILE1  =", 9) != 0)
        k += 80;
    assert_true(k + 80 <= n);
    memcpy(b + k + 10, "                   0", 20);
    assert_int_equal(fseek(fp, (long)k, SEEK_SET), 0);
    assert_int_equal(fwrite(b + k, 1, 80, fp), 80);
    fclose(fp);
}

/* A tile-compressed image is refused, by name and by its extension, with
 * RICE_1 (fpack's default) tiles or GZIP_1 ones or a tiling of 0, plain
 * or gzipped, before cfitsio parses it (io/fits_guard.c): its decoders do
 * not hold a corrupt tile to its bytes and it divides by a tiling of 0
 * (the frame fuzzer: a crash in fits_rdecomp_short, a GZIP tile growing
 * for 20 s, an FPE in imcomp_get_compressed_image_par). */
static void test_compressed_image(void **state)
{
    scratch *s = *state;
    char path[700], name[720], gz[700], cmd[1500];
    snprintf(path, sizeof path, "%s", in_dir(s, "tiles.fits"));
    snprintf(gz, sizeof gz, "%s", in_dir(s, "tiles.fits.gz"));
    static short v[120 * 90];
    const int cmp[2] = {RICE_1, GZIP_1};
    const char *names[2] = {"%s[SCI]", "%s"};
    for (int c = 0; c < 3; c++) {
        write_tiles(path, cmp[c % 2], v);
        if (c == 2)
            zero_ztile1(path);
        /* gzipped as well: cfitsio inflates the file and parses the same
         * tiling (a gzipped ZTILE1 of 0 was a SIGFPE as cfitsio opened it) */
        snprintf(cmd, sizeof cmd, "gzip -c '%s' > '%s'", path, gz);
        assert_int_equal(system(cmd), 0);
        for (int k = 0; k < 4; k++) {
            snprintf(name, sizeof name, names[k % 2], k < 2 ? path : gz);
            expect_read_error(name, k < 2 ? "tiles.fits" : "tiles.fits.gz", "tile-compressed");
        }
    }
}

/* A gzipped file's headers are walked as a plain file's are (io/fits_guard.c
 * walk_gzip): a table extension whose TTYPE1 is not a quoted string, behind
 * an image primary, is refused by name, by its extension and as a PSF
 * file's guard sees it, where cfitsio 4.2.0 overflowed a buffer on it and
 * glibc aborted the process; the same bytes plain are refused alike. */
static void test_gzip_headers_walked(void **state)
{
    scratch *s = *state;
    static unsigned char b[4 * 2880];
    memset(b, ' ', sizeof b);
    const char *cards[] = {"SIMPLE  =                    T", "BITPIX  =                  -32",
                           "NAXIS   =                    2", "NAXIS1  =                   10",
                           "NAXIS2  =                   10", "EXTEND  =                    T", "END",
                           "XTENSION= 'BINTABLE'", "BITPIX  =                    8",
                           "NAXIS   =                    2", "NAXIS1  =                    4",
                           "NAXIS2  =                    1", "PCOUNT  =                    0",
                           "GCOUNT  =                    1", "TFIELDS =                    1",
                           "TTYPE1  = FLUX_NOT_A_QUOTED_STRING_AND_LONGER_THAN_SEVENTY_BYTES_OF_VALUE",
                           "TFORM1  = '1E      '", "END"};
    for (size_t c = 0, rec = 0, k = 0; c < sizeof cards / sizeof cards[0]; c++, k++) {
        memcpy(b + rec * 2880 + 80 * k, cards[c], strlen(cards[c]));
        if (strcmp(cards[c], "END") == 0) {
            rec += 2;                           /* the header, then its data's record */
            k = (size_t)-1;
        }
    }
    memset(b + 2880, 0, 2880);                  /* the image's 400 bytes, zeros */
    char plain[700], gz[700], cmd[1500], why[MP_GUARD_LEN];
    snprintf(plain, sizeof plain, "%s", in_dir(s, "badtab.fits"));
    snprintf(gz, sizeof gz, "%s", in_dir(s, "badtab.fits.gz"));
    FILE *fp = fopen(plain, "wb");
    assert_non_null(fp);
    assert_int_equal(fwrite(b, 1, sizeof b, fp), sizeof b);
    fclose(fp);
    snprintf(cmd, sizeof cmd, "gzip -c '%s' > '%s'", plain, gz);
    assert_int_equal(system(cmd), 0);
    for (int k = 0; k < 2; k++) {
        const char *f = k ? gz : plain;
        char name[720];
        expect_read_error(f, k ? "badtab.fits.gz" : "badtab.fits", "malformed header card TTYPE1");
        snprintf(name, sizeof name, "%s[1]", f);
        expect_read_error(name, k ? "badtab.fits.gz" : "badtab.fits", "malformed header card");
        assert_int_equal(mp_fits_guard_file(f, why), 1);
        assert_non_null(strstr(why, "TTYPE1"));
        /* as a file:// URL, cfitsio's disk driver: walked the same */
        snprintf(name, sizeof name, "file://%s", f);
        expect_read_error(name, "badtab.fits", "malformed header card TTYPE1");
    }
    /* Standard input and other URLs: no walk sees their bytes before
     * cfitsio parses them, so they are refused by name (`cat bad.fits |
     * matphot find -` aborted in cfitsio); a file named "-x.fits" is a
     * file. */
    const char *unseen[4] = {"-", "-[1]", "stdin://", "http://127.0.0.1:9/f.fits"};
    for (int k = 0; k < 4; k++) {
        assert_int_equal(mp_fits_guard_file(unseen[k], why), 1);
        assert_non_null(strstr(why, k < 3 ? "standard input" : "a URL"));
        expect_read_error(unseen[k], unseen[k], k < 3 ? "standard input" : "a URL");
    }
    assert_int_equal(mp_fits_guard_file("-x.fits", why), 0);
    /* cfitsio's "in(out)" copy: refused before cfitsio writes out (it
     * wrote copy.fits, exit 0, before session 77) */
    char copy[700], name[1500];
    snprintf(copy, sizeof copy, "%s", in_dir(s, "copy.fits"));
    snprintf(name, sizeof name, "%s(%s)", plain, copy);
    assert_int_equal(mp_fits_guard_file(name, why), 1);
    assert_non_null(strstr(why, "names a copy for cfitsio to write"));
    expect_read_error(name, "badtab.fits", "names a copy");
    assert_int_equal(access(copy, F_OK), -1);
}

static void test_bad_inputs(void **state)
{
    scratch *s = *state;
    char err[MP_ERRLEN], name[700];
    expect_read_error(in_dir(s, "missing.fits"), "missing.fits", "No such file");

    /* A text file. */
    const char *txt = in_dir(s, "notes.txt");
    FILE *fp = fopen(txt, "w");
    assert_non_null(fp);
    fputs("this is not a FITS file\n", fp);
    fclose(fp);
    expect_read_error(txt, "notes.txt", "not a FITS file");

    /* An empty file. */
    const char *empty = in_dir(s, "empty.fits");
    fp = fopen(empty, "w");
    assert_non_null(fp);
    fclose(fp);
    expect_read_error(empty, "empty.fits", "empty");

    /* A valid FITS file cut in the data, and one cut in the header. */
    double big[100 * 100];
    for (int i = 0; i < 100 * 100; i++)
        big[i] = i;
    const char *cut = in_dir(s, "cut.fits");
    assert_int_equal(mp_image_write(cut, big, 100, 100, -32, NULL, 0, err), 0);
    assert_int_equal(truncate(cut, 2880 + 20000), 0);
    expect_read_error(cut, "cut.fits", "truncated");
    assert_int_equal(truncate(cut, 1000), 0);
    expect_read_error(cut, "cut.fits", "truncated or corrupt");

    /* Gzipped: cfitsio inflates it in memory, to the size gzip's trailer
     * states; a trailer claiming more than deflate can make (1032:1) is
     * refused before cfitsio allocates it.  gzip is Debian-essential. */
    char plain[sizeof s->path], gz[sizeof s->path], cmd[3 * sizeof s->path + 48];
    snprintf(plain, sizeof plain, "%s", in_dir(s, "small.fits"));   /* in_dir's buffer is one */
    snprintf(gz, sizeof gz, "%s", in_dir(s, "small.fits.gz"));
    assert_int_equal(mp_image_write(plain, big, 100, 100, -32, NULL, 0, err), 0);
    snprintf(cmd, sizeof cmd, "gzip -c '%s' > '%s'", plain, gz);
    assert_int_equal(system(cmd), 0);
    mp_image im;
    assert_int_equal(mp_image_read(gz, &im, err), 0);
    assert_int_equal(im.nx, 100);
    assert_true(im.pix[100 * 100 - 1] == 100 * 100 - 1);
    mp_image_free(&im);
    /* The same file in a folder whose name holds ".Z": cfitsio would
     * inflate it as Unix compress and call it "not a FITS file". */
    char zdir[sizeof s->path], zgz[sizeof s->path + 16];
    snprintf(zdir, sizeof zdir, "%s", in_dir(s, "run.Zeta"));
    snprintf(zgz, sizeof zgz, "%s/small.fits.gz", zdir);
    assert_int_equal(mkdir(zdir, 0700), 0);
    snprintf(cmd, sizeof cmd, "cp '%s' '%s'", gz, zgz);
    assert_int_equal(system(cmd), 0);
    expect_read_error(zgz, "small.fits.gz", "which cfitsio takes for Unix compress");
    fp = fopen(gz, "r+b");
    assert_non_null(fp);
    assert_int_equal(fseek(fp, -4, SEEK_END), 0);
    long gzsize = ftell(fp) + 4;
    const unsigned char isize[4] = {0xff, 0xff, 0xff, 0xff};  /* 4 GiB - 1 */
    assert_int_equal(fwrite(isize, 1, 4, fp), 4);
    fclose(fp);
    assert_true(4294967295.0 > 1032.0 * (double)gzsize);      /* the file is small */
    expect_read_error(gz, "small.fits.gz", "corrupt gzip file: it claims 4294967295 bytes");

    /* A cube: refused with the section hint; a plane of it reads. */
    const char *cube = in_dir(s, "cube.fits");
    long ax[3] = {NX, NY, 3};
    double cpix[NX * NY * 3];
    for (int i = 0; i < NX * NY * 3; i++)
        cpix[i] = i;
    write_raw(cube, -32, 3, ax, cpix, 0, NULL);
    expect_read_error(cube, "cube.fits", "3-D image; give a 2-D section like");
    snprintf(name, sizeof name, "%s[*,*,2]", cube);
    assert_int_equal(mp_image_read(name, &im, err), 0);
    assert_int_equal(im.nx, NX);
    assert_int_equal(im.ny, NY);
    assert_true(im.pix[0] == NX * NY);
    mp_image_free(&im);
    /* Degenerate extra axes are fine. */
    long ax1[3] = {NX, NY, 1};
    write_raw(cube, -32, 3, ax1, cpix, 0, NULL);
    assert_int_equal(mp_image_read(cube, &im, err), 0);
    mp_image_free(&im);

    /* No image at all (an empty primary and a table): said so, not "name
     * an image extension like f.fits[1]", which is the table */
    char tab[700];
    snprintf(tab, sizeof tab, "%s", in_dir(s, "table_only.fits"));
    fitsfile *tf;
    int st = 0;
    char *tt[] = {"A"}, *tform[] = {"E"};
    unlink(tab);
    fits_create_file(&tf, tab, &st);
    fits_create_img(tf, 8, 0, NULL, &st);
    fits_create_tbl(tf, BINARY_TBL, 0, 1, tt, tform, NULL, "T", &st);
    fits_close_file(tf, &st);
    assert_int_equal(st, 0);
    expect_read_error(tab, "table_only.fits", "holds no image (its primary HDU is empty");

    /* A directory, a bad section. */
    cube = in_dir(s, "cube.fits");
    expect_read_error(s->dir, "test_io_", "directory");
    snprintf(name, sizeof name, "%s[1:2,x]", cube);
    expect_read_error(name, "cube.fits", NULL);

    /* Writing into a missing directory fails, names the file, leaves
     * nothing. */
    const char *nodir = in_dir(s, "no/such/dir/out.fits");
    assert_int_not_equal(mp_image_write(nodir, big, 10, 10, -32, NULL, 0, err), 0);
    assert_non_null(strstr(err, "out.fits"));
    assert_non_null(strstr(err, "No such file"));
}

/* ---------- frames ---------- */

/* A frame with a DQ plane (HST layout: SCI and DQ image extensions): the
 * dqbad bits carry no weight, the dqsat bits count as saturated, other bits
 * and dqmask="" change nothing; a DQ plane of another shape is refused, and
 * so is a dqmask with neither dqbad nor dqsat bits. */
static void test_frame_dq(void **state)
{
    scratch *s = *state;
    double pix[NX * NY], dq[NX * NY] = {0};
    pattern(pix);
    dq[3] = 256;          /* full well */
    dq[4] = 2048 + 4;     /* A/D saturation and an informational bit */
    dq[5] = 4;            /* informational only */
    dq[6] = 16;           /* hot pixel */
    const char *path = in_dir(s, "mef.fits");
    char name[700];
    snprintf(name, sizeof name, "!%s", path);
    fitsfile *fp;
    int st = 0;
    long ax[2] = {NX, NY}, fpix[2] = {1, 1};
    fits_create_file(&fp, name, &st);
    fits_create_img(fp, 8, 0, NULL, &st);
    fits_create_img(fp, DOUBLE_IMG, 2, ax, &st);
    fits_update_key_str(fp, "EXTNAME", "SCI", NULL, &st);
    fits_write_pix(fp, TDOUBLE, fpix, NX * NY, pix, &st);
    fits_create_img(fp, SHORT_IMG, 2, ax, &st);
    fits_update_key_str(fp, "EXTNAME", "DQ", NULL, &st);
    fits_write_pix(fp, TDOUBLE, fpix, NX * NY, dq, &st);
    fits_close_file(fp, &st);
    assert_int_equal(st, 0);

    char sci[720], err[MP_ERRLEN];
    snprintf(sci, sizeof sci, "%s[SCI]", path);
    mp_frame f;
    mp_datapars dp = {NAN, NAN, NAN, NAN, "[DQ]", 2304, 16, 0, "", 0, 0};
    assert_int_equal(mp_frame_read(sci, &dp, &f, err), 0);
    assert_int_equal(f.nsat, 2);
    assert_int_equal(f.nbad, 1);
    assert_int_equal(f.mask[3], MP_MASK_SATURATED);
    assert_int_equal(f.mask[4], MP_MASK_SATURATED);
    assert_int_equal(f.mask[5], 0);
    assert_int_equal(f.mask[6], MP_MASK_BAD);
    assert_true(f.im.pix[6] == 0.0);
    mp_frame_free(&f);
    /* satgrow = 1: the pixels within one (x and y) of the two saturated
     * ones, x = 3..6 of rows 1 and 2, are saturated too (6 more); the bad
     * pixel at x = 7 stays bad and row 3 is untouched. */
    dp.satgrow = 1;
    assert_int_equal(mp_frame_read(sci, &dp, &f, err), 0);
    assert_int_equal(f.nsat, 8);
    assert_int_equal(f.nbad, 1);
    for (int x = 3; x <= 6; x++)
        for (int y = 1; y <= 2; y++)
            assert_int_equal(f.mask[(y - 1) * NX + x - 1], MP_MASK_SATURATED);
    assert_int_equal(f.mask[1], 0);
    assert_int_equal(f.mask[6], MP_MASK_BAD);
    assert_int_equal(f.mask[NX + 6], 0);
    assert_int_equal(f.mask[2 * NX + 3], 0);
    mp_frame_free(&f);
    dp.satgrow = 0;
    /* A section of the frame applies to the DQ plane too: x 1..5 of row 1
     * holds the two saturated pixels (x = 4, 5), not the hot one (x = 7). */
    snprintf(sci, sizeof sci, "%s[SCI][1:5,1:2]", path);
    assert_int_equal(mp_frame_read(sci, &dp, &f, err), 0);
    assert_int_equal(f.nsat, 2);
    assert_int_equal(f.nbad, 0);
    assert_int_equal(f.mask[3], MP_MASK_SATURATED);
    mp_frame_free(&f);
    snprintf(sci, sizeof sci, "%s[SCI]", path);
    /* A file name works as well as [EXT]. */
    snprintf(dp.dqmask, sizeof dp.dqmask, "%s[DQ]", path);
    assert_int_equal(mp_frame_read(sci, &dp, &f, err), 0);
    assert_int_equal(f.nsat + f.nbad, 3);
    mp_frame_free(&f);
    /* No DQ: nothing masked. */
    dp.dqmask[0] = 0;
    assert_int_equal(mp_frame_read(sci, &dp, &f, err), 0);
    assert_int_equal(f.nsat + f.nbad, 0);
    mp_frame_free(&f);
    /* Wrong shape and a missing extension: one line naming what. */
    snprintf(dp.dqmask, sizeof dp.dqmask, "%s[SCI][1:4,1:4]", path);
    assert_int_not_equal(mp_frame_read(sci, &dp, &f, err), 0);
    assert_non_null(strstr(err, "dqmask"));
    assert_null(f.mask);
    snprintf(dp.dqmask, sizeof dp.dqmask, "[NOPE]");
    assert_int_not_equal(mp_frame_read(sci, &dp, &f, err), 0);
    assert_non_null(strstr(err, "NOPE"));
    /* A mask named with no bit selected would mask nothing: refused,
     * naming dqmask, whatever the file (here one that does not exist). */
    snprintf(dp.dqmask, sizeof dp.dqmask, "nosuch.fits");
    dp.dqsat = dp.dqbad = 0;
    assert_int_not_equal(mp_frame_read(sci, &dp, &f, err), 0);
    assert_non_null(strstr(err, "dqmask: nosuch.fits is given, but dqbad and dqsat select no bit"));
    assert_null(f.mask);
}

/* A pixel both saturated and flagged by a dqbad bit (AstroDrizzle marks
 * saturated cores as cosmic rays: ACS DQ 6400 = 4096|2048|256) is
 * saturated: satgrow grows it and it sets FLAGS 1.  A pixel with the dqbad
 * bit alone stays bad and is not grown.  Counted on a 7 x 5 frame: the
 * saturated pixel (3, 3) and its 8 neighbours are saturated (9), the bad
 * one (7, 1) alone is bad. */
static void test_frame_dq_saturation_first(void **state)
{
    scratch *s = *state;
    double pix[NX * NY], dq[NX * NY] = {0};
    pattern(pix);
    dq[2 * NX + 2] = 6400;    /* (3, 3): saturated and a "cosmic ray" */
    dq[6] = 4096;             /* (7, 1): a cosmic ray */
    const char *path = in_dir(s, "mef2.fits");
    char name[700];
    snprintf(name, sizeof name, "!%s", path);
    fitsfile *fp;
    int st = 0;
    long ax[2] = {NX, NY}, fpix[2] = {1, 1};
    fits_create_file(&fp, name, &st);
    fits_create_img(fp, DOUBLE_IMG, 2, ax, &st);
    fits_write_pix(fp, TDOUBLE, fpix, NX * NY, pix, &st);
    fits_create_img(fp, SHORT_IMG, 2, ax, &st);
    fits_update_key_str(fp, "EXTNAME", "DQ", NULL, &st);
    fits_write_pix(fp, TDOUBLE, fpix, NX * NY, dq, &st);
    fits_close_file(fp, &st);
    assert_int_equal(st, 0);
    char err[MP_ERRLEN];
    mp_frame f;
    mp_datapars dp = {NAN, NAN, NAN, NAN, "[DQ]", 2304, 4096, 1, "", 0, 0};
    assert_int_equal(mp_frame_read(path, &dp, &f, err), 0);
    assert_int_equal(f.nsat, 9);
    assert_int_equal(f.nbad, 1);
    for (int x = 2; x <= 4; x++)
        for (int y = 2; y <= 4; y++)
            assert_int_equal(f.mask[(y - 1) * NX + x - 1], MP_MASK_SATURATED);
    assert_int_equal(f.mask[6], MP_MASK_BAD);
    assert_int_equal(f.mask[5], 0);
    assert_int_equal(f.mask[NX + 6], 0);
    mp_frame_free(&f);
    /* badgrow = 1: the bad pixel's square, (6..7, 1..2) in the corner, is
     * bad (4); a saturated pixel in it, (6, 2), stays saturated, and its
     * satgrow square takes only the pixels still free, (5, 1..3), (6..7,
     * 3): with (3, 3)'s 9 that overlap at none, 9 + 1 + 5 = 15. */
    dp.badgrow = 1;
    dq[NX + 5] = 256;
    st = 0;
    fits_open_file(&fp, path, READWRITE, &st);
    fits_movnam_hdu(fp, IMAGE_HDU, "DQ", 0, &st);
    fits_write_pix(fp, TDOUBLE, fpix, NX * NY, dq, &st);
    fits_close_file(fp, &st);
    assert_int_equal(st, 0);
    assert_int_equal(mp_frame_read(path, &dp, &f, err), 0);
    assert_int_equal(f.nbad, 3);
    assert_int_equal(f.mask[5], MP_MASK_BAD);
    assert_int_equal(f.mask[6], MP_MASK_BAD);
    assert_int_equal(f.mask[NX + 6], MP_MASK_BAD);
    assert_int_equal(f.mask[NX + 5], MP_MASK_SATURATED);
    assert_int_equal(f.mask[2 * NX + 6], MP_MASK_SATURATED);
    assert_int_equal(f.mask[4], MP_MASK_SATURATED);
    assert_int_equal(f.mask[3], 0);                   /* (4, 1): in neither square */
    assert_int_equal(f.nsat, 15);
    assert_int_equal(f.mask[3 * NX + 6], 0);
    mp_frame_free(&f);
}

/* An error plane (HST layout: SCI and ERR extensions), gain 2 and read
 * noise 3 from datapars: xvar is what ERR² (in e-², gain² × ADU²) holds
 * beyond max(data, 0) + RON², and 0 where it holds less; an infinite error
 * or NaN one masks the pixel bad; a negative one on a live pixel, or a plane
 * of another shape, is refused with one line naming errplane; no errplane,
 * no xvar. */
static void test_frame_err(void **state)
{
    scratch *s = *state;
    double pix[NX * NY], e[NX * NY];
    pattern(pix);                       /* 101 ... ADU: 202 ... e- */
    for (int i = 0; i < NX * NY; i++)
        e[i] = sqrt(pix[i] / 2.0 + 25.0);   /* (2e)² = 2 pix + 100 = d + 9 + 91 e-² */
    e[1] = 1.0;                         /* less than Poisson: xvar 0 */
    e[2] = INFINITY;                    /* no weight */
    pix[3] = -50.0;                     /* a negative pixel: no Poisson part */
    e[3] = 10.0;                        /* 400 - 9 = 391 e-² */
    e[4] = 1e20;                        /* 4e40 e-²: beyond a float, no weight */
    const char *path = in_dir(s, "err.fits");
    char name[700];
    snprintf(name, sizeof name, "!%s", path);
    fitsfile *fp;
    int st = 0;
    long ax[2] = {NX, NY}, fpix[2] = {1, 1};
    fits_create_file(&fp, name, &st);
    fits_create_img(fp, 8, 0, NULL, &st);
    fits_create_img(fp, DOUBLE_IMG, 2, ax, &st);
    fits_update_key_str(fp, "EXTNAME", "SCI", NULL, &st);
    fits_write_pix(fp, TDOUBLE, fpix, NX * NY, pix, &st);
    fits_create_img(fp, DOUBLE_IMG, 2, ax, &st);
    fits_update_key_str(fp, "EXTNAME", "ERR", NULL, &st);
    fits_write_pix(fp, TDOUBLE, fpix, NX * NY, e, &st);
    e[5] = -1.0;
    fits_create_img(fp, DOUBLE_IMG, 2, ax, &st);
    fits_update_key_str(fp, "EXTNAME", "NEG", NULL, &st);
    fits_write_pix(fp, TDOUBLE, fpix, NX * NY, e, &st);
    fits_close_file(fp, &st);
    assert_int_equal(st, 0);

    char sci[720], err[MP_ERRLEN];
    snprintf(sci, sizeof sci, "%s[SCI]", path);
    mp_frame f;
    mp_datapars dp = {2.0, 3.0, NAN, NAN, "", 0, 0, 0, "[ERR]", 0, 0};
    assert_int_equal(mp_frame_read(sci, &dp, &f, err), 0);
    assert_non_null(f.xvar);
    assert_float_equal(f.xvar[0], 91.0, 1e-3);
    assert_float_equal(f.xvar[NX * NY - 1], 91.0, 1e-3);
    assert_true(f.xvar[1] == 0.0f);
    assert_int_equal(f.mask[2], MP_MASK_BAD);
    assert_int_equal(f.mask[4], MP_MASK_BAD);
    assert_int_equal(f.nbad, 2);
    assert_true(f.xvar[2] == 0.0f && f.xvar[4] == 0.0f);
    assert_float_equal(f.xvar[3], 391.0, 1e-3);
    mp_frame_free(&f);
    assert_null(f.xvar);
    /* A section applies to the plane too. */
    snprintf(sci, sizeof sci, "%s[SCI][2:5,2:3]", path);
    assert_int_equal(mp_frame_read(sci, &dp, &f, err), 0);
    assert_float_equal(f.xvar[0], 91.0, 1e-3);
    mp_frame_free(&f);
    snprintf(sci, sizeof sci, "%s[SCI]", path);
    dp.errplane[0] = 0;
    assert_int_equal(mp_frame_read(sci, &dp, &f, err), 0);
    assert_null(f.xvar);
    mp_frame_free(&f);
    snprintf(dp.errplane, sizeof dp.errplane, "[NEG]");
    assert_int_not_equal(mp_frame_read(sci, &dp, &f, err), 0);
    assert_non_null(strstr(err, "errplane"));
    assert_non_null(strstr(err, "(6, 1)"));
    assert_null(f.mask);
    assert_null(f.xvar);
    snprintf(dp.errplane, sizeof dp.errplane, "%s[SCI][1:4,1:4]", path);
    assert_int_not_equal(mp_frame_read(sci, &dp, &f, err), 0);
    assert_non_null(strstr(err, "errplane"));
    snprintf(dp.errplane, sizeof dp.errplane, "[NOPE]");
    assert_int_not_equal(mp_frame_read(sci, &dp, &f, err), 0);
    assert_non_null(strstr(err, "NOPE"));
    /* auto (the default): the file's ERR extension, section and all;
     * none: no plane; auto on a file without ERR: no plane, no error. */
    snprintf(dp.errplane, sizeof dp.errplane, "auto");
    snprintf(sci, sizeof sci, "%s[SCI][2:5,2:3]", path);
    assert_int_equal(mp_frame_read(sci, &dp, &f, err), 0);
    assert_non_null(f.xvar);
    assert_float_equal(f.xvar[0], 91.0, 1e-3);
    mp_frame_free(&f);
    snprintf(dp.errplane, sizeof dp.errplane, "none");
    assert_int_equal(mp_frame_read(sci, &dp, &f, err), 0);
    assert_null(f.xvar);
    mp_frame_free(&f);
    const char *plain = in_dir(s, "noerr.fits");
    snprintf(name, sizeof name, "!%s", plain);
    fits_create_file(&fp, name, &st);
    fits_create_img(fp, DOUBLE_IMG, 2, ax, &st);
    fits_write_pix(fp, TDOUBLE, fpix, NX * NY, pix, &st);
    fits_close_file(fp, &st);
    assert_int_equal(st, 0);
    snprintf(dp.errplane, sizeof dp.errplane, "auto");
    assert_int_equal(mp_frame_read(plain, &dp, &f, err), 0);
    assert_null(f.xvar);
    mp_frame_free(&f);
}

/* bleedgrow: a run of two or more saturated pixels along a column (a bleed)
 * grows by bleedgrow at each end, within the frame; a lone saturated pixel
 * and pixels beside the run do not.  Column 2 holds rows 2-3 saturated
 * (SATURATE 1000 ADU), column 5 only row 3. */
static void test_frame_bleed(void **state)
{
    scratch *s = *state;
    double pix[NX * NY];
    pattern(pix);
    pix[1 * NX + 1] = pix[2 * NX + 1] = 2000.0;
    pix[2 * NX + 4] = 2000.0;
    const char *path = in_dir(s, "bleed.fits");
    char err[MP_ERRLEN];
    assert_int_equal(mp_image_write(path, pix, NX, NY, -32, NULL, 0, err), 0);
    mp_datapars dp = {NAN, NAN, 1000.0, NAN, "", 0, 0, 0, "", 1, 0};
    mp_frame f;
    assert_int_equal(mp_frame_read(path, &dp, &f, err), 0);
    assert_int_equal(f.nsat, 5);
    for (int y = 1; y <= 4; y++)
        assert_int_equal(f.mask[(y - 1) * NX + 1], MP_MASK_SATURATED);
    assert_int_equal(f.mask[4 * NX + 1], 0);
    assert_int_equal(f.mask[1 * NX + 0], 0);
    assert_int_equal(f.mask[1 * NX + 4], 0);
    assert_int_equal(f.mask[3 * NX + 4], 0);
    mp_frame_free(&f);
    dp.bleedgrow = 3;       /* clipped at the frame's edges: rows 1-5 */
    assert_int_equal(mp_frame_read(path, &dp, &f, err), 0);
    assert_int_equal(f.nsat, 6);
    mp_frame_free(&f);
}

static void test_frame(void **state)
{
    scratch *s = *state;
    double pix[NX * NY];
    pattern(pix);
    pix[0] = NAN;
    pix[NX * NY - 1] = 1200;         /* above SATURATE */
    pix[NX * NY - 2] = 1000;         /* at SATURATE: saturated too */
    const mp_card cards[] = {
        {"GAIN", 2.0, NULL, NULL}, {"RDNOISE", 5.0, NULL, NULL},
        {"SATURATE", 1000.0, NULL, NULL}, {"EXPTIME", 30.0, NULL, NULL},
    };
    const char *path = in_dir(s, "frame.fits");
    char err[MP_ERRLEN];
    assert_int_equal(mp_image_write(path, pix, NX, NY, -32, cards, 4, err), 0);

    mp_frame f;
    const mp_datapars none = {NAN, NAN, NAN, NAN, "", 0, 0, 0, "", 0, 0};
    assert_int_equal(mp_frame_read(path, &none, &f, err), 0);
    assert_true(f.gain == 2.0 && f.rdnoise == 5.0 && f.saturate == 1000.0 && f.exptime == 30.0);
    assert_int_equal(f.nbad, 1);
    assert_int_equal(f.nsat, 2);
    assert_int_equal(f.mask[0], MP_MASK_BAD);
    assert_true(f.im.pix[0] == 0.0);
    assert_int_equal(f.mask[NX * NY - 1], MP_MASK_SATURATED);
    assert_int_equal(f.mask[NX * NY - 2], MP_MASK_SATURATED);
    assert_int_equal(f.mask[1], 0);
    for (int i = 1; i < NX * NY; i++)
        assert_true(f.im.pix[i] == 2.0 * pix[i]);      /* electrons */
    mp_frame_free(&f);
    mp_frame_free(&f);

    /* datapars wins over the header; NULL datapars means all from header. */
    const mp_datapars dp = {4.0, 1.0, NAN, 2.0, "", 0, 0, 0, "", 0, 0};
    assert_int_equal(mp_frame_read(path, &dp, &f, err), 0);
    assert_true(f.gain == 4.0 && f.rdnoise == 1.0 && f.saturate == 1000.0 && f.exptime == 2.0);
    assert_true(f.im.pix[5] == 4.0 * pix[5]);
    mp_frame_free(&f);
    assert_int_equal(mp_frame_read(path, NULL, &f, err), 0);
    assert_true(f.gain == 2.0);
    mp_frame_free(&f);

    /* No keywords: the defaults. */
    const char *bare = in_dir(s, "bare.fits");
    assert_int_equal(mp_image_write(bare, pix, NX, NY, -32, NULL, 0, err), 0);
    assert_int_equal(mp_frame_read(bare, &none, &f, err), 0);
    assert_true(f.gain == 1.0 && f.rdnoise == 0.0 && isinf(f.saturate) && f.exptime == 1.0);
    assert_int_equal(f.nsat, 0);
    mp_frame_free(&f);

    /* Bad detector numbers, named. */
    const mp_datapars badgain = {0.0, NAN, NAN, NAN, "", 0, 0, 0, "", 0, 0};
    assert_int_not_equal(mp_frame_read(path, &badgain, &f, err), 0);
    assert_true(strncmp(err, "gain: ", 6) == 0);
    assert_null(f.mask);
    const mp_datapars badron = {NAN, -1.0, NAN, NAN, "", 0, 0, 0, "", 0, 0};
    assert_int_not_equal(mp_frame_read(path, &badron, &f, err), 0);
    assert_true(strncmp(err, "rdnoise: ", 9) == 0);
    const mp_card neg[] = {{"GAIN", -2.0, NULL, NULL}};
    const char *negp = in_dir(s, "neg.fits");
    assert_int_equal(mp_image_write(negp, pix, NX, NY, -32, neg, 1, err), 0);
    assert_int_not_equal(mp_frame_read(negp, &none, &f, err), 0);
    assert_non_null(strstr(err, "neg.fits"));
    assert_non_null(strstr(err, "GAIN"));
    const mp_card text[] = {{"RDNOISE", 0, "high", NULL}};
    assert_int_equal(mp_image_write(negp, pix, NX, NY, -32, text, 1, err), 0);
    assert_int_not_equal(mp_frame_read(negp, &none, &f, err), 0);
    assert_non_null(strstr(err, "RDNOISE"));
    /* A value whose electrons a float cannot hold (1e30 ADU at 1e10
     * e-/ADU) is masked bad as a NaN is, not passed on as infinite (the
     * frame fuzzer's finding); the others are scaled as ever. */
    double big[NX * NY];
    pattern(big);
    big[4] = 1e30;
    const char *bigp = in_dir(s, "big.fits");
    assert_int_equal(mp_image_write(bigp, big, NX, NY, -32, NULL, 0, err), 0);
    const mp_datapars huge = {1e10, NAN, NAN, NAN, "", 0, 0, 0, "", 0, 0};
    assert_int_equal(mp_frame_read(bigp, &huge, &f, err), 0);
    assert_int_equal(f.nbad, 1);
    assert_int_equal(f.mask[4], MP_MASK_BAD);
    assert_true(f.im.pix[4] == 0.0f);
    assert_true(f.im.pix[5] == (float)(1e10 * big[5]));
    mp_frame_free(&f);
    /* Read errors pass through. */
    assert_int_not_equal(mp_frame_read(in_dir(s, "nope.fits"), &none, &f, err), 0);
    assert_non_null(strstr(err, "nope.fits"));
}

/* ---------- output files ---------- */

static void test_outfile(void **state)
{
    scratch *s = *state;
    char err[MP_ERRLEN];
    char path[700];
    snprintf(path, sizeof path, "%s/out.txt", s->dir);

    char *tmp = mp_tmp_name(path);
    assert_non_null(tmp);
    /* ".out.txt.tmp.<host>.<pid>" beside the output */
    char want[800], pidtail[40];
    snprintf(want, sizeof want, "%s/.out.txt.tmp.", s->dir);
    snprintf(pidtail, sizeof pidtail, ".%ld", (long)getpid());
    assert_int_equal(strncmp(tmp, want, strlen(want)), 0);
    size_t lt = strlen(tmp), lp = strlen(pidtail);
    assert_true(lt > strlen(want) + lp && strcmp(tmp + lt - lp, pidtail) == 0);
    char *bare = mp_tmp_name("x.fits");
    assert_int_equal(strncmp(bare, ".x.fits.tmp.", 12), 0);
    free(bare);

    /* Abort: neither the output nor the temporary remains. */
    mp_outfile o;
    assert_int_equal(mp_out_open(&o, path, err), 0);
    assert_false(o.is_stdout);
    fputs("partial\n", o.fp);
    assert_true(exists(tmp));
    assert_false(exists(path));
    mp_out_abort(&o);
    assert_false(exists(tmp));
    assert_false(exists(path));
    mp_out_abort(&o);                      /* safe on a spent outfile */

    /* Commit: the temporary becomes the output. */
    assert_int_equal(mp_out_open(&o, path, err), 0);
    fputs("complete\n", o.fp);
    assert_int_equal(mp_out_commit(&o, err), 0);
    assert_false(exists(tmp));
    FILE *fp = mp_open_input(path, err);
    assert_non_null(fp);
    char line[32] = "";
    assert_non_null(fgets(line, sizeof line, fp));
    assert_string_equal(line, "complete\n");
    mp_close_input(fp);

    /* A second commit replaces the first atomically. */
    assert_int_equal(mp_out_open(&o, path, err), 0);
    fputs("second\n", o.fp);
    fp = fopen(path, "r");                 /* the old file is still whole */
    assert_non_null(fgets(line, sizeof line, fp));
    assert_string_equal(line, "complete\n");
    fclose(fp);
    assert_int_equal(mp_out_commit(&o, err), 0);
    fp = fopen(path, "r");
    assert_non_null(fgets(line, sizeof line, fp));
    assert_string_equal(line, "second\n");
    fclose(fp);
    free(tmp);

    /* Cannot create: names the file and the reason. */
    char nodir[800];
    snprintf(nodir, sizeof nodir, "%s/missing/out.txt", s->dir);
    assert_int_not_equal(mp_out_open(&o, nodir, err), 0);
    assert_non_null(strstr(err, nodir));
    assert_non_null(strstr(err, "No such file or directory"));
    assert_null(o.fp);

    /* "-" and NULL are stdout / stdin. */
    assert_int_equal(mp_out_open(&o, "-", err), 0);
    assert_true(o.is_stdout && o.fp == stdout);
    assert_int_equal(mp_out_commit(&o, err), 0);
    assert_int_equal(mp_out_open(&o, NULL, err), 0);
    assert_true(o.is_stdout);
    mp_out_abort(&o);
    assert_true(mp_open_input("-", err) == stdin);
    mp_close_input(stdin);                 /* a no-op: stdin stays open */
    assert_int_equal(fileno(stdin), 0);

    /* Missing input: NULL and a message. */
    assert_null(mp_open_input(in_dir(s, "absent.txt"), err));
    assert_non_null(strstr(err, "absent.txt"));
    assert_int_equal(count_files(s), 1);   /* only out.txt */
}

/* mp_out_copy: the same bytes under the new name (more than one 64 KiB
 * buffer of them, with NULs), nothing left behind; a missing source is
 * an error naming it, and the older copy stays whole. */
static void test_out_copy(void **state)
{
    scratch *s = *state;
    char err[MP_ERRLEN], from[700], to[700];
    snprintf(from, sizeof from, "%s/a.fit", s->dir);
    snprintf(to, sizeof to, "%s/a.cat", s->dir);
    size_t n = 200000;
    unsigned char *b = malloc(n), *got = malloc(n + 1);
    assert_non_null(b);
    assert_non_null(got);
    for (size_t i = 0; i < n; i++)
        b[i] = (unsigned char)(i * 2654435761u >> 13);
    FILE *fp = fopen(from, "wb");
    assert_int_equal(fwrite(b, 1, n, fp), n);
    fclose(fp);
    assert_int_equal(mp_out_copy(from, to, err), 0);
    fp = fopen(to, "rb");
    assert_non_null(fp);
    assert_int_equal(fread(got, 1, n + 1, fp), n);
    fclose(fp);
    assert_memory_equal(got, b, n);
    assert_int_equal(count_files(s), 2);
    char gone[700];
    snprintf(gone, sizeof gone, "%s/none.fit", s->dir);
    assert_int_not_equal(mp_out_copy(gone, to, err), 0);
    assert_non_null(strstr(err, gone));
    fp = fopen(to, "rb");
    assert_int_equal(fread(got, 1, n + 1, fp), n);
    fclose(fp);
    assert_int_equal(count_files(s), 2);
    free(b);
    free(got);
}

/* A killed run's temporary (its pid gone, this host) is swept when the
 * output is next written; a live process's and another host's stay. */
static void test_tmp_sweep(void **state)
{
    scratch *s = *state;
    char path[700], prefix[800], dead[900], live[900], other[900];
    snprintf(path, sizeof path, "%s/swept.cat", s->dir);
    char *mine = mp_tmp_name(path);
    assert_non_null(mine);
    size_t l = strrchr(mine, '.') - mine + 1;          /* up to "<host>." */
    snprintf(prefix, sizeof prefix, "%.*s", (int)l, mine);
    pid_t child = fork();
    assert_true(child >= 0);
    if (child == 0)
        _exit(0);
    waitpid(child, NULL, 0);                           /* now a dead pid */
    snprintf(dead, sizeof dead, "%s%ld", prefix, (long)child);
    snprintf(live, sizeof live, "%s%ld", prefix, (long)getppid());
    snprintf(other, sizeof other, "%s/.swept.cat.tmp.elsewhere-node.%ld", s->dir, (long)child);
    /* Another output's temporary of the same dead run: one listing of
     * the directory removes every stale temporary in it. */
    char dead2[900];
    const char *host = strstr(mine, ".tmp.") + 5;       /* "<host>.<pid>" */
    snprintf(dead2, sizeof dead2, "%s/.other.fit.tmp.%.*s%ld", s->dir,
             (int)(strrchr(mine, '.') + 1 - host), host, (long)child);
    const char *const made[] = {dead, live, other, dead2};
    for (int i = 0; i < 4; i++) {
        FILE *fp = fopen(made[i], "w");
        assert_non_null(fp);
        fclose(fp);
    }
    mp_sweeps *sw = mp_sweeps_new();
    assert_non_null(sw);
    assert_int_equal(mp_tmp_sweep(sw, path), 1);
    assert_false(exists(dead));
    assert_false(exists(dead2));
    assert_true(exists(live));
    assert_true(exists(other));
    /* Writing itself no longer lists the directory: 50 outputs into it
     * after the sweep, one listing in all (issue 14: was one a write). */
    char err[MP_ERRLEN];
    for (int k = 0; k < 50; k++) {
        char out[800];
        snprintf(out, sizeof out, "%s/out%02d.txt", s->dir, k);
        assert_int_equal(mp_tmp_sweep(sw, out), 0);
        mp_outfile o;
        assert_int_equal(mp_out_open(&o, out, err), 0);
        fputs("x\n", o.fp);
        assert_int_equal(mp_out_commit(&o, err), 0);
        unlink(out);
    }
    assert_int_equal(mp_sweeps_listed(sw), 1);
    /* Another directory is listed once too; stdout never. */
    char sub[800], inner[900];
    snprintf(sub, sizeof sub, "%s/sub", s->dir);
    assert_int_equal(mkdir(sub, 0700), 0);
    snprintf(inner, sizeof inner, "%s/a.cat", sub);
    assert_int_equal(mp_tmp_sweep(sw, inner), 1);
    assert_int_equal(mp_tmp_sweep(sw, inner), 0);
    assert_int_equal(mp_tmp_sweep(sw, "-"), 0);
    assert_int_equal(mp_sweeps_listed(sw), 2);
    mp_sweeps_free(sw);
    /* No set: every call lists. */
    assert_int_equal(mp_tmp_sweep(NULL, inner), 1);
    assert_int_equal(mp_tmp_sweep(NULL, inner), 1);
    rmdir(sub);
    unlink(live);
    unlink(other);
    free(mine);
}

/* mp_fits_key_number reads a keyword's card itself: plain, quoted and
 * D-exponent numbers as cfitsio reads them; garbage and a logical as
 * BAD_C2D (cfitsio's own conversion aborts on a long garbage value, the
 * fuzz regression psf_field/nypsfs_long_garbage_value); an absent key as
 * KEY_NO_EXIST; a status set on entry left alone. */
/* The guard's walk over a header whose sizes are absurd (found by
 * tests/fuzz/fuzz_psf_field: PCOUNT = 2⁶³ − 1 overflowed the data size, a
 * signed overflow UBSan stops on): it stops walking and leaves the file to
 * cfitsio (0), and a bad string card in the next header is then not seen;
 * with PCOUNT sane the walk reaches that card (1).  The teeth are the
 * sanitizer build's. */
static void test_guard_absurd_sizes(void **state)
{
    (void)state;
    static const char *cards[] = {"SIMPLE  =                    T", "BITPIX  =                    8",
                                  "NAXIS   =                    1", "NAXIS1  =                   10",
                                  NULL, "GCOUNT  =                    1", "END"};
    const char *pc[2] = {"PCOUNT  =  9223372036854775807", "PCOUNT  =                    0"};
    for (int k = 0; k < 2; k++) {
        unsigned char b[3 * 2880];
        memset(b, ' ', sizeof b);
        for (int c = 0; c < 7; c++) {
            const char *t = cards[c] ? cards[c] : pc[k];
            memcpy(b + 80 * c, t, strlen(t));
        }
        /* the data area (one record), then an extension with a broken
         * XTENSION string */
        const char *x = "XTENSION= 'IMAGE";
        memcpy(b + 2 * 2880, x, strlen(x));
        memcpy(b + 2 * 2880 + 80, "END", 3);
        char why[MP_GUARD_LEN];
        assert_int_equal(mp_fits_guard_mem(b, sizeof b, why), k);
    }
}

/* A structural keyword whose '=' is not in column 9 (found by
 * tests/fuzz/fuzz_psf_field: "TTYPE7  l=" then 70 bytes of garbage, which
 * cfitsio reads as a long keyword name and copies into a 70-byte buffer:
 * glibc aborts) is refused; a commentary card holding '=' is not. */
static void test_guard_misplaced_equals(void **state)
{
    (void)state;
    const char *odd[2] = {"TTYPE7  l= 'abcdefghijklmnopqrstuvwxyz'", "COMMENT a = b"};
    for (int k = 0; k < 2; k++) {
        unsigned char b[2880];
        memset(b, ' ', sizeof b);
        const char *cards[] = {"SIMPLE  =                    T", "BITPIX  =                    8",
                               "NAXIS   =                    0", odd[k], "END"};
        for (int c = 0; c < 5; c++)
            memcpy(b + 80 * c, cards[c], strlen(cards[c]));
        char why[MP_GUARD_LEN];
        assert_int_equal(mp_fits_guard_mem(b, sizeof b, why), k == 0);
    }
}

/* An output is refused when it is one of the run's inputs, by any
 * spelling (an [extension], "./", a hard link); not when it does not
 * exist yet, is stdout, or is another file; inputs "-", "", INDEF and a
 * frame's own "[DQ]" name no file. */
static void test_out_overwrites(void **state)
{
    scratch *s = *state;
    char a[700], b[700], hl[700], dot[720], ext[720], missing[700], err[MP_ERRLEN];
    snprintf(a, sizeof a, "%s", in_dir(s, "a.fits"));
    snprintf(b, sizeof b, "%s", in_dir(s, "b.fits"));
    snprintf(hl, sizeof hl, "%s", in_dir(s, "hard.fits"));
    snprintf(missing, sizeof missing, "%s", in_dir(s, "new.fits"));
    snprintf(dot, sizeof dot, "%s/./a.fits", s->dir);
    snprintf(ext, sizeof ext, "%s[SCI][1:10,1:10]", a);
    double px[4] = {1, 2, 3, 4};
    assert_int_equal(mp_image_write(a, px, 2, 2, -32, NULL, 0, err), 0);
    assert_int_equal(mp_image_write(b, px, 2, 2, -32, NULL, 0, err), 0);
    assert_int_equal(link(a, hl), 0);
    const char *in[5] = {"-", "", "INDEF", "[DQ]", ext};
    mp_inputs *none = mp_inputs_of(in, 4), *all = mp_inputs_of(in, 5);
    assert_non_null(none);
    assert_non_null(all);
    err[0] = '\0';
    assert_int_equal(mp_out_overwrites(none, a, err), 0);      /* none names a file */
    assert_int_equal(mp_out_overwrites(all, b, err), 0);       /* another file */
    assert_int_equal(mp_out_overwrites(all, missing, err), 0);
    assert_int_equal(mp_out_overwrites(all, "-", err), 0);
    assert_string_equal(err, "");
    assert_int_equal(mp_out_overwrites(all, a, err), 1);
    assert_non_null(strstr(err, "(the same file)"));
    assert_null(strchr(err, '\n'));
    assert_int_equal(mp_out_overwrites(all, dot, err), 1);
    assert_int_equal(mp_out_overwrites(all, hl, err), 1);
    const char *same[1] = {a}, *outs[3] = {missing, b, a};
    assert_int_equal(mp_outputs_clear(same, 1, outs, 2, err), 0);
    assert_int_equal(mp_outputs_clear(same, 1, outs, 3, err), 1);
    assert_non_null(strstr(err, "a.fits: named as an output, but it is this run's input: "));
    mp_inputs_free(none);
    mp_inputs_free(all);
}

/* Where a temporary goes: beside its output (rename() is atomic there),
 * but in TMPDIR for an output written in place (a device, a FIFO, a
 * name under /dev/), whose folder it would need root to write to and
 * whose device it would be renamed over. */
static void test_tmp_name_in_place(void **state)
{
    scratch *s = *state;
    char fifo[700], reg[700], want[800];
    snprintf(fifo, sizeof fifo, "%s", in_dir(s, "pipe"));
    snprintf(reg, sizeof reg, "%s", in_dir(s, "plain.coo"));
    assert_int_equal(mkfifo(fifo, 0600), 0);
    FILE *fp = fopen(reg, "w");
    assert_non_null(fp);
    fclose(fp);
    assert_int_equal(mp_out_in_place("/dev/null"), 1);
    assert_int_equal(mp_out_in_place("/dev/stdout"), 1);
    assert_int_equal(mp_out_in_place(fifo), 1);
    assert_int_equal(mp_out_in_place(reg), 0);
    assert_int_equal(mp_out_in_place("not/yet/written.coo"), 0);
    char *old = getenv("TMPDIR") ? strdup(getenv("TMPDIR")) : NULL;
    assert_int_equal(setenv("TMPDIR", s->dir, 1), 0);
    const char *paths[4] = {"/dev/null", fifo, "dir/f.coo", "f.coo"};
    for (int k = 0; k < 4; k++) {
        char *t = mp_tmp_name(paths[k]);
        assert_non_null(t);
        if (k < 2)
            snprintf(want, sizeof want, "%s/.%s.tmp.", s->dir, k ? "pipe" : "null");
        else
            snprintf(want, sizeof want, "%s.f.coo.tmp.", k == 2 ? "dir/" : "");
        if (strncmp(t, want, strlen(want)) != 0)
            print_error("mp_tmp_name(%s) = %s, want %s...\n", paths[k], t, want);
        assert_int_equal(strncmp(t, want, strlen(want)), 0);
        free(t);
    }
    if (old)
        setenv("TMPDIR", old, 1);
    else
        unsetenv("TMPDIR");
    free(old);
}

static void test_key_number(void **state)
{
    (void)state;
    char path[] = "/tmp/test_key_number.XXXXXX";
    int fd = mkstemp(path);
    assert_true(fd >= 0);
    close(fd);
    char name[64];
    snprintf(name, sizeof name, "!%s", path);
    fitsfile *fp;
    int st = 0;
    fits_create_file(&fp, name, &st);
    fits_create_img(fp, FLOAT_IMG, 0, NULL, &st);
    fits_write_record(fp, "PLAIN   =                   4.5", &st);
    fits_write_record(fp, "QUOTED  = '12      '", &st);
    fits_write_record(fp, "FORTRAN =               1.5D2", &st);
    fits_write_record(fp, "GARBAGE = ZZZZZZZZZZZZZZZZZZZZZZZZZZZZZZZZZZZZZZZZZZZZZZZZZZZZZZZZZZZZZZZZZZZZ", &st);
    fits_write_record(fp, "LOGIC   =                    T", &st);
    assert_int_equal(st, 0);
    const struct { const char *key; int status; double v; } cases[] = {
        {"PLAIN", 0, 4.5}, {"QUOTED", 0, 12.0}, {"FORTRAN", 0, 150.0},
        {"GARBAGE", BAD_C2D, -1.0}, {"LOGIC", BAD_C2D, -1.0}, {"ABSENT", KEY_NO_EXIST, -1.0}};
    for (size_t c = 0; c < sizeof cases / sizeof cases[0]; c++) {
        double v = -1.0;
        st = 0;
        assert_int_equal(mp_fits_key_number(fp, cases[c].key, &v, &st), cases[c].status);
        assert_int_equal(st, cases[c].status);
        assert_true(v == cases[c].v);
        fits_clear_errmsg();
    }
    double v = -1.0;
    st = 7;
    assert_int_equal(mp_fits_key_number(fp, "PLAIN", &v, &st), 7);
    assert_true(v == -1.0);
    st = 0;
    fits_close_file(fp, &st);
    unlink(path);
}

/* mp_within answers as hypot(dx, dy) <= r does, everywhere: on circles
 * through whole pixels (3-4-5 and the like, where the squares are exact),
 * one ulp either side of r, at fractional offsets, and for NaN, infinite,
 * zero and negative radii. */
static void test_within_is_hypot(void **state)
{
    (void)state;
    const double rs[] = {0.0, 1.0, 2.5, 3.0, 5.0, 7.071067811865476, 12.0, 1e-200, 1e200,
                         INFINITY, NAN, -1.0};
    long n = 0;
    for (size_t k = 0; k < sizeof rs / sizeof *rs; k++)
        for (int s = -1; s <= 1; s++) {
            double r = s < 0 ? nextafter(rs[k], 0.0) : s > 0 ? nextafter(rs[k], INFINITY) : rs[k];
            for (int j = -13; j <= 13; j++)
                for (int i = -13; i <= 13; i++)
                    for (int f = 0; f < 3; f++) {
                        double dx = i + (f == 1 ? 0.37 : 0.0), dy = j - (f == 2 ? 0.5 : 0.0);
                        assert_int_equal(mp_within(dx, dy, r), hypot(dx, dy) <= r);
                        n++;
                    }
        }
    const double odd[][3] = {{NAN, 0, 1}, {INFINITY, 0, 1e300}, {1e200, 1e200, 1.5e200},
                             {1e-200, 0, 1e-200}, {3e-160, 4e-160, 5e-160}};
    for (size_t k = 0; k < sizeof odd / sizeof *odd; k++)
        assert_int_equal(mp_within(odd[k][0], odd[k][1], odd[k][2]),
                         hypot(odd[k][0], odd[k][1]) <= odd[k][2]);
    assert_true(n > 20000);
}

int main(void)
{
    const struct CMUnitTest tests[] = {
        cmocka_unit_test_setup_teardown(test_round_trip, setup, teardown),
        cmocka_unit_test(test_header_parsing),
        cmocka_unit_test_setup_teardown(test_sections_and_hdus, setup, teardown),
        cmocka_unit_test_setup_teardown(test_compressed_image, setup, teardown),
        cmocka_unit_test_setup_teardown(test_gzip_headers_walked, setup, teardown),
        cmocka_unit_test_setup_teardown(test_out_overwrites, setup, teardown),
        cmocka_unit_test_setup_teardown(test_tmp_name_in_place, setup, teardown),
        cmocka_unit_test_setup_teardown(test_bad_inputs, setup, teardown),
        cmocka_unit_test_setup_teardown(test_frame, setup, teardown),
        cmocka_unit_test_setup_teardown(test_frame_dq, setup, teardown),
        cmocka_unit_test_setup_teardown(test_frame_dq_saturation_first, setup, teardown),
        cmocka_unit_test_setup_teardown(test_frame_err, setup, teardown),
        cmocka_unit_test_setup_teardown(test_frame_bleed, setup, teardown),
        cmocka_unit_test_setup_teardown(test_outfile, setup, teardown),
        cmocka_unit_test_setup_teardown(test_out_copy, setup, teardown),
        cmocka_unit_test_setup_teardown(test_tmp_sweep, setup, teardown),
        cmocka_unit_test(test_key_number),
        cmocka_unit_test(test_guard_absurd_sizes),
        cmocka_unit_test(test_guard_misplaced_equals),
        cmocka_unit_test(test_within_is_hypot),
    };
    return cmocka_run_group_tests(tests, NULL, NULL);
}
