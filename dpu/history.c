/* history.c: the current run's timing batches and report, kept as published,
 * so the host can ask for those the logger missed (command RESEND). lcm-logger
 * subscribes with LCM's default queue of 30 messages and drops the newest when
 * its process falls behind: on a busy machine that punches holes in the log
 * that no reader can fill. The batches live in one byte ring allocated at
 * start-up; the oldest are overwritten, which is why the host repairs the log
 * while the run goes on and not only at its end. */
#include <stdlib.h>
#include <string.h>

#include "dpu.h"

int history_init(skel_history_t *h, int batch_bytes)
{
    memset(h, 0, sizeof *h);
    h->bytes = malloc(SKEL_HISTORY_BYTES);
    h->held = calloc(SKEL_HISTORY_BATCHES, sizeof *h->held);
    h->enc = malloc((size_t)batch_bytes);
    h->enc_cap = batch_bytes;
    h->run_id = -1;
    if (h->bytes == NULL || h->held == NULL || h->enc == NULL) {
        history_free(h);
        return -1;
    }
    for (int i = 0; i < SKEL_HISTORY_BATCHES; i++) h->held[i].seq = -1;
    return 0;
}

void history_free(skel_history_t *h)
{
    free(h->bytes);
    free(h->held);
    free(h->enc);
    free(h->report);
    memset(h, 0, sizeof *h);
}

void history_reset(skel_history_t *h, int64_t run_id)
{
    for (int i = 0; i < SKEL_HISTORY_BATCHES; i++) h->held[i].seq = -1;
    h->run_id = run_id;
    h->report_len = 0;
}

/* Copies LEN bytes between the ring (stream offset AT) and FLAT, either way. */
static void history_copy(skel_history_t *h, uint64_t at, uint8_t *flat, uint32_t len, int into_ring)
{
    uint64_t off = at % SKEL_HISTORY_BYTES;
    uint64_t first = SKEL_HISTORY_BYTES - off < len ? SKEL_HISTORY_BYTES - off : len;
    if (into_ring) {
        memcpy(h->bytes + off, flat, first);
        memcpy(h->bytes, flat + first, len - first);
    } else {
        memcpy(flat, h->bytes + off, first);
        memcpy(flat + first, h->bytes, len - first);
    }
}

int history_publish_batch(skel_history_t *h, lcm_t *lcm, const skelmsg_timing_t *msg)
{
    int len = skelmsg_timing_t_encode(h->enc, 0, h->enc_cap, msg);
    if (len < 0) return -1;
    int rc = seal_publish(h->seal, lcm, SKEL_TIMING_CHANNEL, h->enc, len);
    if (msg->run_id == h->run_id && msg->batch_seq >= 0) {
        skel_held_t *slot = &h->held[msg->batch_seq % SKEL_HISTORY_BATCHES];
        history_copy(h, h->head, h->enc, (uint32_t)len, 1);
        *slot = (skel_held_t){ msg->batch_seq, h->head, (uint32_t)len };
        h->head += (uint64_t)len;
    }
    return rc;
}

int history_publish_report(skel_history_t *h, lcm_t *lcm, const skelmsg_report_t *r)
{
    int len = skelmsg_report_t_encoded_size(r);
    if (len > h->report_cap) {
        uint8_t *grown = realloc(h->report, (size_t)len);
        if (grown == NULL) return -1;
        h->report = grown;
        h->report_cap = len;
    }
    if (skelmsg_report_t_encode(h->report, 0, h->report_cap, r) != len) return -1;
    h->report_len = r->run_id == h->run_id ? len : 0;
    return seal_publish(h->seal, lcm, SKEL_REPORT_CHANNEL, h->report, len);
}

/* A batch is still held when its slot names it and the ring has not wrapped over it. */
static const skel_held_t *history_find(const skel_history_t *h, int64_t seq)
{
    const skel_held_t *slot = &h->held[seq % SKEL_HISTORY_BATCHES];
    if (slot->seq != seq || h->head - slot->at > SKEL_HISTORY_BYTES) return NULL;
    return slot;
}

int history_resend(skel_history_t *h, lcm_t *lcm, const skel_resend_t *ask, int *gone)
{
    *gone = 0;
    if (ask->run_id != h->run_id) return 0;
    /* One ask re-sends at most a ring's worth: the host paces bigger repairs. */
    int64_t to = ask->from < 0 || ask->to < ask->from ? -1
                 : ask->to - ask->from >= SKEL_HISTORY_BATCHES ? ask->from + SKEL_HISTORY_BATCHES - 1
                 : ask->to;
    int sent = 0;
    /* Up to TO inclusive, and never past it: TO may be INT64_MAX, where seq++ would overflow. */
    for (int64_t seq = ask->from; seq >= 0 && seq <= to; seq = seq < to ? seq + 1 : -1) {
        const skel_held_t *held = history_find(h, seq);
        if (held == NULL || held->len > (uint32_t)h->enc_cap) {
            ++*gone;
            continue;
        }
        history_copy(h, held->at, h->enc, held->len, 0);
        if (seal_publish(h->seal, lcm, SKEL_TIMING_CHANNEL, h->enc, (int)held->len) == 0) sent++;
    }
    if (ask->with_report && h->report_len > 0 &&
        seal_publish(h->seal, lcm, SKEL_REPORT_CHANNEL, h->report, h->report_len) == 0)
        sent++;
    return sent;
}
