/* merge_tables.c — the survey merge's two tables: one row per source and
 * one per detection (catalog.h, "Survey merge"). */
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "catalog/merge_priv.h"

static const char *const src_cols[] = {
    "SOURCE_ID", "ALPHA_J2000", "DELTA_J2000", "ERRRA_ARCSEC", "ERRDEC_ARCSEC",
    "MAG_MEAN", "MAGERR_MEAN", "MAG_CHI2", "NDET", "FLAGS"};
static const char *const det_cols[] = {
    "SOURCE_ID", "FRAME", "NUMBER", "XPSF_IMAGE", "YPSF_IMAGE", "ALPHAPSF_J2000",
    "DELTAPSF_J2000", "ERRRA_ARCSEC", "ERRDEC_ARCSEC", "MAG_PSF", "MAGERR_PSF",
    "FLUX_PSF", "FLUXERR_PSF", "FLAGS", "SEP_ARCSEC"};
#define NSRC (sizeof src_cols / sizeof src_cols[0])
#define NDETC (sizeof det_cols / sizeof det_cols[0])

static int add_cols(mp_table *t, const char *const *names, size_t n)
{
    for (size_t i = 0; i < n; i++)
        if (mp_table_add_col(t, names[i]) != (int)i)
            return 1;
    return 0;
}

static int add_row(mp_table *t, const double *v)
{
    long r = mp_table_add_row(t);
    if (r < 0)
        return 1;
    memcpy(t->v + (size_t)r * t->ncol, v, t->ncol * sizeof *v);
    return 0;
}

static int source_rows(const mp_merge *m, mp_table *t)
{
    for (size_t i = 0; i < m->ns; i++) {
        const mg_src *s = &m->s[i];
        double ra, dec, mean = NAN, err = NAN, chi2 = NAN;
        mg_radec(s->m, &ra, &dec);
        if (s->nmag > 0) {
            mean = s->swm / s->wmag;
            err = 1.0 / sqrt(s->wmag);
        }
        if (s->nmag > 1)
            chi2 = fmax(0.0, s->swmm - s->swm * mean) / (double)(s->nmag - 1);
        double v[NSRC] = {(double)(i + 1), ra, dec, 1.0 / sqrt(s->swe), 1.0 / sqrt(s->swn),
                          mean, err, chi2, (double)s->ndet, s->flags};
        if (add_row(t, v))
            return 1;
    }
    return 0;
}

/* Detections by source, then frame: a counting sort by source keeps the
 * frames' order within each. */
static int detection_rows(const mp_merge *m, mp_table *t)
{
    size_t *start = calloc(m->ns + 1, sizeof *start), *order = malloc((m->nd + 1) * sizeof *order);
    if (!start || !order) {
        free(start);
        free(order);
        return 1;
    }
    for (size_t i = 0; i < m->nd; i++)
        start[m->d[i].src + 1]++;
    for (size_t j = 0; j < m->ns; j++)
        start[j + 1] += start[j];
    for (size_t i = 0; i < m->nd; i++)
        order[start[m->d[i].src]++] = i;
    int rc = 0;
    for (size_t k = 0; k < m->nd && !rc; k++) {
        const mg_det *d = &m->d[order[k]];
        double de, dn, sep = NAN;
        if (!mg_tangent(m->s[d->src].m, d->u, &de, &dn))
            sep = hypot(de, dn);
        double v[NDETC] = {(double)(d->src + 1), d->frame, d->number, d->x, d->y, d->ra, d->dec,
                           d->se, d->sn, d->mag, d->magerr, d->flux, d->fluxerr, d->flags, sep};
        rc = add_row(t, v);
    }
    free(start);
    free(order);
    return rc;
}

int mp_merge_tables(const mp_merge *m, mp_table *sources, mp_table *dets, char *err)
{
    mp_table_init(sources);
    mp_table_init(dets);
    if (add_cols(sources, src_cols, NSRC) || add_cols(dets, det_cols, NDETC) ||
        source_rows(m, sources) || detection_rows(m, dets)) {
        mp_table_free(sources);
        mp_table_free(dets);
        snprintf(err, MP_ERRLEN, "out of memory for the merged tables");
        return 1;
    }
    return 0;
}
