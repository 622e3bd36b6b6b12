/* kernel.c — DAOFIND's lowered, truncated Gaussian kernel (Stetson 1987;
 * IRAF daofind, findpars.nsigma; anchors.md §1.3), the same Gaussian not
 * lowered where the sky is known, and its footprint on a frame with
 * masked pixels. */
#include <math.h>
#include <stdio.h>
#include <stdlib.h>

#include "find/find_priv.h"

#define FWHM_PER_SIGMA 2.3548200450309493   /* 2 sqrt(2 ln 2) */

int mpf_kernel_make(double fwhm, double nsigma, int known, mpf_kernel *k, char *err)
{
    *k = (mpf_kernel){0};
    k->known = known != 0;
    if (!(fwhm > 0.0) || !isfinite(fwhm)) {
        snprintf(err, MP_ERRLEN, "fwhm: %g must be a positive number of pixels", fwhm);
        return 1;
    }
    if (!(nsigma > 0.0) || !isfinite(nsigma)) {
        snprintf(err, MP_ERRLEN, "nsigma: %g must be a positive number", nsigma);
        return 1;
    }
    k->sigma = fwhm / FWHM_PER_SIGMA;
    /* DAOPHOT: the kernel reaches nsigma·σ, but never less than 2 pixels,
     * so that even a sharp star has a ring of neighbours to be lowered by. */
    k->radius = fmax(2.0, nsigma * k->sigma);
    if (k->radius > MPF_MAX_HALF) {
        snprintf(err, MP_ERRLEN, "fwhm: %g with nsigma %g gives a kernel radius of %.0f "
                 "pixels (at most %d)", fwhm, nsigma, k->radius, MPF_MAX_HALF);
        return 1;
    }
    k->nh = (int)floor(k->radius);
    int side = 2 * k->nh + 1;
    size_t cap = (size_t)side * (size_t)side;
    k->dx = malloc(cap * sizeof *k->dx);
    k->dy = malloc(cap * sizeof *k->dy);
    k->g = malloc(cap * sizeof *k->g);
    k->kl = malloc(cap * sizeof *k->kl);
    if (!k->dx || !k->dy || !k->g || !k->kl) {
        mpf_kernel_free(k);
        snprintf(err, MP_ERRLEN, "out of memory for the detection kernel");
        return 1;
    }
    double r2max = k->radius * k->radius * (1.0 + 1e-12);
    double sg = 0.0, sgg = 0.0;
    for (int j = -k->nh; j <= k->nh; j++)
        for (int i = -k->nh; i <= k->nh; i++) {
            double r2 = (double)(i * i + j * j);
            if (r2 > r2max)
                continue;
            double g = exp(-0.5 * r2 / (k->sigma * k->sigma));
            k->dx[k->n] = i;
            k->dy[k->n] = j;
            k->g[k->n] = g;
            sg += g;
            sgg += g * g;
            k->n++;
        }
    /* Lowered, h is a Gaussian's amplitude with a constant fitted beside
     * it (DAOFIND: the sky unknown); known, without one.  The constant
     * costs h's S/N a factor sqrt(Σg² / Σ(g − ḡ)²): 1.9 at FWHM 2.3, 2.8
     * at FWHM 3 (13 taps). */
    k->gbar = k->known ? 0.0 : sg / k->n;
    k->denom = k->known ? sgg : sgg - sg * sg / k->n;
    for (int t = 0; t < k->n; t++)
        k->kl[t] = (k->g[t] - k->gbar) / k->denom;
    k->klsum = 0.0;
    for (int t = 0; t < k->n; t++)
        k->klsum += fabs(k->kl[t]);
    k->relerr = 1.0 / sqrt(k->denom);
    k->nmin = (k->n + 1) / 2;
    return 0;
}

void mpf_kernel_free(mpf_kernel *k)
{
    free(k->dx);
    free(k->dy);
    free(k->g);
    free(k->kl);
    *k = (mpf_kernel){0};
}

/* Fraction of a unit-flux Gaussian (σ, centred at o) falling in the pixel
 * centred at i. */
static double pixel_frac(double i, double o, double sigma)
{
    double s = M_SQRT2 * sigma;
    return 0.5 * (erf((i + 0.5 - o) / s) - erf((i - 0.5 - o) / s));
}

double mpf_kernel_response(const mpf_kernel *k, const double *w, double ox, double oy)
{
    double sum = 0.0;
    for (int t = 0; t < k->n; t++)
        if (w[t] != 0.0)
            sum += w[t] * pixel_frac(k->dx[t], ox, k->sigma) * pixel_frac(k->dy[t], oy, k->sigma);
    return sum;
}

void mpf_footprint(const mp_frame *f, const mpf_kernel *k, long px, long py,
                   mpf_foot *fp, double *w)
{
    long nx = f->im.nx, ny = f->im.ny;
    *fp = (mpf_foot){0};
    double sg = 0.0, sgg = 0.0;
    for (int t = 0; t < k->n; t++) {
        long x = px + k->dx[t], y = py + k->dy[t];
        if (w)
            w[t] = 0.0;
        if (x < 0 || x >= nx || y < 0 || y >= ny) {
            fp->edge = 1;
            continue;
        }
        size_t i = (size_t)y * (size_t)nx + (size_t)x;
        if (mpf_bad(f, i)) {
            fp->masked = 1;
            continue;
        }
        if (mpf_sat(f, i))
            fp->sat = 1;
        fp->ngood++;
        sg += k->g[t];
        sgg += k->g[t] * k->g[t];
    }
    if (fp->ngood < 2)
        return;
    fp->gbar = k->known ? 0.0 : sg / fp->ngood;
    fp->denom = k->known ? sgg : sgg - sg * sg / fp->ngood;
    /* Rounding can leave a tiny positive denom for a degenerate set (all
     * good taps at one radius): treat anything that small as none. */
    if (!(fp->denom > 1e-12 * k->denom)) {
        fp->denom = 0.0;
        return;
    }
    if (!w)
        return;
    for (int t = 0; t < k->n; t++) {
        long x = px + k->dx[t], y = py + k->dy[t];
        if (x < 0 || x >= nx || y < 0 || y >= ny)
            continue;
        if (mpf_bad(f, (size_t)y * (size_t)nx + (size_t)x))
            continue;
        w[t] = (k->g[t] - fp->gbar) / fp->denom;
    }
}
