/* denoise.c — the table smoothed only as much as its noise needs
 * (build.h): a Wiener filter in spatial frequency, W(k) = S(k)/(S(k)+N(k)),
 * with N(k) the radially averaged power of a draw of the table's own
 * error (half the difference of two half-star builds) and S = P − N from
 * the table's own power P.  W is made non-increasing outward so that noise
 * beyond the PSF's band is never kept.  It is stored per cycles/pixel so
 * that a table of another sampling takes the same filter. */
#include <complex.h>
#include <fftw3.h>      /* after complex.h: fftw_complex is double complex */
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include "psf/build_priv.h"

/* In-place 2-D DFT of a (ny × nx, row-major), sign −1 forward, +1 back
 * (unnormalised), by FFTW: O(n² log n) where the separable sums were
 * O(n³), 5 % of frame S's run with its PSF built (its ×4 table 241
 * elements a side, a prime).  FFTW's planner is not thread-safe, so plans
 * are made and destroyed one at a time; FFTW_ESTIMATE times nothing and
 * a is from fftw_malloc (aligned as the plan assumes), so a plan and its
 * sums are the same on every run and thread.  Nonzero when FFTW cannot
 * plan it (out of memory). */
static int dft2(double complex *a, int nx, int ny, int sign)
{
    fftw_plan p;
#pragma omp critical(mp_fftw_planner)
    p = fftw_plan_dft_2d(ny, nx, a, a, sign < 0 ? FFTW_FORWARD : FFTW_BACKWARD, FFTW_ESTIMATE);
    if (!p)
        return 1;
    fftw_execute(p);
#pragma omp critical(mp_fftw_planner)
    fftw_destroy_plan(p);
    return 0;
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
    double complex *T = fftw_malloc(nel * sizeof *T), *N = fftw_malloc(nel * sizeof *N);
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
    fftw_free(T);
    fftw_free(N);
    free(pt);
    free(pn);
    free(cnt);
    return rc;
}

int mp_epsf_wiener_apply(mp_epsf *e, const double *w, int nbin)
{
    int nx = e->nx, ny = e->ny;
    size_t nel = (size_t)nx * ny;
    double complex *T = fftw_malloc(nel * sizeof *T);
    if (!T)
        return 1;
    for (int t = 0; t < e->nterms; t++) {
        double *p = e->planes + (size_t)t * nel;
        for (size_t i = 0; i < nel; i++)
            T[i] = p[i];
        if (dft2(T, nx, ny, -1)) {
            fftw_free(T);
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
            fftw_free(T);
            return 1;
        }
        for (size_t i = 0; i < nel; i++)
            p[i] = creal(T[i]) / (double)nel;
    }
    fftw_free(T);
    return 0;
}
