/*
 * plot.c — per-star data files and the paper-style figures (gnuplot).
 *
 * Every file written here ends in .dat (ignored by git) or .png.  Figure:
 * top |Δmag| vs true magnitude, bottom Δr vs true magnitude, one
 * box-and-whisker per 1-mag bin as in the paper's Appendix A (box = hinges,
 * whiskers to the last datum inside the fences UH + 1.5·IQR / LH − 1.5·IQR,
 * outliers as points, median bar), with the performance model's median,
 * top hinge, top fence (grey band between the two) and 5σ-outlier curves,
 * and the CRLB's expected median per bin (red ×).
 */
#include <math.h>
#include <stdarg.h>
#include <stdlib.h>
#include <string.h>
#include "tests/validate/vt.h"

static int cmp_double(const void *a, const void *b)
{
    double x = *(const double *)a, y = *(const double *)b;
    return (x > y) - (x < y);
}

static FILE *open_out(const char *dir, const char *id, const char *suffix, char *path,
                      size_t len, char *err)
{
    snprintf(path, len, "%s/%s%s", dir, id, suffix);
    FILE *fp = fopen(path, "w");
    if (!fp)
        snprintf(err, MP_ERRLEN, "%.400s: cannot write", path);
    return fp;
}

int vt_write_data(const char *dir, const vt_result *r, char *err)
{
    char path[4096];
    FILE *fp = open_out(dir, r->c->id, ".dat", path, sizeof path, err);
    if (!fp)
        return 1;
    fprintf(fp, "# %s: %s\n# seed of star k = %llu + k; fitted table offset %.4f px "
            "(applied by the engine: positions are the star's)\n", r->c->id, r->c->title,
            (unsigned long long)r->seed0, r->shift_px);
    fprintf(fp, "# k mag_true E_true X_true Y_true E X Y sigE sigX sigY sky chi2_red dof niter "
            "flags rc sigE_model sigX_model sigE_crlb sigX_crlb sigY_crlb beta volume L "
            "volume_fit cpu_s\n");
    for (int k = 0; k < r->n; k++) {
        const vt_star *s = &r->s[k];
        fprintf(fp, "%d %.6f %.6f %.6f %.6f %.6f %.6f %.6f %.6g %.6g %.6g %.5f %.6f %d %d %d %d "
                "%.6g %.6g %.6g %.6g %.6g %.5f %.6f %.5f %.6f %.6g\n",
                k, s->mag, s->e_true, s->x_true, s->y_true, s->e, s->x, s->y, s->ee, s->ex,
                s->ey, s->sky, s->chi2, s->dof, s->niter, s->flags, s->rc, s->se_model,
                s->sx_model, s->se_crlb, s->sx_crlb, s->sy_crlb, s->beta, s->volume,
                s->lscale, s->vol_fit, s->cpu);
    }
    if (fclose(fp)) {
        snprintf(err, MP_ERRLEN, "%.400s: write failed", path);
        return 1;
    }
    return 0;
}

/* Box of sorted v: lh, med, uh, bottom and top whisker; outliers to fp. */
static void box_of(const double *v, size_t n, double x, double out[5], FILE *fo, double *vmax)
{
    double lh = vt_quantile_sorted(v, n, 0.25), md = vt_quantile_sorted(v, n, 0.5);
    double uh = vt_quantile_sorted(v, n, 0.75), st = 1.5 * (uh - lh);
    double tf = uh + st, bf = lh - st, tw = lh, bw = uh;
    for (size_t i = 0; i < n; i++) {
        if (v[i] >= bf && v[i] < bw)
            bw = v[i];
        if (v[i] <= tf && v[i] > tw)
            tw = v[i];
        if (v[i] > tf || v[i] < bf)
            fprintf(fo, "%.3f %.6g\n", x, v[i]);
    }
    if (n && v[n - 1] > *vmax)
        *vmax = v[n - 1];
    out[0] = lh;
    out[1] = md;
    out[2] = uh;
    out[3] = bw;
    out[4] = tw;
}

/* The model's σ_mag and σ_X at intensity E with a bin's mean PRF. */
static void model_at(const vt_bin *b, double E, double sky, double *smag, double *sx)
{
    mp_prf_stats st;
    st.volume = b->volume;
    st.beta = b->beta;
    st.lscale = b->lscale;
    st.sharp = 1.0 / (4.0 * M_PI * b->lscale * b->lscale);
    double se;
    mp_perf_model(&st, E, sky, VT_RON, VT_NPIX, &se, sx);
    *smag = 1.0857 * se / E;
}

static int run_gnuplot(const char *script, char *err)
{
    FILE *gp = popen("gnuplot", "w");
    if (!gp) {
        snprintf(err, MP_ERRLEN, "gnuplot: cannot start");
        return 1;
    }
    fputs(script, gp);
    int st = pclose(gp);
    if (st != 0) {
        snprintf(err, MP_ERRLEN, "gnuplot failed (status %d)", st);
        return 1;
    }
    return 0;
}

/* Growable string for the script. */
typedef struct { char *s; size_t n, cap; int bad; } sbuf;

static void sb_printf(sbuf *b, const char *fmt, ...) __attribute__((format(printf, 2, 3)));

static void sb_printf(sbuf *b, const char *fmt, ...)
{
    if (b->bad)
        return;
    for (;;) {
        va_list ap;
        va_start(ap, fmt);
        int k = vsnprintf(b->s ? b->s + b->n : NULL, b->s ? b->cap - b->n : 0, fmt, ap);
        va_end(ap);
        if (k < 0) {
            b->bad = 1;
            return;
        }
        if (b->s && b->n + (size_t)k < b->cap) {
            b->n += (size_t)k;
            return;
        }
        size_t nc = (b->cap ? 2 * b->cap : 4096) + (size_t)k;
        char *t = realloc(b->s, nc);
        if (!t) {
            b->bad = 1;
            return;
        }
        b->s = t;
        b->cap = nc;
    }
}

static int plot_hist(const char *dir, const vt_result *r, const char *term, char *err)
{
    /* Paper Fig. 20: observed (E·V at the fitted position) and measured
     * magnitudes of the fixed-magnitude stars. */
    char path[4096], png[4096];
    FILE *fp = open_out(dir, r->c->id, "_hist.dat", path, sizeof path, err);
    if (!fp)
        return 1;
    for (int pass = 0; pass < 2; pass++) {
        double lo = INFINITY, hi = -INFINITY;
        double *v = malloc((size_t)r->n * sizeof *v);
        if (!v) {
            fclose(fp);
            snprintf(err, MP_ERRLEN, "out of memory");
            return 1;
        }
        int m = 0;
        for (int k = 0; k < r->n; k++) {
            const vt_star *s = &r->s[k];
            double e = pass ? s->e : s->e * s->vol_fit;
            if (e > 0)
                v[m++] = -2.5 * log10(e);
        }
        for (int k = 0; k < m; k++) {
            lo = fmin(lo, v[k]);
            hi = fmax(hi, v[k]);
        }
        int nb = 60;
        double w = (hi - lo) / nb;
        if (!(w > 0))
            w = 1e-3;
        int *h = calloc((size_t)nb + 1, sizeof *h);
        if (!h) {
            free(v);
            fclose(fp);
            snprintf(err, MP_ERRLEN, "out of memory");
            return 1;
        }
        for (int k = 0; k < m; k++)
            h[(int)((v[k] - lo) / w) > nb - 1 ? nb - 1 : (int)((v[k] - lo) / w)]++;
        fprintf(fp, "# %s magnitude histogram\n", pass ? "measured" : "observed");
        for (int i = 0; i < nb; i++)
            fprintf(fp, "%.6f %d\n", lo + (i + 0.5) * w, h[i]);
        fprintf(fp, "\n\n");
        free(h);
        free(v);
    }
    fclose(fp);
    snprintf(png, sizeof png, "%s/%s.png", dir, r->c->id);
    sbuf b = {0};
    sb_printf(&b, "set terminal %s size 800,450 font ',9'\nset output '%s'\n", term, png);
    sb_printf(&b, "set multiplot layout 1,2 title '%s: %d stars at %.0f mag'\n", r->c->name,
              r->n, r->c->mag_lo);
    sb_printf(&b, "set style fill solid 0.4\nset ylabel 'stars'\nunset key\n");
    sb_printf(&b, "set xlabel 'observed magnitude (E V at the fitted position)'\n"
              "plot '%s' index 0 using 1:2 with boxes lc 'gray40'\n", path);
    sb_printf(&b, "set xlabel 'measured magnitude'\nset xtics rotate by -30\n"
              "plot '%s' index 1 using 1:2 with boxes lc 'black'\nunset multiplot\n", path);
    int rc = b.bad ? (snprintf(err, MP_ERRLEN, "out of memory"), 1) : run_gnuplot(b.s, err);
    free(b.s);
    return rc;
}

static int plot_chi2(const char *dir, const vt_result *r, const char *term, char *err)
{
    /* Paper Fig. 18: the χ² CDF of the fits against χ²(dof). */
    char path[4096], png[4096];
    FILE *fp = open_out(dir, r->c->id, "_chi2.dat", path, sizeof path, err);
    if (!fp)
        return 1;
    double *v = malloc((size_t)r->n * sizeof *v);
    if (!v) {
        fclose(fp);
        snprintf(err, MP_ERRLEN, "out of memory");
        return 1;
    }
    int m = 0, dof = 0;
    for (int k = 0; k < r->n; k++)
        if (r->s[k].dof > 0) {
            v[m++] = r->s[k].chi2 * r->s[k].dof;
            dof = r->s[k].dof;
        }
    qsort(v, (size_t)m, sizeof *v, cmp_double);
    fprintf(fp, "# chi2 empirical-CDF chi2(%d)-CDF\n", dof);
    int step = m > 4000 ? m / 4000 : 1;
    for (int k = 0; k < m; k += step)
        fprintf(fp, "%.4f %.6f %.6f\n", v[k], (k + 0.5) / m, vt_chi2_cdf(v[k], dof));
    fclose(fp);
    free(v);
    snprintf(png, sizeof png, "%s/%s_chi2.png", dir, r->c->id);
    sbuf b = {0};
    sb_printf(&b, "set terminal %s size 640,480 font ',10'\nset output '%s'\n", term, png);
    sb_printf(&b, "set title '%s: chi^2 of %d fits vs chi^2(%d); KS p = %.3g'\n", r->c->name,
              m, dof, r->ks_p);
    sb_printf(&b, "set xlabel 'chi^2'\nset ylabel 'cumulative fraction'\nset key left top\n");
    sb_printf(&b, "plot '%s' using 1:3 with lines lw 6 lc 'gray70' title 'chi^2(%d)', "
              "'' using 1:2 with lines lw 1 lc 'black' title 'fits'\n", path, dof);
    int rc = b.bad ? (snprintf(err, MP_ERRLEN, "out of memory"), 1) : run_gnuplot(b.s, err);
    free(b.s);
    return rc;
}

int vt_plot(const char *dir, const vt_result *r, const char *term, char *err)
{
    const vt_case *c = r->c;
    if (c->mag_lo == c->mag_hi)
        return plot_hist(dir, r, term, err);
    if (c->real && !c->gate_drf && plot_chi2(dir, r, term, err))
        return 1;
    char pbox[4096], pout[4096], pcur[4096], png[4096];
    FILE *fb = open_out(dir, c->id, "_box.dat", pbox, sizeof pbox, err);
    if (!fb)
        return 1;
    FILE *fo = open_out(dir, c->id, "_outl.dat", pout, sizeof pout, err);
    if (!fo) {
        fclose(fb);
        return 1;
    }
    double *v = malloc((size_t)(r->n > 0 ? r->n : 1) * sizeof *v);
    if (!v) {
        fclose(fb);
        fclose(fo);
        snprintf(err, MP_ERRLEN, "out of memory");
        return 1;
    }
    double vmax[2] = {0, 0}, lhmin[2] = {INFINITY, INFINITY};
    for (int panel = 0; panel < 2; panel++) {
        fprintf(fb, "# %s: x LH bottom-whisker top-whisker UH median CRLB-median\n",
                panel ? "dr [px]" : "|dmag|");
        fprintf(fo, "# %s outliers\n", panel ? "dr" : "|dmag|");
        for (int bi = 0; bi < VT_NBIN; bi++) {
            const vt_bin *B = &r->bin[bi];
            if (!B->n)
                continue;
            int m = 0;
            double *cr = malloc((size_t)B->n * sizeof *cr);
            if (!cr) {
                free(v);
                fclose(fb);
                fclose(fo);
                snprintf(err, MP_ERRLEN, "out of memory");
                return 1;
            }
            for (int k = 0; k < r->n; k++) {
                const vt_star *s = &r->s[k];
                if (vt_bin_index(s->mag) != bi)
                    continue;
                if (panel) {
                    v[m] = hypot(s->x - s->x_true, s->y - s->y_true);
                    cr[m] = sqrt(0.5 * (s->sx_crlb * s->sx_crlb + s->sy_crlb * s->sy_crlb));
                } else {
                    v[m] = s->e > 0 ? fabs(2.5 * log10(s->e / s->e_true)) : 10.0;
                    cr[m] = 1.0857 * s->se_crlb / s->e_true;
                }
                m++;
            }
            qsort(v, (size_t)m, sizeof *v, cmp_double);
            double bx[5];
            box_of(v, (size_t)m, B->mag, bx, fo, &vmax[panel]);
            double crm = vt_median(cr, (size_t)m) * (panel ? 1.1774 : 0.6745);
            free(cr);
            if (bx[0] > 0 && bx[0] < lhmin[panel])
                lhmin[panel] = bx[0];
            fprintf(fb, "%.3f %.6g %.6g %.6g %.6g %.6g %.6g\n", B->mag, bx[0], bx[3], bx[4],
                    bx[2], bx[1], crm);
        }
        fprintf(fb, "\n\n");
        fprintf(fo, "%s\n\n", panel ? "" : "");
    }
    free(v);
    fclose(fb);
    fclose(fo);

    /* Model curves: for magnitudes in each populated bin, the bin's mean PRF. */
    FILE *fc = open_out(dir, c->id, "_curve.dat", pcur, sizeof pcur, err);
    if (!fc)
        return 1;
    int ref = !c->real && c->volume != 1.0;   /* the V = 1 median (paper Fig. 6) */
    fprintf(fc, "# mag  0.674 1.151 2.398 5.423 sigma_mag   1.178 1.666 3.027 5.890 sigma_X"
            "%s\n", ref ? "   V=1: 0.674 sigma_mag 1.178 sigma_X" : "");
    double cmax[2] = {0, 0};
    for (double mag = c->mag_hi; mag >= c->mag_lo - 1e-9; mag -= 0.05) {
        int bi = vt_bin_index(mag > c->mag_hi - 1e-9 ? mag - 1e-6 : mag);
        if (bi < 0 || !r->bin[bi].n)
            continue;
        const vt_bin *B = &r->bin[bi];
        double E = pow(10.0, -0.4 * mag), sm, sx;
        model_at(B, E, c->sky, &sm, &sx);
        fprintf(fc, "%.3f %.6g %.6g %.6g %.6g %.6g %.6g %.6g %.6g", mag, 0.674 * sm,
                1.151 * sm, 2.398 * sm, 5.423 * sm, 1.178 * sx, 1.666 * sx, 3.027 * sx,
                5.890 * sx);
        cmax[0] = fmax(cmax[0], 5.423 * sm);
        cmax[1] = fmax(cmax[1], 5.890 * sx);
        if (ref) {
            vt_bin B1 = *B;
            B1.volume = B->volume / c->volume;
            B1.beta = B->beta * c->volume * c->volume;
            model_at(&B1, E, c->sky / c->volume, &sm, &sx);
            fprintf(fc, " %.6g %.6g", 0.674 * sm, 1.178 * sx);
        }
        fprintf(fc, "\n");
    }
    fclose(fc);

    snprintf(png, sizeof png, "%s/%s.png", dir, c->id);
    sbuf b = {0};
    sb_printf(&b, "set terminal %s size 800,900 font ',9'\nset output '%s'\n", term, png);
    sb_printf(&b, "set multiplot layout 2,1 title \"%s (N = %d, B = %.4g e-)\"\n", c->name, r->n,
              c->sky);
    sb_printf(&b, "set logscale y\nset format y '10^{%%L}'\nset xrange [%.1f:%.1f]\n"
              "set xtics 1\nset boxwidth 0.45\nset style fill empty\n"
              "set key top left font ',8' spacing 0.9 box opaque\nset grid ytics lc 'gray90'\n",
              c->mag_lo - 0.7, c->mag_hi + 0.7);
    for (int panel = 0; panel < 2; panel++) {
        double lo = isfinite(lhmin[panel]) ? lhmin[panel] / 30.0 : 1e-6;
        double hi = 2.0 * fmax(vmax[panel], cmax[panel]);
        int o = panel ? 6 : 2;
        sb_printf(&b, "set yrange [%.3g:%.3g]\n", lo, hi);
        sb_printf(&b, "set xlabel 'true magnitude (0 mag = 1 e-)'\nset ylabel '%s'\n",
                  panel ? "total position error {/Symbol D}r [px]"
                        : "|{/Symbol D}mag| [mag]");
        sb_printf(&b, "plot '%s' using 1:%d:%d with filledcurves lc 'gray80' "
                  "title 'model top hinge .. top fence', "
                  "'' using 1:%d with lines lw 2 lc 'gray50' title 'model median', "
                  "'' using 1:%d with lines dt 2 lw 1.5 lc 'gray50' title 'model 5{/Symbol s} outlier', ",
                  pcur, o + 1, o + 2, o, o + 3);
        if (ref)
            sb_printf(&b, "'' using 1:%d with lines dt 4 lw 1.5 lc 'black' "
                      "title 'model median, V = 1', ", panel ? 11 : 10);
        sb_printf(&b, "'%s' index %d using 1:2:3:4:5 with candlesticks whiskerbars 0.5 "
                  "lc 'black' lw 1.2 title 'measured (hinges, whiskers, median)', "
                  "'' index %d using 1:6:6:6:6 with candlesticks lc 'black' lw 2 notitle, "
                  "'' index %d using 1:7 with points pt 2 ps 1.3 lc 'red' "
                  "title 'CRLB median (bin)', "
                  "'%s' index %d using 1:2 with points pt 6 ps 0.3 lc 'black' title 'outliers'\n",
                  pbox, panel, panel, panel, pout, panel);
    }
    sb_printf(&b, "unset multiplot\n");
    int rc = b.bad ? (snprintf(err, MP_ERRLEN, "out of memory"), 1) : run_gnuplot(b.s, err);
    free(b.s);
    return rc;
}
