/* halo.c — the light of bright stars beyond what the PSF table holds
 * (pipeline halo=yes, mp_pl_halo in pipeline_priv.h).
 *
 * A table built from a crowded frame's stars misses their outer wings: each
 * PSF star's sky is taken from an annulus that still holds its own light,
 * so the table's wings come out low, and it ends at psfrad.  Around a
 * saturated star of 10⁷ e⁻ (47 Tuc) that light is 3-4 σ a pixel out to
 * 18 px, more than a group's quadratic sky can follow.  The halo is modelled
 * as what it is: an azimuthally symmetric profile h(r) per electron of the
 * star, measured on the residual of the brightest stars, added to every
 * star's light as E·h(r) and taken off the frame as known light (its
 * Poisson variance goes to the pixels' xvar, io.h), so that the PSF's
 * second pass and every later fit see data the table describes. */
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include "pipeline/pipeline_priv.h"

enum { HALO_NSTAR = 10, HALO_MINPIX = 5 };

/* The unmasked residual values in the ring [r0, r1) around s, in buf. */
static size_t ring_values(const mp_frame *f, const float *res, const mp_pl_star *s, double r0,
                          double r1, double *buf)
{
    long nx = f->im.nx, ny = f->im.ny, n = 0;
    long x0 = (long)floor(s->x - r1), x1 = (long)ceil(s->x + r1);
    long y0 = (long)floor(s->y - r1), y1 = (long)ceil(s->y + r1);
    for (long y = y0 < 1 ? 1 : y0; y <= y1 && y <= ny; y++)
        for (long x = x0 < 1 ? 1 : x0; x <= x1 && x <= nx; x++) {
            size_t i = (size_t)(y - 1) * (size_t)nx + (size_t)(x - 1);
            double r = hypot((double)x - s->x, (double)y - s->y);
            if (r >= r0 && r < r1 && !f->mask[i] && isfinite(res[i]))
                buf[n++] = res[i];
        }
    return (size_t)n;
}

/* The median of the ring [r0, r1) around s and its standard error,
 * 1.2533 σ/√m with σ the ring's robust scatter (IQR/1.349; the median of m
 * Gaussian values scatters √(π/2) more than their mean).  0 with fewer than
 * HALO_MINPIX pixels. */
static int ring_median(const mp_frame *f, const float *res, const mp_pl_star *s, double r0, double r1,
                       double *buf, double *med, double *se)
{
    size_t m = ring_values(f, res, s, r0, r1, buf);
    if (m < HALO_MINPIX)
        return 0;
    *med = mp_epsf_median(buf, m);          /* sorts buf */
    double iqr = buf[(3 * m) / 4] - buf[m / 4];
    *se = 1.2533 * (iqr / 1.349) / sqrt((double)m);
    return 1;
}

/* The non-increasing sequence nearest h in the least squares of weights
 * w (pool-adjacent-violators), in place; scratch holds 3n. */
static void non_increasing(double *h, const double *w, int n, double *scratch)
{
    double *v = scratch, *wt = scratch + n, *len = scratch + 2 * n;
    int m = 0;
    for (int j = 0; j < n; j++) {
        v[m] = h[j];
        wt[m] = w[j] > 0 ? w[j] : 1e-300;
        len[m++] = 1;
        while (m > 1 && v[m - 2] < v[m - 1]) {
            double W = wt[m - 2] + wt[m - 1];
            v[m - 2] = (wt[m - 2] * v[m - 2] + wt[m - 1] * v[m - 1]) / W;
            wt[m - 2] = W;
            len[m - 2] += len[m - 1];
            m--;
        }
    }
    for (int b = 0, j = 0; b < m; b++)
        for (int q = 0; q < (int)len[b]; q++)
            h[j++] = v[b];
}

/* The area of ring j, [rin + j, rin + j + 1). */
static double ring_area(double rin, int j)
{
    return M_PI * ((rin + j + 1) * (rin + j + 1) - (rin + j) * (rin + j));
}

/* Per star k (< HALO_NSTAR) and ring j: d[k nb + j] its ring median less
 * its sky, v[k nb + j] that median's variance (NAN where the ring has too
 * few pixels); sky[k] the sky's variance, or NAN for a star with no sky. */
typedef struct {
    double *d, *v, sky[HALO_NSTAR];
} rings;

/* The stars' rings into g; the number of stars with a sky. */
static int star_rings(const mp_frame *f, const float *res, const mp_pl_star *s, size_t ns, double rin,
                      double rout, int nb, double *buf, rings *g)
{
    int used = 0;
    for (size_t k = 0; k < HALO_NSTAR; k++) {
        double sky, se;
        g->sky[k] = NAN;
        for (int j = 0; j < nb; j++)
            g->d[k * (size_t)nb + (size_t)j] = g->v[k * (size_t)nb + (size_t)j] = NAN;
        if (k >= ns || !ring_median(f, res, &s[k], rout, rout + 2 * rin, buf, &sky, &se))
            continue;
        g->sky[k] = se * se;
        used++;
        for (int j = 0; j < nb; j++) {
            double med, sj;
            if (ring_median(f, res, &s[k], rin + j, rin + j + 1, buf, &med, &sj)) {
                g->d[k * (size_t)nb + (size_t)j] = med - sky;
                g->v[k * (size_t)nb + (size_t)j] = sj * sj;
            }
        }
    }
    return used;
}

/* The empirical variance of F = Σ_k c_k F_k, F_k = Σ_j c_kj d_kj / c_k
 * (star k's own estimate of the mean light, c_k = Σ_j c_kj): the weighted
 * scatter of the F_k about their mean F / Σ c_k, n/(n − 1) Σ_k c_k² (F_k −
 * F / Σ c_k)² over the n stars with a sky.  It holds what the pixels'
 * noise does not: a neighbour hidden in one star's rings, one star's own
 * fit residual. */
static double scatter_var(const rings *g, const double *ck, const double *fk, double F)
{
    double v = 0.0, c = 0.0;
    int n = 0;
    for (size_t k = 0; k < HALO_NSTAR; k++)
        c += isfinite(g->sky[k]) ? ck[k] : 0.0;
    for (size_t k = 0; k < HALO_NSTAR; k++)
        if (isfinite(g->sky[k]) && ck[k] > 0) {
            v += ck[k] * ck[k] * (fk[k] - F / c) * (fk[k] - F / c);
            n++;
        }
    return n > 1 ? v * n / (n - 1) : 0.0;
}

/* h[j] = Σ_k E_k d_kj / Σ_k E_k² (least squares of d = E·h over the
 * stars), and the significance of its light beyond rin, z = F / σ_F with
 * F = Σ_j A_j h_j (A_j the ring's area) = Σ_k,j c_kj d_kj.  σ_F² is the
 * larger of the pixels' (each ring median's variance and, since one star's
 * sky enters all its rings, its sky's variance times (Σ_j c_kj)²) and the
 * stars' scatter about F (scatter_var). */
static double profile(const mp_pl_star *s, const rings *g, int nb, double rin, double *h, double *den)
{
    for (int j = 0; j < nb; j++) {
        double num = 0.0;
        den[j] = 0.0;
        for (size_t k = 0; k < HALO_NSTAR; k++)
            if (isfinite(g->d[k * (size_t)nb + (size_t)j])) {
                num += g->d[k * (size_t)nb + (size_t)j] * s[k].e;
                den[j] += s[k].e * s[k].e;
            }
        h[j] = den[j] > 0 ? num / den[j] : 0.0;
    }
    double F = 0.0, var = 0.0, ck[HALO_NSTAR], fk[HALO_NSTAR];
    for (int j = 0; j < nb; j++)
        F += ring_area(rin, j) * h[j];
    for (size_t k = 0; k < HALO_NSTAR; k++) {
        ck[k] = fk[k] = 0.0;
        for (int j = 0; j < nb; j++) {
            size_t i = k * (size_t)nb + (size_t)j;
            if (!isfinite(g->d[i]))
                continue;
            double c = ring_area(rin, j) * s[k].e / den[j];
            ck[k] += c;
            fk[k] += c * g->d[i];
            var += c * c * g->v[i];
        }
        if (isfinite(g->sky[k]))
            var += ck[k] * ck[k] * g->sky[k];
        if (ck[k] > 0)
            fk[k] /= ck[k];
    }
    var = fmax(var, scatter_var(g, ck, fk, F));
    return var > 0 ? F / sqrt(var) : 0.0;
}

/* h[j], the profile on the rings [rin + j, rin + j + 1), j < nb: for each
 * of the brightest stars the median of its ring less its sky (the median of
 * [rout, rout + 2 rin)), fitted as h·E over the stars by least squares
 * (profile); then the nearest non-increasing profile (weights Σ E²), kept
 * >= 0.  *z: the significance of the unconstrained profile's light (the
 * constrained one is biased up by its >= 0).  Returns the number of stars
 * used, −1 when out of memory. */
static int measure(const mp_frame *f, const float *res, const mp_pl_star *s, size_t ns, double rin,
                   double rout, double *h, int nb, double *z)
{
    size_t cap = (size_t)(M_PI * (rout + 2 * rin + 2) * (rout + 2 * rin + 2)) + 16;
    double *buf = malloc((cap > 3 * (size_t)nb ? cap : 3 * (size_t)nb) * sizeof *buf),
           *den = malloc((size_t)nb * sizeof *den);
    rings g = {malloc(HALO_NSTAR * (size_t)nb * sizeof *g.d),
               malloc(HALO_NSTAR * (size_t)nb * sizeof *g.v), {0}};
    int used = -1;
    *z = 0.0;
    if (buf && den && g.d && g.v) {
        used = star_rings(f, res, s, ns, rin, rout, nb, buf, &g);
        *z = profile(s, &g, nb, rin, h, den);
        non_increasing(h, den, nb, buf);
        for (int j = 0; j < nb; j++)
            h[j] = fmax(h[j], 0.0);
    }
    free(buf);
    free(den);
    free(g.d);
    free(g.v);
    return used;
}

/* h at radius r: flat inside rin, linear between ring centres, 0 beyond. */
static double h_at(const double *h, int nb, double rin, double r)
{
    double u = r - rin - 0.5;
    if (u <= 0)
        return h[0];
    int j = (int)u;
    if (j >= nb - 1)
        return 0.0;
    double t = u - j;
    return (1 - t) * h[j] + t * h[j + 1];
}

/* ∫ h(r) 2πr dr out to where h ends, on 0.01-px rings (h_at is linear
 * between ring centres, so this is exact to 1e-4 of the ring's light). */
static double light_of(const double *h, int nb, double rin)
{
    double L = 0.0, dr = 0.01;
    for (double r = 0.5 * dr; r < rin + nb; r += dr)
        L += 2.0 * M_PI * r * dr * h_at(h, nb, rin, r);
    return L;
}

/* Take E·h(r) of every star whose halo reaches a twentieth of a sky pixel's
 * σ off the frame and the residual, its variance into xvar; *nlit counts
 * them. */
static int subtract(mp_frame *f, float *res, const mp_pl_star *s, size_t ns, const double *h, int nb,
                    double rin, double sig, long *nlit)
{
    size_t npix = (size_t)f->im.nx * (size_t)f->im.ny;
    if (!f->xvar && !(f->xvar = calloc(npix ? npix : 1, sizeof *f->xvar)))
        return 1;
    double rmax = rin + nb - 0.5;
    *nlit = 0;
    for (size_t k = 0; k < ns; k++) {
        if (!(s[k].e * h[0] >= 0.05 * sig))
            break;                      /* brightest first: none further */
        (*nlit)++;
        long x0 = (long)floor(s[k].x - rmax), x1 = (long)ceil(s[k].x + rmax);
        long y0 = (long)floor(s[k].y - rmax), y1 = (long)ceil(s[k].y + rmax);
        for (long y = y0 < 1 ? 1 : y0; y <= y1 && y <= f->im.ny; y++)
            for (long x = x0 < 1 ? 1 : x0; x <= x1 && x <= f->im.nx; x++) {
                size_t i = (size_t)(y - 1) * (size_t)f->im.nx + (size_t)(x - 1);
                double l = s[k].e * h_at(h, nb, rin, hypot((double)x - s[k].x, (double)y - s[k].y));
                if (f->mask[i] || l <= 0)
                    continue;
                f->im.pix[i] -= l;
                res[i] -= l;
                f->xvar[i] += (float)l;
            }
    }
    return 0;
}

int mp_pl_halo(mp_frame *f, float *res, const mp_table *t, double fwhm, double *z, double *light,
               char *what, size_t wlen, char *err)
{
    double sky = mp_pl_median_sky(t);
    double rin = fmax(fwhm, 1.0), rout = 16.0 * rin;
    int nb = (int)(rout - rin);
    size_t ns;
    mp_pl_star *s = mp_pl_stars_by_flux(t, 0, &ns);
    double *h = malloc((size_t)nb * sizeof *h);
    int rc = 1, used = s && h ? measure(f, res, s, ns, rin, rout, h, nb, z) : -1;
    int significant = used > 0 && *z > MP_PL_HALO_Z;
    long nlit = 0;
    *light = 0.0;
    double sig = sqrt(fmax(sky, 0.0) + f->rdnoise * f->rdnoise);
    if (used < 0 || (significant && subtract(f, res, s, ns, h, nb, rin, sig, &nlit))) {
        snprintf(err, MP_ERRLEN, "out of memory for the halo");
        goto done;
    }
    /* The halo's share of a star's light beyond rin, and its value at
     * 4 rin (the table's default radius), for the report. */
    double frac = 0.0;
    for (int j = 0; used > 0 && j < nb; j++)
        frac += h[j] * ring_area(rin, j);
    if (significant)
        *light = light_of(h, nb, rin);
    snprintf(what, wlen, "halo from the %d brightest stars, r = %.3g..%.3g px: %.3g of a star's "
             "light beyond %.3g px (z %.1f: %s), %.3g per e- at %.3g px; taken off around %ld "
             "stars, %.3g of each one's light", used, rin, rout, frac, rin, *z,
             significant ? "significant" : "not significant, nothing taken off",
             used > 0 ? h_at(h, nb, rin, 4 * rin) : 0.0, 4 * rin, nlit, *light);
    rc = 0;
done:
    free(s);
    free(h);
    return rc;
}
