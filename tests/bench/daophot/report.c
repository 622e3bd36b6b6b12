/*
 * report.c -- the stats file between "compare stats" and "compare report",
 * and REPORT.md (see compare.c).
 *
 * The stats file is tab-separated text, one record a line, its first field
 * the record type; strings escape backslash, tab and newline as \\, \t, \n;
 * numbers are %.17g (exact), "-" an absent value (Python's None):
 *   M key value                         meta.tsv, commands, cl_example
 *   T frame tool run wall user sys      run times, DAOPHOT totals added
 *   F name desc simcmd fwhm magmin magmax ntrue nedge edges... ntrue_sep[4] ntrue_mag...
 *   X frame# tool# name missing path ndet found false spurious compl zp dx dy posrms sigma_all nmag
 *   B frame# tool# kind bin# n found compl sigma bias   (kind 0 by_mag, 1 by_sep, 2 by_mag_blend)
 */
#include "compare.h"

#include <errno.h>
#include <math.h>
#include <stdarg.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

/* ---------------------------------------------------------------- writing */
static void put_str(FILE *f, const char *s)
{
    fputc('\t', f);
    for (; *s; s++) {
        if (*s == '\\') fputs("\\\\", f);
        else if (*s == '\t') fputs("\\t", f);
        else if (*s == '\n') fputs("\\n", f);
        else fputc(*s, f);
    }
}

static void put_num(FILE *f, double v) { fprintf(f, "\t%.17g", v); }
static void put_opt(FILE *f, cmp_opt o) { if (o.ok) put_num(f, o.v); else fputs("\t-", f); }

int cmp_stats_write(const char *path, const cmp_stats *s)
{
    FILE *f = fopen(path, "w");
    if (!f) {
        fprintf(stderr, "compare: %s: %s\n", path, strerror(errno));
        return -1;
    }
    for (size_t i = 0; i < s->nmeta; i++) {
        fputs("M", f); put_str(f, s->key[i]); put_str(f, s->val[i]); fputc('\n', f);
    }
    for (size_t i = 0; i < s->ntime; i++) {
        const cmp_time *t = &s->times[i];
        fputs("T", f); put_str(f, t->frame); put_str(f, t->tool);
        fprintf(f, "\t%ld", t->run);
        put_num(f, t->wall); put_num(f, t->user); put_num(f, t->sys);
        fputc('\n', f);
    }
    for (size_t i = 0; i < s->nframe; i++) {
        const cmp_frame *fr = &s->frames[i];
        fputs("F", f); put_str(f, fr->name); put_str(f, fr->desc); put_str(f, fr->simcmd);
        put_num(f, fr->fwhm); put_num(f, fr->magmin); put_num(f, fr->magmax);
        fprintf(f, "\t%ld\t%d", fr->ntrue, fr->nedge);
        for (int e = 0; e < fr->nedge; e++) put_num(f, fr->edges[e]);
        for (int b = 0; b < CMP_NSEP; b++) fprintf(f, "\t%ld", fr->ntrue_sep[b]);
        for (int b = 0; b < fr->nedge - 1; b++) fprintf(f, "\t%ld", fr->ntrue_mag[b]);
        fputc('\n', f);
        for (int t = 0; t < CMP_NTOOL; t++) {
            const cmp_tool *T = &fr->tools[t];
            fprintf(f, "X\t%zu\t%d", i, t);
            put_str(f, T->name);
            fprintf(f, "\t%d", T->missing != NULL);
            put_str(f, T->missing ? T->missing : "");
            fprintf(f, "\t%ld\t%ld\t%ld\t%ld", T->ndet, T->found, T->nfalse, T->spurious);
            put_num(f, T->compl); put_num(f, T->zp);
            put_opt(f, T->dx); put_opt(f, T->dy); put_opt(f, T->posrms); put_opt(f, T->sigma_all);
            fprintf(f, "\t%d\n", T->nmag);
            if (T->missing) continue;
            for (int kind = 0; kind < 3; kind++) {
                const cmp_bin *bb = kind == 0 ? T->by_mag : kind == 1 ? T->by_sep : T->by_mag_blend;
                int nb = kind == 1 ? CMP_NSEP : T->nmag;
                for (int b = 0; b < nb; b++) {
                    fprintf(f, "B\t%zu\t%d\t%d\t%d\t%ld\t%ld", i, t, kind, b, bb[b].n, bb[b].found);
                    put_opt(f, bb[b].compl); put_opt(f, bb[b].sigma); put_opt(f, bb[b].bias);
                    fputc('\n', f);
                }
            }
        }
    }
    if (ferror(f) | fclose(f)) {
        fprintf(stderr, "compare: %s: write error\n", path);
        return -1;
    }
    return 0;
}

/* ---------------------------------------------------------------- reading */
typedef struct { size_t n, cap; char **w; } fields;

/* split line at tabs, unescaping each field in place */
static int split_fields(char *line, fields *fl)
{
    fl->n = 0;
    for (char *q = line;;) {
        if (fl->n == fl->cap) {
            size_t c = fl->cap ? 2 * fl->cap : 32;
            char **w = realloc(fl->w, c * sizeof *w);
            if (!w) return -1;
            fl->w = w;
            fl->cap = c;
        }
        fl->w[fl->n++] = q;
        char *tab = strchr(q, '\t');
        if (tab) *tab = '\0';
        char *o = q;
        for (char *p = q; *p; p++) {
            if (*p == '\\' && p[1]) {
                p++;
                *o++ = *p == 't' ? '\t' : *p == 'n' ? '\n' : *p;
            } else
                *o++ = *p;
        }
        *o = '\0';
        if (!tab) break;
        q = tab + 1;
    }
    return 0;
}

typedef struct { const char *path; long lineno; int bad; } rd;

static double get_num(rd *r, const char *s)
{
    char *end;
    double v = strtod(s, &end);
    if (end == s || *end) r->bad = 1;
    return v;
}

static long get_long(rd *r, const char *s)
{
    char *end;
    long v = strtol(s, &end, 10);
    if (end == s || *end) r->bad = 1;
    return v;
}

static cmp_opt get_opt(rd *r, const char *s)
{
    cmp_opt o = { 0, 0.0 };
    if (strcmp(s, "-") == 0) return o;
    o.ok = 1;
    o.v = get_num(r, s);
    return o;
}

static int stats_line(cmp_stats *s, fields *fl, rd *r)
{
    char **w = fl->w;
    size_t n = fl->n;
    if (n == 3 && !strcmp(w[0], "M"))
        return cmp_stats_meta_add(s, w[1], w[2]);
    if (n == 7 && !strcmp(w[0], "T")) {
        long run = get_long(r, w[3]);
        double a = get_num(r, w[4]), b = get_num(r, w[5]), c = get_num(r, w[6]);
        return r->bad ? 0 : cmp_stats_time_add(s, w[1], w[2], run, a, b, c);
    }
    if (n >= 9 && !strcmp(w[0], "F")) {
        long ne = get_long(r, w[8]);
        if (r->bad || ne < 1 || ne > CMP_MAXBIN + 1 || n != (size_t)(9 + ne + CMP_NSEP + ne - 1)) {
            r->bad = 1;
            return 0;
        }
        cmp_frame *fr = realloc(s->frames, (s->nframe + 1) * sizeof *fr);
        if (!fr) return -1;
        s->frames = fr;
        fr = &s->frames[s->nframe++];
        memset(fr, 0, sizeof *fr);
        fr->name = cmp_strdup(w[1]);
        fr->desc = cmp_strdup(w[2]);
        fr->simcmd = cmp_strdup(w[3]);
        if (!fr->name || !fr->desc || !fr->simcmd) return -1;
        fr->fwhm = get_num(r, w[4]);
        fr->magmin = get_num(r, w[5]);
        fr->magmax = get_num(r, w[6]);
        fr->ntrue = get_long(r, w[7]);
        fr->nedge = (int)ne;
        size_t k = 9;
        for (int e = 0; e < fr->nedge; e++) fr->edges[e] = get_num(r, w[k++]);
        for (int b = 0; b < CMP_NSEP; b++) fr->ntrue_sep[b] = get_long(r, w[k++]);
        for (int b = 0; b < fr->nedge - 1; b++) fr->ntrue_mag[b] = get_long(r, w[k++]);
        return 0;
    }
    if (n == 17 && !strcmp(w[0], "X")) {
        long fi = get_long(r, w[1]), ti = get_long(r, w[2]);
        if (r->bad || fi < 0 || (size_t)fi >= s->nframe || ti < 0 || ti >= CMP_NTOOL) {
            r->bad = 1;
            return 0;
        }
        cmp_tool *T = &s->frames[fi].tools[ti];
        snprintf(T->name, sizeof T->name, "%s", w[3]);
        if (get_long(r, w[4])) {
            free(T->missing);
            if (!(T->missing = cmp_strdup(w[5]))) return -1;
        }
        T->ndet = get_long(r, w[6]);
        T->found = get_long(r, w[7]);
        T->nfalse = get_long(r, w[8]);
        T->spurious = get_long(r, w[9]);
        T->compl = get_num(r, w[10]);
        T->zp = get_num(r, w[11]);
        T->dx = get_opt(r, w[12]);
        T->dy = get_opt(r, w[13]);
        T->posrms = get_opt(r, w[14]);
        T->sigma_all = get_opt(r, w[15]);
        T->nmag = (int)get_long(r, w[16]);
        if (T->nmag < 0 || T->nmag > CMP_MAXBIN) r->bad = 1;
        return 0;
    }
    if (n == 10 && !strcmp(w[0], "B")) {
        long fi = get_long(r, w[1]), ti = get_long(r, w[2]), kind = get_long(r, w[3]);
        long b = get_long(r, w[4]);
        if (r->bad || fi < 0 || (size_t)fi >= s->nframe || ti < 0 || ti >= CMP_NTOOL
            || kind < 0 || kind > 2 || b < 0 || b >= (kind == 1 ? CMP_NSEP : CMP_MAXBIN)) {
            r->bad = 1;
            return 0;
        }
        cmp_tool *T = &s->frames[fi].tools[ti];
        cmp_bin *bb = kind == 0 ? T->by_mag : kind == 1 ? T->by_sep : T->by_mag_blend;
        bb[b].n = get_long(r, w[5]);
        bb[b].found = get_long(r, w[6]);
        bb[b].compl = get_opt(r, w[7]);
        bb[b].sigma = get_opt(r, w[8]);
        bb[b].bias = get_opt(r, w[9]);
        return 0;
    }
    r->bad = 1;
    return 0;
}

int cmp_stats_read(const char *path, cmp_stats *s)
{
    memset(s, 0, sizeof *s);
    FILE *f = fopen(path, "r");
    if (!f) {
        fprintf(stderr, "compare: %s: %s\n", path, strerror(errno));
        return -1;
    }
    char *line = NULL;
    size_t cap = 0;
    ssize_t len;
    fields fl = { 0, 0, NULL };
    rd r = { path, 0, 0 };
    int rc = 0;
    while ((len = getline(&line, &cap, f)) >= 0) {
        r.lineno++;
        if (len && line[len - 1] == '\n') line[--len] = '\0';
        if (split_fields(line, &fl) || stats_line(s, &fl, &r)) {
            fprintf(stderr, "compare: out of memory\n");
            rc = -1;
            break;
        }
        if (r.bad) {
            fprintf(stderr, "compare: %s:%ld: malformed line\n", path, r.lineno);
            rc = -1;
            break;
        }
    }
    free(line);
    free(fl.w);
    fclose(f);
    if (rc) cmp_stats_free(s);
    return rc;
}

/* ---------------------------------------------------------------- report */
/* Markdown elements joined by newlines (Python's "\n".join) */
typedef struct { char *s; size_t n, cap; int nel, oom; } sbuf;

static void sb_vadd(sbuf *b, const char *fmt, va_list ap)
{
    if (b->oom) return;
    va_list aq;
    va_copy(aq, ap);
    int k = vsnprintf(NULL, 0, fmt, aq);
    va_end(aq);
    if (k < 0) { b->oom = 1; return; }
    if (b->n + (size_t)k + 1 > b->cap) {
        size_t c = b->cap ? b->cap : 4096;
        while (c < b->n + (size_t)k + 1) c *= 2;
        char *s = realloc(b->s, c);
        if (!s) { b->oom = 1; return; }
        b->s = s;
        b->cap = c;
    }
    vsnprintf(b->s + b->n, (size_t)k + 1, fmt, ap);
    b->n += (size_t)k;
}

#if defined(__GNUC__)
#define CMP_PRINTF(i, j) __attribute__((format(printf, i, j)))
#else
#define CMP_PRINTF(i, j)
#endif

/* text appended to the current element */
static void sb_cat(sbuf *b, const char *fmt, ...) CMP_PRINTF(2, 3);
static void sb_cat(sbuf *b, const char *fmt, ...)
{
    va_list ap;
    va_start(ap, fmt);
    sb_vadd(b, fmt, ap);
    va_end(ap);
}

/* a new element */
static void el(sbuf *b, const char *fmt, ...) CMP_PRINTF(2, 3);
static void el(sbuf *b, const char *fmt, ...)
{
    if (b->nel++) sb_cat(b, "\n");
    va_list ap;
    va_start(ap, fmt);
    sb_vadd(b, fmt, ap);
    va_end(ap);
}

/* fmt(v, f) and pct(v) of bench.py, into buf */
static const char *fmtv(char *buf, size_t n, cmp_opt v, const char *f)
{
    if (!v.ok) return "–";
    snprintf(buf, n, f, v.v);
    return buf;
}

static const char *pct(char *buf, size_t n, cmp_opt v)
{
    if (!v.ok) return "–";
    snprintf(buf, n, "%.1f", 100.0 * v.v);
    return buf;
}

static cmp_opt some(double v) { cmp_opt o = { 1, v }; return o; }

/* the runs of one tool in one frame, the last entry of a run winning:
 * run numbers, wall, CPU = user + sys; returns the count */
static size_t tool_runs(const cmp_stats *s, const char *frame, const char *tool,
                        long *run, double *wall, double *cpu)
{
    size_t n = 0;
    for (size_t k = 0; k < s->ntime; k++) {
        const cmp_time *t = &s->times[k];
        if (strcmp(t->frame, frame) || strcmp(t->tool, tool)) continue;
        size_t q = 0;
        while (q < n && run[q] != t->run) q++;
        if (q == n) n++;
        run[q] = t->run;
        wall[q] = t->wall;
        cpu[q] = t->user + t->sys;
    }
    return n;
}

typedef struct {
    const cmp_stats *s;
    const char *frame;
    long *ra, *rb;
    double *wa, *ca, *wb, *cb, *r;
} timing;

/* median over runs of tool a's time / tool b's (wall or CPU) */
/* The runs' ratios a/b (wall or CPU), each run's a against the same
 * run's b, into T->r; their number. */
static size_t run_ratios(timing *T, const char *a, const char *b, int cpu)
{
    size_t na = tool_runs(T->s, T->frame, a, T->ra, T->wa, T->ca);
    size_t nb = tool_runs(T->s, T->frame, b, T->rb, T->wb, T->cb);
    size_t nr = 0;
    for (size_t i = 0; i < na; i++)
        for (size_t j = 0; j < nb; j++)
            if (T->ra[i] == T->rb[j]) {
                double num = cpu ? T->ca[i] : T->wa[i], den = cpu ? T->cb[j] : T->wb[j];
                if (den > 0) T->r[nr++] = num / den;
            }
    return nr;
}

static cmp_opt ratio(timing *T, const char *a, const char *b, int cpu)
{
    cmp_opt o = { 0, 0.0 };
    size_t nr = run_ratios(T, a, b, cpu);
    if (nr) o = some(cmp_median(T->r, nr));
    return o;
}

/* The runs' ratios a/b as "lo–hi" into buf ("" without runs). */
static const char *ratio_span(timing *T, const char *a, const char *b, int cpu, char *buf,
                              size_t len)
{
    size_t nr = run_ratios(T, a, b, cpu);
    double lo = INFINITY, hi = -INFINITY;
    for (size_t i = 0; i < nr; i++) {
        lo = T->r[i] < lo ? T->r[i] : lo;
        hi = T->r[i] > hi ? T->r[i] : hi;
    }
    if (nr)
        snprintf(buf, len, "%.3f-%.3f", lo, hi);
    else if (len)
        buf[0] = '\0';
    return buf;
}

static int tool_ok(const cmp_frame *F, const char *name)
{
    for (int t = 0; t < CMP_NTOOL; t++)
        if (!strcmp(F->tools[t].name, name)) return F->tools[t].missing == NULL;
    return 0;
}

static const cmp_tool *tool_get(const cmp_frame *F, const char *name)
{
    for (int t = 0; t < CMP_NTOOL; t++)
        if (!strcmp(F->tools[t].name, name)) return &F->tools[t];
    return NULL;
}

static const char *setup_fmt(void)
{
    return
#include "setup.inc"
    ;
}

enum { NTL = 12, NRATIO = 6, LAB = 256 };

int cmp_report(const char *stats_path, const char *out)
{
    cmp_stats st;
    if (cmp_stats_read(stats_path, &st)) return -1;
    const cmp_stats *s = &st;
    int rc = -1;
    sbuf A = { 0 }, B = { 0 }, S = { 0 };
    size_t nt = s->ntime ? s->ntime : 1;
    timing T = { s, NULL, malloc(nt * sizeof(long)), malloc(nt * sizeof(long)),
                 malloc(nt * sizeof(double)), malloc(nt * sizeof(double)),
                 malloc(nt * sizeof(double)), malloc(nt * sizeof(double)),
                 malloc(nt * nt * sizeof(double)) };
    if (!T.ra || !T.rb || !T.wa || !T.ca || !T.wb || !T.cb || !T.r) goto out;
    const char *m_niter = cmp_stats_meta(s, "niter", NULL), *m_reps = cmp_stats_meta(s, "reps", NULL);
    if (!m_niter || !m_reps || s->nframe == 0) {
        fprintf(stderr, "compare: %s: no niter, reps or frames\n", stats_path);
        goto out;
    }
    int n = atoi(m_niter), reps = atoi(m_reps);
    const char *th = cmp_stats_meta(s, "threads", "1"), *clean = cmp_stats_meta(s, "clean", "2");
    const char *iraf = cmp_stats_meta(s, "iraf", "?");

    /* labels */
    static const char *const tl_tool[NTL] = { "mp", "mpd", "mpb", "dao_find", "dao_psf", "dao_als1",
        "dao_refind", "dao1", "dao", "daopsf", "daoa_psf", "daoa" };
    char tl[NTL][LAB];
    snprintf(tl[0], LAB, "matphot pipeline, fitrad = FWHM, %d rounds (%s thread%s)", n, th,
             strcmp(th, "1") ? "s" : "");
    snprintf(tl[1], LAB, "matphot pipeline, default fitrad (5 px), %d rounds", n);
    snprintf(tl[2], LAB, "**matphot pipeline, fitrad = FWHM, PSF built from the frame** (no psf=: "
             "`matphot psf`'s build and its rebuild after round 1 included), %d rounds", n);
    snprintf(tl[3], LAB, "DAOPHOT daofind + phot");
    snprintf(tl[4], LAB, "DAOPHOT phot of 25 PSF stars + psf (gauss, varorder 0, %s cleaning rounds)", clean);
    snprintf(tl[5], LAB, "DAOPHOT allstar, pass 1");
    snprintf(tl[6], LAB, "DAOPHOT %d refind passes (daofind on residual, phot, pfmerge, prenumber, allstar)", n - 1);
    snprintf(tl[7], LAB, "DAOPHOT 1 pass (daofind + phot + allstar), PSF given");
    snprintf(tl[8], LAB, "**DAOPHOT %d passes, PSF given** (the peer of matphot pipeline)", n);
    snprintf(tl[9], LAB, "**DAOPHOT %d passes + building its PSF** (the peer of matphot's built PSF)", n);
    snprintf(tl[10], LAB, "DAOPHOT analytic PSF (varorder −1): phot of 25 PSF stars + psf");
    snprintf(tl[11], LAB, "DAOPHOT analytic PSF (varorder −1), %d passes, PSF given", n);
    static const char *const ra_a[NRATIO] = { "mp", "mpd", "mp", "mp", "mp", "mpb" };
    static const char *const ra_b[NRATIO] = { "dao", "dao", "daopsf", "daoa", "dao1", "daopsf" };
    char rl[NRATIO][LAB];
    snprintf(rl[0], LAB, "**matphot (fitrad = FWHM) / DAOPHOT %d passes**", n);
    snprintf(rl[1], LAB, "matphot (default fitrad) / DAOPHOT %d passes", n);
    snprintf(rl[2], LAB, "matphot (fitrad = FWHM) / DAOPHOT %d passes + psf", n);
    snprintf(rl[3], LAB, "matphot (fitrad = FWHM) / DAOPHOT analytic PSF, %d passes", n);
    snprintf(rl[4], LAB, "matphot (fitrad = FWHM) / DAOPHOT 1 pass");
    snprintf(rl[5], LAB, "**matphot with the PSF built from the frame / DAOPHOT %d passes + psf** "
             "(each building its own PSF)", n);
    static const char *const cl_tool[CMP_NTOOL] = { "mp", "mpd", "mpb", "dao1", "dao", "daoa" };
    char cl[CMP_NTOOL][LAB];
    snprintf(cl[0], LAB, "matphot, fitrad = FWHM");
    snprintf(cl[1], LAB, "matphot, default fitrad (5 px)");
    snprintf(cl[2], LAB, "matphot, fitrad = FWHM, PSF built from the frame");
    snprintf(cl[3], LAB, "DAOPHOT allstar, 1 pass");
    snprintf(cl[4], LAB, "DAOPHOT allstar, %d passes", n);
    snprintf(cl[5], LAB, "DAOPHOT allstar, analytic PSF (varorder −1), %d passes", n);

    char b1[64], b2[64], b3[64], b4[64], b5[64];
    el(&A, "# matphot against IRAF DAOPHOT on the same simulated frames\n");
    el(&A, "Written by `tests/bench/compare_daophot.sh` on %s: %s against %s; "
           "%d timed runs per program and frame; machine %s with %s CPUs (%s), "
           "load average at the start %s.\n", cmp_stats_meta(s, "date", "?"),
       cmp_stats_meta(s, "matphot", "?"), iraf, reps, cmp_stats_meta(s, "host", "?"),
       cmp_stats_meta(s, "ncpu", "?"), cmp_stats_meta(s, "cpu", "?"),
       cmp_stats_meta(s, "load", "?"));
    el(&B, setup_fmt(), n, n - 1, th, clean, iraf, reps);
    for (size_t fi = 0; fi < s->nframe; fi++) {
        const cmp_frame *F = &s->frames[fi];
        T.frame = F->name;
        el(&B, "## Frame %s: %s\n", F->name, F->desc);
        el(&B, "`%s`\n", F->simcmd);
        el(&B, "%ld true stars; nearest true neighbour < 1 / 1–2 / 2–3 / > 3 FWHM away: "
               "%ld / %ld / %ld / %ld stars.\n", F->ntrue, F->ntrue_sep[0], F->ntrue_sep[1],
           F->ntrue_sep[2], F->ntrue_sep[3]);
        el(&B, "### Time (median of %d runs; CPU = user + sys)\n", reps);
        el(&B, "| run | wall [s] | CPU [s] |");
        el(&B, "|---|---:|---:|");
        for (int k = 0; k < NTL; k++) {
            size_t nr = tool_runs(s, F->name, tl_tool[k], T.ra, T.wa, T.ca);
            if (nr)
                el(&B, "| %s | %.2f | %.2f |", tl[k], cmp_median(T.wa, nr), cmp_median(T.ca, nr));
        }
        el(&B, "%s", "");
        el(&B, "| ratio (median of per-run ratios; < 1: matphot faster) | wall | CPU |");
        el(&B, "|---|---:|---:|");
        for (int k = 0; k < NRATIO; k++)
            el(&B, "| %s | %s | %s |", rl[k], fmtv(b1, sizeof b1, ratio(&T, ra_a[k], ra_b[k], 0), "%.3f"),
               fmtv(b2, sizeof b2, ratio(&T, ra_a[k], ra_b[k], 1), "%.3f"));
        el(&B, "%s", "");
        el(&B, "### Detection and photometry (match radius 1 px)\n");
        el(&B, "| catalogue | rows | matched | completeness %% | unmatched rows "
               "| spurious | zero point [mag] | σ Δmag | median Δx, Δy [px] | σ position [px] |");
        el(&B, "|---|---:|---:|---:|---:|---:|---:|---:|---|---:|");
        for (int t = 0; t < CMP_NTOOL; t++) {
            const cmp_tool *U = tool_get(F, cl_tool[t]);
            if (!U) continue;
            if (U->missing) {
                el(&B, "| %s | missing: %s |||||||||", cl[t], U->missing);
                continue;
            }
            el(&B, "| %s | %ld | %ld | %s | %ld | %ld | %+.3f | %s | %s, %s | %s |", cl[t],
               U->ndet, U->found, pct(b1, sizeof b1, some(U->compl)), U->nfalse, U->spurious,
               U->zp, fmtv(b2, sizeof b2, U->sigma_all, "%.3f"), fmtv(b3, sizeof b3, U->dx, "%+.3f"),
               fmtv(b4, sizeof b4, U->dy, "%+.3f"), fmtv(b5, sizeof b5, U->posrms, "%.3f"));
        }
        el(&B, "%s", "");
        static const char *const titles[3] = {
            "Completeness % (σ Δmag) by nearest-neighbour separation [FWHM] (true stars in the bin)",
            "Completeness % (σ Δmag) by true magnitude",
            "Blended stars only (nearest neighbour < 2 FWHM): completeness % (σ Δmag) by true magnitude" };
        for (int kind = 0; kind < 3; kind++) {     /* by_sep, by_mag, by_mag_blend */
            el(&B, "### %s\n", titles[kind]);
            int nb = kind == 0 ? CMP_NSEP : F->nedge - 1;
            el(&B, "| catalogue | ");
            for (int b = 0; b < nb; b++) {
                if (b) sb_cat(&B, " | ");
                if (kind == 0) sb_cat(&B, "%s (%ld)", cmp_sep_name(b), F->ntrue_sep[b]);
                else sb_cat(&B, "%g…%g", F->edges[b], F->edges[b + 1]);
            }
            sb_cat(&B, " |");
            el(&B, "|---|");
            for (int b = 0; b < nb; b++) sb_cat(&B, "---:|");
            const cmp_tool *first = NULL;
            for (int t = 0; t < CMP_NTOOL; t++) {
                const cmp_tool *U = tool_get(F, cl_tool[t]);
                if (!U || U->missing) continue;
                if (!first) first = U;
                const cmp_bin *bb = kind == 0 ? U->by_sep : kind == 1 ? U->by_mag : U->by_mag_blend;
                int ub = kind == 0 ? CMP_NSEP : U->nmag;
                el(&B, "| %s | ", cl[t]);
                for (int b = 0; b < ub; b++)
                    sb_cat(&B, "%s%s (%s)", b ? " | " : "", pct(b1, sizeof b1, bb[b].compl),
                           fmtv(b2, sizeof b2, bb[b].sigma, "%.3f"));
                sb_cat(&B, " |");
            }
            if (kind > 0 && first) {
                const cmp_bin *bb = kind == 1 ? first->by_mag : first->by_mag_blend;
                el(&B, "| (true stars) | ");
                for (int b = 0; b < first->nmag; b++) sb_cat(&B, "%s%ld", b ? " | " : "", bb[b].n);
                sb_cat(&B, " |");
            }
            el(&B, "%s", "");
        }
        if (tool_ok(F, "mp") && tool_ok(F, "mpd") && tool_ok(F, "dao")) {
            el(&S, "frame %s: %s", F->name, F->desc);
            el(&S, "  time matphot/DAOPHOT (%d passes each): wall %s, CPU %s "
                   "(matphot default fitrad: wall %s, CPU %s)", n,
               fmtv(b1, sizeof b1, ratio(&T, "mp", "dao", 0), "%.3f"),
               fmtv(b2, sizeof b2, ratio(&T, "mp", "dao", 1), "%.3f"),
               fmtv(b3, sizeof b3, ratio(&T, "mpd", "dao", 0), "%.3f"),
               fmtv(b4, sizeof b4, ratio(&T, "mpd", "dao", 1), "%.3f"));
            if (tool_ok(F, "mpb"))     /* "daopsf" is a time, not a catalogue */
                el(&S, "  time matphot with its PSF built from the frame / DAOPHOT %d passes + psf: "
                       "wall %s, CPU %s (runs %s)", n,
                   fmtv(b1, sizeof b1, ratio(&T, "mpb", "daopsf", 0), "%.3f"),
                   fmtv(b2, sizeof b2, ratio(&T, "mpb", "daopsf", 1), "%.3f"),
                   ratio_span(&T, "mpb", "daopsf", 1, b3, sizeof b3));
            static const char *const sl[5] = { "matphot fitrad=FWHM", "matphot default    ",
                                               "matphot PSF built  ", "DAOPHOT varorder 0 ",
                                               "DAOPHOT analytic   " };
            static const char *const st_[5] = { "mp", "mpd", "mpb", "dao", "daoa" };
            for (int k = 0; k < 5; k++) {
                if (!tool_ok(F, st_[k])) continue;   /* mp, mpd, dao: checked above */
                const cmp_tool *U = tool_get(F, st_[k]);
                el(&S, "  %s completeness %s%%, NN <1/1-2/2-3/>3 FWHM ", sl[k],
                   pct(b1, sizeof b1, some(U->compl)));
                for (int b = 0; b < CMP_NSEP; b++)
                    sb_cat(&S, "%s%s", b ? "/" : "", pct(b2, sizeof b2, U->by_sep[b].compl));
                sb_cat(&S, "%%, spurious %ld, sigma dmag %s", U->spurious,
                       fmtv(b3, sizeof b3, U->sigma_all, "%.3f"));
            }
        }
    }
    el(&B, "## Commands\n");
    el(&B, "From the top of the tree, with ./matphot built and IRAF installed "
           "(`apt-get install --no-install-recommends iraf iraf-noao`):\n");
    el(&B, "```sh\nsh tests/bench/compare_daophot.sh          # FRAMES=\"A B C\" REPS=3 NITER=3 MATPHOT_THREADS=1\n```\n");
    el(&B, "What it runs, frame by frame (each in its own directory):\n");
    el(&B, "```sh\n%s```\n", cmp_stats_meta(s, "commands", ""));
    el(&B, "The IRAF CL scripts of the last DAOPHOT run of frame %s, one "
           "`irafcl -f` each (find.cl, then the others; WORKDIR is the script's temporary directory):\n",
       s->frames[s->nframe - 1].name);
    el(&B, "```\n%s```\n", cmp_stats_meta(s, "cl_example", ""));
    if (A.oom || B.oom || S.oom) goto out;

    FILE *o = fopen(out, "w");
    if (!o) {
        fprintf(stderr, "compare: %s: %s\n", out, strerror(errno));
        goto done;
    }
    fprintf(o, "%s\n## Summary\n\n```\n%s\n```\n\n%s", A.s ? A.s : "", S.s ? S.s : "", B.s ? B.s : "");
    if (ferror(o) | fclose(o)) {
        fprintf(stderr, "compare: %s: write error\n", out);
        goto done;
    }
    if (S.s) {                                   /* the summary lines */
        for (char *p = S.s, *e; *p; p = e + 1) {
            e = strchr(p, '\n');
            if (!e) { printf("compare_daophot: %s\n", p); break; }
            printf("compare_daophot: %.*s\n", (int)(e - p), p);
        }
    }
    rc = 0;
    goto done;
out:
    fprintf(stderr, "compare: out of memory\n");
done:
    free(A.s); free(B.s); free(S.s);
    free(T.ra); free(T.rb); free(T.wa); free(T.ca); free(T.wb); free(T.cb); free(T.r);
    cmp_stats_free(&st);
    return rc;
}
