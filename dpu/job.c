/* job.c: a process's one job on the tasking executive, the state both of its forms
 * share (tasking.c runs the schedule itself in SLEEP, threads.c on kernel threads)
 * and a live switch carries over (swap.c): when its releases fall, the run's minor
 * cycle its records name, and when a job not completed is locked out. */
#include "dpu.h"

/* P's release K of this plan (K < 0: of the plan before a switch, swap.c). */
int64_t job_release(const skel_process_t *p, int64_t k)
{
    return p->job.anchor_ns + k * (k >= 0 ? p->period_ns : p->job.back_period_ns);
}

static int64_t job_floor_div(int64_t a, int64_t b)
{
    return a >= 0 ? a / b : -((-a + b - 1) / b);
}

/* An event process's next release: its oldest waiting event, or a period after its
 * last release when events come faster (INT64_MAX: none waits). */
int64_t job_event_release(const skel_process_t *p)
{
    int64_t at = event_oldest_ns(p), earliest = p->job.release + p->period_ns;
    if (at == INT64_MAX) return INT64_MAX;
    return at > earliest ? at : earliest;
}

/* The run's minor cycle P's job was released in (the records' frame). */
int64_t job_minor(const skel_plan_t *plan, const skel_process_t *p)
{
    return plan->minor_base + job_floor_div(p->job.release - plan->epoch_t0_ns, plan->minor_ns);
}

/* P's next release that is not a job yet (INT64_MAX: an event process none of whose
 * events waits). */
int64_t job_next_release(const skel_process_t *p)
{
    return p->event >= 0 ? job_event_release(p) : job_release(p, p->next_k);
}

/* P's oldest release not completed yet, and its cycle *K: its job's while it has one
 * (waiting for data or the processor, or started: a job that computes past its lockout
 * instant is locked out there, and the releases behind it are younger); else its next.
 * INT64_MAX: none (an event process no event waits for). Both tasking executives lock
 * out by it. */
static int64_t job_pending(const skel_process_t *p, int64_t *k)
{
    *k = p->k_base + p->next_k;
    return p->job.state != JOB_NONE ? p->job.release : job_next_release(p);
}

/* P's release not completed by its lockout instant, by NOW, is locked out, as on the
 * cyclic executive: waiting for data (naming the buffer), kept from the processor by
 * higher-priority work or by its own late jobs, or still computing. Returns NEXT, or
 * the instant P's lockout would be when sooner. */
int64_t job_lockout(skel_exec_t *x, skel_process_t *p, int64_t now, int64_t next)
{
    int64_t k, release = job_pending(p, &k);
    if (p->locked_out || release >= x->end_mono_ns) return next;
    int64_t at = process_lockout_at(x->plan, p, release);
    if (now < at) return at < next ? at : next;
    int missing = p->job.state == JOB_WAITING ? p->job.missing : -1;
    process_lockout(x, p, missing >= 0 ? p->inputs[missing].buffer : -1, k, release,
                    p->job.state == JOB_STARTED ? "still computing" : "not run: kept from the processor");
    p->job.lockout_k = k;
    return next;
}
