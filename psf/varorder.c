/* varorder.c — does the data demand the next polynomial order? (build.h)
 *
 * With the table of order k built, each used star's normalised residual
 * z = (d − sky − F·PRF)/σ at every pixel offset p from its nearest pixel
 * (within fitrad) is regressed over the stars on the terms of order k+1.
 * Under "order k suffices" the residuals do not depend on position, and
 * the extra terms' F statistic of pixel p, F_p = (ΔRSS/q)/(RSS/d), is
 * F(q, d) distributed (q new terms, d = n − terms − ... dof), whatever the
 * pixel's own noise.  Their sum over P pixels has mean P·d/(d−2) and
 * variance P·2d²(q+d−2)/(q(d−2)²(d−4)) if the pixels' F are independent;
 * the standardised sum is referred to the normal (the sky order's test in
 * fit/sky_test.c is a score test of the same kind).
 *
 * They are not independent when a star's misfit is coherent over its
 * pixels (a built table's error at the star's phase, a neighbour's
 * wing): that misfit does not depend on where the star is, so it belongs
 * to the null, but it spreads the sum 3-4 times wider than the formula
 * (tests/validate/psfbuild/psfbuild_notes.md).  So a sum the formula
 * rejects is referred again to the sums of MP_EPSF_NPERM random
 * permutations of the stars' positions over their residuals (each star's
 * residual kept whole, any dependence on position broken): its log
 * against the normal of their logs (the sums are positive and skewed; of
 * 9 900 permuted sums of test_psf_build's coherent-misfit frames, each
 * referred so to the other 98 of its frame, 0.08 % fell below p 0.001,
 * against 0.37 % by a scaled χ² of their mean and variance and 1.7 % by
 * the normal).  The order is raised only when both nulls reject. */
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include "psf/build_priv.h"
#include "sim/sim.h"

/* RSS of the unweighted LS fits of z[idx] on the first nt0 and the first
 * nt1 (> nt0) columns of the term rows (MP_EPSF_MAXT per star) into *r0,
 * *r1 (NaN where a system is singular).  One pass builds the larger
 * normal equations, whose leading block is the smaller's, each entry the
 * same sum in the same order; one pass sums both residuals: the same
 * values as two fits, for half the reads (with the permuted null, this
 * was the largest self time of frame C built, 6 %). */
static void rss_pair(const double *z, const double *terms, const size_t *idx, size_t m,
                     int nt0, int nt1, double *r0, double *r1)
{
    double A1[MP_EPSF_MAXT * MP_EPSF_MAXT] = {0}, c1[MP_EPSF_MAXT] = {0};
    double A0[MP_EPSF_MAXT * MP_EPSF_MAXT], c0[MP_EPSF_MAXT];
    for (size_t q = 0; q < m; q++) {
        const double *t = terms + idx[q] * MP_EPSF_MAXT;
        for (int a = 0; a < nt1; a++) {
            c1[a] += t[a] * z[q];
            for (int b = 0; b <= a; b++)
                A1[a * nt1 + b] += t[a] * t[b];
        }
    }
    for (int a = 0; a < nt0; a++) {
        c0[a] = c1[a];
        for (int b = 0; b <= a; b++)
            A0[a * nt0 + b] = A1[a * nt1 + b];
    }
    for (int a = 0; a < nt1; a++)
        for (int b = a + 1; b < nt1; b++) {
            A1[a * nt1 + b] = A1[b * nt1 + a];
            if (b < nt0)
                A0[a * nt0 + b] = A0[b * nt0 + a];
        }
    int bad0 = mp_epsf_solve(A0, c0, nt0), bad1 = mp_epsf_solve(A1, c1, nt1);
    double s0 = 0, s1 = 0;
    for (size_t q = 0; q < m; q++) {
        const double *t = terms + idx[q] * MP_EPSF_MAXT;
        double mod0 = 0, mod1 = 0;
        for (int a = 0; a < nt0; a++)
            mod0 += t[a] * c0[a];
        for (int a = 0; a < nt1; a++)
            mod1 += t[a] * c1[a];
        s0 += (z[q] - mod0) * (z[q] - mod0);
        s1 += (z[q] - mod1) * (z[q] - mod1);
    }
    *r0 = bad0 ? NAN : s0;
    *r1 = bad1 ? NAN : s1;
}

/* z of star k at the pixel offsets of a (2R+1)² square about its nearest
 * pixel, NaN where not measured. */
static int residuals(const mp_epsf_star *s, const mp_epsf *e, int R, double fitrad, double *z,
                     mp_psf *tab, mp_prf_work *w, char *err)
{
    int side = 2 * R + 1;
    for (int i = 0; i < side * side; i++)
        z[i] = NAN;
    if (mp_epsf_table(e, s->x, s->y, tab, err))
        return 1;
    mp_prf_model m = {tab, NULL, 10};
    double xs = s->x - (double)(s->x0 - 1), ys = s->y - (double)(s->y0 - 1);
    long bx0, by0;
    int bw, bh;
    mp_prf_box(&m, xs, ys, &bx0, &by0, &bw, &bh);
    double *prf = malloc((size_t)bw * bh * sizeof *prf);
    if (!prf || mp_prf_render(&m, xs, ys, prf, NULL, NULL, w)) {
        free(prf);
        snprintf(err, MP_ERRLEN, "psf build: out of memory");
        return 1;
    }
    long cx = lround(xs), cy = lround(ys);
    double ron2 = fmax(s->f.rdnoise * s->f.rdnoise, 1e-2), sky = fmax(s->sky, 0.0);
    for (int dj = -R; dj <= R; dj++)
        for (int di = -R; di <= R; di++) {
            long px = cx + di, py = cy + dj;
            if (px < 1 || py < 1 || px > s->f.im.nx || py > s->f.im.ny ||
                hypot(px - xs, py - ys) > fitrad)
                continue;
            size_t o = (size_t)(py - 1) * s->f.im.nx + (size_t)(px - 1);
            long bi = px - bx0, bj = py - by0;
            if (s->f.mask[o] || bi < 0 || bj < 0 || bi >= bw || bj >= bh)
                continue;
            double mod = s->flux * prf[(size_t)bj * bw + bi];
            z[(dj + R) * side + di + R] = (s->f.im.pix[o] - s->sky - mod) /
                                          sqrt(fmax(mod + sky, sky) + ron2);
        }
    free(prf);
    return 0;
}

/* The terms of order `to` (> e's) at (x, y) into t, the current order's
 * first (as columns 0..nt0−1) so that the reduced model is the first nt0
 * columns.  PSFEx order is y power outer: the terms of total degree above
 * e->order are moved to the end, each group kept in order. */
static void next_terms(const mp_epsf *e, int to, double x, double y, double *t)
{
    mp_epsf next = *e;
    next.order = to;
    double t1[MP_EPSF_MAXT];
    mp_epsf_terms(&next, x, y, t1);
    int a = 0, b = e->nterms, q1 = 0;
    for (int j = 0; j <= next.order; j++)
        for (int i = 0; i + j <= next.order; i++, q1++)
            t[i + j > e->order ? b++ : a++] = t1[q1];
}

/* Σ over the np pixel offsets of the new terms' F statistic (z: nu stars
 * × np, NaN where not measured; a pixel measured on fewer than nt1 + 9
 * stars is left out), and its mean and variance under F(q, d) a pixel;
 * star k's terms are row perm[k] of terms (perm NULL: row k); zc, idx
 * scratch for nu.  Returns the pixels used. */
static int f_sum(const double *z, const double *terms, const size_t *perm, size_t nu, int np,
                 int nt0, int nt1, double *zc, size_t *idx, double *sum, double *mean,
                 double *var)
{
    int q = nt1 - nt0, npix = 0;
    *sum = *mean = *var = 0.0;
    for (int pix = 0; pix < np; pix++) {
        size_t m = 0;
        for (size_t k = 0; k < nu; k++)
            if (isfinite(z[k * np + pix])) {
                zc[m] = z[k * np + pix];
                idx[m++] = perm ? perm[k] : k;
            }
        int d = (int)m - nt1;
        if (d <= 8)
            continue;
        double r0, r1;
        rss_pair(zc, terms, idx, m, nt0, nt1, &r0, &r1);
        if (!isfinite(r0) || !isfinite(r1) || !(r1 > 0))
            continue;
        *sum += ((r0 - r1) / q) / (r1 / d);
        *mean += (double)d / (d - 2);
        *var += 2.0 * d * d * (q + d - 2.0) / (q * (d - 2.0) * (d - 2.0) * (d - 4.0));
        npix++;
    }
    return npix;
}

/* The permuted null's sums (file comment): permutation b draws from its
 * own seed, so the sums do not depend on the threads. */
#define PERM_SEED 0x6d70766f72646572ULL

static int permuted_sums(const double *z, const double *terms, size_t nu, int np, int nt0,
                         int nt1, double *sums)
{
    int failed = 0;
#pragma omp parallel reduction(+ : failed)
    {
        double *zc = malloc((nu + 1) * sizeof *zc);
        size_t *idx = malloc((nu + 1) * sizeof *idx), *perm = malloc((nu + 1) * sizeof *perm);
        failed = !zc || !idx || !perm;
#pragma omp for schedule(static)
        for (int b = 0; b < MP_EPSF_NPERM; b++) {
            if (!zc || !idx || !perm)
                continue;
            mp_rng r;
            mp_rng_seed(&r, PERM_SEED + (uint64_t)b);
            for (size_t k = 0; k < nu; k++)
                perm[k] = k;
            for (size_t k = nu - 1; k > 0; k--) {     /* Fisher–Yates */
                size_t j = (size_t)(mp_rng_uniform(&r) * (double)(k + 1)), t = perm[k];
                j = j > k ? k : j;
                perm[k] = perm[j];
                perm[j] = t;
            }
            double mean, var;
            f_sum(z, terms, perm, nu, np, nt0, nt1, zc, idx, &sums[b], &mean, &var);
        }
        free(zc);
        free(idx);
        free(perm);
    }
    return failed != 0;
}

/* The one-sided p-value of sum against the permuted sums (file comment):
 * log sum referred to the normal with their logs' mean and σ; *zp its
 * deviate (NaN, p 1, when a sum is not positive). */
static double permuted_p(double sum, const double *sums, double *zp)
{
    double m = 0.0, v = 0.0;
    *zp = NAN;
    for (int b = 0; b < MP_EPSF_NPERM; b++) {
        if (!(sums[b] > 0))
            return 1.0;
        m += log(sums[b]);
    }
    m /= MP_EPSF_NPERM;
    for (int b = 0; b < MP_EPSF_NPERM; b++)
        v += (log(sums[b]) - m) * (log(sums[b]) - m);
    v /= MP_EPSF_NPERM - 1;
    if (!(sum > 0) || !(v > 0))
        return 1.0;
    *zp = (log(sum) - m) / sqrt(v);
    return 0.5 * erfc(*zp / M_SQRT2);
}

int mp_epsf_order_test(const mp_epsf_star *s, size_t n, const mp_epsf *e, double fitrad,
                       double alpha, double *p, double *stat, double *zperm, char *err)
{
    return mp_epsf_order_test_to(s, n, e, e->order + 1, fitrad, alpha, p, stat, zperm, err);
}

/* The used stars' residuals z (np = (2R+1)² each) and order-`to` terms,
 * the u-th used star's at z + u·np and terms + u·MP_EPSF_MAXT, in
 * parallel over the stars (each thread its own table and render work;
 * serial, they were 2.5 % of 47 Tuc built's wall time on 16 threads);
 * which: room for the used stars' indices.  Nonzero with err when out
 * of memory. */
static int stars_residuals(const mp_epsf_star *s, size_t n, const mp_epsf *e, int to, int R,
                           double fitrad, double *z, double *terms, size_t *which, char *err)
{
    size_t nu = 0;
    int np = (2 * R + 1) * (2 * R + 1), failed = 0;
    for (size_t k = 0; k < n; k++)
        if (s[k].used)
            which[nu++] = k;
#pragma omp parallel reduction(| : failed)
    {
        mp_psf tab;
        mp_prf_work w;
        char e1[MP_ERRLEN];
        memset(&tab, 0, sizeof tab);
        memset(&w, 0, sizeof w);
#pragma omp for schedule(dynamic)
        for (size_t u = 0; u < nu; u++) {
            size_t k = which[u];
            next_terms(e, to, s[k].x, s[k].y, terms + u * MP_EPSF_MAXT);
            failed |= residuals(&s[k], e, R, fitrad, z + u * (size_t)np, &tab, &w, e1);
        }
        mp_psf_free(&tab);
        mp_prf_work_free(&w);
    }
    if (failed)
        snprintf(err, MP_ERRLEN, "psf build: out of memory");
    return failed;
}

int mp_epsf_order_test_to(const mp_epsf_star *s, size_t n, const mp_epsf *e, int to,
                          double fitrad, double alpha, double *p, double *stat, double *zperm,
                          char *err)
{
    *p = 1.0;
    *stat = 0.0;
    if (zperm)
        *zperm = NAN;
    if (to <= e->order || to > MP_PSF_MAXORDER)
        return 0;
    int nt0 = e->nterms, nt1 = (to + 1) * (to + 2) / 2;
    int R = (int)ceil(fitrad), side = 2 * R + 1, np = side * side;
    size_t nu = 0;
    for (size_t k = 0; k < n; k++)
        nu += s[k].used != 0;
    if (nu < (size_t)(3 * nt1 + 5))
        return 0;
    double *z = malloc(nu * (size_t)np * sizeof *z);
    double *terms = malloc(nu * MP_EPSF_MAXT * sizeof *terms);
    double *zc = malloc((nu + 1) * sizeof *zc);
    size_t *idx = malloc((nu + 1) * sizeof *idx);
    int rc = 1;
    if (!z || !terms || !zc || !idx) {
        snprintf(err, MP_ERRLEN, "psf build: out of memory");
        goto done;
    }
    if (stars_residuals(s, n, e, to, R, fitrad, z, terms, idx, err))
        goto done;
    double sum, mean, var;
    int npix = f_sum(z, terms, NULL, nu, np, nt0, nt1, zc, idx, &sum, &mean, &var);
    if (npix > 0 && var > 0) {
        *stat = (sum - mean) / sqrt(var);
        *p = 0.5 * erfc(*stat / M_SQRT2);
    }
    if (*p < alpha) {
        double sums[MP_EPSF_NPERM], zp;
        if (permuted_sums(z, terms, nu, np, nt0, nt1, sums)) {
            snprintf(err, MP_ERRLEN, "psf build: out of memory");
            goto done;
        }
        *p = fmax(*p, permuted_p(sum, sums, &zp));
        if (zperm)
            *zperm = zp;
    }
    rc = 0;
done:
    free(z);
    free(terms);
    free(zc);
    free(idx);
    return rc;
}
