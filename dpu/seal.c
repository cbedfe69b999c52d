/* seal.c: signed control. With a key, a control message is accepted only with a
 * seal (lcmtypes/seal_t.lcm) whose HMAC-SHA256 matches and whose counter is newer
 * than the last one accepted from its sender; what the DPU publishes on the
 * record URL carries a seal of its own. Without a key nothing is signed, and a
 * sealed message is refused: a DPU and a host that disagree about the key must
 * fail loudly, not half work.
 *
 * Everything here runs on the control thread: no locks. A flood of rejected
 * messages costs one MAC each and a counter; it logs one line per sender and
 * kind (at most SKEL_SEAL_NOTED of them), then a count every SKEL_SEAL_NOTE_NS. */
#include <errno.h>
#include <fcntl.h>
#include <string.h>
#include <sys/stat.h>
#include <unistd.h>

#include <sodium.h>

#include "dpu.h"

static const char *const seal_kind_names[SEAL_KINDS] = {
    [SEAL_GENUINE] = "genuine", [SEAL_UNSIGNED] = "unsigned", [SEAL_SIGNED] = "signed",
    [SEAL_FORGED] = "forged", [SEAL_REPLAYED] = "replayed",
};

int seal_init(skel_seal_t *k)
{
    memset(k, 0, sizeof *k);
    if (sodium_init() < 0) return -1;
    /* A random id, not the pid: two DPUs restarted with the same pid must not share counters. */
    randombytes_buf(&k->self, sizeof k->self);
    k->self &= INT64_MAX;
    return 0;
}

void seal_free(skel_seal_t *k)
{
    sodium_memzero(k->key, sizeof k->key);
    free(k->out);
    k->out = NULL;
    k->out_cap = 0;
}

int seal_load_key(skel_seal_t *k, const char *path, char *why, size_t len)
{
    int fd = open(path, O_RDONLY | O_CLOEXEC);
    if (fd < 0) {
        snprintf(why, len, "key file %s: %s (make one with `skel keygen %s`)", path, strerror(errno), path);
        return -1;
    }
    struct stat st;
    uint8_t extra;
    ssize_t got = -1;
    if (fstat(fd, &st) != 0) snprintf(why, len, "key file %s: %s", path, strerror(errno));
    else if (st.st_mode & (S_IRWXG | S_IRWXO))
        /* Anyone who reads the key can reconfigure every DPU: refuse, as ssh does. */
        snprintf(why, len, "key file %s: readable by others (mode %03o): chmod 600 %s", path,
                 (unsigned)(st.st_mode & 0777), path);
    else if ((got = read(fd, k->key, sizeof k->key)) != (ssize_t)sizeof k->key || read(fd, &extra, 1) != 0)
        snprintf(why, len, "key file %s: not a key: it must hold exactly %d bytes (`skel keygen`)", path,
                 SKEL_KEY_BYTES);
    else {
        close(fd);
        k->keyed = 1;
        return 0;
    }
    close(fd);
    sodium_memzero(k->key, sizeof k->key);
    return -1;
}

/* MAC = HMAC-SHA256(key, channel || 0 || message || the seal's first SEAL_SIGNED_BYTES). */
static void seal_mac(const skel_seal_t *k, const char *channel, const uint8_t *msg, int len,
                     const uint8_t *head, uint8_t mac[crypto_auth_hmacsha256_BYTES])
{
    crypto_auth_hmacsha256_state st;
    crypto_auth_hmacsha256_init(&st, k->key, sizeof k->key);
    crypto_auth_hmacsha256_update(&st, (const uint8_t *)channel, strlen(channel) + 1);
    crypto_auth_hmacsha256_update(&st, msg, (unsigned long long)len);
    crypto_auth_hmacsha256_update(&st, head, SKEL_SEAL_SIGNED_BYTES);
    crypto_auth_hmacsha256_final(&st, mac);
}

/* A seal is the last SEAL_BYTES of a message, known by seal_t's fingerprint. */
static int seal_find(const uint8_t *data, int len, skelmsg_seal_t *seal)
{
    if (len < SKEL_SEAL_BYTES) return 0;
    const uint8_t *at = data + len - SKEL_SEAL_BYTES;
    int64_t hash = 0;
    if (__int64_t_decode_array(at, 0, 8, &hash, 1) != 8 || (uint64_t)hash != (uint64_t)__skelmsg_seal_t_get_hash())
        return 0;
    return skelmsg_seal_t_decode(at, 0, SKEL_SEAL_BYTES, seal) == SKEL_SEAL_BYTES;
}

static void seal_note_first(skel_seal_t *k, int dpu, int kind, int64_t sender, const char *channel)
{
    for (int i = 0; i < k->nnoted; i++)
        if (k->noted[i].sender == sender && k->noted[i].kind == kind) return;
    if (k->nnoted == SKEL_SEAL_NOTED) return; /* many senders: the periodic count says the rest */
    k->noted[k->nnoted++] = (skel_noted_t){ sender, kind };
    static const char *const why[SEAL_KINDS] = {
        [SEAL_UNSIGNED] = "it has no seal: this DPU has a key and the sender none",
        [SEAL_SIGNED] = "it is signed: the sender has a key and this DPU none (--key FILE or $"
                        SKEL_KEY_ENV ")",
        [SEAL_FORGED] = "its MAC does not match: signed with another key than this DPU's, or altered",
        [SEAL_REPLAYED] = "replayed: its counter is not newer than the last accepted from that "
                          "sender, or older than this DPU's clock by more than the freshness window",
    };
    if (kind == SEAL_UNSIGNED)
        log_line("DPU %d: %s message refused: %s (further ones are counted)", dpu, channel, why[kind]);
    else
        log_line("DPU %d: %s message from sender %016llx refused: %s (further ones are counted)", dpu,
                 channel, (unsigned long long)sender, why[kind]);
}

/* Counter check and update for a genuine seal. The table holds the senders last
 * heard; when full, the least recently heard is forgotten (its replays then meet
 * the freshness window only). */
static int seal_fresh(skel_seal_t *k, const skelmsg_seal_t *seal, int64_t now_utc_ns)
{
    skel_sender_t *slot = NULL, *oldest = NULL;
    for (int i = 0; i < k->nsenders; i++) {
        if (k->senders[i].sender == seal->sender) slot = &k->senders[i];
        if (oldest == NULL || k->senders[i].heard_ns < oldest->heard_ns) oldest = &k->senders[i];
    }
    if (slot != NULL) {
        if (seal->counter <= slot->counter) return 0;
    } else {
        if (seal->counter < now_utc_ns - SKEL_SEAL_FRESH_S * SKEL_NS_PER_S) return 0;
        slot = k->nsenders < SKEL_SEAL_SENDERS ? &k->senders[k->nsenders++] : oldest;
        slot->sender = seal->sender;
    }
    slot->counter = seal->counter;
    slot->heard_ns = now_utc_ns;
    return 1;
}

int seal_check(skel_seal_t *k, int dpu, const char *channel, const void *data, int len, int *msg_len)
{
    skelmsg_seal_t seal;
    int sealed = seal_find(data, len, &seal);
    *msg_len = sealed ? len - SKEL_SEAL_BYTES : len;
    int kind = SEAL_GENUINE;
    if (!k->keyed) kind = sealed ? SEAL_SIGNED : SEAL_GENUINE;
    else if (!sealed) kind = SEAL_UNSIGNED;
    else {
        uint8_t mac[crypto_auth_hmacsha256_BYTES];
        const uint8_t *head = (const uint8_t *)data + *msg_len;
        seal_mac(k, channel, data, *msg_len, head, mac);
        if (crypto_verify_32(mac, seal.mac) != 0) kind = SEAL_FORGED;
        else if (!seal_fresh(k, &seal, clock_utc_ns())) kind = SEAL_REPLAYED;
    }
    if (kind != SEAL_GENUINE) {
        k->rejected[kind]++;
        seal_note_first(k, dpu, kind, kind == SEAL_UNSIGNED ? 0 : seal.sender, channel);
    }
    return kind;
}

void seal_note(skel_seal_t *k, int dpu)
{
    int64_t now = clock_mono_ns();
    if (now - k->noted_ns < SKEL_SEAL_NOTE_NS) return;
    k->noted_ns = now;
    char counts[160];
    size_t at = 0;
    for (int kind = SEAL_UNSIGNED; kind < SEAL_KINDS; kind++) {
        int64_t more = k->rejected[kind] - k->logged[kind];
        if (more > 0 && at < sizeof counts)
            at += (size_t)snprintf(counts + at, sizeof counts - at, "%s%lld %s", at ? ", " : "",
                                   (long long)more, seal_kind_names[kind]);
        k->logged[kind] = k->rejected[kind];
    }
    if (at > 0) log_line("DPU %d: control messages refused since the last count: %s", dpu, counts);
}

int seal_publish(skel_seal_t *k, lcm_t *lcm, const char *channel, const void *data, int len)
{
    if (k == NULL || !k->keyed) return clock_publish(lcm, channel, data, (unsigned)len);
    size_t need = (size_t)len + SKEL_SEAL_BYTES;
    if (need > k->out_cap) {
        /* Grows to the largest message once (a full timing batch): never in the cycle loop. */
        uint8_t *grown = realloc(k->out, need);
        if (grown == NULL) return -1;
        k->out = grown;
        k->out_cap = need;
    }
    memcpy(k->out, data, (size_t)len);
    if (seal_sign(k, channel, k->out, len, k->out + len) != 0) return -1;
    return clock_publish(lcm, channel, k->out, (unsigned)need);
}

int seal_sign(skel_seal_t *k, const char *channel, const uint8_t *msg, int len, uint8_t *tail)
{
    int64_t counter = clock_utc_ns();
    k->counter = counter > k->counter ? counter : k->counter + 1;
    skelmsg_seal_t seal = { .sender = k->self, .counter = k->counter };
    if (skelmsg_seal_t_encode(tail, 0, SKEL_SEAL_BYTES, &seal) != SKEL_SEAL_BYTES) return -1;
    seal_mac(k, channel, msg, len, tail, tail + SKEL_SEAL_SIGNED_BYTES);
    return 0;
}
