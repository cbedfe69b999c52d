/* bench/lcm_publish.c: the cost of a bare lcm_publish() of N bytes, for `make bench`.
 *
 * The baseline for skel-dpu's comm_out: the same message size, published once per
 * period (as a DPU publishes one buffer per cycle, with caches as cold), each call
 * timed with CLOCK_MONOTONIC. Like a DPU it also listens on the URL (its socket
 * receives every message on the port) and drains between cycles. Prints
 * "count mean_ns p50_ns p99_ns max_ns".
 *
 * usage: lcm_publish URL BYTES PERIOD_US COUNT
 */
#include <lcm/lcm.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <time.h>

static int64_t now_ns(void)
{
    struct timespec ts;
    clock_gettime(CLOCK_MONOTONIC, &ts);
    return (int64_t)ts.tv_sec * 1000000000LL + ts.tv_nsec;
}

static void on_message(const lcm_recv_buf_t *rbuf, const char *channel, void *user)
{
    (void)rbuf;
    (void)channel;
    (void)user;
}

static int cmp_i64(const void *a, const void *b)
{
    int64_t x = *(const int64_t *)a, y = *(const int64_t *)b;
    return (x > y) - (x < y);
}

int main(int argc, char **argv)
{
    if (argc != 5) {
        fprintf(stderr, "usage: %s URL BYTES PERIOD_US COUNT\n", argv[0]);
        return 2;
    }
    const long bytes = atol(argv[2]), period_us = atol(argv[3]), count = atol(argv[4]);
    if (bytes <= 0 || period_us <= 0 || count <= 0) {
        fprintf(stderr, "BYTES, PERIOD_US and COUNT must be > 0\n");
        return 2;
    }
    lcm_t *lcm = lcm_create(argv[1]);
    uint8_t *data = calloc((size_t)bytes, 1);
    int64_t *cost = calloc((size_t)count, sizeof *cost);
    if (lcm == NULL || data == NULL || cost == NULL) {
        fprintf(stderr, "cannot create LCM on %s or allocate\n", argv[1]);
        return 1;
    }
    if (lcm_subscribe(lcm, "BENCH_NOTHING", on_message, NULL) == NULL) {
        fprintf(stderr, "lcm_subscribe failed\n");
        return 1;
    }
    int64_t release = now_ns();
    for (long i = 0; i < count; i++) {
        release += period_us * 1000;
        struct timespec ts = { .tv_sec = release / 1000000000LL, .tv_nsec = release % 1000000000LL };
        clock_nanosleep(CLOCK_MONOTONIC, TIMER_ABSTIME, &ts, NULL);
        while (lcm_handle_timeout(lcm, 0) > 0) {
        } /* drain, as a DPU does before its inputs */
        memcpy(data, &i, sizeof i); /* a new payload each time, as a DPU's sequence number */
        int64_t t0 = now_ns();
        if (lcm_publish(lcm, "BENCH_BARE_PUBLISH", data, (unsigned)bytes) != 0) {
            fprintf(stderr, "lcm_publish failed\n");
            return 1;
        }
        cost[i] = now_ns() - t0;
    }
    int64_t sum = 0;
    for (long i = 0; i < count; i++) sum += cost[i];
    qsort(cost, (size_t)count, sizeof *cost, cmp_i64);
    printf("%ld %lld %lld %lld %lld\n", count, (long long)(sum / count), (long long)cost[count / 2],
           (long long)cost[(count * 99) / 100], (long long)cost[count - 1]);
    free(cost);
    free(data);
    lcm_destroy(lcm);
    return 0;
}
