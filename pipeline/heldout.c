/* heldout.c — the PSF's next order judged by the stars it was not built
 * from (issue 11, varorder=auto; tests/validate/psfbuild/psfbuild_notes.md
 * "Stars held out of the build", "The held-out test at the end of the
 * run").
 *
 * Why: the order test on the PSF stars' residuals (psf/varorder.c) cannot
 * see the part of a shape error that a star's flux and position absorb,
 * and that part is what biases the photometry: on the variable scene it
 * stops at order 2 while order 3 takes the brightest stars' errors from
 * 1.43 to about 1.1 of the bound.  Every table fits the stars it was made
 * from; the bright stars that were not PSF stars are a held-out set.  An
 * order that only fits the table's noise makes them fit worse; one the
 * PSF needs makes them fit better: cross-validation.  Each held-out star
 * is fitted with the two tables on the same frame (the frame less every
 * other fitted star), in groups of the held-out stars alone, and the
 * tables are compared by the paired log ratio of the stars' own-disc χ²
 * (CHI2STAR_PSF). */
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include "pipeline/pipeline_priv.h"

/* A candidate's row and flux. */
typedef struct {
    size_t row;
    double flux;
} row_flux;

static int brighter(const void *p, const void *q)
{
    double a = ((const row_flux *)p)->flux, b = ((const row_flux *)q)->flux;
    return (a < b) - (a > b);
}

/* Whether (x, y) is within 1 px of a PSF star. */
static int is_psf_star(const double *px, const double *py, size_t np, double x, double y)
{
    for (size_t k = 0; k < np; k++)
        if (fabs(px[k] - x) < 1.0 && fabs(py[k] - y) < 1.0)
            return 1;
    return 0;
}

long mp_pl_heldout_rows(const mp_table *t, const double *px, const double *py, size_t np,
                        size_t max, unsigned char *sel)
{
    int cf = mp_table_col(t, "FLUX_PSF"), ce = mp_table_col(t, "FLUXERR_PSF"),
        cg = mp_table_col(t, "FLAGS"), cx = mp_table_col(t, "X_IMAGE"),
        cy = mp_table_col(t, "Y_IMAGE");
    memset(sel, 0, t->nrow);
    if (cf < 0 || ce < 0 || cg < 0 || cx < 0 || cy < 0)
        return 0;
    row_flux *c = malloc((t->nrow + 1) * sizeof *c);
    if (!c)
        return -1;
    size_t n = 0;
    for (size_t r = 0; r < t->nrow; r++) {
        double F = mp_table_get(t, r, cf), E = mp_table_get(t, r, ce);
        if (E > 0 && F >= MP_PL_HELDOUT_SNR * E && mp_table_get(t, r, cg) == 0 &&
            !is_psf_star(px, py, np, mp_table_get(t, r, cx), mp_table_get(t, r, cy)))
            c[n++] = (row_flux){r, F};
    }
    qsort(c, n, sizeof *c, brighter);
    n = n < max ? n : max;
    for (size_t k = 0; k < n; k++)
        sel[c[k].row] = 1;
    free(c);
    return (long)n;
}

int mp_pl_rows_of(const mp_table *t, const unsigned char *sel, int want, mp_table *out)
{
    mp_table_init(out);
    for (size_t c = 0; c < t->ncol; c++)
        if (mp_table_add_col(out, t->cols[c].name) < 0)
            return 1;
    /* the rows counted first, their block allocated once and copied (row
     * by row, root.grp's copy of a 2048² frame's 15 900 rows of 32 values,
     * 4 MB, each round, was half a per cent of its run: doubling, NaN
     * fills, copies) */
    size_t m = 0;
    for (size_t r = 0; r < t->nrow; r++)
        m += !sel || !sel[r] == !want;
    if (mp_table_reserve(out, m ? m : 1))
        return 1;
    if (!sel) {                             /* out has t's columns, in order */
        size_t nv = t->nrow * t->ncol, blk = 1 << 16;   /* values, in blocks by thread */
#pragma omp parallel for schedule(static) if (nv > blk)
        for (size_t b = 0; b < nv; b += blk)
            memcpy(out->v + b, t->v + b, (nv - b < blk ? nv - b : blk) * sizeof *t->v);
        out->nrow = t->nrow;
        return 0;
    }
    for (size_t r = 0; r < t->nrow; r++)
        if (!sel || !sel[r] == !want)
            memcpy(out->v + out->nrow++ * out->ncol, t->v + r * t->ncol, t->ncol * sizeof *t->v);
    return 0;
}

int mp_pl_heldout_fit(const mp_frame *f, const mp_table *held, mp_parset *ps, const char *psf,
                      const mp_group_opts *go, mp_table *out, char *err)
{
    mp_fit_setup su;
    char e3[MP_ERRLEN];
    mp_table_init(out);
    int rc = mp_params_set(ps, "psf", psf, err) || mp_fit_setup_read(ps, &su, err);
    mp_params_set(ps, "psf", "", e3);
    if (rc)
        return 1;
    long tested, linked;
    if ((rc = mp_pl_rows_of(held, NULL, 1, out)))
        snprintf(err, MP_ERRLEN, "held-out stars: out of memory");
    /* grouped among themselves: every other star is off the frame */
    rc = rc || mp_pl_group(out, go, &su.model, 0.0, 0.0, f->rdnoise, NULL, &tested, &linked, err) ||
         mp_fit_table(f, &su.model, &su.opts, out, NULL, err);
    mp_fit_setup_free(&su);
    return rc;
}

/* A star's NUMBER and CHI2STAR_PSF. */
typedef struct {
    double num, chi2;
} num_chi2;

static int by_num(const void *p, const void *q)
{
    double a = ((const num_chi2 *)p)->num, b = ((const num_chi2 *)q)->num;
    return (a > b) - (a < b);
}

/* log(χ²_b/χ²_a) of the stars of a and b with the same NUMBER and both
 * CHI2STAR_PSF finite and > 0 into l[]; their number, (size_t)-1 when out
 * of memory. */
static size_t log_ratios(const mp_table *a, const mp_table *b, double *l)
{
    int na = mp_table_col(a, "NUMBER"), nb = mp_table_col(b, "NUMBER");
    int ca = mp_table_col(a, "CHI2STAR_PSF"), cb = mp_table_col(b, "CHI2STAR_PSF");
    if (na < 0 || nb < 0 || ca < 0 || cb < 0)
        return 0;
    num_chi2 *bb = malloc((b->nrow + 1) * sizeof *bb);
    if (!bb)
        return (size_t)-1;
    for (size_t j = 0; j < b->nrow; j++)
        bb[j] = (num_chi2){mp_table_get(b, j, nb), mp_table_get(b, j, cb)};
    qsort(bb, b->nrow, sizeof *bb, by_num);
    size_t n = 0;
    for (size_t i = 0; i < a->nrow; i++) {
        num_chi2 key = {mp_table_get(a, i, na), 0.0};
        const num_chi2 *hit = bsearch(&key, bb, b->nrow, sizeof *bb, by_num);
        double x = mp_table_get(a, i, ca), y = hit ? hit->chi2 : NAN;
        if (x > 0 && y > 0 && isfinite(x) && isfinite(y))
            l[n++] = log(y / x);
    }
    free(bb);
    return n;
}

int mp_pl_heldout_compare(const mp_table *a, const mp_table *b, mp_pl_heldout *h)
{
    size_t cap = a->nrow < b->nrow ? a->nrow : b->nrow;
    double *l = malloc((cap + 1) * sizeof *l);
    if (!l)
        return 1;
    size_t n = log_ratios(a, b, l);
    if (n == (size_t)-1) {
        free(l);
        return 1;
    }
    double s = 0.0, ss = 0.0;
    for (size_t k = 0; k < n; k++)
        s += l[k];
    double m = n ? s / (double)n : 0.0;
    for (size_t k = 0; k < n; k++)
        ss += (l[k] - m) * (l[k] - m);
    free(l);
    h->n = n;
    h->mean = m;
    h->z = n > 1 && ss > 0 ? m / sqrt(ss / ((double)n - 1.0) / (double)n) : 0.0;
    return 0;
}
