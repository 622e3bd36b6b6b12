/*
 * fakes_priv.h — private to pipeline/: the artificial-star run of
 * `matphot fakes` (fakes.c: the engine; fakes_report.c: its table, its
 * report and figure; task_fakes.c: the task).
 */
#ifndef MATPHOT_FAKES_PRIV_H
#define MATPHOT_FAKES_PRIV_H

#include "pipeline/pipeline_priv.h"

typedef struct {
    long nfake;              /* all parts together */
    double magmin, magmax;   /* fakes' magnitudes, uniform */
    uint64_t seed;
    long box;                /* side of the box reduced around each fake [px] */
    double fakerad;          /* found: a fitted star within this [px] ... */
    double fwhm;             /* for the crowding bins [px] */
} mp_fakes_opts;

/* The stars of the frame's own reduction (positions, magnitudes). */
typedef struct {
    double *x, *y, *mag;
    long n;
} mp_fakes_base;

/* One fake and what became of it. */
typedef struct {
    long number;             /* k + 1 */
    double x, y, mag;        /* injected */
    double nn;               /* distance to the nearest star of the frame's reduction [px] */
    int found, flags;
    double xf, yf, magf, emag;  /* its fit (NaN when not found) */
} mp_fake;

/* mp_fakes_run: fakes lo .. hi−1 (0-based) into out[0 .. hi−lo−1], in
 * parallel; f is not modified.  Nonzero with err on failure. */
int mp_fakes_run(const mp_frame *f, const mp_pipeline_opts *o, const mp_fakes_opts *fo,
                 const mp_fakes_base *b, long lo, long hi, mp_fake *out, char *err);

/* mp_fakes_write_table: root.fakes.cat (ASCII_HEAD: NUMBER, X_TRUE,
 * Y_TRUE, MAG_TRUE, FOUND, XPSF_IMAGE, YPSF_IMAGE, MAG_PSF, MAGERR_PSF,
 * FLAGS, NN_DIST), atomically. */
int mp_fakes_write_table(const char *path, const mp_fake *fk, long n, char *err);

/* mp_fakes_write_report: root.fakes.md (completeness, bias and error
 * against magnitude and against crowding) and, with gnuplot, root.fakes.png
 * (its data in root.fakes.dat); what the part was is said in its head. */
int mp_fakes_write_report(const char *root, const char *image, const mp_fakes_opts *fo,
                          long lo, long hi, const mp_fake *fk, char *err);

#endif
