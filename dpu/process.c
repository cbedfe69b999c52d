/* process.c: one cycle of one process, the paper's GCCP/SCCP: read inputs ->
 * (wait for required new data) -> compute -> write outputs, each step timed
 * into a timing record. A data-synchronised wait blocks the whole DPU thread
 * (the procedural model), and is where lockouts show up. */
#include <string.h>
#include <sys/resource.h>

#include "dpu.h"

/* How long after its release a cycle is locked out: INT64_MAX when never (no
 * rule, or a product past int64). */
static int64_t process_lockout_ns(const skel_plan_t *plan, const skel_process_t *p)
{
    if (plan->lockout_cycles <= 0 || plan->lockout_cycles > INT64_MAX / p->period_ns) return INT64_MAX;
    return plan->lockout_cycles * p->period_ns;
}

/* The instant a cycle released at RELEASE is locked out (saturated, never wraps). */
int64_t process_lockout_at(const skel_plan_t *plan, const skel_process_t *p, int64_t release)
{
    int64_t ns = process_lockout_ns(plan, p);
    return release > INT64_MAX - ns ? INT64_MAX : release + ns;
}

/* A lockout is the design's: the lateness the platform's stalls explain (the
 * thread could not run at all) does not count towards it. */
static int process_locked_out(const skel_exec_t *x, const skel_process_t *p, int64_t release,
                              int64_t now)
{
    return now - x->stall_debt_ns >= process_lockout_at(x->plan, p, release);
}

/* When a lockout due AT by the schedule is due on the clock: the stalls so far put
 * it that much later (a wait that woke at AT itself would find the process not yet
 * locked out, and wait with a timeout in the past, i.e. forever). */
static int64_t process_lockout_due(const skel_exec_t *x, int64_t at)
{
    return at > INT64_MAX - x->stall_debt_ns ? INT64_MAX : at + x->stall_debt_ns;
}

/* Recorded once per process per run (1 when new); the process keeps trying and may recover. */
static int process_lockout_record(skel_exec_t *x, skel_process_t *p, int16_t buffer,
                                  int16_t behind, int64_t k, int64_t release_ns)
{
    skel_server_t *s = x->s;
    if (p->locked_out) return 0;
    p->locked_out = 1;
    if (pthread_mutex_lock(&s->lock) != 0) return 1;
    if (s->nlockouts < SKEL_MAX_LOCKOUTS) {
        skelmsg_lockout_t *l = &s->lockouts[s->nlockouts++];
        l->process = p->id;
        l->buffer = buffer;
        l->behind = behind;
        l->cycle = k;
        l->release_ns = release_ns + s->clock_offset_ns;
    }
    pthread_mutex_unlock(&s->lock);
    server_fault(s, SKELMSG_STATUS_T_FAULT_LOCKOUT);
    server_wake(s->notify_fd);
    return 1;
}

void process_lockout(skel_exec_t *x, skel_process_t *p, int16_t buffer, int64_t k,
                     int64_t release_ns, const char *why)
{
    if (!process_lockout_record(x, p, buffer, -1, k, release_ns)) return;
    if (buffer >= 0)
        log_line("DPU %d: LOCKOUT process %d cycle %lld (waiting on buffer %d)", x->plan->dpu, p->id,
                 (long long)k, buffer);
    else
        log_line("DPU %d: LOCKOUT process %d cycle %lld (%s)", x->plan->dpu, p->id, (long long)k, why);
}

/* While P waits in minor J, the DPU's one thread runs nothing else: every other
 * process's oldest release not yet started ages. A process after P in the order
 * is due in J itself; one before it already ran in J and is next due after it.
 * Each that is past its lockout threshold is locked out, held up behind P (its
 * lockout names P, and no buffer: it is not waiting for data). Returns the next
 * instant one would be (INT64_MAX: none in this run). Releases as cyclic_minor
 * computes them: epoch_t0 + k * period. */
static int64_t process_held_up(skel_exec_t *x, const skel_process_t *p, int64_t j, int64_t now)
{
    skel_plan_t *plan = x->plan;
    const int me = (int)(p - plan->processes);
    int64_t next = INT64_MAX;
    for (int i = 0; i < plan->nprocesses; i++) {
        skel_process_t *q = &plan->processes[i];
        /* an event process without an event has nothing to be held up from */
        if (i == me || q->locked_out || q->event >= 0) continue;
        int64_t k = i > me ? (j + q->ratio - 1) / q->ratio : j / q->ratio + 1;
        int64_t release = plan->epoch_t0_ns + k * q->period_ns;
        if (release >= x->end_mono_ns) continue; /* not due in this run */
        int64_t at = process_lockout_at(plan, q, release);
        if (now - x->stall_debt_ns < at) {
            int64_t due = process_lockout_due(x, at);
            if (due < next) next = due;
            continue;
        }
        if (process_lockout_record(x, q, -1, p->id, q->k_base + k, release))
            log_line("DPU %d: LOCKOUT process %d cycle %lld (held up behind process %d, which "
                     "waits for data)", plan->dpu, q->id, (long long)(q->k_base + k), p->id);
    }
    return next;
}

void process_peek_inputs(const skel_plan_t *plan, const skel_process_t *p, skel_rec_t *rec)
{
    rec->ninputs = (int8_t)p->ninputs;
    buffers_flush(plan); /* what a bus heard, through its transmitter */
    /* What an emulated link held back and is due by now is the reader's from now on. */
    int64_t now = INT64_MIN;
    for (int q = 0; q < p->ninputs; q++) {
        skel_slot_t *slot = &plan->slots[p->inputs[q].slot];
        if (slot->pend_count == 0) continue;
        if (now == INT64_MIN) now = clock_mono_ns() + plan->clock_offset_ns;
        buffers_slot_advance(slot, now);
    }
    for (int q = 0; q < p->ninputs; q++)
        buffers_input_peek(&p->inputs[q], &plan->slots[p->inputs[q].slot], &rec->in[q]);
}

/* The first required input without new data, or -1 when all have it. */
int process_missing(const skel_process_t *p, const skel_rec_t *rec)
{
    for (int q = 0; q < p->ninputs; q++)
        if (p->inputs[q].required && !rec->in[q].new_data) return q;
    return -1;
}

/* The run's end (or a STOP) ends every wait: past it the writers have stopped, so
 * waiting on would only keep the DPU from reporting and becoming READY. */
static int process_should_stop(const skel_exec_t *x, int64_t now)
{
    if (atomic_load(&x->s->stop) || atomic_load(&x->s->quit)) return 1;
    return now >= x->end_mono_ns;
}

/* The thread was kept from running for NS in this cycle: the record says so, and the
 * lockout rule does not count it (process_locked_out). */
static void process_stalled(skel_exec_t *x, skel_rec_t *rec, int64_t ns)
{
    rec->stall_ns += ns;
    x->stall_debt_ns += ns;
    x->mark_charged_ns += ns;
}

/* The last look at the clocks of a data wait: wall and thread CPU time. */
typedef struct {
    int64_t mono_ns, cpu_ns;
} skel_look_t;

/* A stall between two looks of a data wait: the wall time between them that the
 * thread neither ran (reading its links) nor chose to wait. Checked against the
 * thread's CPU time only when the gap is long, so a large buffer read is work,
 * not a stall; a stopped or descheduled thread is. The lockouts a wait decides
 * rest on this: a machine that stopped while the DPU read its inputs must not
 * lock out the process that was reading. */
static void process_look(skel_exec_t *x, skel_rec_t *rec, skel_look_t *prev, int64_t now)
{
    int64_t gap = now - prev->mono_ns;
    if (gap <= x->s->compute.stall_ns) return;
    int64_t cpu = clock_thread_cpu_ns();
    int64_t off = gap - (cpu - prev->cpu_ns);
    if (off > x->s->compute.stall_ns) process_stalled(x, rec, off);
}

/* The thread's CPU time from its own clock (getrusage's lags by up to a tick for a
 * running thread), the waits it chose from getrusage. */
static int process_usage(int64_t *cpu_ns, long *chose_to_wait)
{
    struct rusage ru;
    if (getrusage(RUSAGE_THREAD, &ru) != 0) return -1;
    *chose_to_wait = ru.ru_nvcsw;
    *cpu_ns = clock_thread_cpu_ns();
    return 0;
}

static skel_mark_t process_mark(int64_t now)
{
    skel_mark_t m = { now, -1, 0, clock_stops() };
    if (process_usage(&m.cpu_ns, &m.chose_to_wait) != 0) m.cpu_ns = -1; /* not judged */
    return m;
}

/* A fresh mark: at the start of the steps that follow a wait the thread chose (the
 * executive's sleep until a release, a sleeping computation, a data wait), whose
 * voluntary switches would void any judgement across them. */
void process_remark(skel_exec_t *x, int64_t now)
{
    x->mark = process_mark(now);
    x->mark_charged_ns = 0;
    x->mark_stale = 0;
}

/* The time since the last mark that the thread did not run and did not choose to wait
 * (a stop of the process is no choice, though the kernel counts it as one), less the
 * stalls already charged since, at most MOST: a stall when over the threshold, else 0.
 * Marks anew at NOW, so no stall is charged twice. */
int64_t process_lost(skel_exec_t *x, int64_t now, int64_t most)
{
    int64_t cpu_ns;
    long chose_to_wait;
    if (process_usage(&cpu_ns, &chose_to_wait) != 0) return 0;
    const int64_t stops = clock_stops();
    const skel_mark_t was = x->mark;
    int64_t off = 0;
    if (was.cpu_ns >= 0 && !x->mark_stale && (chose_to_wait == was.chose_to_wait || stops != was.stops)) {
        off = (now - was.mono_ns) - (cpu_ns - was.cpu_ns) - x->mark_charged_ns;
        if (off > most) off = most;
        if (off <= x->s->compute.stall_ns) off = 0;
    }
    x->mark = (skel_mark_t){ now, cpu_ns, chose_to_wait, stops };
    x->mark_charged_ns = 0;
    x->mark_stale = 0;
    return off;
}

/* The executive slept until UNTIL, its release, and was on time: the stalls it owed are
 * paid, and a wake-up later than the stall threshold is a stall of its own. What follows
 * is judged from a mark taken here (process_gap). */
void process_woke(skel_exec_t *x, int64_t until)
{
    const int64_t now = clock_mono_ns();
    const int64_t late = now - until;
    x->wake_stall_ns = late > x->s->compute.stall_ns ? late : 0;
    x->stall_debt_ns = x->wake_stall_ns;
    process_remark(x, now);
}

/* From the last mark (the wake-up, the end of the process before) to a process's start
 * at NOW the executive only keeps its books, it never waits: what of a gap longer than
 * the stall threshold the thread was kept from running is this record's stall, and
 * lateness it explains. Uncharged, a DPU stopped right after waking on time ran 80 ms
 * behind as the design's flaw (test_a_stall_of_the_machine_is_not_a_lockout, CI). */
static void process_gap(skel_exec_t *x, int64_t now)
{
    const int64_t gap = now - x->mark.mono_ns;
    if (gap <= x->s->compute.stall_ns) return;
    const int64_t lost = process_lost(x, now, gap);
    x->wake_stall_ns += lost;
    x->stall_debt_ns += lost;
}

/* Reading inputs and publishing outputs run: a step (from STEP_FROM) that took
 * longer than the stall threshold while the thread did not run, and did not choose
 * to wait (a send blocked on a full socket buffer is communication; a stop of the
 * process is not), was a stall: the hypervisor or another thread had its CPU, or the
 * process was stopped. A short step cannot hide one, so it costs two clock reads and
 * no system call; a long one is judged against the last mark (process_lost), at most
 * the step's own length. Returns the stall charged: the platform's, not
 * communication, so the record keeps it in preempted_ns and the caller takes it out
 * of the step's comm_in_ns or comm_out_ns (% communicate is the design's; % overhead
 * holds the stalls). */
int64_t process_kept(skel_exec_t *x, skel_rec_t *rec, int64_t step_from, int64_t now)
{
    if (now - step_from <= x->s->compute.stall_ns) return 0;
    int64_t off = process_lost(x, now, now - step_from);
    if (off > 0) {
        process_stalled(x, rec, off);
        x->mark_charged_ns = 0; /* charged before the new mark */
        rec->preempted_ns += off;
    }
    return off;
}

/* Charges NS of a link's cost (plan.c) to the communicate step under way, emulated as the
 * DPU's compute mode emulates a computation (so SLEEP sleeps it, CPU spins it, and a
 * simulation charges it on virtual time). Returns the wall time the thread was kept from
 * running meanwhile (the platform's, in preempted_ns), which the step leaves out. */
static int64_t process_charge(skel_exec_t *x, skel_rec_t *rec, int64_t ns)
{
    if (ns <= 0) return 0;
    int64_t from = clock_mono_ns(), stall = 0;
    int64_t ran = compute_run(&x->s->compute, x->plan->compute, ns, &stall);
    process_stalled(x, rec, stall);
    x->mark_stale = 1; /* it may have slept: the steps after it are judged from a fresh mark */
    int64_t off = clock_mono_ns() - from - ran;
    if (off <= 0) return 0;
    rec->preempted_ns += off;
    return off;
}

/* What cycle REC's reading costs on its links: every cycle its remote reads, and each
 * message received since its last cycle on the inputs whose messages it pays for. */
static int64_t process_charge_in(const skel_process_t *p, const skel_rec_t *rec)
{
    int64_t ns = p->charge_in_ns;
    for (int q = 0; q < p->ninputs; q++) ns += p->inputs[q].message_ns * rec->in[q].received;
    return ns;
}

/* Waits for new data on every required input: 1 when the run ended or stopped
 * first. Cycle K (minor J of the plan) was released at RELEASE. Meanwhile the
 * processes it holds up are watched for lockout (process_held_up). */
static int process_wait_data(skel_exec_t *x, skel_process_t *p, int64_t k, int64_t release,
                             skel_rec_t *rec)
{
    skel_plan_t *plan = x->plan;
    const int64_t j = (k - p->k_base) * p->ratio;
    const int64_t lockout_at = process_lockout_at(plan, p, release);
    if (process_missing(p, rec) < 0) return 0;
    skel_look_t look = { clock_mono_ns(), clock_thread_cpu_ns() };
    x->mark_stale = 1; /* it waits: the steps after it are judged from a fresh mark */
    for (;;) {
        int missing = process_missing(p, rec);
        if (missing < 0) return 0;
        int64_t now = clock_mono_ns();
        process_look(x, rec, &look, now);
        if (process_should_stop(x, now)) return 1;
        if (process_locked_out(x, p, release, now)) {
            process_lockout(x, p, p->inputs[missing].buffer, k, release, "");
            rec->flags |= SKELMSG_TIMING_T_FLAG_LOCKOUT;
        }
        /* Wake for the next lockout to detect and for the run's end, polling at least every 10 ms. */
        int64_t wake = process_held_up(x, p, j, now);
        int64_t due = process_lockout_due(x, lockout_at);
        if (!p->locked_out && due < wake) wake = due;
        if (x->end_mono_ns < wake) wake = x->end_mono_ns;
        int64_t held = buffers_advance(plan, now); /* a version an emulated link holds back */
        if (held < wake) wake = held;
        int64_t timeout_ns = wake - now < 10 * 1000000LL ? wake - now : 10 * 1000000LL;
        if (timeout_ns < 0) timeout_ns = 0;
        int ready = link_wait(plan->links, plan->nlinks, x->s->wake_fd, timeout_ns);
        if (ready < 0) return 1;
        /* A poll that returned far later than its timeout, with data or without: the
         * thread was kept from running at least that long (data that came meanwhile is
         * no excuse: a stopped machine delivers it all at once when it resumes). */
        look = (skel_look_t){ clock_mono_ns(), clock_thread_cpu_ns() };
        int64_t late = look.mono_ns - now - timeout_ns;
        if (late > x->s->compute.stall_ns) process_stalled(x, rec, late);
        if (link_drain(plan->links, plan->nlinks) < 0) return 1;
        process_peek_inputs(plan, p, rec);
    }
}

/* Emulates cycle K's computation (REC's asked_ns) from NOW, and returns the compute it
 * reports. A cycle still computing at its lockout instant is locked out then, as the
 * definition says, not when it ends nor when its next cycle starts (a 300 ms computation
 * of a 10 ms process with a 100 ms window was named 200 ms late, and as cycle 1): the
 * computation runs in two calls, cut at that instant. A computation that ends before its
 * next release (lockout_cycles >= 1 periods from its release) cannot reach it: for it the
 * check is two additions and a comparison, no clock read, no system call, nothing
 * allocated. A stall in the first part moves the instant later (stalls do not count), so
 * the cut is taken again until the computation is done. */
static int64_t process_compute(skel_exec_t *x, skel_process_t *p, int64_t k, int64_t release,
                               skel_rec_t *rec, int64_t now)
{
    int64_t left = rec->asked_ns, computed = 0;
    for (;;) {
        int64_t part = left;
        if (!p->locked_out && now + left - x->stall_debt_ns >= release + p->period_ns) {
            const int64_t at = process_lockout_at(x->plan, p, release);
            if (now - x->stall_debt_ns >= at) { /* process_locked_out, AT worked out once */
                process_lockout(x, p, -1, k, release, "still computing");
                rec->flags |= SKELMSG_TIMING_T_FLAG_LOCKOUT;
            } else if (process_lockout_due(x, at) - now < part) {
                part = process_lockout_due(x, at) - now; /* > 0: not locked out yet */
            }
        }
        int64_t stall = 0;
        computed += compute_run(&x->s->compute, x->plan->compute, part, &stall);
        process_stalled(x, rec, stall);
        left -= part;
        if (left <= 0) return computed;
        now = clock_mono_ns();
    }
}

void process_write_outputs(skel_exec_t *x, skel_process_t *p, int64_t k)
{
    skel_plan_t *plan = x->plan;
    for (int q = 0; q < p->noutputs; q++) {
        skel_output_t *out = &p->outputs[q];
        int64_t send_ns = server_now(x->s);
        const uint8_t *payload = p->code != NULL ? p->code->out[q].bytes : plan->dummy;
        int32_t nbytes = p->code != NULL ? p->code->out[q].nbytes : out->bytes;
        int len = buffers_output_encode(out, plan->run_id, p->id, k, send_ns, payload, nbytes);
        int rc = len < 0 ? -1 : 0;
        if (rc == 0 && out->link >= 0)
            rc = clock_publish(plan->links[out->link].lcm, out->channel, out->enc, (unsigned)len);
        else if (rc == 0 && out->local_slot >= 0) {
            /* Local memory: the readers' slot is written directly, as common memory was. */
            wire_buffer_hdr_t hdr = { plan->run_id, p->id, out->buffer, k, send_ns, nbytes };
            rc = buffers_slot_receive(&plan->slots[out->local_slot], plan->run_id, &hdr, payload,
                                      server_now(x->s));
        }
        if (rc != 0 && plan->publish_errors++ == 0)
            log_line("DPU %d: process %d cannot publish buffer %d on %s", plan->dpu, p->id,
                     out->buffer, out->channel);
    }
    if (p->nemits > 0) event_emit(plan, p, server_now(x->s));
}

void process_commit(skel_plan_t *plan, skel_process_t *p, const skel_rec_t *rec, int measured)
{
    for (int q = 0; q < p->ninputs; q++)
        buffers_input_commit(&p->inputs[q], &plan->slots[p->inputs[q].slot], &rec->in[q],
                             measured);
}

/* Runs cycle K of P released at RELEASE (monotonic ns) in the run's minor
 * cycle MINOR, due to start at SCHED by the schedule, and fills REC (times
 * reported with the clock offset). The executive adds idle. */
/* A fresh record of cycle K of P started at START (times reported with the
 * clock offset); it carries the stall of the minor cycle's wake-up, if first. */
void process_record_begin(skel_exec_t *x, const skel_process_t *p, int64_t k, int64_t minor,
                          int64_t release, int64_t sched, int64_t start, skel_rec_t *rec)
{
    const int64_t off = x->s->clock_offset_ns;
    memset(rec, 0, offsetof(skel_rec_t, in));
    rec->process = p->id;
    rec->generation = x->plan->generation;
    rec->cycle = k;
    rec->minor = minor;
    rec->release_ns = release + off;
    rec->sched_ns = sched + off;
    rec->start_ns = start + off;
    rec->stall_ns = x->wake_stall_ns;
    x->wake_stall_ns = 0;
    rec->debt_ns = x->stall_debt_ns; /* the cyclic executive's; 0 on the others */
    rec->event_ns = p->queue.taken_ns >= 0 ? p->queue.taken_ns + off : -1;
    rec->event_queued = p->queue.taken_left;
    rec->event_dropped = p->queue.taken_dropped;
}

/* The end of cycle K's work: outputs written since T_OUT. Slack, overrun and the
 * measured sums (the release latency counts the cycle's start). */
void process_finish(skel_exec_t *x, skel_process_t *p, skel_rec_t *rec, int64_t release,
                    int64_t t_out, int measured)
{
    const int64_t off = x->s->clock_offset_ns;
    int64_t end = clock_mono_ns();
    int64_t start = rec->start_ns - off;
    p->queue.taken_ns = -1; /* its event is handled */
    rec->comm_out_ns = end - t_out;
    rec->slack_ns = release + p->period_ns - end;
    /* a tasking job locked out while it ran (job_lockout names its cycle): its record says so */
    if (rec->cycle == p->job.lockout_k) rec->flags |= SKELMSG_TIMING_T_FLAG_LOCKOUT;
    /* A cycle that completes after its lockout instant was locked out, whatever held it
     * (a computation the check between its parts did not see past, outputs, a tasking
     * job preempted): named now at the latest, not when its next cycle starts. Only a
     * cycle that ended past its next release can be (lockout_cycles >= 1): the others
     * skip working the instant out (a 64-bit division). */
    if (!p->locked_out && rec->slack_ns <= 0 && process_locked_out(x, p, release, end)) {
        process_lockout(x, p, -1, rec->cycle, release, "completed after its lockout instant");
        rec->flags |= SKELMSG_TIMING_T_FLAG_LOCKOUT;
    }
    if (rec->slack_ns < 0) {
        rec->flags |= SKELMSG_TIMING_T_FLAG_OVERRUN;
        atomic_fetch_add(&x->s->overruns, 1);
        server_fault(x->s, SKELMSG_STATUS_T_FAULT_OVERRUN);
    }
    if (measured) {
        skel_process_sums_t *sum = &p->sums;
        sum->cycles++;
        sum->overruns += rec->slack_ns < 0;
        sum->compute_ns += rec->compute_ns;
        sum->communicate_ns += rec->comm_in_ns + rec->comm_out_ns;
        sum->wait_ns += rec->blocked_ns;
        if (start - release > sum->max_latency_ns) sum->max_latency_ns = start - release;
    }
}

int process_cycle(skel_exec_t *x, skel_process_t *p, int64_t k, int64_t minor, int64_t release,
                  int64_t sched, skel_rec_t *rec)
{
    skel_plan_t *plan = x->plan;
    const int measured = k >= p->measure_from_k;
    int64_t start = clock_mono_ns();
    if (x->mark_stale) process_remark(x, start);
    else process_gap(x, start);
    process_record_begin(x, p, k, minor, release, sched, start, rec);
    if (process_locked_out(x, p, release, start)) {
        process_lockout(x, p, -1, k, release, "not run: its DPU is behind");
        rec->flags |= SKELMSG_TIMING_T_FLAG_LOCKOUT;
    }
    if (p->ninputs > 0) /* nothing to read: no system call */
        (void)link_drain(plan->links, plan->nlinks); /* an lcm error shows as stale inputs */
    process_peek_inputs(plan, p, rec);
    int64_t t_in = clock_mono_ns();
    rec->comm_in_ns = t_in - start - process_kept(x, rec, start, t_in);
    int stopped = p->sync == SKELMSG_PROCESS_T_SYNC_DATA && process_wait_data(x, p, k, release, rec);
    int64_t t_blocked = clock_mono_ns();
    rec->blocked_ns = t_blocked - t_in;
    if (stopped) {
        /* The partial cycle is recorded so its blocked time is not lost. */
        rec->flags |= SKELMSG_TIMING_T_FLAG_SKIPPED;
        rec->slack_ns = release + p->period_ns - t_blocked;
        return PROCESS_STOPPED;
    }
    /* The link's cost of reading, once what the cycle reads is known (after its data wait):
     * part of comm_in, as the prediction has it (host/model.py charges()). */
    int64_t charge = process_charge_in(p, rec);
    if (charge > 0) {
        int64_t kept = process_charge(x, rec, charge);
        int64_t now = clock_mono_ns();
        rec->comm_in_ns += now - t_blocked - kept;
        t_blocked = now;
    }
    process_commit(plan, p, rec, measured);
    if (p->code != NULL) {
        /* Real code: its compute is the call's wall time, asked of nobody. */
        rec->compute_ns = rec->asked_ns = code_step(plan, p, rec, k);
        if (p->code->failed) server_fault(x->s, SKELMSG_STATUS_T_FAULT_CODE);
    } else {
        rec->asked_ns = draw_ns(&p->draw, p->compute_ns);
        rec->compute_ns = process_compute(x, p, k, release, rec, t_blocked);
    }
    int64_t t_out = clock_mono_ns();
    /* A computation sleeps (a voluntary switch), or charges only the stalls that carried
     * it past its time: what it lost and still ended on time must not be billed to the
     * next long step. What follows is judged from a mark at its end, taken even when no
     * output follows: a DPU behind goes on to its next release without sleeping, and a
     * stop there is judged from this mark (cyclic_behind), else not at all. */
    if (rec->asked_ns > 0 || x->mark_stale) process_remark(x, t_out);
    /* What of the computation's wall time it did not compute: the platform's
     * (its stall), so that the record's parts add up to where its work ended. */
    if (t_out - t_blocked > rec->compute_ns) rec->preempted_ns += t_out - t_blocked - rec->compute_ns;
    int64_t kept_out = 0;
    if ((p->noutputs > 0 || p->nemits > 0) && (p->code == NULL || !p->code->failed)) {
        process_write_outputs(x, p, k);
        kept_out = process_kept(x, rec, t_out, clock_mono_ns());
        kept_out += process_charge(x, rec, p->charge_out_ns); /* the link's cost of publishing */
        if (x->mark_stale) process_remark(x, clock_mono_ns()); /* it may have slept: as a computation */
    }
    /* comm_out_ns runs from where publishing ended less its stall (in preempted_ns) */
    process_finish(x, p, rec, release, t_out + kept_out, measured);
    return PROCESS_DONE;
}
