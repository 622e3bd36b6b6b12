/* normalise.c — the planes' flux scale and centre (build_priv.h): a
 * star's table sums to 1 wherever it is (fluxes mean the same across the
 * frame) and its windowed centroid sits on the central element (the
 * table's centre and the stars' positions are otherwise degenerate). */
#include <math.h>
#include <stdlib.h>
#include <string.h>
#include "psf/build_priv.h"

static void scale_sums(mp_epsf *e)
{
    size_t nel = (size_t)e->nx * e->ny;
    double *p0 = e->planes;
    double s0 = 0.0;
    for (size_t i = 0; i < nel; i++)
        s0 += p0[i];
    if (!(s0 > 0))
        return;
    for (size_t i = 0; i < nel * (size_t)e->nterms; i++)
        e->planes[i] /= s0;
    for (int t = 1; t < e->nterms; t++) {
        double *p = e->planes + (size_t)t * nel, st = 0.0;
        for (size_t i = 0; i < nel; i++)
            st += p[i];
        for (size_t i = 0; i < nel; i++)
            p[i] -= st * p0[i];
    }
}

/* Every plane less a multiple of plane 0's derivatives so that its
 * windowed first moments vanish: P_t −= (M_t/K)·∂P_0 (a shift of −M_t/K
 * elements, to first order). */
static void recentre(mp_epsf *e, double fwhm, double *dx, double *dy)
{
    size_t nel = (size_t)e->nx * e->ny;
    double sw = fwhm / 2.35482 * e->os;
    double cx = (e->nx - 1) / 2, cy = (e->ny - 1) / 2;
    mp_five_point(e->planes, e->nx, e->ny, 0, dx);
    mp_five_point(e->planes, e->nx, e->ny, 1, dy);
    double kx = 0.0, ky = 0.0, mx[MP_EPSF_MAXT] = {0}, my[MP_EPSF_MAXT] = {0};
    for (int j = 0; j < e->ny; j++)
        for (int i = 0; i < e->nx; i++) {
            double u = i - cx, v = j - cy, wgt = exp(-0.5 * (u * u + v * v) / (sw * sw));
            size_t o = (size_t)j * e->nx + i;
            kx += wgt * u * dx[o];
            ky += wgt * v * dy[o];
            for (int t = 0; t < e->nterms; t++) {
                mx[t] += wgt * u * e->planes[(size_t)t * nel + o];
                my[t] += wgt * v * e->planes[(size_t)t * nel + o];
            }
        }
    if (kx == 0.0 || ky == 0.0)
        return;
    for (int t = 0; t < e->nterms; t++) {
        double a = mx[t] / kx, b = my[t] / ky;
        double *p = e->planes + (size_t)t * nel;
        for (size_t o = 0; o < nel; o++)
            p[o] -= a * dx[o] + b * dy[o];
    }
}

/* Every plane zero beyond support px of the central element.  Why: past
 * the radius where the stacked stars show light (psf/tablerad.c) the
 * elements hold only the build's noise, and a bright star's share of it
 * stays above the economy's painting level out to the table's edge, so
 * every neighbour was painted and fitted over the whole box (frame C of
 * compare_daophot.sh, the built table given as psf=: the fit's CPU 36.4 s
 * against the true table's 18.4 s; zeroed past the reach 20.6 s, the same
 * fluxes). */
static void cut_support(mp_epsf *e, double support)
{
    size_t nel = (size_t)e->nx * e->ny;
    double cx = (e->nx - 1) / 2, cy = (e->ny - 1) / 2, r2 = support * e->os * support * e->os;
    if (!(support > 0))
        return;
    for (int j = 0; j < e->ny; j++)
        for (int i = 0; i < e->nx; i++)
            if ((i - cx) * (i - cx) + (j - cy) * (j - cy) > r2)
                for (int t = 0; t < e->nterms; t++)
                    e->planes[(size_t)t * nel + (size_t)j * e->nx + i] = 0.0;
}

void mp_epsf_normalise(mp_epsf *e, double fwhm, double support)
{
    size_t nel = (size_t)e->nx * e->ny;
    double *d = malloc(2 * nel * sizeof *d);
    cut_support(e, support);
    scale_sums(e);
    if (d) {
        /* Twice: the first-order shift leaves a second-order rest. */
        recentre(e, fwhm, d, d + nel);
        recentre(e, fwhm, d, d + nel);
        free(d);
    }
    cut_support(e, support);    /* the shift's rest beyond it */
    scale_sums(e);
}
