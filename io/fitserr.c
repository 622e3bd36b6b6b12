/* fitserr.c — cfitsio status codes in plain words (see fitserr.h). */
#include "io/fitserr.h"

#include <errno.h>
#include <stdio.h>
#include <string.h>
#include <sys/stat.h>
#include <fitsio.h>

#include "io/io.h"

/* Why opening failed, judged from the file itself: cfitsio reports a missing
 * file, a text file and a cut header with the same few codes. */
static const char *diagnose_file(const char *name, char *buf, size_t len)
{
    char root[FLEN_FILENAME];
    int st = 0;
    if (ffrtnm((char *)name, root, &st) || root[0] == '\0')
        return NULL;
    const char *path = root;
    if (strncmp(path, "file://", 7) == 0)
        path += 7;
    struct stat sb;
    if (stat(path, &sb) != 0) {
        snprintf(buf, len, "cannot open: %s", strerror(errno));
        return buf;
    }
    if (S_ISDIR(sb.st_mode))
        return "is a directory, not a FITS file";
    FILE *fp = fopen(path, "rb");
    if (!fp) {
        snprintf(buf, len, "cannot open: %s", strerror(errno));
        return buf;
    }
    char head[10] = {0};
    size_t got = fread(head, 1, 9, fp);
    fclose(fp);
    if (sb.st_size == 0)
        return "empty file, not a FITS file";
    /* gzip and other compressed files are opened by cfitsio itself; only
     * plain files can be judged by their first card. */
    if (got == 9 && memcmp(head, "\x1f\x8b", 2) == 0)
        return NULL;
    if (got < 9 || memcmp(head, "SIMPLE  =", 9) != 0)
        return "not a FITS file (no SIMPLE card at the start)";
    return NULL;
}

static const char *status_words(int status, const char *when)
{
    switch (status) {
    case FILE_NOT_OPENED:  return "cannot open the file";
    case FILE_NOT_CREATED: return "cannot create the file";
    case WRITE_ERROR:      return "error writing the file (disk full?)";
    case END_OF_FILE:
        return strcmp(when, "open") == 0
            ? "not a FITS file (truncated or corrupt), or no such extension"
            : "truncated FITS file (the data end before the header says)";
    case READ_ERROR:
        return strcmp(when, "open") == 0
            ? "not a FITS file (truncated or corrupt)"
            : "truncated FITS file (the data end before the header says)";
    case MEMORY_ALLOCATION: return "out of memory";
    case URL_PARSE_ERROR:
        return "cannot parse the extended file name (HDU or section in [...])";
    case BAD_HDU_NUM:      return "no such HDU (extension number or EXTNAME)";
    case NOT_IMAGE:        return "the HDU holds a table, not an image";
    case NO_END: case UNKNOWN_REC: case END_JUNK: case BAD_HEADER_FILL:
    case NO_SIMPLE: case BAD_SIMPLE: case NO_BITPIX: case NO_NAXIS:
    case NO_NAXES: case BAD_NAXIS: case BAD_NAXES: case NO_XTENSION:
        return "not a FITS file (truncated or corrupt header)";
    case BAD_BITPIX:
        return "unsupported BITPIX (must be 8, 16, 32, 64, -32 or -64)";
    case BAD_PIX_NUM: case NEG_AXIS:
        return "image section outside the image";
    case NUM_OVERFLOW:     return "pixel value out of range for the data type";
    default:               return NULL;
    }
}

/* cfitsio's own first message, for the cases its status code hides (a
 * section beyond the image reports "illegal NAXIS"). */
static const char *section_problem(void)
{
    char msg[FLEN_ERRMSG];
    while (fits_read_errmsg(msg)) {
        if (strstr(msg, "section exceeds"))
            return "image section outside the image";
        if (strstr(msg, "image section"))
            return "cannot parse the image section in [...]";
    }
    return NULL;
}

void mp_fits_error(const char *name, const char *when, int status, char *err)
{
    char buf[256];
    const char *what = NULL;
    if (strcmp(when, "open") == 0 && name && strchr(name, '['))
        what = section_problem();
    if (!what && strcmp(when, "open") == 0 && status != URL_PARSE_ERROR &&
        status != BAD_HDU_NUM && status != NOT_IMAGE)
        what = diagnose_file(name, buf, sizeof buf);
    if (!what && strcmp(when, "open") == 0 && status == END_OF_FILE &&
        name && strchr(name, '['))
        what = "no such HDU (extension number or EXTNAME)";
    if (!what)
        what = status_words(status, when);
    if (!what) {
        char txt[FLEN_STATUS];
        fits_get_errstatus(status, txt);
        snprintf(buf, sizeof buf, "cannot %s: %s (cfitsio status %d)",
                 when, txt, status);
        what = buf;
    }
    snprintf(err, MP_ERRLEN, "%s: %s", name ? name : "(null)", what);
    fits_clear_errmsg();
}
