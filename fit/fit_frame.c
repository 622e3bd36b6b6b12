/* fit_frame.c — fitting every star of a table on one frame as ALLSTAR does
 * (anchors.md §1.6): groups fitted simultaneously, in parallel, each on a
 * local copy of its pixels from which the light of every other star has
 * been subtracted; close pairs merged and insignificant stars rejected, the
 * group refitted after each change. */
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include "fit/fit.h"

void mp_frame_opts_default(mp_frame_opts *o)
{
    mp_fit_opts_default(&o->fit);
    o->fit.fitrad = 5.0;
    o->magzero = 0.0;
    o->mergerad = NAN;
    o->minsnr = 2.0;
    o->passes = 2;
}

/* Column of a table by the first name present, -1 if none. */
static int col_any(const mp_table *t, const char *a, const char *b)
{
    int c = mp_table_col(t, a);
    return c >= 0 ? c : (b ? mp_table_col(t, b) : -1);
}

/* The state of one star through the passes. */
typedef struct {
    mp_star s;          /* current estimate (global coordinates) */
    double id;          /* group id */
    long row;
    int alive;
} star_state;

static int cmp_group(const void *a, const void *b)
{
    const star_state *x = a, *y = b;
    if (x->id != y->id)
        return (x->id > y->id) - (x->id < y->id);
    return (x->row > y->row) - (x->row < y->row);
}

/* Add (sign +1) or subtract E·PRF of one star to an image window
 * [x0, x0+w) × [y0, y0+h) (1-based global), row stride w. */
static int paint(const mp_prf_model *m, const mp_star *s, double sign, double *img,
                 long x0, long y0, long w, long h, mp_prf_work *wk, double **buf, size_t *cap)
{
    if (!isfinite(s->flux) || !isfinite(s->x) || !isfinite(s->y) || s->flux == 0.0)
        return 0;
    long bx, by;
    int bw, bh;
    mp_prf_box(m, s->x, s->y, &bx, &by, &bw, &bh);
    if ((size_t)bw * bh > *cap) {
        free(*buf);
        *cap = (size_t)bw * bh;
        if (!(*buf = malloc(*cap * sizeof **buf)))
            return 1;
    }
    if (mp_prf_render(m, s->x, s->y, *buf, NULL, NULL, wk))
        return 1;
    for (int j = 0; j < bh; j++) {
        long Y = by + j - y0;
        if (Y < 0 || Y >= h)
            continue;
        for (int i = 0; i < bw; i++) {
            long X = bx + i - x0;
            if (X >= 0 && X < w)
                img[Y * w + X] += sign * s->flux * (*buf)[(size_t)j * bw + i];
        }
    }
    return 0;
}

double mp_prf_fwhm(const mp_prf_model *m)
{
    mp_prf_stats st;
    if (mp_prf_stats_at(m, 100.0, 100.0, &st, NULL) || !(st.lscale > 0))
        return 3.0;      /* out of memory: DAOPHOT's usual FWHM keeps find and merge going */
    return 2.0 * sqrt(2.0 * log(2.0)) * st.lscale;
}

/* Merge the closest pair of the group that is closer than mergerad or not
 * significantly separated: the brighter survives at the flux-weighted mean
 * position with the summed flux.  Returns 1 if a pair was merged. */
static int merge_one(mp_star *s, int *alive, int n, double mergerad)
{
    int a = -1, b = -1;
    double best = INFINITY;
    for (int i = 0; i < n; i++)
        for (int j = i + 1; j < n; j++) {
            if (!alive[i] || !alive[j])
                continue;
            double d = hypot(s[i].x - s[j].x, s[i].y - s[j].y);
            double es = sqrt(s[i].ex * s[i].ex + s[i].ey * s[i].ey + s[j].ex * s[j].ex + s[j].ey * s[j].ey);
            if ((d < mergerad || d < 2.0 * es) && d < best) {
                best = d;
                a = i;
                b = j;
            }
        }
    if (a < 0)
        return 0;
    if (s[b].flux > s[a].flux) {
        int t = a;
        a = b;
        b = t;
    }
    double fa = fmax(s[a].flux, 0.0), fb = fmax(s[b].flux, 0.0), ft = fa + fb;
    if (ft > 0) {
        s[a].x = (fa * s[a].x + fb * s[b].x) / ft;
        s[a].y = (fa * s[a].y + fb * s[b].y) / ft;
    }
    s[a].flux = s[a].flux + s[b].flux;
    s[a].flags |= MP_FLAG_MERGED;
    alive[b] = 0;
    return 1;
}

/* Reject the least significant star below minsnr; 1 if one was.  A star
 * rejected beside a neighbour (within 2·mergerad) was most likely half of
 * an unresolved blend whose light the neighbour now carries: flag that
 * neighbour merged (16), as if the pair had been merged. */
static int reject_one(mp_star *s, int *alive, int n, double minsnr, double mergerad)
{
    int worst = -1;
    double wsnr = minsnr;
    for (int i = 0; i < n; i++) {
        if (!alive[i])
            continue;
        double snr = s[i].eflux > 0 ? s[i].flux / s[i].eflux : (s[i].flux > 0 ? INFINITY : -INFINITY);
        if (snr < wsnr) {
            wsnr = snr;
            worst = i;
        }
    }
    if (worst < 0)
        return 0;
    alive[worst] = 0;
    int near = -1;
    double best = 2.0 * mergerad;
    for (int i = 0; i < n; i++) {
        double d = hypot(s[i].x - s[worst].x, s[i].y - s[worst].y);
        if (alive[i] && d < best) {
            best = d;
            near = i;
        }
    }
    if (near >= 0)
        s[near].flags |= MP_FLAG_MERGED;
    return 1;
}

/* Fit one group (members st[0..n-1]) on frame f: merge/reject until
 * stable.  Local copies of the stars move in the frame's coordinates
 * shifted by (dx, dy). */
static int fit_one_group(const mp_frame *f, const mp_prf_model *m, const mp_frame_opts *o,
                         double mergerad, star_state *st, int n, double dx, double dy,
                         mp_frame_report *rep, char *err)
{
    mp_star *s = malloc((size_t)n * sizeof *s), *live = malloc((size_t)n * sizeof *live);
    int *alive = malloc((size_t)n * sizeof *alive), *map = malloc((size_t)n * sizeof *map);
    int rc = 1;
    if (!s || !live || !alive || !map) {
        snprintf(err, MP_ERRLEN, "out of memory");
        goto done;
    }
    for (int k = 0; k < n; k++) {
        s[k] = st[k].s;
        s[k].x -= dx;
        s[k].y -= dy;
        alive[k] = st[k].alive;     /* merged or rejected in an earlier pass: stays out */
    }
    /* Each round removes a star or ends, so n + 1 rounds suffice. */
    for (int round = 0; round <= n; round++) {
        int nl = 0;
        for (int k = 0; k < n; k++)
            if (alive[k]) {
                live[nl] = s[k];
                map[nl++] = k;
            }
        if (nl == 0)
            break;
        double sky0 = nl == 1 ? live[0].sky : NAN;
        if (mp_fit_group(f, m, &o->fit, sky0, live, nl, err))
            goto done;
        rep->iterations += live[0].niter;
        for (int k = 0; k < nl; k++) {
            int keep = s[map[k]].flags & MP_FLAG_MERGED;
            s[map[k]] = live[k];
            s[map[k]].flags |= keep;
        }
        if (mergerad > 0 && merge_one(s, alive, n, mergerad)) {
            rep->merged++;
            continue;
        }
        if (o->minsnr > 0 && reject_one(s, alive, n, o->minsnr, mergerad)) {
            rep->rejected++;
            continue;
        }
        break;
    }
    for (int k = 0; k < n; k++)
        if (alive[k]) {          /* the group's sky order, counted once */
            int so = s[k].sky_order;
            rep->sky_groups[so > 0 && so <= MP_SKY_MAXORDER ? so : 0]++;
            break;
        }
    for (int k = 0; k < n; k++) {
        st[k].s = s[k];
        st[k].s.x += dx;
        st[k].s.y += dy;
        st[k].alive = alive[k];
        if (alive[k] && (s[k].flags & MP_FLAG_NOCONV))
            rep->noconv++;
    }
    rc = 0;
done:
    free(s);
    free(live);
    free(alive);
    free(map);
    return rc;
}

/* The window a group's fit reads: its stars ± fitrad, one pixel of margin
 * (so the fitter's edge test sees only the frame's real edges), clipped. */
static void group_window(const mp_frame *f, const star_state *st, int n, double r,
                         long *x0, long *y0, long *w, long *h)
{
    if (!isfinite(r)) {
        *x0 = *y0 = 1;
        *w = f->im.nx;
        *h = f->im.ny;
        return;
    }
    double xa = INFINITY, xb = -INFINITY, ya = INFINITY, yb = -INFINITY;
    for (int k = 0; k < n; k++) {
        xa = fmin(xa, st[k].s.x);
        xb = fmax(xb, st[k].s.x);
        ya = fmin(ya, st[k].s.y);
        yb = fmax(yb, st[k].s.y);
    }
    long a = (long)floor(xa - r) - 1, b = (long)ceil(xb + r) + 1;
    long c = (long)floor(ya - r) - 1, d = (long)ceil(yb + r) + 1;
    a = a < 1 ? 1 : a;
    c = c < 1 ? 1 : c;
    b = b > f->im.nx ? f->im.nx : b;
    d = d > f->im.ny ? f->im.ny : d;
    *x0 = a;
    *y0 = c;
    *w = b >= a ? b - a + 1 : 0;
    *h = d >= c ? d - c + 1 : 0;
}

/* Fit group g on a local frame: data − (all stars) + (its own stars). */
static int fit_group_local(const mp_frame *f, const mp_prf_model *m, const mp_frame_opts *o,
                           double mergerad, const double *all, star_state *st, int n,
                           mp_frame_report *rep, char *err)
{
    long x0, y0, w, h;
    group_window(f, st, n, o->fit.fitrad, &x0, &y0, &w, &h);
    if (w == 0 || h == 0 || (!all && x0 == 1 && y0 == 1 && w == f->im.nx && h == f->im.ny))
        return fit_one_group(f, m, o, mergerad, st, n, 0.0, 0.0, rep, err);
    mp_frame L = *f;
    L.im.nx = w;
    L.im.ny = h;
    L.im.pix = malloc((size_t)(w * h) * sizeof *L.im.pix);
    L.mask = malloc((size_t)(w * h));
    mp_prf_work wk = {0};
    double *buf = NULL;
    size_t cap = 0;
    int rc = 1;
    if (!L.im.pix || !L.mask) {
        snprintf(err, MP_ERRLEN, "out of memory");
        goto done;
    }
    for (long j = 0; j < h; j++)
        for (long i = 0; i < w; i++) {
            size_t g = (size_t)(y0 - 1 + j) * f->im.nx + (size_t)(x0 - 1 + i);
            L.im.pix[j * w + i] = f->im.pix[g] - (all ? all[g] : 0.0);
            L.mask[j * w + i] = f->mask ? f->mask[g] : 0;
        }
    if (all)
        for (int k = 0; k < n; k++)
            if (st[k].alive && paint(m, &st[k].s, +1.0, L.im.pix, x0, y0, w, h, &wk, &buf, &cap)) {
                snprintf(err, MP_ERRLEN, "out of memory");
                goto done;
            }
    rc = fit_one_group(&L, m, o, mergerad, st, n, (double)(x0 - 1), (double)(y0 - 1), rep, err);
done:
    free(L.im.pix);
    free(L.mask);
    free(buf);
    mp_prf_work_free(&wk);
    return rc;
}

/* The model of every live star on the whole frame. */
static double *all_stars(const mp_frame *f, const mp_prf_model *m, const star_state *st, size_t n)
{
    double *all = calloc((size_t)f->im.nx * f->im.ny, sizeof *all);
    mp_prf_work wk = {0};
    double *buf = NULL;
    size_t cap = 0;
    for (size_t k = 0; all && k < n; k++)
        if (st[k].alive && paint(m, &st[k].s, +1.0, all, 1, 1, f->im.nx, f->im.ny, &wk, &buf, &cap)) {
            free(all);
            all = NULL;
        }
    free(buf);
    mp_prf_work_free(&wk);
    return all;
}

/* Write the fit's columns; drop rows of merged-away or rejected stars. */
static int write_columns(mp_table *t, const star_state *st, size_t n, double magzero, char *err)
{
    static const char *const names[] = {
        "XPSF_IMAGE", "YPSF_IMAGE", "ERRX_PSF", "ERRY_PSF", "FLUX_PSF", "FLUXERR_PSF",
        "MAG_PSF", "MAGERR_PSF", "SKY_PSF", "SKYERR_PSF", "CHI2_PSF", "DOF_PSF",
        "NITER_PSF", "BETA_PSF", "SHARP_PRF", "LSCALE_PRF", "VOLUME_PRF",
        "FLUXERR_MODEL", "POSERR_MODEL", "FLAGS"};
    enum { NCOL = sizeof names / sizeof names[0] };
    int c[NCOL];
    int cflags0 = mp_table_col(t, "FLAGS");
    for (int k = 0; k < NCOL; k++)
        if ((c[k] = mp_table_add_col(t, names[k])) < 0) {
            snprintf(err, MP_ERRLEN, "out of memory");
            return 1;
        }
    unsigned char *keep = calloc(t->nrow ? t->nrow : 1, 1);
    if (!keep) {
        snprintf(err, MP_ERRLEN, "out of memory");
        return 1;
    }
    for (size_t i = 0; i < n; i++) {
        const mp_star *s = &st[i].s;
        size_t r = (size_t)st[i].row;
        keep[r] = (unsigned char)st[i].alive;
        int ok = s->flux > 0;
        /* Flags from earlier stages (find's saturation, group's split) stay. */
        double before = cflags0 >= 0 ? mp_table_get(t, r, c[NCOL - 1]) : 0.0;
        int fl = s->flags | (isfinite(before) ? (int)before : 0);
        double v[NCOL] = {
            s->x, s->y, s->ex, s->ey, s->flux, s->eflux,
            ok ? -2.5 * log10(s->flux) + magzero : 99.0,
            ok ? 2.5 / log(10.0) * s->eflux / s->flux : 99.0,
            s->sky, s->esky, s->chi2, s->dof, s->niter,
            s->st.beta, s->st.sharp, s->st.lscale, s->st.volume,
            s->fluxerr_model, s->poserr_model, fl};
        for (int k = 0; k < NCOL; k++)
            mp_table_set(t, r, c[k], v[k]);
    }
    size_t out = 0;
    for (size_t r = 0; r < t->nrow; r++)
        if (keep[r]) {
            if (out != r)
                memmove(t->v + out * t->ncol, t->v + r * t->ncol, t->ncol * sizeof *t->v);
            out++;
        }
    t->nrow = out;
    free(keep);
    return 0;
}

int mp_fit_table(const mp_frame *f, const mp_prf_model *m, const mp_frame_opts *o,
                 mp_table *t, mp_frame_report *rep, char *err)
{
    mp_frame_report dummy;
    if (!rep)
        rep = &dummy;
    memset(rep, 0, sizeof *rep);
    int cx = col_any(t, "XPSF_IMAGE", "X_IMAGE"), cy = col_any(t, "YPSF_IMAGE", "Y_IMAGE");
    if (cx < 0 || cy < 0) {
        snprintf(err, MP_ERRLEN, "table has no X_IMAGE/Y_IMAGE or XPSF_IMAGE/YPSF_IMAGE columns");
        return 1;
    }
    int cf = col_any(t, "FLUX_PSF", "FLUX"), cs = col_any(t, "SKY_PSF", "BACKGROUND");
    int cg = mp_table_col(t, "GROUP_ID");
    int whole = !isfinite(o->fit.fitrad);
    size_t n = t->nrow;
    star_state *st = calloc(n ? n : 1, sizeof *st);
    size_t *gs = malloc((n + 1) * sizeof *gs);
    double *all = NULL;
    int rc = 1;
    if (!st || !gs) {
        snprintf(err, MP_ERRLEN, "out of memory");
        goto done;
    }
    for (size_t i = 0; i < n; i++) {
        st[i].row = (long)i;
        st[i].alive = 1;
        st[i].s.x = mp_table_get(t, i, cx);
        st[i].s.y = mp_table_get(t, i, cy);
        if (!isfinite(st[i].s.x) || !isfinite(st[i].s.y)) {
            snprintf(err, MP_ERRLEN, "row %zu: position is not a finite number", i + 1);
            goto done;
        }
        st[i].s.flux = cf >= 0 ? mp_table_get(t, i, cf) : NAN;
        st[i].s.sky = cs >= 0 ? mp_table_get(t, i, cs) : NAN;
        double g = cg >= 0 ? mp_table_get(t, i, cg) : NAN;
        st[i].id = whole ? 0.0 : (isfinite(g) ? g : -1.0 - (double)i);
    }
    qsort(st, n, sizeof *st, cmp_group);
    size_t ng = 0;
    for (size_t i = 0; i < n; i++)
        if (i == 0 || st[i].id != st[i - 1].id)
            gs[ng++] = i;
    gs[ng] = n;
    rep->nstars = (long)n;
    rep->ngroups = (long)ng;
    double mergerad = isfinite(o->mergerad) ? o->mergerad : 0.4 * mp_prf_fwhm(m);
    int passes = o->passes < 1 ? 1 : o->passes;
    if (ng <= 1)
        passes = 1;                 /* nobody else's light to subtract */
    for (int pass = 0; pass < passes; pass++) {
        /* Neighbours are subtracted with the latest values; in the first
         * pass only those with a start flux (find's FLUX) can be. */
        free(all);
        if (!(all = all_stars(f, m, st, n))) {
            snprintf(err, MP_ERRLEN, "out of memory for the model image");
            goto done;
        }
        mp_frame_report pr = {0};
        int failed = 0;
        char ferr[MP_ERRLEN] = "";
#pragma omp parallel for schedule(dynamic) reduction(+ : failed)
        for (size_t g = 0; g < ng; g++) {
            char e[MP_ERRLEN];
            mp_frame_report r = {0};
            int k = (int)(gs[g + 1] - gs[g]);
            if (fit_group_local(f, m, o, mergerad, all, st + gs[g], k, &r, e)) {
                failed++;
#pragma omp critical(fit_table_error)
                snprintf(ferr, sizeof ferr, "%s", e);
            }
#pragma omp critical(fit_table_report)
            {
                pr.merged += r.merged;
                pr.rejected += r.rejected;
                pr.noconv += r.noconv;
                pr.iterations += r.iterations;
                for (int o = 0; o <= MP_SKY_MAXORDER; o++)
                    pr.sky_groups[o] += r.sky_groups[o];
            }
        }
        if (failed) {
            snprintf(err, MP_ERRLEN, "%s", ferr);
            goto done;
        }
        rep->merged += pr.merged;
        rep->rejected += pr.rejected;
        rep->iterations += pr.iterations;
        rep->noconv = pr.noconv;
        memcpy(rep->sky_groups, pr.sky_groups, sizeof rep->sky_groups);
    }
    rc = write_columns(t, st, n, o->magzero, err);
done:
    free(all);
    free(st);
    free(gs);
    return rc;
}

int mp_fit_residual(const mp_frame *f, const mp_prf_model *m, const mp_table *t,
                    double *res, char *err)
{
    long nx = f->im.nx, ny = f->im.ny;
    int cx = mp_table_col(t, "XPSF_IMAGE"), cy = mp_table_col(t, "YPSF_IMAGE");
    int cf = mp_table_col(t, "FLUX_PSF");
    if (cx < 0 || cy < 0 || cf < 0) {
        snprintf(err, MP_ERRLEN, "residual: table has no fitted columns");
        return 1;
    }
    for (long i = 0; i < nx * ny; i++)
        res[i] = (f->mask && (f->mask[i] & MP_MASK_BAD)) ? NAN : f->im.pix[i];
    mp_prf_work w = {0};
    double *buf = NULL;
    size_t cap = 0;
    int rc = 0;
    for (size_t r = 0; r < t->nrow && !rc; r++) {
        mp_star s = {.x = mp_table_get(t, r, cx), .y = mp_table_get(t, r, cy),
                     .flux = mp_table_get(t, r, cf)};
        rc = paint(m, &s, -1.0, res, 1, 1, nx, ny, &w, &buf, &cap);
    }
    free(buf);
    mp_prf_work_free(&w);
    if (rc)
        snprintf(err, MP_ERRLEN, "residual: out of memory");
    return rc;
}
