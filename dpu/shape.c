/* shape.c: a link's modelled network enforced by this host's kernel (run.network: kernel).
 * The reading DPU shapes what arrives for it, as its own emulation does (buffers.c): an ifb
 * device takes the link's groups from the ingress of the interface they arrive on; netem on
 * it delays, jitters and loses them, and a tbf under netem is the link's transmitter, which
 * every writer's messages queue for (contention). Where the kernel has no netem, nftables
 * loses them (without bursts) and the DPU emulates latency and jitter. Only a link whose
 * every writer is on another host can be shaped so: a message from this host never passes
 * an interface's ingress.
 * What a run applies is undone by a guard, a shell that waits for the DPU to close a pipe (the
 * run's end) or to die (even by SIGKILL), then removes it: nothing stays on the host. */
#include <errno.h>
#include <fcntl.h>
#include <signal.h>
#include <spawn.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/wait.h>
#include <unistd.h>

#include "dpu.h"

extern char **environ;

enum { SHAPE_CAN_IFB = 1, SHAPE_CAN_NETEM = 2, SHAPE_CAN_NFT = 4 };

/* CMD split at spaces (no argument of ours holds one), run to its end; 0 when it succeeded.
 * QUIET: its errors go to /dev/null (a probe's), else to the DPU's log. */
static int shape_run(const char *cmd, int quiet)
{
    char copy[SHAPE_CMD_LEN], *argv[64], *save = NULL;
    int n = 0;
    if (snprintf(copy, sizeof copy, "%s", cmd) >= (int)sizeof copy) return -1;
    for (char *t = strtok_r(copy, " ", &save); t != NULL && n < 63; t = strtok_r(NULL, " ", &save))
        argv[n++] = t;
    argv[n] = NULL;
    posix_spawn_file_actions_t fa;
    if (n == 0 || posix_spawn_file_actions_init(&fa) != 0) return -1;
    int ok = !quiet || (posix_spawn_file_actions_addopen(&fa, 1, "/dev/null", O_WRONLY, 0) == 0 &&
                        posix_spawn_file_actions_addopen(&fa, 2, "/dev/null", O_WRONLY, 0) == 0);
    pid_t pid;
    int spawned = ok && posix_spawnp(&pid, argv[0], &fa, NULL, argv, environ) == 0;
    posix_spawn_file_actions_destroy(&fa);
    if (!spawned) return -1;
    int st;
    while (waitpid(pid, &st, 0) < 0)
        if (errno != EINTR) return -1;
    return WIFEXITED(st) && WEXITSTATUS(st) == 0 ? 0 : -1;
}

/* What this host's kernel and tools can do for us, probed once: root, ifb and tc; netem;
 * nftables. A scratch ifb device is made and removed for it. */
static int shape_can(void)
{
    static int can = -1;
    if (can >= 0) return can;
    can = 0;
#ifdef FUZZING_BUILD_MODE_UNSAFE_FOR_PRODUCTION
    return can; /* a fuzzer's config never reaches the host's tc */
#endif
    if (geteuid() != 0) return can;
    char ifb[32], cmd[SHAPE_CMD_LEN];
    snprintf(ifb, sizeof ifb, "sklprobe%d", (int)getpid() % 1000000);
    snprintf(cmd, sizeof cmd, "ip link add %s type ifb", ifb);
    if (shape_run(cmd, 1) == 0) {
        can |= SHAPE_CAN_IFB;
        snprintf(cmd, sizeof cmd, "tc qdisc add dev %s root netem delay 1ms", ifb);
        if (shape_run(cmd, 1) == 0) can |= SHAPE_CAN_NETEM;
        snprintf(cmd, sizeof cmd, "ip link del %s", ifb);
        if (shape_run(cmd, 1) != 0) log_line("cannot remove the probe device %s: ip link del %s", ifb, ifb);
    }
    if (shape_run("nft list tables", 1) == 0) can |= SHAPE_CAN_NFT;
    return can;
}

/* The interface a group's datagrams arrive on: where its route leaves. */
static int shape_dev(uint32_t group, char *dev, size_t len)
{
    char cmd[96], line[512];
    snprintf(cmd, sizeof cmd, "ip -o route get %u.%u.%u.%u 2>/dev/null", group >> 24, group >> 16 & 255,
             group >> 8 & 255, group & 255);
    FILE *p = popen(cmd, "r");
    if (p == NULL) return -1;
    int found = -1;
    if (fgets(line, sizeof line, p) != NULL) {
        char *at = strstr(line, " dev ");
        if (at != NULL && sscanf(at + 5, "%15s", dev) == 1 && strlen(dev) < len) found = 0;
    }
    return pclose(p) == 0 ? found : -1;
}

/* Why link L cannot be shaped by the kernel for DPU (NULL: it can), its groups filled. */
static const char *shape_link_groups(skel_shape_link_t *k, const skelmsg_config_t *cfg, int16_t dpu,
                                     const skelmsg_link_t *l)
{
    const char *own = config_host(cfg, dpu);
    for (int i = 0; i < cfg->nbuffers; i++) {
        const skelmsg_buffer_desc_t *b = &cfg->buffers[i];
        uint32_t group;
        unsigned port;
        int ttl;
        if (b->link != l->id) continue;
        if (link_group_port(b->url, &group, &port, &ttl) != 0) return "not a udpm:// link";
        if (ttl == 0) return "ttl=0: it never leaves a host";
        const skelmsg_process_t *w = config_process(cfg, b->writer);
        if (own[0] == '\0' || strcmp(w != NULL ? config_host(cfg, w->dpu) : "", own) == 0)
            return "a writer on this host";
        for (int j = 0; j < cfg->nbuffers; j++) {
            uint32_t g2;
            unsigned p2;
            int t2;
            if (cfg->buffers[j].link != l->id &&
                link_group_port(cfg->buffers[j].url, &g2, &p2, &t2) == 0 && g2 == group)
                return "its group is another link's too";
        }
        /* its IP packet, as plan.c's wire_extra counts it */
        int frame = b->bytes + SKEL_BUFFER_HEADER_BYTES + SKEL_WIRE_LCM_HEADER_BYTES + (int)strlen(b->channel) + 1 +
                    SKEL_WIRE_UDP_IP_BYTES;
        if (frame > k->frame) k->frame = frame;
        int seen = 0;
        for (int g = 0; g < k->ngroups; g++) seen |= k->groups[g] == group && k->ports[g] == port;
        if (seen) continue;
        if (k->ngroups == SHAPE_MAX_GROUPS) return "more groups than the kernel path takes";
        k->groups[k->ngroups] = group;
        k->ports[k->ngroups++] = port;
    }
    return k->ngroups == 0 ? "no buffer on it" : NULL;
}

/* Appends to the text of array BUF, as far as it holds. */
#define SHAPE_ADD(buf, ...)                                                                       \
    do {                                                                                          \
        size_t u_ = strlen(buf);                                                                  \
        if (u_ < sizeof(buf)) snprintf((buf) + u_, sizeof(buf) - u_, __VA_ARGS__);                \
    } while (0)

/* Link L's decision for DPU: each modelled property enforced by the kernel or emulated. */
static void shape_link(skel_shape_t *sh, const skelmsg_config_t *cfg, int16_t dpu, const skelmsg_link_t *l)
{
    int delay = l->latency_us > 0 || l->jitter_us > 0, loss = l->loss_pct > 0 || l->burst_enter_pct > 0,
        rate = l->bandwidth_mbps > 0, bursts = l->burst_enter_pct > 0;
    if (!(delay || loss || rate) || !config_reads_link(cfg, dpu, l->id)) return;
    skel_shape_link_t *k = &sh->links[sh->n];
    memset(k, 0, sizeof *k);
    k->link = *l;
    const char *why = cfg->network != SKELMSG_CONFIG_T_NETWORK_KERNEL ? "run.network: emulated"
                      : clock_simulated()                               ? "simulated"
                                                                        : shape_link_groups(k, cfg, dpu, l);
    int can = why == NULL ? shape_can() : 0;
    if (why == NULL && can == 0) why = "not root, or no tc and nft here";
    if (why == NULL && shape_dev(k->groups[0], k->dev, sizeof k->dev) != 0) why = "no route to its group";
    if (why == NULL && strcmp(k->dev, "lo") == 0) why = "its group is routed on loopback";
    if (why == NULL) {
        if (rate && (can & SHAPE_CAN_IFB)) k->taken |= SHAPE_RATE;
        if (delay && (can & SHAPE_CAN_NETEM)) k->taken |= SHAPE_DELAY;
        if (loss && ((can & SHAPE_CAN_NETEM) || ((can & SHAPE_CAN_NFT) && !bursts))) k->taken |= SHAPE_LOSS;
        k->netem_loss = (k->taken & SHAPE_LOSS) && (can & SHAPE_CAN_NETEM);
    }
    uint32_t hash = 2166136261u; /* FNV-1a of the groups: every DPU of a host names it alike */
    for (int g = 0; g < k->ngroups; g++) hash = (hash ^ k->groups[g]) * 16777619u;
    snprintf(k->name, sizeof k->name, "skl%08x", hash);
    k->pref = (int)(1000 + hash % 30000);
    SHAPE_ADD(sh->text, "%slink %s:", sh->text[0] ? "; " : "", l->name);
    const char *sep = " ";
    if (rate) {
        SHAPE_ADD(sh->text, "%sbandwidth %s", sep, k->taken & SHAPE_RATE ? "tbf" : "emulated");
        sep = ", ";
    }
    if (loss) {
        SHAPE_ADD(sh->text, "%sloss %s", sep, !(k->taken & SHAPE_LOSS) ? "emulated" : k->netem_loss ? "netem" : "nft");
        sep = ", ";
    }
    if (delay) SHAPE_ADD(sh->text, "%slatency %s", sep, k->taken & SHAPE_DELAY ? "netem" : "emulated");
    if (k->taken & (SHAPE_RATE | SHAPE_DELAY) || k->netem_loss)
        SHAPE_ADD(sh->text, " (ifb %s from %s)", k->name, k->dev);
    else if (k->taken & SHAPE_LOSS)
        SHAPE_ADD(sh->text, " (nft table %s)", k->name);
    if (why != NULL) SHAPE_ADD(sh->text, ": %s", why);
    else if ((delay && !(k->taken & SHAPE_DELAY)) || (loss && !(k->taken & SHAPE_LOSS)))
        SHAPE_ADD(sh->text, ": %s", can & SHAPE_CAN_NETEM ? "" : "no netem in this kernel");
    sh->n++;
}

void shape_plan(skel_shape_t *sh, const skelmsg_config_t *cfg, int16_t dpu)
{
    memset(sh, 0, sizeof *sh);
    for (int i = 0; i < cfg->nlinks && sh->n < SKEL_MAX_LINKS; i++) shape_link(sh, cfg, dpu, &cfg->links[i]);
}

int shape_taken(const skel_shape_t *sh, int16_t link)
{
    for (int i = 0; i < sh->n; i++)
        if (sh->links[i].link.id == link) return sh->links[i].taken;
    return 0;
}

/* The guard: sh, in a session of its own and deaf to the signals that end a process group,
 * reads the pipe until the DPU closes it or dies, then runs UNDO. */
static int shape_guard(skel_shaper_t *sp, const char *undo)
{
    int fds[2];
    if (pipe2(fds, O_CLOEXEC) != 0) return -1;
    char script[SHAPE_SCRIPT_LEN + 64];
    snprintf(script, sizeof script, "trap '' HUP INT TERM QUIT; cat >/dev/null; %s", undo);
    char *argv[] = { "sh", "-c", script, NULL };
    posix_spawn_file_actions_t fa;
    posix_spawnattr_t at;
    sigset_t none;
    sigemptyset(&none);
    int ok = posix_spawn_file_actions_init(&fa) == 0;
    ok = ok && posix_spawn_file_actions_adddup2(&fa, fds[0], 0) == 0;
    ok = ok && posix_spawnattr_init(&at) == 0;
    ok = ok && posix_spawnattr_setflags(&at, POSIX_SPAWN_SETSID | POSIX_SPAWN_SETSIGMASK) == 0 &&
         posix_spawnattr_setsigmask(&at, &none) == 0;
    pid_t pid;
    ok = ok && posix_spawn(&pid, "/bin/sh", &fa, &at, argv, environ) == 0;
    posix_spawn_file_actions_destroy(&fa);
    posix_spawnattr_destroy(&at);
    close(fds[0]);
    if (!ok) {
        close(fds[1]);
        return -1;
    }
    sp->guard = pid;
    sp->fd = fds[1];
    return 0;
}

static int shape_exists(const char *fmt, const char *a)
{
    char cmd[SHAPE_CMD_LEN];
    snprintf(cmd, sizeof cmd, fmt, a);
    return shape_run(cmd, 1) == 0;
}

/* Whether DEV has an ingress qdisc already (tc shows the others' too: look for it). */
static int shape_ingress(const char *dev)
{
    char cmd[96], line[256];
    snprintf(cmd, sizeof cmd, "tc qdisc show dev %s ingress 2>/dev/null", dev);
    FILE *p = popen(cmd, "r");
    int found = 0;
    if (p == NULL) return 0;
    while (fgets(line, sizeof line, p) != NULL) found |= strncmp(line, "qdisc ingress", 13) == 0;
    return pclose(p) == 0 && found;
}

/* The commands that apply K (one per line into DO) and those that undo it (into UNDO, for
 * sh). A device or table that exists already is another DPU's of this host: left to it. */
static void shape_commands(const skel_shape_link_t *k, char (*cmds)[SHAPE_CMD_LEN], int *ncmds, char *undo,
                           size_t undo_len)
{
    const skelmsg_link_t *l = &k->link;
    char group[SHAPE_MAX_GROUPS][20];
    for (int g = 0; g < k->ngroups; g++)
        snprintf(group[g], sizeof group[g], "%u.%u.%u.%u", k->groups[g] >> 24, k->groups[g] >> 16 & 255,
                 k->groups[g] >> 8 & 255, k->groups[g] & 255);
    int ifb = (k->taken & (SHAPE_RATE | SHAPE_DELAY)) || k->netem_loss;
    size_t u = strlen(undo);
    if (ifb && !shape_exists("ip link show dev %s", k->name)) {
        snprintf(cmds[(*ncmds)++], SHAPE_CMD_LEN, "ip link add %s type ifb", k->name);
        snprintf(cmds[(*ncmds)++], SHAPE_CMD_LEN, "ip link set dev %s up", k->name);
        const char *parent = "root handle 1:";
        int netem = (k->taken & SHAPE_DELAY) || k->netem_loss;
        if (netem) {
            char *c = cmds[(*ncmds)++];
            snprintf(c, SHAPE_CMD_LEN, "tc qdisc add dev %s root handle 1: netem limit 100000", k->name);
            if (k->taken & SHAPE_DELAY) {
                SHAPE_ADD(cmds[*ncmds - 1], " delay %dus", l->latency_us);
                if (l->jitter_us > 0)
                    SHAPE_ADD(cmds[*ncmds - 1], " %dus%s", l->jitter_us,
                              l->jitter == SKELMSG_LINK_T_JITTER_NORMAL ? " distribution normal" : "");
            }
            if (k->netem_loss && l->burst_enter_pct > 0) /* Gilbert-Elliott: p r 1-h 1-k */
                SHAPE_ADD(cmds[*ncmds - 1], " loss gemodel %g%% %g%% %g%% %g%%", l->burst_enter_pct,
                          l->burst_leave_pct, l->burst_loss_pct, l->loss_pct);
            else if (k->netem_loss)
                SHAPE_ADD(cmds[*ncmds - 1], " loss random %g%%", l->loss_pct);
            parent = "parent 1:1 handle 10:";
        }
        if (k->taken & SHAPE_RATE) { /* a burst of one frame: the link sends one message at a time */
            char path[64];
            snprintf(path, sizeof path, "/sys/class/net/%s/mtu", k->dev);
            FILE *f = fopen(path, "r");
            int mtu = 1500;
            if (f != NULL) {
                if (fscanf(f, "%d", &mtu) != 1 || mtu < 576) mtu = 1500;
                fclose(f);
            }
            /* A frame arrives on the ifb with its Ethernet header, which the model does not
             * count: the size table takes it off, so tbf's bytes are the model's. Its queue: tbf
             * takes a frame while the bytes queued, its own with them, fit the limit; the model,
             * while the wait before it is at most queue_us. The two agree for the link's
             * largest frame: what it sends in queue_us, and that frame. */
            int frame = k->frame < mtu ? k->frame : mtu;
            snprintf(cmds[(*ncmds)++], SHAPE_CMD_LEN,
                     "tc qdisc add dev %s %s stab overhead -14 tbf rate %.0fbit burst %d limit %.0f", k->name,
                     parent, l->bandwidth_mbps * 1e6, mtu, l->bandwidth_mbps * l->queue_us / 8 + frame);
        }
        if (!shape_ingress(k->dev))
            snprintf(cmds[(*ncmds)++], SHAPE_CMD_LEN, "tc qdisc add dev %s handle ffff: ingress", k->dev);
        for (int g = 0; g < k->ngroups; g++)
            snprintf(cmds[(*ncmds)++], SHAPE_CMD_LEN,
                     "tc filter add dev %s parent ffff: protocol ip pref %d u32 match ip dst %s/32 "
                     "action mirred egress redirect dev %s", k->dev, k->pref, group[g], k->name);
        if (u < undo_len)
            u += (size_t)snprintf(undo + u, undo_len - u,
                                  "tc filter del dev %s parent ffff: pref %d 2>/dev/null; ip link del %s 2>/dev/null; "
                                  "tc filter show dev %s parent ffff: | grep -q . || "
                                  "tc qdisc del dev %s ingress 2>/dev/null; ",
                                  k->dev, k->pref, k->name, k->dev, k->dev);
    }
    if ((k->taken & SHAPE_LOSS) && !k->netem_loss && !shape_exists("nft list table inet %s", k->name)) {
        snprintf(cmds[(*ncmds)++], SHAPE_CMD_LEN, "nft add table inet %s", k->name);
        snprintf(cmds[(*ncmds)++], SHAPE_CMD_LEN,
                 "nft add chain inet %s in { type filter hook input priority -10 ; policy accept ; }", k->name);
        for (int g = 0; g < k->ngroups; g++)
            snprintf(cmds[(*ncmds)++], SHAPE_CMD_LEN,
                     "nft add rule inet %s in ip daddr %s udp dport %u numgen random mod 1000000 lt %.0f drop",
                     k->name, group[g], k->ports[g], l->loss_pct * 10000);
        if (u < undo_len) u += (size_t)snprintf(undo + u, undo_len - u, "nft delete table inet %s 2>/dev/null; ", k->name);
    }
}

int shape_apply(skel_shaper_t *sp, const skel_shape_t *sh, char *reason, size_t len)
{
    static char cmds[SKEL_MAX_LINKS * (7 + 2 * SHAPE_MAX_GROUPS)][SHAPE_CMD_LEN];
    static char undo[SHAPE_SCRIPT_LEN];
    int ncmds = 0;
    shape_remove(sp); /* a run's, if its end was never seen: undone before anything new */
    undo[0] = '\0';
    for (int i = 0; i < sh->n; i++)
        if (sh->links[i].taken) shape_commands(&sh->links[i], cmds, &ncmds, undo, sizeof undo);
    if (ncmds == 0) return 0;
    if (strlen(undo) + 1 >= sizeof undo || shape_guard(sp, undo) != 0) {
        snprintf(reason, len, "run.network: kernel: cannot start the guard that would undo it");
        return -1;
    }
    for (int i = 0; i < ncmds; i++) {
        if (shape_run(cmds[i], 0) == 0) continue;
        snprintf(reason, len, "run.network: kernel: `%.180s` failed on this host", cmds[i]);
        shape_remove(sp);
        return -1;
    }
    log_line("network applied by the kernel (%d commands; undone at the run's end): %s", ncmds, sh->text);
    return 0;
}

void shape_remove(skel_shaper_t *sp)
{
    if (sp->guard <= 0) return;
    close(sp->fd); /* the guard undoes it now */
    int st;
    while (waitpid(sp->guard, &st, 0) < 0 && errno == EINTR) {
    }
    sp->guard = 0;
}
