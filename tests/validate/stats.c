/*
 * stats.c — per-bin figures, the χ² distribution and the KS test.
 *
 * Sampling uncertainty of the per-bin figures (asymptotic, N stars in the
 * bin; the sample q-quantile has σ = sqrt(q(1−q)/N) / f(x_q)):
 *
 *  - median of |Z|, Z ~ N(0,1), divided by its expectation 0.6745:
 *    f_|Z|(0.6745) = 2φ(0.6745) = 0.6356, σ(median) = 1/(2·0.6356·√N)
 *    = 0.7867/√N, so σ(ratio) = 0.7867/0.6745/√N = 1.166/√N;
 *  - median of a Rayleigh(1) variate (Δr/σ_X for equal per-axis σ)
 *    divided by its expectation √(2 ln 2) = 1.1774: f(1.1774) =
 *    1.1774·e^(−ln 2) = 0.5887, σ(median) = 1/(2·0.5887·√N) = 0.8493/√N,
 *    σ(ratio) = 0.8493/1.1774/√N = 0.721/√N;
 *  - robust σ = IQR/1.349 of N(0,1): Var(Q3 − Q1) = [2·¼·¾ − 2·¼·¼]/(f²N)
 *    with f = φ(0.6745) = 0.3178 (Cov(Q1,Q3) = q1(1−q3)/(f1 f3 N)), so
 *    σ(IQR) = 0.5/(0.3178 √N) = 1.573/√N and σ(IQR/1.349) = 1.166/√N;
 *  - median of N(0,1): 1/(2φ(0)√N) = 1.2533/√N.
 * `validate -selftest` checks these by Monte Carlo.
 */
#include <math.h>
#include <stdlib.h>
#include <string.h>
#include "tests/validate/vt.h"

#define U_ABSMED 1.166
#define U_RAYMED 0.721
#define U_RSIG 1.166
#define U_MED 1.2533
#define GOAL 0.05                 /* within 5 % of the CRLB ... */
#define NSIG 2.0                  /* ... plus 2 σ of sampling */

static int cmp_double(const void *a, const void *b)
{
    double x = *(const double *)a, y = *(const double *)b;
    return (x > y) - (x < y);
}

double vt_quantile_sorted(const double *v, size_t n, double q)
{
    if (n == 0)
        return NAN;
    double h = q * (double)(n - 1);
    size_t i = (size_t)floor(h);
    if (i + 1 >= n)
        return v[n - 1];
    return v[i] + (h - (double)i) * (v[i + 1] - v[i]);
}

double vt_median(double *v, size_t n)
{
    qsort(v, n, sizeof *v, cmp_double);
    return vt_quantile_sorted(v, n, 0.5);
}

double vt_robust_sigma(double *v, size_t n)
{
    qsort(v, n, sizeof *v, cmp_double);
    return (vt_quantile_sorted(v, n, 0.75) - vt_quantile_sorted(v, n, 0.25)) / 1.349;
}

int vt_bin_index(double mag)
{
    /* bin b is centred on -(6 + b): [c - 0.5, c + 0.5) */
    for (int b = 0; b < VT_NBIN; b++) {
        double c = vt_bin_centre(b);
        if (mag >= c - 0.5 && mag < c + 0.5)
            return b;
    }
    return -1;
}

double vt_bin_centre(int b)
{
    return -6.0 - b;
}

/* |Δmag| of a star; a non-positive fitted flux counts as 10 mag off. */
static double dmag_of(const vt_star *s)
{
    if (!(s->e > 0))
        return 10.0;
    return fabs(-2.5 * log10(s->e / s->e_true));
}

static double dr_of(const vt_star *s)
{
    return hypot(s->x - s->x_true, s->y - s->y_true);
}

/* Regularised lower incomplete gamma P(a, x) (series below a+1, Lentz's
 * continued fraction for Q above).  Single-threaded callers only (lgamma). */
static double gammp(double a, double x)
{
    if (!(x > 0))
        return 0.0;
    double lpre = a * log(x) - x - lgamma(a);
    if (x < a + 1.0) {
        double ap = a, del = 1.0 / a, sum = del;
        for (int i = 0; i < 100000; i++) {
            ap += 1.0;
            del *= x / ap;
            sum += del;
            if (fabs(del) < fabs(sum) * 1e-15)
                break;
        }
        return sum * exp(lpre);
    }
    double b = x + 1.0 - a, cc = 1.0 / 1e-300, d = 1.0 / b, h = d;
    for (int i = 1; i < 100000; i++) {
        double an = -i * (i - a);
        b += 2.0;
        d = an * d + b;
        if (fabs(d) < 1e-300)
            d = 1e-300;
        cc = b + an / cc;
        if (fabs(cc) < 1e-300)
            cc = 1e-300;
        d = 1.0 / d;
        double del = d * cc;
        h *= del;
        if (fabs(del - 1.0) < 1e-15)
            break;
    }
    return 1.0 - exp(lpre) * h;
}

double vt_chi2_cdf(double chi2, double dof)
{
    return gammp(0.5 * dof, 0.5 * chi2);
}

/* Kolmogorov's Q_KS(λ) with Stephens' λ = (√n + 0.12 + 0.11/√n) D. */
double vt_ks_pvalue(double d, size_t n)
{
    double sn = sqrt((double)n);
    double l = (sn + 0.12 + 0.11 / sn) * d;
    if (l < 0.2)
        return 1.0;
    if (l < 1.18) {      /* the theta-function form converges fast here */
        double s = 0.0;
        for (int k = 1; k <= 20; k++) {
            double t = (2 * k - 1) * M_PI / l;
            s += exp(-t * t / 8.0);
        }
        return 1.0 - sqrt(2.0 * M_PI) / l * s;
    }
    double s = 0.0;
    for (int k = 1; k <= 100; k++) {
        double t = 2.0 * exp(-2.0 * k * k * l * l) * (k % 2 ? 1.0 : -1.0);
        s += t;
        if (fabs(t) < 1e-16)
            break;
    }
    return s < 0 ? 0.0 : (s > 1 ? 1.0 : s);
}

int vt_stats(vt_result *r)
{
    int n = r->n;
    double *a = malloc((size_t)(n > 0 ? n : 1) * sizeof *a);
    double *b = malloc((size_t)(n > 0 ? n : 1) * sizeof *b);
    if (!a || !b) {
        free(a);
        free(b);
        return 1;
    }
    /* CPU, flags, χ² KS. */
    r->cpu_total = 0.0;
    r->nflag = 0;
    for (int k = 0; k < n; k++) {
        a[k] = r->s[k].cpu;
        r->cpu_total += r->s[k].cpu;
        if (r->s[k].flags || r->s[k].rc)
            r->nflag++;
    }
    r->cpu_median = vt_median(a, (size_t)n);
    size_t m = 0;
    double csum = 0.0;
    for (int k = 0; k < n; k++)
        if (r->s[k].dof > 0) {
            a[m] = r->s[k].chi2 * r->s[k].dof;
            b[m++] = r->s[k].dof;
            csum += r->s[k].chi2;
        }
    r->chi2_mean = m ? csum / (double)m : NAN;
    /* All dof are equal (3596) unless a fit failed; use the first. */
    qsort(a, m, sizeof *a, cmp_double);
    double D = 0.0;
    for (size_t i = 0; i < m; i++) {
        double F = vt_chi2_cdf(a[i], b[0]);
        D = fmax(D, fmax(F - (double)i / m, (double)(i + 1) / m - F));
    }
    r->ks_d = m ? D : NAN;
    r->ks_p = m ? vt_ks_pvalue(D, m) : NAN;

    for (int bi = 0; bi < VT_NBIN; bi++) {
        vt_bin *B = &r->bin[bi];
        memset(B, 0, sizeof *B);
        B->mag = vt_bin_centre(bi);
        const vt_star **in = malloc((size_t)(n > 0 ? n : 1) * sizeof *in);
        if (!in) {
            free(a);
            free(b);
            return 1;
        }
        int nb = 0;
        for (int k = 0; k < n; k++)
            if (vt_bin_index(r->s[k].mag) == bi)
                in[nb++] = &r->s[k];
        B->n = nb;
        if (!nb) {
            free(in);
            continue;
        }
        for (int k = 0; k < nb; k++) {
            B->beta += in[k]->beta / nb;
            B->volume += in[k]->volume / nb;
            B->lscale += in[k]->lscale / nb;
            if (in[k]->flags || in[k]->rc)
                B->nflag++;
        }
        double sq = sqrt((double)nb);
        B->u_ph = U_ABSMED / sq;
        B->u_as = U_RAYMED / sq;
        B->u_rs = U_RSIG / sq;
        B->u_med = U_MED / sq;
        for (int k = 0; k < nb; k++)
            a[k] = dmag_of(in[k]) / (1.0857 * in[k]->se_model / in[k]->e_true);
        B->ph_model = vt_median(a, (size_t)nb) / 0.6745;
        for (int k = 0; k < nb; k++)
            a[k] = dmag_of(in[k]) / (1.0857 * in[k]->se_crlb / in[k]->e_true);
        B->ph_crlb = vt_median(a, (size_t)nb) / 0.6745;
        for (int k = 0; k < nb; k++)
            a[k] = dr_of(in[k]) / in[k]->sx_model;
        B->as_model = vt_median(a, (size_t)nb) / 1.1774;
        for (int k = 0; k < nb; k++)
            a[k] = dr_of(in[k]) / sqrt(0.5 * (in[k]->sx_crlb * in[k]->sx_crlb +
                                              in[k]->sy_crlb * in[k]->sy_crlb));
        B->as_crlb = vt_median(a, (size_t)nb) / 1.1774;
        int ne = 0, nx = 0, ny = 0;
        for (int k = 0; k < nb; k++)
            if (in[k]->ee > 0)
                a[ne++] = (in[k]->e - in[k]->e_true) / in[k]->ee;
        for (int k = 0; k < ne; k++)
            b[k] = a[k];
        B->nE_med = vt_median(a, (size_t)ne);
        B->nE_rs = vt_robust_sigma(b, (size_t)ne);
        for (int k = 0; k < nb; k++)
            if (in[k]->ex > 0)
                a[nx++] = (in[k]->x - in[k]->x_true) / in[k]->ex;
        for (int k = 0; k < nx; k++)
            b[k] = a[k];
        B->nX_med = vt_median(a, (size_t)nx);
        B->nX_rs = vt_robust_sigma(b, (size_t)nx);
        for (int k = 0; k < nb; k++)
            if (in[k]->ey > 0)
                a[ny++] = (in[k]->y - in[k]->y_true) / in[k]->ey;
        for (int k = 0; k < ny; k++)
            b[k] = a[k];
        B->nY_med = vt_median(a, (size_t)ny);
        B->nY_rs = vt_robust_sigma(b, (size_t)ny);
        for (int k = 0; k < nb; k++)
            a[k] = in[k]->se_model / in[k]->se_crlb;
        B->modE_crlb = vt_median(a, (size_t)nb);
        for (int k = 0; k < nb; k++)
            a[k] = in[k]->sx_model / sqrt(0.5 * (in[k]->sx_crlb * in[k]->sx_crlb +
                                                 in[k]->sy_crlb * in[k]->sy_crlb));
        B->modX_crlb = vt_median(a, (size_t)nb);
        for (int k = 0; k < nb; k++)
            a[k] = dmag_of(in[k]);
        B->med_dmag = vt_median(a, (size_t)nb);
        for (int k = 0; k < nb; k++)
            a[k] = dr_of(in[k]);
        B->med_dr = vt_median(a, (size_t)nb);
        for (int k = 0; k < nb; k++)
            a[k] = 1.0857 * in[k]->se_model / in[k]->e_true;
        B->med_smag_model = vt_median(a, (size_t)nb);
        for (int k = 0; k < nb; k++)
            a[k] = in[k]->sx_model;
        B->med_sx_model = vt_median(a, (size_t)nb);
        B->pass_ph = fabs(B->ph_crlb - 1.0) <= GOAL + NSIG * B->u_ph;
        B->pass_as = fabs(B->as_crlb - 1.0) <= GOAL + NSIG * B->u_as;
        free(in);
    }
    free(a);
    free(b);
    return 0;
}

/* Monte Carlo check of the sampling constants in the header comment. */
void vt_selftest(FILE *fp)
{
    enum { NS = 2000, NREP = 2000 };
    double *v = malloc(NS * sizeof *v), *w = malloc(NS * sizeof *w);
    double *m1 = malloc(NREP * sizeof *m1), *m2 = malloc(NREP * sizeof *m2);
    double *m3 = malloc(NREP * sizeof *m3), *m4 = malloc(NREP * sizeof *m4);
    if (!v || !w || !m1 || !m2 || !m3 || !m4) {
        fprintf(fp, "selftest: out of memory\n");
        goto out;
    }
    mp_rng r;
    mp_rng_seed(&r, 12345);
    for (int rep = 0; rep < NREP; rep++) {
        for (int i = 0; i < NS; i++) {
            double z = mp_rng_normal(&r);
            v[i] = fabs(z);
            w[i] = z;
        }
        m1[rep] = vt_median(v, NS) / 0.6745;
        for (int i = 0; i < NS; i++)
            v[i] = w[i];
        m4[rep] = vt_median(v, NS);
        m3[rep] = vt_robust_sigma(w, NS);
        for (int i = 0; i < NS; i++)
            v[i] = hypot(mp_rng_normal(&r), mp_rng_normal(&r));
        m2[rep] = vt_median(v, NS) / 1.1774;
    }
    const char *name[4] = {"median |N(0,1)| / 0.6745", "median Rayleigh / 1.1774",
                           "IQR/1.349 of N(0,1)", "median of N(0,1)"};
    double want[4] = {U_ABSMED, U_RAYMED, U_RSIG, U_MED};
    double *mm[4] = {m1, m2, m3, m4};
    fprintf(fp, "selftest: %d samples of N = %d; sigma * sqrt(N), Monte Carlo vs formula\n",
            NREP, NS);
    for (int q = 0; q < 4; q++) {
        double mu = 0, s2 = 0;
        for (int i = 0; i < NREP; i++)
            mu += mm[q][i] / NREP;
        for (int i = 0; i < NREP; i++)
            s2 += (mm[q][i] - mu) * (mm[q][i] - mu) / (NREP - 1);
        fprintf(fp, "  %-26s mean %.4f  sigma*sqrt(N) %.4f (formula %.4f; MC 1-sigma %.3f)\n",
                name[q], mu, sqrt(s2 * NS), want[q], sqrt(s2 * NS) / sqrt(2.0 * NREP));
    }
    /* χ² CDF: the median of χ²(ν) ≈ ν(1 − 2/(9ν))³. */
    double nu = 3596;
    double med = nu * pow(1 - 2.0 / (9 * nu), 3);
    fprintf(fp, "  chi2 CDF(3596) at the Wilson-Hilferty median %.3f: %.6f (0.5)\n",
            med, vt_chi2_cdf(med, nu));
    fprintf(fp, "  chi2 CDF(3596) at nu + 2 sqrt(2 nu): %.6f (normal approx 0.977)\n",
            vt_chi2_cdf(nu + 2 * sqrt(2 * nu), nu));
    fprintf(fp, "  KS p-value of D = 1.36/sqrt(n), n = 10000: %.4f (0.05)\n",
            vt_ks_pvalue(1.358 / 100.0, 10000));
out:
    free(v);
    free(w);
    free(m1);
    free(m2);
    free(m3);
    free(m4);
}
