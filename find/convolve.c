/* convolve.c — the kernel amplitude h of every pixel (DAOFIND's
 * convolved image, Stetson 1987).  Where the footprint is whole and clean
 * (almost everywhere) h is one fixed kernel applied row by row; near
 * masked pixels and the image edge the kernel is lowered (unless the sky
 * is known) and normalised again over the good pixels, pixel by pixel. */
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "find/find_priv.h"

/* The sky rows a strip holds: row y at sky + (y − s0)·nx. */
typedef struct {
    const float *sky;
    long s0;
} sky_rows;

/* h at one pixel from its good taps only. */
static double h_slow(const mp_frame *f, const sky_rows *b, const mpf_kernel *k, long px, long py)
{
    long nx = f->im.nx, ny = f->im.ny;
    int n = 0;
    double sg = 0.0, sgg = 0.0, sd = 0.0, sgd = 0.0;
    for (int t = 0; t < k->n; t++) {
        long x = px + k->dx[t], y = py + k->dy[t];
        if (x < 0 || x >= nx || y < 0 || y >= ny)
            continue;
        size_t i = (size_t)y * (size_t)nx + (size_t)x;
        if (mpf_bad(f, i))
            continue;
        float sky = b->sky[(size_t)(y - b->s0) * (size_t)nx + (size_t)x];
        double g = k->g[t], d = f->im.pix[i] - sky;
        n++;
        sg += g;
        sgg += g * g;
        sd += d;
        sgd += g * d;
    }
    if (n < k->nmin)
        return MPF_NO_H;
    double denom = k->known ? sgg : sgg - sg * sg / n;
    if (!(denom > 1e-12 * k->denom))
        return MPF_NO_H;
    return k->known ? sgd / denom : (sgd - sg * sd / n) / denom;
}

/* o[x] += w·(p[x] − s[x]) for x in [0, n): one tap over one row, the
 * inner loop of the whole detection.  restrict and four independent
 * lanes let -O2 keep it in registers without asking for vectorisation
 * (which clang -O1 refuses under -Werror). */
static void tap_row(double *restrict o, const float *restrict p, const float *restrict s,
                    double w, long n)
{
    long x = 0;
    for (; x + 4 <= n; x += 4) {
        double a = (double)p[x] - s[x], b = (double)p[x + 1] - s[x + 1];
        double c = (double)p[x + 2] - s[x + 2], d = (double)p[x + 3] - s[x + 3];
        o[x] += w * a;
        o[x + 1] += w * b;
        o[x + 2] += w * c;
        o[x + 3] += w * d;
    }
    for (; x < n; x++)
        o[x] += w * ((double)p[x] - s[x]);
}

int mpf_any_bad(const mp_frame *f)
{
    /* In parallel, every pixel read (a frame without a bad pixel reads all
     * of them anyway): 1 % of a 1024² crowded frame's detection, serial
     * (issue 14, bench/SCALING.md session 39).  The answer is an or. */
    size_t n = (size_t)f->im.nx * (size_t)f->im.ny;
    int bad = 0;
#pragma omp parallel for schedule(static) reduction(| : bad) if (n > 65536)
    for (size_t i = 0; i < n; i++)
        bad |= mpf_bad(f, i);
    return bad;
}

/* near[x]: a bad pixel lies in the (2nh+1)² box around (x, y); colbad
 * holds nx flags of work. */
static void near_bad(const mp_frame *f, long nh, long y, unsigned char *colbad,
                     unsigned char *near)
{
    long nx = f->im.nx;
    memset(colbad, 0, (size_t)nx);
    for (long j = y - nh; j <= y + nh; j++)
        for (long x = 0; x < nx; x++)
            colbad[x] |= (unsigned char)mpf_bad(f, (size_t)j * (size_t)nx + (size_t)x);
    long run = 0;    /* bad columns in [x - nh, x + nh] */
    for (long x = 0; x < nh && x < nx; x++)
        run += colbad[x];
    for (long x = 0; x < nx; x++) {
        if (x + nh < nx)
            run += colbad[x + nh];
        if (x - nh - 1 >= 0)
            run -= colbad[x - nh - 1];
        near[x] = run > 0;
    }
}

/* Row y of h into ho: the fixed kernel where its footprint is whole and
 * clean, h_slow elsewhere.  o holds nx doubles of work (a row summed in
 * double, kept in single precision: h is an image of the frame's size,
 * issue 14's memory); colbad and near nx flags each when bad. */
static void convolve_row(const mp_frame *f, const sky_rows *b, const mpf_kernel *k, int bad,
                         long y, double *o, unsigned char *colbad, unsigned char *near,
                         float *ho)
{
    long nx = f->im.nx, ny = f->im.ny, nh = k->nh;
    long x0 = nh, x1 = nx - nh;     /* whole footprints: [x0, x1) */
    if (y < nh || y >= ny - nh || x1 <= x0) {
        for (long x = 0; x < nx; x++)
            ho[x] = (float)h_slow(f, b, k, x, y);
        return;
    }
    for (long x = x0; x < x1; x++)
        o[x] = 0.0;
    for (int t = 0; t < k->n; t++) {
        size_t off = (size_t)(y + k->dy[t]) * (size_t)nx;
        size_t soff = (size_t)(y + k->dy[t] - b->s0) * (size_t)nx;
        tap_row(o + x0, f->im.pix + off + k->dx[t] + x0, b->sky + soff + k->dx[t] + x0,
                k->kl[t], x1 - x0);
    }
    for (long x = 0; x < x0; x++)
        o[x] = h_slow(f, b, k, x, y);
    for (long x = x1; x < nx; x++)
        o[x] = h_slow(f, b, k, x, y);
    if (bad) {
        near_bad(f, nh, y, colbad, near);
        for (long x = x0; x < x1; x++)
            if (near[x])
                o[x] = h_slow(f, b, k, x, y);
    }
    for (long x = 0; x < nx; x++)
        ho[x] = (float)o[x];
}

int mpf_convolve_rows(const mp_frame *f, const float *sky, long s0, const mpf_kernel *k,
                      int bad, long y0, long y1, float *h, char *err)
{
    long nx = f->im.nx;
    const sky_rows srows = {sky, s0};
    int nomem = 0;
#pragma omp parallel
    {
        unsigned char *colbad = bad ? malloc((size_t)nx) : NULL;
        unsigned char *near = bad ? malloc((size_t)nx) : NULL;
        double *o = malloc((size_t)nx * sizeof *o);
        int ok = !(bad && (!colbad || !near)) && o;
        if (!ok) {
#pragma omp atomic write
            nomem = 1;
        }
#pragma omp for schedule(static)
        for (long y = y0; y < y1; y++)
            if (ok)
                convolve_row(f, &srows, k, bad, y, o, colbad, near,
                             h + (size_t)(y - y0) * (size_t)nx);
        free(o);
        free(colbad);
        free(near);
    }
    if (nomem) {
        snprintf(err, MP_ERRLEN, "out of memory for the convolution");
        return 1;
    }
    return 0;
}
