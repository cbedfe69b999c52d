/* executive.c: the executive thread. Between runs it waits for a START and keeps
 * the link queues drained; a START chooses the DPU's executive (the cyclic loop,
 * cyclic.c; the tasking executive's one-processor schedule in SLEEP, tasking.c, or
 * its threads in CPU, WALL and WORK, threads.c) and starts it: the thread's class
 * and CPU, the measurement window, the wait for the first release, the event
 * generators, and what the run's end puts back. */
#include <math.h>
#include <stdio.h>
#include <sys/prctl.h>
#include <time.h>

#include "dpu.h"

static void executive_set_state(skel_server_t *s, int8_t state)
{
    if (pthread_mutex_lock(&s->lock) != 0) return;
    s->state = state;
    pthread_mutex_unlock(&s->lock);
    server_wake(s->notify_fd);
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

void executive_run(skel_server_t *s, skel_plan_t *plan, const skel_run_t *run)
{
    skel_exec_t x = { .s = s, .plan = plan, .end_mono_ns = run->end_mono_ns, .switch_seq = -1,
                      .mark_stale = 1 };
    plan_reset_run(plan, run->run_id);
    plan->clock_offset_ns = s->clock_offset_ns;
    cycle_pin(plan);
    int fifo = cycle_schedule(s, plan, 1);
    executive_check_work(s, plan, 1);
    atomic_store(&s->behind_ns, 0);
    atomic_store(&s->stall_ns, 0);
    atomic_store(&s->longest_stall_ns, 0);
    atomic_store(&s->longest_stall_mono_ns, 0);
    int64_t t0 = run->start_mono_ns;
    plan->run_t0_ns = plan->epoch_t0_ns = t0;
    cycle_open_window(plan, t0);
    /* Real code's init runs in the thread that calls its step, before the first release. */
    char why[SKEL_REASON_LEN];
    if (code_begin(plan, why, sizeof why) != 0) {
        log_line("DPU %d: run %lld not run: %s", plan->dpu, (long long)run->run_id, why);
        server_fault(s, SKELMSG_STATUS_T_FAULT_CODE);
        (void)cycle_schedule(s, plan, 0);
        return;
    }
    char klass[96] = "SCHED_OTHER";
    if (fifo > 0) snprintf(klass, sizeof klass, "SCHED_FIFO %d", fifo);
    /* The tasking executive outside SLEEP: a thread per process, made before t0
     * (they wait for their first release themselves). */
    threads_t *th = NULL;
    if (plan->tasking && plan->compute != SKELMSG_DPU_T_COMPUTE_SLEEP &&
        (th = threads_start(&x, klass, sizeof klass)) == NULL) {
        (void)cycle_schedule(s, plan, 0);
        return;
    }
    cycle_poll_switch(&x);
    int rc;
    while ((rc = cycle_wait(&x, t0)) == 2) cycle_poll_switch(&x);
    if (rc != 0) { /* stopped before its first release */
        if (th != NULL) threads_end(th);
        code_end(plan);
        plan->running = 0;
        (void)cycle_schedule(s, plan, 0);
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
    else cyclic_run(&x, run);
    event_generators_stop(x.plan); /* the plan of the run's end: a live switch hands over */
    if (x.announce) cycle_announce(&x);
    atomic_store(&s->behind_ns, 0);
    executive_check_work(s, x.plan, 0);
    code_end(x.plan); /* a live switch of a DPU running real code is refused (apply.c) */
    x.plan->running = 0;
    (void)cycle_schedule(s, x.plan, 0);
}

/* Runs the run a START asked for, if one waits: 1 when it ran one, 0 when none waits,
 * -1 when the lock failed. The caller holds S->lock, held again on return. */
int executive_serve(skel_server_t *s)
{
    if (!s->run.requested || s->plan == NULL) return 0;
    skel_run_t run = s->run;
    skel_plan_t *plan = s->plan;
    s->run.requested = 0;
    pthread_mutex_unlock(&s->lock);
    executive_run(s, plan, &run);
    if (pthread_mutex_lock(&s->lock) != 0) return -1;
    s->run_ended = 1;
    server_wake(s->notify_fd);
    return 1;
}

/* Waits for a START. During a run only the executive swaps the plan (at a
 * boundary, cycle_switch); between runs only the control thread does. */
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
        int served = executive_serve(s);
        if (served < 0) return NULL;
        if (served) continue;
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
