/* no_star.c — why a frame holds no star to find (find.h mp_find_why_none):
 * a frame with no usable star is bad input (one line, exit 1), and the
 * line says which of its faults it is, with the gain where that can be
 * it (a header GAIN of 1e300 overflows every pixel, one of 1e-320
 * rounds every pixel to 0 electrons). */
#include <math.h>
#include <stdio.h>
#include "find/find.h"

int mp_find_why_none(const mp_frame *f, const mp_bkg *b, double threshold, char *why,
                     size_t n)
{
    long nx = f->im.nx, ny = f->im.ny, npix = nx * ny, good = 0;
    double rms = 0.0;
    for (long i = 0; i < npix; i++)
        if (!f->mask || !f->mask[i]) {
            good++;
            if (b && rms <= 0.0)    /* one pixel of noise says enough */
                rms = mp_bkg_rms(b, (size_t)i);
        }
    if (good == 0 && f->nsat > 0)
        snprintf(why, n, "no good pixel (%ld of its %ld x %ld at or above saturate %g ADU, the "
                 "rest NaN, blank or masked)", f->nsat, nx, ny, f->saturate);
    else if (good == 0)
        snprintf(why, n, "no good pixel (every one of its %ld x %ld is NaN, blank, masked or "
                 "saturated, or in electrons at gain %g beyond a float's range)", nx, ny, f->gain);
    else if (good < 4)
        snprintf(why, n, "%ld good pixel%s of %ld x %ld, fewer than a star's 4 parameters (flux, "
                 "x, y, sky)", good, good == 1 ? "" : "s", nx, ny);
    else if (b && rms <= 0.0)
        snprintf(why, n, "its noise is 0 on every good pixel (a constant frame in electrons at "
                 "gain %g, %ld x %ld)", f->gain, nx, ny);
    else {
        snprintf(why, n, "no source above threshold %g sigma of the kernel's amplitude "
                 "(%ld good pixels of %ld x %ld)", threshold, good, nx, ny);
        return 0;
    }
    return 1;
}
