/* frame_memory.c — each star's last fit and refit bound, kept across
 * calls by NUMBER (mp_fit_memory: the pipeline's rounds). */

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
    free(mem->s);
    free(mem->at);
    free(mem);
}

void mp_fit_memory_forget(mp_fit_memory *mem)
{
    if (!mem)
        return;
    memset(&mem->paint, 0, sizeof mem->paint);
    mem->forgot = 1;
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

/* The index grown to NUMBERs 0..maxnum; nonzero when out of memory. */
static int grow_index(mp_fit_memory *mem, double maxnum)
{
    size_t nat = (size_t)maxnum + 1;
    if (nat <= mem->nat)
        return 0;
    uint32_t *at = realloc(mem->at, nat * sizeof *at);
    if (!at)
        return 1;
    memset(at + mem->nat, 0, (nat - mem->nat) * sizeof *at);
    mem->at = at;
    mem->nat = nat;
    return 0;
}

/* The fit's columns of a table (ff_write_columns), in mp_star's order
 * below; nonzero when one is missing. */
enum { NFIT = 18 };
static int fit_columns(const mp_table *t, int *c)
{
    static const char *const names[NFIT] = {
        "XPSF_IMAGE", "YPSF_IMAGE", "FLUX_PSF", "ERRX_PSF", "ERRY_PSF", "FLUXERR_PSF",
        "SKY_PSF", "SKYERR_PSF", "CHI2_PSF", "DOF_PSF", "NITER_PSF", "CHI2STAR_PSF",
        "BETA_PSF", "SHARP_PRF", "LSCALE_PRF", "VOLUME_PRF", "FLUXERR_MODEL", "POSERR_MODEL"};
    for (int k = 0; k < NFIT; k++)
        if ((c[k] = mp_table_col(t, names[k])) < 0)
            return 1;
    return 0;
}

/* Star s as its row r of t and its entry e hold it. */
static void star_from(const mp_table *t, size_t r, const int *c, const star_memo *e, mp_star *s)
{
    double v[NFIT];
    for (int k = 0; k < NFIT; k++)
        v[k] = mp_table_get(t, r, c[k]);
    s->x = v[0], s->y = v[1], s->flux = v[2];
    s->ex = v[3], s->ey = v[4], s->eflux = v[5];
    s->sky = v[6], s->esky = v[7], s->chi2 = v[8];
    s->dof = (int)v[9], s->niter = (int)v[10], s->chi2star = v[11];
    s->st.beta = v[12], s->st.sharp = v[13], s->st.lscale = v[14], s->st.volume = v[15];
    s->fluxerr_model = v[16], s->poserr_model = v[17];
    s->flags = e->flags, s->dofstar = e->dofstar, s->sky_order = e->sky_order;
}

/* A star's light as its entry e painted it, pending as a change
 * (MOVED_CALL) from there. */
static void pending_from(const star_memo *e, star_state *s)
{
    s->moved = MOVED_CALL;
    s->olight = 1;
    s->ox = e->x, s->oy = e->y, s->oflux = e->flux, s->osky = e->sky;
}

/* Give back to the stars of the table their last fits from mem (the
 * pipeline's earlier rounds): a star whose row still holds that fit's
 * values gets its errors and its bound back, so it need not be refitted
 * when its surroundings have not changed.  Every other star's light is a
 * change since the bounds were made: from its entry's (a row changed
 * since), from none (a star new to mem), or to none (an entry whose star
 * is not in t: in *gone). */
int ff_recall(mp_fit_memory *mem, const mp_table *t, star_state *st, size_t n,
              paint_rule *held, star_state **gone, size_t *ngone)
{
    int c[NFIT];
    int cols = !fit_columns(t, c);
    *held = mem->paint;
    *gone = NULL;
    *ngone = 0;
    for (size_t i = 0; i < n; i++) {
        size_t k = (size_t)st[i].number;
        star_memo *r = k < mem->nat && mem->at[k] ? &mem->s[mem->at[k] - 1] : NULL;
        st[i].bound = INFINITY;
        st[i].moved = MOVED_CALL;     /* new to mem: from no light */
        st[i].olight = 0;
        if (!r)
            continue;
        mem->at[k] = 0;
        r->number = UINT32_MAX;       /* taken */
        if (mem->forgot) {      /* as new, its sky order its start (none
                                 * where first_order would not take it) */
            st[i].s.sky_order = ff_warm_order(r->flags, r->sky_order);
            continue;
        }
        if (cols && r->x == st[i].s.x && r->y == st[i].s.y && r->flux == st[i].s.flux &&
            ff_same_value(r->sky, st[i].s.sky)) {
            star_from(t, (size_t)st[i].row, c, r, &st[i].s);
            st[i].bound = r->bound;
            st[i].moved = 0;
        } else {
            pending_from(r, &st[i]);
        }
    }
    for (size_t e = 0; e < mem->ns && !mem->forgot; e++)
        *ngone += mem->s[e].number != UINT32_MAX;
    if (*ngone && !(*gone = calloc(*ngone, sizeof **gone)))
        return 1;
    for (size_t e = 0, q = 0; e < mem->ns; e++)
        if (mem->s[e].number != UINT32_MAX) {
            if (!mem->forgot)
                pending_from(&mem->s[e], &(*gone)[q++]);
            mem->at[mem->s[e].number] = 0;
        }
    mem->forgot = 0;
    free(mem->s);                /* not held through the fit (issue 14) */
    mem->s = NULL;
    mem->ns = 0;
    return 0;
}

/* Keep every live star's fit and bound in mem, by NUMBER, in place of
 * what it held: the stars of the table as the call ends. */
int ff_remember(mp_fit_memory *mem, const star_state *st, size_t n, double maxnum,
                const paint_rule *held)
{
    for (size_t e = 0; e < mem->ns; e++)
        if (mem->s[e].number < mem->nat)
            mem->at[mem->s[e].number] = 0;
    mem->ns = 0;
    if (grow_index(mem, maxnum))
        return 1;
    size_t live = 0;
    for (size_t i = 0; i < n; i++)
        live += st[i].alive;
    star_memo *s = live ? realloc(mem->s, live * sizeof *s) : NULL;
    if (live && !s)
        return 1;
    if (!live)
        free(mem->s);
    mem->s = s;
    mem->paint = *held;
    mem->forgot = 0;             /* the fits of this call: remembered whole */
    for (size_t i = 0; i < n; i++) {
        if (!st[i].alive)
            continue;
        star_memo *r = &mem->s[mem->ns];
        r->x = st[i].s.x;
        r->y = st[i].s.y;
        r->flux = st[i].s.flux;
        r->sky = st[i].s.sky;
        r->bound = st[i].bound;
        r->flags = st[i].s.flags;
        r->dofstar = st[i].s.dofstar;
        r->sky_order = st[i].s.sky_order;
        r->number = (uint32_t)st[i].number;
        mem->at[r->number] = (uint32_t)(++mem->ns);
    }
    return 0;
}
