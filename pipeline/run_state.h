/*
 * run_state.h — private to pipeline/run.c and pipeline/run_psf.c: what one
 * run of one frame holds, and the steps each file gives the other.
 */
#ifndef MATPHOT_RUN_STATE_H
#define MATPHOT_RUN_STATE_H

#include <stdio.h>
#include "pipeline/pipeline_priv.h"

/* Everything one run of one frame holds. */
typedef struct {
    const char *image, *root;
    const mp_pipeline_opts *o;
    mp_pipeline_report *rep;
    mp_frame f;
    mp_bkg bkg;
    mp_table t;        /* the stars: found, then fitted, round by round */
    mp_table found;    /* detections on the residual, this round */
    mp_table gone;     /* where merged or rejected stars were */
    mp_table before;   /* NUMBER and position of every row given to the fit */
    mp_table grp;      /* the stars as the last grouping left them: root.grp,
                        * written with the products (each round's grouping
                        * replaces the last's; its text, written every round,
                        * was 1 % of 47 Tuc's CPU); empty when its values
                        * pass 8 MiB: then written each round (run.c
                        * keep_grouped) */
    float *res;        /* residual [e-], nx*ny, single precision as the frame */
    mp_fit_memory *mem;   /* what every group was fitted against, so a round
                           * refits only the groups new stars reach */
    double fwhm;
    const mp_fit_setup *fit;   /* the fit's setup: the task's, or own */
    mp_fit_setup own;     /* set up from root.psf.fits when the PSF is built */
    mp_fit_setup local;   /* own read at frame positions (a section: mp_pl_psf_on) */
    int have_own;
    long offx, offy;      /* the frame pixel of this image's (1, 1), less 1 */
    long fnx, fny;        /* the whole frame's size (0: this image is the frame) */
    mp_epsf psf;          /* the PSF built from the frame (build_psf) */
    double *px, *py, *pf; /* its stars */
    size_t np;
    size_t np_few;        /* PSF stars selected, too few for a table (then
                           * np = 0: the Gaussian of fwhm, run_psf.c) */
    double tabrad;        /* its table's radius [px], measured in pass 1
                           * with tablerad=INDEF (0: the option's) */
    double tabsupport;    /* the reach measured when short of tabrad (the
                           * table zero beyond it), else 0 */
    char tabwhy[480];     /* how (mp_epsf_rad.why), for the run report */
    int quiet;            /* mp_pipeline_reduce: no stderr lines, no files */
    int own_frame;        /* f read here, so the halo may be taken off it */
    int borrowed;         /* f is the caller's (mp_pipeline_reduce): its mask
                           * stays as given */
    int psf_pass;         /* the built PSF's last pass (0: none built) */
    int last_partial;     /* the last group_and_fit took one pass of several,
                           * or stopped at the loose tol (MP_PL_ROUND_TOL) */
    double halo_light;    /* the light per e- the halo took off every star
                           * (mp_pl_halo), which the PSF's PSFSUM counts */
    mp_coupling coupling; /* the κ table of the fit's model (mp_pl_group),
                           * kept from round to round; freed when the model
                           * changes (adopt_psf) */
    int sharp_known;      /* find's sharpness limits for the fit's model,
                           * measured (mp_pl_sharp_limits) until the model
                           * changes (adopt_psf): each search of a residual
                           * measured them again on the same model, 2 of the
                           * 3 measurements on the DECam cutout with its
                           * PSFEx model, 9 % of its CPU */
    double sharplo, sharphi;
    mp_stars_fwhm stars_fwhm;  /* the first detection's stars' FWHM
                           * (mp_epsf_stars_fwhm_found; n = 0: not measured), which
                           * a build short of PSF stars names */
    char gauss_wrong[MP_ERRLEN];  /* why the Gaussian of fwhm is not the
                           * stars' (mp_epsf_model_verdict), which ends a
                           * build that falls back on it; "": it fits */
    const mp_prf_cache *grid;  /* the phase grid the last fit drew from */
    double win;           /* the window side economy priced the last fit on */
    char none_why[320];   /* why the first detection found nothing
                           * (mp_find_why_none), said when the run keeps
                           * no star; "": it found some */
    unsigned written;     /* the products this run set out to write
                           * (mp_run_writes' bits) */
} run_state;

static inline int oom(char *err)
{
    snprintf(err, MP_ERRLEN, "out of memory");
    return 1;
}

/* ---- run.c -------------------------------------------------------------- */

/* mp_run_writes: the run is about to write root + ext (".coo",
 * ".psf.fits", ...): should it fail, that product goes (a failed run
 * leaves none). */
void mp_run_writes(run_state *s, const char *ext);

/* mp_run_group_and_fit: group the stars (kept for root.grp, written with
 * the products, or written now when large), fit every group (in one pass
 * when once) and draw the residual. */
int mp_run_group_and_fit(run_state *s, int round, int once, char *err);

/* mp_run_phase_grid: the phase grid the fit draws its groups' PRFs from,
 * and its flux limit in *gemax (NULL: exact renders); with glemax, its
 * bilinear interpolation's limit there too; with tiers, the cheaper
 * modes' limits, for the residual's paint.  On the table's median sky,
 * from the run's cache of limits (mp_econ_grid_limits: the sky rounded
 * down, each limit found once a run; found afresh at each call, the
 * limits cost ~1 % of 47 Tuc's run a call), else found here. */
const mp_prf_cache *mp_run_phase_grid(run_state *s, double *gemax, double *glemax,
                                      mp_prf_tiers *tiers);

/* ---- run_psf.c ---------------------------------------------------------- */

/* mp_run_build_psf: the PSF built from the frame (pass 1) or rebuilt with
 * every neighbour gone (pass 2), written to root.psf.fits and adopted. */
int mp_run_build_psf(run_state *s, int pass, char *err);

/* mp_run_heldout_applies: whether varorder=auto's held-out step runs. */
int mp_run_heldout_applies(const run_state *s);

/* mp_run_heldout_order: varorder=auto's last step, the next order judged
 * by the stars held out of the build. */
int mp_run_heldout_order(run_state *s, char *err);

#endif
