/*
 * io.h — the one place where matphot reads and writes FITS images and opens
 * output files.  Every stage uses it; no stage calls cfitsio for images itself.
 *
 * Conventions (design.md §3):
 *   - Image names are cfitsio extended file names: "f.fits", "f.fits[1]",
 *     "f.fits[SCI]", "f.fits[1:512,1:512]", "psf.fits[DRF]".
 *   - Pixels are held row-major: pix[(y-1)*nx + (x-1)] is the pixel whose
 *     centre is at the 1-based coordinate (x, y); as double in mp_image
 *     (PSF tables, DRFs, masks), as float in a frame's mp_fimage.
 *   - Every function that can fail returns 0 on success and nonzero on
 *     failure, and then writes one line (no trailing newline) into err, of at
 *     most MP_ERRLEN bytes, naming the file or parameter and what is wrong.
 *     The caller prefixes "matphot <task>: " and prints it.
 */
#ifndef MATPHOT_IO_H
#define MATPHOT_IO_H

#include <math.h>
#include <stddef.h>
#include <stdint.h>
#include <stdio.h>

#define MP_ERRLEN 512

/* A 2-D image with its primary header kept as text (80-char cards, as
 * fits_hdr2str gives it) so that WCSLIB and keyword look-ups need no
 * second read.  (Added:) for an extension it is that HDU's own header;
 * primary-header keywords are not inherited.  An IRAF-style plane index
 * in a section, "cube.fits[*,*,2]", is accepted as cfitsio's [*,*,2:2]. */
typedef struct {
    long nx, ny;
    double *pix;     /* nx*ny values; NaN where the file has NaN/blank */
    char *hdr;       /* nkeys 80-character cards, not NUL-separated */
    int nkeys;
} mp_image;

/* mp_image_read: read a 2-D image (any HDU/section through the extended
 * name).  Errors: file missing or unreadable, corrupt or truncated FITS, no
 * image in the HDU, more than two non-degenerate axes (a cube without a
 * section), unsupported BITPIX. */
int mp_image_read(const char *name, mp_image *im, char *err);

/* mp_image_header_read: the header alone of the image HDU name names (as
 * mp_image_read opens it: the first HDU with an image, or the one or the
 * section named), into im->hdr and im->nkeys; im->pix NULL, nx = ny = 0.
 * Errors as mp_image_read's opening. */
int mp_image_header_read(const char *name, mp_image *im, char *err);

/* mp_image_free: release what mp_image_read allocated; safe on a zeroed or
 * already freed image. */
void mp_image_free(mp_image *im);

/* A frame's image: as mp_image, its pixels in single precision.  A frame
 * is data with a noise of at least a few electrons a pixel; float's
 * relative 6e-8 rounding is far below it, and it halves the largest
 * arrays of a survey-size run (issue 14: whole-frame memory counted in
 * images).  Arithmetic on the pixels is done in double (the values are
 * promoted as they are read). */
typedef struct {
    long nx, ny;
    float *pix;      /* nx*ny values; NaN where the file has NaN/blank */
    char *hdr;       /* nkeys 80-character cards, not NUL-separated */
    int nkeys;
} mp_fimage;

/* mp_fimage_read / mp_fimage_free: mp_image_read and mp_image_free for a
 * single-precision image (any BITPIX, converted by cfitsio). */
int mp_fimage_read(const char *name, mp_fimage *im, char *err);
void mp_fimage_free(mp_fimage *im);

/* mp_fimage_header: a view of im's size and header as an mp_image with no
 * pixels (pix NULL), for the keyword and WCS readers; nothing to free. */
mp_image mp_fimage_header(const mp_fimage *im);

/* mp_header_double / mp_header_string: look a keyword up in im->hdr.
 * Return 0 when found and parsed, 1 when absent, 2 when present but not of
 * that type. */
int mp_header_double(const mp_image *im, const char *key, double *value);
int mp_header_string(const mp_image *im, const char *key, char *value, size_t len);

/* One header keyword to write with an image.  (Added:) a non-finite value
 * has no FITS form and leaves the card out; integral values are written
 * as integers. */
typedef struct {
    const char *key;
    double value;          /* used when str is NULL */
    const char *str;       /* string value, or NULL */
    const char *comment;
} mp_card;

/* mp_image_write: write pix (nx*ny, row-major as above) as a BITPIX -32 or
 * -64 primary image with the given cards, atomically (temporary name in the
 * same directory, renamed at the end; removed on failure). */
int mp_image_write(const char *path, const double *pix, long nx, long ny,
                   int bitpix, const mp_card *cards, int ncards, char *err);

/* mp_image_write_float: mp_image_write of single-precision pixels, BITPIX
 * -32 (a frame's residual, with no double copy of the frame's size). */
int mp_image_write_float(const char *path, const float *pix, long nx, long ny,
                         const mp_card *cards, int ncards, char *err);

/* mp_image_size: the size of a 2-D image (extended names and sections as
 * mp_image_read) without reading its pixels. */
int mp_image_size(const char *name, long *nx, long *ny, char *err);

/* An image written a rectangle at a time (io/image_stream.c): BITPIX -32,
 * the cards given (written as mp_image_write writes them), under a temporary
 * name that mp_image_out_close renames into place (commit != 0) or
 * removes; pixels never put read back as 0.  put writes w x h values
 * (row-major) with their lower-left pixel at (x1, y1), 1-based.  Errors:
 * cfitsio failures, a rectangle outside the image. */
typedef struct mp_image_out mp_image_out;
int mp_image_out_open(const char *path, long nx, long ny, const mp_card *cards, int ncards,
                      mp_image_out **o, char *err);
int mp_image_out_put(mp_image_out *o, long x1, long y1, long w, long h, const double *pix,
                     char *err);
int mp_image_out_close(mp_image_out *o, int commit, char *err);

/* Detector parameters (datapars.par).  NaN means "take it from the header
 * keyword, else the default": GAIN (1 e-/ADU), RDNOISE (0 e-), SATURATE
 * (none), EXPTIME (1 s). */
typedef struct {
    double gain, rdnoise, saturate, exptime;
    /* Optional data-quality image (HST DQ, SExtractor flag map): dqmask is
     * a file name or, starting with '[', an extension of the frame's own
     * file ("[DQ]"); pixels with a bit of dqbad set carry no weight, with
     * a bit of dqsat set count as saturated.  "": none. */
    char dqmask[1024];
    long dqsat, dqbad;
    /* satgrow: the pixels within this many (a square of side 2 satgrow
     * + 1) of a saturated one count as saturated too: the charge next to
     * a full well spills or is nonlinear, and no DQ plane flags it. */
    int satgrow;
    /* Optional error plane (HST ERR, a weight map's 1/sqrt): the 1-sigma
     * noise of each pixel in the image's units, named as dqmask is.  What
     * its variance holds beyond the Poisson noise of the pixel and RON²
     * (dark current, the bias's and the flat's noise: calacs puts them
     * there) becomes mp_frame.xvar; the Poisson part stays the model's
     * (design.md §5).  "" or "none": none; "auto" (the default): [ERR]
     * when the frame's own file holds an image extension named ERR. */
    char errplane[1024];
    /* bleedgrow: a run of two or more saturated pixels along a column (a
     * bleed trail) counts as this many pixels longer at each end, before
     * satgrow: CCD charge bleeds along columns past where a DQ plane stops
     * flagging it. */
    int bleedgrow;
    /* badgrow: the pixels within this many (a square of side 2 badgrow +
     * 1) of one with a dqbad bit carry no weight too: a cosmic ray's
     * charge spreads past the pixels the DQ plane flags (47 Tuc FLT:
     * README, validate/PSFREAL.md).  Saturated pixels stay saturated. */
    int badgrow;
} mp_datapars;

struct mp_parset_s;
/* mp_datapars_read: the datapars parameters (gain, rdnoise, saturate,
 * exptime, dqmask, dqsat, dqbad, satgrow, errplane, bleedgrow, badgrow) of a task's parameter set; INDEF reals
 * come back NaN (take the header's). */
void mp_datapars_read(const struct mp_parset_s *ps, mp_datapars *dp);

/* Mask bits of mp_frame.mask. */
enum {
    MP_MASK_BAD = 1,       /* NaN, blank or masked: carries no weight */
    MP_MASK_SATURATED = 2  /* at or above SATURATE: carries no weight */
};

/* A frame ready to fit: pixels in electrons (ADU × gain), a mask, and the
 * detector numbers actually in force (already resolved from datapars and
 * header). saturate is in ADU as in the header; INFINITY when none. */
typedef struct {
    mp_fimage im;          /* pix in electrons (single precision); bad pixels hold 0 */
    uint8_t *mask;         /* nx*ny, MP_MASK_* bits */
    double gain, rdnoise, saturate, exptime;
    long nbad, nsat;       /* counts of masked and saturated pixels */
    /* xvar: nx*ny, the variance [e-²] the error plane holds beyond
     * max(data, 0) + RON², at least 0; NULL without errplane.  A fit's
     * pixel weight is 1/(max(m, S) + RON² + xvar) (fit/lm_model.c); a
     * group's local frame adds the neighbours' light it took off to its
     * xvar (fit/frame_refit.c).  A copy
     * of a frame onto other pixels must crop it too, or set it NULL. */
    float *xvar;
} mp_frame;

/* mp_frame_read: read an image and prepare it for fitting.  Errors as
 * mp_image_read, plus non-positive gain, negative read noise, and for
 * dqmask/errplane an image of another size, and in the error plane a
 * negative value on a pixel that is not masked (an infinite or NaN
 * error masks the pixel as bad).  A pixel whose value, or whose error
 * plane's variance, in electrons overflows a float is masked bad too, as
 * a NaN is. */
int mp_frame_read(const char *name, const mp_datapars *dp, mp_frame *f, char *err);
void mp_frame_free(mp_frame *f);

/* An output file written atomically: data go to a temporary file beside the
 * final one, renamed on commit and removed on abort, so a failed run leaves
 * no partial output.  A path of "-" or NULL means stdout (no renaming). */
typedef struct {
    FILE *fp;
    int is_stdout;
    char *final_path;
    char *tmp_path;
} mp_outfile;

int mp_out_open(mp_outfile *o, const char *path, char *err);
int mp_out_commit(mp_outfile *o, char *err);   /* flush, close, rename */
void mp_out_abort(mp_outfile *o);              /* close, unlink temporary */

/* mp_out_copy: the bytes of file from written atomically to path to (a
 * table already formatted once: the pipeline's root.cat when it is
 * root.fit's text).  0, or nonzero with err naming the file. */
int mp_out_copy(const char *from, const char *to, char *err);

/* A run's input files, each stat'ed once as it is added (an @list of
 * thousands of frames is asked once per output, not once per pair):
 * mp_inputs_add takes a cfitsio name (read as mp_fits_local_file reads
 * it: a file:// URL is its path; "-", empty, INDEF, other URLs, a frame's
 * own "[DQ]" and names of no file are skipped) and keeps the pointer for messages, so name must outlive s;
 * 1 when out of memory (or s NULL).  mp_out_overwrites: 1 with err
 * naming both when output path is an existing file that is one of s's,
 * told by device and inode, so another spelling or a link of it is
 * caught too; 0 otherwise.  A task asks before it writes each output:
 * `find f.fits output=f.fits` wrote its table over the frame, as `fit
 * f.fits f.coo output=f.coo` over its coordinates (IRAF refuses an
 * output that exists; here outputs are replaced, inputs never). */
typedef struct mp_inputs mp_inputs;
mp_inputs *mp_inputs_new(void);          /* NULL when out of memory */
mp_inputs *mp_inputs_of(const char *const *names, size_t n);   /* each added; NULL: OOM */
int mp_inputs_add(mp_inputs *s, const char *name);
void mp_inputs_free(mp_inputs *s);
int mp_out_overwrites(const mp_inputs *s, const char *path, char *err);
/* mp_outputs_clear: mp_out_overwrites of each of out[0..nout) against the
 * inputs in[0..nin); 1 with err at the first that is one (or when out of
 * memory), 0 otherwise. */
int mp_outputs_clear(const char *const *in, size_t nin, const char *const *out, size_t nout,
                     char *err);

/* mp_out_fits_named: 0, or 1 with err naming parameter param when the
 * FITS output it names, path, is "-" (text tables go to standard output
 * by that name, a FITS file cannot, and its writers made a file named
 * "-") or holds '[' (written as named, `sim o[1].fits`, it could not be
 * read back: cfitsio takes o.fits's extension 1). */
int mp_out_fits_named(const char *param, const char *path, char *err);

/* mp_out_in_place: whether output path is written in place rather than
 * replaced: an existing device, FIFO or socket, or a name under /dev/ or
 * /proc/ (/dev/stdout, /dev/fd/N).  Renamed over, `output=/dev/null` run
 * as root replaced the system's /dev/null with a regular file; as
 * another user it could not create its temporary beside it.
 * mp_out_place: the finished temporary tmp put at path: renamed there
 * (atomic), or for an output written in place its bytes appended to
 * path and tmp removed; 0, or 1 with err (when not NULL) naming path and
 * what failed: the rename, or the write into it. */
int mp_out_in_place(const char *path);
int mp_out_place(const char *tmp, const char *path, char *err);

/* mp_tmp_name: the temporary name used for path, "<dir>/.<base>.tmp.<host>.<pid>"
 * (an output written in place: <dir> is $TMPDIR, else /tmp; caller frees;
 * NULL when out of memory).  A name only: the temporaries
 * of killed runs are swept by mp_tmp_sweep. */
char *mp_tmp_name(const char *path);

/* Killed runs' temporaries.  SIGKILL cannot be caught (cleanup.c's
 * handler never runs: a node's OOM killer, a job's time limit), so a
 * task sweeps the directory of each output before writing it:
 * mp_tmp_sweep removes from the directory of path's temporaries (its own;
 * TMPDIR for an output written in place) every temporary that a run
 * on this host left (".<base>.tmp.<host>.<pid>", any base, the pid no
 * longer alive), so a resubmitted job leaves its directory as a clean
 * run does.  Another host's temporaries (a shared file system) and live
 * runs' are left alone.  Once per directory per run (issue 14: listing
 * the directory at every write made a survey's thousands of outputs in
 * one folder O(N²)): s is the set of directories the run (a task's
 * invocation, every frame of an @list) has swept; a directory already in
 * it is not listed again.  s NULL: list it every time.  path "-" or ""
 * (stdout, none): nothing.  Returns 1 when the directory was listed, 0
 * otherwise.  mp_sweeps_listed counts the listings a set has made (for
 * tests: counts, not times). */
typedef struct mp_sweeps mp_sweeps;
mp_sweeps *mp_sweeps_new(void);       /* NULL when out of memory */
void mp_sweeps_free(mp_sweeps *s);
int mp_tmp_sweep(mp_sweeps *s, const char *path);
long mp_sweeps_listed(const mp_sweeps *s);

/* Interrupted runs (io/cleanup.c).  The writers above (and the FITS table
 * writer) register each temporary before creating it and unregister it
 * once renamed or removed.  mp_cleanup_install, called once by main(),
 * installs a handler for SIGINT, SIGTERM, SIGHUP and SIGQUIT (not for a
 * signal already ignored, as under nohup) that unlinks every registered
 * temporary, then dies of the signal: an interrupted run leaves no
 * half-written file.  The registry is the one documented piece of global
 * mutable state: a fixed array of lock-free atomic pointers, so the handler
 * is async-signal-safe.  mp_tmp_register returns nonzero when it is full
 * or out of memory (the write may go on unprotected); mp_tmp_live counts
 * the registered names (for tests); mp_tmp_unlink_all is what the handler
 * does. */
int mp_tmp_register(const char *path);
void mp_tmp_unregister(const char *path);
int mp_tmp_live(void);
void mp_tmp_unlink_all(void);
int mp_cleanup_install(void);

/* mp_name_after: an output named after an image, as DAOPHOT and IRAF name
 * theirs: the image name without its [extension or section] and without a
 * .fits/.fit/.fts ending, then ext ("f.fits[1]", ".coo" → "f.coo").  The
 * caller frees; NULL when out of memory. */
char *mp_name_after(const char *image, const char *ext);

/* mp_fits_guard_file / mp_fits_guard_mem: look at a FITS file (a
 * file:// URL's too) or at bytes in memory before cfitsio parses them,
 * and return 1 with why (MP_GUARD_LEN bytes; the file's name not in it)
 * when cfitsio would abort or run away on it:
 *  - standard input ("-", "-[1]", "stdin://") and other URLs: no walk
 *    sees their bytes first (`cat bad.fits | matphot find -` aborted);
 *  - a structural string keyword (XTENSION, EXTNAME, TFORMn, TTYPEn, TUNITn,
 *    TDISPn, TDIMn) whose value is not a well-formed quoted string:
 *    cfitsio 4.2.0 overflows a buffer and aborts on such a card.  Plain
 *    files', gzip files' (as zlib inflates them: once more than cfitsio
 *    does) and memory's headers are walked; PKZIP files', which cfitsio
 *    4.2 does not open as FITS, are not;
 *  - a gzip or PKZIP file stating an uncompressed size more than deflate
 *    can make of its bytes (1032:1): cfitsio allocates that size first;
 *  - a gzip or PKZIP file whose path holds ".Z" or ".bz2" (a folder's name
 *    too): cfitsio inflates it as Unix compress or bzip2 and fails;
 *  - a tile-compressed image HDU (ZIMAGE = T, fpack's .fz) in a plain or
 *    gzip file: cfitsio divides by its tiling as it moves there (an FPE on a
 *    ZTILE of 0) and its decoders read past a corrupt tile (mp_fits_refuse_tiled
 *    refuses what the walk does not see).
 * 0 otherwise. */
#define MP_GUARD_LEN 160
int mp_fits_guard_file(const char *name, char *why);
int mp_fits_guard_mem(const void *b, size_t n, char *why);

/* mp_fits_local_file: the local file a cfitsio name reads (cfitsio's own
 * parse of its [extension], section and (copy) parts; a file:// URL's
 * path) into path (len bytes): 0; 1 with why (MP_GUARD_LEN) for standard
 * input ("-", "-[1]", "stdin://") and other URLs; −1 for a name cfitsio
 * cannot parse or a path longer than len. */
int mp_fits_local_file(const char *name, char *path, size_t len, char *why);

/* mp_fits_guard_named: mp_fits_guard_file on path, its refusal written to
 * err (MP_ERRLEN) as "name: why", the way readers report a file; 1 when
 * refused, 0 otherwise. */
int mp_fits_guard_named(const char *path, const char *name, char *err);

/* mp_fits_refuse_tiled: 0 unless fp's current HDU is a tile-compressed image
 * (fpack's .fz), which cfitsio would expand with decoders that do not
 * hold a corrupt tile to its bytes (tests/fuzz found a RICE_1 crash, a
 * GZIP tile growing for 20 s and more, a leak); then 1, with "name: ..."
 * naming its ZCMPTYPE in err (MP_ERRLEN).  fp is a fitsfile *. */
int mp_fits_refuse_tiled(void *fp, const char *name, char *err);

/* mp_fits_key_number: the value of keyword key of fp's current HDU as a
 * number, parsed here from the card's value (fits_read_keyword), so that
 * cfitsio never converts it: cfitsio 4.2.0 overflows a buffer in ffc2j
 * (and glibc aborts) while writing the error message for a long value
 * that is not a number (found by tests/fuzz: "NYPSFS  = ZZZZ...").  0 and
 * *v on a number (quoted too, as cfitsio reads one; D exponents as E);
 * KEY_NO_EXIST when absent; BAD_C2D when the value is not a number (other
 * strings, a logical, garbage).  *status as cfitsio's: nothing
 * is done when it is nonzero on entry.  fp is a fitsfile * (void here:
 * this header does not include cfitsio's). */
int mp_fits_key_number(void *fp, const char *key, double *v, int *status);

/* A piece of work handed to threads: its cost (stars to fit, say) and
 * its index. */
typedef struct {
    size_t cost, i;
} mp_work_item;

/* mp_costliest_first: w[0..n) sorted by cost, largest first, ties by
 * index: the order to hand work out in (schedule dynamic), so that a long
 * piece does not start last and keep the others waiting at the end. */
void mp_costliest_first(mp_work_item *w, size_t n);

/* mp_select_kth: the k-th smallest of v[0..n) (k < n), with v rearranged
 * so that v[0..k) ≤ v[k] ≤ v[k+1..n) (quickselect, median-of-three pivot,
 * branch-free partitions; linear time on average).  For finite values. */
double mp_select_kth(double *v, size_t n, size_t k);

/* mp_median_select: the median of v[0..n) (the mean of the middle two for
 * even n) by mp_select_kth, v left permuted, not sorted; NaN when n = 0. */
double mp_median_select(double *v, size_t n);

/* mp_mad_sigma: 1.4826 times the median absolute deviation of v[0..n)
 * from its median, the σ of a Gaussian robust to outliers (v
 * overwritten); NaN when n = 0. */
double mp_mad_sigma(double *v, size_t n);

/* mp_within: hypot(dx, dy) <= r, the same answer always, with hypot
 * only where the squared distance lies within 1e-9 of r² (elsewhere its
 * side is certain: hypot errs by an ulp), or where a square is not
 * finite or r is negative.  Inline: it is called on every row of a
 * table and every pixel of a window. */
static inline int mp_within(double dx, double dy, double r)
{
    double d2 = dx * dx + dy * dy, r2 = r * r;
    if (isfinite(d2) && isfinite(r2) && r >= 0) {
        if (d2 < r2 * (1.0 - 1e-9))
            return 1;
        if (d2 > r2 * (1.0 + 1e-9))
            return 0;
    }
    return hypot(dx, dy) <= r;
}

/* mp_seconds: monotonic wall-clock seconds (differences only). */
double mp_seconds(void);

/* mp_open_input: open a file for reading, "-" meaning stdin. */
FILE *mp_open_input(const char *path, char *err);
void mp_close_input(FILE *fp);

#endif
