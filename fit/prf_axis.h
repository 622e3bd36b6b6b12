/*
 * prf_axis.h — inside fit/ only: a table PRF as the product of two 1-D
 * operators (fit/prf_axis.c), for fit/prf_cache.c's phase-grid build.
 */
#ifndef MATPHOT_FIT_PRF_AXIS_H
#define MATPHOT_FIT_PRF_AXIS_H

#include "fit/fit.h"

/* One axis of a table render: the damped-sinc shift, the block-sum and the
 * five-point derivative, composed into one banded operator from table
 * elements to detector pixels [p0, p0 + w): pixel p reads elements
 * [lo[p], lo[p] + len[p]) with weights v (PRF) and d (∂/∂x of the star's
 * coordinate along this axis), bw a row. */
typedef struct {
    long p0;
    int w, bw;
    long *lo;
    int *len;
    double *v, *d;         /* d: NULL when built without the derivative */
    float *vf, *df;        /* v and d in single precision, a row of bwf each,
                            * zero from len to the row's end: what
                            * mp_prf_axis_rows_single and _cols_single read */
    int bwf;
    size_t capw, capv, capf;   /* what lo, len, v and vf hold (mp_prf_axis_refill) */
    struct {               /* the arguments of the last refill (made: 1) */
        int made, n, os, hw, deriv;
        double offset, x, xr;
        long wp0, ww;
    } last;
} mp_prf_axis;

/* The lanes of mp_prf_axis_rows_single's sums: a pixel's run of weights
 * is summed as that many partial sums (element i of the run into sum i
 * mod MP_PRF_LANES), padded with zeros to a whole number of them. */
#define MP_PRF_LANES 4

/* mp_prf_axis_geom: one axis of a table star (n elements, OVERSAMP os) at
 * coordinate x (the table's offset removed), aligned as for one at xr:
 * global fine index g = os·(p − 1) + s holds the table shifted by delta
 * (|delta| ≤ ½ for xr = x) at element g + n0; its box is pixels [p0, p0 + w). */
void mp_prf_axis_geom(int n, int os, double x, double xr, long *n0, double *delta, long *p0,
                      int *w);

/* mp_prf_axis_build: the operator of an axis of n elements (os, offset as
 * the table's) for a star at coordinate x, the table aligned as for one
 * at xr (fit/prf.c's render_table), its box clipped to pixels [wp0, wp0 +
 * ww), with a half-width hw sinc.  Nonzero when out of memory. */
int mp_prf_axis_build(int n, int os, double offset, double x, double xr, long wp0, long ww,
                      int hw, mp_prf_axis *a);

/* mp_prf_axis_refill: the same into a, whose arrays are kept and grown as
 * needed (a zeroed mp_prf_axis, or one built before); the derivative's
 * weights only with deriv (a->d NULL without; then each pixel's run
 * [lo, lo + len) leaves out the zero weights at its ends, the same sums
 * bit for bit in mp_prf_axis_rows and _cols).  Arguments equal to the
 * last refill's leave a as it is (the PSF build's SIRT renders and
 * projects each star at one place through a run's steps).  Nonzero when
 * out of memory. */
int mp_prf_axis_refill(int n, int os, double offset, double x, double xr, long wp0, long ww,
                       int hw, int deriv, mp_prf_axis *a);
void mp_prf_axis_free(mp_prf_axis *a);

/* mp_prf_axis_ops: multiply-adds of one table render (n_x × n_y elements,
 * OVERSAMP os, half-width hw) on a box of w × h detector pixels by the axis
 * operators (sep), or by render_table's shift of the table's elements then
 * block-sum (fit/prf.c), with the derivatives or without: what render_table
 * chooses between, and economy's plan prices (fit/econ_plan.c). */
double mp_prf_axis_ops(int nx, int ny, int os, int hw, int derivs, double w, double h, int sep);

/* mp_prf_axes_apply: whether one render of m is the product of its two
 * axes' operators (a DRF uniform over the pixel, or none); a variable
 * PSF is, once evaluated at the star. */
int mp_prf_axes_apply(const mp_prf_model *m);

/* mp_prf_separable: whether every render of m is the product of the same
 * two axes' operators (mp_prf_axes_apply, and a constant table): the
 * phase grid's build. */
int mp_prf_separable(const mp_prf_model *m);

/* mp_prf_axis_rows: A = T·Xᵀ on table rows [j0, j1) of T (stride nx),
 * (j1 − j0) × ax->w row-major: the x operator's PRF weights, and with Ad
 * (not NULL; ax built with the derivative) its derivative's, in one pass
 * over the rows. */
void mp_prf_axis_rows(const double *T, int nx, long j0, long j1, const mp_prf_axis *ax,
                      double *A, double *Ad);

/* mp_prf_axis_rows_single: mp_prf_axis_rows in single precision, twice
 * the multiply-adds a vector instruction holds: each row's elements the
 * operator reads converted into tf (room for MP_PRF_AXIS_TF(nx) floats),
 * each pixel's sum in MP_PRF_LANES lanes.  Its error is below (len + 2)·
 * 2⁻²⁴ of Σ|T|·|X| a value (the rounding of T, of the weights and of each
 * addition), ~1e-6 of the light; the same for any number of threads.
 * Not for the LM's own renders: their rounding jumps as a star moves, and
 * a fit cannot resolve a change of χ² below that noise (the frozen-wings
 * test's fits of 2e6 e- stars ended 0.054 σ apart, not within 0.05);
 * for what is drawn once and held — the phase grid's nodes (float in the
 * grid anyway), the light painted off a group's window, the PSF build's
 * renders, whose steps need χ² to 1 — it is ample. */
#define MP_PRF_AXIS_TF(nx) (2 * ((size_t)(nx) + MP_PRF_LANES))
void mp_prf_axis_rows_single(const double *T, int nx, long j0, long j1, const mp_prf_axis *ax,
                             float *A, float *Ad, float *tf);

/* mp_prf_axis_cols_single: mp_prf_axis_cols on A from
 * mp_prf_axis_rows_single, each output summed over its rows in order in
 * single precision, then scaled in double; with the rows, the render's
 * error is below (len_x + len_y + 4)·2⁻²⁴ of |Y|·|T|·|X|ᵀ. */
void mp_prf_axis_cols_single(const mp_prf_axis *ay, int deriv, const float *A, long row0,
                             int ax_w, double scale, double *out, long oy, long ox, long ostride);

/* mp_prf_axis_cols: out = scale · Y·A (ay->w × ax_w, the y operator's PRF
 * weights or, deriv, its derivative's), written at (oy, ox) of an image of
 * stride ostride; A's first row is the table's row row0. */
void mp_prf_axis_cols(const mp_prf_axis *ay, int deriv, const double *A, long row0, int ax_w,
                      double scale, double *out, long oy, long ox, long ostride);

#endif
