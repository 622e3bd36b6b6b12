/*
 * lm_group.h — inside fit/ only: the state of one group fit (mp_fit_group)
 * and the routines its files share: fit_group.c (start, outputs),
 * lm_pixels.c (fitted pixels), lm_render.c (the stars' PRFs), lm_model.c
 * (model, weights, deviance), lm_normal.c (normal equations), lm_frozen.c
 * (frozen wings), levmar.c (the LM loop), sky_test.c (the sky's order).
 */
#ifndef MATPHOT_FIT_LM_GROUP_H
#define MATPHOT_FIT_LM_GROUP_H

#include <math.h>
#include <stddef.h>
#include <stdint.h>
#include "fit/fit.h"

/* One star's rendered PRF and derivatives on the fitted pixels of its
 * window, rows [j0, j1) and columns [i0, i1) of the group box: row j0 + t
 * holds the packed pixels [pp[t], pp[t] + pn[t]) (the fitted pixels of a
 * row within a column range are consecutive in the packing), at
 * prf[pb[t] ...]. */
typedef struct {
    int i0, i1, j0, j1;
    int ci0, ci1, cj0, cj1;     /* its core while the wings are frozen (levmar) */
    int *pp, *pn, *pb;          /* bh each */
    int *dp0, *dp1;             /* bh each: row j0 + t's packed pixels where
                                 * dx, dy are drawn, [dp0[t], dp1[t]) (zero
                                 * beyond, not stored: lm_render.c) */
    double *prf, *dx, *dy;      /* cap each */
} rstar;

/* Everything one group fit needs; freed in one place. */
typedef struct {
    const mp_frame *f;
    const mp_prf_model *m;
    const mp_prf_crop *crop;    /* NULL: every star on its whole box */
    double crop_min;            /* never cropped inside its fitting region */
    int n, nsky, np;            /* nsky sky terms fitted (0: sky held fixed) */
    int npmax;                  /* parameters the arrays hold: 3n + 6 */
    long bx0, by0;              /* group box, 1-based, and size */
    int bw, bh;
    double xc, yc, hx, hy;      /* sky basis: u = (x − xc)/hx, v = (y − yc)/hy */
    double dlo, dhi, emax;      /* data range over the fitted pixels, and the
                                 * largest flux any star may take there */
    double ron2;                /* RON², at least 1e-2 so V > 0 */
    double vfloor;              /* S of V(m) = max(m, S) + RON², ≥ 0 */
    double sknown;              /* the sky the stars were found on, or NaN */
    double skylo, skyhi;        /* a plane or quadratic sky's range over the
                                 * fitted pixels, as model_of last drew it */
    double *modt;               /* npix: the last trial's model (levmar.c
                                 * render_trial), swapped with mod when the
                                 * step is taken: a refused one leaves mod
                                 * as it was, not drawn again */
    double tskylo, tskyhi;      /* that trial's sky range */
    uint8_t *sel;               /* bw*bh: pixel fitted */
    /* The fitted pixels packed row by row (issue 12: every per-pixel sum
     * and render runs over them only, not the box around them, which
     * holds about twice as many): runs of consecutive fitted pixels, run
     * r in box row rj[r], columns [ri0[r], ri1[r]), packed from rp[r];
     * row j's runs are rrow[j] .. rrow[j + 1] − 1, its first packed pixel
     * prow[j] (both bh + 1). */
    size_t npix;
    int nrun;
    int *rj, *ri0, *ri1, *rp, *rrow, *prow;
    double *dat, *mod, *var;    /* npix: data, model, V(m) */
    double *rv;                 /* npix: RON² + the error plane's extra
                                 * variance (mp_frame.xvar), the r of V */
    double *wt, *wres;          /* npix: 1/V, and 1/V·(d − m), for the
                                 * normal equations */
    double *basis;              /* 6 × npix: the sky basis at every pixel */
    mp_span *spans;             /* nrun: the spans a star is rendered on */
    size_t *soff;               /* nrun: where each span's values go (core renders) */
    /* Frozen wings (levmar): while set, a render redraws each star on its
     * core only, the rest of its window keeping the values drawn at
     * (fx, fy) — both buffers alike. */
    int freezing, frozen;       /* this fit freezes; frozen now */
    int outside;                /* the last trial left the sky's bounds */
    int skyheld;                /* the constant sky held on its bound in the
                                 * step now taken (levmar.c, bounded_step) */
    int skystall;               /* the last loop stalled on the sky's bounds
                                 * (levmar.c, LM_SKY_STALL) */
    int paired;                 /* the last loop brought two stars within
                                 * o->stop_pair (levmar.c) */
    double *rk;                 /* n: each star's fitting radius
                                 * (lm_pixels.c, star_radius) */
    double *sx;                 /* npmax: the step while a longer or shorter
                                 * one is tried (levmar.c, step_length) */
    double *psave;              /* npmax: a converged state kept while a
                                 * higher sky order is tried */
    double *fx, *fy;            /* n each */
    /* Settled stars (lm_settle.c): held where they are, not redrawn nor
     * summed, while the others go on. */
    uint8_t *settled;           /* n */
    uint8_t *moved;             /* n: redrawn by lm_refresh_movers */
    int *calm;                  /* n: steps running below tol */
    int nsettled;
    uint8_t *dwhole;            /* n: its derivatives drawn on its whole
                                 * window from now to the fit's end
                                 * (lm_render.c deriv_in_box) */
    uint8_t *ongrid;            /* n: star drawn from the phase grid (its
                                 * start flux within o->grid_emax), else
                                 * exactly (0; set with G->work.grid);
                                 * GRID_CUBIC, or a cheaper mode while its
                                 * flux stays within that mode's limit in
                                 * tiers (lm_render.c grid_mode) */
    mp_prf_tiers tiers;         /* o->grid_tiers */
    /* Star pairs between exact normal equations (normal_equations): the
     * pairs whose windows meet, each pair's sums outside its core (9 a
     * pair, unscaled), and each star's core, [cx0, cx1) × [cy0, cy1) of
     * the box (n each); core_hw ≤ 0: every pass exact. */
    int npair, cappair, ne_exact;
    int *pk, *pl;
    double *tail;
    double *pfull;              /* 9 a pair: its whole sums (NE_REUSE) */
    double *pk2;                /* a pair: its largest normalised coupling²
                                 * when last summed exactly (lm_normal.c) */
    double *ppos;               /* 4 a pair: both stars' x, y then */
    int pairs_known;            /* an exact pass listed the pairs in this fit */
    int weak_pairs;             /* mp_fit_opts.weak_pairs */
    double *stail;              /* 27 a star: its sky and self sums outside its core */
    int *cx0, *cx1, *cy0, *cy1;
    double core_hw;
    int stats;                  /* mp_fit_opts.stats */
    size_t cap;                 /* per-star capacity (packed pixels) */
    size_t boxcap;              /* an exact render's box (scr: 3 of them) */
    double *scr;
    rstar *cur, *trial;
    double *p, *pt, *A, *g, *M, *step;
    mp_prf_work work;
} group;

static inline double pixel(const group *G, long x, long y)
{
    return G->f->im.pix[(size_t)(y - 1) * G->f->im.nx + (size_t)(x - 1)];
}

/* RON² plus what the frame's error plane holds beyond it and the Poisson
 * noise, at pixel (x, y). */
static inline double ron2_at(const group *G, long x, long y)
{
    const float *xv = G->f->xvar;
    return G->ron2 + (xv ? (double)xv[(size_t)(y - 1) * G->f->im.nx + (size_t)(x - 1)] : 0.0);
}

/* The packed index of the first fitted pixel at or after column i of box
 * row j. */
static inline int packed_at(const group *G, int j, int i)
{
    for (int q = G->rrow[j]; q < G->rrow[j + 1]; q++) {
        if (i <= G->ri0[q])
            return G->rp[q];
        if (i < G->ri1[q])
            return G->rp[q] + (i - G->ri0[q]);
    }
    return G->prow[j + 1];
}

/* Sky terms of order 0, 1, 2: 1, 3, 6. */
static inline int nsky_of(int order)
{
    return order <= 0 ? 1 : (order == 1 ? 3 : 6);
}

/* The sky basis at (x, y): 1, u, v, u² − 1/3, uv, v² − 1/3, with u, v the
 * offsets from the box centre scaled to [−1, 1].  Scaled and centred (u²
 * has mean about 1/3 over the box) so the normal equations stay well
 * conditioned and one bound fits every coefficient's step. */
static inline void sky_basis(const group *G, double x, double y, double c[6])
{
    double u = (x - G->xc) / G->hx, v = (y - G->yc) / G->hy;
    c[0] = 1.0;
    c[1] = u;
    c[2] = v;
    c[3] = u * u - 1.0 / 3.0;
    c[4] = u * v;
    c[5] = v * v - 1.0 / 3.0;
}

static inline double sky_at(const group *G, const double *p, double x, double y)
{
    if (G->nsky <= 1)
        return p[3 * G->n];      /* constant, or fixed (kept in the first sky slot) */
    double c[6], s = 0.0;
    sky_basis(G, x, y, c);
    for (int a = 0; a < G->nsky; a++)
        s += p[3 * G->n + a] * c[a];
    return s;
}

/* Render every star of parameter vector p into r, on the fitted pixels of
 * its window only (the group's box, the star's PRF box and its crop
 * radius): the fit pays for its fitting region, not for the PSF's wings,
 * nor for the pixels between the stars' fitting radii.  what: RENDER_ALL,
 * or, from the phase grid, RENDER_PRF (a trial step: D needs the PRF
 * only, and a third of the trials are refused) and RENDER_DERIVS (the
 * derivatives of a step taken, whose PRF is there); exact renders always
 * draw all three. */
enum { RENDER_ALL, RENDER_PRF, RENDER_DERIVS };

/* group.ongrid's values of a star drawn from the grid: 1 + its mode
 * (mp_prf_cache_render's): cubically, bilinearly, core tier k. */
enum { GRID_CUBIC = 1 + MP_PRF_CUBIC, GRID_LIN = 1 + MP_PRF_BILINEAR };
#define GRID_CORE(k) (1 + MP_PRF_CORE(k))

/* lm_render.c.  lm_render_all: every star of p into r on its window (or
 * core, while frozen); nonzero when a window overflows its buffers.
 * lm_core_rows: star r's core as spans (G->spans, offsets G->soff), its
 * box clipped to the window in c; returns the number of spans. */
int lm_render_all(group *G, const double *p, rstar *r, int what);
/* lm_render.c: star k of p into r[k] on its whole window, frozen or not;
 * nonzero when the window overflows its buffers. */
int lm_render_star(group *G, const double *p, rstar *r, int k);
int lm_core_rows(group *G, const rstar *r, int c[4]);
/* lm_render.c: lm_core_rows for the box b (box columns b[0]..b[1] − 1,
 * rows b[2]..b[3] − 1) in place of the core. */
int lm_box_rows(group *G, const rstar *r, const int b[4], int c[4]);

/* lm_render.c: render src copied into dst (dst's own arrays kept). */
void lm_render_copy(rstar *dst, const rstar *src);

/* lm_model.c.  lm_model_of: the model of p with renders r into G->mod.
 * lm_variance_of: V(m) into G->var.  lm_deviance_of: D of G->mod.
 * lm_chi2_with: Σ (d − m)²/var. */
void lm_model_of(group *G, const double *p, const rstar *r);
void lm_variance_of(group *G);
double lm_deviance_of(const group *G);
double lm_chi2_with(const group *G, const double *var);

/* How lm_normal_equations sums: the pairs over their cores only (between
 * steps), everything exact, every star's own terms exact, or, between
 * steps, the terms of the stars in G->moved and of their pairs exact
 * (their wings just redrawn: lm_refresh_movers); or everything exact with
 * the pairs' sums those of the last exact pass, when nothing but the sky
 * order has changed since (NE_REUSE). */
enum { NE_STEER, NE_EXACT, NE_STARS, NE_MOVERS, NE_REUSE };

/* lm_normal.c: A and g at p (exact: NE_EXACT, NE_STEER, NE_STARS,
 * NE_MOVERS or NE_REUSE);
 * nonzero when out of memory. */
int lm_normal_equations(group *G, const double *p, const rstar *r, int exact);

/* lm_frozen.c.  lm_freezing_pays: whether the windows hold enough more
 * than the cores.  lm_freeze: freeze every star's wings where it is.
 * lm_moved_far: a star moved far from where its wings were drawn.
 * lm_refresh: every open star redrawn at G->p (the settled ones opened
 * and redrawn too when open), D in *D, exact normal equations, frozen
 * again when again; nonzero when out of memory. */
int lm_freezing_pays(group *G);
/* lm_frozen.c: the box (columns b[0]..b[1] − 1, rows b[2]..b[3] − 1 of the
 * group box) within mp_fit_core_halfwidth px of (x, y): a star's core
 * there. */
void lm_box_at(const group *G, double x, double y, int b[4]);
/* lm_frozen.c: that half-width, mp_fit_core_halfwidth of the fit's fitrad
 * (NaN when the group is fitted on the whole frame). */
double lm_box_halfwidth(const group *G);
void lm_freeze(group *G);
int lm_moved_far(const group *G);
int lm_refresh(group *G, double *D, int again, int open);
/* lm_frozen.c: only the open stars that moved far redrawn and frozen
 * again where they are, D in *D, the normal equations with their terms
 * and pairs exact (NE_MOVERS); nonzero when out of memory. */
int lm_refresh_movers(group *G, double *D);

/* lm_settle.c.  lm_calm_update: each open star's calm count after a step
 * taken (its step in σ, times scale, below tol; none when cut).
 * lm_settle: the calm stars settled, their renders copied into the trial
 * buffers, from the fit's it-th step on (never unless o->settle).
 * lm_unsettle: every star open again (their calm counts cleared too with
 * calm_too). */
void lm_calm_update(group *G, double scale, int cut, double tol);
void lm_settle(group *G, const mp_fit_opts *o, int it);
void lm_unsettle(group *G, int calm_too);

/* levmar.c: LM from G->p (frozen wings unless o->exact_lm), accepted
 * steps added to *iter; rose: only the sky order has changed since the
 * last lm_levmar ended (its pairs' sums are kept); G->skystall set when
 * it ended stalled on the sky's bounds (not converged); nonzero when out
 * of memory. */
int lm_levmar(group *G, const mp_fit_opts *o, int rose, int *iter, int *converged);

/* Whether the plane or quadratic sky of the last lm_model_of stays within
 * the bounds a step must keep (levmar.c): 1 for a constant sky. */
int lm_sky_in_bounds(const group *G);

/* sky_test.c: under MP_SKY_AUTO, the higher sky order the data ask for
 * at a converged fit of order 0 or 1 in *to, or -1; nonzero when out of
 * memory. */
int lm_higher_order(group *G, int order, double fitrad, int *to);

/* lm_pixels.c: the group box, its fitted pixels (packed) and the flags
 * they set on st; 1 when no pixel, 2 when out of memory. */
int lm_select_pixels(group *G, const mp_fit_opts *o, mp_star *st);

#endif
