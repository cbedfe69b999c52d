/* server.c: the one server struct's life cycle and the few helpers both
 * threads use on it (wake-ups, faults, the reported clock). */
#include <errno.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/eventfd.h>
#include <unistd.h>

#include "dpu.h"

int server_init(skel_server_t *s)
{
    pthread_condattr_t attr;
    s->wake_fd = s->notify_fd = -1;
    if (pthread_mutex_init(&s->lock, NULL) != 0) return -1;
    if (pthread_condattr_init(&attr) != 0) return -1;
    /* Monotonic, so a wall-clock step cannot stretch the executive's idle wait. */
    if (pthread_condattr_setclock(&attr, CLOCK_MONOTONIC) != 0) return -1;
    if (pthread_cond_init(&s->cond, &attr) != 0) return -1;
    pthread_condattr_destroy(&attr);
    s->wake_fd = eventfd(0, EFD_NONBLOCK | EFD_CLOEXEC);
    s->notify_fd = eventfd(0, EFD_NONBLOCK | EFD_CLOEXEC);
    if (s->wake_fd < 0 || s->notify_fd < 0) return -1;
    if (timing_ring_init(&s->ring, SKEL_RING_RECORDS) != 0) return -1;
    s->dpu_id = -1;
    s->state = SKELMSG_STATUS_T_STATE_UNCONFIGURED;
    s->staged_dpu_index = -1;
    s->next_generation = -1;
    atomic_init(&s->switch_seq, 0);
    atomic_init(&s->stop, 0);
    atomic_init(&s->quit, 0);
    atomic_init(&s->minor_cycles, 0);
    atomic_init(&s->overruns, 0);
    atomic_init(&s->behind_ns, 0);
    atomic_init(&s->stall_ns, 0);
    atomic_init(&s->longest_stall_ns, 0);
    atomic_init(&s->longest_stall_mono_ns, 0);
    atomic_init(&s->rejected, 0);
    atomic_init(&s->timing_batches, 0);
    atomic_init(&s->faults, 0);
    return 0;
}

void server_free(skel_server_t *s)
{
    plan_free(s->plan);
    plan_free(s->next_plan);
    plan_free(s->retired);
    s->plan = s->next_plan = s->retired = NULL;
    if (s->staged != NULL) {
        skelmsg_config_t_decode_cleanup(s->staged);
        free(s->staged);
        s->staged = NULL;
    }
    timing_ring_free(&s->ring);
    if (s->wake_fd >= 0) close(s->wake_fd);
    if (s->notify_fd >= 0) close(s->notify_fd);
    pthread_cond_destroy(&s->cond);
    pthread_mutex_destroy(&s->lock);
}

/* The control thread's two lcm_t: on S->url, where the DPU receives, and on its record
 * URL (link_record_url), where it only sends. 0, or -1 with WHY. */
int server_open(skel_server_t *s, char *why, size_t len)
{
    if (link_record_url(s->url, s->rec_url, sizeof s->rec_url) != 0) {
        snprintf(why, len, "--url %s: expected udpm://GROUP:PORT?options, its group and port above "
                 "the record URL's offset (%d)", s->url, SKEL_RECORD_OFFSET);
        return -1;
    }
    s->ctl = clock_open(s->url);
    s->rec = s->ctl != NULL ? clock_open(s->rec_url) : NULL;
    if (s->rec == NULL) {
        snprintf(why, len, "cannot open %s URL %s (is there a multicast route?)", s->ctl ? "record" : "control",
                 s->ctl ? s->rec_url : s->url);
        server_close(s);
        return -1;
    }
    return 0;
}

void server_close(skel_server_t *s)
{
    if (s->rec != NULL) clock_close(s->rec);
    if (s->ctl != NULL) clock_close(s->ctl);
    s->rec = s->ctl = NULL;
}

/* Async-signal-safe: a write to an eventfd. A full counter is still readable. */
void server_wake(int fd)
{
    uint64_t one = 1;
    if (fd >= 0 && write(fd, &one, sizeof one) < 0 && errno != EAGAIN) {
        /* Nothing sensible to do: the reader polls with a timeout anyway. */
    }
}

void server_fault(skel_server_t *s, int fault)
{
    atomic_fetch_or(&s->faults, fault);
}

int64_t server_now(const skel_server_t *s)
{
    return clock_mono_ns() + s->clock_offset_ns;
}
