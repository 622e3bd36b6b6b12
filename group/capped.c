/* capped.c — mp_group_capped, mp_group_budget (group.h): components
 * built from the strongest links first, none grown past maxgroup
 * (Kruskal's maximum spanning forest with a cap on each tree's size),
 * and optionally only the links a budget of Σw² per star needs. */
#include <stdlib.h>

#include "group/group.h"
#include "group/group_priv.h"

static int by_weight(const void *p, const void *q)
{
    const mp_group_pair *a = p, *b = q;
    if (a->w != b->w)
        return a->w < b->w ? 1 : -1;     /* strongest first */
    if (a->a != b->a)
        return a->a < b->a ? -1 : 1;     /* ties in row order: deterministic */
    return (a->b > b->b) - (a->b < b->b);
}

/* Strongest first, capped (a link below cutw at weakcap); with budget ≥ 0
 * a link joins only while one of its stars has more than budget of Σw²
 * outside (mp_group_budget). */
static int forest(size_t n, mp_group_pair *p, size_t np, int maxgroup, int weakcap,
                  double budget, size_t *label, unsigned char *cut, double cutw)
{
    mp_uf u;
    size_t *size = calloc(n + 1, sizeof *size);
    double *out = budget >= 0 ? calloc(n + 1, sizeof *out) : NULL;
    if (!size || (budget >= 0 && !out) || mp_uf_init(&u, n ? n : 1)) {
        free(size);
        free(out);
        return 1;
    }
    for (size_t i = 0; i < n; i++)
        size[i] = 1;
    for (size_t k = 0; k < np && out; k++) {
        out[p[k].a] += p[k].w * p[k].w;
        out[p[k].b] += p[k].w * p[k].w;
    }
    if (np > 1)
        qsort(p, np, sizeof *p, by_weight);
    for (size_t k = 0; k < np; k++) {
        size_t ra = mp_uf_find(&u, p[k].a), rb = mp_uf_find(&u, p[k].b);
        double w2 = p[k].w * p[k].w;
        int need = !out || out[p[k].a] > budget || out[p[k].b] > budget;
        if (ra != rb && !need)
            continue;               /* both within budget: left apart */
        int cap = p[k].w >= cutw ? maxgroup : weakcap;
        if (ra != rb && size[ra] + size[rb] > (size_t)cap) {
            if (cut && p[k].w >= cutw)
                cut[p[k].a] = cut[p[k].b] = 1;
            continue;
        }
        if (out) {                  /* inside a set now (or already) */
            out[p[k].a] -= w2;
            out[p[k].b] -= w2;
        }
        if (ra == rb)
            continue;
        size_t s = size[ra] + size[rb];
        mp_uf_union(&u, ra, rb);
        size[mp_uf_find(&u, ra)] = s;
    }
    for (size_t i = 0; i < n; i++)
        label[i] = mp_uf_find(&u, i);
    mp_uf_free(&u);
    free(size);
    free(out);
    return 0;
}

int mp_group_capped(size_t n, mp_group_pair *p, size_t np, int maxgroup, int weakcap,
                    size_t *label, unsigned char *cut, double cutw)
{
    weakcap = weakcap >= 1 && weakcap < maxgroup ? weakcap : maxgroup;
    return forest(n, p, np, maxgroup, weakcap, -1.0, label, cut, cutw);
}

int mp_group_budget(size_t n, mp_group_pair *p, size_t np, int maxgroup, double budget,
                    size_t *label, unsigned char *cut, double cutw)
{
    return forest(n, p, np, maxgroup, maxgroup, budget < 0 ? 0.0 : budget, label, cut, cutw);
}
