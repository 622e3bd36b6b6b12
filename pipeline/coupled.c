/* coupled.c — mp_pl_group: a component too large to fit at once cut at
 * its weakest couplings (issues 12, 13).  DAOPHOT GROUP's rule (any two
 * stars closer than psfrad + fitrad) percolates in a crowded field, and a
 * component above maxgroup was cut at the median of its longer axis, pair
 * or no pair: on a simulated 512² frame of 6000 stars (FWHM 2.5) the parts,
 * each fitted with the others' light held, gave 98 false stars and a
 * robust σ of the normalised flux errors of 1.48 (bench/PROFILE.md,
 * session 24).  Here the links of such a component are taken strongest
 * first, by κ, the largest canonical correlation of two stars' fits
 * (fit/coupling.c), and two sets are joined only while together they hold
 * at most maxgroup stars (mp_group_capped): what is cut is what the fits
 * least share.  A link weaker than couplefrac joins sets only while they
 * hold at most weakgroup stars (maxgroup/2 by default): held apart, such
 * stars move by at most couplefrac of their σ per σ of the other's error,
 * and a group of 30 whose last links are weak costs its fit's iterations
 * for that (47 Tuc built: 0.80 of the CPU, a dense simulated frame 0.85,
 * at the same precision; bench/PROFILE.md, session of 2026-12-02 15:17).
 * A cut link with κ ≥ couplefrac (the fits then move by more than
 * couplefrac of their σ per σ of the other's error) flags its stars 2, as
 * a split did.  Components within maxgroup are DAOPHOT's groups;
 * with groupcut=budget every component is re-formed, a link joined only
 * while a star has more than the budget of Σκ² outside its group
 * (mp_group_budget). */
#include <limits.h>
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include "pipeline/pipeline_priv.h"

/* The pairs within crit among the rows of oversized components, with
 * their κ (the grid's link test, linking nothing: it only records). */
typedef struct {
    const mp_coupling *c;
    const double *E;
    const unsigned char *big;
    mp_group_pair *p;
    size_t n, cap;
    int oom;
} pair_list;

static int record(void *ctx, size_t a, size_t b, double d)
{
    pair_list *L = ctx;
    if (!L->big[a] || L->oom)
        return 0;
    if (L->n == L->cap) {
        size_t cap = L->cap ? 2 * L->cap : 1024;
        mp_group_pair *q = realloc(L->p, cap * sizeof *q);
        if (!q) {
            L->oom = 1;
            return 0;
        }
        L->p = q;
        L->cap = cap;
    }
    L->p[L->n++] = (mp_group_pair){a, b, mp_coupling_kappa(L->c, d, L->E[a], L->E[b])};
    return 0;
}

/* The final grouping's link test: rows of oversized components linked
 * within their capped sets, the others as DAOPHOT GROUP links them. */
typedef struct {
    const unsigned char *big;
    const size_t *label;
} set_test;

static int same_set(void *ctx, size_t a, size_t b, double d)
{
    (void)d;
    const set_test *s = ctx;
    return !s->big[a] || s->label[a] == s->label[b];
}

/* big[r]: row r's component holds more than maxgroup stars; whether any. */
static int oversized(const mp_table *t, int maxgroup, unsigned char *big)
{
    int cs = mp_table_col(t, "GROUP_SIZE"), any = 0;
    for (size_t r = 0; r < t->nrow; r++) {
        big[r] = mp_table_get(t, r, cs) > maxgroup;
        any |= big[r];
    }
    return any;
}

/* Each row's flux: the fitted one, else detection's (not finite: none). */
static double *fluxes_of(const mp_table *t)
{
    int cp = mp_table_col(t, "FLUX_PSF"), cf = mp_table_col(t, "FLUX");
    double *E = malloc((t->nrow + 1) * sizeof *E);
    for (size_t r = 0; E && r < t->nrow; r++) {
        double e = cp >= 0 ? mp_table_get(t, r, cp) : NAN;
        E[r] = isfinite(e) && e > 0 ? e : cf >= 0 ? mp_table_get(t, r, cf) : NAN;
    }
    return E;
}

/* FLAGS bit 2 (group split) on the rows whose strong link the cap cut. */
static void flag_cut(mp_table *t, const unsigned char *cut)
{
    int cf = mp_table_col(t, "FLAGS");
    for (size_t r = 0; cf >= 0 && r < t->nrow; r++) {
        long fl = (long)mp_table_get(t, r, cf);
        if (cut[r] && !(fl & MP_FLAG_SPLIT))
            mp_table_set(t, r, cf, (double)(fl | MP_FLAG_SPLIT));
    }
}

/* The pairs of the components marked big and their κ (L), their capped
 * sets (label; with budget > 0 as mp_group_budget forms them) and the
 * rows whose strong link the cap cut. */
static int capped_sets(mp_table *t, const mp_group_opts *go, const mp_prf_model *m, double frac,
                       double budget, double ron, mp_coupling *kept, pair_list *L, size_t *label,
                       unsigned char *cut, char *err)
{
    double sky = mp_pl_median_positive(t, "SKY_PSF");
    sky = sky > 0 ? sky : mp_pl_median_positive(t, "BACKGROUND");
    mp_coupling own = {0}, *c = kept ? kept : &own;
    double *E = NULL, crit = go->psfrad + go->fitrad;
    int rc = 0;
    /* a table of the same model, fitrad and reach serves any sky */
    if (c == &own || !c->k || c->fitrad != go->fitrad || c->crit != crit) {
        if (c->k)
            mp_coupling_free(c);
        rc = mp_coupling_build(m, go->fitrad, crit, sky, ron, c, err);
    } else {
        mp_coupling_at(c, sky, ron);
    }
    if (!rc && !(E = fluxes_of(t)))
        rc = -1;
    L->c = c;
    L->E = E;
    mp_group_opts o = *go;
    o.maxgroup = INT_MAX;
    o.link = record;
    o.link_ctx = L;
    rc = rc ? rc : mp_group_table(t, &o, err);
    rc = rc ? rc : L->oom ? -1 : 0;
    if (!rc && (budget > 0 ? mp_group_budget(t->nrow, L->p, L->n, go->maxgroup, budget, label,
                                             cut, frac)
                           : mp_group_capped(t->nrow, L->p, L->n, go->maxgroup, go->weakgroup,
                                             label, cut, frac)))
        rc = -1;
    free(E);
    if (c == &own)
        mp_coupling_free(&own);
    return rc;
}

int mp_pl_group(mp_table *t, const mp_group_opts *go, const mp_prf_model *m, double couplefrac,
                double budget, double ron, mp_coupling *kept, long *tested, long *linked,
                char *err)
{
    *tested = *linked = 0;
    if (!(couplefrac > 0))
        return mp_group_table(t, go, err);
    /* DAOPHOT GROUP's components first: none too large, nothing to do. */
    mp_group_opts o = *go;
    o.maxgroup = INT_MAX;
    size_t n = t->nrow;
    unsigned char *big = calloc(2 * n + 1, 1), *cut = big ? big + n : NULL;
    size_t *label = malloc((n + 1) * sizeof *label);
    int rc = big && label ? mp_group_table(t, &o, err) : -1;
    /* With a budget every component is re-formed, not only those above
     * maxgroup. */
    if (!rc && (oversized(t, go->maxgroup, big) || budget > 0)) {
        if (budget > 0)
            memset(big, 1, n);
        pair_list L = {NULL, NULL, big, NULL, 0, 0, 0};
        rc = capped_sets(t, go, m, couplefrac, budget, ron, kept, &L, label, cut, err);
        for (size_t k = 0; k < L.n; k++)
            *linked += L.p[k].w >= couplefrac;
        *tested = (long)L.n;
        free(L.p);
        set_test st = {big, label};
        o.maxgroup = go->maxgroup;
        o.link = same_set;
        o.link_ctx = &st;
        rc = rc ? rc : mp_group_table(t, &o, err);
        if (!rc)
            flag_cut(t, cut);
    }
    if (rc < 0)
        snprintf(err, MP_ERRLEN, "out of memory grouping %zu stars", n);
    free(big);
    free(label);
    return rc != 0;
}

void mp_pl_group_decision(mp_fit_setup *fs, double budget, int weakgroup)
{
    if (!(fs->opts.couplefrac > 0))
        return;
    size_t l = strlen(fs->decisions);
    if (budget > 0)
        snprintf(fs->decisions + l, sizeof fs->decisions - l, "%sgroups: every component "
                 "re-formed from its strongest couplings (the canonical correlation kappa of "
                 "two stars' fits), a link joined only while one of its stars has more than "
                 "%.3g of sum kappa^2 outside its group (groupcut=budget); a link of %.2g or "
                 "more cut by maxgroup flags its stars 2 (fit/coupling.c)", l ? "; " : "",
                 budget, fs->opts.couplefrac);
    else
        snprintf(fs->decisions + l, sizeof fs->decisions - l, "%sgroups: a component above "
                 "maxgroup cut at its weakest couplings (the canonical correlation kappa of two "
                 "stars' fits), not at its median; a link below kappa %.2g joins sets only up "
                 "to %d stars (weakgroup: held apart, each star moves by at most %.2g sigma per "
                 "sigma of the other's error); a cut link of %.2g or more flags its stars 2 "
                 "(fit/coupling.c)", l ? "; " : "", fs->opts.couplefrac, weakgroup,
                 fs->opts.couplefrac, fs->opts.couplefrac);
    fs->ndecisions++;
}
