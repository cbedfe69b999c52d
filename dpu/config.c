/* config.c: the self-configuring DPU's first step. A config_t describes the
 * whole system; this file finds which DPU we are in it (--id N, or the host name
 * for --id auto) and validates our own part against the daemon's fixed limits.
 * A config that fails gets one clear line saying what, where and why, and the
 * old config stays in force. Nothing here allocates or touches the network. */
#include <ctype.h>
#include <math.h>
#include <sched.h>
#include <stdarg.h>
#include <stdio.h>
#include <string.h>

#include "dpu.h"

static int config_fail(char *reason, size_t len, const char *fmt, ...)
    __attribute__((format(printf, 3, 4)));

static int config_fail(char *reason, size_t len, const char *fmt, ...)
{
    va_list ap;
    va_start(ap, fmt);
    vsnprintf(reason, len, fmt, ap);
    va_end(ap);
    return -1;
}

int config_find_self(const skelmsg_config_t *cfg, int id_arg, const char *hostname,
                     skel_self_t *self)
{
    int found = -1, count = 0;
    memset(self, 0, sizeof *self);
    self->dpu_index = -1;
    self->dpu_id = -1;
    for (int i = 0; i < cfg->ndpus; i++) {
        const skelmsg_dpu_t *d = &cfg->dpus[i];
        int match = id_arg >= 0 ? d->id == id_arg : strcmp(d->host, hostname) == 0;
        if (!match) continue;
        if (found < 0) found = i;
        count++;
    }
    if (count == 1) {
        self->dpu_index = found;
        self->dpu_id = cfg->dpus[found].id;
        return 0;
    }
    if (id_arg >= 0 && count == 0)
        snprintf(self->reason, sizeof self->reason, "DPU %d is not in generation %lld",
                 id_arg, (long long)cfg->generation);
    else if (id_arg >= 0)
        snprintf(self->reason, sizeof self->reason, "DPU id %d appears %d times in generation %lld",
                 id_arg, count, (long long)cfg->generation);
    else if (count == 0)
        snprintf(self->reason, sizeof self->reason, "no DPU for host '%s' in generation %lld",
                 hostname, (long long)cfg->generation);
    else
        snprintf(self->reason, sizeof self->reason,
                 "%d DPUs for host '%s' in generation %lld: start each with --id N", count,
                 hostname, (long long)cfg->generation);
    return -1;
}

const skelmsg_buffer_desc_t *config_buffer(const skelmsg_config_t *cfg, int16_t id)
{
    for (int i = 0; i < cfg->nbuffers; i++)
        if (cfg->buffers[i].id == id) return &cfg->buffers[i];
    return NULL;
}

const skelmsg_link_t *config_link(const skelmsg_config_t *cfg, int16_t id)
{
    for (int i = 0; i < cfg->nlinks; i++)
        if (cfg->links[i].id == id) return &cfg->links[i];
    return NULL;
}

/* Process ID of CFG, NULL when none. */
const skelmsg_process_t *config_process(const skelmsg_config_t *cfg, int16_t id)
{
    for (int i = 0; i < cfg->nprocesses; i++)
        if (cfg->processes[i].id == id) return &cfg->processes[i];
    return NULL;
}

/* The host of DPU ID in CFG, "" when unknown. */
const char *config_host(const skelmsg_config_t *cfg, int16_t id)
{
    for (int i = 0; i < cfg->ndpus; i++)
        if (cfg->dpus[i].id == id) return cfg->dpus[i].host;
    return "";
}

static int config_dpu_reaches(const skelmsg_dpu_t *d, int16_t link)
{
    for (int i = 0; i < d->nlinks; i++)
        if (d->links[i] == link) return 1;
    return 0;
}

static int config_is_control_channel(const char *ch)
{
    return strcmp(ch, SKEL_CONFIG_CHANNEL) == 0 || strcmp(ch, SKEL_COMMAND_CHANNEL) == 0 ||
           strcmp(ch, SKEL_STATUS_CHANNEL) == 0 || strcmp(ch, SKEL_TIMING_CHANNEL) == 0 ||
           strcmp(ch, SKEL_REPORT_CHANNEL) == 0;
}

/* A local buffer lives in one DPU's memory: its writer and every reader must be there. */
static int config_check_local(const skelmsg_config_t *cfg, const skelmsg_buffer_desc_t *b,
                              int16_t dpu, char *reason, size_t len)
{
    for (int i = 0; i < cfg->nprocesses; i++) {
        const skelmsg_process_t *p = &cfg->processes[i];
        int uses = p->id == b->writer;
        for (int q = 0; q < p->ninputs; q++) uses |= p->inputs[q] == b->id;
        if (uses && p->dpu != dpu)
            return config_fail(reason, len,
                               "buffer %d is on a local link but process %d uses it from DPU %d",
                               b->id, p->id, p->dpu);
    }
    return 0;
}

static int config_pct(double v) { return v >= 0 && v <= 100; } /* false for NaN too */

/* A link's emulated transport (buffers.c); an int32 of us is far within an int64 of ns. */
static int config_check_transport(const skelmsg_link_t *l, char *reason, size_t len)
{
    if (l->latency_us < 0 || l->jitter_us < 0)
        return config_fail(reason, len, "link %d: latency_us %d or jitter_us %d is negative", l->id,
                           l->latency_us, l->jitter_us);
    if (l->jitter != SKELMSG_LINK_T_JITTER_UNIFORM && l->jitter != SKELMSG_LINK_T_JITTER_NORMAL)
        return config_fail(reason, len, "link %d: unknown jitter %d", l->id, l->jitter);
    if (!config_pct(l->loss_pct) || !config_pct(l->burst_enter_pct) || !config_pct(l->burst_leave_pct) ||
        !config_pct(l->burst_loss_pct))
        return config_fail(reason, len, "link %d: a loss or burst percentage is outside 0..100", l->id);
    if (l->url[0] == '\0' && l->bandwidth_mbps != 0)
        return config_fail(reason, len, "link %d: a local link is memory inside one DPU: it has no "
                           "bandwidth to share", l->id);
    if (!(l->bandwidth_mbps == 0 ||
          (l->bandwidth_mbps >= SKEL_MIN_BANDWIDTH_MBPS && l->bandwidth_mbps <= SKEL_MAX_BANDWIDTH_MBPS)) ||
        (l->bandwidth_mbps > 0 && l->queue_us <= 0) || l->queue_us < 0)
        return config_fail(reason, len, "link %d: bandwidth_mbps %g outside %g..%g, or queue_us %d not "
                           "positive with it", l->id, l->bandwidth_mbps, SKEL_MIN_BANDWIDTH_MBPS,
                           SKEL_MAX_BANDWIDTH_MBPS, l->queue_us);
    return 0;
}

/* One buffer a process of ours reads or writes: known, sized, on a reachable link. */
static int config_check_buffer(const skelmsg_config_t *cfg, const skelmsg_dpu_t *d,
                               const skelmsg_process_t *p, int16_t id, char *reason, size_t len)
{
    const skelmsg_buffer_desc_t *b = config_buffer(cfg, id);
    if (b == NULL)
        return config_fail(reason, len, "process %d uses unknown buffer %d", p->id, id);
    if (b->bytes < 0 || b->bytes > SKEL_MAX_BUFFER_BYTES)
        return config_fail(reason, len, "buffer %d: bytes %d outside 0..%d", b->id, b->bytes,
                           SKEL_MAX_BUFFER_BYTES);
    const skelmsg_link_t *l = config_link(cfg, b->link);
    if (l == NULL) return config_fail(reason, len, "buffer %d: unknown link %d", b->id, b->link);
    if (config_check_transport(l, reason, len) != 0) return -1;
    const double costs[] = { l->per_message_us, l->per_byte_ns, l->push_byte_ns, l->remote_read_us };
    for (size_t i = 0; i < sizeof costs / sizeof *costs; i++)
        if (!(costs[i] >= 0 && costs[i] <= SKEL_MAX_LINK_COST) || (l->url[0] == '\0' && costs[i] != 0))
            return config_fail(reason, len, "link %d (%.64s): a cost outside 0..%d, or one on a local link",
                               l->id, l->name, SKEL_MAX_LINK_COST);
    if (l->url[0] == '\0') {
        if (b->url[0] != '\0')
            return config_fail(reason, len, "buffer %d: on local link %d but sent to '%.64s'", b->id,
                               b->link, b->url);
        return config_check_local(cfg, b, d->id, reason, len);
    }
    /* liblcm opens whatever provider a URL names (file:// writes a log file wherever it
     * says, tcpq:// connects out): a link is multicast, as the host's schema allows, and so
     * is the URL on its writer's port that the buffer travels on. */
    if (strncmp(l->url, "udpm://", 7) != 0 || strncmp(b->url, "udpm://", 7) != 0)
        return config_fail(reason, len, "buffer %d: link %d (%.64s) URL '%.64s' or '%.64s' is not udpm://",
                           b->id, b->link, l->name, l->url, b->url);
    if (!config_dpu_reaches(d, b->link))
        return config_fail(reason, len, "buffer %d: link %d (%s) is not in DPU %d's links",
                           b->id, b->link, l->name, d->id);
    if (b->channel[0] == '\0' || config_is_control_channel(b->channel))
        return config_fail(reason, len, "buffer %d: channel '%.64s' is empty or a SKEL_ control channel",
                           b->id, b->channel);
    /* LCM publishes no longer channel: every cycle's publish would fail. */
    if (strlen(b->channel) > LCM_MAX_CHANNEL_NAME_LENGTH)
        return config_fail(reason, len, "buffer %d: channel '%.64s...' is longer than %d characters", b->id,
                           b->channel, LCM_MAX_CHANNEL_NAME_LENGTH);
    return 0;
}

/* A varying compute time's table: 0 points (constant) or 2..SKEL_QUANTILES, each a
 * finite non-negative time no longer than the longest constant one, non-decreasing. */
static int config_check_quantiles(const skelmsg_process_t *p, char *reason, size_t len)
{
    if (p->nquantiles == 0) return 0;
    if (p->nquantiles < 2 || p->nquantiles > SKEL_QUANTILES)
        return config_fail(reason, len, "process %d: %d compute quantiles; 0 or 2..%d", p->id,
                           p->nquantiles, SKEL_QUANTILES);
    for (int q = 0; q < p->nquantiles; q++) {
        double v = p->quantiles_us[q];
        if (!isfinite(v) || v < 0.0 || v > (double)INT32_MAX ||
            (q > 0 && v < p->quantiles_us[q - 1]))
            return config_fail(reason, len, "process %d: compute quantile %d (%g us) is not a "
                               "non-decreasing time", p->id, q, v);
    }
    return 0;
}

/* An event's name becomes a channel's suffix: letters, digits and _, 1..SKEL_MAX_NAME
 * of them, so that SKEL_EVENT_<name> is a channel LCM publishes. */
_Static_assert(sizeof SKEL_EVENT_CHANNEL_PREFIX - 1 + SKEL_MAX_NAME <= LCM_MAX_CHANNEL_NAME_LENGTH,
               "an event channel must fit LCM's channel names");

static int config_event_name(const char *name)
{
    size_t n = strlen(name);
    if (n == 0 || n > SKEL_MAX_NAME) return -1;
    for (size_t i = 0; i < n; i++)
        if (!((name[i] >= 'a' && name[i] <= 'z') || (name[i] >= 'A' && name[i] <= 'Z') ||
              (name[i] >= '0' && name[i] <= '9') || name[i] == '_'))
            return -1;
    return 0;
}

static int config_check_events_of(const skelmsg_process_t *p, char *reason, size_t len)
{
    if (p->sync == SKELMSG_PROCESS_T_SYNC_EVENT) {
        if (config_event_name(p->event) != 0)
            return config_fail(reason, len, "process %d: event name '%.64s' is not a name", p->id, p->event);
        if (p->queue < 1 || p->queue > SKEL_MAX_QUEUE)
            return config_fail(reason, len, "process %d: queue %d outside 1..%d", p->id, p->queue,
                               SKEL_MAX_QUEUE);
    }
    if (p->nemits > SKEL_MAX_EMITS)
        return config_fail(reason, len, "process %d: emits %d events, limit %d", p->id, p->nemits,
                           SKEL_MAX_EMITS);
    for (int e = 0; e < p->nemits; e++)
        if (config_event_name(p->emits[e]) != 0)
            return config_fail(reason, len, "process %d: emitted event name '%.64s' is not a name", p->id,
                               p->emits[e]);
    return 0;
}

/* A generator this DPU runs: parameters that give a finite, ordered stream of instants. */
static int config_check_source(const skelmsg_event_source_t *g, char *reason, size_t len)
{
    if (config_event_name(g->name) != 0)
        return config_fail(reason, len, "event '%.64s': not a name", g->name);
    switch (g->kind) {
    case SKELMSG_EVENT_SOURCE_T_KIND_PERIODIC:
        if (g->period_us <= 0 || g->jitter_us < 0 || 2LL * g->jitter_us >= g->period_us)
            return config_fail(reason, len, "event %s: period_us %d, jitter_us %d (0 <= 2 jitter < period)",
                               g->name, g->period_us, g->jitter_us);
        return 0;
    case SKELMSG_EVENT_SOURCE_T_KIND_POISSON:
        /* A slower rate's exponential gaps outgrow an int64 of ns (event.c's generator). */
        if (!isfinite(g->rate_hz) || g->rate_hz < SKEL_MIN_RATE_HZ || g->rate_hz > SKEL_MAX_RATE_HZ)
            return config_fail(reason, len, "event %s: rate_hz %g outside %g..%g", g->name, g->rate_hz,
                               SKEL_MIN_RATE_HZ, (double)SKEL_MAX_RATE_HZ);
        return 0;
    case SKELMSG_EVENT_SOURCE_T_KIND_BURSTS:
        if (g->period_us <= 0 || g->count < 1 || g->spacing_us <= 0 ||
            (int64_t)(g->count - 1) * g->spacing_us >= g->period_us)
            return config_fail(reason, len, "event %s: a burst of %d events %d us apart does not fit in "
                               "period_us %d", g->name, g->count, g->spacing_us, g->period_us);
        return 0;
    default:
        return config_fail(reason, len, "event %s: unknown kind %d", g->name, g->kind);
    }
}

/* The events DPU D awaits, emits or generates: each valid, at most SKEL_MAX_EVENTS names. */
static int config_check_events(const skelmsg_config_t *cfg, const skelmsg_dpu_t *d, char *reason,
                               size_t len)
{
    const char *names[SKEL_MAX_EVENTS];
    int n = 0;
    for (int i = 0; i < cfg->nprocesses + cfg->nevents; i++) {
        const char *mine[SKEL_MAX_EMITS + 1];
        int m = 0;
        if (i < cfg->nprocesses) {
            const skelmsg_process_t *p = &cfg->processes[i];
            if (p->dpu != d->id) continue;
            if (p->sync == SKELMSG_PROCESS_T_SYNC_EVENT) mine[m++] = p->event;
            for (int e = 0; e < p->nemits && e < SKEL_MAX_EMITS; e++) mine[m++] = p->emits[e];
        } else {
            const skelmsg_event_source_t *g = &cfg->events[i - cfg->nprocesses];
            if (g->kind == SKELMSG_EVENT_SOURCE_T_KIND_HOST || g->dpu != d->id) continue;
            if (config_check_source(g, reason, len) != 0) return -1;
            mine[m++] = g->name;
        }
        for (int k = 0; k < m; k++) {
            int seen = 0;
            for (int j = 0; j < n && !seen; j++) seen = strcmp(names[j], mine[k]) == 0;
            if (seen) continue;
            if (n == SKEL_MAX_EVENTS)
                return config_fail(reason, len, "DPU %d: more than %d distinct events", d->id, SKEL_MAX_EVENTS);
            names[n++] = mine[k];
        }
    }
    return 0;
}

/* Real code is named, never given as a path (code.c looks it up in --lib-dir only), and runs
 * on the cyclic executive, whose compute step calls it. It reads the bytes a slot keeps as a
 * message comes, which a link that holds versions back (latency, jitter) does not keep yet. */
static int config_check_code(const skelmsg_config_t *cfg, const skelmsg_dpu_t *d, const skelmsg_process_t *p,
                             char *reason, size_t len)
{
    size_t n = strlen(p->library);
    if (n == 0 && p->function[0] == '\0') return 0;
    if (n == 0 || p->function[0] == '\0')
        return config_fail(reason, len, "process %d: real code needs both a library and a function", p->id);
    if (n > SKEL_MAX_NAME || strlen(p->function) > SKEL_MAX_NAME)
        return config_fail(reason, len, "process %d: library or function name longer than %d", p->id,
                           SKEL_MAX_NAME);
    for (size_t i = 0; i < n; i++) {
        char ch = p->library[i];
        if (!isalnum((unsigned char)ch) && ch != '_' && ch != '-' && !(ch == '.' && i > 0))
            return config_fail(reason, len, "process %d: library \"%.60s\" is a path or not a name: "
                               "name a library in the DPU's --lib-dir", p->id, p->library);
    }
    if (d->executive != SKELMSG_DPU_T_EXECUTIVE_CYCLIC)
        return config_fail(reason, len, "process %d: real code runs on the cyclic executive only", p->id);
    for (int i = 0; i < p->ninputs; i++) {
        const skelmsg_buffer_desc_t *b = config_buffer(cfg, p->inputs[i]);
        const skelmsg_link_t *l = b != NULL ? config_link(cfg, b->link) : NULL;
        if (l != NULL && (l->latency_us > 0 || l->jitter_us > 0 || l->bandwidth_mbps > 0))
            return config_fail(reason, len, "process %d: real code cannot read buffer %d through link %d's "
                               "emulated latency or bandwidth yet", p->id, b->id, l->id);
    }
    return 0;
}

static int config_check_process(const skelmsg_config_t *cfg, const skelmsg_dpu_t *d,
                                int64_t minor_us, const skelmsg_process_t *p, char *reason,
                                size_t len)
{
    if (p->period_us < SKEL_MIN_PERIOD_US || p->period_us > SKEL_MAX_PERIOD_US)
        return config_fail(reason, len, "process %d: period_us %d outside %d..%d", p->id,
                           p->period_us, SKEL_MIN_PERIOD_US, SKEL_MAX_PERIOD_US);
    const int tasking = d->executive == SKELMSG_DPU_T_EXECUTIVE_THREADS;
    if (!tasking && p->period_us % minor_us != 0)
        return config_fail(reason, len, "process %d: period_us %d is not a multiple of DPU %d's minor cycle %lld us",
                           p->id, p->period_us, d->id, (long long)minor_us);
    if (p->compute_us < 0)
        return config_fail(reason, len, "process %d: compute_us %d < 0", p->id, p->compute_us);
    if (p->ready_us < 0)
        return config_fail(reason, len, "process %d: ready_us %d < 0", p->id, p->ready_us);
    if (config_check_quantiles(p, reason, len) != 0) return -1;
    if (config_check_code(cfg, d, p, reason, len) != 0) return -1;
    if (tasking ? p->priority < 1 || p->priority > SKEL_MAX_PRIORITY : p->priority != 0)
        return config_fail(reason, len, "process %d: priority %d (the tasking executive's: 1..%d; "
                           "the cyclic one's: 0)", p->id, p->priority, SKEL_MAX_PRIORITY);
    if (p->sync < SKELMSG_PROCESS_T_SYNC_PERIODIC || p->sync > SKELMSG_PROCESS_T_SYNC_EVENT)
        return config_fail(reason, len, "process %d: unknown sync %d", p->id, p->sync);
    if (config_check_events_of(p, reason, len) != 0) return -1;
    if (p->ninputs > SKEL_MAX_IO || p->noutputs > SKEL_MAX_IO)
        return config_fail(reason, len, "process %d: %d inputs / %d outputs, limit %d each",
                           p->id, p->ninputs, p->noutputs, SKEL_MAX_IO);
    for (int q = 0; q < p->ninputs; q++) {
        if (config_check_buffer(cfg, d, p, p->inputs[q], reason, len) != 0) return -1;
        for (int r = 0; r < q; r++)
            if (p->inputs[r] == p->inputs[q])
                return config_fail(reason, len, "process %d reads buffer %d twice", p->id,
                                   p->inputs[q]);
    }
    for (int q = 0; q < p->noutputs; q++) {
        if (config_check_buffer(cfg, d, p, p->outputs[q], reason, len) != 0) return -1;
        const skelmsg_buffer_desc_t *b = config_buffer(cfg, p->outputs[q]);
        if (b->writer != p->id)
            return config_fail(reason, len, "buffer %d is written by process %d, not by process %d",
                               b->id, b->writer, p->id);
    }
    return 0;
}

static int64_t config_gcd(int64_t a, int64_t b)
{
    while (b != 0) {
        int64_t t = a % b;
        a = b;
        b = t;
    }
    return a;
}

/* The gcd of our periods: the minor cycle when the config leaves it at 0. */
int64_t config_minor_us(const skelmsg_config_t *cfg, const skelmsg_dpu_t *d)
{
    if (d->minor_cycle_us > 0) return d->minor_cycle_us;
    int64_t g = 0;
    for (int i = 0; i < cfg->nprocesses; i++)
        if (cfg->processes[i].dpu == d->id && cfg->processes[i].period_us > 0)
            g = config_gcd(cfg->processes[i].period_us, g);
    return g;
}

/* The grid every DPU's minor-cycle grid shares (their lcm, in us), so a live
 * switch can happen at one instant on all of them; 0 when it is longer than
 * SKEL_MAX_COMMON_US (each DPU then switches at its own next release). */
int64_t config_common_us(const skelmsg_config_t *cfg)
{
    int64_t common = 1;
    for (int i = 0; i < cfg->ndpus; i++) {
        int64_t m = config_minor_us(cfg, &cfg->dpus[i]);
        if (m <= 0) continue;
        common = common / config_gcd(common, m) * m; /* <= 1e7 * INT32_MAX: no overflow */
        if (common > SKEL_MAX_COMMON_US) return 0;
    }
    return common;
}

static int config_check_ids(const skelmsg_config_t *cfg, char *reason, size_t len)
{
    for (int i = 0; i < cfg->nbuffers; i++)
        for (int j = 0; j < i; j++)
            if (cfg->buffers[i].id == cfg->buffers[j].id)
                return config_fail(reason, len, "buffer id %d appears twice", cfg->buffers[i].id);
    for (int i = 0; i < cfg->nprocesses; i++)
        for (int j = 0; j < i; j++)
            if (cfg->processes[i].id == cfg->processes[j].id)
                return config_fail(reason, len, "process id %d appears twice",
                                   cfg->processes[i].id);
    return 0;
}

/* Whether a process of DPU reads a buffer on link LINK (its bus is emulated or shaped there). */
int config_reads_link(const skelmsg_config_t *cfg, int16_t dpu, int16_t link)
{
    for (int i = 0; i < cfg->nprocesses; i++)
        for (int q = 0; cfg->processes[i].dpu == dpu && q < cfg->processes[i].ninputs; q++) {
            const skelmsg_buffer_desc_t *b = config_buffer(cfg, cfg->processes[i].inputs[q]);
            if (b != NULL && b->link == link) return 1;
        }
    return 0;
}

/* Whether DPU opens buffer B's URL: a process of its reads or writes B, or B is on a
 * bandwidth-limited link that it reads, whose every message it hears for the bus. */
static int config_opens(const skelmsg_config_t *cfg, int16_t dpu, const skelmsg_buffer_desc_t *b)
{
    for (int i = 0; i < cfg->nprocesses; i++) {
        const skelmsg_process_t *p = &cfg->processes[i];
        if (p->dpu != dpu) continue;
        for (int q = 0; q < p->ninputs + p->noutputs; q++)
            if ((q < p->ninputs ? p->inputs[q] : p->outputs[q - p->ninputs]) == b->id) return 1;
    }
    const skelmsg_link_t *l = config_link(cfg, b->link);
    return l != NULL && l->bandwidth_mbps > 0 && config_reads_link(cfg, dpu, b->link);
}

/* Distinct buffer URLs we open, and the control URL when our processes await or emit
 * events (event_open adds it as a link), stay within SKEL_MAX_LINKS; buffers we open
 * must not share a channel on one URL (a reader could not tell them apart). */
static int config_check_links(const skelmsg_config_t *cfg, const skelmsg_dpu_t *d, char *reason,
                              size_t len)
{
    const char *urls[SKEL_MAX_LINKS];
    int nurls = 0;
    for (int i = 0; i < cfg->nprocesses && nurls == 0; i++) {
        const skelmsg_process_t *p = &cfg->processes[i];
        if (p->dpu == d->id && (p->sync == SKELMSG_PROCESS_T_SYNC_EVENT || p->nemits > 0))
            urls[nurls++] = ""; /* the control URL: no buffer URL is empty */
    }
    int buses = 0;
    for (int i = 0; i < cfg->nlinks; i++)
        buses += cfg->links[i].bandwidth_mbps > 0 && config_reads_link(cfg, d->id, cfg->links[i].id);
    if (buses > SKEL_MAX_LINKS)
        return config_fail(reason, len, "DPU %d: reads more than %d bandwidth-limited links", d->id,
                           SKEL_MAX_LINKS);
    for (int i = 0; i < cfg->nbuffers; i++) {
        const skelmsg_buffer_desc_t *b = &cfg->buffers[i];
        const char *url = b->url;
        if (url[0] == '\0' || !config_opens(cfg, d->id, b)) continue;
        int u = 0;
        while (u < nurls && strcmp(urls[u], url) != 0) u++;
        if (u == nurls && nurls == SKEL_MAX_LINKS)
            return config_fail(reason, len, "DPU %d: more than %d links (a group and port per writer "
                               "it reads or is, every writer on a bandwidth-limited link it reads, and "
                               "the control URL for events)", d->id, SKEL_MAX_LINKS);
        if (u == nurls) urls[nurls++] = url;
        for (int j = 0; j < cfg->nbuffers; j++) {
            const skelmsg_buffer_desc_t *o = &cfg->buffers[j];
            if (o->id != b->id && strcmp(o->url, url) == 0 && strcmp(o->channel, b->channel) == 0)
                return config_fail(reason, len, "buffers %d and %d share channel '%s' on %s",
                                   b->id, o->id, b->channel, url);
        }
    }
    return 0;
}

/* A DPU pinned to a CPU its host lacks (or that its cgroup keeps it off) would run
 * unpinned and measure another machine than the one described: only this DPU can
 * tell, so it refuses the configuration at push time. */
static int config_check_cpu(const skelmsg_dpu_t *d, char *reason, size_t len)
{
    if (d->cpu < 0) return 0;
    cpu_set_t allowed;
    CPU_ZERO(&allowed);
    if (sched_getaffinity(0, sizeof allowed, &allowed) != 0) return 0; /* cannot tell: the run warns */
    if (d->cpu < CPU_SETSIZE && CPU_ISSET(d->cpu, &allowed)) return 0;
    return config_fail(reason, len, "DPU %d: cpu %d is not one this host lets it run on (%d CPUs allowed)",
                       d->id, d->cpu, CPU_COUNT(&allowed));
}

int config_validate(const skelmsg_config_t *cfg, int dpu_index, char *reason, size_t len)
{
    const skelmsg_dpu_t *d = &cfg->dpus[dpu_index];
    const int tasking = d->executive == SKELMSG_DPU_T_EXECUTIVE_THREADS;
    if (!tasking && d->executive != SKELMSG_DPU_T_EXECUTIVE_CYCLIC)
        return config_fail(reason, len, "DPU %d: unknown executive %d", d->id, d->executive);
    if (d->compute < SKELMSG_DPU_T_COMPUTE_SLEEP || d->compute > SKELMSG_DPU_T_COMPUTE_WORK)
        return config_fail(reason, len, "DPU %d: unknown compute mode %d", d->id, d->compute);
    /* Compute times are divided by the speed into int64 ns (plan.c): a tiny speed made them
     * infinite, and the conversion undefined. */
    if (!isfinite(d->speed) || d->speed < SKEL_MIN_SPEED || d->speed > SKEL_MAX_SPEED)
        return config_fail(reason, len, "DPU %d: speed %g outside %g..%g", d->id, d->speed, SKEL_MIN_SPEED,
                           (double)SKEL_MAX_SPEED);
    if (config_check_cpu(d, reason, len) != 0) return -1;
    if (cfg->network != SKELMSG_CONFIG_T_NETWORK_EMULATED && cfg->network != SKELMSG_CONFIG_T_NETWORK_KERNEL)
        return config_fail(reason, len, "network %d is neither emulated (0) nor kernel (1)", cfg->network);
    if (cfg->warmup_cycles < 0)
        return config_fail(reason, len, "warmup_cycles %d < 0", cfg->warmup_cycles);
    if (config_check_ids(cfg, reason, len) != 0) return -1;
    int64_t minor_us = config_minor_us(cfg, d);
    int nown = 0;
    int64_t out_bytes = 0;
    for (int i = 0; i < cfg->nprocesses; i++) {
        const skelmsg_process_t *p = &cfg->processes[i];
        if (p->dpu != d->id) continue;
        if (++nown > SKEL_MAX_PROCESSES)
            return config_fail(reason, len, "DPU %d: more than %d processes", d->id,
                               SKEL_MAX_PROCESSES);
        if (!tasking && minor_us < SKEL_MIN_PERIOD_US)
            return config_fail(reason, len, "DPU %d: minor_cycle_us %lld < %d", d->id,
                               (long long)minor_us, SKEL_MIN_PERIOD_US);
        if (config_check_process(cfg, d, minor_us, p, reason, len) != 0) return -1;
        for (int o = 0; tasking && o < i; o++)
            if (cfg->processes[o].dpu == d->id && cfg->processes[o].priority == p->priority)
                return config_fail(reason, len, "processes %d and %d of DPU %d have one priority %d",
                                   cfg->processes[o].id, p->id, d->id, p->priority);
        for (int q = 0; q < p->noutputs; q++) out_bytes += config_buffer(cfg, p->outputs[q])->bytes;
    }
    if (out_bytes > SKEL_MAX_DPU_BYTES)
        return config_fail(reason, len, "DPU %d: outputs total %lld bytes, limit %d", d->id,
                           (long long)out_bytes, SKEL_MAX_DPU_BYTES);
    if (config_check_events(cfg, d, reason, len) != 0) return -1;
    return config_check_links(cfg, d, reason, len);
}
