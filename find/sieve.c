/* sieve.c — mpf_sieve (find_priv.h): detections offered to a screen as
 * they are made (mp_find_opts.sieve). */
#include <math.h>
#include <stdlib.h>

#include "find/find_priv.h"

int mpf_sieve(const mp_find_opts *o, mpf_star *stars, long *keys, size_t n0, size_t *n)
{
    const struct mp_find_sieve *sv = o->sieve;
    if (!sv || *n <= n0)
        return 0;
    size_t m = *n - n0;
    mp_find_cand *c = malloc(m * sizeof *c);
    if (!c)
        return 1;
    /* As the table holds them (append: a value not finite is 0). */
    for (size_t i = 0; i < m; i++) {
        const mpf_star *s = &stars[n0 + i];
        c[i].x = isfinite(s->x) ? s->x : 0.0;
        c[i].y = isfinite(s->y) ? s->y : 0.0;
        c[i].flux = isfinite(s->flux) ? s->flux : 0.0;
        c[i].snr = NAN;
        c[i].keep = 1;
    }
    int rc = sv->fn(sv->ctx, c, m);
    size_t k = n0;
    for (size_t i = 0; !rc && i < m; i++) {
        if (!c[i].keep)
            continue;
        stars[k] = stars[n0 + i];
        stars[k].flux = c[i].flux;
        stars[k].snr = c[i].snr;
        keys[k++] = keys[n0 + i];
    }
    if (!rc)
        *n = k;
    free(c);
    return rc;
}
