/* rus CMD...: runs CMD and prints "RUS wall user sys minflt nvcsw nivcsw" (its
 * rusage: seconds, minor page faults, voluntary and involuntary context
 * switches) on stderr; for hosts without GNU time (bench/SCALING.md). */
#define _DEFAULT_SOURCE
#include <stdio.h>
#include <sys/resource.h>
#include <sys/wait.h>
#include <time.h>
#include <unistd.h>
int main(int argc, char **argv)
{
    if (argc < 2) return 2;
    struct timespec a, b;
    clock_gettime(CLOCK_MONOTONIC, &a);
    pid_t p = fork();
    if (p == 0) { execvp(argv[1], argv + 1); _exit(127); }
    int st; struct rusage ru;
    wait4(p, &st, 0, &ru);
    clock_gettime(CLOCK_MONOTONIC, &b);
    fprintf(stderr, "RUS %.3f %.3f %.3f %ld %ld %ld\n", (b.tv_sec - a.tv_sec) + 1e-9 * (b.tv_nsec - a.tv_nsec),
            ru.ru_utime.tv_sec + 1e-6 * ru.ru_utime.tv_usec, ru.ru_stime.tv_sec + 1e-6 * ru.ru_stime.tv_usec,
            ru.ru_minflt, ru.ru_nvcsw, ru.ru_nivcsw);
    return WIFEXITED(st) ? WEXITSTATUS(st) : 1;
}
