/* test_fit_memory.c — the frame fit's memory across the pipeline's calls
 * (fit/frame_memory.c): a star whose row still holds its last fit gets
 * that fit's bound and sky order back; a forgotten memory (a new PSF:
 * mp_fit_memory_forget) gives back no bound and no light to account for,
 * only each star's sky order as its next fit's start — none where its
 * last fit did not converge, as first_order would not take it, but a
 * saturated star's, which it now takes — and only once (a memory
 * remembered again holds its new fits whole).  Deterministic: hand-made
 * states. */
#include <setjmp.h>
#include <stdarg.h>
#include <stddef.h>
#include <cmocka.h>
#include <math.h>
#include <stdlib.h>
#include <string.h>

#include "fit/frame_priv.h"
#include "fit/fit.h"

#define NSTAR 3

/* The rows the memory is keyed by (NUMBER 1..3), each as the last fit
 * left it (mp_table through ff_write_columns). */
static void fitted_table(mp_table *t, star_state *st)
{
    mp_table_init(t);
    assert_true(mp_table_add_col(t, "NUMBER") >= 0);
    for (int k = 0; k < NSTAR; k++) {
        assert_true(mp_table_add_row(t) >= 0);
        mp_table_set(t, (size_t)k, 0, k + 1);
    }
    memset(st, 0, NSTAR * sizeof *st);
    for (int k = 0; k < NSTAR; k++) {
        st[k].s.x = 10.0 + 10.0 * k;
        st[k].s.y = 20.0;
        st[k].s.flux = 1e4;
        st[k].s.sky = 100.0;
        st[k].s.sky_order = 2;
        st[k].number = k + 1;
        st[k].row = k;
        st[k].alive = 1;
        st[k].bound = 0.01;
    }
    st[0].s.flags = MP_FLAG_SATURATED;
    st[1].s.flags = MP_FLAG_NOCONV;
    assert_int_equal(ff_write_columns(t, st, NSTAR, 0.0, (char[MP_ERRLEN]){0}), 0);
}

/* The states of the next call, as read_stars makes them: the rows'
 * positions, fluxes and skies, never fitted (sky order 0). */
static void next_states(const star_state *last, star_state *st, int n)
{
    memset(st, 0, (size_t)n * sizeof *st);
    for (int k = 0; k < n; k++) {
        st[k].s.x = last[k].s.x;
        st[k].s.y = last[k].s.y;
        st[k].s.flux = last[k].s.flux;
        st[k].s.sky = last[k].s.sky;
        st[k].number = k + 1;
        st[k].row = k;
        st[k].alive = 1;
        st[k].bound = INFINITY;
    }
}

/* A memory holding the fits of fitted_table's stars (their paint rule
 * set), t and last as fitted_table made them. */
static mp_fit_memory *remembered(mp_table *t, star_state *last)
{
    fitted_table(t, last);
    mp_fit_memory *mem = mp_fit_memory_new();
    assert_non_null(mem);
    paint_rule held = {NULL, 1e6, {0, {0}}, 1};
    assert_int_equal(ff_remember(mem, last, NSTAR, NSTAR, &held), 0);
    return mem;
}

/* Remembered, then recalled unchanged: the bounds and sky orders back. */
static void test_recall_gives_back(void **state)
{
    (void)state;
    mp_table t;
    star_state last[NSTAR], st[NSTAR];
    mp_fit_memory *mem = remembered(&t, last);
    paint_rule back;
    next_states(last, st, NSTAR);
    star_state *gone;
    size_t ngone;
    assert_int_equal(ff_recall(mem, &t, st, NSTAR, &back, &gone, &ngone), 0);
    assert_int_equal(back.set, 1);
    assert_int_equal(ngone, 0);
    for (int k = 0; k < NSTAR; k++) {
        assert_true(st[k].bound == 0.01);
        assert_int_equal(st[k].moved, 0);
        assert_int_equal(st[k].s.sky_order, 2);
    }
    free(gone);
    mp_fit_memory_free(mem);
    mp_table_free(&t);
}

/* Forgotten (the third star gone from the table too): every star as new
 * (no bound, from no light), no light gone to account for, no paint held,
 * and each sky order kept (a saturated star's too) but the one not
 * converged; a second recall
 * finds the memory empty. */
static void test_forget_keeps_sky_orders(void **state)
{
    (void)state;
    mp_table t;
    star_state last[NSTAR], st[NSTAR];
    mp_fit_memory *mem = remembered(&t, last);
    paint_rule back;
    mp_fit_memory_forget(mem);
    next_states(last, st, NSTAR - 1);
    t.nrow = NSTAR - 1;
    star_state *gone;
    size_t ngone;
    assert_int_equal(ff_recall(mem, &t, st, NSTAR - 1, &back, &gone, &ngone), 0);
    assert_int_equal(back.set, 0);
    assert_int_equal(ngone, 0);
    assert_null(gone);
    for (int k = 0; k < NSTAR - 1; k++) {
        assert_true(isinf(st[k].bound));
        assert_int_equal(st[k].moved, MOVED_CALL);
        assert_int_equal(st[k].olight, 0);
    }
    assert_int_equal(st[0].s.sky_order, 2);     /* saturated: warm all the same */
    assert_int_equal(st[1].s.sky_order, 0);     /* not converged: from a constant */
    next_states(last, st, NSTAR - 1);
    assert_int_equal(ff_recall(mem, &t, st, NSTAR - 1, &back, &gone, &ngone), 0);
    assert_int_equal(ngone, 0);
    for (int k = 0; k < NSTAR - 1; k++) {
        assert_true(isinf(st[k].bound));
        assert_int_equal(st[k].s.sky_order, 0);
    }
    t.nrow = NSTAR;
    mp_fit_memory_free(mem);
    mp_table_free(&t);
}

/* Forgotten, then remembered again by a call that did not recall it (no
 * economy there): the new fits are remembered whole, bounds and all. */
static void test_remember_after_forget(void **state)
{
    (void)state;
    mp_table t;
    star_state last[NSTAR], st[NSTAR];
    mp_fit_memory *mem = remembered(&t, last);
    paint_rule held = {NULL, 1e6, {0, {0}}, 1}, back;
    mp_fit_memory_forget(mem);
    assert_int_equal(ff_remember(mem, last, NSTAR, NSTAR, &held), 0);
    next_states(last, st, NSTAR);
    star_state *gone;
    size_t ngone;
    assert_int_equal(ff_recall(mem, &t, st, NSTAR, &back, &gone, &ngone), 0);
    assert_int_equal(back.set, 1);
    for (int k = 0; k < NSTAR; k++)
        assert_true(st[k].bound == 0.01);
    free(gone);
    mp_fit_memory_free(mem);
    mp_table_free(&t);
}

int main(void)
{
    const struct CMUnitTest tests[] = {
        cmocka_unit_test(test_recall_gives_back),
        cmocka_unit_test(test_forget_keeps_sky_orders),
        cmocka_unit_test(test_remember_after_forget),
    };
    return cmocka_run_group_tests(tests, NULL, NULL);
}
