/* link.c: the DPU's side of its communication links. One lcm_t per distinct
 * link URL its processes read or write, created when a config is applied (never
 * during a run) and used by the executive thread only. Buffer messages are
 * subscribed raw: the handler checks and reads the header in place (wire.c),
 * so nothing is allocated per message. */
#include <errno.h>
#include <limits.h>
#include <poll.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <unistd.h>

#include "dpu.h"

/* Handled messages per link per drain: a flood cannot hold a cycle forever. */
#define LINK_DRAIN_MAX 100000

static int64_t link_sysctl(const char *path, int64_t fallback)
{
    FILE *f = fopen(path, "r");
    long long v = fallback;
    if (f == NULL) return fallback;
    if (fscanf(f, "%lld", &v) != 1) v = fallback;
    fclose(f);
    return v;
}

/* The URL to open: LINK->url, asking for a receive buffer that holds its largest
 * message whole when the default would not (LCM's recv_buf_size, capped by the
 * kernel at net.core.rmem_max). A recv_buf_size the system file gives is kept.
 * Without it a large buffer's fragments overflow the socket and the message
 * never arrives; a machine that cannot grant enough is said in the log. */
int link_url(const skel_link_t *link, char *out, size_t len, int32_t *asked)
{
    *asked = 0;
    int64_t want = link->largest > 0 ? (int64_t)link->largest + SKEL_RECV_SLACK_BYTES : 0;
    int64_t dflt = link_sysctl("/proc/sys/net/core/rmem_default", 212992);
    int udpm = strncmp(link->url, "udpm://", 7) == 0;
    if (!udpm || strstr(link->url, "recv_buf_size=") != NULL || 2 * want <= dflt) {
        int n = snprintf(out, len, "%s", link->url);
        return n < 0 || (size_t)n >= len ? -1 : 0;
    }
    *asked = (int32_t)want;
    int n = snprintf(out, len, "%s%crecv_buf_size=%lld", link->url, strchr(link->url, '?') ? '&' : '?',
                     (long long)want);
    return n < 0 || (size_t)n >= len ? -1 : 0;
}

/* The group and port of a udpm URL, LCM's defaults filling what it leaves out, and
 * where its options start. 1: another provider (no group or port); -1: not
 * udpm://A.B.C.D:PORT[?options]. An empty URL is $LCM_DEFAULT_URL, else LCM's default. */
static int link_parse(const char **url, uint32_t *group, unsigned *port, const char **rest)
{
    if (*url == NULL || (*url)[0] == '\0') *url = getenv("LCM_DEFAULT_URL");
    if (*url == NULL || (*url)[0] == '\0') *url = SKEL_DEFAULT_URL;
    if (strncmp(*url, "udpm://", 7) != 0) return 1;
    unsigned g[4];
    if (sscanf(SKEL_DEFAULT_URL, "udpm://%u.%u.%u.%u:%u", &g[0], &g[1], &g[2], &g[3], port) != 5) return -1;
    const char *at = *url + 7;
    int used = 0;
    if (at[0] >= '0' && at[0] <= '9') {
        if (sscanf(at, "%u.%u.%u.%u%n", &g[0], &g[1], &g[2], &g[3], &used) != 4) return -1;
        at += used;
    }
    if (at[0] == ':') { /* as Python's urlsplit: ":" alone, or port 0, leaves LCM's port */
        unsigned given = 0;
        used = 1;
        if (at[1] >= '0' && at[1] <= '9' && sscanf(at, ":%u%n", &given, &used) != 1) return -1;
        if (given != 0) *port = given;
        at += used;
    }
    if (at[0] != '\0' && at[0] != '?' && at[0] != '/') return -1;
    *group = 0;
    for (int i = 0; i < 4; i++) {
        if (g[i] > 255) return -1;
        *group = *group << 8 | g[i];
    }
    *rest = at;
    return *port > 65535 || *group >> 28 != 0xE ? -1 : 0; /* a multicast group, 224.0.0.0/4 */
}

/* URL's group, port and ttl (LCM's default 0 when not given); -1: not a udpm:// URL. */
int link_group_port(const char *url, uint32_t *group, unsigned *port, int *ttl)
{
    const char *rest;
    if (link_parse(&url, group, port, &rest) != 0) return -1;
    const char *at = strstr(rest, "ttl=");
    *ttl = at != NULL && (at[-1] == '?' || at[-1] == '&') ? atoi(at + 4) : 0;
    return 0;
}

/* The record URL of CONTROL (contract: RECORD_OFFSET): its group and port each that much
 * lower, its options kept; host/sysfile/link.py's record_url says the same. Another provider's
 * URL is its own record URL. -1: CONTROL is not udpm://A.B.C.D:PORT[?options], or OUT
 * is too short. */
int link_record_url(const char *control, char *out, size_t len)
{
    uint32_t group;
    unsigned port;
    const char *rest, *url = control;
    int kind = link_parse(&url, &group, &port, &rest), n;
    if (kind < 0) return -1;
    if (kind > 0) {
        n = snprintf(out, len, "%s", url);
        return n < 0 || (size_t)n >= len ? -1 : 0;
    }
    if (port <= SKEL_RECORD_OFFSET || group < 0xE0000000u + SKEL_RECORD_OFFSET) return -1;
    group -= SKEL_RECORD_OFFSET;
    n = snprintf(out, len, "udpm://%u.%u.%u.%u:%u%s", group >> 24, group >> 16 & 255, group >> 8 & 255,
                 group & 255, port - SKEL_RECORD_OFFSET, rest);
    return n < 0 || (size_t)n >= len ? -1 : 0;
}

/* LINK->url was set when the plan was built; the lcm_t is made at apply time. */
int link_open(skel_link_t *link)
{
    char url[1024];
    int32_t asked;
    if (link_url(link, url, sizeof url, &asked) != 0) return -1;
    int64_t max = link_sysctl("/proc/sys/net/core/rmem_max", -1);
    if (asked > 0 && max >= 0 && max < asked)
        log_line("link %s: messages of up to %d bytes need a %d-byte socket receive buffer but "
                 "net.core.rmem_max is %lld: they may never arrive; on this host: "
                 "sysctl -w net.core.rmem_max=%d", link->url, link->largest, asked, (long long)max, asked);
    else if (asked > 0)
        log_line("link %s: socket receive buffer of %d bytes asked (recv_buf_size) for messages of up "
                 "to %d bytes", link->url, asked, link->largest);
    link->lcm = clock_open(url);
    if (link->lcm == NULL) return -1;
    /* Nothing received yet: LCM joins the group, binds the port and starts its receive
     * thread on the first subscription (link_subscribe_channel). A link we only write to
     * never does, so our own datagrams, looped back by the kernel for readers on this
     * host, wake no thread of ours: two wake-ups saved per buffer sent. */
    link->fd = -1;
    return 0;
}

void link_close(skel_link_t *link)
{
    if (link->lcm != NULL) clock_close(link->lcm);
    free(link->url);
    memset(link, 0, sizeof *link);
}

/* When RBUF reached the host on LINK: the receive stamp (UTC, us) tells when it
 * arrived, not when we drained it (monotonic ns, no later than now). Mapping UTC to
 * the monotonic clock jitters by microseconds from one reading to the next, so a
 * message received just after another could seem to come first: on one socket,
 * receipt order is arrival order, and no stamp goes before the previous one. */
int64_t link_arrival_ns(skel_link_t *link, const lcm_recv_buf_t *rbuf)
{
    int64_t now_mono = clock_mono_ns();
    int64_t recv = clock_utc_to_mono(rbuf->recv_utime * 1000, now_mono, clock_utc_ns());
    if (rbuf->recv_utime <= 0 || recv > now_mono) recv = now_mono;
    if (recv < link->last_arrival_ns) recv = link->last_arrival_ns;
    link->last_arrival_ns = recv;
    return recv;
}

/* A message received on SLOT's channel: checked, its header read in place, and
 * during a run taken into the slot. Apart from the subscription, so the fuzzer
 * (tests/fuzz/fuzz_buffer.c) drives exactly this with the bytes it makes. */
void link_receive(skel_slot_t *slot, const lcm_recv_buf_t *rbuf)
{
    skel_plan_t *plan = slot->plan;
    wire_buffer_hdr_t hdr;
    if (rbuf->data_size > INT_MAX ||
        wire_buffer_header(rbuf->data, (int)rbuf->data_size, &hdr) != 0) {
        atomic_fetch_add(plan->rejected, 1);
        return;
    }
    if (!plan->running) return; /* between runs: drained only to keep queues short */
    /* The payload follows the fixed header (wire_buffer_header checked its length). */
    const uint8_t *payload = (const uint8_t *)rbuf->data + SKEL_BUFFER_HEADER_BYTES;
    if (buffers_slot_receive(slot, plan->run_id, &hdr, payload, link_arrival_ns(&plan->links[slot->link], rbuf) +
                                                     plan->clock_offset_ns) ==
        BUFFERS_MISMATCH)
        atomic_fetch_add(plan->rejected, 1);
}

static void link_on_buffer(const lcm_recv_buf_t *rbuf, const char *channel, void *user)
{
    skel_slot_t *slot = user;
    /* The subscription regex is anchored and escaped; this is belt and braces. */
    if (strcmp(channel, slot->channel) != 0) return;
    link_receive(slot, rbuf);
}

/* lcm_subscribe takes a regular expression: escape everything but [A-Za-z0-9_]. */
static int link_channel_regex(const char *channel, char *out, size_t len)
{
    size_t w = 0;
    for (const char *p = channel; *p; p++) {
        int plain = (*p >= 'a' && *p <= 'z') || (*p >= 'A' && *p <= 'Z') ||
                    (*p >= '0' && *p <= '9') || *p == '_';
        if (w + 3 >= len) return -1;
        if (!plain) out[w++] = '\\';
        out[w++] = *p;
    }
    out[w] = '\0';
    return 0;
}

int link_subscribe(skel_link_t *link, skel_slot_t *slot)
{
    return link_subscribe_channel(link, slot->channel, link_on_buffer, slot);
}

int link_subscribe_channel(skel_link_t *link, const char *channel, lcm_msg_handler_t handler, void *user)
{
    char regex[512];
    if (link_channel_regex(channel, regex, sizeof regex) != 0) return -1;
    lcm_subscription_t *sub = clock_subscribe(link->lcm, channel, regex, handler, user);
    if (sub == NULL) return -1;
    if (link->fd < 0 && (link->fd = lcm_get_fileno(link->lcm)) < 0) return -1;
    /* LCM's default queue drops the newest past 30 messages: nothing may be lost here. */
    return lcm_subscription_set_queue_capacity(sub, 0) == 0 ? 0 : -1;
}

int link_drain(skel_link_t *links, int nlinks)
{
    int handled = 0;
    for (int i = 0; i < nlinks; i++) {
        if (links[i].fd < 0) continue; /* written only: lcm_handle would start receiving */
        for (int n = 0; n < LINK_DRAIN_MAX; n++) {
            int rc = clock_handle(links[i].lcm);
            if (rc < 0) return -1;
            if (rc == 0) break;
            handled++;
        }
    }
    return handled;
}

/* Waits up to TIMEOUT_NS (>= 0) until a link has a message or WAKE_FD is
 * signalled: >0 ready, 0 timeout. */
int link_wait(skel_link_t *links, int nlinks, int wake_fd, int64_t timeout_ns)
{
    if (clock_simulated()) { /* nothing wakes a simulated DPU but its links and its clock */
        lcm_t *lcms[SKEL_MAX_LINKS];
        int m = 0;
        for (int i = 0; i < nlinks; i++)
            if (links[i].fd >= 0) lcms[m++] = links[i].lcm;
        return clock_wait(lcms, m, timeout_ns < 0 ? 0 : timeout_ns);
    }
    struct pollfd fds[SKEL_MAX_LINKS + 1];
    int n = 0;
    for (int i = 0; i < nlinks; i++) fds[n++] = (struct pollfd){ .fd = links[i].fd, .events = POLLIN };
    if (wake_fd >= 0) fds[n++] = (struct pollfd){ .fd = wake_fd, .events = POLLIN };
    if (timeout_ns < 0) timeout_ns = 0;
    struct timespec ts = { .tv_sec = timeout_ns / SKEL_NS_PER_S, .tv_nsec = timeout_ns % SKEL_NS_PER_S };
    int rc = ppoll(fds, (nfds_t)n, &ts, NULL);
    if (rc < 0) return errno == EINTR ? 0 : -1;
    if (wake_fd >= 0 && (fds[n - 1].revents & POLLIN)) {
        uint64_t v;
        /* Consumed here; the stop/quit flags are what the caller checks. */
        if (read(wake_fd, &v, sizeof v) < 0 && errno != EAGAIN) return -1;
    }
    return rc;
}
