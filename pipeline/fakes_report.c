/* fakes_report.c — what `matphot fakes` writes: the table of fakes, the
 * report (completeness with its binomial error, bias and error against
 * magnitude and against crowding) and its figure (gnuplot, when there). */
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include "pipeline/fakes_priv.h"

static int add_col(mp_table *t, const char *name, const char *fmt, int is_int, const char *desc,
                   const char *unit)
{
    int c = mp_table_add_col(t, name);
    if (c < 0)
        return -1;
    if (!t->cols[c].desc[0]) {
        snprintf(t->cols[c].fmt, sizeof t->cols[c].fmt, "%s", fmt);
        snprintf(t->cols[c].desc, sizeof t->cols[c].desc, "%s", desc);
        snprintf(t->cols[c].unit, sizeof t->cols[c].unit, "%s", unit);
        t->cols[c].is_int = is_int;
    }
    return c;
}

int mp_fakes_write_table(const char *path, const mp_fake *fk, long n, char *err)
{
    mp_table t;
    mp_table_init(&t);
    int c[11] = {
        add_col(&t, "NUMBER", "%8.0f", 1, "Fake star number (fake k of the whole run)", ""),
        add_col(&t, "X_TRUE", "%11.4f", 0, "Injected x position", "pixel"),
        add_col(&t, "Y_TRUE", "%11.4f", 0, "Injected y position", "pixel"),
        add_col(&t, "MAG_TRUE", "%9.4f", 0, "Injected magnitude", "mag"),
        add_col(&t, "FOUND", "%2.0f", 1, "1: a fitted star within fakerad, nearer it than any frame star", ""),
        add_col(&t, "XPSF_IMAGE", "%11.4f", 0, "X coordinate from PSF-fitting", "pixel"),
        add_col(&t, "YPSF_IMAGE", "%11.4f", 0, "Y coordinate from PSF-fitting", "pixel"),
        add_col(&t, "MAG_PSF", "%9.4f", 0, "Magnitude from PSF-fitting", "mag"),
        add_col(&t, "MAGERR_PSF", "%9.4f", 0, "RMS magnitude error from PSF-fitting", "mag"),
        add_col(&t, "FLAGS", "%4.0f", 1, "Fit flags of the star found", ""),
        add_col(&t, "NN_DIST", "%9.3f", 0, "Distance to the nearest star of the frame", "pixel"),
    };
    int rc = 0;
    for (int j = 0; j < 11; j++)
        rc |= c[j] < 0;
    for (long i = 0; !rc && i < n; i++) {
        long r = mp_table_add_row(&t);
        if (r < 0) {
            rc = 1;
            break;
        }
        const mp_fake *k = &fk[i];
        double v[11] = {(double)k->number, k->x, k->y, k->mag, k->found, k->xf, k->yf, k->magf,
                        k->emag, k->found ? k->flags : NAN, k->nn};
        for (int j = 0; j < 11; j++)
            mp_table_set(&t, (size_t)r, c[j], v[j]);
    }
    if (rc)
        snprintf(err, MP_ERRLEN, "out of memory");
    else
        rc = mp_table_write(path, &t, MP_TAB_ASCII_HEAD, err);
    mp_table_free(&t);
    return rc;
}

/* ---- statistics of a bin ------------------------------------------------ */

static int cmp_d(const void *a, const void *b)
{
    double x = *(const double *)a, y = *(const double *)b;
    return (x > y) - (x < y);
}

static double quant(double *v, int n, double q)
{
    if (n <= 0)
        return NAN;
    qsort(v, (size_t)n, sizeof *v, cmp_d);
    double p = q * (n - 1);
    int i = (int)floor(p);
    return i >= n - 1 ? v[n - 1] : v[i] + (p - i) * (v[i + 1] - v[i]);
}

typedef struct {
    int n, found;
    double c, ec;            /* completeness, binomial σ */
    double bias, rs;         /* median and IQR/1.349 of MAG_PSF − MAG_TRUE */
    double emed, nrs;        /* median MAGERR_PSF; IQR/1.349 of Δmag/MAGERR_PSF */
} bin_stat;

/* Statistics of the fakes with lo ≤ key < hi; buf holds n doubles. */
static bin_stat stat_of(const mp_fake *fk, long n, const double *key, double lo, double hi,
                        double *buf)
{
    bin_stat s = {0};
    int m = 0;
    for (long i = 0; i < n; i++)
        if (key[i] >= lo && key[i] < hi) {
            s.n++;
            s.found += fk[i].found;
        }
    s.c = s.n ? (double)s.found / s.n : NAN;
    s.ec = s.n ? sqrt(s.c * (1 - s.c) / s.n) : NAN;
    for (int w = 0; w < 3; w++) {
        m = 0;
        for (long i = 0; i < n; i++) {
            if (!(key[i] >= lo && key[i] < hi) || !fk[i].found || !isfinite(fk[i].magf))
                continue;
            double d = fk[i].magf - fk[i].mag;
            buf[m++] = w == 0 ? d : w == 1 ? fk[i].emag : d / fk[i].emag;
        }
        if (w == 0) {
            s.bias = quant(buf, m, 0.5);
            s.rs = (quant(buf, m, 0.75) - quant(buf, m, 0.25)) / 1.349;
        } else if (w == 1) {
            s.emed = quant(buf, m, 0.5);
        } else {
            s.nrs = (quant(buf, m, 0.75) - quant(buf, m, 0.25)) / 1.349;
        }
    }
    return s;
}

static void row(FILE *fp, const char *label, const bin_stat *s)
{
    fprintf(fp, "| %s | %d | %d | %.3f ± %.3f | %+.4f | %.4f | %.4f | %.3f |\n", label, s->n,
            s->found, s->c, s->ec, s->bias, s->rs, s->emed, s->nrs);
}

static const char *HEAD =
    "| fakes | found | completeness ± σ | median Δmag | rσ Δmag | median MAGERR_PSF | rσ Δmag/MAGERR_PSF |\n";

#define MAGSTEP 0.5
static const double NNEDGE[] = {0, 0.5, 1.0, 1.5, 2.0, 3.0, INFINITY};   /* [FWHM] */
#define NNN 6

static int write_md(FILE *fp, FILE *dat, const char *image, const mp_fakes_opts *fo, long lo,
                    long hi, const mp_fake *fk, double *key, double *buf)
{
    long n = hi - lo;
    long nf = 0;
    for (long i = 0; i < n; i++)
        nf += fk[i].found;
    fprintf(fp, "# matphot fakes: %s\n\n", image);
    fprintf(fp, "Fakes %ld..%ld of %ld (seed %llu), magnitudes uniform in [%.3f, %.3f], "
            "positions uniform over the frame; each added with its photon noise to its own "
            "copy of the %ld×%ld px box around it, the box reduced by the pipeline, the fake "
            "found when a fitted star lies within %.2f px of it and nearer to it than to any "
            "star of the frame's own reduction.  **%ld of %ld found (%.4f).**\n\n",
            lo + 1, hi, fo->nfake, (unsigned long long)fo->seed, fo->magmin, fo->magmax,
            fo->box, fo->box, fo->fakerad, nf, n, n ? (double)nf / n : NAN);
    fprintf(fp, "## Against magnitude\n\n| mag |%s|---:|---:|---:|---:|---:|---:|---:|---:|\n",
            HEAD + 1);
    fprintf(dat, "# mag completeness sigma bias rsig_dmag rsig_norm n\n");
    for (long i = 0; i < n; i++)
        key[i] = fk[i].mag;
    for (double m0 = fo->magmin; m0 < fo->magmax - 1e-9; m0 += MAGSTEP) {
        double m1 = fmin(m0 + MAGSTEP, fo->magmax + 1e-9);
        bin_stat s = stat_of(fk, n, key, m0, m1, buf);
        char lab[64];
        snprintf(lab, sizeof lab, "%.2f – %.2f", m0, m1);
        row(fp, lab, &s);
        fprintf(dat, "%.4f %.5f %.5f %.5f %.5f %.5f %d\n", 0.5 * (m0 + m1), s.c, s.ec, s.bias,
                s.rs, s.nrs, s.n);
    }
    fprintf(fp, "\n## Against crowding\n\nBy the distance from the fake to the nearest star of "
            "the frame's own reduction, in FWHM (%.2f px).\n\n| nearest star [FWHM] |%s"
            "|---|---:|---:|---:|---:|---:|---:|---:|\n", fo->fwhm, HEAD + 1);
    for (long i = 0; i < n; i++)
        key[i] = fk[i].nn / fo->fwhm;
    for (int b = 0; b < NNN; b++) {
        bin_stat s = stat_of(fk, n, key, NNEDGE[b], NNEDGE[b + 1], buf);
        char lab[64];
        if (isfinite(NNEDGE[b + 1]))
            snprintf(lab, sizeof lab, "%.1f – %.1f", NNEDGE[b], NNEDGE[b + 1]);
        else
            snprintf(lab, sizeof lab, "≥ %.1f", NNEDGE[b]);
        row(fp, lab, &s);
    }
    return ferror(fp) || ferror(dat);
}

/* The figure: completeness and bias ± rσ against magnitude. */
static int plot(const char *dat, const char *png, char *err)
{
    if (system("command -v gnuplot > /dev/null 2>&1") != 0)
        return 2;
    size_t n = strlen(png) + 8;
    char *tmp = malloc(n);
    if (!tmp) {
        snprintf(err, MP_ERRLEN, "out of memory");
        return 1;
    }
    snprintf(tmp, n, "%s.tmp", png);
    FILE *gp = popen("gnuplot 2> /dev/null", "w");
    if (!gp) {
        free(tmp);
        return 2;
    }
    fprintf(gp, "set terminal pngcairo size 900,380 font ',9'\nset output '%s'\n"
            "set multiplot layout 1,2\nset grid\nset xlabel 'injected magnitude'\n"
            "set title 'Artificial stars: completeness'\nset ylabel 'fraction found'\n"
            "set yrange [0:1.05]\nplot '%s' u 1:2:3 w yerrorlines t 'fakes'\n"
            "set title 'Artificial stars: MAG_PSF - MAG_TRUE'\nset ylabel 'median, +- robust sigma [mag]'\n"
            "set yrange [*:*]\nplot '%s' u 1:4:5 w yerrorlines t 'bias +- rsigma'\n"
            "unset multiplot\n", tmp, dat, dat);
    int rc = pclose(gp);
    if (rc == 0 && mp_out_place(tmp, png, NULL) == 0) {
        free(tmp);
        return 0;
    }
    remove(tmp);
    free(tmp);
    return 2;
}

int mp_fakes_write_report(const char *root, const char *image, const mp_fakes_opts *fo,
                          long lo, long hi, const mp_fake *fk, char *err)
{
    char *md = mp_name_after(root, ".fakes.md"), *dat = mp_name_after(root, ".fakes.dat");
    char *png = mp_name_after(root, ".fakes.png");
    long n = hi - lo;
    double *key = malloc(((size_t)n + 1) * sizeof *key), *buf = malloc(((size_t)n + 1) * sizeof *buf);
    mp_outfile om = {0}, od = {0};
    int rc = 1;
    if (!md || !dat || !png || !key || !buf) {
        snprintf(err, MP_ERRLEN, "out of memory");
        goto done;
    }
    if (mp_out_open(&om, md, err))
        goto done;
    if (mp_out_open(&od, dat, err)) {
        mp_out_abort(&om);
        goto done;
    }
    if (write_md(om.fp, od.fp, image, fo, lo, hi, fk, key, buf)) {
        snprintf(err, MP_ERRLEN, "%s: write error", md);
        mp_out_abort(&om);
        mp_out_abort(&od);
        goto done;
    }
    if (mp_out_commit(&od, err)) {
        mp_out_abort(&om);
        goto done;
    }
    int p = plot(dat, png, err);
    if (p == 1) {
        mp_out_abort(&om);
        goto done;
    }
    const char *base = strrchr(png, '/');
    if (p == 0)
        fprintf(om.fp, "\n![fakes](%s)\n", base ? base + 1 : png);
    else
        fprintf(om.fp, "\n(No figure: gnuplot is missing or failed.)\n");
    rc = mp_out_commit(&om, err);
done:
    free(md);
    free(dat);
    free(png);
    free(key);
    free(buf);
    return rc;
}
