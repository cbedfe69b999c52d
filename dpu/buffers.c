/* buffers.c: what a DPU holds of the buffers its processes read and write, and
 * the per-input accounting of the paper's "new data counts": at each cycle an
 * input is new (a sequence newer than the one this process last used), or stale
 * (nothing newer), and `dropped` counts the sequences skipped in between (the
 * writer is faster than the reader, or messages were lost). Pure functions on
 * plain structs, so the unit tests drive them without a network. */
#include <math.h>
#include <string.h>

#include "dpu.h"

#define BUFFERS_STAMP_PAST_NS (10 * SKEL_NS_PER_S) /* a send stamp older than its arrival by more is damaged */

void buffers_slot_reset(skel_slot_t *slot)
{
    slot->newest_seq = -1;
    slot->dup_upto = -1;
    slot->newest_send_ns = 0;
    slot->newest_recv_ns = 0;
    slot->received = 0;
    slot->foreign = 0;
    slot->pend_head = slot->pend_count = 0;
    slot->last_due_ns = INT64_MIN;
    slot->bad = 0;
    slot->lost = slot->overflow = 0;
    slot->heard_seq = -1;
}

/* Each reading DPU draws its own losses and delays (a link loses a version for one reader,
 * not for all), the same from run to run with the same seed: a stream of its own, apart from
 * the processes' (draw_seed: the id in the top bits) and the generators' (0x8000 | i). */
void buffers_slot_seed(skel_slot_t *slot, int64_t seed, int16_t dpu)
{
    uint64_t mine = (uint64_t)seed ^ 0x5851f42d4c957f2dULL ^ ((uint64_t)(uint16_t)dpu << 20);
    draw_seed_state(slot->state, (int64_t)mine, (uint16_t)slot->buffer);
}

static int buffers_emulated(const skel_slot_t *slot)
{
    const skel_transport_t *tr = &slot->tr;
    return tr->latency_ns > 0 || tr->jitter_ns > 0 || tr->loss > 0 || tr->enter > 0 || slot->bus != NULL;
}

void buffers_bus_reset(skel_bus_t *bus)
{
    bus->free_ns = INT64_MIN;
    bus->dropped = 0;
    bus->nheard = 0;
}

/* A message's turn on its link's transmitter, from *AT on: *AT becomes the instant its last
 * byte is sent. 0 when it would wait longer than the queue holds: dropped, for every reader
 * here. */
static int buffers_bus_send(skel_bus_t *bus, int64_t *at, int32_t bytes)
{
    int64_t start = *at > bus->free_ns ? *at : bus->free_ns;
    if (start - *at > bus->queue_ns) {
        bus->dropped++;
        return 0;
    }
    bus->free_ns = *at = start + (int64_t)((double)bytes * bus->ns_per_byte + 0.5);
    return 1;
}

/* Gilbert-Elliott: the state moves first, then the version is lost with its state's loss. */
static int buffers_lost(skel_slot_t *slot)
{
    const skel_transport_t *tr = &slot->tr;
    if (tr->enter > 0 && draw_unit(slot->state) < (slot->bad ? tr->leave : tr->enter)) slot->bad = !slot->bad;
    double p = slot->bad ? tr->burst_loss : tr->loss;
    return p > 0 && draw_unit(slot->state) < p;
}

/* One version's delay: the latency plus a jitter draw (uniform in +-jitter, or normal with
 * jitter as its standard deviation, cut at 3), never below 0. */
static int64_t buffers_delay(skel_slot_t *slot)
{
    const skel_transport_t *tr = &slot->tr;
    double z = 0;
    if (tr->jitter_ns > 0 && tr->jitter == SKELMSG_LINK_T_JITTER_NORMAL) {
        double u1 = 1.0 - draw_unit(slot->state), u2 = draw_unit(slot->state); /* u1 in (0, 1] */
        z = sqrt(-2.0 * log(u1)) * cos(6.283185307179586 * u2);
        z = z > 3 ? 3 : z < -3 ? -3 : z;
    } else if (tr->jitter_ns > 0) {
        z = 2.0 * draw_unit(slot->state) - 1.0;
    }
    double d = (double)tr->latency_ns + z * (double)tr->jitter_ns;
    return d <= 0 ? 0 : (int64_t)(d + 0.5);
}

/* A version the reader may see from AT on. */
/* PAYLOAD (NBYTES of it) is kept when real code here reads the slot (code.c); a held
 * version has none, and real code is refused an input whose link holds versions (config.c). */
static void buffers_take(skel_slot_t *slot, int64_t seq, int64_t send_ns, int64_t at_ns,
                         const uint8_t *payload, int32_t nbytes)
{
    slot->received++;
    /* A late, reordered message still counts as received but never replaces newer data. */
    if (seq > slot->newest_seq) {
        slot->newest_seq = seq;
        slot->newest_send_ns = send_ns;
        slot->newest_recv_ns = at_ns;
        /* a message longer than the buffer is cut */
        if (slot->bytes != NULL && payload != NULL) {
            slot->nbytes = nbytes < 0 ? 0 : nbytes > slot->cap ? slot->cap : nbytes;
            memcpy(slot->bytes, payload, (size_t)slot->nbytes);
        }
    }
}

void buffers_slot_advance(skel_slot_t *slot, int64_t now_ns)
{
    while (slot->pend_count > 0 && slot->pending[slot->pend_head].due_ns <= now_ns) {
        const skel_pending_t *v = &slot->pending[slot->pend_head];
        buffers_take(slot, v->seq, v->send_ns, v->due_ns, NULL, 0);
        slot->pend_head = (slot->pend_head + 1) % slot->pend_cap;
        slot->pend_count--;
    }
}

void buffers_slot_carry(skel_slot_t *slot, const skel_slot_t *old)
{
    memcpy(slot->state, old->state, sizeof slot->state);
    slot->bad = old->bad;
    slot->lost = old->lost;
    slot->overflow = old->overflow;
    slot->last_due_ns = old->last_due_ns;
    for (int n = 0; n < old->pend_count; n++) {
        const skel_pending_t *v = &old->pending[(old->pend_head + n) % old->pend_cap];
        if (v->seq > slot->dup_upto) slot->dup_upto = v->seq;
        if (slot->pend_cap == 0) /* the new plan's link delays nothing: seen at once, stamped as due */
            buffers_take(slot, v->seq, v->send_ns, v->due_ns, NULL, 0);
        else if (slot->pend_count < slot->pend_cap)
            slot->pending[(slot->pend_head + slot->pend_count++) % slot->pend_cap] = *v;
        else
            slot->overflow++;
    }
}

int64_t buffers_advance(skel_plan_t *plan, int64_t now_mono_ns)
{
    buffers_flush(plan);
    int64_t next = INT64_MAX;
    for (int i = 0; i < plan->nslots; i++) {
        skel_slot_t *slot = &plan->slots[i];
        if (slot->pend_count == 0) continue;
        buffers_slot_advance(slot, now_mono_ns + plan->clock_offset_ns);
        if (slot->pend_count > 0 && slot->pending[slot->pend_head].due_ns - plan->clock_offset_ns < next)
            next = slot->pending[slot->pend_head].due_ns - plan->clock_offset_ns;
    }
    return next;
}

/* After the bus, if any: lost, held until due from FROM, or seen at once. Versions leave in
 * the order they came (a link delivers in order): one due before an earlier one waits for
 * it. A full ring drops the version, counted. */
static void buffers_deliver(skel_slot_t *slot, int64_t seq, int64_t send_ns, int64_t from, int64_t recv_ns,
                            const uint8_t *payload, int32_t nbytes)
{
    if (buffers_lost(slot)) {
        slot->lost++;
        return;
    }
    if (slot->pending == NULL) { /* loss only */
        buffers_take(slot, seq, send_ns, recv_ns, payload, nbytes);
        return;
    }
    int64_t due = from + buffers_delay(slot);
    if (due < slot->last_due_ns) due = slot->last_due_ns;
    if (due <= recv_ns && slot->pend_count == 0) {
        slot->last_due_ns = recv_ns;
        buffers_take(slot, seq, send_ns, recv_ns, payload, nbytes);
        return;
    }
    if (slot->pend_count == slot->pend_cap) {
        slot->overflow++;
        return;
    }
    slot->pending[(slot->pend_head + slot->pend_count++) % slot->pend_cap] = (skel_pending_t){ seq, send_ns, due };
    slot->last_due_ns = due;
}

/* The messages a bus heard since its last flush through its transmitter, in the order of
 * their send stamps (then of buffer id: every reading DPU the same), each then delivered to
 * its slot. Insertion sort, in place: each writer's messages come in order already, and
 * nothing is allocated. */
static void buffers_bus_flush(skel_bus_t *bus)
{
    for (int i = 1; i < bus->nheard; i++) {
        skel_heard_t h = bus->heard[i];
        int j = i;
        for (; j > 0 && (bus->heard[j - 1].from_ns > h.from_ns ||
                         (bus->heard[j - 1].from_ns == h.from_ns && bus->heard[j - 1].slot->buffer > h.slot->buffer));
             j--)
            bus->heard[j] = bus->heard[j - 1];
        bus->heard[j] = h;
    }
    for (int i = 0; i < bus->nheard; i++) {
        skel_heard_t *h = &bus->heard[i];
        int sent = buffers_bus_send(bus, &h->from_ns, h->bytes);
        if (!sent && !h->slot->unread) h->slot->lost++;
        if (sent && !h->slot->unread) buffers_deliver(h->slot, h->seq, h->send_ns, h->from_ns, h->recv_ns, NULL, 0);
    }
    bus->nheard = 0;
}

void buffers_flush(const skel_plan_t *plan)
{
    for (int k = 0; k < plan->nbuses; k++)
        if (plan->buses[k].nheard > 0) buffers_bus_flush(&plan->buses[k]);
}

/* Through the link's emulated transport: on a bandwidth-limited link, heard for its bus (whose
 * turn a version lost on the way takes too); then delivered. */
static void buffers_transport(skel_slot_t *slot, const wire_buffer_hdr_t *hdr, const uint8_t *payload,
                              int64_t recv_ns)
{
    /* From the send stamp, but no later than the arrival, nor long before it: a stamp from
     * another clock or a damaged message can hold nothing longer than the delay, nor overflow. */
    int64_t from = slot->tr.from_send && hdr->send_ns < recv_ns && hdr->send_ns > recv_ns - BUFFERS_STAMP_PAST_NS
                   ? hdr->send_ns : recv_ns;
    if (slot->bus == NULL) {
        buffers_deliver(slot, hdr->seq, hdr->send_ns, from, recv_ns, payload, hdr->nbytes);
        return;
    }
    skel_bus_t *bus = slot->bus;
    if (bus->nheard == SKEL_BUS_HEARD) buffers_bus_flush(bus);
    bus->heard[bus->nheard++] = (skel_heard_t){ slot, hdr->seq, hdr->send_ns, from, recv_ns,
                                                slot->wire_extra + (hdr->nbytes > 0 ? hdr->nbytes : 0) };
    if (hdr->seq > slot->heard_seq) slot->heard_seq = hdr->seq;
}

/* A message whose buffer id or writer is not this channel's is malformed or
 * misconfigured (BUFFERS_MISMATCH, counted as rejected); one from another run
 * is a leftover or a neighbour's test (BUFFERS_FOREIGN_RUN, ignored quietly). */
int buffers_slot_receive(skel_slot_t *slot, int64_t run_id, const wire_buffer_hdr_t *hdr,
                         const uint8_t *payload, int64_t recv_ns)
{
    if (hdr->buffer != slot->buffer || hdr->writer != slot->writer) return BUFFERS_MISMATCH;
    if (hdr->run_id != run_id) {
        slot->foreign++;
        return BUFFERS_FOREIGN_RUN;
    }
    /* After a live switch the new plan's lcm_t holds copies of what the old one
     * delivered already: those are not received twice. */
    if (hdr->seq <= slot->dup_upto) return BUFFERS_DUPLICATE;
    if (buffers_emulated(slot)) buffers_transport(slot, hdr, payload, recv_ns);
    else buffers_take(slot, hdr->seq, hdr->send_ns, recv_ns, payload, hdr->nbytes);
    return BUFFERS_ACCEPTED;
}

void buffers_input_reset(skel_input_t *in)
{
    in->last_used = -1;
    in->received_seen = 0;
    in->n_new = in->n_stale = in->n_dropped = 0;
}

static int32_t buffers_clamp32(int64_t v)
{
    if (v > INT32_MAX) return INT32_MAX;
    if (v < 0) return 0;
    return (int32_t)v;
}

/* What this cycle would see, without consuming it: a data-synchronised process
 * peeks repeatedly while it waits and commits once. */
void buffers_input_peek(const skel_input_t *in, const skel_slot_t *slot, skel_in_rec_t *rec)
{
    rec->buffer = in->buffer;
    rec->seq = slot->newest_seq;
    rec->new_data = slot->newest_seq >= 0 && slot->newest_seq > in->last_used;
    /* An input added by a live switch never used anything: nothing was dropped for it.
     * newest - 1 - last_used, in that order: with last_used -1 (nothing used yet) and
     * a sequence of INT64_MAX from the wire, newest - last_used would overflow. */
    int counts = rec->new_data && in->last_used != SKEL_SEQ_JOINED;
    rec->dropped = counts ? buffers_clamp32((slot->newest_seq - 1) - in->last_used) : 0;
    rec->received = buffers_clamp32(slot->received - in->received_seen);
    rec->sent_ns = slot->newest_send_ns;
    rec->recv_ns = slot->newest_recv_ns;
}

/* Only new data advances last_used; MEASURED adds the cycle to the report sums. */
void buffers_input_commit(skel_input_t *in, const skel_slot_t *slot, const skel_in_rec_t *rec,
                          int measured)
{
    if (rec->new_data) in->last_used = rec->seq;
    in->received_seen = slot->received;
    if (!measured) return;
    if (rec->new_data) in->n_new++;
    else in->n_stale++;
    in->n_dropped += rec->dropped;
}

/* The generated encoder copies the payload each cycle (the dummy one, or the NBYTES real
 * code wrote, at most out->bytes): moving the bytes is the communication being emulated.
 * OUT->enc was sized at config time. */
int buffers_output_encode(skel_output_t *out, int64_t run_id, int16_t writer, int64_t seq,
                          int64_t send_ns, const uint8_t *payload, int32_t nbytes)
{
    skelmsg_buffer_t msg;
    memset(&msg, 0, sizeof msg);
    msg.run_id = run_id;
    msg.writer = writer;
    msg.buffer = out->buffer;
    msg.seq = seq;
    msg.send_ns = send_ns;
    msg.nbytes = nbytes;
    msg.payload = (uint8_t *)payload;
    return skelmsg_buffer_t_encode(out->enc, 0, out->enc_len, &msg);
}
