/* executive.c: the cyclic executive, the paper's procedural model. One thread
 * per DPU runs its processes in their configured order on an absolute grid of
 * minor cycles t0 + j*m (CLOCK_MONOTONIC, TIMER_ABSTIME). A late DPU runs the
 * next due release at once and falls further behind, and on an overloaded DPU
 * that backlog is what turns an overload into a lockout; only a `sync: data`
 * process a whole period late on a DPU whose load fits skips a release. A COMMIT
 * during a run switches to the next plan at one boundary (swap.c). Between
 * runs the thread waits for a START and keeps the link queues drained. */
#include <errno.h>
#include <math.h>
#include <sched.h>
#include <stdio.h>
#include <string.h>
#include <sys/prctl.h>
#include <time.h>

#include "dpu.h"

/* The first minor cycle >= J at which some process is due (INT64_MAX: none). */
int64_t executive_next_release(const skel_plan_t *plan, int64_t j)
{
    int64_t best = INT64_MAX;
    for (int i = 0; i < plan->nprocesses; i++) {
        int64_t r = plan->processes[i].ratio;
        int64_t due = (j + r - 1) / r * r;
        if (due < best) best = due;
    }
    return best;
}

static void executive_pin(const skel_plan_t *plan)
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
int executive_rt_priority(const skel_server_t *s, const skel_plan_t *plan)
{
    if (s->rt_priority >= 0) return s->rt_priority;
    return plan->compute == SKELMSG_DPU_T_COMPUTE_SLEEP ? SKEL_RT_PRIORITY : 0;
}

static int executive_schedule(skel_server_t *s, const skel_plan_t *plan, int running)
{
    int prio = running ? executive_rt_priority(s, plan) : 0;
    struct sched_param sp = { .sched_priority = prio };
    int rc = pthread_setschedparam(pthread_self(), prio > 0 ? SCHED_FIFO : SCHED_OTHER, &sp);
    if (rc != 0 && !s->rt_warned) {
        s->rt_warned = 1;
        log_line("DPU %d: warning: cannot run cycles under %s (%s): a busy machine will stretch "
                 "them (needs root or CAP_SYS_NICE; --rt-priority 0 silences this)",
                 plan->dpu, prio > 0 ? "SCHED_FIFO" : "SCHED_OTHER", strerror(rc));
    }
    return rc == 0 ? prio : 0; /* the SCHED_FIFO priority in effect, 0: SCHED_OTHER */
}

static int64_t executive_max_period(const skel_plan_t *plan)
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
static void executive_open_window(skel_plan_t *plan, int64_t t0)
{
    plan->measure_from_ns = t0 + plan->warmup_cycles * executive_max_period(plan);
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
void executive_account(skel_plan_t *plan, skel_process_t *p, const skel_rec_t *rec, int64_t release,
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

void executive_record(skel_server_t *s, const skel_rec_t *rec)
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
int executive_skips(const skel_plan_t *plan, const skel_process_t *p, int64_t release, int64_t now)
{
    return plan->fits && p->sync == SKELMSG_PROCESS_T_SYNC_DATA && now >= release + p->period_ns;
}

void executive_skip_record(skel_exec_t *x, skel_process_t *p, int64_t k, int64_t minor, int64_t release,
                           int64_t sched, int64_t now, skel_rec_t *rec)
{
    process_record_begin(x, p, k, minor, release, sched, now, rec);
    rec->slack_ns = release + p->period_ns - now;
    rec->flags = SKELMSG_TIMING_T_FLAG_RELEASE_SKIPPED;
    if (k >= p->measure_from_k) p->sums.releases_skipped++;
}

/* Whether P runs in minor J: due there, and for an event process, holding an
 * event (executive_take_events). */
static int executive_runs(const skel_process_t *p, int64_t j)
{
    return j % p->ratio == 0 && (p->event < 0 || p->taken_ns >= 0);
}

/* A sync: event process due in minor J takes the oldest event waiting when the
 * frame starts (drained then); without one it does not run in this frame (no record). */
static void executive_take_events(skel_plan_t *plan, int64_t j)
{
    if (!plan->awaits_events) return;
    (void)link_drain(plan->links, plan->nlinks);
    for (int i = 0; i < plan->nprocesses; i++) {
        skel_process_t *p = &plan->processes[i];
        if (p->event < 0 || j % p->ratio != 0) continue;
        event_settle(plan, p, INT64_MAX); /* it looks now: whatever came by now */
        if (event_pending(p)) event_release(plan, p, plan->epoch_t0_ns + j / p->ratio * p->period_ns);
    }
}

/* The held record (the last one of the last minor that ran) counts and goes out, its
 * idle ending at UNTIL: the release of the next minor that runs something (INT64_MAX:
 * as it was when held, up to the next release then). */
static void executive_release_held(skel_exec_t *x, int64_t until)
{
    if (x->held_p == NULL) return;
    if (until != INT64_MAX) x->held.idle_ns = until > x->held_end ? until - x->held_end : 0;
    executive_account(x->plan, x->held_p, &x->held, x->held_release, x->held_end);
    executive_record(x->s, &x->held);
    x->held_p = NULL;
}

/* Runs the due processes of minor cycle J in their order; NEXT_R is the next
 * release (INT64_MAX: none), where the idle of the minor's last record ends. The
 * schedule's start of each is the minor's release plus the configured compute of
 * the processes before it and the data waits the design plans for them: a data
 * reader holds the DPU until its data comes (ready_ns after its release, the
 * prediction's), so what follows it is scheduled from there and only a longer
 * wait makes it late. 1 when the run stopped inside it. */
static int executive_minor(skel_exec_t *x, int64_t j, int64_t next_r)
{
    skel_plan_t *plan = x->plan;
    executive_take_events(plan, j);
    int last = -1;
    for (int i = 0; i < plan->nprocesses; i++)
        if (executive_runs(&plan->processes[i], j)) last = i;
    if (last >= 0) executive_release_held(x, swap_instant(plan, j));
    int64_t sched = -1;
    for (int i = 0; i <= last; i++) {
        skel_process_t *p = &plan->processes[i];
        if (!executive_runs(p, j)) continue;
        /* an event process's cycles count its events, not its frames */
        int64_t k = p->event >= 0 ? p->next_k++ : j / p->ratio;
        int64_t release = plan->epoch_t0_ns + j / p->ratio * p->period_ns;
        if (sched < 0) sched = release;
        skel_rec_t rec;
        int64_t now = clock_mono_ns(), end;
        int rc = PROCESS_DONE;
        if (executive_skips(plan, p, release, now)) {
            executive_skip_record(x, p, p->k_base + k, plan->minor_base + j, release, sched, now, &rec);
            end = now;
        } else {
            rc = process_cycle(x, p, p->k_base + k, plan->minor_base + j, release, sched, &rec);
            end = release + p->period_ns - rec.slack_ns;
        }
        /* the plan, not what happened: a skipped release moves it as a run one would */
        if (release + p->ready_ns > sched) sched = release + p->ready_ns;
        sched += p->compute_ns;
        /* Idle belongs to the last record of the release: gaps between processes are overhead.
         * That record waits for the next minor that runs anything, where its idle ends. */
        if (i == last && rc == PROCESS_DONE) {
            if (next_r != INT64_MAX) rec.idle_ns = next_r > end ? next_r - end : 0;
            x->held = rec;
            x->held_p = p;
            x->held_release = release;
            x->held_end = end;
            continue;
        }
        if (rc == PROCESS_DONE) executive_account(plan, p, &rec, release, end);
        executive_record(x->s, &rec);
        if (rc == PROCESS_STOPPED) return 1;
    }
    return 0;
}

static void executive_set_state(skel_server_t *s, int8_t state)
{
    if (pthread_mutex_lock(&s->lock) != 0) return;
    s->state = state;
    pthread_mutex_unlock(&s->lock);
    server_wake(s->notify_fd);
}

/* Re-reads the pending switch only when the control thread changed it: one
 * atomic load per minor cycle, the lock only on a change. */
void executive_poll_switch(skel_exec_t *x)
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
static int executive_wait(skel_exec_t *x, int64_t until)
{
    const int64_t piece = 50 * 1000 * 1000LL;
    for (;;) {
        if (atomic_load(&x->s->stop)) return 1;
        if (atomic_load(&x->s->switch_seq) != x->switch_seq) return 2;
        int64_t now = clock_mono_ns();
        if (now >= until) return 0;

        int64_t t = until - now > piece ? now + piece : until;
        struct timespec ts = { .tv_sec = t / SKEL_NS_PER_S, .tv_nsec = t % SKEL_NS_PER_S };
        x->mark_stale = 1; /* the steps after a chosen sleep are judged from a fresh mark */
        int rc = clock_nanosleep(CLOCK_MONOTONIC, TIMER_ABSTIME, &ts, NULL);
        if (rc != 0 && rc != EINTR) return 1;
    }
}

/* The switch instant on the current grid given J_PREV (the last minor run),
 * INT64_MAX when no switch is pending. */
static int64_t executive_switch_at(const skel_exec_t *x, int64_t j_prev, int64_t *j_sw)
{
    if (!x->switch_pending) return INT64_MAX;
    *j_sw = swap_index(x->plan, j_prev, x->switch_at_mono_ns);
    return swap_instant(x->plan, *j_sw);
}

/* Between two releases: take the next plan, carry the run into it at minor
 * J_SW of the current one. Nothing is allocated or freed here: the old plan
 * (and its lcm_t) goes back to the control thread. The status changes at the
 * first release of the new plan (executive_announce). 1 when it switched. */
int executive_switch(skel_exec_t *x, int64_t j_sw, int ran)
{
    skel_server_t *s = x->s;
    skel_plan_t *old = x->plan;
    x->mark_stale = 1; /* a switch takes a lock and may re-pin the thread: judge afresh */
    if (pthread_mutex_lock(&s->lock) != 0) return 0;
    skel_plan_t *next = s->next_plan;
    s->next_plan = NULL;
    x->switch_seq = atomic_load(&s->switch_seq);
    x->switch_pending = 0;
    pthread_mutex_unlock(&s->lock);
    if (next == NULL) return 0;
    executive_release_held(x, INT64_MAX); /* its process is the old plan's */
    event_generators_stop(old);
    (void)link_drain(old->links, old->nlinks); /* the old slots are complete ... */
    swap_carry(next, old, j_sw);
    if (next->tasking) swap_carry_tasking(next, old, swap_instant(old, j_sw)); /* its jobs */
    swap_carry_events(next, old, swap_instant(old, j_sw)); /* event processes count their events */
    if (!ran) executive_open_window(next, next->run_t0_ns);
    next->running = 1;
    old->running = 0;
    (void)event_generators_start(next, x->end_mono_ns);
    (void)link_drain(next->links, next->nlinks); /* ... so the copies here are dropped */
    if (next->cpu != old->cpu) executive_pin(next);
    if (next->compute != old->compute) (void)executive_schedule(s, next, 1);
    if (pthread_mutex_lock(&s->lock) != 0) return 0;
    s->plan = next;
    s->retired = old; /* the control thread emptied it before it offered NEXT */
    pthread_mutex_unlock(&s->lock);
    x->plan = next;
    x->announce = 1;
    return 1;
}

void executive_announce(skel_exec_t *x)
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

/* The executive slept until UNTIL, so it was on time: the stalls it owed are
 * paid. A wake-up later than the stall threshold is a stall of its own. */
static void executive_woke(skel_exec_t *x, int64_t until)
{
    int64_t late = clock_mono_ns() - until;
    x->wake_stall_ns = late > x->s->compute.stall_ns ? late : 0;
    x->stall_debt_ns = x->wake_stall_ns;
}

/* The release after minor J: the plan's next due minor, or the switch if sooner. */
static int64_t executive_next_r(const skel_exec_t *x, int64_t j, int64_t next_j)
{
    int64_t next_r = next_j == INT64_MAX ? INT64_MAX : swap_instant(x->plan, next_j);
    int64_t j_sw;
    int64_t t_sw = executive_switch_at(x, j, &j_sw);
    return t_sw < next_r ? t_sw : next_r;
}

/* WORK is calibrated once, at start-up: the reference a slower CPU is measured
 * against. Each run checks, in the run's own thread, class and CPU, how far the
 * kernel's speed is from it at the run's start and again at its end (a neighbour
 * that got busy meanwhile), and says so when it drifted. The report keeps the
 * larger drift of the two. */
static void executive_check_work(skel_server_t *s, skel_plan_t *plan, int at_start)
{
    if (at_start) plan->work_drift_pct = 0.0;
    if (plan->compute != SKELMSG_DPU_T_COMPUTE_WORK) return;
    double drift = compute_check_calibration(&s->compute);
    if (fabs(drift) > fabs(plan->work_drift_pct)) plan->work_drift_pct = drift;
    if (fabs(drift) > SKEL_DRIFT_PCT)
        log_line("DPU %d: warning: at the run's %s the WORK kernel runs %.1f %% %s than at start-up "
                 "(CPU frequency, throttling or a busy neighbour): computations take that much %s",
                 plan->dpu, at_start ? "start" : "end", fabs(drift), drift > 0 ? "slower" : "faster",
                 drift > 0 ? "longer" : "less");
}

/* The cyclic executive's loop: minor cycle after minor cycle until the run's end. */
static void executive_cyclic(skel_exec_t *x, const skel_run_t *run)
{
    skel_server_t *s = x->s;
    int ran = 0;
    int64_t j_prev = -1, j = executive_next_release(x->plan, 0), j_sw = 0;
    for (;;) {
        executive_poll_switch(x);
        int64_t r = j == INT64_MAX ? INT64_MAX : swap_instant(x->plan, j);
        int64_t t_sw = executive_switch_at(x, j_prev, &j_sw);
        if (t_sw <= r && t_sw < run->end_mono_ns) {
            (void)executive_switch(x, j_sw, ran);
            j_prev = -1;
            j = executive_next_release(x->plan, 0);
            continue;
        }
        if (x->announce && r == INT64_MAX) executive_announce(x); /* a plan without processes */
        int64_t until = r < run->end_mono_ns ? r : run->end_mono_ns;
        int on_time = clock_mono_ns() < until;
        int rc = executive_wait(x, until);
        if (rc == 2) continue;
        if (rc != 0 || r >= run->end_mono_ns) break;
        if (on_time) executive_woke(x, until);
        atomic_store(&s->behind_ns, on_time ? 0 : clock_mono_ns() - r);
        if (x->announce) executive_announce(x);
        int64_t next_j = executive_next_release(x->plan, j + 1);
        if (executive_minor(x, j, executive_next_r(x, j, next_j)) != 0) break;
        ran = 1;
        atomic_fetch_add(&s->minor_cycles, 1);
        if (r >= x->plan->measure_from_ns) x->plan->sums.minor_cycles++;
        j_prev = j;
        j = next_j;
    }
    executive_release_held(x, INT64_MAX);
}

void executive_run(skel_server_t *s, skel_plan_t *plan, const skel_run_t *run)
{
    skel_exec_t x = { .s = s, .plan = plan, .end_mono_ns = run->end_mono_ns, .switch_seq = -1,
                      .mark_stale = 1 };
    plan_reset_run(plan, run->run_id);
    plan->clock_offset_ns = s->clock_offset_ns;
    executive_pin(plan);
    int fifo = executive_schedule(s, plan, 1);
    executive_check_work(s, plan, 1);
    atomic_store(&s->behind_ns, 0);
    atomic_store(&s->stall_ns, 0);
    atomic_store(&s->longest_stall_ns, 0);
    atomic_store(&s->longest_stall_mono_ns, 0);
    int64_t t0 = run->start_mono_ns;
    plan->run_t0_ns = plan->epoch_t0_ns = t0;
    executive_open_window(plan, t0);
    char klass[96] = "SCHED_OTHER";
    if (fifo > 0) snprintf(klass, sizeof klass, "SCHED_FIFO %d", fifo);
    /* The tasking executive outside SLEEP: a thread per process, made before t0
     * (they wait for their first release themselves). */
    threads_t *th = NULL;
    if (plan->tasking && plan->compute != SKELMSG_DPU_T_COMPUTE_SLEEP &&
        (th = threads_start(&x, klass, sizeof klass)) == NULL) {
        (void)executive_schedule(s, plan, 0);
        return;
    }
    executive_poll_switch(&x);
    int rc;
    while ((rc = executive_wait(&x, t0)) == 2) executive_poll_switch(&x);
    if (rc != 0) { /* stopped before its first release */
        if (th != NULL) threads_end(th);
        plan->running = 0;
        (void)executive_schedule(s, plan, 0);
        return;
    }
    if (th == NULL) plan->running = 1; /* threads_start set it before its threads drain */
    executive_set_state(s, SKELMSG_STATUS_T_STATE_RUNNING);
    log_line("DPU %d: run %lld started (%d processes, %s)", plan->dpu, (long long)run->run_id,
             plan->nprocesses, klass);
    event_generators_begin(plan, t0);
    (void)event_generators_start(plan, run->end_mono_ns);
    if (th != NULL) threads_run(th, &x);
    else if (plan->tasking) tasking_run(&x);
    else executive_cyclic(&x, run);
    event_generators_stop(x.plan); /* the plan of the run's end: a live switch hands over */
    if (x.announce) executive_announce(&x);
    atomic_store(&s->behind_ns, 0);
    executive_check_work(s, x.plan, 0);
    x.plan->running = 0;
    (void)executive_schedule(s, x.plan, 0);
}

/* Waits for a START. During a run only the executive swaps the plan (at a
 * boundary, executive_switch); between runs only the control thread does. */
void *executive_main(void *arg)
{
    skel_server_t *s = arg;
    (void)pthread_setname_np(pthread_self(), "skel-exec"); /* top -H, /proc/PID/task: which is which */
    /* A normal thread's sleeps end up to 50 us late (the default timer slack):
     * that would show as release latency and lengthen every SLEEP compute. */
    if (prctl(PR_SET_TIMERSLACK, 1UL, 0UL, 0UL, 0UL) != 0)
        log_line("warning: cannot set timer slack: wake-ups may be up to 50 us late");
    if (pthread_mutex_lock(&s->lock) != 0) return NULL;
    while (!atomic_load(&s->quit)) {
        if (s->run.requested && s->plan != NULL) {
            skel_run_t run = s->run;
            skel_plan_t *plan = s->plan;
            s->run.requested = 0;
            pthread_mutex_unlock(&s->lock);
            executive_run(s, plan, &run);
            if (pthread_mutex_lock(&s->lock) != 0) return NULL;
            s->run_ended = 1;
            server_wake(s->notify_fd);
            continue;
        }
        /* Idle: keep the links' unlimited queues from growing between runs. */
        if (s->plan != NULL) (void)link_drain(s->plan->links, s->plan->nlinks);
        struct timespec ts;
        int64_t until = clock_mono_ns() + 50 * 1000 * 1000LL; /* cond uses CLOCK_MONOTONIC */
        ts.tv_sec = until / SKEL_NS_PER_S;
        ts.tv_nsec = until % SKEL_NS_PER_S;
        (void)pthread_cond_timedwait(&s->cond, &s->lock, &ts);
    }
    s->exec_done = 1;
    pthread_mutex_unlock(&s->lock);
    server_wake(s->notify_fd);
    return NULL;
}
