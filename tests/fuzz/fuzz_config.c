/* fuzz_config.c: a config_t as the control thread receives it, up to the plan it
 * becomes, with no thread and no socket: the length check and decode (wire.c), then
 * for every DPU it names, as that DPU (--id N) and for its host (--id auto): finding
 * ourselves and validating our part (config.c); and for a part that passes, what
 * applying it does short of opening links (plan.c, event.c): the plan, a run's reset,
 * the event generators' first instants, the URLs the links would open, the cyclic
 * executive's next releases, and a live switch into a second plan of the same config
 * (swap.c, swap_carry_events). */
#include <limits.h>
#include <string.h>

#include "fuzz.h"

/* What the executive computes from PLAN (built from CFG for DPU_INDEX), and with SWITCH_ a
 * live switch into a second plan of the same config; 1 when it switched. */
static int fuzz_plan(const skelmsg_config_t *cfg, int dpu_index, skel_plan_t *plan, int switch_)
{
    const int64_t t0 = 1000 * SKEL_NS_PER_S;
    char url[1024], reason[SKEL_REASON_LEN];
    int32_t asked;
    plan_reset_run(plan, FUZZ_RUN_ID);
    plan->run_t0_ns = plan->epoch_t0_ns = t0;
    event_generators_begin(plan, t0);
    for (int i = 0; i < plan->nsources; i++) FUZZ_ASSERT(plan->sources[i].next_ns >= t0);
    for (int i = 0; i < plan->nlinks; i++) {
        /* link_open hands it to liblcm, which opens any provider it names */
        FUZZ_ASSERT(strncmp(plan->links[i].url, "udpm://", 7) == 0);
        (void)link_url(&plan->links[i], url, sizeof url, &asked);
        FUZZ_ASSERT(asked >= 0);
    }
    for (int i = 0; i < plan->nevents; i++)
        FUZZ_ASSERT(strlen(plan->events[i].channel) <= LCM_MAX_CHANNEL_NAME_LENGTH);
    for (int i = 0; i < plan->nslots; i++) FUZZ_ASSERT(strlen(plan->slots[i].channel) <= LCM_MAX_CHANNEL_NAME_LENGTH);
    if (plan->tasking) return 0; /* its switch carries jobs a run has made: not here */
    int64_t j = -1;
    for (int n = 0; n < 4; n++) {
        int64_t next = cyclic_next_release(plan, j + 1);
        FUZZ_ASSERT(next > j);
        if (next == INT64_MAX) break;
        j = next;
    }
    if (!switch_) return 0;
    skel_plan_t *next = plan_build(cfg, dpu_index, reason, sizeof reason);
    if (next == NULL) return 0; /* out of memory: said, nothing built */
    plan_reset_run(next, FUZZ_RUN_ID);
    int64_t j_sw = swap_index(plan, j, t0 + SKEL_NS_PER_S);
    FUZZ_ASSERT(j_sw > j);
    swap_carry(next, plan, j_sw);
    swap_carry_events(next, plan, swap_instant(plan, j_sw));
    plan_free(next);
    return 1;
}

/* The DPU --id ID_ARG (or, -1, --id auto on HOSTNAME) finds itself; with PLAN_ it validates
 * its part, and a part that passes becomes its plan (fuzz_plan): 1 when it switched. */
static int fuzz_as(const skelmsg_config_t *cfg, int id_arg, const char *hostname, int plan_, int switch_)
{
    skel_self_t self;
    char reason[SKEL_REASON_LEN];
    if (config_find_self(cfg, id_arg, hostname, &self) != 0) {
        FUZZ_ASSERT(self.dpu_index == -1 && memchr(self.reason, '\0', sizeof self.reason) != NULL);
        return 0;
    }
    FUZZ_ASSERT(self.dpu_index >= 0 && self.dpu_index < cfg->ndpus);
    if (!plan_) return 0;
    if (config_validate(cfg, self.dpu_index, reason, sizeof reason) != 0) {
        FUZZ_ASSERT(reason[0] != '\0' && memchr(reason, '\0', sizeof reason) != NULL);
        return 0;
    }
    skel_plan_t *plan = plan_build(cfg, self.dpu_index, reason, sizeof reason);
    if (plan == NULL) return 0;
    FUZZ_ASSERT(plan->dpu == self.dpu_id && plan->nprocesses <= SKEL_MAX_PROCESSES);
    int switched = fuzz_plan(cfg, self.dpu_index, plan, switch_);
    plan_free(plan);
    return switched;
}

int LLVMFuzzerTestOneInput(const uint8_t *data, size_t size)
{
    skelmsg_config_t cfg;
    if (size > INT_MAX || wire_decode_config(data, (int)size, &cfg) != 0) return 0;
    (void)config_common_us(&cfg);
    /* Every DPU's part (one live switch per config: the same code for each). */
    int switched = 0;
    for (int i = 0; i < cfg.ndpus; i++) switched |= fuzz_as(&cfg, cfg.dpus[i].id, "", 1, !switched);
    if (cfg.ndpus > 0) (void)fuzz_as(&cfg, -1, cfg.dpus[0].host, 0, 0);
    (void)fuzz_as(&cfg, 1, "", 0, 0); /* an id it may not name */
    skelmsg_config_t_decode_cleanup(&cfg);
    return 0;
}
