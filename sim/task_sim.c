/* task_sim.c — the `matphot sim` task (stub). */
#include <stdio.h>
#include "sim/sim.h"

int mp_task_sim(int argc, char **argv)
{
    (void)argc; (void)argv;
    fprintf(stderr, "matphot sim: not implemented yet\n");
    return 1;
}
