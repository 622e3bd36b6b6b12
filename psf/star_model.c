/* star_model.c — the model the PSF stars are fitted with while the table
 * is built (build_priv.h, mp_epsf_fitter).
 *
 * Why: the builder fits every PSF star with its neighbours (up to 13
 * stars) at every outer iteration of every build, and the exact render
 * shifts the whole supersampled table for each star at each LM step: on
 * a crowded frame those fits were 75 % of `matphot psf` (bench/PROFILE.md).
 * At order 0 every star has the same table, so its PRF is drawn from the
 * fit's own phase grid (fit/prf_cache.c) whenever the grid's bias bound for
 * the group's brightest star, q = E·sqrt(Σ δP²/(E P + B + RON²)), is at
 * most MP_EPSF_GRID_FRAC of its σ (the fit's sincfrac default; the bound's
 * argument is fit/sinc_choice.c's).  The grid is built only when the fits
 * it would serve need more renders than it costs.  The back-projection
 * (sirt.c) stays exact: it is the transpose of the render that defines the
 * table. */
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include "psf/build_priv.h"

void mp_epsf_fitter_free(mp_epsf_fitter *z)
{
    mp_psf_free(&z->tab);
    mp_prf_cache_free(&z->grid);
    mp_prf_crop_free(&z->crop);
    memset(z, 0, sizeof *z);
}

void mp_epsf_fitter_start(mp_epsf_fitter *z, int mode, mp_prf_cache *spare)
{
    memset(z, 0, sizeof *z);
    z->mode = mode;
    if (spare) {
        z->grid = *spare;
        memset(spare, 0, sizeof *spare);
    }
}

void mp_epsf_fitter_done(mp_epsf_fitter *z, mp_prf_cache *spare)
{
    if (spare) {
        mp_prf_cache_free(spare);
        *spare = z->grid;
        memset(&z->grid, 0, sizeof z->grid);
    }
    mp_epsf_fitter_free(z);
}

/* Renders a grid of G phases per pixel costs: its nodes (os·(gb + 3) per
 * axis, gb = ⌈G/os⌉: fit/prf_cache.c) and the G² cells where its error is
 * measured. */
static double grid_renders(int G, int os)
{
    int gb = (G + os - 1) / os, na = os * (gb + 3), ng = os * gb;
    return (double)na * na + (double)ng * ng;
}

/* The renders of the used stars' fits that z's grid does not serve (all
 * without one): MP_ECON_RENDERS_PER_FIT per star of a fitted group, at
 * least; with the neighbours held, that for the star alone and one for
 * each neighbour (its light taken off the cut-out, mp_epsf_clean, by its
 * own flux's bound). */
static double unserved(const mp_epsf_fitter *z, const mp_epsf_star *s, size_t n)
{
    double r = 0.0;
    for (size_t k = 0; k < n; k++) {
        if (!s[k].used)
            continue;
        if (!mp_epsf_fitter_grid(z, &s[k]))
            r += MP_ECON_RENDERS_PER_FIT * (z->hold ? 1.0 : 1.0 + s[k].nnb);
        for (int j = 0; z->hold && j < s[k].nnb; j++)
            r += !mp_epsf_nb_grid(z->grid.G > 0 ? &z->grid : NULL, &s[k], j);
    }
    return r;
}

/* The grid's cheaper modes (fit/prf_cache.c: bilinear, and cubic within
 * a core only) for the stars' fits: their limits on the least sky of the
 * used stars, where they are lowest, so that they hold on every star's
 * (from the bins alone: no pixel summed, mp_prf_cache_tiers). */
static void set_tiers(mp_epsf_fitter *z, const mp_epsf_star *s, size_t n)
{
    memset(&z->tiers, 0, sizeof z->tiers);
    double sky = INFINITY;
    for (size_t k = 0; k < n; k++)
        if (s[k].used)
            sky = fmin(sky, fmax(s[k].sky, 0.0));
    if (z->grid.G > 0 && isfinite(sky))
        mp_prf_cache_tiers(&z->grid, sky, s[0].f.rdnoise, MP_EPSF_GRID_FRAC, 0, &z->tiers);
}

/* The grid is built when the fits it would serve need more renders than it
 * costs: first at MP_EPSF_GRID_G phases (a quarter of the fit's nodes per
 * axis at ×4: the cubic's error grows 16-fold, and a PSF star's bound
 * mostly still holds), then at the fit's MP_PRF_CACHE_G when the stars the
 * coarse grid leaves out pay for that; a table that needed the finer grid
 * starts there at the next step (the table changes little between steps). */
int mp_epsf_fitter_set(mp_epsf_fitter *z, const mp_epsf *e, const mp_epsf_star *s, size_t n,
                       int hold, char *err)
{
    z->hold = hold;
    /* The last round's grid: its blocks are this one's when it is built
     * at the same size (fit/prf_cache.c, page faults). */
    mp_prf_cache spare = z->grid;
    memset(&z->grid, 0, sizeof z->grid);
    mp_prf_crop_free(&z->crop);
    z->order0 = e->nterms == 1;
    int rc = 0;
    if (z->order0 && mp_epsf_table(e, e->x0, e->y0, &z->tab, err))
        rc = 1;
    mp_prf_model m = {&z->tab, NULL, 10};
    if (!rc && z->order0 && n > 0 &&
        mp_prf_crop_init(&m, MP_EPSF_CROPFRAC, s[0].f.rdnoise, &z->crop)) {
        snprintf(err, MP_ERRLEN, "psf build: out of memory");
        rc = 1;
    }
    for (int G = z->fine ? MP_PRF_CACHE_G : MP_EPSF_GRID_G;
         !rc && z->order0 && G <= MP_PRF_CACHE_G; G *= 2) {
        double need = unserved(z, s, n);
        if (z->mode < 0 || need == 0.0 || (z->mode == 0 && need < grid_renders(G, e->os)))
            break;
        mp_prf_cache_free(&z->grid);
        rc = mp_prf_cache_build_reusing(&m, G, &z->grid, &spare, err);
        z->fine = G == MP_PRF_CACHE_G;
    }
    set_tiers(z, s, n);
    mp_prf_cache_free(&spare);
    return rc;
}

const mp_prf_cache *mp_epsf_fitter_grid(const mp_epsf_fitter *z, const mp_epsf_star *s)
{
    if (!z->order0 || z->grid.G == 0)
        return NULL;
    /* The group's brightest star; twice over until a fit of the build has
     * set the fluxes: a start flux (the light within half psfrad) falls
     * short of the fitted one, a fitted one is where the next fit starts
     * and, the table changing little between rounds, about where it ends
     * (47 Tuc 256^2: a sixth of the PSF stars' fits were rendered exactly
     * for want of that, a fifth of the run's instructions; bench/
     * PROFILE.md, session 20).  Held, the neighbours are no part of the
     * fit (mp_epsf_clean draws each by its own flux's bound). */
    double E = s->flux;
    for (int j = 0; !z->hold && j < s->nnb; j++)
        E = fmax(E, s->nbf[j]);
    return mp_epsf_grid_serves(&z->grid, s, E) ? &z->grid : NULL;
}

int mp_epsf_grid_serves(const mp_prf_cache *g, const mp_epsf_star *s, double E)
{
    return mp_prf_cache_serves(g, (s->fitted ? 1.0 : 2.0) * E, fmax(s->sky, 0.0), s->f.rdnoise,
                               MP_EPSF_GRID_FRAC);
}

const mp_prf_cache *mp_epsf_nb_grid(const mp_prf_cache *g, const mp_epsf_star *s, int j)
{
    return g && mp_epsf_grid_serves(g, s, s->nbf[j]) ? g : NULL;
}
