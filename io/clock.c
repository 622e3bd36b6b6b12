/* clock.c — wall-clock seconds for the run reports. */
#include <time.h>
#include "io/io.h"

double mp_seconds(void)
{
    struct timespec t;
    clock_gettime(CLOCK_MONOTONIC, &t);
    return (double)t.tv_sec + 1e-9 * (double)t.tv_nsec;
}
