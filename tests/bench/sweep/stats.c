/*
 * stats.c — the error ratios of a setting against the CRLB, their sampling
 * uncertainty, the paired difference from the default setting, and the
 * Pareto fronts.
 *
 * Per star: z_ph = |Δmag| / σ_mag,CRLB with σ_mag = 1.0857 σ_E / E_true
 * (a non-positive fitted flux counts as 10 mag off, as tests/validate), and
 * z_as = Δr / σ_X,CRLB with σ_X = √((σ_X² + σ_Y²)/2).  Ratios: median(z_ph)
 * / 0.6745 (the median of |N(0,1)|) and median(z_as) / 1.1774 (the Rayleigh
 * median); 1 = on the bound.  1σ sampling: 1.166/√n and 0.721/√n (derived
 * in tests/validate/stats.c).  All settings fit the same frames, so the
 * difference from the default is much better determined than either ratio:
 * its 1σ is the standard deviation over SW_NBOOT paired bootstrap
 * resamples of the stars.
 */
#include <math.h>
#include <stdlib.h>
#include <string.h>
#include "tests/bench/sweep/sw.h"

/* k-th smallest of v[0..n-1] (Hoare's selection; reorders v). */
static double select_k(double *v, size_t n, size_t k)
{
    size_t lo = 0, hi = n - 1;
    while (lo < hi) {
        double p = v[lo + (hi - lo) / 2];
        size_t i = lo, j = hi;
        while (i <= j) {
            while (v[i] < p)
                i++;
            while (v[j] > p)
                j--;
            if (i <= j) {
                double t = v[i];
                v[i] = v[j];
                v[j] = t;
                i++;
                if (j == 0)
                    break;
                j--;
            }
        }
        if (k <= j)
            hi = j;
        else if (k >= i)
            lo = i;
        else
            return v[k];
    }
    return v[k];
}

double sw_median(double *v, size_t n)
{
    if (n == 0)
        return NAN;
    double a = select_k(v, n, (n - 1) / 2);
    if (n % 2)
        return a;
    double b = select_k(v, n, n / 2);
    return 0.5 * (a + b);
}

static void z_of(const sw_scene *sc, const sw_result *r, int k, double *zph, double *zas)
{
    const sw_truth *t = &sc->t[k];
    if (!isfinite(r->f[k]) || !isfinite(r->x[k])) {
        *zph = *zas = NAN;        /* lost */
        return;
    }
    double dmag = r->f[k] > 0 ? fabs(-2.5 * log10(r->f[k] / t->e)) : 10.0;
    double smag = 1.0857362047581294 * t->se / t->e;
    *zph = dmag / smag;
    *zas = hypot(r->x[k] - t->x, r->y[k] - t->y) / t->sx;
}

static int in_sub(const sw_truth *t, int s)
{
    return s == 0 || (s == 1 && t->mag > SW_FAINT) || (s == 2 && t->mag < SW_BRIGHT);
}

int sw_stats(const sw_scene *sc, sw_result *res, int nres, int idef, uint64_t seed)
{
    int n = sc->n;
    double *zp = malloc((size_t)n * nres * sizeof *zp), *za = malloc((size_t)n * nres * sizeof *za);
    double *a = malloc((size_t)n * sizeof *a), *b = malloc((size_t)n * sizeof *b);
    int *idx = malloc((size_t)n * sizeof *idx), *pick = malloc((size_t)n * sizeof *pick);
    if (!zp || !za || !a || !b || !idx || !pick) {
        free(zp);
        free(za);
        free(a);
        free(b);
        free(idx);
        free(pick);
        return 1;
    }
    for (int s = 0; s < nres; s++) {
        sw_result *r = &res[s];
        long nf = 0, nn = 0, nl = 0, ns = 0;
        for (int k = 0; k < n; k++) {
            z_of(sc, r, k, &zp[(size_t)s * n + k], &za[(size_t)s * n + k]);
            if (!isfinite(r->f[k])) {
                nl++;
                continue;
            }
            nf += (r->flags[k] & ~MP_FLAG_SPLIT) != 0;
            nn += (r->flags[k] & MP_FLAG_NOCONV) != 0;
            ns += (r->flags[k] & MP_FLAG_SPLIT) != 0;
        }
        r->fflag = (double)nf / n;
        r->fnoconv = (double)nn / n;
        r->flost = (double)nl / n;
        r->fsplit = (double)ns / n;
    }
    for (int s = 0; s < nres; s++) {
        const double *p = zp + (size_t)s * n, *q = za + (size_t)s * n;
        const double *pd = zp + (size_t)idef * n, *qd = za + (size_t)idef * n;
        for (int sub = 0; sub < 3; sub++) {
            sw_sub *u = &res[s].sub[sub];
            memset(u, 0, sizeof *u);
            size_t m = 0;
            for (int k = 0; k < n; k++)
                if (in_sub(&sc->t[k], sub) && isfinite(p[k]))
                    a[m++] = p[k];
            u->n = (int)m;
            u->ph = sw_median(a, m) / 0.6745;
            m = 0;
            for (int k = 0; k < n; k++)
                if (in_sub(&sc->t[k], sub) && isfinite(q[k]))
                    a[m++] = q[k];
            u->as = sw_median(a, m) / 1.1774;
            u->uph = m ? 1.166 / sqrt((double)m) * u->ph : NAN;
            u->uas = m ? 0.721 / sqrt((double)m) * u->as : NAN;
            /* Paired: the stars both settings kept. */
            size_t np = 0;
            for (int k = 0; k < n; k++)
                if (in_sub(&sc->t[k], sub) && isfinite(p[k]) && isfinite(pd[k]))
                    idx[np++] = k;
            if (np == 0) {
                u->dph = u->das = u->udph = u->udas = NAN;
                continue;
            }
            double d[2];
            for (int w = 0; w < 2; w++) {
                const double *x = w ? q : p, *y = w ? qd : pd;
                double c = w ? 1.1774 : 0.6745;
                for (size_t i = 0; i < np; i++) {
                    a[i] = x[idx[i]];
                    b[i] = y[idx[i]];
                }
                d[w] = (sw_median(a, np) - sw_median(b, np)) / c;
            }
            u->dph = d[0];
            u->das = d[1];
            if (s == idef) {
                u->udph = u->udas = 0.0;
                continue;
            }
            mp_rng rng;
            mp_rng_seed(&rng, seed + 7919ULL * (uint64_t)s + (uint64_t)sub);
            double s1[2] = {0, 0}, s2[2] = {0, 0};
            for (int bt = 0; bt < SW_NBOOT; bt++) {
                for (size_t i = 0; i < np; i++) {
                    size_t j = (size_t)(mp_rng_uniform(&rng) * (double)np);
                    pick[i] = idx[j < np ? j : np - 1];
                }
                for (int w = 0; w < 2; w++) {       /* the same resample for both */
                    const double *x = w ? q : p, *y = w ? qd : pd;
                    double c = w ? 1.1774 : 0.6745;
                    for (size_t i = 0; i < np; i++) {
                        a[i] = x[pick[i]];
                        b[i] = y[pick[i]];
                    }
                    double v = (sw_median(a, np) - sw_median(b, np)) / c;
                    s1[w] += v;
                    s2[w] += v * v;
                }
            }
            for (int w = 0; w < 2; w++) {
                double mu = s1[w] / SW_NBOOT, var = s2[w] / SW_NBOOT - mu * mu;
                double sd = sqrt(var > 0 ? var * SW_NBOOT / (SW_NBOOT - 1.0) : 0.0);
                if (w)
                    u->udas = sd;
                else
                    u->udph = sd;
            }
        }
    }
    free(zp);
    free(za);
    free(a);
    free(b);
    free(idx);
    free(pick);
    return 0;
}

/* The Pareto fronts: i is off a front when another setting j is cheaper and
 * no more than SW_PEPS worse in the ratio(s), or as cheap and more than
 * SW_PEPS better — differences far below the sampling uncertainty do not
 * put an otherwise dominated setting on the front.  Settings that flag or
 * lose more than SW_FLAGMAX more of the stars than the default are not
 * usable (a not-converged flag on most stars), nor are settings that beat
 * the bound (sw_beats); they are on no front. */
static int dominates(const sw_result *j, const sw_result *i, int w)
{
    double yj[2] = {j->sub[0].ph, j->sub[0].as}, yi[2] = {i->sub[0].ph, i->sub[0].as};
    int a = w == 2 ? 0 : w, b = w == 2 ? 1 : w;
    int nowworse = 1, better = 0;
    for (int k = a; k <= b; k++) {
        nowworse &= yj[k] <= yi[k] + SW_PEPS;
        better |= yj[k] < yi[k] - SW_PEPS;
    }
    return (j->cpu_star < i->cpu_star && nowworse) ||
           (j->cpu_star <= i->cpu_star && nowworse && better);
}

int sw_usable(const sw_result *r, const sw_result *def)
{
    return r->fflag + r->flost <= def->fflag + def->flost + SW_FLAGMAX && !sw_beats(r, 0);
}

/* No unbiased estimator beats the CRLB: a ratio more than 3σ of sampling
 * below 1 means a bias toward the truth (e.g. positions pulled to the
 * table grid on which the simulated stars sit), not a better fit. */
int sw_beats(const sw_result *r, int sub)
{
    const sw_sub *u = &r->sub[sub];
    return u->n > 0 && (u->ph < 1.0 - 3.0 * 1.166 / sqrt((double)u->n) ||
                        u->as < 1.0 - 3.0 * 0.721 / sqrt((double)u->n));
}

void sw_pareto(sw_result *res, int nres)
{
    for (int i = 0; i < nres; i++) {
        int d[3] = {0, 0, 0};
        if (!sw_usable(&res[i], &res[0]))
            d[0] = d[1] = d[2] = 1;
        for (int j = 0; j < nres; j++)
            for (int w = 0; w < 3 && j != i && sw_usable(&res[j], &res[0]); w++)
                d[w] |= dominates(&res[j], &res[i], w);
        res[i].par_ph = !d[0];
        res[i].par_as = !d[1];
        res[i].par_joint = !d[2];
    }
}
