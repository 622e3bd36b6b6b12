/*
 * list.c — IRAF list arguments: "@frames.lis" stands for the names in
 * frames.lis, one a line (blank lines and # comments skipped).
 */
#include <stdlib.h>
#include <string.h>

#include "params/internal.h"

void mp_list_free(char **items, size_t n)
{
    if (!items)
        return;
    for (size_t i = 0; i < n; i++)
        free(items[i]);
    free(items);
}

int mp_params_list(const char *arg, char ***items, size_t *n, char *err)
{
    char **v = NULL, *text, *s;
    size_t k = 0;
    *items = NULL;
    *n = 0;
    if (!arg || !arg[0])
        return 0;                    /* nothing given: an empty list */
    if (arg[0] != '@') {
        if (!(v = malloc(sizeof *v)) || !(v[0] = strdup(arg))) {
            free(v);
            mpp_errf(err, "%s: out of memory", arg);
            return 1;
        }
        *items = v;
        *n = 1;
        return 0;
    }
    if (!arg[1]) {
        mpp_errf(err, "@: names no list file (@frames.lis: one name a line)");
        return 1;
    }
    if (mpp_read_file(arg + 1, &text, err))
        return 1;
    for (s = text; *s;) {
        char *eol = strchr(s, '\n');
        char *e = eol ? eol : s + strlen(s);
        char *next = eol ? eol + 1 : e;
        /* Trim blanks and the CR of CRLF files. */
        while (*s == ' ' || *s == '\t')
            s++;
        while (e > s && (e[-1] == '\r' || e[-1] == ' ' || e[-1] == '\t'))
            e--;
        if (e > s && *s != '#') {
            char **nv = realloc(v, (k + 1) * sizeof *nv);
            if (!nv || !(nv[k] = strndup(s, (size_t)(e - s)))) {
                mp_list_free(nv ? nv : v, k);
                free(text);
                mpp_errf(err, "%s: out of memory", arg + 1);
                return 1;
            }
            v = nv;
            k++;
        }
        s = next;
    }
    free(text);
    if (k == 0) {
        mpp_errf(err, "%s: the list is empty", arg + 1);
        return 1;
    }
    *items = v;
    *n = k;
    return 0;
}
