/* new_stars.c — the bookkeeping between rounds of the pipeline: which
 * detections on the residual are new stars (not within matchrad of a known
 * star, nor of one the fit merged away or rejected), and where the fit's
 * gone stars were. */
#include <math.h>
#include <stdlib.h>
#include "pipeline/pipeline_priv.h"

/* A table's position columns, looked up once (not per row: by name they
 * were 1 % of a 2048² run's wall time on 16 threads, serial). */
typedef struct {
    int fx, fy, cx, cy;
} pos_cols;

static pos_cols pos_cols_of(const mp_table *t)
{
    return (pos_cols){mp_table_col(t, "XPSF_IMAGE"), mp_table_col(t, "YPSF_IMAGE"),
                      mp_table_col(t, "X_IMAGE"), mp_table_col(t, "Y_IMAGE")};
}

/* Position of a row: the fitted one when there is one. */
static void row_xy(const mp_table *t, const pos_cols *c, size_t r, double *x, double *y)
{
    *x = c->fx >= 0 ? mp_table_get(t, r, c->fx) : NAN;
    *y = c->fy >= 0 ? mp_table_get(t, r, c->fy) : NAN;
    if (!isfinite(*x) || !isfinite(*y)) {
        *x = c->cx >= 0 ? mp_table_get(t, r, c->cx) : NAN;
        *y = c->cy >= 0 ? mp_table_get(t, r, c->cy) : NAN;
    }
}

/* before = NUMBER and position of every row of t. */
int mp_pl_positions_of(const mp_table *t, mp_table *before)
{
    mp_table_free(before);
    mp_table_init(before);
    int n = mp_table_add_col(before, "NUMBER"), x = mp_table_add_col(before, "X_IMAGE"),
        y = mp_table_add_col(before, "Y_IMAGE"), tn = mp_table_col(t, "NUMBER");
    if (n < 0 || x < 0 || y < 0)
        return 1;
    pos_cols c = pos_cols_of(t);
    for (size_t r = 0; r < t->nrow; r++) {
        long row = mp_table_add_row(before);
        if (row < 0)
            return 1;
        double px, py;
        row_xy(t, &c, r, &px, &py);
        mp_table_set(before, (size_t)row, n, tn >= 0 ? mp_table_get(t, r, tn) : (double)r);
        mp_table_set(before, (size_t)row, x, px);
        mp_table_set(before, (size_t)row, y, py);
    }
    return 0;
}

/* Known stars on a grid of cells at least matchrad wide, so each new
 * detection is compared with its neighbourhood only: the 3 x 3 cells
 * around it hold every star within a cell's width.  Cells hold about one
 * star each: cells of matchrad (1.5 px at FWHM 3) cost 7 bytes a pixel
 * for the two grids, more than the frame (issue 14). */
typedef struct {
    long nx, ny;
    double cell;
    long *head, *next;   /* per cell: first row; per row: next row in its cell */
    double *x, *y;       /* per row: its position (row_xy) */
} star_grid;

static long cell_of(const star_grid *g, double x, double y)
{
    long i = (long)floor(x / g->cell), j = (long)floor(y / g->cell);
    i = i < 0 ? 0 : (i >= g->nx ? g->nx - 1 : i);
    j = j < 0 ? 0 : (j >= g->ny ? g->ny - 1 : j);
    return j * g->nx + i;
}

static int grid_build(star_grid *g, const mp_table *t, long fnx, long fny, double cell)
{
    double per_star = sqrt((double)fnx * (double)fny / (double)(t->nrow ? t->nrow : 1));
    g->cell = fmax(fmax(cell, 0.5), per_star);
    g->nx = (long)(fnx / g->cell) + 2;
    g->ny = (long)(fny / g->cell) + 2;
    g->head = malloc((size_t)(g->nx * g->ny) * sizeof *g->head);
    g->next = malloc((t->nrow ? t->nrow : 1) * sizeof *g->next);
    g->x = malloc((t->nrow ? t->nrow : 1) * sizeof *g->x);
    g->y = malloc((t->nrow ? t->nrow : 1) * sizeof *g->y);
    if (!g->head || !g->next || !g->x || !g->y)
        return 1;
    pos_cols c = pos_cols_of(t);
    for (long i = 0; i < g->nx * g->ny; i++)
        g->head[i] = -1;
    for (size_t r = 0; r < t->nrow; r++) {
        double x, y;
        row_xy(t, &c, r, &x, &y);
        g->x[r] = x;
        g->y[r] = y;
        if (!isfinite(x) || !isfinite(y)) {
            g->next[r] = -1;
            continue;
        }
        long c = cell_of(g, x, y);
        g->next[r] = g->head[c];
        g->head[c] = (long)r;
    }
    return 0;
}

static int grid_near(const star_grid *g, double x, double y, double r)
{
    long ci = (long)floor(x / g->cell), cj = (long)floor(y / g->cell);
    for (long j = cj - 1; j <= cj + 1; j++)
        for (long i = ci - 1; i <= ci + 1; i++) {
            if (i < 0 || j < 0 || i >= g->nx || j >= g->ny)
                continue;
            for (long k = g->head[j * g->nx + i]; k >= 0; k = g->next[k])
                if (hypot(g->x[k] - x, g->y[k] - y) < r)
                    return 1;
        }
    return 0;
}

/* Where a new star's values go, looked up at the first one (the columns
 * are added then, not when no star is new): map[c], t's column for
 * found's column c (−1 for skip, found's SNR); to[0..2], t's XPSF_IMAGE,
 * YPSF_IMAGE, FLUX_PSF, from[0..2] found's X_IMAGE, Y_IMAGE, FLUX (the
 * fit's start); to[3] t's SKY_PSF (NaN: none yet).  NULL when out of
 * memory. */
static int *column_map(mp_table *t, const mp_table *found, int fs, int to[4], int from[3])
{
    int *map = malloc((found->ncol ? found->ncol : 1) * sizeof *map);
    if (!map)
        return NULL;
    for (size_t c = 0; c < found->ncol; c++) {
        map[c] = (int)c == fs ? -1 : mp_table_add_col(t, found->cols[c].name);
        if (map[c] < 0 && (int)c != fs) {
            free(map);
            return NULL;
        }
    }
    const char *pairs[3][2] = {{"XPSF_IMAGE", "X_IMAGE"}, {"YPSF_IMAGE", "Y_IMAGE"},
                               {"FLUX_PSF", "FLUX"}};
    for (int p = 0; p < 3; p++) {
        to[p] = mp_table_col(t, pairs[p][0]);
        from[p] = mp_table_col(found, pairs[p][1]);
    }
    to[3] = mp_table_col(t, "SKY_PSF");
    return map;
}

/* Append the detections of found that are not within matchrad of a star of
 * t, numbered on from t's largest NUMBER; their fit starts from find's
 * position and flux.  Returns the number added, −1 when out of memory. */
long mp_pl_add_new_stars(mp_table *t, const mp_table *gone, const mp_table *found, long fnx,
                          long fny, double matchrad, double closerad, double closesnr)
{
    star_grid g = {0}, gg = {0};
    long added = -1;
    int *map = NULL;     /* found's columns in t, at the first new star */
    if (grid_build(&g, t, fnx, fny, matchrad) || grid_build(&gg, gone, fnx, fny, matchrad))
        goto done;
    int cnum = mp_table_add_col(t, "NUMBER");
    if (cnum < 0)
        goto done;
    double maxnum = 0;
    for (size_t r = 0; r < t->nrow; r++)
        if (mp_table_get(t, r, cnum) > maxnum)
            maxnum = mp_table_get(t, r, cnum);
    added = 0;
    int fx = mp_table_col(found, "X_IMAGE"), fy = mp_table_col(found, "Y_IMAGE");
    int fs = mp_table_col(found, MP_PL_SNR_COL), to[4], from[3];
    for (size_t r = 0; r < found->nrow && fx >= 0 && fy >= 0; r++) {
        double x = mp_table_get(found, r, fx), y = mp_table_get(found, r, fy);
        if (!isfinite(x) || !isfinite(y) || grid_near(&gg, x, y, matchrad))
            continue;
        /* Within matchrad of a known star: a second star there only when
         * it takes away a χ² of closesnr² (and is not on top of it). */
        if (grid_near(&g, x, y, matchrad) &&
            (fs < 0 || !(mp_table_get(found, r, fs) >= closesnr) || grid_near(&g, x, y, closerad)))
            continue;
        /* The grid holds the stars known before this round only: two
         * detections of one residual peak are find's business, not ours. */
        long row = mp_table_add_row(t);
        if (row < 0 || (!map && !(map = column_map(t, found, fs, to, from)))) {
            added = -1;
            goto done;
        }
        for (size_t c = 0; c < found->ncol; c++)
            if (map[c] >= 0)
                mp_table_set(t, (size_t)row, map[c], mp_table_get(found, r, (int)c));
        for (int p = 0; p < 3; p++)
            if (to[p] >= 0)
                mp_table_set(t, (size_t)row, to[p],
                             from[p] >= 0 ? mp_table_get(found, r, from[p]) : NAN);
        if (to[3] >= 0)
            mp_table_set(t, (size_t)row, to[3], NAN);
        mp_table_set(t, (size_t)row, cnum, maxnum + (double)++added);
    }
done:
    free(map);
    free(g.head);
    free(g.next);
    free(g.x);
    free(g.y);
    free(gg.head);
    free(gg.next);
    free(gg.x);
    free(gg.y);
    return added;
}

/* Remember where the stars the fit merged away or rejected were, so a
 * residual peak they leave is not found and added again every round.
 * before holds NUMBER, X_IMAGE, Y_IMAGE of every row given to the fit. */
int mp_pl_note_gone(mp_table *gone, const mp_table *before, const mp_table *after)
{
    int bn = mp_table_col(before, "NUMBER"), an = mp_table_col(after, "NUMBER");
    int gx = mp_table_add_col(gone, "X_IMAGE"), gy = mp_table_add_col(gone, "Y_IMAGE");
    if (bn < 0 || an < 0 || gx < 0 || gy < 0)
        return 0;
    /* NUMBERs of after are a subsequence of before's (the fit keeps the
     * order of the rows it keeps). */
    pos_cols bc = pos_cols_of(before);
    size_t j = 0;
    for (size_t i = 0; i < before->nrow; i++) {
        if (j < after->nrow && mp_table_get(after, j, an) == mp_table_get(before, i, bn)) {
            j++;
            continue;
        }
        double x, y;
        row_xy(before, &bc, i, &x, &y);
        long r = mp_table_add_row(gone);
        if (r < 0)
            return 1;
        mp_table_set(gone, (size_t)r, gx, x);
        mp_table_set(gone, (size_t)r, gy, y);
    }
    return 0;
}

