/* frame_bound.c — economy's refit test (issue 5) held as one number a
 * star (issue 14).  A group is kept when the light of the other stars on
 * each member's fitting region has changed by less than refittol in
 * √Σ(Δ/σ)² since its fit.  That change was measured against a copy of the
 * light seen then (a disc of ~80 floats a star, held for every star
 * between rounds: a tenth of a whole frame's memory).  Now each change of
 * a star j's light, Δ_j, adds ‖Δ_j/σ‖ over star k's region to k's bound:
 * by the triangle inequality the sum bounds ‖Σ_j Δ_j/σ‖, the exact test's
 * value, so no fit is kept that the exact test would refit; the price is
 * refits where neighbours' changes cancel. */

#include <limits.h>
#include <math.h>
#include <stdint.h>
#include <stdlib.h>
#include <string.h>
#include "fit/frame_priv.h"

/* Side of the cells the stars are filed in [px]. */
#define CELL 16

/* Changes handled at once: each one's additions are kept until they are
 * added in the changes' order, so the bounds do not depend on threads.
 * Between chunks the bounds that reached refittol close (open_stars): 256
 * rather than 2048 took 47 Tuc with Tiny Tim's table 64.19 → 63.64·10⁹
 * instructions (64: 63.42, but 4 grabs of 16 a chunk for 16 threads). */
#define CHUNK 256

/* Whether a star of flux F is drawn the same way under both rules: from
 * the grid under both, in the same mode, or exactly under both
 * (ff_paint's tests). */
static int same_way(const paint_rule *a, const paint_rule *b, double F)
{
    return (fabs(F) <= a->gemax) == (fabs(F) <= b->gemax) &&
           mp_prf_tier_mode(&a->tiers, F) == mp_prf_tier_mode(&b->tiers, F);
}

/* Whether two rules' tiers are the same limits. */
static int same_tiers(const mp_prf_tiers *a, const mp_prf_tiers *b)
{
    int same = ff_same_value(a->lin, b->lin);
    for (int k = 0; k < MP_PRF_NCORE; k++)
        same = same && ff_same_value(a->core[k], b->core[k]);
    return same;
}

/* Whether the bounds made under rule b hold under rule a: the same grid,
 * and every light they count — each star's as it stands, its old light
 * when it moved, the light of the stars gone — drawn the same way under
 * both flux limits.  The limit follows the frame's median start sky, so
 * it moves a little from round to round (47 Tuc 512²: 5.7e7 → 7.7e7 e⁻
 * between rounds 2 and 3, above its brightest star): the paint is the
 * same then, and every group was refitted for nothing. */
static int same_rule(const paint_rule *a, const paint_rule *b, const star_state *st, size_t n,
                     const star_state *gone, size_t ngone)
{
    if (!a->set || !b->set || a->grid != b->grid)
        return 0;
    if (!a->grid || (ff_same_value(a->gemax, b->gemax) && same_tiers(&a->tiers, &b->tiers)))
        return 1;
    for (size_t k = 0; k < n + ngone; k++) {
        const star_state *s = k < n ? &st[k] : &gone[k - n];
        if ((k < n && !same_way(a, b, s->s.flux)) || (s->olight && !same_way(a, b, s->oflux)))
            return 0;
    }
    return 1;
}

/* The pixels b[0]..b[1] × b[2]..b[3] (1-based) that a paint of s out to
 * rad reaches on the frame (paint_window's box); 0 when none. */
static int paint_box(const mp_frame *f, const mp_prf_model *m, const mp_star *s, double rad,
                     long b[4])
{
    long bx, by;
    int bw, bh;
    mp_prf_box(m, s->x, s->y, &bx, &by, &bw, &bh);
    long c[4] = {bx, bx + bw - 1, by, by + bh - 1};
    if (isfinite(rad)) {
        long a = (long)ceil(s->x - rad), e = (long)floor(s->x + rad);
        long g = (long)ceil(s->y - rad), h = (long)floor(s->y + rad);
        c[0] = a > c[0] ? a : c[0];
        c[1] = e < c[1] ? e : c[1];
        c[2] = g > c[2] ? g : c[2];
        c[3] = h < c[3] ? h : c[3];
    }
    b[0] = c[0] < 1 ? 1 : c[0];
    b[1] = c[1] > f->im.nx ? f->im.nx : c[1];
    b[2] = c[2] < 1 ? 1 : c[2];
    b[3] = c[3] > f->im.ny ? f->im.ny : c[3];
    return b[0] <= b[1] && b[2] <= b[3];
}

/* Σ(d/σ)² over the fitting region of a star at (x, y) (the unmasked
 * pixels within r), d an image on the box b; σ² = max(data, 0) + RON², as
 * the fit weighs them. */
static double norm2_on_disc(const mp_frame *f, const float *d, const long b[4], double x,
                            double y, double r)
{
    long x0 = (long)ceil(x - r), x1 = (long)floor(x + r);
    long y0 = (long)ceil(y - r), y1 = (long)floor(y + r);
    x0 = x0 > b[0] ? x0 : b[0];
    x1 = x1 < b[1] ? x1 : b[1];
    y0 = y0 > b[2] ? y0 : b[2];
    y1 = y1 < b[3] ? y1 : b[3];
    double ron2 = f->rdnoise * f->rdnoise, q = 0.0;
    long w = b[1] - b[0] + 1;
    for (long Y = y0; Y <= y1; Y++)
        for (long X = x0; X <= x1; X++) {
            double dx = X - x, dy = Y - y;
            size_t g = (size_t)(Y - 1) * (size_t)f->im.nx + (size_t)(X - 1);
            if (dx * dx + dy * dy > r * r || (f->mask && f->mask[g]))
                continue;
            double v = (f->im.pix[g] > 0 ? f->im.pix[g] : 0.0) + ron2;
            double dd = d[(Y - b[2]) * w + (X - b[0])];
            q += dd * dd / (v > 1e-2 ? v : 1e-2);
        }
    return q;
}

/* The stars with a finite bound, filed by cells of CELL px: those of cell
 * c are idx[cell0[c] .. cell0[c + 1] − 1], ncx cells a row. */
typedef struct {
    size_t *cell0, *idx;
    long ncx, ncy;
} star_cells;

static long cell_of(double v, long nc)
{
    double c = floor((v - 0.5) / CELL);
    return c < 0 ? 0 : (c >= (double)nc ? nc - 1 : (long)c);
}

static int file_stars(const mp_frame *f, const star_state *st, size_t n, star_cells *C)
{
    C->ncx = (f->im.nx + CELL - 1) / CELL;
    C->ncy = (f->im.ny + CELL - 1) / CELL;
    size_t nc = (size_t)C->ncx * (size_t)C->ncy, cnt = 0;
    C->cell0 = calloc(nc + 1, sizeof *C->cell0);
    for (size_t k = 0; k < n; k++)
        cnt += st[k].alive && isfinite(st[k].bound);
    C->idx = malloc((cnt ? cnt : 1) * sizeof *C->idx);
    size_t *fill = malloc((nc + 1) * sizeof *fill);
    if (!C->cell0 || !C->idx || !fill) {
        free(fill);
        return 1;
    }
    for (size_t k = 0; k < n; k++)
        if (st[k].alive && isfinite(st[k].bound))
            C->cell0[cell_of(st[k].s.y, C->ncy) * C->ncx + cell_of(st[k].s.x, C->ncx) + 1]++;
    for (size_t c = 0; c < nc; c++)
        C->cell0[c + 1] += C->cell0[c];
    memcpy(fill, C->cell0, (nc + 1) * sizeof *fill);
    for (size_t k = 0; k < n; k++)
        if (st[k].alive && isfinite(st[k].bound))
            C->idx[fill[cell_of(st[k].s.y, C->ncy) * C->ncx + cell_of(st[k].s.x, C->ncx)]++] = k;
    free(fill);
    return 0;
}

/* One change of a star's light: from old (when has_old) to now (when
 * has_now); its star's index (n: none) and, when it came from a group's
 * fit, that group's stars [g0, g1) (who saw it). */
typedef struct {
    mp_star old, now;
    int has_old, has_now;
    size_t j, g0, g1;
} light_change;

/* A bound's increment: star k's, by v. */
typedef struct {
    size_t k;
    double v;
} increment;

static light_change change_of(const star_state *s, size_t j, const size_t *gs, size_t ng)
{
    light_change c;
    memset(&c, 0, sizeof c);
    c.now = s->s;
    c.has_now = s->alive && ff_painted(&s->s);
    c.old = s->s;
    c.old.x = s->ox, c.old.y = s->oy, c.old.flux = s->oflux, c.old.sky = s->osky;
    c.has_old = s->olight && ff_painted(&c.old);
    c.j = j;
    c.g0 = c.g1 = 0;
    if (s->moved == MOVED_FIT && ng) {
        size_t lo = 0, hi = ng;       /* the group g with gs[g] <= j < gs[g + 1] */
        while (hi - lo > 1) {
            size_t mid = (lo + hi) / 2;
            *(gs[mid] <= j ? &lo : &hi) = mid;
        }
        c.g0 = gs[lo];
        c.g1 = gs[lo + 1];
    }
    return c;
}

/* The stars of C within r of the box b whose bound is still below tol
 * (not those c's own group fit saw) into *inc, *ninc of them, their v
 * unset.  A star at or above tol refits its group whatever is added
 * (group_kept), so a change that reaches none is not painted (GLIMPSE's
 * last round: the second pass's bounds had a median of 6.6, and their
 * sums were 6 % of its run).  Nonzero when out of memory. */
static int open_stars(const star_state *st, const star_cells *C, const light_change *c,
                      const long b[4], double r, double tol, increment **inc, size_t *ninc)
{
    long cx0 = cell_of(b[0] - r, C->ncx), cx1 = cell_of(b[1] + r, C->ncx);
    long cy0 = cell_of(b[2] - r, C->ncy), cy1 = cell_of(b[3] + r, C->ncy);
    size_t have = 0;
    for (long cy = cy0; cy <= cy1; cy++)
        for (long cx = cx0; cx <= cx1; cx++) {
            size_t cc = (size_t)cy * (size_t)C->ncx + (size_t)cx;
            for (size_t q = C->cell0[cc]; q < C->cell0[cc + 1]; q++) {
                size_t k = C->idx[q];
                if (k == c->j || (k >= c->g0 && k < c->g1) || !(st[k].bound < tol))
                    continue;
                if (*ninc == have) {
                    have = have ? 2 * have : 16;
                    increment *t = realloc(*inc, have * sizeof *t);
                    if (!t)
                        return 1;
                    *inc = t;
                }
                (*inc)[(*ninc)++] = (increment){k, 0.0};
            }
        }
    return 0;
}

/* The box b cut to the pixels within r of the stars inc[0..n-1]
 * (norm2_on_disc's regions): a pixel outside all of them adds to no
 * bound, and each pixel's painted value does not depend on the window it
 * is painted in.  Empty (b[0] > b[1] or b[2] > b[3]) when none reaches. */
static void discs_box(const star_state *st, const increment *inc, size_t n, double r, long b[4])
{
    long u[4] = {LONG_MAX, LONG_MIN, LONG_MAX, LONG_MIN};
    for (size_t q = 0; q < n; q++) {
        const mp_star *s = &st[inc[q].k].s;
        long x0 = (long)ceil(s->x - r), x1 = (long)floor(s->x + r);
        long y0 = (long)ceil(s->y - r), y1 = (long)floor(s->y + r);
        u[0] = x0 < u[0] ? x0 : u[0];
        u[1] = x1 > u[1] ? x1 : u[1];
        u[2] = y0 < u[2] ? y0 : u[2];
        u[3] = y1 > u[3] ? y1 : u[3];
    }
    b[0] = u[0] > b[0] ? u[0] : b[0];
    b[1] = u[1] < b[1] ? u[1] : b[1];
    b[2] = u[2] > b[2] ? u[2] : b[2];
    b[3] = u[3] < b[3] ? u[3] : b[3];
}

/* Paint c's Δ (now − old) on its box; the stars it reaches and by how
 * much into *inc (*ninc of them, allocated).  Nonzero when out of memory. */
static int increments_of(const mp_frame *f, const mp_prf_model *m, const crop_rule *crop,
                         double r, double tol, const star_state *st, const star_cells *C,
                         const light_change *c, mp_prf_work *wk, double **buf, size_t *cap,
                         float **win, size_t *nwin, increment **inc, size_t *ninc)
{
    *inc = NULL;
    *ninc = 0;
    long bo[4], bn[4], b[4];
    double ro = ff_crop_radius(crop, &c->old), rn = ff_crop_radius(crop, &c->now);
    int ho = c->has_old && paint_box(f, m, &c->old, ro, bo);
    int hn = c->has_now && paint_box(f, m, &c->now, rn, bn);
    if (!ho && !hn)
        return 0;
    for (int e = 0; e < 4; e++) {           /* the box of both: min, max, min, max */
        long a = ho ? bo[e] : bn[e], z = hn ? bn[e] : bo[e];
        b[e] = e % 2 ? (a > z ? a : z) : (a < z ? a : z);
    }
    if (open_stars(st, C, c, b, r, tol, inc, ninc))
        return 1;
    if (*ninc == 0)
        return 0;                           /* not painted: no bound it could decide */
    discs_box(st, *inc, *ninc, r, b);
    if (b[0] > b[1] || b[2] > b[3]) {
        *ninc = 0;
        return 0;
    }
    long w = b[1] - b[0] + 1, h = b[3] - b[2] + 1;
    size_t need = (size_t)w * (size_t)h;
    if (need > *nwin) {
        free(*win);
        *nwin = 0;
        if (!(*win = malloc(need * sizeof **win)))
            return 1;
        *nwin = need;
    }
    memset(*win, 0, need * sizeof **win);
    if ((hn && ff_paint(m, &c->now, +1.0, rn, *win, b[0], b[2], w, h, wk, buf, cap, NULL)) ||
        (ho && ff_paint(m, &c->old, -1.0, ro, *win, b[0], b[2], w, h, wk, buf, cap, NULL)))
        return 1;
    size_t kept = 0;                        /* those it reaches, in order */
    for (size_t q = 0; q < *ninc; q++) {
        size_t k = (*inc)[q].k;
        double v = norm2_on_disc(f, *win, b, st[k].s.x, st[k].s.y, r);
        if (v > 0.0)
            (*inc)[kept++] = (increment){k, sqrt(v)};
    }
    *ninc = kept;
    return 0;
}

/* The changes of the stars who[0..nch-1] added to the bounds, CHUNK at a
 * time (who[c] ≥ n: gone[who[c] − n]).  Each change is drawn from its
 * star as it is handled: an array of them held 180 B a star at the whole
 * frame's peak. */
static int add_changes(const mp_frame *f, const mp_prf_model *m, const crop_rule *crop,
                       const paint_rule *now, double r, double tol, star_state *st, size_t n,
                       const size_t *gs, size_t ng, const star_state *gone,
                       const star_cells *C, const size_t *who, size_t nch, double *ops)
{
    increment *inc[CHUNK];
    size_t ninc[CHUNK];
    int nomem = 0;
    double work = 0.0;
    for (size_t c0 = 0; c0 < nch && !nomem; c0 += CHUNK) {
        size_t c1 = nch - c0 < CHUNK ? nch : c0 + CHUNK;
#pragma omp parallel reduction(| : nomem) reduction(+ : work)
        {
            mp_prf_work wk = {0};
            wk.grid = now->grid;
            wk.grid_emax = now->gemax;
            wk.grid_tiers = now->tiers;
            double *buf = NULL;
            float *win = NULL;
            size_t cap = 0, nwin = 0;
#pragma omp for schedule(dynamic, 4)
            for (size_t c = c0; c < c1; c++) {
                size_t j = who[c];
                light_change ch = j < n ? change_of(&st[j], j, gs, ng) : change_of(&gone[j - n], n, gs, 0);
                nomem |= increments_of(f, m, crop, r, tol, st, C, &ch, &wk, &buf, &cap, &win,
                                       &nwin, &inc[c - c0], &ninc[c - c0]);
            }
            free(buf);
            free(win);
            work += wk.ops;
            mp_prf_work_free(&wk);
        }
        for (size_t c = c0; c < c1; c++) {
            for (size_t q = 0; q < ninc[c - c0] && !nomem; q++)
                st[inc[c - c0][q].k].bound += inc[c - c0][q].v;
            free(inc[c - c0]);
        }
    }
    *ops += work;
    return nomem;
}

int ff_update_bounds(const mp_frame *f, const mp_prf_model *m, const crop_rule *crop,
                     const paint_rule *now, paint_rule *held, double r, double tol,
                     star_state *st, size_t n, const size_t *gs, size_t ng,
                     const star_state *gone, size_t ngone, double *ops)
{
    int same = same_rule(now, held, st, n, gone, ngone), any = 0;
    size_t nch = ngone;
    for (size_t k = 0; k < n; k++) {
        if (!same || !(st[k].bound < tol))
            st[k].bound = INFINITY;
        any |= st[k].alive && isfinite(st[k].bound);
        nch += st[k].moved != 0;
    }
    *held = *now;
    held->set = 1;
    size_t *who = any && nch ? malloc(nch * sizeof *who) : NULL;
    star_cells C = {0};
    int rc = any && nch && (!who || file_stars(f, st, n, &C));
    if (!rc && who) {
        size_t q = 0;
        for (size_t k = 0; k < n; k++)
            if (st[k].moved)
                who[q++] = k;
        for (size_t k = 0; k < ngone; k++)
            who[q++] = n + k;
        rc = add_changes(f, m, crop, now, r, tol, st, n, gs, ng, gone, &C, who, nch, ops);
    }
    for (size_t k = 0; k < n; k++) {
        st[k].moved = 0;
        st[k].bound = st[k].bound < tol ? st[k].bound : INFINITY;
    }
    free(who);
    free(C.cell0);
    free(C.idx);
    return rc;
}
