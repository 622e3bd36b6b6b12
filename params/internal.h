/*
 * internal.h — helpers shared by the files of params/ (private).
 */
#ifndef MATPHOT_PARAMS_INTERNAL_H
#define MATPHOT_PARAMS_INTERNAL_H

#include "params/params.h"

/* Write a formatted message into err (MP_ERRLEN bytes). */
void mpp_errf(char *err, const char *fmt, ...)
    __attribute__((format(printf, 2, 3)));
/* Put a formatted prefix in front of the message already in err. */
void mpp_err_prefix(char *err, const char *fmt, ...)
    __attribute__((format(printf, 2, 3)));

/* The parameter called name, or NULL. */
mp_par *mpp_find(const mp_parset *ps, const char *name);

/* 1 when p is filled from the command line's bare words (mode a or q, not
 * hidden); mpp_required: such a parameter with no value. */
int mpp_is_query(const mp_par *p);
int mpp_required(const mp_par *p);
/* 1 for "" and INDEF (any case). */
int mpp_undefined(const char *value);

/* Check value against p's type and range; err names p.  0 when legal. */
int mpp_check(const mp_par *p, const char *value, char *err);
/* Check the min/max fields of p themselves (numbers, INDEF or empty). */
int mpp_check_bounds(const mp_par *p, char *err);
/* The text to store for a legal value: booleans become yes/no, indef
 * INDEF.  NULL when out of memory. */
char *mpp_normalize(const mp_par *p, const char *value);

/* Deep-copy src into ps at position at (0..n).  Nonzero: out of memory. */
int mpp_insert(mp_parset *ps, size_t at, const mp_par *src);
void mpp_free_par(mp_par *p);

/* Parse .par text without checking values; line[i] (when lines is not
 * NULL, malloc'd) is the line number of parameter i. */
int mpp_parse(const char *text, const char *origin, mp_parset *ps,
              int **lines, char *err);

/* Read a whole file into a NUL-terminated malloc'd string. */
int mpp_read_file(const char *path, char **text, char *err);

/* Apply command-line words; check_required: fail on a required query
 * parameter left without a value. */
int mpp_apply(mp_parset *ps, int argc, char **argv, int check_required, char *err);

/* Type letter(s) as written in a .par file. */
const char *mpp_type_name(mp_par_type t);

#endif
