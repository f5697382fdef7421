/* limits.h - per-address bookkeeping against unfriendly clients (internal to server/net;
 * docs/security.md): open connections per address and server-wide, wrong-token throttling,
 * and a log that cannot be flooded. Used by the lws service thread only. */
#ifndef SQ_NET_LIMITS_H
#define SQ_NET_LIMITS_H

#include <stddef.h>

#define SQ_ADDR_MAX 48           /* a numeric IPv4/IPv6 address and NUL */

/* open connections: accepted at the network level, keyed by fd until the wsi exists */
typedef struct sq_conns sq_conns;
sq_conns *sq_conns_new(int max_total, int max_per_addr);
void sq_conns_free(sq_conns *t);
/* a connection on fd from addr: 0 accepted (recorded), -1 refused (why says which cap) */
int sq_conns_accept(sq_conns *t, int fd, const char *addr, char *why, size_t cap);
/* the wsi that now owns fd */
void sq_conns_bind(sq_conns *t, int fd, const void *wsi);
/* wsi closed (unknown wsi: nothing) */
void sq_conns_close(sq_conns *t, const void *wsi);
int sq_conns_open(const sq_conns *t);
long sq_conns_refused(const sq_conns *t);

/* wrong control tokens per address: after SQ_GUARD_FAILS wrong tokens within
 * SQ_GUARD_WINDOW s, the address may not try again for SQ_GUARD_BLOCK s */
#define SQ_GUARD_FAILS 5
#define SQ_GUARD_WINDOW 60.0
#define SQ_GUARD_BLOCK 60.0
typedef struct sq_guard sq_guard;
sq_guard *sq_guard_new(void);
void sq_guard_free(sq_guard *g);
/* seconds addr must still wait before it may try a token (0: it may) */
double sq_guard_wait(sq_guard *g, const char *addr, double now);
void sq_guard_fail(sq_guard *g, const char *addr, double now);

/* lws log emitter that prints at most SQ_LOG_BURST lines per second and then one line saying
 * how many were dropped (an accept error repeated 290,000 times no longer floods stderr) */
#define SQ_LOG_BURST 20
void sq_log_emit(int level, const char *line);

#endif
