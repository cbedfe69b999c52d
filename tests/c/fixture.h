/* fixture.h: a small valid config_t built in C for the tests (two DPUs, a
 * multicast link and a local one, five processes), with fixed storage so a
 * test can mutate any field and nothing needs freeing. */
#ifndef SKEL_FIXTURE_H
#define SKEL_FIXTURE_H

#include <string.h>

#include "dpu.h"

#define FIX_IO 20

typedef struct {
    skelmsg_config_t cfg;
    skelmsg_link_t links[2];
    skelmsg_dpu_t dpus[2];
    int16_t dpu_links[2][1];
    skelmsg_buffer_desc_t buffers[3];
    skelmsg_process_t procs[5];
    int16_t in[5][FIX_IO];
    int8_t req[5][FIX_IO];
    int16_t out[5][FIX_IO];
    skelmsg_chain_t chain;
    int16_t chain_procs[2];
} fixture_t;

static void fixture_process(fixture_t *f, int i, int16_t id, int16_t dpu, int16_t order,
                            int32_t period_us, int32_t compute_us)
{
    skelmsg_process_t *p = &f->procs[i];
    p->id = id;
    p->name = (char *)"p";
    p->event = (char *)"";
    p->library = (char *)"";
    p->function = (char *)"";
    p->dpu = dpu;
    p->order = order;
    p->period_us = period_us;
    p->compute_us = compute_us;
    p->sync = SKELMSG_PROCESS_T_SYNC_PERIODIC;
    p->inputs = f->in[i];
    p->required = f->req[i];
    p->outputs = f->out[i];
}

/* Buffer 1 (net): p1 on DPU 1 every 10 ms -> p2 on DPU 2 every 5 ms.
 * Buffer 2 (net): p3 on DPU 2 every 5 ms -> p4 on DPU 1 every 10 ms.
 * Buffer 3 (local): p5 on DPU 1 -> p4. */
static void fixture_init(fixture_t *f)
{
    memset(f, 0, sizeof *f);
    skelmsg_config_t *c = &f->cfg;
    c->generation = 7;
    c->run_id = 1;
    c->system = (char *)"fixture";
    c->warmup_cycles = 2;
    c->lockout_cycles = 4;
    c->source = (char *)"system: fixture\n";
    c->sender = (char *)"fixture pid 1";
    f->links[0] = (skelmsg_link_t){ .id = 1, .name = (char *)"net", .url = (char *)"udpm://239.255.76.67:7799?ttl=0" };
    f->links[1] = (skelmsg_link_t){ .id = 2, .name = (char *)"mem", .url = (char *)"" };
    c->nlinks = 2;
    c->links = f->links;
    for (int i = 0; i < 2; i++) {
        skelmsg_dpu_t *d = &f->dpus[i];
        d->id = (int16_t)(i + 1);
        d->host = (char *)(i == 0 ? "alpha" : "beta");
        d->cpu = -1;
        d->speed = 1.0;
        d->minor_cycle_us = 5000;
        f->dpu_links[i][0] = 1;
        d->nlinks = 1;
        d->links = f->dpu_links[i];
    }
    c->ndpus = 2;
    c->dpus = f->dpus;
    /* as host/sysfile/link.py gives them: link 1's writers (processes 1 and 3) on its port + 1, + 2 */
    f->buffers[0] = (skelmsg_buffer_desc_t){ 1, (char *)"b1", 1000, 1, (char *)"udpm://239.255.76.67:7800?ttl=0",
                                             1, (char *)"SKEL_BUF_b1" };
    f->buffers[1] = (skelmsg_buffer_desc_t){ 2, (char *)"b2", 2000, 1, (char *)"udpm://239.255.76.67:7801?ttl=0",
                                             3, (char *)"SKEL_BUF_b2" };
    f->buffers[2] = (skelmsg_buffer_desc_t){ 3, (char *)"b3", 300, 2, (char *)"", 5, (char *)"SKEL_BUF_b3" };
    c->nbuffers = 3;
    c->buffers = f->buffers;
    fixture_process(f, 0, 1, 1, 0, 10000, 2000);
    f->procs[0].noutputs = 1;
    f->out[0][0] = 1;
    fixture_process(f, 1, 2, 2, 1, 5000, 1000);
    f->procs[1].ninputs = 1;
    f->in[1][0] = 1;
    f->req[1][0] = 1;
    fixture_process(f, 2, 3, 2, 0, 5000, 1000);
    f->procs[2].noutputs = 1;
    f->out[2][0] = 2;
    fixture_process(f, 3, 4, 1, 2, 10000, 1000);
    f->procs[3].ninputs = 2;
    f->in[3][0] = 2;
    f->in[3][1] = 3;
    fixture_process(f, 4, 5, 1, 1, 20000, 500);
    f->procs[4].noutputs = 1;
    f->out[4][0] = 3;
    c->nprocesses = 5;
    c->processes = f->procs;
    f->chain_procs[0] = 1;
    f->chain_procs[1] = 2;
    f->chain = (skelmsg_chain_t){ (char *)"main", 2, f->chain_procs };
    c->nchains = 1;
    c->chains = &f->chain;
}

#endif
