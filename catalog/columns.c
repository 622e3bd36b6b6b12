/*
 * columns.c — the registry of known columns (design.md §4 plus the
 * simulator's truth columns) and the value parsing/printing shared by the
 * formats.
 *
 * Names, descriptions and units follow SExtractor (src/param.h) where the
 * column means the same thing; fluxes are in electrons, so their unit is
 * [electron] where SExtractor says [count].  Print formats keep full useful
 * precision: positions to 1e-5 pixel, fluxes to 7 significant digits
 * (SExtractor's %12.7g).  Integer columns use "%N.0f" because values are
 * held as doubles; that never overflows, whatever the value.
 */
#define __STDC_WANT_IEC_60559_BFP_EXT__ 1   /* strfromd (ISO/IEC TS 18661-1, C23) */
#include <ctype.h>
#include <math.h>
#include <stdlib.h>
#include <string.h>
#include <strings.h>

#include "catalog/table_priv.h"

#define PIX  "pixel"
#define ELEC "electron"

static const mp_col registry[] = {
    /* find */
    {"NUMBER",         "Running object number",                      "",   "%10.0f", 1},
    {"X_IMAGE",        "Object position along x",                    PIX,  "%11.5f", 0},
    {"Y_IMAGE",        "Object position along y",                    PIX,  "%11.5f", 0},
    {"FLUX",           "First flux estimate from detection",         ELEC, "%12.7g", 0},
    {"FLUX_MAX",       "Peak flux above background",                 ELEC, "%12.7g", 0},
    {"BACKGROUND",     "Background at centroid position",            ELEC, "%12.7g", 0},
    {"SHARPNESS",      "Sharpness statistic from detection (DAOFIND)", "", "%9.5f",  0},
    {"ROUNDNESS",      "Roundness statistic from detection (DAOFIND)", "", "%9.5f",  0},
    /* group */
    {"GROUP_ID",       "Group number",                               "",   "%10.0f", 1},
    {"GROUP_SIZE",     "Number of stars in the group",               "",   "%5.0f",  1},
    /* fit */
    {"XPSF_IMAGE",     "X coordinate from PSF-fitting",              PIX,  "%11.5f", 0},
    {"YPSF_IMAGE",     "Y coordinate from PSF-fitting",              PIX,  "%11.5f", 0},
    {"ERRX_PSF",       "RMS error of X coordinate from PSF-fitting", PIX,  "%12.7g", 0},
    {"ERRY_PSF",       "RMS error of Y coordinate from PSF-fitting", PIX,  "%12.7g", 0},
    {"FLUX_PSF",       "Flux from PSF-fitting",                      ELEC, "%12.7g", 0},
    {"FLUXERR_PSF",    "RMS flux error for PSF-fitting",             ELEC, "%12.7g", 0},
    {"MAG_PSF",        "Magnitude from PSF-fitting",                 "mag", "%9.5f", 0},
    {"MAGERR_PSF",     "RMS magnitude error from PSF-fitting",       "mag", "%10.6f", 0},
    {"MAGZERO",        "Zero point of MAG_PSF (its frame's calibration)", "mag", "%9.5f", 0},
    {"ALPHAPSF_J2000", "Right ascension of the fitted PSF (J2000)",  "deg", "%11.7f", 0},
    {"DELTAPSF_J2000", "Declination of the fitted PSF (J2000)",      "deg", "%+11.7f", 0},
    /* catalog: sky position of the detection (catalog/wcs.c) */
    {"ALPHA_J2000",    "Right ascension of barycenter (J2000)",      "deg", "%11.7f", 0},
    {"DELTA_J2000",    "Declination of barycenter (J2000)",          "deg", "%+11.7f", 0},
    {"SKY_PSF",        "Sky from PSF-fitting at the star position",  ELEC, "%12.7g", 0},
    {"SKYERR_PSF",     "RMS sky error from PSF-fitting",             ELEC, "%12.7g", 0},
    {"SKYORD_PSF",     "Order of the group's sky polynomial (0 constant)", "", "%2.0f", 1},
    {"CHI2_PSF",       "Reduced chi2 from PSF-fitting",              "",   "%10.6g", 0},
    {"DOF_PSF",        "Degrees of freedom of the group fit",        "",   "%8.0f",  1},
    {"CHI2STAR_PSF",   "Reduced chi2 over the star's own fitting disc", "", "%10.6g", 0},
    {"NITER_PSF",      "Number of iterations for PSF-fitting",       "",   "%3.0f",  1},
    {"BETA_PSF",       "Effective background area of the PRF",       "pixel**2", "%12.7g", 0},
    {"SHARP_PRF",      "Sharpness of the PRF",                       "",   "%12.7g", 0},
    {"LSCALE_PRF",     "Critical-sampling scale length of the PRF",  PIX,  "%12.7g", 0},
    {"VOLUME_PRF",     "Volume of the PRF (mean detector efficiency)", "", "%12.7g", 0},
    {"FLUXERR_MODEL",  "RMS flux error predicted by the performance model", ELEC, "%12.7g", 0},
    {"POSERR_MODEL",   "RMS position error predicted by the performance model", PIX, "%12.7g", 0},
    {"FLAGS",          "Extraction flags",                           "",   "%3.0f",  1},
    /* sim: the truth, to full double precision so that tests of the
     * fitter compare against what was simulated, not a rounded copy */
    {"FLUX_TRUE",      "True flux (simulation)",                     ELEC, "%17.10g", 0},
    {"MAG_TRUE",       "True magnitude (simulation)",                "mag", "%12.8f", 0},
    {"SKY_TRUE",       "True sky level (simulation)",                ELEC, "%17.10g", 0},
    /* merge: the survey catalog and its detections (catalog/merge.c) */
    {"SOURCE_ID",      "Source number in the merged survey catalog", "",   "%10.0f", 1},
    {"FRAME",          "Catalog (frame or tile) of the detection, 1-based", "", "%6.0f", 1},
    {"NDET",           "Number of detections merged into the source", "",  "%6.0f",  1},
    {"ERRRA_ARCSEC",   "RMS error of RA*cos(Dec)",                   "arcsec", "%10.6f", 0},
    {"ERRDEC_ARCSEC",  "RMS error of Dec",                           "arcsec", "%10.6f", 0},
    {"MAG_MEAN",       "Weighted mean of the detections' MAG_PSF",   "mag", "%9.5f", 0},
    {"MAGERR_MEAN",    "RMS error of MAG_MEAN",                      "mag", "%10.6f", 0},
    {"MAG_CHI2",       "Reduced chi2 of the detections' MAG_PSF about the mean", "", "%10.4f", 0},
    {"SEP_ARCSEC",     "Separation from the source's mean position", "arcsec", "%10.6f", 0},
};

/* Unknown columns: no description or unit, 10 significant digits. */
static const char generic_fmt[] = "%16.10g";

size_t mp_col_registry_count(void)
{
    return sizeof registry / sizeof registry[0];
}

const mp_col *mp_col_registry_at(size_t i)
{
    return i < mp_col_registry_count() ? &registry[i] : NULL;
}

const mp_col *mp_col_registry_find(const char *name)
{
    for (size_t i = 0; i < mp_col_registry_count(); i++)
        if (strcmp(registry[i].name, name) == 0)
            return &registry[i];
    return NULL;
}

int mp_col_describe(const char *name, mp_col *c)
{
    if (!name || !*name || strlen(name) >= sizeof c->name)
        return 1;
    const mp_col *k = mp_col_registry_find(name);
    if (k) {
        *c = *k;
        return 0;
    }
    memset(c, 0, sizeof *c);
    strcpy(c->name, name);
    strcpy(c->fmt, generic_fmt);
    return 0;
}

int mp_parse_value(const char *s, double *x)
{
    while (*s == ' ' || *s == '\t')
        s++;
    if (strncasecmp(s, "INDEF", 5) == 0) {   /* IRAF's missing value */
        const char *e = s + 5;
        while (*e == ' ' || *e == '\t')
            e++;
        if (*e == '\0') {
            *x = NAN;
            return 0;
        }
        return 1;
    }
    /* strtod itself takes "nan" and "NaN" in any case, and "inf". */
    char *end;
    double v = strtod(s, &end);
    if (end == s)
        return 1;
    while (*end == ' ' || *end == '\t')
        end++;
    if (*end != '\0')
        return 1;
    *x = isnan(v) ? NAN : v;   /* drop the sign of "-nan" */
    return 0;
}

/* Field width of a printf format like "%+11.7f" (0 when none). */
static int fmt_width(const char *fmt)
{
    const char *p = strchr(fmt, '%');
    if (!p)
        return 0;
    p++;
    while (*p && strchr("-+ #0", *p))
        p++;
    return atoi(p);
}

/* The number of one or two decimal digits at *s, *s moved past them;
 * −1 when none. */
static int two_digits(const char **s)
{
    if (!isdigit((unsigned char)**s))
        return -1;
    int v = *(*s)++ - '0';
    if (isdigit((unsigned char)**s))
        v = 10 * v + (*(*s)++ - '0');
    return v;
}

/* fmt "%W.Pc" (W and P of one or two digits, c one of e, f, g; no flags)
 * as its width W and the precision and conversion alone, "%.Pc", in pc
 * (room for 8); −1 for any other format.  Read by hand, a value a call:
 * strtol here was 0.7 % of frame B built's instructions. */
static int plain_width(const char *fmt, char *pc)
{
    const char *s = fmt + 1;
    if (fmt[0] != '%')
        return -1;
    int w = two_digits(&s);
    if (w < 0 || *s != '.')
        return -1;
    const char *dot = s++;
    if (two_digits(&s) < 0 || !(*s == 'e' || *s == 'f' || *s == 'g') || s[1] != '\0')
        return -1;
    pc[0] = '%';
    memcpy(pc + 1, dot, (size_t)(s - dot) + 2);        /* ".Pc" and its NUL */
    return w;
}

/* The width W of an integer column's "%W.0f", or -1 for any other
 * format (flags, another precision or conversion): plain_width's read. */
static int int_width(const char *fmt)
{
    char pc[8];
    int w = plain_width(fmt, pc);
    return w >= 0 && w < 64 && strcmp(pc, "%.0f") == 0 ? w : -1;
}

/* x as snprintf's fmt writes it, for fmt "%W.Pc" (plain_width): libc's
 * strfromd of "%.Pc", right-aligned in W.  The same characters (checked
 * on 4·10⁶ values, and in test_catalog): snprintf itself took glibc's
 * positional path for every value (the printf hooks libquadmath
 * registers, which OpenBLAS's libgfortran loads), 216 against 161 ns a
 * "%12.7g".  −1 when fmt is not plain or the text would not fit. */
static int plain_value(const char *fmt, double x, char *buf, size_t len)
{
    char pc[8];
    int w = plain_width(fmt, pc);
    if (w < 0 || (size_t)w >= len)
        return -1;
    int n = strfromd(buf, len, pc, x);
    if (n < 0 || (size_t)n >= len)
        return -1;
    if (n < w) {
        memmove(buf + (w - n), buf, (size_t)n + 1);
        memset(buf, ' ', (size_t)(w - n));
        n = w;
    }
    return n;
}

int mp_format_value(const mp_col *c, double x, char *buf, size_t len)
{
    /* %f of a huge value is long: callers give room for 330+ chars. */
    int n, w;
    /* An integral value of an integer column as an integer: the same
     * characters as "%W.0f" (every integer below 2^53 is exact in both),
     * without the float conversion's multi-precision digits (a table's
     * text was 18 % of a 5000-star frame's run). */
    if (c->is_int && fabs(x) < 9007199254740992.0 && x == floor(x) && (w = int_width(c->fmt)) >= 0)
        return snprintf(buf, len, "%*lld", w, (long long)x);
    if (isnan(x))
        n = snprintf(buf, len, "%*s", fmt_width(c->fmt), "nan");
    else {
        /* An integer column never prints "-0". */
        double v = c->is_int && x == 0 ? 0.0 : x;
        n = plain_value(c->fmt, v, buf, len);
        if (n < 0)
            n = snprintf(buf, len, c->fmt, v);
    }
    return n;
}
