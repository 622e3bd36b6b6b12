/*
 * econ_state.h — inside fit/ only: the run's economy state (the tables
 * economy may build and the flux limits kept across frames), shared by
 * fit/econ_plan.c, which builds the tables when they pay, and
 * fit/frame_rules.c, which keeps the limits.  Others use fit.h's
 * mp_econ_cache functions.
 */
#ifndef MATPHOT_FIT_ECON_STATE_H
#define MATPHOT_FIT_ECON_STATE_H

#include "fit/fit.h"

/* One table economy may build: its state and what it costs and saves. */
enum { ECON_UNASKED = 0, ECON_BUILT = 1, ECON_FAILED = -1 };

struct mp_econ_cache {
    /* The flux limits of the bound tables per sky level (frame_rules.c). */
    int n;
    struct {
        const void *c;             /* an mp_sinc_choice, mp_ss_level or mp_prf_cache */
        int kind;
        double sky, ron, frac;
        double *emax;
    } e[MP_ECON_CACHE_MAX];
    /* What the run may build (mp_econ_offer) and what it built. */
    int offered;
    mp_psf psf0;                   /* the model's table at the field's origin (no field) */
    mp_prf_model model0;           /* the model with psf0: what every table is measured on */
    const mp_psf *psf;             /* the model's own PSF (its field, if any) */
    const mp_psf_field *field;     /* NULL: a constant PSF */
    int want_sinc, grid_g;
    int nlev, lev_os[MP_SS_MAXLEVELS];
    int sinc_state, lev_state[MP_SS_MAXLEVELS], grid_state;
    mp_sinc_choice sinc;
    mp_ss_level ss[MP_SS_MAXLEVELS];
    mp_prf_cache grid;
    mp_prf_cache spare;            /* an earlier cache's grid, its blocks for this
                                    * one's (mp_econ_cache_hand_grid) */
    double spent;                  /* multiply-adds spent building tables */
    double fits_max;               /* the most star fits a frame was planned for */
    double ops_done;               /* exact-render work the run's fits did (mp_econ_learn) */
    double paint_done;             /* exact-render work the run's paints did
                                    * (mp_econ_learn_paint) */
    double *env;                   /* the model's crop envelope (mp_econ_envelope), NULL
                                    * until a frame needs it */
    int env_nr;
};

/* Kinds of cached limits. */
enum { ECON_LIM_SINC = 0, ECON_LIM_LEVEL = 1, ECON_LIM_GRID = 2 };

/* Multiply-adds of one bound evaluation (one flux) of each kind
 * (fit/econ_plan.c): what the per-group decisions and the limits cost. */
double mp_econ_eval_ops(const void *table, int kind);

#endif
