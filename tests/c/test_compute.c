/* test_compute.c: each compute mode emulates the time asked. SLEEP and WALL
 * are judged on wall time (generous upper bounds: the machine running the
 * tests may be busy), CPU and WORK on this thread's CPU time, which another
 * process on the core does not stretch. */
#include "check.h"
#include "dpu.h"
#include "skelmsg_dpu_t.h"

/* The median over five runs of the wall time taken, or of the CPU time used. */
static int64_t median_of(const skel_compute_t *c, int mode, int64_t ns, int cpu_time)
{
    int64_t v[5];
    for (int i = 0; i < 5; i++) {
        int64_t t0 = clock_thread_cpu_ns();
        v[i] = compute_run(c, mode, ns);
        if (cpu_time) v[i] = clock_thread_cpu_ns() - t0;
    }
    for (int i = 0; i < 5; i++)
        for (int j = i + 1; j < 5; j++)
            if (v[j] < v[i]) { int64_t t = v[i]; v[i] = v[j]; v[j] = t; }
    return v[2];
}

static void test_modes(void)
{
    skel_compute_t c = { .spin_ns = 150000 };
    CHECK_EQ(compute_calibrate(&c), 0);
    CHECK(c.work_iters_per_us > 1.0);
    const int64_t ns = 2000000;
    int64_t sleep_ns = median_of(&c, SKELMSG_DPU_T_COMPUTE_SLEEP, ns, 0);
    int64_t wall_ns = median_of(&c, SKELMSG_DPU_T_COMPUTE_WALL, ns, 0);
    int64_t cpu_ns = median_of(&c, SKELMSG_DPU_T_COMPUTE_CPU, ns, 1);
    int64_t work_ns = median_of(&c, SKELMSG_DPU_T_COMPUTE_WORK, ns, 1);
    printf("2 ms asked: sleep %.3f wall %.3f ms (wall time), cpu %.3f work %.3f ms (CPU time)\n",
           sleep_ns / 1e6, wall_ns / 1e6, cpu_ns / 1e6, work_ns / 1e6);
    CHECK(sleep_ns >= ns && sleep_ns < ns + 5000000);
    CHECK(wall_ns >= ns && wall_ns < ns + 5000000);
    CHECK(cpu_ns >= ns && cpu_ns < ns + 500000);
    CHECK(work_ns > ns / 2 && work_ns < 2 * ns);
    /* SLEEP below the spin stretch is a pure spin; zero is free. */
    int64_t short_ns = compute_run(&c, SKELMSG_DPU_T_COMPUTE_SLEEP, 50000);
    CHECK(short_ns >= 50000 && short_ns < 20000000); /* a preempted spin still ends */
    CHECK_EQ(compute_run(&c, SKELMSG_DPU_T_COMPUTE_WALL, 0), 0);
    /* The kernel is deterministic. */
    CHECK(compute_work_kernel(1000) == compute_work_kernel(1000));
    CHECK(compute_work_kernel(1000) != compute_work_kernel(1001));
}

/* SLEEP leaves the CPU to others for most of the delay; WALL does not. */
static void test_sleep_yields_cpu(void)
{
    skel_compute_t c = { .spin_ns = 150000 };
    int64_t t0 = clock_thread_cpu_ns();
    compute_run(&c, SKELMSG_DPU_T_COMPUTE_SLEEP, 5000000);
    int64_t used = clock_thread_cpu_ns() - t0;
    CHECK(used < 2500000);
}

int main(void)
{
    test_modes();
    test_sleep_yields_cpu();
    return CHECK_DONE();
}
