/* cutout.c — each PSF star's surroundings as a small frame of its own, so
 * the fit engine (mp_fit_group) and the back-projection see only it, and
 * its neighbours can be taken out of it (DAOPHOT's second pass). */
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include "psf/build_priv.h"

void mp_epsf_stars_free(mp_epsf_star *s, size_t n)
{
    if (!s)
        return;
    for (size_t k = 0; k < n; k++) {
        free(s[k].f.im.pix);
        free(s[k].f.mask);
        free(s[k].f.xvar);
        free(s[k].raw);
    }
    free(s);
}

/* The sky of a star from the annulus beyond its table (as DAOPHOT and
 * Anderson & King take it): a constant fitted under the table's wings
 * would trade light with them.  Clipped at 3σ about the median until
 * stable, then SExtractor's mode 2.5·median − 1.5·mean (a crowded
 * annulus is skewed by faint stars).  NaN with fewer than 12 pixels. */
static double annulus_sky(const mp_epsf_star *s, double r0, double r1, double *buf)
{
    const mp_frame *f = &s->f;
    size_t n = 0;
    double xs = s->x - (double)(s->x0 - 1), ys = s->y - (double)(s->y0 - 1);
    /* hypot only where the squared distance lies within 1e-9 of either
     * edge's square: elsewhere its side is certain (hypot errs by an ulp),
     * and the ring is the same pixels for a tenth of the calls */
    double lo2 = r0 * r0 * (1.0 - 1e-9), hi2 = r1 * r1 * (1.0 + 1e-9);
    double lo2b = r0 * r0 * (1.0 + 1e-9), hi2b = r1 * r1 * (1.0 - 1e-9);
    for (long j = 1; j <= f->im.ny; j++)
        for (long i = 1; i <= f->im.nx; i++) {
            double dx = i - xs, dy = j - ys, d2 = dx * dx + dy * dy;
            size_t o = (size_t)(j - 1) * f->im.nx + (size_t)(i - 1);
            if (d2 < lo2 || d2 > hi2 || f->mask[o])
                continue;
            if (d2 > lo2b && d2 < hi2b) {
                buf[n++] = f->im.pix[o];
                continue;
            }
            double r = hypot(dx, dy);
            if (r >= r0 && r <= r1)
                buf[n++] = f->im.pix[o];
        }
    if (n < 12)
        return NAN;
    double lo = -INFINITY, hi = INFINITY, med = 0, mean = 0;
    for (int it = 0; it < 10; it++) {
        size_t m = 0;
        double sum = 0, sum2 = 0;
        for (size_t k = 0; k < n; k++)
            if (buf[k] >= lo && buf[k] <= hi) {
                buf[n + m++] = buf[k];
                sum += buf[k];
                sum2 += buf[k] * buf[k];
            }
        if (m < 12)
            break;
        mean = sum / m;
        double sd = sqrt(fmax(sum2 / m - mean * mean, 0.0));
        med = mp_median_select(buf + n, m);
        double nlo = med - 3 * sd, nhi = med + 3 * sd;
        if (nlo == lo && nhi == hi)
            break;
        lo = nlo;
        hi = nhi;
    }
    return fabs(mean - med) < 1e-12 ? med : 2.5 * med - 1.5 * mean;
}

/* A start flux where none was given: the light above the sky within r. */
static double start_flux(const mp_epsf_star *s, double r)
{
    double xs = s->x - (double)(s->x0 - 1), ys = s->y - (double)(s->y0 - 1), sum = 0;
    for (long j = 1; j <= s->f.im.ny; j++)
        for (long i = 1; i <= s->f.im.nx; i++) {
            size_t o = (size_t)(j - 1) * s->f.im.nx + (size_t)(i - 1);
            if (!s->f.mask[o] && hypot(i - xs, j - ys) <= r)
                sum += s->f.im.pix[o] - s->sky;
        }
    return sum > 1.0 ? sum : 1.0;
}

static int cut_one(const mp_frame *f, const float *img, double x, double y, double psfrad,
                   mp_epsf_star *s)
{
    long r = (long)ceil(psfrad + MP_EPSF_ANNULUS(psfrad)) + 2;
    long xc = lround(x), yc = lround(y);
    long x0 = xc - r < 1 ? 1 : xc - r, y0 = yc - r < 1 ? 1 : yc - r;
    long x1 = xc + r > f->im.nx ? f->im.nx : xc + r, y1 = yc + r > f->im.ny ? f->im.ny : yc + r;
    long w = x1 - x0 + 1, h = y1 - y0 + 1;
    s->f = *f;
    s->f.im.hdr = NULL;
    s->f.im.nkeys = 0;
    s->f.im.nx = w;
    s->f.im.ny = h;
    s->f.im.pix = malloc((size_t)w * h * sizeof *s->f.im.pix);
    s->f.mask = malloc((size_t)w * h);
    s->f.xvar = f->xvar ? malloc((size_t)w * h * sizeof *s->f.xvar) : NULL;
    if (!s->f.im.pix || !s->f.mask || (f->xvar && !s->f.xvar))
        return 1;
    s->f.nbad = s->f.nsat = 0;
    for (long j = 0; j < h; j++)
        for (long i = 0; i < w; i++) {
            size_t o = (size_t)(y0 - 1 + j) * f->im.nx + (size_t)(x0 - 1 + i);
            size_t c = (size_t)j * w + i;
            s->f.mask[c] = f->mask[o];
            if (s->f.xvar)
                s->f.xvar[c] = f->xvar[o];
            s->f.im.pix[c] = f->mask[o] || !isfinite(img[o]) ? 0.0 : img[o];
            if (!isfinite(img[o]))
                s->f.mask[c] |= MP_MASK_BAD;
        }
    s->x0 = x0;
    s->y0 = y0;
    return 0;
}

int mp_epsf_cutouts(const mp_frame *f, const float *img, const double *x, const double *y,
                    const double *flux, const double *sky, size_t n, double psfrad,
                    mp_epsf_star **stars, char *err)
{
    *stars = calloc(n ? n : 1, sizeof **stars);
    if (!*stars) {
        snprintf(err, MP_ERRLEN, "psf build: out of memory");
        return 1;
    }
    for (size_t k = 0; k < n; k++)
        if (!(x[k] >= 0.5 && x[k] < f->im.nx + 0.5 && y[k] >= 0.5 && y[k] < f->im.ny + 0.5)) {
            snprintf(err, MP_ERRLEN, "PSF star at (%g, %g) is off the %ldx%ld frame", x[k], y[k],
                     f->im.nx, f->im.ny);
            free(*stars);
            *stars = NULL;
            return 1;
        }
    /* In parallel over the stars, each writing its own (0.5 % of 47 Tuc
     * built ran here on one thread, bench/SCALING.md). */
    int failed = 0;
#pragma omp parallel for schedule(dynamic) reduction(| : failed)
    for (size_t k = 0; k < n; k++) {
        mp_epsf_star *s = &(*stars)[k];
        if (failed || cut_one(f, img, x[k], y[k], psfrad, s)) {
            failed = 1;
            continue;
        }
        s->x = s->xf = x[k];
        s->y = s->yf = y[k];
        s->flux = flux[k];
        s->sky = sky[k];
        s->used = 1;
        double *buf = malloc(2 * (size_t)s->f.im.nx * s->f.im.ny * sizeof *buf);
        if (!buf) {
            failed = 1;
            continue;
        }
        double b = annulus_sky(s, psfrad + 1.0, psfrad + MP_EPSF_ANNULUS(psfrad), buf);
        free(buf);
        if (isfinite(b))
            s->sky = b;
        if (!isfinite(s->sky))
            s->sky = 0.0;
        if (!(s->flux > 0))
            s->flux = start_flux(s, 0.5 * psfrad);
    }
    if (failed) {
        mp_epsf_stars_free(*stars, n);
        *stars = NULL;
        snprintf(err, MP_ERRLEN, "psf build: out of memory");
        return 1;
    }
    return 0;
}

int mp_epsf_cutout_add(mp_epsf_star *s, const mp_prf_model *m, double x, double y, double flux,
                       char *err)
{
    double xs = x - (double)(s->x0 - 1), ys = y - (double)(s->y0 - 1);
    /* The star's own table: a field is read at its frame position. */
    mp_psf lp;
    mp_psf_field lf;
    mp_psf_local(m->psf, (double)(s->x0 - 1), (double)(s->y0 - 1), &lp, &lf);
    mp_prf_model lm = *m;
    lm.psf = &lp;
    long bx0, by0;
    int bw, bh;
    mp_prf_box(&lm, xs, ys, &bx0, &by0, &bw, &bh);
    double *prf = malloc((size_t)bw * bh * sizeof *prf);
    mp_prf_work w;
    memset(&w, 0, sizeof w);
    w.single = 1;               /* light taken off and held (fit/prf_axis.h) */
    if (!prf || mp_prf_render(&lm, xs, ys, prf, NULL, NULL, &w)) {
        free(prf);
        mp_prf_work_free(&w);
        snprintf(err, MP_ERRLEN, "psf build: out of memory");
        return 1;
    }
    for (int j = 0; j < bh; j++)
        for (int i = 0; i < bw; i++) {
            long px = bx0 + i, py = by0 + j;
            if (px >= 1 && px <= s->f.im.nx && py >= 1 && py <= s->f.im.ny)
                s->f.im.pix[(size_t)(py - 1) * s->f.im.nx + (size_t)(px - 1)] +=
                    flux * prf[(size_t)j * bw + i];
        }
    free(prf);
    mp_prf_work_free(&w);
    return 0;
}

/* The columns of a star table: the fit's when present, else find's. */
static int star_cols(const mp_table *t, int *cx, int *cy, int *cf)
{
    *cx = mp_table_col(t, "XPSF_IMAGE");
    *cy = mp_table_col(t, "YPSF_IMAGE");
    *cf = mp_table_col(t, "FLUX_PSF");
    if (*cx < 0 || *cy < 0 || *cf < 0) {
        *cx = mp_table_col(t, "X_IMAGE");
        *cy = mp_table_col(t, "Y_IMAGE");
        *cf = mp_table_col(t, "FLUX");
    }
    return *cx >= 0 && *cy >= 0 && *cf >= 0;
}

/* Star s's neighbours among t's rows: the MP_EPSF_MAXNB brightest within
 * rmax, kept sorted by flux, brightest first. */
static void pick_neighbours(mp_epsf_star *s, const mp_table *t, int cx, int cy, int cf,
                            double rmax)
{
    s->nnb = 0;
    /* The distances by mp_within (hypot on every row of the frame was
     * 1.4 % of frame B built, tests/bench/daophot).  The star's own flux
     * on the table's scale: its row within 1 px. */
    double F0 = s->flux;
    for (size_t r = 0; r < t->nrow; r++)
        if (mp_within(mp_table_get(t, r, cx) - s->xf, mp_table_get(t, r, cy) - s->yf, 1.0) &&
            mp_table_get(t, r, cf) > 0)
            F0 = mp_table_get(t, r, cf);
    for (size_t r = 0; r < t->nrow; r++) {
        double x = mp_table_get(t, r, cx), y = mp_table_get(t, r, cy), F = mp_table_get(t, r, cf);
        double dx = x - s->xf, dy = y - s->yf;
        if (!mp_within(dx, dy, rmax) || mp_within(dx, dy, 1.0) || !(F > 0) || !isfinite(F) ||
            F < MP_EPSF_NBMIN * F0)
            continue;
        if (s->nnb == MP_EPSF_MAXNB && s->nbf[MP_EPSF_MAXNB - 1] >= F)
            continue;
        int q = s->nnb < MP_EPSF_MAXNB ? s->nnb++ : MP_EPSF_MAXNB - 1;
        for (; q > 0 && s->nbf[q - 1] < F; q--) {
            s->nbx[q] = s->nbx[q - 1];
            s->nby[q] = s->nby[q - 1];
            s->nbf[q] = s->nbf[q - 1];
            s->nbrow[q] = s->nbrow[q - 1];
        }
        s->nbx[q] = x;
        s->nby[q] = y;
        s->nbf[q] = F;
        s->nbrow[q] = r;
    }
}

int mp_epsf_neighbours(mp_epsf_star *s, size_t n, const mp_table *t, const mp_prf_model *m,
                       double psfrad, char *err)
{
    int cx, cy, cf;
    if (!t || !star_cols(t, &cx, &cy, &cf))
        return 0;
    /* In parallel over the stars, each writing its own (0.8 % of 47 Tuc
     * built ran here on one thread, bench/SCALING.md). */
    int failed = 0;
#pragma omp parallel for schedule(dynamic) reduction(| : failed)
    for (size_t k = 0; k < n; k++) {
        char e2[MP_ERRLEN];
        if (failed)
            continue;
        pick_neighbours(&s[k], t, cx, cy, cf, psfrad + MP_EPSF_ANNULUS(psfrad));
        for (int j = 0; m && j < s[k].nnb && !failed; j++)
            failed = mp_epsf_cutout_add(&s[k], m, s[k].nbx[j], s[k].nby[j], s[k].nbf[j], e2);
        size_t np = (size_t)s[k].f.im.nx * s[k].f.im.ny;
        if (failed || s[k].nnb == 0)
            continue;
        if (!(s[k].raw = malloc(np * sizeof *s[k].raw)))
            failed = 1;
        else
            memcpy(s[k].raw, s[k].f.im.pix, np * sizeof *s[k].raw);
    }
    if (failed)
        snprintf(err, MP_ERRLEN, "psf build: out of memory");
    return failed;
}

int mp_epsf_clean(mp_epsf_star *s, const mp_psf *tab, const mp_prf_cache *grid, double psfrad)
{
    if (!s->raw)
        return 0;
    mp_frame *f = &s->f;
    size_t np = (size_t)f->im.nx * f->im.ny;
    memcpy(f->im.pix, s->raw, np * sizeof *f->im.pix);
    mp_prf_model m = {tab, NULL, 10};
    mp_prf_work w;
    memset(&w, 0, sizeof w);
    w.single = 1;               /* light taken off and held (fit/prf_axis.h) */
    double *prf = NULL, *buf = malloc(2 * np * sizeof *buf);
    size_t nprf = 0;
    int rc = !buf;
    for (int j = 0; !rc && j < s->nnb; j++) {
        double xs = s->nbx[j] - (double)(s->x0 - 1), ys = s->nby[j] - (double)(s->y0 - 1);
        long bx0, by0;
        int bw, bh;
        mp_prf_box(&m, xs, ys, &bx0, &by0, &bw, &bh);
        if ((size_t)bw * bh > nprf) {
            free(prf);
            nprf = (size_t)bw * bh;
            if (!(prf = malloc(nprf * sizeof *prf))) {
                rc = 1;
                break;
            }
        }
        /* Each neighbour by its own light's bound (the frame fit's
         * painting of neighbours uses it; the star's light only adds
         * noise there): with the star's, a star too bright for the grid
         * had its neighbours drawn exactly, 151 of 173 samples of this
         * function on 47 Tuc (bench/PROFILE.md). */
        w.grid = mp_epsf_nb_grid(grid, s, j);
        if ((rc = mp_prf_render(&m, xs, ys, prf, NULL, NULL, &w)) != 0)
            break;
        for (int b = 0; b < bh; b++)
            for (int a = 0; a < bw; a++) {
                long px = bx0 + a, py = by0 + b;
                if (px >= 1 && px <= f->im.nx && py >= 1 && py <= f->im.ny)
                    f->im.pix[(size_t)(py - 1) * f->im.nx + (size_t)(px - 1)] -=
                        s->nbf[j] * prf[(size_t)b * bw + a];
            }
    }
    if (!rc) {
        double b = annulus_sky(s, psfrad + 1.0, psfrad + MP_EPSF_ANNULUS(psfrad), buf);
        if (isfinite(b))
            s->sky = b;
    }
    free(prf);
    free(buf);
    mp_prf_work_free(&w);
    return rc;
}
