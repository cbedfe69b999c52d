/* swap.c: live reconfiguration at one cycle boundary. The control thread has
 * built the next plan (links open, every buffer allocated); the executive,
 * between two releases, calls these pure functions to pick the boundary and
 * to carry the run's state from the old plan into the next one. No allocation,
 * no system call: the unit tests drive them without a network.
 *
 * The rules (what a reader of the log or of a buffer sees):
 * - Where: the first point at or after the COMMIT's instant of the grid that
 *   every DPU's minor cycles share (their lcm from the run's start, or from the
 *   last switch; config_common_us), never a release that has already run: so
 *   DPUs with different minor cycles still switch at one instant. The next
 *   plan's grid starts there (its minor 0); minor indexes keep counting.
 * - Cycle counters (the buffers' seq) are kept by process id: a process that
 *   continues goes on from the cycle after its last release, re-anchored on its
 *   new period at the boundary, so its buffers' seq never goes back and skips
 *   nothing. A process new to this DPU takes the index of the boundary on its
 *   period's grid since the run's start: a process moved here from another DPU
 *   with the same period continues that DPU's seq exactly.
 * - Per input, what was last used carries over when the input still exists; a
 *   new input counts no drops for its first data. Slots keep their newest data.
 * - Sums, lockouts and the measured window carry over: warm-up is applied once
 *   per run (a process new at the boundary is measured at once when the
 *   window has started, else when it starts).
 * On the tasking executive (tasking.c) the boundary is the same grid point, and
 * jobs carry over too (swap_carry_tasking):
 * - A process that continues keeps its phase: its first release of the next
 *   plan is the first of its old grid at or after the boundary, then one per
 *   new period; its cycle index k goes on by one.
 * - Its job released before the boundary and not completed yet (waiting for
 *   data, ready, or started and maybe preempted) is carried whole: its release,
 *   what it has left to compute, its record so far (generation: the plan that
 *   released it; one not started yet draws the new compute when it starts).
 *   It completes under the next plan's priorities, is judged (slack, overrun,
 *   lockout) on its new period, and the next release waits for it, as any late
 *   job does. Releases of the old plan it is behind by stay
 *   owed at their old instants.
 * - A process new to this DPU releases on its period's grid since the run's
 *   start; a process removed loses its unfinished job, as at a run's end.
 * - A process still owed a release of the plan before the last one (a period
 *   behind across two switches) postpones the switch to the next grid point
 *   (swap_tasking_ready). */
#include <string.h>

#include "dpu.h"

static int64_t swap_ceil_div(int64_t a, int64_t b)
{
    return a <= 0 ? -(-a / b) : (a + b - 1) / b;
}

/* The old plan's minor index to switch at: the first on the common grid at or
 * after AT_MONO_NS (0: none given: the next release), and never one at or
 * before J_PREV (already run). */
int64_t swap_index(const skel_plan_t *plan, int64_t j_prev, int64_t at_mono_ns)
{
    int64_t j = j_prev + 1;
    if (at_mono_ns <= 0 || plan->minor_ns <= 0) return j;
    int64_t r = plan->common_ns > plan->minor_ns ? plan->common_ns / plan->minor_ns : 1;
    int64_t at = swap_ceil_div(at_mono_ns - plan->epoch_t0_ns, r * plan->minor_ns) * r;
    int64_t next = swap_ceil_div(j, r) * r;
    return at > next ? at : next;
}

int64_t swap_instant(const skel_plan_t *plan, int64_t j_sw)
{
    return plan->epoch_t0_ns + j_sw * plan->minor_ns;
}

static const skel_slot_t *swap_old_slot(const skel_plan_t *old, const skel_slot_t *slot)
{
    for (int i = 0; i < old->nslots; i++)
        if (old->slots[i].buffer == slot->buffer && old->slots[i].writer == slot->writer)
            return &old->slots[i];
    return NULL;
}

static void swap_carry_slots(skel_plan_t *next, const skel_plan_t *old)
{
    buffers_flush(old); /* what its buses heard is the old slots' before they are carried */
    /* A link's transmitter stays as busy across a switch as it was, with its count. */
    for (int k = 0; k < next->nbuses; k++)
        for (int j = 0; j < old->nbuses; j++)
            if (old->buses[j].link == next->buses[k].link) {
                next->buses[k].free_ns = old->buses[j].free_ns;
                next->buses[k].dropped = old->buses[j].dropped;
            }
    for (int i = 0; i < next->nslots; i++) {
        skel_slot_t *slot = &next->slots[i];
        const skel_slot_t *o = swap_old_slot(old, slot);
        buffers_slot_reset(slot);
        if (o == NULL) continue;
        slot->newest_seq = o->newest_seq;
        slot->newest_send_ns = o->newest_send_ns;
        slot->newest_recv_ns = o->newest_recv_ns;
        slot->received = o->received;
        slot->foreign = o->foreign;
        /* what reached the old plan's bus is not heard again, dropped there or not */
        slot->dup_upto = o->heard_seq > o->newest_seq ? o->heard_seq : o->newest_seq;
        buffers_slot_carry(slot, o);
    }
}

static const skel_input_t *swap_old_input(const skel_process_t *old, int16_t buffer)
{
    for (int q = 0; q < old->ninputs; q++)
        if (old->inputs[q].buffer == buffer) return &old->inputs[q];
    return NULL;
}

/* An input keeps its accounting only when its slot carried over too (same
 * buffer, same writer): otherwise its last used seq means nothing any more. */
static void swap_carry_inputs(skel_plan_t *next, skel_process_t *p, const skel_plan_t *old,
                              const skel_process_t *o)
{
    for (int q = 0; q < p->ninputs; q++) {
        skel_input_t *in = &p->inputs[q];
        const skel_input_t *oi = o != NULL ? swap_old_input(o, in->buffer) : NULL;
        int carried = swap_old_slot(old, &next->slots[in->slot]) != NULL;
        buffers_input_reset(in);
        if (oi != NULL && carried) {
            in->last_used = oi->last_used;
            in->received_seen = oi->received_seen;
            in->n_new = oi->n_new;
            in->n_stale = oi->n_stale;
            in->n_dropped = oi->n_dropped;
        } else {
            in->last_used = SKEL_SEQ_JOINED;
            in->received_seen = next->slots[in->slot].received;
        }
    }
}

static void swap_carry_process(skel_plan_t *next, skel_process_t *p, const skel_plan_t *old,
                               int64_t j_sw, int64_t t_sw)
{
    int i = plan_process_index(old, p->id);
    const skel_process_t *o = i >= 0 ? &old->processes[i] : NULL;
    p->locked_out = 0;
    p->sums = (skel_process_sums_t){ 0 };
    if (o != NULL) {
        /* Releases of the old plan before the boundary: minors 0 .. j_sw-1. */
        p->k_base = o->k_base + swap_ceil_div(j_sw, o->ratio);
        p->measure_from_k = o->measure_from_k;
        p->locked_out = o->locked_out;
        p->sums = o->sums;
        memcpy(p->draw.state, o->draw.state, sizeof p->draw.state); /* its draws go on */
    } else {
        draw_seed(&p->draw, next->seed, p->id);
        p->k_base = swap_ceil_div(t_sw - next->run_t0_ns, p->period_ns);
        int64_t warm = next->measure_from_ns - t_sw;
        p->measure_from_k = p->k_base + (warm > 0 ? swap_ceil_div(warm, p->period_ns) : 0);
    }
    swap_carry_inputs(next, p, old, o);
}

/* NEXT takes over from OLD at OLD's minor J_SW (from swap_index). OLD is only
 * read; NEXT's links are left alone (the caller drains them after). */
void swap_carry(skel_plan_t *next, const skel_plan_t *old, int64_t j_sw)
{
    int64_t t_sw = swap_instant(old, j_sw);
    next->run_id = old->run_id;
    next->run_t0_ns = old->run_t0_ns;
    next->epoch_t0_ns = t_sw;
    next->minor_base = old->minor_base + j_sw;
    next->clock_offset_ns = old->clock_offset_ns;
    next->publish_errors = old->publish_errors;
    next->measure_from_ns = old->measure_from_ns;
    next->work_drift_pct = old->work_drift_pct;
    next->sums = old->sums;
    swap_carry_slots(next, old);
    for (int i = 0; i < next->nprocesses; i++)
        swap_carry_process(next, &next->processes[i], old, j_sw, t_sw);
}

/* The tasking executive's (tasking.c): the local index of P's first release at or
 * after T (negative: on the grid of the plan before P's last switch). */
static int64_t swap_first_release(const skel_process_t *p, int64_t t)
{
    if (t <= p->job.anchor_ns) return -((p->job.anchor_ns - t) / p->job.back_period_ns);
    return swap_ceil_div(t - p->job.anchor_ns, p->period_ns);
}

/* 0 when some process of OLD still owes, before T_SW, a release of the plan
 * before OLD as well as some of OLD's own: one grid cannot hold both. */
int swap_tasking_ready(const skel_plan_t *old, int64_t t_sw)
{
    for (int i = 0; i < old->nprocesses; i++) {
        const skel_process_t *o = &old->processes[i];
        int64_t owed = o->next_k + (o->job.state != JOB_NONE); /* the first release not yet a job */
        if (owed < 0 && swap_first_release(o, t_sw) > 0) return 0;
    }
    return 1;
}

/* After swap_carry at the boundary T_SW of OLD: each process's jobs and grid. */
void swap_carry_tasking(skel_plan_t *next, const skel_plan_t *old, int64_t t_sw)
{
    for (int i = 0; i < next->nprocesses; i++) {
        skel_process_t *p = &next->processes[i];
        int j = plan_process_index(old, p->id);
        p->job.state = JOB_NONE;
        p->job.lockout_k = -1;
        p->job.back_period_ns = p->period_ns;
        p->job.back_generation = next->generation;
        if (j < 0) { /* swap_carry put k_base on its period's grid since the run's start */
            p->next_k = 0;
            p->job.anchor_ns = next->run_t0_ns + p->k_base * p->period_ns;
            if (p->event >= 0) p->job.release = INT64_MIN / 4; /* its first event is released when it comes */
            continue;
        }
        const skel_process_t *o = &old->processes[j];
        int64_t n = swap_first_release(o, t_sw);
        p->k_base = o->k_base + n;
        p->job.anchor_ns = job_release(o, n);
        p->job.back_period_ns = n > 0 ? o->period_ns : o->job.back_period_ns;
        p->job.back_generation = n > 0 ? old->generation : o->job.back_generation;
        p->next_k = o->next_k - n;
        p->job.state = o->job.state;
        p->job.lockout_k = o->job.lockout_k;
        p->job.missing = -1;
        p->job.generation = o->job.generation;
        p->job.release = o->job.release;
        p->job.remaining_ns = o->job.remaining_ns;
        p->job.slice_mono_ns = o->job.slice_mono_ns;
        p->job.rec = o->job.rec;
        if (p->job.state == JOB_WAITING && p->sync != SKELMSG_PROCESS_T_SYNC_DATA) p->job.state = JOB_READY;
        /* an event process's next release counts from its last event's (job_event_release) */
        if (p->event >= 0 && o->event < 0) p->job.release = INT64_MIN / 4;
    }
}

/* After swap_carry (and swap_carry_tasking) at the boundary T_SW of OLD: each event
 * process's queue and cycle count, by process id, and the event generators (event.c). */
void swap_carry_events(skel_plan_t *next, const skel_plan_t *old, int64_t t_sw)
{
    for (int i = 0; i < next->nprocesses; i++) {
        skel_process_t *p = &next->processes[i];
        int at = plan_process_index(old, p->id);
        event_carry_process(p, at >= 0 ? &old->processes[at] : NULL);
    }
    event_carry_sources(next, old, t_sw);
}
