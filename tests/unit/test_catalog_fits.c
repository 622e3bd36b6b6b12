/*
 * test_catalog_fits.c — catalog/: FITS_1.0 and FITS_LDAC tables (layout
 * checked with cfitsio directly: HDUs, EXTNAMEs, TTYPE/TFORM/TUNIT/TDISP,
 * the LDAC_IMHEAD card array, values bit for bit), reading them back
 * through mp_table_read, atomic writes, and DS9 region files.
 */
#include <stdarg.h>
#include <stddef.h>
#include <stdint.h>
#include <setjmp.h>
#include <cmocka.h>

#include <dirent.h>
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/stat.h>
#include <unistd.h>
#include <fitsio.h>

#include "catalog/catalog.h"
#include "io/io.h"

/* ---- helpers ---------------------------------------------------------- */

typedef struct {
    char dir[256];
} fixture;

static void remove_tree(const char *dir)
{
    DIR *d = opendir(dir);
    if (!d)
        return;
    struct dirent *e;
    char p[600];
    while ((e = readdir(d)) != NULL) {
        if (strcmp(e->d_name, ".") == 0 || strcmp(e->d_name, "..") == 0)
            continue;
        snprintf(p, sizeof p, "%s/%s", dir, e->d_name);
        struct stat sb;
        if (lstat(p, &sb) == 0 && S_ISDIR(sb.st_mode))
            remove_tree(p);
        else
            unlink(p);
    }
    closedir(d);
    rmdir(dir);
}

static int setup(void **state)
{
    fixture *f = calloc(1, sizeof *f);
    if (!f)
        return -1;
    const char *tmp = getenv("TMPDIR");
    snprintf(f->dir, sizeof f->dir, "%s/test_catalog_fits.XXXXXX", tmp && *tmp ? tmp : "/tmp");
    if (!mkdtemp(f->dir)) {
        free(f);
        return -1;
    }
    *state = f;
    return 0;
}

static int teardown(void **state)
{
    fixture *f = *state;
    remove_tree(f->dir);
    free(f);
    return 0;
}

static void path_in(const fixture *f, const char *name, char *out, size_t n)
{
    snprintf(out, n, "%s/%s", f->dir, name);
}

static int count_entries(const char *dir)
{
    DIR *d = opendir(dir);
    assert_non_null(d);
    int n = 0;
    struct dirent *e;
    while ((e = readdir(d)) != NULL)
        if (strcmp(e->d_name, ".") && strcmp(e->d_name, ".."))
            n++;
    closedir(d);
    return n;
}

/* Same bits (so NaN == NaN and -0 != +0). */
static int same_bits(double a, double b)
{
    return memcmp(&a, &b, sizeof a) == 0;
}

/* A fit-like table: integer, position, flux and flag columns, values that
 * need all 17 digits, a NaN in a D column and one in an integer column. */
static void fit_table(mp_table *t, int with_int_nan)
{
    mp_table_init(t);
    const char *names[] = {"NUMBER", "XPSF_IMAGE", "YPSF_IMAGE", "FLUX_PSF", "MAG_PSF",
                           "GROUP_ID", "FLAGS", "MY_EXTRA"};
    for (int c = 0; c < 8; c++)
        assert_int_equal(mp_table_add_col(t, names[c]), c);
    for (int r = 0; r < 5; r++) {
        assert_int_equal(mp_table_add_row(t), r);
        mp_table_set(t, r, 0, r + 1);
        mp_table_set(t, r, 1, 1.0 + (r + 1) / 3.0 + 1e-13);
        mp_table_set(t, r, 2, 1000.0 * M_PI / (r + 7));
        mp_table_set(t, r, 3, r == 3 ? 1e-300 : 12345.678901234567 * exp(r));
        mp_table_set(t, r, 4, -2.5 * log10(12345.678901234567 * exp(r)));
        mp_table_set(t, r, 5, 100 + r / 2);
        mp_table_set(t, r, 6, r == 4 ? 40 : 0);
        mp_table_set(t, r, 7, sqrt(2.0) * r);
    }
    mp_table_set(t, 2, 3, NAN);
    if (with_int_nan)
        mp_table_set(t, 1, 5, NAN);
}

static void read_str_key(fitsfile *fp, const char *key, char *val)
{
    int st = 0;
    char comm[FLEN_COMMENT];
    if (fits_read_key_str(fp, key, val, comm, &st))
        fail_msg("keyword %s: cfitsio status %d", key, st);
}

/* Check the objects HDU (the current one) against t, with cfitsio. */
static void check_objects(fitsfile *fp, const mp_table *t, const char *extname)
{
    char val[FLEN_VALUE], key[FLEN_KEYWORD];
    int st = 0, hdutype;
    fits_get_hdu_type(fp, &hdutype, &st);
    assert_int_equal(hdutype, BINARY_TBL);
    read_str_key(fp, "EXTNAME", val);
    assert_string_equal(val, extname);
    int ncol;
    LONGLONG nrow;
    fits_get_num_cols(fp, &ncol, &st);
    fits_get_num_rowsll(fp, &nrow, &st);
    assert_int_equal(st, 0);
    assert_int_equal(ncol, (int)t->ncol);
    assert_int_equal(nrow, (LONGLONG)t->nrow);
    for (size_t c = 0; c < t->ncol; c++) {
        const mp_col *col = &t->cols[c];
        char comm[FLEN_COMMENT];
        snprintf(key, sizeof key, "TTYPE%zu", c + 1);
        assert_int_equal(fits_read_key_str(fp, key, val, comm, &st), 0);
        assert_string_equal(val, col->name);
        if (col->desc[0])   /* the description, cut to the card if long */
            assert_int_equal(strncmp(col->desc, comm, strlen(comm)), 0);
        snprintf(key, sizeof key, "TUNIT%zu", c + 1);
        int st2 = 0;
        if (col->unit[0]) {
            read_str_key(fp, key, val);
            assert_string_equal(val, col->unit);
        } else {
            assert_int_not_equal(fits_read_key_str(fp, key, val, NULL, &st2), 0);
            fits_clear_errmsg();
        }
        int code;
        long repeat, width;
        assert_int_equal(fits_get_coltype(fp, (int)c + 1, &code, &repeat, &width, &st), 0);
        assert_int_equal(repeat, 1);
        const char *nm = col->name;
        int want = strcmp(nm, "FLAGS") == 0 ? TSHORT
                 : (!strcmp(nm, "NUMBER") || !strcmp(nm, "GROUP_ID")) ? TLONG : TDOUBLE;
        if (code != want)
            fail_msg("%s: cfitsio type %d, expected %d", nm, code, want);
        /* Every value, bit for bit (integers exactly; NaN as NaN). */
        double *v = malloc((t->nrow ? t->nrow : 1) * sizeof *v);
        assert_non_null(v);
        double nulval = NAN;
        int anynul = 0;
        assert_int_equal(fits_read_col(fp, TDOUBLE, (int)c + 1, 1, 1, nrow, &nulval, v,
                                       &anynul, &st), 0);
        for (size_t r = 0; r < t->nrow; r++) {
            double want_v = mp_table_get(t, r, (int)c);
            if (!same_bits(v[r], want_v) && !(isnan(v[r]) && isnan(want_v)))
                fail_msg("%s row %zu: wrote %.17g, read %.17g", nm, r, want_v, v[r]);
        }
        free(v);
    }
    /* SExtractor's TDISP from the printf format. */
    int cx = mp_table_col(t, "XPSF_IMAGE"), cn = mp_table_col(t, "NUMBER");
    snprintf(key, sizeof key, "TDISP%d", cx + 1);
    read_str_key(fp, key, val);
    assert_string_equal(val, "F11.5");
    snprintf(key, sizeof key, "TDISP%d", cn + 1);
    read_str_key(fp, key, val);
    assert_string_equal(val, "I10");
}

static fitsfile *open_fits(const char *path, int *nhdu)
{
    fitsfile *fp = NULL;
    int st = 0;
    if (fits_open_file(&fp, path, READONLY, &st))
        fail_msg("%s: cannot open, cfitsio status %d", path, st);
    fits_get_num_hdus(fp, nhdu, &st);
    int naxis = -1;
    fits_get_img_dim(fp, &naxis, &st);   /* primary HDU: empty */
    assert_int_equal(st, 0);
    assert_int_equal(naxis, 0);
    return fp;
}

/* ---- FITS_1.0 ----------------------------------------------------------- */

static void test_fits10_layout(void **state)
{
    fixture *f = *state;
    char path[512], err[MP_ERRLEN] = "";
    path_in(f, "cat.fits", path, sizeof path);
    mp_table t;
    fit_table(&t, 1);
    if (mp_table_write(path, &t, MP_TAB_FITS, err))
        fail_msg("%s", err);
    int nhdu, st = 0, type;
    fitsfile *fp = open_fits(path, &nhdu);
    assert_int_equal(nhdu, 2);
    fits_movabs_hdu(fp, 2, &type, &st);
    check_objects(fp, &t, "OBJECTS");
    /* The integer NaN became TNULL (J: its smallest value). */
    char val[FLEN_VALUE];
    read_str_key(fp, "TNULL6", val);
    assert_string_equal(val, "-2147483648");
    fits_close_file(fp, &st);

    /* Nothing left behind but the file. */
    assert_int_equal(count_entries(f->dir), 1);
    mp_table_free(&t);
}

static void test_fits_read_back(void **state)
{
    fixture *f = *state;
    char path[512], err[MP_ERRLEN] = "";
    mp_table t, b;
    fit_table(&t, 1);
    for (int fmt = MP_TAB_FITS; fmt <= MP_TAB_LDAC; fmt++) {
        path_in(f, fmt == MP_TAB_FITS ? "rb.fits" : "rb.ldac", path, sizeof path);
        if (mp_table_write(path, &t, (mp_table_format)fmt, err))
            fail_msg("%s", err);
        if (mp_table_read(path, &b, err))
            fail_msg("%s", err);
        assert_int_equal(b.ncol, t.ncol);
        assert_int_equal(b.nrow, t.nrow);
        for (size_t c = 0; c < t.ncol; c++) {
            assert_string_equal(b.cols[c].name, t.cols[c].name);
            assert_string_equal(b.cols[c].desc, t.cols[c].desc);
            assert_string_equal(b.cols[c].unit, t.cols[c].unit);
            assert_string_equal(b.cols[c].fmt, t.cols[c].fmt);
            assert_int_equal(b.cols[c].is_int, t.cols[c].is_int);
            for (size_t r = 0; r < t.nrow; r++) {
                double w = mp_table_get(&t, r, (int)c), g = mp_table_get(&b, r, (int)c);
                if (!same_bits(w, g) && !(isnan(w) && isnan(g)))
                    fail_msg("%s row %zu: %.17g → %.17g", t.cols[c].name, r, w, g);
            }
        }
        mp_table_free(&b);
    }
    mp_table_free(&t);
}

/* Integer columns widen to K past 32 bits; a fraction makes them D. */
static void test_integer_widths(void **state)
{
    fixture *f = *state;
    char path[512], err[MP_ERRLEN] = "";
    path_in(f, "wide.fits", path, sizeof path);
    mp_table t;
    mp_table_init(&t);
    assert_int_equal(mp_table_add_col(&t, "NUMBER"), 0);
    assert_int_equal(mp_table_add_col(&t, "GROUP_ID"), 1);
    assert_int_equal(mp_table_add_col(&t, "FLAGS"), 2);
    for (int r = 0; r < 3; r++)
        assert_int_equal(mp_table_add_row(&t), r);
    mp_table_set(&t, 0, 0, 12345678901.0);
    mp_table_set(&t, 1, 0, -4.0);
    mp_table_set(&t, 2, 0, 9007199254740993.0);   /* rounds to 2^53 as a double */
    mp_table_set(&t, 0, 1, 1.5);
    mp_table_set(&t, 0, 2, 70000);                /* FLAGS past 16 bits: J */
    if (mp_table_write(path, &t, MP_TAB_FITS, err))
        fail_msg("%s", err);
    int nhdu, st = 0, type;
    fitsfile *fp = open_fits(path, &nhdu);
    fits_movabs_hdu(fp, 2, &type, &st);
    char val[FLEN_VALUE];
    read_str_key(fp, "TFORM1", val);
    assert_string_equal(val, "1K");
    read_str_key(fp, "TFORM2", val);
    assert_string_equal(val, "1D");
    read_str_key(fp, "TFORM3", val);
    assert_string_equal(val, "1J");
    LONGLONG k[3];
    long long nul = 0;
    int anynul;
    assert_int_equal(fits_read_col(fp, TLONGLONG, 1, 1, 1, 3, &nul, k, &anynul, &st), 0);
    assert_true(k[0] == 12345678901LL && k[1] == -4 && k[2] == 9007199254740992LL);
    fits_close_file(fp, &st);
    mp_table_free(&t);
}

/* Every header size: cfitsio 4.2 fails to insert a keyword after the last
 * one when END has just moved into a new 2880-byte block, so each count of
 * columns (with and without units and TNULLs) must write and read back. */
static void test_header_sizes(void **state)
{
    fixture *f = *state;
    char path[512], err[MP_ERRLEN] = "";
    path_in(f, "sizes.fits", path, sizeof path);
    for (int nc = 1; nc <= 80; nc++)
        for (int variant = 0; variant < 4; variant++) {
            mp_table t, b;
            mp_table_init(&t);
            for (int c = 0; c < nc; c++) {
                char name[16];
                snprintf(name, sizeof name, "C%d", c);
                int k = mp_table_add_col(&t, name);
                assert_int_equal(k, c);
                if ((variant & 1) && c % 3 == 0)
                    strcpy(t.cols[k].unit, "pixel");
                t.cols[k].is_int = c % 2;
            }
            for (int r = 0; r < 3; r++) {
                assert_int_equal(mp_table_add_row(&t), r);
                for (int c = 0; c < nc; c++)
                    mp_table_set(&t, r, c, (variant & 2) && r == 1 ? NAN : r * 7 + c);
            }
            mp_ldac_head h = {0};
            if (mp_table_write_fits(path, &t, nc % 2 ? &h : NULL, err))
                fail_msg("%d columns, variant %d: %s", nc, variant, err);
            if (mp_table_read(path, &b, err))
                fail_msg("%d columns, variant %d: %s", nc, variant, err);
            assert_int_equal(b.ncol, (size_t)nc);
            for (int c = 0; c < nc; c++)
                for (int r = 0; r < 3; r++) {
                    double w = mp_table_get(&t, r, c), g = mp_table_get(&b, r, c);
                    assert_true(w == g || (isnan(w) && isnan(g)));
                }
            mp_table_free(&b);
            mp_table_free(&t);
        }
}

/* ---- FITS_LDAC ---------------------------------------------------------- */

/* An image-like header block: 80-character cards without END. */
static char *image_cards(int *n)
{
    static const char *const c[] = {
        "SIMPLE  =                    T / file does conform to FITS standard",
        "BITPIX  =                  -32 / number of bits per data pixel",
        "NAXIS   =                    2 / number of data axes",
        "NAXIS1  =                  512 / length of data axis 1",
        "NAXIS2  =                  256 / length of data axis 2",
        "CTYPE1  = 'RA---TAN'",
        "GAIN    =                  2.5 / [e-/ADU]",
        "EXPTIME =                  300 / [s]",
    };
    *n = (int)(sizeof c / sizeof c[0]);
    char *b = malloc((size_t)*n * 80 + 1);
    assert_non_null(b);
    for (int i = 0; i < *n; i++) {
        memset(b + i * 80, ' ', 80);
        memcpy(b + i * 80, c[i], strlen(c[i]));
    }
    b[*n * 80] = '\0';
    return b;
}

static void test_ldac_layout(void **state)
{
    fixture *f = *state;
    char path[512], err[MP_ERRLEN] = "";
    path_in(f, "cat.ldac", path, sizeof path);
    mp_table t;
    fit_table(&t, 0);
    int nimg;
    char *img = image_cards(&nimg);
    mp_card extra[] = {
        {"SEXGAIN", 2.5, NULL, "Gain used (e-/ADU)"},
        {"EXPTIME", 120, NULL, "replaces the image's"},
        {"FITSFILE", 0, "it's.fits", "File name of the analysed image"},
        {"SEXBKDEV", INFINITY, NULL, "no FITS form: left out"},
    };
    mp_ldac_head h = {img, nimg, extra, 4};
    if (mp_table_write_fits(path, &t, &h, err))
        fail_msg("%s", err);

    int nhdu, st = 0, type;
    fitsfile *fp = open_fits(path, &nhdu);
    assert_int_equal(nhdu, 3);
    fits_movabs_hdu(fp, 2, &type, &st);
    assert_int_equal(type, BINARY_TBL);
    char val[FLEN_VALUE];
    read_str_key(fp, "EXTNAME", val);
    assert_string_equal(val, "LDAC_IMHEAD");
    read_str_key(fp, "TTYPE1", val);
    assert_string_equal(val, "Field Header Card");
    int ncol;
    LONGLONG nrow;
    fits_get_num_cols(fp, &ncol, &st);
    fits_get_num_rowsll(fp, &nrow, &st);
    assert_int_equal(ncol, 1);
    assert_int_equal(nrow, 1);
    /* The image's 8 cards (EXPTIME replaced in place), SEXGAIN and
     * FITSFILE appended, END: 11 cards. */
    int ncards = nimg + 3;
    char want[64];
    read_str_key(fp, "TFORM1", val);
    snprintf(want, sizeof want, "%dA", 80 * ncards);
    assert_string_equal(val, want);
    read_str_key(fp, "TDIM1", val);
    snprintf(want, sizeof want, "(80, %d)", ncards);
    assert_string_equal(val, want);
    unsigned char *cards = malloc((size_t)ncards * 80 + 1);
    assert_non_null(cards);
    assert_int_equal(fits_read_tblbytes(fp, 1, 1, (LONGLONG)ncards * 80, cards, &st), 0);
    cards[ncards * 80] = '\0';
    const char *s = (const char *)cards;
    assert_memory_equal(s, img, 5 * 80);                 /* kept verbatim */
    assert_memory_equal(s + 6 * 80, img + 6 * 80, 80);   /* GAIN */
    assert_memory_equal(s + 7 * 80, "EXPTIME =                  120 / replaces the image's", 53);
    assert_memory_equal(s + 8 * 80, "SEXGAIN =                  2.5 / Gain used (e-/ADU)", 51);
    assert_memory_equal(s + 9 * 80, "FITSFILE= 'it''s.fits'", 22);
    assert_memory_equal(s + 10 * 80, "END     ", 8);
    for (int i = 3; i < 80; i++)
        assert_int_equal(s[10 * 80 + i], ' ');
    assert_null(strstr(s, "SEXBKDEV"));
    free(cards);

    fits_movabs_hdu(fp, 3, &type, &st);
    check_objects(fp, &t, "LDAC_OBJECTS");
    fits_close_file(fp, &st);
    free(img);
    mp_table_free(&t);
}

static void test_ldac_cards(void **state)
{
    (void)state;
    char err[MP_ERRLEN] = "", *cards = NULL;
    int n = 0;
    /* No image: a minimal primary header, then END. */
    mp_ldac_head none = {0};
    assert_int_equal(mp_ldac_cards(&none, &cards, &n, err), 0);
    assert_int_equal(n, 4);
    assert_memory_equal(cards, "SIMPLE  =                    T", 30);
    assert_memory_equal(cards + 3 * 80, "END     ", 8);
    assert_int_equal(strlen(cards), 4 * 80);
    free(cards);

    /* A block that already ends in END: not doubled. */
    int nimg;
    char *img = image_cards(&nimg);
    char *withend = malloc((size_t)(nimg + 2) * 80 + 1);
    assert_non_null(withend);
    memcpy(withend, img, (size_t)nimg * 80);
    memset(withend + nimg * 80, ' ', 160);
    memcpy(withend + nimg * 80, "END", 3);
    withend[(nimg + 2) * 80] = '\0';
    mp_ldac_head h = {withend, nimg + 2, NULL, 0};
    assert_int_equal(mp_ldac_cards(&h, &cards, &n, err), 0);
    assert_int_equal(n, nimg + 1);
    assert_memory_equal(cards, img, (size_t)nimg * 80);
    free(cards);

    /* A bad keyword name is an error, with nothing allocated. */
    mp_card bad = {"TOOLONGKEY", 1, NULL, ""};
    mp_ldac_head hb = {img, nimg, &bad, 1};
    cards = (char *)1;
    assert_int_not_equal(mp_ldac_cards(&hb, &cards, &n, err), 0);
    assert_null(cards);
    assert_non_null(strstr(err, "TOOLONGKEY"));
    free(withend);
    free(img);
}

/* ---- reading others' FITS tables --------------------------------------- */

/* A SExtractor-like table with a vector (VIGNET) and a string column: the
 * scalar numeric columns are read, the others skipped; TNULL reads NaN. */
static void test_read_foreign(void **state)
{
    fixture *f = *state;
    char path[512], err[MP_ERRLEN] = "";
    path_in(f, "foreign.fits", path, sizeof path);
    fitsfile *fp;
    int st = 0;
    fits_create_file(&fp, path, &st);
    fits_create_img(fp, BYTE_IMG, 0, NULL, &st);
    char *tt[] = {"NUMBER", "VIGNET", "NAME", "FLUX_AUTO", "MYINT"};
    char *tf[] = {"1J", "25E", "8A", "1E", "1J"};
    char *tu[] = {"", "count", "", "count", "adu"};
    fits_create_tbl(fp, BINARY_TBL, 2, 5, tt, tf, tu, "LDAC_OBJECTS", &st);
    fits_write_key_lng(fp, "TNULL5", -99, "", &st);
    fits_modify_comment(fp, "TTYPE5", "A private integer", &st);
    fits_set_hdustruc(fp, &st);
    int num[2] = {1, 2}, my[2] = {-99, 7};
    float vig[50] = {0}, flux[2] = {1.5f, 2.25f};
    char *names[2] = {"a", "b"};
    fits_write_col(fp, TINT, 1, 1, 1, 2, num, &st);
    fits_write_col(fp, TFLOAT, 2, 1, 1, 50, vig, &st);
    fits_write_col(fp, TSTRING, 3, 1, 1, 2, names, &st);
    fits_write_col(fp, TFLOAT, 4, 1, 1, 2, flux, &st);
    fits_write_col(fp, TINT, 5, 1, 1, 2, my, &st);
    fits_close_file(fp, &st);
    assert_int_equal(st, 0);

    mp_table t;
    if (mp_table_read(path, &t, err))
        fail_msg("%s", err);
    assert_int_equal(t.ncol, 3);
    assert_string_equal(t.cols[0].name, "NUMBER");
    assert_string_equal(t.cols[1].name, "FLUX_AUTO");
    assert_string_equal(t.cols[1].unit, "count");
    assert_string_equal(t.cols[1].desc, "");   /* not cfitsio's "label for field" */
    assert_string_equal(t.cols[2].name, "MYINT");
    assert_string_equal(t.cols[2].desc, "A private integer");
    assert_string_equal(t.cols[2].unit, "adu");
    assert_int_equal(t.cols[2].is_int, 1);
    assert_true(mp_table_get(&t, 1, 1) == 2.25);
    assert_true(isnan(mp_table_get(&t, 0, 2)));
    assert_true(mp_table_get(&t, 1, 2) == 7);
    mp_table_free(&t);

    /* A FITS file without a table is an error naming the file. */
    double pix[4] = {1, 2, 3, 4};
    path_in(f, "image.fits", path, sizeof path);
    assert_int_equal(mp_image_write(path, pix, 2, 2, -32, NULL, 0, err), 0);
    assert_int_not_equal(mp_table_read(path, &t, err), 0);
    assert_non_null(strstr(err, "image.fits: no binary table"));
    assert_int_equal(t.ncol, 0);
    mp_table_free(&t);
}

/* ---- atomic output ------------------------------------------------------ */

static void test_atomic(void **state)
{
    fixture *f = *state;
    char path[512], err[MP_ERRLEN] = "";
    mp_table t;
    fit_table(&t, 0);

    /* No file name, or stdout: refused before anything is created. */
    assert_int_not_equal(mp_table_write("-", &t, MP_TAB_LDAC, err), 0);
    assert_non_null(strstr(err, "needs an output file name"));
    assert_int_not_equal(mp_table_write_fits(NULL, &t, NULL, err), 0);

    /* A good file stays as it was when a later write fails early. */
    path_in(f, "keep.fits", path, sizeof path);
    assert_int_equal(mp_table_write(path, &t, MP_TAB_FITS, err), 0);
    struct stat before, after;
    assert_int_equal(stat(path, &before), 0);
    mp_card bad = {"", 1, NULL, NULL};
    mp_ldac_head hb = {NULL, 0, &bad, 1};
    assert_int_not_equal(mp_table_write_fits(path, &t, &hb, err), 0);
    assert_int_equal(stat(path, &after), 0);
    assert_int_equal(after.st_size, before.st_size);
    assert_int_equal(count_entries(f->dir), 1);

    /* A failure after cfitsio wrote the whole temporary (the rename onto
     * a non-empty directory fails): the temporary is removed. */
    char sub[512], inner[600];
    path_in(f, "adir", sub, sizeof sub);
    assert_int_equal(mkdir(sub, 0700), 0);
    snprintf(inner, sizeof inner, "%s/x", sub);
    FILE *fx = fopen(inner, "w");
    assert_non_null(fx);
    fclose(fx);
    assert_int_not_equal(mp_table_write(sub, &t, MP_TAB_LDAC, err), 0);
    assert_non_null(strstr(err, "adir: cannot rename"));
    assert_int_equal(count_entries(f->dir), 2);   /* keep.fits and adir */
    assert_int_equal(count_entries(sub), 1);

    /* A directory that does not exist: nothing anywhere. */
    path_in(f, "nodir/cat.fits", path, sizeof path);
    assert_int_not_equal(mp_table_write(path, &t, MP_TAB_FITS, err), 0);
    assert_non_null(strstr(err, "nodir/cat.fits: cannot create"));
    assert_int_equal(count_entries(f->dir), 2);

    /* An empty table (no columns) is refused. */
    mp_table e;
    mp_table_init(&e);
    path_in(f, "empty.fits", path, sizeof path);
    assert_int_not_equal(mp_table_write(path, &e, MP_TAB_FITS, err), 0);
    assert_int_equal(count_entries(f->dir), 2);
    mp_table_free(&t);
}

static void test_format_names(void **state)
{
    (void)state;
    mp_table_format fmt;
    assert_int_equal(mp_table_format_parse("fits", &fmt), 0);
    assert_int_equal(fmt, MP_TAB_FITS);
    assert_int_equal(mp_table_format_parse("FITS_1.0", &fmt), 0);
    assert_int_equal(fmt, MP_TAB_FITS);
    assert_int_equal(mp_table_format_parse("ldac", &fmt), 0);
    assert_int_equal(fmt, MP_TAB_LDAC);
    assert_int_equal(mp_table_format_parse("FITS_LDAC", &fmt), 0);
    assert_int_equal(fmt, MP_TAB_LDAC);
    assert_int_not_equal(mp_table_format_parse("fits_tpx", &fmt), 0);
}

/* ---- DS9 regions -------------------------------------------------------- */

static char *slurp(const char *path)
{
    FILE *fp = fopen(path, "rb");
    assert_non_null(fp);
    fseek(fp, 0, SEEK_END);
    long n = ftell(fp);
    fseek(fp, 0, SEEK_SET);
    char *s = malloc((size_t)n + 1);
    assert_non_null(s);
    assert_int_equal(fread(s, 1, (size_t)n, fp), (size_t)n);
    s[n] = '\0';
    fclose(fp);
    return s;
}

static void test_regions(void **state)
{
    fixture *f = *state;
    char path[512], err[MP_ERRLEN] = "";
    path_in(f, "stars.reg", path, sizeof path);
    mp_table t;
    fit_table(&t, 0);
    mp_table_set(&t, 3, 1, NAN);   /* no position: no circle */
    mp_region_opts o = {3.0, 0, 1};
    long n = -1;
    if (mp_regions_write(path, &t, &o, &n, err))
        fail_msg("%s", err);
    assert_int_equal(n, 4);
    char *s = slurp(path);
    const char *want_head = "# Region file format: DS9 version 4.1\n";
    assert_memory_equal(s, want_head, strlen(want_head));
    assert_non_null(strstr(s, "\nimage\n"));
    char line[128];
    snprintf(line, sizeof line, "circle(%.5f,%.5f,3) # color=green text={1}\n",
             mp_table_get(&t, 0, 1), mp_table_get(&t, 0, 2));
    assert_non_null(strstr(s, line));
    snprintf(line, sizeof line, "circle(%.5f,%.5f,3) # color=red text={5}\n",
             mp_table_get(&t, 4, 1), mp_table_get(&t, 4, 2));
    assert_non_null(strstr(s, line));
    assert_null(strstr(s, "text={4}"));
    int circles = 0;
    for (const char *p = s; (p = strstr(p, "circle(")); p++)
        circles++;
    assert_int_equal(circles, 4);
    free(s);

    /* fk5 needs sky columns: an error, and no file. */
    mp_region_opts k = {1.5, 1, 0};
    path_in(f, "sky.reg", path, sizeof path);
    assert_int_not_equal(mp_regions_write(path, &t, &k, NULL, err), 0);
    assert_non_null(strstr(err, "ALPHAPSF_J2000"));
    assert_int_equal(access(path, F_OK), -1);
    int ca = mp_table_add_col(&t, "ALPHAPSF_J2000"), cd = mp_table_add_col(&t, "DELTAPSF_J2000");
    for (size_t r = 0; r < t.nrow; r++) {
        mp_table_set(&t, r, ca, 150.0 + 1e-4 * (double)r);
        mp_table_set(&t, r, cd, -2.0 - 1e-4 * (double)r);
    }
    assert_int_equal(mp_regions_write(path, &t, &k, &n, err), 0);
    assert_int_equal(n, 5);
    s = slurp(path);
    assert_non_null(strstr(s, "\nfk5\ncircle(150.00000000,-2.00000000,1.5\") # color=green\n"));
    assert_null(strstr(s, "text="));
    free(s);

    /* A bad radius. */
    mp_region_opts r0 = {0.0, 0, 0};
    assert_int_not_equal(mp_regions_write(path, &t, &r0, NULL, err), 0);
    mp_table_free(&t);
}

int main(void)
{
    const struct CMUnitTest tests[] = {
        cmocka_unit_test_setup_teardown(test_fits10_layout, setup, teardown),
        cmocka_unit_test_setup_teardown(test_fits_read_back, setup, teardown),
        cmocka_unit_test_setup_teardown(test_integer_widths, setup, teardown),
        cmocka_unit_test_setup_teardown(test_header_sizes, setup, teardown),
        cmocka_unit_test_setup_teardown(test_ldac_layout, setup, teardown),
        cmocka_unit_test(test_ldac_cards),
        cmocka_unit_test_setup_teardown(test_read_foreign, setup, teardown),
        cmocka_unit_test_setup_teardown(test_atomic, setup, teardown),
        cmocka_unit_test(test_format_names),
        cmocka_unit_test_setup_teardown(test_regions, setup, teardown),
    };
    return cmocka_run_group_tests(tests, NULL, NULL);
}
