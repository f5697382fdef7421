/* errors.c - the one table of the protocol's error codes and their meanings.
 *
 * Order and wording as in the "Error codes" table of docs/protocol.md, which the unit test
 * net_errors_documented checks against this table (a code added on one side only fails it).
 */
#include "net/errors.h"

#include <string.h>

static const struct {
    const char *name;
    const char *meaning;
} codes[SQ_CODE_COUNT] = {
    [SQ_CODE_BAD_JSON] = {"bad_json",
         "not valid UTF-8, not valid JSON, not an object, trailing bytes, or a binary "
         "message from the client that is not a haptic pose (magic `SQHP`)"},
    [SQ_CODE_TOO_LARGE] = {"too_large",
         "text message longer than `limits.max_message` (the message is dropped)"},
    [SQ_CODE_BAD_TYPE] = {"bad_type",
         "`type` missing, not a string, or not a request in the table"},
    [SQ_CODE_BAD_FIELD] = {"bad_field",
         "a field missing, of the wrong JSON type, or unknown"},
    [SQ_CODE_OUT_OF_RANGE] = {"out_of_range",
         "a number non-finite or outside its range, a string too long, an array of the "
         "wrong length"},
    [SQ_CODE_HELLO_REQUIRED] = {"hello_required",
         "a request before `hello`"},
    [SQ_CODE_BAD_TOKEN] = {"bad_token",
         "`control` role (hello, join, take_control) asked with a missing or wrong "
         "token"},
    [SQ_CODE_NOT_CONTROLLER] = {"not_controller",
         "a control request from a viewer (or a demoted client)"},
    [SQ_CODE_CONTROLLER_PRESENT] = {"controller_present",
         "`take_control` while another client controls the session"},
    [SQ_CODE_NO_SESSION] = {"no_session",
         "a session request (`tool`, `set`, `stats`, ...) before `open`/`join`"},
    [SQ_CODE_UNKNOWN_SCENE] = {"unknown_scene",
         "`open` names no loaded scene"},
    [SQ_CODE_UNKNOWN_SESSION] = {"unknown_session",
         "`join` names a session that does not exist (ended, or never did)"},
    [SQ_CODE_UNKNOWN_BODY] = {"unknown_body",
         "`body` is not an id of the session's bodies"},
    [SQ_CODE_UNKNOWN_TOOL] = {"unknown_tool",
         "a `tool` update without `shape`/`pos` for an id the session does not have"},
    [SQ_CODE_TOO_MANY_TOOLS] = {"too_many_tools",
         "more than 8 tools in a session"},
    [SQ_CODE_SESSION_FULL] = {"session_full",
         "the session has `max_clients` clients"},
    [SQ_CODE_SERVER_FULL] = {"server_full",
         "`max_sessions` sessions are running"},
    [SQ_CODE_RATE_LIMITED] = {"rate_limited",
         "more than `limits.rate` requests per second (request dropped), or haptic poses "
         "faster than the channel's `max_rate` (pose dropped, counted)"},
    [SQ_CODE_BUSY] = {"busy",
         "64 requests of this client already wait for its session thread (request "
         "dropped; wait for replies)"},
    [SQ_CODE_SUPERSEDED] = {"superseded",
         "a `nodes` request replaced by a newer one of the same client (one runs at a "
         "time per client)"},
    [SQ_CODE_REFUSED] = {"refused",
         "the engine refused a setting; `message` gives its reason (e.g. the step "
         "bound it would break)"},
    [SQ_CODE_NOT_LOCKSTEP] = {"not_lockstep",
         "`step` on a server not started with `--lockstep`"},
    [SQ_CODE_LOCKSTEP] = {"lockstep",
         "`pause`/`resume` in lockstep mode (the clock never runs)"},
    [SQ_CODE_SCENE_FAILED] = {"scene_failed",
         "the scene could not be instantiated (message says why)"},
    [SQ_CODE_SHUTTING_DOWN] = {"shutting_down",
         "the server is stopping"},
    [SQ_CODE_THROTTLED] = {"throttled",
         "`hello` with a token from an address that sent 5 wrong tokens within 60 s: "
         "it may try again after 60 s (the message says how long)"},
    [SQ_CODE_OVER_BUDGET] = {"over_budget",
         "a `set` whose predicted CPU cost per frame is over the session's frame "
         "budget (`--frame-budget`); the message gives the prediction (substeps x "
         "nodes x measured cost per node update) and the budget; nothing changed"},
    [SQ_CODE_BAD_POSE] = {"bad_pose",
         "a haptic pose message of the wrong size, magic, version or kind, or with a "
         "non-finite or out-of-bounds position (dropped, counted in `stats.haptic`)"},
    [SQ_CODE_BAD_CHANNEL] = {"bad_channel",
         "a haptic pose on a channel this client does not own (never opened, closed, "
         "another client's, or the client no longer controls the session): dropped, counted"},
    [SQ_CODE_INTERNAL] = {"internal",
         "a request the server has no handler for, or a reply it could not build (out "
         "of memory): a defect of the server, to report"},
};

const char *sq_net_code_name(sq_net_code c)
{
    return (unsigned)c < SQ_CODE_COUNT ? codes[c].name : "";
}

const char *sq_net_code_meaning(sq_net_code c)
{
    return (unsigned)c < SQ_CODE_COUNT ? codes[c].meaning : "";
}

sq_net_code sq_net_code_of(const char *name)
{
    for (int c = 0; name && c < SQ_CODE_COUNT; c++)
        if (!strcmp(codes[c].name, name))
            return (sq_net_code)c;
    return SQ_CODE_INTERNAL;
}
