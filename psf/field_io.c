/* field_io.c — matphot's PSF file (psf.h): a 2-D table or a cube of
 * polynomial planes, read and written atomically. */
#include <fitsio.h>
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <unistd.h>
#include "psf/psf_priv.h"

/* Largest cube read: far beyond any PSF (a 1025² ×8 table of 10 planes is
 * 10.5 M elements), small enough that a forged header cannot ask for more. */
#define MAX_ELEMENTS (1L << 25)

void psf_fits_msg(const char *name, const char *what, int status, char *err)
{
    char txt[FLEN_STATUS];
    fits_get_errstatus(status, txt);
    fits_clear_errmsg();
    snprintf(err, MP_ERRLEN, "%s: %s: %s", name, what, txt);
}

/* An optional keyword: 0 found, 1 absent, 2 present but not a number. */
static int key_double(fitsfile *fp, const char *key, double *v)
{
    int status = 0;
    double x;
    mp_fits_key_number(fp, key, &x, &status);
    if (status == KEY_NO_EXIST) {
        fits_clear_errmsg();
        return 1;
    }
    if (status) {
        fits_clear_errmsg();
        return 2;
    }
    *v = x;
    return 0;
}

/* PSFORDER (else from the number of planes), checked against it. */
static int cube_order(fitsfile *fp, const char *name, long nt, int *order, char *err)
{
    double o;
    int k = key_double(fp, "PSFORDER", &o);
    if (k == 1) {
        *order = -1;
        for (int q = 0; q <= MP_PSF_MAXORDER; q++)
            if (mp_psf_nterms(q) == nt)
                *order = q;
    } else if (k == 0 && o == floor(o) && o >= 0 && o <= MP_PSF_MAXORDER) {
        *order = (int)o;
    } else {
        snprintf(err, MP_ERRLEN, "%s: PSFORDER must be 0 .. %d", name, MP_PSF_MAXORDER);
        return 1;
    }
    if (*order < 0 || mp_psf_nterms(*order) != nt) {
        snprintf(err, MP_ERRLEN, "%s: the cube has %ld planes; PSF order %d needs %d "
                 "(1, 3, 6 or 10 planes for order 0, 1, 2, 3)", name, nt, *order < 0 ? 0 : *order,
                 mp_psf_nterms(*order < 0 ? 0 : *order));
        return 1;
    }
    return 0;
}

/* PSFNSTAR and PSFORDWH (optional; a built table's, cube or 2-D). */
static void build_keys(fitsfile *fp, mp_psf_field *f)
{
    double ns;
    if (key_double(fp, "PSFNSTAR", &ns) == 0 && ns >= 0 && ns < 1e9)
        f->nstar = (int)ns;
    int status = 0;
    char *why = NULL;
    fits_read_key_longstr(fp, "PSFORDWH", &why, NULL, &status);
    if (!status && why)
        snprintf(f->why, sizeof f->why, "%s", why);
    if (why)
        fits_free_memory(why, &status);
    fits_clear_errmsg();
}

/* OVERSAMP, POLZERO/POLSCAL, PSFNSTAR, PSFORDWH of a cube. */
static int cube_keys(fitsfile *fp, const char *name, int oversamp, double *os, double pol[4],
                     mp_psf_field *f, char *err)
{
    *os = oversamp > 0 ? oversamp : 1.0;
    int k = key_double(fp, "OVERSAMP", os);
    if (k == 2 || (k == 0 && (*os != floor(*os) || *os < 1 || *os > 8))) {
        snprintf(err, MP_ERRLEN, "%s: OVERSAMP must be an integer 1..8", name);
        return 1;
    }
    static const char *keys[4] = {"POLZERO1", "POLZERO2", "POLSCAL1", "POLSCAL2"};
    for (int i = 0; i < 4; i++) {
        pol[i] = i < 2 ? 0.0 : 1.0;
        k = key_double(fp, keys[i], &pol[i]);
        if (f->order > 0 && (k || !isfinite(pol[i]) || (i >= 2 && !(pol[i] > 0)))) {
            snprintf(err, MP_ERRLEN, "%s: %s %s (a PSF of order %d needs POLZERO1/2 and "
                     "POLSCAL1/2 > 0)", name, keys[i], k == 1 ? "missing" : "invalid", f->order);
            return 1;
        }
    }
    if (f->order > 0 && !mp_psf_field_origin_ok(pol[0], pol[1], pol[2], pol[3])) {
        snprintf(err, MP_ERRLEN, "%s: POLZERO1/2 %g, %g or POLSCAL1/2 %g, %g out of range "
                 "(|POLZERO| <= %g px, %g <= POLSCAL <= %g px)", name, pol[0], pol[1], pol[2],
                 pol[3], MP_PSF_MAXPOS, MP_PSF_MINSCALE, MP_PSF_MAXPOS);
        return 1;
    }
    build_keys(fp, f);
    return 0;
}

/* PSFOFFSE (optional): where the star sits from the centre of the
 * central element, both axes [detector px] (mp_psf.offset). */
static int read_offset(fitsfile *fp, const char *name, mp_psf_field *f, char *err)
{
    double v = 0.0;
    int k = key_double(fp, "PSFOFFSE", &v);
    if (k == 2 || (k == 0 && !(fabs(v) < 1.0))) {
        snprintf(err, MP_ERRLEN, "%s: PSFOFFSE must be a number of pixels, |v| < 1", name);
        return 1;
    }
    f->offset = k == 0 ? v : 0.0;
    return 0;
}

/* Plane 0 is a table (mp_psf_read's checks); every plane finite. */
static int cube_check(const char *name, mp_psf_field *f, int normalize, char *warn, char *err)
{
    size_t plane = (size_t)f->nx * f->ny, nneg = 0;
    for (size_t i = 0; i < plane * f->nterms; i++)
        if (!isfinite(f->planes[i])) {
            snprintf(err, MP_ERRLEN, "%s: PSF cube holds NaN or infinite values", name);
            return 1;
        }
    double sum = 0.0, peak = 0.0;
    for (size_t i = 0; i < plane; i++) {
        sum += f->planes[i];
        peak = f->planes[i] > peak ? f->planes[i] : peak;
        nneg += f->planes[i] < 0;
    }
    if (!(peak > 0) || !(sum > 0)) {
        snprintf(err, MP_ERRLEN, "%s: PSF plane 1 (the table at the origin) is zero or "
                 "negative everywhere", name);
        return 1;
    }
    if (!normalize && sum > 1.01) {
        snprintf(err, MP_ERRLEN, "%s: PSF table at the origin sums to %.6g > 1.01; it must "
                 "hold the fraction of the star's light (use psfnorm=yes to rescale)", name, sum);
        return 1;
    }
    if (nneg && warn)
        snprintf(warn, MP_ERRLEN, "%s: %zu negative PSF elements at the origin", name, nneg);
    if (normalize) {
        for (size_t i = 0; i < plane * f->nterms; i++)
            f->planes[i] /= sum;
        sum = 1.0;
    }
    f->sum = sum;
    return 0;
}

/* The optional PSFSTARS extension (absent: *stars NULL, *n 0). */
static int read_stars(fitsfile *fp, const char *name, mp_psf_star **stars, int *n, char *err)
{
    int status = 0;
    fits_movnam_hdu(fp, BINARY_TBL, "PSFSTARS", 0, &status);
    if (status == BAD_HDU_NUM) {
        fits_clear_errmsg();
        return 0;
    }
    static char *cols[4] = {"X_IMAGE", "Y_IMAGE", "FLUX_PSF", "USED"};
    int cn[4];
    long nrow = 0;
    for (int i = 0; i < 4 && !status; i++)
        fits_get_colnum(fp, CASEINSEN, cols[i], &cn[i], &status);
    fits_get_num_rows(fp, &nrow, &status);
    if (status || nrow < 0 || nrow > 10000000) {
        psf_fits_msg(name, "PSFSTARS extension (X_IMAGE, Y_IMAGE, FLUX_PSF, USED)", status ? status : BAD_ROW_NUM, err);
        return 1;
    }
    if (nrow == 0)
        return 0;
    double *v = malloc((size_t)nrow * 3 * sizeof *v);
    int *u = malloc((size_t)nrow * sizeof *u);
    *stars = malloc((size_t)nrow * sizeof **stars);
    if (!v || !u || !*stars) {
        free(v), free(u), free(*stars), *stars = NULL;
        snprintf(err, MP_ERRLEN, "%s: out of memory for PSFSTARS", name);
        return 1;
    }
    for (int i = 0; i < 3; i++)
        fits_read_col(fp, TDOUBLE, cn[i], 1, 1, nrow, NULL, v + i * nrow, NULL, &status);
    fits_read_col(fp, TINT, cn[3], 1, 1, nrow, NULL, u, NULL, &status);
    for (long r = 0; r < nrow; r++)
        (*stars)[r] = (mp_psf_star){v[r], v[nrow + r], v[2 * nrow + r], u[r]};
    free(v);
    free(u);
    if (status) {
        free(*stars);
        *stars = NULL;
        psf_fits_msg(name, "PSFSTARS extension", status, err);
        return 1;
    }
    *n = (int)nrow;
    return 0;
}

static int read_cube(fitsfile *fp, const char *name, const long naxes[3], int normalize,
                     int oversamp, mp_psf_field *f, char *warn, char *err)
{
    if (naxes[0] % 2 == 0 || naxes[1] % 2 == 0) {
        snprintf(err, MP_ERRLEN, "%s: PSF table is %ldx%ld; its sizes must be odd "
                 "(star at the centre of the central element)", name, naxes[0], naxes[1]);
        return 1;
    }
    if (naxes[0] * naxes[1] > MAX_ELEMENTS / 16) {
        snprintf(err, MP_ERRLEN, "%s: PSF table of %ldx%ld elements is too large", name,
                 naxes[0], naxes[1]);
        return 1;
    }
    int order;
    double os, pol[4];
    if (cube_order(fp, name, naxes[2], &order, err))
        return 1;
    f->order = order;
    if (cube_keys(fp, name, oversamp, &os, pol, f, err))
        return 1;
    int nstar = f->nstar;
    char why[sizeof f->why];
    memcpy(why, f->why, sizeof why);
    if (mp_psf_field_new(order, (int)naxes[0], (int)naxes[1], (int)os, pol[0], pol[1], pol[2],
                         pol[3], f, err))
        return 1;
    f->nstar = nstar;
    if (read_offset(fp, name, f, err))
        return 1;
    memcpy(f->why, why, sizeof why);
    int status = 0;
    long fp1[3] = {1, 1, 1};
    fits_read_pix(fp, TDOUBLE, fp1, naxes[0] * naxes[1] * naxes[2], NULL, f->planes, NULL,
                  &status);
    if (status) {
        psf_fits_msg(name, "cannot read the PSF cube", status, err);
        return 1;
    }
    return cube_check(name, f, normalize, warn, err);
}

/* The image's dimensions (NAXIS 0 for a table HDU: fp stays open for
 * other_format); 1 when the file does not open here (mp_psf_read then says
 * why, with io/'s wording). */
static int open_image(const char *name, fitsfile **fp, int *naxis, long naxes[3])
{
    char why[MP_GUARD_LEN];
    *naxis = 0;
    if (mp_fits_guard_file(name, why))
        return 1;
    int status = 0, type = 0;
    fits_open_file(fp, name, READONLY, &status);
    fits_get_hdu_type(*fp, &type, &status);
    if (!status && type != IMAGE_HDU)
        return 0;
    char err[MP_ERRLEN];
    if (!status && mp_fits_refuse_tiled(*fp, name, err))
        status = DATA_DECOMPRESSION_ERR;    /* io/'s reader says why */
    fits_get_img_dim(*fp, naxis, &status);
    naxes[0] = naxes[1] = naxes[2] = 1;
    if (!status && *naxis >= 1 && *naxis <= 3)
        fits_get_img_size(*fp, *naxis, naxes, &status);
    if (status) {
        int s2 = 0;
        if (*fp)
            fits_close_file(*fp, &s2);
        *fp = NULL;
        fits_clear_errmsg();
        return 1;
    }
    return 0;
}

enum { FMT_NONE, FMT_PSFEX, FMT_WEBBPSF, FMT_GRID, FMT_STDPSF, FMT_DAOPHOT };

static int has_key(fitsfile *fp, const char *key)
{
    char card[FLEN_CARD];
    int st = 0;
    fits_read_card(fp, key, card, &st);
    fits_clear_errmsg();
    return st == 0;
}

/* An image HDU of another program, by its keywords: a grid (DET_YX0 of
 * WebbPSF's GriddedPSFModel, NXPSFS of STDPSF) or a WebbPSF table
 * (DET_SAMP). */
static int image_format(fitsfile *fp, int naxis)
{
    if (has_key(fp, "FUNCTION") && has_key(fp, "PSFHEIGH") && has_key(fp, "PSFRAD"))
        return FMT_DAOPHOT;
    if (naxis == 3 && has_key(fp, "DET_YX0"))
        return FMT_GRID;
    if (naxis == 3 && has_key(fp, "NXPSFS"))
        return FMT_STDPSF;
    if (naxis == 2 && has_key(fp, "DET_SAMP"))
        return FMT_WEBBPSF;
    return FMT_NONE;
}

/* The first table's sum: positive, ≤ 1.01 unless normalize, which divides
 * every plane by it. */
static int check_sum(const char *name, mp_psf_field *f, int normalize, char *err)
{
    size_t plane = (size_t)f->nx * f->ny;
    double s = 0.0;
    for (size_t i = 0; i < plane; i++)
        s += f->planes[i];
    if (!(s > 0) || (!normalize && s > 1.01)) {
        snprintf(err, MP_ERRLEN, "%s: PSF table sums to %.6g; it must hold the fraction of the "
                 "star's light, 0 < sum <= 1.01 (psfnorm=yes rescales)", name, s);
        return 1;
    }
    if (normalize) {
        for (size_t i = 0; i < plane * f->nterms; i++)
            f->planes[i] /= s;
        s = 1.0;
    }
    f->sum = s;
    return 0;
}

/* Which other program's PSF file fp holds: from the HDU it is on, or, on
 * an empty primary HDU, the first HDU that is one.  fp is left there. */
static int other_format(fitsfile **fp, const char *name)
{
    (void)name;
    int status = 0, nhdu = 0, cur = 0;
    fits_get_num_hdus(*fp, &nhdu, &status);
    fits_get_hdu_num(*fp, &cur);
    for (int h = cur; h <= nhdu && !status; h++) {
        int type = 0;
        if (h != cur)
            fits_movabs_hdu(*fp, h, &type, &status);
        else
            fits_get_hdu_type(*fp, &type, &status);
        if (status)
            break;
        if (type != IMAGE_HDU && psf_has_column(*fp, "PSF_MASK"))
            return FMT_PSFEX;
        if (h == cur && cur > 1)
            break;          /* an HDU the name chose: only that one */
    }
    fits_clear_errmsg();
    return FMT_NONE;
}

static int read_other(int kind, fitsfile *fp, const char *name, mp_psf_field *f, char *warn,
                      char *err)
{
    switch (kind) {
    case FMT_PSFEX:
        return psfex_read(fp, name, f, warn, err);
    default:
        snprintf(err, MP_ERRLEN, "%s: not a PSF file matphot knows", name);
        return 1;
    }
}

/* The table at the origin holds light (sum ≥ 1e-12), and every element
 * is finite and within ±1e6 (a table sums to about 1; larger values are a
 * broken file, and would overflow a render). */
static int check_range(const char *name, const mp_psf_field *f, char *err)
{
    if (!(f->sum >= 1e-12)) {
        snprintf(err, MP_ERRLEN, "%s: PSF table sums to %g: it holds no light", name, f->sum);
        return 1;
    }
    size_t n = (size_t)f->nx * f->ny * f->nterms;
    for (size_t i = 0; i < n; i++)
        if (!(fabs(f->planes[i]) <= 1e6)) {
            snprintf(err, MP_ERRLEN, "%s: PSF element %zu of plane %zu is %g, not a finite "
                     "number within +-1e6", name, i % ((size_t)f->nx * f->ny),
                     i / ((size_t)f->nx * f->ny) + 1, f->planes[i]);
            return 1;
        }
    return 0;
}

/* Close fp, quietly (the file was read or has failed already). */
static void close_quietly(fitsfile *fp)
{
    int s = 0;
    if (fp)
        fits_close_file(fp, &s);
    fits_clear_errmsg();
}

/* A gridded PSF or WebbPSF's file (image_format's kind img), checked. */
static int read_gridded(fitsfile *fp, const char *name, int img, const long naxes[3],
                        int normalize, mp_psf_field *f, char *warn, char *err)
{
    int rc = img == FMT_WEBBPSF ? webbpsf_read(fp, name, naxes[0], naxes[1], f, warn, err)
                                : grid_read(fp, name, img == FMT_STDPSF, naxes, f, warn, err);
    return rc || check_sum(name, f, normalize, err);
}

/* matphot's own layout: a 2-D table (or anything else: mp_psf_read names
 * what is wrong) or the polynomial cube, and the PSF stars when asked
 * (only from a file cfitsio opened). */
static int read_own(fitsfile *fp, const char *name, int naxis, const long naxes[3],
                    int normalize, int oversamp, mp_psf_field *f, mp_psf_star **stars,
                    int *nstars, char *warn, char *err)
{
    int rc = 1;
    if (fp && naxis == 3 && naxes[2] > 1)
        rc = read_cube(fp, name, naxes, normalize, oversamp, f, warn, err);
    else {
        mp_psf p;
        if (!mp_psf_read(name, normalize, oversamp, &p, warn, err)) {
            rc = mp_psf_field_from_table(&p, f, err);
            mp_psf_free(&p);
            if (!rc && fp)
                rc = read_offset(fp, name, f, err);
            if (!rc && fp)
                build_keys(fp, f);
        }
    }
    return rc || !stars || !fp ? rc : read_stars(fp, name, stars, nstars, err);
}

/* IRAF DAOPHOT's PSF (its keywords FUNCTION, PSFHEIGH, PSFRAD): the file
 * psf writes holds the analytic function's parameters and a look-up table
 * of its residuals at half-pixel steps, 2 (2 PSFRAD + 1) + 1 elements a
 * side, which matphot does not evaluate; seepsf renders it, the star on
 * the central pixel of a (2 PSFRAD + 1)² image, as the image shows it
 * (pixel-integrated: an ×1 table), scaled to a star of PSFMAG, so it is
 * read as a table summing to 1.  Read as a plain table, the look-up
 * table was refused for its sum (14457 on the 256² test frame) or, with
 * psfnorm=yes, taken for a PSF. */
static int read_daophot(fitsfile *fp, const char *name, int naxis, const long naxes[3],
                        mp_psf_field *f, mp_psf_star **stars, int *nstars, char *warn,
                        char *err)
{
    double rad = 0;
    int st = 0;
    fits_read_key_dbl(fp, "PSFRAD", &rad, NULL, &st);
    fits_clear_errmsg();
    long side = isfinite(rad) && rad > 0 && rad < 1e4 ? 2 * lround(rad) + 1 : -1;
    if (!st && naxis == 2 && naxes[0] == side && naxes[1] == side)
        return read_own(fp, name, naxis, naxes, 1, 1, f, stars, nstars, warn, err);
    snprintf(err, MP_ERRLEN, "%s: an IRAF DAOPHOT PSF (an analytic function and its look-up "
             "table), which matphot does not evaluate: render it with DAOPHOT's seepsf (seepsf "
             "%.60s psfimage) and give psf=psfimage.fits", name, name);
    return 1;
}

int mp_psf_field_read(const char *name, int normalize, int oversamp, mp_psf_field *f,
                      mp_psf_star **stars, int *nstars, char *warn, char *err)
{
    memset(f, 0, sizeof *f);
    if (stars) {
        *stars = NULL;
        *nstars = 0;
    }
    if (warn)
        warn[0] = '\0';
    fitsfile *fp = NULL;
    int naxis = 0, rc;
    long naxes[3];
    int kind = !open_image(name, &fp, &naxis, naxes) && naxis == 0 ? other_format(&fp, name)
                                                                    : FMT_NONE;
    int img = !kind && fp ? image_format(fp, naxis) : FMT_NONE;
    if (kind)          /* another program's PSF file, recognised from its content */
        rc = read_other(kind, fp, name, f, warn, err) || check_range(name, f, err);
    else if (img == FMT_DAOPHOT)
        rc = read_daophot(fp, name, naxis, naxes, f, stars, nstars, warn, err);
    else if (img != FMT_NONE)
        rc = read_gridded(fp, name, img, naxes, normalize, f, warn, err);
    else
        rc = read_own(fp, name, naxis, naxes, normalize, oversamp, f, stars, nstars, warn, err);
    close_quietly(fp);
    if (!rc && !kind)
        rc = check_range(name, f, err);
    if (rc) {
        mp_psf_field_free(f);
        if (stars) {
            free(*stars);
            *stars = NULL;
            *nstars = 0;
        }
    }
    return rc;
}

/* ---- Writing ---------------------------------------------------------------- */

/* A double keyword with 17 significant digits, so that it reads back to
 * the same double (cfitsio's TDOUBLE default writes 15). */
static void write_exact(fitsfile *fp, const char *key, double v, const char *comment,
                        int *status)
{
    fits_write_key_dbl(fp, key, v, -17, comment, status);
}

static void write_keys(fitsfile *fp, const mp_psf_field *f, int *status)
{
    int os = f->os, order = f->order;
    fits_write_key(fp, TINT, "OVERSAMP", &os, "table elements per detector pixel", status);
    fits_write_key(fp, TINT, "PSFORDER", &order, "polynomial order in (x, y)", status);
    write_exact(fp, "POLZERO1", f->x0, "origin x [pixel, 1-based]", status);
    write_exact(fp, "POLZERO2", f->y0, "origin y [pixel, 1-based]", status);
    write_exact(fp, "POLSCAL1", f->xscale, "dx = (x - POLZERO1)/POLSCAL1", status);
    write_exact(fp, "POLSCAL2", f->yscale, "dy = (y - POLZERO2)/POLSCAL2", status);
    write_exact(fp, "PSFSUM", f->sum, "light fraction of the table at the origin", status);
    fits_write_comment(fp, "planes: PSFEx order, dy power outer, dx power inner, total degree "
                       "<= PSFORDER: 1, dx, dx^2, dy, dx*dy, dy^2 for order 2", status);
    if (f->nstar > 0)
        fits_write_key(fp, TINT, "PSFNSTAR", (void *)&f->nstar, "PSF stars used", status);
    if (f->offset != 0.0) {
        write_exact(fp, "PSFOFFSE", f->offset, "star from the central element's centre [pixel]",
                    status);
    }
    if (f->why[0]) {
        fits_write_key_longwarn(fp, status);
        fits_write_key_longstr(fp, "PSFORDWH", f->why, "why this order", status);
    }
}

static void write_stars(fitsfile *fp, const mp_psf_star *s, int n, int *status)
{
    char *ttype[4] = {"X_IMAGE", "Y_IMAGE", "FLUX_PSF", "USED"};
    char *tform[4] = {"1D", "1D", "1D", "1J"};
    char *tunit[4] = {"pixel", "pixel", "electron", ""};
    fits_create_tbl(fp, BINARY_TBL, 0, 4, ttype, tform, tunit, "PSFSTARS", status);
    for (int r = 0; r < n && !*status; r++) {
        double v[3] = {s[r].x, s[r].y, s[r].flux};
        int u = s[r].used;
        for (int c = 0; c < 3; c++)
            fits_write_col(fp, TDOUBLE, c + 1, r + 1, 1, 1, &v[c], status);
        fits_write_col(fp, TINT, 4, r + 1, 1, 1, &u, status);
    }
}

int mp_psf_field_write(const char *path, const mp_psf_field *f, const mp_psf_star *stars,
                       int nstars, char *err)
{
    if (f->order == MP_PSF_GRID) {
        snprintf(err, MP_ERRLEN, "%s: a gridded PSF has no form in matphot's PSF file", path);
        return 1;
    }
    char *tmp = mp_tmp_name(path);
    if (!tmp) {
        snprintf(err, MP_ERRLEN, "%s: out of memory", path);
        return 1;
    }
    (void)mp_tmp_register(tmp);
    unlink(tmp);
    fitsfile *fp = NULL;
    int status = 0;
    long naxes[3] = {f->nx, f->ny, f->nterms};
    fits_create_file(&fp, tmp, &status);
    fits_create_img(fp, DOUBLE_IMG, f->order > 0 ? 3 : 2, naxes, &status);
    write_keys(fp, f, &status);
    long fp1[3] = {1, 1, 1};
    fits_write_pix(fp, TDOUBLE, fp1, naxes[0] * naxes[1] * naxes[2], f->planes, &status);
    if (stars && nstars > 0)
        write_stars(fp, stars, nstars, &status);
    int s2 = 0;
    if (fp)
        fits_close_file(fp, status ? &s2 : &status);
    if (status)
        psf_fits_msg(path, "cannot write the PSF file", status, err);
    else if (mp_out_place(tmp, path, err))
        status = 1;
    if (status)
        unlink(tmp);
    mp_tmp_unregister(tmp);
    free(tmp);
    return status ? 1 : 0;
}
