/* outputs.c — what the pipeline writes for one frame: the intermediate
 * tables, the residual image, the catalog (with sky positions when the
 * frame has a WCS) and its DS9 regions, and the run report. */
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include "pipeline/pipeline_priv.h"

const char *const mp_pl_products[MP_PL_NPRODUCT] = {".coo", ".grp", ".fit", ".res.fits",
                                                    ".cat", ".reg", ".report", ".psf.fits"};

/* root + ext, written atomically in format fmt. */
int mp_pl_write_named(const char *root, const char *ext, const mp_table *t,
                      mp_table_format fmt, const mp_text_kept *prev, mp_text_kept **keep,
                      char *err)
{
    size_t n = strlen(root) + strlen(ext) + 1;
    char *path = malloc(n);
    if (!path) {
        snprintf(err, MP_ERRLEN, "out of memory");
        return 1;
    }
    snprintf(path, n, "%s%s", root, ext);
    int rc = mp_table_write_kept(path, t, fmt, prev, keep, err);
    free(path);
    return rc;
}

int mp_pl_outputs_clear(const char *root, const char *const *ext, size_t next,
                        const mp_inputs *in, char *err)
{
    for (size_t k = 0; k < next; k++) {
        char *path = mp_name_after(root, ext[k]);
        if (!path) {
            snprintf(err, MP_ERRLEN, "out of memory");
            return 1;
        }
        int rc = mp_out_overwrites(in, path, err);
        free(path);
        if (rc)
            return 1;
    }
    return 0;
}

int mp_pl_no_star(const char *image, const mp_frame *f, const char *none_why, double fwhm,
                  const mp_pipeline_opts *o, const mp_pipeline_report *rep, char *err)
{
    char why[320];
    long seen = rep->found + rep->added;
    double th = rep->threshold > 0 ? rep->threshold : o->find.threshold;
    if (f && mp_find_why_none(f, NULL, th, why, sizeof why))
        ;                       /* the frame's own fault, whatever was detected */
    else if (seen == 0 && rep->screened == 0 && none_why[0])
        snprintf(why, sizeof why, "%s", none_why);
    else if (seen == 0 && rep->screened == 0)
        snprintf(why, sizeof why, "no source above threshold %g sigma of the kernel's amplitude",
                 th);
    else {
        /* A disc narrower than the star cannot tell its light from the sky
         * (fitrad=1 on stars of FWHM 3: 5 pixels, every flux error huge). */
        double fr = o->fit.opts.fit.fitrad;
        char narrow[128] = "";
        if (fr > 0 && fwhm > 0 && fr < fwhm)
            snprintf(narrow, sizeof narrow, "; fitrad %.3g px is under the PSF's FWHM %.3g px: "
                     "a disc that narrow cannot tell a star from its sky", fr, fwhm);
        snprintf(why, sizeof why, "%ld detection%s and %ld candidate%s below the screen's S/N, "
                 "none kept by its fit (S/N FLUX_PSF/FLUXERR_PSF >= minsnr %g, not merged)%s",
                 seen, seen == 1 ? "" : "s", rep->screened, rep->screened == 1 ? "" : "s",
                 o->fit.opts.minsnr, narrow);
    }
    snprintf(err, MP_ERRLEN, "%.180s: no usable star: %.310s", image, why);
    return 1;
}

/* Does the header have a CTYPE1 card (a WCS to try)? */
static int has_wcs(const mp_image *im)
{
    for (int k = 0; k < im->nkeys; k++)
        if (memcmp(im->hdr + (size_t)k * 80, "CTYPE1", 6) == 0)
            return 1;
    return 0;
}

/* root.cat (sky positions when the frame has a WCS; FITS_LDAC carries the
 * frame's header as SExtractor's does) and the DS9 regions root.reg;
 * root.fit holds t in o->fit.fmt (written just before). */
int mp_pl_write_catalog(const char *root, const mp_frame *f, mp_table *t,
                         const mp_pipeline_opts *o, const mp_text_kept *fit_text, char *err)
{
    char e[MP_ERRLEN];
    mp_image hv = mp_fimage_header(&f->im);
    int sky = has_wcs(&hv);
    if (sky && mp_table_add_sky(t, &hv, e))
        fprintf(stderr, "matphot pipeline: warning: no sky positions: %s\n", e);
    size_t n = strlen(root) + 8;
    char *path = malloc(n);
    if (!path) {
        snprintf(err, MP_ERRLEN, "out of memory");
        return 1;
    }
    int rc;
    if (o->catfmt == MP_TAB_LDAC) {
        mp_card extra[2] = {{"SEXGAIN", f->gain, NULL, "gain [e-/ADU]"},
                            {"EXPTIME", f->exptime, NULL, "exposure time [s]"}};
        mp_ldac_head h = {f->im.hdr, f->im.nkeys, extra, 2};
        snprintf(path, n, "%s.cat", root);
        rc = mp_table_write_fits(path, t, &h, err);
    } else if (!sky && o->catfmt == o->fit.fmt && o->catfmt != MP_TAB_FITS) {
        /* root.fit's text, the same table: copied, not formatted again
         * (the text's numbers were most of a 5000-star frame's writes) */
        char *fit = malloc(n);
        rc = !fit;
        if (fit) {
            snprintf(fit, n, "%s.fit", root);
            snprintf(path, n, "%s.cat", root);
            rc = mp_out_copy(fit, path, err);
        } else {
            snprintf(err, MP_ERRLEN, "out of memory");
        }
        free(fit);
    } else {
        rc = mp_pl_write_named(root, ".cat", t, o->catfmt,
                               o->catfmt == o->fit.fmt ? fit_text : NULL, NULL, err);
    }
    if (!rc && o->regions) {
        mp_region_opts ro = {3.0, 0, 1};
        snprintf(path, n, "%s.reg", root);
        rc = mp_regions_write(path, t, &ro, NULL, err);
    }
    free(path);
    return rc;
}


int mp_pl_residual_open(const char *root, const mp_frame *f, long nx, long ny,
                        mp_image_out **out, char *err)
{
    size_t n = strlen(root) + 10;
    char *path = malloc(n);
    if (!path) {
        snprintf(err, MP_ERRLEN, "out of memory");
        return 1;
    }
    snprintf(path, n, "%s.res.fits", root);
    mp_card cards[2] = {{"GAIN", f->gain, NULL, "e-/ADU"}, {"RDNOISE", f->rdnoise, NULL, "e-"}};
    int rc = mp_image_out_open(path, nx, ny, cards, 2, out, err);
    free(path);
    return rc;
}

int mp_pl_residual_put(mp_image_out *out, const mp_frame *f, const float *res, long x1, long y1,
                       long w, long h, long ox, long oy, char *err)
{
    /* RES_ROWS rows at a time, in ADU: no copy of the frame's size; the
     * rows converted in parallel and written by one call (a row a call,
     * serial, was 3 % of a 2048² run's wall time on 16 threads). */
    enum { RES_ROWS = 64 };
    long nb = h < RES_ROWS ? h : RES_ROWS;
    double *rows = malloc((size_t)w * (size_t)(nb > 0 ? nb : 1) * sizeof *rows);
    if (!rows) {
        snprintf(err, MP_ERRLEN, "out of memory");
        return 1;
    }
    int rc = 0;
    for (long j0 = 0; j0 < h && !rc; j0 += nb) {
        long m = h - j0 < nb ? h - j0 : nb;
#pragma omp parallel for schedule(static) if ((size_t)w * (size_t)m > 65536)
        for (long j = 0; j < m; j++) {
            size_t p = (size_t)(y1 - 1 - oy + j0 + j) * (size_t)f->im.nx + (size_t)(x1 - 1 - ox);
            double *row = rows + (size_t)j * (size_t)w;
            for (long i = 0; i < w; i++)
                row[i] = (f->mask[p + i] & MP_MASK_BAD) ? NAN : res[p + i] / f->gain;
        }
        rc = mp_image_out_put(out, x1, y1 + j0, w, m, rows, err);
    }
    free(rows);
    return rc;
}

int mp_pl_write_residual(const char *root, const mp_frame *f, const float *res, char *err)
{
    mp_image_out *out;
    if (mp_pl_residual_open(root, f, f->im.nx, f->im.ny, &out, err))
        return 1;
    int rc = mp_pl_residual_put(out, f, res, 1, 1, f->im.nx, f->im.ny, 0, 0, err);
    return mp_image_out_close(out, !rc, err) || rc;
}

/* The run report's counts, from the pipeline's. */
static void report_counts(const mp_pipeline_report *rep, const mp_table *t, mp_run_report *run)
{
    run->t_read = rep->t_read;
    run->t_bkg = rep->t_bkg;
    run->t_find = rep->t_find;
    run->t_group = rep->t_group;
    run->t_fit = rep->t_fit;
    run->t_write = rep->t_write;
    mp_report_counts(&rep->fit, run);
    run->nstars = (long)t->nrow;
    run->pairs_close = rep->pairs_close;
    run->pairs_coupled = rep->pairs_coupled;
}

static int cmp_dbl(const void *a, const void *b)
{
    double x = *(const double *)a, y = *(const double *)b;
    return (x > y) - (x < y);
}

/* Median of the finite values of column name, NaN when none. */
static double col_median(const mp_table *t, const char *name)
{
    int c = mp_table_col(t, name);
    double *v = c >= 0 && t->nrow ? malloc(t->nrow * sizeof *v) : NULL;
    size_t n = 0;
    for (size_t r = 0; v && r < t->nrow; r++) {
        double x = mp_table_get(t, r, c);
        if (isfinite(x))
            v[n++] = x;
    }
    double m = NAN;
    if (n) {
        qsort(v, n, sizeof *v, cmp_dbl);
        m = n % 2 ? v[n / 2] : 0.5 * (v[n / 2 - 1] + v[n / 2]);
    }
    free(v);
    return m;
}

/* The detection limit stated as the S/N of a fitted star (issue 13), and
 * the flux it means for an isolated star on this frame: the paper's
 * practical S/N E/√(E + β(B + RON²)) = minsnr solved for E, with β and B
 * the catalog's median BETA_PSF and SKY_PSF. */
static void detection_line(const mp_fit_setup *fit, const mp_pipeline_report *rep,
                           const mp_table *t, mp_run_report *run)
{
    double s = fit->opts.minsnr, cut = s - MP_PL_SCREEN_SLACK;
    size_t n = sizeof run->detection;
    int k = s > 0 ? snprintf(run->detection, n, "a star is kept when its fit's S/N "
                             "FLUX_PSF/FLUXERR_PSF >= %g (minsnr)", s)
                  : snprintf(run->detection, n, "no S/N cut (minsnr 0)");
    if (k < 0 || (size_t)k >= n)
        return;
    if (rep->threshold > 0)
        k += snprintf(run->detection + k, n - (size_t)k, "; find offers peaks above %g sigma "
                      "of its kernel's amplitude (threshold; on the residual also, where that "
                      "stays below it, of the amplitude over the fitted sky)", rep->threshold);
    if (k > 0 && (size_t)k < n && s > 0 && cut > 0)
        k += snprintf(run->detection + k, n - (size_t)k, ", a linear fit at each keeps S/N "
                      ">= %g", cut);
    if (k > 0 && (size_t)k < n && rep->sharp[0])
        k += snprintf(run->detection + k, n - (size_t)k, "; %s; on the residual the low limit "
                      "less %g of each candidate's own sharpness sigma", rep->sharp,
                      MP_PL_SHARP_SIGMA);
    if (k > 0 && (size_t)k < n && rep->stars_fwhm[0])
        k += snprintf(run->detection + k, n - (size_t)k, "; %s", rep->stars_fwhm);
    if (k > 0 && (size_t)k < n && (rep->escale[0] != 1.0 || rep->escale[1] != 1.0))
        k += snprintf(run->detection + k, n - (size_t)k, "; the catalog's errors are the "
                      "fit's x %.3g (flux), x %.3g (position), what the residual holds at the "
                      "PSF's scale (its S/N that much lower)", rep->escale[0], rep->escale[1]);
    mp_pl_escale es = {{rep->escale[0], rep->escale[1]},
                       {rep->escale_raw[0], rep->escale_raw[1], rep->escale_raw[2]},
                       rep->escale_places > 0 ? (size_t)rep->escale_places : 0};
    if (k > 0 && (size_t)k < n && mp_pl_escale_unused(&es)) {
        char why[320];
        mp_pl_escale_unused_why(&es, why, sizeof why);
        k += snprintf(run->detection + k, n - (size_t)k, "; %s", why);
    }
    if (k > 0 && (size_t)k < n && rep->cr_k > 0)
        k += snprintf(run->detection + k, n - (size_t)k, "; %ld pixels masked as cosmic rays "
                      "or hot pixels around %ld that no sum of stars makes (crmask: side "
                      "neighbours under %.3g of the pixel by %.2f sigma)", rep->cr_masked,
                      rep->cr_cores, rep->cr_s, rep->cr_k);
    double beta = col_median(t, "BETA_PSF"), B = col_median(t, "SKY_PSF");
    double v = beta * (fmax(B, 0.0) + rep->rdnoise * rep->rdnoise);
    if (k > 0 && (size_t)k < n && s > 0 && isfinite(v) && v > 0) {
        double E = 0.5 * (s * s + sqrt(s * s * s * s + 4.0 * s * s * v));
        snprintf(run->detection + k, n - (size_t)k, "; S/N %g here is E = %.4g e- (MAG_PSF "
                 "%.2f) for an isolated star on the median sky %.4g e- (beta %.3g px^2, "
                 "RON %.3g e-)", s, E, -2.5 * log10(E) + fit->opts.magzero, B, beta,
                 rep->rdnoise);
    }
}

int mp_pl_write_report(const char *image, const char *root,
                       const mp_fit_setup *fit, const mp_pipeline_report *rep, const mp_table *t,
                       char *err)
{
    mp_run_report run;
    memset(&run, 0, sizeof run);
    run.image = image;
    report_counts(rep, t, &run);
    mp_report_from_table(t, &run);
    mp_frame_report last = {.nstars = (long)t->nrow, .ngroups = rep->fit.ngroups};
    memcpy(last.sky_groups, rep->fit.sky_groups, sizeof last.sky_groups);
    mp_report_parts(&fit->model, &fit->opts, &last, &run);
    run.decisions = fit->decisions;
    run.ndecisions = fit->ndecisions;
    char tables[512];
    mp_econ_summary(fit->cache, rep->fit.ops_render, tables, sizeof tables);
    run.tables = tables;
    detection_line(fit, rep, t, &run);
    size_t n = strlen(root) + 8;
    char *path = malloc(n);
    if (!path) {
        snprintf(err, MP_ERRLEN, "out of memory");
        return 1;
    }
    snprintf(path, n, "%s.report", root);
    int rc = mp_report_write(path, "pipeline", &run, err);
    free(path);
    return rc;
}
