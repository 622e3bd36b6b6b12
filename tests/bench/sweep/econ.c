/*
 * econ.c — economy=yes against economy=no on one scene (issue 5, point 2):
 * the scene's PSF table (and DRF map) written as files, fit.par's defaults
 * read twice through mp_fit_setup_read — the path `matphot fit` and the
 * pipeline take — once with economy=yes and once with economy=no, and every
 * star fitted with both setups, interleaved (sw_run_block).  Writes
 * WORK/SCENE_econ.md (a table row) and WORK/SCENE_econ_dec.md (the
 * decisions of both setups, as the run report prints them).
 *
 * The verdict: the paired difference of each error ratio (yes − no, on the
 * same stars) against its paired-bootstrap σ; "same" when |Δ| ≤ 2σ for the
 * photometric and astrometric ratios of all stars and of the bright ones
 * (a 2σ test on four correlated quantities: under no true change a false
 * "differs" comes about 10 % of the time at most, so a "differs" alone is a
 * prompt to look, not a proof).
 */
#include <math.h>
#include <stdlib.h>
#include <string.h>
#include <time.h>
#include "params/params.h"
#include "tests/bench/sweep/sw.h"

/* The scene's PSF (and DRF) as FITS files for fit.par's psf and drf. */
static int write_inputs(const sw_scene *sc, const char *work, char *psf, char *drf, size_t n,
                        char *err)
{
    const mp_psf *p = &sc->tab[0];
    mp_card pc[] = {{"OVERSAMP", p->os, NULL, "table elements per detector pixel"}};
    snprintf(psf, n, "%s/%s_econ_psf.fits", work, sc->name);
    if (mp_image_write(psf, p->t, p->nx, p->ny, -64, pc, 1, err))
        return 1;
    drf[0] = '\0';
    if (sc->drf.k > 0) {
        snprintf(drf, n, "%s/%s_econ_drf.fits", work, sc->name);
        if (mp_image_write(drf, sc->drf.qe, sc->drf.k, sc->drf.k, -64, NULL, 0, err))
            return 1;
    }
    return 0;
}

/* fit.par's defaults with the scene's files and economy=yes|no. */
static int setup_of(const char *psf, const char *drf, const char *economy, int whole,
                    const char *psfos, mp_fit_setup *s, char *err)
{
    mp_parset ps;
    if (mp_params_defaults("fit", &ps, err))
        return 1;
    int rc = mp_params_set(&ps, "psf", psf, err) || mp_params_set(&ps, "psfnorm", "no", err) ||
             (drf[0] && mp_params_set(&ps, "drf", drf, err)) ||
             mp_params_set(&ps, "rdnoise", "3", err) || mp_params_set(&ps, "gain", "1", err) ||
             mp_params_set(&ps, "economy", economy, err) ||
             (whole && mp_params_set(&ps, "fitrad", "INDEF", err)) ||
             (psfos && mp_params_set(&ps, "psfos", psfos, err)) || mp_fit_setup_read(&ps, s, err);
    mp_params_free(&ps);
    return rc;
}

static int group_maxgroup(int *mg, char *err)
{
    mp_parset ps;
    if (mp_params_defaults("group", &ps, err))
        return 1;
    int rc = mp_par_int(&ps, "maxgroup", mg);
    mp_params_free(&ps);
    if (rc)
        snprintf(err, MP_ERRLEN, "group.par lacks maxgroup");
    return rc;
}

static void setting_of(const mp_fit_setup *s, const char *value, int maxgroup, sw_setting *st)
{
    memset(st, 0, sizeof *st);
    snprintf(st->knob, sizeof st->knob, "economy");
    snprintf(st->value, sizeof st->value, "%s", value);
    st->model = &s->model;
    st->fopts = &s->opts;
    st->hw = s->model.sinc_hw;
    st->fitrad = s->opts.fit.fitrad;
    st->tol = s->opts.fit.tol;
    st->maxiter = s->opts.fit.maxiter;
    st->maxgroup = maxgroup;
}

/* |Δ| within 2σ.  Differences below 5e-4 (the tables' last digit, a tenth
 * of the sampling σ of a ratio even at N = 50000) count as none, so that a
 * change confined to a few stars, whose bootstrap σ can be 0, is no
 * "differs". */
static int within(double d, double u)
{
    return fabs(d) < 5e-4 || (isfinite(d) && isfinite(u) && fabs(d) <= 2.0 * u);
}

/* How many stars carry each flag bit, and how many were lost (merged away
 * or rejected), as "edge 3, merged 12, lost 40" ("none" when none). */
static void flag_counts(const sw_result *r, int n, char *buf, size_t nb)
{
    static const char *const names[] = {"saturated", "split", "edge", "not converged",
                                        "merged", "masked"};
    long c[6] = {0}, lost = 0;
    for (int k = 0; k < n; k++) {
        if (!isfinite(r->f[k])) {
            lost++;
            continue;
        }
        for (int b = 0; b < 6; b++)
            c[b] += (r->flags[k] >> b) & 1;
    }
    buf[0] = '\0';
    for (int b = 0; b <= 6; b++) {
        long v = b < 6 ? c[b] : lost;
        size_t l = strlen(buf);
        if (v)
            snprintf(buf + l, nb - l, "%s%s %ld", l ? ", " : "", b < 6 ? names[b] : "lost", v);
    }
    if (!buf[0])
        snprintf(buf, nb, "none");
}

static int write_row(const char *work, const sw_scene *sc, const sw_result *no,
                     const sw_result *yes, const mp_fit_setup *sy, const mp_fit_setup *sn,
                     int reps, char *err)
{
    const sw_sub *a = &yes->sub[0], *b = &yes->sub[2], *a0 = &no->sub[0];
    int same = within(a->dph, a->udph) && within(a->das, a->udas) &&
               (b->n == 0 || (within(b->dph, b->udph) && within(b->das, b->udas)));
    int ident = a->dph == 0.0 && a->das == 0.0 && b->dph == 0.0 && b->das == 0.0;
    double saved = no->cpu_star > 0 ? 1.0 - yes->cpu_star / no->cpu_star : NAN;
    char path[1024];
    snprintf(path, sizeof path, "%s/%s_econ.md", work, sc->name);
    FILE *fp = fopen(path, "w");
    if (!fp) {
        snprintf(err, MP_ERRLEN, "%.400s: cannot write", path);
        return 1;
    }
    fprintf(fp, "| %s | %d | %.3f / %.3f | %+.0f %% (±%.0f %%) | %.3f / %.3f ± %.3f | %+.4f ± %.4f "
            "| %.3f / %.3f ± %.3f | %+.4f ± %.4f | %+.4f ± %.4f / %+.4f ± %.4f | %.3f / %.3f | %s |\n",
            sc->name, sc->n, 1e3 * no->cpu_star, 1e3 * yes->cpu_star, 100.0 * saved,
            100.0 * (no->cpu_spread > yes->cpu_spread ? no->cpu_spread : yes->cpu_spread),
            a0->ph, a->ph, a0->uph, a->dph, a->udph, a0->as, a->as, a0->uas, a->das, a->udas,
            b->dph, b->udph, b->das, b->udas, no->fflag + no->flost, yes->fflag + yes->flost,
            ident ? "identical fits" : same ? "same within 2σ" : "**differs** (> 2σ)");
    if (ferror(fp) | fclose(fp)) {
        snprintf(err, MP_ERRLEN, "%.400s: write error", path);
        return 1;
    }
    snprintf(path, sizeof path, "%s/%s_econ_dec.md", work, sc->name);
    fp = fopen(path, "w");
    if (!fp) {
        snprintf(err, MP_ERRLEN, "%.400s: cannot write", path);
        return 1;
    }
    char fl[2][160];
    flag_counts(no, sc->n, fl[0], sizeof fl[0]);
    flag_counts(yes, sc->n, fl[1], sizeof fl[1]);
    fprintf(fp, "- **%s** (%s; %d stars, CPU the median of %d interleaved repeats): "
            "economy=yes — %d decisions: %s; economy=no — %d decisions%s%s.  Stars by flag, "
            "no / yes: %s / %s.  Stars fitted with a coarser table by economy=yes: %ld of %d\n",
            sc->name, sc->title, sc->n, reps, sy->ndecisions, sy->ndecisions ? sy->decisions : "-",
            sn->ndecisions, sn->ndecisions ? ": " : "", sn->ndecisions ? sn->decisions : "",
            fl[0], fl[1], yes->coarse, sc->n);
    if (ferror(fp) | fclose(fp)) {
        snprintf(err, MP_ERRLEN, "%.400s: write error", path);
        return 1;
    }
    return 0;
}

/* The beta >= 21 rule's x1 table against economy=yes on the same stars
 * (d: old − yes, paired): WORK/SCENE_old.md. */
static int write_old(const char *work, const sw_scene *sc, const sw_result *no,
                     const sw_result *yes, const sw_result *old, const sw_sub *d, char *err)
{
    const sw_sub *a = &old->sub[0];
    int same = within(d[0].dph, d[0].udph) && within(d[0].das, d[0].udas) &&
               (d[2].n == 0 || (within(d[2].dph, d[2].udph) && within(d[2].das, d[2].udas)));
    char path[1024];
    snprintf(path, sizeof path, "%s/%s_old.md", work, sc->name);
    FILE *fp = fopen(path, "w");
    if (!fp) {
        snprintf(err, MP_ERRLEN, "%.400s: cannot write", path);
        return 1;
    }
    fprintf(fp, "| %s | %d | %.1f | %.3f / %.3f / %.3f | %.3f ± %.3f | %+.4f ± %.4f | %.3f ± %.3f | "
            "%+.4f ± %.4f | %+.4f ± %.4f / %+.4f ± %.4f | %s |\n", sc->name, sc->n, sc->beta_norm,
            1e3 * no->cpu_star, 1e3 * yes->cpu_star, 1e3 * old->cpu_star, a->ph, a->uph, d[0].dph,
            d[0].udph, a->as, a->uas, d[0].das, d[0].udas, d[2].dph, d[2].udph, d[2].das, d[2].udas,
            same ? "same within 2σ" : "**differs** (> 2σ)");
    if (ferror(fp) | fclose(fp)) {
        snprintf(err, MP_ERRLEN, "%.400s: write error", path);
        return 1;
    }
    return 0;
}

#define SW_KFRAC 0.1   /* per-star kernel: bias bound, in units of the photon noise */

/* The per-star kernel against economy=yes's fixed sinchw: WORK/SCENE_kern.md. */
static int write_kern(const char *work, const sw_scene *sc, const sw_result *yes,
                      const sw_result *ps, const sw_sub *d, double tbuild, char *err)
{
    int same = 1;
    for (int k = 0; k < 3; k++)
        same &= within(d[k].dph, d[k].udph) && within(d[k].das, d[k].udas);
    char path[1024];
    snprintf(path, sizeof path, "%s/%s_kern.md", work, sc->name);
    FILE *fp = fopen(path, "w");
    if (!fp) {
        snprintf(err, MP_ERRLEN, "%.400s: cannot write", path);
        return 1;
    }
    fprintf(fp, "| %s | %d | %d → %.2f | %.3f / %.3f | %+.0f %% (±%.0f %%) | %.1f | ",
            sc->name, sc->n, yes->s.hw, (double)ps->hwsum / sc->n, 1e3 * yes->cpu_star,
            1e3 * ps->cpu_star, 100.0 * (1.0 - ps->cpu_star / yes->cpu_star),
            100.0 * fmax(yes->cpu_spread, ps->cpu_spread), 1e3 * tbuild);
    for (int k = 0; k < 3; k++)
        fprintf(fp, "%+.4f ± %.4f / %+.4f ± %.4f | ", d[k].dph, d[k].udph, d[k].das, d[k].udas);
    fprintf(fp, "%s |\n", same ? "same within 2σ" : "**differs** (> 2σ)");
    if (ferror(fp) | fclose(fp)) {
        snprintf(err, MP_ERRLEN, "%.400s: write error", path);
        return 1;
    }
    return 0;
}

static double cpu_now(void)
{
    struct timespec ts;
    clock_gettime(CLOCK_PROCESS_CPUTIME_ID, &ts);
    return (double)ts.tv_sec + 1e-9 * (double)ts.tv_nsec;
}

int sw_econ(const sw_scene *sc, const char *work, int reps, int verbose, char *err)
{
    char psf[1024], drf[1024];
    int maxgroup = 0;
    if (write_inputs(sc, work, psf, drf, sizeof psf, err) || group_maxgroup(&maxgroup, err))
        return 1;
    mp_fit_setup s[3];
    memset(s, 0, sizeof s);
    sw_result res[3];
    memset(res, 0, sizeof res);
    mp_sinc_choice ch;
    memset(&ch, 0, sizeof ch);
    int rc = 1, nset = 2;
    double tbuild = 0.0;
    if (setup_of(psf, drf, "no", sc->whole, NULL, &s[0], err) ||
        setup_of(psf, drf, "yes", sc->whole, NULL, &s[1], err))
        goto done;
    /* The scene's stars are one run (as `matphot fit` plans an @list's):
     * economy builds the tables that pay for them (fit/econ_plan.c). */
    for (int k = 0; k < 2; k++)
        s[k].opts.fits = sc->n;
    setting_of(&s[0], "no", maxgroup, &res[0].s);
    setting_of(&s[1], "yes", maxgroup, &res[1].s);
    res[0].s.is_default = 1;
    /* The per-star kernel is economy=yes's own since fit_frame.c chooses it
     * per group (issue 10): the separate setting is kept for the sweep's
     * old runs only (SW_KERN=1). */
    if (sc->kind == SW_SINGLE && s[1].psf.kind == MP_PSF_TABLE && getenv("SW_KERN")) {
        /* economy=yes plus the per-star kernel length (fit/sinc_choice.c). */
        double t0 = cpu_now();
        if (mp_sinc_choice_build(&s[1].model, &ch, err))
            goto done;
        mp_sinc_choice_limits(&ch, SW_SKY, SW_RON, SW_KFRAC, res[2].s.emax);
        tbuild = cpu_now() - t0;
        double emax[65];
        memcpy(emax, res[2].s.emax, sizeof emax);
        setting_of(&s[1], "yes+kernel", maxgroup, &res[2].s);
        memcpy(res[2].s.emax, emax, sizeof emax);
        res[2].s.choice = &ch;
        res[2].s.frac = SW_KFRAC;
        nset = 3;
    }
    /* Where paper 5.4's beta >= 21 rule (the economy before issue 10)
     * block-summed the table for every star, that too: psfos=x1. */
    int iold = -1;
    if (nset == 2 && sc->def_tab != 0) {
        char os[8];
        snprintf(os, sizeof os, "%d", sc->tab[sc->def_tab].os);
        if (setup_of(psf, drf, "yes", sc->whole, os, &s[2], err))
            goto done;
        s[2].opts.fits = sc->n;
        setting_of(&s[2], "beta rule", maxgroup, &res[2].s);
        iold = nset++;
    }
    if (sw_run_block(sc, res, 0, nset, reps, verbose, err))
        goto done;
    if (sw_stats(sc, res, nset, 0, sc->seed + 55)) {
        snprintf(err, MP_ERRLEN, "out of memory for the statistics");
        goto done;
    }
    if (nset == 3 && iold < 0) {
        /* The per-star kernel's differences from economy=yes, same stars. */
        sw_sub keep[3], d[3];
        memcpy(keep, res[1].sub, sizeof keep);
        if (sw_stats(sc, res + 1, 2, 0, sc->seed + 56)) {
            snprintf(err, MP_ERRLEN, "out of memory for the statistics");
            goto done;
        }
        memcpy(d, res[2].sub, sizeof d);
        memcpy(res[1].sub, keep, sizeof keep);
        if (write_kern(work, sc, &res[1], &res[2], d, tbuild, err))
            goto done;
    }
    if (write_row(work, sc, &res[0], &res[1], &s[1], &s[0], reps, err))
        goto done;
    if (iold == 2) {
        /* The rule's differences from economy=yes, same stars. */
        sw_sub keep[2][3], d[3];
        memcpy(keep[0], res[1].sub, sizeof keep[0]);
        memcpy(keep[1], res[2].sub, sizeof keep[1]);
        if (sw_stats(sc, res + 1, 2, 0, sc->seed + 57)) {
            snprintf(err, MP_ERRLEN, "out of memory for the statistics");
            goto done;
        }
        memcpy(d, res[2].sub, sizeof d);
        memcpy(res[1].sub, keep[0], sizeof keep[0]);
        memcpy(res[2].sub, keep[1], sizeof keep[1]);
        if (write_old(work, sc, &res[0], &res[1], &res[2], d, err))
            goto done;
    }
    rc = 0;
done:
    for (int i = 0; i < 3; i++)
        sw_result_free(&res[i]);
    mp_sinc_choice_free(&ch);
    for (int i = 0; i < 3; i++)
        mp_fit_setup_free(&s[i]);
    return rc;
}
