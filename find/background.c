/* background.c — mp_bkg_estimate (find.h): a mesh of boxes, SExtractor's
 * clipped mode in each, a median filter over the meshes and a bicubic
 * spline to every pixel (anchors.md §2.1: BACK_SIZE, BACK_FILTERSIZE). */
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "find/find_priv.h"

/* The mesh grid along one axis: nb boxes of equal size ±1, box i covering
 * [lo[i], lo[i+1]), centred at c[i] (0-based pixel coordinates). */
typedef struct {
    int nb;
    long *lo;
    double *c;
} axis_grid;

static int grid_make(long n, int mesh, axis_grid *g)
{
    long nb = (long)floor((double)n / mesh + 0.5);
    if (nb < 1)
        nb = 1;
    g->nb = (int)nb;
    g->lo = malloc((size_t)(nb + 1) * sizeof *g->lo);
    g->c = malloc((size_t)nb * sizeof *g->c);
    if (!g->lo || !g->c)
        return 1;
    for (long i = 0; i <= nb; i++)
        g->lo[i] = (long)((long long)i * n / nb);
    for (long i = 0; i < nb; i++)
        g->c[i] = 0.5 * (double)(g->lo[i] + g->lo[i + 1] - 1);
    return 0;
}

static void grid_free(axis_grid *g)
{
    free(g->lo);
    free(g->c);
}

/* Mode and rms of every mesh; valid[m] = 0 where fewer than half of the
 * mesh's pixels are good (SExtractor's BACK_MINGOODFRAC of 0.5). */
static int mesh_values(const mp_frame *f, const axis_grid *gx, const axis_grid *gy,
                       double *sky, double *rms, unsigned char *valid)
{
    long nx = f->im.nx;
    long wmax = 0, hmax = 0;
    for (int i = 0; i < gx->nb; i++)
        if (gx->lo[i + 1] - gx->lo[i] > wmax)
            wmax = gx->lo[i + 1] - gx->lo[i];
    for (int j = 0; j < gy->nb; j++)
        if (gy->lo[j + 1] - gy->lo[j] > hmax)
            hmax = gy->lo[j + 1] - gy->lo[j];
    int nomem = 0;
    int nmesh = gx->nb * gy->nb;
    double shrink = mpf_clip_shrink(3.0);
#pragma omp parallel
    {
        double *buf = malloc((size_t)(wmax * hmax) * sizeof *buf);
        uint64_t *work = malloc((size_t)(wmax * hmax) * 2 * sizeof *work);
        if (!buf || !work) {
            free(buf);
            buf = NULL;
#pragma omp atomic write
            nomem = 1;
        }
#pragma omp for schedule(dynamic, 4)
        for (int m = 0; m < nmesh; m++) {
            valid[m] = 0;
            sky[m] = rms[m] = 0.0;
            if (!buf)
                continue;
            int bx = m % gx->nb, by = m / gx->nb;
            size_t n = 0, area = 0;
            for (long y = gy->lo[by]; y < gy->lo[by + 1]; y++)
                for (long x = gx->lo[bx]; x < gx->lo[bx + 1]; x++) {
                    size_t i = (size_t)y * (size_t)nx + (size_t)x;
                    area++;
                    if (f->mask && (f->mask[i] & (MP_MASK_BAD | MP_MASK_SATURATED)))
                        continue;
                    if (!isfinite(f->im.pix[i]))
                        continue;
                    buf[n++] = f->im.pix[i];
                }
            if (n == 0 || 2 * n < area)
                continue;
            if (mpf_mesh_stats(buf, n, shrink, work, &sky[m], &rms[m]) == 0)
                valid[m] = 1;
        }
        free(buf);
        free(work);
    }
    return nomem;
}

/* Fill invalid meshes, ring by ring, with the mean of their valid
 * 8-neighbours (SExtractor fills bad meshes from their neighbours).
 * Returns the number of valid meshes there were at the start. */
static int fill_invalid(double *v, double *r, unsigned char *valid, int nbx, int nby)
{
    int n = nbx * nby, nvalid = 0;
    for (int m = 0; m < n; m++)
        nvalid += valid[m];
    if (nvalid == 0 || nvalid == n)
        return nvalid;
    unsigned char *next = malloc((size_t)n);
    if (!next) {
        /* Fall back to the mean of all valid meshes: still a usable map. */
        double sv = 0.0, sr = 0.0;
        for (int m = 0; m < n; m++)
            if (valid[m]) {
                sv += v[m];
                sr += r[m];
            }
        for (int m = 0; m < n; m++)
            if (!valid[m]) {
                v[m] = sv / nvalid;
                r[m] = sr / nvalid;
                valid[m] = 1;
            }
        return nvalid;
    }
    for (int left = n - nvalid; left > 0;) {
        memcpy(next, valid, (size_t)n);
        for (int m = 0; m < n; m++) {
            if (valid[m])
                continue;
            int bx = m % nbx, by = m / nbx, k = 0;
            double sv = 0.0, sr = 0.0;
            for (int j = by - 1; j <= by + 1; j++)
                for (int i = bx - 1; i <= bx + 1; i++)
                    if (i >= 0 && i < nbx && j >= 0 && j < nby && valid[j * nbx + i]) {
                        sv += v[j * nbx + i];
                        sr += r[j * nbx + i];
                        k++;
                    }
            if (k) {
                v[m] = sv / k;
                r[m] = sr / k;
                next[m] = 1;
                left--;
            }
        }
        memcpy(valid, next, (size_t)n);
    }
    free(next);
    return nvalid;
}

/* Median filter of half-width h over the mesh grid.  At the edges the
 * window shrinks symmetrically about the mesh (SExtractor truncates it),
 * so that a plane stays a plane. */
static int median_filter(double *v, int nbx, int nby, int h)
{
    if (h <= 0)
        return 0;
    size_t n = (size_t)nbx * (size_t)nby;
    double *in = malloc(n * sizeof *in);
    double *win = malloc((size_t)(2 * h + 1) * (size_t)(2 * h + 1) * sizeof *win);
    if (!in || !win) {
        free(in);
        free(win);
        return 1;
    }
    memcpy(in, v, n * sizeof *in);
    for (int by = 0; by < nby; by++)
        for (int bx = 0; bx < nbx; bx++) {
            int hx = h, hy = h;
            if (bx < hx) hx = bx;
            if (nbx - 1 - bx < hx) hx = nbx - 1 - bx;
            if (by < hy) hy = by;
            if (nby - 1 - by < hy) hy = nby - 1 - by;
            size_t k = 0;
            for (int j = by - hy; j <= by + hy; j++)
                for (int i = bx - hx; i <= bx + hx; i++)
                    win[k++] = in[(size_t)j * nbx + i];
            v[(size_t)by * nbx + bx] = mpf_median_small(win, k);
        }
    free(in);
    free(win);
    return 0;
}

/* The bicubic natural spline through the mesh centres, kept by rows: for
 * image row y, the values of the spline along y of every mesh column at
 * y (vals) and the second derivatives of the spline along x through them
 * (d2).  A pixel's value is then one cubic in x (mp_bkg_sky): the same
 * arithmetic, value for value, as a map of every pixel, in 16/mesh bytes
 * a pixel instead of 4 a map (issue 14: the whole-frame run's memory). */
static int spline_rows(const double *v, const axis_grid *gx, const axis_grid *gy, long ny,
                       double *vals, double *d2)
{
    int nbx = gx->nb, nby = gy->nb;
    /* vt, d2col [bx*nby + by]: mesh column bx and its second derivatives
     * along y. */
    size_t nm = (size_t)nbx * (size_t)nby;
    double *vt = malloc(nm * sizeof *vt);
    double *d2col = malloc(nm * sizeof *d2col);
    double *work = malloc((size_t)(nby > nbx ? nby : nbx) * sizeof *work);
    if (!vt || !d2col || !work) {
        free(vt);
        free(d2col);
        free(work);
        return 1;
    }
    for (int bx = 0; bx < nbx; bx++) {
        for (int by = 0; by < nby; by++)
            vt[(size_t)bx * nby + by] = v[(size_t)by * nbx + bx];
        mpf_spline_init(gy->c, vt + (size_t)bx * nby, nby, d2col + (size_t)bx * nby, work);
    }
    /* The rows in parallel (serial, they were a tenth of the background's
     * time: issue 14), each thread with its own work array. */
    int nomem = 0;
#pragma omp parallel reduction(| : nomem)
    {
        double *wk = malloc((size_t)(nby > nbx ? nby : nbx) * sizeof *wk);
        nomem |= !wk;
#pragma omp for schedule(static)
        for (long y = 0; y < ny; y++) {
            double *row = vals + (size_t)y * (size_t)nbx;
            for (int bx = 0; bx < nbx; bx++) {
                int k = 0;
                row[bx] = mpf_spline_eval(gy->c, vt + (size_t)bx * nby, d2col + (size_t)bx * nby,
                                          nby, (double)y, &k);
            }
            if (wk)
                mpf_spline_init(gx->c, row, nbx, d2 + (size_t)y * (size_t)nbx, wk);
        }
        free(wk);
    }
    free(work);
    free(vt);
    free(d2col);
    return nomem;
}

void mp_bkg_free(mp_bkg *b)
{
    if (!b)
        return;
    free(b->cx);
    free(b->vals);
    free(b->xv);
    free(b->xvd);
    free(b->xs);
    free(b->cell0);
    memset(b, 0, sizeof *b);
}

size_t mp_bkg_bytes(const mp_bkg *b)
{
    /* the rms rows are given back once the noise model replaces them;
     * the stars' flux-squared term: MP_BKG_XS values a star, a cell
     * index of 8 bytes per nxv² px and v per class and ring */
    size_t ex = b->nxs * MP_BKG_XS * sizeof(double) +
                (b->cell0 ? ((size_t)b->ncx * (size_t)b->ncy + 1) * sizeof *b->cell0 : 0) +
                (b->xv ? (size_t)b->nxc * (size_t)b->nxv * sizeof *b->xv : 0) +
                (b->xvd ? (size_t)b->nxc * (size_t)b->nxv * MP_BKG_NSECT * sizeof *b->xvd : 0);
    return ex + (b->cx ? (size_t)b->nbx * sizeof *b->cx * (1 + (b->model ? 2 : 4) * (size_t)b->ny)
                       : 0);
}

/* Room for the rows of nbx meshes (sky and rms: values and d2). */
static int rows_alloc(mp_bkg *b, const axis_grid *gx)
{
    size_t n = (size_t)gx->nb * (size_t)b->ny;
    b->nbx = gx->nb;
    b->cx = malloc((size_t)gx->nb * sizeof *b->cx);
    b->vals = malloc(4 * n * sizeof *b->vals);
    if (!b->cx || !b->vals)
        return 1;
    memcpy(b->cx, gx->c, (size_t)gx->nb * sizeof *b->cx);
    return 0;
}

int mp_bkg_set_flat(mp_bkg *b, long nx, long ny, double sky, double rms)
{
    mp_bkg_free(b);
    b->nx = nx;
    b->ny = ny;
    axis_grid g1 = {0};
    int rc = grid_make(1, 1, &g1) || rows_alloc(b, &g1);
    grid_free(&g1);
    if (rc) {
        mp_bkg_free(b);
        return 1;
    }
    size_t n = (size_t)ny;
    for (size_t y = 0; y < n; y++) {
        b->vals[y] = sky;
        b->vals[n + y] = 0.0;
        b->vals[2 * n + y] = rms;
        b->vals[3 * n + y] = 0.0;
    }
    return 0;
}

int mp_bkg_estimate(const mp_frame *f, int mesh, int filter, mp_bkg *b, char *err)
{
    memset(b, 0, sizeof *b);
    if (mesh < 1) {
        snprintf(err, MP_ERRLEN, "mesh: %d must be at least 1 pixel", mesh);
        return 1;
    }
    if (filter < 1 || filter % 2 == 0) {
        snprintf(err, MP_ERRLEN, "filter: %d must be an odd number of meshes >= 1", filter);
        return 1;
    }
    long nx = f->im.nx, ny = f->im.ny;
    if (nx < 1 || ny < 1 || !f->im.pix) {
        snprintf(err, MP_ERRLEN, "image is empty (%ld x %ld pixels)", nx, ny);
        return 1;
    }
    axis_grid gx = {0}, gy = {0};
    double *sky = NULL, *rms = NULL;
    unsigned char *valid = NULL;
    int rc = 1;
    b->nx = nx;
    b->ny = ny;
    if (grid_make(nx, mesh, &gx) || grid_make(ny, mesh, &gy) || rows_alloc(b, &gx))
        goto nomem;
    size_t nm = (size_t)gx.nb * (size_t)gy.nb, nrow = (size_t)gx.nb * (size_t)ny;
    sky = malloc(nm * sizeof *sky);
    rms = malloc(nm * sizeof *rms);
    valid = malloc(nm);
    if (!sky || !rms || !valid)
        goto nomem;
    if (mesh_values(f, &gx, &gy, sky, rms, valid))
        goto nomem;
    if (fill_invalid(sky, rms, valid, gx.nb, gy.nb) == 0) {
        /* No good pixel anywhere: a flat map of zeros; detection will
         * find nothing (every footprint lacks good pixels). */
        rc = mp_bkg_set_flat(b, nx, ny, 0.0, 0.0);
        if (rc)
            goto nomem;
        goto done;
    }
    if (median_filter(sky, gx.nb, gy.nb, filter / 2) ||
        median_filter(rms, gx.nb, gy.nb, filter / 2) ||
        spline_rows(sky, &gx, &gy, ny, b->vals, b->vals + nrow) ||
        spline_rows(rms, &gx, &gy, ny, b->vals + 2 * nrow, b->vals + 3 * nrow))
        goto nomem;
    rc = 0;
    goto done;
nomem:
    snprintf(err, MP_ERRLEN, "out of memory for the background map (%ld x %ld pixels)", nx, ny);
    mp_bkg_free(b);
done:
    grid_free(&gx);
    grid_free(&gy);
    free(sky);
    free(rms);
    free(valid);
    return rc;
}
