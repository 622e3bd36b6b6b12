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
    size_t ccap;              /* columns allocated in cols */
    mp_col *cols;
    double *v;                /* v[row*ncol + col] */
} mp_table;

typedef enum { MP_TAB_ASCII_HEAD, MP_TAB_CSV,
               MP_TAB_FITS, MP_TAB_LDAC /* added: see the FITS section below */ } mp_table_format;

void mp_table_init(mp_table *t);
void mp_table_free(mp_table *t);

/* mp_table_add_col: add a column (values NaN in existing rows) and return its
 * index, or the existing index if the name is already there; -1 when out of
 * memory (and, added: when name is empty or longer than 31 characters).
 * Description, unit and format come from the registry of known names. */
int mp_table_add_col(mp_table *t, const char *name);

/* mp_table_add_cols: the columns names[0..n-1] added at once (one
 * re-layout of the rows instead of n), each's index in idx[k] (an existing
 * column's own); 0, or -1 when out of memory or a name is bad (then no
 * column is added).  Adding columns leaves the rows' block exactly nrow
 * long, and grows it in place (issue 14: the peak is the new table, not
 * the old and the new side by side). */
int mp_table_add_cols(mp_table *t, const char *const *names, int n, int *idx);

/* mp_table_shrink: the rows' block cut to nrow rows (after rows were
 * dropped or appended: appending doubles it); 0, or -1 when out of memory
 * (the table unchanged). */
int mp_table_shrink(mp_table *t);

/* mp_table_reserve: room for at least rows rows (the rows' block grown,
 * its values as they were; nrow unchanged), so that a copy of known size
 * is one allocation; 0, or -1 when out of memory (the table unchanged). */
int mp_table_reserve(mp_table *t, size_t rows);

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

/* A table's ASCII_HEAD rows as mp_table_write_kept last wrote them. */
typedef struct mp_text_kept mp_text_kept;

/* mp_table_write_kept: mp_table_write, the same bytes, for tables written
 * one after another with the same columns (root.grp, then root.fit), or
 * with prev's columns first and more after (root.fit, then root.cat with
 * sky positions): a row whose NUMBER prev (NULL: none) holds with the same
 * values in prev's columns, bit for bit, is copied from there rather than
 * formatted again (its columns after, formatted).  With keep, *keep
 * then holds t's rows (a copy of its values and its text; NULL unless
 * ASCII_HEAD, and unless their text fits 16 MiB at 12 bytes a value: a
 * large frame's tables are formatted again, for its peak RSS) until
 * mp_text_kept_free. */
int mp_table_write_kept(const char *path, const mp_table *t, mp_table_format fmt,
                        const mp_text_kept *prev, mp_text_kept **keep, char *err);
void mp_text_kept_free(mp_text_kept *k);

/* mp_table_format_parse: "ascii_head"/"csv" (case-insensitive) → format;
 * nonzero when unknown. */
int mp_table_format_parse(const char *s, mp_table_format *fmt);

/* ==== WCS: sky positions through WCSLIB (catalog/wcs.c) ==================
 *
 * Added for "ALPHAPSF_J2000/DELTAPSF_J2000 through WCSLIB".  Every WCS is
 * read and evaluated by WCSLIB (>= 7.5; Debian has 7.12): wcspih() with
 * WCSHDR_all reads the image's header cards (im->hdr), wcsfix() repairs
 * common non-standard forms, wcsset() sets the struct up once, and
 * wcsp2s()/wcss2p() do the transformations.  Distortions are WCSLIB's own:
 * TAN-SIP (A_p_q/B_p_q, AP_p_q/BP_p_q), TPV (PVi_m on RA---TPV) and IRAF's
 * TNX (WATi_nnn lngcor/latcor surfaces; wcspih translates them into a TPD
 * sequent distortion), plus DSS and ZPX.  matphot adds no distortion code
 * of its own.
 *
 * Which WCS: the primary one (alternate code ' ').  An alternate WCS
 * ("...O", "...A") is used only when the header has no primary one.  The
 * celestial axes must be the image's first two axes (a cube plane read with
 * a section keeps its header; the other axes are dropped with wcssub()).
 * Repairs: wcsfix's cdfix and unitfix always, celfix for NCP/GLS, cylfix
 * for cylindrical projections; a CD/PC matrix that is singular is refused
 * (WCSLIB itself only notices a row of zeros).
 *
 * Coordinates: pixels are 1-based FITS pixels, (1.0, 1.0) being the centre
 * of the first pixel (WCSLIB's convention, and matphot's).  Sky coordinates
 * are degrees in the header's own celestial frame (ICRS, FK5 J2000, ...,
 * or Galactic for GLON/GLAT), see mp_wcs_frame().  mp_wcs_pix2j2000()
 * and mp_table_add_sky() give J2000 equatorial coordinates: ICRS and FK5
 * J2000 as they are (they differ by < 25 mas, which matphot ignores),
 * Galactic rotated to ICRS (the Hipparcos definition of the Galactic pole,
 * ESA 1997 vol. 1 sec. 1.5.3; astropy, which goes through FK4/FK5, differs
 * by about 25 mas); any other frame (FK4, another equinox, ecliptic, ...)
 * is an error.
 *
 * Thread safety: WCSLIB's wcsp2s()/wcss2p() are not safe on one shared
 * wcsprm even after wcsset(): they write into scratch memory inside it
 * (linprm::tmpcrd, disprm::tmpmem) when there is a distortion, and into
 * wcsprm::err on failure (a shared wcsprm was seen to give wrong TPV
 * results from 8 threads).  So an mp_wcs holds several deep copies (as
 * many as OpenMP threads or processors at open time, at most 256; made by
 * wcssub() and set up by wcsset() in mp_wcs_open), each behind its own
 * mutex; a call takes a free copy
 * (trylock, starting with the calling OpenMP thread's own), waiting only
 * when every copy is busy.  mp_wcs_pix2sky, mp_wcs_sky2pix and
 * mp_wcs_pix2j2000 are therefore safe to call concurrently on one mp_wcs
 * from any number of threads (OpenMP or not); they never allocate.
 * mp_wcs_open is safe to call concurrently (WCSLIB >= 7.5's header parser
 * is reentrant); mp_wcs_close must not run while others use the mp_wcs.
 *
 * Errors: 0 on success; otherwise one line in err (MP_ERRLEN bytes)
 * saying what is wrong in words, without the file name (the caller knows
 * it and prefixes it).  The transformations return MP_WCS_BADCOORD when
 * only that point has no valid result (outside the projection's domain,
 * the distortion's inversion failed, NaN in), with the outputs set to NaN.
 */
typedef struct mp_wcs mp_wcs;   /* opaque: WCSLIB wcsprm copies + locks */

#define MP_WCS_BADCOORD 1       /* this point has no valid transformation */
#define MP_WCS_FAIL     2       /* anything else (unset struct, locks) */

/* mp_wcs_open: the celestial WCS of im's header (im->hdr, im->nkeys; im->nx
 * and im->ny are used by wcsfix's cylindrical fix).  On failure *w is NULL
 * and err says why: no WCS cards, no celestial axes (naming CTYPEs), a
 * WCS that WCSLIB rejects (singular matrix, unknown projection, bad
 * distortion parameters, ...), out of memory. */
int  mp_wcs_open(const mp_image *im, mp_wcs **w, char *err);

/* mp_wcs_pix2sky: 1-based FITS pixel (x, y) -> (ra, dec) in degrees, in the
 * header's celestial frame (longitude in [0, 360)). */
int  mp_wcs_pix2sky(const mp_wcs *w, double x, double y, double *ra, double *dec, char *err);

/* mp_wcs_sky2pix: the inverse, degrees in the header's frame -> 1-based
 * FITS pixel.  Distortions are inverted iteratively by WCSLIB (SIP uses
 * AP/BP as the first guess); the round trip is good to well under 1e-6 px. */
int  mp_wcs_sky2pix(const mp_wcs *w, double ra, double dec, double *x, double *y, char *err);

/* mp_wcs_pix2j2000: like mp_wcs_pix2sky, but J2000 equatorial (ICRS) as
 * described above; MP_WCS_FAIL when the frame cannot be converted. */
int  mp_wcs_pix2j2000(const mp_wcs *w, double x, double y, double *ra, double *dec, char *err);

/* mp_wcs_frame: the header's celestial frame in DS9's words, for messages
 * and region files: "icrs", "fk5", "fk4", "fk4-no-e", "gappt", "galactic",
 * "ecliptic", "supergalactic", "helioecliptic", or WCSLIB's longitude type
 * (e.g. "xLON") for anything else.  mp_wcs_equinox: EQUINOX in years, NaN
 * when the header gives none. */
const char *mp_wcs_frame(const mp_wcs *w);
double mp_wcs_equinox(const mp_wcs *w);

/* mp_wcs_close: free; NULL is fine. */
void mp_wcs_close(mp_wcs *w);

/* mp_table_add_sky: add ALPHAPSF_J2000/DELTAPSF_J2000 [deg] computed from
 * XPSF_IMAGE/YPSF_IMAGE, and ALPHA_J2000/DELTA_J2000 [deg] from
 * X_IMAGE/Y_IMAGE, for whichever of the two position pairs the table has
 * (columns already there are overwritten).  Rows whose position is NaN or
 * has no valid sky position get NaN.  Errors: neither pair present, no
 * usable celestial WCS in im's header, a frame that cannot be turned into
 * J2000, out of memory.  Every position is computed before any column is
 * added, so a failure leaves the table as it was (except when memory runs
 * out while adding the columns: they may then be there, NaN-filled).  Rows
 * are converted in parallel (OpenMP).  The catalog task calls this. */
int  mp_table_add_sky(mp_table *t, const mp_image *im, char *err);

/* ==== end of WCS section ================================================= */

/* ==== FITS tables, FITS_LDAC, DS9 regions, the catalog task ==============
 * (catalog/fits_table.c, catalog/ldac.c, catalog/regions.c,
 * catalog/task_catalog.c; anchors.md §2.3, checked against SExtractor's own
 * FITS_1.0 and FITS_LDAC output)
 *
 * MP_TAB_FITS is SExtractor's FITS_1.0: an empty primary HDU, then one
 * BINTABLE EXTNAME='OBJECTS'.  MP_TAB_LDAC is FITS_LDAC: an empty primary
 * HDU, a one-row BINTABLE EXTNAME='LDAC_IMHEAD' with one column
 * 'Field Header Card' (TFORM '<80n>A', TDIM '(80, n)') holding n header
 * cards, the last one END, then BINTABLE EXTNAME='LDAC_OBJECTS'.
 *
 * Object tables: TTYPE = column name (its comment the description), TUNIT =
 * unit, TDISP from the column's printf format.  Integer columns (mp_col
 * is_int, all values integral) are J, or K beyond 32 bits; FLAGS is I, as
 * SExtractor writes it, because SCAMP and PSFEx read FLAGS through a 16-bit
 * pointer.  Every other column is D, so positions and fluxes keep full
 * double precision.  NaN stays NaN in D columns; an integer column holding
 * NaN gets TNULL = the type's smallest value.
 *
 * mp_table_format_parse also takes "fits" / "fits_1.0" and "ldac" /
 * "fits_ldac".  mp_table_write with a FITS format and path "-" or NULL is an
 * error (FITS needs a file); MP_TAB_LDAC there gets the minimal header of
 * mp_ldac_cards.  mp_table_read also reads FITS (told by "SIMPLE  =" at the
 * start, from a file or stdin): the first HDU named LDAC_OBJECTS, else
 * OBJECTS, else the first binary table; its scalar numeric columns (vector,
 * string and logical columns are skipped; integer TNULL reads as NaN). */

/* The LDAC_IMHEAD contents: an image's header cards, plus keywords to set
 * in it (SExtractor's SEXGAIN, SEXBKDEV, ... which PSFEx looks up there). */
typedef struct {
    const char *cards;     /* ncards 80-character cards (mp_image.hdr; an
                              END card, if any, ends them); NULL: minimal */
    int ncards;
    const mp_card *extra;  /* set these (replacing a card of the same key) */
    int nextra;
} mp_ldac_head;

/* mp_ldac_cards: the card block of LDAC_IMHEAD: h's cards (or, without
 * any, the minimal SIMPLE = T, BITPIX = 8, NAXIS = 0), each extra keyword
 * replacing a card of its key or appended (a non-finite number is left
 * out), then END.  *cards (80 * *ncards chars, NUL after) is the caller's
 * to free.  Errors: a malformed extra keyword, out of memory. */
int mp_ldac_cards(const mp_ldac_head *h, char **cards, int *ncards, char *err);

/* mp_table_write_fits: write t as FITS_1.0 (ldac NULL) or FITS_LDAC with
 * the header ldac describes, atomically (temporary name beside path,
 * renamed at the end, removed on failure).  Errors: no file name or "-",
 * no columns, more than 999 columns, cfitsio failures. */
int mp_table_write_fits(const char *path, const mp_table *t, const mp_ldac_head *ldac,
                        char *err);

/* mp_table_read_fits: read a FITS table (as described above) from the file
 * name (a cfitsio extended name) or, when mem is not NULL, from the len
 * bytes at mem, name then only naming it in messages.  t is set up by the
 * call and left empty on failure. */
int mp_table_read_fits(const char *name, const void *mem, size_t len, mp_table *t, char *err);

/* DS9 regions (version 4.1): one circle per row, "image" coordinates from
 * XPSF_IMAGE/YPSF_IMAGE (else X_IMAGE/Y_IMAGE), or "fk5" from
 * ALPHAPSF_J2000/DELTAPSF_J2000 (else ALPHA_J2000/DELTA_J2000); green when
 * FLAGS is 0 or absent, red otherwise; text={NUMBER} when asked and NUMBER
 * exists.  Rows without a finite position are left out. */
typedef struct {
    double radius;   /* pixels ("image") or arcsec ("fk5") */
    int fk5;         /* 0: image, 1: fk5 */
    int label;       /* write text={NUMBER} */
} mp_region_opts;

/* mp_regions_write: write the region file atomically ("-": stdout).
 * Errors: the position columns are missing, radius not positive, I/O.
 * *nwritten (may be NULL) gets the number of circles. */
int mp_regions_write(const char *path, const mp_table *t, const mp_region_opts *o,
                     long *nwritten, char *err);

/* The `matphot catalog` task (params/catalog.par). */
int mp_task_catalog(int argc, char **argv);

/* ==== end of FITS / regions / catalog task section ======================= */

/* ==== Survey merge (catalog/merge.c, merge_frame.c, task_merge.c) ========
 *
 * Many frames' (or tiles') catalogs merged on the sky into one survey
 * catalog.  Sky positions are the catalogs' ALPHAPSF_J2000/DELTAPSF_J2000
 * (else ALPHA_J2000/DELTA_J2000), which `matphot catalog`/`pipeline` write
 * through WCSLIB from the frame's WCS.  A detection's position error on the
 * sky (east, north) is its ERRX_PSF/ERRY_PSF carried through its catalog's
 * own pixel-to-sky Jacobian (a least-squares affine fit of the catalog's
 * sky positions on its pixel positions), plus syserr in quadrature (the
 * frames' WCS registration).
 *
 * The match rule: a detection and a source are one star when
 *   Δe²/(σe_d² + σe_s²) + Δn²/(σn_d² + σn_s²) <= nsigma²
 * (Δ the offsets east and north from the source's current mean, σ_s the
 * mean's errors) and they are less than maxrad apart.  For one star that
 * sum is χ² with 2 degrees of freedom, so nsigma = 5 splits a star by
 * mistake with probability exp(-12.5) = 3.7e-6 per detection.  A frame
 * gives a source one detection at most (its detections are stars it
 * resolved); within a frame, pairs are taken in increasing order of that
 * sum, so the result does not depend on the order of a catalog's rows.
 * Frames are merged in the order given.  Sources are found through a hash
 * of cells of 2 maxrad on the unit sphere, so the cost is linear in the
 * number of detections.
 *
 * A source's position is the weighted mean (weights 1/σ², east and north
 * apart) in the tangent plane at its first detection, with errors
 * 1/sqrt(Σ 1/σ²); its magnitude the weighted mean of MAG_PSF (weights
 * 1/MAGERR_PSF²; the catalogs' own zero points: calibrate each with
 * `matphot catalog magzero=` first, which writes a MAGZERO column; a mix
 * of calibrated and instrumental catalogs is an error naming one of each),
 * with MAGERR_MEAN = 1/sqrt(Σw) and
 * MAG_CHI2 the reduced χ² of its magnitudes about the mean (≈ 1 for a
 * constant star with right errors).  NDET counts its detections; FLAGS ORs
 * theirs.
 *
 * Tables: sources (SOURCE_ID, ALPHA_J2000, DELTA_J2000, ERRRA_ARCSEC,
 * ERRDEC_ARCSEC, MAG_MEAN, MAGERR_MEAN, MAG_CHI2, NDET, FLAGS) and
 * detections, one row per detection (SOURCE_ID, FRAME (1-based, in the
 * order given), NUMBER, XPSF_IMAGE, YPSF_IMAGE, ALPHAPSF_J2000,
 * DELTAPSF_J2000, ERRRA_ARCSEC, ERRDEC_ARCSEC, MAG_PSF, MAGERR_PSF,
 * FLUX_PSF, FLUXERR_PSF, FLAGS, SEP_ARCSEC from the source's mean), sorted
 * by source then frame. */
typedef struct {
    double nsigma;     /* match threshold on the normalised separation */
    double syserr;     /* [arcsec] added in quadrature to every position error */
    double maxrad;     /* [arcsec] never match farther apart */
    double pixscale;   /* [arcsec] for a catalog of fewer than 3 stars; NaN: none */
} mp_merge_opts;

typedef struct mp_merge mp_merge;   /* opaque */

/* mp_merge_new: an empty merge; NULL when out of memory. */
mp_merge *mp_merge_new(const mp_merge_opts *o);

/* mp_merge_add: the next frame's catalog (name for messages).  Rows
 * without a finite sky position or position errors are skipped (counted in
 * *skipped when not NULL).  Errors: a missing column, too few stars for
 * the pixel scale without pixscale, out of memory. */
int mp_merge_add(mp_merge *m, const mp_table *cat, const char *name, long *skipped, char *err);

/* mp_merge_tables: the sources and detections tables (see above). */
int mp_merge_tables(const mp_merge *m, mp_table *sources, mp_table *dets, char *err);

void mp_merge_free(mp_merge *m);

/* The `matphot merge` task. */
int mp_task_merge(int argc, char **argv);

#endif
