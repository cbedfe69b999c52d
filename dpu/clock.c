/* clock.c: time inside the DPU. Everything is CLOCK_MONOTONIC in ns; UTC only
 * appears at the edges (a START instant, a message's kernel receive stamp), and
 * is converted with one simultaneous reading of both clocks. */
#include <errno.h>
#include <sys/resource.h>
#include <time.h>

#include "dpu.h"

static int64_t clock_read(clockid_t id)
{
    struct timespec ts;
    /* These clocks cannot fail on Linux with valid ids; 0 makes a misuse visible. */
    if (clock_gettime(id, &ts) != 0) return 0;
    return (int64_t)ts.tv_sec * SKEL_NS_PER_S + ts.tv_nsec;
}

int64_t clock_mono_ns(void) { return clock_read(CLOCK_MONOTONIC); }
int64_t clock_utc_ns(void) { return clock_read(CLOCK_REALTIME); }
int64_t clock_thread_cpu_ns(void) { return clock_read(CLOCK_THREAD_CPUTIME_ID); }

int64_t clock_thread_preemptions(void)
{
    struct rusage ru;
    return getrusage(RUSAGE_THREAD, &ru) == 0 ? ru.ru_nivcsw : 0;
}

int64_t clock_utc_to_mono(int64_t at_utc_ns, int64_t now_mono_ns, int64_t now_utc_ns)
{
    return now_mono_ns + (at_utc_ns - now_utc_ns);
}

int64_t clock_mono_to_utc(int64_t at_mono_ns, int64_t now_mono_ns, int64_t now_utc_ns)
{
    return now_utc_ns + (at_mono_ns - now_mono_ns);
}

/* Long sleeps are cut in 50 ms pieces so a STOP or a signal is seen promptly;
 * the last piece is an absolute sleep to the exact instant. */
int clock_sleep_until(int64_t mono_ns, atomic_int *stop)
{
    const int64_t piece = 50 * 1000 * 1000LL;
    for (;;) {
        if (stop != NULL && atomic_load(stop)) return 1;
        int64_t now = clock_mono_ns();
        if (now >= mono_ns) return 0;
        int64_t until = mono_ns - now > piece ? now + piece : mono_ns;
        struct timespec ts = { .tv_sec = until / SKEL_NS_PER_S, .tv_nsec = until % SKEL_NS_PER_S };
        int rc = clock_nanosleep(CLOCK_MONOTONIC, TIMER_ABSTIME, &ts, NULL);
        if (rc != 0 && rc != EINTR) return -1;
    }
}
