/* sirt.c — one step of the table's reconstruction (build.h): each used
 * star's residual per unit flux, back-projected onto the table grid by
 * the transpose of the fit's render (fit/prf.c mp_prf_adjoint: pixel p
 * holds Σ_s S_δ(T)[os(p−1) + s + n0], S_δ the damped sinc shift by δ,
 * whose transpose is the shift by −δ), then combined over the stars element by
 * element: a weighted fit of the polynomial in position, clipped at 4
 * robust σ (the robust mean of Anderson & King 2000, §4).  The stars'
 * passes and the elements' combination run in parallel; each writes its
 * own star's or element's share, and χ² is summed star by star in order,
 * so the table does not depend on the number of threads. */
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include "psf/build_priv.h"

int mp_epsf_sirt_init(mp_epsf_sirt *w, const mp_epsf *e, size_t nstar, char *err)
{
    memset(w, 0, sizeof *w);
    w->nstar = nstar;
    w->nel = (size_t)e->nx * e->ny;
    w->nR = (size_t)(e->nx / e->os + 2) * (size_t)(e->ny / e->os + 2);
    w->G = malloc(nstar * w->nel * sizeof *w->G);
    w->H = malloc(nstar * w->nel * sizeof *w->H);
    w->R = malloc(nstar * w->nR * sizeof *w->R);
    w->W = malloc(nstar * w->nR * sizeof *w->W);
    w->noise_drop = NAN;
    w->geo = malloc(6 * (nstar + 1) * sizeof *w->geo);
    w->chi2s = malloc((nstar + 1) * sizeof *w->chi2s);
    w->npix = malloc((nstar + 1) * sizeof *w->npix);
    w->axes = calloc(nstar + 1, sizeof *w->axes);
    w->tmp = malloc(w->nel * sizeof *w->tmp);
    w->mask = calloc(nstar * w->nel + 1, 1);
    if (!w->G || !w->H || !w->R || !w->W || !w->geo || !w->chi2s || !w->npix || !w->axes ||
        !w->tmp || !w->mask) {
        mp_epsf_sirt_free(w);
        snprintf(err, MP_ERRLEN, "psf build: out of memory");
        return 1;
    }
    return 0;
}

void mp_epsf_sirt_free(mp_epsf_sirt *w)
{
    free(w->G);
    free(w->H);
    free(w->R);
    free(w->W);
    free(w->Rn);
    free(w->geo);
    free(w->chi2s);
    free(w->npix);
    for (size_t k = 0; w->axes && k < w->nstar; k++) {
        mp_prf_work own = {0};
        own.axes = w->axes[k];
        mp_prf_work_free(&own);
    }
    free(w->axes);
    free(w->tmp);
    free(w->mask);
    memset(w, 0, sizeof *w);
}

/* A thread's scratch for its stars: the table at a star's place, the
 * star's box and a render's work. */
typedef struct {
    mp_psf tab;
    int tab0;              /* tab holds the pass's order-0 table (the same
                            * at every star's place: drawn once) */
    double *prf;
    size_t nprf;
    double *g;             /* a star's G in doubles (mp_prf_adjoint's) */
    mp_prf_work pw;
} scratch;

static void scratch_free(scratch *c)
{
    mp_psf_free(&c->tab);
    free(c->prf);
    free(c->g);
    mp_prf_work_free(&c->pw);
}

/* Where the fit's render puts a star at x (cut-out coordinates) on the
 * table's axis of n elements: fine cell g = os(p−1)+s holds S[g + n0],
 * S the table shifted by δ (fit/prf.c, table_axis). */
static void axis_of(int n, int os, double x, long *n0, double *delta)
{
    double c0 = (n - 1) / 2 + 0.5 + os * (0.5 - x);
    *n0 = lround(c0);
    *delta = c0 - (double)*n0;
}

/* W added to the os × os elements of H (nx × ny) a pixel is drawn from,
 * (mx0, my0) its first (the unshifted axes: H only normalises). */
static inline void add_weight(float *H, int nx, int ny, int os, long mx0, long my0, double W)
{
    for (int sy = 0; sy < os; sy++) {
        long my = my0 + sy;
        if (my < 0 || my >= ny)
            continue;
        for (int sx = 0; sx < os; sx++) {
            long mx = mx0 + sx;
            if (mx >= 0 && mx < nx)
                H[(size_t)my * nx + mx] += (float)W;
        }
    }
}

/* One star: R = W ρ on its box (ρ the residual per unit flux, W = F²/σ²
 * its information; zero where masked or beyond psfrad) and its box in
 * geo, H = Aᵀ W (the weight each element gets, unshifted: it only
 * normalises), Σ r²/σ² into *chi2.  G = Aᵀ W ρ (projected, below) waits
 * until a step is taken: the pass that ends a run is read only for its
 * χ².  1 when out of memory. */
static int backproject(scratch *w, const mp_epsf_star *s, const mp_epsf *e, double psfrad,
                       double *R, double *Wp, double *geo, float *H, double *chi2,
                       double *npix)
{
    char err[MP_ERRLEN];
    if (!(w->tab0 && e->nterms == 1) && mp_epsf_table(e, s->x, s->y, &w->tab, err))
        return 1;
    w->tab0 = e->nterms == 1;
    mp_prf_model m = {&w->tab, NULL, 10};
    double xs = s->x - (double)(s->x0 - 1), ys = s->y - (double)(s->y0 - 1);
    long bx0, by0;
    int bw, bh;
    mp_prf_box(&m, xs, ys, &bx0, &by0, &bw, &bh);
    size_t nb = (size_t)bw * bh;       /* ≤ nR: a box is ≤ n/os + 2 a side */
    if (nb > w->nprf) {
        free(w->prf);
        if (!(w->prf = malloc(nb * sizeof *w->prf))) {
            w->nprf = 0;
            return 1;
        }
        w->nprf = nb;
    }
    if (mp_prf_render(&m, xs, ys, w->prf, NULL, NULL, &w->pw))
        return 1;
    int os = e->os, nx = e->nx, ny = e->ny;
    long n0x, n0y;
    double dx, dy;
    axis_of(nx, os, xs, &n0x, &dx);
    axis_of(ny, os, ys, &n0y, &dy);
    const double g[6] = {(double)bx0, (double)by0, bw, bh, xs, ys};
    memcpy(geo, g, sizeof g);
    size_t nel = (size_t)nx * ny;
    memset(R, 0, nb * sizeof *R);
    memset(Wp, 0, nb * sizeof *Wp);
    memset(H, 0, nel * sizeof *H);
    *chi2 = 0.0;
    *npix = 0.0;
    const mp_frame *f = &s->f;
    double ron2 = fmax(f->rdnoise * f->rdnoise, 1e-2), F = s->flux, sky = fmax(s->sky, 0.0);
    for (int j = 0; j < bh; j++) {
        long py = by0 + j;
        if (py < 1 || py > f->im.ny)
            continue;
        for (int i = 0; i < bw; i++) {
            long px = bx0 + i;
            if (px < 1 || px > f->im.nx)
                continue;
            size_t o = (size_t)(py - 1) * f->im.nx + (size_t)(px - 1);
            if (f->mask[o] || (px - xs) * (px - xs) + (py - ys) * (py - ys) > psfrad * psfrad)
                continue;
            double mod = F * w->prf[(size_t)j * bw + i];
            double r = f->im.pix[o] - s->sky - mod;
            double var = fmax(mod + sky, sky) + ron2;
            double W = F * F / var, rho = r / F;
            *chi2 += r * r / var;
            R[(size_t)j * bw + i] = W * rho;
            Wp[(size_t)j * bw + i] = W;
            *npix += 1.0;
            add_weight(H, nx, ny, os, os * (px - 1) + n0x, os * (py - 1) + n0y, W);
        }
    }
    return 0;
}

/* G = Aᵀ W ρ: the render's transpose applied to the star's R
 * (mp_prf_adjoint: each pixel spread back over the elements it is drawn
 * from, with the damped sinc's weights; a fifth of the work of spreading
 * it over its block and shifting the whole table back, at ×4). */
static int projected(scratch *w, const mp_epsf *e, const double *R, const double *geo, float *G)
{
    mp_psf geom = {.kind = MP_PSF_TABLE, .nx = e->nx, .ny = e->ny, .os = e->os, .sum = 1.0};
    mp_prf_model m = {&geom, NULL, 10};
    size_t nel = (size_t)e->nx * e->ny;
    if (!w->g && !(w->g = malloc(nel * sizeof *w->g)))
        return 1;
    if (mp_prf_adjoint(&m, geo[4], geo[5], (long)geo[0], (long)geo[1], (int)geo[2], (int)geo[3],
                       R, w->g, &w->pw))
        return 1;
    for (size_t i = 0; i < nel; i++)
        G[i] = (float)w->g[i];
    return 0;
}

/* The used stars' back-projections (backproject; with project, G from
 * their R: projected), in parallel, each star's render operators (w->axes,
 * kept through the run) lent to the thread's work for its turn; 1 when
 * out of memory. */
static int stars_pass(mp_epsf_sirt *w, const mp_epsf_star *s, size_t n, const mp_epsf *e,
                      double psfrad, int project)
{
    size_t nel = w->nel;
    int failed = 0;
#pragma omp parallel reduction(| : failed)
    {
        scratch c;
        memset(&c, 0, sizeof c);
        c.pw.single = 1;        /* χ² to 1 is all a step needs (fit/prf_axis.h) */
#pragma omp for schedule(dynamic)
        for (size_t k = 0; k < n; k++) {
            if (failed || !s[k].used)
                continue;
            c.pw.axes = w->axes[k];
            if (project)
                failed = projected(&c, e, w->R + k * w->nR, w->geo + 6 * k, w->G + k * nel);
            else
                failed = backproject(&c, &s[k], e, psfrad, w->R + k * w->nR, w->W + k * w->nR,
                                     w->geo + 6 * k, w->H + k * nel, &w->chi2s[k],
                                     &w->npix[k]);
            w->axes[k] = c.pw.axes;
            c.pw.axes = NULL;
        }
        scratch_free(&c);
    }
    return failed;
}

/* One block of elements as the combination reads it: the used stars
 * us[0..m) (their indices in s, ascending) and, element-major, the H, G
 * and mask of star us[q] at the block's element i at [i·m + q].  Each
 * star's row of the block is read once (elements_block), not each
 * element's column of stars, whose reads lie nel floats apart: they
 * stalled the combination, 6 % of 47 Tuc built's run. */
typedef struct {
    size_t *us, m;
    float *h, *g;
    unsigned char *mk;
} elem_block;

/* The block of elements [e0, e0 + nb) of b's stars (b->us, set once a
 * step: the used ones) into b (room for them × nb elements). */
static void elements_block(const mp_epsf_sirt *w, size_t e0, size_t nb, elem_block *b)
{
    size_t nel = w->nel, m = b->m;
    for (size_t q = 0; q < m; q++) {
        const float *H = w->H + b->us[q] * nel + e0, *G = w->G + b->us[q] * nel + e0;
        const unsigned char *M = w->mask + b->us[q] * nel + e0;
        for (size_t i = 0; i < nb; i++) {
            b->h[i * m + q] = H[i];
            b->g[i * m + q] = G[i];
            b->mk[i * m + q] = M[i];
        }
    }
}

/* Weighted least squares of g_k = G_k/H_k on the terms over the stars
 * idx[0..m) of an element's h, g (elem_block's us for their terms),
 * weights H_k; c receives the nterms coefficients. */
static int wls(const float *h, const float *g, const size_t *us, const size_t *idx, size_t m,
               const double *terms, int nt, double ridge, double *c)
{
    double A[MP_EPSF_MAXT * MP_EPSF_MAXT] = {0};
    for (int t = 0; t < nt; t++)
        c[t] = 0.0;
    for (size_t q = 0; q < m; q++) {
        double hq = h[idx[q]], G = g[idx[q]];
        const double *tk = terms + us[idx[q]] * MP_EPSF_MAXT;
        for (int a = 0; a < nt; a++) {
            c[a] += tk[a] * G;
            for (int b = 0; b <= a; b++)
                A[a * nt + b] += hq * tk[a] * tk[b];
        }
    }
    /* Marquardt's damping of the diagonal, and a floor (1e-9 of the
     * best-measured element's weight) that keeps an element few pixels
     * reach solvable; neither moves the fixed point, only the step. */
    for (int a = 0; a < nt; a++) {
        A[a * nt + a] *= 1.0 + 1e-3;
        A[a * nt + a] += ridge;
        for (int b = a + 1; b < nt; b++)
            A[a * nt + b] = A[b * nt + a];
    }
    return mp_epsf_solve(A, c, nt);
}

/* A star's deviation from the fit c at an element, in its σ: its h and g
 * there, its terms tk. */
static inline double deviation(double h, double g, const double *tk, int nt, const double *c)
{
    double mod = 0;
    for (int t = 0; t < nt; t++)
        mod += tk[t] * c[t];
    return fabs(g / h - mod) * sqrt(h);
}

/* Whether no deviation (the largest, dmax) can pass the clip at 4 robust
 * σ, σ = 1.4826 × the median of dev[0..m), without selecting it: the
 * median is at least t when more than half the deviations are, and t is
 * set so that 4 × 1.4826 × t ≥ dmax in the clip's own arithmetic.  Most
 * elements clip nothing, and the selection was 6 % of a simulated
 * frame's run with its PSF built. */
static int within_clip(const double *dev, size_t m, double dmax)
{
    double t = dmax / (4.0 * 1.4826) * (1.0 + 1e-12);
    if (!(4.0 * (1.4826 * t) >= dmax) || !(t > 0))
        return 0;
    size_t above = 0;
    for (size_t q = 0; q < m; q++)
        above += dev[q] >= t;
    return above >= m / 2 + 1;
}

/* Whether a used star the mask left out deviates by more than dmax at
 * the block's element i (within_clip's bound holds for the flags then
 * too); all: every star's deviation there (all_deviations). */
static int masked_above(const elem_block *b, size_t i, const double *all, double dmax)
{
    const float *h = b->h + i * b->m;
    const unsigned char *mk = b->mk + i * b->m;
    for (size_t q = 0; q < b->m; q++)
        if (h[q] > 0 && (mk[q] & MP_EPSF_MASKED) && !(all[q] <= dmax))
            return 1;
    return 0;
}

/* The order-0 solution from an element's Σg and Σh, in wls's arithmetic
 * bit for bit: Marquardt's factor and the ridge, and the 1×1 Cholesky's
 * two divisions by √A; *c Σg, and 1 returned, when A is not positive (as
 * wls leaves it).  wls0's and combine_few's. */
static int solve0(double sg, double sh, double ridge, double *c)
{
    *c = sg;
    double a = sh * (1.0 + 1e-3);
    a += ridge;
    if (!(a > 0))
        return 1;
    a = sqrt(a);
    *c = sg / a / a;
    return 0;
}

/* wls of the order-0 table (one term, 1 at every star) in its own
 * arithmetic, bit for bit: Σg and Σh over the stars the mask leaves, in
 * their order (a star left out adds +0, which no such sum can tell: it
 * is never −0), Marquardt's factor and the ridge, and the 1×1 Cholesky's
 * two divisions by √A.  The stars it leaves into idx[0..*m), with no
 * branch on them.  1 when A is not positive,
 * c then Σg as wls leaves it. */
static int wls0(const float *h, const float *g, const unsigned char *mk, size_t n,
                double ridge, size_t *idx, size_t *m, double *c)
{
    double sg = 0.0, sh = 0.0;
    size_t k = 0;
    for (size_t q = 0; q < n; q++) {
        int in = h[q] > 0 && !(mk[q] & MP_EPSF_MASKED);
        idx[k] = q;
        k += (size_t)in;
        sg += in ? (double)g[q] : 0.0;
        sh += in ? (double)h[q] : 0.0;
    }
    *m = k;
    c[0] = sg;
    return k == 0 ? 0 : solve0(sg, sh, ridge, c);
}

/* Every star's deviation from the fit c at the block's element i
 * (deviation), into all[0..b->m): one dense pass the compiler
 * vectorises, read through the kept stars' indices after. */
static void all_deviations(const elem_block *b, size_t i, const double *terms, int nt,
                           const double *c, double *restrict all)
{
    const float *h = b->h + i * b->m, *g = b->g + i * b->m;
    if (nt == 1) {           /* deviation's value: |·| makes a zero c's sign moot */
        double c0 = c[0];
        for (size_t q = 0; q < b->m; q++)
            all[q] = fabs((double)g[q] / (double)h[q] - c0) * sqrt((double)h[q]);
        return;
    }
    for (size_t q = 0; q < b->m; q++)
        all[q] = deviation(h[q], g[q], terms + b->us[q] * MP_EPSF_MAXT, nt, c);
}

/* The update of element el, the block's element i, robust: fit (leaving
 * out the stars whose mask says a neighbour is there), clip at 4 robust
 * σ, fit again.  With flag, every star whose deviation is above 4 σ is
 * marked MP_EPSF_HIT in w->mask (mp_epsf_sirt_dilate makes the next
 * step's mask of it). */
static void combine_element(mp_epsf_sirt *w, size_t el, const elem_block *b, size_t i,
                            const double *terms, int nt, size_t *idx, double *dev, double *c,
                            int flag)
{
    const float *h = b->h + i * b->m, *g = b->g + i * b->m;
    const unsigned char *mk = b->mk + i * b->m;
    double *all = dev + 2 * b->m;
    size_t m = 0;
    for (int t = 0; t < nt; t++)
        c[t] = 0.0;
    if (nt == 1) {
        if (wls0(h, g, mk, b->m, w->ridge, idx, &m, c) || m == 0)
            return;
    } else {
        for (size_t q = 0; q < b->m; q++)
            if (h[q] > 0 && !(mk[q] & MP_EPSF_MASKED))
                idx[m++] = q;
        if (m < (size_t)nt || wls(h, g, b->us, idx, m, terms, nt, w->ridge, c))
            return;
    }
    if (m < 5)
        return;
    all_deviations(b, i, terms, nt, c, all);
    double dmax = 0.0;
    for (size_t q = 0; q < m; q++) {
        dev[q] = all[idx[q]];
        dmax = dev[q] > dmax || isnan(dev[q]) ? dev[q] : dmax;
    }
    if (within_clip(dev, m, dmax) && !(flag && masked_above(b, i, all, dmax)))
        return;
    double *tmp = dev + b->m;
    memcpy(tmp, dev, m * sizeof *dev);
    double sig = 1.4826 * mp_median_select(tmp, m);
    if (!(sig > 0))
        return;
    for (size_t q = 0; flag && q < b->m; q++)
        if (h[q] > 0 && all[q] > 4.0 * sig)
            w->mask[b->us[q] * w->nel + el] |= MP_EPSF_HIT;
    size_t kept = 0;
    for (size_t q = 0; q < m; q++)
        if (dev[q] <= 4.0 * sig)
            idx[kept++] = idx[q];
    if (kept == m || kept < (size_t)nt)
        return;
    if (wls(h, g, b->us, idx, kept, terms, nt, w->ridge, c))
        for (int t = 0; t < nt; t++)
            c[t] = 0.0;
}

/* The update filtered by the kernel whose transfer vanishes at k/os
 * cycles per element (k = 1..os−1): the os-element box (odd os), or for
 * even os the box convolved with [½, ½] so that it is centred
 * (os = 4: ½ 1 1 1 ½, /4).  Those are the frequencies that block-summing
 * to detector pixels cannot see: however unevenly the stars sample the
 * phases (the per-element weights then vary with period os), no step
 * adds what the data cannot constrain — the dotted, multi-peaked tables
 * of anchors.md §3.2 — while everything the pixels see is still fitted. */
static void null_filter(double *u, int nx, int ny, int os, double *tmp)
{
    if (os < 2)
        return;
    double k[9];
    int h = os / 2;
    for (int i = -h; i <= h; i++)
        k[i + h] = (os % 2 == 0 && (i == -h || i == h)) ? 0.5 / os : 1.0 / os;
    for (int pass = 0; pass < 2; pass++) {
        const double *src = pass ? tmp : u;
        double *dst = pass ? u : tmp;
        for (int j = 0; j < ny; j++)
            for (int i = 0; i < nx; i++) {
                double v = 0;
                for (int q = -h; q <= h; q++) {
                    int a = pass ? j + q : i + q;
                    if (a < 0 || a >= (pass ? ny : nx))
                        continue;
                    v += k[q + h] * (pass ? src[(size_t)a * nx + i] : src[(size_t)j * nx + a]);
                }
                dst[(size_t)j * nx + i] = v;
            }
    }
}

/* Elements a block of the combination holds (elem_block). */
#define ELEM_BLOCK 64

/* Fewer used stars than an element's clip needs (combine_element: 5): each
 * element's order-0 update is wls0's, nothing clipped.  Summed here a row
 * of elements at a time, star by star in their order (the same sums,
 * solved by solve0 as wls0 solves them, bit for bit), where the blocks' transposes and the
 * per-element calls were 11 % of the DECam cutout's run with its four PSF
 * stars. */
static int combine_few(const mp_epsf_sirt *w, const mp_epsf_star *s, size_t n,
                       const mp_epsf *e, double rmax, double *upd)
{
    int nx = e->nx, failed = 0;
#pragma omp parallel reduction(| : failed)
    {
        double *sg = malloc(3 * (size_t)nx * sizeof *sg), *sh = sg ? sg + nx : NULL;
        double *cnt = sg ? sg + 2 * (size_t)nx : NULL;
        failed = !sg;
#pragma omp for schedule(static)
        for (int y = 0; y < e->ny; y++) {
            size_t r0 = (size_t)y * nx;
            if (!sg)
                continue;
            for (int x = 0; x < nx; x++)
                sg[x] = sh[x] = cnt[x] = 0.0;
            for (size_t k = 0; k < n; k++) {
                if (!s[k].used)
                    continue;
                const float *H = w->H + k * w->nel + r0, *G = w->G + k * w->nel + r0;
                const unsigned char *M = w->mask + k * w->nel + r0;
                for (int x = 0; x < nx; x++) {
                    int in = H[x] > 0 && !(M[x] & MP_EPSF_MASKED);
                    sg[x] += in ? (double)G[x] : 0.0;
                    sh[x] += in ? (double)H[x] : 0.0;
                    cnt[x] += in;
                }
            }
            for (int x = 0; x < nx; x++) {
                double dx = x - (nx - 1) / 2, dy = y - (e->ny - 1) / 2;
                if (mp_within(dx, dy, rmax) && cnt[x] > 0)
                    solve0(sg[x], sh[x], w->ridge, &upd[r0 + x]);
            }
        }
        free(sg);
    }
    return failed;
}

/* The step's update upd (nterms planes) of every element within rmax of
 * the centre (combine_element; the stars' hits flagged beyond rcore), in
 * parallel by blocks of elements, and the ridge it is solved with; 1 when
 * out of memory. */
static int combine_elements(mp_epsf_sirt *w, const mp_epsf_star *s, size_t n, const mp_epsf *e,
                            const double *terms, double rmax, double rcore, int hits, double *upd)
{
    size_t nel = w->nel, nblk = (nel + ELEM_BLOCK - 1) / ELEM_BLOCK;
    int nt = e->nterms, failed = 0;
    double hmax = 0;
    /* each element's weight summed over the used stars in their order,
     * a block's stars row by row */
#pragma omp parallel for schedule(static) reduction(max : hmax)
    for (size_t bk = 0; bk < nblk; bk++) {
        size_t e0 = bk * ELEM_BLOCK, nb = nel - e0 < ELEM_BLOCK ? nel - e0 : ELEM_BLOCK;
        double h[ELEM_BLOCK] = {0};
        for (size_t k = 0; k < n; k++)
            if (s[k].used)
                for (size_t i = 0; i < nb; i++)
                    h[i] += w->H[k * nel + e0 + i];
        for (size_t i = 0; i < nb; i++)
            hmax = h[i] > hmax ? h[i] : hmax;
    }
    w->ridge = 1e-9 * hmax;
    memset(upd, 0, (size_t)nt * nel * sizeof *upd);
    size_t nused = 0;
    for (size_t k = 0; k < n; k++)
        nused += s[k].used != 0;
    if (nt == 1 && nused < 5 && !w->per_element)
        return combine_few(w, s, n, e, rmax, upd);
#pragma omp parallel reduction(| : failed)
    {
        double *dev = malloc(3 * (n + 1) * sizeof *dev);
        size_t *idx = malloc((n + 1) * sizeof *idx);
        elem_block b = {malloc((n + 1) * sizeof *b.us), 0,
                        malloc((n + 1) * ELEM_BLOCK * sizeof *b.h),
                        malloc((n + 1) * ELEM_BLOCK * sizeof *b.g),
                        malloc((n + 1) * ELEM_BLOCK)};
        failed = !dev || !idx || !b.us || !b.h || !b.g || !b.mk;
        for (size_t k = 0; !failed && k < n; k++)
            if (s[k].used)
                b.us[b.m++] = k;
#pragma omp for schedule(dynamic, 1)
        for (size_t bk = 0; bk < nblk; bk++) {
            size_t e0 = bk * ELEM_BLOCK, nb = nel - e0 < ELEM_BLOCK ? nel - e0 : ELEM_BLOCK;
            if (failed)
                continue;
            elements_block(w, e0, nb, &b);
            for (size_t i = 0; i < nb; i++) {
                size_t el = e0 + i;
                int x = (int)(el % (size_t)e->nx), y = (int)(el / (size_t)e->nx);
                double dx = x - (e->nx - 1) / 2, dy = y - (e->ny - 1) / 2;
                if (!mp_within(dx, dy, rmax))
                    continue;
                double c[MP_EPSF_MAXT];
                combine_element(w, el, &b, i, terms, nt, idx, dev, c,
                                hits && !mp_within(dx, dy, rcore));
                for (int t = 0; t < nt; t++)
                    upd[(size_t)t * nel + el] = c[t];
            }
        }
        free(dev);
        free(idx);
        free(b.us);
        free(b.h);
        free(b.g);
        free(b.mk);
    }
    return failed;
}

/* A run's constants (mp_epsf_sirt_run, mp_epsf_sirt_noise): each star's
 * polynomial terms, room for a step's update, the disc of elements a step
 * moves (rmax, in elements; those beyond are zeroed) and how many values
 * it holds, the core within which no hit is flagged, the step size. */
typedef struct {
    double *terms, *upd;
    double rmax, rcore, nfree, step;
} run_consts;

static void run_end(run_consts *c)
{
    free(c->terms);
    free(c->upd);
}

/* Whether element (i, j) of e lies on the disc of radius rmax elements
 * about the table's centre. */
static int on_disc(const mp_epsf *e, int i, int j, double rmax)
{
    return hypot(i - (e->nx - 1) / 2, j - (e->ny - 1) / 2) <= rmax;
}

/* run_consts of a run on e's planes, e as it is (mp_epsf_sirt_floor: a
 * round's floor leaves the table alone); 1 with err when out of
 * memory. */
static int run_consts_of(const mp_epsf_star *s, size_t n, const mp_epsf_opts *o,
                         const mp_epsf *e, run_consts *c, char *err)
{
    int nt = e->nterms;
    size_t nel = (size_t)e->nx * e->ny;
    c->terms = malloc(n * MP_EPSF_MAXT * sizeof *c->terms);
    c->upd = malloc((size_t)nt * nel * sizeof *c->upd);
    if (!c->terms || !c->upd) {
        run_end(c);
        snprintf(err, MP_ERRLEN, "psf build: out of memory");
        return 1;
    }
    for (size_t k = 0; k < n; k++)
        mp_epsf_terms(e, s[k].x, s[k].y, c->terms + k * MP_EPSF_MAXT);
    /* Elements beyond psfrad (less the half pixel a block reaches) hold
     * nothing: the table is defined on the disc its stars' pixels cover,
     * the light beyond is PSFSUM's (growth.c); so do those beyond the
     * support (mp_epsf_opts), which mp_epsf_normalise zeroes. */
    c->rmax = (o->psfrad - 0.5) * e->os;
    if (o->support > 0 && o->support * e->os < c->rmax)
        c->rmax = o->support * e->os;
    /* Neighbours are masked beyond the core only: within a FWHM every
     * star's own fit (its centre's error) varies from star to star. */
    c->rcore = o->fwhm * e->os;
    c->nfree = 0.0;
    for (int j = 0; j < e->ny; j++)
        for (int i = 0; i < e->nx; i++)
            c->nfree += on_disc(e, i, j, c->rmax) ? nt : 0;
    c->step = 1.0 / ((double)e->os * e->os);
    return 0;
}

/* run_consts of a run on e's planes, its elements beyond rmax zeroed. */
static int run_start(const mp_epsf_star *s, size_t n, const mp_epsf_opts *o, mp_epsf *e,
                     run_consts *c, char *err)
{
    if (run_consts_of(s, n, o, e, c, err))
        return 1;
    size_t nel = (size_t)e->nx * e->ny;
    for (int j = 0; j < e->ny; j++)
        for (int i = 0; i < e->nx; i++)
            if (!on_disc(e, i, j, c->rmax))
                for (int t = 0; t < e->nterms; t++)
                    e->planes[(size_t)t * nel + (size_t)j * e->nx + i] = 0.0;
    return 0;
}

/* A step's update into c->upd from the stars' G (their residuals
 * projected): the clipped combination (hits: flag the stars above the
 * clip for the next step's mask) and the null filter, the same for the
 * data's steps and noise_drop's draw.  1 when out of memory. */
static int step_update(mp_epsf_sirt *w, const mp_epsf_star *s, size_t n, const mp_epsf *e,
                       const run_consts *c, int hits)
{
    if (combine_elements(w, s, n, e, c->terms, c->rmax, c->rcore, hits, c->upd))
        return 1;
    for (int t = 0; t < e->nterms; t++)
        null_filter(c->upd + (size_t)t * w->nel, e->nx, e->ny, e->os, w->tmp);
    return 0;
}

/* The χ² drop a step takes from pure noise, into w->noise_drop: the
 * step (the stars' back-projection, the clipped combination, the null
 * filter) made from a draw of noise on the stars' weights, and the drop
 * 2s⟨Rn, A u⟩ − s²‖A u‖²_W that step u of size s makes on that draw.  A
 * step whose drop on the data is no larger fits only noise: its
 * direction is made from the data, so it lowers χ² by more than the one
 * a single parameter fitted to noise would.  1 when out of memory. */
static int noise_drop(mp_epsf_sirt *w, const mp_epsf_star *s, size_t n, const mp_epsf *e,
                      const run_consts *c)
{
    if (!w->Rn && !(w->Rn = malloc(w->nstar * w->nR * sizeof *w->Rn)))
        return 1;
    mp_epsf_sirt_noise_draw(w, s, n);
    double *R = w->R;
    w->R = w->Rn;
    int failed = stars_pass(w, s, n, e, 0.0, 1);
    w->R = R;
    if (failed || step_update(w, s, n, e, c, 0))
        return 1;
    mp_epsf eu = *e;
    eu.planes = c->upd;
    double a, b;
    if (mp_epsf_sirt_update_sums(w, s, n, &eu, &a, &b))
        return 1;
    w->noise_drop = 2.0 * c->step * a - c->step * c->step * b;
    return 0;
}

/* The least χ² drop that takes the step after step it (drop: the last
 * step's): one, or pure noise's (noise_drop) where a draw of it could
 * reach the drop.  A draw's drop is at most the part of its χ² (Σ z²,
 * z ~ N(0, 1)) that the best change of the table's elements removes, a
 * χ² of as many degrees of freedom as the fewer of the stars' pixels
 * with weight and the elements' values (q): a drop above q + 5√(2q)
 * needs no draw.  Below, it is drawn on this round's stars and weights,
 * unless the drop is twice the last round's draw: from round to round
 * that moved by 17 % at most (frames S and X, their PSF built).  1 when
 * out of memory. */
static int step_floor(mp_epsf_sirt *w, const mp_epsf_star *s, size_t n, const mp_epsf *e,
                      const run_consts *c, double drop, double *floor)
{
    *floor = 1.0;
    double q = 0.0;
    for (size_t k = 0; k < n; k++)
        q += s[k].used ? w->npix[k] : 0.0;
    q = fmin(q, c->nfree);
    if (!(drop >= 1.0) || drop >= q + 5.0 * sqrt(2.0 * q))
        return 0;
    if (!w->noise_fresh && !(drop >= 2.0 * w->noise_drop)) {
        if (noise_drop(w, s, n, e, c))
            return 1;
        w->noise_fresh = 1;
    }
    *floor = fmax(1.0, w->noise_drop);
    return 0;
}

int mp_epsf_sirt_floor(mp_epsf_sirt *w, const mp_epsf_star *s, size_t n, const mp_epsf_opts *o,
                       const mp_epsf *e, double drop, double *floor, char *err)
{
    run_consts c;
    if (run_consts_of(s, n, o, e, &c, err))
        return 1;
    int rc = step_floor(w, s, n, e, &c, drop, floor);
    if (rc)
        snprintf(err, MP_ERRLEN, "psf build: out of memory");
    run_end(&c);
    return rc;
}

int mp_epsf_sirt_noise(mp_epsf_sirt *w, const mp_epsf_star *s, size_t n, const mp_epsf_opts *o,
                       mp_epsf *e, char *err)
{
    run_consts c;
    if (run_start(s, n, o, e, &c, err))
        return 1;
    int rc = stars_pass(w, s, n, e, o->psfrad, 0) || noise_drop(w, s, n, e, &c);
    if (rc)
        snprintf(err, MP_ERRLEN, "psf build: out of memory");
    run_end(&c);
    return rc;
}

int mp_epsf_sirt_run(mp_epsf_sirt *w, const mp_epsf_star *s, size_t n, const mp_epsf_opts *o,
                     mp_epsf *e, char *err)
{
    int nt = e->nterms, rc = 1;
    size_t nel = w->nel;
    run_consts c;
    if (run_start(s, n, o, e, &c, err))
        return 1;
    double prev = INFINITY;
    w->steps = 0;
    w->noise_fresh = 0;
    for (int it = 0; it <= o->sirt; it++) {
        if (stars_pass(w, s, n, e, o->psfrad, 0)) {
            snprintf(err, MP_ERRLEN, "psf build: out of memory");
            goto done;
        }
        double chi2 = 0.0;
        for (size_t k = 0; k < n; k++)
            chi2 += s[k].used ? w->chi2s[k] : 0.0;
        w->chi2 = chi2;
        /* A step that no longer lowers χ² by more than pure noise's
         * (step_floor) fits only noise. */
        double floor = 1.0;
        if (it > 0 && it < o->sirt && step_floor(w, s, n, e, &c, prev - chi2, &floor)) {
            snprintf(err, MP_ERRLEN, "psf build: out of memory");
            goto done;
        }
        if (it == o->sirt || prev - chi2 < floor)
            break;
        prev = chi2;
        if (stars_pass(w, s, n, e, o->psfrad, 1)) {
            snprintf(err, MP_ERRLEN, "psf build: out of memory");
            goto done;
        }
        if (step_update(w, s, n, e, &c, 1) ||
            mp_epsf_sirt_dilate(w, e, n, 0.75 * o->fwhm * e->os)) {
            snprintf(err, MP_ERRLEN, "psf build: out of memory");
            goto done;
        }
        for (size_t i = 0; i < (size_t)nt * nel; i++)
            e->planes[i] += c.step * c.upd[i];
        w->steps++;
    }
    rc = 0;
done:
    run_end(&c);
    return rc;
}
