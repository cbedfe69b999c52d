/* report.c: what the DPU tells the host. status_t is the heartbeat (state,
 * generations, counters, faults, lockouts, whose run it is, the last ping, and
 * why the last config or command was refused); report_t is the end-of-run sums
 * over the measured window, a cross-check of the analysis of timing records.
 * Both are built by the control thread; a run's plan is read only after the
 * executive has finished with it. */
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "dpu.h"

/* LOCKOUTS (SKEL_MAX_LOCKOUTS), REASON (SKEL_REASON_LEN) and OWNER (SKEL_OWNER_LEN)
 * are the caller's storage, so the message stays valid after the lock is released. */
static void report_status_fill(skel_server_t *s, skelmsg_status_t *st, skelmsg_lockout_t *lockouts,
                               char *reason, char *owner)
{
    memset(st, 0, sizeof *st);
    reason[0] = owner[0] = '\0';
    st->reject_reason = reason;
    st->run_owner = owner;
    st->lockouts = lockouts;
    st->host = s->hostname;
    st->pid = s->pid;
    if (pthread_mutex_lock(&s->lock) != 0) return;
    st->dpu = s->dpu_id;
    st->state = s->state;
    st->generation = s->generation;
    st->staged_generation = s->staged_generation;
    st->rejected_generation = s->rejected_generation;
    memcpy(reason, s->reject_reason, SKEL_REASON_LEN);
    st->run_id = s->run_id;
    st->nlockouts = (int16_t)s->nlockouts;
    memcpy(lockouts, s->lockouts, sizeof(skelmsg_lockout_t) * (size_t)s->nlockouts);
    st->run_session = s->run_session;
    st->run_end_utc_ns = s->run_end_utc_ns;
    memcpy(owner, s->run_owner, SKEL_OWNER_LEN);
    pthread_mutex_unlock(&s->lock);
    reason[SKEL_REASON_LEN - 1] = '\0';
    owner[SKEL_OWNER_LEN - 1] = '\0';
    st->minor_cycles = atomic_load(&s->minor_cycles);
    st->faults = atomic_load(&s->faults);
    st->overruns = atomic_load(&s->overruns);
    st->rejected_messages = atomic_load(&s->rejected);
    const skel_seal_t *k = &s->seal; /* the control thread's, as this function is */
    st->keyed = (int8_t)k->keyed;
    st->rejected_unsigned = k->rejected[SEAL_UNSIGNED];
    st->rejected_signed = k->rejected[SEAL_SIGNED];
    st->rejected_forged = k->rejected[SEAL_FORGED];
    st->rejected_replayed = k->rejected[SEAL_REPLAYED];
    st->timing_batches = atomic_load(&s->timing_batches);
    st->timing_lost = atomic_load(&s->ring.lost);
    st->behind_ns = atomic_load(&s->behind_ns);
    st->stall_ns = atomic_load(&s->stall_ns);
    st->longest_stall_ns = atomic_load(&s->longest_stall_ns);
    st->longest_stall_mono_ns = atomic_load(&s->longest_stall_mono_ns);
    st->utc_ns = clock_utc_ns();
    st->mono_ns = server_now(s);
}

int report_status_publish(skel_control_t *c)
{
    skelmsg_status_t st;
    skelmsg_lockout_t lockouts[SKEL_MAX_LOCKOUTS];
    char reason[SKEL_REASON_LEN], owner[SKEL_OWNER_LEN];
    report_status_fill(c->s, &st, lockouts, reason, owner);
    st.ping_seq = c->ping_seq;
    st.ping_t1_ns = c->ping_t1_ns;
    st.ping_t2_ns = c->ping_t2_ns;
    st.ping_t3_ns = c->ping_t3_ns;
    st.network = c->network;
    c->last_status_ns = clock_mono_ns();
    c->status_due = 0;
    uint8_t enc[SKEL_STATUS_BYTES];
    int len = skelmsg_status_t_encode(enc, 0, sizeof enc, &st);
    return len < 0 ? -1 : seal_publish(&c->s->seal, c->s->rec, SKEL_STATUS_CHANNEL, enc, len);
}

/* A config or command refused (or, forced, let through): REASON goes in the
 * status at once, with GENERATION as rejected_generation when >= 0; FAULT marks
 * a config this DPU cannot run. */
void report_reject(skel_control_t *c, int64_t generation, const char *reason, int fault)
{
    skel_server_t *s = c->s;
    if (pthread_mutex_lock(&s->lock) != 0) return;
    if (generation >= 0) s->rejected_generation = generation;
    snprintf(s->reject_reason, sizeof s->reject_reason, "%s", reason);
    pthread_mutex_unlock(&s->lock);
    if (fault) server_fault(s, SKELMSG_STATUS_T_FAULT_CONFIG_REJECTED);
    log_line("DPU %d: %s", s->dpu_id, reason);
    c->status_due = 1;
}

static void report_fill_process(skelmsg_process_report_t *r, const skel_process_t *p)
{
    r->process = p->id;
    r->cycles = p->sums.cycles;
    r->overruns = p->sums.overruns;
    r->compute_ns = p->sums.compute_ns;
    r->communicate_ns = p->sums.communicate_ns;
    r->wait_ns = p->sums.wait_ns;
    r->max_latency_ns = p->sums.max_latency_ns;
    r->releases_skipped = p->sums.releases_skipped;
    r->events_dropped = p->sums.events_dropped;
    r->code_faults = p->code != NULL ? p->code->faults : 0;
    r->locked_out = p->locked_out;
    r->ninputs = (int16_t)p->ninputs;
    for (int q = 0; q < p->ninputs; q++) {
        r->input_buffer[q] = p->inputs[q].buffer;
        r->input_new[q] = p->inputs[q].n_new;
        r->input_stale[q] = p->inputs[q].n_stale;
        r->input_dropped[q] = p->inputs[q].n_dropped;
    }
}

/* Input arrays point into one block sized for the limits: no per-field frees. */
typedef struct {
    int16_t buffer[SKEL_MAX_IO];
    int64_t n_new[SKEL_MAX_IO], stale[SKEL_MAX_IO], dropped[SKEL_MAX_IO];
} report_inputs_t;

/* Where the window's elapsed time begins (analysis/measure/metrics.py elapsed_ns, the same
 * definition): its first release, or, when warm-up work was still going on then (a DPU
 * behind its schedule), when that work ended, at the latest the first measured start. */
static int64_t report_begin_ns(const skel_dpu_sums_t *d)
{
    if (d->warmup_end_ns <= d->first_release_ns) return d->first_release_ns;
    return d->warmup_end_ns < d->first_start_ns ? d->warmup_end_ns : d->first_start_ns;
}

int report_publish(skel_server_t *s, const skel_plan_t *plan, skel_history_t *history)
{
    skelmsg_report_t r;
    memset(&r, 0, sizeof r);
    int n = plan->nprocesses;
    skelmsg_process_report_t *procs = calloc((size_t)(n > 0 ? n : 1), sizeof *procs);
    report_inputs_t *ins = calloc((size_t)(n > 0 ? n : 1), sizeof *ins);
    if (procs == NULL || ins == NULL) {
        free(procs);
        free(ins);
        return -1;
    }
    for (int i = 0; i < n; i++) {
        procs[i].input_buffer = ins[i].buffer;
        procs[i].input_new = ins[i].n_new;
        procs[i].input_stale = ins[i].stale;
        procs[i].input_dropped = ins[i].dropped;
        report_fill_process(&procs[i], &plan->processes[i]);
    }
    const skel_dpu_sums_t *d = &plan->sums;
    r.dpu = plan->dpu;
    r.run_id = plan->run_id;
    r.generation = plan->generation;
    r.compute = plan->compute;
    r.speed = plan->speed;
    r.elapsed_ns = d->first_release_ns >= 0 ? d->end_ns - report_begin_ns(d) : 0;
    r.minor_cycles = d->minor_cycles;
    r.compute_ns = d->compute_ns;
    r.communicate_ns = d->communicate_ns;
    r.wait_ns = d->wait_ns;
    r.timing_batches = atomic_load(&s->timing_batches);
    r.timing_lost = atomic_load(&s->ring.lost);
    r.rejected_messages = atomic_load(&s->rejected) - s->rejected_at_start;
    r.faults = atomic_load(&s->faults);
    r.work_drift_pct = plan->work_drift_pct;
    r.stall_ns = d->stall_ns;
    r.nprocesses = (int16_t)n;
    r.processes = procs;
    /* What an emulated link took away shows in the analysis as lost (never received); the
     * log says which of it a full ring of held versions dropped rather than the link. */
    for (int i = 0; i < plan->nslots; i++)
        if (plan->slots[i].overflow > 0 || plan->slots[i].lost > 0)
            log_line("DPU %d: buffer %d: the link's emulation lost %lld versions, its full ring of held "
                     "versions %lld", plan->dpu, plan->slots[i].buffer, (long long)plan->slots[i].lost,
                     (long long)plan->slots[i].overflow);
    for (int k = 0; k < plan->nbuses; k++)
        if (plan->buses[k].dropped > 0)
            log_line("DPU %d: link %d: its emulated transmit queue (bandwidth) dropped %lld messages",
                     plan->dpu, plan->buses[k].link, (long long)plan->buses[k].dropped);
    int rc = history_publish_report(history, s->rec, &r);
    free(procs);
    free(ins);
    return rc;
}
