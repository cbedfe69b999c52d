/* compute.c: the emulated computation, the paper's "time delay" in place of
 * application code. The modes answer different questions:
 *   SLEEP  the DPU is a dedicated processor (more DPUs than cores may share a
 *          machine): sleep until spin_ns before the end, spin the rest, so the
 *          OS wake-up latency does not lengthen the delay;
 *   WALL   busy until this much wall time has passed;
 *   CPU    busy until this thread consumed this much CPU time (preemption
 *          stretches it, as it would real code);
 *   WORK   a fixed number of iterations of a deterministic kernel. Honest
 *          caveat: iterations per us are calibrated on THIS CPU at start-up, so
 *          WORK only shows a slower CPU when the calibration is carried over. */
#include <time.h>

#include "dpu.h"
#include "skelmsg_dpu_t.h"

/* xorshift64 with a multiply: cheap, branch-free, not foldable by the compiler. */
uint64_t compute_work_kernel(uint64_t iterations)
{
    uint64_t x = 0x9e3779b97f4a7c15ULL;
    for (uint64_t i = 0; i < iterations; i++) {
        x ^= x << 13;
        x ^= x >> 7;
        x ^= x << 17;
        x *= 0x2545f4914f6cdd1dULL;
    }
    return x;
}

/* Best of several runs: the fastest is the one least disturbed by preemption. */
int compute_calibrate(skel_compute_t *c)
{
    const uint64_t iterations = 200000;
    volatile uint64_t sink = 0;
    int64_t best = INT64_MAX;
    for (int i = 0; i < 7; i++) {
        int64_t t0 = clock_thread_cpu_ns();
        sink += compute_work_kernel(iterations);
        int64_t dt = clock_thread_cpu_ns() - t0;
        if (dt > 0 && dt < best) best = dt;
    }
    (void)sink;
    if (best == INT64_MAX) return -1;
    c->work_iters_per_us = (double)iterations * 1000.0 / (double)best;
    return 0;
}

static void compute_spin_until(int64_t end_mono)
{
    while (clock_mono_ns() < end_mono) {
    }
}

static void compute_sleep(const skel_compute_t *c, int64_t start, int64_t ns)
{
    int64_t end = start + ns;
    if (ns > c->spin_ns) {
        int64_t wake = end - c->spin_ns;
        struct timespec ts = { .tv_sec = wake / SKEL_NS_PER_S, .tv_nsec = wake % SKEL_NS_PER_S };
        /* EINTR only shortens the sleep; the spin below still ends on time. */
        (void)clock_nanosleep(CLOCK_MONOTONIC, TIMER_ABSTIME, &ts, NULL);
    }
    compute_spin_until(end);
}

static void compute_cpu(int64_t ns)
{
    int64_t end = clock_thread_cpu_ns() + ns;
    while (clock_thread_cpu_ns() < end) {
    }
}

static void compute_work(const skel_compute_t *c, int64_t ns)
{
    volatile uint64_t sink;
    double iterations = (double)ns / 1000.0 * c->work_iters_per_us;
    sink = compute_work_kernel(iterations > 0 ? (uint64_t)iterations : 0);
    (void)sink;
}

/* Emulates NS of computation in MODE; returns the wall time it took. */
int64_t compute_run(const skel_compute_t *c, int mode, int64_t ns)
{
    int64_t start = clock_mono_ns();
    if (ns <= 0) return 0;
    switch (mode) {
    case SKELMSG_DPU_T_COMPUTE_SLEEP: compute_sleep(c, start, ns); break;
    case SKELMSG_DPU_T_COMPUTE_WALL: compute_spin_until(start + ns); break;
    case SKELMSG_DPU_T_COMPUTE_CPU: compute_cpu(ns); break;
    case SKELMSG_DPU_T_COMPUTE_WORK: compute_work(c, ns); break;
    default: break; /* config.c rejects unknown modes */
    }
    return clock_mono_ns() - start;
}
