/* centroid.c — what DAOFIND measures of a candidate (Stetson 1987; IRAF
 * daofind; anchors.md §1.1): sharpness, centroids and heights from 1-D
 * Gaussian fits to the marginal sums, the roundness "ground" from those
 * heights, and a first flux. */
#include <math.h>
#include <stdlib.h>
#include <string.h>

#include "find/find_priv.h"

#define MAX_ITER 25

/* Solve the 3×3 system a·x = r by Gaussian elimination with partial
 * pivoting; nonzero when singular. */
static int solve3(double a[3][3], double r[3], double x[3])
{
    for (int c = 0; c < 3; c++) {
        int p = c;
        for (int i = c + 1; i < 3; i++)
            if (fabs(a[i][c]) > fabs(a[p][c]))
                p = i;
        if (!(fabs(a[p][c]) > 1e-300))
            return 1;
        if (p != c) {
            for (int j = 0; j < 3; j++) {
                double t = a[c][j];
                a[c][j] = a[p][j];
                a[p][j] = t;
            }
            double t = r[c];
            r[c] = r[p];
            r[p] = t;
        }
        for (int i = c + 1; i < 3; i++) {
            double m = a[i][c] / a[c][c];
            for (int j = c; j < 3; j++)
                a[i][j] -= m * a[c][j];
            r[i] -= m * r[c];
        }
    }
    for (int i = 2; i >= 0; i--) {
        double s = r[i];
        for (int j = i + 1; j < 3; j++)
            s -= a[i][j] * x[j];
        x[i] = s / a[i][i];
    }
    for (int i = 0; i < 3; i++)
        if (!isfinite(x[i]))
            return 1;
    return 0;
}

/* One marginal: its values m[i], template factors c[i] and weights u[i]
 * for i = −nh..nh (stored at i + nh). */
typedef struct {
    int nh;
    double m[2 * MPF_MAX_HALF + 1], c[2 * MPF_MAX_HALF + 1], u[2 * MPF_MAX_HALF + 1];
} marginal;

/* The marginal of the box around (px, py) along axis (0: x, 1: y), with
 * DAOFIND's triangular weights nh + 1 − |j| across it.  Masked pixels are
 * left out of each sum, which is then an average over the good ones; the
 * template factor c[i] is the same average of the kernel profile, and the
 * element's weight shrinks with the weight it lost. */
static void marginal_of(const mp_frame *f, const mp_bkg *b, const mpf_kernel *k,
                        long px, long py, int axis, marginal *mg)
{
    long nx = f->im.nx, ny = f->im.ny;
    int nh = k->nh;
    double wfull = 0.0;
    for (int j = -nh; j <= nh; j++)
        wfull += nh + 1 - abs(j);
    mg->nh = nh;
    for (int i = -nh; i <= nh; i++) {
        double sw = 0.0, swd = 0.0, swg = 0.0;
        for (int j = -nh; j <= nh; j++) {
            long x = axis == 0 ? px + i : px + j;
            long y = axis == 0 ? py + j : py + i;
            if (x < 0 || x >= nx || y < 0 || y >= ny)
                continue;
            size_t q = (size_t)y * (size_t)nx + (size_t)x;
            if (mpf_bad(f, q))
                continue;
            double w = nh + 1 - abs(j);
            sw += w;
            swd += w * (f->im.pix[q] - mp_bkg_sky(b, q));
            swg += w * exp(-0.5 * j * j / (k->sigma * k->sigma));
        }
        int e = i + nh;
        if (sw > 0.0) {
            mg->m[e] = swd / sw;
            mg->c[e] = swg / sw;
            mg->u[e] = (nh + 1 - abs(i)) * sw / wfull;
        } else {
            mg->m[e] = mg->c[e] = mg->u[e] = 0.0;
        }
    }
}

/* Fit m ≈ sky + a·c·exp(−(i − d)²/2σ²) by weighted least squares:
 * (sky, a) linear at d = 0 first, then Gauss–Newton on all three (DAOFIND
 * takes a single step in d; iterating removes its bias for stars off the
 * pixel centre).  Nonzero when the height is not positive, the centre
 * leaves the box, or the fit is singular. */
static int fit_marginal(const marginal *mg, double sigma, double *d_out, double *a_out)
{
    int nh = mg->nh, npt = 0;
    double s2 = sigma * sigma;
    for (int e = 0; e <= 2 * nh; e++)
        npt += mg->u[e] > 0.0;
    if (npt < 3)
        return 1;
    /* Linear start. */
    double s00 = 0, s01 = 0, s11 = 0, r0 = 0, r1 = 0;
    for (int e = 0; e <= 2 * nh; e++) {
        double i = e - nh, u = mg->u[e];
        double t = mg->c[e] * exp(-0.5 * i * i / s2);
        s00 += u;
        s01 += u * t;
        s11 += u * t * t;
        r0 += u * mg->m[e];
        r1 += u * t * mg->m[e];
    }
    double det = s00 * s11 - s01 * s01;
    if (!(det > 1e-300 * (s00 * s11)))
        return 1;
    double sky = (r0 * s11 - r1 * s01) / det, a = (s00 * r1 - s01 * r0) / det, d = 0.0;
    if (!(a > 0.0))
        return 1;
    for (int it = 0; it < MAX_ITER; it++) {
        double A[3][3] = {{0}}, R[3] = {0}, x[3];
        for (int e = 0; e <= 2 * nh; e++) {
            double u = mg->u[e];
            if (u <= 0.0)
                continue;
            double i = e - nh;
            double t = mg->c[e] * exp(-0.5 * (i - d) * (i - d) / s2);
            double j[3] = {1.0, t, a * t * (i - d) / s2};
            double r = mg->m[e] - sky - a * t;
            for (int p = 0; p < 3; p++) {
                R[p] += u * r * j[p];
                for (int q = 0; q < 3; q++)
                    A[p][q] += u * j[p] * j[q];
            }
        }
        if (solve3(A, R, x))
            return 1;
        /* A step of more than half a pixel is outside the linear regime. */
        if (x[2] > 0.5)
            x[2] = 0.5;
        else if (x[2] < -0.5)
            x[2] = -0.5;
        sky += x[0];
        a += x[1];
        d += x[2];
        if (!(a > 0.0) || !(fabs(d) <= nh))
            return 1;
        if (fabs(x[2]) < 1e-6)
            break;
    }
    *d_out = d;
    *a_out = a;
    return 0;
}

/* The variance sums of SHARPNESS s = N/h, N = d₀ − (the m others'
 * mean), h = Σ w·d, each good tap's d of variance v = rms² + max(d, 0):
 * the map's noise at the peak and the star's own photons (electrons; the
 * map's rms holds the sky's, and a candidate's light is in no model yet).
 * v0, w0: the centre's; vo, wvo, wwvo: Σ v, Σ w·v, Σ w²·v over the
 * others. */
typedef struct {
    double v0, w0, vo, wvo, wwvo;
} sharp_var;

/* σ of s from its sums: var N = v₀ + Σv/m², var h = Σ w²v,
 * cov(N, h) = w₀v₀ − Σ w v/m, and by the delta method
 * var s = (var N − 2s·cov + s²·var h)/h². */
static double sharp_noise(const sharp_var *sv, int m, double s, double h)
{
    double vn = sv->v0 + sv->vo / ((double)m * m);
    double vh = sv->w0 * sv->w0 * sv->v0 + sv->wwvo;
    double cov = sv->w0 * sv->v0 - sv->wvo / m;
    return sqrt(fmax(vn - 2.0 * s * cov + s * s * vh, 0.0)) / h;
}

void mpf_measure(const mp_frame *f, const mp_bkg *b, const mpf_kernel *k,
                 long px, long py, double h, double *w, mpf_star *s)
{
    long nx = f->im.nx, ny = f->im.ny;
    memset(s, 0, sizeof *s);
    mpf_foot fp;
    mpf_footprint(f, k, px, py, &fp, w);
    s->flags = (fp.edge ? MP_FIND_EDGE : 0) | (fp.masked ? MP_FIND_MASKED : 0) |
               (fp.sat ? MP_FIND_SATURATED : 0);
    size_t ic = (size_t)py * (size_t)nx + (size_t)px;
    if (fp.denom <= 0.0 || !(h > 0.0) || mpf_bad(f, ic))
        return;

    /* DAOFIND's sharpness: the central pixel above the mean of the rest of
     * the footprint, in units of the fitted height. */
    double others = 0.0, rms = mp_bkg_rms(b, ic), r2 = rms * rms;
    int nothers = 0;
    sharp_var sv = {0};
    for (int t = 0; t < k->n; t++) {
        long x = px + k->dx[t], y = py + k->dy[t];
        if (k->dx[t] == 0 && k->dy[t] == 0)
            sv.w0 = w[t];
        if ((k->dx[t] == 0 && k->dy[t] == 0) || x < 0 || x >= nx || y < 0 || y >= ny)
            continue;
        size_t q = (size_t)y * (size_t)nx + (size_t)x;
        if (mpf_bad(f, q))
            continue;
        double d = f->im.pix[q] - mp_bkg_sky(b, q), v = r2 + mpf_nonneg(d);
        others += d;
        nothers++;
        sv.vo += v;
        sv.wvo += w[t] * v;
        sv.wwvo += w[t] * w[t] * v;
    }
    if (nothers == 0)
        return;
    double d0 = f->im.pix[ic] - mp_bkg_sky(b, ic);
    sv.v0 = r2 + mpf_nonneg(d0);
    s->sharp = (d0 - others / nothers) / h;
    s->sharp_sd = sharp_noise(&sv, nothers, s->sharp, h);

    marginal mg;
    double ddx, ddy, hx, hy;
    marginal_of(f, b, k, px, py, 0, &mg);
    if (fit_marginal(&mg, k->sigma, &ddx, &hx))
        return;
    marginal_of(f, b, k, px, py, 1, &mg);
    if (fit_marginal(&mg, k->sigma, &ddy, &hy))
        return;
    s->round = 2.0 * (hx - hy) / (hx + hy);
    s->x = (double)px + 1.0 + ddx;
    s->y = (double)py + 1.0 + ddy;

    /* h = F · (the kernel's response to a unit star at this offset). */
    double h1 = mpf_kernel_response(k, w, ddx, ddy);
    s->flux = h1 > 0.0 ? h / h1 : 0.0;

    double fmax = -HUGE_VAL;
    for (long y = py - 1; y <= py + 1; y++)
        for (long x = px - 1; x <= px + 1; x++) {
            if (x < 0 || x >= nx || y < 0 || y >= ny)
                continue;
            size_t q = (size_t)y * (size_t)nx + (size_t)x;
            if (!mpf_bad(f, q) && f->im.pix[q] - mp_bkg_sky(b, q) > fmax)
                fmax = f->im.pix[q] - mp_bkg_sky(b, q);
        }
    s->flux_max = fmax;
    long cx = lround(s->x) - 1, cy = lround(s->y) - 1;
    cx = cx < 0 ? 0 : cx >= nx ? nx - 1 : cx;
    cy = cy < 0 ? 0 : cy >= ny ? ny - 1 : cy;
    s->background = mp_bkg_sky(b, (size_t)cy * (size_t)nx + (size_t)cx);
    s->ok = isfinite(s->x) && isfinite(s->y) && isfinite(s->sharp) && isfinite(s->round) &&
            isfinite(s->flux);
}

void mpf_measure_plateau(const mp_frame *f, const mp_bkg *b, const mpf_kernel *k,
                         const long *idx, size_t n, mpf_star *s)
{
    long nx = f->im.nx, ny = f->im.ny;
    memset(s, 0, sizeof *s);
    double sx = 0.0, sy = 0.0, dmax = -HUGE_VAL;
    long x0 = nx, x1 = -1, y0 = ny, y1 = -1;
    int edge = 0;
    for (size_t i = 0; i < n; i++) {
        long x = idx[i] % nx, y = idx[i] / nx;
        sx += (double)x;
        sy += (double)y;
        x0 = x < x0 ? x : x0;
        x1 = x > x1 ? x : x1;
        y0 = y < y0 ? y : y0;
        y1 = y > y1 ? y : y1;
        double d = f->im.pix[idx[i]] - mp_bkg_sky(b, idx[i]);
        if (d > dmax)
            dmax = d;
        if (x < k->nh || y < k->nh || x >= nx - k->nh || y >= ny - k->nh)
            edge = 1;
    }
    s->x = sx / (double)n + 1.0;
    s->y = sy / (double)n + 1.0;
    long cx = lround(s->x) - 1, cy = lround(s->y) - 1;
    s->background = mp_bkg_sky(b, (size_t)cy * (size_t)nx + (size_t)cx);
    s->flux_max = dmax;
    /* A Gaussian of peak A clipped at level S is flat out to radius r_s
     * with A·exp(−r_s²/2σ²) = S; the plateau's area gives r_s² = n/π,
     * unless its narrower side is shorter: a bleed trail adds area along
     * a column, not radius (frame V: a 9e6 e- star with its trail was
     * offered at 4e18 e-, a start its fit did not always come back from).
     * σ includes the pixel's own width (σ² + 1/12).  Capped all the same:
     * the fit refines this. */
    double se2 = k->sigma * k->sigma + 1.0 / 12.0;
    double side = 0.5 * (double)((x1 - x0 < y1 - y0 ? x1 - x0 : y1 - y0) + 1);
    double r2 = (double)n / M_PI < side * side ? (double)n / M_PI : side * side;
    double e = r2 / (2.0 * se2);
    s->flux = dmax > 0.0 ? 2.0 * M_PI * se2 * dmax * exp(e < 30.0 ? e : 30.0) : 0.0;
    s->flags = MP_FIND_SATURATED | (edge ? MP_FIND_EDGE : 0);
    s->ok = 1;
}
