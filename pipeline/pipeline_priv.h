/*
 * pipeline_priv.h — private to pipeline/: the bookkeeping between rounds
 * (new_stars.c) and the files a run writes (outputs.c).
 */
#ifndef MATPHOT_PIPELINE_PRIV_H
#define MATPHOT_PIPELINE_PRIV_H

#include "pipeline/pipeline.h"

/* ---- task_pipeline.c --------------------------------------------------- */

/* mp_pl_opts_read: the pipeline's options from its parameters (pipeline.par
 * names; `matphot fakes` has them all too).  Nonzero with err set on a bad
 * value; o->fit is then to be freed with mp_fit_setup_free all the same. */
int mp_pl_opts_read(mp_parset *ps, mp_pipeline_opts *o, char *err);

/* ---- sharp_limits.c ---------------------------------------------------- */

/* mp_pl_sharp_limits: o's sharpness limits, set by the user for stars of
 * the kernel's Gaussian (whose SHARPNESS over subpixel phases spans
 * [g0, g1]), widened so that stars of m (spanning [p0, p1]; over the
 * frame's centre and quarter points when m's PSF varies, nx × ny the
 * frame) keep the same margins: sharplo = min(sharplo, p0 − (g0 −
 * sharplo)), sharphi = max(sharphi, p1 + (sharphi − g1)).  A limit that is
 * NaN, or does not bracket the Gaussian's range, is kept.  why: one line
 * for the report.  A PSF or kernel whose sharpness find cannot measure (no
 * positive height, a bad kernel) keeps the limits as given, and why says
 * so: the run goes on.  Errors: out of memory. */
int mp_pl_sharp_limits(const mp_prf_model *m, long nx, long ny, mp_find_opts *o, char *why,
                       size_t nwhy, char *err);

/* ---- fwhm_check.c ------------------------------------------------------ */

/* mp_pl_stars_why: the report's words for the stars' FWHM measured (m). */
void mp_pl_stars_why(const mp_stars_fwhm *m, char *why, size_t nwhy);

/* mp_pl_frame_fwhm: the FWHM of image's stars (fwhm=INDEF): the frame
 * read with o's datapars, its sky and noise maps as o's, and the stars
 * measured (mp_epsf_stars_fwhm) on find's detections with a kernel of
 * FWHM 3, else 12, else 48 px, shape cuts open, until MP_EPSF_FWHM_NEED
 * are measured.  Errors: the frame's, too few stars (naming fwhm), out of
 * memory. */
int mp_pl_frame_fwhm(const char *image, const mp_pipeline_opts *o, mp_stars_fwhm *m, char *err);

/* ---- bright_stars.c ---------------------------------------------------- */

/* A fitted star: position, flux (e-), FLAGS and sky (SKY_PSF; NaN: none). */
typedef struct {
    double x, y, e;
    long flags;
    double sky;
} mp_pl_star;

/* mp_pl_stars_by_flux: the rows of t with a finite XPSF/YPSF_IMAGE, a
 * positive FLUX_PSF and none of skipflags in FLAGS, brightest first; *n
 * of them.  NULL when out of memory (*n = 0); the caller frees. */
mp_pl_star *mp_pl_stars_by_flux(const mp_table *t, long skipflags, size_t *n);

/* mp_pl_star_excess: b's noise model (mp_bkg_noise_from_model) given the
 * error that grows as a star's flux squared around t's stars
 * (mp_bkg_star_excess: measured on the MP_BKG_EXCESS_NSTAR brightest of
 * the stars fitted whole and of those fitted without saturated pixels,
 * out to the reach of m's table).  *nring, *nkept: its rings and stars.
 * Nonzero with err when out of memory. */
int mp_pl_star_excess(const mp_frame *f, mp_bkg *b, const mp_table *t, const mp_prf_model *m,
                      int *nring, size_t *nkept, char *err);

/* mp_pl_group: t grouped as mp_group_table does with go; with couplefrac
 * > 0 a component of more than go->maxgroup stars is cut at its weakest
 * couplings instead of its median (pipeline/coupled.c: κ of model m at each
 * pair's FLUX_PSF, else FLUX, on the median SKY_PSF, else BACKGROUND, with
 * read noise ron [e-]), its stars whose link of κ ≥ couplefrac was cut
 * flagged 2.  With budget > 0 (groupcut=budget) every component is
 * re-formed so, its links joined only as mp_group_budget needs.  *tested,
 * *linked: the pairs within the critical separation in such components,
 * and of them those of κ ≥ couplefrac.  kept (may be NULL): the κ table
 * of an earlier call with m, kept for the next (it holds for any sky:
 * fit.h, mp_coupling_build; its owner frees it when m changes).  Nonzero
 * with err as mp_group_table, or when out of memory. */
int mp_pl_group(mp_table *t, const mp_group_opts *go, const mp_prf_model *m, double couplefrac,
                double budget, double ron, mp_coupling *kept, long *tested, long *linked,
                char *err);

/* mp_pl_group_decision: mp_pl_group's rule (budget as its; weakgroup,
 * go->weakgroup's cap on weak links, 0: none) added to fs's economy
 * decisions (none with couplefrac 0). */
void mp_pl_group_decision(mp_fit_setup *fs, double budget, int weakgroup);

/* mp_pl_median_positive: the (upper) median of column name over t's rows
 * where it is finite and > 0; 0 when there is none, no such column or no
 * memory. */
double mp_pl_median_positive(const mp_table *t, const char *name);

/* mp_pl_median_sky: the median fitted sky (SKY_PSF) of t's stars with a
 * finite one; 0 when there is none (or no memory to sort them). */
double mp_pl_median_sky(const mp_table *t);

/* ---- cosmics.c --------------------------------------------------------- */

/* A PRF pixel enters the sharpness bound s when it holds at least this
 * fraction of its star's peak pixel; the fainter ones are D's.  Any split
 * keeps the test valid: it trades s (the test's reach) against D (the
 * allowance near bright stars).  47 Tuc's built table: s 2.18, D 1.5e-4. */
#define MP_PL_CR_CORE 0.02
/* Pixels a frame that noise alone flags (mp_pl_cr_sigma). */
#define MP_PL_CR_RATE 0.01

/* mp_pl_cr_bound: the PSF's sharpness (cosmics.c): *s, the least ratio of
 * a PRF pixel's four side neighbours to the pixel, over the pixels holding
 * at least MP_PL_CR_CORE of the peak, 5 × 5 phases (a pixel's centre,
 * edges, corners and between) and, for a variable PSF, 3 × 3 places of an
 * nx × ny frame, less half its largest step between neighbouring phases;
 * *D, the most by which any PRF pixel's s·P exceeds its neighbours' sum
 * (zero beyond the box), per electron.  Nonzero with err when out of
 * memory. */
int mp_pl_cr_bound(const mp_prf_model *m, long nx, long ny, double *s, double *D, char *err);

/* mp_pl_cr_sigma: k with npix · Q(k) = rate (Q the normal upper tail): the
 * threshold at which noise alone passes rate of npix pixels. */
double mp_pl_cr_sigma(double npix, double rate);

/* The test's constants: s and D (mp_pl_cr_bound), k [σ], the growth
 * around each pixel flagged (a square of side 2 grow + 1), and the side of
 * the box the sky under a pixel is taken from [px]. */
typedef struct {
    double s, D, k;
    int grow, side;
    const size_t *guard;     /* stars of the mp_pl_cr_stars whose pixels within
                              * MP_PL_CR_GUARD are not tested (NULL: none) */
    size_t nguard;
} mp_pl_cr_test;

/* The fitted stars (mp_pl_stars_by_flux: brightest first), whose light
 * D bounds out to the reach of their table [px]. */
typedef struct {
    const mp_pl_star *s;
    size_t n;
    double reach;
} mp_pl_cr_stars;

/* mp_pl_cr_sharpness: how much sharper the frame's stars are than the
 * model m says, as a factor on s.  At the peak pixel of each of the
 * MP_PL_CR_NSHARP brightest stars of st (their sky known, the pixel's 3 × 3
 * unmasked and led by it), the side-neighbour ratio (Σ_nb d − 4 B) /
 * (d_p − B) over the model's at the same pixel, from the stars that
 * measure it within MP_PL_CR_SHARP_SIG; the factor is their median less z
 * of their robust σ, z = mp_pl_cr_sigma(st->n, MP_PL_CR_RATE), so that
 * every star of st stays above it, at most 1, at least 0.  With fewer
 * than MP_PL_CR_NMIN such stars the factor is 1 and those stars (indices
 * into st) come back in guard (room for MP_PL_CR_NSHARP), *nguard of
 * them: too few to check the model on, they are kept out of the test; the
 * fainter stars, whose ratio no star measures within 10 %, hold too little
 * light for a model's ratio too high by less than k × 10 % to pass their
 * cores.  A model broader than the stars (a table smoothed as its
 * noise needs; IRAC's undersampled stars, each sharp as its pixel phase
 * makes it) would let their cores pass as cosmic rays; a hit the first
 * round took for a star moves a median and its spread little. */
#define MP_PL_CR_NSHARP 100
#define MP_PL_CR_SHARP_SIG 0.1
#define MP_PL_CR_NMIN 10
#define MP_PL_CR_GUARD 2.0
double mp_pl_cr_sharpness(const mp_frame *f, const mp_prf_model *m, const mp_pl_cr_stars *st,
                          size_t *guard, size_t *nguard);

/* mp_pl_mask_cosmics: every pixel of f whose excess over starlight,
 * T = s·(d − B) − Σ of its four side neighbours' (d − B), exceeds
 * k σ_T + D·Φ (Φ the flux of st's stars within reach; st may be NULL),
 * with B the sky from below (the 10th percentile of the unmasked pixels in
 * the box of side ct->side around it, at most b's sky there and the least
 * pixel of its 3 × 3), itself and its eight neighbours unmasked and on the
 * frame: masked bad with the pixels within grow of it (unless masked
 * already) and set NaN in res (may be NULL).  σ_T from max(d, 0) + RON² +
 * xvar.  Returns the pixels masked, *cores those flagged; -1 when out of
 * memory. */
long mp_pl_mask_cosmics(mp_frame *f, const mp_bkg *b, float *res, const mp_pl_cr_stars *st,
                        const mp_pl_cr_test *ct, long *cores);

/* ---- heldout.c --------------------------------------------------------- */

/* The held-out stars' least S/N: their χ² then tells a table's shape from
 * the noise (a star at S/N 20 holds 400 σ² of signal). */
#define MP_PL_HELDOUT_SNR 20.0

/* The held-out verdict that raises the order: z below −1.645, a one-sided
 * 5 % test that the next order fits them better.  Where that order fits
 * only the table's noise the stars fit it worse (z +2 to +6 on the
 * constant scenes, psfbuild_notes.md), so it raises far more rarely than
 * 5 %; a missed order costs the variable scene 10-40 % of its errors. */
#define MP_PL_HELDOUT_Z 1.645

/* The paired comparison of two tables on the held-out stars: their
 * number, the mean of log(χ²_b/χ²_a) (CHI2STAR_PSF), and the mean over its
 * standard error. */
typedef struct {
    size_t n;
    double mean, z;
} mp_pl_heldout;

/* mp_pl_heldout_rows: sel[r] = 1 for t's held-out stars — FLAGS 0, S/N
 * FLUX_PSF/FLUXERR_PSF ≥ MP_PL_HELDOUT_SNR, farther than 1 px from every
 * PSF star (px, py)[0..np) — the brightest max of them; their number, −1
 * when out of memory. */
long mp_pl_heldout_rows(const mp_table *t, const double *px, const double *py, size_t np,
                        size_t max, unsigned char *sel);

/* mp_pl_rows_of: out (initialised here) = the rows r of t with !!sel[r]
 * == want, every column (sel NULL: all rows).  Nonzero when out of memory. */
int mp_pl_rows_of(const mp_table *t, const unsigned char *sel, int want, mp_table *out);

/* mp_pl_heldout_fit: out (initialised here) = the rows of held grouped
 * among themselves (go) and fitted on f as `fit psf=PSF` with the options
 * of ps would fit them (ps's psf is set and put back to "").  Nonzero with
 * err on failure. */
int mp_pl_heldout_fit(const mp_frame *f, const mp_table *held, mp_parset *ps, const char *psf,
                      const mp_group_opts *go, mp_table *out, char *err);

/* mp_pl_heldout_compare: *h of the stars (by NUMBER) fitted in both a and
 * b.  Nonzero when out of memory. */
int mp_pl_heldout_compare(const mp_table *a, const mp_table *b, mp_pl_heldout *h);

/* ---- halo.c ------------------------------------------------------------ */

/* mp_pl_halo: the light of bright stars beyond what the PSF table holds
 * (halo=yes).  From res (f's data less every star of t, sky kept) around
 * t's 10 brightest stars (XPSF_IMAGE, YPSF_IMAGE, FLUX_PSF): the profile
 * h(r) per electron on 1-px rings from rin = max(fwhm, 1) to 16 rin, each
 * star's ring median less its sky (the ring beyond), fitted as E·h over the
 * stars, the nearest non-increasing profile, >= 0, flat inside rin.
 * *z: the significance of the unconstrained profile's light beyond rin
 * against its own error (each ring median's from its pixels' robust
 * scatter, and each star's sky's, common to all its rings); N(0, 1) where
 * there is no halo; where that passes MP_PL_HALO_Z, the smaller of it and
 * the light's significance against up to 99 copies of the stars shifted
 * together over the frame, read until it is decided (halo.c placebo_z:
 * the residual's lumps that stars close together share).  Only when z > MP_PL_HALO_Z (one-sided false rate
 * 1e-3) is E·h(r) of every star whose halo reaches 0.05 σ of a sky pixel
 * taken off f's pixels and res, and its Poisson variance added to f->xvar
 * (allocated when NULL); otherwise nothing changes.  what: one line for the
 * report.  *light: the light taken off a star per electron of its flux,
 * ∫ h(r) 2πr dr (0 when nothing is taken off): a PSF built afterwards
 * from f must count it in its PSFSUM, or every flux misses it.  Nonzero
 * with err when out of memory. */
#define MP_PL_HALO_Z 3.090
int mp_pl_halo(mp_frame *f, float *res, const mp_table *t, double fwhm, double *z, double *light,
               char *what, size_t wlen, char *err);

/* ---- tablerad.c -------------------------------------------------------- */

/* mp_pl_tablerad: the built table's radius for frame f (tablerad=INDEF):
 * mp_epsf_tablerad on the PSF stars (px, py; find fluxes pf) and the find
 * table t's bright stars (saturated, or brighter than every PSF star),
 * frac 0.02 (the economy's cropfrac), within po->psfrad (4 fwhm, the
 * fixed radius before) .. min(10 fwhm, an eighth of the frame's smaller
 * side); po->psfrad when it cannot be measured.  Nonzero only on out of
 * memory. */
int mp_pl_tablerad(const mp_frame *f, const mp_table *t, const double *px, const double *py,
                   const double *pf, size_t np, const mp_epsf_opts *po, mp_epsf_rad *out,
                   char *err);

/* ---- lookup.c ---------------------------------------------------------- */

/* mp_pl_lookup: what the PSF leaves around every star (lookup=yes): from
 * f's data less the light (model m, as mp_fit_residual draws it with
 * cropfrac) of t's stars no fainter than a hundredth of the stacked ones,
 * around t's 50 brightest converged unsaturated stars (XPSF_IMAGE,
 * YPSF_IMAGE, FLUX_PSF, SKY_PSF, FLAGS), each less its sky (the median just
 * outside the box), the mean residual per electron M
 * on the detector grid, ±16 fwhm, by least squares over the stars (pixels
 * spread bilinearly over the grid); elements within rin of the centre or
 * below 3 σ of their own noise are 0.  Then E·M (bilinear at each pixel's
 * offset) around every star whose largest correction reaches 0.05 σ of a
 * sky pixel is taken off f's pixels and res, its variance (E·σ_M)² added to
 * f->xvar (allocated when NULL).  what: one line for the report.  Nonzero
 * with err when out of memory. */
int mp_pl_lookup(mp_frame *f, float *res, const mp_table *t, const mp_prf_model *m,
                 double cropfrac, double fwhm, double rin, char *what, size_t wlen, char *err);

/* ---- new_stars.c ------------------------------------------------------- */

/* mp_pl_positions_of: before = NUMBER, X_IMAGE, Y_IMAGE of every row of t
 * (the fitted position where there is one).  Nonzero when out of memory. */
int mp_pl_positions_of(const mp_table *t, mp_table *before);

/* mp_pl_note_gone: append to gone the positions (from before) of the rows
 * the fit merged away or rejected (their NUMBER is in before, not in
 * after), so a residual peak they leave is not added again every round. */
int mp_pl_note_gone(mp_table *gone, const mp_table *before, const mp_table *after);

/* mp_pl_add_new_stars: append the detections of found that are not within
 * matchrad of a star of t or of gone, numbered on from t's largest NUMBER;
 * their fit starts from find's position and flux.  A detection within
 * matchrad of a star of t (not of gone) is added all the same when it lies
 * at least closerad from every star of t and its screen S/N (column
 * MP_PL_SNR_COL, prescreen.c) reaches closesnr: the one-or-two test of a
 * blend (closesnr² is the χ² a second star at that place removes).
 * Returns the number added, −1 when out of memory.  fnx, fny: the frame's
 * size. */
long mp_pl_add_new_stars(mp_table *t, const mp_table *gone, const mp_table *found, long fnx,
                         long fny, double matchrad, double closerad, double closesnr);

/* ---- prescreen.c ------------------------------------------------------- */

/* mp_pl_prescreen: deep detection's screen.  For every candidate of found
 * (X_IMAGE, Y_IMAGE), a linear fit of its flux and a constant sky on the
 * residual res (data − stars, sky kept) over the pixels within fitrad,
 * weighted by b's rms map (the fitted model's noise): X_IMAGE set NaN
 * (so mp_pl_add_new_stars skips it) when its S/N is below snrmin, else
 * FLUX set to the fitted flux (the fit's start); a saturated plateau
 * (FLAGS bit MP_FIND_SATURATED) below snrmin is kept, FLUX set NaN (the
 * fit starts from its own estimate); its S/N goes to column
 * MP_PL_SNR_COL either way.  Returns the number
 * dropped, −1 when out of memory.  Threads over candidates (OpenMP). */
long mp_pl_prescreen(const mp_frame *f, const mp_bkg *b, const float *res,
                     const mp_prf_model *m, double fitrad, double snrmin, mp_table *found);

/* The column mp_pl_prescreen writes each candidate's S/N to (not copied
 * into the star table). */
#define MP_PL_SNR_COL "SNR_SCREEN"

/* mp_pl_screen_sieve: mp_pl_prescreen as find's sieve (find.h,
 * mp_find_opts.sieve, ctx an mp_pl_screen): each candidate's S/N into snr,
 * keep = 0 when below snrmin (counted in dropped), else flux the fitted
 * flux; the kept rows are those mp_pl_prescreen leaves, with the same
 * values, but the dropped are never held (issue 14: at 2048² the
 * residual's candidates were 10 of the 70 MB heap at the peak).  Returns
 * nonzero when out of memory. */
typedef struct {
    const mp_frame *f;
    const mp_bkg *b;
    const float *res;
    const mp_prf_model *m;
    double fitrad, snrmin;
    long dropped;
    const mp_prf_cache *grid;    /* NULL: exact renders; else the candidates */
    double gemax;                /* whose fitted flux is within gemax from it */
} mp_pl_screen;
int mp_pl_screen_sieve(void *ctx, mp_find_cand *c, size_t n);

/* mp_pl_drop_unset: remove the rows whose X_IMAGE is NaN (the screen's)
 * and the screen's column MP_PL_SNR_COL. */
void mp_pl_drop_unset(mp_table *t);

/* The screen's cut below the fit's minsnr: a star at the cut reaches the
 * screen's S/N ± 1 (one parameter's σ), so 2 below it passes 97.7 % of
 * them. */
#define MP_PL_SCREEN_SLACK 2.0

/* A residual candidate's sharpness goes below sharplo only when it lies
 * this many of its own σ below (mp_find_opts.sharpsig): a star whose
 * true sharpness sits at the limit is kept with probability 0.977. */
#define MP_PL_SHARP_SIGMA 2.0

/* The LM's tol (× each parameter's σ) in the fit with the PSF's first
 * pass (round 1 when the PSF is built): what it leaves places the
 * neighbours the second pass takes off and is the next fit's start, and
 * the next fit refits every group to the run's tol, the second pass's
 * table coming with a forgotten fit memory (mp_frame_opts.loosetol);
 * its merges and rejections, which are for good, are decided as a fit
 * to the run's tol would.  A star 0.3 σ from its optimum leaves in the
 * residual a bump of S/N ≤ 0.3 at its place, a tenth of the screen's
 * cut (minsnr − MP_PL_SCREEN_SLACK = 3).  Every round another round
 * follows was loose too, measured (bench/PROFILE.md, session of
 * 2026-12-03 23:15): 47 Tuc built −7 % of the instructions, but where
 * the next round keeps most groups (the simulated frames with their
 * true table: frame B kept 2 750 of 3 116) refitting them cost more than
 * the loose fits saved (+4 to +12 %). */
#define MP_PL_ROUND_TOL 0.3

/* ---- run.c ------------------------------------------------------------- */

/* mp_pl_warn_whole_frame_only: one warning line on stderr, naming task and
 * image, when o asks for halo= or lookup=, which are measured on the whole
 * frame's residual and so are not applied where the frame is reduced in
 * pieces (tiles, artificial-star boxes). */
void mp_pl_warn_whole_frame_only(const mp_pipeline_opts *o, const char *task, const char *image,
                                 const char *where);

/* mp_pl_reduce: what mp_pipeline_run does to image, writing no file: at the
 * end done(ctx, frame, stars, residual [e-], err) gets the run's results
 * (its to modify, not to keep) and its return is the run's.  For tiles. */
typedef int (*mp_pl_done_fn)(void *ctx, const mp_frame *f, mp_table *t, float *res, char *err);
int mp_pl_reduce(const char *image, const mp_pipeline_opts *o, mp_pipeline_report *rep,
                 mp_pl_done_fn done, void *ctx, char *err);

/* mp_pl_psf_on: the PSF of a frame built as mp_pipeline_run builds it
 * (find, pass 1, fit, pass 2 with the neighbours subtracted) on section,
 * a part of the frame whose pixel (1, 1) is frame pixel (1 + offx,
 * 1 + offy), the frame being fnx x fny: root.psf.fits is written in frame
 * coordinates (its polynomial's origin and scales the frame's, as a whole
 * run writes them).  *built = 0 (no file) when the section has no star
 * fit to shape a PSF.  For tiles. */
int mp_pl_psf_on(const char *section, const char *root, const mp_pipeline_opts *o, long offx,
                 long offy, long fnx, long fny, int *built, char *err);

/* ---- split.c ------------------------------------------------------------ */

/* mp_pl_split_candidates: one star or two.  For every star of t (fitted:
 * XPSF_IMAGE, YPSF_IMAGE, FLUX_PSF, FLUXERR_PSF) of S/N ≥ √2·snrmin and
 * its fitting region inside the frame, the score test of a second star at
 * 3 rings × 12 places between rmin and rmax [px] from it, on the residual
 * res weighted by b's rms map over the pixels within fitrad: the place
 * whose Δχ² (after the first star and the sky readjust) is largest is
 * appended to found (X_IMAGE, Y_IMAGE, FLUX, MP_PL_SNR_COL = √Δχ²) when
 * Δχ² ≥ snrmin².  The PRFs of a star whose FLUX_PSF is at most gemax
 * are drawn from the phase grid (may be NULL: exact renders), as its
 * group's fit draws them (mp_frame_opts.grid); the trial stars' from it
 * too, bilinearly while the best one's flux is within glemax (0: never),
 * the bilinear interpolation's limit.  Returns the number appended, −1
 * when out of memory.  Threads over stars (OpenMP). */
/* The least √Δχ² at which a second star is proposed, whatever minsnr:
 * χ²(1) > 25 has probability 6e-7 at one place. */
#define MP_PL_SPLIT_MINSNR 5.0

long mp_pl_split_candidates(const mp_frame *f, const mp_bkg *b, const float *res,
                            const mp_prf_model *m, const mp_prf_cache *grid, double gemax,
                            double glemax, const mp_table *t, double fitrad, double rmin,
                            double rmax, double snrmin, mp_table *found);

/* ---- outputs.c --------------------------------------------------------- */

/* mp_pl_products: the files a run writes, root + each; the last,
 * .psf.fits, only when it builds the PSF (psf=root.psf.fits of an
 * earlier run is read, not written).  What a run checks against its
 * inputs before it starts and removes when it fails. */
#define MP_PL_NPRODUCT 8
extern const char *const mp_pl_products[MP_PL_NPRODUCT];

/* mp_pl_outputs_clear: 1 with err when one of root + ext[k] (k < next)
 * is one of the run's input files in (io.h mp_out_overwrites):
 * `pipeline f.res.fits root=f` would write its residual over its frame. */
int mp_pl_outputs_clear(const char *root, const char *const *ext, size_t next,
                        const mp_inputs *in, char *err);

/* mp_pl_write_named: t written atomically to root + ext in format fmt;
 * the rows prev holds the same copied, t's rows kept into *keep when keep
 * is set (mp_table_write_kept; NULL, NULL: plain). */
int mp_pl_write_named(const char *root, const char *ext, const mp_table *t,
                      mp_table_format fmt, const mp_text_kept *prev, mp_text_kept **keep,
                      char *err);

/* mp_pl_no_star: the error of a run that kept no star, a frame with no
 * usable star (bad input: one line, exit 1, no product written), into
 * err: the frame's own fault when it has one (f, mp_find_why_none: no good
 * pixel, every pixel saturated, too few; f NULL: not told, a tiled run),
 * else none_why, why its first detection found nothing, when it is not ""
 * and no round found a star; else the detections' count, and that fitrad
 * is under the PSF's FWHM fwhm when it is (NaN: not told).  Returns 1. */
int mp_pl_no_star(const char *image, const mp_frame *f, const char *none_why, double fwhm,
                  const mp_pipeline_opts *o, const mp_pipeline_report *rep, char *err);

/* mp_pl_write_catalog: root.cat (sky positions when the frame has a WCS;
 * FITS_LDAC carries the frame's header) and, with o->regions, root.reg.
 * root.fit must hold t, written in o->fit.fmt: a root.cat of the same
 * text is its copy; with sky positions, its rows' text as root.fit's write
 * kept it (fit_text; NULL: none) and the positions after. */
int mp_pl_write_catalog(const char *root, const mp_frame *f, mp_table *t,
                        const mp_pipeline_opts *o, const mp_text_kept *fit_text, char *err);

/* The residual image root.res.fits (BITPIX -32, GAIN and RDNOISE of f),
 * in ADU, NaN where the frame is masked bad; written whole by
 * mp_pl_write_residual, or a core at a time by the tiles:
 * mp_pl_residual_open makes an nx x ny image (mp_image_out: close it with
 * mp_image_out_close), mp_pl_residual_put writes its rectangle of w x h
 * pixels at frame pixel (x1, y1) from res [e-], the residual of frame f
 * whose pixel (1, 1) is frame pixel (1 + ox, 1 + oy). */
int mp_pl_residual_open(const char *root, const mp_frame *f, long nx, long ny,
                        mp_image_out **out, char *err);
int mp_pl_residual_put(mp_image_out *out, const mp_frame *f, const float *res, long x1, long y1,
                       long w, long h, long ox, long oy, char *err);
int mp_pl_write_residual(const char *root, const mp_frame *f, const float *res, char *err);

/* mp_pl_write_report: the run report of a finished run (stderr and
 * root.report) from the pipeline's counts and the final table; fit is the
 * setup the last round used (the task's, or one from the built PSF). */
int mp_pl_write_report(const char *image, const char *root,
                       const mp_fit_setup *fit, const mp_pipeline_report *rep, const mp_table *t,
                       char *err);

/* ---- error_scale.c ----------------------------------------------------- */

/* What the residual holds at the PSF's scale, as a factor on the fit's
 * errors: k[0] flux (FLUXERR_PSF, MAGERR_PSF), k[1] position (ERRX_PSF,
 * ERRY_PSF); raw the measured robust σ of flux, x and y (NaN: not
 * measured), nplace the places it is over. */
typedef struct {
    double k[2], raw[3];
    size_t nplace;
} mp_pl_escale;

/* Places at most, and at least, that the scale is measured on; a k is
 * used when it differs from 1 by more than MP_PL_ESCALE_Z of its sampling
 * errors (two-sided false rate 2.7e-3: on a frame whose residual is noise
 * the errors stay as the fit gave them). */
#define MP_PL_ESCALE_MAXPLACES 4000
#define MP_PL_ESCALE_MINPLACES 100
#define MP_PL_ESCALE_Z 3.0
#define MP_PL_ESCALE_REX 1.0

/* mp_pl_error_scale: at the centres of a grid of disjoint windows of
 * the pixels within fitrad (at most MP_PL_ESCALE_MAXPLACES, none with a
 * masked or non-finite pixel), the weighted linear fit of m's PRF there,
 * its ∂/∂x, ∂/∂y and a constant sky to res (f's data less every fitted
 * star, sky kept; weights 1/(model + the window's median + RON² + xvar)
 * as the fit's); each of the three estimates over its σ, and their robust
 * σ (1.4826·MAD) over the places: raw.  Places within MP_PL_ESCALE_REX
 * fwhm of a star of t (XPSF_IMAGE, YPSF_IMAGE) are left out: that star's
 * fit took up the noise there, and they read low.  k[0] = raw flux,
 * k[1] = the rms of raw x and y (over twice the places), each where
 * significant (above), else 1.  Errors: out of memory. */
int mp_pl_error_scale(const mp_frame *f, const float *res, const mp_table *t,
                      const mp_prf_model *m, double fitrad, double fwhm, mp_pl_escale *e,
                      char *err);

/* mp_pl_escale_unused: whether e's measured scatter differs from 1 (as
 * above) where too few places (MP_PL_ESCALE_MINPLACES) let it scale the
 * errors: the catalog's errors are then the fit's, and say less than the
 * residual does (a frame whose noise is not its model's: a wrong gain, its
 * sky subtracted without an error plane). */
int mp_pl_escale_unused(const mp_pl_escale *e);

/* mp_pl_escale_unused_why: what such a scatter says, one clause into why
 * (n bytes), for the warning and the report's detection line. */
void mp_pl_escale_unused_why(const mp_pl_escale *e, char *why, size_t n);

/* mp_pl_apply_error_scale: t's FLUXERR_PSF and MAGERR_PSF times k[0],
 * ERRX_PSF and ERRY_PSF times k[1] (the columns t has). */
void mp_pl_apply_error_scale(mp_table *t, const mp_pl_escale *e);

#endif
