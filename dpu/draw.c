/* draw.c: the compute time of a cycle when it varies. The host sends each varying
 * process's quantile function as a table (process_t.quantiles_us); a cycle draws
 * u in [0, 1) and computes for the table's value at u, linear between its points.
 * So every distribution the system file can name, and measured samples, are one
 * mechanism here: no libm, no allocation and a few ns per draw in the cycle.
 *
 * u comes from xoshiro256** (Blackman and Vigna), one generator per process
 * seeded from the run's seed and the process id by splitmix64: the same seed
 * gives every process the same draws, run after run, whatever else the system
 * holds. */
#include "dpu.h"

static uint64_t draw_splitmix(uint64_t *x)
{
    uint64_t z = (*x += 0x9e3779b97f4a7c15ULL);
    z = (z ^ (z >> 30)) * 0xbf58476d1ce4e5b9ULL;
    z = (z ^ (z >> 27)) * 0x94d049bb133111ebULL;
    return z ^ (z >> 31);
}

static uint64_t draw_rotl(uint64_t x, int k) { return (x << k) | (x >> (64 - k)); }

static uint64_t draw_next(uint64_t s[4])
{
    const uint64_t out = draw_rotl(s[1] * 5, 7) * 9;
    const uint64_t t = s[1] << 17;
    s[2] ^= s[0];
    s[3] ^= s[1];
    s[1] ^= s[2];
    s[0] ^= s[3];
    s[2] ^= t;
    s[3] = draw_rotl(s[3], 45);
    return out;
}

void draw_seed_state(uint64_t state[4], int64_t seed, uint64_t stream)
{
    uint64_t x = (uint64_t)seed ^ (stream << 48);
    for (int i = 0; i < 4; i++) state[i] = draw_splitmix(&x);
}

void draw_seed(skel_draw_t *d, int64_t seed, int16_t process)
{
    draw_seed_state(d->state, seed, (uint16_t)process);
}

double draw_unit(uint64_t state[4])
{
    return (double)(draw_next(state) >> 11) * 0x1.0p-53; /* 53 bits */
}

int64_t draw_ns(skel_draw_t *d, int64_t constant_ns)
{
    if (d->n < 2) return constant_ns;
    const double u = draw_unit(d->state);
    const double at = u * (double)(d->n - 1);
    const int i = (int)at; /* < n - 1 */
    const double v = d->table_ns[i] + (at - (double)i) * (d->table_ns[i + 1] - d->table_ns[i]);
    return (int64_t)(v + 0.5);
}
