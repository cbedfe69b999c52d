/* skel_step.h: the interface between a skeleton process and real application code
 * (docs/how-to/real-code.md). A shared library built against this header alone
 * replaces one process's emulated computation: skel-dpu calls its step function
 * once per cycle, in the compute step, with the bytes the process's writers sent
 * and its output buffers to fill. Nothing of the skeleton's internals is here; the
 * ABI changes only with SKEL_STEP_ABI, which skel-dpu checks when it loads the
 * library (a mismatch refuses the configuration).
 *
 * The library exports:
 *   SKEL_STEP_DECLARE_ABI;                        once, anywhere in the library
 *   int NAME(skel_step_t *step);                  the step function the file names
 *   int NAME_init(void **state, const skel_step_info_t *info);   optional
 *   void NAME_fini(void *state);                  optional
 * A return other than 0 from NAME or NAME_init is that process's fault: counted
 * and reported; a failing init refuses the run's start of that process. */
#ifndef SKEL_STEP_H
#define SKEL_STEP_H

#include <stdint.h>

#ifdef __cplusplus
extern "C" {
#endif

#define SKEL_STEP_ABI 1

/* The ABI version the library was built for, read by skel-dpu with dlsym. */
#define SKEL_STEP_DECLARE_ABI const uint32_t skel_step_abi = SKEL_STEP_ABI

/* One input buffer, as its writer last sent it. */
typedef struct {
    int16_t buffer;           /* the buffer's id in the system file */
    int32_t nbytes;           /* bytes in `bytes` (0: nothing received yet this run) */
    const uint8_t *bytes;     /* valid during this call only */
    int64_t seq;              /* the writer's cycle that sent it, -1: nothing yet */
    int32_t is_new;           /* 1: newer than what this process used last cycle */
} skel_step_input_t;

/* One output buffer: fill `bytes` and set `nbytes` (at most `capacity`, the size the
 * system file declares; it starts at `capacity`). A larger `nbytes` is a fault of
 * the process: that cycle publishes none of its outputs. */
typedef struct {
    int16_t buffer;
    int32_t capacity;
    int32_t nbytes;
    uint8_t *bytes;
} skel_step_output_t;

/* What one call gets. */
typedef struct {
    int64_t cycle;            /* the process's cycle index: its outputs carry it as their seq */
    int32_t ninputs;
    const skel_step_input_t *inputs;   /* in the order of the process's `inputs` */
    int32_t noutputs;
    skel_step_output_t *outputs;       /* in the order of the process's `outputs` */
    void *state;              /* what NAME_init set, kept between cycles */
} skel_step_t;

/* What NAME_init is told once, before a run's first cycle. */
typedef struct {
    int16_t process;          /* the process's id and name */
    const char *name;
    int32_t period_us;
    int32_t ninputs, noutputs;
} skel_step_info_t;

typedef int (*skel_step_fn)(skel_step_t *step);
typedef int (*skel_step_init_fn)(void **state, const skel_step_info_t *info);
typedef void (*skel_step_fini_fn)(void *state);

#ifdef __cplusplus
}
#endif

#endif
