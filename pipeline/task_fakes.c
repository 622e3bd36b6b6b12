/* task_fakes.c — the `matphot fakes` task: the pipeline's options, the
 * frame reduced once in memory (the stars it has), then this part's fakes
 * (fakes.c) and what they say (fakes_report.c). */
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include "pipeline/fakes_priv.h"

/* part=k/K → fakes [lo, hi) of n. */
static int part_range(const char *s, long n, long *lo, long *hi, char *err)
{
    long k, K;
    char extra;
    if (sscanf(s, "%ld/%ld%c", &k, &K, &extra) != 2 || K < 1 || k < 1 || k > K) {
        snprintf(err, MP_ERRLEN, "part: '%.100s' is not k/K with 1 <= k <= K", s);
        return 1;
    }
    *lo = (long)((double)(k - 1) * (double)n / (double)K);
    *hi = (long)((double)k * (double)n / (double)K);
    return 0;
}

static int fakes_opts(mp_parset *ps, const mp_pipeline_opts *o, mp_fakes_opts *fo, long *lo,
                      long *hi, char *err)
{
    int nfake = 0, seed = 1, box = 64;
    mp_par_int(ps, "nfake", &nfake);
    mp_par_int(ps, "seed", &seed);
    mp_par_int(ps, "box", &box);
    mp_par_real(ps, "magmin", &fo->magmin);
    mp_par_real(ps, "magmax", &fo->magmax);
    mp_par_real(ps, "fakerad", &fo->fakerad);
    fo->nfake = nfake;
    fo->seed = (uint64_t)(seed < 0 ? 0 : seed);
    fo->box = box;
    fo->fwhm = mp_prf_fwhm(&o->fit.model);
    if (o->build_psf) {
        snprintf(err, MP_ERRLEN, "psf: required (the fakes are drawn and fitted with the "
                 "frame's PSF; `matphot psf` builds one)");
        return 1;
    }
    return part_range(mp_par_string(ps, "part"), fo->nfake, lo, hi, err);
}

/* The frame's own stars; INDEF magnitude limits from them; the factors
 * its errors took from its residual (error_scale.c) given to the boxes'
 * reductions, whose few places could not measure them, so that a fake's
 * MAGERR_PSF is what the frame's catalog would say. */
static int base_stars(const mp_frame *f, mp_pipeline_opts *o, mp_fakes_opts *fo,
                      mp_fakes_base *b, char *err)
{
    mp_table t;
    mp_pipeline_report rep;
    if (mp_pipeline_reduce(f, o, &t, &rep, err))
        return 1;
    o->escale[0] = rep.escale[0];
    o->escale[1] = rep.escale[1];
    int cx = mp_table_col(&t, "XPSF_IMAGE"), cy = mp_table_col(&t, "YPSF_IMAGE");
    int cm = mp_table_col(&t, "MAG_PSF");
    size_t n = t.nrow;
    b->x = malloc((n + 1) * sizeof *b->x);
    b->y = malloc((n + 1) * sizeof *b->y);
    b->mag = malloc((n + 1) * sizeof *b->mag);
    b->n = 0;
    int rc = !b->x || !b->y || !b->mag;
    double lo = INFINITY, hi = -INFINITY;
    for (size_t r = 0; !rc && cx >= 0 && cy >= 0 && r < n; r++) {
        b->x[b->n] = mp_table_get(&t, r, cx);
        b->y[b->n] = mp_table_get(&t, r, cy);
        b->mag[b->n] = cm >= 0 ? mp_table_get(&t, r, cm) : NAN;
        if (isfinite(b->mag[b->n])) {
            lo = fmin(lo, b->mag[b->n]);
            hi = fmax(hi, b->mag[b->n]);
        }
        b->n++;
    }
    mp_table_free(&t);
    if (rc) {
        snprintf(err, MP_ERRLEN, "out of memory");
        return 1;
    }
    if (!isfinite(fo->magmin))
        fo->magmin = lo;
    if (!isfinite(fo->magmax))
        fo->magmax = hi + 1.0;
    if (!(lo <= hi) && !(isfinite(fo->magmin) && isfinite(fo->magmax))) {
        /* INDEF's range from no star: say so, not inf and -inf */
        snprintf(err, MP_ERRLEN, "magmin, magmax: INDEF takes them from the stars the frame's "
                 "reduction finds, and it found none (give both, or see why no star passes: "
                 "threshold, minsnr, gain, saturate)");
        return 1;
    }
    if (!(fo->magmax > fo->magmin)) {
        snprintf(err, MP_ERRLEN, "magmin, magmax: no range of magnitudes (%g, %g)", fo->magmin,
                 fo->magmax);
        return 1;
    }
    return 0;
}

int mp_task_fakes(int argc, char **argv)
{
    mp_parset ps;
    int b = mp_task_begin("fakes", argc, argv, &ps);
    if (b)
        return b;
    char err[MP_ERRLEN] = "";
    mp_pipeline_opts o;
    mp_fakes_opts fo = {0};
    mp_fakes_base base = {0};
    mp_frame f = {0};
    mp_fake *out = NULL;
    char *root = NULL, *cat = NULL;
    long lo = 0, hi = 0;
    int rc = 1;
    double t0 = mp_seconds();
    const char *image = mp_par_string(&ps, "image");
    if (mp_pl_opts_read(&ps, &o, err) || fakes_opts(&ps, &o, &fo, &lo, &hi, err))
        goto done;
    mp_fit_setup_warn(&o.fit, "fakes");
    const char *r = mp_par_string(&ps, "root");
    root = r[0] ? strdup(r) : mp_name_after(image, "");
    cat = root ? mp_name_after(root, ".fakes.cat") : NULL;
    out = calloc((size_t)(hi - lo) + 1, sizeof *out);
    if (!root || !cat || !out) {
        snprintf(err, MP_ERRLEN, "out of memory");
        goto done;
    }
    static const char *const ext[] = {".fakes.cat", ".fakes.md", ".fakes.dat", ".fakes.png"};
    mp_inputs *ins = mp_inputs_of(&image, 1);
    if (!ins)
        snprintf(err, MP_ERRLEN, "out of memory");
    int same = !ins || mp_fit_setup_inputs(&ps, &o.fit, ins, err) ||
               mp_pl_outputs_clear(root, ext, 4, ins, err);
    mp_inputs_free(ins);
    if (same || mp_frame_read(image, &o.fit.dp, &f, err) || base_stars(&f, &o, &fo, &base, err))
        goto done;
    mp_pl_warn_whole_frame_only(&o, "fakes", image, "to the fakes' boxes");
    if (mp_fakes_run(&f, &o, &fo, &base, lo, hi, out, err))
        goto done;
    mp_sweeps *sw = mp_sweeps_new();  /* killed runs' temporaries, once a directory */
    mp_tmp_sweep(sw, cat);
    mp_tmp_sweep(sw, root);
    mp_sweeps_free(sw);
    if (mp_fakes_write_table(cat, out, hi - lo, err) ||
        mp_fakes_write_report(root, image, &fo, lo, hi, out, err))
        goto done;
    long nf = 0;
    for (long i = 0; i < hi - lo; i++)
        nf += out[i].found;
    fprintf(stderr, "matphot fakes: %s: fakes %ld..%ld of %ld: %ld found, %.1f s\n", image,
            lo + 1, hi, fo.nfake, nf, mp_seconds() - t0);
    rc = 0;
done:
    if (rc)
        fprintf(stderr, "matphot fakes: %s\n", err);
    free(base.x);
    free(base.y);
    free(base.mag);
    free(out);
    free(root);
    free(cat);
    mp_frame_free(&f);
    mp_fit_setup_free(&o.fit);
    mp_params_free(&ps);
    return rc;
}
