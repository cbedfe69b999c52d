/* fuzz.h: what the libFuzzer harnesses share (fuzz.c). Each harness feeds the bytes
 * libFuzzer makes into one path by which received bytes reach a DPU's state, as the
 * daemon's threads would, without their threads and without a network: fuzz_buffer
 * (a buffer_t on a link), fuzz_event (an event_t), fuzz_config (a config_t up to the
 * built plan), fuzz_command (configs and commands through command.c), fuzz_seal (the
 * seal check a keyed DPU runs first). */
#ifndef SKEL_FUZZ_H
#define SKEL_FUZZ_H

#include <stddef.h>
#include <stdint.h>

#include "dpu.h"

int LLVMFuzzerTestOneInput(const uint8_t *data, size_t size);

/* An invariant of the DPU's state that an input broke: a crash libFuzzer keeps, with
 * the condition as the report's summary (stderr is closed while fuzzing). */
#define FUZZ_ASSERT(cond)                                                   \
    do {                                                                    \
        if (!(cond)) fuzz_fail("FUZZ_ASSERT(" #cond ")", __FILE__, __LINE__); \
    } while (0)
_Noreturn void fuzz_fail(const char *what, const char *file, int line);

/* What the harnesses build from tests/c/fixture.h's config (DPU 2's part: it reads
 * buffer 1 from process 1 over the multicast link), links not opened. With EVENTS,
 * DPU 2's processes 2 and 3 await the event "go" (queues of 2 and 1) and the plan's
 * one link stands for the control URL event_open would have opened. */
#define FUZZ_RUN_ID 1
skel_plan_t *fuzz_fixture_plan(int events);

/* A plan during run FUZZ_RUN_ID, as the executive has it when it drains its links. */
void fuzz_plan_running(skel_plan_t *plan);

/* The lcm_recv_buf_t LCM hands a handler for DATA (SIZE bytes) received now. */
lcm_recv_buf_t fuzz_recv_buf(const uint8_t *data, size_t size);

/* A fuzz input holding several messages: frames of [tag][length, 2 bytes big-endian]
 * [length bytes]. fuzz_frame gives the next (1) or says there is none left (0); a
 * truncated last frame is given as far as it goes. */
typedef struct {
    const uint8_t *at;
    size_t left;
} fuzz_frames_t;

int fuzz_frame(fuzz_frames_t *f, uint8_t *tag, const uint8_t **msg, size_t *len);

#endif
