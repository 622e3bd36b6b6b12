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

/* Blocks of 1 MiB and more mapped on their own, so that freeing one gives
 * its pages back: glibc's default threshold rises to the largest block
 * freed (up to 32 MiB), after which the tables, star arrays and maps of
 * one stage stay in the heap, holding their pages after they are freed
 * (issue 14: peak RSS at 2048^2, 15 600 stars, 89.4 -> 81.4 MiB, the
 * heap's own peak being 70.6 MB; CPU unchanged within 1 %).  A fixed
 * threshold also fixes the trim threshold, as mallopt(3) says, at 128 KiB:
 * the heap then gave back and faulted in again 320 MB of pages on 47 Tuc
 * 512^2 (82 000 of its 148 000 page faults; at 16 threads 5 s of system
 * time, the faults serialised on the process's memory map).  Up to 4 MiB
 * of free heap is kept instead: 66 000 faults, system time 0.7 -> 0.2 s,
 * peak RSS +0.8 MB (bench/SCALING.md, session of 2026-11-30 20:55). */
static void malloc_policy(void)
{
#ifdef __GLIBC__
    (void)mallopt(M_MMAP_THRESHOLD, 1 << 20);
    (void)mallopt(M_TRIM_THRESHOLD, 4 << 20);
#endif
}

static int is_help(const char *s)
{
    return !strcmp(s, "-h") || !strcmp(s, "--help");
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
    for (size_t i = 0; i < NTASKS; i++) {
        if (strcmp(argv[1], tasks[i].name))
            continue;
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
    fprintf(stderr, "matphot: unknown task '%s' (matphot --help lists the tasks)\n", argv[1]);
    return 2;
}
