/* net.h - the simulation service: request decoding, binary mesh messages, the server.
 *
 * Stage "net" of the data flow (mesh -> sim -> lod -> scene -> net/render -> app). The wire
 * format is documented in docs/protocol.md; this header is its C side:
 *   - sq_request_decode / sq_request_check: JSON text -> validated request, or an error with a
 *     protocol code. Pure functions (no server state), unit-tested and fuzzed.
 *   - sq_blob and the encoders of the binary messages (topology, frame, nodes).
 *   - sq_serve: run the libwebsockets server until SIGINT/SIGTERM.
 */
#ifndef SQ_NET_H
#define SQ_NET_H

#include <stddef.h>
#include <stdint.h>

#include "body/body.h"

#define SQ_PROTOCOL_VERSION 1
#define SQ_SERVER_NAME "squish/0.1"
#define SQ_NET_NAME_MAX 64      /* client, scene names (63 chars + NUL) */
#define SQ_NET_TOKEN_MAX 128    /* control token */
#define SQ_NET_MAX_TOOL_ID 255
#define SQ_NET_MAX_STEP 1000    /* frames per step request */
#define SQ_NET_POS_MAX 1000.0   /* |tool coordinate| bound, m */
#define SQ_NET_SESSION_MAX 9007199254740991.0 /* largest session id: 2^53 - 1 */

/* ---------------------------------------------------------------- requests */

/* request types (the "type" of a client text message) */
typedef enum sq_req_type {
    SQ_REQ_NONE = 0,
    SQ_REQ_HELLO,
    SQ_REQ_LIST_SCENES,
    SQ_REQ_OPEN,
    SQ_REQ_JOIN,
    SQ_REQ_LEAVE,
    SQ_REQ_TOOL,
    SQ_REQ_SET,
    SQ_REQ_PAUSE,
    SQ_REQ_RESUME,
    SQ_REQ_RESET,
    SQ_REQ_STEP,
    SQ_REQ_STATS,
    SQ_REQ_SUBSCRIBE,
    SQ_REQ_NODES,
    SQ_REQ_PING,
    SQ_REQ_TAKE_CONTROL,
    SQ_REQ_COUNT
} sq_req_type;

/* client roles */
typedef enum sq_role { SQ_ROLE_CONTROL = 0, SQ_ROLE_VIEW = 1 } sq_role;

/* the optional "ref" of a request, echoed in its reply */
typedef enum sq_ref_kind {
    SQ_REF_NONE = 0,
    SQ_REF_STRING = 1,
    SQ_REF_NUMBER = 2,
    SQ_REF_NULL = 3          /* "ref": null in the reply (unreadable message, ref not found) */
} sq_ref_kind;

/* a decoded request; fields of the other types are zero. has_* flags tell which optional
 * fields were given. */
typedef struct sq_request {
    sq_req_type type;
    sq_ref_kind ref_kind;
    char ref_str[SQ_NET_NAME_MAX];
    double ref_num;

    struct {
        char client[SQ_NET_NAME_MAX];
        sq_role role;                  /* default control */
        int has_token;
        char token[SQ_NET_TOKEN_MAX];
    } hello;
    struct {
        char scene[SQ_NET_NAME_MAX];
    } open;
    struct {
        uint64_t session;              /* < 2^53: exact in JSON */
        int has_role;
        sq_role role;
    } join;
    struct {
        int id;
        int has_shape, has_pos, has_radius, has_size, has_active;
        sq_tool_shape shape;
        double pos[3];
        double radius;                 /* m */
        double size[3];                /* box full extents, m */
        int active;
    } tool;
    struct {
        int body;                      /* -1: every body */
        int has_E, has_nu, has_density;
        double E, nu, density;
        int has_operator;
        sq_operator_kind op;
        int has_elasticity;
        sq_elasticity_kind elasticity;
        int has_pressure, nodal_pressure;
        int has_integrator;            /* "integrator" given */
        sq_integrator_kind integrator;
        int has_substeps, has_tol, has_max_iter, has_precond, has_newton; /* "implicit" fields */
        sq_implicit_def implicit;      /* the given fields (the others unused) */
        int has_mass, has_stiffness;   /* damping */
        double mass, stiffness;
        int has_mode, has_level, has_split, has_merge, has_max_level, has_budget, has_adapt_every;
        sq_lod_mode mode;
        int level, max_level, adapt_every;
        double split, merge, budget;
    } set;
    struct {
        int body;                      /* -1: whole scene */
    } reset;
    struct {
        int frames;
    } step;
    struct {
        int stats;                     /* -1 unchanged, 0 off, 1 on */
        int frames;                    /* -1 unchanged, 0 off, 1 on */
        int has_hz;
        double stats_hz;
    } subscribe;
    struct {
        int body;
    } nodes;
    struct {
        int has_t;
        double t;
    } ping;
    struct {
        int has_token;
        char token[SQ_NET_TOKEN_MAX];
    } take_control;
} sq_request;

/* a protocol error: a code from docs/protocol.md and a message naming field, value and fix */
typedef struct sq_net_error {
    const char *code;                  /* static string, e.g. "bad_field" */
    char message[320];
} sq_net_error;

/* name of a request type ("hello", ...); "" for SQ_REQ_NONE */
const char *sq_req_name(sq_req_type t);

/* decode one text message of len bytes (need not be NUL-terminated) into req. Checks JSON
 * syntax, the type, field names and JSON types, number finiteness and ranges, string
 * lengths. Messages longer than max_len are refused ("too_large"). Returns 0, or -1 with err
 * filled; on error req->type and the ref are still set when they could be read. A message
 * that is not valid UTF-8 or JSON gets its ref from a scan of the raw text for a top-level
 * "ref" string or number (SQ_REF_NULL when there is none to recover). */
int sq_request_decode(const char *text, size_t len, size_t max_len, sq_request *req,
                      sq_net_error *err);

/* what a request is checked against: the connection's and its session's state */
typedef struct sq_client_ctx {
    int greeted;             /* hello done */
    int in_session;          /* opened or joined */
    int is_controller;       /* controls its session */
    int lockstep;            /* server in lockstep mode */
    int nbodies;             /* bodies of the session */
    int ntools;              /* tools of the session */
    const int *tool_ids;     /* their ids (ntools) */
    int max_tools;           /* SQ_MAX_TOOLS */
} sq_client_ctx;

/* state checks of a decoded request: hello first, session needed, controller needed,
 * body/tool ids known, lockstep-only requests. Pure; 0 or -1 + err. */
int sq_request_check(const sq_request *req, const sq_client_ctx *ctx, sq_net_error *err);

/* ---------------------------------------------------------------- binary messages */

#define SQ_MSG_HEADER 64
#define SQ_MSG_TOPOLOGY 1
#define SQ_MSG_FRAME 2
#define SQ_MSG_NODES 3
#define SQ_MSG_FLAG_RESET 1u
#define SQ_TOOL_RECORD 36

/* an immutable, reference-counted message buffer shared by every client it goes to;
 * data has LWS_PRE (<= SQ_BLOB_PRE) bytes of headroom before the message */
#define SQ_BLOB_PRE 32
typedef struct sq_blob {
    int refs;                /* atomic */
    int binary;              /* 1 binary, 0 text */
    size_t len;              /* message bytes */
    unsigned char *msg;      /* = buf + SQ_BLOB_PRE */
    unsigned char buf[];
} sq_blob;

/* new blob with len message bytes (uninitialised), one reference */
sq_blob *sq_blob_new(size_t len, int binary);
/* text blob holding a copy of s */
sq_blob *sq_blob_text(const char *s);
sq_blob *sq_blob_ref(sq_blob *b);
void sq_blob_unref(sq_blob *b);

/* the decoded header of a binary message */
typedef struct sq_msg_header {
    int kind, flags;
    uint32_t body, frame;
    double time;
    uint32_t count0, count1;
    float offset[3], scale[3];
    uint32_t raw_bytes, zbytes;
} sq_msg_header;

/* per-body scratch kept between frames (sizes of the last frame) */
typedef struct sq_codec {
    int nsurf;
    float *rest;             /* rest surface positions (nsurf x 3) */
    float *cur;              /* scratch: current positions (nsurf x 3) */
    unsigned char *level;    /* scratch (nsurf) */
    unsigned char *raw;      /* scratch payload */
    size_t raw_cap;
    unsigned char *z;        /* scratch compressed */
    size_t z_cap;
    float precision;         /* minimum quantisation step, m (SQ_CODEC_PRECISION x diagonal) */
    float diagonal;          /* rest bounding-box diagonal, m */
} sq_codec;

/* default precision floor of frames, relative to the rest bounding-box diagonal */
#define SQ_CODEC_PRECISION 1e-3

/* set up a codec for a surface of nsurf vertices with rest positions xyz (nsurf x 3) */
void sq_codec_init(sq_codec *c, int nsurf, const float *rest_xyz);
/* the same for the surface of mesh m (its surface nodes' rest positions), with the precision
 * floor precision_rel x the rest diagonal (SQ_CODEC_PRECISION: serve's default) */
void sq_codec_init_surface(sq_codec *c, const sq_mesh *m, double precision_rel);
void sq_codec_free(sq_codec *c);

/* topology message: rest positions of the surface (nsurf x 3) and triangles (ntris x 3) */
sq_blob *sq_encode_topology(sq_codec *c, uint32_t body, uint32_t frame, double time,
                            const int *tris, int ntris);
/* frame message from current surface positions cur (nsurf x 3), levels (nsurf) and tools
 * with their feedback for this body (feedback may be NULL) */
sq_blob *sq_encode_frame(sq_codec *c, uint32_t body, uint32_t frame, double time,
                         unsigned flags, const float *cur, const unsigned char *level,
                         const sq_tool *tools, const sq_tool_feedback *feedback, int ntools);
/* nodes message: n records of position (n x 3) and level (n) */
sq_blob *sq_encode_nodes(uint32_t body, uint32_t frame, double time, const float *xyz,
                         const unsigned char *level, int n);

/* parse a binary message header; -1 + err if the bytes are not a valid header */
int sq_msg_parse_header(const unsigned char *msg, size_t len, sq_msg_header *h, sq_err *err);
/* decompress the payload of msg into out (h->raw_bytes bytes); -1 + err on failure */
int sq_msg_payload(const unsigned char *msg, size_t len, const sq_msg_header *h,
                   unsigned char *out, sq_err *err);

/* ---------------------------------------------------------------- server */

#define SQ_SERVE_MAX_ORIGINS 16

/* options of `squish serve`, filled by sq_serve_options_default() then the flags */
typedef struct sq_serve_options {
    const char *host;        /* "127.0.0.1" */
    int port;                /* 8080; 0 = any free port (printed) */
    const char *scenes_dir;  /* NULL: the embedded default scene only */
    const char *web_dir;     /* NULL: no static files */
    const char *token;       /* NULL: control needs no token */
    int norigins;
    const char *origins[SQ_SERVE_MAX_ORIGINS];
    int max_sessions;        /* 16 */
    int max_clients;         /* per session, 256 */
    int max_message;         /* bytes of a text message, 65536 */
    double rate;             /* requests per second per client, 200 */
    double grace;            /* seconds an empty session lives, 30 */
    double precision;        /* frame quantisation floor / body diagonal, SQ_CODEC_PRECISION */
    int lockstep;            /* 0 */
    int verbose;
    int instance;            /* 0; 1..99 behind a proxy: every session id ends in these two digits */
    /* limits against unfriendly clients (docs/security.md) */
    double frame_budget;     /* CPU per frame a session may use, fraction of its period, 1.0 */
    int max_conns;           /* open connections, server-wide, 2000 */
    int max_conns_per_addr;  /* open connections from one address, 500 (a classroom behind
                                one NAT shares an address) */
    double idle_timeout;     /* s without a message before a WebSocket is closed, 300 */
    int max_sessions_per_addr; /* sessions opened without the token from one address that may
                                  run at once, 0 = no cap (behind a proxy every client shares
                                  the proxy's address) */
    int io_priority;         /* 0: normal; 1..99: the service thread runs SCHED_FIFO at it
                                (threads it starts reset to normal) */
} sq_serve_options;

sq_serve_options sq_serve_options_default(void);

/* run the server until SIGINT/SIGTERM; returns 0 after a clean shutdown, -1 + err if it
 * cannot start (port in use, no scenes, ...) */
int sq_serve(const sq_serve_options *opt, sq_err *err);

#endif
