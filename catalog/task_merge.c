/* task_merge.c — the `matphot merge` task: an @list of catalogs → the
 * survey catalog and its detections table (catalog.h, "Survey merge"). */
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "catalog/catalog.h"
#include "params/params.h"

typedef struct {
    const char *input, *output, *detections;
    char *det_owned;
    mp_table_format fmt;
    mp_merge_opts o;
} merge_setup;

/* output.cat → output.det; output.fits → output.det.fits; else + ".det". */
static char *det_name(const char *out, mp_table_format fmt)
{
    size_t n = strlen(out);
    const char *tail = fmt == MP_TAB_FITS ? ".det.fits" : ".det";
    if (n > 4 && strcmp(out + n - 4, ".cat") == 0)
        n -= 4;
    else if (n > 5 && strcmp(out + n - 5, ".fits") == 0)
        n -= 5;
    char *s = malloc(n + strlen(tail) + 1);
    if (s) {
        memcpy(s, out, n);
        strcpy(s + n, tail);
    }
    return s;
}

static int setup_of(const mp_parset *ps, merge_setup *s, char *err)
{
    memset(s, 0, sizeof *s);
    s->input = mp_par_string(ps, "input");
    s->output = mp_par_string(ps, "output");
    s->detections = mp_par_string(ps, "detections");
    const char *f = mp_par_string(ps, "format");
    if (!s->input || !s->output || !s->detections || !f ||
        mp_par_real(ps, "nsigma", &s->o.nsigma) || mp_par_real(ps, "syserr", &s->o.syserr) ||
        mp_par_real(ps, "maxrad", &s->o.maxrad) || mp_par_real(ps, "pixscale", &s->o.pixscale)) {
        snprintf(err, MP_ERRLEN, "merge.par: a parameter is missing from the defaults");
        return 1;
    }
    if (mp_table_format_parse(f, &s->fmt) || s->fmt == MP_TAB_LDAC) {
        snprintf(err, MP_ERRLEN, "format: '%s' is not ascii_head, csv or fits", f);
        return 1;
    }
    const char *nan = !isfinite(s->o.nsigma) ? "nsigma" : !isfinite(s->o.syserr) ? "syserr"
                    : !isfinite(s->o.maxrad) ? "maxrad" : NULL;
    if (nan) {
        snprintf(err, MP_ERRLEN, "%s: INDEF is not allowed; give a number", nan);
        return 1;
    }
    if (!*s->output || strcmp(s->output, "-") == 0) {
        snprintf(err, MP_ERRLEN, "output: name a file (the detections table is named after it)");
        return 1;
    }
    if (!*s->detections) {
        if (!(s->det_owned = det_name(s->output, s->fmt))) {
            snprintf(err, MP_ERRLEN, "out of memory");
            return 1;
        }
        s->detections = s->det_owned;
    }
    if (strcmp(s->detections, s->output) == 0) {
        snprintf(err, MP_ERRLEN, "detections: '%s' is also the output", s->detections);
        return 1;
    }
    return 0;
}

/* Every catalog of the list into the merge, in order. */
static int merge_all(mp_merge *m, char **cats, size_t n, long *ndet, char *err)
{
    *ndet = 0;
    for (size_t i = 0; i < n; i++) {
        mp_table t;
        long skipped = 0;
        if (mp_table_read(cats[i], &t, err))
            return 1;
        int rc = mp_merge_add(m, &t, cats[i], &skipped, err);
        if (!rc && skipped > 0)
            fprintf(stderr, "matphot merge: %s: %ld rows without a sky position or position "
                    "errors left out\n", cats[i], skipped);
        *ndet += (long)t.nrow - skipped;
        mp_table_free(&t);
        if (rc)
            return 1;
    }
    return 0;
}

int mp_task_merge(int argc, char **argv)
{
    mp_parset ps;
    int b = mp_task_begin("merge", argc, argv, &ps);
    if (b)
        return b;
    char err[MP_ERRLEN] = "";
    merge_setup s;
    char **cats = NULL;
    size_t ncat = 0;
    mp_merge *m = NULL;
    mp_table src, det;
    mp_table_init(&src);
    mp_table_init(&det);
    long ndet = 0;
    int rc = 1;
    if (setup_of(&ps, &s, err) || mp_params_list(s.input, &cats, &ncat, err))
        goto done;
    if (ncat == 0) {
        snprintf(err, MP_ERRLEN, "input: no catalog given");
        goto done;
    }
    const char *out[2] = {s.output, s.detections};
    if (mp_outputs_clear((const char *const *)cats, ncat, out, 2, err))
        goto done;
    if (!(m = mp_merge_new(&s.o))) {
        snprintf(err, MP_ERRLEN, "out of memory");
        goto done;
    }
    if (merge_all(m, cats, ncat, &ndet, err) || mp_merge_tables(m, &src, &det, err))
        goto done;
    /* Killed runs' temporaries: each output directory swept once. */
    mp_sweeps *sw = mp_sweeps_new();
    mp_tmp_sweep(sw, s.detections);
    mp_tmp_sweep(sw, s.output);
    mp_sweeps_free(sw);
    /* The detections first: a survey catalog on disk always has its table. */
    if (mp_table_write(s.detections, &det, s.fmt, err))
        goto done;
    if (mp_table_write(s.output, &src, s.fmt, err)) {
        remove(s.detections);
        goto done;
    }
    fprintf(stderr, "matphot merge: %zu catalogs, %ld detections -> %zu sources (%s, %s)\n",
            ncat, ndet, src.nrow, s.output, s.detections);
    rc = 0;
done:
    if (rc)
        fprintf(stderr, "matphot merge: %s\n", err);
    mp_merge_free(m);
    mp_table_free(&src);
    mp_table_free(&det);
    mp_list_free(cats, ncat);
    free(s.det_owned);
    mp_params_free(&ps);
    return rc;
}
