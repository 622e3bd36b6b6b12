/* star_excess.c — mp_bkg_star_excess (find.h): the residual's variance
 * beyond its noise model around the brightest stars, per ring of
 * distance, as F²·v(r), and its evaluation at a pixel. */
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "find/find_priv.h"

/* The trim: z² above its 0.9 quantile is left out, |z| ≤ a for noise. */
#define TRIM_Q 0.9
#define TRIM_A 1.6448536269514722

/* The cell of a position (clamped to the grid). */
static long cell_of(double v, int size, long n)
{
    long c = (long)floor(v / size);
    return c < 0 ? 0 : c >= n ? n - 1 : c;
}

/* The direction cell of an offset (dx, dy) from a star: MP_BKG_NSECT
 * equal turns counter-clockwise from +x, ⌊atan2(dy, dx)·NSECT/2π⌋ (mod
 * NSECT) but on the cells' edges.  By the tangents of the edges in a
 * quadrant and the quadrant's reflection, not atan2: the noise map
 * evaluates it at every pixel within a kept star's reach (with atan2
 * there frame X of compare_daophot.sh took 3 % more CPU with its table,
 * 47 Tuc ~8 % more with Tiny Tim's). */
#define QSECT (MP_BKG_NSECT / 4)
_Static_assert(MP_BKG_NSECT == 32, "sector_of's edges are those of 32 cells");
static int sector_of(double dx, double dy)
{
    /* tan(j·2π/NSECT), j = 1 .. QSECT − 1 (NSECT 32: steps of π/16) */
    static const double edge[QSECT - 1] = {0.19891236737965800, 0.41421356237309503,
                                           0.66817863791929891, 1.0,
                                           1.4966057626654890, 2.4142135623730950,
                                           5.0273394921258460};
    double ax = fabs(dx), ay = fabs(dy);
    int k = 0;
    while (k < QSECT - 1 && ay >= ax * edge[k])
        k++;
    if (dy >= 0)
        return dx >= 0 ? k : 2 * QSECT - 1 - k;
    return dx < 0 ? 2 * QSECT + k : MP_BKG_NSECT - 1 - k;
}

void mp_bkg_excess_span(const mp_bkg *b, long y, long x0, long x1, double *v)
{
    for (long x = x0; x < x1; x++)
        v[x - x0] = 0.0;
    long cy = cell_of((double)y, b->nxv, b->ncy);
    for (long a = x0, e; a < x1; a = e) {
        /* the pixels of one column of cells: the same nine cells each */
        long cx = cell_of((double)a, b->nxv, b->ncx);
        e = cx + 1 < b->ncx && (cx + 1) * b->nxv < x1 ? (cx + 1) * b->nxv : x1;
        for (long j = cy - 1; j <= cy + 1; j++)
            for (long i = cx - 1; i <= cx + 1; i++) {
                if (i < 0 || j < 0 || i >= b->ncx || j >= b->ncy)
                    continue;
                size_t c = (size_t)j * (size_t)b->ncx + (size_t)i;
                for (size_t s = b->cell0[c]; s < b->cell0[c + 1]; s++) {
                    const double *st = b->xs + MP_BKG_XS * s;
                    double dy = (double)y - st[1], dy2 = dy * dy;
                    if (!(dy2 < st[4]))     /* then no dx² + dy² is below it */
                        continue;
                    /* the row's pixels within reach, a pixel to spare
                     * each side; each tested exactly: d2 < reach² */
                    double h = sqrt(st[4] - dy2);
                    long lo = (long)floor(st[0] - h) - 1, hi = (long)ceil(st[0] + h) + 2;
                    lo = lo < a ? a : lo;
                    hi = hi > e ? e : hi;
                    const double *xv = b->xv + (size_t)st[3] * (size_t)b->nxv;
                    const double *xd = b->xvd ? b->xvd + (size_t)st[3] * (size_t)b->nxv * MP_BKG_NSECT
                                              : NULL;
                    for (long x = lo; x < hi; x++) {
                        double dx = (double)x - st[0], d2 = dx * dx + dy2;
                        if (!(d2 < st[4]))
                            continue;
                        size_t r = (size_t)sqrt(d2);
                        v[x - x0] += st[2] * (xd ? xd[r * MP_BKG_NSECT + (size_t)sector_of(dx, dy)]
                                                 : xv[r]);
                    }
                }
            }
    }
}

/* A ring's pixels: z² and F²/σ² each, the star's place among those that
 * measure the class and the pixel's direction cell about it. */
typedef struct {
    double z2, w;
    int star, sect;
} ring_px;

typedef struct {
    ring_px *p;
    size_t n, cap;
} ring;

static int ring_push(ring *g, double z2, double w, int star, int sect)
{
    if (g->n == g->cap) {
        size_t cap = g->cap ? 2 * g->cap : 64;
        ring_px *a = realloc(g->p, cap * sizeof *a);
        if (!a)
            return 1;
        g->p = a;
        g->cap = cap;
    }
    g->p[g->n++] = (ring_px){z2, w, star, sect};
    return 0;
}

/* The unmasked pixels around one star (the class's star-th), by ring. */
static int ring_pixels(const mp_bkg *b, const mp_frame *f, double xs, double ys, double F,
                       int nr, int star, ring *g)
{
    long nx = f->im.nx, ny = f->im.ny;
    long x0 = (long)floor(xs - nr), x1 = (long)ceil(xs + nr);
    long y0 = (long)floor(ys - nr), y1 = (long)ceil(ys + nr);
    for (long y = y0 > 0 ? y0 : 0; y <= y1 && y < ny; y++)
        for (long x = x0 > 0 ? x0 : 0; x <= x1 && x < nx; x++) {
            double d = hypot((double)x - xs, (double)y - ys);
            size_t i = (size_t)y * (size_t)nx + (size_t)x;
            if (d >= nr || f->mask[i] || !isfinite(b->res[i]))
                continue;
            double rms = mp_bkg_rms(b, i);
            if (!(rms > 0))
                continue;
            double z = (b->res[i] - mp_bkg_sky(b, i)) / rms;
            if (ring_push(&g[(int)d], z * z, F * F / (rms * rms), star,
                          sector_of((double)x - xs, (double)y - ys)))
                return 1;
        }
    return 0;
}

/* v of one ring (0 unless significant): the trimmed moment estimate. */
static double ring_excess(ring *g, double *tmp)
{
    if (g->n < 10)
        return 0.0;
    for (size_t i = 0; i < g->n; i++)
        tmp[i] = g->p[i].z2;
    size_t k = (size_t)(TRIM_Q * (double)g->n);
    double cut = mp_select_kth(tmp, g->n, k < g->n ? k : g->n - 1);
    /* noise alone: E[z²], E[z⁴] of a normal z given |z| ≤ a */
    double phi = exp(-0.5 * TRIM_A * TRIM_A) / sqrt(2.0 * M_PI);
    double c1 = (TRIM_Q - 2.0 * TRIM_A * phi) / TRIM_Q;
    double c2 = (3.0 * TRIM_Q - 2.0 * phi * (TRIM_A * TRIM_A * TRIM_A + 3.0 * TRIM_A)) / TRIM_Q;
    double S = 0.0, A = 0.0, m = 0.0;
    for (size_t i = 0; i < g->n; i++)
        if (g->p[i].z2 <= cut) {
            S += g->p[i].z2 - c1;
            A += g->p[i].w;
            m += 1.0;
        }
    return A > 0 && S > 3.0 * sqrt(m * (c2 - c1 * c1)) ? S / A : 0.0;
}

/* A ring's direction cells (mp_bkg_star_excess, find.h) into
 * vd[0..MP_BKG_NSECT-1]: the median of the nstar stars' estimates where
 * at least three have pixels and more than half of those are above 3 of
 * their null σ, when above the ring's own v; else v.  Their number into
 * *nd.  Nonzero when out of memory. */
static int ring_cells(const ring *g, int nstar, double v, double *vd, int *nd)
{
    size_t nc = (size_t)nstar * MP_BKG_NSECT;
    double *S = calloc(3 * nc + (size_t)nstar + 1, sizeof *S), *A = S + nc, *M = A + nc;
    if (!S)
        return 1;
    double *est = M + nc;
    for (size_t i = 0; i < g->n; i++) {
        size_t k = (size_t)g->p[i].star * MP_BKG_NSECT + (size_t)g->p[i].sect;
        S[k] += g->p[i].z2 - 1.0;
        A[k] += g->p[i].w;
        M[k] += 1.0;
    }
    for (int c = 0; c < MP_BKG_NSECT; c++) {
        size_t ne = 0, nsig = 0;
        for (int j = 0; j < nstar; j++) {
            size_t k = (size_t)j * MP_BKG_NSECT + (size_t)c;
            if (!(M[k] > 0 && A[k] > 0))
                continue;
            est[ne++] = S[k] / A[k];
            nsig += S[k] > 3.0 * sqrt(2.0 * M[k]);
        }
        vd[c] = v;
        if (ne >= 3 && 2 * nsig > ne) {
            double med = mp_median_select(est, ne);
            if (med > v) {
                vd[c] = med;
                (*nd)++;
            }
        }
    }
    free(S);
    return 0;
}

/* The kept stars (MP_BKG_XS values each; m of them) by cell into b. */
static int index_cells(mp_bkg *b, double *xs, size_t m)
{
    long ncx = (b->nx + b->nxv - 1) / b->nxv, ncy = (b->ny + b->nxv - 1) / b->nxv;
    size_t nc = (size_t)ncx * (size_t)ncy;
    size_t *c0 = calloc(nc + 1, sizeof *c0), *fill = calloc(nc + 1, sizeof *fill);
    double *sorted = malloc((MP_BKG_XS * m + 1) * sizeof *sorted);
    if (!c0 || !fill || !sorted) {
        free(c0);
        free(fill);
        free(sorted);
        free(xs);
        return 1;
    }
    for (size_t s = 0; s < m; s++) {
        const double *st = xs + MP_BKG_XS * s;
        c0[cell_of(st[1], b->nxv, ncy) * ncx + cell_of(st[0], b->nxv, ncx) + 1]++;
    }
    for (size_t c = 0; c < nc; c++)
        c0[c + 1] += c0[c];
    for (size_t s = 0; s < m; s++) {
        const double *st = xs + MP_BKG_XS * s;
        long c = cell_of(st[1], b->nxv, ncy) * ncx + cell_of(st[0], b->nxv, ncx);
        memcpy(sorted + MP_BKG_XS * (c0[c] + fill[c]++), st, MP_BKG_XS * sizeof *xs);
    }
    free(fill);
    free(xs);
    b->xs = sorted;
    b->nxs = m;
    b->cell0 = c0;
    b->ncx = ncx;
    b->ncy = ncy;
    return 0;
}

/* The stars whose term F²·v reaches MP_BKG_EXCESS_FLOOR of their sky
 * pixel's variance on some ring, each out to the last such ring (its
 * reach: the term is dropped beyond), as (x, y, F², class, reach²) by
 * cell into b. */
static int keep_stars(mp_bkg *b, const mp_frame *f, const double *x, const double *y,
                      const double *F, const int *cls, size_t n)
{
    double *xs = malloc((MP_BKG_XS * n + 1) * sizeof *xs);
    if (!xs)
        return 1;
    size_t m = 0;
    for (size_t s = 0; s < n; s++) {
        long px = lround(x[s]), py = lround(y[s]);
        if (!isfinite(F[s]) || px < 0 || py < 0 || px >= f->im.nx || py >= f->im.ny)
            continue;
        size_t i = (size_t)py * (size_t)f->im.nx + (size_t)px;
        double var = b->k * b->k * (fmax(mp_bkg_sky(b, i), 0.0) + b->ron2);
        const double *v = b->xv + (size_t)cls[s] * (size_t)b->nxv;
        const double *vd = b->xvd ? b->xvd + (size_t)cls[s] * (size_t)b->nxv * MP_BKG_NSECT : NULL;
        int reach = 0;
        for (int r = 0; r < b->nxv; r++) {
            double vr = v[r];
            for (int c = 0; vd && c < MP_BKG_NSECT; c++)
                vr = fmax(vr, vd[(size_t)r * MP_BKG_NSECT + (size_t)c]);
            if (F[s] * F[s] * vr >= MP_BKG_EXCESS_FLOOR * var)
                reach = r + 1;
        }
        if (reach > 0) {
            double *st = xs + MP_BKG_XS * m++;
            st[0] = x[s];
            st[1] = y[s];
            st[2] = F[s] * F[s];
            st[3] = (double)cls[s];
            st[4] = (double)reach * reach;
        }
    }
    return index_cells(b, xs, m);
}

/* Whether star s measures its class's excess: usable (NULL: every star),
 * a positive flux, and none of the nh stars of a higher class (higher,
 * their indices) within the rings' reach nr of it.  The classes go up with how far a star's misfit reaches (the
 * pipeline: 1, a saturated star's flux from its wings); such a star's
 * misfit fills the rings of every star near it, and is its own class's
 * excess, added around it.  (V, the segmented scene with its PSF built:
 * the ten brightest stars fitted whole in round 1 were fits in the wings
 * of its saturated stars, fluxes 10⁶–10¹¹ e⁻ traded against the sky; the
 * 4·10⁵ e⁻ stars fitted well were not among them.) */
static int measures(const double *x, const double *y, const double *F,
                    const unsigned char *usable, const size_t *higher, size_t nh, size_t s,
                    int nr)
{
    if (!(F[s] > 0) || (usable && !usable[s]))
        return 0;
    for (size_t h = 0; h < nh; h++)
        if (hypot(x[higher[h]] - x[s], y[higher[h]] - y[s]) < nr)
            return 0;
    return 1;
}

/* v of class c into v[0..nr-1] (the rings of its nb brightest stars that
 * measure it) and its rings' direction cells into vd (ring_cells); its
 * rings kept, its cells with their own v added to *nd. */
static int class_excess(const mp_bkg *b, const mp_frame *f, const double *x, const double *y,
                        const double *F, const int *cls, const unsigned char *usable, size_t n,
                        int c, size_t nb, int nr, double *v, double *vd, int *kept, int *nd)
{
    ring *g = calloc((size_t)nr, sizeof *g);
    size_t *higher = malloc((n + 1) * sizeof *higher), nh = 0;
    int rc = !g || !higher;
    for (size_t s = 0; !rc && s < n; s++)
        if (cls[s] > c)
            higher[nh++] = s;
    size_t used = 0;
    for (size_t s = 0; !rc && s < n && used < nb; s++)
        if (cls[s] == c && measures(x, y, F, usable, higher, nh, s, nr)) {
            rc = ring_pixels(b, f, x[s], y[s], F[s], nr, (int)used, g);
            used++;
        }
    size_t big = 0;
    for (int r = 0; !rc && r < nr; r++)
        big = g[r].n > big ? g[r].n : big;
    double *tmp = rc ? NULL : malloc((big + 1) * sizeof *tmp);
    rc = rc || !tmp;
    *kept = 0;
    for (int r = 0; !rc && r < nr; r++) {
        v[r] = ring_excess(&g[r], tmp);
        *kept += v[r] > 0;
        rc = ring_cells(&g[r], (int)used, v[r], vd + (size_t)r * MP_BKG_NSECT, nd);
    }
    for (int r = 0; g && r < nr; r++)
        free(g[r].p);
    free(g);
    free(higher);
    free(tmp);
    return rc;
}

int mp_bkg_star_excess(mp_bkg *b, const mp_frame *f, const double *x, const double *y,
                       const double *F, const int *cls, const unsigned char *usable, size_t n,
                       int ncls, size_t nb, double rmax, int *nring, size_t *nkept, char *err)
{
    *nring = 0;
    *nkept = 0;
    int nr = (int)ceil(rmax);
    if (!b->model || nr < 1 || n == 0 || ncls < 1)
        return 0;
    free(b->xv);
    free(b->xvd);
    free(b->xs);
    free(b->cell0);
    b->xv = NULL, b->xvd = NULL, b->xs = NULL, b->cell0 = NULL, b->nxv = 0, b->nxs = 0;
    b->nxd = 0;
    double *v = calloc((size_t)ncls * (size_t)nr, sizeof *v);
    double *vd = calloc((size_t)ncls * (size_t)nr * MP_BKG_NSECT, sizeof *vd);
    int rc = !v || !vd, nd = 0;
    for (int c = 0; !rc && c < ncls; c++) {
        int kept;
        rc = class_excess(b, f, x, y, F, cls, usable, n, c, nb, nr, v + (size_t)c * nr,
                          vd + (size_t)c * nr * MP_BKG_NSECT, &kept, &nd);
        *nring += kept;
    }
    if (!rc && (*nring > 0 || nd > 0)) {
        b->xv = v;
        b->nxv = nr;
        b->nxc = ncls;
        v = NULL;
        if (nd > 0) {       /* else every cell is its ring: the rings alone */
            b->xvd = vd;
            b->nxd = nd;
            vd = NULL;
        }
        rc = keep_stars(b, f, x, y, F, cls, n);
        *nkept = b->nxs;
    }
    free(v);
    free(vd);
    if (rc)
        snprintf(err, MP_ERRLEN, "out of memory for the residual noise map");
    return rc;
}
