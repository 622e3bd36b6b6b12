/*
 * run.c — one setting on one scene: every star fitted once, CPU seconds of
 * the fits only (CLOCK_PROCESS_CPUTIME_ID: the program runs with one
 * OpenMP and one BLAS thread, so this is the fit's own CPU).
 *
 * Single-star scenes: one mp_fit_group per frame (as tests/validate), for
 * the stars [k0, k1) (the caller interleaves the settings in chunks); in
 * the economy=yes/no mode one mp_fit_table per frame (run_single_table).
 * Crowded: a table of start values (NUMBER, X_IMAGE, Y_IMAGE, FLUX), grouped
 * by mp_group_table (fitrad of the setting, psfrad 10, maxgroup of the
 * setting; not timed), then mp_fit_table with mp_frame_opts_default and the
 * setting's fitrad, tol, maxiter (timed).  Stars merged away or rejected
 * leave the table: they come back as NaN ("lost").  k0, k1 are ignored.
 */
#include <math.h>
#include <stdlib.h>
#include <string.h>
#include <time.h>
#include "group/group.h"
#include "tests/bench/sweep/sw.h"

static double cpu_now(void)
{
    struct timespec ts;
    clock_gettime(CLOCK_PROCESS_CPUTIME_ID, &ts);
    return (double)ts.tv_sec + 1e-9 * (double)ts.tv_nsec;
}

void sw_result_free(sw_result *r)
{
    free(r->x);
    free(r->y);
    free(r->f);
    free(r->flags);
    r->x = r->y = r->f = NULL;
    r->flags = NULL;
}

static int result_alloc(sw_result *r, int n)
{
    if (r->x)
        return 0;
    r->x = malloc((size_t)n * sizeof *r->x);
    r->y = malloc((size_t)n * sizeof *r->y);
    r->f = malloc((size_t)n * sizeof *r->f);
    r->flags = malloc((size_t)n * sizeof *r->flags);
    if (!r->x || !r->y || !r->f || !r->flags) {
        sw_result_free(r);
        return 1;
    }
    return 0;
}

static void frame_init(mp_frame *f, const sw_scene *sc, uint8_t *mask)
{
    memset(f, 0, sizeof *f);
    f->im.nx = sc->fnx;
    f->im.ny = sc->fny;
    f->im.pix = sc->img;
    f->mask = mask;
    f->gain = 1.0;
    f->rdnoise = SW_RON;
    f->saturate = INFINITY;
    f->exptime = 1.0;
}

static int run_single(const sw_scene *sc, const mp_prf_model *m, const sw_setting *st,
                      int k0, int k1, sw_result *r, int record, double *cpu, char *err)
{
    uint8_t *mask = calloc(SW_NPIX, 1);
    if (!mask) {
        snprintf(err, MP_ERRLEN, "out of memory");
        return 1;
    }
    mp_frame f;
    frame_init(&f, sc, mask);
    mp_fit_opts o;
    if (st->fopts)
        o = st->fopts->fit;
    else
        mp_fit_opts_default(&o);
    o.fitrad = st->fitrad;
    o.tol = st->tol;
    o.maxiter = st->maxiter;
    long iters = 0;
    int rc = 0;
    double t0 = cpu_now();
    for (int k = k0; k < k1; k++) {
        f.im.pix = sc->img + (size_t)k * SW_NPIX;
        mp_star s;
        memset(&s, 0, sizeof s);
        s.x = sc->t[k].x0;
        s.y = sc->t[k].y0;
        s.flux = NAN;
        mp_prf_model mk = *m;
        if (st->choice)
            mk.sinc_hw = mp_sinc_choice_pick(st->emax, st->choice->hwmax, sc->t[k].e);
        if (record)
            r->hwsum += mk.sinc_hw;
        if (mp_fit_group(&f, &mk, &o, NAN, &s, 1, err)) {
            rc = 1;
            break;
        }
        if (record) {
            r->x[k] = s.x;
            r->y[k] = s.y;
            r->f[k] = s.flux;
            r->flags[k] = s.flags;
            iters += s.niter;
        }
    }
    *cpu = cpu_now() - t0;
    if (record)
        r->iters += iters;
    free(mask);
    return rc;
}

/* Economy=yes/no mode (st->fopts): each frame through mp_fit_table, the
 * path of `matphot fit`, with a one-row table (NUMBER, X_IMAGE, Y_IMAGE,
 * FLUX = f0, find's stand-in), so every economy decision of the frame fit
 * (table sampling and kernel per group, crop, refits) applies as it does
 * from the command line. */
static int run_single_table(const sw_scene *sc, const mp_prf_model *m, const sw_setting *st,
                            int k0, int k1, sw_result *r, int record, double *cpu, char *err)
{
    uint8_t *mask = calloc(SW_NPIX, 1);
    if (!mask) {
        snprintf(err, MP_ERRLEN, "out of memory");
        return 1;
    }
    mp_frame f;
    frame_init(&f, sc, mask);
    mp_frame_opts fo = *st->fopts;
    fo.fit.fitrad = st->fitrad;
    fo.fit.tol = st->tol;
    fo.fit.maxiter = st->maxiter;
    static const char *const in[4] = {"NUMBER", "X_IMAGE", "Y_IMAGE", "FLUX"};
    int rc = 0;
    double t0 = cpu_now();
    for (int k = k0; k < k1 && !rc; k++) {
        f.im.pix = sc->img + (size_t)k * SW_NPIX;
        mp_table t;
        mp_table_init(&t);
        double v[4] = {k + 1, sc->t[k].x0, sc->t[k].y0, sc->t[k].f0};
        long row = -1;
        for (int c = 0; c < 4 && !rc; c++)
            rc = mp_table_add_col(&t, in[c]) < 0;
        if (!rc && (row = mp_table_add_row(&t)) < 0)
            rc = 1;
        for (int c = 0; c < 4 && !rc; c++)
            mp_table_set(&t, (size_t)row, c, v[c]);
        if (rc)
            snprintf(err, MP_ERRLEN, "out of memory");
        mp_frame_report rep;
        if (!rc && mp_fit_table(&f, m, &fo, &t, &rep, err))
            rc = 1;
        if (!rc && record) {
            int px = mp_table_col(&t, "XPSF_IMAGE"), py = mp_table_col(&t, "YPSF_IMAGE"),
                pf = mp_table_col(&t, "FLUX_PSF"), pg = mp_table_col(&t, "FLAGS");
            int ok = t.nrow == 1 && px >= 0 && py >= 0 && pf >= 0 && pg >= 0;
            double fl = ok ? mp_table_get(&t, 0, pg) : 0.0;
            r->x[k] = ok ? mp_table_get(&t, 0, px) : NAN;
            r->y[k] = ok ? mp_table_get(&t, 0, py) : NAN;
            r->f[k] = ok ? mp_table_get(&t, 0, pf) : NAN;
            r->flags[k] = isfinite(fl) ? (int)fl : 0;
            r->iters += rep.iterations;
            r->coarse += rep.kcoarse;
        }
        mp_table_free(&t);
    }
    *cpu = cpu_now() - t0;
    free(mask);
    return rc;
}

static int run_crowded(const sw_scene *sc, const mp_prf_model *m, const sw_setting *st,
                       sw_result *r, int record, double *cpu, char *err)
{
    mp_table t;
    mp_table_init(&t);
    uint8_t *mask = calloc((size_t)sc->fnx * sc->fny, 1);
    int rc = 1;
    if (!mask) {
        snprintf(err, MP_ERRLEN, "out of memory");
        goto done;
    }
    int cn = mp_table_add_col(&t, "NUMBER"), cx = mp_table_add_col(&t, "X_IMAGE"),
        cy = mp_table_add_col(&t, "Y_IMAGE"), cf = mp_table_add_col(&t, "FLUX");
    if (cn < 0 || cx < 0 || cy < 0 || cf < 0) {
        snprintf(err, MP_ERRLEN, "out of memory");
        goto done;
    }
    for (int k = 0; k < sc->n; k++) {
        long row = mp_table_add_row(&t);
        if (row < 0) {
            snprintf(err, MP_ERRLEN, "out of memory");
            goto done;
        }
        mp_table_set(&t, (size_t)row, cn, k + 1);
        mp_table_set(&t, (size_t)row, cx, sc->t[k].x0);
        mp_table_set(&t, (size_t)row, cy, sc->t[k].y0);
        mp_table_set(&t, (size_t)row, cf, sc->t[k].f0);
    }
    mp_group_opts go;
    mp_group_opts_default(&go);
    go.fitrad = st->fitrad;
    go.psfrad = SW_PSFRAD;
    go.maxgroup = st->maxgroup;
    if (mp_group_table(&t, &go, err))
        goto done;
    mp_frame f;
    frame_init(&f, sc, mask);
    mp_frame_opts fo;
    if (st->fopts)
        fo = *st->fopts;
    else
        mp_frame_opts_default(&fo);
    fo.fit.fitrad = st->fitrad;
    fo.fit.tol = st->tol;
    fo.fit.maxiter = st->maxiter;
    mp_frame_report rep;
    double t0 = cpu_now();
    int frc = mp_fit_table(&f, m, &fo, &t, &rep, err);
    *cpu = cpu_now() - t0;
    if (frc)
        goto done;
    if (record) {
        for (int k = 0; k < sc->n; k++) {
            r->x[k] = r->y[k] = r->f[k] = NAN;
            r->flags[k] = 0;
        }
        int cn2 = mp_table_col(&t, "NUMBER"), px = mp_table_col(&t, "XPSF_IMAGE"),
            py = mp_table_col(&t, "YPSF_IMAGE"), pf = mp_table_col(&t, "FLUX_PSF"),
            pg = mp_table_col(&t, "FLAGS");
        if (cn2 < 0 || px < 0 || py < 0 || pf < 0 || pg < 0) {
            snprintf(err, MP_ERRLEN, "mp_fit_table left out a column");
            goto done;
        }
        for (size_t i = 0; i < t.nrow; i++) {
            double num = mp_table_get(&t, i, cn2);
            long k = isfinite(num) ? lround(num) - 1 : -1;
            if (k < 0 || k >= sc->n) {
                snprintf(err, MP_ERRLEN, "mp_fit_table returned row %zu with NUMBER %g", i + 1, num);
                goto done;
            }
            r->x[k] = mp_table_get(&t, i, px);
            r->y[k] = mp_table_get(&t, i, py);
            r->f[k] = mp_table_get(&t, i, pf);
            double fl = mp_table_get(&t, i, pg);
            r->flags[k] = isfinite(fl) ? (int)fl : 0;
        }
        r->iters = rep.iterations;
    }
    rc = 0;
done:
    mp_table_free(&t);
    free(mask);
    return rc;
}

int sw_run(const sw_scene *sc, const sw_setting *st, int k0, int k1, sw_result *r, int record,
           double *cpu, char *err)
{
    if (record && result_alloc(r, sc->n)) {
        snprintf(err, MP_ERRLEN, "out of memory");
        return 1;
    }
    mp_prf_model m = {&sc->tab[st->tab], sc->drf.k > 0 ? &sc->drf : NULL, st->hw};
    const mp_prf_model *pm = st->model ? st->model : &m;
    if (sc->kind == SW_CROWDED)
        return run_crowded(sc, pm, st, r, record, cpu, err);
    if (st->fopts && !st->choice)
        return run_single_table(sc, pm, st, k0, k1, r, record, cpu, err);
    return run_single(sc, pm, st, k0, k1, r, record, cpu, err);
}
