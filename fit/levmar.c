/* levmar.c — fitting a group of stars and its sky by Levenberg–Marquardt
 * (design.md §5).
 *
 * The answer is the root of the unbiased estimating equation
 * Σ (d − m)/V(m) ∂m/∂p = 0 with the variance function V(m) = max(m, S) + RON²
 * from the model, not the data (S, the lowest sky the group's stars were
 * found on, or 0: no pixel carries less light than the sky, and a model
 * dipping below it
 * — a table's negative wings, a neighbour over-subtracted — must not weigh
 * a pixel at 1/RON², which with RON = 0 made one negative pixel outweigh a
 * star; minimising a χ² whose weights move with the
 * parameters would bias faint fluxes by about β/2 electrons).  That root is
 * the minimum of one fixed objective, the quasi-likelihood deviance
 * D = 2 Σ ∫_d^m (t − d)/V(t) dt (McCullagh & Nelder, Generalized Linear
 * Models, §9.2: its gradient is −2× the estimating equation, its expected
 * Hessian 2 JᵀV⁻¹J, the normal matrix).  A step is accepted only when it
 * lowers D: comparing χ² under weights refreshed after every step follows
 * no fixed objective, and on a large crowded group with sky and fluxes
 * nearly degenerate it walked off (sky −5.7e5 e⁻, fluxes 10⁷× the truth).
 * Steps are also bounded (positions 1 px, fluxes ×10 up, sky a few σ of a
 * pixel), and a fit that stalls or runs out of iterations before its steps
 * are below tol·σ keeps its best (last accepted) state and is flagged. */
#include <math.h>
#include <stddef.h>
#include <stdlib.h>
#include <string.h>
#include "fit/lm_group.h"
#include "fit/spd.h"

/* Solve (A + λ diag A) δ = g by Cholesky, the constant sky held (its
 * step 0, its row and column out of the system) when G->skyheld; nonzero
 * when not positive definite. */
static int lm_step(group *G, double lambda)
{
    int np = G->np, h = G->skyheld ? 3 * G->n : -1;
    memcpy(G->M, G->A, (size_t)np * np * sizeof *G->M);
    for (int a = 0; a < np; a++) {
        double d = G->A[(size_t)a * np + a];
        G->M[(size_t)a * np + a] = d * (1.0 + lambda) + (d > 0 ? 0.0 : 1e-300);
    }
    memcpy(G->step, G->g, (size_t)np * sizeof *G->step);
    if (h >= 0) {
        for (int a = 0; a < np; a++)
            G->M[(size_t)a * np + h] = G->M[(size_t)h * np + a] = 0.0;
        G->M[(size_t)h * np + h] = 1.0;
        G->step[h] = 0.0;
    }
    /* M is symmetric: its row-major upper triangle is the column-major
     * lower one that mp_spd_solve reads in place (fit/spd.h: not LAPACK,
     * whose per-call lock serialised the threads). */
    return mp_spd_solve(G->M, np, G->step) != 0;
}

/* The sky's lower bound (bound_step, sky_in_bounds): 10 σ below the sky
 * the stars were found on.  Not the lowest pixel: a bright star's wings
 * can fill its window, so its lowest pixel sits far above the sky (Tiny
 * Tim, 10⁶ e⁻, fitrad 5: 140 e⁻ over a sky of 100; a sky held there was
 * flag 8 for 6 % of the bench's ugly scene); and a neighbour painted out
 * with too much light leaves data far below the sky, which a bound from
 * the data lets the sky follow (GLIMPSE near its hollow saturated cores:
 * −7·10⁴ e⁻, the group's fluxes to 10⁹, and on through the next rounds
 * until every residual pixel was off).  Without a known sky, one data
 * range below the lowest pixel. */
static double sky_floor(const group *G)
{
    double base = isfinite(G->sknown) ? G->sknown : G->dlo - (G->dhi - G->dlo);
    return base - 10.0 * sqrt(fmax(base, 0.0) + G->ron2);
}

/* Whether the plane or quadratic sky of the last model_of stays within
 * [sky_floor, dhi] on every fitted pixel (model_of keeps its range).
 * Bounding the coefficients one by one does not: each within its own
 * bound, their sum can still go far below the floor at the box's corners
 * (GLIMPSE's left quarter, 3 rounds: without this 5 stars ended on a
 * negative sky and 3 with CHI2_PSF > 1e4, with it none).  A trial step
 * outside is refused as one that raises D is. */
int lm_sky_in_bounds(const group *G)
{
    if (G->nsky <= 1)
        return 1;                /* the constant: bound_step */
    return G->skylo >= sky_floor(G) && G->skyhi <= G->dhi;
}

/* Cut the step to what one iteration may do, so a step the local
 * linearisation cannot vouch for is not even tried: positions by at most
 * 1 px (DAOPHOT does the same: a start far off cannot fling a star across
 * the group); a flux by at most ×10 up and 90 % down, plus 3 of its σ so
 * faint stars can cross zero (a start of 1 e⁻ reaches 10⁶ e⁻ in five
 * steps); each sky coefficient (the basis is scaled to ±1 on the box) by
 * 3 σ of a sky pixel or half the sky, whichever is larger.  Returns 1 when
 * something was cut. */
static int bound_step(group *G)
{
    int n = G->n, np = G->np, cut = 0;
    for (int k = 0; k < n; k++) {
        double E = fabs(G->p[3 * k]), aee = G->A[(size_t)(3 * k) * np + 3 * k];
        double se = aee > 0 ? 3.0 / sqrt(aee) : INFINITY;
        double lim[3][2] = {{-(0.9 * E + se), 9.0 * E + se}, {-1.0, 1.0}, {-1.0, 1.0}};
        for (int a = 0; a < 3; a++) {
            double *d = &G->step[3 * k + a];
            if (*d < lim[a][0] || *d > lim[a][1]) {
                *d = *d < lim[a][0] ? lim[a][0] : lim[a][1];
                cut = 1;
            }
        }
    }
    /* Absolute bounds, whatever D does: a flux beyond emax or a sky outside
     * the data's range is no answer but a walk along a degenerate direction
     * (a table with negative wings lets huge fluxes trade against a huge
     * negative sky: GLIMPSE's IRAC PSF, sky −2.8e13, fluxes 1e17). */
    for (int k = 0; k < n; k++) {
        double *d = &G->step[3 * k], E = G->p[3 * k];
        if (fabs(E + *d) > G->emax) {
            *d = (E + *d > 0 ? G->emax : -G->emax) - E;
            cut = 1;
        }
    }
    if (G->nsky && !G->skyheld) {
        double B0 = G->p[3 * n], lo = sky_floor(G);
        if (B0 + G->step[3 * n] < lo || B0 + G->step[3 * n] > G->dhi) {
            G->step[3 * n] = (B0 + G->step[3 * n] < lo ? lo : G->dhi) - B0;
            cut = 1;
        }
        for (int a = 1; a < G->nsky; a++) {
            double *d = &G->step[3 * n + a], c = G->p[3 * n + a], span = G->dhi - lo;
            if (fabs(c + *d) > span) {
                *d = (c + *d > 0 ? span : -span) - c;
                cut = 1;
            }
        }
    }
    if (G->nsky) {
        double B = G->p[3 * n];
        double lim = fmax(3.0 * sqrt((B > 0 ? B : 0.0) + G->ron2), 0.5 * fabs(B));
        for (int a = 0; a < G->nsky; a++) {
            double *d = &G->step[3 * n + a];
            if (fabs(*d) > lim) {
                *d = *d > 0 ? lim : -lim;
                cut = 1;
            }
        }
    }
    return cut;
}

/* Whether the constant sky sits on one of bound_step's absolute bounds
 * (sky_floor, dhi), the step G->step pushing it further out. */
static int sky_pinned(const group *G)
{
    if (!G->nsky)
        return 0;
    double B0 = G->p[3 * G->n], d = G->step[3 * G->n];
    double eps = 1e-9 * fmax(fabs(B0), 1.0);
    return (d < 0 && B0 <= sky_floor(G) + eps) || (d > 0 && B0 >= G->dhi - eps);
}

/* The LM step at λ within bound_step's limits.  A constant sky on one of
 * its absolute bounds that the step would push further is held there and
 * the others' step solved without it: the step of the minimum on that
 * bound, where D's gradient still points out of it.  Cut to the bound
 * instead, every step counted as cut, so the fit could not converge
 * however small the stars' steps (47 Tuc built: 74 loops ran to maxiter,
 * nearly all on a sky pinned there, four loops of 50 steps each for
 * some groups).  −1 when A + λ diag A is not positive definite, else
 * whether bound_step cut the step. */
static int bounded_step(group *G, double lambda)
{
    G->skyheld = 0;
    if (lm_step(G, lambda))
        return -1;
    if (sky_pinned(G)) {
        G->skyheld = 1;
        if (lm_step(G, lambda))
            return -1;
    }
    return bound_step(G);
}

/* The largest step of a fitted parameter in units of its σ, 1/sqrt(A_aa)
 * (the conditional σ; the fit's stopping rule compares it with tol). */
static double step_sigmas(const group *G)
{
    int np = G->np, npar = 3 * G->n + G->nsky;
    double z = 0.0;
    for (int a = 0; a < npar; a++) {
        double d = G->A[(size_t)a * np + a];
        double v = d > 0 ? fabs(G->step[a]) * sqrt(d) : 0.0;
        z = v > z ? v : z;
    }
    return z;
}

/* The resolution of D [σ]: the position derivatives are the five-point
 * formula on the shifted table (paper §3.2), not the exact derivatives of
 * the rendered model, so the root the normal equations point to lies a
 * little off D's own minimum, and within that distance a step can raise D
 * although the quadratic model says it should not (measured on 600
 * single-star fits, FWHM 3 px, 1× table, at the first refused step: median
 * 0.003 σ, 99th percentile 0.2 σ, largest 0.26 σ; faint stars, whose
 * weight sits in the wings, have the largest).  On steps this small the
 * model is otherwise quadratic to high accuracy, so a step below
 * LM_RESOLVE_SIGMAS (undamped) that cannot lower D even when damped means
 * the fit is as close as D can tell: it has converged. */
#define LM_RESOLVE_SIGMAS 0.5

/* The quasi-likelihood dispersion φ = D/dof of deviance D, floored at 1
 * (a model that fits keeps the Fisher σ). */
static double dispersion(const group *G, double D)
{
    double dof = (double)G->npix - (double)(3 * G->n + G->nsky);
    return dof > 0 && D / dof > 1.0 ? D / dof : 1.0;
}

/* The step's length along its direction (issue 12).  D along the step,
 * D(α) ≈ D − 2α gᵀδ + c α² (−2g is D's gradient, exact), with c from D at
 * the step's end, puts its minimum at α = gᵀδ / c: 1 when the Hessian is
 * right.
 * - Overshoot: at χ²/dof ≫ 1 the expected Hessian JᵀV⁻¹J can under-state
 *   D's curvature (47 Tuc, PSF built from the frame: a 5500 e⁻ star's y in
 *   a group of 48 stepped ±0.3 px for 25 iterations, each step 1.9× the
 *   distance to the minimum, D falling a little every time, so LM never
 *   damped it).  Below LM_OVERSHOOT the step α·δ is tried.
 * - Undershoot: a star far from where it starts (a detection 1-3 px off,
 *   the pair it was half of) walks there in short steps, the linearised
 *   model seeing little of the light it moves to (47 Tuc built: the LM
 *   loops in which a star moved more than 1 px were half the big groups'
 *   star-iterations, 18 a loop; a star 3 px off in 0.15 px steps for 30
 *   iterations, D falling by 20 each).  Above LM_UNDERSHOOT (or where D
 *   has no minimum along δ) a step at most LM_LONGEST times δ is tried,
 *   when it stays within bound_step's limits.
 * Either is kept when it lowers D further (one more render, against
 * iterations); *Dt, *z and G->step follow the step kept, and the trial
 * buffers hold its render.  The fit's end is the same test on the same
 * estimating equation: only the way there changes. */
#define LM_OVERSHOOT 0.75
#define LM_UNDERSHOOT 1.5
#define LM_LONGEST 4.0

/* The trial's model and the current one trade places (mod, modt). */
static void swap_models(group *G)
{
    double *m = G->mod, lo = G->skylo, hi = G->skyhi;
    G->mod = G->modt;
    G->modt = m;
    G->skylo = G->tskylo;
    G->skyhi = G->tskyhi;
    G->tskylo = lo;
    G->tskyhi = hi;
}

static int render_trial(group *G, double alpha, double *Dt)
{
    for (int a = 0; a < G->np; a++)
        G->pt[a] = G->p[a] + alpha * G->step[a];
    if (lm_render_all(G, G->pt, G->trial, RENDER_PRF))
        return 1;
    swap_models(G);             /* drawn in modt; mod stays the current one */
    lm_model_of(G, G->pt, G->trial);
    G->outside = !lm_sky_in_bounds(G);
    *Dt = G->outside ? INFINITY : lm_deviance_of(G);
    swap_models(G);
    return 0;
}

/* The step α·δ tried (step_length): kept when it lowers D below *Dt,
 * else δ again, rendered.  A longer step that bound_step would cut is not
 * tried.  Nonzero when out of memory. */
static int try_length(group *G, double alpha, double *Dt, double *z)
{
    int np = G->np;
    double Ds;
    memcpy(G->sx, G->step, (size_t)np * sizeof *G->sx);
    for (int a = 0; a < np; a++)
        G->step[a] *= alpha;
    if (alpha > 1.0 && bound_step(G)) {
        memcpy(G->step, G->sx, (size_t)np * sizeof *G->step);
        return 0;
    }
    if (render_trial(G, 1.0, &Ds))
        return 1;
    if (Ds < *Dt) {
        *Dt = Ds;
        *z *= alpha;
        return 0;
    }
    memcpy(G->step, G->sx, (size_t)np * sizeof *G->step);
    return render_trial(G, 1.0, &Ds);
}

/* The step δ, taken (D at its end *Dt), shortened or lengthened by D's
 * parabola along it (above); not lengthened when bound_step cut it (z
 * infinite).  Nonzero when out of memory. */
static int step_length(group *G, double D, double *Dt, double *z)
{
    double gd = 0.0;
    for (int a = 0; a < G->np; a++)
        gd += G->g[a] * G->step[a];
    double c = *Dt - D + 2.0 * gd;
    double alpha = !(gd > 0) ? 1.0 : c > 0 ? gd / c : LM_LONGEST;
    if (alpha < LM_OVERSHOOT)
        return try_length(G, alpha, Dt, z);
    if (alpha > LM_UNDERSHOOT && isfinite(*z))
        return try_length(G, fmin(alpha, LM_LONGEST), Dt, z);
    return 0;
}

/* Whether the step LM would take from G->p at λ is below tol·σ·√φ in
 * every parameter, as lm_loop's test (A and g exact at G->p, every star
 * open): the fit has converged without taking it. */
static int step_below_tol(group *G, double lambda, double rphi, double tol)
{
    if (bounded_step(G, lambda) != 0)
        return 0;
    return step_sigmas(G) * rphi * (1.0 + lambda) < tol;
}

/* Every settled star opened again (lm_settle.c) and the normal equations
 * summed exactly over all of them at G->p: their renders in G->cur are
 * those of their parameters.  Nonzero when out of memory. */
static int open_all(group *G)
{
    lm_unsettle(G, 0);
    return lm_normal_equations(G, G->p, G->cur, NE_EXACT);
}

/* Where lm_loop stands: D at G->p, the damping, the first (least damped)
 * step tried from the current state (its size in σ, undamped, and its
 * λ), 1/√φ, and the counts: steps taken, steps tried, steps since the
 * last exact sums (0: A and g are exact at G->p). */
typedef struct {
    double D, lambda, zfirst, lfirst, rphi;
    int it, trials, fresh, since, skyhits;
} lm_state;

/* What a step of lm_loop leads to. */
enum { LM_ON, LM_DONE, LM_NOMEM };

/* The loop's start at G->p: frozen wings where they pay, the model, exact
 * normal equations, D; with rose, the pairs' sums of the last loop's end
 * (the same renders, model and weights: only the sky order rose, its new
 * terms at zero).  Nonzero when out of memory. */
static int lm_start(group *G, int freeze_ok, int rose, lm_state *s)
{
    lm_unsettle(G, 1);
    G->skystall = 0;
    G->paired = 0;
    G->freezing = freeze_ok && G->core_hw > 0 && G->crop && lm_freezing_pays(G);
    lm_model_of(G, G->p, G->cur);
    lm_variance_of(G);
    if (lm_normal_equations(G, G->p, G->cur, rose ? NE_REUSE : NE_EXACT))
        return 1;
    *s = (lm_state){.D = lm_deviance_of(G), .lambda = 1e-3, .zfirst = INFINITY, .lfirst = 1e-3,
                    .fresh = 1};
    if (G->freezing)
        lm_freeze(G);
    /* Steps are judged in σ of the data as they scatter: the quasi-
     * likelihood dispersion φ = D/dof (McCullagh & Nelder §9.2.4) scales
     * every σ by √φ when the model misses the data (a PSF sharper than the
     * stars, χ²/dof ≫ 1); φ is floored at 1, so a model that fits keeps
     * the Fisher σ. */
    s->rphi = 1.0 / sqrt(dispersion(G, s->D));
    return 0;
}

/* A loop stalls on the sky's bounds when LM_SKY_STALL of its trials,
 * each damped by LM_SKY_STALL_LAMBDA or more, were refused for leaving
 * them.  Such a loop crawls: the step least damped that lowers D is tiny
 * and the same every time, D falling by the same amount, the next one
 * out of bounds again (47 Tuc 256², a quadratic sky, λ 1e5-1e8 for 40
 * iterations until maxiter; GLIMPSE the same): D has no minimum inside
 * them, so the step test is never met. */
#define LM_SKY_STALL 5
#define LM_SKY_STALL_LAMBDA 1.0

/* A loop ends on a close pair (o->stop_pair) from its LM_PAIR_AFTER-th
 * step on.  GLIMPSE's loops that ran to maxiter crawled along a blend's
 * degenerate direction, a pair within 0.22 px a quarter of the time
 * (bench/PROFILE.md); the frame fit merges such a pair at the end anyway.
 * From the first step on, pairs that pass close and part again were cut
 * short too: GLIMPSE lost 2 600 of its 13 700 stars (the merge also takes
 * pairs within twice their separation's error, unconverged there); from
 * the 10th, none. */
#define LM_PAIR_AFTER 10

/* Whether two stars of G lie closer than r. */
static int close_pair(const group *G, double r)
{
    for (int a = 0; a < G->n; a++)
        for (int b = a + 1; b < G->n; b++) {
            double dx = G->p[3 * a + 1] - G->p[3 * b + 1], dy = G->p[3 * a + 2] - G->p[3 * b + 2];
            if (dx * dx + dy * dy < r * r)
                return 1;
        }
    return 0;
}

/* A step refused (it did not lower D): more damping, or the end when it
 * took 1000× more to no avail from a first step within D's resolution —
 * after a whole refresh when the wings are frozen and moved since, or
 * with every settled star opened again. */
static int step_refused(group *G, lm_state *s, int *converged)
{
    /* Damped 1000× or more and still out of the sky's bounds, time after
     * time: stalled (fit_group.c's fit_orders drops the order). */
    if (G->outside && s->lambda >= LM_SKY_STALL_LAMBDA && ++s->skyhits >= LM_SKY_STALL) {
        G->skystall = 1;
        return LM_DONE;
    }
    int at_floor = s->zfirst < LM_RESOLVE_SIGMAS;
    /* Within D's resolution the next trial is the 1000× damped one at
     * once: the 10× and 100× ones between change a step this short by
     * a factor 1 + λ ≈ 1 and were refused alike (47 Tuc: 4 renders of
     * every open star to end each loop, a third of all the trials). */
    s->lambda = at_floor && s->lambda < 1e3 * s->lfirst ? 1e3 * s->lfirst : 10.0 * s->lambda;
    if (!(at_floor && s->lambda > 1e3 * s->lfirst * (1.0 + 1e-9)))
        return s->lambda > 1e8 ? LM_DONE : LM_ON;
    if (G->frozen && (s->since > 0 || G->nsettled)) {     /* frozen model: see */
        if (lm_refresh(G, &s->D, 1, 1))
            return LM_NOMEM;
        s->since = 0;
        s->fresh = 1;
        s->lambda = s->lfirst;
        s->rphi = 1.0 / sqrt(dispersion(G, s->D));
        return LM_ON;
    }
    if (G->nsettled) {          /* the open stars are done: all again */
        if (open_all(G))
            return LM_NOMEM;
        s->fresh = 1;
        s->lambda = s->lfirst;
        return LM_ON;
    }
    *converged = 1;             /* damped 1000×: nothing left D can see */
    return LM_DONE;
}

/* The trial state made current (the buffers swapped), with its D. */
static void step_taken(group *G, lm_state *s, double Dt)
{
    double *tp = G->p;
    G->p = G->pt;
    G->pt = tp;
    rstar *tr = G->cur;
    G->cur = G->trial;
    G->trial = tr;
    swap_models(G);
    s->D = Dt;
    s->rphi = 1.0 / sqrt(dispersion(G, s->D));
    s->fresh = 1;
    s->lambda = s->lambda / 10.0 > 1e-7 ? s->lambda / 10.0 : 1e-7;
    lm_variance_of(G);
}

/* After a step taken (done: it met the stopping rule; every: no star was
 * settled): the sums for the next step, or the end.  Frozen and done: a
 * whole refresh, converged when the step was taken from exact sums or the
 * next one would be below tol.  A star moved far: it is redrawn.  The open
 * stars done: all opened again, converged when the next step would be
 * below tol.  Else calm stars settle and the next sums are made. */
static int next_sums(group *G, const mp_fit_opts *o, lm_state *s, int done, int every,
                     int *converged)
{
    if (G->frozen && done) {
        /* Converged from a refreshed state (the step was computed from
         * exact sums there): the same test as unfrozen. */
        int real = s->since == 1 && every;
        if (lm_refresh(G, &s->D, !real, 1))
            return LM_NOMEM;
        s->since = 0;
        s->rphi = 1.0 / sqrt(dispersion(G, s->D));
        *converged = real || step_below_tol(G, s->lambda, s->rphi, o->tol);
        return *converged ? LM_DONE : LM_ON;
    }
    if (lm_render_all(G, G->p, G->cur, RENDER_DERIVS))
        return LM_NOMEM;
    if (G->frozen && lm_moved_far(G)) {
        /* Still frozen (since goes on): only the stars that moved far
         * are redrawn, or every open one. */
        if (o->refresh_movers ? lm_refresh_movers(G, &s->D) : lm_refresh(G, &s->D, 1, 0))
            return LM_NOMEM;
        s->since = o->refresh_movers ? s->since : 0;    /* a whole refresh is exact */
        s->rphi = 1.0 / sqrt(dispersion(G, s->D));
        return LM_ON;
    }
    if (done && !every) {       /* the open stars are done */
        if (open_all(G))
            return LM_NOMEM;
        *converged = step_below_tol(G, s->lambda, s->rphi, o->tol);
        return *converged ? LM_DONE : LM_ON;
    }
    if (!done)
        lm_settle(G, o, s->it);
    if (lm_normal_equations(G, G->p, G->cur, done))
        return LM_NOMEM;
    *converged = done;
    return done ? LM_DONE : LM_ON;
}

/* A step below tol before it is tried: the stopping rule's "the step
 * that would be taken next from exact sums is below tol" tested without
 * rendering the trial — at once on exact sums with every star open, else
 * after a refresh of the frozen wings, every settled star opened again,
 * or exact sums made (47 Tuc 256²: 13 % of the trials, counted by their
 * stars, were steps below tol, half of them refused on D's noise floor
 * and tried again damped). */
static int below_tol_untried(group *G, const mp_fit_opts *o, lm_state *s, int *converged)
{
    if (G->ne_exact && !G->nsettled) {
        *converged = 1;
        return LM_DONE;
    }
    if (G->frozen) {
        if (lm_refresh(G, &s->D, 1, 1))
            return LM_NOMEM;
        s->since = 0;
        s->rphi = 1.0 / sqrt(dispersion(G, s->D));
    } else if (G->nsettled ? open_all(G) : lm_normal_equations(G, G->p, G->cur, NE_EXACT)) {
        return LM_NOMEM;
    }
    s->fresh = 1;
    *converged = step_below_tol(G, s->lambda, s->rphi, o->tol);
    return *converged ? LM_DONE : LM_ON;
}

/* One LM step from G->p at the current damping: solved (more damping
 * when A + λ diag A is not positive definite), bounded, rendered, and
 * taken when it lowers D. */
static int lm_iterate(group *G, const mp_fit_opts *o, lm_state *s, int *converged)
{
    s->trials++;
    int cut = bounded_step(G, s->lambda);
    if (cut < 0) {
        s->lambda *= 10.0;
        return s->lambda > 1e12 ? LM_DONE : LM_ON;
    }
    double z = cut ? INFINITY : step_sigmas(G) * s->rphi, Dt;
    if (z * (1.0 + s->lambda) < o->tol)
        return below_tol_untried(G, o, s, converged);
    if (s->fresh) {
        s->zfirst = z * (1.0 + s->lambda);
        s->lfirst = s->lambda;
    }
    s->fresh = 0;
    if (render_trial(G, 1.0, &Dt))
        return LM_NOMEM;
    if (!(Dt < s->D))
        return step_refused(G, s, converged);
    if (step_length(G, s->D, &Dt, &z))
        return LM_NOMEM;
    s->it++;
    s->since++;
    /* Taken: converged when the step, undamped, was below tol, or when
     * only 1000× damping made progress from a state whose undamped step
     * was within D's resolution (creeping on D's noise floor). */
    int done = z * (1.0 + s->lambda) < o->tol ||
               (s->zfirst < LM_RESOLVE_SIGMAS && s->lambda > 1e3 * s->lfirst * (1.0 - 1e-9));
    int every = !G->nsettled;        /* every star stepped */
    lm_calm_update(G, s->rphi * (1.0 + s->lambda), cut, o->tol);
    step_taken(G, s, Dt);
    int r = next_sums(G, o, s, done, every, converged);
    /* Two stars within the merge radius: the frame fit merges them and
     * fits again, so the loop need not crawl on (issue 12; the sums are
     * exact at the state it ends in). */
    if (r == LM_ON && o->stop_pair > 0 && s->it >= LM_PAIR_AFTER && close_pair(G, o->stop_pair)) {
        G->paired = 1;
        return LM_DONE;
    }
    return r;
}

/* Levenberg–Marquardt from G->p at the current sky order.  A step is taken
 * only when it lowers D.  Converged (*converged = 1) when a step taken
 * with every star open is below tol·σ·√φ in every parameter (φ the
 * dispersion, lm_start; scaled back by 1 + λ, so damping cannot fake it),
 * or the step that would be taken next from exact sums is; or when the
 * first, least damped step tried from the current state was already below
 * LM_RESOLVE_SIGMAS and it took 1000× more damping to lower D, or that did
 * not help either.  Stars whose own steps stay below tol are settled on
 * the way (lm_settle.c) and opened again before any of these tests is
 * final.  Not converged when the damping blows up (λ > 1e8) from a larger
 * step, when it stalls on the sky's bounds (LM_SKY_STALL), when a step
 * from the LM_PAIR_AFTER-th on leaves two stars within o->stop_pair
 * (G->paired), or after maxiter steps; the state is then the best one
 * reached.
 * Accepted steps are added to *iter.  Nonzero: out of memory. */
static int lm_loop(group *G, const mp_fit_opts *o, int freeze_ok, int rose, int *iter,
                   int *converged)
{
    lm_state s;
    *converged = 0;
    if (lm_start(G, freeze_ok, rose, &s))
        return 1;
    int r = LM_ON;
    while (r == LM_ON && s.it < o->maxiter && s.trials < 4 * o->maxiter)
        r = lm_iterate(G, o, &s, converged);
    if (r == LM_NOMEM)
        return 1;
    *iter += s.it;
    /* The covariance and the next sky order start from exact sums on
     * whole windows. */
    if (G->frozen) {
        if ((s.since > 0 || G->nsettled) && lm_refresh(G, &s.D, 0, 1))
            return 1;
        G->frozen = 0;
    }
    lm_unsettle(G, 1);
    if (!G->ne_exact && lm_normal_equations(G, G->p, G->cur, 1))
        return 1;
    return 0;
}

/* A fit that did not converge with frozen wings goes on from its best
 * state without them (with its own maxiter): frozen, a few more fits end
 * unconverged (47 Tuc 256², PSF built from the frame: 38 of 588 stars
 * flagged 8 against 1). */
int lm_levmar(group *G, const mp_fit_opts *o, int rose, int *iter, int *converged)
{
    if (lm_loop(G, o, !o->exact_lm, rose, iter, converged))
        return 1;
    if (*converged || !G->freezing || G->skystall || G->paired)
        return 0;
    if (lm_render_all(G, G->p, G->cur, RENDER_ALL))
        return 1;
    return lm_loop(G, o, 0, 0, iter, converged);
}
