/* plan.c: one DPU's part of a validated config, turned into everything a run
 * needs: processes in run order, one slot per buffer read, a preallocated
 * encode buffer per output, the dummy payload, and one lcm_t per link URL.
 * All allocation happens here, when a config is applied, never in a cycle. */
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "dpu.h"

#define PLAN_MAX_HELD 65536 /* versions one slot holds back at most (an emulated link's delay) */

/* Index of URL in plan->links (registered once); -1 for local or when full. */
static int plan_link_index(skel_plan_t *plan, const char *url)
{
    if (url[0] == '\0') return -1;
    for (int i = 0; i < plan->nlinks; i++)
        if (strcmp(plan->links[i].url, url) == 0) return i;
    if (plan->nlinks >= SKEL_MAX_LINKS) return -2;
    plan->links[plan->nlinks].url = strdup(url);
    if (plan->links[plan->nlinks].url == NULL) return -2;
    plan->links[plan->nlinks].fd = -1;
    return plan->nlinks++;
}

int plan_process_index(const skel_plan_t *plan, int16_t id)
{
    for (int i = 0; i < plan->nprocesses; i++)
        if (plan->processes[i].id == id) return i;
    return -1;
}

/* Link L's transmitter as this DPU emulates it: one per link, shared by its slots. */
static skel_bus_t *plan_bus(skel_plan_t *plan, const skelmsg_link_t *l)
{
    for (int i = 0; i < plan->nbuses; i++)
        if (plan->buses[i].link == l->id) return &plan->buses[i];
    if (plan->nbuses == SKEL_MAX_LINKS) return NULL; /* config.c refuses more */
    skel_bus_t *bus = &plan->buses[plan->nbuses];
    if ((bus->heard = calloc(SKEL_BUS_HEARD, sizeof *bus->heard)) == NULL) return NULL;
    plan->nbuses++;
    bus->link = l->id;
    bus->ns_per_byte = 8000.0 / l->bandwidth_mbps;
    bus->queue_ns = (int64_t)l->queue_us * SKEL_NS_PER_US;
    buffers_bus_reset(bus);
    return bus;
}

/* The emulated transport of buffer B's link as this DPU reads it, and its ring of held
 * versions: as many as the writer can send within the longest delay and a reader's period
 * here, and a few for a burst of late cycles (a full ring drops and counts). A writer on another host stamps its send
 * time on its own clock, so its delay starts at the arrival there (the real network's adds). */
static int plan_transport(skel_plan_t *plan, const skelmsg_config_t *cfg, const skelmsg_buffer_desc_t *b,
                          skel_slot_t *slot)
{
    const skelmsg_link_t *l = config_link(cfg, b->link);
    skel_transport_t *tr = &slot->tr;
    int kernel = shape_taken(&plan->shape, l->id); /* what the host's kernel does instead */
    if (!(kernel & SHAPE_DELAY)) {
        tr->latency_ns = (int64_t)l->latency_us * SKEL_NS_PER_US;
        tr->jitter_ns = (int64_t)l->jitter_us * SKEL_NS_PER_US;
    }
    tr->jitter = l->jitter;
    if (!(kernel & SHAPE_LOSS)) {
        tr->loss = l->loss_pct / 100;
        tr->enter = l->burst_enter_pct / 100;
        tr->leave = l->burst_leave_pct / 100;
        tr->burst_loss = l->burst_loss_pct / 100;
    }
    const skelmsg_process_t *w = config_process(cfg, b->writer);
    tr->from_send = clock_simulated() ||
                    (w != NULL && strcmp(config_host(cfg, w->dpu), config_host(cfg, plan->dpu)) == 0);
    if (l->bandwidth_mbps > 0 && !(kernel & SHAPE_RATE)) {
        if ((slot->bus = plan_bus(plan, l)) == NULL) return -1;
        /* an udpm link (config.c refuses a local link's bandwidth) */
        slot->wire_extra = SKEL_BUFFER_HEADER_BYTES + SKEL_WIRE_LCM_HEADER_BYTES +
                           (int32_t)strlen(b->channel) + 1 + SKEL_WIRE_UDP_IP_BYTES;
    }
    if (slot->unread || (tr->latency_ns == 0 && tr->jitter_ns == 0 && slot->bus == NULL)) return 0;
    int64_t most = tr->latency_ns + (tr->jitter == SKELMSG_LINK_T_JITTER_NORMAL ? 3 : 1) * tr->jitter_ns, gap = 0;
    if (slot->bus != NULL) /* a full queue, then its own bytes */
        most += slot->bus->queue_ns + (int64_t)((double)(slot->wire_extra + b->bytes) * slot->bus->ns_per_byte);
    /* ... and what comes between two reads here, which take what is due: a reader's period */
    for (int i = 0; i < cfg->nprocesses; i++)
        for (int q = 0; cfg->processes[i].dpu == plan->dpu && q < cfg->processes[i].ninputs; q++)
            if (cfg->processes[i].inputs[q] == b->id && cfg->processes[i].period_us > gap)
                gap = cfg->processes[i].period_us;
    int64_t period = w != NULL && w->period_us > 0 ? (int64_t)w->period_us * SKEL_NS_PER_US : SKEL_MIN_PERIOD_US * SKEL_NS_PER_US;
    int64_t cap = (most + gap * SKEL_NS_PER_US) / period + 8;
    slot->pend_cap = (int)(cap > PLAN_MAX_HELD ? PLAN_MAX_HELD : cap);
    slot->pending = calloc((size_t)slot->pend_cap, sizeof *slot->pending);
    return slot->pending == NULL ? -1 : 0;
}

static int plan_slot_index(skel_plan_t *plan, const skelmsg_config_t *cfg, int16_t id, int unread)
{
    for (int i = 0; i < plan->nslots; i++)
        if (plan->slots[i].buffer == id) return i;
    if (plan->nslots >= SKEL_MAX_SLOTS) return -1;
    const skelmsg_buffer_desc_t *b = config_buffer(cfg, id);
    skel_slot_t *slot = &plan->slots[plan->nslots];
    slot->buffer = id;
    slot->unread = (int8_t)unread;
    slot->writer = b->writer;
    slot->link = plan_link_index(plan, b->url);
    slot->channel = strdup(b->channel);
    slot->plan = plan;
    if (slot->link == -2 || slot->channel == NULL) return -1;
    if (plan_transport(plan, cfg, b, slot) != 0) return -1;
    buffers_slot_reset(slot);
    return plan->nslots++;
}

static int plan_cmp_order(const void *a, const void *b)
{
    const skel_process_t *p = a, *q = b;
    if (p->order != q->order) return p->order < q->order ? -1 : 1;
    return (p->id > q->id) - (p->id < q->id);
}

static int plan_cmp_priority(const void *a, const void *b)
{
    const skel_process_t *p = a, *q = b;
    return (q->priority > p->priority) - (q->priority < p->priority);
}

static int plan_add_output(skel_plan_t *plan, const skelmsg_config_t *cfg, skel_output_t *out,
                           int16_t id)
{
    const skelmsg_buffer_desc_t *b = config_buffer(cfg, id);
    out->buffer = id;
    out->bytes = b->bytes;
    out->link = plan_link_index(plan, b->url);
    out->local_slot = -1;
    out->channel = strdup(b->channel);
    out->enc_len = wire_buffer_encoded_size(b->bytes);
    out->enc = malloc((size_t)out->enc_len);
    return out->link == -2 || out->channel == NULL || out->enc == NULL ? -1 : 0;
}

/* Each link's socket receives every message on its URL (a writer's port), read or
 * not: size it for the largest buffer sent there (link.c asks the kernel for it). */
static void plan_size_links(skel_plan_t *plan, const skelmsg_config_t *cfg)
{
    for (int i = 0; i < cfg->nbuffers; i++) {
        const skelmsg_buffer_desc_t *b = &cfg->buffers[i];
        const char *url = b->url;
        if (b->bytes <= 0 || b->bytes > SKEL_MAX_BUFFER_BYTES) continue;
        int32_t encoded = wire_buffer_encoded_size(b->bytes);
        for (int l = 0; l < plan->nlinks; l++)
            if (strcmp(plan->links[l].url, url) == 0 && encoded > plan->links[l].largest)
                plan->links[l].largest = encoded;
    }
}

/* Processes first (their inputs make the slots), then local outputs find their slot. */
static int plan_add_processes(skel_plan_t *plan, const skelmsg_config_t *cfg, int16_t dpu)
{
    for (int i = 0; i < cfg->nprocesses; i++) {
        const skelmsg_process_t *src = &cfg->processes[i];
        if (src->dpu != dpu) continue;
        skel_process_t *p = &plan->processes[plan->nprocesses++];
        p->id = src->id;
        p->order = src->order;
        p->priority = src->priority;
        p->sync = src->sync;
        p->period_ns = (int64_t)src->period_us * SKEL_NS_PER_US;
        p->compute_ns = (int64_t)((double)src->compute_us * SKEL_NS_PER_US / plan->speed);
        p->ready_ns = (int64_t)src->ready_us * SKEL_NS_PER_US;
        p->draw.n = src->nquantiles;
        for (int q = 0; q < src->nquantiles; q++)
            p->draw.table_ns[q] = src->quantiles_us[q] * SKEL_NS_PER_US / plan->speed;
        p->ratio = p->period_ns / plan->minor_ns;
        p->ninputs = src->ninputs;
        for (int q = 0; q < src->ninputs; q++) {
            skel_input_t *in = &p->inputs[q];
            in->buffer = src->inputs[q];
            in->required = src->required[q];
            in->slot = plan_slot_index(plan, cfg, src->inputs[q], 0);
            if (in->slot < 0) return -1;
            buffers_input_reset(in);
        }
        p->noutputs = src->noutputs;
        for (int q = 0; q < src->noutputs; q++)
            if (plan_add_output(plan, cfg, &p->outputs[q], src->outputs[q]) != 0) return -1;
        if (event_add_process(plan, p, src) != 0) return -1;
    }
    /* Every other message on a link whose bus a reader here emulates takes its turn too. */
    for (int i = 0; i < cfg->nbuffers; i++)
        for (int k = 0; k < plan->nbuses; k++)
            if (cfg->buffers[i].link == plan->buses[k].link && plan_slot_index(plan, cfg, cfg->buffers[i].id, 1) < 0)
                return -1;
    for (int i = 0; i < plan->nprocesses; i++)
        for (int q = 0; q < plan->processes[i].noutputs; q++) {
            skel_output_t *out = &plan->processes[i].outputs[q];
            for (int s = 0; out->link == -1 && s < plan->nslots; s++)
                if (plan->slots[s].buffer == out->buffer) out->local_slot = s;
        }
    qsort(plan->processes, (size_t)plan->nprocesses, sizeof *plan->processes,
          plan->tasking ? plan_cmp_priority : plan_cmp_order);
    return 0;
}

/* The DPUs other than DPU where some process reads buffer B. */
static int plan_other_readers(const skelmsg_config_t *cfg, int16_t b, int16_t dpu)
{
    int n = 0;
    for (int i = 0; i < cfg->nprocesses; i++) {
        const skelmsg_process_t *r = &cfg->processes[i];
        int reads = 0, counted = r->dpu == dpu;
        for (int q = 0; q < r->ninputs; q++) reads |= r->inputs[q] == b;
        for (int j = 0; reads && !counted && j < i; j++)
            for (int q = 0; q < cfg->processes[j].ninputs; q++)
                counted |= cfg->processes[j].dpu == r->dpu && cfg->processes[j].inputs[q] == b;
        n += reads && !counted;
    }
    return n;
}

/* Whether P pays for the messages of buffer B this DPU receives: of its processes reading
 * B, it has the shortest period, then the lowest (order, id). */
static int plan_pays(const skel_plan_t *plan, const skel_process_t *p, int16_t b)
{
    for (int i = 0; i < plan->nprocesses; i++) {
        const skel_process_t *r = &plan->processes[i];
        int reads = 0;
        for (int q = 0; q < r->ninputs; q++) reads |= r->inputs[q].buffer == b;
        if (reads && r != p && (r->period_ns < p->period_ns || (r->period_ns == p->period_ns &&
                                (r->order < p->order || (r->order == p->order && r->id < p->id)))))
            return 0;
    }
    return 1;
}

/* The link costs each process pays per cycle, worked out once (host/model.py charges()
 * says the same: keep the two alike); the cycle only multiplies messages received. */
static int plan_charges(skel_plan_t *plan, const skelmsg_config_t *cfg, char *reason, size_t len)
{
    for (int i = 0; i < plan->nprocesses; i++) {
        skel_process_t *p = &plan->processes[i];
        double in = 0, out = 0, mean = 0;
        for (int q = 0; q < p->noutputs; q++) {
            const skelmsg_buffer_desc_t *b = config_buffer(cfg, p->outputs[q].buffer);
            const skelmsg_link_t *l = config_link(cfg, b->link);
            int others = plan_other_readers(cfg, b->id, plan->dpu);
            out += l->per_message_us * SKEL_NS_PER_US + (l->per_byte_ns + l->push_byte_ns * others) * b->bytes;
        }
        for (int q = 0; q < p->ninputs; q++) {
            skel_input_t *inp = &p->inputs[q];
            const skelmsg_buffer_desc_t *b = config_buffer(cfg, inp->buffer);
            const skelmsg_link_t *l = config_link(cfg, b->link);
            const skelmsg_process_t *w = config_process(cfg, b->writer);
            if (w == NULL || w->period_us <= 0) continue; /* config_validate refuses it */
            if (w->dpu != plan->dpu) in += l->remote_read_us * SKEL_NS_PER_US;
            double message = l->per_message_us * SKEL_NS_PER_US + l->per_byte_ns * b->bytes;
            inp->message_ns = plan_pays(plan, p, b->id) ? llround(message) : 0;
            mean += (double)inp->message_ns * (double)p->period_ns / ((double)w->period_us * SKEL_NS_PER_US);
        }
        p->charge_in_ns = llround(in);
        p->charge_out_ns = llround(out);
        p->charge_mean_ns = llround(in + out + mean);
        if (plan->tasking && p->charge_mean_ns > 0) {
            snprintf(reason, len, "DPU %d: the tasking executive charges no link costs (process %d)",
                     plan->dpu, p->id);
            return -1;
        }
    }
    return 0;
}

/* Whether the configured load fits the DPU (Σ compute / period <= 1): cycle.c
 * skips a data-synchronised process's late releases only then. */
static int plan_fits(const skel_plan_t *plan)
{
    double load = 0.0;
    for (int i = 0; i < plan->nprocesses; i++)
        load += (double)(plan->processes[i].compute_ns + plan->processes[i].charge_mean_ns) /
                (double)plan->processes[i].period_ns;
    return load <= 1.0;
}

/* CFG must have passed config_validate for DPU_INDEX. */
skel_plan_t *plan_build(const skelmsg_config_t *cfg, int dpu_index, char *reason, size_t len)
{
    const skelmsg_dpu_t *d = &cfg->dpus[dpu_index];
    skel_plan_t *plan = calloc(1, sizeof *plan);
    if (plan == NULL) goto oom;
    plan->generation = cfg->generation;
    plan->dpu = d->id;
    plan->cpu = d->cpu;
    plan->compute = d->compute;
    /* On virtual time every mode computes exactly what it is asked, which is SLEEP's
     * definition (a dedicated processor), so the tasking executive runs its own exact
     * schedule (tasking.c), and no simulated DPU takes a CPU of the machine. */
    if (clock_simulated()) {
        plan->compute = SKELMSG_DPU_T_COMPUTE_SLEEP;
        plan->cpu = -1;
    }
    plan->tasking = d->executive == SKELMSG_DPU_T_EXECUTIVE_THREADS;
    plan->speed = d->speed;
    plan->minor_ns = config_minor_us(cfg, d) * SKEL_NS_PER_US;
    plan->common_ns = config_common_us(cfg) * SKEL_NS_PER_US;
    if (plan->minor_ns <= 0 || plan->common_ns % plan->minor_ns != 0) plan->common_ns = plan->minor_ns;
    plan->warmup_cycles = cfg->warmup_cycles;
    plan->lockout_cycles = cfg->lockout_cycles;
    plan->seed = cfg->seed;
    plan->processes = calloc(SKEL_MAX_PROCESSES, sizeof *plan->processes);
    plan->slots = calloc(SKEL_MAX_SLOTS, sizeof *plan->slots);
    plan->buses = calloc(SKEL_MAX_LINKS, sizeof *plan->buses);
    if (plan->processes == NULL || plan->slots == NULL || plan->buses == NULL) goto oom;
    plan->event_link = -1;
    shape_plan(&plan->shape, cfg, d->id);
    if (plan_add_processes(plan, cfg, d->id) != 0) goto oom;
    if (plan_charges(plan, cfg, reason, len) != 0) {
        plan_free(plan);
        return NULL;
    }
    if (event_add_sources(plan, cfg, d->id) != 0) goto oom;
    plan->fits = plan_fits(plan);
    plan_size_links(plan, cfg);
    int32_t max_bytes = 1;
    for (int i = 0; i < cfg->nbuffers; i++)
        if (cfg->buffers[i].bytes > max_bytes && cfg->buffers[i].bytes <= SKEL_MAX_BUFFER_BYTES)
            max_bytes = cfg->buffers[i].bytes;
    plan->dummy = malloc((size_t)max_bytes);
    if (plan->dummy == NULL) goto oom;
    /* A recognisable, non-zero pattern: a capture shows the dummy payload for what it is. */
    for (int32_t i = 0; i < max_bytes; i++) plan->dummy[i] = (uint8_t)(0xA5 ^ (i & 0xff));
    return plan;
oom:
    snprintf(reason, len, "DPU %d: out of memory building the plan for generation %lld", d->id,
             (long long)cfg->generation);
    plan_free(plan);
    return NULL;
}

/* The network side of applying: lcm_t per URL, a subscription per slot read
 * over a link. Made by the control thread, used afterwards by the executive. */
int plan_open_links(skel_plan_t *plan, const char *control_url, const char *record_url,
                    atomic_int_fast64_t *rejected, char *reason, size_t len)
{
    plan->rejected = rejected;
    for (int i = 0; i < plan->nlinks; i++)
        if (link_open(&plan->links[i]) != 0) {
            snprintf(reason, len, "DPU %d: cannot open link %s (multicast route?)", plan->dpu,
                     plan->links[i].url);
            return -1;
        }
    for (int s = 0; s < plan->nslots; s++) {
        skel_slot_t *slot = &plan->slots[s];
        if (slot->link >= 0 && link_subscribe(&plan->links[slot->link], slot) != 0) {
            snprintf(reason, len, "DPU %d: cannot subscribe to %s on %s", plan->dpu,
                     slot->channel, plan->links[slot->link].url);
            return -1;
        }
    }
    if (event_open(plan, control_url, record_url) != 0) {
        snprintf(reason, len, "DPU %d: cannot open or subscribe to its events on %s", plan->dpu, control_url);
        return -1;
    }
    return 0;
}

void plan_free(skel_plan_t *plan)
{
    if (plan == NULL) return;
    event_free(plan);
    for (int i = 0; i < plan->nlinks; i++) link_close(&plan->links[i]);
    for (int s = 0; plan->slots != NULL && s < plan->nslots; s++) {
        free(plan->slots[s].channel);
        free(plan->slots[s].pending);
        free(plan->slots[s].bytes);
    }
    for (int i = 0; plan->processes != NULL && i < plan->nprocesses; i++) code_free(&plan->processes[i]);
    /* nprocesses counts a process before its outputs are allocated (plan_add_processes),
     * so a plan that failed half-way is freed whole; the rest of the table is zeros. */
    for (int i = 0; plan->processes != NULL && i < plan->nprocesses; i++)
        for (int q = 0; q < SKEL_MAX_IO; q++) {
            free(plan->processes[i].outputs[q].channel);
            free(plan->processes[i].outputs[q].enc);
        }
    for (int k = 0; plan->buses != NULL && k < plan->nbuses; k++) free(plan->buses[k].heard);
    free(plan->buses);
    free(plan->processes);
    free(plan->slots);
    free(plan->dummy);
    free(plan);
}

/* Everything a run counts starts from zero; the allocations stay. */
void plan_reset_run(skel_plan_t *plan, int64_t run_id)
{
    plan->run_id = run_id;
    for (int s = 0; s < plan->nslots; s++) {
        buffers_slot_reset(&plan->slots[s]);
        buffers_slot_seed(&plan->slots[s], plan->seed, plan->dpu);
    }
    for (int k = 0; k < plan->nbuses; k++) buffers_bus_reset(&plan->buses[k]);
    for (int i = 0; i < plan->nprocesses; i++) {
        skel_process_t *p = &plan->processes[i];
        for (int q = 0; q < p->ninputs; q++) buffers_input_reset(&p->inputs[q]);
        p->k_base = 0;
        p->measure_from_k = plan->warmup_cycles;
        p->locked_out = 0;
        p->job.lockout_k = -1;
        p->job.state = JOB_NONE;
        p->job.release = INT64_MIN / 4; /* an event process's first event is released when it comes */
        p->next_k = 0;
        p->sums = (skel_process_sums_t){ 0 };
        draw_seed(&p->draw, plan->seed, p->id);
    }
    event_reset_run(plan);
    plan->publish_errors = 0;
    plan->run_t0_ns = plan->epoch_t0_ns = 0;
    plan->minor_base = 0;
    plan->measure_from_ns = 0;
    memset(&plan->sums, 0, sizeof plan->sums);
    plan->sums.first_release_ns = plan->sums.first_start_ns = plan->sums.warmup_end_ns = -1;
}
