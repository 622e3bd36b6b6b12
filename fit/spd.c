/* spd.c — small symmetric positive-definite systems by Cholesky (spd.h:
 * why not LAPACK in these places).  Every loop runs down a column, which
 * the storage keeps contiguous. */
#include <math.h>
#include <stdlib.h>
#include <string.h>
#include "fit/spd.h"

/* Column j: its diagonal's square root, the column below it scaled, and
 * the columns j+1..k1-1 less its outer product (rank 1).  0, or j + 1. */
static int factor_column(double *a, int n, int j, int k1)
{
    double *cj = a + (size_t)j * n;
    double d = cj[j];
    if (!(d > 0.0) || !isfinite(d))
        return j + 1;
    d = sqrt(d);
    cj[j] = d;
    double r = 1.0 / d;
#pragma omp simd
    for (int i = j + 1; i < n; i++)
        cj[i] *= r;
    for (int k = j + 1; k < k1; k++) {
        double *ck = a + (size_t)k * n, f = cj[k];
#pragma omp simd
        for (int i = k; i < n; i++)
            ck[i] -= cj[i] * f;
    }
    return 0;
}

int mp_spd_factor(double *a, int n)
{
    /* Right-looking by panels of four columns: each panel factored with
     * rank-1 updates among its own columns, then the trailing columns less
     * the panel's rank-4 product in one pass (a quarter of the passes over
     * the trailing triangle the column-by-column loop makes). */
    int j0 = 0;
    for (; j0 + 4 <= n; j0 += 4) {
        for (int j = j0; j < j0 + 4; j++) {
            int rc = factor_column(a, n, j, j0 + 4);
            if (rc)
                return rc;
        }
        const double *c0 = a + (size_t)j0 * n, *c1 = c0 + n, *c2 = c1 + n, *c3 = c2 + n;
        for (int k = j0 + 4; k < n; k++) {
            double *ck = a + (size_t)k * n;
            double f0 = c0[k], f1 = c1[k], f2 = c2[k], f3 = c3[k];
#pragma omp simd
            for (int i = k; i < n; i++)
                ck[i] -= c0[i] * f0 + c1[i] * f1 + c2[i] * f2 + c3[i] * f3;
        }
    }
    for (int j = j0; j < n; j++) {
        int rc = factor_column(a, n, j, n);
        if (rc)
            return rc;
    }
    return 0;
}

/* L y = b in place, by columns (y_j, then its share out of the rows
 * below), b zero above row from. */
static void forward(const double *a, int n, double *b, int from)
{
    for (int j = from; j < n; j++) {
        const double *cj = a + (size_t)j * n;
        double y = b[j] / cj[j];
        b[j] = y;
#pragma omp simd
        for (int i = j + 1; i < n; i++)
            b[i] -= cj[i] * y;
    }
}

void mp_spd_solve_factored(const double *a, int n, double *b)
{
    forward(a, n, b, 0);
    /* Lᵀ x = y: row j of Lᵀ is column j of L */
    for (int j = n - 1; j >= 0; j--) {
        const double *cj = a + (size_t)j * n;
        double s = 0.0;
#pragma omp simd reduction(+ : s)
        for (int i = j + 1; i < n; i++)
            s += cj[i] * b[i];
        b[j] = (b[j] - s) / cj[j];
    }
}

int mp_spd_solve(double *a, int n, double *b)
{
    int rc = mp_spd_factor(a, n);
    if (rc == 0)
        mp_spd_solve_factored(a, n, b);
    return rc;
}

int mp_spd_inverse(double *a, int n)
{
    int rc = mp_spd_factor(a, n);
    if (rc)
        return rc;
    /* X = L⁻¹ by columns (column j: L x = e_j, zero above j), then
     * A⁻¹ = Xᵀ X: element (i, j) the dot product of columns i and j
     * from row max(i, j) down. */
    double *x = calloc((size_t)n * n + 1, sizeof *x);
    if (!x)
        return -1;
    for (int j = 0; j < n; j++) {
        x[(size_t)j * n + j] = 1.0;
        forward(a, n, x + (size_t)j * n, j);
    }
    for (int j = 0; j < n; j++)
        for (int i = j; i < n; i++) {
            const double *xi = x + (size_t)i * n, *xj = x + (size_t)j * n;
            double s = 0.0;
#pragma omp simd reduction(+ : s)
            for (int k = i; k < n; k++)
                s += xi[k] * xj[k];
            a[(size_t)j * n + i] = s;
            a[(size_t)i * n + j] = s;
        }
    free(x);
    return 0;
}
