/* union_find.c — disjoint sets with path compression and union by rank. */
#include <stdlib.h>

#include "group/group_priv.h"

int mp_uf_init(mp_uf *u, size_t n)
{
    u->n = n;
    u->parent = malloc((n ? n : 1) * sizeof *u->parent);
    u->rank = calloc(n ? n : 1, sizeof *u->rank);
    if (!u->parent || !u->rank) {
        mp_uf_free(u);
        return 1;
    }
    for (size_t i = 0; i < n; i++)
        u->parent[i] = i;
    return 0;
}

void mp_uf_free(mp_uf *u)
{
    free(u->parent);
    free(u->rank);
    u->parent = NULL;
    u->rank = NULL;
    u->n = 0;
}

size_t mp_uf_find(mp_uf *u, size_t i)
{
    size_t r = i;
    while (u->parent[r] != r)
        r = u->parent[r];
    while (u->parent[i] != r) {          /* second pass: point all at r */
        size_t next = u->parent[i];
        u->parent[i] = r;
        i = next;
    }
    return r;
}

int mp_uf_union(mp_uf *u, size_t a, size_t b)
{
    a = mp_uf_find(u, a);
    b = mp_uf_find(u, b);
    if (a == b)
        return 0;
    if (u->rank[a] < u->rank[b]) {
        size_t t = a;
        a = b;
        b = t;
    }
    u->parent[b] = a;
    if (u->rank[a] == u->rank[b])
        u->rank[a]++;
    return 1;
}
