/* code.c: real application code in place of a process's emulated computation
 * (include/skel_step.h). A config names a library, never a path: it is looked up
 * as lib<name>.so in the directories on the DPU's own command line (--lib-dir) and
 * nowhere else, so a config from the network cannot make the DPU load code from
 * anywhere else. Everything that allocates or resolves (dlopen, dlsym, the buffers
 * a step reads and writes) happens when the config is applied, on the control
 * thread (config.c has refused a path); a cycle only fills the step's views and calls it. A crash inside the
 * step is a crash of the DPU: nothing here isolates it. */
#include <dlfcn.h>
#include <signal.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/stat.h>
#include <unistd.h>

#include "dpu.h"

/* A crash in a step kills the DPU; its log says whose step it was. The name of the process
 * whose step runs (NULL: none), and the handlers a run's code_begin replaced. */
static const char *volatile code_running;
static const int code_signals[] = { SIGSEGV, SIGBUS, SIGFPE, SIGILL, SIGABRT };
#define CODE_NSIGNALS ((int)(sizeof code_signals / sizeof code_signals[0]))
static struct sigaction code_saved[CODE_NSIGNALS];
static int code_watching;

static void code_put(const char *text)
{
    ssize_t n = write(STDERR_FILENO, text, strlen(text)); /* async-signal-safe; nothing to do on failure */
    (void)n;
}

/* Says whose step crashed, puts the previous handler back and returns: the faulting
 * instruction runs again and the previous handler (the default: a core dump, or a
 * sanitizer's report) takes it. */
static void code_crashed(int sig)
{
    const char *name = code_running;
    if (name != NULL) {
        code_put("skel-dpu: process ");
        code_put(name);
        code_put(" crashed in its real code's step (");
        code_put(sig == SIGSEGV ? "SIGSEGV" : sig == SIGBUS ? "SIGBUS" : sig == SIGFPE ? "SIGFPE"
                 : sig == SIGILL ? "SIGILL" : "SIGABRT");
        code_put("): this DPU is lost\n");
    }
    for (int i = 0; i < CODE_NSIGNALS; i++)
        if (code_signals[i] == sig) (void)sigaction(sig, &code_saved[i], NULL);
    if (sig == SIGABRT) (void)raise(sig); /* abort() raised it: no instruction to run again */
}

static void code_watch(int on)
{
    if (on == code_watching) return;
    for (int i = 0; i < CODE_NSIGNALS; i++) {
        if (on) {
            struct sigaction sa;
            memset(&sa, 0, sizeof sa);
            sa.sa_handler = code_crashed;
            sa.sa_flags = SA_NODEFER | SA_RESETHAND;
            if (sigemptyset(&sa.sa_mask) != 0 || sigaction(code_signals[i], &sa, &code_saved[i]) != 0)
                log_line("warning: cannot watch signal %d: a crash in real code is not named", code_signals[i]);
        } else if (sigaction(code_signals[i], &code_saved[i], NULL) != 0) {
            log_line("warning: cannot restore the handler of signal %d", code_signals[i]);
        }
    }
    code_watching = on;
}

static int code_fail(char *reason, size_t len, const char *what, const char *name, const char *detail)
{
    snprintf(reason, len, "%s %.60s: %.180s", what, name, detail);
    return -1;
}

/* The first DIRS/lib<LIBRARY>.so that is a regular file, into PATH; -1: none. */
static int code_find(const char *library, const char *const *dirs, int ndirs, char *path, size_t len)
{
    for (int i = 0; i < ndirs; i++) {
        struct stat st;
        int n = snprintf(path, len, "%s/lib%s.so", dirs[i], library);
        if (n < 0 || (size_t)n >= len) continue;
        if (stat(path, &st) == 0 && S_ISREG(st.st_mode)) return 0;
    }
    return -1;
}

static int code_open(skel_code_t *code, const skelmsg_process_t *src, const char *path, char *reason,
                     size_t len)
{
    char sym[SKEL_MAX_NAME + 8];
    code->handle = dlopen(path, RTLD_NOW | RTLD_LOCAL);
    if (code->handle == NULL) return code_fail(reason, len, "cannot load library", src->library, dlerror());
    const uint32_t *abi = dlsym(code->handle, "skel_step_abi");
    if (abi == NULL)
        return code_fail(reason, len, "library", src->library,
                         "exports no skel_step_abi: build it against include/skel_step.h (SKEL_STEP_DECLARE_ABI)");
    if (*abi != SKEL_STEP_ABI) {
        char why[96];
        snprintf(why, sizeof why, "built for step ABI %u, this DPU runs ABI %d: rebuild it", (unsigned)*abi,
                 SKEL_STEP_ABI);
        return code_fail(reason, len, "library", src->library, why);
    }
    /* dlsym returns void *; POSIX guarantees it converts to a function pointer. */
    *(void **)&code->step = dlsym(code->handle, src->function);
    if (code->step == NULL) return code_fail(reason, len, "no function", src->function, "in its library");
    snprintf(sym, sizeof sym, "%s_init", src->function);
    *(void **)&code->init = dlsym(code->handle, sym);
    snprintf(sym, sizeof sym, "%s_fini", src->function);
    *(void **)&code->fini = dlsym(code->handle, sym);
    snprintf(code->name, sizeof code->name, "%s", src->name);
    return 0;
}

/* The guard bytes before and after each output: what a step wrote there, it wrote past
 * the output (a byte may happen to be written with the guard's own value, so a write is
 * caught unless every byte it touched kept it). */
static uint8_t code_guard_byte(size_t i) { return (uint8_t)(0x5A ^ (i * 37)); }

static void code_guard_fill(uint8_t *at)
{
    for (size_t i = 0; i < SKEL_CODE_GUARD; i++) at[i] = code_guard_byte(i);
}

/* Did the step write into a guard? Each guard is restored for the next cycle. */
static int code_guards_broken(skel_code_t *code, int noutputs)
{
    int broken = 0;
    for (int q = 0; q <= noutputs; q++) {
        uint8_t *g = code->guards[q];
        for (size_t i = 0; i < SKEL_CODE_GUARD; i++) broken |= g[i] != code_guard_byte(i);
        if (broken) code_guard_fill(g);
    }
    return broken;
}

/* The step's views of P's inputs and outputs: outputs over one allocation of their
 * declared sizes, a guard before, between and after them (code_guards_broken), inputs
 * over their slots, which keep the bytes from now on. */
static int code_views(skel_plan_t *plan, skel_process_t *p, const skelmsg_config_t *cfg)
{
    skel_code_t *code = p->code;
    size_t total = SKEL_CODE_GUARD;
    for (int q = 0; q < p->noutputs; q++) total += (size_t)p->outputs[q].bytes + SKEL_CODE_GUARD;
    code->out_bytes = calloc(1, total);
    if (code->out_bytes == NULL) return -1;
    code->guards[0] = code->out_bytes;
    code_guard_fill(code->guards[0]);
    size_t at = SKEL_CODE_GUARD;
    for (int q = 0; q < p->noutputs; q++) {
        code->out[q] = (skel_step_output_t){ p->outputs[q].buffer, p->outputs[q].bytes, p->outputs[q].bytes,
                                             code->out_bytes + at };
        at += (size_t)p->outputs[q].bytes;
        code->guards[q + 1] = code->out_bytes + at;
        code_guard_fill(code->guards[q + 1]);
        at += SKEL_CODE_GUARD;
    }
    for (int q = 0; q < p->ninputs; q++) {
        skel_slot_t *slot = &plan->slots[p->inputs[q].slot];
        code->in[q] = (skel_step_input_t){ p->inputs[q].buffer, 0, NULL, -1, 0 };
        if (slot->bytes != NULL) continue;
        const skelmsg_buffer_desc_t *b = config_buffer(cfg, slot->buffer);
        slot->cap = b != NULL ? b->bytes : 0;
        slot->bytes = calloc(1, (size_t)slot->cap + 1);
        if (slot->bytes == NULL) return -1;
    }
    return 0;
}

/* SRC's library, found in DIRS into PATH; -1 with REASON when it cannot be. */
static int code_locate(const skelmsg_process_t *src, const char *const *dirs, int ndirs, char *path,
                       size_t path_len, char *reason, size_t len)
{
    if (clock_simulated())
        return code_fail(reason, len, "process", src->name,
                         "runs real code, which a simulation cannot time: run it on DPUs");
    if (ndirs == 0)
        return code_fail(reason, len, "library", src->library,
                         "cannot be loaded: this DPU was started without --lib-dir");
    if (code_find(src->library, dirs, ndirs, path, path_len) != 0) {
        char why[256];
        snprintf(why, sizeof why, "lib%.60s.so is not in this DPU's --lib-dir (%.140s%s)", src->library,
                 dirs[0], ndirs > 1 ? ", ..." : "");
        return code_fail(reason, len, "library", src->library, why);
    }
    return 0;
}

int code_check(const skelmsg_config_t *cfg, int16_t dpu, const char *const *dirs, int ndirs, char *reason,
               size_t len)
{
    char path[4096];
    for (int i = 0; i < cfg->nprocesses; i++) {
        const skelmsg_process_t *src = &cfg->processes[i];
        if (src->dpu == dpu && src->library[0] != '\0' &&
            code_locate(src, dirs, ndirs, path, sizeof path, reason, len) != 0)
            return -1;
    }
    return 0;
}

int code_load(skel_plan_t *plan, const skelmsg_config_t *cfg, const char *const *dirs, int ndirs,
              char *reason, size_t len)
{
    for (int i = 0; i < cfg->nprocesses; i++) {
        const skelmsg_process_t *src = &cfg->processes[i];
        if (src->dpu != plan->dpu || src->library[0] == '\0') continue;
        skel_process_t *p = NULL;
        for (int j = 0; j < plan->nprocesses && p == NULL; j++)
            if (plan->processes[j].id == src->id) p = &plan->processes[j];
        if (p == NULL) continue;
        char path[4096];
        if (code_locate(src, dirs, ndirs, path, sizeof path, reason, len) != 0) return -1;
        p->code = calloc(1, sizeof *p->code);
        if (p->code == NULL) return code_fail(reason, len, "process", src->name, "out of memory");
        if (code_open(p->code, src, path, reason, len) != 0) return -1;
        if (code_views(plan, p, cfg) != 0) return code_fail(reason, len, "process", src->name, "out of memory");
    }
    return 0;
}

int code_begin(skel_plan_t *plan, char *reason, size_t len)
{
    int any = 0;
    for (int i = 0; i < plan->nprocesses; i++) any |= plan->processes[i].code != NULL;
    if (any) code_watch(1);
    for (int i = 0; i < plan->nprocesses; i++) {
        skel_process_t *p = &plan->processes[i];
        skel_code_t *code = p->code;
        if (code == NULL) continue;
        code->faults = 0;
        code->state = NULL;
        skel_step_info_t info = { p->id, code->name, (int32_t)(p->period_ns / SKEL_NS_PER_US), p->ninputs,
                                  p->noutputs };
        code_running = code->name;
        int failed = code->init != NULL && code->init(&code->state, &info) != 0;
        code_running = NULL;
        if (failed) {
            snprintf(reason, len, "process %s: its init returned an error", code->name);
            code_end(plan);
            return -1;
        }
        code->started = 1;
    }
    return 0;
}

void code_end(skel_plan_t *plan)
{
    for (int i = 0; i < plan->nprocesses; i++) {
        skel_code_t *code = plan->processes[i].code;
        if (code == NULL || !code->started) continue;
        code_running = code->name;
        if (code->fini != NULL) code->fini(code->state);
        code_running = NULL;
        code->started = 0;
        code->state = NULL;
    }
    code_watch(0);
}

/* Cycle K's call of P's step with the inputs REC saw; returns the wall time it took.
 * Nothing allocated, no system call but the two clock reads. */
int64_t code_step(skel_plan_t *plan, skel_process_t *p, const skel_rec_t *rec, int64_t k)
{
    skel_code_t *code = p->code;
    for (int q = 0; q < p->ninputs; q++) {
        const skel_slot_t *slot = &plan->slots[p->inputs[q].slot];
        code->in[q].bytes = slot->bytes;
        code->in[q].nbytes = slot->newest_seq >= 0 ? slot->nbytes : 0;
        code->in[q].seq = slot->newest_seq;
        code->in[q].is_new = rec->in[q].new_data;
    }
    for (int q = 0; q < p->noutputs; q++) code->out[q].nbytes = code->out[q].capacity;
    skel_step_t step = { k, p->ninputs, code->in, p->noutputs, code->out, code->state };
    code_running = code->name;
    int64_t t0 = clock_mono_ns();
    int rc = code->step(&step);
    int64_t took = clock_mono_ns() - t0;
    code_running = NULL;
    int overlong = 0;
    for (int q = 0; q < p->noutputs; q++)
        overlong |= code->out[q].nbytes < 0 || code->out[q].nbytes > code->out[q].capacity;
    int past = code_guards_broken(code, p->noutputs);
    code->failed = rc != 0 || overlong || past;
    if (code->failed && code->faults++ == 0)
        log_line("DPU %d: process %s: its step failed at cycle %lld (%s): that cycle's outputs are not sent",
                 plan->dpu, code->name, (long long)k,
                 rc != 0 ? "it returned an error"
                 : past  ? "it wrote past an output's declared bytes"
                         : "an output longer than declared");
    return took;
}

void code_free(skel_process_t *p)
{
    skel_code_t *code = p->code;
    if (code == NULL) return;
    /* A library's code stays mapped until its fini has run (code_end, at every run's end). */
    if (code->handle != NULL && dlclose(code->handle) != 0)
        log_line("process %s: dlclose: %s", code->name, dlerror());
    free(code->out_bytes);
    free(code);
    p->code = NULL;
}
