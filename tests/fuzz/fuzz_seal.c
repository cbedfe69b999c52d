/* fuzz_seal.c: the seal check (seal.c), the first thing a control message meets in a DPU
 * with a key. Any bytes, on a control channel: a verdict, and the message's own length
 * within the input. The same bytes sealed here with the key: genuine once, a replay the
 * second time, forged (or unsealed) with any byte flipped; to a DPU without a key, sealed
 * input is refused as signed. The key is FUZZ_KEY_BYTE repeated (seeds.py seals with it). */
#include <stdlib.h>
#include <string.h>

#include "fuzz.h"

#define FUZZ_KEY_BYTE 0x5A
#define FUZZ_SEAL_MAX 4096

static skel_seal_t dpu, host, bare;

static void fuzz_seal_setup(void)
{
    FUZZ_ASSERT(seal_init(&dpu) == 0 && seal_init(&host) == 0 && seal_init(&bare) == 0);
    memset(dpu.key, FUZZ_KEY_BYTE, sizeof dpu.key);
    memset(host.key, FUZZ_KEY_BYTE, sizeof host.key);
    dpu.keyed = host.keyed = 1;
}

int LLVMFuzzerTestOneInput(const uint8_t *data, size_t size)
{
    static int ready;
    static uint8_t buf[FUZZ_SEAL_MAX + SKEL_SEAL_BYTES];
    if (!ready) {
        fuzz_seal_setup();
        ready = 1;
    }
    if (size > FUZZ_SEAL_MAX) return 0;
    const char *channel = size > 0 && (data[0] & 1) ? SKEL_CONFIG_CHANNEL : SKEL_COMMAND_CHANNEL;
    int len = (int)size, msg_len = -1;
    int verdict = seal_check(&dpu, 1, channel, data, len, &msg_len);
    FUZZ_ASSERT(verdict >= SEAL_GENUINE && verdict < SEAL_KINDS);
    FUZZ_ASSERT(msg_len == len || msg_len == len - SKEL_SEAL_BYTES);
    FUZZ_ASSERT(seal_check(&bare, 1, channel, data, len, &msg_len) != SEAL_FORGED);

    memcpy(buf, data, size);
    FUZZ_ASSERT(seal_sign(&host, channel, buf, len, buf + len) == 0);
    int sealed = len + SKEL_SEAL_BYTES;
    FUZZ_ASSERT(seal_check(&dpu, 1, channel, buf, sealed, &msg_len) == SEAL_GENUINE && msg_len == len);
    FUZZ_ASSERT(seal_check(&dpu, 1, channel, buf, sealed, &msg_len) == SEAL_REPLAYED);
    FUZZ_ASSERT(seal_check(&bare, 1, channel, buf, sealed, &msg_len) == SEAL_SIGNED);
    if (size > 0) {
        size_t at = data[size - 1] % (size_t)sealed;
        buf[at] ^= 0x01;
        int flipped = seal_check(&dpu, 1, channel, buf, sealed, &msg_len);
        FUZZ_ASSERT(flipped == SEAL_FORGED || flipped == SEAL_UNSIGNED);
    }
    return 0;
}
