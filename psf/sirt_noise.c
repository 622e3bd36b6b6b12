/* sirt_noise.c — what a SIRT step takes from pure noise (build_priv.h):
 * a draw of noise on the stars' own weights, and the χ² drop a step's
 * update makes on that draw.  sirt.c makes the step from the draw as
 * from the data (noise_drop) and stops stepping where the data's drop is
 * no larger: a step that lowers χ² no more than noise alone would fits
 * only noise. */
#include <math.h>
#include <stdint.h>
#include <stdlib.h>
#include <string.h>
#include "psf/build_priv.h"
#include "sim/sim.h"

/* The seed of the draw: star k's generator is seeded with this + k. */
#define NOISE_SEED 0x51a7u

void mp_epsf_sirt_noise_draw(mp_epsf_sirt *w, const mp_epsf_star *s, size_t n)
{
#pragma omp parallel for schedule(static)
    for (size_t k = 0; k < n; k++) {
        if (!s[k].used)
            continue;
        mp_rng r;
        mp_rng_seed(&r, NOISE_SEED + (uint64_t)k);
        const double *W = w->W + k * w->nR;
        double *R = w->Rn + k * w->nR;
        size_t nb = (size_t)w->geo[6 * k + 2] * (size_t)w->geo[6 * k + 3];
        for (size_t p = 0; p < nb; p++)
            R[p] = W[p] > 0 ? sqrt(W[p]) * mp_rng_normal(&r) : 0.0;
    }
}

/* A thread's scratch for update_sums. */
typedef struct {
    mp_psf tab;
    mp_prf_work pw;
    double *prf;
    size_t nprf;
} scratch;

/* Star k's Σ Rn·(A u) and Σ W·(A u)² over its box into t[0], t[1]: the
 * update eu at its place rendered as a step renders the table (with its
 * operators, w->axes[k]).  1 when out of memory. */
static int update_sums(mp_epsf_sirt *w, size_t k, const mp_epsf_star *sk, const mp_epsf *eu,
                       scratch *c, double t[2])
{
    char err[MP_ERRLEN];
    const double *geo = w->geo + 6 * k;
    size_t nb = (size_t)geo[2] * (size_t)geo[3];
    if (nb > c->nprf) {
        free(c->prf);
        c->nprf = 0;
        if (!(c->prf = malloc(nb * sizeof *c->prf)))
            return 1;
        c->nprf = nb;
    }
    if (mp_epsf_table(eu, sk->x, sk->y, &c->tab, err))
        return 1;
    mp_prf_model m = {&c->tab, NULL, 10};
    c->pw.axes = w->axes[k];
    int rc = mp_prf_render(&m, geo[4], geo[5], c->prf, NULL, NULL, &c->pw);
    w->axes[k] = c->pw.axes;
    c->pw.axes = NULL;
    if (rc)
        return 1;
    const double *R = w->Rn + k * w->nR, *W = w->W + k * w->nR;
    double a = 0.0, b = 0.0;
    for (size_t p = 0; p < nb; p++) {
        a += R[p] * c->prf[p];
        b += W[p] * c->prf[p] * c->prf[p];
    }
    t[0] = a;
    t[1] = b;
    return 0;
}

int mp_epsf_sirt_update_sums(mp_epsf_sirt *w, const mp_epsf_star *s, size_t n,
                             const mp_epsf *eu, double *a, double *b)
{
    double *t = calloc(2 * (n + 1), sizeof *t);
    if (!t)
        return 1;
    int failed = 0;
#pragma omp parallel reduction(| : failed)
    {
        scratch c;
        memset(&c, 0, sizeof c);
        c.pw.single = 1;        /* χ² to 1 is all a step needs (fit/prf_axis.h) */
#pragma omp for schedule(dynamic)
        for (size_t k = 0; k < n; k++)
            if (!failed && s[k].used)
                failed = update_sums(w, k, &s[k], eu, &c, t + 2 * k);
        free(c.prf);
        mp_psf_free(&c.tab);
        mp_prf_work_free(&c.pw);
    }
    /* summed in the stars' order: the same on any number of threads */
    *a = *b = 0.0;
    for (size_t k = 0; k < n; k++) {
        *a += t[2 * k];
        *b += t[2 * k + 1];
    }
    free(t);
    return failed;
}
