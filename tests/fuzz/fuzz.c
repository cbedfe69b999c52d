/* fuzz.c: the harnesses' shared parts (fuzz.h). */
#include <sanitizer/common_interface_defs.h>
#include <stdio.h>

#include "fixture.h"
#include "fuzz.h"

_Noreturn void fuzz_fail(const char *what, const char *file, int line)
{
    char summary[512];
    snprintf(summary, sizeof summary, "%s at %s:%d", what, file, line);
    /* libFuzzer closes the target's stderr (-close_fd_mask=2); a sanitizer's report still
     * reaches the terminal, so the broken invariant is said that way. */
    __sanitizer_report_error_summary(summary);
    __builtin_trap();
}

skel_plan_t *fuzz_fixture_plan(int events)
{
    static fixture_t f; /* the plan keeps no pointer into it, but it is large for a stack */
    char reason[SKEL_REASON_LEN];
    fixture_init(&f);
    if (events) {
        f.procs[1].sync = SKELMSG_PROCESS_T_SYNC_EVENT;
        f.procs[1].event = (char *)"go";
        f.procs[1].queue = 2;
        f.procs[2].sync = SKELMSG_PROCESS_T_SYNC_EVENT;
        f.procs[2].event = (char *)"go";
        f.procs[2].queue = 1;
    }
    if (config_validate(&f.cfg, 1, reason, sizeof reason) != 0) fuzz_fail(reason, __FILE__, __LINE__);
    skel_plan_t *plan = plan_build(&f.cfg, 1, reason, sizeof reason);
    if (plan == NULL) fuzz_fail(reason, __FILE__, __LINE__);
    FUZZ_ASSERT(plan->nlinks == 2 && plan->nslots == 1); /* the ports of p1, read here, and of p3 */
    if (events) plan->event_link = 0;
    return plan;
}

void fuzz_plan_running(skel_plan_t *plan)
{
    static atomic_int_fast64_t rejected;
    plan_reset_run(plan, FUZZ_RUN_ID);
    plan->rejected = &rejected;
    plan->running = 1;
    for (int i = 0; i < plan->nlinks; i++) plan->links[i].last_arrival_ns = 0;
}

lcm_recv_buf_t fuzz_recv_buf(const uint8_t *data, size_t size)
{
    /* LCM gives at most LCM_MAX_MESSAGE_SIZE bytes; libFuzzer's inputs are far shorter. */
    return (lcm_recv_buf_t){ .data = (void *)data, .data_size = (uint32_t)size,
                             .recv_utime = clock_utc_ns() / 1000, .lcm = NULL };
}

int fuzz_frame(fuzz_frames_t *f, uint8_t *tag, const uint8_t **msg, size_t *len)
{
    if (f->left == 0) return 0;
    *tag = f->at[0];
    size_t want = f->left >= 3 ? (size_t)f->at[1] << 8 | f->at[2] : 0;
    size_t head = f->left >= 3 ? 3 : f->left;
    f->at += head;
    f->left -= head;
    *len = want < f->left ? want : f->left;
    *msg = f->at;
    f->at += *len;
    f->left -= *len;
    return 1;
}
