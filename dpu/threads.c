/* threads.c: the tasking executive (executive: threads) in compute modes CPU,
 * WALL and WORK, where the kernel does the scheduling. The DPU is still one
 * processor under fixed-priority preemptive scheduling, but a real one: each
 * process is a thread of its own, SCHED_FIFO at the process's priority, and all
 * of them are pinned to one CPU (the DPU's `cpu`, or the one its executive
 * thread was on), so a release of a higher-priority process preempts a lower
 * one in the kernel. Each thread loops: an absolute wait for its release (a
 * `sync: event` process: for its oldest event, at most one per period), a
 * `sync: data` wait for new data on its required inputs, inputs, the
 * computation in the DPU's mode (compute.c), outputs, its record. The state of
 * a process's one job lives in its skel_process_t (job, next_k: job.c) as on the
 * schedule tasking.c runs in SLEEP: so a live switch carries it over by the
 * same rules (swap.c).
 *
 * The executive thread becomes the watcher: moved off that CPU, it wakes at
 * the lockout instants (a job not completed lockout_cycles periods after its
 * release is locked out, as on the other executives: waiting for data, naming
 * the buffer, kept from the processor, or still computing), at STOP and at the run's end, when
 * it wakes every thread and joins them.
 *
 * What the threads share (the slots and links, the records' ring, the DPU's
 * sums, the processor's idle) is guarded by one mutex with priority
 * inheritance, held only to read inputs, write outputs and file a record: a
 * lower-priority process writing its outputs holds up a higher one that wants
 * to read for that long, as one bus would. Nothing is allocated once the run
 * started: the threads, their state and their eventfds are made before t0.
 *
 * A job's record: start_ns is when it got the processor for the first time
 * (for a data job: once its data came), sched_ns when the processor was its by
 * the schedule (its release or its data, or the completion before it), the
 * computation's compute_ns the time it ran (in CPU and WALL the wall time it
 * held the processor: a gap of more than the stall threshold between two looks
 * at the clock is time it was preempted, not computation; in WORK the wall time
 * of its chunks of work, less the excess of each chunk that took more than the
 * stall threshold beyond its work),
 * preempted_ns the time its computation did not run between its start and its
 * end, and preemptions the involuntary context switches of its thread during
 * the job (getrusage RUSAGE_THREAD). The kernel cannot tell the DPU who took
 * the processor: on a faithful run only the DPU's higher-priority processes
 * can. But a gap in a CPU or WALL computation during which its thread was not
 * switched out is not preemption: the machine stopped the CPU (a VM's vCPU
 * not running, a long interrupt). That part of preempted_ns is also the job's
 * stall_ns (the platform's, as on the other executives). In WORK it is
 * preempted_ns only.
 * Where SCHED_FIFO or the pinning is refused, the DPU says so once in its log
 * and the run's status and report carry FAULT_NOT_FAITHFUL: the kernel's
 * ordinary time sharing then stands in for the model.
 *
 * A live switch (COMMIT during a run) falls on the same grid point as on the
 * other executives. The watcher learns of it, publishes its instant, and from
 * then on a thread whose next release is at or after it waits for it; at the
 * instant the watcher takes the lock, carries the run into the next plan
 * (cycle_switch) and hands each thread its process there by id: a job in
 * progress completes under its new priority and writes to the next plan's
 * buffers; a removed process's thread drops its job and ends (demoted to
 * SCHED_IDLE meanwhile, so its computation takes the processor from nobody);
 * a new process gets a thread then, the one allocation of a run after t0. */
#include <errno.h>
#include <poll.h>
#include <sched.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/eventfd.h>
#include <sys/sysinfo.h>
#include <unistd.h>

#include "dpu.h"

#define THREADS_PIECE_NS (50 * 1000 * 1000LL) /* a wait looks at the run's end this often */

struct threads;

typedef struct {
    struct threads *t;
    skel_process_t *p;             /* its process in the current plan (lock); NULL: removed */
    int16_t id;                    /* the process's id: a live switch finds it in the next plan by it */
    skel_exec_t x;                 /* this thread's own: record_begin and finish read it */
    pthread_t tid;
    int live;                      /* its thread runs or is to be joined */
    int kick_fd;                   /* eventfd: new data or an event, a switch, the run's end */
    int waiting;                   /* in a wait on the links (lock): what another drains wakes it */
    int64_t ready_ns;              /* its data job's data came (lock) */
    int64_t woke_ns;               /* its last wake-up from a wait, before it took the lock */
    skel_rec_t rec;                /* the job's record */
} threads_worker_t;

struct threads {
    skel_server_t *s;
    skel_plan_t *plan;             /* the current plan (lock): a live switch replaces it */
    pthread_mutex_t lock;          /* priority inheritance: the plan, its slots and links, the ring, below */
    int lock_ok;
    int done_fd;                   /* eventfd, written once at the end and never read */
    atomic_int done;
    int64_t switch_at;             /* a pending live switch's instant, INT64_MAX none (lock) */
    int64_t switch_j;              /* ... its minor on the current plan's grid */
    int64_t switch_seq;            /* the COMMIT it is for */
    int cpu;                       /* the processor: every thread is pinned to it */
    int faithful;
    cpu_set_t watcher_was;         /* the executive thread's affinity before the run */
    int watcher_moved;
    /* the processor, under lock */
    int active;                    /* jobs started and not complete */
    int64_t last_end_ns;           /* the latest completion */
    int idle_pending;              /* the last job to complete left the processor idle ... */
    skel_process_t *idle_p;        /* ... its record waits for the idle's end */
    skel_rec_t idle_rec;
    int nworkers;                  /* slots used: a removed process's, once its thread ended, is reused */
    threads_worker_t w[SKEL_MAX_PROCESSES * 2]; /* a switch's new threads start while removed ones end */
};

static int threads_eventfd(void) { return eventfd(0, EFD_NONBLOCK | EFD_CLOEXEC); }

/* The lock cannot fail short of a bug (it is never taken twice by one thread):
 * the DPU stops loudly rather than run on with its state unguarded. */
static void threads_lock(threads_t *t)
{
    int rc = pthread_mutex_lock(&t->lock);
    if (rc == 0) return;
    log_line("DPU %d: the tasking executive's lock failed (%s)", t->plan->dpu, strerror(rc));
    abort();
}

static void threads_unlock(threads_t *t) { (void)pthread_mutex_unlock(&t->lock); }

static void threads_free(threads_t *t)
{
    for (int i = 0; i < (int)(sizeof t->w / sizeof t->w[0]); i++)
        if (t->w[i].kick_fd >= 0) close(t->w[i].kick_fd);
    if (t->done_fd >= 0) close(t->done_fd);
    if (t->lock_ok) pthread_mutex_destroy(&t->lock);
    free(t);
}

/* The processor's idle after the last completion ends at NOW: that record is
 * complete and counts (as tasking.c's tasking_flush). Under lock. */
static void threads_flush_idle(threads_t *t, int64_t now)
{
    if (!t->idle_pending) return;
    skel_rec_t *rec = &t->idle_rec;
    skel_process_t *p = t->idle_p;
    int64_t release = rec->release_ns - t->s->clock_offset_ns;
    int64_t end = release + p->period_ns - rec->slack_ns;
    rec->idle_ns = now > end ? now - end : 0;
    cycle_account(t->plan, p, rec, release, end);
    cycle_record(t->s, rec);
    t->idle_pending = 0;
}

static void threads_kick(threads_t *t, const threads_worker_t *self)
{
    for (int i = 0; i < t->nworkers; i++)
        if (&t->w[i] != self && t->w[i].waiting) server_wake(t->w[i].kick_fd);
}

static void threads_kick_all(threads_t *t)
{
    for (int i = 0; i < t->nworkers; i++) server_wake(t->w[i].kick_fd);
}

/* Drains the links, under lock: what came for another thread's wait wakes it. */
static void threads_drain(threads_worker_t *w)
{
    skel_plan_t *plan = w->t->plan;
    if (link_drain(plan->links, plan->nlinks) > 0) threads_kick(w->t, w);
}

/* Drains and looks at P's inputs, under lock: the first required input without
 * new data (-1: none). */
static int threads_look(threads_worker_t *w, skel_rec_t *look)
{
    threads_drain(w);
    process_peek_inputs(w->t->plan, w->p, look);
    return process_missing(w->p, look);
}

/* Waits, the lock let go meanwhile, for a kick, the run's end, UNTIL (at most a
 * piece), and with WATCH for anything on the links: 1 when the run is done. Never
 * called with UNTIL past: a SCHED_FIFO thread must not spin (the kernel's real-time
 * throttling would then take the watcher's CPU time too). */
static int threads_wait(threads_worker_t *w, int64_t until, int watch)
{
    threads_t *t = w->t;
    const skel_plan_t *plan = t->plan;
    struct pollfd fds[SKEL_MAX_LINKS + 2];
    int n = 0;
    for (int i = 0; watch && i < plan->nlinks; i++)
        fds[n++] = (struct pollfd){ .fd = plan->links[i].fd, .events = POLLIN };
    fds[n++] = (struct pollfd){ .fd = w->kick_fd, .events = POLLIN };
    fds[n++] = (struct pollfd){ .fd = t->done_fd, .events = POLLIN };
    int64_t held = watch ? buffers_advance(t->plan, clock_mono_ns()) : INT64_MAX; /* held back by an emulated link */
    if (held < until) until = held;
    int64_t left = until - clock_mono_ns();
    left = left < 0 ? 0 : left > THREADS_PIECE_NS ? THREADS_PIECE_NS : left;
    struct timespec ts = { .tv_sec = left / SKEL_NS_PER_S, .tv_nsec = left % SKEL_NS_PER_S };
    w->waiting = watch;
    threads_unlock(t);
    int rc = ppoll(fds, (nfds_t)n, &ts, NULL);
    w->woke_ns = clock_mono_ns();
    int failed = rc < 0 && errno != EINTR;
    uint64_t v;
    if (rc > 0 && (fds[n - 2].revents & POLLIN) && read(w->kick_fd, &v, sizeof v) < 0 && errno != EAGAIN)
        failed = 1;
    threads_lock(t);
    w->waiting = 0;
    return failed || atomic_load(&t->done);
}

/* The computation, in mode MODE: what it ran (the record's compute); the time
 * the machine stopped it is added to *STALL. */
static int64_t threads_compute(const skel_compute_t *c, int mode, int64_t ns, int64_t *stall)
{
    if (mode == SKELMSG_DPU_T_COMPUTE_WORK) {
        int64_t kept = 0; /* what its chunks took beyond their work: preempted_ns here */
        return compute_run(c, mode, ns, &kept);
    }
    /* CPU, WALL: the wall time it held the processor; a gap between two looks
     * longer than the stall threshold is time it was preempted, or, when its
     * thread was not switched out meanwhile, time the machine stopped the CPU. */
    return compute_held(c, ns, stall);
}

/* Its release RELEASE is due: P has a job (under lock). */
static void threads_release(threads_t *t, skel_process_t *p, int64_t release)
{
    p->job.release = release;
    p->job.generation = p->event < 0 && p->next_k < 0 ? p->job.back_generation : t->plan->generation;
    p->job.missing = -1;
    p->job.state = p->sync == SKELMSG_PROCESS_T_SYNC_DATA ? JOB_WAITING : JOB_READY;
    if (p->event >= 0) event_release(t->plan, p, release);
}

/* A data job whose data is all new is ready; one whose data came a whole period
 * late skips its release (cycle_skips). 1 when it still waits (under lock). */
static int threads_check_data(threads_worker_t *w)
{
    threads_t *t = w->t;
    skel_process_t *p = w->p;
    skel_rec_t look;
    p->job.missing = (int8_t)threads_look(w, &look);
    if (p->job.missing >= 0) return 1;
    w->ready_ns = clock_mono_ns();
    p->job.state = JOB_READY;
    if (!cycle_skips(t->plan, p, p->job.release, w->ready_ns)) return 0;
    cycle_skip_record(&w->x, p, p->k_base + p->next_k, job_minor(t->plan, p), p->job.release,
                          p->job.release, w->ready_ns, &look);
    look.generation = p->job.generation;
    cycle_record(t->s, &look);
    p->job.state = JOB_NONE;
    p->next_k++;
    return 0;
}

/* W's ready job: it takes the processor, computes with the lock let go, and
 * completes under whatever plan is current by then (under lock). */
static void threads_job(threads_worker_t *w)
{
    threads_t *t = w->t;
    skel_plan_t *plan = t->plan;
    skel_process_t *p = w->p;
    skel_rec_t *rec = &w->rec;
    int64_t k = p->k_base + p->next_k;
    int64_t csw0 = clock_thread_preemptions();
    int64_t start = clock_mono_ns();
    /* The processor was this job's at its release (or data), or at the completion
     * that freed it: what is left to the start is the kernel's latency. */
    int64_t ready = p->sync == SKELMSG_PROCESS_T_SYNC_DATA ? w->ready_ns : p->job.release;
    int64_t sched = t->active > 0 || t->last_end_ns < ready ? ready : t->last_end_ns;
    threads_flush_idle(t, start);
    t->active++;
    process_record_begin(&w->x, p, k, job_minor(plan, p), p->job.release, sched, start, rec);
    /* Woken later than the processor was its by more than the stall threshold:
     * the kernel or the machine kept it, as a late wake-up is a stall on the
     * other executives (waiting for the lock after is the bus, not counted). */
    if (w->woke_ns - sched > t->s->compute.stall_ns) rec->stall_ns += w->woke_ns - sched;
    if (k == p->job.lockout_k) rec->flags |= SKELMSG_TIMING_T_FLAG_LOCKOUT;
    rec->generation = p->job.generation;
    (void)threads_look(w, rec); /* a data job's data is still new: only its own commit uses it */
    process_commit(plan, p, rec, k >= p->measure_from_k);
    p->job.state = JOB_STARTED;
    rec->asked_ns = draw_ns(&p->draw, p->compute_ns);
    const int mode = plan->compute;
    threads_unlock(t);
    int64_t t_in = clock_mono_ns();
    rec->comm_in_ns = t_in - start;
    int64_t stall = 0;
    rec->compute_ns = threads_compute(&t->s->compute, mode, rec->asked_ns, &stall);
    int64_t t_out = clock_mono_ns();
    rec->stall_ns += stall; /* also in preempted_ns: the parts add up to the job's end */
    rec->preempted_ns = t_out - t_in - rec->compute_ns;
    if (rec->preempted_ns < 0) rec->preempted_ns = 0;
    threads_lock(t);
    t->active--;
    p = w->p; /* a live switch may have handed it another plan's process, or none */
    plan = t->plan;
    if (p == NULL) return; /* removed: its job is lost, as at a run's end */
    const int measured = k >= p->measure_from_k;
    process_write_outputs(&w->x, p, k);
    threads_kick(t, w); /* a local output may be what a data wait waits for */
    process_finish(&w->x, p, rec, p->job.release, t_out, measured);
    int64_t csw = clock_thread_preemptions() - csw0;
    rec->preemptions = csw > INT32_MAX ? INT32_MAX : (int32_t)csw;
    p->job.state = JOB_NONE;
    p->next_k++;
    int64_t end = clock_mono_ns();
    t->last_end_ns = end;
    atomic_fetch_add(&t->s->minor_cycles, 1);
    if (measured) plan->sums.minor_cycles++;
    if (t->active == 0) { /* the processor goes idle: the record waits for the idle's end */
        t->idle_rec = *rec;
        t->idle_p = p;
        t->idle_pending = 1;
    } else { /* preempted work goes on at once: no idle follows this job */
        cycle_account(plan, p, rec, p->job.release, p->job.release + p->period_ns - rec->slack_ns);
        cycle_record(t->s, rec);
    }
}

/* One step of W's loop, under lock: 1 when the thread is done. */
static int threads_step(threads_worker_t *w)
{
    threads_t *t = w->t;
    skel_process_t *p = w->p;
    if (p == NULL || atomic_load(&t->done)) return 1;
    if (clock_mono_ns() >= t->switch_at) /* past the switch's instant nothing starts before it */
        return threads_wait(w, INT64_MAX, 0);
    if (p->job.state == JOB_NONE) {
        if (p->event >= 0) threads_drain(w); /* its events come on the links */
        int64_t release = job_next_release(p), now = clock_mono_ns();
        if (release >= w->x.end_mono_ns) /* none in this run: the run's end, an event, a switch */
            return threads_wait(w, INT64_MAX, p->event >= 0);
        if (release >= t->switch_at) /* the switch first: the watcher kicks after it */
            return threads_wait(w, INT64_MAX, 0);
        if (release > now) {
            if (p->event >= 0) return threads_wait(w, release, 1);
            threads_unlock(t);
            int rc = clock_sleep_until(release, &t->done);
            threads_lock(t);
            return rc != 0;
        }
        threads_release(t, p, release);
    }
    if (p->job.state == JOB_WAITING && threads_check_data(w)) return threads_wait(w, INT64_MAX, 1);
    if (p->job.state == JOB_READY) threads_job(w);
    return 0;
}

static void *threads_worker(void *arg)
{
    threads_worker_t *w = arg;
    threads_t *t = w->t;
    char name[16];
    snprintf(name, sizeof name, "skel-p%d", w->id);
    (void)pthread_setname_np(pthread_self(), name);
    threads_lock(t);
    while (!threads_step(w)) {}
    threads_unlock(t);
    return NULL;
}

/* Pins W to the processor and gives it its priority: 0, or -1 (said once) when refused. */
static int threads_place(threads_t *t, threads_worker_t *w)
{
    cpu_set_t set;
    CPU_ZERO(&set);
    CPU_SET(t->cpu, &set);
    int rc = pthread_setaffinity_np(w->tid, sizeof set, &set);
    const char *what = "pinning to CPU";
    if (rc == 0) {
        struct sched_param sp = { .sched_priority = w->p->priority };
        rc = pthread_setschedparam(w->tid, SCHED_FIFO, &sp);
        what = "SCHED_FIFO on CPU";
    }
    if (rc == 0) return 0;
    if (t->faithful)
        log_line("DPU %d: warning: the tasking executive's threads cannot run under %s %d (%s): "
                 "the kernel's time sharing stands in for fixed-priority preemptive scheduling, "
                 "so this run is not faithful (needs root or CAP_SYS_NICE)",
                 t->plan->dpu, what, t->cpu, strerror(rc));
    t->faithful = 0;
    return -1;
}

/* The watcher (the executive thread) runs off the processor when it can, and
 * under SCHED_FIFO where it may: the threads wait for it at a live switch. */
static void threads_move_watcher(threads_t *t)
{
    struct sched_param sp = { .sched_priority = SKEL_RT_PRIORITY };
    if (t->faithful) (void)pthread_setschedparam(pthread_self(), SCHED_FIFO, &sp); /* refused: as the threads */
    cpu_set_t others;
    CPU_ZERO(&others);
    int n = get_nprocs();
    for (int c = 0; c < n && c < CPU_SETSIZE; c++)
        if (c != t->cpu) CPU_SET(c, &others);
    if (CPU_COUNT(&others) == 0) return;
    if (!t->watcher_moved && pthread_getaffinity_np(pthread_self(), sizeof t->watcher_was, &t->watcher_was) != 0)
        return;
    if (pthread_setaffinity_np(pthread_self(), sizeof others, &others) == 0) t->watcher_moved = 1;
}

/* A free slot: a removed process's whose thread has ended, or a new one (NULL: none). */
static threads_worker_t *threads_slot(threads_t *t)
{
    for (int i = 0; i < t->nworkers; i++) {
        threads_worker_t *w = &t->w[i];
        if (w->live && w->p == NULL && pthread_tryjoin_np(w->tid, NULL) == 0) w->live = 0;
        if (!w->live) return w;
    }
    if (t->nworkers == (int)(sizeof t->w / sizeof t->w[0])) return NULL;
    return &t->w[t->nworkers++];
}

/* A thread for process P (in X's plan): 0, or -1 said. */
static int threads_add(threads_t *t, const skel_exec_t *x, skel_process_t *p)
{
    threads_worker_t *w = threads_slot(t);
    if (w == NULL) {
        log_line("DPU %d: no room for a thread for process %d: it does not run", t->plan->dpu, p->id);
        return -1;
    }
    w->t = t;
    w->p = p;
    w->id = p->id;
    w->x = *x;
    w->x.wake_stall_ns = w->x.stall_debt_ns = 0;
    if (w->kick_fd < 0) w->kick_fd = threads_eventfd();
    int rc = w->kick_fd >= 0 ? pthread_create(&w->tid, NULL, threads_worker, w) : errno;
    if (rc != 0) {
        w->p = NULL;
        log_line("DPU %d: cannot start the thread of process %d (%s)", t->plan->dpu, p->id, strerror(rc));
        return -1;
    }
    w->live = 1;
    (void)threads_place(t, w); /* refused: said once, the run is not faithful */
    return 0;
}

void threads_end(threads_t *t)
{
    atomic_store(&t->done, 1);
    server_wake(t->done_fd);
    for (int i = 0; i < t->nworkers; i++)
        if (t->w[i].live && pthread_join(t->w[i].tid, NULL) != 0)
            log_line("DPU %d: cannot join the thread of process %d", t->plan->dpu, t->w[i].id);
    threads_lock(t);
    threads_flush_idle(t, clock_mono_ns());
    threads_unlock(t);
    if (t->watcher_moved &&
        pthread_setaffinity_np(pthread_self(), sizeof t->watcher_was, &t->watcher_was) != 0)
        log_line("DPU %d: warning: cannot restore the executive thread's CPUs", t->plan->dpu);
    threads_free(t);
}

threads_t *threads_start(skel_exec_t *x, char *klass, size_t len)
{
    skel_plan_t *plan = x->plan;
    threads_t *t = calloc(1, sizeof *t);
    if (t == NULL) return NULL;
    t->s = x->s;
    t->plan = plan;
    t->faithful = 1;
    t->done_fd = -1;
    t->switch_at = INT64_MAX;
    t->switch_seq = -1;
    plan->running = 1; /* before the threads that drain the links exist */
    atomic_init(&t->done, 0);
    for (int i = 0; i < (int)(sizeof t->w / sizeof t->w[0]); i++) t->w[i].kick_fd = -1;
    pthread_mutexattr_t ma;
    int ok = pthread_mutexattr_init(&ma) == 0;
    if (ok) {
        ok = pthread_mutexattr_setprotocol(&ma, PTHREAD_PRIO_INHERIT) == 0 && pthread_mutex_init(&t->lock, &ma) == 0;
        pthread_mutexattr_destroy(&ma);
    }
    t->lock_ok = ok;
    t->done_fd = threads_eventfd();
    ok = ok && t->done_fd >= 0;
    for (int i = 0; ok && i < plan->nprocesses; i++) ok = (t->w[i].kick_fd = threads_eventfd()) >= 0;
    if (!ok) {
        log_line("DPU %d: cannot prepare the tasking executive's threads (%s)", plan->dpu, strerror(errno));
        threads_free(t);
        return NULL;
    }
    for (int i = 0; i < plan->nprocesses; i++) { /* every release from the run's start (job_release) */
        skel_process_t *p = &plan->processes[i];
        p->job.anchor_ns = plan->epoch_t0_ns;
        p->job.back_period_ns = p->period_ns;
        p->job.back_generation = plan->generation;
    }
    int here = sched_getcpu();
    t->cpu = plan->cpu >= 0 ? plan->cpu : here >= 0 ? here : 0;
    threads_lock(t); /* the threads start once all are placed */
    for (int i = 0; i < plan->nprocesses; i++) {
        if (threads_add(t, x, &plan->processes[i]) != 0) {
            threads_unlock(t);
            threads_end(t);
            return NULL;
        }
    }
    threads_unlock(t);
    threads_move_watcher(t);
    if (!t->faithful) server_fault(t->s, SKELMSG_STATUS_T_FAULT_NOT_FAITHFUL);
    int lo = 0, hi = 0;
    for (int i = 0; i < plan->nprocesses; i++) {
        int prio = plan->processes[i].priority;
        if (lo == 0 || prio < lo) lo = prio;
        if (prio > hi) hi = prio;
    }
    if (t->faithful)
        snprintf(klass, len, "a thread each, SCHED_FIFO %d..%d on CPU %d", lo, hi, t->cpu);
    else
        snprintf(klass, len, "a thread each on CPU %d, NOT FAITHFUL: no SCHED_FIFO", t->cpu);
    return t;
}

/* Each thread gets its process of X's new plan, a removed one's thread is
 * demoted and ends, a new process gets a thread (under lock). */
static void threads_hand_over(threads_t *t, skel_exec_t *x, int cpu_moved)
{
    skel_plan_t *next = x->plan;
    const int nworkers = t->nworkers;
    for (int i = 0; i < nworkers; i++) {
        threads_worker_t *w = &t->w[i];
        if (!w->live || w->p == NULL) continue;
        int j = plan_process_index(next, w->id);
        w->x.plan = next;
        w->p = j >= 0 ? &next->processes[j] : NULL;
        int rc;
        if (w->p == NULL) {
            struct sched_param idle = { .sched_priority = 0 };
            rc = pthread_setschedparam(w->tid, SCHED_IDLE, &idle);
        } else if (cpu_moved) {
            rc = threads_place(t, w) == 0 ? 0 : -1;
        } else {
            struct sched_param sp = { .sched_priority = w->p->priority };
            rc = t->faithful ? pthread_setschedparam(w->tid, SCHED_FIFO, &sp) : 0;
        }
        if (rc > 0) log_line("DPU %d: cannot change the scheduling of process %d's thread (%s)", next->dpu,
                             w->id, strerror(rc));
    }
    for (int j = 0; j < next->nprocesses; j++) {
        int has = 0;
        for (int i = 0; i < nworkers && !has; i++) has = t->w[i].live && t->w[i].p == &next->processes[j];
        if (!has) (void)threads_add(t, x, &next->processes[j]);
    }
}

/* The pending switch's instant, once per COMMIT, on the grid of the minors not
 * begun by NOW (under lock); kicks the threads waiting for an earlier one. */
static void threads_plan_switch(threads_t *t, skel_exec_t *x, int64_t now)
{
    cycle_poll_switch(x);
    if (!x->switch_pending) {
        t->switch_at = INT64_MAX;
        return;
    }
    if (t->switch_seq == x->switch_seq) return;
    const skel_plan_t *plan = t->plan;
    int64_t j_prev = (now - plan->epoch_t0_ns) / plan->minor_ns;
    t->switch_seq = x->switch_seq;
    t->switch_j = swap_index(plan, j_prev, x->switch_at_mono_ns);
    t->switch_at = swap_instant(plan, t->switch_j);
    threads_kick_all(t);
}

/* At the switch's instant: the next plan takes over, unless a process still owes
 * a release of the plan before the current one (swap_tasking_ready): then at the
 * next point of the grid (under lock). */
static void threads_switch(threads_t *t, skel_exec_t *x)
{
    skel_plan_t *old = t->plan;
    if (!swap_tasking_ready(old, t->switch_at)) {
        t->switch_j = swap_index(old, t->switch_j, t->switch_at + 1);
        t->switch_at = swap_instant(old, t->switch_j);
        return;
    }
    threads_flush_idle(t, clock_mono_ns()); /* its process is the old plan's */
    skel_plan_t *next = cycle_take(x);
    int switched = next != NULL && cycle_switch(x, next, t->switch_j, 1);
    t->switch_at = INT64_MAX;
    t->switch_seq = x->switch_seq;
    if (switched) {
        int cpu = next->cpu >= 0 ? next->cpu : t->cpu, moved = cpu != t->cpu;
        t->plan = next;
        t->cpu = cpu;
        threads_hand_over(t, x, moved);
        if (next->cpu != old->cpu) threads_move_watcher(t); /* cycle_switch pinned it there */
        cycle_announce(x);
    }
    threads_kick_all(t);
}

/* Lockouts due by NOW (under lock, job_lockout); the next instant one would be. */
static int64_t threads_lockouts(threads_t *t, skel_exec_t *x, int64_t now)
{
    int64_t next = INT64_MAX;
    for (int i = 0; i < t->nworkers; i++)
        if (t->w[i].live && t->w[i].p != NULL) next = job_lockout(x, t->w[i].p, now, next);
    return next;
}

/* Watches for live switches and lockouts until the run's end or a STOP, then ends every thread. */
void threads_run(threads_t *t, skel_exec_t *x)
{
    skel_server_t *s = t->s;
    for (;;) {
        int64_t now = clock_mono_ns();
        if (atomic_load(&s->stop) || atomic_load(&s->quit) || now >= x->end_mono_ns) break;
        int64_t next = x->end_mono_ns - now > THREADS_PIECE_NS ? now + THREADS_PIECE_NS : x->end_mono_ns;
        threads_lock(t);
        threads_plan_switch(t, x, now);
        if (t->switch_at <= now) threads_switch(t, x);
        int64_t lockout = threads_lockouts(t, x, now);
        if (lockout < next) next = lockout;
        if (t->switch_at < next) next = t->switch_at;
        threads_unlock(t);
        now = clock_mono_ns();
        if (next > now && link_wait(x->plan->links, 0, s->wake_fd, next - now) < 0) break;
    }
    threads_end(t);
}
