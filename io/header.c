/* header.c — keyword look-ups in a kept header (io.h). */
#include "io/io.h"

#include <ctype.h>
#include <stdlib.h>
#include <string.h>

/* The value field of key's first card (NUL-terminated copy in val), or
 * NULL when absent.  Handles standard 8-character keys ("KEY     = ") and
 * ESO HIERARCH keys ("HIERARCH A B C = "). */
static const char *find_value(const mp_image *im, const char *lkey, char *val)
{
    size_t klen = strlen(lkey);
    if (!im || !im->hdr || klen == 0 || klen > 70)
        return NULL;
    char key[72];          /* keywords are upper case in FITS */
    for (size_t i = 0; i <= klen; i++)
        key[i] = (char)toupper((unsigned char)lkey[i]);
    for (int k = 0; k < im->nkeys; k++) {
        const char *c = im->hdr + (size_t)k * 80;
        const char *v = NULL;
        if (klen <= 8 && memcmp(c, key, klen) == 0) {
            size_t i = klen;
            while (i < 8 && c[i] == ' ') i++;
            if (i == 8 && c[8] == '=')
                v = c + 9;
        }
        if (!v && memcmp(c, "HIERARCH ", 9) == 0) {
            const char *p = c + 9;
            while (p < c + 80 && *p == ' ') p++;
            if (p + klen < c + 80 && memcmp(p, key, klen) == 0) {
                p += klen;
                while (p < c + 80 && *p == ' ') p++;
                if (p < c + 80 && *p == '=')
                    v = p + 1;
            }
        }
        if (v) {
            size_t n = (size_t)(c + 80 - v);
            memcpy(val, v, n);
            val[n] = '\0';
            return val;
        }
    }
    return NULL;
}

int mp_header_double(const mp_image *im, const char *key, double *value)
{
    char buf[81];
    const char *v = find_value(im, key, buf);
    if (!v)
        return 1;
    while (*v == ' ') v++;
    if (*v == '\'')
        return 2;
    /* The number runs up to the comment slash; FITS allows a D exponent. */
    char num[81];
    size_t n = 0;
    for (; v[n] && v[n] != '/'; n++)
        num[n] = (v[n] == 'D' || v[n] == 'd') ? 'E' : v[n];
    while (n > 0 && num[n - 1] == ' ') n--;
    num[n] = '\0';
    if (n == 0)
        return 2;
    char *end;
    double x = strtod(num, &end);
    if (*end != '\0' || end == num)
        return 2;
    *value = x;
    return 0;
}

int mp_header_string(const mp_image *im, const char *key, char *value, size_t len)
{
    char buf[81];
    const char *v = find_value(im, key, buf);
    if (!v)
        return 1;
    while (*v == ' ') v++;
    if (*v != '\'')
        return 2;
    /* A doubled quote is a literal quote; trailing blanks are not part of
     * the value (FITS standard §4.2.1). */
    char s[81];
    size_t n = 0;
    const char *p = v + 1;
    for (;;) {
        if (*p == '\0')
            return 2;          /* no closing quote */
        if (*p == '\'') {
            if (p[1] == '\'') { s[n++] = '\''; p += 2; continue; }
            break;
        }
        s[n++] = *p++;
    }
    while (n > 0 && s[n - 1] == ' ') n--;
    s[n] = '\0';
    if (len > 0) {
        size_t m = n < len - 1 ? n : len - 1;
        memcpy(value, s, m);
        value[m] = '\0';
    }
    return 0;
}
