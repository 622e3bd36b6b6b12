/* grid.c — link every pair of stars closer than the critical separation,
 * in time linear in the number of stars.
 *
 * The plane is cut into square cells of side h slightly above crit/2.
 * Stars are sorted by cell in raster order (an LSD radix sort on the
 * integer cell coordinates: linear, stable, so a cell's stars stay in row
 * order), and only occupied cells are kept, so memory is O(n) however far
 * apart the stars are.  Then:
 *
 *   - Two stars in one cell are at most h·√2 ≈ 0.71·crit apart, so a cell is
 *     a clique: its stars are linked without a single distance test.  Many
 *     stars at one point cost O(n), not O(n²).  (With a link test of the
 *     pairs' own, mp_group_opts.link, no cell is a clique: every pair
 *     within crit is tested.)
 *   - Two stars closer than crit (< 2h) lie at most 2 cells apart along each
 *     axis, so each cell is compared with the cells of its 5×5 neighbourhood,
 *     each pair of cells once (the cells after it in raster order: the next
 *     two in its row, five in each of the next two rows).  Those are found by
 *     three cursors that only move forward through the sorted cells, so the
 *     sweep is sequential in memory.  Cells whose bounding boxes are at least
 *     crit apart are skipped, as are two cliques already in one set;
 *     otherwise the first close pair links the two cliques and the search
 *     stops.
 *
 * For a bounded density the work per star is bounded, so the total is
 * linear (plus union–find's inverse-Ackermann factor).  The worst case left
 * is adversarial: two crowded neighbouring cells none of whose stars are
 * close, at O(k_A·k_B).
 *
 * h = 0.500001·crit rather than crit/2 leaves a margin of 2e-6 cells for
 * the rounding of x/h, so that coverage holds exactly for |x/h| up to 1e9.
 * Cell coordinates beyond ±1e9 (stars absurdly far off the frame) are
 * clamped to ±1e9: clamping keeps neighbours neighbours, but such a cell is
 * no longer a clique, so its stars are compared pair by pair.
 */
#include <math.h>
#include <stdint.h>
#include <stdlib.h>
#include <string.h>

#include "group/group_priv.h"

#define SIDE 0.500001    /* cell side in units of crit */
#define CMAX 1e9         /* largest |cell coordinate| */

typedef struct {
    uint64_t key;            /* (row << bx) | column */
    size_t start, end;       /* its stars: sorted positions [start, end) */
    double x0, x1, y0, y1;   /* bounding box of its stars */
    int clique;              /* no member clamped: all members are close */
} cell;

typedef struct {
    size_t n, nc;
    double *x, *y;           /* positions in cell order */
    size_t *row;             /* table row of each sorted position */
    cell *c;
    int bx;                  /* bits of the column part of a key */
    mp_uf uf;                /* over sorted positions */
    mp_group_link_fn link;   /* the pairs' own test (NULL: none) */
    void *ctx;
    size_t work;             /* cell pairs + distance tests + unions */
} grid;

static void grid_free(grid *g)
{
    free(g->x);
    free(g->y);
    free(g->row);
    free(g->c);
    mp_uf_free(&g->uf);
}

static uint64_t coord(double v, int *clamped)
{
    double c = floor(v);
    if (c > CMAX) {
        c = CMAX;
        *clamped = 1;
    } else if (c < -CMAX) {
        c = -CMAX;
        *clamped = 1;
    }
    return (uint64_t)(c + CMAX);     /* 0 .. 2e9 */
}

static int bits_of(uint64_t v)
{
    int b = 0;
    while (v >> b)
        b++;
    return b;
}

/* Stable LSD radix sort of (key, row) by key, 8 bits a pass over the low
 * `bits` bits.  The sorted pairs end up in *key and *row. */
static int radix_sort(uint64_t **key, size_t **row, size_t n, int bits)
{
    uint64_t *k = *key, *k2 = malloc(n * sizeof *k2);
    size_t *r = *row, *r2 = malloc(n * sizeof *r2);
    if (!k2 || !r2) {
        free(k2);
        free(r2);
        return 1;
    }
    for (int shift = 0; shift < bits; shift += 8) {
        size_t at[256] = {0};
        for (size_t i = 0; i < n; i++)
            at[(k[i] >> shift) & 255]++;
        for (size_t d = 0, sum = 0; d < 256; d++) {
            size_t c = at[d];
            at[d] = sum;
            sum += c;
        }
        for (size_t i = 0; i < n; i++) {
            size_t p = at[(k[i] >> shift) & 255]++;
            k2[p] = k[i];
            r2[p] = r[i];
        }
        uint64_t *tk = k;
        k = k2;
        k2 = tk;
        size_t *tr = r;
        r = r2;
        r2 = tr;
    }
    free(k2);
    free(r2);
    *key = k;
    *row = r;
    return 0;
}

/* Sort the stars by cell and build the list of occupied cells. */
static int grid_build(grid *g, const double *x, const double *y, size_t n, double h)
{
    uint64_t *key = malloc(n * sizeof *key), *cx = malloc(n * sizeof *cx);
    unsigned char *clamped = calloc(n, 1);
    g->row = malloc(n * sizeof *g->row);
    g->x = malloc(n * sizeof *g->x);
    g->y = malloc(n * sizeof *g->y);
    int rc = 1;
    if (!key || !cx || !clamped || !g->row || !g->x || !g->y)
        goto done;
    /* Cell coordinates, shifted to start at 0 so that keys are short. */
    uint64_t x0 = UINT64_MAX, y0 = UINT64_MAX, x1 = 0, y1 = 0;
    for (size_t i = 0; i < n; i++) {
        int cl = 0;
        cx[i] = coord(x[i] / h, &cl);
        key[i] = coord(y[i] / h, &cl);
        clamped[i] = (unsigned char)cl;
        x0 = cx[i] < x0 ? cx[i] : x0;
        x1 = cx[i] > x1 ? cx[i] : x1;
        y0 = key[i] < y0 ? key[i] : y0;
        y1 = key[i] > y1 ? key[i] : y1;
    }
    /* Room for column + 2 and row + 2, which the neighbour search forms. */
    g->bx = bits_of(x1 - x0 + 2);
    int by = bits_of(y1 - y0 + 2);
    for (size_t i = 0; i < n; i++) {
        key[i] = ((key[i] - y0) << g->bx) | (cx[i] - x0);
        g->row[i] = i;
    }
    if (radix_sort(&key, &g->row, n, g->bx + by))
        goto done;
    size_t nc = 0;
    for (size_t p = 0; p < n; p++)
        nc += p == 0 || key[p] != key[p - 1];
    if (!(g->c = malloc(nc * sizeof *g->c)) || mp_uf_init(&g->uf, n))
        goto done;
    g->n = n;
    g->nc = 0;
    for (size_t p = 0; p < n; p++) {
        size_t r = g->row[p];
        double xr = x[r], yr = y[r];
        g->x[p] = xr;
        g->y[p] = yr;
        if (p == 0 || key[p] != key[p - 1]) {
            cell *c = &g->c[g->nc++];
            c->key = key[p];
            c->start = p;
            c->x0 = c->x1 = xr;
            c->y0 = c->y1 = yr;
            c->clique = !g->link;
        }
        cell *c = &g->c[g->nc - 1];
        c->end = p + 1;
        c->x0 = fmin(c->x0, xr);
        c->x1 = fmax(c->x1, xr);
        c->y0 = fmin(c->y0, yr);
        c->y1 = fmax(c->y1, yr);
        if (clamped[r])
            c->clique = 0;
    }
    rc = 0;
done:
    free(key);
    free(cx);
    free(clamped);
    return rc;
}

/* Whether sorted stars s and t are linked: closer than crit and, with a
 * link test, passing it. */
static int linked(const grid *g, size_t s, size_t t, double c2)
{
    if (!mp_close(g->x[s], g->y[s], g->x[t], g->y[t], c2))
        return 0;
    return !g->link || g->link(g->ctx, g->row[s], g->row[t],
                               hypot(g->x[s] - g->x[t], g->y[s] - g->y[t]));
}

/* Link the stars of one cell among themselves. */
static void link_within(grid *g, const cell *a, double c2)
{
    if (a->clique) {
        for (size_t s = a->start + 1; s < a->end; s++)
            g->work += 1 + (size_t)mp_uf_union(&g->uf, a->start, s);
        return;
    }
    for (size_t s = a->start; s < a->end; s++)
        for (size_t t = s + 1; t < a->end; t++) {
            g->work++;
            if (linked(g, s, t, c2))
                g->work += (size_t)mp_uf_union(&g->uf, s, t);
        }
}

/* Whether two cells' bounding boxes are at least crit apart, by the same
 * floating-point operations as mp_close (rounding is monotone), so that no
 * pair of their stars can pass mp_close. */
static int boxes_apart(const cell *a, const cell *b, double c2)
{
    double gx = fmax(b->x0 - a->x1, a->x0 - b->x1), gy = fmax(b->y0 - a->y1, a->y0 - b->y1);
    gx = gx > 0 ? gx : 0;
    gy = gy > 0 ? gy : 0;
    return !(gx * gx + gy * gy < c2);
}

/* Link the stars of two different cells. */
static void link_between(grid *g, const cell *a, const cell *b, double c2)
{
    g->work++;
    if (boxes_apart(a, b, c2))
        return;
    int cliques = a->clique && b->clique;
    if (cliques && mp_uf_find(&g->uf, a->start) == mp_uf_find(&g->uf, b->start))
        return;
    for (size_t s = a->start; s < a->end; s++)
        for (size_t t = b->start; t < b->end; t++) {
            g->work++;
            if (linked(g, s, t, c2)) {
                g->work += (size_t)mp_uf_union(&g->uf, s, t);
                if (cliques)
                    return;       /* one close pair joins two cliques */
            }
        }
}

/* Compare every cell with the cells after it in its 5×5 neighbourhood. */
static void sweep(grid *g, double c2)
{
    uint64_t colmask = ((uint64_t)1 << g->bx) - 1;
    size_t cur[3] = {0, 0, 0};     /* cursors into rows +0 (unused), +1, +2 */
    for (size_t k = 0; k < g->nc; k++) {
        const cell *a = &g->c[k];
        uint64_t col = a->key & colmask, rowk = a->key >> g->bx;
        /* Same row: columns +1 and +2 follow directly, if present. */
        for (size_t j = k + 1; j < g->nc && j <= k + 2 && g->c[j].key <= a->key + 2; j++)
            link_between(g, a, &g->c[j], c2);
        for (int dy = 1; dy <= 2; dy++) {
            uint64_t r = rowk + (uint64_t)dy;
            uint64_t lo = (r << g->bx) | (col >= 2 ? col - 2 : 0), hi = (r << g->bx) | (col + 2);
            while (cur[dy] < g->nc && g->c[cur[dy]].key < lo)
                cur[dy]++;
            for (size_t j = cur[dy]; j < g->nc && g->c[j].key <= hi; j++)
                link_between(g, a, &g->c[j], c2);
        }
    }
}

int mp_grid_link(const double *x, const double *y, size_t n, double crit,
                 mp_group_link_fn link, void *ctx, size_t *label, size_t *work)
{
    if (work)
        *work = 0;
    if (n == 0)
        return 0;
    grid g;
    memset(&g, 0, sizeof g);
    g.link = link;
    g.ctx = ctx;
    if (grid_build(&g, x, y, n, crit * SIDE)) {
        grid_free(&g);
        return 1;
    }
    double c2 = crit * crit;
    for (size_t k = 0; k < g.nc; k++)
        link_within(&g, &g.c[k], c2);
    sweep(&g, c2);
    for (size_t p = 0; p < n; p++)
        label[g.row[p]] = g.row[mp_uf_find(&g.uf, p)];
    if (work)
        *work = g.work;
    grid_free(&g);
    return 0;
}
