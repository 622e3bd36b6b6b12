/* group.c — grouping the stars of a table (group.h): positions out of the
 * table, components by union–find on the grid (grid.c), oversized groups
 * split (split.c), GROUP_ID / GROUP_SIZE / FLAGS written back. */
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "group/group.h"
#include "group/group_priv.h"

#define FLAG_SPLIT 2   /* design.md §4: group split */

void mp_group_opts_default(mp_group_opts *o)
{
    o->fitrad = 5.0;
    o->psfrad = 10.0;
    o->maxgroup = 60;
    o->weakgroup = 0;
    o->link = NULL;
    o->link_ctx = NULL;
}

static int check_opts(const mp_group_opts *o, char *err)
{
    if (!(isfinite(o->fitrad) && o->fitrad >= 0)) {
        snprintf(err, MP_ERRLEN, "fitrad: %g is not a finite number >= 0", o->fitrad);
        return 1;
    }
    if (!(isfinite(o->psfrad) && o->psfrad >= 0)) {
        snprintf(err, MP_ERRLEN, "psfrad: %g is not a finite number >= 0", o->psfrad);
        return 1;
    }
    double crit = o->psfrad + o->fitrad;
    if (!(crit >= 1e-100 && crit <= 1e100)) {
        snprintf(err, MP_ERRLEN, "psfrad + fitrad: critical separation %g is outside "
                 "[1e-100, 1e100]", crit);
        return 1;
    }
    if (o->maxgroup < 1) {
        snprintf(err, MP_ERRLEN, "maxgroup: %d is not >= 1", o->maxgroup);
        return 1;
    }
    return 0;
}

/* v with FLAGS bit 2 set (on) or cleared; NaN or negative counts as 0. */
static double with_split_bit(double v, int on)
{
    if (!(v >= 0))
        v = 0;
    int has = fmod(floor(v / 2), 2) == 1;
    if (on && !has)
        v += FLAG_SPLIT;
    else if (!on && has)
        v -= FLAG_SPLIT;
    return v;
}

/* Working arrays, all of n elements. */
typedef struct {
    double *x, *y;
    size_t *label;        /* part representative of each row */
    size_t *count;        /* stars per representative */
    size_t *id;           /* GROUP_ID per representative, 0 = not yet */
    unsigned char *split; /* row belongs to a split group */
} work;

static void work_free(work *w)
{
    free(w->x);
    free(w->y);
    free(w->label);
    free(w->count);
    free(w->id);
    free(w->split);
}

static int work_alloc(work *w, size_t n)
{
    size_t k = n ? n : 1;
    memset(w, 0, sizeof *w);
    w->x = malloc(k * sizeof *w->x);
    w->y = malloc(k * sizeof *w->y);
    w->label = malloc(k * sizeof *w->label);
    w->count = calloc(k, sizeof *w->count);
    w->id = calloc(k, sizeof *w->id);
    w->split = calloc(k, 1);
    if (!w->x || !w->y || !w->label || !w->count || !w->id || !w->split)
        return 1;
    return 0;
}

/* Split every component larger than maxgroup; label[] then holds parts. */
static int split_big(work *w, size_t n, size_t maxgroup)
{
    size_t total = 0;
    for (size_t r = 0; r < n; r++)
        if (w->count[r] > maxgroup)
            total += w->count[r];
    if (!total)
        return 0;
    /* Members of the big groups, group after group, in row order: id[]
     * serves here as each group's write position. */
    size_t *mem = malloc(total * sizeof *mem);
    if (!mem)
        return 1;
    size_t at = 0;
    for (size_t r = 0; r < n; r++)
        if (w->count[r] > maxgroup) {
            w->id[r] = at;
            at += w->count[r];
        }
    for (size_t i = 0; i < n; i++) {
        size_t r = w->label[i];
        if (w->count[r] > maxgroup) {
            mem[w->id[r]++] = i;
            w->split[i] = 1;
        }
    }
    for (size_t r = 0; r < n; r++)
        if (w->count[r] > maxgroup) {
            size_t m = w->count[r];
            mp_split_group(mem + w->id[r] - m, m, w->x, w->y, maxgroup, w->label);
        }
    free(mem);
    memset(w->id, 0, n * sizeof *w->id);
    memset(w->count, 0, n * sizeof *w->count);
    for (size_t i = 0; i < n; i++)
        w->count[w->label[i]]++;
    return 0;
}

int mp_group_table(mp_table *t, const mp_group_opts *o, char *err)
{
    if (check_opts(o, err))
        return 1;
    const char *xn = "XPSF_IMAGE", *yn = "YPSF_IMAGE";
    int cx = mp_table_col(t, xn), cy = mp_table_col(t, yn);
    if (cx < 0 || cy < 0) {
        xn = "X_IMAGE";
        yn = "Y_IMAGE";
        cx = mp_table_col(t, xn);
        cy = mp_table_col(t, yn);
    }
    if (cx < 0 || cy < 0) {
        snprintf(err, MP_ERRLEN, "table has no XPSF_IMAGE/YPSF_IMAGE or X_IMAGE/Y_IMAGE columns");
        return 1;
    }
    size_t n = t->nrow;
    for (size_t i = 0; i < n; i++) {
        double x = mp_table_get(t, i, cx), y = mp_table_get(t, i, cy);
        if (!isfinite(x) || !isfinite(y)) {
            snprintf(err, MP_ERRLEN, "row %zu: position %s, %s = %g, %g is not finite",
                     i + 1, xn, yn, x, y);
            return 1;
        }
    }
    work w;
    int rc = 1;
    if (work_alloc(&w, n))
        goto oom;
    for (size_t i = 0; i < n; i++) {
        w.x[i] = mp_table_get(t, i, cx);
        w.y[i] = mp_table_get(t, i, cy);
    }
    if (mp_grid_link(w.x, w.y, n, o->psfrad + o->fitrad, o->link, o->link_ctx, w.label, NULL))
        goto oom;
    for (size_t i = 0; i < n; i++)
        w.count[w.label[i]]++;
    if (split_big(&w, n, (size_t)o->maxgroup))
        goto oom;
    /* Columns last, so that an error above leaves t as it was. */
    int cg = mp_table_add_col(t, "GROUP_ID"), cs = mp_table_add_col(t, "GROUP_SIZE");
    int cf = mp_table_add_col(t, "FLAGS");
    if (cg < 0 || cs < 0 || cf < 0)
        goto oom;
    size_t ngroups = 0;
    for (size_t i = 0; i < n; i++) {
        size_t r = w.label[i];
        if (!w.id[r])
            w.id[r] = ++ngroups;
        mp_table_set(t, i, cg, (double)w.id[r]);
        mp_table_set(t, i, cs, (double)w.count[r]);
        mp_table_set(t, i, cf, with_split_bit(mp_table_get(t, i, cf), w.split[i]));
    }
    rc = 0;
    goto done;
oom:
    snprintf(err, MP_ERRLEN, "out of memory grouping %zu stars", n);
done:
    work_free(&w);
    return rc;
}
