/* test_bench_scoring.c — the DAOPHOT bench's scoring (tests/bench/daophot/
 * compare.c, `compare stats`): each catalog read by its own reader and
 * matched to the truth.  Its built-PSF row (mpb.cat) was read as a
 * DAOPHOT .als for sessions and scored 0 stars found, and no test saw it.
 *
 * A frame of 100 true stars on a grid 30 px apart; matphot's catalogs
 * (ASCII_HEAD, XPSF_IMAGE/YPSF_IMAGE/MAG_PSF) hold the first 90 (mp) and 80
 * (mpb), DAOPHOT's (an ALLSTAR text database: #N lines continued by a
 * backslash, records over two lines) the first 70 (dao), each with its
 * own magnitude zero point and positions 0.1 px off; one spurious entry
 * far from any star in mp.  Every number below follows from that exactly.
 * The other catalogs (mpd, dao1, daoa) are absent and must read so. */
#define main compare_main
#include "../bench/daophot/compare.c"
#undef main
#include "../bench/daophot/report.c"

#include <setjmp.h>
#include <stdarg.h>
#include <stddef.h>
#include <cmocka.h>
#include <unistd.h>

enum { NTRUE = 100 };

static double true_x(int k) { return 20.0 + 30.0 * (k % 10); }
static double true_y(int k) { return 20.0 + 30.0 * (k / 10); }
static double true_mag(int k) { return -12.5 + 0.05 * k; }

static char *joined(const char *dir, const char *name)
{
    char *p = malloc(strlen(dir) + strlen(name) + 2);
    assert_non_null(p);
    sprintf(p, "%s/%s", dir, name);
    return p;
}

/* An ASCII_HEAD table of the first n true stars: x + dx, y, mag + zp. */
static void write_matphot(const char *dir, const char *name, const char *cx, const char *cy,
                          const char *cm, int n, double dx, double zp, int spurious)
{
    char *p = joined(dir, name);
    FILE *f = fopen(p, "w");
    assert_non_null(f);
    fprintf(f, "#   1 %-22s x\n#   2 %-22s y\n#   3 %-22s magnitude\n", cx, cy, cm);
    for (int k = 0; k < n; k++)
        fprintf(f, "%.4f %.4f %.4f\n", true_x(k) + dx, true_y(k), true_mag(k) + zp);
    if (spurious)
        fprintf(f, "%.4f %.4f %.4f\n", 5.0, 290.0, -9.0);
    fclose(f);
    free(p);
}

/* ALLSTAR's .als layout: the first n true stars, y + dy, mag + zp. */
static void write_als(const char *dir, const char *name, int n, double dy, double zp)
{
    char *p = joined(dir, name);
    FILE *f = fopen(p, "w");
    assert_non_null(f);
    fputs("#K TASK       = allstar                 name       %-23s\n#\n"
          "#N ID    XCENTER   YCENTER   MAG         MERR          MSKY           NITER    \\\n"
          "#U ##    pixels    pixels    magnitudes  magnitudes    counts         ##       \\\n"
          "#F %-9d  %-10.3f   %-10.3f   %-12.3f     %-14.3f       %-15.7g        %-6d\n#\n"
          "#N         SHARPNESS   CHI         PIER  PERROR                                \\\n"
          "#U         ##          ##          ##    perrors                               \\\n"
          "#F         %-23.3f     %-12.3f     %-6d  %-13s\n#\n", f);
    for (int k = 0; k < n; k++)
        fprintf(f, "%-9d%-10.3f%-10.3f%-12.3f0.011         100.0          4        \\\n"
                   "           -0.050      1.000       0     No_error\n",
                k + 1, true_x(k), true_y(k) + dy, true_mag(k) + zp);
    /* a star ALLSTAR could not measure: INDEF, left out */
    fputs("999      INDEF     INDEF     INDEF       INDEF         INDEF          0        \\\n"
          "           INDEF       INDEF       1     Single_pixel\n", f);
    fclose(f);
    free(p);
}

static void test_each_catalog_by_its_reader(void **state)
{
    (void)state;
    char work[] = "/tmp/test_bench_scoring.XXXXXX";
    assert_non_null(mkdtemp(work));
    char *frame = joined(work, "A"), *cat = joined(frame, "cat");
    assert_int_equal(mkdir(frame, 0700), 0);
    assert_int_equal(mkdir(cat, 0700), 0);
    write_matphot(frame, "A.truth", "X_IMAGE", "Y_IMAGE", "MAG_TRUE", NTRUE, 0.0, 0.0, 0);
    write_matphot(cat, "mp.cat", "XPSF_IMAGE", "YPSF_IMAGE", "MAG_PSF", 90, 0.1, 0.25, 1);
    write_matphot(cat, "mpb.cat", "XPSF_IMAGE", "YPSF_IMAGE", "MAG_PSF", 80, 0.1, -0.5, 0);
    write_als(cat, "dao.als", 70, 0.1, 1.75);
    cmp_frame fr;
    memset(&fr, 0, sizeof fr);
    fr.name = "A";
    fr.fwhm = 3.0;
    fr.magmin = -13.0;
    fr.magmax = -7.0;
    assert_int_equal(frame_stats(work, &fr), 0);
    assert_int_equal(fr.ntrue, NTRUE);
    const struct { const char *name; long found, ndet, spurious; double zp; } want[CMP_NTOOL] = {
        {"mp", 90, 91, 1, 0.25}, {"mpd", -1, 0, 0, 0}, {"mpb", 80, 80, 0, -0.5},
        {"dao1", -1, 0, 0, 0},   {"dao", 70, 70, 0, 1.75}, {"daoa", -1, 0, 0, 0}};
    for (int i = 0; i < CMP_NTOOL; i++) {
        const cmp_tool *T = &fr.tools[i];
        print_message("%-4s missing %d, %ld rows, %ld found, %ld spurious, zp %+.3f\n", T->name,
                      T->missing != NULL, T->ndet, T->found, T->spurious, T->zp);
        assert_string_equal(T->name, want[i].name);
        if (want[i].found < 0) {
            assert_non_null(T->missing);
            free(T->missing);
            continue;
        }
        assert_null(T->missing);
        assert_int_equal(T->ndet, want[i].ndet);
        assert_int_equal(T->found, want[i].found);
        assert_int_equal(T->spurious, want[i].spurious);
        assert_true(fabs(T->compl - want[i].found / (double)NTRUE) < 1e-12);
        assert_true(fabs(T->zp - want[i].zp) < 1e-3);         /* the catalogs' 4 decimals */
        assert_true(T->sigma_all.ok && T->sigma_all.v < 1e-3); /* after the zero point */
        assert_true(T->posrms.ok && fabs(T->dx.v + T->dy.v - 0.1) < 1e-3);
    }
    char cmd[128];
    snprintf(cmd, sizeof cmd, "rm -rf '%s'", work);
    assert_int_equal(system(cmd), 0);
    free(frame);
    free(cat);
}

int main(void)
{
    const struct CMUnitTest tests[] = {
        cmocka_unit_test(test_each_catalog_by_its_reader),
    };
    return cmocka_run_group_tests(tests, NULL, NULL);
}
