/*
 * sim_inputs.h — private to sim/: the PSF table and DRF files of
 * `matphot sim`, read and checked into an mp_sim_prf.
 */
#ifndef MATPHOT_SIM_INPUTS_H
#define MATPHOT_SIM_INPUTS_H

#include "io/io.h"
#include "sim/sim.h"

/* What mp_sim_prf points into; free with sim_inputs_free. */
typedef struct {
    mp_image psf, drf;
    double drf_mean;        /* the PRF volume the DRF implies */
    int kernel;             /* the detector kernel folded into psf: its size, 0 none */
} sim_inputs;

/* sim_load_psf: read a PSF table (odd sizes, OVERSAMP integer >= 1, absent
 * = hos when > 0, else 1; no NaN; sum <= 1.01) into in->psf, fold in the
 * detector kernel kspec names (psf/psf.h mp_psf_kernel_read: auto, header,
 * none or a file), and point prf at it.  Negative elements only warn (on
 * stderr, prefixed "matphot sim: warning: "). */
int sim_load_psf(const char *path, int hos, const char *kspec, sim_inputs *in, mp_sim_prf *prf,
                 char *err);

/* sim_load_drf: read a k×k DRF (QE in [0,1]) into in->drf and point prf at
 * it; for a table PSF, k must divide its OVERSAMP. */
int sim_load_drf(const char *path, sim_inputs *in, mp_sim_prf *prf, char *err);

void sim_inputs_free(sim_inputs *in);

#endif
