/* lm_model.c — a group fit's model on its fitted pixels, the weights
 * V(m) and the objective D (the quasi-likelihood deviance, levmar.c). */

#include <math.h>
#include <stddef.h>
#include "fit/lm_group.h"

void lm_model_of(group *G, const double *p, const rstar *r)
{
    size_t N = G->npix;
    if (G->nsky <= 1)
        for (size_t o = 0; o < N; o++)
            G->mod[o] = p[3 * G->n];
    else {
        G->skylo = INFINITY;
        G->skyhi = -INFINITY;
        for (size_t o = 0; o < N; o++) {
            double b = 0.0;
            for (int a = 0; a < G->nsky; a++)
                b += p[3 * G->n + a] * G->basis[(size_t)a * N + o];
            G->mod[o] = b;
            G->skylo = b < G->skylo ? b : G->skylo;
            G->skyhi = b > G->skyhi ? b : G->skyhi;
        }
    }
    for (int k = 0; k < G->n; k++) {
        const rstar *rk = &r[k];
        double E = p[3 * k];
        for (int t = 0; t < rk->j1 - rk->j0; t++) {
            const double *pr = rk->prf + rk->pb[t];
            double *mr = G->mod + rk->pp[t];
            for (int i = 0; i < rk->pn[t]; i++)
                mr[i] += E * pr[i];
        }
    }
}

/* Weights from the model: σ² = V(m) = max(m, S) + RON² (+ the error
 * plane's extra variance), RON² at least 1e-2 so a zero model and sky
 * with no read noise cannot give an infinite weight. */
void lm_variance_of(group *G)
{
    for (size_t i = 0; i < G->npix; i++)
        G->var[i] = (G->mod[i] > G->vfloor ? G->mod[i] : G->vfloor) + G->rv[i];
}

/* ∫_a^b (t − d)/V(t) dt for 0 ≤ a ≤ b, where V(t) = t + r. */
static double dev_positive(double a, double b, double d, double r)
{
    return (b - a) - (d + r) * log1p((b - a) / (a + r));
}

/* One pixel's deviance 2 ∫_d^m (t − d)/V(t) dt, V(t) = max(t, s) + r with
 * s ≥ 0: zero at m = d and growing on both sides, whatever the sign of d.
 * For m, d ≥ s it is the Poisson deviance of d + r about m + r, written
 * with log1p so it keeps its precision near m = d, where the fit ends;
 * below s, V is constant and the deviance a parabola. */
static double pixel_deviance(double m, double d, double s, double r)
{
    if (m >= s && d >= s) {
        double x = (m - d) / (d + r);
        return 2.0 * (d + r) * (x - log1p(x));
    }
    double lo = m < d ? m : d, hi = m < d ? d : m, sum = 0.0;
    if (lo < s) {
        double b = hi < s ? hi : s;
        sum += (b - lo) * (0.5 * (lo + b) - d) / (s + r);
    }
    if (hi > s)
        sum += dev_positive(lo > s ? lo : s, hi, d, r);
    return 2.0 * (m >= d ? sum : -sum);
}

/* The objective every step must lower (see the top of the file). */
double lm_deviance_of(const group *G)
{
    double D = 0.0;
    for (size_t o = 0; o < G->npix; o++)
        D += pixel_deviance(G->mod[o], G->dat[o], G->vfloor, G->rv[o]);
    return D;
}

double lm_chi2_with(const group *G, const double *var)
{
    double c = 0.0;
    for (size_t o = 0; o < G->npix; o++) {
        double r = G->dat[o] - G->mod[o];
        c += r * r / var[o];
    }
    return c;
}
