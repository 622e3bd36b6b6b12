/* realcmp.c — helper of tests/bench/real/real.sh (issue 12: real frames
 * against IRAF DAOPHOT).
 *   realcmp sky IMAGE GAIN RON        the sky (20th percentile of the finite
 *                                     pixels: a crowded frame's median is on
 *                                     stars) and its noise √(sky·GAIN + RON²)/
 *                                     GAIN: DAOPHOT's datapars.sigma
 *   realcmp dao A.cat B.als RADIUS    matphot's catalog against DAOPHOT's:
 *                                     stars each, matched within RADIUS px
 *                                     (nearest, both ways), median Δmag and
 *                                     its robust σ, median |Δpos|
 *   realcmp same A.fit B.fit          two fits of the same stars (rows by
 *                                     NUMBER): |ΔE|/σ_E and |Δx|,|Δy|/σ_x
 *                                     (median, 99th percentile, max), and
 *                                     the medians of σ_E and σ_x ratios; all
 *                                     stars, then those of groups converged
 *                                     in both (FLAGS 8, 16 clear)
 *   realcmp truth A.fit T.truth       a fit of simulated stars against the
 *                                     truth: normalised errors in E and X
 *   realcmp timed OUT CMD...          run CMD; "wall user sys maxrss_kB" into
 *                                     OUT: the CPU of CMD and the children it
 *                                     waited for (getrusage RUSAGE_CHILDREN,
 *                                     as /usr/bin/time's wait4) to the
 *                                     microsecond, where /usr/bin/time prints
 *                                     10 ms; exits with CMD's status
 * One line on stdout each, "key value" pairs for the report. */
#include <errno.h>
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/resource.h>
#include <sys/wait.h>
#include <time.h>
#include <unistd.h>
#include "catalog/catalog.h"
#include "io/io.h"

static int cmpd(const void *a, const void *b)
{
    double x = *(const double *)a, y = *(const double *)b;
    return (x > y) - (x < y);
}

/* The p-th percentile (linear between order statistics) of v[0..n), sorted here. */
static double pct(double *v, size_t n, double p)
{
    if (n == 0)
        return NAN;
    qsort(v, n, sizeof *v, cmpd);
    double g = p / 100.0 * (double)(n - 1);
    size_t i = (size_t)g;
    return i + 1 < n ? v[i] + (g - (double)i) * (v[i + 1] - v[i]) : v[n - 1];
}

static double robust(double *v, size_t n)
{
    return n < 5 ? NAN : (pct(v, n, 75.0) - pct(v, n, 25.0)) / 1.349;
}

static int cmd_sky(const char *name, double gain, double ron)
{
    mp_image im;
    char err[MP_ERRLEN];
    memset(&im, 0, sizeof im);
    if (mp_image_read(name, &im, err)) {
        fprintf(stderr, "realcmp: %s\n", err);
        return 1;
    }
    size_t n = 0, np = (size_t)im.nx * (size_t)im.ny;
    double *v = malloc((np ? np : 1) * sizeof *v);
    if (!v) {
        mp_image_free(&im);
        return 1;
    }
    for (size_t i = 0; i < np; i++)
        if (isfinite(im.pix[i]))
            v[n++] = im.pix[i];
    /* A crowded frame's median sits on stars: its sky is a low percentile,
     * its noise that sky's Poisson and read noise (in the image's units). */
    double sky = pct(v, n, 20.0), sig = sqrt((sky > 0 ? sky * gain : 0.0) + ron * ron) / gain;
    printf("%.6g %.6g\n", sky, sig);
    free(v);
    mp_image_free(&im);
    return 0;
}

typedef struct { size_t n; double *x, *y, *m, *e; } cat;

static void cat_free(cat *c)
{
    free(c->x);
    free(c->y);
    free(c->m);
    free(c->e);
}

static int cat_push(cat *c, size_t *cap, double x, double y, double m, double e)
{
    if (c->n == *cap) {
        size_t nc = *cap ? 2 * *cap : 256;
        double *a = realloc(c->x, nc * sizeof *a);
        if (a) c->x = a;
        double *b = realloc(c->y, nc * sizeof *b);
        if (b) c->y = b;
        double *d = realloc(c->m, nc * sizeof *d);
        if (d) c->m = d;
        double *f = realloc(c->e, nc * sizeof *f);
        if (f) c->e = f;
        if (!a || !b || !d || !f)
            return 1;
        *cap = nc;
    }
    c->x[c->n] = x;
    c->y[c->n] = y;
    c->m[c->n] = m;
    c->e[c->n] = e;
    c->n++;
    return 0;
}

/* XPSF/YPSF_IMAGE, MAG_PSF, MAGERR_PSF of a matphot table. */
static int read_mp(const char *path, cat *c)
{
    mp_table t;
    char err[MP_ERRLEN];
    size_t cap = 0;
    if (mp_table_read(path, &t, err)) {
        fprintf(stderr, "realcmp: %s\n", err);
        return 1;
    }
    int cx = mp_table_col(&t, "XPSF_IMAGE"), cy = mp_table_col(&t, "YPSF_IMAGE");
    int cm = mp_table_col(&t, "MAG_PSF"), ce = mp_table_col(&t, "MAGERR_PSF");
    int rc = cx < 0 || cy < 0 || cm < 0 || ce < 0;
    for (size_t i = 0; i < t.nrow && !rc; i++)
        rc = cat_push(c, &cap, mp_table_get(&t, i, cx), mp_table_get(&t, i, cy),
                      mp_table_get(&t, i, cm), mp_table_get(&t, i, ce));
    mp_table_free(&t);
    if (rc)
        fprintf(stderr, "realcmp: %s: no XPSF_IMAGE, YPSF_IMAGE, MAG_PSF, MAGERR_PSF\n", path);
    return rc;
}

/* XCENTER, YCENTER, MAG, MERR of an ALLSTAR .als: "#N" names the fields,
 * a record runs over lines ending in a backslash; INDEF rows are left out. */
static int read_als(const char *path, cat *c)
{
    FILE *f = fopen(path, "r");
    if (!f) {
        fprintf(stderr, "realcmp: %s: %s\n", path, strerror(errno));
        return 1;
    }
    char line[4096], rec[16384] = "", names[4096] = "";
    size_t cap = 0;
    int rc = 0, ix = -1, iy = -1, im = -1, ie = -1;
    while (!rc && fgets(line, sizeof line, f)) {
        char *nl = strchr(line, '\n');
        if (nl)
            *nl = '\0';
        if (strncmp(line, "#N", 2) == 0) {
            strncat(names, line + 2, sizeof names - strlen(names) - 1);
            continue;
        }
        if (line[0] == '#' || strspn(line, " \t\r") == strlen(line))
            continue;
        size_t len = strlen(line);
        while (len && strchr(" \t\r", line[len - 1]))
            len--;
        int cont = len && line[len - 1] == '\\';
        strncat(rec, line, sizeof rec - strlen(rec) - 2);
        strcat(rec, " ");
        if (cont)
            continue;
        if (ix < 0) {
            char tmp[4096], *save = NULL;
            snprintf(tmp, sizeof tmp, "%s", names);
            int k = 0;
            for (char *w = strtok_r(tmp, " \\\t", &save); w; w = strtok_r(NULL, " \\\t", &save), k++) {
                ix = strcmp(w, "XCENTER") ? ix : k;
                iy = strcmp(w, "YCENTER") ? iy : k;
                im = strcmp(w, "MAG") ? im : k;
                ie = strcmp(w, "MERR") ? ie : k;
            }
            if (ix < 0 || iy < 0 || im < 0 || ie < 0) {
                fprintf(stderr, "realcmp: %s: no XCENTER, YCENTER, MAG, MERR\n", path);
                rc = 1;
                break;
            }
        }
        double v[4] = {NAN, NAN, NAN, NAN};
        char *save = NULL;
        int k = 0;
        for (char *w = strtok_r(rec, " \\\t", &save); w; w = strtok_r(NULL, " \\\t", &save), k++) {
            double d = strcmp(w, "INDEF") ? strtod(w, NULL) : NAN;
            if (k == ix) v[0] = d;
            if (k == iy) v[1] = d;
            if (k == im) v[2] = d;
            if (k == ie) v[3] = d;
        }
        rec[0] = '\0';
        if (isfinite(v[0]) && isfinite(v[1]) && isfinite(v[2]))
            rc = cat_push(c, &cap, v[0], v[1], v[2], v[3]);
    }
    fclose(f);
    return rc;
}

/* Index of the nearest star of b to (x, y) within r, or -1 (n·m: the
 * catalogs hold a few thousand stars). */
static long nearest(const cat *b, double x, double y, double r)
{
    long best = -1;
    double d2 = r * r;
    for (size_t j = 0; j < b->n; j++) {
        double dx = b->x[j] - x, dy = b->y[j] - y, e = dx * dx + dy * dy;
        if (e <= d2) {
            d2 = e;
            best = (long)j;
        }
    }
    return best;
}

static int cmd_dao(const char *mp, const char *als, double r)
{
    cat a = {0}, b = {0};
    int rc = read_mp(mp, &a) || read_als(als, &b);
    double *dm = malloc((a.n + 1) * sizeof *dm), *dp = malloc((a.n + 1) * sizeof *dp);
    size_t nm = 0;
    if (!rc && dm && dp) {
        for (size_t i = 0; i < a.n; i++) {
            long j = nearest(&b, a.x[i], a.y[i], r);
            if (j < 0 || nearest(&a, b.x[j], b.y[j], r) != (long)i)
                continue;                   /* mutual nearest neighbours only */
            dm[nm] = a.m[i] - b.m[j];
            dp[nm] = hypot(a.x[i] - b.x[j], a.y[i] - b.y[j]);
            nm++;
        }
        double med = pct(dm, nm, 50.0), sig = robust(dm, nm), pos = pct(dp, nm, 50.0);
        printf("matphot %zu dao %zu matched %zu dmag_median %.4f dmag_rsigma %.4f dpos_median %.3f\n",
               a.n, b.n, nm, med, sig, pos);
    } else {
        rc = 1;
    }
    free(dm);
    free(dp);
    cat_free(&a);
    cat_free(&b);
    return rc;
}

/* NUMBER, XPSF, YPSF, FLUX_PSF and their errors of a fit table. */
typedef struct { mp_table t; int cn, cx, cy, cf, ex, ey, ef, fl; } fit_tab;

static int read_fit(const char *path, fit_tab *f)
{
    char err[MP_ERRLEN];
    if (mp_table_read(path, &f->t, err)) {
        fprintf(stderr, "realcmp: %s\n", err);
        return 1;
    }
    f->cn = mp_table_col(&f->t, "NUMBER");
    f->cx = mp_table_col(&f->t, "XPSF_IMAGE");
    f->cy = mp_table_col(&f->t, "YPSF_IMAGE");
    f->cf = mp_table_col(&f->t, "FLUX_PSF");
    f->ex = mp_table_col(&f->t, "ERRX_PSF");
    f->ey = mp_table_col(&f->t, "ERRY_PSF");
    f->ef = mp_table_col(&f->t, "FLUXERR_PSF");
    f->fl = mp_table_col(&f->t, "FLAGS");
    if (f->cn < 0 || f->cx < 0 || f->cy < 0 || f->cf < 0 || f->ex < 0 || f->ey < 0 || f->ef < 0 ||
        f->fl < 0) {
        fprintf(stderr, "realcmp: %s: not a fit table\n", path);
        return 1;
    }
    return 0;
}

/* Stars in a group that converged in both fits (FLAGS 8 and 16 clear):
 * elsewhere both runs stop at a best state short of the optimum, and the
 * two best states differ by what the fit had not resolved. */
static int converged(const fit_tab *a, size_t i, const fit_tab *b, size_t j)
{
    return !(((long)mp_table_get(&a->t, i, a->fl) | (long)mp_table_get(&b->t, j, b->fl)) & 24);
}

static int cmd_same(const char *pa, const char *pb, int conv)
{
    fit_tab a, b;
    memset(&a, 0, sizeof a);
    memset(&b, 0, sizeof b);
    int rc = read_fit(pa, &a) || read_fit(pb, &b);
    size_t n = a.t.nrow, k = 0;
    double *qe = malloc((n + 1) * sizeof *qe), *qx = malloc((2 * n + 1) * sizeof *qx);
    double *re = malloc((n + 1) * sizeof *re), *rx = malloc((n + 1) * sizeof *rx);
    size_t kx = 0;
    if (!rc && qe && qx && re && rx) {
        for (size_t i = 0; i < n; i++) {
            double num = mp_table_get(&a.t, i, a.cn);
            size_t j = 0;
            while (j < b.t.nrow && mp_table_get(&b.t, j, b.cn) != num)
                j++;
            if (j == b.t.nrow || (conv && !converged(&a, i, &b, j)))
                continue;
            double sa = mp_table_get(&a.t, i, a.ef), sx = mp_table_get(&a.t, i, a.ex);
            double sy = mp_table_get(&a.t, i, a.ey);
            if (!(sa > 0 && sx > 0 && sy > 0))
                continue;
            qe[k] = fabs(mp_table_get(&a.t, i, a.cf) - mp_table_get(&b.t, j, b.cf)) / sa;
            re[k] = mp_table_get(&b.t, j, b.ef) / sa;
            rx[k] = mp_table_get(&b.t, j, b.ex) / sx;
            qx[kx++] = fabs(mp_table_get(&a.t, i, a.cx) - mp_table_get(&b.t, j, b.cx)) / sx;
            qx[kx++] = fabs(mp_table_get(&a.t, i, a.cy) - mp_table_get(&b.t, j, b.cy)) / sy;
            k++;
        }
        double e50 = pct(qe, k, 50.0), e99 = pct(qe, k, 99.0), emax = k ? qe[k - 1] : NAN;
        double x50 = pct(qx, kx, 50.0), x99 = pct(qx, kx, 99.0), xmax = kx ? qx[kx - 1] : NAN;
        printf("%s %zu of %zu dE/sigE median %.3g p99 %.3g max %.3g dpos/sigpos median %.3g "
               "p99 %.3g max %.3g errE_ratio %.4f errX_ratio %.4f\n", conv ? "converged" : "stars", k, n, e50, e99, emax,
               x50, x99, xmax, pct(re, k, 50.0), pct(rx, k, 50.0));
    } else {
        rc = 1;
    }
    free(qe);
    free(qx);
    free(re);
    free(rx);
    mp_table_free(&a.t);
    mp_table_free(&b.t);
    return rc;
}

/* A fit against the simulation's truth (rows by NUMBER): the normalised
 * errors (E − E_true)/σ_E and (X − X_true)/σ_X — their medians and robust
 * σ (1 when the errors are what the fit says) — and median |ΔE|/E. */
static int cmd_truth(const char *pf, const char *pt)
{
    fit_tab a;
    mp_table t;
    char err[MP_ERRLEN];
    memset(&a, 0, sizeof a);
    if (read_fit(pf, &a))
        return 1;
    if (mp_table_read(pt, &t, err)) {
        fprintf(stderr, "realcmp: %s\n", err);
        mp_table_free(&a.t);
        return 1;
    }
    int tn = mp_table_col(&t, "NUMBER"), tx = mp_table_col(&t, "X_IMAGE");
    int ty = mp_table_col(&t, "Y_IMAGE"), tf = mp_table_col(&t, "FLUX_TRUE");
    size_t n = a.t.nrow, k = 0;
    double *ze = malloc((n + 1) * sizeof *ze), *zx = malloc((2 * n + 1) * sizeof *zx);
    double *re = malloc((n + 1) * sizeof *re);
    int rc = tn < 0 || tx < 0 || ty < 0 || tf < 0 || !ze || !zx || !re;
    for (size_t i = 0; i < n && !rc; i++) {
        double num = mp_table_get(&a.t, i, a.cn), se = mp_table_get(&a.t, i, a.ef);
        double sx = mp_table_get(&a.t, i, a.ex), sy = mp_table_get(&a.t, i, a.ey);
        size_t j = 0;
        while (j < t.nrow && mp_table_get(&t, j, tn) != num)
            j++;
        if (j == t.nrow || !(se > 0 && sx > 0 && sy > 0))
            continue;
        double E = mp_table_get(&t, j, tf);
        ze[k] = (mp_table_get(&a.t, i, a.cf) - E) / se;
        re[k] = fabs(mp_table_get(&a.t, i, a.cf) - E) / E;
        zx[2 * k] = (mp_table_get(&a.t, i, a.cx) - mp_table_get(&t, j, tx)) / sx;
        zx[2 * k + 1] = (mp_table_get(&a.t, i, a.cy) - mp_table_get(&t, j, ty)) / sy;
        k++;
    }
    if (!rc)
        printf("stars %zu zE_median %.3f zE_rsigma %.3f zX_median %.3f zX_rsigma %.3f "
               "relE_median %.5f\n", k, pct(ze, k, 50.0), robust(ze, k), pct(zx, 2 * k, 50.0),
               robust(zx, 2 * k), pct(re, k, 50.0));
    free(ze);
    free(zx);
    free(re);
    mp_table_free(&a.t);
    mp_table_free(&t);
    return rc;
}

static double now_s(void)
{
    struct timespec t;
    clock_gettime(CLOCK_MONOTONIC, &t);
    return (double)t.tv_sec + 1e-9 * (double)t.tv_nsec;
}

/* realcmp timed: cmd[0..] run as a child, its times into out. */
static int cmd_timed(const char *out, char **cmd)
{
    double t0 = now_s();
    pid_t pid = fork();
    if (pid < 0) {
        perror("realcmp timed: fork");
        return 2;
    }
    if (pid == 0) {
        execvp(cmd[0], cmd);
        perror(cmd[0]);
        _exit(127);
    }
    int st;
    while (waitpid(pid, &st, 0) < 0)
        if (errno != EINTR) {
            perror("realcmp timed: waitpid");
            return 2;
        }
    struct rusage u;
    getrusage(RUSAGE_CHILDREN, &u);
    FILE *f = fopen(out, "w");
    if (!f || fprintf(f, "%.3f %ld.%06ld %ld.%06ld %ld\n", now_s() - t0, (long)u.ru_utime.tv_sec,
                      (long)u.ru_utime.tv_usec, (long)u.ru_stime.tv_sec,
                      (long)u.ru_stime.tv_usec, u.ru_maxrss) < 0 || fclose(f)) {
        fprintf(stderr, "realcmp timed: cannot write %s\n", out);
        return 2;
    }
    return WIFEXITED(st) ? WEXITSTATUS(st) : 128 + WTERMSIG(st);
}

int main(int argc, char **argv)
{
    if (argc >= 4 && strcmp(argv[1], "timed") == 0)
        return cmd_timed(argv[2], argv + 3);
    if (argc == 4 && strcmp(argv[1], "truth") == 0)
        return cmd_truth(argv[2], argv[3]);
    if (argc == 5 && strcmp(argv[1], "sky") == 0)
        return cmd_sky(argv[2], atof(argv[3]), atof(argv[4]));
    if (argc == 5 && strcmp(argv[1], "dao") == 0)
        return cmd_dao(argv[2], argv[3], atof(argv[4]));
    if (argc == 4 && strcmp(argv[1], "same") == 0)
        return cmd_same(argv[2], argv[3], 0) || cmd_same(argv[2], argv[3], 1);
    fprintf(stderr, "usage: realcmp sky IMAGE GAIN RON | dao A.cat B.als RADIUS | same A.fit "
            "B.fit | truth A.fit T.truth | timed OUT CMD...\n");
    return 2;
}
