/* main.c - the `squish` command line front end. */
#include <stdio.h>
#include <string.h>

#include "app/commands.h"

static const struct {
    const char *name;
    int (*fn)(int, char **);
    const char *help;
} commands[] = {
    {"mesh", sq_cmd_mesh, "mesh info FILE | mesh box NX NY NZ [--size X Y Z] --out FILE | mesh convert IN OUT"},
    {"run", sq_cmd_run, "run SCENE.json [--frames N | --seconds T | --until-rest] [--out DIR]"},
    {"serve", sq_cmd_serve, "serve [--host 127.0.0.1] [--port 8080] [--scenes DIR] [--web DIR] ..."},
    {"render", sq_cmd_render, "render SCENE.json [--frames N] [--every K] [--size WxH] [--color level|plain|stress] --out DIR"},
    {"bench", sq_cmd_bench, "bench [step|...]"},
    {"tradeoff", sq_cmd_tradeoff, "tradeoff SCENE.json [--out DIR]"},
    {"sweep", sq_cmd_sweep, "sweep [--out DIR]  (stability at the extremes)"},
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
