/* threads.c: the tasking executive (executive: threads) in compute modes CPU,
 * WALL and WORK, where the kernel does the scheduling. The DPU is still one
 * processor under fixed-priority preemptive scheduling, but a real one: each
 * process is a thread of its own, SCHED_FIFO at the process's priority, and all
 * of them are pinned to one CPU (the DPU's `cpu`, or the one its executive
 * thread was on), so a release of a higher-priority process preempts a lower
 * one in the kernel. Each thread loops: an absolute wait for its release, a
 * `sync: data` wait for new data on its required inputs, inputs, the
 * computation in the DPU's mode (compute.c), outputs, its record.
 *
 * The executive thread becomes the watcher: moved off that CPU, it wakes at
 * the lockout instants (a job not started lockout_cycles periods after its
 * release is locked out, as on the other executives: waiting for data, naming
 * the buffer, or kept from the processor), at STOP and at the run's end, when
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
 * computation's compute_ns the time it ran (CPU time in CPU and WORK; in WALL
 * the wall time it held the processor: a gap of more than the stall threshold
 * between two looks at the clock is time it was preempted, not computation),
 * preempted_ns the time its computation did not run between its start and its
 * end, and preemptions the involuntary context switches of its thread during
 * the job (getrusage RUSAGE_THREAD). The kernel cannot tell the DPU who took
 * the processor, so stall_ns is 0: on a faithful run only the DPU's
 * higher-priority processes can (and interrupts, which are not switches).
 * Where SCHED_FIFO or the pinning is refused, the DPU says so once in its log
 * and the run's status and report carry FAULT_NOT_FAITHFUL: the kernel's
 * ordinary time sharing then stands in for the model. A live switch of plans
 * is refused on this executive, as on the other tasking one (apply.c). */
#include <errno.h>
#include <poll.h>
#include <sched.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/eventfd.h>
#include <sys/resource.h>
#include <sys/sysinfo.h>
#include <unistd.h>

#include "dpu.h"

#define THREADS_PIECE_NS (50 * 1000 * 1000LL) /* a wait looks at the run's end this often */

struct threads;

typedef struct {
    struct threads *t;
    skel_process_t *p;
    skel_exec_t x;                 /* this thread's own: record_begin and finish read it */
    pthread_t tid;
    int kick_fd;                   /* eventfd: new data for a data wait */
    int waiting;                   /* in a data wait (lock) */
    atomic_int_fast64_t pending_k; /* its oldest release not started yet */
    atomic_int missing;            /* the buffer its data wait lacks, -1 when not waiting */
    atomic_int_fast64_t locked_k;  /* the cycle the watcher locked out, -1 none */
    skel_rec_t rec;                /* the job's record */
} threads_worker_t;

struct threads {
    skel_server_t *s;
    skel_plan_t *plan;
    pthread_mutex_t lock;          /* priority inheritance: slots, links, ring, DPU sums, below */
    int lock_ok;
    int done_fd;                   /* eventfd, written once at the end and never read */
    atomic_int done;
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
    int nworkers;                  /* created */
    threads_worker_t w[];
};

static int threads_eventfd(void) { return eventfd(0, EFD_NONBLOCK | EFD_CLOEXEC); }

static void threads_free(threads_t *t)
{
    for (int i = 0; i < t->plan->nprocesses; i++)
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
    executive_account(t->plan, p, rec, release, end);
    executive_record(t->s, rec);
    t->idle_pending = 0;
}

/* Sleeps until UNTIL, in pieces, unless the run is done: 0 reached, 1 done. */
static int threads_sleep(threads_t *t, int64_t until)
{
    return clock_sleep_until(until, &t->done) != 0;
}

static void threads_kick(threads_t *t, const threads_worker_t *self)
{
    for (int i = 0; i < t->plan->nprocesses; i++)
        if (&t->w[i] != self && t->w[i].waiting) server_wake(t->w[i].kick_fd);
}

/* Drains the links and looks at P's inputs, under lock: the first required input
 * without new data (-1: none). Data drained for another thread's wait wakes it. */
static int threads_look(threads_worker_t *w, skel_rec_t *look)
{
    threads_t *t = w->t;
    skel_plan_t *plan = t->plan;
    if (link_drain(plan->links, plan->nlinks) > 0) threads_kick(t, w);
    process_peek_inputs(plan, w->p, look);
    return process_missing(w->p, look);
}

/* A data job waits for new data on every required input: 0 ready (at *READY),
 * 1 the run is done. The thread does not hold the processor meanwhile. */
static int threads_wait_data(threads_worker_t *w, int64_t *ready)
{
    threads_t *t = w->t;
    skel_plan_t *plan = t->plan;
    struct pollfd fds[SKEL_MAX_LINKS + 2];
    skel_rec_t look;
    for (;;) {
        if (pthread_mutex_lock(&t->lock) != 0) return 1;
        int missing = threads_look(w, &look);
        w->waiting = missing >= 0;
        pthread_mutex_unlock(&t->lock);
        if (missing < 0) {
            atomic_store(&w->missing, -1);
            *ready = clock_mono_ns();
            return 0;
        }
        atomic_store(&w->missing, w->p->inputs[missing].buffer);
        int n = 0;
        for (int i = 0; i < plan->nlinks; i++) fds[n++] = (struct pollfd){ .fd = plan->links[i].fd, .events = POLLIN };
        fds[n++] = (struct pollfd){ .fd = w->kick_fd, .events = POLLIN };
        fds[n++] = (struct pollfd){ .fd = t->done_fd, .events = POLLIN };
        struct timespec ts = { .tv_sec = 0, .tv_nsec = THREADS_PIECE_NS };
        int rc = ppoll(fds, (nfds_t)n, &ts, NULL);
        if (atomic_load(&t->done) || (rc < 0 && errno != EINTR)) return 1;
        uint64_t v;
        if (rc > 0 && (fds[n - 2].revents & POLLIN) && read(w->kick_fd, &v, sizeof v) < 0 && errno != EAGAIN)
            return 1;
    }
}

/* The computation, in the DPU's mode: what it ran (the record's compute). */
static int64_t threads_compute(threads_t *t, int64_t ns)
{
    const skel_compute_t *c = &t->s->compute;
    if (t->plan->compute != SKELMSG_DPU_T_COMPUTE_WALL) {
        int64_t stall = 0; /* CPU, WORK: wall less CPU time, which is preempted_ns here */
        return compute_run(c, t->plan->compute, ns, &stall);
    }
    /* WALL: the wall time it held the processor; a gap between two looks longer
     * than the stall threshold is time it was preempted. */
    int64_t ran = 0, prev = clock_mono_ns();
    while (ran < ns) {
        int64_t now = clock_mono_ns(), d = now - prev;
        if (d <= c->stall_ns) ran += d;
        prev = now;
    }
    return ran;
}

static int64_t threads_nivcsw(void)
{
    struct rusage ru;
    return getrusage(RUSAGE_THREAD, &ru) == 0 ? ru.ru_nivcsw : 0;
}

/* Job K of W's process, released at RELEASE, ready (its data there) at READY. */
static void threads_job(threads_worker_t *w, int64_t k, int64_t release, int64_t ready)
{
    threads_t *t = w->t;
    skel_plan_t *plan = t->plan;
    skel_process_t *p = w->p;
    skel_rec_t *rec = &w->rec;
    const int measured = k >= p->measure_from_k;
    const int64_t minor = plan->minor_base + (release - plan->epoch_t0_ns) / plan->minor_ns;
    int64_t csw0 = threads_nivcsw();
    if (pthread_mutex_lock(&t->lock) != 0) return;
    int64_t start = clock_mono_ns();
    /* The processor was this job's at its release (or data), or at the completion
     * that freed it: what is left to the start is the kernel's latency. */
    int64_t sched = t->active > 0 || t->last_end_ns < ready ? ready : t->last_end_ns;
    threads_flush_idle(t, start);
    t->active++;
    atomic_store(&w->pending_k, k + 1);
    process_record_begin(&w->x, p, p->k_base + k, minor, release, sched, start, rec);
    (void)threads_look(w, rec); /* a data job's data is still new: only its own commit uses it */
    process_commit(plan, p, rec, measured);
    pthread_mutex_unlock(&t->lock);
    rec->asked_ns = draw_ns(&p->draw, p->compute_ns);
    int64_t t_in = clock_mono_ns();
    rec->comm_in_ns = t_in - start;
    rec->compute_ns = threads_compute(t, rec->asked_ns);
    int64_t t_out = clock_mono_ns();
    rec->preempted_ns = t_out - t_in - rec->compute_ns;
    if (rec->preempted_ns < 0) rec->preempted_ns = 0;
    if (pthread_mutex_lock(&t->lock) != 0) return;
    process_write_outputs(&w->x, p, p->k_base + k);
    threads_kick(t, w); /* a local output may be what a data wait waits for */
    process_finish(&w->x, p, rec, release, t_out, measured);
    if (atomic_load(&w->locked_k) == k) rec->flags |= SKELMSG_TIMING_T_FLAG_LOCKOUT;
    int64_t csw = threads_nivcsw() - csw0;
    rec->preemptions = csw > INT32_MAX ? INT32_MAX : (int32_t)csw;
    int64_t end = clock_mono_ns();
    t->last_end_ns = end;
    atomic_fetch_add(&t->s->minor_cycles, 1);
    if (measured) plan->sums.minor_cycles++;
    if (--t->active == 0) { /* the processor goes idle: the record waits for the idle's end */
        t->idle_rec = *rec;
        t->idle_p = p;
        t->idle_pending = 1;
    } else { /* preempted work goes on at once: no idle follows this job */
        executive_account(plan, p, rec, release, release + p->period_ns - rec->slack_ns);
        executive_record(t->s, rec);
    }
    pthread_mutex_unlock(&t->lock);
}

static void *threads_worker(void *arg)
{
    threads_worker_t *w = arg;
    threads_t *t = w->t;
    skel_plan_t *plan = t->plan;
    skel_process_t *p = w->p;
    char name[16];
    snprintf(name, sizeof name, "skel-p%d", p->id);
    (void)pthread_setname_np(pthread_self(), name);
    for (int64_t k = 0;; k++) {
        const int64_t release = plan->epoch_t0_ns + k * p->period_ns;
        if (release >= w->x.end_mono_ns) break;
        if (threads_sleep(t, release) != 0 || atomic_load(&t->done)) break;
        int64_t ready = release;
        if (p->sync == SKELMSG_PROCESS_T_SYNC_DATA) {
            if (threads_wait_data(w, &ready) != 0) break;
            if (executive_skips(plan, p, release, ready)) { /* a period late: the next job takes it */
                const int64_t minor = plan->minor_base + (release - plan->epoch_t0_ns) / plan->minor_ns;
                if (pthread_mutex_lock(&t->lock) != 0) break;
                executive_skip_record(&w->x, p, p->k_base + k, minor, release, release, ready, &w->rec);
                executive_record(t->s, &w->rec);
                atomic_store(&w->pending_k, k + 1);
                pthread_mutex_unlock(&t->lock);
                continue;
            }
        }
        threads_job(w, k, release, ready);
    }
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

/* The watcher (the executive thread) runs off the processor when it can. */
static void threads_move_watcher(threads_t *t)
{
    cpu_set_t others;
    CPU_ZERO(&others);
    int n = get_nprocs();
    for (int c = 0; c < n && c < CPU_SETSIZE; c++)
        if (c != t->cpu) CPU_SET(c, &others);
    if (CPU_COUNT(&others) == 0) return;
    if (pthread_getaffinity_np(pthread_self(), sizeof t->watcher_was, &t->watcher_was) != 0) return;
    t->watcher_moved = pthread_setaffinity_np(pthread_self(), sizeof others, &others) == 0;
}

void threads_end(threads_t *t)
{
    atomic_store(&t->done, 1);
    server_wake(t->done_fd);
    for (int i = 0; i < t->nworkers; i++)
        if (pthread_join(t->w[i].tid, NULL) != 0)
            log_line("DPU %d: cannot join the thread of process %d", t->plan->dpu, t->w[i].p->id);
    if (pthread_mutex_lock(&t->lock) == 0) {
        threads_flush_idle(t, clock_mono_ns());
        pthread_mutex_unlock(&t->lock);
    }
    if (t->watcher_moved &&
        pthread_setaffinity_np(pthread_self(), sizeof t->watcher_was, &t->watcher_was) != 0)
        log_line("DPU %d: warning: cannot restore the executive thread's CPUs", t->plan->dpu);
    threads_free(t);
}

threads_t *threads_start(skel_exec_t *x, char *klass, size_t len)
{
    skel_plan_t *plan = x->plan;
    threads_t *t = calloc(1, sizeof *t + (size_t)plan->nprocesses * sizeof(threads_worker_t));
    if (t == NULL) return NULL;
    t->s = x->s;
    t->plan = plan;
    t->faithful = 1;
    t->done_fd = -1;
    plan->running = 1; /* before the threads that drain the links exist */
    atomic_init(&t->done, 0);
    for (int i = 0; i < plan->nprocesses; i++) t->w[i].kick_fd = -1;
    pthread_mutexattr_t ma;
    int ok = pthread_mutexattr_init(&ma) == 0;
    if (ok) {
        ok = pthread_mutexattr_setprotocol(&ma, PTHREAD_PRIO_INHERIT) == 0 && pthread_mutex_init(&t->lock, &ma) == 0;
        pthread_mutexattr_destroy(&ma);
    }
    t->lock_ok = ok;
    t->done_fd = threads_eventfd();
    ok = ok && t->done_fd >= 0;
    for (int i = 0; ok && i < plan->nprocesses; i++) {
        threads_worker_t *w = &t->w[i];
        w->t = t;
        w->p = &plan->processes[i];
        w->x = *x;
        w->x.wake_stall_ns = w->x.stall_debt_ns = 0;
        atomic_init(&w->pending_k, 0);
        atomic_init(&w->missing, -1);
        atomic_init(&w->locked_k, -1);
        w->kick_fd = threads_eventfd();
        ok = w->kick_fd >= 0;
    }
    if (!ok) {
        log_line("DPU %d: cannot prepare the tasking executive's threads (%s)", plan->dpu, strerror(errno));
        threads_free(t);
        return NULL;
    }
    int here = sched_getcpu();
    t->cpu = plan->cpu >= 0 ? plan->cpu : here >= 0 ? here : 0;
    for (int i = 0; i < plan->nprocesses; i++) {
        int rc = pthread_create(&t->w[i].tid, NULL, threads_worker, &t->w[i]);
        if (rc != 0) {
            log_line("DPU %d: cannot start the thread of process %d (%s)", plan->dpu, plan->processes[i].id,
                     strerror(rc));
            threads_end(t);
            return NULL;
        }
        t->nworkers++;
        (void)threads_place(t, &t->w[i]); /* refused: said once, the run is not faithful */
    }
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

/* Watches for lockouts until the run's end or a STOP, then ends every thread. */
void threads_run(threads_t *t, skel_exec_t *x)
{
    skel_server_t *s = t->s;
    skel_plan_t *plan = t->plan;
    for (;;) {
        int64_t now = clock_mono_ns();
        if (atomic_load(&s->stop) || atomic_load(&s->quit) || now >= x->end_mono_ns) break;
        int64_t next = x->end_mono_ns - now > THREADS_PIECE_NS ? now + THREADS_PIECE_NS : x->end_mono_ns;
        for (int i = 0; i < plan->nprocesses; i++) {
            threads_worker_t *w = &t->w[i];
            skel_process_t *p = w->p;
            if (p->locked_out) continue;
            int64_t k = atomic_load(&w->pending_k);
            int64_t release = plan->epoch_t0_ns + k * p->period_ns;
            if (release >= x->end_mono_ns) continue;
            int64_t at = process_lockout_at(plan, p, release);
            if (now < at) {
                if (at < next) next = at;
                continue;
            }
            atomic_store(&w->locked_k, k);
            process_lockout(x, p, (int16_t)atomic_load(&w->missing), p->k_base + k, release);
        }
        if (link_wait(plan->links, 0, s->wake_fd, next - now) < 0) break;
    }
    threads_end(t);
}
