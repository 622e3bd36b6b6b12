/* cosmics.c — cosmic rays and hot pixels masked: pixels that no sum of
 * stars can make (crmask=yes).
 *
 * Light that passed through the optics reaches a pixel's four side
 * neighbours too: for every star at any phase and place, and every PRF
 * pixel holding at least MP_PL_CR_CORE of the star's peak pixel, those
 * neighbours hold at least s times the pixel (s measured on the PSF,
 * mp_pl_cr_bound).  A sum of stars keeps that ratio, since each of them
 * does: s·(d_p − B) − Σ_nb (d − B) ≤ 0 wherever starlight is all there
 * is.  A cosmic ray, a charged particle's track through one or a few
 * pixels, breaks it.  The fainter PRF pixels (a star's wings, where the
 * ratio does not hold) are bounded by D per electron, the most by which
 * any of them exceeds it, times the flux of the stars reaching p.  So the
 * test flags p when T = s·(d_p − B) − Σ_nb (d − B) exceeds k σ_T + D·Φ_p,
 * k such that noise alone flags 0.01 pixel a frame.  T grows with B by
 * (4 − s)·B, so a sky set too high would pass starlight: B is taken from
 * below.  And s is scaled by the frame's brightest stars' own ratio over
 * the model's (mp_pl_cr_sharpness), so a model broader than the stars
 * (a table smoothed as its noise needs) does not pass their cores.  The
 * IRAF crutil task `cosmicrays` tests a pixel against its neighbours the
 * same way, with a flux ratio the user guesses; here the PSF and the
 * stars give it.  On 47 Tuc (FLT, DQ known) every pixel flagged is on or
 * beside one the DQ plane marks as a cosmic ray (psfreal_notes.md). */
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include "pipeline/pipeline_priv.h"

/* The least side-neighbour ratio over the PRF's brighter pixels of one
 * render (prf, w × h; zero beyond it), or with s given (>= 0), the most by
 * which s·P exceeds the neighbours' sum over all its pixels, per electron. */
static double render_ratio(const double *prf, int w, int h, double s)
{
    double peak = 0.0, flux = 0.0, out = s < 0 ? 4.0 : 0.0;
    for (int i = 0; i < w * h; i++) {
        peak = prf[i] > peak ? prf[i] : peak;
        flux += prf[i];
    }
    if (!(peak > 0) || !(flux > 0))
        return out;
    for (int j = 0; j < h; j++)
        for (int i = 0; i < w; i++) {
            double v = prf[j * w + i];
            double nb = (i > 0 ? prf[j * w + i - 1] : 0.0) +
                        (i < w - 1 ? prf[j * w + i + 1] : 0.0) +
                        (j > 0 ? prf[(j - 1) * w + i] : 0.0) +
                        (j < h - 1 ? prf[(j + 1) * w + i] : 0.0);
            if (s < 0 && v >= MP_PL_CR_CORE * peak && nb / v < out)
                out = nb / v;
            if (s >= 0 && (s * v - nb) / flux > out)
                out = (s * v - nb) / flux;
        }
    return out;
}

/* Phases a pixel's side: 0, ±1/4, ±1/2 (a star on a pixel's centre, its
 * edge and its corner, where a symmetric PSF's ratio is least). */
#define CR_NPH 5

/* The centre of place q of 3 × 3 over the nx × ny frame: its phases are
 * mp_prf_phase's about it. */
static void place_at(long nx, long ny, int q, double *x, double *y)
{
    *x = (double)(1 + (q % 3) * (nx - 1) / 2);
    *y = (double)(1 + (q / 3) * (ny - 1) / 2);
}

/* The renders of mp_pl_cr_bound: a place's phases rendered together
 * (mp_prf_render_phases: a variable PSF evaluated and the x-passes made
 * once a place; one by one, twice over, the bound was a fifth of the DECam
 * cutout's run), and kept from the first sweep for the second when they
 * fit in CR_KEEP_BYTES (else rendered again: the same values).  Kept, the
 * cutout's 225 boxes raise its peak RSS 19.3 → 23.5 MB and save 5 ms of
 * its ~205, where DAOPHOT's whole chain takes 200–220: the CPU is what
 * that frame's budget is short of (ceaed85 kept them, 254264d took that
 * back for the RSS when the run was 260 ms). */
#define CR_KEEP_BYTES ((size_t)64 << 20)
#define CR_NR (CR_NPH * CR_NPH)
typedef struct {
    const mp_prf_model *m;
    long nx, ny;
    int q0;
    double **keep;              /* CR_NR a place from q0, or NULL */
    double *cur[CR_NR];         /* place curq's, when not kept */
    int curq;
    mp_prf_work wk;
} cr_sweep;

/* Place q's renders (phase (a, b) at [b·CR_NPH + a]); NULL when out of
 * memory. */
static double *const *place_renders(cr_sweep *c, int q)
{
    double **r = c->keep ? c->keep + (size_t)(q - c->q0) * CR_NR : c->cur;
    if (c->keep ? r[0] != NULL : c->curq == q)
        return r;
    double x, y;
    place_at(c->nx, c->ny, q, &x, &y);
    for (int k = 0; k < CR_NR; k++) {
        long bx, by;
        int w, h;
        mp_prf_box(c->m, mp_prf_phase(x, k % CR_NPH, CR_NPH), mp_prf_phase(y, k / CR_NPH, CR_NPH),
                   &bx, &by, &w, &h);
        double *p = realloc(r[k], (size_t)(w > 0 ? w : 1) * (size_t)(h > 0 ? h : 1) * sizeof *p);
        if (!p)
            return NULL;
        r[k] = p;
    }
    c->curq = -1;
    if (mp_prf_render_phases(c->m, x, y, CR_NPH, r, &c->wk))
        return NULL;
    c->curq = q;
    return r;
}

/* The ratio (s < 0) or the excess (s >= 0) of render_ratio for a star at
 * place q and phase (a, b), into *out. */
static int ratio_at(cr_sweep *c, int q, int a, int b, double s, double *out)
{
    double x, y;
    long bx, by;
    int w, h;
    double *const *r = place_renders(c, q);
    if (!r)
        return 1;
    place_at(c->nx, c->ny, q, &x, &y);
    mp_prf_box(c->m, mp_prf_phase(x, a, CR_NPH), mp_prf_phase(y, b, CR_NPH), &bx, &by, &w, &h);
    *out = render_ratio(r[b * CR_NPH + a], w, h, s);
    return 0;
}

int mp_pl_cr_bound(const mp_prf_model *m, long nx, long ny, double *s, double *D, char *err)
{
    double r[CR_NPH][CR_NPH];
    /* at the 3 × 3 places only when the PSF varies (else the centre's,
     * place 4, is every place's) */
    int q0 = m->psf && m->psf->field ? 0 : 4, q1 = q0 ? 5 : 9, rc = 0;
    cr_sweep c = {.m = m, .nx = nx, .ny = ny, .q0 = q0, .curq = -1};
    long bx, by;
    int w, h;
    mp_prf_box(m, 0.5 * (double)nx, 0.5 * (double)ny, &bx, &by, &w, &h);
    size_t nk = (size_t)(q1 - q0) * CR_NR;
    if ((size_t)(w + 1) * (size_t)(h + 1) * sizeof(double) * nk <= CR_KEEP_BYTES)
        c.keep = calloc(nk, sizeof *c.keep);
    *s = 4.0;
    *D = 0.0;
    /* the least ratio over the phase grid, less half its largest step
     * between neighbouring phases: the ratio between grid phases can dip
     * below the nodes by about that much */
    for (int q = q0; q < q1 && !rc; q++) {
        double lo = 4.0, step = 0.0;
        for (int b = 0; b < CR_NPH && !rc; b++)
            for (int a = 0; a < CR_NPH && !rc; a++) {
                if ((rc = ratio_at(&c, q, a, b, -1.0, &r[b][a])))
                    break;
                lo = fmin(lo, r[b][a]);
                if (a > 0)
                    step = fmax(step, fabs(r[b][a] - r[b][a - 1]));
                if (b > 0)
                    step = fmax(step, fabs(r[b][a] - r[b - 1][a]));
            }
        *s = fmin(*s, lo - 0.5 * step);
    }
    *s = fmax(*s, 0.0);
    for (int q = q0; q < q1 && !rc; q++)
        for (int b = 0; b < CR_NPH && !rc; b++)
            for (int a = 0; a < CR_NPH && !rc; a++) {
                double e = 0.0;
                rc = ratio_at(&c, q, a, b, *s, &e);
                *D = fmax(*D, e);
            }
    for (size_t k = 0; c.keep && k < nk; k++)
        free(c.keep[k]);
    free(c.keep);
    for (int k = 0; k < CR_NR; k++)
        free(c.cur[k]);
    mp_prf_work_free(&c.wk);
    if (rc)
        snprintf(err, MP_ERRLEN, "cosmic rays: out of memory for the PSF's renders");
    return rc;
}

double mp_pl_cr_sigma(double npix, double rate)
{
    /* k with npix·Q(k) = rate, Q the normal upper tail (bisection) */
    double lo = 0.0, hi = 40.0, q = npix > rate ? rate / npix : 0.5;
    for (int it = 0; it < 100; it++) {
        double mid = 0.5 * (lo + hi);
        if (0.5 * erfc(mid / sqrt(2.0)) > q)
            lo = mid;
        else
            hi = mid;
    }
    return 0.5 * (lo + hi);
}

/* p's 8 neighbours and itself: none masked or saturated, none off the
 * frame (the test needs all four side neighbours, and a saturated
 * neighbour's value is clipped). */
static int testable(const mp_frame *f, long x, long y)
{
    long nx = f->im.nx, ny = f->im.ny;
    if (x < 1 || y < 1 || x >= nx - 1 || y >= ny - 1)
        return 0;
    for (long j = y - 1; j <= y + 1; j++)
        for (long i = x - 1; i <= x + 1; i++)
            if (f->mask[j * nx + i])
                return 0;
    return 1;
}

static double var_at(const mp_frame *f, size_t k, double ron2)
{
    double d = f->im.pix[k];
    return (d > 0 ? d : 0.0) + ron2 + (f->xvar ? f->xvar[k] : 0.0);
}

/* At p (0-based x, y): the starlight test's excess with no sky,
 * s·d_p − Σ_nb d, into *t, and its σ into *sig. */
static void excess_at(const mp_frame *f, long x, long y, double s, double *t, double *sig)
{
    long nx = f->im.nx;
    size_t k = (size_t)(y * nx + x), nb[4] = {k - 1, k + 1, k - (size_t)nx, k + (size_t)nx};
    double ron2 = f->rdnoise * f->rdnoise;
    *t = s * f->im.pix[k];
    double v = s * s * var_at(f, k, ron2);
    for (int a = 0; a < 4; a++) {
        *t -= f->im.pix[nb[a]];
        v += var_at(f, nb[a], ron2);
    }
    *sig = sqrt(v);
}

/* The sky under p from below: the 10th percentile of the unmasked pixels
 * of the box of side `side` around it (1.28 σ of a pixel under the sky
 * between stars; in a crowd, under the mode), and no higher than bb, the
 * sky of the mesh there, nor than the least pixel of p's 3 × 3 (where the
 * sky dips under the box's, as on a mosaic's uneven background, a pixel
 * above its lower neighbours would pass for a hit).  v: room for that
 * box clipped to the frame. */
static double sky_below(const mp_frame *f, double bb, long x, long y, int side, double *v)
{
    long nx = f->im.nx, ny = f->im.ny, h = side / 2;
    size_t n = 0;
    for (long j = y - h > 0 ? y - h : 0; j <= y + h && j < ny; j++)
        for (long i = x - h > 0 ? x - h : 0; i <= x + h && i < nx; i++)
            if (!f->mask[j * nx + i])
                v[n++] = f->im.pix[j * nx + i];
    double lo = bb;                   /* and the 3 × 3's least (a dip) */
    for (long j = y - 1; j <= y + 1; j++)
        for (long i = x - 1; i <= x + 1; i++)
            lo = fmin(lo, f->im.pix[j * nx + i]);
    return n ? fmin(lo, mp_select_kth(v, n, n / 10)) : lo;
}

/* Φ: the flux of the stars whose table reaches (x, y) (0-based). */
static double flux_near(const mp_pl_cr_stars *st, double x, double y)
{
    double phi = 0.0;
    for (size_t i = 0; i < st->n; i++)
        if (fabs(st->s[i].x - 1.0 - x) <= st->reach && fabs(st->s[i].y - 1.0 - y) <= st->reach)
            phi += st->s[i].e;
    return phi;
}

/* Whether p (0-based x, y) is flagged: T = s·(d_p − B) − Σ_nb (d − B)
 * grows with B by (4 − s)·B, so it is tried first with B at d_p + 3 σ_p,
 * above any sky under p (most pixels end here), then at the mesh's sky,
 * B's cap, then with the sky from below and the wings' allowance; never
 * within MP_PL_CR_GUARD px of a guarded star (ct->guard).  v: sky_below's
 * room. */
static int flagged(const mp_frame *f, const mp_bkg *b, const mp_pl_cr_stars *st,
                   const mp_pl_cr_test *ct, long x, long y, double *v)
{
    double t, sig;
    if (!testable(f, x, y))
        return 0;
    excess_at(f, x, y, ct->s, &t, &sig);
    size_t k = (size_t)(y * f->im.nx + x);
    double hi = f->im.pix[k] + 3.0 * sqrt(var_at(f, k, f->rdnoise * f->rdnoise));
    if (!(t + (4.0 - ct->s) * hi > ct->k * sig))
        return 0;
    double bb = mp_bkg_sky(b, k);
    if (!(t + (4.0 - ct->s) * bb > ct->k * sig))
        return 0;
    for (size_t g = 0; st && g < ct->nguard; g++)
        if (fabs(st->s[ct->guard[g]].x - 1.0 - x) <= MP_PL_CR_GUARD &&
            fabs(st->s[ct->guard[g]].y - 1.0 - y) <= MP_PL_CR_GUARD)
            return 0;
    double B = sky_below(f, bb, x, y, ct->side, v);
    double phi = st ? flux_near(st, (double)x, (double)y) : 0.0;
    return t + (4.0 - ct->s) * B - ct->D * phi > ct->k * sig;
}

/* The pixels within g of each hit masked bad (unless masked already) and
 * NaN in res (may be NULL); returns how many.  Only the rows with a hit
 * (rowhits) are read: the map is calloc'd, and reading its untouched
 * pages faults them in on this kernel (a 64 MiB calloc read: RSS +65 MB),
 * so a scan of the whole map held a frame's worth of bytes at 8192², the
 * run's peak (bench/SCALING.md, session 48). */
static long mask_around(mp_frame *f, const uint8_t *hit, const long *rowhits, int g, float *res)
{
    long nx = f->im.nx, ny = f->im.ny, masked = 0;
    for (long y = 0; y < ny; y++)
        for (long x = 0; x < nx && rowhits[y]; x++) {
            if (!hit[y * nx + x])
                continue;
            for (long j = y - g > 0 ? y - g : 0; j <= y + g && j < ny; j++)
                for (long i = x - g > 0 ? x - g : 0; i <= x + g && i < nx; i++) {
                    size_t k = (size_t)(j * nx + i);
                    if (f->mask[k])
                        continue;
                    f->mask[k] = MP_MASK_BAD;
                    f->nbad++;
                    if (res)
                        res[k] = NAN;
                    masked++;
                }
        }
    return masked;
}

long mp_pl_mask_cosmics(mp_frame *f, const mp_bkg *b, float *res, const mp_pl_cr_stars *st,
                        const mp_pl_cr_test *ct, long *cores)
{
    long nx = f->im.nx, ny = f->im.ny;
    uint8_t *hit = calloc((size_t)(nx * ny), 1);
    long *rowhits = calloc((size_t)ny, sizeof *rowhits);
    if (!hit || !rowhits) {
        free(hit);
        free(rowhits);
        return -1;
    }
    long nc = 0;
    int failed = 0;
#pragma omp parallel reduction(+ : nc) reduction(| : failed)
    {
        /* sky_below's box, clipped to the frame (mesh may be any size) */
        size_t box = 2 * (size_t)(ct->side / 2) + 1;
        size_t bw = box < (size_t)nx ? box : (size_t)nx, bh = box < (size_t)ny ? box : (size_t)ny;
        double *v = malloc(bw * bh * sizeof *v);
        failed |= !v;
#pragma omp for schedule(dynamic, 16)
        for (long y = 1; y < ny - 1; y++)
            for (long x = 1; x < nx - 1; x++)
                if (v && flagged(f, b, st, ct, x, y, v)) {
                    hit[y * nx + x] = 1;
                    rowhits[y]++;       /* row y is this thread's alone */
                    nc++;
                }
        free(v);
    }
    long masked = failed ? -1 : mask_around(f, hit, rowhits, ct->grow, res);
    free(hit);
    free(rowhits);
    *cores = nc;
    return masked;
}

/* The side-neighbour ratio at pixel (px, py) (0-based) of image v on
 * box (x0, y0, w × h) (0-based origin), less sky B, NaN off the box; with
 * ron2 >= 0 its σ from the pixels' Poisson and read noise into *sig. */
static double ratio_in(const double *v, long x0, long y0, int w, int h, long px, long py, double B,
                       double ron2, double *sig)
{
    long i = px - x0, j = py - y0;
    if (i < 1 || j < 1 || i >= w - 1 || j >= h - 1)
        return NAN;
    const double *c = v + j * w + i;
    double n = c[-1] + c[1] + c[-w] + c[w] - 4.0 * B, p = c[0] - B, r = n / p;
    if (ron2 >= 0) {
        double vn = 4.0 * ron2, vp = fmax(c[0], 0.0) + ron2;
        for (int a = 0; a < 4; a++)
            vn += fmax(c[a == 0 ? -1 : a == 1 ? 1 : a == 2 ? -w : w], 0.0);
        *sig = sqrt(vn + r * r * vp) / fabs(p);
    }
    return r;
}

/* One star's ratio observed over the model's at its peak pixel, and its
 * σ into *sq (NaN when not measurable, or when that σ is above
 * MP_PL_CR_SHARP_SIG: a faint star's ratio says more of its noise than of
 * its shape). */
static double star_sharpness(const mp_frame *f, const mp_prf_model *m, double x, double y,
                             double B, double **prf, mp_prf_work *wk, double *sq)
{
    long nx = f->im.nx, bx, by;
    int w, h;
    mp_prf_box(m, x, y, &bx, &by, &w, &h);
    double *p = realloc(*prf, (size_t)(w > 0 ? w : 1) * (size_t)(h > 0 ? h : 1) * sizeof *p);
    if (!p)
        return NAN;
    *prf = p;
    if (w < 3 || h < 3 || mp_prf_render(m, x, y, p, NULL, NULL, wk))
        return NAN;
    int top = 0;                      /* the model's peak pixel */
    for (int i = 1; i < w * h; i++)
        top = p[i] > p[top] ? i : top;
    long px = bx - 1 + top % w, py = by - 1 + top / w;
    if (!testable(f, px, py))
        return NAN;
    double obs[9];
    for (int k = 0; k < 9; k++)
        obs[k] = f->im.pix[(py - 1 + k / 3) * nx + px - 1 + k % 3];
    for (int k = 0; k < 9; k++)
        if (obs[k] > obs[4])
            return NAN;               /* another star's light leads there */
    double sig = NAN, rm = ratio_in(p, bx - 1, by - 1, w, h, px, py, 0.0, -1.0, &sig);
    double ro = ratio_in(obs, px - 1, py - 1, 3, 3, px, py, B, f->rdnoise * f->rdnoise, &sig);
    if (!(rm > 0) || !isfinite(ro) || !(sig / rm <= MP_PL_CR_SHARP_SIG))
        return NAN;
    *sq = sig / rm;
    return ro / rm;
}

double mp_pl_cr_sharpness(const mp_frame *f, const mp_prf_model *m, const mp_pl_cr_stars *st,
                          size_t *guard, size_t *nguard)
{
    *nguard = 0;
    if (!st || st->n == 0)
        return 1.0;
    double q[MP_PL_CR_NSHARP], *prf = NULL, out = 1.0, sq;
    mp_prf_work wk = {0};
    size_t nq = 0;
    for (size_t i = 0; i < st->n && nq < MP_PL_CR_NSHARP; i++) {
        const mp_pl_star *p = &st->s[i];
        double v = isfinite(p->sky) ? star_sharpness(f, m, p->x, p->y, p->sky, &prf, &wk, &sq)
                                    : NAN;
        if (isfinite(v)) {
            guard[nq] = i;
            q[nq++] = v;
        }
    }
    /* every star of the frame's, from the measured ones' spread: their
     * median less z of their robust σ, z such that all n stars of st stay
     * above it but for MP_PL_CR_RATE of a star (the spread holds the
     * ratios' noise too, so it errs low).  Not their least: a hit the
     * first round took for a bright star (a sharp one passes find's
     * limits) has the ratio of a hit, near 0, and would switch the test
     * off on the frames that need it; the median and its spread do not
     * see a few. */
    if (nq >= MP_PL_CR_NMIN) {
        double med = mp_median_select(q, nq), sd = mp_mad_sigma(q, nq);
        out = fmin(out, med - mp_pl_cr_sigma((double)st->n, MP_PL_CR_RATE) * sd);
    } else {
        *nguard = nq;       /* too few to check the model on: kept out */
    }
    free(prf);
    mp_prf_work_free(&wk);
    return out > 0 ? out : 0.0;
}
