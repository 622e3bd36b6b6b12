/*
 * sweep.c — error against run time for one scene (issue 5).
 *
 *   sweep -s SCENE [-n N] [-r REPS] [-o WORKDIR] [-g PNGDIR] [-p TINYTIM_X4.fits]
 *         [-d DAOPHOT_POINTS] [-k KNOBS] [-w DIR] [-e] [-q]
 *
 * -e: only economy=yes against economy=no (econ.c; also the scenes
 * gradient and gate).  SCENE: isolated, crowded, undersampled, ugly.  The knobs of fit.par and
 * group.par are swept one at a time around their defaults (read from the
 * compiled-in params/fit.par and params/group.par; the supersampling
 * default is what economy=yes picks): sinchw, the table's sampling, fitrad,
 * tol, maxiter and, on the crowded scene, maxgroup; then the "economy"
 * combination of the cheapest harmless value of every knob (economy()).  Every setting fits the same stars; its CPU seconds are the
 * median of REPS repeats (interleaved over the settings).  Writes
 * WORKDIR/SCENE.md (the report's section), WORKDIR/SCENE*.dat, WORKDIR/SCENE.gp
 * (gnuplot script writing PNGDIR/SCENE.png).  Exit 0 on success (also when
 * the scene is skipped for a missing input), 1 on error, 2 on usage.
 */
#include <math.h>
#include <stdlib.h>
#include <string.h>
#include <time.h>
#include "group/group.h"
#include "params/params.h"
#include "tests/bench/sweep/sw.h"

#define DEFAULT_REAL "../shared/data/real/hst_acs_hrc_47tuc/tinytim_acs_hrc_f606w_x512y512_sub4.fits"

static double wall_now(void)
{
    struct timespec ts;
    clock_gettime(CLOCK_MONOTONIC, &ts);
    return (double)ts.tv_sec + 1e-9 * (double)ts.tv_nsec;
}

static double cpu_total(void)
{
    struct timespec ts;
    clock_gettime(CLOCK_PROCESS_CPUTIME_ID, &ts);
    return (double)ts.tv_sec + 1e-9 * (double)ts.tv_nsec;
}

static void usage(FILE *fp)
{
    fprintf(fp, "usage: sweep -s isolated|crowded|undersampled|ugly|gradient|gate [-n N] [-r REPS]\n"
                "             [-o WORKDIR] [-g PNGDIR] [-p TINYTIM_X4.fits] [-d DAOPHOT_POINTS]\n"
                "             [-k KNOBS] [-w DIR] [-e] [-q]\n"
                "  -e        economy=yes against economy=no only (WORKDIR/SCENE_econ.md)\n"
                "  -k KNOBS  comma list of knobs to sweep (sinchw,os,fitrad,tol,maxiter,maxgroup;\n"
                "            default all; none: only the default)\n"
                "  -w DIR    write the scene (frame or mosaic, truth, PSF) to DIR and stop\n");
}

/* fit.par's and group.par's defaults. */
static int read_defaults(sw_setting *d, char *err)
{
    mp_parset ps;
    memset(d, 0, sizeof *d);
    if (mp_params_defaults("fit", &ps, err))
        return 1;
    int rc = mp_par_int(&ps, "sinchw", &d->hw) || mp_par_real(&ps, "fitrad", &d->fitrad) ||
             mp_par_real(&ps, "tol", &d->tol) || mp_par_int(&ps, "maxiter", &d->maxiter);
    mp_params_free(&ps);
    if (rc) {
        snprintf(err, MP_ERRLEN, "fit.par lacks sinchw, fitrad, tol or maxiter");
        return 1;
    }
    if (mp_params_defaults("group", &ps, err))
        return 1;
    rc = mp_par_int(&ps, "maxgroup", &d->maxgroup);
    mp_params_free(&ps);
    if (rc) {
        snprintf(err, MP_ERRLEN, "group.par lacks maxgroup");
        return 1;
    }
    return 0;
}

static const char *fitrad_label(double r, char *buf, size_t n)
{
    if (!isfinite(r))
        snprintf(buf, n, "INDEF");
    else
        snprintf(buf, n, "%g", r);
    return buf;
}

static int same(const sw_setting *a, const sw_setting *b)
{
    int fr = (!isfinite(a->fitrad) && !isfinite(b->fitrad)) || a->fitrad == b->fitrad;
    return a->tab == b->tab && a->hw == b->hw && fr && a->tol == b->tol &&
           a->maxiter == b->maxiter && a->maxgroup == b->maxgroup;
}

/* Add a setting (knob = value) unless it is the default; add its row. */
static void add(sw_result *res, int *nres, sw_row *rows, int *nrows, const sw_setting *s,
                const char *only)
{
    if (only) {                  /* -k LIST: only these knobs */
        size_t l = strlen(s->knob);
        const char *p = strstr(only, s->knob);
        if (!p || (p != only && p[-1] != ',') || (p[l] != ',' && p[l] != '\0'))
            return;
    }
    int ir = -1;
    for (int i = 0; i < *nres; i++)
        if (same(&res[i].s, s))
            ir = i;
    if (ir < 0 && *nres < SW_MAXSET) {
        ir = (*nres)++;
        memset(&res[ir], 0, sizeof res[ir]);
        res[ir].s = *s;
    }
    if (ir >= 0 && *nrows < 2 * SW_MAXSET) {
        snprintf(rows[*nrows].knob, sizeof rows[*nrows].knob, "%s", s->knob);
        snprintf(rows[*nrows].value, sizeof rows[*nrows].value, "%s", s->value);
        rows[*nrows].ires = ir;
        (*nrows)++;
    }
}

static int build_settings(const sw_scene *sc, const sw_setting *def, sw_result *res, int *nres,
                          sw_row *rows, int *nrows, const char *only)
{
    static const int hws[] = {0, 2, 3, 4, 6, 8, 10, 14};
    static const double frs[] = {2, 3, 4, 5, 7, 10};
    static const double tols[] = {1e-1, 1e-2, 1e-3, 1e-4};
    static const char *const tolv[] = {"1e-1", "1e-2", "1e-3", "1e-4"};
    static const int its[] = {2, 3, 5, 10, 50};
    static const int mgs[] = {5, 10, 20, 60};
    *nres = 0;
    *nrows = 0;
    memset(&res[0], 0, sizeof res[0]);
    res[0].s = *def;
    *nres = 1;
    sw_setting s;
    char b[24];
    for (size_t i = 0; i < sizeof hws / sizeof *hws; i++) {
        s = *def;
        s.is_default = 0;
        s.hw = hws[i];
        snprintf(s.knob, sizeof s.knob, "sinchw");
        snprintf(s.value, sizeof s.value, "%d", hws[i]);
        add(res, nres, rows, nrows, &s, only);
    }
    for (int k = 0; k < sc->ntab; k++) {
        s = *def;
        s.is_default = 0;
        s.tab = k;
        snprintf(s.knob, sizeof s.knob, "os");
        snprintf(s.value, sizeof s.value, "x%d", sc->tab[k].os);
        add(res, nres, rows, nrows, &s, only);
    }
    int nfr = (int)(sizeof frs / sizeof *frs) + (sc->kind == SW_SINGLE);
    for (int i = 0; i < nfr; i++) {
        s = *def;
        s.is_default = 0;
        s.fitrad = i < (int)(sizeof frs / sizeof *frs) ? frs[i] : NAN;
        snprintf(s.knob, sizeof s.knob, "fitrad");
        snprintf(s.value, sizeof s.value, "%s", fitrad_label(s.fitrad, b, sizeof b));
        add(res, nres, rows, nrows, &s, only);
    }
    for (size_t i = 0; i < sizeof tols / sizeof *tols; i++) {
        s = *def;
        s.is_default = 0;
        s.tol = tols[i];
        snprintf(s.knob, sizeof s.knob, "tol");
        snprintf(s.value, sizeof s.value, "%s", tolv[i]);
        add(res, nres, rows, nrows, &s, only);
    }
    for (size_t i = 0; i < sizeof its / sizeof *its; i++) {
        s = *def;
        s.is_default = 0;
        s.maxiter = its[i];
        snprintf(s.knob, sizeof s.knob, "maxiter");
        snprintf(s.value, sizeof s.value, "%d", its[i]);
        add(res, nres, rows, nrows, &s, only);
    }
    if (sc->kind == SW_CROWDED)
        for (size_t i = 0; i < sizeof mgs / sizeof *mgs; i++) {
            s = *def;
            s.is_default = 0;
            s.maxgroup = mgs[i];
            snprintf(s.knob, sizeof s.knob, "maxgroup");
            snprintf(s.value, sizeof s.value, "%d", mgs[i]);
            add(res, nres, rows, nrows, &s, only);
        }
    return 0;
}

static int cmp_d(const void *a, const void *b)
{
    double x = *(const double *)a, y = *(const double *)b;
    return (x > y) - (x < y);
}

/* Run settings [i0, i1) reps times.  The machine is shared, so the
 * settings are interleaved finely: single-star scenes every SW_CHUNK stars,
 * the crowded frame every repeat, in alternating order. */
int sw_run_block(const sw_scene *sc, sw_result *res, int i0, int i1, int reps, int verbose,
                 char *err)
{
    int nchunk = sc->kind == SW_SINGLE ? (sc->n + SW_CHUNK - 1) / SW_CHUNK : 1;
    for (int rep = 0; rep < reps; rep++) {
        double w0 = wall_now();
        for (int i = i0; i < i1; i++) {
            res[i].cpu[rep] = 0.0;
            res[i].nrep = rep + 1;
            if (rep == 0)
                res[i].iters = res[i].hwsum = res[i].coarse = 0;
        }
        for (int c = 0; c < nchunk; c++) {
            int k0 = c * SW_CHUNK, k1 = k0 + SW_CHUNK < sc->n ? k0 + SW_CHUNK : sc->n;
            for (int q = i0; q < i1; q++) {
                int i = (rep * nchunk + c) % 2 ? i1 - 1 - (q - i0) : q;
                double cpu;
                if (sw_run(sc, &res[i].s, k0, k1, &res[i], rep == 0, &cpu, err))
                    return 1;
                res[i].cpu[rep] += cpu;
            }
        }
        if (verbose)
            fprintf(stderr, "sweep: %-12s repeat %d/%d of %d settings: %.1f s\n", sc->name, rep + 1,
                    reps, i1 - i0, wall_now() - w0);
    }
    for (int i = i0; i < i1; i++) {
        double c[16];
        int m = res[i].nrep;
        memcpy(c, res[i].cpu, (size_t)m * sizeof *c);
        qsort(c, (size_t)m, sizeof *c, cmp_d);
        double med = m % 2 ? c[m / 2] : 0.5 * (c[m / 2 - 1] + c[m / 2]);
        res[i].cpu_star = med / sc->n;
        res[i].cpu_spread = med > 0 ? (c[m - 1] - c[0]) / med : 0.0;
    }
    return 0;
}

/* One knob's value applied to a setting. */
static void apply(sw_setting *e, const sw_setting *b)
{
    if (!strcmp(b->knob, "sinchw"))
        e->hw = b->hw;
    else if (!strcmp(b->knob, "os"))
        e->tab = b->tab;
    else if (!strcmp(b->knob, "fitrad"))
        e->fitrad = b->fitrad;
    else if (!strcmp(b->knob, "tol"))
        e->tol = b->tol;
    else if (!strcmp(b->knob, "maxiter"))
        e->maxiter = b->maxiter;
    else
        e->maxgroup = b->maxgroup;
}

/* Harmless against the default, shown with 2σ margins: |Δ| + 2σ within
 * SW_SAFE for both ratios on all stars and 2·SW_SAFE on the bright ones, not
 * beating the bound, at most 1 % more stars flagged or lost. */
static int harmless(const sw_result *r, const sw_result *d)
{
    const sw_sub *a = &r->sub[0], *b = &r->sub[2];
    return fabs(a->dph) + 2.0 * a->udph <= SW_SAFE && fabs(a->das) + 2.0 * a->udas <= SW_SAFE &&
           (b->n == 0 || (fabs(b->dph) + 2.0 * b->udph <= 2.0 * SW_SAFE &&
                          fabs(b->das) + 2.0 * b->udas <= 2.0 * SW_SAFE)) &&
           !sw_beats(r, 0) && r->fflag + r->flost <= d->fflag + d->flost + 0.01;
}

/* The economy combination, greedily: per knob the cheapest harmless value
 * at least 3 % cheaper than the default; then, biggest saving first, each is
 * added to the combination only if the combination stays harmless (knobs
 * interact: checked by fitting every star once more).  Returns the number
 * of knobs kept, -1 on error. */
static int economy(const sw_scene *sc, const sw_result *res, int nres, sw_setting *e, char *why,
                   size_t nwhy, char *err)
{
    static const char *const knobs[] = {"sinchw", "os", "fitrad", "tol", "maxiter", "maxgroup"};
    enum { NK = sizeof knobs / sizeof *knobs };
    const sw_result *d = &res[0];
    int cand[NK], nc = 0;
    for (int k = 0; k < NK; k++) {
        int best = -1;
        for (int i = 1; i < nres; i++) {
            const sw_result *r = &res[i];
            if (strcmp(r->s.knob, knobs[k]) || r->s.is_econ || !(r->cpu_star < 0.97 * d->cpu_star) ||
                !harmless(r, d))
                continue;
            if (best < 0 || r->cpu_star < res[best].cpu_star)
                best = i;
        }
        if (best >= 0)
            cand[nc++] = best;
    }
    for (int a = 1; a < nc; a++)            /* biggest saving first */
        for (int c = a; c > 0 && res[cand[c]].cpu_star < res[cand[c - 1]].cpu_star; c--) {
            int t = cand[c];
            cand[c] = cand[c - 1];
            cand[c - 1] = t;
        }
    *e = d->s;
    e->is_default = 0;
    e->is_econ = 1;
    snprintf(e->knob, sizeof e->knob, "economy");
    char kept[256] = "", dropped[256] = "";
    int nk = 0, nd = 0;
    for (int c = 0; c < nc; c++) {
        const sw_setting *b = &res[cand[c]].s;
        int ok = 1;
        if (nk > 0) {                       /* one knob alone was measured already */
            sw_result pair[2];
            memset(pair, 0, sizeof pair);
            pair[0] = *d;                   /* shares the default's arrays, read only */
            pair[1].s = *e;
            apply(&pair[1].s, b);
            double cpu;
            if (sw_run(sc, &pair[1].s, 0, sc->n, &pair[1], 1, &cpu, err)) {
                sw_result_free(&pair[1]);
                return -1;
            }
            if (sw_stats(sc, pair, 2, 0, sc->seed + 77)) {
                sw_result_free(&pair[1]);
                snprintf(err, MP_ERRLEN, "out of memory for the statistics");
                return -1;
            }
            ok = harmless(&pair[1], d);
            sw_result_free(&pair[1]);
        }
        char *dst = ok ? kept : dropped;
        size_t l = strlen(dst);
        snprintf(dst + l, sizeof kept - l, "%s%s=%s", (ok ? nk : nd) ? ", " : "", b->knob, b->value);
        if (ok) {
            apply(e, b);
            nk++;
        } else {
            nd++;
        }
    }
    if (nk == 0)
        snprintf(why, nwhy, "no knob value is cheaper than the default at no cost in error");
    else if (nd)
        snprintf(why, nwhy, "%s (dropped, harmful in combination: %s)", kept, dropped);
    else
        snprintf(why, nwhy, "%s", kept);
    snprintf(e->value, sizeof e->value, "%d knobs", nk);
    return nk;
}

int main(int argc, char **argv)
{
    const char *scene = NULL, *work = ".", *pngdir = ".", *real = DEFAULT_REAL, *dao = NULL;
    const char *only = NULL, *exportdir = NULL;
    int n = 0, reps = 3, verbose = 1, econ_mode = 0;
    mp_blas_single_thread();
    for (int i = 1; i < argc; i++) {
        const char *a = argv[i];
        const char *v = i + 1 < argc ? argv[i + 1] : NULL;
        if (!strcmp(a, "-q")) {
            verbose = 0;
            continue;
        }
        if (!strcmp(a, "-e")) {
            econ_mode = 1;
            continue;
        }
        if (!v || a[0] != '-' || strlen(a) != 2) {
            usage(stderr);
            return 2;
        }
        switch (a[1]) {
        case 's': scene = v; break;
        case 'n': n = atoi(v); break;
        case 'r': reps = atoi(v); break;
        case 'o': work = v; break;
        case 'g': pngdir = v; break;
        case 'p': real = v; break;
        case 'd': dao = v; break;
        case 'k': only = v; break;
        case 'w': exportdir = v; break;
        default: usage(stderr); return 2;
        }
        i++;
    }
    if (!scene || reps < 1 || reps > 16 || n < 0) {
        usage(stderr);
        return 2;
    }
    if (n == 0)
        n = !strcmp(scene, "crowded") ? 1500 : 2000;
    char err[MP_ERRLEN] = "";
    double w0 = wall_now();
    sw_setting def;
    if (read_defaults(&def, err)) {
        fprintf(stderr, "sweep: %s\n", err);
        return 1;
    }
    sw_scene sc;
    int brc = sw_scene_build(&sc, scene, n, real, err);
    if (brc == 1) {
        fprintf(stderr, "sweep: %s\n", err);
        sw_scene_free(&sc);
        return 1;
    }
    if (brc == 2) {
        fprintf(stderr, "sweep: %s: skipped: %s\n", scene, sc.note);
        int rc = sw_write_skip(work, scene, sc.note, err);
        if (rc)
            fprintf(stderr, "sweep: %s\n", err);
        sw_scene_free(&sc);
        return rc;
    }
    if (exportdir) {             /* for running another program on the same scene */
        int rc = sw_export(exportdir, &sc, err);
        if (rc)
            fprintf(stderr, "sweep: %s\n", err);
        else if (verbose)
            fprintf(stderr, "sweep: wrote %s/%s.fits, .truth, _psf.fits\n", exportdir, sc.name);
        sw_scene_free(&sc);
        return rc;
    }
    if (econ_mode) {             /* economy=yes against economy=no only */
        int rc = sw_econ(&sc, work, reps, verbose, err);
        if (rc)
            fprintf(stderr, "sweep: %s: %s\n", scene, err);
        else if (verbose)
            fprintf(stderr, "sweep: %-12s economy done in %.1f s wall, %.1f s CPU\n", sc.name,
                    wall_now() - w0, cpu_total());
        sw_scene_free(&sc);
        return rc;
    }
    def.tab = sc.def_tab;
    def.is_default = 1;
    snprintf(def.knob, sizeof def.knob, "default");
    snprintf(def.value, sizeof def.value, "fit.par");
    if (verbose)
        fprintf(stderr, "sweep: %-12s %d stars built in %.1f s\n", sc.name, sc.n, wall_now() - w0);

    sw_result *res = calloc(SW_MAXSET, sizeof *res);
    sw_row *rows = calloc(2 * SW_MAXSET, sizeof *rows);
    if (!res || !rows) {
        fprintf(stderr, "sweep: out of memory\n");
        free(res);
        free(rows);
        sw_scene_free(&sc);
        return 1;
    }
    int nres = 0, nrows = 0, rc = 1;
    build_settings(&sc, &def, res, &nres, rows, &nrows, only);
    if (sw_run_block(&sc, res, 0, nres, reps, verbose, err))
        goto fail;
    if (sw_stats(&sc, res, nres, 0, sc.seed + 99)) {
        snprintf(err, MP_ERRLEN, "out of memory for the statistics");
        goto fail;
    }
    char why[512];
    sw_setting econ;
    int iecon = -1;
    int nk = economy(&sc, res, nres, &econ, why, sizeof why, err);
    if (nk < 0)
        goto fail;
    if (nk > 0 && nres < SW_MAXSET) {
        {
            /* Timed interleaved with a re-run of the default, and scaled to
             * the default's CPU of the first phase (the load may differ). */
            sw_result pair[2];
            memset(pair, 0, sizeof pair);
            pair[0].s = res[0].s;
            pair[1].s = econ;
            int prc = sw_run_block(&sc, pair, 0, 2, reps, verbose, err);
            sw_result_free(&pair[0]);
            if (prc) {
                sw_result_free(&pair[1]);
                goto fail;
            }
            iecon = nres++;
            res[iecon] = pair[1];
            if (pair[0].cpu_star > 0)
                res[iecon].cpu_star *= res[0].cpu_star / pair[0].cpu_star;
            if (sw_stats(&sc, res, nres, 0, sc.seed + 99)) {
                snprintf(err, MP_ERRLEN, "out of memory for the statistics");
                goto fail;
            }
        }
    }
    sw_pareto(res, nres);
    if (sw_write(work, pngdir, &sc, res, nres, rows, nrows, iecon, why, dao, reps,
                 wall_now() - w0, cpu_total(), err))
        goto fail;
    if (verbose)
        fprintf(stderr, "sweep: %-12s done in %.1f s wall, %.1f s CPU\n", sc.name, wall_now() - w0,
                cpu_total());
    rc = 0;
fail:
    if (rc)
        fprintf(stderr, "sweep: %s: %s\n", scene, err);
    for (int i = 0; i < nres; i++)
        sw_result_free(&res[i]);
    free(res);
    free(rows);
    sw_scene_free(&sc);
    return rc;
}
