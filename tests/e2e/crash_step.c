/* crash_step.c: real code that crashes, for tests/e2e/test_code_dpus.py (built there with
 * plain cc against include/skel_step.h): a segmentation fault at cycle 100. */
#include <stddef.h>

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
