/* test_stiff_signal.c — an interrupted run leaves no half-written file
 * (io/cleanup.c): a child process installs the handler, opens outputs
 * through mp_out_open (temporary names registered), writes, and is killed
 * by SIGINT, SIGTERM or SIGHUP; the parent checks that the child died of
 * that signal and that neither the temporaries nor the final files exist.
 * A committed or aborted output leaves the registry empty. */
#include <setjmp.h>
#include <stdarg.h>
#include <stddef.h>
#include <cmocka.h>
#include <signal.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/stat.h>
#include <sys/wait.h>
#include <unistd.h>

#include "io/io.h"

static int exists(const char *p)
{
    struct stat st;
    return stat(p, &st) == 0;
}

static void interrupted_by(int sig)
{
    char dir[] = "/tmp/stiff_sig.XXXXXX";
    assert_non_null(mkdtemp(dir));
    char a[256], b[256];
    snprintf(a, sizeof a, "%s/a.coo", dir);
    snprintf(b, sizeof b, "%s/b.fit", dir);
    char *ta = mp_tmp_name(a), *tb = mp_tmp_name(b);
    pid_t pid = fork();
    assert_true(pid >= 0);
    if (pid == 0) {
        char err[MP_ERRLEN];
        signal(sig, SIG_DFL);
        if (mp_cleanup_install())
            _exit(3);
        mp_outfile oa, ob;
        if (mp_out_open(&oa, a, err) || mp_out_open(&ob, b, err))
            _exit(4);
        fputs("half a table\n", oa.fp);
        fflush(oa.fp);
        fputs("half another\n", ob.fp);
        fflush(ob.fp);
        /* The temporaries exist now (names as the parent computes them). */
        char *ca = mp_tmp_name(a);
        if (!ca || !exists(ca) || mp_tmp_live() != 2)
            _exit(5);
        free(ca);
        kill(getpid(), sig);
        _exit(6);   /* not reached: the handler re-raises the signal */
    }
    int status = 0;
    assert_int_equal(waitpid(pid, &status, 0), pid);
    assert_true(WIFSIGNALED(status));
    assert_int_equal(WTERMSIG(status), sig);
    assert_false(exists(ta));
    assert_false(exists(tb));
    assert_false(exists(a));
    assert_false(exists(b));
    free(ta);
    free(tb);
    assert_int_equal(rmdir(dir), 0);   /* empty: nothing else left */
}

static void test_sigint(void **state) { (void)state; interrupted_by(SIGINT); }
static void test_sigterm(void **state) { (void)state; interrupted_by(SIGTERM); }
static void test_sighup(void **state) { (void)state; interrupted_by(SIGHUP); }

static void test_registry_empties(void **state)
{
    (void)state;
    char dir[] = "/tmp/stiff_reg.XXXXXX", p[256], err[MP_ERRLEN];
    assert_non_null(mkdtemp(dir));
    snprintf(p, sizeof p, "%s/x.coo", dir);
    int before = mp_tmp_live();
    mp_outfile o;
    assert_int_equal(mp_out_open(&o, p, err), 0);
    assert_int_equal(mp_tmp_live(), before + 1);
    assert_int_equal(mp_out_commit(&o, err), 0);
    assert_int_equal(mp_tmp_live(), before);
    assert_int_equal(mp_out_open(&o, p, err), 0);
    mp_out_abort(&o);
    assert_int_equal(mp_tmp_live(), before);
    double px = 1.0;
    assert_int_equal(mp_image_write(p, &px, 1, 1, -32, NULL, 0, err), 0);
    assert_int_equal(mp_tmp_live(), before);
    assert_int_equal(unlink(p), 0);
    assert_int_equal(rmdir(dir), 0);
}

int main(void)
{
    const struct CMUnitTest tests[] = {
        cmocka_unit_test(test_sigint),
        cmocka_unit_test(test_sigterm),
        cmocka_unit_test(test_sighup),
        cmocka_unit_test(test_registry_empties),
    };
    return cmocka_run_group_tests(tests, NULL, NULL);
}
