/* spline.c — the natural cubic spline used to interpolate the background
 * meshes to every pixel (SExtractor back.c makebackspline()/backline()
 * interpolate the same way; we continue linearly past the end nodes). */
#include "find/find_priv.h"

void mpf_spline_init(const double *x, const double *y, int n, double *d2, double *work)
{
    for (int i = 0; i < n; i++)
        d2[i] = 0.0;
    if (n < 3)
        return;
    /* Tridiagonal solve for the interior second derivatives, with
     * d2[0] = d2[n-1] = 0 (natural ends); work holds the eliminated
     * super-diagonal. */
    work[0] = 0.0;
    for (int i = 1; i < n - 1; i++) {
        double sig = (x[i] - x[i - 1]) / (x[i + 1] - x[i - 1]);
        double p = sig * d2[i - 1] + 2.0;
        d2[i] = (sig - 1.0) / p;
        double r = (y[i + 1] - y[i]) / (x[i + 1] - x[i]) - (y[i] - y[i - 1]) / (x[i] - x[i - 1]);
        work[i] = (6.0 * r / (x[i + 1] - x[i - 1]) - sig * work[i - 1]) / p;
    }
    d2[n - 1] = 0.0;
    for (int i = n - 2; i >= 1; i--)
        d2[i] = d2[i] * d2[i + 1] + work[i];
}

double mpf_spline_eval(const double *x, const double *y, const double *d2, int n,
                       double t, int *k)
{
    if (n == 1)
        return y[0];
    if (t <= x[0]) {
        double h = x[1] - x[0];
        double slope = (y[1] - y[0]) / h - h * (2.0 * d2[0] + d2[1]) / 6.0;
        return y[0] + slope * (t - x[0]);
    }
    if (t >= x[n - 1]) {
        double h = x[n - 1] - x[n - 2];
        double slope = (y[n - 1] - y[n - 2]) / h + h * (d2[n - 2] + 2.0 * d2[n - 1]) / 6.0;
        return y[n - 1] + slope * (t - x[n - 1]);
    }
    int i = (*k >= 0 && *k < n - 1 && x[*k] <= t) ? *k : 0;
    while (i < n - 2 && x[i + 1] < t)
        i++;
    *k = i;
    double h = x[i + 1] - x[i];
    double a = (x[i + 1] - t) / h, bb = (t - x[i]) / h;
    return a * y[i] + bb * y[i + 1] +
           ((a * a * a - a) * d2[i] + (bb * bb * bb - bb) * d2[i + 1]) * h * h / 6.0;
}

/* One value of the spline at t (c[0] < t < c[n-1], n >= 2) as
 * mpf_spline_row forms it, on interval i (c[i] <= t < c[i+1]). */
static double interval_value(const double *x, const double *y, const double *d2, int i, double t)
{
    double h = x[i + 1] - x[i], c = h * h / 6.0;
    double a = (x[i + 1] - t) / h, b = 1.0 - a;
    return a * y[i] + b * y[i + 1] + ((a * a * a - a) * d2[i] + (b * b * b - b) * d2[i + 1]) * c;
}

static float to_map(double v, int clamp0)
{
    return (float)(clamp0 && v < 0.0 ? 0.0 : v);
}

void mpf_spline_row(const double *x, const double *y, const double *d2, int n,
                    float *out, long count, int clamp0)
{
    long t = 0;
    if (n == 1) {
        for (; t < count; t++)
            out[t] = to_map(y[0], clamp0);
        return;
    }
    int k = 0;
    /* Left of the first node, then interval by interval, then right of
     * the last: the same values as mpf_spline_eval, without its search. */
    for (; t < count && (double)t <= x[0]; t++)
        out[t] = to_map(mpf_spline_eval(x, y, d2, n, (double)t, &k), clamp0);
    for (int i = 0; i < n - 1 && t < count; i++)
        for (; t < count && (double)t < x[i + 1]; t++)
            out[t] = to_map(interval_value(x, y, d2, i, (double)t), clamp0);
    for (; t < count; t++)
        out[t] = to_map(mpf_spline_eval(x, y, d2, n, (double)t, &k), clamp0);
}

float mpf_spline_at(const double *x, const double *y, const double *d2, int n, long t,
                    int clamp0)
{
    double v = (double)t;
    if (n == 1)
        return to_map(y[0], clamp0);
    if (v <= x[0] || v >= x[n - 1]) {
        int k = 0;
        return to_map(mpf_spline_eval(x, y, d2, n, v, &k), clamp0);
    }
    /* The nodes are nearly evenly spaced (equal meshes ±1 px): guess the
     * interval, then step to it. */
    int i = (int)((v - x[0]) / (x[n - 1] - x[0]) * (n - 1));
    i = i < 0 ? 0 : i > n - 2 ? n - 2 : i;
    while (i > 0 && x[i] > v)
        i--;
    while (i < n - 2 && x[i + 1] <= v)
        i++;
    return to_map(interval_value(x, y, d2, i, v), clamp0);
}
