/* executive.c: the cyclic executive, the paper's procedural model. One thread
 * per DPU runs its processes in their configured order on an absolute grid of
 * minor cycles t0 + j*m (CLOCK_MONOTONIC, TIMER_ABSTIME). Releases are never
 * skipped: a late DPU runs the next due release at once and falls further
 * behind, and that backlog is what turns an overload into a lockout. Between
 * runs the thread waits for a START and keeps the link queues drained. */
#include <sched.h>
#include <string.h>

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
        skel_log("DPU %d: warning: cannot pin to CPU %d (%s); running unpinned", plan->dpu,
                 plan->cpu, rc > 0 ? strerror(rc) : "out of range");
}

static int64_t executive_max_period(const skel_plan_t *plan)
{
    int64_t m = 0;
    for (int i = 0; i < plan->nprocesses; i++)
        if (plan->processes[i].period_ns > m) m = plan->processes[i].period_ns;
    return m;
}

/* The DPU's measured window starts when every process is past its warm-up, so
 * its % compute / communicate / wait cover one consistent stretch of time. */
static void executive_account(skel_plan_t *plan, skel_process_t *p, const skel_rec_t *rec,
                              int64_t release, int64_t end)
{
    skel_dpu_sums_t *d = &plan->sums;
    if (rec->cycle >= plan->warmup_cycles) p->wait_sum += rec->idle_ns;
    if (release < plan->measure_from_ns) return;
    if (d->first_release_ns < 0) d->first_release_ns = release;
    d->end_ns = end + rec->idle_ns;
    d->compute_ns += rec->compute_ns;
    d->communicate_ns += rec->comm_in_ns + rec->comm_out_ns;
    d->wait_ns += rec->blocked_ns + rec->idle_ns;
}

static void executive_record(skel_server_t *s, const skel_rec_t *rec)
{
    if (timing_ring_push(&s->ring, rec) != 0) server_fault(s, SKELMSG_STATUS_T_FAULT_TIMING_LOST);
}

/* Runs the due processes of minor cycle J; 1 when the run stopped inside it. */
static int executive_minor(skel_exec_t *x, int64_t t0, int64_t j, int64_t next_j)
{
    skel_plan_t *plan = x->plan;
    int last = -1;
    for (int i = 0; i < plan->nprocesses; i++)
        if (j % plan->processes[i].ratio == 0) last = i;
    for (int i = 0; i <= last; i++) {
        skel_process_t *p = &plan->processes[i];
        if (j % p->ratio != 0) continue;
        int64_t k = j / p->ratio;
        int64_t release = t0 + k * p->period_ns;
        skel_rec_t rec;
        int rc = process_cycle(x, p, k, j, release, &rec);
        int64_t end = release + p->period_ns - rec.slack_ns;
        /* Idle belongs to the last process of the release: gaps between processes are overhead. */
        if (i == last && rc == PROCESS_DONE && next_j != INT64_MAX) {
            int64_t next = t0 + next_j * plan->minor_ns;
            rec.idle_ns = next > end ? next - end : 0;
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

void executive_run(skel_server_t *s, skel_plan_t *plan, const skel_run_t *run)
{
    skel_exec_t x = { s, plan, run->end_mono_ns };
    plan_reset_run(plan, run->run_id);
    plan->clock_offset_ns = s->clock_offset_ns;
    executive_pin(plan);
    int64_t t0 = run->start_mono_ns;
    plan->measure_from_ns = t0 + plan->warmup_cycles * executive_max_period(plan);
    if (clock_sleep_until(t0, &s->stop) != 0) return;
    plan->running = 1;
    executive_set_state(s, SKELMSG_STATUS_T_STATE_RUNNING);
    skel_log("DPU %d: run %lld started (%d processes)", plan->dpu, (long long)run->run_id,
             plan->nprocesses);
    for (int64_t j = executive_next_release(plan, 0); j != INT64_MAX;) {
        int64_t r = t0 + j * plan->minor_ns;
        if (r >= run->end_mono_ns || atomic_load(&s->stop)) break;
        if (clock_sleep_until(r, &s->stop) != 0) break;
        int64_t next_j = executive_next_release(plan, j + 1);
        if (executive_minor(&x, t0, j, next_j) != 0) break;
        atomic_fetch_add(&s->minor_cycles, 1);
        if (r >= plan->measure_from_ns) plan->sums.minor_cycles++;
        j = next_j;
    }
    if (plan->nprocesses == 0) (void)clock_sleep_until(run->end_mono_ns, &s->stop);
    plan->running = 0;
}

/* Waits for a START; the plan cannot be swapped while a run holds it
 * (control.c only applies a config when no run is active). */
void *executive_main(void *arg)
{
    skel_server_t *s = arg;
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
