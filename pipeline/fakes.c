/* fakes.c — the artificial-star engine of `matphot fakes` (issue 13), the
 * way crowded-field users measure completeness (DAOPHOT addstar, DOLPHOT
 * fakes): the frame is reduced once (the stars it has), then each fake
 * star, drawn with the frame's PSF and its own photon noise, is added to
 * its own copy of a box of the frame around it and the box reduced again
 * with the same pipeline; the fake is found when a fitted star lies within
 * fakerad of it and nearer to it than to every star of the frame's own
 * reduction.  One fake per copy keeps the crowding as it is; fake k
 * depends on (seed, k) only, so the fakes run in parallel (OpenMP) and any
 * split into parts gives the rows of the whole run. */
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include "pipeline/fakes_priv.h"
#include "sim/sim.h"

/* Fake k's generator: its own stream, from (seed, k) alone. */
static void fake_rng(uint64_t seed, long k, mp_rng *r)
{
    mp_rng_seed(r, seed * 0x9E3779B97F4A7C15ULL + (uint64_t)k * 0xD1B54A32D192ED03ULL + 1);
}

/* The box of side `side` around (x, y), clipped to the frame; a copy of its
 * pixels and mask as a frame of its own (no header). */
static int cut_box(const mp_frame *f, double x, double y, long side, mp_frame *c, long *x0,
                   long *y0)
{
    long a = (long)floor(x) - side / 2, b = (long)floor(y) - side / 2;
    long a1 = a + side - 1, b1 = b + side - 1;
    a = a < 1 ? 1 : a;
    b = b < 1 ? 1 : b;
    a1 = a1 > f->im.nx ? f->im.nx : a1;
    b1 = b1 > f->im.ny ? f->im.ny : b1;
    memset(c, 0, sizeof *c);
    c->im.nx = a1 - a + 1;
    c->im.ny = b1 - b + 1;
    size_t n = (size_t)c->im.nx * (size_t)c->im.ny;
    c->im.pix = malloc(n * sizeof *c->im.pix);
    c->mask = malloc(n);
    if (!c->im.pix || !c->mask)
        return 1;
    for (long j = 0; j < c->im.ny; j++) {
        size_t src = (size_t)(b - 1 + j) * (size_t)f->im.nx + (size_t)(a - 1);
        memcpy(c->im.pix + (size_t)j * c->im.nx, f->im.pix + src, (size_t)c->im.nx * sizeof *c->im.pix);
        memcpy(c->mask + (size_t)j * c->im.nx, f->mask + src, (size_t)c->im.nx);
    }
    c->gain = f->gain;
    c->rdnoise = f->rdnoise;
    c->saturate = f->saturate;
    c->exptime = f->exptime;
    for (size_t i = 0; i < n; i++) {
        c->nbad += (c->mask[i] & MP_MASK_BAD) != 0;
        c->nsat += (c->mask[i] & MP_MASK_SATURATED) != 0;
    }
    *x0 = a;
    *y0 = b;
    return 0;
}

/* Add E·PRF at (x, y) (the box's own coordinates) with its photon noise;
 * a pixel pushed to SATURATE [ADU] is masked saturated, as the frame's
 * reader masks it. */
static int inject(mp_frame *c, const mp_prf_model *m, double x, double y, double E, mp_rng *r,
                  mp_prf_work *wk)
{
    long bx, by;
    int bw, bh;
    mp_prf_box(m, x, y, &bx, &by, &bw, &bh);
    double *p = malloc((size_t)bw * (size_t)bh * sizeof *p);
    if (!p || mp_prf_render(m, x, y, p, NULL, NULL, wk)) {
        free(p);
        return 1;
    }
    for (int j = 0; j < bh; j++)
        for (int i = 0; i < bw; i++) {
            long gx = bx + i, gy = by + j;
            if (gx < 1 || gy < 1 || gx > c->im.nx || gy > c->im.ny)
                continue;
            size_t k = (size_t)(gy - 1) * (size_t)c->im.nx + (size_t)(gx - 1);
            double mu = E * p[(size_t)j * bw + i];
            if (c->mask[k] & MP_MASK_BAD)
                continue;
            c->im.pix[k] += mu > 0 ? mp_rng_poisson(r, mu) : mu;
            if (isfinite(c->saturate) && c->im.pix[k] / c->gain >= c->saturate &&
                !(c->mask[k] & MP_MASK_SATURATED)) {
                c->mask[k] |= MP_MASK_SATURATED;
                c->nsat++;
            }
        }
    free(p);
    return 0;
}

/* Nearest of n points (px, py) to (x, y): its index (-1 when n is 0). */
static long nearest(const double *px, const double *py, long n, double x, double y, double *d)
{
    long best = -1;
    *d = INFINITY;
    for (long i = 0; i < n; i++) {
        double e = hypot(px[i] - x, py[i] - y);
        if (e < *d) {
            *d = e;
            best = i;
        }
    }
    return best;
}

/* Look for the fake in the box's reduction t (offsets x0, y0). */
static void look_for(const mp_table *t, long x0, long y0, const mp_fakes_base *b, double fakerad,
                     mp_fake *fk)
{
    int cx = mp_table_col(t, "XPSF_IMAGE"), cy = mp_table_col(t, "YPSF_IMAGE");
    int cm = mp_table_col(t, "MAG_PSF"), ce = mp_table_col(t, "MAGERR_PSF");
    int cf = mp_table_col(t, "FLAGS");
    fk->found = 0;
    fk->xf = fk->yf = fk->magf = fk->emag = NAN;
    fk->flags = 0;
    if (cx < 0 || cy < 0)
        return;
    long best = -1;
    double bd = fakerad;
    for (size_t r = 0; r < t->nrow; r++) {
        double x = mp_table_get(t, r, cx) + (double)(x0 - 1), y = mp_table_get(t, r, cy) + (double)(y0 - 1);
        double d = hypot(x - fk->x, y - fk->y);
        if (d <= bd) {
            bd = d;
            best = (long)r;
        }
    }
    if (best < 0)
        return;
    double x = mp_table_get(t, (size_t)best, cx) + (double)(x0 - 1);
    double y = mp_table_get(t, (size_t)best, cy) + (double)(y0 - 1);
    double db;
    nearest(b->x, b->y, b->n, x, y, &db);
    if (db < bd)
        return;          /* a star the frame has, not the fake */
    fk->found = 1;
    fk->xf = x;
    fk->yf = y;
    fk->magf = cm >= 0 ? mp_table_get(t, (size_t)best, cm) : NAN;
    fk->emag = ce >= 0 ? mp_table_get(t, (size_t)best, ce) : NAN;
    fk->flags = cf >= 0 ? (int)mp_table_get(t, (size_t)best, cf) : 0;
}

/* One fake: draw, cut, inject, reduce, look. */
static int one_fake(const mp_frame *f, const mp_pipeline_opts *o, const mp_fakes_opts *fo,
                    const mp_fakes_base *b, long k, mp_fake *fk, mp_prf_work *wk, char *err)
{
    mp_rng r;
    fake_rng(fo->seed, k, &r);
    fk->number = k + 1;
    fk->x = 0.5 + (double)f->im.nx * mp_rng_uniform(&r);
    fk->y = 0.5 + (double)f->im.ny * mp_rng_uniform(&r);
    fk->mag = fo->magmin + (fo->magmax - fo->magmin) * mp_rng_uniform(&r);
    double dnn;
    nearest(b->x, b->y, b->n, fk->x, fk->y, &dnn);
    fk->nn = dnn;
    mp_frame c;
    long x0, y0;
    int rc = cut_box(f, fk->x, fk->y, fo->box, &c, &x0, &y0);
    /* The box is a frame of its own: a variable PSF read at frame positions. */
    mp_pipeline_opts *lo = rc || !o->fit.psf.field ? NULL : malloc(sizeof *lo);
    if (lo) {
        *lo = *o;
        mp_fit_setup_local(&o->fit, (double)(x0 - 1), (double)(y0 - 1), &lo->fit);
    } else if (!rc && o->fit.psf.field) {
        rc = 1;
    }
    const mp_pipeline_opts *ob = lo ? lo : o;
    double E = pow(10.0, -0.4 * (fk->mag - o->fit.opts.magzero));
    if (!rc)
        rc = inject(&c, &ob->fit.model, fk->x - (double)(x0 - 1), fk->y - (double)(y0 - 1), E, &r, wk);
    if (rc)
        snprintf(err, MP_ERRLEN, "out of memory");
    mp_table t;
    mp_table_init(&t);
    if (!rc && !(rc = mp_pipeline_reduce(&c, ob, &t, NULL, err)))
        look_for(&t, x0, y0, b, fo->fakerad, fk);
    mp_table_free(&t);
    free(lo);
    free(c.im.pix);
    free(c.mask);
    return rc;
}

int mp_fakes_run(const mp_frame *f, const mp_pipeline_opts *o, const mp_fakes_opts *fo,
                 const mp_fakes_base *b, long lo, long hi, mp_fake *out, char *err)
{
    /* The boxes are one run: economy's tables pay for all their fits, at
     * least one per fake (fit/econ_plan.c), not for one box's few; all
     * parts' fakes, so that a part's fits are the whole run's. */
    mp_pipeline_opts *run = malloc(sizeof *run);
    if (!run) {
        snprintf(err, MP_ERRLEN, "out of memory");
        return 1;
    }
    *run = *o;
    run->fit.opts.fits = (double)fo->nfake;
    run->fit.opts.learn = 0;    /* boxes in parallel: no history */
    o = run;
    int failed = 0;
    char ferr[MP_ERRLEN] = "";
#pragma omp parallel
    {
        mp_prf_work wk = {0};
        char e[MP_ERRLEN];
#pragma omp for schedule(dynamic, 1)
        for (long k = lo; k < hi; k++) {
            int skip;
#pragma omp atomic read
            skip = failed;
            if (skip)
                continue;
            if (one_fake(f, o, fo, b, k, &out[k - lo], &wk, e)) {
#pragma omp critical(fakes_err)
                {
                    if (!ferr[0])
                        snprintf(ferr, sizeof ferr, "fake %ld: %.400s", k + 1, e);
#pragma omp atomic write
                    failed = 1;
                }
            }
        }
        mp_prf_work_free(&wk);
    }
    if (failed)
        snprintf(err, MP_ERRLEN, "%s", ferr);
    free(run);
    return failed;
}
