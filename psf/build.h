/*
 * build.h — the effective PSF built from a frame's stars (`matphot psf`,
 * issue 11; Anderson & King 2000, anchors.md §4.2; DAOPHOT's psf task).
 *
 * The table is what the fit renders: a star of flux F at (X, Y) puts
 * F·Σ_block S_δ(T) on each detector pixel, S_δ the damped-sinc shift of
 * paper §3.1 and the block the OVERSAMP² elements of the pixel.  That is
 * linear in the table T, so the table is solved for directly on the
 * stars' pixels: each star's centre, flux and sky fitted with the current
 * table (mp_fit_group), the residual per unit flux back-projected onto the
 * table grid (the transpose of render: spread over the pixel's block,
 * shifted back by −δ), combined over the stars robustly (a weighted fit of
 * the polynomial in position per element, clipped), and added — a
 * simultaneous iterative reconstruction (SIRT/Landweber) from a smooth
 * start.  Such an iteration never adds what block-summing cannot see (the
 * box's null space: the dotted, multi-peaked tables of anchors.md §3.2),
 * and its early stop, when an iteration's change is below the noise, is
 * the smoothing the noise needs.  Each element is a polynomial of order 0
 * to 3 in the star's position (PSFEx order: 1, dx, dx², dy, dx·dy, dy² for
 * order 2; psf.h).
 *
 * Errors: 0 on success, nonzero with one line in err (MP_ERRLEN bytes).
 */
#ifndef MATPHOT_PSF_BUILD_H
#define MATPHOT_PSF_BUILD_H

#include "catalog/catalog.h"
#include "find/find.h"
#include "fit/fit.h"
#include "io/io.h"

/* Neighbours fitted with each PSF star at most (the brightest), and the
 * least flux one has, in units of the star's: a fainter detection beside
 * a bright star is as likely a feature of its own PSF (a ring, a
 * segment's satellite: fitted as a neighbour it would take that light
 * out of the table; `matphot psf`'s unscreened find list on the
 * segmented scene: largest error 6 % of the peak), and a faint real
 * neighbour is left to the star's mask (sirt_mask.c). */
#define MP_EPSF_MAXNB 12
#define MP_EPSF_NBMIN 0.05

/* Terms of the highest order the builder makes (MP_PSF_MAXORDER). */
#define MP_EPSF_MAXT ((MP_PSF_MAXORDER + 1) * (MP_PSF_MAXORDER + 2) / 2)

/* One PSF star: a cut-out of the frame around it, and its current fit.
 * With neighbours (mp_epsf_neighbours) the cut-out as cut is kept in raw,
 * the star is fitted together with them on it, and f holds raw less the
 * neighbours' current models (what the table is built from). */
typedef struct {
    mp_frame f;        /* the cut-out; pixels in electrons, own mask */
    float *raw;        /* NULL, or the cut-out with the neighbours in */
    int nnb;           /* neighbours, frame coordinates and flux [e-] */
    double nbx[MP_EPSF_MAXNB], nby[MP_EPSF_MAXNB], nbf[MP_EPSF_MAXNB];
    size_t nbrow[MP_EPSF_MAXNB];   /* their rows in the table they came from */
    long x0, y0;       /* frame pixel of the cut-out's pixel (1, 1) */
    double x, y;       /* position, frame coordinates (1-based) */
    double xf, yf;     /* where it was found (a fit straying > 1 px from it
                        * rejects the star) */
    double flux, sky;  /* fitted flux [e-] (for the table's current sum), sky [e-/px] */
    double chi2;       /* reduced χ² of its last fit */
    int used;          /* 0: rejected by the last build */
    int fitted;        /* 1 once a fit of the build set flux (and its
                        * neighbours'): their start values, 0, may fall
                        * short of the fitted ones */
    int skip;          /* set by the caller: left out of builds */
} mp_epsf_star;

/* How the table is built. */
typedef struct {
    int os;            /* OVERSAMP 1..4; 0: the coarsest whose aliasing
                        * error is below the noise of the brightest star
                        * (with fewer than 6 stars, no finer than they
                        * determine: os² ≤ their number) */
    double psfrad;     /* table half-size [px] */
    double support;    /* elements farther than this from the centre [px]
                        * are zero: the light the stacks could not
                        * measure there (mp_epsf_tablerad's reach), which
                        * mp_epsf_growth counts instead; 0: none */
    double fitrad;     /* radius of each star's fit [px] */
    double fwhm;       /* FWHM of the start (a Gaussian) [px] */
    int order;         /* 0..MP_PSF_MAXORDER; -1: auto (mp_epsf_order_test) */
    int raise;         /* mp_epsf_pass with e built: order e->order + 1 built
                        * from e as it is, its sampling and filter kept (the
                        * pipeline's held-out test of the next order); 0:
                        * order as above */
    double alpha;      /* the order test's false-alarm probability */
    int maxnpsf;       /* stars used at most (selection) */
    int outer;         /* star fits per pass at most (each followed by SIRT
                        * steps; fewer once a round no longer lowers χ²) */
    int sirt;          /* largest number of SIRT steps per outer iteration */
    int grid;          /* the stars' fits at order 0 from a phase grid within
                        * its bias bound (psf/star_model.c): 0 when it pays,
                        * 1 always, -1 never (exact renders; tests compare) */
    double x0, y0, xs, ys;   /* polynomial origin and scales [px] */
    mp_prf_cache *spare;   /* the phase grid one build of a pass leaves
                        * to the next, whose grid takes its blocks when
                        * of the same size (psf/star_model.c): set by
                        * mp_epsf_pass for its builds; NULL (the
                        * default): none */
    int frame_nb;      /* the stars' neighbours as a fit of the frame with
                        * the table the pass starts from placed them (a
                        * pass on the residual: set by mp_epsf_pass), so
                        * held in the stars' last fit as well; 0 (the
                        * default): fitted again there */
    int first_pass;    /* a pass on the residual follows (the pipeline's
                        * first pass): the stars' last fit, which here
                        * only the order test reads, holds their
                        * neighbours as the build's rounds left them (that
                        * test's permuted null takes a neighbour's misfit,
                        * the same wherever the star lies), as frame_nb;
                        * 0 (the default): fitted with each star there */
} mp_epsf_opts;

/* mp_epsf_opts_default: os auto, psfrad 4·fwhm, fitrad 2·fwhm, order auto,
 * alpha 1e-3, maxnpsf 100, 5 outer × up to 30 SIRT steps; origin and
 * scales from nx, ny (the frame's centre and half-sizes, as PSFEx). */
void mp_epsf_opts_default(double fwhm, long nx, long ny, mp_epsf_opts *o);

/* Bins of the table's noise filter (psf/denoise.c). */
#define MP_EPSF_NWBIN 40

/* The built PSF: nterms planes of nx × ny elements, term-major. */
typedef struct {
    int order, nterms, nx, ny, os;
    double x0, y0, xs, ys;
    double *planes;
    double sum;          /* fraction of a star's light the table holds (PSFSUM) */
    int nstar;           /* stars used */
    char why[256];       /* why this order (PSFORDWH) */
    char osw[160];       /* why this OVERSAMP */
    double sum_err;      /* error of sum (0: not measured) */
    int ngrowth;         /* stars the sum was measured on */
    double wiener[MP_EPSF_NWBIN];   /* the noise filter per 0.05 cycles/px
                          * (S/(S+N), measured in the first pass) */
    int have_wiener;
    int filtered;        /* the filter applied since the last build's SIRT */
    long fits, fits_grid;   /* star fits of the builds so far, and of them
                          * from the phase grid (star_model.c) */
} mp_epsf;

void mp_epsf_free(mp_epsf *e);

/* mp_epsf_copy: *c = e with planes of its own.  Nonzero when out of memory. */
int mp_epsf_copy(const mp_epsf *e, mp_epsf *c);

/* mp_epsf_terms: the polynomial terms of the order at (x, y). */
void mp_epsf_terms(const mp_epsf *e, double x, double y, double *terms);

/* mp_epsf_table: the table at (x, y) into p (allocated here, MP_PSF_TABLE,
 * sum = its sum). */
int mp_epsf_table(const mp_epsf *e, double x, double y, mp_psf *p, char *err);

/* ---- Star selection (psf/select.c; DAOPHOT pstselect) --------------------- */

/* mp_epsf_select: rows of a find table (X_IMAGE, Y_IMAGE, FLUX, FLUX_MAX,
 * BACKGROUND, SHARPNESS, ROUNDNESS, FLAGS) fit to be PSF stars: FLAGS 0;
 * no masked or saturated pixel within psfrad; whole fitting region inside
 * the frame; sharpness and roundness within 3 robust σ of the bright
 * stars'; no brighter detection within fitrad; S/N ≥ 20 by the find flux;
 * then the brightest, in turn from each cell of a grid over the frame, so
 * that they spread over it, up to maxnpsf.  idx receives the rows (at
 * most maxnpsf), *n their number (0 is not an error here). */
int mp_epsf_select(const mp_frame *f, const mp_table *found, const mp_epsf_opts *o,
                   size_t *idx, size_t *n, char *err);

/* ---- The stars' FWHM (psf/star_fwhm.c) ------------------------------------ */

/* The FWHM of a frame's stars, measured (mp_epsf_stars_fwhm). */
typedef struct {
    double fwhm;       /* the half-sample mode over the stars measured [px] */
    double err;        /* its error, by bootstrap (∞ for one star) */
    int n;             /* stars measured (0: none; fwhm and err are then 0) */
} mp_stars_fwhm;

/* mp_epsf_stars_fwhm: the FWHM of the Gaussian (pixel-integrated, as
 * psf=gauss's) that fits each of up to nmax of the brightest detections
 * of t (X_IMAGE, Y_IMAGE, FLUX, BACKGROUND; FLAGS 0 when present) that
 * are lone (no detection of a tenth of their flux within the window),
 * clear of masked pixels and the frame's edge; each fitted alone with a
 * flat sky on a window of twice its half-maximum width read off the
 * pixels, so that the measure does not depend on any FWHM given.  Of
 * the first 400 detections by flux; out->n = 0 when none qualifies (not
 * an error).  Nonzero with err: t lacks a column, out of memory. */
int mp_epsf_stars_fwhm(const mp_frame *f, const mp_table *t, int nmax, mp_stars_fwhm *out,
                       char *err);

/* Stars measured at least for a verdict on the model's width. */
#define MP_EPSF_FWHM_NEED 3

/* mp_epsf_stars_fwhm_found: mp_epsf_stars_fwhm on t, find's detections
 * with options fo on f (b: its sky and noise maps); with fewer than
 * MP_EPSF_FWHM_NEED stars measured (a kernel far wider than the stars
 * blends them: fwhm=20 on stars of FWHM 3, 2 lone detections; fwhm=200,
 * none), find looks again with a kernel a quarter as wide, down to 1 px,
 * its shape cuts open, for the measure alone.  Errors: find's, t's
 * columns, out of memory. */
int mp_epsf_stars_fwhm_found(const mp_frame *f, const mp_bkg *b, const mp_find_opts *fo,
                             const mp_table *t, int nmax, mp_stars_fwhm *m, char *err);

/* Stars measured at most for their FWHM (the pipeline, fit, psf). */
#define MP_EPSF_FWHM_STARS 25

/* mp_epsf_fwhm_off: whether m measured at least MP_EPSF_FWHM_NEED stars
 * and fwhm lies more than 3 σ of the measure off their FWHM. */
int mp_epsf_fwhm_off(const mp_stars_fwhm *m, double fwhm);

/* mp_epsf_stars_fwhm_kernel: mp_epsf_stars_fwhm on find's detections on
 * f (b: its sky and noise maps) with fo's options but a kernel of FWHM
 * kernel and the shape cuts open (a kernel far off the stars' would cut
 * them).  Errors: find's, out of memory. */
int mp_epsf_stars_fwhm_kernel(const mp_frame *f, const mp_bkg *b, const mp_find_opts *fo,
                              double kernel, int nmax, mp_stars_fwhm *m, char *err);

/* mp_epsf_frame_fwhm: the stars' FWHM of f measured with no FWHM given
 * (fwhm=INDEF: pipeline, psf): mp_epsf_stars_fwhm_kernel with kernels of
 * FWHM 3, 12 and 48 px in turn until MP_EPSF_FWHM_NEED stars are
 * measured (a narrow kernel breaks a wide star's top into peaks no test
 * calls lone).  With fewer (m->n) err names fwhm and image: nonzero.
 * Errors: find's, out of memory. */
int mp_epsf_frame_fwhm(const mp_frame *f, const mp_bkg *b, const mp_find_opts *fo,
                       const char *image, mp_stars_fwhm *m, char *err);

/* mp_epsf_model_is_gauss: whether model is an analytic Gaussian that does
 * not vary (psf=gauss, or the start of a build): its width is fwhm. */
int mp_epsf_model_is_gauss(const mp_prf_model *model);

/* mp_epsf_model_verdict: model against the stars' width m measured on f
 * (psf/model_check.c says why), its figures added to why (nwhy bytes).
 * The Gaussian of fwhm (mp_epsf_model_is_gauss): 2 with err naming fwhm
 * when it is more than 3 σ of the measure off the stars and its flux bias
 * on them exceeds the median detection's flux error (t's FLUX,
 * BACKGROUND).  A table: 2 with err naming oversamp when its own star
 * (mp_epsf_model_fwhm at the frame's centre, read at its OVERSAMP) is
 * more than 3 σ off and nearer in log to twice or half their width than
 * to it; 1 with err when it cannot be measured.  0 otherwise, and when m
 * measured too few stars. */
int mp_epsf_model_verdict(const mp_frame *f, const mp_table *t, const mp_prf_model *model,
                          const mp_stars_fwhm *m, char *why, size_t nwhy, char *err);

/* mp_epsf_model_fwhm: the FWHM of the Gaussian that fits a noiseless star
 * of model m at frame position (x, y), measured as mp_epsf_stars_fwhm
 * measures a star (the mean over four subpixel phases), so that the two
 * compare: a table read at the wrong OVERSAMP is that many times too wide
 * or narrow.  Errors: no render, no core within 60 px, out of memory. */
int mp_epsf_model_fwhm(const mp_prf_model *m, double x, double y, double *fwhm, char *err);

/* ---- Cut-outs (psf/cutout.c) ---------------------------------------------- */

/* mp_epsf_cutouts: a star per (x[k], y[k], flux[k], sky[k]), its cut-out
 * of img (nx*ny electrons as f's pixels: the frame, or data less every
 * fitted star) reaching psfrad + 2 px around it, with f's mask and
 * detector numbers.  Errors: a star whose centre is off the frame (named
 * by its position), out of memory. */
int mp_epsf_cutouts(const mp_frame *f, const float *img, const double *x, const double *y,
                    const double *flux, const double *sky, size_t n, double psfrad,
                    mp_epsf_star **stars, char *err);

/* mp_epsf_cutout_add: add flux·PRF of model m at frame position (x, y)
 * to the star's cut-out (a star taken out of a residual put back). */
int mp_epsf_cutout_add(mp_epsf_star *s, const mp_prf_model *m, double x, double y, double flux,
                       char *err);

/* mp_epsf_neighbours: each star's neighbours, the rows of t (XPSF_IMAGE,
 * YPSF_IMAGE, FLUX_PSF when present, else find's X_IMAGE, Y_IMAGE, FLUX)
 * more than 1 px from where the star was found and within psfrad and its
 * sky annulus (MP_EPSF_ANNULUS), at least MP_EPSF_NBMIN of the star's flux
 * (its own row's, within 1 px, else its start flux), the MP_EPSF_MAXNB
 * brightest; with m
 * (the cut-outs are of a residual) each is first put back with model m.
 * They are then fitted with their star at every fit of the build, with
 * the current table, so that their light (and the old table's error in
 * it) leaves neither the table nor the star's sky.  Nonzero only on out
 * of memory. */
int mp_epsf_neighbours(mp_epsf_star *s, size_t n, const mp_table *t, const mp_prf_model *m,
                       double psfrad, char *err);

/* mp_epsf_clean: f = raw less the neighbours' models drawn with table
 * tab (for the star at s->x, s->y; a neighbour from grid, tab's phase
 * grid when not NULL, where its bias bound for the neighbour's own flux
 * is at most MP_EPSF_GRID_FRAC of its σ), and the star's sky again from
 * the annulus of that; nothing without neighbours.  Nonzero on out of
 * memory. */
int mp_epsf_clean(mp_epsf_star *s, const mp_psf *tab, const mp_prf_cache *grid, double psfrad);

void mp_epsf_stars_free(mp_epsf_star *s, size_t n);

/* ---- The build (psf/epsf_build.c) ----------------------------------------- */

/* mp_epsf_build: build the table of order o->order (0..MP_PSF_MAXORDER) at OVERSAMP os
 * (1..4) from the stars, starting from e when e->planes is set (its order
 * may be lower: the missing terms start at 0), else from a Gaussian of
 * o->fwhm.  Every star not skipped takes part afresh (one rejected by a
 * lower order may well fit a higher one); stars' fits are updated, and
 * those whose fit fails, strays or stands out in χ² are marked unused.  e->sum stays 1 (mp_epsf_growth sets it).
 * Errors: fewer usable stars than 2·nterms + 1, out of memory. */
int mp_epsf_build(mp_epsf_star *s, size_t n, const mp_epsf_opts *o, int os, int order,
                  mp_epsf *e, char *err);

/* PSF stars per polynomial term that varorder=auto needs before it raises
 * the order: a table of nt terms fitted over N stars has at a star's place
 * a variance nt/N (the mean leverage) times that of the stars' mean, so it
 * adds about nt/N of a like star's own variance to that star's fit; 10
 * keeps it within 10 % (5 % in σ, a third of issue 11's 15 %): order 1
 * needs 30 stars, order 2 60, order 3 100. */
#define MP_EPSF_PER_TERM 10

/* Permutations of the stars' positions behind the order test's second
 * null (psf/varorder.c). */
#define MP_EPSF_NPERM 99

/* mp_epsf_order_test: is order+1 demanded by the data?  The stars'
 * normalised residuals (d − model)/σ per pixel offset are regressed on the
 * next order's new terms of position; the F statistics of the pixels are
 * summed and compared with their null distribution if the pixels were
 * independent (normal approximation): *stat the standardised sum.  When
 * that rejects at alpha, the sum is compared again with its distribution
 * over MP_EPSF_NPERM permutations of the stars' positions (a star's misfit
 * is coherent over its pixels), *zperm its normal deviate there (NaN when
 * not run), and *p is the larger of the two p-values.  Nonzero only on out
 * of memory; *p = 1 when too few stars to test (fewer than 3 × the terms
 * + 5).  zperm may be NULL. */
int mp_epsf_order_test(const mp_epsf_star *s, size_t n, const mp_epsf *e, double fitrad,
                       double alpha, double *p, double *stat, double *zperm, char *err);

/* mp_epsf_order_test_to: the same for the terms of every degree above
 * e's up to order `to` at once (e->order < to ≤ MP_PSF_MAXORDER; *p = 1
 * otherwise).  to = e->order + 2 sees a variation with no terms of degree
 * e->order + 1: a focus that changes as the square of the distance from
 * the frame's centre, symmetric about it, has no linear term. */
int mp_epsf_order_test_to(const mp_epsf_star *s, size_t n, const mp_epsf *e, int to,
                          double fitrad, double alpha, double *p, double *stat, double *zperm,
                          char *err);

/* mp_epsf_oversamp_error: the largest over ¼-px phases of
 * E·sqrt(Σ δP²/(E·P + B + ron²)) with δP the difference between the PRF
 * of table e (at the origin) block-summed to OVERSAMP os_coarse and the
 * PRF of e itself: the coarser table's bias in units of the noise for a
 * star of E electrons on sky B. */
double mp_epsf_oversamp_error(const mp_epsf *e, int os_coarse, double E, double B, double ron);

/* mp_epsf_rebin: e block-summed to OVERSAMP e->os/factor (planes re-sampled
 * so the star stays at the centre of the central element). */
int mp_epsf_rebin(const mp_epsf *e, int factor, mp_epsf *out, char *err);

/* ---- Total flux (psf/growth.c) -------------------------------------------- */

/* mp_epsf_growth: the fraction of a star's light inside the table, by the
 * light beyond it on the brightest used stars (DAOPHOT's aperture
 * correction): each star's flux F fitted with the table (of sum 1)
 * against F + L, L the light its model leaves out between rin − 1.5 px
 * (the table's edge, which pixels only partly cover, rin its radius) and
 * rbig on img.  The stars' images of img less their models, interpolated
 * to their own centres, less their sky (the median of rbig..rbig+4 px),
 * per unit flux, are stacked: the median over the (up to 10) stars per
 * offset, robust to the neighbours and faint stars a crowded ring holds;
 * then summed over the annulus ring by ring as each ring's mean over
 * azimuth, so narrow features (diffraction spikes) count with their
 * light, which a ring's median drops.  img is the frame, or with fitted
 * and m given, data less every star of fitted (then the star's own rows,
 * within 1 px of where it was found, are put back with m, as they were
 * taken).  e->sum is set to 1/(1 + L/F) when that is below 1 by more
 * than 3 times its error, else 1; e->sum_err its error (the larger of
 * the per-offset medians' errors summed and the stars' own sums'
 * scatter).  Nonzero only on out of memory (fewer than 3 measurable
 * stars: sum 1). */
int mp_epsf_growth(const mp_frame *f, const float *img, const mp_table *fitted,
                   const mp_prf_model *m, const mp_epsf_star *s, size_t n, double rin,
                   double rbig, mp_epsf *e, char *err);

/* mp_epsf_growth_rin: the table's radius as mp_epsf_growth's rin: its
 * support when shorter than psfrad (the light between them is left out
 * of the table and must be counted), else psfrad. */
double mp_epsf_growth_rin(const mp_epsf_opts *o);

/* ---- The table's radius (psf/tablerad.c) -------------------------------- */

/* A ring's light is "measured" when its 0.9 quantile over azimuth, less
 * what noise alone gives that quantile, is this many of that quantile's
 * sampling errors for noise alone (one-sided false rate 1.3e-4 a ring). */
#define MP_EPSF_RADZ 3.65

/* Past the last measured ring, the next rings are kept while their light
 * is at least its own error (z ≥ MP_EPSF_RADKEEP) and reaches the level.
 * Why: a ring dropped leaves its light μ out of every star's model (a
 * bias μ², coherent over the ring: the brightest stars' cut rings and
 * spikes were fitted as stars), a ring kept puts the stack's noise σ² in
 * (incoherent); keeping lowers the expected squared error when μ > σ,
 * whose plug-in is z ≥ 1.  On validate/CROWDED.md's segmented scene the
 * rings past the measured ones read z 2.0 (ring 18, then −0.9), and on
 * its second draw 2.9, 1.4, 1.5 (rings 19–21, then −1.5); cut at ring 18,
 * the first draw's table left out ~2·10⁻⁶ of the flux a pixel there, ~1 σ
 * of a sky pixel around its saturated stars.  A ring of noise alone is
 * kept with probability 0.16. */
#define MP_EPSF_RADKEEP 1.0

/* How the table radius is measured (mp_epsf_tablerad). */
typedef struct {
    double frac;       /* the brightest star's light per pixel above frac·σ of a
                        * sky pixel (the economy's cropfrac, 0.02) */
    double fwhm;       /* [px] the PSF stars' flux: their light within 2 fwhm */
    double rmin, rmax; /* [px] floor, and cap (the frame's and the build's budget) */
    double rdefault;   /* [px] when it cannot be measured (fewer than 3 PSF stars) */
} mp_epsf_radopts;

/* What it measured. */
typedef struct {
    double rad;        /* the table radius [px] */
    double reach;      /* the radius measured, before rmin..rmax (0: none) */
    double fmax;       /* the brightest star's flux in the stacks' unit [e-] */
    double level;      /* frac·σ of a sky pixel [e-] */
    int npsf, nbright; /* stars in the two stacks */
    char why[400];     /* one line for the run report */
} mp_epsf_rad;

/* What a ring of noise alone gives the ring test (mp_epsf_profile_hi), in
 * units of its median error s: its 0.9 quantile at kq·s on average, with
 * sampling error s·√(kz²/m + k0²) for m values (k0: an error every value
 * of the ring shares); s taken no lower than sfloor.  Normal theory, for
 * a stack of many stars (s the medians' sd): MP_EPSF_RING_NORMAL, the 0.9
 * quantile of m normal values of sd σ at 1.2816 σ with sampling error
 * √(0.09)/φ(1.2816) σ/√m = 1.709 σ/√m.  A stack of few stars measures its
 * own (psf/tablerad.c small_stack_null). */
typedef struct {
    double kq, kz, k0, sfloor;
} mp_epsf_ringnull;
#define MP_EPSF_RING_NORMAL ((mp_epsf_ringnull){1.2816, 1.709, 0.0, 0.0})

/* mp_epsf_profile_hi: the high-quantile profile of a stacked star image
 * (med, sig: (2hw+1)² values per unit flux and their errors, NaN where
 * unmeasured) on 1-px rings r = 0..hw (distance of the offset in [r, r+1)):
 * q[r] the ring's 0.9 quantile over azimuth less what noise alone gives
 * that quantile (nz), so a spike that fills a tenth of the ring counts at
 * its own height where a median or a mean would dilute it; z[r] = q[r]
 * over that quantile's sampling error for noise alone (nz).  NaN for
 * rings with fewer than 8 values.  Nonzero on out of memory. */
int mp_epsf_profile_hi(const double *med, const double *sig, int hw, const mp_epsf_ringnull *nz,
                       double *q, double *z);

/* mp_epsf_radius_rule: 1 + the largest ring r < nr whose light is
 * measured (z[r] ≥ MP_EPSF_RADZ) and, for a star of flux fmax, reaches
 * level per pixel (fmax·q[r] ≥ level), taken on over the rings after it
 * that reach the level at z ≥ MP_EPSF_RADKEEP; 0 when none. */
double mp_epsf_radius_rule(const double *q, const double *z, int nr, double fmax, double level);

/* mp_epsf_tablerad: the table radius a frame needs (pipeline tablerad=INDEF):
 * the PSF stars (x, y: unsaturated, alone) stacked on img, each as its
 * light per unit flux (its flux the light within 2 fwhm, its sky the
 * median of the ring rmax..rmax+4 px), the median over stars per pixel
 * offset (a neighbour or a faint star is in one star's image, a spike or
 * a ring in all); then mp_epsf_radius_rule on the stack's high-quantile
 * profile with fmax the brightest star's flux — the PSF stars', or a
 * bright star's (bx, by: saturated, their cores clipped) from its wings,
 * the median over its first usable rings of its ring median over the
 * stack's — and level frac·σ of the median sky pixel; within
 * rmin..rmax.  Light a bright star shows beyond the table is fitted as
 * stars (validate/CROWDED.md's segmented scene: 1130 false entries with
 * ±12 px).  Fewer than 3 usable PSF stars: rdefault.  Nonzero only on out
 * of memory. */
int mp_epsf_tablerad(const mp_frame *f, const float *img, const double *x, const double *y,
                     size_t n, const double *bx, const double *by, size_t nb,
                     const mp_epsf_radopts *o, mp_epsf_rad *out, char *err);

/* ---- From a frame (psf/frame_build.c): what `matphot psf` and the
 * pipeline run ---------------------------------------------------------- */

/* What a build decided, for the run report. */
typedef struct {
    size_t nsel, nused;      /* PSF stars given or selected, and used */
    double oserr[5];         /* oversamp_error of OVERSAMP 1..4 (index) for the
                              * brightest star (0 where not measured) */
    double chi2;             /* median reduced χ² of the PSF stars' fits */
    double ptest[MP_PSF_MAXORDER + 1];   /* order test p-values k→k+1 (index k;
                              * NaN: not run) */
    double ztest[MP_PSF_MAXORDER + 1];   /* their standardised statistics */
    double zperm[MP_PSF_MAXORDER + 1];   /* against the permuted null (NaN: not run) */
    double ptest2[MP_PSF_MAXORDER + 1];  /* the test k→k+2 (index k) where k→k+1
                              * kept order k; NaN: not run */
    double ztest2[MP_PSF_MAXORDER + 1], zperm2[MP_PSF_MAXORDER + 1];
    char what[512];          /* one line: stars, OVERSAMP, order, sum, why */
} mp_epsf_report;

/* mp_epsf_pass: one pass of the build on frame f: cut-outs of the n stars
 * (x, y, start flux: NaN for "measure it") from img — the frame's pixels
 * (residual 0), or data less every fitted star of `fitted` (residual 1: each
 * PSF star's own fitted light, the rows of `fitted` within 1 px, put back
 * with model m); the rows of `fitted` (may be NULL; with residual 0 a
 * find table will do) around each star its neighbours, fitted with it
 * (mp_epsf_neighbours) — then the table: at o->os, or with o->os 0 built at ×4 and
 * taken to the coarsest OVERSAMP whose aliasing error for the brightest
 * star is below 1 σ of its noise; of order o->order, or with −1 from e's
 * order (0 when e is empty) raised while mp_epsf_order_test rejects the
 * lower order at o->alpha (with o->raise and e built: of order e->order + 1
 * from e as it is); then PSFSUM by the growth curve out to
 * 2·psfrad.  e may hold the previous pass's table (its OVERSAMP and order
 * are kept as the start).  Errors: no usable PSF star, a star off the
 * frame, out of memory. */
int mp_epsf_pass(const mp_frame *f, const float *img, int residual, const mp_table *fitted,
                 const mp_prf_model *m, const double *x, const double *y, const double *flux,
                 size_t n, const mp_epsf_opts *o, mp_epsf *e, mp_epsf_report *rep,
                 mp_psf_star **stars, char *err);

/* mp_epsf_field: e as the PSF file's field (planes scaled to e->sum, why,
 * nstar) for mp_psf_field_write and the fit. */
int mp_epsf_field(const mp_epsf *e, mp_psf_field *fld, char *err);

/* mp_epsf_model: the fit's model of field fld: *tab its table at the
 * origin, pointing at fld when the order is above 0. */
int mp_epsf_model(const mp_psf_field *fld, mp_psf *tab, mp_prf_model *m, char *err);

/* The `matphot psf` task (params/psf.par). */
int mp_task_psf(int argc, char **argv);

/* mp_epsf_median: the median of v[0..n), the mean of the middle two for
 * even n; sorts v in place (callers read quantiles off it after).  NaN
 * when n = 0.  The builder's, and the pipeline's models of the light the
 * table leaves out (pipeline/halo.c, lookup.c).  Where nothing reads v
 * after, io.h's mp_median_select gives the same value without sorting
 * (the build's hot loops: each PSF star's sky annulus, every table
 * element's combination). */
double mp_epsf_median(double *v, size_t n);

#endif
