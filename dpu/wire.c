/* wire.c: safe decoding of received messages. lcm-gen's C decoders trust every
 * length they read (a negative one makes them malloc SIZE_MAX), so each message
 * is first walked by the generated skelmsg_<type>_check(). buffer_t and event_t,
 * received on the hot path, are not decoded at all (the decoder mallocs): their
 * fixed header is read in place with lcm_coretypes primitives. A unit test
 * compares this reader with the generated decoder, so drift fails a test. */
#include <stdlib.h>
#include <string.h>

#include <lcm/lcm_coretypes.h>

#include "dpu.h"
#include "skelmsg_check.h"

int wire_buffer_header(const void *buf, int len, wire_buffer_hdr_t *hdr)
{
    if (skelmsg_buffer_t_check(buf, len) != 0) return -1;
    int pos = 8;
    int n;
    memset(hdr, 0, sizeof *hdr);
    if ((n = __int64_t_decode_array(buf, pos, len - pos, &hdr->run_id, 1)) < 0) return -1;
    pos += n;
    if ((n = __int16_t_decode_array(buf, pos, len - pos, &hdr->writer, 1)) < 0) return -1;
    pos += n;
    if ((n = __int16_t_decode_array(buf, pos, len - pos, &hdr->buffer, 1)) < 0) return -1;
    pos += n;
    if ((n = __int64_t_decode_array(buf, pos, len - pos, &hdr->seq, 1)) < 0) return -1;
    pos += n;
    if ((n = __int64_t_decode_array(buf, pos, len - pos, &hdr->send_ns, 1)) < 0) return -1;
    pos += n;
    if ((n = __int32_t_decode_array(buf, pos, len - pos, &hdr->nbytes, 1)) < 0) return -1;
    return 0;
}

int wire_event_header(const void *buf, int len, wire_event_hdr_t *hdr)
{
    if (skelmsg_event_t_check(buf, len) != 0) return -1;
    int pos = 8;
    int n;
    memset(hdr, 0, sizeof *hdr);
    if ((n = __int64_t_decode_array(buf, pos, len - pos, &hdr->run_id, 1)) < 0) return -1;
    pos += n;
    if ((n = __int16_t_decode_array(buf, pos, len - pos, &hdr->dpu, 1)) < 0) return -1;
    pos += n;
    if ((n = __int16_t_decode_array(buf, pos, len - pos, &hdr->process, 1)) < 0) return -1;
    pos += n;
    if ((n = __int64_t_decode_array(buf, pos, len - pos, &hdr->seq, 1)) < 0) return -1;
    pos += n;
    if ((n = __int64_t_decode_array(buf, pos, len - pos, &hdr->sent_ns, 1)) < 0) return -1;
    return 0;
}

int wire_buffer_encoded_size(int32_t nbytes)
{
    return SKEL_BUFFER_HEADER_BYTES + nbytes;  /* fingerprint and fixed fields (contract.txt) */
}

/* On success the caller owns CFG and releases it with skelmsg_config_t_decode_cleanup. */
int wire_decode_config(const void *buf, int len, skelmsg_config_t *cfg)
{
    memset(cfg, 0, sizeof *cfg);
    if (skelmsg_config_t_check(buf, len) != 0) return -1;
    /* After a passed check the decoder cannot fail; if it ever did, a partial
     * decode's arrays are not safe to clean up, so they would leak, not crash. */
    return skelmsg_config_t_decode(buf, 0, len, cfg) < 0 ? -1 : 0;
}

/* On success the caller releases CMD (its sender string) with skelmsg_command_t_decode_cleanup. */
int wire_decode_command(const void *buf, int len, skelmsg_command_t *cmd)
{
    memset(cmd, 0, sizeof *cmd);
    if (skelmsg_command_t_check(buf, len) != 0) return -1;
    return skelmsg_command_t_decode(buf, 0, len, cmd) < 0 ? -1 : 0;
}

/* A config wire_decode_config decoded into malloc'd storage (command.c): its
 * arrays and strings, then itself. NULL is nothing. */
void wire_free_config(skelmsg_config_t *cfg)
{
    if (cfg == NULL) return;
    skelmsg_config_t_decode_cleanup(cfg);
    free(cfg);
}
