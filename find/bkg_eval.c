/* bkg_eval.c — a background map's values where they are used (find.h
 * mp_bkg): one cubic in x per pixel from the rows the spline is kept by,
 * and the residual's noise model pixel by pixel. */
#include <math.h>
#include <stdlib.h>

#include "find/find_priv.h"

/* Map m (0: sky, 1: rms) of row y: its nbx values and second derivatives. */
static const double *row_vals(const mp_bkg *b, int m, long y)
{
    return b->vals + ((size_t)(2 * m) * (size_t)b->ny + (size_t)y) * (size_t)b->nbx;
}

static const double *row_d2(const mp_bkg *b, int m, long y)
{
    return b->vals + ((size_t)(2 * m + 1) * (size_t)b->ny + (size_t)y) * (size_t)b->nbx;
}

/* The residual's noise at pixel i given its sky: sqrt(k²·(sky + M + RON²)
 * + ε²M² + the stars' F²·v(r)), M = frame − residual (find.h,
 * mp_bkg_noise_from_model, mp_bkg_star_excess); the same arithmetic as
 * its map was formed with. */
static float model_rms(const mp_bkg *b, size_t i, float sky)
{
    double m = fmax(b->pix[i] - b->res[i], 0.0);
    double v = fmax(sky, 0.0) + m + b->ron2;
    double x = b->nxs ? mp_bkg_excess_var(b, (double)(i % (size_t)b->nx),
                                          (double)(i / (size_t)b->nx)) : 0.0;
    return (float)sqrt(b->k * b->k * v + b->eps * b->eps * m * m + x);
}

float mp_bkg_sky(const mp_bkg *b, size_t i)
{
    long y = (long)(i / (size_t)b->nx), x = (long)(i % (size_t)b->nx);
    return mpf_spline_at(b->cx, row_vals(b, 0, y), row_d2(b, 0, y), b->nbx, x, 0);
}

float mp_bkg_rms(const mp_bkg *b, size_t i)
{
    long y = (long)(i / (size_t)b->nx), x = (long)(i % (size_t)b->nx);
    if (b->model)
        return model_rms(b, i, mp_bkg_sky(b, i));
    return mpf_spline_at(b->cx, row_vals(b, 1, y), row_d2(b, 1, y), b->nbx, x, 1);
}

void mp_bkg_rows(const mp_bkg *b, long y0, long y1, float *sky, float *rms)
{
    size_t nx = (size_t)b->nx;
    for (long y = y0; y < y1; y++) {
        float *s = sky + (size_t)(y - y0) * nx;
        mpf_spline_row(b->cx, row_vals(b, 0, y), row_d2(b, 0, y), b->nbx, s, b->nx, 0);
        if (!rms)
            continue;
        float *r = rms + (size_t)(y - y0) * nx;
        if (!b->model) {
            mpf_spline_row(b->cx, row_vals(b, 1, y), row_d2(b, 1, y), b->nbx, r, b->nx, 1);
            continue;
        }
        for (size_t x = 0; x < nx; x++)
            r[x] = model_rms(b, (size_t)y * nx + x, s[x]);
    }
}
