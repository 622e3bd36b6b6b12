/*
 * cases.c — simulate, fit and bound one experiment of design.md §6.
 *
 * Per star: a 60x60 frame from sim.h (Gaussian PRFs integrated exactly over
 * pixels, table PRFs block-summed from the x4 grid; Poisson + Gaussian
 * noise), one mp_fit_group over the whole frame, and, at the truth, the
 * paper's performance model and the exact Cramér–Rao bound of (E, X, Y, B).
 */
#include <math.h>
#include <stdlib.h>
#include <string.h>
#include <time.h>
#include <omp.h>
#include "tests/validate/vt.h"

#define REAL_HALF 80             /* crop: ±20 px · 4 elements around the peak */

static double fwhm_to_sigma(double fwhm)
{
    return fwhm / (2.0 * sqrt(2.0 * log(2.0)));
}

/* Band-limit an n×n table (n odd, OVERSAMP os) in place to |f| ≤ fc
 * cycles per detector pixel along each axis: periodic convolution of every
 * row, then every column, with the Dirichlet kernel of the kept DFT
 * frequencies |u| ≤ U = floor(fc·n/os), i.e. the ideal low-pass of the
 * table's DFT.  Nonzero when out of memory. */
static int band_limit(double *t, int n, int os, double fc)
{
    int U = (int)floor(fc * n / os);
    double *d = malloc((size_t)n * sizeof *d), *line = malloc((size_t)n * sizeof *line);
    if (!d || !line) {
        free(d);
        free(line);
        return 1;
    }
    /* D[k] = (1/n) Σ_{|u|≤U} cos(2πuk/n) */
    for (int k = 0; k < n; k++) {
        double v = 1.0;
        for (int u = 1; u <= U; u++)
            v += 2.0 * cos(2.0 * M_PI * u * k / n);
        d[k] = v / n;
    }
    for (int axis = 0; axis < 2; axis++)
        for (int r = 0; r < n; r++) {
            size_t step = axis ? (size_t)n : 1, base = axis ? (size_t)r : (size_t)r * n;
            for (int i = 0; i < n; i++) {
                double v = 0.0;
                for (int k = 0; k < n; k++)
                    v += t[base + step * (size_t)((i - k + n) % n)] * d[k];
                line[i] = v;
            }
            for (int i = 0; i < n; i++)
                t[base + step * (size_t)i] = line[i];
        }
    free(d);
    free(line);
    return 0;
}

int vt_inputs_load(vt_inputs *in, const char *realpath, char *err)
{
    memset(in, 0, sizeof *in);
    in->realpath = realpath;
    /* The gate-structure DRF of paper §5.7: first row and first column of
     * the 4x4 subpixels dead, the rest QE 1 (V = 9/16). */
    for (int j = 0; j < 4; j++)
        for (int i = 0; i < 4; i++)
            in->gate_qe[j * 4 + i] = (i == 0 || j == 0) ? 0.0 : 1.0;
    in->gate.k = 4;
    in->gate.qe = in->gate_qe;
    in->gate.volume = 0.5625;

    FILE *fp = fopen(realpath, "rb");
    if (!fp) {
        snprintf(in->real_note, sizeof in->real_note,
                 "%s is absent: the ugly-PSF and ugly-detector cases are skipped", realpath);
        return 0;
    }
    fclose(fp);
    /* 582x582 (even), x4, peak at 1-based (292,292): the section [2:582,2:582]
     * is 581x581 with the peak at its centre element. */
    char name[4096];
    snprintf(name, sizeof name, "%s[2:582,2:582]", realpath);
    mp_image im = {0};
    if (mp_image_read(name, &im, err))
        return 1;
    if (im.nx != 581 || im.ny != 581) {
        snprintf(err, MP_ERRLEN, "%.400s: section is %ldx%ld, expected 581x581", name, im.nx, im.ny);
        mp_image_free(&im);
        return 1;
    }
    long c = 290, pk = 0;
    for (long i = 1; i < im.nx * im.ny; i++)
        if (im.pix[i] > im.pix[pk])
            pk = i;
    int n = 2 * REAL_HALF + 1;
    double *t = malloc((size_t)n * n * sizeof *t);
    if (!t) {
        snprintf(err, MP_ERRLEN, "out of memory");
        mp_image_free(&im);
        return 1;
    }
    double full = 0.0, sum = 0.0;
    for (long i = 0; i < im.nx * im.ny; i++)
        full += im.pix[i];
    for (int j = 0; j < n; j++)
        for (int i = 0; i < n; i++) {
            double v = im.pix[(size_t)(c - REAL_HALF + j) * im.nx + (size_t)(c - REAL_HALF + i)];
            if (!isfinite(v)) {
                snprintf(err, MP_ERRLEN, "%.400s: NaN in the PSF table", name);
                free(t);
                mp_image_free(&im);
                return 1;
            }
            t[(size_t)j * n + i] = v;
            sum += v;
        }
    in->real4.kind = MP_PSF_TABLE;
    in->real4.nx = in->real4.ny = n;
    in->real4.os = 4;
    in->real4.t = t;
    in->real4.sum = sum;
    snprintf(in->real_note, sizeof in->real_note,
             "%.300s read with the section [2:582,2:582] (581x581, peak at element (%ld,%ld) 0-based, expected (290,290)); "
             "cropped to the central %dx%d elements (±%d px), OVERSAMP 4; it holds %.5f of the "
             "light of the 581x581 section (sum %.5f)", realpath, pk % im.nx, pk / im.nx,
             n, n, REAL_HALF / 4, sum / full, full);
    mp_image_free(&im);
    if (mp_psf_rebin(&in->real4, 2, &in->real2, err))
        return 1;
    in->shift2 = in->real2.offset;
    /* Case 7's truth: the same table without its power above 1 cycle/px,
     * the x2 table's Nyquist frequency.  HST's optics pass nothing above
     * D/λ ≈ 0.6–0.7 cycle per HRC pixel across F606W, so that power is
     * not the telescope's (tests/unit/test_table_sampling.c: it is what
     * biases x2 fits at half-element phases). */
    size_t nt = (size_t)in->real4.nx * (size_t)in->real4.ny;
    in->real4bl = in->real4;
    in->real4bl.t = malloc(nt * sizeof *in->real4bl.t);
    if (!in->real4bl.t) {
        snprintf(err, MP_ERRLEN, "out of memory");
        return 1;
    }
    memcpy(in->real4bl.t, in->real4.t, nt * sizeof *in->real4bl.t);
    if (band_limit(in->real4bl.t, in->real4bl.nx, 4, 1.0)) {
        snprintf(err, MP_ERRLEN, "out of memory");
        return 1;
    }
    double rem = 0.0;
    for (size_t i = 0; i < nt; i++)
        rem += (in->real4.t[i] - in->real4bl.t[i]) * (in->real4.t[i] - in->real4bl.t[i]);
    in->bl_removed = rem;
    if (mp_psf_rebin(&in->real4bl, 2, &in->real2bl, err))
        return 1;
    in->have_real = 1;
    return 0;
}

void vt_inputs_free(vt_inputs *in)
{
    mp_psf_free(&in->real4);
    mp_psf_free(&in->real2);
    mp_psf_free(&in->real4bl);
    mp_psf_free(&in->real2bl);
}

/* The biggest negative side lobe of the 1x FWHM 1.5 table shifted by half a
 * pixel with the fitter's damped sinc (paper Fig. 8: about -0.0006). */
double vt_side_lobe(double *row_min, char *err)
{
    mp_psf p;
    if (mp_psf_gauss_table(1.5, 1, 15.0, &p, err))
        return NAN;
    size_t n = (size_t)p.nx * p.ny;
    double *out = malloc(n * sizeof *out), *tmp = malloc(n * sizeof *tmp);
    double mn = NAN;
    if (out && tmp) {
        mp_shift_table(p.t, p.nx, p.ny, 0.5, 0.0, 10, out, tmp);
        mn = INFINITY;
        *row_min = INFINITY;
        int cy = (p.ny - 1) / 2;
        for (size_t i = 0; i < n; i++)
            mn = fmin(mn, out[i]);
        for (int i = 0; i < p.nx; i++)
            *row_min = fmin(*row_min, out[(size_t)cy * p.nx + i]);
    } else {
        snprintf(err, MP_ERRLEN, "out of memory");
    }
    free(out);
    free(tmp);
    mp_psf_free(&p);
    return mn;
}

static double thread_cpu(void)
{
    struct timespec ts;
    clock_gettime(CLOCK_THREAD_CPUTIME_ID, &ts);
    return (double)ts.tv_sec + 1e-9 * (double)ts.tv_nsec;
}

static double wall_now(void)
{
    struct timespec ts;
    clock_gettime(CLOCK_MONOTONIC, &ts);
    return (double)ts.tv_sec + 1e-9 * (double)ts.tv_nsec;
}

/* Per-thread scratch. */
typedef struct {
    float *img;            /* the frame (io.h: single precision) */
    double *P, *DX, *DY, *bp, *bx, *by;
    uint8_t *mask;
    mp_prf_work w;
} scratch;

static void scratch_free(scratch *s)
{
    free(s->img);
    free(s->P);
    free(s->DX);
    free(s->DY);
    free(s->bp);
    free(s->bx);
    free(s->by);
    free(s->mask);
    mp_prf_work_free(&s->w);
}

static int scratch_alloc(scratch *s, size_t cap)
{
    memset(s, 0, sizeof *s);
    s->img = malloc(VT_NPIX * sizeof *s->img);
    s->P = malloc(VT_NPIX * sizeof *s->P);
    s->DX = malloc(VT_NPIX * sizeof *s->DX);
    s->DY = malloc(VT_NPIX * sizeof *s->DY);
    s->bp = malloc(cap * sizeof *s->bp);
    s->bx = malloc(cap * sizeof *s->bx);
    s->by = malloc(cap * sizeof *s->by);
    s->mask = calloc(VT_NPIX, 1);
    if (!s->img || !s->P || !s->DX || !s->DY || !s->bp || !s->bx || !s->by || !s->mask) {
        scratch_free(s);
        return 1;
    }
    return 0;
}

/* The truth PRF of a star at (x, y) and its derivatives, pasted into the
 * whole 60x60 frame (zero outside the model's box). */
static int truth_prf(const mp_prf_model *m, double x, double y, size_t cap, scratch *s)
{
    long x0, y0;
    int w, h;
    mp_prf_box(m, x, y, &x0, &y0, &w, &h);
    if ((size_t)w * h > cap)
        return 1;
    if (mp_prf_render(m, x, y, s->bp, s->bx, s->by, &s->w))
        return 1;
    memset(s->P, 0, VT_NPIX * sizeof *s->P);
    memset(s->DX, 0, VT_NPIX * sizeof *s->DX);
    memset(s->DY, 0, VT_NPIX * sizeof *s->DY);
    for (int j = 0; j < h; j++) {
        long Y = y0 + j;
        if (Y < 1 || Y > VT_NX)
            continue;
        for (int i = 0; i < w; i++) {
            long X = x0 + i;
            if (X < 1 || X > VT_NX)
                continue;
            size_t o = (size_t)(Y - 1) * VT_NX + (size_t)(X - 1), b = (size_t)j * w + i;
            s->P[o] = s->bp[b];
            s->DX[o] = s->bx[b];
            s->DY[o] = s->by[b];
        }
    }
    return 0;
}


/* qsort comparator for doubles. */
static int cmp_double(const void *a, const void *b)
{
    double x = *(const double *)a, y = *(const double *)b;
    return (x > y) - (x < y);
}

#define NB_POS 16                /* x4-grid phases of one pixel: 4 per axis */
#define NB_MAG 3                 /* magnitudes per bin: midpoints of thirds */
#define NB_DRAWS 200000          /* Monte Carlo draws per bin */

/* Model adequacy of a table-truth case (issue 2): fit noiseless frames —
 * the simulator's star at each of the 16 x4-grid phases of a pixel, at
 * three magnitudes per bin, no noise — with the case's own fit model and
 * options, and express the position errors in CRLB sigmas at the truth.
 * Any error here is the fitted model's, not the noise's.  The astro/CRLB
 * ratio it implies is the median of |bias + N(0, CRLB)| / σ_r / 1.1774
 * over the phases, magnitudes and noise (fixed-seed Monte Carlo), the
 * statistic of the bin tables.  Nonzero when out of memory or a fit fails. */
static int noiseless_bias(const vt_case *c, const mp_sim_prf *sp, const mp_prf_model *fit,
                          const mp_prf_model *truth, const mp_fit_opts *opts, size_t cap,
                          vt_result *r)
{
    enum { NP = NB_POS * NB_MAG };
    double bx[VT_NBIN][NP], by[VT_NBIN][NP], sx[VT_NBIN][NP], sy[VT_NBIN][NP];
    int used[VT_NBIN] = {0}, bad = 0;
    for (int b = 0; b < VT_NBIN; b++) {
        double cen = vt_bin_centre(b);
        used[b] = c->mag_lo == c->mag_hi ? vt_bin_index(c->mag_lo) == b
                                         : cen + 0.5 > c->mag_lo && cen - 0.5 < c->mag_hi;
    }
#pragma omp parallel
    {
        scratch s;
        int mybad = scratch_alloc(&s, cap);
        mp_frame fr;
        memset(&fr, 0, sizeof fr);
        fr.im.nx = fr.im.ny = VT_NX;
        fr.im.pix = s.img;
        fr.mask = s.mask;
        fr.gain = 1.0;
        fr.rdnoise = VT_RON;
        fr.saturate = INFINITY;
        fr.exptime = 1.0;
        char ferr[MP_ERRLEN];
#pragma omp for schedule(dynamic, 4) collapse(2)
        for (int b = 0; b < VT_NBIN; b++)
            for (int k = 0; k < NP; k++) {
                int p = k % NB_POS, q = k / NB_POS;
                if (mybad || !used[b] || (c->mag_lo == c->mag_hi && q > 0))
                    continue;
                double mag = c->mag_lo == c->mag_hi
                                 ? c->mag_lo
                                 : vt_bin_centre(b) - 1.0 / 3.0 + q / 3.0;
                double x = 30.125 + 0.25 * (p % 4), y = 30.125 + 0.25 * (p / 4);
                double E = pow(10.0, -0.4 * mag);
                for (int i = 0; i < VT_NPIX; i++)
                    s.img[i] = c->sky;
                mp_star st;
                memset(&st, 0, sizeof st);
                st.x = x + 0.05;
                st.y = y - 0.03;
                st.flux = NAN;
                double sd[4];
                if (mp_sim_add_star_float(sp, x, y, E, s.img, VT_NX, VT_NX) ||
                    mp_fit_group(&fr, fit, opts, NAN, &st, 1, ferr) ||
                    truth_prf(truth, x, y, cap, &s) ||
                    mp_crlb(s.P, s.DX, s.DY, VT_NPIX, E, c->sky, VT_RON, sd)) {
                    mybad = 1;
                    continue;
                }
                bx[b][k] = st.x - x;
                by[b][k] = st.y - y;
                sx[b][k] = sd[1];
                sy[b][k] = sd[2];
            }
        if (mybad) {
#pragma omp atomic write
            bad = 1;
        }
        scratch_free(&s);
    }
    if (bad)
        return 1;
    double *v = malloc(NB_DRAWS * sizeof *v);
    if (!v)
        return 1;
    mp_rng rng;
    mp_rng_seed(&rng, 20261122ULL);
    for (int b = 0; b < VT_NBIN; b++) {
        r->nb_x[b] = r->nb_xmax[b] = r->nb_y[b] = r->nb_ymax[b] = r->nb_ratio[b] = NAN;
        if (!used[b])
            continue;
        int np = c->mag_lo == c->mag_hi ? NB_POS : NP;
        double mx = 0, my = 0, wx = 0, wy = 0;
        for (int k = 0; k < np; k++) {
            double zx = bx[b][k] / sx[b][k], zy = by[b][k] / sy[b][k];
            mx += zx / np;
            my += zy / np;
            wx = fmax(wx, fabs(zx));
            wy = fmax(wy, fabs(zy));
        }
        for (int i = 0; i < NB_DRAWS; i++) {
            int k = (int)(np * mp_rng_uniform(&rng));
            double ex = bx[b][k] + sx[b][k] * mp_rng_normal(&rng);
            double ey = by[b][k] + sy[b][k] * mp_rng_normal(&rng);
            v[i] = sqrt((ex * ex + ey * ey) / (0.5 * (sx[b][k] * sx[b][k] + sy[b][k] * sy[b][k])));
        }
        qsort(v, NB_DRAWS, sizeof *v, cmp_double);
        r->nb_x[b] = mx;
        r->nb_y[b] = my;
        r->nb_xmax[b] = wx;
        r->nb_ymax[b] = wy;
        r->nb_ratio[b] = 0.5 * (v[NB_DRAWS / 2 - 1] + v[NB_DRAWS / 2]) / 1.1774;
    }
    free(v);
    r->nb_u = 0.721 / sqrt((double)NB_DRAWS);
    r->have_nb = 1;
    return 0;
}

int vt_run_case(const vt_case *c, const vt_inputs *in, int n, int seedset, int verbose,
                vt_result *r, char *err)
{
    memset(r, 0, sizeof *r);
    r->c = c;
    if (c->real && !in->have_real) {
        r->skipped = 1;
        snprintf(r->note, sizeof r->note, "skipped: %s", in->real_note);
        return 0;
    }
    r->n = c->half_n ? n / 2 : n;
    /* Seed set S (option -seed) moves every case to fresh frames. */
    r->seed0 = ((uint64_t)c->simset + 16ULL * (uint64_t)seedset) * VT_SEED_STRIDE;
    r->s = calloc((size_t)r->n, sizeof *r->s);
    if (!r->s) {
        snprintf(err, MP_ERRLEN, "%s: out of memory", c->id);
        return 1;
    }

    /* Simulation, fit model and truth model. */
    mp_sim_prf sp;
    memset(&sp, 0, sizeof sp);
    mp_psf gpsf, fpsf;
    memset(&gpsf, 0, sizeof gpsf);
    memset(&fpsf, 0, sizeof fpsf);
    mp_drf udrf;
    mp_drf_uniform(c->volume, &udrf);
    mp_prf_model fit = {0}, truth = {0};
    fit.sinc_hw = truth.sinc_hw = 10;
    if (c->real) {
        /* The x2 case's truth is the band-limited table (vt_inputs_load). */
        const mp_psf *t4 = c->fit == VT_FIT_REAL2 ? &in->real4bl : &in->real4;
        sp.kind = MP_SIM_TABLE;
        sp.tab = t4->t;
        sp.tnx = t4->nx;
        sp.tny = t4->ny;
        sp.tos = t4->os;
        sp.volume = 1.0;
        if (c->gate_drf) {
            sp.drf = in->gate_qe;
            sp.dk = 4;
            truth.drf = &in->gate;
        }
        truth.psf = t4;
        if (c->fit == VT_FIT_REAL2) {
            /* The x2 table's star sits in->shift2 px from its central element;
             * the engine accounts for mp_psf.offset, so positions are true. */
            fit.psf = &in->real2bl;
        } else {
            fit.psf = &in->real4;
        }
        fit.drf = truth.drf;
    } else {
        sp.kind = MP_SIM_GAUSS;
        sp.sigma = fwhm_to_sigma(c->fwhm);
        sp.volume = c->volume;
        mp_psf_gauss(c->fwhm, &gpsf);
        truth.psf = &gpsf;
        truth.drf = c->volume != 1.0 ? &udrf : NULL;
        fit.drf = truth.drf;
        if (c->fit == VT_FIT_ANALYTIC) {
            fit.psf = &gpsf;
        } else {
            if (mp_psf_gauss_table(c->fwhm, c->fit_os, 15.0, &fpsf, err))
                return 1;
            fit.psf = &fpsf;
        }
    }
    r->shift_px = fit.psf->offset;
    r->tab_sum = fit.psf->sum;

    long bx0, by0;
    int bw, bh;
    mp_prf_box(&truth, 30.5, 30.5, &bx0, &by0, &bw, &bh);
    size_t cap = (size_t)(bw + 2) * (size_t)(bh + 2);

    mp_fit_opts opts;
    mp_fit_opts_default(&opts);
    double t0 = wall_now();
    int bad = 0;
    char terr[MP_ERRLEN] = "";

#pragma omp parallel
    {
        scratch s;
        int mybad = scratch_alloc(&s, cap);
        if (mybad) {
#pragma omp atomic write
            bad = 1;
        }
        mp_frame fr;
        memset(&fr, 0, sizeof fr);
        fr.im.nx = fr.im.ny = VT_NX;
        fr.im.pix = s.img;
        fr.mask = s.mask;
        fr.gain = 1.0;
        fr.rdnoise = VT_RON;
        fr.saturate = INFINITY;
        fr.exptime = 1.0;
        char ferr[MP_ERRLEN];

#pragma omp for schedule(dynamic, 8)
        for (int k = 0; k < r->n; k++) {
            if (mybad)
                continue;
            vt_star *o = &r->s[k];
            mp_rng rng;
            mp_rng_seed(&rng, r->seed0 + (uint64_t)k);
            /* Draw order is fixed so cases of one simset share their frames. */
            double u = mp_rng_uniform(&rng);
            double mag = c->mag_lo == c->mag_hi ? c->mag_lo : c->mag_lo + (c->mag_hi - c->mag_lo) * u;
            double x = 30.5 + (mp_rng_uniform(&rng) - 0.5);
            double y = 30.5 + (mp_rng_uniform(&rng) - 0.5);
            mp_sim_snap(&sp, &x, &y);
            double dx0 = 0.5 * mp_rng_uniform(&rng) - 0.25;
            double dy0 = 0.5 * mp_rng_uniform(&rng) - 0.25;
            double E = pow(10.0, -0.4 * mag);
            for (int i = 0; i < VT_NPIX; i++)
                s.img[i] = c->sky;
            if (mp_sim_add_star_float(&sp, x, y, E, s.img, VT_NX, VT_NX)) {
                o->rc = -1;
                continue;
            }
            mp_sim_add_noise_float(&rng, s.img, VT_NPIX, VT_RON);

            mp_star st;
            memset(&st, 0, sizeof st);
            st.x = x + dx0;
            st.y = y + dy0;
            st.flux = NAN;
            double c0 = thread_cpu();
            o->rc = mp_fit_group(&fr, &fit, &opts, NAN, &st, 1, ferr);
            o->cpu = thread_cpu() - c0;
            if (o->rc) {
#pragma omp critical(vt_err)
                snprintf(terr, sizeof terr, "%s", ferr);
            }
            o->mag = mag;
            o->e_true = E;
            o->x_true = x;
            o->y_true = y;
            o->e = st.flux;
            o->x = st.x;
            o->y = st.y;
            o->ee = st.eflux;
            o->ex = st.ex;
            o->ey = st.ey;
            o->sky = st.sky;
            o->chi2 = st.chi2;
            o->dof = st.dof;
            o->niter = st.niter;
            o->flags = st.flags;
            o->vol_fit = st.st.volume;

            /* Predictions at the truth: the exact pixel-integrated model of
             * the truth (table truth: the x4 table at its own grid, shift 0). */
            if (truth_prf(&truth, x, y, cap, &s)) {
                o->rc = -2;
                continue;
            }
            mp_prf_stats pst;
            mp_prf_stats_of(s.P, VT_NPIX, &pst);
            o->beta = pst.beta;
            o->volume = pst.volume;
            o->lscale = pst.lscale;
            mp_perf_model(&pst, E, c->sky, VT_RON, VT_NPIX, &o->se_model, &o->sx_model);
            double sd[4];
            if (mp_crlb(s.P, s.DX, s.DY, VT_NPIX, E, c->sky, VT_RON, sd)) {
                o->se_crlb = o->sx_crlb = o->sy_crlb = NAN;
            } else {
                o->se_crlb = sd[0];
                o->sx_crlb = sd[1];
                o->sy_crlb = sd[2];
            }
        }
        scratch_free(&s);
    }
    mp_psf_free(&fpsf);
    r->wall = wall_now() - t0;
    if (bad) {
        snprintf(err, MP_ERRLEN, "%s: out of memory for the per-thread buffers", c->id);
        return 1;
    }
    for (int k = 0; k < r->n; k++) {
        if (r->s[k].rc == -1) {
            snprintf(err, MP_ERRLEN, "%s: the simulator refused star %d", c->id, k);
            return 1;
        }
        if (r->s[k].rc == -2) {
            snprintf(err, MP_ERRLEN, "%s: rendering the truth PRF failed (star %d)", c->id, k);
            return 1;
        }
        if (r->s[k].rc)
            r->nfail_rc++;
    }
    if (r->nfail_rc)
        snprintf(r->note, sizeof r->note, "%d fits returned an error, e.g. \"%s\"",
                 r->nfail_rc, terr);
    /* Issue 2: what the fitted table itself contributes, for the Tiny Tim
     * truths (the tables in question; 1-3 s of noiseless fits). */
    if (c->real && noiseless_bias(c, &sp, &fit, &truth, &opts, cap, r)) {
        snprintf(err, MP_ERRLEN, "%s: the noiseless fits failed", c->id);
        return 1;
    }
    r->ran = 1;
    if (verbose)
        fprintf(stderr, "validate: %-22s %6d stars  %7.1f s wall\n", c->id, r->n, r->wall);
    return 0;
}
