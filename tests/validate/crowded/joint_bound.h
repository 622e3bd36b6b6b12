/* joint_bound.h — each star's Cramér–Rao bound fitted together with its
 * neighbours (issue 13): the bound the crowded-field report divides the
 * errors by, beside the isolated star's performance model. */
#ifndef CROWDED_JOINT_BOUND_H
#define CROWDED_JOINT_BOUND_H

/* A star of the scene: position (1-based pixel centres) and intensity E. */
typedef struct {
    double x, y, flux;
} jb_star;

/* The scene: a Gaussian PSF of standard deviation sigma [px] integrated
 * over pixels (or the stamps below), read noise ron [e-], pixels whose expected value reaches
 * satur masked (the pipeline masks them), fitting radius fitrad [px];
 * mean is the expected image (sky + every star), nx × ny, row-major. */
typedef struct {
    double sigma, ron, satur, fitrad;
    long nx, ny;
    const double *mean;
    /* Optional (NULL: the Gaussian of sigma): any PRF as stamps, star k's
     * at stamp + 3·k·sw², three sw × sw planes (sw odd) centred on the
     * pixel (lround(x), lround(y)): the PRF, its x and its y derivative.
     * Light beyond a stamp is left out of the bound. */
    const double *stamp;
    int sw;
} jb_scene;

/* joint_bounds: for each star t, the bound of (E, X, Y) when t is fitted
 * together with every star whose fitting region overlaps t's (centres
 * within 2·fitrad) and one constant sky, on the union of their fitting
 * regions, from the Fisher matrix F = Σ ∂m/∂p ∂m/∂pᵀ / (mean + ron²) at
 * the true parameters (the variance includes the light of every star).
 * sig_e, sig_x, sig_y receive √diag(F⁻¹) of t's parameters; INFINITY when
 * F is singular (two stars on one spot).  *nmax (may be NULL) receives the
 * largest joint set.  Returns nonzero when out of memory. */
int joint_bounds(const jb_scene *sc, const jb_star *s, int n, double *sig_e, double *sig_x,
                 double *sig_y, int *nmax);

#endif
