/* mesh_stats.c — the statistics of one background mesh: SExtractor's
 * clipped mode and rms (anchors.md §2; SExtractor back.c backguess()). */
#include <math.h>
#include <stdint.h>
#include <stdlib.h>
#include <string.h>

#include "find/find_priv.h"

#define CLIP_K 3.0        /* SExtractor clips at median ± 3σ */
#define MAX_ITER 100

static int cmp_double(const void *a, const void *b)
{
    double x = *(const double *)a, y = *(const double *)b;
    return (x > y) - (x < y);
}

/* The bits of x as an unsigned key that sorts as x does (IEEE 754:
 * flip all bits of negatives, the sign bit of the rest). */
static uint64_t key_of(double x)
{
    uint64_t u;
    memcpy(&u, &x, sizeof u);
    return (u >> 63) ? ~u : u | (UINT64_C(1) << 63);
}

static double double_of(uint64_t u)
{
    u = (u >> 63) ? u & ~(UINT64_C(1) << 63) : ~u;
    double x;
    memcpy(&x, &u, sizeof x);
    return x;
}

/* Counts of a radix pass's 256 buckets turned into their first places. */
static void bucket_starts(size_t *count)
{
    size_t pos = 0;
    for (int c = 0; c < 256; c++) {
        size_t k = count[c];
        count[c] = pos;
        pos += k;
    }
}

/* The bits of float x as an unsigned key that sorts as x does (key_of's
 * rule on 32 bits). */
static uint32_t key32_of(float x)
{
    uint32_t u;
    memcpy(&u, &x, sizeof u);
    return (u >> 31) ? ~u : u | (UINT32_C(1) << 31);
}

static float float_of(uint32_t u)
{
    u = (u >> 31) ? u & ~(UINT32_C(1) << 31) : ~u;
    float x;
    memcpy(&x, &u, sizeof x);
    return x;
}

/* radix_sort of values that are all floats' (a frame's pixels): their
 * 32-bit keys, the four bytes' counts taken in the same pass, four passes
 * at most (half of the doubles' eight, whose low bytes are the zeros a
 * float's mantissa leaves).  The same values in the same order. */
static void radix_sort32(double *v, size_t n, uint32_t *work)
{
    uint32_t *a = work, *b = work + n;
    size_t count[4][256] = {{0}};
    for (size_t i = 0; i < n; i++) {
        uint32_t k = key32_of((float)v[i]);
        a[i] = k;
        for (int p = 0; p < 4; p++)
            count[p][(k >> (8 * p)) & 0xff]++;
    }
    for (int p = 0; p < 4; p++) {
        int shift = 8 * p;
        size_t *c = count[p];
        if (c[(a[0] >> shift) & 0xff] == n)
            continue;
        bucket_starts(c);
        for (size_t i = 0; i < n; i++)
            b[c[(a[i] >> shift) & 0xff]++] = a[i];
        uint32_t *t = a;
        a = b;
        b = t;
    }
    for (size_t i = 0; i < n; i++)
        v[i] = float_of(a[i]);
}

/* LSD radix sort of finite doubles, 8 bits a pass; a pass whose byte is
 * the same for every value (the sign and exponent of a sky, mostly) is
 * skipped; values that are all floats' by radix_sort32.  Several times
 * faster than qsort on a mesh of 4096 values, and sorting is most of the
 * background's time.  work: room for 2n keys. */
static void radix_sort(double *v, size_t n, uint64_t *work)
{
    int single = 1;
    for (size_t i = 0; i < n; i++)
        single &= (double)(float)v[i] == v[i];
    if (single) {
        radix_sort32(v, n, (uint32_t *)work);
        return;
    }
    uint64_t *a = work, *b = work + n;
    for (size_t i = 0; i < n; i++)
        a[i] = key_of(v[i]);
    for (int shift = 0; shift < 64; shift += 8) {
        size_t count[256] = {0};
        for (size_t i = 0; i < n; i++)
            count[(a[i] >> shift) & 0xff]++;
        if (count[(a[0] >> shift) & 0xff] == n)
            continue;
        bucket_starts(count);
        for (size_t i = 0; i < n; i++)
            b[count[(a[i] >> shift) & 0xff]++] = a[i];
        uint64_t *t = a;
        a = b;
        b = t;
    }
    for (size_t i = 0; i < n; i++)
        v[i] = double_of(a[i]);
}

double mpf_clip_shrink(double k)
{
    /* Clipping N(0, 1) at ±t keeps variance F(t) = 1 − 2tφ(t)/erf(t/√2);
     * iterating the clip at k times the kept σ converges to the fixed
     * point s = sqrt(F(k·s)). */
    double s = 1.0;
    for (int i = 0; i < 200; i++) {
        double t = k * s;
        double phi = exp(-0.5 * t * t) / sqrt(2.0 * M_PI);
        double s2 = 1.0 - 2.0 * t * phi / erf(t / sqrt(2.0));
        double next = sqrt(s2 > 0.0 ? s2 : 0.0);
        if (fabs(next - s) < 1e-15)
            break;
        s = next;
    }
    return s;
}

/* Median of sorted a[0..m).  Tied middle values (integer ADU) are treated
 * as a histogram bin whose width is the gap to the nearest other value,
 * and the median is interpolated inside that bin, as SExtractor's
 * histogram median is; otherwise the plain median. */
static double median_sorted(const double *a, size_t m)
{
    size_t mid = m / 2;
    double v = a[mid];
    size_t first = mid, last = mid + 1;
    while (first > 0 && a[first - 1] == v)
        first--;
    while (last < m && a[last] == v)
        last++;
    size_t neq = last - first;
    if (neq < 2)
        return m % 2 ? v : 0.5 * (a[mid - 1] + a[mid]);
    double q = HUGE_VAL;
    if (first > 0)
        q = v - a[first - 1];
    if (last < m && a[last] - v < q)
        q = a[last] - v;
    if (!isfinite(q))
        return v;                         /* all values equal */
    return v + q * (((double)m / 2.0 - (double)first) / (double)neq - 0.5);
}

double mpf_median_small(double *v, size_t n)
{
    qsort(v, n, sizeof *v, cmp_double);
    return n % 2 ? v[n / 2] : 0.5 * (v[n / 2 - 1] + v[n / 2]);
}

/* First index in a[0..n) with a[i] >= x (lower) or a[i] > x (upper). */
static size_t bound(const double *a, size_t n, double x, int upper)
{
    size_t lo = 0, hi = n;
    while (lo < hi) {
        size_t m = lo + (hi - lo) / 2;
        if (upper ? a[m] <= x : a[m] < x)
            lo = m + 1;
        else
            hi = m;
    }
    return lo;
}

int mpf_mesh_stats(double *v, size_t n, double shrink, uint64_t *work, double *mode,
                   double *rms)
{
    if (n == 0)
        return 1;
    radix_sort(v, n, work);
    size_t lo = 0, hi = n;
    double med = 0.0, mean = 0.0, sd = 0.0;
    for (int it = 0; it < MAX_ITER; it++) {
        size_t m = hi - lo;
        const double *a = v + lo;
        /* Mean and variance about the median, which is close to the mean,
         * so the sum of squares does not cancel. */
        med = median_sorted(a, m);
        double s1 = 0.0, s2 = 0.0;
        for (size_t i = 0; i < m; i++) {
            double d = a[i] - med;
            s1 += d;
            s2 += d * d;
        }
        mean = med + s1 / (double)m;
        double var = m > 1 ? (s2 - s1 * s1 / (double)m) / (double)(m - 1) : 0.0;
        sd = var > 0.0 ? sqrt(var) : 0.0;
        if (sd == 0.0)
            break;
        size_t nlo = bound(v, n, med - CLIP_K * sd, 0);
        size_t nhi = bound(v, n, med + CLIP_K * sd, 1);
        if (nhi <= nlo || (nlo == lo && nhi == hi))
            break;
        lo = nlo;
        hi = nhi;
    }
    /* SExtractor: the mode estimate unless the clipped distribution is
     * still skewed (|mean − median| ≥ 0.3σ, a crowded box): the median. */
    if (sd > 0.0)
        *mode = fabs(mean - med) < 0.3 * sd ? 2.5 * med - 1.5 * mean : med;
    else
        *mode = mean;
    *rms = sd / shrink;
    return 0;
}
