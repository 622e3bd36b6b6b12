/* lm_frozen.c — frozen wings (issue 12): the LM iterates with each star
 * redrawn on its core only, its wings as last drawn. */

#include <math.h>
#include "fit/lm_group.h"

/* Frozen wings (issue 12).  A star's window reaches as far as its light
 * matters to the model (its crop radius: 47 Tuc, 1240 fitted px a star on
 * average, against 80 in its own fitting disc), yet between two steps the
 * light of its wings barely moves.  So the LM iterates with each star
 * redrawn on its core only — the box LM_CORE px beyond G->core_hw around
 * where it stood when the wings were last drawn — and its wings (values
 * and derivatives) as they were then, scaled by its current flux; it
 * redraws a star that has moved LM_MOVE px from there (that star alone:
 * lm_refresh_movers), and everything (a refresh) when the steps have
 * converged on that model.  A fit is converged only by the tests of an
 * unfrozen one on the same exact normal equations, after a refresh, so
 * the answer is the same to within those tests (levmar.c: tol, or D's
 * resolution); the frozen model only steers the way there. */
#define LM_CORE 1.0
#define LM_MOVE 0.5

double mp_fit_core_halfwidth(double fitrad)
{
    return fitrad + 1.0 + LM_CORE;      /* G->core_hw + LM_CORE (fit_group.c) */
}

double lm_box_halfwidth(const group *G)
{
    return G->core_hw + LM_CORE;
}

void lm_box_at(const group *G, double x, double y, int b[4])
{
    double h = lm_box_halfwidth(G);
    b[0] = (int)floor(x - h) - (int)G->bx0;
    b[1] = (int)ceil(x + h) + 1 - (int)G->bx0;
    b[2] = (int)floor(y - h) - (int)G->by0;
    b[3] = (int)ceil(y + h) + 1 - (int)G->by0;
}

/* Freeze every star's wings where it is now: its core box, and the trial
 * buffers as the current ones (the same windows and wing values). */
static void core_box(group *G, int k)
{
    int b[4];
    rstar *c = &G->cur[k];
    lm_box_at(G, G->p[3 * k + 1], G->p[3 * k + 2], b);
    c->ci0 = b[0];
    c->ci1 = b[1];
    c->cj0 = b[2];
    c->cj1 = b[3];
}

/* Whether freezing pays: the stars' windows hold LM_PAYS times the
 * pixels of their cores (a PSF with faint wings, or a Gaussian's small
 * crop radius, leaves nothing to save but the refreshes' cost: the crowded
 * Gaussian scene of make validate ran 28 % slower frozen). */
#define LM_PAYS 2.0

int lm_freezing_pays(group *G)
{
    double win = 0.0, core = 0.0;
    for (int k = 0; k < G->n; k++) {
        rstar *c = &G->cur[k];
        int b[4], ns;
        core_box(G, k);
        ns = lm_core_rows(G, c, b);
        for (int t = 0; t < c->j1 - c->j0; t++)
            win += c->pn[t];
        for (int q = 0; q < ns; q++)
            core += G->spans[q].n;
    }
    return win > LM_PAYS * core;
}

/* Star k's wings frozen where it is now: its core box, and its trial
 * buffer as its current one (the same window and wing values). */
static void freeze_star(group *G, int k)
{
    G->fx[k] = G->p[3 * k + 1];
    G->fy[k] = G->p[3 * k + 2];
    core_box(G, k);
    lm_render_copy(&G->trial[k], &G->cur[k]);
}

void lm_freeze(group *G)
{
    for (int k = 0; k < G->n; k++)
        freeze_star(G, k);
    G->frozen = 1;
}

/* Whether star k has moved LM_MOVE px from where its wings were drawn. */
static int star_moved_far(const group *G, int k)
{
    return fabs(G->p[3 * k + 1] - G->fx[k]) > LM_MOVE || fabs(G->p[3 * k + 2] - G->fy[k]) > LM_MOVE;
}

int lm_moved_far(const group *G)
{
    for (int k = 0; k < G->n; k++)
        if (star_moved_far(G, k))
            return 1;
    return 0;
}

/* A refresh for a star that moved far, between steps: it alone is
 * redrawn and frozen again (47 Tuc: 1.9 of a group's 28.7 open stars had
 * moved at such a refresh, and a whole refresh was ~20 % of the CPU); the
 * others' wings stay as drawn, within LM_MOVE of where they are.  Its own
 * terms and its pairs' sums are made exact, the rest stay as between
 * steps: the model only steers, and the fit still ends on a whole
 * refresh (lm_refresh). */
int lm_refresh_movers(group *G, double *D)
{
    for (int k = 0; k < G->n; k++) {
        G->moved[k] = !G->settled[k] && star_moved_far(G, k);
        if (!G->moved[k])
            continue;
        if (lm_render_star(G, G->p, G->cur, k))
            return 1;
        freeze_star(G, k);
    }
    lm_model_of(G, G->p, G->cur);
    lm_variance_of(G);
    *D = lm_deviance_of(G);
    return lm_normal_equations(G, G->p, G->cur, NE_MOVERS);
}

/* Every open star redrawn at G->p (whole windows), the settled ones too
 * (opened) when open is set, D in *D, exact normal equations over the open
 * stars; frozen again there when again is set.  A settled star does not
 * move, so a refresh for a neighbour that moved far leaves it as it is.
 * Nonzero when out of memory. */
int lm_refresh(group *G, double *D, int again, int open)
{
    G->frozen = 0;
    if (open)
        lm_unsettle(G, 0);
    if (lm_render_all(G, G->p, G->cur, RENDER_ALL))
        return 1;
    lm_model_of(G, G->p, G->cur);
    lm_variance_of(G);
    *D = lm_deviance_of(G);
    if (lm_normal_equations(G, G->p, G->cur, NE_EXACT))
        return 1;
    if (again)
        lm_freeze(G);
    return 0;
}
