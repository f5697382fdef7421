/* main.c - the `squish` command line front end. */
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <unistd.h>

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

/* The heap on transparent huge pages (docs/benchmarks.md, "Memory and page faults"). A first
 * touch of a 4 KiB page costs 10-15 us of CPU on the machines we measure on (a fault through the
 * hypervisor) and a 2 MiB huge page about as much, so box-big's load (about 0.5 GB) and the
 * adaptive frame's growing arrays paid seconds and milliseconds in faults. This kernel grants
 * huge pages only to memory marked for them (transparent_hugepage "madvise"), and glibc marks
 * its heap and large blocks only when asked at start-up (the tunable glibc.malloc.hugetlb=1),
 * so the process starts itself again once with it set. Not done when already set, when
 * SQUISH_HUGE_PAGES=0, under valgrind (its preload: the measured process must be this one), or
 * where the kernel has no huge pages; if the exec fails the command simply goes on. */
static void reexec_on_huge_pages(char **argv)
{
    const char *t = getenv("GLIBC_TUNABLES"), *opt = getenv("SQUISH_HUGE_PAGES"), *pre = getenv("LD_PRELOAD");
    if ((t && strstr(t, "glibc.malloc.hugetlb")) || (opt && !strcmp(opt, "0")) || (pre && strstr(pre, "vgpreload")))
        return;
    FILE *f = fopen("/sys/kernel/mm/transparent_hugepage/enabled", "r");
    char mode[128] = "";
    if (!f)
        return;
    int got = fgets(mode, sizeof mode, f) != NULL;
    fclose(f);
    if (!got || strstr(mode, "[never]"))
        return;
    char val[1024];
    if (snprintf(val, sizeof val, "%s%sglibc.malloc.hugetlb=1", t ? t : "", t ? ":" : "") >= (int)sizeof val)
        return;
    if (setenv("GLIBC_TUNABLES", val, 1) != 0)
        return;
    fflush(NULL);
    execv("/proc/self/exe", argv);
    /* not started again: go on as we are, without the variable for children either */
    if (t)
        setenv("GLIBC_TUNABLES", t, 1);
    else
        unsetenv("GLIBC_TUNABLES");
}

int main(int argc, char **argv)
{
    reexec_on_huge_pages(argv);
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
