/*
 * main.c — the matphot executable: `matphot TASK args...` runs one task
 * (design.md §1).  One binary keeps tool names off the user's PATH and gives
 * every task the same parameter handling (params/params.h).
 *
 * A task is int f(int argc, char **argv) with argv[0] the task name and
 * argv[1..] its words; it returns the exit status (0, 1 error, 2 usage) and
 * normally starts with mp_task_begin.  Adding a task is one line in tasks[].
 */
#include <stdio.h>
#include <string.h>
#ifdef __GLIBC__
#include <malloc.h>
#endif

#include "find/find.h"
#include "fit/fit.h"
#include "group/group.h"
#include "io/io.h"
#include "params/params.h"
#include "pipeline/pipeline.h"
#include "psf/build.h"
#include "sim/sim.h"

#ifndef MATPHOT_VERSION
#define MATPHOT_VERSION "0.1.0"
#endif

typedef int (*task_fn)(int argc, char **argv);

static const struct {
    const char *name;
    task_fn run;
    const char *what;
} tasks[] = {
    { "find", mp_task_find, "sky background map and DAOFIND-style star detection" },
    { "group", mp_task_group, "group stars whose PSFs reach each other's fitting regions (DAOPHOT GROUP)" },
    { "psf", mp_task_psf, "build the PSF from the frame's stars (effective PSF, spatially variable)" },
    { "fit", mp_task_fit, "fit stars and sky with a discrete or analytic PSF (MATPHOT)" },
    { "catalog", mp_task_catalog, "final catalogue: magnitudes, sky positions, FITS/LDAC, DS9 regions" },
    { "merge", mp_task_merge, "many frames' catalogues matched on the sky into one survey catalogue" },
    { "pipeline", mp_task_pipeline, "find, group and fit in rounds on the residual, then the catalogue" },
    { "fakes", mp_task_fakes, "artificial stars: completeness, bias and errors of the pipeline" },
    { "sim", mp_task_sim, "simulate a frame of stars with exact pixel-integrated PRFs" },
    { "params", mp_task_params, "print a task's parameters as a .par file (no TASK: list them)" },
};

#define NTASKS (sizeof tasks / sizeof tasks[0])

static void usage(FILE *fp)
{
    fprintf(fp,
            "usage: matphot TASK [words] [name=value ...] [@file.par]\n"
            "       matphot TASK --help | matphot --help | matphot --version\n"
            "Crowded-field stellar photometry with the MATPHOT algorithm.\n"
            "\n"
            "tasks:\n");
    for (size_t i = 0; i < NTASKS; i++)
        fprintf(fp, "  %-8s %s\n", tasks[i].name, tasks[i].what);
    fprintf(fp,
            "\n"
            "Bare words fill a task's query parameters in order; name=value sets any\n"
            "parameter; `matphot params fit > my.par` writes fit's defaults, and\n"
            "`matphot fit img.fits img.coo @my.par fitrad=4` uses them.\n");
}

/* Blocks up to 32 MiB (glibc's largest fixed threshold) come from the
 * heap, so that a block freed is reused, not given back and faulted in
 * again; up to 4 MiB of free heap is kept, as before.  The PSF build's
 * per-star arrays (G, H, the mask: 23 MB each on frame S's ×4
 * half-tables, one set a half and a pass) and the phase grids were mapped
 * afresh each time above the 1 MiB threshold of 2026-11-25 (which took
 * the 2048² frame's peak RSS 89.4 -> 81.4 MiB): on this project's
 * virtual machines a page fault costs ~5 µs of system time.  One thread,
 * five interleaved pairs (bench/PROFILE.md, session of 2026-12-07
 * 00:50): frame S built 52 200 -> 29 500 faults, CPU 2.88 -> 2.55 s; 47
 * Tuc built 27 600 -> 12 500, 3.96 -> 3.75 s.  Peak RSS: S +0.9 %, 47 Tuc
 * +0.7 %, the simulated 2048², 4096² and 8192² frames whole +6, +2.6 and
 * +2.1 % (the last 2.96 -> 3.02 times its floats, where the goal is 3;
 * 16 MiB of free heap kept as well: 3.07).  A fixed threshold also fixes
 * the trim threshold (mallopt(3)), so both are set.  Every output the
 * same bytes. */
static void malloc_policy(void)
{
#ifdef __GLIBC__
    (void)mallopt(M_MMAP_THRESHOLD, 32 << 20);
    (void)mallopt(M_TRIM_THRESHOLD, 4 << 20);
#endif
}

static int is_help(const char *s)
{
    return !strcmp(s, "-h") || !strcmp(s, "--help");
}

/* The task word names: the one so called, else the one whose name it
 * begins (IRAF's minimum match: `matphot pipe`); NTASKS, said on stderr,
 * when it names none or begins two or more. */
static size_t task_of(const char *word)
{
    size_t hit = NTASKS, nhit = 0, k = strlen(word);
    for (size_t i = 0; i < NTASKS; i++) {
        if (!strcmp(word, tasks[i].name))
            return i;
        if (k > 0 && !strncmp(word, tasks[i].name, k)) {
            hit = i;
            nhit++;
        }
    }
    if (nhit == 1)
        return hit;
    if (nhit == 0) {
        fprintf(stderr, "matphot: unknown task '%s' (matphot --help lists the tasks)\n", word);
        return NTASKS;
    }
    fprintf(stderr, "matphot: '%s' begins the names of %zu tasks (", word, nhit);
    for (size_t i = 0, n = 0; i < NTASKS; i++)
        if (!strncmp(word, tasks[i].name, k))
            fprintf(stderr, "%s%s", n++ ? ", " : "", tasks[i].name);
    fprintf(stderr, "): give more of the name\n");
    return NTASKS;
}

int main(int argc, char **argv)
{
    /* An interrupted run (SIGINT, SIGTERM, SIGHUP, SIGQUIT) removes the
     * temporaries of the outputs it was writing (io/cleanup.c). */
    (void)mp_cleanup_install();
    mp_blas_single_thread();
    malloc_policy();
    if (argc < 2) {
        usage(stderr);
        return 2;
    }
    if (is_help(argv[1])) {
        usage(stdout);
        return 0;
    }
    if (!strcmp(argv[1], "--version") || !strcmp(argv[1], "-V")) {
        printf("matphot %s\n", MATPHOT_VERSION);
        return 0;
    }
    size_t i = task_of(argv[1]);
    if (i == NTASKS)
        return 2;
    argv[1] = (char *)tasks[i].name;     /* the task's whole name from here on */
    /* `matphot TASK --help` is answered here from the task's .par, so
     * every task has it without code of its own. */
    if (argc == 3 && is_help(argv[2]) && strcmp(tasks[i].name, "params")) {
        printf("matphot %s: %s\n", tasks[i].name, tasks[i].what);
        if (mp_task_usage(tasks[i].name, stdout))
            printf("usage: matphot %s ...\n", tasks[i].name);
        return 0;
    }
    return tasks[i].run(argc - 1, argv + 1);
}
