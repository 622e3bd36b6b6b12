/*
 * fitserr.h — private to io/: turn a cfitsio status into the one-line
 * "<file>: <what is wrong>" message of io.h.
 */
#ifndef MATPHOT_IO_FITSERR_H
#define MATPHOT_IO_FITSERR_H

#include "io/io.h"

/* mp_fits_error: write "<name>: <what>" for a failed cfitsio call into err
 * (MP_ERRLEN bytes).  when says what was being done ("open", "read",
 * "write") and picks the wording; for a failed open the file itself is
 * looked at, so a missing, empty or non-FITS file is named as such.  Clears
 * cfitsio's message stack. */
void mp_fits_error(const char *name, const char *when, int status, char *err);

/* mp_fits_write_cards: the cards into fp's current HDU as mp_image_write
 * writes them (io.h: integers as integers, the shortest exact decimal
 * otherwise, non-finite values left out); returns *status.  fp is a
 * fitsfile * (void here: this header does not include cfitsio's). */
int mp_fits_write_cards(void *fp, const mp_card *cards, int ncards, int *status);

#endif
