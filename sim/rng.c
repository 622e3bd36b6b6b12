/* rng.c — xoshiro256** (Blackman & Vigna 2018) and the distributions the
 * simulator draws from.  All state lives in the caller's mp_rng. */
#include "sim/sim.h"

#include <math.h>

static inline uint64_t rotl(uint64_t x, int k)
{
    return (x << k) | (x >> (64 - k));
}

/* splitmix64 spreads any seed (even 0) over the 256-bit state, as the
 * xoshiro authors recommend. */
static uint64_t splitmix64(uint64_t *x)
{
    uint64_t z = (*x += 0x9e3779b97f4a7c15ULL);
    z = (z ^ (z >> 30)) * 0xbf58476d1ce4e5b9ULL;
    z = (z ^ (z >> 27)) * 0x94d049bb133111ebULL;
    return z ^ (z >> 31);
}

void mp_rng_seed(mp_rng *r, uint64_t seed)
{
    uint64_t x = seed;
    for (int i = 0; i < 4; i++)
        r->s[i] = splitmix64(&x);
}

uint64_t mp_rng_next(mp_rng *r)
{
    uint64_t *s = r->s;
    const uint64_t result = rotl(s[1] * 5, 7) * 9;
    const uint64_t t = s[1] << 17;
    s[2] ^= s[0];
    s[3] ^= s[1];
    s[1] ^= s[2];
    s[0] ^= s[3];
    s[2] ^= t;
    s[3] = rotl(s[3], 45);
    return result;
}

double mp_rng_uniform(mp_rng *r)
{
    /* The top 53 bits: every double in [0,1) on the 2^-53 grid, equally
     * likely. */
    return (double)(mp_rng_next(r) >> 11) * 0x1.0p-53;
}

double mp_rng_normal(mp_rng *r)
{
    /* Marsaglia's polar method; the second deviate is dropped so that no
     * state is kept between calls. */
    double u, v, s;
    do {
        u = 2.0 * mp_rng_uniform(r) - 1.0;
        v = 2.0 * mp_rng_uniform(r) - 1.0;
        s = u * u + v * v;
    } while (s >= 1.0 || s == 0.0);
    return u * sqrt(-2.0 * log(s) / s);
}

/* log(k!) without lgamma(), which writes the global signgam and so is not
 * safe in threads: exact products for small k, Stirling's series beyond
 * (error < 1e-17 for k >= 16). */
static double log_factorial(double k)
{
    if (k < 16) {
        double f = 1.0;
        for (int i = 2; i <= (int)k; i++)
            f *= i;
        return log(f);
    }
    double n = k + 1.0;           /* log Γ(n) */
    double n2 = n * n;
    return (n - 0.5) * log(n) - n + 0.91893853320467274178 /* log √(2π) */
        + (1.0 / 12.0 - (1.0 / 360.0 - (1.0 / 1260.0 - 1.0 / (1680.0 * n2)) / n2) / n2) / n;
}

/* Inversion by sequential search: exact, and fast while the mean is small
 * (expected mean+1 steps). */
static double poisson_inversion(mp_rng *r, double mean)
{
    for (;;) {
        double u = mp_rng_uniform(r);
        double p = exp(-mean), cdf = p;
        double k = 0;
        while (u > cdf) {
            k += 1;
            p *= mean / k;
            cdf += p;
            /* Rounding can leave the summed cdf just below u near 1:
             * start again rather than return a wrong tail value. */
            if (p < 1e-300 && k > mean)
                break;
        }
        if (u <= cdf)
            return k;
    }
}

/* PTRS, transformed rejection with squeeze (Hörmann 1993, Insurance:
 * Mathematics and Economics 12, 39): exact for mean >= 10 with about 1.1
 * uniform pairs per deviate at any mean. */
static double poisson_ptrs(mp_rng *r, double mean)
{
    const double slam = sqrt(mean), loglam = log(mean);
    const double b = 0.931 + 2.53 * slam;
    const double a = -0.059 + 0.02483 * b;
    const double invalpha = 1.1239 + 1.1328 / (b - 3.4);
    const double vr = 0.9277 - 3.6224 / (b - 2.0);
    for (;;) {
        double u = mp_rng_uniform(r) - 0.5;
        double v = mp_rng_uniform(r);
        double us = 0.5 - fabs(u);
        double k = floor((2.0 * a / us + b) * u + mean + 0.43);
        if (us >= 0.07 && v <= vr)
            return k;
        if (k < 0 || (us < 0.013 && v > us))
            continue;
        if (log(v) + log(invalpha) - log(a / (us * us) + b)
            <= -mean + k * loglam - log_factorial(k))
            return k;
    }
}

double mp_rng_poisson(mp_rng *r, double mean)
{
    if (isnan(mean) || isinf(mean))
        return mean > 0 ? mean : (isnan(mean) ? mean : 0.0);
    if (!(mean > 0))
        return 0.0;
    return mean < 10.0 ? poisson_inversion(r, mean) : poisson_ptrs(r, mean);
}
