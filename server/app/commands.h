/* commands.h - the subcommands of the `squish` command line; each returns an exit code. */
#ifndef SQ_COMMANDS_H
#define SQ_COMMANDS_H

int sq_cmd_mesh(int argc, char **argv);     /* cmd_mesh.c:     mesh info | box | convert */
int sq_cmd_run(int argc, char **argv);      /* cmd_run.c:      batch run of a scene */
int sq_cmd_serve(int argc, char **argv);    /* cmd_serve.c:    the WebSocket service */
int sq_cmd_render(int argc, char **argv);   /* cmd_render.c:   headless PNG rendering */
int sq_cmd_bench(int argc, char **argv);    /* cmd_bench.c:    benchmarks */
int sq_cmd_tradeoff(int argc, char **argv); /* cmd_tradeoff.c: speed/accuracy grid */
int sq_cmd_sweep(int argc, char **argv);    /* cmd_sweep.c: stability sweep (engines/sweep.c) */
int sq_bench_implicit(int quick);           /* cmd_bench_implicit.c: squish bench implicit */
int sq_bench_contact(int quick);            /* cmd_bench_contact.c: squish bench contact */

#include <stdio.h>
/* DIR/NAME opened for writing, its path in path[n]; NULL after saying on stderr which file
 * `squish CMD` cannot write and why, and to choose another --out (main.c) */
FILE *sq_cmd_open_out(const char *cmd, const char *dir, const char *name, char *path, size_t n);

#endif
