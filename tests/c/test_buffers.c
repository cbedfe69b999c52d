/* test_buffers.c: new / stale / dropped accounting, on the pure functions the
 * cycle uses, with the paper's mismatched-rate patterns. */
#include "check.h"
#include "dpu.h"

typedef struct {
    skel_slot_t slot;
    skel_input_t in;
    int64_t run_id;
} rig_t;

static void rig_init(rig_t *r)
{
    memset(r, 0, sizeof *r);
    r->slot.buffer = 3;
    r->slot.writer = 9;
    r->run_id = 42;
    r->in.buffer = 3;
    buffers_slot_reset(&r->slot);
    buffers_input_reset(&r->in);
}

static int rig_write(rig_t *r, int64_t seq)
{
    wire_buffer_hdr_t h = { r->run_id, 9, 3, seq, 1000 + seq, 16 };
    return buffers_slot_receive(&r->slot, r->run_id, &h, NULL, 2000 + seq);
}

static skel_in_rec_t rig_read(rig_t *r, int measured)
{
    skel_in_rec_t rec;
    buffers_input_peek(&r->in, &r->slot, &rec);
    buffers_input_commit(&r->in, &r->slot, &rec, measured);
    return rec;
}

/* Writer every 10 ms, reader every 5 ms: half the reads are stale, none dropped. */
static void test_stale_half(void)
{
    rig_t r;
    rig_init(&r);
    for (int tick = 0; tick < 100; tick++) {
        if (tick % 2 == 0) CHECK_EQ(rig_write(&r, tick / 2), BUFFERS_ACCEPTED);
        skel_in_rec_t rec = rig_read(&r, 1);
        CHECK_EQ(rec.new_data, tick % 2 == 0);
        CHECK_EQ(rec.received, tick % 2 == 0);
    }
    CHECK_EQ(r.in.n_new, 50);
    CHECK_EQ(r.in.n_stale, 50);
    CHECK_EQ(r.in.n_dropped, 0);
}

/* Writer every 5 ms, reader every 10 ms: every read is new and skips one sequence. */
static void test_drop_half(void)
{
    rig_t r;
    rig_init(&r);
    for (int tick = 0; tick < 100; tick++) {
        CHECK_EQ(rig_write(&r, tick), BUFFERS_ACCEPTED);
        if (tick % 2 == 0) continue;
        skel_in_rec_t rec = rig_read(&r, 1);
        CHECK_EQ(rec.new_data, 1);
        CHECK_EQ(rec.seq, tick);
        CHECK_EQ(rec.dropped, 1);
        CHECK_EQ(rec.received, 2);
        CHECK_EQ(rec.sent_ns, 1000 + tick);
        CHECK_EQ(rec.recv_ns, 2000 + tick);
    }
    CHECK_EQ(r.in.n_new, 50);
    CHECK_EQ(r.in.n_stale, 0);
    CHECK_EQ(r.in.n_dropped, 50);
}

static void test_loss_and_order(void)
{
    rig_t r;
    rig_init(&r);
    skel_in_rec_t rec = rig_read(&r, 1);
    CHECK_EQ(rec.seq, -1);
    CHECK_EQ(rec.new_data, 0);
    rig_write(&r, 0);
    CHECK_EQ(rig_read(&r, 1).dropped, 0);
    rig_write(&r, 4); /* 1..3 lost */
    rec = rig_read(&r, 1);
    CHECK_EQ(rec.dropped, 3);
    CHECK_EQ(rec.received, 1);
    /* A late, reordered message is received but does not replace newer data. */
    rig_write(&r, 2);
    rec = rig_read(&r, 1);
    CHECK_EQ(rec.new_data, 0);
    CHECK_EQ(rec.seq, 4);
    CHECK_EQ(rec.received, 1);
    CHECK_EQ(r.in.last_used, 4);
}

/* A sequence of INT64_MAX as the first message (the wire's, not ours): every earlier
 * one dropped, counted without overflow (a fuzzer found newest - last_used overflow). */
static void test_sequence_at_int64_max(void)
{
    rig_t r;
    rig_init(&r);
    wire_buffer_hdr_t h = { r.run_id, 9, 3, INT64_MAX, 1000, 16 };
    CHECK_EQ(buffers_slot_receive(&r.slot, r.run_id, &h, NULL, 2000), BUFFERS_ACCEPTED);
    skel_in_rec_t rec = rig_read(&r, 1);
    CHECK_EQ(rec.new_data, 1);
    CHECK_EQ(rec.dropped, INT32_MAX);
    CHECK_EQ(r.in.last_used, INT64_MAX);
}

static void test_foreign_and_mismatch(void)
{
    rig_t r;
    rig_init(&r);
    wire_buffer_hdr_t h = { 41, 9, 3, 5, 0, 16 };
    CHECK_EQ(buffers_slot_receive(&r.slot, r.run_id, &h, NULL, 0), BUFFERS_FOREIGN_RUN);
    CHECK_EQ(r.slot.foreign, 1);
    h.run_id = 42;
    h.writer = 8;
    CHECK_EQ(buffers_slot_receive(&r.slot, r.run_id, &h, NULL, 0), BUFFERS_MISMATCH);
    h.writer = 9;
    h.buffer = 4;
    CHECK_EQ(buffers_slot_receive(&r.slot, r.run_id, &h, NULL, 0), BUFFERS_MISMATCH);
    CHECK_EQ(r.slot.newest_seq, -1);
    CHECK_EQ(r.slot.received, 0);
}

/* Warm-up cycles advance the state but do not count in the report sums. */
static void test_warmup_not_counted(void)
{
    rig_t r;
    rig_init(&r);
    rig_write(&r, 0);
    rig_read(&r, 0);
    rig_read(&r, 0);
    CHECK_EQ(r.in.n_new + r.in.n_stale, 0);
    CHECK_EQ(r.in.last_used, 0);
    rig_write(&r, 2);
    rig_read(&r, 1);
    CHECK_EQ(r.in.n_new, 1);
    CHECK_EQ(r.in.n_dropped, 1);
}

static void test_output_encode(void)
{
    uint8_t dummy[64];
    memset(dummy, 0xA5, sizeof dummy);
    skel_output_t out = { .buffer = 7, .bytes = 64 };
    out.enc_len = wire_buffer_encoded_size(64);
    uint8_t enc[200];
    out.enc = enc;
    int len = buffers_output_encode(&out, 5, 2, 11, 123456, dummy, 64);
    CHECK_EQ(len, out.enc_len);
    wire_buffer_hdr_t h;
    CHECK_EQ(wire_buffer_header(enc, len, &h), 0);
    CHECK_EQ(h.run_id, 5);
    CHECK_EQ(h.writer, 2);
    CHECK_EQ(h.buffer, 7);
    CHECK_EQ(h.seq, 11);
    CHECK_EQ(h.send_ns, 123456);
    CHECK_EQ(h.nbytes, 64);
    CHECK(memcmp(enc + len - 64, dummy, 64) == 0);
}

static int rig_send(rig_t *r, int64_t seq, int64_t send_ns, int64_t recv_ns)
{
    wire_buffer_hdr_t h = { r->run_id, 9, 3, seq, send_ns, 16 };
    return buffers_slot_receive(&r->slot, r->run_id, &h, NULL, recv_ns);
}

/* A link's emulated latency: held until the send stamp plus the latency, in order, and a
 * full ring drops and counts. */
static void test_held_until_due_in_order(void)
{
    rig_t r;
    rig_init(&r);
    skel_pending_t ring[3];
    r.slot.pending = ring;
    r.slot.pend_cap = 3;
    r.slot.tr.latency_ns = 1000;
    r.slot.tr.from_send = 1;
    buffers_slot_seed(&r.slot, 1, 2);
    CHECK_EQ(rig_send(&r, 0, 0, 10), BUFFERS_ACCEPTED);
    buffers_slot_advance(&r.slot, 999);
    CHECK_EQ(rig_read(&r, 1).new_data, 0); /* arrived, not due */
    CHECK_EQ(r.slot.received, 0);
    buffers_slot_advance(&r.slot, 1000);
    skel_in_rec_t rec = rig_read(&r, 1);
    CHECK_EQ(rec.seq, 0);
    CHECK_EQ(rec.recv_ns, 1000); /* seen when due */
    /* seq 2 would be due before seq 1: it waits for it */
    CHECK_EQ(rig_send(&r, 1, 500, 510), BUFFERS_ACCEPTED);
    CHECK_EQ(rig_send(&r, 2, 400, 520), BUFFERS_ACCEPTED);
    buffers_slot_advance(&r.slot, 1499);
    CHECK_EQ(rig_read(&r, 1).new_data, 0);
    buffers_slot_advance(&r.slot, 1500);
    rec = rig_read(&r, 1);
    CHECK_EQ(rec.seq, 2);
    CHECK_EQ(rec.recv_ns, 1500);
    CHECK_EQ(rec.dropped, 1);
    CHECK_EQ(rec.received, 2);
    /* a version due already when it arrives, nothing held: seen at its arrival */
    CHECK_EQ(rig_send(&r, 3, 600, 1700), BUFFERS_ACCEPTED);
    CHECK_EQ(r.slot.pend_count, 0);
    CHECK_EQ(rig_read(&r, 1).recv_ns, 1700);
    /* a stamp from the future holds it no longer than the delay from its arrival */
    CHECK_EQ(rig_send(&r, 4, INT64_MAX, 1800), BUFFERS_ACCEPTED);
    buffers_slot_advance(&r.slot, 2799);
    CHECK_EQ(rig_read(&r, 1).new_data, 0);
    buffers_slot_advance(&r.slot, 2800);
    CHECK_EQ(rig_read(&r, 1).seq, 4);
    for (int64_t k = 5; k < 9; k++) CHECK_EQ(rig_send(&r, k, 5000, 5001), BUFFERS_ACCEPTED);
    CHECK_EQ(r.slot.pend_count, 3);
    CHECK_EQ(r.slot.overflow, 1);
    buffers_slot_reset(&r.slot);
    CHECK_EQ(r.slot.pend_count, 0);
    CHECK_EQ(r.slot.overflow, 0);
}

/* A bandwidth-limited link: one transmitter for every buffer on it. A message takes its
 * bytes' time after the previous one's last byte, read here or not (unread: heard for the bus
 * only), in the order of their send stamps whatever the order the sockets were read in, and
 * before the latency; one that would wait longer than the queue is dropped, for the readers
 * here counted as lost. */
static void test_bus_queues_every_buffer_of_the_link(void)
{
    rig_t r, other;
    rig_init(&r);
    rig_init(&other);
    other.slot.buffer = 4;
    skel_heard_t heard[SKEL_BUS_HEARD];
    skel_bus_t bus = { .link = 1, .ns_per_byte = 10.0, .queue_ns = 500, .heard = heard };
    buffers_bus_reset(&bus);
    skel_plan_t plan = { .nbuses = 1, .buses = &bus };
    skel_pending_t ring[8];
    r.slot.pending = ring;
    r.slot.pend_cap = 8;
    r.slot.bus = &bus;
    r.slot.wire_extra = 4; /* 16 payload + 4: 200 ns a message */
    r.slot.tr.latency_ns = 1000;
    r.slot.tr.from_send = 1;
    other.slot.bus = &bus;
    other.slot.unread = 1;
    other.slot.wire_extra = 4;
    other.slot.tr.from_send = 1;
    buffers_slot_seed(&r.slot, 1, 2);
    /* our socket read first, the other's after: the other's message was sent first, so ours
     * waits for its 200 ns, then takes its own */
    wire_buffer_hdr_t h = { r.run_id, 9, 4, 0, 100, 16 };
    CHECK_EQ(rig_send(&r, 0, 150, 160), BUFFERS_ACCEPTED);
    CHECK_EQ(buffers_slot_receive(&other.slot, other.run_id, &h, NULL, 110), BUFFERS_ACCEPTED);
    CHECK_EQ(bus.nheard, 2);
    buffers_flush(&plan);
    CHECK_EQ(bus.nheard, 0);
    CHECK_EQ(bus.free_ns, 500);
    CHECK_EQ(other.slot.received, 0); /* heard, not kept */
    CHECK_EQ(other.slot.heard_seq, 0);
    buffers_slot_advance(&r.slot, 1499);
    CHECK_EQ(rig_read(&r, 1).new_data, 0);
    buffers_slot_advance(&r.slot, 1500); /* 500 on the bus, then the latency */
    CHECK_EQ(rig_read(&r, 1).recv_ns, 1500);
    /* an idle bus: its own time only */
    CHECK_EQ(rig_send(&r, 1, 2000, 2001), BUFFERS_ACCEPTED);
    buffers_flush(&plan);
    CHECK_EQ(bus.free_ns, 2200);
    /* a burst: the queue holds 500 ns of waiting, the next is dropped, for this reader lost */
    for (int64_t k = 1; k <= 3; k++) {
        h.seq = k;
        h.send_ns = 2200;
        CHECK_EQ(buffers_slot_receive(&other.slot, other.run_id, &h, NULL, 2201), BUFFERS_ACCEPTED);
    }
    CHECK_EQ(rig_send(&r, 2, 2200, 2202), BUFFERS_ACCEPTED); /* at the same instant: by buffer id, ours first */
    h.seq = 4;
    CHECK_EQ(buffers_slot_receive(&other.slot, other.run_id, &h, NULL, 2203), BUFFERS_ACCEPTED);
    buffers_flush(&plan);
    CHECK_EQ(bus.free_ns, 2800); /* ours, then two of the other's (waits 0, 200, 400); two waited 600 */
    CHECK_EQ(bus.dropped, 2);
    CHECK_EQ(r.slot.lost, 0);
    CHECK_EQ(other.slot.lost, 0); /* the unread one counts no loss */
    CHECK_EQ(other.slot.heard_seq, 4);
    /* now ours finds the queue full: it would wait 550 */
    CHECK_EQ(rig_send(&r, 3, 2250, 2251), BUFFERS_ACCEPTED);
    buffers_flush(&plan);
    CHECK_EQ(bus.dropped, 3);
    CHECK_EQ(r.slot.lost, 1);
    /* a stamp from long before its arrival starts at the arrival, whatever the bus's time */
    CHECK_EQ(rig_send(&r, 4, INT64_MIN + 1, 100 * SKEL_NS_PER_S), BUFFERS_ACCEPTED);
    buffers_flush(&plan);
    CHECK_EQ(bus.free_ns, 100 * SKEL_NS_PER_S + 200);
    buffers_bus_reset(&bus);
    CHECK_EQ(bus.dropped, 0);
}

/* A live switch carries what is held: into the new ring, or seen at once when the new link delays nothing. */
static void test_carry_held(void)
{
    rig_t old, with, without;
    rig_init(&old);
    rig_init(&with);
    rig_init(&without);
    skel_pending_t ring[4], ring2[4];
    old.slot.pending = ring;
    old.slot.pend_cap = 4;
    old.slot.tr.latency_ns = 1000;
    old.slot.tr.from_send = 1;
    CHECK_EQ(rig_send(&old, 0, 0, 10), BUFFERS_ACCEPTED);
    CHECK_EQ(rig_send(&old, 1, 100, 110), BUFFERS_ACCEPTED);
    with.slot.pending = ring2;
    with.slot.pend_cap = 4;
    buffers_slot_carry(&with.slot, &old.slot);
    CHECK_EQ(with.slot.pend_count, 2);
    CHECK_EQ(with.slot.dup_upto, 1);
    buffers_slot_advance(&with.slot, 1100);
    CHECK_EQ(rig_read(&with, 1).seq, 1);
    buffers_slot_carry(&without.slot, &old.slot);
    CHECK_EQ(without.slot.received, 2);
    CHECK_EQ(rig_read(&without, 1).seq, 1);
}

/* loss_pct 100: every version lost, none received; 0: none. */
static void test_emulated_loss(void)
{
    rig_t r;
    rig_init(&r);
    r.slot.tr.loss = 1.0;
    buffers_slot_seed(&r.slot, 1, 2);
    for (int64_t k = 0; k < 10; k++) CHECK_EQ(rig_write(&r, k), BUFFERS_ACCEPTED);
    CHECK_EQ(r.slot.lost, 10);
    CHECK_EQ(r.slot.received, 0);
    CHECK_EQ(rig_read(&r, 1).new_data, 0);
    r.slot.tr.loss = 0.0;
    r.slot.tr.enter = 0.5; /* bursts: a bad state that loses nothing loses nothing */
    r.slot.tr.leave = 0.5;
    for (int64_t k = 10; k < 20; k++) CHECK_EQ(rig_write(&r, k), BUFFERS_ACCEPTED);
    CHECK_EQ(r.slot.lost, 10);
    CHECK_EQ(rig_read(&r, 1).seq, 19);
}

/* A slot real code reads keeps the newest message's bytes (cut to the buffer's size); a
 * late, older message does not replace them. Real code may send fewer bytes than declared. */
static void test_slot_bytes(void)
{
    uint8_t kept[8], a[8] = { 1, 2, 3, 4, 5, 6, 7, 8 }, b[10] = { 9, 9, 9, 9, 9, 9, 9, 9, 9, 9 };
    skel_slot_t slot = { .buffer = 3, .writer = 4, .bytes = kept, .cap = 8 };
    buffers_slot_reset(&slot);
    wire_buffer_hdr_t h = { 1, 4, 3, 5, 0, 8 };
    CHECK_EQ(buffers_slot_receive(&slot, 1, &h, a, 0), BUFFERS_ACCEPTED);
    CHECK_EQ(slot.nbytes, 8);
    CHECK_EQ(memcmp(kept, a, 8), 0);
    h.seq = 4;
    CHECK_EQ(buffers_slot_receive(&slot, 1, &h, b, 0), BUFFERS_ACCEPTED);
    CHECK_EQ(memcmp(kept, a, 8), 0);
    h.seq = 6;
    h.nbytes = 10;
    CHECK_EQ(buffers_slot_receive(&slot, 1, &h, b, 0), BUFFERS_ACCEPTED);
    CHECK_EQ(slot.nbytes, 8);
    CHECK_EQ(kept[7], 9);

    skel_output_t out = { .buffer = 7, .bytes = 64 };
    out.enc_len = wire_buffer_encoded_size(64);
    uint8_t enc[200];
    out.enc = enc;
    int len = buffers_output_encode(&out, 5, 2, 11, 123456, a, 8);
    CHECK_EQ(len, wire_buffer_encoded_size(8));
    CHECK_EQ(wire_buffer_header(enc, len, &h), 0);
    CHECK_EQ(h.nbytes, 8);
    CHECK_EQ(memcmp(enc + SKEL_BUFFER_HEADER_BYTES, a, 8), 0);
}

int main(void)
{
    test_slot_bytes();
    test_stale_half();
    test_drop_half();
    test_loss_and_order();
    test_sequence_at_int64_max();
    test_foreign_and_mismatch();
    test_warmup_not_counted();
    test_output_encode();
    test_held_until_due_in_order();
    test_emulated_loss();
    test_carry_held();
    test_bus_queues_every_buffer_of_the_link();
    return CHECK_DONE();
}
