/* timing.c: per-process-cycle timing records on their way from the executive
 * to the log. The executive pushes into a lock-free single-producer /
 * single-consumer ring (C11 atomics, no lock in the cycle loop); the control
 * thread pops them into a timing_t batch whose parallel arrays were allocated
 * once. A full ring loses the record and counts it: the cycle loop never waits
 * for the reporting side. */
#include <stdlib.h>
#include <string.h>

#include "dpu.h"

int timing_ring_init(skel_ring_t *ring, uint64_t cap)
{
    if (cap == 0 || (cap & (cap - 1)) != 0) return -1;
    ring->recs = calloc(cap, sizeof *ring->recs);
    if (ring->recs == NULL) return -1;
    /* Every page written now: calloc maps untouched pages, and the ring's first lap
     * would take a page fault in the cycle loop every few records (measured on
     * SERVO: ~0.4 a cycle for the first 20 s). */
    volatile unsigned char *page = (volatile unsigned char *)ring->recs;
    for (size_t at = 0; at < cap * sizeof *ring->recs; at += 4096) page[at] = 0;
    ring->cap = cap;
    atomic_init(&ring->head, 0);
    atomic_init(&ring->tail, 0);
    atomic_init(&ring->lost, 0);
    return 0;
}

void timing_ring_free(skel_ring_t *ring)
{
    free(ring->recs);
    ring->recs = NULL;
}

/* Producer only. Release on head publishes the record's bytes to the consumer. */
int timing_ring_push(skel_ring_t *ring, const skel_rec_t *rec)
{
    uint64_t head = atomic_load_explicit(&ring->head, memory_order_relaxed);
    uint64_t tail = atomic_load_explicit(&ring->tail, memory_order_acquire);
    if (head - tail >= ring->cap) {
        atomic_fetch_add_explicit(&ring->lost, 1, memory_order_relaxed);
        return -1;
    }
    ring->recs[head & (ring->cap - 1)] = *rec;
    atomic_store_explicit(&ring->head, head + 1, memory_order_release);
    return 0;
}

/* Consumer only: 1 with a record, 0 when empty. */
int timing_ring_pop(skel_ring_t *ring, skel_rec_t *rec)
{
    uint64_t tail = atomic_load_explicit(&ring->tail, memory_order_relaxed);
    uint64_t head = atomic_load_explicit(&ring->head, memory_order_acquire);
    if (tail == head) return 0;
    *rec = ring->recs[tail & (ring->cap - 1)];
    atomic_store_explicit(&ring->tail, tail + 1, memory_order_release);
    return 1;
}

int timing_batch_init(skel_batch_t *b)
{
    const int n = SKEL_BATCH_RECORDS, ni = SKEL_BATCH_RECORDS * SKEL_MAX_IO;
    skelmsg_timing_t *m = &b->msg;
    memset(b, 0, sizeof *b);
    m->process = calloc(n, sizeof *m->process);
    m->cycle = calloc(n, sizeof *m->cycle);
    m->minor = calloc(n, sizeof *m->minor);
    m->release_ns = calloc(n, sizeof *m->release_ns);
    m->sched_ns = calloc(n, sizeof *m->sched_ns);
    m->start_ns = calloc(n, sizeof *m->start_ns);
    m->comm_in_ns = calloc(n, sizeof *m->comm_in_ns);
    m->blocked_ns = calloc(n, sizeof *m->blocked_ns);
    m->asked_ns = calloc(n, sizeof *m->asked_ns);
    m->compute_ns = calloc(n, sizeof *m->compute_ns);
    m->comm_out_ns = calloc(n, sizeof *m->comm_out_ns);
    m->idle_ns = calloc(n, sizeof *m->idle_ns);
    m->slack_ns = calloc(n, sizeof *m->slack_ns);
    m->stall_ns = calloc(n, sizeof *m->stall_ns);
    m->debt_ns = calloc(n, sizeof *m->debt_ns);
    m->preemptions = calloc(n, sizeof *m->preemptions);
    m->preempted_ns = calloc(n, sizeof *m->preempted_ns);
    m->event_ns = calloc(n, sizeof *m->event_ns);
    m->event_queued = calloc(n, sizeof *m->event_queued);
    m->event_dropped = calloc(n, sizeof *m->event_dropped);
    m->flags = calloc(n, sizeof *m->flags);
    m->in_record = calloc(ni, sizeof *m->in_record);
    m->in_buffer = calloc(ni, sizeof *m->in_buffer);
    m->in_seq = calloc(ni, sizeof *m->in_seq);
    m->in_new = calloc(ni, sizeof *m->in_new);
    m->in_dropped = calloc(ni, sizeof *m->in_dropped);
    m->in_received = calloc(ni, sizeof *m->in_received);
    m->in_sent_ns = calloc(ni, sizeof *m->in_sent_ns);
    m->in_recv_ns = calloc(ni, sizeof *m->in_recv_ns);
    if (!m->process || !m->cycle || !m->minor || !m->release_ns || !m->sched_ns || !m->start_ns ||
        !m->comm_in_ns || !m->blocked_ns || !m->asked_ns || !m->compute_ns || !m->comm_out_ns || !m->idle_ns ||
        !m->slack_ns || !m->stall_ns || !m->debt_ns || !m->preemptions || !m->preempted_ns || !m->event_ns ||
        !m->event_queued || !m->event_dropped || !m->flags || !m->in_record || !m->in_buffer || !m->in_seq ||
        !m->in_new || !m->in_dropped || !m->in_received || !m->in_sent_ns || !m->in_recv_ns) {
        timing_batch_free(b);
        return -1;
    }
    return 0;
}

void timing_batch_free(skel_batch_t *b)
{
    skelmsg_timing_t *m = &b->msg;
    free(m->process); free(m->cycle); free(m->minor); free(m->release_ns);
    free(m->sched_ns); free(m->start_ns); free(m->comm_in_ns); free(m->blocked_ns); free(m->asked_ns);
    free(m->compute_ns); free(m->comm_out_ns); free(m->idle_ns); free(m->slack_ns);
    free(m->stall_ns); free(m->debt_ns); free(m->preemptions); free(m->preempted_ns);
    free(m->event_ns); free(m->event_queued); free(m->event_dropped); free(m->flags);
    free(m->in_record); free(m->in_buffer); free(m->in_seq); free(m->in_new);
    free(m->in_dropped); free(m->in_received); free(m->in_sent_ns); free(m->in_recv_ns);
    memset(b, 0, sizeof *b);
}

void timing_batch_clear(skel_batch_t *b)
{
    b->msg.n = 0;
    b->msg.ninputs = 0;
    b->first_add_ns = 0;
}

int timing_batch_full(const skel_batch_t *b)
{
    return b->msg.n >= SKEL_BATCH_RECORDS;
}

/* The caller checks timing_batch_full() first; a record always brings at most
 * SKEL_MAX_IO inputs, so the input arrays cannot overflow either. */
void timing_batch_add(skel_batch_t *b, const skel_rec_t *rec)
{
    skelmsg_timing_t *m = &b->msg;
    int i = m->n;
    if (i >= SKEL_BATCH_RECORDS) return;
    m->process[i] = rec->process;
    m->cycle[i] = rec->cycle;
    m->minor[i] = rec->minor;
    m->release_ns[i] = rec->release_ns;
    m->sched_ns[i] = rec->sched_ns;
    m->start_ns[i] = rec->start_ns;
    m->comm_in_ns[i] = rec->comm_in_ns;
    m->blocked_ns[i] = rec->blocked_ns;
    m->asked_ns[i] = rec->asked_ns;
    m->compute_ns[i] = rec->compute_ns;
    m->comm_out_ns[i] = rec->comm_out_ns;
    m->idle_ns[i] = rec->idle_ns;
    m->slack_ns[i] = rec->slack_ns;
    m->stall_ns[i] = rec->stall_ns;
    m->debt_ns[i] = rec->debt_ns;
    m->preemptions[i] = rec->preemptions;
    m->preempted_ns[i] = rec->preempted_ns;
    m->event_ns[i] = rec->event_ns;
    m->event_queued[i] = rec->event_queued;
    m->event_dropped[i] = rec->event_dropped;
    m->flags[i] = rec->flags;
    for (int q = 0; q < rec->ninputs && q < SKEL_MAX_IO; q++) {
        int w = m->ninputs++;
        const skel_in_rec_t *in = &rec->in[q];
        m->in_record[w] = i;
        m->in_buffer[w] = in->buffer;
        m->in_seq[w] = in->seq;
        m->in_new[w] = in->new_data;
        m->in_dropped[w] = in->dropped;
        m->in_received[w] = in->received;
        m->in_sent_ns[w] = in->sent_ns;
        m->in_recv_ns[w] = in->recv_ns;
    }
    m->n = i + 1;
}
