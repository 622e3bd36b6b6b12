/* levmar.c — fitting a group of stars and its sky by Levenberg–Marquardt
 * (design.md §5).  Weights are 1/(m_i + RON²) from the current model and
 * are held fixed within each step, so the fixed point solves the unbiased
 * estimating equation Σ (d − m)/σ² ∂m/∂p = 0 rather than minimising a χ²
 * whose weights move with the parameters (which would bias faint fluxes
 * by about β/2 electrons). */
#include <lapacke.h>
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include "fit/fit.h"

void mp_fit_opts_default(mp_fit_opts *o)
{
    o->sky_order = 0;
    o->fitrad = NAN;
    o->tol = 1e-3;
    o->maxiter = 50;
    o->fit_sky = 1;
    o->crop = NULL;
}

/* One star's rendered PRF and derivatives on its box. */
typedef struct {
    long x0, y0;
    int w, h;
    double *prf, *dx, *dy;
} rstar;

/* Everything one group fit needs; freed in one place. */
typedef struct {
    const mp_frame *f;
    const mp_prf_model *m;
    const mp_prf_crop *crop;    /* NULL: every star on its whole box */
    double crop_min;            /* never cropped inside its fitting region */
    int n, nsky, np;
    long bx0, by0;              /* group box, 1-based, and size */
    int bw, bh;
    double xc, yc;              /* sky-plane reference point */
    uint8_t *sel;               /* bw*bh: pixel fitted */
    size_t npix;
    double *mod, *var;          /* bw*bh */
    size_t cap;                 /* per-star box capacity */
    rstar *cur, *trial;
    double *p, *pt, *A, *g, *M, *step;
    mp_prf_work work;
} group;

static void group_free(group *G)
{
    free(G->sel);
    free(G->mod);
    free(G->var);
    for (int s = 0; s < 2; s++) {
        rstar *r = s ? G->trial : G->cur;
        if (!r)
            continue;
        for (int k = 0; k < G->n; k++) {
            free(r[k].prf);
            free(r[k].dx);
            free(r[k].dy);
        }
        free(r);
    }
    free(G->p);
    free(G->pt);
    free(G->A);
    free(G->g);
    free(G->M);
    free(G->step);
    mp_prf_work_free(&G->work);
}

static double pixel(const group *G, long x, long y)
{
    return G->f->im.pix[(size_t)(y - 1) * G->f->im.nx + (size_t)(x - 1)];
}

/* Render every star of parameter vector p into r, on the group's box only:
 * the fit pays for its fitting region, not for the PSF's wings. */
static int render_all(group *G, const double *p, rstar *r)
{
    for (int k = 0; k < G->n; k++) {
        double x = p[3 * k + 1], y = p[3 * k + 2];
        long x0, y0;
        int w, h;
        mp_prf_box(G->m, x, y, &x0, &y0, &w, &h);
        if ((size_t)(w < G->bw ? w : G->bw) * (size_t)(h < G->bh ? h : G->bh) > G->cap)
            return 1;
        /* Economy: only out to where the star's light is below a fraction
         * of the noise (fit_frame.c subtracts neighbours the same way). */
        long wx0 = G->bx0, wy0 = G->by0, wx1 = G->bx0 + G->bw, wy1 = G->by0 + G->bh;
        double rad = mp_prf_crop_radius(G->crop, p[3 * k], p[3 * G->n]);
        if (isfinite(rad)) {
            rad = rad > G->crop_min ? rad : G->crop_min;
            long a = (long)ceil(x - rad), b = (long)ceil(y - rad);
            long c = (long)floor(x + rad) + 1, d = (long)floor(y + rad) + 1;
            wx0 = a > wx0 ? a : wx0;
            wy0 = b > wy0 ? b : wy0;
            wx1 = c < wx1 ? c : wx1;
            wy1 = d < wy1 ? d : wy1;
            wx1 = wx1 > wx0 ? wx1 : wx0;
            wy1 = wy1 > wy0 ? wy1 : wy0;
        }
        if (mp_prf_render_window(G->m, x, y, wx0, wy0, wx1 - wx0, wy1 - wy0, &r[k].x0, &r[k].y0,
                                 &r[k].w, &r[k].h, r[k].prf, r[k].dx, r[k].dy, &G->work))
            return 1;
    }
    return 0;
}

static double sky_at(const group *G, const double *p, double x, double y)
{
    if (!G->nsky)
        return p[3 * G->n];      /* fixed sky is kept in the first sky slot */
    double s = p[3 * G->n];
    if (G->nsky == 3)
        s += p[3 * G->n + 1] * (x - G->xc) + p[3 * G->n + 2] * (y - G->yc);
    return s;
}

/* Intersection of star box r with the group box, in group-box coordinates. */
static int clip(const group *G, const rstar *r, int *i0, int *i1, int *j0, int *j1)
{
    *i0 = (int)(r->x0 > G->bx0 ? r->x0 - G->bx0 : 0);
    *j0 = (int)(r->y0 > G->by0 ? r->y0 - G->by0 : 0);
    long ie = r->x0 + r->w - G->bx0, je = r->y0 + r->h - G->by0;
    *i1 = (int)(ie < G->bw ? ie : G->bw);
    *j1 = (int)(je < G->bh ? je : G->bh);
    return *i0 < *i1 && *j0 < *j1;
}

static void model_of(group *G, const double *p, const rstar *r)
{
    for (int j = 0; j < G->bh; j++)
        for (int i = 0; i < G->bw; i++)
            G->mod[(size_t)j * G->bw + i] = sky_at(G, p, (double)(G->bx0 + i), (double)(G->by0 + j));
    for (int k = 0; k < G->n; k++) {
        int i0, i1, j0, j1;
        if (!clip(G, &r[k], &i0, &i1, &j0, &j1))
            continue;
        double E = p[3 * k];
        for (int j = j0; j < j1; j++) {
            const double *pr = r[k].prf + (size_t)(j + G->by0 - r[k].y0) * r[k].w + (G->bx0 - r[k].x0);
            double *mr = G->mod + (size_t)j * G->bw;
            for (int i = i0; i < i1; i++)
                mr[i] += E * pr[i];
        }
    }
}

/* Weights from the model: σ² = m + RON², floored so a zero model with no
 * read noise cannot give an infinite weight. */
static void variance_of(group *G)
{
    double ron2 = G->f->rdnoise * G->f->rdnoise;
    size_t nb = (size_t)G->bw * G->bh;
    for (size_t i = 0; i < nb; i++) {
        double v = (G->mod[i] > 0 ? G->mod[i] : 0.0) + ron2;
        G->var[i] = v > 1e-2 ? v : 1e-2;
    }
}

static double chi2_with(const group *G, const double *var)
{
    double c = 0.0;
    for (int j = 0; j < G->bh; j++)
        for (int i = 0; i < G->bw; i++) {
            size_t o = (size_t)j * G->bw + i;
            if (!G->sel[o])
                continue;
            double r = pixel(G, G->bx0 + i, G->by0 + j) - G->mod[o];
            c += r * r / var[o];
        }
    return c;
}

/* Normal equations A = JᵀWJ and g = JᵀW(d − m) at the current model. */
static void normal_equations(group *G, const double *p, const rstar *r)
{
    int np = G->np, n = G->n;
    memset(G->A, 0, (size_t)np * np * sizeof *G->A);
    memset(G->g, 0, (size_t)np * sizeof *G->g);
    int s0 = 3 * n;
    /* Sky columns and the data term over all fitted pixels. */
    for (int j = 0; j < G->bh; j++)
        for (int i = 0; i < G->bw; i++) {
            size_t o = (size_t)j * G->bw + i;
            if (!G->sel[o])
                continue;
            double w = 1.0 / G->var[o];
            double res = pixel(G, G->bx0 + i, G->by0 + j) - G->mod[o];
            double c[3] = {1.0, G->bx0 + i - G->xc, G->by0 + j - G->yc};
            for (int a = 0; a < G->nsky; a++) {
                G->g[s0 + a] += w * c[a] * res;
                for (int b = a; b < G->nsky; b++)
                    G->A[(size_t)(s0 + a) * np + s0 + b] += w * c[a] * c[b];
            }
        }
    for (int k = 0; k < n; k++) {
        int i0, i1, j0, j1;
        if (!clip(G, &r[k], &i0, &i1, &j0, &j1))
            continue;
        double Ek = p[3 * k];
        for (int j = j0; j < j1; j++)
            for (int i = i0; i < i1; i++) {
                size_t o = (size_t)j * G->bw + i;
                if (!G->sel[o])
                    continue;
                size_t t = (size_t)(j + G->by0 - r[k].y0) * r[k].w + (size_t)(i + G->bx0 - r[k].x0);
                double w = 1.0 / G->var[o];
                double res = pixel(G, G->bx0 + i, G->by0 + j) - G->mod[o];
                double jk[3] = {r[k].prf[t], Ek * r[k].dx[t], Ek * r[k].dy[t]};
                double c[3] = {1.0, G->bx0 + i - G->xc, G->by0 + j - G->yc};
                for (int a = 0; a < 3; a++) {
                    G->g[3 * k + a] += w * jk[a] * res;
                    for (int b = 0; b < G->nsky; b++)
                        G->A[(size_t)(3 * k + a) * np + s0 + b] += w * jk[a] * c[b];
                }
                /* Couplings with every star l ≥ k whose box holds this pixel. */
                for (int l = k; l < n; l++) {
                    long X = G->bx0 + i, Y = G->by0 + j;
                    if (X < r[l].x0 || X >= r[l].x0 + r[l].w || Y < r[l].y0 || Y >= r[l].y0 + r[l].h)
                        continue;
                    size_t u = (size_t)(Y - r[l].y0) * r[l].w + (size_t)(X - r[l].x0);
                    double El = p[3 * l];
                    double jl[3] = {r[l].prf[u], El * r[l].dx[u], El * r[l].dy[u]};
                    for (int a = 0; a < 3; a++)
                        for (int b = (l == k ? a : 0); b < 3; b++)
                            G->A[(size_t)(3 * k + a) * np + 3 * l + b] += w * jk[a] * jl[b];
                }
            }
    }
    for (int a = 0; a < np; a++)           /* mirror the upper triangle */
        for (int b = 0; b < a; b++)
            G->A[(size_t)a * np + b] = G->A[(size_t)b * np + a];
    /* Without a fitted sky the sky slot is held fixed: the slot gets a unit,
     * uncoupled row, so the step solves the star block only. */
    if (!G->nsky) {
        int s = 3 * n;
        for (int a = 0; a < np; a++)
            G->A[(size_t)a * np + s] = G->A[(size_t)s * np + a] = 0.0;
        G->A[(size_t)s * np + s] = 1.0;
        G->g[s] = 0.0;
    }
}

/* Solve (A + λ diag A) δ = g by Cholesky; nonzero when not positive definite. */
static int lm_step(group *G, double lambda)
{
    int np = G->np;
    memcpy(G->M, G->A, (size_t)np * np * sizeof *G->M);
    for (int a = 0; a < np; a++) {
        double d = G->A[(size_t)a * np + a];
        G->M[(size_t)a * np + a] = d * (1.0 + lambda) + (d > 0 ? 0.0 : 1e-300);
    }
    memcpy(G->step, G->g, (size_t)np * sizeof *G->step);
    return LAPACKE_dposv(LAPACK_ROW_MAJOR, 'U', np, 1, G->M, np, G->step, 1) != 0;
}

/* Covariance = A⁻¹ into G->M.  Cholesky first; when A is singular or
 * nearly so, the eigen pseudo-inverse (small eigenvalues dropped) and a
 * return of 1 so the stars are flagged degenerate. */
static int covariance(group *G)
{
    int np = G->np;
    /* Equilibrate: C = D⁻¹ (D⁻¹ A D⁻¹)⁻¹ D⁻¹ with D = sqrt(diag A). */
    double *d = G->step;
    for (int a = 0; a < np; a++) {
        double v = G->A[(size_t)a * np + a];
        d[a] = v > 0 ? sqrt(v) : 1.0;
    }
    for (int a = 0; a < np; a++)
        for (int b = 0; b < np; b++)
            G->M[(size_t)a * np + b] = G->A[(size_t)a * np + b] / (d[a] * d[b]);
    int rc = 0;
    if (LAPACKE_dpotrf(LAPACK_ROW_MAJOR, 'U', np, G->M, np) == 0 &&
        LAPACKE_dpotri(LAPACK_ROW_MAJOR, 'U', np, G->M, np) == 0) {
        for (int a = 0; a < np; a++)
            for (int b = 0; b < a; b++)
                G->M[(size_t)a * np + b] = G->M[(size_t)b * np + a];
    } else {
        rc = 1;
        double *ev = malloc((size_t)np * sizeof *ev), *V = malloc((size_t)np * np * sizeof *V);
        if (!ev || !V) {
            free(ev);
            free(V);
            return 2;
        }
        for (int a = 0; a < np; a++)
            for (int b = 0; b < np; b++)
                V[(size_t)a * np + b] = G->A[(size_t)a * np + b] / (d[a] * d[b]);
        if (LAPACKE_dsyev(LAPACK_ROW_MAJOR, 'V', 'U', np, V, np, ev) != 0) {
            free(ev);
            free(V);
            return 2;
        }
        double emax = ev[np - 1];
        memset(G->M, 0, (size_t)np * np * sizeof *G->M);
        for (int e = 0; e < np; e++) {
            if (!(ev[e] > emax * 1e-12))
                continue;
            for (int a = 0; a < np; a++)
                for (int b = 0; b < np; b++)
                    G->M[(size_t)a * np + b] += V[(size_t)a * np + e] * V[(size_t)b * np + e] / ev[e];
        }
        free(ev);
        free(V);
    }
    for (int a = 0; a < np; a++)
        for (int b = 0; b < np; b++)
            G->M[(size_t)a * np + b] /= d[a] * d[b];
    return rc;
}

static int cmp_double(const void *a, const void *b)
{
    double x = *(const double *)a, y = *(const double *)b;
    return (x > y) - (x < y);
}

/* Whole-frame fits have no fitting radius: flag a star whose PRF footprint
 * (mp_prf_box) holds a masked (32) or saturated (1) pixel or crosses the
 * frame's edge (4).  Without this a whole-frame fit never set 32 or 1 and
 * set 4 only for a centre off the frame (found by tests/unit/test_stiff_fit.c). */
static void flag_footprint(const group *G, mp_star *s)
{
    const mp_frame *f = G->f;
    long nx = f->im.nx, ny = f->im.ny, x0, y0;
    int w, h;
    mp_prf_box(G->m, s->x, s->y, &x0, &y0, &w, &h);
    if (x0 < 1 || y0 < 1 || x0 + w - 1 > nx || y0 + h - 1 > ny)
        s->flags |= MP_FLAG_EDGE;
    if (!f->mask)
        return;
    for (long Y = y0 > 1 ? y0 : 1; Y <= y0 + h - 1 && Y <= ny; Y++)
        for (long X = x0 > 1 ? x0 : 1; X <= x0 + w - 1 && X <= nx; X++) {
            uint8_t mk = f->mask[(size_t)(Y - 1) * nx + (size_t)(X - 1)];
            if (mk & MP_MASK_BAD)
                s->flags |= MP_FLAG_MASKED;
            if (mk & MP_MASK_SATURATED)
                s->flags |= MP_FLAG_SATURATED;
        }
}

/* Choose the fitted pixels and set the flags that depend on them. */
static int select_pixels(group *G, const mp_fit_opts *o, mp_star *st)
{
    const mp_frame *f = G->f;
    long nx = f->im.nx, ny = f->im.ny;
    double r = o->fitrad;
    int whole = !isfinite(r);
    if (whole) {
        G->bx0 = G->by0 = 1;
        G->bw = (int)nx;
        G->bh = (int)ny;
    } else {
        double xa = INFINITY, xb = -INFINITY, ya = INFINITY, yb = -INFINITY;
        for (int k = 0; k < G->n; k++) {
            xa = fmin(xa, st[k].x - r);
            xb = fmax(xb, st[k].x + r);
            ya = fmin(ya, st[k].y - r);
            yb = fmax(yb, st[k].y + r);
        }
        long x0 = (long)ceil(xa), x1 = (long)floor(xb), y0 = (long)ceil(ya), y1 = (long)floor(yb);
        x0 = x0 < 1 ? 1 : x0;
        y0 = y0 < 1 ? 1 : y0;
        x1 = x1 > nx ? nx : x1;
        y1 = y1 > ny ? ny : y1;
        if (x1 < x0 || y1 < y0)
            return 1;
        G->bx0 = x0;
        G->by0 = y0;
        G->bw = (int)(x1 - x0 + 1);
        G->bh = (int)(y1 - y0 + 1);
    }
    size_t nb = (size_t)G->bw * G->bh;
    G->sel = calloc(nb, 1);
    G->mod = malloc(nb * sizeof *G->mod);
    G->var = malloc(nb * sizeof *G->var);
    if (!G->sel || !G->mod || !G->var)
        return 2;
    G->npix = 0;
    for (int j = 0; j < G->bh; j++)
        for (int i = 0; i < G->bw; i++) {
            long X = G->bx0 + i, Y = G->by0 + j;
            uint8_t mk = f->mask ? f->mask[(size_t)(Y - 1) * nx + (size_t)(X - 1)] : 0;
            int inside = whole;
            for (int k = 0; k < G->n && !whole; k++) {
                double dx = X - st[k].x, dy = Y - st[k].y;
                if (dx * dx + dy * dy <= r * r) {
                    inside = 1;
                    if (mk & MP_MASK_BAD)
                        st[k].flags |= MP_FLAG_MASKED;
                    if (mk & MP_MASK_SATURATED)
                        st[k].flags |= MP_FLAG_SATURATED;
                }
            }
            if (inside && !mk) {
                G->sel[(size_t)j * G->bw + i] = 1;
                G->npix++;
            }
        }
    for (int k = 0; k < G->n; k++) {
        double rr = whole ? 0.0 : r;
        if (st[k].x - rr < 0.5 || st[k].y - rr < 0.5 || st[k].x + rr > nx + 0.5 || st[k].y + rr > ny + 0.5)
            st[k].flags |= MP_FLAG_EDGE;
        if (whole)
            flag_footprint(G, &st[k]);
    }
    G->xc = G->bx0 + 0.5 * (G->bw - 1);
    G->yc = G->by0 + 0.5 * (G->bh - 1);
    return 0;
}

static double start_sky(const group *G)
{
    double *v = malloc(G->npix * sizeof *v);
    if (!v)
        return 0.0;
    size_t n = 0;
    for (int j = 0; j < G->bh; j++)
        for (int i = 0; i < G->bw; i++)
            if (G->sel[(size_t)j * G->bw + i])
                v[n++] = pixel(G, G->bx0 + i, G->by0 + j);
    qsort(v, n, sizeof *v, cmp_double);
    double s = n ? v[n / 2] : 0.0;
    free(v);
    return s;
}

static int alloc_stars(group *G)
{
    long x0, y0;
    int w, h;
    /* The box can grow by one pixel a side as a star moves within a pixel;
     * it is cut to the group's box. */
    mp_prf_box(G->m, 0.0, 0.0, &x0, &y0, &w, &h);
    w = w + 2 < G->bw ? w + 2 : G->bw;
    h = h + 2 < G->bh ? h + 2 : G->bh;
    G->cap = (size_t)w * h;
    G->cur = calloc((size_t)G->n, sizeof *G->cur);
    G->trial = calloc((size_t)G->n, sizeof *G->trial);
    if (!G->cur || !G->trial)
        return 1;
    for (int s = 0; s < 2; s++) {
        rstar *r = s ? G->trial : G->cur;
        for (int k = 0; k < G->n; k++) {
            r[k].prf = malloc(G->cap * sizeof(double));
            r[k].dx = malloc(G->cap * sizeof(double));
            r[k].dy = malloc(G->cap * sizeof(double));
            if (!r[k].prf || !r[k].dx || !r[k].dy)
                return 1;
        }
    }
    size_t np = (size_t)G->np;
    G->p = malloc(np * sizeof *G->p);
    G->pt = malloc(np * sizeof *G->pt);
    G->A = malloc(np * np * sizeof *G->A);
    G->M = malloc(np * np * sizeof *G->M);
    G->g = malloc(np * sizeof *G->g);
    G->step = malloc(np * sizeof *G->step);
    return !G->p || !G->pt || !G->A || !G->M || !G->g || !G->step;
}

/* First flux guess: data above the sky over the star's box, over the PRF. */
static double start_flux(const group *G, const rstar *r, double sky)
{
    double s = 0.0, q = 0.0;
    int i0, i1, j0, j1;
    if (!clip(G, r, &i0, &i1, &j0, &j1))
        return 1.0;
    for (int j = j0; j < j1; j++)
        for (int i = i0; i < i1; i++) {
            if (!G->sel[(size_t)j * G->bw + i])
                continue;
            size_t t = (size_t)(j + G->by0 - r->y0) * r->w + (size_t)(i + G->bx0 - r->x0);
            s += pixel(G, G->bx0 + i, G->by0 + j) - sky;
            q += r->prf[t];
        }
    return q > 0 && s > 0 ? s / q : 1.0;
}

static int all_finite(const double *v, int n)
{
    for (int i = 0; i < n; i++)
        if (!isfinite(v[i]))
            return 0;
    return 1;
}

int mp_fit_group(const mp_frame *f, const mp_prf_model *m, const mp_fit_opts *o,
                 double sky0, mp_star *stars, int n, char *err)
{
    group G;
    memset(&G, 0, sizeof G);
    G.f = f;
    G.m = m;
    G.crop = isfinite(o->fitrad) ? o->crop : NULL;
    G.crop_min = o->fitrad + 1.0;
    G.n = n;
    G.nsky = o->fit_sky ? (o->sky_order >= 1 ? 3 : 1) : 0;
    G.np = 3 * n + (G.nsky ? G.nsky : 1);   /* a fixed sky still has a slot */
    int npar = 3 * n + G.nsky;
    int rc = 1;
    for (int k = 0; k < n; k++) {
        stars[k].flags = 0;
        stars[k].niter = 0;
    }
    int sp = select_pixels(&G, o, stars);
    if (sp == 2 || alloc_stars(&G)) {
        snprintf(err, MP_ERRLEN, "fit: out of memory for a group of %d stars", n);
        goto done;
    }
    if (sp == 1 || G.npix <= (size_t)npar) {
        for (int k = 0; k < n; k++)
            stars[k].flags |= MP_FLAG_NOCONV | MP_FLAG_EDGE;
        rc = 0;
        goto finish_flagged;
    }
    double sky = isfinite(sky0) ? sky0 : start_sky(&G);
    for (int k = 0; k < n; k++) {
        G.p[3 * k] = stars[k].flux;
        G.p[3 * k + 1] = stars[k].x;
        G.p[3 * k + 2] = stars[k].y;
    }
    G.p[3 * n] = sky;
    for (int a = 3 * n + 1; a < G.np; a++)
        G.p[a] = 0.0;
    if (render_all(&G, G.p, G.cur))
        goto nomem;
    for (int k = 0; k < n; k++)
        if (!(isfinite(G.p[3 * k]) && G.p[3 * k] > 0))
            G.p[3 * k] = start_flux(&G, &G.cur[k], sky);

    int np = G.np;
    model_of(&G, G.p, G.cur);
    variance_of(&G);
    normal_equations(&G, G.p, G.cur);
    double chi2 = chi2_with(&G, G.var);
    double lambda = 1e-3;
    int converged = 0, iter = 0, trials = 0;
    while (iter < o->maxiter && trials < 4 * o->maxiter) {
        trials++;
        if (lm_step(&G, lambda)) {
            lambda *= 10.0;
            if (lambda > 1e12)
                break;
            continue;
        }
        /* Positions move at most one pixel a step (DAOPHOT does the same):
         * a start far off cannot fling a star across the group. */
        for (int k = 0; k < n; k++)
            for (int a = 1; a <= 2; a++) {
                double *s = &G.step[3 * k + a];
                *s = *s > 1.0 ? 1.0 : (*s < -1.0 ? -1.0 : *s);
            }
        for (int a = 0; a < np; a++)
            G.pt[a] = G.p[a] + G.step[a];
        if (render_all(&G, G.pt, G.trial))
            goto nomem;
        model_of(&G, G.pt, G.trial);
        double chi2t = chi2_with(&G, G.var);
        if (!(chi2t <= chi2 * (1.0 + 1e-12))) {
            model_of(&G, G.p, G.cur);
            lambda *= 10.0;
            if (lambda > 1e8) {
                converged = 1;   /* no downhill step left at machine precision */
                break;
            }
            continue;
        }
        iter++;
        int small = 1;
        for (int a = 0; a < npar; a++) {
            double d = G.A[(size_t)a * np + a];
            if (d > 0 && fabs(G.step[a]) * sqrt(d) > o->tol)
                small = 0;
        }
        double *tp = G.p;
        G.p = G.pt;
        G.pt = tp;
        rstar *tr = G.cur;
        G.cur = G.trial;
        G.trial = tr;
        lambda = lambda / 10.0 > 1e-7 ? lambda / 10.0 : 1e-7;
        variance_of(&G);
        normal_equations(&G, G.p, G.cur);
        chi2 = chi2_with(&G, G.var);
        if (small) {
            converged = 1;
            break;
        }
    }

    int cv = covariance(&G);
    if (cv == 2)
        goto nomem;
    double chi2f = chi2_with(&G, G.var);
    int dof = (int)G.npix - npar;
    for (int k = 0; k < n; k++) {
        mp_star *s = &stars[k];
        double out[6] = {G.p[3 * k + 1], G.p[3 * k + 2], G.p[3 * k],
                         sqrt(G.M[(size_t)(3 * k + 1) * np + 3 * k + 1]),
                         sqrt(G.M[(size_t)(3 * k + 2) * np + 3 * k + 2]),
                         sqrt(G.M[(size_t)(3 * k) * np + 3 * k])};
        double skyv = sky_at(&G, G.p, out[0], out[1]);
        double c[3] = {1.0, out[0] - G.xc, out[1] - G.yc};
        double vs = 0.0;
        for (int a = 0; a < G.nsky; a++)
            for (int b = 0; b < G.nsky; b++)
                vs += c[a] * c[b] * G.M[(size_t)(3 * n + a) * np + 3 * n + b];
        /* The performance model wants the whole PRF, not the fitted window. */
        if (!isfinite(out[0]) || !isfinite(out[1]))
            memset(&s->st, 0, sizeof s->st);
        else if (mp_prf_stats_at(G.m, out[0], out[1], &s->st, &G.work))
            goto nomem;
        double se, sx;
        double E = out[2] > 1.0 ? out[2] : 1.0;
        mp_perf_model(&s->st, E, skyv > 0 ? skyv : 0.0, f->rdnoise, (double)G.npix, &se, &sx);
        if (!converged)
            s->flags |= MP_FLAG_NOCONV;
        if (cv)
            s->flags |= MP_FLAG_MERGED;
        if (!all_finite(out, 6) || !isfinite(skyv) || !isfinite(vs) || !isfinite(chi2f)) {
            s->flags |= MP_FLAG_NOCONV;
            continue;             /* keep the start values */
        }
        s->x = out[0];
        s->y = out[1];
        s->flux = out[2];
        s->ex = out[3];
        s->ey = out[4];
        s->eflux = out[5];
        s->sky = skyv;
        s->esky = sqrt(vs > 0 ? vs : 0.0);
        s->chi2 = dof > 0 ? chi2f / dof : 0.0;
        s->dof = dof;
        s->niter = iter;
        s->fluxerr_model = isfinite(se) ? se : 0.0;
        s->poserr_model = isfinite(sx) ? sx : 0.0;
    }
    rc = 0;
    goto done;

nomem:
    snprintf(err, MP_ERRLEN, "fit: out of memory for a group of %d stars", n);
    rc = 1;
    goto done;
finish_flagged:
    for (int k = 0; k < n; k++) {
        mp_star *s = &stars[k];
        s->ex = s->ey = s->eflux = s->esky = 0.0;
        s->chi2 = 0.0;
        s->dof = 0;
        if (!isfinite(s->flux))
            s->flux = 0.0;
        if (!isfinite(s->sky))
            s->sky = 0.0;
    }
done:
    group_free(&G);
    return rc;
}
