/* task_find.c — the `matphot find` task: IMAGE → table of detections
 * (params/find.par).  IMAGE may be an @list (IRAF); outputs are then
 * output=@list or named after each image (frame.fits → frame.coo, DAOFIND's
 * extension). */
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "catalog/catalog.h"
#include "find/find.h"
#include "io/io.h"
#include "params/params.h"

typedef struct {
    mp_find_opts opts;
    int mesh, filter;
    mp_datapars dp;
    mp_table_format fmt;
} find_setup;

/* A shape limit; INDEF (NaN) means none. */
static double limit(const mp_parset *ps, const char *name)
{
    double v = NAN;
    mp_par_real(ps, name, &v);
    return v;
}

static int setup_of(const mp_parset *ps, find_setup *s, char *err)
{
    memset(s, 0, sizeof *s);
    mp_find_opts_default(&s->opts);
    if (mp_par_need_real(ps, "fwhm", &s->opts.fwhm, err) ||
        mp_par_need_real(ps, "threshold", &s->opts.threshold, err) ||
        mp_par_need_real(ps, "nsigma", &s->opts.nsigma, err) ||
        mp_par_need_int(ps, "mesh", &s->mesh, err) ||
        mp_par_need_int(ps, "filter", &s->filter, err))
        return 1;
    s->opts.sharplo = limit(ps, "sharplo");
    s->opts.sharphi = limit(ps, "sharphi");
    s->opts.roundlo = limit(ps, "roundlo");
    s->opts.roundhi = limit(ps, "roundhi");
    if (s->filter % 2 == 0) {
        snprintf(err, MP_ERRLEN, "filter: %d must be odd (a window centred on each mesh)",
                 s->filter);
        return 1;
    }
    const char *fmt = mp_par_string(ps, "format");
    if (!fmt || mp_table_format_parse(fmt, &s->fmt)) {
        snprintf(err, MP_ERRLEN, "format: unknown table format '%s'", fmt ? fmt : "");
        return 1;
    }
    mp_datapars_read(ps, &s->dp);
    return 0;
}

/* image.fits → image<ext> (section and extension dropped). */
static char *named_after(const char *image, const char *ext)
{
    const char *br = strchr(image, '[');
    size_t n = br ? (size_t)(br - image) : strlen(image);
    const char *dot = NULL;
    for (size_t i = 0; i < n; i++)
        if (image[i] == '.')
            dot = image + i;
        else if (image[i] == '/')
            dot = NULL;
    if (dot && (strncmp(dot, ".fits", 5) == 0 || strncmp(dot, ".fit", 4) == 0 ||
                strncmp(dot, ".fts", 4) == 0))
        n = (size_t)(dot - image);
    char *s = malloc(n + strlen(ext) + 1);
    if (s) {
        memcpy(s, image, n);
        strcpy(s + n, ext);
    }
    return s;
}

static int find_one(const find_setup *s, const char *image, const char *output, char *err)
{
    mp_frame f;
    mp_bkg b = {0};
    mp_table t;
    mp_table_init(&t);
    char e[MP_ERRLEN];
    int rc = 1;
    if (mp_frame_read(image, &s->dp, &f, err))
        goto done;
    if (mp_bkg_estimate(&f, s->mesh, s->filter, &b, e) ||
        mp_find_stars(&f, &b, &s->opts, &t, e)) {
        snprintf(err, MP_ERRLEN, "%.200s: %.300s", image, e);
        goto done;
    }
    /* A frame with no usable star is bad input: none found, or all its
     * pixels bad or saturated (saturate=0 found the frame as one star). */
    char why[300];
    if ((t.nrow == 0 || f.nbad + f.nsat >= f.im.nx * f.im.ny) &&
        (mp_find_why_none(&f, &b, s->opts.threshold, why, sizeof why) || t.nrow == 0)) {
        snprintf(err, MP_ERRLEN, "%.200s: no star found: %.290s", image, why);
        goto done;
    }
    if (mp_table_write(output, &t, s->fmt, err))
        goto done;
    rc = 0;
done:
    mp_table_free(&t);
    mp_bkg_free(&b);
    mp_frame_free(&f);
    return rc;
}

int mp_task_find(int argc, char **argv)
{
    mp_parset ps;
    int b = mp_task_begin("find", argc, argv, &ps);
    if (b)
        return b;
    char err[MP_ERRLEN] = "";
    find_setup s;
    char **im = NULL, **out = NULL;
    size_t nim = 0, nout = 0;
    int rc = 1;
    mp_sweeps *sw = NULL;
    mp_inputs *ins = NULL;
    if (setup_of(&ps, &s, err))
        goto done;
    if (mp_params_list(mp_par_string(&ps, "image"), &im, &nim, err) ||
        mp_params_list(mp_par_string(&ps, "output"), &out, &nout, err))
        goto done;
    if (nim == 0) {
        snprintf(err, MP_ERRLEN, "image: no image named");
        goto done;
    }
    if (nout && nout != nim) {
        snprintf(err, MP_ERRLEN, "output: %zu outputs for %zu images: lists must pair "
                 "line by line", nout, nim);
        goto done;
    }
    sw = mp_sweeps_new();        /* each output directory swept once */
    /* every frame of the list: an output of the first may be the input
     * of a later one */
    if (!(ins = mp_inputs_of((const char *const *)im, nim)) ||
        mp_inputs_add(ins, s.dp.dqmask) || mp_inputs_add(ins, s.dp.errplane)) {
        snprintf(err, MP_ERRLEN, "out of memory");
        goto done;
    }
    /* A frame's bad input is its own line: the list's other frames go on,
     * the status 1 (as pipeline's). */
    int failed = 0;
    for (size_t i = 0; i < nim; i++) {
        char *named = NULL;
        const char *o = nout ? out[i] : "-";
        if (!nout && nim > 1) {
            if (!(named = named_after(im[i], ".coo"))) {
                snprintf(err, MP_ERRLEN, "out of memory");
                goto done;
            }
            o = named;
        }
        int r = mp_out_overwrites(ins, o, err);
        if (!r) {
            mp_tmp_sweep(sw, o);
            r = find_one(&s, im[i], o, err);
        }
        free(named);
        if (r)
            fprintf(stderr, "matphot find: %s\n", err);
        failed |= r;
    }
    rc = failed;
    err[0] = '\0';             /* each said where it happened */
done:
    if (rc && err[0])
        fprintf(stderr, "matphot find: %s\n", err);
    mp_list_free(im, nim);
    mp_list_free(out, nout);
    mp_sweeps_free(sw);
    mp_inputs_free(ins);
    mp_params_free(&ps);
    return rc;
}
