/* test_fuzz_replay.c — every input the fuzzers once failed on
 * (tests/fuzz/regressions/TARGET/) and every seed (tests/fuzz/corpus/TARGET/)
 * through the fuzz bodies of tests/fuzz/fuzz_bodies.h: none may crash,
 * leak (under `make sanitize`) or break a contract (the bodies abort). */
#include <setjmp.h>
#include <stdarg.h>
#include <stddef.h>
#include <cmocka.h>
#include <dirent.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "tests/fuzz/fuzz_bodies.h"

typedef int (*body_fn)(const uint8_t *, size_t);

/* Under `make sanitize`: a corrupt FITS header can make cfitsio ask for
 * petabytes; in a normal build calloc returns NULL and cfitsio reports
 * MEMORY_ALLOCATION, which matphot passes on.  Let ASan behave the same
 * (the fuzz runs set it too).  Ignored without ASan. */
const char *__asan_default_options(void);
const char *__asan_default_options(void)
{
    return "allocator_may_return_null=1";
}

/* Replay every file of DIR through fn; the number replayed. */
static int replay_dir(const char *dir, body_fn fn)
{
    DIR *d = opendir(dir);
    if (!d)
        return 0;
    int n = 0;
    struct dirent *e;
    while ((e = readdir(d))) {
        if (e->d_name[0] == '.')
            continue;
        char path[1024];
        snprintf(path, sizeof path, "%s/%s", dir, e->d_name);
        FILE *fp = fopen(path, "rb");
        assert_non_null(fp);
        assert_int_equal(fseek(fp, 0, SEEK_END), 0);
        long len = ftell(fp);
        assert_true(len >= 0);
        rewind(fp);
        uint8_t *buf = malloc((size_t)len + 1);
        assert_non_null(buf);
        assert_int_equal(fread(buf, 1, (size_t)len, fp), (size_t)len);
        fclose(fp);
        assert_int_equal(fn(buf, (size_t)len), 0);
        free(buf);
        n++;
    }
    closedir(d);
    return n;
}

/* Where the tree is: tests run from its top (make), as __FILE__ says. */
static void replay(const char *target, body_fn fn, int min_regressions)
{
    char dir[512];
    snprintf(dir, sizeof dir, "tests/fuzz/regressions/%s", target);
    int nr = replay_dir(dir, fn);
    snprintf(dir, sizeof dir, "tests/fuzz/corpus/%s", target);
    int nc = replay_dir(dir, fn);
    /* The inputs are committed: finding none means the test ran nowhere. */
    assert_true(nr >= min_regressions);
    assert_true(nc > 0);
}

static void test_replay_params(void **state) { (void)state; replay("params", fuzz_params_body, 1); }
static void test_replay_table(void **state) { (void)state; replay("table", fuzz_table_body, 1); }
static void test_replay_psf(void **state) { (void)state; replay("psf", fuzz_psf_body, 1); }
static void test_replay_frame(void **state) { (void)state; replay("frame", fuzz_frame_body, 1); }
static void test_replay_psf_field(void **state)
{
    (void)state;
    replay("psf_field", fuzz_psf_field_body, 1);
}

int main(void)
{
    const struct CMUnitTest tests[] = {
        cmocka_unit_test(test_replay_params),
        cmocka_unit_test(test_replay_table),
        cmocka_unit_test(test_replay_psf),
        cmocka_unit_test(test_replay_psf_field),
        cmocka_unit_test(test_replay_frame),
    };
    return cmocka_run_group_tests(tests, NULL, NULL);
}
