/*
 * pipeline.h — the staged reduction of one frame (design.md §1):
 * find → group → fit → find on the residual → merge → group → fit … until
 * nothing new is found or niter rounds are done, then the catalog.  Files
 * are named after the image: root.coo, root.grp, root.fit, root.res.fits,
 * root.cat (with sky positions when the frame has a WCS), root.reg and the
 * run report root.report (also on stderr).
 */
#ifndef MATPHOT_PIPELINE_H
#define MATPHOT_PIPELINE_H

#include "find/find.h"
#include "fit/fit.h"
#include "group/group.h"
#include "psf/build.h"

enum { MP_PL_HALO_ASKED = 1, MP_PL_HALO_AUTO = 2 };

typedef struct {
    mp_fit_setup fit;        /* PSF, model, fit options, datapars */
    mp_find_opts find;
    int mesh, filter;        /* background mesh and filter */
    mp_group_opts group;
    int groupcut_median;     /* groupcut=median: a group above maxgroup cut at
                              * its median, not its weakest couplings */
    double couplebudget;     /* groupcut=budget: every component re-formed, a
                              * link joined only while a star has more than
                              * this of Σκ² outside its group (0: not so) */
    int niter;
    double matchrad;         /* [px]; NaN: 0.5 FWHM */
    mp_table_format catfmt;
    int regions;             /* also write root.reg (DS9) */
    int build_psf;           /* psf="" : build root.psf.fits from the frame
                              * before the first round and once after it */
    mp_epsf_opts psfb;       /* how (psf.par's names: varorder, maxnpsf) */
    int tablerad_auto;       /* tablerad=INDEF: the table's radius measured on
                              * the frame's stars (psf/tablerad.c) */
    int halo;                /* after the first round, model the bright stars'
                              * light beyond the table (pipeline/halo.c):
                              * 0 no, MP_PL_HALO_ASKED (halo=yes),
                              * MP_PL_HALO_AUTO (halo=auto, the PSF built) */
    int crmask;              /* after the first round's fit, mask the pixels no
                              * sum of stars can make: cosmic rays, hot
                              * pixels (pipeline/cosmics.c) */
    int crgrow;              /* and the pixels within this many of each */
    int lookup;              /* after the first round, take off the PSF's mean
                              * residual around bright stars (pipeline/lookup.c) */
    mp_parset *ps;           /* the task's parameters: the fit is set up
                              * again from them with psf=root.psf.fits */
    long tilesize;           /* core of a tile [px]; 0: whole frame; -1: from maxmem */
    double maxmem;           /* memory budget [MB] that chooses tiles when tilesize = -1 */
    long tilemargin;         /* [px] read around a core; -1: 2 (fitrad + psfrad) + 2 FWHM */
    mp_sweeps *sweeps;       /* the directories this run (every frame of an
                              * @list) has swept of killed runs' temporaries
                              * (io.h mp_tmp_sweep); NULL: each frame sweeps */
    double grp_hold;         /* root.grp's values held to the end up to this
                              * many bytes, else written each round
                              * (run.c keep_grouped; mp_pl_opts_read: 8 MiB) */
    double escale[2];        /* the errors' factors (flux, position) given,
                              * not measured (fakes: the frame's own); 0:
                              * measured on the residual (pipeline/error_scale.c) */
} mp_pipeline_opts;

/* Seconds and counts of every stage, for the report on stderr.  t_find
 * holds every detection: the frame's, and on the residual its noise map,
 * screen, one-or-two test (split.c) and the new stars' matching. */
typedef struct {
    double t_read, t_bkg, t_find, t_group, t_fit, t_write;
    int rounds;
    long screened;                /* candidates deep detection's screen dropped */
    long found, added, fitted;
    mp_frame_report fit;          /* the rounds' frame fits: sums over rounds
                                   * (mp_frame_report_add); ngroups, noconv,
                                   * sky_groups and ops_render the last round's */
    long pairs_close, pairs_coupled;  /* grouping (mp_pl_group), summed over rounds */
    double threshold, rdnoise;    /* find's threshold [σ] and the frame's read noise
                                   * [e-], for the report's detection line (0: unknown) */
    char sharp[200];              /* find's last sharpness limits and why
                                   * (mp_pl_sharp_limits), for that line too */
    char stars_fwhm[400];         /* the first detection's stars' FWHM
                                   * against the model (run.c's check_fwhm), for
                                   * that line too; "": not measured */
    double escale[2], escale_raw[3];  /* the errors' factors (flux, position) from
                                   * the residual at the PSF's scale, and as
                                   * measured (flux, x, y; pipeline/error_scale.c;
                                   * NaN: not measured) */
    long escale_places;           /* the places they were measured at */
    long cr_cores, cr_masked;     /* cosmic-ray pixels flagged, and masked with
                                   * their growth (pipeline/cosmics.c) */
    double cr_s, cr_D, cr_k;      /* its test's constants (0: not run) */
} mp_pipeline_report;

/* mp_pipeline_run: reduce one image; root names the outputs. */
int mp_pipeline_run(const char *image, const char *root, const mp_pipeline_opts *o,
                    mp_pipeline_report *rep, char *err);

/* mp_pipeline_run_tiled: reduce one image in tiles (pipeline/tiles.c):
 * cores of tilesize x tilesize pixels, each read through a cfitsio section
 * with margin pixels more on every side and reduced as a frame of its own;
 * each star kept once, by the tile whose core holds its fitted position
 * (ties at the cores' edges settled as tiles.c says); root.fit,
 * root.res.fits (the cores' residuals), root.cat (+ .reg) and the report
 * for the whole frame (no root.coo or root.grp).  Needs a PSF model given
 * (not built from the frame) and no dqmask. */
int mp_pipeline_run_tiled(const char *image, const char *root, const mp_pipeline_opts *o,
                          long tilesize, long margin, mp_pipeline_report *rep, char *err);

/* MP_PL_BYTES_PER_PIXEL: peak memory of a whole-frame run per pixel; it
 * sets the tiles from maxmem.  Measured (issue 14, session 8: peak RSS,
 * OMP 1, crowded frames of 3.7e-3 stars a pixel, FWHM 3, x2 table):
 * 4096², 61 600 stars, 218.5 MiB = 13.65 B/px; 8192², 246 500 stars,
 * 808.2 MiB = 12.63 B/px (session 23, the refit bound: 756.0 MiB, 11.8
 * B/px).  Per pixel 8 (frame and residual, floats; the mask is paged in
 * only where a pixel is masked), per star ~0.9 kB at the peak (~3.5 B/px
 * at this density: table, fit state), and
 * ~22 MiB whatever the frame (libraries, the PSF's tables), which the
 * 4096² ratio, rounded up, covers for frames of 4096² and more; a
 * budget under ~200 MB is met less well (that fixed part dominates). */
#define MP_PL_BYTES_PER_PIXEL 14.0

/* mp_pipeline_run_any: mp_pipeline_run or mp_pipeline_run_tiled, as
 * o->tilesize, o->maxmem and the frame's size say. */
int mp_pipeline_run_any(const char *image, const char *root, const mp_pipeline_opts *o,
                        mp_pipeline_report *rep, char *err);

/* mp_pipeline_reduce: the same reduction of a frame already in memory
 * (not modified), with o's PSF (o->build_psf must be 0): t receives the
 * fitted stars (the table root.fit would hold; initialised here, the
 * caller frees it); rep, when not NULL, its report.  Nothing is written,
 * nothing printed; safe to call
 * from several threads at once on different frames (artificial stars,
 * pipeline/fakes.c). */
int mp_pipeline_reduce(const mp_frame *f, const mp_pipeline_opts *o, mp_table *t,
                       mp_pipeline_report *rep, char *err);

/* The `matphot pipeline` task. */
int mp_task_pipeline(int argc, char **argv);

/* The `matphot fakes` task: artificial-star tests (pipeline/fakes.c). */
int mp_task_fakes(int argc, char **argv);

#endif
