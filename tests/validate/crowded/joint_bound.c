/* joint_bound.c — each star's Cramér–Rao bound fitted with its neighbours
 * (joint_bound.h).  The PRF is the Gaussian the scene was drawn with,
 * integrated over pixels by erf, so the bound's derivatives are exact (the
 * isolated bound of crowded.c uses central differences of the same). */
#include "tests/validate/crowded/joint_bound.h"

#include <lapacke.h>
#include <math.h>
#include <stdlib.h>
#include <string.h>

#define JB_MAXSET 48        /* members of one joint set, nearest first */
#define JB_REACH 6.0        /* a star's light is drawn out to this many σ */

/* One axis of the pixel-integrated Gaussian: the fraction of light of a
 * star at c in the pixel centred on i, and its derivative with respect
 * to c. */
static void axis(double i, double c, double sigma, double *p, double *dp)
{
    double a = (i - 0.5 - c) / sigma, b = (i + 0.5 - c) / sigma;
    *p = 0.5 * (erfc(-b / M_SQRT2) - erfc(-a / M_SQRT2));
    const double k = 1.0 / sqrt(2.0 * M_PI);
    *dp = -(k * exp(-0.5 * b * b) - k * exp(-0.5 * a * a)) / sigma;
}

/* Stars bucketed on a grid of cells of side cs. */
typedef struct {
    int *head, *next;
    long gx, gy;
    double cs;
} grid;

static int grid_build(grid *g, const jb_star *s, int n, long nx, long ny, double cs)
{
    g->cs = cs;
    g->gx = (long)(nx / cs) + 2;
    g->gy = (long)(ny / cs) + 2;
    g->head = malloc(sizeof(int) * (size_t)(g->gx * g->gy));
    g->next = malloc(sizeof(int) * (size_t)(n > 0 ? n : 1));
    if (!g->head || !g->next)
        return 1;
    for (long c = 0; c < g->gx * g->gy; c++)
        g->head[c] = -1;
    for (int k = 0; k < n; k++) {
        long cx = (long)floor(s[k].x / cs), cy = (long)floor(s[k].y / cs);
        cx = cx < 0 ? 0 : cx >= g->gx ? g->gx - 1 : cx;
        cy = cy < 0 ? 0 : cy >= g->gy ? g->gy - 1 : cy;
        g->next[k] = g->head[cy * g->gx + cx];
        g->head[cy * g->gx + cx] = k;
    }
    return 0;
}

typedef struct {
    int k;
    double d;
} member;

static int cmp_member(const void *a, const void *b)
{
    const member *x = a, *y = b;
    return (x->d > y->d) - (x->d < y->d);
}

/* The joint set of star t: t first, then the stars within 2·fitrad,
 * nearest first, at most JB_MAXSET in all. */
static int joint_set(const grid *g, const jb_star *s, int t, double reach, member *set)
{
    int m = 0;
    long cx = (long)floor(s[t].x / g->cs), cy = (long)floor(s[t].y / g->cs);
    set[m++] = (member){t, 0.0};
    member extra[4 * JB_MAXSET];
    int ne = 0;
    for (long yy = cy - 1; yy <= cy + 1; yy++)
        for (long xx = cx - 1; xx <= cx + 1; xx++) {
            if (xx < 0 || yy < 0 || xx >= g->gx || yy >= g->gy)
                continue;
            for (int k = g->head[yy * g->gx + xx]; k >= 0; k = g->next[k]) {
                double d = hypot(s[k].x - s[t].x, s[k].y - s[t].y);
                if (k != t && d <= reach && ne < 4 * JB_MAXSET)
                    extra[ne++] = (member){k, d};
            }
        }
    qsort(extra, (size_t)ne, sizeof *extra, cmp_member);
    for (int i = 0; i < ne && m < JB_MAXSET; i++)
        set[m++] = extra[i];
    return m;
}

/* F of one joint set (np = 3m + 1 parameters: E, X, Y per member, then the
 * sky), summed over the union of the members' fitting regions. */
static void fisher_of(const jb_scene *sc, const jb_star *s, const member *set, int m, double *F)
{
    int np = 3 * m + 1;
    memset(F, 0, sizeof(double) * (size_t)np * np);
    double r = sc->fitrad, x0 = INFINITY, y0 = INFINITY, x1 = -INFINITY, y1 = -INFINITY;
    for (int a = 0; a < m; a++) {
        const jb_star *q = &s[set[a].k];
        x0 = fmin(x0, q->x - r);
        x1 = fmax(x1, q->x + r);
        y0 = fmin(y0, q->y - r);
        y1 = fmax(y1, q->y + r);
    }
    long X0 = (long)ceil(x0) < 1 ? 1 : (long)ceil(x0), Y0 = (long)ceil(y0) < 1 ? 1 : (long)ceil(y0);
    long X1 = (long)floor(x1) > sc->nx ? sc->nx : (long)floor(x1);
    long Y1 = (long)floor(y1) > sc->ny ? sc->ny : (long)floor(y1);
    double reach = JB_REACH * sc->sigma + 1.0;
    double g[3 * JB_MAXSET + 1];
    int nz[3 * JB_MAXSET + 1];
    for (long Y = Y0; Y <= Y1; Y++)
        for (long X = X0; X <= X1; X++) {
            int in = 0;
            for (int a = 0; a < m && !in; a++)
                in = hypot((double)X - s[set[a].k].x, (double)Y - s[set[a].k].y) <= r;
            double mu = sc->mean[(size_t)(Y - 1) * sc->nx + (size_t)(X - 1)];
            if (!in || !(mu < sc->satur))
                continue;
            int nn = 0;
            for (int a = 0; a < m; a++) {
                const jb_star *q = &s[set[a].k];
                double p, dx, dy;
                if (sc->stamp) {
                    long h = sc->sw / 2, i = X - lround(q->x) + h, j = Y - lround(q->y) + h;
                    if (i < 0 || j < 0 || i >= sc->sw || j >= sc->sw)
                        continue;
                    size_t ss = (size_t)sc->sw * (size_t)sc->sw;
                    const double *st = sc->stamp + 3 * ss * (size_t)set[a].k;
                    size_t o = (size_t)j * (size_t)sc->sw + (size_t)i;
                    p = st[o], dx = st[ss + o], dy = st[2 * ss + o];
                } else {
                    if (fabs((double)X - q->x) > reach || fabs((double)Y - q->y) > reach)
                        continue;
                    double px, dpx, py, dpy;
                    axis((double)X, q->x, sc->sigma, &px, &dpx);
                    axis((double)Y, q->y, sc->sigma, &py, &dpy);
                    p = px * py, dx = dpx * py, dy = px * dpy;
                }
                g[nn] = p;
                nz[nn++] = 3 * a;
                g[nn] = q->flux * dx;
                nz[nn++] = 3 * a + 1;
                g[nn] = q->flux * dy;
                nz[nn++] = 3 * a + 2;
            }
            g[nn] = 1.0;
            nz[nn++] = 3 * m;
            double w = 1.0 / (mu + sc->ron * sc->ron);
            for (int i = 0; i < nn; i++)
                for (int j = 0; j < nn; j++)
                    F[(size_t)nz[i] * np + nz[j]] += w * g[i] * g[j];
        }
}

int joint_bounds(const jb_scene *sc, const jb_star *s, int n, double *sig_e, double *sig_x,
                 double *sig_y, int *nmax)
{
    grid g = {0};
    int np1 = 3 * JB_MAXSET + 1, rc = 1, big = 0;
    double *F = malloc(sizeof(double) * (size_t)np1 * np1);
    member *set = malloc(sizeof *set * JB_MAXSET);
    if (!F || !set || grid_build(&g, s, n, sc->nx, sc->ny, 2.0 * sc->fitrad))
        goto done;
    for (int t = 0; t < n; t++) {
        int m = joint_set(&g, s, t, 2.0 * sc->fitrad, set);
        big = m > big ? m : big;
        int np = 3 * m + 1;
        fisher_of(sc, s, set, m, F);
        /* t's parameters are the first three: their variances are the
         * diagonal of F⁻¹ (Cholesky, then the inverse from the factor). */
        if (LAPACKE_dpotrf(LAPACK_ROW_MAJOR, 'U', np, F, np) ||
            LAPACKE_dpotri(LAPACK_ROW_MAJOR, 'U', np, F, np)) {
            sig_e[t] = sig_x[t] = sig_y[t] = INFINITY;
            continue;
        }
        sig_e[t] = sqrt(F[0]);
        sig_x[t] = sqrt(F[(size_t)np + 1]);
        sig_y[t] = sqrt(F[2 * (size_t)np + 2]);
    }
    if (nmax)
        *nmax = big;
    rc = 0;
done:
    free(F);
    free(set);
    free(g.head);
    free(g.next);
    return rc;
}
