/* task_fit.c — the `matphot fit` task (stub until the engine lands). */
#include <stdio.h>
#include "fit/fit.h"

int mp_task_fit(int argc, char **argv)
{
    (void)argc; (void)argv;
    fprintf(stderr, "matphot fit: not implemented yet\n");
    return 1;
}
