/* bench/frame.c: the least any executive does with the rate part's frame, for `make bench`.
 *
 * Each period it sleeps to the frame's release (an absolute CLOCK_MONOTONIC time), then runs
 * PIECES computations of WORK_US each the way skel-dpu's sleep mode runs a short one: busy on
 * the wall clock until its end, each from the end of the one before. A frame overran when its
 * last piece ended after the next release; behind, the next frame starts at once, as a DPU's
 * does. No inputs, no outputs, no records: what is left is what the platform takes from a
 * frame of that work (a wake-up late, a stall in the middle of it), which cyclictest, whose
 * frame holds no work, is not exposed to for the frame's length.
 *
 * It sees its stalls as a DPU does (dpu/compute.c): a wake-up, or a gap between two looks at
 * the clock that carried a piece past its end, of more than STALL_NS (the DPU's threshold) is
 * time the thread was not running. An overrun is one a stall explains when the stalls since
 * the frames were last on time add up to at least how late it ended.
 *
 * SCHED_FIFO PRIORITY on CPU, memory locked, timer slack 1 ns: as skel-dpu runs its cycles.
 * The first WARMUP frames are not counted, as the rate part's runs skip theirs.
 * Prints "frames overran unexplained" (unexplained: overruns no stall explains).
 *
 * usage: frame PERIOD_US WORK_US PIECES SECONDS CPU PRIORITY
 */
#include <errno.h>
#include <sched.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <sys/mman.h>
#include <sys/prctl.h>
#include <time.h>

#define WARMUP 200
#define STALL_NS 50000 /* SKEL_STALL_NS, dpu/dpu.h */

static int64_t now_ns(void)
{
    struct timespec ts;
    clock_gettime(CLOCK_MONOTONIC, &ts);
    return (int64_t)ts.tv_sec * 1000000000LL + ts.tv_nsec;
}

int main(int argc, char **argv)
{
    if (argc != 7) {
        fprintf(stderr, "usage: frame PERIOD_US WORK_US PIECES SECONDS CPU PRIORITY\n");
        return 2;
    }
    int64_t period = atoll(argv[1]) * 1000, work = atoll(argv[2]) * 1000;
    int pieces = atoi(argv[3]), cpu = atoi(argv[5]), priority = atoi(argv[6]);
    double seconds = atof(argv[4]);
    if (period <= 0 || work < 0 || pieces < 1 || !(seconds > 0) || cpu < 0 || priority < 0) {
        fprintf(stderr, "frame: bad argument\n");
        return 2;
    }
    cpu_set_t set;
    CPU_ZERO(&set);
    CPU_SET(cpu, &set);
    if (sched_setaffinity(0, sizeof set, &set) != 0) {
        perror("frame: sched_setaffinity");
        return 1;
    }
    struct sched_param sp = { .sched_priority = priority };
    if (priority > 0 && sched_setscheduler(0, SCHED_FIFO, &sp) != 0) {
        perror("frame: SCHED_FIFO");
        return 1;
    }
    if (mlockall(MCL_CURRENT | MCL_FUTURE) != 0) perror("frame: mlockall (going on)");
    if (prctl(PR_SET_TIMERSLACK, 1UL, 0UL, 0UL, 0UL) != 0) {
        perror("frame: timer slack");
        return 1;
    }
    int64_t frames = (int64_t)(seconds * 1e9 / (double)period), overran = 0, unexplained = 0, debt = 0;
    int64_t release = now_ns() + period, last = 0;
    for (int64_t k = 0; k < WARMUP + frames; k++, release += period) {
        struct timespec wake = { release / 1000000000LL, release % 1000000000LL };
        int rc;
        while ((rc = clock_nanosleep(CLOCK_MONOTONIC, TIMER_ABSTIME, &wake, NULL)) != 0) {
            if (rc != EINTR) {
                fprintf(stderr, "frame: clock_nanosleep failed (%d)\n", rc);
                return 1;
            }
        }
        /* Behind, it runs on at once: late from the last frame's end, not from its release */
        int64_t end = now_ns(), due = release > last ? release : last;
        if (end - due > STALL_NS) debt += end - due;
        for (int i = 0; i < pieces; i++) {
            /* A gap that ends before the piece's end delays nothing; one that carries it past
             * its end made it that much late (compute_spin_until) */
            int64_t until = end + work, prev = end;
            while ((end = now_ns()) < until) prev = end;
            if (end - prev > STALL_NS) debt += end - until;
        }
        int64_t late = end - (release + period);
        last = end;
        if (k >= WARMUP && late > 0) {
            overran++;
            if (debt < late) unexplained++;
        }
        if (late <= 0) debt = 0; /* on time again: the stalls are caught up */
    }
    printf("%lld %lld %lld\n", (long long)frames, (long long)overran, (long long)unexplained);
    return 0;
}
