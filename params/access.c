/*
 * access.c — checking values against a parameter's type and range, setting
 * them, and typed access for the tasks.
 */
#include <errno.h>
#include <limits.h>
#include <math.h>
#include <stdarg.h>
#include <stdlib.h>
#include <string.h>
#include <strings.h>

#include "params/internal.h"

void mpp_errf(char *err, const char *fmt, ...)
{
    va_list ap;
    va_start(ap, fmt);
    vsnprintf(err, MP_ERRLEN, fmt, ap);
    va_end(ap);
}

void mpp_err_prefix(char *err, const char *fmt, ...)
{
    char msg[MP_ERRLEN];
    va_list ap;
    size_t k;
    memcpy(msg, err, MP_ERRLEN);
    msg[MP_ERRLEN - 1] = '\0';
    va_start(ap, fmt);
    vsnprintf(err, MP_ERRLEN, fmt, ap);
    va_end(ap);
    k = strlen(err);
    if (k < MP_ERRLEN - 1)
        snprintf(err + k, MP_ERRLEN - k, "%s", msg);
}

mp_par *mpp_find(const mp_parset *ps, const char *name)
{
    for (size_t i = 0; i < ps->n; i++)
        if (!strcmp(ps->p[i].name, name))
            return &ps->p[i];
    return NULL;
}

int mpp_is_query(const mp_par *p)
{
    return p->type != MP_PAR_PSET && !strchr(p->mode, 'h')
           && (strchr(p->mode, 'a') || strchr(p->mode, 'q'));
}

int mpp_undefined(const char *value)
{
    return value[0] == '\0' || !strcasecmp(value, "INDEF");
}

int mpp_required(const mp_par *p)
{
    return mpp_is_query(p) && mpp_undefined(p->value);
}

/* Booleans: IRAF's yes/no, and the spellings people type anyway. */
static int parse_bool(const char *s, int *v)
{
    static const char *const yes[] = { "yes", "y", "true", "1", NULL };
    static const char *const no[] = { "no", "n", "false", "0", NULL };
    for (int i = 0; yes[i]; i++)
        if (!strcasecmp(s, yes[i])) { *v = 1; return 0; }
    for (int i = 0; no[i]; i++)
        if (!strcasecmp(s, no[i])) { *v = 0; return 0; }
    return 1;
}

/* 0: an int in range, 1: not a number, 2: too large. */
static int parse_int(const char *s, long *v)
{
    char *end;
    errno = 0;
    *v = strtol(s, &end, 10);
    if (end == s || *end != '\0')
        return 1;
    /* INT_MIN is MP_PAR_INDEF_INT, so it is not a value. */
    if (errno == ERANGE || *v > INT_MAX || *v <= INT_MIN)
        return 2;
    return 0;
}

static int parse_real(const char *s, double *v)
{
    char *end;
    *v = strtod(s, &end);
    return end == s || *end != '\0' || !isfinite(*v);
}

/* A bound: "" or INDEF (open), a number, or with the excl character in front
 * (">0" in min, "<1" in max) an exclusive bound.  Returns 1 when malformed. */
static int parse_bound(const char *s, char excl, int *open, int *exclusive, double *v)
{
    *open = mpp_undefined(s);
    *exclusive = 0;
    if (*open)
        return 0;
    if (*s == excl) {
        *exclusive = 1;
        s++;
    }
    return parse_real(s, v);
}

/* The enumeration in a string's min field ("a|b|c", IRAF also writes
 * "|a|b|c|"), or NULL when there is none. */
static const char *enumeration(const mp_par *p)
{
    if ((p->type == MP_PAR_STRING || p->type == MP_PAR_FILE) && strchr(p->min, '|'))
        return p->min;
    return NULL;
}

static int in_enumeration(const char *list, const char *v)
{
    size_t n = strlen(v);
    for (const char *s = list; *s;) {
        const char *e = strchr(s, '|');
        size_t k = e ? (size_t)(e - s) : strlen(s);
        if (k == n && k > 0 && !strncmp(s, v, n))
            return 1;
        s += k + (e != NULL);
    }
    return 0;
}

int mpp_check_bounds(const mp_par *p, char *err)
{
    int open, excl;
    double v;
    if (p->type != MP_PAR_INT && p->type != MP_PAR_REAL)
        return 0;
    if (parse_bound(p->min, '>', &open, &excl, &v)) {
        mpp_errf(err, "%s: minimum '%s' is not a number", p->name, p->min);
        return 1;
    }
    if (parse_bound(p->max, '<', &open, &excl, &v)) {
        mpp_errf(err, "%s: maximum '%s' is not a number", p->name, p->max);
        return 1;
    }
    return 0;
}

/* "[0, 1000]", "(0, inf)", ... from the min/max fields (checked already). */
static void format_range(const mp_par *p, char *buf, size_t size)
{
    int lo_open, lo_ex, hi_open, hi_ex;
    double lo, hi;
    const char *ls, *hs;
    parse_bound(p->min, '>', &lo_open, &lo_ex, &lo);
    parse_bound(p->max, '<', &hi_open, &hi_ex, &hi);
    ls = lo_open ? "-inf" : p->min + lo_ex;
    hs = hi_open ? "inf" : p->max + hi_ex;
    snprintf(buf, size, "%c%s, %s%c", lo_open || lo_ex ? '(' : '[', ls, hs,
             hi_open || hi_ex ? ')' : ']');
}

int mpp_check(const mp_par *p, const char *value, char *err)
{
    const char *list = enumeration(p);
    int b;
    long l;
    double x = 0;

    if (strchr(value, '\n') || strchr(value, '\r')) {
        mpp_errf(err, "%s: the value holds a line break", p->name);
        return 1;
    }
    if (list) {
        if (in_enumeration(list, value))
            return 0;
        /* Show "a|b|c" even when the file wrote "|a|b|c|". */
        size_t k = strlen(list);
        while (*list == '|')
            list++, k--;
        while (k > 0 && list[k - 1] == '|')
            k--;
        mpp_errf(err, "%s: '%s' is not one of %.*s", p->name, value, (int)k, list);
        return 1;
    }
    if (mpp_undefined(value))
        return 0;
    switch (p->type) {
    case MP_PAR_BOOL:
        if (parse_bool(value, &b)) {
            mpp_errf(err, "%s: '%s' is not a boolean (yes or no)", p->name, value);
            return 1;
        }
        return 0;
    case MP_PAR_INT:
        switch (parse_int(value, &l)) {
        case 1:
            mpp_errf(err, "%s: '%s' is not an integer", p->name, value);
            return 1;
        case 2:
            mpp_errf(err, "%s: '%s' is too large for an integer", p->name, value);
            return 1;
        }
        x = (double)l;
        break;
    case MP_PAR_REAL:
        if (parse_real(value, &x)) {
            mpp_errf(err, "%s: '%s' is not a number", p->name, value);
            return 1;
        }
        break;
    default:
        return 0;
    }
    int lo_open, lo_ex, hi_open, hi_ex;
    double lo = 0, hi = 0;
    parse_bound(p->min, '>', &lo_open, &lo_ex, &lo);
    parse_bound(p->max, '<', &hi_open, &hi_ex, &hi);
    if ((!lo_open && (lo_ex ? x <= lo : x < lo)) || (!hi_open && (hi_ex ? x >= hi : x > hi))) {
        char range[256];
        format_range(p, range, sizeof range);
        mpp_errf(err, "%s: %s is outside %s", p->name, value, range);
        return 1;
    }
    return 0;
}

char *mpp_normalize(const mp_par *p, const char *value)
{
    int b;
    if (p->type != MP_PAR_STRING && p->type != MP_PAR_FILE && p->type != MP_PAR_PSET
        && !strcasecmp(value, "INDEF"))
        return strdup("INDEF");
    if (p->type == MP_PAR_BOOL && !parse_bool(value, &b))
        return strdup(b ? "yes" : "no");
    return strdup(value);
}

void mpp_free_par(mp_par *p)
{
    free(p->name);
    free(p->mode);
    free(p->value);
    free(p->min);
    free(p->max);
    free(p->prompt);
    memset(p, 0, sizeof *p);
}

int mpp_insert(mp_parset *ps, size_t at, const mp_par *src)
{
    mp_par q = *src;
    mp_par *np;
    q.name = strdup(src->name);
    q.mode = strdup(src->mode);
    q.value = strdup(src->value);
    q.min = strdup(src->min);
    q.max = strdup(src->max);
    q.prompt = strdup(src->prompt);
    if (!q.name || !q.mode || !q.value || !q.min || !q.max || !q.prompt
        || !(np = realloc(ps->p, (ps->n + 1) * sizeof *np))) {
        mpp_free_par(&q);
        return 1;
    }
    ps->p = np;
    memmove(&np[at + 1], &np[at], (ps->n - at) * sizeof *np);
    np[at] = q;
    ps->n++;
    return 0;
}

void mp_params_free(mp_parset *ps)
{
    if (!ps)
        return;
    for (size_t i = 0; i < ps->n; i++)
        mpp_free_par(&ps->p[i]);
    free(ps->p);
    ps->p = NULL;
    ps->n = 0;
}

int mp_params_set(mp_parset *ps, const char *name, const char *value, char *err)
{
    mp_par *p = mpp_find(ps, name);
    char *v;
    if (!p) {
        mpp_errf(err, "%s: unknown parameter of task %s", name, ps->task);
        return 1;
    }
    if (mpp_check(p, value, err))
        return 1;
    /* A pset given a file name takes that file's values (IRAF's
     * daopars=night1.par). */
    if (p->type == MP_PAR_PSET && value[0] && mp_params_load_file(ps, value, err))
        return 1;
    if (!(v = mpp_normalize(p, value))) {
        mpp_errf(err, "%s: out of memory", name);
        return 1;
    }
    free(p->value);
    p->value = v;
    p->set = 1;
    return 0;
}

/* ---- typed access ------------------------------------------------------ */

int mp_par_bool(const mp_parset *ps, const char *name, int *v)
{
    const mp_par *p = mpp_find(ps, name);
    if (!p || p->type != MP_PAR_BOOL)
        return 1;
    return parse_bool(p->value, v);
}

int mp_par_int(const mp_parset *ps, const char *name, int *v)
{
    const mp_par *p = mpp_find(ps, name);
    long l;
    if (!p || p->type != MP_PAR_INT)
        return 1;
    if (mpp_undefined(p->value)) {
        *v = MP_PAR_INDEF_INT;
        return 0;
    }
    if (parse_int(p->value, &l))
        return 1;
    *v = (int)l;
    return 0;
}

int mp_par_real(const mp_parset *ps, const char *name, double *v)
{
    const mp_par *p = mpp_find(ps, name);
    if (!p || (p->type != MP_PAR_REAL && p->type != MP_PAR_INT))
        return 1;
    if (mpp_undefined(p->value)) {
        *v = NAN;
        return 0;
    }
    return parse_real(p->value, v);
}

int mp_par_need_real(const mp_parset *ps, const char *name, double *v, char *err)
{
    if (mp_par_real(ps, name, v) || !isfinite(*v)) {
        mpp_errf(err, "%s: INDEF is not allowed; give a number", name);
        return 1;
    }
    return 0;
}

int mp_par_need_int(const mp_parset *ps, const char *name, int *v, char *err)
{
    if (mp_par_int(ps, name, v) || *v == MP_PAR_INDEF_INT) {
        mpp_errf(err, "%s: INDEF is not allowed; give a number", name);
        return 1;
    }
    return 0;
}

const char *mp_par_string(const mp_parset *ps, const char *name)
{
    const mp_par *p = mpp_find(ps, name);
    if (!p)
        return NULL;
    return mpp_undefined(p->value) ? "" : p->value;
}
