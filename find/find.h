/*
 * find.h — the sky background and noise map, DAOFIND-style star detection,
 * and the `matphot find` task (design.md §1–4; anchors.md §1.1, §1.3, §2).
 *
 * Conventions:
 *   - Frames are mp_frame (io/io.h): pixels in electrons, row-major,
 *     pix[(y-1)*nx + (x-1)] centred on the 1-based coordinate (x, y).
 *   - Pixels with MP_MASK_BAD carry no weight anywhere.  Pixels with
 *     MP_MASK_SATURATED are left out of the background, but keep their
 *     (clipped) values for detection, so a saturated star is still found,
 *     once (see mp_find_stars).
 *   - Output positions are FITS/IRAF/SExtractor: 1-based, centre of the
 *     first pixel at (1.0, 1.0).
 *   - Functions that can fail return 0 on success, nonzero on failure with
 *     one line in err (MP_ERRLEN bytes) naming the parameter or what is
 *     wrong; the task prefixes "matphot find: <image>: ".
 *   - No global mutable state; the work is split over rows with OpenMP.
 */
#ifndef MATPHOT_FIND_H
#define MATPHOT_FIND_H

#include "catalog/catalog.h"
#include "io/io.h"

/* ---- Background ----------------------------------------------------------- */

/* The sky and sky-noise maps, electrons, of an nx × ny frame.  No plane
 * of the frame's size is held (issue 14: the whole-frame run's memory is
 * counted in planes): the bicubic spline through the meshes is kept by
 * image rows (per row, the nbx values of the mesh columns' splines along y
 * and the second derivatives along x: 32/mesh bytes a pixel for both
 * maps, 0.5 at mesh 64), and a pixel's value is one cubic in x, evaluated where it is
 * used (mp_bkg_sky, mp_bkg_rms, mp_bkg_rows below) — in single precision,
 * bit for bit the value a stored float map would hold.  After
 * mp_bkg_noise_from_model the rms is the fitted model's noise, evaluated
 * from the frame and residual it was given (which must then outlive the
 * map).  Read the fields through the functions only. */
typedef struct {
    long nx, ny;
    int nbx;              /* mesh centres along x */
    double *cx;           /* their x [pixel, 0-based] */
    double *vals;         /* [4][ny][nbx]: sky values, sky d2, rms values, rms d2 */
    int model;            /* rms from the noise model below */
    double k, eps, ron2;  /* its scale, profile error and RON² */
    const float *pix, *res;   /* its frame and residual */
    /* The model error that grows as a star's flux squared
     * (mp_bkg_star_excess): v per class and 1-px ring of distance r < nxv,
     * and the stars it is added around (x, y, F², class, reach² each;
     * 0-based), by cells of nxv × nxv px: those of cell c are stars
     * cell0[c] .. cell0[c + 1] − 1 of xs, cells ncx a row. */
    double *xv;
    int nxv, nxc;         /* rings, classes */
    /* v per class, ring and direction (MP_BKG_NSECT equal turns about the
     * star, counter-clockwise from +x): the ring's v, or the cell's where
     * most of the class's stars hold a significant excess in it (a
     * table's spikes: mp_bkg_star_excess); NULL when no cell does */
    double *xvd;
    int nxd;              /* the cells with their own v */
    double *xs;
    size_t nxs;
    size_t *cell0;
    long ncx, ncy;
} mp_bkg;

/* mp_bkg_sky, mp_bkg_rms: the sky and rms at pixel i = y·nx + x (0-based). */
float mp_bkg_sky(const mp_bkg *b, size_t i);
float mp_bkg_rms(const mp_bkg *b, size_t i);

/* mp_bkg_rms_span: mp_bkg_rms of pixels [x0, x1) of row y (0-based) into
 * rms[0 .. x1 − x0), bit for bit: the residual's noise model adds its
 * stars' excess a span at a time (a star's window: the one-or-two test,
 * the residual's screen). */
void mp_bkg_rms_span(const mp_bkg *b, long y, long x0, long x1, float *rms);

/* mp_bkg_rows: sky (and rms when not NULL) of the rows [y0, y1), nx values
 * a row, into sky[(y − y0)·nx + x] and rms[…]: the cheap way for whole rows. */
void mp_bkg_rows(const mp_bkg *b, long y0, long y1, float *sky, float *rms);

/* mp_bkg_bytes: the bytes the map holds (for tests of the memory). */
size_t mp_bkg_bytes(const mp_bkg *b);

/* mp_bkg_set_flat: make b a flat map of nx × ny (sky and rms constant),
 * freeing what it held.  Errors (nonzero): out of memory. */
int mp_bkg_set_flat(mp_bkg *b, long nx, long ny, double sky, double rms);

/*
 * mp_bkg_estimate: the background map of f, as SExtractor makes it
 * (anchors.md §2.1: BACK_SIZE, BACK_FILTERSIZE).
 *
 *   mesh    box size [pixel] (SExtractor BACK_SIZE, ≥ 1).  The frame is cut
 *           into max(1, round(nx/mesh)) × max(1, round(ny/mesh)) boxes of
 *           equal size (±1 pixel), so there is no thin leftover box at the
 *           far edge; a frame smaller than a mesh is one box.
 *   filter  median filter over filter × filter boxes (SExtractor
 *           BACK_FILTERSIZE; odd, ≥ 1; 1 = none).
 *
 * In each box the good pixels (neither MP_MASK_BAD nor MP_MASK_SATURATED)
 * are clipped iteratively at median ± 3σ until the kept set stops
 * changing.  The sky is SExtractor's mode 2.5·median − 1.5·mean, or the
 * median when |mean − median| > 0.3σ (a skewed, crowded box: SExtractor's
 * back.c does the same).  The median of tied (integer) values is
 * interpolated within the tied value's bin, as SExtractor's histogram
 * median is, so integer ADU do not quantise the sky.  The rms is the
 * clipped standard deviation divided by the shrink factor of ±3σ clipping
 * to convergence on Gaussian noise (0.9846…), so that it estimates the true
 * σ and thresholds in σ mean what they say.  The mode, not the mean: on a
 * Poisson sky of B e- with read noise RON it lies ≈ 0.42·B/(B + RON²) e-
 * below the mean (under half an electron); the sampling error of one box of
 * n pixels is ≈ 2.14σ/√n.
 *
 * A box with fewer good pixels than half its area is filled with the mean
 * of its valid neighbours (SExtractor's rule).  The median filter shrinks
 * its window symmetrically at the grid's edges (SExtractor truncates it),
 * so a sky gradient is kept exactly rather than bent at the borders.  The
 * box values are then interpolated to every pixel by a bicubic natural
 * spline through the box centres (SExtractor's), continued linearly
 * beyond the outermost centres; rms is clamped at ≥ 0.
 *
 * A constant frame gives a flat map (sky = the constant, rms = 0).  A
 * frame with no good pixel at all gives a flat map with sky = rms = 0 (not
 * an error: detection then simply finds nothing).
 * Errors: mesh < 1, filter < 1 or even, out of memory.
 * On failure b holds nothing to free.
 */
int mp_bkg_estimate(const mp_frame *f, int mesh, int filter, mp_bkg *b, char *err);

/*
 * mp_bkg_noise_from_model: replace b's rms map by the noise the fitted
 * model predicts, for detection on a fit's residual.  res (nx*ny,
 * electrons) is data − stars with the sky kept; the stars' model is
 * M = f->im.pix − res.  The map is sqrt(k²(sky + M + RON²) + ε²M²):
 * Poisson noise of everything in the pixel, so a faint star between bright
 * ones meets the sky's noise and a residual on a bright star meets that
 * star's photon noise (the mesh rms of a crowded frame instead averages
 * star light into one number per box), plus a profile error ε·M as
 * DAOPHOT's proferr (anchors.md §1.3), here measured, so that where the
 * PSF does not match the data its residual is not taken for new stars.
 * k is the robust σ (1.4826·MAD) of the residual's detection-kernel
 * amplitude (DAOFIND's lowered Gaussian of fwhm and nsigma, as
 * mp_find_stars) over its Poisson σ, at pixels whose footprint's M is
 * below its own noise (or, when fewer than a quarter are, the quarter with
 * the least): 1 for Poisson data in electrons; it absorbs a wrong gain,
 * extra noise, and noise correlated between neighbouring pixels
 * (resampled mosaics), as detection sees it, and not the structure
 * smoother than the kernel (the lowered kernel sums to zero);
 * ε makes that robust σ 1 over the pixels where M is above 3 of k's σ,
 * and is 0 unless their excess is significant (3 sampling σ).  *scale receives k
 * (NaN, and rms left as it was, with fewer than 10 such pixels), *proferr
 * ε.  b->sky is used as the sky.  Errors: fwhm or nsigma not positive
 * (or a kernel too large), out of memory.
 */
int mp_bkg_noise_from_model(mp_bkg *b, const mp_frame *f, const float *res, double fwhm,
                            double nsigma, double *scale, double *proferr, char *err);

/*
 * mp_bkg_star_excess: after mp_bkg_noise_from_model, the model's error
 * that grows as a star's flux squared (the PSF table's own error, a
 * saturated star's flux taken from its wings), measured and added to b's
 * noise, so that detection and the one-or-two test do not take a bright
 * star's misfit rings for stars (issue 13: false stars on the rings and
 * spikes of a segmented-mirror frame's bright stars with its PSF built).
 *
 * Stars of one class share it (the pipeline: 0 the stars fitted whole,
 * 1 those whose fit left saturated pixels out; a higher class's misfit
 * reaches further).  It is measured around the nb brightest stars of each
 * class of the n stars (x, y 0-based pixels, F their fluxes [e−], cls
 * their classes 0..ncls−1, brightest first) that measure it: usable[s]
 * (NULL: all; the pipeline leaves out fits flagged not converged or
 * merged/degenerate) and no star of a higher class within rmax (its
 * misfit fills their rings).  Per 1-px ring r of distance below rmax
 * [px], over the unmasked pixels: z the residual less the sky over the
 * noise so far; the largest tenth of the ring's z² is left out (a star
 * not yet found, a cosmic ray: few pixels of a ring,
 * where a misfit PSF's rings and spikes fill much of it), and over the
 * rest S = Σ (z² − c₁), A = Σ F²/σ², c₁ = E[z² | |z| ≤ 1.645] for noise
 * alone (0.623, the same trim), whose variance c₂ − c₁² (0.461) gives S's
 * null σ.  A ring whose S exceeds 3 of that σ (one-sided false alarm
 * 1.35e-3 a ring) gets v(r) = S/A, the moment estimate of the variance
 * F²·v(r) its pixels hold beyond the noise (low by what the trim takes);
 * other rings 0.  Then around every star F²·v(r) of its class is added
 * to the variance of the pixels (mp_bkg_rms, mp_bkg_rows) out to the
 * last ring where it reaches MP_BKG_EXCESS_FLOOR of its sky pixel's
 * variance (a term below that changes the noise by under 0.5 %).
 * The trim keeps a ring's v from what few of its pixels hold, and so
 * from a PSF's spikes, which a built table may leave out (beyond the
 * radius its light per pixel reaches at 0.9 of the directions: frame V of
 * validate/CROWDED.md, its saturated stars' spikes at the table's edge
 * found as stars).  So each ring is also cut into MP_BKG_NSECT turns of
 * direction: a star's cell estimate is S/A over its pixels there with
 * every z² (null σ √(2m)/A, m pixels); a cell where at least three of the
 * class's stars have pixels and more than half of those are above 3 of
 * their σ gets the median of their estimates, when above the ring's v (in
 * b->xvd, b->nxd such cells).  A table's misfit repeats at the same place
 * about every star of a class; a companion, a cosmic ray, a star not yet
 * found lie about one.
 * *nring, *nkept: the rings (all classes) and stars that got it.  Nothing
 * changes without the noise model (b->model 0).  Errors: out of memory.
 */
#define MP_BKG_NSECT 32
#define MP_BKG_EXCESS_NSTAR 10
#define MP_BKG_EXCESS_FLOOR 0.01
int mp_bkg_star_excess(mp_bkg *b, const mp_frame *f, const double *x, const double *y,
                       const double *F, const int *cls, const unsigned char *usable, size_t n,
                       int ncls, size_t nb, double rmax, int *nring, size_t *nkept, char *err);

/* mp_bkg_free: release the maps; safe on a zeroed or freed mp_bkg. */
void mp_bkg_free(mp_bkg *b);

/* ---- Detection ------------------------------------------------------------ */

/* Detection options (IRAF findpars, anchors.md §1.3).  A NaN limit means
 * "no limit". */
typedef struct {
    double fwhm;       /* FWHM of the Gaussian kernel [pixel] (datapars.fwhmpsf) */
    double threshold;  /* threshold in σ of the kernel amplitude (4.0) */
    double nsigma;     /* kernel radius in Gaussian σ, at least 2 px (1.5) */
    double sharplo, sharphi;  /* sharpness limits (0.2, 1.0) */
    /* sharplo lowered, candidate by candidate, by this many σ of its own
     * SHARPNESS (its pixels' noise; step 6 below).  0, the default:
     * DAOFIND's fixed limit. */
    double sharpsig;
    double roundlo, roundhi;  /* roundness limits (−1.0, 1.0) */
    /* The sky map is the sky itself (a fitted model's residual, its sky
     * kept): where DAOFIND's h stays below threshold, peaks of the
     * Gaussian's amplitude with no constant beside it are offered too
     * (step 4b below).  0, the default: DAOFIND's alone. */
    int sky_known;
    /* A screen of the detections as they are made (NULL, the default:
     * none): see mp_find_sieve_fn. */
    struct mp_find_sieve *sieve;
} mp_find_opts;

/* A detection offered to a sieve: its 1-based position and flux as the
 * table would hold them; the sieve sets keep (0: dropped there and then,
 * never held nor written), and may set flux (written as FLUX) and snr
 * (written as column `col`). */
typedef struct {
    double x, y, flux, snr;
    int keep;
} mp_find_cand;

/* mp_find_opts.sieve: fn(ctx, c, n) is called with the detections of each
 * strip that pass the shape cuts (and with the saturated plateaus' at the
 * end), from one thread (it may thread itself); nonzero: out of memory.
 * A deep search of a residual finds several candidates a star, most of
 * them noise that a screen drops: sieved as they are made, they are never
 * all held at once (issue 14).  The table keeps the rows' order and
 * NUMBERs run on over the kept rows only. */
typedef int (*mp_find_sieve_fn)(void *ctx, mp_find_cand *c, size_t n);
struct mp_find_sieve {
    mp_find_sieve_fn fn;
    void *ctx;
    const char *col;           /* the column snr is written to */
};

/* mp_find_opts_default: DAOPHOT's findpars defaults (fwhm 3.0, the
 * design's usual PSF): threshold 4, nsigma 1.5, sharpness 0.2..1.0,
 * roundness −1..1. */
void mp_find_opts_default(mp_find_opts *o);

/* FLAGS bits of a detection (the design.md §4 bits). */
enum {
    MP_FIND_SATURATED = 1,  /* a saturated star (detected as its plateau) */
    MP_FIND_EDGE = 4,       /* the kernel footprint crosses the image edge */
    MP_FIND_MASKED = 32     /* masked (bad) pixels inside the footprint */
};

/*
 * mp_find_stars: detect stars on f with sky map b and append one row per
 * star to t (columns created when missing):
 *
 *   NUMBER      running number, continuing after the largest already in t
 *   X_IMAGE, Y_IMAGE  centroid, 1-based [pixel]
 *   FLUX_MAX    brightest pixel above background within 1 px of the peak
 *               (of the plateau for a saturated star) [electron]
 *   BACKGROUND  sky map at the centroid's pixel [electron]
 *   SHARPNESS   DAOFIND's: (peak pixel − mean of the other footprint
 *               pixels) / convolved height
 *   ROUNDNESS   DAOFIND's "ground": 2(hx − hy)/(hx + hy) from the heights
 *               of the 1-D Gaussian fits to the x and y marginals (the
 *               symmetry-based "sround" is not computed)
 *   FLUX        first flux estimate [electron]: the convolved height divided
 *               by the kernel's response to a unit-flux, pixel-integrated
 *               Gaussian of fwhm at the measured centroid — exact for an
 *               isolated star of the kernel's shape
 *   FLAGS       MP_FIND_* bits
 *
 * Rows come in raster order of their peak pixels (y, then x), as DAOFIND's.
 *
 * Algorithm (DAOFIND; Stetson 1987, PASP 99, 191; anchors.md §1.1):
 *   1. Kernel: K = exp(−r²/2σ²), σ = fwhm/2.35482, on the pixels with
 *      r ≤ max(2, nsigma·σ) (DAOPHOT); the lowered kernel is
 *      (K − mean K)/Σ(K − mean K)², so the convolution h of the
 *      background-subtracted image is the least-squares amplitude of a
 *      Gaussian star (plus any constant) centred on the pixel.
 *   2. Masked pixels and pixels outside the image have zero weight: the
 *      kernel is lowered and normalised again over the good pixels of that
 *      footprint.  A footprint needs at least half its pixels good.
 *   3. Threshold: h = Σ w·d with weights w = (K − K̄)/Σ(K − K̄)², so on
 *      independent pixel noise of σ its noise is σ_h = σ·sqrt(Σ w²) =
 *      σ·relerr, relerr = 1/sqrt(Σ_good (K − mean_good K)²) (IRAF's and
 *      photutils' "relerr"; 1.285 for FWHM 3); σ is the rms map at the
 *      pixel (DAOFIND's one sky σ made local); a pixel is a candidate when
 *      h ≥ threshold·σ_h and h exceeds roundoff (1e-10·(1 + |sky|), which
 *      matters only on noiseless frames, where rms = 0).
 *   4. A candidate must be the maximum of h over its footprint (ties go to
 *      the first in raster order).
 *   4b. With sky_known, also a pixel where h stays below threshold over the
 *      whole footprint but hu ≥ threshold·σ_hu and hu is the footprint's
 *      maximum: hu = Σ g·d / Σ g², the Gaussian's amplitude over the known
 *      sky, σ_hu = σ/sqrt(Σ g²).  The lowered kernel fits a constant
 *      beside the star, which costs h a factor sqrt(Σ g²/Σ (g − ḡ)²) of
 *      S/N (1.9 at FWHM 2.3, 2.8 at FWHM 3: 13 taps): a star of S/N 6
 *      in hu is 2.2 σ in h at FWHM 3.  Where h passes somewhere in the
 *      footprint DAOFIND's candidates stand (hu, with no negative
 *      surround, merges close pairs that h keeps apart).  Such a
 *      candidate is measured (5, 6) with DAOFIND's h like any other.
 *   5. Centroid: Gaussian fits (sky, height, shift) to the x and y marginal
 *      sums of the footprint box with DAOFIND's triangular weights,
 *      iterated to convergence (DAOFIND takes one step); a star whose fit
 *      has height ≤ 0 or moves more than the box half-width is rejected.
 *      Masked pixels leave the marginal sums (each becomes a weighted mean
 *      over its good pixels, with the kernel profile averaged alike).
 *   6. Cuts: sharplo ≤ SHARPNESS ≤ sharphi, roundlo ≤ ROUNDNESS ≤ roundhi.
 *      (A star of the kernel's FWHM has SHARPNESS ≈ 0.47 for FWHM 3; its
 *      noise at 10σ is ≈ 0.12, so DAOPHOT's sharplo = 0.2 costs ~1 % of
 *      10σ stars, more of fainter ones: ~8 % at 4.5σ.)  With sharpsig > 0
 *      the low limit is sharplo − sharpsig·σ_s, σ_s the candidate's own
 *      SHARPNESS noise from its pixels' (the rms map at the peak; the
 *      delta method on (d₀ − mean of the others)/h, their covariance
 *      through the shared pixels): a candidate goes only when its
 *      sharpness lies that far below the limit.
 *
 * On white noise h is nearly uncorrelated beyond one pixel (the lowering
 * makes ρ ≈ 0.08 at lag 1, −0.34 at lag 2 for FWHM 3), so the false
 * detections before cuts number ≈ Npix·Q(threshold): ~33 per 1024² at 4σ.
 *
 * Saturation: each 8-connected region of MP_MASK_SATURATED pixels is one
 * star at the region's centroid with FLAGS 1 (no shape cuts; SHARPNESS and
 * ROUNDNESS 0, not measured; FLUX from the plateau's area, assuming a
 * Gaussian of fwhm clipped at the saturated level).  Ordinary candidates
 * with a saturated pixel within their footprint are dropped, so a flat
 * top or its rim never splits into several stars.
 *
 * o NULL means mp_find_opts_default.
 * No value written is NaN or infinite.  Errors: fwhm ≤ 0, nsigma ≤ 0,
 * threshold < 0 or not finite, b not the frame's size, out of memory
 * (t may then hold some new columns but no new rows).
 */
int mp_find_stars(const mp_frame *f, const mp_bkg *b, const mp_find_opts *o,
                  mp_table *t, char *err);

/*
 * mp_find_sharpness: the SHARPNESS mp_find_stars would measure of the star
 * in img (nx × ny, row-major, sky-free and noiseless) with o's kernel: at
 * the pixel of largest h among those whose footprint lies inside img and,
 * with reach > 0, that lie within reach of img's centre pixel (nx/2,
 * ny/2) on both axes (each pixel costs the kernel's area: a whole window
 * of a 200-px FWHM kernel took hours).  What the shape cut sees of a PSF
 * itself, phase by phase: a PSF sharper than the kernel's Gaussian (an
 * undersampled one) can exceed sharphi at some phases with no noise at
 * all (pipeline/sharp_limits.c).  Errors: a bad kernel, out of memory, no
 * positive h.
 */
int mp_find_sharpness(const double *img, long nx, long ny, const mp_find_opts *o, long reach,
                      double *sharp, char *err);

/*
 * mp_find_why_none: why f holds no star to find, into why (n bytes), for
 * the one line a frame with no usable star ends with (find, fit,
 * pipeline).  1 when the frame itself holds none: no good pixel (all NaN,
 * blank, masked or saturated), fewer good pixels than a star's 4
 * parameters, or a noise of 0 on every good pixel (a constant frame; b
 * the frame's estimated background, or NULL: not told).  0 when it could:
 * why then says no source rose above threshold [sigma].
 */
int mp_find_why_none(const mp_frame *f, const mp_bkg *b, double threshold, char *why,
                     size_t n);

/* The `matphot find` task: IMAGE → table (params/find.par).  argv[0] is
 * "find".  Returns the exit status: 0, 1 (error, one line on stderr),
 * 2 (usage). */
int mp_task_find(int argc, char **argv);

#endif
