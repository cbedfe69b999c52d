/* test_draw.c: a varying compute time drawn from its quantile table: within the
 * table, with the table's mean, the same draws for the same seed and process,
 * other draws for another, and the constant when there is no table. */
#include "check.h"
#include "dpu.h"

static skel_draw_t linear(int64_t seed, int16_t process)
{
    skel_draw_t d = { .n = 3 };
    d.table_ns[0] = 1000.0; /* quantile function 1000 + 2000 u: uniform on [1000, 3000] */
    d.table_ns[1] = 2000.0;
    d.table_ns[2] = 3000.0;
    draw_seed(&d, seed, process);
    return d;
}

static void test_within_the_table_with_its_mean(void)
{
    skel_draw_t d = linear(1, 7);
    double sum = 0;
    int64_t lo = INT64_MAX, hi = 0;
    const int n = 200000;
    for (int i = 0; i < n; i++) {
        int64_t v = draw_ns(&d, -1);
        sum += (double)v;
        if (v < lo) lo = v;
        if (v > hi) hi = v;
    }
    CHECK(lo >= 1000 && lo < 1010);
    CHECK(hi <= 3000 && hi > 2990);
    CHECK(sum / n > 1990.0 && sum / n < 2010.0);
}

static void test_same_seed_same_draws(void)
{
    skel_draw_t a = linear(42, 3), b = linear(42, 3), other_seed = linear(43, 3), other_process = linear(42, 4);
    int same = 1, differ_seed = 0, differ_process = 0;
    for (int i = 0; i < 1000; i++) {
        int64_t x = draw_ns(&a, 0);
        same &= x == draw_ns(&b, 0);
        differ_seed += x != draw_ns(&other_seed, 0);
        differ_process += x != draw_ns(&other_process, 0);
    }
    CHECK(same);
    CHECK(differ_seed > 900);
    CHECK(differ_process > 900);
}

static void test_constant_without_a_table(void)
{
    skel_draw_t d = { .n = 0 };
    draw_seed(&d, 1, 1);
    CHECK_EQ(draw_ns(&d, 1234567), 1234567);
}

int main(void)
{
    test_within_the_table_with_its_mean();
    test_same_seed_same_draws();
    test_constant_without_a_table();
    return CHECK_DONE();
}
