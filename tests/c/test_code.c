/* test_code.c: real code in a process (dpu/code.c) with the example library
 * build/examples/libsum.so (examples/code/sum.c): a library is a name found only in
 * the DPU's --lib-dir, a path is refused; the step gets the bytes its writer sent and
 * its output is what it wrote; an output said to be longer than declared is a fault
 * and drops the cycle's outputs. Run from the repository's root (make test-c). */
#include "check.h"
#include "dpu.h"
#include "fixture.h"

static char reason[SKEL_REASON_LEN];
static const char *const examples[] = { "build/examples" };

/* DPU 2's process 2 reads b1 (1000 bytes, written by p1 on DPU 1) and writes b2. */
static void fixture_code(fixture_t *f, const char *function)
{
    fixture_init(f);
    f->procs[1].library = (char *)"sum";
    f->procs[1].function = (char *)function;
    f->procs[1].noutputs = 1;
    f->out[1][0] = 2;
    f->procs[2].noutputs = 0; /* p2 writes b2 now */
    f->buffers[1].writer = 2;
}

static void test_names_and_dirs(void)
{
    fixture_t f;
    fixture_code(&f, "sum_bytes");
    CHECK_EQ(config_validate(&f.cfg, 1, reason, sizeof reason), 0);
    const char *paths[] = { "../sum", "/usr/lib/sum", "a/b", ".hidden" };
    for (int i = 0; i < 4; i++) {
        f.procs[1].library = (char *)paths[i];
        CHECK(config_validate(&f.cfg, 1, reason, sizeof reason) != 0);
        CHECK_HAS(reason, "is a path or not a name");
    }
    fixture_code(&f, "");
    CHECK(config_validate(&f.cfg, 1, reason, sizeof reason) != 0);
    CHECK_HAS(reason, "needs both a library and a function");
    fixture_code(&f, "sum_bytes");
    f.dpus[1].executive = SKELMSG_DPU_T_EXECUTIVE_THREADS;
    f.procs[1].priority = 1;
    f.procs[2].priority = 2;
    CHECK(config_validate(&f.cfg, 1, reason, sizeof reason) != 0);
    CHECK_HAS(reason, "real code runs on the cyclic executive only");

    fixture_code(&f, "sum_bytes");
    CHECK(code_check(&f.cfg, 2, NULL, 0, reason, sizeof reason) != 0);
    CHECK_HAS(reason, "started without --lib-dir");
    const char *elsewhere[] = { "tests/c" };
    CHECK(code_check(&f.cfg, 2, elsewhere, 1, reason, sizeof reason) != 0);
    CHECK_HAS(reason, "libsum.so is not in this DPU's --lib-dir (tests/c)");
    CHECK_EQ(code_check(&f.cfg, 2, examples, 1, reason, sizeof reason), 0);
    CHECK_EQ(code_check(&f.cfg, 1, NULL, 0, reason, sizeof reason), 0); /* DPU 1 runs none */

    fixture_code(&f, "no_such_step");
    skel_plan_t *plan = plan_build(&f.cfg, 1, reason, sizeof reason);
    CHECK(plan != NULL);
    if (plan == NULL) return;
    CHECK(code_load(plan, &f.cfg, examples, 1, reason, sizeof reason) != 0);
    CHECK_HAS(reason, "no function no_such_step");
    plan_free(plan);
}

/* Cycle K of the plan's process 2 after its writer sent SEQ: the record the executive makes. */
static int64_t step_once(skel_plan_t *plan, skel_process_t *p, int64_t seq, const uint8_t *payload)
{
    skel_slot_t *slot = &plan->slots[p->inputs[0].slot];
    wire_buffer_hdr_t hdr = { plan->run_id, 1, 1, seq, 0, 1000 };
    CHECK_EQ(buffers_slot_receive(slot, plan->run_id, &hdr, payload, 0), BUFFERS_ACCEPTED);
    skel_rec_t rec;
    memset(&rec, 0, sizeof rec);
    buffers_input_peek(&p->inputs[0], slot, &rec.in[0]);
    buffers_input_commit(&p->inputs[0], slot, &rec.in[0], 1);
    return code_step(plan, p, &rec, seq + 100);
}

static uint64_t get_u64(const uint8_t *at)
{
    uint64_t v = 0;
    for (int i = 7; i >= 0; i--) v = v << 8 | at[i];
    return v;
}

static void test_step(void)
{
    fixture_t f;
    fixture_code(&f, "sum_bytes");
    skel_plan_t *plan = plan_build(&f.cfg, 1, reason, sizeof reason);
    CHECK(plan != NULL);
    if (plan == NULL) return;
    CHECK_EQ(code_load(plan, &f.cfg, examples, 1, reason, sizeof reason), 0);
    int index = plan_process_index(plan, 2);
    skel_process_t *p = &plan->processes[index];
    CHECK(p->code != NULL && plan->processes[plan_process_index(plan, 3)].code == NULL);
    if (p->code == NULL) return;
    plan_reset_run(plan, 9);
    CHECK_EQ(code_begin(plan, reason, sizeof reason), 0);
    CHECK(p->code->state != NULL); /* sum_bytes_init's */
    static uint8_t payload[1000];
    for (int round = 0; round < 3; round++) {
        uint64_t want = 0;
        for (int i = 0; i < 1000; i++) {
            payload[i] = (uint8_t)(i * (round + 1));
            want += payload[i];
        }
        CHECK(step_once(plan, p, 40 + round, payload) >= 0);
        CHECK_EQ(p->code->failed, 0);
        CHECK_EQ(p->code->out[0].nbytes, 16);
        CHECK_EQ(get_u64(p->code->out[0].bytes), 40 + round);
        CHECK_EQ(get_u64(p->code->out[0].bytes + 8), want);
        CHECK_EQ(p->code->in[0].is_new, 1);
    }
    code_end(plan);
    CHECK_EQ(p->code->started, 0);
    plan_free(plan);

    /* A step that says it wrote more than its output holds, and one that writes past its
     * output's end (into the guard after it) saying it did not: each cycle of either fails,
     * the guard restored in between (the second cycle is caught too). */
    const char *faulty[] = { "sum_overlong", "sum_past_end" };
    for (size_t i = 0; i < sizeof faulty / sizeof *faulty; i++) {
        fixture_code(&f, faulty[i]);
        plan = plan_build(&f.cfg, 1, reason, sizeof reason);
        CHECK(plan != NULL);
        if (plan == NULL) return;
        CHECK_EQ(code_load(plan, &f.cfg, examples, 1, reason, sizeof reason), 0);
        p = &plan->processes[plan_process_index(plan, 2)];
        plan_reset_run(plan, 9);
        CHECK_EQ(code_begin(plan, reason, sizeof reason), 0);
        (void)step_once(plan, p, 1, payload);
        (void)step_once(plan, p, 2, payload);
        CHECK_EQ(p->code->failed, 1);
        CHECK_EQ(p->code->faults, 2);
        code_end(plan);
        plan_free(plan);
    }
}

int main(void)
{
    test_names_and_dirs();
    test_step();
    return CHECK_DONE();
}
