/* merge.c — many catalogs matched on the sky into one survey catalog
 * (catalog.h, "Survey merge": the match rule, the means, the tables). */
#include <math.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "catalog/merge_priv.h"

/* ---- the hash of sky cells ---------------------------------------------- */

static double cell_size(const mp_merge *m)
{
    return 2.0 * m->o.maxrad * MP_ARCSEC;
}

static size_t hash_cell(const mp_merge *m, int64_t ix, int64_t iy, int64_t iz)
{
    uint64_t h = (uint64_t)ix * 0x9E3779B97F4A7C15u ^ (uint64_t)iy * 0xC2B2AE3D27D4EB4Fu ^
                 (uint64_t)iz * 0x165667B19E3779F9u;
    return (size_t)((h ^ (h >> 29)) & (m->nbucket - 1));
}

static void cell_of(const mp_merge *m, const double u[3], int64_t c[3])
{
    for (int k = 0; k < 3; k++)
        c[k] = (int64_t)floor(u[k] / cell_size(m));
}

/* A source is filed under the cell of its first detection; it stays
 * within maxrad of it (each detection it takes is), so the cells around a
 * query's own, one cell of 2 maxrad each way, hold every candidate. */
static void file_source(mp_merge *m, long i)
{
    int64_t c[3];
    cell_of(m, m->s[i].ref, c);
    size_t h = hash_cell(m, c[0], c[1], c[2]);
    m->s[i].next = m->bucket[h];
    m->bucket[h] = i;
}

static int rehash(mp_merge *m)
{
    size_t nb = m->nbucket ? m->nbucket : 1024;
    while (nb < 2 * m->caps)
        nb *= 2;
    if (nb == m->nbucket)
        return 0;
    long *b = malloc(nb * sizeof *b);
    if (!b)
        return 1;
    free(m->bucket);
    m->bucket = b;
    m->nbucket = nb;
    for (size_t i = 0; i < nb; i++)
        b[i] = -1;
    for (size_t i = 0; i < m->ns; i++)
        file_source(m, (long)i);
    return 0;
}

/* ---- sources -------------------------------------------------------------- */

static long new_source(mp_merge *m, const mg_det *d)
{
    if (m->ns == m->caps) {
        size_t cap = m->caps ? 2 * m->caps : 1024;
        mg_src *s = realloc(m->s, cap * sizeof *s);
        if (!s)
            return -1;
        m->s = s;
        m->caps = cap;
        if (rehash(m))
            return -1;
    }
    mg_src *s = &m->s[m->ns];
    memset(s, 0, sizeof *s);
    memcpy(s->ref, d->u, sizeof s->ref);
    memcpy(s->m, d->u, sizeof s->m);
    file_source(m, (long)m->ns);
    return (long)m->ns++;
}

/* The detection's weight added to its source's sums, and the mean moved. */
static void accumulate(mg_src *s, const mg_det *d)
{
    double xi, eta;
    if (mg_tangent(s->ref, d->u, &xi, &eta))
        xi = eta = 0;               /* cannot happen within maxrad */
    double we = 1.0 / (d->se * d->se), wn = 1.0 / (d->sn * d->sn);
    s->swe += we;
    s->swn += wn;
    s->swxi += we * xi;
    s->sweta += wn * eta;
    mg_untangent(s->ref, s->swxi / s->swe, s->sweta / s->swn, s->m);
    if (isfinite(d->mag) && d->magerr > 0 && isfinite(d->magerr)) {
        double w = 1.0 / (d->magerr * d->magerr);
        s->wmag += w;
        s->swm += w * d->mag;
        s->swmm += w * d->mag * d->mag;
        s->nmag++;
    }
    s->ndet++;
    s->flags = (double)((long)s->flags | (long)d->flags);
}

/* ---- one frame -------------------------------------------------------------- */

typedef struct { double q; size_t det; long src; } pair;

static int pair_order(const void *a, const void *b)
{
    const pair *p = a, *r = b;
    if (p->q != r->q)
        return p->q < r->q ? -1 : 1;
    if (p->det != r->det)
        return p->det < r->det ? -1 : 1;
    return (p->src > r->src) - (p->src < r->src);
}

/* The normalised separation² of d from s's mean; +inf beyond maxrad. */
static double separation2(const mp_merge *m, const mg_src *s, const mg_det *d)
{
    double de, dn;
    if (mg_tangent(s->m, d->u, &de, &dn) || hypot(de, dn) > m->o.maxrad)
        return INFINITY;
    return de * de / (d->se * d->se + 1.0 / s->swe) + dn * dn / (d->sn * d->sn + 1.0 / s->swn);
}

/* Every (detection, source) pair of this frame within the match rule. */
static int candidates(const mp_merge *m, size_t first, pair **pp, size_t *np)
{
    size_t n = 0, cap = 0;
    pair *p = NULL;
    double lim = m->o.nsigma * m->o.nsigma;
    for (size_t i = first; i < m->nd; i++) {
        int64_t c[3];
        cell_of(m, m->d[i].u, c);
        for (int dx = -1; dx <= 1; dx++)
            for (int dy = -1; dy <= 1; dy++)
                for (int dz = -1; dz <= 1; dz++)
                    for (long j = m->bucket[hash_cell(m, c[0] + dx, c[1] + dy, c[2] + dz)];
                         j >= 0; j = m->s[j].next) {
                        double q = separation2(m, &m->s[j], &m->d[i]);
                        if (!(q <= lim))
                            continue;
                        if (n == cap) {
                            cap = cap ? 2 * cap : 256;
                            pair *np2 = realloc(p, cap * sizeof *p);
                            if (!np2) {
                                free(p);
                                return 1;
                            }
                            p = np2;
                        }
                        p[n++] = (pair){q, i, j};
                    }
    }
    *pp = p;
    *np = n;
    return 0;
}

/* Pairs taken best first: a detection and a source each once per frame.
 * (Hash buckets shared by neighbouring cells can list a pair twice; the
 * second is then refused like any taken pair.) */
static int assign(mp_merge *m, size_t first, int frame)
{
    pair *p;
    size_t np;
    if (candidates(m, first, &p, &np))
        return 1;
    if (np)
        qsort(p, np, sizeof *p, pair_order);
    for (size_t k = 0; k < np; k++) {
        mg_det *d = &m->d[p[k].det];
        mg_src *s = &m->s[p[k].src];
        if (d->src >= 0 || s->last_frame == frame)
            continue;
        d->src = p[k].src;
        s->last_frame = frame;
    }
    free(p);
    for (size_t i = first; i < m->nd; i++)
        if (m->d[i].src < 0) {
            long j = new_source(m, &m->d[i]);
            if (j < 0)
                return 1;
            m->d[i].src = j;
            m->s[j].last_frame = frame;
        }
    for (size_t i = first; i < m->nd; i++)
        accumulate(&m->s[m->d[i].src], &m->d[i]);
    return 0;
}

mp_merge *mp_merge_new(const mp_merge_opts *o)
{
    mp_merge *m = calloc(1, sizeof *m);
    if (!m)
        return NULL;
    m->o = *o;
    m->zp = -1;
    if (rehash(m)) {
        free(m);
        return NULL;
    }
    return m;
}

void mp_merge_free(mp_merge *m)
{
    if (!m)
        return;
    free(m->d);
    free(m->s);
    free(m->bucket);
    free(m);
}

static int append_dets(mp_merge *m, const mg_det *d, size_t n)
{
    if (m->nd + n > m->capd) {
        size_t cap = m->capd ? m->capd : 1024;
        while (cap < m->nd + n)
            cap *= 2;
        mg_det *nd = realloc(m->d, cap * sizeof *nd);
        if (!nd)
            return 1;
        m->d = nd;
        m->capd = cap;
    }
    memcpy(m->d + m->nd, d, n * sizeof *d);
    m->nd += n;
    return 0;
}

/* Magnitudes on one system: every catalog calibrated (a MAGZERO column:
 * its frame's zero point, each MAG_PSF on it) or none (instrumental, all
 * on the fit's magzero); a mix would average magnitudes of different
 * systems, so it is refused, naming a catalog of each kind. */
static int same_system(mp_merge *m, const mp_table *cat, const char *name, char *err)
{
    int c = mp_table_col(cat, "MAGZERO");
    double zp = NAN;
    for (size_t r = 0; c >= 0 && r < cat->nrow && !isfinite(zp); r++)
        zp = mp_table_get(cat, r, c);
    int kind = c >= 0;
    if (m->zp < 0) {
        m->zp = kind;
        m->zpval = zp;
        snprintf(m->zpname, sizeof m->zpname, "%s", name);
        return 0;
    }
    if (kind == m->zp)
        return 0;
    const char *cal = kind ? name : m->zpname, *ins = kind ? m->zpname : name;
    int lc = (int)strnlen(cal, 180), li = (int)strnlen(ins, 180);
    snprintf(err, MP_ERRLEN, "%.*s: magnitudes on a calibrated zero point (MAGZERO %g) but %.*s's "
             "are instrumental (no MAGZERO column): calibrate every catalog with `matphot "
             "catalog magzero=` (or none)", lc, cal, kind ? zp : m->zpval, li, ins);
    return 1;
}

int mp_merge_add(mp_merge *m, const mp_table *cat, const char *name, long *skipped, char *err)
{
    mg_det *d;
    size_t n;
    int frame = m->nframes + 1;
    if (same_system(m, cat, name, err))
        return 1;
    if (mg_frame_dets(cat, name, frame, m->o.syserr, m->o.pixscale, &d, &n, err))
        return 1;
    if (skipped)
        *skipped = (long)(cat->nrow - n);
    size_t first = m->nd;
    int rc = append_dets(m, d, n) || assign(m, first, frame);
    free(d);
    if (rc) {
        snprintf(err, MP_ERRLEN, "%s: out of memory", name);
        return 1;
    }
    m->nframes = frame;
    return 0;
}
