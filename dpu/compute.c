/* compute.c: the emulated computation, the paper's "time delay" in place of
 * application code. The modes answer different questions:
 *   SLEEP  the DPU is a dedicated processor (more DPUs than cores may share a
 *          machine): sleep until spin_ns before the end, spin the rest, so the
 *          OS wake-up latency does not lengthen the delay;
 *   WALL   busy until this much wall time has passed;
 *   CPU    busy until this thread consumed this much CPU time;
 *   WORK   a fixed number of iterations of a deterministic kernel, calibrated
 *          when the daemon starts (the reference) and checked at every run
 *          start: a slower or throttled CPU takes longer, as real code would.
 * What a cycle reports as its compute: the wall time for SLEEP and WALL (that
 * is what they emulate), the thread's CPU time for CPU and WORK. Time a CPU or
 * WORK computation spends preempted is not computation: it lengthens the
 * cycle (response, slack, overruns) and shows as % overhead, so % compute is
 * what the computations consumed even on a CPU the DPU shares.
 *
 * Every mode also reports stalls: a wake-up later than asked, or a gap between
 * two looks at the clock, longer than the stall threshold means the thread was
 * kept from running (the machine, the hypervisor, another real-time thread):
 * the platform, not the design. */
#include <math.h>
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

static void compute_sort(int64_t *v, int n)
{
    for (int i = 1; i < n; i++)
        for (int j = i; j > 0 && v[j] < v[j - 1]; j--) {
            int64_t t = v[j];
            v[j] = v[j - 1];
            v[j - 1] = t;
        }
}

/* Median thread CPU time of RUNS runs of the kernel for ITERATIONS: the median,
 * not the best, because a cycle's computation is a typical run, not the luckiest. */
static int64_t compute_kernel_median_ns(uint64_t iterations, int runs)
{
    int64_t v[CALIBRATION_RUNS_MAX];
    volatile uint64_t sink = 0;
    if (runs > CALIBRATION_RUNS_MAX) runs = CALIBRATION_RUNS_MAX;
    for (int i = 0; i < runs; i++) {
        int64_t t0 = clock_thread_cpu_ns();
        sink += compute_work_kernel(iterations);
        v[i] = clock_thread_cpu_ns() - t0;
    }
    (void)sink;
    compute_sort(v, runs);
    return v[runs / 2];
}

/* Iterations per us of the WORK kernel on this CPU, measured as it runs in a
 * cycle (thread CPU time, the median of RUNS runs); -1 on failure. Runs of 4 ms,
 * as long as a scheduler tick at 250 Hz: the interrupts a computation of
 * milliseconds absorbs (about 1.5 % here) are in the rate, which runs of a
 * fraction of a millisecond miss. */
static double compute_measure_rate(int runs)
{
    int64_t probe = compute_kernel_median_ns(100000, 3);
    if (probe <= 0) return -1;
    uint64_t n = (uint64_t)(100000.0 * CALIBRATION_RUN_NS / (double)probe);
    if (n < 1000) n = 1000;
    int64_t t = compute_kernel_median_ns(n, runs);
    if (t <= 0) return -1;
    return (double)n * 1000.0 / (double)t;
}

int compute_calibrate(skel_compute_t *c)
{
    double rate = compute_measure_rate(CALIBRATION_RUNS_MAX);
    if (!(rate > 0)) return -1;
    c->work_iters_per_us = rate;
    return 0;
}

/* The start-up calibration stays the reference (so a throttled CPU shows as
 * slower); a run start only measures how far today's CPU is from it. */
double compute_check_calibration(const skel_compute_t *c)
{
    double rate = compute_measure_rate(5);
    if (!(rate > 0) || !(c->work_iters_per_us > 0)) return 0.0;
    return 100.0 * (c->work_iters_per_us - rate) / rate; /* > 0: the kernel now runs slower */
}

/* Adds to *STALL every gap between two clock readings above the threshold. */
static int64_t compute_spin_until(const skel_compute_t *c, int64_t end_mono, int64_t *stall)
{
    int64_t prev = clock_mono_ns(), now = prev;
    while (now < end_mono) {
        now = clock_mono_ns();
        if (now - prev > c->stall_ns) *stall += now - prev;
        prev = now;
    }
    return now;
}

static void compute_sleep(const skel_compute_t *c, int64_t start, int64_t ns, int64_t *stall)
{
    int64_t end = start + ns;
    if (ns > c->spin_ns) {
        int64_t wake = end - c->spin_ns;
        struct timespec ts = { .tv_sec = wake / SKEL_NS_PER_S, .tv_nsec = wake % SKEL_NS_PER_S };
        /* EINTR only shortens the sleep; the spin below still ends on time. */
        (void)clock_nanosleep(CLOCK_MONOTONIC, TIMER_ABSTIME, &ts, NULL);
        int64_t late = clock_mono_ns() - wake;
        if (late > c->stall_ns) *stall += late;
    }
    (void)compute_spin_until(c, end, stall);
}

static void compute_cpu(const skel_compute_t *c, int64_t ns, int64_t *stall)
{
    int64_t end = clock_thread_cpu_ns() + ns;
    int64_t prev = clock_mono_ns();
    while (clock_thread_cpu_ns() < end) {
        int64_t now = clock_mono_ns();
        if (now - prev > c->stall_ns) *stall += now - prev;
        prev = now;
    }
}

static void compute_work(const skel_compute_t *c, int64_t ns)
{
    volatile uint64_t sink;
    double iterations = (double)ns / 1000.0 * c->work_iters_per_us;
    sink = compute_work_kernel(iterations > 0 ? (uint64_t)llround(iterations) : 0);
    (void)sink;
}

/* Emulates NS of computation in MODE; returns the compute it reports (the wall
 * time for SLEEP and WALL, the thread CPU time for CPU and WORK) and adds the
 * stalls it saw to *STALL. */
int64_t compute_run(const skel_compute_t *c, int mode, int64_t ns, int64_t *stall)
{
    if (ns <= 0) return 0;
    int64_t start = clock_mono_ns();
    switch (mode) {
    case SKELMSG_DPU_T_COMPUTE_SLEEP: compute_sleep(c, start, ns, stall); break;
    case SKELMSG_DPU_T_COMPUTE_WALL: (void)compute_spin_until(c, start + ns, stall); break;
    case SKELMSG_DPU_T_COMPUTE_CPU:
    case SKELMSG_DPU_T_COMPUTE_WORK: {
        int64_t cpu0 = clock_thread_cpu_ns();
        if (mode == SKELMSG_DPU_T_COMPUTE_CPU) compute_cpu(c, ns, stall);
        else compute_work(c, ns);
        int64_t used = clock_thread_cpu_ns() - cpu0;
        /* WORK has no clock in its loop: what it lost is its wall time less its CPU time. */
        int64_t lost = clock_mono_ns() - start - used;
        if (mode == SKELMSG_DPU_T_COMPUTE_WORK && lost > c->stall_ns) *stall += lost;
        return used;
    }
    default: break; /* config.c rejects unknown modes */
    }
    return clock_mono_ns() - start;
}
