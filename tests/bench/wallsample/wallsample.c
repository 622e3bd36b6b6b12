/*
 * wallsample.c — a wall-clock sampler of a program's main thread, loaded
 * with LD_PRELOAD (bench/SCALING.md; not part of matphot).  Where perf is
 * missing (the lent many-core machines have none), it shows where a
 * many-thread run's wall time goes: every millisecond the main thread
 * (OpenMP's master, which takes part in every parallel region) records
 * its stack; a frame inside an outlined region ("fn._omp_fn.N") means
 * work in that region, a leaf in libgomp a wait at its barrier (a thread
 * done early waits for the slowest), neither the serial code.
 *
 *   cc -O2 -fPIC -shared -o wallsample.so wallsample.c -lrt
 *   WALLSAMPLE_OUT=s.txt LD_PRELOAD=./wallsample.so matphot pipeline ...
 *   sh tests/bench/wallsample/report.sh s.txt build/matphot
 *
 * Each sample is one line "S frame frame ...", leaf first, the sampler's
 * own frames and the signal trampoline dropped; a frame is "name:offset"
 * (offset from the module's load address, in hex; a return address less
 * 1, inside its call), name the module's file name.  Written at exit.
 */
#define _GNU_SOURCE
#include <execinfo.h>
#include <signal.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <time.h>
#include <unistd.h>
#include <sys/syscall.h>

enum { DEPTH = 48, MAXS = 200000 };

static void **stacks;           /* MAXS stacks of DEPTH frames */
static int *depth;
static volatile sig_atomic_t nsamp;
static timer_t timer;

static void on_tick(int sig)
{
    (void)sig;
    int i = nsamp;
    if (i >= MAXS)
        return;
    depth[i] = backtrace(stacks + (size_t)i * DEPTH, DEPTH);
    nsamp = i + 1;
}

/* A 1 ms timer that signals the main thread only. */
__attribute__((constructor)) static void start(void)
{
    if (!getenv("WALLSAMPLE_OUT"))
        return;
    stacks = malloc(sizeof *stacks * DEPTH * MAXS);
    depth = malloc(sizeof *depth * MAXS);
    if (!stacks || !depth)
        return;
    void *warm[4];
    backtrace(warm, 4);         /* loads the unwinder outside the handler */
    struct sigaction sa;
    memset(&sa, 0, sizeof sa);
    sa.sa_handler = on_tick;
    sa.sa_flags = SA_RESTART;
    sigaction(SIGRTMIN + 3, &sa, NULL);
    struct sigevent sev;
    memset(&sev, 0, sizeof sev);
    sev.sigev_notify = SIGEV_THREAD_ID;
    sev.sigev_signo = SIGRTMIN + 3;
    sev._sigev_un._tid = (pid_t)syscall(SYS_gettid);
    struct itimerspec its = {{0, 1000000}, {0, 1000000}};
    if (timer_create(CLOCK_MONOTONIC, &sev, &timer) || timer_settime(timer, 0, &its, NULL))
        perror("wallsample");
}

/* The mapped modules, from /proc/self/maps: start, end, load address
 * (the start of its mapping at file offset 0) and file name. */
typedef struct {
    unsigned long lo, hi, base;
    char name[64];
} module;

static int read_modules(module *m, int cap)
{
    FILE *f = fopen("/proc/self/maps", "r");
    char line[1024], path[512];
    int n = 0;
    while (f && n < cap && fgets(line, sizeof line, f)) {
        unsigned long lo, hi, off;
        path[0] = 0;
        if (sscanf(line, "%lx-%lx %*s %lx %*s %*s %511s", &lo, &hi, &off, path) < 3 || !path[0])
            continue;
        const char *base = strrchr(path, '/') ? strrchr(path, '/') + 1 : path;
        unsigned long load = lo - off;  /* a first approximation, fixed below */
        for (int i = 0; i < n; i++)
            if (strcmp(m[i].name, base) == 0)
                load = m[i].base;
        m[n].lo = lo, m[n].hi = hi, m[n].base = off == 0 ? lo : load;
        snprintf(m[n].name, sizeof m[n].name, "%s", base);
        n++;
    }
    if (f)
        fclose(f);
    return n;
}

__attribute__((destructor)) static void stop(void)
{
    const char *path = getenv("WALLSAMPLE_OUT");
    if (!path || !stacks)
        return;
    timer_delete(timer);
    static module mods[512];
    int nm = read_modules(mods, 512), n = nsamp;
    FILE *f = fopen(path, "w");
    if (!f)
        return;
    for (int i = 0; i < n; i++) {
        void **s = stacks + (size_t)i * DEPTH;
        int k = 0, first = -1;
        for (; k < depth[i]; k++) {     /* skip ours, then the trampoline */
            unsigned long a = (unsigned long)s[k];
            int j = 0;
            while (j < nm && !(a >= mods[j].lo && a < mods[j].hi))
                j++;
            if (j == nm || !strstr(mods[j].name, "wallsample")) {
                first = k + 1;
                break;
            }
        }
        fputc('S', f);
        for (k = first; first >= 0 && k < depth[i]; k++) {
            unsigned long a = (unsigned long)s[k] - (k > first ? 1 : 0);
            int j = 0;
            while (j < nm && !(a >= mods[j].lo && a < mods[j].hi))
                j++;
            if (j < nm)
                fprintf(f, " %s:%lx", mods[j].name, a - mods[j].base);
            else
                fprintf(f, " ?:%lx", a);
        }
        fputc('\n', f);
    }
    fclose(f);
}
