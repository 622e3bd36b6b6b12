/* task_sim.c — the `matphot sim` task: a simulated frame and its truth
 * table (paper §5: one star near the centre of 60×60 px, or a crowded
 * field), in the magnitude system of design.md §3. */
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <time.h>
#include <unistd.h>

#include "catalog/catalog.h"
#include "io/io.h"
#include "params/params.h"
#include "psf/psf.h"
#include "sim/sim.h"
#include "sim/sim_inputs.h"

/* Everything the task needs from its parameters, checked. */
typedef struct {
    const char *output, *psf, *drf, *psfout, *psfkernel;
    char *truth;                      /* owned */
    int nx, ny, crowded, nstars, noise, psfos, segmented, ncosrays;
    int oversamp;                     /* psf='s OVERSAMP when its header has none; 0 */
    int fieldnx, fieldny, x0, y0;     /* the field the frame looks at */
    double magmin, magmax, sky, rdnoise, gain, fwhm, volume, saturate, lod, band, crenergy;
    double ra, dec, pixscale;         /* TAN WCS at the field's centre; ra NaN: none */
    double fwhmvar, stretch;          /* the Gaussian across the field (star_prf) */
    uint64_t seed;
} sim_config;

/* The field and its WCS: a frame is a window (x0, y0) on a field of
 * fieldnx x fieldny whose stars one seed draws, so frames with the same
 * seed and other offsets overlap on the same stars (and, with ra/dec, on
 * the sky). */
static int read_field(const mp_parset *ps, sim_config *c, char *err)
{
    if (mp_par_int(ps, "fieldnx", &c->fieldnx) || mp_par_int(ps, "fieldny", &c->fieldny) ||
        mp_par_need_int(ps, "x0", &c->x0, err) || mp_par_need_int(ps, "y0", &c->y0, err) ||
        mp_par_real(ps, "ra", &c->ra) || mp_par_real(ps, "dec", &c->dec) ||
        mp_par_need_real(ps, "pixscale", &c->pixscale, err)) {
        if (!*err)
            snprintf(err, MP_ERRLEN, "sim.par: a field parameter is missing from the defaults");
        return 1;
    }
    if (c->fieldnx == MP_PAR_INDEF_INT)
        c->fieldnx = c->nx;
    if (c->fieldny == MP_PAR_INDEF_INT)
        c->fieldny = c->ny;
    if (isfinite(c->ra) != isfinite(c->dec)) {
        snprintf(err, MP_ERRLEN, "%s: INDEF while %s is given; a WCS needs both",
                 isfinite(c->ra) ? "dec" : "ra", isfinite(c->ra) ? "ra" : "dec");
        return 1;
    }
    return 0;
}

/* The numeric parameters, each one a number. */
static int read_numbers(const mp_parset *ps, sim_config *c, char *err)
{
    static const char *const reals[] = {"magmin", "magmax", "sky",  "rdnoise", "gain",
                                        "fwhm",   "volume", "lod",  "band",    "crenergy",
                                        "fwhmvar", "stretch"};
    double *rv[] = {&c->magmin, &c->magmax, &c->sky,  &c->rdnoise,  &c->gain,    &c->fwhm,
                    &c->volume, &c->lod,    &c->band, &c->crenergy, &c->fwhmvar, &c->stretch};
    if (mp_par_need_int(ps, "nx", &c->nx, err) || mp_par_need_int(ps, "ny", &c->ny, err) ||
        mp_par_need_int(ps, "nstars", &c->nstars, err) ||
        mp_par_need_int(ps, "psfos", &c->psfos, err) ||
        mp_par_need_int(ps, "ncosrays", &c->ncosrays, err))
        return 1;
    c->oversamp = MP_PAR_INDEF_INT;
    mp_par_int(ps, "oversamp", &c->oversamp);
    if (c->oversamp == MP_PAR_INDEF_INT)
        c->oversamp = 0;
    for (size_t k = 0; k < sizeof reals / sizeof *reals; k++)
        if (mp_par_need_real(ps, reals[k], rv[k], err))
            return 1;
    return 0;
}

/* pupil=: gaussian, or segmented (which draws its own PSF). */
static int read_pupil(const mp_parset *ps, sim_config *c, char *err)
{
    const char *pupil = mp_par_string(ps, "pupil");
    c->segmented = pupil && strcmp(pupil, "segmented") == 0;
    if (!pupil || (!c->segmented && strcmp(pupil, "gaussian") != 0)) {
        snprintf(err, MP_ERRLEN, "pupil: '%s' is not gaussian or segmented", pupil ? pupil : "");
        return 1;
    }
    if (c->segmented && *c->psf) {
        snprintf(err, MP_ERRLEN, "pupil: segmented draws its own PSF; give no psf=");
        return 1;
    }
    if ((c->fwhmvar != 0.0 || c->stretch != 0.0) && (c->segmented || *c->psf)) {
        snprintf(err, MP_ERRLEN, "%s: only the Gaussian of fwhm varies across the field (no "
                 "psf=, pupil=gaussian)", c->fwhmvar != 0.0 ? "fwhmvar" : "stretch");
        return 1;
    }
    return 0;
}

/* seed=, noise= and mode=. No seed: one from the clock, recorded in the
 * SEED card so the frame can be made again. */
static int read_mode_seed(const mp_parset *ps, const char *mode, sim_config *c, char *err)
{
    int seed;
    if (mp_par_real(ps, "saturate", &c->saturate) || mp_par_int(ps, "seed", &seed)) {
        snprintf(err, MP_ERRLEN, "sim.par: saturate or seed is missing from the defaults");
        return 1;
    }
    if (mp_par_bool(ps, "noise", &c->noise)) {
        snprintf(err, MP_ERRLEN, "noise: give yes or no");
        return 1;
    }
    c->seed = seed == MP_PAR_INDEF_INT
        ? ((uint64_t)time(NULL) * 1000003u ^ (uint64_t)getpid()) & 0x7fffffff
        : (uint64_t)seed;
    if (strcmp(mode, "single") != 0 && strcmp(mode, "crowded") != 0) {
        snprintf(err, MP_ERRLEN, "mode: '%s' is not single or crowded", mode);
        return 1;
    }
    c->crowded = strcmp(mode, "crowded") == 0;
    return 0;
}

/* Values that are numbers but not usable ones. */
static int check_ranges(const sim_config *c, char *err)
{
    if (c->magmax < c->magmin) {
        snprintf(err, MP_ERRLEN, "magmax: %g is brighter than magmin %g", c->magmax, c->magmin);
        return 1;
    }
    if (!(c->gain > 0)) {
        snprintf(err, MP_ERRLEN, "gain: %g is not > 0", c->gain);
        return 1;
    }
    if (c->ncosrays < 0) {
        snprintf(err, MP_ERRLEN, "ncosrays: %d is not >= 0", c->ncosrays);
        return 1;
    }
    if (!(fabs(c->fwhmvar) < 1.0) || !(c->stretch >= 0.0)) {
        snprintf(err, MP_ERRLEN, "%s: out of range", !(fabs(c->fwhmvar) < 1.0) ? "fwhmvar"
                                                                               : "stretch");
        return 1;
    }
    if (!(c->crenergy > 0)) {
        snprintf(err, MP_ERRLEN, "crenergy: %g is not > 0", c->crenergy);
        return 1;
    }
    if (c->sky < 0 || c->rdnoise < 0 || !(c->fwhm > 0) || !(c->volume > 0) || c->volume > 1) {
        const char *bad = c->sky < 0 ? "sky" : c->rdnoise < 0 ? "rdnoise"
                        : !(c->fwhm > 0) ? "fwhm" : "volume";
        snprintf(err, MP_ERRLEN, "%s: out of range", bad);
        return 1;
    }
    if (*c->drf && c->volume != 1.0) {
        snprintf(err, MP_ERRLEN, "volume: not used with drf (the DRF's mean is the volume); "
                 "give one of them");
        return 1;
    }
    return 0;
}

/* truth=, or the output's name with .truth; never the output itself. */
static int name_truth(const char *truth, sim_config *c, char *err)
{
    c->truth = *truth ? strdup(truth) : mp_name_after(c->output, ".truth");
    if (!c->truth) {
        snprintf(err, MP_ERRLEN, "truth: out of memory");
        return 1;
    }
    if (strcmp(c->truth, c->output) == 0) {
        snprintf(err, MP_ERRLEN, "truth: '%s' is also the output frame", c->truth);
        return 1;
    }
    return 0;
}

static int read_config(const mp_parset *ps, sim_config *c, char *err)
{
    memset(c, 0, sizeof *c);
    c->output = mp_par_string(ps, "output");
    c->psf = mp_par_string(ps, "psf");
    c->drf = mp_par_string(ps, "drf");
    c->psfout = mp_par_string(ps, "psfout");
    c->psfkernel = mp_par_string(ps, "psfkernel");
    const char *truth = mp_par_string(ps, "truth");
    const char *mode = mp_par_string(ps, "mode");
    if (!c->output || !c->psf || !c->drf || !c->psfkernel || !truth || !mode) {
        snprintf(err, MP_ERRLEN, "sim.par: a parameter is missing from the defaults");
        return 1;
    }
    if (!*c->output) {
        snprintf(err, MP_ERRLEN, "output: no output frame named");
        return 1;
    }
    if (mp_out_fits_named("output", c->output, err) || mp_out_fits_named("psfout", c->psfout, err))
        return 1;
    if (!*c->psf && mp_psf_kernel_spec(c->psfkernel) >= MP_KERNEL_HEADER) {
        snprintf(err, MP_ERRLEN, "psfkernel: %s: a detector kernel needs a PSF table (psf=)",
                 c->psfkernel);
        return 1;
    }
    /* The order of the checks is the order of the messages a user with
     * several mistakes sees first. */
    return read_numbers(ps, c, err) || read_pupil(ps, c, err) ||
           read_mode_seed(ps, mode, c, err) || read_field(ps, c, err) ||
           check_ranges(c, err) || name_truth(truth, c, err);
}

/* Stars of the scene, drawn in a fixed order (x, y, mag per star) so one
 * seed gives one scene. */
static int make_truth(const sim_config *c, const mp_sim_prf *prf, mp_rng *r,
                      mp_table *t, char *err)
{
    mp_table_init(t);
    const char *names[] = {"NUMBER", "X_IMAGE", "Y_IMAGE", "FLUX_TRUE", "MAG_TRUE", "SKY_TRUE"};
    int col[6];
    for (int i = 0; i < 6; i++)
        if ((col[i] = mp_table_add_col(t, names[i])) < 0) {
            snprintf(err, MP_ERRLEN, "truth: out of memory");
            return 1;
        }
    /* Truth positions to 1e-8 px: snapped table positions are exact
     * fractions the fit is judged against. */
    strcpy(t->cols[col[1]].fmt, "%14.8f");
    strcpy(t->cols[col[2]].fmt, "%14.8f");
    int n = c->crowded ? c->nstars : 1;
    for (int k = 0; k < n; k++) {
        double x, y;
        if (c->crowded) {
            x = 0.5 + c->fieldnx * mp_rng_uniform(r) - c->x0;   /* in the frame */
            y = 0.5 + c->fieldny * mp_rng_uniform(r) - c->y0;
        } else {
            x = (c->nx + 1) / 2.0 + mp_rng_uniform(r) - 0.5;
            y = (c->ny + 1) / 2.0 + mp_rng_uniform(r) - 0.5;
        }
        mp_sim_snap(prf, &x, &y);
        double mag = c->magmin + (c->magmax - c->magmin) * mp_rng_uniform(r);
        double flux = pow(10.0, -0.4 * mag);
        long row = mp_table_add_row(t);
        if (row < 0) {
            snprintf(err, MP_ERRLEN, "truth: out of memory");
            return 1;
        }
        double v[6] = {k + 1, x, y, flux, -2.5 * log10(flux), c->sky};
        for (int i = 0; i < 6; i++)
            mp_table_set(t, (size_t)row, col[i], v[i]);
    }
    return 0;
}

/* A TAN WCS (ICRS) whose reference point is the field's centre, north up
 * and east left: 12 cards. */
static int wcs_cards(const sim_config *c, mp_card *k)
{
    double d = c->pixscale / 3600.0;
    int n = 0;
    k[n++] = (mp_card){"WCSAXES", 2, NULL, "simulated field's WCS"};
    k[n++] = (mp_card){"CTYPE1", 0, "RA---TAN", "gnomonic"};
    k[n++] = (mp_card){"CTYPE2", 0, "DEC--TAN", "gnomonic"};
    k[n++] = (mp_card){"CRPIX1", (c->fieldnx + 1) / 2.0 - c->x0, NULL, "field centre x"};
    k[n++] = (mp_card){"CRPIX2", (c->fieldny + 1) / 2.0 - c->y0, NULL, "field centre y"};
    k[n++] = (mp_card){"CRVAL1", c->ra, NULL, "[deg] RA of the field centre"};
    k[n++] = (mp_card){"CRVAL2", c->dec, NULL, "[deg] Dec of the field centre"};
    k[n++] = (mp_card){"CD1_1", -d, NULL, "[deg/pixel] east left"};
    k[n++] = (mp_card){"CD2_2", d, NULL, "[deg/pixel] north up"};
    k[n++] = (mp_card){"RADESYS", 0, "ICRS", "reference frame"};
    k[n++] = (mp_card){"CUNIT1", 0, "deg", "units of CRVAL1, CD1_1"};
    k[n++] = (mp_card){"CUNIT2", 0, "deg", "units of CRVAL2, CD2_2"};
    return n;
}

static int write_frame(const sim_config *c, const mp_sim_prf *prf, double volume, int kernel,
                       const double *adu, char *err)
{
    /* A pixel a float (a noisy frame's BITPIX -32) cannot hold, or none
     * can, is no frame: sky=1e300 wrote one of +inf. */
    for (size_t i = 0; i < (size_t)c->nx * (size_t)c->ny; i++)
        if (!isfinite(c->noise ? (float)adu[i] : adu[i])) {
            snprintf(err, MP_ERRLEN, "%s: pixel (%ld, %ld) would hold %g ADU, beyond a %s (sky, "
                     "rdnoise, gain, the stars' magnitudes or crenergy out of scale)", c->output,
                     (long)(i % (size_t)c->nx) + 1, (long)(i / (size_t)c->nx) + 1, adu[i],
                     c->noise ? "float" : "double");
            return 1;
        }
    mp_card cards[28];          /* 14 at most, and the WCS's 12 */
    int nc = 0;
    cards[nc++] = (mp_card){"BUNIT", 0, "ADU", "pixel unit"};
    cards[nc++] = (mp_card){"GAIN", c->gain, NULL, "[e-/ADU] gain"};
    cards[nc++] = (mp_card){"RDNOISE", c->rdnoise, NULL, "[e-] read noise"};
    if (isfinite(c->saturate))
        cards[nc++] = (mp_card){"SATURATE", c->saturate, NULL, "[ADU] saturation level"};
    cards[nc++] = (mp_card){"EXPTIME", 1.0, NULL, "[s] exposure time"};
    cards[nc++] = (mp_card){"SKY", c->sky, NULL, "[e-] simulated sky per pixel"};
    cards[nc++] = (mp_card){"SEED", (double)c->seed, NULL, "matphot sim random seed"};
    if (prf->kind == MP_SIM_GAUSS)
        cards[nc++] = (mp_card){"FWHM", c->fwhm, NULL, "[pixel] simulated Gaussian PSF FWHM"};
    else
        cards[nc++] = (mp_card){"PSF", 0, c->segmented ? "segmented mirror" : c->psf,
                                "simulated PSF table"};
    if (kernel)
        cards[nc++] = (mp_card){"PSFKERN", 0, c->psfkernel, "detector kernel folded into PSF"};
    if (c->fwhmvar != 0.0 || c->stretch != 0.0) {
        cards[nc++] = (mp_card){"FWHMVAR", c->fwhmvar, NULL, "FWHM x (1 + FWHMVAR u) across x"};
        cards[nc++] = (mp_card){"STRETCH", c->stretch, NULL, "x (1+S v^2) along x, (1+S u^2) y"};
    }
    if (*c->drf)
        cards[nc++] = (mp_card){"DRF", 0, c->drf, "simulated detector response"};
    cards[nc++] = (mp_card){"VOLUME", volume, NULL, "PRF volume (mean detector QE)"};
    cards[nc++] = (mp_card){"ORIGIN", 0, "matphot sim", "simulated frame"};
    if (isfinite(c->ra))
        nc += wcs_cards(c, cards + nc);
    return mp_image_write(c->output, adu, c->nx, c->ny, c->noise ? -32 : -64, cards, nc, err);
}

/* A table star's table block-summed by an odd factor to OVERSAMP psfos
 * (the star stays at the centre of the central element), written to
 * psfout: what the fit is given, exactly the sums the simulator draws. */
static int write_table_psf(const sim_config *c, const mp_sim_prf *prf, char *err)
{
    int f = prf->tos / c->psfos;
    if (prf->tos % c->psfos || f % 2 == 0) {
        snprintf(err, MP_ERRLEN, "psfos: %d must divide the table's OVERSAMP %d by an odd factor",
                 c->psfos, prf->tos);
        return 1;
    }
    int cx = (prf->tnx - 1) / 2, cy = (prf->tny - 1) / 2, hx = (cx + f / 2) / f, hy = (cy + f / 2) / f;
    int nx = 2 * hx + 1, ny = 2 * hy + 1;
    double *t = calloc((size_t)nx * ny, sizeof *t);
    if (!t) {
        snprintf(err, MP_ERRLEN, "%s: out of memory", c->psfout);
        return 1;
    }
    for (int j = 0; j < prf->tny; j++)
        for (int i = 0; i < prf->tnx; i++) {
            int I = (int)floor((double)(i - cx + f / 2) / f) + hx;
            int J = (int)floor((double)(j - cy + f / 2) / f) + hy;
            if (I >= 0 && I < nx && J >= 0 && J < ny)
                t[(size_t)J * nx + I] += prf->tab[(size_t)j * prf->tnx + i];
        }
    mp_card cards[1] = {{"OVERSAMP", c->psfos, NULL, "table elements per detector pixel"}};
    int rc = mp_image_write(c->psfout, t, nx, ny, -64, cards, 1, err);
    free(t);
    return rc;
}

/* The Gaussian as a PSF table (design.md §3): OVERSAMP os, odd size, each
 * element the integral over its subpixel — drawn as a star of width σ·os at
 * the centre of a fine frame, so it is exact like every simulated star. */
static int write_psf(const sim_config *c, const mp_sim_prf *prf, char *err)
{
    if (prf->kind == MP_SIM_TABLE)
        return write_table_psf(c, prf, err);
    int os = c->psfos, h = (int)ceil(4.0 * c->fwhm * os), n = 2 * h + 1;
    mp_sim_prf fine = *prf;
    fine.sigma = prf->sigma * os;
    fine.volume = 1.0;
    double *t = calloc((size_t)n * n, sizeof *t);
    if (!t) {
        snprintf(err, MP_ERRLEN, "%s: out of memory for a table of %d x %d elements (fwhm %g at "
                 "psfos %d)", c->psfout, n, n, c->fwhm, os);
        return 1;
    }
    int rc = mp_sim_add_star(&fine, h + 1.0, h + 1.0, 1.0, t, n, n);
    if (rc)
        snprintf(err, MP_ERRLEN, "%s: cannot draw the PSF", c->psfout);
    mp_card cards[2] = {{"OVERSAMP", os, NULL, "table elements per detector pixel"},
                        {"FWHM", c->fwhm, NULL, "[pixel] Gaussian FWHM"}};
    if (!rc)
        rc = mp_image_write(c->psfout, t, n, n, -64, cards, 2, err);
    free(t);
    return rc;
}

/* The truth lists the stars whose centre is on the frame (1-based pixels
 * 1..n cover 0.5 .. n + 0.5); a field's other stars still add their light
 * near the edges. */
static void keep_on_frame(mp_table *t, int nx, int ny)
{
    int cx = mp_table_col(t, "X_IMAGE"), cy = mp_table_col(t, "Y_IMAGE");
    size_t k = 0;
    for (size_t i = 0; i < t->nrow; i++) {
        double x = mp_table_get(t, i, cx), y = mp_table_get(t, i, cy);
        if (x < 0.5 || x >= nx + 0.5 || y < 0.5 || y >= ny + 0.5)
            continue;
        memmove(t->v + k * t->ncol, t->v + i * t->ncol, t->ncol * sizeof *t->v);
        k++;
    }
    t->nrow = k;
}

/* The star's PRF: the Gaussian, a table given (psf=) or the segmented
 * mirror's, seen through a DRF (drf=); *volume the frame's mean DRF
 * volume; *seg the segmented table, to free.  Nonzero with err. */
static int setup_prf(const sim_config *c, sim_inputs *in, mp_sim_prf *prf, double *volume,
                     double **seg, char *err)
{
    *prf = (mp_sim_prf){.kind = MP_SIM_GAUSS, .volume = c->volume,
                        .sigma = c->fwhm / (2.0 * sqrt(2.0 * log(2.0)))};
    *volume = c->volume;
    if (*c->psf && sim_load_psf(c->psf, c->oversamp, c->psfkernel, in, prf, err))
        return 1;
    if (c->segmented) {
        /* The segmented mirror's table at psfos, drawn as any table star. */
        int n;
        char e[256];
        if (mp_sim_segmented_psf(c->lod, c->band, c->psfos, 20.0, seg, &n, e)) {
            snprintf(err, MP_ERRLEN, "pupil: %s", e);
            return 1;
        }
        *prf = (mp_sim_prf){.kind = MP_SIM_TABLE, .tab = *seg, .tnx = n, .tny = n,
                            .tos = c->psfos, .volume = c->volume};
    }
    if (*c->drf) {
        if (sim_load_drf(c->drf, in, prf, err))
            return 1;
        *volume = in->drf_mean;
    }
    return 0;
}

/* ncosrays hits after the noise (IRAF artdata mknoise's ncosrays): each a
 * straight track of 1-3 pixels (equally likely) in one of the 8 grid
 * directions from a pixel anywhere on the frame, its charge uniform in
 * 0.5..1.5 crenergy [e-], shared equally by its pixels (a track leaving
 * the frame loses the rest).  No draw at all when there are none, so a
 * frame without hits is the one made before they existed. */
static void add_cosmic_rays(const sim_config *c, mp_rng *rng, double *img)
{
    static const int step[8][2] = {{1, 0}, {1, 1}, {0, 1}, {-1, 1},
                                   {-1, 0}, {-1, -1}, {0, -1}, {1, -1}};
    for (int h = 0; h < c->ncosrays; h++) {
        long x = (long)(mp_rng_uniform(rng) * c->nx), y = (long)(mp_rng_uniform(rng) * c->ny);
        int len = 1 + (int)(3.0 * mp_rng_uniform(rng)), d = (int)(8.0 * mp_rng_uniform(rng));
        double q = c->crenergy * (0.5 + mp_rng_uniform(rng)) / len;
        for (int a = 0; a < len; a++, x += step[d][0], y += step[d][1])
            if (x >= 0 && y >= 0 && x < c->nx && y < c->ny)
                img[y * c->nx + x] += q;
    }
}

/* The PRF of a star at frame pixel (x, y): the Gaussian of fwhm varying
 * across the field as psfb.c's variable scene (issue 11's second case),
 * with u, v from −1 to 1 across the field: σ_x = σ(1 + fwhmvar·u)(1 +
 * stretch·v²), σ_y = σ(1 + fwhmvar·u)(1 + stretch·u²) — broader to the
 * right, elongated along the edges; prf itself elsewhere. */
static mp_sim_prf star_prf(const sim_config *c, const mp_sim_prf *prf, double x, double y)
{
    mp_sim_prf at = *prf;
    if (prf->kind != MP_SIM_GAUSS || (c->fwhmvar == 0.0 && c->stretch == 0.0))
        return at;
    double u = (x + c->x0 - 0.5 * (c->fieldnx + 1)) / (0.5 * c->fieldnx);
    double v = (y + c->y0 - 0.5 * (c->fieldny + 1)) / (0.5 * c->fieldny);
    double s0 = prf->sigma * (1.0 + c->fwhmvar * u);
    at.sigma = s0 * (1.0 + c->stretch * v * v);
    at.sigy = s0 * (1.0 + c->stretch * u * u);
    return at;
}

/* The frame [image units]: the sky, the truth's stars, the noise, the
 * cosmic rays, the gain and the saturation.  NULL with err when out of
 * memory. */
static double *draw_frame(const sim_config *c, const mp_sim_prf *prf, const mp_table *t,
                          mp_rng *rng, char *err)
{
    size_t npix = (size_t)c->nx * (size_t)c->ny;
    double *img = malloc(npix * sizeof *img);
    if (!img) {
        snprintf(err, MP_ERRLEN, "%s: out of memory for %d x %d pixels", c->output, c->nx, c->ny);
        return NULL;
    }
    for (size_t i = 0; i < npix; i++)
        img[i] = c->sky;
    int cx = mp_table_col(t, "X_IMAGE"), cy = mp_table_col(t, "Y_IMAGE");
    int cf = mp_table_col(t, "FLUX_TRUE");
    for (size_t k = 0; k < t->nrow; k++) {
        double x = mp_table_get(t, k, cx), y = mp_table_get(t, k, cy);
        mp_sim_prf at = star_prf(c, prf, x, y);
        if (mp_sim_add_star(&at, x, y, mp_table_get(t, k, cf), img, c->nx, c->ny)) {
            snprintf(err, MP_ERRLEN, "%s: cannot draw star %zu (out of memory?)",
                     c->output, k + 1);
            free(img);
            return NULL;
        }
    }
    if (c->noise)
        mp_sim_add_noise(rng, img, (long)npix, c->rdnoise);
    add_cosmic_rays(c, rng, img);
    for (size_t i = 0; i < npix; i++) {
        img[i] /= c->gain;
        if (img[i] > c->saturate)      /* never true for INDEF (NaN) */
            img[i] = c->saturate;
    }
    return img;
}

/* The frame, its truth (the stars on it) and the PSF table asked for: all
 * of them or none (a failed write removes the ones written). */
static int write_outputs(const sim_config *c, const mp_sim_prf *prf, double volume,
                         int kernel, const double *img, mp_table *t, char *err)
{
    if (write_frame(c, prf, volume, kernel, img, err))
        return 1;
    keep_on_frame(t, c->nx, c->ny);
    if (mp_table_write(c->truth, t, MP_TAB_ASCII_HEAD, err)) {
        remove(c->output);           /* no frame without its truth */
        return 1;
    }
    if (c->psfout && *c->psfout && write_psf(c, prf, err)) {
        remove(c->output);
        remove(c->truth);
        return 1;
    }
    return 0;
}

static int run(const sim_config *c, char *err)
{
    mp_sim_prf prf;
    sim_inputs in;
    memset(&in, 0, sizeof in);
    mp_table t;
    mp_table_init(&t);
    double *img = NULL, *seg = NULL, volume;
    mp_rng rng;
    mp_rng_seed(&rng, c->seed);
    int rc = setup_prf(c, &in, &prf, &volume, &seg, err) || make_truth(c, &prf, &rng, &t, err) ||
             !(img = draw_frame(c, &prf, &t, &rng, err)) ||
             write_outputs(c, &prf, volume, in.kernel, img, &t, err);
    free(seg);
    free(img);
    mp_table_free(&t);
    sim_inputs_free(&in);
    return rc;
}

int mp_task_sim(int argc, char **argv)
{
    mp_parset ps;
    int rc = mp_task_begin("sim", argc, argv, &ps);
    if (rc)
        return rc;
    sim_config c;
    char err[MP_ERRLEN];
    rc = read_config(&ps, &c, err);
    if (!rc) {
        const char *in[2] = {c.psf, c.drf}, *out[3] = {c.output, c.psfout, c.truth};
        rc = mp_outputs_clear(in, 2, out, 3, err);
    }
    if (!rc) {                   /* killed runs' temporaries, once a directory */
        mp_sweeps *sw = mp_sweeps_new();
        mp_tmp_sweep(sw, c.output);
        mp_tmp_sweep(sw, c.psfout);
        mp_tmp_sweep(sw, c.truth);
        mp_sweeps_free(sw);
    }
    rc = rc || run(&c, err);
    if (rc)
        fprintf(stderr, "matphot sim: %s\n", err);
    free(c.truth);
    mp_params_free(&ps);
    return rc ? 1 : 0;
}
