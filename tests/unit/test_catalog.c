/*
 * test_catalog.c — catalog/: the table model, the column registry, and the
 * ASCII_HEAD and CSV formats (round trips, SExtractor's exact header layout,
 * malformed input, atomic output).
 *
 * With MP_SAMPLE_OUT=path set, also writes a sample of every registry
 * column to path (ASCII_HEAD) and path.csv for tests/e2e/astropy_sextractor.sh.
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

#include "catalog/catalog.h"
#include "catalog/table_priv.h"
#include "io/io.h"
#ifdef _OPENMP
#include <omp.h>
#endif

/* ---- helpers ---------------------------------------------------------- */

typedef struct {
    char dir[256];
} fixture;

static int setup(void **state)
{
    fixture *f = calloc(1, sizeof *f);
    if (!f)
        return -1;
    const char *tmp = getenv("TMPDIR");
    snprintf(f->dir, sizeof f->dir, "%s/test_catalog.XXXXXX", tmp && *tmp ? tmp : "/tmp");
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
    DIR *d = opendir(f->dir);
    if (d) {
        struct dirent *e;
        char p[600];
        while ((e = readdir(d)) != NULL) {
            if (strcmp(e->d_name, ".") == 0 || strcmp(e->d_name, "..") == 0)
                continue;
            snprintf(p, sizeof p, "%s/%s", f->dir, e->d_name);
            unlink(p);
        }
        closedir(d);
    }
    rmdir(f->dir);
    free(f);
    return 0;
}

static void path_in(const fixture *f, const char *name, char *out, size_t n)
{
    snprintf(out, n, "%s/%s", f->dir, name);
}

static void write_text(const char *path, const char *text, size_t len)
{
    FILE *fp = fopen(path, "wb");
    assert_non_null(fp);
    assert_int_equal(fwrite(text, 1, len, fp), len);
    assert_int_equal(fclose(fp), 0);
}

/* Whole file into a NUL-terminated buffer (caller frees). */
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

/* Expect mp_table_read of path to fail with exactly msg. */
static void expect_read_error(const char *path, const char *msg)
{
    mp_table t;
    char err[MP_ERRLEN] = "";
    assert_int_not_equal(mp_table_read(path, &t, err), 0);
    assert_string_equal(err, msg);
    assert_int_equal(t.ncol, 0);      /* left empty on failure */
    assert_int_equal(t.nrow, 0);
    mp_table_free(&t);
}

/* The precision a column's print format keeps: half a unit of its last
 * printed digit ("%11.5f" → 5e-6 absolute, "%12.7g" → 5e-7 relative). */
static int close_enough(const mp_col *c, double want, double got)
{
    if (isnan(want))
        return isnan(got);
    if (c->is_int)
        return want == got;
    const char *dot = strchr(c->fmt, '.');
    int prec = dot ? atoi(dot + 1) : 6;
    char conv = c->fmt[strlen(c->fmt) - 1];
    double tol = conv == 'f' ? 0.5 * pow(10, -prec) * (1 + 1e-9) + 1e-12 * fabs(want)
                             : 0.5 * pow(10, 1 - prec) * fabs(want) * (1 + 1e-9);
    return fabs(want - got) <= tol;
}

/* A table holding every registry column and a few rows of awkward values. */
static void sample_table(mp_table *t)
{
    mp_table_init(t);
    size_t n = mp_col_registry_count();
    for (size_t i = 0; i < n; i++)
        assert_int_equal(mp_table_add_col(t, mp_col_registry_at(i)->name), (int)i);
    for (size_t r = 0; r < 4; r++) {
        assert_int_equal(mp_table_add_row(t), (long)r);
        for (size_t c = 0; c < n; c++) {
            const mp_col *k = &t->cols[c];
            double x;
            if (k->is_int)
                /* r = 3: larger than any int, still printed exactly */
                x = r == 3 ? 12345678901.0 : (double)(c * 10 + r);
            else if (strcmp(k->name, "DELTAPSF_J2000") == 0)
                x = -89.1234567 + 30.0 * (double)r;
            else if (strstr(k->name, "IMAGE"))
                x = 1.0 + 1234.567891234 * (double)(r + 1) / 7.0;
            else if (strstr(k->name, "MAG"))
                x = -15.0 + 1.23456789 * (double)r;
            else
                x = pow(10.0, (double)r * 2.3 - 1.7) * (1.0 + 0.0123456789 * (double)c);
            if (r == 2 && c % 5 == 1)
                x = NAN;                 /* missing values survive too */
            mp_table_set(t, r, (int)c, x);
        }
    }
}

static void compare_tables(const mp_table *a, const mp_table *b)
{
    assert_int_equal(b->ncol, a->ncol);
    assert_int_equal(b->nrow, a->nrow);
    for (size_t c = 0; c < a->ncol; c++) {
        assert_string_equal(b->cols[c].name, a->cols[c].name);
        assert_string_equal(b->cols[c].desc, a->cols[c].desc);
        assert_string_equal(b->cols[c].unit, a->cols[c].unit);
        for (size_t r = 0; r < a->nrow; r++) {
            double want = mp_table_get(a, r, (int)c), got = mp_table_get(b, r, (int)c);
            if (!close_enough(&a->cols[c], want, got))
                fail_msg("%s row %zu: wrote %.17g, read %.17g (format %s)",
                         a->cols[c].name, r, want, got, a->cols[c].fmt);
        }
    }
}

/* ---- the model -------------------------------------------------------- */

static void test_table_model(void **state)
{
    (void)state;
    mp_table t;
    mp_table_init(&t);
    assert_int_equal(mp_table_col(&t, "X_IMAGE"), -1);
    int x = mp_table_add_col(&t, "X_IMAGE");
    assert_int_equal(x, 0);
    assert_int_equal(mp_table_add_col(&t, "X_IMAGE"), 0);   /* existing */
    assert_int_equal(mp_table_add_col(&t, ""), -1);
    assert_int_equal(mp_table_add_col(&t, "A_NAME_THAT_IS_FAR_TOO_LONG_FOR_IT"), -1);

    /* Many rows: amortised growth keeps earlier values. */
    for (long r = 0; r < 100000; r++) {
        assert_int_equal(mp_table_add_row(&t), r);
        mp_table_set(&t, (size_t)r, x, (double)r + 0.25);
    }
    /* A column added later is NaN in existing rows; old values stay. */
    int f = mp_table_add_col(&t, "FLAGS");
    assert_int_equal(f, 1);
    assert_true(t.cols[1].is_int);
    for (size_t r = 0; r < t.nrow; r++) {
        assert_true(isnan(mp_table_get(&t, r, f)));
        assert_true(mp_table_get(&t, r, x) == (double)r + 0.25);
    }
    long r = mp_table_add_row(&t);
    assert_true(isnan(mp_table_get(&t, (size_t)r, x)));
    assert_int_equal(mp_table_col(&t, "FLAGS"), 1);

    /* Unknown names get a generic description. */
    int u = mp_table_add_col(&t, "MY_COLUMN");
    assert_string_equal(t.cols[u].desc, "");
    assert_string_equal(t.cols[u].unit, "");
    assert_false(t.cols[u].is_int);
    mp_table_free(&t);
    mp_table_free(&t);   /* safe twice */
}

/* Columns added at once (issue 14): one re-layout, the old values in
 * place, the new NaN, an existing name's own index, a bad name adding
 * none; the rows' block exactly nrow rows after, and after a shrink. */
static void test_table_add_cols(void **state)
{
    (void)state;
    mp_table t;
    mp_table_init(&t);
    int x = mp_table_add_col(&t, "X_IMAGE"), y = mp_table_add_col(&t, "Y_IMAGE");
    for (long r = 0; r < 1000; r++) {
        assert_int_equal(mp_table_add_row(&t), r);
        mp_table_set(&t, (size_t)r, x, (double)r);
        mp_table_set(&t, (size_t)r, y, -(double)r);
    }
    assert_true(t.cap > t.nrow);            /* doubling left room: 1024 */
    const char *const bad[] = {"FLUX_PSF", "NOT A NAME OF 32 CHARACTERS OR MORE"};
    int idx[3];
    assert_int_equal(mp_table_add_cols(&t, bad, 2, idx), -1);
    assert_int_equal(t.ncol, 2);            /* none added */
    const char *const names[] = {"FLUX_PSF", "Y_IMAGE", "FLAGS", "FLUX_PSF"};
    int c[4];
    assert_int_equal(mp_table_add_cols(&t, names, 4, c), 0);
    assert_int_equal(t.ncol, 4);
    assert_int_equal(c[0], 2);
    assert_int_equal(c[1], y);
    assert_int_equal(c[2], 3);
    assert_int_equal(c[3], 2);             /* named twice: one column */
    assert_int_equal(t.cap, t.nrow);
    for (size_t r = 0; r < t.nrow; r++) {
        assert_true(mp_table_get(&t, r, x) == (double)r);
        assert_true(mp_table_get(&t, r, y) == -(double)r);
        assert_true(isnan(mp_table_get(&t, r, c[0])) && isnan(mp_table_get(&t, r, c[2])));
    }
    assert_int_equal(mp_table_add_cols(&t, names, 4, c), 0);   /* all there: no-op */
    assert_int_equal(t.ncol, 4);
    assert_int_equal(mp_table_add_row(&t), 1000);
    assert_true(t.cap > t.nrow);
    assert_int_equal(mp_table_shrink(&t), 0);
    assert_int_equal(t.cap, t.nrow);
    assert_true(mp_table_get(&t, 999, x) == 999.0 && isnan(mp_table_get(&t, 1000, x)));
    mp_table_free(&t);
}

/* ASCII_HEAD rows are formatted in parallel chunks (2048 rows a thread)
 * and written in order: the bytes of 1 and of 3 threads are the same, over
 * a table that spans several rounds of chunks and ends in a part chunk. */
static void test_ascii_rows_threads(void **state)
{
    (void)state;
    mp_table t;
    mp_table_init(&t);
    int c[3] = {mp_table_add_col(&t, "NUMBER"), mp_table_add_col(&t, "XPSF_IMAGE"),
                mp_table_add_col(&t, "MAG_PSF")};
    for (long r = 0; r < 13001; r++) {
        assert_int_equal(mp_table_add_row(&t), r);
        mp_table_set(&t, (size_t)r, c[0], (double)(r + 1));
        mp_table_set(&t, (size_t)r, c[1], 0.001 * (double)r * (double)r);
        mp_table_set(&t, (size_t)r, c[2], r % 97 ? -2.5 * log10(1.0 + (double)r) : NAN);
    }
    char *out[2];
    size_t len[2];
    char err[MP_ERRLEN];
    int threads[2] = {1, 3};
    for (int k = 0; k < 2; k++) {
#ifdef _OPENMP
        omp_set_num_threads(threads[k]);
#endif
        FILE *fp = open_memstream(&out[k], &len[k]);
        assert_non_null(fp);
        assert_int_equal(mp_ascii_head_write(fp, "mem", &t, err), 0);
        fclose(fp);
    }
    (void)threads;
    assert_true(len[0] > 13001 * 20);
    assert_int_equal(len[0], len[1]);
    assert_memory_equal(out[0], out[1], len[0]);
    /* the last row, whole, at the end */
    assert_non_null(strstr(out[0] + len[0] - 64, "13001 "));
    free(out[0]);
    free(out[1]);
    mp_table_free(&t);
}

static void test_registry(void **state)
{
    (void)state;
    static const char *const design[] = {
        "NUMBER", "X_IMAGE", "Y_IMAGE", "FLUX_MAX", "BACKGROUND", "SHARPNESS",
        "ROUNDNESS", "GROUP_ID", "GROUP_SIZE", "XPSF_IMAGE", "YPSF_IMAGE",
        "ERRX_PSF", "ERRY_PSF", "FLUX_PSF", "FLUXERR_PSF", "MAG_PSF", "MAGERR_PSF",
        "ALPHAPSF_J2000", "DELTAPSF_J2000", "SKY_PSF", "SKYERR_PSF", "CHI2_PSF",
        "DOF_PSF", "CHI2STAR_PSF", "NITER_PSF", "BETA_PSF", "SHARP_PRF", "LSCALE_PRF", "VOLUME_PRF",
        "FLUXERR_MODEL", "POSERR_MODEL", "FLAGS", "FLUX_TRUE", "MAG_TRUE",
        "SKY_TRUE", "FLUX",
    };
    for (size_t i = 0; i < sizeof design / sizeof design[0]; i++)
        if (!mp_col_registry_find(design[i]))
            fail_msg("%s missing from the registry", design[i]);
    for (size_t i = 0; i < mp_col_registry_count(); i++) {
        const mp_col *c = mp_col_registry_at(i);
        assert_true(strlen(c->name) <= 22);   /* SExtractor's name field */
        assert_true(strlen(c->desc) <= 58);   /* ... and description field */
        assert_true(c->desc[0] != '\0');
        assert_non_null(strchr(c->fmt, '%'));
    }
    /* SExtractor's wording and our units. */
    const mp_col *c = mp_col_registry_find("FLUX_PSF");
    assert_string_equal(c->desc, "Flux from PSF-fitting");
    assert_string_equal(c->unit, "electron");
    assert_string_equal(mp_col_registry_find("XPSF_IMAGE")->desc, "X coordinate from PSF-fitting");
    assert_string_equal(mp_col_registry_find("X_IMAGE")->desc, "Object position along x");
    assert_string_equal(mp_col_registry_find("BACKGROUND")->desc, "Background at centroid position");
    assert_string_equal(mp_col_registry_find("FLUX_MAX")->desc, "Peak flux above background");
    assert_string_equal(mp_col_registry_find("FLAGS")->desc, "Extraction flags");
    assert_string_equal(mp_col_registry_find("NUMBER")->desc, "Running object number");
    assert_string_equal(mp_col_registry_find("MAG_PSF")->unit, "mag");
    assert_string_equal(mp_col_registry_find("ALPHAPSF_J2000")->unit, "deg");
    assert_string_equal(mp_col_registry_find("BETA_PSF")->unit, "pixel**2");
    assert_string_equal(mp_col_registry_find("CHI2_PSF")->unit, "");
    assert_null(mp_col_registry_find("NO_SUCH_COLUMN"));
}

/* An integer column's values as printf's "%W.0f" writes them, the
 * integral ones taken as integers (mp_format_value's fast path): the same
 * characters for every value, whichever path it takes. */
static void test_integer_columns(void **state)
{
    (void)state;
    static const double v[] = {0.0, -0.0, 1.0, -1.0, 7.0, 4937.0, -12345.0, 1e9, -1e12,
                               999999999999999.0, 9007199254740991.0, 9007199254740992.0,
                               -9007199254740993.0, 1e17, 2.5, 3.5, -0.5, 1e-300, 123.4999};
    int tested = 0;
    for (size_t i = 0; i < mp_col_registry_count(); i++) {
        const mp_col *c = mp_col_registry_at(i);
        if (!c->is_int)
            continue;
        for (size_t k = 0; k < sizeof v / sizeof v[0]; k++) {
            char got[512], want[512];
            int n = mp_format_value(c, v[k], got, sizeof got);
            int m = snprintf(want, sizeof want, c->fmt, v[k] == 0 ? 0.0 : v[k]);
            if (n != m || strcmp(got, want) != 0)
                fail_msg("%s %s of %.17g: '%s' against '%s'", c->name, c->fmt, v[k], got, want);
            tested++;
        }
    }
    assert_true(tested >= 6 * (int)(sizeof v / sizeof v[0]));   /* NUMBER, FLAGS, GROUP_ID, ... */
}

/* A float column's values as printf writes them with its format, which
 * mp_format_value writes through libc's strfromd and pads to the width:
 * the same characters and length for fixed values at the formats' edges
 * (rounding to even, widths overflowed, huge %f, subnormals, ±inf, −0)
 * and 20 000 drawn over 40 decades with both signs, in every registry
 * column and in formats it does not take that way (flags: snprintf). */
static void test_float_columns(void **state)
{
    (void)state;
    static const double v[] = {0.0, -0.0, 0.5, 1.5, 2.5, -2.5, 0.125, 1e-5, 5e-6, 0.000015,
                               123456.75, 9999999.5, 99999995.0, 1.23456785e21, -1e300, 1e308,
                               4.9e-324, 2.2250738585072014e-308, 1.0 / 3.0, -2.0 / 3.0,
                               INFINITY, -INFINITY, 1e100, 6.02214076e23};
    static const mp_col extra[] = {{"A", "", "", "%-12.7g", 0}, {"B", "", "", "%+10.4f", 0},
                                   {"C", "", "", "%12.3e", 0}, {"D", "", "", "%3.0f", 0}};
    unsigned long long r = 20261205;
    int tested = 0;
    size_t nreg = mp_col_registry_count(), nx = sizeof extra / sizeof extra[0];
    for (size_t i = 0; i < nreg + nx; i++) {
        const mp_col *c = i < nreg ? mp_col_registry_at(i) : &extra[i - nreg];
        if (c->is_int || strchr(c->fmt, 's'))
            continue;
        for (size_t k = 0; k < sizeof v / sizeof v[0] + 20000; k++) {
            double x;
            if (k < sizeof v / sizeof v[0]) {
                x = v[k];
            } else {
                r = r * 6364136223846793005ULL + 1442695040888963407ULL;
                x = ((double)(r >> 11) / 9007199254740992.0 - 0.5) * pow(10.0, (int)(r % 40) - 20);
            }
            char got[512], want[512];
            int n = mp_format_value(c, x, got, sizeof got);
            int m = snprintf(want, sizeof want, c->fmt, x);
            if (n != m || strcmp(got, want) != 0)
                fail_msg("%s %s of %.17g: '%s' against '%s'", c->name, c->fmt, x, got, want);
            tested++;
        }
    }
    assert_true(tested >= 20 * 20000);
}

static void test_parse_value(void **state)
{
    (void)state;
    double x;
    assert_int_equal(mp_parse_value("  1.5e3 ", &x), 0);
    assert_true(x == 1500.0);
    assert_int_equal(mp_parse_value("-42", &x), 0);
    assert_true(x == -42.0);
    assert_int_equal(mp_parse_value("nan", &x), 0);
    assert_true(isnan(x));
    assert_int_equal(mp_parse_value("NaN", &x), 0);
    assert_true(isnan(x));
    assert_int_equal(mp_parse_value("INDEF", &x), 0);
    assert_true(isnan(x));
    assert_int_equal(mp_parse_value("-nan", &x), 0);
    assert_true(isnan(x) && !signbit(x));
    assert_int_not_equal(mp_parse_value("abc", &x), 0);
    assert_int_not_equal(mp_parse_value("1.5x", &x), 0);
    assert_int_not_equal(mp_parse_value("", &x), 0);
    assert_int_not_equal(mp_parse_value("INDEFX", &x), 0);
}

static void test_format_parse(void **state)
{
    (void)state;
    mp_table_format f;
    assert_int_equal(mp_table_format_parse("ascii_head", &f), 0);
    assert_int_equal(f, MP_TAB_ASCII_HEAD);
    assert_int_equal(mp_table_format_parse("CSV", &f), 0);
    assert_int_equal(f, MP_TAB_CSV);
    assert_int_equal(mp_table_format_parse("ASCII_Head", &f), 0);
    assert_int_equal(f, MP_TAB_ASCII_HEAD);
    assert_int_equal(mp_table_format_parse("fits", &f), 0);
    assert_int_equal(f, MP_TAB_FITS);
    assert_int_not_equal(mp_table_format_parse("votable", &f), 0);
    assert_int_not_equal(mp_table_format_parse("", &f), 0);
}

/* ---- ASCII_HEAD layout ------------------------------------------------- */

static void test_header_bytes(void **state)
{
    fixture *f = *state;
    char path[512], err[MP_ERRLEN];
    path_in(f, "head.cat", path, sizeof path);

    mp_table t;
    mp_table_init(&t);
    mp_table_add_col(&t, "NUMBER");
    mp_table_add_col(&t, "XPSF_IMAGE");
    mp_table_add_col(&t, "YPSF_IMAGE");
    int fl = mp_table_add_col(&t, "FLUX_PSF");
    strcpy(t.cols[fl].unit, "count");   /* as SExtractor, for the anchor */
    long r = mp_table_add_row(&t);
    mp_table_set(&t, (size_t)r, 0, 1);
    mp_table_set(&t, (size_t)r, 1, 12.25);
    mp_table_set(&t, (size_t)r, 2, NAN);
    mp_table_set(&t, (size_t)r, 3, 1234.5);
    assert_int_equal(mp_table_write(path, &t, MP_TAB_ASCII_HEAD, err), 0);
    mp_table_free(&t);

    /* anchors.md §2.2, copied byte for byte (SExtractor catout.c). */
    const char *want =
        "#   1 NUMBER                 Running object number                                     \n"
        "#   2 XPSF_IMAGE             X coordinate from PSF-fitting                              [pixel]\n"
        "#   3 YPSF_IMAGE             Y coordinate from PSF-fitting                              [pixel]\n"
        "#   4 FLUX_PSF               Flux from PSF-fitting                                      [count]\n"
        "         1    12.25000         nan       1234.5\n";
    char *got = slurp(path);
    assert_string_equal(got, want);
    free(got);
}

/* ---- round trips -------------------------------------------------------- */

static void round_trip(fixture *f, mp_table_format fmt, const char *name)
{
    char path[512], err[MP_ERRLEN] = "";
    path_in(f, name, path, sizeof path);
    mp_table a, b;
    sample_table(&a);
    if (mp_table_write(path, &a, fmt, err) != 0)
        fail_msg("write: %s", err);
    if (mp_table_read(path, &b, err) != 0)
        fail_msg("read: %s", err);
    if (fmt == MP_TAB_CSV) {
        /* CSV carries no descriptions: they come back from the registry. */
        for (size_t c = 0; c < b.ncol; c++)
            assert_string_equal(b.cols[c].fmt, a.cols[c].fmt);
    }
    compare_tables(&a, &b);
    mp_table_free(&a);
    mp_table_free(&b);
    assert_int_equal(count_entries(f->dir), 1);   /* no temporary left */
}

/* A table written with the last one's rows kept (mp_table_write_kept: the
 * pipeline's root.grp, then root.fit) is the same bytes as written alone,
 * with its rows in another order, one row's flux one ulp away, one row
 * gone and one new; the rows copied are exactly those with the same
 * NUMBER and values; a table of other columns copies none. */
static void test_write_kept_same_bytes(void **state)
{
    fixture *f = *state;
    char pa[512], pb[512], pc[512], err[MP_ERRLEN] = "";
    path_in(f, "k.grp", pa, sizeof pa);
    path_in(f, "k.fit", pb, sizeof pb);
    path_in(f, "k.alone", pc, sizeof pc);
    mp_table a, b;
    sample_table(&a);
    int cn = mp_table_col(&a, "NUMBER"), cf = mp_table_col(&a, "FLUX_PSF");
    assert_true(cn >= 0 && cf >= 0);
    static const double num[4] = {5, 3, 9, 1};
    for (size_t r = 0; r < 4; r++)
        mp_table_set(&a, r, cn, num[r]);
    /* b: a's rows 3, 1, 0 (row 2 gone), row 1's flux one ulp up, NUMBER 7 new */
    mp_table_init(&b);
    for (size_t c = 0; c < a.ncol; c++)
        assert_int_equal(mp_table_add_col(&b, a.cols[c].name), (int)c);
    static const size_t from[3] = {3, 1, 0};
    for (size_t q = 0; q < 4; q++) {
        assert_int_equal(mp_table_add_row(&b), (long)q);
        for (size_t c = 0; c < a.ncol; c++)
            mp_table_set(&b, q, (int)c, mp_table_get(&a, q < 3 ? from[q] : 2, (int)c));
    }
    mp_table_set(&b, 1, cf, nextafter(mp_table_get(&b, 1, cf), INFINITY));
    mp_table_set(&b, 3, cn, 7.0);
    mp_text_kept *k = NULL;
    assert_int_equal(mp_table_write_kept(pa, &a, MP_TAB_ASCII_HEAD, NULL, &k, err), 0);
    assert_non_null(k);
    assert_true(mp_text_kept_fits(k, &b));
    const char *txt;
    size_t len;
    static const int copied[4] = {1, 0, 1, 0};
    for (size_t q = 0; q < 4; q++)
        assert_int_equal(mp_text_kept_row(k, &b, cn, q, &txt, &len), copied[q]);
    assert_int_equal(mp_table_write_kept(pb, &b, MP_TAB_ASCII_HEAD, k, NULL, err), 0);
    assert_int_equal(mp_table_write(pc, &b, MP_TAB_ASCII_HEAD, err), 0);
    char *with = slurp(pb), *alone = slurp(pc), *first = slurp(pa);
    assert_string_equal(with, alone);
    char *again = NULL;            /* a's rows as kept: its file's tail */
    assert_true(mp_text_kept_row(k, &a, cn, 0, &txt, &len));
    assert_non_null(again = strstr(first, "\n         5 "));
    assert_memory_equal(again + 1, txt, len);
    /* other columns: nothing copied, the same bytes */
    mp_table c1;
    mp_table_init(&c1);
    assert_true(mp_table_add_col(&c1, "NUMBER") == 0 && mp_table_add_col(&c1, "FLUX_PSF") == 1);
    assert_int_equal(mp_table_add_row(&c1), 0);
    mp_table_set(&c1, 0, 0, 5.0);
    mp_table_set(&c1, 0, 1, 1.0);
    assert_false(mp_text_kept_fits(k, &c1));
    free(with);
    free(alone);
    free(first);
    mp_text_kept_free(k);
    mp_table_free(&a);
    mp_table_free(&b);
    mp_table_free(&c1);
}

/* A table with the kept one's columns first and more after (root.fit,
 * then root.cat with its sky positions) copies the kept text of its rows
 * whose values in those columns are the same, bit for bit, and formats
 * the columns after: the same bytes as written alone, one row's flux one
 * ulp away formatted whole.  (Before, no row of it was copied.) */
static void test_write_kept_prefix(void **state)
{
    fixture *f = *state;
    char pa[512], pb[512], pc[512], err[MP_ERRLEN] = "";
    path_in(f, "p.fit", pa, sizeof pa);
    path_in(f, "p.cat", pb, sizeof pb);
    path_in(f, "p.alone", pc, sizeof pc);
    mp_table a, b, s;
    sample_table(&b);
    size_t na = b.ncol - 2;             /* a: b's columns but the last two */
    mp_table_init(&a);
    mp_table_init(&s);                  /* s: one column fewer than a */
    for (size_t c = 0; c < na; c++) {
        assert_int_equal(mp_table_add_col(&a, b.cols[c].name), (int)c);
        if (c + 1 < na)
            assert_int_equal(mp_table_add_col(&s, b.cols[c].name), (int)c);
    }
    for (size_t r = 0; r < b.nrow; r++) {
        assert_int_equal(mp_table_add_row(&a), (long)r);
        for (size_t c = 0; c < na; c++)
            mp_table_set(&a, r, (int)c, mp_table_get(&b, r, (int)c));
    }
    int cn = mp_table_col(&b, "NUMBER"), cf = mp_table_col(&b, "FLUX_PSF");
    assert_true(cn >= 0 && cf >= 0 && (size_t)cf < na);
    static const double num[4] = {5, 3, 9, 1};
    for (size_t r = 0; r < 4; r++) {
        mp_table_set(&a, r, cn, num[r]);
        mp_table_set(&b, r, cn, num[r]);
    }
    mp_table_set(&b, 2, cf, nextafter(mp_table_get(&b, 2, cf), INFINITY));
    mp_text_kept *k = NULL;
    assert_int_equal(mp_table_write_kept(pa, &a, MP_TAB_ASCII_HEAD, NULL, &k, err), 0);
    assert_non_null(k);
    assert_true(mp_text_kept_fits(k, &b));
    assert_false(mp_text_kept_fits(k, &s));
    const char *txt;
    size_t len;
    for (size_t q = 0; q < 4; q++)
        assert_int_equal(mp_text_kept_row(k, &b, cn, q, &txt, &len), q != 2);
    assert_int_equal(mp_table_write_kept(pb, &b, MP_TAB_ASCII_HEAD, k, NULL, err), 0);
    assert_int_equal(mp_table_write(pc, &b, MP_TAB_ASCII_HEAD, err), 0);
    char *with = slurp(pb), *alone = slurp(pc);
    assert_string_equal(with, alone);
    free(with);
    free(alone);
    mp_text_kept_free(k);
    mp_table_free(&a);
    mp_table_free(&b);
    mp_table_free(&s);
}

/* A table whose text would pass the budget (16 MiB at 12 bytes a value:
 * 699 051 rows of two values) is written the same bytes, but its rows are
 * not kept: the 8192² run held 227 MB of them at its writes.  (Before,
 * every table's were.) */
static void test_write_kept_budget(void **state)
{
    fixture *f = *state;
    char pa[512], pb[512], err[MP_ERRLEN] = "";
    path_in(f, "b.grp", pa, sizeof pa);
    path_in(f, "b.alone", pb, sizeof pb);
    mp_table t;
    mp_table_init(&t);
    assert_true(mp_table_add_col(&t, "NUMBER") == 0 && mp_table_add_col(&t, "FLUX_PSF") == 1);
    size_t n = (size_t)(16.0 * 1024 * 1024 / 24.0) + 1;
    assert_int_equal(mp_table_reserve(&t, n), 0);
    for (size_t r = 0; r < n; r++) {
        assert_int_equal(mp_table_add_row(&t), (long)r);
        mp_table_set(&t, r, 0, (double)(r + 1));
        mp_table_set(&t, r, 1, 1000.0 + (double)r);
    }
    mp_text_kept *k = NULL;
    assert_int_equal(mp_table_write_kept(pa, &t, MP_TAB_ASCII_HEAD, NULL, &k, err), 0);
    assert_null(k);
    assert_int_equal(mp_table_write(pb, &t, MP_TAB_ASCII_HEAD, err), 0);
    char *kept = slurp(pa), *alone = slurp(pb);
    assert_string_equal(kept, alone);
    free(kept);
    free(alone);
    mp_table_free(&t);
}

static void test_round_trip_ascii(void **state) { round_trip(*state, MP_TAB_ASCII_HEAD, "rt.cat"); }
static void test_round_trip_csv(void **state) { round_trip(*state, MP_TAB_CSV, "rt.csv"); }

static void test_positions_precision(void **state)
{
    fixture *f = *state;
    char path[512], err[MP_ERRLEN];
    const char *names[] = {"rt.cat", "rt.csv"};
    for (int k = 0; k < 2; k++) {
        path_in(f, names[k], path, sizeof path);
        mp_table a, b;
        mp_table_init(&a);
        int x = mp_table_add_col(&a, "XPSF_IMAGE");
        for (int i = 0; i < 1000; i++) {
            long r = mp_table_add_row(&a);
            mp_table_set(&a, (size_t)r, x, 0.5 + 4095.0 * i / 999.0 + 1e-3 * sin(i));
        }
        assert_int_equal(mp_table_write(path, &a, k ? MP_TAB_CSV : MP_TAB_ASCII_HEAD, err), 0);
        assert_int_equal(mp_table_read(path, &b, err), 0);
        for (size_t r = 0; r < a.nrow; r++)
            assert_true(fabs(mp_table_get(&a, r, x) - mp_table_get(&b, r, x)) <= 1e-5);
        mp_table_free(&a);
        mp_table_free(&b);
    }
}

static void test_stdin(void **state)
{
    fixture *f = *state;
    char path[512], err[MP_ERRLEN];
    path_in(f, "in.cat", path, sizeof path);
    const char *text = "#   1 NUMBER  Running object number\n"
                       "#   2 X_IMAGE Object position along x [pixel]\n"
                       "1 10.5\n2 20.5\n";
    write_text(path, text, strlen(text));
    assert_non_null(freopen(path, "r", stdin));
    mp_table t;
    assert_int_equal(mp_table_read("-", &t, err), 0);
    assert_int_equal(t.nrow, 2);
    assert_true(mp_table_get(&t, 1, 1) == 20.5);
    mp_table_free(&t);
}

/* ---- accepted inputs --------------------------------------------------- */

static void test_crlf_and_blank_lines(void **state)
{
    fixture *f = *state;
    char path[512], err[MP_ERRLEN];
    path_in(f, "crlf.cat", path, sizeof path);
    const char *text =
        "\r\n"
        "#   1 NUMBER                 Running object number                                     \r\n"
        "#   2 X_IMAGE                Object position along x                                    [pixel]\r\n"
        "# a comment that is not a column\r\n"
        "#   3 FLUX_MAX               Peak flux above background                                 [count]\r\n"
        "\r\n"
        "         1   100.1234   1.234567e+04\r\n"
        "   \t  \r\n"
        "         2   nan   INDEF\r\n"
        "# a comment among the data\r\n"
        "\n"
        "         3   -5.5   NaN";          /* no final line end */
    write_text(path, text, strlen(text));
    mp_table t;
    if (mp_table_read(path, &t, err) != 0)
        fail_msg("%s", err);
    assert_int_equal(t.ncol, 3);
    assert_int_equal(t.nrow, 3);
    assert_string_equal(t.cols[1].name, "X_IMAGE");
    assert_string_equal(t.cols[1].unit, "pixel");
    assert_string_equal(t.cols[2].desc, "Peak flux above background");
    assert_string_equal(t.cols[2].unit, "count");   /* the file's unit is kept */
    assert_true(mp_table_get(&t, 0, 1) == 100.1234);
    assert_true(mp_table_get(&t, 0, 2) == 12345.67);
    assert_true(isnan(mp_table_get(&t, 1, 1)));
    assert_true(isnan(mp_table_get(&t, 1, 2)));
    assert_true(mp_table_get(&t, 2, 1) == -5.5);
    assert_true(isnan(mp_table_get(&t, 2, 2)));
    mp_table_free(&t);

    /* The same as CSV with CRLF and blank lines. */
    path_in(f, "crlf.csv", path, sizeof path);
    const char *csv = "\r\nNUMBER,X_IMAGE\r\n\r\n1,2.5\r\n  \r\n2,\r\n";
    write_text(path, csv, strlen(csv));
    if (mp_table_read(path, &t, err) != 0)
        fail_msg("%s", err);
    assert_int_equal(t.nrow, 2);
    assert_true(mp_table_get(&t, 0, 1) == 2.5);
    assert_true(isnan(mp_table_get(&t, 1, 1)));
    mp_table_free(&t);
}

static void test_long_lines(void **state)
{
    fixture *f = *state;
    char path[512], err[MP_ERRLEN];

    /* 10 000 columns: the header and the ~110 kB row both read whole. */
    enum { NC = 10000 };
    size_t cap = (size_t)NC * 100 + 1000;
    char *text = malloc(cap);
    assert_non_null(text);
    size_t n = 0;
    for (int c = 0; c < NC; c++)
        n += (size_t)snprintf(text + n, cap - n, "# %3d C%d  column %d\n", c + 1, c, c);
    for (int c = 0; c < NC; c++)
        n += (size_t)snprintf(text + n, cap - n, "%s%.6f", c ? " " : "", c + 0.123456);
    n += (size_t)snprintf(text + n, cap - n, "\n");
    path_in(f, "wide.cat", path, sizeof path);
    write_text(path, text, n);
    mp_table t;
    if (mp_table_read(path, &t, err) != 0)
        fail_msg("%s", err);
    assert_int_equal(t.ncol, NC);
    assert_int_equal(t.nrow, 1);
    assert_true(mp_table_get(&t, 0, NC - 1) == NC - 1 + 0.123456);
    mp_table_free(&t);

    /* A 100 kB comment and a value padded by 100 kB of blanks. */
    n = 0;
    n += (size_t)snprintf(text + n, cap - n, "#   1 FLUX  a flux\n#");
    memset(text + n, 'x', 100000);
    n += 100000;
    text[n++] = '\n';
    memset(text + n, ' ', 100000);
    n += 100000;
    n += (size_t)snprintf(text + n, cap - n, "42\n");
    write_text(path, text, n);
    if (mp_table_read(path, &t, err) != 0)
        fail_msg("%s", err);
    assert_int_equal(t.nrow, 1);
    assert_true(mp_table_get(&t, 0, 0) == 42.0);
    mp_table_free(&t);

    /* And a 100 kB CSV row. */
    n = (size_t)snprintf(text, cap, "A,B\n");
    memset(text + n, ' ', 100000);
    n += 100000;
    n += (size_t)snprintf(text + n, cap - n, "1,2\n");
    path_in(f, "long.csv", path, sizeof path);
    write_text(path, text, n);
    if (mp_table_read(path, &t, err) != 0)
        fail_msg("%s", err);
    assert_true(mp_table_get(&t, 0, 1) == 2.0);
    mp_table_free(&t);
    free(text);
}

static void test_sextractor_vectors(void **state)
{
    fixture *f = *state;
    char path[512], err[MP_ERRLEN];
    path_in(f, "sex.cat", path, sizeof path);
    /* As SExtractor writes it, with MAG_APER(3) taking columns 3-5. */
    const char *text =
        "#   1 NUMBER                 Running object number                                     \n"
        "#   2 FLUX_PSF               Flux from PSF-fitting                                      [count]\n"
        "#   3 MAG_APER               Fixed aperture magnitude vector                            [mag]\n"
        "#   6 FLAGS                  Extraction flags                                          \n"
        "         1   1234.567  -7.7290 -7.8000 -7.8500   0\n"
        "         2   9.999e+05 -14.9999 99.0000 99.0000   3\n";
    write_text(path, text, strlen(text));
    mp_table t;
    if (mp_table_read(path, &t, err) != 0)
        fail_msg("%s", err);
    assert_int_equal(t.ncol, 6);
    assert_string_equal(t.cols[2].name, "MAG_APER");
    assert_string_equal(t.cols[3].name, "MAG_APER_1");
    assert_string_equal(t.cols[4].name, "MAG_APER_2");
    assert_string_equal(t.cols[4].unit, "mag");
    assert_string_equal(t.cols[5].name, "FLAGS");
    assert_true(mp_table_get(&t, 1, 1) == 9.999e5);
    assert_true(mp_table_get(&t, 1, 5) == 3);
    mp_table_free(&t);
}

/* IRAF's text databases (catalog/iraf_text.c), as DAOPHOT writes them:
 * allstar's .als (two lines a record, a string field), phot's .mag
 * (MAG and MERR written into each other, INDEF), and their errors. */
static void test_iraf_text(void **state)
{
    fixture *f = *state;
    char path[512], err[MP_ERRLEN];
    path_in(f, "im.als", path, sizeof path);
    const char *als =
        "#K IRAF       = CommunityIRAFV2.17      version    %-23s     \n"
        "#K TASK       = allstar                 name       %-23s     \n"
        "#\n"
        "#N ID    XCENTER   YCENTER   MAG         MERR          MSKY           NITER    \\\n"
        "#U ##    pixels    pixels    magnitudes  magnitudes    counts         ##       \\\n"
        "#F %-9d  %-10.3f   %-10.3f   %-12.3f     %-14.3f       %-15.7g        %-6d      \n"
        "#\n"
        "#N         SHARPNESS   CHI         PIER  PERROR                                \\\n"
        "#U         ##          ##          ##    perrors                               \\\n"
        "#F         %-23.3f     %-12.3f     %-6d  %-13s                                  \n"
        "#\n"
        "1        21.152    19.481    -13.144     0.017         98.24342       4        \\\n"
        "           -0.152      2.634       0     No_error                               \n"
        "47       230.482   63.008    INDEF       0.026         100.2233       4        \\\n"
        "           -0.130      0.866       0     No_error                               \n";
    write_text(path, als, strlen(als));
    mp_table t;
    if (mp_table_read(path, &t, err) != 0)
        fail_msg("%s", err);
    assert_int_equal(t.nrow, 2);
    assert_int_equal(t.ncol, 10);           /* PERROR, a string, left out */
    int cx = mp_table_col(&t, "X_IMAGE"), cn = mp_table_col(&t, "NUMBER");
    assert_true(cx >= 0 && cn >= 0 && mp_table_col(&t, "PERROR") < 0);
    assert_true(mp_table_get(&t, 1, cx) == 230.482);
    assert_true(mp_table_get(&t, 1, cn) == 47);
    assert_true(isnan(mp_table_get(&t, 1, mp_table_col(&t, "MAG"))));
    assert_true(mp_table_get(&t, 0, mp_table_col(&t, "CHI")) == 2.634);
    assert_string_equal(t.cols[cx].unit, "pixels");
    mp_table_free(&t);

    /* fields written into each other: read at their widths */
    path_in(f, "im.mag", path, sizeof path);
    const char *mag =
        "#N RAPERT   SUM           AREA       FLUX          MAG    MERR   PIER PERROR   \\\n"
        "#F %-12.2f  %-14.7g       %-11.7g    %-14.7g       %-7.3f %-6.3f %-5d %-9s      \n"
        "   3.00     84982.69      28.49881   82145.09      -12.2860.004 0    NoError    \n";
    write_text(path, mag, strlen(mag));
    if (mp_table_read(path, &t, err) != 0)
        fail_msg("%s", err);
    assert_true(mp_table_get(&t, 0, mp_table_col(&t, "MAG")) == -12.286);
    assert_true(mp_table_get(&t, 0, mp_table_col(&t, "MERR")) == 0.004);
    assert_true(mp_table_get(&t, 0, mp_table_col(&t, "FLUX")) == 82145.09);
    mp_table_free(&t);

    /* phot's last line once an aperture, marked '*': MAG_1, MERR_1 ... */
    path_in(f, "ap3.mag", path, sizeof path);
    const char *ap3 =
        "#N ID    XCENTER   \\\n"
        "#F %-6d %-10.3f   \n"
        "#N RAPERT   SUM           AREA       FLUX          MAG    MERR   PIER PERROR   \\\n"
        "#F %-12.2f  %-14.7g       %-11.7g    %-14.7g       %-7.3f %-6.3f %-5d %-9s      \n"
        "1      218.849     \\\n"
        "   3.00     84982.69      28.49881   82145.09      -12.2860.004 0    NoError  *\\\n"
        "   5.00     97097.8       78.8533    89246.45      -12.3760.004 0    NoError  *\\\n"
        "   7.00     104796.4      154.4323   89419.69      INDEF  INDEF  0    NoError  * \n";
    write_text(path, ap3, strlen(ap3));
    if (mp_table_read(path, &t, err) != 0)
        fail_msg("%s", err);
    assert_int_equal(t.nrow, 1);
    assert_true(mp_table_get(&t, 0, mp_table_col(&t, "MAG")) == -12.286);
    assert_true(mp_table_get(&t, 0, mp_table_col(&t, "MAG_1")) == -12.376);
    assert_true(mp_table_get(&t, 0, mp_table_col(&t, "RAPERT_2")) == 7);
    assert_true(isnan(mp_table_get(&t, 0, mp_table_col(&t, "MERR_2"))));
    assert_true(mp_table_col(&t, "PERROR_1") < 0);
    mp_table_free(&t);

    /* a record cut short; a header without its formats; not a number */
    path_in(f, "cut.als", path, sizeof path);
    write_text(path, als, strlen(als) - 81);
    char want[700];
    snprintf(want, sizeof want, "%s:14: the last record ends in '\\' (truncated)", path);
    expect_read_error(path, want);
    path_in(f, "nofmt.coo", path, sizeof path);
    const char *nofmt = "#N XCENTER YCENTER ID\n   1.0 2.0 3\n";
    write_text(path, nofmt, strlen(nofmt));
    snprintf(want, sizeof want, "%s: an IRAF text table whose header does not give a format to "
             "each name (3 names on 1 #N lines, 0 formats on 0 #F lines)", path);
    expect_read_error(path, want);
    path_in(f, "bad.coo", path, sizeof path);
    const char *bad = "#N XCENTER YCENTER ID\n#F %-10.3f %-10.3f %-6d\n   1.0 abc 3\n";
    write_text(path, bad, strlen(bad));
    snprintf(want, sizeof want, "%s:3: 'abc' in field YCENTER is not a number", path);
    expect_read_error(path, want);
}

/* Stetson's DAOPHOT II tables (catalog/daophot2.c): ALLSTAR's .als (NL
 * 1, an X of 10⁴ px touching its ID), PHOTOMETRY's .ap (NL 2, two lines a
 * star), GROUP's .grp (NL 3, groups parted by blank lines), and errors. */
static void test_daophot2(void **state)
{
    fixture *f = *state;
    char path[512], err[MP_ERRLEN], want[700];
    const char *head = " NL    NX    NY  LOWBAD HIGHBAD  THRESH     AP1  PH/ADU  RNOISE    FRAD\n";
    char text[2048];
    path_in(f, "f.als", path, sizeof path);
    snprintf(text, sizeof text, "%s%s", head,
             "  1 20480  4096   129.5 32766.5   28.56    3.00    1.70    4.68    2.00\n\n"
             "     1   64.700   64.600  -13.000   0.0050  100.000     4.    0.970   0.010\n"
             "    2012345.678   40.110   -9.500   0.0450  100.120     5.    1.020  -0.050\n");
    write_text(path, text, strlen(text));
    mp_table t;
    if (mp_table_read(path, &t, err) != 0)
        fail_msg("%s", err);
    assert_int_equal(t.ncol, 9);
    assert_int_equal(t.nrow, 2);
    assert_string_equal(t.cols[8].name, "SHARPNESS");
    assert_true(mp_table_get(&t, 1, mp_table_col(&t, "NUMBER")) == 20);
    assert_true(mp_table_get(&t, 1, mp_table_col(&t, "X_IMAGE")) == 12345.678);
    assert_true(mp_table_get(&t, 1, mp_table_col(&t, "CHI")) == 1.02);
    mp_table_free(&t);

    path_in(f, "f.ap", path, sizeof path);
    snprintf(text, sizeof text, "%s%s", head,
             "  2   512   512   129.5 32766.5   28.56    3.00    1.70    4.68    2.00\n\n"
             "     1   64.700   64.600   13.000   13.500\n"
             "     100.000  5.20  0.10   0.0050   0.0060\n\n"
             "     2   30.210   40.110   16.500   16.900\n"
             "     100.120  5.10  0.05   0.0450   0.0500\n");
    write_text(path, text, strlen(text));
    if (mp_table_read(path, &t, err) != 0)
        fail_msg("%s", err);
    assert_int_equal(t.nrow, 2);
    assert_int_equal(t.ncol, 10);
    assert_true(mp_table_get(&t, 1, mp_table_col(&t, "MAG_1")) == 16.9);
    assert_true(mp_table_get(&t, 1, mp_table_col(&t, "MSKY")) == 100.12);
    assert_true(mp_table_get(&t, 1, mp_table_col(&t, "MERR_1")) == 0.05);
    mp_table_free(&t);
    /* cut after a record's first line */
    write_text(path, text, strlen(text) - 43);
    snprintf(want, sizeof want, "%s:7: the last record has its first line only (truncated)",
             path);
    expect_read_error(path, want);

    path_in(f, "f.grp", path, sizeof path);
    snprintf(text, sizeof text, "%s%s", head,
             "  3   512   512   129.5 32766.5   28.56    3.00    1.70    4.68    2.00\n\n"
             "     1   64.700   64.600   13.000   0.0050  100.000\n"
             "     5   66.700   64.600   15.000   0.0050  100.000\n\n\n"
             "     2   30.210   40.110   16.500   0.0450  100.120\n");
    write_text(path, text, strlen(text));
    if (mp_table_read(path, &t, err) != 0)
        fail_msg("%s", err);
    int cg = mp_table_col(&t, "GROUP_ID");
    assert_true(cg >= 0);
    assert_true(mp_table_get(&t, 1, cg) == 1 && mp_table_get(&t, 2, cg) == 2);
    mp_table_free(&t);

    path_in(f, "bad.als", path, sizeof path);
    snprintf(text, sizeof text, "%s%s", head,
             "  5   512   512   129.5 32766.5   28.56    3.00    1.70    4.68    2.00\n\n");
    write_text(path, text, strlen(text));
    snprintf(want, sizeof want, "%s:2: a DAOPHOT II header whose NL is not 1, 2 or 3", path);
    expect_read_error(path, want);
    snprintf(text, sizeof text, "%s%s", head,
             "  1   512   512   129.5 32766.5   28.56    3.00    1.70    4.68    2.00\n\n"
             "     1   64.700   64.600  -13.000\n     2   30.210   40.110\n");
    write_text(path, text, strlen(text));
    snprintf(want, sizeof want, "%s:5: a record of 3 fields, where the first had 4", path);
    expect_read_error(path, want);
}

static void test_csv_quoted_header(void **state)
{
    fixture *f = *state;
    char path[512], err[MP_ERRLEN];
    path_in(f, "q.csv", path, sizeof path);
    const char *text = "\xEF\xBB\xBF\"NUMBER\", \"X_IMAGE\" ,\"A,B\",\"SAY \"\"HI\"\"\"\n"
                       "1,\"2.5\",NaN,INDEF\n"
                       "2,,\"\",nan\n";
    write_text(path, text, strlen(text));
    mp_table t;
    if (mp_table_read(path, &t, err) != 0)
        fail_msg("%s", err);
    assert_int_equal(t.ncol, 4);
    assert_string_equal(t.cols[0].name, "NUMBER");
    assert_string_equal(t.cols[1].name, "X_IMAGE");
    assert_string_equal(t.cols[1].unit, "pixel");   /* known: registry's */
    assert_string_equal(t.cols[2].name, "A,B");
    assert_string_equal(t.cols[3].name, "SAY \"HI\"");
    assert_true(mp_table_get(&t, 0, 1) == 2.5);
    for (int c = 1; c < 4; c++)
        assert_true(isnan(mp_table_get(&t, 1, c)));

    /* Such names survive a CSV round trip but cannot be ASCII_HEAD columns. */
    char out[512];
    path_in(f, "q2.csv", out, sizeof out);
    assert_int_equal(mp_table_write(out, &t, MP_TAB_CSV, err), 0);
    mp_table u;
    assert_int_equal(mp_table_read(out, &u, err), 0);
    assert_string_equal(u.cols[3].name, "SAY \"HI\"");
    mp_table_free(&u);
    path_in(f, "q.cat", out, sizeof out);
    assert_int_not_equal(mp_table_write(out, &t, MP_TAB_ASCII_HEAD, err), 0);
    assert_non_null(strstr(err, "SAY"));
    assert_int_equal(access(out, F_OK), -1);
    mp_table_free(&t);
}

/* A BOM alone on a blank first line: the next line tells the format, so
 * "# 1 NUMBER" starts ASCII_HEAD column definitions, not a CSV header
 * named "# 1 NUMBER" (a fuzzer's find: such a table could not be written
 * back). */
static void test_bom_blank_first_line(void **state)
{
    fixture *f = *state;
    char path[512], err[MP_ERRLEN];
    path_in(f, "bom.cat", path, sizeof path);
    const char *text = "\xEF\xBB\xBF  \n"
                       "\n"
                       "#   1 NUMBER   Running object number\n"
                       "#   2 X_IMAGE  Object position along x  [pixel]\n"
                       "7 3.5\n";
    write_text(path, text, strlen(text));
    mp_table t;
    if (mp_table_read(path, &t, err) != 0)
        fail_msg("%s", err);
    assert_int_equal(t.ncol, 2);
    assert_string_equal(t.cols[0].name, "NUMBER");
    assert_int_equal(t.nrow, 1);
    assert_true(mp_table_get(&t, 0, 1) == 3.5);
    mp_table_free(&t);
}

/* ---- rejected inputs --------------------------------------------------- */

static void test_errors(void **state)
{
    fixture *f = *state;
    char path[512], msg[1024];

    /* Text in a number, with the line number (blank line counted). */
    path_in(f, "stars.coo", path, sizeof path);
    const char *t1 = "#   1 NUMBER   Running object number\n"
                     "#   2 X_IMAGE  Object position along x  [pixel]\n"
                     "\n"
                     "1 2.0\n"
                     "2 abc\n";
    write_text(path, t1, strlen(t1));
    snprintf(msg, sizeof msg, "%s:5: 'abc' in column X_IMAGE is not a number", path);
    expect_read_error(path, msg);

    /* Wrong field count. */
    const char *t2 = "#   1 NUMBER   Running object number\n"
                     "#   2 X_IMAGE  Object position along x  [pixel]\n"
                     "1 2.0 3.0\n";
    write_text(path, t2, strlen(t2));
    snprintf(msg, sizeof msg, "%s:3: 3 fields, header has 2 columns", path);
    expect_read_error(path, msg);

    /* The same in CSV. */
    path_in(f, "stars.csv", path, sizeof path);
    const char *t3 = "NUMBER,X_IMAGE\n1,2\n2,x1\n";
    write_text(path, t3, strlen(t3));
    snprintf(msg, sizeof msg, "%s:3: 'x1' in column X_IMAGE is not a number", path);
    expect_read_error(path, msg);
    const char *t4 = "NUMBER,X_IMAGE\n1,2\n\n2\n";
    write_text(path, t4, strlen(t4));
    snprintf(msg, sizeof msg, "%s:4: 1 field, header has 2 columns", path);
    expect_read_error(path, msg);

    /* Missing header: numbers where the names should be. */
    const char *t5 = "1.0 2.0 3.0\n4.0 5.0 6.0\n";
    write_text(path, t5, strlen(t5));
    snprintf(msg, sizeof msg, "%s:1: no header row: '1.0 2.0 3.0' is a number, "
             "not a column name", path);
    expect_read_error(path, msg);
    const char *t6 = "1,2,3\n";
    write_text(path, t6, strlen(t6));
    snprintf(msg, sizeof msg, "%s:1: no header row: '1' is a number, not a column name", path);
    expect_read_error(path, msg);
    const char *t7 = "# made by hand\n1 2 3\n";
    write_text(path, t7, strlen(t7));
    snprintf(msg, sizeof msg, "%s:2: data before any column definition "
             "(\"#   1 NAME  description  [unit]\")", path);
    expect_read_error(path, msg);

    /* A header with no columns. */
    const char *t8 = "# nothing here\n#\n";
    write_text(path, t8, strlen(t8));
    snprintf(msg, sizeof msg, "%s: header has no column definitions", path);
    expect_read_error(path, msg);

    /* Empty, or blank only. */
    write_text(path, "", 0);
    snprintf(msg, sizeof msg, "%s: empty file", path);
    expect_read_error(path, msg);
    write_text(path, "\n  \r\n\n", 6);
    expect_read_error(path, msg);

    /* Gzipped (a FITS table's or a text table's bytes alike): one line
     * naming it, not its binary bytes quoted as a number. */
    path_in(f, "stars.cat.gz", path, sizeof path);
    write_text(path, "\x1f\x8b\x08\x00\x00\x00\x00\x00\x00\x03+.I,*V\x00", 18);
    snprintf(msg, sizeof msg, "%s: a compressed file (gzip or compress: its first byte is "
             "0x1f); a table is read uncompressed: gzip -dc it to a file, or pipe it in as -",
             path);
    expect_read_error(path, msg);

    /* Missing. */
    path_in(f, "missing.coo", path, sizeof path);
    snprintf(msg, sizeof msg, "%s: cannot open: No such file or directory", path);
    expect_read_error(path, msg);

    /* Duplicate and out-of-order columns. */
    path_in(f, "dup.cat", path, sizeof path);
    const char *t9 = "#   1 NUMBER  n\n#   2 NUMBER  n\n";
    write_text(path, t9, strlen(t9));
    snprintf(msg, sizeof msg, "%s:2: column NUMBER defined twice", path);
    expect_read_error(path, msg);
    const char *t10 = "#   2 NUMBER  n\n";
    write_text(path, t10, strlen(t10));
    snprintf(msg, sizeof msg, "%s:1: first column is numbered 2, not 1", path);
    expect_read_error(path, msg);
    const char *t11 = "NUMBER,X,NUMBER\n";
    write_text(path, t11, strlen(t11));
    snprintf(msg, sizeof msg, "%s:1: column NUMBER appears twice", path);
    expect_read_error(path, msg);
}

/* ---- atomic output ----------------------------------------------------- */

static void test_atomic_write(void **state)
{
    fixture *f = *state;
    char path[512], err[MP_ERRLEN];
    mp_table t;
    sample_table(&t);

    /* Into a directory that does not exist: an error naming the path. */
    path_in(f, "no_such_dir/out.cat", path, sizeof path);
    assert_int_not_equal(mp_table_write(path, &t, MP_TAB_ASCII_HEAD, err), 0);
    assert_non_null(strstr(err, path));
    assert_int_equal(count_entries(f->dir), 0);

    /* A write refused after the output was opened (a name ASCII_HEAD
     * cannot hold) leaves the older file as it was and no temporary. */
    path_in(f, "out.cat", path, sizeof path);
    write_text(path, "old\n", 4);
    int bad = mp_table_add_col(&t, "NOT A NAME");
    assert_true(bad >= 0);
    assert_int_not_equal(mp_table_write(path, &t, MP_TAB_ASCII_HEAD, err), 0);
    assert_non_null(strstr(err, path));
    char *got = slurp(path);
    assert_string_equal(got, "old\n");
    free(got);
    assert_int_equal(count_entries(f->dir), 1);

    /* A table without columns is refused the same way. */
    mp_table e;
    mp_table_init(&e);
    assert_int_not_equal(mp_table_write(path, &e, MP_TAB_CSV, err), 0);
    assert_int_equal(count_entries(f->dir), 1);
    mp_table_free(&e);
    mp_table_free(&t);
}

/* ---- sample for the astropy e2e check --------------------------------- */

static void test_sample_out(void **state)
{
    (void)state;
    const char *out = getenv("MP_SAMPLE_OUT");
    if (!out || !*out)
        skip();
    char err[MP_ERRLEN], csv[1024];
    mp_table t;
    sample_table(&t);
    if (mp_table_write(out, &t, MP_TAB_ASCII_HEAD, err) != 0)
        fail_msg("%s", err);
    snprintf(csv, sizeof csv, "%s.csv", out);
    if (mp_table_write(csv, &t, MP_TAB_CSV, err) != 0)
        fail_msg("%s", err);
    mp_table_free(&t);
}

int main(void)
{
    const struct CMUnitTest tests[] = {
        cmocka_unit_test(test_table_model),
        cmocka_unit_test(test_table_add_cols),
        cmocka_unit_test(test_ascii_rows_threads),
        cmocka_unit_test(test_registry),
        cmocka_unit_test(test_parse_value),
        cmocka_unit_test(test_format_parse),
        cmocka_unit_test_setup_teardown(test_header_bytes, setup, teardown),
        cmocka_unit_test_setup_teardown(test_round_trip_ascii, setup, teardown),
        cmocka_unit_test_setup_teardown(test_round_trip_csv, setup, teardown),
        cmocka_unit_test_setup_teardown(test_positions_precision, setup, teardown),
        cmocka_unit_test_setup_teardown(test_stdin, setup, teardown),
        cmocka_unit_test_setup_teardown(test_crlf_and_blank_lines, setup, teardown),
        cmocka_unit_test_setup_teardown(test_long_lines, setup, teardown),
        cmocka_unit_test_setup_teardown(test_sextractor_vectors, setup, teardown),
        cmocka_unit_test_setup_teardown(test_bom_blank_first_line, setup, teardown),
        cmocka_unit_test_setup_teardown(test_csv_quoted_header, setup, teardown),
        cmocka_unit_test_setup_teardown(test_iraf_text, setup, teardown),
        cmocka_unit_test_setup_teardown(test_daophot2, setup, teardown),
        cmocka_unit_test_setup_teardown(test_errors, setup, teardown),
        cmocka_unit_test_setup_teardown(test_atomic_write, setup, teardown),
        cmocka_unit_test(test_integer_columns),
        cmocka_unit_test(test_float_columns),
        cmocka_unit_test_setup_teardown(test_write_kept_same_bytes, setup, teardown),
        cmocka_unit_test_setup_teardown(test_write_kept_prefix, setup, teardown),
        cmocka_unit_test_setup_teardown(test_write_kept_budget, setup, teardown),
        cmocka_unit_test(test_sample_out),
    };
    return cmocka_run_group_tests(tests, NULL, NULL);
}
