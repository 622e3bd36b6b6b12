/*
 * sim.h — the simulator behind `matphot sim` and the validation runs.
 *
 * It never uses the fitter's shifter (design.md §2): analytic Gaussian PRFs
 * are integrated exactly over pixels (and over DRF subpixels) with erf, and
 * discrete-PSF stars are made by exact block-summing of a finer table placed
 * at a position on its own grid.  Noise: Poisson on the expected electrons,
 * then Gaussian read noise.  Everything is seeded; no global state.
 *
 * Coordinates are 1-based FITS pixel coordinates; img is row-major,
 * img[(y-1)*nx + (x-1)].
 */
#ifndef MATPHOT_SIM_H
#define MATPHOT_SIM_H

#include <stdint.h>

/* xoshiro256** generator. */
typedef struct { uint64_t s[4]; } mp_rng;

void mp_rng_seed(mp_rng *r, uint64_t seed);
uint64_t mp_rng_next(mp_rng *r);
double mp_rng_uniform(mp_rng *r);             /* [0,1) */
double mp_rng_normal(mp_rng *r);              /* N(0,1) */
double mp_rng_poisson(mp_rng *r, double mean);/* exact for any mean >= 0 */

typedef enum { MP_SIM_GAUSS, MP_SIM_TABLE } mp_sim_kind;

/* How a star is drawn. */
typedef struct {
    mp_sim_kind kind;
    double sigma;            /* MP_SIM_GAUSS: Gaussian sigma [px] (along x) */
    const double *tab;       /* MP_SIM_TABLE: fine table, tnx*tny, row-major, */
    int tnx, tny, tos;       /*   odd sizes, star at the central element, OVERSAMP tos */
    const double *drf;       /* optional DRF, dk*dk subpixel QE (row-major, */
    int dk;                  /*   subpixel (0,0) at the pixel's low x,y corner); NULL = none */
    double volume;           /* uniform QE when drf is NULL (1 = perfect) */
    double sigy;             /* MP_SIM_GAUSS: sigma along y [px]; 0: sigma (round;
                              * last, so positional initialisers keep it 0) */
} mp_sim_prf;

/* mp_sim_snap: the nearest position to (x,y) on which a MP_SIM_TABLE star
 * can be drawn exactly (the table's grid); identity for MP_SIM_GAUSS. */
void mp_sim_snap(const mp_sim_prf *p, double *x, double *y);

/* mp_sim_add_star: add flux·PRF (expected electrons, noiseless) to img.
 * MP_SIM_TABLE requires (x,y) on the grid (see mp_sim_snap); returns
 * nonzero otherwise.  (Added:) also nonzero, drawing nothing, for an
 * invalid PRF (sigma <= 0, even table size, dk not dividing tos, negative
 * volume), a non-finite position or flux, or no memory.  Light falling
 * outside the image is dropped. */
int mp_sim_add_star(const mp_sim_prf *p, double x, double y, double flux,
                    double *img, long nx, long ny);

/* mp_sim_add_noise: replace each expected value m by Poisson(m) +
 * N(0, ron²). */
void mp_sim_add_noise(mp_rng *r, double *img, long n, double ron);

/* mp_sim_add_star_float / mp_sim_add_noise_float: the same on a frame's
 * single-precision pixels (io.h mp_fimage: tests draw their frames in
 * place); the sums are formed in double, each pixel rounded once. */
int mp_sim_add_star_float(const mp_sim_prf *p, double x, double y, double flux, float *img,
                          long nx, long ny);
void mp_sim_add_noise_float(mp_rng *r, float *img, long n, double ron);

/* mp_sim_segmented_psf: the monochromatic PSF of a segmented mirror (18
 * hexagonal segments in two rings, no centre segment, 2 % gaps; Fraunhofer
 * diffraction, sim/segmented.c) with λ/D = lod detector px at the blue end
 * of a flat band [λ, λ(1 + band)] (band 0: monochromatic), as a table of
 * OVERSAMP os: (2·ceil(radius·os) + 1)² elements, star at the centre of the
 * central one, each the light of its element (the whole plane sums to 1, so
 * the table's sum is the fraction it holds).  *tab is malloc'ed (caller
 * frees), *n its side.  Nonzero with err (256 bytes) on bad arguments or
 * no memory. */
int mp_sim_segmented_psf(double lod, double band, int os, double radius, double **tab, int *n,
                         char *err);

/* The `matphot sim` task. */
int mp_task_sim(int argc, char **argv);

#endif
