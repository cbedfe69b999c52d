/* test_compute.c: each compute mode emulates the time asked. SLEEP and WALL
 * report wall time (the median of five within 0.5 ms: one run can meet a
 * stop of the machine), CPU the time the thread held the processor and WORK the wall time
 * of its chunks of work less what a chunk took beyond its work, which another
 * process on the core does not stretch: those are held close to what was
 * asked. */
#include <math.h>

#include "check.h"
#include "dpu.h"
#include "skelmsg_dpu_t.h"

static int64_t median(int64_t *v, int n)
{
    for (int i = 0; i < n; i++)
        for (int j = i + 1; j < n; j++)
            if (v[j] < v[i]) { int64_t t = v[i]; v[i] = v[j]; v[j] = t; }
    return v[n / 2];
}

/* The median over five runs of the compute each run reports. */
static int64_t median_of(const skel_compute_t *c, int mode, int64_t ns)
{
    int64_t v[5], stall = 0;
    for (int i = 0; i < 5; i++) v[i] = compute_run(c, mode, ns, &stall);
    return median(v, 5);
}

static void test_modes(void)
{
    skel_compute_t c = { .spin_ns = 150000, .stall_ns = SKEL_STALL_NS };
    CHECK_EQ(compute_calibrate(&c), 0);
    CHECK(c.work_iters_per_us > 1.0);
    const int64_t ns = 2000000;
    int64_t sleep_ns = median_of(&c, SKELMSG_DPU_T_COMPUTE_SLEEP, ns);
    int64_t wall_ns = median_of(&c, SKELMSG_DPU_T_COMPUTE_WALL, ns);
    int64_t cpu_ns = median_of(&c, SKELMSG_DPU_T_COMPUTE_CPU, ns);
    /* WORK's speed moves with the load on a shared VM: calibrate and measure side
     * by side, ROUNDS times, and judge the median, each taken back by the
     * kernel's drift from its calibration measured just before and just after
     * it (the mean of the two), as a run says it. Not taken back, 4 of 30 runs
     * here came out 7-11 % long: the calibration (the fastest of three batches)
     * against a speed whose p10 and p90 over runs of 130 us were 10-30 % apart,
     * in spells of 100-200 ms up to 2.7 times slower. */
    enum { ROUNDS = 9 };
    int64_t works[ROUNDS], ran[ROUNDS], drifts[ROUNDS]; /* drifts in hundredths of a percent */
    for (int i = 0; i < ROUNDS; i++) {
        CHECK_EQ(compute_calibrate(&c), 0);
        double before = compute_check_calibration(&c);
        ran[i] = median_of(&c, SKELMSG_DPU_T_COMPUTE_WORK, ns);
        double after = compute_check_calibration(&c);
        drifts[i] = llround(before * 100.0);
        works[i] = llround((double)ran[i] / (1.0 + (before + after) / 200.0));
    }
    int64_t work_ns = median(works, ROUNDS);
    printf("2 ms asked: sleep %.3f wall %.3f ms (wall time), cpu %.3f work %.3f ms (time run; "
           "%.3f ms before its drift was taken back)\n",
           sleep_ns / 1e6, wall_ns / 1e6, cpu_ns / 1e6, work_ns / 1e6, median(ran, ROUNDS) / 1e6);
    /* Medians of five runs: 2.000 ms each in 5 runs here, beside a probe that woke up to 5 ms
     * late (2026-12-02); a bound of 5 ms came without a measured cause. */
    CHECK(sleep_ns >= ns && sleep_ns < ns + 500000);
    CHECK(wall_ns >= ns && wall_ns < ns + 500000);
    CHECK(cpu_ns >= ns && cpu_ns < ns + ns / 200); /* within 0.5 % */
    /* This checks the calibration is the one used (a computation that ran 7 %
     * more work than it says fails here); how close the calibration comes to the
     * speed of the moment is the drift checked below, and `make bench` measures
     * it on a quiet machine. 5 %: a CI run beside a build measured 2.21 %, and 5
     * runs here (2026-12-02) -0.9 to +2.1 %: 2 % fails one run in five. */
    CHECK(work_ns > ns - ns / 20 && work_ns < ns + ns / 20);
    /* SLEEP below the spin stretch is a pure spin; zero is free. */
    int64_t stall = 0;
    int64_t short_ns = compute_run(&c, SKELMSG_DPU_T_COMPUTE_SLEEP, 50000, &stall);
    CHECK(short_ns >= 50000 && short_ns < 1000000); /* 0.050 ms in each of 5 runs here */
    CHECK_EQ(compute_run(&c, SKELMSG_DPU_T_COMPUTE_WALL, 0, &stall), 0);
    /* The run-start check finds the calibration it was made with: the median of
     * the checks just after each, as one alone here ranged from 29 % faster to
     * 2.7 times slower within a second. */
    double drift = (double)median(drifts, ROUNDS) / 100.0;
    printf("WORK calibration drift %.2f %% (the median of %d)\n", drift, ROUNDS);
    CHECK(drift > -25.0 && drift < 25.0);
    /* The kernel is deterministic. */
    CHECK(compute_work_kernel(1000) == compute_work_kernel(1000));
    CHECK(compute_work_kernel(1000) != compute_work_kernel(1001));
}

/* A wake-up past the end longer than the stall threshold is reported as a
 * stall, and nothing shorter: no real wake-up is 0 ns late, none is a second
 * late. Without the final spin, the sleep itself ends past the end. */
static void test_stalls(void)
{
    skel_compute_t c = { .spin_ns = 0, .stall_ns = 0 };
    int64_t stall = 0;
    compute_run(&c, SKELMSG_DPU_T_COMPUTE_SLEEP, 2000000, &stall);
    CHECK(stall > 0);
    c.stall_ns = SKEL_NS_PER_S;
    stall = 0;
    compute_run(&c, SKELMSG_DPU_T_COMPUTE_SLEEP, 2000000, &stall);
    compute_run(&c, SKELMSG_DPU_T_COMPUTE_WALL, 2000000, &stall);
    compute_run(&c, SKELMSG_DPU_T_COMPUTE_CPU, 2000000, &stall);
    CHECK_EQ(stall, 0);
}

/* CPU is paced by what the thread saw of itself running, never by the kernel's
 * thread CPU clock: on a VM that clock lags and then jumps by up to a tick, and
 * paced by it one 250 us computation in a few hundred here reported more than
 * 350 us (2000 runs: 1 to 5 such, up to 3.4 ms). Each run ends within a look at
 * the clock (at most the stall threshold) of what was asked, and no run reports
 * more than the wall time it took. */
static void test_cpu_is_held_time(void)
{
    skel_compute_t c = { .spin_ns = 150000, .stall_ns = SKEL_STALL_NS };
    const int64_t ns = 250000;
    int over = 0, beyond_wall = 0;
    for (int i = 0; i < 2000; i++) {
        int64_t stall = 0, t0 = clock_mono_ns();
        int64_t ran = compute_run(&c, SKELMSG_DPU_T_COMPUTE_CPU, ns, &stall);
        int64_t wall = clock_mono_ns() - t0;
        if (ran < ns || ran > ns + SKEL_STALL_NS) over++;
        if (ran > wall) beyond_wall++;
    }
    CHECK_EQ(over, 0);
    CHECK_EQ(beyond_wall, 0);
}

/* SLEEP leaves the CPU to others for most of the delay; WALL does not. */
static void test_sleep_yields_cpu(void)
{
    skel_compute_t c = { .spin_ns = 150000, .stall_ns = SKEL_STALL_NS };
    int64_t t0 = clock_thread_cpu_ns(), stall = 0;
    compute_run(&c, SKELMSG_DPU_T_COMPUTE_SLEEP, 5000000, &stall);
    int64_t used = clock_thread_cpu_ns() - t0;
    CHECK(used < 2500000);
}

int main(void)
{
    test_modes();
    test_stalls();
    test_cpu_is_held_time();
    test_sleep_yields_cpu();
    return CHECK_DONE();
}
