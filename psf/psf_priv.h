/*
 * psf_priv.h — private to psf/: the readers of other programs' PSF files,
 * called by mp_psf_field_read once it has recognised the file's content.
 * Each fills an mp_psf_field (planes in psf.h's layout and term order, a
 * table of odd size whose star sits at the centre of the central element)
 * from the HDU fp is positioned on; name is for messages; warn (may be
 * NULL) receives what the conversion cost.
 */
#ifndef MATPHOT_PSF_PRIV_H
#define MATPHOT_PSF_PRIV_H

#include <fitsio.h>
#include "psf/psf.h"

/* psf_fits_msg: "<name>: <what>: <cfitsio's text>" into err. */
void psf_fits_msg(const char *name, const char *what, int status, char *err);

/* psf_has_column: nonzero when the table HDU has a column of that name
 * (case-insensitive). */
int psf_has_column(fitsfile *fp, const char *col);

/* psfex_read: a PSFEx model — a classic .psf (PSF_DATA, PSF_MASK, the
 * POL* and PSF_SAMP keywords) or legacypipe's merged table (one row,
 * lowercase columns psf_mask, polzero1, …) — resampled to OVERSAMP 1 when
 * PSF_SAMP ≠ 1 (Lanczos-3; the round-trip error goes to warn), plane 0
 * normalised to sum 1. */
int psfex_read(fitsfile *fp, const char *name, mp_psf_field *f, char *warn, char *err);

/* webbpsf_read: a WebbPSF/STPSF table (the HDU fp is on, nx × ny, its
 * OVERSAMP keyword); an even table padded to odd size, offset 0.5/os. */
int webbpsf_read(fitsfile *fp, const char *name, long nx, long ny, mp_psf_field *f, char *warn,
                 char *err);

/* grid_read: a cube of PSFs on a grid of detector positions — WebbPSF's
 * GriddedPSFModel (DET_YXn '(y, x)', 0-based; OVERSAMP) or, stdpsf set,
 * Anderson's STDPSF (NXPSFS, NYPSFS, IPSFXnn, JPSFYnn; ePSFs sampled at
 * whole pixels into ×1 tables). */
int grid_read(fitsfile *fp, const char *name, int stdpsf, const long naxes[3], mp_psf_field *f,
              char *warn, char *err);

/* psf_lanczos3: the Lanczos-3 kernel sinc(x)·sinc(x/3) for |x| < 3, else 0. */
double psf_lanczos3(double x);

/* psf_resample: plane src (nx×ny elements of s detector px, star at
 * element (nx/2, ny/2), PSFEx's centre, the middle one for odd sizes)
 * onto mx×my elements of step t px (star at (mx/2, my/2)) by separable Lanczos-3, values scaled by (t/s)² so
 * the sum is kept.  tmp holds nx·my doubles. */
void psf_resample(const double *src, int nx, int ny, double s, double *dst, int mx, int my,
                  double t, double *tmp);

#endif
