/* setup.c — the fit's parameters (fit.par, shared by the pipeline) turned
 * into a PSF, a DRF, a model and options, once for every image. */
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include "fit/fit.h"

const mp_fit_setup *mp_fit_setup_local(const mp_fit_setup *s, double dx, double dy,
                                       mp_fit_setup *out)
{
    if (!s->psf.field)
        return s;
    *out = *s;
    mp_psf_local(&s->psf, dx, dy, &out->psf, &out->field);
    out->model.psf = &out->psf;
    /* The run's coarser levels (built later, shared) are read there too. */
    out->opts.psfdx = s->opts.psfdx + dx;
    out->opts.psfdy = s->opts.psfdy + dy;
    return out;
}

void mp_fit_setup_free(mp_fit_setup *s)
{
    mp_psf_free(&s->psf);
    mp_psf_field_free(&s->field);
    mp_drf_free(&s->drf);
    mp_econ_cache_free(s->cache);
}

/* A warning line added to s->warn (dropped when full). */
static void add_warning(mp_fit_setup *s, const char *w)
{
    size_t l = strlen(s->warn);
    if (l + strlen(w) + 2 <= sizeof s->warn)
        snprintf(s->warn + l, sizeof s->warn - l, "%s%s", l ? "\n" : "", w);
}

/* Paper §5.4: a discrete PSF needs β ≥ 21 in its own (super)pixels, or
 * bright stars alias.  β·V² = 1/sharpness keeps the test independent of
 * the detector's efficiency. */
static void warn_undersampled(mp_fit_setup *s)
{
    mp_prf_stats st;
    if (s->psf.kind != MP_PSF_TABLE || mp_prf_stats_at(&s->model, 1000.0, 1000.0, &st, NULL))
        return;
    double b = st.sharp > 0 ? 1.0 / st.sharp : 0.0, bs = b * s->psf.os * s->psf.os;
    char w[MP_ERRLEN];
    snprintf(w, sizeof w, "PSF undersampled: beta = %.1f px^2 < 21, and its OVERSAMP %d gives "
             "%.1f < 21 table px^2; bright stars will alias (use a table supersampled %dx or "
             "more)", b, s->psf.os, bs, (int)ceil(sqrt(21.0 / b)));
    if (b < 21.0 && bs < 21.0)
        add_warning(s, w);
}

void mp_fit_setup_warn(const mp_fit_setup *s, const char *task)
{
    for (const char *p = s->warn; *p;) {
        size_t n = strcspn(p, "\n");
        fprintf(stderr, "matphot %s: warning: %.*s\n", task, (int)n, p);
        p += n + (p[n] == '\n');
    }
}

/* Block-sum the table and the field alike by factor (the block-sum is
 * linear, so the rebinned field evaluated anywhere is the rebinned table
 * of the field there). */
static int rebin_both(mp_fit_setup *s, int factor, char *err)
{
    mp_psf coarse;
    mp_psf_field fc;
    if (mp_psf_rebin(&s->psf, factor, &coarse, err))
        return 1;
    if (mp_psf_field_rebin(&s->field, factor, &fc, err)) {
        mp_psf_free(&coarse);
        return 1;
    }
    mp_psf_free(&s->psf);
    mp_psf_field_free(&s->field);
    s->psf = coarse;
    s->field = fc;
    return 0;
}

/* Note one economy decision and its reason for the run report. */
static void decide(mp_fit_setup *s, const char *what)
{
    size_t k = strlen(s->decisions);
    snprintf(s->decisions + k, sizeof s->decisions - k, "%s%s", k ? "; " : "", what);
    s->ndecisions++;
}

/* 1/sharpness of the PRF at a pixel centre: β·V², the paper's β for V = 1. */
static double beta_normalised(const mp_prf_model *m)
{
    mp_prf_stats st;
    if (mp_prf_stats_at(m, 1000.0, 1000.0, &st, NULL) || !(st.sharp > 0))
        return 0.0;
    return 1.0 / st.sharp;
}

/* The coarser samplings of a supersampled table (every divisor k of its
 * OVERSAMP, coarsest first), offered to the frame fit, which uses, per
 * group, the coarsest whose linearised bias at the group's brightest star
 * is ≤ ssfrac of each parameter's σ and whose χ² shift is ≤ 1
 * (fit/ss_choice.c).  Each one's bias table is measured on this PSF only
 * once the run's star fits pay for it (fit/econ_plan.c); the run report
 * names the levels built and their flux limits. */
static void supersampling_levels(mp_fit_setup *s)
{
    char why[512];
    int os = s->psf.os, n = 0, k = snprintf(why, sizeof why, "supersampling: per group, the "
                                            "coarsest table whose linearised bias stays below "
                                            "%.2g of its brightest star's sigma and shifts "
                                            "chi2 by <= 1 (fit/ss_choice.c), offered at",
                                            s->opts.ssfrac);
    for (int c = 1; c < os && n < MP_SS_MAXLEVELS; c++) {
        if (os % c)
            continue;
        s->econ_os[n++] = c;
        if (k < (int)sizeof why)
            k += snprintf(why + k, sizeof why - (size_t)k, " x%d,", c);
    }
    if (k < (int)sizeof why)
        snprintf(why + k, sizeof why - (size_t)k, " the x%d table above (beta = %.1f px^2 at "
                 "detector sampling)", os, beta_normalised(&s->model));
    s->econ_nlev = n;
    decide(s, why);
}

/* The PRF from a grid of subpixel phases (fit/prf_cache.c) for the model as
 * given (its finest table, the costliest to render; a coarser sampling's
 * renders are os² times cheaper and keep the exact render); a variable PSF
 * gets a grid per term of its field. */
static void phase_grids(mp_fit_setup *s, const mp_parset *ps)
{
    int grid = MP_PRF_CACHE_G;
    mp_par_int(ps, "phasegrid", &grid);
    if (grid <= 0 || s->psf.kind != MP_PSF_TABLE)
        return;
    s->econ_grid = grid;
    char why[640], terms[160] = "";
    if (s->field.order > 0)
        snprintf(terms, sizeof terms, "; for the variable PSF a grid per term (%d), a star's PRF "
                 "their sum at its place, bounded for every place within the field's scales",
                 s->field.nterms);
    snprintf(why, sizeof why, "PRF from a grid of %d subpixel phases per pixel (cubic, five-point "
             "derivatives interpolated) for groups whose brightest star's bias bound stays below "
             "%.2g sigma, exact renders for brighter ones, and bilinear (a quarter of the reads) for "
             "a star whose own bound with it stays below %.2g sigma (fit/prf_cache.c)%s", grid,
             s->opts.sincfrac, s->opts.sincfrac, terms);
    decide(s, why);
    snprintf(why, sizeof why, "position derivatives: drawn from the grid within fitrad + 2 px of "
             "a star whose pixels beyond hold at most %.2g of its information on x and y (its "
             "sigma grows <= %.2g %%), on its whole window for brighter ones "
             "(fit/prf_deriv_box.c)", MP_DBOX_SHARE, 100.0 * (1.0 / sqrt(1.0 - MP_DBOX_SHARE) - 1.0));
    decide(s, why);
}

/* economy=yes: leave out what cannot change the answer (issue 5); every
 * decision, to drop a part or to keep it, is logged with its reason.
 *  - A DRF map whose subpixels are all equal is the scalar V.
 *  - A supersampled table is offered per group at every coarser sampling
 *    whose error, measured on this PSF, is provably small for the group's
 *    brightest star (supersampling_levels), when no DRF map needs the
 *    subpixels, unless the user asked for a sampling with psfos. */
static void economize(mp_fit_setup *s, int psfos_given)
{
    char why[256];
    if (s->drf.k > 0) {
        int uniform = 1;
        double lo = s->drf.qe[0], hi = s->drf.qe[0];
        for (int i = 1; i < s->drf.k * s->drf.k; i++) {
            uniform &= s->drf.qe[i] == s->drf.qe[0];
            lo = s->drf.qe[i] < lo ? s->drf.qe[i] : lo;
            hi = s->drf.qe[i] > hi ? s->drf.qe[i] : hi;
        }
        if (uniform) {
            double v = s->drf.qe[0];
            snprintf(why, sizeof why, "DRF: the %dx%d map is uniform, used as the scalar V = %.6g",
                     s->drf.k, s->drf.k, v);
            mp_drf_free(&s->drf);
            mp_drf_uniform(v, &s->drf);
        } else {
            snprintf(why, sizeof why, "DRF: the %dx%d map varies (QE %.3g to %.3g), kept",
                     s->drf.k, s->drf.k, lo, hi);
        }
        decide(s, why);
    }
    if (s->psf.kind != MP_PSF_TABLE || s->psf.os <= 1)
        return;
    int os = s->psf.os;
    if (psfos_given) {
        snprintf(why, sizeof why, "supersampling: psfos given, the x%d table used as asked", os);
        decide(s, why);
        return;
    }
    if (s->drf.k > 0) {
        snprintf(why, sizeof why, "supersampling: the %dx%d DRF map needs the x%d subpixels, kept",
                 s->drf.k, s->drf.k, os);
        decide(s, why);
        return;
    }
    supersampling_levels(s);
}

/* skymodel: an explicit order is honoured; auto chooses per group from the
 * data (a score test, sky_test.c) under economy=yes and economy=no alike.
 * The order is a choice of the model from the data, not an economy: a
 * quadratic sky where the data hold none is no more exact, it only adds
 * five parameters that correlate with the star (within a 5 px fitting
 * radius they raised the flux error 1.45x over the constant-sky bound,
 * bench/REPORT.md, issue 10). */
static int sky_order_of(const char *v)
{
    if (!strcmp(v, "constant"))
        return 0;
    if (!strcmp(v, "plane"))
        return 1;
    if (!strcmp(v, "quadratic"))
        return 2;
    return MP_SKY_AUTO;
}

/* The PSF file (psf/psf.h's layout, any order): the field, and the table
 * at its origin, which is what the PSF-wide measurements below (β, the
 * coarsest sampling, the sinc kernel's error) are taken on; the fit then
 * evaluates the field at every star (psf.field, set last). */
static int read_psf(mp_fit_setup *s, const char *name, int norm, int os, const char *kspec,
                    char *warn, char *err)
{
    if (mp_psf_field_read(name, norm, os, &s->field, NULL, NULL, warn, err))
        return 1;
    /* Folded into the supersampled table: exact (psf/kernel.c). */
    mp_psf k;
    if (mp_psf_kernel_read(kspec, name, &k, err))
        return 1;
    if (k.t) {
        int rc = mp_psf_field_fold_kernel(&s->field, &k, err);
        mp_kernel_spec ks = mp_psf_kernel_spec(kspec);
        char why[320];
        snprintf(why, sizeof why, "detector kernel: %dx%d (sum %.6g) from %s folded into the x%d "
                 "table (exact: it commutes with the shift, the DRF and the block-sum)%s", k.nx,
                 k.ny, k.sum, ks == MP_KERNEL_FILE ? kspec : "the PSF file's header",
                 s->field.os, ks != MP_KERNEL_AUTO ? "" : "; psfkernel=auto: Tiny Tim's "
                 "subsampled table says its charge diffusion was not applied (none leaves it out)");
        mp_psf_free(&k);
        if (rc)
            return 1;
        decide(s, why);
    }
    if (mp_psf_field_eval(&s->field, s->field.x0, s->field.y0, &s->psf, err))
        return 1;
    s->psf.sum = s->field.sum;
    return 0;
}

/* The PSF: a table (psf=, with its detector kernel and an optional
 * block-sum to psfos) or the analytic Gaussian (psf= empty or gauss: the
 * pipeline builds a PSF from the frame when psf is empty). */
static int setup_psf(const mp_parset *ps, mp_fit_setup *s, char *err)
{
    const char *psf = mp_par_string(ps, "psf");
    const char *kspec = mp_par_string(ps, "psfkernel");
    if (!psf[0] || strcmp(psf, "gauss") == 0) {
        if (mp_psf_kernel_spec(kspec) >= MP_KERNEL_HEADER) {
            snprintf(err, MP_ERRLEN, "psfkernel: %s: a detector kernel needs a PSF table (psf=)",
                     kspec);
            return 1;
        }
        double fwhm;
        if (mp_par_need_real(ps, "fwhm", &fwhm, err))
            return 1;       /* NaN: a Gaussian of no width ("out of memory") */
        mp_psf_gauss(fwhm, &s->psf);
        return 0;
    }
    int norm = 0, hos = MP_PAR_INDEF_INT, os = MP_PAR_INDEF_INT;
    mp_par_bool(ps, "psfnorm", &norm);
    mp_par_int(ps, "oversamp", &hos);
    char warn[MP_ERRLEN];
    if (read_psf(s, psf, norm, hos == MP_PAR_INDEF_INT ? 0 : hos, kspec ? kspec : "", warn, err))
        return 1;
    if (warn[0])
        add_warning(s, warn);
    mp_par_int(ps, "psfos", &os);
    if (os == MP_PAR_INDEF_INT || os == s->psf.os)
        return 0;
    if (s->psf.os % os) {
        snprintf(err, MP_ERRLEN, "psfos: %d does not divide the table's OVERSAMP %d", os,
                 s->psf.os);
        return 1;
    }
    return rebin_both(s, s->psf.os / os, err);
}

/* The detector response: drf= a table, else a uniform pixel of `volume`. */
static int setup_drf(const mp_parset *ps, mp_fit_setup *s, char *err)
{
    const char *drf = mp_par_string(ps, "drf");
    double vol = 1.0;
    mp_par_real(ps, "volume", &vol);
    if (drf[0])
        return mp_drf_read(drf, s->psf.os, &s->drf, err);
    mp_drf_uniform(vol, &s->drf);
    return 0;
}

/* The fit's own parameters, the model's sinc half-width and the data
 * parameters. */
static int read_fit_options(const mp_parset *ps, mp_fit_setup *s, char *err)
{
    mp_frame_opts_default(&s->opts);
    s->opts.learn = 1;          /* the pipeline's rounds and passes, in turn (fit: 0) */
    mp_par_real(ps, "fitrad", &s->opts.fit.fitrad);   /* INDEF (NaN): whole image */
    mp_par_real(ps, "tol", &s->opts.fit.tol);
    mp_par_int(ps, "maxiter", &s->opts.fit.maxiter);
    mp_par_real(ps, "mergerad", &s->opts.mergerad);
    mp_par_real(ps, "minsnr", &s->opts.minsnr);
    mp_par_int(ps, "passes", &s->opts.passes);
    int hw = 10;
    mp_par_int(ps, "sinchw", &hw);
    s->model.psf = &s->psf;
    s->model.drf = &s->drf;
    s->model.sinc_hw = hw;
    mp_par_real(ps, "magzero", &s->opts.magzero);
    mp_datapars_read(ps, &s->dp);
    if (mp_table_format_parse(mp_par_string(ps, "format"), &s->fmt)) {
        snprintf(err, MP_ERRLEN, "format: unknown table format '%s'", mp_par_string(ps, "format"));
        return 1;
    }
    /* Under auto, the per-group choices are counted in the run report
     * (mp_report_parts) as one more decision. */
    s->opts.fit.sky_order = sky_order_of(mp_par_string(ps, "skymodel"));
    return 0;
}

/* economy=yes: the model parts measured against their bounds, each
 * decision stated for the run report. */
static void economy_decisions(const mp_parset *ps, mp_fit_setup *s)
{
    char why[320];
    int hw = s->model.sinc_hw;
    int psfos = MP_PAR_INDEF_INT;
    mp_par_int(ps, "psfos", &psfos);
    economize(s, psfos != MP_PAR_INDEF_INT);
    /* The kernel choice is measured on the model as it now stands (after
     * any block-summing above). */
    s->econ_sinc = s->psf.kind == MP_PSF_TABLE && hw > 0;
    if (s->econ_sinc) {
        snprintf(why, sizeof why, "sinc kernel: per group, the shortest half-width <= %d "
                 "whose bias stays below %.2g of its brightest star's sigma "
                 "(fit/sinc_choice.c)", hw, s->opts.sincfrac);
        decide(s, why);
    }
    phase_grids(s, ps);
    snprintf(why, sizeof why, "tables: each of these measured on the PSF only when the "
             "run's star fits can pay for it (fit/econ_plan.c)");
    decide(s, why);
    snprintf(why, sizeof why, "neighbour light: painted out to where it falls below %.2g of a "
             "sky pixel's sigma (residual too)", s->opts.cropfrac);
    decide(s, why);
    snprintf(why, sizeof why, "refits: a group is refitted only when its members or its "
             "neighbours' light changed (sqrt(sum (dlight/sigma)^2) >= %.2g, which bounds "
             "every parameter's change to that many sigma)", s->opts.refittol);
    decide(s, why);
}

static void variable_psf_decision(mp_fit_setup *s)
{
    if (s->field.order <= 0)
        return;
    s->psf.field = &s->field;
    char why[256];
    snprintf(why, sizeof why, "variable PSF: order %d, each star's table evaluated at its "
             "own position; sampling and sinc kernel from the table at the origin (%.1f, %.1f)",
             s->field.order, s->field.x0, s->field.y0);
    decide(s, why);
}

int mp_fit_setup_inputs(const mp_parset *ps, const mp_fit_setup *s, mp_inputs *in, char *err)
{
    const char *name[4] = {mp_par_string(ps, "psf"), mp_par_string(ps, "drf"), s->dp.dqmask,
                           s->dp.errplane};
    for (int k = 0; k < 4; k++)
        if (mp_inputs_add(in, name[k])) {
            snprintf(err, MP_ERRLEN, "out of memory");
            return 1;
        }
    return 0;
}

int mp_fit_setup_read(const mp_parset *ps, mp_fit_setup *s, char *err)
{
    memset(s, 0, sizeof *s);
    if (setup_psf(ps, s, err) || setup_drf(ps, s, err) || read_fit_options(ps, s, err))
        return 1;
    int economy = 1;
    mp_par_bool(ps, "economy", &economy);
    if (economy) {
        economy_decisions(ps, s);
    } else {
        decide(s, "economy=no: every part of the model forced on");
        s->opts.cropfrac = 0.0;     /* economy=no: the full work, to compare */
        s->opts.refittol = 0.0;
        s->opts.couplefrac = 0.0;
    }
    warn_undersampled(s);
    variable_psf_decision(s);
    /* Economy's tables: offered now, built by the frame fit when they pay. */
    if (economy && s->psf.kind == MP_PSF_TABLE) {
        if (!(s->opts.cache = s->cache = mp_econ_cache_new())) {
            snprintf(err, MP_ERRLEN, "out of memory");
            return 1;
        }
        mp_econ_offer(s->cache, &s->model, s->econ_nlev, s->econ_os, s->econ_sinc, s->econ_grid);
    }
    return 0;
}
