/* tasking.c: the tasking executive (executive: threads), the paper's "tasking
 * model to allow single-processor concurrent modeling". The DPU is one
 * processor under fixed-priority preemptive scheduling: each process releases
 * a job every period (a `sync: data` job is ready only once its required inputs
 * hold new data), and the highest-priority ready job holds the processor until
 * it completes or a higher-priority job becomes ready and preempts it.
 *
 * In compute mode SLEEP the DPU runs that one-processor schedule itself: it
 * knows each job's remaining computation and sleeps until the next completion,
 * release or data arrival, so preemption is exact however many DPUs share the
 * machine. A job computes exactly what it asks, counted from when it got the
 * processor; reading inputs and writing outputs take the processor too, as on
 * the cyclic executive. Each cycle's record keeps when the schedule handed it
 * the processor (sched_ns: the release or completion that let it run), its
 * start, and how often and how long it was preempted. A job waiting for data
 * does not hold the processor: its data wait is part of its release latency.
 *
 * A COMMIT during a run switches plans at the first point of the grid all DPUs
 * share at or after its instant, as on the cyclic executive, before that
 * point's releases; the jobs not completed yet carry over (swap.c). */
#include <stdatomic.h>
#include <string.h>

#include "dpu.h"

/* Waits until UNTIL (monotonic), watching the links when a job waits for data:
 * 0 at UNTIL, 1 when data came first, 2 stopped. A wake-up later than the stall
 * threshold adds to *STALL (one already past UNTIL on entry is the DPU's own
 * overhead, not a stall). The last stretch is spun, as compute mode SLEEP does. */
static int tasking_wait(skel_exec_t *x, int64_t until, int watch, int64_t *stall)
{
    skel_plan_t *plan = x->plan;
    const int64_t spin = x->s->compute.spin_ns, piece = 50 * 1000 * 1000LL;
    const int64_t entered = clock_mono_ns();
    for (;;) {
        if (atomic_load(&x->s->stop)) return 2;
        int64_t now = clock_mono_ns();
        if (now >= until - spin) break;
        int64_t t = until - spin - now;
        /* a version an emulated link holds back comes when it is due */
        const int64_t held = watch ? buffers_advance(plan, now) : INT64_MAX;
        if (held - now < t) t = held - now;
        int rc = link_wait(plan->links, watch ? plan->nlinks : 0, x->s->wake_fd, t > piece ? piece : t);
        if (rc < 0) return 2;
        if ((rc > 0 || clock_mono_ns() >= held) && watch && !atomic_load(&x->s->stop)) return 1;
        if (atomic_load(&x->s->switch_seq) != x->switch_seq) return 1; /* a COMMIT: a new event */
    }
    int64_t now = clock_mono_ns();
    while (now < until) now = clock_mono_ns();
    int64_t late = now - (entered > until ? entered : until);
    if (late > x->s->compute.stall_ns) *stall += late;
    return 0;
}

static int64_t tasking_floor_div(int64_t a, int64_t b)
{
    return a >= 0 ? a / b : -((-a + b - 1) / b);
}

/* A data job becomes ready once its required inputs are new. Looked at in a
 * scratch record: P's own may still hold its last cycle, waiting for its idle.
 * A job whose data comes a whole period after its release skips that release
 * (cycle skipping, as on the cyclic executive: cycle_skips), so that the
 * next job runs on this data rather than the process staying a period behind. */
static void tasking_check_data(skel_exec_t *x, skel_process_t *p, int64_t vt)
{
    skel_plan_t *plan = x->plan;
    skel_rec_t look;
    process_peek_inputs(plan, p, &look);
    p->job.missing = (int8_t)process_missing(p, &look);
    if (p->job.missing >= 0) return;
    p->job.state = JOB_READY;
    if (!cycle_skips(plan, p, p->job.release, vt)) return;
    cycle_skip_record(x, p, p->k_base + p->next_k, job_minor(plan, p), p->job.release,
                          p->job.release, vt, &look);
    look.generation = p->job.generation;
    cycle_record(x->s, &look);
    p->job.state = JOB_NONE;
    p->next_k++;
}

/* Releases due at VT become jobs: at most one per process, the next one only
 * when the last completed (a late process runs its releases back to back). */
static void tasking_release_due(skel_exec_t *x, int64_t vt)
{
    skel_plan_t *plan = x->plan;
    for (int i = 0; i < plan->nprocesses; i++) {
        skel_process_t *p = &plan->processes[i];
        if (p->event >= 0) {
            int64_t release = job_event_release(p);
            if (p->job.state == JOB_NONE && release <= vt && release < x->end_mono_ns) {
                p->job.release = release;
                p->job.generation = plan->generation;
                p->job.state = JOB_READY;
                event_release(plan, p, release);
            }
            continue;
        }
        while (p->job.state == JOB_NONE) { /* again after a skipped release */
            int64_t release = job_release(p, p->next_k);
            if (release > vt || release >= x->end_mono_ns) break;
            p->job.release = release;
            p->job.generation = p->next_k < 0 ? p->job.back_generation : plan->generation;
            p->job.state = p->sync == SKELMSG_PROCESS_T_SYNC_DATA ? JOB_WAITING : JOB_READY;
            if (p->job.state == JOB_WAITING) tasking_check_data(x, p, vt);
        }
    }
}

/* Lockouts due by VT; returns the next instant one would be. */
static int64_t tasking_lockouts(skel_exec_t *x, int64_t vt)
{
    int64_t next = INT64_MAX;
    for (int i = 0; i < x->plan->nprocesses; i++) next = job_lockout(x, &x->plan->processes[i], vt, next);
    return next;
}

/* P gets the processor for the first time at VT: its record opens, its inputs are read. */
static void tasking_start(skel_exec_t *x, skel_process_t *p, int64_t vt, int64_t now)
{
    skel_plan_t *plan = x->plan;
    process_record_begin(x, p, p->k_base + p->next_k, job_minor(plan, p), p->job.release, vt, now,
                         &p->job.rec);
    if (p->k_base + p->next_k == p->job.lockout_k) p->job.rec.flags |= SKELMSG_TIMING_T_FLAG_LOCKOUT;
    p->job.rec.generation = p->job.generation;
    (void)link_drain(plan->links, plan->nlinks); /* an lcm error shows as stale inputs */
    process_peek_inputs(plan, p, &p->job.rec);
    process_commit(plan, p, &p->job.rec, p->k_base + p->next_k >= p->measure_from_k);
    p->job.rec.asked_ns = draw_ns(&p->draw, p->compute_ns);
    p->job.remaining_ns = p->job.rec.asked_ns;
    p->job.slice_mono_ns = clock_mono_ns();
    p->job.rec.comm_in_ns = p->job.slice_mono_ns - now;
    p->job.state = JOB_STARTED;
}

/* P held the processor from its slice's start until T. */
static void tasking_ran(skel_process_t *p, int64_t t)
{
    int64_t d = t - p->job.slice_mono_ns;
    if (d <= 0) return;
    p->job.remaining_ns -= d;
    p->job.rec.compute_ns += d;
    p->job.slice_mono_ns = t;
}

/* P's computation is done: outputs, the record, the sums. */
static void tasking_complete(skel_exec_t *x, skel_process_t *p)
{
    skel_plan_t *plan = x->plan;
    int64_t t_out = clock_mono_ns();
    /* Its computation ended at its slice's end: a later wake-up (its stall) kept
     * it, so that the record's parts add up to where its work ended. */
    if (t_out > p->job.slice_mono_ns) p->job.rec.preempted_ns += t_out - p->job.slice_mono_ns;
    const int measured = p->k_base + p->next_k >= p->measure_from_k;
    process_write_outputs(x, p, p->k_base + p->next_k);
    process_finish(x, p, &p->job.rec, p->job.release, t_out, measured);
    p->job.state = JOB_NONE;
    p->next_k++;
    atomic_fetch_add(&x->s->minor_cycles, 1);
    if (measured) plan->sums.minor_cycles++;
}

/* The idle that followed a completed job ends at NOW: its record is complete and
 * counts in the sums, as on the cyclic executive. (P may have a new job by now:
 * the completed one is known by its record only.) */
static void tasking_flush(skel_exec_t *x, skel_process_t **idle, int64_t now)
{
    skel_process_t *p = *idle;
    if (p == NULL) return;
    int64_t release = p->job.rec.release_ns - x->s->clock_offset_ns;
    int64_t end = release + p->period_ns - p->job.rec.slack_ns;
    p->job.rec.idle_ns = now > end ? now - end : 0;
    cycle_account(x->plan, p, &p->job.rec, release, end);
    cycle_record(x->s, &p->job.rec);
    *idle = NULL;
}

static skel_process_t *tasking_highest(skel_plan_t *plan)
{
    for (int i = 0; i < plan->nprocesses; i++) /* sorted by priority, highest first */
        if (plan->processes[i].job.state >= JOB_READY) return &plan->processes[i];
    return NULL;
}

/* A pending live switch: the first point of the shared grid at or after the
 * COMMIT's instant whose releases are not jobs yet (those at VT are when DONE),
 * and its minor index J_SW; INT64_MAX when none is pending. */
static int64_t tasking_switch_at(skel_exec_t *x, int64_t vt, int done, int64_t *j_sw)
{
    cycle_poll_switch(x);
    if (!x->switch_pending) return INT64_MAX;
    const skel_plan_t *plan = x->plan;
    int64_t j_prev = tasking_floor_div(vt - plan->epoch_t0_ns - !done, plan->minor_ns);
    *j_sw = swap_index(plan, j_prev, x->switch_at_mono_ns);
    return swap_instant(plan, *j_sw);
}

/* The switch at VT, minor J_SW, before VT's releases: the old plan's idle record
 * ends here; the job that held the processor holds it on if it still may. */
static void tasking_switch(skel_exec_t *x, skel_process_t **cur, skel_process_t **idle, int64_t vt,
                           int64_t j_sw)
{
    tasking_flush(x, idle, clock_mono_ns());
    int16_t running = *cur != NULL ? (*cur)->id : -1;
    skel_plan_t *next = cycle_take(x);
    if (next == NULL || !cycle_switch(x, next, j_sw, vt > x->plan->run_t0_ns)) return;
    skel_plan_t *plan = x->plan;
    int i = running >= 0 ? plan_process_index(plan, running) : -1;
    *cur = i >= 0 && plan->processes[i].job.state == JOB_STARTED ? &plan->processes[i] : NULL;
    cycle_announce(x);
    for (i = 0; i < plan->nprocesses; i++) /* its inputs may have changed */
        if (plan->processes[i].job.state == JOB_WAITING) tasking_check_data(x, &plan->processes[i], vt);
}

void tasking_run(skel_exec_t *x)
{
    skel_plan_t *plan = x->plan;
    int64_t vt = plan->epoch_t0_ns, released = -1;
    skel_process_t *cur = NULL, *idle = NULL;
    for (int i = 0; i < plan->nprocesses; i++) {
        plan->processes[i].job.anchor_ns = plan->epoch_t0_ns;
        plan->processes[i].job.back_period_ns = plan->processes[i].period_ns;
        plan->processes[i].job.back_generation = plan->generation;
    }
    int64_t woke_mono = clock_mono_ns(), woke_cpu = clock_thread_cpu_ns();
    for (;;) {
        int64_t j_sw = 0, t_sw = tasking_switch_at(x, vt, released == vt, &j_sw);
        if (t_sw <= vt && !swap_tasking_ready(plan, t_sw)) {
            x->switch_at_mono_ns = t_sw + 1; /* the next point of the grid */
            continue;
        }
        if (t_sw <= vt) {
            tasking_switch(x, &cur, &idle, vt, j_sw);
            plan = x->plan;
            continue;
        }
        /* Releasing the jobs due only decides, in memory (no link read or written, no
         * lock, no system call): taking longer than the stall threshold there is the
         * platform's, read by the wall clock alone, as the thread CPU clock charges a VM's
         * stopped vCPU to the thread and so cannot see it. It delays the job that runs
         * next. (The CPU-clock check below sees only a stop that was not charged, another
         * thread's: in this window that would count twice, but no other thread of a faithful
         * run can take the processor for that long.) */
        const int64_t decide_from = clock_mono_ns();
        tasking_release_due(x, vt);
        released = vt;
        const int64_t decided = clock_mono_ns() - decide_from;
        if (decided > x->s->compute.stall_ns) x->wake_stall_ns += decided;
        int64_t next = tasking_lockouts(x, vt);
        skel_process_t *h = tasking_highest(plan);
        int64_t now = clock_mono_ns();
        if (h != cur && cur != NULL && cur->job.state == JOB_STARTED) /* preempted at the last event */
            cur->job.rec.preemptions++;
        if (h != NULL) tasking_flush(x, &idle, now);
        if (h != cur && h != NULL) {
            if (h->job.state == JOB_READY) {
                tasking_start(x, h, vt, now); /* takes x->wake_stall_ns; its slice starts */
            } else {
                int64_t resumed = clock_mono_ns();
                h->job.rec.preempted_ns += resumed - h->job.slice_mono_ns;
                h->job.slice_mono_ns = resumed;
            }
        }
        if (h != NULL) { /* a late wake-up delayed the job that runs after it */
            h->job.rec.stall_ns += x->wake_stall_ns;
            x->wake_stall_ns = 0;
        }
        cur = h;
        /* The next event: a release, the running job's completion, a lockout, the end. */
        int watch = 0;
        for (int i = 0; i < plan->nprocesses; i++) {
            skel_process_t *p = &plan->processes[i];
            /* an idle event process waits for its event: an arrival wakes the schedule */
            watch |= p->job.state == JOB_WAITING || (p->event >= 0 && p->job.state == JOB_NONE);
            int64_t r = job_next_release(p);
            if (p->job.state == JOB_NONE && r < next) next = r;
        }
        if (h != NULL && h->job.slice_mono_ns + h->job.remaining_ns < next) next = h->job.slice_mono_ns + h->job.remaining_ns;
        if (t_sw < next) next = t_sw;
        if (x->end_mono_ns < next) next = x->end_mono_ns;
        /* Between two waits the thread works (inputs, outputs): time it did not run
         * there is a stall too. It delayed the job that has the processor now (its
         * start or its inputs), or, with none, the job that runs next. */
        int64_t off = clock_mono_ns() - woke_mono - (clock_thread_cpu_ns() - woke_cpu);
        if (off > x->s->compute.stall_ns) {
            if (h != NULL) h->job.rec.stall_ns += off;
            else x->wake_stall_ns += off;
        }
        int64_t stall = 0;
        int rc = tasking_wait(x, next, watch, &stall);
        if (h != NULL) h->job.rec.stall_ns += stall; /* the running job's end came that late */
        else x->wake_stall_ns += stall;           /* it delays the job that runs next */
        woke_mono = clock_mono_ns();
        woke_cpu = clock_thread_cpu_ns();
        if (rc == 2) break;
        /* The event's instant: a computation ends, a release comes, on time; data when seen. */
        int64_t t = rc == 0 ? next : woke_mono;
        if (t > next) t = next;
        if (h != NULL) tasking_ran(h, t);
        if (t > vt) vt = t;
        if (vt >= x->end_mono_ns) break;
        if (h != NULL && h->job.remaining_ns <= 0) {
            tasking_complete(x, h);
            tasking_flush(x, &idle, clock_mono_ns());
            idle = h;
            cur = NULL;
        }
        if (watch) { /* data for a waiting job, or an event */
            (void)link_drain(plan->links, plan->nlinks);
            for (int i = 0; i < plan->nprocesses; i++)
                if (plan->processes[i].job.state == JOB_WAITING) tasking_check_data(x, &plan->processes[i], vt);
        }
    }
    tasking_flush(x, &idle, clock_mono_ns());
}
