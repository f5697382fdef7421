/* main.c - the `squish` command line front end. */
#include <stdio.h>
#include <string.h>

#include "app/commands.h"

static const struct {
    const char *name;
    int (*fn)(int, char **);
    const char *help;
} commands[] = {
    /* one line per command: every option named here is one the command takes (its own
     * --help lists them all); tests/stages/cli_help.sh checks it */
    {"mesh", sq_cmd_mesh, "mesh info FILE | mesh box NX NY NZ [--size X Y Z] [--origin X Y Z] --out FILE | mesh convert IN OUT"},
    {"run", sq_cmd_run, "run SCENE.json|--default [--frames N | --seconds T | --until-rest] [--realtime] [--out DIR]"},
    {"serve", sq_cmd_serve, "serve [--host 127.0.0.1] [--port 8080] [--scenes DIR] [--web DIR] [--token T] [--lockstep] ..."},
    {"render", sq_cmd_render, "render SCENE.json|--default [--frames N] [--every K] [--size WxH] [--color level|plain|stress] [--camera AZ,EL[,DIST]] --out DIR"},
    {"bench", sq_cmd_bench, "bench [step|operators|cube] [--sizes LIST] [--seconds T] [--op fem|paper|both|corot]"},
    {"tradeoff", sq_cmd_tradeoff, "tradeoff SCENE.json [--out DIR] [--frames N] [--quick] [--finest K] | tradeoff --bench"},
    {"sweep", sq_cmd_sweep, "sweep [--out DIR] [--quick] [--verbose]  (stability at the extremes)"},
};

static void usage(FILE *f)
{
    fprintf(f, "squish - real-time adaptive soft-body simulation\n\nusage:\n");
    for (size_t i = 0; i < sizeof commands / sizeof commands[0]; i++)
        fprintf(f, "  squish %s\n", commands[i].help);
    fprintf(f, "\n'squish COMMAND --help' for a command's options.\n");
}

int main(int argc, char **argv)
{
    if (argc < 2 || !strcmp(argv[1], "--help") || !strcmp(argv[1], "-h") || !strcmp(argv[1], "help")) {
        usage(argc < 2 ? stderr : stdout);
        return argc < 2 ? 2 : 0;
    }
    for (size_t i = 0; i < sizeof commands / sizeof commands[0]; i++)
        if (!strcmp(argv[1], commands[i].name))
            return commands[i].fn(argc - 1, argv + 1);
    fprintf(stderr, "squish: unknown command '%s'; run 'squish --help' for the list\n", argv[1]);
    return 2;
}
