/*
 * cleanup.c — the registry of live temporary files and the signal handler
 * that removes them (io.h: mp_tmp_register, mp_cleanup_install).
 *
 * This is matphot's only global mutable state, and deliberately so: a
 * signal handler can reach nothing else.  It is a fixed array of
 * MP_TMP_SLOTS lock-free atomic pointers, each NULL or a malloc'd copy of
 * a temporary's path.  Writers (mp_out_open, mp_image_write,
 * mp_table_write_fits) register a temporary before creating it and
 * unregister it after renaming or removing it; the handler walks the array
 * and unlink()s every name it finds.  Lock-free atomic loads and unlink()
 * are async-signal-safe (C17 7.14.1.1, POSIX 2.4.3); the handler neither
 * allocates nor frees.  Registration is thread-safe (compare-and-swap into
 * a free slot).  A name registered but never created only costs an
 * unlink() that fails with ENOENT.
 *
 * The handler then restores the default action and re-raises the signal,
 * so the shell sees the process die of it (exit status 128 + signal).
 *
 * Limits, stated: when all slots are taken a temporary is not registered
 * (mp_tmp_register returns nonzero; the write goes on, and only an
 * interrupt could then leave that one file behind); and a handler running
 * on one thread while another thread is between unregistering and freeing
 * a name may unlink that (already renamed, hence absent) name.
 */
#include "io/io.h"

#include <signal.h>
#include <stdatomic.h>
#include <stdlib.h>
#include <string.h>
#include <unistd.h>

#define MP_TMP_SLOTS 256

_Static_assert(ATOMIC_POINTER_LOCK_FREE == 2,
               "the signal handler needs lock-free atomic pointers");

static _Atomic(char *) live[MP_TMP_SLOTS];

int mp_tmp_register(const char *path)
{
    if (!path)
        return 1;
    char *copy = strdup(path);
    if (!copy)
        return 1;
    for (int i = 0; i < MP_TMP_SLOTS; i++) {
        char *expect = NULL;
        if (atomic_load(&live[i]) == NULL &&
            atomic_compare_exchange_strong(&live[i], &expect, copy))
            return 0;
    }
    free(copy);
    return 1;
}

void mp_tmp_unregister(const char *path)
{
    if (!path)
        return;
    for (int i = 0; i < MP_TMP_SLOTS; i++) {
        char *p = atomic_load(&live[i]);
        if (p && strcmp(p, path) == 0) {
            char *expect = p;
            if (atomic_compare_exchange_strong(&live[i], &expect, NULL)) {
                free(p);
                return;
            }
        }
    }
}

int mp_tmp_live(void)
{
    int n = 0;
    for (int i = 0; i < MP_TMP_SLOTS; i++)
        n += atomic_load(&live[i]) != NULL;
    return n;
}

void mp_tmp_unlink_all(void)
{
    /* Async-signal-safe: atomic loads and unlink() only. */
    for (int i = 0; i < MP_TMP_SLOTS; i++) {
        char *p = atomic_load(&live[i]);
        if (p)
            unlink(p);
    }
}

static void on_signal(int sig)
{
    mp_tmp_unlink_all();
    /* SA_RESETHAND has put the default action back and SA_NODEFER leaves
     * the signal unblocked: re-raising it ends the process of it now. */
    raise(sig);
}

int mp_cleanup_install(void)
{
    static const int sigs[] = {SIGINT, SIGTERM, SIGHUP, SIGQUIT};
    int rc = 0;
    for (size_t i = 0; i < sizeof sigs / sizeof sigs[0]; i++) {
        struct sigaction old, sa;
        if (sigaction(sigs[i], NULL, &old) != 0) {
            rc = 1;
            continue;
        }
        if (old.sa_handler == SIG_IGN)   /* nohup: keep ignoring it */
            continue;
        memset(&sa, 0, sizeof sa);
        sa.sa_handler = on_signal;
        sigemptyset(&sa.sa_mask);
        sa.sa_flags = SA_RESETHAND | SA_NODEFER;
        if (sigaction(sigs[i], &sa, NULL) != 0)
            rc = 1;
    }
    return rc;
}
