/*
 * table_io.c — reading a table in whichever format it is in, and writing it
 * atomically through io/io.h's mp_outfile.
 */
#include <errno.h>
#include <stdint.h>
#include <stdio.h>
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

/* Read all of fp into a malloc'd buffer (for FITS on stdin, which cannot
 * be rewound). */
static int slurp(FILE *fp, const char *name, char **buf, size_t *len, char *err)
{
    size_t cap = 1 << 16, n = 0;
    char *b = malloc(cap);
    for (;;) {
        if (!b) {
            snprintf(err, MP_ERRLEN, "%s: out of memory", name);
            return 1;
        }
        n += fread(b + n, 1, cap - n, fp);
        if (n < cap)
            break;
        char *nb = cap <= SIZE_MAX / 2 ? realloc(b, cap * 2) : NULL;
        if (!nb)
            free(b);
        b = nb;
        cap *= 2;
    }
    if (ferror(fp)) {
        snprintf(err, MP_ERRLEN, "%s: read error: %s", name, errno ? strerror(errno) : "I/O error");
        free(b);
        return 1;
    }
    *buf = b;
    *len = n;
    return 0;
}

/* Messages quote the file's text, which may hold a newline (inside a CSV
 * quote) or other control characters: keep the message one printable
 * line (found by tests/fuzz). */
static void one_line(char *err)
{
    for (char *p = err; *p; p++)
        if ((unsigned char)*p < 0x20 || *p == 0x7f)
            *p = '?';
}

/* The text table on L: the first non-blank line tells the format: "#"
 * starts ASCII_HEAD's column definitions, anything else is a CSV header
 * row. */
static int read_text(mp_lines *L, mp_table *t, char *err)
{
    int r;
    while ((r = mp_lines_next(L, err)) == 1) {
        if (L->lineno == 1 && L->len >= 3 && memcmp(L->line, "\xEF\xBB\xBF", 3) == 0) {
            /* A UTF-8 byte-order mark, as spreadsheets write before a CSV;
             * dropped before the blank test, so a blank first line stays
             * blank. */
            memmove(L->line, L->line + 3, (size_t)L->len - 2);
            L->len -= 3;
        }
        if (!is_blank(L->line))
            break;
    }
    if (r == 0)
        snprintf(err, MP_ERRLEN, "%s: empty file", L->name);
    if (r != 1)
        return 1;
    L->pending = 1;
    const char *p = L->line;
    while (*p == ' ' || *p == '\t')
        p++;
    /* IRAF's text databases open with "#K" keywords or "#N" names;
     * ASCII_HEAD's lines are "#   1 NAME" */
    if (p[0] == '#' && (p[1] == 'K' || p[1] == 'N') && (p[2] == ' ' || p[2] == '\t'))
        return mp_iraf_text_read(L, t, err);
    /* DAOPHOT II's open with " NL    NX    NY  LOWBAD ..." */
    if (p[0] == 'N' && p[1] == 'L' && (p[2] == ' ' || p[2] == '\t'))
        return mp_daophot2_read(L, t, err);
    return *p == '#' ? mp_ascii_head_read(L, t, err) : mp_csv_read(L, t, err);
}

/* FITS tables start with "SIMPLE  =".  A first 'S' has the stream read
 * into memory (*mem, *mlen bytes), where cfitsio reads a FITS table from;
 * text starting with S (a CSV header) is then read from that copy (*fp
 * reopened on it).  Returns 0: text to read from *fp; 1: failed (err);
 * 2: a FITS table in *mem. */
static int sniff(FILE **fp, const char *name, char **mem, size_t *mlen, char *err)
{
    int c0 = getc(*fp);
    if (c0 != EOF)
        ungetc(c0, *fp);
    if (c0 == 0x1f) {
        /* gzip's or compress's first byte, never a text table's: read as
         * text it was refused by a line of its binary bytes */
        snprintf(err, MP_ERRLEN, "%s: a compressed file (gzip or compress: its first byte is "
                 "0x1f); a table is read uncompressed: gzip -dc it to a file, or pipe it in as -",
                 name);
        return 1;
    }
    if (c0 != 'S')
        return 0;
    int bad = slurp(*fp, name, mem, mlen, err);
    mp_close_input(*fp);
    *fp = NULL;
    if (bad)
        return 1;
    if (*mlen >= 9 && memcmp(*mem, "SIMPLE  =", 9) == 0)
        return 2;
    if (!(*fp = fmemopen(*mem, *mlen, "r"))) {
        snprintf(err, MP_ERRLEN, "%s: %s", name, strerror(errno));
        return 1;
    }
    return 0;
}

int mp_table_read(const char *path, mp_table *t, char *err)
{
    mp_table_init(t);
    int is_stdin = !path || strcmp(path, "-") == 0;
    FILE *fp = mp_open_input(is_stdin ? "-" : path, err);
    if (!fp)
        return 1;
    const char *name = is_stdin ? "stdin" : path;
    char *mem = NULL;
    size_t mlen = 0;
    int how = sniff(&fp, name, &mem, &mlen, err), rc;
    if (how == 1) {
        free(mem);
        return 1;
    }
    if (how == 2)
        rc = mp_table_read_fits(name, mem, mlen, t, err);
    else {
        mp_lines L = {.fp = fp, .name = name};
        rc = read_text(&L, t, err);
        free(L.line);
        if (mem)
            fclose(fp);
        else
            mp_close_input(fp);
    }
    free(mem);
    if (rc) {
        mp_table_free(t);
        one_line(err);
    }
    return rc;
}

/* t written to path (mp_table_write_kept: the rows prev holds the same
 * copied; t's rows kept into *keep when keep is set). */
static int write_kept(const char *path, const mp_table *t, mp_table_format fmt,
                      const mp_text_kept *prev, mp_text_kept **keep, char *err)
{
    /* FITS is written by cfitsio to a named file, atomically on its own. */
    if (fmt == MP_TAB_FITS || fmt == MP_TAB_LDAC) {
        mp_ldac_head minimal = {0};
        return mp_table_write_fits(path, t, fmt == MP_TAB_LDAC ? &minimal : NULL, err);
    }
    int is_stdout = !path || strcmp(path, "-") == 0;
    const char *name = is_stdout ? "stdout" : path;
    mp_outfile o;
    if (mp_out_open(&o, is_stdout ? "-" : path, err))
        return 1;
    int rc = fmt == MP_TAB_CSV ? mp_csv_write(o.fp, name, t, err)
                               : mp_ascii_head_write_kept(o.fp, name, t, prev, keep, err);
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

int mp_table_write(const char *path, const mp_table *t, mp_table_format fmt, char *err)
{
    return mp_table_write_kept(path, t, fmt, NULL, NULL, err);
}

int mp_table_write_kept(const char *path, const mp_table *t, mp_table_format fmt,
                        const mp_text_kept *prev, mp_text_kept **keep, char *err)
{
    if (keep)
        *keep = NULL;
    int rc = write_kept(path, t, fmt, prev, keep, err);
    if (rc && keep) {
        mp_text_kept_free(*keep);
        *keep = NULL;
    }
    return rc;
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
    /* SExtractor's CATALOG_TYPE names work too. */
    if (strcasecmp(s, "fits") == 0 || strcasecmp(s, "fits_1.0") == 0) {
        *fmt = MP_TAB_FITS;
        return 0;
    }
    if (strcasecmp(s, "ldac") == 0 || strcasecmp(s, "fits_ldac") == 0) {
        *fmt = MP_TAB_LDAC;
        return 0;
    }
    return 1;
}
