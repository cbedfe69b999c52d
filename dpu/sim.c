/* sim.c: every DPU of a system on virtual time, in one process (`skel-dpu --simulate`).
 *
 * The executives, the control rounds, the config and command handling are the DPU's
 * own code; only what clock.c reaches changes: the clock reads virtual time, a sleep
 * moves it, a message is delivered by this file, a thread is a fiber. It is a
 * sequential discrete-event simulation: one queue of events (a fiber's wake-up, a
 * message's arrival, a host message of the input, a control round), taken in order of
 * time and then of insertion, so that no DPU ever runs past the earliest pending event
 * of another, and the same input gives the same output, byte for byte.
 *
 * A fiber (ucontext) runs until it waits: it never takes virtual time while it runs,
 * so every step but a sleep, a computation or a wait is instantaneous, and nothing
 * stalls it. A buffer published at t arrives at t (a link's emulated delay and loss are
 * the reading DPU's own, buffers.c, as on the machine). The
 * fibers are switched on one thread: a handover between two DPUs costs 0.2-0.5 us so, and
 * 2.3-3.2 us between two threads (bench/switch.c, `make bench`, 2026-12-02): ten minutes
 * of SERVO are 2.8 million events, which threads alone would take 15 s of handovers for,
 * short of the goal of 100 times real time (fibers: 2.5 s in all).
 *
 * The input is an LCM log the host tool writes: the configs and commands it would
 * publish, each at its virtual UTC instant. The output is the log the run's logger
 * would have written: those, and everything the DPUs publish on the record URL, each
 * stamped with the virtual instant it was published. */
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <ucontext.h>
#include <unistd.h>

#include <lcm/eventlog.h>

#include "dpu.h"

#if defined(__SANITIZE_ADDRESS__)
#include <sanitizer/common_interface_defs.h>
#define SIM_ASAN 1
#else
#define SIM_ASAN 0
#endif

#define SIM_STACK_BYTES (512 * 1024)
#define SIM_T0_NS       SKEL_NS_PER_S /* the virtual monotonic clock at the input's first message */
#define SIM_ROUND_NS    (10 * 1000 * 1000LL) /* the control thread polls at least this often */

enum { FIBER_FREE = 0, FIBER_ASLEEP, FIBER_WAITING, FIBER_JOINING, FIBER_DONE };
enum { EV_WAKE, EV_ARRIVE, EV_INPUT, EV_ROUND };

typedef struct {
    ucontext_t uc;
    void *stack;
    void *(*fn)(void *);
    void *arg;
    int dpu;                   /* index into sim->dpus */
    int state;
    int run;                   /* the DPU's executive for a run (not a generator) */
    uint64_t gen;              /* a wake-up of an older gen is stale */
    int woke_by_message;
    lcm_t *const *watch;       /* FIBER_WAITING: the lcm_t whose messages wake it */
    int nwatch;
    int joiner;                /* the fiber waiting for this one to end, -1: none */
    void *fake_stack;          /* ASan's, while switched out */
} sim_fiber_t;

typedef struct {
    uint8_t *bytes;
    int len, refs;
} sim_msg_t;

typedef struct {
    sim_msg_t *msg;
    int sub;
    int64_t at;                /* when it arrived: its receive stamp */
} sim_delivery_t;

typedef struct {
    lcm_t *lcm;                /* NULL: a free slot */
    int dpu;
    int url;                   /* index into sim->urls */
    sim_delivery_t *inbox;     /* arrived, not handled yet: a ring */
    int head, count, cap;
} sim_endpoint_t;

typedef struct {
    int endpoint;              /* -1: gone with its lcm_t */
    int url;
    char *channel;
    lcm_msg_handler_t handler;
    void *user;
} sim_sub_t;

typedef struct {
    int64_t t;
    uint64_t seq;
    int kind, a;
    uint64_t gen;
    void *p;
} sim_event_t;

typedef struct {
    skel_server_t s;
    skel_control_t c;
    int run_fiber;             /* -1: no run in progress */
} sim_dpu_t;

typedef struct {
    int64_t now, utc_offset_ns;
    uint64_t seq;
    sim_event_t *heap;
    int nheap, capheap;
    sim_fiber_t *fibers;
    int nfibers, capfibers, current, alive;
    sim_endpoint_t *endpoints;
    int nendpoints, capendpoints;
    sim_sub_t *subs;
    int nsubs, capsubs;
    char **urls;
    int nurls, capurls, record_url;
    sim_dpu_t *dpus;
    int ndpus, cur_dpu;
    lcm_eventlog_t *in, *out;
    int inputs_left, failed;
    int64_t events, deliveries;
    ucontext_t main_uc;
    void *main_fake;
    const void *main_bottom;
    size_t main_size;
} sim_t;

static void *sim_grow(void *p, int *cap, int need, size_t size)
{
    if (need <= *cap && p != NULL) return p;
    int n = *cap > 0 ? *cap : 16;
    while (n < need) n *= 2;
    void *q = realloc(p, (size_t)n * size);
    if (q == NULL) {
        fprintf(stderr, "skel-dpu: simulation: out of memory\n");
        exit(SKEL_EXIT_FAILED);
    }
    *cap = n;
    return q;
}

/* ---- the event queue: a binary heap on (t, seq) ----------------------------------- */

static int sim_before(const sim_event_t *a, const sim_event_t *b)
{
    return a->t < b->t || (a->t == b->t && a->seq < b->seq);
}

static void sim_push(sim_t *sim, int64_t t, int kind, int a, uint64_t gen, void *p)
{
    sim->heap = sim_grow(sim->heap, &sim->capheap, sim->nheap + 1, sizeof *sim->heap);
    int i = sim->nheap++;
    sim_event_t e = { t < sim->now ? sim->now : t, sim->seq++, kind, a, gen, p };
    while (i > 0 && sim_before(&e, &sim->heap[(i - 1) / 2])) {
        sim->heap[i] = sim->heap[(i - 1) / 2];
        i = (i - 1) / 2;
    }
    sim->heap[i] = e;
}

static sim_event_t sim_pop(sim_t *sim)
{
    sim_event_t top = sim->heap[0], last = sim->heap[--sim->nheap];
    int i = 0;
    for (;;) {
        int l = 2 * i + 1, m = i;
        const sim_event_t *best = &last;
        if (l < sim->nheap && sim_before(&sim->heap[l], best)) { m = l; best = &sim->heap[l]; }
        if (l + 1 < sim->nheap && sim_before(&sim->heap[l + 1], best)) m = l + 1;
        if (m == i) break;
        sim->heap[i] = sim->heap[m];
        i = m;
    }
    if (sim->nheap > 0) sim->heap[i] = last;
    return top;
}

/* ---- fibers ---------------------------------------------------------------------- */

static sim_t *sim_self; /* makecontext passes ints only: the one simulation of the process */

static void sim_wake(sim_t *sim, int f, int64_t t)
{
    sim_push(sim, t, EV_WAKE, f, ++sim->fibers[f].gen, NULL);
}

/* From a fiber back to the scheduler; it returns when the fiber is resumed. */
static void sim_yield(sim_t *sim)
{
    sim_fiber_t *f = &sim->fibers[sim->current];
#if SIM_ASAN
    __sanitizer_start_switch_fiber(f->state == FIBER_DONE ? NULL : &f->fake_stack, sim->main_bottom,
                                   sim->main_size);
#endif
    if (swapcontext(&f->uc, &sim->main_uc) != 0) abort();
#if SIM_ASAN
    __sanitizer_finish_switch_fiber(f->fake_stack, &sim->main_bottom, &sim->main_size);
#endif
}

static void sim_fiber_main(void)
{
    sim_t *sim = sim_self;
    sim_fiber_t *f = &sim->fibers[sim->current];
#if SIM_ASAN
    __sanitizer_finish_switch_fiber(NULL, &sim->main_bottom, &sim->main_size);
#endif
    f->fn(f->arg);
    f = &sim->fibers[sim->current]; /* the array may have moved */
    f->state = FIBER_DONE;
    sim->alive--;
    if (f->joiner >= 0) sim_wake(sim, f->joiner, sim->now);
    sim_yield(sim);
    abort(); /* a finished fiber is never resumed */
}

static void sim_resume(sim_t *sim, int i)
{
    sim->current = i;
    sim->cur_dpu = sim->fibers[i].dpu;
    sim_fiber_t *f = &sim->fibers[i];
#if SIM_ASAN
    __sanitizer_start_switch_fiber(&sim->main_fake, f->stack, SIM_STACK_BYTES);
#endif
    if (swapcontext(&sim->main_uc, &f->uc) != 0) abort();
#if SIM_ASAN
    __sanitizer_finish_switch_fiber(sim->main_fake, NULL, NULL);
#endif
    sim->current = -1;
}

/* Apart from its caller: getcontext returns like setjmp, which would leave the caller's
 * locals undefined. */
static int sim_context(sim_fiber_t *f)
{
    if (getcontext(&f->uc) != 0) return -1;
    f->uc.uc_stack.ss_sp = f->stack;
    f->uc.uc_stack.ss_size = SIM_STACK_BYTES;
    f->uc.uc_link = NULL;
    makecontext(&f->uc, sim_fiber_main, 0);
    return 0;
}

static int sim_fiber_new(sim_t *sim, int dpu, void *(*fn)(void *), void *arg)
{
    int i = 0;
    while (i < sim->nfibers && sim->fibers[i].state != FIBER_FREE) i++;
    if (i == sim->nfibers) {
        sim->fibers = sim_grow(sim->fibers, &sim->capfibers, i + 1, sizeof *sim->fibers);
        memset(&sim->fibers[i], 0, sizeof sim->fibers[i]);
        sim->nfibers++;
    }
    sim_fiber_t *f = &sim->fibers[i];
    if (f->stack == NULL && (f->stack = malloc(SIM_STACK_BYTES)) == NULL) return -1;
    if (sim_context(f) != 0) return -1;
    f->fn = fn;
    f->arg = arg;
    f->dpu = dpu;
    f->state = FIBER_ASLEEP;
    f->run = 0;
    f->joiner = -1;
    sim->alive++;
    sim_wake(sim, i, sim->now);
    return i;
}

/* ---- the world clock.c sees ------------------------------------------------------ */

static int64_t sim_now(void *ctx) { return ((sim_t *)ctx)->now; }

static void sim_nap(void *ctx, int64_t until)
{
    sim_t *sim = ctx;
    if (until <= sim->now || sim->current < 0) return;
    sim->fibers[sim->current].state = FIBER_ASLEEP;
    sim_wake(sim, sim->current, until);
    sim_yield(sim);
}

static int sim_url(sim_t *sim, const char *url)
{
    size_t n = strcspn(url, "?"); /* the options (a receive buffer's size) are no part of it */
    for (int i = 0; i < sim->nurls; i++)
        if (strlen(sim->urls[i]) == n && strncmp(sim->urls[i], url, n) == 0) return i;
    sim->urls = sim_grow(sim->urls, &sim->capurls, sim->nurls + 1, sizeof *sim->urls);
    if ((sim->urls[sim->nurls] = strndup(url, n)) == NULL) return -1;
    return sim->nurls++;
}

static int sim_endpoint(sim_t *sim, const lcm_t *lcm)
{
    for (int i = 0; i < sim->nendpoints; i++)
        if (sim->endpoints[i].lcm == lcm) return i;
    return -1;
}

/* Nothing reaches LCM's own queue: it holds the subscriptions, this file the messages. */
static lcm_t *sim_open(void *ctx, const char *url)
{
    sim_t *sim = ctx;
    int u = sim_url(sim, url);
    lcm_t *lcm = u < 0 ? NULL : lcm_create("memq://");
    if (lcm == NULL) return NULL;
    int i = sim_endpoint(sim, NULL);
    if (i < 0) {
        sim->endpoints = sim_grow(sim->endpoints, &sim->capendpoints, sim->nendpoints + 1,
                                  sizeof *sim->endpoints);
        i = sim->nendpoints++;
    }
    sim->endpoints[i] = (sim_endpoint_t){ .lcm = lcm, .dpu = sim->cur_dpu, .url = u };
    return lcm;
}

static void sim_release(sim_msg_t *m)
{
    if (--m->refs > 0) return;
    free(m->bytes);
    free(m);
}

static void sim_close(void *ctx, lcm_t *lcm)
{
    sim_t *sim = ctx;
    int e = sim_endpoint(sim, lcm);
    if (e < 0) return;
    sim_endpoint_t *ep = &sim->endpoints[e];
    for (int n = 0; n < ep->count; n++) sim_release(ep->inbox[(ep->head + n) % ep->cap].msg);
    free(ep->inbox);
    memset(ep, 0, sizeof *ep);
    for (int i = 0; i < sim->nsubs; i++)
        if (sim->subs[i].endpoint == e) sim->subs[i].endpoint = -1;
}

static int sim_subscribe(void *ctx, lcm_t *lcm, const char *channel, lcm_msg_handler_t handler, void *user)
{
    sim_t *sim = ctx;
    int e = sim_endpoint(sim, lcm);
    if (e < 0) return -1;
    sim->subs = sim_grow(sim->subs, &sim->capsubs, sim->nsubs + 1, sizeof *sim->subs);
    char *copy = strdup(channel);
    if (copy == NULL) return -1;
    sim->subs[sim->nsubs++] = (sim_sub_t){ e, sim->endpoints[e].url, copy, handler, user };
    return 0;
}

static void sim_log(sim_t *sim, const char *channel, const void *data, unsigned len)
{
    lcm_eventlog_event_t ev = { .timestamp = (sim->now + sim->utc_offset_ns) / 1000,
                                .channellen = (int32_t)strlen(channel), .datalen = (int32_t)len,
                                .channel = (char *)channel, .data = (void *)data };
    if (lcm_eventlog_write_event(sim->out, &ev) != 0) sim->failed = 1;
}

/* On the record URL: into the log. Elsewhere: to every subscriber of the channel on
 * that URL, arriving now. */
static int sim_publish(void *ctx, lcm_t *lcm, const char *channel, const void *data, unsigned len)
{
    sim_t *sim = ctx;
    int e = sim_endpoint(sim, lcm);
    if (e < 0) return -1;
    int url = sim->endpoints[e].url;
    if (url == sim->record_url) {
        sim_log(sim, channel, data, len);
        return 0;
    }
    sim_msg_t *m = NULL;
    for (int i = 0; i < sim->nsubs; i++) {
        const sim_sub_t *sub = &sim->subs[i];
        if (sub->endpoint < 0 || sub->url != url || strcmp(sub->channel, channel) != 0) continue;
        if (m == NULL) {
            if ((m = calloc(1, sizeof *m)) == NULL || (m->bytes = malloc(len > 0 ? len : 1)) == NULL) {
                free(m);
                return -1;
            }
            memcpy(m->bytes, data, len);
            m->len = (int)len;
            m->refs = 1; /* held until every arrival is queued */
        }
        m->refs++;
        sim_push(sim, sim->now, EV_ARRIVE, i, 0, m);
    }
    if (m != NULL) sim_release(m);
    return 0;
}

static void sim_arrive(sim_t *sim, int s, sim_msg_t *m)
{
    const sim_sub_t *sub = &sim->subs[s];
    if (sub->endpoint < 0) { /* its lcm_t was closed meanwhile */
        sim_release(m);
        return;
    }
    sim_endpoint_t *ep = &sim->endpoints[sub->endpoint];
    if (ep->count == ep->cap) { /* a full ring grows in order, from its head */
        int cap = ep->cap;
        sim_delivery_t *grown = sim_grow(NULL, &cap, ep->count + 1, sizeof *grown);
        for (int n = 0; n < ep->count; n++) grown[n] = ep->inbox[(ep->head + n) % ep->cap];
        free(ep->inbox);
        ep->inbox = grown;
        ep->cap = cap;
        ep->head = 0;
    }
    ep->inbox[(ep->head + ep->count) % ep->cap] = (sim_delivery_t){ m, s, sim->now };
    ep->count++;
    sim->deliveries++;
    for (int f = 0; f < sim->nfibers; f++) {
        sim_fiber_t *fb = &sim->fibers[f];
        if (fb->state != FIBER_WAITING || fb->dpu != ep->dpu) continue;
        for (int w = 0; w < fb->nwatch; w++)
            if (fb->watch[w] == ep->lcm) {
                fb->woke_by_message = 1;
                fb->state = FIBER_ASLEEP;
                sim_wake(sim, f, sim->now);
                break;
            }
    }
}

static int sim_handle(void *ctx, lcm_t *lcm)
{
    sim_t *sim = ctx;
    int e = sim_endpoint(sim, lcm);
    if (e < 0 || sim->endpoints[e].count == 0) return 0;
    sim_endpoint_t *ep = &sim->endpoints[e];
    sim_delivery_t d = ep->inbox[ep->head];
    ep->head = (ep->head + 1) % ep->cap;
    ep->count--;
    const sim_sub_t *sub = &sim->subs[d.sub];
    lcm_recv_buf_t rbuf = { .data = d.msg->bytes, .data_size = (uint32_t)d.msg->len,
                            .recv_utime = (d.at + sim->utc_offset_ns) / 1000, .lcm = lcm };
    sub->handler(&rbuf, sub->channel, sub->user);
    sim_release(d.msg);
    return 1;
}

static int sim_waiting(sim_t *sim, lcm_t *const *lcms, int n)
{
    for (int i = 0; i < n; i++) {
        int e = sim_endpoint(sim, lcms[i]);
        if (e >= 0 && sim->endpoints[e].count > 0) return 1;
    }
    return 0;
}

static int sim_wait(void *ctx, lcm_t *const *lcms, int n, int64_t timeout_ns)
{
    sim_t *sim = ctx;
    if (sim_waiting(sim, lcms, n)) return 1;
    if (timeout_ns <= 0 || sim->current < 0) return 0;
    sim_fiber_t *f = &sim->fibers[sim->current];
    f->state = FIBER_WAITING;
    f->watch = lcms;
    f->nwatch = n;
    f->woke_by_message = 0;
    sim_wake(sim, sim->current, sim->now + timeout_ns);
    sim_yield(sim);
    f = &sim->fibers[sim->current];
    f->watch = NULL;
    f->nwatch = 0;
    return f->woke_by_message;
}

/* What a write to a DPU's wake eventfd does on the machine: the fibers of the DPU whose
 * control is at work wake from their waits now, and find what changed (a COMMIT's switch). */
static void sim_poke(void *ctx)
{
    sim_t *sim = ctx;
    for (int f = 0; f < sim->nfibers; f++) {
        sim_fiber_t *fb = &sim->fibers[f];
        if (fb->state != FIBER_WAITING || fb->dpu != sim->cur_dpu) continue;
        fb->state = FIBER_ASLEEP;
        sim_wake(sim, f, sim->now);
    }
}

static int sim_spawn(void *ctx, int *fiber, void *(*fn)(void *), void *arg)
{
    sim_t *sim = ctx;
    *fiber = sim_fiber_new(sim, sim->cur_dpu, fn, arg);
    return *fiber < 0 ? -1 : 0;
}

static int sim_join(void *ctx, int fiber)
{
    sim_t *sim = ctx;
    sim_fiber_t *t = &sim->fibers[fiber];
    if (t->state != FIBER_DONE) {
        if (sim->current < 0) return -1; /* only a fiber waits for another */
        t->joiner = sim->current;
        t->state = FIBER_ASLEEP;
        sim_wake(sim, fiber, sim->now); /* it sees its stop flag at once */
        sim->fibers[sim->current].state = FIBER_JOINING;
        sim_yield(sim);
        t = &sim->fibers[fiber];
    }
    t->state = FIBER_FREE;
    return 0;
}

/* ---- the DPUs and their control rounds ---------------------------------------------- */

static void *sim_run(void *arg)
{
    skel_server_t *s = arg;
    if (pthread_mutex_lock(&s->lock) != 0) return NULL;
    (void)executive_serve(s);
    pthread_mutex_unlock(&s->lock);
    return NULL;
}

/* What the control thread would do now for DPU D: its round, and a START's executive. */
static void sim_control(sim_t *sim, int d)
{
    sim_dpu_t *u = &sim->dpus[d];
    sim->cur_dpu = d;
    if (u->run_fiber >= 0 && sim->fibers[u->run_fiber].state == FIBER_DONE) {
        sim->fibers[u->run_fiber].state = FIBER_FREE;
        u->run_fiber = -1;
    }
    control_notice(&u->c);
    (void)control_step(&u->c);
    if (u->run_fiber < 0 && u->s.run.requested && u->s.plan != NULL) {
        u->run_fiber = sim_fiber_new(sim, d, sim_run, &u->s);
        if (u->run_fiber >= 0) sim->fibers[u->run_fiber].run = 1;
    }
}

static int sim_busy(const sim_t *sim)
{
    if (sim->inputs_left > 0 || sim->alive > 0) return 1;
    for (int d = 0; d < sim->ndpus; d++)
        if (sim->dpus[d].s.run_active) return 1;
    return 0;
}

/* A host message of the input, now: to every DPU's control, and into the log. */
static void sim_input(sim_t *sim, lcm_eventlog_event_t *ev)
{
    sim_log(sim, ev->channel, ev->data, (unsigned)ev->datalen);
    for (int d = 0; d < sim->ndpus; d++) {
        sim->cur_dpu = d;
        if (strcmp(ev->channel, SKEL_CONFIG_CHANNEL) == 0) command_handle_config(&sim->dpus[d].c, ev->data, ev->datalen);
        else if (strcmp(ev->channel, SKEL_COMMAND_CHANNEL) == 0)
            command_handle_command(&sim->dpus[d].c, ev->data, ev->datalen);
        sim_control(sim, d);
    }
    lcm_eventlog_free_event(ev);
}

static void sim_next_input(sim_t *sim)
{
    lcm_eventlog_event_t *ev = lcm_eventlog_read_next_event(sim->in);
    if (ev == NULL) {
        sim->inputs_left = 0;
        return;
    }
    sim_push(sim, ev->timestamp * 1000 - sim->utc_offset_ns, EV_INPUT, 0, 0, ev);
}

static int sim_dpus(sim_t *sim, const char *url, const lcm_eventlog_event_t *first)
{
    skelmsg_config_t *cfg = malloc(sizeof *cfg);
    if (cfg == NULL) return -1;
    if (strcmp(first->channel, SKEL_CONFIG_CHANNEL) != 0 ||
        wire_decode_config(first->data, first->datalen, cfg) != 0) {
        fprintf(stderr, "skel-dpu: simulation: the input's first message is no config_t\n");
        free(cfg);
        return -1;
    }
    sim->ndpus = cfg->ndpus;
    sim->dpus = calloc((size_t)(cfg->ndpus > 0 ? cfg->ndpus : 1), sizeof *sim->dpus);
    int rc = sim->dpus == NULL ? -1 : 0;
    char why[512];
    for (int d = 0; rc == 0 && d < cfg->ndpus; d++) {
        sim_dpu_t *u = &sim->dpus[d];
        skel_server_t *s = &u->s;
        sim->cur_dpu = d;
        u->run_fiber = -1;
        if (server_init(s) != 0 || seal_init(&s->seal) != 0) { rc = -1; break; }
        s->id_arg = cfg->dpus[d].id;
        s->dpu_id = cfg->dpus[d].id;
        s->url = url;
        s->rt_priority = 0; /* no simulated DPU takes a class of the machine's */
        s->compute.stall_ns = SKEL_STALL_NS;
        snprintf(s->hostname, sizeof s->hostname, "%s", cfg->dpus[d].host);
        s->pid = 0; /* no process of its own; and the output stays the same from run to run */
        if (server_open(s, why, sizeof why) != 0 || control_init(&u->c, s) != 0) {
            fprintf(stderr, "skel-dpu: simulation: DPU %d: %s\n", s->dpu_id, why);
            rc = -1;
        }
    }
    wire_free_config(cfg);
    return rc;
}

static void sim_free(sim_t *sim)
{
    for (int d = 0; d < sim->ndpus; d++) {
        control_free(&sim->dpus[d].c);
        seal_free(&sim->dpus[d].s.seal);
        server_close(&sim->dpus[d].s);
        server_free(&sim->dpus[d].s);
    }
    free(sim->dpus);
    for (int i = 0; i < sim->nfibers; i++) free(sim->fibers[i].stack);
    free(sim->fibers);
    for (int i = 0; i < sim->nendpoints; i++) free(sim->endpoints[i].inbox);
    free(sim->endpoints);
    for (int i = 0; i < sim->nsubs; i++) free(sim->subs[i].channel);
    free(sim->subs);
    for (int i = 0; i < sim->nurls; i++) free(sim->urls[i]);
    free(sim->urls);
    while (sim->nheap > 0) {
        sim_event_t e = sim_pop(sim);
        if (e.kind == EV_INPUT) lcm_eventlog_free_event(e.p);
        if (e.kind == EV_ARRIVE) sim_release(e.p);
    }
    free(sim->heap);
}

static void sim_loop(sim_t *sim)
{
    sim_push(sim, sim->now, EV_ROUND, 0, 0, NULL);
    while (sim->nheap > 0 && !sim->failed) {
        sim_event_t e = sim_pop(sim);
        sim->now = e.t;
        sim->events++;
        switch (e.kind) {
        case EV_WAKE: {
            sim_fiber_t *f = &sim->fibers[e.a];
            if (e.gen != f->gen || f->state == FIBER_FREE || f->state == FIBER_DONE) break;
            sim_resume(sim, e.a);
            sim_control(sim, sim->fibers[e.a].dpu);
            break;
        }
        case EV_ARRIVE: sim_arrive(sim, e.a, e.p); break;
        case EV_INPUT:
            sim_input(sim, e.p);
            sim_next_input(sim);
            break;
        default: /* EV_ROUND: batches that waited long enough, statuses */
            for (int d = 0; d < sim->ndpus; d++) sim_control(sim, d);
            if (sim_busy(sim)) sim_push(sim, sim->now + SIM_ROUND_NS, EV_ROUND, 0, 0, NULL);
            break;
        }
    }
}

int sim_main(const char *input, const char *output, const char *url)
{
    static sim_t sim;
    sim.current = -1;
    sim.in = lcm_eventlog_create(input, "r");
    if (sim.in == NULL) {
        fprintf(stderr, "skel-dpu: simulation: cannot read %s\n", input);
        return SKEL_EXIT_USAGE;
    }
    lcm_eventlog_event_t *first = lcm_eventlog_read_next_event(sim.in);
    if (first == NULL) {
        fprintf(stderr, "skel-dpu: simulation: %s holds no message\n", input);
        lcm_eventlog_destroy(sim.in);
        return SKEL_EXIT_USAGE;
    }
    sim.out = lcm_eventlog_create(output, "w");
    char record[1024];
    if (sim.out == NULL || link_record_url(url, record, sizeof record) != 0) {
        fprintf(stderr, "skel-dpu: simulation: cannot write %s\n", output);
        lcm_eventlog_free_event(first);
        lcm_eventlog_destroy(sim.in);
        return SKEL_EXIT_USAGE;
    }
    sim_self = &sim;
    sim.now = SIM_T0_NS;
    sim.utc_offset_ns = first->timestamp * 1000 - SIM_T0_NS;
    static const clock_world_t world = { .now = sim_now, .nap = sim_nap, .open = sim_open,
                                         .close = sim_close, .subscribe = sim_subscribe,
                                         .publish = sim_publish, .handle = sim_handle, .wait = sim_wait,
                                         .spawn = sim_spawn, .join = sim_join, .poke = sim_poke };
    clock_world_t w = world;
    w.ctx = &sim;
    w.utc_offset_ns = sim.utc_offset_ns;
    clock_simulate(&w);
    sim.record_url = sim_url(&sim, record);
    int rc = sim_dpus(&sim, url, first);
    if (rc == 0) {
        sim.inputs_left = 1;
        sim_push(&sim, sim.now, EV_INPUT, 0, 0, first);
        sim_loop(&sim);
    } else {
        lcm_eventlog_free_event(first);
    }
    log_line("simulation: %lld events, %lld messages delivered, %.3f s of virtual time",
             (long long)sim.events, (long long)sim.deliveries, (double)(sim.now - SIM_T0_NS) / 1e9);
    sim_free(&sim);
    clock_simulate(NULL);
    lcm_eventlog_destroy(sim.in);
    lcm_eventlog_destroy(sim.out);
    if (rc != 0 || sim.failed) return SKEL_EXIT_FAILED;
    return SKEL_EXIT_OK;
}
