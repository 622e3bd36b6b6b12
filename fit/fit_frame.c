/* fit_frame.c — fitting every star of a table on one frame: grouping by
 * GROUP_ID (or the whole frame as one group when fitrad is INDEF), fitting
 * the groups in parallel, and writing the fit's columns (design.md §4). */
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include "fit/fit_frame.h"

/* Column of a table by the first name present, -1 if none. */
static int col_any(const mp_table *t, const char *a, const char *b)
{
    int c = mp_table_col(t, a);
    return c >= 0 ? c : (b ? mp_table_col(t, b) : -1);
}

typedef struct { double id; long row; } id_row;

static int cmp_id(const void *a, const void *b)
{
    const id_row *x = a, *y = b;
    if (x->id != y->id)
        return (x->id > y->id) - (x->id < y->id);
    return (x->row > y->row) - (x->row < y->row);
}

/* Groups as runs of rows sorted by group id. */
static int make_groups(const mp_table *t, int whole, id_row **out)
{
    int cg = mp_table_col(t, "GROUP_ID");
    id_row *r = malloc((t->nrow ? t->nrow : 1) * sizeof *r);
    if (!r)
        return 1;
    for (size_t i = 0; i < t->nrow; i++) {
        r[i].row = (long)i;
        if (whole)
            r[i].id = 0;
        else if (cg >= 0 && isfinite(mp_table_get(t, i, cg)))
            r[i].id = mp_table_get(t, i, cg);
        else
            r[i].id = -1.0 - (double)i;     /* a group of its own */
    }
    qsort(r, t->nrow, sizeof *r, cmp_id);
    *out = r;
    return 0;
}

int mp_fit_table(const mp_frame *f, const mp_prf_model *m, const mp_fit_opts *o,
                 mp_table *t, double magzero, char *err)
{
    int cx = col_any(t, "XPSF_IMAGE", "X_IMAGE"), cy = col_any(t, "YPSF_IMAGE", "Y_IMAGE");
    if (cx < 0 || cy < 0) {
        snprintf(err, MP_ERRLEN, "table has no X_IMAGE/Y_IMAGE or XPSF_IMAGE/YPSF_IMAGE columns");
        return 1;
    }
    int cf = col_any(t, "FLUX_PSF", "FLUX");
    int cs = col_any(t, "SKY_PSF", "BACKGROUND");
    size_t n = t->nrow;
    for (size_t i = 0; i < n; i++)
        if (!isfinite(mp_table_get(t, i, cx)) || !isfinite(mp_table_get(t, i, cy))) {
            snprintf(err, MP_ERRLEN, "row %zu: position is not a finite number", i + 1);
            return 1;
        }
    id_row *ord = NULL;
    mp_star *st = calloc(n ? n : 1, sizeof *st);
    if (!st || make_groups(t, !isfinite(o->fitrad), &ord)) {
        free(st);
        snprintf(err, MP_ERRLEN, "out of memory");
        return 1;
    }
    for (size_t i = 0; i < n; i++) {
        long r = ord[i].row;
        st[i].x = mp_table_get(t, (size_t)r, cx);
        st[i].y = mp_table_get(t, (size_t)r, cy);
        st[i].flux = cf >= 0 ? mp_table_get(t, (size_t)r, cf) : NAN;
        st[i].sky = cs >= 0 ? mp_table_get(t, (size_t)r, cs) : NAN;
    }
    /* Group starts: runs of equal id. */
    size_t *gs = malloc((n + 1) * sizeof *gs);
    if (!gs) {
        free(st);
        free(ord);
        snprintf(err, MP_ERRLEN, "out of memory");
        return 1;
    }
    size_t ng = 0;
    for (size_t i = 0; i < n; i++)
        if (i == 0 || ord[i].id != ord[i - 1].id)
            gs[ng++] = i;
    gs[ng] = n;
    int failed = 0;
    char ferr[MP_ERRLEN] = "";
#pragma omp parallel for schedule(dynamic)
    for (size_t g = 0; g < ng; g++) {
        char e[MP_ERRLEN];
        mp_star *s = st + gs[g];
        int k = (int)(gs[g + 1] - gs[g]);
        double sky0 = k == 1 ? s[0].sky : NAN;
        if (mp_fit_group(f, m, o, sky0, s, k, e)) {
#pragma omp critical(fit_error)
            {
                failed = 1;
                snprintf(ferr, sizeof ferr, "%s", e);
            }
        }
    }
    free(gs);
    if (failed) {
        free(st);
        free(ord);
        snprintf(err, MP_ERRLEN, "%s", ferr);
        return 1;
    }
    static const char *const names[] = {
        "XPSF_IMAGE", "YPSF_IMAGE", "ERRX_PSF", "ERRY_PSF", "FLUX_PSF", "FLUXERR_PSF",
        "MAG_PSF", "MAGERR_PSF", "SKY_PSF", "SKYERR_PSF", "CHI2_PSF", "DOF_PSF",
        "NITER_PSF", "BETA_PSF", "SHARP_PRF", "LSCALE_PRF", "VOLUME_PRF",
        "FLUXERR_MODEL", "POSERR_MODEL", "FLAGS"};
    enum { NCOL = sizeof names / sizeof names[0] };
    int c[NCOL];
    for (int k = 0; k < NCOL; k++)
        if ((c[k] = mp_table_add_col(t, names[k])) < 0) {
            free(st);
            free(ord);
            snprintf(err, MP_ERRLEN, "out of memory");
            return 1;
        }
    for (size_t i = 0; i < n; i++) {
        const mp_star *s = &st[i];
        size_t r = (size_t)ord[i].row;
        int ok = s->flux > 0;
        double v[NCOL] = {
            s->x, s->y, s->ex, s->ey, s->flux, s->eflux,
            ok ? -2.5 * log10(s->flux) + magzero : 99.0,
            ok ? 2.5 / log(10.0) * s->eflux / s->flux : 99.0,
            s->sky, s->esky, s->chi2, s->dof, s->niter,
            s->st.beta, s->st.sharp, s->st.lscale, s->st.volume,
            s->fluxerr_model, s->poserr_model, s->flags};
        for (int k = 0; k < NCOL; k++)
            mp_table_set(t, r, c[k], v[k]);
    }
    free(st);
    free(ord);
    return 0;
}

int mp_fit_residual(const mp_frame *f, const mp_prf_model *m, const mp_table *t,
                    double *res, char *err)
{
    long nx = f->im.nx, ny = f->im.ny;
    int cx = mp_table_col(t, "XPSF_IMAGE"), cy = mp_table_col(t, "YPSF_IMAGE");
    int cf = mp_table_col(t, "FLUX_PSF");
    if (cx < 0 || cy < 0 || cf < 0) {
        snprintf(err, MP_ERRLEN, "residual: table has no fitted columns");
        return 1;
    }
    for (long i = 0; i < nx * ny; i++)
        res[i] = f->mask[i] & MP_MASK_BAD ? NAN : f->im.pix[i];
    mp_prf_work w = {0};
    double *prf = NULL;
    size_t cap = 0;
    int rc = 0;
    for (size_t r = 0; r < t->nrow && !rc; r++) {
        double x = mp_table_get(t, r, cx), y = mp_table_get(t, r, cy), E = mp_table_get(t, r, cf);
        if (!isfinite(x) || !isfinite(y) || !isfinite(E))
            continue;
        long x0, y0;
        int bw, bh;
        mp_prf_box(m, x, y, &x0, &y0, &bw, &bh);
        if ((size_t)bw * bh > cap) {
            free(prf);
            cap = (size_t)bw * bh;
            if (!(prf = malloc(cap * sizeof *prf))) {
                rc = 1;
                break;
            }
        }
        if (mp_prf_render(m, x, y, prf, NULL, NULL, &w)) {
            rc = 1;
            break;
        }
        for (int j = 0; j < bh; j++) {
            long Y = y0 + j;
            if (Y < 1 || Y > ny)
                continue;
            for (int i = 0; i < bw; i++) {
                long X = x0 + i;
                if (X >= 1 && X <= nx)
                    res[(Y - 1) * nx + (X - 1)] -= E * prf[(size_t)j * bw + i];
            }
        }
    }
    free(prf);
    mp_prf_work_free(&w);
    if (rc)
        snprintf(err, MP_ERRLEN, "residual: out of memory");
    return rc;
}
