/* merge_frame.c — one catalog's detections for the survey merge, with
 * their position errors on the sky (merge_priv.h), and the sky geometry
 * the merge works in (unit vectors, gnomonic tangent planes). */
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "catalog/merge_priv.h"

#define DEG (M_PI / 180.0)

void mg_unit(double ra, double dec, double u[3])
{
    double a = ra * DEG, d = dec * DEG;
    u[0] = cos(d) * cos(a);
    u[1] = cos(d) * sin(a);
    u[2] = sin(d);
}

void mg_radec(const double u[3], double *ra, double *dec)
{
    double a = atan2(u[1], u[0]) / DEG;
    *ra = a < 0 ? a + 360.0 : a;
    *dec = atan2(u[2], hypot(u[0], u[1])) / DEG;
}

/* East and north unit vectors at t (at a pole, east is +y by convention). */
static void basis(const double t[3], double e[3], double n[3])
{
    double h = hypot(t[0], t[1]);
    if (h < 1e-15) {
        e[0] = 0; e[1] = 1; e[2] = 0;
    } else {
        e[0] = -t[1] / h; e[1] = t[0] / h; e[2] = 0;
    }
    n[0] = t[1] * e[2] - t[2] * e[1];   /* n = t x e */
    n[1] = t[2] * e[0] - t[0] * e[2];
    n[2] = t[0] * e[1] - t[1] * e[0];
}

static double dot(const double a[3], const double b[3])
{
    return a[0] * b[0] + a[1] * b[1] + a[2] * b[2];
}

int mg_tangent(const double t[3], const double p[3], double *xi, double *eta)
{
    double e[3], n[3], c = dot(t, p);
    if (!(c > 0))
        return 1;
    basis(t, e, n);
    *xi = dot(p, e) / c / MP_ARCSEC;
    *eta = dot(p, n) / c / MP_ARCSEC;
    return 0;
}

void mg_untangent(const double t[3], double xi, double eta, double p[3])
{
    double e[3], n[3];
    basis(t, e, n);
    xi *= MP_ARCSEC;
    eta *= MP_ARCSEC;
    double s = 0;
    for (int k = 0; k < 3; k++) {
        p[k] = t[k] + xi * e[k] + eta * n[k];
        s += p[k] * p[k];
    }
    s = sqrt(s);
    for (int k = 0; k < 3; k++)
        p[k] /= s;
}

/* The catalog's columns the merge reads; -1 when absent. */
typedef struct { int ra, dec, x, y, ex, ey, num, mag, magerr, flux, fluxerr, flags; } cols;

static int col2(const mp_table *t, const char *a, const char *b)
{
    int c = mp_table_col(t, a);
    return c >= 0 ? c : mp_table_col(t, b);
}

static int find_cols(const mp_table *t, const char *name, cols *c, char *err)
{
    c->ra = col2(t, "ALPHAPSF_J2000", "ALPHA_J2000");
    c->dec = col2(t, "DELTAPSF_J2000", "DELTA_J2000");
    c->x = col2(t, "XPSF_IMAGE", "X_IMAGE");
    c->y = col2(t, "YPSF_IMAGE", "Y_IMAGE");
    c->ex = mp_table_col(t, "ERRX_PSF");
    c->ey = mp_table_col(t, "ERRY_PSF");
    c->num = mp_table_col(t, "NUMBER");
    c->mag = mp_table_col(t, "MAG_PSF");
    c->magerr = mp_table_col(t, "MAGERR_PSF");
    c->flux = mp_table_col(t, "FLUX_PSF");
    c->fluxerr = mp_table_col(t, "FLUXERR_PSF");
    c->flags = mp_table_col(t, "FLAGS");
    const char *miss = c->ra < 0 ? "ALPHAPSF_J2000" : c->dec < 0 ? "DELTAPSF_J2000"
                     : c->x < 0 ? "XPSF_IMAGE" : c->y < 0 ? "YPSF_IMAGE"
                     : c->ex < 0 ? "ERRX_PSF" : c->ey < 0 ? "ERRY_PSF" : NULL;
    if (miss) {
        snprintf(err, MP_ERRLEN, "%s: no %s column (sky positions come from `matphot catalog "
                 "image=` of a frame with a WCS, errors from the fit)", name, miss);
        return 1;
    }
    return 0;
}

static double get(const mp_table *t, size_t r, int c)
{
    return c < 0 ? NAN : mp_table_get(t, r, c);
}

static int usable(const mp_table *t, size_t r, const cols *c)
{
    return isfinite(get(t, r, c->ra)) && isfinite(get(t, r, c->dec)) &&
           isfinite(get(t, r, c->x)) && isfinite(get(t, r, c->y)) &&
           get(t, r, c->ex) >= 0 && get(t, r, c->ey) >= 0 &&
           fabs(get(t, r, c->dec)) <= 90.0;
}

/* J [arcsec/pixel]: d(xi, eta)/d(x, y) of the catalog's least-squares
 * affine map from pixels to its tangent plane.  Nonzero when fewer than 3
 * stars or they lie on a line. */
static int jacobian(const mg_det *d, size_t n, double J[2][2])
{
    if (n < 3)
        return 1;
    double t[3] = {0, 0, 0}, mx = 0, my = 0;
    for (size_t i = 0; i < n; i++) {
        for (int k = 0; k < 3; k++)
            t[k] += d[i].u[k];
        mx += d[i].x;
        my += d[i].y;
    }
    mg_untangent(t, 0, 0, t);     /* normalise */
    mx /= (double)n;
    my /= (double)n;
    double sxx = 0, sxy = 0, syy = 0, sxa = 0, sya = 0, sxb = 0, syb = 0;
    for (size_t i = 0; i < n; i++) {
        double xi, eta, dx = d[i].x - mx, dy = d[i].y - my;
        if (mg_tangent(t, d[i].u, &xi, &eta))
            return 1;
        sxx += dx * dx; sxy += dx * dy; syy += dy * dy;
        sxa += dx * xi; sya += dy * xi; sxb += dx * eta; syb += dy * eta;
    }
    double det = sxx * syy - sxy * sxy;
    if (!(det > 1e-9 * sxx * syy))
        return 1;
    J[0][0] = (syy * sxa - sxy * sya) / det;
    J[0][1] = (sxx * sya - sxy * sxa) / det;
    J[1][0] = (syy * sxb - sxy * syb) / det;
    J[1][1] = (sxx * syb - sxy * sxb) / det;
    return 0;
}

static void fill(const mp_table *t, size_t r, const cols *c, int frame, mg_det *d)
{
    memset(d, 0, sizeof *d);
    d->ra = get(t, r, c->ra);
    d->dec = get(t, r, c->dec);
    mg_unit(d->ra, d->dec, d->u);
    d->x = get(t, r, c->x);
    d->y = get(t, r, c->y);
    d->se = get(t, r, c->ex);      /* pixels until the Jacobian is known */
    d->sn = get(t, r, c->ey);
    d->number = get(t, r, c->num);
    d->mag = get(t, r, c->mag);
    d->magerr = get(t, r, c->magerr);
    d->flux = get(t, r, c->flux);
    d->fluxerr = get(t, r, c->fluxerr);
    d->flags = c->flags < 0 ? 0 : get(t, r, c->flags);
    d->frame = frame;
    d->src = -1;
}

int mg_frame_dets(const mp_table *cat, const char *name, int frame, double syserr,
                  double pixscale, mg_det **dp, size_t *np, char *err)
{
    cols c;
    *dp = NULL;
    *np = 0;
    if (find_cols(cat, name, &c, err))
        return 1;
    mg_det *d = malloc((cat->nrow ? cat->nrow : 1) * sizeof *d);
    if (!d) {
        snprintf(err, MP_ERRLEN, "%s: out of memory", name);
        return 1;
    }
    size_t n = 0;
    for (size_t r = 0; r < cat->nrow; r++)
        if (usable(cat, r, &c))
            fill(cat, r, &c, frame, &d[n++]);
    double J[2][2];
    if (jacobian(d, n, J)) {
        if (!isfinite(pixscale) && n > 0) {
            snprintf(err, MP_ERRLEN, "%s: %zu stars cannot give the pixel scale (3 not on a "
                     "line are needed): give pixscale=", name, n);
            free(d);
            return 1;
        }
        J[0][0] = J[1][1] = pixscale;
        J[0][1] = J[1][0] = 0;
    }
    for (size_t i = 0; i < n; i++) {
        double ex = d[i].se, ey = d[i].sn;
        /* floored at 0.1 mas so that no weight is infinite */
        d[i].se = fmax(1e-4, sqrt(J[0][0] * J[0][0] * ex * ex + J[0][1] * J[0][1] * ey * ey +
                                  syserr * syserr));
        d[i].sn = fmax(1e-4, sqrt(J[1][0] * J[1][0] * ex * ex + J[1][1] * J[1][1] * ey * ey +
                                  syserr * syserr));
    }
    *dp = d;
    *np = n;
    return 0;
}
