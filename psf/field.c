/* field.c — spatially variable PSF tables: every element a polynomial of
 * order 0–3 in the star's position (DAOPHOT varorder, PSFEx PSFVAR_DEGREES),
 * evaluated, made and block-summed. */
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include "psf/psf.h"

int mp_psf_nterms(int order)
{
    return order >= 0 && order <= MP_PSF_MAXORDER ? (order + 1) * (order + 2) / 2 : 0;
}

void mp_psf_field_free(mp_psf_field *f)
{
    if (!f)
        return;
    free(f->planes);
    memset(f, 0, sizeof *f);
}

/* Where v falls on the ascending grid g[0..n−1]: the cell's low index and
 * the weight of its high end, clamped to the grid. */
static void grid_cell(const double *g, int n, double v, int *i, double *w)
{
    if (n == 1 || !(v > g[0])) {
        *i = 0;
        *w = 0.0;
        return;
    }
    if (v >= g[n - 1]) {
        *i = n - 2;
        *w = 1.0;
        return;
    }
    int k = 0;
    while (k < n - 2 && v >= g[k + 1])
        k++;
    *i = k;
    *w = (v - g[k]) / (g[k + 1] - g[k]);
}

static void grid_terms(const mp_psf_field *f, double x, double y, double *terms)
{
    for (int k = 0; k < f->nterms; k++)
        terms[k] = 0.0;
    int i, j;
    double wx, wy;
    grid_cell(f->gx, f->ngx, x, &i, &wx);
    grid_cell(f->gy, f->ngy, y, &j, &wy);
    int i1 = f->ngx > 1 ? i + 1 : i, j1 = f->ngy > 1 ? j + 1 : j;
    terms[j * f->ngx + i] += (1 - wx) * (1 - wy);
    terms[j * f->ngx + i1] += wx * (1 - wy);
    terms[j1 * f->ngx + i] += (1 - wx) * wy;
    terms[j1 * f->ngx + i1] += wx * wy;
}

/* PSFEx order: y power outer, x power inner, total degree ≤ order. */
void mp_psf_field_terms(const mp_psf_field *f, double x, double y, double *terms)
{
    if (f->order == MP_PSF_GRID) {
        grid_terms(f, x, y, terms);
        return;
    }
    double dx = f->order > 0 ? (x - f->x0) / f->xscale : 0.0;
    double dy = f->order > 0 ? (y - f->y0) / f->yscale : 0.0;
    int k = 0;
    double py = 1.0;
    for (int j = 0; j <= f->order; j++) {
        double px = 1.0;
        for (int i = 0; i + j <= f->order; i++) {
            terms[k++] = px * py;
            px *= dx;
        }
        py *= dy;
    }
}

void mp_psf_field_eval_rect(const mp_psf_field *f, double x, double y, long i0, long i1,
                            long j0, long j1, double *out)
{
    double c[MP_PSF_MAXTERMS];
    mp_psf_field_terms(f, x, y, c);
    size_t plane = (size_t)f->nx * (size_t)f->ny;
    for (long j = j0; j < j1; j++) {
        double *o = out + (size_t)j * f->nx;
        const double *p0 = f->planes + (size_t)j * f->nx;
        for (long i = i0; i < i1; i++)
            o[i] = c[0] * p0[i];
        for (int k = 1; k < f->nterms; k++) {
            const double *pk = p0 + (size_t)k * plane;
            double ck = c[k];
            if (ck == 0.0)
                continue;       /* a grid's far planes */
            for (long i = i0; i < i1; i++)
                o[i] += ck * pk[i];
        }
    }
}

int mp_psf_field_eval(const mp_psf_field *f, double x, double y, mp_psf *out, char *err)
{
    memset(out, 0, sizeof *out);
    size_t n = (size_t)f->nx * (size_t)f->ny;
    out->t = malloc(n * sizeof *out->t);
    if (!out->t) {
        snprintf(err, MP_ERRLEN, "psf field: out of memory");
        return 1;
    }
    mp_psf_field_eval_rect(f, x, y, 0, f->nx, 0, f->ny, out->t);
    double s = 0.0;
    for (size_t i = 0; i < n; i++)
        s += out->t[i];
    out->kind = MP_PSF_TABLE;
    out->nx = f->nx;
    out->ny = f->ny;
    out->os = f->os;
    out->sum = s;
    out->offset = f->offset;
    return 0;
}

int mp_psf_field_origin_ok(double x0, double y0, double xs, double ys)
{
    return fabs(x0) <= MP_PSF_MAXPOS && fabs(y0) <= MP_PSF_MAXPOS && xs >= MP_PSF_MINSCALE &&
           ys >= MP_PSF_MINSCALE && xs <= MP_PSF_MAXPOS && ys <= MP_PSF_MAXPOS;
}

int mp_psf_field_new(int order, int nx, int ny, int os, double x0, double y0, double xs,
                     double ys, mp_psf_field *f, char *err)
{
    memset(f, 0, sizeof *f);
    int nt = mp_psf_nterms(order);
    if (!nt || nx < 1 || ny < 1 || nx % 2 == 0 || ny % 2 == 0 || os < 1 || os > 8 ||
        (order > 0 && !mp_psf_field_origin_ok(x0, y0, xs, ys))) {
        snprintf(err, MP_ERRLEN, "psf field: bad order %d, size %dx%d, OVERSAMP %d, origin "
                 "%g, %g or scales %g, %g", order, nx, ny, os, x0, y0, xs, ys);
        return 1;
    }
    f->planes = calloc((size_t)nt * (size_t)nx * (size_t)ny, sizeof *f->planes);
    if (!f->planes) {
        snprintf(err, MP_ERRLEN, "psf field: out of memory");
        return 1;
    }
    f->order = order;
    f->nterms = nt;
    f->nx = nx;
    f->ny = ny;
    f->os = os;
    f->x0 = order > 0 ? x0 : 0.0;
    f->y0 = order > 0 ? y0 : 0.0;
    f->xscale = order > 0 ? xs : 1.0;
    f->yscale = order > 0 ? ys : 1.0;
    return 0;
}

int mp_psf_field_new_grid(int ngx, int ngy, const double *gx, const double *gy, int nx, int ny,
                          int os, mp_psf_field *f, char *err)
{
    memset(f, 0, sizeof *f);
    int ok = ngx >= 1 && ngy >= 1 && ngx <= MP_PSF_MAXGRID && ngy <= MP_PSF_MAXGRID &&
             ngx * ngy <= MP_PSF_MAXTERMS && nx % 2 && ny % 2 && nx > 0 && ny > 0 && os >= 1 &&
             os <= 8;
    for (int i = 0; ok && i < ngx; i++)
        ok = fabs(gx[i]) <= MP_PSF_MAXPOS && (i == 0 || gx[i] > gx[i - 1]);
    for (int j = 0; ok && j < ngy; j++)
        ok = fabs(gy[j]) <= MP_PSF_MAXPOS && (j == 0 || gy[j] > gy[j - 1]);
    if (!ok) {
        snprintf(err, MP_ERRLEN, "psf grid: bad grid %dx%d (at most %d a side, positions "
                 "ascending within +-1e7 px), table %dx%d or OVERSAMP %d",
                 ngx, ngy, MP_PSF_MAXGRID, nx, ny, os);
        return 1;
    }
    f->planes = calloc((size_t)ngx * ngy * nx * ny, sizeof *f->planes);
    if (!f->planes) {
        snprintf(err, MP_ERRLEN, "psf grid: out of memory");
        return 1;
    }
    f->order = MP_PSF_GRID;
    f->nterms = ngx * ngy;
    f->ngx = ngx;
    f->ngy = ngy;
    memcpy(f->gx, gx, (size_t)ngx * sizeof *gx);
    memcpy(f->gy, gy, (size_t)ngy * sizeof *gy);
    f->nx = nx;
    f->ny = ny;
    f->os = os;
    /* Centre and span: what the crop envelope's corner points read. */
    f->x0 = 0.5 * (gx[0] + gx[ngx - 1]);
    f->y0 = 0.5 * (gy[0] + gy[ngy - 1]);
    f->xscale = gx[ngx - 1] - gx[0];
    f->yscale = gy[ngy - 1] - gy[0];
    return 0;
}

void mp_psf_local(const mp_psf *p, double dx, double dy, mp_psf *out, mp_psf_field *fout)
{
    *out = *p;
    if (!p->field)
        return;
    *fout = *p->field;
    fout->x0 -= dx;
    fout->y0 -= dy;
    for (int i = 0; i < fout->ngx; i++)
        fout->gx[i] -= dx;
    for (int j = 0; j < fout->ngy; j++)
        fout->gy[j] -= dy;
    out->field = fout;
}

int mp_psf_field_from_table(const mp_psf *p, mp_psf_field *f, char *err)
{
    if (p->kind != MP_PSF_TABLE) {
        memset(f, 0, sizeof *f);
        snprintf(err, MP_ERRLEN, "psf field: the analytic Gaussian is not a table");
        return 1;
    }
    if (mp_psf_field_new(0, p->nx, p->ny, p->os, 0, 0, 1, 1, f, err))
        return 1;
    memcpy(f->planes, p->t, (size_t)p->nx * (size_t)p->ny * sizeof *p->t);
    f->sum = p->sum;
    f->offset = p->offset;
    return 0;
}

int mp_psf_field_rebin(const mp_psf_field *in, int factor, mp_psf_field *out, char *err)
{
    memset(out, 0, sizeof *out);
    size_t plane = (size_t)in->nx * (size_t)in->ny;
    for (int k = 0; k < in->nterms; k++) {
        mp_psf src = {.kind = MP_PSF_TABLE, .nx = in->nx, .ny = in->ny, .os = in->os,
                      .t = in->planes + (size_t)k * plane, .offset = in->offset};
        mp_psf dst;
        if (mp_psf_rebin(&src, factor, &dst, err)) {
            mp_psf_field_free(out);
            return 1;
        }
        if (k == 0) {
            int bad = in->order == MP_PSF_GRID
                          ? mp_psf_field_new_grid(in->ngx, in->ngy, in->gx, in->gy, dst.nx,
                                                  dst.ny, dst.os, out, err)
                          : mp_psf_field_new(in->order, dst.nx, dst.ny, dst.os, in->x0, in->y0,
                                             in->xscale, in->yscale, out, err);
            if (bad) {
                mp_psf_free(&dst);
                return 1;
            }
            out->offset = dst.offset;
        }
        memcpy(out->planes + (size_t)k * dst.nx * dst.ny, dst.t,
               (size_t)dst.nx * dst.ny * sizeof *dst.t);
        mp_psf_free(&dst);
    }
    out->sum = in->sum;
    out->nstar = in->nstar;
    memcpy(out->why, in->why, sizeof out->why);
    return 0;
}
