/*
 * ascii_head.c — SExtractor's ASCII_HEAD catalogue format (anchors.md §2.2):
 * one "#" line per column, then one whitespace-separated row per object.
 *
 * Writing follows SExtractor's catout.c byte for byte ("# %3d %-22.22s
 * %-58.58s [%s]"), except that names and descriptions are never truncated:
 * a cut name would no longer be the column.  Reading takes any SExtractor
 * ASCII_HEAD file: blank lines, CRLF, any line length, "#" comment lines,
 * and vector columns (an index gap), which get astropy's names NAME,
 * NAME_1, NAME_2, ...
 */
#include <ctype.h>
#include <errno.h>
#include <stdlib.h>
#include <string.h>

#include "catalog/table_priv.h"
#include "io/io.h"

/* Longest piece of an offending value quoted back in a message. */
#define QUOTE_MAX 40
#define MAX_HIDDEN 4096    /* SExtractor's VIGNET(63,63) still fits; the cost of adding
                              * columns grows as their square */

static char *skip_blanks(char *p)
{
    while (*p == ' ' || *p == '\t')
        p++;
    return p;
}

static char *skip_word(char *p)
{
    while (*p && *p != ' ' && *p != '\t')
        p++;
    return p;
}

static void rtrim(char *s)
{
    size_t n = strlen(s);
    while (n > 0 && (s[n - 1] == ' ' || s[n - 1] == '\t'))
        s[--n] = '\0';
}

/* Copy at most size-1 bytes of src[0..n) into dst. */
static void copy_trunc(char *dst, size_t size, const char *src, size_t n)
{
    if (n >= size)
        n = size - 1;
    memcpy(dst, src, n);
    dst[n] = '\0';
}

/* A column definition parsed from a "#" line. */
typedef struct {
    long index;
    char *name;            /* points into the line */
    char desc[64], unit[24];
} coldef;

/* parse_def: "#  <index> <NAME> <description> [<unit>]" → 1; any other "#"
 * line is a comment → 0.  Modifies the line (NUL after the name). */
static int parse_def(char *line, coldef *d)
{
    char *p = skip_blanks(line);
    if (*p != '#')
        return 0;
    p = skip_blanks(p + 1);
    if (!isdigit((unsigned char)*p))
        return 0;
    char *end;
    errno = 0;
    d->index = strtol(p, &end, 10);
    if (errno || (*end != ' ' && *end != '\t'))
        return 0;
    p = skip_blanks(end);
    if (!*p)
        return 0;
    d->name = p;
    p = skip_word(p);
    char *rest = *p ? p + 1 : p;
    *p = '\0';

    rest = skip_blanks(rest);
    rtrim(rest);
    d->unit[0] = '\0';
    size_t n = strlen(rest);
    if (n > 0 && rest[n - 1] == ']') {
        /* The unit is the last bracketed word, after a blank (or alone). */
        char *open = strrchr(rest, '[');
        if (open && (open == rest || open[-1] == ' ' || open[-1] == '\t')) {
            copy_trunc(d->unit, sizeof d->unit, open + 1,
                       (size_t)(rest + n - 1 - (open + 1)));
            *open = '\0';
            rtrim(rest);
        }
    }
    copy_trunc(d->desc, sizeof d->desc, rest, strlen(rest));
    return 1;
}

/* Add a column read from the file: the registry's format, and the file's
 * description and unit where it gives them (so a SExtractor catalogue keeps
 * its [count]). */
static int add_def(mp_table *t, const char *name, const coldef *d,
                   const char *fname, long lineno, char *err)
{
    if (strlen(name) >= sizeof t->cols[0].name) {
        snprintf(err, MP_ERRLEN, "%s:%ld: column name '%.*s...' is too long",
                 fname, lineno, QUOTE_MAX, name);
        return 1;
    }
    if (mp_col_name_bad(name)) {
        snprintf(err, MP_ERRLEN, "%s:%ld: a column name cannot hold control or non-ASCII "
                 "characters", fname, lineno);
        return 1;
    }
    if (mp_table_col(t, name) >= 0) {
        snprintf(err, MP_ERRLEN, "%s:%ld: column %s defined twice", fname, lineno, name);
        return 1;
    }
    int c = mp_table_add_col(t, name);
    if (c < 0) {
        snprintf(err, MP_ERRLEN, "%s: out of memory", fname);
        return 1;
    }
    if (d->desc[0])
        strcpy(t->cols[c].desc, d->desc);
    if (d->unit[0])
        strcpy(t->cols[c].unit, d->unit);
    return 0;
}

/* One header line: add its column, and the hidden elements of a vector
 * column before it when the index jumps. */
static int header_line(mp_table *t, coldef *d, long *expect,
                       const char *fname, long lineno, char *err)
{
    if (d->index < *expect) {
        snprintf(err, MP_ERRLEN, "%s:%ld: column %ld (%s) listed after column %ld",
                 fname, lineno, d->index, d->name, *expect - 1);
        return 1;
    }
    if (d->index - lineno > MAX_HIDDEN) {
        /* The hidden elements of vector columns (index jumps) become
         * columns; each line defines at most one visible column, so
         * index - lineno bounds the hidden ones.  Unbounded, a 149-byte
         * header numbered 170819 cost minutes (found by tests/fuzz). */
        snprintf(err, MP_ERRLEN, "%s:%ld: column number %ld: vector columns of more than "
                 "%d elements in all are not supported", fname, lineno, d->index, MAX_HIDDEN);
        return 1;
    }
    if (d->index > *expect) {
        if (t->ncol == 0) {
            snprintf(err, MP_ERRLEN, "%s:%ld: first column is numbered %ld, not 1",
                     fname, lineno, d->index);
            return 1;
        }
        /* The previous column is a vector of index - expect + 1 elements. */
        coldef prev = {0};
        const mp_col *pc = &t->cols[t->ncol - 1];
        char base[sizeof pc->name];
        strcpy(base, pc->name);
        strcpy(prev.desc, pc->desc);
        strcpy(prev.unit, pc->unit);
        for (long k = 1; *expect < d->index; k++, (*expect)++) {
            char name[64];
            snprintf(name, sizeof name, "%s_%ld", base, k);
            if (add_def(t, name, &prev, fname, lineno, err))
                return 1;
        }
    }
    if (add_def(t, d->name, d, fname, lineno, err))
        return 1;
    (*expect)++;
    return 0;
}

/* One data row: exactly ncol values. */
static int data_line(mp_table *t, char *line, const char *fname, long lineno, char *err)
{
    size_t n = 0;
    for (char *p = skip_blanks(line); *p; p = skip_blanks(skip_word(p)))
        n++;
    if (n != t->ncol) {
        snprintf(err, MP_ERRLEN, "%s:%ld: %zu field%s, header has %zu column%s",
                 fname, lineno, n, n == 1 ? "" : "s", t->ncol, t->ncol == 1 ? "" : "s");
        return 1;
    }
    long r = mp_table_add_row(t);
    if (r < 0) {
        snprintf(err, MP_ERRLEN, "%s: out of memory", fname);
        return 1;
    }
    size_t c = 0;
    for (char *p = skip_blanks(line); *p; c++) {
        char *e = skip_word(p);
        char save = *e;
        *e = '\0';
        double x;
        if (mp_parse_value(p, &x) != 0) {
            size_t len = strlen(p);
            snprintf(err, MP_ERRLEN, "%s:%ld: '%.*s%s' in column %s is not a number",
                     fname, lineno, QUOTE_MAX, p, len > QUOTE_MAX ? "..." : "",
                     t->cols[c].name);
            return 1;
        }
        mp_table_set(t, (size_t)r, (int)c, x);
        *e = save;
        p = skip_blanks(e);
    }
    return 0;
}

int mp_ascii_head_read(mp_lines *L, mp_table *t, char *err)
{
    int in_header = 1;
    long expect = 1;
    int r;
    while ((r = mp_lines_next(L, err)) == 1) {
        char *p = skip_blanks(L->line);
        if (*p == '\0')
            continue;
        if (*p == '#') {
            /* After the data have begun, "#" lines are comments. */
            coldef d;
            if (in_header && parse_def(L->line, &d)
                && header_line(t, &d, &expect, L->name, L->lineno, err))
                return 1;
            continue;
        }
        if (in_header) {
            in_header = 0;
            if (t->ncol == 0) {
                snprintf(err, MP_ERRLEN, "%s:%ld: data before any column definition "
                         "(\"#   1 NAME  description  [unit]\")", L->name, L->lineno);
                return 1;
            }
        }
        if (data_line(t, L->line, L->name, L->lineno, err))
            return 1;
    }
    if (r < 0)
        return 1;
    if (t->ncol == 0) {
        snprintf(err, MP_ERRLEN, "%s: header has no column definitions", L->name);
        return 1;
    }
    return 0;
}

/* A name that the reader would split or take for a comment. */
static int bad_name(const char *s)
{
    if (!*s)
        return 1;
    for (; *s; s++)
        if (isspace((unsigned char)*s) || !isprint((unsigned char)*s))
            return 1;
    return 0;
}

/* What format_rows formats: the table, and the rows kept from the last
 * one written (copied where the same: mp_text_kept_row), or NULL. */
typedef struct {
    const mp_table *t;
    const mp_text_kept *prev;
    int cnum;                   /* t's NUMBER column */
} rows_ctx;

/* Rows [r0, r1) of the table (ctx, a rows_ctx), formatted as ASCII_HEAD
 * rows, appended to b (mp_rows_format); nonzero when out of memory. */
static int format_rows(const void *ctx, size_t r0, size_t r1, mp_text *b)
{
    const rows_ctx *x = ctx;
    const mp_table *t = x->t;
    char buf[512];
    size_t kc = mp_text_kept_ncol(x->prev);
    for (size_t r = r0; r < r1; r++) {
        const char *s;
        size_t len, c0 = 0;
        if (x->prev && mp_text_kept_row(x->prev, t, x->cnum, r, &s, &len)) {
            /* its first kc columns as kept, the separator its newline was
             * (the rest, t's columns after them, formatted below) */
            int more = kc < t->ncol;
            if (mp_text_put(b, s, len - (size_t)more) || (more && mp_text_put(b, " ", 1)))
                return 1;
            if (!more)
                continue;
            c0 = kc;
        }
        for (size_t c = c0; c < t->ncol; c++) {
            int w = mp_format_value(&t->cols[c], mp_table_get(t, r, (int)c), buf, sizeof buf);
            size_t n = w < 0 ? 0 : (size_t)w < sizeof buf ? (size_t)w : strlen(buf);
            /* a separator even when a value overflows its width (n < 512:
             * it takes the place of the terminating NUL at most) */
            buf[n] = c + 1 < t->ncol ? ' ' : '\n';
            if (mp_text_put(b, buf, n + 1))
                return 1;
        }
    }
    return 0;
}

/* Whether t's rows may be kept as text: up to 16 MiB of it, at 12 bytes
 * a value (root.fit's rows are 11.1).  The pipeline's writes keep
 * root.grp's text for root.fit and root.fit's for root.cat while the
 * frame, residual and mask are still held; kept whole, they took the
 * 8192² run's peak RSS from 825 to 1047 MiB (3.22 to 4.09 times the
 * frame's floats, where the goal is 3: bench/SCALING.md, 2026-12-07).  47
 * Tuc's 3 800 rows are 1.5 MB, a 2048² frame's 15 600 6 MB; a 4096² frame's
 * 61 600 (24 MB) are formatted again. */
static int keep_within_budget(const mp_table *t)
{
    return (double)t->nrow * (double)t->ncol * 12.0 <= 16.0 * 1024 * 1024;
}

/* t's rows written to fp; with out, and when they fit the budget
 * (keep_within_budget), through a buffer kept there as t's rows
 * (mp_text_kept_make; else *out is left as it is).  Nonzero when out of
 * memory. */
static int write_rows(FILE *fp, const rows_ctx *x, mp_text_kept **out)
{
    if (!out || !keep_within_budget(x->t))
        return mp_rows_write(fp, x->t->nrow, format_rows, x);
    char *text = NULL;
    size_t len = 0;
    FILE *ms = open_memstream(&text, &len);
    if (!ms)
        return 1;
    int rc = mp_rows_write(ms, x->t->nrow, format_rows, x);
    rc |= fclose(ms) != 0;
    if (rc) {
        free(text);
        return 1;
    }
    fwrite(text, 1, len, fp);
    return mp_text_kept_make(out, x->t, text, len);
}

int mp_ascii_head_write(FILE *fp, const char *name, const mp_table *t, char *err)
{
    return mp_ascii_head_write_kept(fp, name, t, NULL, NULL, err);
}

int mp_ascii_head_write_kept(FILE *fp, const char *name, const mp_table *t,
                             const mp_text_kept *prev, mp_text_kept **out, char *err)
{
    if (t->ncol == 0) {
        snprintf(err, MP_ERRLEN, "%s: table has no columns to write", name);
        return 1;
    }
    for (size_t c = 0; c < t->ncol; c++)
        if (bad_name(t->cols[c].name)) {
            snprintf(err, MP_ERRLEN, "%s: column name '%s' cannot be written in "
                     "ASCII_HEAD (blank or unprintable characters)", name, t->cols[c].name);
            return 1;
        }

    for (size_t c = 0; c < t->ncol; c++) {
        const mp_col *k = &t->cols[c];
        /* SExtractor's catout.c layout; unit-less lines keep the padding. */
        fprintf(fp, "# %3zu %-22s %-58s", c + 1, k->name, k->desc);
        if (k->unit[0])
            fprintf(fp, " [%s]", k->unit);
        fputc('\n', fp);
    }

    int cnum = mp_table_col(t, "NUMBER");
    rows_ctx x = {t, cnum >= 0 && mp_text_kept_fits(prev, t) ? prev : NULL, cnum};
    if (write_rows(fp, &x, out)) {
        snprintf(err, MP_ERRLEN, "%s: out of memory formatting the rows", name);
        return 1;
    }
    return 0;
}
