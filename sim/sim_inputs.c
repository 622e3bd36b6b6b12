/* sim_inputs.c — PSF table and DRF files for `matphot sim` (sim_inputs.h). */
#include "sim/sim_inputs.h"

#include "psf/psf.h"

#include <math.h>
#include <stdio.h>
#include <string.h>

int sim_load_psf(const char *path, int hos, const char *kspec, sim_inputs *in, mp_sim_prf *prf,
                 char *err)
{
    if (mp_image_read(path, &in->psf, err))
        return 1;
    const mp_image *im = &in->psf;
    double os = hos > 0 ? hos : 1.0;
    int h = mp_header_double(im, "OVERSAMP", &os);
    if (h == 2 || (h == 0 && (os < 1 || os > 1000 || os != floor(os)))) {
        snprintf(err, MP_ERRLEN, "%s: OVERSAMP must be a positive integer", path);
        return 1;
    }
    if (im->nx % 2 == 0 || im->ny % 2 == 0) {
        snprintf(err, MP_ERRLEN, "%s: the PSF table is %ld x %ld; its sizes must be odd "
                 "(the star at the centre of the central element)", path, im->nx, im->ny);
        return 1;
    }
    double sum = 0;
    long nneg = 0;
    size_t n = (size_t)im->nx * (size_t)im->ny;
    for (size_t i = 0; i < n; i++) {
        if (!isfinite(im->pix[i])) {
            snprintf(err, MP_ERRLEN, "%s: the PSF table holds NaN or infinite values", path);
            return 1;
        }
        sum += im->pix[i];
        nneg += im->pix[i] < 0;
    }
    /* The sum is the share of the light the table holds (design.md §3):
     * below 1 is fine, above 1 is more light than the star has. */
    if (sum > 1.01) {
        snprintf(err, MP_ERRLEN, "%s: the PSF table sums to %.6g; it must hold at most "
                 "all the light (sum <= 1)", path, sum);
        return 1;
    }
    if (nneg)
        fprintf(stderr, "matphot sim: warning: %s: %ld negative PSF elements\n", path, nneg);
    /* The detector kernel as the fit folds it (fit/setup.c): a star is
     * drawn from the same table the fit is given. */
    mp_psf k;
    if (mp_psf_kernel_read(kspec, path, &k, err))
        return 1;
    int nx = (int)im->nx, ny = (int)im->ny;
    int rc = k.t && mp_psf_table_fold_kernel(&in->psf.pix, &nx, &ny, (int)os, &k, err);
    in->kernel = k.t ? k.nx : 0;
    mp_psf_free(&k);
    if (rc)
        return 1;
    in->psf.nx = nx;
    in->psf.ny = ny;
    prf->kind = MP_SIM_TABLE;
    prf->tab = im->pix;
    prf->tnx = (int)im->nx;
    prf->tny = (int)im->ny;
    prf->tos = (int)os;
    return 0;
}

int sim_load_drf(const char *path, sim_inputs *in, mp_sim_prf *prf, char *err)
{
    if (mp_image_read(path, &in->drf, err))
        return 1;
    const mp_image *im = &in->drf;
    if (im->nx != im->ny || im->nx > 1000) {
        snprintf(err, MP_ERRLEN, "%s: the DRF is %ld x %ld; it must be k x k", path,
                 im->nx, im->ny);
        return 1;
    }
    int k = (int)im->nx;
    double sum = 0;
    for (long i = 0; i < im->nx * im->ny; i++) {
        if (!(im->pix[i] >= 0 && im->pix[i] <= 1)) {
            snprintf(err, MP_ERRLEN, "%s: DRF values are quantum efficiencies and must "
                     "lie in [0, 1]", path);
            return 1;
        }
        sum += im->pix[i];
    }
    if (prf->kind == MP_SIM_TABLE && prf->tos % k != 0) {
        snprintf(err, MP_ERRLEN, "%s: the DRF is %d x %d but %d does not divide the PSF's "
                 "OVERSAMP %d", path, k, k, k, prf->tos);
        return 1;
    }
    in->drf_mean = sum / ((double)k * k);
    prf->drf = im->pix;
    prf->dk = k;
    return 0;
}

void sim_inputs_free(sim_inputs *in)
{
    mp_image_free(&in->psf);
    mp_image_free(&in->drf);
}
