/*
 * crowded.c — the crowded-field case of `make validate` (issue 3, "the
 * staged reduction"): a simulated 1024×1024 frame of 5000 stars reduced by
 * `matphot pipeline`, and the match of its catalog against the truth.
 *
 *   crowded sim DIR
 *       DIR/frame.fits (ADU, gain 1, SATURATE card), DIR/psf.fits (the 2×
 *       table of the Gaussian, OVERSAMP 2), DIR/truth.dat (ASCII_HEAD).
 *   crowded match DIR ROOT LABEL
 *       reads DIR/truth.dat, DIR/ROOT.cat and DIR/ROOT.report; writes
 *       DIR/ROOT.md (the report section) and DIR/ROOT_{cmag,csep,err}.dat
 *       (for gnuplot); prints a one-line summary on stdout.
 *
 * The scene (fixed seed, see SEED):
 *   - Gaussian PSF, FWHM 3 px, integrated exactly over pixels
 *     (MP_SIM_GAUSS: positions are continuous, not on a grid); fitted by the
 *     pipeline with the 2× table of the same Gaussian (built like
 *     sim/task_sim.c's write_psf: the Gaussian of σ·2 drawn at the centre of
 *     a fine frame, half-size ceil(4·FWHM·2) elements).
 *   - 4580 field stars, uniform over the frame, mag uniform in [−14, −6];
 *     200 close pairs: primary uniform in [10.5, 1014.5]², mag uniform in
 *     [−14, −8], companion at a separation uniform in 0.5–2 FWHM (uniform
 *     angle), 0–2 mag fainter (uniform); 20 bright stars, mag uniform in
 *     [−16.5, −15.5], uniform in [20.5, 1004.5]² — all of them saturate.
 *     5000 stars in all; 0 mag = 1 e−.
 *   - Sky plane 100 e− at pixel (1,1) rising to 150 e− at (1024,1024)
 *     (25 e− across x plus 25 e− across y); Poisson + read noise 3 e−;
 *     gain 1; pixels above SATURATE = 60000 ADU clipped to it.
 */
#include <math.h>
#include <stddef.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "catalog/catalog.h"
#include "fit/fit.h"
#include "io/io.h"
#include "sim/sim.h"
#include "tests/validate/crowded/joint_bound.h"

#define NX 1024
#define NY 1024
#define FWHM 3.0
#define OS 2
#define RON 3.0
#define SATURATE 60000.0
#define SKY0 100.0
#define SKYGRAD 50.0          /* corner to corner */
#define NFIELD 4580
#define NPAIR 200
#define NBRIGHT 20
#define SEED 20261122ULL
#define MATCHR 1.0            /* [px] */
#define FITRAD 5.0            /* the pipeline's default fitrad [px]: the joint bound's regions */

enum { K_FIELD = 0, K_PRIMARY = 1, K_COMPANION = 2, K_BRIGHT = 3 };

static double sky_at(double x, double y)
{
    return SKY0 + 0.5 * SKYGRAD * (x - 1) / (NX - 1) + 0.5 * SKYGRAD * (y - 1) / (NY - 1);
}

/* ---- small statistics ------------------------------------------------- */

static int cmp_d(const void *a, const void *b)
{
    double x = *(const double *)a, y = *(const double *)b;
    return (x > y) - (x < y);
}

/* Quantile q of the n finite values of v (sorted in place); NaN if none. */
static double quant(double *v, int n, double q)
{
    int m = 0;
    for (int i = 0; i < n; i++)
        if (isfinite(v[i]))
            v[m++] = v[i];
    if (m == 0)
        return NAN;
    qsort(v, (size_t)m, sizeof *v, cmp_d);
    double p = q * (m - 1);
    int i = (int)floor(p);
    if (i >= m - 1)
        return v[m - 1];
    return v[i] + (p - i) * (v[i + 1] - v[i]);
}

static double median(double *v, int n) { return quant(v, n, 0.5); }

static double rsigma(double *v, int n)
{
    double q1 = quant(v, n, 0.25), q3 = quant(v, n, 0.75);
    return (q3 - q1) / 1.349;
}

/* ---- the simulation ----------------------------------------------------- */

typedef struct {
    double x, y, mag, flux;
    int kind, pair;           /* pair: NUMBER of the other member, 0 none */
    double sep;               /* pair separation [FWHM] */
} star;

static int add(mp_table *t, const char *name, const char *fmt, int is_int, const char *desc,
               const char *unit)
{
    int c = mp_table_add_col(t, name);
    if (c < 0)
        return -1;
    snprintf(t->cols[c].fmt, sizeof t->cols[c].fmt, "%s", fmt);
    snprintf(t->cols[c].desc, sizeof t->cols[c].desc, "%s", desc);
    snprintf(t->cols[c].unit, sizeof t->cols[c].unit, "%s", unit);
    t->cols[c].is_int = is_int;
    return c;
}

static int write_psf(const char *path, double sigma, char *err)
{
    int h = (int)ceil(4.0 * FWHM * OS), n = 2 * h + 1;
    mp_sim_prf fine = {.kind = MP_SIM_GAUSS, .sigma = sigma * OS, .volume = 1.0};
    double *t = calloc((size_t)n * n, sizeof *t);
    if (!t) {
        snprintf(err, MP_ERRLEN, "%.400s: out of memory", path);
        return 1;
    }
    int rc = mp_sim_add_star(&fine, h + 1.0, h + 1.0, 1.0, t, n, n);
    if (rc)
        snprintf(err, MP_ERRLEN, "%.400s: cannot draw the PSF", path);
    mp_card cards[2] = {{"OVERSAMP", OS, NULL, "table elements per detector pixel"},
                        {"FWHM", FWHM, NULL, "[pixel] Gaussian FWHM"}};
    if (!rc)
        rc = mp_image_write(path, t, n, n, -64, cards, 2, err);
    free(t);
    return rc;
}

/* The S/N of a star at its Cramér–Rao bound, alone on its sky (design.md
 * §6: E, X, Y, B fitted, the exact pixel-integrated PRF over 15×15 px,
 * position derivatives by central differences of the exact render). */
#define BB 15
static double snr_bound(const mp_sim_prf *prf, double x, double y, double E, double B)
{
    double p[BB * BB] = {0}, a[BB * BB] = {0}, b[BB * BB] = {0}, c[BB * BB] = {0},
           d[BB * BB] = {0}, dx[BB * BB], dy[BB * BB], sd[4];
    const double h = 1e-3, fx = x - floor(x), fy = y - floor(y);
    double cx = BB / 2 + 1 + fx, cy = BB / 2 + 1 + fy;
    mp_sim_add_star(prf, cx, cy, 1.0, p, BB, BB);
    mp_sim_add_star(prf, cx + h, cy, 1.0, a, BB, BB);
    mp_sim_add_star(prf, cx - h, cy, 1.0, b, BB, BB);
    mp_sim_add_star(prf, cx, cy + h, 1.0, c, BB, BB);
    mp_sim_add_star(prf, cx, cy - h, 1.0, d, BB, BB);
    for (int i = 0; i < BB * BB; i++) {
        dx[i] = (a[i] - b[i]) / (2 * h);
        dy[i] = (c[i] - d[i]) / (2 * h);
    }
    if (mp_crlb(p, dx, dy, BB * BB, E, B, RON, sd))
        return NAN;
    return E / sd[0];
}

static int do_sim(const char *dir)
{
    char err[MP_ERRLEN], path[4096];
    const int n = NFIELD + 2 * NPAIR + NBRIGHT;
    const double sigma = FWHM / (2.0 * sqrt(2.0 * log(2.0)));
    star *s = calloc((size_t)n, sizeof *s);
    double *img = malloc(sizeof(double) * NX * NY);
    double *alone = malloc(sizeof(double) * 9);
    if (!s || !img || !alone) {
        fprintf(stderr, "crowded: out of memory\n");
        return 1;
    }
    /* CROWDED_SEED: another realisation of the same scene (the report's
     * frame is SEED's; others serve checks over several frames). */
    const char *es = getenv("CROWDED_SEED");
    unsigned long long seed = es && *es ? strtoull(es, NULL, 10) : SEED;
    mp_rng r;
    mp_rng_seed(&r, seed);
    int k = 0;
    for (int i = 0; i < NFIELD; i++, k++) {
        s[k].x = 0.5 + NX * mp_rng_uniform(&r);
        s[k].y = 0.5 + NY * mp_rng_uniform(&r);
        s[k].mag = -14.0 + 8.0 * mp_rng_uniform(&r);
        s[k].kind = K_FIELD;
    }
    for (int i = 0; i < NPAIR; i++, k += 2) {
        star *p = &s[k], *c = &s[k + 1];
        p->x = 10.5 + (NX - 20) * mp_rng_uniform(&r);
        p->y = 10.5 + (NY - 20) * mp_rng_uniform(&r);
        p->mag = -14.0 + 6.0 * mp_rng_uniform(&r);
        double sep = 0.5 + 1.5 * mp_rng_uniform(&r);
        double th = 2.0 * M_PI * mp_rng_uniform(&r);
        c->x = p->x + sep * FWHM * cos(th);
        c->y = p->y + sep * FWHM * sin(th);
        c->mag = p->mag + 2.0 * mp_rng_uniform(&r);
        p->kind = K_PRIMARY;
        c->kind = K_COMPANION;
        p->pair = k + 2;
        c->pair = k + 1;
        p->sep = c->sep = sep;
    }
    for (int i = 0; i < NBRIGHT; i++, k++) {
        s[k].x = 20.5 + (NX - 40) * mp_rng_uniform(&r);
        s[k].y = 20.5 + (NY - 40) * mp_rng_uniform(&r);
        s[k].mag = -16.5 + 1.0 * mp_rng_uniform(&r);
        s[k].kind = K_BRIGHT;
    }
    for (int i = 0; i < n; i++)
        s[i].flux = pow(10.0, -0.4 * s[i].mag);

    for (long y = 1; y <= NY; y++)
        for (long x = 1; x <= NX; x++)
            img[(y - 1) * NX + (x - 1)] = sky_at((double)x, (double)y);
    mp_sim_prf prf = {.kind = MP_SIM_GAUSS, .sigma = sigma, .volume = 1.0};
    for (int i = 0; i < n; i++)
        if (mp_sim_add_star(&prf, s[i].x, s[i].y, s[i].flux, img, NX, NY)) {
            fprintf(stderr, "crowded: cannot draw star %d\n", i + 1);
            return 1;
        }
    /* Each star's bound fitted with its neighbours, on the expected image. */
    double *bse = malloc(sizeof(double) * (size_t)n), *bsx = malloc(sizeof(double) * (size_t)n);
    double *bsy = malloc(sizeof(double) * (size_t)n);
    jb_star *js = malloc(sizeof *js * (size_t)n);
    int jmax = 0;
    if (!bse || !bsx || !bsy || !js) {
        fprintf(stderr, "crowded: out of memory\n");
        return 1;
    }
    for (int i = 0; i < n; i++)
        js[i] = (jb_star){s[i].x, s[i].y, s[i].flux};
    jb_scene jsc = {sigma, RON, SATURATE, FITRAD, NX, NY, img, NULL, 0};
    if (joint_bounds(&jsc, js, n, bse, bsx, bsy, &jmax)) {
        fprintf(stderr, "crowded: out of memory\n");
        return 1;
    }
    mp_sim_add_noise(&r, img, (long)NX * NY, RON);
    unsigned char *clip = calloc((size_t)NX * NY, 1);
    if (!clip) {
        fprintf(stderr, "crowded: out of memory\n");
        return 1;
    }
    long nclip = 0;
    for (long i = 0; i < (long)NX * NY; i++)
        if (img[i] > SATURATE) {
            img[i] = SATURATE;      /* gain 1: electrons = ADU */
            clip[i] = 1;
            nclip++;
        }

    mp_card cards[] = {
        {"BUNIT", 0, "ADU", "pixel unit"},
        {"GAIN", 1.0, NULL, "[e-/ADU] gain"},
        {"RDNOISE", RON, NULL, "[e-] read noise"},
        {"SATURATE", SATURATE, NULL, "[ADU] saturation level"},
        {"EXPTIME", 1.0, NULL, "[s] exposure time"},
        {"FWHM", FWHM, NULL, "[pixel] simulated Gaussian PSF FWHM"},
        {"SEED", (double)seed, NULL, "crowded.c random seed"},
        {"SKY0", SKY0, NULL, "[e-] sky at pixel (1,1)"},
        {"SKYGRAD", SKYGRAD, NULL, "[e-] sky rise from (1,1) to (NX,NY)"},
        {"ORIGIN", 0, "tests/validate/crowded/crowded.c", "simulated frame"},
    };
    snprintf(path, sizeof path, "%s/frame.fits", dir);
    if (mp_image_write(path, img, NX, NY, -32, cards, (int)(sizeof cards / sizeof cards[0]), err)) {
        fprintf(stderr, "crowded: %s\n", err);
        return 1;
    }
    snprintf(path, sizeof path, "%s/psf.fits", dir);
    if (write_psf(path, sigma, err)) {
        fprintf(stderr, "crowded: %s\n", err);
        return 1;
    }

    /* Truth table, with per star: whether the star alone on its sky reaches
     * SATURATE in its brightest pixel (noiseless), the clipped pixels within
     * 3 px of it, and the distance to its nearest neighbour. */
    mp_table t;
    mp_table_init(&t);
    int cn = add(&t, "NUMBER", "%6.0f", 1, "Running star number", "");
    int cx = add(&t, "X_TRUE", "%14.8f", 0, "True x position", "pixel");
    int cy = add(&t, "Y_TRUE", "%14.8f", 0, "True y position", "pixel");
    int cf = add(&t, "FLUX_TRUE", "%14.4f", 0, "True intensity E", "electron");
    int cm = add(&t, "MAG_TRUE", "%9.5f", 0, "True magnitude (0 mag = 1 e-)", "mag");
    int cs = add(&t, "SKY_TRUE", "%9.4f", 0, "True sky at the star", "electron");
    int ck = add(&t, "KIND", "%2.0f", 1, "0 field, 1 pair primary, 2 companion, 3 bright", "");
    int cp = add(&t, "PAIR", "%6.0f", 1, "NUMBER of the other pair member (0 none)", "");
    int cd = add(&t, "SEP_FWHM", "%8.5f", 0, "Pair separation", "FWHM");
    int cq = add(&t, "SAT_SELF", "%2.0f", 1, "Star alone + sky reaches SATURATE", "");
    int cc = add(&t, "NSATPIX", "%4.0f", 1, "Clipped pixels within 3 px", "");
    int cnn = add(&t, "NN_DIST", "%9.4f", 0, "Distance to the nearest other star", "pixel");
    int csn = add(&t, "SNR_BOUND", "%10.3f", 0, "S/N at the Cramer-Rao bound, alone on its sky", "");
    int cje = add(&t, "FLUXERR_JOINT", "%12.4f", 0, "sigma_E at the bound fitted with its neighbours", "electron");
    int cjx = add(&t, "POSERR_JOINT", "%10.6f", 0, "rms of sigma_X, sigma_Y at the same bound", "pixel");
    if (cn < 0 || cx < 0 || cy < 0 || cf < 0 || cm < 0 || cs < 0 || ck < 0 || cp < 0 ||
        cd < 0 || cq < 0 || cc < 0 || cnn < 0 || csn < 0 || cje < 0 || cjx < 0) {
        fprintf(stderr, "crowded: out of memory\n");
        return 1;
    }
    long nsat = 0;
    for (int i = 0; i < n; i++) {
        long row = mp_table_add_row(&t);
        if (row < 0) {
            fprintf(stderr, "crowded: out of memory\n");
            return 1;
        }
        /* Star alone: its brightest pixel among the 3x3 around its centre. */
        long px = lround(s[i].x), py = lround(s[i].y);
        double peak = 0;
        for (int j = 0; j < 9; j++)
            alone[j] = 0;
        mp_sim_add_star(&prf, s[i].x - (double)px + 2.0, s[i].y - (double)py + 2.0,
                        s[i].flux, alone, 3, 3);
        for (int j = 0; j < 9; j++)
            peak = fmax(peak, alone[j]);
        int satself = peak + sky_at(s[i].x, s[i].y) > SATURATE;
        nsat += satself;
        int ncl = 0;
        for (long yy = py - 3; yy <= py + 3; yy++)
            for (long xx = px - 3; xx <= px + 3; xx++)
                if (xx >= 1 && xx <= NX && yy >= 1 && yy <= NY &&
                    hypot((double)xx - s[i].x, (double)yy - s[i].y) <= 3.0 &&
                    clip[(yy - 1) * NX + (xx - 1)])
                    ncl++;
        double nn = INFINITY;
        for (int j = 0; j < n; j++)
            if (j != i)
                nn = fmin(nn, hypot(s[j].x - s[i].x, s[j].y - s[i].y));
        double v[15] = {i + 1, s[i].x, s[i].y, s[i].flux, s[i].mag, sky_at(s[i].x, s[i].y),
                        s[i].kind, s[i].pair, s[i].kind == K_PRIMARY || s[i].kind == K_COMPANION
                        ? s[i].sep : NAN, satself, ncl, nn,
                        snr_bound(&prf, s[i].x, s[i].y, s[i].flux, sky_at(s[i].x, s[i].y)),
                        bse[i], sqrt(0.5 * (bsx[i] * bsx[i] + bsy[i] * bsy[i]))};
        int col[15] = {cn, cx, cy, cf, cm, cs, ck, cp, cd, cq, cc, cnn, csn, cje, cjx};
        for (int j = 0; j < 15; j++)
            mp_table_set(&t, (size_t)row, col[j], v[j]);
    }
    snprintf(path, sizeof path, "%s/truth.dat", dir);
    if (mp_table_write(path, &t, MP_TAB_ASCII_HEAD, err)) {
        fprintf(stderr, "crowded: %s\n", err);
        return 1;
    }
    printf("crowded: %s/frame.fits: %d stars (%d field, %d pairs, %d bright), "
           "%ld saturated stars, %ld clipped pixels; joint bounds over sets of up to %d stars\n",
           dir, n, NFIELD, NPAIR, NBRIGHT, nsat, nclip, jmax);
    free(bse);
    free(bsx);
    free(bsy);
    free(js);
    mp_table_free(&t);
    free(s);
    free(img);
    free(alone);
    free(clip);
    return 0;
}

/* ---- the match ---------------------------------------------------------- */

typedef struct { int t, c; double d; } cand;

static int cmp_cand(const void *a, const void *b)
{
    const cand *x = a, *y = b;
    return (x->d > y->d) - (x->d < y->d);
}

static int need(const mp_table *t, const char *name, const char *file)
{
    int c = mp_table_col(t, name);
    if (c < 0)
        fprintf(stderr, "crowded: %s: no column %s\n", file, name);
    return c;
}

/* Per matched star: the normalised errors. */
typedef struct {
    double dmag_model;   /* |Δmag| / σ_mag,model */
    double dr_model;     /* Δr / σ_X,model */
    double ne, nx, ny;   /* (E−Et)/σE, (X−Xt)/σX, (Y−Yt)/σY (the fit's own σ) */
    double dmag;         /* MAG − MAG_TRUE */
    double ferr_ratio;   /* FLUXERR_PSF / FLUXERR_MODEL */
    double dmag_joint;   /* |E − Et| / σ_E at the joint bound (joint_bound.h) */
    double dr_joint;     /* Δr / σ_X at the joint bound */
    double ne_res;       /* ne, or NaN when a true star the catalog does not hold
                          * lies within 2 FWHM (an unresolved blend) */
    double snr_miss;     /* the largest S/N at the joint bound (E_true /
                          * FLUXERR_JOINT) of those stars; NaN: none */
} errs;

/* Statistics of a set of matched stars. */
typedef struct {
    int n;
    double ph, as;            /* median(|Δmag|/σ_mag)/0.6745, median(Δr/σ_X)/1.1774 */
    double ne_med, ne_rs, nx_med, nx_rs, ny_med, ny_rs;
    double dmag_med;          /* bias [mag] */
    double ferr;              /* median FLUXERR_PSF/FLUXERR_MODEL */
    double phj, asj;          /* as ph, as over the joint bound */
    int nres;                 /* stars with ne_res, and its robust σ */
    double ne_rs_res;
} estat;

/* Copy one field of the selected stars into buf. */
static int gather(const errs *e, const int *idx, int n, size_t off, double *buf)
{
    for (int i = 0; i < n; i++)
        memcpy(&buf[i], (const char *)&e[idx[i]] + off, sizeof(double));
    return n;
}

static void stats_of(const errs *e, const int *idx, int n, estat *o, double *buf)
{
    o->n = n;
    o->ph = median(buf, gather(e, idx, n, offsetof(errs, dmag_model), buf)) / 0.6745;
    o->as = median(buf, gather(e, idx, n, offsetof(errs, dr_model), buf)) / 1.1774;
    o->ne_med = median(buf, gather(e, idx, n, offsetof(errs, ne), buf));
    o->ne_rs = rsigma(buf, gather(e, idx, n, offsetof(errs, ne), buf));
    o->nx_med = median(buf, gather(e, idx, n, offsetof(errs, nx), buf));
    o->nx_rs = rsigma(buf, gather(e, idx, n, offsetof(errs, nx), buf));
    o->ny_med = median(buf, gather(e, idx, n, offsetof(errs, ny), buf));
    o->ny_rs = rsigma(buf, gather(e, idx, n, offsetof(errs, ny), buf));
    o->dmag_med = median(buf, gather(e, idx, n, offsetof(errs, dmag), buf));
    o->ferr = median(buf, gather(e, idx, n, offsetof(errs, ferr_ratio), buf));
    o->phj = median(buf, gather(e, idx, n, offsetof(errs, dmag_joint), buf)) / 0.6745;
    o->asj = median(buf, gather(e, idx, n, offsetof(errs, dr_joint), buf)) / 1.1774;
    gather(e, idx, n, offsetof(errs, ne_res), buf);
    o->nres = 0;
    for (int i = 0; i < n; i++)
        o->nres += isfinite(buf[i]);
    o->ne_rs_res = rsigma(buf, n);
}

static void estat_row(FILE *f, const estat *s)
{
    if (s->n == 0) {
        fprintf(f, " 0 | – | – | – | – | – | – | – | – | – | – |");
        return;
    }
    fprintf(f, " %d | %.3f | %.3f | %.3f | %.3f | %+.4f | %+.3f, %.3f | %d, %.3f | %+.3f, %.3f "
            "| %+.3f, %.3f | %.3f |",
            s->n, s->phj, s->asj, s->ph, s->as, s->dmag_med, s->ne_med, s->ne_rs, s->nres,
            s->ne_rs_res, s->nx_med, s->nx_rs, s->ny_med, s->ny_rs, s->ferr);
}

static const char *EHEAD =
    " N | phot/joint | astro/joint | phot/model | astro/model | median Δmag | (E−Et)/σE med, rσ "
    "| no unfound star ≤ 2 FWHM: N, rσ (E−Et)/σE | (X−Xt)/σX med, rσ "
    "| (Y−Yt)/σY med, rσ | FLUXERR_PSF/MODEL |";
static const char *EALIGN = "---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|";

#define NMBIN 11            /* 1-mag bins centred on -16 ... -6 */
static const double SEPEDGE[5] = {0.5, 0.75, 1.0, 1.5, 2.0};
#define NSBIN 4

static int mbin(double mag)
{
    int b = (int)floor(mag + 16.5);     /* [-16.5,-15.5) -> 0 */
    return b < 0 ? 0 : b >= NMBIN ? NMBIN - 1 : b;
}

static int sbin(double sep)
{
    for (int b = 0; b < NSBIN; b++)
        if (sep < SEPEDGE[b + 1])
            return b;
    return NSBIN - 1;
}

static int do_match(const char *dir, const char *root, const char *label)
{
    char err[MP_ERRLEN], path[4096];
    mp_table tt, ct;
    snprintf(path, sizeof path, "%s/truth.dat", dir);
    if (mp_table_read(path, &tt, err)) {
        fprintf(stderr, "crowded: %s\n", err);
        return 1;
    }
    char catpath[4096];
    snprintf(catpath, sizeof catpath, "%s/%s.cat", dir, root);
    if (mp_table_read(catpath, &ct, err)) {
        fprintf(stderr, "crowded: %s\n", err);
        return 1;
    }
    int tx = need(&tt, "X_TRUE", path), ty = need(&tt, "Y_TRUE", path);
    int tf = need(&tt, "FLUX_TRUE", path), tm = need(&tt, "MAG_TRUE", path);
    int tk = need(&tt, "KIND", path), tp = need(&tt, "PAIR", path);
    int td = need(&tt, "SEP_FWHM", path), tq = need(&tt, "SAT_SELF", path);
    int tc = need(&tt, "NSATPIX", path);
    int tje = need(&tt, "FLUXERR_JOINT", path), tjx = need(&tt, "POSERR_JOINT", path);
    int kx = need(&ct, "XPSF_IMAGE", catpath), ky = need(&ct, "YPSF_IMAGE", catpath);
    int kex = need(&ct, "ERRX_PSF", catpath), key = need(&ct, "ERRY_PSF", catpath);
    int kf = need(&ct, "FLUX_PSF", catpath), kef = need(&ct, "FLUXERR_PSF", catpath);
    int kmag = need(&ct, "MAG_PSF", catpath), kfl = need(&ct, "FLAGS", catpath);
    int kfm = need(&ct, "FLUXERR_MODEL", catpath), kpm = need(&ct, "POSERR_MODEL", catpath);
    int kchi = need(&ct, "CHI2_PSF", catpath);
    if (tx < 0 || ty < 0 || tf < 0 || tm < 0 || tk < 0 || tp < 0 || td < 0 || tq < 0 ||
        tc < 0 || tje < 0 || tjx < 0 || kx < 0 || ky < 0 || kex < 0 || key < 0 || kf < 0 || kef < 0 || kmag < 0 ||
        kfl < 0 || kfm < 0 || kpm < 0 || kchi < 0)
        return 1;
    const int nt = (int)tt.nrow, nc = (int)ct.nrow;

    /* Catalog entries bucketed on a 1-px grid; candidates within MATCHR. */
    int *head = malloc(sizeof(int) * (NX + 2) * (NY + 2)), *next = malloc(sizeof(int) * (size_t)(nc + 1));
    int *tmatch = malloc(sizeof(int) * (size_t)nt), *cmatch = malloc(sizeof(int) * (size_t)(nc + 1));
    int *cnear = calloc((size_t)nc + 1, sizeof(int)), *cnear2 = calloc((size_t)nc + 1, sizeof(int));
    size_t ccap = 1024, ncand = 0;
    cand *cd = malloc(ccap * sizeof *cd);
    double *buf = malloc(sizeof(double) * (size_t)(nt + nc + 1));
    int *idx = malloc(sizeof(int) * (size_t)(nt + 1));
    errs *e = calloc((size_t)nt, sizeof *e);
    if (!head || !next || !tmatch || !cmatch || !cnear || !cnear2 || !cd || !buf || !idx || !e) {
        fprintf(stderr, "crowded: out of memory\n");
        return 1;
    }
    for (int i = 0; i < (NX + 2) * (NY + 2); i++)
        head[i] = -1;
    for (int j = 0; j < nc; j++) {
        cmatch[j] = -1;
        double x = mp_table_get(&ct, (size_t)j, kx), y = mp_table_get(&ct, (size_t)j, ky);
        if (!isfinite(x) || !isfinite(y)) {
            next[j] = -1;
            continue;
        }
        long gx = lround(x), gy = lround(y);
        gx = gx < 0 ? 0 : gx > NX + 1 ? NX + 1 : gx;
        gy = gy < 0 ? 0 : gy > NY + 1 ? NY + 1 : gy;
        next[j] = head[gy * (NX + 2) + gx];
        head[gy * (NX + 2) + gx] = j;
    }
    for (int i = 0; i < nt; i++) {
        tmatch[i] = -1;
        double x = mp_table_get(&tt, (size_t)i, tx), y = mp_table_get(&tt, (size_t)i, ty);
        long gx = lround(x), gy = lround(y);
        for (long yy = gy - 3; yy <= gy + 3; yy++)
            for (long xx = gx - 3; xx <= gx + 3; xx++) {
                if (xx < 0 || xx > NX + 1 || yy < 0 || yy > NY + 1)
                    continue;
                for (int j = head[yy * (NX + 2) + xx]; j >= 0; j = next[j]) {
                    double d = hypot(mp_table_get(&ct, (size_t)j, kx) - x,
                                     mp_table_get(&ct, (size_t)j, ky) - y);
                    if (d <= 2.0 * MATCHR)
                        cnear2[j] = 1;
                    if (d > MATCHR)
                        continue;
                    cnear[j] = 1;
                    if (ncand == ccap) {
                        ccap *= 2;
                        cand *c2 = realloc(cd, ccap * sizeof *cd);
                        if (!c2) {
                            fprintf(stderr, "crowded: out of memory\n");
                            return 1;
                        }
                        cd = c2;
                    }
                    cd[ncand++] = (cand){i, j, d};
                }
            }
    }
    qsort(cd, ncand, sizeof *cd, cmp_cand);
    for (size_t q = 0; q < ncand; q++)
        if (tmatch[cd[q].t] < 0 && cmatch[cd[q].c] < 0) {
            tmatch[cd[q].t] = cd[q].c;
            cmatch[cd[q].c] = cd[q].t;
        }

    /* Normalised errors of every matched star. */
    for (int i = 0; i < nt; i++) {
        int j = tmatch[i];
        if (j < 0)
            continue;
        double E = mp_table_get(&ct, (size_t)j, kf), Et = mp_table_get(&tt, (size_t)i, tf);
        double X = mp_table_get(&ct, (size_t)j, kx), Xt = mp_table_get(&tt, (size_t)i, tx);
        double Y = mp_table_get(&ct, (size_t)j, ky), Yt = mp_table_get(&tt, (size_t)i, ty);
        double sEm = mp_table_get(&ct, (size_t)j, kfm), sXm = mp_table_get(&ct, (size_t)j, kpm);
        double dmag = mp_table_get(&ct, (size_t)j, kmag) - mp_table_get(&tt, (size_t)i, tm);
        e[i].dmag = dmag;
        e[i].dmag_model = fabs(dmag) / (1.0857 * sEm / Et);
        e[i].dr_model = hypot(X - Xt, Y - Yt) / sXm;
        e[i].ne = (E - Et) / mp_table_get(&ct, (size_t)j, kef);
        e[i].nx = (X - Xt) / mp_table_get(&ct, (size_t)j, kex);
        e[i].ny = (Y - Yt) / mp_table_get(&ct, (size_t)j, key);
        e[i].ferr_ratio = mp_table_get(&ct, (size_t)j, kef) / sEm;
        e[i].dmag_joint = fabs(E - Et) / mp_table_get(&tt, (size_t)i, tje);
        e[i].dr_joint = hypot(X - Xt, Y - Yt) / mp_table_get(&tt, (size_t)i, tjx);
        e[i].ne_res = e[i].ne;
        e[i].snr_miss = NAN;
        for (int k = 0; k < nt; k++)
            if (k != i && tmatch[k] < 0 &&
                hypot(mp_table_get(&tt, (size_t)k, tx) - Xt,
                      mp_table_get(&tt, (size_t)k, ty) - Yt) < 2.0 * FWHM) {
                double s = mp_table_get(&tt, (size_t)k, tf) / mp_table_get(&tt, (size_t)k, tje);
                e[i].ne_res = NAN;
                e[i].snr_miss = isnan(e[i].snr_miss) || s > e[i].snr_miss ? s : e[i].snr_miss;
            }
    }

    /* Each unsaturated field star's normalised flux error (NaN: not found;
     * ne_res NaN: an unfound star within 2 FWHM) and its S/N at the joint
     * bound, for `crowdpool` (several realisations pooled per bin). */
    snprintf(path, sizeof path, "%s/%s_ne.dat", dir, root);
    FILE *ned = fopen(path, "w");
    if (!ned) {
        fprintf(stderr, "crowded: %s: cannot write\n", path);
        return 1;
    }
    fprintf(ned, "# mag_true ne ne_res snr_joint ne_joint snr_miss (unsaturated field stars; "
            "NaN: not found; ne_joint: (E - Et)/FLUXERR_JOINT of the resolved; snr_miss: the "
            "largest joint-bound S/N of the true stars not found within 2 FWHM of a found one)\n");
    for (int i = 0; i < nt; i++)
        if ((int)mp_table_get(&tt, (size_t)i, tk) == K_FIELD && !mp_table_get(&tt, (size_t)i, tq)) {
            double sj = mp_table_get(&tt, (size_t)i, tje), et = mp_table_get(&tt, (size_t)i, tf);
            double nj = tmatch[i] >= 0 && isfinite(e[i].ne_res)
                        ? (mp_table_get(&ct, (size_t)tmatch[i], kf) - et) / sj : NAN;
            fprintf(ned, "%.5f %.5f %.5f %.4f %.5f %.4f\n", mp_table_get(&tt, (size_t)i, tm),
                    tmatch[i] >= 0 ? e[i].ne : NAN, tmatch[i] >= 0 ? e[i].ne_res : NAN, et / sj,
                    nj, tmatch[i] >= 0 ? e[i].snr_miss : NAN);
        }
    fclose(ned);

    snprintf(path, sizeof path, "%s/%s.md", dir, root);
    FILE *md = fopen(path, "w");
    if (!md) {
        fprintf(stderr, "crowded: %s: cannot write\n", path);
        return 1;
    }
    int nmatched = 0, nfalse = 0, ndup = 0, nfalse2 = 0;
    for (int i = 0; i < nt; i++)
        nmatched += tmatch[i] >= 0;
    for (int j = 0; j < nc; j++) {
        nfalse += !cnear[j];
        nfalse2 += !cnear[j] && cnear2[j];
        ndup += cnear[j] && cmatch[j] < 0;
    }
    /* The false entries for pooling over realisations (crowded.sh): all,
     * those with a true star the catalog missed within 2 × MATCHR (that
     * star, or a blend of two, measured off its place), the true stars. */
    int nfalse_miss = 0;
    for (int j = 0; j < nc; j++) {
        if (cnear[j])
            continue;
        double X = mp_table_get(&ct, (size_t)j, kx), Y = mp_table_get(&ct, (size_t)j, ky);
        for (int i = 0; i < nt; i++)
            if (tmatch[i] < 0 && hypot(mp_table_get(&tt, (size_t)i, tx) - X,
                                       mp_table_get(&tt, (size_t)i, ty) - Y) <= 2 * MATCHR) {
                nfalse_miss++;
                break;
            }
    }
    snprintf(path, sizeof path, "%s/%s_false.dat", dir, root);
    FILE *fd = fopen(path, "w");
    if (!fd) {
        fprintf(stderr, "crowded: %s: cannot write\n", path);
        fclose(md);
        return 1;
    }
    fprintf(fd, "%d %d %d\n", nfalse, nfalse_miss, nt);
    fclose(fd);
    fprintf(md, "### %s\n\n", label);
    fprintf(md, "- Catalog `%s.cat`: %d entries; %d of %d true stars matched one-to-one within "
            "%.1f px (nearest pairs first); **%d false detections** (no true star within %.1f px; %d of them have one within %.1f px); "
            "%d further entries within %.1f px of a true star that another entry already took "
            "(split or duplicate).\n", root, nc, nmatched, nt, MATCHR, nfalse, MATCHR, nfalse2, 2 * MATCHR, ndup, MATCHR);

    /* Run report (seconds per stage), copied from ROOT.report. */
    snprintf(path, sizeof path, "%s/%s.report", dir, root);
    FILE *rp = fopen(path, "r");
    if (rp) {
        char line[1024];
        fprintf(md, "- Run report (`%s.report`, verbatim):\n\n```\n", root);
        while (fgets(line, sizeof line, rp))
            fputs(line, md);
        fprintf(md, "```\n\n");
        fclose(rp);
    } else {
        fprintf(md, "- (no run report %s)\n\n", path);
    }

    /* Completeness and false detections against magnitude. */
    int nt_b[NMBIN] = {0}, nf_b[NMBIN] = {0}, ntf_b[NMBIN] = {0}, nff_b[NMBIN] = {0};
    int nfalse_b[NMBIN] = {0}, ncat_b[NMBIN] = {0}, ndup_b[NMBIN] = {0}, nfalse2_b[NMBIN] = {0};
    for (int i = 0; i < nt; i++) {
        int b = mbin(mp_table_get(&tt, (size_t)i, tm));
        nt_b[b]++;
        nf_b[b] += tmatch[i] >= 0;
        if ((int)mp_table_get(&tt, (size_t)i, tk) == K_FIELD) {
            ntf_b[b]++;
            nff_b[b] += tmatch[i] >= 0;
        }
    }
    for (int j = 0; j < nc; j++) {
        double m = mp_table_get(&ct, (size_t)j, kmag);
        if (!isfinite(m))
            continue;
        int b = mbin(m);
        ncat_b[b]++;
        nfalse_b[b] += !cnear[j];
        nfalse2_b[b] += !cnear[j] && cnear2[j];
        ndup_b[b] += cnear[j] && cmatch[j] < 0;
    }
    snprintf(path, sizeof path, "%s/%s_cmag.dat", dir, root);
    FILE *dat = fopen(path, "w");
    if (!dat) {
        fprintf(stderr, "crowded: %s: cannot write\n", path);
        return 1;
    }
    fprintf(dat, "# mag  completeness_all  err  completeness_field  err  false_fraction\n");
    fprintf(md, "#### Completeness and false detections against magnitude\n\n"
            "True magnitude bins (1 mag, centred) for completeness; the catalog's MAG_PSF for "
            "its entries.  *Field* = stars not placed as a pair member or bright star.\n\n"
            "| mag | true stars | found | completeness | field stars | field completeness "
            "| catalog entries | false | of which a true star ≤ 2 px | split/dup |\n|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|\n");
    for (int b = 0; b < NMBIN; b++) {
        double c = -16.0 + b;
        double fa = nt_b[b] ? (double)nf_b[b] / nt_b[b] : NAN;
        double ff = ntf_b[b] ? (double)nff_b[b] / ntf_b[b] : NAN;
        fprintf(md, "| %.0f | %d | %d | %.4f | %d | %.4f | %d | %d | %d | %d |\n", c, nt_b[b],
                nf_b[b], fa, ntf_b[b], ff, ncat_b[b], nfalse_b[b], nfalse2_b[b], ndup_b[b]);
        fprintf(dat, "%.1f %.5f %.5f %.5f %.5f %.5f\n", c, fa,
                nt_b[b] ? sqrt(fa * (1 - fa) / nt_b[b]) : NAN, ff,
                ntf_b[b] ? sqrt(ff * (1 - ff) / ntf_b[b]) : NAN,
                ncat_b[b] ? (double)nfalse_b[b] / ncat_b[b] : NAN);
    }
    fclose(dat);
    /* False detections beyond the bins (MAG_PSF NaN) */
    int nfalse_nan = 0;
    for (int j = 0; j < nc; j++)
        if (!isfinite(mp_table_get(&ct, (size_t)j, kmag)) && !cnear[j])
            nfalse_nan++;
    if (nfalse_nan)
        fprintf(md, "\n%d false detections have no finite MAG_PSF.\n", nfalse_nan);
    fprintf(md, "\n(Bin −16 holds the 20 saturating stars, −15 no true star; −14 and −6 are "
            "half-width ends of the uniform [−14, −6] field distribution; the first and last "
            "bins also collect catalog entries beyond them.  A false entry with a true star "
            "within 2 px is most likely a faint star measured more than 1 px off.)\n\n");

    /* Issue 13: the stars measurable at S/N >= 5 (their bound alone on the
     * sky) and how many were found; pair members found against field stars
     * of the same magnitude (each member expected at its 1-mag bin's field
     * completeness). */
    int csn = mp_table_col(&tt, "SNR_BOUND");
    int n5 = 0, f5 = 0;
    for (int i = 0; csn >= 0 && i < nt; i++)
        if (mp_table_get(&tt, (size_t)i, csn) >= 5.0) {
            n5++;
            f5 += tmatch[i] >= 0;
        }
    double pexp[NSBIN] = {0}, pvar[NSBIN] = {0};
    int pfound[NSBIN] = {0}, pn[NSBIN] = {0};
    for (int i = 0; i < nt; i++) {
        int k = (int)mp_table_get(&tt, (size_t)i, tk);
        if (k != K_PRIMARY && k != K_COMPANION)
            continue;
        int b = sbin(mp_table_get(&tt, (size_t)i, td)), mb = mbin(mp_table_get(&tt, (size_t)i, tm));
        double q = ntf_b[mb] ? (double)nff_b[mb] / ntf_b[mb] : NAN;
        if (!isfinite(q))
            continue;
        pn[b]++;
        pfound[b] += tmatch[i] >= 0;
        pexp[b] += q;
        pvar[b] += q * (1 - q);
    }
    fprintf(md, "\n#### Deep detection and blends (issue 13)\n\n");
    if (csn >= 0)
        fprintf(md, "- Stars whose S/N at their Cramér–Rao bound (alone on their sky, E, X, Y, B "
                "fitted; truth column SNR_BOUND) reaches 5: **%d of %d (%.3f)**; of them found: "
                "**%d (%.3f)**.\n", n5, nt, (double)n5 / nt, f5, n5 ? (double)f5 / n5 : NAN);
    fprintf(md, "- Pair members found against field stars of the same magnitude (found / "
            "expected at their 1-mag bin's field completeness; σ from the binomial variance of "
            "that expectation):\n\n| separation [FWHM] | members | found | expected | ratio ± σ |\n"
            "|---|---:|---:|---:|---:|\n");
    double pratio[NSBIN];
    for (int b = 0; b < NSBIN; b++) {
        pratio[b] = pexp[b] > 0 ? pfound[b] / pexp[b] : NAN;
        fprintf(md, "| %.2f–%.2f | %d | %d | %.1f | %.3f ± %.3f |\n", SEPEDGE[b], SEPEDGE[b + 1],
                pn[b], pfound[b], pexp[b], pratio[b], pexp[b] > 0 ? sqrt(pvar[b]) / pexp[b] : NAN);
    }
    fprintf(md, "\n");

    /* Pairs against separation. */
    int np_b[NSBIN] = {0}, nboth[NSBIN] = {0}, none[NSBIN] = {0}, nzero[NSBIN] = {0};
    int nonep[NSBIN] = {0};
    double *ratio_sum = malloc(sizeof(double) * NSBIN * NPAIR * 2);
    double *ratio_pri = malloc(sizeof(double) * NSBIN * NPAIR * 2);
    int nr[NSBIN] = {0};
    int *pidx[NSBIN];
    int npi[NSBIN] = {0};
    for (int b = 0; b < NSBIN; b++)
        pidx[b] = malloc(sizeof(int) * (size_t)(2 * nt + 1));
    if (!ratio_sum || !ratio_pri) {
        fprintf(stderr, "crowded: out of memory\n");
        return 1;
    }
    for (int i = 0; i < nt; i++) {
        if ((int)mp_table_get(&tt, (size_t)i, tk) != K_PRIMARY)
            continue;
        int c = (int)mp_table_get(&tt, (size_t)i, tp) - 1;
        int b = sbin(mp_table_get(&tt, (size_t)i, td));
        np_b[b]++;
        int fp = tmatch[i] >= 0, fc = tmatch[c] >= 0;
        if (fp && fc) {
            nboth[b]++;
            pidx[b][npi[b]++] = i;
            pidx[b][npi[b]++] = c;
        } else if (fp || fc) {
            none[b]++;
            nonep[b] += fp;
            int j = fp ? tmatch[i] : tmatch[c];
            double F = mp_table_get(&ct, (size_t)j, kf);
            ratio_sum[b * 2 * NPAIR + nr[b]] = F / (mp_table_get(&tt, (size_t)i, tf) +
                                                    mp_table_get(&tt, (size_t)c, tf));
            ratio_pri[b * 2 * NPAIR + nr[b]] = F / mp_table_get(&tt, (size_t)i, tf);
            nr[b]++;
        } else {
            nzero[b]++;
        }
    }
    snprintf(path, sizeof path, "%s/%s_csep.dat", dir, root);
    dat = fopen(path, "w");
    if (!dat) {
        fprintf(stderr, "crowded: %s: cannot write\n", path);
        return 1;
    }
    fprintf(dat, "# sep_lo sep_hi sep_mid both_frac err merged_frac err none_frac ph_ratio as_ratio\n");
    fprintf(md, "#### Close pairs against separation\n\n"
            "200 placed pairs (primary −14…−8 mag, companion 0–2 mag fainter). *Both*: each "
            "member matched to its own entry; *merged*: only one member matched (which one "
            "in brackets: p = primary); the flux of that entry over the pair's summed true "
            "flux and over the primary's.\n\n"
            "| separation [FWHM] | pairs | both found | merged (p) | none | both-found fraction "
            "| merged: F/(F1+F2) median | merged: F/F1 median |\n"
            "|---|---:|---:|---:|---:|---:|---:|---:|\n");
    estat sp[NSBIN];
    for (int b = 0; b < NSBIN; b++) {
        double fb = np_b[b] ? (double)nboth[b] / np_b[b] : NAN;
        double fo = np_b[b] ? (double)none[b] / np_b[b] : NAN;
        double fz = np_b[b] ? (double)nzero[b] / np_b[b] : NAN;
        double rs = median(ratio_sum + b * 2 * NPAIR, nr[b]);
        double rp2 = median(ratio_pri + b * 2 * NPAIR, nr[b]);
        stats_of(e, pidx[b], npi[b], &sp[b], buf);
        fprintf(md, "| %.2f–%.2f | %d | %d | %d (%d) | %d | %.3f | %.3f | %.3f |\n", SEPEDGE[b],
                SEPEDGE[b + 1], np_b[b], nboth[b], none[b], nonep[b], nzero[b], fb, rs, rp2);
        fprintf(dat, "%.2f %.2f %.3f %.5f %.5f %.5f %.5f %.5f %.4f %.4f\n", SEPEDGE[b],
                SEPEDGE[b + 1], 0.5 * (SEPEDGE[b] + SEPEDGE[b + 1]), fb,
                np_b[b] ? sqrt(fb * (1 - fb) / np_b[b]) : NAN, fo,
                np_b[b] ? sqrt(fo * (1 - fo) / np_b[b]) : NAN, fz, sp[b].ph, sp[b].as);
    }
    fclose(dat);
    fprintf(md, "\nErrors of the members of pairs found as two (both members), over the "
            "performance model and normalised by the fit's own errors:\n\n"
            "| separation [FWHM] |%s\n|---|%s\n", EHEAD, EALIGN);
    for (int b = 0; b < NSBIN; b++) {
        fprintf(md, "| %.2f–%.2f |", SEPEDGE[b], SEPEDGE[b + 1]);
        estat_row(md, &sp[b]);
        fprintf(md, "\n");
    }

    /* Errors against magnitude: matched stars, field stars only and all. */
    snprintf(path, sizeof path, "%s/%s_err.dat", dir, root);
    dat = fopen(path, "w");
    if (!dat) {
        fprintf(stderr, "crowded: %s: cannot write\n", path);
        return 1;
    }
    fprintf(dat, "# mag N ph_model as_model ne_rs nx_rs ny_rs dmag_med (field stars, matched, "
            "not saturated)\n");
    fprintf(md, "\n#### Photometric and astrometric errors against magnitude\n\n"
            "Matched *field* stars that do not saturate (pair members and bright stars left "
            "out; neighbours at any distance kept — this is the crowded-field error), by true "
            "magnitude.  *phot/model* = median(|Δmag| / σ_mag) / 0.6745 with σ_mag = 1.0857 "
            "FLUXERR_MODEL / FLUX_TRUE; *astro/model* = median(Δr / POSERR_MODEL) / 1.1774 "
            "(1 = on the paper's performance model for an isolated star); *phot/joint*, "
            "*astro/joint* the same over each star's joint Cramér–Rao bound (truth.dat's "
            "FLUXERR_JOINT, POSERR_JOINT: the star fitted with every true star whose fitting "
            "region overlaps its own, centres within 2 fitrad, and one constant sky, on the "
            "union of their regions; tests/validate/crowded/joint_bound.c); normalised errors "
            "use the fit's FLUXERR_PSF, ERRX_PSF, ERRY_PSF (robust σ = IQR/1.349; 1 = honest "
            "error bars; its sampling error for N normal values is 1.17/√N: 0.05 at N = 550).  *No unfound star ≤ 2 FWHM*: "
            "the stars with no true star the catalog missed within 2 FWHM (a missed star that "
            "close is fitted as part of this one, an error no covariance of the model fitted "
            "can carry).\n\n| mag |%s\n|---:|%s\n", EHEAD, EALIGN);
    int *fi = malloc(sizeof(int) * (size_t)(nt + 1));
    int *ni = malloc(sizeof(int) * (size_t)(nt + 1));
    if (!fi || !ni) {
        fprintf(stderr, "crowded: out of memory\n");
        return 1;
    }
    int nfi_all = 0, nni_all = 0;
    for (int b = 0; b < NMBIN; b++) {
        int nfi = 0;
        for (int i = 0; i < nt; i++)
            if (tmatch[i] >= 0 && (int)mp_table_get(&tt, (size_t)i, tk) == K_FIELD &&
                !mp_table_get(&tt, (size_t)i, tq) && mbin(mp_table_get(&tt, (size_t)i, tm)) == b)
                fi[nfi++] = i;
        if (nfi == 0)
            continue;
        estat s;
        stats_of(e, fi, nfi, &s, buf);
        fprintf(md, "| %.0f |", -16.0 + b);
        estat_row(md, &s);
        fprintf(md, "\n");
        fprintf(dat, "%.1f %d %.4f %.4f %.4f %.4f %.4f %.5f\n", -16.0 + b, s.n, s.ph, s.as,
                s.ne_rs, s.nx_rs, s.ny_rs, s.dmag_med);
    }
    fclose(dat);
    for (int i = 0; i < nt; i++)
        if (tmatch[i] >= 0 && (int)mp_table_get(&tt, (size_t)i, tk) == K_FIELD &&
            !mp_table_get(&tt, (size_t)i, tq)) {
            fi[nfi_all++] = i;
            if ((int)mp_table_get(&ct, (size_t)tmatch[i], kfl) == 0)
                ni[nni_all++] = i;
        }
    estat sall, sclean;
    stats_of(e, fi, nfi_all, &sall, buf);
    stats_of(e, ni, nni_all, &sclean, buf);
    fprintf(md, "| all |");
    estat_row(md, &sall);
    fprintf(md, "\n| all, FLAGS 0 |");
    estat_row(md, &sclean);
    fprintf(md, "\n");

    /* Completeness of bright field stars against their nearest neighbour. */
    {
        static const double NNE[7] = {0.0, 0.5, 1.0, 1.5, 2.0, 3.0, 1e9};
        int nn_t[6] = {0}, nn_f[6] = {0};
        int tnn = need(&tt, "NN_DIST", path);
        if (tnn >= 0) {
            for (int i = 0; i < nt; i++) {
                if ((int)mp_table_get(&tt, (size_t)i, tk) != K_FIELD ||
                    mp_table_get(&tt, (size_t)i, tm) > -8.5)
                    continue;
                double d = mp_table_get(&tt, (size_t)i, tnn) / FWHM;
                for (int b = 0; b < 6; b++)
                    if (d >= NNE[b] && d < NNE[b + 1]) {
                        nn_t[b]++;
                        nn_f[b] += tmatch[i] >= 0;
                    }
            }
            fprintf(md, "\n#### Field stars against their nearest neighbour\n\nField stars brighter "
                    "than −8.5 mag (well above the detection limit), by the distance to the nearest "
                    "other true star of any magnitude (accidental pairs of the random field):\n\n"
                    "| nearest neighbour [FWHM] | stars | found | completeness |\n|---|---:|---:|---:|\n");
            for (int b = 0; b < 6; b++) {
                char lab[32];
                if (b == 5)
                    snprintf(lab, sizeof lab, "≥ %.1f", NNE[b]);
                else
                    snprintf(lab, sizeof lab, "%.1f–%.1f", NNE[b], NNE[b + 1]);
                fprintf(md, "| %s | %d | %d | %.4f |\n", lab, nn_t[b], nn_f[b],
                        nn_t[b] ? (double)nn_f[b] / nn_t[b] : NAN);
            }
        }
    }

    /* Per-star match list, for diagnostics. */
    snprintf(path, sizeof path, "%s/%s_match.dat", dir, root);
    dat = fopen(path, "w");
    if (dat) {
        fprintf(dat, "# truth_row kind mag_true x_true y_true cat_row mag_psf flags dist "
                "(cat_row -1: not found; rows 1-based)\n");
        for (int i = 0; i < nt; i++) {
            int j = tmatch[i];
            fprintf(dat, "%d %d %.4f %.3f %.3f %d %.4f %d %.4f\n", i + 1,
                    (int)mp_table_get(&tt, (size_t)i, tk), mp_table_get(&tt, (size_t)i, tm),
                    mp_table_get(&tt, (size_t)i, tx), mp_table_get(&tt, (size_t)i, ty),
                    j >= 0 ? j + 1 : -1, j >= 0 ? mp_table_get(&ct, (size_t)j, kmag) : NAN,
                    j >= 0 ? (int)mp_table_get(&ct, (size_t)j, kfl) : -1,
                    j >= 0 ? hypot(mp_table_get(&ct, (size_t)j, kx) - mp_table_get(&tt, (size_t)i, tx),
                                   mp_table_get(&ct, (size_t)j, ky) - mp_table_get(&tt, (size_t)i, ty))
                           : NAN);
        }
        fclose(dat);
    }

    /* Saturated stars. */
    fprintf(md, "\n#### Saturated stars\n\nStars whose own noiseless peak pixel plus sky "
            "reaches SATURATE = %.0f ADU (gain 1): the pipeline masks the pixels at "
            "SATURATE and fits the wings.\n\n| star | mag | clipped px (≤ 3 px) | found | FLAGS "
            "| flag 1 | FLUX_PSF/FLUX_TRUE | (E−Et)/σE | Δr [px] | true stars ≤ 5 px: n (found), brightest mag |\n"
            "|---:|---:|---:|---|---:|---|---:|---:|---:|---|\n", SATURATE);
    int nsat = 0, nsat_found = 0, nsat_f1 = 0;
    int nsatnb = 0, nsatnb_f1 = 0;   /* not saturated themselves, clipped pixels within 3 px */
    int cn = need(&tt, "NUMBER", path);
    for (int i = 0; i < nt; i++) {
        int j = tmatch[i];
        if (!mp_table_get(&tt, (size_t)i, tq)) {
            if (mp_table_get(&tt, (size_t)i, tc) > 0 && j >= 0) {
                nsatnb++;
                nsatnb_f1 += ((int)mp_table_get(&ct, (size_t)j, kfl) & 1) != 0;
            }
            continue;
        }
        nsat++;
        /* true neighbours within 5 px */
        int nnb = 0, nnbf = 0;
        double nbmag = NAN;
        for (int q = 0; q < nt; q++)
            if (q != i && hypot(mp_table_get(&tt, (size_t)q, tx) - mp_table_get(&tt, (size_t)i, tx),
                                mp_table_get(&tt, (size_t)q, ty) - mp_table_get(&tt, (size_t)i, ty)) <= 5.0) {
                nnb++;
                nnbf += tmatch[q] >= 0;
                double mq = mp_table_get(&tt, (size_t)q, tm);
                if (!(mq >= nbmag))
                    nbmag = mq;
            }
        char nbtxt[64];
        if (nnb)
            snprintf(nbtxt, sizeof nbtxt, "%d (%d), %.2f", nnb, nnbf, nbmag);
        else
            snprintf(nbtxt, sizeof nbtxt, "0");
        if (j < 0) {
            fprintf(md, "| %.0f | %.3f | %.0f | no | | | | | | %s |\n",
                    cn >= 0 ? mp_table_get(&tt, (size_t)i, cn) : (double)(i + 1),
                    mp_table_get(&tt, (size_t)i, tm), mp_table_get(&tt, (size_t)i, tc), nbtxt);
            continue;
        }
        nsat_found++;
        int fl = (int)mp_table_get(&ct, (size_t)j, kfl);
        nsat_f1 += (fl & 1) != 0;
        double E = mp_table_get(&ct, (size_t)j, kf), Et = mp_table_get(&tt, (size_t)i, tf);
        fprintf(md, "| %.0f | %.3f | %.0f | yes | %d | %s | %.4f | %+.2f | %.3f | %s |\n",
                cn >= 0 ? mp_table_get(&tt, (size_t)i, cn) : (double)(i + 1),
                mp_table_get(&tt, (size_t)i, tm), mp_table_get(&tt, (size_t)i, tc), fl,
                (fl & 1) ? "yes" : "**no**", E / Et, e[i].ne,
                hypot(mp_table_get(&ct, (size_t)j, kx) - mp_table_get(&tt, (size_t)i, tx),
                      mp_table_get(&ct, (size_t)j, ky) - mp_table_get(&tt, (size_t)i, ty)), nbtxt);
    }
    fprintf(md, "\n%d saturated stars, %d found, %d of those with flag 1.  Unsaturated stars "
            "with a clipped pixel within 3 px, found: %d, with flag 1: %d.\n\n", nsat,
            nsat_found, nsat_f1, nsatnb, nsatnb_f1);

    /* chi2 of the fits */
    int nchi = 0;
    for (int j = 0; j < nc; j++)
        buf[nchi++] = mp_table_get(&ct, (size_t)j, kchi);
    double chimed = median(buf, nchi);
    fprintf(md, "Median CHI2_PSF over the catalog: %.4f.\n\n", chimed);
    fclose(md);

    /* One row of the summary table (ROOT_row.md), with the seconds of the
     * run report's "seconds:" line. */
    double sec[7];
    for (int q = 0; q < 7; q++)
        sec[q] = NAN;
    snprintf(path, sizeof path, "%s/%s.report", dir, root);
    rp = fopen(path, "r");
    if (rp) {
        char line[1024];
        while (fgets(line, sizeof line, rp)) {
            const char *p = strstr(line, "seconds:");
            if (p && sscanf(p, "seconds: read %lf, background %lf, find %lf, group %lf, fit %lf, "
                            "write %lf, total %lf", &sec[0], &sec[1], &sec[2], &sec[3], &sec[4],
                            &sec[5], &sec[6]) == 7)
                break;
        }
        fclose(rp);
    }
    snprintf(path, sizeof path, "%s/%s_row.md", dir, root);
    FILE *row = fopen(path, "w");
    if (row) {
        fprintf(row, "| %s | %d | %d | %d | %.3f |", label, nc, nmatched, nfalse,
                (double)nmatched / nt);
        for (int b = 0; b < NSBIN; b++)
            fprintf(row, " %d/%d", nboth[b], np_b[b]);
        fprintf(row, " |");
        for (int b = 0; b < NSBIN; b++)
            fprintf(row, " %.2f", pratio[b]);
        fprintf(row, " | %d/%d | %.3f | %.3f | %.3f | %.3f | %d/%d, %d | %.1f | %.1f |\n", f5, n5,
                sall.ph, sall.as, sall.ne_rs, sall.nx_rs, nsat_found, nsat, nsat_f1, sec[4], sec[6]);
        fclose(row);
    }

    /* The issue-13 table's row (ROOT_i13.md), and its last row: the stars
     * measurable at S/N >= 5 (ROOT_i13b.md). */
    snprintf(path, sizeof path, "%s/%s_i13.md", dir, root);
    if ((row = fopen(path, "w"))) {
        fprintf(row, "| matphot, %s | %.3f | %d | %.3f | %.3f | %.3f | %.3f | %.3f | %.3f |\n",
                label, (double)nmatched / nt, nfalse, sall.phj, sall.asj, sall.ph, sall.as,
                sall.ne_rs, sall.ne_rs_res);
        fclose(row);
    }
    snprintf(path, sizeof path, "%s/%s_i13b.md", dir, root);
    if ((row = fopen(path, "w"))) {
        fprintf(row, "| stars with S/N ≥ 5 at their bound | %.3f | — | 1.00 | 1.00 | — | — "
                "| 1.00 | 1.00 |\n",
                (double)n5 / nt);
        fclose(row);
    }

    /* One-line summary. */
    printf("crowded %-9s: %d entries, %d/%d matched, %d false (%d within %.0f px of a true "
           "star not found); pairs both found by sep bin:", label, nc, nmatched, nt, nfalse,
           nfalse_miss, 2 * MATCHR);
    for (int b = 0; b < NSBIN; b++)
        printf(" %d/%d", nboth[b], np_b[b]);
    printf("; members/field by sep bin:");
    for (int b = 0; b < NSBIN; b++)
        printf(" %.2f", pratio[b]);
    printf("; S/N>=5 found %d/%d", f5, n5);
    printf("; field phot/joint %.3f astro/joint %.3f phot/model %.3f astro/model %.3f, rsig E %.3f "
           "(resolved %.3f) X %.3f; saturated %d/%d found, %d flag 1\n", sall.phj, sall.asj,
           sall.ph, sall.as, sall.ne_rs, sall.ne_rs_res, sall.nx_rs, nsat_found, nsat, nsat_f1);

    for (int b = 0; b < NSBIN; b++)
        free(pidx[b]);
    free(ratio_sum);
    free(ratio_pri);
    free(fi);
    free(ni);
    free(head);
    free(next);
    free(tmatch);
    free(cmatch);
    free(cnear);
    free(cnear2);
    free(cd);
    free(buf);
    free(idx);
    free(e);
    mp_table_free(&tt);
    mp_table_free(&ct);
    return 0;
}

/* The artificial-star completeness (matphot fakes: FAKES, a .fakes.cat)
 * beside the field stars' completeness against the truth (ROOT_cmag.dat),
 * in the same 1-mag bins: fakes and field stars are both uniform over the
 * frame and in [-14, -6] mag, so the two estimate the same curve.  Writes
 * ROOT_fakes.dat and ROOT_fakes.md (the table, each bin's difference over
 * its combined binomial σ, and χ² over the bins with its p-value). */
static int do_fakes(const char *dir, const char *root, const char *fakes)
{
    char err[MP_ERRLEN], path[4096];
    mp_table ft;
    if (mp_table_read(fakes, &ft, err)) {
        fprintf(stderr, "crowded: %s\n", err);
        return 1;
    }
    int fm = need(&ft, "MAG_TRUE", fakes), ff = need(&ft, "FOUND", fakes);
    if (fm < 0 || ff < 0)
        return 1;
    int n_b[NMBIN] = {0}, f_b[NMBIN] = {0};
    for (size_t r = 0; r < ft.nrow; r++) {
        int b = mbin(mp_table_get(&ft, r, fm));
        n_b[b]++;
        f_b[b] += mp_table_get(&ft, r, ff) == 1;
    }
    double tc[NMBIN], te[NMBIN];
    for (int b = 0; b < NMBIN; b++)
        tc[b] = te[b] = NAN;
    snprintf(path, sizeof path, "%s/%s_cmag.dat", dir, root);
    FILE *in = fopen(path, "r");
    if (!in) {
        fprintf(stderr, "crowded: %s: cannot read\n", path);
        return 1;
    }
    char line[512];
    while (fgets(line, sizeof line, in)) {
        double m, a, ea, c, ec;
        if (line[0] != '#' && sscanf(line, "%lf %lf %lf %lf %lf", &m, &a, &ea, &c, &ec) == 5) {
            int b = mbin(m);
            tc[b] = c;
            te[b] = ec;
        }
    }
    fclose(in);
    snprintf(path, sizeof path, "%s/%s_fakes.dat", dir, root);
    FILE *dat = fopen(path, "w");
    snprintf(path, sizeof path, "%s/%s_fakes.md", dir, root);
    FILE *md = fopen(path, "w");
    if (!dat || !md) {
        fprintf(stderr, "crowded: %s: cannot write\n", path);
        return 1;
    }
    fprintf(dat, "# mag completeness_fakes sigma n\n");
    fprintf(md, "| mag | field stars: completeness ± σ (truth) | fakes | found | completeness ± σ "
            "(fakes) | difference / σ |\n|---:|---:|---:|---:|---:|---:|\n");
    double chi2 = 0;
    int nb = 0, nall = 0, fall = 0;
    for (int b = 0; b < NMBIN; b++) {
        nall += n_b[b];
        fall += f_b[b];
        if (n_b[b] == 0)
            continue;
        double c = (double)f_b[b] / n_b[b], e = sqrt(c * (1 - c) / n_b[b]);
        fprintf(dat, "%.1f %.5f %.5f %d\n", -16.0 + b, c, e, n_b[b]);
        /* σ² of the difference: each side's binomial variance at the pooled
         * estimate (so a bin at 1.000 on both sides still has one) */
        double nt = isfinite(te[b]) && tc[b] > 0 && tc[b] < 1 ? tc[b] * (1 - tc[b]) / (te[b] * te[b]) : NAN;
        double pool = isfinite(nt) ? (c * n_b[b] + tc[b] * nt) / (n_b[b] + nt) : c;
        double v = pool * (1 - pool) * (1.0 / n_b[b] + (isfinite(nt) ? 1.0 / nt : 0));
        double z = isfinite(tc[b]) && v > 0 ? (c - tc[b]) / sqrt(v) : NAN;
        if (isfinite(z)) {
            chi2 += z * z;
            nb++;
        }
        fprintf(md, "| %.0f | %.4f ± %.4f | %d | %d | %.4f ± %.4f | %+.2f |\n", -16.0 + b, tc[b],
                te[b], n_b[b], f_b[b], c, e, z);
    }
    fprintf(md, "\n%d fakes, %d found (%.4f).  Agreement over the %d bins with a defined "
            "difference: χ² = %.2f for %d degrees of freedom, p = %.3f (the two curves differ "
            "beyond their sampling error when p < 0.01).\n", nall, fall,
            nall ? (double)fall / nall : NAN, nb, chi2, nb, nb ? mp_chi2_sf(nb, chi2) : NAN);
    printf("crowded fakes: %d fakes, %d found; chi2 %.2f / %d bins, p %.3f\n", nall, fall, chi2,
           nb, nb ? mp_chi2_sf(nb, chi2) : NAN);
    fclose(dat);
    fclose(md);
    mp_table_free(&ft);
    return 0;
}

int main(int argc, char **argv)
{
    if (argc == 5 && strcmp(argv[1], "fakes") == 0)
        return do_fakes(argv[2], argv[3], argv[4]) ? 1 : 0;
    if (argc == 3 && strcmp(argv[1], "sim") == 0)
        return do_sim(argv[2]) ? 1 : 0;
    if (argc == 5 && strcmp(argv[1], "match") == 0)
        return do_match(argv[2], argv[3], argv[4]) ? 1 : 0;
    fprintf(stderr, "usage: crowded sim DIR | crowded match DIR ROOT LABEL | crowded fakes DIR ROOT FAKES\n");
    return 2;
}
