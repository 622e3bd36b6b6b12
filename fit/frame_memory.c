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
    free(mem->at);
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

/* The entries that still hold a disc (stars not in this call's table)
 * moved to the front, in place, and indexed anew. */
static void compact(mp_fit_memory *mem)
{
    size_t j = 0;
    for (size_t i = 0; i < mem->ns; i++)
        if (mem->s[i].seen) {
            mem->s[j] = mem->s[i];
            mem->at[mem->s[j].number] = (uint32_t)(j + 1);
            j++;
        }
    mem->ns = j;
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
static void star_from(const mp_table *t, size_t r, const int *c, const star_seen *e, mp_star *s)
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

/* Give back to the stars of the table their last fits from mem (the
 * pipeline's earlier rounds): a star whose row still holds that fit's
 * values gets its errors and its patch back, so it need not be refitted
 * when its surroundings have not changed.  The entries of the table's
 * stars are then forgotten (ff_remember would replace them): the fit
 * holds the patches meanwhile, not the memory too. */
void ff_recall(mp_fit_memory *mem, const mp_table *t, star_state *st, size_t n)
{
    int c[NFIT];
    int cols = !fit_columns(t, c);
    for (size_t i = 0; i < n; i++) {
        size_t k = (size_t)st[i].number;
        if (k >= mem->nat || !mem->at[k])
            continue;
        star_seen *r = &mem->s[mem->at[k] - 1];
        mem->at[k] = 0;
        if (cols && r->seen && r->x == st[i].s.x && r->y == st[i].s.y &&
            r->flux == st[i].s.flux) {
            star_from(t, (size_t)st[i].row, c, r, &st[i].s);
            st[i].seen = r->seen;
            st[i].cx = r->cx;
            st[i].cy = r->cy;
            st[i].sx0 = r->sx0;
            st[i].sy0 = r->sy0;
            st[i].sw = r->sw;
        } else {
            free(r->seen);
        }
        r->seen = NULL;
    }
    compact(mem);
}

/* Keep every live star's fit and patch in mem, by NUMBER: each star of
 * this call forgets its earlier entry, the others' stay, the live ones
 * are appended. */
int ff_remember(mp_fit_memory *mem, star_state *st, size_t n, double maxnum)
{
    if (grow_index(mem, maxnum))
        return 1;
    size_t live = 0;
    for (size_t i = 0; i < n; i++) {
        size_t k = (size_t)st[i].number;
        if (mem->at[k]) {
            star_seen *r = &mem->s[mem->at[k] - 1];
            free(r->seen);
            r->seen = NULL;
            mem->at[k] = 0;
        }
        live += st[i].alive && st[i].seen;
    }
    compact(mem);
    size_t ns = mem->ns + live;
    star_seen *s = ns ? realloc(mem->s, ns * sizeof *s) : NULL;
    if (ns && !s)
        return 1;
    if (!ns)
        free(mem->s);
    mem->s = s;
    for (size_t i = 0; i < n; i++) {
        if (!st[i].alive || !st[i].seen)
            continue;
        star_seen *r = &mem->s[mem->ns];
        r->x = st[i].s.x;
        r->y = st[i].s.y;
        r->flux = st[i].s.flux;
        r->flags = st[i].s.flags;
        r->dofstar = st[i].s.dofstar;
        r->sky_order = st[i].s.sky_order;
        r->seen = st[i].seen;
        r->cx = st[i].cx;
        r->cy = st[i].cy;
        r->sx0 = st[i].sx0;
        r->sy0 = st[i].sy0;
        r->sw = st[i].sw;
        r->number = (uint32_t)st[i].number;
        mem->at[r->number] = (uint32_t)(++mem->ns);
        st[i].seen = NULL;
    }
    return 0;
}
