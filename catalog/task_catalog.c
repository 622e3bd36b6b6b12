/*
 * task_catalog.c — `matphot catalog INPUT [output=] [format=] [image=] ...`:
 * the last stage (design.md §1).  It takes a fit table and writes the
 * catalogue a user keeps: MAG_PSF on a zero point per second of exposure
 * (SExtractor's MAG = MAG_ZEROPOINT - 2.5 log10 FLUX, 99 for FLUX <= 0),
 * ALPHAPSF_J2000/DELTAPSF_J2000 from the frame's WCS, the columns asked
 * for, in ASCII_HEAD, CSV, FITS_1.0 or FITS_LDAC (whose LDAC_IMHEAD holds
 * the frame's header), and a DS9 region file.
 *
 * Every check that can fail is made before anything is written; the region
 * file is written first and removed again if the catalogue then fails, so
 * a failed run leaves no output behind.
 */
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <unistd.h>

#include "catalog/catalog.h"
#include "io/io.h"
#include "params/params.h"

/* SExtractor's magnitude error factor, 2.5 / ln 10. */
#define MAGERR_K 1.0857
/* SExtractor's magnitude for a non-positive flux. */
#define MAG_NONE 99.0

typedef struct {
    const char *input, *output, *image, *columns, *regions;
    mp_table_format fmt;
    int wcs, fk5, label;
    double magzero, radius;
    mp_datapars dp;
} cat_setup;

static int setup_of(const mp_parset *ps, cat_setup *s, char *err)
{
    memset(s, 0, sizeof *s);
    s->input = mp_par_string(ps, "input");
    s->output = mp_par_string(ps, "output");
    s->image = mp_par_string(ps, "image");
    s->columns = mp_par_string(ps, "columns");
    s->regions = mp_par_string(ps, "regions");
    const char *format = mp_par_string(ps, "format");
    if (mp_table_format_parse(format, &s->fmt)) {
        snprintf(err, MP_ERRLEN, "format: unknown table format '%s'", format);
        return 1;
    }
    if ((s->fmt == MP_TAB_FITS || s->fmt == MP_TAB_LDAC) &&
        (!s->output[0] || strcmp(s->output, "-") == 0)) {
        snprintf(err, MP_ERRLEN, "output: format=%s writes a FITS file, which cannot go to "
                 "stdout: give output=NAME", format);
        return 1;
    }
    if ((s->fmt == MP_TAB_FITS || s->fmt == MP_TAB_LDAC) &&
        mp_out_fits_named("output", s->output, err))
        return 1;
    if (s->regions[0] && strcmp(s->regions, "-") == 0 &&
        (!s->output[0] || strcmp(s->output, "-") == 0)) {
        snprintf(err, MP_ERRLEN, "regions: stdout already takes the catalogue; give a file name");
        return 1;
    }
    s->wcs = 1;
    s->label = 1;
    mp_par_bool(ps, "wcs", &s->wcs);
    mp_par_bool(ps, "reglabel", &s->label);
    s->fk5 = strcmp(mp_par_string(ps, "regsys"), "fk5") == 0;
    s->magzero = NAN;
    s->radius = 3.0;
    mp_par_real(ps, "magzero", &s->magzero);
    mp_par_real(ps, "regradius", &s->radius);
    mp_datapars_read(ps, &s->dp);
    return 0;
}

/* The datapars value when set, else the header keyword, else dflt. */
static double detector_value(double par, const mp_image *im, const char *key, double dflt)
{
    double v;
    if (!isnan(par))
        return par;
    if (im && im->hdr && mp_header_double(im, key, &v) == 0)
        return v;
    return dflt;
}

/* Does the header have any CTYPE1 (primary or alternate) card?  A frame
 * without a WCS simply gets no sky positions. */
static int has_wcs_cards(const mp_image *im)
{
    for (int k = 0; im->hdr && k < im->nkeys; k++)
        if (memcmp(im->hdr + (size_t)k * 80, "CTYPE1", 6) == 0)
            return 1;
    return 0;
}

/* MAG_PSF and MAGERR_PSF from FLUX_PSF/FLUXERR_PSF, per second. */
static int recompute_mags(mp_table *t, const char *input, double magzero, double exptime,
                          char *err)
{
    int cf = mp_table_col(t, "FLUX_PSF"), ce = mp_table_col(t, "FLUXERR_PSF");
    if (cf < 0) {
        snprintf(err, MP_ERRLEN, "%s: no FLUX_PSF column to compute MAG_PSF from (magzero=%g)",
                 input, magzero);
        return 1;
    }
    int cm = mp_table_add_col(t, "MAG_PSF");
    /* MAGERR_PSF does not depend on the zero point: without FLUXERR_PSF
     * the fit's own is kept. */
    int cme = ce >= 0 ? mp_table_add_col(t, "MAGERR_PSF") : -1;
    if (cm < 0 || (ce >= 0 && cme < 0)) {
        snprintf(err, MP_ERRLEN, "%s: out of memory", input);
        return 1;
    }
    /* The zero point goes with the magnitudes (matphot merge checks that
     * the frames it averages are all calibrated). */
    int cz = mp_table_add_col(t, "MAGZERO");
    if (cz < 0) {
        snprintf(err, MP_ERRLEN, "%s: out of memory", input);
        return 1;
    }
    double zp = magzero + 2.5 * log10(exptime);
    for (size_t r = 0; r < t->nrow; r++) {
        mp_table_set(t, r, cz, magzero);
        double f = mp_table_get(t, r, cf);
        double m, me = NAN;
        if (isnan(f))
            m = NAN;            /* missing stays missing */
        else if (f <= 0)
            m = me = MAG_NONE;
        else {
            m = zp - 2.5 * log10(f);
            if (ce >= 0)
                me = MAGERR_K * mp_table_get(t, r, ce) / f;
        }
        mp_table_set(t, r, cm, m);
        if (cme >= 0)
            mp_table_set(t, r, cme, me);
    }
    return 0;
}

/* out = the columns of in named in the comma-separated list, in its order
 * (their descriptions and units as in is). */
static int select_columns(const mp_table *in, const char *list, mp_table *out, char *err)
{
    mp_table_init(out);
    size_t n = strlen(list);
    int *idx = malloc((n / 2 + 1) * sizeof *idx);
    char *copy = malloc(n + 1);
    int nsel = 0, rc = 1;
    if (!idx || !copy) {
        snprintf(err, MP_ERRLEN, "columns: out of memory");
        goto done;
    }
    memcpy(copy, list, n + 1);
    for (char *p = copy, *next; p; p = next) {
        next = strchr(p, ',');
        if (next)
            *next++ = '\0';
        while (*p == ' ' || *p == '\t')
            p++;
        size_t len = strlen(p);
        while (len > 0 && (p[len - 1] == ' ' || p[len - 1] == '\t'))
            p[--len] = '\0';
        if (!len) {
            snprintf(err, MP_ERRLEN, "columns: empty column name in '%s'", list);
            goto done;
        }
        int c = mp_table_col(in, p);
        if (c < 0) {
            snprintf(err, MP_ERRLEN, "columns: the input has no column %s", p);
            goto done;
        }
        for (int k = 0; k < nsel; k++)
            if (idx[k] == c) {
                snprintf(err, MP_ERRLEN, "columns: %s is listed twice", p);
                goto done;
            }
        idx[nsel++] = c;
    }
    for (int k = 0; k < nsel; k++) {
        int c = mp_table_add_col(out, in->cols[idx[k]].name);
        if (c < 0)
            goto oom;
        out->cols[c] = in->cols[idx[k]];
    }
    for (size_t r = 0; r < in->nrow; r++) {
        long o = mp_table_add_row(out);
        if (o < 0)
            goto oom;
        for (int k = 0; k < nsel; k++)
            mp_table_set(out, (size_t)o, k, mp_table_get(in, r, idx[k]));
    }
    rc = 0;
    goto done;
oom:
    snprintf(err, MP_ERRLEN, "columns: out of memory");
done:
    if (rc)
        mp_table_free(out);
    free(idx);
    free(copy);
    return rc;
}

static int cmp_double(const void *a, const void *b)
{
    double x = *(const double *)a, y = *(const double *)b;
    return (x > y) - (x < y);
}

/* Median of column c's finite values; NaN when there are none. */
static double column_median(const mp_table *t, int c)
{
    double *v = malloc((t->nrow ? t->nrow : 1) * sizeof *v);
    if (!v)
        return NAN;
    size_t n = 0;
    for (size_t r = 0; r < t->nrow; r++)
        if (isfinite(mp_table_get(t, r, c)))
            v[n++] = mp_table_get(t, r, c);
    double m = NAN;
    if (n) {
        qsort(v, n, sizeof *v, cmp_double);
        m = n % 2 ? v[n / 2] : 0.5 * (v[n / 2 - 1] + v[n / 2]);
    }
    free(v);
    return m;
}

/* SExtractor's keywords in LDAC_IMHEAD that readers look for: PSFEx needs
 * SEXBKDEV and SEXGAIN.  The background is the fit's sky (SKY_PSF, in
 * electrons) in ADU, and its RMS the photon + read noise of that sky. */
static int ldac_extras(const cat_setup *s, const mp_image *im, const mp_table *t,
                       double exptime, mp_card *k)
{
    int n = 0;
    double gain = detector_value(s->dp.gain, im, "GAIN", NAN);
    double ron = detector_value(s->dp.rdnoise, im, "RDNOISE", 0.0);
    if (s->image[0])
        k[n++] = (mp_card){"FITSFILE", 0, s->image, "File name of the analysed image"};
    k[n++] = (mp_card){"SEXNFIN", (double)t->nrow, NULL, "Final number of extracted sources"};
    k[n++] = (mp_card){"SEXNPARA", (double)t->ncol, NULL, "Number of parameters per source"};
    int cs = mp_table_col(t, "SKY_PSF");
    if (gain > 0 && cs >= 0) {
        double sky = column_median(t, cs);
        if (isfinite(sky)) {
            k[n++] = (mp_card){"SEXBKGND", sky / gain, NULL, "Median background level (ADU)"};
            k[n++] = (mp_card){"SEXBKDEV", sqrt(fmax(sky, 0.0) + ron * ron) / gain, NULL,
                               "Median background RMS (ADU)"};
        }
    }
    if (gain > 0)
        k[n++] = (mp_card){"SEXGAIN", gain, NULL, "Gain used (e-/ADU)"};
    if (isfinite(s->magzero))
        k[n++] = (mp_card){"SEXMGZPT", s->magzero, NULL, "Zero-point used for magnitudes"};
    if (!isnan(s->dp.exptime))
        k[n++] = (mp_card){"EXPTIME", exptime, NULL, "[s] exposure time"};
    return n;
}

/* What one catalog run holds between its steps. */
typedef struct {
    mp_table t;          /* the input table, with magnitudes and sky added */
    mp_image im;         /* image=, when given */
    int have_image;
    double exptime;
} cat_run;

/* The input table and, when image= is given, the frame (header and WCS). */
static int read_inputs(const cat_setup *s, cat_run *r, char *err)
{
    if (mp_table_read(s->input, &r->t, err))
        return 1;
    if (s->image[0]) {
        if (mp_image_read(s->image, &r->im, err))
            return 1;
        r->have_image = 1;
    }
    r->exptime = detector_value(s->dp.exptime, r->have_image ? &r->im : NULL, "EXPTIME", 1.0);
    return 0;
}

/* MAG_* from the fluxes when magzero= is given: magnitudes per second. */
static int apply_magzero(const cat_setup *s, cat_run *r, char *err)
{
    if (!isfinite(s->magzero))
        return 0;
    if (!(r->exptime > 0) || !isfinite(r->exptime)) {
        snprintf(err, MP_ERRLEN, "%s: exposure time %g is not positive: magnitudes per "
                 "second need one (give exptime=)",
                 isnan(s->dp.exptime) ? s->image : "exptime", r->exptime);
        return 1;
    }
    return recompute_mags(&r->t, s->input, s->magzero, r->exptime, err);
}

/* Sky positions by the WCS section's routine (catalog/wcs.c). */
static int add_sky(const cat_setup *s, cat_run *r, char *err)
{
    if (!s->wcs || !r->have_image || !has_wcs_cards(&r->im))
        return 0;
    char e[MP_ERRLEN];
    if (mp_table_add_sky(&r->t, &r->im, e)) {
        snprintf(err, MP_ERRLEN, "%.200s: %.300s", s->image, e);
        return 1;
    }
    return 0;
}

/* Regions come from the whole table (FLAGS and NUMBER even when columns=
 * leaves them out of the catalogue). *wrote: a regions file now exists. */
static int write_regions(const cat_setup *s, const cat_run *r, int *wrote, char *err)
{
    *wrote = 0;
    if (!s->regions[0])
        return 0;
    mp_region_opts ro = {s->radius, s->fk5, s->label};
    if (mp_regions_write(s->regions, &r->t, &ro, NULL, err)) {
        if (s->fk5 && mp_table_col(&r->t, "ALPHAPSF_J2000") < 0 &&
            mp_table_col(&r->t, "ALPHA_J2000") < 0)
            snprintf(err, MP_ERRLEN, "regsys: fk5 regions need sky positions: give image= "
                     "a frame with a WCS (and wcs=yes), or regsys=image");
        return 1;
    }
    *wrote = strcmp(s->regions, "-") != 0;
    return 0;
}

/* The catalogue in its format; LDAC carries the frame's header and
 * SExtractor's keywords. */
static int write_catalog(const cat_setup *s, const cat_run *r, const mp_table *cat, char *err)
{
    if (s->fmt != MP_TAB_LDAC)
        return mp_table_write(s->output[0] ? s->output : "-", cat, s->fmt, err);
    const mp_image *im = r->have_image ? &r->im : NULL;
    mp_card extra[10];
    mp_ldac_head h = {im ? im->hdr : NULL, im ? im->nkeys : 0, extra, 0};
    h.nextra = ldac_extras(s, im, cat, r->exptime, extra);
    return mp_table_write_fits(s->output, cat, &h, err);
}

int mp_task_catalog(int argc, char **argv)
{
    mp_parset ps;
    int b = mp_task_begin("catalog", argc, argv, &ps);
    if (b)
        return b;
    char err[MP_ERRLEN] = "";
    cat_setup s;
    cat_run r;
    mp_table sel;
    memset(&r, 0, sizeof r);
    mp_table_init(&r.t);
    mp_table_init(&sel);
    int rc = 1, wrote_regions = 0;
    if (setup_of(&ps, &s, err))
        goto done;
    const char *in[2] = {s.input, s.image}, *out[2] = {s.output, s.regions};
    if (mp_outputs_clear(in, 2, out, 2, err) || read_inputs(&s, &r, err) ||
        apply_magzero(&s, &r, err) || add_sky(&s, &r, err))
        goto done;
    const mp_table *cat = &r.t;
    if (s.columns[0]) {
        if (select_columns(&r.t, s.columns, &sel, err))
            goto done;
        cat = &sel;
    }
    /* Killed runs' temporaries: each output directory swept once. */
    mp_sweeps *sw = mp_sweeps_new();
    mp_tmp_sweep(sw, s.regions);
    mp_tmp_sweep(sw, s.output);
    mp_sweeps_free(sw);
    if (write_regions(&s, &r, &wrote_regions, err))
        goto done;
    if (write_catalog(&s, &r, cat, err)) {
        if (wrote_regions)
            unlink(s.regions);   /* no half of the outputs from a failed run */
        goto done;
    }
    rc = 0;
done:
    if (rc)
        fprintf(stderr, "matphot catalog: %s\n", err);
    mp_table_free(&sel);
    mp_table_free(&r.t);
    mp_image_free(&r.im);
    mp_params_free(&ps);
    return rc;
}
