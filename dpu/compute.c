/* compute.c: the emulated computation, the paper's "time delay" in place of
 * application code. The modes answer different questions:
 *   SLEEP  the DPU is a dedicated processor (more DPUs than cores may share a
 *          machine): sleep until spin_ns before the end, spin the rest, so the
 *          OS wake-up latency does not lengthen the delay;
 *   WALL   busy until this much wall time has passed;
 *   CPU    busy until this thread has held the processor this long: the time
 *          its own looks at the clock, at most the stall threshold apart,
 *          cover (a longer gap is time something else had the CPU). Not the
 *          kernel's thread CPU clock: on a VM it charges the thread what the
 *          hypervisor took (hiccups the guest does not see as steal: 1.5-2 %
 *          of the time on our CI's VM) and lags by up to a scheduler tick
 *          before it catches up in one jump: paced by it, a 3 ms computation
 *          was seen to run 3.8 ms;
 *   WORK   a fixed number of iterations of a deterministic kernel, calibrated
 *          when the daemon starts (the reference) and checked at every run
 *          start: a slower or throttled CPU takes longer, as real code would.
 * What a cycle reports as its compute: the time the computation ran, i.e. the
 * wall time for SLEEP, WALL and WORK and the time it held the processor for
 * CPU, less the time the thread was kept from running. That time is not
 * computation: it lengthens the cycle (response, slack, overruns) and shows as
 * % overhead and as stalls, so % compute is what the computations took even on
 * a CPU the DPU shares.
 *
 * Every mode also reports how much later than asked the thread's not running
 * made it end (stalls): SLEEP and WALL by a wake-up or a gap between two looks
 * at the clock longer than the stall threshold (50 us: far above a look at the
 * clock, above most wake-up latencies) that carried them past their end, CPU
 * by its wall time less the time it ran, WORK by what its chunks took beyond
 * their work. That is the platform's (the machine, the hypervisor, other
 * threads on the CPU), not the design's. */
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

/* WORK's kernel runs in chunks of this much work, the clock read after each. */
#define COMPUTE_WORK_CHUNK_NS 10000

/* Runs ITERATIONS of the kernel in chunks of CHUNK, the wall clock read after
 * each from PREV on, as every WORK computation does; a chunk that took longer
 * than its work at RATE (iterations per us) by more than STALL_NS adds that
 * excess to *LOST. */
static void compute_work_chunks(uint64_t iterations, uint64_t chunk, double rate, int64_t prev,
                                int64_t stall_ns, int64_t *lost)
{
    volatile uint64_t sink = 0;
    uint64_t left = iterations;
    while (left > 0) {
        uint64_t n = left < chunk ? left : chunk;
        sink += compute_work_kernel(n);
        left -= n;
        int64_t now = clock_mono_ns();
        int64_t over = now - prev - (int64_t)((double)n * 1000.0 / rate);
        if (over > stall_ns) *lost += over;
        prev = now;
    }
    (void)sink;
}

static uint64_t compute_chunk(double rate)
{
    uint64_t chunk = (uint64_t)llround(rate * COMPUTE_WORK_CHUNK_NS / 1000.0);
    return chunk < 1 ? 1 : chunk;
}

/* Median thread CPU time of RUNS runs of ITERATIONS of the kernel, run as a
 * computation at RATE runs it, clock reads and stall checks and all (they cost
 * 0.2 % of it here: calibrated without them, WORK computed that much longer
 * than asked). The median, not the best, because a cycle's computation is a
 * typical run, not the luckiest. */
static int64_t compute_kernel_median_ns(const skel_compute_t *c, uint64_t iterations, double rate, int runs)
{
    int64_t v[CALIBRATION_RUNS_MAX], lost = 0;
    if (runs > CALIBRATION_RUNS_MAX) runs = CALIBRATION_RUNS_MAX;
    for (int i = 0; i < runs; i++) {
        int64_t t0 = clock_thread_cpu_ns();
        compute_work_chunks(iterations, compute_chunk(rate), rate, clock_mono_ns(), c->stall_ns, &lost);
        v[i] = clock_thread_cpu_ns() - t0;
    }
    compute_sort(v, runs);
    return v[runs / 2];
}

/* Iterations per us of the WORK kernel on this CPU, measured as it runs in a
 * cycle (thread CPU time, the median of RUNS runs); -1 on failure. Runs of 4 ms,
 * as long as a scheduler tick at 250 Hz: the interrupts a computation of
 * milliseconds absorbs (about 1.5 % here) are in the rate, which runs of a
 * fraction of a millisecond miss. */
static double compute_measure_rate(const skel_compute_t *c, int runs)
{
    /* A rough rate first: 100 000 iterations, chunked as if 1000 ran per us */
    int64_t probe = compute_kernel_median_ns(c, 100000, 1000.0, 3);
    if (probe <= 0) return -1;
    double guess = 100000.0 * 1000.0 / (double)probe;
    uint64_t n = (uint64_t)(guess * CALIBRATION_RUN_NS / 1000.0);
    if (n < 1000) n = 1000;
    int64_t t = compute_kernel_median_ns(c, n, guess, runs);
    if (t <= 0) return -1;
    return (double)n * 1000.0 / (double)t;
}

/* The reference: the fastest of three batches 20 ms apart, each the median of its
 * runs, so a neighbour busy during one batch (a daemon starting beside it) does not
 * set how much work every later computation does. */
int compute_calibrate(skel_compute_t *c)
{
    double best = -1;
    for (int batch = 0; batch < 3; batch++) {
        if (batch > 0) {
            struct timespec gap = { .tv_sec = 0, .tv_nsec = 20 * 1000 * 1000 };
            (void)nanosleep(&gap, NULL);
        }
        double rate = compute_measure_rate(c, CALIBRATION_RUNS_MAX / 3);
        if (rate > best) best = rate;
    }
    if (!(best > 0)) return -1;
    c->work_iters_per_us = best;
    return 0;
}

/* The start-up calibration stays the reference (so a throttled CPU shows as
 * slower); a run start only measures how far today's CPU is from it. */
double compute_check_calibration(const skel_compute_t *c)
{
    double rate = compute_measure_rate(c, 5);
    if (!(rate > 0) || !(c->work_iters_per_us > 0)) return 0.0;
    return 100.0 * (c->work_iters_per_us - rate) / rate; /* > 0: the kernel now runs slower */
}

/* Spins until END. PREV is when the thread should last have been running: when
 * the last look at the clock comes a stall after the one before and past END,
 * the computation ended late because the thread was not running, and that
 * overshoot is added to *STALL. A stall that ends before END delays nothing. */
static void compute_spin_until(const skel_compute_t *c, int64_t prev, int64_t end, int64_t *stall)
{
    int64_t now = clock_mono_ns();
    while (now < end) {
        prev = now;
        now = clock_mono_ns();
    }
    if (now - prev > c->stall_ns) *stall += now - end;
}

static void compute_sleep(const skel_compute_t *c, int64_t start, int64_t ns, int64_t *stall)
{
    int64_t end = start + ns, wake = start;
    if (ns > c->spin_ns) {
        wake = end - c->spin_ns;
        /* Ending early only shortens the sleep; the spin below still ends on time. */
        (void)clock_nap(wake);
    }
    compute_spin_until(c, wake, end, stall);
}

int64_t compute_held(const skel_compute_t *c, int64_t ns, int64_t *unswitched)
{
    int64_t held = 0, prev = clock_mono_ns();
    int64_t switches = unswitched != NULL ? clock_thread_preemptions() : 0;
    while (held < ns) {
        int64_t now = clock_mono_ns(), gap = now - prev;
        if (gap <= c->stall_ns) {
            held += gap; /* a look takes far less */
        } else if (unswitched != NULL) { /* gaps are rare: a system call each is cheap */
            int64_t s = clock_thread_preemptions();
            if (s == switches) *unswitched += gap;
            switches = s;
        }
        prev = now;
    }
    return held;
}

/* Runs the kernel for NS of work at the calibrated rate, from START. A chunk
 * that took longer than its work by more than the stall threshold was kept
 * from running (a stop of the machine, a preemption) for that excess: added to
 * *LOST, so that it is not the computation's. Read by the wall clock, not the
 * thread's CPU clock, which lags and jumps on a VM (see CPU above). A CPU
 * slower than at calibration, even 5 times, makes every chunk longer by less
 * than the threshold: that is the computation's, as in real code. */
static void compute_work(const skel_compute_t *c, int64_t start, int64_t ns, int64_t *lost)
{
    double rate = c->work_iters_per_us;
    if (!(rate > 0)) return;
    double iterations = (double)ns / 1000.0 * rate;
    compute_work_chunks(iterations > 0 ? (uint64_t)llround(iterations) : 0, compute_chunk(rate), rate,
                        start, c->stall_ns, lost);
}

/* Emulates NS of computation in MODE; returns the compute it reports (the time
 * it ran) and adds the time it was kept from running to *STALL. */
int64_t compute_run(const skel_compute_t *c, int mode, int64_t ns, int64_t *stall)
{
    if (ns <= 0) return 0;
    int64_t start = clock_mono_ns(), lost = 0;
    switch (mode) {
    case SKELMSG_DPU_T_COMPUTE_SLEEP: compute_sleep(c, start, ns, &lost); break;
    case SKELMSG_DPU_T_COMPUTE_WALL: compute_spin_until(c, start, start + ns, &lost); break;
    case SKELMSG_DPU_T_COMPUTE_WORK: compute_work(c, start, ns, &lost); break;
    case SKELMSG_DPU_T_COMPUTE_CPU: {
        int64_t used = compute_held(c, ns, NULL);
        int64_t off = clock_mono_ns() - start - used; /* the time it was not running */
        if (off > c->stall_ns) *stall += off;
        return used;
    }
    default: break; /* config.c rejects unknown modes */
    }
    *stall += lost;
    return clock_mono_ns() - start - lost;
}
