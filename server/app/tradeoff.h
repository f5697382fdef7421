/* tradeoff.h - helpers shared by squish tradeoff, squish sweep and the scene benchmarks
 * (server/app/cmd_tradeoff.c, tradeoff_sweep.c, bench_scenes.c). */
#ifndef SQ_TRADEOFF_H
#define SQ_TRADEOFF_H

/* squish tradeoff --bench: frame-budget headroom of the shipped scenes and 1 vs 2 threads
 * (bench_scenes.c); argv[0] is the subcommand name */
int sq_bench_scenes(int argc, char **argv);

#endif
