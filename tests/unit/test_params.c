/* test_params.c — params/: .par parsing and writing, checks, command line,
 * @files, lists, compiled-in defaults. */
#include <math.h>
#include <setjmp.h>
#include <stdarg.h>
#include <stddef.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <unistd.h>

#include <cmocka.h>

#include "params/params.h"

static const char *TEXT =
    "# a test task\n"
    "image,f,a,,,,\"Input image\"\n"
    "coords,f,a,\"\",,,\"Input table\"\n"
    "fitrad,r,h,3.0,0,1000,\"Fitting radius [px], INDEF = all\"\n"
    "nx,i,h,INDEF,1,,\"Width\"\n"
    "gain,r,h,INDEF,>0,,\"Gain [e-/ADU]\"\n"
    "mode,s,h,single,single|crowded,,\"Fit mode\"\n"
    "algo,s,h,\"none\",\"|centroid|gauss|none|\",,\"IRAF-style enumeration\"\n"
    "verbose,b,h,yes,,,\"Say more\"\n"
    "title,s,h,\"a, \\\"quoted\\\" \\\\ title\",,,\"Title, with commas\"\n"
    "note,s,h,plain,,,unquoted prompt, with a comma\n";

/* A scratch directory for files, removed by the teardown. */
typedef struct {
    char dir[64];
    char path[128];
} scratch;

static int setup(void **state)
{
    scratch *s = calloc(1, sizeof *s);
    if (!s)
        return -1;
    strcpy(s->dir, "/tmp/test_params.XXXXXX");
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
    char cmd[128];
    snprintf(cmd, sizeof cmd, "rm -rf '%s'", s->dir);
    if (system(cmd) != 0)
        return -1;
    free(s);
    return 0;
}

/* Write text to DIR/name; return the path (in the scratch). */
static const char *put_file(void **state, const char *name, const char *text)
{
    scratch *s = *state;
    snprintf(s->path, sizeof s->path, "%s/%s", s->dir, name);
    FILE *fp = fopen(s->path, "wb");
    assert_non_null(fp);
    fputs(text, fp);
    assert_int_equal(fclose(fp), 0);
    return s->path;
}

static void parse_ok(const char *text, mp_parset *ps)
{
    char err[MP_ERRLEN] = "";
    int rc = mp_params_parse_text(text, "t.par", ps, err);
    if (rc)
        fail_msg("parse failed: %s", err);
}

static int ends_with(const char *s, const char *tail)
{
    size_t n = strlen(s), k = strlen(tail);
    return n >= k && !strcmp(s + n - k, tail);
}

#define assert_err(got, want) do {                                      \
        if (strcmp((got), (want)))                                      \
            fail_msg("error text\n  got:  %s\n  want: %s", (got), (want)); \
    } while (0)

/* ---- parsing ------------------------------------------------------------ */

static void test_parse_fields(void **state)
{
    (void)state;
    mp_parset ps;
    parse_ok(TEXT, &ps);
    assert_int_equal(ps.n, 10);
    assert_string_equal(ps.task, "t");
    assert_string_equal(ps.p[0].name, "image");
    assert_int_equal(ps.p[0].type, MP_PAR_FILE);
    assert_string_equal(ps.p[0].mode, "a");
    assert_string_equal(ps.p[0].value, "");
    assert_string_equal(ps.p[2].prompt, "Fitting radius [px], INDEF = all");
    assert_string_equal(ps.p[2].min, "0");
    assert_string_equal(ps.p[2].max, "1000");
    assert_string_equal(mp_par_string(&ps, "title"), "a, \"quoted\" \\ title");
    assert_string_equal(ps.p[9].prompt, "unquoted prompt, with a comma");
    assert_int_equal(ps.p[7].type, MP_PAR_BOOL);
    mp_params_free(&ps);
}

static void test_optional_fields_and_comments(void **state)
{
    (void)state;
    mp_parset ps;
    parse_ok("\n   # comment\n\nx,r,h\ny , i , h , 4 \n", &ps);
    assert_int_equal(ps.n, 2);
    assert_string_equal(ps.p[0].value, "");
    assert_string_equal(ps.p[0].prompt, "");
    assert_string_equal(ps.p[1].value, "4");
    int v = 0;
    assert_int_equal(mp_par_int(&ps, "y", &v), 0);
    assert_int_equal(v, 4);
    mp_params_free(&ps);
}

static void test_crlf(void **state)
{
    (void)state;
    mp_parset ps;
    parse_ok("# dos\r\nfitrad,r,h,3.0,0,10,\"Radius\"\r\nname,s,h,\"x\",,,\"Name\"\r\n", &ps);
    assert_int_equal(ps.n, 2);
    assert_string_equal(ps.p[0].prompt, "Radius");
    assert_string_equal(mp_par_string(&ps, "name"), "x");
    double r = 0;
    assert_int_equal(mp_par_real(&ps, "fitrad", &r), 0);
    assert_true(r == 3.0);
    mp_params_free(&ps);
}

static void test_crlf_file(void **state)
{
    mp_parset ps;
    char err[MP_ERRLEN] = "";
    parse_ok(TEXT, &ps);
    const char *path = put_file(state, "dos.par", "fitrad,r,h,7.5,,,\"\"\r\nmode,s,h,crowded\r\n");
    assert_int_equal(mp_params_load_file(&ps, path, err), 0);
    assert_string_equal(mp_par_string(&ps, "fitrad"), "7.5");
    assert_string_equal(mp_par_string(&ps, "mode"), "crowded");
    mp_params_free(&ps);
}

static void test_malformed(void **state)
{
    (void)state;
    static const char *bad[] = {
        "ok,r,h,1\nx,r\n",                   /* too few fields */
        "ok,r,h,1\nx,s,h,\"unterminated\n",   /* open quote */
        "ok,r,h,1\nx,s,h,\"a\"b,,,\"\"\n",    /* text after a quote */
        "ok,r,h,1\n9x,r,h,1\n",               /* bad name */
        "ok,r,h,1\nx,r,,1\n",                 /* empty mode */
        "ok,r,h,1\nx,r,h,1,,,\"p\" junk\n",   /* junk after prompt */
    };
    for (size_t i = 0; i < sizeof bad / sizeof bad[0]; i++) {
        mp_parset ps;
        char err[MP_ERRLEN] = "";
        assert_int_not_equal(mp_params_parse_text(bad[i], "my.par", &ps, err), 0);
        assert_err(err, "my.par:2: malformed line (expected name,type,mode,value,min,max,prompt)");
        assert_null(ps.p);
        assert_int_equal(ps.n, 0);
    }
}

static void test_bad_type_and_duplicate(void **state)
{
    (void)state;
    mp_parset ps;
    char err[MP_ERRLEN];
    assert_int_not_equal(mp_params_parse_text("x,gcur,h\n", "my.par", &ps, err), 0);
    assert_err(err, "my.par:1: x: type 'gcur' is not supported (b, i, r, s, f or pset)");
    assert_int_not_equal(mp_params_parse_text("x,r,h\nx,i,h\n", "my.par", &ps, err), 0);
    assert_err(err, "my.par:2: x: defined twice");
    assert_int_not_equal(mp_params_parse_text("x,r,h,5,zero,\n", "my.par", &ps, err), 0);
    assert_err(err, "my.par:1: x: minimum 'zero' is not a number");
}

static void test_default_checked(void **state)
{
    (void)state;
    mp_parset ps;
    char err[MP_ERRLEN];
    assert_int_not_equal(
        mp_params_parse_text("# c\n\nfitrad,r,h,-3,0,1000,\"r\"\n", "fit.par", &ps, err), 0);
    assert_err(err, "fit.par:3: fitrad: -3 is outside [0, 1000]");
}

/* ---- round trip ---------------------------------------------------------- */

static void assert_same(const mp_parset *a, const mp_parset *b)
{
    assert_int_equal(a->n, b->n);
    for (size_t i = 0; i < a->n; i++) {
        assert_string_equal(a->p[i].name, b->p[i].name);
        assert_int_equal(a->p[i].type, b->p[i].type);
        assert_string_equal(a->p[i].mode, b->p[i].mode);
        assert_string_equal(a->p[i].value, b->p[i].value);
        assert_string_equal(a->p[i].min, b->p[i].min);
        assert_string_equal(a->p[i].max, b->p[i].max);
        assert_string_equal(a->p[i].prompt, b->p[i].prompt);
    }
}

static void round_trip(const mp_parset *ps)
{
    char *buf = NULL;
    size_t len = 0;
    FILE *fp = open_memstream(&buf, &len);
    assert_non_null(fp);
    mp_params_write(ps, fp);
    assert_int_equal(fclose(fp), 0);
    mp_parset back;
    char err[MP_ERRLEN] = "";
    if (mp_params_parse_text(buf, "written.par", &back, err))
        fail_msg("written text does not parse: %s\n%s", err, buf);
    assert_same(ps, &back);
    mp_params_free(&back);
    free(buf);
}

static void test_round_trip(void **state)
{
    (void)state;
    mp_parset ps;
    char err[MP_ERRLEN] = "";
    parse_ok(TEXT, &ps);
    round_trip(&ps);
    /* Values that need quoting, set through the checked path. */
    assert_int_equal(mp_params_set(&ps, "title", "x,\"y\"\\z, ", err), 0);
    assert_int_equal(mp_params_set(&ps, "image", "f.fits[1:10,1:10]", err), 0);
    assert_int_equal(mp_params_set(&ps, "verbose", "n", err), 0);
    round_trip(&ps);
    mp_params_free(&ps);
}

static void test_round_trip_defaults(void **state)
{
    (void)state;
    const char *const *t = mp_params_tasks();
    assert_non_null(t);
    assert_non_null(t[0]);
    for (size_t i = 0; t[i]; i++) {
        mp_parset ps;
        char err[MP_ERRLEN] = "";
        if (mp_params_defaults(t[i], &ps, err))
            fail_msg("defaults of %s: %s", t[i], err);
        round_trip(&ps);
        mp_params_free(&ps);
    }
}

/* ---- values -------------------------------------------------------------- */

static void test_indef(void **state)
{
    (void)state;
    mp_parset ps;
    char err[MP_ERRLEN];
    parse_ok(TEXT, &ps);
    double g = 0;
    int nx = 0;
    assert_int_equal(mp_par_real(&ps, "gain", &g), 0);
    assert_true(isnan(g));
    assert_int_equal(mp_par_int(&ps, "nx", &nx), 0);
    assert_int_equal(nx, MP_PAR_INDEF_INT);
    assert_string_equal(mp_par_string(&ps, "image"), "");
    assert_int_equal(mp_params_set(&ps, "fitrad", "indef", err), 0);
    assert_string_equal(ps.p[2].value, "INDEF");
    assert_int_equal(mp_par_real(&ps, "fitrad", &g), 0);
    assert_true(isnan(g));
    assert_int_equal(mp_params_set(&ps, "nx", "12", err), 0);
    assert_int_equal(mp_par_int(&ps, "nx", &nx), 0);
    assert_int_equal(nx, 12);
    mp_params_free(&ps);
}

static void test_ranges(void **state)
{
    (void)state;
    mp_parset ps;
    char err[MP_ERRLEN];
    parse_ok(TEXT, &ps);
    assert_int_equal(mp_params_set(&ps, "fitrad", "0", err), 0);      /* inclusive */
    assert_int_equal(mp_params_set(&ps, "fitrad", "1000", err), 0);
    assert_int_not_equal(mp_params_set(&ps, "fitrad", "-3", err), 0);
    assert_err(err, "fitrad: -3 is outside [0, 1000]");
    assert_int_not_equal(mp_params_set(&ps, "fitrad", "1000.5", err), 0);
    assert_err(err, "fitrad: 1000.5 is outside [0, 1000]");
    assert_string_equal(mp_par_string(&ps, "fitrad"), "1000");     /* unchanged */
    assert_int_not_equal(mp_params_set(&ps, "gain", "0", err), 0);    /* exclusive */
    assert_err(err, "gain: 0 is outside (0, inf)");
    assert_int_equal(mp_params_set(&ps, "gain", "1e-3", err), 0);
    assert_int_not_equal(mp_params_set(&ps, "nx", "0", err), 0);
    assert_err(err, "nx: 0 is outside [1, inf)");
    assert_int_not_equal(mp_params_set(&ps, "nx", "abc", err), 0);
    assert_err(err, "nx: 'abc' is not an integer");
    assert_int_not_equal(mp_params_set(&ps, "nx", "2.5", err), 0);
    assert_err(err, "nx: '2.5' is not an integer");
    assert_int_not_equal(mp_params_set(&ps, "nx", "99999999999", err), 0);
    assert_int_not_equal(mp_params_set(&ps, "fitrad", "3x", err), 0);
    assert_err(err, "fitrad: '3x' is not a number");
    assert_int_not_equal(mp_params_set(&ps, "fitrad", "nan", err), 0);
    assert_int_not_equal(mp_params_set(&ps, "verbose", "maybe", err), 0);
    assert_err(err, "verbose: 'maybe' is not a boolean (yes or no)");
    mp_params_free(&ps);
}

static void test_enumeration(void **state)
{
    (void)state;
    mp_parset ps;
    char err[MP_ERRLEN];
    parse_ok(TEXT, &ps);
    assert_int_equal(mp_params_set(&ps, "mode", "crowded", err), 0);
    assert_string_equal(mp_par_string(&ps, "mode"), "crowded");
    assert_int_not_equal(mp_params_set(&ps, "mode", "foo", err), 0);
    assert_err(err, "mode: 'foo' is not one of single|crowded");
    assert_int_not_equal(mp_params_set(&ps, "mode", "", err), 0);
    assert_int_not_equal(mp_params_set(&ps, "mode", "singl", err), 0);
    assert_int_equal(mp_params_set(&ps, "algo", "gauss", err), 0);
    assert_int_not_equal(mp_params_set(&ps, "algo", "mode", err), 0);
    assert_err(err, "algo: 'mode' is not one of centroid|gauss|none");
    mp_params_free(&ps);
}

static void test_bool(void **state)
{
    (void)state;
    mp_parset ps;
    char err[MP_ERRLEN];
    int b = -1;
    parse_ok(TEXT, &ps);
    assert_int_equal(mp_par_bool(&ps, "verbose", &b), 0);
    assert_int_equal(b, 1);
    assert_int_equal(mp_params_set(&ps, "verbose", "No", err), 0);
    assert_string_equal(mp_par_string(&ps, "verbose"), "no");
    assert_int_equal(mp_par_bool(&ps, "verbose", &b), 0);
    assert_int_equal(b, 0);
    /* Asking for what is not there, or for the wrong type. */
    assert_int_not_equal(mp_par_bool(&ps, "nosuch", &b), 0);
    assert_int_not_equal(mp_par_bool(&ps, "fitrad", &b), 0);
    assert_null(mp_par_string(&ps, "nosuch"));
    mp_params_free(&ps);
}

/* ---- command line -------------------------------------------------------- */

static void test_overrides(void **state)
{
    (void)state;
    mp_parset ps;
    char err[MP_ERRLEN] = "";
    parse_ok(TEXT, &ps);
    char *argv[] = { "img.fits", "img.coo", "fitrad=4", "verbose-", "mode=crowded",
                     "title=a=b" };
    if (mp_params_cmdline(&ps, 6, argv, err))
        fail_msg("%s", err);
    assert_string_equal(mp_par_string(&ps, "image"), "img.fits");
    assert_string_equal(mp_par_string(&ps, "coords"), "img.coo");
    assert_string_equal(mp_par_string(&ps, "fitrad"), "4");
    assert_string_equal(mp_par_string(&ps, "verbose"), "no");
    assert_string_equal(mp_par_string(&ps, "title"), "a=b");
    assert_int_equal(ps.p[2].set, 1);
    assert_int_equal(ps.p[3].set, 0);
    mp_params_free(&ps);
}

static void test_positional(void **state)
{
    (void)state;
    mp_parset ps;
    char err[MP_ERRLEN] = "";
    /* A named query parameter is skipped by the bare words. */
    parse_ok(TEXT, &ps);
    char *a1[] = { "image=a.fits", "b.coo" };
    assert_int_equal(mp_params_cmdline(&ps, 2, a1, err), 0);
    assert_string_equal(mp_par_string(&ps, "image"), "a.fits");
    assert_string_equal(mp_par_string(&ps, "coords"), "b.coo");
    mp_params_free(&ps);
    /* An @list that is not a .par file is a value. */
    parse_ok(TEXT, &ps);
    char *a2[] = { "@frames.lis", "@coo.lis" };
    assert_int_equal(mp_params_cmdline(&ps, 2, a2, err), 0);
    assert_string_equal(mp_par_string(&ps, "image"), "@frames.lis");
    mp_params_free(&ps);
    /* Too many words. */
    parse_ok(TEXT, &ps);
    char *a3[] = { "a", "b", "c" };
    assert_int_not_equal(mp_params_cmdline(&ps, 3, a3, err), 0);
    assert_err(err, "'c': unexpected argument (task t takes only image coords)");
    mp_params_free(&ps);
    /* Missing query parameter. */
    parse_ok(TEXT, &ps);
    char *a4[] = { "a.fits" };
    assert_int_not_equal(mp_params_cmdline(&ps, 1, a4, err), 0);
    assert_err(err, "coords: required (query) parameter not given");
    mp_params_free(&ps);
    parse_ok(TEXT, &ps);
    assert_int_not_equal(mp_params_cmdline(&ps, 0, NULL, err), 0);
    assert_err(err, "image: required (query) parameter not given");
    mp_params_free(&ps);
}

static void test_unknown(void **state)
{
    (void)state;
    mp_parset ps;
    char err[MP_ERRLEN] = "";
    assert_int_equal(mp_params_parse_text(TEXT, "fit.par", &ps, err), 0);
    char *argv[] = { "a", "b", "fitradius=3" };
    assert_int_not_equal(mp_params_cmdline(&ps, 3, argv, err), 0);
    assert_err(err, "fitradius: unknown parameter of task fit");
    mp_params_free(&ps);
    assert_int_equal(mp_params_parse_text(TEXT, "fit.par", &ps, err), 0);
    char *a2[] = { "a", "b", "fitrad=-3" };
    assert_int_not_equal(mp_params_cmdline(&ps, 3, a2, err), 0);
    assert_err(err, "fitrad: -3 is outside [0, 1000]");
    mp_params_free(&ps);
}

/* IRAF's minimum match: a name's unique beginning names it, a switch's
 * among the booleans alone; a whole name wins over longer ones it
 * begins; two or more begun refused, naming them. */
static void test_abbreviations(void **state)
{
    (void)state;
    mp_parset ps;
    char err[MP_ERRLEN] = "";
    parse_ok(TEXT, &ps);
    char *a1[] = { "i.fits", "c.coo", "fit=4", "verb-", "mo=crowded", "ga=2" };
    if (mp_params_cmdline(&ps, 6, a1, err))
        fail_msg("%s", err);
    assert_string_equal(mp_par_string(&ps, "fitrad"), "4");
    assert_string_equal(mp_par_string(&ps, "verbose"), "no");
    assert_string_equal(mp_par_string(&ps, "mode"), "crowded");
    assert_string_equal(mp_par_string(&ps, "gain"), "2");
    mp_params_free(&ps);
    parse_ok(TEXT, &ps);
    char *a2[] = { "i.fits", "c.coo", "n=3" };
    assert_int_not_equal(mp_params_cmdline(&ps, 3, a2, err), 0);
    assert_err(err, "n: an abbreviation of 2 parameters of task t (nx, note): give more of the "
               "name");
    mp_params_free(&ps);
    /* "no-" switches no boolean: a bare word, the image's name */
    parse_ok(TEXT, &ps);
    char *a3[] = { "no-", "c.coo" };
    if (mp_params_cmdline(&ps, 2, a3, err))
        fail_msg("%s", err);
    assert_string_equal(mp_par_string(&ps, "image"), "no-");
    assert_string_equal(mp_par_string(&ps, "note"), "plain");
    mp_params_free(&ps);
    parse_ok("psf,s,h,gauss\npsfrad,r,h,10\n", &ps);
    char *a4[] = { "psf=table.fits", "psfr=12" };
    if (mp_params_cmdline(&ps, 2, a4, err))
        fail_msg("%s", err);
    assert_string_equal(mp_par_string(&ps, "psf"), "table.fits");
    assert_string_equal(mp_par_string(&ps, "psfrad"), "12");
    mp_params_free(&ps);
}

static void test_at_file(void **state)
{
    mp_parset ps;
    char err[MP_ERRLEN] = "", word[160];
    parse_ok(TEXT, &ps);
    /* Values only: the file's own types and ranges do not matter. */
    const char *path = put_file(state, "my.par",
                                "# edited\nfitrad,r,h,4.5,0,2,\"my radius\"\n"
                                "mode,s,h,crowded,,,\"\"\nverbose,b,h,no\n");
    snprintf(word, sizeof word, "@%s", path);
    char *argv[] = { "i.fits", "c.coo", word, "fitrad=6" };
    if (mp_params_cmdline(&ps, 4, argv, err))
        fail_msg("%s", err);
    assert_string_equal(mp_par_string(&ps, "fitrad"), "6");        /* later wins */
    assert_string_equal(mp_par_string(&ps, "mode"), "crowded");
    assert_string_equal(mp_par_string(&ps, "verbose"), "no");
    assert_string_equal(ps.p[2].prompt, "Fitting radius [px], INDEF = all");
    mp_params_free(&ps);

    /* Errors name the file, the line and the parameter. */
    parse_ok(TEXT, &ps);
    path = put_file(state, "bad.par", "fitrad,r,h,4\n\n\n# x\n\n\nfitradius,r,h,4\n");
    assert_int_not_equal(mp_params_load_file(&ps, path, err), 0);
    assert_true(ends_with(err, "bad.par:7: fitradius: unknown parameter of task t"));
    path = put_file(state, "bad2.par", "fitrad,r,h,-3\n");
    assert_int_not_equal(mp_params_load_file(&ps, path, err), 0);
    assert_true(ends_with(err, "bad2.par:1: fitrad: -3 is outside [0, 1000]"));
    path = put_file(state, "bad3.par", "fitrad,r,h,4\nfitrad r h 4\n");
    assert_int_not_equal(mp_params_load_file(&ps, path, err), 0);
    assert_true(ends_with(err, "bad3.par:2: malformed line (expected name,type,mode,value,min,max,prompt)"));
    /* IRAF's own lines, `$nargs` and the task's mode, read past where the
     * task has no mode of its own; where it has (t's), a value for it */
    path = put_file(state, "iraf.par", "fitrad,r,h,5\n$nargs,i,h,0\nmode,s,h,\"ql\"\n");
    assert_int_not_equal(mp_params_load_file(&ps, path, err), 0);
    assert_non_null(strstr(err, "iraf.par:3: mode"));
    mp_params_free(&ps);
    parse_ok("fitrad,r,h,3.0,0,1000\n", &ps);
    assert_int_equal(mp_params_load_file(&ps, path, err), 0);
    assert_string_equal(mp_par_string(&ps, "fitrad"), "5");
    snprintf(word, sizeof word, "@%s/missing.par", ((scratch *)*state)->dir);
    char *a2[] = { word };
    assert_int_not_equal(mp_params_cmdline(&ps, 1, a2, err), 0);
    assert_non_null(strstr(err, "missing.par: cannot open"));
    mp_params_free(&ps);
}

static void test_write_then_load(void **state)
{
    mp_parset ps, ps2;
    char err[MP_ERRLEN] = "";
    parse_ok(TEXT, &ps);
    assert_int_equal(mp_params_set(&ps, "title", "a,b \"c\"", err), 0);
    assert_int_equal(mp_params_set(&ps, "nx", "7", err), 0);
    scratch *s = *state;
    char path[160];
    snprintf(path, sizeof path, "%s/w.par", s->dir);
    FILE *fp = fopen(path, "w");
    assert_non_null(fp);
    mp_params_write(&ps, fp);
    assert_int_equal(fclose(fp), 0);
    parse_ok(TEXT, &ps2);
    if (mp_params_load_file(&ps2, path, err))
        fail_msg("%s", err);
    assert_same(&ps, &ps2);
    mp_params_free(&ps);
    mp_params_free(&ps2);
}

/* ---- compiled-in defaults and psets -------------------------------------- */

static void test_defaults(void **state)
{
    (void)state;
    mp_parset ps;
    char err[MP_ERRLEN] = "";
    assert_int_not_equal(mp_params_defaults("nosuchtask", &ps, err), 0);
    assert_non_null(strstr(err, "nosuchtask"));
    assert_int_equal(mp_params_defaults("datapars", &ps, err), 0);
    static const char *names[] = { "gain", "rdnoise", "saturate", "exptime" };
    for (int i = 0; i < 4; i++) {
        double v = 0;
        assert_int_equal(mp_par_real(&ps, names[i], &v), 0);
        assert_true(isnan(v));               /* INDEF: from the header */
    }
    assert_int_not_equal(mp_params_set(&ps, "gain", "0", err), 0);
    assert_int_not_equal(mp_params_set(&ps, "rdnoise", "-1", err), 0);
    assert_int_equal(mp_params_set(&ps, "rdnoise", "0", err), 0);
    mp_params_free(&ps);
}

/* Every task with a "datapars,pset" line gets the datapars parameters right
 * after it, settable by name. */
static void test_pset_merge(void **state)
{
    (void)state;
    const char *const *t = mp_params_tasks();
    int seen = 0;
    for (size_t i = 0; t[i]; i++) {
        mp_parset ps;
        char err[MP_ERRLEN] = "";
        assert_int_equal(mp_params_defaults(t[i], &ps, err), 0);
        for (size_t j = 0; j < ps.n; j++) {
            if (ps.p[j].type != MP_PAR_PSET || strcmp(ps.p[j].name, "datapars"))
                continue;
            seen++;
            assert_true(j + 1 < ps.n);
            assert_string_equal(ps.p[j + 1].name, "gain");
            assert_int_equal(mp_params_set(&ps, "gain", "2", err), 0);
            double g = 0;
            assert_int_equal(mp_par_real(&ps, "gain", &g), 0);
            assert_true(g == 2.0);
        }
        mp_params_free(&ps);
    }
    if (!seen)
        skip();
}

static void test_pset_file(void **state)
{
    mp_parset ps;
    char err[MP_ERRLEN] = "", word[200];
    parse_ok("image,f,a\ndatapars,pset,h,,,,\"Detector\"\ngain,r,h,INDEF,>0\n", &ps);
    const char *path = put_file(state, "night1.par", "gain,r,h,2.5\n");
    snprintf(word, sizeof word, "datapars=%s", path);
    char *argv[] = { "x.fits", word };
    if (mp_params_cmdline(&ps, 2, argv, err))
        fail_msg("%s", err);
    assert_string_equal(mp_par_string(&ps, "gain"), "2.5");
    assert_string_equal(mp_par_string(&ps, "datapars"), path);
    mp_params_free(&ps);
}

static void test_task_begin(void **state)
{
    (void)state;
    mp_parset ps;
    char *none[] = { "datapars" };
    /* datapars has no query parameters: no words is fine. */
    assert_int_equal(mp_task_begin("datapars", 1, none, &ps), 0);
    mp_params_free(&ps);
    char *bad[] = { "datapars", "gain=-1" };
    assert_int_equal(mp_task_begin("datapars", 2, bad, &ps), 1);
    assert_int_equal(mp_task_begin("nosuchtask", 1, none, &ps), 1);
}

/* ---- lists --------------------------------------------------------------- */

static void test_list(void **state)
{
    char **v;
    size_t n;
    char err[MP_ERRLEN] = "", word[160];
    /* "@" alone names no file (it said ": cannot open") */
    assert_int_not_equal(mp_params_list("@", &v, &n, err), 0);
    assert_err(err, "@: names no list file (@frames.lis: one name a line)");
    assert_int_equal(mp_params_list("frame.fits[1]", &v, &n, err), 0);
    assert_int_equal(n, 1);
    assert_string_equal(v[0], "frame.fits[1]");
    mp_list_free(v, n);

    const char *path = put_file(state, "frames.lis",
                                "# frames\r\na.fits\r\n\r\n  b.fits[1:10,1:10]  \r\n#c.fits\nd.fits");
    snprintf(word, sizeof word, "@%s", path);
    assert_int_equal(mp_params_list(word, &v, &n, err), 0);
    assert_int_equal(n, 3);
    assert_string_equal(v[0], "a.fits");
    assert_string_equal(v[1], "b.fits[1:10,1:10]");
    assert_string_equal(v[2], "d.fits");
    mp_list_free(v, n);

    path = put_file(state, "empty.lis", "# nothing\n\n");
    snprintf(word, sizeof word, "@%s", path);
    assert_int_not_equal(mp_params_list(word, &v, &n, err), 0);
    assert_true(ends_with(err, "empty.lis: the list is empty"));
    assert_int_not_equal(mp_params_list("@/nonexistent/x.lis", &v, &n, err), 0);
    assert_non_null(strstr(err, "/nonexistent/x.lis: cannot open"));
}

int main(void)
{
    const struct CMUnitTest tests[] = {
        cmocka_unit_test(test_parse_fields),
        cmocka_unit_test(test_optional_fields_and_comments),
        cmocka_unit_test(test_crlf),
        cmocka_unit_test_setup_teardown(test_crlf_file, setup, teardown),
        cmocka_unit_test(test_malformed),
        cmocka_unit_test(test_bad_type_and_duplicate),
        cmocka_unit_test(test_default_checked),
        cmocka_unit_test(test_round_trip),
        cmocka_unit_test(test_round_trip_defaults),
        cmocka_unit_test(test_indef),
        cmocka_unit_test(test_ranges),
        cmocka_unit_test(test_enumeration),
        cmocka_unit_test(test_bool),
        cmocka_unit_test(test_overrides),
        cmocka_unit_test(test_positional),
        cmocka_unit_test(test_unknown),
        cmocka_unit_test(test_abbreviations),
        cmocka_unit_test_setup_teardown(test_at_file, setup, teardown),
        cmocka_unit_test_setup_teardown(test_write_then_load, setup, teardown),
        cmocka_unit_test(test_defaults),
        cmocka_unit_test(test_pset_merge),
        cmocka_unit_test_setup_teardown(test_pset_file, setup, teardown),
        cmocka_unit_test(test_task_begin),
        cmocka_unit_test_setup_teardown(test_list, setup, teardown),
    };
    return cmocka_run_group_tests(tests, NULL, NULL);
}
