/* coupling.c — how strongly two stars' fits are coupled (fit.h,
 * mp_coupling): the largest canonical correlation κ between the
 * parameters (flux, x, y) of one star and those of the other in their
 * joint fit, from the Fisher information of the pixels of both fitting
 * discs with the paper's weights 1/(B + RON² + E_a P_a + E_b P_b)
 * (§2).  Canonical correlations do not depend on how each star's
 * parameters are scaled, so the gradients are P, ∂P/∂x, ∂P/∂y and the
 * fluxes enter through the weights alone. */
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "fit/fit.h"
#include "fit/spd.h"

#define DSTEP 0.5    /* separations tabulated every DSTEP px */
#define NDIR 8       /* directions of the pair, the largest κ kept */
#define A0 (-1.0)    /* log10(E / (B + RON²)) of the first flux node */
#define ASTEP 1.0
#define NA 9         /* flux nodes: E/(B + RON²) from 0.1 to 10^7 */

/* The largest eigenvalue of the symmetric 3×3 s (row-major), by the
 * trigonometric solution of its characteristic cubic (Smith 1961, CACM
 * 4, 168).  Not LAPACK's dsygv: Debian's OpenBLAS took its process-wide
 * buffer lock 280 000 times a 47 Tuc 512² run in this one call
 * (dsygs2's dsyr2 and dtrsv, dpotrf), and the coupling build, parallel
 * over pairs, ran as long on 16 threads as on one (fit/spd.h). */
static double sym3_max_eigen(const double s[9])
{
    double p1 = s[1] * s[1] + s[2] * s[2] + s[5] * s[5];
    double q = (s[0] + s[4] + s[8]) / 3.0;
    if (p1 == 0.0)
        return fmax(s[0], fmax(s[4], s[8]));
    double d0 = s[0] - q, d1 = s[4] - q, d2 = s[8] - q;
    double p = sqrt((d0 * d0 + d1 * d1 + d2 * d2 + 2.0 * p1) / 6.0);
    /* r = det((s − q I)/p)/2, within [−1, 1] but for rounding */
    double det = d0 * (d1 * d2 - s[5] * s[5]) - s[1] * (s[1] * d2 - s[5] * s[2]) +
                 s[2] * (s[1] * s[5] - d1 * s[2]);
    double r = det / (2.0 * p * p * p);
    r = r < -1.0 ? -1.0 : (r > 1.0 ? 1.0 : r);
    return q + 2.0 * p * cos(acos(r) / 3.0);
}

/* y = L⁻¹ v for the 3×3 lower factor l of mp_spd_factor (L(i, j) at
 * l[i + 3j]); v and y with stride inc. */
static void lower3_solve(const double l[9], const double *v, size_t inc, double y[3])
{
    y[0] = v[0] / l[0];
    y[1] = (v[inc] - l[1] * y[0]) / l[4];
    y[2] = (v[2 * inc] - l[2] * y[0] - l[5] * y[1]) / l[8];
}

/* κ of one pair from its information, the sums Σ w g gᵀ over the pixels
 * at[0..nat-1] of both discs for the 6 gradients (a's three, then b's). */
static double pair_kappa(const double *g[6], const double *pa, const double *pb,
                         const size_t *at, size_t nat, double beff, double ea, double eb)
{
    double Fi[6][6] = {{0}};
    for (size_t q = 0; q < nat; q++) {
        size_t p = at[q];
        double v = beff + ea * fmax(pa[p], 0.0) + eb * fmax(pb[p], 0.0);
        double w = 1.0 / v;
        for (int r = 0; r < 6; r++) {
            double wr = w * g[r][p];
            for (int c = r; c < 6; c++)
                Fi[r][c] += wr * g[c][p];
        }
    }
    double Iaa[9], Ibb[9], Iab[9];
    for (int r = 0; r < 3; r++)
        for (int c = 0; c < 3; c++) {
            Iaa[3 * r + c] = r <= c ? Fi[r][c] : Fi[c][r];
            Ibb[3 * r + c] = r <= c ? Fi[r + 3][c + 3] : Fi[c + 3][r + 3];
            Iab[3 * r + c] = Fi[r][c + 3];
        }
    /* X = Ibb⁻¹ Iba, C = Iab X; κ² the largest λ of C v = λ Iaa v.
     * Column c of Iba is row c of Iab: Xt holds X's columns as rows. */
    double Xt[9];
    memcpy(Xt, Iab, sizeof Xt);
    if (mp_spd_factor(Ibb, 3))
        return 1.0;            /* degenerate: count the pair as coupled */
    for (int c = 0; c < 3; c++)
        mp_spd_solve_factored(Ibb, 3, Xt + 3 * c);
    double C[9];
    for (int r = 0; r < 3; r++)
        for (int c = 0; c < 3; c++)
            C[3 * r + c] = Iab[3 * r] * Xt[3 * c] + Iab[3 * r + 1] * Xt[3 * c + 1] +
                           Iab[3 * r + 2] * Xt[3 * c + 2];
    /* C v = λ Iaa v with Iaa = L Lᵀ: the eigenvalues of S = L⁻¹ C L⁻ᵀ,
     * M = L⁻¹ C by columns, then S's columns L⁻¹ (M's rows). */
    if (mp_spd_factor(Iaa, 3))
        return 1.0;
    double M[9], S[9], y[3];
    for (int c = 0; c < 3; c++) {
        lower3_solve(Iaa, C + c, 3, y);
        for (int r = 0; r < 3; r++)
            M[3 * r + c] = y[r];
    }
    for (int c = 0; c < 3; c++) {
        lower3_solve(Iaa, M + 3 * c, 1, y);
        for (int r = 0; r < 3; r++)
            S[3 * r + c] = y[r];
    }
    for (int r = 0; r < 3; r++)
        for (int c = 0; c < r; c++)
            S[3 * r + c] = S[3 * c + r] = 0.5 * (S[3 * r + c] + S[3 * c + r]);
    double lam = sym3_max_eigen(S);
    return lam > 0 ? fmin(sqrt(lam), 1.0) : 0.0;
}

/* Scatter a rendered box into the window (zero elsewhere). */
static void place(const double *src, long bx0, long by0, int bw, int bh, long wx0, long wy0,
                  int W, double *dst)
{
    memset(dst, 0, (size_t)W * W * sizeof *dst);
    for (int j = 0; j < bh; j++)
        memcpy(dst + (size_t)(by0 - wy0 + j) * W + (bx0 - wx0), src + (size_t)j * bw,
               (size_t)bw * sizeof *src);
}

/* Star b at (xb, yb) rendered into the window's three planes q. */
static int render_into(const mp_prf_model *m, double xb, double yb, long wx0, long wy0, int W,
                       double *tmp, double *q[3], mp_prf_work *wk)
{
    long bx0, by0;
    int bw, bh;
    size_t n = (size_t)W * W;
    if (mp_prf_render_window(m, xb, yb, wx0, wy0, W, W, &bx0, &by0, &bw, &bh, tmp, tmp + n,
                             tmp + 2 * n, wk))
        return 1;
    for (int k = 0; k < 3; k++)
        place(tmp + k * n, bx0, by0, bw, bh, wx0, wy0, W, q[k]);
    return 0;
}

/* κ at separation d, every flux pair, the largest over NDIR directions,
 * into k[NA·NA]; fluxes and variances in units of B + RON² (fit.h). */
static int kappa_at(const mp_prf_model *m, double xc, double yc, double d, double fitrad,
                    long wx0, long wy0, int W, const double *ga[3], double *buf, size_t *at,
                    mp_prf_work *wk, float *k)
{
    size_t n = (size_t)W * W;
    double *gb[3] = {buf, buf + n, buf + 2 * n}, *tmp = buf + 3 * n;
    double E[NA];                 /* the flux nodes */
    for (int i = 0; i < NA; i++)
        E[i] = pow(10.0, A0 + ASTEP * i);
    for (int t = 0; t < NA * NA; t++)
        k[t] = 0.0f;
    for (int dir = 0; dir < NDIR; dir++) {
        double th = 2.0 * M_PI * dir / NDIR, xb = xc + d * cos(th), yb = yc + d * sin(th);
        if (render_into(m, xb, yb, wx0, wy0, W, tmp, gb, wk))
            return 1;
        size_t nat = 0;
        for (int j = 0; j < W; j++)
            for (int i = 0; i < W; i++) {
                double X = (double)(wx0 + i), Y = (double)(wy0 + j);
                if (hypot(X - xc, Y - yc) <= fitrad || hypot(X - xb, Y - yb) <= fitrad)
                    at[nat++] = (size_t)j * W + i;
            }
        const double *g[6] = {ga[0], ga[1], ga[2], gb[0], gb[1], gb[2]};
        for (int ia = 0; ia < NA; ia++)
            for (int ib = 0; ib < NA; ib++) {
                double kap = pair_kappa(g, ga[0], gb[0], at, nat, 1.0, E[ia], E[ib]);
                float *o = &k[ia * NA + ib];
                *o = kap > *o ? (float)kap : *o;
            }
    }
    return 0;
}

/* Conservative lookups: κ made non-increasing in d and non-decreasing in
 * each flux (a running maximum), so that the node at or below d and at or
 * above each flux bounds every value between the nodes it stands for. */
static void make_monotone(mp_coupling *c)
{
    size_t pl = (size_t)NA * NA;
    for (int id = c->nd - 2; id >= 0; id--)
        for (size_t t = 0; t < pl; t++)
            c->k[id * pl + t] = fmaxf(c->k[id * pl + t], c->k[(id + 1) * pl + t]);
    for (int id = 0; id < c->nd; id++) {
        float *k = c->k + id * pl;
        for (int ia = 0; ia < NA; ia++)
            for (int ib = 0; ib < NA; ib++) {
                if (ia > 0)
                    k[ia * NA + ib] = fmaxf(k[ia * NA + ib], k[(ia - 1) * NA + ib]);
                if (ib > 0)
                    k[ia * NA + ib] = fmaxf(k[ia * NA + ib], k[ia * NA + ib - 1]);
            }
    }
}

int mp_coupling_build(const mp_prf_model *m, double fitrad, double crit, double sky, double ron,
                      mp_coupling *c, char *err)
{
    memset(c, 0, sizeof *c);
    if (!(fitrad > 0) || !isfinite(fitrad) || !(crit > 0) || !isfinite(crit)) {
        snprintf(err, MP_ERRLEN, "coupling: fitrad %g and crit %g must be finite and > 0",
                 fitrad, crit);
        return 1;
    }
    c->crit = crit;
    c->fitrad = fitrad;
    mp_coupling_at(c, sky, ron);
    c->na = NA;
    c->dstep = DSTEP;
    c->a0 = A0;
    c->astep = ASTEP;
    /* a whole pixel's centre; a variable PSF at its field's origin */
    const mp_psf_field *fd = m->psf ? m->psf->field : NULL;
    double xc = fd && fd->order > 0 ? round(fd->x0) : 100.0;
    double yc = fd && fd->order > 0 ? round(fd->y0) : 100.0;
    /* Separations and the window need reach no further than the PRF's
     * box (reach: from the star to its farthest corner): the gradients
     * are zero beyond it, and so are their terms in every sum; two stars
     * whose boxes cannot meet have κ = 0, as the last node then says for
     * every d up to crit (psfrad or fitrad of 100000 asked for a window
     * 200 000 pixels a side). */
    long bx, by;
    int bw, bh;
    mp_prf_box(m, xc, yc, &bx, &by, &bw, &bh);
    double reach = 0.5 * hypot(bw, bh) + 1.0, span = fmin(crit, 2.0 * reach + DSTEP);
    c->nd = (int)ceil(span / DSTEP) + 1;
    int H = (int)ceil(span + fmin(fitrad, reach)) + 2, W = 2 * H + 1;
    long wx0 = (long)xc - H, wy0 = (long)yc - H;
    size_t n = (size_t)W * W;
    double *ga = malloc(3 * n * sizeof *ga), *tmp = malloc(3 * n * sizeof *tmp);
    c->k = malloc((size_t)c->nd * NA * NA * sizeof *c->k);
    int rc = !ga || !tmp || !c->k;
    mp_prf_work wk0 = {0};
    double *qa[3] = {ga, ga ? ga + n : NULL, ga ? ga + 2 * n : NULL};
    if (!rc)
        rc = render_into(m, xc, yc, wx0, wy0, W, tmp, qa, &wk0);
    const double *cga[3] = {qa[0], qa[1], qa[2]};
    int failed = 0;
#pragma omp parallel reduction(+ : failed)
    {
        mp_prf_work wk = {0};
        double *buf = rc ? NULL : malloc(6 * n * sizeof *buf);
        size_t *at = rc ? NULL : malloc(n * sizeof *at);
        failed += !rc && (!buf || !at);
#pragma omp for schedule(dynamic)
        for (int id = 0; id < c->nd; id++)
            if (buf && at)
                failed += kappa_at(m, xc, yc, id * DSTEP, fitrad, wx0, wy0, W, cga, buf, at,
                                   &wk, c->k + (size_t)id * NA * NA);
        free(buf);
        free(at);
        mp_prf_work_free(&wk);
    }
    mp_prf_work_free(&wk0);
    free(ga);
    free(tmp);
    if (rc || failed) {
        mp_coupling_free(c);
        snprintf(err, MP_ERRLEN, "out of memory measuring the stars' coupling");
        return 1;
    }
    make_monotone(c);
    return 0;
}

void mp_coupling_at(mp_coupling *c, double sky, double ron)
{
    c->beff = fmax(sky, 0.0) + ron * ron;
    c->beff = c->beff > 0 ? c->beff : 1.0;
}

/* The flux node at or above E (E not finite: the last). */
static int flux_node(const mp_coupling *c, double E)
{
    if (!isfinite(E))
        return c->na - 1;
    if (!(E > 0))
        return 0;
    double a = ceil((log10(E / c->beff) - c->a0) / c->astep);
    return a < 0 ? 0 : a > c->na - 1 ? c->na - 1 : (int)a;
}

double mp_coupling_kappa(const mp_coupling *c, double d, double Ea, double Eb)
{
    if (!(d >= 0))
        return 1.0;
    if (d >= c->crit)
        return 0.0;
    int id = (int)floor(d / c->dstep);
    id = id > c->nd - 1 ? c->nd - 1 : id;
    return c->k[((size_t)id * c->na + (size_t)flux_node(c, Ea)) * c->na +
                (size_t)flux_node(c, Eb)];
}

void mp_coupling_free(mp_coupling *c)
{
    free(c->k);
    memset(c, 0, sizeof *c);
}
