/* test_fit_economy.c — the economy decisions of the frame fit (issue 5):
 * a group whose surroundings did not change is not refitted (in a later
 * pass, or in a later call with the pipeline's memory) and its result is
 * the one a full refit gives, within the stated bound; a group whose
 * neighbour changed is refitted; economy=no (refittol 0) refits every
 * group every pass; and the PRF envelope that crops painted light bounds
 * the rendered PRF.  Frames are simulated with sim/ (exact Gaussian pixel
 * integrals), fixed seeds. */
#include <setjmp.h>
#include <stdarg.h>
#include <stddef.h>
#include <cmocka.h>
#include <stdio.h>

#include "tests/unit/stiff_common.h"

#define FWHM 3.0
#define NS 6

/* Two groups 50 px apart (far beyond the Gaussian's 7.5σ + 1 px box), and
 * a sixth star near the second that the first call does not know of. */
static const double SX[NS] = {30.0, 33.5, 28.0, 31.0, 34.2, 27.0};
static const double SY[NS] = {30.0, 31.0, 34.0, 80.0, 78.5, 83.0};
static const double SE[NS] = {3e4, 1e4, 5e3, 2e4, 8e3, 6e3};
static const double SG[NS] = {1, 1, 1, 2, 2, 2};

/* A frame with the first n stars: sky 100, read noise 3. */
static void frame6(mp_frame *f, int n)
{
    sf_frame_make(f, 60, 110, 3.0);
    mp_rng r;
    mp_rng_seed(&r, 501);
    sf_render(f, 100.0, FWHM, SX, SY, SE, n, &r, 3.0);
}

/* The start table of the first n stars, with their GROUP_ID and a start
 * flux 20 % off (as find's would be). */
static void table_n(mp_table *t, int n)
{
    double E[NS];
    for (int k = 0; k < n; k++)
        E[k] = 1.2 * SE[k];
    sf_table(t, SX, SY, E, n, 0);
    int cg = mp_table_add_col(t, "GROUP_ID");
    assert_true(cg >= 0);
    for (int k = 0; k < n; k++)
        mp_table_set(t, (size_t)k, cg, SG[k]);
}

/* Add star k as a new row (the pipeline's next round): NUMBER k+1, find's
 * position and flux in the fitted columns, as add_new_stars does. */
static void add_row(mp_table *t, int k)
{
    long r = mp_table_add_row(t);
    assert_true(r >= 0);
    const char *c[5] = {"NUMBER", "X_IMAGE", "Y_IMAGE", "GROUP_ID", "FLUX"};
    double v[5] = {k + 1, SX[k], SY[k], SG[k], 1.2 * SE[k]};
    for (int i = 0; i < 5; i++)
        mp_table_set(t, (size_t)r, mp_table_col(t, c[i]), v[i]);
    const char *d[4] = {"XPSF_IMAGE", "YPSF_IMAGE", "FLUX_PSF", "SKY_PSF"};
    double w[4] = {SX[k], SY[k], 1.2 * SE[k], NAN};
    for (int i = 0; i < 4; i++)
        mp_table_set(t, (size_t)r, mp_table_col(t, d[i]), w[i]);
}

static double get(const mp_table *t, size_t r, const char *c)
{
    return mp_table_get(t, r, mp_table_col(t, c));
}

/* Within one call: groups that cannot see each other are fitted once; the
 * second pass finds no change and keeps both (2 fits, 2 kept), and the
 * result is what the full two passes give within the economy's bound,
 * 0.1 σ (the 2nd pass of an isolated group restarts from its own
 * converged fit and moves by ~0.01 σ: weights follow the model). */
static void test_second_pass_kept_when_isolated(void **state)
{
    (void)state;
    char err[MP_ERRLEN];
    mp_psf p;
    mp_psf_gauss(FWHM, &p);
    mp_prf_model m = {&p, NULL, 10};
    mp_frame f;
    frame6(&f, 5);     /* every star of the frame in the table */
    mp_frame_opts eco, full;
    mp_frame_opts_default(&eco);
    full = eco;
    full.refittol = 0.0;
    full.cropfrac = 0.0;
    mp_table a, b;
    table_n(&a, 5);
    table_n(&b, 5);
    mp_frame_report ra, rb;
    assert_int_equal(mp_fit_table(&f, &m, &eco, &a, &ra, err), 0);
    assert_int_equal(mp_fit_table(&f, &m, &full, &b, &rb, err), 0);
    print_message("economy: %ld fits, %ld kept; full: %ld fits, %ld kept\n", ra.fits, ra.kept,
                  rb.fits, rb.kept);
    assert_int_equal(ra.fits, 2);
    assert_int_equal(ra.kept, 2);
    assert_int_equal(rb.fits, 4);     /* economy=no: every group, every pass */
    assert_int_equal(rb.kept, 0);
    assert_int_equal(a.nrow, b.nrow);
    for (size_t i = 0; i < a.nrow; i++) {
        double s = get(&b, i, "FLUXERR_PSF");
        print_message("star %zu: economy %.3f full %.3f (%.4f sigma)\n", i, get(&a, i, "FLUX_PSF"),
                      get(&b, i, "FLUX_PSF"), (get(&a, i, "FLUX_PSF") - get(&b, i, "FLUX_PSF")) / s);
        assert_true(fabs(get(&a, i, "FLUX_PSF") - get(&b, i, "FLUX_PSF")) < 0.1 * s);
    }
    mp_table_free(&a);
    mp_table_free(&b);
    sf_frame_drop(&f);
}

/* A frame fit leaves each group fit's PRF statistics unset
 * (mp_fit_opts.stats) and sets them once at its end, for every star it
 * fitted: the output columns are the statistics of the whole PRF at the
 * fitted position, as mp_prf_stats_at gives them, and the model errors
 * are set. */
static void test_model_errors_at_the_end(void **state)
{
    (void)state;
    char err[MP_ERRLEN];
    mp_psf p;
    mp_psf_gauss(FWHM, &p);
    mp_prf_model m = {&p, NULL, 10};
    mp_frame f;
    frame6(&f, 5);
    mp_frame_opts o;
    mp_frame_opts_default(&o);
    mp_table t;
    table_n(&t, 5);
    mp_frame_report r;
    assert_int_equal(mp_fit_table(&f, &m, &o, &t, &r, err), 0);
    assert_int_equal(t.nrow, 5);
    for (size_t i = 0; i < t.nrow; i++) {
        mp_prf_stats st;
        assert_int_equal(mp_prf_stats_at(&m, get(&t, i, "XPSF_IMAGE"), get(&t, i, "YPSF_IMAGE"),
                                         &st, NULL), 0);
        assert_true(st.beta > 0);
        assert_true(get(&t, i, "BETA_PSF") == st.beta);
        assert_true(get(&t, i, "SHARP_PRF") == st.sharp);
        assert_true(get(&t, i, "LSCALE_PRF") == st.lscale);
        assert_true(get(&t, i, "VOLUME_PRF") == st.volume);
        assert_true(get(&t, i, "FLUXERR_MODEL") > 0 && get(&t, i, "POSERR_MODEL") > 0);
    }
    mp_table_free(&t);
    sf_frame_drop(&f);
}

/* Across calls (the pipeline's rounds): a new star joins group 2; group 1,
 * 50 px away, is not refitted (its fit is kept bit for bit), group 2 is.
 * Against a full refit of the same table, group 1 differs by less than the
 * refit tolerance bound (0.1 σ; nothing changed around it, so in fact by
 * the convergence tolerance). */
static void test_round_refits_only_touched_group(void **state)
{
    (void)state;
    char err[MP_ERRLEN];
    mp_psf p;
    mp_psf_gauss(FWHM, &p);
    mp_prf_model m = {&p, NULL, 10};
    mp_frame f;
    frame6(&f, NS);
    mp_frame_opts eco, full;
    mp_frame_opts_default(&eco);
    full = eco;
    full.refittol = 0.0;
    mp_fit_memory *mem = mp_fit_memory_new();
    assert_non_null(mem);
    mp_table t;
    table_n(&t, 5);
    mp_frame_report r1, r2, r3;
    assert_int_equal(mp_fit_table_mem(&f, &m, &eco, &t, mem, &r1, err), 0);
    double before[3];
    for (int k = 0; k < 3; k++)
        before[k] = get(&t, (size_t)k, "FLUX_PSF");
    add_row(&t, 5);
    mp_table u;                       /* the same table for the full refit */
    mp_table_init(&u);
    for (size_t c = 0; c < t.ncol; c++)
        assert_true(mp_table_add_col(&u, t.cols[c].name) >= 0);
    for (size_t r = 0; r < t.nrow; r++) {
        assert_true(mp_table_add_row(&u) >= 0);
        for (size_t c = 0; c < t.ncol; c++)
            mp_table_set(&u, r, (int)c, mp_table_get(&t, r, (int)c));
    }
    assert_int_equal(mp_fit_table_mem(&f, &m, &eco, &t, mem, &r2, err), 0);
    assert_int_equal(mp_fit_table(&f, &m, &full, &u, &r3, err), 0);
    print_message("round 2: economy %ld fits, %ld kept; full %ld fits, %ld kept\n", r2.fits,
                  r2.kept, r3.fits, r3.kept);
    /* pass 1: group 2 refitted (a new member), group 1 kept; pass 2:
     * group 2 refitted only if group 1 changed around it, which it did not. */
    assert_int_equal(r2.fits, 1);
    assert_int_equal(r2.kept, 3);
    assert_int_equal(r3.fits, 4);
    assert_int_equal(t.nrow, 6);
    for (int k = 0; k < 3; k++) {
        assert_true(get(&t, (size_t)k, "FLUX_PSF") == before[k]);
        double s = get(&u, (size_t)k, "FLUXERR_PSF");
        assert_true(fabs(get(&t, (size_t)k, "FLUX_PSF") - get(&u, (size_t)k, "FLUX_PSF")) < 0.1 * s);
        assert_true(get(&t, (size_t)k, "FLUXERR_PSF") > 0);   /* errors came back too */
    }
    /* The new star was fitted: near its true flux (5σ of its error). */
    double s5 = get(&t, 5, "FLUXERR_PSF");
    assert_true(s5 > 0 && fabs(get(&t, 5, "FLUX_PSF") - SE[5]) < 5 * s5);
    mp_fit_memory_free(mem);
    mp_table_free(&t);
    mp_table_free(&u);
    sf_frame_drop(&f);
}

/* A loose fit (mp_frame_opts.loosetol: a fit a full one follows, stopped
 * at a tol above the run's) is never kept: a later call with the same memory
 * and nothing changed refits both groups, and ends where a full fit of
 * the same start does within 0.1 σ; after a fit at the run's tol the same
 * later call keeps both (0 fits). */
static void test_loose_fit_refitted(void **state)
{
    (void)state;
    char err[MP_ERRLEN];
    mp_psf p;
    mp_psf_gauss(FWHM, &p);
    mp_prf_model m = {&p, NULL, 10};
    mp_frame f;
    frame6(&f, 5);
    mp_frame_opts eco, loose, full;
    mp_frame_opts_default(&eco);
    eco.fit.tol = 0.03;
    loose = eco;
    loose.passes = 1;
    loose.loosetol = 0.3;
    full = eco;
    full.refittol = 0.0;
    mp_table u;                       /* the full fit of the same start */
    table_n(&u, 5);
    assert_int_equal(mp_fit_table(&f, &m, &full, &u, NULL, err), 0);
    long fits[2];
    for (int lo = 0; lo < 2; lo++) {
        mp_fit_memory *mem = mp_fit_memory_new();
        assert_non_null(mem);
        mp_table t;
        table_n(&t, 5);
        mp_frame_report r1, r2;
        assert_int_equal(mp_fit_table_mem(&f, &m, lo ? &loose : &eco, &t, mem, &r1, err), 0);
        assert_int_equal(mp_fit_table_mem(&f, &m, &eco, &t, mem, &r2, err), 0);
        fits[lo] = r2.fits;
        for (size_t k = 0; lo && k < t.nrow; k++) {
            double s = get(&u, k, "FLUXERR_PSF");
            assert_true(s > 0);
            assert_true(fabs(get(&t, k, "FLUX_PSF") - get(&u, k, "FLUX_PSF")) < 0.1 * s);
        }
        mp_fit_memory_free(mem);
        mp_table_free(&t);
    }
    mp_table_free(&u);
    print_message("the call after: %ld fits after a fit at tol, %ld after a loose one\n",
                  fits[0], fits[1]);
    assert_int_equal(fits[0], 0);
    assert_true(fits[1] >= 2);
    sf_frame_drop(&f);
}

/* The faintest star's S/N in t (its NUMBER in *num); +inf when t is empty. */
static double faintest_snr(const mp_table *t, double *num)
{
    double lo = INFINITY;
    for (size_t k = 0; k < t->nrow; k++) {
        double e = get(t, k, "FLUXERR_PSF"), s = get(t, k, "FLUX_PSF") / e;
        if (e > 0 && s < lo) {
            lo = s;
            *num = get(t, k, "NUMBER");
        }
    }
    return lo;
}

/* Whether star NUMBER num is still in t (a rejected or merged star's row
 * is dropped). */
static int has_number(const mp_table *t, double num)
{
    for (size_t k = 0; k < t->nrow; k++)
        if (get(t, k, "NUMBER") == num)
            return 1;
    return 0;
}

/* The steps' tol above the deciding one (mp_frame_opts.decidetol): with
 * minsnr 0.05 above the faintest star's S/N at tol 0.1, the rejection is
 * pending at that tol, so the group is fitted on to decidetol 0.03 (one
 * more LM fit of it than with decidetol 0, which decides at 0.1), and
 * the star's fate (kept or rejected) is the one a fit to 0.03 gives. */
static void test_decided_at_decidetol(void **state)
{
    (void)state;
    char err[MP_ERRLEN];
    mp_psf p;
    mp_psf_gauss(FWHM, &p);
    mp_prf_model m = {&p, NULL, 10};
    mp_frame f;
    frame6(&f, 3);
    mp_frame_opts o;
    mp_frame_opts_default(&o);
    o.fit.tol = 0.1;
    o.decidetol = 0.0;
    o.passes = 1;
    mp_table t;
    table_n(&t, 3);
    assert_int_equal(mp_fit_table(&f, &m, &o, &t, NULL, err), 0);
    double num = -1.0;
    double s01 = faintest_snr(&t, &num);
    mp_table_free(&t);
    assert_true(isfinite(s01));
    o.minsnr = s01 + 0.05;
    long calls[3], alive[3];
    for (int run = 0; run < 3; run++) {      /* decide at 0.1; at 0.03; fit to 0.03 */
        mp_frame_opts u = o;
        u.decidetol = run == 1 ? 0.03 : 0.0;
        u.fit.tol = run == 2 ? 0.03 : 0.1;
        mp_frame_report rep;
        table_n(&t, 3);
        assert_int_equal(mp_fit_table(&f, &m, &u, &t, &rep, err), 0);
        alive[run] = has_number(&t, num);
        calls[run] = rep.kcalls;
        mp_table_free(&t);
    }
    print_message("S/N %.3f at tol 0.1, minsnr %.3f: LM fits %ld / %ld / %ld, kept %ld / %ld / "
                  "%ld (decided at 0.1, at 0.03, fitted to 0.03)\n", s01, o.minsnr, calls[0],
                  calls[1], calls[2], alive[0], alive[1], alive[2]);
    assert_int_equal(calls[1], calls[0] + 1);
    assert_int_equal(alive[1], alive[2]);
    sf_frame_drop(&f);
}

/* Two groups 7 px apart (given separate GROUP_IDs, so each sees the other
 * as neighbour light): the first pass subtracts each with its start flux,
 * 20 % off; the fit changes that light by far more than 0.1 σ in the other
 * group's fitting region, so both are refitted in pass 2 (4 fits). */
static void test_changed_neighbour_refitted(void **state)
{
    (void)state;
    char err[MP_ERRLEN];
    mp_psf p;
    mp_psf_gauss(FWHM, &p);
    mp_prf_model m = {&p, NULL, 10};
    const double x[2] = {25.0, 32.0}, y[2] = {30.0, 30.0}, E[2] = {4e4, 4e4};
    mp_frame f;
    sf_frame_make(&f, 60, 60, 3.0);
    mp_rng r;
    mp_rng_seed(&r, 502);
    sf_render(&f, 100.0, FWHM, x, y, E, 2, &r, 3.0);
    double E0[2] = {1.2 * E[0], 0.8 * E[1]};
    mp_table t;
    sf_table(&t, x, y, E0, 2, 0);
    int cg = mp_table_add_col(&t, "GROUP_ID");
    mp_table_set(&t, 0, cg, 1);
    mp_table_set(&t, 1, cg, 2);
    mp_frame_opts o;
    mp_frame_opts_default(&o);
    mp_frame_report rep;
    assert_int_equal(mp_fit_table(&f, &m, &o, &t, &rep, err), 0);
    print_message("neighbours 7 px apart: %ld fits, %ld kept\n", rep.fits, rep.kept);
    assert_int_equal(rep.fits, 4);
    assert_int_equal(rep.kept, 0);
    mp_table_free(&t);
    sf_frame_drop(&f);
}

/* The envelope bounds the PRF: for stars at 40 random subpixel positions
 * (seeded), every rendered pixel at distance ≥ r from the star is at most
 * env[r] — for the analytic Gaussian and for a 2× table (whose sinc
 * shift rings).  A bound, so no tolerance. */
static void test_envelope_bounds_prf(void **state)
{
    (void)state;
    char err[MP_ERRLEN];
    mp_psf g, t;
    mp_psf_gauss(FWHM, &g);
    assert_int_equal(mp_psf_gauss_table(FWHM, 2, 12.0, &t, err), 0);
    const mp_psf *ps[2] = {&g, &t};
    mp_rng rng;
    mp_rng_seed(&rng, 503);
    for (int c = 0; c < 2; c++) {
        mp_prf_model m = {ps[c], NULL, 10};
        int nr;
        double *env = mp_prf_envelope(&m, &nr);
        assert_non_null(env);
        for (int r = 1; r < nr; r++)
            assert_true(env[r] <= env[r - 1]);
        mp_prf_work w = {0};
        for (int s = 0; s < 40; s++) {
            double x = 50.0 + mp_rng_uniform(&rng), y = 50.0 + mp_rng_uniform(&rng);
            long x0, y0;
            int bw, bh;
            mp_prf_box(&m, x, y, &x0, &y0, &bw, &bh);
            double *prf = malloc((size_t)bw * bh * sizeof *prf);
            assert_non_null(prf);
            assert_int_equal(mp_prf_render(&m, x, y, prf, NULL, NULL, &w), 0);
            for (int j = 0; j < bh; j++)
                for (int i = 0; i < bw; i++) {
                    double d = hypot(x0 + i - x, y0 + j - y);
                    int r = (int)floor(d);
                    double v = fabs(prf[(size_t)j * bw + i]);
                    assert_true(r >= nr ? v == 0.0 : v <= env[r]);
                }
            free(prf);
        }
        mp_prf_work_free(&w);
        free(env);
    }
    mp_psf_free(&t);
}

/* The run's envelope (mp_econ_envelope) is the model's own, measured
 * once: for the cache's model each copy holds mp_prf_envelope's values
 * bit for bit, the second served from the memo; a table the cache was
 * not offered (another width) gets its own envelope, not the memo, and a
 * NULL cache measures afresh.  Exact: the same renders. */
static void test_envelope_kept_per_model(void **state)
{
    (void)state;
    char err[MP_ERRLEN];
    mp_psf a, b;
    assert_int_equal(mp_psf_gauss_table(FWHM, 2, 12.0, &a, err), 0);
    assert_int_equal(mp_psf_gauss_table(2.0 * FWHM, 2, 12.0, &b, err), 0);
    mp_prf_model ma = {&a, NULL, 10}, mb = {&b, NULL, 10};
    int na, nb, n1, n2, n3, n4;
    double *ea = mp_prf_envelope(&ma, &na), *eb = mp_prf_envelope(&mb, &nb);
    mp_econ_cache *c = mp_econ_cache_new();
    assert_non_null(c);
    assert_int_equal(mp_econ_offer(c, &ma, 0, NULL, 0, MP_PRF_CACHE_G), 0);
    double *e1 = mp_econ_envelope(c, &ma, &n1), *e2 = mp_econ_envelope(c, &ma, &n2);
    double *e3 = mp_econ_envelope(c, &mb, &n3), *e4 = mp_econ_envelope(NULL, &mb, &n4);
    assert_true(ea && eb && e1 && e2 && e3 && e4 && e1 != e2);
    assert_int_equal(n1, na);
    assert_int_equal(n2, na);
    assert_memory_equal(e1, ea, (size_t)na * sizeof *ea);
    assert_memory_equal(e2, ea, (size_t)na * sizeof *ea);
    assert_int_equal(n3, nb);
    assert_int_equal(n4, nb);
    assert_memory_equal(e3, eb, (size_t)nb * sizeof *eb);
    assert_memory_equal(e4, eb, (size_t)nb * sizeof *eb);
    /* the wider table's envelope is not the memo's */
    assert_true(nb != na || memcmp(eb, ea, (size_t)na * sizeof *ea) != 0);
    free(ea);
    free(eb);
    free(e1);
    free(e2);
    free(e3);
    free(e4);
    mp_econ_cache_free(c);
    mp_psf_free(&a);
    mp_psf_free(&b);
}

/* The kernel length per group (economy, fit/sinc_choice.c): on a 1x table
 * of FWHM 3 the groups of these 5e3–3e4 e- stars get a kernel shorter than
 * sinchw 10, counted in the report, and the fluxes differ from the full
 * kernel's by at most the choice's bound, 0.1 of their σ (+ 0.02 σ for the
 * two fits' convergence, tol 1e-3 σ each, and the error estimate's own
 * spread). */
static void test_short_kernel_per_group(void **state)
{
    (void)state;
    char err[MP_ERRLEN];
    mp_psf p;
    assert_int_equal(mp_psf_gauss_table(FWHM, 1, 15.0, &p, err), 0);
    mp_prf_model m = {&p, NULL, 10};
    mp_sinc_choice c;
    assert_int_equal(mp_sinc_choice_build(&m, &c, err), 0);
    mp_frame f;
    frame6(&f, 5);
    mp_frame_opts eco, full;
    mp_frame_opts_default(&eco);
    full = eco;
    eco.sinc = &c;
    mp_table a, b;
    table_n(&a, 5);
    table_n(&b, 5);
    mp_frame_report ra, rb;
    assert_int_equal(mp_fit_table(&f, &m, &eco, &a, &ra, err), 0);
    assert_int_equal(mp_fit_table(&f, &m, &full, &b, &rb, err), 0);
    print_message("short kernels: %ld of %ld LM fits, mean half-width %.1f\n", ra.kshort,
                  ra.kcalls, ra.khw / (double)ra.kcalls);
    assert_true(ra.kshort >= 1 && ra.kshort <= ra.kcalls);
    assert_true(ra.khw < 10.0 * (double)ra.kcalls);
    assert_int_equal(rb.kshort, 0);
    assert_int_equal(a.nrow, b.nrow);
    for (size_t i = 0; i < a.nrow; i++) {
        double s = get(&b, i, "FLUXERR_PSF");
        assert_true(fabs(get(&a, i, "FLUX_PSF") - get(&b, i, "FLUX_PSF")) < 0.12 * s);
        assert_true(fabs(get(&a, i, "XPSF_IMAGE") - get(&b, i, "XPSF_IMAGE")) <
                    0.12 * get(&b, i, "ERRX_PSF"));
    }
    mp_table_free(&a);
    mp_table_free(&b);
    mp_sinc_choice_free(&c);
    mp_psf_free(&p);
    sf_frame_drop(&f);
}

/* The paper's setup: one star of E e- at (30.3, 29.8) on a 60×60 frame
 * (noise drawn from r, seeded), a ×1 Gaussian table (FWHM, ±15 px) as
 * model m, its kernel choice c, and economy's options with it for a
 * whole-frame fit (fitrad INDEF). */
typedef struct {
    mp_psf p;
    mp_prf_model m;
    mp_sinc_choice c;
    mp_frame_opts eco;
    mp_frame f;
    mp_rng r;
    double x, y;
} lone_star;

static void lone_star_make(lone_star *L, double E, uint64_t seed)
{
    char err[MP_ERRLEN];
    assert_int_equal(mp_psf_gauss_table(FWHM, 1, 15.0, &L->p, err), 0);
    L->m = (mp_prf_model){&L->p, NULL, 10};
    assert_int_equal(mp_sinc_choice_build(&L->m, &L->c, err), 0);
    mp_frame_opts_default(&L->eco);
    L->eco.sinc = &L->c;
    L->eco.fit.fitrad = NAN;
    sf_frame_make(&L->f, 60, 60, 3.0);
    mp_rng_seed(&L->r, seed);
    L->x = 30.3;
    L->y = 29.8;
    sf_render(&L->f, 100.0, FWHM, &L->x, &L->y, &E, 1, &L->r, 3.0);
}

/* A star offered far below its flux (a saturated star's plateau, a
 * detection on a bright star's wings) is fitted with the kernel its start
 * flux allows, and that kernel's bias bound holds for that flux only: the
 * group is fitted again with the kernel its fitted flux chooses (once:
 * MP_REFIT_BRIGHTER), and ends where a fit offered the true flux ends.
 * One star of 10^6 e- offered at 10^3 on a 60×60 frame, whole-frame fit.
 * The bounds: the first kernel mp_sinc_choice_hw gives for 10^3 is
 * shorter than the one for the fitted flux (else the test is void, and
 * fails); both fits stop at tol = 0.1 of the flux's σ from the same
 * minimum, so they agree within 0.2 σ (deterministic: fixed seed). */
static void test_refit_when_fitted_brighter(void **state)
{
    (void)state;
    char err[MP_ERRLEN];
    double E = 1e6, low = 1e3;
    lone_star L;
    lone_star_make(&L, E, 79);
    int hlow = mp_sinc_choice_hw(&L.c, low, 0.0, 3.0, L.eco.sincfrac);
    int hfit = mp_sinc_choice_hw(&L.c, E, 0.0, 3.0, L.eco.sincfrac);
    assert_true(hlow < hfit);
    mp_table a, b;
    sf_table(&a, &L.x, &L.y, &low, 1, 0);
    sf_table(&b, &L.x, &L.y, &E, 1, 0);
    mp_frame_report ra, rb;
    assert_int_equal(mp_fit_table(&L.f, &L.m, &L.eco, &a, &ra, err), 0);
    assert_int_equal(mp_fit_table(&L.f, &L.m, &L.eco, &b, &rb, err), 0);
    print_message("offered 1e3: %ld LM fits (%ld again, fitted brighter), last half-width %.0f; "
                  "offered 1e6: %ld\n", ra.kcalls, ra.refits[MP_REFIT_BRIGHTER],
                  ra.khw - hlow, rb.kcalls);
    assert_int_equal(ra.refits[MP_REFIT_BRIGHTER], 1);
    assert_int_equal(rb.refits[MP_REFIT_BRIGHTER], 0);
    double sa = get(&b, 0, "FLUXERR_PSF");
    assert_true(fabs(get(&a, 0, "FLUX_PSF") - get(&b, 0, "FLUX_PSF")) < 0.2 * sa);
    assert_true(fabs(get(&a, 0, "XPSF_IMAGE") - get(&b, 0, "XPSF_IMAGE")) <
                0.2 * get(&b, 0, "ERRX_PSF"));
    mp_table_free(&a);
    mp_table_free(&b);
    mp_sinc_choice_free(&L.c);
    mp_psf_free(&L.p);
    sf_frame_drop(&L.f);
}

/* Economy's own cost is bounded by counts (issue 10.3; never a time): a
 * whole-frame fit (fitrad INDEF, the paper's setup: one 60×60 frame, one
 * star) builds no crop envelope (nobody else's light to crop) and spends at
 * most hwmax kernel-bound evaluations per LM fit, where the per-frame
 * limits table took MP_SINC_LIMITS_EVALS·hwmax = 620; and a frame of more
 * groups than MP_SINC_LIMITS_EVALS builds the limits once, so the choice
 * never costs more than min(LM fits, MP_SINC_LIMITS_EVALS)·hwmax
 * evaluations; with the run's cache (mp_econ_cache) only the first frame
 * of an @list pays.  The kernel a lone star gets is the one
 * mp_sinc_choice_hw gives for its start flux on the safe side (sky 0).
 * Deterministic given the seeds. */
static void test_whole_frame_overhead_counted(void **state)
{
    (void)state;
    char err[MP_ERRLEN];
    /* One star, whole frame. */
    double E = 2e4, E0 = 1.2 * E;
    lone_star L;
    lone_star_make(&L, E, 77);
    mp_frame_opts eco = L.eco;
    mp_sinc_choice *c = &L.c;
    mp_prf_model m = L.m;
    mp_frame f = L.f;
    mp_rng r = L.r;
    double x = L.x, y = L.y;
    mp_table t;
    sf_table(&t, &x, &y, &E0, 1, 0);
    mp_frame_report rep;
    assert_int_equal(mp_fit_table(&f, &m, &eco, &t, &rep, err), 0);
    assert_int_equal(rep.envelopes, 0);
    assert_int_equal(rep.kcalls, 1);
    int hw = mp_sinc_choice_hw(c, E0, 0.0, 3.0, eco.sincfrac);
    assert_true(hw < c->hwmax);                  /* a decision was taken... */
    assert_int_equal((int)rep.khw, hw);         /* ...the one the bound gives */
    assert_int_equal(rep.kbounds, hw + 1);      /* at hw + 1 evaluations */
    assert_true(rep.kbounds <= (long)c->hwmax * rep.kcalls);
    mp_table_free(&t);
    sf_frame_drop(&f);
    /* 70 lone stars 20 px apart, fitrad 5: 70 groups > 62, limits once. */
    enum { NX = 10, NY = 7, NN = NX * NY };
    double xs[NN], ys[NN], es[NN], e0[NN];
    for (int k = 0; k < NN; k++) {
        xs[k] = 10.0 + 20.0 * (k % NX) + 0.1 * (k % 3);
        ys[k] = 10.0 + 20.0 * (k / NX) - 0.1 * (k % 5);
        es[k] = 3e3 * (1 + k % 7);
        e0[k] = 1.2 * es[k];
    }
    sf_frame_make(&f, 20 * NX, 20 * NY, 3.0);
    sf_render(&f, 100.0, FWHM, xs, ys, es, NN, &r, 3.0);
    sf_table(&t, xs, ys, e0, NN, 0);
    eco.fit.fitrad = 5.0;
    assert_int_equal(mp_fit_table(&f, &m, &eco, &t, &rep, err), 0);
    print_message("70 groups: %ld LM fits, %ld bound evaluations, %ld envelopes\n", rep.kcalls,
                  rep.kbounds, rep.envelopes);
    assert_int_equal(rep.ngroups, NN);
    assert_int_equal(rep.kbounds, (long)c->hwmax * MP_SINC_LIMITS_EVALS);
    assert_int_equal(rep.envelopes, 1);
    mp_table_free(&t);
    sf_frame_drop(&f);
    /* With the run's cache (mp_fit_setup's, an @list's frames, when the
     * run plans for more fits than the limits cost evaluations): the first
     * frame finds the limits, every later one on the same sky level none. */
    eco.cache = mp_econ_cache_new();
    assert_non_null(eco.cache);
    eco.fits = 100.0;
    eco.fit.fitrad = NAN;
    for (int k = 0; k < 3; k++) {
        sf_frame_make(&f, 60, 60, 3.0);
        sf_render(&f, 100.0, FWHM, &x, &y, &E, 1, &r, 3.0);
        sf_table(&t, &x, &y, &E0, 1, 0);
        assert_int_equal(mp_fit_table(&f, &m, &eco, &t, &rep, err), 0);
        assert_int_equal(rep.kbounds, k == 0 ? (long)c->hwmax * MP_SINC_LIMITS_EVALS : 0);
        assert_int_equal((int)rep.khw, hw);     /* the same choice as without */
        mp_table_free(&t);
        sf_frame_drop(&f);
    }
    mp_econ_cache_free(eco.cache);
    mp_sinc_choice_free(c);
    mp_psf_free(&L.p);
}

/* The supersampling choice per group (issue 10.2, fit/ss_choice.c): on a
 * Gaussian FWHM 3 x2 table, a faint star's group (half the limit) is
 * fitted with the x1 block-sum (its linearised bias is below 0.1 σ and
 * its χ² shift below 1), a bright one's (1e6 e-, over the x1 limit of
 * 2.5e5 e- on sky 100) with the x2 table, as counted, and the bright one's
 * fit is the x2 fit exactly.  The criterion bounds the BIAS of the x1 fit
 * against the x2 fit, E[x1 − x2] ≤ 0.1 σ; one noisy frame adds a
 * noise-driven difference (the two models' derivatives differ; 0.12 σ in
 * x on one frame), so the mean difference over NDRAW seeded frames is
 * tested: |mean| ≤ 0.1 + 3·sd/√NDRAW in flux, x and y (each a 3σ bound on
 * a mean of NDRAW = 30 draws: a false failure ≤ 0.3 % per parameter, 0.8 %
 * for the three, were the bias exactly at the bound).  The bias itself is
 * checked on noiseless fits at the limit in test_economy. */
/* One frame of the two stars (seed), fitted with the x1 level offered and
 * without; d[3] the faint star's (x1 − x2) in flux, x, y over x2's σ. */
static void coarse_pair(const mp_prf_model *m, const mp_ss_level *lv, const double *es,
                        uint64_t seed, mp_frame_report *ra, mp_frame_report *rb, mp_table *a,
                        mp_table *b, double d[3])
{
    char err[MP_ERRLEN];
    double xs[2] = {30.3, 30.6}, ys[2] = {30.2, 79.7}, e0[2] = {es[0], es[1]};
    mp_frame f;
    sf_frame_make(&f, 60, 110, 3.0);
    mp_rng r;
    mp_rng_seed(&r, seed);
    sf_render(&f, 100.0, FWHM, xs, ys, es, 2, &r, 3.0);
    mp_frame_opts eco, full;
    mp_frame_opts_default(&eco);
    full = eco;
    eco.ss = lv;
    eco.nss = 1;
    sf_table(a, xs, ys, e0, 2, 0);
    sf_table(b, xs, ys, e0, 2, 0);
    int cs = mp_table_add_col(a, "SKY_PSF"), cb = mp_table_add_col(b, "SKY_PSF");
    for (size_t i = 0; i < 2; i++) {
        mp_table_set(a, i, cs, 100.0);
        mp_table_set(b, i, cb, 100.0);
    }
    assert_int_equal(mp_fit_table(&f, m, &eco, a, ra, err), 0);
    assert_int_equal(mp_fit_table(&f, m, &full, b, rb, err), 0);
    assert_int_equal(a->nrow, 2);
    d[0] = (get(a, 0, "FLUX_PSF") - get(b, 0, "FLUX_PSF")) / get(b, 0, "FLUXERR_PSF");
    d[1] = (get(a, 0, "XPSF_IMAGE") - get(b, 0, "XPSF_IMAGE")) / get(b, 0, "ERRX_PSF");
    d[2] = (get(a, 0, "YPSF_IMAGE") - get(b, 0, "YPSF_IMAGE")) / get(b, 0, "ERRY_PSF");
    sf_frame_drop(&f);
}

static void test_coarse_table_per_group(void **state)
{
    (void)state;
    enum { NDRAW = 30 };
    char err[MP_ERRLEN];
    mp_psf p;
    assert_int_equal(mp_psf_gauss_table(FWHM, 2, 15.0, &p, err), 0);
    mp_prf_model m = {&p, NULL, 10};
    mp_ss_level lv;
    assert_int_equal(mp_ss_level_build(&m, 2, 0, &lv, err), 0);   /* its full kernel */
    lv.os = 1;
    double lim = mp_ss_level_emax(&lv, 100.0, 3.0, 0.1);
    double es[2] = {0.5 * lim, 1e6}, sum[3] = {0}, sum2[3] = {0};
    for (int k = 0; k < NDRAW; k++) {
        mp_frame_report ra, rb;
        mp_table a, b;
        double d[3];
        coarse_pair(&m, &lv, es, 91 + (uint64_t)k, &ra, &rb, &a, &b, d);
        if (k == 0)
            print_message("x1 limit %.3g e-: %ld of %ld LM fits with the x1 table, %ld bound "
                          "evaluations\n", lim, ra.kcoarse, ra.kcalls, ra.kbounds);
        assert_int_equal(ra.ngroups, 2);
        assert_true(ra.kcalls >= 2);
        assert_int_equal(ra.kcoarse, ra.kcalls / 2);   /* the faint star's every fit, no other */
        assert_int_equal(rb.kcoarse, 0);
        assert_true(get(&a, 1, "FLUX_PSF") == get(&b, 1, "FLUX_PSF"));   /* the same x2 fit */
        for (int j = 0; j < 3; j++) {
            sum[j] += d[j];
            sum2[j] += d[j] * d[j];
        }
        mp_table_free(&a);
        mp_table_free(&b);
    }
    static const char *const name[3] = {"flux", "x", "y"};
    for (int j = 0; j < 3; j++) {
        double mean = sum[j] / NDRAW, sd = sqrt(fmax(sum2[j] / NDRAW - mean * mean, 0.0));
        double tol = 0.1 + 3.0 * sd / sqrt((double)NDRAW);
        print_message("faint star x1 - x2 over %d frames: %s mean %.4f sigma (sd %.4f, bound %.4f)\n",
                      NDRAW, name[j], mean, sd, tol);
        assert_true(fabs(mean) <= tol);
    }
    mp_ss_level_free(&lv);
    mp_psf_free(&p);
}

/* Economy's tables pay for themselves (issue 10: "economy must never cost
 * more than it saves"), counted in the plan's unit (multiply-adds of the
 * renders and bound sums, fit/econ_plan.c), never timed.  One 60×60 frame
 * with one star, whole-frame fit: no table can pay for its build, none is
 * built (nothing spent) and the fit is economy=no's exactly.  A run of 200
 * such frames (the paper's magnitudes −6 … −15, start flux ×1.2, planned
 * as one run as `matphot fit @list` plans it): tables are built, and what
 * they and their bound evaluations cost over the run is at most what they
 * saved on the fits' renders.  Deterministic given the seeds. */
static void test_tables_pay_for_themselves(void **state)
{
    (void)state;
    enum { NRUN = 200 };
    char err[MP_ERRLEN];
    mp_psf p;
    assert_int_equal(mp_psf_gauss_table(FWHM, 2, 15.0, &p, err), 0);
    mp_prf_model m = {&p, NULL, 10};
    mp_frame_opts eco, full;
    mp_frame_opts_default(&eco);
    eco.fit.fitrad = NAN;
    full = eco;
    eco.cache = mp_econ_cache_new();
    assert_non_null(eco.cache);
    int lev[1] = {1};
    assert_int_equal(mp_econ_offer(eco.cache, &m, 1, lev, 1, MP_PRF_CACHE_G), 0);
    mp_rng r;
    mp_rng_seed(&r, 4242);
    double spent = 0.0, saved = 0.0, first = 0.0;
    long coarse = 0, shortk = 0;
    for (int k = 0; k <= NRUN; k++) {
        double x = 30.0 + mp_rng_uniform(&r), y = 30.0 + mp_rng_uniform(&r);
        double E = pow(10.0, 0.4 * (6.0 + 9.0 * mp_rng_uniform(&r))), E0 = 1.2 * E;
        mp_frame f;
        sf_frame_make(&f, 60, 60, 3.0);
        sf_render(&f, 100.0, FWHM, &x, &y, &E, 1, &r, 3.0);
        mp_table t;
        sf_table(&t, &x, &y, &E0, 1, 0);
        mp_frame_report rep;
        eco.fits = k == 0 ? 0.0 : NRUN;        /* frame 0: alone */
        assert_int_equal(mp_fit_table(&f, &m, &eco, &t, &rep, err), 0);
        if (k == 0) {
            assert_true(rep.ops_tables == 0.0);
            assert_int_equal(rep.kbounds, 0);
            assert_int_equal(rep.kcoarse + rep.kshort + rep.kcache, 0);
            mp_table u;
            sf_table(&u, &x, &y, &E0, 1, 0);
            assert_int_equal(mp_fit_table(&f, &m, &full, &u, NULL, err), 0);
            assert_true(get(&t, 0, "FLUX_PSF") == get(&u, 0, "FLUX_PSF"));
            assert_true(get(&t, 0, "XPSF_IMAGE") == get(&u, 0, "XPSF_IMAGE"));
            mp_table_free(&u);
        } else {
            first = k == 1 ? rep.ops_tables : first;
            spent += rep.ops_tables;
            saved += rep.ops_saved;
            coarse += rep.kcoarse;
            shortk += rep.kshort;
        }
        mp_table_free(&t);
        sf_frame_drop(&f);
    }
    double unit = mp_econ_render_ops(&m, m.sinc_hw, NAN);
    print_message("%d frames: tables and bounds %.0f renders (first frame %.0f), saved %.0f; "
                  "%ld fits with x1, %ld with a shorter kernel\n", NRUN, spent / unit,
                  first / unit, saved / unit, coarse, shortk);
    assert_true(first > 0.0);                   /* built: the run pays for them */
    assert_true(spent <= saved);
    mp_econ_cache_free(eco.cache);
    mp_psf_free(&p);
}

/* The plan prices a render on the windows the frame measured
 * (mp_frame_opts.win, issue 12), not on a lone star's 2·ceil(fitrad) + 3
 * px: on 47 Tuc a star is rendered on ~40 px a side, not 13, so the phase
 * grid never paid in `matphot fit`.  The smallest run (fits, powers of 2)
 * for which the grid is built, with win = 0 (fitrad 5: 13 px) and win =
 * 40: the gain is fits · 4 · (exact render − grid render), so the
 * thresholds are in the ratio of the savings per render, 5.3 for this
 * ×2 table of 41 px (econ_plan.c's render_ops: 266e3 against 50e3 ops);
 * on powers of 2, 4 or 8.  A plan that ignored win gives 1.
 * Deterministic: no false-failure rate. */
/* paint_ops > 0: instead, a run planned for one fit that has painted n
 * whole boxes of paint_ops multiply-adds each (mp_econ_learn_paint), its
 * options' learn as given; the smallest such n. */
static long grid_threshold_of(const mp_prf_model *m, double win, double paint_ops, int learn)
{
    for (long n = 1; n <= (1L << 24); n *= 2) {
        char err[MP_ERRLEN];
        mp_frame_opts o;
        mp_frame_opts_default(&o);
        o.win = win;
        o.learn = learn;
        mp_econ_cache *c = mp_econ_cache_new();
        assert_non_null(c);
        assert_int_equal(mp_econ_offer(c, m, 0, NULL, 0, MP_PRF_CACHE_G), 0);
        mp_econ_learn_paint(c, (double)n * paint_ops);
        double fits = paint_ops > 0 ? 1.0 : (double)n;
        assert_int_equal(mp_econ_choose(c, fits, o.fit.fitrad, &o, NULL, err), 0);
        int built = o.grid != NULL;
        mp_econ_cache_free(c);
        if (built)
            return n;
    }
    return -1;
}

static long grid_threshold(const mp_prf_model *m, double win)
{
    return grid_threshold_of(m, win, 0.0, 0);
}

static void test_plan_prices_measured_windows(void **state)
{
    (void)state;
    char err[MP_ERRLEN];
    mp_psf p;
    assert_int_equal(mp_psf_gauss_table(FWHM, 2, 20.0, &p, err), 0);
    mp_prf_model m = {&p, NULL, 10};
    long lone = grid_threshold(&m, 0.0), wide = grid_threshold(&m, 40.0);
    print_message("grid built from %ld fits (13-px windows), %ld (40-px)\n", lone, wide);
    assert_true(lone > 0 && wide > 0);
    assert_true(lone >= 4 * wide && lone <= 8 * wide);
    mp_psf_free(&p);
}

/* The exact paints of a run's neighbours' light pay for the model's
 * phase grid, which draws them too (fit/frame_paint.c): a run planned for
 * one star fit builds no grid, but once it has painted enough whole
 * boxes exactly (mp_econ_learn_paint, counted as the paints count their
 * work: mp_prf_work.ops of a render without derivatives) a run that
 * learns (a pipeline frame's) builds it; one that does not learn never
 * does.  On frame S of compare_daophot.sh at fitrad = FWHM, whose fits
 * took coarser tables that never paid for the grid, the exact paints were
 * half the run's samples.  Deterministic: no false-failure rate. */
static void test_paints_pay_for_grid(void **state)
{
    (void)state;
    char err[MP_ERRLEN];
    mp_psf p;
    assert_int_equal(mp_psf_gauss_table(FWHM, 2, 20.0, &p, err), 0);
    mp_prf_model m = {&p, NULL, 10};
    long x0, y0;
    int w, h;
    mp_prf_box(&m, 50.3, 50.6, &x0, &y0, &w, &h);
    double *prf = malloc((size_t)w * h * sizeof *prf);
    assert_non_null(prf);
    mp_prf_work wk = {0};
    assert_int_equal(mp_prf_render(&m, 50.3, 50.6, prf, NULL, NULL, &wk), 0);
    double ops = wk.ops;
    mp_prf_work_free(&wk);
    free(prf);
    assert_true(ops > 0);
    long learned = grid_threshold_of(&m, 0.0, ops, 1), unlearned = grid_threshold_of(&m, 0.0, ops, 0);
    print_message("grid built after %ld whole-box paints (%.0f multiply-adds each)\n", learned,
                  ops);
    assert_true(learned > 0);
    assert_int_equal(unlearned, -1);
    /* The residual's paints reach the cache: 64 stars painted 2·learned/64
     * times build the grid, a cache that painted none does not. */
    mp_frame f;
    sf_frame_make(&f, 160, 160, 3.0);
    enum { NP = 64 };
    double xs[NP], ys[NP], es[NP];
    for (int k = 0; k < NP; k++) {
        xs[k] = 12.3 + 19.0 * (k % 8);
        ys[k] = 12.7 + 19.0 * (k / 8);
        es[k] = 1e4;
    }
    mp_table t;
    sf_fitted_table(&t, xs, ys, es, 100.0, NP);
    float *res = malloc(160 * 160 * sizeof *res);
    assert_non_null(res);
    mp_econ_cache *c = mp_econ_cache_new(), *none = mp_econ_cache_new();
    assert_true(c && none);
    assert_int_equal(mp_econ_offer(c, &m, 0, NULL, 0, MP_PRF_CACHE_G), 0);
    assert_int_equal(mp_econ_offer(none, &m, 0, NULL, 0, MP_PRF_CACHE_G), 0);
    for (long k = 0; k < 2 * learned / NP + 1; k++)
        assert_int_equal(mp_fit_residual_grid(&f, &m, &t, 0.0, c, NULL, 0.0, NULL, res, err), 0);
    mp_frame_opts o, on;
    mp_frame_opts_default(&o);
    o.learn = 1;
    on = o;
    assert_int_equal(mp_econ_choose(c, 1.0, o.fit.fitrad, &o, NULL, err), 0);
    assert_int_equal(mp_econ_choose(none, 1.0, on.fit.fitrad, &on, NULL, err), 0);
    assert_non_null(o.grid);
    assert_null(on.grid);
    mp_econ_cache_free(c);
    mp_econ_cache_free(none);
    free(res);
    mp_table_free(&t);
    sf_frame_drop(&f);
    mp_psf_free(&p);
}

/* The grid economy built for one cache, planned for 2^20 fits, with its
 * options' grid set; NULL when none was built. */
static const mp_prf_cache *grid_built(mp_econ_cache *c, const mp_prf_model *m)
{
    char err[MP_ERRLEN];
    mp_frame_opts o;
    mp_frame_opts_default(&o);
    assert_int_equal(mp_econ_offer(c, m, 0, NULL, 0, MP_PRF_CACHE_G), 0);
    assert_int_equal(mp_econ_choose(c, 1048576.0, o.fit.fitrad, &o, NULL, err), 0);
    return o.grid;
}

/* A cache handed an earlier one's grid (the pipeline's second pass,
 * pipeline/run_psf.c adopt_psf) builds its own in that grid's blocks when
 * they are of its size: the same blocks, and the values of a grid built
 * afresh, byte for byte; the earlier cache is left without one. */
static void test_grid_handed_on(void **state)
{
    (void)state;
    char err[MP_ERRLEN];
    mp_psf p, q;
    assert_int_equal(mp_psf_gauss_table(FWHM, 2, 20.0, &p, err), 0);
    assert_int_equal(mp_psf_gauss_table(1.1 * FWHM, 2, 20.0, &q, err), 0);
    mp_prf_model mp = {&p, NULL, 10}, mq = {&q, NULL, 10};
    mp_econ_cache *a = mp_econ_cache_new(), *b = mp_econ_cache_new(), *c = mp_econ_cache_new();
    assert_true(a && b && c);
    const mp_prf_cache *ga = grid_built(a, &mp);
    assert_non_null(ga);
    const float *img = ga->img;
    mp_econ_cache_hand_grid(a, b);
    const mp_prf_cache *gb = grid_built(b, &mq), *gc = grid_built(c, &mq);
    assert_true(gb && gc && gb->img == img && gc->img != img);
    int NA = gb->os * (gb->gb + 3);
    size_t ni = 3 * (size_t)NA * NA * gb->npix, nc = (size_t)gb->nph * gb->npix;
    assert_true(gb->npix == gc->npix && gb->nph == gc->nph);
    assert_memory_equal(gb->img, gc->img, ni * sizeof *gb->img);
    assert_memory_equal(gb->p, gc->p, nc * sizeof *gb->p);
    assert_memory_equal(gb->d2, gc->d2, nc * sizeof *gb->d2);
    mp_econ_cache_free(a);
    mp_econ_cache_free(b);
    mp_econ_cache_free(c);
    mp_psf_free(&p);
    mp_psf_free(&q);
}

/* The frame fit names the phase grid its groups drew from
 * (mp_frame_report.grid), so the pipeline's residual and one-or-two test
 * draw from that same grid (pipeline/run.c mp_run_phase_grid): asked afresh on
 * fitrad's windows, economy declined the grid that the fit's measured
 * ~40-px windows paid for, and 47 Tuc's one-or-two test rendered every
 * star exactly.  Planned for 2^20 fits the grid pays on any window: the
 * fit draws from it (kcache > 0) and names it, the grid economy keeps for
 * the run; without economy's cache it names none. */
static void test_report_names_grid(void **state)
{
    (void)state;
    char err[MP_ERRLEN];
    mp_psf p;
    assert_int_equal(mp_psf_gauss_table(FWHM, 2, 20.0, &p, err), 0);
    mp_prf_model m = {&p, NULL, 10};
    mp_frame f;
    frame6(&f, 5);
    mp_frame_opts eco, bare;
    mp_frame_opts_default(&eco);
    bare = eco;
    eco.cache = mp_econ_cache_new();
    assert_non_null(eco.cache);
    assert_int_equal(mp_econ_offer(eco.cache, &m, 0, NULL, 0, MP_PRF_CACHE_G), 0);
    eco.fits = (double)(1L << 20);
    mp_table a, b;
    table_n(&a, 5);
    table_n(&b, 5);
    mp_frame_report ra, rb;
    assert_int_equal(mp_fit_table(&f, &m, &eco, &a, &ra, err), 0);
    assert_int_equal(mp_fit_table(&f, &m, &bare, &b, &rb, err), 0);
    mp_frame_opts o = eco;
    assert_int_equal(mp_econ_choose(eco.cache, eco.fits, o.fit.fitrad, &o, NULL, err), 0);
    assert_true(ra.kcache > 0);
    assert_non_null(ra.grid);
    assert_ptr_equal(ra.grid, o.grid);
    assert_null(rb.grid);
    mp_table_free(&a);
    mp_table_free(&b);
    sf_frame_drop(&f);
    mp_econ_cache_free(eco.cache);
    mp_psf_free(&p);
}

int main(void)
{
    const struct CMUnitTest tests[] = {
        cmocka_unit_test(test_second_pass_kept_when_isolated),
        cmocka_unit_test(test_model_errors_at_the_end),
        cmocka_unit_test(test_round_refits_only_touched_group),
        cmocka_unit_test(test_loose_fit_refitted),
        cmocka_unit_test(test_decided_at_decidetol),
        cmocka_unit_test(test_changed_neighbour_refitted),
        cmocka_unit_test(test_envelope_bounds_prf),
        cmocka_unit_test(test_short_kernel_per_group),
        cmocka_unit_test(test_whole_frame_overhead_counted),
        cmocka_unit_test(test_refit_when_fitted_brighter),
        cmocka_unit_test(test_coarse_table_per_group),
        cmocka_unit_test(test_tables_pay_for_themselves),
        cmocka_unit_test(test_plan_prices_measured_windows),
        cmocka_unit_test(test_paints_pay_for_grid),
        cmocka_unit_test(test_grid_handed_on),
        cmocka_unit_test(test_report_names_grid),
        cmocka_unit_test(test_envelope_kept_per_model),
    };
    return cmocka_run_group_tests(tests, NULL, NULL);
}
