/* prf_cache.c — the PRF drawn from a grid of subpixel phases (issue 12).
 *
 * Why: a discrete PSF's PRF depends on the star's position only through its
 * subpixel phase, yet the exact render shifts the whole supersampled table
 * with the damped sinc for every star at every LM iteration (paper §3.1),
 * which was 60-80 % of a real frame's CPU (bench/REPORT.md's profile).  The
 * PRF is therefore rendered once, exactly, with its five-point position
 * derivatives (paper §3.2), on a grid of phases, and a star's PRF and
 * derivatives are the tensor-product cubic (4-point Lagrange) interpolation
 * between the 4×4 grid phases around its own: 16 contiguous rows combined
 * with fixed weights per star, no shift.  The derivatives are interpolated,
 * not taken from the interpolant, so the fit sees the Jacobian of the exact
 * render and LM stops where it stopped before (with the interpolant's own
 * derivative it descended the deviance further, linearly when χ²/dof ≫ 1:
 * 47 Tuc 256², 65 % more iterations and 4× the groups at maxiter).  Nodes
 * are stored as float (relative rounding 6e-8, inside the measured δP).
 *
 * The exact render is not smooth in the phase everywhere: every 1/OVERSAMP
 * px the table element nearest the star changes, the sinc's shift jumps
 * from +½ to −½ element and the box's edge pixel gains or loses an element
 * (8.6e-7 of the light at one pixel of the Tiny Tim ×2 table, 3e-6 at the
 * box edge: enough to dominate the bound of a 10⁷ e⁻ star).  So the grid is
 * kept per branch — the stretch of phases between two such points, 1/os px
 * wide — with its own alignment: Gb intervals a branch, nodes a = −1..Gb+1
 * rendered with the branch's alignment (mp_prf_render_branch), so that no
 * stencil straddles a jump; G = os·Gb phases per pixel.
 *
 * What it costs in accuracy, bounded as fit/sinc_choice.c bounds a shorter
 * kernel: with δP the interpolated minus the exact PRF, a fit's bias in any
 * of (E, X, Y, B) is at most q = E·sqrt(Σ δP²/(E P + B + RON²)) of its
 * Cramér–Rao σ.  δP is measured at the centre of every cell of the phase
 * grid in both axes — where the cubic's error term (f+1)f(f−1)(f−2) peaks —
 * and the worst cell counts; mp_prf_cache_limit turns q ≤ frac into the
 * largest flux served on a given sky, and brighter stars are rendered
 * exactly (frame_paint.c).
 *
 * A faint star's bound leaves room for a cruder interpolation: the
 * bilinear one between the 2×2 nodes around its phase reads a quarter of
 * the nodes and writes each output once (about half the instructions of a
 * cubic render in 47 Tuc's group fits), with an error, f(1 − f)·h²·P''/2
 * an axis, that grows as h², not h⁴.  Its δP² is measured at the same
 * cell centres, where it too peaks, and bounded the same way
 * (mp_prf_cache_limit_lin); a group fit draws a star bilinearly while its
 * flux stays within that limit (fit/lm_render.c).
 *
 * Between the two, a star too bright for the bilinear interpolation is
 * drawn cubically within a core of radius r around it and bilinearly
 * beyond (the core tiers, mp_prf_cache_core_radius): the bilinear error
 * goes as the PRF's curvature, which is largest in the core, while a
 * bright star's box reaches far into its wings (Tiny Tim's ±40 px), where
 * the cubic's 16 nodes read four times the bilinear's 4.  Each tier's δP²
 * is the cubic's within its core and the bilinear's beyond, pixel by
 * pixel, so its bound and flux limit are measured as the others' are
 * (mp_prf_cache_limit_core), and a star is drawn at the tier of the
 * least core whose limit holds its flux (mp_prf_tier_mode). */
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include "fit/prf_axis.h"

/* Where reference stars sit: far from 0 so that every box index is positive
 * (any position works; the render only sees its phase and box). */
#define REF 1000L

/* Largest grid built [bytes]: beyond it the exact render is kept. */
#define CACHE_MAX_BYTES (160.0 * 1024 * 1024)

void mp_prf_cache_free(mp_prf_cache *c)
{
    if (!c)
        return;
    for (int t = 0; c->term && t < c->nt; t++)
        mp_prf_cache_free(&c->term[t]);
    free(c->term);
    free(c->img);
    free(c->p);
    free(c->d2);
    free(c->d2bin);
    free(c->d2l);
    free(c->d2lbin);
    free(c->d2cbin);
    memset(c, 0, sizeof *c);
}

/* One axis of a star at coordinate x: s = (x − offset − ½)·os counts the
 * alignment jumps, k = ⌊s⌋ is the branch over the whole frame, kq = ⌊k/os⌋
 * its whole pixels from the reference, beta = k mod os the branch within
 * the pixel, t ∈ [0, 1) the place within the branch. */
typedef struct { long kq; int beta, a; double f; } axis_pos;

static axis_pos axis_of(const mp_prf_cache *c, double x)
{
    axis_pos r;
    double s = (x - c->offset - 0.5) * c->os, k = floor(s), t = s - k;
    long kk = (long)k;
    r.kq = kk >= 0 ? kk / c->os : -((-kk + c->os - 1) / c->os);
    r.beta = (int)(kk - r.kq * c->os);
    double u = t * c->gb;
    int a = (int)floor(u);
    r.a = a < 0 ? 0 : (a > c->gb - 1 ? c->gb - 1 : a);
    r.f = u - r.a;
    return r;
}

/* The reference star's coordinate for branch beta at place t (kq = REF). */
static double ref_coord(const mp_prf_cache *c, int beta, double t)
{
    return c->offset + 0.5 + (double)REF + (beta + t) / c->os;
}

/* The union over the branches of their boxes, relative to pixel REF. */
static void union_box(const mp_prf_model *m, mp_prf_cache *c)
{
    for (int b = 0; b < c->os; b++) {
        long x0, y0;
        int w, h;
        double r = ref_coord(c, b, 0.5);
        mp_prf_box(m, r, r, &x0, &y0, &w, &h);
        long xa = x0 - REF, xb = x0 + w - REF, ya = y0 - REF, yb = y0 + h - REF;
        if (b == 0 || xa < c->ux0)
            c->ux0 = xa;
        if (b == 0 || ya < c->uy0)
            c->uy0 = ya;
        long ux1 = b == 0 ? xb : (c->ux0 + c->uw > xb ? c->ux0 + c->uw : xb);
        long uy1 = b == 0 ? yb : (c->uy0 + c->uh > yb ? c->uy0 + c->uh : yb);
        c->uw = (int)(ux1 - c->ux0);
        c->uh = (int)(uy1 - c->uy0);
    }
}

/* Copy a rendered box into a union-box image (zero elsewhere). */
static void place(const mp_prf_cache *c, long x0, long y0, int w, int h, const double *buf,
                  double *img)
{
    memset(img, 0, c->npix * sizeof *img);
    for (int j = 0; j < h; j++)
        memcpy(img + (size_t)(y0 - REF - c->uy0 + j) * c->uw + (size_t)(x0 - REF - c->ux0),
               buf + (size_t)j * w, (size_t)w * sizeof *buf);
}

/* 4-point Lagrange weights on nodes −1, 0, 1, 2 at f ∈ [0, 1]. */
static void weights(double f, double L[4])
{
    double a = f + 1.0, b = f, c = f - 1.0, d = f - 2.0;
    L[0] = -b * c * d / 6.0;
    L[1] = a * c * d / 2.0;
    L[2] = -a * b * d / 2.0;
    L[3] = a * b * c / 6.0;
}

/* Where a star's PRF is read from the grid: its whole pixels and branch
 * per axis and the 4×4 Lagrange weights. */
typedef struct {
    axis_pos px, py;
    double Lx[4], Ly[4];
    int mode;           /* MP_PRF_CUBIC, MP_PRF_BILINEAR or MP_PRF_CORE(k) */
} star_pos;

static star_pos star_of(const mp_prf_cache *c, double x, double y, int mode)
{
    star_pos s;
    s.mode = mode;
    s.px = axis_of(c, x);
    s.py = axis_of(c, y);
    weights(s.px.f, s.Lx);
    weights(s.py.f, s.Ly);
    return s;
}

/* One plane's row: out[i] (= or +=) Σ_ka w[ka]·a_ka[i] over four nodes,
 * in one pass (the output read and written once per node row, not once
 * per node).  omp simd: gcc 12 at -O2 left it scalar (a quarter of the
 * crowded frame's CPU); vectorised across i, each element's sum keeps
 * its order, so the values are the same bit for bit. */
static void row4(double *restrict out, const float *restrict a0, const float *restrict a1,
                 const float *restrict a2, const float *restrict a3, const double w[4], long n,
                 int add)
{
    double w0 = w[0], w1 = w[1], w2 = w[2], w3 = w[3];
    if (add)
#pragma omp simd
        for (long i = 0; i < n; i++)
            out[i] += w0 * a0[i] + w1 * a1[i] + w2 * a2[i] + w3 * a3[i];
    else
#pragma omp simd
        for (long i = 0; i < n; i++)
            out[i] = w0 * a0[i] + w1 * a1[i] + w2 * a2[i] + w3 * a3[i];
}

/* One plane's row, bilinear: out[i] = Σ w[k]·a_k[i] over the 2×2 nodes
 * around the star's phase, in one pass. */
static void row_bilinear(double *restrict out, const float *restrict a00,
                         const float *restrict a01, const float *restrict a10,
                         const float *restrict a11, const double w[4], long n, int add)
{
    double w0 = w[0], w1 = w[1], w2 = w[2], w3 = w[3];
    if (add)
#pragma omp simd
        for (long i = 0; i < n; i++)
            out[i] += w0 * a00[i] + w1 * a01[i] + w2 * a10[i] + w3 * a11[i];
    else
#pragma omp simd
        for (long i = 0; i < n; i++)
            out[i] = w0 * a00[i] + w1 * a01[i] + w2 * a10[i] + w3 * a11[i];
}

/* Where a span of row y (1-based), pixels [x0, x0+w), meets the cached
 * union box: its columns [i0, i1) inside, and the offset q0 + i0 of the
 * first of them in a plane; inside is 0 when none is. */
typedef struct { long i0, i1, off; int inside; } span_at;

static inline span_at span_in_box(const mp_prf_cache *c, const star_pos *s, long x0, long y, int w)
{
    span_at a;
    long q0 = x0 - s->px.kq - c->ux0, row = y - s->py.kq - c->uy0;
    a.i0 = q0 < 0 ? -q0 : 0;
    a.i1 = q0 + w > c->uw ? c->uw - q0 : w;
    a.inside = a.i1 > a.i0 && row >= 0 && row < c->uh;
    a.off = row * c->uw + q0 + a.i0;
    return a;
}

/* The span's ends beyond the box (all of it when it misses the box) set
 * to zero in each of the three optional outputs. */
static inline void zero_outside(const span_at *a, int w, double *out[3])
{
    if (a->inside && a->i0 == 0 && a->i1 == w)
        return;                     /* most spans: a call per plane saved */
    for (int k = 0; k < 3; k++)
        if (out[k] && !a->inside)
            memset(out[k], 0, (size_t)w * sizeof *out[k]);
        else if (out[k]) {
            memset(out[k], 0, (size_t)a->i0 * sizeof *out[k]);
            memset(out[k] + a->i1, 0, (size_t)(w - a->i1) * sizeof *out[k]);
        }
}

/* interp_spans' bilinear interpolation: the nodes a, a + 1 of each axis
 * (Lagrange's 0 and 1), every output written once (add: added to, the
 * ends beyond the box left as they are), times k. */
static void bilinear_spans(const mp_prf_cache *c, const star_pos *s, const mp_span *sp,
                           const size_t *at, int ns, double *pr, double *gx, double *gy,
                           double k, int add)
{
    int na = c->gb + 3, NA = c->os * na;
    size_t step = 3 * c->npix, row = (size_t)NA * step;    /* next node along x, y */
    size_t pl = (size_t)(s->py.beta * na + s->py.a + 1) * NA + (size_t)(s->px.beta * na + s->px.a + 1);
    const float *p0 = c->img + 3 * pl * c->npix;
    double fx = s->px.f, fy = s->py.f;
    double wv[4] = {(1 - fy) * (1 - fx) * k, (1 - fy) * fx * k, fy * (1 - fx) * k, fy * fx * k};
    size_t o = 0;
    for (int n = 0; n < ns; n++) {
        o = at ? at[n] : o;
        double *out[3] = {pr ? pr + o : NULL, gx ? gx + o : NULL, gy ? gy + o : NULL};
        span_at a = span_in_box(c, s, sp[n].x0, sp[n].y, sp[n].n);
        o += (size_t)sp[n].n;
        if (!add)
            zero_outside(&a, sp[n].n, out);
        if (!a.inside)
            continue;
        for (int q = 0; q < 3; q++)
            if (out[q]) {
                const float *v = p0 + (size_t)q * c->npix + (size_t)a.off;
                row_bilinear(out[q] + a.i0, v, v + step, v + row, v + row + step, wv,
                             a.i1 - a.i0, add);
            }
    }
}

/* The interpolated PRF on ns spans of frame pixels (rows, 1-based), span
 * k's values at index at[k] of each output (at NULL: one after the other),
 * each of the three outputs optional; pixels outside the cached union box
 * are zero.  Plane pl holds the PRF at img[3·pl·npix], then ∂/∂x, then
 * ∂/∂y.  The node rows are the outer loop: one node row's four planes are
 * read over every span before the next (a few regular strided streams the
 * prefetcher follows, not 48 short ones a row), and the outputs, a star's
 * window, stay in L1 between the passes.  Each element's sum keeps its
 * order (node row kb = 0..3), so the values are those of a row-by-row pass
 * bit for bit. */
static void cubic_spans(const mp_prf_cache *c, const star_pos *s, const mp_span *sp,
                        const size_t *at, int ns, double *pr, double *gx, double *gy, double k,
                        int add)
{
    int na = c->gb + 3, NA = c->os * na;
    size_t step = 3 * c->npix;          /* the next node along x */
    for (int kb = 0; kb < 4; kb++) {
        /* node a − 1 + ka of branch beta is plane beta·na + a + ka */
        size_t pl = (size_t)(s->py.beta * na + s->py.a + kb) * NA +
                    (size_t)(s->px.beta * na + s->px.a);
        const float *p0 = c->img + 3 * pl * c->npix;
        double wv[4];
        for (int ka = 0; ka < 4; ka++)
            wv[ka] = s->Ly[kb] * s->Lx[ka] * k;     /* k = 1: exact, the same bits */
        size_t o = 0;
        for (int n = 0; n < ns; n++) {
            o = at ? at[n] : o;
            double *out[3] = {pr ? pr + o : NULL, gx ? gx + o : NULL, gy ? gy + o : NULL};
            span_at a = span_in_box(c, s, sp[n].x0, sp[n].y, sp[n].n);
            o += (size_t)sp[n].n;
            if (kb == 0 && !add)
                zero_outside(&a, sp[n].n, out);
            if (!a.inside)
                continue;
            for (int q = 0; q < 3; q++)
                if (out[q]) {
                    const float *v = p0 + (size_t)q * c->npix + (size_t)a.off;
                    row4(out[q] + a.i0, v, v + step, v + 2 * step, v + 3 * step, wv,
                         a.i1 - a.i0, kb > 0 || add);
                }
        }
    }
}

static const int core_radius[MP_PRF_NCORE] = {0, 1, 2, 3, 4, 6, 9, 14};

int mp_prf_cache_core_radius(int k)
{
    return k >= 0 && k < MP_PRF_NCORE ? core_radius[k] : -1;
}

/* Whether a pixel's offset along one axis from the star's whole pixel
 * (axis_pos.kq = ⌊x − offset − ½⌋) lies in a core of radius r: within
 * [−r, r + 1], about the star (a pixel is in the core when both are). */
static inline int in_core(long off, int r)
{
    return off >= -r && off <= r + 1;
}

/* A core tier's render (MP_PRF_CORE(k)): each span cut where it crosses the
 * core's columns, the parts in the core drawn by cubic_spans, the rest by
 * bilinear_spans, each part to its own place of the outputs; up to CHUNK
 * spans at a time. */
static void core_spans(const mp_prf_cache *c, const star_pos *s, const mp_span *sp,
                       const size_t *at, int ns, double *pr, double *gx, double *gy, double k,
                       int add)
{
    enum { CHUNK = 64 };
    int r = core_radius[s->mode - 2];
    long cx0 = s->px.kq - r, cx1 = s->px.kq + r + 2;    /* frame columns [cx0, cx1) */
    mp_span out[2 * CHUNK], core[CHUNK];
    size_t oat[2 * CHUNK], cat[CHUNK], o = 0;
    for (int n0 = 0; n0 < ns; n0 += CHUNK) {
        int no = 0, nc = 0;
        for (int n = n0; n < ns && n < n0 + CHUNK; n++) {
            o = at ? at[n] : o;
            long x0 = sp[n].x0, x1 = x0 + sp[n].n, y = sp[n].y;
            long a = x0, b = x0;                    /* the core part [a, b) */
            if (in_core(y - s->py.kq, r)) {
                a = cx0 > x0 ? (cx0 < x1 ? cx0 : x1) : x0;
                b = cx1 < x1 ? (cx1 > a ? cx1 : a) : x1;
            }
            if (a > x0) {
                out[no] = (mp_span){x0, y, (int)(a - x0)};
                oat[no++] = o;
            }
            if (b > a) {
                core[nc] = (mp_span){a, y, (int)(b - a)};
                cat[nc++] = o + (size_t)(a - x0);
            }
            if (x1 > b) {
                out[no] = (mp_span){b, y, (int)(x1 - b)};
                oat[no++] = o + (size_t)(b - x0);
            }
            o += (size_t)sp[n].n;
        }
        if (no)
            bilinear_spans(c, s, out, oat, no, pr, gx, gy, k, add);
        if (nc)
            cubic_spans(c, s, core, cat, nc, pr, gx, gy, k, add);
    }
}

/* The star's PRF on the spans at its mode, times k (add: added to). */
static void interp_spans_k(const mp_prf_cache *c, const star_pos *s, const mp_span *sp,
                           const size_t *at, int ns, double *pr, double *gx, double *gy,
                           double k, int add)
{
    if (s->mode == MP_PRF_BILINEAR)
        bilinear_spans(c, s, sp, at, ns, pr, gx, gy, k, add);
    else if (s->mode >= 2 && s->mode < 2 + MP_PRF_NCORE)
        core_spans(c, s, sp, at, ns, pr, gx, gy, k, add);
    else
        cubic_spans(c, s, sp, at, ns, pr, gx, gy, k, add);
}

/* The star's PRF on the spans: from c's own grid, or, for a variable PSF,
 * Σ c_t·grid_t with the field's terms c_t at the star (m's field: a
 * view's is moved to its sub-image, mp_psf_local; m is read only then). */
static void interp_spans_at(const mp_prf_cache *c, const mp_prf_model *m, double x, double y,
                            const star_pos *s, const mp_span *sp, const size_t *at, int ns,
                            double *pr, double *gx, double *gy)
{
    if (!c->nt) {
        interp_spans_k(c, s, sp, at, ns, pr, gx, gy, 1.0, 0);
        return;
    }
    double ct[MP_PSF_MAXTERMS];
    mp_psf_field_terms(m->psf->field, x, y, ct);
    interp_spans_k(&c->term[0], s, sp, at, ns, pr, gx, gy, ct[0], 0);
    for (int t = 1; t < c->nt; t++)
        if (ct[t] != 0.0)           /* a grid of tables' far planes */
            interp_spans_k(&c->term[t], s, sp, at, ns, pr, gx, gy, ct[t], 1);
}

/* The interpolated PRF on box [x0, x0+w) × [y0, y0+h): its rows as spans
 * (m may be NULL for a constant PSF's grid). */
static void interp(const mp_prf_cache *c, const mp_prf_model *m, double x, double y, long x0,
                   long y0, int w, int h, double *prf, double *ddx, double *ddy, int mode)
{
    star_pos s = star_of(c, x, y, mode);
    enum { CHUNK = 64 };
    mp_span rows[CHUNK];
    for (int j = 0; j < h; j += CHUNK) {
        int n = h - j < CHUNK ? h - j : CHUNK;
        for (int t = 0; t < n; t++)
            rows[t] = (mp_span){x0, y0 + j + t, w};
        size_t o = (size_t)j * w;
        interp_spans_at(c, m, x, y, &s, rows, NULL, n, prf + o, ddx ? ddx + o : NULL,
                        ddy ? ddy + o : NULL);
    }
}

int mp_prf_cache_usable(const mp_prf_cache *c, const mp_prf_model *m)
{
    if (!c || !c->G || c->drf != m->drf)
        return 0;
    const mp_psf_field *f = m->psf->field;
    if (f)
        return c->nt == f->nterms && c->planes == f->planes;
    return c->img && c->psf == m->psf;
}

int mp_prf_cache_covers(const mp_prf_cache *c, const mp_prf_model *m, double x, double y)
{
    const mp_psf_field *f = m->psf->field;
    if (!c || !c->nt || !f || f->order == MP_PSF_GRID || f->order == 0)
        return 1;
    return fabs(x - f->x0) <= f->xscale && fabs(y - f->y0) <= f->yscale;
}

int mp_prf_cache_render(const mp_prf_cache *c, const mp_prf_model *m, double x, double y,
                        long x0, long y0, int w, int h, double *prf, double *ddx, double *ddy,
                        int mode)
{
    if (!mp_prf_cache_usable(c, m))
        return 1;
    interp(c, m, x, y, x0, y0, w, h, prf, ddx, ddy, mode);
    return 0;
}

int mp_prf_cache_render_at(const mp_prf_cache *c, const mp_prf_model *m, double x, double y,
                           const mp_span *sp, const size_t *at, int ns, double *prf, double *ddx,
                           double *ddy, int mode)
{
    if (!mp_prf_cache_usable(c, m))
        return 1;
    star_pos s = star_of(c, x, y, mode);
    interp_spans_at(c, m, x, y, &s, sp, at, ns, prf, ddx, ddy);
    return 0;
}

int mp_prf_cache_render_spans(const mp_prf_cache *c, const mp_prf_model *m, double x, double y,
                              const mp_span *sp, int ns, double *prf, double *ddx, double *ddy)
{
    return mp_prf_cache_render_at(c, m, x, y, sp, NULL, ns, prf, ddx, ddy, 0);
}

/* The nodes: branch (bx, by), node (a − 1, b − 1), aligned as the branch;
 * buf holds 6 npix (three renders, three union-box images). */
static int render_nodes(const mp_prf_model *m, mp_prf_cache *c, double *buf, mp_prf_work *wk)
{
    int na = c->gb + 3, NA = c->os * na;
    size_t np = c->npix;
    for (int Y = 0; Y < NA; Y++)
        for (int X = 0; X < NA; X++) {
            int bx = X / na, by = Y / na, a = X % na, b = Y % na;
            double x = ref_coord(c, bx, (a - 1.0) / c->gb), y = ref_coord(c, by, (b - 1.0) / c->gb);
            long x0, y0;
            int w, h;
            if (mp_prf_render_branch(m, x, y, ref_coord(c, bx, 0.5), ref_coord(c, by, 0.5),
                                     REF + c->ux0, REF + c->uy0, c->uw, c->uh, &x0, &y0, &w, &h,
                                     buf, buf + np, buf + 2 * np, wk))
                return 1;
            float *pl = c->img + 3 * ((size_t)Y * NA + (size_t)X) * np;
            for (int k = 0; k < 3; k++) {
                place(c, x0, y0, w, h, buf + k * np, buf + (3 + k) * np);
                for (size_t i = 0; i < np; i++)
                    pl[k * np + i] = (float)buf[(3 + k) * np + i];
            }
        }
    return 0;
}

/* Cell ph's error at its centre (x, y): p (the natural exact render ex)
 * and δP² of the cubic and of the bilinear interpolation (cur: npix of
 * scratch). */
static void cell_errors(mp_prf_cache *c, double x, double y, size_t ph, const double *ex,
                        double *cur)
{
    float *p = c->p + ph * c->npix;
    for (size_t i = 0; i < c->npix; i++)
        p[i] = (float)ex[i];
    for (int lin = 0; lin < 2; lin++) {
        float *d = (lin ? c->d2l : c->d2) + ph * c->npix;
        interp(c, NULL, x, y, REF + c->ux0, REF + c->uy0, c->uw, c->uh, cur, NULL, NULL, lin);
        for (size_t i = 0; i < c->npix; i++)
            d[i] = (float)((cur[i] - ex[i]) * (cur[i] - ex[i]));
    }
}

/* The error at the centre of every cell of every branch: p (the natural
 * exact render) and δP² per phase. */
static int measure(const mp_prf_model *m, mp_prf_cache *c, double *buf, double *ex,
                   double *cur, mp_prf_work *wk)
{
    int ng = c->os * c->gb;
    for (int ph = 0; ph < c->nph; ph++) {
        int ix = ph % ng, iy = ph / ng;
        double x = ref_coord(c, ix / c->gb, (ix % c->gb + 0.5) / c->gb);
        double y = ref_coord(c, iy / c->gb, (iy % c->gb + 0.5) / c->gb);
        long x0, y0;
        int w, h;
        if (mp_prf_render_window(m, x, y, REF + c->ux0, REF + c->uy0, c->uw, c->uh, &x0, &y0, &w,
                                 &h, buf, NULL, NULL, wk))
            return 1;
        place(c, x0, y0, w, h, buf, ex);
        cell_errors(c, x, y, (size_t)ph, ex, cur);
    }
    return 0;
}

/* ---- The nodes and cells from the axis operators (fit/prf_axis.c) -------- */

/* A coordinate's operator along one axis of the union box (xr: aligned as
 * for a star there). */
static int axis_op(const mp_prf_model *m, const mp_prf_cache *c, int yaxis, double x, double xr,
                   mp_prf_axis *a)
{
    const mp_psf *p = m->psf;
    return yaxis ? mp_prf_axis_build(p->ny, p->os, p->offset, x, xr, REF + c->uy0, c->uh,
                                     m->sinc_hw, a)
                 : mp_prf_axis_build(p->nx, p->os, p->offset, x, xr, REF + c->ux0, c->uw,
                                     m->sinc_hw, a);
}

/* Y·A (or Y'·A) into a union-box image (zero outside the box), as double. */
static void product(const mp_prf_cache *c, const mp_prf_axis *ax, const mp_prf_axis *ay,
                    int yderiv, const double *A, double scale, double *img)
{
    memset(img, 0, c->npix * sizeof *img);
    mp_prf_axis_cols(ay, yderiv, A, 0, ax->w, scale, img, ay->p0 - REF - c->uy0,
                     ax->p0 - REF - c->ux0, c->uw);
}

/* The same from mp_prf_axis_rows_single's A, in single precision: the
 * nodes are held as floats, and a node's rounding is fixed, so the PRF
 * interpolated between nodes stays smooth in the star's phase (what the
 * LM needs of it: fit/prf_axis.h). */
static void product_single(const mp_prf_cache *c, const mp_prf_axis *ax, const mp_prf_axis *ay,
                           int yderiv, const float *A, double scale, double *img)
{
    memset(img, 0, c->npix * sizeof *img);
    mp_prf_axis_cols_single(ay, yderiv, A, 0, ax->w, scale, img, ay->p0 - REF - c->uy0,
                            ax->p0 - REF - c->ux0, c->uw);
}

/* Every node: per x node A = T·Xᵀ and T·X'ᵀ, then per y node the PRF
 * Y·A, ∂/∂x Y·(T·X'ᵀ) and ∂/∂y Y'·A.  The x nodes in parallel (their
 * planes are disjoint), each thread with its own npix doubles and 2·ny·uw
 * floats (and a row's: mp_prf_axis_rows_single, in single precision): built
 * serially, the grids were a quarter of the frame fit's serial time
 * (issue 14, bench/SCALING.md). */
static int nodes_sep(const mp_prf_model *m, mp_prf_cache *c)
{
    int na = c->gb + 3, NA = c->os * na, rc = 0;
    size_t np = c->npix, nA = (size_t)m->psf->ny * c->uw;
    double scale = m->drf ? m->drf->volume : 1.0;
    mp_prf_axis *ay = calloc((size_t)NA, sizeof *ay);
    for (int Y = 0; ay && Y < NA && !rc; Y++)
        rc = axis_op(m, c, 1, ref_coord(c, Y / na, (Y % na - 1.0) / c->gb),
                     ref_coord(c, Y / na, 0.5), &ay[Y]);
    rc = rc || !ay;
#pragma omp parallel if (!rc) reduction(| : rc)
    {
        mp_prf_axis ax = {0};
        double *buf = malloc(np * sizeof *buf);
        float *A = malloc((2 * nA + MP_PRF_AXIS_TF(m->psf->nx)) * sizeof *A);
        float *Ad = A ? A + nA : NULL;
        int bad = !buf || !A;
        rc |= bad;
#pragma omp for schedule(dynamic)
        for (int X = 0; X < NA; X++) {
            if (bad || axis_op(m, c, 0, ref_coord(c, X / na, (X % na - 1.0) / c->gb),
                               ref_coord(c, X / na, 0.5), &ax)) {
                rc = 1;
                continue;
            }
            mp_prf_axis_rows_single(m->psf->t, m->psf->nx, 0, m->psf->ny, &ax, A, Ad, Ad + nA);
            for (int Y = 0; Y < NA; Y++) {
                float *pl = c->img + 3 * ((size_t)Y * NA + (size_t)X) * np;
                for (int k = 0; k < 3; k++) {
                    product_single(c, &ax, &ay[Y], k == 2, k == 1 ? Ad : A, scale, buf);
                    for (size_t i = 0; i < np; i++)
                        pl[k * np + i] = (float)buf[i];
                }
            }
            mp_prf_axis_free(&ax);
        }
        mp_prf_axis_free(&ax);
        free(buf);
        free(A);
    }
    for (int Y = 0; ay && Y < NA; Y++)
        mp_prf_axis_free(&ay[Y]);
    free(ay);
    return rc;
}

/* The cells' exact renders (natural alignment) the same way, in double
 * (they measure the grid's error: its float nodes' rounding, mp_prf_axis_
 * rows_single's, is part of what they see), then the error as measure()
 * takes it; the x cells in parallel, each thread with its own 2·npix +
 * ny·uw. */
static int measure_sep(const mp_prf_model *m, mp_prf_cache *c)
{
    int ng = c->os * c->gb, rc = 0;
    size_t np = c->npix, nA = (size_t)m->psf->ny * c->uw;
    double scale = m->drf ? m->drf->volume : 1.0;
    mp_prf_axis *ay = calloc((size_t)ng, sizeof *ay);
    for (int iy = 0; ay && iy < ng && !rc; iy++) {
        double y = ref_coord(c, iy / c->gb, (iy % c->gb + 0.5) / c->gb);
        rc = axis_op(m, c, 1, y, y, &ay[iy]);
    }
    rc = rc || !ay;
#pragma omp parallel if (!rc) reduction(| : rc)
    {
        mp_prf_axis ax = {0};
        double *ex = malloc((2 * np + nA) * sizeof *ex), *cur = ex + np, *A = cur + np;
        rc |= !ex;
#pragma omp for schedule(dynamic)
        for (int ix = 0; ix < ng; ix++) {
            double x = ref_coord(c, ix / c->gb, (ix % c->gb + 0.5) / c->gb);
            if (!ex || axis_op(m, c, 0, x, x, &ax)) {
                rc = 1;
                continue;
            }
            mp_prf_axis_rows(m->psf->t, m->psf->nx, 0, m->psf->ny, &ax, A, NULL);
            for (int iy = 0; iy < ng; iy++) {
                double y = ref_coord(c, iy / c->gb, (iy % c->gb + 0.5) / c->gb);
                size_t ph = (size_t)iy * ng + ix;
                product(c, &ax, &ay[iy], 0, A, scale, ex);
                cell_errors(c, x, y, ph, ex, cur);
            }
            mp_prf_axis_free(&ax);
        }
        mp_prf_axis_free(&ax);
        free(ex);
    }
    for (int iy = 0; ay && iy < ng; iy++)
        mp_prf_axis_free(&ay[iy]);
    free(ay);
    return rc;
}

/* The bin of a pixel of PRF value v (d2bin's, pmax > 0). */
static int bin_of(double v, double pmax)
{
    if (!(v > 0))
        return 0;
    int b = 1 + (int)floor(-log2(v / pmax));
    return b < 1 ? 1 : b > MP_PRF_CACHE_NBIN - 1 ? MP_PRF_CACHE_NBIN - 1 : b;
}

/* Cell ph's bins of each core tier: the bilinear one's, with the pixels
 * of its core moved from the bilinear δP² to the cubic's (a core holds
 * (2r + 2)² pixels, the cell npix). */
static void core_bins(mp_prf_cache *c, int ph)
{
    size_t o = (size_t)ph * c->npix;
    const double *binl = c->d2lbin + (size_t)ph * MP_PRF_CACHE_NBIN;
    for (int k = 0; k < MP_PRF_NCORE; k++) {
        int r = core_radius[k];
        double *bin = c->d2cbin + ((size_t)k * c->nph + (size_t)ph) * MP_PRF_CACHE_NBIN;
        memcpy(bin, binl, MP_PRF_CACHE_NBIN * sizeof *bin);
        long j0 = -r - c->uy0, j1 = r + 2 - c->uy0, i0 = -r - c->ux0, i1 = r + 2 - c->ux0;
        for (long j = j0 < 0 ? 0 : j0; j < j1 && j < c->uh; j++)
            for (long i = i0 < 0 ? 0 : i0; i < i1 && i < c->uw; i++) {
                size_t q = o + (size_t)j * c->uw + (size_t)i;
                bin[bin_of(c->p[q], c->pmax)] += (double)c->d2[q] - (double)c->d2l[q];
            }
    }
}

/* What mp_prf_cache_serves bounds the cells' sums with: the least and the
 * largest P, and each cell's Σ δP² binned by P, for each interpolation.
 * Nonzero when out of memory. */
static int cell_bins(mp_prf_cache *c)
{
    /* In parallel (the phase grid's serial part, bench/SCALING.md); the
     * least and largest and each cell's own sums do not depend on it. */
    double pmin = INFINITY, pmax = -INFINITY;
    size_t ntot = (size_t)c->nph * c->npix;
#pragma omp parallel for schedule(static) reduction(min : pmin) reduction(max : pmax)
    for (size_t i = 0; i < ntot; i++) {
        pmin = c->p[i] < pmin ? c->p[i] : pmin;
        pmax = c->p[i] > pmax ? c->p[i] : pmax;
    }
    c->pmin = pmin;
    c->pmax = pmax;
    c->d2bin = calloc((size_t)c->nph * MP_PRF_CACHE_NBIN, sizeof *c->d2bin);
    c->d2lbin = calloc((size_t)c->nph * MP_PRF_CACHE_NBIN, sizeof *c->d2lbin);
    c->d2cbin = calloc((size_t)MP_PRF_NCORE * c->nph * MP_PRF_CACHE_NBIN, sizeof *c->d2cbin);
    if (!c->d2bin || !c->d2lbin || !c->d2cbin)
        return 1;
    if (!(c->pmax > 0))
        return 0;
#pragma omp parallel for schedule(static)
    for (int ph = 0; ph < c->nph; ph++) {
        size_t o = (size_t)ph * c->npix;
        double *bin = c->d2bin + (size_t)ph * MP_PRF_CACHE_NBIN;
        double *binl = c->d2lbin + (size_t)ph * MP_PRF_CACHE_NBIN;
        for (size_t i = 0; i < c->npix; i++) {
            int b = bin_of(c->p[o + i], c->pmax);
            bin[b] += c->d2[o + i];
            binl[b] += c->d2l[o + i];
        }
        core_bins(c, ph);
    }
    return 0;
}

static int build_field(const mp_prf_model *m, int G, int sep, mp_prf_cache *c, char *err);

/* n floats: *b, taken from a spare grid, when it holds exactly n (have),
 * else a new block.  A grid rebuilt for a table that changed (each round
 * of the PSF build) fills the pages its last one had faulted in: as new
 * blocks, above malloc's mmap threshold, the PSF build's grids were 40 %
 * of 47 Tuc's page faults (bench/PROFILE.md, 2026-12-03). */
static float *reused(float **b, size_t have, size_t n)
{
    if (b && *b && have == n) {
        float *r = *b;
        *b = NULL;
        return r;
    }
    return malloc(n * sizeof **b);
}

/* The grid, its nodes and cells rendered by the axis operators when the
 * model allows (sep), else by fit/prf.c's render; the blocks of spare
 * (NULL: none) of the sizes it needs taken from it. */
static int build(const mp_prf_model *m, int G, int sep, mp_prf_cache *c, mp_prf_cache *spare,
                 char *err)
{
    memset(c, 0, sizeof *c);
    if (m->psf->kind != MP_PSF_TABLE || G < 1)
        return 0;                       /* the analytic Gaussian is rendered exactly */
    if (m->psf->field)
        return build_field(m, G, sep, c, err);
    mp_prf_model me = *m;               /* the nodes are exact renders (no grid in wk) */
    c->os = m->psf->os;
    c->offset = m->psf->offset;
    c->gb = (G + c->os - 1) / c->os;
    union_box(&me, c);
    int NA = c->os * (c->gb + 3), ng = c->os * c->gb;
    c->npix = (size_t)c->uw * c->uh;
    c->nph = ng * ng;
    double bytes = (double)c->npix * (3.0 * NA * NA * sizeof *c->img +
                                      3.0 * c->nph * sizeof *c->p);
    if (bytes > CACHE_MAX_BYTES) {
        memset(c, 0, sizeof *c);        /* too big to pay: exact renders */
        return 0;
    }
    int sa = spare ? spare->os * (spare->gb + 3) : 0;
    size_t simg = spare ? 3 * (size_t)sa * sa * spare->npix : 0;
    size_t sp = spare ? (size_t)spare->nph * spare->npix : 0, np = (size_t)c->nph * c->npix;
    c->img = reused(spare ? &spare->img : NULL, simg, 3 * (size_t)NA * NA * c->npix);
    c->p = reused(spare ? &spare->p : NULL, sp, np);
    c->d2 = reused(spare ? &spare->d2 : NULL, sp, np);
    c->d2l = reused(spare ? &spare->d2l : NULL, sp, np);
    sep = sep && mp_prf_separable(&me);
    double *buf = sep ? NULL : malloc(6 * c->npix * sizeof *buf);
    mp_prf_work wk = {0};
    int rc = 1;
    if (!c->img || !c->p || !c->d2 || !c->d2l || (!sep && !buf)) {
        snprintf(err, MP_ERRLEN, "out of memory for the PRF phase grid (%d x %d phases, %dx%d px)",
                 NA, NA, c->uw, c->uh);
        goto done;
    }
    c->psf = m->psf;
    c->drf = m->drf;
    if (sep ? nodes_sep(&me, c) || measure_sep(&me, c)
            : render_nodes(&me, c, buf, &wk) ||
                  measure(&me, c, buf, buf + c->npix, buf + 2 * c->npix, &wk)) {
        snprintf(err, MP_ERRLEN, "out of memory rendering the PRF phase grid");
        goto done;
    }
    if (cell_bins(c)) {
        snprintf(err, MP_ERRLEN, "out of memory for the PRF phase grid's bound");
        goto done;
    }
    c->G = ng;
    rc = 0;
done:
    free(buf);
    mp_prf_work_free(&wk);
    if (rc)
        mp_prf_cache_free(c);
    return rc;
}

/* The first plane's grid as c's geometry, and its P and |δP| (of both
 * interpolations) as the start of the bound's: nonzero when out of
 * memory. */
static int field_start(mp_prf_cache *c, const mp_prf_cache *t0)
{
    c->G = t0->G;
    c->os = t0->os;
    c->gb = t0->gb;
    c->offset = t0->offset;
    c->ux0 = t0->ux0;
    c->uy0 = t0->uy0;
    c->uw = t0->uw;
    c->uh = t0->uh;
    c->npix = t0->npix;
    c->nph = t0->nph;
    size_t n = (size_t)c->nph * c->npix;
    c->p = malloc(n * sizeof *c->p);
    c->d2 = malloc(n * sizeof *c->d2);
    c->d2l = malloc(n * sizeof *c->d2l);
    if (!c->p || !c->d2 || !c->d2l)
        return 1;
    for (size_t i = 0; i < n; i++) {
        c->p[i] = t0->p[i];
        c->d2[i] = sqrtf(t0->d2[i]);
        c->d2l[i] = sqrtf(t0->d2l[i]);
    }
    return 0;
}

/* Plane t's P and |δP| into the bound's (d2 holds |δP| until
 * field_finish): a polynomial's term is at most 1 in size, so |δP| adds
 * and P loses |P_t| at most; a grid of tables' weights are a convex
 * combination, so |δP| is at most the largest and P at least the least. */
static void field_add(mp_prf_cache *c, const mp_prf_cache *t, int convex)
{
    size_t n = (size_t)c->nph * c->npix;
    for (size_t i = 0; i < n; i++) {
        float d = sqrtf(t->d2[i]), dl = sqrtf(t->d2l[i]);
        if (convex) {
            c->p[i] = fminf(c->p[i], t->p[i]);
            c->d2[i] = fmaxf(c->d2[i], d);
            c->d2l[i] = fmaxf(c->d2l[i], dl);
        } else {
            c->p[i] -= fabsf(t->p[i]);
            c->d2[i] += d;
            c->d2l[i] += dl;
        }
    }
}

/* |δP| squared, P at least 0 (a pixel whose least P is negative is
 * bounded at the sky's variance alone), and the bins. */
static int field_finish(mp_prf_cache *c)
{
    size_t n = (size_t)c->nph * c->npix;
    for (size_t i = 0; i < n; i++) {
        c->p[i] = fmaxf(c->p[i], 0.0f);
        c->d2[i] *= c->d2[i];
        c->d2l[i] *= c->d2l[i];
    }
    return cell_bins(c);
}

/* Plane t's grid's own bound tables, once added to the field's. */
static void free_bound(mp_prf_cache *t)
{
    free(t->p);
    free(t->d2);
    free(t->d2l);
    free(t->d2bin);
    free(t->d2lbin);
    free(t->d2cbin);
    t->p = t->d2 = t->d2l = NULL;
    t->d2bin = t->d2lbin = t->d2cbin = NULL;
}

/* A variable PSF's grid (mp_prf_cache_build): a grid per plane of the
 * field, each built as a constant table's, and the bound of any
 * combination the field takes.  An empty cache when the planes are not
 * the table's geometry or the grids would take more than the cap. */
static int build_field(const mp_prf_model *m, int G, int sep, mp_prf_cache *c, char *err)
{
    const mp_psf *p = m->psf;
    const mp_psf_field *f = p->field;
    if (f->nx != p->nx || f->ny != p->ny || f->os != p->os || f->nterms < 1)
        return 0;
    if (!(c->term = calloc((size_t)f->nterms, sizeof *c->term))) {
        snprintf(err, MP_ERRLEN, "out of memory for the PRF phase grid of a variable PSF");
        return 1;
    }
    c->nt = f->nterms;
    size_t plane = (size_t)f->nx * (size_t)f->ny;
    int convex = f->order == MP_PSF_GRID, rc = 0;
    for (int t = 0; t < c->nt && !rc; t++) {
        mp_psf pt = *p;
        pt.field = NULL;
        pt.t = f->planes + (size_t)t * plane;
        mp_prf_model mt = *m;
        mt.psf = &pt;
        mp_prf_cache *g = &c->term[t];
        if (build(&mt, G, sep, g, NULL, err))
            rc = 1;
        else if (!g->G || 3.0 * c->nt * (double)g->os * (g->gb + 3) * g->os * (g->gb + 3) *
                                  (double)g->npix * sizeof *g->img > CACHE_MAX_BYTES) {
            mp_prf_cache_free(c);       /* too big to pay: exact renders */
            return 0;
        } else {
            g->psf = NULL;              /* pt is gone; the field's cache is used */
            if (t == 0 ? field_start(c, g) : (field_add(c, g, convex), 0))
                rc = 2;
            free_bound(g);
        }
    }
    if (!rc && field_finish(c))
        rc = 2;
    if (rc) {
        if (rc == 2)
            snprintf(err, MP_ERRLEN, "out of memory for the PRF phase grid of a variable PSF");
        mp_prf_cache_free(c);
        return 1;
    }
    c->psf = p;
    c->drf = m->drf;
    c->planes = f->planes;
    return 0;
}

int mp_prf_cache_build(const mp_prf_model *m, int G, mp_prf_cache *c, char *err)
{
    return build(m, G, 1, c, NULL, err);
}

int mp_prf_cache_build_reusing(const mp_prf_model *m, int G, mp_prf_cache *c,
                               mp_prf_cache *spare, char *err)
{
    return build(m, G, 1, c, spare, err);
}

int mp_prf_cache_build_exact(const mp_prf_model *m, int G, mp_prf_cache *c, char *err)
{
    return build(m, G, 0, c, NULL, err);
}

/* The δP² of an interpolation (lin: the bilinear one) and the bins of a
 * mode's (a core tier's: its own, core_bins). */
static const float *d2_of(const mp_prf_cache *c, int lin)
{
    return c ? (lin ? c->d2l : c->d2) : NULL;
}

static const double *bins_of(const mp_prf_cache *c, int mode)
{
    if (!c)
        return NULL;
    if (mode >= 2)
        return c->d2cbin ? c->d2cbin + (size_t)(mode - 2) * c->nph * MP_PRF_CACHE_NBIN : NULL;
    return mode ? c->d2lbin : c->d2bin;
}

/* One cell's Σ δP²/v of a core tier: the cubic's δP² (d) within the
 * core's rows and columns, the bilinear's (dl) elsewhere. */
static double core_sum(const mp_prf_cache *c, int r, const float *p, const float *d,
                       const float *dl, double E, double var0)
{
    double s = 0.0;
    for (long j = 0; j < c->uh; j++) {
        int row = in_core(j + c->uy0, r);
        for (long i = 0; i < c->uw; i++) {
            size_t q = (size_t)j * c->uw + (size_t)i;
            double v = E * p[q] + var0;
            if (v > 0)
                s += (row && in_core(i + c->ux0, r) ? d[q] : dl[q]) / v;
        }
    }
    return s;
}

/* The bound of mode over the cells, leaving out those whose sum over
 * bins with the variances inv_lo (serves_of's upper bounds of their sums)
 * is at most cut (inv_lo NULL: none left out). */
static double bound_over(const mp_prf_cache *c, int mode, double E, double B, double ron,
                         const double *inv_lo, double cut)
{
    int lin = mode == MP_PRF_BILINEAR, core = mode >= 2;
    const float *d2 = d2_of(c, lin);
    const double *bins = bins_of(c, mode);
    if (!d2)
        return INFINITY;
    double worst = 0.0, var0 = B + ron * ron;
    /* In parallel over the cells: the flux limits' bisections call this
     * from the frame fit's serial set-up (2.3 % of 47 Tuc built on one
     * thread, bench/SCALING.md); inside a group fit's parallel loop it
     * runs on that thread alone.  The largest is the same on any threads.
     * (A small grid, under ~64k terms, is not worth starting a team.) */
#pragma omp parallel for schedule(static) reduction(max : worst) if (c->nph * c->npix > 65536)
    for (int ph = 0; ph < c->nph; ph++) {
        const float *d = d2 + (size_t)ph * c->npix, *p = c->p + (size_t)ph * c->npix;
        double s = 0.0;
        if (inv_lo && bins) {
            const double *bin = bins + (size_t)ph * MP_PRF_CACHE_NBIN;
            for (int b = 0; b < MP_PRF_CACHE_NBIN; b++)
                s += bin[b] * inv_lo[b];
            if (s <= cut)
                continue;
            s = 0.0;
        }
        if (core) {
            s = core_sum(c, core_radius[mode - 2], p, d, c->d2l + (size_t)ph * c->npix, E, var0);
            worst = s > worst ? s : worst;
            continue;
        }
        for (size_t i = 0; i < c->npix; i++) {
            double v = E * p[i] + var0;
            if (v > 0)
                s += d[i] / v;
        }
        worst = s > worst ? s : worst;
    }
    return E * sqrt(worst);
}

static double bound_of(const mp_prf_cache *c, int lin, double E, double B, double ron)
{
    return bound_over(c, lin, E, B, ron, NULL, 0.0);
}

double mp_prf_cache_bound(const mp_prf_cache *c, double E, double B, double ron)
{
    return bound_of(c, 0, E, B, ron);
}

double mp_prf_cache_bound_lin(const mp_prf_cache *c, double E, double B, double ron)
{
    return bound_of(c, 1, E, B, ron);
}

double mp_prf_cache_bound_core(const mp_prf_cache *c, int k, double E, double B, double ron)
{
    return k >= 0 && k < MP_PRF_NCORE ? bound_of(c, 2 + k, E, B, ron) : INFINITY;
}

/* Whether mode's bound at E is ≤ frac: by the bins where they decide,
 * else, with exact, by the pixels' sums, without, not (a core tier's
 * limit: conservative, and no pixel summed). */
static int serves_of(const mp_prf_cache *c, int mode, double E, double B, double ron, double frac,
                     int exact)
{
    const double *bins = bins_of(c, mode);
    if (!d2_of(c, mode) || !bins || !(E >= 0))
        return 0;
    /* Within bin b ≥ 1 a pixel's variance lies in [v0 + E·pmax·2^−b,
     * v0 + E·pmax·2^(1−b)] (the last bin's lower end v0), in bin 0 in
     * [v0 + E·pmin, v0]: each cell's Σ δP²/v, and so their largest, lies
     * between the sums over bins at the ends.  With every lower end
     * positive (no pixel skipped) the bounds decide; the margin keeps the
     * decision the summed bound's where the two meet within rounding. */
    double v0 = B + ron * ron, f2 = frac * frac / (E * E);
    double lo0 = v0 + E * fmin(c->pmin, 0.0);
    double inv_lo[MP_PRF_CACHE_NBIN], inv_hi[MP_PRF_CACHE_NBIN];
    int binned = lo0 > 0 && c->pmax > 0;
    if (binned) {
        inv_lo[0] = 1.0 / lo0;
        inv_hi[0] = 1.0 / v0;
        for (int b = 1; b < MP_PRF_CACHE_NBIN; b++) {
            double top = c->pmax * exp2(1 - b), bot = b < MP_PRF_CACHE_NBIN - 1 ? 0.5 * top : 0.0;
            inv_lo[b] = 1.0 / (v0 + E * bot);
            inv_hi[b] = 1.0 / (v0 + E * top);
        }
        double up = 0.0, low = 0.0;
        for (int ph = 0; ph < c->nph; ph++) {
            const double *bin = bins + (size_t)ph * MP_PRF_CACHE_NBIN;
            double su = 0.0, sl = 0.0;
            for (int b = 0; b < MP_PRF_CACHE_NBIN; b++) {
                su += bin[b] * inv_lo[b];
                sl += bin[b] * inv_hi[b];
            }
            up = su > up ? su : up;
            low = sl > low ? sl : low;
        }
        if (up <= f2 * (1.0 - 1e-9))
            return 1;
        if (low > f2 * (1.0 + 1e-9))
            return 0;
    }
    if (!exact)
        return 0;
    /* Undecided: the cells summed pixel by pixel, but not those whose
     * upper bound is below the cut (their sums are: at most frac·√(1 −
     * 1e−9), so the largest, where the decision lies, is among the rest —
     * the same decision; 47 Tuc with Tiny Tim's table: its limits' 2.89 →
     * 1.51·10⁹ instructions). */
    return bound_over(c, mode, E, B, ron, binned ? inv_lo : NULL, f2 * (1.0 - 1e-9)) <= frac;
}

int mp_prf_cache_serves(const mp_prf_cache *c, double E, double B, double ron, double frac)
{
    return serves_of(c, 0, E, B, ron, frac, 1);
}

/* q(E) increases with E (each term E²δP²/(E P + v) does): bisection in log E,
 * each flux decided as mp_prf_cache_serves decides it. */
static double limit_of(const mp_prf_cache *c, int mode, double B, double ron, double frac,
                       int exact)
{
    double lo = 1e-3, hi = 1e15;
    if (!serves_of(c, mode, lo, B, ron, frac, exact))
        return 0.0;
    if (serves_of(c, mode, hi, B, ron, frac, exact))
        return INFINITY;
    for (int it = 0; it < MP_SINC_LIMITS_EVALS - 2; it++) {  /* 18 decades: E to 0.25 % */
        double mid = sqrt(lo * hi);
        if (serves_of(c, mode, mid, B, ron, frac, exact))
            lo = mid;
        else
            hi = mid;
    }
    return lo;
}

double mp_prf_cache_limit(const mp_prf_cache *c, double B, double ron, double frac)
{
    return limit_of(c, 0, B, ron, frac, 1);
}

double mp_prf_cache_limit_lin(const mp_prf_cache *c, double B, double ron, double frac)
{
    return limit_of(c, 1, B, ron, frac, 1);
}

double mp_prf_cache_limit_core(const mp_prf_cache *c, int k, double B, double ron, double frac)
{
    return k >= 0 && k < MP_PRF_NCORE ? limit_of(c, 2 + k, B, ron, frac, 0) : 0.0;
}

void mp_prf_cache_tiers(const mp_prf_cache *c, double B, double ron, double frac, int exact,
                        mp_prf_tiers *t)
{
    t->lin = limit_of(c, MP_PRF_BILINEAR, B, ron, frac, exact);
    for (int k = 0; k < MP_PRF_NCORE; k++)
        t->core[k] = mp_prf_cache_limit_core(c, k, B, ron, frac);
}

int mp_prf_tier_mode_from(const mp_prf_tiers *t, double E, int from)
{
    double e = fabs(E);
    if (!t || from == MP_PRF_CUBIC)
        return MP_PRF_CUBIC;
    if (from == MP_PRF_BILINEAR && e <= t->lin)
        return MP_PRF_BILINEAR;
    for (int k = from >= 2 ? from - 2 : 0; k < MP_PRF_NCORE; k++)
        if (e <= t->core[k])
            return MP_PRF_CORE(k);
    return MP_PRF_CUBIC;
}

int mp_prf_tier_mode(const mp_prf_tiers *t, double E)
{
    return mp_prf_tier_mode_from(t, E, MP_PRF_BILINEAR);
}
