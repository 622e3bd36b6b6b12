/* ss_choice.c — supersampling matched to the star (issue 10): a coarser
 * block-sum of the PSF table wherever its error is provably far below the
 * star's photon noise, the table as given elsewhere.
 *
 * Paper §5.4's rule (a 1× table is on the Cramér–Rao bound from β = 21 px²
 * on) was derived for Gaussians; a diffraction-limited PSF holds power up
 * to its cutoff 1/(λ/D) cycles/px whatever its β, and a coarse table of it
 * aliases.  So the error is measured on THIS PSF, as fit/sinc_choice.c does
 * for the kernel length: δP = PRF(coarse table) − PRF(given table), both
 * shifted with the model's full sinc kernel, at a 4×4 grid of subpixel
 * phases, and the same Cauchy–Schwarz bound in the fit's weights,
 *     q(E) = E·max_phase sqrt(Σ δP² / (E P + B + RON²)),
 * bounds |bias|/σ_CRLB of flux, position and sky at once (linearised).  A
 * group (or a painted star) uses the coarse table when q at its brightest
 * star is ≤ frac; q grows with E, so bright stars keep the fine table.
 * The table is held in the mp_sinc_choice layout with one "half-width",
 * so mp_sinc_choice_bound(&lv->bound, 0, E, B, ron) is q. */
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include "fit/fit.h"

#define NPH_AXIS 4

void mp_ss_level_free(mp_ss_level *lv)
{
    if (!lv)
        return;
    mp_psf_free(&lv->psf);
    mp_psf_field_free(&lv->field);
    mp_sinc_choice_free(&lv->bound);
    mp_sinc_choice_free(&lv->sinc);
    memset(lv, 0, sizeof *lv);
}

/* The union of the two models' boxes for a star at (x, y). */
static void union_box(const mp_prf_model *a, const mp_prf_model *b, double x, double y,
                      long *x0, long *y0, int *w, int *h)
{
    long ax, ay, bx, by;
    int aw, ah, bw, bh;
    mp_prf_box(a, x, y, &ax, &ay, &aw, &ah);
    mp_prf_box(b, x, y, &bx, &by, &bw, &bh);
    *x0 = ax < bx ? ax : bx;
    *y0 = ay < by ? ay : by;
    long x1 = ax + aw > bx + bw ? ax + aw : bx + bw, y1 = ay + ah > by + bh ? ay + ah : by + bh;
    *w = (int)(x1 - *x0);
    *h = (int)(y1 - *y0);
}

/* Render m at (x, y) and add sign × it onto the box (x0, y0, w) in out. */
static int add_render(const mp_prf_model *m, double x, double y, double sign, long x0, long y0,
                      int w, double *out, double *buf, mp_prf_work *wk)
{
    long bx, by;
    int bw, bh;
    mp_prf_box(m, x, y, &bx, &by, &bw, &bh);
    if (mp_prf_render(m, x, y, buf, NULL, NULL, wk))
        return 1;
    for (int j = 0; j < bh; j++)
        for (int i = 0; i < bw; i++)
            out[(size_t)(by - y0 + j) * w + (size_t)(bx - x0 + i)] += sign * buf[(size_t)j * bw + i];
    return 0;
}

/* The δP table of coarse against fine (see the top of the file). */
static int bound_build(const mp_prf_model *fine, const mp_prf_model *coarse, mp_sinc_choice *c,
                       char *err)
{
    memset(c, 0, sizeof *c);
    c->hwmax = 1;
    c->nph = NPH_AXIS * NPH_AXIS;
    size_t big = 0;
    for (int ph = 0; ph < c->nph; ph++) {
        long x0, y0;
        int w, h;
        union_box(fine, coarse, 1000.0 + (double)(ph % NPH_AXIS) / NPH_AXIS,
                  1000.0 + (double)(ph / NPH_AXIS) / NPH_AXIS, &x0, &y0, &w, &h);
        big = (size_t)w * (size_t)h > big ? (size_t)w * (size_t)h : big;
    }
    c->npix = big;
    c->p = calloc(big * (size_t)c->nph, sizeof *c->p);
    c->d2 = calloc(big * (size_t)c->nph, sizeof *c->d2);
    double *buf = malloc(big * sizeof *buf);
    mp_prf_work wk = {0};
    int rc = 1;
    if (!c->p || !c->d2 || !buf) {
        snprintf(err, MP_ERRLEN, "out of memory for the supersampling table");
        goto done;
    }
    for (int ph = 0; ph < c->nph; ph++) {
        double x = 1000.0 + (double)(ph % NPH_AXIS) / NPH_AXIS;
        double y = 1000.0 + (double)(ph / NPH_AXIS) / NPH_AXIS;
        long x0, y0;
        int w, h;
        union_box(fine, coarse, x, y, &x0, &y0, &w, &h);
        double *p = c->p + (size_t)ph * big, *d = c->d2 + (size_t)ph * big;
        if (add_render(fine, x, y, +1.0, x0, y0, w, p, buf, &wk) ||
            add_render(coarse, x, y, +1.0, x0, y0, w, d, buf, &wk) ||
            add_render(fine, x, y, -1.0, x0, y0, w, d, buf, &wk)) {
            snprintf(err, MP_ERRLEN, "out of memory rendering the PRF");
            goto done;
        }
        for (size_t i = 0; i < (size_t)w * h; i++)
            d[i] *= d[i];
    }
    rc = 0;
done:
    free(buf);
    mp_prf_work_free(&wk);
    if (rc)
        mp_sinc_choice_free(c);
    return rc;
}

int mp_ss_level_build(const mp_prf_model *m, int factor, mp_ss_level *lv, char *err)
{
    memset(lv, 0, sizeof *lv);
    if (mp_psf_rebin(m->psf, factor, &lv->psf, err))
        return 1;
    lv->model = *m;
    lv->model.psf = &lv->psf;
    if (bound_build(m, &lv->model, &lv->bound, err) ||
        mp_sinc_choice_build(&lv->model, &lv->sinc, err)) {
        mp_ss_level_free(lv);
        return 1;
    }
    return 0;
}

double mp_ss_level_emax(const mp_ss_level *lv, double B, double ron, double frac)
{
    double emax = 0.0;
    mp_sinc_choice_limits(&lv->bound, B, ron, frac, &emax);
    return emax;
}
