/* build_priv.h — what the builder's files share (psf/ only). */
#ifndef MATPHOT_PSF_BUILD_PRIV_H
#define MATPHOT_PSF_BUILD_PRIV_H

#include "psf/build.h"

/* The outer radius of a star's sky annulus beyond psfrad r [px]: from
 * r + 1 to r + max(4, r/2). */
#define MP_EPSF_ANNULUS(r) ((r) / 2 > 4.0 ? (r) / 2 : 4.0)

/* The SIRT step's work: per star the back-projected residual (G) and its
 * weight (H) on the table grid.  (Each thread renders into scratch of its
 * own: sirt.c.) */
typedef struct {
    size_t nstar, nel;
    float *G, *H;          /* nstar × nel (floats: the combination of
                            * each element reads every star's, and at ×4
                            * these arrays are tens of MB a step) */
    double *R;             /* nstar × nR: each star's W·ρ on its box */
    double *W;             /* nstar × nR: each box pixel's W (0: none) */
    double *Rn;            /* nstar × nR: W·ρ of a draw of pure noise
                            * (noise_drop; allocated when first drawn) */
    size_t nR;             /* the largest box's pixels */
    double *geo;           /* nstar × 6: the box (x0, y0, w, h) and the
                            * star (x, y) in its cut-out's coordinates */
    double *chi2s;         /* nstar: each star's Σ W ρ², summed in order */
    double *npix;          /* nstar: each star's pixels with weight */
    struct mp_prf_axes_s **axes;  /* nstar: each star's render operators
                            * (fit/prf.c), made at its first render of a
                            * run and read by every step after */
    double *tmp;           /* nel */
    unsigned char *mask;   /* nstar × nel: MP_EPSF_MASKED, MP_EPSF_HIT */
    double chi2;           /* Σ W ρ² of the last step */
    double ridge;          /* added to each element's normal equations */
    int steps;             /* steps taken by the last mp_epsf_sirt_run */
    double noise_drop;     /* the χ² drop a step takes from pure noise
                            * (sirt.c noise_drop; NaN: not drawn yet) */
    int noise_fresh;       /* noise_drop drawn in this mp_epsf_sirt_run */
    int per_element;       /* 1: every element's update by the clipped
                            * combination's code, even where fewer than 5
                            * stars leave nothing to clip (sirt.c
                            * combine_few's check; mp_epsf_sirt_init: 0) */
} mp_epsf_sirt;

/* Bits of mp_epsf_sirt.mask per star and element: left out of the
 * combination (a neighbour's light is there, mp_epsf_sirt_dilate), and
 * above 4 robust σ of the other stars in the last step. */
enum { MP_EPSF_MASKED = 1, MP_EPSF_HIT = 2 };

/* The model the stars are fitted with for one state of the table
 * (star_model.c): at order 0 the table of every star, and its phase grid
 * when the fits pay for it; at higher orders each star's own table. */
typedef struct {
    mp_psf tab;            /* order 0: the table; else the last star's */
    mp_prf_cache grid;     /* order 0: tab's phase grid (G 0: none) */
    mp_prf_tiers tiers;    /* its cheaper modes' limits on the least sky of
                            * the used stars (zeroed: cubic) */
    int order0;            /* tab is every star's table */
    int mode;              /* mp_epsf_opts.grid */
    int fine;              /* the last grid was MP_PRF_CACHE_G's */
    int hold;              /* the fits hold the neighbours: a star is fitted
                            * alone, each neighbour drawn once (the
                            * mp_epsf_fitter_set that set this state) */
    mp_prf_crop crop;      /* order 0: each star rendered out to where its
                            * light falls below MP_EPSF_CROPFRAC of a sky
                            * pixel's σ (env NULL: its whole box) */
    long fits, fits_grid;  /* star fits done, and of them from the grid */
} mp_epsf_fitter;

/* The crop of the stars' renders in the build's fits: the pipeline fit's
 * cropfrac default (fit/fit_frame.c), whose bound it shares (a star's
 * light left out of a pixel is below that fraction of its noise). */
#define MP_EPSF_CROPFRAC 0.02

/* The bias bound, in units of the brightest star's σ, under which a
 * group's PRF is drawn from the phase grid (the fit's sincfrac default). */
#define MP_EPSF_GRID_FRAC 0.1
/* The coarser grid tried first (phases per pixel; star_model.c). */
#define MP_EPSF_GRID_G 8

/* mp_epsf_fitter_set: z for table e as it now is, before fitting the used
 * stars of s, with their neighbours held (hold) or fitted beside them
 * (the grid is built when their fits need more renders than it costs).
 * Nonzero on out of memory. */
int mp_epsf_fitter_set(mp_epsf_fitter *z, const mp_epsf *e, const mp_epsf_star *s, size_t n,
                       int hold, char *err);

/* mp_epsf_fitter_grid: the grid to fit star s (and its neighbours, when
 * not held) from, or NULL: none built, or its bound at twice the fitted
 * group's brightest flux above MP_EPSF_GRID_FRAC. */
const mp_prf_cache *mp_epsf_fitter_grid(const mp_epsf_fitter *z, const mp_epsf_star *s);

/* mp_epsf_grid_serves: whether grid g may draw light E around PSF star s:
 * its bias bound, on s's sky, at E (twice E until a fit of the build has
 * set the fluxes) is at most MP_EPSF_GRID_FRAC of its σ. */
int mp_epsf_grid_serves(const mp_prf_cache *g, const mp_epsf_star *s, double E);

/* mp_epsf_nb_grid: the grid g (NULL: none) when it may draw star s's
 * neighbour j by that neighbour's own flux (mp_epsf_grid_serves), else
 * NULL: how a held neighbour is taken off the cut-out (mp_epsf_clean). */
const mp_prf_cache *mp_epsf_nb_grid(const mp_prf_cache *g, const mp_epsf_star *s, int j);
void mp_epsf_fitter_free(mp_epsf_fitter *z);
/* mp_epsf_fitter_start: z zeroed, with the grid in spare (NULL: none)
 * for its first mp_epsf_fitter_set to rebuild in; mp_epsf_fitter_done: z
 * freed, its grid left in spare (mp_epsf_opts.spare).  A pass builds its
 * table several times over (the two halves, the refits, the next order),
 * each round rebuilding the grid for the table as it stands: in fresh
 * blocks each time, the PSF build's grids were 40 % of the page faults of
 * 47 Tuc 512² built (bench/PROFILE.md, 2026-12-03). */
void mp_epsf_fitter_start(mp_epsf_fitter *z, int mode, mp_prf_cache *spare);
void mp_epsf_fitter_done(mp_epsf_fitter *z, mp_prf_cache *spare);

int mp_epsf_sirt_init(mp_epsf_sirt *w, const mp_epsf *e, size_t nstar, char *err);

/* mp_epsf_sirt_dilate: each used star's MP_EPSF_MASKED elements become
 * those within a square of half-width rd elements of a cluster of its
 * MP_EPSF_HIT elements (an element hit with at least min(3, os²) − 1 hit
 * among its 8 neighbours: one pixel's light reaches os² elements, so a
 * lone hit is noise), and the hits are cleared: what only one star
 * shows beyond its core, a neighbour too faint to be found, is left out
 * of that star's share of the table, its wings with it (the 4 σ clip
 * takes only its core).  Stars in parallel; 1 when out of memory. */
int mp_epsf_sirt_dilate(mp_epsf_sirt *w, const mp_epsf *e, size_t n, double rd);
void mp_epsf_sirt_free(mp_epsf_sirt *w);

/* mp_epsf_sirt_run: up to o->sirt steps on e's planes from the used stars'
 * current fits; stops when a step lowers χ² by less than one, or by no
 * more than a step made from pure noise would (w->noise_drop, drawn where
 * it could be the larger: sirt.c step_floor). */
int mp_epsf_sirt_run(mp_epsf_sirt *w, const mp_epsf_star *s, size_t n, const mp_epsf_opts *o,
                     mp_epsf *e, char *err);

/* mp_epsf_sirt_floor: the least χ² drop (into *floor) that is more than
 * noise after a drop of drop, by mp_epsf_sirt_run's own rule: one, or
 * what a step made from pure noise of the stars' weights lowers χ² by
 * (w->noise_drop: the run's draw, drawn now where it could decide).  For
 * a round of the build (mp_epsf_rounds) after its run.  Nonzero with err
 * when out of memory. */
int mp_epsf_sirt_floor(mp_epsf_sirt *w, const mp_epsf_star *s, size_t n, const mp_epsf_opts *o,
                       const mp_epsf *e, double drop, double *floor, char *err);

/* mp_epsf_sirt_noise: the χ² drop a step from e would take from pure
 * noise of the used stars' weights at their current fits, into
 * w->noise_drop: a draw of that noise (mp_epsf_sirt_noise_draw), the step
 * made from it as mp_epsf_sirt_run makes one from the data, and the drop
 * it makes on the draw.  e's elements beyond the run's disc are zeroed,
 * as a run does.  Nonzero with err when out of memory. */
int mp_epsf_sirt_noise(mp_epsf_sirt *w, const mp_epsf_star *s, size_t n, const mp_epsf_opts *o,
                       mp_epsf *e, char *err);

/* mp_epsf_sirt_noise_draw: into w->Rn, W·ρ of pure noise on each used
 * star's box (ρ = z/√W, z ~ N(0, 1), where the pixel has weight W),
 * star k's z from a generator seeded by k: the same draw on any number of
 * threads (sirt_noise.c). */
void mp_epsf_sirt_noise_draw(mp_epsf_sirt *w, const mp_epsf_star *s, size_t n);

/* mp_epsf_sirt_update_sums: an update eu (nterms planes) rendered at each
 * used star's place as a step renders the table (its operators
 * w->axes), *a = Σ ⟨Rn, A u⟩ and *b = Σ ‖A u‖²_W over the stars' boxes,
 * summed in the stars' order.  Nonzero when out of memory. */
int mp_epsf_sirt_update_sums(mp_epsf_sirt *w, const mp_epsf_star *s, size_t n,
                             const mp_epsf *eu, double *a, double *b);

/* mp_epsf_normalise: plane 0 to sum 1, the other planes to sum 0 (a
 * star's flux means the same everywhere), and the windowed centroid of
 * every plane (Gaussian window of fwhm) to the central element; elements
 * beyond support px of it zero first (mp_epsf_opts.support; 0: none). */
void mp_epsf_normalise(mp_epsf *e, double fwhm, double support);

/* The Wiener filter of the table (denoise.c): MP_EPSF_NWBIN bins of
 * MP_EPSF_WBIN cycles per detector pixel (out to 2: the ×4 Nyquist). */
#define MP_EPSF_WBIN 0.05

/* mp_epsf_wiener_measure: w[b] = S/(S+N) per radial bin from table e and a
 * draw of its noise (same size and sampling), non-increasing outward.
 * Nonzero on out of memory. */
int mp_epsf_wiener_measure(const mp_epsf *e, const mp_epsf *noise, double *w, int nbin);

/* mp_epsf_wiener_apply: every plane of e filtered by w (per cycles per
 * pixel, so any OVERSAMP).  Nonzero on out of memory. */
int mp_epsf_wiener_apply(mp_epsf *e, const double *w, int nbin);

/* mp_epsf_rounds: mp_epsf_build (build.h) without its last step, the
 * stars' fit with the final table: their fits are those of the last
 * round, made with the table before its last SIRT steps.  For builds whose
 * table is changed again before the stars' fits matter (the halves, a
 * table then filtered or block-summed: their own refit follows), where
 * that fit cost a tenth of the first pass. */
int mp_epsf_rounds(mp_epsf_star *s, size_t n, const mp_epsf_opts *o, int os, int order,
                   mp_epsf *e, char *err);

/* mp_epsf_common_drop: a round's χ² (chi2s, each star's) against the
 * last round's (last), summed over the stars used in both: last − this.
 * last then holds this round's χ² of each used star, NaN for the others
 * (all NaN before the first round: a drop of 0).  A star the clip takes
 * out lowers the whole sum by its own χ², which says nothing of the
 * table: on frame B built's ×4 halves that sum fell by 2·10⁴–10⁵ a round
 * from round 2 on while the stars kept rose by 32–1064. */
double mp_epsf_common_drop(const mp_epsf_star *s, size_t n, const double *chi2s, double *last);

/* mp_epsf_refit: every used star (and its neighbours, unless
 * o->frame_nb or o->first_pass) fitted again with table e as it now is
 * (after a filter or a new order), e->nstar the stars still used: fluxes
 * that go with the table (growth.c). */
int mp_epsf_refit(mp_epsf_star *s, size_t n, const mp_epsf_opts *o, mp_epsf *e, char *err);

/* mp_epsf_solve: the symmetric positive system A x = b of order m ≤ MP_EPSF_MAXT by
 * Cholesky (A, b overwritten; x in b); nonzero when not positive. */
int mp_epsf_solve(double *A, double *b, int m);

#endif
