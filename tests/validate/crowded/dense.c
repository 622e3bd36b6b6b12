/* dense.c — `dense score TRUTH CAT LABEL CPU`: a dense simulated frame's
 * catalog against its truth (matphot sim's .truth: X_IMAGE, Y_IMAGE,
 * FLUX_TRUE, MAG_TRUE), one markdown row on stdout.  Each true star is
 * matched to the nearest catalog entry (XPSF_IMAGE, YPSF_IMAGE) within
 * 1 px, one to one, closest pairs first; a false entry is one left
 * unmatched.  Robust σ = 1.4826 × the median absolute deviation: of
 * z = (FLUX_PSF − FLUX_TRUE)/FLUXERR_PSF over the matched stars, and of
 * ΔE/E_true per 1-mag bin of MAG_TRUE (−13 … −8).  As CROWDED.md, z is
 * also split by whether an unmatched true star lies within 2 FWHM (5 px
 * for the scene's FWHM 2.5): its light is fitted as part of the matched
 * star, an error of identification the error bar cannot carry. */
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "catalog/catalog.h"
#include "io/io.h"

#define RESOLVED_PX 5.0     /* 2 FWHM of the scene's 2.5 px */

typedef struct {
    double d;
    size_t t, c;
} cand;

static int by_d(const void *a, const void *b)
{
    double x = ((const cand *)a)->d, y = ((const cand *)b)->d;
    return (x > y) - (x < y);
}

static double rsigma(double *v, size_t n)
{
    if (n == 0)
        return NAN;
    double m = mp_median_select(v, n);
    for (size_t i = 0; i < n; i++)
        v[i] = fabs(v[i] - m);
    return 1.4826 * mp_median_select(v, n);
}

static int col(const mp_table *t, const char *name, const char *path)
{
    int c = mp_table_col(t, name);
    if (c < 0) {
        fprintf(stderr, "dense: %s: no column %s\n", path, name);
        exit(1);
    }
    return c;
}

int main(int argc, char **argv)
{
    if (argc != 6 || strcmp(argv[1], "score") != 0) {
        fprintf(stderr, "usage: dense score TRUTH CAT LABEL CPU\n");
        return 2;
    }
    char err[MP_ERRLEN];
    mp_table T, C;
    if (mp_table_read(argv[2], &T, err) || mp_table_read(argv[3], &C, err)) {
        fprintf(stderr, "dense: %s\n", err);
        return 1;
    }
    int tx = col(&T, "X_IMAGE", argv[2]), ty = col(&T, "Y_IMAGE", argv[2]);
    int te = col(&T, "FLUX_TRUE", argv[2]), tm = col(&T, "MAG_TRUE", argv[2]);
    int cx = col(&C, "XPSF_IMAGE", argv[3]), cy = col(&C, "YPSF_IMAGE", argv[3]);
    int ce = col(&C, "FLUX_PSF", argv[3]), cs = col(&C, "FLUXERR_PSF", argv[3]);
    size_t nt = T.nrow, nc = C.nrow, np = 0, cap = 1024;
    cand *p = malloc(cap * sizeof *p);
    for (size_t i = 0; p && i < nt; i++)
        for (size_t j = 0; j < nc; j++) {
            double d = hypot(mp_table_get(&T, i, tx) - mp_table_get(&C, j, cx),
                             mp_table_get(&T, i, ty) - mp_table_get(&C, j, cy));
            if (!(d < 1.0))
                continue;
            if (np == cap && !(p = realloc(p, (cap *= 2) * sizeof *p)))
                break;
            p[np++] = (cand){d, i, j};
        }
    long *mt = malloc((nt + 1) * sizeof *mt), *mc = malloc((nc + 1) * sizeof *mc);
    double *z = malloc((nt + 1) * sizeof *z), *r = malloc((nt + 1) * sizeof *r);
    if (!p || !mt || !mc || !z || !r) {
        fprintf(stderr, "dense: out of memory\n");
        return 1;
    }
    qsort(p, np, sizeof *p, by_d);
    memset(mt, -1, (nt + 1) * sizeof *mt);
    memset(mc, -1, (nc + 1) * sizeof *mc);
    size_t nm = 0;
    for (size_t k = 0; k < np; k++)
        if (mt[p[k].t] < 0 && mc[p[k].c] < 0) {
            mt[p[k].t] = (long)p[k].c;
            mc[p[k].c] = (long)p[k].t;
            nm++;
        }
    size_t nz = 0, nres = 0;
    double *zr = malloc((nt + 1) * sizeof *zr), *zu = malloc((nt + 1) * sizeof *zu);
    if (!zr || !zu) {
        fprintf(stderr, "dense: out of memory\n");
        return 1;
    }
    for (size_t i = 0; i < nt; i++)
        if (mt[i] >= 0) {
            double v = (mp_table_get(&C, (size_t)mt[i], ce) - mp_table_get(&T, i, te)) /
                       mp_table_get(&C, (size_t)mt[i], cs);
            int resolved = 1;
            for (size_t k = 0; k < nt && resolved; k++)
                resolved = mt[k] >= 0 ||
                           !(hypot(mp_table_get(&T, i, tx) - mp_table_get(&T, k, tx),
                                   mp_table_get(&T, i, ty) - mp_table_get(&T, k, ty)) < RESOLVED_PX);
            if (resolved)
                zr[nres] = v;
            else
                zu[nz - nres] = v;
            nres += (size_t)resolved;
            z[nz++] = v;
        }
    double rz = rsigma(z, nz), rres = rsigma(zr, nres);
    double mu = nz > nres ? mp_median_select(zu, nz - nres) : NAN;
    printf("| %s | %s | %zu | %zu | %zu | %.3f | %.3f (%zu) | %.2f (%zu) |", argv[4], argv[5], nc,
           nm, nc - nm, rz, rres, nres, mu, nz - nres);
    free(zr);
    free(zu);
    for (int m = -13; m <= -8; m++) {
        size_t nb = 0;
        for (size_t i = 0; i < nt; i++) {
            double mag = mp_table_get(&T, i, tm);
            if (mt[i] >= 0 && mag >= m && mag < m + 1) {
                double e = mp_table_get(&T, i, te);
                r[nb++] = (mp_table_get(&C, (size_t)mt[i], ce) - e) / e;
            }
        }
        printf(" %.4f |", rsigma(r, nb));
    }
    printf("\n");
    free(p);
    free(mt);
    free(mc);
    free(z);
    free(r);
    mp_table_free(&T);
    mp_table_free(&C);
    return 0;
}
