/*
 * scenes.c — the fixed simulated scenes of the sweep and the Cramér–Rao
 * bound of every star (computed as tests/validate/cases.c does: the exact
 * pixel-integrated truth PRF and its derivatives on a 60x60 frame, then
 * mp_crlb for E, X, Y and a constant sky B).
 *
 *  isolated      60x60 single-star frames, Gaussian FWHM 3, fitted with a
 *                2x discrete table (and its 1x block-sum)
 *  undersampled  the same with FWHM 1.5
 *  ugly          the Tiny Tim ACS/HRC x4 table (cropped to ±20 px) as truth
 *                on its own grid, fitted at x4, x2, x1 (mp_psf_rebin)
 *  crowded       one frame, 1500 stars on 512x512 (the same density for
 *                other N), Gaussian FWHM 3, 2x table; the CRLB of each star
 *                as if it were alone on a 60x60 frame
 *
 * Every scene: magnitudes uniform over [-15, -6), sky 100 e-/px, read noise
 * 3 e-, Poisson + Gaussian noise (sim.h), start position = truth +
 * U(-0.25, 0.25) px per axis, fixed seeds.
 */
#include <math.h>
#include <stdlib.h>
#include <string.h>
#include "tests/bench/sweep/sw.h"

#define REAL_HALF 80             /* Tiny Tim crop: ±20 px · 4 elements */
#define CROWD_N 1500             /* stars on ... */
#define CROWD_SIDE 512           /* ... a frame of this side */
#define CROWD_MARGIN 12.0        /* stars kept this far from the frame's edge [px] */
#define CROWD_FLUX_SCATTER 0.2   /* start flux = truth · exp(0.2 N(0,1)), as a detection's */

static double fwhm_to_sigma(double fwhm)
{
    return fwhm / (2.0 * sqrt(2.0 * log(2.0)));
}

/* The Tiny Tim x4 table as tests/validate/cases.c reads it: the section
 * [2:582,2:582] (581x581, peak at its centre element), cropped to the
 * central 161x161 elements (±20 px), OVERSAMP 4.  1 = absent (note says so). */
static int load_real(const char *path, mp_psf *p, char *note, size_t nn, char *err)
{
    FILE *fp = fopen(path, "rb");
    if (!fp) {
        snprintf(note, nn, "the Tiny Tim x4 table %s is absent", path);
        return 1;
    }
    fclose(fp);
    char name[4096];
    snprintf(name, sizeof name, "%s[2:582,2:582]", path);
    mp_image im;
    memset(&im, 0, sizeof im);
    if (mp_image_read(name, &im, err))
        return -1;
    if (im.nx != 581 || im.ny != 581) {
        snprintf(err, MP_ERRLEN, "%.400s: section is %ldx%ld, expected 581x581", name, im.nx, im.ny);
        mp_image_free(&im);
        return -1;
    }
    long c = 290;
    int n = 2 * REAL_HALF + 1;
    double *t = malloc((size_t)n * n * sizeof *t);
    if (!t) {
        snprintf(err, MP_ERRLEN, "out of memory");
        mp_image_free(&im);
        return -1;
    }
    double sum = 0.0;
    for (int j = 0; j < n; j++)
        for (int i = 0; i < n; i++) {
            double v = im.pix[(size_t)(c - REAL_HALF + j) * im.nx + (size_t)(c - REAL_HALF + i)];
            if (!isfinite(v)) {
                snprintf(err, MP_ERRLEN, "%.400s: NaN in the PSF table", name);
                free(t);
                mp_image_free(&im);
                return -1;
            }
            t[(size_t)j * n + i] = v;
            sum += v;
        }
    mp_image_free(&im);
    memset(p, 0, sizeof *p);
    p->kind = MP_PSF_TABLE;
    p->nx = p->ny = n;
    p->os = 4;
    p->t = t;
    p->sum = sum;
    snprintf(note, nn, "%.300s[2:582,2:582] cropped to the central %dx%d elements (±%d px), "
             "OVERSAMP 4, sum %.5f", path, n, n, REAL_HALF / 4, sum);
    return 0;
}

/* 1/sharpness of the table's PRF at a pixel centre (fit/setup.c's rule). */
static double beta_norm(const mp_psf *p)
{
    mp_prf_model m = {p, NULL, 10};
    long x0, y0;
    int w, h;
    mp_prf_box(&m, 1000.0, 1000.0, &x0, &y0, &w, &h);
    double *v = malloc((size_t)w * h * sizeof *v);
    mp_prf_work wk = {0};
    double b = 0.0;
    if (v && !mp_prf_render(&m, 1000.0, 1000.0, v, NULL, NULL, &wk)) {
        mp_prf_stats st;
        mp_prf_stats_of(v, (size_t)w * h, &st);
        b = st.sharp > 0 ? 1.0 / st.sharp : 0.0;
    }
    free(v);
    mp_prf_work_free(&wk);
    return b;
}

/* Scratch for the bound: the truth PRF and derivatives on a 60x60 frame. */
typedef struct {
    double *P, *DX, *DY, *bp, *bx, *by;
    size_t cap;
    mp_prf_work w;
} crlb_work;

static void crlb_free(crlb_work *c)
{
    free(c->P);
    free(c->DX);
    free(c->DY);
    free(c->bp);
    free(c->bx);
    free(c->by);
    mp_prf_work_free(&c->w);
}

static int crlb_alloc(crlb_work *c, const mp_prf_model *m)
{
    memset(c, 0, sizeof *c);
    long x0, y0;
    int w, h;
    mp_prf_box(m, 30.5, 30.5, &x0, &y0, &w, &h);
    c->cap = (size_t)(w + 2) * (size_t)(h + 2);
    c->P = malloc(SW_NPIX * sizeof *c->P);
    c->DX = malloc(SW_NPIX * sizeof *c->DX);
    c->DY = malloc(SW_NPIX * sizeof *c->DY);
    c->bp = malloc(c->cap * sizeof *c->bp);
    c->bx = malloc(c->cap * sizeof *c->bx);
    c->by = malloc(c->cap * sizeof *c->by);
    if (!c->P || !c->DX || !c->DY || !c->bp || !c->bx || !c->by) {
        crlb_free(c);
        return 1;
    }
    return 0;
}

/* CRLB of a star of E electrons at (x, y) of a 60x60 frame (x, y within
 * the central pixels): sigma_E and sigma_X = sqrt((sX^2 + sY^2)/2). */
static int crlb_at(const mp_prf_model *m, double x, double y, double E, crlb_work *c,
                   double *se, double *sx)
{
    long x0, y0;
    int w, h;
    mp_prf_box(m, x, y, &x0, &y0, &w, &h);
    if ((size_t)w * h > c->cap || mp_prf_render(m, x, y, c->bp, c->bx, c->by, &c->w))
        return 1;
    memset(c->P, 0, SW_NPIX * sizeof *c->P);
    memset(c->DX, 0, SW_NPIX * sizeof *c->DX);
    memset(c->DY, 0, SW_NPIX * sizeof *c->DY);
    for (int j = 0; j < h; j++) {
        long Y = y0 + j;
        if (Y < 1 || Y > SW_NX)
            continue;
        for (int i = 0; i < w; i++) {
            long X = x0 + i;
            if (X < 1 || X > SW_NX)
                continue;
            size_t o = (size_t)(Y - 1) * SW_NX + (size_t)(X - 1), b = (size_t)j * w + i;
            c->P[o] = c->bp[b];
            c->DX[o] = c->bx[b];
            c->DY[o] = c->by[b];
        }
    }
    double sd[4];
    if (mp_crlb(c->P, c->DX, c->DY, SW_NPIX, E, SW_SKY, SW_RON, sd)) {
        *se = *sx = NAN;
        return 0;
    }
    *se = sd[0];
    *sx = sqrt(0.5 * (sd[1] * sd[1] + sd[2] * sd[2]));
    return 0;
}

void sw_scene_free(sw_scene *sc)
{
    for (int k = 0; k < SW_MAXTAB; k++)
        mp_psf_free(&sc->tab[k]);
    mp_drf_free(&sc->drf);
    free(sc->img);
    free(sc->t);
    memset(sc, 0, sizeof *sc);
}

/* Coarser samplings of tab[0]: every os/k for k dividing os. */
static int add_rebins(sw_scene *sc, char *err)
{
    int os = sc->tab[0].os;
    sc->ntab = 1;
    for (int f = 2; f <= os && sc->ntab < SW_MAXTAB; f++) {
        if (os % f)
            continue;
        if (mp_psf_rebin(&sc->tab[0], f, &sc->tab[sc->ntab], err))
            return 1;
        sc->ntab++;
    }
    /* The knob sweep's default table: x1 when beta >= 21 at detector
     * sampling (paper 5.4), economy=yes's one table before issue 10; it
     * now chooses per group by a measured bound (fit/ss_choice.c), which
     * the Economy section (econ.c) measures, beside this rule. */
    sc->beta_norm = beta_norm(&sc->tab[0]);
    sc->def_tab = 0;
    if (os > 1 && sc->beta_norm >= 21.0 && sc->drf.k == 0)
        for (int k = 0; k < sc->ntab; k++)
            if (sc->tab[k].os == 1)
                sc->def_tab = k;
    return 0;
}

/* Truth, noise and bound of the single-star frames. */
static int build_single(sw_scene *sc, const mp_sim_prf *sp, const mp_prf_model *truth, char *err)
{
    sc->fnx = sc->fny = SW_NX;
    sc->img = malloc((size_t)sc->n * SW_NPIX * sizeof *sc->img);
    sc->t = calloc((size_t)sc->n, sizeof *sc->t);
    crlb_work cw;
    if (!sc->img || !sc->t || crlb_alloc(&cw, truth)) {
        snprintf(err, MP_ERRLEN, "%s: out of memory for %d frames", sc->name, sc->n);
        return 1;
    }
    int rc = 0;
    for (int k = 0; k < sc->n && !rc; k++) {
        mp_rng r;
        mp_rng_seed(&r, sc->seed + (uint64_t)k);
        sw_truth *t = &sc->t[k];
        t->mag = SW_MAG_LO + (SW_MAG_HI - SW_MAG_LO) * mp_rng_uniform(&r);
        t->x = 30.5 + (mp_rng_uniform(&r) - 0.5);
        t->y = 30.5 + (mp_rng_uniform(&r) - 0.5);
        mp_sim_snap(sp, &t->x, &t->y);
        t->x0 = t->x + 0.5 * mp_rng_uniform(&r) - 0.25;
        t->y0 = t->y + 0.5 * mp_rng_uniform(&r) - 0.25;
        t->e = pow(10.0, -0.4 * t->mag);
        float *img = sc->img + (size_t)k * SW_NPIX;
        for (int i = 0; i < SW_NPIX; i++)    /* sky: a plane through SW_SKY at the centre */
            img[i] = SW_SKY + sc->gx * (i % SW_NX + 1 - 30.5) + sc->gy * (i / SW_NX + 1 - 30.5);
        if (mp_sim_add_star_float(sp, t->x, t->y, t->e, img, SW_NX, SW_NX)) {
            snprintf(err, MP_ERRLEN, "%s: the simulator refused star %d", sc->name, k);
            rc = 1;
            break;
        }
        mp_sim_add_noise_float(&r, img, SW_NPIX, SW_RON);
        /* Drawn last, so the frames are those of the sweep before it. */
        t->f0 = t->e * exp(CROWD_FLUX_SCATTER * mp_rng_normal(&r));
        if (crlb_at(truth, t->x, t->y, t->e, &cw, &t->se, &t->sx)) {
            snprintf(err, MP_ERRLEN, "%s: rendering the truth PRF failed (star %d)", sc->name, k);
            rc = 1;
        }
    }
    crlb_free(&cw);
    return rc;
}

/* One frame of many stars; the bound of each as if alone on a 60x60 frame
 * at the same pixel phase. */
static int build_crowded(sw_scene *sc, const mp_sim_prf *sp, const mp_prf_model *truth, char *err)
{
    long side = lround(CROWD_SIDE * sqrt((double)sc->n / CROWD_N));
    if (side < 64)
        side = 64;
    sc->fnx = sc->fny = side;
    size_t np = (size_t)side * side;
    sc->img = malloc(np * sizeof *sc->img);
    sc->t = calloc((size_t)sc->n, sizeof *sc->t);
    crlb_work cw;
    if (!sc->img || !sc->t || crlb_alloc(&cw, truth)) {
        snprintf(err, MP_ERRLEN, "%s: out of memory for the frame", sc->name);
        return 1;
    }
    for (size_t i = 0; i < np; i++)
        sc->img[i] = SW_SKY;
    mp_rng r;
    mp_rng_seed(&r, sc->seed);
    double span = (double)side + 1.0 - 2.0 * CROWD_MARGIN;
    int rc = 0;
    for (int k = 0; k < sc->n && !rc; k++) {
        sw_truth *t = &sc->t[k];
        t->mag = SW_MAG_LO + (SW_MAG_HI - SW_MAG_LO) * mp_rng_uniform(&r);
        t->x = CROWD_MARGIN + span * mp_rng_uniform(&r);
        t->y = CROWD_MARGIN + span * mp_rng_uniform(&r);
        t->x0 = t->x + 0.5 * mp_rng_uniform(&r) - 0.25;
        t->y0 = t->y + 0.5 * mp_rng_uniform(&r) - 0.25;
        t->e = pow(10.0, -0.4 * t->mag);
        t->f0 = t->e * exp(CROWD_FLUX_SCATTER * mp_rng_normal(&r));
        if (mp_sim_add_star_float(sp, t->x, t->y, t->e, sc->img, side, side)) {
            snprintf(err, MP_ERRLEN, "%s: the simulator refused star %d", sc->name, k);
            rc = 1;
            break;
        }
        double xv = 30.0 + (t->x - floor(t->x)), yv = 30.0 + (t->y - floor(t->y));
        if (crlb_at(truth, xv, yv, t->e, &cw, &t->se, &t->sx)) {
            snprintf(err, MP_ERRLEN, "%s: rendering the truth PRF failed (star %d)", sc->name, k);
            rc = 1;
        }
    }
    if (!rc)
        mp_sim_add_noise_float(&r, sc->img, (long)np, SW_RON);
    crlb_free(&cw);
    return rc;
}

/* Returns 0 built, 1 error, 2 skipped (note says why). */
int sw_scene_build(sw_scene *sc, const char *name, int n, const char *realpath, char *err)
{
    memset(sc, 0, sizeof *sc);
    sc->n = n;
    mp_sim_prf sp;
    memset(&sp, 0, sizeof sp);
    sp.volume = 1.0;
    mp_psf gauss;
    memset(&gauss, 0, sizeof gauss);
    mp_prf_model truth = {NULL, NULL, 10};
    int gradient = !strcmp(name, "gradient");
    double *seg = NULL;          /* segmented: the x6 truth table */
    if (!strcmp(name, "segmented")) {
        /* Issue 10: a diffraction-limited PSF, λ/D = 2 px at the blue end
         * of a 50 % band (beta 28 px^2: paper 5.4's rule took it to x1),
         * truth x6 on its own grid, fitted with its exact x2 block-sum,
         * whole frames (fitrad=INDEF) as the paper and the issue ran it. */
        int nt;
        char e[256];
        if (mp_sim_segmented_psf(2.0, 0.5, 6, 15.0, &seg, &nt, e)) {
            snprintf(err, MP_ERRLEN, "%s", e);
            return 1;
        }
        mp_psf t6 = {.kind = MP_PSF_TABLE, .nx = nt, .ny = nt, .os = 6, .t = seg, .sum = 0.0};
        for (int i = 0; i < nt * nt; i++)
            t6.sum += seg[i];
        if (mp_psf_rebin(&t6, 3, &sc->tab[0], err)) {
            free(seg);
            return 1;
        }
        sc->kind = SW_SINGLE;
        sc->name = "segmented";
        sc->whole = 1;
        sc->seed = 7070000000ULL;
        sc->title = "60x60 single-star frames, whole-frame fits (fitrad=INDEF), segmented-mirror "
                    "PSF (18 hexagons, lambda/D = 2 px at the blue end of a 50 % band), x6 truth, "
                    "x2 table";
        snprintf(sc->note, sizeof sc->note, "truth: mp_sim_segmented_psf(lambda/D 2 px, band 0.5, "
                 "x6, radius 15 px), sum %.4f, stars on its x6 grid; fitted table: its x2 block-sum",
                 t6.sum);
        sp.kind = MP_SIM_TABLE;
        sp.tab = seg;
        sp.tnx = sp.tny = nt;
        sp.tos = 6;
        gauss = t6;              /* the truth model for the bound (not freed: seg is) */
        truth.psf = &gauss;
    } else if (!strcmp(name, "isolated") || !strcmp(name, "undersampled") ||
               !strcmp(name, "crowded") || gradient || !strcmp(name, "wholeframe")) {
        int under = !strcmp(name, "undersampled");
        sc->kind = strcmp(name, "crowded") ? SW_SINGLE : SW_CROWDED;
        sc->name = sc->kind == SW_CROWDED ? "crowded" : (under ? "undersampled" : "isolated");
        sc->fwhm = under ? 1.5 : 3.0;
        sc->seed = sc->kind == SW_CROWDED ? 4040000000ULL : (under ? 2020000000ULL : 1010000000ULL);
        sc->title = sc->kind == SW_CROWDED
                        ? "one crowded frame, Gaussian FWHM 3 px, 2x table, truth start positions "
                          "(+U(-0.25,0.25) px), GROUP_ID from mp_group_table, mp_fit_table"
                        : (under ? "60x60 single-star frames, Gaussian FWHM 1.5 px (undersampled, "
                                   "beta 6.2 px^2), 2x table"
                                 : "60x60 single-star frames, Gaussian FWHM 3 px, 2x table");
        if (mp_psf_gauss_table(sc->fwhm, 2, SW_PSFRAD, &sc->tab[0], err))
            return 1;
        sp.kind = MP_SIM_GAUSS;
        sp.sigma = fwhm_to_sigma(sc->fwhm);
        mp_psf_gauss(sc->fwhm, &gauss);
        truth.psf = &gauss;
        snprintf(sc->note, sizeof sc->note,
                 "truth: Gaussian FWHM %.2f px integrated exactly over pixels (sim.h); fitted "
                 "table: mp_psf_gauss_table(FWHM %.2f, x2, radius %.0f px = group.par's psfrad)", sc->fwhm,
                 sc->fwhm, SW_PSFRAD);
        if (!strcmp(name, "wholeframe")) {
            /* The paper's (and issue 10's) setup: the isolated scene's
             * frames, each fitted whole (fitrad=INDEF). */
            sc->name = "wholeframe";
            sc->whole = 1;
            sc->title = "60x60 single-star frames (the isolated scene's), Gaussian FWHM 3 px, 2x "
                        "table, whole-frame fits (fitrad=INDEF)";
        }
        if (gradient) {
            /* A sky plane: 1.5 and 1.0 e-/px per px in x and y (100 ± 75 e-/px
             * over the frame), what a constant sky cannot absorb. */
            sc->name = "gradient";
            sc->seed = 5050000000ULL;
            sc->gx = 1.5;
            sc->gy = 1.0;
            sc->title = "60x60 single-star frames, Gaussian FWHM 3 px, 2x table, sky plane "
                        "1.5 / 1.0 e-/px per px in x / y";
            size_t l = strlen(sc->note);
            snprintf(sc->note + l, sizeof sc->note - l, "; sky 100 + 1.5 (x - 30.5) + 1.0 (y - 30.5) "
                     "e-/px (the CRLB is that of a constant sky of 100 e-/px)");
        }
    } else if (!strcmp(name, "ugly") || !strcmp(name, "gate")) {
        int gate = !strcmp(name, "gate");
        sc->kind = SW_SINGLE;
        sc->name = gate ? "gate" : "ugly";
        sc->seed = gate ? 6060000000ULL : 3030000000ULL;
        sc->title = gate ? "60x60 single-star frames, Tiny Tim ACS/HRC F606W x4 table as truth on "
                           "its own grid, gate-structure DRF 4x4 (paper 5.7, validate case 8)"
                         : "60x60 single-star frames, Tiny Tim ACS/HRC F606W x4 table as truth on "
                           "its own grid";
        char note[1024];
        int rc = load_real(realpath, &sc->tab[0], note, sizeof note, err);
        if (rc < 0)
            return 1;
        if (rc > 0) {
            snprintf(sc->note, sizeof sc->note, "%s", note);
            return 2;
        }
        snprintf(sc->note, sizeof sc->note, "truth: %.*s, stars on its x4 grid (mp_sim_snap), "
                 "block-summed exactly by the simulator", (int)(sizeof sc->note - 100), note);
        sp.kind = MP_SIM_TABLE;
        sp.tab = sc->tab[0].t;
        sp.tnx = sc->tab[0].nx;
        sp.tny = sc->tab[0].ny;
        sp.tos = sc->tab[0].os;
        truth.psf = &sc->tab[0];   /* on-grid positions: the shift is zero */
        if (gate) {
            /* Paper §5.7's gate structure: first row and column of the 4x4
             * subpixels dead, the rest QE 1 (V = 9/16), as validate case 8. */
            sc->drf.qe = malloc(16 * sizeof *sc->drf.qe);
            if (!sc->drf.qe) {
                snprintf(err, MP_ERRLEN, "out of memory");
                return 1;
            }
            sc->drf.k = 4;
            sc->drf.volume = 0.5625;
            for (int j = 0; j < 4; j++)
                for (int i = 0; i < 4; i++)
                    sc->drf.qe[j * 4 + i] = (i == 0 || j == 0) ? 0.0 : 1.0;
            sp.drf = sc->drf.qe;
            sp.dk = 4;
            truth.drf = &sc->drf;
            size_t l = strlen(sc->note);
            snprintf(sc->note + l, sizeof sc->note - l, "; gate DRF 4x4, first row and column dead");
        }
    } else {
        snprintf(err, MP_ERRLEN, "unknown scene '%s' (isolated, crowded, undersampled, ugly, "
                 "gradient, gate, wholeframe, segmented)", name);
        return 1;
    }
    int rc = add_rebins(sc, err) ? 1
             : sc->kind == SW_CROWDED ? build_crowded(sc, &sp, &truth, err)
                                      : build_single(sc, &sp, &truth, err);
    free(seg);
    return rc;
}
