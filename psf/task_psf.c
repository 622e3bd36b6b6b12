/* task_psf.c — `matphot psf IMAGE [stars=LIST]`: find the stars, pick the
 * PSF stars (or take the list), build the table, fit every star with it,
 * rebuild with their neighbours subtracted, write the PSF file. */
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include "find/find.h"
#include "group/group.h"
#include "psf/build.h"

typedef struct {
    mp_epsf_opts o;
    mp_datapars dp;
    int passes, mesh, filter;
    double threshold;
    int measure;               /* fwhm=INDEF: the stars' FWHM measured */
    double psfrad, fitrad;     /* as given (NaN: INDEF, from fwhm) */
    const char *image, *stars, *output;
} psf_task;

/* What follows fwhm: the table's and the stars' fit's radii, unless
 * given. */
static void set_fwhm(psf_task *t, double fwhm)
{
    t->o.fwhm = fwhm;
    t->o.psfrad = isfinite(t->psfrad) ? t->psfrad : 4.0 * fwhm;
    t->o.fitrad = isfinite(t->fitrad) ? t->fitrad : 2.0 * fwhm;
    t->o.fitrad = fmin(t->o.fitrad, t->o.psfrad);
}

static int read_opts(const mp_parset *ps, psf_task *t, char *err)
{
    memset(t, 0, sizeof *t);
    double fwhm = NAN;
    int os = MP_PAR_INDEF_INT;
    mp_par_real(ps, "fwhm", &fwhm);
    t->measure = !isfinite(fwhm);
    t->psfrad = t->fitrad = NAN;
    mp_par_real(ps, "psfrad", &t->psfrad);
    mp_par_real(ps, "fitrad", &t->fitrad);
    mp_par_int(ps, "oversamp", &os);
    mp_epsf_opts_default(3.0, 1, 1, &t->o);
    set_fwhm(t, t->measure ? 3.0 : fwhm);   /* INDEF: measured on the frame (run) */
    t->o.os = os == MP_PAR_INDEF_INT ? 0 : os;
    const char *vo = mp_par_string(ps, "varorder");
    t->o.order = !strcmp(vo, "auto") ? -1 : atoi(vo);
    mp_par_real(ps, "alpha", &t->o.alpha);
    mp_par_int(ps, "maxnpsf", &t->o.maxnpsf);
    mp_par_int(ps, "passes", &t->passes);
    mp_par_int(ps, "mesh", &t->mesh);
    mp_par_int(ps, "filter", &t->filter);
    mp_par_real(ps, "threshold", &t->threshold);
    mp_datapars_read(ps, &t->dp);
    t->image = mp_par_string(ps, "image");
    t->stars = mp_par_string(ps, "stars");
    t->output = mp_par_string(ps, "output");
    if (!t->image || !t->image[0]) {
        snprintf(err, MP_ERRLEN, "image: no image given");
        return 1;
    }
    return mp_out_fits_named("output", t->output, err);
}

/* A table wider than the frame holds no star whole: psfrad=200 on a 128²
 * frame ran out of memory after a minute, psfrad=80 on 160² built a
 * table of no light. */
static int table_fits(const psf_task *t, const mp_frame *f, char *err)
{
    long n = f->im.nx > f->im.ny ? f->im.nx : f->im.ny;
    if (2.0 * t->o.psfrad + 1.0 <= (double)n)
        return 0;
    snprintf(err, MP_ERRLEN, "psfrad: %g px makes a table %g px across, wider than the frame "
             "%s (%ld x %ld pixels)", t->o.psfrad, 2.0 * t->o.psfrad + 1.0, t->image, f->im.nx,
             f->im.ny);
    return 1;
}

/* The stars given as a list: X_IMAGE/Y_IMAGE (or XPSF_/YPSF_), every one
 * on the frame. */
static int stars_from_list(const psf_task *t, const mp_frame *f, double **x, double **y,
                           double **fl, size_t *n, char *err)
{
    mp_table l;
    mp_table_init(&l);
    char e2[MP_ERRLEN];
    if (mp_table_read(t->stars, &l, e2)) {
        snprintf(err, MP_ERRLEN, "%.500s", e2);
        return 1;
    }
    int cx = mp_table_col(&l, "X_IMAGE"), cy = mp_table_col(&l, "Y_IMAGE");
    if (cx < 0 || cy < 0) {
        cx = mp_table_col(&l, "XPSF_IMAGE");
        cy = mp_table_col(&l, "YPSF_IMAGE");
    }
    int cf = mp_table_col(&l, "FLUX_PSF") >= 0 ? mp_table_col(&l, "FLUX_PSF") : mp_table_col(&l, "FLUX");
    int rc = 1;
    if (cx < 0 || cy < 0) {
        snprintf(err, MP_ERRLEN, "%s: no X_IMAGE/Y_IMAGE (or XPSF_IMAGE/YPSF_IMAGE) columns",
                 t->stars);
        goto done;
    }
    if (l.nrow == 0) {
        snprintf(err, MP_ERRLEN, "%s: no stars in the list", t->stars);
        goto done;
    }
    *x = malloc(l.nrow * sizeof **x);
    *y = malloc(l.nrow * sizeof **y);
    *fl = malloc(l.nrow * sizeof **fl);
    if (!*x || !*y || !*fl) {
        snprintf(err, MP_ERRLEN, "out of memory");
        goto done;
    }
    for (size_t r = 0; r < l.nrow; r++) {
        double X = mp_table_get(&l, r, cx), Y = mp_table_get(&l, r, cy);
        if (!(X >= 0.5 && X < f->im.nx + 0.5 && Y >= 0.5 && Y < f->im.ny + 0.5)) {
            snprintf(err, MP_ERRLEN, "%s: row %zu: star at (%g, %g) is outside the %ldx%ld "
                     "frame %s", t->stars, r + 1, X, Y, f->im.nx, f->im.ny, t->image);
            goto done;
        }
        (*x)[r] = X;
        (*y)[r] = Y;
        (*fl)[r] = cf >= 0 ? mp_table_get(&l, r, cf) : NAN;
    }
    *n = l.nrow;
    rc = 0;
done:
    mp_table_free(&l);
    return rc;
}

/* Every detection fitted with the first pass's table (grouped as the
 * pipeline groups), and the residual: what the second pass needs.  With
 * the fit's economy as `matphot fit` has it: the sinc kernel's choice and,
 * for a constant PSF, the phase grid, each built only when the frame's
 * fits pay for it and used only within its bias bound (fit/fit.h). */
static int fit_all(const mp_frame *f, const psf_task *t, mp_table *found,
                   const mp_prf_model *m, float *res, char *err)
{
    mp_group_opts go;
    mp_group_opts_default(&go);
    go.fitrad = t->o.fitrad;
    go.psfrad = t->o.psfrad;
    if (mp_group_table(found, &go, err))
        return 1;
    mp_frame_opts fo;
    mp_frame_opts_default(&fo);
    fo.fit.fitrad = t->o.fitrad;
    if (!(fo.cache = mp_econ_cache_new())) {
        snprintf(err, MP_ERRLEN, "out of memory");
        return 1;
    }
    int rc = mp_econ_offer(fo.cache, m, 0, NULL, m->sinc_hw > 0,
                           m->psf->field ? 0 : MP_PRF_CACHE_G);
    if (rc)
        snprintf(err, MP_ERRLEN, "out of memory");
    else
        rc = mp_fit_table(f, m, &fo, found, NULL, err);
    const mp_prf_cache *grid = NULL;
    if (!rc) {
        /* The residual from the grid the fit built, within its bound. */
        mp_frame_opts oe = fo;
        rc = mp_econ_choose(fo.cache, (double)found->nrow, fo.fit.fitrad, &oe, NULL, err);
        grid = oe.grid;
    }
    /* Its flux limit on no sky (the safe side: less sky, lower limit). */
    if (!rc)
        rc = grid ? mp_fit_residual_grid(f, m, found, 0.0, NULL, grid,
                                         mp_prf_cache_limit(grid, 0.0, f->rdnoise, fo.sincfrac),
                                         NULL, res, err)
                  : mp_fit_residual(f, m, found, 0.0, res, err);
    mp_econ_cache_free(fo.cache);
    return rc;
}

/* find's options for the PSF stars' detection: DAOPHOT's, the kernel of
 * fwhm, the task's threshold. */
static mp_find_opts find_opts(const psf_task *t)
{
    mp_find_opts fo;
    mp_find_opts_default(&fo);
    fo.fwhm = t->o.fwhm;
    fo.threshold = t->threshold;
    return fo;
}

/* After err (a build short of stars): the stars' FWHM measured on the
 * detections, when more than 3 σ off fwhm (psfrad and fitrad follow it:
 * a start far off the stars' leaves none alone, or fits none).  Where
 * they give too few (a kernel below 1 px, or found's rows refitted by
 * the second pass with the failing table), as fwhm=INDEF measures it. */
static void fwhm_hint(const psf_task *t, const mp_frame *f, const mp_bkg *b,
                      const mp_table *found, char *err)
{
    mp_stars_fwhm m;
    mp_find_opts fo = find_opts(t);
    char e2[MP_ERRLEN];
    size_t l = strlen(err);
    if (mp_epsf_stars_fwhm_found(f, b, &fo, found, MP_EPSF_FWHM_STARS, &m, e2))
        return;
    if (m.n < MP_EPSF_FWHM_NEED && mp_epsf_frame_fwhm(f, b, &fo, t->image, &m, e2))
        return;
    if (!mp_epsf_fwhm_off(&m, t->o.fwhm) || l >= MP_ERRLEN)
        return;
    snprintf(err + l, MP_ERRLEN - l, "; the stars' FWHM is %.3g +- %.1g px (%d lone stars), "
             "not fwhm=%g", m.fwhm, m.err, m.n, t->o.fwhm);
}

/* The find table's rows picked by mp_epsf_select as arrays. */
static int stars_selected(const psf_task *t, const mp_frame *f, const mp_table *found,
                          double **x, double **y, double **fl, size_t *n, char *err)
{
    size_t *idx = malloc((size_t)(t->o.maxnpsf + 1) * sizeof *idx);
    if (!idx) {
        snprintf(err, MP_ERRLEN, "out of memory");
        return 1;
    }
    if (mp_epsf_select(f, found, &t->o, idx, n, err)) {
        free(idx);
        return 1;
    }
    *x = malloc((*n + 1) * sizeof **x);
    *y = malloc((*n + 1) * sizeof **y);
    *fl = malloc((*n + 1) * sizeof **fl);
    if (!*x || !*y || !*fl) {
        free(idx);
        snprintf(err, MP_ERRLEN, "out of memory");
        return 1;
    }
    int cx = mp_table_col(found, "X_IMAGE"), cy = mp_table_col(found, "Y_IMAGE");
    int cf = mp_table_col(found, "FLUX");
    for (size_t k = 0; k < *n; k++) {
        (*x)[k] = mp_table_get(found, idx[k], cx);
        (*y)[k] = mp_table_get(found, idx[k], cy);
        (*fl)[k] = mp_table_get(found, idx[k], cf);
    }
    free(idx);
    if (*n == 0) {
        snprintf(err, MP_ERRLEN, "%s: no usable PSF star among %zu detections (none bright, "
                 "unsaturated, unmasked, star-like and without a brighter neighbour within "
                 "psfrad %.1f px)", t->image, found->nrow, t->o.psfrad);
        return 1;
    }
    return 0;
}

/* The frame's polynomial origin and scales (its centre and half-sizes),
 * and its detections into found (b: its sky and noise maps, estimated). */
static int detect(psf_task *t, const mp_frame *f, mp_bkg *b, mp_table *found, char *err)
{
    t->o.x0 = 0.5 * (double)(f->im.nx + 1);
    t->o.y0 = 0.5 * (double)(f->im.ny + 1);
    t->o.xs = f->im.nx > 1 ? 0.5 * (double)f->im.nx : 1.0;
    t->o.ys = f->im.ny > 1 ? 0.5 * (double)f->im.ny : 1.0;
    mp_find_opts fo = find_opts(t);
    if (mp_find_stars(f, b, &fo, found, err))
        return 1;
    if (found->nrow == 0) {     /* a frame with no usable star: said as find says it */
        char why[320];
        mp_find_why_none(f, b, fo.threshold, why, sizeof why);
        snprintf(err, MP_ERRLEN, "%.180s: no usable star: %.310s", t->image, why);
        return 1;
    }
    return 0;
}

/* The second pass (DAOPHOT's): every detection fitted with the first
 * pass's table and subtracted, the PSF stars put back one by one and the
 * table built again from the residual (its order from the first pass's,
 * raised if needed, unless given); its PSF stars into *ps. */
static int second_pass(const psf_task *t, const mp_frame *f, mp_table *found,
                       const double *x, const double *y, const double *fl, size_t n, mp_epsf *e,
                       mp_epsf_report *rep, mp_psf_star **ps, char *err)
{
    mp_psf_field fld;
    memset(&fld, 0, sizeof fld);
    mp_psf tab;
    memset(&tab, 0, sizeof tab);
    mp_prf_model m;
    float *res = NULL;
    char e2[MP_ERRLEN];
    int rc = 1;
    if (mp_epsf_field(e, &fld, err) || mp_epsf_model(&fld, &tab, &m, err))
        goto done;
    if (!(res = malloc((size_t)f->im.nx * f->im.ny * sizeof *res))) {
        snprintf(err, MP_ERRLEN, "out of memory");
        goto done;
    }
    if (fit_all(f, t, found, &m, res, err))
        goto done;
    mp_epsf_opts o2 = t->o;
    o2.order = -1;     /* from the first pass's order, raised if needed */
    if (t->o.order >= 0)
        o2.order = t->o.order;
    if (mp_epsf_pass(f, res, 1, found, &m, x, y, fl, n, &o2, e, rep, ps, e2)) {
        snprintf(err, MP_ERRLEN, "%s: pass 2: %.400s", t->image, e2);
        goto done;
    }
    fprintf(stderr, "matphot psf: %s: pass 2 (neighbours subtracted): %s\n", t->image, rep->what);
    rc = 0;
done:
    free(res);
    mp_psf_field_free(&fld);
    mp_psf_free(&tab);
    return rc;
}

/* 1 with err when the PSF file (output=, or the image's name with
 * .psf.fits) is one of the task's inputs (io.h mp_out_overwrites): asked
 * before the build, not after it. */
static int output_clear(const psf_task *t, char *err)
{
    char *named = NULL;
    const char *out = t->output;
    if (!out || !out[0]) {
        if (!(named = mp_name_after(t->image, ".psf.fits"))) {
            snprintf(err, MP_ERRLEN, "out of memory");
            return 1;
        }
        out = named;
    }
    const char *in[4] = {t->image, t->stars, t->dp.dqmask, t->dp.errplane};
    int rc = mp_outputs_clear(in, 4, &out, 1, err);
    free(named);
    return rc;
}

/* The table e written as the PSF file (output=, or the image's name with
 * .psf.fits), with its PSF stars ps[0..n). */
static int write_psf(const psf_task *t, const mp_epsf *e, const mp_psf_star *ps, size_t n,
                     char *err)
{
    mp_psf_field fld;
    memset(&fld, 0, sizeof fld);
    char *named = NULL;
    int rc = 1;
    if (mp_epsf_field(e, &fld, err))
        goto done;
    const char *out = t->output;
    if (!out || !out[0]) {
        if (!(named = mp_name_after(t->image, ".psf.fits"))) {
            snprintf(err, MP_ERRLEN, "out of memory");
            goto done;
        }
        out = named;
    }
    mp_tmp_sweep(NULL, out);         /* killed runs' temporaries */
    if (mp_psf_field_write(out, &fld, ps, (int)n, err))
        goto done;
    fprintf(stderr, "matphot psf: %s: wrote %s (OVERSAMP %d, %dx%d, order %d, PSFSUM %.4f)\n",
            t->image, out, fld.os, fld.nx, fld.ny, fld.order, fld.sum);
    rc = 0;
done:
    free(named);
    mp_psf_field_free(&fld);
    return rc;
}

/* fwhm=INDEF: the stars' FWHM measured on the frame (mp_epsf_frame_fwhm),
 * as pipeline measures it, and what follows it set from it. */
static int measure_fwhm(psf_task *t, const mp_frame *f, const mp_bkg *b, char *err)
{
    mp_stars_fwhm m;
    mp_find_opts fo = find_opts(t);
    if (mp_epsf_frame_fwhm(f, b, &fo, t->image, &m, err))
        return 1;
    set_fwhm(t, m.fwhm);
    fprintf(stderr, "matphot psf: %s: fwhm INDEF: the stars' FWHM %.3g +- %.2g px (a Gaussian "
            "fitted to each of %d lone detections); psfrad %g px, fitrad %g px\n", t->image,
            m.fwhm, m.err, m.n, t->o.psfrad, t->o.fitrad);
    return 0;
}

/* matphot psf: read, detect, pick the PSF stars (or take the list), build
 * (pass 1, and pass 2 with the neighbours subtracted), write. */
static int run(psf_task *t, char *err)
{
    mp_frame f;
    memset(&f, 0, sizeof f);
    mp_bkg b;
    memset(&b, 0, sizeof b);
    mp_table found;
    mp_table_init(&found);
    mp_epsf e;
    memset(&e, 0, sizeof e);
    mp_psf_star *ps = NULL;
    double *x = NULL, *y = NULL, *fl = NULL;
    size_t n = 0;
    int rc = 1;
    mp_epsf_report rep;
    memset(&rep, 0, sizeof rep);
    /* the sky and noise maps once, for the measure and the detection */
    if (output_clear(t, err) || mp_frame_read(t->image, &t->dp, &f, err) ||
        mp_bkg_estimate(&f, t->mesh, t->filter, &b, err) ||
        (t->measure && measure_fwhm(t, &f, &b, err)) || table_fits(t, &f, err) ||
        detect(t, &f, &b, &found, err))
        goto done;
    int listed = t->stars && t->stars[0];
    if (listed ? stars_from_list(t, &f, &x, &y, &fl, &n, err)
               : stars_selected(t, &f, &found, &x, &y, &fl, &n, err)) {
        if (!listed && n == 0)
            fwhm_hint(t, &f, &b, &found, err);
        goto done;
    }
    char e2[MP_ERRLEN];
    /* The PSF stars used go into the file (PSFSTARS): the last pass's. */
    if (mp_epsf_pass(&f, f.im.pix, 0, &found, NULL, x, y, fl, n, &t->o, &e, &rep,
                     t->passes > 1 ? NULL : &ps, e2)) {
        snprintf(err, MP_ERRLEN, "%s: %.300s", t->image, e2);
        fwhm_hint(t, &f, &b, &found, err);
        goto done;
    }
    fprintf(stderr, "matphot psf: %s: pass 1: %s\n", t->image, rep.what);
    if (t->passes > 1 && second_pass(t, &f, &found, x, y, fl, n, &e, &rep, &ps, err)) {
        fwhm_hint(t, &f, &b, &found, err);
        goto done;
    }
    rc = write_psf(t, &e, ps, n, err);
done:
    free(ps);
    free(x);
    free(y);
    free(fl);
    mp_epsf_free(&e);
    mp_table_free(&found);
    mp_bkg_free(&b);
    mp_frame_free(&f);
    return rc;
}

int mp_task_psf(int argc, char **argv)
{
    mp_parset ps;
    int b = mp_task_begin("psf", argc, argv, &ps);
    if (b)
        return b;
    char err[MP_ERRLEN] = "";
    psf_task t;
    int rc = read_opts(&ps, &t, err) || run(&t, err);
    if (rc)
        fprintf(stderr, "matphot psf: %s\n", err);
    mp_params_free(&ps);
    return rc ? 1 : 0;
}
