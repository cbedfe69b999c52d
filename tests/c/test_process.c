/* test_process.c: a step of a cycle that should not wait (reading inputs, publishing)
 * is a stall when the thread was kept from running, not when it ran or chose to wait. */
#include <pthread.h>
#include <sched.h>
#include <semaphore.h>
#include <time.h>

#include "check.h"
#include "dpu.h"

static skel_server_t server;

static void spin_until(int64_t end)
{
    while (clock_mono_ns() < end) {
    }
}

/* The stall process_kept finds in a step from FROM to now. */
static int64_t kept_ns(skel_exec_t *x, int64_t from)
{
    skel_rec_t rec;
    memset(&rec, 0, sizeof rec);
    x->stall_debt_ns = 0;
    int64_t kept = process_kept(x, &rec, from, clock_mono_ns());
    CHECK_EQ(rec.stall_ns, x->stall_debt_ns); /* what the record says, the debt owes */
    /* the platform's time, not the step's communication: the caller takes it out of that */
    CHECK_EQ(kept, rec.stall_ns);
    CHECK_EQ(rec.preempted_ns, kept);
    return rec.stall_ns;
}

/* Running for 5 ms is no stall (but what the machine took of it, as often here: at
 * most half of it, or the test says nothing), nor is sleeping for 5 ms (a wait it chose). */
static void test_running_or_waiting_is_no_stall(skel_exec_t *x)
{
    int64_t from = clock_mono_ns();
    process_remark(x, from);
    CHECK(x->mark.cpu_ns >= 0);
    spin_until(from + 5000000);
    CHECK(kept_ns(x, from) < 2500000);
    from = clock_mono_ns();
    process_remark(x, from);
    struct timespec ts = { 0, 5000000 };
    CHECK_EQ(nanosleep(&ts, NULL), 0);
    CHECK_EQ(kept_ns(x, from), 0);
}

/* A short step costs no system call and judges nothing: the mark stays. */
static void test_a_short_step_is_not_judged(skel_exec_t *x)
{
    int64_t from = clock_mono_ns();
    process_remark(x, from);
    skel_mark_t was = x->mark;
    CHECK_EQ(kept_ns(x, clock_mono_ns()), 0);
    CHECK_EQ(x->mark.mono_ns, was.mono_ns);
}

static sem_t go;

static void *hog(void *arg)
{
    (void)arg;
    while (sem_wait(&go) != 0) {
    }
    spin_until(clock_mono_ns() + 8000000);
    return NULL;
}

/* A real-time thread on our CPU takes it for 8 ms while we run: that is a stall of
 * about 8 ms. Needs the right to real-time scheduling (root): said and left out when not. */
static void test_a_thread_that_takes_the_cpu_is_a_stall(skel_exec_t *x)
{
    cpu_set_t one;
    CPU_ZERO(&one);
    CPU_SET(0, &one);
    if (pthread_setaffinity_np(pthread_self(), sizeof one, &one) != 0) return;
    CHECK_EQ(sem_init(&go, 0, 0), 0);
    pthread_attr_t attr;
    struct sched_param prio = { .sched_priority = 10 };
    CHECK_EQ(pthread_attr_init(&attr), 0);
    CHECK_EQ(pthread_attr_setinheritsched(&attr, PTHREAD_EXPLICIT_SCHED), 0);
    CHECK_EQ(pthread_attr_setschedpolicy(&attr, SCHED_FIFO), 0);
    CHECK_EQ(pthread_attr_setschedparam(&attr, &prio), 0);
    CHECK_EQ(pthread_attr_setaffinity_np(&attr, sizeof one, &one), 0);
    pthread_t t;
    if (pthread_create(&t, &attr, hog, NULL) != 0) {
        fprintf(stderr, "test_process: no real-time thread here (not root?): the stall case not run\n");
        pthread_attr_destroy(&attr);
        return;
    }
    /* Below the hog, above every ordinary process: on a busy machine a neighbour taking
     * our CPU would be a stall too, and the steps after the hog's must have none. */
    struct sched_param below = { .sched_priority = 5 }, none = { .sched_priority = 0 };
    CHECK_EQ(pthread_setschedparam(pthread_self(), SCHED_FIFO, &below), 0);
    int64_t from = clock_mono_ns();
    process_remark(x, from);
    CHECK_EQ(sem_post(&go), 0);
    spin_until(from + 12000000); /* the hog runs 8 ms of these 12 */
    int64_t stall = kept_ns(x, from);
    CHECK(stall >= 6000000 && stall <= 13000000);
    /* the next long step is judged from where this one ended: none of the 8 ms again */
    int64_t step = clock_mono_ns();
    spin_until(step + 10000000);
    CHECK(kept_ns(x, step) < 4000000);
    CHECK_EQ(pthread_setschedparam(pthread_self(), SCHED_OTHER, &none), 0);
    CHECK_EQ(pthread_join(t, NULL), 0);
    pthread_attr_destroy(&attr);
    sem_destroy(&go);
}

int main(void)
{
    server.compute.stall_ns = SKEL_STALL_NS;
    skel_exec_t x = { .s = &server };
    test_running_or_waiting_is_no_stall(&x);
    test_a_short_step_is_not_judged(&x);
    test_a_thread_that_takes_the_cpu_is_a_stall(&x);
    return CHECK_DONE();
}
