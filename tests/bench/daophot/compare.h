/*
 * compare.h -- helpers of tests/bench/compare_daophot.sh (matphot against
 * IRAF DAOPHOT), shared by compare.c (reading, matching, statistics) and
 * report.c (the stats file and REPORT.md).
 */
#ifndef MATPHOT_BENCH_COMPARE_H
#define MATPHOT_BENCH_COMPARE_H

#include <stddef.h>
#include <stdio.h>

#define CMP_NSEP   4     /* nearest-neighbour bins */
#define CMP_NTOOL  6     /* catalogues per frame */
#define CMP_MAXBIN 64    /* magnitude bins */

typedef struct { int ok; double v; } cmp_opt;   /* ok == 0: None */

typedef struct {
    long n, found;
    cmp_opt compl, sigma, bias;
} cmp_bin;

typedef struct {
    char name[8];
    char *missing;                   /* path when the catalogue is missing */
    long ndet, found, nfalse, spurious;
    double compl, zp;
    cmp_opt dx, dy, posrms, sigma_all;
    int nmag;                        /* bins in by_mag, by_mag_blend */
    cmp_bin by_mag[CMP_MAXBIN], by_sep[CMP_NSEP], by_mag_blend[CMP_MAXBIN];
} cmp_tool;

typedef struct {
    char *name, *desc, *simcmd;
    double fwhm, magmin, magmax;
    long ntrue;
    int nedge;
    double edges[CMP_MAXBIN + 1];
    long ntrue_sep[CMP_NSEP], ntrue_mag[CMP_MAXBIN];
    cmp_tool tools[CMP_NTOOL];
} cmp_frame;

typedef struct {
    char *frame, *tool;
    long run;
    double wall, user, sys;
} cmp_time;

typedef struct {
    size_t nmeta;
    char **key, **val;               /* meta.tsv, commands, cl_example */
    size_t nframe;
    cmp_frame *frames;
    size_t ntime, captime;
    cmp_time *times;
} cmp_stats;

/* the nearest-neighbour bins [FWHM]: [edge(k), edge(k+1)), named name(k) */
double cmp_sep_edge(int k);
const char *cmp_sep_name(int k);

/* compare.c */
char *cmp_strdup(const char *s);
int cmp_stats_meta_add(cmp_stats *s, const char *key, const char *val);
const char *cmp_stats_meta(const cmp_stats *s, const char *key, const char *dflt);
int cmp_stats_time_add(cmp_stats *s, const char *frame, const char *tool, long run,
                       double wall, double user, double sys);
void cmp_stats_free(cmp_stats *s);
double cmp_median(const double *v, size_t n);   /* numpy's median; n > 0 */

/* report.c */
int cmp_stats_write(const char *path, const cmp_stats *s);
int cmp_stats_read(const char *path, cmp_stats *s);
int cmp_report(const char *stats_path, const char *out);

#endif
