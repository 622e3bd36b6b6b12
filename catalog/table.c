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
    t->ncol = t->nrow = t->cap = 0;
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

int mp_table_add_col(mp_table *t, const char *name)
{
    int have = mp_table_col(t, name);
    if (have >= 0)
        return have;
    if (t->ncol >= (size_t)INT32_MAX)
        return -1;

    mp_col c;
    if (mp_col_describe(name, &c) != 0)
        return -1;

    mp_col *cols = realloc(t->cols, (t->ncol + 1) * sizeof *cols);
    if (!cols)
        return -1;
    t->cols = cols;

    /* Rows are stored contiguously, so a new column means re-laying out
     * every row; columns are added a handful of times per table. */
    size_t nc = t->ncol + 1;
    if (t->cap > 0) {
        size_t n = n_values(t->cap, nc);
        if (n == 0)
            return -1;
        double *v = malloc(n * sizeof *v);
        if (!v)
            return -1;
        for (size_t r = 0; r < t->nrow; r++) {
            if (t->ncol)
                memcpy(v + r * nc, t->v + r * t->ncol, t->ncol * sizeof *v);
            v[r * nc + t->ncol] = NAN;
        }
        free(t->v);
        t->v = v;
    }
    t->cols[t->ncol] = c;
    t->ncol = nc;
    return (int)(nc - 1);
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
