/* sum.c: the example of real code (docs/how-to/real-code.md), built by `make` into
 * build/examples/libsum.so with nothing but the header:
 *   cc -std=c11 -O2 -fPIC -shared -Iinclude -o libsum.so examples/code/sum.c
 * examples/code/sum.yaml runs it: sum_source writes bytes that change every cycle,
 * sum_bytes sums the bytes its input's writer sent into its output. */
#include <stdlib.h>

#include "skel_step.h"

SKEL_STEP_DECLARE_ABI;

static void put_u64(uint8_t *at, uint64_t v)
{
    for (int i = 0; i < 8; i++) at[i] = (uint8_t)(v >> (8 * i)); /* little-endian, on any host */
}

/* Each output's byte i at cycle k: (7k + 3i) mod 256, so every cycle's sum differs. */
int sum_source(skel_step_t *step)
{
    for (int32_t q = 0; q < step->noutputs; q++) {
        skel_step_output_t *out = &step->outputs[q];
        for (int32_t i = 0; i < out->capacity; i++) out->bytes[i] = (uint8_t)(7 * step->cycle + 3 * i);
    }
    return 0;
}

/* The state kept between cycles: how many cycles had no input yet. */
typedef struct {
    int64_t waited;
} sum_state_t;

int sum_bytes_init(void **state, const skel_step_info_t *info)
{
    (void)info;
    *state = calloc(1, sizeof(sum_state_t));
    return *state != NULL ? 0 : -1;
}

void sum_bytes_fini(void *state)
{
    free(state);
}

/* Output 0: the sequence number of the input it summed (int64), then the sum of its
 * bytes (uint64), both little-endian: 16 bytes. */
int sum_bytes(skel_step_t *step)
{
    sum_state_t *st = step->state;
    if (step->ninputs < 1 || step->noutputs < 1 || step->outputs[0].capacity < 16) return -1;
    const skel_step_input_t *in = &step->inputs[0];
    if (in->seq < 0) st->waited++;
    uint64_t sum = 0;
    for (int32_t i = 0; i < in->nbytes; i++) sum += in->bytes[i];
    put_u64(step->outputs[0].bytes, (uint64_t)in->seq);
    put_u64(step->outputs[0].bytes + 8, sum);
    step->outputs[0].nbytes = 16;
    return 0;
}

/* A faulty step for the tests: it says it wrote one byte more than its output holds. */
int sum_overlong(skel_step_t *step)
{
    if (step->noutputs > 0) step->outputs[0].nbytes = step->outputs[0].capacity + 1;
    return 0;
}

/* A faulty step for the tests: it writes 8 bytes past its output's end, and says it wrote the
 * output's size. */
int sum_past_end(skel_step_t *step)
{
    if (step->noutputs > 0) {
        skel_step_output_t *out = &step->outputs[0];
        for (int32_t i = 0; i < out->capacity + 8; i++) out->bytes[i] = 0xEE;
        out->nbytes = out->capacity;
    }
    return 0;
}
