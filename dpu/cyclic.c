/* cyclic.c: the cyclic executive, the paper's procedural model. One thread
 * per DPU runs its processes in their configured order on an absolute grid of
 * minor cycles t0 + j*m (CLOCK_MONOTONIC, TIMER_ABSTIME). A late DPU runs the
 * next due release at once and falls further behind, and on an overloaded DPU
 * that backlog is what turns an overload into a lockout; only a `sync: data`
 * process a whole period late on a DPU whose load fits skips a release. A COMMIT
 * during a run switches to the next plan at one boundary (swap.c, cycle.c). */
#include <stdatomic.h>

#include "dpu.h"

/* The cyclic executive's own state: the last record of the last minor that ran
 * anything is held, as its idle ends where the next one runs (a sync: event
 * process may leave minors empty). */
typedef struct {
    skel_exec_t *x;
    skel_rec_t held;
    skel_process_t *held_p;    /* NULL: none held */
    int64_t held_release, held_end;
} cyclic_t;

/* The first minor cycle >= J at which some process is due (INT64_MAX: none). */
int64_t cyclic_next_release(const skel_plan_t *plan, int64_t j)
{
    int64_t best = INT64_MAX;
    for (int i = 0; i < plan->nprocesses; i++) {
        int64_t r = plan->processes[i].ratio;
        int64_t due = (j + r - 1) / r * r;
        if (due < best) best = due;
    }
    return best;
}

/* Whether P runs in minor J: due there, and for an event process, holding an
 * event (cyclic_take_events). */
static int cyclic_runs(const skel_process_t *p, int64_t j)
{
    return j % p->ratio == 0 && (p->event < 0 || p->queue.taken_ns >= 0);
}

/* A sync: event process due in minor J takes the oldest event waiting when the
 * frame starts (drained then); without one it does not run in this frame (no record). */
static void cyclic_take_events(skel_plan_t *plan, int64_t j)
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
static void cyclic_release_held(cyclic_t *c, int64_t until)
{
    if (c->held_p == NULL) return;
    if (until != INT64_MAX) c->held.idle_ns = until > c->held_end ? until - c->held_end : 0;
    cycle_account(c->x->plan, c->held_p, &c->held, c->held_release, c->held_end);
    cycle_record(c->x->s, &c->held);
    c->held_p = NULL;
}

/* Runs the due processes of minor cycle J in their order; NEXT_R is the next
 * release (INT64_MAX: none), where the idle of the minor's last record ends. The
 * schedule's start of each is the minor's release plus the configured compute of
 * the processes before it and the data waits the design plans for them: a data
 * reader holds the DPU until its data comes (ready_ns after its release, the
 * prediction's), so what follows it is scheduled from there and only a longer
 * wait makes it late. 1 when the run stopped inside it. */
static int cyclic_minor(cyclic_t *c, int64_t j, int64_t next_r)
{
    skel_exec_t *x = c->x;
    skel_plan_t *plan = x->plan;
    cyclic_take_events(plan, j);
    int last = -1;
    for (int i = 0; i < plan->nprocesses; i++)
        if (cyclic_runs(&plan->processes[i], j)) last = i;
    if (last >= 0) cyclic_release_held(c, swap_instant(plan, j));
    int64_t sched = -1;
    for (int i = 0; i <= last; i++) {
        skel_process_t *p = &plan->processes[i];
        if (!cyclic_runs(p, j)) continue;
        /* an event process's cycles count its events, not its frames */
        int64_t k = p->event >= 0 ? p->next_k++ : j / p->ratio;
        int64_t release = plan->epoch_t0_ns + j / p->ratio * p->period_ns;
        if (sched < 0) sched = release;
        skel_rec_t rec;
        int64_t now = clock_mono_ns(), end;
        int rc = PROCESS_DONE;
        if (cycle_skips(plan, p, release, now)) {
            cycle_skip_record(x, p, p->k_base + k, plan->minor_base + j, release, sched, now, &rec);
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
            c->held = rec;
            c->held_p = p;
            c->held_release = release;
            c->held_end = end;
            continue;
        }
        if (rc == PROCESS_DONE) cycle_account(plan, p, &rec, release, end);
        cycle_record(x->s, &rec);
        if (rc == PROCESS_STOPPED) return 1;
    }
    return 0;
}

/* The switch instant on the current grid given J_PREV (the last minor run),
 * INT64_MAX when no switch is pending. */
static int64_t cyclic_switch_at(const skel_exec_t *x, int64_t j_prev, int64_t *j_sw)
{
    if (!x->switch_pending) return INT64_MAX;
    *j_sw = swap_index(x->plan, j_prev, x->switch_at_mono_ns);
    return swap_instant(x->plan, *j_sw);
}

/* The executive found itself at release R already past: what of the time since its
 * last step the thread was kept from running (a stop of the process between two steps,
 * after the last one judged) is the stall of this minor's wake-up, at most its lateness.
 * Nothing charged it, and the lateness it explains would read as the design's. */
static void cyclic_behind(skel_exec_t *x, int64_t r)
{
    int64_t now = clock_mono_ns();
    int64_t lost = process_lost(x, now, now - r);
    x->wake_stall_ns += lost;
    x->stall_debt_ns += lost;
}

/* The release after minor J: the plan's next due minor, or the switch if sooner. */
static int64_t cyclic_next_r(const skel_exec_t *x, int64_t j, int64_t next_j)
{
    int64_t next_r = next_j == INT64_MAX ? INT64_MAX : swap_instant(x->plan, next_j);
    int64_t j_sw;
    int64_t t_sw = cyclic_switch_at(x, j, &j_sw);
    return t_sw < next_r ? t_sw : next_r;
}

/* The cyclic executive's loop: minor cycle after minor cycle until the run's end. */
void cyclic_run(skel_exec_t *x, const skel_run_t *run)
{
    skel_server_t *s = x->s;
    cyclic_t c = { .x = x, .held_p = NULL };
    int ran = 0;
    int64_t j_prev = -1, j = cyclic_next_release(x->plan, 0), j_sw = 0;
    for (;;) {
        cycle_poll_switch(x);
        int64_t r = j == INT64_MAX ? INT64_MAX : swap_instant(x->plan, j);
        int64_t t_sw = cyclic_switch_at(x, j_prev, &j_sw);
        if (t_sw <= r && t_sw < run->end_mono_ns) {
            skel_plan_t *next = cycle_take(x);
            if (next != NULL) {
                cyclic_release_held(&c, INT64_MAX); /* its process is the old plan's */
                (void)cycle_switch(x, next, j_sw, ran);
            }
            j_prev = -1;
            j = cyclic_next_release(x->plan, 0);
            continue;
        }
        if (x->announce && r == INT64_MAX) cycle_announce(x); /* a plan without processes */
        int64_t until = r < run->end_mono_ns ? r : run->end_mono_ns;
        int on_time = clock_mono_ns() < until;
        int rc = cycle_wait(x, until);
        if (rc == 2) continue;
        if (rc != 0 || r >= run->end_mono_ns) break;
        if (on_time) process_woke(x, until);
        else cyclic_behind(x, r);
        atomic_store(&s->behind_ns, on_time ? 0 : clock_mono_ns() - r);
        if (x->announce) cycle_announce(x);
        int64_t next_j = cyclic_next_release(x->plan, j + 1);
        if (cyclic_minor(&c, j, cyclic_next_r(x, j, next_j)) != 0) break;
        ran = 1;
        atomic_fetch_add(&s->minor_cycles, 1);
        if (r >= x->plan->measure_from_ns) x->plan->sums.minor_cycles++;
        j_prev = j;
        j = next_j;
    }
    cyclic_release_held(&c, INT64_MAX);
}
