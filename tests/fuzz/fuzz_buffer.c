/* fuzz_buffer.c: a buffer_t as a link hands it to the DPU (link.c's link_receive: the
 * length checks, wire.c's in-place header reader, buffers.c's slot) during a run, twice
 * as a duplicate would come, then what the process reading it sees at its next cycle
 * (buffers_input_peek/commit). Whatever the header reader accepts, lcm-gen's decoder
 * must read the same. */
#include <limits.h>

#include "fuzz.h"

static skel_plan_t *plan;

/* The in-place reader and the generated decoder agree on every message it accepts. */
static void fuzz_compare_decoder(const uint8_t *data, size_t size)
{
    wire_buffer_hdr_t hdr;
    if (size > INT_MAX || wire_buffer_header(data, (int)size, &hdr) != 0) return;
    skelmsg_buffer_t msg;
    FUZZ_ASSERT(skelmsg_buffer_t_decode(data, 0, (int)size, &msg) >= 0);
    FUZZ_ASSERT(msg.run_id == hdr.run_id && msg.writer == hdr.writer && msg.buffer == hdr.buffer &&
                msg.seq == hdr.seq && msg.send_ns == hdr.send_ns && msg.nbytes == hdr.nbytes);
    FUZZ_ASSERT(hdr.nbytes >= 0 && (size_t)wire_buffer_encoded_size(hdr.nbytes) <= size);
    skelmsg_buffer_t_decode_cleanup(&msg);
}

int LLVMFuzzerTestOneInput(const uint8_t *data, size_t size)
{
    if (plan == NULL) plan = fuzz_fixture_plan(0);
    fuzz_compare_decoder(data, size);
    fuzz_plan_running(plan);
    skel_slot_t *slot = &plan->slots[0];
    lcm_recv_buf_t rbuf = fuzz_recv_buf(data, size);
    link_receive(slot, &rbuf);
    const int64_t newest = slot->newest_seq;
    link_receive(slot, &rbuf);
    FUZZ_ASSERT(slot->received >= 0 && slot->received <= 2 && slot->newest_seq == newest);
    FUZZ_ASSERT(slot->newest_seq == -1 || slot->received > 0);
    for (int i = 0; i < plan->nprocesses; i++) {
        skel_process_t *p = &plan->processes[i];
        for (int q = 0; q < p->ninputs; q++) {
            skel_in_rec_t rec;
            buffers_input_peek(&p->inputs[q], &plan->slots[p->inputs[q].slot], &rec);
            FUZZ_ASSERT(rec.dropped >= 0 && rec.received >= 0 && rec.received <= 2);
            buffers_input_commit(&p->inputs[q], &plan->slots[p->inputs[q].slot], &rec, 1);
            FUZZ_ASSERT(p->inputs[q].n_new + p->inputs[q].n_stale == 1);
        }
    }
    return 0;
}
