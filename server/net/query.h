/* query.h - pure parsers of what HTTP clients put in URLs: the query arguments of
 * GET /snapshot.png, and the rule that names the instance in a session id (scale-out behind
 * a proxy, docs/deploy.md). No I/O, no libwebsockets: fuzzed by tests/fuzz/fuzz_query.c. */
#ifndef SQ_NET_QUERY_H
#define SQ_NET_QUERY_H

#include <stddef.h>
#include <stdint.h>

#define SQ_INSTANCE_MAX 99 /* --instance K: 1..99, written as the id's last two decimal digits */

/* what GET /snapshot.png?session=ID[&size=WxH] asks for */
typedef struct sq_snapshot_query {
    uint64_t session;
    int width, height;       /* 800 x 600 when size is not given */
} sq_snapshot_query;

/* parse the query arguments (nargs "name=value" fragments, already split at '&' and
 * URL-decoded, as libwebsockets hands them over; other names are ignored, e.g. a proxy's own).
 * Returns 0, or the HTTP status to answer (400: malformed or repeated argument, bad size;
 * 404: no session id) with a one-line message in msg (n bytes) that says what to send. */
int sq_snapshot_query_parse(const char *const *args, int nargs, int max_side, sq_snapshot_query *q,
                            char *msg, size_t n);

/* session ids: the server composes local = generation << slot bits | slot; with an instance
 * number K (1..99) the id handed out is 100 * local + K, so a proxy can route by the id's
 * last two digits (docker/nginx.conf); K = 0 (a lone server) keeps id = local. */
/* mask of the random generation: ids stay below 2^49 (exact in JSON), with an instance
 * 100 * local too */
uint64_t sq_session_gen_mask(int instance, int slot_bits);
uint64_t sq_session_id_public(uint64_t local, int instance);
/* local part of a public id; -1 when the id belongs to another instance */
int sq_session_id_local(uint64_t id, int instance, uint64_t *local);

#endif
