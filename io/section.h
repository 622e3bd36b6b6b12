/*
 * section.h — private to io/: IRAF-style image sections for cfitsio.
 */
#ifndef MATPHOT_IO_SECTION_H
#define MATPHOT_IO_SECTION_H

/* mp_section_name: a copy of name (caller frees) in which a single pixel
 * index in an image section becomes a range, "f.fits[*,*,2]" →
 * "f.fits[*,*,2:2]": IRAF and users write the former, cfitsio accepts only
 * the latter.  Other names are copied unchanged.  NULL when out of memory. */
char *mp_section_name(const char *name);

#endif
