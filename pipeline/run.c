/* run.c — the pipeline of one frame: find → group → fit, then rounds of
 * find on the residual → add the new stars → group → fit (DAOPHOT's
 * practice, anchors.md §1.1), then the catalog. */
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <time.h>
#include "pipeline/pipeline.h"

static double now(void)
{
    return mp_seconds();
}

/* root + ext, written atomically in format fmt. */
static int write_named(const char *root, const char *ext, const mp_table *t,
                       mp_table_format fmt, char *err)
{
    size_t n = strlen(root) + strlen(ext) + 1;
    char *path = malloc(n);
    if (!path) {
        snprintf(err, MP_ERRLEN, "out of memory");
        return 1;
    }
    snprintf(path, n, "%s%s", root, ext);
    int rc = mp_table_write(path, t, fmt, err);
    free(path);
    return rc;
}

/* Position of a row: the fitted one when there is one. */
static void row_xy(const mp_table *t, size_t r, double *x, double *y)
{
    int fx = mp_table_col(t, "XPSF_IMAGE"), fy = mp_table_col(t, "YPSF_IMAGE");
    int cx = mp_table_col(t, "X_IMAGE"), cy = mp_table_col(t, "Y_IMAGE");
    *x = fx >= 0 ? mp_table_get(t, r, fx) : NAN;
    *y = fy >= 0 ? mp_table_get(t, r, fy) : NAN;
    if (!isfinite(*x) || !isfinite(*y)) {
        *x = cx >= 0 ? mp_table_get(t, r, cx) : NAN;
        *y = cy >= 0 ? mp_table_get(t, r, cy) : NAN;
    }
}

/* before = NUMBER and position of every row of t. */
static int positions_of(const mp_table *t, mp_table *before)
{
    mp_table_free(before);
    mp_table_init(before);
    int n = mp_table_add_col(before, "NUMBER"), x = mp_table_add_col(before, "X_IMAGE"),
        y = mp_table_add_col(before, "Y_IMAGE"), tn = mp_table_col(t, "NUMBER");
    if (n < 0 || x < 0 || y < 0)
        return 1;
    for (size_t r = 0; r < t->nrow; r++) {
        long row = mp_table_add_row(before);
        if (row < 0)
            return 1;
        double px, py;
        row_xy(t, r, &px, &py);
        mp_table_set(before, (size_t)row, n, tn >= 0 ? mp_table_get(t, r, tn) : (double)r);
        mp_table_set(before, (size_t)row, x, px);
        mp_table_set(before, (size_t)row, y, py);
    }
    return 0;
}

/* Known stars on a grid of cells matchrad wide, so each new detection is
 * compared with its neighbourhood only. */
typedef struct {
    long nx, ny;
    double cell;
    long *head, *next;   /* per cell: first row; per row: next row in its cell */
} star_grid;

static long cell_of(const star_grid *g, double x, double y)
{
    long i = (long)floor(x / g->cell), j = (long)floor(y / g->cell);
    i = i < 0 ? 0 : (i >= g->nx ? g->nx - 1 : i);
    j = j < 0 ? 0 : (j >= g->ny ? g->ny - 1 : j);
    return j * g->nx + i;
}

static int grid_build(star_grid *g, const mp_table *t, long fnx, long fny, double cell)
{
    g->cell = cell > 0.5 ? cell : 0.5;
    g->nx = (long)(fnx / g->cell) + 2;
    g->ny = (long)(fny / g->cell) + 2;
    g->head = malloc((size_t)(g->nx * g->ny) * sizeof *g->head);
    g->next = malloc((t->nrow ? t->nrow : 1) * sizeof *g->next);
    if (!g->head || !g->next)
        return 1;
    for (long i = 0; i < g->nx * g->ny; i++)
        g->head[i] = -1;
    for (size_t r = 0; r < t->nrow; r++) {
        double x, y;
        row_xy(t, r, &x, &y);
        if (!isfinite(x) || !isfinite(y)) {
            g->next[r] = -1;
            continue;
        }
        long c = cell_of(g, x, y);
        g->next[r] = g->head[c];
        g->head[c] = (long)r;
    }
    return 0;
}

static int grid_near(const star_grid *g, const mp_table *t, double x, double y, double r)
{
    long ci = (long)floor(x / g->cell), cj = (long)floor(y / g->cell);
    for (long j = cj - 1; j <= cj + 1; j++)
        for (long i = ci - 1; i <= ci + 1; i++) {
            if (i < 0 || j < 0 || i >= g->nx || j >= g->ny)
                continue;
            for (long k = g->head[j * g->nx + i]; k >= 0; k = g->next[k]) {
                double sx, sy;
                row_xy(t, (size_t)k, &sx, &sy);
                if (hypot(sx - x, sy - y) < r)
                    return 1;
            }
        }
    return 0;
}

/* Append the detections of found that are not within matchrad of a star of
 * t, numbered on from t's largest NUMBER; their fit starts from find's
 * position and flux.  Returns the number added, −1 when out of memory. */
static long add_new_stars(mp_table *t, const mp_table *gone, const mp_table *found, long fnx,
                          long fny, double matchrad)
{
    star_grid g = {0}, gg = {0};
    long added = -1;
    if (grid_build(&g, t, fnx, fny, matchrad) || grid_build(&gg, gone, fnx, fny, matchrad))
        goto done;
    int cnum = mp_table_add_col(t, "NUMBER");
    if (cnum < 0)
        goto done;
    double maxnum = 0;
    for (size_t r = 0; r < t->nrow; r++)
        if (mp_table_get(t, r, cnum) > maxnum)
            maxnum = mp_table_get(t, r, cnum);
    added = 0;
    int fx = mp_table_col(found, "X_IMAGE"), fy = mp_table_col(found, "Y_IMAGE");
    for (size_t r = 0; r < found->nrow && fx >= 0 && fy >= 0; r++) {
        double x = mp_table_get(found, r, fx), y = mp_table_get(found, r, fy);
        if (!isfinite(x) || !isfinite(y) || grid_near(&g, t, x, y, matchrad) ||
            grid_near(&gg, gone, x, y, matchrad))
            continue;
        /* The grid holds the stars known before this round only: two
         * detections of one residual peak are find's business, not ours. */
        long row = mp_table_add_row(t);
        if (row < 0) {
            added = -1;
            goto done;
        }
        for (size_t c = 0; c < found->ncol; c++) {
            int tc = mp_table_add_col(t, found->cols[c].name);
            if (tc < 0) {
                added = -1;
                goto done;
            }
            mp_table_set(t, (size_t)row, tc, mp_table_get(found, r, (int)c));
        }
        const char *pairs[3][2] = {{"XPSF_IMAGE", "X_IMAGE"}, {"YPSF_IMAGE", "Y_IMAGE"},
                                   {"FLUX_PSF", "FLUX"}};
        for (int p = 0; p < 3; p++) {
            int to = mp_table_col(t, pairs[p][0]), from = mp_table_col(found, pairs[p][1]);
            if (to >= 0)
                mp_table_set(t, (size_t)row, to, from >= 0 ? mp_table_get(found, r, from) : NAN);
        }
        int sky = mp_table_col(t, "SKY_PSF");
        if (sky >= 0)
            mp_table_set(t, (size_t)row, sky, NAN);
        mp_table_set(t, (size_t)row, cnum, maxnum + (double)++added);
    }
done:
    free(g.head);
    free(g.next);
    free(gg.head);
    free(gg.next);
    return added;
}

/* Remember where the stars the fit merged away or rejected were, so a
 * residual peak they leave is not found and added again every round.
 * before holds NUMBER, X_IMAGE, Y_IMAGE of every row given to the fit. */
static int note_gone(mp_table *gone, const mp_table *before, const mp_table *after)
{
    int bn = mp_table_col(before, "NUMBER"), an = mp_table_col(after, "NUMBER");
    int gx = mp_table_add_col(gone, "X_IMAGE"), gy = mp_table_add_col(gone, "Y_IMAGE");
    if (bn < 0 || an < 0 || gx < 0 || gy < 0)
        return 0;
    /* NUMBERs of after are a subsequence of before's (the fit keeps the
     * order of the rows it keeps). */
    size_t j = 0;
    for (size_t i = 0; i < before->nrow; i++) {
        if (j < after->nrow && mp_table_get(after, j, an) == mp_table_get(before, i, bn)) {
            j++;
            continue;
        }
        double x, y;
        row_xy(before, i, &x, &y);
        long r = mp_table_add_row(gone);
        if (r < 0)
            return 1;
        mp_table_set(gone, (size_t)r, gx, x);
        mp_table_set(gone, (size_t)r, gy, y);
    }
    return 0;
}

/* Does the header have a CTYPE1 card (a WCS to try)? */
static int has_wcs(const mp_image *im)
{
    for (int k = 0; k < im->nkeys; k++)
        if (memcmp(im->hdr + (size_t)k * 80, "CTYPE1", 6) == 0)
            return 1;
    return 0;
}

/* root.cat (sky positions when the frame has a WCS; FITS_LDAC carries the
 * frame's header as SExtractor's does) and the DS9 regions root.reg. */
static int write_catalog(const char *root, const mp_frame *f, mp_table *t,
                         const mp_pipeline_opts *o, char *err)
{
    char e[MP_ERRLEN];
    if (has_wcs(&f->im) && mp_table_add_sky(t, &f->im, e))
        fprintf(stderr, "matphot pipeline: warning: no sky positions: %s\n", e);
    size_t n = strlen(root) + 8;
    char *path = malloc(n);
    if (!path) {
        snprintf(err, MP_ERRLEN, "out of memory");
        return 1;
    }
    int rc;
    if (o->catfmt == MP_TAB_LDAC) {
        mp_card extra[2] = {{"SEXGAIN", f->gain, NULL, "gain [e-/ADU]"},
                            {"EXPTIME", f->exptime, NULL, "exposure time [s]"}};
        mp_ldac_head h = {f->im.hdr, f->im.nkeys, extra, 2};
        snprintf(path, n, "%s.cat", root);
        rc = mp_table_write_fits(path, t, &h, err);
    } else {
        rc = write_named(root, ".cat", t, o->catfmt, err);
    }
    if (!rc && o->regions) {
        mp_region_opts ro = {3.0, 0, 1};
        snprintf(path, n, "%s.reg", root);
        rc = mp_regions_write(path, t, &ro, NULL, err);
    }
    free(path);
    return rc;
}

int mp_pipeline_run(const char *image, const char *root, const mp_pipeline_opts *o,
                    mp_pipeline_report *rep, char *err)
{
    memset(rep, 0, sizeof *rep);
    mp_frame f, R;
    memset(&f, 0, sizeof f);
    mp_bkg bkg;
    memset(&bkg, 0, sizeof bkg);
    mp_table t, found, gone, before;
    mp_table_init(&t);
    mp_table_init(&found);
    mp_table_init(&gone);
    mp_table_init(&before);
    double *res = NULL;
    int rc = 1;
    /* What every group was fitted against, so a round refits only the
     * groups the new stars (or their neighbours' changes) reach. */
    mp_fit_memory *mem = mp_fit_memory_new();
    double t0 = now();
    if (!mem) {
        snprintf(err, MP_ERRLEN, "out of memory");
        return 1;
    }
    const mp_prf_model *m = &o->fit.model;
    if (mp_frame_read(image, &o->fit.dp, &f, err))
        goto done;
    rep->t_read = now() - t0;

    t0 = now();
    if (mp_bkg_estimate(&f, o->mesh, o->filter, &bkg, err))
        goto done;
    rep->t_bkg = now() - t0;

    t0 = now();
    if (mp_find_stars(&f, &bkg, &o->find, &t, err))
        goto done;
    rep->t_find += now() - t0;
    rep->found = (long)t.nrow;
    if (write_named(root, ".coo", &t, o->fit.fmt, err))
        goto done;
    fprintf(stderr, "matphot pipeline: %s: %zu stars found\n", image, t.nrow);

    double fwhm = mp_prf_fwhm(m);
    double matchrad = isfinite(o->matchrad) ? o->matchrad : fwhm;
    size_t npix = (size_t)f.im.nx * f.im.ny;
    if (!(res = malloc(npix * sizeof *res))) {
        snprintf(err, MP_ERRLEN, "%s: out of memory for the residual", image);
        goto done;
    }
    for (int round = 1; round <= o->niter; round++) {
        rep->rounds = round;
        t0 = now();
        if (mp_group_table(&t, &o->group, err))
            goto done;
        rep->t_group += now() - t0;
        if (write_named(root, ".grp", &t, o->fit.fmt, err))
            goto done;

        t0 = now();
        mp_frame_report fr;
        if (positions_of(&t, &before)) {
            snprintf(err, MP_ERRLEN, "out of memory");
            goto done;
        }
        if (mp_fit_table_mem(&f, m, &o->fit.opts, &t, mem, &fr, err))
            goto done;
        if (note_gone(&gone, &before, &t)) {
            snprintf(err, MP_ERRLEN, "out of memory");
            goto done;
        }
        if (mp_fit_residual(&f, m, &t, o->fit.opts.cropfrac, res, err))
            goto done;
        rep->t_fit += now() - t0;
        rep->merged += fr.merged;
        rep->rejected += fr.rejected;
        rep->noconv = fr.noconv;
        rep->iterations += fr.iterations;
        rep->fits += fr.fits;
        rep->kept += fr.kept;
        rep->cropped += fr.cropped;
        rep->kcalls += fr.kcalls;
        rep->kshort += fr.kshort;
        rep->kcache += fr.kcache;
        memcpy(rep->sky_groups, fr.sky_groups, sizeof rep->sky_groups);
        rep->khw += fr.khw;
        rep->ngroups = fr.ngroups;
        rep->fitted = (long)t.nrow;
        fprintf(stderr, "matphot pipeline: %s: round %d: %ld stars fitted in %ld groups "
                "(%ld merged, %ld rejected; %ld group fits, %ld kept), %.2f s\n", image, round,
                fr.nstars - fr.merged - fr.rejected, fr.ngroups, fr.merged, fr.rejected, fr.fits,
                fr.kept, now() - t0);
        if (round == o->niter)
            break;

        /* The residual keeps the sky.  Its sky is measured anew (the star
         * light is gone from the boxes) and its noise map comes from the
         * fitted model: in a crowded frame the first map's boxes average
         * star light into the rms (frame C of the DAOPHOT comparison:
         * 13.4 e- against the sky's 10.4), which hides faint stars in the
         * gaps and under-states the noise on bright stars, all the more
         * when the PSF does not match them (GLIMPSE: spurious companions
         * at 0.7 FWHM taking 15-40 % of bright stars' light). */
        t0 = now();
        R = f;
        R.im.pix = res;
        mp_table_free(&found);
        mp_table_init(&found);
        for (size_t i = 0; i < npix; i++)
            if (!isfinite(res[i]))
                res[i] = 0.0;
        mp_bkg_free(&bkg);
        double kscale, proferr;
        if (mp_bkg_estimate(&R, o->mesh, o->filter, &bkg, err) ||
            mp_bkg_noise_from_model(&bkg, &f, res, (int)lround(fmax(1.0, fwhm)), &kscale,
                                    &proferr, err))
            goto done;
        /* A star half-hidden by a neighbour's fit leaves a lopsided residual
         * peak: relax the roundness limits there (the fit then keeps or
         * rejects what was found, by its significance). */
        mp_find_opts ro = o->find;
        ro.roundlo = fmin(ro.roundlo, -2.0);
        ro.roundhi = fmax(ro.roundhi, 2.0);
        int frc = mp_find_stars(&R, &bkg, &ro, &found, err);
        rep->t_find += now() - t0;
        if (frc)
            goto done;
        long added = add_new_stars(&t, &gone, &found, f.im.nx, f.im.ny, matchrad);
        if (added < 0) {
            snprintf(err, MP_ERRLEN, "out of memory");
            goto done;
        }
        rep->added += added;
        if (isfinite(kscale))
            fprintf(stderr, "matphot pipeline: %s: round %d: %ld new stars on the residual "
                    "(noise: %.3f x Poisson, profile error %.1f %%)\n", image, round, added,
                    kscale, 100.0 * proferr);
        else
            fprintf(stderr, "matphot pipeline: %s: round %d: %ld new stars on the residual "
                    "(noise: the residual's mesh map)\n", image, round, added);
        if (added == 0) {
            /* Nothing new: the last fit stands, its residual is current. */
            break;
        }
    }

    t0 = now();
    if (write_named(root, ".fit", &t, o->fit.fmt, err))
        goto done;
    for (size_t i = 0; i < npix; i++)
        res[i] = (f.mask[i] & MP_MASK_BAD) ? NAN : res[i] / f.gain;
    {
        size_t n = strlen(root) + 10;
        char *path = malloc(n);
        if (!path) {
            snprintf(err, MP_ERRLEN, "out of memory");
            goto done;
        }
        snprintf(path, n, "%s.res.fits", root);
        mp_card cards[2] = {{"GAIN", f.gain, NULL, "e-/ADU"}, {"RDNOISE", f.rdnoise, NULL, "e-"}};
        int wrc = mp_image_write(path, res, f.im.nx, f.im.ny, -32, cards, 2, err);
        free(path);
        if (wrc)
            goto done;
    }
    if (write_catalog(root, &f, &t, o, err))
        goto done;
    rep->t_write = now() - t0;
    /* The run report: stage seconds, counts, error against prediction, parts. */
    {
        mp_run_report run;
        memset(&run, 0, sizeof run);
        run.image = image;
        run.t_read = rep->t_read;
        run.t_bkg = rep->t_bkg;
        run.t_find = rep->t_find;
        run.t_group = rep->t_group;
        run.t_fit = rep->t_fit;
        run.t_write = rep->t_write;
        run.nstars = (long)t.nrow;
        run.ngroups = rep->ngroups;
        run.iterations = rep->iterations;
        run.merged = rep->merged;
        run.rejected = rep->rejected;
        run.noconv = rep->noconv;
        run.fits = rep->fits;
        run.kept = rep->kept;
        run.cropped = rep->cropped;
        run.kcalls = rep->kcalls;
        run.kshort = rep->kshort;
        run.kcache = rep->kcache;
        run.khw = rep->khw;
        mp_report_from_table(&t, &run);
        mp_frame_report last = {.nstars = (long)t.nrow, .ngroups = rep->ngroups};
        memcpy(last.sky_groups, rep->sky_groups, sizeof last.sky_groups);
        mp_report_parts(m, &o->fit.opts, &last, &run);
        run.decisions = o->fit.decisions;
        run.ndecisions = o->fit.ndecisions;
        size_t n = strlen(root) + 8;
        char *path = malloc(n);
        if (!path) {
            snprintf(err, MP_ERRLEN, "out of memory");
            goto done;
        }
        snprintf(path, n, "%s.report", root);
        int wrc = mp_report_write(path, "pipeline", &run, err);
        free(path);
        if (wrc)
            goto done;
    }
    rc = 0;
done:
    mp_fit_memory_free(mem);
    free(res);
    mp_table_free(&t);
    mp_table_free(&found);
    mp_table_free(&gone);
    mp_table_free(&before);
    mp_bkg_free(&bkg);
    mp_frame_free(&f);
    return rc;
}
