/* main.c: skel-dpu's command line, start-up and shutdown. It fills the server,
 * calibrates the WORK kernel, starts the control and executive threads, and
 * waits for SIGTERM/SIGINT (or a SHUTDOWN command, which raises SIGTERM): the
 * run in progress ends at its next boundary, timing is flushed, exit 0. */
#include <errno.h>
#include <signal.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/stat.h>
#include <unistd.h>

#include "dpu.h"

static void usage(void)
{
    fprintf(stderr,
            "usage: skel-dpu --id N|auto [--url URL] [--clock-offset-ns N] [--spin-us N]\n"
            "                [--rt-priority N] [--key FILE] [--lib-dir DIR]... [--verbose]\n"
            "       skel-dpu --simulate INPUT.lcm OUTPUT.lcm [--url URL]\n"
            "  --id N|auto          this DPU's id in the config; auto: the DPU whose host is this\n"
            "                       machine's host name\n"
            "  --url URL            control URL (default %s); status and timing go to its\n"
            "                       record URL, the group and port each one lower\n"
            "  --clock-offset-ns N  test option: add N to every reported timestamp\n"
            "  --spin-us N          compute mode SLEEP spins the last N us (default 150)\n"
            "  --rt-priority N      run cycles under SCHED_FIFO priority N (1-99; 0: never);\n"
            "                       default: 10 in compute mode SLEEP where permitted\n"
            "  --key FILE           sign and check control with this key (`skel keygen`);\n"
            "                       default: $%s when set, else none (unauthenticated)\n"
            "  --lib-dir DIR        real code (a process's compute: {library: NAME}) loads\n"
            "                       DIR/libNAME.so from these directories only (repeatable);\n"
            "                       none: a config naming a library is refused\n"
            "  --simulate           run every DPU of INPUT's system on virtual time: INPUT holds\n"
            "                       the host's configs and commands (`skel simulate` writes it),\n"
            "                       OUTPUT the log a run's logger would have written\n",
            SKEL_DEFAULT_URL, SKEL_KEY_ENV);
}

static int parse_i64(const char *text, int64_t *out)
{
    char *end = NULL;
    errno = 0;
    long long v = strtoll(text, &end, 10);
    if (errno != 0 || end == text || *end != '\0') return -1;
    *out = v;
    return 0;
}

static int parse_args(skel_server_t *s, int argc, char **argv)
{
    int have_id = 0;
    int64_t v;
    s->url = SKEL_DEFAULT_URL;
    s->compute.spin_ns = 150 * SKEL_NS_PER_US;
    s->compute.stall_ns = SKEL_STALL_NS;
    s->rt_priority = -1;
    for (int i = 1; i < argc; i++) {
        const char *a = argv[i], *next = i + 1 < argc ? argv[i + 1] : NULL;
        if (strcmp(a, "--verbose") == 0) { s->verbose = 1; continue; }
        if (strcmp(a, "--help") == 0 || strcmp(a, "-h") == 0) return -1;
        if (next == NULL) { fprintf(stderr, "skel-dpu: %s needs a value\n", a); return -1; }
        i++;
        if (strcmp(a, "--id") == 0 && strcmp(next, "auto") == 0) { s->id_arg = -1; have_id = 1; }
        else if (strcmp(a, "--id") == 0 && parse_i64(next, &v) == 0 && v >= 0 && v <= INT16_MAX) {
            s->id_arg = (int)v;
            s->dpu_id = (int16_t)v;
            have_id = 1;
        } else if (strcmp(a, "--url") == 0) s->url = next;
        else if (strcmp(a, "--key") == 0) s->key_path = next;
        else if (strcmp(a, "--lib-dir") == 0 && s->nlib_dirs < SKEL_MAX_LIB_DIRS) {
            struct stat st;
            if (stat(next, &st) != 0 || !S_ISDIR(st.st_mode)) {
                fprintf(stderr, "skel-dpu: --lib-dir %s is not a directory\n", next);
                return -1;
            }
            s->lib_dirs[s->nlib_dirs++] = next;
        }
        else if (strcmp(a, "--clock-offset-ns") == 0 && parse_i64(next, &v) == 0) s->clock_offset_ns = v;
        else if (strcmp(a, "--spin-us") == 0 && parse_i64(next, &v) == 0 && v >= 0 && v < 1000000)
            s->compute.spin_ns = v * SKEL_NS_PER_US;
        else if (strcmp(a, "--rt-priority") == 0 && parse_i64(next, &v) == 0 && v >= 0 && v <= 99)
            s->rt_priority = (int)v;
        else { fprintf(stderr, "skel-dpu: bad option or value: %s %s\n", a, next); return -1; }
    }
    if (s->key_path == NULL && getenv(SKEL_KEY_ENV) != NULL && getenv(SKEL_KEY_ENV)[0] != '\0')
        s->key_path = getenv(SKEL_KEY_ENV);
    if (!have_id) fprintf(stderr, "skel-dpu: --id N|auto is required\n");
    return have_id ? 0 : -1;
}

/* Signals are blocked in every thread and taken by sigwait() in main only, so no
 * handler runs in the middle of a cycle or an LCM call. SIGCONT is blocked too, and
 * never taken here: its continuing cannot be blocked, and the signal left pending is
 * how the executives learn that the process was stopped (clock_stops). */
static int wait_for_signal(void)
{
    sigset_t set;
    int sig = 0;
    sigemptyset(&set);
    sigaddset(&set, SIGTERM);
    sigaddset(&set, SIGINT);
    return sigwait(&set, &sig) == 0 ? sig : -1;
}

static int block_signals(void)
{
    sigset_t set;
    sigemptyset(&set);
    sigaddset(&set, SIGTERM);
    sigaddset(&set, SIGINT);
    sigaddset(&set, SIGCONT);
    return pthread_sigmask(SIG_BLOCK, &set, NULL);
}

static int run_threads(skel_server_t *s, skel_control_t *c)
{
    pthread_t exec_thread, ctl_thread;
    if (pthread_create(&exec_thread, NULL, executive_main, s) != 0) return -1;
    if (pthread_create(&ctl_thread, NULL, control_main, c) != 0) {
        atomic_store(&s->quit, 1);
        pthread_join(exec_thread, NULL);
        return -1;
    }
    int sig = wait_for_signal();
    log_line("DPU %d: %s: stopping", s->dpu_id, sig == SIGINT ? "SIGINT" : "SIGTERM");
    atomic_store(&s->stop, 1);
    atomic_store(&s->quit, 1);
    server_wake(s->wake_fd);
    if (pthread_mutex_lock(&s->lock) == 0) {
        pthread_cond_broadcast(&s->cond);
        pthread_mutex_unlock(&s->lock);
    }
    pthread_join(exec_thread, NULL);
    pthread_join(ctl_thread, NULL); /* it finishes the run and sends a last status */
    return 0;
}

int main(int argc, char **argv)
{
    if (argc >= 2 && strcmp(argv[1], "--simulate") == 0) {
        int with_url = argc == 6 && strcmp(argv[4], "--url") == 0;
        if (argc != 4 && !with_url) { usage(); return SKEL_EXIT_USAGE; }
        return sim_main(argv[2], argv[3], with_url ? argv[5] : SKEL_DEFAULT_URL);
    }
    static skel_server_t server; /* large (ring, lockouts): static, not on the stack */
    static skel_control_t control;
    skel_server_t *s = &server;
    if (server_init(s) != 0) { fprintf(stderr, "skel-dpu: cannot initialise\n"); return SKEL_EXIT_FAILED; }
    if (parse_args(s, argc, argv) != 0) { usage(); return SKEL_EXIT_USAGE; }
    if (seal_init(&s->seal) != 0) { fprintf(stderr, "skel-dpu: cannot initialise libsodium\n"); return SKEL_EXIT_FAILED; }
    char why[512];
    if (s->key_path != NULL && seal_load_key(&s->seal, s->key_path, why, sizeof why) != 0) {
        fprintf(stderr, "skel-dpu: %s\n", why);
        return SKEL_EXIT_USAGE;
    }
    if (gethostname(s->hostname, sizeof s->hostname - 1) != 0) strcpy(s->hostname, "?");
    s->pid = (int32_t)getpid();
    if (compute_calibrate(&s->compute) != 0) {
        log_line("WORK calibration failed");
        return SKEL_EXIT_FAILED;
    }
    if (block_signals() != 0) return SKEL_EXIT_FAILED;
    if (server_open(s, why, sizeof why) != 0) {
        log_line("%s", why);
        return SKEL_EXIT_FAILED;
    }
    if (control_init(&control, s) != 0) { log_line("out of memory"); return SKEL_EXIT_FAILED; }
    log_line("DPU %s on %s: control %s, record %s (%s), WORK %.1f iterations/us, clock offset %lld ns",
             s->id_arg >= 0 ? argv[2] : "auto", s->hostname, s->url, s->rec_url,
             s->seal.keyed ? "signed" : "unauthenticated: no key", s->compute.work_iters_per_us,
             (long long)s->clock_offset_ns);
    int rc = run_threads(s, &control);
    control_free(&control);
    seal_free(&s->seal);
    server_close(s);
    server_free(s);
    return rc == 0 ? SKEL_EXIT_OK : SKEL_EXIT_FAILED;
}
