/*
 * table_io.c — reading a table in whichever format it is in, and writing it
 * atomically through io/io.h's mp_outfile.
 */
#include <errno.h>
#include <stdlib.h>
#include <string.h>
#include <strings.h>

#include "catalog/catalog.h"
#include "catalog/table_priv.h"
#include "io/io.h"

int mp_lines_next(mp_lines *L, char *err)
{
    if (L->pending) {
        L->pending = 0;
        return 1;
    }
    errno = 0;
    ssize_t n = getline(&L->line, &L->cap, L->fp);
    if (n < 0) {
        if (ferror(L->fp)) {
            snprintf(err, MP_ERRLEN, "%s: read error: %s", L->name,
                     errno ? strerror(errno) : "I/O error");
            return -1;
        }
        return 0;
    }
    /* getline allocates as needed, so a line of any length is read whole. */
    L->lineno++;
    if (n > 0 && L->line[n - 1] == '\n')
        L->line[--n] = '\0';
    if (n > 0 && L->line[n - 1] == '\r')   /* CRLF files */
        L->line[--n] = '\0';
    L->len = n;
    return 1;
}

static int is_blank(const char *s)
{
    for (; *s; s++)
        if (*s != ' ' && *s != '\t')
            return 0;
    return 1;
}

int mp_table_read(const char *path, mp_table *t, char *err)
{
    mp_table_init(t);
    int is_stdin = !path || strcmp(path, "-") == 0;
    FILE *fp = mp_open_input(is_stdin ? "-" : path, err);
    if (!fp)
        return 1;
    mp_lines L = {.fp = fp, .name = is_stdin ? "stdin" : path};

    /* The first non-blank line tells the format: "#" starts ASCII_HEAD's
     * column definitions, anything else is a CSV header row. */
    int r;
    while ((r = mp_lines_next(&L, err)) == 1 && is_blank(L.line))
        ;
    int rc = 1;
    if (r == 0)
        snprintf(err, MP_ERRLEN, "%s: empty file", L.name);
    if (r == 1) {
        if (L.lineno == 1 && L.len >= 3 && memcmp(L.line, "\xEF\xBB\xBF", 3) == 0) {
            /* A UTF-8 byte-order mark, as spreadsheets write before a CSV. */
            memmove(L.line, L.line + 3, (size_t)L.len - 2);
            L.len -= 3;
        }
        L.pending = 1;
        const char *p = L.line;
        while (*p == ' ' || *p == '\t')
            p++;
        rc = *p == '#' ? mp_ascii_head_read(&L, t, err) : mp_csv_read(&L, t, err);
    }
    free(L.line);
    mp_close_input(fp);
    if (rc)
        mp_table_free(t);
    return rc;
}

int mp_table_write(const char *path, const mp_table *t, mp_table_format fmt, char *err)
{
    int is_stdout = !path || strcmp(path, "-") == 0;
    const char *name = is_stdout ? "stdout" : path;
    mp_outfile o;
    if (mp_out_open(&o, is_stdout ? "-" : path, err))
        return 1;
    int rc = fmt == MP_TAB_CSV ? mp_csv_write(o.fp, name, t, err)
                               : mp_ascii_head_write(o.fp, name, t, err);
    if (!rc && ferror(o.fp)) {
        snprintf(err, MP_ERRLEN, "%s: write error: %s", name,
                 errno ? strerror(errno) : "I/O error");
        rc = 1;
    }
    if (rc) {
        mp_out_abort(&o);   /* removes the temporary: no partial output */
        return 1;
    }
    return mp_out_commit(&o, err) ? 1 : 0;
}

int mp_table_format_parse(const char *s, mp_table_format *fmt)
{
    if (!s)
        return 1;
    if (strcasecmp(s, "ascii_head") == 0) {
        *fmt = MP_TAB_ASCII_HEAD;
        return 0;
    }
    if (strcasecmp(s, "csv") == 0) {
        *fmt = MP_TAB_CSV;
        return 0;
    }
    return 1;
}
