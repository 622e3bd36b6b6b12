/*
 * iraf_text.c — reading IRAF's text databases, the tables DAOPHOT and
 * APPHOT write (daofind's .coo, phot's .mag, pstselect's .pst, group's
 * .grp and psf's .psg, nstar's .nst, allstar's .als).  After "#K" keyword
 * lines, the header gives each line of a record its "#N" names, "#U"
 * units and "#F" formats; a record's lines but its last end in '\'.  A
 * line is its fields one after another at their formats' widths from
 * its first column (phot's "%-7.3f%-6.3f" writes -12.2860.004 for MAG and
 * MERR): split at blanks when that gives the line's number of fields,
 * else at the widths.  The numeric fields (%d %f %g %e) are read, INDEF
 * as NaN; the strings (%s: IMAGE, PERROR) are left out.  phot's last
 * line comes once an aperture, marked '*': the second aperture's fields
 * are read as RAPERT_1, MAG_1, ... (as SExtractor's MAG_APER_1).  ID,
 * XCENTER, YCENTER and GROUP are read as NUMBER, X_IMAGE, Y_IMAGE and
 * GROUP_ID: IRAF's pixel coordinates put the first pixel's centre at
 * 1.0, as SExtractor's do (design.md), so a DAOPHOT star list is a
 * coordinate table as it is.
 */
#include <stdlib.h>
#include <string.h>

#include "catalog/table_priv.h"

/* More fields than any DAOPHOT or APPHOT table has (a .mag of one
 * aperture has 33): a bound on what a corrupt header can ask for. */
#define IRAF_MAXFIELD 4096
#define IRAF_MAXLINE 64
#define IRAF_MAXWIDTH 4096     /* a field's width, as its format gives it */
#define QUOTE_MAX 40

/* A header line's words (names, units or formats), appended line by line;
 * line k's are w[at[k] .. at[k + 1]). */
typedef struct {
    char **w;
    size_t n, cap;
    size_t at[IRAF_MAXLINE + 1];
    int nline;
} words;

static void words_free(words *v)
{
    for (size_t i = 0; i < v->n; i++)
        free(v->w[i]);
    free(v->w);
}

/* The words of header line s (after "#N", "#U" or "#F"), a final "\"
 * left out, as the next line's.  1 when out of memory or past the
 * bounds. */
static int words_line(words *v, const char *s)
{
    if (v->nline == IRAF_MAXLINE)
        return 1;
    v->at[v->nline] = v->n;
    for (;;) {
        s += strspn(s, " \t");
        size_t k = strcspn(s, " \t");
        if (!k || (k == 1 && *s == '\\' && !s[1 + strspn(s + 1, " \t")]))
            break;
        if (v->n == IRAF_MAXFIELD)
            return 1;
        if (v->n == v->cap) {
            size_t cap = v->cap ? 2 * v->cap : 32;
            char **w = realloc(v->w, cap * sizeof *w);
            if (!w)
                return 1;
            v->w = w;
            v->cap = cap;
        }
        if (!(v->w[v->n] = strndup(s, k)))
            return 1;
        v->n++;
        s += k;
    }
    v->at[++v->nline] = v->n;
    return 0;
}

/* The header, and where each field's column went in t (−1: a string,
 * left out) and its width. */
typedef struct {
    words name, unit, fmt;
    int *col, *width;
    int *apcol, nap;    /* the last line's columns for apertures 2 .. nap + 1
                         * (phot's .mag: that line once an aperture, '*') */
} header;

static const char *our_name(const char *iraf)
{
    static const char *const map[][2] = {
        {"ID", "NUMBER"}, {"XCENTER", "X_IMAGE"}, {"YCENTER", "Y_IMAGE"}, {"GROUP", "GROUP_ID"}};
    for (size_t i = 0; i < sizeof map / sizeof *map; i++)
        if (!strcmp(iraf, map[i][0]))
            return map[i][1];
    return iraf;
}

/* Field i's column added to t when its format is a number's, and its
 * width; 1 with err on a name no column can have. */
static int field_column(header *h, size_t i, mp_table *t, const char *fname, char *err)
{
    const char *f = h->fmt.w[i];
    size_t k = strlen(f);
    long w = f[0] == '%' ? strtol(f + 1, NULL, 10) : 0;    /* "%-9d": 9 */
    w = w < -IRAF_MAXWIDTH || w > IRAF_MAXWIDTH ? IRAF_MAXWIDTH : labs(w);
    h->col[i] = -1;
    h->width[i] = (int)w;
    if (f[0] != '%' || !strchr("dfgeDFGE", f[k - 1]))
        return 0;                       /* %s, %b: text, not a number */
    const char *name = our_name(h->name.w[i]);
    if (mp_col_name_bad(name) || strlen(name) >= sizeof t->cols[0].name ||
        mp_table_col(t, name) >= 0) {
        snprintf(err, MP_ERRLEN, "%s: field %zu's name '%.*s' is not one a column can have, or "
                 "a second one", fname, i + 1, QUOTE_MAX, name);
        return 1;
    }
    if ((h->col[i] = mp_table_add_col(t, name)) < 0) {
        snprintf(err, MP_ERRLEN, "%s: out of memory", fname);
        return 1;
    }
    if (h->unit.n == h->name.n && strcmp(h->unit.w[i], "##") != 0)
        snprintf(t->cols[h->col[i]].unit, sizeof t->cols[0].unit, "%s", h->unit.w[i]);
    return 0;
}

/* The columns of h's numeric fields added to t; 1 with err on a header
 * that does not describe its fields line by line. */
static int header_columns(header *h, mp_table *t, const char *fname, char *err)
{
    int same = h->fmt.nline == h->name.nline;
    for (int k = 0; same && k <= h->name.nline; k++)
        same = h->fmt.at[k] == h->name.at[k];
    if (h->name.n == 0 || !same) {
        snprintf(err, MP_ERRLEN, "%s: an IRAF text table whose header does not give a format "
                 "to each name (%zu names on %d #N lines, %zu formats on %d #F lines)", fname,
                 h->name.n, h->name.nline, h->fmt.n, h->fmt.nline);
        return 1;
    }
    h->col = malloc(h->name.n * sizeof *h->col);
    h->width = malloc(h->name.n * sizeof *h->width);
    if (!h->col || !h->width) {
        snprintf(err, MP_ERRLEN, "%s: out of memory", fname);
        return 1;
    }
    for (size_t i = 0; i < h->name.n; i++)
        if (field_column(h, i, t, fname, err))
            return 1;
    if (t->ncol == 0) {
        snprintf(err, MP_ERRLEN, "%s: an IRAF text table with no numeric field (every #F "
                 "format is a string's)", fname);
        return 1;
    }
    return 0;
}

/* Field i's text, trimmed, into f: the word w when the line split at
 * blanks into its fields, else the next width[i] bytes from *pos. */
static void field_text(const header *h, size_t i, const char *line, size_t len, const char *w,
                       size_t *pos, char *f, size_t cap)
{
    const char *s = w;
    size_t k = w ? strlen(w) : 0;
    if (!w) {
        size_t a = *pos < len ? *pos : len, b = a + (size_t)h->width[i];
        s = line + a;
        k = (b < len ? b : len) - a;
        *pos = a + k;
        while (k && (*s == ' ' || *s == '\t'))
            s++, k--;
        while (k && (s[k - 1] == ' ' || s[k - 1] == '\t'))
            k--;
    }
    snprintf(f, cap, "%.*s", (int)(k < cap ? k : cap - 1), s);
}

/* Record line li (line, len bytes without its final backslash and
 * marker) into row, field j into column cols[j] (−1: not kept). */
static int record_line(const header *h, int li, const int *cols, const char *line, size_t len,
                       mp_table *t, long row, const char *fname, long lineno, char *err)
{
    size_t i0 = h->name.at[li], nf = h->name.at[li + 1] - i0, nw = 0, pos = 0;
    char *cp = strndup(line, len), **w = malloc((nf + 1) * sizeof *w);
    if (!cp || !w) {
        free(cp);
        free(w);
        snprintf(err, MP_ERRLEN, "%s: out of memory", fname);
        return 1;
    }
    for (char *p = cp; *(p += strspn(p, " \t")) && nw <= nf;) {
        w[nw++] = p;
        p += strcspn(p, " \t");
        if (*p)
            *p++ = '\0';
    }
    int split = nw == nf, rc = 0;
    for (size_t j = 0; j < nf && !rc; j++) {
        size_t i = i0 + j;
        char f[64];
        double x;
        field_text(h, i, line, len, split ? w[j] : NULL, &pos, f, sizeof f);
        if (cols[j] < 0)
            continue;
        if ((rc = mp_parse_value(f, &x) != 0))
            snprintf(err, MP_ERRLEN, "%s:%ld: '%.*s' in field %s is not a number", fname, lineno,
                     QUOTE_MAX, f, h->name.w[i]);
        else
            mp_table_set(t, (size_t)row, cols[j], x);
    }
    free(cp);
    free(w);
    return rc;
}

/* The length of line s without a final '\' (*more when it had one) and
 * an aperture's '*' before it (*array), and the blanks before each. */
static size_t record_len(const char *s, size_t n, int *more, int *array)
{
    while (n && (s[n - 1] == ' ' || s[n - 1] == '\t'))
        n--;
    if ((*more = n && s[n - 1] == '\\'))
        n--;
    while (n && (s[n - 1] == ' ' || s[n - 1] == '\t'))
        n--;
    if ((*array = n && s[n - 1] == '*'))
        n--;
    return n;
}

/* The columns of aperture a (1: the second) of the last line's numeric
 * fields, NAME_a, added to t when first met. */
static const int *aperture_cols(header *h, int a, mp_table *t, const char *fname, char *err)
{
    size_t i0 = h->name.at[h->name.nline - 1], nf = h->name.n - i0;
    if (a > IRAF_MAXFIELD / (int)(nf ? nf : 1)) {
        snprintf(err, MP_ERRLEN, "%s: more than %d fields", fname, IRAF_MAXFIELD);
        return NULL;
    }
    for (; h->nap < a; h->nap++) {
        int *c = realloc(h->apcol, (size_t)(h->nap + 1) * nf * sizeof *c);
        if (!c)
            goto oom;
        h->apcol = c;
        for (size_t j = 0; j < nf; j++) {
            char name[64], unit[sizeof t->cols[0].unit];
            int *cj = &h->apcol[(size_t)h->nap * nf + j];
            *cj = -1;
            if (h->col[i0 + j] < 0)
                continue;
            const mp_col *base = &t->cols[h->col[i0 + j]];
            snprintf(name, sizeof name, "%s_%d", base->name, h->nap + 1);
            memcpy(unit, base->unit, sizeof unit);
            if (strlen(name) >= sizeof t->cols[0].name || mp_table_col(t, name) >= 0) {
                snprintf(err, MP_ERRLEN, "%s: aperture %d's %.40s is too long a name, or a "
                         "field's", fname, h->nap + 2, name);
                return NULL;
            }
            if ((*cj = mp_table_add_col(t, name)) < 0)
                goto oom;
            memcpy(t->cols[*cj].unit, unit, sizeof unit);
        }
    }
    return h->apcol + (size_t)(a - 1) * nf;
oom:
    snprintf(err, MP_ERRLEN, "%s: out of memory", fname);
    return NULL;
}

static int read_lines(mp_lines *L, header *h, mp_table *t, char *err)
{
    int li = 0, got;
    long row = -1, start = 0;
    while ((got = mp_lines_next(L, err)) == 1) {
        const char *s = L->line + strspn(L->line, " \t");
        if (!h->col && s[0] == '#') {
            words *v = s[1] == 'N' ? &h->name : s[1] == 'U' ? &h->unit
                     : s[1] == 'F' ? &h->fmt : NULL;
            if (v && strchr(" \t", s[2]) && words_line(v, s + 2)) {
                snprintf(err, MP_ERRLEN, "%s:%ld: more than %d fields or %d header lines, or "
                         "out of memory", L->name, L->lineno, IRAF_MAXFIELD, IRAF_MAXLINE);
                return 1;
            }
            continue;                   /* #K keywords, "#" alone */
        }
        if (!*s || (s[0] == '#' && li == 0))
            continue;
        if (!h->col && header_columns(h, t, L->name, err))
            return 1;
        if (li == 0) {
            start = L->lineno;
            if ((row = mp_table_add_row(t)) < 0) {
                snprintf(err, MP_ERRLEN, "%s: out of memory", L->name);
                return 1;
            }
        }
        int more, array, last = h->name.nline - 1;
        size_t len = record_len(L->line, (size_t)L->len, &more, &array);
        if ((li > last && !array) || (!more && li < last)) {
            snprintf(err, MP_ERRLEN, "%s:%ld: a record of %s lines than the header's %d", L->name,
                     start, li > last ? "more" : "fewer", h->name.nline);
            return 1;
        }
        const int *cols = li <= last ? h->col + h->name.at[li]
                                     : aperture_cols(h, li - last, t, L->name, err);
        if (!cols || record_line(h, li < last ? li : last, cols, L->line, len, t, row, L->name,
                                 L->lineno, err))
            return 1;
        li = more ? li + 1 : 0;
    }
    if (got < 0)
        return 1;
    if (li) {
        snprintf(err, MP_ERRLEN, "%s:%ld: the last record ends in '\\' (truncated)", L->name,
                 start);
        return 1;
    }
    return !h->col && header_columns(h, t, L->name, err);
}

int mp_iraf_text_read(mp_lines *L, mp_table *t, char *err)
{
    header h;
    memset(&h, 0, sizeof h);
    int rc = read_lines(L, &h, t, err);
    words_free(&h.name);
    words_free(&h.unit);
    words_free(&h.fmt);
    free(h.col);
    free(h.width);
    free(h.apcol);
    return rc;
}
