/* cycle.c: what the three executives share (the cyclic loop, cyclic.c; the tasking
 * schedule in SLEEP, tasking.c; the tasking executive's threads, threads.c), and calls
 * none of them: a cycle's accounting in the DPU's window and its record, cycle skipping,
 * the wait for a release, the class and CPU a run's cycles take, and a live switch
 * (COMMIT during a run) taken at a boundary each executive picks, its rules in swap.c. */
#include <errno.h>
#include <fcntl.h>
#include <sched.h>
#include <string.h>
#include <time.h>
#include <unistd.h>

#include "dpu.h"

/* A run's cycles on the DPU's own CPU, when its config names one. */
void cycle_pin(const skel_plan_t *plan)
{
    if (plan->cpu < 0) return;
    cpu_set_t set;
    CPU_ZERO(&set);
    if (plan->cpu < CPU_SETSIZE) CPU_SET(plan->cpu, &set);
    int rc = plan->cpu < CPU_SETSIZE ? pthread_setaffinity_np(pthread_self(), sizeof set, &set) : -1;
    if (rc != 0)
        log_line("DPU %d: warning: cannot pin to CPU %d (%s); running unpinned", plan->dpu,
                 plan->cpu, rc > 0 ? strerror(rc) : "out of range");
}

/* SLEEP models a dedicated processor: on a shared machine every late wake-up
 * would lengthen the emulated computations and the DPU would seem overloaded.
 * So a run's cycles go under SCHED_FIFO where permitted; they sleep nearly all
 * the time, so this cannot starve the machine. The spinning modes stay
 * SCHED_OTHER unless --rt-priority asks. Between runs: SCHED_OTHER. */
int cycle_rt_priority(const skel_server_t *s, const skel_plan_t *plan)
{
    if (s->rt_priority >= 0) return s->rt_priority;
    return plan->compute == SKELMSG_DPU_T_COMPUTE_SLEEP ? SKEL_RT_PRIORITY : 0;
}

/* A run, in every mode and executive, keeps the CPUs out of deep idle states, as
 * cyclictest does by default: a wake-up from one costs every release. On our VM
 * (haltpoll) a sleeping SCHED_FIFO thread woke 38.7-39.7 us late at the median at
 * 1 kHz, 18.4-19.1 us with the request held. The kernel keeps the request while the
 * file is open. */
static void cycle_hold_idle(skel_server_t *s, int hold)
{
    if (clock_simulated() || hold == s->idle_held) return;
    if (!hold) {
        s->idle_held = 0;
        if (close(s->idle_fd) != 0) log_line("warning: cannot close /dev/cpu_dma_latency (%s)", strerror(errno));
        return;
    }
    const int32_t none = 0;
    int fd = open("/dev/cpu_dma_latency", O_WRONLY | O_CLOEXEC);
    if (fd >= 0 && write(fd, &none, sizeof none) == (ssize_t)sizeof none) {
        s->idle_fd = fd;
        s->idle_held = 1;
        return;
    }
    int err = errno;
    if (fd >= 0) (void)close(fd); /* the write's error is the one said */
    if (!s->idle_warned) {
        s->idle_warned = 1;
        log_line("warning: cannot keep the CPUs out of deep idle states (/dev/cpu_dma_latency: %s): "
                 "waking from one lengthens every release (needs root)", strerror(err));
    }
}

int cycle_schedule(skel_server_t *s, const skel_plan_t *plan, int running)
{
    int prio = running ? cycle_rt_priority(s, plan) : 0;
    struct sched_param sp = { .sched_priority = prio };
    int rc = pthread_setschedparam(pthread_self(), prio > 0 ? SCHED_FIFO : SCHED_OTHER, &sp);
    if (rc != 0 && !s->rt_warned) {
        s->rt_warned = 1;
        log_line("DPU %d: warning: cannot run cycles under %s (%s): a busy machine will stretch "
                 "them (needs root or CAP_SYS_NICE; --rt-priority 0 silences this)",
                 plan->dpu, prio > 0 ? "SCHED_FIFO" : "SCHED_OTHER", strerror(rc));
    }
    cycle_hold_idle(s, running);
    return rc == 0 ? prio : 0; /* the SCHED_FIFO priority in effect, 0: SCHED_OTHER */
}

static int64_t cycle_max_period(const skel_plan_t *plan)
{
    int64_t m = 0;
    for (int i = 0; i < plan->nprocesses; i++)
        if (plan->processes[i].period_ns > m) m = plan->processes[i].period_ns;
    return m;
}

/* One measurement window per DPU, shared by all its processes: it opens at
 * t0 + warmup_cycles * the DPU's longest period, when even its slowest process
 * is past its warm-up. A process's cycles count from its first release in the
 * window, so a fast process's sums and a slow one's cover the same time and
 * the DPU's % compute is its configured load whatever the mix of periods. */
void cycle_open_window(skel_plan_t *plan, int64_t t0)
{
    plan->measure_from_ns = t0 + plan->warmup_cycles * cycle_max_period(plan);
    for (int i = 0; i < plan->nprocesses; i++) {
        skel_process_t *p = &plan->processes[i];
        /* an event process's cycles come with its events: its first in the window (event.c) */
        p->measure_from_k = p->event >= 0 ? INT64_MAX
                                          : (plan->measure_from_ns - t0 + p->period_ns - 1) / p->period_ns;
    }
}

/* The DPU's sums cover its window only; so do the process sums (process.c). The tasking
 * executives sum a job when it completes, not in release order: the window's span is the
 * earliest release and the latest end summed, whichever came first. */
void cycle_account(skel_plan_t *plan, skel_process_t *p, const skel_rec_t *rec, int64_t release,
                   int64_t end)
{
    skel_dpu_sums_t *d = &plan->sums;
    if (rec->cycle >= p->measure_from_k) p->sums.wait_ns += rec->idle_ns;
    if (release < plan->measure_from_ns) {
        /* A DPU behind its schedule (report.c); a skipped release did no work, as the analysis
         * counts it (metrics.warmup_end_ns: completed cycles only). */
        int worked = !(rec->flags & SKELMSG_TIMING_T_FLAG_RELEASE_SKIPPED);
        if (worked && end > d->warmup_end_ns) d->warmup_end_ns = end;
        return;
    }
    if (d->first_release_ns < 0 || release < d->first_release_ns) d->first_release_ns = release;
    int64_t start = rec->start_ns - (rec->release_ns - release); /* a record's times carry the clock offset */
    if (d->first_start_ns < 0 || start < d->first_start_ns) d->first_start_ns = start;
    if (end + rec->idle_ns > d->end_ns) d->end_ns = end + rec->idle_ns;
    d->compute_ns += rec->compute_ns;
    d->communicate_ns += rec->comm_in_ns + rec->comm_out_ns;
    d->wait_ns += rec->blocked_ns + rec->idle_ns;
    d->stall_ns += rec->stall_ns;
}

void cycle_record(skel_server_t *s, const skel_rec_t *rec)
{
    if (timing_ring_push(&s->ring, rec) != 0) server_fault(s, SKELMSG_STATUS_T_FAULT_TIMING_LOST);
    if (rec->stall_ns <= 0) return;
    atomic_fetch_add(&s->stall_ns, rec->stall_ns);
    if (rec->stall_ns > atomic_load(&s->longest_stall_ns)) { /* the host groups a host's stalls */
        atomic_store(&s->longest_stall_ns, rec->stall_ns);
        atomic_store(&s->longest_stall_mono_ns, server_now(s));
    }
}

/* Cycle skipping: a data-synchronised process runs on the newest sample of its
 * inputs, so a release whose period has already passed when its turn comes would
 * only repeat old work and keep the DPU behind for good (it gets at most one new
 * sample per writer period, so a lag after a hiccup never shrinks). It skips that
 * release, as a real data-driven executive would, and its readers see the skipped
 * sequence as dropped. Only on a DPU whose configured load fits: an overloaded one
 * runs every release and falls ever further behind, so its overload shows as the
 * paper's lockout and pipeline jam instead of being shed. Periodic processes run
 * every release. */
int cycle_skips(const skel_plan_t *plan, const skel_process_t *p, int64_t release, int64_t now)
{
    return plan->fits && p->sync == SKELMSG_PROCESS_T_SYNC_DATA && now >= release + p->period_ns;
}

void cycle_skip_record(skel_exec_t *x, skel_process_t *p, int64_t k, int64_t minor, int64_t release,
                       int64_t sched, int64_t now, skel_rec_t *rec)
{
    process_record_begin(x, p, k, minor, release, sched, now, rec);
    rec->slack_ns = release + p->period_ns - now;
    rec->flags = SKELMSG_TIMING_T_FLAG_RELEASE_SKIPPED;
    if (k >= p->measure_from_k) p->sums.releases_skipped++;
}

/* Re-reads the pending switch only when the control thread changed it: one
 * atomic load per minor cycle, the lock only on a change. */
void cycle_poll_switch(skel_exec_t *x)
{
    skel_server_t *s = x->s;
    if (atomic_load(&s->switch_seq) == x->switch_seq) return;
    if (pthread_mutex_lock(&s->lock) != 0) return;
    x->switch_seq = atomic_load(&s->switch_seq);
    x->switch_pending = s->next_plan != NULL;
    x->switch_at_mono_ns = s->next_at_mono_ns;
    pthread_mutex_unlock(&s->lock);
}

/* Sleeps until UNTIL (INT64_MAX: until told): 0 reached, 1 stop, 2 the pending
 * switch changed. 50 ms pieces, so a COMMIT is seen within one piece. It always
 * sleeps, however short the wait: a SCHED_FIFO thread that never slept would be
 * throttled by the kernel (sched_rt_runtime_us: 50 ms of every second). */
int cycle_wait(skel_exec_t *x, int64_t until)
{
    const int64_t piece = 50 * 1000 * 1000LL;
    for (;;) {
        if (atomic_load(&x->s->stop)) return 1;
        if (atomic_load(&x->s->switch_seq) != x->switch_seq) return 2;
        int64_t now = clock_mono_ns();
        if (now >= until) return 0;

        x->mark_stale = 1; /* the steps after a chosen sleep are judged from a fresh mark */
        if (clock_nap(until - now > piece ? now + piece : until) != 0) return 1;
    }
}

/* Between two releases: takes the pending switch's next plan from the control thread
 * (NULL: none any more). The caller hands over what it still holds of the old plan's
 * processes, then cycle_switch. */
skel_plan_t *cycle_take(skel_exec_t *x)
{
    skel_server_t *s = x->s;
    x->mark_stale = 1; /* a switch takes a lock and may re-pin the thread: judge afresh */
    if (pthread_mutex_lock(&s->lock) != 0) return NULL;
    skel_plan_t *next = s->next_plan;
    s->next_plan = NULL;
    x->switch_seq = atomic_load(&s->switch_seq);
    x->switch_pending = 0;
    pthread_mutex_unlock(&s->lock);
    return next;
}

/* Carries the run into NEXT (from cycle_take) at minor J_SW of the current plan.
 * Nothing is allocated or freed here: the old plan (and its lcm_t) goes back to the
 * control thread. The status changes at the first release of the new plan
 * (cycle_announce). 1 when it switched. */
int cycle_switch(skel_exec_t *x, skel_plan_t *next, int64_t j_sw, int ran)
{
    skel_server_t *s = x->s;
    skel_plan_t *old = x->plan;
    event_generators_stop(old);
    (void)link_drain(old->links, old->nlinks); /* the old slots are complete ... */
    swap_carry(next, old, j_sw);
    if (next->tasking) swap_carry_tasking(next, old, swap_instant(old, j_sw)); /* its jobs */
    swap_carry_events(next, old, swap_instant(old, j_sw)); /* event processes count their events */
    if (!ran) cycle_open_window(next, next->run_t0_ns);
    next->running = 1;
    old->running = 0;
    (void)event_generators_start(next, x->end_mono_ns);
    (void)link_drain(next->links, next->nlinks); /* ... so the copies here are dropped */
    if (next->cpu != old->cpu) cycle_pin(next);
    if (next->compute != old->compute) (void)cycle_schedule(s, next, 1);
    if (pthread_mutex_lock(&s->lock) != 0) return 0;
    s->plan = next;
    s->retired = old; /* the control thread emptied it before it offered NEXT */
    pthread_mutex_unlock(&s->lock);
    x->plan = next;
    x->announce = 1;
    return 1;
}

void cycle_announce(skel_exec_t *x)
{
    skel_server_t *s = x->s;
    x->announce = 0;
    if (pthread_mutex_lock(&s->lock) != 0) return;
    s->generation = x->plan->generation;
    s->run_generation = x->plan->generation;
    s->next_generation = -1;
    pthread_mutex_unlock(&s->lock);
    server_wake(s->notify_fd); /* a status at once, with the new generation */
    log_line("DPU %d: switched to generation %lld at minor %lld of run %lld (%d processes)",
             x->plan->dpu, (long long)x->plan->generation, (long long)x->plan->minor_base,
             (long long)x->plan->run_id, x->plan->nprocesses);
}
