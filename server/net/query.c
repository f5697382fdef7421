/* query.c - query arguments of /snapshot.png and the instance rule of session ids. */
#include "net/query.h"

#include <stdio.h>
#include <string.h>

#include "render/render.h"

/* a decimal session id: digits only (no sign, space or "0x"), at most 4294967295 */
static int parse_id(const char *s, uint32_t *out)
{
    uint64_t v = 0;
    if (!*s)
        return -1;
    for (; *s; s++) {
        if (*s < '0' || *s > '9')
            return -1;
        v = 10 * v + (uint64_t)(*s - '0');
        if (v > UINT32_MAX)
            return -1;
    }
    *out = (uint32_t)v;
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

uint32_t sq_session_gen_mask(int instance, int slot_bits)
{
    /* 100 * ((mask << slot_bits) | slot) < 2^32 needs mask < 2^(32 - slot_bits) / 100 */
    int bits = 32 - slot_bits - (instance > 0 ? 7 : 0);
    return (uint32_t)((1ull << bits) - 1);
}

uint32_t sq_session_id_public(uint32_t local, int instance)
{
    return instance > 0 ? 100 * local + (uint32_t)instance : local;
}

int sq_session_id_local(uint32_t id, int instance, uint32_t *local)
{
    if (instance <= 0) {
        *local = id;
        return 0;
    }
    if (id % 100 != (uint32_t)instance)
        return -1;
    *local = id / 100;
    return 0;
}
