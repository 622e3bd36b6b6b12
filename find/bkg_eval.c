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

/* The residual's noise at pixel i given its sky and the stars' excess
 * variance there, x: sqrt(k²·(sky + M + RON²) + ε²M² + x), M = frame −
 * residual (find.h, mp_bkg_noise_from_model, mp_bkg_star_excess); the
 * same arithmetic as its map was formed with. */
static float rms_with(const mp_bkg *b, size_t i, float sky, double x)
{
    double m = mpf_nonneg(b->pix[i] - b->res[i]);
    double v = mpf_nonneg(sky) + m + b->ron2;
    return (float)sqrt(b->k * b->k * v + b->eps * b->eps * m * m + x);
}

double mp_bkg_white_var(const mp_bkg *b, size_t i, float sky)
{
    if (!b->model) {
        double r = mp_bkg_rms(b, i);
        return r * r;
    }
    double m = mpf_nonneg(b->pix[i] - b->res[i]);
    return b->k * b->k * (mpf_nonneg(sky) + m + b->ron2);
}

/* The model rms of pixels [x0, x1) of row y into r, from their sky s
 * (s[x − x0]; NULL: each pixel's mp_bkg_sky), the stars' excess a span of
 * pixels at a time (mp_bkg_excess_span). */
enum { SPAN = 128 };
static void model_rms_span(const mp_bkg *b, long y, long x0, long x1, const float *s, float *r)
{
    size_t o = (size_t)y * (size_t)b->nx;
    double v[SPAN];
    for (long a = x0; a < x1; a += SPAN) {
        long e = a + SPAN < x1 ? a + SPAN : x1;
        if (b->nxs)
            mp_bkg_excess_span(b, y, a, e, v);
        for (long x = a; x < e; x++) {
            size_t i = o + (size_t)x;
            float sky = s ? s[x - x0] : mp_bkg_sky(b, i);
            r[x - x0] = rms_with(b, i, sky, b->nxs ? v[x - a] : 0.0);
        }
    }
}

void mp_bkg_rms_span(const mp_bkg *b, long y, long x0, long x1, float *rms)
{
    if (b->model) {
        model_rms_span(b, y, x0, x1, NULL, rms);
        return;
    }
    for (long x = x0; x < x1; x++)
        rms[x - x0] = mp_bkg_rms(b, (size_t)y * (size_t)b->nx + (size_t)x);
}

float mp_bkg_sky(const mp_bkg *b, size_t i)
{
    long y = (long)(i / (size_t)b->nx), x = (long)(i % (size_t)b->nx);
    return mpf_spline_at(b->cx, row_vals(b, 0, y), row_d2(b, 0, y), b->nbx, x, 0);
}

float mp_bkg_rms(const mp_bkg *b, size_t i)
{
    long y = (long)(i / (size_t)b->nx), x = (long)(i % (size_t)b->nx);
    if (b->model) {
        float r;
        model_rms_span(b, y, x, x + 1, NULL, &r);
        return r;
    }
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
        model_rms_span(b, y, 0, b->nx, s, r);
    }
}
