/* lookup.c — what the PSF leaves around every bright star (pipeline
 * lookup=yes, mp_pl_lookup in pipeline_priv.h; issue 13).
 *
 * A table that misses part of the light — cut off before a segmented
 * mirror's spikes and rings end, or built from the frame with wings too
 * low — leaves the same pattern per electron around every star: in the
 * segmented scene of validate/CROWDED.md, with the PSF built from the frame,
 * 1130 false detections, half of them within 5 degrees of a spike, 10-14 px
 * from stars 5+ mag brighter (outside the built table's 9 px).  The pattern
 * is measured as DAOPHOT's look-up table of corrections is: the mean
 * residual per electron around the brightest stars, here in 2-D on the
 * detector grid (spikes have no azimuthal symmetry, so pipeline/halo.c's
 * radial profile cannot hold them), kept only where it is significant, and
 * taken off the frame as known light around every star bright enough for
 * it to matter. */
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include "pipeline/pipeline_priv.h"

/* Stars stacked (the brightest), the significance an element of the look-up
 * must reach to be kept (two-sided 3 σ: 0.27 % of pure-noise elements), and
 * the fraction of a sky pixel's σ a star's correction must reach to be
 * taken off around it. */
enum { LK_NSTAR = 50 };
#define LK_NSIG 3.0
#define LK_MINSKY 0.05
#define LK_MINEFF 5.0
/* Elements a pixel per axis.  At 1 the stack and its read-back (both
 * bilinear) widen a FWHM-3 feature enough to leave 17 % of its peak
 * (test_lookup: 36 false entries -> 11); at 2 nine stars are too few to
 * make the finer elements significant (-> 31). */
#define LK_OS 1


typedef struct {
    int hp, os;           /* half-size [px]; elements a pixel, per axis */
    int h, n;             /* half-size hp·os, side 2h + 1 [elements] */
    double rin;           /* inside rin nothing is stacked or taken off */
    double *num, *den, *sq, *w2;   /* per element, y = (r − sky)/E of a star's
                                 * pixel, u = w·E² its weight: Σ u·y, Σ u,
                                 * Σ u·y², Σ u² */
    double *m, *sig;      /* the look-up per e-, its σ */
} lookup;

/* The star's sky: the median residual on the square ring just outside the
 * look-up's box (NaN with fewer than 8 pixels). */
static double sky_near(const mp_frame *f, const float *res, const mp_pl_star *s, int h, double *buf)
{
    long cx = lround(s->x), cy = lround(s->y);
    size_t m = 0;
    for (long y = cy - h - 2; y <= cy + h + 2; y++)
        for (long x = cx - h - 2; x <= cx + h + 2; x++) {
            if (labs(x - cx) <= h && labs(y - cy) <= h)
                continue;
            if (x < 1 || y < 1 || x > f->im.nx || y > f->im.ny)
                continue;
            size_t i = (size_t)(y - 1) * (size_t)f->im.nx + (size_t)(x - 1);
            if (!f->mask[i] && isfinite(res[i]))
                buf[m++] = res[i];
        }
    if (m < 8)
        return NAN;
    return mp_epsf_median(buf, m);
}

/* Star s's residual into the stack: each pixel at offset (dx, dy) from the
 * star spread over the four elements around it with bilinear weights (so
 * the stars' subpixel phases average rather than blur by a whole pixel),
 * as a least-squares estimate of the look-up per electron. */
static void stack_star(lookup *L, const mp_frame *f, const float *res, const mp_pl_star *s, double sky)
{
    long x0 = (long)floor(s->x) - L->hp, y0 = (long)floor(s->y) - L->hp;
    for (long y = y0; y <= y0 + 2 * L->hp + 1; y++)
        for (long x = x0; x <= x0 + 2 * L->hp + 1; x++) {
            if (x < 1 || y < 1 || x > f->im.nx || y > f->im.ny)
                continue;
            size_t i = (size_t)(y - 1) * (size_t)f->im.nx + (size_t)(x - 1);
            if (f->mask[i] || !isfinite(res[i]))
                continue;
            double dx = L->os * ((double)x - s->x), dy = L->os * ((double)y - s->y);
            double fx = floor(dx), fy = floor(dy), tx = dx - fx, ty = dy - fy;
            double y = (res[i] - sky) / s->e;
            for (int q = 0; q < 4; q++) {
                long ex = (long)fx + (q & 1), ey = (long)fy + (q >> 1);
                double w = ((q & 1) ? tx : 1 - tx) * ((q >> 1) ? ty : 1 - ty);
                if (w <= 0 || labs(ex) > L->h || labs(ey) > L->h)
                    continue;
                size_t k = (size_t)(ey + L->h) * (size_t)L->n + (size_t)(ex + L->h);
                double u = w * s->e * s->e;
                L->num[k] += u * y;
                L->den[k] += u;
                L->sq[k] += u * y * y;
                L->w2[k] += u * u;
            }
        }
}

/* The look-up from the stack: M = Σuy/Σu, its σ from the stars' own
 * scatter about it (the weighted variance over the effective number of
 * stars (Σu)²/Σu²: so that the neighbours' residuals and the stars too
 * faint to be found count as the noise they are, which the pixels'
 * Poisson variance leaves out); elements within rin of the centre, seen
 * by fewer than LK_MINEFF stars' worth, or below LK_NSIG σ are 0.
 * Returns the elements kept. */
static long finish(lookup *L)
{
    long kept = 0;
    for (int j = 0; j < L->n; j++)
        for (int i = 0; i < L->n; i++) {
            size_t k = (size_t)j * (size_t)L->n + (size_t)i;
            double r = hypot(i - L->h, j - L->h) / L->os;
            L->m[k] = L->sig[k] = 0.0;
            if (r < L->rin || !(L->den[k] > 0))
                continue;
            double neff = L->den[k] * L->den[k] / L->w2[k], m = L->num[k] / L->den[k];
            double sg = sqrt(fmax(L->sq[k] / L->den[k] - m * m, 0.0) / fmax(neff - 1.0, 1.0));
            if (neff < LK_MINEFF)
                continue;
            if (fabs(m) >= LK_NSIG * sg) {
                L->m[k] = m;
                L->sig[k] = sg;
                kept++;
            }
        }
    return kept;
}

/* The look-up at offset (dx, dy) [px], bilinear; its σ likewise. */
static double at(const lookup *L, const double *v, double dx, double dy)
{
    dx *= L->os;
    dy *= L->os;
    double fx = floor(dx), fy = floor(dy), tx = dx - fx, ty = dy - fy, s = 0.0;
    for (int q = 0; q < 4; q++) {
        long ex = (long)fx + (q & 1), ey = (long)fy + (q >> 1);
        if (labs(ex) > L->h || labs(ey) > L->h)
            continue;
        double w = ((q & 1) ? tx : 1 - tx) * ((q >> 1) ? ty : 1 - ty);
        s += w * v[(size_t)(ey + L->h) * (size_t)L->n + (size_t)(ex + L->h)];
    }
    return s;
}

/* E·M around every star whose largest correction reaches LK_MINSKY of a
 * sky pixel's σ taken off f and res, (E·σ_M)² added to f->xvar; *nlit
 * counts the stars. */
static int take_off(const lookup *L, mp_frame *f, float *res, const mp_pl_star *s, size_t ns,
                    double sigsky, long *nlit)
{
    size_t npix = (size_t)f->im.nx * (size_t)f->im.ny;
    double mmax = 0.0;
    for (size_t k = 0; k < (size_t)L->n * (size_t)L->n; k++)
        mmax = fmax(mmax, fabs(L->m[k]));
    *nlit = 0;
    if (!(mmax > 0))
        return 0;
    if (!f->xvar && !(f->xvar = calloc(npix ? npix : 1, sizeof *f->xvar)))
        return 1;
    for (size_t k = 0; k < ns && s[k].e * mmax >= LK_MINSKY * sigsky; k++) {
        (*nlit)++;
        long x0 = (long)floor(s[k].x) - L->hp, y0 = (long)floor(s[k].y) - L->hp;
        for (long y = y0; y <= y0 + 2 * L->hp + 1; y++)
            for (long x = x0; x <= x0 + 2 * L->hp + 1; x++) {
                if (x < 1 || y < 1 || x > f->im.nx || y > f->im.ny)
                    continue;
                size_t i = (size_t)(y - 1) * (size_t)f->im.nx + (size_t)(x - 1);
                double dx = (double)x - s[k].x, dy = (double)y - s[k].y;
                double c = s[k].e * at(L, L->m, dx, dy), sg = s[k].e * at(L, L->sig, dx, dy);
                if (f->mask[i] || hypot(dx, dy) < L->rin)
                    continue;
                f->im.pix[i] -= (float)c;
                res[i] -= (float)c;
                f->xvar[i] += (float)(sg * sg);
            }
    }
    return 0;
}

/* The stars to stack: the LK_NSTAR brightest unsaturated ones of s (ns)
 * within 2.5 mag of the brightest (the stars whose features matter, not
 * the features themselves, which the first round fitted as stars), at
 * s[*last] the faintest of them; *nst how many. */
static void pick(const mp_pl_star *s, size_t ns, size_t *last, size_t *nst)
{
    double emax = NAN;
    *nst = 0;
    *last = 0;
    for (size_t k = 0; k < ns && *nst < LK_NSTAR; k++)
        if (!(s[k].flags & 1)) {
            if (isnan(emax))
                emax = s[k].e;
            if (s[k].e < 0.1 * emax)
                break;
            (*nst)++;
            *last = k;
        }
}

/* rb = f's data less the light of t's stars of flux >= ecut only (sky
 * kept): the stars that sit on a bright star's features, which the first
 * round fitted as stars, put back, so the stack sees the features (and,
 * averaged over the stars, the neighbours as the noise they are). */
static int bright_residual(const mp_frame *f, const mp_prf_model *m, const mp_table *t,
                           double cropfrac, double ecut, float *rb, char *err)
{
    const char *cols[4] = {"XPSF_IMAGE", "YPSF_IMAGE", "FLUX_PSF", "SKY_PSF"};
    int from[4], to[4], rc = 1;
    mp_table b;
    mp_table_init(&b);
    for (int c = 0; c < 4; c++)
        if ((from[c] = mp_table_col(t, cols[c])) < 0 || (to[c] = mp_table_add_col(&b, cols[c])) < 0)
            goto done;
    for (size_t r = 0; r < t->nrow; r++) {
        if (!(mp_table_get(t, r, from[2]) >= ecut))
            continue;
        long row = mp_table_add_row(&b);
        if (row < 0)
            goto done;
        for (int c = 0; c < 4; c++)
            mp_table_set(&b, (size_t)row, to[c], mp_table_get(t, r, from[c]));
    }
    rc = mp_fit_residual(f, m, &b, cropfrac, rb, err);
done:
    if (rc && !err[0])
        snprintf(err, MP_ERRLEN, "out of memory for the PSF's look-up");
    mp_table_free(&b);
    return rc;
}

static void lookup_free(lookup *L)
{
    free(L->num);
    free(L->den);
    free(L->sq);
    free(L->w2);
    free(L->m);
    free(L->sig);
}

int mp_pl_lookup(mp_frame *f, float *res, const mp_table *t, const mp_prf_model *m,
                 double cropfrac, double fwhm, double rin, char *what, size_t wlen, char *err)
{
    lookup L = {0};
    L.hp = (int)ceil(16.0 * fmax(fwhm, 1.0));
    L.os = LK_OS;
    L.h = L.hp * L.os;
    L.n = 2 * L.h + 1;
    L.rin = rin;
    size_t nel = (size_t)L.n * (size_t)L.n, ns = 0, used = 0;
    /* Converged fits only (FLAGS 8, 16 not set), brightest first. */
    mp_pl_star *s = mp_pl_stars_by_flux(t, 8 | 16, &ns);
    double *buf = malloc((size_t)(2 * L.hp + 5) * (size_t)(2 * L.hp + 5) * sizeof *buf);
    L.num = calloc(nel, sizeof *L.num);
    L.den = calloc(nel, sizeof *L.den);
    L.sq = calloc(nel, sizeof *L.sq);
    L.w2 = calloc(nel, sizeof *L.w2);
    L.m = calloc(nel, sizeof *L.m);
    L.sig = calloc(nel, sizeof *L.sig);
    long nlit = 0, kept = 0;
    int rc = 1;
    size_t npix = (size_t)f->im.nx * (size_t)f->im.ny, last, nst;
    float *rb = malloc((npix ? npix : 1) * sizeof *rb);
    err[0] = '\0';
    if (!s || !buf || !rb || !L.num || !L.den || !L.sq || !L.w2 || !L.m || !L.sig)
        goto oom;
    /* Stars >= 5 mag fainter than the faintest stacked one put back. */
    pick(s, ns, &last, &nst);
    if (nst && bright_residual(f, m, t, cropfrac, 0.01 * s[last].e, rb, err))
        goto fail;
    for (size_t k = 0; nst && k <= last; k++) {
        if (s[k].flags & 1)
            continue;            /* spilled charge is no PSF's */
        double sky = sky_near(f, rb, &s[k], L.hp, buf);
        if (!isfinite(sky))
            continue;
        stack_star(&L, f, rb, &s[k], sky);
        used++;
    }
    kept = finish(&L);
    double sky = mp_pl_median_sky(t), sig = sqrt(fmax(sky, 0.0) + f->rdnoise * f->rdnoise);
    if (take_off(&L, f, res, s, ns, sig, &nlit))
        goto oom;
    snprintf(what, wlen, "look-up of the PSF's residual from the %zu brightest stars (+-%d px, "
             "x%d, r >= %.3g px): %ld of %zu elements significant at %g sigma; taken off around "
             "%ld stars", used, L.hp, L.os, rin, kept, nel, LK_NSIG, nlit);
    rc = 0;
    goto done;
oom:
    snprintf(err, MP_ERRLEN, "out of memory for the PSF's look-up");
fail:
done:
    free(rb);
    lookup_free(&L);
    free(s);
    free(buf);
    return rc;
}
