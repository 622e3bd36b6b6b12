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
 * redraws everything (a refresh) when a star has moved LM_MOVE px from
 * there, and when the steps have converged on that model.  A fit is
 * converged only when the first step from a refreshed state is below tol:
 * the same test on the same exact normal equations as without freezing,
 * so the answer is the same to within tol; the frozen model only steers
 * the way there. */
#define LM_CORE 1.0
#define LM_MOVE 0.5

/* Freeze every star's wings where it is now: its core box, and the trial
 * buffers as the current ones (the same windows and wing values). */
static void core_box(group *G, int k)
{
    double h = G->core_hw + LM_CORE, x = G->p[3 * k + 1], y = G->p[3 * k + 2];
    rstar *c = &G->cur[k];
    c->ci0 = (int)floor(x - h) - (int)G->bx0;
    c->ci1 = (int)ceil(x + h) + 1 - (int)G->bx0;
    c->cj0 = (int)floor(y - h) - (int)G->by0;
    c->cj1 = (int)ceil(y + h) + 1 - (int)G->by0;
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

void lm_freeze(group *G)
{
    for (int k = 0; k < G->n; k++) {
        G->fx[k] = G->p[3 * k + 1];
        G->fy[k] = G->p[3 * k + 2];
        core_box(G, k);
        lm_render_copy(&G->trial[k], &G->cur[k]);
    }
    G->frozen = 1;
}

/* Whether a star has moved LM_MOVE px from where its wings were drawn. */
int lm_moved_far(const group *G)
{
    for (int k = 0; k < G->n; k++)
        if (fabs(G->p[3 * k + 1] - G->fx[k]) > LM_MOVE || fabs(G->p[3 * k + 2] - G->fy[k]) > LM_MOVE)
            return 1;
    return 0;
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
