/*
 * task_params.c — the compiled-in defaults of every task, their psets, and
 * the `matphot params` task that prints them.
 */
#include <stdlib.h>
#include <string.h>

#include "params/defaults.h"
#include "params/internal.h"

static const char *default_text(const char *task)
{
    for (size_t i = 0; mp_par_defaults[i].task; i++)
        if (!strcmp(mp_par_defaults[i].task, task))
            return mp_par_defaults[i].text;
    return NULL;
}

const char *const *mp_params_tasks(void)
{
    return mp_par_tasks;
}

static int parse_default(const char *task, mp_parset *ps, char *err)
{
    char origin[64];
    const char *text = default_text(task);
    if (!text) {
        mpp_errf(err, "%s: no such task (matphot params lists the tasks)", task);
        return 1;
    }
    snprintf(origin, sizeof origin, "%.50s.par", task);
    return mp_params_parse_text(text, origin, ps, err);
}

int mp_params_defaults(const char *task, mp_parset *ps, char *err)
{
    if (parse_default(task, ps, err))
        return 1;
    /* Each pset line (e.g. datapars) brings its set's parameters in right
     * after it, one level deep, so name=value reaches them. */
    for (size_t i = 0; i < ps->n; i++) {
        mp_parset sub;
        if (ps->p[i].type != MP_PAR_PSET)
            continue;
        if (parse_default(ps->p[i].name, &sub, err)) {
            mpp_err_prefix(err, "%s.par: pset %s: ", task, ps->p[i].name);
            goto fail;
        }
        size_t at = i + 1;
        for (size_t j = 0; j < sub.n; j++) {
            if (sub.p[j].type == MP_PAR_PSET)
                continue;
            if (mpp_find(ps, sub.p[j].name)) {
                mpp_errf(err, "%s.par: %s: defined in %s.par too", task, sub.p[j].name,
                         ps->p[i].name);
                mp_params_free(&sub);
                goto fail;
            }
            if (mpp_insert(ps, at++, &sub.p[j])) {
                mpp_errf(err, "%s: out of memory", task);
                mp_params_free(&sub);
                goto fail;
            }
        }
        mp_params_free(&sub);
        i = at - 1;
    }
    return 0;
fail:
    mp_params_free(ps);
    return 1;
}

int mp_task_params(int argc, char **argv)
{
    mp_parset ps;
    char err[MP_ERRLEN];
    if (argc < 2) {
        const char *const *t = mp_params_tasks();
        printf("tasks with parameters (matphot params TASK prints them):\n");
        for (size_t i = 0; t[i]; i++)
            printf("  %s\n", t[i]);
        return 0;
    }
    if (!strcmp(argv[1], "-h") || !strcmp(argv[1], "--help")) {
        printf("usage: matphot params [TASK [name=value ...] [@file.par]]\n"
               "Print TASK's parameters as a .par file (defaults, then the given\n"
               "values); without TASK, list the tasks.\n");
        return 0;
    }
    if (mp_params_defaults(argv[1], &ps, err)) {
        fprintf(stderr, "matphot params: %s\n", err);
        return 1;
    }
    if (mpp_apply(&ps, argc - 2, argv + 2, 0, err)) {
        fprintf(stderr, "matphot params: %s\n", err);
        mp_params_free(&ps);
        return 1;
    }
    printf("# %s parameters: name,type,mode,value,min,max,\"prompt\"\n"
           "# edit, then: matphot %s ... @this.par name=value\n", argv[1], argv[1]);
    mp_params_write(&ps, stdout);
    mp_params_free(&ps);
    return fflush(stdout) || ferror(stdout) ? 1 : 0;
}
