/*
 * validate.c — `make validate`: the paper's §5 experiments (design.md §6).
 *
 *   validate [-n N] [-c 1,2,6a,...] [-o DIR] [-p TINYTIM_X4.fits] [-q]
 *   validate -selftest
 *
 * For each case: N simulated single-star 60x60 frames (OpenMP over stars),
 * one fit each, the per-star predictions at the truth, per-bin statistics,
 * DIR/<case>.dat (per star) and DIR/<case>.png; at the end DIR/REPORT.md.
 * The summary table goes to stdout.  Exit 0 when everything ran (whatever
 * the verdicts), 1 on an error, 2 on usage.
 */
#include <errno.h>
#include <math.h>
#include <stdlib.h>
#include <string.h>
#include <sys/stat.h>
#include <time.h>
#include <omp.h>
#include "tests/validate/vt.h"

#define DEFAULT_N 20000
#define DEFAULT_REAL "../shared/data/real/hst_acs_hrc_47tuc/tinytim_acs_hrc_f606w_x512y512_sub4.fits"

static const vt_case CASES[] = {
    {"1_analytic", "1 oversampled, analytic",
     "Gaussian FWHM 3 px truth; fitted with the analytic pixel-integrated Gaussian FWHM 3",
     "Figs. 1–2 — median errors on the model in every bin, normalised errors N(0,1)",
     21.44, 1, 0, 3.0, 1.0, 0, 100.0, -15, -6, 0, VT_FIT_ANALYTIC, 1, VT_EXPECT_CRLB, 0.0},
    {"2_discrete", "2 oversampled, discrete",
     "the same frames as case 1; fitted with a 1× discrete Gaussian table FWHM 3 (radius 15 px)",
     "Figs. 3–5 — as case 1; positions differ from the analytic fit by < 1/15 of the photon noise",
     21.44, 1, 0, 3.0, 1.0, 0, 100.0, -15, -6, 0, VT_FIT_GTABLE, 1, VT_EXPECT_CRLB, 0.0},
    {"3_inefficient", "3 inefficient detector",
     "Gaussian FWHM 3 truth on a V = 1/9 detector (B = 11.1111 e−, −15 … −8 mag); fitted with "
     "the 1× FWHM 3 table and a uniform V = 1/9 DRF",
     "Fig. 6 — on the model; errors ≈ 3× (V^−1/2) the V = 1 case, β ≈ 1736.79",
     1736.79, 3, 0, 3.0, 1.0 / 9.0, 0, 100.0 / 9.0, -15, -8, 0, VT_FIT_GTABLE, 1, VT_EXPECT_CRLB, 0.0},
    {"4_under_1x", "4 undersampled, 1× table",
     "Gaussian FWHM 1.5 truth; fitted with a 1× discrete table FWHM 1.5",
     "Figs. 7–8 — fine below 30 000 e−, bright stars fail (up to ~40× the model); side lobe −0.0006",
     6.12, 4, 0, 1.5, 1.0, 0, 100.0, -15, -6, 0, VT_FIT_GTABLE, 1, VT_EXPECT_FAIL_BRIGHT, 30000.0},
    {"5_under_2x", "5 undersampled, 2× table",
     "the same frames as case 4; fitted with a 2× supersampled table FWHM 1.5",
     "Figs. 9–10 — on the model at all brightnesses (σ_X from the fit slightly low)",
     6.17, 4, 0, 1.5, 1.0, 0, 100.0, -15, -6, 0, VT_FIT_GTABLE, 2, VT_EXPECT_CRLB, 0.0},
    {"6a_critical_1x", "6a critically sampled, 1× table",
     "Gaussian FWHM 2.35482 truth; fitted with a 1× table FWHM 2.35482",
     "Figs. 11–12 — on the model except the brightest bins (E ≳ 316 000 e−)",
     13.62, 6, 0, 2.35482, 1.0, 0, 100.0, -15, -6, 0, VT_FIT_GTABLE, 1, VT_EXPECT_FAIL_BRIGHT, 316000.0},
    {"6b_critical_2x", "6b critically sampled, 2× table",
     "the same frames as case 6a; fitted with a 2× table FWHM 2.35482",
     "Figs. 13–14 — on the model at all brightnesses",
     13.62, 6, 0, 2.35482, 1.0, 0, 100.0, -15, -6, 0, VT_FIT_GTABLE, 2, VT_EXPECT_CRLB, 0.0},
    {"7_ugly_psf", "7 ugly PSF (Tiny Tim ACS/HRC)",
     "Tiny Tim ACS/HRC F606W ×4 table truth, band-limited to 1 cycle/px (block-summed on its "
     "grid); fitted with that table block-summed to ×2",
     "Figs. 16–18 (NGST PSF, β ≈ 31.25) — on the model; χ² distributed as χ²(3596)",
     31.25, 7, 1, 0.0, 1.0, 0, 100.0, -15, -6, 0, VT_FIT_REAL2, 2, VT_EXPECT_CRLB, 0.0},
    {"8a_ugly_det_m13", "8a ugly detector, −13 mag",
     "the ×4 Tiny Tim table on a 4×4-subpixel detector with a dead first row and column "
     "(V = 0.5625, B = 56.25 e−), all stars at −13 mag; fitted at ×4 with the same DRF",
     "Figs. 19–20 — measured −12.9998 ± 0.0039 mag, error estimate 0.00384; β 28.10",
     28.10, 8, 1, 0.0, 1.0, 1, 56.25, -13, -13, 1, VT_FIT_REAL4, 4, VT_EXPECT_CRLB, 0.0},
    {"8b_ugly_detector", "8b ugly detector, −15 … −6",
     "as 8a over the full magnitude range",
     "Fig. 21 — on the model; β 28.04",
     28.04, 9, 1, 0.0, 1.0, 1, 56.25, -15, -6, 0, VT_FIT_REAL4, 4, VT_EXPECT_CRLB, 0.0},
};
#define NCASES ((int)(sizeof CASES / sizeof CASES[0]))

static void usage(FILE *fp)
{
    fprintf(fp, "usage: validate [-n N] [-c CASES] [-o DIR] [-p PSF_X4.fits] [-seed S] [-q]\n"
                "       validate -selftest\n"
                "  -n N      stars per case (default %d; case 8a uses N/2)\n"
                "  -c LIST   comma-separated case ids or prefixes (1,2,3,4,5,6a,6b,7,8a,8b)\n"
                "  -o DIR    output folder (default validate)\n"
                "  -p FILE   Tiny Tim x4 PSF (default %s)\n"
                "  -seed S   seed set (default 0): star k of a case uses seed\n"
                "            (simset + 16 S) * 10^7 + k\n"
                "  -q        no progress on stderr\n", DEFAULT_N, DEFAULT_REAL);
}

static int selected(const char *list, const char *id)
{
    if (!list)
        return 1;
    const char *p = list;
    while (*p) {
        const char *e = strchr(p, ',');
        size_t l = e ? (size_t)(e - p) : strlen(p);
        /* "6" selects 6a and 6b; "6a" only 6a; "1" never selects "10". */
        if (l && !strncmp(p, id, l) && (id[l] == '_' || (l == 1 && id[l] >= 'a' && id[l] <= 'z') ||
                                       id[l] == '\0'))
            return 1;
        if (!e)
            break;
        p = e + 1;
    }
    return 0;
}

static double wall_now(void)
{
    struct timespec ts;
    clock_gettime(CLOCK_MONOTONIC, &ts);
    return (double)ts.tv_sec + 1e-9 * (double)ts.tv_nsec;
}

int main(int argc, char **argv)
{
    int n = DEFAULT_N, verbose = 1, seedset = 0;
    const char *list = NULL, *dir = "validate", *real = DEFAULT_REAL;
    mp_blas_single_thread();
    for (int i = 1; i < argc; i++) {
        const char *a = argv[i];
        if (!strcmp(a, "-selftest") || !strcmp(a, "--selftest")) {
            vt_selftest(stdout);
            return 0;
        } else if (!strcmp(a, "-q")) {
            verbose = 0;
        } else if (!strcmp(a, "-h") || !strcmp(a, "--help")) {
            usage(stdout);
            return 0;
        } else if (i + 1 < argc && !strcmp(a, "-n")) {
            char *end;
            errno = 0;
            long v = strtol(argv[++i], &end, 10);
            if (errno || *end || v < 10 || v >= (long)VT_SEED_STRIDE) {
                fprintf(stderr, "validate: -n %s: need an integer 10 .. %llu\n", argv[i],
                        (unsigned long long)VT_SEED_STRIDE - 1);
                return 2;
            }
            n = (int)v;
        } else if (i + 1 < argc && !strcmp(a, "-seed")) {
            char *end;
            errno = 0;
            long v = strtol(argv[++i], &end, 10);
            if (errno || *end || v < 0 || v > 1000000) {
                fprintf(stderr, "validate: -seed %s: need an integer 0 .. 1000000\n", argv[i]);
                return 2;
            }
            seedset = (int)v;
        } else if (i + 1 < argc && !strcmp(a, "-c")) {
            list = argv[++i];
        } else if (i + 1 < argc && !strcmp(a, "-o")) {
            dir = argv[++i];
        } else if (i + 1 < argc && !strcmp(a, "-p")) {
            real = argv[++i];
        } else {
            fprintf(stderr, "validate: %s: unknown option or missing value\n", a);
            usage(stderr);
            return 2;
        }
    }
    char cmdline[1024] = "validate";
    for (int i = 1; i < argc; i++) {
        size_t l = strlen(cmdline);
        snprintf(cmdline + l, sizeof cmdline - l, " %s", argv[i]);
    }
    if (mkdir(dir, 0777) && errno != EEXIST) {
        fprintf(stderr, "validate: %s: cannot create the output folder\n", dir);
        return 1;
    }
    int have_gnuplot = system("gnuplot -e 'set terminal pngcairo' >/dev/null 2>&1") == 0;
    const char *term = "pngcairo";
    if (!have_gnuplot && system("gnuplot -e 'set terminal png' >/dev/null 2>&1") == 0) {
        have_gnuplot = 1;
        term = "png";
    }
    char err[MP_ERRLEN] = "";
    vt_inputs in;
    if (vt_inputs_load(&in, real, err)) {
        fprintf(stderr, "validate: %s\n", err);
        return 1;
    }
    if (verbose) {
        fprintf(stderr, "validate: N = %d per case, %d threads, output in %s/\n", n,
                omp_get_max_threads(), dir);
        if (!in.have_real)
            fprintf(stderr, "validate: %s\n", in.real_note);
    }
    vt_result res[NCASES];
    memset(res, 0, sizeof res);
    double t0 = wall_now();
    int rc = 0;
    for (int i = 0; i < NCASES; i++) {
        res[i].c = &CASES[i];
        if (!selected(list, CASES[i].id))
            continue;
        if (vt_run_case(&CASES[i], &in, n, seedset, verbose, &res[i], err)) {
            fprintf(stderr, "validate: %s\n", err);
            rc = 1;
            break;
        }
        if (!res[i].ran)
            continue;
        if (vt_stats(&res[i])) {
            fprintf(stderr, "validate: %s: out of memory in the statistics\n", CASES[i].id);
            rc = 1;
            break;
        }
        if (vt_write_data(dir, &res[i], err)) {
            fprintf(stderr, "validate: %s\n", err);
            rc = 1;
            break;
        }
        if (have_gnuplot && vt_plot(dir, &res[i], term, err)) {
            fprintf(stderr, "validate: %s: %s (figure skipped)\n", CASES[i].id, err);
            err[0] = '\0';
        }
    }
    double wall = wall_now() - t0;
    if (!rc && vt_write_report(dir, res, NCASES, &in, n, seedset, cmdline, wall, have_gnuplot, err)) {
        fprintf(stderr, "validate: %s\n", err);
        rc = 1;
    }
    if (!rc) {
        vt_print_summary(stdout, res, NCASES);
        printf("\nvalidate: %d stars per case, %.1f s wall in all; report %s/REPORT.md\n", n,
               wall, dir);
    }
    for (int i = 0; i < NCASES; i++)
        free(res[i].s);
    vt_inputs_free(&in);
    return rc;
}
