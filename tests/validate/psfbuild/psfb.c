/*
 * psfb.c — the PSF built from the frame against the truth (issue 11 part B,
 * "What it must show" 1): crowded frames drawn by sim/ (exact block-sums of
 * ×5 tables at positions on their grid; never the fitter's shifter), then
 * matched against `matphot pipeline`'s catalogs run with the true table,
 * with the PSF built from the frame, and with a Gaussian.
 *
 *   psfb sim DIR KIND [SEED]   KIND segmented | variable | gauss (SEED: another
 *       draw of the same scene; default the scene's own)
 *       DIR/frame.fits (gain 1, RDNOISE), DIR/truth.dat (ASCII_HEAD:
 *       position, flux, and each star's Cramér–Rao bound of flux and x
 *       alone on its sky), DIR/true.psf.fits (segmented: the ×5 table;
 *       variable: the table at the frame's centre, for the comparison;
 *       gauss: the one Gaussian table).
 *   psfb match DIR ROOT [zp]  errors over the bound per magnitude bin
 *       (median |ΔE|/(0.6745 σ_E), median Δr/(1.1774 σ_X): 1 on the
 *       bound) and completeness, from DIR/ROOT.cat; one line per bin;
 *       zp: the fluxes rescaled first by the median E_true/E of the two
 *       brightest bins (a peer's fluxes on its aperture scale); a last
 *       row "-14..-8 (all)" pools the bins.
 *   psfb pool ROOT DIR...   the matches of DIR/ROOT.cat of several draws
 *       of one scene pooled: per bin completeness, phot and astro over
 *       the joint bound with their bootstrap standard errors.
 *   psfb resid FRAME RES CAT R RON [CAT2]   the normalised residual near
 *       the stars (within R px of each star of CAT, or of CAT and CAT2),
 *       as issue 11 compares it with DAOPHOT's on 47 Tuc.
 *   psfb noise SCI ERR RON   a calibrated frame's error plane against the
 *       noise model (ERR^2 over max(SCI, 0) + RON^2).
 *   psfb chi2 CAT   median CHI2_PSF by flux, by whether the group holds
 *       a saturated star, and by group size.
 *   psfb cmp BUILT TRUE    the built PSF against the true one as the fit
 *       sees them: PRFs at 16 phases, rms and largest pixel difference
 *       over the peak; and element by element when the samplings agree.
 *
 * Scenes (fixed seeds): 256×256 px, 400 stars uniform in position,
 * magnitudes uniform in [−14, −8] (0 mag = 1 e−), sky 100 e−, RON 3 e−.
 *   segmented: sim/segmented.c's 18-hexagon mirror, λ/D = 2 px at the
 *     blue end of a 50 % band (undersampled, ugly: issue 11's third case),
 *     its ±8 px table normalised to 1 (all of a star's light in the frame).
 *   variable: an elliptical Gaussian whose FWHM runs 3 px × (1 ± 0.15)
 *     across x, stretched by up to 15 % along y at the left and right
 *     edges and along x at the top and bottom (issue 11's second case).
 *   gauss: the variable scene's table at the centre (a round Gaussian of
 *     FWHM 3 px) everywhere: the crowded Gaussian scene of the peers'
 *     side by side, at this frame size.
 */
#include <ctype.h>
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include <fitsio.h>

#include "catalog/catalog.h"
#include "fit/fit.h"
#include "io/io.h"
#include "psf/build.h"
#include "sim/sim.h"
#include "tests/validate/crowded/joint_bound.h"

#define NX 256
#define NSTAR 400
#define TOS 5
#define RAD 8.0
#define SKY 100.0
#define RON 3.0
#define FITRAD 5.0           /* the pipeline's default fitrad (params/pipeline.par) */
#define SW 19                /* joint-bound stamps: the ±RAD table and 1 px of phase */

/* The variable scene's table at (x, y): ×TOS, ±RAD px, sum 1. */
static void var_table(double x, double y, double *t, int *n)
{
    double u = (x - 0.5 * (NX + 1)) / (0.5 * NX), v = (y - 0.5 * (NX + 1)) / (0.5 * NX);
    double s0 = 3.0 / 2.35482 * (1.0 + 0.15 * u);
    double sx = s0 * (1.0 + 0.15 * v * v), sy = s0 * (1.0 + 0.15 * u * u);
    int h = (int)ceil(RAD * TOS), m = 2 * h + 1;
    double sum = 0;
    for (int j = 0; j < m; j++)
        for (int i = 0; i < m; i++) {
            double a = 0;
            for (int q = 0; q < 9; q++) {     /* 3×3 midpoints per element */
                double px = (i - h + ((q % 3) - 1) / 3.0) / TOS, py = (j - h + ((q / 3) - 1) / 3.0) / TOS;
                a += exp(-0.5 * (px * px / (sx * sx) + py * py / (sy * sy)));
            }
            t[(size_t)j * m + i] = a;
            sum += a;
        }
    for (int i = 0; i < m * m; i++)
        t[i] /= sum;
    *n = m;
}

static int write_table(const char *path, const double *t, int n, char *err)
{
    mp_card c[1] = {{"OVERSAMP", TOS, NULL, "table elements per pixel"}};
    return mp_image_write(path, t, n, n, -64, c, 1, err);
}

/* The CRLB of flux and x of a star alone on the sky: the exact PRF (the
 * sim's own block-sum) and its x, y derivatives by central differences of
 * one table element (the sim can only draw on its grid). */
static void crlb_of(const mp_sim_prf *p, double x, double y, double E, double *sE, double *sX)
{
    int w = 2 * (int)RAD + 5;
    size_t nn = (size_t)w * w;
    double *a = calloc(nn, sizeof *a), *b = calloc(nn, sizeof *b), *c = calloc(nn, sizeof *c),
           *d = calloc(nn, sizeof *d), *e = calloc(nn, sizeof *e);
    double cx = w / 2 + 1 + (x - floor(x)), cy = w / 2 + 1 + (y - floor(y)), h = 1.0 / TOS;
    mp_sim_add_star(p, cx, cy, 1.0, a, w, w);
    mp_sim_add_star(p, cx + h, cy, 1.0, b, w, w);
    mp_sim_add_star(p, cx - h, cy, 1.0, c, w, w);
    mp_sim_add_star(p, cx, cy + h, 1.0, d, w, w);
    mp_sim_add_star(p, cx, cy - h, 1.0, e, w, w);
    for (size_t i = 0; i < nn; i++) {
        b[i] = (b[i] - c[i]) / (2 * h);
        d[i] = (d[i] - e[i]) / (2 * h);
    }
    double sd[4];
    if (mp_crlb(a, b, d, nn, E, SKY, RON, sd)) {
        *sE = *sX = NAN;
    } else {
        *sE = sd[0];
        *sX = sd[1];
    }
    free(a), free(b), free(c), free(d), free(e);
}

/* The joint bound's stamps of a star (joint_bound.h): its PRF and its x,
 * y derivatives (central differences of one table element) on SW × SW
 * pixels centred on (lround(x), lround(y)). */
static void stamp_of(const mp_sim_prf *p, double x, double y, double *st)
{
    const size_t ss = SW * SW;
    const double h = 1.0 / TOS, c = SW / 2 + 1;
    double cx = c + x - (double)lround(x), cy = c + y - (double)lround(y);
    memset(st, 0, 3 * ss * sizeof *st);
    mp_sim_add_star(p, cx, cy, 1.0, st, SW, SW);
    mp_sim_add_star(p, cx + h, cy, 0.5 / h, st + ss, SW, SW);
    mp_sim_add_star(p, cx - h, cy, -0.5 / h, st + ss, SW, SW);
    mp_sim_add_star(p, cx, cy + h, 0.5 / h, st + 2 * ss, SW, SW);
    mp_sim_add_star(p, cx, cy - h, -0.5 / h, st + 2 * ss, SW, SW);
}

/* Each star's bound fitted with its neighbours (issue 13's joint bound,
 * tests/validate/crowded/joint_bound.c): every star whose fitting disc
 * (FITRAD) overlaps its own and one constant sky, on the union of their
 * discs, the variance from the noiseless frame mean; and the same star
 * fitted alone on its disc (its neighbours known): the bound's part that
 * is the disc and the neighbours' photon noise, apart from their
 * parameters.  sE, sX: flux and the mean of the x and y variances. */
static int joint_of(const double *mean, const double *stamps, const jb_star *js, int n, double *sE,
                    double *sX, double *aE, double *aX)
{
    double *ex = malloc(sizeof(double) * (size_t)n), *ey = malloc(sizeof(double) * (size_t)n);
    jb_scene sc = {0, RON, INFINITY, FITRAD, NX, NX, mean, stamps, SW};
    int rc = !ex || !ey || joint_bounds(&sc, js, n, sE, ex, ey, NULL);
    for (int k = 0; !rc && k < n; k++)
        sX[k] = sqrt(0.5 * (ex[k] * ex[k] + ey[k] * ey[k]));
    for (int k = 0; !rc && k < n; k++) {
        double e, x, y;
        sc.stamp = stamps + (size_t)3 * SW * SW * k;
        rc = joint_bounds(&sc, js + k, 1, &e, &x, &y, NULL);
        aE[k] = e;
        aX[k] = sqrt(0.5 * (x * x + y * y));
    }
    free(ex), free(ey);
    return rc;
}

static int do_sim(const char *dir, const char *kind, long seed)
{
    int seg = !strcmp(kind, "segmented"), gau = !strcmp(kind, "gauss");
    if (!seg && !gau && strcmp(kind, "variable"))
        return fprintf(stderr, "psfb: scene %s: segmented, variable or gauss\n", kind), 1;
    char err[MP_ERRLEN], path[1024];
    mp_rng r;
    mp_rng_seed(&r, seed > 0 ? (uint64_t)seed : seg ? 1101 : gau ? 1103 : 1102);
    double *img = malloc(sizeof(double) * NX * NX), *tab = NULL;
    int n = 0;
    for (int i = 0; i < NX * NX; i++)
        img[i] = SKY;
    if (seg) {
        if (mp_sim_segmented_psf(2.0, 0.5, TOS, RAD, &tab, &n, err)) {
            fprintf(stderr, "psfb: %s\n", err);
            return 1;
        }
        /* Every star's light drawn: the table (87 % of the mirror's light
         * within ±RAD) normalised to 1, so that the frame holds the total
         * flux the truth lists (light the frame never received cannot be
         * found by a growth curve). */
        double sum = 0;
        for (int i = 0; i < n * n; i++)
            sum += tab[i];
        for (int i = 0; i < n * n; i++)
            tab[i] /= sum;
    } else {
        int m = 2 * (int)ceil(RAD * TOS) + 1;
        tab = malloc(sizeof(double) * m * m);
        var_table(0.5 * (NX + 1), 0.5 * (NX + 1), tab, &n);
    }
    snprintf(path, sizeof path, "%s/true.psf.fits", dir);
    if (write_table(path, tab, n, err)) {
        fprintf(stderr, "psfb: %s\n", err);
        return 1;
    }
    mp_table t;
    mp_table_init(&t);
    int cn = mp_table_add_col(&t, "NUMBER"), cx = mp_table_add_col(&t, "X_IMAGE"),
        cy = mp_table_add_col(&t, "Y_IMAGE"), cf = mp_table_add_col(&t, "FLUX"),
        cm = mp_table_add_col(&t, "MAG"), ce = mp_table_add_col(&t, "CRLB_FLUX"),
        cq = mp_table_add_col(&t, "CRLB_X"), cje = mp_table_add_col(&t, "JOINT_FLUX"),
        cjq = mp_table_add_col(&t, "JOINT_X"), cae = mp_table_add_col(&t, "DISC_FLUX"),
        caq = mp_table_add_col(&t, "DISC_X");
    double *vt = malloc(sizeof(double) * (2 * (int)ceil(RAD * TOS) + 1) * (2 * (int)ceil(RAD * TOS) + 1));
    const size_t ss = SW * SW;
    double *stamps = malloc(sizeof(double) * 3 * ss * NSTAR), *mean = malloc(sizeof(double) * NX * NX);
    double *b = malloc(sizeof(double) * 8 * NSTAR);   /* sE sX jE jX aE aX mag */
    jb_star *js = malloc(sizeof *js * NSTAR);
    if (!vt || !stamps || !mean || !b || !js)
        return fprintf(stderr, "psfb: out of memory\n"), 1;
    for (int k = 0; k < NSTAR; k++) {
        double x = 0.5 + NX * mp_rng_uniform(&r), y = 0.5 + NX * mp_rng_uniform(&r);
        double mag = -14.0 + 6.0 * mp_rng_uniform(&r), E = pow(10.0, -0.4 * mag);
        int m = n;
        const double *use = tab;
        if (!seg && !gau) {
            var_table(x, y, vt, &m);
            use = vt;
        }
        mp_sim_prf p = {MP_SIM_TABLE, 0, use, m, m, TOS, NULL, 0, 1.0, 0.0};
        mp_sim_snap(&p, &x, &y);
        mp_sim_add_star(&p, x, y, E, img, NX, NX);
        crlb_of(&p, x, y, E, &b[k], &b[NSTAR + k]);
        stamp_of(&p, x, y, stamps + 3 * ss * (size_t)k);
        js[k] = (jb_star){x, y, E};
        b[6 * NSTAR + k] = mag;
    }
    memcpy(mean, img, sizeof(double) * NX * NX);
    if (joint_of(mean, stamps, js, NSTAR, b + 2 * NSTAR, b + 3 * NSTAR, b + 4 * NSTAR,
                 b + 5 * NSTAR))
        return fprintf(stderr, "psfb: out of memory\n"), 1;
    for (int k = 0; k < NSTAR; k++) {
        long row = mp_table_add_row(&t);
        double v[11] = {k + 1, js[k].x, js[k].y, js[k].flux, b[6 * NSTAR + k], b[k],
                        b[NSTAR + k], b[2 * NSTAR + k], b[3 * NSTAR + k], b[4 * NSTAR + k],
                        b[5 * NSTAR + k]};
        int col[11] = {cn, cx, cy, cf, cm, ce, cq, cje, cjq, cae, caq};
        for (int j = 0; j < 11; j++)
            mp_table_set(&t, (size_t)row, col[j], v[j]);
    }
    free(stamps), free(mean), free(b), free(js);
    mp_sim_add_noise(&r, img, (long)NX * NX, RON);
    mp_card c[2] = {{"GAIN", 1.0, NULL, "e-/ADU"}, {"RDNOISE", RON, NULL, "e-"}};
    snprintf(path, sizeof path, "%s/frame.fits", dir);
    if (mp_image_write(path, img, NX, NX, -32, c, 2, err)) {
        fprintf(stderr, "psfb: %s\n", err);
        return 1;
    }
    snprintf(path, sizeof path, "%s/truth.dat", dir);
    if (mp_table_write(path, &t, MP_TAB_ASCII_HEAD, err)) {
        fprintf(stderr, "psfb: %s\n", err);
        return 1;
    }
    printf("psfb: %s/frame.fits: %d stars, %s PSF\n", dir, NSTAR, kind);
    free(vt);
    free(tab);
    free(img);
    mp_table_free(&t);
    return 0;
}

static int cmpd(const void *a, const void *b)
{
    double x = *(const double *)a, y = *(const double *)b;
    return (x > y) - (x < y);
}

static double median(double *v, int n)
{
    if (n == 0)
        return NAN;
    qsort(v, (size_t)n, sizeof *v, cmpd);
    return n % 2 ? v[n / 2] : 0.5 * (v[n / 2 - 1] + v[n / 2]);
}

/* The bounds a match divides by: the joint bound (the star fitted with
 * its neighbours on the union of their FITRAD discs; the row's ratios),
 * the star alone on a 21 × 21 px box of its sky (the isolated bound, the
 * scoring before), and alone on its disc (neighbours known). */
enum { NB = 6, NK = 3 };
static const char *const kflux[NK] = {"JOINT_FLUX", "CRLB_FLUX", "DISC_FLUX"};
static const char *const kpos[NK] = {"JOINT_X", "CRLB_X", "DISC_X"};

/* One magnitude bin's matched stars: fitted and true flux, position
 * error, and each bound. */
typedef struct {
    double *ef, *et, *dr, *se[NK], *sx[NK];
    int nin, nm;
} mbin;

static double med_ratio(const mbin *bn, int nb, int k, int astro, double scale, int bias)
{
    int n = 0;
    for (int b = 0; b < nb; b++)
        n += bn[b].nm;
    double *v = malloc((size_t)(n + 1) * sizeof *v), r;
    n = 0;
    for (int b = 0; b < nb; b++)
        for (int q = 0; q < bn[b].nm; q++) {
            double dE = scale * bn[b].ef[q] - bn[b].et[q];
            v[n++] = astro ? bn[b].dr[q] / (1.1774 * bn[b].sx[k][q])
                     : bias ? dE / bn[b].se[k][q] : fabs(dE) / (0.6745 * bn[b].se[k][q]);
        }
    r = median(v, n);
    free(v);
    return r;
}

/* One row: "root: LABEL | true | found | completeness | phot/joint |
 * astro/joint | bias | phot/alone | astro/alone | phot/disc | astro/disc". */
static void match_row(const char *root, const char *label, const mbin *bn, int nb, double scale)
{
    int nin = 0, nm = 0;
    for (int b = 0; b < nb; b++)
        nin += bn[b].nin, nm += bn[b].nm;
    printf("%s: %s | %d | %d | %.3f | %.3f | %.3f | %+.2f", root, label, nin, nm,
           nin ? (double)nm / nin : NAN, med_ratio(bn, nb, 0, 0, scale, 0),
           med_ratio(bn, nb, 0, 1, scale, 0), med_ratio(bn, nb, 0, 0, scale, 1));
    for (int k = 1; k < NK; k++)
        printf(" | %.3f | %.3f", med_ratio(bn, nb, k, 0, scale, 0), med_ratio(bn, nb, k, 1, scale, 0));
    printf("\n");
}

/* The bins' arrays, room for cap stars each; nonzero on out of memory. */
static int bins_alloc(mbin *bn, size_t cap)
{
    memset(bn, 0, NB * sizeof *bn);
    for (int b = 0; b < NB; b++) {
        double **a[3 + 2 * NK] = {&bn[b].ef, &bn[b].et, &bn[b].dr};
        for (int k = 0; k < NK; k++)
            a[3 + k] = &bn[b].se[k], a[3 + NK + k] = &bn[b].sx[k];
        for (int q = 0; q < 3 + 2 * NK; q++)
            if (!(*a[q] = malloc((cap + 1) * sizeof(double))))
                return 1;
    }
    return 0;
}

static void bins_free(mbin *bn)
{
    for (int b = 0; b < NB; b++) {
        free(bn[b].ef), free(bn[b].et), free(bn[b].dr);
        for (int k = 0; k < NK; k++)
            free(bn[b].se[k]), free(bn[b].sx[k]);
    }
}

/* DIR/ROOT.cat matched against DIR/truth.dat, appended to the bins (room
 * for cap stars each): each true star takes the nearest unused catalog
 * star within 1 px, brightest true stars first (they are found first and
 * best). */
static int match_dir(const char *dir, const char *root, mbin *bn, size_t cap)
{
    char err[MP_ERRLEN], path[1024];
    mp_table tr, ct;
    mp_table_init(&tr);
    mp_table_init(&ct);
    snprintf(path, sizeof path, "%s/truth.dat", dir);
    if (mp_table_read(path, &tr, err))
        return fprintf(stderr, "psfb: %s\n", err), 1;
    snprintf(path, sizeof path, "%s/%s.cat", dir, root);
    if (mp_table_read(path, &ct, err))
        return fprintf(stderr, "psfb: %s\n", err), 1;
    int tx = mp_table_col(&tr, "X_IMAGE"), ty = mp_table_col(&tr, "Y_IMAGE"),
        tf = mp_table_col(&tr, "FLUX"), tm = mp_table_col(&tr, "MAG"), te[NK], tq[NK];
    for (int k = 0; k < NK; k++)
        if ((te[k] = mp_table_col(&tr, kflux[k])) < 0 || (tq[k] = mp_table_col(&tr, kpos[k])) < 0)
            return fprintf(stderr, "psfb: %s/truth.dat: no %s (run psfb sim again)\n", dir,
                           kflux[k]), 1;
    int cx = mp_table_col(&ct, "XPSF_IMAGE"), cy = mp_table_col(&ct, "YPSF_IMAGE"),
        cf = mp_table_col(&ct, "FLUX_PSF");
    size_t nt = tr.nrow, nc = ct.nrow;
    int *used = calloc(nc + 1, sizeof *used);
    size_t *ord = malloc((nt + 1) * sizeof *ord);
    if (!used || !ord)
        return fprintf(stderr, "psfb: out of memory\n"), 1;
    for (size_t i = 0; i < nt; i++)
        ord[i] = i;
    for (size_t i = 0; i < nt; i++)       /* insertion sort by magnitude */
        for (size_t j = i; j > 0 && mp_table_get(&tr, ord[j], tm) < mp_table_get(&tr, ord[j - 1], tm); j--) {
            size_t s = ord[j];
            ord[j] = ord[j - 1];
            ord[j - 1] = s;
        }
    for (size_t q = 0; q < nt; q++) {
        size_t i = ord[q];
        double x = mp_table_get(&tr, i, tx), y = mp_table_get(&tr, i, ty);
        int b = (int)floor(mp_table_get(&tr, i, tm) + 14.0);
        if (b < 0 || b >= NB || (size_t)bn[b].nm >= cap)
            continue;
        bn[b].nin++;
        long best = -1;
        double bd = 1.0;
        for (size_t c = 0; c < nc; c++) {
            double d = hypot(mp_table_get(&ct, c, cx) - x, mp_table_get(&ct, c, cy) - y);
            if (!used[c] && d < bd) {
                bd = d;
                best = (long)c;
            }
        }
        if (best < 0)
            continue;
        used[best] = 1;
        int m = bn[b].nm++;
        bn[b].ef[m] = mp_table_get(&ct, (size_t)best, cf);
        bn[b].et[m] = mp_table_get(&tr, i, tf);
        bn[b].dr[m] = bd;
        for (int k = 0; k < NK; k++) {
            bn[b].se[k][m] = mp_table_get(&tr, i, te[k]);
            bn[b].sx[k][m] = mp_table_get(&tr, i, tq[k]);
        }
    }
    free(ord);
    free(used);
    mp_table_free(&tr);
    mp_table_free(&ct);
    return 0;
}

/* zp: the catalog's fluxes times one scale, the median E_true/E of the
 * matched stars in the two brightest bins (a peer's aperture-scale fluxes
 * put on the truth's, as an aperture correction would). */
static int do_match(const char *dir, const char *root, int zp)
{
    mbin bn[NB];
    if (bins_alloc(bn, 4 * NSTAR))
        return fprintf(stderr, "psfb: out of memory\n"), 1;
    if (match_dir(dir, root, bn, 4 * NSTAR))
        return 1;
    double scale = 1.0;
    if (zp) {
        double *r = malloc((4 * NSTAR + 1) * sizeof *r);
        int nr = 0;
        for (int b = 0; b < 2; b++)
            for (int k = 0; k < bn[b].nm; k++)
                if (bn[b].ef[k] > 0)
                    r[nr++] = bn[b].et[k] / bn[b].ef[k];
        scale = nr ? median(r, nr) : 1.0;
        free(r);
        printf("%s: flux scale %.5f from %d stars\n", root, scale, nr);
    }
    printf("%s: mag bin | true | found | completeness | phot/joint | astro/joint | "
           "median dE/joint | phot/alone | astro/alone | phot/disc | astro/disc\n", root);
    for (int b = 0; b < NB; b++) {
        char label[32];
        snprintf(label, sizeof label, "%.0f..%.0f", b - 14.0, b - 13.0);
        match_row(root, label, &bn[b], 1, scale);
    }
    /* All bins pooled: a bin's median of ~60 stars scatters by ~16 %
     * (the median of |N(0,1)| from n draws: 0.5/(sqrt(n)·0.636)/0.674),
     * the pooled one of ~400 by ~6 %. */
    match_row(root, "-14..-8 (all)", bn, NB, scale);
    bins_free(bn);
    return 0;
}

/* The median ratio (phot or astro over the joint bound) of nb bins and
 * its standard error by the bootstrap over the stars (NBOOT resamples,
 * a fixed seed): the error of "within 15 % of the bound" in a bin. */
#define NBOOT 400
static void ratio_se(const mbin *bn, int nb, int astro, double *r, double *se)
{
    int n = 0;
    for (int b = 0; b < nb; b++)
        n += bn[b].nm;
    double *v = malloc((size_t)(n + 1) * sizeof *v), *w = malloc((size_t)(n + 1) * sizeof *w);
    double *bs = malloc(NBOOT * sizeof *bs);
    *r = *se = NAN;
    if (!v || !w || !bs || n < 2) {
        free(v), free(w), free(bs);
        return;
    }
    n = 0;
    for (int b = 0; b < nb; b++)
        for (int q = 0; q < bn[b].nm; q++)
            v[n++] = astro ? bn[b].dr[q] / (1.1774 * bn[b].sx[0][q])
                           : fabs(bn[b].ef[q] - bn[b].et[q]) / (0.6745 * bn[b].se[0][q]);
    mp_rng g;
    mp_rng_seed(&g, 4242);
    double s = 0, s2 = 0;
    for (int t = 0; t < NBOOT; t++) {
        for (int q = 0; q < n; q++)
            w[q] = v[(int)(n * mp_rng_uniform(&g)) % n];
        bs[t] = median(w, n);
        s += bs[t];
        s2 += bs[t] * bs[t];
    }
    *r = median(v, n);
    *se = sqrt(fmax(s2 / NBOOT - (s / NBOOT) * (s / NBOOT), 0.0));
    free(v), free(w), free(bs);
}

static void pool_row(const char *label, const mbin *bn, int nb)
{
    int nin = 0, nm = 0;
    for (int b = 0; b < nb; b++)
        nin += bn[b].nin, nm += bn[b].nm;
    double rp, sp, ra, sa;
    ratio_se(bn, nb, 0, &rp, &sp);
    ratio_se(bn, nb, 1, &ra, &sa);
    printf("pool: %s | %d | %d | %.3f | %.3f +- %.3f | %.3f +- %.3f\n", label, nin, nm,
           nin ? (double)nm / nin : NAN, rp, sp, ra, sa);
}

/* psfb pool ROOT DIR...: the frames' matches pooled (draws of one scene):
 * per magnitude bin completeness and phot, astro over the joint bound,
 * each with its bootstrap standard error. */
static int do_pool(const char *root, char **dirs, int nd)
{
    mbin bn[NB];
    size_t cap = (size_t)nd * NSTAR * 4;
    if (bins_alloc(bn, cap))
        return fprintf(stderr, "psfb: out of memory\n"), 1;
    for (int d = 0; d < nd; d++)
        if (match_dir(dirs[d], root, bn, cap))
            return 1;
    printf("pool: %s over %d frames: mag bin | true | found | completeness | phot/joint +- se | "
           "astro/joint +- se\n", root, nd);
    for (int b = 0; b < NB; b++) {
        char label[32];
        snprintf(label, sizeof label, "%.0f..%.0f", b - 14.0, b - 13.0);
        pool_row(label, &bn[b], 1);
    }
    pool_row("-14..-8 (all)", bn, NB);
    bins_free(bn);
    return 0;
}

static void cmp_at(const mp_psf *b, const mp_psf *t, double *rms, double *mx, double *peak);

/* The variable scene: the built field against var_table at 3×3 places. */
static int do_cmpvar(const char *built)
{
    char err[MP_ERRLEN], warn[MP_ERRLEN];
    mp_psf_field fb;
    if (mp_psf_field_read(built, 0, 0, &fb, NULL, NULL, warn, err))
        return fprintf(stderr, "psfb: %s\n", err), 1;
    int m = 2 * (int)ceil(RAD * TOS) + 1;
    double *tab = malloc(sizeof(double) * m * m);
    for (int q = 0; q < 9; q++) {
        double u = 0.8 * (q % 3 - 1), v = 0.8 * (q / 3 - 1);
        double x = 0.5 * (NX + 1) + u * 0.5 * NX, y = 0.5 * (NX + 1) + v * 0.5 * NX;
        int n;
        var_table(x, y, tab, &n);
        mp_psf t = {MP_PSF_TABLE, n, n, TOS, tab, 1.0, 0, 0, NULL}, b;
        memset(&b, 0, sizeof b);
        if (mp_psf_field_eval(&fb, x, y, &b, err))
            return fprintf(stderr, "psfb: %s\n", err), 1;
        double rms, mx, peak;
        cmp_at(&b, &t, &rms, &mx, &peak);
        printf("psfb cmpvar: %s (order %d) at u %+.1f v %+.1f: PRF rms %.2f %%, largest %.2f %% "
               "of the peak\n", built, fb.order, u, v, 100 * rms / peak, 100 * mx / peak);
        mp_psf_free(&b);
    }
    free(tab);
    mp_psf_field_free(&fb);
    return 0;
}

/* The variable scene's floor for an order-`order` field: every element
 * of var_table fitted by least squares with the order's terms over a
 * 15 × 15 grid of places (PSFEx's terms, origin the centre, scales the
 * half-sizes), then compared as cmpvar compares a built field: what no
 * build of that order can do better than. */
static int do_varfloor(int order, const char *out)
{
    char err[MP_ERRLEN];
    int m = 2 * (int)ceil(RAD * TOS) + 1, n;
    size_t nel = (size_t)m * m;
    enum { G = 15, MT = MP_EPSF_MAXT };
    mp_psf_field fb;
    if (mp_psf_field_new(order, m, m, TOS, 0.5 * (NX + 1), 0.5 * (NX + 1), 0.5 * NX, 0.5 * NX,
                         &fb, err))
        return fprintf(stderr, "psfb: %s\n", err), 1;
    int nt = fb.nterms;
    double *tabs = malloc(sizeof(double) * nel * G * G), A[MT * MT] = {0}, T[G * G][MT];
    for (int q = 0; q < G * G; q++) {
        double x = 0.5 * (NX + 1) + (-1 + 2.0 * (q % G) / (G - 1)) * 0.5 * NX;
        double y = 0.5 * (NX + 1) + (-1 + 2.0 * (q / G) / (G - 1)) * 0.5 * NX;
        var_table(x, y, tabs + q * nel, &n);
        mp_psf_field_terms(&fb, x, y, T[q]);
        for (int a = 0; a < nt; a++)
            for (int b = 0; b < nt; b++)
                A[a * nt + b] += T[q][a] * T[q][b];
    }
    /* A⁻¹ by Gauss–Jordan (at most 10×10, well conditioned). */
    double I[MT * MT] = {0};
    for (int a = 0; a < nt; a++)
        I[a * nt + a] = 1;
    for (int c = 0; c < nt; c++) {
        double p = A[c * nt + c];
        for (int k = 0; k < nt; k++)
            A[c * nt + k] /= p, I[c * nt + k] /= p;
        for (int r = 0; r < nt; r++)
            if (r != c) {
                double f = A[r * nt + c];
                for (int k = 0; k < nt; k++)
                    A[r * nt + k] -= f * A[c * nt + k], I[r * nt + k] -= f * I[c * nt + k];
            }
    }
    for (size_t el = 0; el < nel; el++) {
        double b[MT] = {0};
        for (int q = 0; q < G * G; q++)
            for (int a = 0; a < nt; a++)
                b[a] += T[q][a] * tabs[q * nel + el];
        for (int a = 0; a < nt; a++) {
            double c = 0;
            for (int k = 0; k < nt; k++)
                c += I[a * nt + k] * b[k];
            fb.planes[(size_t)a * nel + el] = c;
        }
    }
    fb.sum = 1.0;
    if (out && mp_psf_field_write(out, &fb, NULL, 0, err))
        return fprintf(stderr, "psfb: %s\n", err), 1;
    double *tab = malloc(sizeof(double) * nel);
    for (int q = 0; q < 9; q++) {
        double u = 0.8 * (q % 3 - 1), v = 0.8 * (q / 3 - 1);
        double x = 0.5 * (NX + 1) + u * 0.5 * NX, y = 0.5 * (NX + 1) + v * 0.5 * NX;
        var_table(x, y, tab, &n);
        mp_psf t = {MP_PSF_TABLE, n, n, TOS, tab, 1.0, 0, 0, NULL}, b;
        memset(&b, 0, sizeof b);
        if (mp_psf_field_eval(&fb, x, y, &b, err))
            return fprintf(stderr, "psfb: %s\n", err), 1;
        double rms, mx, peak;
        cmp_at(&b, &t, &rms, &mx, &peak);
        printf("psfb varfloor: order-%d least squares at u %+.1f v %+.1f: PRF rms %.2f %%, "
               "largest %.2f %% of the peak\n", order, u, v, 100 * rms / peak, 100 * mx / peak);
        mp_psf_free(&b);
    }
    free(tab);
    free(tabs);
    mp_psf_field_free(&fb);
    return 0;
}

/* The variable scene's floor for a gridded PSF (photutils'
 * GriddedPSFModel, Anderson's STDPSF): the true table at n × n places
 * spread evenly from edge to edge, interpolated bilinearly between them
 * (psf/field.c), written as a GriddedPSFModel cube (DET_YXk "(y, x)"
 * 0-based, OVERSAMP) that fit and pipeline read; compared as cmpvar
 * compares a built field. */
static int do_gridfloor(int ng, const char *out)
{
    char err[MP_ERRLEN];
    int m = 2 * (int)ceil(RAD * TOS) + 1, n;
    size_t nel = (size_t)m * m;
    double *cube = malloc(sizeof(double) * nel * ng * ng);
    fitsfile *fp;
    int st = 0, os = TOS;
    long nax[3] = {m, m, (long)ng * ng};
    char tmp[1100];
    snprintf(tmp, sizeof tmp, "!%s", out);
    fits_create_file(&fp, tmp, &st);
    fits_create_img(fp, DOUBLE_IMG, 3, nax, &st);
    fits_write_key(fp, TINT, "OVERSAMP", &os, "table elements per pixel", &st);
    for (int q = 0; q < ng * ng; q++) {
        double x = 1.0 + (NX - 1.0) * (q % ng) / (ng - 1), y = 1.0 + (NX - 1.0) * (q / ng) / (ng - 1);
        var_table(x, y, cube + q * nel, &n);
        char key[24], val[64];
        snprintf(key, sizeof key, "DET_YX%d", q);
        snprintf(val, sizeof val, "(%.1f, %.1f)", y - 1.0, x - 1.0);
        fits_write_key(fp, TSTRING, key, val, "grid point (y, x), 0-based", &st);
    }
    fits_write_img(fp, TDOUBLE, 1, (LONGLONG)(nel * ng * ng), cube, &st);
    fits_close_file(fp, &st);
    free(cube);
    if (st)
        return fprintf(stderr, "psfb: %s: cfitsio status %d\n", out, st), 1;
    mp_psf_field fb;
    char warn[MP_ERRLEN];
    if (mp_psf_field_read(out, 0, 0, &fb, NULL, NULL, warn, err))
        return fprintf(stderr, "psfb: %s\n", err), 1;
    double *tab = malloc(sizeof(double) * nel);
    for (int q = 0; q < 9; q++) {
        double u = 0.8 * (q % 3 - 1), v = 0.8 * (q / 3 - 1);
        double x = 0.5 * (NX + 1) + u * 0.5 * NX, y = 0.5 * (NX + 1) + v * 0.5 * NX;
        var_table(x, y, tab, &n);
        mp_psf t = {MP_PSF_TABLE, n, n, TOS, tab, 1.0, 0, 0, NULL}, b;
        memset(&b, 0, sizeof b);
        if (mp_psf_field_eval(&fb, x, y, &b, err))
            return fprintf(stderr, "psfb: %s\n", err), 1;
        double rms, mx, peak;
        cmp_at(&b, &t, &rms, &mx, &peak);
        printf("psfb gridfloor: %dx%d grid at u %+.1f v %+.1f: PRF rms %.2f %%, largest %.2f %% "
               "of the peak\n", ng, ng, u, v, 100 * rms / peak, 100 * mx / peak);
        mp_psf_free(&b);
    }
    free(tab);
    mp_psf_field_free(&fb);
    return 0;
}

/* x = A⁻¹ b for a small symmetric positive A (n ≤ MP_EPSF_MAXT), by
 * Gauss–Jordan without pivoting (A, b overwritten); nonzero if singular. */
static int solve_small(double *A, double *b, int n)
{
    for (int c = 0; c < n; c++) {
        double p = A[c * n + c];
        if (!(fabs(p) > 1e-300))
            return 1;
        for (int k = 0; k < n; k++)
            A[c * n + k] /= p;
        b[c] /= p;
        for (int r = 0; r < n; r++)
            if (r != c) {
                double f = A[r * n + c];
                for (int k = 0; k < n; k++)
                    A[r * n + k] -= f * A[c * n + k];
                b[r] -= f * b[c];
            }
    }
    return 0;
}

/* The noise side of the order's trade: N · the leverage of an order-k
 * fit over the used PSF stars of a built file (PSFSTARS) at the 3 × 3
 * places of cmpvar, k = 0..3 — the variance of the fitted table there
 * over that of the mean of all N stars (1 everywhere for order 0). */
static int do_leverage(const char *built)
{
    char err[MP_ERRLEN], warn[MP_ERRLEN];
    mp_psf_field fb;
    mp_psf_star *st = NULL;
    int ns = 0;
    if (mp_psf_field_read(built, 0, 0, &fb, &st, &ns, warn, err))
        return fprintf(stderr, "psfb: %s\n", err), 1;
    enum { MT = MP_EPSF_MAXT };
    for (int k = 0; k <= MP_PSF_MAXORDER; k++) {
        mp_psf_field f;
        if (mp_psf_field_new(k, 1, 1, 1, 0.5 * (NX + 1), 0.5 * (NX + 1), 0.5 * NX, 0.5 * NX, &f,
                             err))
            return fprintf(stderr, "psfb: %s\n", err), 1;
        int nt = f.nterms, nu = 0;
        double A[MT * MT] = {0}, t[MT];
        for (int q = 0; q < ns; q++) {
            if (!st[q].used)
                continue;
            nu++;
            mp_psf_field_terms(&f, st[q].x, st[q].y, t);
            for (int a = 0; a < nt; a++)
                for (int b = 0; b < nt; b++)
                    A[a * nt + b] += t[a] * t[b];
        }
        printf("psfb leverage: %s: %d PSF stars, order %d (%d terms): N x leverage at u,v in "
               "-0.8,0,0.8:", built, nu, k, nt);
        for (int q = 0; q < 9; q++) {
            double x = 0.5 * (NX + 1) + 0.8 * (q % 3 - 1) * 0.5 * NX;
            double y = 0.5 * (NX + 1) + 0.8 * (q / 3 - 1) * 0.5 * NX, M[MT * MT], b[MT];
            mp_psf_field_terms(&f, x, y, t);
            memcpy(M, A, sizeof M);
            memcpy(b, t, sizeof b);
            double h = NAN;
            if (!solve_small(M, b, nt)) {
                h = 0;
                for (int a = 0; a < nt; a++)
                    h += t[a] * b[a];
            }
            printf(" %.2f", nu * h);
        }
        printf("\n");
        mp_psf_field_free(&f);
    }
    free(st);
    mp_psf_field_free(&fb);
    return 0;
}

/* The PRFs of two tables at 16 phases on one canvas: rms, largest
 * difference, the truth's peak. */
static void cmp_at(const mp_psf *b, const mp_psf *t, double *rms, double *mxo, double *pko)
{
    int cw = 2 * (int)RAD + 12;
    double *P = calloc((size_t)cw * cw, sizeof *P), *Q = calloc((size_t)cw * cw, sizeof *Q);
    double ss = 0, mx = 0, peak = 0;
    long np = 0;
    mp_prf_work w;
    memset(&w, 0, sizeof w);
    for (int ph = 0; ph < 16; ph++) {
        double x = cw / 2 + 0.25 * (ph % 4), y = cw / 2 + 0.25 * (ph / 4);
        memset(P, 0, (size_t)cw * cw * sizeof *P);
        memset(Q, 0, (size_t)cw * cw * sizeof *Q);
        for (int k = 0; k < 2; k++) {
            mp_prf_model m = {k ? t : b, NULL, 10};
            long x0, y0;
            int bw, bh;
            mp_prf_box(&m, x, y, &x0, &y0, &bw, &bh);
            double *r = malloc(sizeof(double) * bw * bh);
            mp_prf_render(&m, x, y, r, NULL, NULL, &w);
            for (int j = 0; j < bh; j++)
                for (int i = 0; i < bw; i++) {
                    long px = x0 + i, py = y0 + j;
                    if (px >= 1 && px <= cw && py >= 1 && py <= cw)
                        (k ? Q : P)[(py - 1) * cw + px - 1] += r[j * bw + i];
                }
            free(r);
        }
        for (int i = 0; i < cw * cw; i++) {
            double d = P[i] - Q[i];
            ss += d * d;
            mx = fmax(mx, fabs(d));
            peak = fmax(peak, Q[i]);
            np++;
        }
    }
    *rms = sqrt(ss / np);
    *mxo = mx;
    *pko = peak;
    free(P);
    free(Q);
    mp_prf_work_free(&w);
}

/* The PRFs of two PSF files at 16 phases on one canvas. */
static int do_cmp(const char *built, const char *truth)
{
    char err[MP_ERRLEN], warn[MP_ERRLEN];
    mp_psf_field fb, ft;
    if (mp_psf_field_read(built, 0, 0, &fb, NULL, NULL, warn, err) ||
        mp_psf_field_read(truth, 0, 0, &ft, NULL, NULL, warn, err))
        return fprintf(stderr, "psfb: %s\n", err), 1;
    mp_psf b, t;
    memset(&b, 0, sizeof b);
    memset(&t, 0, sizeof t);
    double xc = 0.5 * (NX + 1);
    if (mp_psf_field_eval(&fb, xc, xc, &b, err) || mp_psf_field_eval(&ft, xc, xc, &t, err))
        return fprintf(stderr, "psfb: %s\n", err), 1;
    int cw = 2 * (int)RAD + 12;
    double *P = calloc((size_t)cw * cw, sizeof *P), *Q = calloc((size_t)cw * cw, sizeof *Q);
    double ss = 0, mx = 0, peak = 0, sb = 0, st = 0;
    long np = 0;
    mp_prf_work w;
    memset(&w, 0, sizeof w);
    for (int ph = 0; ph < 16; ph++) {
        double x = cw / 2 + 0.25 * (ph % 4), y = cw / 2 + 0.25 * (ph / 4);
        memset(P, 0, (size_t)cw * cw * sizeof *P);
        memset(Q, 0, (size_t)cw * cw * sizeof *Q);
        for (int k = 0; k < 2; k++) {
            mp_prf_model m = {k ? &t : &b, NULL, 10};
            long x0, y0;
            int bw, bh;
            mp_prf_box(&m, x, y, &x0, &y0, &bw, &bh);
            double *r = malloc(sizeof(double) * bw * bh);
            mp_prf_render(&m, x, y, r, NULL, NULL, &w);
            for (int j = 0; j < bh; j++)
                for (int i = 0; i < bw; i++) {
                    long px = x0 + i, py = y0 + j;
                    if (px >= 1 && px <= cw && py >= 1 && py <= cw)
                        (k ? Q : P)[(py - 1) * cw + px - 1] += r[j * bw + i];
                }
            free(r);
        }
        for (int i = 0; i < cw * cw; i++) {
            double d = P[i] - Q[i];
            ss += d * d;
            mx = fmax(mx, fabs(d));
            peak = fmax(peak, Q[i]);
            if (ph == 0) {
                sb += P[i];
                st += Q[i];
            }
            np++;
        }
    }
    printf("psfb cmp: built %s (x%d, order %d, sum %.4f) vs true %s (x%d, sum %.4f) at the "
           "centre, PRF at 16 phases: rms %.3g, largest %.3g of the peak %.4g (rms %.2f %%, "
           "largest %.2f %%); light on the canvas %.4f vs %.4f\n", built, fb.os, fb.order, fb.sum,
           truth, ft.os, ft.sum, sqrt(ss / np), mx, peak, 100 * sqrt(ss / np) / peak,
           100 * mx / peak, sb, st);
    if (fb.os == ft.os) {
        int n = b.nx < t.nx ? b.nx : t.nx, ob = (b.nx - n) / 2, ot = (t.nx - n) / 2;
        double s2 = 0, m2 = 0;
        for (int j = 0; j < n; j++)
            for (int i = 0; i < n; i++) {
                double d = b.t[(j + ob) * b.nx + i + ob] - t.t[(j + ot) * t.nx + i + ot];
                s2 += d * d;
                m2 = fmax(m2, fabs(d));
            }
        printf("psfb cmp: elements (x%d, %dx%d): rms %.3g, largest %.3g\n", fb.os, n, n,
               sqrt(s2 / n / n), m2);
    }
    free(P);
    free(Q);
    mp_prf_work_free(&w);
    mp_psf_free(&b);
    mp_psf_free(&t);
    mp_psf_field_free(&fb);
    mp_psf_field_free(&ft);
    return 0;
}

/* The normalised residual near the stars: z = (res − median res)/σ with
 * σ² = max(data, 0) + RON² (the data's own Poisson and read noise), over
 * the pixels within r px of a catalog star (XPSF/YPSF_IMAGE); robust σ
 * (IQR/1.349) and the median |z|.  FRAME and RES in electrons. */
/* near[] |= the pixels within r px of CAT's stars (XPSF/YPSF_IMAGE). */
static int mark_near(const char *cat, double r, long nx, long ny, char *near, size_t *nstar, char *err)
{
    mp_table t;
    mp_table_init(&t);
    if (mp_table_read(cat, &t, err))
        return 1;
    int cx = mp_table_col(&t, "XPSF_IMAGE"), cy = mp_table_col(&t, "YPSF_IMAGE");
    if (cx < 0 || cy < 0) {
        snprintf(err, MP_ERRLEN, "%s: no XPSF_IMAGE/YPSF_IMAGE column", cat);
        mp_table_free(&t);
        return 1;
    }
    for (size_t k = 0; k < t.nrow; k++) {
        double x = mp_table_get(&t, k, cx), y = mp_table_get(&t, k, cy);
        for (long j = (long)floor(y - r); j <= (long)ceil(y + r); j++)
            for (long i = (long)floor(x - r); i <= (long)ceil(x + r); i++)
                if (i >= 1 && j >= 1 && i <= nx && j <= ny && hypot(i - x, j - y) <= r)
                    near[(j - 1) * nx + i - 1] = 1;
    }
    *nstar += t.nrow;
    mp_table_free(&t);
    return 0;
}

static int do_resid(const char *frame, const char *res, const char *cat, double r, double ron,
                    const char *cat2)
{
    char err[MP_ERRLEN];
    mp_image f, q;
    memset(&f, 0, sizeof f);
    memset(&q, 0, sizeof q);
    if (mp_image_read(frame, &f, err) || mp_image_read(res, &q, err))
        return fprintf(stderr, "psfb: %s\n", err), 1;
    if (f.nx != q.nx || f.ny != q.ny)
        return fprintf(stderr, "psfb: %s and %s differ in size\n", frame, res), 1;
    long n = f.nx * f.ny;
    char *near = calloc((size_t)n, 1);
    double *v = malloc(sizeof(double) * n), *z = malloc(sizeof(double) * n);
    size_t nstar = 0;
    if (!near || !v || !z)
        return fprintf(stderr, "psfb: out of memory\n"), 1;
    if (mark_near(cat, r, f.nx, f.ny, near, &nstar, err) ||
        (cat2 && mark_near(cat2, r, f.nx, f.ny, near, &nstar, err)))
        return fprintf(stderr, "psfb: %s\n", err), 1;
    long m = 0;
    for (long i = 0; i < n; i++)
        if (isfinite(q.pix[i]))
            v[m++] = q.pix[i];
    double med = median(v, (int)m);
    long nz = 0;
    for (long i = 0; i < n; i++)
        if (near[i] && isfinite(q.pix[i]) && isfinite(f.pix[i]))
            z[nz++] = (q.pix[i] - med) / sqrt(fmax(f.pix[i], 0.0) + ron * ron);
    qsort(z, (size_t)nz, sizeof *z, cmpd);
    double iqr = nz ? z[3 * nz / 4] - z[nz / 4] : NAN;
    for (long i = 0; i < nz; i++)
        z[i] = fabs(z[i]);
    printf("psfb resid: %s: %ld pixels within %.1f px of %zu stars: robust sigma of the "
           "normalised residual %.3f, median |z| %.3f (sky of the residual %.2f)\n", res, nz, r,
           nstar, iqr / 1.349, median(z, (int)nz), med);
    free(near), free(v), free(z);
    mp_image_free(&f);
    mp_image_free(&q);
    return 0;
}

/* The noise model against a calibrated frame's error plane: the median
 * and quartiles of ERR^2 / (max(SCI, 0) + RON^2); and the median excess
 * ERR^2 - max(SCI, 0) - RON^2 in SCI bins (constant: an additive variance
 * the calibration carries, an effective read noise; growing as SCI^2: a
 * flat-field term). */
static int do_noise(const char *sci, const char *errp, double ron)
{
    char err[MP_ERRLEN];
    mp_image f, e;
    memset(&f, 0, sizeof f);
    memset(&e, 0, sizeof e);
    if (mp_image_read(sci, &f, err) || mp_image_read(errp, &e, err))
        return fprintf(stderr, "psfb: %s\n", err), 1;
    long n = f.nx * f.ny, m = 0;
    double *v = malloc(sizeof(double) * n), *w = malloc(sizeof(double) * n);
    if (!v || !w || e.nx * e.ny != n)
        return fprintf(stderr, "psfb: %s: out of memory or not the size of %s\n", errp, sci), 1;
    for (long i = 0; i < n; i++)
        if (isfinite(f.pix[i]) && isfinite(e.pix[i]) && e.pix[i] > 0)
            v[m++] = e.pix[i] * e.pix[i] / (fmax(f.pix[i], 0.0) + ron * ron);
    double mv = median(v, (int)m);
    printf("ERR^2 / (max(SCI,0) + RON^2): median %.4f (quartiles %.4f, %.4f) over %ld pixels\n", mv,
           v[m / 4], v[3 * m / 4], m);
    static const double lo[] = {-1e30, 300, 1000, 3000, 1e4, 3e4, 1e5};
    for (int b = 0; b < 6; b++) {
        long k = 0;
        for (long i = 0; i < n; i++)
            if (f.pix[i] >= lo[b] && f.pix[i] < lo[b + 1] && isfinite(e.pix[i]) && e.pix[i] > 0)
                w[k++] = e.pix[i] * e.pix[i] - fmax(f.pix[i], 0.0) - ron * ron;
        if (k)
            printf("SCI %6.0f..%-6.0f %6ld pixels: median ERR^2 - SCI - RON^2 = %.1f e-^2\n",
                   fmax(lo[b], 0.0), lo[b + 1], k, median(w, (int)k));
    }
    free(v), free(w);
    mp_image_free(&f);
    mp_image_free(&e);
    return 0;
}

/* Median CHI2_PSF of a catalog by FLUX_PSF (factors of 4) and by
 * GROUP_SIZE, to tell a profile error (grows with the flux) from
 * neighbours and the noise model (do not). */
static int do_chi2(const char *cat)
{
    char err[MP_ERRLEN];
    mp_table t;
    mp_table_init(&t);
    if (mp_table_read(cat, &t, err))
        return fprintf(stderr, "psfb: %s\n", err), 1;
    int cc = mp_table_col(&t, "CHI2_PSF"), cf = mp_table_col(&t, "FLUX_PSF"),
        cg = mp_table_col(&t, "GROUP_SIZE"), cl = mp_table_col(&t, "FLAGS");
    if (cc < 0 || cf < 0)
        return fprintf(stderr, "psfb: %s: no CHI2_PSF/FLUX_PSF\n", cat), 1;
    double *v = malloc(sizeof(double) * (t.nrow + 1));
    if (!v)
        return 1;
    for (int pass = 0; pass < 2; pass++) {
        printf(pass ? "E [e-]         stars  median CHI2_PSF  (FLAGS 0 only)\n"
                    : "E [e-]         stars  median CHI2_PSF  (all)\n");
        for (double lo = 1e2; lo < 1e7; lo *= 4) {
            int n = 0;
            for (size_t k = 0; k < t.nrow; k++) {
                double E = mp_table_get(&t, k, cf);
                if (E >= lo && E < 4 * lo && (!pass || cl < 0 || mp_table_get(&t, k, cl) == 0))
                    v[n++] = mp_table_get(&t, k, cc);
            }
            if (n)
                printf("%8.3g..%-8.3g %5d  %.2f\n", lo, 4 * lo, n, median(v, n));
        }
    }
    int ci = mp_table_col(&t, "GROUP_ID");
    if (ci >= 0 && cl >= 0) {
        /* A group's CHI2_PSF is its fit's: one saturated member (FLAGS
         * 1: its core has no weight, its halo and bleed trail do) sets it
         * for every star of the group. */
        /* CHI2STAR_PSF (each star's own disc), where the fit wrote it:
         * beside the group's, by the same split. */
        int cs = mp_table_col(&t, "CHI2STAR_PSF");
        double *w = malloc(sizeof(double) * (t.nrow + 1));
        if (!w)
            return free(v), 1;
        printf(cs >= 0 ? "groups         stars  median CHI2_PSF  median CHI2STAR_PSF\n"
                       : "groups         stars  median CHI2_PSF\n");
        for (int with = 0; with < 2; with++) {
            int n = 0;
            for (size_t k = 0; k < t.nrow; k++) {
                int sat = 0;
                for (size_t q = 0; q < t.nrow && !sat; q++)
                    sat = mp_table_get(&t, q, ci) == mp_table_get(&t, k, ci) &&
                          ((long)mp_table_get(&t, q, cl) & 1);
                if (sat == with) {
                    w[n] = cs >= 0 ? mp_table_get(&t, k, cs) : NAN;
                    v[n++] = mp_table_get(&t, k, cc);
                }
            }
            if (n && cs >= 0) {
                double mv = median(v, n);
                printf("%-14s %5d  %-15.2f  %.2f\n", with ? "a saturated" : "no saturated", n, mv,
                       median(w, n));
            } else if (n) {
                printf("%-14s %5d  %.2f\n", with ? "a saturated" : "no saturated", n, median(v, n));
            }
        }
        free(w);
    }
    if (cg >= 0) {
        printf("GROUP_SIZE     stars  median CHI2_PSF\n");
        int lim[] = {1, 2, 5, 10, 20, 1000000};
        for (int b = 0; b + 1 < 6; b++) {
            int n = 0;
            for (size_t k = 0; k < t.nrow; k++) {
                double g = mp_table_get(&t, k, cg);
                if (g >= lim[b] && g < lim[b + 1])
                    v[n++] = mp_table_get(&t, k, cc);
            }
            if (n)
                printf("%4d..%-9d %5d  %.2f\n", lim[b], lim[b + 1] - 1, n, median(v, n));
        }
    }
    free(v);
    mp_table_free(&t);
    return 0;
}

/* Encircled energy of a PSF file's table at the frame's centre: the
 * elements whose centres lie within r px of the table's centre, for a
 * few r (a flux-scale error of the fit shows as a difference inside the
 * fitting radius). */
static int do_ee(const char *file)
{
    char err[MP_ERRLEN], warn[MP_ERRLEN];
    mp_psf_field fb;
    if (mp_psf_field_read(file, 0, 0, &fb, NULL, NULL, warn, err))
        return fprintf(stderr, "psfb: %s\n", err), 1;
    mp_psf b;
    memset(&b, 0, sizeof b);
    double xc = 0.5 * (NX + 1);
    if (mp_psf_field_eval(&fb, xc, xc, &b, err))
        return fprintf(stderr, "psfb: %s\n", err), 1;
    static const double rr[] = {1, 1.5, 2, 3, 4, 5, 6, 7, 8, 9, 10, 11, 12, 16};
    printf("psfb ee: %s (x%d, %dx%d):", file, b.os, b.nx, b.ny);
    for (int q = 0; q < 14; q++) {
        double s = 0;
        for (int j = 0; j < b.ny; j++)
            for (int i = 0; i < b.nx; i++)
                if (hypot(i - (b.nx - 1) / 2.0, j - (b.ny - 1) / 2.0) <= rr[q] * b.os)
                    s += b.t[(size_t)j * b.nx + i];
        printf(" r%g %.4f", rr[q], s);
    }
    printf("\n");
    mp_psf_free(&b);
    mp_psf_field_free(&fb);
    return 0;
}

/* The builder alone: DIR's frame less every true star but the npsf
 * brightest (a perfect neighbour subtraction, drawn as the sim drew
 * them), those stars' PSF built at their true positions by one pass
 * (matphot psf's defaults, fwhm 3), written to DIR/ideal.psf.fits.  What
 * the builder's own algorithm costs, apart from crowding.  Stars fainter
 * than fkeep [e-] are left in (what undetected neighbours cost).  order
 * (−1: auto) and os (0: auto) as matphot psf's varorder and oversamp. */
static int do_ideal(const char *dir, const char *kind, int npsf, double fkeep, int order, int os)
{
    int seg = !strcmp(kind, "segmented");
    char err[MP_ERRLEN], path[1024];
    mp_datapars dp = {NAN, NAN, NAN, NAN, "", 0, 0, 0, "", 0, 0};
    mp_frame f;
    mp_table tr;
    mp_table_init(&tr);
    snprintf(path, sizeof path, "%s/frame.fits", dir);
    if (mp_frame_read(path, &dp, &f, err))
        return fprintf(stderr, "psfb: %s\n", err), 1;
    snprintf(path, sizeof path, "%s/truth.dat", dir);
    if (mp_table_read(path, &tr, err))
        return fprintf(stderr, "psfb: %s\n", err), 1;
    int tx = mp_table_col(&tr, "X_IMAGE"), ty = mp_table_col(&tr, "Y_IMAGE"),
        tf = mp_table_col(&tr, "FLUX");
    size_t nt = tr.nrow, *ord = malloc(nt * sizeof *ord);
    for (size_t i = 0; i < nt; i++)
        ord[i] = i;
    for (size_t i = 1; i < nt; i++)       /* by flux, brightest first */
        for (size_t j = i; j > 0 && mp_table_get(&tr, ord[j], tf) > mp_table_get(&tr, ord[j - 1], tf); j--) {
            size_t q = ord[j];
            ord[j] = ord[j - 1];
            ord[j - 1] = q;
        }
    int m = 2 * (int)ceil(RAD * TOS) + 1, n = m;
    double *tab = malloc(sizeof(double) * m * m);
    snprintf(path, sizeof path, "%s/true.psf.fits", dir);
    mp_psf tp;
    if (seg) {
        if (mp_psf_read(path, 0, 0, &tp, NULL, err))
            return fprintf(stderr, "psfb: %s\n", err), 1;
        memcpy(tab, tp.t, sizeof(double) * m * m);
        mp_psf_free(&tp);
    }
    double *x = malloc(nt * sizeof *x), *y = malloc(nt * sizeof *y), *fl = malloc(nt * sizeof *fl);
    size_t np = 0;
    for (size_t q = 0; q < nt; q++) {
        size_t i = ord[q];
        double sx = mp_table_get(&tr, i, tx), sy = mp_table_get(&tr, i, ty);
        /* The brightest, none within 20 px of another PSF star (whose
         * light would then stay in its cut-out). */
        int lone = (int)np < npsf && sx >= 15 && sy >= 15 && sx <= NX - 15 && sy <= NX - 15;
        for (size_t k = 0; lone && k < np; k++)
            lone = hypot(sx - x[k], sy - y[k]) > 20.0;
        if (lone) {
            x[np] = sx, y[np] = sy, fl[np++] = NAN;
            continue;
        }
        if (mp_table_get(&tr, i, tf) < fkeep)
            continue;
        if (!seg)
            var_table(sx, sy, tab, &n);
        mp_sim_prf p = {MP_SIM_TABLE, 0, tab, n, n, TOS, NULL, 0, 1.0, 0.0};
        mp_sim_add_star_float(&p, sx, sy, -mp_table_get(&tr, i, tf), f.im.pix, NX, NX);
    }
    mp_epsf_opts o;
    mp_epsf_opts_default(3.0, NX, NX, &o);
    o.x0 = o.y0 = 0.5 * (NX + 1);
    o.xs = o.ys = 0.5 * NX;
    o.order = order;
    o.os = os;
    mp_epsf e;
    memset(&e, 0, sizeof e);
    mp_epsf_report rep;
    memset(&rep, 0, sizeof rep);
    mp_psf_field fld;
    if (mp_epsf_pass(&f, f.im.pix, 0, NULL, NULL, x, y, fl, np, &o, &e, &rep, NULL, err) ||
        mp_epsf_field(&e, &fld, err))
        return fprintf(stderr, "psfb: %s\n", err), 1;
    snprintf(path, sizeof path, "%s/ideal.psf.fits", dir);
    if (mp_psf_field_write(path, &fld, NULL, 0, err))
        return fprintf(stderr, "psfb: %s\n", err), 1;
    printf("psfb ideal: %s: %s\n", path, rep.what);
    mp_psf_field_free(&fld);
    mp_epsf_free(&e);
    free(x), free(y), free(fl), free(tab), free(ord);
    mp_table_free(&tr);
    mp_frame_free(&f);
    return 0;
}

int main(int argc, char **argv)
{
    /* psfb varfloor [ORDER] [OUT.fits]: order 2 unless a digit is given */
    if (argc >= 2 && argc <= 4 && !strcmp(argv[1], "varfloor")) {
        int has_ord = argc >= 3 && isdigit((unsigned char)argv[2][0]) && !argv[2][1];
        int ord = has_ord ? argv[2][0] - '0' : 2;
        const char *out = argc > 2 + has_ord ? argv[2 + has_ord] : NULL;
        if (ord > MP_PSF_MAXORDER || argc > 3 + has_ord)
            return fprintf(stderr, "psfb: varfloor [0..%d] [OUT.fits]\n", MP_PSF_MAXORDER), 2;
        return do_varfloor(ord, out) ? 1 : 0;
    }
    if (argc == 4 && !strcmp(argv[1], "gridfloor") && atoi(argv[2]) >= 2 &&
        atoi(argv[2]) <= 16)
        return do_gridfloor(atoi(argv[2]), argv[3]) ? 1 : 0;
    if (argc >= 5 && argc <= 8 && !strcmp(argv[1], "ideal"))
        return do_ideal(argv[2], argv[3], atoi(argv[4]), argc >= 6 ? atof(argv[5]) : 0.0,
                        argc >= 7 ? atoi(argv[6]) : -1, argc >= 8 ? atoi(argv[7]) : 0) ? 1 : 0;
    if (argc == 3 && !strcmp(argv[1], "ee"))
        return do_ee(argv[2]) ? 1 : 0;
    if ((argc == 7 || argc == 8) && !strcmp(argv[1], "resid"))
        return do_resid(argv[2], argv[3], argv[4], atof(argv[5]), atof(argv[6]),
                        argc == 8 ? argv[7] : NULL) ? 1 : 0;
    if (argc == 5 && !strcmp(argv[1], "noise"))
        return do_noise(argv[2], argv[3], atof(argv[4])) ? 1 : 0;
    if (argc == 3 && !strcmp(argv[1], "chi2"))
        return do_chi2(argv[2]) ? 1 : 0;
    if ((argc == 4 || argc == 5) && !strcmp(argv[1], "sim"))
        return do_sim(argv[2], argv[3], argc == 5 ? atol(argv[4]) : 0) ? 1 : 0;
    if ((argc == 4 || (argc == 5 && !strcmp(argv[4], "zp"))) && !strcmp(argv[1], "match"))
        return do_match(argv[2], argv[3], argc == 5) ? 1 : 0;
    if (argc >= 4 && !strcmp(argv[1], "pool"))
        return do_pool(argv[2], argv + 3, argc - 3) ? 1 : 0;
    if (argc == 3 && !strcmp(argv[1], "leverage"))
        return do_leverage(argv[2]) ? 1 : 0;
    if (argc == 3 && !strcmp(argv[1], "cmpvar"))
        return do_cmpvar(argv[2]) ? 1 : 0;
    if (argc == 4 && !strcmp(argv[1], "cmp"))
        return do_cmp(argv[2], argv[3]) ? 1 : 0;
    fprintf(stderr, "usage: psfb sim DIR segmented|variable | psfb match DIR ROOT [zp] | "
            "psfb pool ROOT DIR... | psfb cmp BUILT.fits TRUE.fits | psfb ee PSF.fits | psfb ideal DIR KIND NPSF [FKEEP [ORDER [OS]]] | "
            "psfb varfloor [ORDER] [OUT.fits] | psfb gridfloor N OUT.fits | psfb leverage PSF.fits | psfb resid FRAME RES CAT R RON [CAT2] | "
            "psfb noise SCI ERR RON | psfb chi2 CAT\n");
    return 2;
}
