/* test_swap.c: the live switch of plans at one cycle boundary (swap.c): where
 * the boundary falls, and what carries over (cycle counters by process id,
 * per-input accounting, slots, sums, lockouts), what starts fresh (a process
 * or an input new to this DPU) and how duplicates from the old link are
 * dropped. Plans are built from the fixture without opening links. */
#include "check.h"
#include "dpu.h"
#include "fixture.h"

#define MS (1000 * 1000LL)
#define T0 (1000 * MS)

static char reason[SKEL_REASON_LEN];

static skel_plan_t *build(fixture_t *f)
{
    CHECK_EQ(config_validate(&f->cfg, 0, reason, sizeof reason), 0);
    skel_plan_t *plan = plan_build(&f->cfg, 0, reason, sizeof reason);
    CHECK(plan != NULL);
    return plan;
}

static skel_process_t *proc(skel_plan_t *plan, int16_t id)
{
    int i = plan_process_index(plan, id);
    return i >= 0 ? &plan->processes[i] : NULL;
}

static skel_slot_t *slot_of(skel_plan_t *plan, int16_t buffer)
{
    for (int i = 0; i < plan->nslots; i++)
        if (plan->slots[i].buffer == buffer) return &plan->slots[i];
    return NULL;
}

/* The old plan in a run started at T0, as if it had run for a while. */
static skel_plan_t *old_plan(void)
{
    fixture_t f;
    fixture_init(&f);
    skel_plan_t *plan = build(&f);
    if (plan == NULL) return NULL;
    plan_reset_run(plan, 9);
    plan->run_t0_ns = plan->epoch_t0_ns = T0;
    plan->measure_from_ns = T0 + 2 * 20 * MS; /* warm-up 2 x the longest period */
    plan->sums.first_release_ns = T0 + 40 * MS;
    plan->sums.compute_ns = 12345;
    plan->sums.minor_cycles = 33;
    skel_slot_t *b2 = slot_of(plan, 2), *b3 = slot_of(plan, 3);
    b2->newest_seq = 40;
    b2->received = 41;
    b2->newest_send_ns = 777;
    b3->newest_seq = 10;
    b3->received = 11;
    skel_process_t *p1 = proc(plan, 1), *p4 = proc(plan, 4);
    p1->sums.cycles = 20;
    p1->sums.overruns = 3;
    p1->locked_out = 1;
    p1->sums.compute_ns = 999;
    skel_input_t *in2 = &p4->inputs[0];
    CHECK_EQ(in2->buffer, 2);
    in2->last_used = 39;
    in2->received_seen = 40;
    in2->n_new = 30;
    in2->n_stale = 5;
    in2->n_dropped = 2;
    p4->inputs[1].last_used = 10;
    return plan;
}

/* Generation 8: p1 at 5 ms with more compute and a new input (buffer 2); p5
 * gone; p6 new, now writing the local buffer 3 that p4 reads. */
static skel_plan_t *next_plan(void)
{
    fixture_t f;
    fixture_init(&f);
    f.cfg.generation = 8;
    f.procs[0].period_us = 5000;
    f.procs[0].compute_us = 3000;
    f.procs[0].ninputs = 1;
    f.in[0][0] = 2;
    f.procs[4].id = 6;
    f.buffers[2].writer = 6;
    return build(&f);
}

static void test_index(void)
{
    skel_plan_t plan;
    memset(&plan, 0, sizeof plan);
    plan.epoch_t0_ns = T0;
    plan.minor_ns = 5 * MS;
    CHECK_EQ(swap_index(&plan, 10, 0), 11);                  /* no instant: the next release */
    CHECK_EQ(swap_index(&plan, 10, T0 + 3 * 5 * MS), 11);     /* in the past: the next release */
    CHECK_EQ(swap_index(&plan, 10, T0 + 10 * 5 * MS), 11);    /* minor 10 has run already */
    CHECK_EQ(swap_index(&plan, 10, T0 + 20 * 5 * MS), 20);    /* on the grid: that release */
    CHECK_EQ(swap_index(&plan, 10, T0 + 20 * 5 * MS + 1), 21); /* between: the next one */
    CHECK_EQ(swap_index(&plan, -1, T0 - 7 * MS), 0);          /* before the start: at the start */
    CHECK_EQ(swap_index(&plan, -1, 1), 0);
    CHECK_EQ(swap_instant(&plan, 21), T0 + 105 * MS);
    /* Another DPU runs 15 ms minor cycles: the switch waits for the 15 ms grid they share. */
    plan.common_ns = 15 * MS;
    CHECK_EQ(swap_index(&plan, 10, T0 + 20 * 5 * MS), 21);   /* 100 ms -> 105 ms, minor 21 */
    CHECK_EQ(swap_index(&plan, 10, T0 + 21 * 5 * MS), 21);   /* on the common grid: that one */
    CHECK_EQ(swap_index(&plan, 10, T0 + 3 * 5 * MS), 12);    /* in the past: next common point */
    CHECK_EQ(swap_index(&plan, 11, 0), 12);                  /* no instant: the next release */
    CHECK_EQ(swap_index(&plan, -1, T0 - 7 * MS), 0);
}

static void test_carry(void)
{
    skel_plan_t *old = old_plan(), *next = next_plan();
    if (old == NULL || next == NULL) return;
    swap_carry(next, old, 41); /* p1 and p4 (every 2 minors) ran 21 cycles: 0 .. 40 */
    CHECK_EQ(next->run_id, 9);
    CHECK_EQ(next->run_t0_ns, T0);
    CHECK_EQ(next->epoch_t0_ns, T0 + 205 * MS);
    CHECK_EQ(next->minor_base, 41);
    CHECK_EQ(next->measure_from_ns, T0 + 40 * MS);
    CHECK_EQ(next->sums.compute_ns, 12345);
    CHECK_EQ(next->sums.minor_cycles, 33);
    CHECK_EQ(next->sums.first_release_ns, T0 + 40 * MS);
    CHECK(proc(next, 5) == NULL);

    skel_process_t *p1 = proc(next, 1), *p4 = proc(next, 4), *p6 = proc(next, 6);
    CHECK(p1 != NULL && p4 != NULL && p6 != NULL);
    if (p1 == NULL || p4 == NULL || p6 == NULL) return;
    /* Continuing: the counter goes on, re-anchored on the new period (p1: 5 ms). */
    CHECK_EQ(p1->k_base, 21);
    CHECK_EQ(p1->ratio, 1);
    CHECK_EQ(p1->compute_ns, 3 * MS);
    CHECK_EQ(p1->measure_from_k, 2); /* warm-up not re-applied */
    CHECK_EQ(p1->locked_out, 1);     /* lockout state carries over */
    CHECK_EQ(p1->sums.cycles, 20);
    CHECK_EQ(p1->sums.overruns, 3);
    CHECK_EQ(p1->sums.compute_ns, 999);
    CHECK_EQ(p4->k_base, 21);
    /* New: the boundary's index on its period's grid since the run's start. */
    CHECK_EQ(p6->k_base, 11); /* ceil(205 ms / 20 ms) */
    CHECK_EQ(p6->measure_from_k, 11);
    CHECK_EQ(p6->sums.cycles, 0);

    /* Slots keep their data; the old link's copies are not received twice. */
    skel_slot_t *b2 = slot_of(next, 2), *b3 = slot_of(next, 3);
    CHECK_EQ(b2->newest_seq, 40);
    CHECK_EQ(b2->received, 41);
    CHECK_EQ(b2->newest_send_ns, 777);
    CHECK_EQ(b2->dup_upto, 40);
    wire_buffer_hdr_t h = { 9, 3, 2, 40, 0, 2000 };
    CHECK_EQ(buffers_slot_receive(b2, 9, &h, NULL, 1), BUFFERS_DUPLICATE);
    CHECK_EQ(b2->received, 41);
    /* Buffer 3 changed writer (p5 -> p6): nothing of p5's stream carries over. */
    CHECK_EQ(b3->newest_seq, -1);
    CHECK_EQ(b3->writer, 6);

    /* p4 still reads buffer 2: its accounting carries over. */
    skel_input_t *in2 = &p4->inputs[0], *in3 = &p4->inputs[1];
    CHECK_EQ(in2->last_used, 39);
    CHECK_EQ(in2->n_new, 30);
    CHECK_EQ(in2->n_stale, 5);
    CHECK_EQ(in2->n_dropped, 2);
    skel_in_rec_t rec;
    buffers_input_peek(in2, b2, &rec);
    CHECK_EQ(rec.new_data, 1);
    CHECK_EQ(rec.dropped, 0);
    CHECK_EQ(rec.received, 1);
    /* ... but not for buffer 3, whose writer changed: it joins afresh. */
    CHECK_EQ(in3->last_used, SKEL_SEQ_JOINED);
    buffers_input_peek(in3, b3, &rec);
    CHECK_EQ(rec.new_data, 0);
    /* p1's new input: what the slot holds is new to it, and nothing was dropped for it. */
    skel_input_t *j2 = &p1->inputs[0];
    CHECK_EQ(j2->last_used, SKEL_SEQ_JOINED);
    buffers_input_peek(j2, b2, &rec);
    CHECK_EQ(rec.new_data, 1);
    CHECK_EQ(rec.dropped, 0);
    CHECK_EQ(rec.received, 0);
    buffers_input_commit(j2, b2, &rec, 1);
    h.seq = 44;
    CHECK_EQ(buffers_slot_receive(b2, 9, &h, NULL, 2), BUFFERS_ACCEPTED);
    buffers_input_peek(j2, b2, &rec);
    CHECK_EQ(rec.dropped, 3); /* from now on, gaps count */
    /* The new grid starts at the boundary with every process due. */
    CHECK_EQ(cyclic_next_release(next, 0), 0);
    plan_free(old);
    plan_free(next);
}

/* A switch inside the warm-up: a new process is measured from where the DPU's
 * window starts; a continuing one keeps its own warm-up. */
static void test_carry_in_warmup(void)
{
    skel_plan_t *old = old_plan(), *next = next_plan();
    if (old == NULL || next == NULL) return;
    swap_carry(next, old, 3); /* t_sw = T0 + 15 ms, window from T0 + 40 ms */
    skel_process_t *p1 = proc(next, 1), *p6 = proc(next, 6);
    if (p1 == NULL || p6 == NULL) return;
    CHECK_EQ(p1->k_base, 2);  /* minors 0, 2 */
    CHECK_EQ(p1->measure_from_k, 2);
    CHECK_EQ(p6->k_base, 1);  /* ceil(15 / 20) */
    CHECK_EQ(p6->measure_from_k, 3); /* + ceil(25 / 20) */
    plan_free(old);
    plan_free(next);
}

/* Two switches in a row: counters keep going from wherever the last left them. */
static void test_chain(void)
{
    skel_plan_t *a = old_plan(), *b = next_plan(), *c = next_plan();
    if (a == NULL || b == NULL || c == NULL) return;
    swap_carry(b, a, 41);
    CHECK_EQ(proc(b, 1)->k_base, 21);
    swap_carry(c, b, 7); /* p1 at ratio 1 ran 7 more cycles in b */
    CHECK_EQ(proc(c, 1)->k_base, 28);
    CHECK_EQ(proc(c, 6)->k_base, 13); /* p6 (every 4 minors) ran at minors 0, 4: k 11, 12 */
    CHECK_EQ(c->minor_base, 48);
    CHECK_EQ(c->epoch_t0_ns, T0 + 240 * MS);
    plan_free(a);
    plan_free(b);
    plan_free(c);
}

/* The tasking executive's jobs at a switch at T0 + 205 ms (minor 41): p1's job
 * (k 20) is half computed, p4 is a release behind (its job k 19 waits, k 20 is
 * owed), p5's k 10 is done. Continuing processes keep their phase and carry
 * their job; releases they owe stay at their old instants; p6 is new. */
static void test_carry_tasking(void)
{
    skel_plan_t *old = old_plan(), *next = next_plan(), *third = next_plan();
    if (old == NULL || next == NULL || third == NULL) return;
    for (int i = 0; i < old->nprocesses; i++) {
        old->processes[i].job.anchor_ns = T0;
        old->processes[i].job.back_period_ns = old->processes[i].period_ns;
    }
    skel_process_t *o1 = proc(old, 1), *o4 = proc(old, 4), *o5 = proc(old, 5);
    o1->next_k = 20;
    o1->job.state = JOB_STARTED;
    o1->job.generation = 7;
    o1->job.release = T0 + 200 * MS;
    o1->job.remaining_ns = MS;
    o1->job.rec.cycle = 20;
    o1->job.rec.compute_ns = MS;
    o4->next_k = 19;
    o4->job.state = JOB_READY;
    o4->job.release = T0 + 190 * MS;
    o5->next_k = 11;
    const int64_t t_sw = swap_instant(old, 41);
    CHECK_EQ(t_sw, T0 + 205 * MS);
    CHECK_EQ(swap_tasking_ready(old, t_sw), 1);
    swap_carry(next, old, 41);
    swap_carry_tasking(next, old, t_sw);
    skel_process_t *p1 = proc(next, 1), *p4 = proc(next, 4), *p6 = proc(next, 6);
    CHECK_EQ(p1->k_base, 21);                /* k 20 carried: k 21 is its next release, ... */
    CHECK_EQ(p1->next_k, -1);
    CHECK_EQ(p1->job.anchor_ns, T0 + 210 * MS);  /* ... at its old grid's next point, then every 5 ms */
    CHECK_EQ(job_release(p1, 1), T0 + 215 * MS);
    CHECK_EQ(p1->job.state, JOB_STARTED);
    CHECK_EQ(p1->job.release, T0 + 200 * MS);
    CHECK_EQ(p1->job.generation, 7);
    CHECK_EQ(p1->job.remaining_ns, MS);
    CHECK_EQ(p1->job.rec.cycle, 20);
    CHECK_EQ(p1->job.rec.compute_ns, MS);
    CHECK_EQ(p4->k_base + p4->next_k, 19);   /* its waiting job, then k 20 owed at T0 + 200 ms */
    CHECK_EQ(p4->job.state, JOB_READY);
    CHECK_EQ(p4->job.back_generation, 7);        /* k 20 is generation 7's release */
    CHECK_EQ(job_release(p4, p4->next_k + 1), T0 + 200 * MS);
    CHECK_EQ(job_release(p4, 0), T0 + 210 * MS);
    CHECK_EQ(p6->k_base, 11);                /* on its 20 ms grid since the run's start */
    CHECK_EQ(p6->job.anchor_ns, T0 + 220 * MS);
    CHECK_EQ(p6->next_k, 0);
    CHECK_EQ(p6->job.state, JOB_NONE);
    /* Switching again before p4 has caught up: its owed k 20 and the next plan's own
     * releases do not fit one grid, so only a switch before T0 + 210 ms may happen. */
    CHECK_EQ(swap_tasking_ready(next, T0 + 207 * MS), 1);
    CHECK_EQ(swap_tasking_ready(next, T0 + 215 * MS), 0);
    swap_carry(third, next, 0);
    swap_carry_tasking(third, next, T0 + 207 * MS);
    skel_process_t *q4 = proc(third, 4);
    CHECK_EQ(q4->k_base + q4->next_k, 19);
    CHECK_EQ(job_release(q4, q4->next_k + 1), T0 + 200 * MS);
    CHECK_EQ(job_release(q4, q4->next_k + 2), T0 + 210 * MS);
    plan_free(old);
    plan_free(next);
    plan_free(third);
}

int main(void)
{
    test_index();
    test_carry();
    test_carry_in_warmup();
    test_chain();
    test_carry_tasking();
    return CHECK_DONE();
}
