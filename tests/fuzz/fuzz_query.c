/* fuzz_query.c - libFuzzer harness of the /snapshot.png query parser and the session-id
 * instance rule (server/net/query.c). The input is split at '&' into at most 8 arguments, as
 * libwebsockets splits a query string; the parser must answer 0 with a size in range, or
 * 400/404 with a one-line message; the id rule must round-trip. */
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "net/query.h"
#include "render/render.h"

static void expect(int cond)
{
    if (!cond)
        abort();
}

int LLVMFuzzerTestOneInput(const uint8_t *data, size_t size)
{
    char *text = malloc(size + 1);
    memcpy(text, data, size);
    text[size] = 0;
    const char *args[8];
    int nargs = 0;
    for (char *p = text, *amp; nargs < 8 && p; p = amp ? amp + 1 : NULL) {
        amp = strchr(p, '&');
        if (amp)
            *amp = 0;
        if (*p)
            args[nargs++] = p;
    }
    sq_snapshot_query q;
    char msg[400];
    int st = sq_snapshot_query_parse(args, nargs, SQ_SNAPSHOT_MAX_SIZE, &q, msg, sizeof msg);
    if (st == 0) {
        expect(q.width >= SQ_RENDER_MIN_SIZE && q.width <= SQ_SNAPSHOT_MAX_SIZE);
        expect(q.height >= SQ_RENDER_MIN_SIZE && q.height <= SQ_SNAPSHOT_MAX_SIZE);
        /* the instance rule on the parsed id, for every instance */
        for (int k = 0; k <= SQ_INSTANCE_MAX; k += 7) {
            uint64_t local, id = q.session;
            if (sq_session_id_local(id, k, &local) == 0) {
                expect(sq_session_id_public(local, k) == id);
            } else {
                expect(k > 0 && id % 100 != (uint64_t)k);
            }
        }
    } else {
        expect(st == 400 || st == 404);
        size_t n = strlen(msg);
        expect(n > 0 && n < sizeof msg && msg[n - 1] == '\n' && !memchr(msg, '\n', n - 1));
    }
    free(text);
    return 0;
}
