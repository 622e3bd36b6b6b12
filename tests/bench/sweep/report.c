/*
 * report.c — one scene's section of bench/REPORT.md, its data and its
 * gnuplot script (error ratio against CPU seconds per star, log x, points
 * labelled knob=value, Pareto front, the default and the economy setting
 * marked, and IRAF DAOPHOT's point when bench/daophot_points.txt has one).
 *
 * The "what to choose" paragraph is derived from the numbers with fixed
 * rules: a change in a ratio is significant when it exceeds
 * max(0.01, 2σ) with σ the paired-bootstrap uncertainty of the difference
 * from the default; a setting is cheaper or dearer when its CPU differs
 * from the default's by more than 5 %.
 */
#include <math.h>
#include <stdlib.h>
#include <string.h>
#include "tests/bench/sweep/sw.h"

#define CPU_MARGIN 0.05

static const char *const KNOBS[] = {"sinchw", "os", "fitrad", "tol", "maxiter", "maxgroup"};
static const char *const COLOURS[] = {"#1f77b4", "#ff7f0e", "#2ca02c", "#9467bd", "#8c564b",
                                      "#e377c2"};
#define NKNOB ((int)(sizeof KNOBS / sizeof *KNOBS))

static FILE *open_out(const char *dir, const char *name, const char *ext, char *path, size_t n,
                      char *err)
{
    snprintf(path, n, "%s/%s%s", dir, name, ext);
    FILE *fp = fopen(path, "w");
    if (!fp)
        snprintf(err, MP_ERRLEN, "%.400s: cannot write", path);
    return fp;
}

static int close_out(FILE *fp, const char *path, char *err)
{
    if (ferror(fp) | fclose(fp)) {
        snprintf(err, MP_ERRLEN, "%.400s: write error", path);
        return 1;
    }
    return 0;
}

int sw_write_skip(const char *dir, const char *name, const char *why, char *err)
{
    char path[1024];
    FILE *fp = open_out(dir, name, ".md", path, sizeof path, err);
    if (!fp)
        return 1;
    fprintf(fp, "## %s\n\nSkipped: %s.\n\n", name, why);
    if (close_out(fp, path, err))
        return 1;
    if (!(fp = open_out(dir, name, "_sum.md", path, sizeof path, err)))
        return 1;
    fprintf(fp, "| %s | skipped: %s | | | | | |\n", name, why);
    return close_out(fp, path, err);
}

/* DAOPHOT's point for this scene from `scene cpu_s_per_star phot astro`
 * lines ('#' comments); 0 when there is none. */
static int dao_point(const char *file, const char *scene, double v[3], char *why, size_t nwhy)
{
    if (!file) {
        snprintf(why, nwhy, "no points file given");
        return 0;
    }
    FILE *fp = fopen(file, "r");
    if (!fp) {
        snprintf(why, nwhy, "%s absent (IRAF not installed or the comparison not run)", file);
        return 0;
    }
    char line[512], name[128];
    int found = 0;
    while (fgets(line, sizeof line, fp)) {
        if (line[0] == '#')
            continue;
        double a, b, c;
        if (sscanf(line, "%127s %lf %lf %lf", name, &a, &b, &c) == 4 && !strcmp(name, scene)) {
            v[0] = a;
            v[1] = b;
            v[2] = c;
            found = 1;
        }
    }
    fclose(fp);
    if (!found)
        snprintf(why, nwhy, "%s has no line for '%s'", file, scene);
    return found;
}

static int knob_index(const char *k)
{
    for (int i = 0; i < NKNOB; i++)
        if (!strcmp(k, KNOBS[i]))
            return i;
    return -1;
}

static void label_of(const sw_result *r, char *b, size_t n)
{
    if (r->s.is_default)
        snprintf(b, n, "default");
    else if (r->s.is_econ)
        snprintf(b, n, "economy");
    else
        snprintf(b, n, "%s=%s", r->s.knob, r->s.value);
}

/* Significance threshold of a paired difference. */
static double thr(double u)
{
    return fmax(0.01, 2.0 * (isfinite(u) ? u : 0.0));
}

/* ---- the plot ---------------------------------------------------------- */

typedef struct {
    double lo, clip, hi;       /* axis from lo to hi; points above clip drawn at clip */
    int clipped;
} range;

static range yrange(const sw_result *res, int nres, int w, const double *dao)
{
    double mn = INFINITY, mx = -INFINITY;
    for (int i = 0; i < nres; i++) {
        double y = w ? res[i].sub[0].as : res[i].sub[0].ph;
        if (isfinite(y)) {
            mn = fmin(mn, y);
            mx = fmax(mx, y);
        }
    }
    if (dao && isfinite(dao[1 + w])) {
        mn = fmin(mn, dao[1 + w]);
        mx = fmax(mx, dao[1 + w]);
    }
    double d = w ? res[0].sub[0].as : res[0].sub[0].ph;
    double cap = 1.5 * fmax(1.0, isfinite(d) ? d : 1.0);
    range r;
    r.lo = 0.97 * mn;
    r.clip = fmin(mx, cap);
    r.clipped = mx > cap;
    r.hi = r.clip + 0.15 * (r.clip - r.lo) + 0.01;
    return r;
}

static int write_plot(const char *dir, const char *pngdir, const sw_scene *sc,
                      const sw_result *res, int nres, int iecon, const double *dao,
                      const char *daowhy, int nrep, char *err)
{
    char dpath[1024], gpath[1024];
    FILE *fp = open_out(dir, sc->name, "_plot.dat", dpath, sizeof dpath, err);
    if (!fp)
        return 1;
    range yr[2] = {yrange(res, nres, 0, dao), yrange(res, nres, 1, dao)};
    double xmn = INFINITY, xmx = -INFINITY;
    for (int i = 0; i < nres; i++) {
        xmn = fmin(xmn, res[i].cpu_star);
        xmx = fmax(xmx, res[i].cpu_star);
    }
    if (dao) {
        xmn = fmin(xmn, dao[0]);
        xmx = fmax(xmx, dao[0]);
    }
    /* Blocks: 0..NKNOB-1 knobs, NKNOB default, +1 economy, +2 phot front,
     * +3 astro front, +4 DAOPHOT.  Columns: cpu, phot, astro, labels. */
    int nblk = NKNOB + 5, have[NKNOB + 5];
    memset(have, 0, sizeof have);
    for (int b = 0; b < nblk; b++) {
        fprintf(fp, "# block %d\n", b);
        if (b < NKNOB + 2) {
            for (int i = 0; i < nres; i++) {
                const sw_result *r = &res[i];
                int k = knob_index(r->s.knob);
                int in = b < NKNOB ? k == b : (b == NKNOB ? r->s.is_default : r->s.is_econ);
                if (!in)
                    continue;
                char lab[96], l2[2][128];
                label_of(r, lab, sizeof lab);
                if (sw_beats(r, 0))
                    snprintf(lab + strlen(lab), sizeof lab - strlen(lab), " [beats CRLB: biased]");
                else if (!sw_usable(r, &res[0]))
                    snprintf(lab + strlen(lab), sizeof lab - strlen(lab), " [%.0f%% flagged]",
                             100.0 * (r->fflag + r->flost));
                double y[2] = {r->sub[0].ph, r->sub[0].as};
                for (int w = 0; w < 2; w++) {
                    if (y[w] > yr[w].clip) {
                        snprintf(l2[w], sizeof l2[w], "%s (%.3g)", lab, y[w]);
                        y[w] = yr[w].clip;
                    } else {
                        snprintf(l2[w], sizeof l2[w], "%s", lab);
                    }
                }
                fprintf(fp, "%.6e %.6f %.6f \"%s\" \"%s\"\n", r->cpu_star, y[0], y[1], l2[0], l2[1]);
                have[b] = 1;
            }
        } else if (b == NKNOB + 2 || b == NKNOB + 3) {
            int w = b - (NKNOB + 2);
            int *ord = malloc((size_t)nres * sizeof *ord), m = 0;
            if (!ord) {
                fclose(fp);
                snprintf(err, MP_ERRLEN, "out of memory");
                return 1;
            }
            for (int i = 0; i < nres; i++)
                if (w ? res[i].par_as : res[i].par_ph)
                    ord[m++] = i;
            for (int a = 1; a < m; a++)      /* by CPU */
                for (int c = a; c > 0 && res[ord[c]].cpu_star < res[ord[c - 1]].cpu_star; c--) {
                    int t = ord[c];
                    ord[c] = ord[c - 1];
                    ord[c - 1] = t;
                }
            for (int a = 0; a < m; a++) {
                double y = w ? res[ord[a]].sub[0].as : res[ord[a]].sub[0].ph;
                fprintf(fp, "%.6e %.6f %.6f\n", res[ord[a]].cpu_star, w ? NAN : fmin(y, yr[0].clip),
                        w ? fmin(y, yr[1].clip) : NAN);
            }
            have[b] = m > 0;
            free(ord);
        } else if (dao) {
            fprintf(fp, "%.6e %.6f %.6f \"IRAF DAOPHOT\" \"IRAF DAOPHOT\"\n", dao[0],
                    fmin(dao[1], yr[0].clip), fmin(dao[2], yr[1].clip));
            have[b] = 1;
        }
        if (!have[b])            /* gnuplot does not count an empty block */
            fprintf(fp, "NaN NaN NaN \"\" \"\"\n");
        fprintf(fp, "\n\n");
    }
    if (close_out(fp, dpath, err))
        return 1;

    fp = open_out(dir, sc->name, ".gp", gpath, sizeof gpath, err);
    if (!fp)
        return 1;
    fprintf(fp, "# gnuplot script written by tests/bench/sweep (make bench)\n");
    fprintf(fp, "set terminal pngcairo size 1600,700 font ',10' noenhanced\n");
    fprintf(fp, "set output '%s/%s.png'\n", pngdir, sc->name);
    char dw[600];                /* no double quotes in a gnuplot "string" */
    size_t o = 0;
    for (const char *c = daowhy; *c && o + 1 < sizeof dw; c++)
        dw[o++] = *c == '"' ? '\'' : *c;
    dw[o] = 0;
    fprintf(fp, "set multiplot layout 1,2 title \"%s: achieved error over the CRLB against CPU "
                "seconds per star (N = %d, CPU median of %d repeats)%s%s\"\n", sc->name, sc->n,
            nrep, dao ? "" : "\\nIRAF DAOPHOT: no point — ", dao ? "" : dw);
    fprintf(fp, "set logscale x\nset grid xtics ytics mxtics lc rgb 'gray85'\n");
    double xlo = xmn / 1.6, xhi = xmx * 1.6;
    fprintf(fp, "set xrange [%.4e:%.4e]\nset xtics (", xlo, xhi);
    /* 1, 2, 5 x 10^k inside the range; every m x 10^k when that gives < 3. */
    int dense = 0, nt = 0;
    for (int pass = 0; pass < 2 && nt < 3; pass++) {
        dense = pass;
        nt = 0;
        for (int e = (int)floor(log10(xlo)); e <= (int)ceil(log10(xhi)); e++)
            for (int m = 1; m <= 9; m++)
                if ((dense || m == 1 || m == 2 || m == 5) && m * pow(10.0, e) >= xlo &&
                    m * pow(10.0, e) <= xhi)
                    nt++;
    }
    nt = 0;
    for (int e = (int)floor(log10(xlo)); e <= (int)ceil(log10(xhi)); e++)
        for (int m = 1; m <= 9; m++) {
            double v = m * pow(10.0, e);
            if ((dense || m == 1 || m == 2 || m == 5) && v >= xlo && v <= xhi)
                fprintf(fp, "%s\"%g\" %g", nt++ ? ", " : "", v, v);
        }
    fprintf(fp, ")\n");
    fprintf(fp, "set xlabel 'CPU seconds per star (one thread)'\n");
    fprintf(fp, "set key outside bottom center horizontal font ',9'\n");
    for (int w = 0; w < 2; w++) {
        fprintf(fp, "set yrange [%.4f:%.4f]\n", yr[w].lo, yr[w].hi);
        fprintf(fp, "set ylabel '%s'\n", w ? "astrometric: median(dr / sigma_X,CRLB) / 1.1774"
                                           : "photometric: median(|dmag| / sigma_mag,CRLB) / 0.6745");
        if (yr[w].clipped) {
            fprintf(fp, "set title '%s (points above %.3g are drawn on the dotted line, value in "
                        "brackets)'\n", w ? "astrometry" : "photometry", yr[w].clip);
            fprintf(fp, "set arrow 2 from graph 0, first %.4f to graph 1, first %.4f nohead dt 3 "
                        "lc rgb 'gray60'\n", yr[w].clip, yr[w].clip);
        } else {
            fprintf(fp, "set title '%s'\nunset arrow 2\n", w ? "astrometry" : "photometry");
        }
        fprintf(fp, "plot ");
        int first = 1;
        int c = 2 + w, l = 4 + w;
#define SEP() (first ? (first = 0, "") : ", \\\n     ")
        if (have[NKNOB + 2 + w])
            fprintf(fp, "%s'%s' index %d using 1:%d with steps lw 2 lc rgb 'gray50' title 'Pareto front'",
                    SEP(), dpath, NKNOB + 2 + w, c);
        for (int k = 0; k < NKNOB; k++) {
            if (!have[k])
                continue;
            fprintf(fp, "%s'%s' index %d using 1:%d with points pt 7 ps 1.2 lc rgb '%s' title '%s'",
                    SEP(), dpath, k, c, COLOURS[k], KNOBS[k]);
            fprintf(fp, "%s'%s' index %d using 1:%d:%d with labels left rotate by 35 offset char 0.4,0.3 "
                        "font ',7' textcolor rgb '%s' notitle", SEP(), dpath, k, c, l, COLOURS[k]);
        }
        if (have[NKNOB])
            fprintf(fp, "%s'%s' index %d using 1:%d with points pt 6 ps 3.2 lw 2 lc rgb 'black' "
                        "title 'default (fit.par)'", SEP(), dpath, NKNOB, c);
        if (have[NKNOB + 1]) {
            fprintf(fp, "%s'%s' index %d using 1:%d with points pt 12 ps 3 lw 2 lc rgb '#b00000' "
                        "title 'economy combination'", SEP(), dpath, NKNOB + 1, c);
            fprintf(fp, "%s'%s' index %d using 1:%d:%d with labels right offset char -1,-0.6 "
                        "font ',8' textcolor rgb '#b00000' notitle", SEP(), dpath, NKNOB + 1, c, l);
        }
        if (have[NKNOB + 4]) {
            fprintf(fp, "%s'%s' index %d using 1:%d with points pt 5 ps 2 lc rgb 'red' "
                        "title 'IRAF DAOPHOT'", SEP(), dpath, NKNOB + 4, c);
            fprintf(fp, "%s'%s' index %d using 1:%d:%d with labels left offset char 1,-0.6 "
                        "font ',8' textcolor rgb 'red' notitle", SEP(), dpath, NKNOB + 4, c, l);
        }
#undef SEP
        fprintf(fp, "\n");
    }
    fprintf(fp, "unset multiplot\n");
    (void)iecon;
    return close_out(fp, gpath, err);
}

/* ---- the section ------------------------------------------------------- */

static void fmt_d(char *b, size_t n, double d, double u)
{
    if (!isfinite(d))
        snprintf(b, n, "—");
    else if (u == 0.0)
        snprintf(b, n, "0");
    else
        snprintf(b, n, "%+.3f ± %.3f", d, u);
}

static void pareto_tag(const sw_result *r, char *b, size_t n)
{
    snprintf(b, n, "%s%s%s%s%s", r->par_ph ? "ph" : "", r->par_ph && r->par_as ? ", " : "",
             r->par_as ? "as" : "", r->par_joint && (r->par_ph || r->par_as) ? ", " : "",
             r->par_joint ? "**joint**" : "");
}

static void table_row(FILE *fp, const sw_scene *sc, const char *knob, const char *value,
                      const sw_result *r)
{
    char d1[64], d2[64], pt[32];
    fmt_d(d1, sizeof d1, r->sub[0].dph, r->sub[0].udph);
    fmt_d(d2, sizeof d2, r->sub[0].das, r->sub[0].udas);
    pareto_tag(r, pt, sizeof pt);
    fprintf(fp, "| %s | %s | %.3f | %.3f | %s | %s | %.3g | %.0f %% | %.1f %% (%.1f %%) |", knob,
            value, r->sub[0].ph, r->sub[0].as, d1, d2, 1e3 * r->cpu_star, 100.0 * r->cpu_spread,
            100.0 * r->fflag, 100.0 * r->fnoconv);
    if (sc->kind == SW_CROWDED)
        fprintf(fp, " %.1f %% | %.1f %% |", 100.0 * r->flost, 100.0 * r->fsplit);
    fprintf(fp, " %.1f | %s |\n", (double)r->iters / sc->n, pt);
}

/* Significant loss / gain / neither of r against the default, over subset s. */
static int worse(const sw_result *r, int s)
{
    return r->sub[s].dph > thr(r->sub[s].udph) || r->sub[s].das > thr(r->sub[s].udas);
}

static int better(const sw_result *r, int s)
{
    return r->sub[s].dph < -thr(r->sub[s].udph) || r->sub[s].das < -thr(r->sub[s].udas);
}

/* Append "knob=value (what)" items of one class to a line. */
static void list_class(FILE *fp, const sw_result *res, int nres, int cls)
{
    const sw_result *d = &res[0];
    int cnt = 0;
    for (int i = 1; i < nres; i++) {
        const sw_result *r = &res[i];
        if (r->s.is_econ)
            continue;
        double rel = r->cpu_star / d->cpu_star - 1.0;
        int cheaper = rel < -CPU_MARGIN, dearer = rel > CPU_MARGIN;
        int beats = sw_beats(r, 0), usable = sw_usable(r, d);
        int w = worse(r, 0) || !usable, b = better(r, 0) && usable;
        int in = !beats ? (cls == 0 && cheaper && !w && !b) || (cls == 1 && dearer && !b) ||
                              (cls == 2 && cheaper && w) || (cls == 3 && dearer && b) ||
                              (cls == 4 && !cheaper && !dearer && w) ||
                              (cls == 6 && cheaper && b)
                        : cls == 5;
        if (!in)
            continue;
        char lab[64];
        label_of(r, lab, sizeof lab);
        fprintf(fp, "%s%s (CPU %+.0f %%, phot %+.3f, astro %+.3f", cnt ? "; " : "", lab,
                100.0 * rel, r->sub[0].dph, r->sub[0].das);
        if (beats)
            fprintf(fp, ", ratios %.3f / %.3f", r->sub[0].ph, r->sub[0].as);
        else if (!usable)
            fprintf(fp, ", but %.0f %% of the stars flagged or lost", 100.0 * (r->fflag + r->flost));
        fprintf(fp, ")");
        cnt++;
    }
    if (!cnt)
        fprintf(fp, "none");
}

/* The shortest kernel whose ratios over subset s stay within the
 * significance threshold of sinchw = default; -1 if none was swept. */
static int shortest_safe(const sw_result *res, int nres, const sw_row *rows, int nrows, int s)
{
    int best = -1;
    for (int q = 0; q < nrows; q++) {
        if (strcmp(rows[q].knob, "sinchw"))
            continue;
        const sw_result *r = &res[rows[q].ires];
        const sw_sub *u = &r->sub[s];
        /* Shown to be safe: the 2σ bound on the change, either way, within
         * SW_SAFE for both ratios (an equivalence test: noise is no proof). */
        if (!(fabs(u->dph) + 2.0 * u->udph <= SW_SAFE && fabs(u->das) + 2.0 * u->udas <= SW_SAFE) ||
            sw_beats(r, s))
            continue;
        int hw = r->s.hw;
        if (best < 0 || hw < best)
            best = hw;
    }
    (void)nres;
    return best;
}

int sw_write(const char *dir, const char *pngdir, const sw_scene *sc, const sw_result *res,
             int nres, const sw_row *rows, int nrows, int iecon, const char *econ_why,
             const char *daofile, int nrep, double wall, double cpu, char *err)
{
    double dao[3];
    char daowhy[600];
    int have_dao = dao_point(daofile, sc->name, dao, daowhy, sizeof daowhy);
    if (write_plot(dir, pngdir, sc, res, nres, iecon, have_dao ? dao : NULL, daowhy, nrep, err))
        return 1;
    char path[1024];
    FILE *fp = open_out(dir, sc->name, ".md", path, sizeof path, err);
    if (!fp)
        return 1;
    const sw_result *d = &res[0];
    const sw_setting *ds = &d->s;
    int single = sc->kind == SW_SINGLE;
    fprintf(fp, "## %s — %s\n\n", sc->name, sc->title);
    fprintf(fp, "- %d stars, magnitudes uniform over [%.0f, %.0f) (0 mag = 1 e−), sky %.0f e−/px, "
                "read noise %.0f e−, seeds %llu + k (xoshiro256**).  %s.\n",
            sc->n, SW_MAG_LO, SW_MAG_HI, SW_SKY, SW_RON, (unsigned long long)sc->seed, sc->note);
    if (single)
        fprintf(fp, "- Fit: one `mp_fit_group` per frame from the truth + U(−0.25, 0.25) px, start "
                    "flux and sky estimated by the engine; CPU = the fit calls only.\n");
    else
        fprintf(fp, "- Fit: %ldx%ld frame; start table = truth + U(−0.25, 0.25) px; `mp_group_table` "
                    "(fitrad of the setting, psfrad %.0f, maxgroup of the setting; not timed), then "
                    "`mp_fit_table` with `mp_frame_opts_default` (%s passes, merge radius 0.4 FWHM, "
                    "minsnr 2) and the setting's fitrad, tol, maxiter; CPU = `mp_fit_table` only.  "
                    "The CRLB of every star is computed **as if it were isolated** (the same star "
                    "alone on a 60x60 frame): crowding raises the true bound, so ratios above 1 "
                    "are expected here and measure the cost of crowding plus the fit's own loss.  "
                    "Stars merged away or rejected (*lost*) leave the medians.\n",
                sc->fnx, sc->fny, SW_PSFRAD, "2");
    char frl[24];
    if (isfinite(ds->fitrad))
        snprintf(frl, sizeof frl, "%g", ds->fitrad);
    else
        snprintf(frl, sizeof frl, "INDEF");
    fprintf(fp, "- Default (fit.par, economy=yes): sinchw %d, table x%d%s, fitrad %s, tol %g, maxiter %d%s.\n",
            ds->hw, sc->tab[ds->tab].os,
            sc->tab[0].os > 1 && ds->tab != 0
                ? " (economy=yes block-sums the given table to x1: beta·V² at detector sampling "
                  "is >= 21 px²)"
                : (sc->tab[0].os > 1 ? " (the table as given: beta·V² at detector sampling < 21 px², "
                                       "economy keeps the supersampling)" : ""),
            frl, ds->tol, ds->maxiter, single ? "" : ", maxgroup 60");
    fprintf(fp, "  beta·V² of the given x%d table at detector sampling: %.2f px².\n",
            sc->tab[0].os, sc->beta_norm);
    if (sc->fwhm == 0.0)
        fprintf(fp, "- The simulated stars sit on the x%d grid of the table (the simulator draws a "
                    "table star exactly only there), so a fit biased toward grid positions — a "
                    "short kernel at the table's own sampling — can beat the CRLB; such settings "
                    "are marked *beats CRLB* and kept off the fronts and the economy.\n",
                sc->tab[0].os);
    double n0 = d->sub[0].n, n1 = d->sub[1].n, n2 = d->sub[2].n;
    fprintf(fp, "- Sampling uncertainty (1σ) of a ratio: all stars (n = %.0f) phot ±%.1f %%, astro "
                "±%.1f %%; faint third (n = %.0f) ±%.1f %%, ±%.1f %%; bright third (n = %.0f) ±%.1f %%, "
                "±%.1f %%.  Every setting fits the same stars, so the differences from the default "
                "(Δ columns, ±1σ by %d paired bootstrap resamples) are far better determined.\n",
            n0, 116.6 / sqrt(fmax(n0, 1)), 72.1 / sqrt(fmax(n0, 1)), n1, 116.6 / sqrt(fmax(n1, 1)),
            72.1 / sqrt(fmax(n1, 1)), n2, 116.6 / sqrt(fmax(n2, 1)), 72.1 / sqrt(fmax(n2, 1)),
            SW_NBOOT);
    char il[48];
    if (single)
        snprintf(il, sizeof il, "every %d stars", SW_CHUNK);
    else
        snprintf(il, sizeof il, "every repeat");
    fprintf(fp, "- CPU: median of %d repeats, settings interleaved (%s), one thread; the scene "
                "took %.0f s wall and %.0f s CPU (simulation, fits, statistics).%s\n\n", nrep,
            il, wall, cpu,
            single || sc->n >= 1000 ? ""
                                    : "  **Few stars: the frame has only a handful of groups, so "
                                      "one group's failure moves the medians; run the full "
                                      "version for numbers.**");
    fprintf(fp, "![%s](%s.png)\n\n", sc->name, sc->name);

    fprintf(fp, "| knob | value | phot/CRLB | astro/CRLB | Δphot | Δastro | CPU ms/star | CPU spread | flagged (not converged) |%s iter/star | Pareto |\n",
            single ? "" : " lost | split |");
    fprintf(fp, "|---|---|---:|---:|---:|---:|---:|---:|---:|%s---:|---|\n", single ? "" : "---:|---:|");
    table_row(fp, sc, "**default**", "fit.par", d);
    for (int q = 0; q < nrows; q++) {
        const sw_result *r = &res[rows[q].ires];
        char v[48];
        snprintf(v, sizeof v, "%s%s", rows[q].value, r->s.is_default ? " (default)" : "");
        table_row(fp, sc, rows[q].knob, v, r);
    }
    if (iecon >= 0)
        table_row(fp, sc, "**economy**", econ_why, &res[iecon]);
    if (have_dao)
        fprintf(fp, "| **IRAF DAOPHOT** | same scene | %.3f | %.3f | | | %.3g | | |%s | |\n", dao[1],
                dao[2], 1e3 * dao[0], single ? "" : " | |");
    else
        fprintf(fp, "| **IRAF DAOPHOT** | — | *no point: %s* | | | | | | |%s | |\n", daowhy,
                single ? "" : " | |");
    fprintf(fp, "\nphot/CRLB = median(|Δmag| / σ_mag,CRLB) / 0.6745, astro/CRLB = median(Δr / "
                "σ_X,CRLB) / 1.1774 over the stars (1 = on the bound); Δ = minus the default's, "
                "on the stars both kept; CPU spread = (max − min)/median of the repeats' CPU; "
                "flagged = any FLAGS bit but 2 (split); iter/star = "
                "Levenberg–Marquardt iterations summed over %s, per star; Pareto: on the front "
                "of CPU against phot (ph), against astro (as), of (CPU, phot, astro) (**joint**); "
                "a setting is off a front when another is cheaper and no more than %.3f worse "
                "in the ratio(s); settings flagging or losing %.0f %% more of the stars than the "
                "default (e.g. not converged) are on no front.\n\n", single ? "the fits" : "groups and passes", SW_PEPS, 100.0 * SW_FLAGMAX);

    /* Faint and bright stars against the kernel length. */
    fprintf(fp, "### %s: kernel length for faint (mag > %.0f) and bright (mag < %.0f) stars\n\n",
            sc->name, SW_FAINT, SW_BRIGHT);
    fprintf(fp, "Table x%d, everything else at the default.  Value ± 1σ sampling; Δ = minus "
                "sinchw %d's on the same stars ± 1σ (paired bootstrap).\n\n",
            sc->tab[ds->tab].os, ds->hw);
    fprintf(fp, "| sinchw | taps | CPU ms/star | faint phot | faint astro | Δ faint phot | Δ faint astro | bright phot | bright astro | Δ bright phot | Δ bright astro |\n");
    fprintf(fp, "|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|\n");
    for (int q = 0; q < nrows; q++) {
        if (strcmp(rows[q].knob, "sinchw"))
            continue;
        const sw_result *r = &res[rows[q].ires];
        const sw_sub *f = &r->sub[1], *b = &r->sub[2];
        char a1[48], a2[48], a3[48], a4[48];
        fmt_d(a1, sizeof a1, f->dph, f->udph);
        fmt_d(a2, sizeof a2, f->das, f->udas);
        fmt_d(a3, sizeof a3, b->dph, b->udph);
        fmt_d(a4, sizeof a4, b->das, b->udas);
        fprintf(fp, "| %s | %d | %.4g | %.3f ± %.3f | %.3f ± %.3f | %s | %s | %.3f ± %.3f | %.3f ± %.3f | %s | %s |\n",
                rows[q].value, 2 * r->s.hw + 1, 1e3 * r->cpu_star, f->ph, f->uph, f->as, f->uas,
                a1, a2, b->ph, b->uph, b->as, b->uas, a3, a4);
    }
    int sf = shortest_safe(res, nres, rows, nrows, 1), sb = shortest_safe(res, nres, rows, nrows, 2);
    fprintf(fp, "\n**Kernel finding (%s).** The shortest kernel shown to be safe for the faint "
                "stars — |Δ| + 2σ ≤ %.2f for both ratios against sinchw %d, and not beating the "
                "bound: **sinchw %d** (%d taps); for the bright stars: **sinchw %d** (%d taps). ",
            sc->name, SW_SAFE, ds->hw, sf, 2 * sf + 1, sb, 2 * sb + 1);
    if (sf >= 0 && sb >= 0 && sf < sb)
        fprintf(fp, "A faint star can use a shorter kernel than a bright one here: shortening "
                    "it to %d for mag > %.0f is safe on this scene within the stated "
                    "uncertainty.\n\n", sf, SW_FAINT);
    else if (sf >= 0 && sb >= 0 && sf == sb)
        fprintf(fp, "Faint and bright stars tolerate the same kernel here, so a shorter kernel "
                    "for faint stars only buys nothing beyond shortening it for all.\n\n");
    else
        fprintf(fp, "Faint stars do not tolerate a shorter kernel than bright ones here.\n\n");

    /* What to choose. */
    fprintf(fp, "### %s: what to choose\n\n", sc->name);
    fprintf(fp, "The default costs %.3g ms/star at phot %.3f, astro %.3f. ", 1e3 * d->cpu_star,
            d->sub[0].ph, d->sub[0].as);
    fprintf(fp, "On the joint Pareto front (CPU, phot, astro), by CPU: ");
    int *ord = malloc((size_t)nres * sizeof *ord), m = 0;
    if (ord) {
        for (int i = 0; i < nres; i++)
            if (res[i].par_joint)
                ord[m++] = i;
        for (int a = 1; a < m; a++)
            for (int c = a; c > 0 && res[ord[c]].cpu_star < res[ord[c - 1]].cpu_star; c--) {
                int t = ord[c];
                ord[c] = ord[c - 1];
                ord[c - 1] = t;
            }
        for (int a = 0; a < m; a++) {
            char lab[64];
            label_of(&res[ord[a]], lab, sizeof lab);
            fprintf(fp, "%s%s (%.3g ms, %.3f/%.3f)", a ? ", " : "", lab, 1e3 * res[ord[a]].cpu_star,
                    res[ord[a]].sub[0].ph, res[ord[a]].sub[0].as);
        }
        free(ord);
    }
    fprintf(fp, ".\n\n");
    fprintf(fp, "- *Cheap wins* (more than 5 %% less CPU, no significant change — "
                "a change counts when it exceeds max(0.01, 2σ paired)): ");
    list_class(fp, res, nres, 0);
    fprintf(fp, ".\n- *Buy nothing* (more than 5 %% more CPU, no significant gain): ");
    list_class(fp, res, nres, 1);
    fprintf(fp, ".\n- *Worth their cost only if the gain matters* (dearer, significantly better): ");
    list_class(fp, res, nres, 3);
    fprintf(fp, ".\n- *False economies* (cheaper, significantly worse, or flagging %.0f %% more "
                "of the stars): ", 100.0 * SW_FLAGMAX);
    list_class(fp, res, nres, 2);
    fprintf(fp, ".\n- *Worse at the same cost*: ");
    list_class(fp, res, nres, 4);
    fprintf(fp, ".\n- *Cheaper and significantly better* (check before trusting): ");
    list_class(fp, res, nres, 6);
    fprintf(fp, ".\n- *Beat the CRLB* (a ratio more than 3σ below 1: biased toward the truth, "
                "not better; kept off the fronts and the economy): ");
    list_class(fp, res, nres, 5);
    fprintf(fp, ".\n");
    if (iecon >= 0) {
        const sw_result *e = &res[iecon];
        fprintf(fp, "- *Economy combination* (per knob the cheapest value ≥ 3 %% cheaper than the "
                    "default whose change is shown to be small — |Δ| + 2σ ≤ %.2f for both ratios on "
                    "all stars, ≤ %.2f on the bright ones — with at most 1 %% more stars flagged or "
                    "lost and not beating the bound; added biggest saving first, each kept only if "
                    "the combination, fitted again, stays within those limits; timed interleaved "
                    "with a re-run of the default and scaled to the default's CPU above): "
                    "%s → %.3g ms/star (×%.2f the default's CPU), phot %.3f (%+.3f ± %.3f), astro "
                    "%.3f (%+.3f ± %.3f), faint Δ %+.3f/%+.3f, bright Δ %+.3f/%+.3f, flagged %.1f %%.\n",
                SW_SAFE, 2.0 * SW_SAFE, econ_why, 1e3 * e->cpu_star, e->cpu_star / d->cpu_star,
                e->sub[0].ph, e->sub[0].dph,
                e->sub[0].udph, e->sub[0].as, e->sub[0].das, e->sub[0].udas, e->sub[1].dph,
                e->sub[1].das, e->sub[2].dph, e->sub[2].das, 100.0 * e->fflag);
    } else {
        fprintf(fp, "- *Economy combination*: not run — %s.\n", econ_why);
    }
    fprintf(fp, "\n");
    if (close_out(fp, path, err))
        return 1;

    /* One row of the report's summary table. */
    fp = open_out(dir, sc->name, "_sum.md", path, sizeof path, err);
    if (!fp)
        return 1;
    fprintf(fp, "| %s | %d | %.3g ms, %.3f / %.3f | ", sc->name, sc->n, 1e3 * d->cpu_star,
            d->sub[0].ph, d->sub[0].as);
    if (iecon >= 0) {
        const sw_result *e = &res[iecon];
        fprintf(fp, "%s: %.3g ms (×%.2f), %.3f / %.3f | ", econ_why, 1e3 * e->cpu_star,
                e->cpu_star / d->cpu_star, e->sub[0].ph, e->sub[0].as);
    } else {
        fprintf(fp, "none (%s) | ", econ_why);
    }
    fprintf(fp, "%d | %d | ", sf, sb);
    if (have_dao)
        fprintf(fp, "%.3g ms, %.3f / %.3f |\n", 1e3 * dao[0], dao[1], dao[2]);
    else
        fprintf(fp, "— |\n");
    return close_out(fp, path, err);
}
