/* section.c — rewrite IRAF-style sections for cfitsio (see section.h). */
#include "io/section.h"

#include <ctype.h>
#include <stdlib.h>
#include <string.h>

/* An image section holds only these characters and at least one comma;
 * "[1]" and "[SCI]" are HDU selectors and stay as they are. */
static int is_section(const char *s, size_t n)
{
    int comma = 0;
    for (size_t i = 0; i < n; i++) {
        if (s[i] == ',')
            comma = 1;
        else if (!isdigit((unsigned char)s[i]) && !strchr("*:-+ ", s[i]))
            return 0;
    }
    return comma;
}

/* A lone integer: digits with optional sign and blanks. */
static int is_index(const char *s, size_t n)
{
    size_t i = 0, digits = 0;
    while (i < n && s[i] == ' ') i++;
    if (i < n && (s[i] == '+' || s[i] == '-')) i++;
    while (i < n && isdigit((unsigned char)s[i])) { i++; digits++; }
    while (i < n && s[i] == ' ') i++;
    return digits > 0 && i == n;
}

char *mp_section_name(const char *name)
{
    size_t len = strlen(name);
    /* The worst case doubles every item; 2*len+1 always suffices. */
    char *out = malloc(2 * len + 1);
    if (!out)
        return NULL;
    const char *open = strrchr(name, '[');
    const char *close = open ? strchr(open, ']') : NULL;
    if (!open || !close || !is_section(open + 1, (size_t)(close - open - 1))) {
        memcpy(out, name, len + 1);
        return out;
    }
    size_t o = (size_t)(open - name) + 1;
    memcpy(out, name, o);
    const char *p = open + 1;
    while (p < close) {
        const char *e = memchr(p, ',', (size_t)(close - p));
        if (!e)
            e = close;
        size_t n = (size_t)(e - p);
        memcpy(out + o, p, n);
        o += n;
        if (is_index(p, n)) {
            out[o++] = ':';
            memcpy(out + o, p, n);
            o += n;
        }
        if (e < close)
            out[o++] = ',';
        p = e + 1;
    }
    strcpy(out + o, close);
    return out;
}
