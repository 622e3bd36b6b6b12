/* frame_build.c — one pass of the PSF build on a frame (build.h): the
 * stars' cut-outs, the sampling and order decisions, the total-flux
 * fraction.  `matphot psf` runs it twice (the second time with every
 * neighbour fitted and subtracted: DAOPHOT's two passes); the pipeline
 * before its first round and once after it. */
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include "psf/build_priv.h"

int mp_epsf_field(const mp_epsf *e, mp_psf_field *fld, char *err)
{
    if (mp_psf_field_new(e->order, e->nx, e->ny, e->os, e->x0, e->y0, e->xs, e->ys, fld, err))
        return 1;
    size_t n = (size_t)e->nterms * e->nx * e->ny;
    for (size_t i = 0; i < n; i++)
        fld->planes[i] = e->planes[i] * e->sum;
    fld->sum = 0.0;
    for (size_t i = 0; i < (size_t)e->nx * e->ny; i++)
        fld->sum += fld->planes[i];
    fld->nstar = e->nstar;
    snprintf(fld->why, sizeof fld->why, "%s", e->why);
    return 0;
}

int mp_epsf_model(const mp_psf_field *fld, mp_psf *tab, mp_prf_model *m, char *err)
{
    if (mp_psf_field_eval(fld, fld->x0, fld->y0, tab, err))
        return 1;
    tab->field = fld->order > 0 ? fld : NULL;
    m->psf = tab;
    m->drf = NULL;
    m->sinc_hw = 10;
    return 0;
}

/* Put back each PSF star's own fitted light: the rows of t within 1 px. */
static int put_back(mp_epsf_star *s, size_t n, const mp_table *t, const mp_prf_model *m,
                    char *err)
{
    int cx = mp_table_col(t, "XPSF_IMAGE"), cy = mp_table_col(t, "YPSF_IMAGE");
    int cf = mp_table_col(t, "FLUX_PSF");
    if (cx < 0 || cy < 0 || cf < 0)
        return 0;
    for (size_t k = 0; k < n; k++)
        for (size_t r = 0; r < t->nrow; r++) {
            double x = mp_table_get(t, r, cx), y = mp_table_get(t, r, cy);
            double F = mp_table_get(t, r, cf);
            if (isfinite(F) && mp_within(x - s[k].xf, y - s[k].yf, 1.0) &&
                mp_epsf_cutout_add(&s[k], m, x, y, F, err))
                return 1;
        }
    return 0;
}

/* Used stars. */
static size_t count_used_stars(const mp_epsf_star *s, size_t n)
{
    size_t m = 0;
    for (size_t k = 0; k < n; k++)
        m += s[k].used != 0;
    return m;
}

static double median_chi2(const mp_epsf_star *s, size_t n)
{
    double *v = malloc((n + 1) * sizeof *v);
    size_t m = 0;
    if (!v)
        return NAN;
    for (size_t k = 0; k < n; k++)
        if (s[k].used)
            v[m++] = s[k].chi2;
    double med = mp_epsf_median(v, m);
    free(v);
    return med;
}

/* The brightest used star's flux and the median sky: what the sampling
 * decision is measured for. */
static void brightest(const mp_epsf_star *s, size_t n, double *E, double *B)
{
    *E = 0;
    *B = 0;
    double *v = malloc((n + 1) * sizeof *v);
    size_t m = 0;
    for (size_t k = 0; k < n; k++)
        if (s[k].used) {
            *E = fmax(*E, s[k].flux);
            if (v)
                v[m++] = s[k].sky;
        }
    if (v && m)
        *B = fmax(mp_epsf_median(v, m), 0.0);
    free(v);
}

/* The ×4 table and its own error, measured: the stars split in two
 * halves (alternate ones), each builds its own ×4 table from the start;
 * half their difference is a draw of the table's error (each half has
 * twice its variance) into noise, and their mean, the table, into e,
 * each star used as its own half left it.  (A build of all the stars
 * from that mean, 3 rounds more, was a third of the PSF's first pass on
 * 47 Tuc; the second pass rebuilds from this table anyway.) */
static int half_tables(mp_epsf_star *s, size_t n, const mp_epsf_opts *o, mp_epsf *e,
                       mp_epsf *noise, char *err)
{
    mp_epsf h[2];
    memset(h, 0, sizeof h);
    int rc = 0;
    unsigned char *used = malloc(n + 1);
    if (!used) {
        snprintf(err, MP_ERRLEN, "psf build: out of memory");
        return 1;
    }
    for (int half = 0; half < 2 && !rc; half++) {
        for (size_t k = 0; k < n; k++)
            s[k].skip = (int)(k % 2) != half;
        rc = mp_epsf_rounds(s, n, o, 4, 0, &h[half], err);
        for (size_t k = 0; k < n; k++) {
            if ((int)(k % 2) == half)
                used[k] = s[k].used != 0;
            s[k].skip = 0;
        }
    }
    for (size_t k = 0; k < n && !rc; k++)
        s[k].used = used[k];
    free(used);
    long fits = e->fits + h[0].fits + h[1].fits;
    long fits_grid = e->fits_grid + h[0].fits_grid + h[1].fits_grid;
    if (!rc) {
        size_t nel = (size_t)h[0].nx * h[0].ny;
        mp_epsf_free(e);
        *e = h[0];
        *noise = h[1];
        h[0].planes = h[1].planes = NULL;
        for (size_t i = 0; i < nel; i++) {
            double a = e->planes[i], b = noise->planes[i];
            e->planes[i] = 0.5 * (a + b);
            noise->planes[i] = 0.5 * (a - b);
        }
        e->nstar = (int)count_used_stars(s, n);
    }
    e->fits = fits;
    e->fits_grid = fits_grid;
    mp_epsf_free(&h[0]);
    mp_epsf_free(&h[1]);
    return rc;
}

/* The finest sampling n stars determine: a table of OVERSAMP os holds os²
 * elements per detector pixel, and n stars give n samples of each
 * pixel's PRF, one at each star's subpixel phase, so a finer table's
 * extra elements hold its start and its noise, not the data's light. */
static int finest_os(size_t n)
{
    return n >= 16 ? 4 : n >= 4 ? 2 : 1;
}

/* The OVERSAMP decision (choose_os) said into rep->what: the table it was
 * measured on (os0: ×4, the halves' mean smoothed by their measured
 * noise; else the finest its n stars determine, its noise not
 * measured), each coarser sampling's aliasing error. */
static void say_os_choice(mp_epsf_report *rep, const mp_epsf *e, int pick, double E, int os0,
                          int halved, size_t n)
{
    size_t l = strlen(rep->what);
    if (!halved && os0 < 4) {
        snprintf(rep->what + l, sizeof rep->what - l,
                 "OVERSAMP %d (%zu PSF stars, too few to halve and so to measure the table's noise: "
                 "x%d, the finest they determine (x4 holds 16 elements a pixel)", pick, n, os0);
        for (int os = os0 / 2; os >= 1; os /= 2) {
            l = strlen(rep->what);
            snprintf(rep->what + l, sizeof rep->what - l, "; x%d's aliasing error for the "
                     "brightest star, %.3g e-, %.2g sigma", os, E, rep->oserr[os]);
        }
        l = strlen(rep->what);
        snprintf(rep->what + l, sizeof rep->what - l, "); ");
        return;
    }
    int band = 0;
    while (band < MP_EPSF_NWBIN && e->wiener[band] >= 0.5)
        band++;
    char x1[48] = "not tried (x2 is above 1 already)";
    if (!isnan(rep->oserr[1]))
        snprintf(x1, sizeof x1, "%.2g sigma", rep->oserr[1]);
    snprintf(rep->what + l, sizeof rep->what - l,
             "OVERSAMP %d (aliasing error for the brightest star, %.3g e-, of the x4 table "
             "smoothed as its noise needs (S/N > 1 out to %.2f cycles/px%s): x2 %.2g sigma, x1 %s; "
             "the coarsest below 1); ", pick, E, band * MP_EPSF_WBIN,
             e->have_wiener ? "" : ", not measured", rep->oserr[2], x1);
}

/* OVERSAMP auto: the ×4 table (the halves' mean, half_tables) smoothed as
 * its noise needs (the Wiener filter of the halves' measured draw of that
 * noise); then the coarsest of ×1, ×2 whose aliasing error on that table,
 * for the brightest PSF star, is below 1 σ of its noise, else ×4.  With
 * too few stars to halve, the table is built from a Gaussian at the
 * finest sampling its stars determine (finest_os): the aliasing of a
 * finer one, its noise unmeasured, measures that noise (the DECam
 * cutout's four stars: ×2 "120 σ" on a ×4 table of 241² elements). */
static int choose_os(mp_epsf_star *s, size_t n, const mp_epsf_opts *o, const mp_frame *f,
                     mp_epsf *e, mp_epsf_report *rep, char *err)
{
    mp_epsf noise;
    memset(&noise, 0, sizeof noise);
    int halved = n >= 6 && half_tables(s, n, o, e, &noise, err) == 0;
    int os0 = halved ? 4 : finest_os(n);
    if (!halved && mp_epsf_rounds(s, n, o, os0, 0, e, err)) {
        mp_epsf_free(&noise);
        return 1;
    }
    double E, B;
    brightest(s, n, &E, &B);
    if (halved && mp_epsf_wiener_measure(e, &noise, e->wiener, MP_EPSF_NWBIN) == 0 &&
        mp_epsf_wiener_apply(e, e->wiener, MP_EPSF_NWBIN) == 0) {
        e->have_wiener = 1;
        e->filtered = 1;
        mp_epsf_normalise(e, o->fwhm, o->support);
    }
    mp_epsf_free(&noise);
    int pick = os0;
    rep->oserr[1] = rep->oserr[2] = NAN; /* NaN: not tried (a finer one failed) */
    for (int os = os0 / 2; os >= 1; os /= 2) {
        rep->oserr[os] = mp_epsf_oversamp_error(e, os, E, B, f->rdnoise);
        if (rep->oserr[os] < 1.0)
            pick = os;
        else
            break;
    }
    say_os_choice(rep, e, pick, E, os0, halved, n);
    /* The coarser table is the finer one block-summed: the decision bounds
     * its error for the brightest star, and the second pass builds at
     * its sampling from it (a build here as well cost a fifth of the
     * first pass).  The stars are fitted with the table kept, as
     * filtered and sampled. */
    if (pick < os0) {
        mp_epsf c;
        if (mp_epsf_rebin(e, os0 / pick, &c, err))
            return 1;
        mp_epsf_free(e);
        *e = c;
    }
    return mp_epsf_refit(s, n, o, e, err);
}

/* The table smoothed as its noise needs (the first pass's measured
 * filter) and the stars fitted with it, when a build ran since the filter
 * was last applied: its SIRT steps add back some of what the filter took.
 * (Applied twice to one table, it smoothed twice: a ×4 table kept by the
 * first pass, before 2026-11-29.) */
static int filter_refit(mp_epsf_star *s, size_t n, const mp_epsf_opts *o, mp_epsf *e, char *err)
{
    if (!e->have_wiener || e->filtered)
        return 0;
    e->filtered = 1;
    if (mp_epsf_wiener_apply(e, e->wiener, MP_EPSF_NWBIN)) {
        snprintf(err, MP_ERRLEN, "psf build: out of memory");
        return 1;
    }
    mp_epsf_normalise(e, o->fwhm, o->support);
    return mp_epsf_refit(s, n, o, e, err);
}

/* The order test's verdicts so far, for PSFORDWH: from the order the pass
 * started at (the first pass's raises said once), each k→k+1 test and,
 * where it kept order k, the k→k+2 one. */
static void order_why(const mp_epsf_opts *o, const mp_epsf_report *rep, int start, mp_epsf *e)
{
    size_t l = strlen(e->why);
    snprintf(e->why + l, sizeof e->why - l, "auto: order %d", e->order);
    const char *sep = " (";
    if (start > 0) {
        l = strlen(e->why);
        snprintf(e->why + l, sizeof e->why - l, "%s order 0->%d in the first pass", sep, start);
        sep = ";";
    }
    for (int k = start; k <= e->order && k < MP_PSF_MAXORDER; k++)
        for (int two = 0; two < 2; two++) {
            double pk = two ? rep->ptest2[k] : rep->ptest[k];
            double zk = two ? rep->ztest2[k] : rep->ztest[k];
            double zpk = two ? rep->zperm2[k] : rep->zperm[k];
            if (isnan(pk))
                continue;           /* not run: passed over, or k→k+1 raised */
            char zp[32] = "";       /* the permuted null's, when it ran */
            if (!isnan(zpk))
                snprintf(zp, sizeof zp, ", permuted %.1f", zpk);
            l = strlen(e->why);
            snprintf(e->why + l, sizeof e->why - l, "%s order %d->%d p=%.2g (z %.1f%s)%s", sep, k,
                     k + 1 + two, pk, zk, zp, pk < o->alpha ? " <" : " >=");
            sep = ";";
        }
    l = strlen(e->why);
    snprintf(e->why + l, sizeof e->why - l, "%s alpha %.0e)", *sep == ';' ? "" : " (", o->alpha);
}

/* One order test k→to of e, its verdict into rep (two: the k→k+2 slots). */
static int test_order(mp_epsf_star *s, size_t n, const mp_epsf_opts *o, mp_epsf *e, int to,
                      mp_epsf_report *rep, int two, double *p, char *err)
{
    double z, zp;
    int k = e->order;
    if (mp_epsf_order_test_to(s, n, e, to, o->fitrad, o->alpha, p, &z, &zp, err))
        return 1;
    (two ? rep->ptest2 : rep->ptest)[k] = *p;
    (two ? rep->ztest2 : rep->ztest)[k] = z;
    (two ? rep->zperm2 : rep->zperm)[k] = zp;
    return 0;
}

/* varorder auto: raise the order while the test rejects the lower one and
 * the used stars number at least MP_EPSF_PER_TERM per term of the higher
 * order (build.h: its table's noise then stays within ~5 % of a PSF star's
 * own σ).  Where k→k+1 keeps order k, k→k+2 is tested too (both at alpha:
 * at most 2·alpha of false raises a step): a focus that changes as the
 * square of the distance from the frame's centre has no term of degree
 * k+1, and the k→k+1 test cannot see it (`matphot sim stretch=0.15`:
 * order 0 kept, the brightest stars' flux errors 6.5 times their σ, 56
 * false detections; order 2: 1.1). */
static int choose_order(mp_epsf_star *s, size_t n, const mp_epsf_opts *o, mp_epsf *e,
                        mp_epsf_report *rep, char *err)
{
    int short_of = 0, start = e->order;
    size_t nu = 0;
    for (;;) {
        double p;
        if (test_order(s, n, o, e, e->order + 1, rep, 0, &p, err))
            return 1;
        if (e->order >= MP_PSF_MAXORDER)
            break;
        int to = e->order + 1;
        if (!(p < o->alpha)) {
            if (e->order + 2 > MP_PSF_MAXORDER ||
                test_order(s, n, o, e, e->order + 2, rep, 1, &p, err) || !(p < o->alpha))
                break;
            to = e->order + 2;
        }
        nu = count_used_stars(s, n);
        if (nu < (size_t)(MP_EPSF_PER_TERM * mp_psf_nterms(to))) {
            short_of = to;
            break;
        }
        if (mp_epsf_build(s, n, o, e->os, to, e, err))
            return 1;
    }
    order_why(o, rep, start, e);
    if (short_of) {
        size_t l = strlen(e->why);
        snprintf(e->why + l, sizeof e->why - l, "; not raised: %zu stars < %d per term x %d",
                 nu, MP_EPSF_PER_TERM, mp_psf_nterms(short_of));
    }
    return 0;
}

/* The table at its sampling: chosen (OVERSAMP auto, choose_os) in a first
 * pass, else the first pass's or the one given, built at order 0 (or the
 * first pass's order).  Nonzero with err on failure. */
static int build_sampled(mp_epsf_star *s, size_t n, const mp_epsf_opts *o, const mp_frame *f,
                         mp_epsf *e, mp_epsf_report *rep, char *err)
{
    if (!e->planes && o->os == 0)
        return choose_os(s, n, o, f, e, rep, err);
    int os = e->planes ? e->os : o->os;
    snprintf(rep->what, sizeof rep->what, "OVERSAMP %d (%s); ", os,
             e->planes ? "as the first pass" : "given");
    /* With the first pass's filter to apply, the stars' last fit is the
     * one with the filtered table (a fit with the build's own before it
     * was a fifth of the second pass), and the order test sees that
     * table, as the first pass's does. */
    return e->have_wiener ? mp_epsf_rounds(s, n, o, os, e->planes ? e->order : 0, e, err) ||
                                filter_refit(s, n, o, e, err)
                          : mp_epsf_build(s, n, o, os, e->planes ? e->order : 0, e, err);
}

/* The table's polynomial order: the one given (varorder), else raised
 * while the data demand it (choose_order).  Nonzero with err on failure. */
static int build_order(mp_epsf_star *s, size_t n, const mp_epsf_opts *o, mp_epsf *e,
                       mp_epsf_report *rep, char *err)
{
    if (o->order < 0)
        return choose_order(s, n, o, e, rep, err);
    if (e->order != o->order && mp_epsf_build(s, n, o, e->os, o->order, e, err))
        return 1;
    snprintf(e->why, sizeof e->why, "order %d as given (varorder=%d)", o->order, o->order);
    return 0;
}

/* The PSF stars as the file's PSFSTARS lists them (their fluxes total
 * fluxes: fitted with the table of sum 1, the light the table holds, so
 * over PSFSUM) into *stars.  Nonzero with err when out of memory. */
static int stars_out(const mp_epsf_star *s, size_t n, const mp_epsf *e, mp_psf_star **stars,
                     char *err)
{
    if (!(*stars = malloc((n + 1) * sizeof **stars))) {
        snprintf(err, MP_ERRLEN, "psf build: out of memory");
        return 1;
    }
    for (size_t k = 0; k < n; k++)
        (*stars)[k] = (mp_psf_star){s[k].x, s[k].y, s[k].flux / e->sum, s[k].used};
    return 0;
}

/* o->raise: the next order built from e as it is (its OVERSAMP and
 * filter), the stars' fits starting from e. */
static int build_raised(mp_epsf_star *s, size_t n, const mp_epsf_opts *o, mp_epsf *e,
                        mp_epsf_report *rep, char *err)
{
    int from = e->order;
    snprintf(rep->what, sizeof rep->what, "OVERSAMP %d (as the first pass); ", e->os);
    if (mp_epsf_build(s, n, o, e->os, from + 1, e, err))
        return 1;
    snprintf(e->why, sizeof e->why, "order %d, raised from %d", from + 1, from);
    return 0;
}

/* A table built is a PSF only when its stars' last fit, with the table
 * kept, leaves as many as its order needs (`psf fwhm=0.5` on stars of
 * FWHM 2.5 built a 2-px table that fitted none of them, and wrote it: "0
 * of 100 stars used"), and it holds light (psfrad 64 on a 128² frame
 * wrote one of zeros, PSFSUM 0, that every reader then refused).  1 with
 * err when not. */
static int built_verdict(const mp_epsf *e, size_t n, const mp_epsf_opts *o, char *err)
{
    if (e->nstar < 2 * e->nterms + 1) {
        snprintf(err, MP_ERRLEN, "psf build: only %d usable PSF stars (an order-%d PSF needs %d; "
                 "%zu fitted with the table built, psfrad %g px, fitrad %g px)", e->nstar,
                 e->order, 2 * e->nterms + 1, n, o->psfrad, o->fitrad);
        return 1;
    }
    double tot = 0.0;
    for (size_t i = 0; i < (size_t)e->nx * (size_t)e->ny; i++)
        tot += e->planes[i];
    if (!(tot > 0) || !(e->sum > 0)) {
        snprintf(err, MP_ERRLEN, "psf build: the table holds no light (its elements sum to %g, "
                 "PSFSUM %g; psfrad %g px)", tot, e->sum, o->psfrad);
        return 1;
    }
    return 0;
}

int mp_epsf_pass(const mp_frame *f, const float *img, int residual, const mp_table *fitted,
                 const mp_prf_model *m, const double *x, const double *y, const double *flux,
                 size_t n, const mp_epsf_opts *oin, mp_epsf *e, mp_epsf_report *rep,
                 mp_psf_star **stars, char *err)
{
    /* The pass's builds hand their phase grid on (mp_epsf_opts.spare). */
    mp_prf_cache spare;
    memset(&spare, 0, sizeof spare);
    mp_epsf_opts po = *oin;
    po.spare = po.spare ? po.spare : &spare;
    po.frame_nb = residual && fitted && m;
    const mp_epsf_opts *o = &po;
    mp_epsf_star *s = NULL;
    double *sky = malloc((n + 1) * sizeof *sky);
    int rc = 1;
    rep->what[0] = '\0';
    for (int k = 0; k <= MP_PSF_MAXORDER; k++)
        rep->ptest[k] = rep->ztest[k] = rep->zperm[k] = rep->ptest2[k] = rep->ztest2[k] =
            rep->zperm2[k] = NAN;
    if (!sky) {
        snprintf(err, MP_ERRLEN, "psf build: out of memory");
        return 1;
    }
    for (size_t k = 0; k < n; k++)
        sky[k] = NAN;
    if (mp_epsf_cutouts(f, img, x, y, flux, sky, n, o->psfrad, &s, err))
        goto done;
    if (residual && fitted && m && put_back(s, n, fitted, m, err))
        goto done;
    if (mp_epsf_neighbours(s, n, fitted, residual ? m : NULL, o->psfrad, err))
        goto done;
    rep->nsel = n;
    e->why[0] = '\0';
    if (o->raise && e->planes && e->order < MP_PSF_MAXORDER
            ? build_raised(s, n, o, e, rep, err)
            : build_sampled(s, n, o, f, e, rep, err) || build_order(s, n, o, e, rep, err))
        goto done;
    /* a table built since (a higher order, or the order given) */
    if (filter_refit(s, n, o, e, err))
        goto done;
    /* The light beyond the table (its support) only once the neighbours
     * are gone: in a crowded frame they fill the big aperture. */
    if (residual &&
        mp_epsf_growth(f, img, fitted, m, s, n, mp_epsf_growth_rin(o), 2.0 * o->psfrad, e, err))
        goto done;
    if (built_verdict(e, n, o, err))
        goto done;
    rep->nused = (size_t)e->nstar;
    rep->chi2 = median_chi2(s, n);
    size_t l = strlen(rep->what);
    snprintf(rep->what + l, sizeof rep->what - l,
             "%zu of %zu stars used (median chi2 %.2f); %s; PSFSUM %.4f +- %.4f from %d stars; "
             "%ld star fits, %ld from the phase grid", rep->nused, n, rep->chi2, e->why, e->sum,
             e->sum_err, e->ngrowth, e->fits, e->fits_grid);
    rc = stars ? stars_out(s, n, e, stars, err) : 0;
done:
    free(sky);
    mp_epsf_stars_free(s, n);
    mp_prf_cache_free(&spare);
    return rc;
}
