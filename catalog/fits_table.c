/*
 * fits_table.c — tables as FITS binary tables through cfitsio (catalog.h):
 * SExtractor's FITS_1.0 (empty primary + OBJECTS) and FITS_LDAC (empty
 * primary + LDAC_IMHEAD + LDAC_OBJECTS), written atomically, and read back.
 *
 * The header layout follows what SExtractor 2.25 writes (checked on its
 * own output): EXTNAME right after TFIELDS, then per column TTYPE (comment:
 * the description), TFORM, TUNIT, TDISP.
 */
#include <errno.h>
#include <math.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <unistd.h>
#include <fitsio.h>

#include "catalog/catalog.h"
#include "catalog/table_priv.h"

/* How one column is stored. */
typedef struct {
    char tform[4];      /* "1D", "1J", "1K", "1I" */
    int datatype;       /* cfitsio type handed to fits_write_col */
    char tdisp[16];     /* "" when the format has no TDISP form */
    int has_null;       /* an integer column with NaN rows: TNULL = tnull */
    long long tnull;
} colspec;

/* Name and description of a cfitsio status, for messages. */
static void fits_message(const char *name, const char *what, int status, char *err)
{
    char txt[FLEN_STATUS];
    fits_get_errstatus(status, txt);
    snprintf(err, MP_ERRLEN, "%s: %s: %s (cfitsio status %d)", name, what, txt, status);
    fits_clear_errmsg();
}

/* TDISP from a printf format, as SExtractor's printftotdisp: %W.Pf → FW.P,
 * %W.Pg → GW.P, %W.Pe → EW.P; integers stored as integers → IW. */
static void tdisp_of(const mp_col *c, int stored_int, char *out, size_t len)
{
    out[0] = '\0';
    const char *p = strchr(c->fmt, '%');
    if (!p)
        return;
    p++;
    while (*p && strchr("-+ #0", *p))
        p++;
    char *end;
    long w = strtol(p, &end, 10), d = -1;
    if (end == p || w <= 0 || w > 99)
        return;
    p = end;
    if (*p == '.') {
        d = strtol(p + 1, &end, 10);
        if (end == p + 1 || d < 0 || d > 99)
            return;
        p = end;
    }
    char conv = *p;
    if (stored_int) {
        snprintf(out, len, "I%ld", w);
        return;
    }
    char t = conv == 'f' || conv == 'F' ? 'F' : conv == 'e' || conv == 'E' ? 'E'
           : conv == 'g' || conv == 'G' ? 'G' : 0;
    if (!t)
        return;
    if (d >= 0)
        snprintf(out, len, "%c%ld.%ld", t, w, d);
    else
        snprintf(out, len, "%c%ld", t, w);
}

/* Choose the storage of column c: the narrowest of I (FLAGS only), J, K
 * that holds every value of an integer column, with room for TNULL at the
 * type's minimum; D for everything else. */
static void spec_of(const mp_table *t, int c, colspec *s)
{
    memset(s, 0, sizeof *s);
    const mp_col *col = &t->cols[c];
    int integral = col->is_int, nan = 0;
    double lo = 0, hi = 0;
    for (size_t r = 0; r < t->nrow && integral; r++) {
        double v = mp_table_get(t, r, c);
        if (isnan(v)) {
            nan = 1;
            continue;
        }
        if (!isfinite(v) || v != floor(v)) {
            integral = 0;
            break;
        }
        if (v < lo) lo = v;
        if (v > hi) hi = v;
    }
    int kind = 0;   /* 0 D, 16 I, 32 J, 64 K */
    if (integral) {
        if (strcmp(col->name, "FLAGS") == 0 && lo > INT16_MIN && hi <= INT16_MAX)
            kind = 16;
        else if (lo > INT32_MIN && hi <= INT32_MAX)
            kind = 32;
        else if (lo > -9223372036854775808.0 && hi < 9223372036854775808.0)
            kind = 64;
    }
    switch (kind) {
    case 16: strcpy(s->tform, "1I"); s->tnull = INT16_MIN; break;
    case 32: strcpy(s->tform, "1J"); s->tnull = INT32_MIN; break;
    case 64: strcpy(s->tform, "1K"); s->tnull = INT64_MIN; break;
    default: strcpy(s->tform, "1D"); break;
    }
    s->datatype = kind ? TLONGLONG : TDOUBLE;
    s->has_null = kind && nan;
    tdisp_of(col, kind != 0, s->tdisp, sizeof s->tdisp);
}

/* Is the card last read the header's last one?  cfitsio 4.2 fails
 * (END_OF_FILE) inserting after the last keyword when END has just moved
 * into a new 2880-byte block; appending puts the card at the same place. */
static int at_header_end(fitsfile *fp, int *status)
{
    int nkeys = 0, next = 0;
    fits_get_hdrpos(fp, &nkeys, &next, status);
    return next > nkeys;
}

/* Write a keyword right after the card last read. */
static void put_str_after(fitsfile *fp, const char *key, const char *val, const char *comm,
                          int *status)
{
    if (at_header_end(fp, status))
        fits_write_key_str(fp, key, val, comm, status);
    else
        fits_insert_key_str(fp, key, val, comm, status);
}

static void put_lng_after(fitsfile *fp, const char *key, long long val, const char *comm,
                          int *status)
{
    if (at_header_end(fp, status))
        fits_write_key_lng(fp, key, val, comm, status);
    else
        fits_insert_key_lng(fp, key, val, comm, status);
}

/* A one-row BINTABLE LDAC_IMHEAD holding the card block as one string
 * column of 80 × ncards characters, shaped (80, ncards) by TDIM1. */
static int write_imhead(fitsfile *fp, const char *cards, int ncards, int *status)
{
    char tform[32], tdim[48];
    snprintf(tform, sizeof tform, "%ldA", (long)ncards * 80);
    snprintf(tdim, sizeof tdim, "(80, %d)", ncards);
    char *ttype[] = {"Field Header Card"};
    char *tforms[] = {tform};
    /* Rows are added once the header is complete, so that growing the
     * header never has cfitsio shift a data area not yet written. */
    fits_create_tbl(fp, BINARY_TBL, 0, 1, ttype, tforms, NULL, NULL, status);
    char card[FLEN_CARD];
    fits_read_card(fp, "TFIELDS", card, status);
    put_str_after(fp, "EXTNAME", "LDAC_IMHEAD", "extension name", status);
    fits_read_card(fp, "TFORM1", card, status);
    put_str_after(fp, "TDIM1", tdim, "", status);
    fits_set_hdustruc(fp, status);
    fits_insert_rows(fp, 0, 1, status);
    /* Raw bytes: cfitsio's string I/O would split the column at TDIM's 80. */
    fits_write_tblbytes(fp, 1, 1, (LONGLONG)ncards * 80, (unsigned char *)cards, status);
    return *status;
}

/* The objects table: columns and then the values, one column at a time. */
static int write_objects(fitsfile *fp, const mp_table *t, const colspec *spec,
                         const char *extname, int *status)
{
    int nc = (int)t->ncol;
    char **ttype = malloc((size_t)nc * sizeof *ttype);
    char **tform = malloc((size_t)nc * sizeof *tform);
    char **tunit = malloc((size_t)nc * sizeof *tunit);
    size_t nbuf = t->nrow ? t->nrow : 1;
    double *dv = malloc(nbuf * sizeof *dv);
    long long *iv = malloc(nbuf * sizeof *iv);
    if (!ttype || !tform || !tunit || !dv || !iv) {
        *status = MEMORY_ALLOCATION;
        goto done;
    }
    for (int c = 0; c < nc; c++) {
        ttype[c] = (char *)t->cols[c].name;
        tform[c] = (char *)spec[c].tform;
        tunit[c] = (char *)t->cols[c].unit;
    }
    /* Rows come after the header is complete (see write_imhead). */
    if (fits_create_tbl(fp, BINARY_TBL, 0, nc, ttype, tform, tunit, NULL, status))
        goto done;
    char card[FLEN_CARD], key[FLEN_KEYWORD];
    fits_read_card(fp, "TFIELDS", card, status);
    put_str_after(fp, "EXTNAME", extname, "extension name", status);
    for (int c = 0; c < nc && !*status; c++) {
        const mp_col *col = &t->cols[c];
        if (col->desc[0]) {
            snprintf(key, sizeof key, "TTYPE%d", c + 1);
            fits_modify_comment(fp, key, col->desc, status);
        }
        /* TDISP and TNULL go right after the column's last keyword. */
        snprintf(key, sizeof key, col->unit[0] ? "TUNIT%d" : "TFORM%d", c + 1);
        fits_read_card(fp, key, card, status);
        if (spec[c].tdisp[0]) {
            snprintf(key, sizeof key, "TDISP%d", c + 1);
            put_str_after(fp, key, spec[c].tdisp, "", status);
        }
        if (spec[c].has_null) {
            snprintf(key, sizeof key, "TNULL%d", c + 1);
            put_lng_after(fp, key, spec[c].tnull, "undefined value", status);
        }
    }
    fits_set_hdustruc(fp, status);   /* re-read the table with its TNULLs */
    fits_insert_rows(fp, 0, (LONGLONG)t->nrow, status);
    for (int c = 0; c < nc && !*status; c++) {
        void *buf;
        if (spec[c].datatype == TDOUBLE) {
            for (size_t r = 0; r < t->nrow; r++)
                dv[r] = mp_table_get(t, r, c);
            buf = dv;
        } else {
            for (size_t r = 0; r < t->nrow; r++) {
                double v = mp_table_get(t, r, c);
                iv[r] = isnan(v) ? spec[c].tnull : (long long)v;
            }
            buf = iv;
        }
        if (t->nrow)
            fits_write_col(fp, spec[c].datatype, c + 1, 1, 1, (LONGLONG)t->nrow, buf, status);
    }
done:
    free(ttype);
    free(tform);
    free(tunit);
    free(dv);
    free(iv);
    return *status;
}

/* A FITS table can be written to path: a file name, 1..999 columns. */
static int check_writable(const char *path, const mp_table *t, const char *kind, char *err)
{
    if (!path || !*path || strcmp(path, "-") == 0) {
        snprintf(err, MP_ERRLEN, "%s: a %s table needs an output file name (not stdout)",
                 path && *path ? "stdout" : "(no name)", kind);
        return 1;
    }
    if (t->ncol == 0) {
        snprintf(err, MP_ERRLEN, "%s: the table has no columns to write", path);
        return 1;
    }
    if (t->ncol > 999) {
        snprintf(err, MP_ERRLEN, "%s: %zu columns: a FITS table holds at most 999", path, t->ncol);
        return 1;
    }
    return 0;
}

/* The file written as tmp (registered: an interrupt removes it,
 * io/cleanup.c) and renamed to path when whole; no file left on failure. */
static int write_and_rename(const char *tmp, const char *path, const mp_table *t,
                            const colspec *spec, const char *cards, int ncards, int ldac,
                            char *err)
{
    /* The disk-file driver takes the name literally (no extended-name
     * parsing of brackets in the user's path). */
    unlink(tmp);
    (void)mp_tmp_register(tmp);
    errno = 0;
    fitsfile *fp = NULL;
    int status = 0;
    if (fits_create_diskfile(&fp, tmp, &status)) {
        int en = errno;
        fits_clear_errmsg();
        snprintf(err, MP_ERRLEN, "%s: cannot create: %s", path,
                 en ? strerror(en) : "cfitsio could not create the file");
        return 1;
    }
    fits_create_img(fp, BYTE_IMG, 0, NULL, &status);   /* empty primary HDU */
    if (ldac)
        write_imhead(fp, cards, ncards, &status);
    write_objects(fp, t, spec, ldac ? "LDAC_OBJECTS" : "OBJECTS", &status);
    int wstatus = status;
    fits_close_file(fp, &status);   /* closes even after an error */
    if (wstatus || status) {
        fits_message(path, "cannot write the table", wstatus ? wstatus : status, err);
        unlink(tmp);
        return 1;
    }
    if (mp_out_place(tmp, path, err) != 0) {
        unlink(tmp);
        return 1;
    }
    return 0;
}

int mp_table_write_fits(const char *path, const mp_table *t, const mp_ldac_head *ldac,
                        char *err)
{
    if (check_writable(path, t, ldac ? "FITS_LDAC" : "FITS", err))
        return 1;
    colspec *spec = malloc(t->ncol * sizeof *spec);
    char *cards = NULL;
    int ncards = 0;
    char e[MP_ERRLEN];
    if (!spec) {
        snprintf(err, MP_ERRLEN, "%s: out of memory", path);
        return 1;
    }
    if (ldac && mp_ldac_cards(ldac, &cards, &ncards, e)) {
        snprintf(err, MP_ERRLEN, "%.200s: %.300s", path, e);
        free(spec);
        return 1;
    }
    for (size_t c = 0; c < t->ncol; c++)
        spec_of(t, (int)c, &spec[c]);
    int rc = 1;
    char *tmp = mp_tmp_name(path);
    if (!tmp)
        snprintf(err, MP_ERRLEN, "%s: out of memory", path);
    else
        rc = write_and_rename(tmp, path, t, spec, cards, ncards, ldac != NULL, err);
    mp_tmp_unregister(tmp);
    free(tmp);
    free(cards);
    free(spec);
    return rc;
}

/* ---- reading ------------------------------------------------------------ */

/* Move to the objects table: LDAC_OBJECTS, else OBJECTS, else the first
 * binary table that is not an LDAC_IMHEAD. */
static int find_objects(fitsfile *fp, int *status)
{
    static char *const names[] = {"LDAC_OBJECTS", "OBJECTS"};
    for (int i = 0; i < 2; i++) {
        if (!fits_movnam_hdu(fp, BINARY_TBL, names[i], 0, status))
            return 0;
        *status = 0;
    }
    fits_clear_errmsg();
    int nhdu = 0;
    fits_get_num_hdus(fp, &nhdu, status);
    for (int h = 2; h <= nhdu && !*status; h++) {
        int type;
        if (fits_movabs_hdu(fp, h, &type, status))
            break;
        char extname[FLEN_VALUE] = "";
        int st = 0;
        fits_read_key_str(fp, "EXTNAME", extname, NULL, &st);
        if (type == BINARY_TBL && strcmp(extname, "LDAC_IMHEAD") != 0)
            return 0;
    }
    if (!*status)
        *status = BAD_HDU_NUM;
    return *status;
}

/* Is cfitsio column type code numeric and readable as double? */
static int numeric_type(int code)
{
    switch (code) {
    case TBYTE: case TSBYTE: case TSHORT: case TUSHORT: case TINT: case TUINT:
    case TLONG: case TULONG: case TLONGLONG: case TULONGLONG: case TFLOAT: case TDOUBLE:
        return 1;
    default:
        return 0;
    }
}

/* Add file column fc as a table column: the registry's description and
 * format for a known name, the file's TUNIT and TTYPE comment otherwise
 * (a comment cut short by the 80-column card keeps the registry's). */
static int add_fits_col(fitsfile *fp, int fc, int code, mp_table *t, const char *name,
                        int *status, char *err)
{
    char key[FLEN_KEYWORD], val[FLEN_VALUE], comm[FLEN_COMMENT] = "", unit[FLEN_VALUE] = "";
    snprintf(key, sizeof key, "TTYPE%d", fc);
    fits_read_key_str(fp, key, val, comm, status);
    if (*status)
        return *status;
    snprintf(key, sizeof key, "TUNIT%d", fc);
    int st = 0;
    if (fits_read_key_str(fp, key, unit, NULL, &st))
        unit[0] = '\0';
    fits_clear_errmsg();
    if (!val[0] || strspn(val, " ") == strlen(val))
        snprintf(val, sizeof val, "COL%d", fc);   /* unnamed (found by tests/fuzz) */
    if (strlen(val) >= sizeof t->cols[0].name) {
        snprintf(err, MP_ERRLEN, "%s: column name '%.40s...' is too long (at most %zu characters)",
                 name, val, sizeof t->cols[0].name - 1);
        return -1;
    }
    if (mp_table_col(t, val) >= 0) {
        snprintf(err, MP_ERRLEN, "%s: column %s appears twice", name, val);
        return -1;
    }
    const mp_col *known = mp_col_registry_find(val);
    int c = mp_table_add_col(t, val);
    if (c < 0) {
        snprintf(err, MP_ERRLEN, "%s: out of memory", name);
        return -1;
    }
    mp_col *col = &t->cols[c];
    /* cfitsio's own default comment says nothing about the column. */
    if (strncmp(comm, "label for field", 15) == 0)
        comm[0] = '\0';
    if (comm[0] && !(known && strncmp(known->desc, comm, strlen(comm)) == 0))
        snprintf(col->desc, sizeof col->desc, "%s", comm);
    if (unit[0])
        snprintf(col->unit, sizeof col->unit, "%s", unit);
    if (!known && code != TFLOAT && code != TDOUBLE) {
        col->is_int = 1;
        strcpy(col->fmt, code == TLONGLONG || code == TULONGLONG ? "%20.0f" : "%10.0f");
    }
    return 0;
}

/* The FITS file or memory image opened read-only.  cfitsio reads whole
 * 2880-byte records, and its memory driver does not stop at the end of the
 * bytes: it gets a copy padded with zeros to a whole record, *mbuf, which
 * the caller frees after closing (found by tests/fuzz: a heap over-read). */
static int table_open(const char *name, const void *mem, size_t len, fitsfile **fp,
                      void **mbuf, size_t *msize, char *err)
{
    char why[MP_GUARD_LEN];
    if (mem ? mp_fits_guard_mem(mem, len, why) : mp_fits_guard_file(name, why)) {
        snprintf(err, MP_ERRLEN, "%s: %s", name, why);
        return 1;
    }
    int status = 0;
    if (mem) {
        *msize = (len / 2880 + 1) * 2880;
        if (!(*mbuf = calloc(*msize, 1))) {
            snprintf(err, MP_ERRLEN, "%s: out of memory", name);
            return 1;
        }
        memcpy(*mbuf, mem, len);
        fits_open_memfile(fp, name, READONLY, mbuf, msize, 0, NULL, &status);
    } else {
        fits_open_file(fp, name, READONLY, &status);
    }
    if (status) {
        fits_message(name, "cannot open as FITS", status, err);
        if (*fp) {   /* cfitsio may fail with fp set: see io/image_read.c */
            int s2 = 0;
            fits_close_file(*fp, &s2);
            *fp = NULL;
        }
        return 1;
    }
    return 0;
}

/* 0 when nrow rows of the current HDU fit in the bytes there are.  A
 * table whose rows end past the end of the bytes would make cfitsio's
 * memory driver read beyond the buffer (found by tests/fuzz), and a header
 * claiming 10^12 rows would ask for terabytes: say so first.  Returns -1
 * with err set, or a cfitsio status. */
static int table_size_check(fitsfile *fp, const char *name, const void *mem, size_t len,
                            LONGLONG nrow, int *status, char *err)
{
    LONGLONG hstart, dstart, dend, width = 0;
    fits_get_hduaddrll(fp, &hstart, &dstart, &dend, status);
    fits_read_key_lnglng(fp, "NAXIS1", &width, NULL, status);
    if (*status)
        return *status;
    LONGLONG avail = (mem ? (LONGLONG)len : fp->Fptr->logfilesize) - dstart;
    /* (A row of no bytes counts as one: rows cannot outnumber bytes.) */
    if (width < 0 || nrow < 0 || nrow > avail / (width > 0 ? width : 1)) {
        snprintf(err, MP_ERRLEN, "%s: truncated FITS table (%lld rows of %lld bytes "
                 "do not fit in the file)", name, (long long)nrow, (long long)width);
        return -1;
    }
    return 0;
}

/* The table's columns: one per numeric scalar column of the file (the
 * table model has no vectors), whose file column numbers go to fcol[].
 * Returns -1 with err set, or a cfitsio status. */
static int table_columns_define(fitsfile *fp, int ncol, mp_table *t, const char *name,
                                int *fcol, int *nuse, int *status, char *err)
{
    *nuse = 0;
    for (int fc = 1; fc <= ncol; fc++) {
        int code;
        long repeat, width;
        if (fits_get_coltype(fp, fc, &code, &repeat, &width, status))
            return *status;
        if (!numeric_type(code) || repeat != 1)
            continue;
        int r = add_fits_col(fp, fc, code, t, name, status, err);
        if (r)
            return r;
        fcol[(*nuse)++] = fc;
    }
    if (*nuse == 0) {
        snprintf(err, MP_ERRLEN, "%s: the binary table has no numeric scalar columns", name);
        return -1;
    }
    return 0;
}

/* nrow rows of the table's nuse columns, read column by column through
 * buf (nrow doubles).  Returns -1 with err set, or a cfitsio status. */
static int table_rows_read(fitsfile *fp, const int *fcol, int nuse, LONGLONG nrow,
                           double *buf, mp_table *t, const char *name, int *status,
                           char *err)
{
    for (LONGLONG r = 0; r < nrow; r++)
        if (mp_table_add_row(t) < 0) {
            snprintf(err, MP_ERRLEN, "%s: out of memory for %lld rows", name, (long long)nrow);
            return -1;
        }
    for (int c = 0; c < nuse; c++) {
        double nulval = NAN;
        int anynul = 0;
        if (nrow && fits_read_col(fp, TDOUBLE, fcol[c], 1, 1, nrow, &nulval, buf, &anynul,
                                  status))
            return *status;
        for (LONGLONG r = 0; r < nrow; r++)
            mp_table_set(t, (size_t)r, c, buf[r]);
    }
    return 0;
}

int mp_table_read_fits(const char *name, const void *mem, size_t len, mp_table *t, char *err)
{
    mp_table_init(t);
    fitsfile *fp = NULL;
    void *mbuf = NULL;
    size_t msize = 0;
    if (table_open(name, mem, len, &fp, &mbuf, &msize, err)) {
        free(mbuf);
        return 1;
    }
    int st = -1, status = 0, ncol = 0, nuse = 0, *fcol = NULL;
    double *buf = NULL;
    LONGLONG nrow = 0;
    if (find_objects(fp, &status)) {
        fits_clear_errmsg();
        snprintf(err, MP_ERRLEN, "%s: no binary table in the file (FITS_1.0 OBJECTS or "
                 "FITS_LDAC LDAC_OBJECTS)", name);
        goto done;
    }
    fits_get_num_cols(fp, &ncol, &status);
    fits_get_num_rowsll(fp, &nrow, &status);
    st = status ? status : table_size_check(fp, name, mem, len, nrow, &status, err);
    if (st)
        goto done;
    fcol = malloc((size_t)(ncol > 0 ? ncol : 1) * sizeof *fcol);
    if (!fcol || (uint64_t)nrow > SIZE_MAX / sizeof *buf ||
        !(buf = malloc((size_t)(nrow > 0 ? nrow : 1) * sizeof *buf))) {
        snprintf(err, MP_ERRLEN, "%s: out of memory for %lld rows", name, (long long)nrow);
        st = -1;
        goto done;
    }
    st = table_columns_define(fp, ncol, t, name, fcol, &nuse, &status, err);
    if (!st)
        st = table_rows_read(fp, fcol, nuse, nrow, buf, t, name, &status, err);
done:
    if (st > 0)
        fits_message(name, "cannot read the table", st, err);
    status = 0;
    fits_close_file(fp, &status);
    fits_clear_errmsg();
    free(mbuf);
    free(fcol);
    free(buf);
    if (st)
        mp_table_free(t);
    return st ? 1 : 0;
}
