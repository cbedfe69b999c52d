/* event.c: processes that await an external event (sync: event, the paper's
 * ext_event_sync), and the events themselves. An event is a message on its own
 * channel of the control URL (SKEL_EVENT_<name>): the host sends it (`skel
 * event`), a process fires it at the end of its cycle (emits:), or a DPU
 * generates it during the run (the system file's events:, every draw from
 * run.seed, so a run repeats exactly).
 *
 * A DPU subscribes to the events its processes await on one more link (the
 * control URL), drained by the executive thread like any buffer: an arrival,
 * stamped with the kernel's receive time, goes into each awaiting process's
 * queue. `queue: 1` keeps only the newest (the one it replaces is dropped);
 * `queue: N` keeps up to N, and drops the ones that find it full. The rule is
 * applied by the stamps, not by when the executive drained them: arrivals
 * wait in their order until a release looks at the queue, and join it then
 * up to the release's instant (event_settle), so a burst drained late in one
 * go keeps the events it would have kept had each been seen when it came. The process's
 * period is the least time between two of its cycles: the cyclic executive
 * looks at the queue at its place in the frame, the tasking one releases a job
 * at the event (or a period after the last one, when events come faster).
 *
 * Generators run in a thread of their own per run: they only sleep and publish,
 * so they take nothing from the executive's processor. */
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <time.h>

#include "dpu.h"

/* An event_t of NAME, encoded: fingerprint and fixed fields (contract.txt), then the name as
 * LCM writes a string: its int32 length, its bytes and a NUL. */
static int event_enc_cap(const char *name)
{
    return SKEL_EVENT_HEADER_BYTES + 4 + (int)strlen(name) + 1;
}

/* Index of NAME in plan->events, added when new; -1 when the table is full. */
static int event_index(skel_plan_t *plan, const char *name)
{
    for (int i = 0; i < plan->nevents; i++)
        if (strcmp(plan->events[i].name, name) == 0) return i;
    if (plan->nevents >= SKEL_MAX_EVENTS) return -1;
    skel_event_t *e = &plan->events[plan->nevents];
    size_t n = strlen(SKEL_EVENT_CHANNEL_PREFIX) + strlen(name) + 1;
    e->name = strdup(name);
    e->channel = malloc(n);
    e->enc_cap = event_enc_cap(name);
    e->enc = malloc((size_t)e->enc_cap);
    e->plan = plan;
    if (e->name == NULL || e->channel == NULL || e->enc == NULL) return -1;
    snprintf(e->channel, n, "%s%s", SKEL_EVENT_CHANNEL_PREFIX, name);
    return plan->nevents++;
}

/* What process P (configured as SRC) awaits and emits. */
int event_add_process(skel_plan_t *plan, skel_process_t *p, const skelmsg_process_t *src)
{
    p->event = -1;
    if (src->sync == SKELMSG_PROCESS_T_SYNC_EVENT) {
        p->event = (int16_t)event_index(plan, src->event);
        if (p->event < 0) return -1;
        plan->events[p->event].awaited = 1;
        plan->awaits_events = 1;
        p->queue.cap = src->queue;
    }
    p->nemits = src->nemits;
    for (int e = 0; e < src->nemits; e++)
        if ((p->emits[e] = (int16_t)event_index(plan, src->emits[e])) < 0) return -1;
    return 0;
}

/* The generators DPU runs (the config's events: with dpu: it). */
int event_add_sources(skel_plan_t *plan, const skelmsg_config_t *cfg, int16_t dpu)
{
    for (int i = 0; i < cfg->nevents; i++) {
        const skelmsg_event_source_t *src = &cfg->events[i];
        if (src->kind == SKELMSG_EVENT_SOURCE_T_KIND_HOST || src->dpu != dpu) continue;
        skel_source_t *g = &plan->sources[plan->nsources];
        g->kind = src->kind;
        g->event = event_index(plan, src->name);
        g->period_ns = (int64_t)src->period_us * SKEL_NS_PER_US;
        g->jitter_ns = (int64_t)src->jitter_us * SKEL_NS_PER_US;
        g->spacing_ns = (int64_t)src->spacing_us * SKEL_NS_PER_US;
        g->rate_hz = src->rate_hz;
        g->count = src->count;
        g->enc_cap = event_enc_cap(src->name);
        g->enc = malloc((size_t)g->enc_cap);
        if (g->event < 0 || g->enc == NULL) return -1;
        plan->nsources++;
    }
    return 0;
}

/* The event that arrived AT joins P's queue by its rule. */
static void event_queue(skel_plan_t *plan, skel_process_t *p, int64_t at)
{
    skel_queue_t *q = &p->queue;
    int full = q->count >= q->cap;
    if (full && q->cap > 1) { /* N pending: the newcomer is dropped */
        q->dropped++;
        if (at >= plan->measure_from_ns) p->sums.events_dropped++;
        return;
    }
    if (full) { /* only the newest counts: it replaces the one waiting */
        q->dropped++;
        if (q->queued_ns[q->head] >= plan->measure_from_ns) p->sums.events_dropped++;
        q->queued_ns[q->head] = at;
        return;
    }
    q->queued_ns[(q->head + q->count) % SKEL_MAX_QUEUE] = at;
    q->count++;
}

void event_settle(skel_plan_t *plan, skel_process_t *p, int64_t upto)
{
    skel_queue_t *q = &p->queue;
    while (q->a_count > 0 && q->arrived_ns[q->a_head] <= upto) {
        event_queue(plan, p, q->arrived_ns[q->a_head]);
        q->a_head = (q->a_head + 1) % SKEL_MAX_QUEUE;
        q->a_count--;
    }
}

/* An event_t received on E's channel: checked, its header read in place, and during
 * its run queued for every process awaiting it. Apart from the subscription, so the
 * fuzzer (tests/fuzz/fuzz_event.c) drives exactly this with the bytes it makes. */
void event_receive(skel_event_t *e, const lcm_recv_buf_t *rbuf)
{
    skel_plan_t *plan = e->plan;
    wire_event_hdr_t hdr;
    if (rbuf->data_size > (uint32_t)SKEL_MAX_BUFFER_BYTES ||
        wire_event_header(rbuf->data, (int)rbuf->data_size, &hdr) != 0) {
        atomic_fetch_add(plan->rejected, 1);
        return;
    }
    if (!plan->running || (hdr.run_id != 0 && hdr.run_id != plan->run_id)) return;
    const int64_t at = link_arrival_ns(&plan->links[plan->event_link], rbuf);
    const int index = (int)(e - plan->events);
    for (int i = 0; i < plan->nprocesses; i++) {
        skel_process_t *p = &plan->processes[i];
        if (p->event != index) continue;
        skel_queue_t *q = &p->queue;
        if (q->a_count == SKEL_MAX_QUEUE) event_settle(plan, p, q->arrived_ns[q->a_head]); /* bounded */
        q->arrived_ns[(q->a_head + q->a_count) % SKEL_MAX_QUEUE] = at;
        q->a_count++;
    }
}

static void event_on_message(const lcm_recv_buf_t *rbuf, const char *channel, void *user)
{
    skel_event_t *e = user;
    if (strcmp(channel, e->channel) != 0) return;
    event_receive(e, rbuf);
}

/* The network side: the control URL joins the plan's links when an event is awaited
 * or emitted here, and the generators get an lcm_t of their own (another thread). What
 * this DPU sends goes to the record URL too, for the log (contract: RECORD_OFFSET); each
 * sending thread has its lcm_t there, so neither waits on the other's lock. */
int event_open(skel_plan_t *plan, const char *control_url, const char *record_url)
{
    int emits = 0;
    for (int i = 0; i < plan->nprocesses; i++) emits |= plan->processes[i].nemits > 0;
    if (emits && (plan->emit_rec = clock_open(record_url)) == NULL) return -1;
    if (plan->awaits_events || emits) {
        for (int i = 0; i < plan->nlinks && plan->event_link < 0; i++)
            if (strcmp(plan->links[i].url, control_url) == 0) plan->event_link = i;
        if (plan->event_link < 0) {
            if (plan->nlinks >= SKEL_MAX_LINKS) return -1;
            skel_link_t *l = &plan->links[plan->nlinks];
            l->url = strdup(control_url);
            l->fd = -1;
            if (l->url == NULL || link_open(l) != 0) {
                link_close(l); /* not counted in nlinks: plan_free would not free it */
                return -1;
            }
            plan->event_link = plan->nlinks++;
        }
        for (int i = 0; i < plan->nevents; i++)
            if (plan->events[i].awaited &&
                link_subscribe_channel(&plan->links[plan->event_link], plan->events[i].channel,
                                       event_on_message, &plan->events[i]) != 0)
                return -1;
    }
    if (plan->nsources > 0 && ((plan->gen_lcm = clock_open(control_url)) == NULL ||
                               (plan->gen_rec = clock_open(record_url)) == NULL))
        return -1;
    return 0;
}

void event_free(skel_plan_t *plan)
{
    event_generators_stop(plan);
    if (plan->gen_lcm != NULL) clock_close(plan->gen_lcm);
    if (plan->gen_rec != NULL) clock_close(plan->gen_rec);
    if (plan->emit_rec != NULL) clock_close(plan->emit_rec);
    for (int i = 0; i < plan->nevents; i++) {
        free(plan->events[i].name);
        free(plan->events[i].channel);
        free(plan->events[i].enc);
    }
    for (int i = 0; i < plan->nsources; i++) free(plan->sources[i].enc);
}

/* P holds no event, none waits. */
static void event_clear(skel_process_t *p)
{
    skel_queue_t *q = &p->queue;
    q->head = q->count = 0;
    q->a_head = q->a_count = 0;
    q->dropped = 0;
    q->taken_ns = -1;
}

void event_reset_run(skel_plan_t *plan)
{
    for (int i = 0; i < plan->nprocesses; i++) event_clear(&plan->processes[i]);
    for (int i = 0; i < plan->nevents; i++) plan->events[i].seq = 0;
    for (int i = 0; i < plan->nsources; i++)
        draw_seed_state(plan->sources[i].state, plan->seed, 0x8000u | (uint64_t)i);
}

int event_pending(const skel_process_t *p)
{
    const skel_queue_t *q = &p->queue;
    return q->count + q->a_count > 0;
}

int64_t event_oldest_ns(const skel_process_t *p)
{
    const skel_queue_t *q = &p->queue;
    return q->count > 0 ? q->queued_ns[q->head] : q->a_count > 0 ? q->arrived_ns[q->a_head] : INT64_MAX;
}

/* The oldest waiting event becomes the next cycle's (P's next_k-th): its record
 * gets the arrival, what still waits and what was dropped since the last cycle.
 * An event process's cycles are counted as they come, so its measured window
 * starts at its first cycle released inside the DPU's. */
static void event_take(skel_process_t *p)
{
    skel_queue_t *q = &p->queue;
    q->taken_ns = q->queued_ns[q->head];
    q->head = (q->head + 1) % SKEL_MAX_QUEUE;
    q->count--;
    q->taken_left = (int16_t)q->count;
    q->taken_dropped = q->dropped;
    q->dropped = 0;
}

/* The first measured cycle of event process P (its cycle index, as the executives
 * compare it), once its release RELEASE is in the window. */
static void event_window(const skel_plan_t *plan, skel_process_t *p, int64_t release)
{
    if (p->measure_from_k == INT64_MAX && release >= plan->measure_from_ns)
        p->measure_from_k = p->k_base + p->next_k;
}

static int event_encode(skel_event_t *e, uint8_t *enc, int cap, int64_t run_id, int16_t dpu,
                        int16_t process, int64_t seq, int64_t sent_ns)
{
    skelmsg_event_t msg = { .run_id = run_id, .dpu = dpu, .process = process, .seq = seq,
                            .sent_ns = sent_ns, .name = e->name };
    return skelmsg_event_t_encode(enc, 0, cap, &msg);
}

/* P's cycle ended: it fires each event it emits (the executive thread's lcm_t), and
 * sends the log its copy. */
void event_emit(skel_plan_t *plan, const skel_process_t *p, int64_t now_ns)
{
    for (int i = 0; i < p->nemits; i++) {
        skel_event_t *e = &plan->events[p->emits[i]];
        int len = event_encode(e, e->enc, e->enc_cap, plan->run_id, plan->dpu, p->id, e->seq++, now_ns);
        if ((len < 0 || clock_publish(plan->links[plan->event_link].lcm, e->channel, e->enc, (unsigned)len) != 0 ||
             clock_publish(plan->emit_rec, e->channel, e->enc, (unsigned)len) != 0)
            && plan->publish_errors++ == 0)
            log_line("DPU %d: process %d cannot publish event %s", plan->dpu, p->id, e->name);
    }
}

/* ---- generators ---------------------------------------------------------------- */

/* G's next instant after its K-th event (K from 0), from the run's first release T0:
 * periodic every period, each moved by a uniform draw in +-jitter; Poisson with
 * exponential gaps; bursts of `count` events `spacing` apart every period. */
static int64_t event_source_next(skel_source_t *g, int64_t t0, int64_t prev)
{
    switch (g->kind) {
    case SKELMSG_EVENT_SOURCE_T_KIND_PERIODIC: {
        double u = draw_unit(g->state);
        return t0 + (g->k + 1) * g->period_ns + (int64_t)((2.0 * u - 1.0) * (double)g->jitter_ns);
    }
    case SKELMSG_EVENT_SOURCE_T_KIND_POISSON: {
        double gap = -log1p(-draw_unit(g->state)) / g->rate_hz;
        return prev + (int64_t)(gap * (double)SKEL_NS_PER_S);
    }
    default: /* BURSTS */
        return t0 + (g->k / g->count + 1) * g->period_ns + (g->k % g->count) * g->spacing_ns;
    }
}

static void *event_generate(void *arg)
{
    skel_plan_t *plan = arg;
    (void)pthread_setname_np(pthread_self(), "skel-events");
    for (;;) {
        skel_source_t *g = NULL;
        for (int i = 0; i < plan->nsources; i++)
            if (g == NULL || plan->sources[i].next_ns < g->next_ns) g = &plan->sources[i];
        if (g == NULL || g->next_ns >= plan->gen_end_ns) break;
        if (clock_sleep_until(g->next_ns, &plan->gen_stop) != 0) break;
        skel_event_t *e = &plan->events[g->event];
        int len = event_encode(e, g->enc, g->enc_cap, plan->run_id, plan->dpu, 0, g->k,
                               g->next_ns + plan->clock_offset_ns);
        if (len < 0 || clock_publish(plan->gen_lcm, e->channel, g->enc, (unsigned)len) != 0 ||
            clock_publish(plan->gen_rec, e->channel, g->enc, (unsigned)len) != 0)
            log_line("DPU %d: cannot publish generated event %s", plan->dpu, e->name);
        g->k++;
        g->next_ns = event_source_next(g, plan->run_t0_ns, g->next_ns);
    }
    return NULL;
}

/* G's first instant at or after FROM, in a run whose first release was T0. */
static void event_source_begin(skel_source_t *g, int64_t t0, int64_t from)
{
    g->k = 0;
    if (g->kind != SKELMSG_EVENT_SOURCE_T_KIND_POISSON && from > t0) /* on the grid: skip whole periods */
        g->k = (from - t0) / g->period_ns * (g->kind == SKELMSG_EVENT_SOURCE_T_KIND_BURSTS ? g->count : 1);
    g->next_ns = event_source_next(g, t0, from);
}

/* A live switch, after the executive's carry (swap.c, swap_carry_events): event process
 * P of the next plan keeps the events waiting for the same process O of the old one (NULL:
 * new here) and counts on from its cycles. Only read from O. */
void event_carry_process(skel_process_t *p, const skel_process_t *o)
{
    event_clear(p);
    if (p->event < 0) return; /* the executive's own carry counts its releases */
    p->next_k = 0;
    if (o == NULL || o->event < 0) { /* a new event process: counts from here */
        p->k_base = 0;
        p->measure_from_k = INT64_MAX;
        return;
    }
    p->k_base = o->k_base + o->next_k;
    p->measure_from_k = o->measure_from_k;
    /* a tasking job released for an event and carried over keeps it */
    skel_queue_t *q = &p->queue;
    const skel_queue_t *oq = &o->queue;
    q->taken_ns = oq->taken_ns;
    q->taken_left = oq->taken_left;
    q->taken_dropped = oq->taken_dropped;
    for (int n = 0; n < oq->count && q->count < q->cap; n++)
        q->queued_ns[q->count++] = oq->queued_ns[(oq->head + n) % SKEL_MAX_QUEUE];
    q->dropped = oq->dropped;
    for (int n = 0; n < oq->a_count; n++)
        q->arrived_ns[q->a_count++] = oq->arrived_ns[(oq->a_head + n) % SKEL_MAX_QUEUE];
}

/* A live switch at T_SW: NEXT's events count their seq afresh; a generator of the same
 * event, kind and parameters as one of OLD goes on with its draws, another starts at T_SW.
 * Only read from OLD. */
void event_carry_sources(skel_plan_t *next, const skel_plan_t *old, int64_t t_sw)
{
    for (int i = 0; i < next->nevents; i++) next->events[i].seq = 0;
    for (int i = 0; i < next->nsources; i++) {
        skel_source_t *g = &next->sources[i];
        const skel_source_t *same = NULL;
        for (int o = 0; o < old->nsources && same == NULL; o++) {
            const skel_source_t *h = &old->sources[o];
            if (strcmp(old->events[h->event].name, next->events[g->event].name) == 0 && h->kind == g->kind &&
                h->period_ns == g->period_ns && h->jitter_ns == g->jitter_ns && h->rate_hz == g->rate_hz &&
                h->count == g->count && h->spacing_ns == g->spacing_ns)
                same = h;
        }
        if (same != NULL) {
            memcpy(g->state, same->state, sizeof g->state);
            g->k = same->k;
            g->next_ns = same->next_ns;
        } else {
            draw_seed_state(g->state, next->seed, 0x8000u | (uint64_t)i);
            event_source_begin(g, next->run_t0_ns, t_sw);
        }
    }
}

/* The run's generators: each source's first instant from the run's first release T0. */
void event_generators_begin(skel_plan_t *plan, int64_t t0)
{
    for (int i = 0; i < plan->nsources; i++) event_source_begin(&plan->sources[i], t0, t0);
}

/* The generators' thread, publishing until END. */
int event_generators_start(skel_plan_t *plan, int64_t end)
{
    if (plan->nsources == 0) return 0;
    plan->gen_end_ns = end;
    atomic_store(&plan->gen_stop, 0);
    if (clock_thread_start(&plan->gen_thread, event_generate, plan) != 0) {
        log_line("DPU %d: cannot start the event generators' thread: no generated events", plan->dpu);
        return -1;
    }
    plan->gen_started = 1;
    return 0;
}

void event_generators_stop(skel_plan_t *plan)
{
    if (!plan->gen_started) return;
    atomic_store(&plan->gen_stop, 1);
    if (clock_thread_join(&plan->gen_thread) != 0) log_line("DPU %d: cannot join the event thread", plan->dpu);
    plan->gen_started = 0;
}

/* Used by both executives when an event process's cycle is released at RELEASE
 * (not before its oldest event): what arrived by then joins its queue, it takes one. */
void event_release(skel_plan_t *plan, skel_process_t *p, int64_t release)
{
    event_settle(plan, p, release);
    event_take(p);
    event_window(plan, p, release);
}
