/* fwhm_check.c — the stars' width measured for the pipeline
 * (pipeline_priv.h: mp_pl_stars_why, mp_pl_frame_fwhm): in the words of
 * the report, and on a frame of its own for fwhm=INDEF.  The verdicts on
 * the model (psf=gauss's fwhm, a table's OVERSAMP) and why are in
 * psf/model_check.c. */
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "pipeline/pipeline_priv.h"
#include "psf/build.h"

void mp_pl_stars_why(const mp_stars_fwhm *m, char *why, size_t nwhy)
{
    if (m->n < MP_EPSF_FWHM_NEED)
        snprintf(why, nwhy, "the stars' FWHM not measured (%d lone, clean detections of %d "
                 "needed)", m->n, MP_EPSF_FWHM_NEED);
    else
        snprintf(why, nwhy, "the stars' FWHM %.3g +- %.2g px (a Gaussian fitted to each of %d "
                 "lone detections)", m->fwhm, m->err, m->n);
}

int mp_pl_frame_fwhm(const char *image, const mp_pipeline_opts *o, mp_stars_fwhm *m, char *err)
{
    mp_frame f;
    mp_bkg b;
    memset(&b, 0, sizeof b);
    memset(m, 0, sizeof *m);
    if (mp_frame_read(image, &o->fit.dp, &f, err))
        return 1;
    int rc = mp_bkg_estimate(&f, o->mesh, o->filter, &b, err) ||
             mp_epsf_frame_fwhm(&f, &b, &o->find, image, m, err);
    mp_bkg_free(&b);
    mp_frame_free(&f);
    return rc;
}
