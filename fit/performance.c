/* performance.c — the paper's performance model (§2.3.4, §2.4.4) and the
 * exact Cramér–Rao bound it approximates (design.md §6). */
#include <math.h>
#include <stdlib.h>
#include <string.h>
#include "fit/fit.h"
#include "fit/spd.h"

void mp_prf_stats_of(const double *prf, size_t n, mp_prf_stats *s)
{
    double v = 0.0, q = 0.0;
    for (size_t i = 0; i < n; i++) {
        v += prf[i];
        q += prf[i] * prf[i];
    }
    s->volume = v;
    s->beta = q > 0 ? 1.0 / q : 0.0;                   /* eq. (beta) */
    s->sharp = v > 0 ? q / (v * v) : 0.0;              /* eq. (sharpness) */
    s->lscale = s->sharp > 0 ? 1.0 / sqrt(4.0 * M_PI * s->sharp) : 0.0; /* eq. (cssl) */
}

int mp_prf_stats_at(const mp_prf_model *m, double x, double y, mp_prf_stats *s, mp_prf_work *w)
{
    memset(s, 0, sizeof *s);
    long x0, y0;
    int bw, bh;
    mp_prf_box(m, x, y, &x0, &y0, &bw, &bh);
    mp_prf_work own = {0};
    double *p = malloc((size_t)bw * bh * sizeof *p);
    int rc = !p || mp_prf_render(m, x, y, p, NULL, NULL, w ? w : &own);
    if (!rc)
        mp_prf_stats_of(p, (size_t)bw * bh, s);
    free(p);
    mp_prf_work_free(&own);
    return rc;
}

int mp_star_model_errors(const mp_prf_model *m, double ron, mp_star *s, mp_prf_work *w)
{
    if (!isfinite(s->x) || !isfinite(s->y))
        memset(&s->st, 0, sizeof s->st);
    else if (mp_prf_stats_at(m, s->x, s->y, &s->st, w))
        return 1;
    double se, sx, E = s->flux > 1.0 ? s->flux : 1.0;
    mp_perf_model(&s->st, E, s->sky > 0 ? s->sky : 0.0, ron, (double)s->npix, &se, &sx);
    s->fluxerr_model = isfinite(se) ? se : 0.0;
    s->poserr_model = isfinite(sx) ? sx : 0.0;
    return 0;
}

void mp_perf_model(const mp_prf_stats *s, double E, double B, double ron, double npix,
                   double *sigma_e, double *sigma_x)
{
    double var_rms = B + ron * ron;
    double V = s->volume, beta = s->beta, L2 = s->lscale * s->lscale;
    double nfac = npix > 0 ? 1.0 + sqrt(beta / npix) : 1.0;
    double EV = E * V;
    /* eq. (practical-snr): σ_E² = E/V + β(1 + √(β/N))² (B + RON²) */
    double ve = (V > 0 && E > 0 ? E / V : 0.0) + beta * nfac * nfac * var_rms;
    *sigma_e = sqrt(ve);
    /* eq. (practical-astrometric-model-x) */
    if (EV > 0)
        *sigma_x = sqrt(L2 / EV * (1.0 + 8.0 * M_PI * var_rms * L2 / EV));
    else
        *sigma_x = INFINITY;
}

int mp_crlb(const double *prf, const double *dx, const double *dy, size_t n,
            double E, double B, double ron, double sd[4])
{
    double F[16] = {0};
    for (size_t i = 0; i < n; i++) {
        double m = B + E * prf[i];
        double var = (m > 0 ? m : 0) + ron * ron;
        if (!(var > 0))
            continue;
        double g[4] = {prf[i], E * dx[i], E * dy[i], 1.0};
        for (int a = 0; a < 4; a++)
            for (int b = a; b < 4; b++)
                F[a * 4 + b] += g[a] * g[b] / var;
    }
    /* F is symmetric positive definite for any star with light and sky. */
    if (mp_spd_inverse(F, 4) != 0)
        return 1;
    for (int a = 0; a < 4; a++)
        sd[a] = sqrt(F[a * 4 + a]);
    return 0;
}
