/* spd.h — small symmetric positive-definite systems (fit/ only): the LM
 * step, the covariance, the sky test, the performance model's 4×4 and
 * the coupling's 3×3, solved in the calling thread.
 *
 * Why not LAPACK here: Debian's OpenBLAS (0.3.21, pthread build) takes
 * one process-wide mutex for a work buffer at every dpotrf and dtrsm call
 * (blas_memory_alloc), and the fit makes ~10^5–10^6 such calls from every
 * OpenMP thread.  Measured on a 16-core machine (bench/SCALING.md, session
 * of 2026-11-30 20:55): 13×13 systems by LAPACKE_dposv, 1.44 M/s on one
 * thread, 21 k/s per thread on 16 (all 16 together 0.34 M/s, fewer than
 * one thread alone); by the loop below 2.07 M/s and 1.37 M/s per thread.
 * The group fits then ran 2.2× slower each on 16 threads than on one, and
 * no faster on 16 than on 8.  On one thread the loops here (panels of
 * four columns, vectorised) are as fast as OpenBLAS's: a solve 0.38 µs
 * against dposv's 1.29 µs at n = 7, 4.0 against 6.3 at 31, 87 against 83
 * at 96 (the largest group, 30 stars and a quadratic sky); the inverse
 * 0.65 against 1.50 µs at 7, 241 against 181 at 96 (once a group fit).
 * The eigen-decompositions (dsyev, dsygv) stay with LAPACK: they are
 * rare.
 *
 * Storage: an n×n array whose column-major lower triangle holds the
 * matrix (element (i, j), i ≥ j, at a[i + j·n]) — the same memory as a
 * row-major upper triangle, so both LAPACKE layouts the callers used map
 * onto it unchanged.  The other triangle is neither read nor kept. */
#ifndef MATPHOT_FIT_SPD_H
#define MATPHOT_FIT_SPD_H

/* mp_spd_factor: a = L Lᵀ, L into the lower triangle (Cholesky, right-
 * looking, by panels of four columns).  0, or j + 1 when the leading
 * minor of order j + 1 is not positive (or not finite): LAPACK dpotrf's
 * info. */
int mp_spd_factor(double *a, int n);

/* mp_spd_solve_factored: b ← A⁻¹ b with a holding L (mp_spd_factor). */
void mp_spd_solve_factored(const double *a, int n, double *b);

/* mp_spd_solve: factor a (overwritten by L) and solve for b in place; the
 * factor's return value (b untouched when it is nonzero).  LAPACK dposv. */
int mp_spd_solve(double *a, int n, double *b);

/* mp_spd_inverse: a ← A⁻¹, both triangles, from a holding A; the factor's
 * return value, or -1 when out of memory.  LAPACK dpotrf + dpotri (which
 * fill one triangle). */
int mp_spd_inverse(double *a, int n);

#endif
