/*
 * catalog.h — the table that passes between matphot's stages and its file
 * formats (design.md §4; SExtractor's layout, anchors.md §2.2).
 *
 * A table is a list of named numeric columns and rows of doubles.  Integer
 * columns (NUMBER, FLAGS, GROUP_ID, ...) are stored as doubles and written
 * without decimals.  Known column names (the design.md §4 list and the
 * SExtractor names we use) carry their description, unit and print format
 * from a built-in registry; unknown names get a generic one.
 *
 * ASCII_HEAD lines are exactly SExtractor's:
 *   "#   3 XPSF_IMAGE             X coordinate from PSF-fitting                              [pixel]"
 * i.e. "#", the 1-based index right-aligned in 4, a space, the name
 * left-aligned in 22, a space, the description left-aligned in 58, a space,
 * and the unit in brackets (omitted when there is none).
 * (That is SExtractor's "# %3d %-22.22s %-58.58s [%s]", which differs only
 * from column 1000 on: "# 1000 ..."; matphot never truncates a name or
 * description.)  Values: each column's format, one blank between columns,
 * NaN as "nan"; CSV: a header row of quoted names, NaN as an empty field.
 *
 * Errors: functions return 0 on success, nonzero on failure with one line in
 * err (MP_ERRLEN bytes) naming the file and what is wrong (line number for
 * malformed rows).
 */
#ifndef MATPHOT_CATALOG_H
#define MATPHOT_CATALOG_H

#include <stddef.h>

#include "io/io.h"   /* MP_ERRLEN (added: callers size err with it) */

typedef struct {
    char name[32];
    char desc[64];
    char unit[24];
    char fmt[16];    /* printf format for one value, e.g. "%10.4f" */
    int is_int;
} mp_col;

typedef struct {
    size_t ncol, nrow, cap;   /* cap: rows allocated */
    mp_col *cols;
    double *v;                /* v[row*ncol + col] */
} mp_table;

typedef enum { MP_TAB_ASCII_HEAD, MP_TAB_CSV } mp_table_format;

void mp_table_init(mp_table *t);
void mp_table_free(mp_table *t);

/* mp_table_add_col: add a column (values NaN in existing rows) and return its
 * index, or the existing index if the name is already there; -1 when out of
 * memory (and, added: when name is empty or longer than 31 characters).
 * Description, unit and format come from the registry of known names. */
int mp_table_add_col(mp_table *t, const char *name);

/* mp_table_col: index of a column, -1 when absent. */
int mp_table_col(const mp_table *t, const char *name);

/* mp_table_add_row: append a row of NaN; return its index, -1 when out of
 * memory. */
long mp_table_add_row(mp_table *t);

static inline double mp_table_get(const mp_table *t, size_t row, int col)
{ return t->v[row * t->ncol + (size_t)col]; }
static inline void mp_table_set(mp_table *t, size_t row, int col, double x)
{ t->v[row * t->ncol + (size_t)col] = x; }

/* mp_table_read: read an ASCII_HEAD table or a CSV table with a header row
 * (told apart by the first line); path "-" is stdin.  Errors: missing file,
 * empty file, no header, text in a number, wrong number of fields.
 * (Added:) t need not be initialised: it is set up by the call and left
 * empty on failure, so mp_table_free(t) is always safe afterwards.  "nan",
 * "NaN", "INDEF" and empty CSV fields read as NaN; blank lines, CRLF line
 * ends and lines of any length are accepted. */
int mp_table_read(const char *path, mp_table *t, char *err);

/* mp_table_write: write atomically (see mp_outfile); path "-" or NULL is
 * stdout. */
int mp_table_write(const char *path, const mp_table *t, mp_table_format fmt, char *err);

/* mp_table_format_parse: "ascii_head"/"csv" (case-insensitive) → format;
 * nonzero when unknown. */
int mp_table_format_parse(const char *s, mp_table_format *fmt);

#endif
