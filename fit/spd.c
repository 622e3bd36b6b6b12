/* spd.c — small symmetric positive-definite systems by Cholesky (spd.h:
 * why not LAPACK in these places).  Every loop runs down a column, which
 * the storage keeps contiguous. */
#include <math.h>
#include <stdlib.h>
#include <string.h>
#include "fit/spd.h"

int mp_spd_factor(double *a, int n)
{
    for (int j = 0; j < n; j++) {
        double *cj = a + (size_t)j * n;
        double d = cj[j];
        if (!(d > 0.0) || !isfinite(d))
            return j + 1;
        d = sqrt(d);
        cj[j] = d;
        for (int i = j + 1; i < n; i++)
            cj[i] /= d;
        /* the trailing lower triangle less column j's outer product */
        for (int k = j + 1; k < n; k++) {
            double *ck = a + (size_t)k * n, f = cj[k];
            for (int i = k; i < n; i++)
                ck[i] -= cj[i] * f;
        }
    }
    return 0;
}

void mp_spd_solve_factored(const double *a, int n, double *b, size_t inc)
{
    /* L y = b, by columns: y_j, then its share out of the rows below */
    for (int j = 0; j < n; j++) {
        const double *cj = a + (size_t)j * n;
        double y = b[j * inc] / cj[j];
        b[j * inc] = y;
        for (int i = j + 1; i < n; i++)
            b[i * inc] -= cj[i] * y;
    }
    /* Lᵀ x = y: row j of Lᵀ is column j of L */
    for (int j = n - 1; j >= 0; j--) {
        const double *cj = a + (size_t)j * n;
        double s = b[j * inc];
        for (int i = j + 1; i < n; i++)
            s -= cj[i] * b[i * inc];
        b[j * inc] = s / cj[j];
    }
}

int mp_spd_solve(double *a, int n, double *b)
{
    int rc = mp_spd_factor(a, n);
    if (rc == 0)
        mp_spd_solve_factored(a, n, b, 1);
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
        double *xj = x + (size_t)j * n;
        xj[j] = 1.0;
        for (int k = j; k < n; k++) {
            const double *ck = a + (size_t)k * n;
            double y = xj[k] / ck[k];
            xj[k] = y;
            for (int i = k + 1; i < n; i++)
                xj[i] -= ck[i] * y;
        }
    }
    for (int j = 0; j < n; j++)
        for (int i = j; i < n; i++) {
            const double *xi = x + (size_t)i * n, *xj = x + (size_t)j * n;
            double s = 0.0;
            for (int k = i; k < n; k++)
                s += xi[k] * xj[k];
            a[(size_t)j * n + i] = s;
            a[(size_t)i * n + j] = s;
        }
    free(x);
    return 0;
}
