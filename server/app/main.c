/* main.c - the `squish` command line front end. */
#include <errno.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "app/commands.h"
#include "util/util.h"

FILE *sq_cmd_open_out(const char *cmd, const char *dir, const char *name, char *path, size_t n)
{
    snprintf(path, n, "%s/%s", dir, name);
    FILE *f = fopen(path, "w");
    if (!f)
        fprintf(stderr, "squish %s: cannot write %s: %s; choose another --out\n", cmd, path, strerror(errno));
    return f;
}

/* the debug switches (util/util.h sq_debug_options) from the one environment variable SQ_DEBUG:
 * words separated by commas or spaces, e.g. SQ_DEBUG=guard_trace,sharp_trace or
 * SQ_DEBUG=sharp_check=2. Returns -1 (and says so) on a word it does not know */
static int read_debug(const char *s, sq_debug_options *o)
{
    static const struct {
        const char *name;
        size_t off;
    } words[] = {
        {"progress", offsetof(sq_debug_options, progress)},
        {"guard_trace", offsetof(sq_debug_options, guard_trace)},
        {"sharp_trace", offsetof(sq_debug_options, sharp_trace)},
        {"sharp_check", offsetof(sq_debug_options, sharp_check)},
        {"sharp_no_stop", offsetof(sq_debug_options, sharp_no_stop)},
        {"static_trace", offsetof(sq_debug_options, static_trace)},
    };
    memset(o, 0, sizeof *o);
    while (s && *s) {
        size_t n = strcspn(s, ", ");
        if (n > 0) {
            size_t k = 0;
            while (k < n && s[k] != '=')
                k++;
            int value = k < n ? atoi(s + k + 1) : 1, found = 0;
            for (size_t i = 0; i < sizeof words / sizeof words[0]; i++)
                if (strlen(words[i].name) == k && !strncmp(s, words[i].name, k)) {
                    *(int *)((char *)o + words[i].off) = value;
                    found = 1;
                }
            if (!found) {
                fprintf(stderr, "squish: SQ_DEBUG: unknown switch '%.*s'; known: progress, guard_trace, "
                        "sharp_trace, sharp_check[=2], sharp_no_stop, static_trace\n", (int)n, s);
                return -1;
            }
        }
        s += n;
        if (*s)
            s++;
    }
    return 0;
}

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
    sq_debug_options dbg;
    if (read_debug(getenv("SQ_DEBUG"), &dbg) < 0)
        return 2;
    sq_debug_set(&dbg);
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
