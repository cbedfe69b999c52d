/* fuzz_command.c: configs and commands through command.c as the control thread hands
 * them over (command_handle_config, command_handle_command), in any order: staging,
 * refusing and applying generations (apply.c), START, STOP, COMMIT (between runs and
 * live), PING, RESEND and SHUTDOWN, who owns a run (owner.c), and the status each
 * leaves (report.c). An input is a sequence of frames (fuzz.h): tag even, a config;
 * odd, a command. Each input starts from a daemon as it starts (--id 1, nothing
 * configured); after each frame the server's state must hold together.
 *
 * No network: a config whose plan would open a socket (a link with a URL, an event
 * awaited, emitted or generated) is left out, as LCM would start a receive thread
 * for each; fuzz_config covers those configs up to the built plan. The status is
 * published on a real lcm_t, on a port below every test's (tests/conftest.py draws
 * blocks of ports from 10000) with ttl=0, so it never reaches another machine or a test. No
 * executive thread runs: a START leaves the run ARMED, as it is until its start. */
#include <limits.h>
#include <signal.h>
#include <stdio.h>
#include <string.h>
#include <unistd.h>

#include "fuzz.h"

#define FUZZ_CTL_URL "udpm://239.255.76.67:7599?ttl=0"
#define FUZZ_DPU 1

static skel_server_t server;
static skel_control_t control;

static void fuzz_setup(void)
{
    /* SHUTDOWN raises SIGTERM, which the daemon's main() takes with sigwait; here it
     * must not end the fuzzer (libFuzzer would stop at its first SHUTDOWN). */
    struct sigaction ignore = { .sa_handler = SIG_IGN };
    FUZZ_ASSERT(sigaction(SIGTERM, &ignore, NULL) == 0);
    FUZZ_ASSERT(server_init(&server) == 0);
    server.url = FUZZ_CTL_URL;
    snprintf(server.hostname, sizeof server.hostname, "fuzz");
    server.pid = (int32_t)getpid();
    char why[256];
    FUZZ_ASSERT(server_open(&server, why, sizeof why) == 0);
    FUZZ_ASSERT(control_init(&control, &server) == 0);
}

/* The server and control state as main() leaves them for `skel-dpu --id 1`, keeping
 * what server_init and control_init allocated (the ring, the history, the lcm_t). */
static void fuzz_reset(void)
{
    skel_server_t *s = &server;
    plan_free(s->plan);
    plan_free(s->next_plan);
    plan_free(s->retired);
    wire_free_config(s->staged);
    s->plan = s->next_plan = s->retired = NULL;
    s->staged = NULL;
    s->id_arg = FUZZ_DPU;
    s->dpu_id = FUZZ_DPU;
    s->state = SKELMSG_STATUS_T_STATE_UNCONFIGURED;
    s->generation = s->staged_generation = s->rejected_generation = 0;
    s->reject_reason[0] = '\0';
    s->staged_dpu_index = -1;
    s->apply_pending = 0;
    s->next_at_mono_ns = 0;
    s->next_generation = -1;
    memset(&s->run, 0, sizeof s->run);
    s->run_active = s->run_ended = 0;
    s->run_id = s->run_generation = s->run_session = 0;
    s->run_owner[0] = '\0';
    s->run_end_utc_ns = s->rejected_at_start = 0;
    s->applied_any = 0;
    s->nlockouts = 0;
    atomic_store(&s->stop, 0);
    atomic_store(&s->switch_seq, 0);
    atomic_store(&s->rejected, 0);
    atomic_store(&s->faults, 0);
    atomic_store(&s->minor_cycles, 0);
    atomic_store(&s->overruns, 0);
    atomic_store(&s->timing_batches, 0);
    uint64_t drained;
    while (read(s->wake_fd, &drained, sizeof drained) > 0) {
    } /* STOP's wake-ups */
    control.nseen = 0;
    memset(control.seen, 0, sizeof control.seen);
    control.ping_seq = -1;
    control.ping_t1_ns = control.ping_t2_ns = control.ping_t3_ns = 0;
    control.batch_seq = 0;
    control.status_due = 0;
    history_reset(&control.history, 0);
}

/* 1 when applying this config as DPU FUZZ_DPU would open a socket (see the top): a
 * process of ours that uses a buffer on a link with a URL (plan.c's links), awaits or
 * emits an event, or a generator of ours (event_open). As config.c finds them. */
static int fuzz_opens_socket(const uint8_t *msg, size_t len)
{
    skelmsg_config_t cfg;
    if (len > INT_MAX || wire_decode_config(msg, (int)len, &cfg) != 0) return 0;
    int opens = 0;
    for (int i = 0; i < cfg.nprocesses; i++) {
        const skelmsg_process_t *p = &cfg.processes[i];
        if (p->dpu != FUZZ_DPU) continue;
        opens |= p->sync == SKELMSG_PROCESS_T_SYNC_EVENT || p->nemits > 0;
        for (int q = 0; q < p->ninputs + p->noutputs; q++) {
            const skelmsg_buffer_desc_t *b = config_buffer(&cfg, q < p->ninputs ? p->inputs[q]
                                                                          : p->outputs[q - p->ninputs]);
            opens |= b != NULL && b->url[0] != '\0'; /* the URL on its writer's port */
        }
    }
    for (int i = 0; i < cfg.nevents; i++)
        opens |= cfg.events[i].kind != SKELMSG_EVENT_SOURCE_T_KIND_HOST && cfg.events[i].dpu == FUZZ_DPU;
    skelmsg_config_t_decode_cleanup(&cfg);
    return opens;
}

/* What the rest of the daemon relies on, whatever came. */
static void fuzz_check(void)
{
    skel_server_t *s = &server;
    FUZZ_ASSERT(s->state >= SKELMSG_STATUS_T_STATE_UNCONFIGURED && s->state <= SKELMSG_STATUS_T_STATE_RUNNING);
    FUZZ_ASSERT(memchr(s->reject_reason, '\0', sizeof s->reject_reason) != NULL);
    FUZZ_ASSERT(memchr(s->run_owner, '\0', sizeof s->run_owner) != NULL);
    /* A DPU left out of a newer generation drops its plan between runs (command_absent):
     * unconfigured, it still knows the last generation it applied. */
    FUZZ_ASSERT(!s->applied_any || (s->plan != NULL && s->plan->generation == s->generation) ||
                (s->plan == NULL && s->state == SKELMSG_STATUS_T_STATE_UNCONFIGURED && !s->run_active));
    FUZZ_ASSERT(s->applied_any || s->state == SKELMSG_STATUS_T_STATE_UNCONFIGURED);
    FUZZ_ASSERT(s->staged == NULL || s->staged->generation == s->staged_generation);
    FUZZ_ASSERT(s->next_plan == NULL || (s->run_active && s->next_plan->generation == s->next_generation));
    if (s->run_active) {
        FUZZ_ASSERT(s->state == SKELMSG_STATUS_T_STATE_ARMED && s->plan != NULL);
        FUZZ_ASSERT(s->run.start_mono_ns > 0 && s->run.end_mono_ns > s->run.start_mono_ns);
        FUZZ_ASSERT(s->run_end_utc_ns >= 0);
        FUZZ_ASSERT(s->next_at_mono_ns >= 0);
    }
}

int LLVMFuzzerTestOneInput(const uint8_t *data, size_t size)
{
    static int ready;
    if (!ready) {
        fuzz_setup();
        ready = 1;
    }
    fuzz_reset();
    fuzz_frames_t frames = { data, size };
    uint8_t tag;
    const uint8_t *msg;
    size_t len;
    while (fuzz_frame(&frames, &tag, &msg, &len)) {
        if (tag % 2 == 0 && !fuzz_opens_socket(msg, len)) command_handle_config(&control, msg, (int)len);
        else if (tag % 2 == 1) command_handle_command(&control, msg, (int)len);
        fuzz_check();
    }
    FUZZ_ASSERT(report_status_publish(&control) == 0);
    return 0;
}
