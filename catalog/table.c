/*
 * table.c — the in-memory table: named columns, rows of doubles stored row
 * by row (v[row*ncol + col]) so that a stage fills one star at a time.
 */
#include <ctype.h>
#include <limits.h>
#include <math.h>
#include <stdint.h>
#include <stdlib.h>
#include <string.h>

#include "catalog/catalog.h"
#include "catalog/table_priv.h"

void mp_table_init(mp_table *t)
{
    t->ncol = t->nrow = t->cap = t->ccap = 0;
    t->cols = NULL;
    t->v = NULL;
}

void mp_table_free(mp_table *t)
{
    free(t->cols);
    free(t->v);
    mp_table_init(t);
}

int mp_table_col(const mp_table *t, const char *name)
{
    for (size_t i = 0; i < t->ncol; i++)
        if (strcmp(t->cols[i].name, name) == 0)
            return (int)i;
    return -1;
}

/* Room for cap rows of ncol values, or 0 when that does not fit in size_t. */
static size_t n_values(size_t cap, size_t ncol)
{
    if (ncol != 0 && cap > SIZE_MAX / sizeof(double) / ncol)
        return 0;
    return cap * ncol;
}

/* The rows laid out anew with nc ≥ ncol values each (the new ones NaN)
 * in a block of exactly nrow rows, in place: realloc grows the block (a
 * large one by remapping its pages, not by copying) and the rows move
 * back to front, so the peak is the new table alone, not the old beside
 * it, and a capacity left over from a longer past (find's candidates) is
 * given back.  Issue 14: at 2048² the fit's 21 columns, added one by one
 * to the candidates' capacity, held two copies of it: 32 of 88 MB. */
static int relayout(mp_table *t, size_t nc)
{
    size_t rows = t->nrow ? t->nrow : 1, n = n_values(rows, nc);
    if (n == 0)
        return -1;
    double *v = realloc(t->v, n * sizeof *v);
    if (!v)
        return -1;
    for (size_t r = t->nrow; r-- > 0;) {
        if (t->ncol)
            memmove(v + r * nc, v + r * t->ncol, t->ncol * sizeof *v);
        for (size_t c = t->ncol; c < nc; c++)
            v[r * nc + c] = NAN;
    }
    t->v = v;
    t->cap = t->nrow;
    t->ncol = nc;
    return 0;
}

int mp_table_add_cols(mp_table *t, const char *const *names, int n, int *idx)
{
    size_t nc = t->ncol;
    mp_col *cols;
    for (int k = 0; k < n; k++) {
        int have = mp_table_col(t, names[k]);
        for (size_t j = t->ncol; have < 0 && j < nc; j++)
            if (strcmp(t->cols[j].name, names[k]) == 0)
                have = (int)j;
        if (have >= 0) {
            idx[k] = have;
            continue;
        }
        if (nc >= (size_t)INT32_MAX)
            return -1;
        mp_col c;
        if (mp_col_describe(names[k], &c) != 0)
            return -1;
        if (nc >= t->ccap) {
            /* Doubling: a header of thousands of columns (a vector's
             * hidden elements) copied them all at each one (a fuzz
             * timeout under ASan). */
            size_t ccap = nc >= 8 ? 2 * nc : 16;
            if (!(cols = realloc(t->cols, ccap * sizeof *cols)))
                return -1;
            t->cols = cols;
            t->ccap = ccap;
        }
        t->cols[nc] = c;
        idx[k] = (int)nc++;
    }
    if (nc == t->ncol)
        return 0;
    /* Rows are stored contiguously: new columns re-lay every row out. */
    if (t->cap > 0 || t->nrow > 0)
        return relayout(t, nc);
    t->ncol = nc;
    return 0;
}

int mp_table_add_col(mp_table *t, const char *name)
{
    int idx;
    return mp_table_add_cols(t, &name, 1, &idx) ? -1 : idx;
}

int mp_table_shrink(mp_table *t)
{
    if (t->cap <= t->nrow || t->ncol == 0)
        return 0;
    return relayout(t, t->ncol);
}

int mp_table_reserve(mp_table *t, size_t rows)
{
    if (rows <= t->cap)
        return 0;
    if (t->ncol > 0) {
        size_t n = n_values(rows, t->ncol);
        double *v = n ? realloc(t->v, n * sizeof *v) : NULL;
        if (!v)
            return -1;
        t->v = v;
    }
    t->cap = rows;
    return 0;
}

long mp_table_add_row(mp_table *t)
{
    if (t->nrow >= (size_t)LONG_MAX)
        return -1;
    if (t->nrow == t->cap) {
        /* Doubling keeps appending amortised O(1) per row. */
        size_t cap = t->cap ? 2 * t->cap : 64;
        if (t->ncol > 0) {
            size_t n = n_values(cap, t->ncol);
            if (n == 0)
                return -1;
            double *v = realloc(t->v, n * sizeof *v);
            if (!v)
                return -1;
            t->v = v;
        }
        t->cap = cap;
    }
    for (size_t c = 0; c < t->ncol; c++)
        t->v[t->nrow * t->ncol + c] = NAN;
    return (long)t->nrow++;
}

int mp_col_name_bad(const char *name)
{
    for (const char *p = name; *p; p++)
        if (!isgraph((unsigned char)*p) || (unsigned char)*p > 0x7e)
            return 1;
    return 0;
}
