/* buffers.c: what a DPU holds of the buffers its processes read and write, and
 * the per-input accounting of the paper's "new data counts": at each cycle an
 * input is new (a sequence newer than the one this process last used), or stale
 * (nothing newer), and `dropped` counts the sequences skipped in between (the
 * writer is faster than the reader, or messages were lost). Pure functions on
 * plain structs, so the unit tests drive them without a network. */
#include <string.h>

#include "dpu.h"

void buffers_slot_reset(skel_slot_t *slot)
{
    slot->newest_seq = -1;
    slot->dup_upto = -1;
    slot->newest_send_ns = 0;
    slot->newest_recv_ns = 0;
    slot->received = 0;
    slot->foreign = 0;
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
    slot->received++;
    /* A late, reordered message still counts as received but never replaces newer data. */
    if (hdr->seq > slot->newest_seq) {
        slot->newest_seq = hdr->seq;
        slot->newest_send_ns = hdr->send_ns;
        slot->newest_recv_ns = recv_ns;
        /* Real code reads the bytes (code.c); a message longer than the buffer is cut. */
        if (slot->bytes != NULL && payload != NULL) {
            slot->nbytes = hdr->nbytes < 0 ? 0 : hdr->nbytes > slot->cap ? slot->cap : hdr->nbytes;
            memcpy(slot->bytes, payload, (size_t)slot->nbytes);
        }
    }
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
