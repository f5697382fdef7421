/* bench_scenes.c - scene benchmarks (placeholder until filled in). */
#include <stdio.h>

#include "app/tradeoff.h"

int sq_bench_scenes(int argc, char **argv)
{
    (void)argc;
    (void)argv;
    fprintf(stderr, "squish tradeoff --bench: not available yet\n");
    return 2;
}
