/* epsf.c — the built PSF's planes: terms of position, a table at a
 * position, options, freeing. */
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include "psf/build.h"

void mp_epsf_opts_default(double fwhm, long nx, long ny, mp_epsf_opts *o)
{
    memset(o, 0, sizeof *o);
    o->os = 0;
    o->fwhm = fwhm;
    o->psfrad = 4.0 * fwhm;
    o->fitrad = 2.0 * fwhm;
    o->order = -1;
    o->alpha = 1e-3;
    o->maxnpsf = 100;   /* 200 picked order 3 on 47 Tuc (README) */
    o->outer = 5;
    o->sirt = 30;
    /* PSFEx's origin and scales: the frame's centre, its half-sizes. */
    o->x0 = 0.5 * (double)(nx + 1);
    o->y0 = 0.5 * (double)(ny + 1);
    o->xs = nx > 1 ? 0.5 * (double)nx : 1.0;
    o->ys = ny > 1 ? 0.5 * (double)ny : 1.0;
}

void mp_epsf_free(mp_epsf *e)
{
    if (!e)
        return;
    free(e->planes);
    memset(e, 0, sizeof *e);
}

int mp_epsf_copy(const mp_epsf *e, mp_epsf *c)
{
    *c = *e;
    size_t n = (size_t)e->nterms * (size_t)e->nx * (size_t)e->ny;
    if (!(c->planes = malloc((n ? n : 1) * sizeof *c->planes)))
        return 1;
    memcpy(c->planes, e->planes, n * sizeof *c->planes);
    return 0;
}

void mp_epsf_terms(const mp_epsf *e, double x, double y, double *t)
{
    /* PSFEx order, as mp_psf_field_terms: y power outer, x power inner. */
    double dx = (x - e->x0) / e->xs, dy = (y - e->y0) / e->ys, py = 1.0;
    int k = 0;
    for (int j = 0; j <= e->order; j++) {
        double px = 1.0;
        for (int i = 0; i + j <= e->order; i++) {
            t[k++] = px * py;
            px *= dx;
        }
        py *= dy;
    }
}

int mp_epsf_table(const mp_epsf *e, double x, double y, mp_psf *p, char *err)
{
    size_t nel = (size_t)e->nx * e->ny;
    if (!p->t || p->nx != e->nx || p->ny != e->ny) {
        mp_psf_free(p);
        if (!(p->t = malloc(nel * sizeof *p->t))) {
            snprintf(err, MP_ERRLEN, "psf build: out of memory");
            return 1;
        }
    }
    double t[MP_EPSF_MAXT];
    mp_epsf_terms(e, x, y, t);
    double s = 0.0;
    for (size_t i = 0; i < nel; i++) {
        double v = 0.0;
        for (int k = 0; k < e->nterms; k++)
            v += t[k] * e->planes[(size_t)k * nel + i];
        p->t[i] = v;
        s += v;
    }
    p->kind = MP_PSF_TABLE;
    p->nx = e->nx;
    p->ny = e->ny;
    p->os = e->os;
    p->sum = s;
    p->offset = 0.0;
    p->sigma = 0.0;
    return 0;
}
