/* cmd_serve.c - `squish serve`: the WebSocket simulation service (server/net).
 *
 * Without --web / --scenes the viewer and the shipped scenes are looked for where a build or
 * an install puts them (sq_serve_find_data): next to the executable's tree (<exe>/../web,
 * <exe>/../meshes/scenes: the repository's build/squish), the installed data directory
 * relative to the executable (<exe>/../share/squish/{web,scenes}) and the data directory
 * compiled in (SQ_DATADIR, from the Makefile's PREFIX).
 */
#include <limits.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <dirent.h>
#include <sys/stat.h>
#include <unistd.h>

#ifndef SQ_DATADIR
#define SQ_DATADIR "/usr/local/share/squish"
#endif

#include "app/commands.h"
#include "net/net.h"

static void usage(FILE *f)
{
    fprintf(f,
            "usage: squish serve [options]\n"
            "  --host ADDR         address to bind (default 127.0.0.1; 0.0.0.0 for all)\n"
            "  --port N            TCP port (default 8080; 0 picks a free one, printed)\n"
            "  --scenes DIR        scene files (*.json) offered to clients (default: the shipped\n"
            "                      scenes, found next to the executable or in " SQ_DATADIR "/scenes)\n"
            "  --no-scenes         offer only the built-in cube (scene \"default\")\n"
            "  --web DIR           static files served over HTTP (default: the viewer, found next to\n"
            "                      the executable or in " SQ_DATADIR "/web)\n"
            "  --no-web            serve no viewer (/ says how to get one)\n"
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
            "  --max-sessions-per-addr N  sessions that clients without the token at one address\n"
            "                      may have running (default 0: no cap; not behind a proxy)\n"
            "  --io-priority N     1..99: run the service thread (WebSocket I/O, haptic forces)\n"
            "                      SCHED_FIFO at N, so that a busy machine cannot delay a pose;\n"
            "                      sessions' threads stay normal (needs CAP_SYS_NICE or\n"
            "                      RLIMIT_RTPRIO; without it a warning, and normal priority)\n"
            "  --verbose           log sessions and connections\n"
            "  --instance K        1..99: this server is instance K behind a proxy; every session\n"
            "                      id ends in K's two digits (docs/deploy.md, docker/nginx.conf)\n"
            "Protocol: docs/protocol.md. Stops cleanly on SIGINT/SIGTERM.\n");
}

/* dir holds a regular file `file` */
static int has_file(const char *dir, const char *file)
{
    char p[PATH_MAX + 64];
    struct stat st;
    if (snprintf(p, sizeof p, "%s/%s", dir, file) >= (int)sizeof p)
        return 0;
    return stat(p, &st) == 0 && S_ISREG(st.st_mode);
}

/* dir holds at least one *.json file */
static int has_json(const char *dir)
{
    DIR *d = opendir(dir);
    if (!d)
        return 0;
    int found = 0;
    struct dirent *e;
    while (!found && (e = readdir(d))) {
        size_t n = strlen(e->d_name);
        found = e->d_name[0] != '.' && n > 5 && !strcmp(e->d_name + n - 5, ".json");
    }
    closedir(d);
    return found;
}

/* the first candidate directory that holds what is wanted (index.html for the viewer, a
 * *.json for scenes), made absolute; NULL when none does */
static const char *find_data(int scenes, char *out, size_t cap)
{
    char exe[PATH_MAX] = "", dir[PATH_MAX] = "";
    ssize_t n = readlink("/proc/self/exe", exe, sizeof exe - 1);
    if (n > 0) {
        exe[n] = 0;
        snprintf(dir, sizeof dir, "%s", exe);
        char *slash = strrchr(dir, '/');
        if (slash)
            *slash = 0;
    }
    const char *tails[] = {scenes ? "/../meshes/scenes" : "/../web",
                           scenes ? "/../share/squish/scenes" : "/../share/squish/web",
                           scenes ? "/meshes/scenes" : "/web"};
    char cand[PATH_MAX + 64];
    for (int i = 0; i < 4; i++) {
        if (i < 3) {
            if (!dir[0])
                continue;
            snprintf(cand, sizeof cand, "%s%s", dir, tails[i]);
        } else {
            snprintf(cand, sizeof cand, "%s%s", SQ_DATADIR, scenes ? "/scenes" : "/web");
        }
        if (scenes ? has_json(cand) : has_file(cand, "index.html")) {
            char real[PATH_MAX];
            if (snprintf(out, cap, "%s", realpath(cand, real) ? real : cand) >= (int)cap)
                continue; /* too long to hold: look further */
            return out;
        }
    }
    return NULL;
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
                                        "--grace", "--precision", "--instance", "--frame-budget",
                                        "--max-conns", "--max-conns-per-addr", "--idle-timeout",
                                        "--max-sessions-per-addr", "--io-priority", NULL};
    for (int i = 0; flags[i]; i++)
        if (!strcmp(a, flags[i]))
            return 1;
    return 0;
}

int sq_cmd_serve(int argc, char **argv)
{
    sq_serve_options o = sq_serve_options_default();
    int no_scenes = 0, no_web = 0;
    static char web_found[PATH_MAX], scenes_found[PATH_MAX];
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
        } else if (!strcmp(a, "--no-scenes")) {
            no_scenes = 1;
            used = 0;
        } else if (!strcmp(a, "--no-web")) {
            no_web = 1;
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
        } else if (!strcmp(a, "--instance")) {
            rc = int_arg(a, v, 1, 99, &o.instance);
        } else if (!strcmp(a, "--frame-budget")) {
            rc = num_arg(a, v, 0.01, 1e6, &o.frame_budget);
        } else if (!strcmp(a, "--max-conns")) {
            rc = int_arg(a, v, 1, 1000000, &o.max_conns);
        } else if (!strcmp(a, "--max-conns-per-addr")) {
            rc = int_arg(a, v, 1, 1000000, &o.max_conns_per_addr);
        } else if (!strcmp(a, "--max-sessions-per-addr")) {
            rc = int_arg(a, v, 0, 1024, &o.max_sessions_per_addr);
        } else if (!strcmp(a, "--idle-timeout")) {
            rc = num_arg(a, v, 1, 86400, &o.idle_timeout);
        } else if (!strcmp(a, "--io-priority")) {
            rc = int_arg(a, v, 1, 99, &o.io_priority);
        } else {
            fprintf(stderr, "squish serve: unknown option '%s'; see squish serve --help\n", a);
            return 2;
        }
        if (rc)
            return 2;
        i += used;
    }
    if ((no_scenes && o.scenes_dir) || (no_web && o.web_dir)) {
        fprintf(stderr, "squish serve: %s contradicts %s; give one of them\n",
                no_scenes && o.scenes_dir ? "--no-scenes" : "--no-web",
                no_scenes && o.scenes_dir ? "--scenes" : "--web");
        return 2;
    }
    if (!o.web_dir && !no_web)
        o.web_dir = find_data(0, web_found, sizeof web_found);
    if (!o.scenes_dir && !no_scenes)
        o.scenes_dir = find_data(1, scenes_found, sizeof scenes_found);
    sq_err err = {{0}};
    if (sq_serve(&o, &err)) {
        fprintf(stderr, "squish serve: %s\n", err.msg);
        return 1;
    }
    return 0;
}
