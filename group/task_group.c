/* task_group.c — the `matphot group` task: INPUT table → the same table with
 * GROUP_ID, GROUP_SIZE and FLAGS (params/group.par).  stdout carries only
 * the table, so `matphot find f.fits | matphot group - | matphot fit f.fits -`
 * works; with verbose=yes a histogram of group sizes goes to stderr, as
 * DAOPHOT GROUP prints one. */
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "catalog/catalog.h"
#include "group/group.h"
#include "params/params.h"

static int read_opts(const mp_parset *ps, mp_group_opts *o, mp_table_format *fmt,
                     int *verbose, char *err)
{
    mp_group_opts_default(o);
    if (mp_par_need_real(ps, "fitrad", &o->fitrad, err) ||
        mp_par_need_real(ps, "psfrad", &o->psfrad, err))
        return 1;
    if (mp_par_need_int(ps, "maxgroup", &o->maxgroup, err))
        return 1;
    if (mp_par_bool(ps, "verbose", verbose)) {
        snprintf(err, MP_ERRLEN, "verbose: give yes or no");
        return 1;
    }
    const char *f = mp_par_string(ps, "format");
    if (!f || mp_table_format_parse(f, fmt)) {
        snprintf(err, MP_ERRLEN, "format: unknown table format '%s'", f ? f : "");
        return 1;
    }
    return 0;
}

/* DAOPHOT GROUP's summary: how many groups of each size. */
static int histogram(const mp_table *t, const mp_group_opts *o, const char *input, char *err)
{
    int cs = mp_table_col(t, "GROUP_SIZE"), cf = mp_table_col(t, "FLAGS");
    size_t big = 0, nsplit = 0;
    for (size_t i = 0; i < t->nrow; i++) {
        double s = mp_table_get(t, i, cs);
        big = s > (double)big ? (size_t)s : big;
        nsplit += fmod(floor(mp_table_get(t, i, cf) / 2), 2) == 1;
    }
    size_t *h = calloc(big + 1, sizeof *h);
    if (!h) {
        snprintf(err, MP_ERRLEN, "out of memory for the histogram");
        return 1;
    }
    for (size_t i = 0; i < t->nrow; i++)
        h[(size_t)mp_table_get(t, i, cs)]++;
    size_t ngroups = 0;
    for (size_t s = 1; s <= big; s++)
        ngroups += h[s] / s;
    fprintf(stderr, "matphot group: %s: %zu stars in %zu groups (critical separation "
            "psfrad + fitrad = %g px, maxgroup %d)\n",
            input, t->nrow, ngroups, o->psfrad + o->fitrad, o->maxgroup);
    fprintf(stderr, "  size of group   number of groups   stars\n");
    for (size_t s = 1; s <= big; s++)
        if (h[s])
            fprintf(stderr, "  %13zu   %16zu   %5zu\n", s, h[s] / s, h[s]);
    if (nsplit)
        fprintf(stderr, "  %zu stars are in parts of groups larger than maxgroup (FLAGS 2)\n",
                nsplit);
    free(h);
    return 0;
}

int mp_task_group(int argc, char **argv)
{
    mp_parset ps;
    int b = mp_task_begin("group", argc, argv, &ps);
    if (b)
        return b;
    char err[MP_ERRLEN] = "";
    mp_group_opts o;
    mp_table_format fmt;
    int verbose = 0, rc = 1;
    mp_table t;
    mp_table_init(&t);
    const char *input = mp_par_string(&ps, "input"), *output = mp_par_string(&ps, "output");
    if (read_opts(&ps, &o, &fmt, &verbose, err))
        goto done;
    if (!input || !input[0]) {
        snprintf(err, MP_ERRLEN, "input: no input table named");
        goto done;
    }
    if (mp_outputs_clear(&input, 1, &output, 1, err) || mp_table_read(input, &t, err))
        goto done;
    char e[MP_ERRLEN];
    if (mp_group_table(&t, &o, e)) {
        snprintf(err, MP_ERRLEN, "%.200s: %.300s", strcmp(input, "-") ? input : "stdin", e);
        goto done;
    }
    if (verbose && histogram(&t, &o, strcmp(input, "-") ? input : "stdin", err))
        goto done;
    mp_tmp_sweep(NULL, output);      /* killed runs' temporaries */
    if (mp_table_write(output && output[0] ? output : "-", &t, fmt, err))
        goto done;
    rc = 0;
done:
    if (rc)
        fprintf(stderr, "matphot group: %s\n", err);
    mp_table_free(&t);
    mp_params_free(&ps);
    return rc;
}
