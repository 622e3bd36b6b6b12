/* prf_deriv_box.c — how far from a star its position derivatives need
 * be drawn (issue 12).  A star's window reaches as far as its light
 * matters to the model, yet its x and y are told by its core: in the
 * wings ∂P/∂x is small where the variance is the sky's.  Measured here, on
 * the phase grid the fit draws from, as the share of the Fisher
 * information on x and y outside a box around the star, against
 * u = E/(B + RON²), the one number that share depends on for an isolated
 * star: E²(∂P/∂x)²/(E·P + B + RON²) = E·(∂P/∂x)²/(P + 1/u). */

#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include "fit/fit.h"

#define DB_PHASES 4         /* subpixel phases per axis */
#define DB_PER_DECADE 8     /* u values a decade */
#define DB_LOG_LO (-2)      /* u from 1e-2 ... */
#define DB_LOG_HI 9         /* ... to 1e9 */
#define DB_NU ((DB_LOG_HI - DB_LOG_LO) * DB_PER_DECADE + 1)
/* The fitting disc is drawn around where a star starts (fit/lm_pixels.c);
 * one that moves up to DB_MOVE px keeps the disc of fitrad − DB_MOVE
 * around where it is. */
#define DB_MOVE 1.0

static double u_at(int k)
{
    return pow(10.0, DB_LOG_LO + (double)k / DB_PER_DECADE);
}

/* The largest u of the grid at and below which the star at (X, Y), drawn
 * into p, dx, dy on box (x0, y0, w, h), loses at most smax of its
 * information on either axis: I_out/(I_disc + I_out) ≤ smax, I_out summed
 * beyond the box [floor(X − hw), ceil(X + hw)] × the same in y, I_disc
 * within rd px of the star (what a group fit always has of it: its own
 * fitting disc; the ring between them is counted in neither, as though it
 * were not fitted).  Every u at once, each pixel read once. */
static double phase_limit(const double *p, const double *dx, const double *dy, long x0,
                          long y0, int w, int h, double X, double Y, double hw, double rd,
                          double smax)
{
    double ax[DB_NU] = {0}, ay[DB_NU] = {0}, ox[DB_NU] = {0}, oy[DB_NU] = {0}, c[DB_NU];
    for (int k = 0; k < DB_NU; k++)
        c[k] = 1.0 / u_at(k);
    long bx0 = (long)floor(X - hw), bx1 = (long)ceil(X + hw);
    long by0 = (long)floor(Y - hw), by1 = (long)ceil(Y + hw);
    for (int j = 0; j < h; j++)
        for (int i = 0; i < w; i++) {
            size_t o = (size_t)j * w + i;
            long x = x0 + i, y = y0 + j;
            int out = x < bx0 || x > bx1 || y < by0 || y > by1;
            int disc = (x - X) * (x - X) + (y - Y) * (y - Y) <= rd * rd;
            double P = p[o] > 0 ? p[o] : 0.0, gx = dx[o] * dx[o], gy = dy[o] * dy[o];
            if (!(out || disc) || (gx == 0.0 && gy == 0.0))
                continue;
            double fo = out ? 1.0 : 0.0;
#pragma omp simd
            for (int k = 0; k < DB_NU; k++) {
                double v = 1.0 / (P + c[k]);
                ax[k] += v * gx;
                ay[k] += v * gy;
                ox[k] += fo * v * gx;
                oy[k] += fo * v * gy;
            }
        }
    for (int k = 0; k < DB_NU; k++)
        if (ox[k] > smax * ax[k] || oy[k] > smax * ay[k])
            return k ? u_at(k - 1) : 0.0;
    return INFINITY;
}

int mp_prf_cache_deriv_box(mp_prf_cache *c, const mp_prf_model *m, double fitrad, double smax,
                           char *err)
{
    c->dbox_hw = 0.0;
    c->dbox_u = 0.0;
    double h = mp_fit_core_halfwidth(fitrad), rd = fitrad - DB_MOVE;
    if (!(h > 0) || !(rd > 0) || !(smax > 0) || !mp_prf_cache_usable(c, m))
        return 0;
    double lim = INFINITY, *buf = NULL;
    size_t cap = 0;
    /* A variable PSF: at its origin and the eight points ±scale/2 from it
     * (fit/prf.c's phase_maxima takes the same). */
    const mp_psf_field *fd = m->psf->field;
    int npt = fd && fd->order > 0 ? 9 : 1;
    for (int b = 0; b < npt * DB_PHASES * DB_PHASES; b++) {
        int q = b / (DB_PHASES * DB_PHASES);
        double cx = npt > 1 ? floor(fd->x0 + (q % 3 - 1) * 0.5 * fd->xscale) : 1000.0;
        double cy = npt > 1 ? floor(fd->y0 + (q / 3 - 1) * 0.5 * fd->yscale) : 1000.0;
        double X = cx + (double)(b % DB_PHASES) / DB_PHASES;
        double Y = cy + (double)(b / DB_PHASES % DB_PHASES) / DB_PHASES;
        long x0, y0;
        int w, bh;
        mp_prf_box(m, X, Y, &x0, &y0, &w, &bh);
        size_t n = (size_t)w * bh;
        if (n > cap) {
            free(buf);
            if (!(buf = malloc(3 * n * sizeof *buf))) {
                snprintf(err, MP_ERRLEN, "out of memory for the derivatives' box");
                return 1;
            }
            cap = n;
        }
        if (mp_prf_cache_render(c, m, X, Y, x0, y0, w, bh, buf, buf + n, buf + 2 * n, 0)) {
            lim = 0.0;              /* not usable: none served */
            break;
        }
        double l = phase_limit(buf, buf + n, buf + 2 * n, x0, y0, w, bh, X, Y, h, rd, smax);
        lim = l < lim ? l : lim;
    }
    free(buf);
    c->dbox_hw = h;
    c->dbox_u = lim;
    return 0;
}
