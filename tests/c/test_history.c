/* test_history.c: the published-batch history behind RESEND, over LCM's
 * in-process memq provider: a re-sent batch or report is byte for byte what was
 * published, batches the byte ring has overwritten are counted as gone, and a
 * RESEND for another run re-sends nothing. */
#include <stdlib.h>

#include "check.h"
#include "dpu.h"

#define MAX_HEARD 512

typedef struct {
    int n;
    char channel[MAX_HEARD][32];
    uint8_t *data[MAX_HEARD];
    int len[MAX_HEARD];
} heard_t;

static void on_message(const lcm_recv_buf_t *rbuf, const char *channel, void *user)
{
    heard_t *h = user;
    if (h->n >= MAX_HEARD) return;
    snprintf(h->channel[h->n], sizeof h->channel[h->n], "%s", channel);
    h->data[h->n] = malloc(rbuf->data_size);
    memcpy(h->data[h->n], rbuf->data, rbuf->data_size);
    h->len[h->n] = (int)rbuf->data_size;
    h->n++;
}

static void heard_clear(heard_t *h)
{
    for (int i = 0; i < h->n; i++) free(h->data[i]);
    h->n = 0;
}

static void pump(lcm_t *lcm)
{
    while (lcm_handle_timeout(lcm, 0) > 0) {
    }
}

/* Batch SEQ of RUN with N records whose cycles are seq*1000 + i. */
static void fill(skel_batch_t *b, int64_t run, int64_t seq, int n)
{
    timing_batch_clear(b);
    skel_rec_t rec;
    memset(&rec, 0, sizeof rec);
    for (int i = 0; i < n; i++) {
        rec.cycle = seq * 1000 + i;
        rec.ninputs = SKEL_MAX_IO;
        for (int q = 0; q < SKEL_MAX_IO; q++) rec.in[q].seq = seq + q;
        timing_batch_add(b, &rec);
    }
    b->msg.dpu = 3;
    b->msg.run_id = run;
    b->msg.batch_seq = seq;
}

static int64_t seq_of(const heard_t *h, int i)
{
    skelmsg_timing_t m;
    if (skelmsg_timing_t_decode(h->data[i], 0, h->len[i], &m) < 0) return -1;
    int64_t seq = m.batch_seq;
    int ok = m.n > 0 && m.cycle[m.n - 1] == seq * 1000 + m.n - 1;
    skelmsg_timing_t_decode_cleanup(&m);
    return ok ? seq : -2;
}

static void test_resend_is_what_was_published(lcm_t *lcm, heard_t *h, skel_batch_t *b)
{
    skel_history_t hist;
    CHECK_EQ(history_init(&hist, 1 << 20), 0);
    history_reset(&hist, 7);
    for (int64_t seq = 0; seq < 10; seq++) {
        fill(b, 7, seq, 4);
        CHECK_EQ(history_publish_batch(&hist, lcm, &b->msg), 0);
    }
    pump(lcm);
    CHECK_EQ(h->n, 10);
    uint8_t *third = malloc((size_t)h->len[3]);
    int third_len = h->len[3];
    memcpy(third, h->data[3], (size_t)third_len);
    heard_clear(h);

    int gone = -1;
    skel_resend_t ask = { 7, 2, 4, 0 };
    CHECK_EQ(history_resend(&hist, lcm, &ask, &gone), 3);
    CHECK_EQ(gone, 0);
    pump(lcm);
    CHECK_EQ(h->n, 3);
    CHECK_EQ(seq_of(h, 0), 2);
    CHECK_EQ(seq_of(h, 2), 4);
    CHECK(h->len[1] == third_len && memcmp(h->data[1], third, (size_t)third_len) == 0);
    heard_clear(h);
    free(third);

    /* Another run's batches, or seqs never published, are not re-sent. */
    ask = (skel_resend_t){ 8, 0, 9, 1 };
    CHECK_EQ(history_resend(&hist, lcm, &ask, &gone), 0);
    ask = (skel_resend_t){ 7, 9, 12, 0 };
    CHECK_EQ(history_resend(&hist, lcm, &ask, &gone), 1);
    CHECK_EQ(gone, 3);
    pump(lcm);
    heard_clear(h);

    /* The report: kept as published, re-sent on its own (an empty batch range). */
    skelmsg_report_t r;
    memset(&r, 0, sizeof r);
    r.dpu = 3;
    r.run_id = 7;
    r.timing_batches = 10;
    CHECK_EQ(history_publish_report(&hist, lcm, &r), 0);
    ask = (skel_resend_t){ 7, 0, -1, 1 };
    CHECK_EQ(history_resend(&hist, lcm, &ask, &gone), 1);
    pump(lcm);
    CHECK_EQ(h->n, 2);
    CHECK(strcmp(h->channel[1], SKEL_REPORT_CHANNEL) == 0);
    CHECK(h->len[0] == h->len[1] && memcmp(h->data[0], h->data[1], (size_t)h->len[0]) == 0);
    heard_clear(h);

    /* A new run forgets the old one's batches and report. */
    history_reset(&hist, 9);
    ask = (skel_resend_t){ 9, 0, 9, 1 };
    CHECK_EQ(history_resend(&hist, lcm, &ask, &gone), 0);
    CHECK_EQ(gone, 10);
    /* A range ending at INT64_MAX (anyone's RESEND): every seq up to it, none past it (the
     * loop's seq++ overflowed there; tests/fuzz/regressions/command/resend-int64-max). */
    ask = (skel_resend_t){ 9, INT64_MAX - 2, INT64_MAX, 0 };
    CHECK_EQ(history_resend(&hist, lcm, &ask, &gone), 0);
    CHECK_EQ(gone, 3);
    history_free(&hist);
}

/* Big batches wrap the byte ring: the oldest are gone, every survivor (one of
 * them straddling the ring's end) comes back intact. */
static void test_ring_wraps(lcm_t *lcm, heard_t *h, skel_batch_t *b)
{
    skel_history_t hist;
    CHECK_EQ(history_init(&hist, 1 << 20), 0);
    history_reset(&hist, 1);
    const int64_t total = 300;
    for (int64_t seq = 0; seq < total; seq++) {
        fill(b, 1, seq, SKEL_BATCH_RECORDS);
        CHECK_EQ(history_publish_batch(&hist, lcm, &b->msg), 0);
        pump(lcm);
        heard_clear(h);
    }
    int gone = 0;
    skel_resend_t ask = { 1, 0, total - 1, 0 };
    int sent = history_resend(&hist, lcm, &ask, &gone);
    CHECK(gone > 0 && sent > 0);
    CHECK_EQ(sent + gone, total);
    pump(lcm);
    CHECK_EQ(h->n, sent);
    int bad = 0;
    for (int i = 0; i < h->n; i++) bad += seq_of(h, i) != total - sent + i;
    CHECK_EQ(bad, 0);
    heard_clear(h);
    history_free(&hist);
}

/* More small batches than slots: the slot's newer batch is not the one asked for. */
static void test_slots_wrap(lcm_t *lcm, heard_t *h, skel_batch_t *b)
{
    skel_history_t hist;
    CHECK_EQ(history_init(&hist, 1 << 20), 0);
    history_reset(&hist, 2);
    for (int64_t seq = 0; seq < SKEL_HISTORY_BATCHES + 5; seq++) {
        fill(b, 2, seq, 1);
        CHECK_EQ(history_publish_batch(&hist, lcm, &b->msg), 0);
        pump(lcm);
        heard_clear(h);
    }
    int gone = 0;
    skel_resend_t ask = { 2, 0, 9, 0 };
    CHECK_EQ(history_resend(&hist, lcm, &ask, &gone), 5);
    CHECK_EQ(gone, 5);
    pump(lcm);
    CHECK_EQ(seq_of(h, 0), 5);
    heard_clear(h);
    history_free(&hist);
}

int main(void)
{
    lcm_t *lcm = lcm_create("memq://");
    CHECK(lcm != NULL);
    if (lcm == NULL) return CHECK_DONE();
    static heard_t heard;
    lcm_subscription_t *t = lcm_subscribe(lcm, SKEL_TIMING_CHANNEL, on_message, &heard);
    lcm_subscription_t *r = lcm_subscribe(lcm, SKEL_REPORT_CHANNEL, on_message, &heard);
    CHECK(t != NULL && r != NULL);
    CHECK_EQ(lcm_subscription_set_queue_capacity(t, 0), 0);
    CHECK_EQ(lcm_subscription_set_queue_capacity(r, 0), 0);
    skel_batch_t b;
    CHECK_EQ(timing_batch_init(&b), 0);
    test_resend_is_what_was_published(lcm, &heard, &b);
    test_ring_wraps(lcm, &heard, &b);
    test_slots_wrap(lcm, &heard, &b);
    timing_batch_free(&b);
    lcm_destroy(lcm);
    return CHECK_DONE();
}
