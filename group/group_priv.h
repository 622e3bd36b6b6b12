/*
 * group_priv.h — private to group/: union–find, the spatial grid that links
 * close stars, and the splitting of oversized groups.
 */
#ifndef MATPHOT_GROUP_PRIV_H
#define MATPHOT_GROUP_PRIV_H

#include <stddef.h>

#include "group/group.h"

/* ---- union_find.c ------------------------------------------------------ */

/* Disjoint sets over 0..n-1 with path compression and union by rank
 * (inverse-Ackermann amortised time per operation). */
typedef struct {
    size_t *parent;
    unsigned char *rank;   /* <= log2(n) < 64 */
    size_t n;
} mp_uf;

/* mp_uf_init: n singletons; nonzero when out of memory (u then holds
 * nothing to free). */
int mp_uf_init(mp_uf *u, size_t n);

/* mp_uf_free: release; safe on a zeroed or freed set. */
void mp_uf_free(mp_uf *u);

/* mp_uf_find: representative of i's set; compresses the path. */
size_t mp_uf_find(mp_uf *u, size_t i);

/* mp_uf_union: merge the sets of a and b; 1 when they were distinct. */
int mp_uf_union(mp_uf *u, size_t a, size_t b);

/* ---- grid.c ------------------------------------------------------------ */

/* mp_close: the one test of "closer than the critical separation" (c2 =
 * crit²), used by the grid and by the tests' brute force alike. */
static inline int mp_close(double xa, double ya, double xb, double yb, double c2)
{
    double dx = xa - xb, dy = ya - yb;
    return dx * dx + dy * dy < c2;
}

/* mp_grid_link: label the n points (x, y) (finite) by connected component
 * of the relation mp_close(·, ·, crit²) (crit finite, > 0) and, when link is
 * not NULL, link(ctx, i, j, d) (cells are then no cliques): label[i] = the
 * row of one member of i's component, the same for all its members.
 * When work is not NULL it receives the operations done after the sort:
 * cell pairs compared + distance tests + unions — a machine-independent
 * measure of cost, so a test can check linearity without a clock.
 * Nonzero when out of memory. */
int mp_grid_link(const double *x, const double *y, size_t n, double crit,
                 mp_group_link_fn link, void *ctx, size_t *label, size_t *work);

/* ---- split.c ----------------------------------------------------------- */

/* mp_split_group: split the group of m rows mem[0..m-1] (m > maxgroup >= 1)
 * by the rule of group.h (median of the longer bounding-box axis, recursively)
 * and write, for each member row r, rep[r] = the smallest row of its part.
 * mem is reordered.  Needs no memory; recursion depth ~log2(m / maxgroup). */
void mp_split_group(size_t *mem, size_t m, const double *x, const double *y,
                   size_t maxgroup, size_t *rep);

#endif
