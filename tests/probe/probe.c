/* probe.c: the test harness's own witness of the platform (tests/steal.py), what cyclictest
 * measures, apart from the code under test.
 *
 *   probe FILE
 *
 * sleeps PERIOD_NS at a time to an absolute deadline and appends to FILE one line "fifo" (or
 * "other", and exits, where SCHED_FIFO is refused), then "<CLOCK_MONOTONIC of the wake-up, ns>
 * <lateness, ns>" for every wake-up REPORT_NS or more late. A wake-up a period late or more
 * skips the periods it missed: its one line says the whole gap.
 *
 * It runs under SCHED_FIFO PRIORITY: above a DPU's cycles (SCHED_FIFO 10 in sleep mode,
 * SCHED_OTHER in the spinning ones), below the tasking executive's threads (97..99, pinned to
 * one CPU: the kernel wakes the probe on another CPU at once). So nothing a DPU does at its
 * priority makes it late: when it is, the hypervisor or the kernel did not run the machine.
 * Without SCHED_FIFO any busy process delays it, the code under test too: then it measures
 * nothing. Its cost: a few microseconds of CPU a wake-up. */
#include <sched.h>
#include <signal.h>
#include <stdint.h>
#include <stdio.h>
#include <sys/mman.h>
#include <sys/prctl.h>
#include <time.h>
#include <unistd.h>

#define PERIOD_NS 1000000LL
#define REPORT_NS 200000LL
#define PRIORITY 50

static int64_t ns_of(const struct timespec *t) { return (int64_t)t->tv_sec * 1000000000LL + t->tv_nsec; }

static struct timespec at(int64_t ns) { return (struct timespec){ ns / 1000000000LL, ns % 1000000000LL }; }

int main(int argc, char **argv)
{
    if (argc != 2) {
        fprintf(stderr, "usage: probe FILE\n");
        return 2;
    }
    /* It ends with the harness, however the harness ends: never a stray SCHED_FIFO process. */
    pid_t parent = getppid();
    if (prctl(PR_SET_PDEATHSIG, SIGKILL) != 0 || getppid() != parent) return 1;
    FILE *out = fopen(argv[1], "a");
    if (out == NULL) {
        perror(argv[1]);
        return 1;
    }
    struct sched_param sp = { .sched_priority = PRIORITY };
    int fifo = sched_setscheduler(0, SCHED_FIFO, &sp) == 0;
    (void)mlockall(MCL_CURRENT | MCL_FUTURE); /* a page fault is not the platform's */
    fputs(fifo ? "fifo\n" : "other\n", out);
    fflush(out);
    if (!fifo) return 0;
    struct timespec now;
    clock_gettime(CLOCK_MONOTONIC, &now);
    int64_t due = ns_of(&now) + PERIOD_NS;
    for (;;) {
        struct timespec wake = at(due);
        while (clock_nanosleep(CLOCK_MONOTONIC, TIMER_ABSTIME, &wake, NULL) != 0) continue;
        clock_gettime(CLOCK_MONOTONIC, &now);
        int64_t woke = ns_of(&now), late = woke - due;
        if (late >= REPORT_NS) {
            fprintf(out, "%lld %lld\n", (long long)woke, (long long)late);
            fflush(out);
        }
        due = late >= PERIOD_NS ? woke + PERIOD_NS : due + PERIOD_NS;
    }
}
