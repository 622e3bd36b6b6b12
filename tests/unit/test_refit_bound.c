/* test_refit_bound.c — economy's refit bound (fit/frame_bound.c, issue 14):
 * each change of a star's light adds its norm over a neighbour's fitting
 * region to the neighbour's bound.  Checked against a whole-frame
 * computation written here independently: every bound is the sum of the
 * norms of the changes that reach it (none missed, none counted twice, a
 * change its own group's fit saw left out), so by the triangle inequality
 * it is at least the norm of their sum, the exact test's value; and a
 * change of the paint's rule leaves no bound standing.  Deterministic
 * (seeded positions); the tolerances are float rounding of the painted
 * light (values ≤ 1e4 e-, ulp ≤ 1e-3, σ ≥ 3: below 1e-4 σ a pixel). */
#include <setjmp.h>
#include <stdarg.h>
#include <stddef.h>
#include <cmocka.h>
#include <stdio.h>

#include "tests/unit/stiff_common.h"
#include "fit/frame_priv.h"

#define NX 80
#define NST 24
#define FITRAD 5.0

/* Σ(d/σ)² over the unmasked pixels within r of (x, y), d a whole frame. */
static double norm2_whole(const mp_frame *f, const float *d, double x, double y, double r)
{
    double q = 0.0, ron2 = f->rdnoise * f->rdnoise;
    for (long Y = 1; Y <= f->im.ny; Y++)
        for (long X = 1; X <= f->im.nx; X++) {
            size_t g = (size_t)(Y - 1) * (size_t)f->im.nx + (size_t)(X - 1);
            if ((X - x) * (X - x) + (Y - y) * (Y - y) > r * r || f->mask[g])
                continue;
            double v = fmax(f->im.pix[g], 0.0) + ron2;
            q += (double)d[g] * d[g] / fmax(v, 1e-2);
        }
    return q;
}

/* Star j's change of light (now − old) on the whole frame, into d. */
static void change_image(const mp_prf_model *m, const crop_rule *crop, const star_state *s,
                         float *d)
{
    memset(d, 0, NX * NX * sizeof *d);
    mp_prf_work wk = {0};
    double *buf = NULL;
    size_t cap = 0;
    mp_star old = s->s;
    old.x = s->ox, old.y = s->oy, old.flux = s->oflux, old.sky = s->osky;
    if (s->alive)
        assert_int_equal(ff_paint(m, &s->s, +1.0, ff_crop_radius(crop, &s->s), d, 1, 1, NX, NX,
                                  &wk, &buf, &cap, NULL), 0);
    if (s->olight)
        assert_int_equal(ff_paint(m, &old, -1.0, ff_crop_radius(crop, &old), d, 1, 1, NX, NX,
                                  &wk, &buf, &cap, NULL), 0);
    free(buf);
    mp_prf_work_free(&wk);
}

/* NST stars in groups of three; each moved by up to 0.4 px and its flux by
 * up to 15 %, every fifth one dead; groups alternately changed by their
 * own fits (MOVED_FIT) and between calls (MOVED_CALL); all bounds 0.  One
 * star gone from the table. */
static void scene(mp_frame *f, star_state *st, size_t *gs, size_t *ng, star_state *gone)
{
    mp_rng r;
    mp_rng_seed(&r, 611);
    double x[NST], y[NST], E[NST];
    for (int k = 0; k < NST; k++) {
        x[k] = 8.0 + 64.0 * mp_rng_uniform(&r);
        y[k] = 8.0 + 64.0 * mp_rng_uniform(&r);
        E[k] = pow(10.0, 3.0 + 2.0 * mp_rng_uniform(&r));
    }
    sf_frame_make(f, NX, NX, 3.0);
    sf_render(f, 100.0, 3.0, x, y, E, NST, &r, 3.0);
    for (int j = 40; j < 43; j++)            /* masked pixels are left out */
        for (int i = 40; i < 43; i++)
            f->mask[(size_t)(j - 1) * NX + (size_t)(i - 1)] = 1;
    memset(st, 0, NST * sizeof *st);
    for (int k = 0; k < NST; k++) {
        star_state *s = &st[k];
        s->alive = k % 5 != 4;
        s->ox = x[k], s->oy = y[k], s->oflux = E[k], s->osky = 100.0;
        s->s.x = x[k] + 0.8 * (mp_rng_uniform(&r) - 0.5);
        s->s.y = y[k] + 0.8 * (mp_rng_uniform(&r) - 0.5);
        s->s.flux = E[k] * (1.0 + 0.3 * (mp_rng_uniform(&r) - 0.5));
        s->s.sky = 100.0;
        s->olight = 1;
        s->moved = (k / 3) % 2 ? MOVED_CALL : MOVED_FIT;
        s->bound = 0.0;
    }
    *ng = NST / 3;
    for (size_t g = 0; g <= *ng; g++)
        gs[g] = 3 * g;
    memset(gone, 0, sizeof *gone);
    gone->ox = 40.0, gone->oy = 36.0, gone->oflux = 2e4, gone->osky = 100.0;
    gone->s = st[0].s;
    gone->olight = 1;
    gone->moved = MOVED_CALL;
}

/* The bounds of st (no change pending) after a call with rule now,
 * the bounds having been made under held: kept (all finite and as they
 * were) or all INFINITY, and held becomes now. */
static int bounds_kept(const mp_frame *f, const mp_prf_model *m, const crop_rule *crop,
                       paint_rule now, paint_rule held, star_state *st, const size_t *gs,
                       size_t ng)
{
    double before[NST];
    for (int k = 0; k < NST; k++)
        before[k] = st[k].bound;
    double ops = 0.0;
    assert_int_equal(ff_update_bounds(f, m, crop, &now, &held, FITRAD, INFINITY, st, NST, gs, ng,
                                      NULL, 0, &ops),
                     0);
    assert_ptr_equal(held.grid, now.grid);
    assert_true(held.gemax == now.gemax || (isnan(held.gemax) && isnan(now.gemax)));
    assert_memory_equal(&held.tiers, &now.tiers, sizeof now.tiers);
    int kept = 1, gone = 1;
    for (int k = 0; k < NST; k++) {
        kept &= st[k].bound == before[k];
        gone &= isinf(st[k].bound) != 0;
        st[k].bound = before[k];
    }
    assert_true(kept != gone);
    return kept;
}

/* A paint rule: grid g up to gemax, bilinearly up to lin, no core tier. */
static paint_rule rule(const mp_prf_cache *g, double gemax, double lin, int set)
{
    paint_rule r = {g, gemax, {lin, {0}}, set};
    return r;
}

/* When the bounds hold under another rule: only when it paints every star
 * as the first did (the grid is never read: no change is pending). */
static void paint_rules_checked(const mp_frame *f, const mp_prf_model *m, const crop_rule *crop,
                                star_state *st, const size_t *gs, size_t ng)
{
    mp_prf_cache g1, g2;             /* two grids, told apart by address */
    double Emin = INFINITY, Emax = 0;
    for (int k = 0; k < NST; k++) {
        Emin = fmin(Emin, fabs(st[k].s.flux));
        Emax = fmax(Emax, fabs(st[k].s.flux));
    }
    double mid = sqrt(Emin * Emax);
    /* No grid: the limit draws nobody another way. */
    assert_true(bounds_kept(f, m, crop, rule(NULL, 1e3, 0.0, 1),
                            rule(NULL, NAN, 0.0, 1), st, gs, ng));
    /* One grid, both limits above every star (or both below). */
    assert_true(bounds_kept(f, m, crop, rule(&g1, 2 * Emax, 0.0, 1),
                            rule(&g1, 3 * Emax, 0.0, 1), st, gs, ng));
    assert_true(bounds_kept(f, m, crop, rule(&g1, 0.5 * Emin, 0.0, 1),
                            rule(&g1, 0.2 * Emin, 0.0, 1), st, gs, ng));
    /* A star between the limits, the grid against none, another grid,
     * bounds never made: none holds. */
    assert_false(bounds_kept(f, m, crop, rule(&g1, mid, 0.0, 1),
                             rule(&g1, 2 * Emax, 0.0, 1), st, gs, ng));
    assert_false(bounds_kept(f, m, crop, rule(&g1, 2 * Emax, 0.0, 1),
                             rule(NULL, 2 * Emax, 0.0, 1), st, gs, ng));
    assert_false(bounds_kept(f, m, crop, rule(&g2, 2 * Emax, 0.0, 1),
                             rule(&g1, 2 * Emax, 0.0, 1), st, gs, ng));
    assert_false(bounds_kept(f, m, crop, rule(&g1, 2 * Emax, 0.0, 1),
                             rule(&g1, 2 * Emax, 0.0, 0), st, gs, ng));
    /* The bilinear limit alike: a star between, and none. */
    assert_false(bounds_kept(f, m, crop, rule(&g1, 2 * Emax, mid, 1),
                             rule(&g1, 2 * Emax, 0.0, 1), st, gs, ng));
    assert_true(bounds_kept(f, m, crop, rule(&g1, 2 * Emax, 2 * Emax, 1),
                            rule(&g1, 2 * Emax, 3 * Emax, 1), st, gs, ng));
    /* A core tier's limit alike: a star drawn within another core under
     * the one rule than under the other, and every star in the same. */
    paint_rule a = rule(&g1, 2 * Emax, 0.0, 1), b = a;
    a.tiers.core[2] = b.tiers.core[3] = 2 * Emax;
    assert_false(bounds_kept(f, m, crop, a, b, st, gs, ng));
    b.tiers.core[2] = 3 * Emax;
    assert_true(bounds_kept(f, m, crop, a, b, st, gs, ng));
}

/* A scene's run: the Gaussian model, the frame, its stars as they were
 * (before) and with their bounds summed without a cap (st). */
typedef struct {
    mp_psf p;
    mp_prf_model m;
    mp_frame f;
    star_state st[NST], before[NST], gone;
    size_t gs[NST / 3 + 1], ng;
    crop_rule crop;
} bound_case;

static void summed_case(bound_case *c)
{
    mp_psf_gauss(3.0, &c->p);
    c->m = (mp_prf_model){&c->p, NULL, 10};
    scene(&c->f, c->st, c->gs, &c->ng, &c->gone);
    memcpy(c->before, c->st, sizeof c->st);
    assert_int_equal(ff_crop_init(&c->f, &c->m, 0.02, NULL, &c->crop), 0);
    paint_rule now = rule(NULL, NAN, 0.0, 1), held = now;
    double ops = 0.0;
    assert_int_equal(ff_update_bounds(&c->f, &c->m, &c->crop, &now, &held, FITRAD, INFINITY, c->st,
                                      NST, c->gs, c->ng, &c->gone, 1, &ops), 0);
}

static void case_free(bound_case *c)
{
    free(c->crop.env);
    sf_frame_drop(&c->f);
}

static void test_bound_sums_the_changes(void **state)
{
    (void)state;
    bound_case c;
    summed_case(&c);
    mp_prf_model m = c.m;
    mp_frame f = c.f;
    star_state *st = c.st, *ref = c.before, gone = c.gone;
    const size_t *gs = c.gs, ng = c.ng;
    crop_rule crop = c.crop;
    float *d[NST + 1], *sum = malloc(NX * NX * sizeof *sum);
    assert_non_null(sum);
    for (int j = 0; j <= NST; j++) {
        assert_non_null(d[j] = malloc(NX * NX * sizeof *d[j]));
        change_image(&m, &crop, j < NST ? &ref[j] : &gone, d[j]);
    }
    int single = 0, several = 0;
    for (int k = 0; k < NST; k++) {
        assert_int_equal(st[k].moved, 0);
        if (!st[k].alive)
            continue;
        double b = 0.0;
        int reach = 0;
        memset(sum, 0, NX * NX * sizeof *sum);
        for (int j = 0; j <= NST; j++) {
            int seen = j < NST && ref[j].moved == MOVED_FIT && j / 3 == k / 3;
            if (j == k || seen)
                continue;
            double v = sqrt(norm2_whole(&f, d[j], st[k].s.x, st[k].s.y, FITRAD));
            b += v;
            reach += v > 0.0;
            for (int i = 0; i < NX * NX; i++)
                sum[i] += d[j][i];
        }
        double q = sqrt(norm2_whole(&f, sum, st[k].s.x, st[k].s.y, FITRAD));
        assert_true(fabs(st[k].bound - b) <= 1e-4 * (1.0 + b));
        assert_true(st[k].bound >= q - 1e-4 * (1.0 + q));
        single += reach == 1;
        several += reach > 1 && st[k].bound > q * 1.01;
    }
    print_message("%d stars reached by one change, %d by several (bound > exact)\n", single,
                  several);
    assert_true(single >= 2);    /* the scene tests both cases */
    assert_true(several >= 2);
    paint_rules_checked(&f, &m, &crop, st, gs, ng);
    for (int j = 0; j <= NST; j++)
        free(d[j]);
    free(sum);
    case_free(&c);
}

/* With refittol the bounds below it are the sums as without, bit for bit,
 * and the others INFINITY (they refit their groups whatever is added):
 * the groups kept are the same.  tol the median of the full bounds. */
static void test_bound_capped_at_tol(void **state)
{
    (void)state;
    bound_case c;
    summed_case(&c);
    star_state *st = c.st, capped[NST];
    memcpy(capped, c.before, sizeof capped);
    paint_rule now = rule(NULL, NAN, 0.0, 1), held = now;
    double b[NST];
    int nb = 0;
    for (int k = 0; k < NST; k++)
        if (st[k].alive && st[k].bound > 0)
            b[nb++] = st[k].bound;
    assert_true(nb >= 4);
    for (int i = 1; i < nb; i++)            /* sorted: the median */
        for (int j = i; j > 0 && b[j - 1] > b[j]; j--) {
            double t = b[j];
            b[j] = b[j - 1];
            b[j - 1] = t;
        }
    double tol = b[nb / 2];
    double ops = 0.0;
    assert_int_equal(ff_update_bounds(&c.f, &c.m, &c.crop, &now, &held, FITRAD, tol, capped, NST,
                                      c.gs, c.ng, &c.gone, 1, &ops), 0);
    int below = 0, above = 0;
    for (int k = 0; k < NST; k++) {
        if (!st[k].alive)
            continue;
        if (st[k].bound < tol) {
            assert_true(memcmp(&st[k].bound, &capped[k].bound, sizeof st[k].bound) == 0);
            below++;
        } else {
            assert_true(isinf(capped[k].bound));
            above++;
        }
    }
    assert_true(below >= 2 && above >= 2);
    case_free(&c);
}

int main(void)
{
    const struct CMUnitTest tests[] = {
        cmocka_unit_test(test_bound_sums_the_changes),
        cmocka_unit_test(test_bound_capped_at_tol),
    };
    return cmocka_run_group_tests(tests, NULL, NULL);
}
