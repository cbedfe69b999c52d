/* fuzz_event.c: an event_t as the control URL's link hands it to the DPU (event.c's
 * event_receive: the length check, wire.c's in-place header reader) during a run,
 * three times, to two processes awaiting it (queues of 2 and 1, so one keeps the
 * newest and the other drops), then each process's next cycle takes its event as the
 * cyclic executive does (event_settle, event_release). Whatever the header reader
 * accepts, lcm-gen's decoder must read the same. */
#include <limits.h>
#include <string.h>

#include "fuzz.h"

static skel_plan_t *plan;

static void fuzz_compare_decoder(const uint8_t *data, size_t size)
{
    wire_event_hdr_t hdr;
    if (size > INT_MAX || wire_event_header(data, (int)size, &hdr) != 0) return;
    skelmsg_event_t msg;
    FUZZ_ASSERT(skelmsg_event_t_decode(data, 0, (int)size, &msg) >= 0);
    FUZZ_ASSERT(msg.run_id == hdr.run_id && msg.dpu == hdr.dpu && msg.process == hdr.process &&
                msg.seq == hdr.seq && msg.sent_ns == hdr.sent_ns);
    FUZZ_ASSERT(msg.name != NULL && strlen(msg.name) < size);
    skelmsg_event_t_decode_cleanup(&msg);
}

int LLVMFuzzerTestOneInput(const uint8_t *data, size_t size)
{
    if (plan == NULL) plan = fuzz_fixture_plan(1);
    fuzz_compare_decoder(data, size);
    fuzz_plan_running(plan);
    FUZZ_ASSERT(plan->nevents == 1 && plan->events[0].awaited);
    lcm_recv_buf_t rbuf = fuzz_recv_buf(data, size);
    for (int n = 0; n < 3; n++) event_receive(&plan->events[0], &rbuf);
    const int64_t now = clock_mono_ns();
    for (int i = 0; i < plan->nprocesses; i++) {
        skel_process_t *p = &plan->processes[i];
        if (p->event < 0) continue;
        FUZZ_ASSERT(p->queue.a_count >= 0 && p->queue.a_count <= 3);
        event_settle(plan, p, INT64_MAX);
        FUZZ_ASSERT(p->queue.count >= 0 && p->queue.count <= p->queue.cap);
        if (!event_pending(p)) continue;
        event_release(plan, p, now);
        FUZZ_ASSERT(p->queue.taken_ns >= 0 && p->queue.taken_ns <= now && p->queue.taken_left >= 0 &&
                    p->queue.taken_left < p->queue.cap && p->queue.taken_dropped >= 0);
    }
    return 0;
}
