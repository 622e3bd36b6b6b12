/*
 * merge_priv.h — private to catalog/merge*.c: the detections and sources
 * of a survey merge (catalog.h, "Survey merge"), and the sky geometry they
 * share.
 */
#ifndef MATPHOT_MERGE_PRIV_H
#define MATPHOT_MERGE_PRIV_H

#include "catalog/catalog.h"

#define MP_ARCSEC (M_PI / 648000.0)   /* one arcsecond in radians */

/* One star of one frame's catalog, as the merge keeps it. */
typedef struct {
    double u[3];              /* unit vector of (ra, dec) */
    double ra, dec;           /* [deg] */
    double se, sn;            /* position error east, north [arcsec], syserr included */
    double number, x, y, mag, magerr, flux, fluxerr, flags;
    int frame;                /* 1-based index of its catalog */
    long src;                 /* its source (index), -1 until matched */
    double sep;               /* from the source's final mean [arcsec] */
} mg_det;

/* A source: the weighted mean of its detections, kept as sums in the
 * tangent plane of its first detection (ref). */
typedef struct {
    double ref[3];            /* where it was first seen: the plane's tangent point */
    double m[3];              /* current mean position (unit vector) */
    double swe, swn, swxi, sweta;   /* sums of weights and weighted offsets east/north */
    double swm, swmm, wmag;   /* magnitude: sum w, w·m, w·m² ... */
    long nmag, ndet;
    double flags;             /* OR of its detections' FLAGS */
    int last_frame;           /* a frame gives a source one detection at most */
    long next;                /* next source in its hash bucket, -1: none */
} mg_src;

/* The merge's state (merge.c builds it, merge_tables.c reads it). */
struct mp_merge {
    mp_merge_opts o;
    mg_det *d;            /* every detection, in the order the frames came */
    size_t nd, capd;
    mg_src *s;
    size_t ns, caps;
    long *bucket;         /* heads of the hash chains (mg_src.next), -1: empty */
    size_t nbucket;       /* a power of two, >= 2 caps */
    int nframes;
    int zp;               /* the catalogs' magnitudes: -1 none yet, 0 instrumental
                           * (no MAGZERO column), 1 calibrated (MAGZERO) */
    double zpval;         /* the first calibrated catalog's zero point */
    char zpname[256];     /* the first catalog, for the message */
};

/* Unit vector of (ra, dec) [deg]. */
void mg_unit(double ra, double dec, double u[3]);

/* (ra, dec) [deg] of a unit vector; ra in [0, 360). */
void mg_radec(const double u[3], double *ra, double *dec);

/* Gnomonic offsets [arcsec] of p in the tangent plane at t: xi east, eta
 * north.  Nonzero when p is 90 degrees or more from t. */
int mg_tangent(const double t[3], const double p[3], double *xi, double *eta);

/* The point at offsets (xi, eta) [arcsec] in the tangent plane at t. */
void mg_untangent(const double t[3], double xi, double eta, double p[3]);

/* mg_frame_dets: the detections of one catalog (rows with a finite sky
 * position), their position errors on the sky from ERRX_PSF/ERRY_PSF
 * through the catalog's own pixel-to-sky Jacobian (a least-squares affine
 * fit of its sky positions against its pixel positions; pixscale [arcsec]
 * when fewer than 3 stars), syserr added in quadrature.  *d (n of them) is
 * the caller's to free. */
int mg_frame_dets(const mp_table *cat, const char *name, int frame, double syserr,
                  double pixscale, mg_det **d, size_t *n, char *err);

#endif
