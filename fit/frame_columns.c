/* frame_columns.c — the fit's output columns of a table. */

#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include "fit/frame_priv.h"

/* Write the fit's columns; drop rows of merged-away or rejected stars. */
int ff_write_columns(mp_table *t, const star_state *st, size_t n, double magzero, char *err)
{
    static const char *const names[] = {
        "XPSF_IMAGE", "YPSF_IMAGE", "ERRX_PSF", "ERRY_PSF", "FLUX_PSF", "FLUXERR_PSF",
        "MAG_PSF", "MAGERR_PSF", "SKY_PSF", "SKYERR_PSF", "SKYORD_PSF", "CHI2_PSF", "DOF_PSF",
        "CHI2STAR_PSF", "NITER_PSF", "BETA_PSF", "SHARP_PRF", "LSCALE_PRF", "VOLUME_PRF",
        "FLUXERR_MODEL", "POSERR_MODEL", "FLAGS"};
    enum { NCOL = sizeof names / sizeof names[0] };
    int c[NCOL];
    int cflags0 = mp_table_col(t, "FLAGS");
    if (mp_table_add_cols(t, names, NCOL, c)) {
        snprintf(err, MP_ERRLEN, "out of memory");
        return 1;
    }
    unsigned char *keep = calloc(t->nrow ? t->nrow : 1, 1);
    if (!keep) {
        snprintf(err, MP_ERRLEN, "out of memory");
        return 1;
    }
    for (size_t i = 0; i < n; i++) {
        const mp_star *s = &st[i].s;
        size_t r = (size_t)st[i].row;
        keep[r] = (unsigned char)st[i].alive;
        int ok = s->flux > 0;
        /* Flags from earlier stages (find's saturation, group's split)
         * stay; the fit's own (edge, not converged, merged, masked) are
         * this fit's, not a previous round's: a star flagged not converged
         * in round 1 and converged in round 2 is not flagged. */
        double before = cflags0 >= 0 ? mp_table_get(t, r, c[NCOL - 1]) : 0.0;
        int carried = isfinite(before) ? (int)before & (MP_FLAG_SATURATED | MP_FLAG_SPLIT) : 0;
        int fl = s->flags | carried;
        double v[NCOL] = {
            s->x, s->y, s->ex, s->ey, s->flux, s->eflux,
            ok ? -2.5 * log10(s->flux) + magzero : 99.0,
            ok ? 2.5 / log(10.0) * s->eflux / s->flux : 99.0,
            s->sky, s->esky, s->sky_order, s->chi2, s->dof, s->chi2star, s->niter,
            s->st.beta, s->st.sharp, s->st.lscale, s->st.volume,
            s->fluxerr_model, s->poserr_model, fl};
        for (int k = 0; k < NCOL; k++)
            mp_table_set(t, r, c[k], v[k]);
    }
    size_t out = 0;
    for (size_t r = 0; r < t->nrow; r++)
        if (keep[r]) {
            if (out != r)
                memmove(t->v + out * t->ncol, t->v + r * t->ncol, t->ncol * sizeof *t->v);
            out++;
        }
    t->nrow = out;
    free(keep);
    return 0;
}
