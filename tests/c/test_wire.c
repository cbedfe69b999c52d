/* test_wire.c: every received type is checked before it is decoded. Valid
 * encodings pass; negative or huge lengths, truncation, a wrong fingerprint and
 * an unterminated string are refused; random corruption never crashes (ASan);
 * and wire.c's in-place buffer_t header equals the generated decoder. */
#include <stdlib.h>

#include "check.h"
#include "dpu.h"
#include "fixture.h"
#include "skelmsg_check.h"

static int encode_config(const skelmsg_config_t *c, uint8_t **out)
{
    int len = skelmsg_config_t_encoded_size(c);
    *out = malloc((size_t)len);
    return skelmsg_config_t_encode(*out, 0, len, c);
}

static void put_be(uint8_t *p, int bytes, int64_t v)
{
    for (int i = bytes - 1; i >= 0; i--, v >>= 8) p[i] = (uint8_t)(v & 0xff);
}

static void test_config_mutations(void)
{
    fixture_t f;
    fixture_init(&f);
    uint8_t *buf;
    int len = encode_config(&f.cfg, &buf);
    CHECK(len > 0);
    CHECK_EQ(skelmsg_config_t_check(buf, len), 0);
    skelmsg_config_t cfg;
    CHECK_EQ(wire_decode_config(buf, len, &cfg), 0);
    CHECK_EQ(cfg.nprocesses, 5);
    CHECK_EQ(cfg.processes[3].inputs[1], 3);
    skelmsg_config_t_decode_cleanup(&cfg);
    /* Truncated at every length: refused, never read past the end. */
    int truncated_ok = 0;
    for (int n = 0; n < len; n++) truncated_ok += skelmsg_config_t_check(buf, n) == 0;
    CHECK_EQ(truncated_ok, 0);
    /* `system` is right after generation, run_id, sent_utc_ns, committed. */
    const int sys_len_at = 8 + 8 + 8 + 8 + 1;
    const int sys_len = (int)strlen(f.cfg.system) + 1;
    const int nlinks_at = sys_len_at + 4 + sys_len + 4 * 4 + 8; /* the four pcts and cycles, seed */
    uint8_t *m = malloc((size_t)len);
    memcpy(m, buf, (size_t)len);
    m[sys_len_at + 4 + sys_len - 1] = 'x'; /* string without its NUL */
    CHECK(skelmsg_config_t_check(m, len) != 0);
    CHECK(wire_decode_config(m, len, &cfg) != 0);
    memcpy(m, buf, (size_t)len);
    put_be(m + sys_len_at, 4, -5); /* negative string length */
    CHECK(skelmsg_config_t_check(m, len) != 0);
    memcpy(m, buf, (size_t)len);
    put_be(m + nlinks_at, 2, -1); /* negative array length: lcm-gen would malloc SIZE_MAX */
    CHECK(skelmsg_config_t_check(m, len) != 0);
    CHECK(wire_decode_config(m, len, &cfg) != 0);
    memcpy(m, buf, (size_t)len);
    put_be(m + nlinks_at, 2, 32767); /* huge array length */
    CHECK(skelmsg_config_t_check(m, len) != 0);
    memcpy(m, buf, (size_t)len);
    m[0] ^= 0x40; /* wrong fingerprint */
    CHECK(skelmsg_config_t_check(m, len) != 0);
    CHECK(wire_decode_config(m, len, &cfg) != 0);
    /* A foreign type on our channel: a command is not a config. */
    skelmsg_command_t cmd = { .seq = 1, .kind = SKELMSG_COMMAND_T_PING, .dpu = -1, .ping_t1_ns = 5,
                              .sender = (char *)"test pid 1" };
    uint8_t cbuf[128];
    int clen = skelmsg_command_t_encode(cbuf, 0, sizeof cbuf, &cmd);
    CHECK(wire_decode_config(cbuf, clen, &cfg) != 0);
    skelmsg_command_t back;
    CHECK_EQ(wire_decode_command(cbuf, clen, &back), 0);
    CHECK_EQ(back.ping_t1_ns, 5);
    CHECK(strcmp(back.sender, "test pid 1") == 0);
    skelmsg_command_t_decode_cleanup(&back);
    CHECK(wire_decode_command(cbuf, clen - 1, &back) != 0);
    CHECK(wire_decode_command(buf, len, &back) != 0);
    free(m);
    free(buf);
}

/* lcm-gen's decoder is the reference the in-place header reader must match. */
static void test_buffer_header_matches_decoder(void)
{
    static uint8_t payload[3000];
    const int64_t values[] = { 0, 1, -1, INT64_MAX, INT64_MIN, 0x0102030405060708LL };
    for (int i = 0; i < 6; i++) {
        skelmsg_buffer_t msg = { values[i], (int16_t)(i - 3), (int16_t)(300 * i - 1), values[5 - i],
                                 values[(i + 2) % 6], (int32_t)(i * 500), payload };
        uint8_t enc[4096];
        int len = skelmsg_buffer_t_encode(enc, 0, sizeof enc, &msg);
        CHECK_EQ(len, wire_buffer_encoded_size(msg.nbytes));
        wire_buffer_hdr_t h;
        skelmsg_buffer_t dec;
        CHECK_EQ(wire_buffer_header(enc, len, &h), 0);
        CHECK(skelmsg_buffer_t_decode(enc, 0, len, &dec) >= 0);
        CHECK_EQ(h.run_id, dec.run_id);
        CHECK_EQ(h.writer, dec.writer);
        CHECK_EQ(h.buffer, dec.buffer);
        CHECK_EQ(h.seq, dec.seq);
        CHECK_EQ(h.send_ns, dec.send_ns);
        CHECK_EQ(h.nbytes, dec.nbytes);
        skelmsg_buffer_t_decode_cleanup(&dec);
    }
}

static void test_buffer_mutations(void)
{
    uint8_t payload[100] = { 0 };
    skelmsg_buffer_t msg = { 1, 2, 3, 4, 5, 100, payload };
    uint8_t enc[256], m[256];
    int len = skelmsg_buffer_t_encode(enc, 0, sizeof enc, &msg);
    const int nbytes_at = 8 + 8 + 2 + 2 + 8 + 8;
    wire_buffer_hdr_t h;
    memcpy(m, enc, (size_t)len);
    put_be(m + nbytes_at, 4, -1);
    CHECK(wire_buffer_header(m, len, &h) != 0);
    put_be(m + nbytes_at, 4, 0x7fffffff);
    CHECK(wire_buffer_header(m, len, &h) != 0);
    CHECK(wire_buffer_header(enc, len - 1, &h) != 0);
    CHECK(wire_buffer_header(enc, 10, &h) != 0);
    CHECK(wire_buffer_header(NULL, 0, &h) != 0);
    memcpy(m, enc, (size_t)len);
    m[7] ^= 1;
    CHECK(wire_buffer_header(m, len, &h) != 0);
    /* Trailing bytes beyond the message are tolerated, as the decoder does. */
    CHECK_EQ(wire_buffer_header(enc, len, &h), 0);
}

/* The in-place event reader against the decoder, and its refusals. */
static void test_event_header(void)
{
    skelmsg_event_t msg = { 42, 3, 7, 1000, -5, (char *)"shutter" };
    uint8_t enc[256], m[256];
    int len = skelmsg_event_t_encode(enc, 0, sizeof enc, &msg);
    CHECK(len > 0);
    wire_event_hdr_t h;
    skelmsg_event_t dec;
    CHECK_EQ(wire_event_header(enc, len, &h), 0);
    CHECK(skelmsg_event_t_decode(enc, 0, len, &dec) >= 0);
    CHECK_EQ(h.run_id, dec.run_id);
    CHECK_EQ(h.dpu, dec.dpu);
    CHECK_EQ(h.process, dec.process);
    CHECK_EQ(h.seq, dec.seq);
    CHECK_EQ(h.sent_ns, dec.sent_ns);
    skelmsg_event_t_decode_cleanup(&dec);
    const int name_len_at = 8 + 8 + 2 + 2 + 8 + 8;
    memcpy(m, enc, (size_t)len);
    put_be(m + name_len_at, 4, -1);
    CHECK(wire_event_header(m, len, &h) != 0);
    put_be(m + name_len_at, 4, 0x7fffffff);
    CHECK(wire_event_header(m, len, &h) != 0);
    CHECK(wire_event_header(enc, len - 1, &h) != 0);
    CHECK(wire_event_header(enc, 10, &h) != 0);
    memcpy(m, enc, (size_t)len);
    m[0] ^= 1; /* another type's fingerprint */
    CHECK(wire_event_header(m, len, &h) != 0);
}

/* Random byte flips: whatever the check lets through must decode cleanly. */
static void test_fuzz(void)
{
    fixture_t f;
    fixture_init(&f);
    uint8_t *buf;
    int len = encode_config(&f.cfg, &buf);
    uint8_t *m = malloc((size_t)len);
    unsigned seed = 12345;
    int accepted = 0, crashed = 0;
    for (int it = 0; it < 20000; it++) {
        memcpy(m, buf, (size_t)len);
        int flips = 1 + (int)(rand_r(&seed) % 4);
        for (int k = 0; k < flips; k++) m[rand_r(&seed) % (unsigned)len] = (uint8_t)rand_r(&seed);
        int n = len - (int)(rand_r(&seed) % 3);
        skelmsg_config_t cfg;
        if (wire_decode_config(m, n, &cfg) == 0) {
            accepted++;
            if (cfg.nprocesses < 0 || cfg.nlinks < 0) crashed++;
            skelmsg_config_t_decode_cleanup(&cfg);
        }
        wire_buffer_hdr_t h;
        (void)wire_buffer_header(m, n, &h);
        wire_event_hdr_t e;
        (void)wire_event_header(m, n, &e);
        skelmsg_command_t cmd;
        if (wire_decode_command(m, n, &cmd) == 0) skelmsg_command_t_decode_cleanup(&cmd);
    }
    CHECK_EQ(crashed, 0);
    CHECK(accepted < 20000);
    free(m);
    free(buf);
}

int main(void)
{
    test_config_mutations();
    test_buffer_header_matches_decoder();
    test_buffer_mutations();
    test_event_header();
    test_fuzz();
    return CHECK_DONE();
}
