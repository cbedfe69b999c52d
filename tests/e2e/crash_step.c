/* crash_step.c: real code that fails, for tests/e2e/test_code_dpus.py (built there with
 * plain cc against include/skel_step.h): a segmentation fault at cycle 100, and a step that
 * computes 10 times its period (10 ms) from cycle 50 on. */
#include <stddef.h>
#include <time.h>

#include "skel_step.h"

SKEL_STEP_DECLARE_ABI;

int crash_at_100(skel_step_t *step)
{
    if (step->cycle == 100) {
        volatile int *nowhere = NULL;
        *nowhere = 1;
    }
    return 0;
}

int slow_from_50(skel_step_t *step)
{
    if (step->cycle < 50) return 0;
    struct timespec t0, now;
    if (clock_gettime(CLOCK_MONOTONIC, &t0) != 0) return -1;
    do {
        if (clock_gettime(CLOCK_MONOTONIC, &now) != 0) return -1;
    } while ((now.tv_sec - t0.tv_sec) * 1000000000L + (now.tv_nsec - t0.tv_nsec) < 100000000L);
    return 0;
}
