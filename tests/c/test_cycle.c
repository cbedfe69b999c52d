/* test_cycle.c: the DPU's own window sums (cycle_account), which report_t
 * sends beside the analysis's figures (analysis/measure/metrics.py elapsed_ns). The
 * tasking executives sum jobs as they complete, so the sums must not depend on
 * that order. Plans are built from the fixture without opening links. */
#include "check.h"
#include "dpu.h"
#include "fixture.h"

#define MS (1000 * 1000LL)
#define T0 (1000 * MS)

static char reason[SKEL_REASON_LEN];

/* A completed cycle released at RELEASE that worked from START to END, then idled IDLE. */
static skel_rec_t cycle(int64_t release, int64_t start, int64_t end, int64_t idle)
{
    skel_rec_t rec;
    memset(&rec, 0, sizeof rec);
    rec.release_ns = release;
    rec.start_ns = start;
    rec.compute_ns = end - start;
    rec.idle_ns = idle;
    return rec;
}

static void account(skel_plan_t *plan, skel_rec_t rec)
{
    cycle_account(plan, &plan->processes[0], &rec, rec.release_ns, rec.start_ns + rec.compute_ns);
}

static void test_sums_span_the_earliest_release_to_the_latest_end_in_any_order(void)
{
    fixture_t f;
    fixture_init(&f);
    CHECK_EQ(config_validate(&f.cfg, 0, reason, sizeof reason), 0);
    skel_plan_t *plan = plan_build(&f.cfg, 0, reason, sizeof reason);
    CHECK(plan != NULL);
    if (plan == NULL) return;
    plan_reset_run(plan, 9);
    plan->measure_from_ns = T0;
    /* Completion order, as a preemptive executive sums them: a job released 1 ms into the
     * window preempts the one released at its start and completes first; the last to
     * complete ends before the idle that followed the long job did. */
    account(plan, cycle(T0 - 5 * MS, T0 - 5 * MS, T0 - 4 * MS, MS)); /* warm-up */
    account(plan, cycle(T0 + MS, T0 + MS, T0 + 2 * MS, 0));
    account(plan, cycle(T0, T0, T0 + 8 * MS, 4 * MS));
    account(plan, cycle(T0 + 9 * MS, T0 + 9 * MS, T0 + 10 * MS, MS));
    CHECK_EQ(plan->sums.first_release_ns, T0);
    CHECK_EQ(plan->sums.first_start_ns, T0);
    CHECK_EQ(plan->sums.end_ns, T0 + 12 * MS);
    CHECK_EQ(plan->sums.warmup_end_ns, T0 - 4 * MS);
    plan_free(plan);
}

int main(void)
{
    test_sums_span_the_earliest_release_to_the_latest_end_in_any_order();
    return CHECK_DONE();
}
