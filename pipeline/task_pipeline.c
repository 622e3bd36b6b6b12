/* task_pipeline.c — the `matphot pipeline` task: parameters → options, one
 * run per image (an @list gives one run each), the report on stderr. */
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include "pipeline/pipeline_priv.h"

/* psf="" builds the PSF from the frame (psf/build.h); the find kernel and
 * the builder's start are the Gaussian of fwhm until it exists. */
static void psf_build_opts(mp_parset *ps, mp_pipeline_opts *o)
{
    o->ps = ps;
    o->build_psf = mp_par_string(ps, "psf")[0] == '\0';
    double fwhm = 3.0;
    mp_par_real(ps, "fwhm", &fwhm);
    mp_epsf_opts_default(fwhm, 1, 1, &o->psfb);
    const char *vo = mp_par_string(ps, "varorder");
    o->psfb.order = !strcmp(vo, "auto") ? -1 : atoi(vo);
    mp_par_int(ps, "maxnpsf", &o->psfb.maxnpsf);
    /* The table must reach as far as the bright stars' light is above
     * the noise: cut short, a segmented mirror's rings and spikes beyond
     * it are found as stars (issue 13, validate/CROWDED.md's segmented
     * scene: 1130 false entries with ±12 px, 199 with ±16).  INDEF: that
     * radius measured (run_psf.c's mp_run_build_psf, psf/tablerad.c). */
    double tr = NAN;
    mp_par_real(ps, "tablerad", &tr);
    o->tablerad_auto = !isfinite(tr);
    if (isfinite(tr))
        o->psfb.psfrad = tr;
}

int mp_pl_opts_read(mp_parset *ps, mp_pipeline_opts *o, char *err)
{
    memset(o, 0, sizeof *o);
    if (mp_fit_setup_read(ps, &o->fit, err))
        return 1;
    psf_build_opts(ps, o);
    mp_find_opts_default(&o->find);
    o->grp_hold = 8.0 * 1024 * 1024;
    o->find.fwhm = mp_prf_fwhm(&o->fit.model);   /* the PSF's own width */
    mp_par_real(ps, "threshold", &o->find.threshold);
    mp_par_real(ps, "nsigma", &o->find.nsigma);
    mp_par_real(ps, "sharplo", &o->find.sharplo);
    mp_par_real(ps, "sharphi", &o->find.sharphi);
    mp_par_real(ps, "roundlo", &o->find.roundlo);
    mp_par_real(ps, "roundhi", &o->find.roundhi);
    mp_par_int(ps, "mesh", &o->mesh);
    mp_par_int(ps, "filter", &o->filter);
    mp_group_opts_default(&o->group);
    o->group.fitrad = o->fit.opts.fit.fitrad;
    double psfrad;
    mp_par_real(ps, "psfrad", &psfrad);
    o->group.psfrad = isfinite(psfrad) ? psfrad : 2.0 * o->find.fwhm;
    mp_par_int(ps, "maxgroup", &o->group.maxgroup);
    int wg;
    mp_par_int(ps, "weakgroup", &wg);
    wg = wg == MP_PAR_INDEF_INT ? o->group.maxgroup / 2 : wg;
    o->group.weakgroup = wg >= 1 && wg < o->group.maxgroup ? wg : o->group.maxgroup;
    o->groupcut_median = strcmp(mp_par_string(ps, "groupcut"), "median") == 0;
    if (o->groupcut_median)
        o->fit.opts.couplefrac = 0.0;
    if (strcmp(mp_par_string(ps, "groupcut"), "budget") == 0)
        mp_par_real(ps, "couplebudget", &o->couplebudget);
    mp_pl_group_decision(&o->fit, o->couplebudget, o->group.weakgroup);
    mp_par_int(ps, "niter", &o->niter);
    mp_par_real(ps, "matchrad", &o->matchrad);
    mp_par_bool(ps, "regions", &o->regions);
    /* The halo by default where the table is built from the frame: its
     * wings come out low there (each PSF star's sky ring holds its own
     * light) and its growth curve can miss what the halo holds (47 Tuc:
     * 7 % of the light); a table given is the user's (pipeline/halo.c). */
    const char *halo = mp_par_string(ps, "halo");
    o->halo = !halo ? 0
              : !strcmp(halo, "yes")                   ? MP_PL_HALO_ASKED
              : !strcmp(halo, "auto") && o->build_psf ? MP_PL_HALO_AUTO
                                                        : 0;
    mp_par_bool(ps, "lookup", &o->lookup);
    mp_par_bool(ps, "crmask", &o->crmask);
    mp_par_int(ps, "crgrow", &o->crgrow);
    int ts, tm;
    mp_par_int(ps, "tilesize", &ts);
    mp_par_int(ps, "tilemargin", &tm);
    mp_par_real(ps, "maxmem", &o->maxmem);
    o->tilesize = ts == MP_PAR_INDEF_INT ? -1 : ts;
    o->tilemargin = tm == MP_PAR_INDEF_INT ? -1 : tm;
    if (mp_table_format_parse(mp_par_string(ps, "catformat"), &o->catfmt)) {
        snprintf(err, MP_ERRLEN, "catformat: unknown table format '%s'", mp_par_string(ps, "catformat"));
        return 1;
    }
    if (!isfinite(o->fit.opts.fit.fitrad)) {
        snprintf(err, MP_ERRLEN, "fitrad: INDEF (whole image) is for single-star frames; "
                 "the pipeline fits groups within a radius");
        return 1;
    }
    return 0;
}

/* fwhm=INDEF: each image's stars' FWHM measured (mp_pl_frame_fwhm), set
 * as fwhm and the options read again with it (the Gaussian, find's
 * kernel, the build's start and radii); said on stderr. */
static int fwhm_of_image(mp_parset *ps, mp_pipeline_opts *o, const char *image, char *err)
{
    mp_stars_fwhm m;
    char v[32];
    if (mp_pl_frame_fwhm(image, o, &m, err))
        return 1;
    snprintf(v, sizeof v, "%.4g", m.fwhm);
    mp_sweeps *sw = o->sweeps;
    mp_fit_setup_free(&o->fit);
    if (mp_params_set(ps, "fwhm", v, err) || mp_pl_opts_read(ps, o, err)) {
        o->sweeps = sw;
        return 1;
    }
    o->sweeps = sw;
    fprintf(stderr, "matphot pipeline: %s: fwhm %s (INDEF: the stars' FWHM, +- %.2g px on %d "
            "lone stars)\n", image, v, m.err, m.n);
    return 0;
}

int mp_task_pipeline(int argc, char **argv)
{
    mp_parset ps;
    int b = mp_task_begin("pipeline", argc, argv, &ps);
    if (b)
        return b;
    char err[MP_ERRLEN] = "";
    mp_pipeline_opts o;
    char **im = NULL;
    size_t nim = 0;
    mp_inputs *ins = NULL;
    int rc = 1;
    double fw = NAN;
    mp_par_real(&ps, "fwhm", &fw);
    int measure = !isfinite(fw);     /* INDEF: measured on each image */
    if ((measure && mp_params_set(&ps, "fwhm", "3", err)) || mp_pl_opts_read(&ps, &o, err))
        goto done;
    mp_fit_setup_warn(&o.fit, "pipeline");
    if (!(o.sweeps = mp_sweeps_new())) {
        snprintf(err, MP_ERRLEN, "out of memory");
        goto done;
    }
    if (mp_params_list(mp_par_string(&ps, "image"), &im, &nim, err))
        goto done;
    const char *root = mp_par_string(&ps, "root");
    if (root[0] && nim > 1) {
        snprintf(err, MP_ERRLEN, "root: one root for %zu images; leave it empty so each "
                 "output is named after its image", nim);
        goto done;
    }
    /* root.res.fits and root.psf.fits are read back ('-' names a file here) */
    if (strchr(root, '[') && mp_out_fits_named("root", root, err))
        goto done;
    /* every frame of the list: an output of the first may be the input
     * of a later one */
    if (!(ins = mp_inputs_of((const char *const *)im, nim))) {
        snprintf(err, MP_ERRLEN, "out of memory");
        goto done;
    }
    if (mp_fit_setup_inputs(&ps, &o.fit, ins, err))
        goto done;
    /* A frame's bad input (no usable star, a corrupt file) is its own
     * line: the @list's other frames are reduced, the status 1. */
    int failed = 0;
    for (size_t i = 0; i < nim; i++) {
        char *named = root[0] ? NULL : mp_name_after(im[i], "");
        if (!root[0] && !named) {
            snprintf(err, MP_ERRLEN, "out of memory");
            goto done;
        }
        mp_pipeline_report r;
        int prc = mp_pl_outputs_clear(root[0] ? root : named, mp_pl_products,
                                      MP_PL_NPRODUCT - !o.build_psf, ins, err) ||
                  (measure && fwhm_of_image(&ps, &o, im[i], err)) ||
                  mp_pipeline_run_any(im[i], root[0] ? root : named, &o, &r, err);
        free(named);
        if (prc)
            fprintf(stderr, "matphot pipeline: %s\n", err);
        failed |= prc;
    }
    rc = failed;
    err[0] = '\0';             /* each said where it happened */
done:
    if (rc && err[0])
        fprintf(stderr, "matphot pipeline: %s\n", err);
    mp_list_free(im, nim);
    mp_sweeps_free(o.sweeps);
    mp_inputs_free(ins);
    mp_fit_setup_free(&o.fit);
    mp_params_free(&ps);
    return rc;
}
