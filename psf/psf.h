/*
 * psf.h — the PSF as a model (design.md §2, §3): discrete supersampled
 * tables (FITS, OVERSAMP), the analytic Gaussian, and spatially variable
 * tables whose every element is a polynomial in the star's position.
 *
 * A table holds the PSF on a grid of OVERSAMP elements per detector pixel,
 * odd sizes, the star at the centre of the central element; its sum is the
 * fraction of the star's light it holds (≤ 1).  The fit (fit/) shifts it
 * to each star; the simulator (sim/) block-sums finer tables itself.
 * The PSF built from a frame's stars (`matphot psf`) is declared in
 * psf/build.h: it fits stars with fit/'s engine, which itself includes
 * this header, so it cannot live here.
 *
 * matphot's PSF file (what `matphot psf` writes and `fit`/`pipeline` read):
 *   primary HDU  2-D image (order 0: one table) or 3-D cube
 *                NAXIS1 × NAXIS2 × NTERMS, odd sizes;
 *   OVERSAMP     int, table elements per detector pixel (1..8);
 *   PSFORDER     0..3: polynomial order in (x, y) of every element;
 *   POLZERO1/2   1-based pixel x, y of the polynomial's origin;
 *   POLSCAL1/2   its scales: dx = (x − POLZERO1)/POLSCAL1, likewise dy;
 *   planes       in PSFEx order, y power outer, x power inner, total
 *                degree ≤ PSFORDER: 1, dx, dx², dy, dx·dy, dy² (order 1:
 *                1, dx, dy; order 3: 1, dx, dx², dx³, dy, dx·dy, dx²·dy,
 *                dy², dx·dy², dy³), so T(x,y) = Σ_k P_k · term_k;
 *   PSFSUM       fraction of a star's light the table holds at the origin;
 *   PSFORDWH     optional string: why this order;
 *   PSFNSTAR     optional: number of PSF stars used;
 *   PSFOFFSE     optional: where the star sits from the centre of the
 *                central element, both axes [detector px] (default 0;
 *                mp_psf.offset, after an even block-sum or an even table);
 *   PSFSTARS     optional binary-table extension of the PSF stars
 *                (X_IMAGE, Y_IMAGE, FLUX_PSF, USED).
 * A plain 2-D table without these keywords is order 0.
 *
 * Errors: 0 on success, nonzero with one line in err (MP_ERRLEN bytes)
 * naming the file and what is wrong.
 */
#ifndef MATPHOT_PSF_H
#define MATPHOT_PSF_H

#include "io/io.h"

/* ---- One table ------------------------------------------------------------ */

typedef enum { MP_PSF_TABLE, MP_PSF_GAUSS } mp_psf_kind;

typedef struct mp_psf_field_s mp_psf_field;

typedef struct {
    mp_psf_kind kind;
    int nx, ny;        /* table size (odd), elements */
    int os;            /* OVERSAMP: table elements per detector pixel */
    double *t;         /* nx*ny, row-major, star at element ((nx-1)/2,(ny-1)/2) */
    double sum;        /* fraction of the star's light the table holds */
    double sigma;      /* MP_PSF_GAUSS: sigma [detector px] */
    double offset;     /* where the star sits from the centre of the central
                        * element, both axes [detector px]: 0 for a table as
                        * design.md §3 defines it, nonzero after an even
                        * block-sum (mp_psf_rebin) */
    const mp_psf_field *field;  /* NULL: this table everywhere.  Else (not
                        * owned) the variable PSF this table is the value
                        * of at its origin, of the same size, OVERSAMP and
                        * offset: every render of a star (fit/prf.c) uses
                        * the field evaluated at the star's own position.
                        * The model's value is then exact at each star;
                        * its position derivatives leave out the table's
                        * change with position (a part in POLSCAL/FWHM of
                        * the PSF's own).  Copies (mp_psf_rebin) keep it. */
} mp_psf;

/* mp_psf_read: a PSF table from FITS (extended names work: an even-sized
 * table can be cut to odd size around its peak with a section).  OVERSAMP
 * comes from the header; when the header has none, from oversamp (> 0),
 * else 1 (oversamp ≤ 0).  Errors: even size, all-zero, NaN, sum > 1.01, OVERSAMP
 * outside 1..8.  Negative elements are a warning written to warn (may be
 * NULL).  normalize rescales the table to sum 1. */
int mp_psf_read(const char *name, int normalize, int oversamp, mp_psf *p, char *warn,
                char *err);

/* mp_psf_gauss_table: a table of an (exactly pixel-integrated) Gaussian of
 * the given FWHM [detector px], OVERSAMP os, half-size radius [detector px]. */
int mp_psf_gauss_table(double fwhm, int os, double radius, mp_psf *p, char *err);

/* mp_psf_gauss: the analytic pixel-integrated Gaussian of the given FWHM. */
void mp_psf_gauss(double fwhm, mp_psf *p);

/* mp_psf_rebin: block-sum a table to OVERSAMP os/factor (factor divides os).
 * For odd factor the star stays at the centre of the central element; for
 * even factor it sits half an input element above it, which out->offset
 * records (the renderer accounts for it, so fitted positions stay true). */
int mp_psf_rebin(const mp_psf *in, int factor, mp_psf *out, char *err);

void mp_psf_free(mp_psf *p);

/* ---- A spatially variable table (psf/field.c, psf/field_io.c) ------------- */

/* order MP_PSF_GRID: a grid of tables at fiducial positions (WebbPSF's
 * GriddedPSFModel, Anderson's STDPSF), interpolated bilinearly between the
 * four around a star (clamped to the grid's edge, never extrapolated);
 * plane j·ngx + i is the table at (gx[i], gy[j]). */
enum { MP_PSF_MAXORDER = 3, MP_PSF_GRID = 9, MP_PSF_MAXGRID = 32, MP_PSF_MAXTERMS = 256 };

struct mp_psf_field_s {
    int order;         /* 0..MP_PSF_MAXORDER; MP_PSF_GRID */
    int nterms;        /* (order+1)(order+2)/2; a grid's ngx·ngy */
    double x0, y0;     /* origin (1-based pixel x, y): POLZERO1/2 (a grid's centre) */
    double xscale, yscale;   /* POLSCAL1/2 (> 0 for order ≥ 1; a grid's span) */
    int ngx, ngy;      /* MP_PSF_GRID: the grid, positions ascending (1-based px) */
    double gx[MP_PSF_MAXGRID], gy[MP_PSF_MAXGRID];
    int nx, ny, os;    /* every plane's size and OVERSAMP, as mp_psf */
    double *planes;    /* nterms × ny × nx, term-major, PSFEx order */
    double sum;        /* Σ of plane 0: the table's sum at the origin */
    double offset;     /* as mp_psf.offset (after an even mp_psf_field_rebin) */
    int nstar;         /* PSFNSTAR (0: not given) */
    char why[256];     /* PSFORDWH ("" when not given) */
};

/* A PSF star of the optional PSFSTARS extension. */
typedef struct {
    double x, y, flux;
    int used;
} mp_psf_star;

/* mp_psf_nterms: the number of polynomial terms of an order
 * (0..MP_PSF_MAXORDER), 0 for any other order. */
int mp_psf_nterms(int order);

/* mp_psf_field_terms: the values of the order's terms at (x, y) in PSFEx
 * order (y power outer, x power inner: 1, dx, dx², dy, dx·dy, dy² for
 * order 2; order 1: 1, dx, dy); for a grid, the
 * bilinear weight of every plane (at most four nonzero). */
void mp_psf_field_terms(const mp_psf_field *f, double x, double y, double *terms);

/* mp_psf_field_eval: the table at pixel position (x, y) into out (a
 * MP_PSF_TABLE of the field's size, OVERSAMP and offset; out->sum its sum).
 * out is allocated here; free with mp_psf_free. */
int mp_psf_field_eval(const mp_psf_field *f, double x, double y, mp_psf *out, char *err);

/* mp_psf_field_eval_rect: the table at (x, y) on the elements
 * [i0, i1) × [j0, j1) only, written into out with stride f->nx (the rest
 * of out untouched): what a renderer needs of one star's table. */
void mp_psf_field_eval_rect(const mp_psf_field *f, double x, double y, long i0, long i1,
                            long j0, long j1, double *out);

/* mp_psf_local: *out a view of p (sharing p's table and planes; nothing
 * to free) for a sub-image whose pixel (1, 1) is frame pixel
 * (1 + dx, 1 + dy): with a field, *fout is a copy of p->field whose origin
 * (a grid's positions) is moved by (−dx, −dy) and out->field points to it,
 * so that a star at sub-image (x, y) is rendered with the field at frame
 * (x + dx, y + dy), where it is.  Without a field, *out is *p. */
void mp_psf_local(const mp_psf *p, double dx, double dy, mp_psf *out, mp_psf_field *fout);

/* mp_psf_field_from_table: an order-0 field holding a copy of table p. */
int mp_psf_field_from_table(const mp_psf *p, mp_psf_field *f, char *err);

/* Where a variable PSF may put its origin or grid (|POLZERO|, |position|
 * ≤ MP_PSF_MAXPOS px) and how fine its scale may be (MP_PSF_MINSCALE ≤
 * POLSCAL ≤ MP_PSF_MAXPOS): inside these a cubic's terms stay finite at
 * every pixel of any frame up to MP_PSF_MAXPOS a side (at most
 * (2e7 / 1e-2)³ ≈ 1e28); outside them no detector's positions lie. */
#define MP_PSF_MAXPOS 1e7
#define MP_PSF_MINSCALE 1e-2

/* mp_psf_field_origin_ok: 1 when origin (x0, y0) and scales (xs, ys) lie
 * within the bounds above, 0 otherwise (NaN included). */
int mp_psf_field_origin_ok(double x0, double y0, double xs, double ys);

/* mp_psf_field_new: an order-`order` field of nx × ny elements, planes
 * zeroed, origin (x0, y0), scales (xs, ys) (for order ≥ 1 within the
 * bounds of mp_psf_field_origin_ok). */
int mp_psf_field_new(int order, int nx, int ny, int os, double x0, double y0, double xs,
                     double ys, mp_psf_field *f, char *err);

/* mp_psf_field_new_grid: a grid field of ngx × ngy tables of nx × ny
 * elements at the ascending positions gx, gy, planes zeroed. */
int mp_psf_field_new_grid(int ngx, int ngy, const double *gx, const double *gy, int nx, int ny,
                          int os, mp_psf_field *f, char *err);

/* mp_psf_field_rebin: every plane block-summed as mp_psf_rebin does.  The
 * block-sum is linear, so the rebinned field evaluated at (x, y) is the
 * rebinned table of the field at (x, y), exactly. */
int mp_psf_field_rebin(const mp_psf_field *in, int factor, mp_psf_field *out, char *err);

/* mp_psf_field_read: matphot's PSF file (layout above).  A 2-D table is
 * read by mp_psf_read (same arguments, same checks) as order 0.  For a
 * cube: PSFORDER (else from NTERMS), POLZERO/POLSCAL (required for order
 * ≥ 1, scales finite and > 0), OVERSAMP as mp_psf_read; plane 0 must be a
 * valid table (odd sizes, finite, positive sum ≤ 1.01 unless normalize,
 * which divides every plane by plane 0's sum); every plane finite.  The
 * optional PSFSTARS extension is read into *stars (malloc'ed, *nstars)
 * when stars is not NULL (NULL, 0 when absent).
 * Other programs' files are recognised from their content: PSFEx (.psf
 * and legacypipe's table), WebbPSF/STPSF (the OVERSAMP HDU; an even table
 * padded to odd size, the half-element offset kept in offset), WebbPSF's
 * GriddedPSFModel (DET_YXn) and Anderson's STDPSF (NXPSFS, IPSFXnn)
 * grids; what a conversion costs is written to warn. */
int mp_psf_field_read(const char *name, int normalize, int oversamp, mp_psf_field *f,
                      mp_psf_star **stars, int *nstars, char *warn, char *err);

/* mp_psf_field_write: write f as matphot's PSF file, atomically (a
 * temporary name beside path, renamed at the end; removed on failure):
 * a 2-D image for order 0, else the cube (a grid is refused); the stars (may be NULL, n 0)
 * as the PSFSTARS extension. */
int mp_psf_field_write(const char *path, const mp_psf_field *f, const mp_psf_star *stars,
                       int nstars, char *err);

void mp_psf_field_free(mp_psf_field *f);

/* ---- A detector-level kernel (psf/kernel.c) ------------------------------ */

/* mp_psf_kernel_read: the kernel spec names — "header": Tiny Tim's kernel
 * in the COMMENT cards of psfname's header ("…convolve it with the
 * following kernel", one card a row; an error when there is none);
 * "auto": that kernel when the header carries one, else none; "" or
 * "none": none; else a FITS image (odd sizes ≤ 99) — as an OVERSAMP-1
 * table k (sum kept as given, k->sum).  It acts on detector pixels, after
 * the block-sum.  No kernel: 0 with k->t NULL. */
int mp_psf_kernel_read(const char *spec, const char *psfname, mp_psf *k, char *err);

/* What a psfkernel spec names: none ("" or "none"), auto, header, or a
 * file; the last two need a PSF table. */
typedef enum { MP_KERNEL_NONE, MP_KERNEL_AUTO, MP_KERNEL_HEADER, MP_KERNEL_FILE } mp_kernel_spec;
mp_kernel_spec mp_psf_kernel_spec(const char *spec);

/* mp_psf_field_fold_kernel: every plane convolved with k placed at
 * whole-pixel steps (os elements) and padded by os·r a side, so that the
 * renderer's block-summed PRF of the folded field is exactly the unfolded
 * PRF convolved with k on detector pixels, at every shift and for any DRF
 * (kernel.c says why); f->sum scales by k's sum. */
int mp_psf_field_fold_kernel(mp_psf_field *f, const mp_psf *k, char *err);

/* mp_psf_table_fold_kernel: the same for one table *t (nx × ny elements,
 * OVERSAMP os, malloc'ed), replaced by its folded and padded copy, *nx and
 * *ny by its sizes; its sum times k's is the folded table's. */
int mp_psf_table_fold_kernel(double **t, int *nx, int *ny, int os, const mp_psf *k, char *err);

#endif
