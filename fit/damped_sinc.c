/* damped_sinc.c — moving a discrete PSF: the damped-sinc interpolant of
 * paper §3.1 (eq. dampedsinc), applied separably. */
#include <float.h>
#include <math.h>
#include "fit/fit.h"

/* A shift on the table's grid: for |δ| ≤ ε/2 (ε = DBL_EPSILON) the weights
 * are the identity's to double precision — w_0 = 1 − (π²/6 + 1/3.25²)δ²
 * rounds to 1 and |w_k| ≤ |δ|/|k| ≤ ε/2 for k ≠ 0 — so skipping the pass
 * changes an output element by at most |δ|·Σ_{k≠0}|f_{i+k}|/|k| ≤
 * 2·H(hw)·(ε/2)·max|f| (H the harmonic number: ≤ 6.5e-16·max|f| for
 * hw = 10).  Issue 5's "shift skipped when it falls on the table's grid". */
int mp_shift_on_grid(double delta)
{
    return fabs(delta) <= 0.5 * DBL_EPSILON;
}

double mp_damped_sinc(double d)
{
    if (fabs(d) < 1e-12)
        return 1.0;
    double pd = M_PI * d;
    double e = d / 3.25;
    return sin(pd) / pd * exp(-e * e);
}

/* Weights w[k+hw] = ds(k − shift) for taps k = −hw..hw, so that
 * f(i + shift) ≈ Σ_k f(i + k) w[k+hw].  The paper's form is used as is, not
 * renormalised: its small departure from unit sum is part of what §5.3's
 * 1× experiment shows. */
static void sinc_weights(double shift, int hw, double *w)
{
    for (int k = -hw; k <= hw; k++)
        w[k + hw] = mp_damped_sinc((double)k - shift);
}

/* One pass along rows (stride 1) or columns (stride nx). */
static void shift_pass(const double *in, int nx, int ny, int along_y,
                       const double *w, int hw, double *out)
{
    int n = along_y ? ny : nx;        /* length along the shift axis */
    int m = along_y ? nx : ny;        /* number of lines */
    long step = along_y ? nx : 1;     /* stride along the axis */
    long lstep = along_y ? 1 : nx;    /* stride between lines */
    for (int l = 0; l < m; l++) {
        const double *src = in + l * lstep;
        double *dst = out + l * lstep;
        for (int i = 0; i < n; i++) {
            int k0 = i - hw < 0 ? -i : -hw;
            int k1 = i + hw > n - 1 ? n - 1 - i : hw;
            double s = 0.0;
            for (int k = k0; k <= k1; k++)
                s += src[(i + k) * step] * w[k + hw];
            dst[i * step] = s;
        }
    }
}

void mp_shift_table(const double *in, int nx, int ny, double dx, double dy,
                    int hw, double *out, double *tmp)
{
    double w[2 * 64 + 1];
    if (hw > 64)
        hw = 64;
    size_t n = (size_t)nx * (size_t)ny;
    const double *src = in;
    /* A shift on the grid is the identity (ds(k) = δ_k0): skip the pass. */
    if (!mp_shift_on_grid(dx) && hw > 0) {
        sinc_weights(dx, hw, w);
        shift_pass(src, nx, ny, 0, w, hw, tmp);
        src = tmp;
    }
    if (!mp_shift_on_grid(dy) && hw > 0) {
        sinc_weights(dy, hw, w);
        shift_pass(src, nx, ny, 1, w, hw, out);
    } else if (src != out) {
        for (size_t i = 0; i < n; i++)
            out[i] = src[i];
    }
}

void mp_five_point(const double *in, int nx, int ny, int axis, double *out)
{
    /* Paper §3.2, eq. (five-point): f'(i) ≈ [f(i−2) − 8f(i−1) + 8f(i+1) − f(i+2)]/12,
     * with the table taken as zero beyond its edge. */
    int n = axis ? ny : nx;
    int m = axis ? nx : ny;
    long step = axis ? nx : 1;
    long lstep = axis ? 1 : nx;
    for (int l = 0; l < m; l++) {
        const double *f = in + l * lstep;
        double *d = out + l * lstep;
        for (int i = 0; i < n; i++) {
            double fm2 = i >= 2 ? f[(i - 2) * step] : 0.0;
            double fm1 = i >= 1 ? f[(i - 1) * step] : 0.0;
            double fp1 = i + 1 < n ? f[(i + 1) * step] : 0.0;
            double fp2 = i + 2 < n ? f[(i + 2) * step] : 0.0;
            d[i * step] = (fm2 - 8.0 * fm1 + 8.0 * fp1 - fp2) / 12.0;
        }
    }
}
