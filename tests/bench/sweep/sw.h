/*
 * sw.h — `make bench` part 2 (issue 5, "error against run time"): the fit's
 * cost knobs swept one at a time around fit.par's defaults on fixed
 * simulated scenes, the achieved error measured against the Cramér–Rao
 * bound of every star.  Private to tests/bench/sweep/.
 */
#ifndef MATPHOT_SW_H
#define MATPHOT_SW_H

#include <stdio.h>
#include "fit/fit.h"
#include "sim/sim.h"

#define SW_NX 60                 /* single-star frame side [px] (as tests/validate) */
#define SW_NPIX (SW_NX * SW_NX)
#define SW_RON 3.0               /* read noise [e-] */
#define SW_SKY 100.0             /* sky [e-/px] */
#define SW_MAG_LO (-15.0)        /* magnitudes uniform over [LO, HI) */
#define SW_MAG_HI (-6.0)
#define SW_FAINT (-9.0)          /* faint: mag > -9 */
#define SW_BRIGHT (-12.0)        /* bright: mag < -12 */
#define SW_MAXTAB 3              /* table samplings per scene (x4, x2, x1) */
#define SW_MAXSET 48
#define SW_CHUNK 50              /* single-star scenes: settings interleaved every 50 stars */
#define SW_NBOOT 200             /* bootstrap resamples for paired differences */
#define SW_PSFRAD 10.0           /* group.par's psfrad; radius of the Gaussian tables */
#define SW_PEPS 0.005            /* ratio differences the Pareto fronts ignore */
#define SW_FLAGMAX 0.05          /* more flagged or lost than the default: not usable */
#define SW_SAFE 0.03             /* a change shown (2σ) to be below this is safe */

typedef enum { SW_SINGLE, SW_CROWDED } sw_kind;

/* Truth and start of one star. */
typedef struct {
    double mag, e, x, y;         /* truth (x, y 1-based, frame coordinates) */
    double x0, y0;               /* start position of the fit */
    double f0;                   /* start flux (find's FLUX stand-in): truth · exp(0.2 N(0,1)) */
    double se, sx;               /* CRLB: sigma_E [e-], sigma_X = sqrt((sx^2+sy^2)/2) [px] */
} sw_truth;

typedef struct {
    const char *name;            /* isolated, crowded, undersampled, ugly */
    const char *title;           /* one line */
    sw_kind kind;
    int n;                       /* stars */
    double fwhm;                 /* Gaussian truth FWHM (0: Tiny Tim table) */
    uint64_t seed;
    /* Fit tables: tab[0] is the table as given, then block-summed coarser. */
    mp_psf tab[SW_MAXTAB];
    int ntab;
    int def_tab;                 /* what fit.par's economy=yes uses */
    double beta_norm;            /* 1/sharpness of the given table at detector sampling */
    mp_drf drf;                  /* the detector's DRF map (k = 0: perfect detector) */
    double gx, gy;               /* sky gradient [e-/px per px] about the frame's centre */
    int whole;                   /* economy mode: fitrad=INDEF (the paper's whole-frame fits) */
    /* Frames: single: n frames of SW_NPIX; crowded: one fnx x fny frame. */
    long fnx, fny;
    float *img;                  /* single precision, as a frame (io.h) */
    sw_truth *t;
    char note[1024];
} sw_scene;

/* One setting: the fit options and model knobs. */
typedef struct {
    char knob[16], value[24];
    int tab;                     /* index into scene tab[] */
    int hw;                      /* sinchw */
    double fitrad;               /* NaN: whole frame */
    double tol;
    int maxiter;
    int maxgroup;                /* crowded only */
    int is_default, is_econ;
    /* economy=yes/no mode (-e): the model and options of an mp_fit_setup
     * read from fit.par (NULL: tab[tab], the scene's DRF, sinchw hw and
     * mp_frame_opts_default with fitrad, tol, maxiter above). */
    const mp_prf_model *model;
    const mp_frame_opts *fopts;
    /* Per-star kernel length (single-star scenes): each star fitted with
     * mp_sinc_choice_hw(choice, E, SW_SKY, SW_RON, frac), E its true flux. */
    const mp_sinc_choice *choice;
    double frac;
    double emax[65];             /* mp_sinc_choice_limits at SW_SKY, SW_RON, frac */
} sw_setting;

/* Per-subset statistics (all, faint, bright). */
typedef struct {
    int n;
    double ph, as;               /* median(|dmag|/s_mag)/0.6745, median(dr/s_X)/1.1774 */
    double uph, uas;             /* 1-sigma sampling (1.166/sqrt n, 0.721/sqrt n) */
    double dph, das;             /* minus the default setting's, on the stars both kept */
    double udph, udas;           /* 1-sigma of those (paired bootstrap) */
} sw_sub;

typedef struct {
    sw_setting s;
    double *x, *y, *f;           /* fitted (NaN: lost, i.e. merged away or rejected) */
    int *flags;
    double cpu[16];              /* CPU s of each repeat (all stars) */
    int nrep;
    double cpu_star;             /* median over repeats / n [s] */
    double cpu_spread;           /* (max - min) / median over the repeats */
    long iters;                  /* summed iterations (first repeat) */
    long hwsum;                  /* per-star kernel: summed half-widths (first repeat) */
    long coarse;                 /* economy mode: LM fits with a coarser table (all repeats) */
    double fflag, fnoconv, flost, fsplit;
    sw_sub sub[3];
    int par_ph, par_as, par_joint;  /* on the Pareto front */
} sw_result;

/* A row of a scene's table: knob = value, and which result holds it (the
 * default's values of every knob point to the default's result). */
typedef struct {
    char knob[16], value[24];
    int ires;
} sw_row;

/* scenes.c */
int sw_scene_build(sw_scene *sc, const char *name, int n, const char *realpath, char *err);
void sw_scene_free(sw_scene *sc);

/* export.c: DIR/SCENE.fits, SCENE.truth, SCENE_psf.fits */
int sw_export(const char *dir, const sw_scene *sc, char *err);

/* run.c */
int sw_run(const sw_scene *sc, const sw_setting *st, int k0, int k1, sw_result *r, int record,
           double *cpu, char *err);
void sw_result_free(sw_result *r);

/* stats.c */
double sw_median(double *v, size_t n);          /* reorders v */
int sw_stats(const sw_scene *sc, sw_result *res, int nres, int idef, uint64_t seed);
int sw_usable(const sw_result *r, const sw_result *def);
int sw_beats(const sw_result *r, int sub);
void sw_pareto(sw_result *res, int nres);

/* report.c */
int sw_write(const char *dir, const char *pngdir, const sw_scene *sc, const sw_result *res,
             int nres, const sw_row *rows, int nrows, int iecon, const char *econ_why,
             const char *daofile, int nrep, double wall, double cpu, char *err);
int sw_write_skip(const char *dir, const char *name, const char *why, char *err);

/* sweep.c: settings [i0, i1) fitted reps times, interleaved; CPU medians */
int sw_run_block(const sw_scene *sc, sw_result *res, int i0, int i1, int reps, int verbose,
                 char *err);

/* econ.c: economy=yes against economy=no (-e): WORKDIR/SCENE_econ.md */
int sw_econ(const sw_scene *sc, const char *work, int reps, int verbose, char *err);

#endif
