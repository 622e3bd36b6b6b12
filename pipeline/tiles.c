/* tiles.c — a frame reduced in tiles (pipeline.h: mp_pipeline_run_tiled).
 *
 * The frame is cut into a grid of cores of tilesize x tilesize pixels; each
 * core is read with a margin on every side (a cfitsio section,
 * image[x1:x2,y1:y2]) and reduced as a frame of its own by the pipeline's
 * steps (mp_pl_reduce), so a star near the core's edge is fitted with its
 * neighbours from the margin, and only the core's residual is kept.
 *
 * Ownership: a star belongs to the tile whose core holds its fitted
 * position.  Two tiles fit a star near their common edge independently, so
 * one may place it just inside its core and the other just inside its own:
 * the candidates within matchrad of a core's edge (inside or out) are
 * therefore settled together, deepest in its tile's section first: a
 * candidate is kept unless one of another tile already kept lies within
 * matchrad.  So no star is counted twice, and none is lost because both
 * tiles put it across the line.  Stars deeper in a core are kept as they
 * are.  Memory: one tile's frame and maps at a time, the stars of the whole
 * frame, and the residual written a core at a time (mp_image_out). */
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <unistd.h>

#include "pipeline/pipeline_priv.h"

/* A star of a tile near its core's edge, waiting to be settled. */
typedef struct {
    double x, y, depth;   /* frame position; distance to its section's edge */
    long tile;
    size_t row;           /* in the edge table */
} edge_star;

typedef struct {
    const mp_pipeline_opts *o;
    const char *root;
    long nx, ny;                 /* the frame */
    double matchrad;
    long tile;                   /* index of the tile being reduced */
    long sx1, sy1, sx2, sy2;     /* its section, frame pixels (1-based, inclusive) */
    long cx1, cy1, cx2, cy2;     /* its core */
    mp_table all;                /* stars kept for good */
    mp_table edge;               /* stars near a core's edge, to settle */
    edge_star *es;
    size_t nes, capes;
    mp_image_out *res;
    double next_group;
    mp_pipeline_report rep;      /* summed over tiles */
} tiling;

static int oom(char *err)
{
    snprintf(err, MP_ERRLEN, "out of memory");
    return 1;
}

static const char *const shifted_x[] = {"X_IMAGE", "XPSF_IMAGE"};
static const char *const shifted_y[] = {"Y_IMAGE", "YPSF_IMAGE"};

/* Row r of t appended to dst (columns matched by name), moved to frame
 * coordinates, its group numbered on from the tiles before. */
static int copy_row(const tiling *g, const mp_table *t, size_t r, mp_table *dst)
{
    for (size_t c = 0; c < t->ncol; c++)
        if (mp_table_add_col(dst, t->cols[c].name) < 0)
            return 1;
    long k = mp_table_add_row(dst);
    if (k < 0)
        return 1;
    for (size_t c = 0; c < t->ncol; c++)
        mp_table_set(dst, (size_t)k, mp_table_col(dst, t->cols[c].name), mp_table_get(t, r, (int)c));
    for (int i = 0; i < 2; i++) {
        int cx = mp_table_col(dst, shifted_x[i]), cy = mp_table_col(dst, shifted_y[i]);
        if (cx >= 0)
            mp_table_set(dst, (size_t)k, cx, mp_table_get(dst, (size_t)k, cx) + (double)(g->sx1 - 1));
        if (cy >= 0)
            mp_table_set(dst, (size_t)k, cy, mp_table_get(dst, (size_t)k, cy) + (double)(g->sy1 - 1));
    }
    int cg = mp_table_col(dst, "GROUP_ID");
    if (cg >= 0)
        mp_table_set(dst, (size_t)k, cg, mp_table_get(dst, (size_t)k, cg) + g->next_group);
    return 0;
}

/* The fitted position of row r in frame pixels (find's when not fitted). */
static void position(const tiling *g, const mp_table *t, size_t r, double *x, double *y)
{
    int cx = mp_table_col(t, "XPSF_IMAGE"), cy = mp_table_col(t, "YPSF_IMAGE");
    *x = cx >= 0 ? mp_table_get(t, r, cx) : NAN;
    *y = cy >= 0 ? mp_table_get(t, r, cy) : NAN;
    if (!isfinite(*x) || !isfinite(*y)) {
        *x = mp_table_get(t, r, mp_table_col(t, "X_IMAGE"));
        *y = mp_table_get(t, r, mp_table_col(t, "Y_IMAGE"));
    }
    *x += (double)(g->sx1 - 1);
    *y += (double)(g->sy1 - 1);
}

static int push_edge(tiling *g, const mp_table *t, size_t r, double x, double y)
{
    if (g->nes == g->capes) {
        size_t cap = g->capes ? 2 * g->capes : 256;
        edge_star *e = realloc(g->es, cap * sizeof *e);
        if (!e)
            return 1;
        g->es = e;
        g->capes = cap;
    }
    double depth = fmin(fmin(x - (g->sx1 - 0.5), (g->sx2 + 0.5) - x),
                        fmin(y - (g->sy1 - 0.5), (g->sy2 + 0.5) - y));
    g->es[g->nes++] = (edge_star){x, y, depth, g->tile, g->edge.nrow};
    return copy_row(g, t, r, &g->edge);
}

/* Sort the tile's stars: deep in the core → kept; near the core's edge →
 * settled at the end; the rest belong to other tiles. */
static int take_stars(tiling *g, mp_table *t)
{
    double band = g->matchrad, gmax = 0;
    int cg = mp_table_col(t, "GROUP_ID");
    for (size_t r = 0; r < t->nrow; r++) {
        double x, y;
        position(g, t, r, &x, &y);
        if (cg >= 0)
            gmax = fmax(gmax, mp_table_get(t, r, cg));
        /* distance inside the core (negative: outside) */
        double in = fmin(fmin(x - (g->cx1 - 0.5), (g->cx2 + 0.5) - x),
                         fmin(y - (g->cy1 - 0.5), (g->cy2 + 0.5) - y));
        if (in > band) {
            if (copy_row(g, t, r, &g->all))
                return 1;
        } else if (in > -band && push_edge(g, t, r, x, y)) {
            return 1;
        }
    }
    g->next_group += gmax;
    return 0;
}

/* The core's residual into the frame's residual file. */
static int put_residual(tiling *g, const mp_frame *f, const float *res, char *err)
{
    return mp_pl_residual_put(g->res, f, res, g->cx1, g->cy1, g->cx2 - g->cx1 + 1,
                              g->cy2 - g->cy1 + 1, g->sx1 - 1, g->sy1 - 1, err);
}

static int tile_done(void *ctx, const mp_frame *f, mp_table *t, float *res, char *err)
{
    tiling *g = ctx;
    /* opened with the first tile's detector values */
    if (!g->res && mp_pl_residual_open(g->root, f, g->nx, g->ny, &g->res, err))
        return 1;
    if (take_stars(g, t))
        return oom(err);
    return put_residual(g, f, res, err);
}

static int deeper_first(const void *a, const void *b)
{
    const edge_star *p = a, *q = b;
    if (p->depth != q->depth)
        return p->depth > q->depth ? -1 : 1;
    return (p->tile > q->tile) - (p->tile < q->tile);
}

/* The edge stars settled (see the top of the file): brute force over the
 * kept ones, which are few (a band of 2 matchrad along the cores' edges). */
static int settle_edges(tiling *g)
{
    if (g->nes)
        qsort(g->es, g->nes, sizeof *g->es, deeper_first);
    size_t nkept = 0;
    for (size_t i = 0; i < g->nes; i++) {
        const edge_star *e = &g->es[i];
        int dup = 0;
        for (size_t k = 0; k < nkept && !dup; k++) {
            const edge_star *q = &g->es[k];
            dup = q->tile != e->tile && hypot(q->x - e->x, q->y - e->y) < g->matchrad;
        }
        if (!dup)
            g->es[nkept++] = *e;     /* kept ones gather at the front */
    }
    for (size_t k = 0; k < nkept; k++)
        if (copy_row(&(tiling){.sx1 = 1, .sy1 = 1}, &g->edge, g->es[k].row, &g->all))
            return 1;
    return 0;
}

static void add_report(mp_pipeline_report *s, const mp_pipeline_report *r)
{
    s->t_read += r->t_read; s->t_bkg += r->t_bkg; s->t_find += r->t_find;
    s->t_group += r->t_group; s->t_fit += r->t_fit;
    s->rounds = s->rounds > r->rounds ? s->rounds : r->rounds;
    s->screened += r->screened; s->found += r->found; s->added += r->added;
    s->cr_cores += r->cr_cores; s->cr_masked += r->cr_masked;
    s->cr_s = r->cr_s; s->cr_D = r->cr_D; s->cr_k = r->cr_k;
    mp_frame_report_add(&s->fit, &r->fit);
    s->fit.noconv += r->fit.noconv;  /* the tiles' last rounds, summed */
    s->fit.ngroups += r->fit.ngroups;
    for (int i = 0; i <= MP_SKY_MAXORDER; i++)
        s->fit.sky_groups[i] += r->fit.sky_groups[i];
    s->fit.ops_render = r->fit.ops_render;
    s->pairs_close += r->pairs_close; s->pairs_coupled += r->pairs_coupled;
    s->threshold = r->threshold;     /* one frame: the same in every tile */
    s->rdnoise = r->rdnoise;
}

/* One tile: its section read and reduced, its stars and residual taken. */
static int run_tile(tiling *g, const char *image, long margin, char *err)
{
    long nx = g->nx, ny = g->ny;
    g->sx1 = g->cx1 - margin > 1 ? g->cx1 - margin : 1;
    g->sy1 = g->cy1 - margin > 1 ? g->cy1 - margin : 1;
    g->sx2 = g->cx2 + margin < nx ? g->cx2 + margin : nx;
    g->sy2 = g->cy2 + margin < ny ? g->cy2 + margin : ny;
    size_t n = strlen(image) + 96;
    char *sec = malloc(n);
    if (!sec) {
        snprintf(err, MP_ERRLEN, "out of memory");
        return 1;
    }
    snprintf(sec, n, "%s[%ld:%ld,%ld:%ld]", image, g->sx1, g->sx2, g->sy1, g->sy2);
    fprintf(stderr, "matphot pipeline: tile %ld: %s (core [%ld:%ld,%ld:%ld])\n", g->tile + 1,
            sec, g->cx1, g->cx2, g->cy1, g->cy2);
    /* The section is a frame of its own: a variable PSF read at frame
     * positions. */
    mp_pipeline_opts *lo = g->o->fit.psf.field ? malloc(sizeof *lo) : NULL;
    if (g->o->fit.psf.field && !lo) {
        free(sec);
        snprintf(err, MP_ERRLEN, "out of memory");
        return 1;
    }
    if (lo) {
        *lo = *g->o;
        mp_fit_setup_local(&g->o->fit, (double)(g->sx1 - 1), (double)(g->sy1 - 1), &lo->fit);
    }
    mp_pipeline_report r;
    int rc = mp_pl_reduce(sec, lo ? lo : g->o, &r, tile_done, g, err);
    free(lo);
    free(sec);
    add_report(&g->rep, &r);
    return rc;
}

/* root.fit, root.cat (+ .reg; sky positions from the frame's header, read
 * through a one-pixel section) and the run report. */
static int write_tiled(tiling *g, const char *image, const char *root, char *err)
{
    int cn = mp_table_col(&g->all, "NUMBER");
    for (size_t r = 0; r < g->all.nrow && cn >= 0; r++)
        mp_table_set(&g->all, r, cn, (double)(r + 1));
    g->rep.fitted = (long)g->all.nrow;
    size_t n = strlen(image) + 16;
    char *one = malloc(n);
    mp_frame hf;
    memset(&hf, 0, sizeof hf);
    if (!one) {
        snprintf(err, MP_ERRLEN, "out of memory");
        return 1;
    }
    snprintf(one, n, "%s[1:1,1:1]", image);
    int rc = mp_pl_write_named(root, ".fit", &g->all, g->o->fit.fmt, NULL, NULL, err) ||
             mp_frame_read(one, &g->o->fit.dp, &hf, err) ||
             mp_pl_write_catalog(root, &hf, &g->all, g->o, NULL, err) ||
             mp_pl_write_report(image, root, &g->o->fit, &g->rep, &g->all, err);
    mp_frame_free(&hf);
    free(one);
    return rc;
}

int mp_pipeline_run_tiled(const char *image, const char *root, const mp_pipeline_opts *o,
                          long tilesize, long margin, mp_pipeline_report *rep, char *err)
{
    long nx, ny;
    if (mp_image_size(image, &nx, &ny, err))
        return 1;
    mp_tmp_sweep(o->sweeps, root);   /* every output is root.*: one directory */
    tiling g;
    memset(&g, 0, sizeof g);
    g.o = o;
    g.root = root;
    g.nx = nx;
    g.ny = ny;
    g.matchrad = isfinite(o->matchrad) ? o->matchrad : mp_prf_fwhm(&o->fit.model);
    mp_table_init(&g.all);
    mp_table_init(&g.edge);
    int rc = 0;
    long ntx = (nx + tilesize - 1) / tilesize, nty = (ny + tilesize - 1) / tilesize;
    fprintf(stderr, "matphot pipeline: %s: %ld x %ld in %ld x %ld tiles of %ld (margin %ld)\n",
            image, nx, ny, ntx, nty, tilesize, margin);
    for (long j = 0; j < nty && !rc; j++)
        for (long i = 0; i < ntx && !rc; i++) {
            g.tile = j * ntx + i;
            g.cx1 = 1 + i * tilesize;
            g.cy1 = 1 + j * tilesize;
            g.cx2 = g.cx1 + tilesize - 1 < nx ? g.cx1 + tilesize - 1 : nx;
            g.cy2 = g.cy1 + tilesize - 1 < ny ? g.cy1 + tilesize - 1 : ny;
            rc = run_tile(&g, image, margin, err);
        }
    if (!rc && settle_edges(&g))
        rc = oom(err);
    if (!rc && g.all.nrow == 0)
        rc = mp_pl_no_star(image, NULL, "", NAN, o, &g.rep, err);
    if (!rc)
        rc = write_tiled(&g, image, root, err);
    if (g.res)
        rc = mp_image_out_close(g.res, !rc, err) || rc;
    *rep = g.rep;
    mp_table_free(&g.all);
    mp_table_free(&g.edge);
    free(g.es);
    return rc;
}

/* No PSF given: it is built once, as a whole run builds it, on the
 * largest central section that maxmem holds (the whole frame when it
 * fits), written as root.psf.fits in frame coordinates, and every tile is
 * then fitted with it. */
static int tiles_with_built_psf(const char *image, const char *root, const mp_pipeline_opts *o,
                                long nx, long ny, long ts, long margin, mp_pipeline_report *rep,
                                char *err)
{
    long side = (long)floor(sqrt(o->maxmem / (MP_PL_BYTES_PER_PIXEL / 1048576.0)));
    side = side > ts + 2 * margin ? side : ts + 2 * margin;
    long w = side < nx ? side : nx, h = side < ny ? side : ny;
    long x1 = (nx - w) / 2 + 1, y1 = (ny - h) / 2 + 1;
    size_t n = strlen(image) + 96;
    char *sec = malloc(n);
    if (!sec)
        return oom(err);
    snprintf(sec, n, "%s[%ld:%ld,%ld:%ld]", image, x1, x1 + w - 1, y1, y1 + h - 1);
    fprintf(stderr, "matphot pipeline: %s: the PSF from %s\n", image, sec);
    int have = 0;
    int rc = mp_pl_psf_on(sec, root, o, x1 - 1, y1 - 1, nx, ny, &have, err);
    free(sec);
    /* The tiles reduced as `pipeline psf=root.psf.fits` would reduce them
     * (detection kernel and grouping radii from it too), the options read
     * in place (a fit setup holds pointers into itself: it is not copied). */
    mp_pipeline_opts *lo = rc ? NULL : malloc(sizeof *lo);
    char *path = rc ? NULL : mp_name_after(root, ".psf.fits");
    if (!rc && (!lo || !path))
        rc = oom(err);
    int own = 0;
    if (!rc && !have) {          /* no PSF star: the Gaussian of fwhm, said */
        *lo = *o;
        lo->build_psf = 0;
    } else if (!rc && !(rc = mp_params_set(o->ps, "psf", path, err))) {
        rc = mp_pl_opts_read(o->ps, lo, err);
        own = !rc;
        lo->sweeps = o->sweeps;
        char e2[MP_ERRLEN];
        mp_params_set(o->ps, "psf", "", e2);
    }
    if (!rc)
        rc = mp_pipeline_run_tiled(image, root, lo, ts, margin, rep, err);
    if (rc && have && path)
        unlink(path);            /* a failed run leaves no product (run.c) */
    if (own)
        mp_fit_setup_free(&lo->fit);
    free(lo);
    free(path);
    return rc;
}

int mp_pipeline_run_any(const char *image, const char *root, const mp_pipeline_opts *o,
                        mp_pipeline_report *rep, char *err)
{
    if (o->tilesize == 0)
        return mp_pipeline_run(image, root, o, rep, err);
    long nx, ny;
    if (mp_image_size(image, &nx, &ny, err))
        return 1;
    double fwhm = mp_prf_fwhm(&o->fit.model);
    long margin = o->tilemargin >= 0 ? o->tilemargin
                : (long)ceil(2.0 * (o->group.fitrad + o->group.psfrad) + 2.0 * fwhm);
    long ts = o->tilesize;
    /* A core smaller than twice its margin reads mostly margins (tilesize=1
     * on a 512² frame: 262 144 tiles of 59² pixels each), as maxmem's
     * tiles may not either. */
    if (ts > 0 && ts < 2 * margin && (ts < nx || ts < ny)) {
        snprintf(err, MP_ERRLEN, "tilesize: %ld px is less than twice the tile margin, %ld px "
                 "(a larger tilesize, or a smaller tilemargin)", ts, margin);
        return 1;
    }
    if (ts < 0) {      /* from the budget: whole when it fits, else tiles that do */
        double per = MP_PL_BYTES_PER_PIXEL / 1048576.0;
        if ((double)nx * (double)ny * per <= o->maxmem)
            return mp_pipeline_run(image, root, o, rep, err);
        ts = (long)floor(sqrt(o->maxmem / per)) - 2 * margin;
        if (ts < 2 * margin) {
            snprintf(err, MP_ERRLEN, "maxmem: %g MB holds no tile of twice its margin %ld px",
                     o->maxmem, margin);
            return 1;
        }
    }
    if (ts >= nx && ts >= ny)
        return mp_pipeline_run(image, root, o, rep, err);
    mp_pl_warn_whole_frame_only(o, "pipeline", image, "in tiles");
    if (o->build_psf)
        return tiles_with_built_psf(image, root, o, nx, ny, ts, margin, rep, err);
    return mp_pipeline_run_tiled(image, root, o, ts, margin, rep, err);
}
