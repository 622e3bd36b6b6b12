/* sirt_mask.c — each PSF star's mask of table elements where only it
 * shows light (build_priv.h): a neighbour too faint to be found, whose
 * wings the per-element 4 σ clip of sirt.c would let into the table (the
 * segmented scene of validate/PSFBUILD.md: stars fainter than 1e4 e-
 * left in raise the fluxes' bias from 0.1 to 1.0 σ in the brightest bin). */
#include <math.h>
#include <stdlib.h>
#include <string.h>
#include "psf/build_priv.h"

/* Cluster of hits: element (i, j) hit, with at least need hit neighbours. */
static int cluster(const unsigned char *m, int nx, int ny, int i, int j, int need)
{
    if (!(m[(size_t)j * nx + i] & MP_EPSF_HIT))
        return 0;
    int c = 0;
    for (int b = j - 1; b <= j + 1; b++)
        for (int a = i - 1; a <= i + 1; a++)
            if ((a != i || b != j) && a >= 0 && b >= 0 && a < nx && b < ny &&
                (m[(size_t)b * nx + a] & MP_EPSF_HIT))
                c++;
    return c >= need;
}

/* Whether m[0..n) holds a hit: one or-reduction the compiler vectorises
 * (a star without a hit is most stars in most steps). */
static int any_hit(const unsigned char *m, size_t n)
{
    unsigned char acc = 0;
    for (size_t i = 0; i < n; i++)
        acc |= m[i];
    return (acc & MP_EPSF_HIT) != 0;
}

/* One star's mask m: the clusters of hits dilated by h, rows first
 * (row marks the row-dilation; a row without a hit has no cluster), then
 * columns, a row at a time (last: each column's last marked row; every
 * element of m written once, MP_EPSF_MASKED or 0: the loops run along
 * rows, which the compiler vectorises); a star without a hit only
 * cleared.  row: nx·ny bytes, last: nx ints. */
static void dilate_star(unsigned char *m, int nx, int ny, int h, int need, unsigned char *row,
                        int *last)
{
    if (!any_hit(m, (size_t)nx * ny)) {
        memset(m, 0, (size_t)nx * ny);
        return;
    }
    for (int j = 0; j < ny; j++) {
        unsigned char *rj = row + (size_t)j * nx;
        memset(rj, 0, (size_t)nx);
        if (!any_hit(m + (size_t)j * nx, (size_t)nx))
            continue;
        int lc = -h - 1;       /* last cluster column seen */
        for (int i = 0; i < nx + h; i++) {
            if (i < nx && cluster(m, nx, ny, i, j, need))
                lc = i;
            int t = i - h;      /* covered by a cluster within h on the left or right */
            if (t >= 0 && t < nx && i - lc <= 2 * h)
                rj[t] = 1;
        }
    }
    for (int i = 0; i < nx; i++)
        last[i] = -h - 1;
    for (int j = 0; j < ny + h; j++) {
        if (j < ny) {
            const unsigned char *rj = row + (size_t)j * nx;
            for (int i = 0; i < nx; i++)
                last[i] = rj[i] ? j : last[i];
        }
        int t = j - h;         /* covered by a marked row within h above or below */
        if (t < 0 || t >= ny)
            continue;
        unsigned char *mt = m + (size_t)t * nx;
        for (int i = 0; i < nx; i++)
            mt[i] = j - last[i] <= 2 * h ? MP_EPSF_MASKED : 0;
    }
}

int mp_epsf_sirt_dilate(mp_epsf_sirt *w, const mp_epsf *e, size_t n, double rd)
{
    int nx = e->nx, ny = e->ny, h = (int)ceil(rd);
    int need = (e->os * e->os < 3 ? e->os * e->os : 3) - 1;
    size_t nel = w->nel;
    int failed = 0;
#pragma omp parallel reduction(| : failed)
    {
        unsigned char *row = malloc(nel);
        int *last = malloc((size_t)nx * sizeof *last);
        failed = !row || !last;
#pragma omp for schedule(static)
        for (size_t k = 0; k < n; k++)
            if (row && last)
                dilate_star(w->mask + k * nel, nx, ny, h, need, row, last);
        free(row);
        free(last);
    }
    return failed;
}
