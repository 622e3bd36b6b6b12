/* oversamp.c — the coarsest sampling the built PSF can have (build.h):
 * the table block-summed to a coarser OVERSAMP is rendered beside the
 * table itself; their difference is what the coarser table's own
 * interpolation (aliasing) costs a star, measured against its noise. */
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include "psf/build_priv.h"

int mp_epsf_rebin(const mp_epsf *e, int factor, mp_epsf *out, char *err)
{
    memset(out, 0, sizeof *out);
    if (factor < 1 || e->os % factor) {
        snprintf(err, MP_ERRLEN, "psf build: factor %d does not divide OVERSAMP %d", factor, e->os);
        return 1;
    }
    size_t nel = (size_t)e->nx * e->ny;
    double *sh = malloc(nel * sizeof *sh), *tmp = malloc(nel * sizeof *tmp);
    if (!sh || !tmp) {
        free(sh);
        free(tmp);
        snprintf(err, MP_ERRLEN, "psf build: out of memory");
        return 1;
    }
    int rc = 1;
    for (int t = 0; t < e->nterms; t++) {
        /* An even block-sum leaves the star half an input element off the
         * new centre (mp_psf_rebin): shift it the other way first. */
        const double *src = e->planes + (size_t)t * nel;
        double off = 0.0;
        if (factor % 2 == 0) {
            mp_shift_table(src, e->nx, e->ny, 0.5, 0.5, 10, sh, tmp);
            src = sh;
            off = -0.5 / e->os;
        }
        mp_psf in = {MP_PSF_TABLE, e->nx, e->ny, e->os, (double *)src, 1.0, 0.0, off, NULL}, o;
        if (mp_psf_rebin(&in, factor, &o, err))
            goto done;
        if (!out->planes) {
            *out = *e;
            out->nx = o.nx;
            out->ny = o.ny;
            out->os = o.os;
            if (!(out->planes = calloc((size_t)e->nterms * o.nx * o.ny, sizeof *out->planes))) {
                mp_psf_free(&o);
                snprintf(err, MP_ERRLEN, "psf build: out of memory");
                goto done;
            }
        }
        memcpy(out->planes + (size_t)t * o.nx * o.ny, o.t, (size_t)o.nx * o.ny * sizeof *o.t);
        mp_psf_free(&o);
    }
    rc = 0;
done:
    if (rc)
        mp_epsf_free(out);
    free(sh);
    free(tmp);
    return rc;
}

/* Add the PRF of table p at (x, y) with sign to canvas [1, cw] × [1, cw]. */
static int paint(const mp_psf *p, double x, double y, double sign, double *cv, int cw,
                 mp_prf_work *w)
{
    mp_prf_model m = {p, NULL, 10};
    long x0, y0;
    int bw, bh;
    mp_prf_box(&m, x, y, &x0, &y0, &bw, &bh);
    double *prf = malloc((size_t)bw * bh * sizeof *prf);
    if (!prf || mp_prf_render(&m, x, y, prf, NULL, NULL, w)) {
        free(prf);
        return 1;
    }
    for (int j = 0; j < bh; j++)
        for (int i = 0; i < bw; i++) {
            long px = x0 + i, py = y0 + j;
            if (px >= 1 && px <= cw && py >= 1 && py <= cw)
                cv[(size_t)(py - 1) * cw + (size_t)(px - 1)] += sign * prf[(size_t)j * bw + i];
        }
    free(prf);
    return 0;
}

/* The aliasing measure of table d (its block-sum to os_coarse against
 * itself), weighted by the noise of a star of E electrons whose PRF is
 * that of table p. */
static double alias_q(const mp_epsf *d, const mp_epsf *p, int os_coarse, double E, double B,
                      double ron)
{
    if (os_coarse >= d->os)
        return 0.0;
    char err[MP_ERRLEN];
    mp_epsf c;
    mp_psf tf, tc, tp;
    memset(&tf, 0, sizeof tf);
    memset(&tc, 0, sizeof tc);
    memset(&tp, 0, sizeof tp);
    double worst = INFINITY;
    if (d->os % os_coarse || mp_epsf_rebin(d, d->os / os_coarse, &c, err))
        return INFINITY;
    int cw = (int)(d->nx / d->os) + 8;
    double *P = calloc((size_t)cw * cw, sizeof *P), *D = calloc((size_t)cw * cw, sizeof *D);
    mp_prf_work w;
    memset(&w, 0, sizeof w);
    if (!P || !D || mp_epsf_table(d, d->x0, d->y0, &tf, err) ||
        mp_epsf_table(&c, c.x0, c.y0, &tc, err) || mp_epsf_table(p, p->x0, p->y0, &tp, err))
        goto done;
    worst = 0.0;
    for (int ph = 0; ph < 16; ph++) {
        double x = 0.5 * cw + 0.25 * (ph % 4), y = 0.5 * cw + 0.25 * (ph / 4);
        memset(P, 0, (size_t)cw * cw * sizeof *P);
        memset(D, 0, (size_t)cw * cw * sizeof *D);
        if (paint(&tp, x, y, 1.0, P, cw, &w) || paint(&tf, x, y, -1.0, D, cw, &w) ||
            paint(&tc, x, y, 1.0, D, cw, &w)) {
            worst = INFINITY;
            goto done;
        }
        double q = 0.0;
        for (size_t i = 0; i < (size_t)cw * cw; i++)
            q += D[i] * D[i] / (fmax(E * P[i], 0.0) + B + ron * ron);
        q = E * sqrt(q);
        worst = q > worst ? q : worst;
    }
done:
    free(P);
    free(D);
    mp_prf_work_free(&w);
    mp_psf_free(&tf);
    mp_psf_free(&tc);
    mp_psf_free(&tp);
    mp_epsf_free(&c);
    return worst;
}

double mp_epsf_oversamp_error(const mp_epsf *e, int os_coarse, double E, double B, double ron)
{
    return alias_q(e, e, os_coarse, E, B, ron);
}
