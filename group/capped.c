/* capped.c — mp_group_capped (group.h): components built from the
 * strongest links first, none grown past maxgroup (Kruskal's maximum
 * spanning forest with a cap on each tree's size). */
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

int mp_group_capped(size_t n, mp_group_pair *p, size_t np, int maxgroup, size_t *label,
                    unsigned char *cut, double cutw)
{
    mp_uf u;
    size_t *size = calloc(n + 1, sizeof *size);
    if (!size || mp_uf_init(&u, n ? n : 1)) {
        free(size);
        return 1;
    }
    for (size_t i = 0; i < n; i++)
        size[i] = 1;
    if (np > 1)
        qsort(p, np, sizeof *p, by_weight);
    for (size_t k = 0; k < np; k++) {
        size_t ra = mp_uf_find(&u, p[k].a), rb = mp_uf_find(&u, p[k].b);
        if (ra == rb)
            continue;
        if (size[ra] + size[rb] > (size_t)maxgroup) {
            if (cut && p[k].w >= cutw)
                cut[p[k].a] = cut[p[k].b] = 1;
            continue;
        }
        size_t s = size[ra] + size[rb];
        mp_uf_union(&u, ra, rb);
        size[mp_uf_find(&u, ra)] = s;
    }
    for (size_t i = 0; i < n; i++)
        label[i] = mp_uf_find(&u, i);
    mp_uf_free(&u);
    free(size);
    return 0;
}
