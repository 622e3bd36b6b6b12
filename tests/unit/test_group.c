/*
 * test_group.c — group/: the critical separation (just inside / outside),
 * transitive chains, identical partitions to a brute-force O(N²) grouping
 * on random, snapped, clustered and far-off fields, the splitting rule
 * (parts <= maxgroup, FLAGS 2 exactly on split members, other bits kept),
 * 0 and 1 star, non-finite positions, and linear cost (operations counted,
 * 1e5 vs 1e6 stars; run times belong to make bench).
 */
#include <stdarg.h>
#include <stddef.h>
#include <stdint.h>
#include <setjmp.h>
#include <cmocka.h>

#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "catalog/catalog.h"
#include "group/group.h"
#include "group/group_priv.h"

/* ---- helpers ---------------------------------------------------------- */

static double urand(uint64_t *s)       /* splitmix64 → [0, 1) */
{
    uint64_t z = (*s += 0x9E3779B97F4A7C15u);
    z = (z ^ (z >> 30)) * 0xBF58476D1CE4E5B9u;
    z = (z ^ (z >> 27)) * 0x94D049BB133111EBu;
    z ^= z >> 31;
    return (double)(z >> 11) * 0x1p-53;
}

/* A table of n stars at (x[i], y[i]) in X_IMAGE/Y_IMAGE. */
static void make_table(mp_table *t, const double *x, const double *y, size_t n)
{
    mp_table_init(t);
    int cx = mp_table_add_col(t, "X_IMAGE"), cy = mp_table_add_col(t, "Y_IMAGE");
    assert_true(cx >= 0 && cy >= 0);
    for (size_t i = 0; i < n; i++) {
        long r = mp_table_add_row(t);
        assert_true(r >= 0);
        mp_table_set(t, (size_t)r, cx, x[i]);
        mp_table_set(t, (size_t)r, cy, y[i]);
    }
}

static mp_group_opts opts(double fitrad, double psfrad, int maxgroup)
{
    mp_group_opts o = { fitrad, psfrad, maxgroup, 0, NULL, NULL };
    return o;
}

static double get(const mp_table *t, size_t i, const char *name)
{
    int c = mp_table_col(t, name);
    assert_true(c >= 0);
    return mp_table_get(t, i, c);
}

/* GROUP_ID numbered 1..G in order of first row; GROUP_SIZE = count of its
 * GROUP_ID.  Returns G. */
static size_t check_ids(const mp_table *t)
{
    size_t n = t->nrow, g = 0;
    size_t *count = calloc(n + 1, sizeof *count);
    assert_non_null(count);
    for (size_t i = 0; i < n; i++) {
        double id = get(t, i, "GROUP_ID");
        assert_true(id >= 1 && id <= (double)g + 1 && id == floor(id));
        if (id == (double)g + 1)
            g++;
        count[(size_t)id]++;
    }
    for (size_t i = 0; i < n; i++)
        assert_int_equal((size_t)get(t, i, "GROUP_SIZE"), count[(size_t)get(t, i, "GROUP_ID")]);
    free(count);
    return g;
}

/* Brute force: naive disjoint sets over all pairs, with the same test. */
static size_t naive_find(size_t *p, size_t i)
{
    while (p[i] != i)
        i = p[i];
    return i;
}

static size_t *brute_labels(const double *x, const double *y, size_t n, double crit)
{
    size_t *p = malloc((n ? n : 1) * sizeof *p);
    assert_non_null(p);
    for (size_t i = 0; i < n; i++)
        p[i] = i;
    for (size_t i = 0; i < n; i++)
        for (size_t j = i + 1; j < n; j++) {
            double dx = x[i] - x[j], dy = y[i] - y[j];
            if (dx * dx + dy * dy < crit * crit) {
                size_t a = naive_find(p, i), b = naive_find(p, j);
                if (a != b)
                    p[a < b ? b : a] = a < b ? a : b;
            }
        }
    for (size_t i = 0; i < n; i++)
        p[i] = naive_find(p, i);
    return p;
}

/* The partition by GROUP_ID equals the partition by label: the map
 * label → id and id → label are both functions. */
static void assert_same_partition(const mp_table *t, const size_t *label)
{
    size_t n = t->nrow;
    double *id_of_label = malloc((n ? n : 1) * sizeof *id_of_label);
    size_t *label_of_id = malloc((n + 1) * sizeof *label_of_id);
    assert_true(id_of_label && label_of_id);
    for (size_t i = 0; i < n; i++) {
        id_of_label[i] = -1;
        label_of_id[i] = SIZE_MAX;
    }
    label_of_id[n] = SIZE_MAX;
    for (size_t i = 0; i < n; i++) {
        double id = get(t, i, "GROUP_ID");
        size_t l = label[i];
        if (id_of_label[l] < 0)
            id_of_label[l] = id;
        assert_true(id_of_label[l] == id);
        if (label_of_id[(size_t)id] == SIZE_MAX)
            label_of_id[(size_t)id] = l;
        assert_int_equal(label_of_id[(size_t)id], l);
    }
    free(id_of_label);
    free(label_of_id);
}

/* Group x,y with opts and compare with the brute force (no splitting). */
static void compare_with_brute(const double *x, const double *y, size_t n, double fitrad,
                               double psfrad)
{
    mp_table t;
    make_table(&t, x, y, n);
    mp_group_opts o = opts(fitrad, psfrad, 100000000);
    char err[MP_ERRLEN];
    assert_int_equal(mp_group_table(&t, &o, err), 0);
    check_ids(&t);
    size_t *label = brute_labels(x, y, n, fitrad + psfrad);
    assert_same_partition(&t, label);
    for (size_t i = 0; i < n; i++)
        assert_true(get(&t, i, "FLAGS") == 0);
    free(label);
    mp_table_free(&t);
}

/* ---- tests ------------------------------------------------------------ */

static void test_defaults(void **state)
{
    (void)state;
    mp_group_opts o;
    mp_group_opts_default(&o);
    assert_true(o.fitrad == 5.0 && o.psfrad == 10.0 && o.maxgroup == 60);
}

/* crit = 15: at 15 - 1e-9 one group, at 15 exactly or 15 + 1e-9 two. */
static void test_critical_separation(void **state)
{
    (void)state;
    const double d[] = { 15.0 - 1e-9, 15.0, 15.0 + 1e-9, 3.0, 40.0 };
    const size_t want[] = { 1, 2, 2, 1, 2 };
    for (size_t k = 0; k < sizeof d / sizeof d[0]; k++) {
        /* Along x, and (away from the exact boundary, where c/√2 rounds)
         * along a diagonal too. */
        for (int diag = 0; diag < (k < 3 ? 1 : 2); diag++) {
            double c = diag ? d[k] / sqrt(2.0) : d[k];
            double x[2] = { 1000.5, 1000.5 + c }, y[2] = { -77.25, -77.25 + (diag ? c : 0) };
            mp_table t;
            make_table(&t, x, y, 2);
            mp_group_opts o = opts(5, 10, 60);
            char err[MP_ERRLEN];
            assert_int_equal(mp_group_table(&t, &o, err), 0);
            assert_int_equal(check_ids(&t), want[k]);
            assert_true(get(&t, 0, "GROUP_SIZE") == (want[k] == 1 ? 2 : 1));
            mp_table_free(&t);
        }
    }
}

/* A–B–C within 15 pairwise along a chain (A–C 28 apart) share a group;
 * D at 50 is alone; E, F form a second pair.  Rows interleaved so that
 * the numbering follows first rows. */
static void test_chain(void **state)
{
    (void)state;
    double x[] = { 100, 300, 114, 150, 128, 310 };
    double y[] = { 0, 0, 0, 0, 0, 5 };
    mp_table t;
    make_table(&t, x, y, 6);
    mp_group_opts o = opts(5, 10, 60);
    char err[MP_ERRLEN];
    assert_int_equal(mp_group_table(&t, &o, err), 0);
    const double id[] = { 1, 2, 1, 3, 1, 2 }, size[] = { 3, 2, 3, 1, 3, 2 };
    for (size_t i = 0; i < 6; i++) {
        assert_true(get(&t, i, "GROUP_ID") == id[i]);
        assert_true(get(&t, i, "GROUP_SIZE") == size[i]);
        assert_true(get(&t, i, "FLAGS") == 0);
    }
    mp_table_free(&t);
}

/* Random fields of several densities against the brute force. */
static void test_random_vs_brute(void **state)
{
    (void)state;
    uint64_t s = 12345;
    const size_t n = 3000;
    double *x = malloc(n * sizeof *x), *y = malloc(n * sizeof *y);
    assert_true(x && y);
    const double side[] = { 300, 800, 2000, 5000 };
    for (size_t k = 0; k < sizeof side / sizeof side[0]; k++) {
        for (size_t i = 0; i < n; i++) {
            x[i] = side[k] * urand(&s) - 20;     /* some off the frame */
            y[i] = side[k] * urand(&s) - 20;
        }
        compare_with_brute(x, y, n, 5, 10);
        compare_with_brute(x, y, n, 1.5, 2.2);
    }
    /* Positions snapped to a grid (exact ties at the cell boundaries and at
     * the critical separation), with many coincident stars. */
    for (size_t i = 0; i < n; i++) {
        x[i] = 0.5 * floor(400 * urand(&s));
        y[i] = 0.5 * floor(400 * urand(&s));
    }
    compare_with_brute(x, y, n, 2.0, 1.0);
    compare_with_brute(x, y, n, 5.0, 0.0);
    /* Clusters: tight clumps of many stars, some touching. */
    for (size_t i = 0; i < n; i++) {
        size_t c = i % 40;
        x[i] = 37.0 * (double)(c % 8) + 3 * urand(&s);
        y[i] = 41.0 * (double)(c / 8) + 3 * urand(&s);
    }
    compare_with_brute(x, y, n, 5, 10);
    free(x);
    free(y);
}

/* Stars far off any frame, beyond the grid's clamped cells. */
static void test_far_off(void **state)
{
    (void)state;
    uint64_t s = 99;
    const size_t n = 600;
    double x[600], y[600];
    for (size_t i = 0; i < n; i++) {
        double far = (i % 3 == 0) ? 1e12 : (i % 3 == 1) ? -3e11 : 0;
        x[i] = far + 200 * urand(&s);
        y[i] = (i % 2 ? -1 : 1) * 2e11 + 200 * urand(&s);
    }
    compare_with_brute(x, y, n, 5, 10);
}

/* A line of 200 stars 1 px apart along x: cut at medians into 4 runs of
 * 50; an unrelated pair far away is not split and keeps FLAGS 1 (a stale
 * 2 is cleared); the line's FLAGS 1 survives next to the new 2. */
static void test_split_line(void **state)
{
    (void)state;
    double x[202], y[202];
    for (size_t i = 0; i < 200; i++) {
        x[i] = 1000 - (double)i;     /* decreasing: parts are not row runs by x */
        y[i] = 50 + 0.01 * (double)(i % 7);
    }
    x[200] = 5000, y[200] = 5000;
    x[201] = 5003, y[201] = 5000;
    mp_table t;
    make_table(&t, x, y, 202);
    int cf = mp_table_add_col(&t, "FLAGS");
    for (size_t i = 0; i < 202; i++)
        mp_table_set(&t, i, cf, i < 200 ? 1 : 3);
    mp_group_opts o = opts(5, 10, 60);
    char err[MP_ERRLEN];
    assert_int_equal(mp_group_table(&t, &o, err), 0);
    assert_int_equal(check_ids(&t), 5);
    for (size_t i = 0; i < 200; i++) {
        assert_true(get(&t, i, "GROUP_ID") == (double)(i / 50 + 1));
        assert_true(get(&t, i, "GROUP_SIZE") == 50);
        assert_true(get(&t, i, "FLAGS") == 3);
    }
    for (size_t i = 200; i < 202; i++) {
        assert_true(get(&t, i, "GROUP_ID") == 5);
        assert_true(get(&t, i, "FLAGS") == 1);
    }
    mp_table_free(&t);
}

/* A dense random field: parts <= maxgroup, every part inside one brute-
 * force component, FLAGS 2 exactly on members of components > maxgroup. */
static void test_split_random(void **state)
{
    (void)state;
    uint64_t s = 777;
    const size_t n = 2500;
    double *x = malloc(n * sizeof *x), *y = malloc(n * sizeof *y);
    assert_true(x && y);
    for (size_t i = 0; i < n; i++) {
        x[i] = 700 * urand(&s);
        y[i] = 700 * urand(&s);
    }
    const int maxg[] = { 1, 7, 60, 500 };
    size_t *label = brute_labels(x, y, n, 15);
    size_t *csize = calloc(n, sizeof *csize);
    assert_non_null(csize);
    for (size_t i = 0; i < n; i++)
        csize[label[i]]++;
    for (size_t k = 0; k < sizeof maxg / sizeof maxg[0]; k++) {
        mp_table t;
        make_table(&t, x, y, n);
        mp_group_opts o = opts(5, 10, maxg[k]);
        char err[MP_ERRLEN];
        assert_int_equal(mp_group_table(&t, &o, err), 0);
        size_t g = check_ids(&t);
        size_t *lab_of_id = malloc((g + 1) * sizeof *lab_of_id);
        assert_non_null(lab_of_id);
        for (size_t j = 0; j <= g; j++)
            lab_of_id[j] = SIZE_MAX;
        size_t nsplit = 0;
        for (size_t i = 0; i < n; i++) {
            size_t id = (size_t)get(&t, i, "GROUP_ID");
            assert_true(get(&t, i, "GROUP_SIZE") <= maxg[k]);
            if (lab_of_id[id] == SIZE_MAX)
                lab_of_id[id] = label[i];
            assert_int_equal(lab_of_id[id], label[i]);      /* refines */
            int split = csize[label[i]] > (size_t)maxg[k];
            assert_true(get(&t, i, "FLAGS") == (split ? 2 : 0));
            nsplit += (size_t)split;
            if (!split)          /* unsplit components stay whole */
                assert_true(get(&t, i, "GROUP_SIZE") == (double)csize[label[i]]);
        }
        if (maxg[k] < 500)
            assert_true(nsplit > 0);
        free(lab_of_id);
        mp_table_free(&t);
    }
    free(csize);
    free(label);
    free(x);
    free(y);
}

/* All stars at one point: one component, split into parts by row. */
static void test_one_point(void **state)
{
    (void)state;
    const size_t n = 1000;
    double *x = malloc(n * sizeof *x), *y = malloc(n * sizeof *y);
    assert_true(x && y);
    for (size_t i = 0; i < n; i++)
        x[i] = y[i] = 42.5;
    mp_table t;
    make_table(&t, x, y, n);
    mp_group_opts o = opts(5, 10, 100000);
    char err[MP_ERRLEN];
    assert_int_equal(mp_group_table(&t, &o, err), 0);
    assert_int_equal(check_ids(&t), 1);
    assert_true(get(&t, 0, "GROUP_SIZE") == (double)n);
    mp_table_free(&t);
    make_table(&t, x, y, n);
    o.maxgroup = 60;          /* 1000 → 500 → 250 → 125 → 62/63 → 31/32 */
    assert_int_equal(mp_group_table(&t, &o, err), 0);
    assert_int_equal(check_ids(&t), 32);
    for (size_t i = 0; i < n; i++) {
        assert_true(get(&t, i, "GROUP_SIZE") <= 60 && get(&t, i, "GROUP_SIZE") >= 31);
        assert_true(get(&t, i, "FLAGS") == 2);
        assert_true(get(&t, i, "GROUP_ID") == (i < 31 ? 1 : i < 62 ? 2 : get(&t, i, "GROUP_ID")));
    }   /* ties are cut by row: rows 0-30 form group 1, rows 31-61 group 2 */
    mp_table_free(&t);
    free(x);
    free(y);
}

static void test_zero_and_one(void **state)
{
    (void)state;
    mp_table t;
    char err[MP_ERRLEN];
    mp_group_opts o = opts(5, 10, 60);
    make_table(&t, NULL, NULL, 0);
    assert_int_equal(mp_group_table(&t, &o, err), 0);
    assert_true(mp_table_col(&t, "GROUP_ID") >= 0 && mp_table_col(&t, "GROUP_SIZE") >= 0 &&
                mp_table_col(&t, "FLAGS") >= 0);
    assert_int_equal(t.nrow, 0);
    mp_table_free(&t);
    double x = -3.25, y = 1e6;            /* off the frame */
    make_table(&t, &x, &y, 1);
    assert_int_equal(mp_group_table(&t, &o, err), 0);
    assert_true(get(&t, 0, "GROUP_ID") == 1 && get(&t, 0, "GROUP_SIZE") == 1 &&
                get(&t, 0, "FLAGS") == 0);
    /* Grouping again overwrites, adding no column. */
    size_t ncol = t.ncol;
    assert_int_equal(mp_group_table(&t, &o, err), 0);
    assert_int_equal(t.ncol, ncol);
    mp_table_free(&t);
}

/* XPSF_IMAGE/YPSF_IMAGE win over X_IMAGE/Y_IMAGE. */
static void test_prefers_psf_positions(void **state)
{
    (void)state;
    double x[2] = { 0, 100 }, y[2] = { 0, 0 };
    mp_table t;
    make_table(&t, x, y, 2);
    int px = mp_table_add_col(&t, "XPSF_IMAGE"), py = mp_table_add_col(&t, "YPSF_IMAGE");
    mp_table_set(&t, 0, px, 50);
    mp_table_set(&t, 1, px, 60);
    mp_table_set(&t, 0, py, 0);
    mp_table_set(&t, 1, py, 0);
    mp_group_opts o = opts(5, 10, 60);
    char err[MP_ERRLEN];
    assert_int_equal(mp_group_table(&t, &o, err), 0);
    assert_int_equal(check_ids(&t), 1);
    mp_table_free(&t);
}

static void test_errors(void **state)
{
    (void)state;
    double x[4] = { 1, 2, NAN, 4 }, y[4] = { 1, 2, 3, INFINITY };
    mp_table t;
    char err[MP_ERRLEN];
    mp_group_opts o = opts(5, 10, 60);
    make_table(&t, x, y, 4);
    size_t ncol = t.ncol;
    assert_int_not_equal(mp_group_table(&t, &o, err), 0);
    assert_non_null(strstr(err, "row 3"));
    assert_int_equal(t.ncol, ncol);                 /* t untouched */
    mp_table_set(&t, 2, 0, 3);
    assert_int_not_equal(mp_group_table(&t, &o, err), 0);
    assert_non_null(strstr(err, "row 4"));
    mp_table_set(&t, 3, 1, 4);
    assert_int_equal(mp_group_table(&t, &o, err), 0);
    const mp_group_opts bad[] = { { -1, 10, 60, 0, NULL, NULL }, { 5, NAN, 60, 0, NULL, NULL },
                                   { 0, 0, 60, 0, NULL, NULL }, { 5, 10, 0, 0, NULL, NULL } };
    const char *name[] = { "fitrad", "psfrad", "critical", "maxgroup" };
    for (size_t k = 0; k < 4; k++) {
        assert_int_not_equal(mp_group_table(&t, &bad[k], err), 0);
        assert_non_null(strstr(err, name[k]));
    }
    mp_table_free(&t);
    mp_table_init(&t);
    mp_table_add_col(&t, "FLUX_PSF");
    assert_int_not_equal(mp_group_table(&t, &o, err), 0);
    assert_non_null(strstr(err, "X_IMAGE"));
    mp_table_free(&t);
}

static void test_union_find(void **state)
{
    (void)state;
    mp_uf u;
    assert_int_equal(mp_uf_init(&u, 10), 0);
    assert_int_equal(mp_uf_union(&u, 1, 2), 1);
    assert_int_equal(mp_uf_union(&u, 3, 2), 1);
    assert_int_equal(mp_uf_union(&u, 1, 3), 0);
    assert_true(mp_uf_find(&u, 1) == mp_uf_find(&u, 3));
    assert_true(mp_uf_find(&u, 1) != mp_uf_find(&u, 4));
    mp_uf_free(&u);
    mp_uf_free(&u);                                  /* safe twice */
}

/* Operations (cell pairs compared + distance tests + unions) of linking n
 * stars at a fixed density (about 2.5 stars per critical disc: every regime
 * from singles to large groups), or of n stars at one point.  A count, not a
 * clock: the same on every machine and every run. */
static size_t work_of_grouping(size_t n, int one_point)
{
    uint64_t s = 4242;
    double side = sqrt((double)n * 3.14159 * 15 * 15 / 2.5);
    double *x = malloc(n * sizeof *x), *y = malloc(n * sizeof *y);
    size_t *label = malloc(n * sizeof *label), work = 0;
    assert_true(x && y && label);
    for (size_t i = 0; i < n; i++) {
        x[i] = one_point ? 7.0 : side * urand(&s);
        y[i] = one_point ? 7.0 : side * urand(&s);
    }
    assert_int_equal(mp_grid_link(x, y, n, 15.0, NULL, NULL, label, &work), 0);
    free(x);
    free(y);
    free(label);
    return work;
}

/* Linear cost: 10x the stars at the same density costs 10x the operations.
 * The work per star is a mean over ~n cells of bounded, independent terms,
 * so the ratio is 10 up to the sampling error (relative ~1/sqrt(1e5), below
 * 1 %) and the edge effect (stars within crit of the border, 4·crit/side ≈
 * 1.1 % of 1e5 stars, with about half the neighbours): within 5 % of 10.
 * n log n would give 12, quadratic 100.  Stars at one point are one clique:
 * n - 1 unions and as many visits, nothing pairwise. */
static void test_linear_work(void **state)
{
    (void)state;
    size_t w5 = work_of_grouping(100000, 0), w6 = work_of_grouping(1000000, 0);
    size_t wp = work_of_grouping(1000000, 1);
    double ratio = (double)w6 / (double)w5;
    print_message("group: operations 1e5 stars %zu, 1e6 stars %zu (ratio %.3f); "
                  "1e6 at one point %zu\n", w5, w6, ratio, wp);
    assert_true(ratio > 9.5 && ratio < 10.5);
    assert_true(wp <= 2 * (size_t)1000000);
}

/* A link test (mp_group_opts.link): a pair it refuses is not linked,
 * though closer than crit; stars of one cell are tested pair by pair (no
 * clique).  Four stars 2 px apart in a row (one or two cells of side
 * crit/2 = 7.5 px), the test refusing every pair across the middle: {1,2}
 * and {3,4}, its 6 pairs each tested once; without it, one group. */
static int refuse_middle(void *ctx, size_t a, size_t b, double d)
{
    int *calls = ctx;
    (*calls)++;
    assert_true(d < 15.0 && d > 0.0);
    return (a <= 1) == (b <= 1);
}

static void test_link_test(void **state)
{
    (void)state;
    char err[MP_ERRLEN];
    mp_table t;
    double x[] = {10, 12, 14, 16}, y[] = {10, 10, 10, 10};
    make_table(&t, x, y, 4);
    int calls = 0;
    mp_group_opts o = opts(5, 10, 60);
    o.link = refuse_middle;
    o.link_ctx = &calls;
    assert_int_equal(mp_group_table(&t, &o, err), 0);
    assert_int_equal(calls, 6);
    assert_true(get(&t, 0, "GROUP_ID") == get(&t, 1, "GROUP_ID"));
    assert_true(get(&t, 2, "GROUP_ID") == get(&t, 3, "GROUP_ID"));
    assert_true(get(&t, 1, "GROUP_ID") != get(&t, 2, "GROUP_ID"));
    assert_true(get(&t, 0, "GROUP_SIZE") == 2.0);
    o.link = NULL;
    assert_int_equal(mp_group_table(&t, &o, err), 0);
    assert_true(get(&t, 0, "GROUP_SIZE") == 4.0);
    mp_table_free(&t);
}

/* mp_group_capped: the strongest links first, no set above the cap, and
 * the strong links the cap refused reported.  A chain 0-1-2-3-4-5 with
 * weights 0.9, 0.1, 0.8, 0.7, 0.05 (links 0-1, 1-2, 2-3, 3-4, 4-5), cap 3:
 * 0-1 (0.9), then 2-3 (0.8), 3-4 (0.7) make {2,3,4}; 1-2 (0.1) would make
 * 5: refused (its weight ≥ cutw 0.1 marks 1 and 2); 4-5 refused too (4
 * sets) but below cutw.  So {0,1}, {2,3,4}, {5}.  With cap 6 one set.
 * With cap 6 and weakcap 3 the strong links make {0,...,4}, and 4-5
 * (0.05, below cutw) is refused by the weak cap, unflagged: {5} apart. */
static void test_capped(void **state)
{
    (void)state;
    mp_group_pair p[] = {{4, 5, 0.05}, {1, 2, 0.1}, {0, 1, 0.9}, {3, 4, 0.7}, {2, 3, 0.8}};
    size_t label[6];
    unsigned char cut[6] = {0};
    assert_int_equal(mp_group_capped(6, p, 5, 3, 0, label, cut, 0.1), 0);
    assert_true(label[0] == label[1]);
    assert_true(label[2] == label[3] && label[3] == label[4]);
    assert_true(label[1] != label[2] && label[4] != label[5] && label[0] != label[5]);
    unsigned char want[6] = {0, 1, 1, 0, 0, 0};
    assert_memory_equal(cut, want, 6);
    assert_true(p[0].w == 0.9 && p[4].w == 0.05);      /* sorted strongest first */
    assert_int_equal(mp_group_capped(6, p, 5, 6, 0, label, NULL, 0.1), 0);
    for (int i = 1; i < 6; i++)
        assert_true(label[i] == label[0]);
    memset(cut, 0, sizeof cut);
    assert_int_equal(mp_group_capped(6, p, 5, 6, 3, label, cut, 0.1), 0);
    for (int i = 1; i < 5; i++)
        assert_true(label[i] == label[0]);
    assert_true(label[5] != label[0]);
    unsigned char none[6] = {0};
    assert_memory_equal(cut, none, 6);
}

/* mp_group_budget: links joined strongest first only while one of their
 * stars has more than the budget of Σw² outside its set.  Stars 0..3,
 * Σw²: 0.2504, 0.2516, 0.0916, 0.0904.  Budget 0.003: 0-1 and 2-3 join,
 * after which every star has ≤ 0.0016 outside and 1-2 (0.04) and 0-3
 * (0.02) stay cut.  Budget 0.001: 1-2 joins too (star 1 still has 0.0016
 * out), 0-3 is then inside.  With a cap of 2 that join is refused and its
 * stars flagged (w 0.04 ≥ cutw 0.03); 0-3, never needed, is not.  A
 * budget of 1: nothing is needed. */
static void test_budget(void **state)
{
    (void)state;
    const mp_group_pair p0[] = {{0, 1, 0.5}, {1, 2, 0.04}, {2, 3, 0.3}, {0, 3, 0.02}};
    mp_group_pair p[4];
    size_t label[4];
    unsigned char cut[4] = {0};
    memcpy(p, p0, sizeof p);
    assert_int_equal(mp_group_budget(4, p, 4, 10, 0.003, label, NULL, 0.03), 0);
    assert_true(label[0] == label[1] && label[2] == label[3] && label[1] != label[2]);
    memcpy(p, p0, sizeof p);
    assert_int_equal(mp_group_budget(4, p, 4, 10, 0.001, label, NULL, 0.03), 0);
    assert_true(label[0] == label[1] && label[1] == label[2] && label[2] == label[3]);
    memcpy(p, p0, sizeof p);
    assert_int_equal(mp_group_budget(4, p, 4, 2, 0.001, label, cut, 0.03), 0);
    assert_true(label[0] == label[1] && label[2] == label[3] && label[1] != label[2]);
    unsigned char want[4] = {0, 1, 1, 0};
    assert_memory_equal(cut, want, 4);
    memcpy(p, p0, sizeof p);
    assert_int_equal(mp_group_budget(4, p, 4, 10, 1.0, label, NULL, 0.03), 0);
    for (int i = 0; i < 4; i++)
        for (int j = i + 1; j < 4; j++)
            assert_true(label[i] != label[j]);
}

int main(void)
{
    const struct CMUnitTest tests[] = {
        cmocka_unit_test(test_defaults),
        cmocka_unit_test(test_critical_separation),
        cmocka_unit_test(test_chain),
        cmocka_unit_test(test_random_vs_brute),
        cmocka_unit_test(test_far_off),
        cmocka_unit_test(test_split_line),
        cmocka_unit_test(test_split_random),
        cmocka_unit_test(test_one_point),
        cmocka_unit_test(test_zero_and_one),
        cmocka_unit_test(test_prefers_psf_positions),
        cmocka_unit_test(test_errors),
        cmocka_unit_test(test_union_find),
        cmocka_unit_test(test_linear_work),
        cmocka_unit_test(test_link_test),
        cmocka_unit_test(test_capped),
        cmocka_unit_test(test_budget),
    };
    return cmocka_run_group_tests(tests, NULL, NULL);
}
