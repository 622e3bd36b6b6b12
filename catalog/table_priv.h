/*
 * table_priv.h — private to catalog/: the column registry and the per-format
 * readers and writers that table_io.c dispatches to.  Other folders use
 * catalog/catalog.h only.
 */
#ifndef MATPHOT_TABLE_PRIV_H
#define MATPHOT_TABLE_PRIV_H

#include <stdio.h>
#include <sys/types.h>

#include "catalog/catalog.h"

/* mp_col_registry_find: the built-in description of a known column name
 * (design.md §4 and the simulator's truth columns), NULL when unknown. */
const mp_col *mp_col_registry_find(const char *name);

/* mp_col_registry_count / mp_col_registry_at: walk the registry (tests). */
size_t mp_col_registry_count(void);
const mp_col *mp_col_registry_at(size_t i);

/* mp_col_describe: fill c for name: the registry entry when known, else a
 * generic float column with no description or unit.  Nonzero when the name
 * is empty or does not fit in mp_col.name. */
int mp_col_describe(const char *name, mp_col *c);

/* mp_col_name_bad: nonzero when a name holds a blank, a control or a
 * non-ASCII character, which ASCII_HEAD cannot write back; its reader
 * refuses such names (found by tests/fuzz).  CSV and FITS keep them, as
 * their own formats can (the ASCII_HEAD writer then says why it cannot). */
int mp_col_name_bad(const char *name);

/* mp_parse_value: a table value: a decimal number, or "nan"/"NaN"/"INDEF"
 * (any case) for a missing one.  Surrounding blanks are allowed; nothing
 * else.  Returns 0 on success. */
int mp_parse_value(const char *s, double *x);

/* mp_format_value: print x with the column's format into buf (NUL
 * terminated); NaN is "nan" right-aligned in the format's width, so that
 * "%+11.7f" never gives "+nan".  Returns the length. */
int mp_format_value(const mp_col *c, double x, char *buf, size_t len);

/* mp_text: a growing text buffer; mp_text_put appends len bytes of s,
 * nonzero when out of memory (b unchanged then). */
typedef struct {
    char *s;
    size_t n, cap;
} mp_text;
int mp_text_put(mp_text *b, const char *s, size_t len);

/* mp_rows_format: rows [r0, r1) of what ctx holds, as text appended to b;
 * nonzero when out of memory. */
typedef int (*mp_rows_format)(const void *ctx, size_t r0, size_t r1, mp_text *b);

/* mp_rows_write: rows 0..nrow formatted by fmt in parallel, a chunk of
 * rows a thread, and written to fp in order, so the bytes do not depend
 * on the threads (issue 14: the writes were the largest serial part of a
 * run).  Nonzero when out of memory; write errors are left on fp. */
int mp_rows_write(FILE *fp, size_t nrow, mp_rows_format fmt, const void *ctx);

/* A line source that lets table_io.c look at the first line (to tell the
 * format) before handing the stream to a reader: `line` holds the pending
 * line when `pending` is set. */
typedef struct {
    FILE *fp;
    const char *name;     /* for messages: the path, or "stdin" */
    char *line;           /* getline buffer */
    size_t cap;
    ssize_t len;          /* length of line, without the stripped newline */
    long lineno;          /* 1-based number of the line in `line` */
    int pending;          /* `line` was peeked and not yet consumed */
} mp_lines;

/* mp_lines_next: the next line with its "\n" or "\r\n" stripped; 1 when
 * one is returned, 0 at end of file, -1 on a read error (err set). */
int mp_lines_next(mp_lines *L, char *err);

/* Readers: read the stream after table_io.c peeked at its first non-blank
 * line (left pending in L) into an empty table t. */
int mp_ascii_head_read(mp_lines *L, mp_table *t, char *err);
/* mp_iraf_text_read: IRAF's text database (DAOPHOT's and APPHOT's
 * tables: "#K", "#N", "#U", "#F" headers, records continued by '\'). */
int mp_iraf_text_read(mp_lines *L, mp_table *t, char *err);
/* mp_daophot2_read: Stetson's DAOPHOT II tables (the "NL NX NY ..."
 * header, Fortran's fixed columns: ID X Y MAG ...). */
int mp_daophot2_read(mp_lines *L, mp_table *t, char *err);
int mp_csv_read(mp_lines *L, mp_table *t, char *err);

/* Writers: write t to fp; nonzero (err set, naming `name`) when t cannot be
 * written in that format. Stream errors are found by the caller at commit.
 * mp_ascii_head_write_kept: with prev (NULL: none), a row it holds the
 * same (mp_text_kept_row) copied from it; with out, the rows' text kept
 * there for the next table (NULL when it cannot be, or is above the
 * budget: keep_within_budget). */
int mp_ascii_head_write(FILE *fp, const char *name, const mp_table *t, char *err);
int mp_ascii_head_write_kept(FILE *fp, const char *name, const mp_table *t,
                             const mp_text_kept *prev, mp_text_kept **out, char *err);

/* text_kept.c.  mp_text_kept_fits: whether k's columns are t's first
 * ones (names, formats; all of them, or t's with columns after), and k can
 * be looked up by NUMBER.  mp_text_kept_ncol: k's columns.
 * mp_text_kept_row: row r of t (NUMBER in column cnum) as k wrote it,
 * when k holds that NUMBER with the same values bit for bit in k's
 * columns: its text into *s, *len (with its newline).
 * mp_text_kept_make: *out for t from its rows' text (len bytes, taken
 * over); left NULL when the text is not one line a row; nonzero when out
 * of memory. */
int mp_text_kept_fits(const mp_text_kept *k, const mp_table *t);
size_t mp_text_kept_ncol(const mp_text_kept *k);
int mp_text_kept_row(const mp_text_kept *k, const mp_table *t, int cnum, size_t r,
                     const char **s, size_t *len);
int mp_text_kept_make(mp_text_kept **out, const mp_table *t, char *text, size_t len);
int mp_csv_write(FILE *fp, const char *name, const mp_table *t, char *err);

#endif
