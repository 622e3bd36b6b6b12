/* resample.c — a PSF plane moved to another sampling step by separable
 * Lanczos-3 interpolation (what PSFEx itself resamples with). */
#include <math.h>
#include "psf/psf_priv.h"

double psf_lanczos3(double x)
{
    double a = fabs(x);
    if (a < 1e-12)
        return 1.0;
    if (a >= 3.0)
        return 0.0;
    double px = M_PI * x;
    return 3.0 * sin(px) * sin(px / 3.0) / (px * px);
}

/* out[k] (k < m) = Σ_i in[i·stride]·L3(u_k − i), u_k the source index of
 * target element k. */
static void pass(const double *in, long stride, int n, double s, double *out, long ostride,
                 int m, double t)
{
    int c = n / 2, cm = m / 2;     /* PSFEx's centre: element n/2 (odd n: the middle) */
    for (int k = 0; k < m; k++) {
        double u = c + (k - cm) * t / s;
        int i0 = (int)floor(u) - 2, i1 = (int)floor(u) + 3;
        double v = 0.0;
        for (int i = i0 < 0 ? 0 : i0; i <= i1 && i < n; i++)
            v += in[i * stride] * psf_lanczos3(u - i);
        out[k * ostride] = v;
    }
}

void psf_resample(const double *src, int nx, int ny, double s, double *dst, int mx, int my,
                  double t, double *tmp)
{
    /* y first: tmp is my rows of nx, then x along each row. */
    for (int i = 0; i < nx; i++)
        pass(src + i, nx, ny, s, tmp + i, nx, my, t);
    double scale = (t / s) * (t / s);
    for (int j = 0; j < my; j++) {
        pass(tmp + (long)j * nx, 1, nx, s, dst + (long)j * mx, 1, mx, t);
        for (int k = 0; k < mx; k++)
            dst[(long)j * mx + k] *= scale;
    }
}
