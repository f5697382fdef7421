/* errors.h - the protocol's error codes (internal to server/net).
 *
 * Every error reply of the server carries one of these codes: the request decoder
 * (request.c), the service thread (dispatch.c, registry.c, callback.c) and the session
 * threads (jobs.c) name them by their enum, errors.c holds the one table of their names and
 * meanings. docs/protocol.md ("Error codes") lists the same codes with the same meanings;
 * the unit test net_errors_documented compares the two in both directions.
 */
#ifndef SQ_NET_ERRORS_H
#define SQ_NET_ERRORS_H

typedef enum sq_net_code {
    SQ_CODE_BAD_JSON,
    SQ_CODE_TOO_LARGE,
    SQ_CODE_BAD_TYPE,
    SQ_CODE_BAD_FIELD,
    SQ_CODE_OUT_OF_RANGE,
    SQ_CODE_HELLO_REQUIRED,
    SQ_CODE_BAD_TOKEN,
    SQ_CODE_NOT_CONTROLLER,
    SQ_CODE_CONTROLLER_PRESENT,
    SQ_CODE_NO_SESSION,
    SQ_CODE_UNKNOWN_SCENE,
    SQ_CODE_UNKNOWN_SESSION,
    SQ_CODE_UNKNOWN_BODY,
    SQ_CODE_UNKNOWN_TOOL,
    SQ_CODE_TOO_MANY_TOOLS,
    SQ_CODE_SESSION_FULL,
    SQ_CODE_SERVER_FULL,
    SQ_CODE_RATE_LIMITED,
    SQ_CODE_BUSY,
    SQ_CODE_SUPERSEDED,
    SQ_CODE_REFUSED,
    SQ_CODE_NOT_LOCKSTEP,
    SQ_CODE_LOCKSTEP,
    SQ_CODE_SCENE_FAILED,
    SQ_CODE_SHUTTING_DOWN,
    SQ_CODE_THROTTLED,
    SQ_CODE_OVER_BUDGET,
    SQ_CODE_BAD_POSE,
    SQ_CODE_BAD_CHANNEL,
    SQ_CODE_INTERNAL,
    SQ_CODE_COUNT
} sq_net_code;

/* the code as sent in "code" ("bad_json", ...): a static string; "" out of range */
const char *sq_net_code_name(sq_net_code c);
/* the code called name; SQ_CODE_INTERNAL for a name not in the table (a defect) */
sq_net_code sq_net_code_of(const char *name);
/* its meaning, worded as in docs/protocol.md (Markdown); "" out of range */
const char *sq_net_code_meaning(sq_net_code c);

#endif
