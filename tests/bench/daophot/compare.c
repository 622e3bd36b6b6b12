/*
 * compare.c -- helpers of tests/bench/compare_daophot.sh (matphot against
 * IRAF DAOPHOT).
 *
 *   compare pststars TRUTH FWHM PSFRAD NX NY N OUT
 *       the N least contaminated bright stars of the truth table, as a
 *       DAOFIND-style coordinate list (x y), for DAOPHOT's psf task
 *   compare stats WORKDIR OUT
 *       match the catalogues in WORKDIR/FRAME/cat/ to WORKDIR/FRAME/FRAME.truth,
 *       add up the run times of WORKDIR/runs.tsv, write the numbers to OUT
 *       (a tab-separated stats file, see report.c)
 *   compare report STATS REPORT.md
 *       the Markdown report and a short summary on stdout
 *
 * matphot tables (ASCII_HEAD) are read with mp_table_read; IRAF's
 * APPHOT/DAOPHOT text databases (.coo, .mag, .als) with read_iraf_db below.
 * The statistics follow numpy: median of an even count = mean of the two
 * middle values, percentiles by linear interpolation ("linear" method),
 * pairs matched closest first with ties in generation order (a stable sort).
 */
#include "compare.h"

#include <errno.h>
#include <math.h>
#include <stdarg.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/stat.h>

#include "catalog/catalog.h"

double cmp_sep_edge(int k)
{
    static const double e[CMP_NSEP + 1] = { 0.0, 1.0, 2.0, 3.0, INFINITY };
    return e[k];
}

const char *cmp_sep_name(int k)
{
    static const char *const n[CMP_NSEP] = { "< 1", "1-2", "2-3", "> 3" };
    return n[k];
}

char *cmp_strdup(const char *s)
{
    size_t n = strlen(s) + 1;
    char *p = malloc(n);
    if (p) memcpy(p, s, n);
    return p;
}

static void oom(void) { fprintf(stderr, "compare: out of memory\n"); }

/* ---------------------------------------------------------------- stats */
int cmp_stats_meta_add(cmp_stats *s, const char *key, const char *val)
{
    for (size_t i = 0; i < s->nmeta; i++)
        if (strcmp(s->key[i], key) == 0) {       /* a dict: the last wins */
            char *v = cmp_strdup(val);
            if (!v) return -1;
            free(s->val[i]);
            s->val[i] = v;
            return 0;
        }
    char **k = realloc(s->key, (s->nmeta + 1) * sizeof *k);
    if (!k) return -1;
    s->key = k;
    char **v = realloc(s->val, (s->nmeta + 1) * sizeof *v);
    if (!v) return -1;
    s->val = v;
    k[s->nmeta] = cmp_strdup(key);
    v[s->nmeta] = cmp_strdup(val);
    if (!k[s->nmeta] || !v[s->nmeta]) {
        free(k[s->nmeta]);
        free(v[s->nmeta]);
        return -1;
    }
    s->nmeta++;
    return 0;
}

const char *cmp_stats_meta(const cmp_stats *s, const char *key, const char *dflt)
{
    for (size_t i = 0; i < s->nmeta; i++)
        if (strcmp(s->key[i], key) == 0) return s->val[i];
    return dflt;
}

int cmp_stats_time_add(cmp_stats *s, const char *frame, const char *tool, long run,
                       double wall, double user, double sys)
{
    if (s->ntime == s->captime) {
        size_t c = s->captime ? 2 * s->captime : 64;
        cmp_time *t = realloc(s->times, c * sizeof *t);
        if (!t) return -1;
        s->times = t;
        s->captime = c;
    }
    cmp_time *t = &s->times[s->ntime];
    t->frame = cmp_strdup(frame);
    t->tool = cmp_strdup(tool);
    if (!t->frame || !t->tool) {
        free(t->frame);
        free(t->tool);
        return -1;
    }
    t->run = run;
    t->wall = wall;
    t->user = user;
    t->sys = sys;
    s->ntime++;
    return 0;
}

void cmp_stats_free(cmp_stats *s)
{
    for (size_t i = 0; i < s->nmeta; i++) {
        free(s->key[i]);
        free(s->val[i]);
    }
    free(s->key);
    free(s->val);
    for (size_t i = 0; i < s->nframe; i++) {
        cmp_frame *f = &s->frames[i];
        free(f->name);
        free(f->desc);
        free(f->simcmd);
        for (int t = 0; t < CMP_NTOOL; t++) free(f->tools[t].missing);
    }
    free(s->frames);
    for (size_t i = 0; i < s->ntime; i++) {
        free(s->times[i].frame);
        free(s->times[i].tool);
    }
    free(s->times);
    memset(s, 0, sizeof *s);
}

/* ---------------------------------------------------------------- numbers */
static int cmp_double(const void *a, const void *b)
{
    double x = *(const double *)a, y = *(const double *)b;
    return (x > y) - (x < y);
}

/* sorted copy; NULL when out of memory, *hasnan when v holds a NaN */
static double *sorted_copy(const double *v, size_t n, int *hasnan)
{
    double *c = malloc((n ? n : 1) * sizeof *c);
    if (!c) return NULL;
    *hasnan = 0;
    for (size_t i = 0; i < n; i++) {
        c[i] = v[i];
        if (isnan(v[i])) *hasnan = 1;
    }
    qsort(c, n, sizeof *c, cmp_double);
    return c;
}

double cmp_median(const double *v, size_t n)
{
    int hasnan;
    double *c = sorted_copy(v, n, &hasnan);
    if (!c) { oom(); exit(1); }
    double m = hasnan ? NAN
             : n % 2 ? c[n / 2] : (c[n / 2 - 1] + c[n / 2]) / 2.0;
    free(c);
    return m;
}

/* numpy's percentile, method "linear", on sorted c[n] */
static double percentile_sorted(const double *c, size_t n, double q)
{
    double g = (double)(n - 1) * (q / 100.0);
    double pf = floor(g);
    size_t prev = (size_t)pf, next = prev + 1;
    if (g >= (double)(n - 1)) prev = next = n - 1;
    double gamma = g - pf;
    double a = c[prev], b = c[next], d = b - a;
    return gamma >= 0.5 ? b - d * (1.0 - gamma) : a + d * gamma;
}

/* IQR/1.349; None below 5 values */
static cmp_opt robust_sigma(const double *v, size_t n)
{
    cmp_opt r = { 0, 0.0 };
    if (n < 5) return r;
    int hasnan;
    double *c = sorted_copy(v, n, &hasnan);
    if (!c) { oom(); exit(1); }
    r.ok = 1;
    r.v = hasnan ? NAN
        : (percentile_sorted(c, n, 75.0) - percentile_sorted(c, n, 25.0)) / 1.349;
    free(c);
    return r;
}

/* ---------------------------------------------------------------- tables */
typedef struct { size_t n; double *x, *y, *m; } xym;

static void xym_free(xym *c) { free(c->x); free(c->y); free(c->m); c->x = c->y = c->m = NULL; }

/* columns of an ASCII_HEAD table (NULL names are skipped) */
static int read_table_cols(const char *path, const char *const *names, int ncol,
                           size_t *n, double **out)
{
    mp_table t;
    char err[MP_ERRLEN];
    if (mp_table_read(path, &t, err)) {
        fprintf(stderr, "compare: %s\n", err);
        mp_table_free(&t);
        return -1;
    }
    int rc = 0;
    for (int k = 0; k < ncol; k++) out[k] = NULL;
    for (int k = 0; k < ncol && !rc; k++) {
        int c = mp_table_col(&t, names[k]);
        if (c < 0) {
            fprintf(stderr, "compare: %s: no column %s\n", path, names[k]);
            rc = -1;
            break;
        }
        out[k] = malloc((t.nrow ? t.nrow : 1) * sizeof(double));
        if (!out[k]) { oom(); rc = -1; break; }
        for (size_t i = 0; i < t.nrow; i++) out[k][i] = mp_table_get(&t, i, c);
    }
    *n = t.nrow;
    mp_table_free(&t);
    if (rc)
        for (int k = 0; k < ncol; k++) { free(out[k]); out[k] = NULL; }
    return rc;
}

/* one whitespace-separated token list */
typedef struct { size_t n, cap; char **w; } toks;

static void toks_free(toks *t)
{
    for (size_t i = 0; i < t->n; i++) free(t->w[i]);
    free(t->w);
    t->w = NULL;
    t->n = t->cap = 0;
}

/* split s (backslashes read as blanks) onto t */
static int toks_split(toks *t, char *s)
{
    for (char *p = s; *p; p++)
        if (*p == '\\') *p = ' ';
    for (char *save = NULL, *w = strtok_r(s, " \t\r\n\v\f", &save); w;
         w = strtok_r(NULL, " \t\r\n\v\f", &save)) {
        if (t->n == t->cap) {
            size_t c = t->cap ? 2 * t->cap : 16;
            char **nw = realloc(t->w, c * sizeof *nw);
            if (!nw) return -1;
            t->w = nw;
            t->cap = c;
        }
        if (!(t->w[t->n] = cmp_strdup(w))) return -1;
        t->n++;
    }
    return 0;
}

static int is_blank(const char *s)
{
    for (; *s; s++)
        if (!strchr(" \t\r\n\v\f", *s)) return 0;
    return 1;
}

/* XCENTER, YCENTER, MAG of an APPHOT/DAOPHOT text database: "#N" lines name
 * the fields (continued with a backslash), other "#" lines are skipped, a
 * record is the fields of one or more lines, each but its last ending in a
 * backslash.  Records with INDEF in any of the three are left out, and so
 * are records too short to hold them. */
static int read_iraf_db(const char *path, xym *c)
{
    FILE *f = fopen(path, "r");
    if (!f) {
        fprintf(stderr, "compare: %s: %s\n", path, strerror(errno));
        return -1;
    }
    toks names = { 0, 0, NULL }, rec = { 0, 0, NULL };
    size_t cap = 0;
    char *line = NULL;
    size_t lcap = 0;
    int rc = 0;
    long ix = -1, iy = -1, im = -1;
    c->n = 0;
    c->x = c->y = c->m = NULL;
    while (getline(&line, &lcap, f) >= 0) {
        size_t len = strlen(line);
        if (len && line[len - 1] == '\n') line[--len] = '\0';
        if (strncmp(line, "#N", 2) == 0) {
            if (toks_split(&names, line + 2)) { rc = -1; break; }
            continue;
        }
        if (line[0] == '#' || is_blank(line)) continue;
        size_t e = len;
        while (e && strchr(" \t\r\n\v\f", line[e - 1])) e--;
        int cont = e && line[e - 1] == '\\';
        if (toks_split(&rec, line)) { rc = -1; break; }
        if (cont) continue;
        if (ix < 0) {
            for (size_t k = names.n; k-- > 0;) {
                if (strcmp(names.w[k], "XCENTER") == 0) ix = (long)k;
                if (strcmp(names.w[k], "YCENTER") == 0) iy = (long)k;
                if (strcmp(names.w[k], "MAG") == 0) im = (long)k;
            }
            if (ix < 0 || iy < 0 || im < 0) { toks_free(&rec); break; }   /* no rows */
        }
        size_t need = (size_t)(ix > iy ? (ix > im ? ix : im) : (iy > im ? iy : im));
        if (rec.n > need) {
            const char *s[3] = { rec.w[ix], rec.w[iy], rec.w[im] };
            if (strcmp(s[0], "INDEF") && strcmp(s[1], "INDEF") && strcmp(s[2], "INDEF")) {
                double v[3];
                for (int k = 0; k < 3; k++) {
                    char *end;
                    v[k] = strtod(s[k], &end);
                    if (end == s[k] || *end) {
                        fprintf(stderr, "compare: %s: not a number: %s\n", path, s[k]);
                        rc = -1;
                    }
                }
                if (rc) break;
                if (c->n == cap) {
                    size_t nc = cap ? 2 * cap : 256;
                    double *nx = realloc(c->x, nc * sizeof *nx);
                    if (nx) c->x = nx;
                    double *ny = realloc(c->y, nc * sizeof *ny);
                    if (ny) c->y = ny;
                    double *nm = realloc(c->m, nc * sizeof *nm);
                    if (nm) c->m = nm;
                    if (!nx || !ny || !nm) { rc = -1; break; }
                    cap = nc;
                }
                c->x[c->n] = v[0];
                c->y[c->n] = v[1];
                c->m[c->n] = v[2];
                c->n++;
            }
        }
        toks_free(&rec);
    }
    if (rc == 0 && ferror(f)) {
        fprintf(stderr, "compare: %s: read error\n", path);
        rc = -2;
    }
    if (rc == -1 && errno == ENOMEM) oom();
    free(line);
    toks_free(&names);
    toks_free(&rec);
    fclose(f);
    if (rc) xym_free(c);
    return rc ? -1 : 0;
}

/* ---------------------------------------------------------------- geometry */
typedef struct { size_t n, cap; size_t *i, *j; double *d; } pairs;

static void pairs_free(pairs *p) { free(p->i); free(p->j); free(p->d); memset(p, 0, sizeof *p); }

static int pairs_push(pairs *p, size_t i, size_t j, double d)
{
    if (p->n == p->cap) {
        size_t c = p->cap ? 2 * p->cap : 1024;
        size_t *ni = realloc(p->i, c * sizeof *ni);
        if (ni) p->i = ni;
        size_t *nj = realloc(p->j, c * sizeof *nj);
        if (nj) p->j = nj;
        double *nd = realloc(p->d, c * sizeof *nd);
        if (nd) p->d = nd;
        if (!ni || !nj || !nd) return -1;
        p->cap = c;
    }
    p->i[p->n] = i;
    p->j[p->n] = j;
    p->d[p->n] = d;
    p->n++;
    return 0;
}

typedef struct { long long cx, cy; size_t j; } cellent;

static int cmp_cellent(const void *a, const void *b)
{
    const cellent *p = a, *q = b;
    if (p->cx != q->cx) return p->cx < q->cx ? -1 : 1;
    if (p->cy != q->cy) return p->cy < q->cy ? -1 : 1;
    return (p->j > q->j) - (p->j < q->j);
}

/* All (i, j, d) with |p1_i - p2_j| <= r, through a grid of cell r, in the
 * order: i, then the cells dx = -1..1, dy = -1..1, then j.  Points with a
 * non-finite coordinate never pair. */
static int pairs_within(const double *x1, const double *y1, size_t n1,
                        const double *x2, const double *y2, size_t n2,
                        double r, pairs *p)
{
    memset(p, 0, sizeof *p);
    if (n1 == 0 || n2 == 0) return 0;
    cellent *g = malloc(n2 * sizeof *g);
    if (!g) return -1;
    size_t ng = 0;
    for (size_t j = 0; j < n2; j++) {
        if (!isfinite(x2[j]) || !isfinite(y2[j])) continue;
        g[ng].cx = (long long)floor(x2[j] / r);
        g[ng].cy = (long long)floor(y2[j] / r);
        g[ng].j = j;
        ng++;
    }
    qsort(g, ng, sizeof *g, cmp_cellent);
    for (size_t i = 0; i < n1; i++) {
        if (!isfinite(x1[i]) || !isfinite(y1[i])) continue;
        long long cx = (long long)floor(x1[i] / r), cy = (long long)floor(y1[i] / r);
        for (int dx = -1; dx <= 1; dx++)
            for (int dy = -1; dy <= 1; dy++) {
                cellent key = { cx + dx, cy + dy, 0 };
                size_t lo = 0, hi = ng;          /* first entry >= key */
                while (lo < hi) {
                    size_t mid = lo + (hi - lo) / 2;
                    if (cmp_cellent(&g[mid], &key) < 0) lo = mid + 1; else hi = mid;
                }
                for (size_t k = lo; k < ng && g[k].cx == key.cx && g[k].cy == key.cy; k++) {
                    size_t j = g[k].j;
                    double d = hypot(x1[i] - x2[j], y1[i] - y2[j]);
                    if (d <= r && pairs_push(p, i, j, d)) { free(g); pairs_free(p); return -1; }
                }
            }
    }
    free(g);
    return 0;
}

/* distance of each point to its nearest other point (inf beyond rmax) */
static int nearest_neighbour(const double *x, const double *y, size_t n, double rmax, double *nn)
{
    pairs p;
    if (pairs_within(x, y, n, x, y, n, rmax, &p)) return -1;
    for (size_t k = 0; k < n; k++) nn[k] = INFINITY;
    for (size_t k = 0; k < p.n; k++)
        if (p.i[k] != p.j[k] && p.d[k] < nn[p.i[k]]) nn[p.i[k]] = p.d[k];
    pairs_free(&p);
    return 0;
}

typedef struct { double d; size_t k; } dk;

static int cmp_dk(const void *a, const void *b)
{
    const dk *p = a, *q = b;
    if (p->d != q->d) return p->d < q->d ? -1 : 1;
    return (p->k > q->k) - (p->k < q->k);
}

/* one-to-one matching, closest pairs first: t2c[truth] = catalogue row or -1 */
static int match(const xym *t, const xym *c, double r, long *t2c)
{
    pairs p;
    if (pairs_within(t->x, t->y, t->n, c->x, c->y, c->n, r, &p)) return -1;
    dk *o = malloc((p.n ? p.n : 1) * sizeof *o);
    unsigned char *used = calloc(c->n ? c->n : 1, 1);
    if (!o || !used) { free(o); free(used); pairs_free(&p); return -1; }
    for (size_t k = 0; k < p.n; k++) { o[k].d = p.d[k]; o[k].k = k; }
    qsort(o, p.n, sizeof *o, cmp_dk);
    for (size_t k = 0; k < t->n; k++) t2c[k] = -1;
    for (size_t q = 0; q < p.n; q++) {
        size_t k = o[q].k;
        if (t2c[p.i[k]] < 0 && !used[p.j[k]]) {
            t2c[p.i[k]] = (long)p.j[k];
            used[p.j[k]] = 1;
        }
    }
    free(o);
    free(used);
    pairs_free(&p);
    return 0;
}

/* ---------------------------------------------------------------- pststars */
static int num_arg(const char *s, double *v)
{
    char *end;
    errno = 0;
    *v = strtod(s, &end);
    if (end == s || *end || errno) {
        fprintf(stderr, "compare: not a number: %s\n", s);
        return -1;
    }
    return 0;
}

static int cmd_pststars(char **a)
{
    double fwhm, psfrad, nx, ny, nd;
    if (num_arg(a[1], &fwhm) || num_arg(a[2], &psfrad) || num_arg(a[3], &nx)
        || num_arg(a[4], &ny) || num_arg(a[5], &nd))
        return 1;
    long n = (long)nd;
    static const char *const cols[3] = { "X_IMAGE", "Y_IMAGE", "FLUX_TRUE" };
    double *v[3];
    size_t nt;
    if (read_table_cols(a[0], cols, 3, &nt, v)) return 1;
    double *x = v[0], *y = v[1], *f = v[2];
    double sig = fwhm / 2.3548200450309493;
    /* light of every neighbour inside the PSF star's psfrad circle
     * (Gaussian, roughly: the neighbour's light within psfrad+fwhm counted
     * at its peak weight), relative to the star's own flux */
    double R = psfrad + 3.0 * sig;
    pairs p;
    double *contam = calloc(nt ? nt : 1, sizeof *contam);
    double *fl = malloc((nt ? nt : 1) * sizeof *fl);
    dk *cand = malloc((nt ? nt : 1) * sizeof *cand);
    unsigned char *ok = malloc(nt ? nt : 1);
    int rc = 1;
    if (!contam || !fl || !cand || !ok || pairs_within(x, y, nt, x, y, nt, R, &p)) {
        oom();
        goto out;
    }
    for (size_t k = 0; k < p.n; k++) {
        if (p.i[k] == p.j[k]) continue;
        double c = p.d[k] - psfrad;
        if (c < 0) c = 0;
        double w = exp(-0.5 * (c * c) / (sig * sig));
        contam[p.i[k]] += f[p.j[k]] * w;
    }
    pairs_free(&p);
    for (size_t k = 0; k < nt; k++) contam[k] /= f[k];
    double edge = psfrad + 2.0;
    size_t nok = 0;
    for (size_t k = 0; k < nt; k++) {
        ok[k] = x[k] > edge && x[k] < nx - edge + 1 && y[k] > edge && y[k] < ny - edge + 1;
        if (ok[k]) fl[nok++] = f[k];
    }
    /* bright: the top third in flux of the stars away from the edge */
    qsort(fl, nok, sizeof *fl, cmp_double);                  /* ascending */
    double fcut = 0;
    if (nok) {
        size_t r = nok / 3 >= 1 ? nok / 3 - 1 : 0;           /* descending rank */
        fcut = fl[nok - 1 - r];
    }
    size_t nc = 0;
    for (size_t k = 0; k < nt; k++)
        if (ok[k] && f[k] >= fcut) { cand[nc].d = contam[k]; cand[nc].k = k; nc++; }
    qsort(cand, nc, sizeof *cand, cmp_dk);
    if (n < 0) n = 0;
    if ((size_t)n < nc) nc = (size_t)n;
    FILE *o = fopen(a[6], "w");
    if (!o) {
        fprintf(stderr, "compare: %s: %s\n", a[6], strerror(errno));
        goto out;
    }
    double cmax = 0;
    for (size_t k = 0; k < nc; k++) {
        fprintf(o, "%.3f %.3f\n", x[cand[k].k], y[cand[k].k]);
        if (k == 0 || cand[k].d > cmax) cmax = cand[k].d;
    }
    if (fclose(o)) {
        fprintf(stderr, "compare: %s: write error\n", a[6]);
        goto out;
    }
    fprintf(stderr, "pststars: %zu stars, contamination max %.4f\n", nc, cmax);
    rc = 0;
out:
    free(contam); free(fl); free(cand); free(ok);
    free(x); free(y); free(f);
    return rc;
}

/* ---------------------------------------------------------------- stats */
static int in_bin(double v, double lo, double hi) { return v >= lo && v < hi; }

/* the numbers of one bin: sel[k] selects true star k */
static void binstats(const unsigned char *sel, const long *t2c, const double *dmz,
                     size_t nt, double *buf, cmp_bin *b)
{
    long n = 0, h = 0;
    for (size_t k = 0; k < nt; k++) {
        if (!sel[k]) continue;
        n++;
        if (t2c[k] >= 0) buf[h++] = dmz[k];
    }
    b->n = n;
    b->found = h;
    b->compl.ok = n > 0;
    b->compl.v = n ? (double)h / (double)n : 0;
    b->sigma = robust_sigma(buf, (size_t)h);
    b->bias.ok = h >= 5;
    b->bias.v = h >= 5 ? cmp_median(buf, (size_t)h) : 0;
}

static int tool_stats(const xym *t, const double *nn, const cmp_frame *fr,
                      const xym *c, cmp_tool *T)
{
    size_t nt = t->n;
    long *t2c = malloc((nt ? nt : 1) * sizeof *t2c);
    double *dmz = malloc((nt ? nt : 1) * sizeof *dmz);
    double *buf = malloc((nt ? nt : 1) * sizeof *buf);
    double *bx = malloc((nt ? nt : 1) * sizeof *bx);
    double *by = malloc((nt ? nt : 1) * sizeof *by);
    unsigned char *sel = malloc(nt ? nt : 1);
    unsigned char *used = calloc(c->n ? c->n : 1, 1);
    int rc = -1;
    if (!t2c || !dmz || !buf || !bx || !by || !sel || !used) goto out;
    if (match(t, c, 1.0, t2c)) goto out;
    size_t nhit = 0, nb = 0;
    for (size_t k = 0; k < nt; k++) {
        dmz[k] = NAN;
        if (t2c[k] < 0) continue;
        nhit++;
        dmz[k] = c->m[t2c[k]] - t->m[k];
        used[t2c[k]] = 1;
        if (t->m[k] < fr->edges[0] + 3.0) buf[nb++] = dmz[k];
    }
    double zp = nb ? cmp_median(buf, nb) : 0.0;
    for (size_t k = 0; k < nt; k++) dmz[k] -= zp;
    /* unmatched detections with no true star within 1 FWHM: spurious */
    size_t nun = 0;
    for (size_t j = 0; j < c->n; j++)
        if (!used[j]) nun++;
    long spurious = 0;
    if (nun) {
        double *ux = malloc(nun * sizeof *ux), *uy = malloc(nun * sizeof *uy);
        unsigned char *near = calloc(nun, 1);
        pairs p;
        if (!ux || !uy || !near) { free(ux); free(uy); free(near); goto out; }
        size_t q = 0;
        for (size_t j = 0; j < c->n; j++)
            if (!used[j]) { ux[q] = c->x[j]; uy[q] = c->y[j]; q++; }
        if (pairs_within(ux, uy, nun, t->x, t->y, nt, fr->fwhm, &p)) {
            free(ux); free(uy); free(near);
            goto out;
        }
        for (size_t k = 0; k < p.n; k++) near[p.i[k]] = 1;
        for (size_t k = 0; k < nun; k++) spurious += !near[k];
        pairs_free(&p);
        free(ux); free(uy); free(near);
    }
    size_t nh = 0;
    for (size_t k = 0; k < nt; k++)
        if (t2c[k] >= 0) {
            bx[nh] = c->x[t2c[k]] - t->x[k];
            by[nh] = c->y[t2c[k]] - t->y[k];
            nh++;
        }
    T->ndet = (long)c->n;
    T->found = (long)nhit;
    T->compl = (double)nhit / (double)nt;
    T->nfalse = (long)nun;
    T->spurious = spurious;
    T->zp = zp;
    T->dx.ok = T->dy.ok = T->posrms.ok = nh > 0;
    T->dx.v = nh ? cmp_median(bx, nh) : 0;
    T->dy.v = nh ? cmp_median(by, nh) : 0;
    if (nh) {
        for (size_t k = 0; k < nh; k++) buf[k] = hypot(bx[k], by[k]);
        T->posrms = robust_sigma(buf, nh);
    }
    nb = 0;
    for (size_t k = 0; k < nt; k++)
        if (t2c[k] >= 0) buf[nb++] = dmz[k];
    T->sigma_all = robust_sigma(buf, nb);
    T->nmag = fr->nedge - 1;
    for (int b = 0; b < T->nmag; b++) {
        for (size_t k = 0; k < nt; k++) sel[k] = in_bin(t->m[k], fr->edges[b], fr->edges[b + 1]);
        binstats(sel, t2c, dmz, nt, buf, &T->by_mag[b]);
        for (size_t k = 0; k < nt; k++) sel[k] = sel[k] && nn[k] < 2.0;
        binstats(sel, t2c, dmz, nt, buf, &T->by_mag_blend[b]);
    }
    for (int b = 0; b < CMP_NSEP; b++) {
        for (size_t k = 0; k < nt; k++) sel[k] = in_bin(nn[k], cmp_sep_edge(b), cmp_sep_edge(b + 1));
        binstats(sel, t2c, dmz, nt, buf, &T->by_sep[b]);
    }
    rc = 0;
out:
    if (rc) oom();
    free(t2c); free(dmz); free(buf); free(bx); free(by); free(sel); free(used);
    return rc;
}

static char *path_join(const char *a, const char *b, const char *c)
{
    size_t n = strlen(a) + strlen(b) + (c ? strlen(c) : 0) + 3;
    char *p = malloc(n);
    if (!p) return NULL;
    if (c) snprintf(p, n, "%s/%s/%s", a, b, c);
    else snprintf(p, n, "%s/%s", a, b);
    return p;
}

static int frame_stats(const char *workdir, cmp_frame *fr)
{
    static const char *const names[CMP_NTOOL] = { "mp", "mpd", "mpb", "dao1", "dao", "daoa" };
    static const char *const files[CMP_NTOOL] = { "mp.cat", "mpd.cat", "mpb.cat", "dao1.als", "dao.als",
                                                  "daoa.als" };
    static const char *const tcols[3] = { "X_IMAGE", "Y_IMAGE", "MAG_TRUE" };
    static const char *const mcols[3] = { "XPSF_IMAGE", "YPSF_IMAGE", "MAG_PSF" };
    size_t tn = strlen(fr->name) + 7;
    char *tname = malloc(tn);
    char *tpath = NULL;
    if (tname) {
        snprintf(tname, tn, "%s.truth", fr->name);
        tpath = path_join(workdir, fr->name, tname);
    }
    free(tname);
    if (!tpath) { oom(); return -1; }
    xym t = { 0, NULL, NULL, NULL };
    double *v[3];
    int rc = read_table_cols(tpath, tcols, 3, &t.n, v);
    free(tpath);
    if (rc) return -1;
    t.x = v[0]; t.y = v[1]; t.m = v[2];
    double *nn = malloc((t.n ? t.n : 1) * sizeof *nn);
    if (!nn || nearest_neighbour(t.x, t.y, t.n, 6.0 * fr->fwhm, nn)) {
        oom();
        free(nn);
        xym_free(&t);
        return -1;
    }
    for (size_t k = 0; k < t.n; k++) nn[k] /= fr->fwhm;
    double lo = floor(fmin(fr->magmin, fr->magmax));
    double stop = ceil(fmax(fr->magmin, fr->magmax)) + 1e-9;
    double ne = ceil(stop - lo);                              /* numpy arange */
    if (!(ne >= 2 && ne <= CMP_MAXBIN + 1)) {
        fprintf(stderr, "compare: frame %s: magnitude range %g..%g gives %g bin edges\n",
                fr->name, fr->magmin, fr->magmax, ne);
        free(nn);
        xym_free(&t);
        return -1;
    }
    fr->nedge = (int)ne;
    for (int e = 0; e < fr->nedge; e++) fr->edges[e] = lo + e * 1.0;
    fr->ntrue = (long)t.n;
    for (int b = 0; b < CMP_NSEP; b++) {
        fr->ntrue_sep[b] = 0;
        for (size_t k = 0; k < t.n; k++)
            fr->ntrue_sep[b] += in_bin(nn[k], cmp_sep_edge(b), cmp_sep_edge(b + 1));
    }
    for (int b = 0; b < fr->nedge - 1; b++) {
        fr->ntrue_mag[b] = 0;
        for (size_t k = 0; k < t.n; k++)
            fr->ntrue_mag[b] += in_bin(t.m[k], fr->edges[b], fr->edges[b + 1]);
    }
    rc = 0;
    for (int i = 0; i < CMP_NTOOL && !rc; i++) {
        cmp_tool *T = &fr->tools[i];
        snprintf(T->name, sizeof T->name, "%s", names[i]);
        char *path = path_join(workdir, fr->name, "cat");
        char *p2 = path ? path_join(path, files[i], NULL) : NULL;
        free(path);
        if (!p2) { oom(); rc = -1; break; }
        struct stat st;
        if (stat(p2, &st) != 0) {
            T->missing = p2;
            continue;
        }
        xym c = { 0, NULL, NULL, NULL };
        if (strncmp(names[i], "mp", 2) == 0) {     /* matphot's tables; DAOPHOT's .als */
            double *cv[3];
            rc = read_table_cols(p2, mcols, 3, &c.n, cv);
            if (!rc) { c.x = cv[0]; c.y = cv[1]; c.m = cv[2]; }
        } else
            rc = read_iraf_db(p2, &c);
        free(p2);
        if (!rc) rc = tool_stats(&t, nn, fr, &c, T);
        xym_free(&c);
    }
    free(nn);
    xym_free(&t);
    return rc;
}

/* lines of a file without their newline; f(line, ctx) for each */
static int each_line(const char *path, int (*fn)(char *line, void *ctx), void *ctx)
{
    FILE *f = fopen(path, "r");
    if (!f) {
        fprintf(stderr, "compare: %s: %s\n", path, strerror(errno));
        return -1;
    }
    char *line = NULL;
    size_t cap = 0;
    ssize_t len;
    int rc = 0;
    while (!rc && (len = getline(&line, &cap, f)) >= 0) {
        if (len && line[len - 1] == '\n') line[--len] = '\0';
        rc = fn(line, ctx);
    }
    free(line);
    fclose(f);
    return rc;
}

static int meta_line(char *line, void *ctx)
{
    char *tab = strchr(line, '\t');
    if (!tab) return 0;
    *tab = '\0';
    if (cmp_stats_meta_add(ctx, line, tab + 1)) { oom(); return -1; }
    return 0;
}

static int frames_line(char *line, void *ctx)
{
    cmp_stats *s = ctx;
    char *p[6];
    int n = 0;
    for (char *q = line; n < 6; n++) {
        p[n] = q;
        char *tab = strchr(q, '\t');
        if (!tab) { n++; break; }
        *tab = '\0';
        q = tab + 1;
    }
    if (n < 6) return 0;
    /* the sixth field runs to the next tab (as Python's split) */
    char *tab = strchr(p[5], '\t');
    if (tab) *tab = '\0';
    cmp_frame *fr = realloc(s->frames, (s->nframe + 1) * sizeof *fr);
    if (!fr) { oom(); return -1; }
    s->frames = fr;
    fr = &s->frames[s->nframe];
    memset(fr, 0, sizeof *fr);
    s->nframe++;
    if (num_arg(p[1], &fr->fwhm) || num_arg(p[2], &fr->magmin) || num_arg(p[3], &fr->magmax))
        return -1;
    fr->name = cmp_strdup(p[0]);
    fr->desc = cmp_strdup(p[4]);
    fr->simcmd = cmp_strdup(p[5]);
    if (!fr->name || !fr->desc || !fr->simcmd) { oom(); return -1; }
    return 0;
}

static int runs_line(char *line, void *ctx)
{
    char *w[6], *save = NULL;
    int n = 0;
    for (char *t = strtok_r(line, " \t\r\v\f", &save); t && n < 6;
         t = strtok_r(NULL, " \t\r\v\f", &save))
        w[n++] = t;
    if (n < 6) return 0;
    double run, v[3];
    if (num_arg(w[2], &run) || num_arg(w[3], &v[0]) || num_arg(w[4], &v[1]) || num_arg(w[5], &v[2]))
        return -1;
    if (cmp_stats_time_add(ctx, w[0], w[1], (long)run, v[0], v[1], v[2])) { oom(); return -1; }
    return 0;
}

static int read_whole(const char *path, char **out)
{
    *out = NULL;
    FILE *f = fopen(path, "r");
    if (!f) return errno == ENOENT ? 1 : -1;
    size_t n = 0, cap = 4096;
    char *b = malloc(cap);
    size_t got;
    while (b && (got = fread(b + n, 1, cap - n - 1, f)) > 0) {
        n += got;
        if (cap - n - 1 == 0) {
            char *nb = realloc(b, 2 * cap);
            if (!nb) { free(b); b = NULL; break; }
            b = nb;
            cap *= 2;
        }
    }
    int bad = ferror(f);
    fclose(f);
    if (!b) { oom(); return -1; }
    if (bad) { free(b); fprintf(stderr, "compare: %s: read error\n", path); return -1; }
    b[n] = '\0';
    *out = b;
    return 0;
}

/* the DAOPHOT totals: tool = sum of parts, run by run */
static int dao_totals(cmp_stats *s)
{
    static const char *const tot[4] = { "dao1", "dao", "daopsf", "daoa" };
    static const char *const need[4][4] = {
        { "dao_find", "dao_als1", NULL, NULL },
        { "dao_find", "dao_als1", "dao_refind", NULL },
        { "dao_find", "dao_als1", "dao_refind", "dao_psf" },
        { "daoa_find", "daoa_als1", "daoa_refind", NULL } };
    for (size_t fi = 0; fi < s->nframe; fi++) {
        const char *fn = s->frames[fi].name;
        size_t n0 = s->ntime;
        long *runs = malloc((n0 ? n0 : 1) * sizeof *runs);
        if (!runs) { oom(); return -1; }
        size_t nr = 0;
        for (size_t k = 0; k < n0; k++) {
            if (strcmp(s->times[k].frame, fn)) continue;
            size_t q = 0;
            while (q < nr && runs[q] != s->times[k].run) q++;
            if (q == nr) runs[nr++] = s->times[k].run;
        }
        for (size_t a = 0; a < nr; a++)          /* sorted */
            for (size_t b = a + 1; b < nr; b++)
                if (runs[b] < runs[a]) { long x = runs[a]; runs[a] = runs[b]; runs[b] = x; }
        for (size_t q = 0; q < nr; q++) {
            size_t nt = s->ntime;   /* parts: the entries before this run's totals */
            for (int t = 0; t < 4; t++) {
                double w = 0, u = 0, y = 0;
                int all = 1;
                for (int p = 0; p < 4 && need[t][p]; p++) {
                    long last = -1;   /* the last entry of that tool wins */
                    for (size_t k = 0; k < nt; k++)
                        if (s->times[k].run == runs[q] && !strcmp(s->times[k].frame, fn)
                            && !strcmp(s->times[k].tool, need[t][p]))
                            last = (long)k;
                    if (last < 0) { all = 0; break; }
                    w += s->times[last].wall;
                    u += s->times[last].user;
                    y += s->times[last].sys;
                }
                if (all && cmp_stats_time_add(s, fn, tot[t], runs[q], w, u, y)) {
                    oom();
                    free(runs);
                    return -1;
                }
            }
        }
        free(runs);
    }
    return 0;
}

static int cmd_stats(const char *workdir, const char *out)
{
    cmp_stats s;
    memset(&s, 0, sizeof s);
    int rc = -1;
    char *p = path_join(workdir, "meta.tsv", NULL);
    if (!p || each_line(p, meta_line, &s)) goto out;
    free(p);
    if (!(p = path_join(workdir, "frames.tsv", NULL)) || each_line(p, frames_line, &s)) goto out;
    static const char *const extra[2][2] = { { "commands", "commands.txt" },
                                             { "cl_example", "example.cl" } };
    for (int k = 0; k < 2; k++) {
        free(p);
        if (!(p = path_join(workdir, extra[k][1], NULL))) goto out;
        char *text;
        int r = read_whole(p, &text);
        if (r < 0) goto out;
        r = cmp_stats_meta_add(&s, extra[k][0], text ? text : "");
        free(text);
        if (r) { oom(); goto out; }
    }
    free(p);
    if (!(p = path_join(workdir, "runs.tsv", NULL)) || each_line(p, runs_line, &s)) goto out;
    if (dao_totals(&s)) goto out;
    for (size_t i = 0; i < s.nframe; i++)
        if (frame_stats(workdir, &s.frames[i])) goto out;
    rc = cmp_stats_write(out, &s);
out:
    if (!p) oom();
    free(p);
    cmp_stats_free(&s);
    return rc ? 1 : 0;
}

static void usage(void)
{
    fputs("usage: compare pststars TRUTH FWHM PSFRAD NX NY N OUT\n"
          "       compare stats WORKDIR OUT\n"
          "       compare report STATS REPORT.md\n", stderr);
}

int main(int argc, char **argv)
{
    if (argc < 2) { usage(); return 2; }
    if (strcmp(argv[1], "pststars") == 0 && argc == 9) return cmd_pststars(argv + 2);
    if (strcmp(argv[1], "stats") == 0 && argc == 4) return cmd_stats(argv[2], argv[3]);
    if (strcmp(argv[1], "report") == 0 && argc == 4) return cmp_report(argv[2], argv[3]) ? 1 : 0;
    usage();
    return 2;
}
