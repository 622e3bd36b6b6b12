/* frame_memory.c — what each star was fitted against, kept across calls
 * by NUMBER (mp_fit_memory: the pipeline's rounds). */

#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include "fit/frame_priv.h"

void mp_fit_memory_scratch(mp_fit_memory *mem, float *buf, size_t n)
{
    mem->scratch = buf;
    mem->nscratch = buf ? n : 0;
}

mp_fit_memory *mp_fit_memory_new(void)
{
    return calloc(1, sizeof(mp_fit_memory));
}

void mp_fit_memory_free(mp_fit_memory *mem)
{
    if (!mem)
        return;
    for (size_t i = 0; i < mem->ns; i++)
        free(mem->s[i].seen);
    free(mem->s);
    free(mem);
}

/* Numbers of the rows (NUMBER) when every row has a distinct-looking
 * whole one the memory can index, else −1 (no memory across calls). */
double ff_max_number(const mp_table *t)
{
    int cn = mp_table_col(t, "NUMBER");
    if (cn < 0)
        return -1.0;
    double mx = 0.0;
    for (size_t r = 0; r < t->nrow; r++) {
        double v = mp_table_get(t, r, cn);
        if (!(v >= 0 && v < 1e8 && v == floor(v)))
            return -1.0;
        mx = v > mx ? v : mx;
    }
    return mx;
}

/* Give back to the stars of the table their last fits from mem (the
 * pipeline's earlier rounds): a star whose row still holds that fit's
 * values gets its errors and its patch back, so it need not be refitted
 * when its surroundings have not changed. */
void ff_recall(mp_fit_memory *mem, star_state *st, size_t n)
{
    for (size_t i = 0; i < n; i++) {
        size_t k = (size_t)st[i].number;
        if (k >= mem->ns || !mem->s[k].seen)
            continue;
        star_seen *r = &mem->s[k];
        if (r->s.x != st[i].s.x || r->s.y != st[i].s.y || r->s.flux != st[i].s.flux)
            continue;
        st[i].s = r->s;
        st[i].seen = r->seen;
        st[i].cx = r->cx;
        st[i].cy = r->cy;
        st[i].sx0 = r->sx0;
        st[i].sy0 = r->sy0;
        st[i].sw = r->sw;
        r->seen = NULL;
    }
}

/* Keep every live star's fit and patch in mem, by NUMBER. */
int ff_remember(mp_fit_memory *mem, star_state *st, size_t n, double maxnum)
{
    size_t ns = (size_t)maxnum + 1;
    if (ns > mem->ns) {
        star_seen *s = realloc(mem->s, ns * sizeof *s);
        if (!s)
            return 1;
        memset(s + mem->ns, 0, (ns - mem->ns) * sizeof *s);
        mem->s = s;
        mem->ns = ns;
    }
    for (size_t i = 0; i < n; i++) {
        star_seen *r = &mem->s[(size_t)st[i].number];
        free(r->seen);
        r->seen = NULL;
        if (!st[i].alive)
            continue;
        r->s = st[i].s;
        r->seen = st[i].seen;
        r->cx = st[i].cx;
        r->cy = st[i].cy;
        r->sx0 = st[i].sx0;
        r->sy0 = st[i].sy0;
        r->sw = st[i].sw;
        st[i].seen = NULL;
    }
    return 0;
}
