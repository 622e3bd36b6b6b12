/* select.c — order statistics by selection (io.h): the medians and
 * quantiles of the hot loops (the residual's noise map, the PSF build's
 * sky annuli and table elements), linear time on average where a sort is
 * O(n log n). */
#include <math.h>
#include <stdlib.h>
#include "io/io.h"
#ifdef _OPENMP
#include <omp.h>
#endif

static void swap(double *v, size_t a, size_t b)
{
    double t = v[a];
    v[a] = v[b];
    v[b] = t;
}

/* v[lo], the middle of v[lo..hi] and v[hi] put in order; the middle's
 * index (the median of the three: the pivot). */
static size_t median_of_three(double *v, size_t lo, size_t hi)
{
    size_t mid = lo + (hi - lo) / 2;
    if (v[mid] < v[lo])
        swap(v, mid, lo);
    if (v[hi] < v[lo])
        swap(v, hi, lo);
    if (v[hi] < v[mid])
        swap(v, hi, mid);
    return mid;
}

/* Hoare's partition of v[lo..hi] about the median of v[lo], its middle
 * and v[hi] (which stop the scans): v[lo..j] ≤ p ≤ v[j+1..hi], lo ≤ j <
 * hi; returns j.  Even with many equal values it splits near the middle. */
static size_t partition_hoare(double *v, size_t lo, size_t hi)
{
    double p = v[median_of_three(v, lo, hi)];
    size_t i = lo, j = hi;
    for (;;) {
        while (v[i] < p)
            i++;
        while (p < v[j])
            j--;
        if (i >= j)
            return j;
        swap(v, i, j);
        i++;
        j--;
    }
}

/* Lomuto's partition of v[lo..hi], hi > lo, about p, the median of v[lo],
 * its middle and v[hi]: v[lo..s) < p = v[s] ≤ v[s+1..hi]; returns s.
 * Branch-free: every element is swapped to the boundary and the boundary
 * advanced by its comparison, so no branch waits on the data (Hoare's
 * scans mispredicted every other element: the median selections were
 * 6 % of 47 Tuc built's run, 11 % of a simulated frame's with its PSF
 * built; this is 2.4 to 5 times faster on 20 to 2·10⁵ random values). */
static size_t partition_lomuto(double *v, size_t lo, size_t hi)
{
    swap(v, median_of_three(v, lo, hi), hi);
    double p = v[hi];
    size_t s = lo;
    for (size_t i = lo; i < hi; i++) {
        double x = v[i];
        v[i] = v[s];
        v[s] = x;
        s += x < p;
    }
    v[hi] = v[s];
    v[s] = p;
    return s;
}

double mp_select_kth(double *v, size_t n, size_t k)
{
    size_t lo = 0, hi = n - 1;
    while (hi > lo) {
        size_t len = hi - lo, s = partition_lomuto(v, lo, hi);
        /* Values equal to the pivot all go right: with many of them (a
         * flat patch) the split is lopsided, and a Hoare step, which
         * splits equal values evenly, keeps the time linear. */
        if (len >= 16 && (16 * (s - lo) < len || 16 * (hi - s) < len)) {
            size_t j = partition_hoare(v, lo, hi);
            if (k <= j)
                hi = j;
            else
                lo = j + 1;
        } else if (k == s) {
            return v[k];
        } else if (k < s) {
            hi = s - 1;
        } else {
            lo = s + 1;
        }
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

#ifdef _OPENMP
/* The parallel median's sizes: from PAR_MIN values on, PAR_BINS bins. */
enum { PAR_MIN = 1 << 16, PAR_BINS = 4096 };

/* The bin of value x on [lo, lo + PAR_BINS/scale] (the top one's end in
 * it). */
static inline size_t bin_of(double x, double lo, double scale)
{
    size_t c = (size_t)((x - lo) * scale);
    return c < PAR_BINS ? c : PAR_BINS - 1;
}

/* The k-th smallest of v[0..n), all finite within [lo, hi], v unchanged,
 * into *out: a histogram of PAR_BINS bins over [lo, hi] (a count a thread
 * and bin), then the k-th among the values of the bin that holds it,
 * gathered (each thread's after the earlier threads', in its own order)
 * and selected (mp_select_kth).  Both loops in one parallel region with
 * the same static schedule, so each thread meets in the second the values
 * it counted in the first (OpenMP's guarantee).  The same value as a
 * selection on the whole.  Nonzero when out of memory. */
static int kth_by_bins(const double *v, size_t n, size_t k, double lo, double hi, double *out)
{
    int nt = omp_get_max_threads(), failed = 0;
    double scale = hi > lo ? PAR_BINS / (hi - lo) : 0.0, *buf = NULL;
    size_t *h = calloc((size_t)nt * PAR_BINS, sizeof *h), *off = calloc((size_t)nt, sizeof *off);
    size_t b = 0, below = 0, m = 0;
    if (!h || !off) {
        free(h);
        free(off);
        return 1;
    }
#pragma omp parallel num_threads(nt)
    {
        int t = omp_get_thread_num(), T = omp_get_num_threads();
        size_t *mine = h + (size_t)t * PAR_BINS;
#pragma omp for schedule(static)
        for (size_t i = 0; i < n; i++)
            mine[bin_of(v[i], lo, scale)]++;
#pragma omp single
        {
            for (;; b++) {              /* the bin of the k-th */
                m = 0;
                for (int u = 0; u < T; u++)
                    m += h[(size_t)u * PAR_BINS + b];
                if (k < below + m || b == PAR_BINS - 1)
                    break;
                below += m;
            }
            for (int u = 1; u < T; u++)
                off[u] = off[u - 1] + h[(size_t)(u - 1) * PAR_BINS + b];
            failed = !(buf = malloc((m ? m : 1) * sizeof *buf));
        }
        size_t at = off[t];
#pragma omp for schedule(static)
        for (size_t i = 0; i < n; i++)
            if (!failed && bin_of(v[i], lo, scale) == b)
                buf[at++] = v[i];
    }
    if (!failed)
        *out = mp_select_kth(buf, m, k - below);
    free(buf);
    free(h);
    free(off);
    return failed;
}

/* The median of v[0..n) in parallel (v unchanged), into *med: the upper
 * middle value by kth_by_bins; for even n the lower one is the largest
 * value below it when n/2 values are below it, else the same value (the
 * values a selection on the whole gives).  Nonzero when it cannot: out
 * of memory, or a value not finite (the serial selection's own order
 * then decides). */
static int median_parallel(const double *v, size_t n, double *med)
{
    double lo = INFINITY, hi = -INFINITY;
    size_t bad = 0;
#pragma omp parallel for schedule(static) reduction(min : lo) reduction(max : hi) reduction(+ : bad)
    for (size_t i = 0; i < n; i++) {
        bad += !isfinite(v[i]);
        lo = v[i] < lo ? v[i] : lo;
        hi = v[i] > hi ? v[i] : hi;
    }
    double up;
    if (bad || kth_by_bins(v, n, n / 2, lo, hi, &up))
        return 1;
    if (n % 2) {
        *med = up;
        return 0;
    }
    size_t below = 0;
    double under = -INFINITY;
#pragma omp parallel for schedule(static) reduction(+ : below) reduction(max : under)
    for (size_t i = 0; i < n; i++)
        if (v[i] < up) {
            below++;
            under = v[i] > under ? v[i] : under;
        }
    *med = 0.5 * ((below >= n / 2 ? under : up) + up);
    return 0;
}
#endif

double mp_median_select(double *v, size_t n)
{
    if (n == 0)
        return NAN;
    /* Large samples outside a parallel region in parallel: the residual's
     * noise model takes two medians of up to 2·10⁵ values at each step of
     * its bisection, serial, which were 1.5 % of 47 Tuc built's wall time
     * on 16 threads. */
#ifdef _OPENMP
    double med;
    if (n >= PAR_MIN && omp_get_max_threads() > 1 && !omp_in_parallel() &&
        !median_parallel(v, n, &med))
        return med;
#endif
    double hi = mp_select_kth(v, n, n / 2);
    if (n % 2)
        return hi;
    double lo = v[0];               /* the largest left of the upper */
    for (size_t i = 1; i < n / 2; i++)
        lo = v[i] > lo ? v[i] : lo;
    return 0.5 * (lo + hi);
}

static int cmp_costliest(const void *a, const void *b)
{
    const mp_work_item *x = a, *y = b;
    if (x->cost != y->cost)
        return (x->cost < y->cost) - (x->cost > y->cost);
    return (x->i > y->i) - (x->i < y->i);
}

void mp_costliest_first(mp_work_item *w, size_t n)
{
    qsort(w, n, sizeof *w, cmp_costliest);
}
