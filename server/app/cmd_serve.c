/* cmd_serve.c - `squish serve`: the WebSocket simulation service (server/net). */
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "app/commands.h"
#include "net/net.h"

static void usage(FILE *f)
{
    fprintf(f,
            "usage: squish serve [options]\n"
            "  --host ADDR         address to bind (default 127.0.0.1; 0.0.0.0 for all)\n"
            "  --port N            TCP port (default 8080; 0 picks a free one, printed)\n"
            "  --scenes DIR        scene files (*.json) offered to clients (default: built-in cube)\n"
            "  --web DIR           static files served over HTTP (the viewer)\n"
            "  --token T           clients need this token for the control role\n"
            "  --origin URL        allowed Origin of WebSocket clients (repeatable; default any)\n"
            "  --max-sessions N    running sessions (default 16)\n"
            "  --max-clients N     clients per session (default 256)\n"
            "  --max-message BYTES largest text message accepted (default 65536)\n"
            "  --rate N            requests per second per client (default 200)\n"
            "  --grace SECONDS     how long an empty session is kept (default 30)\n"
            "  --precision REL     frame quantisation floor as a fraction of a body's size\n"
            "                      (default 1e-3: 1.7 mm on a 1 m cube; smaller = finer, more bytes)\n"
            "  --lockstep          no real-time clock: sessions advance only on 'step'\n"
            "  --frame-budget F    CPU time a session may spend per frame, as a fraction of its\n"
            "                      frame period (default 1); costlier settings are refused\n"
            "  --max-conns N       open connections, server-wide (default 2000)\n"
            "  --max-conns-per-addr N  open connections from one address (default 500)\n"
            "  --idle-timeout S    close a WebSocket silent for S seconds (default 300)\n"
            "  --verbose           log sessions and connections\n"
            "Protocol: docs/protocol.md. Stops cleanly on SIGINT/SIGTERM.\n");
}

/* integer flag value in [lo, hi]; -1 on error (message printed) */
static int int_arg(const char *flag, const char *v, long lo, long hi, int *out)
{
    char *end;
    long x = v ? strtol(v, &end, 10) : 0;
    if (!v || *end || end == v || x < lo || x > hi) {
        fprintf(stderr, "squish serve: %s needs an integer in [%ld, %ld], got '%s'\n", flag, lo, hi,
                v ? v : "(nothing)");
        return -1;
    }
    *out = (int)x;
    return 0;
}

static int num_arg(const char *flag, const char *v, double lo, double hi, double *out)
{
    char *end;
    double x = v ? strtod(v, &end) : 0;
    if (!v || *end || end == v || !(x >= lo && x <= hi)) {
        fprintf(stderr, "squish serve: %s needs a number in [%g, %g], got '%s'\n", flag, lo, hi,
                v ? v : "(nothing)");
        return -1;
    }
    *out = x;
    return 0;
}

/* flags that take a value */
static int is_value_flag(const char *a)
{
    static const char *const flags[] = {"--host", "--port", "--scenes", "--web", "--token", "--origin",
                                        "--max-sessions", "--max-clients", "--max-message", "--rate",
                                        "--grace", "--precision", "--frame-budget", "--max-conns",
                                        "--max-conns-per-addr", "--idle-timeout", NULL};
    for (int i = 0; flags[i]; i++)
        if (!strcmp(a, flags[i]))
            return 1;
    return 0;
}

int sq_cmd_serve(int argc, char **argv)
{
    sq_serve_options o = sq_serve_options_default();
    for (int i = 1; i < argc; i++) {
        const char *a = argv[i], *v = i + 1 < argc ? argv[i + 1] : NULL;
        int used = 1, rc = 0;
        double rate;
        if (!strcmp(a, "--help") || !strcmp(a, "-h")) {
            usage(stdout);
            return 0;
        } else if (!strcmp(a, "--lockstep")) {
            o.lockstep = 1;
            used = 0;
        } else if (!strcmp(a, "--verbose")) {
            o.verbose = 1;
            used = 0;
        } else if (!is_value_flag(a)) {
            fprintf(stderr, "squish serve: unknown option '%s'; see squish serve --help\n", a);
            return 2;
        } else if (!v) {
            fprintf(stderr, "squish serve: %s needs a value; see squish serve --help\n", a);
            return 2;
        } else if (!strcmp(a, "--host")) {
            o.host = v;
        } else if (!strcmp(a, "--port")) {
            rc = int_arg(a, v, 0, 65535, &o.port);
        } else if (!strcmp(a, "--scenes")) {
            o.scenes_dir = v;
        } else if (!strcmp(a, "--web")) {
            o.web_dir = v;
        } else if (!strcmp(a, "--token")) {
            o.token = v;
        } else if (!strcmp(a, "--origin")) {
            if (o.norigins == SQ_SERVE_MAX_ORIGINS) {
                fprintf(stderr, "squish serve: at most %d --origin flags\n", SQ_SERVE_MAX_ORIGINS);
                return 2;
            }
            o.origins[o.norigins++] = v;
        } else if (!strcmp(a, "--max-sessions")) {
            rc = int_arg(a, v, 1, 1024, &o.max_sessions);
        } else if (!strcmp(a, "--max-clients")) {
            rc = int_arg(a, v, 1, 100000, &o.max_clients);
        } else if (!strcmp(a, "--max-message")) {
            rc = int_arg(a, v, 64, 64 << 20, &o.max_message);
        } else if (!strcmp(a, "--rate")) {
            /* accepts "N" or "N/s" */
            char buf[32];
            snprintf(buf, sizeof buf, "%s", v);
            char *slash = strstr(buf, "/s");
            if (slash && !slash[2])
                *slash = 0;
            rc = num_arg(a, buf, 1, 1e6, &rate);
            o.rate = rate;
        } else if (!strcmp(a, "--precision")) {
            rc = num_arg(a, v, 1e-7, 0.01, &o.precision);
        } else if (!strcmp(a, "--grace")) {
            rc = num_arg(a, v, 0, 86400, &o.grace);
        } else if (!strcmp(a, "--frame-budget")) {
            rc = num_arg(a, v, 0.01, 1e6, &o.frame_budget);
        } else if (!strcmp(a, "--max-conns")) {
            rc = int_arg(a, v, 1, 1000000, &o.max_conns);
        } else if (!strcmp(a, "--max-conns-per-addr")) {
            rc = int_arg(a, v, 1, 1000000, &o.max_conns_per_addr);
        } else if (!strcmp(a, "--idle-timeout")) {
            rc = num_arg(a, v, 1, 86400, &o.idle_timeout);
        } else {
            fprintf(stderr, "squish serve: unknown option '%s'; see squish serve --help\n", a);
            return 2;
        }
        if (rc)
            return 2;
        i += used;
    }
    sq_err err = {{0}};
    if (sq_serve(&o, &err)) {
        fprintf(stderr, "squish serve: %s\n", err.msg);
        return 1;
    }
    return 0;
}
