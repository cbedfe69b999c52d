/* test_timing.c: the SPSC timing ring (full ring counts lost, order kept, a
 * real producer/consumer pair) and the timing_t batch it feeds. */
#include <pthread.h>
#include <stdlib.h>

#include "check.h"
#include "dpu.h"

static void test_ring_basic(void)
{
    skel_ring_t ring;
    CHECK(timing_ring_init(&ring, 6) != 0); /* not a power of two */
    CHECK_EQ(timing_ring_init(&ring, 8), 0);
    skel_rec_t rec, out;
    memset(&rec, 0, sizeof rec);
    CHECK_EQ(timing_ring_pop(&ring, &out), 0);
    for (int i = 0; i < 8; i++) {
        rec.cycle = i;
        CHECK_EQ(timing_ring_push(&ring, &rec), 0);
    }
    rec.cycle = 99;
    CHECK(timing_ring_push(&ring, &rec) != 0);
    CHECK_EQ(atomic_load(&ring.lost), 1);
    for (int i = 0; i < 8; i++) {
        CHECK_EQ(timing_ring_pop(&ring, &out), 1);
        CHECK_EQ(out.cycle, i);
    }
    CHECK_EQ(timing_ring_pop(&ring, &out), 0);
    /* Wrap-around many times. */
    int ok = 1;
    for (int i = 0; i < 1000; i++) {
        rec.cycle = i;
        ok &= timing_ring_push(&ring, &rec) == 0;
        ok &= timing_ring_pop(&ring, &out) == 1 && out.cycle == i;
    }
    CHECK(ok);
    timing_ring_free(&ring);
}

typedef struct {
    skel_ring_t ring;
    int n;
} pc_t;

static void *producer(void *arg)
{
    pc_t *pc = arg;
    skel_rec_t rec;
    memset(&rec, 0, sizeof rec);
    for (int i = 0; i < pc->n; i++) {
        rec.cycle = i;
        rec.in[SKEL_MAX_IO - 1].seq = i; /* the whole record travels, not just its head */
        (void)timing_ring_push(&pc->ring, &rec);
    }
    return NULL;
}

static void test_ring_threads(void)
{
    pc_t pc = { .n = 200000 };
    CHECK_EQ(timing_ring_init(&pc.ring, 64), 0);
    pthread_t t;
    CHECK_EQ(pthread_create(&t, NULL, producer, &pc), 0);
    int64_t popped = 0, last = -1, bad = 0;
    skel_rec_t out;
    for (;;) {
        if (timing_ring_pop(&pc.ring, &out) == 1) {
            bad += out.cycle <= last || out.in[SKEL_MAX_IO - 1].seq != out.cycle;
            last = out.cycle;
            popped++;
            if (last == pc.n - 1) break;
            continue;
        }
        if (popped + atomic_load(&pc.ring.lost) == pc.n) break;
    }
    pthread_join(t, NULL);
    while (timing_ring_pop(&pc.ring, &out) == 1) popped++;
    CHECK_EQ(bad, 0);
    CHECK_EQ(popped + atomic_load(&pc.ring.lost), pc.n);
    timing_ring_free(&pc.ring);
}

static void test_batch(void)
{
    skel_batch_t b;
    CHECK_EQ(timing_batch_init(&b), 0);
    skel_rec_t rec;
    memset(&rec, 0, sizeof rec);
    for (int i = 0; i < SKEL_BATCH_RECORDS; i++) {
        CHECK(!timing_batch_full(&b));
        rec.process = (int16_t)(i % 3);
        rec.cycle = i;
        rec.slack_ns = -i;
        rec.flags = (int8_t)(i & 7);
        rec.ninputs = (int8_t)(i % 3 == 0 ? SKEL_MAX_IO : 1);
        for (int q = 0; q < rec.ninputs; q++) {
            rec.in[q].buffer = (int16_t)q;
            rec.in[q].seq = i * 100 + q;
            rec.in[q].dropped = q;
        }
        timing_batch_add(&b, &rec);
    }
    CHECK(timing_batch_full(&b));
    CHECK_EQ(b.msg.n, SKEL_BATCH_RECORDS);
    CHECK_EQ(b.msg.cycle[10], 10);
    CHECK_EQ(b.msg.slack_ns[10], -10);
    CHECK_EQ(b.msg.flags[13], 5);
    int bad = 0;
    for (int w = 0; w < b.msg.ninputs; w++) {
        int r = b.msg.in_record[w];
        bad += b.msg.in_seq[w] != r * 100 + b.msg.in_buffer[w];
    }
    CHECK_EQ(bad, 0);
    /* The batch encodes as a valid timing_t. */
    int len = skelmsg_timing_t_encoded_size(&b.msg);
    uint8_t *enc = malloc((size_t)len);
    CHECK_EQ(skelmsg_timing_t_encode(enc, 0, len, &b.msg), len);
    free(enc);
    timing_batch_clear(&b);
    CHECK_EQ(b.msg.n, 0);
    CHECK_EQ(b.msg.ninputs, 0);
    timing_batch_free(&b);
}

int main(void)
{
    test_ring_basic();
    test_ring_threads();
    test_batch();
    return CHECK_DONE();
}
