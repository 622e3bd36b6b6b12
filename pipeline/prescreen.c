/* prescreen.c — deep detection's first look (issue 13): a candidate found
 * on the residual well below the final cut goes on to the full fit only
 * when a linear fit of its flux and a constant sky, at find's position,
 * reaches a S/N near the cut.  The fit then decides (minsnr); the screen
 * only spares it the thousands of noise peaks a 2-sigma find returns,
 * which in a group each cost a refit (issue 13: threshold 2 without it,
 * 9825 candidates, fit 23 s for one round against 1 s). */
#include <math.h>
#include <stdlib.h>
#include <string.h>
#include "pipeline/pipeline_priv.h"

/* The sums of the linear fit of E·P + B over the pixels within r of
 * (x, y), P rendered on box (rx0, ry0, rw × rh): E and its S/N.  NaN
 * when the window holds too little. */
static double snr_of(const mp_frame *f, const mp_bkg *b, const float *res, double x, double y,
                     double r, const double *prf, long rx0, long ry0, int rw, int rh,
                     unsigned char *in, float *rrow, double *flux)
{
    double spp = 0, sp = 0, s1 = 0, spd = 0, sd = 0;
    for (long j = 0; j < rh; j++) {
        long gy = ry0 + j, lo = rw, hi = -1;       /* 1-based */
        for (long i = 0; i < rw; i++) {
            in[i] = mp_within((double)(rx0 + i) - x, (double)gy - y, r);
            lo = in[i] && i < lo ? i : lo;
            hi = in[i] ? i : hi;
        }
        /* the noise of the row's pixels within r, a span at once */
        if (hi >= lo)
            mp_bkg_rms_span(b, gy - 1, rx0 + lo - 1, rx0 + hi, rrow);
        for (long i = 0; i < rw; i++) {
            long gx = rx0 + i;
            if (!in[i])
                continue;
            size_t k = (size_t)(gy - 1) * (size_t)f->im.nx + (size_t)(gx - 1);
            if (f->mask[k] || !isfinite(res[k]))
                continue;
            float rms = rrow[i - lo];
            if (!(rms > 0))
                continue;
            double w = 1.0 / (rms * rms), p = prf[j * rw + i];
            spp += w * p * p;
            sp += w * p;
            s1 += w;
            spd += w * p * res[k];
            sd += w * res[k];
        }
    }
    double det = spp * s1 - sp * sp;
    *flux = NAN;
    if (!(det > 0) || s1 <= 0)
        return NAN;
    *flux = (s1 * spd - sp * sd) / det;
    return *flux / sqrt(s1 / det);
}

/* Linear weighted fit of E·P + B over the pixels within r of (x, y):
 * E and its σ from the 2×2 normal equations, weights 1/rms².  P from the
 * phase grid when one is given and the fitted E lies within its flux
 * limit gemax (its bias then below the fit's own bound, issue 12: the
 * exact renders were a tenth of a simulated crowded frame's run), else
 * exact.  NaN when the window holds too little. */
/* A thread's room for linear_snr's windows of side × side pixels: the
 * PRF, and a row's noise and pixels within r. */
typedef struct {
    double *prf;
    float *rrow;
    unsigned char *in;
} window_room;

/* The side of linear_snr's window for fitrad on frame f: the pixels within
 * fitrad, clipped to the frame (fitrad may be any size: 100000 asked for
 * 320 GB a thread). */
static long window_side(const mp_frame *f, double fitrad)
{
    long n = f->im.nx > f->im.ny ? f->im.nx : f->im.ny;
    return 2 * (long)ceil(fmin(fitrad, (double)n)) + 3;
}

static int room_alloc(window_room *w, long side)
{
    w->prf = malloc((size_t)(side * side) * sizeof *w->prf);
    w->rrow = malloc((size_t)side * sizeof *w->rrow);
    w->in = malloc((size_t)side);
    return !w->prf || !w->rrow || !w->in;
}

static void room_free(window_room *w)
{
    free(w->prf);
    free(w->rrow);
    free(w->in);
}

static double linear_snr(const mp_frame *f, const mp_bkg *b, const float *res,
                         const mp_prf_model *m, const mp_prf_cache *grid, double gemax,
                         double x, double y, double r, window_room *room, mp_prf_work *wk,
                         double *flux)
{
    double *prf = room->prf;
    long wx0 = (long)ceil(x - r), wy0 = (long)ceil(y - r);
    long wx1 = (long)floor(x + r) + 1, wy1 = (long)floor(y + r) + 1;
    wx0 = wx0 < 1 ? 1 : wx0;
    wy0 = wy0 < 1 ? 1 : wy0;
    wx1 = wx1 > f->im.nx + 1 ? f->im.nx + 1 : wx1;
    wy1 = wy1 > f->im.ny + 1 ? f->im.ny + 1 : wy1;
    *flux = NAN;
    if (wx1 <= wx0 || wy1 <= wy0)
        return NAN;
    double snr = NAN;
    for (int exact = grid == NULL; exact <= 1; exact++) {
        long rx0, ry0;
        int rw, rh;
        wk->grid = exact ? NULL : grid;
        int rc = mp_prf_render_window(m, x, y, wx0, wy0, wx1 - wx0, wy1 - wy0, &rx0, &ry0, &rw,
                                      &rh, prf, NULL, NULL, wk);
        wk->grid = NULL;
        if (rc)
            return NAN;
        snr = snr_of(f, b, res, x, y, r, prf, rx0, ry0, rw, rh, room->in, room->rrow, flux);
        if (!exact && fabs(*flux) <= gemax)
            break;
    }
    return snr;
}

long mp_pl_prescreen(const mp_frame *f, const mp_bkg *b, const float *res,
                     const mp_prf_model *m, double fitrad, double snrmin, mp_table *found)
{
    int fx = mp_table_col(found, "X_IMAGE"), fy = mp_table_col(found, "Y_IMAGE");
    int ff = mp_table_col(found, "FLUX"), fl = mp_table_col(found, "FLAGS");
    if (fx < 0 || fy < 0 || !(snrmin > 0) || found->nrow == 0)
        return 0;
    int fs = mp_table_add_col(found, MP_PL_SNR_COL);
    if (fs < 0)
        return -1;
    long side = window_side(f, fitrad);
    long dropped = 0, nrow = (long)found->nrow;
    int failed = 0;
#pragma omp parallel reduction(+ : dropped) reduction(| : failed)
    {
        mp_prf_work wk = {0};
        window_room room;
        int bad = room_alloc(&room, side);
        failed |= bad;
#pragma omp for schedule(dynamic, 64)
        for (long r = 0; r < nrow; r++) {
            double x = mp_table_get(found, (size_t)r, fx), y = mp_table_get(found, (size_t)r, fy);
            if (bad || !isfinite(x) || !isfinite(y))
                continue;
            double e, snr = linear_snr(f, b, res, m, NULL, 0.0, x, y, fitrad, &room, &wk, &e);
            mp_table_set(found, (size_t)r, fs, snr);
            /* A saturated plateau is a star whatever the screen says: its
             * core is masked, and the first model's shape on the pixels
             * around it can give any S/N (the segmented scene: a −16.7 mag
             * star screened out, its wings found as 14 stars instead). */
            long flags = fl >= 0 ? (long)mp_table_get(found, (size_t)r, fl) : 0;
            int low = isfinite(snr) && snr < snrmin;
            if (low && !(flags & MP_FIND_SATURATED)) {
                mp_table_set(found, (size_t)r, fx, NAN);
                dropped++;
            } else if (low && ff >= 0) {
                /* neither find's plateau flux (a Gaussian's extrapolation:
                 * 1.3e10 e- for that 5e6 e- star) nor that fit's: the
                 * fit's own start (its window's light over the PRF's) */
                mp_table_set(found, (size_t)r, ff, NAN);
            } else if (ff >= 0 && isfinite(e) && e > 0) {
                mp_table_set(found, (size_t)r, ff, e);
            }
        }
        room_free(&room);
        mp_prf_work_free(&wk);
    }
    return failed ? -1 : dropped;
}

int mp_pl_screen_sieve(void *ctx, mp_find_cand *c, size_t n)
{
    mp_pl_screen *sc = ctx;
    long side = window_side(sc->f, sc->fitrad), dropped = 0;
    int failed = 0;
    /* as mp_pl_prescreen does to each row */
#pragma omp parallel reduction(+ : dropped) reduction(| : failed)
    {
        mp_prf_work wk = {0};
        window_room room;
        int bad = room_alloc(&room, side);
        failed |= bad;
#pragma omp for schedule(dynamic, 64)
        for (size_t i = 0; i < n; i++) {
            if (bad || !isfinite(c[i].x) || !isfinite(c[i].y))
                continue;
            double e;
            c[i].snr = linear_snr(sc->f, sc->b, sc->res, sc->m, sc->grid, sc->gemax, c[i].x,
                                  c[i].y, sc->fitrad, &room, &wk, &e);
            if (isfinite(c[i].snr) && c[i].snr < sc->snrmin) {
                c[i].keep = 0;
                dropped++;
            } else if (isfinite(e) && e > 0) {
                c[i].flux = e;
            }
        }
        room_free(&room);
        mp_prf_work_free(&wk);
    }
    sc->dropped += dropped;
    return failed;
}

/* Remove column c of t. */
static void drop_col(mp_table *t, int c)
{
    size_t nc = t->ncol - 1;
    for (size_t r = 0; r < t->nrow; r++)
        for (size_t j = 0; j < nc; j++)
            t->v[r * nc + j] = t->v[r * t->ncol + j + (j >= (size_t)c)];
    memmove(t->cols + c, t->cols + c + 1, (nc - (size_t)c) * sizeof *t->cols);
    t->ncol = nc;
}

void mp_pl_drop_unset(mp_table *t)
{
    int fx = mp_table_col(t, "X_IMAGE"), fs = mp_table_col(t, MP_PL_SNR_COL);
    if (fs >= 0)
        drop_col(t, fs);
    fx = mp_table_col(t, "X_IMAGE");
    if (fx < 0)
        return;
    size_t k = 0;
    for (size_t r = 0; r < t->nrow; r++) {
        if (!isfinite(mp_table_get(t, r, fx)))
            continue;
        if (k != r)
            memmove(t->v + k * t->ncol, t->v + r * t->ncol, t->ncol * sizeof *t->v);
        k++;
    }
    t->nrow = k;
}
