/* query.c - query arguments of /snapshot.png and the instance rule of session ids. */
#include "net/query.h"

#include <stdio.h>
#include <string.h>

#include "render/render.h"

/* a decimal session id: digits only (no sign, space or "0x"), at most 2^53 - 1 */
static int parse_id(const char *s, uint64_t *out)
{
    uint64_t v = 0;
    if (!*s)
        return -1;
    for (; *s; s++) {
        if (*s < '0' || *s > '9')
            return -1;
        v = 10 * v + (uint64_t)(*s - '0');
        if (v > 9007199254740991ull)
            return -1;
    }
    *out = v;
    return 0;
}

int sq_snapshot_query_parse(const char *const *args, int nargs, int max_side, sq_snapshot_query *q,
                            char *msg, size_t n)
{
    const char *session = NULL, *size = NULL;
    q->session = 0;
    q->width = 800;
    q->height = 600;
    for (int i = 0; i < nargs; i++) {
        const char *a = args[i];
        const char **slot = !strncmp(a, "session=", 8) ? &session : !strncmp(a, "size=", 5) ? &size : NULL;
        if (!slot)
            continue;
        if (*slot) {
            snprintf(msg, n, "%s given twice; use /snapshot.png?session=ID[&size=WxH] once each\n",
                     slot == &session ? "session" : "size");
            return 400;
        }
        *slot = strchr(a, '=') + 1;
    }
    if (!session || parse_id(session, &q->session)) {
        /* the value is echoed: printable ASCII only, so the answer stays one line */
        char shown[41];
        size_t k = 0;
        for (const char *c = session ? session : "(missing)"; *c && k < sizeof shown - 1; c++)
            shown[k++] = *c >= 32 && *c < 127 ? *c : '?';
        shown[k] = 0;
        snprintf(msg, n, "no session %s; use /snapshot.png?session=ID with the id of 'opened'\n", shown);
        return 404;
    }
    if (size) {
        sq_err err = {{0}};
        if (sq_render_parse_size(size, max_side, &q->width, &q->height, &err)) {
            /* the message quotes the value: printable ASCII only, so the answer stays one line */
            for (char *c = err.msg; *c; c++)
                if (*c < 32 || *c >= 127)
                    *c = '?';
            snprintf(msg, n, "size: %.300s\n", err.msg);
            return 400;
        }
    }
    return 0;
}

uint64_t sq_session_gen_mask(int instance, int slot_bits)
{
    /* ids stay below 2^49 (at most 15 decimal digits, which JSON numbers as cJSON prints
     * them keep exactly): 100 * ((mask << slot_bits) | slot) < 2^49 needs 7 bits fewer */
    int bits = 49 - slot_bits - (instance > 0 ? 7 : 0);
    return (1ull << bits) - 1;
}

uint64_t sq_session_id_public(uint64_t local, int instance)
{
    return instance > 0 ? 100 * local + (uint64_t)instance : local;
}

int sq_session_id_local(uint64_t id, int instance, uint64_t *local)
{
    if (instance <= 0) {
        *local = id;
        return 0;
    }
    if (id % 100 != (uint64_t)instance)
        return -1;
    *local = id / 100;
    return 0;
}
