/* error_scale.c — the fit's error bars widened by what the residual holds
 * at the PSF's scale (mp_pl_error_scale, pipeline_priv.h).
 *
 * A star's fitted flux and position take up whatever the frame holds
 * under its PSF beyond the stars and sky fitted: the light of stars too
 * faint to find, the misfit of neighbours' tables.  The fit's errors count
 * photon noise only, so on a crowded real frame they are too small
 * (47 Tuc's core: artificial stars scatter by 1.5-3.9 of their
 * MAGERR_PSF).  What a star at a random place would take up is measured
 * directly, as artificial-star tests and the "random apertures" of deep
 * fields do: the fit's own linear estimator (PSF, its two position
 * derivatives and a constant sky, Poisson weights, the pixels within
 * fitrad) applied to the final residual at places on a grid of windows
 * that do not overlap, each estimate over its Poisson σ.  Their robust σ
 * is the factor each error needs: 1 where the residual is noise. */
#include <lapacke.h>
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "pipeline/pipeline_priv.h"

enum { NPAR = 4 };              /* flux, x, y, sky */

/* A thread's room for one place: the three templates rendered on the
 * window's box, scratch for the window's residual values, the render's
 * work space. */
typedef struct {
    double *prf, *dx, *dy;      /* rendered on the window's box */
    double *vals;               /* scratch: the window's residual values */
    mp_prf_work wk;
} place_work;

/* The box [x0, x1) × [y0, y1) (1-based) of the pixels within r of (x, y);
 * 0 when it leaves the frame (the place is not used). */
static int window_box(const mp_frame *f, double x, double y, double r, long *x0, long *y0,
                      long *x1, long *y1)
{
    *x0 = (long)ceil(x - r);
    *y0 = (long)ceil(y - r);
    *x1 = (long)floor(x + r) + 1;
    *y1 = (long)floor(y + r) + 1;
    return *x0 >= 1 && *y0 >= 1 && *x1 <= f->im.nx + 1 && *y1 <= f->im.ny + 1;
}

/* The median of the residual over the window's usable pixels: its sky,
 * for the weights.  NaN when a pixel of the window is masked or not
 * finite (the place is not used). */
static double window_sky(const mp_frame *f, const float *res, double x, double y, double r,
                         long x0, long y0, long x1, long y1, double *vals)
{
    size_t n = 0;
    for (long gy = y0; gy < y1; gy++)
        for (long gx = x0; gx < x1; gx++) {
            if (!mp_within((double)gx - x, (double)gy - y, r))
                continue;
            size_t k = (size_t)(gy - 1) * (size_t)f->im.nx + (size_t)(gx - 1);
            if (f->mask[k] || !isfinite(res[k]) || !isfinite(f->im.pix[k]))
                return NAN;
            vals[n++] = res[k];
        }
    return n > NPAR ? mp_median_select(vals, n) : NAN;
}

/* z[0..2]: the weighted least-squares estimates of flux, x and y (the
 * templates P, ∂P/∂x, ∂P/∂y with a constant sky) of the residual in the
 * window, each over its σ.  Weights 1/(model light + sky + RON² + xvar),
 * as the fit's.  Nonzero when the normal matrix is singular. */
static int window_z(const mp_frame *f, const float *res, double x, double y, double r,
                    double sky, const place_work *pw, long rx0, long ry0, int rw, int rh,
                    double z[3])
{
    double a[NPAR * NPAR] = {0}, b[NPAR] = {0};
    for (int j = 0; j < rh; j++)
        for (int i = 0; i < rw; i++) {
            long gx = rx0 + i, gy = ry0 + j;
            if (!mp_within((double)gx - x, (double)gy - y, r))
                continue;
            size_t k = (size_t)(gy - 1) * (size_t)f->im.nx + (size_t)(gx - 1);
            double m = fmax((double)f->im.pix[k] - res[k], 0.0);
            double v = m + fmax(sky, 0.0) + f->rdnoise * f->rdnoise + (f->xvar ? f->xvar[k] : 0.0);
            if (!(v > 0))
                continue;
            size_t t = (size_t)j * (size_t)rw + (size_t)i;
            double g[NPAR] = {pw->prf[t], pw->dx[t], pw->dy[t], 1.0};
            for (int p = 0; p < NPAR; p++) {
                b[p] += g[p] * (res[k] - sky) / v;
                for (int q = 0; q <= p; q++)
                    a[p * NPAR + q] += g[p] * g[q] / v;
            }
        }
    if (LAPACKE_dpotrf(LAPACK_ROW_MAJOR, 'L', NPAR, a, NPAR) != 0)
        return 1;
    double sol[NPAR];
    memcpy(sol, b, sizeof sol);
    if (LAPACKE_dpotrs(LAPACK_ROW_MAJOR, 'L', NPAR, 1, a, NPAR, sol, 1) != 0 ||
        LAPACKE_dpotri(LAPACK_ROW_MAJOR, 'L', NPAR, a, NPAR) != 0)
        return 1;
    for (int p = 0; p < 3; p++) {
        if (!(a[p * NPAR + p] > 0))
            return 1;
        z[p] = sol[p] / sqrt(a[p * NPAR + p]);
    }
    return 0;
}

/* The templates of a place, rendered once for every place when the
 * PSF is the same table everywhere: the places sit on whole pixels
 * (cell_centre) and every window used lies inside the frame, so each
 * place's render is this one moved by whole pixels.  Rendered at each
 * place they differ from it by rounding only (the shift's fraction is
 * formed from the position: by at most 1.6e-7, the PRF summing to 1, on
 * frames A-C of tests/bench/daophot, 47 Tuc and GLIMPSE, which moves the
 * error factors by ~1e-6 of themselves); a render at every place was 7.7 %
 * of frame A's instructions with its table given. */
typedef struct {
    double x, y;                /* where it was rendered */
    double *prf, *dx, *dy;
    long rx0, ry0;
    int rw, rh;
} place_templates;

/* Place j's z into z[3j..3j+2], or NaN there when it is not usable; its
 * templates tp's, moved, when tp is not NULL. */
static void place_z(const mp_frame *f, const float *res, const mp_prf_model *m, double r,
                    double x, double y, const place_templates *tp, place_work *pw, double *z)
{
    z[0] = z[1] = z[2] = NAN;
    long x0, y0, x1, y1, rx0, ry0;
    int rw, rh;
    if (!window_box(f, x, y, r, &x0, &y0, &x1, &y1))
        return;
    double sky = window_sky(f, res, x, y, r, x0, y0, x1, y1, pw->vals);
    if (!isfinite(sky))
        return;
    place_work w = *pw;
    if (tp) {
        rx0 = tp->rx0 + (long)(x - tp->x);
        ry0 = tp->ry0 + (long)(y - tp->y);
        rw = tp->rw;
        rh = tp->rh;
        w.prf = tp->prf;
        w.dx = tp->dx;
        w.dy = tp->dy;
    } else if (mp_prf_render_window(m, x, y, x0, y0, x1 - x0, y1 - y0, &rx0, &ry0, &rw, &rh,
                                    pw->prf, pw->dx, pw->dy, &pw->wk)) {
        return;
    }
    double zz[3];
    if (rw > 0 && rh > 0 && !window_z(f, res, x, y, r, sky, &w, rx0, ry0, rw, rh, zz))
        memcpy(z, zz, sizeof zz);
}

/* 1.4826·MAD of the finite values z[3i + c] over i < n (scratch v). */
static double robust_sigma_of(const double *z, size_t n, int c, double *v, size_t *used)
{
    size_t m = 0;
    for (size_t i = 0; i < n; i++)
        if (isfinite(z[3 * i + (size_t)c]))
            v[m++] = z[3 * i + (size_t)c];
    *used = m;
    return m < 2 ? NAN : mp_mad_sigma(v, m);
}

/* The grid: gx × gy windows side px apart (so that no two share a
 * pixel); cell c's centre (1-based pixel) into *x, *y. */
static void cell_centre(long side, long gx, size_t c, double *x, double *y)
{
    *x = (double)((long)(c % (size_t)gx) * side + side / 2 + 1);
    *y = (double)((long)(c / (size_t)gx) * side + side / 2 + 1);
}

/* near[c]: cell c's centre lies within rex of a fitted star of t, whose
 * fit took up the noise there along its own PSF and derivatives (a place
 * there would read low).  NULL when out of memory. */
static unsigned char *near_stars(const mp_table *t, long side, long gx, long gy, double rex)
{
    unsigned char *near = calloc((size_t)gx * (size_t)gy + 1, 1);
    int cx = mp_table_col(t, "XPSF_IMAGE"), cy = mp_table_col(t, "YPSF_IMAGE");
    for (size_t r = 0; near && cx >= 0 && cy >= 0 && r < t->nrow; r++) {
        double x = mp_table_get(t, r, cx), y = mp_table_get(t, r, cy);
        if (!isfinite(x) || !isfinite(y))
            continue;
        /* the cells whose centre i·side + side/2 + 1 can lie within rex */
        double c0 = (double)(side / 2 + 1), w = (double)side;
        long i0 = (long)ceil((x - rex - c0) / w), i1 = (long)floor((x + rex - c0) / w);
        long j0 = (long)ceil((y - rex - c0) / w), j1 = (long)floor((y + rex - c0) / w);
        for (long j = j0 < 0 ? 0 : j0; j <= j1 && j < gy; j++)
            for (long i = i0 < 0 ? 0 : i0; i <= i1 && i < gx; i++) {
                size_t c = (size_t)j * (size_t)gx + (size_t)i;
                double px, py;
                cell_centre(side, gx, c, &px, &py);
                if (hypot(px - x, py - y) <= rex)
                    near[c] = 1;
            }
    }
    return near;
}

/* The places: the centres of the grid's cells not near a fitted star,
 * every stride-th of them so that at most MP_PL_ESCALE_MAXPLACES are
 * used; (size_t)-1 when out of memory. */
static size_t grid_places(const mp_frame *f, const mp_table *t, long side, double rex,
                          double **px, double **py)
{
    long gx = f->im.nx / side, gy = f->im.ny / side;
    gx = gx > 0 ? gx : 0;
    gy = gy > 0 ? gy : 0;
    size_t all = 0, cells = (size_t)gx * (size_t)gy;
    unsigned char *near = near_stars(t, side, gx, gy, rex);
    if (!near)
        return (size_t)-1;
    for (size_t c = 0; c < cells; c++)
        all += !near[c];
    size_t stride = all / MP_PL_ESCALE_MAXPLACES + 1, n = (all + stride - 1) / stride;
    *px = malloc((n ? n : 1) * sizeof **px);
    *py = malloc((n ? n : 1) * sizeof **py);
    size_t j = 0, free_seen = 0;
    for (size_t c = 0; *px && *py && c < cells && j < n; c++) {
        if (near[c] || free_seen++ % stride)
            continue;
        cell_centre(side, gx, c, &(*px)[j], &(*py)[j]);
        j++;
    }
    free(near);
    return *px && *py ? j : (size_t)-1;
}

/* The templates at place (x, y) into tp (room for box values each, in
 * buf), when the PSF is one table and every place lies on a whole pixel
 * (place_templates); 0 when not shared (or out of memory: then each
 * place renders its own). */
static int shared_templates(const mp_frame *f, const mp_prf_model *m, double r, const double *px,
                            const double *py, size_t n, size_t box, double *buf,
                            place_templates *tp)
{
    if (!buf || n == 0 || m->psf->field)
        return 0;
    for (size_t j = 0; j < n; j++)
        if (px[j] != floor(px[j]) || py[j] != floor(py[j]))
            return 0;
    double x = px[0], y = py[0];
    long x0, y0, x1, y1;
    (void)window_box(f, x, y, r, &x0, &y0, &x1, &y1);  /* inside or not: the same render */
    mp_prf_work wk = {0};
    *tp = (place_templates){x, y, buf, buf + box, buf + 2 * box, 0, 0, 0, 0};
    int rc = mp_prf_render_window(m, x, y, x0, y0, x1 - x0, y1 - y0, &tp->rx0, &tp->ry0, &tp->rw,
                                  &tp->rh, tp->prf, tp->dx, tp->dy, &wk);
    mp_prf_work_free(&wk);
    return rc == 0;
}

/* z of every place, in parallel; nonzero when out of memory. */
static int places_z(const mp_frame *f, const float *res, const mp_prf_model *m, double r,
                    long side, const double *px, const double *py, size_t n, double *z)
{
    int failed = 0;
    size_t tbox = (size_t)((side + 2) * (side + 2));
    double *tbuf = malloc(3 * tbox * sizeof *tbuf);
    place_templates t;
    const place_templates *tp = shared_templates(f, m, r, px, py, n, tbox, tbuf, &t) ? &t : NULL;
#pragma omp parallel reduction(| : failed)
    {
        size_t box = tbox;
        place_work pw = {0};
        pw.prf = malloc(4 * box * sizeof *pw.prf);
        failed |= !pw.prf;
        if (pw.prf) {
            pw.dx = pw.prf + box;
            pw.dy = pw.prf + 2 * box;
            pw.vals = pw.prf + 3 * box;
        }
#pragma omp for schedule(dynamic, 16)
        for (size_t j = 0; j < n; j++)
            if (pw.prf)
                place_z(f, res, m, r, px[j], py[j], tp, &pw, z + 3 * j);
            else
                z[3 * j] = z[3 * j + 1] = z[3 * j + 2] = NAN;
        free(pw.prf);
        mp_prf_work_free(&pw.wk);
    }
    free(tbuf);
    return failed;
}

/* Whether k, measured over n values, differs from 1 by more than
 * MP_PL_ESCALE_Z of its sampling errors (1.166/√n relative). */
static int differs(double k, size_t n)
{
    return isfinite(k) && n > 0 && fabs(k - 1.0) > MP_PL_ESCALE_Z * 1.166 / sqrt((double)n);
}

/* k, measured over n values at nplace places, where it differs from 1
 * and the places are enough to scale on, else 1.  (The position's k is
 * over twice the places, x and y; the floor is on the places: at 70 a
 * sky-subtracted frame's position errors were scaled 12.5 times and its
 * flux errors, 9.7 off, not.) */
static double significant(double k, size_t n, size_t nplace)
{
    return nplace >= MP_PL_ESCALE_MINPLACES && differs(k, n) ? k : 1.0;
}

/* The position's k: the rms of x's and y's. */
static double position_k(const mp_pl_escale *e)
{
    return sqrt(0.5 * (e->raw[1] * e->raw[1] + e->raw[2] * e->raw[2]));
}

int mp_pl_escale_unused(const mp_pl_escale *e)
{
    return e->nplace < MP_PL_ESCALE_MINPLACES &&
           (differs(e->raw[0], e->nplace) || differs(position_k(e), 2 * e->nplace));
}

void mp_pl_escale_unused_why(const mp_pl_escale *e, char *why, size_t n)
{
    snprintf(why, n, "the catalog's errors are the fit's, but the residual fitted as a star "
             "scatters by %.3g (flux), %.3g, %.3g (x, y) of their sigma at %zu places, fewer "
             "than the %d that scale them", e->raw[0], e->raw[1], e->raw[2], e->nplace,
             MP_PL_ESCALE_MINPLACES);
}

int mp_pl_error_scale(const mp_frame *f, const float *res, const mp_table *t,
                      const mp_prf_model *m, double fitrad, double fwhm, mp_pl_escale *e,
                      char *err)
{
    memset(e, 0, sizeof *e);
    e->k[0] = e->k[1] = 1.0;
    e->raw[0] = e->raw[1] = e->raw[2] = NAN;
    long side = 2 * (long)ceil(fitrad) + 1;
    double *px = NULL, *py = NULL;
    size_t n = grid_places(f, t, side, MP_PL_ESCALE_REX * fwhm, &px, &py);
    if (n == 0) {               /* no window fits the frame: k stays 1 */
        free(px);
        free(py);
        return 0;
    }
    double *z = n == (size_t)-1 ? NULL : malloc(4 * n * sizeof *z);
    if (!z || places_z(f, res, m, fitrad, side, px, py, n, z)) {
        free(px);
        free(py);
        free(z);
        snprintf(err, MP_ERRLEN, "out of memory for the error scale");
        return 1;
    }
    for (int c = 0; c < 3; c++)
        e->raw[c] = robust_sigma_of(z, n, c, z + 3 * n, &e->nplace);
    e->k[0] = significant(e->raw[0], e->nplace, e->nplace);
    e->k[1] = significant(position_k(e), 2 * e->nplace, e->nplace);
    free(px);
    free(py);
    free(z);
    return 0;
}

/* Column name's values times k, where the column exists. */
static void scale_col(mp_table *t, const char *name, double k)
{
    int c = mp_table_col(t, name);
    for (size_t r = 0; c >= 0 && r < t->nrow; r++)
        mp_table_set(t, r, c, k * mp_table_get(t, r, c));
}

void mp_pl_apply_error_scale(mp_table *t, const mp_pl_escale *e)
{
    if (e->k[0] != 1.0) {
        scale_col(t, "FLUXERR_PSF", e->k[0]);
        scale_col(t, "MAGERR_PSF", e->k[0]);
    }
    if (e->k[1] != 1.0) {
        scale_col(t, "ERRX_PSF", e->k[1]);
        scale_col(t, "ERRY_PSF", e->k[1]);
    }
}
