/* blas_threads.c — keep OpenBLAS to one thread.
 *
 * matphot threads over groups with OpenMP; each group's normal equations
 * are small (3 per star plus the sky, ≤ 186 rows), far below where a
 * threaded factorisation pays.  Debian's default OpenBLAS (the pthread
 * build) starts its own threads anyway, and they spin in sched_yield
 * beside the OpenMP team: on a 256² GLIMPSE crop one fit round took 26.6 s
 * of CPU (9 s of it in the kernel) against 9.0 s with OpenBLAS on one
 * thread, the same numbers out. */
#include <cblas.h>
#include "fit/fit.h"

void mp_blas_single_thread(void)
{
    openblas_set_num_threads(1);
}
