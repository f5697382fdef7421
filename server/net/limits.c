/* limits.c - connection caps, token-guess throttling, rate-limited log (lws thread only). */
#include "net/limits.h"

#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "util/util.h"

typedef struct conn_rec {
    int fd;
    const void *wsi;             /* NULL until bound */
    char addr[SQ_ADDR_MAX];
} conn_rec;

struct sq_conns {
    int max_total, max_per_addr;
    conn_rec *recs;
    int n;                       /* recs[0..n) are open connections */
    long refused;
};

sq_conns *sq_conns_new(int max_total, int max_per_addr)
{
    sq_conns *t = sq_calloc(1, sizeof *t);
    t->max_total = max_total;
    t->max_per_addr = max_per_addr;
    t->recs = sq_calloc((size_t)max_total + 1, sizeof *t->recs);
    return t;
}

void sq_conns_free(sq_conns *t)
{
    if (!t)
        return;
    free(t->recs);
    free(t);
}

static void drop(sq_conns *t, int i)
{
    t->recs[i] = t->recs[--t->n];
}

int sq_conns_accept(sq_conns *t, int fd, const char *addr, char *why, size_t cap)
{
    /* an fd still recorded was closed without a wsi (adoption failed): forget it */
    for (int i = 0; i < t->n; i++)
        if (t->recs[i].fd == fd) {
            drop(t, i);
            break;
        }
    if (t->n >= t->max_total) {
        snprintf(why, cap, "%d connections are open (--max-conns)", t->n);
        t->refused++;
        return -1;
    }
    int same = 0;
    for (int i = 0; i < t->n; i++)
        same += !strcmp(t->recs[i].addr, addr);
    if (same >= t->max_per_addr) {
        snprintf(why, cap, "%d connections from %s are open (--max-conns-per-addr)", same, addr);
        t->refused++;
        return -1;
    }
    conn_rec *r = &t->recs[t->n++];
    r->fd = fd;
    r->wsi = NULL;
    snprintf(r->addr, sizeof r->addr, "%s", addr);
    return 0;
}

void sq_conns_bind(sq_conns *t, int fd, const void *wsi)
{
    for (int i = 0; i < t->n; i++)
        if (t->recs[i].fd == fd && !t->recs[i].wsi) {
            t->recs[i].wsi = wsi;
            return;
        }
}

void sq_conns_close(sq_conns *t, const void *wsi)
{
    for (int i = 0; i < t->n; i++)
        if (t->recs[i].wsi == wsi) {
            drop(t, i);
            return;
        }
}

int sq_conns_open(const sq_conns *t) { return t->n; }
long sq_conns_refused(const sq_conns *t) { return t->refused; }

/* ---------------------------------------------------------------- token guesses */

#define GUARD_SLOTS 1024         /* addresses remembered (oldest forgotten first) */

typedef struct guard_rec {
    char addr[SQ_ADDR_MAX];
    int fails;
    double first, blocked_until, last;
} guard_rec;

struct sq_guard {
    guard_rec recs[GUARD_SLOTS];
    int n;
};

sq_guard *sq_guard_new(void) { return sq_calloc(1, sizeof(sq_guard)); }
void sq_guard_free(sq_guard *g) { free(g); }

static guard_rec *guard_find(sq_guard *g, const char *addr, int create, double now)
{
    for (int i = 0; i < g->n; i++)
        if (!strcmp(g->recs[i].addr, addr))
            return &g->recs[i];
    if (!create)
        return NULL;
    guard_rec *r;
    if (g->n < GUARD_SLOTS) {
        r = &g->recs[g->n++];
    } else {
        r = &g->recs[0];
        for (int i = 1; i < g->n; i++)
            if (g->recs[i].last < r->last)
                r = &g->recs[i];
    }
    memset(r, 0, sizeof *r);
    snprintf(r->addr, sizeof r->addr, "%s", addr);
    r->first = r->last = now;
    return r;
}

double sq_guard_wait(sq_guard *g, const char *addr, double now)
{
    guard_rec *r = guard_find(g, addr, 0, now);
    return r && r->blocked_until > now ? r->blocked_until - now : 0;
}

void sq_guard_fail(sq_guard *g, const char *addr, double now)
{
    guard_rec *r = guard_find(g, addr, 1, now);
    if (now - r->first > SQ_GUARD_WINDOW) {
        r->first = now;
        r->fails = 0;
    }
    r->last = now;
    if (++r->fails >= SQ_GUARD_FAILS) {
        r->blocked_until = now + SQ_GUARD_BLOCK;
        r->fails = 0;
        r->first = now;
    }
}

/* ---------------------------------------------------------------- log */

void sq_log_emit(int level, const char *line)
{
    static double window;
    static int lines;
    static long dropped;
    (void)level;
    double now = sq_now();
    if (now - window >= 1.0) {
        if (dropped)
            fprintf(stderr, "squish: %ld log lines dropped in the last second (repeated errors)\n",
                    dropped);
        window = now;
        lines = 0;
        dropped = 0;
    }
    if (++lines > SQ_LOG_BURST) {
        dropped++;
        return;
    }
    fputs(line, stderr);
}
