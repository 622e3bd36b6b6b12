/*
 * csv.c — CSV tables through libcsv: a header row of column names, then one
 * row of numbers per object.  Empty fields are NaN both ways.
 *
 * The input is fed to csv_parse one line at a time so that every message
 * can name the line where the offending row ends.
 */
#include <csv.h>
#include <math.h>
#include <stdlib.h>
#include <string.h>

#include "catalog/table_priv.h"
#include "io/io.h"

#define QUOTE_MAX 40

typedef struct {
    mp_table *t;
    mp_lines *L;
    char *err;
    int failed;
    int in_header;
    char **names;          /* header fields, until the header row ends */
    size_t nnames, capnames;
    double *row;           /* values of the data row being parsed */
    size_t nfield;
} csv_state;

static void fail_oom(csv_state *s)
{
    snprintf(s->err, MP_ERRLEN, "%s: out of memory", s->L->name);
    s->failed = 1;
}

/* A header field that is really a value: its first word is a number (so a
 * headerless CSV or a whitespace-separated table without "#" lines is
 * caught, while "2MASS_ID" is still a name). */
static int looks_numeric(const char *f)
{
    char word[64];
    size_t i = 0;
    while (*f == ' ' || *f == '\t')
        f++;
    while (f[i] && f[i] != ' ' && f[i] != '\t' && i < sizeof word - 1) {
        word[i] = f[i];
        i++;
    }
    word[i] = '\0';
    char *end;
    if (i == 0)
        return 0;
    double x = strtod(word, &end);
    return end != word && *end == '\0' && isfinite(x);   /* "nan", "inf": names */
}

static void on_field(void *f, size_t len, void *data)
{
    csv_state *s = data;
    if (s->failed)
        return;
    const char *str = f ? f : "";   /* CSV_EMPTY_IS_NULL gives NULL */
    (void)len;                      /* CSV_APPEND_NULL: str is terminated */

    if (s->in_header) {
        if (s->nnames == s->capnames) {
            size_t cap = s->capnames ? 2 * s->capnames : 16;
            char **nn = realloc(s->names, cap * sizeof *nn);
            if (!nn) {
                fail_oom(s);
                return;
            }
            s->names = nn;
            s->capnames = cap;
        }
        char *copy = strdup(str);
        if (!copy) {
            fail_oom(s);
            return;
        }
        s->names[s->nnames++] = copy;
        return;
    }

    /* Extra fields are only counted; the row callback reports them. */
    if (s->nfield < s->t->ncol) {
        double x;
        const char *p = str;
        while (*p == ' ' || *p == '\t')
            p++;
        if (*p == '\0')
            x = NAN;
        else if (mp_parse_value(p, &x) != 0) {
            snprintf(s->err, MP_ERRLEN, "%s:%ld: '%.*s%s' in column %s is not a number",
                     s->L->name, s->L->lineno, QUOTE_MAX, p,
                     strlen(p) > QUOTE_MAX ? "..." : "", s->t->cols[s->nfield].name);
            s->failed = 1;
            return;
        }
        s->row[s->nfield] = x;
    }
    s->nfield++;
}

/* The header row is complete: it names the columns. */
static void end_header(csv_state *s)
{
    const char *fname = s->L->name;
    long ln = s->L->lineno;
    for (size_t i = 0; i < s->nnames && !s->failed; i++) {
        const char *nm = s->names[i];
        if (looks_numeric(nm)) {
            snprintf(s->err, MP_ERRLEN, "%s:%ld: no header row: '%.*s' is a number, "
                     "not a column name", fname, ln, QUOTE_MAX, nm);
            s->failed = 1;
        } else if (!*nm) {
            snprintf(s->err, MP_ERRLEN, "%s:%ld: header field %zu is empty", fname, ln, i + 1);
            s->failed = 1;
        } else if (strlen(nm) >= sizeof s->t->cols[0].name) {
            snprintf(s->err, MP_ERRLEN, "%s:%ld: column name '%.*s...' is too long",
                     fname, ln, QUOTE_MAX, nm);
            s->failed = 1;
        } else if (mp_table_col(s->t, nm) >= 0) {
            snprintf(s->err, MP_ERRLEN, "%s:%ld: column %s appears twice", fname, ln, nm);
            s->failed = 1;
        } else if (mp_table_add_col(s->t, nm) < 0) {
            fail_oom(s);
        }
    }
    if (s->failed)
        return;
    s->row = malloc((s->t->ncol ? s->t->ncol : 1) * sizeof *s->row);
    if (!s->row)
        fail_oom(s);
    s->in_header = 0;
}

static void on_row(int c, void *data)
{
    csv_state *s = data;
    (void)c;
    if (s->failed)
        return;
    if (s->in_header) {
        end_header(s);
        return;
    }
    mp_table *t = s->t;
    if (s->nfield != t->ncol) {
        snprintf(s->err, MP_ERRLEN, "%s:%ld: %zu field%s, header has %zu column%s",
                 s->L->name, s->L->lineno, s->nfield, s->nfield == 1 ? "" : "s",
                 t->ncol, t->ncol == 1 ? "" : "s");
        s->failed = 1;
        return;
    }
    long r = mp_table_add_row(t);
    if (r < 0) {
        fail_oom(s);
        return;
    }
    for (size_t i = 0; i < t->ncol; i++)
        mp_table_set(t, (size_t)r, (int)i, s->row[i]);
    s->nfield = 0;
}

int mp_csv_read(mp_lines *L, mp_table *t, char *err)
{
    struct csv_parser p;
    if (csv_init(&p, CSV_APPEND_NULL | CSV_EMPTY_IS_NULL) != 0) {
        snprintf(err, MP_ERRLEN, "%s: out of memory", L->name);
        return 1;
    }
    csv_state s = {.t = t, .L = L, .err = err, .in_header = 1};
    int r = 0;
    while (!s.failed && (r = mp_lines_next(L, err)) == 1) {
        /* mp_lines strips the line end; give libcsv one back. */
        if (csv_parse(&p, L->line, (size_t)L->len, on_field, on_row, &s) != (size_t)L->len
            || csv_parse(&p, "\n", 1, on_field, on_row, &s) != 1) {
            snprintf(err, MP_ERRLEN, "%s:%ld: %s", L->name, L->lineno,
                     csv_strerror(csv_error(&p)));
            s.failed = 1;
        }
    }
    if (!s.failed && r < 0)
        s.failed = 1;
    if (!s.failed && csv_fini(&p, on_field, on_row, &s) != 0) {
        snprintf(err, MP_ERRLEN, "%s:%ld: %s", L->name, L->lineno,
                 csv_strerror(csv_error(&p)));
        s.failed = 1;
    }
    if (!s.failed && s.in_header) {
        /* Only possible when the first line opened a quote never closed. */
        snprintf(err, MP_ERRLEN, "%s: no header row", L->name);
        s.failed = 1;
    }
    csv_free(&p);
    for (size_t i = 0; i < s.nnames; i++)
        free(s.names[i]);
    free(s.names);
    free(s.row);
    return s.failed;
}

int mp_csv_write(FILE *fp, const char *name, const mp_table *t, char *err)
{
    if (t->ncol == 0) {
        snprintf(err, MP_ERRLEN, "%s: table has no columns to write", name);
        return 1;
    }
    for (size_t c = 0; c < t->ncol; c++) {
        if (c)
            fputc(',', fp);
        /* csv_fwrite quotes the name, so any name survives the round trip. */
        csv_fwrite(fp, t->cols[c].name, strlen(t->cols[c].name));
    }
    fputc('\n', fp);

    char buf[512];
    for (size_t r = 0; r < t->nrow; r++) {
        for (size_t c = 0; c < t->ncol; c++) {
            if (c)
                fputc(',', fp);
            double x = mp_table_get(t, r, (int)c);
            if (isnan(x)) {
                /* NaN is an empty field; a row of one empty field would be
                 * a blank line, which readers skip, so quote it (found by
                 * tests/fuzz: a one-column row of NaN was lost). */
                if (t->ncol == 1)
                    fputs("\"\"", fp);
                continue;
            }
            mp_format_value(&t->cols[c], x, buf, sizeof buf);
            const char *v = buf;
            while (*v == ' ')
                v++;                     /* padding is for ASCII columns only */
            fputs(v, fp);
        }
        fputc('\n', fp);
    }
    return 0;
}
