/* denoise.c — the table smoothed only as much as its noise needs
 * (build.h): a Wiener filter in spatial frequency, W(k) = S(k)/(S(k)+N(k)),
 * with N(k) the radially averaged power of a draw of the table's own
 * error (half the difference of two half-star builds) and S = P − N from
 * the table's own power P.  W is made non-increasing outward so that noise
 * beyond the PSF's band is never kept.  It is stored per cycles/pixel so
 * that a table of another sampling takes the same filter. */
#include <complex.h>
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include "psf/build_priv.h"

/* In-place 2-D DFT of a (ny × nx, row-major), sign −1 forward, +1 back
 * (unnormalised): separable 1-D DFTs, O(n³) — tables are ≤ ~200 wide.
 * The rows (then the columns) in parallel, each into its own buffer: 1 %
 * of 47 Tuc built ran here on one thread (bench/SCALING.md); every value
 * is summed in the same order on any threads. */
static int dft2(double complex *a, int nx, int ny, int sign)
{
    int n = nx > ny ? nx : ny, failed = 0;
    double complex *tw = malloc((size_t)n * sizeof *tw);
    if (!tw)
        return 1;
    for (int pass = 0; pass < 2 && !failed; pass++) {
        int len = pass ? ny : nx, cnt = pass ? nx : ny;
        for (int k = 0; k < len; k++)
            tw[k] = cexp(sign * 2.0 * M_PI * I * k / len);
#pragma omp parallel reduction(| : failed)
        {
            double complex *row = malloc((size_t)n * sizeof *row);
            failed = !row;
#pragma omp for schedule(static)
            for (int c = 0; c < cnt; c++) {
                if (!row)
                    continue;
                for (int k = 0; k < len; k++) {
                    double sr = 0.0, si = 0.0;
                    /* the twiddle's index j·k mod len, stepped by k (no
                     * division a term: it was most of the transform);
                     * each product as C's complex one forms it for finite
                     * values (re = ac − bd, im = ad + bc), without its
                     * test for an infinite part a term */
                    for (int j = 0, t = 0; j < len; j++) {
                        double complex v = pass ? a[(size_t)j * nx + c] : a[(size_t)c * nx + j];
                        double vr = creal(v), vi = cimag(v), tr = creal(tw[t]), ti = cimag(tw[t]);
                        sr += vr * tr - vi * ti;
                        si += vr * ti + vi * tr;
                        t += k;
                        t -= t >= len ? len : 0;
                    }
                    double *rk = (double *)&row[k];  /* C11 6.2.5: re, im */
                    rk[0] = sr;
                    rk[1] = si;
                }
                for (int k = 0; k < len; k++) {
                    if (pass)
                        a[(size_t)k * nx + c] = row[k];
                    else
                        a[(size_t)c * nx + k] = row[k];
                }
            }
            free(row);
        }
    }
    free(tw);
    return failed;
}

/* Frequency of DFT index k of n, cycles per element. */
static double freq(int k, int n)
{
    return (k <= n / 2 ? k : k - n) / (double)n;
}

int mp_epsf_wiener_measure(const mp_epsf *e, const mp_epsf *noise, double *w, int nbin)
{
    int nx = e->nx, ny = e->ny;
    size_t nel = (size_t)nx * ny;
    double complex *T = malloc(nel * sizeof *T), *N = malloc(nel * sizeof *N);
    double *pt = calloc((size_t)nbin, sizeof *pt), *pn = calloc((size_t)nbin, sizeof *pn);
    long *cnt = calloc((size_t)nbin, sizeof *cnt);
    int rc = 1;
    if (!T || !N || !pt || !pn || !cnt)
        goto done;
    for (size_t i = 0; i < nel; i++) {
        T[i] = e->planes[i];
        N[i] = noise->planes[i];
    }
    if (dft2(T, nx, ny, -1) || dft2(N, nx, ny, -1))
        goto done;
    /* Bins of MP_EPSF_WBIN cycles per detector pixel. */
    for (int j = 0; j < ny; j++)
        for (int i = 0; i < nx; i++) {
            double f = hypot(freq(i, nx), freq(j, ny)) * e->os;
            int b = (int)(f / MP_EPSF_WBIN);
            if (b >= nbin)
                continue;
            size_t o = (size_t)j * nx + i;
            pt[b] += creal(T[o] * conj(T[o]));
            pn[b] += creal(N[o] * conj(N[o]));
            cnt[b]++;
        }
    double last = 1.0;
    for (int b = 0; b < nbin; b++) {
        double v = last;
        if (cnt[b] > 0 && pt[b] > 0)
            v = fmax(0.0, 1.0 - pn[b] / pt[b]);
        else if (cnt[b] == 0)
            v = 0.0;       /* beyond the table's own Nyquist */
        last = fmin(last, v);
        w[b] = last;
    }
    rc = 0;
done:
    free(T);
    free(N);
    free(pt);
    free(pn);
    free(cnt);
    return rc;
}

int mp_epsf_wiener_apply(mp_epsf *e, const double *w, int nbin)
{
    int nx = e->nx, ny = e->ny;
    size_t nel = (size_t)nx * ny;
    double complex *T = malloc(nel * sizeof *T);
    if (!T)
        return 1;
    for (int t = 0; t < e->nterms; t++) {
        double *p = e->planes + (size_t)t * nel;
        for (size_t i = 0; i < nel; i++)
            T[i] = p[i];
        if (dft2(T, nx, ny, -1)) {
            free(T);
            return 1;
        }
        for (int j = 0; j < ny; j++)
            for (int i = 0; i < nx; i++) {
                double f = hypot(freq(i, nx), freq(j, ny)) * e->os / MP_EPSF_WBIN;
                int b = (int)f;
                /* linear between bin centres */
                double x = f - 0.5, wv;
                int b0 = (int)floor(x);
                if (b >= nbin)
                    wv = 0.0;
                else if (b0 < 0)
                    wv = w[0];
                else if (b0 + 1 >= nbin)
                    wv = w[nbin - 1];
                else
                    wv = w[b0] + (x - b0) * (w[b0 + 1] - w[b0]);
                T[(size_t)j * nx + i] *= wv;
            }
        if (dft2(T, nx, ny, +1)) {
            free(T);
            return 1;
        }
        for (size_t i = 0; i < nel; i++)
            p[i] = creal(T[i]) / (double)nel;
    }
    free(T);
    return 0;
}
