/*
 * fuzz_bodies.h — what each fuzz target does with one input, shared by the
 * libFuzzer targets (tests/fuzz/fuzz_*.c, `make fuzz`) and by the unit test
 * that replays the seed corpora and every input that once crashed
 * (tests/unit/test_fuzz_replay.c, tests/fuzz/regressions/).
 *
 * Each body returns 0 when the input was handled: accepted, or refused with
 * one non-empty error line.  A crash, a sanitizer report, a leak, or a
 * broken contract (an error without a message, a table or .par file that
 * does not read back as it was written) is a finding; the bodies call
 * abort() for a broken contract so libFuzzer keeps the input.
 *
 * File-based readers get the bytes through a temporary file (one per
 * process, reused, in $TMPDIR): that is the path users take.
 */
#ifndef MATPHOT_FUZZ_BODIES_H
#define MATPHOT_FUZZ_BODIES_H

#include <math.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <unistd.h>
#include <zlib.h>

#include "catalog/catalog.h"
#include "fit/fit.h"
#include "io/io.h"
#include "params/params.h"

/* Abort with a message: a contract broken by this input. */
static inline void fuzz_fail(const char *what, const char *detail)
{
    fprintf(stderr, "fuzz: contract broken: %s: %s\n", what, detail ? detail : "");
    abort();
}

/* Every refusal must say why, in one line. */
static inline void fuzz_check_err(const char *what, const char *err)
{
    if (!err[0])
        fuzz_fail(what, "failed without a message");
    if (strchr(err, '\n'))
        fuzz_fail(what, "message of more than one line");
}

/* The per-process temporary file: "<TMPDIR>/mp_fuzz_<tag>_<pid><ext>". */
static inline const char *fuzz_tmp_path(const char *tag, const char *ext, char *buf, size_t len)
{
    const char *dir = getenv("TMPDIR");
    snprintf(buf, len, "%s/mp_fuzz_%s_%ld%s", dir && *dir ? dir : "/tmp", tag,
             (long)getpid(), ext);
    return buf;
}

static inline int fuzz_write_file(const char *path, const uint8_t *data, size_t size)
{
    FILE *fp = fopen(path, "wb");
    if (!fp)
        return 1;
    int bad = size && fwrite(data, 1, size, fp) != size;
    bad |= fclose(fp) != 0;
    return bad;
}

/* The bytes gzipped into path (fastest level): a mutation of the FITS
 * bytes reaches a gzip file's readers whole, where a mutation of gzip's
 * own bytes mostly breaks its stream. */
static inline int fuzz_write_gzip(const char *path, const uint8_t *data, size_t size)
{
    gzFile gz = gzopen(path, "wb1");
    if (!gz)
        return 1;
    int bad = size && gzwrite(gz, data, (unsigned)size) != (int)size;
    bad |= gzclose(gz) != Z_OK;
    return bad;
}

/* ---- .par text (mp_params_parse_text) ------------------------------------ */

/* Parse; what parses must write and parse back to the same parameters
 * (params.h's promise for mp_params_write). */
static inline int fuzz_params_body(const uint8_t *data, size_t size)
{
    char *text = malloc(size + 1);
    if (!text)
        return 0;
    memcpy(text, data, size);
    text[size] = '\0';
    char err[MP_ERRLEN] = "";
    mp_parset ps;
    int rc = mp_params_parse_text(text, "fuzz.par", &ps, err);
    free(text);
    if (rc) {
        fuzz_check_err("mp_params_parse_text", err);
        return 0;
    }
    char *buf = NULL;
    size_t blen = 0;
    FILE *mem = open_memstream(&buf, &blen);
    if (!mem) {
        mp_params_free(&ps);
        return 0;
    }
    mp_params_write(&ps, mem);
    fclose(mem);
    mp_parset back;
    err[0] = '\0';
    if (mp_params_parse_text(buf, "fuzz.par", &back, err)) {
        fprintf(stderr, "written:\n%s\n", buf);
        fuzz_fail("mp_params_write output does not parse back", err);
    }
    if (back.n != ps.n)
        fuzz_fail("round trip", "parameter count changed");
    for (size_t i = 0; i < ps.n; i++) {
        const mp_par *a = &ps.p[i], *b = &back.p[i];
        if (strcmp(a->name, b->name) || a->type != b->type || strcmp(a->value, b->value) ||
            strcmp(a->min, b->min) || strcmp(a->max, b->max) || strcmp(a->prompt, b->prompt) ||
            strcmp(a->mode, b->mode))
            fuzz_fail("round trip changed parameter", a->name);
    }
    /* Typed access never crashes, whatever the value. */
    for (size_t i = 0; i < ps.n; i++) {
        int iv;
        double rv;
        (void)mp_par_bool(&ps, ps.p[i].name, &iv);
        (void)mp_par_int(&ps, ps.p[i].name, &iv);
        (void)mp_par_real(&ps, ps.p[i].name, &rv);
        (void)mp_par_string(&ps, ps.p[i].name);
    }
    mp_params_free(&back);
    mp_params_free(&ps);
    free(buf);
    return 0;
}

/* ---- tables (mp_table_read: ASCII_HEAD, CSV, FITS) ----------------------- */

/* The first character of the first non-blank line, seen as mp_table_read
 * sees lines: C strings (a NUL ends the line's text), a UTF-8 BOM skipped
 * on line 1, blanks and a final CR ignored. */
static inline int fuzz_first_char(const uint8_t *d, size_t n)
{
    size_t i = 0;
    for (int line = 1; i < n; line++) {
        size_t j = i;
        if (line == 1 && n - j >= 3 && memcmp(d + j, "\xEF\xBB\xBF", 3) == 0)
            j += 3;
        while (j < n && (d[j] == ' ' || d[j] == '\t'))
            j++;
        if (j < n && d[j] != '\n' && d[j] != '\0' && !(d[j] == '\r' && (j + 1 == n || d[j + 1] == '\n')))
            return d[j];
        while (i < n && d[i] != '\n')
            i++;
        i++;
    }
    return -1;
}

/* Read a table from the bytes; what reads must write in its own format
 * (ASCII_HEAD, CSV or FITS, told as mp_table_read tells them) and read back
 * with the same columns and rows.  FITS bytes are also read straight from
 * memory (mp_table_read_fits). */
static inline int fuzz_table_body(const uint8_t *data, size_t size)
{
    char path[256], out[256], err[MP_ERRLEN] = "";
    fuzz_tmp_path("table", ".tab", path, sizeof path);
    fuzz_tmp_path("table", ".out", out, sizeof out);
    if (fuzz_write_file(path, data, size))
        return 0;
    mp_table t;
    int rc = mp_table_read(path, &t, err);
    if (rc) {
        fuzz_check_err("mp_table_read", err);
    } else {
        mp_table_format fmt = size >= 9 && memcmp(data, "SIMPLE  =", 9) == 0 ? MP_TAB_FITS
                              : fuzz_first_char(data, size) == '#'         ? MP_TAB_ASCII_HEAD
                                                                           : MP_TAB_CSV;
        err[0] = '\0';
        if (mp_table_write(out, &t, fmt, err))
            fuzz_fail("mp_table_write of a table that was read", err);
        mp_table back;
        if (mp_table_read(out, &back, err)) {
            if (t.ncol == 0)
                ;   /* a table without columns writes nothing to read */
            else
                fuzz_fail("written table does not read back", err);
        } else if (back.ncol != t.ncol || back.nrow != t.nrow) {
            fuzz_fail("round trip", "columns or rows changed");
        }
        mp_table_free(&back);
        unlink(out);
    }
    mp_table_free(&t);
    if (size >= 9 && memcmp(data, "SIMPLE  =", 9) == 0) {
        err[0] = '\0';
        if (mp_table_read_fits("fuzz.fits", data, size, &t, err))
            fuzz_check_err("mp_table_read_fits", err);
        mp_table_free(&t);
    }
    unlink(path);
    return 0;
}

/* ---- PSF, kernel and DRF files (mp_psf_read, mp_psf_kernel_read, mp_drf_read) */

/* The bytes as a FITS file read as a PSF table (with and without
 * normalisation), as a detector kernel (its image, and Tiny Tim's COMMENT
 * cards) and as a DRF; a PSF that loads is rendered once at an arbitrary
 * position, which must give finite values. */
static inline int fuzz_psf_body(const uint8_t *data, size_t size)
{
    char path[256], gz[256], err[MP_ERRLEN] = "", warn[MP_ERRLEN] = "";
    fuzz_tmp_path("psf", ".fits", path, sizeof path);
    fuzz_tmp_path("psf", ".fits.gz", gz, sizeof gz);
    if (fuzz_write_file(path, data, size) || fuzz_write_gzip(gz, data, size))
        return 0;
    /* v 2: the same bytes gzipped (fuzz_write_gzip), read as v 0 */
    for (int v = 0; v < 3; v++) {
        mp_psf p;
        err[0] = '\0';
        if (mp_psf_read(v == 2 ? gz : path, v == 1, 0, &p, warn, err)) {
            fuzz_check_err("mp_psf_read", err);
            continue;
        }
        if (!(p.sum > 0) || !isfinite(p.sum) || p.nx % 2 == 0 || p.ny % 2 == 0 || p.os < 1)
            fuzz_fail("mp_psf_read", "accepted a table it promises to refuse");
        /* Render a small PSF: a fuzzed 1000x1000 table would only be slow. */
        if ((size_t)p.nx * (size_t)p.ny <= 4096) {
            mp_prf_model m = {&p, NULL, 10};
            long x0, y0;
            int w, h;
            mp_prf_box(&m, 20.3, 17.8, &x0, &y0, &w, &h);
            size_t n = (size_t)w * (size_t)h;
            double *prf = malloc(3 * n * sizeof *prf);
            mp_prf_work work = {0};
            if (prf && mp_prf_render(&m, 20.3, 17.8, prf, prf + n, prf + 2 * n, &work) == 0)
                for (size_t i = 0; i < 3 * n; i++)
                    if (!isfinite(prf[i]))
                        fuzz_fail("mp_prf_render", "non-finite PRF from an accepted table");
            free(prf);
            mp_prf_work_free(&work);
        }
        mp_psf_free(&p);
    }
    /* A detector kernel: the image itself, Tiny Tim's COMMENT cards (header),
     * or those cards when there are any (auto: none is no error). */
    for (int spec = 0; spec < 3; spec++) {
        mp_psf k;
        err[0] = '\0';
        if (mp_psf_kernel_read(spec == 0 ? path : spec == 1 ? "header" : "auto", path, &k,
                               err)) {
            fuzz_check_err("mp_psf_kernel_read", err);
            continue;
        }
        if (!k.t && spec == 2)
            continue;
        double sum = 0.0;
        for (int i = 0; i < k.nx * k.ny; i++)
            sum += k.t[i];
        if (k.nx % 2 == 0 || k.ny % 2 == 0 || k.nx > 99 || k.ny > 99 || !(sum > 0) ||
            !isfinite(sum))
            fuzz_fail("mp_psf_kernel_read", "accepted a kernel it promises to refuse");
        mp_psf_free(&k);
    }
    for (int os = 1; os <= 4; os++) {
        mp_drf d;
        err[0] = '\0';
        if (mp_drf_read(path, os, &d, err)) {
            fuzz_check_err("mp_drf_read", err);
            continue;
        }
        if (!(d.volume > 0 && d.volume <= 1) || d.k < 1 || os % d.k)
            fuzz_fail("mp_drf_read", "accepted a DRF it promises to refuse");
        mp_drf_free(&d);
    }
    unlink(path);
    unlink(gz);
    return 0;
}

/* ---- matphot PSF files (mp_psf_field_read) ---------------------------------- */

/* Read; what is accepted must keep the reader's promises, render finite
 * PRFs at a few positions, and write and read back to the same planes. */
static inline int fuzz_psf_field_body(const uint8_t *data, size_t size)
{
    char path[256], gz[256], back[256], err[MP_ERRLEN] = "", warn[MP_ERRLEN] = "";
    fuzz_tmp_path("psffield", ".fits", path, sizeof path);
    fuzz_tmp_path("psffield", ".fits.gz", gz, sizeof gz);
    fuzz_tmp_path("psffield_back", ".fits", back, sizeof back);
    if (fuzz_write_file(path, data, size) || fuzz_write_gzip(gz, data, size))
        return 0;
    /* v 2: the same bytes gzipped (fuzz_write_gzip), read as v 0 */
    for (int v = 0; v < 3; v++) {
        int norm = v == 1;
        mp_psf_field f;
        mp_psf_star *st = NULL;
        int ns = 0;
        err[0] = '\0';
        if (mp_psf_field_read(v == 2 ? gz : path, norm, 0, &f, &st, &ns, warn, err)) {
            fuzz_check_err("mp_psf_field_read", err);
            continue;
        }
        if (!(f.sum > 0) || !isfinite(f.sum) || f.nx % 2 == 0 || f.ny % 2 == 0 || f.os < 1 ||
            f.os > 8 ||
            f.nterms != (f.order == MP_PSF_GRID ? f.ngx * f.ngy : mp_psf_nterms(f.order)) ||
            (f.order > 0 && f.order != MP_PSF_GRID && !(f.xscale > 0 && f.yscale > 0)) ||
            /* a grid's span: 0 along an axis with one grid point */
            (f.order == MP_PSF_GRID && !(f.xscale >= 0 && f.yscale >= 0)) ||
            (ns > 0) != (st != NULL))
            fuzz_fail("mp_psf_field_read", "accepted a file it promises to refuse");
        if ((size_t)f.nx * (size_t)f.ny <= 4096) {
            mp_psf o;
            if (mp_psf_field_eval(&f, f.x0, f.y0, &o, err) == 0) {
                o.field = &f;
                mp_prf_model m = {&o, NULL, 10};
                mp_prf_work work = {0};
                const double xs[2] = {20.3, f.x0 + 0.37 * f.xscale};
                for (int c = 0; c < 2; c++) {
                    /* The box depends on the position: size the arrays for
                     * the one rendered. */
                    long x0, y0;
                    int w, h;
                    mp_prf_box(&m, xs[c], 17.8, &x0, &y0, &w, &h);
                    size_t n = (size_t)w * (size_t)h;
                    double *prf = malloc(3 * n * sizeof *prf);
                    if (prf && mp_prf_render(&m, xs[c], 17.8, prf, prf + n, prf + 2 * n, &work) == 0)
                        for (size_t i = 0; i < 3 * n; i++)
                            if (!isfinite(prf[i]))
                                fuzz_fail("mp_prf_render", "non-finite PRF from an accepted field");
                    free(prf);
                }
                mp_prf_work_free(&work);
                mp_psf_free(&o);
            }
        }
        mp_psf_field g;
        if (mp_psf_field_write(back, &f, st, ns, err) == 0) {
            if (mp_psf_field_read(back, 0, 0, &g, NULL, NULL, warn, err))
                fuzz_fail("mp_psf_field_write output does not read back", err);
            size_t n = (size_t)f.nx * f.ny * f.nterms;
            if (g.order != f.order || g.nx != f.nx || g.ny != f.ny || g.os != f.os ||
                g.offset != f.offset)
                fuzz_fail("round trip", "geometry changed");
            /* Values as written (subnormals may come back as zero). */
            for (size_t i = 0; i < n; i++)
                if (!(fabs(g.planes[i] - f.planes[i]) <= 1e-300))
                    fuzz_fail("round trip", "a plane's values changed");
            mp_psf_field_free(&g);
            unlink(back);
        } else {
            fuzz_check_err("mp_psf_field_write", err);
        }
        free(st);
        mp_psf_field_free(&f);
    }
    unlink(path);
    unlink(gz);
    return 0;
}

/* ---- Frames (mp_frame_read) ----------------------------------------------- */

/* What an accepted frame promises (io.h): positive finite gain, read noise
 * >= 0, a mask whose counts are nbad and nsat, a bad pixel 0, every other
 * pixel finite, and the error plane's extra variance finite and >= 0. */
static inline void fuzz_frame_check(const mp_frame *f)
{
    if (f->im.nx < 1 || f->im.ny < 1 || !f->im.pix || !f->mask)
        fuzz_fail("mp_frame_read", "accepted a frame without pixels or mask");
    if (!(f->gain > 0) || !isfinite(f->gain) || !(f->rdnoise >= 0) || !isfinite(f->rdnoise))
        fuzz_fail("mp_frame_read", "accepted a gain or read noise it promises to refuse");
    size_t n = (size_t)f->im.nx * (size_t)f->im.ny;
    long nbad = 0, nsat = 0;
    for (size_t i = 0; i < n; i++) {
        uint8_t m = f->mask[i];
        nbad += (m & MP_MASK_BAD) != 0;
        nsat += m == MP_MASK_SATURATED;
        if ((m & MP_MASK_BAD) && f->im.pix[i] != 0.0f)
            fuzz_fail("mp_frame_read", "a bad pixel that is not 0");
        if (!isfinite(f->im.pix[i]))
            fuzz_fail("mp_frame_read", "a pixel that is not finite");
        if (f->xvar && !(f->xvar[i] >= 0.0f && isfinite(f->xvar[i])))
            fuzz_fail("mp_frame_read", "an error plane's variance not finite and >= 0");
    }
    if (nbad != f->nbad || nsat != f->nsat)
        fuzz_fail("mp_frame_read", "nbad or nsat is not the mask's count");
}

/* Read as a frame three ways: alone; with the DQ, ERR and growth options of
 * an HST FLT (the DQ and ERR planes as extensions of the same file); and
 * its first extension with the detector numbers given. */
static inline int fuzz_frame_body(const uint8_t *data, size_t size)
{
    char path[256], gz[256], name[300], err[MP_ERRLEN];
    fuzz_tmp_path("frame", ".fits", path, sizeof path);
    fuzz_tmp_path("frame", ".fits.gz", gz, sizeof gz);
    if (fuzz_write_file(path, data, size) || fuzz_write_gzip(gz, data, size))
        return 0;
    /* v 3: the same bytes gzipped, read as v 0 reads them (cfitsio
     * inflates the file and parses what a plain one holds) */
    for (int v = 0; v < 4; v++) {
        mp_datapars dp = {NAN, NAN, NAN, NAN, "", 0, 0, 0, "", 0, 0};
        snprintf(name, sizeof name, "%s%s", v == 3 ? gz : path, v == 2 ? "[1]" : "");
        if (v == 1) {
            snprintf(dp.dqmask, sizeof dp.dqmask, "[DQ]");
            snprintf(dp.errplane, sizeof dp.errplane, "auto");
            dp.dqsat = 256 | 2048;
            dp.dqbad = 4 | 16 | 32 | 64 | 128 | 4096 | 8192;
            dp.satgrow = 1;
            dp.bleedgrow = 2;
            dp.badgrow = 1;
        } else if (v == 2) {
            dp.gain = 2.5;
            dp.rdnoise = 4.0;
            dp.saturate = 1000.0;
            snprintf(dp.dqmask, sizeof dp.dqmask, "[2]");
            snprintf(dp.errplane, sizeof dp.errplane, "[3]");
            dp.dqbad = 1;
        }
        mp_frame f;
        err[0] = '\0';
        if (mp_frame_read(name, &dp, &f, err)) {
            fuzz_check_err("mp_frame_read", err);
            continue;
        }
        fuzz_frame_check(&f);
        mp_frame_free(&f);
    }
    unlink(path);
    unlink(gz);
    return 0;
}

#endif
