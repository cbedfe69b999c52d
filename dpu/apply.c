/* apply.c: a staged config becomes this DPU's plan, always on the control
 * thread (every allocation, every lcm_t). Between runs it replaces the plan at
 * once: on COMMIT, or when a config arrives already committed (the host's
 * periodic re-send, which is how a restarted DPU catches up: it applies the
 * config and is READY for the next START, without joining a run in progress).
 * During a run, a COMMIT offers the built plan to the executive as
 * s->next_plan, and the executive switches at one cycle boundary (swap.c,
 * cycle.c); a committed re-send during our own run waits for its end,
 * because only a COMMIT names the instant at which every DPU switches. */

#include <stdio.h>
#include <string.h>

#include "dpu.h"

/* Takes the staged config and builds its plan with its links open; NULL (the
 * config refused, the current plan untouched) when that fails. */
static skel_plan_t *apply_build(skel_control_t *c)
{
    skel_server_t *s = c->s;
    char reason[SKEL_REASON_LEN];
    if (pthread_mutex_lock(&s->lock) != 0) return NULL;
    skelmsg_config_t *cfg = s->staged;
    int index = s->staged_dpu_index;
    s->staged = NULL;
    pthread_mutex_unlock(&s->lock);
    if (cfg == NULL) return NULL;
    skel_plan_t *plan = plan_build(cfg, index, reason, sizeof reason);
    if (plan != NULL && code_load(plan, cfg, s->lib_dirs, s->nlib_dirs, reason, sizeof reason) != 0) {
        char line[SKEL_REASON_LEN];
        snprintf(line, sizeof line, "generation %lld rejected: %.200s", (long long)cfg->generation, reason);
        snprintf(reason, sizeof reason, "%s", line);
        plan_free(plan);
        plan = NULL;
    }
    /* LCM's receive threads, started by plan_open_links, inherit our name and policy. A
     * buffer a process waits on must not queue behind every ordinary thread of a busy
     * machine: they take the executive's own SCHED_FIFO priority. (One below, they queued
     * behind every other DPU's runnable executive on a shared machine: the namespace lab's
     * 64 DPUs dropped 32-70 % of their buffers, against 0-0.4 % at the same priority.) */
    int prio = plan != NULL ? cycle_rt_priority(s, plan) : 0;
    struct sched_param fifo = { .sched_priority = prio }, other = { .sched_priority = 0 };
    int raised = prio > 0 && pthread_setschedparam(pthread_self(), SCHED_FIFO, &fifo) == 0;
    (void)pthread_setname_np(pthread_self(), "lcm-link"); /* for LCM's threads, as in control.c */
    if (plan != NULL && plan_open_links(plan, s->url, s->rec_url, &s->rejected, reason, sizeof reason) != 0) {
        plan_free(plan);
        plan = NULL;
    }
    (void)pthread_setname_np(pthread_self(), "skel-ctl");
    if (raised && pthread_setschedparam(pthread_self(), SCHED_OTHER, &other) != 0)
        log_line("DPU %d: the control thread stays under SCHED_FIFO %d", s->dpu_id, prio);
    if (plan == NULL) report_reject(c, cfg->generation, reason, 1);
    wire_free_config(cfg);
    return plan;
}

/* Between runs only (the control thread is the one that starts runs). */
static void apply_install(skel_control_t *c, skel_plan_t *plan)
{
    skel_server_t *s = c->s;
    if (pthread_mutex_lock(&s->lock) != 0) return;
    skel_plan_t *old = s->plan;
    s->plan = plan;
    s->generation = plan->generation;
    s->applied_any = 1;
    s->state = SKELMSG_STATUS_T_STATE_READY;
    pthread_mutex_unlock(&s->lock);
    plan_free(old); /* the executive drains links only under the lock: old is unused */
    snprintf(c->network, sizeof c->network, "%s", plan->shape.text);
    log_line("DPU %d: applied generation %lld: %d processes, %d links, minor cycle %lld us",
             plan->dpu, (long long)plan->generation, plan->nprocesses, plan->nlinks,
             (long long)(plan->minor_ns / SKEL_NS_PER_US));
    c->status_due = 1;
}

/* Applies the staged config if no run holds the plan; otherwise it waits for
 * the end of the run (the control thread, control.c, calls again then). */
void apply_staged(skel_control_t *c)
{
    skel_server_t *s = c->s;
    if (pthread_mutex_lock(&s->lock) != 0) return;
    if (s->staged == NULL || s->run_active) {
        s->apply_pending = s->staged != NULL;
        pthread_mutex_unlock(&s->lock);
        return;
    }
    pthread_mutex_unlock(&s->lock);
    skel_plan_t *plan = apply_build(c);
    if (plan != NULL) apply_install(c, plan);
}

/* The COMMIT's instant on our monotonic clock; 0 (the next release) for 0 or
 * any instant in the past, and far instants clamped so nothing overflows. */
static int64_t apply_at_mono(int64_t at_utc_ns)
{
    if (at_utc_ns <= 0) return 0;
    int64_t now_mono = clock_mono_ns(), now_utc = clock_utc_ns();
    if (at_utc_ns - now_utc > SKEL_FAR_NS) at_utc_ns = now_utc + SKEL_FAR_NS;
    int64_t at = clock_utc_to_mono(at_utc_ns, now_mono, now_utc);
    return at > now_mono ? at : 0;
}

/* What a live switch from OLD to NEXT cannot do yet (NULL: it can). The tasking
 * executive switches at a boundary as the cyclic one does (swap.c), both where it
 * runs the schedule itself (SLEEP) and on kernel threads; not from one executive,
 * or one of those two ways, to the other. */
static int apply_runs_code(const skel_plan_t *plan)
{
    for (int i = 0; i < plan->nprocesses; i++)
        if (plan->processes[i].code != NULL) return 1;
    return 0;
}

static int apply_kernel_shapes(const skel_plan_t *plan)
{
    for (int i = 0; i < plan->shape.n; i++)
        if (plan->shape.links[i].taken) return 1;
    return 0;
}

static const char *apply_live_refused(const skel_plan_t *old, const skel_plan_t *next)
{
    if (old == NULL) return NULL;
    if (apply_runs_code(old) || apply_runs_code(next))
        return "a live switch of a DPU running real code is not built (its init and fini): push between runs";
    if (old->tasking != next->tasking)
        return "a live switch between the cyclic and the tasking executive is not built: push between runs";
    if (strcmp(old->shape.text, next->shape.text) != 0 && (apply_kernel_shapes(old) || apply_kernel_shapes(next)))
        return "a live switch of a link's latency, jitter, loss or bandwidth under run.network: kernel is "
               "not built (the host's tc holds the run's): push between runs, or run.network: emulated";
    if (next->tasking && (old->compute == SKELMSG_DPU_T_COMPUTE_SLEEP) != (next->compute == SKELMSG_DPU_T_COMPUTE_SLEEP))
        return "a live switch of the tasking executive between compute mode sleep (its own schedule) and "
               "cpu, wall or work (kernel threads) is not built: push between runs";
    return NULL;
}

/* COMMIT during a run: build now, switch at the first release at or after
 * AT_UTC_NS. A plan offered earlier and not taken yet is replaced. */
void apply_commit_live(skel_control_t *c, int64_t at_utc_ns)
{
    skel_server_t *s = c->s;
    int64_t at = apply_at_mono(at_utc_ns);
    skel_plan_t *plan = apply_build(c);
    if (plan == NULL) return;
    if (pthread_mutex_lock(&s->lock) != 0) return;
    if (!s->run_active) {
        pthread_mutex_unlock(&s->lock);
        apply_install(c, plan);
        return;
    }
    const char *refused = apply_live_refused(s->plan, plan);
    if (refused != NULL) {
        pthread_mutex_unlock(&s->lock);
        report_reject(c, plan->generation, refused, 1);
        plan_free(plan);
        return;
    }
    /* The executive hands back at most one plan per switch: emptied before each offer. */
    skel_plan_t *retired = s->retired, *replaced = s->next_plan;
    s->retired = NULL;
    s->next_plan = plan;
    s->next_at_mono_ns = at;
    s->next_generation = plan->generation;
    atomic_fetch_add(&s->switch_seq, 1);
    pthread_mutex_unlock(&s->lock);
    /* The tasking executive sleeps until its next event (a completion, a release): a COMMIT
     * for a point of the grid before it must wake it, or the switch comes at that event, late
     * and off the grid (a COMMIT 1 ms before the point, during a 3 ms computation: 1 ms late). */
    if (clock_simulated()) clock_poke();
    else server_wake(s->wake_fd);
    snprintf(c->network, sizeof c->network, "%s", plan->shape.text);
    plan_free(retired);
    plan_free(replaced);
    log_line("DPU %d: generation %lld ready: switch in %.3f ms (run %lld)", plan->dpu,
             (long long)plan->generation, at > 0 ? (double)(at - clock_mono_ns()) / 1e6 : 0.0,
             (long long)s->run_id);
    c->status_due = 1;
}

/* At the end of a run: a plan offered but not reached becomes the plan, and a
 * plan a switch replaced is freed. */
void apply_install_next(skel_control_t *c)
{
    skel_server_t *s = c->s;
    if (pthread_mutex_lock(&s->lock) != 0) return;
    skel_plan_t *next = s->next_plan, *retired = s->retired, *old = NULL;
    s->next_plan = s->retired = NULL;
    s->next_generation = -1;
    atomic_fetch_add(&s->switch_seq, 1);
    if (next != NULL) {
        old = s->plan;
        s->plan = next;
        s->generation = next->generation;
    }
    pthread_mutex_unlock(&s->lock);
    plan_free(retired);
    plan_free(old);
    if (next != NULL) snprintf(c->network, sizeof c->network, "%s", next->shape.text);
    if (next != NULL)
        log_line("DPU %d: applied generation %lld at the end of run %lld", next->dpu,
                 (long long)next->generation, (long long)s->run_id);
}

/* Every control loop: free what a switch handed back, and keep the offered
 * plan's link queues short (its handler ignores messages until it runs; the
 * executive takes the plan under the same lock, so never while we drain). */
void apply_drain_next(skel_control_t *c)
{
    skel_server_t *s = c->s;
    if (pthread_mutex_lock(&s->lock) != 0) return;
    skel_plan_t *retired = s->retired;
    s->retired = NULL;
    if (s->next_plan != NULL) (void)link_drain(s->next_plan->links, s->next_plan->nlinks);
    pthread_mutex_unlock(&s->lock);
    plan_free(retired);
}
