/* sinc_choice.c — interpolation effort matched to the star (issue 5): the
 * shortest damped-sinc half-width whose error stays far below the star's
 * photon noise.
 *
 * Why a bound in one number: a model error r_i = E·δP_i (δP the rendered
 * PRF with half-width h minus that with the user's sinchw) moves the
 * weighted least-squares solution θ = (E, X, Y, B) by Δθ = F⁻¹ Gᵀ W r
 * (linearised, G the model gradient, W = diag 1/(m_i + RON²), F = Gᵀ W G the
 * Fisher matrix).  By Cauchy–Schwarz in the W inner product, for every
 * parameter j
 *     |Δθ_j| ≤ sqrt((F⁻¹)_jj) · ‖r‖_W = σ_j · E · sqrt(Σ_i δP_i² / (E P_i + B + RON²)),
 * σ_j the parameter's Cramér–Rao σ (paper §2: what the fit achieves).  So
 * q(h) = E·‖δP_h‖_W ≤ frac bounds the bias of flux and position at once to
 * frac of their photon-noise σ.  q grows with E (as E for faint stars, as
 * √E for bright ones), which is paper §5.4's observation that aliasing only
 * matters for bright stars.
 *
 * δP is measured once per PSF: the PRF rendered at a grid of subpixel
 * phases with every half-width 0..sinchw; the worst phase counts. */
#include <math.h>
#include <stdlib.h>
#include <string.h>
#include "fit/fit.h"

/* Phases per axis: star positions k/MP_SINC_NPH px off a pixel centre. */
#define NPH_AXIS 4

void mp_sinc_choice_free(mp_sinc_choice *c)
{
    if (!c)
        return;
    free(c->p);
    free(c->d2);
    memset(c, 0, sizeof *c);
}

int mp_sinc_choice_build(const mp_prf_model *m, mp_sinc_choice *c, char *err)
{
    memset(c, 0, sizeof *c);
    int hmax = m->sinc_hw < 0 ? 0 : (m->sinc_hw > 64 ? 64 : m->sinc_hw);
    c->hwmax = hmax;
    if (m->psf->kind != MP_PSF_TABLE || hmax == 0)
        return 0;                           /* nothing to shorten */
    long x0, y0;
    int w, h;
    mp_prf_box(m, 1000.0, 1000.0, &x0, &y0, &w, &h);
    /* The box's size can grow by one pixel with the phase. */
    c->npix = (size_t)(w + 1) * (size_t)(h + 1);
    c->nph = NPH_AXIS * NPH_AXIS;
    size_t per = c->npix * (size_t)c->nph;
    c->p = calloc(per, sizeof *c->p);
    c->d2 = calloc(per * (size_t)hmax, sizeof *c->d2);
    double *full = malloc(c->npix * sizeof *full), *cur = malloc(c->npix * sizeof *cur);
    mp_prf_work wk = {0};
    int rc = 1;
    if (!c->p || !c->d2 || !full || !cur) {
        snprintf(err, MP_ERRLEN, "out of memory for the kernel-length table");
        goto done;
    }
    for (int ph = 0; ph < c->nph; ph++) {
        double x = 1000.0 + (double)(ph % NPH_AXIS) / NPH_AXIS;
        double y = 1000.0 + (double)(ph / NPH_AXIS) / NPH_AXIS;
        long bx, by;
        int bw, bh;
        mp_prf_box(m, x, y, &bx, &by, &bw, &bh);
        if ((size_t)bw * (size_t)bh > c->npix) {
            snprintf(err, MP_ERRLEN, "kernel-length table: PRF box %dx%d larger than expected", bw, bh);
            goto done;
        }
        if (mp_prf_render(m, x, y, full, NULL, NULL, &wk)) {
            snprintf(err, MP_ERRLEN, "out of memory rendering the PRF");
            goto done;
        }
        size_t nb = (size_t)bw * (size_t)bh;
        memcpy(c->p + (size_t)ph * c->npix, full, nb * sizeof *full);
        mp_prf_model mh = *m;
        for (int hw = 0; hw < hmax; hw++) {
            mh.sinc_hw = hw;
            if (mp_prf_render(&mh, x, y, cur, NULL, NULL, &wk)) {
                snprintf(err, MP_ERRLEN, "out of memory rendering the PRF");
                goto done;
            }
            double *d = c->d2 + ((size_t)hw * c->nph + (size_t)ph) * c->npix;
            for (size_t i = 0; i < nb; i++)
                d[i] = (cur[i] - full[i]) * (cur[i] - full[i]);
        }
    }
    rc = 0;
done:
    free(full);
    free(cur);
    mp_prf_work_free(&wk);
    if (rc)
        mp_sinc_choice_free(c);
    return rc;
}

double mp_sinc_choice_bound(const mp_sinc_choice *c, int hw, double E, double B, double ron)
{
    if (hw >= c->hwmax || !c->d2)
        return 0.0;
    if (hw < 0)
        hw = 0;
    double worst = 0.0, var0 = B + ron * ron;
    for (int ph = 0; ph < c->nph; ph++) {
        const double *d = c->d2 + ((size_t)hw * c->nph + (size_t)ph) * c->npix;
        const double *p = c->p + (size_t)ph * c->npix;
        double s = 0.0;
        for (size_t i = 0; i < c->npix; i++) {
            double v = E * p[i] + var0;
            if (v > 0)
                s += d[i] / v;
        }
        worst = s > worst ? s : worst;
    }
    return E * sqrt(worst);
}

/* q_h(E) increases with E (each term E²δP²/(E P + v) does), so every
 * half-width has a largest flux it serves, found by bisection in log E. */
int mp_sinc_choice_limits(const mp_sinc_choice *c, double B, double ron, double frac,
                          double *emax)
{
    /* The half-widths in parallel, each its own bisection (the frame
     * fit's serial set-up, bench/SCALING.md). */
#pragma omp parallel for schedule(dynamic)
    for (int hw = 0; hw < c->hwmax; hw++) {
        double lo = 1e-3, hi = 1e15;
        if (mp_sinc_choice_bound(c, hw, lo, B, ron) > frac) {
            emax[hw] = 0.0;
            continue;
        }
        if (mp_sinc_choice_bound(c, hw, hi, B, ron) <= frac) {
            emax[hw] = INFINITY;
            continue;
        }
        for (int it = 0; it < MP_SINC_LIMITS_EVALS - 2; it++) {   /* 18 decades: E to 0.25 % */
            double mid = sqrt(lo * hi);
            if (mp_sinc_choice_bound(c, hw, mid, B, ron) <= frac)
                lo = mid;
            else
                hi = mid;
        }
        emax[hw] = lo;
    }
    return c->hwmax;
}

int mp_sinc_choice_pick(const double *emax, int hwmax, double E)
{
    if (!(E > 0))
        return hwmax;
    for (int hw = 0; hw < hwmax; hw++)
        if (E <= emax[hw])
            return hw;
    return hwmax;
}

int mp_sinc_choice_hw(const mp_sinc_choice *c, double E, double B, double ron, double frac)
{
    if (!c->d2 || !(E > 0))
        return c->hwmax;
    for (int hw = 0; hw < c->hwmax; hw++)
        if (mp_sinc_choice_bound(c, hw, E, B, ron) <= frac)
            return hw;
    return c->hwmax;
}
