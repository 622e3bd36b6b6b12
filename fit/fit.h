/*
 * fit.h — the MATPHOT fit engine (paper §2–4, design.md §5).
 *
 * A star is E · PRF(x − X, y − Y) with PRF = PSF ∗ DRF sampled on detector
 * pixels.  A discrete PSF table (OVERSAMP os) is shifted to the star with the
 * separable damped sinc of paper §3.1 at the table's own sampling, weighted by
 * the DRF's subpixel QE and block-summed to detector pixels; its position
 * derivatives come from the five-point formula of paper §3.2 on the shifted
 * table.  The analytic mode integrates a Gaussian over pixels with erf.
 * Stars and a sky model are fitted together by Levenberg–Marquardt with
 * weights 1/(max(m_i, S) + RON²) from the current model (S the sky the
 * stars were found on: a model below the sky, from a table's negative
 * wings, weighs a pixel as the sky does); a step is taken only when
 * it lowers one fixed objective, the quasi-likelihood deviance whose
 * minimum is where those weighted normal equations balance (levmar.c).
 *
 * Coordinates are 1-based FITS pixel coordinates (centre of the first pixel
 * at 1.0); fluxes are electrons for a PRF volume of one (design.md §3).
 * Errors: 0 on success, nonzero with one line in err (MP_ERRLEN bytes).
 */
#ifndef MATPHOT_FIT_H
#define MATPHOT_FIT_H

#include "catalog/catalog.h"
#include "io/io.h"
#include "params/params.h"
#include "psf/psf.h"

/* ---- PSF: the table model lives in psf/psf.h ------------------------------ */

/* ---- DRF ---------------------------------------------------------------- */

/* Detector response: k×k subpixel QE of one pixel (k divides the PSF's os),
 * or, with k == 0, a uniform detector of efficiency volume. */
typedef struct {
    int k;
    double *qe;        /* k*k, row-major, (0,0) at the pixel's low x,y corner */
    double volume;     /* mean QE = PRF volume for a full PSF */
} mp_drf;

int mp_drf_read(const char *name, int psf_os, mp_drf *d, char *err);
void mp_drf_uniform(double volume, mp_drf *d);
void mp_drf_free(mp_drf *d);

/* ---- Shifting and derivatives (paper §3) ---------------------------------- */

/* mp_damped_sinc: sinc(d)·exp(−(d/3.25)²), paper eq. (dampedsinc). */
double mp_damped_sinc(double d);

/* mp_shift_on_grid: nonzero when a shift of delta table elements is the
 * identity to double precision (|delta| ≤ DBL_EPSILON/2), so the damped-sinc
 * pass is skipped (mp_shift_table, mp_prf_render). */
int mp_shift_on_grid(double delta);

/* mp_shift_table: out(i,j) = in(i+dx, j+dy) by the separable damped sinc of
 * half-width hw (hw=10: 21 taps); |dx|,|dy| ≤ 0.5 in table elements; outside
 * the table counts as zero.  tmp holds nx*ny doubles. */
void mp_shift_table(const double *in, int nx, int ny, double dx, double dy,
                    int hw, double *out, double *tmp);

/* mp_five_point: first derivative along x (axis 0) or y (axis 1) per table
 * element by (f[i-2] − 8f[i-1] + 8f[i+1] − f[i+2])/12, zero outside. */
void mp_five_point(const double *in, int nx, int ny, int axis, double *out);

/* ---- PRF on detector pixels ---------------------------------------------- */

struct mp_prf_cache_s;

/* How a star is drawn from a phase grid (fit/prf_cache.c; the mode of
 * mp_prf_cache_render): the cubic interpolation, the bilinear one, or core
 * tier k (cubic within a core of mp_prf_cache_core_radius(k), bilinear
 * beyond). */
#define MP_PRF_CUBIC 0
#define MP_PRF_BILINEAR 1
#define MP_PRF_NCORE 8
#define MP_PRF_CORE(k) (2 + (k))

/* The flux limits of a grid's cheaper modes on one sky: bilinear up to
 * lin, core tier k up to core[k] (zeroed: cubic for every flux but 0). */
typedef struct {
    double lin, core[MP_PRF_NCORE];
} mp_prf_tiers;

/* What makes a model PRF, and which of its parts are used. */
typedef struct {
    const mp_psf *psf;     /* the PSF; a variable one (psf->field) is
                            * evaluated at each star in every render */
    const mp_drf *drf;     /* NULL: perfect detector */
    int sinc_hw;           /* damped-sinc half-width, 10 = 21 taps */
} mp_prf_model;

/* Scratch space for mp_prf_render (one per thread). */
typedef struct {
    size_t n;
    double *a, *b, *c, *d;
    size_t ne;
    double *e;             /* the star's own table, when the model has a field */
    int single;            /* separable renders in single precision
                            * (fit/prf_axis.h mp_prf_axis_rows_single): for
                            * light drawn once and held, never the LM's */
    size_t nf;
    float *f;              /* their A, A' and table rows */
    long nshift, nskip;    /* table renders: axes shifted, and of those skipped
                            * because the shift is on the grid (mp_shift_on_grid) */
    double ops;            /* multiply-adds of the exact table renders done
                            * (shift taps, block-sums; economy's plan) */
    const struct mp_prf_cache_s *grid;  /* economy: renders of the model this
                            * phase grid was built for are drawn from it
                            * (fit/prf_cache.c); NULL: exact renders */
    double grid_emax;      /* the frame fit's paint of a star (frame_paint.c)
                            * uses grid only up to this flux, its bound */
    mp_prf_tiers grid_tiers;  /* and in its cheaper modes up to these (zeroed:
                            * cubic), their bounds */
    int grid_mode;         /* this render's mode (ff_paint) */
    struct mp_prf_axes_s *axes;  /* the separable render's two axis operators
                            * (fit/prf.c), kept between renders */
} mp_prf_work;

void mp_prf_work_free(mp_prf_work *w);

/* mp_prf_box: the detector box [*x0, *x0+*w) × [*y0, *y0+*h) (1-based) that
 * the PRF of a star at (x,y) covers. */
void mp_prf_box(const mp_prf_model *m, double x, double y,
                long *x0, long *y0, int *w, int *h);

/* mp_prf_render: the PRF (volume V·sum, not normalised) of a star at (x,y)
 * on the box of mp_prf_box, and its derivatives ∂/∂x, ∂/∂y (may be NULL).
 * Arrays are w*h, row-major. */
int mp_prf_render(const mp_prf_model *m, double x, double y,
                  double *prf, double *dprf_dx, double *dprf_dy, mp_prf_work *w);

/* mp_merge_sig: the separation, in units of its σ (widened by
 * √(CHI2STAR_PSF) of the pair's discs when above 1), from which a pair
 * closer than mergerad is two stars, not one (the frame fit's merge):
 * minsnr, the level at which the one-or-two test proposes a second star
 * (Δχ² ≥ minsnr², pipeline/split.c), at least 2; INFINITY when
 * minsnr ≤ 0 (nothing rejected: mergerad merges every pair). */
double mp_merge_sig(double minsnr);

/* mp_prf_fwhm: the PRF's equivalent FWHM, 2.3548·L at a pixel centre (L,
 * the critical-sampling scale length, is the σ of a Gaussian of the same
 * sharpness, paper §2.4.2); what find's kernel and the merge radius use. */
double mp_prf_fwhm(const mp_prf_model *m);

/* mp_prf_phase: where mp_prf_render_phases puts phase k of n along an
 * axis: c + k/(n − 1) − ½ (c for n = 1), a pixel's width in n steps
 * about c. */
double mp_prf_phase(double c, int k, int n);

/* mp_prf_render_phases: mp_prf_render of a star at the n × n phases about
 * (x, y) — (mp_prf_phase(x, a, n), mp_prf_phase(y, b, n)) into out[b·n + a],
 * each on its own box (mp_prf_box), no derivatives — for the PSF's
 * measured bounds (the crop envelope, the cosmic-ray test's).  A variable
 * PSF is evaluated once, at (x, y): within half a pixel its table moves by
 * 0.5 px/POLSCAL of its change across the field.  Where a table is shifted
 * element by element (fit/prf.c render_table), the x-pass of a column of
 * phases is made once for its n rows.  The values are those of the
 * one-by-one renders of that table up to the order of the sums.  Nonzero
 * when out of memory. */
int mp_prf_render_phases(const mp_prf_model *m, double x, double y, int n, double *const *out,
                         mp_prf_work *w);

/* mp_prf_render_window: as mp_prf_render, on the part of the star's box
 * inside the window [wx0, wx0+ww) × [wy0, wy0+wh) only — the box rendered
 * comes back in *x0, *y0, *w, *h (w or h 0 when they do not meet).  The
 * values are those of the full render: only the table elements that land
 * in the window (and the taps they need) are shifted, so a fit pays for
 * its fitting region, not for the PSF's wings. */
int mp_prf_render_window(const mp_prf_model *m, double x, double y,
                         long wx0, long wy0, long ww, long wh,
                         long *x0, long *y0, int *w, int *h,
                         double *prf, double *dprf_dx, double *dprf_dy, mp_prf_work *work);

/* mp_prf_adjoint: the transpose of mp_prf_render's PRF (the values, a
 * table PSF) for a star at (x, y): g (the table's nx × ny elements,
 * overwritten) = Aᵀ·r with r an image on the detector box [x0, x0+w) ×
 * [y0, y0+h) (row-major) and A the render (damped-sinc shift by the
 * star's sub-element phase, DRF, block-sum): every pixel's value spread
 * back over the elements it was drawn from, with the same weights — the
 * back-projection of an effective-PSF build (psf/sirt.c).  Nonzero when
 * out of memory or the PSF is not a table. */
int mp_prf_adjoint(const mp_prf_model *m, double x, double y, long x0, long y0, int w, int h,
                   const double *r, double *g, mp_prf_work *work);

/* ---- Interpolation effort per star (fit/sinc_choice.c, issue 5) ---------- */

/* The damped sinc's error for every half-width below the model's sinc_hw,
 * measured once per PSF: δP_h = PRF(h) − PRF(sinc_hw) squared per pixel, at
 * a 4×4 grid of subpixel phases, with the full PRF P. */
typedef struct mp_sinc_choice_s {
    int hwmax;         /* the model's sinc_hw (the user's sinchw) */
    int nph;           /* phases (0 when nothing can be shortened) */
    size_t npix;       /* pixels stored per phase */
    double *p;         /* nph × npix */
    double *d2;        /* hwmax × nph × npix */
} mp_sinc_choice;

int mp_sinc_choice_build(const mp_prf_model *m, mp_sinc_choice *c, char *err);
void mp_sinc_choice_free(mp_sinc_choice *c);

/* mp_sinc_choice_bound: q = E·max_phase sqrt(Σ δP_h²/(E P + B + ron²)), a
 * bound on |bias|/σ_CRLB of the star's flux, position and sky alike from
 * using half-width hw instead of sinc_hw (0 for hw ≥ sinc_hw). */
double mp_sinc_choice_bound(const mp_sinc_choice *c, int hw, double E, double B, double ron);

/* mp_sinc_choice_hw: the shortest half-width whose bound is ≤ frac for a
 * star of E electrons on sky B [e-/px] with read noise ron [e-]; sinc_hw
 * when none is. */
int mp_sinc_choice_hw(const mp_sinc_choice *c, double E, double B, double ron, double frac);

/* The same per star in O(sinc_hw): mp_sinc_choice_limits fills emax[h]
 * (h < sinc_hw), the largest flux whose bound at half-width h is ≤ frac on
 * sky B (once per sky level); mp_sinc_choice_pick returns the shortest h
 * with E ≤ emax[h], else hwmax. */
int mp_sinc_choice_limits(const mp_sinc_choice *c, double B, double ron, double frac,
                          double *emax);
/* Bound evaluations mp_sinc_choice_limits spends per half-width, at most
 * (two ends, 14 halvings of 18 decades: the limit to 0.25 %, rounded to
 * the served side, so every flux below it is served): a frame with fewer
 * groups than this evaluates the bound per group instead (frame_rules.c).
 * mp_prf_cache_limit spends as many. */
#define MP_SINC_LIMITS_EVALS 16
int mp_sinc_choice_pick(const double *emax, int hwmax, double E);
/* ---- Supersampling per star (fit/ss_choice.c, issue 10) ----------------- */

/* A coarser sampling of the model's table (block-summed by factor), with
 * its error measured once per PSF: bias holds, at a 4×4 grid of subpixel
 * phases, the given table's PRF P, ∂P/∂x, ∂P/∂y and δP = PRF(coarse) −
 * PRF(given) (signed).  A star of flux E is served by the coarse table when
 * the linearised bias it causes in the fit of (flux, x, y, sky) is ≤ frac
 * of each parameter's Cramér–Rao σ at every phase, and the part of E·δP the
 * fit cannot absorb raises χ² by λ ≤ MP_SS_CHI2MAX (fit/ss_choice.c).
 * sinc is the coarse model's own kernel-length table (not built: the
 * full kernel for that level).  model points into
 * psf: build in place, do not copy. */
typedef struct {
    int nph;               /* phases */
    size_t npix;           /* pixels stored per phase */
    double *p, *dx, *dy, *dp;   /* nph × npix each (one allocation, at p) */
} mp_ss_bias;

typedef struct mp_ss_level_s {
    int os;                /* its OVERSAMP */
    mp_psf psf;            /* psf.field: field, when the PSF varies */
    mp_psf_field field;    /* the given field block-summed alike (order 0: unused) */
    mp_prf_model model;    /* the given model with psf swapped in */
    mp_ss_bias bias;
    mp_sinc_choice sinc;
    struct mp_prf_cache_s *grid;  /* economy: its own phase grid (fit/prf_cache.c,
                            * built by mp_econ_choose when it pays); NULL: none */
} mp_ss_level;

/* mp_ss_level_build: the level of m's table block-summed by factor
 * (dividing its OVERSAMP), with its own kernel-length table (lv->sinc)
 * when with_sinc. */
int mp_ss_level_build(const mp_prf_model *m, int factor, int with_sinc, mp_ss_level *lv,
                      char *err);
void mp_ss_level_free(mp_ss_level *lv);

/* mp_ss_level_bias: max over phases and over (flux, x, y, sky) of
 * |bias|/σ_CRLB from fitting a star of E e- on sky B [e-/px], read noise
 * ron [e-], with the coarse table (linearised); *chi2 (if not NULL) gets
 * the worst phase's λ, the χ² the fit cannot absorb. */
double mp_ss_level_bias(const mp_ss_level *lv, double E, double B, double ron, double *chi2);

/* mp_ss_level_serves: 1 when that bias is ≤ frac and λ ≤ MP_SS_CHI2MAX
 * (one evaluation of 4×4 normal equations per phase). */
int mp_ss_level_serves(const mp_ss_level *lv, double E, double B, double ron, double frac);
#define MP_SS_CHI2MAX 1.0

/* mp_ss_level_emax: a flux below which the level serves every flux on sky
 * B with read noise ron (0: none; INFINITY: every flux): bisection, then
 * checked on a log grid of MP_SS_VERIFY fluxes below it and lowered below
 * the first failure.  Costs at most MP_SS_LIMITS_EVALS evaluations. */
double mp_ss_level_emax(const mp_ss_level *lv, double B, double ron, double frac);
#define MP_SS_BISECT 14     /* 18 decades in 14 halvings: E to 0.25 % */
#define MP_SS_VERIFY 30
#define MP_SS_LIMITS_EVALS (2 + MP_SS_BISECT + MP_SS_VERIFY)

#define MP_SS_MAXLEVELS 3

/* mp_prf_envelope: env[r] (r = 0..*nr−1, detector px) bounds |PRF| of one
 * detector pixel whose centre lies r px or more from the star, at any
 * subpixel phase (the PRF of unit flux; for a table, measured on renders
 * at ¼-px phases with a factor 2 of slack).  *nr is the first radius past
 * which the PRF box holds nothing.  env is malloc'ed (caller frees); NULL
 * when out of memory.  It is what a neighbour's light is cropped by: a
 * star of flux E puts less than E·env[r] on every pixel beyond r. */
double *mp_prf_envelope(const mp_prf_model *m, int *nr);

/* Where a star's light is worth rendering (economy): out to the radius
 * where it falls below frac·σ of a sky pixel, σ² = RON² + sky, by the
 * envelope. */
typedef struct {
    double *env;        /* mp_prf_envelope; NULL: the whole box */
    int nr;
    double frac, ron2;
} mp_prf_crop;

/* mp_prf_crop_init: the crop of model m for read noise ron [e-]; frac 0
 * gives no crop.  Nonzero when out of memory. */
int mp_prf_crop_init(const mp_prf_model *m, double frac, double ron, mp_prf_crop *c);
void mp_prf_crop_free(mp_prf_crop *c);

/* mp_prf_crop_radius: the radius [px] beyond which a star of flux E on sky
 * puts less than frac·σ on any pixel; INFINITY (c NULL, no envelope, or
 * never below): its whole box. */
double mp_prf_crop_radius(const mp_prf_crop *c, double E, double sky);

/* ---- The PRF from a grid of subpixel phases (fit/prf_cache.c, issue 12) --- */

/* The exact PRF (full sinc_hw) and its five-point derivatives rendered once
 * on a grid of phases, G per pixel, kept per alignment branch (1/os px wide,
 * Gb = G/os intervals, nodes −1..Gb+1 with the branch's alignment); a star's
 * PRF and derivatives are the tensor-product 4-point Lagrange interpolation
 * between the 4×4 nodes around its phase, or, for a star faint enough,
 * the bilinear one between the 2×2 nodes around it (a quarter of the
 * reads and sums, a larger error).  The error each adds to the PRF, δP,
 * is measured at the centre of each of the G² cells, where both peak. */
typedef struct mp_prf_cache_s {
    int G;                 /* phases per pixel (os·gb); 0: no cache */
    int os, gb;            /* the table's OVERSAMP; intervals per branch */
    double offset;         /* the table's offset (mp_psf) */
    long ux0, uy0;         /* union box relative to the reference pixel */
    int uw, uh;
    size_t npix;           /* uw*uh */
    float *img;            /* (os(gb+3))² planes of 3 npix: PRF, ∂/∂x, ∂/∂y */
    int nph;               /* measured phases (G²) */
    float *p, *d2;         /* nph × npix: exact PRF and δP² at cell centres */
    float *d2l;            /* nph × npix: the bilinear interpolation's δP² */
    double pmin, pmax;     /* the least and the largest P of any cell's pixel */
    double *d2bin;         /* nph × MP_PRF_CACHE_NBIN: each cell's Σ δP² over
                            * its pixels by P (mp_prf_cache_serves): bin 0
                            * P ≤ 0, bin b ≥ 1 P in (pmax·2^−b, pmax·2^(1−b)],
                            * the last down to 0 */
    double *d2lbin;        /* the same of d2l */
    double *d2cbin;        /* MP_PRF_NCORE × nph × MP_PRF_CACHE_NBIN: the same
                            * of each core tier (mp_prf_cache_limit_core) */
    const mp_psf *psf;     /* what it was built from (mp_prf_cache_usable) */
    const mp_drf *drf;
    /* Position derivatives drawn within a box alone (mp_prf_cache_deriv_box):
     * its half-width [px] and the largest E/(B + RON²) served; 0: none. */
    double dbox_hw, dbox_u;
    /* A variable PSF (psf->field): one grid per plane of the field (img,
     * geometry; their own bounds freed), a star's PRF Σ c_t(x, y)·grid_t;
     * this cache's own img is then NULL and its p, d2, d2l bound every
     * combination the field takes (mp_prf_cache_build). */
    int nt;
    struct mp_prf_cache_s *term;
    const double *planes;  /* the field's (mp_prf_cache_usable) */
} mp_prf_cache;

/* mp_prf_cache_build: the grid of model m (its full sinc_hw; m->cache is
 * ignored), at least G phases per pixel.  An analytic PSF, or a grid that
 * would take more than 160 MB, gets an empty cache (c->G = 0).  A
 * variable PSF (m->psf->field) gets a grid per plane of the field, and
 * its bound holds for every star whose terms are at most 1 in size: a
 * polynomial field's within its scales of the origin (|x − x0| ≤ xscale,
 * |y − y0| ≤ yscale, where the PSF built from a frame holds the whole
 * frame), any position of a grid of tables (its weights are a convex
 * combination).  There δP = Σ c_t δP_t is at most Σ |δP_t| (a grid's:
 * the largest |δP_t|) and P at least P_0 − Σ_{t≥1} |P_t| (a grid's: the
 * least P_t), which the bound (mp_prf_cache_bound) takes.
 * Nonzero with err when out of memory. */
int mp_prf_cache_build(const mp_prf_model *m, int G, mp_prf_cache *c, char *err);

/* mp_prf_cache_build_reusing: the same, its blocks taken from spare (a
 * grid built before, or zeroed) where spare holds one of the size it
 * needs (spare's pointer then NULL); spare keeps the rest, for the caller
 * to free (mp_prf_cache_free).  The values are mp_prf_cache_build's. */
int mp_prf_cache_build_reusing(const mp_prf_model *m, int G, mp_prf_cache *c,
                               mp_prf_cache *spare, char *err);

/* mp_prf_cache_build_exact: the same grid with every node and cell drawn
 * by mp_prf_render_branch (the path a DRF with subpixel QE takes; the
 * others' are drawn as a product of per-axis operators, fit/prf_axis.c,
 * equal up to the order of the sums: test_prf_cache compares them). */
int mp_prf_cache_build_exact(const mp_prf_model *m, int G, mp_prf_cache *c, char *err);

/* The bins of mp_prf_cache.d2bin. */
#define MP_PRF_CACHE_NBIN 16

/* The grid economy=yes builds by default (fit/setup.c; parameter phasegrid). */
#define MP_PRF_CACHE_G 16
void mp_prf_cache_free(mp_prf_cache *c);

/* mp_prf_cache_bound: q = E·max_cell sqrt(Σ δP²/(E P + B + ron²)), the bound
 * on |bias|/σ_CRLB of a star's flux, position and sky from drawing its PRF
 * from the grid (the argument of fit/sinc_choice.c); INFINITY without a grid. */
double mp_prf_cache_bound(const mp_prf_cache *c, double E, double B, double ron);

/* mp_prf_cache_serves: whether mp_prf_cache_bound(c, E, B, ron) ≤ frac,
 * decided first by bounds on each cell's sum from its δP² binned by P
 * (d2bin: within a bin a pixel's variance B + ron² + E·P lies between the
 * bin's ends), within a factor 2 of each other: only a flux within that of
 * the limit sums every pixel (0 without a grid). */
int mp_prf_cache_serves(const mp_prf_cache *c, double E, double B, double ron, double frac);

/* mp_prf_cache_limit: the largest flux whose bound is ≤ frac on sky B
 * (0 when none, INFINITY when all). */
double mp_prf_cache_limit(const mp_prf_cache *c, double B, double ron, double frac);

/* mp_prf_cache_bound_lin, mp_prf_cache_limit_lin: the same of the bilinear
 * interpolation (mp_prf_cache_render_at with lin): its δP is the d2l's. */
double mp_prf_cache_bound_lin(const mp_prf_cache *c, double E, double B, double ron);
double mp_prf_cache_limit_lin(const mp_prf_cache *c, double B, double ron, double frac);

/* mp_prf_cache_core_radius: core tier k's radius r (k in 0..MP_PRF_NCORE −
 * 1, -1 beyond): a star drawn at MP_PRF_CORE(k) is drawn cubically on the
 * pixels whose offsets from its own whole pixel are within [−r, r + 1] on
 * both axes, bilinearly beyond.  mp_prf_cache_bound_core: that tier's
 * bound, its δP² the cubic's within the core, the bilinear's beyond.
 * mp_prf_cache_limit_core: the largest flux (to 0.25 %) whose bound the
 * bins alone hold ≤ frac (mp_prf_cache_serves's test without its pixel
 * sums: found without summing a pixel, and conservative — within each bin
 * P spans a factor 2, so the bound at twice the limit is above frac where
 * the last bin, P down to 0, spreads the variance little; no flux where
 * the bins cannot bound, a PSF's negative pixels below −(B + ron²)/E). */
int mp_prf_cache_core_radius(int k);
double mp_prf_cache_bound_core(const mp_prf_cache *c, int k, double E, double B, double ron);
double mp_prf_cache_limit_core(const mp_prf_cache *c, int k, double B, double ron, double frac);

/* mp_prf_cache_tiers: c's tiers on sky B: mp_prf_cache_limit_core's, and
 * with exact mp_prf_cache_limit_lin, else the bilinear limit as the
 * cores' are found, from the bins alone (conservative, and no pixel
 * summed: mp_prf_cache_limit_lin's sums cost ~1 % of 47 Tuc's run a
 * call). */
void mp_prf_cache_tiers(const mp_prf_cache *c, double B, double ron, double frac, int exact,
                        mp_prf_tiers *t);

/* mp_prf_tier_mode: the cheapest mode whose limit in t holds |E|:
 * MP_PRF_BILINEAR, the least core, else MP_PRF_CUBIC (t NULL: cubic).
 * mp_prf_tier_mode_from: the same among from and the modes more exact
 * than it (in the order bilinear, cores 0, 1, ..., cubic). */
int mp_prf_tier_mode(const mp_prf_tiers *t, double E);
int mp_prf_tier_mode_from(const mp_prf_tiers *t, double E, int from);

/* mp_prf_cache_deriv_box: for a group fit with fitting radius fitrad, sets
 * c->dbox_hw = h = mp_fit_core_halfwidth(fitrad) and c->dbox_u, the
 * largest u = E/(B + RON²) at which an isolated star loses at most the
 * fraction smax of its Fisher information on x and on y when its
 * derivatives are drawn within [floor(x − h), ceil(x + h)] × the same in y
 * alone: I_out/(I_disc + I_out) ≤ smax, with I = Σ E²(∂P/∂x)²/(E·P + B +
 * RON²) over the pixels beyond that box (I_out) and within fitrad − 1 px
 * of the star (I_disc: its own fitting disc, which the group's fitted
 * pixels always hold, after a move of up to 1 px).  Drawn from the grid at
 * 4 × 4 subpixel phases, on a grid of 8 u a decade from 1e-2 to 1e9 (the
 * limit is the last u at and below which every phase passes: 0 when the
 * faintest does not, INFINITY when all do).  A fit that draws the
 * derivatives within the box alone (fit/lm_render.c) has a position σ at
 * most 1/sqrt(1 − smax) of its whole window's.  Nonzero with err when out
 * of memory. */
#define MP_DBOX_SHARE 0.01
int mp_prf_cache_deriv_box(mp_prf_cache *c, const mp_prf_model *m, double fitrad,
                           double smax, char *err);

/* mp_prf_render_branch: as mp_prf_render_window, the
 * table aligned (its element nearest the star, and so the box) as for a
 * star at (xr, yr), then shifted to (x, y) — for the phase grid, whose
 * renders must stay on one side of the points where the natural alignment
 * jumps (every 1/OVERSAMP px), so that they are smooth in the phase. */
int mp_prf_render_branch(const mp_prf_model *m, double x, double y, double xr, double yr,
                         long wx0, long wy0, long ww, long wh, long *x0, long *y0, int *w,
                         int *h, double *prf, double *ddx, double *ddy, mp_prf_work *work);

/* mp_prf_cache_usable: nonzero when c was built for m's psf and drf (for a
 * variable PSF: for its field's planes, so that a view of it at a
 * sub-image's place, mp_psf_local, is served too). */
int mp_prf_cache_usable(const mp_prf_cache *c, const mp_prf_model *m);

/* mp_prf_cache_covers: nonzero when c's bound holds for a star of model m
 * at (x, y): always for a constant PSF and a grid of tables, within the
 * field's scales of its origin for a polynomial one (mp_prf_cache_build). */
int mp_prf_cache_covers(const mp_prf_cache *c, const mp_prf_model *m, double x, double y);

/* mp_prf_cache_render: the interpolated PRF (and derivatives, may be NULL)
 * of model m on the box [x0, x0+w) × [y0, y0+h), in mode (MP_PRF_CUBIC,
 * MP_PRF_BILINEAR within mp_prf_cache_limit_lin's bound, MP_PRF_CORE(k)
 * within mp_prf_cache_limit_core's); nonzero when c is not usable for m. */
int mp_prf_cache_render(const mp_prf_cache *c, const mp_prf_model *m, double x, double y,
                        long x0, long y0, int w, int h, double *prf, double *ddx, double *ddy,
                        int mode);

/* A row span of detector pixels: [x0, x0 + n) of row y (1-based). */
typedef struct {
    long x0, y;
    int n;
} mp_span;

/* mp_prf_cache_render_spans: as mp_prf_cache_render, on the pixels of ns
 * spans only, their values one span after the other (Σ n of each array;
 * any of the three may be NULL): a group fit renders its fitted pixels,
 * not the box around them, and a trial step its PRF only. */
int mp_prf_cache_render_spans(const mp_prf_cache *c, const mp_prf_model *m, double x, double y,
                              const mp_span *sp, int ns, double *prf, double *ddx, double *ddy);

/* mp_prf_cache_render_at: as mp_prf_cache_render_spans, span k's values at
 * index at[k] of each array (at NULL: one span after the other), so that a
 * part of a star's window is rendered in place (lm_render.c's core
 * renders), in mode as mp_prf_cache_render (a bilinear part's derivatives
 * interpolated as well: the grid's, not the interpolant's). */
int mp_prf_cache_render_at(const mp_prf_cache *c, const mp_prf_model *m, double x, double y,
                           const mp_span *sp, const size_t *at, int ns, double *prf, double *ddx,
                           double *ddy, int mode);

/* ---- How strongly two stars' fits are coupled (fit/coupling.c) ---------- */

/* κ, the largest canonical correlation between the parameters (flux, x, y)
 * of one star and those of another in their joint fit: fitted apart, the
 * other held at its estimate, a star's parameters move by at most κ of
 * their σ for each σ of the other's error, and their variance misses at
 * most a fraction κ² (the pipeline cuts a component too large to fit at
 * once at its weakest κ, pipeline/coupled.c).  Tabulated once per PSF and
 * sky: nd separations every dstep px below crit, na fluxes
 * E = (B + RON²)·10^(a0 + astep·i) each, the largest over eight
 * directions; made conservative (non-increasing in the
 * separation, non-decreasing in each flux), so a lookup at the node at or
 * below d and at or above each flux bounds κ between the nodes.  The
 * fitting discs are the pixels within fitrad of each star; the sky is left
 * out (each group fits its own). */
typedef struct {
    int nd, na;
    double dstep, a0, astep, crit, fitrad, beff;
    float *k;          /* nd × na × na */
} mp_coupling;

/* mp_coupling_build: c for model m (a variable PSF: at its field's origin),
 * fitting radius fitrad, separations below crit, sky [e-/px] and ron [e-].
 * κ depends on the fluxes only through E/(B + RON²) (a canonical
 * correlation is the same for the information scaled by any constant),
 * so the table is made in those units and serves any sky
 * (mp_coupling_at).  Nonzero with err on bad arguments or out of memory
 * (c then empty). */
int mp_coupling_build(const mp_prf_model *m, double fitrad, double crit, double sky, double ron,
                      mp_coupling *c, char *err);

/* mp_coupling_at: c's lookups for sky [e-/px] and ron [e-] from now on
 * (the table as it was made: it holds for every sky). */
void mp_coupling_at(mp_coupling *c, double sky, double ron);

/* mp_coupling_kappa: the bound on κ of two stars d px apart with fluxes Ea
 * and Eb [e-] (not finite: the brightest node; ≤ 0: the faintest); 0 from
 * crit on, 1 for a d that is not a number ≥ 0. */
double mp_coupling_kappa(const mp_coupling *c, double d, double Ea, double Eb);
void mp_coupling_free(mp_coupling *c);

/* ---- Performance model (paper §2) ----------------------------------------- */

typedef struct {
    double volume;     /* V = Σ PRF */
    double sharp;      /* Σ (PRF/V)² */
    double beta;       /* 1/Σ PRF²  [px²] */
    double lscale;     /* L = 1/sqrt(4π sharp) [px] */
} mp_prf_stats;

void mp_prf_stats_of(const double *prf, size_t n, mp_prf_stats *s);

/* mp_prf_stats_at: the statistics of the whole PRF of a star at (x, y); w
 * may be NULL.  Nonzero (and s zeroed) when out of memory. */
int mp_prf_stats_at(const mp_prf_model *m, double x, double y, mp_prf_stats *s, mp_prf_work *w);

/* mp_perf_model: the paper's predicted σ_E [e-] (eq. practical-snr) and σ_X
 * [px] (eq. practical-astrometric-model) for intensity E on sky B [e-/px],
 * read noise ron [e-], N pixels in the fit. */
void mp_perf_model(const mp_prf_stats *s, double E, double B, double ron, double npix,
                   double *sigma_e, double *sigma_x);

/* mp_crlb: the Cramér–Rao bound of (E, X, Y, B) for one star on a constant
 * sky: invert F_jk = Σ ∂m/∂p_j ∂m/∂p_k / (m + ron²) with m = B + E·prf.
 * sd receives the four standard deviations.  Nonzero if F is singular. */
int mp_crlb(const double *prf, const double *dx, const double *dy, size_t n,
            double E, double B, double ron, double sd[4]);

/* mp_chi2_sf: P(χ²(k) > x), the χ² survival function for integer k ≥ 1
 * (closed form); the sky-order test's p-value. */
double mp_chi2_sf(int k, double x);

/* The run's economy state (fit/econ_plan.c): the tables economy may build
 * and, per sky level, their flux limits.  A table is built only when the
 * work it can save on the star fits the run expects exceeds the work it
 * costs — fits · MP_ECON_RENDERS_PER_FIT · (multiply-adds saved per render,
 * at most) ≥ its build + its decisions — decided before building, and
 * kept for the run once built.  The limits: a frame's sky is rounded down
 * to a quarter octave (the safe side: less sky, less noise, lower limits),
 * so an @list of frames pays MP_SINC_LIMITS_EVALS·hwmax bound evaluations
 * per table and sky level once, not per frame.  Thread-safe; at most
 * MP_ECON_CACHE_MAX limit entries (past that, frames compute their own). */
typedef struct mp_econ_cache mp_econ_cache;
#define MP_ECON_CACHE_MAX 64
/* LM renders of a star fit, at least, as the plan counts them: the start
 * and three trial steps (the median star of the bench's scenes takes 3
 * iterations, bench/REPORT.md). */
#define MP_ECON_RENDERS_PER_FIT 4.0
mp_econ_cache *mp_econ_cache_new(void);      /* NULL when out of memory */
void mp_econ_cache_free(mp_econ_cache *c);
/* mp_econ_cache_hand_grid: from's phase grid (if built) handed to to, whose
 * own grid, when built, takes its blocks where they are of the size it
 * needs (mp_prf_cache_build_reusing; the rest freed then or with to); from,
 * left without one, is for freeing only.  A run whose PSF is built anew
 * (the pipeline's second pass) builds the new grid in the old one's
 * pages. */
void mp_econ_cache_hand_grid(mp_econ_cache *from, mp_econ_cache *to);
/* mp_econ_envelope: a copy of model m's crop envelope (mp_prf_envelope,
 * the caller frees it), measured once per cache while m is the cache's
 * own model (its PSF, DRF and sinc half-width; a variable PSF's costs 225
 * renders, and every frame fit and residual of a run crops by it); any
 * other model's, or with c NULL, measured afresh.  NULL when out of
 * memory. */
double *mp_econ_envelope(mp_econ_cache *c, const mp_prf_model *m, int *nr);

/* ---- The fit --------------------------------------------------------------- */

enum {
    MP_FLAG_SATURATED = 1, MP_FLAG_SPLIT = 2, MP_FLAG_EDGE = 4,
    MP_FLAG_NOCONV = 8, MP_FLAG_MERGED = 16, MP_FLAG_MASKED = 32
};

/* Sky models: a polynomial in the group box's coordinates scaled to
 * [-1, 1] (u, v), order 0: 1; 1: 1, u, v; 2: also u² − 1/3, uv, v² − 1/3.
 * MP_SKY_AUTO: the order is chosen per group from the data — constant,
 * then higher when a score test of the extra terms at the lower-order fit
 * (over the fitted pixels and the background around them) is significant
 * at p < MP_SKY_ALPHA (sky_test.c). */
enum { MP_SKY_AUTO = -1, MP_SKY_MAXORDER = 2 };
#define MP_SKY_ALPHA 1e-3
/* The test also reads the background out to this many fitrad from the
 * group's stars (sky_test.c ring_sums); a group's frame must hold it. */
#define MP_SKY_TEST_RADIUS 2.0

/* mp_frame_opts.decidetol's default: merges and rejections decided on fits
 * whose last step is below 0.03 σ (the tasks' tol before session 51: a
 * step of that size squared is 0.1 % of the variance).  The steps' own
 * tol (the .par files' 0.1) alone lost 1-3 of the 4 600 stars of each
 * crowded frame (validate/CROWDED.md), as loose rounds did before
 * decision_pending. */
#define MP_DECIDE_TOL 0.03

typedef struct {
    int sky_order;     /* MP_SKY_AUTO, or 0 constant, 1 plane, 2 quadratic */
    double fitrad;     /* radius fitted around each star [px]; NaN: whole frame */
    double tol;        /* converged when every |step| < tol·σ (1e-3 here,
                        * which the PSF build's star fits keep; the tasks'
                        * .par files say 0.1: a step of that size squared
                        * is 1 % of the variance, the bound refittol holds
                        * a kept group to, with merges and rejections
                        * decided on fits to MP_DECIDE_TOL) */
    int maxiter;
    double stop_pair;  /* end the fit, not converged, when a step from the
                        * 10th on leaves two stars closer than this [px]
                        * (the frame fit's merge radius: it merges them and
                        * fits again; fit/levmar.c LM_PAIR_AFTER); 0: never */
    int fit_sky;       /* 0: sky fixed at the start value */
    const mp_prf_crop *crop;   /* economy: each star rendered out to its
                                * crop radius only (NULL: its whole box) */
    const struct mp_prf_cache_s *grid;  /* economy: the group's PRF drawn from
                                * this phase grid when built for its model
                                * (fit/prf_cache.c); NULL: exact renders */
    double grid_emax;          /* economy: a star whose start flux exceeds this
                                * (the grid's bias bound) is rendered exactly,
                                * its neighbours from grid (INFINITY: all) */
    mp_prf_tiers grid_tiers;   /* economy: a star whose flux stays within one
                                * of these (the bounds of the bilinear
                                * interpolation and the core tiers,
                                * mp_prf_cache_tiers) is drawn in that mode;
                                * once above, in the next to its fit's end
                                * (zeroed: cubic) */
    double *work;              /* not NULL: the multiply-adds of the group's
                                * exact table renders are added to *work (the
                                * caller's own, per thread; economy's plan) */
    int exact_lm;              /* 1: every LM step on the whole windows, no
                                * frozen wings (fit/lm_frozen.c); 0, the default,
                                * freezes them where it pays (tests compare) */
    int settle;                /* 1, the default: a star whose steps stay
                                * below tol is held while the others go on
                                * (fit/lm_settle.c); 0: every star steps to
                                * the end (tests compare) */
    int refresh_movers;        /* 1, the default: frozen wings redrawn only
                                * for the stars that moved far, between
                                * steps (fit/lm_frozen.c); 0: every star's
                                * (tests compare) */
    int reuse_pairs;           /* 1, the default: after a sky-order rise the
                                * LM starts from the pairs' sums of the last
                                * loop's exact pass (fit/lm_normal.c
                                * NE_REUSE); 0: sums them again (tests
                                * compare: the same bytes) */
    int weak_pairs;            /* 1, the default: a fit's later exact passes
                                * keep the sums of the pairs its earlier one
                                * found weakly coupled (fit/lm_normal.c
                                * pairs_kept_weak); 0: sums every pair (tests
                                * compare) */
    int stats;                 /* 1, the default: each star's PRF statistics
                                * and model errors (st, fluxerr_model,
                                * poserr_model) set; 0: left for the caller
                                * (a frame fit sets them once, at its end:
                                * mp_star_model_errors) */
    int warm_sky;              /* 1 in frame fits (mp_frame_opts_default),
                                * 0 here: under MP_SKY_AUTO a group starts
                                * at the highest sky order its stars were
                                * last fitted with (mp_star.sky_order, 0
                                * when never fitted), from the polynomial
                                * through their last sky values, the score
                                * test going on from there; unless one of
                                * them last ended flagged saturated or not
                                * converged (fit_group.c first_order).  A
                                * refit (the fit's second pass, the
                                * pipeline's later rounds) then skips the
                                * loops that raised the order from
                                * constant the time before */
    double sky_known;          /* the lowest sky the group's stars were
                                * found on (find's BACKGROUND), whence the
                                * sky's floor, 10 σ below it (levmar.c
                                * sky_floor); a frame fit sets it per
                                * group.  NaN here: the lowest of the
                                * stars' own skies, which for a star
                                * fitted before is that fit's: a blend's,
                                * raised by its unresolved companion's
                                * light (frame X of the DAOPHOT bench: 37
                                * of 4025 stars at 150-1000 e- on a sky of
                                * 100), held the next round's group far
                                * above the sky */
} mp_fit_opts;

void mp_fit_opts_default(mp_fit_opts *o);

/* OpenBLAS to one thread, for the process: call once at the start of a
 * program that fits (the fits are threaded over groups; OpenBLAS's own
 * threads only spin beside them, fit/blas_threads.c). */
void mp_blas_single_thread(void);

/* One star: start values in, fitted values out. */
typedef struct {
    double x, y, flux;              /* in/out */
    double ex, ey, eflux;           /* 1σ from the covariance */
    double sky, esky;               /* fitted sky at the star and its error */
    double chi2;                    /* reduced χ² of its group */
    int dof, niter, flags;
    /* Reduced χ² over the star's own disc alone (the group's fitted pixels
     * within fitrad of its fitted position; the whole group's when fitrad
     * is not finite), with dof = those pixels − 3: DAOPHOT's CHI, squared.
     * Beside chi2, not instead of it (CHI2STAR_PSF). */
    double chi2star;
    int dofstar;
    int sky_order;                  /* the order the group's sky was fitted with */
    int npix;                       /* its group's fitted pixels at its last fit */
    mp_prf_stats st;                /* of the PRF at the fitted position */
    double fluxerr_model, poserr_model;
} mp_star;

/* mp_star_model_errors: s->st, the statistics of the whole PRF of model m
 * at (s->x, s->y) (zero when not finite), and s->fluxerr_model,
 * s->poserr_model from them (mp_perf_model with s->flux, at least 1,
 * s->sky and s->npix); w as mp_prf_stats_at's.  Nonzero when out of
 * memory. */
int mp_star_model_errors(const mp_prf_model *m, double ron, mp_star *s, mp_prf_work *w);

/* mp_fit_group: fit n stars (one group) with their sky on frame f.
 * sky0 is the starting sky level (NaN: estimated from the fitted pixels).
 * Never leaves NaN or inf in stars: a fit that does not meet tol within
 * maxiter (or stalls before it) keeps the best state it reached and flags
 * every star MP_FLAG_NOCONV; a star without finite values keeps its start.
 * stars[k].sky_order tells the sky order used (o->sky_order, or the one
 * chosen under MP_SKY_AUTO). */
int mp_fit_group(const mp_frame *f, const mp_prf_model *m, const mp_fit_opts *o,
                 double sky0, mp_star *stars, int n, char *err);

/* mp_fit_core_halfwidth: the half-width [px] of the box around a star
 * within which a group fit with fitting radius fitrad redraws it while its
 * wings are frozen, and draws its position derivatives when the phase
 * grid's mp_prf_cache_deriv_box, measured for this half-width or less,
 * serves it (fit/lm_frozen.c, fit/lm_render.c). */
double mp_fit_core_halfwidth(double fitrad);

/* ---- A whole frame ------------------------------------------------------- */

/* How every star of a table is fitted on a frame (ALLSTAR's practice,
 * anchors.md §1.6): groups by GROUP_ID fitted simultaneously with their own
 * sky, the light of all other stars subtracted first (from the previous
 * pass), close pairs merged, insignificant stars rejected. */
typedef struct {
    mp_fit_opts fit;
    double magzero;    /* MAG_PSF = −2.5 log10(FLUX_PSF) + magzero */
    double mergerad;   /* merge stars closer than this [px], unless they
                        * are separated by mp_merge_sig(minsnr) or more of
                        * their separation's σ; NaN: 0.4 FWHM of the PSF;
                        * 0: never.  Pairs closer than twice the error of
                        * their separation are merged too. */
    double minsnr;     /* reject stars with FLUX_PSF/FLUXERR_PSF below this */
    int passes;        /* fits of every group; from the 2nd on, neighbours'
                        * light comes from the previous pass */
    double loosetol;   /* above fit.tol: the groups' fits stop at this tol
                        * (a fit a full one follows, pipeline/run.c), but a
                        * group whose loose fit leaves a merge or rejection
                        * the fit to fit.tol might not make is fitted on to
                        * fit.tol first (frame_group.c); a later fit with
                        * the same memory never keeps a loose group (its
                        * stars' refit bounds start at infinity, not 0).
                        * 0: every fit to fit.tol */
    double decidetol;  /* below fit.tol: a group whose fit to fit.tol leaves
                        * a merge or rejection pending (as for loosetol) is
                        * fitted on to this tol first, so those decisions,
                        * which are for good, are made on the same fits
                        * whatever the steps' tol (MP_DECIDE_TOL; 0: at
                        * fit.tol) */
    double cropfrac;   /* economy: a star's light is painted (neighbour
                        * subtraction, residual) out to the radius where it
                        * falls below cropfrac·σ of a sky pixel; 0: its
                        * whole PSF table (economy=no) */
    double refittol;   /* economy: a group is not refitted when, for each
                        * member, the light of all other stars on its
                        * fitting region changed by less than refittol in
                        * √Σ(Δ/σ)² since its last fit (that bounds the
                        * change of its fitted parameters to refittol of
                        * their σ), as an upper bound of that change says
                        * (fit/frame_bound.c); 0: refit every group every
                        * pass (economy=no) */
    double couplefrac; /* economy: the pipeline cuts a component of more
                        * than maxgroup stars at its weakest couplings, κ
                        * (mp_coupling), and flags 2 the stars of a cut link
                        * with κ ≥ couplefrac (fitted apart, each moves by
                        * more than that many σ per σ of the other's error);
                        * 0: at its median (economy=no, DAOPHOT GROUP's
                        * rule and group.h's split) */
    const struct mp_ss_level_s *ss;  /* economy: nss coarser samplings of the
                        * model's table, coarsest first; each group is fitted
                        * with the coarsest whose linearised bias at its
                        * brightest star is ≤ ssfrac of each parameter's σ
                        * and whose χ² shift is ≤ 1 (fit/ss_choice.c),
                        * else with the model's table (neighbours are painted
                        * with the model's table) */
    int nss;
    int ss_sinc;       /* bit l: level l's own kernel choice (ss[l].sinc) is
                        * used when built (default all; mp_econ_choose sets
                        * the levels' whose choice pays for this frame) */
    int ss_grid;       /* bit l: level l's own phase grid (ss[l].grid) serves
                        * its groups within its bound, as grid does the
                        * model's table (default all; mp_econ_choose sets
                        * the levels' whose grid pays for this frame) */
    double ssfrac;
    mp_econ_cache *cache;  /* economy: the run's tables, built when they pay
                        * (mp_econ_choose), and the choices' flux limits
                        * kept across frames (NULL: none) */
    double fits;       /* economy: star fits the run expects (an @list's
                        * stars); a frame plans for the larger of this and
                        * its own stars (0: its own) */
    int learn;         /* economy: the LM renders this run has already done
                        * count toward a table's pay-off too (the pipeline's
                        * rounds and passes of a frame); 0 where the plan
                        * knows the run (fit's @list) and where frames are
                        * fitted in parallel (fakes: timing) */
    double win;        /* economy: the side [px] of the square whose area is
                        * the mean window a star is rendered on in its group's
                        * fit (its group's box, PSF box and crop radius),
                        * measured on the frame by mp_fit_table_mem; 0:
                        * 2·ceil(fitrad) + 3, a lone star's (issue 12: 47 Tuc
                        * measures 36-42 px against that 13) */
    double psfdx, psfdy;  /* a sub-image's pixel (1, 1) is the PSF field's
                        * (1 + psfdx, 1 + psfdy) (mp_fit_setup_local): the
                        * run's coarser levels read a variable PSF there */
    const struct mp_sinc_choice_s *sinc;  /* economy: each group fitted with
                        * the shortest sinc half-width whose bias stays below
                        * sincfrac of its brightest star's σ (fit/sinc_choice.c);
                        * NULL: the model's sinc_hw for all */
    double sincfrac;
    const struct mp_prf_cache_s *grid;  /* economy: the PRF from a grid of
                        * phases for groups whose brightest star's bias bound
                        * stays below sincfrac of its σ (fit/prf_cache.c);
                        * NULL: exact renders */
} mp_frame_opts;

void mp_frame_opts_default(mp_frame_opts *o);

/* mp_econ_offer: what the run may build for model m (kept by pointer: m,
 * its PSF and field must outlive c): nlev coarser samplings of its table
 * with OVERSAMP lev_os[] (coarsest first), the sinc kernel choice (sinc
 * nonzero), the phase grid of grid_g phases per pixel (0: none; never for
 * a variable PSF).  Measures nothing. */
int mp_econ_offer(mp_econ_cache *c, const mp_prf_model *m, int nlev, const int *lev_os,
                  int sinc, int grid_g);

/* mp_econ_choose: point o->sinc, o->ss/o->nss and o->grid (those still
 * NULL) at the offered tables that pay for `fits` star fits over windows
 * of side o->win, or of radius fitrad when o->win is 0 (NaN: whole
 * frames), building them on first need.  The decision depends on fits,
 * the windows and the PSF only.  *spent (may be NULL) gets
 * the multiply-adds this call spent building.  Nonzero with err when a
 * build fails (out of memory). */
int mp_econ_choose(mp_econ_cache *c, double fits, double fitrad, mp_frame_opts *o,
                   double *spent, char *err);

/* mp_econ_grid_limits: the flux limits of phase grid g on sky level sky,
 * computed once a run in cache as the frame fit's own are: the sky
 * rounded down to a quarter octave (a lower limit, so one that holds on
 * sky itself), the cubic interpolation's into *emax, the bilinear one's
 * and the core tiers' into *tiers (either may be NULL).  Nonzero, and
 * nothing set, when cache or g is NULL, the cache is full or out of
 * memory. */
int mp_econ_grid_limits(mp_econ_cache *cache, const mp_prf_cache *g, double sky, double ron,
                        double frac, double *emax, mp_prf_tiers *tiers);

/* mp_econ_learn: add ops (multiply-adds of the exact table renders the
 * run's fits have done) to what mp_econ_choose counts for options with
 * learn set: a table is also built once that work, times the fraction of
 * a render the table saves, would have paid for it (at most twice the
 * work of knowing the run's length in advance). */
void mp_econ_learn(mp_econ_cache *c, double ops);
/* mp_econ_learn_paint: add ops (multiply-adds of the exact renders the
 * run has painted neighbours' light and residuals with) to what
 * mp_econ_choose counts for the model's phase grid, which serves the
 * paints too (fit/frame_paint.c), at the fraction of a whole-box render
 * it saves. */
void mp_econ_learn_paint(mp_econ_cache *c, double ops);

/* mp_econ_forget: the learned work back to 0, for a run whose every frame
 * must come out as it would alone (the pipeline: an @list's frame is
 * byte-identical to its own job's); tables already built stay, used only
 * where this frame's own count pays for them. */
void mp_econ_forget(mp_econ_cache *c);

/* The plan's unit: multiply-adds of one LM render (with derivatives) of
 * model m at half-width hw over a fitting window of radius fitrad (NaN:
 * its whole box); of one render from the phase grid. */
double mp_econ_render_ops(const mp_prf_model *m, int hw, double fitrad);
double mp_econ_grid_render_ops(const mp_prf_model *m, double fitrad);

/* mp_econ_summary: one line for the run report — the tables built and
 * their cost in renders of the model (ops_render multiply-adds each). */
void mp_econ_summary(const mp_econ_cache *c, double ops_render, char *buf, size_t n);

/* Why a group's LM fit ran again within its frame fit (fit/frame_group.c):
 * a pair merged, stars rejected below minsnr, a merge or rejection that
 * the fit at its tol left pending decided at the deciding tol, a fit cut
 * short on a close pair that proved two stars fitted to its end, a star
 * fitted brighter than economy's choices for the group held. */
enum { MP_REFIT_MERGE, MP_REFIT_REJECT, MP_REFIT_DECIDE, MP_REFIT_UNSTOPPED, MP_REFIT_BRIGHTER,
       MP_REFIT_CAUSES };

/* What a frame fit did, for the run report. */
typedef struct {
    long nstars, ngroups, merged, rejected, noconv;
    long iterations;   /* summed over groups and passes */
    long sky_groups[MP_SKY_MAXORDER + 1];  /* groups of the last pass by sky order */
    long fits;         /* group fits done, over passes (and rounds) */
    long kcalls;       /* LM fits of groups (a group refits after a merge) */
    long kshort;       /* of them, with a sinc kernel shorter than sinchw */
    long kcache;       /* of them, with the PRF from the phase grid */
    long klin;         /* star fits in them drawn bilinearly (final flux
                        * within the bilinear limit) */
    long kcore;        /* ... and with a cubic core (within a core tier's
                        * limit) */
    long kstars;       /* star fits in the LM fits */
    double khw;        /* their half-widths, summed */
    long kbounds;      /* the kernel and table choices' cost: bound
                        * evaluations (mp_sinc_choice_bound,
                        * mp_ss_level_serves), each nph × npix terms */
    long kcoarse;      /* LM fits with a coarser table (opts ss) */
    long refits[MP_REFIT_CAUSES];       /* LM fits of a group again within its
                        * fit, by cause (MP_REFIT_*) */
    long refit_steps[MP_REFIT_CAUSES];  /* and their LM steps */
    double ops_tables; /* economy's tables built by this call (mp_econ_choose)
                        * and its bound evaluations [multiply-adds] */
    double ops_saved;  /* what the tables saved, counted per LM fit: its
                        * renders (iterations + 1) × (a render of the
                        * model as given − the render used) */
    double ops_render; /* one render of the model as given (the unit) */
    double render_ops; /* multiply-adds of the group fits' exact table
                        * renders (mp_fit_opts.work) */
    long envelopes;    /* crop envelopes built (mp_prf_envelope: 25 PSF
                        * renders each); 0 when the frame is one group */
    long kept;         /* group fits left out: no star's surroundings changed */
    long cropped;      /* stars painted with a cropped PSF */
    const struct mp_prf_cache_s *grid;  /* the phase grid the last pass drew
                        * its groups' PRFs from (economy's, kept for the run;
                        * NULL: exact renders) */
    double win;        /* the window side [px] economy priced its tables on
                        * (mp_frame_opts.win, measured on the frame's stars);
                        * 0: none */
} mp_frame_report;

/* mp_frame_report_add: the counts of r added to d — the sums (iterations,
 * merges and rejections, group and LM fits, economy's work and cost,
 * paints cropped, envelopes); what stands for the last pass (nstars,
 * ngroups, noconv, sky_groups, ops_render, grid, win) is left to the
 * caller. */
void mp_frame_report_add(mp_frame_report *d, const mp_frame_report *r);

/* Every star's last fit and how far its neighbours' light has moved
 * since, so a later pipeline round can tell whether refitting it could
 * change anything (economy, fit/frame_bound.c). */
typedef struct mp_fit_memory mp_fit_memory;

/* mp_fit_memory_new: an empty memory; NULL when out of memory. */
mp_fit_memory *mp_fit_memory_new(void);
void mp_fit_memory_free(mp_fit_memory *mem);

/* mp_fit_memory_forget: every remembered fit and bound dropped (a new
 * PSF, or light taken off the frame: every group is fitted afresh), but
 * each star's sky order kept, from which its group's next fit starts
 * (the frame fit's warm start, as after any remembered fit). */
void mp_fit_memory_forget(mp_fit_memory *mem);

/* mp_fit_memory_scratch: lend the fit a buffer of n floats it may
 * overwrite with the model of every star (the neighbours subtracted from
 * each group) instead of allocating one of the frame's size: the
 * pipeline lends its residual, which is dead until mp_fit_residual
 * redraws it.  A buffer smaller than the frame is not used; NULL takes
 * the loan back.  The memory never frees it. */
void mp_fit_memory_scratch(mp_fit_memory *mem, float *buf, size_t n);

/* mp_fit_table: fit every star of t on f — rows carry X_IMAGE/Y_IMAGE or
 * XPSF_IMAGE/YPSF_IMAGE, optional GROUP_ID (else each star alone, or all in
 * one group when fit.fitrad is NaN), optional start FLUX_PSF or FLUX and
 * SKY_PSF or BACKGROUND, optional SKYORD_PSF (with fit.warm_sky and
 * MP_SKY_AUTO a group's sky starts at its stars' highest order, 0 for a
 * star whose FLAGS say not converged) — and add the fit's
 * columns of design.md §4 with CHI2STAR_PSF and SKYORD_PSF.  Merged and rejected stars leave the table (the survivor of a merge has
 * flag 16).  rep may be NULL. */
int mp_fit_table(const mp_frame *f, const mp_prf_model *m, const mp_frame_opts *o,
                 mp_table *t, mp_frame_report *rep, char *err);

/* mp_fit_table_mem: as mp_fit_table, remembering across calls (the rounds
 * of the pipeline, on the same frame and table growing by new rows) what
 * every star was fitted against, keyed by the table's NUMBER column: a
 * star whose surroundings (the light of all other stars on its fitting
 * region) have not changed beyond o->refittol keeps its fit.  mem NULL:
 * mp_fit_table. */
int mp_fit_table_mem(const mp_frame *f, const mp_prf_model *m, const mp_frame_opts *o,
                     mp_table *t, mp_fit_memory *mem, mp_frame_report *rep, char *err);

/* mp_fit_residual: res = data − Σ E·PRF over the stars of a fitted table
 * (electrons, single precision as the frame; NaN where masked).  res holds
 * nx*ny.  cropfrac as in
 * mp_frame_opts (0: every star's whole PSF). */
int mp_fit_residual(const mp_frame *f, const mp_prf_model *m, const mp_table *t,
                    double cropfrac, float *res, char *err);

/* mp_fit_residual_grid: as mp_fit_residual, the stars whose |FLUX_PSF| is
 * at most gemax painted from the phase grid (economy, fit/prf_cache.c: the
 * PRF within its bound of 0.1 σ of such a star's fit, as the fit's own
 * paints of the neighbours draw it), in the cheaper modes of tiers (NULL:
 * cubic); grid NULL: exact renders.  The crop's envelope is cache's
 * (mp_econ_envelope; NULL: measured here). */
int mp_fit_residual_grid(const mp_frame *f, const mp_prf_model *m, const mp_table *t,
                         double cropfrac, mp_econ_cache *cache, const mp_prf_cache *grid,
                         double gemax, const mp_prf_tiers *tiers, float *res, char *err);

/* ---- The run report ------------------------------------------------------ */

/* What a run reports (design: every fit and pipeline run ends with it, on
 * stderr and in root.report): seconds per stage (0 for stages not run), the
 * counts of the frame fit, the achieved error against the predicted one, and
 * the model parts used and left out. */
typedef struct {
    const char *image;
    double t_read, t_bkg, t_find, t_group, t_fit, t_write;
    long nstars, ngroups, iterations, merged, rejected, noconv;
    double chi2_median;        /* of CHI2_PSF */
    double errratio_median;    /* of FLUXERR_PSF / FLUXERR_MODEL */
    double poserr_median;      /* of ERRX_PSF / POSERR_MODEL */
    char used[512], left[512];
    const char *decisions;     /* economy decisions, "; "-separated (may be NULL) */
    int ndecisions;
    char sky[192];             /* skymodel=auto: the per-group sky orders (one more
                                * decision; mp_report_parts fills it) */
    long fits, kept, cropped;  /* what the economy decisions did: group fits
                                * done and left out, star paints cropped */
    long kcalls, kshort;       /* LM fits of groups, and of them with a shorter
                                * sinc kernel */
    long refits[MP_REFIT_CAUSES], refit_steps[MP_REFIT_CAUSES];  /* mp_frame_report's */
    long kcache;               /* LM fits with the PRF from the phase grid */
    long klin, kstars;         /* star fits in LM fits drawn bilinearly, and
                                * all star fits */
    long kcore;                /* star fits drawn with a cubic core */
    double khw;                /* their half-widths, summed */
    long kcoarse;              /* LM fits with a coarser table */
    double ops_tables, ops_saved, ops_render;  /* mp_frame_report's */
    const char *tables;        /* economy's tables (mp_econ_summary; may be NULL) */
    long kbounds, envelopes;   /* economy's own cost: kernel-bound evaluations
                                * and crop envelopes built (mp_frame_report) */
    long pairs_close, pairs_coupled;  /* the pipeline's grouping: pairs within
                                * psfrad + fitrad, and of them coupled (0 0:
                                * DAOPHOT GROUP's rule) */
    char detection[1536];       /* the pipeline's detection limit in words ("": no
                                * line; pipeline/outputs.c fills it) */
} mp_run_report;

/* mp_report_counts: the frame fit's counts (fr) into the run's report:
 * groups, iterations, merges, rejections, not converged, and what economy
 * did and cost. */
void mp_report_counts(const mp_frame_report *fr, mp_run_report *r);

/* mp_report_from_table: the medians, from a fitted table. */
void mp_report_from_table(const mp_table *t, mp_run_report *r);

/* mp_report_parts: which parts of the model a run used and left out. */
void mp_report_parts(const mp_prf_model *m, const mp_frame_opts *o, const mp_frame_report *fr,
                     mp_run_report *r);

/* mp_report_write: the report on stderr (lines prefixed "matphot TASK: ")
 * and, when path is given, in that file (atomically). */
int mp_report_write(const char *path, const char *task, const mp_run_report *r, char *err);

/* ---- From parameters ------------------------------------------------------ */

/* What fit.par's parameters (psf, psfnorm, psfos, drf, volume, fwhm, fitrad,
 * skymodel, sinchw, tol, maxiter, mergerad, minsnr, passes, magzero, format
 * and datapars) say, resolved once for every image.  The pipeline's .par
 * holds the same names, so both tasks read them here. */
typedef struct {
    mp_psf psf;
    mp_psf_field field;     /* the PSF file as read (order 0: a copy of psf) */
    mp_drf drf;
    mp_prf_model model;     /* points into psf and drf: do not copy the struct */
    mp_frame_opts opts;
    mp_datapars dp;
    mp_table_format fmt;
    mp_econ_cache *cache;   /* economy: the tables it may build — per-group
                             * kernel length, coarser samplings, the phase
                             * grid — built when they pay (opts.cache) */
    int econ_nlev, econ_os[MP_SS_MAXLEVELS], econ_sinc, econ_grid;  /* what it may
                             * build (mp_econ_offer's arguments) */
    char decisions[4096];   /* economy decisions and their reasons (a variable
                             * PSF built from the frame: ~2.6 KB) */
    int ndecisions;
    char warn[1024];        /* what reading the PSF noticed, a line each (a
                             * table too coarse for the data, paper §5.4;
                             * negative elements; a conversion's cost), for
                             * the task to say (mp_fit_setup_warn) */
} mp_fit_setup;

/* mp_fit_setup_read: read the PSF (and DRF) files and the options; what
 * the PSF's reading noticed goes to s->warn, not to stderr (the pipeline's
 * own tables need no warning). */
int mp_fit_setup_read(const mp_parset *ps, mp_fit_setup *s, char *err);

/* mp_fit_setup_warn: s->warn on stderr, a line each, as "matphot TASK:
 * warning: ...". */
void mp_fit_setup_warn(const mp_fit_setup *s, const char *task);
void mp_fit_setup_free(mp_fit_setup *s);
/* mp_fit_setup_inputs: the files a setup read from ps (psf, drf) and those
 * its frames' reads take (datapars dqmask, errplane) added to in (io.h),
 * for the outputs that may not be written over them; 1 when out of
 * memory, with err. */
int mp_fit_setup_inputs(const mp_parset *ps, const mp_fit_setup *s, mp_inputs *in, char *err);
/* mp_fit_setup_local: the setup to reduce a sub-image whose pixel (1, 1)
 * is frame pixel (1 + dx, 1 + dy) with (a tile's section, a fake's box):
 * s itself when the PSF does not vary; else *out, a view of s (sharing its
 * tables, DRF and economy state: never pass it to mp_fit_setup_free) whose
 * field, and each coarser level's, is read at the star's frame position
 * (mp_psf_local). */
const mp_fit_setup *mp_fit_setup_local(const mp_fit_setup *s, double dx, double dy,
                                       mp_fit_setup *out);

/* The `matphot fit` task. */
int mp_task_fit(int argc, char **argv);

#endif
