/* control.c: the control thread. It owns the lcm_t on the control URL: it
 * receives configs and commands (handled by command.c, which has apply.c build
 * plans), publishes status (report.c) every SKEL_STATUS_NS and at once on every
 * event, turns the executive's timing records into timing_t batches, and closes
 * each run (flush the records, publish the report, READY). Calls run one way:
 * from here to those files, never back. */
#include <errno.h>
#include <poll.h>
#include <stdlib.h>
#include <string.h>
#include <unistd.h>

#include "dpu.h"

int control_init(skel_control_t *c, skel_server_t *s)
{
    memset(c, 0, sizeof *c);
    c->s = s;
    c->ping_seq = -1;
    if (timing_batch_init(&c->batch) != 0) return -1;
    /* The largest batch: every record with every input. */
    c->batch.msg.n = SKEL_BATCH_RECORDS;
    c->batch.msg.ninputs = SKEL_BATCH_RECORDS * SKEL_MAX_IO;
    int largest = skelmsg_timing_t_encoded_size(&c->batch.msg);
    timing_batch_clear(&c->batch);
    if (history_init(&c->history, largest) != 0) {
        timing_batch_free(&c->batch);
        return -1;
    }
    c->history.seal = &s->seal;
    return 0;
}

void control_free(skel_control_t *c)
{
    history_free(&c->history);
    timing_batch_free(&c->batch);
}

static void control_publish_batch(skel_control_t *c)
{
    skel_server_t *s = c->s;
    if (c->batch.msg.n == 0) return;
    c->batch.msg.dpu = s->dpu_id;
    c->batch.msg.run_id = s->run_id;
    c->batch.msg.generation = c->batch_generation;
    c->batch.msg.batch_seq = c->batch_seq++;
    if (history_publish_batch(&c->history, s->rec, &c->batch.msg) != 0)
        log_line("cannot publish timing batch %lld", (long long)c->batch.msg.batch_seq);
    atomic_fetch_add(&s->timing_batches, 1);
    timing_batch_clear(&c->batch);
}

/* Full batches go at once; a partial one waits at most SKEL_BATCH_NS, or FLUSH.
 * A batch holds one generation: a live switch closes the batch in progress. */
static void control_drain_timing(skel_control_t *c, int flush)
{
    skel_rec_t rec;
    while (timing_ring_pop(&c->s->ring, &rec) == 1) {
        if (c->batch.msg.n > 0 && rec.generation != c->batch_generation) control_publish_batch(c);
        if (c->batch.msg.n == 0) {
            c->batch.first_add_ns = clock_mono_ns();
            c->batch_generation = rec.generation;
        }
        timing_batch_add(&c->batch, &rec);
        if (timing_batch_full(&c->batch)) control_publish_batch(c);
    }
    if (c->batch.msg.n > 0 && (flush || clock_mono_ns() - c->batch.first_add_ns >= SKEL_BATCH_NS))
        control_publish_batch(c);
}

/* The executive has left the run: every record is in the ring (the mutex that
 * carried run_ended orders them), so flush, report, and become READY. */
static void control_finish_run(skel_control_t *c)
{
    skel_server_t *s = c->s;
    control_drain_timing(c, 1);
    /* Before the report: whoever reads the log of a run that went wrong (a user, the test
     * harness once the host has the report) finds the platform's part of it there. The
     * longest stall is one cycle's (a record's stall_ns). */
    log_line("DPU %d: run %lld ended: %lld minor cycles, %lld overruns, %d lockouts, %lld timing lost, "
             "longest platform stall %.1f ms",
             s->dpu_id, (long long)s->run_id, (long long)atomic_load(&s->minor_cycles),
             (long long)atomic_load(&s->overruns), s->nlockouts,
             (long long)atomic_load(&s->ring.lost), (double)atomic_load(&s->longest_stall_ns) / 1e6);
    /* Before the report: a host tool that has it finds the host as it was before the run. */
    shape_remove(&c->shaper);
    if (report_publish(s, s->plan, &c->history) != 0) log_line("cannot publish the report of run %lld",
                                                  (long long)s->run_id);
    apply_install_next(c); /* a switch the run did not reach takes effect now */
    if (pthread_mutex_lock(&s->lock) != 0) return;
    s->run_ended = 0;
    s->run_active = 0;
    s->state = SKELMSG_STATUS_T_STATE_READY;
    int apply = s->apply_pending;
    s->apply_pending = 0;
    pthread_mutex_unlock(&s->lock);
    for (int i = 0; s->verbose && s->plan != NULL && i < s->plan->nprocesses; i++) {
        const skel_process_t *p = &s->plan->processes[i];
        log_line("DPU %d:   process %d: %lld measured cycles, %lld overruns, max latency %lld us%s",
                 s->dpu_id, p->id, (long long)p->sums.cycles, (long long)p->sums.overruns,
                 (long long)(p->sums.max_latency_ns / 1000), p->locked_out ? ", LOCKED OUT" : "");
    }
    c->status_due = 1;
    if (apply) apply_staged(c);
}

/* Only what passes the seal check reaches command.c, without its seal. */
static int control_accept(skel_control_t *c, const lcm_recv_buf_t *rbuf, const char *channel, int *len)
{
    if (rbuf->data_size > INT32_MAX) return 0;
    return seal_check(&c->s->seal, c->s->dpu_id, channel, rbuf->data, (int)rbuf->data_size, len) == SEAL_GENUINE;
}

static void control_on_config(const lcm_recv_buf_t *rbuf, const char *channel, void *user)
{
    int len;
    if (control_accept(user, rbuf, channel, &len)) command_handle_config(user, rbuf->data, len);
}

static void control_on_command(const lcm_recv_buf_t *rbuf, const char *channel, void *user)
{
    int len;
    if (control_accept(user, rbuf, channel, &len)) command_handle_command(user, rbuf->data, len);
}

static int control_subscribe(skel_control_t *c)
{
    lcm_subscription_t *cfg = lcm_subscribe(c->s->ctl, SKEL_CONFIG_CHANNEL, control_on_config, c);
    lcm_subscription_t *cmd = lcm_subscribe(c->s->ctl, SKEL_COMMAND_CHANNEL, control_on_command, c);
    if (cfg == NULL || cmd == NULL) return -1;
    /* Unlimited queues: a burst of commands must not silently lose the newest. */
    if (lcm_subscription_set_queue_capacity(cfg, 0) != 0) return -1;
    return lcm_subscription_set_queue_capacity(cmd, 0);
}

static int control_poll(skel_control_t *c)
{
    struct pollfd fds[2] = {
        { .fd = lcm_get_fileno(c->s->ctl), .events = POLLIN },
        { .fd = c->s->notify_fd, .events = POLLIN },
    };
    int rc = poll(fds, 2, 10);
    if (rc < 0) return errno == EINTR ? 0 : -1;
    if (fds[0].revents & POLLIN)
        for (int n = 0; n < 1000 && lcm_handle_timeout(c->s->ctl, 0) > 0; n++) {
        }
    if (fds[1].revents & POLLIN) control_notice(c);
    return 0;
}

/* The executive said something happened (a lockout, a state, a switch): a status at once. */
void control_notice(skel_control_t *c)
{
    uint64_t v;
    if (read(c->s->notify_fd, &v, sizeof v) > 0) c->status_due = 1;
}

/* One round of the control thread's work between two polls: timing batches, a
 * switch's plans, the end of a run, the status when due. 1 once the executive has
 * exited. A simulation (sim.c) runs the same rounds on virtual time. */
int control_step(skel_control_t *c)
{
    skel_server_t *s = c->s;
    control_drain_timing(c, 0);
    apply_drain_next(c);
    if (pthread_mutex_lock(&s->lock) != 0) return 1;
    int ended = s->run_ended, done = s->exec_done;
    pthread_mutex_unlock(&s->lock);
    if (ended) control_finish_run(c);
    if (c->status_due || clock_mono_ns() - c->last_status_ns >= SKEL_STATUS_NS)
        if (report_status_publish(c) != 0) log_line("cannot publish status");
    seal_note(&s->seal, s->dpu_id);
    return done;
}

void *control_main(void *arg)
{
    skel_control_t *c = arg;
    skel_server_t *s = c->s;
    /* LCM starts its receive thread on the first subscription and the thread
     * inherits our name: give it its own, so its CPU is told apart. */
    (void)pthread_setname_np(pthread_self(), "lcm-ctl");
    int subscribed = control_subscribe(c);
    (void)pthread_setname_np(pthread_self(), "skel-ctl");
    if (subscribed != 0) {
        log_line("cannot subscribe to %s/%s on %s", SKEL_CONFIG_CHANNEL, SKEL_COMMAND_CHANNEL, s->url);
        return NULL;
    }
    c->status_due = 1;
    for (;;) {
        if (control_poll(c) != 0) log_line("control poll failed: %s", strerror(errno));
        if (control_step(c)) break;
    }
    return NULL;
}
