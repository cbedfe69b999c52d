/* test_seal.c: the seal check (dpu/seal.c) on messages sealed here: genuine once, then a
 * replay; any flipped byte, another channel or another key is forged; unsealed input is
 * unsigned to a keyed DPU and fine to one without a key, which refuses sealed input; key
 * files must hold exactly the key and be private. Python's side (analysis/read/seal.py)
 * checks the DPUs' seals in tests/unit/test_seal.py, and the DPUs check Python's. */
#include <fcntl.h>
#include <stdlib.h>
#include <sys/stat.h>
#include <unistd.h>

#include "check.h"
#include "dpu.h"

#define MSG_BYTES 40

static void keyed(skel_seal_t *k, uint8_t fill)
{
    CHECK_EQ(seal_init(k), 0);
    memset(k->key, fill, sizeof k->key);
    k->keyed = 1;
}

static int sealed(skel_seal_t *k, const char *channel, uint8_t *buf)
{
    for (int i = 0; i < MSG_BYTES; i++) buf[i] = (uint8_t)(i * 7);
    CHECK_EQ(seal_sign(k, channel, buf, MSG_BYTES, buf + MSG_BYTES), 0);
    return MSG_BYTES + SKEL_SEAL_BYTES;
}

static void test_checks(void)
{
    skel_seal_t dpu, host, stranger;
    keyed(&dpu, 1);
    keyed(&host, 1);
    keyed(&stranger, 2);
    uint8_t buf[MSG_BYTES + SKEL_SEAL_BYTES];
    int len = sealed(&host, SKEL_COMMAND_CHANNEL, buf), msg_len = -1;
    CHECK_EQ(seal_check(&dpu, 1, SKEL_COMMAND_CHANNEL, buf, len, &msg_len), SEAL_GENUINE);
    CHECK_EQ(msg_len, MSG_BYTES);
    CHECK_EQ(seal_check(&dpu, 1, SKEL_COMMAND_CHANNEL, buf, len, &msg_len), SEAL_REPLAYED);
    len = sealed(&host, SKEL_COMMAND_CHANNEL, buf); /* a newer counter: fine again */
    CHECK_EQ(seal_check(&dpu, 1, SKEL_CONFIG_CHANNEL, buf, len, &msg_len), SEAL_FORGED);
    for (int at = 0; at < len; at += 9) {
        len = sealed(&host, SKEL_COMMAND_CHANNEL, buf);
        buf[at] ^= 0x10;
        /* a flipped fingerprint byte makes it unsealed; any other, forged */
        int fp = at >= MSG_BYTES && at < MSG_BYTES + 8;
        CHECK_EQ(seal_check(&dpu, 1, SKEL_COMMAND_CHANNEL, buf, len, &msg_len), fp ? SEAL_UNSIGNED : SEAL_FORGED);
    }
    len = sealed(&stranger, SKEL_COMMAND_CHANNEL, buf);
    CHECK_EQ(seal_check(&dpu, 1, SKEL_COMMAND_CHANNEL, buf, len, &msg_len), SEAL_FORGED);
    CHECK_EQ(seal_check(&dpu, 1, SKEL_COMMAND_CHANNEL, buf, MSG_BYTES, &msg_len), SEAL_UNSIGNED);
    CHECK_EQ(msg_len, MSG_BYTES);
    CHECK_EQ(seal_check(&dpu, 1, SKEL_COMMAND_CHANNEL, buf, 3, &msg_len), SEAL_UNSIGNED);
    /* counted by kind, logged once per sender and kind */
    CHECK(dpu.rejected[SEAL_FORGED] >= 2 && dpu.rejected[SEAL_REPLAYED] == 1 && dpu.rejected[SEAL_UNSIGNED] >= 2);
    /* however many senders forge, at most SKEL_SEAL_NOTED lines name one */
    for (int i = 0; i < 3 * SKEL_SEAL_NOTED; i++) {
        stranger.self = 1000 + i;
        len = sealed(&stranger, SKEL_COMMAND_CHANNEL, buf);
        CHECK_EQ(seal_check(&dpu, 1, SKEL_COMMAND_CHANNEL, buf, len, &msg_len), SEAL_FORGED);
    }
    CHECK_EQ(dpu.nnoted, SKEL_SEAL_NOTED);
    skel_seal_t bare;
    CHECK_EQ(seal_init(&bare), 0);
    CHECK_EQ(seal_check(&bare, 1, SKEL_COMMAND_CHANNEL, buf, MSG_BYTES, &msg_len), SEAL_GENUINE);
    len = sealed(&host, SKEL_COMMAND_CHANNEL, buf);
    CHECK_EQ(seal_check(&bare, 1, SKEL_COMMAND_CHANNEL, buf, len, &msg_len), SEAL_SIGNED);
    seal_free(&dpu);
    seal_free(&host);
    seal_free(&stranger);
    seal_free(&bare);
}

static void test_key_files(void)
{
    char dir[] = "/tmp/skel-seal-XXXXXX";
    CHECK(mkdtemp(dir) != NULL);
    char path[64], why[512];
    snprintf(path, sizeof path, "%s/key", dir);
    skel_seal_t k;
    CHECK_EQ(seal_init(&k), 0);
    CHECK_EQ(seal_load_key(&k, path, why, sizeof why), -1);
    CHECK_HAS(why, "skel keygen");
    uint8_t bytes[SKEL_KEY_BYTES + 1] = { 0 };
    for (int n = SKEL_KEY_BYTES - 1; n <= SKEL_KEY_BYTES + 1; n++) {
        int fd = open(path, O_WRONLY | O_CREAT | O_TRUNC, 0600);
        CHECK(fd >= 0 && write(fd, bytes, (size_t)n) == n);
        close(fd);
        int rc = seal_load_key(&k, path, why, sizeof why);
        CHECK_EQ(rc, n == SKEL_KEY_BYTES ? 0 : -1);
        if (rc != 0) CHECK_HAS(why, "exactly 32 bytes");
    }
    CHECK_EQ(chmod(path, 0644), 0);
    CHECK_EQ(seal_load_key(&k, path, why, sizeof why), -1);
    CHECK_HAS(why, "readable by others");
    seal_free(&k);
    unlink(path);
    rmdir(dir);
}

int main(void)
{
    test_checks();
    test_key_files();
    return CHECK_DONE();
}
