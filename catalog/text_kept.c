/*
 * text_kept.c — a table's ASCII_HEAD rows kept as written
 * (mp_table_write_kept, catalog.h), so that the next table written with
 * them copies the rows it shares instead of formatting them again: the
 * pipeline writes root.grp, then root.fit, whose rows are mostly the same
 * stars with the same values, and the text's numbers were 4 % of a
 * 5000-star frame's instructions; then root.cat, root.fit's columns and
 * the sky positions after them.
 */
#include <math.h>
#include <stdint.h>
#include <stdlib.h>
#include <string.h>

#include "catalog/table_priv.h"

struct mp_text_kept {
    size_t ncol, nrow;
    mp_col *cols;          /* the columns as written */
    double *v;             /* the values, v[row·ncol + col] */
    char *text;            /* the rows' text, row r at off[r] .. off[r + 1] */
    size_t *off;
    uint32_t *at;          /* NUMBER → its row + 1 (0: none), nat of them */
    size_t nat;
};

void mp_text_kept_free(mp_text_kept *k)
{
    if (!k)
        return;
    free(k->cols);
    free(k->v);
    free(k->text);
    free(k->off);
    free(k->at);
    free(k);
}

/* A whole NUMBER an index can hold, else −1. */
static long number_of(double v)
{
    return v >= 0 && v < 1e8 && v == floor(v) ? (long)v : -1;
}

int mp_text_kept_fits(const mp_text_kept *k, const mp_table *t)
{
    if (!k || k->ncol == 0 || k->ncol > t->ncol || !k->at)
        return 0;
    for (size_t c = 0; c < k->ncol; c++)
        if (strcmp(k->cols[c].name, t->cols[c].name) || strcmp(k->cols[c].fmt, t->cols[c].fmt) ||
            k->cols[c].is_int != t->cols[c].is_int)
            return 0;
    return 1;
}

int mp_text_kept_row(const mp_text_kept *k, const mp_table *t, int cnum, size_t r,
                     const char **s, size_t *len)
{
    long num = number_of(mp_table_get(t, r, cnum));
    if (num < 0 || (size_t)num >= k->nat || !k->at[num])
        return 0;
    size_t q = k->at[num] - 1;
    if (memcmp(k->v + q * k->ncol, t->v + r * t->ncol, k->ncol * sizeof *t->v) != 0)
        return 0;            /* bit for bit: the same bits print the same */
    *s = k->text + k->off[q];
    *len = k->off[q + 1] - k->off[q];
    return 1;
}

size_t mp_text_kept_ncol(const mp_text_kept *k)
{
    return k ? k->ncol : 0;
}

/* The index NUMBER → row of k (none when a NUMBER is missing, not
 * whole, or repeated); nonzero when out of memory. */
static int index_numbers(mp_text_kept *k, int cnum)
{
    if (cnum < 0)
        return 0;
    long mx = -1;
    for (size_t r = 0; r < k->nrow; r++) {
        long n = number_of(k->v[r * k->ncol + (size_t)cnum]);
        if (n < 0)
            return 0;
        mx = n > mx ? n : mx;
    }
    k->nat = (size_t)(mx + 1);
    if (!(k->at = calloc(k->nat + 1, sizeof *k->at)))
        return 1;
    for (size_t r = 0; r < k->nrow; r++) {
        long n = number_of(k->v[r * k->ncol + (size_t)cnum]);
        if (k->at[n]) {         /* repeated: nothing is copied */
            free(k->at);
            k->at = NULL;
            return 0;
        }
        k->at[n] = (uint32_t)(r + 1);
    }
    return 0;
}

int mp_text_kept_make(mp_text_kept **out, const mp_table *t, char *text, size_t len)
{
    mp_text_kept *k = calloc(1, sizeof *k);
    size_t nv = t->nrow * t->ncol;
    if (!k || !(k->cols = malloc((t->ncol + 1) * sizeof *k->cols)) ||
        !(k->v = malloc((nv + 1) * sizeof *k->v)) ||
        !(k->off = malloc((t->nrow + 1) * sizeof *k->off))) {
        mp_text_kept_free(k);
        free(text);
        return 1;
    }
    k->ncol = t->ncol;
    k->nrow = t->nrow;
    k->text = text;
    memcpy(k->cols, t->cols, t->ncol * sizeof *k->cols);
    if (nv)
        memcpy(k->v, t->v, nv * sizeof *k->v);
    /* a row's text ends at its newline: its numbers hold none */
    size_t r = 0;
    k->off[0] = 0;
    for (size_t i = 0; i < len && r < t->nrow; i++)
        if (text[i] == '\n')
            k->off[++r] = i + 1;
    if (r != t->nrow || index_numbers(k, mp_table_col(t, "NUMBER"))) {
        mp_text_kept_free(k);
        return r != t->nrow ? 0 : 1;     /* rows not as expected: none kept */
    }
    *out = k;
    return 0;
}
