/* bench/switch.c: what handing the processor from one DPU to another costs a simulation that
 * runs every DPU on one clock: a fiber switch (ucontext, on one thread) against a handover
 * between two threads (a POSIX semaphore each way). Prints ns per handover for each. */
#include <pthread.h>
#include <semaphore.h>
#include <stdio.h>
#include <stdlib.h>
#include <time.h>
#include <ucontext.h>

#define ROUNDS 1000000

static ucontext_t main_uc, fiber_uc;
static sem_t ping, pong;

static long long now_ns(void)
{
    struct timespec ts;
    clock_gettime(CLOCK_MONOTONIC, &ts);
    return (long long)ts.tv_sec * 1000000000LL + ts.tv_nsec;
}

static void fiber(void)
{
    for (;;)
        if (swapcontext(&fiber_uc, &main_uc) != 0) abort();
}

static void *partner(void *arg)
{
    (void)arg;
    for (int i = 0; i < ROUNDS; i++) {
        if (sem_wait(&ping) != 0 || sem_post(&pong) != 0) abort();
    }
    return NULL;
}

int main(void)
{
    static char stack[64 * 1024];
    if (getcontext(&fiber_uc) != 0) return 1;
    fiber_uc.uc_stack.ss_sp = stack;
    fiber_uc.uc_stack.ss_size = sizeof stack;
    makecontext(&fiber_uc, fiber, 0);
    long long t0 = now_ns();
    for (int i = 0; i < ROUNDS; i++)
        if (swapcontext(&main_uc, &fiber_uc) != 0) return 1;
    double fibers = (double)(now_ns() - t0) / ROUNDS / 2;

    pthread_t tid;
    if (sem_init(&ping, 0, 0) != 0 || sem_init(&pong, 0, 0) != 0) return 1;
    if (pthread_create(&tid, NULL, partner, NULL) != 0) return 1;
    t0 = now_ns();
    for (int i = 0; i < ROUNDS; i++)
        if (sem_post(&ping) != 0 || sem_wait(&pong) != 0) return 1;
    double threads = (double)(now_ns() - t0) / ROUNDS / 2;
    pthread_join(tid, NULL);
    printf("fiber %.0f ns, threads %.0f ns per handover\n", fibers, threads);
    return 0;
}
