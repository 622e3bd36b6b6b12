/* select.c — order statistics by selection (io.h): the medians and
 * quantiles of the hot loops (the residual's noise map, the PSF build's
 * sky annuli and table elements), linear time on average where a sort is
 * O(n log n). */
#include <math.h>
#include "io/io.h"

double mp_select_kth(double *v, size_t n, size_t k)
{
    size_t lo = 0, hi = n - 1;
    while (hi > lo) {
        size_t mid = lo + (hi - lo) / 2;
        double t;
        /* median of three at mid, so that v[lo] ≤ pivot ≤ v[hi] stop the
         * scans below */
        if (v[mid] < v[lo])
            t = v[mid], v[mid] = v[lo], v[lo] = t;
        if (v[hi] < v[lo])
            t = v[hi], v[hi] = v[lo], v[lo] = t;
        if (v[hi] < v[mid])
            t = v[hi], v[hi] = v[mid], v[mid] = t;
        double p = v[mid];
        size_t i = lo, j = hi;
        for (;;) {                  /* Hoare's partition */
            while (v[i] < p)
                i++;
            while (p < v[j])
                j--;
            if (i >= j)
                break;
            t = v[i], v[i] = v[j], v[j] = t;
            i++;
            j--;
        }
        /* v[lo..j] ≤ p ≤ v[j+1..hi], lo ≤ j < hi */
        if (k <= j)
            hi = j;
        else
            lo = j + 1;
    }
    return v[k];
}

double mp_mad_sigma(double *v, size_t n)
{
    double med = mp_median_select(v, n);
    for (size_t i = 0; i < n; i++)
        v[i] = fabs(v[i] - med);
    return 1.482602218505602 * mp_median_select(v, n);
}

double mp_median_select(double *v, size_t n)
{
    if (n == 0)
        return NAN;
    double hi = mp_select_kth(v, n, n / 2);
    if (n % 2)
        return hi;
    double lo = v[0];               /* the largest left of the upper */
    for (size_t i = 1; i < n / 2; i++)
        lo = v[i] > lo ? v[i] : lo;
    return 0.5 * (lo + hi);
}
