/* lm_normal.c — a group fit's normal equations A = JᵀWJ, g = JᵀW(d − m):
 * the sky block, each star's terms and the star pairs' sums, block-sparse
 * over the windows' overlaps (issue 12). */

#include <math.h>
#include <stddef.h>
#include <stdlib.h>
#include <string.h>
#include "fit/lm_group.h"

/* The weights, the data term and the sky's block of the normal equations,
 * over all fitted pixels. */
static void ne_sky(group *G)
{
    int np = G->np, s0 = 3 * G->n, ns = G->nsky;
    size_t N = G->npix;
    for (size_t o = 0; o < N; o++) {
        double w = 1.0 / G->var[o];
        G->wt[o] = w;
        G->wres[o] = w * (G->dat[o] - G->mod[o]);
    }
    for (int a = 0; a < ns; a++) {
        const double *ca = G->basis + (size_t)a * N;
        double ga = 0.0;
        for (size_t o = 0; o < N; o++)
            ga += ca[o] * G->wres[o];
        G->g[s0 + a] = ga;
        for (int b = a; b < ns; b++) {
            const double *cb = G->basis + (size_t)b * N;
            double s = 0.0;
            for (size_t o = 0; o < N; o++)
                s += G->wt[o] * ca[o] * cb[o];
            G->A[(size_t)(s0 + a) * np + s0 + b] = s;
        }
    }
}

/* One row's star–sky sums in one pass over m pixels (the row read once,
 * not 3 + 3·ns times: star_sky_sums was 6 % of 47 Tuc's CPU) over the
 * star's first nj columns (3, or 1 beyond its derivatives' box, where they
 * are zero): with gq, gq[c] = Σ wr·jk_c; aq[c][b] = Σ (w·jk_c)·cb_b for
 * b < ns (0 for c ≥ nj).  Each sum adds its terms in the order of i, so
 * the values are those of separate loops, bit for bit.  Called with
 * constant nj and ns (sky_row), so the sums stay in registers. */
static inline void row_sky(const double *restrict wr, const double *restrict w,
                           const double *restrict j0, const double *restrict j1,
                           const double *restrict j2, const double *const cb[6], int nj, int ns,
                           int m, double *gq, double aq[3][6])
{
    double g0 = 0, g1 = 0, g2 = 0, q[3][6] = {{0}};
    for (int i = 0; i < m; i++) {
        if (gq) {
            g0 += wr[i] * j0[i];
            if (nj == 3) {
                g1 += wr[i] * j1[i];
                g2 += wr[i] * j2[i];
            }
        }
        double a0 = w[i] * j0[i], a1 = nj == 3 ? w[i] * j1[i] : 0.0;
        double a2 = nj == 3 ? w[i] * j2[i] : 0.0;
        for (int b = 0; b < ns; b++) {
            double c = cb[b][i];
            q[0][b] += a0 * c;
            if (nj == 3) {
                q[1][b] += a1 * c;
                q[2][b] += a2 * c;
            }
        }
    }
    if (gq) {
        gq[0] = g0;
        gq[1] = g1;
        gq[2] = g2;
    }
    for (int c = 0; c < 3; c++)
        for (int b = 0; b < ns; b++)
            aq[c][b] = q[c][b];
}

/* row_sky with nj and ns constants at each call (a sky of order 0, 1, 2
 * has 1, 3, 6 terms; none when the sky is not fitted). */
#define SKY_CASE(NJ, NS)                                                                 \
    case (NJ) * 8 + (NS):                                                                \
        row_sky(wr, w, jk[0], jk[1], jk[2], cb, NJ, NS, m, gq, aq);                      \
        break;
static void sky_row(const double *wr, const double *w, const double *const jk[3],
                    const double *const cb[6], int nj, int ns, int m, double *gq,
                    double aq[3][6])
{
    switch (nj * 8 + ns) {
        SKY_CASE(3, 0) SKY_CASE(3, 1) SKY_CASE(3, 3) SKY_CASE(3, 6)
        SKY_CASE(1, 0) SKY_CASE(1, 1) SKY_CASE(1, 3) SKY_CASE(1, 6)
    default:                /* no other sky today; correct, only slower */
        row_sky(wr, w, jk[0], jk[1], jk[2], cb, nj, ns, m, gq, aq);
        break;
    }
}
#undef SKY_CASE

/* Where star r's derivatives may be nonzero on box row j, within its
 * packed pixels [o, e): [*m0, *m1) (rstar.dp0, dp1). */
static inline void deriv_span(const rstar *r, int j, int o, int e, int *m0, int *m1)
{
    int t = j - r->j0, a = r->dp0[t], b = r->dp1[t];
    *m0 = a < o ? o : a > e ? e : a;
    *m1 = b < *m0 ? *m0 : b > e ? e : b;
}

/* Star r's sums over the fitted pixels of its window within box columns
 * [x0, x1) and rows [y0, y1), added in: with g, its data terms Σ wres·J
 * (unscaled); with a, its coupling with the sky Σ w·J·c_b. */
static void star_sky_sums(const group *G, const rstar *rk, int x0, int x1, int y0, int y1,
                          double g[3], double a[3][6])
{
    int ns = a ? G->nsky : 0, full = x0 <= rk->i0 && x1 >= rk->i1;
    size_t N = G->npix;
    int j0 = rk->j0 > y0 ? rk->j0 : y0, j1 = rk->j1 < y1 ? rk->j1 : y1;
    for (int j = j0; j < j1; j++) {
        int t = j - rk->j0, o = rk->pp[t], e = o + rk->pn[t];
        if (!full) {
            int q0 = packed_at(G, j, x0), q1 = packed_at(G, j, x1);
            o = o > q0 ? o : q0;
            e = e < q1 ? e : q1;
        }
        if (o >= e)
            continue;
        /* the row's parts: [o, m0) and [m1, e) the PRF's alone */
        int cut[4] = {o, 0, 0, e};
        deriv_span(rk, j, o, e, &cut[1], &cut[2]);
        for (int part = 0; part < 3; part++) {
            int s = cut[part], z = cut[part + 1];
            if (s >= z)
                continue;
            size_t u = (size_t)(rk->pb[t] + s - rk->pp[t]);
            const double *jk[3] = {rk->prf + u, rk->dx + u, rk->dy + u}, *cb[6] = {0};
            for (int b = 0; b < ns; b++)
                cb[b] = G->basis + (size_t)b * N + s;
            double gq[3] = {0}, aq[3][6];
            sky_row(G->wres + s, G->wt + s, jk, cb, part == 1 ? 3 : 1, ns, z - s,
                    g ? gq : NULL, aq);
            for (int c = 0; c < 3; c++) {
                if (g)
                    g[c] += gq[c];
                for (int b = 0; b < ns; b++)
                    a[c][b] += aq[c][b];
            }
        }
    }
}

/* One row's sums q[a][b] = Σ_i w_i·jk_a,i·jl_b,i over m pixels, the
 * three columns of each star (PRF, ∂x, ∂y), in one pass: the row's
 * values are read once, not once per sum (pair_sums was 23 % of 47 Tuc's
 * CPU).  Each sum adds its terms in the order of i, each term (w·jk)·jl,
 * so the values are those of nine separate loops, bit for bit. */
static void row_sums(const double *restrict w, const double *restrict k0,
                     const double *restrict k1, const double *restrict k2,
                     const double *restrict l0, const double *restrict l1,
                     const double *restrict l2, int m, double q[3][3])
{
    double q00 = 0, q01 = 0, q02 = 0, q10 = 0, q11 = 0, q12 = 0, q20 = 0, q21 = 0, q22 = 0;
    for (int i = 0; i < m; i++) {
        double a0 = w[i] * k0[i], a1 = w[i] * k1[i], a2 = w[i] * k2[i];
        double b0 = l0[i], b1 = l1[i], b2 = l2[i];
        q00 += a0 * b0;
        q01 += a0 * b1;
        q02 += a0 * b2;
        q10 += a1 * b0;
        q11 += a1 * b1;
        q12 += a1 * b2;
        q20 += a2 * b0;
        q21 += a2 * b1;
        q22 += a2 * b2;
    }
    q[0][0] = q00;
    q[0][1] = q01;
    q[0][2] = q02;
    q[1][0] = q10;
    q[1][1] = q11;
    q[1][2] = q12;
    q[2][0] = q20;
    q[2][1] = q21;
    q[2][2] = q22;
}

/* One row's sums over m pixels of (w·a1)·b and (w·a2)·b into out: a
 * star's derivatives against the other's PRF (or its derivatives) where
 * those are drawn. */
static void row_two(const double *restrict w, const double *restrict a1,
                    const double *restrict a2, const double *restrict b, int m, double out[2])
{
    double s1 = 0, s2 = 0;
    for (int i = 0; i < m; i++) {
        double wb = w[i] * b[i];
        s1 += wb * a1[i];
        s2 += wb * a2[i];
    }
    out[0] = s1;
    out[1] = s2;
}

/* One row's Σ (w_i·a_i)·b_i over m pixels. */
static double row_dot(const double *restrict w, const double *restrict a,
                      const double *restrict b, int m)
{
    double s = 0;
    for (int i = 0; i < m; i++)
        s += w[i] * a[i] * b[i];
    return s;
}

/* The sums of stars k and l on packed pixels [b0, b1) of their rows tk,
 * tl into q: row_sums where both stars' derivatives are drawn on the
 * whole span; else each block of q over where its columns are nonzero
 * (lm_render.c: a star's derivatives drawn on its core box alone) — the
 * PRFs' over the span, k's derivatives against l's PRF over k's box, l's
 * against k's over l's, the derivatives' over both boxes — one call each,
 * not one per piece of the span. */
static void pair_row(const group *G, const rstar *rk, const rstar *rl, int tk, int tl, int b0,
                     int b1, double q[3][3])
{
    int j = rk->j0 + tk, k0, k1, l0, l1;
    deriv_span(rk, j, b0, b1, &k0, &k1);
    deriv_span(rl, j, b0, b1, &l0, &l1);
    /* the span's first pixel in each array (b0 ≥ both rows' starts), the
     * rest by their distance from it */
    size_t u = (size_t)(rk->pb[tk] + b0 - rk->pp[tk]), v = (size_t)(rl->pb[tl] + b0 - rl->pp[tl]);
    const double *w = G->wt + b0, *pk = rk->prf + u, *xk = rk->dx + u, *yk = rk->dy + u;
    const double *pl = rl->prf + v, *xl = rl->dx + v, *yl = rl->dy + v;
    if (k0 == b0 && k1 == b1 && l0 == b0 && l1 == b1) {
        row_sums(w, pk, xk, yk, pl, xl, yl, b1 - b0, q);
        return;
    }
    double t[2];
    memset(q, 0, 9 * sizeof q[0][0]);
    q[0][0] = row_dot(w, pk, pl, b1 - b0);
    int a = k0 - b0, c = l0 - b0;
    if (k0 < k1) {
        row_two(w + a, xk + a, yk + a, pl + a, k1 - k0, t);
        q[1][0] = t[0];
        q[2][0] = t[1];
    }
    if (l0 < l1) {
        row_two(w + c, xl + c, yl + c, pk + c, l1 - l0, t);
        q[0][1] = t[0];
        q[0][2] = t[1];
    }
    int c0 = k0 > l0 ? k0 : l0, c1 = k1 < l1 ? k1 : l1, d = c0 - b0;
    if (c0 < c1) {
        row_two(w + d, xk + d, yk + d, xl + d, c1 - c0, t);
        q[1][1] = t[0];
        q[2][1] = t[1];
        row_two(w + d, xk + d, yk + d, yl + d, c1 - c0, t);
        q[1][2] = t[0];
        q[2][2] = t[1];
    }
}

/* Where the windows of stars k and l meet on box row j: packed pixels
 * [*a0, *a1) (empty when *a0 ≥ *a1), their rows *tk, *tl. */
static void row_overlap(const rstar *rk, const rstar *rl, int j, int *tk, int *tl, int *a0,
                        int *a1)
{
    *tk = j - rk->j0;
    *tl = j - rl->j0;
    int e0 = rk->pp[*tk] + rk->pn[*tk], e1 = rl->pp[*tl] + rl->pn[*tl];
    *a0 = rk->pp[*tk] > rl->pp[*tl] ? rk->pp[*tk] : rl->pp[*tl];
    *a1 = e0 < e1 ? e0 : e1;
}

/* Σ w J_k,a J_l,b over the fitted pixels where the windows of stars k and
 * l meet, within box columns [x0, x1) and rows [y0, y1); s is 3×3, only
 * b ≥ a when k == l.  Nonzero when they meet there at all. */
static int pair_sums(const group *G, const rstar *rk, const rstar *rl, int same, int x0, int x1,
                     int y0, int y1, double s[3][3])
{
    int j0 = rk->j0 > rl->j0 ? rk->j0 : rl->j0, j1 = rk->j1 < rl->j1 ? rk->j1 : rl->j1;
    int c0 = rk->i0 > rl->i0 ? rk->i0 : rl->i0, c1 = rk->i1 < rl->i1 ? rk->i1 : rl->i1;
    int full = x0 <= c0 && x1 >= c1;
    j0 = j0 > y0 ? j0 : y0;
    j1 = j1 < y1 ? j1 : y1;
    memset(s, 0, 9 * sizeof s[0][0]);
    if (j0 >= j1 || c0 >= c1 || x0 >= c1 || x1 <= c0)
        return 0;
    for (int j = j0; j < j1; j++) {
        int tk, tl, a0, a1;
        row_overlap(rk, rl, j, &tk, &tl, &a0, &a1);
        if (!full) {
            int q0 = packed_at(G, j, x0), q1 = packed_at(G, j, x1);
            a0 = a0 > q0 ? a0 : q0;
            a1 = a1 < q1 ? a1 : q1;
        }
        if (a0 >= a1)
            continue;
        double q[3][3];
        pair_row(G, rk, rl, tk, tl, a0, a1, q);
        for (int a = 0; a < 3; a++)
            for (int b = (same ? a : 0); b < 3; b++)
                s[a][b] += q[a][b];
    }
    return 1;
}

/* The core of a pair: the box around both stars' cores when they lie
 * within two core half-widths of each other (else empty, x0 = x1). */
static void pair_core(const group *G, int k, int l, int *x0, int *x1, int *y0, int *y1)
{
    *x0 = G->cx0[k] < G->cx0[l] ? G->cx0[k] : G->cx0[l];
    *x1 = G->cx1[k] > G->cx1[l] ? G->cx1[k] : G->cx1[l];
    *y0 = G->cy0[k] < G->cy0[l] ? G->cy0[k] : G->cy0[l];
    *y1 = G->cy1[k] > G->cy1[l] ? G->cy1[k] : G->cy1[l];
    int span = (int)ceil(4.0 * G->core_hw) + 2;
    if (*x1 - *x0 > span || *y1 - *y0 > span)
        *x1 = *x0;
}

static void put_pair(group *G, const double *p, int k, int l, double s[3][3])
{
    int np = G->np;
    double sk[3] = {1.0, p[3 * k], p[3 * k]}, sl[3] = {1.0, p[3 * l], p[3 * l]};
    for (int a = 0; a < 3; a++)
        for (int b = (l == k ? a : 0); b < 3; b++)
            G->A[(size_t)(3 * k + a) * np + 3 * l + b] = sk[a] * sl[b] * s[a][b];
}

/* Star k's core for the pair and self sums between exact passes: the box
 * within G->core_hw px of where it is at an exact pass. */
static void set_core(group *G, const double *p, int k)
{
    double h = G->core_hw;
    G->cx0[k] = (int)floor(p[3 * k + 1] - h) - (int)G->bx0;
    G->cx1[k] = (int)ceil(p[3 * k + 1] + h) + 1 - (int)G->bx0;
    G->cy0[k] = (int)floor(p[3 * k + 2] - h) - (int)G->by0;
    G->cy1[k] = (int)ceil(p[3 * k + 2] + h) + 1 - (int)G->by0;
}

/* pair_sums over the whole box into s and, in the same pass, over the
 * box columns [x0, x1) and rows [y0, y1) into c: each row's overlap cut
 * at the core's ends, its three parts summed once (not the core twice). */
static int pair_sums_core(const group *G, const rstar *rk, const rstar *rl, int x0, int x1,
                          int y0, int y1, double s[3][3], double c[3][3])
{
    int j0 = rk->j0 > rl->j0 ? rk->j0 : rl->j0, j1 = rk->j1 < rl->j1 ? rk->j1 : rl->j1;
    int c0 = rk->i0 > rl->i0 ? rk->i0 : rl->i0, c1 = rk->i1 < rl->i1 ? rk->i1 : rl->i1;
    memset(s, 0, 9 * sizeof s[0][0]);
    memset(c, 0, 9 * sizeof c[0][0]);
    if (j0 >= j1 || c0 >= c1)
        return 0;
    int core_cols = x0 < c1 && x1 > c0;
    for (int j = j0; j < j1; j++) {
        int tk, tl, a0, a1;
        row_overlap(rk, rl, j, &tk, &tl, &a0, &a1);
        if (a0 >= a1)
            continue;
        /* the row's parts: [a0, m0) outside, [m0, m1) in the core, [m1, a1) */
        int m0 = a1, m1 = a1;
        if (core_cols && j >= y0 && j < y1) {
            m0 = packed_at(G, j, x0);
            m1 = packed_at(G, j, x1);
            m0 = m0 < a0 ? a0 : m0 > a1 ? a1 : m0;
            m1 = m1 < m0 ? m0 : m1 > a1 ? a1 : m1;
        }
        const int cut[4] = {a0, m0, m1, a1};
        for (int part = 0; part < 3; part++) {
            int b0 = cut[part], b1 = cut[part + 1];
            if (b0 >= b1)
                continue;
            double q[3][3];
            pair_row(G, rk, rl, tk, tl, b0, b1, q);
            for (int a = 0; a < 3; a++)
                for (int b = 0; b < 3; b++) {
                    s[a][b] += q[a][b];
                    if (part == 1)
                        c[a][b] += q[a][b];
                }
        }
    }
    return 1;
}

/* *a grown to n values (realloc; left as it was when out of memory);
 * nonzero when out of memory. */
static int grow_ints(int **a, size_t n)
{
    int *q = realloc(*a, n * sizeof *q);
    *a = q ? q : *a;
    return !q;
}

static int grow_doubles(double **a, size_t n)
{
    double *q = realloc(*a, n * sizeof *q);
    *a = q ? q : *a;
    return !q;
}

/* The pair list's room for one more (G->cappair); nonzero when out of
 * memory. */
static int pairs_room(group *G)
{
    if (G->npair < G->cappair)
        return 0;
    size_t cap = G->cappair ? 2 * (size_t)G->cappair : 64;
    int bad = grow_ints(&G->pk, cap) | grow_ints(&G->pl, cap) | grow_doubles(&G->tail, 9 * cap) |
              grow_doubles(&G->pfull, 9 * cap) | grow_doubles(&G->pk2, cap) |
              grow_doubles(&G->ppos, 4 * cap);
    if (bad)
        return 1;
    G->cappair = (int)cap;
    return 0;
}

/* The largest normalised coupling² of stars k and l in A, over their
 * three columns each: A_ka,lb² / (A_ka,ka · A_lb,lb), the squared
 * correlation of the two parameters' estimates were they alone (star_terms
 * set the diagonal before the pairs are summed). */
static double pair_coupling2(const group *G, int k, int l)
{
    int np = G->np;
    double c2 = 0.0;
    for (int a = 0; a < 3; a++)
        for (int b = 0; b < 3; b++) {
            double v = G->A[(size_t)(3 * k + a) * np + 3 * l + b];
            double d = G->A[(size_t)(3 * k + a) * np + 3 * k + a] *
                       G->A[(size_t)(3 * l + b) * np + 3 * l + b];
            c2 = d > 0 && v * v > c2 * d ? v * v / d : c2;
        }
    return c2;
}

/* Pair k < l summed exactly into A when their windows meet, and listed
 * with its sums outside its core in G->tail (when G->core_hw > 0: the
 * cores as set_core fixed them), its whole sums, its coupling and where
 * both stars stood.  Nonzero when out of memory. */
static int pair_exact(group *G, const double *p, const rstar *r, int k, int l)
{
    double s[3][3], c[3][3];
    if (!(G->core_hw > 0)) {
        if (pair_sums(G, &r[k], &r[l], 0, 0, G->bw, 0, G->bh, s))
            put_pair(G, p, k, l, s);
        return 0;
    }
    int x0, x1, y0, y1;
    pair_core(G, k, l, &x0, &x1, &y0, &y1);
    if (!pair_sums_core(G, &r[k], &r[l], x0, x1, y0, y1, s, c))
        return 0;
    put_pair(G, p, k, l, s);
    if (pairs_room(G))
        return 1;
    size_t q = (size_t)G->npair;
    double *t = G->tail + q * 9, *u = G->pfull + q * 9, *x = G->ppos + q * 4;
    for (int a = 0; a < 9; a++) {
        t[a] = s[a / 3][a % 3] - c[a / 3][a % 3];
        u[a] = s[a / 3][a % 3];
    }
    G->pk2[q] = pair_coupling2(G, k, l);
    x[0] = p[3 * k + 1];
    x[1] = p[3 * k + 2];
    x[2] = p[3 * l + 1];
    x[3] = p[3 * l + 2];
    G->pk[q] = k;
    G->pl[G->npair++] = l;
    return 0;
}

/* A pair too weakly coupled to be summed again at a later exact pass of
 * the same fit: its largest normalised coupling² below LM_WEAK_C2 when it
 * was summed, and neither star moved LM_WEAK_MOVE px since.  κ < 0.001:
 * at κ < 0.01 (1e-4) the frozen-wings scene's fit took another path to
 * D's resolution and ended 0.054 σ from the exact one's
 * (test_levmar.c test_weak_pairs_same_fit); 47 Tuc built gained 6 %
 * of its CPU with it, 4 % with this. */
#define LM_WEAK_C2 1e-6
#define LM_WEAK_MOVE 0.1
/* The largest group whose pairs are marked in an n² table of bytes
 * (256 kB); a larger one sums every pair. */
#define LM_KNOWN_MAX 512
static int pair_stays_weak(const group *G, const double *p, int q)
{
    const double *x = G->ppos + (size_t)q * 4;
    int k = G->pk[q], l = G->pl[q];
    return G->pk2[q] < LM_WEAK_C2 && fabs(p[3 * k + 1] - x[0]) < LM_WEAK_MOVE &&
           fabs(p[3 * k + 2] - x[1]) < LM_WEAK_MOVE && fabs(p[3 * l + 1] - x[2]) < LM_WEAK_MOVE &&
           fabs(p[3 * l + 2] - x[3]) < LM_WEAK_MOVE;
}

/* List entry q's whole sums, as its exact pass made them, put into A
 * (its stars' fluxes as they are now). */
static void put_listed(group *G, const double *p, int q)
{
    double s[3][3];
    memcpy(s, G->pfull + (size_t)q * 9, sizeof s);
    put_pair(G, p, G->pk[q], G->pl[q], s);
}

/* List entry q moved to entry m (m ≤ q). */
static void pair_move(group *G, int m, int q)
{
    G->pk[m] = G->pk[q];
    G->pl[m] = G->pl[q];
    G->pk2[m] = G->pk2[q];
    memmove(G->tail + (size_t)m * 9, G->tail + (size_t)q * 9, 9 * sizeof *G->tail);
    memmove(G->pfull + (size_t)m * 9, G->pfull + (size_t)q * 9, 9 * sizeof *G->pfull);
    memmove(G->ppos + (size_t)m * 4, G->ppos + (size_t)q * 4, 4 * sizeof *G->ppos);
}

/* The pairs of the last exact pass that stay weak (pair_stays_weak), both
 * stars open, kept at the list's front with their whole sums put into A
 * as they were; their count.  known[k·n + l] marks them (k < l).  A pair
 * this weak moves a star's variance by a second-order term or by the
 * product of two other couplings (A only steers the steps; the covariance
 * comes from the last exact pass): measured in bench/PROFILE.md. */
static int pairs_kept_weak(group *G, const double *p, unsigned char *known)
{
    int m = 0, n = G->n;
    for (int q = 0; q < G->npair; q++) {
        int k = G->pk[q], l = G->pl[q];
        if (G->settled[k] || G->settled[l] || !pair_stays_weak(G, p, q))
            continue;
        pair_move(G, m, q);
        put_listed(G, p, m++);
        known[(size_t)k * n + l] = 1;
    }
    return m;
}

/* The exact pass's pairs: every pair of open stars whose windows meet,
 * summed — but for the weak pairs a fit's earlier exact pass summed
 * (pairs_kept_weak).  Nonzero when out of memory. */
static int pairs_exact(group *G, const double *p, const rstar *r)
{
    int n = G->n;
    unsigned char *known = G->weak_pairs && G->pairs_known && n <= LM_KNOWN_MAX
                               ? calloc((size_t)n * n, 1)
                               : NULL;
    G->npair = known ? pairs_kept_weak(G, p, known) : 0;
    for (int k = 0; k < n; k++)
        for (int l = k + 1; l < n; l++)
            if (!G->settled[k] && !G->settled[l] && !(known && known[(size_t)k * n + l]) &&
                pair_exact(G, p, r, k, l)) {
                free(known);
                return 1;
            }
    free(known);
    G->pairs_known = 1;
    return 0;
}

/* Between exact passes: each pair's core summed afresh, its tail as the
 * exact pass left it. */
static void pairs_core(group *G, const double *p, const rstar *r)
{
    for (int q = 0; q < G->npair; q++) {
        int k = G->pk[q], l = G->pl[q], x0, x1, y0, y1;
        double s[3][3];
        if (G->settled[k] || G->settled[l])
            continue;
        const double *t = G->tail + (size_t)q * 9;
        pair_core(G, k, l, &x0, &x1, &y0, &y1);
        pair_sums(G, &r[k], &r[l], 0, x0, x1, y0, y1, s);
        for (int a = 0; a < 9; a++)
            s[a / 3][a % 3] += t[a];
        put_pair(G, p, k, l, s);
    }
}

/* The pairs of the last exact pass, their whole sums as it made them (the
 * renders, weights and fluxes unchanged since: NE_REUSE). */
static void pairs_reuse(group *G, const double *p)
{
    for (int q = 0; q < G->npair; q++)
        put_listed(G, p, q);
}

/* After the movers (G->moved) were redrawn (lm_refresh_movers): the
 * other pairs as between exact passes, every pair with a mover summed
 * exactly and listed afresh (its windows may meet others now) — but a
 * weak one (below LM_WEAK_C2 when last summed), kept as between exact
 * passes too: this pass only steers, and the next exact pass sums it
 * again, its star having moved (pair_stays_weak).  Nonzero when out of
 * memory. */
static int pairs_movers(group *G, const double *p, const rstar *r)
{
    int m = 0, n = G->n;
    unsigned char *known = G->weak_pairs && n <= LM_KNOWN_MAX ? calloc((size_t)n * n, 1) : NULL;
    for (int q = 0; q < G->npair; q++) {
        int k = G->pk[q], l = G->pl[q];
        if ((G->moved[k] || G->moved[l]) && !(known && G->pk2[q] < LM_WEAK_C2))
            continue;
        if (known)
            known[(size_t)k * n + l] = 1;
        pair_move(G, m++, q);
    }
    G->npair = m;
    pairs_core(G, p, r);
    int rc = 0;
    for (int k = 0; k < n && !rc; k++)
        for (int l = k + 1; l < n && !rc; l++)
            rc = (G->moved[k] || G->moved[l]) && !G->settled[k] && !G->settled[l] &&
                 !(known && known[(size_t)k * n + l]) && pair_exact(G, p, r, k, l);
    free(known);
    return rc;
}

/* Star k's rows of g and A: its data terms, its coupling with the sky and
 * with itself.  While the wings are frozen (levmar) the couplings are
 * summed over the star's core only between exact passes, the rest (its
 * wings, whose values are frozen: only their weights move) kept from the
 * last exact pass in G->stail (every exact pass keeps it: the wings are
 * frozen right after one); g is summed over the whole window always. */
static void star_terms(group *G, const double *p, const rstar *rk, int k, int exact)
{
    int np = G->np, s0 = 3 * G->n, ns = G->nsky, bw = G->bw, bh = G->bh;
    double gk[3] = {0}, sk[3][6] = {{0}}, ss[3][3], *tl = G->stail + (size_t)k * 27;
    int x0 = G->cx0[k], x1 = G->cx1[k], y0 = G->cy0[k], y1 = G->cy1[k];
    if (exact || !G->frozen) {
        star_sky_sums(G, rk, 0, bw, 0, bh, gk, sk);
        pair_sums(G, rk, rk, 1, 0, bw, 0, bh, ss);
        if (exact && G->freezing) {
            double ck[3][6] = {{0}}, cs[3][3];
            star_sky_sums(G, rk, x0, x1, y0, y1, NULL, ck);
            pair_sums(G, rk, rk, 1, x0, x1, y0, y1, cs);
            for (int a = 0; a < 18; a++)
                tl[a] = sk[a / 6][a % 6] - ck[a / 6][a % 6];
            for (int a = 0; a < 9; a++)
                tl[18 + a] = ss[a / 3][a % 3] - cs[a / 3][a % 3];
        }
    } else {
        star_sky_sums(G, rk, 0, bw, 0, bh, gk, NULL);
        star_sky_sums(G, rk, x0, x1, y0, y1, NULL, sk);
        pair_sums(G, rk, rk, 1, x0, x1, y0, y1, ss);
        for (int a = 0; a < 18; a++)
            sk[a / 6][a % 6] += tl[a];
        for (int a = 0; a < 9; a++)
            ss[a / 3][a % 3] += tl[18 + a];
    }
    double sc[3] = {1.0, p[3 * k], p[3 * k]};
    for (int a = 0; a < 3; a++) {
        G->g[3 * k + a] = sc[a] * gk[a];
        for (int b = 0; b < ns; b++)
            G->A[(size_t)(3 * k + a) * np + s0 + b] = sc[a] * sk[a][b];
    }
    put_pair(G, p, k, k, ss);
}

/* Normal equations A = JᵀWJ and g = JᵀW(d − m) at the current model.
 * Block-sparse (issue 12): a star's columns meet the sky's over its own
 * window and another star's only where their windows overlap, so each
 * pair is summed over its windows' intersection alone, and only over the
 * fitted pixels (packed: contiguous rows, branch-free inner loops).
 * Between the steps of a fit (exact = 0) a pair of stars is summed only
 * over its core — within G->core_hw px of either star, when they lie
 * that close — and keeps its sums over the rest (the stars' far wings,
 * where both are faint and the coupling barely moves with a step) from
 * the last exact pass: A only steers the steps, so the root the fit
 * converges to (g = 0, always exact) does not change, and every fit ends
 * on an exact pass, from which its covariance comes.  In a big group the
 * pairs were most of the work (47 Tuc, 60 stars: 2.1e6 pixel-pairs a pass
 * against 1.1e5 pixels in the stars' windows).  g, the diagonal blocks and
 * the sky's, which set the steps' σ and the bounds, are exact every time.
 * Nonzero when out of memory. */
int lm_normal_equations(group *G, const double *p, const rstar *r, int exact)
{
    /* exact: NE_EXACT, or NE_STEER between steps; NE_STARS (every star's
     * own terms exact, its pairs' as between steps) was tried for the
     * refreshes of frozen wings: 47 Tuc 256² 10 % less CPU, but 51 fits
     * not converged against 21 (the first step after a refresh, steered
     * by stale pair sums, missed tol) */
    int np = G->np, n = G->n;
    memset(G->A, 0, (size_t)np * np * sizeof *G->A);
    memset(G->g, 0, (size_t)np * sizeof *G->g);
    ne_sky(G);
    int reuse = exact == NE_REUSE && G->core_hw > 0;
    int full = exact == NE_EXACT || exact == NE_REUSE || !(G->core_hw > 0);
    int movers = !full && exact == NE_MOVERS;
    for (int k = 0; k < n && G->core_hw > 0; k++)
        if (full || (movers && G->moved[k]))
            set_core(G, p, k);
    for (int k = 0; k < n; k++)
        if (!G->settled[k])
            star_terms(G, p, &r[k], k, full || exact == NE_STARS || (movers && G->moved[k]));
    if (reuse)
        pairs_reuse(G, p);
    else if (full) {
        if (pairs_exact(G, p, r))
            return 1;
    } else if (movers) {
        if (pairs_movers(G, p, r))
            return 1;
    } else
        pairs_core(G, p, r);
    G->ne_exact = full && !G->nsettled;
    for (int a = 0; a < np; a++)           /* mirror the upper triangle */
        for (int b = 0; b < a; b++)
            G->A[(size_t)a * np + b] = G->A[(size_t)b * np + a];
    /* A settled star (lm_settle.c) is held: unit, uncoupled rows, g = 0,
     * so its step is 0. */
    for (int k = 0; k < n; k++)
        if (G->settled[k])
            for (int a = 3 * k; a < 3 * k + 3; a++)
                G->A[(size_t)a * np + a] = 1.0;
    /* Without a fitted sky the sky slot is held fixed: the slot gets a unit,
     * uncoupled row, so the step solves the star block only. */
    if (!G->nsky) {
        int s = 3 * n;
        for (int a = 0; a < np; a++)
            G->A[(size_t)a * np + s] = G->A[(size_t)s * np + a] = 0.0;
        G->A[(size_t)s * np + s] = 1.0;
        G->g[s] = 0.0;
    }
    return 0;
}
