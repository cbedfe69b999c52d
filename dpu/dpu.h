/* dpu.h: the types, limits and module interfaces of skel-dpu, the DPU daemon.
 *
 * One skel_server_t holds everything the daemon knows (Redis-style: one server
 * struct, no hidden globals). A configuration becomes a skel_plan_t: every
 * piece of memory a run needs, allocated when the config is applied, so the
 * cycle loop never allocates. Two threads share the server: the control thread
 * (config, commands, status, timing batches, reports) and the executive thread
 * (the cycles). They hand data over through the server mutex (plan swap, run
 * requests, lockouts) and a lock-free SPSC ring (timing records). */
#ifndef SKEL_DPU_H
#define SKEL_DPU_H

#include <pthread.h>
#include <stdatomic.h>
#include <stddef.h>
#include <stdint.h>
#include <sys/types.h>

#include <lcm/lcm.h>

#include "skel_step.h"
#include "skelmsg_buffer_t.h"
#include "skelmsg_command_t.h"
#include "skelmsg_config_t.h"
#include "skelmsg_contract.h"
#include "skelmsg_event_t.h"
#include "skelmsg_report_t.h"
#include "skelmsg_seal_t.h"
#include "skelmsg_status_t.h"
#include "skelmsg_timing_t.h"

/* ---- the wire contract's channels, default URL and limits (SKEL_CONFIG_CHANNEL,
 * SKEL_MAX_IO, ...) come from lcmtypes/contract.txt, shared with the host and the
 * analysis; a config beyond a limit is rejected with a reason, never truncated.
 * Below: what only this daemon decides. -------------------------------------------- */
#define SKEL_BUS_HEARD       4096 /* messages a bus sorts at once: more are taken in two batches */
#define SKEL_MAX_SLOTS       (SKEL_MAX_PROCESSES * SKEL_MAX_IO)
#define SKEL_MAX_LOCKOUTS    SKEL_MAX_PROCESSES /* once per process per run */
#define SKEL_RING_RECORDS    8192               /* timing records in flight */
#define SKEL_BATCH_RECORDS   64                 /* records per timing_t */
#define SKEL_BATCH_NS        (50 * 1000 * 1000LL)
#define SKEL_HISTORY_BYTES   (4 * 1024 * 1024)  /* published batches kept for RESEND */
#define SKEL_HISTORY_BATCHES 4096               /* ... at most this many */
#define SKEL_STATUS_NS       (SKEL_STATUS_PERIOD_MS * 1000 * 1000LL)
#define SKEL_REASON_LEN      256
#define SKEL_MAX_LIB_DIRS    8   /* --lib-dir given at most this often */
#define SKEL_RT_PRIORITY     10                 /* SCHED_FIFO of SLEEP-mode cycles, by default */
#define SKEL_STALL_NS        (50 * 1000LL)      /* a wake-up this late, a gap this long: not running */
#define SKEL_DRIFT_PCT       2.0                /* WORK calibration further off than this: said */
#define SKEL_SEEN_COMMANDS   64
#define SKEL_OWNER_LEN       128                /* "HOST pid N" of a run's host tool */
#define SKEL_STATUS_BYTES    5120               /* an encoded status_t: its strings and lockouts are bounded */
/* A received instant or duration further ahead than this is refused (START) or clamped
 * (COMMIT): any sum of instants and durations then stays far within an int64. */
#define SKEL_FAR_NS          (10LL * 365 * 24 * 3600 * 1000000000LL)

/* skel-dpu's exit codes (main.c) */
#define SKEL_EXIT_OK         0                  /* a clean shutdown (SIGTERM, SIGINT, SHUTDOWN) */
#define SKEL_EXIT_FAILED     1                  /* could not start, or could not run its threads */
#define SKEL_EXIT_USAGE      2                  /* a bad command line */

#define SKEL_NS_PER_US 1000LL
#define SKEL_NS_PER_S  1000000000LL

/* ---- logging (log.c) --------------------------------------------------------- */
void log_line(const char *fmt, ...) __attribute__((format(printf, 1, 2)));
void log_sanitize(char *line); /* control characters -> '?', in place */

/* ---- clock (clock.c): time and the wire, the machine's or a simulation's ---------- */
int64_t clock_mono_ns(void);
int64_t clock_utc_ns(void);
int64_t clock_thread_cpu_ns(void);
/* The calling thread's involuntary context switches so far (0 if unknown). */
int64_t clock_thread_preemptions(void);
int64_t clock_stops(void); /* the times the process was stopped and continued so far */
/* The monotonic instant of UTC instant AT, given one simultaneous reading of both clocks. */
int64_t clock_utc_to_mono(int64_t at_utc_ns, int64_t now_mono_ns, int64_t now_utc_ns);
int64_t clock_mono_to_utc(int64_t at_mono_ns, int64_t now_mono_ns, int64_t now_utc_ns);
/* Absolute sleep on CLOCK_MONOTONIC; returns early (1) when *stop becomes set. */
int clock_sleep_until(int64_t mono_ns, atomic_int *stop);
/* One absolute sleep until UNTIL; it may end early (a signal, another fiber's join): 0, -1 failed. */
int clock_nap(int64_t until);

/* The wire as the executives reach it: LCM on the machine, the simulation's delivery under
 * one. A channel's subscription names it plainly (CHANNEL) beside LCM's regular expression. */
lcm_t *clock_open(const char *url);
void clock_close(lcm_t *lcm);
lcm_subscription_t *clock_subscribe(lcm_t *lcm, const char *channel, const char *regex,
                                    lcm_msg_handler_t handler, void *user);
int clock_publish(lcm_t *lcm, const char *channel, const void *data, unsigned len);
int clock_handle(lcm_t *lcm);                     /* one message received: 1, none: 0, -1 */
/* Simulated only: waits up to TIMEOUT_NS for a message on one of LCMS: >0 one came, 0 not. */
int clock_wait(lcm_t *const *lcms, int n, int64_t timeout_ns);

/* A thread of the DPU's own (the event generators): a kernel thread, or a simulation's fiber. */
typedef struct {
    pthread_t tid;
    int fiber;
    int simulated;
} clock_thread_t;

int clock_thread_start(clock_thread_t *t, void *(*fn)(void *), void *arg); /* 0, or an error */
int clock_thread_join(clock_thread_t *t);

/* A simulated world (sim.c): virtual CLOCK_MONOTONIC, and messages delivered by it. Every
 * DPU of a system runs on one thread, each executive and generator a fiber of it. */
typedef struct {
    void *ctx;
    int64_t utc_offset_ns;                            /* UTC = monotonic + this */
    int64_t (*now)(void *ctx);
    void (*nap)(void *ctx, int64_t until);
    lcm_t *(*open)(void *ctx, const char *url);
    void (*close)(void *ctx, lcm_t *lcm);               /* before LCM destroys it */
    int (*subscribe)(void *ctx, lcm_t *lcm, const char *channel, lcm_msg_handler_t handler, void *user);
    int (*publish)(void *ctx, lcm_t *lcm, const char *channel, const void *data, unsigned len);
    int (*handle)(void *ctx, lcm_t *lcm);
    int (*wait)(void *ctx, lcm_t *const *lcms, int n, int64_t timeout_ns);
    int (*spawn)(void *ctx, int *fiber, void *(*fn)(void *), void *arg);
    int (*join)(void *ctx, int fiber);
    void (*poke)(void *ctx);   /* the current DPU's waiting fibers wake now (server_wake's eventfd) */
} clock_world_t;

void clock_simulate(const clock_world_t *world); /* before anything runs; NULL: the machine */
int clock_simulated(void);
void clock_poke(void); /* simulated: the current DPU's waits wake now, as server_wake's eventfd does */

/* ---- wire (wire.c): every received message is checked before it is decoded ---- */
typedef struct {
    int64_t run_id;
    int16_t writer;
    int16_t buffer;
    int64_t seq;
    int64_t send_ns;
    int32_t nbytes;
} wire_buffer_hdr_t;

int wire_buffer_header(const void *buf, int len, wire_buffer_hdr_t *hdr);

/* An event_t's fixed fields, read in place (its name is the channel's). */
typedef struct {
    int64_t run_id;
    int16_t dpu;
    int16_t process;
    int64_t seq;
    int64_t sent_ns;
} wire_event_hdr_t;

int wire_event_header(const void *buf, int len, wire_event_hdr_t *hdr);
int wire_decode_config(const void *buf, int len, skelmsg_config_t *cfg);
int wire_decode_command(const void *buf, int len, skelmsg_command_t *cmd);
void wire_free_config(skelmsg_config_t *cfg); /* one wire_decode_config filled in malloc'd storage */
int wire_buffer_encoded_size(int32_t nbytes);

/* ---- buffers (buffers.c): what a DPU holds of each buffer it reads ------------- */
struct skel_plan;

/* A version received and held back by the link's emulated latency until it is due. */
typedef struct {
    int64_t seq, send_ns, due_ns;
} skel_pending_t;

/* The transport the reading DPU emulates for one buffer (link_t's latency, jitter, loss). */
typedef struct {
    int64_t latency_ns, jitter_ns;
    int8_t jitter;             /* link_t JITTER_* */
    int8_t from_send;          /* the writer shares this DPU's clock: due from its send stamp,
                                * else from the arrival (the real network's delay adds) */
    double loss, enter, leave, burst_loss; /* probabilities per version (Gilbert-Elliott) */
} skel_transport_t;

/* A message on a bandwidth-limited link, heard and not yet through its transmitter. */
typedef struct {
    struct skel_slot *slot;
    int64_t seq, send_ns, from_ns, recv_ns;
    int32_t bytes;             /* on the wire */
} skel_heard_t;

/* A bandwidth-limited link as one reading DPU emulates it: one transmitter that every
 * message on the link queues for, in the order of their send stamps (buffers.c): what the
 * DPU heard since it last read its inputs is sorted first, since its sockets are read one
 * after the other. Each reading DPU keeps its own, from the same messages: on virtual time
 * they agree exactly. */
typedef struct {
    int16_t link;              /* link_t.id */
    double ns_per_byte;        /* 8000 / bandwidth_mbps */
    int64_t queue_ns;          /* a message that would wait longer is dropped (tail drop) */
    int64_t free_ns;           /* the transmitter is busy until then */
    int64_t dropped;           /* messages the full queue dropped in this run */
    skel_heard_t *heard;       /* heard since the last flush, SKEL_BUS_HEARD of them at most */
    int nheard;
} skel_bus_t;

/* One buffer this DPU reads (shared by all its readers on this DPU), or, on a bandwidth-
 * limited link, one it only hears so that its messages take their turn on the bus
 * (unread). Written by the link handler or by a local writer; read by process cycles;
 * one thread. */
typedef struct skel_slot {
    int16_t buffer;
    int16_t writer;
    int link;                  /* index into plan->links, -1: local memory */
    char *channel;
    int64_t newest_seq;        /* -1: nothing yet in this run */
    int64_t dup_upto;          /* live switch: seqs <= this came via the old plan's link, -1: none */
    int64_t newest_send_ns;
    int64_t newest_recv_ns;
    int64_t received;          /* messages accepted in this run */
    int64_t foreign;           /* messages of another run (ignored) */
    struct skel_plan *plan;
    /* The link's emulated transport (buffers.c): NULL pending when it has no latency. */
    skel_transport_t tr;
    skel_bus_t *bus;           /* its link's transmitter (plan->buses), NULL: no bandwidth given */
    int32_t wire_extra;        /* a message's bytes on the bus besides its payload */
    int8_t unread;             /* heard for the bus only: no process here reads it */
    int64_t heard_seq;         /* the newest sequence that reached its bus, -1: none (live switch) */
    skel_pending_t *pending;   /* a ring of pend_cap, sized at config time */
    int pend_cap, pend_head, pend_count;
    int64_t last_due_ns;       /* versions are delivered in order: none due before this */
    int8_t bad;                /* Gilbert-Elliott: in the bad state */
    uint64_t state[4];         /* its draws, seeded by the run's seed, this DPU and the buffer */
    int64_t lost, overflow;    /* versions the emulation lost; versions a full ring dropped */
    /* The newest message's payload, kept only when real code here reads it (code.c): cap 0
     * for a skeleton's slot, whose bytes nothing reads. */
    uint8_t *bytes;
    int32_t cap, nbytes;
} skel_slot_t;

/* One input of one process: what it last used, and its measured-window sums. */
typedef struct {
    int slot;
    int16_t buffer;
    int8_t required;
    int64_t last_used;         /* -1: nothing used yet; SKEL_SEQ_JOINED: input added mid-run */
    int64_t received_seen;     /* slot->received at the previous cycle */
    int64_t n_new, n_stale, n_dropped;
    int64_t message_ns;        /* link cost per message received here, when this process pays it (plan.c) */
} skel_input_t;

/* What one cycle saw on one input. */
typedef struct {
    int16_t buffer;
    int8_t new_data;
    int32_t dropped;
    int32_t received;
    int64_t seq;
    int64_t sent_ns;
    int64_t recv_ns;
} skel_in_rec_t;

typedef struct {
    int16_t buffer;
    int link;                  /* -1: local */
    int local_slot;            /* local: the slot readers on this DPU use, -1: none */
    char *channel;
    int32_t bytes;
    uint8_t *enc;              /* preallocated encoded buffer_t */
    int enc_len;
} skel_output_t;

enum { BUFFERS_ACCEPTED = 0, BUFFERS_FOREIGN_RUN = 1, BUFFERS_DUPLICATE = 2, BUFFERS_MISMATCH = -1 };
/* An input that joins a running run (live switch): its first new data counts no drops. */
#define SKEL_SEQ_JOINED INT64_MIN

void buffers_slot_reset(skel_slot_t *slot);
/* PAYLOAD: the message's hdr->nbytes bytes, kept when SLOT keeps bytes (NULL: none sent). */
int buffers_slot_receive(skel_slot_t *slot, int64_t run_id, const wire_buffer_hdr_t *hdr,
                         const uint8_t *payload, int64_t recv_ns);
void buffers_slot_seed(skel_slot_t *slot, int64_t seed, int16_t dpu);
/* A live switch: what OLD's emulated link still holds comes as it would have (its draws go on). */
void buffers_slot_carry(skel_slot_t *slot, const skel_slot_t *old);
/* Takes the held versions due at NOW into the slot: what a reader may see from then on. */
void buffers_slot_advance(skel_slot_t *slot, int64_t now_ns);
/* Every slot's versions due by NOW (monotonic): the next instant one is (INT64_MAX: none). */
int64_t buffers_advance(struct skel_plan *plan, int64_t now_mono_ns);
void buffers_bus_reset(skel_bus_t *bus);
void buffers_flush(const struct skel_plan *plan);
void buffers_input_reset(skel_input_t *in);
void buffers_input_peek(const skel_input_t *in, const skel_slot_t *slot, skel_in_rec_t *rec);
void buffers_input_commit(skel_input_t *in, const skel_slot_t *slot, const skel_in_rec_t *rec,
                          int measured);
int buffers_output_encode(skel_output_t *out, int64_t run_id, int16_t writer, int64_t seq,
                          int64_t send_ns, const uint8_t *payload, int32_t nbytes);

/* ---- compute (compute.c): the emulated computation ----------------------------- */
typedef struct {
    double work_iters_per_us;  /* this CPU's calibration of the WORK kernel (the reference) */
    int64_t spin_ns;           /* SLEEP: spin this last stretch */
    int64_t stall_ns;          /* a wake-up this late, or a gap this long: the thread was not running */
} skel_compute_t;

#define CALIBRATION_RUNS_MAX 15
#define CALIBRATION_RUN_NS   (4 * 1000 * 1000LL)

int compute_calibrate(skel_compute_t *c);
double compute_check_calibration(const skel_compute_t *c); /* % slower than the reference */
int64_t compute_run(const skel_compute_t *c, int mode, int64_t ns, int64_t *stall);
/* Busy until the thread was seen holding the processor NS (gaps longer than
 * the stall threshold are not counted); returns that time. UNSWITCHED (or
 * NULL) gets the gaps during which the thread was not switched out: the
 * machine stopped the CPU. */
int64_t compute_held(const skel_compute_t *c, int64_t ns, int64_t *unswitched);
uint64_t compute_work_kernel(uint64_t iterations);

/* ---- timing (timing.c): per-cycle records, SPSC ring, timing_t batches ---------- */
typedef struct {
    int16_t process;
    int8_t flags;
    int8_t ninputs;
    int64_t generation;        /* of the plan that ran the cycle: batches never mix two */
    int32_t preemptions;
    int16_t event_queued;
    int32_t event_dropped;
    int64_t cycle, minor, release_ns, sched_ns, start_ns, comm_in_ns, blocked_ns, asked_ns, compute_ns,
        comm_out_ns, idle_ns, slack_ns, stall_ns, debt_ns, preempted_ns, event_ns;
    skel_in_rec_t in[SKEL_MAX_IO];
} skel_rec_t;

typedef struct {
    skel_rec_t *recs;
    uint64_t cap;              /* a power of two */
    _Alignas(64) atomic_uint_fast64_t head;  /* next write (producer) */
    _Alignas(64) atomic_uint_fast64_t tail;  /* next read (consumer) */
    _Alignas(64) atomic_int_fast64_t lost;
} skel_ring_t;

int timing_ring_init(skel_ring_t *ring, uint64_t cap);
void timing_ring_free(skel_ring_t *ring);
int timing_ring_push(skel_ring_t *ring, const skel_rec_t *rec);
int timing_ring_pop(skel_ring_t *ring, skel_rec_t *rec);

/* A timing_t whose arrays are preallocated for SKEL_BATCH_RECORDS records. */
typedef struct {
    skelmsg_timing_t msg;
    int64_t first_add_ns;
} skel_batch_t;

int timing_batch_init(skel_batch_t *b);
void timing_batch_free(skel_batch_t *b);
void timing_batch_clear(skel_batch_t *b);
int timing_batch_full(const skel_batch_t *b);
void timing_batch_add(skel_batch_t *b, const skel_rec_t *rec);

/* ---- history (history.c): what was published, for a RESEND ---------------------- */
typedef struct {
    int64_t seq;               /* -1: empty */
    uint64_t at;               /* offset in the ring's byte stream */
    uint32_t len;
} skel_held_t;

typedef struct {
    uint8_t *bytes;            /* SKEL_HISTORY_BYTES, a ring of encoded batches */
    skel_held_t *held;         /* SKEL_HISTORY_BATCHES slots, by batch_seq */
    uint64_t head;             /* bytes stored since start-up */
    int64_t run_id;            /* the run they belong to */
    uint8_t *enc;              /* one encoded batch */
    int enc_cap;
    uint8_t *report;           /* the run's report_t as published */
    int report_len, report_cap;
    struct skel_seal *seal;    /* signs what is published; NULL: nothing */
} skel_history_t;

typedef struct {
    int64_t run_id, from, to;  /* batches from..to inclusive (to < from: none) */
    int with_report;
} skel_resend_t;

int history_init(skel_history_t *h, int batch_bytes);
void history_free(skel_history_t *h);
void history_reset(skel_history_t *h, int64_t run_id);
int history_publish_batch(skel_history_t *h, lcm_t *lcm, const skelmsg_timing_t *msg);
int history_publish_report(skel_history_t *h, lcm_t *lcm, const skelmsg_report_t *r);
int history_resend(skel_history_t *h, lcm_t *lcm, const skel_resend_t *ask, int *gone);

/* ---- link (link.c): one lcm_t per distinct link URL ----------------------------- */
typedef struct {
    char *url;
    lcm_t *lcm;
    int fd;                    /* LCM's notify pipe once something is subscribed; -1 on a link only written */
    int32_t largest;           /* the largest message (encoded bytes) its socket receives */
    int64_t last_arrival_ns;   /* the latest receive stamp given out (link_arrival_ns) */
} skel_link_t;

/* A socket's receive buffer is asked for a message of ENCODED bytes whole plus
 * SKEL_RECV_SLACK_BYTES (the contract's: the analysis judges delivery by it), one
 * more LCM fragment of slack (its headers, the next message). The kernel grants
 * twice what is asked, for its bookkeeping, up to net.core.rmem_max. */
int link_url(const skel_link_t *link, char *out, size_t len, int32_t *asked);
int link_open(skel_link_t *link);
int link_record_url(const char *control, char *out, size_t len);
int link_group_port(const char *url, uint32_t *group, unsigned *port, int *ttl);
void link_close(skel_link_t *link);
void link_receive(skel_slot_t *slot, const lcm_recv_buf_t *rbuf); /* a buffer_t on SLOT's channel */
int link_subscribe(skel_link_t *link, skel_slot_t *slot);
int link_subscribe_channel(skel_link_t *link, const char *channel, lcm_msg_handler_t handler, void *user);
int64_t link_arrival_ns(skel_link_t *link, const lcm_recv_buf_t *rbuf);
int link_drain(skel_link_t *links, int nlinks);
int link_wait(skel_link_t *links, int nlinks, int wake_fd, int64_t timeout_ns);

/* ---- plan (plan.c, config.c): one DPU's part of a config, ready to run ---------- */
/* One process's totals over the measured window (report_t's process_report_t);
 * a live switch carries them over whole. */
typedef struct {
    int64_t cycles, overruns, compute_ns, communicate_ns, wait_ns, max_latency_ns, releases_skipped,
        events_dropped;
} skel_process_sums_t;

/* ---- draw (draw.c): a compute time that varies ---------------------------------- */
typedef struct {
    int n;                                /* points of the table; < 2: constant */
    double table_ns[SKEL_QUANTILES];      /* quantile function, over the DPU's speed */
    uint64_t state[4];                    /* the process's generator */
} skel_draw_t;

void draw_seed(skel_draw_t *d, int64_t seed, int16_t process);
int64_t draw_ns(skel_draw_t *d, int64_t constant_ns);
/* A generator of its own for anything else a run draws (event generators): STREAM
 * keeps it apart from every process's. */
void draw_seed_state(uint64_t state[4], int64_t seed, uint64_t stream);
double draw_unit(uint64_t state[4]); /* [0, 1) */

/* ---- event (event.c): sync: event processes, emitted and generated events ------- */
struct skel_plan;

/* One event this DPU awaits, emits or generates; its name is its channel's suffix. */
typedef struct {
    char *name;
    char *channel;             /* SKEL_EVENT_PREFIX + name */
    int awaited;               /* a process here awaits it: subscribed */
    uint8_t *enc;              /* an encoded event_t, the executive thread's (emits) */
    int enc_cap;
    int64_t seq;
    struct skel_plan *plan;
} skel_event_t;

/* A generator of one event during a run (events: with dpu: this one); its own thread. */
typedef struct {
    int8_t kind;               /* event_source_t KIND_* */
    int event;                 /* index into plan->events */
    int64_t period_ns, jitter_ns, spacing_ns;
    double rate_hz;
    int32_t count;
    uint64_t state[4];
    int64_t next_ns, k;        /* the next instant, and the events so far */
    uint8_t *enc;              /* the generator thread's encoded event_t */
    int enc_cap;
} skel_source_t;

/* The events waiting for a sync: event process (event.c), oldest first, as arrival
 * instants, and the one its coming cycle handles. */
typedef struct {
    int16_t cap;               /* queue: N */
    int64_t queued_ns[SKEL_MAX_QUEUE];
    int head, count;
    int64_t arrived_ns[SKEL_MAX_QUEUE]; /* drained, not yet in the queue (event_settle) */
    int a_head, a_count;
    int32_t dropped;           /* since its last cycle */
    int64_t taken_ns;          /* arrival of the event the coming cycle handles, -1: none */
    int16_t taken_left;
    int32_t taken_dropped;
} skel_queue_t;

/* A process's one job on the tasking executive (job.c; tasking.c, threads.c). */
enum { JOB_NONE = 0, JOB_WAITING, JOB_READY, JOB_STARTED };
typedef struct {
    int8_t state;              /* JOB_* */
    int64_t lockout_k;         /* the cycle its lockout was recorded for (its record's flag), -1 */
    int8_t missing;            /* a waiting data job: its first required input without new data */
    int64_t anchor_ns;         /* release next_k = 0: the run's start, or the first at or after a switch */
    int64_t back_period_ns;    /* the period of releases next_k < 0 (the plan before a switch) ... */
    int64_t back_generation;   /* ... and that plan's generation */
    int64_t generation;        /* of the plan that released the job: its record's */
    int64_t release;
    int64_t remaining_ns;      /* of the job's computation */
    int64_t slice_mono_ns;     /* where its computation was last counted up to (tasking_ran) */
    skel_rec_t rec;            /* the job's record, sent at its completion */
} skel_job_t;

/* ---- code (code.c): real application code in place of the emulated computation -- */
#define SKEL_CODE_GUARD 64     /* bytes before and after each output a step's stray write lands in */
typedef struct {
    void *handle;              /* dlopen's, at config apply time (control thread) */
    skel_step_fn step;
    skel_step_init_fn init;    /* NULL: the library has none */
    skel_step_fini_fn fini;
    void *state;
    int started;               /* init ran for the current run: fini is owed */
    char name[SKEL_MAX_NAME + 1];
    skel_step_input_t in[SKEL_MAX_IO];
    skel_step_output_t out[SKEL_MAX_IO];
    uint8_t *out_bytes;        /* every output's bytes, one allocation, guards between */
    uint8_t *guards[SKEL_MAX_IO + 1]; /* before the first output, after each (code.c) */
    int failed;                /* this cycle's step failed: its outputs are not published */
    int64_t faults;            /* steps that failed this run */
} skel_code_t;

typedef struct {
    int16_t id;
    int16_t order;
    int16_t priority;          /* the tasking executive's, higher first: plan->processes are sorted by it there */
    int8_t sync;
    int64_t period_ns;
    int64_t compute_ns;        /* the constant, or the mean of the draws */
    int64_t ready_ns;          /* cyclic, sync: data: when the schedule has its data come, after
                                * its release (process_t.ready_us); 0: no wait planned */
    skel_draw_t draw;
    int64_t ratio;             /* period / minor cycle */
    /* Link costs (plan.c), charged in the DPU's compute mode: comm_in every cycle (remote
     * reads; plus its inputs' message_ns per message received), comm_out every cycle, and
     * the mean of both per cycle (the configured load). */
    int64_t charge_in_ns, charge_out_ns, charge_mean_ns;
    int ninputs, noutputs;
    skel_input_t inputs[SKEL_MAX_IO];
    skel_output_t outputs[SKEL_MAX_IO];
    int16_t event;             /* sync: event: index into plan->events, -1: not an event process */
    int nemits;
    int16_t emits[SKEL_MAX_EMITS];   /* indexes into plan->events */
    /* run state and measured-window sums */
    int64_t k_base;            /* cycle index of this plan's first cycle (live switch: carried) */
    int64_t next_k;            /* the next cycle from k_base not released yet (tasking: < 0, one of
                                * the plan before a switch); an event process's: its events so far */
    int64_t measure_from_k;    /* cycles >= this count in the sums (warm-up applied once) */
    int8_t locked_out;
    skel_process_sums_t sums;
    skel_job_t job;            /* the tasking executive's */
    skel_queue_t queue;        /* an event process's */
    skel_code_t *code;         /* real code (code.c), NULL: a skeleton */
} skel_process_t;

typedef struct {
    int64_t first_release_ns;  /* the earliest measured release; -1: none yet */
    int64_t first_start_ns;    /* of a measured cycle; -1: none yet */
    int64_t warmup_end_ns;     /* the latest end of a warm-up cycle's work; -1: none yet */
    int64_t end_ns;            /* the latest end of a measured cycle's work plus its idle */
    int64_t minor_cycles;
    int64_t compute_ns, communicate_ns, wait_ns, stall_ns;
} skel_dpu_sums_t;

/* ---- shape (shape.c): a link's modelled network enforced by this host's kernel ------ */
#define SHAPE_DELAY 1           /* latency and jitter: netem */
#define SHAPE_LOSS 2            /* loss: netem, or nftables where netem is missing */
#define SHAPE_RATE 4            /* bandwidth: tbf */
#define SHAPE_MAX_GROUPS 8      /* a link's groups the kernel path takes */
#define SHAPE_CMD_LEN 384
#define SHAPE_SCRIPT_LEN 16384
#define SHAPE_TEXT_LEN 1024     /* status_t.network */
typedef struct {
    skelmsg_link_t link;        /* its model (strings not owned) */
    int8_t taken;               /* SHAPE_*: enforced by the kernel; the rest emulated */
    int8_t netem_loss;          /* its loss by netem (else nftables) */
    char dev[16];               /* where its groups arrive */
    char name[16];              /* its ifb device and nft table */
    int pref;                   /* its ingress filters' */
    int frame;                  /* its largest message's bytes on an Ethernet (before IP fragments) */
    int ngroups;
    uint32_t groups[SHAPE_MAX_GROUPS];
    unsigned ports[SHAPE_MAX_GROUPS];
} skel_shape_link_t;

typedef struct {
    int n;
    skel_shape_link_t links[SKEL_MAX_LINKS];
    char text[SHAPE_TEXT_LEN];  /* each modelled property's path, per link */
} skel_shape_t;

typedef struct {
    pid_t guard;                /* 0: nothing applied */
    int fd;                     /* its pipe: closed, it undoes */
} skel_shaper_t;

void shape_plan(skel_shape_t *sh, const skelmsg_config_t *cfg, int16_t dpu);
int shape_taken(const skel_shape_t *sh, int16_t link); /* SHAPE_* */
int shape_apply(skel_shaper_t *sp, const skel_shape_t *sh, char *reason, size_t len);
void shape_remove(skel_shaper_t *sp);

typedef struct skel_plan {
    int64_t generation;
    int16_t dpu;
    int16_t cpu;
    int8_t compute;
    int8_t tasking;             /* executive: threads (tasking.c) rather than cyclic */
    double speed;
    int64_t minor_ns;
    int64_t common_ns;          /* the grid all DPUs share (a multiple of minor_ns): live switches */
    int fits;                   /* the configured load fits (<= 100 %): cycle skipping applies */
    int32_t warmup_cycles;
    int32_t lockout_cycles;
    int64_t seed;               /* every process's draws start from it at each run */
    int nprocesses;
    skel_process_t *processes;  /* sorted by (order, id) */
    int nslots;
    skel_slot_t *slots;
    int nlinks;
    skel_link_t links[SKEL_MAX_LINKS];
    int nbuses;
    skel_bus_t *buses;          /* SKEL_MAX_LINKS of them, nbuses used */
    uint8_t *dummy;             /* the payload every output sends */
    /* run context read by the link handler (executive thread only) */
    int64_t run_id;
    int64_t run_t0_ns;          /* the run's first release (monotonic) */
    int64_t epoch_t0_ns;        /* this plan's minor 0: the run's start or its switch instant */
    int64_t minor_base;         /* run-wide index of this plan's minor 0 */
    int running;
    int64_t clock_offset_ns;
    atomic_int_fast64_t *rejected;
    int64_t publish_errors;
    int64_t measure_from_ns;    /* DPU window: every process past its warm-up */
    double work_drift_pct;      /* WORK: the larger calibration drift of the run's start and end */
    skel_dpu_sums_t sums;
    /* events (event.c): received, emitted and generated on the control URL */
    int nevents;
    skel_event_t events[SKEL_MAX_EVENTS];
    int event_link;             /* index into links of the control URL, -1: no events here */
    int awaits_events;          /* some process here is sync: event */
    int nsources;
    skel_source_t sources[SKEL_MAX_EVENTS];
    lcm_t *gen_lcm;             /* the generator thread's own lcm_t */
    lcm_t *gen_rec;             /* ... and its own on the record URL, for the log's copy */
    lcm_t *emit_rec;            /* the executive's on the record URL, for the log's copy of what it emits */
    clock_thread_t gen_thread;
    int gen_started;
    atomic_int gen_stop;
    int64_t gen_end_ns;
    skel_shape_t shape;         /* what the kernel takes of its links' model (shape.c) */
} skel_plan_t;

typedef struct {
    int dpu_index;             /* index into cfg->dpus, -1 when absent */
    int16_t dpu_id;
    char reason[SKEL_REASON_LEN];
} skel_self_t;

int config_find_self(const skelmsg_config_t *cfg, int id_arg, const char *hostname,
                     skel_self_t *self);
int config_validate(const skelmsg_config_t *cfg, int dpu_index, char *reason, size_t len);
int64_t config_minor_us(const skelmsg_config_t *cfg, const skelmsg_dpu_t *d);
int64_t config_common_us(const skelmsg_config_t *cfg);
const skelmsg_buffer_desc_t *config_buffer(const skelmsg_config_t *cfg, int16_t id);
const skelmsg_link_t *config_link(const skelmsg_config_t *cfg, int16_t id);
const skelmsg_process_t *config_process(const skelmsg_config_t *cfg, int16_t id);
const char *config_host(const skelmsg_config_t *cfg, int16_t id);
int config_reads_link(const skelmsg_config_t *cfg, int16_t dpu, int16_t link);
skel_plan_t *plan_build(const skelmsg_config_t *cfg, int dpu_index, char *reason, size_t len);
int plan_open_links(skel_plan_t *plan, const char *control_url, const char *record_url,
                    atomic_int_fast64_t *rejected, char *reason, size_t len);
void plan_free(skel_plan_t *plan);
void plan_reset_run(skel_plan_t *plan, int64_t run_id);
int plan_process_index(const skel_plan_t *plan, int16_t id);

/* ---- the server: everything the daemon knows --------------------------------- */
typedef struct {
    int requested;             /* a START is waiting for the executive */
    int64_t run_id;
    int64_t generation;
    int64_t start_mono_ns;
    int64_t end_mono_ns;       /* INT64_MAX: until STOP */
} skel_run_t;

/* ---- seal (seal.c): signed control, HMAC-SHA256 with a shared key; control thread only */
enum { SEAL_GENUINE = 0, SEAL_UNSIGNED, SEAL_SIGNED, SEAL_FORGED, SEAL_REPLAYED, SEAL_KINDS };
#define SKEL_SEAL_SENDERS 64                      /* senders whose last counter is kept */
#define SKEL_SEAL_NOTED   16                      /* first rejections logged by sender and kind */
#define SKEL_SEAL_NOTE_NS (10 * SKEL_NS_PER_S)    /* then a count at most this often */

typedef struct {
    int64_t sender, counter, heard_ns;
} skel_sender_t;

typedef struct {
    int64_t sender;
    int kind;
} skel_noted_t;

typedef struct skel_seal {
    int keyed;
    uint8_t key[SKEL_KEY_BYTES];
    int64_t self, counter;                        /* our sender id and last counter */
    skel_sender_t senders[SKEL_SEAL_SENDERS];
    int nsenders;
    skel_noted_t noted[SKEL_SEAL_NOTED];
    int nnoted;
    int64_t rejected[SEAL_KINDS], logged[SEAL_KINDS], noted_ns;
    uint8_t *out;                                 /* a message and its seal, being published */
    size_t out_cap;
} skel_seal_t;

int seal_init(skel_seal_t *k);
void seal_free(skel_seal_t *k);
int seal_load_key(skel_seal_t *k, const char *path, char *why, size_t len);
/* SEAL_GENUINE, or why DATA is refused (counted, the first of a kind logged); *MSG_LEN:
 * the message's own bytes, without its seal. */
int seal_check(skel_seal_t *k, int dpu, const char *channel, const void *data, int len, int *msg_len);
void seal_note(skel_seal_t *k, int dpu);           /* the counts since the last note, now and then */
int seal_publish(skel_seal_t *k, lcm_t *lcm, const char *channel, const void *data, int len);
/* Writes the SEAL_BYTES seal of MSG (LEN bytes) on CHANNEL at TAIL, with our next counter. */
int seal_sign(skel_seal_t *k, const char *channel, const uint8_t *msg, int len, uint8_t *tail);

typedef struct skel_server {
    /* arguments */
    int id_arg;                /* -1: --id auto */
    const char *url;
    const char *key_path;      /* NULL: no key, control unauthenticated */
    const char *lib_dirs[SKEL_MAX_LIB_DIRS]; /* --lib-dir: the only places real code loads from */
    int nlib_dirs;
    int64_t clock_offset_ns;
    int verbose;
    char hostname[256];
    int32_t pid;
    skel_compute_t compute;
    int rt_priority;           /* SCHED_FIFO priority of a run's cycles; 0 never, -1 default */
    int rt_warned;             /* executive thread only: SCHED_FIFO refused, said once */
    int idle_held, idle_fd;    /* executive thread only: /dev/cpu_dma_latency held open at 0 */
    int idle_warned;           /* ... refused, said once */

    lcm_t *ctl;                /* control thread's lcm_t on the control URL: it receives there */
    lcm_t *rec;                /* control thread's lcm_t on the record URL: it only sends there */
    char rec_url[1024];
    skel_seal_t seal;          /* control thread's: the key, and what it refused */
    int wake_fd;               /* eventfd: anything -> executive (stop, quit) */
    int notify_fd;             /* eventfd: executive -> control (events) */

    pthread_mutex_t lock;      /* guards everything down to the atomics */
    pthread_cond_t cond;
    int16_t dpu_id;            /* -1: not known yet (--id auto) */
    int8_t state;
    int64_t generation, staged_generation, rejected_generation;
    char reject_reason[SKEL_REASON_LEN];
    skelmsg_config_t *staged;  /* decoded, validated, waiting for COMMIT */
    int staged_dpu_index;
    int apply_pending;         /* staged config committed, apply when the run ends */
    skel_plan_t *plan;
    /* Live switch (swap.c): built by the control thread, taken by the executive
     * at the first release of its grid at or after next_at_mono_ns. */
    skel_plan_t *next_plan;
    int64_t next_at_mono_ns;   /* 0: the next release */
    int64_t next_generation;   /* of next_plan; -1 when none */
    skel_plan_t *retired;      /* the plan a switch replaced: the control thread frees it */
    skel_run_t run;
    int run_active;            /* ARMED or RUNNING: the executive owns the plan */
    int run_ended;             /* executive finished; control finalises */
    int64_t run_id;            /* current/last run */
    int64_t run_generation;
    int64_t run_session;       /* the host tool that started the current/last run (owner.c) */
    char run_owner[SKEL_OWNER_LEN];
    int64_t run_end_utc_ns;    /* its planned end, 0: until STOP */
    int64_t rejected_at_start;
    int applied_any;           /* a generation was applied (the last: generation); its plan is
                                  dropped between runs when a newer one leaves this DPU out */
    int nlockouts;
    skelmsg_lockout_t lockouts[SKEL_MAX_LOCKOUTS];
    int exec_done;             /* executive thread has exited */

    atomic_int stop;           /* end the run at the next boundary */
    atomic_int_fast64_t switch_seq; /* bumped when next_plan changes: the executive re-reads it */
    atomic_int quit;           /* daemon is shutting down */
    atomic_int_fast64_t minor_cycles, overruns, rejected, timing_batches;
    atomic_int_fast64_t behind_ns, stall_ns, longest_stall_ns, longest_stall_mono_ns; /* executive -> status */
    atomic_int faults;

    skel_ring_t ring;
} skel_server_t;

int server_init(skel_server_t *s);
void server_free(skel_server_t *s);
int server_open(skel_server_t *s, char *why, size_t len);
void server_close(skel_server_t *s);
void server_wake(int fd);
void server_fault(skel_server_t *s, int fault);
int64_t server_now(const skel_server_t *s); /* reported time: monotonic + test offset */

/* ---- process (process.c): one process's cycle ---------------------------------- */
/* The wall clock, the thread's CPU time (-1: unknown), the waits it chose
 * (voluntary switches) and the process's stops at one instant: what a step's stall
 * is judged from. */
typedef struct {
    int64_t mono_ns, cpu_ns;
    long chose_to_wait;
    int64_t stops;
} skel_mark_t;

typedef struct {
    skel_server_t *s;
    skel_plan_t *plan;
    int64_t end_mono_ns;       /* the run's end: a blocked wait gives up after it */
    int64_t switch_seq;        /* the s->switch_seq last read */
    int switch_pending;        /* s->next_plan was set at that read ... */
    int64_t switch_at_mono_ns; /* ... to switch at the first release at or after this */
    int announce;              /* a switch happened: publish the generation at its release */
    int64_t wake_stall_ns;     /* the stall of this minor's wake-up, for its first record */
    int64_t stall_debt_ns;     /* stalls since the executive was last on time: lateness they explain */
    /* The last mark (process_remark) and the stalls charged since: a step that ran
     * long is judged against it. Stale after a wait the thread chose. */
    skel_mark_t mark;
    int64_t mark_charged_ns;
    int mark_stale;
} skel_exec_t;

enum { PROCESS_DONE = 0, PROCESS_STOPPED = 1 };
int process_cycle(skel_exec_t *x, skel_process_t *p, int64_t k, int64_t minor, int64_t release_ns,
                  int64_t sched_ns, skel_rec_t *rec);
void process_record_begin(skel_exec_t *x, const skel_process_t *p, int64_t k, int64_t minor,
                          int64_t release_ns, int64_t sched_ns, int64_t start_ns, skel_rec_t *rec);
/* WHY: what kept cycle K from completing when it waits on no BUFFER (< 0), for the log. */
void process_lockout(skel_exec_t *x, skel_process_t *p, int16_t buffer, int64_t k,
                     int64_t release_ns, const char *why);
int64_t process_lockout_at(const skel_plan_t *plan, const skel_process_t *p, int64_t release);
void process_peek_inputs(const skel_plan_t *plan, const skel_process_t *p, skel_rec_t *rec);
int process_missing(const skel_process_t *p, const skel_rec_t *rec);
void process_commit(skel_plan_t *plan, skel_process_t *p, const skel_rec_t *rec, int measured);
void process_write_outputs(skel_exec_t *x, skel_process_t *p, int64_t k);
void process_finish(skel_exec_t *x, skel_process_t *p, skel_rec_t *rec, int64_t release,
                    int64_t t_out, int measured);
void process_remark(skel_exec_t *x, int64_t now);
void process_woke(skel_exec_t *x, int64_t until);
int64_t process_kept(skel_exec_t *x, skel_rec_t *rec, int64_t step_from, int64_t now);
int64_t process_lost(skel_exec_t *x, int64_t now, int64_t most);

/* ---- event (event.c) ------------------------------------------------------------ */
int event_add_process(skel_plan_t *plan, skel_process_t *p, const skelmsg_process_t *src);
int event_add_sources(skel_plan_t *plan, const skelmsg_config_t *cfg, int16_t dpu);
int event_open(skel_plan_t *plan, const char *control_url, const char *record_url);
void event_receive(skel_event_t *e, const lcm_recv_buf_t *rbuf); /* an event_t on E's channel */
void event_free(skel_plan_t *plan);
void event_reset_run(skel_plan_t *plan);
int event_pending(const skel_process_t *p);
int64_t event_oldest_ns(const skel_process_t *p); /* of the events waiting, INT64_MAX: none */
void event_settle(skel_plan_t *plan, skel_process_t *p, int64_t upto);
void event_release(skel_plan_t *plan, skel_process_t *p, int64_t release);
void event_emit(skel_plan_t *plan, const skel_process_t *p, int64_t now_ns);
void event_carry_process(skel_process_t *p, const skel_process_t *o);
void event_carry_sources(skel_plan_t *next, const skel_plan_t *old, int64_t t_sw);
void event_generators_begin(skel_plan_t *plan, int64_t t0);
int event_generators_start(skel_plan_t *plan, int64_t end);
void event_generators_stop(skel_plan_t *plan);

/* ---- job (job.c): a process's one job on the tasking executive (tasking.c, threads.c) */
int64_t job_release(const skel_process_t *p, int64_t k);
int64_t job_event_release(const skel_process_t *p);
int64_t job_next_release(const skel_process_t *p);
int64_t job_minor(const skel_plan_t *plan, const skel_process_t *p);
int64_t job_lockout(skel_exec_t *x, skel_process_t *p, int64_t now, int64_t next);

/* ---- swap (swap.c): a live switch of plans at one cycle boundary ---------------- */
int64_t swap_index(const skel_plan_t *plan, int64_t j_prev, int64_t at_mono_ns);
int64_t swap_instant(const skel_plan_t *plan, int64_t j_sw);
void swap_carry(skel_plan_t *next, const skel_plan_t *old, int64_t j_sw);
int swap_tasking_ready(const skel_plan_t *old, int64_t t_sw);
void swap_carry_tasking(skel_plan_t *next, const skel_plan_t *old, int64_t t_sw);
void swap_carry_events(skel_plan_t *next, const skel_plan_t *old, int64_t t_sw);

/* ---- cycle (cycle.c): what every executive shares, calling none of them ---------- */
void cycle_pin(const skel_plan_t *plan);
int cycle_rt_priority(const skel_server_t *s, const skel_plan_t *plan); /* 0: SCHED_OTHER */
int cycle_schedule(skel_server_t *s, const skel_plan_t *plan, int running); /* the FIFO priority, 0 */
void cycle_open_window(skel_plan_t *plan, int64_t t0);
void cycle_account(skel_plan_t *plan, skel_process_t *p, const skel_rec_t *rec, int64_t release,
                   int64_t end);
void cycle_record(skel_server_t *s, const skel_rec_t *rec);
int cycle_skips(const skel_plan_t *plan, const skel_process_t *p, int64_t release, int64_t now);
void cycle_skip_record(skel_exec_t *x, skel_process_t *p, int64_t k, int64_t minor, int64_t release,
                       int64_t sched, int64_t now, skel_rec_t *rec);
void cycle_poll_switch(skel_exec_t *x);
int cycle_wait(skel_exec_t *x, int64_t until); /* 0 reached, 1 stop, 2 the pending switch changed */
skel_plan_t *cycle_take(skel_exec_t *x);
int cycle_switch(skel_exec_t *x, skel_plan_t *next, int64_t j_sw, int ran);
void cycle_announce(skel_exec_t *x);

/* ---- cyclic (cyclic.c): the cyclic executive's loop ------------------------------ */
int64_t cyclic_next_release(const skel_plan_t *plan, int64_t j);
void cyclic_run(skel_exec_t *x, const skel_run_t *run);

/* ---- tasking (tasking.c): the tasking executive's one-processor schedule -------- */
void tasking_run(skel_exec_t *x);

/* ---- threads (threads.c): the tasking executive in CPU, WALL and WORK: a SCHED_FIFO
 * thread per process, all pinned to one CPU, the kernel preempting ------------------ */
typedef struct threads threads_t;
threads_t *threads_start(skel_exec_t *x, char *klass, size_t len); /* before t0; NULL: failed, said */
void threads_run(threads_t *t, skel_exec_t *x); /* watches lockouts until the end or STOP, ends T */
void threads_end(threads_t *t);                 /* stops and joins every thread, frees T */

/* ---- executive (executive.c): the executive thread; a START chooses and starts the
 * DPU's executive ----------------------------------------------------------------- */
void *executive_main(void *arg);
void executive_run(skel_server_t *s, skel_plan_t *plan, const skel_run_t *run);
int executive_serve(skel_server_t *s);

/* ---- control (control.c): the control thread ------------------------------------ */
typedef struct {
    int64_t seq, generation, run_id, at_utc_ns, ping_t1_ns;
    int8_t kind;
} skel_seen_t;

typedef struct {
    skel_server_t *s;
    skel_batch_t batch;
    skel_history_t history;
    int64_t batch_seq;
    int64_t batch_generation;  /* of every record in the batch */
    int64_t last_status_ns;
    skel_seen_t seen[SKEL_SEEN_COMMANDS];
    int nseen;
    int64_t ping_seq, ping_t1_ns, ping_t2_ns, ping_t3_ns; /* repeated by later statuses */
    int status_due;
    skel_shaper_t shaper;      /* the run's network applied by the kernel */
    char network[SHAPE_TEXT_LEN]; /* the newest plan's shape text (status_t.network) */
} skel_control_t;

int control_init(skel_control_t *c, skel_server_t *s);
void control_free(skel_control_t *c);
void *control_main(void *arg);
void control_notice(skel_control_t *c);
int control_step(skel_control_t *c);

/* ---- command (command.c): a config or a command the control thread received ---- */
void command_handle_config(skel_control_t *c, const void *data, int len);
void command_handle_command(skel_control_t *c, const void *data, int len);

/* ---- apply (apply.c): a staged config becomes the plan ---------------------------- */
void apply_staged(skel_control_t *c);
void apply_commit_live(skel_control_t *c, int64_t at_utc_ns);
void apply_install_next(skel_control_t *c);
void apply_drain_next(skel_control_t *c);

/* ---- owner (owner.c): a run belongs to the host tool that started it ------------- */
void owner_take(skel_server_t *s, const skelmsg_command_t *start, int64_t start_utc_ns);
int owner_refuses(skel_control_t *c, int64_t session, int8_t force, const char *sender,
                  const char *what, int64_t generation);

/* ---- report (report.c): status_t and report_t, what the host hears ---------------- */
int report_status_publish(skel_control_t *c);
void report_reject(skel_control_t *c, int64_t generation, const char *reason, int fault);
int report_publish(skel_server_t *s, const skel_plan_t *plan, skel_history_t *history);

/* ---- code (code.c) ------------------------------------------------------------ */
/* Loads the real code CFG names for PLAN's processes from DIRS only (control thread, at
 * config apply time): -1 with REASON when a library or symbol is missing or its ABI differs. */
int code_load(skel_plan_t *plan, const skelmsg_config_t *cfg, const char *const *dirs, int ndirs,
              char *reason, size_t len);
/* At staging: whether every library CFG names for DPU is in DIRS (-1 with REASON when not). */
int code_check(const skelmsg_config_t *cfg, int16_t dpu, const char *const *dirs, int ndirs, char *reason,
               size_t len);
int code_begin(skel_plan_t *plan, char *reason, size_t len); /* every init, before a run */
void code_end(skel_plan_t *plan);                  /* every fini owed, after a run */
int64_t code_step(skel_plan_t *plan, skel_process_t *p, const skel_rec_t *rec, int64_t k);
void code_free(skel_process_t *p);

/* ---- sim (sim.c): every DPU of a system on virtual time, one process ------------ */
int sim_main(const char *input, const char *output, const char *url); /* an exit code */

#endif
