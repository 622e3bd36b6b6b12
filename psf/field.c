/* field.c — spatially variable PSF tables: every element a polynomial of
 * order 0–2 in the star's position (DAOPHOT varorder, PSFEx PSFVAR_DEGREES),
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

/* PSFEx order: y power outer, x power inner, total degree ≤ order. */
void mp_psf_field_terms(const mp_psf_field *f, double x, double y, double *terms)
{
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

int mp_psf_field_new(int order, int nx, int ny, int os, double x0, double y0, double xs,
                     double ys, mp_psf_field *f, char *err)
{
    memset(f, 0, sizeof *f);
    int nt = mp_psf_nterms(order);
    if (!nt || nx < 1 || ny < 1 || nx % 2 == 0 || ny % 2 == 0 || os < 1 || os > 8 ||
        (order > 0 && !(isfinite(x0) && isfinite(y0) && xs > 0 && ys > 0 && isfinite(xs) &&
                        isfinite(ys)))) {
        snprintf(err, MP_ERRLEN, "psf field: bad order %d, size %dx%d, OVERSAMP %d or "
                 "scales %g, %g", order, nx, ny, os, xs, ys);
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
            if (mp_psf_field_new(in->order, dst.nx, dst.ny, dst.os, in->x0, in->y0,
                                 in->xscale, in->yscale, out, err)) {
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
