/* ss_choice.c — supersampling matched to the star (issue 10): a coarser
 * block-sum of the PSF table wherever the fit with it is provably as good
 * as with the table as given, the table as given elsewhere.
 *
 * Paper §5.4's rule (a 1× table is on the Cramér–Rao bound from β = 21 px²
 * on) was derived for Gaussians; a diffraction-limited PSF holds power up
 * to its cutoff 1/(λ/D) cycles/px whatever its β, and a coarse table of it
 * aliases.  So the error is measured on THIS PSF: δP = PRF(coarse table) −
 * PRF(given table), both shifted with the model's full sinc kernel, at a
 * 4×4 grid of subpixel phases, with P, ∂P/∂x, ∂P/∂y of the given table.
 *
 * What the error does to one star of flux E on sky B (linearised, as
 * fit/sinc_choice.c): the weighted least-squares solution of
 * θ = (E, X, Y, sky) moves by b = F⁻¹JᵀW(E δP), J = [P, E ∂P/∂x, E ∂P/∂y, 1],
 * W = diag 1/(E P + B + RON²), F = JᵀWJ; its bias in σ units is
 * |b_k|/sqrt((F⁻¹)_kk).  The part of E δP the fit cannot absorb (its
 * W-residual after that projection) raises χ² by
 *     λ = E² Σ W δP_⊥².
 * A level serves E when, at the worst phase, every |b_k|/σ_k ≤ frac and
 * λ ≤ MP_SS_CHI2MAX = 1: one unit of χ², against its spread sqrt(2·dof)
 * ≥ 12 even for a fitting window of radius 5 px (≈ 78 px, dof ≈ 74), so
 * no test of the fit's quality could tell the coarse table's residual.
 * Cauchy–Schwarz bounds every |b_k|/σ_k by E‖δP‖_W (the old criterion),
 * but that counts error in the directions the fit does not move along: for
 * a Gaussian FWHM 3 ×2 → ×1 most of δP is a symmetric width change the
 * flux and sky absorb, so the bias itself is far below the bound. */
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include "fit/fit.h"

#define NPH_AXIS 4
#define NPAR 4

void mp_ss_level_free(mp_ss_level *lv)
{
    if (!lv)
        return;
    mp_psf_free(&lv->psf);
    mp_psf_field_free(&lv->field);
    free(lv->bias.p);
    mp_sinc_choice_free(&lv->sinc);
    mp_prf_cache_free(lv->grid);
    free(lv->grid);
    memset(lv, 0, sizeof *lv);
}

/* The union of the two models' boxes for a star at (x, y). */
static void union_box(const mp_prf_model *a, const mp_prf_model *b, double x, double y,
                      long *x0, long *y0, int *w, int *h)
{
    long ax, ay, bx, by;
    int aw, ah, bw, bh;
    mp_prf_box(a, x, y, &ax, &ay, &aw, &ah);
    mp_prf_box(b, x, y, &bx, &by, &bw, &bh);
    *x0 = ax < bx ? ax : bx;
    *y0 = ay < by ? ay : by;
    long x1 = ax + aw > bx + bw ? ax + aw : bx + bw, y1 = ay + ah > by + bh ? ay + ah : by + bh;
    *w = (int)(x1 - *x0);
    *h = (int)(y1 - *y0);
}

/* Render m at (x, y) and add sign × it (and its derivatives when dx, dy)
 * onto the box (x0, y0, w) in out. */
static int add_render(const mp_prf_model *m, double x, double y, double sign, long x0, long y0,
                      int w, double *out, double *dx, double *dy, double *buf, mp_prf_work *wk)
{
    long bx, by;
    int bw, bh;
    mp_prf_box(m, x, y, &bx, &by, &bw, &bh);
    size_t n = (size_t)bw * bh;
    if (mp_prf_render(m, x, y, buf, dx ? buf + n : NULL, dy ? buf + 2 * n : NULL, wk))
        return 1;
    for (int j = 0; j < bh; j++)
        for (int i = 0; i < bw; i++) {
            size_t o = (size_t)(by - y0 + j) * w + (size_t)(bx - x0 + i), s = (size_t)j * bw + i;
            out[o] += sign * buf[s];
            if (dx)
                dx[o] = buf[n + s];
            if (dy)
                dy[o] = buf[2 * n + s];
        }
    return 0;
}

/* The largest union box over the phases. */
static size_t box_pixels(const mp_prf_model *fine, const mp_prf_model *coarse)
{
    size_t big = 0;
    for (int ph = 0; ph < NPH_AXIS * NPH_AXIS; ph++) {
        long x0, y0;
        int w, h;
        union_box(fine, coarse, 1000.0 + (double)(ph % NPH_AXIS) / NPH_AXIS,
                  1000.0 + (double)(ph / NPH_AXIS) / NPH_AXIS, &x0, &y0, &w, &h);
        big = (size_t)w * (size_t)h > big ? (size_t)w * (size_t)h : big;
    }
    return big;
}

/* P, ∂P/∂x, ∂P/∂y and δP of coarse against fine (see the top of the file). */
static int bias_build(const mp_prf_model *fine, const mp_prf_model *coarse, mp_ss_bias *c,
                      char *err)
{
    memset(c, 0, sizeof *c);
    c->nph = NPH_AXIS * NPH_AXIS;
    size_t big = box_pixels(fine, coarse), all = big * (size_t)c->nph;
    c->npix = big;
    c->p = calloc(4 * all, sizeof *c->p);
    double *buf = malloc(3 * big * sizeof *buf);
    mp_prf_work wk = {0};
    int rc = 1;
    if (!c->p || !buf) {
        snprintf(err, MP_ERRLEN, "out of memory for the supersampling table");
        goto done;
    }
    c->dx = c->p + all;
    c->dy = c->p + 2 * all;
    c->dp = c->p + 3 * all;
    for (int ph = 0; ph < c->nph; ph++) {
        double x = 1000.0 + (double)(ph % NPH_AXIS) / NPH_AXIS;
        double y = 1000.0 + (double)(ph / NPH_AXIS) / NPH_AXIS;
        long x0, y0;
        int w, h;
        union_box(fine, coarse, x, y, &x0, &y0, &w, &h);
        size_t o = (size_t)ph * big;
        if (add_render(fine, x, y, +1.0, x0, y0, w, c->p + o, c->dx + o, c->dy + o, buf, &wk) ||
            add_render(coarse, x, y, +1.0, x0, y0, w, c->dp + o, NULL, NULL, buf, &wk)) {
            snprintf(err, MP_ERRLEN, "out of memory rendering the PRF");
            goto done;
        }
        for (size_t i = 0; i < (size_t)w * h; i++)
            c->dp[o + i] -= c->p[o + i];
    }
    rc = 0;
done:
    free(buf);
    mp_prf_work_free(&wk);
    if (rc) {
        free(c->p);
        memset(c, 0, sizeof *c);
    }
    return rc;
}

int mp_ss_level_build(const mp_prf_model *m, int factor, int with_sinc, mp_ss_level *lv,
                      char *err)
{
    memset(lv, 0, sizeof *lv);
    if (mp_psf_rebin(m->psf, factor, &lv->psf, err))
        return 1;
    lv->model = *m;
    lv->model.psf = &lv->psf;
    if (bias_build(m, &lv->model, &lv->bias, err) ||
        (with_sinc && mp_sinc_choice_build(&lv->model, &lv->sinc, err))) {
        mp_ss_level_free(lv);
        return 1;
    }
    return 0;
}

/* Cholesky of the 4×4 a (lower, in place), equilibrated by its diagonal
 * s (a_ij/(s_i s_j)) so that columns of 1 and of E ∂P/∂x mix safely.
 * Nonzero when a is not positive definite. */
static int chol4(double a[NPAR][NPAR], double s[NPAR])
{
    for (int i = 0; i < NPAR; i++) {
        if (!(a[i][i] > 0))
            return 1;
        s[i] = sqrt(a[i][i]);
    }
    for (int i = 0; i < NPAR; i++)
        for (int j = 0; j < NPAR; j++)
            a[i][j] /= s[i] * s[j];
    for (int j = 0; j < NPAR; j++) {
        double d = a[j][j];
        for (int k = 0; k < j; k++)
            d -= a[j][k] * a[j][k];
        if (!(d > 1e-13))
            return 1;
        a[j][j] = sqrt(d);
        for (int i = j + 1; i < NPAR; i++) {
            double v = a[i][j];
            for (int k = 0; k < j; k++)
                v -= a[i][k] * a[j][k];
            a[i][j] = v / a[j][j];
        }
    }
    return 0;
}

/* x = A⁻¹ r with A = S L Lᵀ S (chol4's factors). */
static void solve4(double l[NPAR][NPAR], const double s[NPAR], const double r[NPAR],
                   double x[NPAR])
{
    double z[NPAR];
    for (int i = 0; i < NPAR; i++) {
        double v = r[i] / s[i];
        for (int k = 0; k < i; k++)
            v -= l[i][k] * z[k];
        z[i] = v / l[i][i];
    }
    for (int i = NPAR - 1; i >= 0; i--) {
        double v = z[i];
        for (int k = i + 1; k < NPAR; k++)
            v -= l[k][i] * x[k];
        x[i] = v / l[i][i];
    }
    for (int i = 0; i < NPAR; i++)
        x[i] /= s[i];
}

/* One phase: the worst |b_k|/σ_k, and λ in *chi2.  The x and y columns are
 * ∂P (not E ∂P): a parameter's scale cancels in b_k/σ_k and in λ. */
static double phase_bias(const mp_ss_bias *c, int ph, double E, double B, double ron,
                         double *chi2)
{
    const double *p = c->p + (size_t)ph * c->npix, *dx = c->dx + (size_t)ph * c->npix;
    const double *dy = c->dy + (size_t)ph * c->npix, *dp = c->dp + (size_t)ph * c->npix;
    double F[NPAR][NPAR] = {{0}}, g[NPAR] = {0}, s[NPAR], b[NPAR], var0 = B + ron * ron;
    double rr = 0.0;
    for (size_t i = 0; i < c->npix; i++) {
        double v = E * p[i] + var0;
        if (!(v > 0))
            continue;
        /* one division a pixel, not eleven: 3.5 % → 2.3 % of the samples
         * of 47 Tuc with Tiny Tim's table (the limits' bisections), its
         * catalog byte-identical */
        double w = 1.0 / v, j[NPAR] = {p[i], dx[i], dy[i], 1.0}, r = E * dp[i], rw = r * w;
        rr += r * rw;
        for (int a = 0; a < NPAR; a++) {
            g[a] += j[a] * rw;
            for (int k = 0; k <= a; k++)
                F[a][k] += j[a] * j[k] * w;
        }
    }
    for (int a = 0; a < NPAR; a++)
        for (int k = a + 1; k < NPAR; k++)
            F[a][k] = F[k][a];
    if (chol4(F, s)) {
        *chi2 = INFINITY;          /* not identifiable: never serves */
        return INFINITY;
    }
    solve4(F, s, g, b);
    double worst = 0.0, gb = 0.0;
    for (int k = 0; k < NPAR; k++) {
        double e[NPAR] = {0}, col[NPAR];
        e[k] = 1.0;
        solve4(F, s, e, col);
        worst = fmax(worst, fabs(b[k]) / sqrt(col[k]));
        gb += g[k] * b[k];
    }
    /* λ = ‖EδP‖²_W − gᵀF⁻¹g, the W-residual of the projection; it loses
     * ~1e-16·‖EδP‖²_W to cancellation, far below the limit 1 for every
     * flux where the bias itself is ≤ frac. */
    *chi2 = fmax(rr - gb, 0.0);
    return worst;
}

double mp_ss_level_bias(const mp_ss_level *lv, double E, double B, double ron, double *chi2)
{
    double worst = 0.0, lam = 0.0;
    for (int ph = 0; ph < lv->bias.nph; ph++) {
        double l, q = phase_bias(&lv->bias, ph, E, B, ron, &l);
        worst = fmax(worst, q);
        lam = fmax(lam, l);
    }
    if (chi2)
        *chi2 = lam;
    return worst;
}

int mp_ss_level_serves(const mp_ss_level *lv, double E, double B, double ron, double frac)
{
    if (!lv->bias.p || !(E > 0))
        return 0;
    /* mp_ss_level_bias's largest q and λ against their limits, phase by
     * phase: the first phase over either decides (half the bisection's
     * fluxes, mp_ss_level_emax). */
    int ok = 1;
    /* In parallel over the phases (the coarser table's limit, 0.5 % of 47
     * Tuc built, serial, bench/SCALING.md); a phase once one failed is
     * skipped.  The answer is the same on any threads, and on one the
     * phases run in order and stop at the first failure, as before.  (A
     * small table, under ~64k terms, is not worth starting a team.) */
#pragma omp parallel for schedule(static) if (lv->bias.nph * lv->bias.npix > 65536)
    for (int ph = 0; ph < lv->bias.nph; ph++) {
        int on;
#pragma omp atomic read
        on = ok;
        if (!on)
            continue;
        double l, q = phase_bias(&lv->bias, ph, E, B, ron, &l);
        if (!(q <= frac && l <= MP_SS_CHI2MAX)) {
#pragma omp atomic write
            ok = 0;
        }
    }
    return ok;
}

/* Bisection in log E (as mp_sinc_choice_limits), then — the criterion is
 * not proven monotone in E (F depends on E) — a check on a log grid of
 * MP_SS_VERIFY fluxes from 1 e- to the limit, lowered below the first
 * failure. */
double mp_ss_level_emax(const mp_ss_level *lv, double B, double ron, double frac)
{
    double lo = 1e-3, hi = 1e15;
    if (!mp_ss_level_serves(lv, lo, B, ron, frac))
        return 0.0;
    if (mp_ss_level_serves(lv, hi, B, ron, frac))
        return INFINITY;
    for (int it = 0; it < MP_SS_BISECT; it++) {
        double mid = sqrt(lo * hi);
        if (mp_ss_level_serves(lv, mid, B, ron, frac))
            lo = mid;
        else
            hi = mid;
    }
    double prev = 0.0;
    for (int k = 1; k <= MP_SS_VERIFY; k++) {
        double E = lo > 1.0 ? pow(lo, (double)k / MP_SS_VERIFY) : lo * k / MP_SS_VERIFY;
        if (!mp_ss_level_serves(lv, E, B, ron, frac))
            return prev;
        prev = E;
    }
    return lo;
}
