/*
 * params.h — IRAF parameter files and the one command-line parser every
 * matphot task uses (design.md §3, anchors.md §1.2).
 *
 * A .par line is  name,type,mode,value,min,max,"prompt"  with type one of
 * b (bool yes/no), i (int), r (real), s (string), f (file name); a value, min
 * or max may be INDEF or empty.  A string/file min may hold an enumeration
 * "a|b|c" of allowed values.  Lines starting with # are comments.
 *
 * A task's defaults are the compiled-in copy of params/<task>.par.  On the
 * command line (mp_params_cmdline):
 *   - a bare word fills the next mode-"a" (query) parameter in file order,
 *     as IRAF does (e.g. `matphot fit frame.fits frame.coo`);
 *   - name=value sets a parameter;
 *   - @file.par loads an edited parameter file (values only; its names must
 *     be the task's);
 *   - an unknown name, a value of the wrong type or outside [min,max], or a
 *     missing query parameter is an error naming the parameter, its value
 *     and the allowed range.
 * A positional "@frames.lis" is not a .par file: it is kept as the value of
 * its parameter, and mp_params_list expands it.
 *
 * Also: a boolean may be switched as IRAF does (fitsky+ / fitsky-); a word
 * "@name" is a parameter file only when name ends in ".par".
 *
 * Ranges: min/max are inclusive (IRAF); as our extension, a min written ">0"
 * or a max written "<1" excludes the bound.  INDEF or empty is legal for
 * every parameter (undefined), except a string with an enumeration.
 *
 * Errors: functions return 0 on success, nonzero on failure with one line in
 * err (MP_ERRLEN bytes), e.g. "fitrad: -3 is outside [0, 1000]".
 */
#ifndef MATPHOT_PARAMS_H
#define MATPHOT_PARAMS_H

#include <stddef.h>
#include <stdio.h>

/* MP_PAR_PSET (type "pset", IRAF's parameter-set type) is not a value: its
 * value names a .par file of the set (empty: the defaults).  When a task's
 * .par has a line "datapars,pset,h,,,,"..."", mp_params_defaults inserts the
 * datapars parameters right after it, so name=value sets them on the task's
 * command line; datapars=my_datapars.par on the command line loads that file
 * into them. */
typedef enum { MP_PAR_BOOL, MP_PAR_INT, MP_PAR_REAL, MP_PAR_STRING, MP_PAR_FILE,
               MP_PAR_PSET } mp_par_type;

#ifndef MP_ERRLEN
#define MP_ERRLEN 512   /* as in io/io.h */
#endif

typedef struct {
    char *name;
    mp_par_type type;
    char *mode;      /* "a", "h", "q", "l", ... as written */
    char *value;     /* text as written; "INDEF" or "" when undefined */
    char *min, *max; /* text, "" when absent */
    char *prompt;
    int set;         /* 1 when given on the command line or in an @file */
} mp_par;

typedef struct mp_parset_s {
    char task[32];
    mp_par *p;
    size_t n;
} mp_parset;

/* mp_params_defaults: the compiled-in defaults of task (params/<task>.par).
 * Error when there is no such task. */
int mp_params_defaults(const char *task, mp_parset *ps, char *err);

/* mp_params_parse_text: parse .par text (used for defaults and files) into
 * ps (initialised here; ps->task is origin's basename without ".par");
 * origin names the file in errors ("my.par:7: ...").  Every value is checked
 * against its own line's type and range.  Psets are not merged. */
int mp_params_parse_text(const char *text, const char *origin, mp_parset *ps, char *err);

/* mp_params_load_file: apply the values of a .par file to ps (only the
 * values: each name must be one of ps's, and is checked against ps's type
 * and range; pset lines are skipped). */
int mp_params_load_file(mp_parset *ps, const char *path, char *err);

/* mp_params_cmdline: apply argv[0..argc-1] (the words after the task name)
 * to ps, then check every value and that every query parameter has a value
 * (given, or a non-empty default). */
int mp_params_cmdline(mp_parset *ps, int argc, char **argv, char *err);

/* mp_params_set: set one value (checked). */
int mp_params_set(mp_parset *ps, const char *name, const char *value, char *err);

/* mp_params_write: write ps as a .par file; mp_params_parse_text reads it
 * back to the same names, types, modes, values, ranges and prompts. */
void mp_params_write(const mp_parset *ps, FILE *fp);

/* mp_params_tasks: NULL-terminated list of tasks that have defaults. */
const char *const *mp_params_tasks(void);

/* Typed access.  Asking for a name the set lacks (or of another type) is a
 * programming error and returns nonzero (mp_par_string: NULL).  INDEF reals
 * come back as NaN (mp_par_real also reads an int parameter), INDEF ints as
 * MP_PAR_INDEF_INT, INDEF or empty strings as ""; an INDEF bool returns
 * nonzero. */
#define MP_PAR_INDEF_INT (-2147483647 - 1)
int mp_par_bool(const mp_parset *ps, const char *name, int *v);
int mp_par_int(const mp_parset *ps, const char *name, int *v);
int mp_par_real(const mp_parset *ps, const char *name, double *v);
const char *mp_par_string(const mp_parset *ps, const char *name);

/* mp_par_need_real / mp_par_need_int: a real (int) parameter that must be
 * a number: nonzero with err "NAME: INDEF is not allowed; give a number"
 * when it is INDEF (or not of that type). */
int mp_par_need_real(const mp_parset *ps, const char *name, double *v, char *err);
int mp_par_need_int(const mp_parset *ps, const char *name, int *v, char *err);

void mp_params_free(mp_parset *ps);

/* mp_params_list: expand an IRAF list argument: "@file" gives its
 * non-empty, non-comment lines; an empty or NULL argument gives no items;
 * anything else gives itself.  The caller
 * frees with mp_list_free. */
int mp_params_list(const char *arg, char ***items, size_t *n, char *err);
void mp_list_free(char **items, size_t n);

/* The "matphot params TASK [args]" task: print the defaults of TASK as a
 * .par file, with any further words (name=value, @file.par) applied first;
 * with no TASK, list the tasks.  argv[0] is "params". */
int mp_task_params(int argc, char **argv);

/* mp_task_begin: what every task calls first.  argc/argv are what the task
 * function got from the dispatcher: argv[0] is the task name, argv[1..] its
 * words.  Loads task's defaults into ps and applies the words.  Returns 0
 * (the caller then owns ps and frees it with mp_params_free), 1 after printing
 * "matphot TASK: <err>" to stderr, or 2 after printing a usage line when
 * there are no words at all and the task has required query parameters.
 * On nonzero, ps holds nothing to free. */
int mp_task_begin(const char *task, int argc, char **argv, mp_parset *ps);

/* mp_task_usage: print "usage: matphot TASK query... [name=value ...]
 * [@file.par]" and the task's parameters with their defaults and prompts
 * (what `matphot TASK --help` shows).  Nonzero when TASK has no defaults. */
int mp_task_usage(const char *task, FILE *fp);

#endif
