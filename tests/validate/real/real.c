/*
 * real.c — helpers for the real-frame part of `make validate` (issue 3):
 * the 47 Tuc ACS/HRC crop and the Spitzer GLIMPSE frame, reduced by
 * `matphot pipeline` in tests/validate/real/real.sh.
 *
 *   real gain IMAGE
 *       prints GAIN·EXPTIME/FLUXCONV of IMAGE's header: electrons per
 *       (MJy/sr) of a Spitzer mosaic (1 MJy/sr = 1/FLUXCONV DN/s).
 *   real stamp IMAGE X0 Y0 N OUT
 *       writes the N×N pixels from (X0, Y0) (1-based, lower left) of IMAGE
 *       (a cfitsio extended name) as a text matrix for gnuplot, rows of
 *       increasing y; NaN as "nan"; prints the stamp's median and robust σ.
 *   real noise RES SKYCOL CAT
 *       robust statistics of a residual image (electrons): median and
 *       robust σ (IQR/1.349) of its pixels against the median sky of the
 *       catalog (SKY_PSF): prints "median rsigma sqrt(sky) sky".
 *   real summary CAT
 *       markdown lines on stdout: rows, median CHI2_PSF, median
 *       FLUXERR_PSF/FLUXERR_MODEL and ERRX_PSF/POSERR_MODEL, FLAGS bits,
 *       sky positions present.
 *   real glimpse CAT CSV GAIN OUT
 *       the GLIMPSE comparison: OUT.md (markdown), OUT_pos.dat,
 *       OUT_flux.dat; a one-line summary on stdout.
 */
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "catalog/catalog.h"
#include "io/io.h"

/* (1.2")² in sr, and MJy → mJy: the MANIFEST's conversion. */
#define PIXSR 3.385e-11
#define MATCH_R 2.0            /* [px] */
#define BLEND_R 1.5            /* [px]: ≈ 1 FWHM of IRAC ch2 (1.72″) on 1.2″ pixels */
#define OUTLIER 5.0            /* robust σ */

static int cmp_d(const void *a, const void *b)
{
    double x = *(const double *)a, y = *(const double *)b;
    return (x > y) - (x < y);
}

/* Quantile of the finite values among v[0..n) (v is reordered). */
static double quant(double *v, long n, double q)
{
    long m = 0;
    for (long i = 0; i < n; i++)
        if (isfinite(v[i]))
            v[m++] = v[i];
    if (m == 0)
        return NAN;
    qsort(v, (size_t)m, sizeof *v, cmp_d);
    double p = q * (double)(m - 1);
    long i = (long)floor(p);
    if (i >= m - 1)
        return v[m - 1];
    return v[i] + (p - (double)i) * (v[i + 1] - v[i]);
}

static double median(double *v, long n) { return quant(v, n, 0.5); }
static double rsigma(double *v, long n)
{
    double a = quant(v, n, 0.25), b = quant(v, n, 0.75);
    return (b - a) / 1.349;
}

static int col(const mp_table *t, const char *name, const char *file)
{
    int c = mp_table_col(t, name);
    if (c < 0)
        fprintf(stderr, "real: %s: no column %s\n", file, name);
    return c;
}

static int do_gain(const char *image)
{
    mp_image im;
    char err[MP_ERRLEN];
    memset(&im, 0, sizeof im);
    if (mp_image_read(image, &im, err)) {
        fprintf(stderr, "real: %s\n", err);
        return 1;
    }
    double g, t, fc;
    if (mp_header_double(&im, "GAIN", &g) || mp_header_double(&im, "EXPTIME", &t) ||
        mp_header_double(&im, "FLUXCONV", &fc) || !(fc > 0)) {
        fprintf(stderr, "real: %s: GAIN, EXPTIME or FLUXCONV missing\n", image);
        mp_image_free(&im);
        return 1;
    }
    printf("%.4f %g %g %g\n", g * t / fc, g, t, fc);
    mp_image_free(&im);
    return 0;
}

static int do_stamp(const char *image, long x0, long y0, long n, const char *out)
{
    mp_image im;
    char err[MP_ERRLEN];
    memset(&im, 0, sizeof im);
    if (mp_image_read(image, &im, err)) {
        fprintf(stderr, "real: %s\n", err);
        return 1;
    }
    FILE *f = fopen(out, "w");
    if (!f) {
        fprintf(stderr, "real: %s: cannot write\n", out);
        mp_image_free(&im);
        return 1;
    }
    for (long y = y0; y < y0 + n; y++) {
        for (long x = x0; x < x0 + n; x++) {
            double v = (x >= 1 && x <= im.nx && y >= 1 && y <= im.ny)
                       ? im.pix[(y - 1) * im.nx + (x - 1)] : NAN;
            fprintf(f, x > x0 ? " %.6g" : "%.6g", v);
        }
        fputc('\n', f);
    }
    fclose(f);
    /* median and robust sigma of the stamp, on stdout */
    double *v = malloc(sizeof(double) * (size_t)(n * n));
    if (!v) {
        mp_image_free(&im);
        return 1;
    }
    long k = 0;
    for (long y = y0; y < y0 + n; y++)
        for (long x = x0; x < x0 + n; x++)
            if (x >= 1 && x <= im.nx && y >= 1 && y <= im.ny)
                v[k++] = im.pix[(y - 1) * im.nx + (x - 1)];
    double med = median(v, k);
    double rs = rsigma(v, k);
    printf("%.6g %.6g\n", med, rs > 0 ? rs : 1.0);
    free(v);
    mp_image_free(&im);
    return 0;
}

static int do_noise(const char *res, const char *catpath)
{
    mp_image im;
    mp_table t;
    char err[MP_ERRLEN];
    memset(&im, 0, sizeof im);
    if (mp_image_read(res, &im, err) || mp_table_read(catpath, &t, err)) {
        fprintf(stderr, "real: %s\n", err);
        return 1;
    }
    int cs = col(&t, "SKY_PSF", catpath);
    if (cs < 0)
        return 1;
    long n = im.nx * im.ny;
    double *v = malloc(sizeof(double) * (size_t)(n > (long)t.nrow ? n : (long)t.nrow));
    if (!v)
        return 1;
    memcpy(v, im.pix, sizeof(double) * (size_t)n);
    double med = median(v, n);
    memcpy(v, im.pix, sizeof(double) * (size_t)n);
    double rs = rsigma(v, n);
    for (size_t i = 0; i < t.nrow; i++)
        v[i] = mp_table_get(&t, i, cs);
    double sky = median(v, (long)t.nrow);
    printf("%.4f %.4f %.4f %.4f\n", med, rs, sqrt(fmax(sky, 0)), sky);
    free(v);
    mp_image_free(&im);
    mp_table_free(&t);
    return 0;
}

static int do_summary(const char *catpath)
{
    mp_table t;
    char err[MP_ERRLEN];
    if (mp_table_read(catpath, &t, err)) {
        fprintf(stderr, "real: %s\n", err);
        return 1;
    }
    int cchi = col(&t, "CHI2_PSF", catpath), cef = col(&t, "FLUXERR_PSF", catpath);
    int cfm = col(&t, "FLUXERR_MODEL", catpath), cex = col(&t, "ERRX_PSF", catpath);
    int cpm = col(&t, "POSERR_MODEL", catpath), cfl = col(&t, "FLAGS", catpath);
    int cf = col(&t, "FLUX_PSF", catpath), cgs = col(&t, "GROUP_SIZE", catpath);
    if (cchi < 0 || cef < 0 || cfm < 0 || cex < 0 || cpm < 0 || cfl < 0 || cf < 0 || cgs < 0)
        return 1;
    int ca = mp_table_col(&t, "ALPHAPSF_J2000"), cd = mp_table_col(&t, "DELTAPSF_J2000");
    long n = (long)t.nrow;
    double *v = malloc(sizeof(double) * (size_t)(n + 1));
    if (!v)
        return 1;
    for (long i = 0; i < n; i++)
        v[i] = mp_table_get(&t, (size_t)i, cchi);
    double chi = median(v, n);
    double chq1 = quant(v, n, 0.25), chq3 = quant(v, n, 0.75);
    for (long i = 0; i < n; i++)
        v[i] = mp_table_get(&t, (size_t)i, cef) / mp_table_get(&t, (size_t)i, cfm);
    double fr = median(v, n);
    for (long i = 0; i < n; i++)
        v[i] = mp_table_get(&t, (size_t)i, cex) / mp_table_get(&t, (size_t)i, cpm);
    double pr = median(v, n);
    for (long i = 0; i < n; i++)
        v[i] = mp_table_get(&t, (size_t)i, cf) / mp_table_get(&t, (size_t)i, cef);
    double snr = median(v, n);
    for (long i = 0; i < n; i++)
        v[i] = mp_table_get(&t, (size_t)i, cgs);
    double gmax = quant(v, n, 1.0), gmed = median(v, n);
    /* Fits gone astray: huge reduced chi2, or a fitted position far from
     * the detection. */
    int cx0 = mp_table_col(&t, "X_IMAGE"), cy0 = mp_table_col(&t, "Y_IMAGE");
    int cxp = mp_table_col(&t, "XPSF_IMAGE"), cyp = mp_table_col(&t, "YPSF_IMAGE");
    long nchi10 = 0, nchi1e4 = 0, nmoved = 0, nnan = 0;
    for (long i = 0; i < n; i++) {
        double c = mp_table_get(&t, (size_t)i, cchi);
        nchi10 += c > 10;
        nchi1e4 += c > 1e4;
        nnan += !isfinite(c) || !isfinite(mp_table_get(&t, (size_t)i, cf));
        if (cx0 >= 0 && cy0 >= 0 && cxp >= 0 && cyp >= 0 &&
            hypot(mp_table_get(&t, (size_t)i, cxp) - mp_table_get(&t, (size_t)i, cx0),
                  mp_table_get(&t, (size_t)i, cyp) - mp_table_get(&t, (size_t)i, cy0)) > 3.0)
            nmoved++;
    }
    long bits[6] = {0}, nsky = 0;
    for (long i = 0; i < n; i++) {
        int fl = (int)mp_table_get(&t, (size_t)i, cfl);
        for (int b = 0; b < 6; b++)
            bits[b] += (fl >> b) & 1;
        if (ca >= 0 && cd >= 0 && isfinite(mp_table_get(&t, (size_t)i, ca)) &&
            isfinite(mp_table_get(&t, (size_t)i, cd)))
            nsky++;
    }
    printf("- Catalog: %ld stars; median CHI2_PSF %.3f (quartiles %.3f, %.3f); median "
           "FLUXERR_PSF/FLUXERR_MODEL %.3f; median ERRX_PSF/POSERR_MODEL %.3f; median "
           "S/N (FLUX_PSF/FLUXERR_PSF) %.1f; GROUP_SIZE median %.0f, largest %.0f.\n",
           n, chi, chq1, chq3, fr, pr, snr, gmed, gmax);
    printf("- Fits gone astray: CHI2_PSF > 10 for %ld stars, > 1e4 for %ld; fitted position more "
           "than 3 px from the detection (X_IMAGE, Y_IMAGE) for %ld; CHI2_PSF or FLUX_PSF not "
           "finite for %ld.\n", nchi10, nchi1e4, nmoved, nnan);
    printf("- FLAGS: saturated (1) %ld, split group (2) %ld, edge (4) %ld, not converged (8) "
           "%ld, merged (16) %ld, masked pixels (32) %ld.\n", bits[0], bits[1], bits[2],
           bits[3], bits[4], bits[5]);
    if (ca >= 0 && cd >= 0) {
        printf("- Sky positions: ALPHAPSF_J2000/DELTAPSF_J2000 finite for %ld of %ld stars", nsky, n);
        double amin = INFINITY, amax = -INFINITY, dmin = INFINITY, dmax = -INFINITY;
        for (long i = 0; i < n; i++) {
            double a = mp_table_get(&t, (size_t)i, ca), d = mp_table_get(&t, (size_t)i, cd);
            if (!isfinite(a) || !isfinite(d))
                continue;
            amin = fmin(amin, a);
            amax = fmax(amax, a);
            dmin = fmin(dmin, d);
            dmax = fmax(dmax, d);
        }
        if (nsky)
            printf(" (RA %.5f…%.5f°, Dec %.5f…%.5f°)", amin, amax, dmin, dmax);
        printf(".\n");
    } else {
        printf("- Sky positions: **no ALPHAPSF_J2000/DELTAPSF_J2000 columns**.\n");
    }
    free(v);
    mp_table_free(&t);
    return 0;
}

/* ---- GLIMPSE -------------------------------------------------------------- */

typedef struct { double x, y, f, df; } gstar;

static int read_csv(const char *path, gstar **out, int *n)
{
    FILE *f = fopen(path, "r");
    if (!f) {
        fprintf(stderr, "real: %s: cannot open\n", path);
        return 1;
    }
    char line[4096];
    int cap = 256, m = 0, ix = -1, iy = -1, iff = -1, idf = -1, header = 0;
    gstar *s = malloc(sizeof *s * (size_t)cap);
    if (!s) {
        fclose(f);
        return 1;
    }
    while (fgets(line, sizeof line, f)) {
        if (line[0] == '#' || line[0] == '\n')
            continue;
        char *fld[64];
        int nf = 0;
        for (char *p = strtok(line, ",\r\n"); p && nf < 64; p = strtok(NULL, ",\r\n"))
            fld[nf++] = p;
        if (!header) {
            for (int i = 0; i < nf; i++) {
                if (strcmp(fld[i], "x_fits") == 0) ix = i;
                if (strcmp(fld[i], "y_fits") == 0) iy = i;
                if (strcmp(fld[i], "f4_5_mJy") == 0) iff = i;
                if (strcmp(fld[i], "df4_5_mJy") == 0) idf = i;
            }
            if (ix < 0 || iy < 0 || iff < 0 || idf < 0) {
                fprintf(stderr, "real: %s: x_fits, y_fits, f4_5_mJy or df4_5_mJy missing\n", path);
                fclose(f);
                free(s);
                return 1;
            }
            header = 1;
            continue;
        }
        if (nf <= ix || nf <= iy || nf <= iff || nf <= idf)
            continue;
        if (m == cap) {
            cap *= 2;
            gstar *s2 = realloc(s, sizeof *s * (size_t)cap);
            if (!s2) {
                fclose(f);
                free(s);
                return 1;
            }
            s = s2;
        }
        s[m].x = atof(fld[ix]);
        s[m].y = atof(fld[iy]);
        s[m].f = atof(fld[iff]);
        s[m].df = atof(fld[idf]);
        m++;
    }
    fclose(f);
    *out = s;
    *n = m;
    return 0;
}

static int do_glimpse(const char *catpath, const char *csv, double gain, const char *out)
{
    mp_table t;
    char err[MP_ERRLEN], path[4096];
    if (mp_table_read(catpath, &t, err)) {
        fprintf(stderr, "real: %s\n", err);
        return 1;
    }
    int cx = col(&t, "XPSF_IMAGE", catpath), cy = col(&t, "YPSF_IMAGE", catpath);
    int cf = col(&t, "FLUX_PSF", catpath), cef = col(&t, "FLUXERR_PSF", catpath);
    int cfl = col(&t, "FLAGS", catpath), cchi = col(&t, "CHI2_PSF", catpath);
    int cex = col(&t, "ERRX_PSF", catpath), cey = col(&t, "ERRY_PSF", catpath);
    if (cx < 0 || cy < 0 || cf < 0 || cef < 0 || cfl < 0 || cchi < 0 || cex < 0 || cey < 0)
        return 1;
    gstar *g;
    int ng;
    if (read_csv(csv, &g, &ng))
        return 1;
    long nc = (long)t.nrow;
    int *m = malloc(sizeof(int) * (size_t)ng);
    double *dx = malloc(sizeof(double) * (size_t)ng), *dy = malloc(sizeof(double) * (size_t)ng);
    double *v = malloc(sizeof(double) * (size_t)ng), *lr = malloc(sizeof(double) * (size_t)ng);
    double *dmin2 = malloc(sizeof(double) * (size_t)ng);
    if (!m || !dx || !dy || !v || !lr || !dmin2)
        return 1;

    /* Match within MATCH_R of the shifted GLIMPSE position (nearest entry);
     * the shift = median offset of the matches (ours − GLIMPSE), iterated
     * from zero until it stops changing. */
    double sx = 0, sy = 0;
    int nm = 0, iter;
    for (iter = 0; iter < 20; iter++) {
        nm = 0;
        for (int i = 0; i < ng; i++) {
            double best = INFINITY;
            int bj = -1;
            for (long j = 0; j < nc; j++) {
                double d = hypot(mp_table_get(&t, (size_t)j, cx) - (g[i].x + sx),
                                 mp_table_get(&t, (size_t)j, cy) - (g[i].y + sy));
                if (d < best) {
                    best = d;
                    bj = (int)j;
                }
            }
            m[i] = best <= MATCH_R ? bj : -1;
            if (m[i] >= 0) {
                dx[nm] = mp_table_get(&t, (size_t)m[i], cx) - g[i].x;
                dy[nm] = mp_table_get(&t, (size_t)m[i], cy) - g[i].y;
                nm++;
            }
        }
        memcpy(v, dx, sizeof(double) * (size_t)nm);
        double nsx = median(v, nm);
        memcpy(v, dy, sizeof(double) * (size_t)nm);
        double nsy = median(v, nm);
        int same = fabs(nsx - sx) < 1e-6 && fabs(nsy - sy) < 1e-6;
        sx = nsx;
        sy = nsy;
        if (same)
            break;
    }
    /* Residuals after the shift. */
    int k = 0;
    double *rx = malloc(sizeof(double) * (size_t)ng), *ry = malloc(sizeof(double) * (size_t)ng);
    double *nrx = malloc(sizeof(double) * (size_t)ng), *nry = malloc(sizeof(double) * (size_t)ng);
    if (!rx || !ry || !nrx || !nry)
        return 1;
    for (int i = 0; i < ng; i++) {
        if (m[i] < 0)
            continue;
        rx[k] = mp_table_get(&t, (size_t)m[i], cx) - g[i].x - sx;
        ry[k] = mp_table_get(&t, (size_t)m[i], cy) - g[i].y - sy;
        nrx[k] = rx[k] / mp_table_get(&t, (size_t)m[i], cex);
        nry[k] = ry[k] / mp_table_get(&t, (size_t)m[i], cey);
        k++;
    }
    memcpy(v, rx, sizeof(double) * (size_t)k);
    double rsx = rsigma(v, k);
    memcpy(v, ry, sizeof(double) * (size_t)k);
    double rsy = rsigma(v, k);
    for (int i = 0; i < k; i++)
        v[i] = hypot(rx[i], ry[i]);
    double rmed = median(v, k);
    memcpy(v, nrx, sizeof(double) * (size_t)k);
    double nrsx = rsigma(v, k);
    memcpy(v, nry, sizeof(double) * (size_t)k);
    double nrsy = rsigma(v, k);
    /* Expected from our own errors alone (median ERRX_PSF) */
    k = 0;
    for (int i = 0; i < ng; i++)
        if (m[i] >= 0)
            v[k++] = mp_table_get(&t, (size_t)m[i], cex);
    double medex = median(v, k);

    /* Fluxes: FLUX_PSF [e-] / gain [e- per MJy/sr] = Σ MJy/sr over the PRF;
     * × PIXSR sr × 1e9 = mJy.  Scale = median of ours/GLIMPSE. */
    k = 0;
    for (int i = 0; i < ng; i++) {
        if (m[i] < 0)
            continue;
        double fm = mp_table_get(&t, (size_t)m[i], cf) / gain * PIXSR * 1e9;
        lr[k++] = log(fm / g[i].f);
    }
    memcpy(v, lr, sizeof(double) * (size_t)k);
    double lscale = median(v, k);
    memcpy(v, lr, sizeof(double) * (size_t)k);
    double lrs = rsigma(v, k);
    /* The same with our fluxes summed within BLEND_R of the shifted
     * GLIMPSE position: pairs closer than GLIMPSE's resolution are one
     * source in its catalog. */
    int kb = 0, nblend = 0;
    for (int i = 0; i < ng; i++) {
        if (m[i] < 0)
            continue;
        double fsum = 0.0;
        int nin = 0;
        for (long j = 0; j < nc; j++)
            if (hypot(mp_table_get(&t, (size_t)j, cx) - (g[i].x + sx),
                      mp_table_get(&t, (size_t)j, cy) - (g[i].y + sy)) <= BLEND_R) {
                fsum += mp_table_get(&t, (size_t)j, cf);
                nin++;
            }
        if (nin == 0)   /* the match itself lies between BLEND_R and MATCH_R */
            fsum = mp_table_get(&t, (size_t)m[i], cf);
        nblend += nin > 1;
        v[kb++] = log(fsum / gain * PIXSR * 1e9 / g[i].f);
    }
    double bscale = median(v, kb);
    for (int i = 0; i < kb; i++)
        v[i] -= bscale;
    double brs = rsigma(v, kb);
    /* Expected scatter from the two catalogs' own errors. */
    k = 0;
    for (int i = 0; i < ng; i++)
        if (m[i] >= 0)
            v[k++] = hypot(g[i].df / g[i].f, mp_table_get(&t, (size_t)m[i], cef) /
                                             mp_table_get(&t, (size_t)m[i], cf));
    double experr = median(v, k);
    k = 0;
    for (int i = 0; i < ng; i++)
        if (m[i] >= 0)
            v[k++] = g[i].df / g[i].f;
    double gerr = median(v, k);

    snprintf(path, sizeof path, "%s_pos.dat", out);
    FILE *fp = fopen(path, "w");
    snprintf(path, sizeof path, "%s_flux.dat", out);
    FILE *ff = fopen(path, "w");
    snprintf(path, sizeof path, "%s.md", out);
    FILE *md = fopen(path, "w");
    if (!fp || !ff || !md) {
        fprintf(stderr, "real: %s: cannot write\n", out);
        return 1;
    }
    fprintf(fp, "# x_glimpse y_glimpse dx dy (ours - GLIMPSE - shift) outlier\n");
    fprintf(ff, "# f4_5_mJy ours_mJy_scaled ratio outlier\n");
    int npos_out = 0, nflux_out = 0;
    k = 0;
    fprintf(md, "- Matched %d of the %d GLIMPSE stars within %.1f px of the shifted GLIMPSE "
            "position (nearest catalog entry; the shift iterated to convergence in %d "
            "steps).\n", nm, ng, MATCH_R, iter + 1);
    fprintf(md, "- **Shift** (ours − GLIMPSE, median of the matches): **(%+.3f, %+.3f) px** "
            "(MANIFEST, 2-D Gaussian centroids: about (+0.13, +0.29)).\n", sx, sy);
    fprintf(md, "- **Position scatter** after the shift: robust σ (IQR/1.349) %.3f px in x, "
            "%.3f px in y; median radial offset %.3f px; median ERRX_PSF of the matches %.4f px; "
            "robust σ of the offsets over our ERRX/ERRY_PSF %.2f, %.2f (GLIMPSE's own position "
            "errors are not in the subset, so this ratio is an upper bound on ours).\n",
            rsx, rsy, rmed, medex, nrsx, nrsy);
    fprintf(md, "- **Flux scale** (median of FLUX_PSF/gain × %.4g sr × 1e9 mJy over f4_5): "
            "**%.4f**; scatter: robust σ of ln(ratio) **%.4f** (%.3f mag); expected from the "
            "two catalogs' quoted errors (median, in quadrature) %.4f, GLIMPSE's df4_5/f4_5 "
            "alone %.4f.\n", PIXSR, exp(lscale), lrs, 1.0857 * lrs, experr, gerr);
    fprintf(md, "- **Blends**: %d of the matched GLIMPSE stars have more than one of our stars "
            "within %.1f px (≈ 1 FWHM, GLIMPSE's resolution); with our fluxes summed there the "
            "flux scale is **%.4f** and the robust σ of ln(ratio) **%.4f** (%.3f mag).\n",
            nblend, BLEND_R, exp(bscale), brs, 1.0857 * brs);
    fprintf(md, "\nOutliers (> %.0f robust σ: position in either axis after the shift, or "
            "ln flux ratio after the scale):\n\n| x_fits | y_fits | f4_5 [mJy] | ours [mJy] "
            "(after scale) | dx, dy [px] | flux σ | FLAGS | CHI2_PSF | why |\n"
            "|---:|---:|---:|---:|---|---:|---:|---:|---|\n", OUTLIER);
    for (int i = 0; i < ng; i++) {
        if (m[i] < 0)
            continue;
        double x = mp_table_get(&t, (size_t)m[i], cx) - g[i].x - sx;
        double y = mp_table_get(&t, (size_t)m[i], cy) - g[i].y - sy;
        double fm = mp_table_get(&t, (size_t)m[i], cf) / gain * PIXSR * 1e9 / exp(lscale);
        double ns = (log(fm / g[i].f)) / lrs;
        int po = fabs(x) > OUTLIER * rsx || fabs(y) > OUTLIER * rsy;
        int fo = fabs(ns) > OUTLIER;
        npos_out += po;
        nflux_out += fo;
        fprintf(fp, "%.3f %.3f %.4f %.4f %d\n", g[i].x, g[i].y, x, y, po);
        fprintf(ff, "%.3f %.3f %.4f %d\n", g[i].f, fm, fm / g[i].f, fo);
        if (po || fo)
            fprintf(md, "| %.2f | %.2f | %.1f | %.1f | %+.3f, %+.3f | %+.1f | %d | %.2f | %s |\n",
                    g[i].x, g[i].y, g[i].f, fm, x, y, ns,
                    (int)mp_table_get(&t, (size_t)m[i], cfl), mp_table_get(&t, (size_t)m[i], cchi),
                    po && fo ? "position, flux" : po ? "position" : "flux");
    }
    fprintf(md, "\n%d position outliers, %d flux outliers among %d matches.\n", npos_out,
            nflux_out, nm);
    fprintf(md, "\nNot matched (no catalog entry within %.1f px after the shift):", MATCH_R);
    int nun = 0;
    for (int i = 0; i < ng; i++)
        if (m[i] < 0) {
            /* nearest entry */
            double best = INFINITY;
            for (long j = 0; j < nc; j++)
                best = fmin(best, hypot(mp_table_get(&t, (size_t)j, cx) - (g[i].x + sx),
                                        mp_table_get(&t, (size_t)j, cy) - (g[i].y + sy)));
            fprintf(md, "%s (%.2f, %.2f; %.1f mJy; nearest entry %.2f px)", nun ? "," : "",
                    g[i].x, g[i].y, g[i].f, best);
            nun++;
        }
    fprintf(md, "%s\n", nun ? "." : " none.");
    fclose(fp);
    fclose(ff);
    fclose(md);
    printf("glimpse: %d/%d matched; shift (%+.3f, %+.3f) px; pos rsigma (%.3f, %.3f) px; "
           "flux scale %.4f, ln-ratio rsigma %.4f; outliers %d pos, %d flux; blends %d: "
           "summed within %.1f px, scale %.4f, rsigma %.4f\n", nm, ng, sx, sy,
           rsx, rsy, exp(lscale), lrs, npos_out, nflux_out, nblend, BLEND_R, exp(bscale), brs);
    free(g);
    free(m);
    free(dx);
    free(dy);
    free(v);
    free(lr);
    free(dmin2);
    free(rx);
    free(ry);
    free(nrx);
    free(nry);
    mp_table_free(&t);
    return 0;
}

int main(int argc, char **argv)
{
    if (argc == 3 && strcmp(argv[1], "gain") == 0)
        return do_gain(argv[2]);
    if (argc == 7 && strcmp(argv[1], "stamp") == 0)
        return do_stamp(argv[2], atol(argv[3]), atol(argv[4]), atol(argv[5]), argv[6]);
    if (argc == 4 && strcmp(argv[1], "noise") == 0)
        return do_noise(argv[2], argv[3]);
    if (argc == 3 && strcmp(argv[1], "summary") == 0)
        return do_summary(argv[2]);
    if (argc == 6 && strcmp(argv[1], "glimpse") == 0)
        return do_glimpse(argv[2], argv[3], atof(argv[4]), argv[5]);
    fprintf(stderr, "usage: real gain IMAGE | real stamp IMAGE X0 Y0 N OUT | "
            "real noise RES CAT | real summary CAT | real glimpse CAT CSV GAIN OUT\n");
    return 2;
}
