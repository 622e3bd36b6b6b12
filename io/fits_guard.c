/* fits_guard.c — a pre-flight walk over a FITS file's headers before
 * cfitsio parses them.  cfitsio 4.2.0 overflows a 70-byte buffer (and glibc
 * aborts the process) on a table keyword whose value is not a quoted
 * string, e.g. "TTYPE2  =" followed by 70 bytes of garbage (found by
 * tests/fuzz).  Only the string-valued structural keywords are checked;
 * everything else is left to cfitsio.  The walk reads header records only:
 * data areas are skipped by their size, computed as FITS 4.0 §4.4.1.1 and
 * §7.3.1 define it (|BITPIX|/8 · GCOUNT · (PCOUNT + Π NAXISn)).  A gzip
 * file is walked as zlib inflates it (cfitsio inflates it whole and parses
 * the same headers: unwalked, a bad TTYPE card in one aborted the process
 * and a ZTILE of 0 divided by zero); a gzip or PKZIP file's stated size
 * is checked as well.  A tile-compressed image HDU (ZIMAGE = T) is
 * refused. */
#include <fitsio.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <zlib.h>
#include "io/io.h"

/* Is the value of an 80-byte card a well-formed string (FITS 4.0 §4.2.1)? */
static int string_ok(const unsigned char *c)
{
    int i = 9;
    while (i < 80 && c[i] == ' ')
        i++;
    if (i == 80 || c[i] != '\'')
        return 0;
    for (i++; i < 80; i++) {
        if (c[i] != '\'')
            continue;
        if (i + 1 < 80 && c[i + 1] == '\'') {
            i++;
            continue;
        }
        for (i++; i < 80 && c[i] == ' '; i++)
            ;
        return i == 80 || c[i] == '/';
    }
    return 0;
}

static long long card_int(const unsigned char *c)
{
    char v[72];
    memcpy(v, c + 10, 70);
    v[70] = '\0';
    return strtoll(v, NULL, 10);
}

/* What one header record of cards tells; 1 when END was seen. */
typedef struct { long long bitpix, naxis, n[1000], pcount, gcount; } hdu_sizes;

static int scan_record(const unsigned char *r, hdu_sizes *h, char *bad)
{
    static const char *const strings[] = {"XTENSION", "EXTNAME", "TFORM", "TTYPE", "TUNIT",
                                          "TDISP", "TDIM"};
    for (int k = 0; k < 36; k++) {
        const unsigned char *c = r + 80 * k;
        if (memcmp(c, "END     ", 8) == 0)
            return 1;
        /* A structural keyword's card with an '=' elsewhere than column 9
         * is read by cfitsio as a long keyword name and its value, which
         * overflows the same buffer (found by tests/fuzz: "TTYPE7  l=" and
         * 70 bytes of garbage). */
        int misplaced = c[8] != '=' && memchr(c, '=', 80) != NULL;
        if (c[8] != '=' && !misplaced)
            continue;
        for (size_t s = 0; s < sizeof strings / sizeof strings[0]; s++)
            if (strncmp((const char *)c, strings[s], strlen(strings[s])) == 0 &&
                (misplaced || !string_ok(c))) {
                memcpy(bad, c, 8);
                bad[8] = '\0';
                for (int i = 7; i >= 0 && bad[i] == ' '; i--)
                    bad[i] = '\0';
                return -1;
            }
        if (c[8] != '=')
            continue;
        /* A tile-compressed image: cfitsio parses its tiling as it moves
         * to the HDU and divides by a ZTILE or ZVAL of 0 (an FPE in
         * imcomp_get_compressed_image_par, found by tests/fuzz), and its
         * decoders read past a corrupt tile: refused (io.h). */
        if (memcmp(c, "ZIMAGE  ", 8) == 0) {
            int i = 10;
            while (i < 80 && c[i] == ' ')
                i++;
            if (i < 80 && c[i] == 'T')
                return -2;
        }
        if (memcmp(c, "BITPIX  ", 8) == 0)
            h->bitpix = card_int(c);
        else if (memcmp(c, "PCOUNT  ", 8) == 0)
            h->pcount = card_int(c);
        else if (memcmp(c, "GCOUNT  ", 8) == 0)
            h->gcount = card_int(c);
        else if (memcmp(c, "NAXIS", 5) == 0) {
            char d[4] = {(char)c[5], (char)c[6], (char)c[7], 0};
            if (d[0] == ' ')
                h->naxis = card_int(c);
            else {
                long j = strtol(d, NULL, 10);
                if (j >= 1 && j < 1000)
                    h->n[j] = card_int(c);
            }
        }
    }
    return 0;
}

/* Bytes of the data area after a header, padded to records; -1 if absurd. */
static long long data_bytes(const hdu_sizes *h)
{
    if (h->naxis <= 0)
        return 0;
    if (h->naxis >= 1000)
        return -1;
    long long n = 1;
    for (long long j = 1; j <= h->naxis; j++) {
        if (h->n[j] < 0 || (h->n[j] && n > (1LL << 60) / h->n[j]))
            return -1;
        n *= h->n[j];
    }
    /* Bounded before any product: a fuzzed PCOUNT of 2⁶³ − 1 overflowed. */
    if (h->bitpix < -64 || h->bitpix > 64 || h->pcount < 0 || h->pcount > (1LL << 60) ||
        h->gcount > (1LL << 30))
        return -1;
    long long b = (h->bitpix < 0 ? -h->bitpix : h->bitpix) / 8;
    long long g = h->gcount > 0 ? h->gcount : 1;
    long long w = h->pcount + n;                 /* ≤ 2⁶¹ */
    if (b > 0 && w > (1LL << 61) / (b * g))
        return -1;
    long long bytes = b * g * w;                 /* ≤ 2⁶¹ */
    return (bytes + 2879) / 2880 * 2880;
}

/* Walk records from get(ctx, offset, record) until the bytes end. */
typedef int (*record_fn)(void *ctx, long long off, unsigned char *rec);

static int walk(record_fn get, void *ctx, char *bad)
{
    unsigned char rec[2880];
    long long off = 0;
    for (int hdu = 0; hdu < 10000; hdu++) {
        hdu_sizes h;
        memset(&h, 0, sizeof h);
        int end = 0;
        while (!end) {
            if (get(ctx, off, rec))
                return 0;                 /* the bytes end: cfitsio says the rest */
            off += 2880;
            end = scan_record(rec, &h, bad);
            if (end < 0)
                return end == -2 ? 2 : 1;
        }
        long long d = data_bytes(&h);
        if (d < 0)
            return 0;
        off += d;
    }
    return 0;
}

typedef struct { const unsigned char *b; size_t n; } mem_ctx;

static int mem_record(void *ctx, long long off, unsigned char *rec)
{
    const mem_ctx *m = ctx;
    if (off < 0 || (size_t)off >= m->n)
        return 1;
    size_t k = m->n - (size_t)off < 2880 ? m->n - (size_t)off : 2880;
    memcpy(rec, m->b + off, k);
    memset(rec + k, ' ', 2880 - k);
    return 0;
}

static int file_record(void *ctx, long long off, unsigned char *rec)
{
    FILE *fp = ctx;
    if (fseeko(fp, (off_t)off, SEEK_SET))
        return 1;
    size_t k = fread(rec, 1, 2880, fp);
    if (k == 0)
        return 1;
    memset(rec + k, ' ', 2880 - k);
    return 0;
}

/* A gzip file's records as zlib inflates them: a seek forward inflates and
 * drops the data area between (the walk only goes forward), and a corrupt
 * stream ends the records as the file's end does. */
static int gz_record(void *ctx, long long off, unsigned char *rec)
{
    gzFile gz = ctx;
    if (off < 0 || gzseek(gz, (z_off_t)off, SEEK_SET) != (z_off_t)off)
        return 1;
    int k = gzread(gz, rec, 2880);
    if (k <= 0)
        return 1;
    memset(rec + k, ' ', 2880 - (size_t)k);
    return 0;
}

/* Deflate makes at most 1032 bytes of one (a run of 258-byte matches at
 * about two bits each; zlib's "zlib technical details"). */
#define DEFLATE_MAX_RATIO 1032

static unsigned long long le32(const unsigned char b[4])
{
    return b[0] | (unsigned long long)b[1] << 8 | (unsigned long long)b[2] << 16 |
           (unsigned long long)b[3] << 24;
}

/* A gzip or PKZIP file: the uncompressed size cfitsio will allocate before
 * inflating (its drvrmem.c mem_compress_open: gzip's trailer, with 4 GiB
 * added while it is below the file's own size past 10000 bytes; PKZIP's
 * local header at byte 22), refused when deflate cannot make that much of
 * the file's bytes.  A corrupt trailer would otherwise cost gigabytes of
 * memory before the stream is found broken (found by tests/fuzz). */
static int compressed_size_ok(FILE *fp, int gzip, char *why)
{
    const char *kind = gzip ? "gzip" : "zip";
    long long least = gzip ? 18 : 30;     /* header and trailer; a local file header */
    unsigned char b[4];
    if (fseeko(fp, 0, SEEK_END))
        return 1;
    long long size = (long long)ftello(fp);
    if (size < least) {
        snprintf(why, MP_GUARD_LEN, "corrupt %s file: %lld bytes, shorter than its headers",
                 kind, size);
        return 0;
    }
    if (fseeko(fp, gzip ? size - 4 : 22, SEEK_SET) || fread(b, 1, 4, fp) != 4)
        return 1;
    unsigned long long claimed = le32(b);
    if (gzip && size > 10000)
        while (claimed < (unsigned long long)size)
            claimed += 1ULL << 32;
    if (claimed <= (unsigned long long)size * DEFLATE_MAX_RATIO)
        return 1;
    snprintf(why, MP_GUARD_LEN, "corrupt %s file: it claims %llu bytes uncompressed, more "
             "than deflate makes of its %lld bytes", kind, claimed, size);
    return 0;
}

/* A gzip or PKZIP file whose name cfitsio 4.2 would inflate with another
 * method: its drvrmem.c mem_uncompress2mem takes any name with ".Z" in
 * it (strstr, the folders too) for Unix compress and any with ".bz2" for
 * bzip2, whatever the file's magic bytes, and then fails with "not a FITS
 * file" (found by stop 24's CI: a mkdtemp folder "test_io.Z..."). */
static int compressed_name_ok(const char *path, int gzip, char *why)
{
    const char *tag = strstr(path, ".Z") ? ".Z" : strstr(path, ".bz2") ? ".bz2" : NULL;
    if (!tag)
        return 1;
    snprintf(why, MP_GUARD_LEN, "a %s file whose path holds \"%s\", which cfitsio takes for %s: "
             "rename the file or its folder", gzip ? "gzip" : "zip", tag,
             tag[1] == 'Z' ? "Unix compress" : "bzip2");
    return 0;
}

/* Walk a gzip file's inflated headers (gz_record); walk's return. */
static int walk_gzip(const char *path, char *badkey)
{
    gzFile gz = gzopen(path, "rb");
    if (!gz)
        return 0;                 /* cfitsio says why it cannot open it */
    (void)gzbuffer(gz, 1 << 16);
    int rc = walk(gz_record, gz, badkey);
    gzclose(gz);
    return rc;
}

/* The card's keyword as printed: a byte outside printable ASCII shown as
 * '?' (the refusal is one line; a keyword "TUNITE \n" broke it, found by
 * tests/fuzz). */
static void key_why(const char *badkey, char *why)
{
    if (!badkey) {
        snprintf(why, MP_GUARD_LEN, "a tile-compressed image (fpack's .fz: cfitsio's tile "
                 "decoders do not hold a corrupt tile to its bytes): funpack it first");
        return;
    }
    char key[9];
    size_t i = 0;
    for (; i < 8 && badkey[i]; i++)
        key[i] = badkey[i] >= 0x20 && badkey[i] < 0x7f ? badkey[i] : '?';
    key[i] = '\0';
    snprintf(why, MP_GUARD_LEN, "malformed header card %s (its value is not a well-formed "
             "quoted string)", key);
}

int mp_fits_guard_mem(const void *b, size_t n, char *why)
{
    mem_ctx m = {b, n};
    char badkey[9];
    int rc = walk(mem_record, &m, badkey);
    if (!rc)
        return 0;
    key_why(rc == 2 ? NULL : badkey, why);
    return 1;
}

/* io.h; standard input and URLs other than file:// are refused because
 * no walk sees their bytes before cfitsio parses them (`find -` and `find
 * file://bad.fits` reached cfitsio's buffer overflow unwalked). */
int mp_fits_local_file(const char *name, char *path, size_t len, char *why)
{
    char root[FLEN_FILENAME];
    int st = 0;
    if (strlen(name) >= FLEN_FILENAME || ffrtnm((char *)name, root, &st) || !root[0])
        return -1;
    const char *p = strncmp(root, "file://", 7) == 0 ? root + 7 : root;
    /* "-", "-[1]"; "stdin://" comes as "-://" (a file "-x.fits" is a file) */
    if (strcmp(p, "-") == 0 || strncmp(p, "-://", 4) == 0) {
        snprintf(why, MP_GUARD_LEN, "a FITS image or PSF from standard input, which matphot "
                 "does not read: write it to a file (tables are read from -)");
        return 1;
    }
    if (strstr(p, "://")) {
        snprintf(why, MP_GUARD_LEN, "a URL, which matphot does not read: download it first");
        return 1;
    }
    /* "in.fits(out.fits)": cfitsio copies the input to out.fits as it
     * opens it, a write no output check of the run sees */
    char type[FLEN_FILENAME], in[FLEN_FILENAME], out[FLEN_FILENAME], ext[FLEN_FILENAME],
        rows[FLEN_FILENAME], bin[FLEN_FILENAME], col[FLEN_FILENAME];
    if (ffiurl((char *)name, type, in, out, ext, rows, bin, col, &st) == 0 && out[0]) {
        snprintf(why, MP_GUARD_LEN, "names a copy for cfitsio to write (%.60s), which matphot "
                 "does not make: copy the file first", out);
        return 1;
    }
    if (strlen(p) >= len)
        return -1;
    snprintf(path, len, "%s", p);
    return 0;
}

int mp_fits_guard_file(const char *name, char *why)
{
    char path[FLEN_FILENAME];
    int local = mp_fits_local_file(name, path, sizeof path, why);
    if (local)
        return local > 0;
    FILE *fp = fopen(path, "rb");
    if (!fp)
        return 0;
    unsigned char magic[2] = {0, 0};
    char badkey[9];
    int rc = 0;
    if (fread(magic, 1, 2, fp) == 2) {
        int gzip = magic[0] == 0x1f && magic[1] == 0x8b, zip = magic[0] == 'P' && magic[1] == 'K';
        if (gzip || zip)
            rc = !compressed_name_ok(path, gzip, why) || !compressed_size_ok(fp, gzip, why);
        if (!rc && !zip && (rc = gzip ? walk_gzip(path, badkey) : walk(file_record, fp, badkey)))
            key_why(rc == 2 ? NULL : badkey, why);
    }
    fclose(fp);
    return rc;
}

int mp_fits_guard_named(const char *path, const char *name, char *err)
{
    char why[MP_GUARD_LEN];
    if (!mp_fits_guard_file(path, why))
        return 0;
    snprintf(err, MP_ERRLEN, "%s: %s", name, why);
    return 1;
}

int mp_fits_key_number(void *fp, const char *key, double *v, int *status)
{
    char val[FLEN_VALUE] = "";
    if (*status)
        return *status;
    if (fits_read_keyword(fp, (char *)key, val, NULL, status))
        return *status;
    /* A quoted number is read as cfitsio reads it (its string's value). */
    char *a = val[0] == '\'' ? val + 1 : val, *q = val[0] == '\'' ? strrchr(a, '\'') : NULL;
    if (q)
        *q = '\0';
    for (char *c = a; *c; c++)          /* a Fortran exponent (FITS 4.0 §4.2.4) */
        *c = *c == 'D' || *c == 'd' ? 'E' : *c;
    char *end;
    double x = strtod(a, &end);
    while (end != a && *end == ' ')
        end++;
    if (end == a || *end != '\0')
        return *status = BAD_C2D;
    *v = x;
    return 0;
}
