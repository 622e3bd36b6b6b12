/* epsf_build.c — the effective-PSF iteration (build.h; Anderson & King
 * 2000): fit every star with the current table, back-project the
 * residuals onto the table grid, combine them over the stars robustly,
 * step, and repeat until a step changes χ² by less than the noise. */
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include "psf/build.h"
#include "psf/build_priv.h"

static int oom(char *err)
{
    snprintf(err, MP_ERRLEN, "psf build: out of memory");
    return 1;
}

/* The powers of x and y of each term of an order, in PSFEx order. */
static void term_powers(int order, int pw[][2])
{
    int k = 0;
    for (int j = 0; j <= order; j++)
        for (int i = 0; i + j <= order; i++) {
            pw[k][0] = i;
            pw[k++][1] = j;
        }
}

/* The start: a Gaussian of o->fwhm (*cold set), or e's planes padded to
 * order. */
static int start_planes(const mp_epsf_opts *o, int os, int order, mp_epsf *e, int *cold,
                        char *err)
{
    int nterms = (order + 1) * (order + 2) / 2;
    *cold = !(e->planes && e->os == os);
    if (!*cold) {
        if (e->order == order)
            return 0;
        size_t nel = (size_t)e->nx * e->ny;
        double *p = calloc((size_t)nterms * nel, sizeof *p);
        if (!p)
            return oom(err);
        /* Terms keep their meaning across orders: map by powers. */
        int pa[MP_EPSF_MAXT][2], pb[MP_EPSF_MAXT][2];
        term_powers(e->order, pa);
        term_powers(order, pb);
        for (int a = 0; a < e->nterms; a++)
            for (int b = 0; b < nterms; b++)
                if (pa[a][0] == pb[b][0] && pa[a][1] == pb[b][1])
                    memcpy(p + (size_t)b * nel, e->planes + (size_t)a * nel, nel * sizeof *p);
        free(e->planes);
        e->planes = p;
        e->order = order;
        e->nterms = nterms;
        return 0;
    }
    mp_psf g;
    if (mp_psf_gauss_table(o->fwhm, os, o->psfrad, &g, err))
        return 1;
    size_t nel = (size_t)g.nx * g.ny;
    long fits = e->fits, fits_grid = e->fits_grid;   /* the work so far stays counted */
    mp_epsf_free(e);
    e->fits = fits;
    e->fits_grid = fits_grid;
    if (!(e->planes = calloc((size_t)nterms * nel, sizeof *e->planes))) {
        mp_psf_free(&g);
        return oom(err);
    }
    for (size_t i = 0; i < nel; i++)
        e->planes[i] = g.t[i] / g.sum;
    e->nx = g.nx;
    e->ny = g.ny;
    e->os = os;
    e->order = order;
    e->nterms = nterms;
    e->x0 = o->x0;
    e->y0 = o->y0;
    e->xs = o->xs;
    e->ys = o->ys;
    e->sum = 1.0;
    mp_psf_free(&g);
    return 0;
}

/* The LM's tol (× each parameter's σ) for the stars' fits of a build's
 * rounds before the stars' clip (rounds 0 and 1 from a Gaussian): the
 * table they are fitted against moves more in the round's SIRT steps than
 * anything the fit could settle (47 Tuc 512²: the cold ×4 halves' χ²
 * 2.3·10⁸ → 5.5·10⁷ over round 0), so the default's 1e-3 (mp_fit_opts_default,
 * which the later rounds and the stars' last fit keep) only bought
 * steps: ~9 a fit of 12 stars there against ~5.  The build's decisions
 * come after (the χ² stopping rule from round 2, OVERSAMP, the order). */
#define EARLY_TOL 0.1

/* The fit's options for a PSF star: the phase grid where z's bound lets
 * it serve the star, its crop, fitrad; the sky the annulus's. */
static void star_fit_opts(const mp_epsf_star *s, const mp_epsf_opts *o, const mp_epsf_fitter *z,
                          int early, mp_fit_opts *fo)
{
    mp_fit_opts_default(fo);
    fo->grid = mp_epsf_fitter_grid(z, s);
    if (fo->grid)
        fo->grid_tiers = z->tiers;
    if (early)
        fo->tol = EARLY_TOL;
    fo->crop = z->order0 && z->crop.env ? &z->crop : NULL;
    fo->sky_order = 0;
    fo->fitrad = o->fitrad;
    fo->fit_sky = 0;            /* the annulus's (mp_epsf_cutouts) */
    fo->stats = 0;              /* its PRF's statistics and model errors unread
                                 * here: an exact render of each star a fit */
}

/* The star's fit (st[0], its neighbours st[1..nfit-1], cut-out
 * coordinates, offset ox, oy) kept in s: 0 when it is not a star the
 * table describes (s->used cleared). */
static int keep_fit(mp_epsf_star *s, const mp_star *st, int nfit, double ox, double oy)
{
    double nx = st[0].x + ox, ny = st[0].y + oy;
    /* A fit that strays from where the star was found, or loses its light,
     * is not a star this table describes. */
    if (!(st[0].flux > 0) || !isfinite(nx) || !isfinite(ny) || hypot(nx - s->xf, ny - s->yf) > 1.0 ||
        (st[0].flags & (MP_FLAG_NOCONV | MP_FLAG_EDGE))) {
        s->used = 0;
        return 0;
    }
    s->x = nx;
    s->y = ny;
    s->flux = st[0].flux;
    s->fitted = 1;
    s->sky = st[0].sky;
    s->chi2 = st[0].chi2;
    /* A neighbour keeps a fit that stays finite, positive and near its
     * start; else its last values. */
    for (int j = 0; j < nfit - 1; j++) {
        double x = st[1 + j].x + ox, y = st[1 + j].y + oy;
        if (st[1 + j].flux > 0 && isfinite(x) && isfinite(y) &&
            hypot(x - s->nbx[j], y - s->nby[j]) <= 1.0) {
            s->nbx[j] = x;
            s->nby[j] = y;
            s->nbf[j] = st[1 + j].flux;
        }
    }
    return 1;
}

/* Fit one star (centre, flux; the sky its annulus's) with its table at
 * its place (z's model: star_model.c), together with its neighbours on
 * the cut-out as cut; then the cut-out less the neighbours' models
 * (mp_epsf_clean).  With hold, the neighbours keep their last fit: the
 * cut-out less their models drawn with this table first, then the star
 * alone on it (with them it is a group fit of up to 13 stars).  tab is
 * z's table at order 0, else the caller's own (the table at the star's
 * place is drawn into it); *grid is raised when the phase grid served
 * the fit.  early: a round before the stars' clip (EARLY_TOL).  1 when
 * out of memory. */
static int fit_star(mp_epsf_star *s, const mp_epsf *e, const mp_epsf_opts *o,
                    const mp_epsf_fitter *z, mp_psf *tab, int hold, int early, long *grid)
{
    char err[MP_ERRLEN];
    if (!z->order0 && mp_epsf_table(e, s->x, s->y, tab, err))
        return 1;
    mp_prf_model m = {tab, NULL, 10};
    mp_fit_opts fo;
    star_fit_opts(s, o, z, early, &fo);
    *grid += fo.grid != NULL;
    /* the neighbours taken off the cut-out from the grid, each by its own
     * flux's bound (mp_epsf_clean) */
    const mp_prf_cache *nbgrid = z->order0 && z->grid.G > 0 ? &z->grid : NULL;
    mp_star st[1 + MP_EPSF_MAXNB];
    memset(st, 0, sizeof st);
    double ox = (double)(s->x0 - 1), oy = (double)(s->y0 - 1);
    st[0].x = s->x - ox;
    st[0].y = s->y - oy;
    st[0].flux = s->flux;
    for (int j = 0; j < s->nnb; j++) {
        st[1 + j].x = s->nbx[j] - ox;
        st[1 + j].y = s->nby[j] - oy;
        st[1 + j].flux = s->nbf[j];
    }
    mp_frame raw = s->f;
    int nfit = 1 + s->nnb;
    if (hold && s->raw) {
        if (mp_epsf_clean(s, tab, nbgrid, o->psfrad))
            return 1;
        nfit = 1;
    } else if (s->raw) {
        raw.im.pix = s->raw;
    }
    char e2[MP_ERRLEN];
    if (mp_fit_group(&raw, &m, &fo, s->sky, st, nfit, e2)) {
        s->used = 0;
        return 0;
    }
    if (!keep_fit(s, st, nfit, ox, oy))
        return 0;
    return nfit > 1 && mp_epsf_clean(s, tab, nbgrid, o->psfrad);
}

/* Every used star fitted (fit_star), in parallel: a fit reads the table
 * and z and writes only its own star, so the stars' fits do not depend on
 * the number of threads or their order.  Those with the most neighbours
 * to fit are handed out first (at 16 threads 47 Tuc built waited 3.5 % of
 * its run at this loop's end). */
static int fit_stars(mp_epsf_star *s, size_t n, const mp_epsf *e, const mp_epsf_opts *o,
                     mp_epsf_fitter *z, int hold, int early, char *err)
{
    long fits = 0, grid = 0;
    int failed = 0;
    size_t nu = 0;
    mp_work_item *by = malloc((n ? n : 1) * sizeof *by);
    if (!by)
        return oom(err);
    for (size_t k = 0; k < n; k++)      /* its fit's stars */
        if (s[k].used)
            by[nu++] = (mp_work_item){hold && s[k].raw ? 1 : 1 + (size_t)s[k].nnb, k};
    mp_costliest_first(by, nu);
#pragma omp parallel reduction(+ : fits, grid) reduction(| : failed)
    {
        mp_psf own;             /* the table at a star's place (order > 0) */
        memset(&own, 0, sizeof own);
        mp_psf *tab = z->order0 ? &z->tab : &own;
#pragma omp for schedule(dynamic)
        for (size_t q = 0; q < nu; q++)
            if (!failed) {
                fits++;
                failed = fit_star(&s[by[q].i], e, o, z, tab, hold, early, &grid);
            }
        mp_psf_free(&own);
    }
    free(by);
    z->fits += fits;
    z->fits_grid += grid;
    return failed ? oom(err) : 0;
}

/* Stars whose χ² stands out among stars of their brightness (a blend, a
 * cosmic ray the table cannot be): while the table is still imperfect the
 * brightest stars have the largest χ², so the cut is on the residual of
 * ln χ² about its straight-line trend in ln F, above 5 robust σ. */
static void reject_chi2(mp_epsf_star *s, size_t n, double *tmp)
{
    double sx = 0, sy = 0, sxx = 0, sxy = 0;
    size_t m = 0;
    for (size_t k = 0; k < n; k++)
        if (s[k].used && s[k].chi2 > 0 && s[k].flux > 0) {
            double x = log(s[k].flux), y = log(s[k].chi2);
            sx += x, sy += y, sxx += x * x, sxy += x * y;
            m++;
        }
    if (m < 8)
        return;
    double d = m * sxx - sx * sx, b = d > 0 ? (m * sxy - sx * sy) / d : 0.0;
    double a = (sy - b * sx) / m;
    size_t q = 0;
    for (size_t k = 0; k < n; k++)
        if (s[k].used && s[k].chi2 > 0 && s[k].flux > 0)
            tmp[q++] = log(s[k].chi2) - a - b * log(s[k].flux);
    double med = mp_epsf_median(tmp, q);
    for (size_t k = 0; k < q; k++)
        tmp[k] = fabs(tmp[k] - med);
    double sig = 1.4826 * mp_epsf_median(tmp, q);
    for (size_t k = 0; k < n; k++)
        if (s[k].used && s[k].chi2 > 0 && s[k].flux > 0 &&
            log(s[k].chi2) - a - b * log(s[k].flux) - med > 5.0 * sig)
            s[k].used = 0;
}

double mp_epsf_common_drop(const mp_epsf_star *s, size_t n, const double *chi2s, double *last)
{
    double was = 0.0, now = 0.0;
    for (size_t k = 0; k < n; k++) {
        if (s[k].used && !isnan(last[k])) {
            was += last[k];
            now += chi2s[k];
        }
        last[k] = s[k].used ? chi2s[k] : NAN;
    }
    return was - now;
}

static size_t count_used(const mp_epsf_star *s, size_t n)
{
    size_t m = 0;
    for (size_t k = 0; k < n; k++)
        m += s[k].used != 0;
    return m;
}

/* A build's rounds (mp_epsf_rounds): what each holds across rounds. */
typedef struct {
    mp_epsf_sirt w;
    mp_epsf_fitter z;
    int held_from;         /* the round from which the neighbours are held
                            * and the stars' clip runs */
    int stop_from;         /* the first round the χ² rule may end */
    double *tmp, *last;    /* scratch; each star's χ² in the last round */
} rounds_state;

/* Round it of a build: the stars fitted with the table, clipped, the
 * SIRT's steps.  0: go on; 2: the round fitted only noise (the rounds
 * end); 1: an error in err. */
static int one_round(mp_epsf_star *s, size_t n, const mp_epsf_opts *o, int it, mp_epsf *e,
                     rounds_state *r, char *err)
{
    int held = it >= r->held_from;
    if (mp_epsf_fitter_set(&r->z, e, s, n, held, err))
        return 1;
    /* The neighbours are fitted with their star while the table is
     * far from made (the first two rounds from a Gaussian: held from
     * its round 1, a bright companion's fit to the Gaussian spoils the
     * table, test_psf_build's test_neighbours_fitted) and in the
     * stars' last fit (mp_epsf_refit); the rounds between hold them.
     * A build from a table already made (the second pass, an order
     * raised) holds them from its first round: their last fit was
     * with that table (the frame's fit, or the last build's stars'
     * last fit), and fitting them again there was a quarter of 47
     * Tuc's second pass.  Placed by the frame's fit (o->frame_nb),
     * they are held in the stars' last fit as well: a fit of each
     * with its star on the cut-out, as good at best, was another
     * quarter (its fits five times the held ones').  So are they in
     * a first pass (o->first_pass), whose last fit only its order
     * test reads: fitted there, they were 3 % of 47 Tuc's run. */
    if (fit_stars(s, n, e, o, &r->z, held, !held, err))
        return 1;
    if (held)
        reject_chi2(s, n, r->tmp);
    size_t m = count_used(s, n);
    if (m < (size_t)(2 * e->nterms + 1)) {
        snprintf(err, MP_ERRLEN, "psf build: only %zu usable PSF stars (an order-%d PSF "
                 "needs %d)", m, e->order, 2 * e->nterms + 1);
        return 1;
    }
    if (mp_epsf_sirt_run(&r->w, s, n, o, e, err))
        return 1;
    mp_epsf_normalise(e, o->fwhm, o->support);
    /* The SIRT's own rule, one level up: once the stars' clip has run,
     * a round of fits and steps that no longer lowers the χ² of the
     * stars it kept by more than a step made from pure noise would
     * (mp_epsf_sirt_floor) fits only noise.  From a Gaussian that is
     * tested from round 2 on (against round 1, whose neighbours were
     * fitted), from a table already made from round 1 (against round
     * 0, held as well): such a build mostly stops there.  Against one
     * (the floor before 2026-12-05), a build from the table its stars
     * were drawn with ran every round to o->outer: a round's drop on
     * noise, 6-29, never falls below one (test_psf_build's
     * test_rounds_stop_on_noise). */
    double drop = mp_epsf_common_drop(s, n, r->w.chi2s, r->last), floor = 1.0;
    if (it < r->stop_from)
        return 0;
    if (mp_epsf_sirt_floor(&r->w, s, n, o, e, drop, &floor, err))
        return 1;
    return drop >= floor ? 0 : 2;
}

int mp_epsf_rounds(mp_epsf_star *s, size_t n, const mp_epsf_opts *o, int os, int order,
                   mp_epsf *e, char *err)
{
    if (os < 1 || os > 8 || order < 0 || order > MP_PSF_MAXORDER) {
        snprintf(err, MP_ERRLEN, "psf build: oversamp %d or order %d out of range", os, order);
        return 1;
    }
    int cold;
    if (start_planes(o, os, order, e, &cold, err))
        return 1;
    rounds_state r;
    memset(&r, 0, sizeof r);
    r.held_from = cold ? 2 : 0;
    r.stop_from = cold ? 2 : 1;
    for (size_t k = 0; k < n; k++)
        s[k].used = !s[k].skip;
    if (mp_epsf_sirt_init(&r.w, e, n, err))
        return 1;
    mp_epsf_fitter_start(&r.z, o->grid, o->spare);
    int rc = 1;
    r.tmp = malloc((n + 1) * sizeof *r.tmp);
    r.last = malloc((n + 1) * sizeof *r.last);
    if (!r.tmp || !r.last) {
        oom(err);
        goto done;
    }
    for (size_t k = 0; k < n; k++)
        r.last[k] = NAN;    /* no round yet */
    rc = 0;
    for (int it = 0; it < o->outer && rc == 0; it++)
        rc = one_round(s, n, o, it, e, &r, err);
    if (rc == 1)
        goto done;
    e->filtered = 0;
    e->nstar = (int)count_used(s, n);
    rc = 0;
done:
    free(r.tmp);
    free(r.last);
    e->fits += r.z.fits;
    e->fits_grid += r.z.fits_grid;
    mp_epsf_fitter_done(&r.z, o->spare);
    mp_epsf_sirt_free(&r.w);
    return rc;
}

int mp_epsf_build(mp_epsf_star *s, size_t n, const mp_epsf_opts *o, int os, int order,
                  mp_epsf *e, char *err)
{
    /* The stars' last fit with the final table. */
    return mp_epsf_rounds(s, n, o, os, order, e, err) || mp_epsf_refit(s, n, o, e, err);
}

int mp_epsf_refit(mp_epsf_star *s, size_t n, const mp_epsf_opts *o, mp_epsf *e, char *err)
{
    mp_epsf_fitter z;
    mp_epsf_fitter_start(&z, o->grid, o->spare);
    int hold = o->frame_nb || o->first_pass;
    int rc = mp_epsf_fitter_set(&z, e, s, n, hold, err) || fit_stars(s, n, e, o, &z, hold, 0, err);
    e->nstar = (int)count_used(s, n);
    e->fits += z.fits;
    e->fits_grid += z.fits_grid;
    mp_epsf_fitter_done(&z, o->spare);
    return rc;
}
