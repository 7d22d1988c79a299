/* Shared by the C clients of bench/pty_clients.sh: the monotonic clock in seconds and the
 * comparison for sorting latencies. */
#ifndef DRIVEBUS_BENCH_TIMING_H
#define DRIVEBUS_BENCH_TIMING_H
#include <time.h>

static double now_s(void) {
    struct timespec t;
    clock_gettime(CLOCK_MONOTONIC, &t);
    return t.tv_sec + t.tv_nsec / 1e9;
}

static int cmp(const void *a, const void *b) {
    double x = *(const double *)a, y = *(const double *)b;
    return (x > y) - (x < y);
}
#endif
