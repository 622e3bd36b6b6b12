/*
 * vt.h — the paper's §5 experiments (design.md §6): shared types of the
 * validation program tests/validate/.  Private to this folder.
 */
#ifndef MATPHOT_VT_H
#define MATPHOT_VT_H

#include <stdio.h>
#include "fit/fit.h"
#include "sim/sim.h"

#define VT_NX 60                 /* frame side [px] */
#define VT_NPIX (VT_NX * VT_NX)
#define VT_RON 3.0               /* read noise [e-] */
#define VT_SEED_STRIDE 10000000ULL  /* seed = simset * stride + star */
#define VT_NBIN 10               /* 1-mag bins centred on -6 ... -15 */

typedef enum { VT_FIT_ANALYTIC, VT_FIT_GTABLE, VT_FIT_REAL2, VT_FIT_REAL4 } vt_fitkind;
typedef enum { VT_EXPECT_CRLB, VT_EXPECT_FAIL_BRIGHT } vt_expect;

/* One experiment of design.md §6. */
typedef struct {
    const char *id;          /* file stem under the output folder */
    const char *name;        /* short name for tables */
    const char *title;       /* one line: what is simulated and fitted */
    const char *paper;       /* the paper's figure and statement */
    double paper_beta;       /* the paper's beta [px^2] (0: none) */
    int simset;              /* seed set: cases sharing it share frames */
    int real;                /* truth is the Tiny Tim x4 table (else Gaussian) */
    double fwhm;             /* Gaussian truth FWHM [px] */
    double volume;           /* uniform QE (sim and fit); 1 = perfect */
    int gate_drf;            /* 4x4 DRF with a dead first row and column */
    double sky;              /* observed sky B [e-/px] */
    double mag_lo, mag_hi;   /* uniform magnitudes; equal: all at mag_lo */
    int half_n;              /* run N/2 stars (the paper's 10 000 of 20 000) */
    vt_fitkind fit;
    int fit_os;              /* VT_FIT_GTABLE: OVERSAMP of the fitted table */
    vt_expect expect;
    double fail_e;           /* failure cases: the paper's onset [e-] */
} vt_case;

/* Per star: truth, fit, and the two error predictions at the truth. */
typedef struct {
    double mag, e_true, x_true, y_true;
    double e, x, y, ee, ex, ey;          /* fitted (x, y: true-star frame) */
    double sky, chi2;                    /* reduced chi^2 */
    int dof, niter, flags, rc;
    double se_model, sx_model;           /* paper's model at the truth */
    double se_crlb, sx_crlb, sy_crlb;    /* exact CRLB at the truth */
    double beta, volume, lscale;         /* truth PRF (whole frame) */
    double vol_fit;                      /* PRF volume at the fitted position */
    double cpu;                          /* thread CPU s of mp_fit_group */
} vt_star;

/* Statistics of one magnitude bin. */
typedef struct {
    double mag;              /* bin centre */
    int n, nflag;
    double beta, volume, lscale;         /* means of the truth PRF */
    double ph_model, ph_crlb;            /* median(|dmag|/s_mag)/0.6745 */
    double as_model, as_crlb;            /* median(dr/s_x)/1.1774 */
    double u_ph, u_as;                   /* 1-sigma sampling of those */
    double nE_med, nE_rs, nX_med, nX_rs, nY_med, nY_rs;  /* normalised errors */
    double u_med, u_rs;                  /* 1-sigma sampling of median, robust sigma */
    double modE_crlb, modX_crlb;         /* median sigma_model / sigma_CRLB */
    double med_dmag, med_dr;             /* raw medians */
    double med_smag_model, med_sx_model; /* median model sigmas */
    int pass_ph, pass_as;                /* within 5 % + 2 sigma of the CRLB */
} vt_bin;

/* Results of one case. */
typedef struct {
    const vt_case *c;
    int n;
    vt_star *s;
    vt_bin bin[VT_NBIN];
    double wall, cpu_total, cpu_median;
    double chi2_mean, ks_d, ks_p;
    int nflag, nfail_rc;
    double shift_px;         /* offset of the fitted table (mp_psf.offset) */
    double tab_sum;          /* light held by the fitted table */
    /* Table truths: noiseless fits at the 16 x4-grid phases of a pixel
     * (model adequacy, issue 2): per bin, the mean and worst position bias
     * in CRLB sigmas and the astro/CRLB ratio that bias alone implies. */
    int have_nb;
    double nb_x[VT_NBIN], nb_xmax[VT_NBIN], nb_y[VT_NBIN], nb_ymax[VT_NBIN];
    double nb_ratio[VT_NBIN], nb_u;      /* nb_u: 1-sigma Monte Carlo of the ratio */
    int ran, skipped;
    uint64_t seed0;          /* seed of star 0; star k uses seed0 + k */
    char note[1536];
} vt_result;

/* Everything the PSFs of the cases are made of, built once. */
typedef struct {
    const char *realpath;    /* Tiny Tim x4 table */
    mp_psf real4;            /* cropped 161x161, OVERSAMP 4 (kind 0 if absent) */
    mp_psf real2;            /* block-summed to x2 */
    double shift2;           /* real2.offset [px] */
    mp_psf real4bl, real2bl; /* real4 band-limited to 1 cycle/px, and x2 */
    double bl_removed;       /* Σ (real4 − real4bl)² */
    double gate_qe[16];
    mp_drf gate;             /* k = 4, the array above */
    int have_real;
    char real_note[1400];
} vt_inputs;

/* cases.c */
int vt_inputs_load(vt_inputs *in, const char *realpath, char *err);
void vt_inputs_free(vt_inputs *in);
int vt_run_case(const vt_case *c, const vt_inputs *in, int n, int seedset, int verbose,
                vt_result *r, char *err);
double vt_side_lobe(double *row_min, char *err);

/* stats.c */
double vt_quantile_sorted(const double *v, size_t n, double q);
double vt_median(double *v, size_t n);             /* sorts v */
double vt_robust_sigma(double *v, size_t n);       /* IQR/1.349; sorts v */
int vt_bin_index(double mag);                      /* -1 outside */
double vt_bin_centre(int b);
int vt_stats(vt_result *r);
double vt_chi2_cdf(double chi2, double dof);
double vt_ks_pvalue(double d, size_t n);
void vt_selftest(FILE *fp);

/* report.c */
int vt_write_report(const char *dir, vt_result *res, int nres, const vt_inputs *in,
                    int n, int seedset, const char *cmdline, double wall, int have_gnuplot, char *err);
void vt_print_summary(FILE *fp, vt_result *res, int nres);

/* plot.c */
int vt_write_data(const char *dir, const vt_result *r, char *err);
int vt_plot(const char *dir, const vt_result *r, const char *term, char *err);

#endif
