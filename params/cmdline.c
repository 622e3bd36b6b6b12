/*
 * cmdline.c — applying a task's command line to its parameters: bare words
 * fill the query parameters in file order, name=value and name+/name- set
 * any parameter, @file.par loads an edited parameter file (IRAF's rules,
 * anchors.md §1.2).  Also the start-up helper every task calls.
 */
#include <stdlib.h>
#include <string.h>

#include "params/internal.h"

int mp_params_load_file(mp_parset *ps, const char *path, char *err)
{
    char *text;
    int *lines;
    mp_parset f;
    int rc = 0;
    if (mpp_read_file(path, &text, err))
        return 1;
    rc = mpp_parse(text, path, &f, &lines, err);
    free(text);
    if (rc)
        return 1;
    /* Only the values count; ps's own types and ranges check them.  A file
     * gives new defaults, not command-line words: an empty query value in it
     * (what `matphot params TASK` writes) leaves the parameter to the
     * command line, and nothing it sets counts as named on the line. */
    for (size_t i = 0; i < f.n && !rc; i++) {
        const mp_par *q = &f.p[i];
        const mp_par *p = mpp_find(ps, q->name);
        /* IRAF's files end with the task's mode (`mode,s,h,"ql"`), the
         * CL's, which no task of ours reads but sim's own mode */
        if (q->type == MP_PAR_PSET || (p && p->type == MP_PAR_PSET) ||
            (!p && !strcmp(q->name, "mode")))
            continue;
        if (p && mpp_is_query(p) && mpp_undefined(q->value))
            continue;
        if (mp_params_set(ps, q->name, q->value, err)) {
            mpp_err_prefix(err, "%s:%d: ", path, lines[i]);
            rc = 1;
        }
    }
    for (size_t i = 0; i < ps->n; i++)
        ps->p[i].set = 0;
    free(lines);
    mp_params_free(&f);
    return rc;
}

/* Length of the parameter name at the start of w (letters, digits, _), or 0. */
static size_t name_len(const char *w)
{
    size_t k = 0;
    if (!((w[0] >= 'A' && w[0] <= 'Z') || (w[0] >= 'a' && w[0] <= 'z') || w[0] == '_'))
        return 0;
    while ((w[k] >= 'A' && w[k] <= 'Z') || (w[k] >= 'a' && w[k] <= 'z')
           || (w[k] >= '0' && w[k] <= '9') || w[k] == '_')
        k++;
    return k;
}

/* The parameter w[0..k) names on the command line into name (room for
 * cap bytes): the one so called, else the one parameter whose name it
 * begins (IRAF's minimum match: `imhead l+` is longheader=yes), of the
 * booleans alone when switch_ (a word "f-" that switches none is a bare
 * word, a file name); 1 with err when it begins two or more (naming
 * them), 0 otherwise (an unknown name is left to the caller). */
static int resolve_name(const mp_parset *ps, const char *w, size_t k, int switch_, char *name,
                        size_t cap, char *err)
{
    snprintf(name, cap, "%.*s", (int)k, w);
    if (mpp_find(ps, name))
        return 0;
    const mp_par *hit = NULL;
    char names[MP_ERRLEN] = "";
    size_t len = 0, nhit = 0;
    for (size_t j = 0; j < ps->n; j++)
        if (!strncmp(ps->p[j].name, name, k) && (!switch_ || ps->p[j].type == MP_PAR_BOOL)) {
            hit = &ps->p[j];
            if (len < sizeof names)
                len += (size_t)snprintf(names + len, sizeof names - len, "%s%s",
                                        nhit ? ", " : "", hit->name);
            nhit++;
        }
    if (nhit > 1) {
        mpp_errf(err, "%s: an abbreviation of %zu parameters of task %s (%s): give more of the "
                 "name", name, nhit, ps->task, names);
        return 1;
    }
    if (hit)
        snprintf(name, cap, "%s", hit->name);
    return 0;
}

static int is_parfile(const char *w)
{
    size_t n = strlen(w);
    return w[0] == '@' && n > 5 && !strcmp(w + n - 4, ".par");
}

int mpp_apply(mp_parset *ps, int argc, char **argv, int check_required, char *err)
{
    size_t next = 0;        /* the next query parameter a bare word may fill */
    /* Parameter files first, wherever they stand: they replace the defaults,
     * and every other word on the line then overrides them. */
    for (int i = 0; i < argc; i++)
        if (is_parfile(argv[i]) && mp_params_load_file(ps, argv[i] + 1, err))
            return 1;
    for (int i = 0; i < argc; i++) {
        const char *w = argv[i];
        size_t k = name_len(w);
        if (is_parfile(w))
            continue;
        char name[128];
        if (k > 0 && w[k] == '=') {
            if (k >= sizeof name) {
                mpp_errf(err, "%.40s...: unknown parameter of task %s", w, ps->task);
                return 1;
            }
            if (resolve_name(ps, w, k, 0, name, sizeof name, err) ||
                mp_params_set(ps, name, w + k + 1, err))
                return 1;
            continue;
        }
        if (k > 0 && k < sizeof name && (w[k] == '+' || w[k] == '-') && w[k + 1] == '\0') {
            const mp_par *p;
            if (resolve_name(ps, w, k, 1, name, sizeof name, err))
                return 1;
            if ((p = mpp_find(ps, name)) && p->type == MP_PAR_BOOL) {
                if (mp_params_set(ps, name, w[k] == '+' ? "yes" : "no", err))
                    return 1;
                continue;
            }
        }
        /* A bare word: the next query parameter not named on the line. */
        while (next < ps->n && (!mpp_is_query(&ps->p[next]) || ps->p[next].set))
            next++;
        if (next == ps->n) {
            char names[MP_ERRLEN] = "";
            size_t len = 0;
            for (size_t j = 0; j < ps->n && len < sizeof names; j++)
                if (mpp_is_query(&ps->p[j]))
                    len += (size_t)snprintf(names + len, sizeof names - len, " %s",
                                            ps->p[j].name);
            mpp_errf(err, "'%s': unexpected argument (task %s takes %s%s)", w, ps->task,
                     names[0] ? "only" : "no positional arguments", names);
            return 1;
        }
        if (mp_params_set(ps, ps->p[next].name, w, err))
            return 1;
        next++;
    }
    if (check_required)
        for (size_t j = 0; j < ps->n; j++)
            if (mpp_required(&ps->p[j])) {
                mpp_errf(err, "%s: required (query) parameter not given", ps->p[j].name);
                return 1;
            }
    return 0;
}

int mp_params_cmdline(mp_parset *ps, int argc, char **argv, char *err)
{
    return mpp_apply(ps, argc, argv, 1, err);
}

/* "usage: matphot fit image coords [name=value ...] [@file.par]" */
static void print_usage_line(const mp_parset *ps, FILE *fp)
{
    fprintf(fp, "usage: matphot %s", ps->task);
    for (size_t j = 0; j < ps->n; j++)
        if (mpp_is_query(&ps->p[j]))
            fprintf(fp, mpp_required(&ps->p[j]) ? " %s" : " [%s]", ps->p[j].name);
    fprintf(fp, " [name=value ...] [@file.par]\n");
}

int mp_task_begin(const char *task, int argc, char **argv, mp_parset *ps)
{
    char err[MP_ERRLEN];
    int words = argc > 1 ? argc - 1 : 0;
    if (mp_params_defaults(task, ps, err)) {
        fprintf(stderr, "matphot %s: %s\n", task, err);
        return 1;
    }
    if (words == 0) {
        for (size_t j = 0; j < ps->n; j++)
            if (mpp_required(&ps->p[j])) {
                print_usage_line(ps, stderr);
                mp_params_free(ps);
                return 2;
            }
    }
    if (mp_params_cmdline(ps, words, argv + 1, err)) {
        fprintf(stderr, "matphot %s: %s\n", task, err);
        mp_params_free(ps);
        return 1;
    }
    return 0;
}

int mp_task_usage(const char *task, FILE *fp)
{
    mp_parset ps;
    char err[MP_ERRLEN];
    int w = 4;
    if (mp_params_defaults(task, &ps, err))
        return 1;
    print_usage_line(&ps, fp);
    for (size_t j = 0; j < ps.n; j++)
        if ((int)strlen(ps.p[j].name) > w)
            w = (int)strlen(ps.p[j].name);
    fprintf(fp, "parameters (`matphot params %s > my.par` writes them as a .par file):\n", task);
    for (size_t j = 0; j < ps.n; j++) {
        const mp_par *p = &ps.p[j];
        if (p->type == MP_PAR_PSET) {
            fprintf(fp, "  %-*s  (parameter set) %s\n", w, p->name, p->prompt);
            continue;
        }
        fprintf(fp, "  %-*s  %-10s %s\n", w, p->name,
                mpp_required(p) ? "(required)" : p->value, p->prompt);
    }
    mp_params_free(&ps);
    return 0;
}
