/*
 * group.h — grouping of overlapping stars for simultaneous fitting (the
 * `group` stage of design.md §1; DAOPHOT GROUP, anchors.md §1.6).
 *
 * Two stars belong to the same group when they are closer than the critical
 * separation  crit = psfrad + fitrad  (strictly: d < crit): then one star's
 * PSF, defined out to psfrad, reaches the other's fitting region of radius
 * fitrad, and their fits are not independent.  Groups are the connected
 * components of that relation, so A–B and B–C put A, B and C together even
 * when A and C are far apart.  DAOPHOT's flux-dependent test (critsnratio)
 * needs fluxes and a PSF; this purely geometric rule needs neither, and is
 * the conservative limit of DAOPHOT's (critsnratio → 0).
 *
 * Cost: union–find (path compression, union by rank) over a uniform grid
 * whose occupied cells are found by a linear radix sort, so time and memory
 * are linear in the number of stars for a bounded density, however far
 * apart the stars are (group/grid.c).  Cells have side ~crit/2 rather than
 * crit: any two stars of one cell are then closer than crit and are linked
 * without distance tests, so many stars at one point also cost O(n), not
 * O(n²); each cell is compared with its 5×5 neighbourhood.
 *
 * Splitting rule (groups larger than maxgroup): such a group is cut in two
 * at the median of its longer bounding-box axis (the lower half by that
 * coordinate, ties broken by row number), and each half that is still too
 * large is cut again the same way, until every part has at most maxgroup
 * stars.  Every part becomes a group of its own; all members of a group that
 * was split get FLAGS bit 2 ("group split", design.md §4), because their
 * fits ignore neighbours that were cut away.  Why geometric and not
 * DAOPHOT's ALLSTAR rule (regroup with smaller critical separations, then
 * drop the faintest star): it needs no fluxes, always ends (stars at one
 * point are still split), drops no star, gives balanced parts, and costs
 * O(m log m) for a group of m stars.  The pipeline, which knows the PSF and
 * the fluxes, cuts such a component at its weakest couplings instead
 * (mp_group_capped with κ of fit.h's mp_coupling; pipeline/coupled.c).
 *
 * Errors: functions return 0 on success, nonzero on failure with one line in
 * err (MP_ERRLEN bytes).
 */
#ifndef MATPHOT_GROUP_H
#define MATPHOT_GROUP_H

#include "catalog/catalog.h"

/* Options of the grouping.  Critical separation = psfrad + fitrad (DAOPHOT
 * GROUP: a star's PSF reaches another's fitting region); maxgroup default 60
 * as DAOPHOT's daopars. */
/* mp_group_link_fn: whether two stars closer than the critical separation
 * are linked after all: rows ra and rb of the table, d their separation
 * [pixel] (< crit); nonzero links them.  The pipeline's test is the
 * coupling of their fits (fit.h, mp_coupling). */
typedef int (*mp_group_link_fn)(void *ctx, size_t ra, size_t rb, double d);

typedef struct {
    double fitrad, psfrad;   /* [pixel], finite, >= 0, sum > 0 */
    int maxgroup;            /* >= 1 */
    int weakgroup;           /* the pipeline's coupled groups: a link weaker
                              * than its couplefrac joins sets only up to this
                              * many stars (mp_group_capped's weakcap; 0:
                              * maxgroup); the group task ignores it */
    mp_group_link_fn link;   /* NULL: every pair closer than crit linked */
    void *link_ctx;
} mp_group_opts;

/* mp_group_opts_default: fitrad 5 (fit.par's default), psfrad 10,
 * maxgroup 60 (group.par's defaults), no link test. */
void mp_group_opts_default(mp_group_opts *o);

/* mp_group_table: group the stars of t.  Positions are XPSF_IMAGE/YPSF_IMAGE
 * when t has both, else X_IMAGE/Y_IMAGE.  Adds (or overwrites) GROUP_ID,
 * numbered 1..G in the order of each group's first row, and GROUP_SIZE, the
 * number of stars with that GROUP_ID; sets FLAGS bit 2 on members of groups
 * that were split (FLAGS is created as 0 where absent, NaN counts as 0; its
 * other bits are kept; bit 2 is cleared on everyone else, since it describes
 * this grouping and a regrouped table must not carry a stale one).
 * Errors (t unchanged): options out of range, no position columns, a row
 * whose position is not finite (named by its 1-based row), out of memory.
 * A table of 0 rows is fine (the columns are added). */
int mp_group_table(mp_table *t, const mp_group_opts *o, char *err);

/* A link between rows a and b of weight w (mp_group_capped). */
typedef struct {
    size_t a, b;
    double w;
} mp_group_pair;

/* mp_group_capped: label[i] (i < n) = a representative row of i's set,
 * the sets built by taking the np links of p strongest first (ties in row
 * order) and joining two sets only when together they hold at most
 * maxgroup rows, or weakcap rows for a link of weight below cutw (a
 * maximum spanning forest with capped trees; weakcap outside 1..maxgroup:
 * maxgroup); p is sorted.  When cut is not NULL, cut[a] and cut[b] are set
 * for each link of weight ≥ cutw refused by the cap.  Nonzero when out of
 * memory. */
int mp_group_capped(size_t n, mp_group_pair *p, size_t np, int maxgroup, int weakcap,
                    size_t *label, unsigned char *cut, double cutw);

/* mp_group_budget: as mp_group_capped, but a link joins its two sets only
 * while one of its stars still has more than budget of Σw² outside its
 * set (each w² counted outside until its link is reached, strongest
 * first, or found inside a set: a conservative count).  With w = κ, the
 * fraction of a star's variance its fit misses when one neighbour is held
 * is at most κ²: the groups are then as small as a budget of that per
 * star allows.  cut as mp_group_capped's (links refused by the cap). */
int mp_group_budget(size_t n, mp_group_pair *p, size_t np, int maxgroup, double budget,
                    size_t *label, unsigned char *cut, double cutw);

/* The "matphot group INPUT [output=...] [fitrad=...] ..." task
 * (params/group.par): read a table (- = stdin), group it, write it (empty
 * output = stdout); with verbose=yes, a histogram of group sizes on stderr.
 * argv[0] is "group".  Returns the exit status (0, 1 error, 2 usage). */
int mp_task_group(int argc, char **argv);

#endif
