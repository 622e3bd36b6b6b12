/* report.c — the short run report every fit and pipeline run ends with
 * (stderr and root.report): seconds per stage, what was fitted, the achieved
 * error against the predicted one, and which parts of the model were used. */
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include "fit/fit.h"

static int cmp_d(const void *a, const void *b)
{
    double x = *(const double *)a, y = *(const double *)b;
    return (x > y) - (x < y);
}

/* Median of f(row) over rows where it is finite; NaN when none. */
static double median_of(const mp_table *t, int a, int b, int ratio)
{
    if (a < 0 || (ratio && b < 0))
        return NAN;
    double *v = malloc((t->nrow ? t->nrow : 1) * sizeof *v);
    if (!v)
        return NAN;
    size_t n = 0;
    for (size_t r = 0; r < t->nrow; r++) {
        double x = mp_table_get(t, r, a);
        if (ratio) {
            double y = mp_table_get(t, r, b);
            x = y > 0 ? x / y : NAN;
        }
        if (isfinite(x))
            v[n++] = x;
    }
    double m = NAN;
    if (n) {
        qsort(v, n, sizeof *v, cmp_d);
        m = n % 2 ? v[n / 2] : 0.5 * (v[n / 2 - 1] + v[n / 2]);
    }
    free(v);
    return m;
}

void mp_report_counts(const mp_frame_report *fr, mp_run_report *r)
{
    r->ngroups = fr->ngroups;
    r->iterations = fr->iterations;
    r->merged = fr->merged;
    r->rejected = fr->rejected;
    r->noconv = fr->noconv;
    r->fits = fr->fits;
    r->kept = fr->kept;
    r->cropped = fr->cropped;
    r->kcalls = fr->kcalls;
    memcpy(r->refits, fr->refits, sizeof r->refits);
    memcpy(r->refit_steps, fr->refit_steps, sizeof r->refit_steps);
    r->kshort = fr->kshort;
    r->kcache = fr->kcache;
    r->klin = fr->klin;
    r->kcore = fr->kcore;
    r->kstars = fr->kstars;
    r->khw = fr->khw;
    r->kbounds = fr->kbounds;
    r->kcoarse = fr->kcoarse;
    r->envelopes = fr->envelopes;
    r->ops_tables = fr->ops_tables;
    r->ops_saved = fr->ops_saved;
    r->ops_render = fr->ops_render;
}

void mp_report_from_table(const mp_table *t, mp_run_report *r)
{
    r->chi2_median = median_of(t, mp_table_col(t, "CHI2_PSF"), -1, 0);
    r->errratio_median = median_of(t, mp_table_col(t, "FLUXERR_PSF"),
                                   mp_table_col(t, "FLUXERR_MODEL"), 1);
    r->poserr_median = median_of(t, mp_table_col(t, "ERRX_PSF"),
                                 mp_table_col(t, "POSERR_MODEL"), 1);
}

void mp_report_parts(const mp_prf_model *m, const mp_frame_opts *o, const mp_frame_report *fr,
                     mp_run_report *r)
{
    const mp_psf *p = m->psf;
    char *u = r->used, *l = r->left;
    size_t nu = sizeof r->used, nl = sizeof r->left;
    int ku = 0, kl = 0;
#define ADD(buf, k, n, ...) (k += snprintf(buf + k, (size_t)k < n ? n - (size_t)k : 0, __VA_ARGS__))
    static const char *const order[] = {"constant", "plane", "quadratic"};
    u[0] = l[0] = r->sky[0] = '\0';
    long ng[MP_SKY_MAXORDER + 1] = {0};
    if (fr)
        memcpy(ng, fr->sky_groups, sizeof ng);
    int top = 0;                 /* highest sky order fitted */
    if (!o->fit.fit_sky) {
        ADD(l, kl, nl, "sky (held fixed); ");
        top = -1;
    } else if (o->fit.sky_order == MP_SKY_AUTO) {
        for (int k = 0; k <= MP_SKY_MAXORDER; k++)
            top = ng[k] ? k : top;
        if (ng[0] + ng[1] + ng[2]) {
            snprintf(r->sky, sizeof r->sky, "sky: constant in %ld groups, plane in %ld, "
                     "quadratic in %ld (score test, p < %g)", ng[0], ng[1], ng[2], MP_SKY_ALPHA);
            ADD(u, ku, nu, "sky per group (highest order %s); ", order[top]);
        } else {                 /* the caller has no counts: say what was possible */
            snprintf(r->sky, sizeof r->sky, "sky: order chosen per group (score test, p < %g)",
                     MP_SKY_ALPHA);
            ADD(u, ku, nu, "sky per group (constant, plane or quadratic); ");
            top = MP_SKY_MAXORDER;
        }
    } else {
        top = o->fit.sky_order < 0 ? 0 : (o->fit.sky_order > 2 ? 2 : o->fit.sky_order);
        ADD(u, ku, nu, "sky %s; ", order[top]);
    }
    for (int k = top + 1; k <= MP_SKY_MAXORDER; k++)
        if (k > 0)
            ADD(l, kl, nl, "sky %s; ", order[k]);
    if (m->drf && m->drf->k)
        ADD(u, ku, nu, "DRF %dx%d map (V = %.4g); ", m->drf->k, m->drf->k, m->drf->volume);
    else if (m->drf && m->drf->volume != 1.0)
        ADD(u, ku, nu, "uniform detector V = %.4g; ", m->drf->volume);
    else
        ADD(l, kl, nl, "DRF (perfect detector); ");
    if (p->kind == MP_PSF_GAUSS) {
        ADD(u, ku, nu, "analytic Gaussian PSF; ");
        ADD(l, kl, nl, "sinc shift and supersampling (analytic PSF); ");
    } else {
        if (m->sinc_hw > 0)
            ADD(u, ku, nu, "damped-sinc shift (%d taps); ", 2 * m->sinc_hw + 1);
        else
            ADD(l, kl, nl, "sinc shift (nearest table element); ");
        if (p->os > 1 && r->kcoarse > 0)
            ADD(u, ku, nu, "supersampled table x%d (a coarser block-sum per group: %ld of %ld "
                "LM fits); ", p->os, r->kcoarse, r->kcalls);
        else if (p->os > 1)
            ADD(u, ku, nu, "supersampled table x%d; ", p->os);
        else
            ADD(l, kl, nl, "supersampling (x1 table); ");
    }
    if (fr && fr->ngroups < fr->nstars)
        ADD(u, ku, nu, "group coupling (%ld groups for %ld stars); ", fr->ngroups, fr->nstars);
    else
        ADD(l, kl, nl, "group coupling (every star alone); ");
#undef ADD
    if (ku > 1 && (size_t)ku < nu)
        u[ku - 2] = '\0';
    if (kl > 1 && (size_t)kl < nl)
        l[kl - 2] = '\0';
}

static void report_lines(FILE *fp, const char *prefix, const mp_run_report *r)
{
    fprintf(fp, "%s%s: run report\n", prefix, r->image);
    fprintf(fp, "%s  seconds: read %.3f, background %.3f, find %.3f, group %.3f, fit %.3f, "
            "write %.3f, total %.3f\n", prefix, r->t_read, r->t_bkg, r->t_find, r->t_group,
            r->t_fit, r->t_write, r->t_read + r->t_bkg + r->t_find + r->t_group + r->t_fit + r->t_write);
    fprintf(fp, "%s  stars: %ld fitted in %ld groups, %ld iterations, %ld merged, %ld rejected, "
            "%ld not converged\n", prefix, r->nstars, r->ngroups, r->iterations, r->merged,
            r->rejected, r->noconv);
    if (r->nstars > 0)
        fprintf(fp, "%s  error: median chi2/dof %.4f, median FLUXERR_PSF/FLUXERR_MODEL %.4f, "
                "median ERRX_PSF/POSERR_MODEL %.4f\n", prefix, r->chi2_median,
                r->errratio_median, r->poserr_median);
    else        /* no median of nothing (it read nan or 0) */
        fprintf(fp, "%s  error: no star fitted\n", prefix);
    fprintf(fp, "%s  model parts used: %s\n", prefix, r->used[0] ? r->used : "-");
    fprintf(fp, "%s  model parts left out: %s\n", prefix, r->left[0] ? r->left : "-");
    int nd = r->ndecisions + (r->sky[0] != '\0');
    const char *d = r->ndecisions && r->decisions ? r->decisions : "";
    fprintf(fp, "%s  economy: %d decisions%s%s%s%s\n", prefix, nd, nd ? ": " : "", d,
            d[0] && r->sky[0] ? "; " : "", r->sky);
    fprintf(fp, "%s  work: %ld group fits, %ld left out (neighbours' light unchanged), "
            "%ld star paints cropped; %ld of %ld LM fits with a shorter sinc kernel (mean "
            "half-width %.1f), %ld with a coarser table, %ld with the PRF from the phase grid "
            "(%ld of their %ld star fits bilinear, %ld with a cubic core); economy's own cost: "
            "%ld bound evaluations, "
            "%ld crop envelopes\n", prefix, r->fits, r->kept, r->cropped, r->kshort, r->kcalls,
            r->kcalls > 0 ? r->khw / (double)r->kcalls : 0.0, r->kcoarse, r->kcache, r->klin,
            r->kstars, r->kcore, r->kbounds, r->envelopes);
    long nre = 0;
    for (int c = 0; c < MP_REFIT_CAUSES; c++)
        nre += r->refits[c];
    if (nre > 0)
        fprintf(fp, "%s  refits: %ld of the LM fits were a group's again within its fit: %ld "
                "after merges (%ld LM steps), %ld after rejections (%ld), %ld to decide a pending "
                "merge or rejection at the deciding tol (%ld), %ld fitted on past a close pair "
                "(%ld), %ld with a star fitted brighter than economy's choices held (%ld)\n",
                prefix, nre, r->refits[MP_REFIT_MERGE], r->refit_steps[MP_REFIT_MERGE],
                r->refits[MP_REFIT_REJECT], r->refit_steps[MP_REFIT_REJECT],
                r->refits[MP_REFIT_DECIDE], r->refit_steps[MP_REFIT_DECIDE],
                r->refits[MP_REFIT_UNSTOPPED], r->refit_steps[MP_REFIT_UNSTOPPED],
                r->refits[MP_REFIT_BRIGHTER], r->refit_steps[MP_REFIT_BRIGHTER]);
    if (r->pairs_close > 0)
        fprintf(fp, "%s  groups: components above maxgroup cut at their weakest couplings "
                "(%ld pairs within psfrad + fitrad, %ld of them coupled), summed over rounds\n",
                prefix, r->pairs_close, r->pairs_coupled);
    if (r->detection[0])
        fprintf(fp, "%s  detection: %s\n", prefix, r->detection);
    if (r->tables && r->tables[0]) {
        double u = r->ops_render > 0 ? r->ops_render : 1.0;
        fprintf(fp, "%s  economy tables: %s; spent %.1f renders on them here (builds and "
                "bound evaluations) and saved %.1f\n", prefix, r->tables, r->ops_tables / u,
                r->ops_saved / u);
    }
}

int mp_report_write(const char *path, const char *task, const mp_run_report *r, char *err)
{
    char prefix[64];
    snprintf(prefix, sizeof prefix, "matphot %s: ", task);
    report_lines(stderr, prefix, r);
    if (!path || !path[0])
        return 0;
    mp_outfile o;
    if (mp_out_open(&o, path, err))
        return 1;
    report_lines(o.fp, "", r);
    return mp_out_commit(&o, err);
}
