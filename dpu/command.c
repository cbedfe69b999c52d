/* command.c: what the control thread does with a config or a command. A config
 * is checked, decoded, our part found and validated, then staged; apply.c turns
 * it into the plan on COMMIT (between runs at once, during a run at the
 * COMMIT's cycle boundary) or when it arrives already committed. A staged
 * config that a newer one overtakes is discarded, never applied. Commands act
 * once per seq: the host repeats them over lossy multicast. */
#include <signal.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <unistd.h>

#include "dpu.h"

/* Our id is absent (or ambiguous for --id auto): keep waiting, unconfigured. */
static void command_absent(skel_control_t *c, const skelmsg_config_t *cfg, const char *reason)
{
    skel_server_t *s = c->s;
    skel_plan_t *old = NULL;
    if (pthread_mutex_lock(&s->lock) != 0) return;
    if (!s->run_active) {
        old = s->plan;
        s->plan = NULL;
        s->state = SKELMSG_STATUS_T_STATE_UNCONFIGURED;
    }
    pthread_mutex_unlock(&s->lock);
    plan_free(old);
    report_reject(c, cfg->generation, reason, 0);
}

/* Re-sends of a generation we already applied, offered for a switch, staged or
 * refused change nothing. A newer generation discards an uncommitted staged one. */
static int command_config_known(skel_control_t *c, const skelmsg_config_t *cfg)
{
    skel_server_t *s = c->s;
    int known = 0, apply = 0;
    skelmsg_config_t *discard = NULL;
    if (pthread_mutex_lock(&s->lock) != 0) return 1;
    if (s->applied_any && cfg->generation <= s->generation) known = 1;
    else if (s->next_generation >= 0 && cfg->generation <= s->next_generation) known = 1;
    else if (cfg->generation == s->rejected_generation && s->reject_reason[0] != '\0') known = 1;
    else if (s->staged != NULL && cfg->generation == s->staged_generation) {
        known = 1;
        apply = cfg->committed;
    } else if (s->staged != NULL && cfg->generation > s->staged_generation) {
        discard = s->staged;
        s->staged = NULL;
        s->apply_pending = 0;
    }
    pthread_mutex_unlock(&s->lock);
    if (discard != NULL)
        log_line("DPU %d: generation %lld discarded (never committed): %lld arrived", s->dpu_id,
                 (long long)discard->generation, (long long)cfg->generation);
    wire_free_config(discard);
    if (apply) apply_staged(c);
    return known;
}

void command_handle_config(skel_control_t *c, const void *data, int len)
{
    skel_server_t *s = c->s;
    skelmsg_config_t *cfg = malloc(sizeof *cfg);
    if (cfg == NULL) return;
    if (wire_decode_config(data, len, cfg) != 0) {
        free(cfg);
        atomic_fetch_add(&s->rejected, 1);
        server_fault(s, SKELMSG_STATUS_T_FAULT_REJECTED_MESSAGES);
        return;
    }
    if (command_config_known(c, cfg)) {
        wire_free_config(cfg);
        return;
    }
    char what[64];
    snprintf(what, sizeof what, "generation %lld", (long long)cfg->generation);
    if (owner_refuses(c, cfg->session, cfg->force, cfg->sender, what, cfg->generation)) {
        wire_free_config(cfg);
        return;
    }
    skel_self_t self;
    char reason[SKEL_REASON_LEN];
    if (config_find_self(cfg, s->id_arg, s->hostname, &self) != 0) {
        command_absent(c, cfg, self.reason);
        wire_free_config(cfg);
        return;
    }
    if (config_validate(cfg, self.dpu_index, reason, sizeof reason) != 0 ||
        code_check(cfg, self.dpu_id, s->lib_dirs, s->nlib_dirs, reason, sizeof reason) != 0) {
        char line[SKEL_REASON_LEN];
        snprintf(line, sizeof line, "generation %lld rejected: %.200s", (long long)cfg->generation,
                 reason);
        report_reject(c, cfg->generation, line, 1);
        wire_free_config(cfg);
        return;
    }
    if (pthread_mutex_lock(&s->lock) != 0) return;
    wire_free_config(s->staged);
    s->staged = cfg;
    s->staged_generation = cfg->generation;
    s->staged_dpu_index = self.dpu_index;
    if (!s->run_active) s->dpu_id = self.dpu_id;
    s->reject_reason[0] = '\0';
    int committed = cfg->committed;
    pthread_mutex_unlock(&s->lock);
    atomic_fetch_and(&s->faults, ~SKELMSG_STATUS_T_FAULT_CONFIG_REJECTED);
    log_line("DPU %d: staged generation %lld%s", self.dpu_id, (long long)cfg->generation,
             committed ? " (committed)" : "");
    c->status_due = 1;
    if (committed) apply_staged(c);
}

/* 1 when this exact command was acted on already. The whole command is
 * compared, not just seq, so a restarted host reusing small seqs still works. */
static int command_seen(skel_control_t *c, const skelmsg_command_t *cmd)
{
    skel_seen_t now = { cmd->seq, cmd->generation, cmd->run_id, cmd->at_utc_ns, cmd->ping_t1_ns,
                        cmd->kind };
    int n = c->nseen < SKEL_SEEN_COMMANDS ? c->nseen : SKEL_SEEN_COMMANDS;
    for (int i = 0; i < n; i++) {
        const skel_seen_t *o = &c->seen[i];
        if (o->seq == now.seq && o->kind == now.kind && o->generation == now.generation &&
            o->run_id == now.run_id && o->at_utc_ns == now.at_utc_ns &&
            o->ping_t1_ns == now.ping_t1_ns)
            return 1;
    }
    c->seen[c->nseen % SKEL_SEEN_COMMANDS] = now;
    c->nseen++;
    return 0;
}

static const char *command_state_name(int8_t state)
{
    static const char *names[] = { "UNCONFIGURED", "READY", "ARMED", "RUNNING" };
    return state >= 0 && state <= 3 ? names[state] : "?";
}

static void command_start(skel_control_t *c, const skelmsg_command_t *cmd)
{
    skel_server_t *s = c->s;
    char reason[SKEL_REASON_LEN] = "";
    int64_t now_mono = clock_mono_ns(), now_utc = clock_utc_ns();
    if (pthread_mutex_lock(&s->lock) != 0) return;
    if (!s->applied_any || s->generation != cmd->generation)
        snprintf(reason, sizeof reason, "START for generation %lld but applied %lld",
                 (long long)cmd->generation, (long long)s->generation);
    else if (s->state != SKELMSG_STATUS_T_STATE_READY)
        snprintf(reason, sizeof reason, "START of run %lld while %s (run %lld)",
                 (long long)cmd->run_id, command_state_name(s->state), (long long)s->run_id);
    /* Anyone's int64s: a start or an end beyond SKEL_FAR_NS is no run, and refusing it
     * keeps start + duration (here and in owner_take) from overflowing. */
    else if (cmd->at_utc_ns > now_utc && cmd->at_utc_ns - now_utc > SKEL_FAR_NS)
        snprintf(reason, sizeof reason, "START of run %lld at %lld ns UTC: more than ten years ahead",
                 (long long)cmd->run_id, (long long)cmd->at_utc_ns);
    else if (cmd->duration_ns > SKEL_FAR_NS)
        snprintf(reason, sizeof reason, "START of run %lld for %lld ns: more than ten years",
                 (long long)cmd->run_id, (long long)cmd->duration_ns);
    if (reason[0] != '\0') {
        pthread_mutex_unlock(&s->lock);
        report_reject(c, -1, reason, 0);
        return;
    }
    /* The links' network the kernel takes, applied now and undone at the run's end (the lock
     * let go: the executive is idle, and only this thread arms a run). */
    pthread_mutex_unlock(&s->lock);
    if (shape_apply(&c->shaper, &s->plan->shape, reason, sizeof reason) != 0) {
        report_reject(c, -1, reason, 0);
        return;
    }
    if (pthread_mutex_lock(&s->lock) != 0) {
        shape_remove(&c->shaper);
        return;
    }
    /* In the past (or 0): start now. Converted only when ahead, so no difference overflows. */
    int64_t start = cmd->at_utc_ns > now_utc ? clock_utc_to_mono(cmd->at_utc_ns, now_mono, now_utc) : now_mono;
    owner_take(s, cmd, clock_mono_to_utc(start, now_mono, now_utc));
    s->run = (skel_run_t){ 1, cmd->run_id, cmd->generation, start,
                           cmd->duration_ns > 0 ? start + cmd->duration_ns : INT64_MAX };
    s->run_id = cmd->run_id;
    s->run_generation = cmd->generation;
    s->run_active = 1;
    s->run_ended = 0;
    s->nlockouts = 0;
    s->state = SKELMSG_STATUS_T_STATE_ARMED;
    s->reject_reason[0] = '\0';
    atomic_store(&s->stop, 0);
    atomic_store(&s->minor_cycles, 0);
    atomic_store(&s->overruns, 0);
    atomic_store(&s->timing_batches, 0);
    atomic_store(&s->ring.lost, 0);
    /* Run-scoped faults restart; a rejected config or message stays visible. */
    atomic_fetch_and(&s->faults, SKELMSG_STATUS_T_FAULT_CONFIG_REJECTED |
                                     SKELMSG_STATUS_T_FAULT_REJECTED_MESSAGES);
    s->rejected_at_start = atomic_load(&s->rejected);
    pthread_cond_signal(&s->cond);
    pthread_mutex_unlock(&s->lock);
    c->batch_seq = 0;
    timing_batch_clear(&c->batch);
    history_reset(&c->history, cmd->run_id);
    log_line("DPU %d: run %lld armed: start in %.3f ms, duration %.3f s", s->dpu_id,
             (long long)cmd->run_id, (double)(start - now_mono) / 1e6,
             (double)cmd->duration_ns / 1e9);
    c->status_due = 1;
}

static void command_stop(skel_control_t *c)
{
    skel_server_t *s = c->s;
    atomic_store(&s->stop, 1);
    server_wake(s->wake_fd); /* interrupts a data-synchronised wait */
    log_line("DPU %d: STOP", s->dpu_id);
}

static void command_commit(skel_control_t *c, const skelmsg_command_t *cmd)
{
    skel_server_t *s = c->s;
    char reason[SKEL_REASON_LEN] = "";
    if (pthread_mutex_lock(&s->lock) != 0) return;
    int applied = s->applied_any && s->generation == cmd->generation;
    int offered = s->next_generation >= 0 && s->next_generation == cmd->generation;
    int staged = s->staged != NULL && s->staged_generation == cmd->generation;
    int live = s->run_active;
    if (!applied && !offered && !staged)
        snprintf(reason, sizeof reason, "COMMIT for generation %lld but staged %lld%s",
                 (long long)cmd->generation, (long long)s->staged_generation,
                 s->staged == NULL ? " (none waiting)" : "");
    pthread_mutex_unlock(&s->lock);
    /* Ignored, not a fault: nothing changes, and the status says why. */
    if (reason[0] != '\0') report_reject(c, -1, reason, 0);
    else if (staged && live) apply_commit_live(c, cmd->at_utc_ns);
    else if (staged) apply_staged(c);
}

/* The logger missed some of what we published: publish it again, as it was. */
static void command_resend(skel_control_t *c, const skelmsg_command_t *cmd)
{
    skel_resend_t ask = { cmd->run_id, cmd->batch_from, cmd->batch_to, cmd->with_report };
    int gone = 0;
    int sent = history_resend(&c->history, c->s->rec, &ask, &gone);
    log_line("DPU %d: re-sent %d of run %lld (batches %lld..%lld%s)%s", c->s->dpu_id, sent,
             (long long)cmd->run_id, (long long)cmd->batch_from, (long long)cmd->batch_to,
             cmd->with_report ? " and the report" : "",
             gone > 0 ? ": some no longer held" : "");
}

/* The commands that steer a run, by name; NULL for those anyone may send. */
static const char *command_steers(int8_t kind)
{
    switch (kind) {
    case SKELMSG_COMMAND_T_START: return "START";
    case SKELMSG_COMMAND_T_STOP: return "STOP";
    case SKELMSG_COMMAND_T_COMMIT: return "COMMIT";
    case SKELMSG_COMMAND_T_SHUTDOWN: return "SHUTDOWN";
    default: return NULL;
    }
}

static void command_dispatch(skel_control_t *c, const skelmsg_command_t *cmd, int64_t received)
{
    skel_server_t *s = c->s;
    if (cmd->dpu != -1 && cmd->dpu != s->dpu_id) return;
    if (command_seen(c, cmd)) return;
    const char *steers = command_steers(cmd->kind);
    if (steers != NULL && owner_refuses(c, cmd->session, cmd->force, cmd->sender, steers, -1)) return;
    switch (cmd->kind) {
    case SKELMSG_COMMAND_T_START: command_start(c, cmd); break;
    case SKELMSG_COMMAND_T_STOP: command_stop(c); break;
    case SKELMSG_COMMAND_T_COMMIT: command_commit(c, cmd); break;
    case SKELMSG_COMMAND_T_PING:
        c->ping_seq = cmd->seq;
        c->ping_t1_ns = cmd->ping_t1_ns;
        c->ping_t2_ns = received;
        c->ping_t3_ns = server_now(s); /* as late as possible: just before the publish */
        if (report_status_publish(c) != 0) log_line("cannot answer ping %lld", (long long)cmd->seq);
        break;
    case SKELMSG_COMMAND_T_RESEND: command_resend(c, cmd); break;
    case SKELMSG_COMMAND_T_SHUTDOWN:
        log_line("DPU %d: SHUTDOWN", s->dpu_id);
        /* main() waits for SIGTERM in sigwait: the same clean path as a signal. */
        if (kill(getpid(), SIGTERM) != 0) log_line("cannot signal shutdown");
        break;
    default:
        atomic_fetch_add(&s->rejected, 1);
        server_fault(s, SKELMSG_STATUS_T_FAULT_REJECTED_MESSAGES);
        break;
    }
}

void command_handle_command(skel_control_t *c, const void *data, int len)
{
    skel_server_t *s = c->s;
    int64_t received = server_now(s);
    skelmsg_command_t cmd;
    if (wire_decode_command(data, len, &cmd) != 0) {
        atomic_fetch_add(&s->rejected, 1);
        server_fault(s, SKELMSG_STATUS_T_FAULT_REJECTED_MESSAGES);
        return;
    }
    command_dispatch(c, &cmd, received);
    skelmsg_command_t_decode_cleanup(&cmd); /* the sender string */
}
