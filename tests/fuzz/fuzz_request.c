/* fuzz_request.c - libFuzzer harness for the request decoder and state checks
 * (server/net/request.c). Any input must give either a valid request whose fields respect
 * the documented ranges, or an error with a known code and a message; never a crash, a leak
 * or undefined behaviour (built with -fsanitize=fuzzer,address,undefined). */
#include <math.h>
#include <stdint.h>
#include <stdlib.h>
#include <string.h>

#include "net/net.h"

static const char *const codes[] = {"bad_json", "too_large", "bad_type", "bad_field", "out_of_range",
                                    "hello_required", "no_session", "not_controller", "not_lockstep",
                                    "lockstep", "unknown_body", "unknown_tool", "too_many_tools", NULL};

static void expect(int cond)
{
    if (!cond)
        abort();
}

static void check_error(const sq_net_error *e)
{
    int known = 0;
    expect(e->code != NULL);
    for (int i = 0; codes[i]; i++)
        known |= !strcmp(e->code, codes[i]);
    expect(known);
    expect(e->message[0] != 0);
    expect(strlen(e->message) < sizeof e->message);
}

static void check_request(const sq_request *r)
{
    expect(r->type > SQ_REQ_NONE && r->type < SQ_REQ_COUNT);
    expect(sq_req_name(r->type)[0] != 0);
    if (r->ref_kind == SQ_REF_NUMBER)
        expect(isfinite(r->ref_num));
    switch (r->type) {
    case SQ_REQ_TOOL:
        expect(r->tool.id >= 0 && r->tool.id <= SQ_NET_MAX_TOOL_ID);
        for (int k = 0; k < 3; k++) {
            if (r->tool.has_pos)
                expect(isfinite(r->tool.pos[k]) && fabs(r->tool.pos[k]) <= SQ_NET_POS_MAX);
            if (r->tool.has_size)
                expect(r->tool.size[k] > 0 && r->tool.size[k] <= 200);
        }
        if (r->tool.has_radius)
            expect(r->tool.radius > 0 && r->tool.radius <= 100);
        break;
    case SQ_REQ_SET:
        if (r->set.has_nu)
            expect(r->set.nu >= 0 && r->set.nu < 0.5);
        if (r->set.has_E)
            expect(r->set.E > 0 && r->set.E <= 1e10);
        if (r->set.has_budget)
            expect(r->set.budget > 0 && r->set.budget <= 1);
        if (r->set.has_level)
            expect(r->set.level >= 0 && r->set.level < SQ_MAX_LEVELS);
        break;
    case SQ_REQ_STEP:
        expect(r->step.frames >= 1 && r->step.frames <= SQ_NET_MAX_STEP);
        break;
    case SQ_REQ_SUBSCRIBE:
        if (r->subscribe.has_hz)
            expect(r->subscribe.stats_hz >= 0.5 && r->subscribe.stats_hz <= 30);
        break;
    default:
        break;
    }
}

int LLVMFuzzerTestOneInput(const uint8_t *data, size_t size)
{
    /* an exact-size heap copy, so reads past `size` are caught */
    char *text = malloc(size ? size : 1);
    if (size)
        memcpy(text, data, size);
    sq_request r;
    sq_net_error e;
    if (sq_request_decode(text, size, 4096, &r, &e) == 0) {
        check_request(&r);
        /* the state checks over a few client states */
        int ids[3] = {1, 2, 255};
        for (int state = 0; state < 8; state++) {
            sq_client_ctx c = {.greeted = state & 1, .in_session = (state >> 1) & 1,
                               .is_controller = (state >> 2) & 1, .lockstep = state == 7,
                               .nbodies = 2, .ntools = 3, .tool_ids = ids, .max_tools = 8};
            if (sq_request_check(&r, &c, &e))
                check_error(&e);
        }
    } else {
        check_error(&e);
        /* a ref goes back to the client: short, finite; one recovered from unreadable text
         * (bad_json, too_large) printable ASCII (a valid message's ref is echoed as cJSON
         * read it, escaped on output) */
        if (r.ref_kind == SQ_REF_STRING) {
            size_t n = strnlen(r.ref_str, sizeof r.ref_str);
            expect(n < sizeof r.ref_str);
            int recovered = !strcmp(e.code, "bad_json") || !strcmp(e.code, "too_large");
            for (size_t i = 0; recovered && i < n; i++)
                expect((unsigned char)r.ref_str[i] >= 0x20 && (unsigned char)r.ref_str[i] < 0x7f);
        } else if (r.ref_kind == SQ_REF_NUMBER) {
            expect(isfinite(r.ref_num));
        }
    }
    free(text);
    return 0;
}
