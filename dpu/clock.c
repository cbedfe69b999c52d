/* clock.c: the one way the DPU reaches time and the wire: its clocks, a sleep, a wait
 * for a message, receiving one, publishing, a thread of its own. On the machine they
 * are CLOCK_MONOTONIC (ns), nanosleep, poll and LCM; under a simulation (sim.c,
 * clock_simulate) they are virtual time and the simulation's delivery, and the same
 * executives run on them unchanged. UTC only appears at the edges (a START instant, a
 * message's kernel receive stamp), converted with one simultaneous reading of both clocks. */
#include <errno.h>
#include <pthread.h>
#include <signal.h>
#include <sys/resource.h>
#include <time.h>

#include "dpu.h"

static const clock_world_t *clock_world;

static int64_t clock_read(clockid_t id)
{
    struct timespec ts;
    /* These clocks cannot fail on Linux with valid ids; 0 makes a misuse visible. */
    if (clock_gettime(id, &ts) != 0) return 0;
    return (int64_t)ts.tv_sec * SKEL_NS_PER_S + ts.tv_nsec;
}

int64_t clock_mono_ns(void)
{
    return clock_world != NULL ? clock_world->now(clock_world->ctx) : clock_read(CLOCK_MONOTONIC);
}

int64_t clock_utc_ns(void)
{
    return clock_world != NULL ? clock_world->now(clock_world->ctx) + clock_world->utc_offset_ns
                               : clock_read(CLOCK_REALTIME);
}

/* Simulated, a thread runs whenever it is not waiting: its CPU time is the wall time,
 * and nothing ever preempts it (no stall can be seen). */
int64_t clock_thread_cpu_ns(void)
{
    return clock_world != NULL ? clock_mono_ns() : clock_read(CLOCK_THREAD_CPUTIME_ID);
}

int64_t clock_thread_preemptions(void)
{
    if (clock_world != NULL) return 0;
    struct rusage ru;
    return getrusage(RUSAGE_THREAD, &ru) == 0 ? ru.ru_nivcsw : 0;
}

/* A stopped process (SIGSTOP, a debugger, job control) is a stall the platform
 * imposed, though to the kernel its threads chose to wait. main blocks SIGCONT in
 * every thread, so each continue stays pending until one call here takes it and
 * counts it: a thread that read the count before a stop reads a larger one after,
 * whichever thread took the signal. Simulated, nothing stops. */
int64_t clock_stops(void)
{
    static pthread_mutex_t lock = PTHREAD_MUTEX_INITIALIZER;
    static int64_t stops;
    if (clock_world != NULL) return 0;
    if (pthread_mutex_lock(&lock) != 0) return 0;
    sigset_t pending, cont;
    sigemptyset(&cont);
    sigaddset(&cont, SIGCONT);
    const struct timespec none = { 0, 0 };
    if (sigpending(&pending) == 0 && sigismember(&pending, SIGCONT) == 1 && sigtimedwait(&cont, NULL, &none) == SIGCONT)
        stops++;
    int64_t n = stops;
    pthread_mutex_unlock(&lock);
    return n;
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
        if (clock_nap(mono_ns - now > piece ? now + piece : mono_ns) != 0) return -1;
    }
}

/* ---- the simulated world ----------------------------------------------------------
 * NULL: the machine's clock and network. Set once, before anything runs, by the
 * simulation (sim.c), which then runs every DPU on one thread of its own. */
void clock_simulate(const clock_world_t *world) { clock_world = world; }
int clock_simulated(void) { return clock_world != NULL; }

int clock_nap(int64_t until)
{
    if (clock_world != NULL) {
        clock_world->nap(clock_world->ctx, until);
        return 0;
    }
    struct timespec ts = { .tv_sec = until / SKEL_NS_PER_S, .tv_nsec = until % SKEL_NS_PER_S };
    int rc = clock_nanosleep(CLOCK_MONOTONIC, TIMER_ABSTIME, &ts, NULL);
    return rc == 0 || rc == EINTR ? 0 : -1;
}

lcm_t *clock_open(const char *url)
{
    return clock_world != NULL ? clock_world->open(clock_world->ctx, url) : lcm_create(url);
}

lcm_subscription_t *clock_subscribe(lcm_t *lcm, const char *channel, const char *regex,
                                    lcm_msg_handler_t handler, void *user)
{
    lcm_subscription_t *sub = lcm_subscribe(lcm, regex, handler, user);
    if (sub != NULL && clock_world != NULL &&
        clock_world->subscribe(clock_world->ctx, lcm, channel, handler, user) != 0)
        return NULL;
    return sub;
}

void clock_close(lcm_t *lcm)
{
    if (clock_world != NULL) clock_world->close(clock_world->ctx, lcm);
    lcm_destroy(lcm);
}

int clock_publish(lcm_t *lcm, const char *channel, const void *data, unsigned len)
{
    if (clock_world != NULL) return clock_world->publish(clock_world->ctx, lcm, channel, data, len);
    return lcm_publish(lcm, channel, data, len);
}

int clock_handle(lcm_t *lcm)
{
    return clock_world != NULL ? clock_world->handle(clock_world->ctx, lcm) : lcm_handle_timeout(lcm, 0);
}

void clock_poke(void)
{
    clock_world->poke(clock_world->ctx);
}

int clock_wait(lcm_t *const *lcms, int n, int64_t timeout_ns)
{
    return clock_world->wait(clock_world->ctx, lcms, n, timeout_ns);
}

int clock_thread_start(clock_thread_t *t, void *(*fn)(void *), void *arg)
{
    t->simulated = clock_world != NULL;
    if (t->simulated) return clock_world->spawn(clock_world->ctx, &t->fiber, fn, arg);
    return pthread_create(&t->tid, NULL, fn, arg);
}

int clock_thread_join(clock_thread_t *t)
{
    if (t->simulated) return clock_world->join(clock_world->ctx, t->fiber);
    return pthread_join(t->tid, NULL);
}
