/*
 * daophot2.c — reading the tables of Stetson's DAOPHOT II (FIND's .coo,
 * PHOTOMETRY's .ap, PEAK's .pk, GROUP's .grp, NSTAR's .nst, ALLSTAR's
 * .als): three header lines (the names "NL NX NY LOWBAD ...", their
 * values, a blank), then one record a star in Fortran's fixed columns,
 * (1X,I5,3F9.3,nF9.?): ID, X, Y, MAG and the program's own fields
 * (anchors.md §1.4).  NL says the layout: 1 one line a star, 2 two lines
 * a star (PHOTOMETRY: the magnitudes, then SKY, its σ and skew and the
 * magnitudes' errors), 3 groups of stars parted by blank lines (GROUP_ID
 * counts them).  ID, X and Y are read as NUMBER, X_IMAGE and Y_IMAGE
 * (DAOPHOT puts the first pixel's centre at 1.0, as SExtractor does); a
 * record of nine fields as ALLSTAR's and NSTAR's (MAG MERR MSKY NITER CHI
 * SHARPNESS), other fields as FIELD5, FIELD6, ...  A line is split at
 * blanks, else at the format's widths (X of 10⁴ px and more fills its
 * nine columns and touches its neighbour).
 */
#include <stdlib.h>
#include <string.h>

#include "catalog/table_priv.h"

#define D2_MAXFIELD 64

/* The fields of line s into v (at most D2_MAXFIELD; their number is
 * returned, −1 past it): split at blanks, or where that does not give
 * want fields (want > 0), at the widths 6, 9, 9, ... */
static int line_fields(const char *s, int want, char v[D2_MAXFIELD][32])
{
    int n = 0;
    for (const char *p = s; *(p += strspn(p, " \t"));) {
        size_t k = strcspn(p, " \t");
        if (n == D2_MAXFIELD)
            return -1;
        snprintf(v[n++], 32, "%.*s", (int)(k < 31 ? k : 31), p);
        p += k;
    }
    if (want <= 0 || n == want || want > D2_MAXFIELD)
        return n;
    size_t len = strlen(s), pos = 0;
    for (n = 0; n < want && pos < len; n++) {
        size_t w = n == 0 ? 6 : 9, k = len - pos < w ? len - pos : w;
        const char *p = s + pos;
        pos += k;
        while (k && (*p == ' ' || *p == '\t'))
            p++, k--;
        snprintf(v[n], 32, "%.*s", (int)(k < 31 ? k : 31), p);
    }
    return n;
}

/* The name of field i (0-based) of a record of nf fields, NL nl: the
 * second line of a PHOTOMETRY record numbered on from the first's. */
static void field_name(int nl, int nf1, int i, int nf, char *name, size_t cap)
{
    static const char *const als[] = {"NUMBER", "X_IMAGE", "Y_IMAGE", "MAG", "MERR",
                                      "MSKY", "NITER", "CHI", "SHARPNESS"};
    static const char *const first[] = {"NUMBER", "X_IMAGE", "Y_IMAGE"};
    if (nl == 2 && i >= nf1) {
        static const char *const sky[] = {"MSKY", "STDEV", "SSKEW"};
        int j = i - nf1;
        if (j < 3)
            snprintf(name, cap, "%s", sky[j]);
        else
            snprintf(name, cap, "MERR%s%.0d", j > 3 ? "_" : "", j > 3 ? j - 3 : 0);
        return;
    }
    if (nl == 2 && i >= 3)
        snprintf(name, cap, "MAG%s%.0d", i > 3 ? "_" : "", i > 3 ? i - 3 : 0);
    else if (nf == 9 && nl != 2)
        snprintf(name, cap, "%s", als[i]);
    else if (i < 3)
        snprintf(name, cap, "%s", first[i]);
    else if (i == 3)
        snprintf(name, cap, "MAG");
    else
        snprintf(name, cap, "FIELD%d", i + 1);
}

typedef struct {
    int nl, nf1, nf;        /* NL; fields of a record's first line, of all */
    long group;             /* NL 3: the group being read (1, 2, ...) */
    char v[D2_MAXFIELD * 2][32];
} d2;

/* The columns for records of d's fields (and GROUP_ID for NL 3). */
static int add_columns(const d2 *d, mp_table *t, const char *fname, char *err)
{
    for (int i = 0; i < d->nf; i++) {
        char name[32];
        field_name(d->nl, d->nf1, i, d->nf, name, sizeof name);
        if (mp_table_add_col(t, name) < 0)
            goto oom;
    }
    if (d->nl == 3 && mp_table_add_col(t, "GROUP_ID") < 0)
        goto oom;
    return 0;
oom:
    snprintf(err, MP_ERRLEN, "%s: out of memory", fname);
    return 1;
}

/* Record d->v[0..n) into a new row of t. */
static int add_record(const d2 *d, int n, mp_table *t, const char *fname, long lineno, char *err)
{
    if (n != d->nf) {
        snprintf(err, MP_ERRLEN, "%s:%ld: a record of %d fields, where the first had %d", fname,
                 lineno, n, d->nf);
        return 1;
    }
    long row = mp_table_add_row(t);
    if (row < 0) {
        snprintf(err, MP_ERRLEN, "%s: out of memory", fname);
        return 1;
    }
    for (int i = 0; i < n; i++) {
        double x;
        if (mp_parse_value(d->v[i], &x)) {
            snprintf(err, MP_ERRLEN, "%s:%ld: '%s' in field %d is not a number", fname, lineno,
                     d->v[i], i + 1);
            return 1;
        }
        mp_table_set(t, (size_t)row, i, x);
    }
    if (d->nl == 3)
        mp_table_set(t, (size_t)row, n, (double)d->group);
    return 0;
}

/* The header's three lines: NL from the second. */
static int read_header(mp_lines *L, d2 *d, char *err)
{
    char v[D2_MAXFIELD][32];
    double nl = 0;
    int got = mp_lines_next(L, err);        /* the names, peeked */
    if (got == 1)
        got = mp_lines_next(L, err);
    if (got != 1 || line_fields(L->line, 0, v) < 1 || mp_parse_value(v[0], &nl) ||
        !(nl == 1 || nl == 2 || nl == 3)) {
        if (got >= 0)
            snprintf(err, MP_ERRLEN, "%s:2: a DAOPHOT II header whose NL is not 1, 2 or 3",
                     L->name);
        return 1;
    }
    d->nl = (int)nl;
    return 0;
}

static int read_records(mp_lines *L, d2 *d, mp_table *t, char *err)
{
    int got, n = 0, half = 0;       /* half: a PHOTOMETRY record's first line read */
    int grouped = 0;                /* a star read since the last blank line */
    long start = 0;
    d->group = 1;
    while ((got = mp_lines_next(L, err)) == 1) {
        const char *s = L->line + strspn(L->line, " \t");
        if (!*s) {
            d->group += grouped && !half;
            grouped = grouped && half;
            continue;
        }
        grouped = 1;
        /* the widths are known for a record's first line only */
        int k = line_fields(L->line, half ? 0 : d->nf1, d->v + n);
        if (k < 0 || n + k > D2_MAXFIELD) {
            snprintf(err, MP_ERRLEN, "%s:%ld: more than %d fields", L->name, L->lineno,
                     D2_MAXFIELD);
            return 1;
        }
        if (!half)
            start = L->lineno;
        n += k;
        if (d->nl == 2 && !half) {
            half = 1;
            if (!d->nf1)
                d->nf1 = k;
            continue;
        }
        if (!d->nf) {
            d->nf = n;
            d->nf1 = d->nl == 2 ? d->nf1 : n;
            if (n < 3 || add_columns(d, t, L->name, err)) {
                if (n < 3)
                    snprintf(err, MP_ERRLEN, "%s:%ld: a record of %d fields, not ID, X, Y ...",
                             L->name, start, n);
                return 1;
            }
        }
        if (add_record(d, n, t, L->name, start, err))
            return 1;
        n = half = 0;
    }
    if (got < 0)
        return 1;
    if (half) {
        snprintf(err, MP_ERRLEN, "%s:%ld: the last record has its first line only (truncated)",
                 L->name, start);
        return 1;
    }
    if (!d->nf) {
        snprintf(err, MP_ERRLEN, "%s: a DAOPHOT II table with no star", L->name);
        return 1;
    }
    return 0;
}

int mp_daophot2_read(mp_lines *L, mp_table *t, char *err)
{
    d2 *d = calloc(1, sizeof *d);
    if (!d) {
        snprintf(err, MP_ERRLEN, "%s: out of memory", L->name);
        return 1;
    }
    int rc = read_header(L, d, err) || read_records(L, d, t, err);
    free(d);
    return rc;
}
