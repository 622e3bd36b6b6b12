/*
 * regions.c — DS9 region files (format version 4.1) of a table's stars, to
 * overlay a catalogue on its frame (catalog.h).
 *
 * DS9's "image" system is 1-based with (1, 1) the centre of the first
 * pixel, as matphot's pixel coordinates, so positions are written as they
 * are.  In "fk5" a bare radius would be degrees, so it carries DS9's
 * arcsecond mark (").
 */
#include <errno.h>
#include <math.h>
#include <stdio.h>
#include <string.h>

#include "catalog/table_priv.h"

/* The first pair of columns the table has, or -1s. */
static void find_pair(const mp_table *t, const char *const pairs[][2], int npairs,
                      int *cx, int *cy)
{
    *cx = *cy = -1;
    for (int i = 0; i < npairs; i++) {
        int x = mp_table_col(t, pairs[i][0]), y = mp_table_col(t, pairs[i][1]);
        if (x >= 0 && y >= 0) {
            *cx = x;
            *cy = y;
            return;
        }
    }
}

/* What a region row is drawn from. */
typedef struct {
    const mp_table *t;
    int cx, cy, cflags, cnum, fk5;
    double radius;
} region_rows;

/* Rows [r0, r1) as DS9 circles appended to b (mp_rows_format): those with
 * a finite position, green when FLAGS is 0, red else (a missing, NaN,
 * FLAGS is not "clean"); nonzero when out of memory. */
static int format_regions(const void *ctx, size_t r0, size_t r1, mp_text *b)
{
    const region_rows *g = ctx;
    char line[2048];      /* three %.8f-wide values of up to 1e308: ~1000 */
    for (size_t r = r0; r < r1; r++) {
        double x = mp_table_get(g->t, r, g->cx), y = mp_table_get(g->t, r, g->cy);
        if (!isfinite(x) || !isfinite(y))
            continue;
        double f = g->cflags >= 0 ? mp_table_get(g->t, r, g->cflags) : 0.0;
        double num = g->cnum >= 0 ? mp_table_get(g->t, r, g->cnum) : NAN;
        int n = g->fk5 ? snprintf(line, sizeof line, "circle(%.8f,%+.8f,%.6g\")", x, y, g->radius)
                       : snprintf(line, sizeof line, "circle(%.5f,%.5f,%.6g)", x, y, g->radius);
        n += snprintf(line + n, sizeof line - (size_t)n, " # color=%s", f == 0.0 ? "green" : "red");
        if (isfinite(num))
            n += snprintf(line + n, sizeof line - (size_t)n, " text={%.0f}", num);
        n += snprintf(line + n, sizeof line - (size_t)n, "\n");
        if (mp_text_put(b, line, (size_t)n))
            return 1;
    }
    return 0;
}

int mp_regions_write(const char *path, const mp_table *t, const mp_region_opts *o,
                     long *nwritten, char *err)
{
    static const char *const pix[][2] = {{"XPSF_IMAGE", "YPSF_IMAGE"}, {"X_IMAGE", "Y_IMAGE"}};
    static const char *const sky[][2] = {{"ALPHAPSF_J2000", "DELTAPSF_J2000"},
                                         {"ALPHA_J2000", "DELTA_J2000"}};
    int is_stdout = !path || strcmp(path, "-") == 0;
    const char *name = is_stdout ? "stdout" : path;
    if (nwritten)
        *nwritten = 0;
    if (!(o->radius > 0) || !isfinite(o->radius)) {
        snprintf(err, MP_ERRLEN, "%s: region radius %g is not a positive number", name, o->radius);
        return 1;
    }
    int cx, cy;
    if (o->fk5)
        find_pair(t, sky, 2, &cx, &cy);
    else
        find_pair(t, pix, 2, &cx, &cy);
    if (cx < 0) {
        snprintf(err, MP_ERRLEN, "%s: the table has no %s columns for %s regions", name,
                 o->fk5 ? "ALPHAPSF_J2000/DELTAPSF_J2000 or ALPHA_J2000/DELTA_J2000"
                        : "XPSF_IMAGE/YPSF_IMAGE or X_IMAGE/Y_IMAGE",
                 o->fk5 ? "fk5" : "image");
        return 1;
    }
    int cflags = mp_table_col(t, "FLAGS");
    int cnum = o->label ? mp_table_col(t, "NUMBER") : -1;

    mp_outfile out;
    if (mp_out_open(&out, is_stdout ? "-" : path, err))
        return 1;
    FILE *fp = out.fp;
    fprintf(fp, "# Region file format: DS9 version 4.1\n");
    fprintf(fp, "global color=green dashlist=8 3 width=1 font=\"helvetica 10 normal roman\" "
                "select=1 highlite=1 dash=0 fixed=0 edit=1 move=1 delete=1 include=1 source=1\n");
    fprintf(fp, "%s\n", o->fk5 ? "fk5" : "image");
    long n = 0;
    for (size_t r = 0; r < t->nrow; r++)
        n += isfinite(mp_table_get(t, r, cx)) && isfinite(mp_table_get(t, r, cy));
    region_rows g = {t, cx, cy, cflags, cnum, o->fk5, o->radius};
    if (mp_rows_write(fp, t->nrow, format_regions, &g)) {
        snprintf(err, MP_ERRLEN, "%s: out of memory formatting the regions", name);
        mp_out_abort(&out);
        return 1;
    }
    if (ferror(fp)) {
        snprintf(err, MP_ERRLEN, "%s: write error: %s", name, errno ? strerror(errno) : "I/O error");
        mp_out_abort(&out);
        return 1;
    }
    if (mp_out_commit(&out, err))
        return 1;
    if (nwritten)
        *nwritten = n;
    return 0;
}
