/* split.c — splitting a group larger than maxgroup (the rule of group.h).
 *
 * The group is cut in two at the median of its longer bounding-box axis:
 * the first m/2 stars in the order (coordinate, row) form one part, the rest
 * the other; parts still larger than maxgroup are cut again.  Ordering by
 * row within equal coordinates makes the cut well defined even for stars at
 * one point, so the rule always ends, and the parts do not depend on how the
 * selection is done.  Quickselect with pseudo-random pivots (a local
 * generator with a fixed seed: same input, same work) costs O(m) per level,
 * O(m log(m / maxgroup)) in all.
 */
#include <stdint.h>

#include "group/group_priv.h"

/* Total order of rows by key v, ties by row. */
static int before(const double *v, size_t a, size_t b)
{
    return v[a] < v[b] || (v[a] == v[b] && a < b);
}

static uint64_t next_rand(uint64_t *s)      /* xorshift64* */
{
    *s ^= *s >> 12;
    *s ^= *s << 25;
    *s ^= *s >> 27;
    return *s * 0x2545F4914F6CDD1Du;
}

static void swap(size_t *a, size_t *b)
{
    size_t t = *a;
    *a = *b;
    *b = t;
}

/* Reorder mem[0..m) so that its first k rows are the k first by `before`. */
static void select_first(size_t *mem, size_t m, size_t k, const double *v, uint64_t *rng)
{
    size_t lo = 0, hi = m;
    while (hi - lo > 1) {
        swap(&mem[lo + (size_t)(next_rand(rng) % (hi - lo))], &mem[hi - 1]);
        size_t pivot = mem[hi - 1], store = lo;
        for (size_t i = lo; i < hi - 1; i++)
            if (before(v, mem[i], pivot))
                swap(&mem[i], &mem[store++]);
        swap(&mem[store], &mem[hi - 1]);
        if (store == k)
            return;
        if (k < store)
            hi = store;
        else
            lo = store + 1;
    }
}

static void split(size_t *mem, size_t m, const double *x, const double *y, size_t maxgroup,
                  size_t *rep, uint64_t *rng)
{
    if (m <= maxgroup) {
        size_t first = mem[0];
        for (size_t i = 1; i < m; i++)
            first = mem[i] < first ? mem[i] : first;
        for (size_t i = 0; i < m; i++)
            rep[mem[i]] = first;
        return;
    }
    double x0 = x[mem[0]], x1 = x0, y0 = y[mem[0]], y1 = y0;
    for (size_t i = 1; i < m; i++) {
        double a = x[mem[i]], b = y[mem[i]];
        x0 = a < x0 ? a : x0;
        x1 = a > x1 ? a : x1;
        y0 = b < y0 ? b : y0;
        y1 = b > y1 ? b : y1;
    }
    size_t h = m / 2;
    select_first(mem, m, h, x1 - x0 >= y1 - y0 ? x : y, rng);
    split(mem, h, x, y, maxgroup, rep, rng);
    split(mem + h, m - h, x, y, maxgroup, rep, rng);
}

void mp_split_group(size_t *mem, size_t m, const double *x, const double *y,
                    size_t maxgroup, size_t *rep)
{
    uint64_t rng = 0x9E3779B97F4A7C15u;
    if (m && maxgroup)
        split(mem, m, x, y, maxgroup, rep, &rng);
}
