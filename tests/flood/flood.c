/* flood.c: hostile traffic for the flood test (tests/e2e/test_flood.py) and `make bench`.
 *
 *   flood URL RATE SECONDS CHANNEL[@URL]...
 *
 * publishes up to RATE messages a second for SECONDS (wall clock: where the machine cannot
 * send that many, fewer, and it says how many) on the CHANNELs (round robin), each on its
 * own URL where one follows it (a buffer's: its writer's port, host/sysfile/link.py), else on URL,
 * cycling
 * through four kinds: garbage (random bytes), a foreign fingerprint, our own
 * fingerprints with lengths that lie (command_t, config_t, buffer_t), and well-formed
 * but unsigned command_t (STOP, SHUTDOWN, START: what a DPU without a key would obey).
 * It prints one line of JSON: what it sent, per channel, and how late it fell behind. */
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <time.h>

#include <lcm/lcm.h>
#include <lcm/lcm_coretypes.h>

#include "skelmsg_buffer_t.h"
#include "skelmsg_command_t.h"
#include "skelmsg_config_t.h"

#define FLOOD_MAX_CHANNELS 64
#define FLOOD_BATCH_NS (1000 * 1000LL) /* one burst a millisecond */

enum { KIND_GARBAGE, KIND_FOREIGN, KIND_LYING, KIND_UNSIGNED, KINDS };

static int64_t mono_ns(void)
{
    struct timespec ts;
    clock_gettime(CLOCK_MONOTONIC, &ts);
    return (int64_t)ts.tv_sec * 1000000000LL + ts.tv_nsec;
}

static uint64_t rng = 0x9E3779B97F4A7C15ULL;
static uint64_t next_random(void)
{
    rng ^= rng << 13;
    rng ^= rng >> 7;
    rng ^= rng << 17;
    return rng;
}

/* A message whose fingerprint is ours but whose length fields lie: a string or array
 * length that is negative or far past the end. N picks which. */
static int lying(uint8_t *buf, int cap, uint64_t n)
{
    int64_t hash = (int64_t)(n % 3 == 0 ? __skelmsg_command_t_get_hash()
                             : n % 3 == 1 ? __skelmsg_config_t_get_hash() : __skelmsg_buffer_t_get_hash());
    int pos = __int64_t_encode_array(buf, 0, cap, &hash, 1);
    int64_t fields[4] = { (int64_t)next_random(), 7, (int64_t)next_random(), 1 };
    pos += __int64_t_encode_array(buf, pos, cap - pos, fields, 4);
    int32_t length = (n / 3) % 2 == 0 ? -5 : 0x7fffff00;
    pos += __int32_t_encode_array(buf, pos, cap - pos, &length, 1);
    return pos;
}

static int unsigned_command(uint8_t *buf, int cap, uint64_t n)
{
    static const int8_t kinds[] = { SKELMSG_COMMAND_T_STOP, SKELMSG_COMMAND_T_SHUTDOWN, SKELMSG_COMMAND_T_START };
    skelmsg_command_t cmd;
    memset(&cmd, 0, sizeof cmd);
    cmd.seq = (int64_t)(next_random() >> 1);
    cmd.kind = kinds[n % 3];
    cmd.dpu = -1;
    cmd.session = (int64_t)(next_random() >> 1);
    cmd.force = 1;
    cmd.sender = (char *)"flood";
    return skelmsg_command_t_encode(buf, 0, cap, &cmd);
}

static int make(uint8_t *buf, int cap, int kind, uint64_t n)
{
    switch (kind) {
    case KIND_GARBAGE: {
        int len = 1 + (int)(next_random() % 200);
        for (int i = 0; i < len; i++) buf[i] = (uint8_t)next_random();
        return len;
    }
    case KIND_FOREIGN: {
        for (int i = 0; i < 72; i++) buf[i] = (uint8_t)next_random();
        return 72;
    }
    case KIND_LYING: return lying(buf, cap, n);
    default: return unsigned_command(buf, cap, n);
    }
}

int main(int argc, char **argv)
{
    if (argc < 5) {
        fprintf(stderr, "usage: flood URL RATE SECONDS CHANNEL[@URL]...\n");
        return 2;
    }
    long rate = strtol(argv[2], NULL, 10);
    double seconds = strtod(argv[3], NULL);
    int nchannels = argc - 4;
    if (rate <= 0 || seconds <= 0 || nchannels > FLOOD_MAX_CHANNELS) {
        fprintf(stderr, "flood: RATE and SECONDS must be positive, at most %d channels\n", FLOOD_MAX_CHANNELS);
        return 2;
    }
    /* Per channel its name and the lcm_t of its URL (one per distinct URL). */
    static char *names[FLOOD_MAX_CHANNELS];
    static const char *urls[FLOOD_MAX_CHANNELS];
    static lcm_t *lcms[FLOOD_MAX_CHANNELS], *by_channel[FLOOD_MAX_CHANNELS];
    int nlcms = 0;
    for (int c = 0; c < nchannels; c++) {
        names[c] = argv[4 + c];
        char *at = strchr(names[c], '@');
        const char *url = at != NULL ? at + 1 : argv[1];
        if (at != NULL) *at = '\0';
        int u = 0;
        while (u < nlcms && strcmp(urls[u], url) != 0) u++;
        if (u == nlcms) {
            urls[u] = url;
            lcms[u] = lcm_create(url);
            if (lcms[u] == NULL) {
                fprintf(stderr, "flood: cannot open %s\n", url);
                return 1;
            }
            nlcms++;
        }
        by_channel[c] = lcms[u];
    }
    static int64_t sent[FLOOD_MAX_CHANNELS][KINDS];
    int64_t failed = 0, most_behind_ns = 0;
    uint8_t buf[512];
    uint64_t n = 0;
    int64_t total = (int64_t)(rate * seconds);
    int64_t start = mono_ns(), end = start + (int64_t)(seconds * 1e9);
    while ((int64_t)n < total && mono_ns() < end) {
        /* Messages due by now: sent in a burst, then sleep to the next millisecond. */
        int64_t now = mono_ns();
        int64_t due = (int64_t)((double)(now - start) * (double)rate / 1e9) + 1;
        if (due > total) due = total;
        /* The end is checked per message: one catch-up burst could otherwise outlast it. */
        while ((int64_t)n < due && ((n & 63) != 0 || mono_ns() < end)) {
            int channel = (int)(n % (uint64_t)nchannels), kind = (int)((n / (uint64_t)nchannels) % KINDS);
            int len = make(buf, sizeof buf, kind, n);
            if (len < 0 || lcm_publish(by_channel[channel], names[channel], buf, (unsigned)len) != 0) failed++;
            else sent[channel][kind]++;
            n++;
        }
        int64_t behind = mono_ns() - (start + (int64_t)((double)n * 1e9 / (double)rate));
        if (behind > most_behind_ns) most_behind_ns = behind;
        struct timespec ts = { 0, FLOOD_BATCH_NS };
        nanosleep(&ts, NULL);
    }
    double took = (double)(mono_ns() - start) / 1e9;
    printf("{\"seconds\": %.3f, \"failed\": %lld, \"most_behind_ms\": %.1f, \"sent\": {", took, (long long)failed,
           (double)most_behind_ns / 1e6);
    for (int c = 0; c < nchannels; c++) {
        printf("%s\"%s\": [", c ? ", " : "", names[c]);
        for (int k = 0; k < KINDS; k++) printf("%s%lld", k ? ", " : "", (long long)sent[c][k]);
        printf("]");
    }
    printf("}}\n");
    for (int u = 0; u < nlcms; u++) lcm_destroy(lcms[u]);
    return failed > 0 ? 1 : 0;
}
