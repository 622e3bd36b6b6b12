/* render.c — noiseless stars and noise for the simulator (sim.h).
 *
 * Independent of the fitter on purpose (design.md §2): Gaussian PRFs are
 * integrated exactly over pixels (or DRF subpixels) with erf, and table
 * PSFs are block-summed from their own fine grid, never shifted. */
#include "sim/sim.h"

#include <math.h>
#include <stdlib.h>

/* Half-width of the rendered window in σ: the light beyond it on each
 * side, Φ(-8) = 6.2e-16, keeps the total truncated light below 3e-15. */
#define GAUSS_NSIGMA 8.0

static const double SQRT1_2 = 0.70710678118654752440;

static int prf_ok(const mp_sim_prf *p)
{
    if (!p)
        return 0;
    if (p->drf) {
        if (p->dk < 1)
            return 0;
    } else if (!(p->volume >= 0) || !isfinite(p->volume)) {
        return 0;
    }
    if (p->kind == MP_SIM_GAUSS)
        return p->sigma > 0 && isfinite(p->sigma) && p->sigy >= 0 && isfinite(p->sigy);
    if (p->kind == MP_SIM_TABLE)
        return p->tab && p->tnx >= 1 && p->tny >= 1 && p->tnx % 2 == 1 &&
               p->tny % 2 == 1 && p->tos >= 1 && (!p->drf || p->tos % p->dk == 0);
    return 0;
}

/* ∫ of the unit normal over [a,b] (a <= b, in σ), by erfc in the tails so
 * that faint wing pixels keep their relative precision. */
static double normal_interval(double a, double b)
{
    if (a >= 0)
        return 0.5 * (erfc(a * SQRT1_2) - erfc(b * SQRT1_2));
    if (b <= 0)
        return 0.5 * (erfc(-b * SQRT1_2) - erfc(-a * SQRT1_2));
    return 0.5 * (erf(b * SQRT1_2) - erf(a * SQRT1_2));
}

/* Subpixel integrals along one axis for pixels lo..hi: out[(p-lo)*dk + i]
 * is the Gaussian's share of [p-½+i/dk, p-½+(i+1)/dk]. */
static void axis_integrals(double c, double sigma, long lo, long hi, int dk, double *out)
{
    for (long p = lo; p <= hi; p++)
        for (int i = 0; i < dk; i++) {
            double a = (double)p - 0.5 + (double)i / dk - c;
            double b = (double)p - 0.5 + (double)(i + 1) / dk - c;
            out[(p - lo) * dk + i] = normal_interval(a / sigma, b / sigma);
        }
}

static long lmax(long a, long b) { return a > b ? a : b; }

/* The image a star is added to: double (the simulator's own) or float
 * (a frame's pixels, io.h); exactly one is set. */
typedef struct {
    double *d;
    float *f;
} sink;

static void add_at(sink img, size_t i, double v)
{
    if (img.d)
        img.d[i] += v;
    else
        img.f[i] = (float)(img.f[i] + v);
}
static long lmin(long a, long b) { return a < b ? a : b; }

static int add_gauss(const mp_sim_prf *p, double x, double y, double flux,
                     sink img, long nx, long ny)
{
    double sy = p->sigy > 0 ? p->sigy : p->sigma;
    double r = GAUSS_NSIGMA * (sy > p->sigma ? sy : p->sigma);
    /* Pixels containing x-r .. x+r, clipped to the image. */
    double fx0 = floor(x - r + 0.5), fx1 = floor(x + r + 0.5);
    double fy0 = floor(y - r + 0.5), fy1 = floor(y + r + 0.5);
    if (fx1 < 1 || fy1 < 1 || fx0 > nx || fy0 > ny)
        return 0;
    long x0 = lmax(1, (long)fmax(fx0, 0)), x1 = lmin(nx, (long)fmin(fx1, (double)nx));
    long y0 = lmax(1, (long)fmax(fy0, 0)), y1 = lmin(ny, (long)fmin(fy1, (double)ny));
    const int dk = p->drf ? p->dk : 1;
    const double unit = p->volume;
    const double *qe = p->drf ? p->drf : &unit;
    long wx = x1 - x0 + 1, wy = y1 - y0 + 1;

    double *ax = malloc(sizeof(double) * (size_t)(wx * dk));
    double *ay = malloc(sizeof(double) * (size_t)(wy * dk));
    double *w = malloc(sizeof(double) * (size_t)(wx * dk));
    if (!ax || !ay || !w) {
        free(ax); free(ay); free(w);
        return 1;
    }
    axis_integrals(x, p->sigma, x0, x1, dk, ax);
    axis_integrals(y, sy, y0, y1, dk, ay);
    /* w[j][px] = Σ_i qe(i,j)·ax(px,i): the x sums of each subpixel row,
     * so each pixel then costs dk products. */
    for (int j = 0; j < dk; j++)
        for (long px = 0; px < wx; px++) {
            double s = 0;
            for (int i = 0; i < dk; i++)
                s += qe[j * dk + i] * ax[px * dk + i];
            w[j * wx + px] = s;
        }
    for (long py = 0; py < wy; py++) {
        size_t row = (size_t)((y0 - 1 + py) * nx + (x0 - 1));
        for (long px = 0; px < wx; px++) {
            double s = 0;
            for (int j = 0; j < dk; j++)
                s += ay[py * dk + j] * w[j * wx + px];
            add_at(img, row + (size_t)px, flux * s);
        }
    }
    free(ax); free(ay); free(w);
    return 0;
}

/* Floor division for possibly negative fine indices. */
static long long floordiv(long long a, long long b)
{
    long long q = a / b;
    return (a % b != 0 && (a < 0) != (b < 0)) ? q - 1 : q;
}

/* The fine-grid offset m of a coordinate: on the grid when
 * c = ½ + (m + ½)/tos, i.e. m = c·tos − (tos+1)/2 is an integer. */
static double grid_offset(double c, int tos)
{
    return c * tos - (tos + 1) / 2.0;
}

void mp_sim_snap(const mp_sim_prf *p, double *x, double *y)
{
    if (!p || p->kind != MP_SIM_TABLE || p->tos < 1)
        return;
    double h = (p->tos + 1) / 2.0;
    *x = (round(grid_offset(*x, p->tos)) + h) / p->tos;
    *y = (round(grid_offset(*y, p->tos)) + h) / p->tos;
}

static int add_table(const mp_sim_prf *p, double x, double y, double flux,
                     sink img, long nx, long ny)
{
    const int tos = p->tos;
    if (fabs(x) > 1e12 || fabs(y) > 1e12)   /* beyond exact integer offsets */
        return 1;
    double sx = x, sy = y;
    mp_sim_snap(p, &sx, &sy);
    if (fabs(sx - x) > 1e-9 || fabs(sy - y) > 1e-9)
        return 1;
    long long mx = llround(grid_offset(x, tos)), my = llround(grid_offset(y, tos));
    /* Fine index (0-based over the whole image) of table element 0. */
    long long gx0 = mx - (p->tnx - 1) / 2, gy0 = my - (p->tny - 1) / 2;
    long long px0 = floordiv(gx0, tos) + 1, px1 = floordiv(gx0 + p->tnx - 1, tos) + 1;
    long long py0 = floordiv(gy0, tos) + 1, py1 = floordiv(gy0 + p->tny - 1, tos) + 1;
    if (px0 < 1) px0 = 1;
    if (py0 < 1) py0 = 1;
    if (px1 > nx) px1 = nx;
    if (py1 > ny) py1 = ny;
    for (long long py = py0; py <= py1; py++)
        for (long long px = px0; px <= px1; px++) {
            /* Exact block sum of this pixel's tos×tos fine elements, each
             * weighted by the QE of the DRF subpixel it lies in. */
            double sum = 0;
            for (int fy = 0; fy < tos; fy++) {
                long long j = (py - 1) * tos + fy - gy0;
                if (j < 0 || j >= p->tny)
                    continue;
                const double *trow = p->tab + j * p->tnx;
                for (int fx = 0; fx < tos; fx++) {
                    long long i = (px - 1) * tos + fx - gx0;
                    if (i < 0 || i >= p->tnx)
                        continue;
                    double qe = p->drf
                        ? p->drf[(fy * p->dk / tos) * p->dk + fx * p->dk / tos]
                        : p->volume;
                    sum += trow[i] * qe;
                }
            }
            add_at(img, (size_t)((py - 1) * nx + (px - 1)), flux * sum);
        }
    return 0;
}

static int add_star(const mp_sim_prf *p, double x, double y, double flux, sink img, long nx,
                    long ny)
{
    if (!prf_ok(p) || (!img.d && !img.f) || nx < 1 || ny < 1 || !isfinite(x) || !isfinite(y) ||
        !isfinite(flux))
        return 1;
    return p->kind == MP_SIM_GAUSS ? add_gauss(p, x, y, flux, img, nx, ny)
                                   : add_table(p, x, y, flux, img, nx, ny);
}

int mp_sim_add_star(const mp_sim_prf *p, double x, double y, double flux,
                    double *img, long nx, long ny)
{
    return add_star(p, x, y, flux, (sink){img, NULL}, nx, ny);
}

int mp_sim_add_star_float(const mp_sim_prf *p, double x, double y, double flux, float *img,
                          long nx, long ny)
{
    return add_star(p, x, y, flux, (sink){NULL, img}, nx, ny);
}

static double noisy(mp_rng *r, double m, double ron)
{
    double v = m > 0 ? mp_rng_poisson(r, m) : 0.0;
    if (ron > 0)
        v += ron * mp_rng_normal(r);
    return v;
}

void mp_sim_add_noise(mp_rng *r, double *img, long n, double ron)
{
    for (long i = 0; i < n; i++)
        img[i] = noisy(r, img[i], ron);
}

void mp_sim_add_noise_float(mp_rng *r, float *img, long n, double ron)
{
    for (long i = 0; i < n; i++)
        img[i] = (float)noisy(r, img[i], ron);
}
