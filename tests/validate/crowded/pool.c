/*
 * pool.c — the normalised flux errors of several realisations of the
 * crowded frame pooled per magnitude bin (issue 13: "the robust σ of the
 * normalised errors 1.00 ± 0.05 in every magnitude bin"; one frame's bin of
 * ~550 stars has a sampling error of 0.05 by itself).
 *
 *   crowdpool MINSNR FILE...
 *       FILE: `crowded match`'s ROOT_ne.dat (mag_true, ne, ne_res,
 *       snr_joint, ne_joint per unsaturated field star, ne NaN when not
 *       found).
 *       Writes a Markdown table on stdout: per 1-mag bin the robust σ
 *       (IQR/1.349) of ne over the found stars and of ne_res over the
 *       resolved ones (no unfound true star within 2 FWHM), N, the
 *       sampling error 1.17/√N of a normal sample's robust σ, the
 *       deviation from 1 in those units, the robust σ of (E − E_true)
 *       over each resolved star's joint bound (the scatter itself against
 *       the bound, whatever the fit's error bars say), and what a cut at fitted
 *       S/N ≥ MINSNR alone does to the survivors: each star of true S/N s
 *       (E_true over its joint bound) is kept when its normalised error
 *       z ≥ MINSNR − s, so the found stars' z follow the mixture of
 *       normals truncated there; its robust σ is the one to expect.
 *       A second table splits the found stars of each bin by whether a
 *       true star the catalog missed lies within 2 FWHM (ROOT_ne.dat's
 *       sixth column, snr_miss: the largest S/N at the joint bound of
 *       those missed stars): the rσ of each part, the median of snr_miss
 *       over the stars beside a missed one, and how many of them have a
 *       missed neighbour that could have been found at all (S/N ≥ MINSNR).
 */
#include <math.h>
#include <stdio.h>
#include <stdlib.h>

enum { MB0 = -14, MB1 = -6, NB = MB1 - MB0 + 1 };

static int cmp_d(const void *a, const void *b)
{
    double x = *(const double *)a, y = *(const double *)b;
    return (x > y) - (x < y);
}

static double quant(double *v, long n, double q)
{
    if (n <= 0)
        return NAN;
    qsort(v, (size_t)n, sizeof *v, cmp_d);
    double p = q * (double)(n - 1);
    long i = (long)floor(p);
    return i >= n - 1 ? v[n - 1] : v[i] + (p - (double)i) * (v[i + 1] - v[i]);
}

static double rsig(double *v, long n) { return (quant(v, n, 0.75) - quant(v, n, 0.25)) / 1.349; }

static double Phi(double z) { return 0.5 * erfc(-z / M_SQRT2); }

/* The mixture's CDF at z: star i's normal truncated below at c_i. */
static double mix_cdf(const double *c, long n, double z)
{
    double num = 0, den = 0;
    for (long i = 0; i < n; i++) {
        double lo = Phi(c[i]);
        num += fmax(0.0, Phi(z) - lo);
        den += 1.0 - lo;
    }
    return den > 0 ? num / den : NAN;
}

static double mix_quant(const double *c, long n, double q)
{
    double lo = -10, hi = 10;
    for (int it = 0; it < 60; it++) {
        double mid = 0.5 * (lo + hi);
        if (mix_cdf(c, n, mid) < q)
            lo = mid;
        else
            hi = mid;
    }
    return 0.5 * (lo + hi);
}

int main(int argc, char **argv)
{
    if (argc < 3) {
        fprintf(stderr, "usage: crowdpool MINSNR FILE...\n");
        return 2;
    }
    double minsnr = atof(argv[1]);
    long cap = 1 << 16, n[NB] = {0};
    double *ne[NB], *nr[NB], *cut[NB], *nj[NB], *nb[NB], *sm[NB];
    long nn[NB] = {0}, nrr[NB] = {0}, nnj[NB] = {0}, nnb[NB] = {0}, nsm5[NB] = {0};
    for (int b = 0; b < NB; b++) {
        ne[b] = malloc(sizeof(double) * (size_t)cap);
        nr[b] = malloc(sizeof(double) * (size_t)cap);
        cut[b] = malloc(sizeof(double) * (size_t)cap);
        nj[b] = malloc(sizeof(double) * (size_t)cap);
        nb[b] = malloc(sizeof(double) * (size_t)cap);
        sm[b] = malloc(sizeof(double) * (size_t)cap);
        if (!ne[b] || !nr[b] || !cut[b] || !nj[b] || !nb[b] || !sm[b])
            return fprintf(stderr, "crowdpool: out of memory\n"), 1;
    }
    for (int a = 2; a < argc; a++) {
        FILE *f = fopen(argv[a], "r");
        char line[512];
        if (!f)
            return fprintf(stderr, "crowdpool: %s: cannot read\n", argv[a]), 1;
        while (fgets(line, sizeof line, f)) {
            double m, e, r, s, j = NAN, x = NAN;
            if (line[0] == '#' ||
                sscanf(line, "%lf %lf %lf %lf %lf %lf", &m, &e, &r, &s, &j, &x) < 4)
                continue;
            int b = (int)lround(m) - MB0;
            if (b < 0 || b >= NB || n[b] >= cap)
                continue;
            cut[b][n[b]++] = minsnr - s;
            if (isfinite(e))
                ne[b][nn[b]++] = e;
            if (isfinite(r))
                nr[b][nrr[b]++] = r;
            if (isfinite(j))
                nj[b][nnj[b]++] = j;
            if (isfinite(e) && !isfinite(r)) {     /* found, beside a missed star */
                nb[b][nnb[b]] = e;
                sm[b][nnb[b]++] = x;
                nsm5[b] += x >= minsnr;
            }
        }
        fclose(f);
    }
    printf("| mag | found | rσ (E−Et)/σE | resolved | median, resolved | rσ, resolved ± 1.17/√N | (rσ − 1)/σ | "
           "resolved: rσ (E−Et)/FLUXERR_JOINT | expected from the S/N ≥ %g cut alone: median, rσ |\n"
           "|---:|---:|---:|---:|---:|---:|---:|---:|---|\n",
           minsnr);
    for (int b = 0; b < NB; b++) {
        if (nrr[b] == 0)
            continue;
        double rs = rsig(nr[b], nrr[b]), se = 1.17 / sqrt((double)nrr[b]);
        double q1 = mix_quant(cut[b], n[b], 0.25), q2 = mix_quant(cut[b], n[b], 0.5),
               q3 = mix_quant(cut[b], n[b], 0.75);
        printf("| %d | %ld | %.3f | %ld | %+.3f | %.3f ± %.3f | %+.1f | %.3f | %+.3f, %.3f |\n",
               MB0 + b, nn[b], rsig(ne[b], nn[b]), nrr[b], quant(nr[b], nrr[b], 0.5), rs, se,
               (rs - 1.0) / se, rsig(nj[b], nnj[b]), q2, (q3 - q1) / 1.349);
    }
    printf("\n| mag | found | rσ (E−Et)/σE ± 1.17/√N | resolved: rσ | beside a missed star (≤ 2 FWHM) | "
           "their rσ | the brightest missed star's S/N at its joint bound: median | of them, ≥ %g |\n"
           "|---:|---:|---:|---:|---:|---:|---:|---:|\n", minsnr);
    for (int b = 0; b < NB; b++) {
        if (nn[b] == 0)
            continue;
        double med = quant(sm[b], nnb[b], 0.5);
        printf("| %d | %ld | %.3f ± %.3f | %.3f | %ld | %.3f | %.1f | %ld |\n", MB0 + b, nn[b],
               rsig(ne[b], nn[b]), 1.17 / sqrt((double)nn[b]), rsig(nr[b], nrr[b]), nnb[b],
               rsig(nb[b], nnb[b]), med, nsm5[b]);
    }
    for (int b = 0; b < NB; b++)
        free(ne[b]), free(nr[b]), free(cut[b]), free(nj[b]), free(nb[b]), free(sm[b]);
    return 0;
}
