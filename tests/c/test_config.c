/* test_config.c: finding our DPU in a config, the validation of our part (one
 * clear reason per refusal), and the plan built from a valid config. No
 * network: plan_open_links is not called. */
#include "check.h"
#include "dpu.h"
#include "fixture.h"

static char reason[SKEL_REASON_LEN];

static int validate(fixture_t *f, int dpu_index)
{
    reason[0] = '\0';
    return config_validate(&f->cfg, dpu_index, reason, sizeof reason);
}

static void test_find_self(void)
{
    fixture_t f;
    fixture_init(&f);
    skel_self_t self;
    CHECK_EQ(config_find_self(&f.cfg, 2, "whatever", &self), 0);
    CHECK_EQ(self.dpu_index, 1);
    CHECK_EQ(self.dpu_id, 2);
    CHECK(config_find_self(&f.cfg, 9, "alpha", &self) != 0);
    CHECK_HAS(self.reason, "DPU 9 is not in generation 7");
    CHECK_EQ(config_find_self(&f.cfg, -1, "beta", &self), 0);
    CHECK_EQ(self.dpu_id, 2);
    CHECK(config_find_self(&f.cfg, -1, "gamma", &self) != 0);
    CHECK_HAS(self.reason, "no DPU for host 'gamma'");
    f.dpus[1].host = (char *)"alpha";
    CHECK(config_find_self(&f.cfg, -1, "alpha", &self) != 0);
    CHECK_HAS(self.reason, "2 DPUs for host 'alpha'");
}

static void test_valid(void)
{
    fixture_t f;
    fixture_init(&f);
    CHECK_EQ(validate(&f, 0), 0);
    CHECK_EQ(validate(&f, 1), 0);
    /* minor_cycle_us 0: the gcd of our periods. */
    f.dpus[0].minor_cycle_us = 0;
    CHECK_EQ(validate(&f, 0), 0);
    CHECK_EQ(config_minor_us(&f.cfg, &f.dpus[0]), 10000);
    /* The grid both DPUs share: lcm(10 ms, 5 ms); none when it would be longer than 10 s. */
    CHECK_EQ(config_common_us(&f.cfg), 10000);
    f.dpus[1].minor_cycle_us = 23800;
    CHECK_EQ(config_common_us(&f.cfg), 1190000);
    f.dpus[1].minor_cycle_us = 9999991; /* a prime: the lcm is 100 s */
    CHECK_EQ(config_common_us(&f.cfg), 0);
    f.dpus[1].minor_cycle_us = 0;
}

#define REJECTS(setup, dpu_index, words)                 \
    do {                                                 \
        fixture_t f;                                     \
        fixture_init(&f);                                \
        setup;                                           \
        CHECK(validate(&f, dpu_index) != 0);             \
        CHECK_HAS(reason, words);                        \
    } while (0)

static void test_rejections(void)
{
    /* The tasking executive: priorities 1..99, one per process of a DPU, in every compute mode. */
    REJECTS(f.dpus[0].executive = SKELMSG_DPU_T_EXECUTIVE_THREADS, 0,
            "process 1: priority 0 (the tasking executive's: 1..99");
    REJECTS(f.dpus[0].executive = SKELMSG_DPU_T_EXECUTIVE_THREADS; f.procs[0].priority = 7;
            f.procs[3].priority = 8; f.procs[4].priority = 100, 0, "process 5: priority 100");
    REJECTS(f.dpus[0].executive = SKELMSG_DPU_T_EXECUTIVE_THREADS; f.procs[0].priority = 7;
            f.procs[3].priority = 7; f.procs[4].priority = 6, 0, "processes 1 and 4 of DPU 1 have one priority 7");
    REJECTS(f.procs[0].priority = 5, 0, "process 1: priority 5 (the tasking executive's: 1..99; the cyclic one's: 0)");
    /* A link's emulated transport */
    REJECTS(f.links[0].latency_us = -1, 0, "link 1: latency_us -1 or jitter_us 0 is negative");
    REJECTS(f.links[0].jitter = 2, 0, "link 1: unknown jitter 2");
    REJECTS(f.links[0].loss_pct = 100.5, 0, "link 1: a loss or burst percentage is outside 0..100");
    REJECTS(f.links[0].burst_leave_pct = -1, 0, "link 1: a loss or burst percentage is outside 0..100");
    {
        fixture_t f;
        fixture_init(&f);
        f.dpus[0].executive = SKELMSG_DPU_T_EXECUTIVE_THREADS;
        f.procs[0].priority = 9;
        f.procs[3].priority = 8;
        f.procs[4].priority = 7;
        CHECK_EQ(validate(&f, 0), 0);
        for (int8_t mode = SKELMSG_DPU_T_COMPUTE_WALL; mode <= SKELMSG_DPU_T_COMPUTE_WORK; mode++) {
            f.dpus[0].compute = mode; /* kernel-scheduled threads (threads.c) */
            CHECK_EQ(validate(&f, 0), 0);
        }
    }
    REJECTS(f.dpus[0].compute = 9, 0, "unknown compute mode 9");
    /* A link's costs: 0 .. MAX_LINK_COST, none on a local link (host/sysfile/schema.py says the same) */
    REJECTS(f.links[0].per_message_us = -1.0, 0, "link 1 (net): a cost outside 0..1000000, or one on a local link");
    REJECTS(f.links[0].push_byte_ns = 0.0 / 0.0, 0, "link 1 (net): a cost outside");
    REJECTS(f.links[0].per_byte_ns = 2e6, 0, "link 1 (net): a cost outside");
    REJECTS(f.links[1].remote_read_us = 5.0, 0, "link 2 (mem): a cost outside");
    REJECTS(f.dpus[0].cpu = 1000, 0, "cpu 1000 is not one this host lets it run on");
    REJECTS(f.dpus[0].speed = 0.0, 0, "DPU 1: speed 0 outside 0.001..1000");
    /* A speed so small that compute times / speed are no int64 of ns (UB in plan.c), or huge */
    REJECTS(f.dpus[0].speed = 1e-300, 0, "DPU 1: speed 1e-300 outside 0.001..1000");
    REJECTS(f.dpus[0].speed = 1e300, 0, "DPU 1: speed 1e+300 outside");
    REJECTS(f.dpus[0].speed = 0.0 / 0.0, 0, "DPU 1: speed");
    /* liblcm opens any provider a URL names: only multicast links reach a plan. */
    REJECTS(f.links[0].url = (char *)"file:///tmp/skel-fuzz.log?mode=w", 0,
            "buffer 1: link 1 (net) URL 'file:///tmp/skel-fuzz.log?mode=w' or 'udpm://239.255.76.67:7800?ttl=0' "
            "is not udpm://");
    REJECTS(f.links[0].url = (char *)"tcpq://localhost:7700", 1, "URL 'tcpq://localhost:7700' or");
    /* ... nor the URL on its writer's port that a buffer travels on, which is what a DPU opens */
    REJECTS(f.buffers[1].url = (char *)"tcpq://localhost:7700", 1, "or 'tcpq://localhost:7700' is not udpm://");
    REJECTS(f.buffers[2].url = (char *)"udpm://239.255.76.67:7802", 0,
            "buffer 3: on local link 2 but sent to 'udpm://239.255.76.67:7802'");
    /* A channel LCM would not publish: longer than LCM_MAX_CHANNEL_NAME_LENGTH. */
    REJECTS(f.buffers[0].channel = (char *)"SKEL_BUF_0123456789012345678901234567890123456789012345678901234", 0,
            "buffer 1: channel 'SKEL_BUF_0123456789012345678901234567890123456789012345678901234...' is "
            "longer than 63 characters");
    REJECTS(f.procs[0].period_us = 50, 0, "process 1: period_us 50 outside");
    REJECTS(f.procs[0].period_us = 12000, 0, "not a multiple of DPU 1's minor cycle 5000 us");
    REJECTS(f.out[0][0] = 77, 0, "process 1 uses unknown buffer 77");
    REJECTS(f.buffers[0].bytes = 5 * 1024 * 1024, 0, "buffer 1: bytes 5242880 outside");
    REJECTS(f.buffers[0].bytes = -1, 0, "buffer 1: bytes -1 outside");
    REJECTS(f.dpus[0].nlinks = 0, 0, "link 1 (net) is not in DPU 1's links");
    REJECTS(f.buffers[0].link = 5, 0, "buffer 1: unknown link 5");
    REJECTS(f.buffers[0].writer = 2, 0, "buffer 1 is written by process 2, not by process 1");
    REJECTS(f.procs[3].ninputs = 17, 0, "17 inputs");
    REJECTS(f.procs[1].dpu = 1; f.buffers[2].link = 2; f.in[1][0] = 3; f.procs[4].dpu = 2, 0,
            "buffer 3 is on a local link but process 5 uses it from DPU 2");
    REJECTS(f.procs[4].id = 1, 0, "process id 1 appears twice");
    REJECTS(f.buffers[1].id = 1, 0, "buffer id 1 appears twice");
    REJECTS(f.buffers[1].channel = (char *)"SKEL_BUF_b1"; f.buffers[1].url = f.buffers[0].url, 0,
            "share channel 'SKEL_BUF_b1'"); /* on one URL (one writer's port) a reader could not tell */
    REJECTS(f.buffers[0].channel = (char *)SKEL_STATUS_CHANNEL, 0, "SKEL_ control channel");
    REJECTS(f.in[3][1] = 2, 0, "process 4 reads buffer 2 twice");
    REJECTS(f.procs[1].sync = 3, 1, "process 2: unknown sync 3");
    /* sync: event: a name for a channel, a queue of 1..MAX_QUEUE, generators that make sense */
    REJECTS(f.procs[1].sync = SKELMSG_PROCESS_T_SYNC_EVENT; f.procs[1].event = (char *)"a.b";
            f.procs[1].queue = 1, 1, "process 2: event name 'a.b' is not a name");
    REJECTS(f.procs[1].sync = SKELMSG_PROCESS_T_SYNC_EVENT; f.procs[1].event = (char *)"go";
            f.procs[1].queue = 65, 1, "process 2: queue 65 outside 1..64");
    /* SKEL_EVENT_ + the name must be a channel LCM publishes: at most SKEL_MAX_NAME (52) characters. */
    {
        char name[SKEL_MAX_NAME + 2];
        memset(name, 'e', sizeof name - 1);
        name[SKEL_MAX_NAME + 1] = '\0';
        REJECTS(f.procs[1].sync = SKELMSG_PROCESS_T_SYNC_EVENT; f.procs[1].event = name; f.procs[1].queue = 1,
                1, "process 2: event name 'eeeeeeeeeeeeeeeeeeeeeeeeeeeeeeeeeeeeeeeeeeeeeeeeeeeee' is not a name");
        name[SKEL_MAX_NAME] = '\0';
        fixture_t f;
        fixture_init(&f);
        f.procs[1].sync = SKELMSG_PROCESS_T_SYNC_EVENT;
        f.procs[1].event = name;
        f.procs[1].queue = 1;
        CHECK_EQ(validate(&f, 1), 0);
    }
    char *emits[9] = { (char *)"a", (char *)"b", (char *)"c", (char *)"d", (char *)"e", (char *)"f",
                       (char *)"g", (char *)"h", (char *)"i" };
    REJECTS(f.procs[1].nemits = 9; f.procs[1].emits = emits, 1, "process 2: emits 9 events, limit 8");
    skelmsg_event_source_t src = { (char *)"tick", SKELMSG_EVENT_SOURCE_T_KIND_PERIODIC, 2, 1000, 500, 0.0, 0, 0 };
    REJECTS(f.cfg.nevents = 1; f.cfg.events = &src, 1, "event tick: period_us 1000, jitter_us 500");
    skelmsg_event_source_t poisson = { (char *)"tick", SKELMSG_EVENT_SOURCE_T_KIND_POISSON, 2, 0, 0, -1.0, 0, 0 };
    REJECTS(f.cfg.nevents = 1; f.cfg.events = &poisson, 1, "event tick: rate_hz -1 outside");
    /* A rate so small its exponential gaps overflow an int64 of ns (event.c), or huge */
    poisson.rate_hz = 1e-300;
    REJECTS(f.cfg.nevents = 1; f.cfg.events = &poisson, 1, "event tick: rate_hz 1e-300 outside 1e-06..1e+06");
    poisson.rate_hz = 2e6;
    REJECTS(f.cfg.nevents = 1; f.cfg.events = &poisson, 1, "event tick: rate_hz 2e+06 outside");
    poisson.rate_hz = SKEL_MIN_RATE_HZ;
    {
        fixture_t f;
        fixture_init(&f);
        f.cfg.nevents = 1;
        f.cfg.events = &poisson;
        CHECK_EQ(validate(&f, 1), 0);
    }
    skelmsg_event_source_t bursts = { (char *)"tick", SKELMSG_EVENT_SOURCE_T_KIND_BURSTS, 2, 1000, 0, 0.0, 5, 300 };
    REJECTS(f.cfg.nevents = 1; f.cfg.events = &bursts, 1, "a burst of 5 events 300 us apart does not fit");
    REJECTS(f.procs[1].compute_us = -1, 1, "compute_us -1 < 0");
    double one[1] = { 5.0 }, falling[3] = { 1.0, 3.0, 2.0 }, nan_at[2] = { 1.0, 0.0 / 0.0 };
    REJECTS(f.procs[1].nquantiles = 1; f.procs[1].quantiles_us = one, 1, "1 compute quantiles; 0 or 2..512");
    REJECTS(f.procs[1].nquantiles = 3; f.procs[1].quantiles_us = falling, 1,
            "compute quantile 2 (2 us) is not a non-decreasing time");
    REJECTS(f.procs[1].nquantiles = 2; f.procs[1].quantiles_us = nan_at, 1, "compute quantile 1");
    REJECTS(f.cfg.warmup_cycles = -1, 1, "warmup_cycles -1 < 0");
    REJECTS(f.dpus[1].minor_cycle_us = 50; f.procs[1].period_us = 100; f.procs[2].period_us = 100,
            1, "minor_cycle_us 50 < 100");
    /* Too many processes on one DPU. */
    {
        fixture_t f;
        fixture_init(&f);
        static skelmsg_process_t many[SKEL_MAX_PROCESSES + 1];
        for (int i = 0; i <= SKEL_MAX_PROCESSES; i++) {
            many[i] = f.procs[4];
            many[i].id = (int16_t)(100 + i);
            many[i].noutputs = 0;
        }
        f.cfg.processes = many;
        f.cfg.nprocesses = SKEL_MAX_PROCESSES + 1;
        CHECK(validate(&f, 0) != 0);
        CHECK_HAS(reason, "more than 64 processes");
    }
    /* Another DPU's mistakes are not ours: DPU 2 ignores a bad process of DPU 1. */
    {
        fixture_t f;
        fixture_init(&f);
        f.procs[4].period_us = 7;
        CHECK(validate(&f, 0) != 0);
        CHECK_EQ(validate(&f, 1), 0);
    }
}

/* DPU 1 writing the buffers of `urls` distinct URLs (every process moved to it, each
 * writing up to SKEL_MAX_IO buffers of a URL each), emitting an event or not. */
static int validate_urls(int urls, int events)
{
    static skelmsg_buffer_desc_t many[3 + 5 * SKEL_MAX_IO];
    static char url[3 + 5 * SKEL_MAX_IO][48], channel[3 + 5 * SKEL_MAX_IO][24];
    static char *emits[1] = { (char *)"tick" };
    fixture_t f;
    fixture_init(&f);
    memcpy(many, f.buffers, sizeof f.buffers);
    f.procs[1].dpu = f.procs[2].dpu = 1; /* all five on DPU 1: b1 and b2 are two URLs */
    f.procs[1].order = 3;
    f.procs[2].order = 4;
    int n = 3;
    for (int i = 0; i < 5 && n - 1 < urls; i++)
        for (skelmsg_process_t *p = &f.procs[i]; p->noutputs < SKEL_MAX_IO && n - 1 < urls; n++) {
            snprintf(url[n], sizeof url[n], "udpm://239.255.77.%d:%d?ttl=0", n, 7900 + n);
            snprintf(channel[n], sizeof channel[n], "SKEL_BUF_m%d", n);
            many[n] = (skelmsg_buffer_desc_t){ (int16_t)(n + 1), (char *)"m", 8, 1, url[n], p->id, channel[n] };
            f.out[i][p->noutputs++] = (int16_t)(n + 1);
        }
    CHECK_EQ(n - 1, urls); /* b1, b2 and the new ones */
    f.cfg.buffers = many;
    f.cfg.nbuffers = n;
    if (events) {
        f.procs[0].nemits = 1;
        f.procs[0].emits = emits;
    }
    return validate(&f, 0);
}

static void test_links_limit(void)
{
    CHECK_EQ(validate_urls(SKEL_MAX_LINKS, 0), 0);
    CHECK(validate_urls(SKEL_MAX_LINKS + 1, 0) != 0);
    CHECK_HAS(reason, "DPU 1: more than 64 links");
    /* Events travel on the control URL, which the DPU then opens as one link more. */
    CHECK_EQ(validate_urls(SKEL_MAX_LINKS - 1, 1), 0);
    CHECK(validate_urls(SKEL_MAX_LINKS, 1) != 0);
    CHECK_HAS(reason, "DPU 1: more than 64 links");
}

static void test_plan(void)
{
    fixture_t f;
    fixture_init(&f);
    f.dpus[0].speed = 2.0;
    CHECK_EQ(validate(&f, 0), 0);
    skel_plan_t *plan = plan_build(&f.cfg, 0, reason, sizeof reason);
    CHECK(plan != NULL);
    if (plan == NULL) return;
    CHECK_EQ(plan->dpu, 1);
    CHECK_EQ(plan->nprocesses, 3);
    /* Run order: p1 (order 0), p5 (order 1), p4 (order 2). */
    CHECK_EQ(plan->processes[0].id, 1);
    CHECK_EQ(plan->processes[1].id, 5);
    CHECK_EQ(plan->processes[2].id, 4);
    CHECK_EQ(plan->processes[0].ratio, 2);
    CHECK_EQ(plan->processes[1].ratio, 4);
    CHECK_EQ(plan->processes[0].compute_ns, 1000000); /* 2000 us at speed 2 */
    CHECK_EQ(plan->nslots, 2);
    CHECK_EQ(plan->nlinks, 2); /* the ports of its writer p1 (b1) and of p3, whose b2 p4 reads */
    CHECK_HAS(plan->links[0].url, ":7800?");
    CHECK_HAS(plan->links[1].url, ":7801?");
    skel_process_t *p5 = &plan->processes[1], *p4 = &plan->processes[2];
    CHECK_EQ(p5->outputs[0].link, -1);
    CHECK(p5->outputs[0].local_slot >= 0);
    CHECK_EQ(plan->slots[p5->outputs[0].local_slot].buffer, 3);
    CHECK_EQ(plan->slots[p4->inputs[0].slot].link, 1);
    CHECK_EQ(plan->processes[0].outputs[0].enc_len, wire_buffer_encoded_size(1000));
    /* Minor cycles with work: 0 (p1 p5 p4), 2 (p1 p4), 4 (all), ... never 1 or 3. */
    CHECK_EQ(cyclic_next_release(plan, 0), 0);
    CHECK_EQ(cyclic_next_release(plan, 1), 2);
    CHECK_EQ(cyclic_next_release(plan, 3), 4);
    plan_reset_run(plan, 9);
    CHECK_EQ(plan->run_id, 9);
    CHECK_EQ(plan->slots[0].newest_seq, -1);
    CHECK_EQ(plan->sums.first_release_ns, -1);
    plan_free(plan);
}

/* Each process's link costs, worked out once (host/model.py charges() says the same): the
 * writer per message, per byte and per byte for each other reading DPU; the reader per
 * remote input; the reading DPU per message received, paid by its fastest reader. */
static void test_plan_charges(void)
{
    fixture_t f;
    fixture_init(&f);
    f.links[0].per_message_us = 10;
    f.links[0].per_byte_ns = 1;
    f.links[0].push_byte_ns = 2;
    f.links[0].remote_read_us = 3;
    CHECK_EQ(validate(&f, 0), 0);
    skel_plan_t *plan = plan_build(&f.cfg, 0, reason, sizeof reason);
    CHECK(plan != NULL);
    if (plan == NULL) return;
    skel_process_t *p1 = &plan->processes[0], *p5 = &plan->processes[1], *p4 = &plan->processes[2];
    /* p1 writes b1 (1000 B), read on DPU 2 only: 10 us + (1 + 2 x 1 DPU) ns x 1000 B */
    CHECK_EQ(p1->charge_out_ns, 13000);
    CHECK_EQ(p1->charge_in_ns, 0);
    /* p5 writes b3 on the local link: nothing */
    CHECK_EQ(p5->charge_out_ns + p5->charge_in_ns + p5->charge_mean_ns, 0);
    /* p4 reads b2 (2000 B) from DPU 2 every 10 ms, written every 5 ms: a remote read, and two
     * messages a cycle of 10 us + 1 ns x 2000 B; b3 is local */
    CHECK_EQ(p4->charge_in_ns, 3000);
    CHECK_EQ(p4->inputs[0].message_ns, 12000);
    CHECK_EQ(p4->inputs[1].message_ns, 0);
    CHECK_EQ(p4->charge_mean_ns, 3000 + 2 * 12000);
    plan_free(plan);
    /* The tasking executive charges none yet: refused with the process named */
    f.dpus[0].executive = SKELMSG_DPU_T_EXECUTIVE_THREADS;
    f.procs[0].priority = 9;
    f.procs[3].priority = 8;
    f.procs[4].priority = 7;
    CHECK_EQ(validate(&f, 0), 0);
    CHECK(plan_build(&f.cfg, 0, reason, sizeof reason) == NULL);
    CHECK_HAS(reason, "DPU 1: the tasking executive charges no link costs (process 1)");
}

/* A link's socket is sized for the largest buffer on its URL (a writer's port), and only
 * asked for when the kernel's default would not hold it. */
static void test_link_recv_buf_size(void)
{
    fixture_t f;
    fixture_init(&f);
    char reason[SKEL_REASON_LEN], url[1024];
    int32_t asked = -1;
    skel_plan_t *plan = plan_build(&f.cfg, 0, reason, sizeof reason);
    CHECK(plan != NULL);
    if (plan == NULL) return;
    CHECK_EQ(plan->links[0].largest, wire_buffer_encoded_size(1000));
    CHECK_EQ(plan->links[1].largest, wire_buffer_encoded_size(2000));
    CHECK_EQ(link_url(&plan->links[1], url, sizeof url, &asked), 0);
    CHECK_EQ(asked, 0); /* 2 kB: the default holds it */
    CHECK(strstr(url, "recv_buf_size") == NULL);
    plan_free(plan);

    f.buffers[1].bytes = 1000000; /* written by p3 on DPU 2, read here: its port's socket grows */
    plan = plan_build(&f.cfg, 0, reason, sizeof reason);
    CHECK(plan != NULL);
    if (plan == NULL) return;
    int32_t want = wire_buffer_encoded_size(1000000) + SKEL_RECV_SLACK_BYTES;
    CHECK_EQ(link_url(&plan->links[1], url, sizeof url, &asked), 0);
    CHECK_EQ(asked, want);
    char expected[128];
    snprintf(expected, sizeof expected, "udpm://239.255.76.67:7801?ttl=0&recv_buf_size=%d", want);
    CHECK(strcmp(url, expected) == 0);
    CHECK_EQ(link_url(&plan->links[0], url, sizeof url, &asked), 0); /* p1's port: not at all */
    CHECK_EQ(asked, 0);
    /* A recv_buf_size the system file gives is the user's choice: kept as it is. */
    free(plan->links[1].url);
    plan->links[1].url = strdup("udpm://239.255.76.67:7799?recv_buf_size=4096");
    CHECK_EQ(link_url(&plan->links[1], url, sizeof url, &asked), 0);
    CHECK_EQ(asked, 0);
    CHECK(strcmp(url, "udpm://239.255.76.67:7799?recv_buf_size=4096") == 0);
    plan_free(plan);
}

/* The record URL (contract RECORD_OFFSET): the control URL's group and port one lower,
 * LCM's defaults for what is left out, the options kept; tests/unit/test_link.py holds the host's
 * record_url to the same cases. */
static void test_record_url(void)
{
    char url[128];
    CHECK_EQ(link_record_url("udpm://239.255.80.67:7667?ttl=0", url, sizeof url), 0);
    CHECK(strcmp(url, "udpm://239.255.80.66:7666?ttl=0") == 0);
    CHECK_EQ(link_record_url("udpm://239.1.0.0:9000", url, sizeof url), 0); /* the borrow crosses octets */
    CHECK(strcmp(url, "udpm://239.0.255.255:8999") == 0);
    CHECK_EQ(link_record_url("udpm://?ttl=1", url, sizeof url), 0);
    CHECK(strcmp(url, "udpm://239.255.76.66:7666?ttl=1") == 0);
    CHECK_EQ(link_record_url("udpm://239.255.0.9?ttl=1", url, sizeof url), 0);
    CHECK(strcmp(url, "udpm://239.255.0.8:7666?ttl=1") == 0);
    CHECK_EQ(link_record_url("udpm://239.255.0.9:?ttl=1", url, sizeof url), 0); /* ":" or ":0": LCM's port */
    CHECK(strcmp(url, "udpm://239.255.0.8:7666?ttl=1") == 0);
    CHECK_EQ(link_record_url("udpm://239.255.0.9:0", url, sizeof url), 0);
    CHECK(strcmp(url, "udpm://239.255.0.8:7666") == 0);
    CHECK_EQ(link_record_url("udpm://240.0.0.1:7667", url, sizeof url), -1); /* not a multicast group */
    CHECK_EQ(link_record_url("memq://", url, sizeof url), 0); /* no ports: the same URL */
    CHECK(strcmp(url, "memq://") == 0);
    CHECK_EQ(link_record_url("udpm://239.255.76.67:1", url, sizeof url), -1);
    CHECK_EQ(link_record_url("udpm://224.0.0.0:7667", url, sizeof url), -1); /* 223.255.255.255: not multicast */
    CHECK_EQ(link_record_url("udpm://239.255.76.300:7667", url, sizeof url), -1);
    CHECK_EQ(link_record_url("udpm://239.255.76:7667", url, sizeof url), -1);
    CHECK_EQ(link_record_url("udpm://239.255.80.67:7667?ttl=0", url, 20), -1);
}

/* run.network: kernel takes a link only where the kernel can shape it: never one that stays
 * on its host (ttl=0), nor one a writer on the reader's own host sends on; emulated, never. */
static void test_shape_decisions(void)
{
    fixture_t f;
    fixture_init(&f);
    f.links[0].bandwidth_mbps = 1;
    f.links[0].queue_us = 20000;
    f.links[0].loss_pct = 5;
    skel_shape_t sh;
    shape_plan(&sh, &f.cfg, 2);
    CHECK_EQ(sh.n, 1);
    CHECK_EQ(shape_taken(&sh, 1), 0);
    CHECK(strcmp(sh.text, "link net: bandwidth emulated, loss emulated: run.network: emulated") == 0);
    f.cfg.network = SKELMSG_CONFIG_T_NETWORK_KERNEL;
    shape_plan(&sh, &f.cfg, 2);
    CHECK(strstr(sh.text, ": ttl=0: it never leaves a host") != NULL);
    f.buffers[0].url = (char *)"udpm://239.255.76.67:7800?ttl=1";
    f.buffers[1].url = (char *)"udpm://239.255.76.67:7801?ttl=1";
    f.dpus[1].host = (char *)"alpha"; /* the writer of b2 (process 3) shares DPU 2's host */
    shape_plan(&sh, &f.cfg, 2);
    CHECK_EQ(shape_taken(&sh, 1), 0);
    CHECK(strstr(sh.text, ": a writer on this host") != NULL);
    shape_plan(&sh, &f.cfg, 1); /* DPU 1 reads b2 on it: its own decision */
    CHECK_EQ(sh.n, 1);
    f.links[0].bandwidth_mbps = 0;
    f.links[0].loss_pct = 0;
    shape_plan(&sh, &f.cfg, 2); /* nothing modelled: nothing to say */
    CHECK_EQ(sh.n, 0);
    CHECK_EQ(sh.text[0], '\0');
}

int main(void)
{
    test_find_self();
    test_valid();
    test_rejections();
    test_plan();
    test_shape_decisions();
    test_plan_charges();
    test_link_recv_buf_size();
    test_links_limit();
    test_record_url();
    return CHECK_DONE();
}
