/* fit_frame.h — private to fit/: fitting a whole table of stars on a frame. */
#ifndef MATPHOT_FIT_FRAME_H
#define MATPHOT_FIT_FRAME_H

#include "catalog/catalog.h"
#include "fit/fit.h"

/* mp_fit_table: fit every star of t on f (groups by GROUP_ID; one group for
 * the whole frame when o->fitrad is NaN; otherwise each star alone) and add
 * the fit's columns of design.md §4 to t. */
int mp_fit_table(const mp_frame *f, const mp_prf_model *m, const mp_fit_opts *o,
                 mp_table *t, double magzero, char *err);

/* mp_fit_residual: res = data − Σ stars (electrons; NaN where masked). */
int mp_fit_residual(const mp_frame *f, const mp_prf_model *m, const mp_table *t,
                    double *res, char *err);

#endif
