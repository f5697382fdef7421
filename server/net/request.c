/* request.c - client text messages: JSON -> validated sq_request, and the state checks.
 *
 * Pure functions: nothing here touches a session or a socket, so the fuzzer and the unit
 * tests call them directly. Every refusal names the field, the value and what to do.
 */
#include "net/errors.h"
#include "net/net.h"
#include "net/rawtext.h"

#include <cJSON.h>
#include <math.h>
#include <stdarg.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

static const char *const req_names[SQ_REQ_COUNT] = {
    [SQ_REQ_NONE] = "",
    [SQ_REQ_HELLO] = "hello",
    [SQ_REQ_LIST_SCENES] = "list_scenes",
    [SQ_REQ_OPEN] = "open",
    [SQ_REQ_JOIN] = "join",
    [SQ_REQ_LEAVE] = "leave",
    [SQ_REQ_TOOL] = "tool",
    [SQ_REQ_SET] = "set",
    [SQ_REQ_PAUSE] = "pause",
    [SQ_REQ_RESUME] = "resume",
    [SQ_REQ_RESET] = "reset",
    [SQ_REQ_STEP] = "step",
    [SQ_REQ_STATS] = "stats",
    [SQ_REQ_SUBSCRIBE] = "subscribe",
    [SQ_REQ_NODES] = "nodes",
    [SQ_REQ_PING] = "ping",
    [SQ_REQ_TAKE_CONTROL] = "take_control",
};

const char *sq_req_name(sq_req_type t)
{
    return (t > SQ_REQ_NONE && t < SQ_REQ_COUNT) ? req_names[t] : "";
}

static int fail(sq_net_error *err, sq_net_code code, const char *fmt, ...)
    __attribute__((format(printf, 3, 4)));
static int fail(sq_net_error *err, sq_net_code code, const char *fmt, ...)
{
    err->code = sq_net_code_name(code);
    va_list ap;
    va_start(ap, fmt);
    vsnprintf(err->message, sizeof err->message, fmt, ap);
    va_end(ap);
    return -1;
}

/* a short printable rendering of a JSON value for messages */
static void show(const cJSON *v, char *out, size_t n)
{
    char *s = cJSON_PrintUnformatted(v);
    if (!s) {
        snprintf(out, n, "?");
        return;
    }
    if (strlen(s) > 40)
        snprintf(out, n, "%.37s...", s);
    else
        snprintf(out, n, "%s", s);
    cJSON_free(s);
}

static const char *json_kind(const cJSON *v)
{
    const char *k = sq_json_kind(v);
    return k ? k : "invalid";
}

/* the protocol's wording of a refused field (util/json.c checks it): the path, the value,
 * what to send; bad_field for a wrong JSON type or key, out_of_range for a wrong value */
static int report(sq_json_reader *r, const sq_json_fault *f)
{
    sq_net_error *err = r->ctx;
    const char *path = f->path;
    char buf[48];
    switch (f->kind) {
    case SQ_JSON_WRONG_TYPE: {
        static const char *const want[] = {
            [SQ_JSON_NUMBER] = "a number", [SQ_JSON_STRING] = "a string",
            [SQ_JSON_BOOL] = "true or false", [SQ_JSON_ARRAY] = "an array",
            [SQ_JSON_OBJECT] = "an object", [SQ_JSON_VEC3] = "[x, y, z]"};
        show(f->item, buf, sizeof buf);
        return fail(err, SQ_CODE_BAD_FIELD, "%s: expected %s, got %s (%s)", path, want[f->want],
                    json_kind(f->item), buf);
    }
    case SQ_JSON_NOT_FINITE:
        return fail(err, SQ_CODE_OUT_OF_RANGE, "%s: %g is not a finite number; send a finite value",
                    path, f->x);
    case SQ_JSON_BAD_INT:
    case SQ_JSON_OUT_OF_RANGE:
        /* an integer outside [lo, hi] is refused as outside, before being whole */
        if (f->kind == SQ_JSON_BAD_INT && f->in_range)
            return fail(err, SQ_CODE_OUT_OF_RANGE, "%s: %g is not an integer; send a whole number", path,
                        f->x);
        return fail(err, SQ_CODE_OUT_OF_RANGE, "%s: %g is outside %s%g, %g]; send a value in range",
                    path, f->x, f->lo_open ? "(" : "[", f->lo, f->hi);
    case SQ_JSON_TOO_LONG:
        return fail(err, SQ_CODE_OUT_OF_RANGE, "%s: string of %zu bytes is too long (at most %zu)",
                    path, f->len, f->cap - 1);
    case SQ_JSON_CONTROL_CHAR:
        return fail(err, SQ_CODE_OUT_OF_RANGE, "%s: control character at byte %zu; send plain text",
                    path, f->at);
    case SQ_JSON_WRONG_LENGTH:
        return fail(err, SQ_CODE_OUT_OF_RANGE, "%s: expected 3 numbers [x, y, z], got %d", path, f->n);
    case SQ_JSON_UNKNOWN_KEY: {
        char list[200] = "";
        for (int i = 0; f->known[i]; i++) {
            strncat(list, i ? ", " : "", sizeof list - strlen(list) - 1);
            strncat(list, f->known[i], sizeof list - strlen(list) - 1);
        }
        return fail(err, SQ_CODE_BAD_FIELD, "%s: unknown field '%.40s'; known fields: %s", path,
                    f->key, list);
    }
    case SQ_JSON_DUPLICATE_KEY:
        return fail(err, SQ_CODE_BAD_FIELD, "%s.%.40s: given twice; give each field once", path,
                    f->key);
    }
    return fail(err, SQ_CODE_INTERNAL, "%s: refused", path);
}

/* the readers of request fields, with the protocol's wording: a key given twice is refused
 * where it first appears */
#define READER(err) sq_json_reader rd = {report, err, 1}

/* every child of obj must be named in allowed (NULL-terminated) and appear once */
static int check_fields(const cJSON *obj, const char *path, const char *const *allowed,
                        sq_net_error *err)
{
    READER(err);
    return sq_json_keys(&rd, obj, path, allowed);
}

/* a finite number in [lo, hi] (open ends when lo_open/hi_open) */
static int get_number(const cJSON *v, const char *path, double lo, double hi, int lo_open,
                      double *out, sq_net_error *err)
{
    READER(err);
    return sq_json_number(&rd, v, path, lo, hi, lo_open, out);
}

static int get_int(const cJSON *v, const char *path, int lo, int hi, int *out,
                   sq_net_error *err)
{
    READER(err);
    double x = 0;
    if (sq_json_int(&rd, v, path, lo, hi, &x))
        return -1;
    *out = (int)x;
    return 0;
}

static int get_bool(const cJSON *v, const char *path, int *out, sq_net_error *err)
{
    READER(err);
    return sq_json_bool(&rd, v, path, out);
}

/* a string of at most cap - 1 bytes, without control characters */
static int get_string(const cJSON *v, const char *path, char *out, size_t cap,
                      sq_net_error *err)
{
    READER(err);
    return sq_json_string(&rd, v, path, out, cap, 1);
}

/* one of the given words; returns its index */
static int get_enum(const cJSON *v, const char *path, const char *const *words, int *out,
                    sq_net_error *err)
{
    char s[32];
    if (get_string(v, path, s, sizeof s, err)) {
        if (err->code == sq_net_code_name(SQ_CODE_OUT_OF_RANGE))
            err->code = sq_net_code_name(SQ_CODE_BAD_FIELD);
        return -1;
    }
    char list[120] = "";
    for (int i = 0; words[i]; i++) {
        if (!strcmp(s, words[i])) {
            *out = i;
            return 0;
        }
        strncat(list, i ? "\", \"" : "\"", sizeof list - strlen(list) - 1);
        strncat(list, words[i], sizeof list - strlen(list) - 1);
    }
    return fail(err, SQ_CODE_OUT_OF_RANGE, "%s: \"%s\" is not one of %s\"", path, s, list);
}

/* [x, y, z], each finite in [lo, hi] (lo open when lo_open) */
static int get_vec3(const cJSON *v, const char *path, double lo, double hi, int lo_open,
                    double out[3], sq_net_error *err)
{
    READER(err);
    return sq_json_vec3(&rd, v, path, lo, hi, lo_open, out);
}

static int expect_object(const cJSON *v, const char *path, sq_net_error *err)
{
    READER(err);
    return sq_json_expect(&rd, v, path, SQ_JSON_OBJECT);
}

static const char *const roles[] = {"control", "view", NULL};
static const char *const shapes[] = {"sphere", "box", "grab", NULL};
static const char *const operators[] = {"fem", "paper", NULL};
static const char *const elasticities[] = {"linear", "corotational", NULL};
static const char *const pressures[] = {"element", "nodal", "smoothed", NULL}; /* SQ_PRESSURE_* */
static const char *const lod_modes[] = {"fixed", "adaptive", NULL};
static const char *const integrators[] = {"explicit", "implicit", NULL};
static const char *const preconditioners[] = {"jacobi", "block_jacobi", "multigrid", NULL}; /* SQ_PRECOND_* */

static int decode_hello(const cJSON *o, sq_request *r, sq_net_error *err)
{
    static const char *const f[] = {"type", "ref", "client", "role", "token", NULL};
    if (check_fields(o, "hello", f, err))
        return -1;
    const cJSON *v;
    int e;
    if ((v = cJSON_GetObjectItemCaseSensitive(o, "client")) &&
        get_string(v, "hello.client", r->hello.client, sizeof r->hello.client, err))
        return -1;
    r->hello.role = SQ_ROLE_CONTROL;
    if ((v = cJSON_GetObjectItemCaseSensitive(o, "role"))) {
        if (get_enum(v, "hello.role", roles, &e, err))
            return -1;
        r->hello.role = (sq_role)e;
    }
    if ((v = cJSON_GetObjectItemCaseSensitive(o, "token"))) {
        if (get_string(v, "hello.token", r->hello.token, sizeof r->hello.token, err))
            return -1;
        r->hello.has_token = 1;
    }
    return 0;
}

static int decode_take_control(const cJSON *o, sq_request *r, sq_net_error *err)
{
    static const char *const f[] = {"type", "ref", "token", NULL};
    if (check_fields(o, "take_control", f, err))
        return -1;
    const cJSON *v = cJSON_GetObjectItemCaseSensitive(o, "token");
    if (v) {
        if (get_string(v, "take_control.token", r->take_control.token,
                       sizeof r->take_control.token, err))
            return -1;
        r->take_control.has_token = 1;
    }
    return 0;
}

static int decode_open(const cJSON *o, sq_request *r, sq_net_error *err)
{
    static const char *const f[] = {"type", "ref", "scene", NULL};
    if (check_fields(o, "open", f, err))
        return -1;
    const cJSON *v = cJSON_GetObjectItemCaseSensitive(o, "scene");
    if (!v)
        return fail(err, SQ_CODE_BAD_FIELD, "open.scene: missing; give a scene name from list_scenes");
    return get_string(v, "open.scene", r->open.scene, sizeof r->open.scene, err);
}

static int decode_join(const cJSON *o, sq_request *r, sq_net_error *err)
{
    static const char *const f[] = {"type", "ref", "session", "role", NULL};
    if (check_fields(o, "join", f, err))
        return -1;
    const cJSON *v = cJSON_GetObjectItemCaseSensitive(o, "session");
    if (!v)
        return fail(err, SQ_CODE_BAD_FIELD, "join.session: missing; give the session id from 'opened'");
    double s;
    if (get_number(v, "join.session", 0, SQ_NET_SESSION_MAX, 0, &s, err))
        return -1;
    if (s != floor(s))
        return fail(err, SQ_CODE_OUT_OF_RANGE, "join.session: %g is not an integer session id", s);
    r->join.session = (uint64_t)s;
    if ((v = cJSON_GetObjectItemCaseSensitive(o, "role"))) {
        int e;
        if (get_enum(v, "join.role", roles, &e, err))
            return -1;
        r->join.has_role = 1;
        r->join.role = (sq_role)e;
    }
    return 0;
}

static int decode_tool(const cJSON *o, sq_request *r, sq_net_error *err)
{
    static const char *const f[] = {"type", "ref", "id", "shape", "pos", "radius", "size",
                                    "active", NULL};
    if (check_fields(o, "tool", f, err))
        return -1;
    const cJSON *v = cJSON_GetObjectItemCaseSensitive(o, "id");
    if (!v)
        return fail(err, SQ_CODE_BAD_FIELD, "tool.id: missing; give an integer 0..%d",
                    SQ_NET_MAX_TOOL_ID);
    if (get_int(v, "tool.id", 0, SQ_NET_MAX_TOOL_ID, &r->tool.id, err))
        return -1;
    int e;
    if ((v = cJSON_GetObjectItemCaseSensitive(o, "shape"))) {
        if (get_enum(v, "tool.shape", shapes, &e, err))
            return -1;
        r->tool.has_shape = 1;
        r->tool.shape = (sq_tool_shape)e;
    }
    if ((v = cJSON_GetObjectItemCaseSensitive(o, "pos"))) {
        if (get_vec3(v, "tool.pos", -SQ_NET_POS_MAX, SQ_NET_POS_MAX, 0, r->tool.pos, err))
            return -1;
        r->tool.has_pos = 1;
    }
    if ((v = cJSON_GetObjectItemCaseSensitive(o, "radius"))) {
        if (get_number(v, "tool.radius", 0, 100, 1, &r->tool.radius, err))
            return -1;
        r->tool.has_radius = 1;
    }
    if ((v = cJSON_GetObjectItemCaseSensitive(o, "size"))) {
        if (get_vec3(v, "tool.size", 0, 200, 1, r->tool.size, err))
            return -1;
        r->tool.has_size = 1;
    }
    if ((v = cJSON_GetObjectItemCaseSensitive(o, "active"))) {
        if (get_bool(v, "tool.active", &r->tool.active, err))
            return -1;
        r->tool.has_active = 1;
    }
    return 0;
}

static int decode_body(const cJSON *o, const char *path, int *body, sq_net_error *err)
{
    const cJSON *v = cJSON_GetObjectItemCaseSensitive(o, "body");
    *body = -1;
    if (v && get_int(v, path, 0, 1000000, body, err))
        return -1;
    return 0;
}

/* set.implicit: the implicit integrator's settings (*given = 1 when one is there) */
static int decode_set_implicit(const cJSON *m, sq_request *r, int *given, sq_net_error *err)
{
    static const char *const fi[] = {"substeps", "cg_tolerance", "cg_max_iterations", "preconditioner",
                                     "newton_iterations", NULL};
    const cJSON *v;
    if (expect_object(m, "set.implicit", err) || check_fields(m, "set.implicit", fi, err))
        return -1;
    sq_implicit_def *im = &r->set.implicit;
    if ((v = cJSON_GetObjectItemCaseSensitive(m, "substeps"))) {
        if (get_int(v, "set.implicit.substeps", 1, SQ_IMPLICIT_MAX_SUBSTEPS, &im->substeps, err))
            return -1;
        r->set.has_substeps = *given = 1;
    }
    if ((v = cJSON_GetObjectItemCaseSensitive(m, "cg_tolerance"))) {
        if (get_number(v, "set.implicit.cg_tolerance", 0, 1, 1, &im->tol, err))
            return -1;
        if (!(im->tol < 1))
            return fail(err, SQ_CODE_OUT_OF_RANGE, "set.implicit.cg_tolerance: %g is outside (0, 1); send a "
                        "relative residual such as 1e-6", im->tol);
        r->set.has_tol = *given = 1;
    }
    if ((v = cJSON_GetObjectItemCaseSensitive(m, "cg_max_iterations"))) {
        if (get_int(v, "set.implicit.cg_max_iterations", 1, SQ_IMPLICIT_MAX_ITER, &im->max_iter, err))
            return -1;
        r->set.has_max_iter = *given = 1;
    }
    if ((v = cJSON_GetObjectItemCaseSensitive(m, "preconditioner"))) {
        if (get_enum(v, "set.implicit.preconditioner", preconditioners, &im->precond, err))
            return -1;
        r->set.has_precond = *given = 1;
    }
    if ((v = cJSON_GetObjectItemCaseSensitive(m, "newton_iterations"))) {
        if (get_int(v, "set.implicit.newton_iterations", 1, SQ_IMPLICIT_MAX_NEWTON, &im->newton, err))
            return -1;
        r->set.has_newton = *given = 1;
    }
    return 0;
}

/* set.lod: the level-of-detail settings (*given = 1 when one is there) */
static int decode_set_lod(const cJSON *m, sq_request *r, int *given, sq_net_error *err)
{
    static const char *const fl[] = {"mode", "level", "split", "merge", "max_level", "budget",
                                     "adapt_every", NULL};
    const cJSON *v;
    int e;
    if (expect_object(m, "set.lod", err) || check_fields(m, "set.lod", fl, err))
        return -1;
    if ((v = cJSON_GetObjectItemCaseSensitive(m, "mode"))) {
        if (get_enum(v, "set.lod.mode", lod_modes, &e, err))
            return -1;
        r->set.has_mode = *given = 1;
        r->set.mode = e ? SQ_LOD_ADAPTIVE : SQ_LOD_FIXED;
    }
    if ((v = cJSON_GetObjectItemCaseSensitive(m, "level"))) {
        if (get_int(v, "set.lod.level", 0, SQ_MAX_LEVELS - 1, &r->set.level, err))
            return -1;
        r->set.has_level = *given = 1;
    }
    if ((v = cJSON_GetObjectItemCaseSensitive(m, "split"))) {
        if (get_number(v, "set.lod.split", 0, 1e3, 0, &r->set.split, err))
            return -1;
        r->set.has_split = *given = 1;
    }
    if ((v = cJSON_GetObjectItemCaseSensitive(m, "merge"))) {
        if (get_number(v, "set.lod.merge", 0, 1e3, 0, &r->set.merge, err))
            return -1;
        r->set.has_merge = *given = 1;
    }
    if ((v = cJSON_GetObjectItemCaseSensitive(m, "max_level"))) {
        if (get_int(v, "set.lod.max_level", 0, SQ_MAX_LEVELS - 1, &r->set.max_level, err))
            return -1;
        r->set.has_max_level = *given = 1;
    }
    if ((v = cJSON_GetObjectItemCaseSensitive(m, "budget"))) {
        if (get_number(v, "set.lod.budget", 0, 1, 1, &r->set.budget, err))
            return -1;
        r->set.has_budget = *given = 1;
    }
    if ((v = cJSON_GetObjectItemCaseSensitive(m, "adapt_every"))) {
        if (get_int(v, "set.lod.adapt_every", 1, SQ_LOD_ADAPT_EVERY_MAX, &r->set.adapt_every, err))
            return -1;
        r->set.has_adapt_every = *given = 1;
    }
    return 0;
}

static int decode_set(const cJSON *o, sq_request *r, sq_net_error *err)
{
    static const char *const f[] = {"type", "ref", "body", "material", "operator", "damping",
                                    "lod", "elasticity", "pressure", "integrator", "implicit", NULL};
    static const char *const fm[] = {"E", "nu", "density", NULL};
    static const char *const fd[] = {"mass", "stiffness", NULL};
    if (check_fields(o, "set", f, err) || decode_body(o, "set.body", &r->set.body, err))
        return -1;
    int given = 0, e;
    const cJSON *v, *m;
    if ((m = cJSON_GetObjectItemCaseSensitive(o, "material"))) {
        if (expect_object(m, "set.material", err) || check_fields(m, "set.material", fm, err))
            return -1;
        if ((v = cJSON_GetObjectItemCaseSensitive(m, "E"))) {
            if (get_number(v, "set.material.E", 0, 1e10, 1, &r->set.E, err))
                return -1;
            r->set.has_E = given = 1;
        }
        if ((v = cJSON_GetObjectItemCaseSensitive(m, "nu"))) {
            /* [0, 0.5), as in scene files (docs/scenes.md); the engine refuses a value whose
             * step bound it cannot meet */
            if (cJSON_IsNumber(v) && isfinite(v->valuedouble) &&
                !(v->valuedouble >= 0 && v->valuedouble < 0.5))
                return fail(err, SQ_CODE_OUT_OF_RANGE, "set.material.nu: %g is outside [0, 0.5); "
                            "send a value in range", v->valuedouble);
            if (get_number(v, "set.material.nu", 0, 0.5, 0, &r->set.nu, err))
                return -1;
            r->set.has_nu = given = 1;
        }
        if ((v = cJSON_GetObjectItemCaseSensitive(m, "density"))) {
            if (get_number(v, "set.material.density", 0, 1e5, 1, &r->set.density, err))
                return -1;
            r->set.has_density = given = 1;
        }
    }
    if ((v = cJSON_GetObjectItemCaseSensitive(o, "operator"))) {
        if (get_enum(v, "set.operator", operators, &e, err))
            return -1;
        r->set.has_operator = given = 1;
        r->set.op = e ? SQ_OPERATOR_PAPER : SQ_OPERATOR_FEM;
    }
    if ((v = cJSON_GetObjectItemCaseSensitive(o, "elasticity"))) {
        if (get_enum(v, "set.elasticity", elasticities, &e, err))
            return -1;
        r->set.has_elasticity = given = 1;
        r->set.elasticity = e ? SQ_ELASTICITY_COROTATIONAL : SQ_ELASTICITY_LINEAR;
    }
    if ((v = cJSON_GetObjectItemCaseSensitive(o, "pressure"))) {
        if (get_enum(v, "set.pressure", pressures, &e, err))
            return -1;
        r->set.has_pressure = given = 1;
        r->set.nodal_pressure = e;
    }
    if ((v = cJSON_GetObjectItemCaseSensitive(o, "integrator"))) {
        if (get_enum(v, "set.integrator", integrators, &e, err))
            return -1;
        r->set.has_integrator = given = 1;
        r->set.integrator = e ? SQ_INTEGRATOR_IMPLICIT : SQ_INTEGRATOR_EXPLICIT;
    }
    if ((m = cJSON_GetObjectItemCaseSensitive(o, "implicit")) && decode_set_implicit(m, r, &given, err))
        return -1;
    if ((m = cJSON_GetObjectItemCaseSensitive(o, "damping"))) {
        if (expect_object(m, "set.damping", err) || check_fields(m, "set.damping", fd, err))
            return -1;
        if ((v = cJSON_GetObjectItemCaseSensitive(m, "mass"))) {
            if (get_number(v, "set.damping.mass", 0, 1000, 0, &r->set.mass, err))
                return -1;
            r->set.has_mass = given = 1;
        }
        if ((v = cJSON_GetObjectItemCaseSensitive(m, "stiffness"))) {
            if (get_number(v, "set.damping.stiffness", 0, 10, 0, &r->set.stiffness, err))
                return -1;
            r->set.has_stiffness = given = 1;
        }
    }
    if ((m = cJSON_GetObjectItemCaseSensitive(o, "lod")) && decode_set_lod(m, r, &given, err))
        return -1;
    if (!given)
        return fail(err, SQ_CODE_BAD_FIELD,
                    "set: nothing to change; give material, operator, elasticity, pressure, damping, lod, "
                    "integrator or implicit");
    return 0;
}

static int decode_subscribe(const cJSON *o, sq_request *r, sq_net_error *err)
{
    static const char *const f[] = {"type", "ref", "stats", "stats_hz", "frames", NULL};
    if (check_fields(o, "subscribe", f, err))
        return -1;
    r->subscribe.stats = r->subscribe.frames = -1;
    const cJSON *v;
    if ((v = cJSON_GetObjectItemCaseSensitive(o, "stats")) &&
        get_bool(v, "subscribe.stats", &r->subscribe.stats, err))
        return -1;
    if ((v = cJSON_GetObjectItemCaseSensitive(o, "frames")) &&
        get_bool(v, "subscribe.frames", &r->subscribe.frames, err))
        return -1;
    if ((v = cJSON_GetObjectItemCaseSensitive(o, "stats_hz"))) {
        if (get_number(v, "subscribe.stats_hz", 0.5, 30, 0, &r->subscribe.stats_hz, err))
            return -1;
        r->subscribe.has_hz = 1;
    }
    return 0;
}

/* requests with only type and ref, or a single optional/required field */
static int decode_simple(const cJSON *o, sq_request *r, sq_net_error *err)
{
    const char *name = sq_req_name(r->type);
    static const char *const f0[] = {"type", "ref", NULL};
    static const char *const fb[] = {"type", "ref", "body", NULL};
    static const char *const fs[] = {"type", "ref", "frames", NULL};
    static const char *const ft[] = {"type", "ref", "t", NULL};
    const cJSON *v;
    switch (r->type) {
    case SQ_REQ_RESET:
        return check_fields(o, name, fb, err) || decode_body(o, "reset.body", &r->reset.body, err);
    case SQ_REQ_NODES:
        if (check_fields(o, name, fb, err) || decode_body(o, "nodes.body", &r->nodes.body, err))
            return -1;
        if (r->nodes.body < 0)
            r->nodes.body = 0;
        return 0;
    case SQ_REQ_STEP:
        if (check_fields(o, name, fs, err))
            return -1;
        if (!(v = cJSON_GetObjectItemCaseSensitive(o, "frames")))
            return fail(err, SQ_CODE_BAD_FIELD, "step.frames: missing; give 1..%d", SQ_NET_MAX_STEP);
        return get_int(v, "step.frames", 1, SQ_NET_MAX_STEP, &r->step.frames, err);
    case SQ_REQ_PING:
        if (check_fields(o, name, ft, err))
            return -1;
        if ((v = cJSON_GetObjectItemCaseSensitive(o, "t"))) {
            if (get_number(v, "ping.t", -1e300, 1e300, 0, &r->ping.t, err))
                return -1;
            r->ping.has_t = 1;
        }
        return 0;
    default:
        return check_fields(o, name, f0, err);
    }
}

int sq_request_decode(const char *text, size_t len, size_t max_len, sq_request *req,
                      sq_net_error *err)
{
    memset(req, 0, sizeof *req);
    err->code = NULL;
    err->message[0] = 0;
    if (len > max_len) {
        sq_recover_ref(text, len, req);
        return fail(err, SQ_CODE_TOO_LARGE, "message of %zu bytes exceeds the limit of %zu bytes; "
                    "send smaller messages", len, max_len);
    }
    if (!text)
        return fail(err, SQ_CODE_BAD_JSON, "empty message; send a JSON object with a \"type\"");
    size_t bad = sq_utf8_check((const unsigned char *)text, len);
    if (bad < len) {
        sq_recover_ref(text, len, req);
        return fail(err, SQ_CODE_BAD_JSON, "text is not valid UTF-8 at byte %zu; send UTF-8 JSON", bad);
    }

    const char *end = NULL;
    cJSON *root = cJSON_ParseWithLengthOpts(text, len, &end, 0);
    if (!root) {
        sq_recover_ref(text, len, req);
        size_t at = (end && end >= text && end <= text + len) ? (size_t)(end - text) : 0;
        return fail(err, SQ_CODE_BAD_JSON, "invalid JSON at byte %zu; send one JSON object", at);
    }
    /* only whitespace (or a NUL terminator) may follow the object */
    for (const char *p = end; p && p < text + len; p++) {
        if (*p == 0 && p == text + len - 1)
            break;
        if (*p != ' ' && *p != '\t' && *p != '\n' && *p != '\r') {
            cJSON_Delete(root);
            sq_recover_ref(text, len, req);
            return fail(err, SQ_CODE_BAD_JSON, "trailing bytes after the JSON value at byte %zu; "
                        "send exactly one JSON object", (size_t)(p - text));
        }
    }
    int rc = -1;
    if (!cJSON_IsObject(root)) {
        req->ref_kind = SQ_REF_NULL;
        fail(err, SQ_CODE_BAD_JSON, "expected a JSON object with a \"type\", got %s", json_kind(root));
        goto out;
    }

    /* ref first, so that errors can echo it */
    const cJSON *ref = cJSON_GetObjectItemCaseSensitive(root, "ref");
    if (ref) {
        if (cJSON_IsString(ref) && ref->valuestring && strlen(ref->valuestring) < SQ_NET_NAME_MAX) {
            req->ref_kind = SQ_REF_STRING;
            snprintf(req->ref_str, sizeof req->ref_str, "%s", ref->valuestring);
        } else if (cJSON_IsNumber(ref) && isfinite(ref->valuedouble)) {
            req->ref_kind = SQ_REF_NUMBER;
            req->ref_num = ref->valuedouble;
        } else {
            req->ref_kind = SQ_REF_NULL; /* given but unusable: the error says "ref": null */
            fail(err, SQ_CODE_BAD_FIELD, "ref: expected a string of at most %d bytes or a finite "
                 "number", SQ_NET_NAME_MAX - 1);
            goto out;
        }
    }

    const cJSON *type = cJSON_GetObjectItemCaseSensitive(root, "type");
    if (!type) {
        fail(err, SQ_CODE_BAD_TYPE, "\"type\" missing; every message needs a \"type\" (see "
             "docs/protocol.md)");
        goto out;
    }
    if (!cJSON_IsString(type) || !type->valuestring) {
        fail(err, SQ_CODE_BAD_TYPE, "\"type\" must be a string, got %s", json_kind(type));
        goto out;
    }
    for (int t = SQ_REQ_NONE + 1; t < SQ_REQ_COUNT; t++)
        if (!strcmp(type->valuestring, req_names[t]))
            req->type = (sq_req_type)t;
    if (req->type == SQ_REQ_NONE) {
        fail(err, SQ_CODE_BAD_TYPE, "unknown type \"%.40s\"; known: hello, list_scenes, open, join, "
             "leave, tool, set, pause, resume, reset, step, stats, subscribe, nodes, ping, "
             "take_control",
             type->valuestring);
        goto out;
    }

    switch (req->type) {
    case SQ_REQ_HELLO: rc = decode_hello(root, req, err); break;
    case SQ_REQ_OPEN: rc = decode_open(root, req, err); break;
    case SQ_REQ_JOIN: rc = decode_join(root, req, err); break;
    case SQ_REQ_TOOL: rc = decode_tool(root, req, err); break;
    case SQ_REQ_SET: rc = decode_set(root, req, err); break;
    case SQ_REQ_SUBSCRIBE: rc = decode_subscribe(root, req, err); break;
    case SQ_REQ_TAKE_CONTROL: rc = decode_take_control(root, req, err); break;
    default: rc = decode_simple(root, req, err); break;
    }
    rc = rc ? -1 : 0;
out:
    cJSON_Delete(root);
    return rc;
}

/* requests that change the simulation: controller only */
static int needs_control(sq_req_type t)
{
    return t == SQ_REQ_TOOL || t == SQ_REQ_SET || t == SQ_REQ_PAUSE || t == SQ_REQ_RESUME ||
           t == SQ_REQ_RESET || t == SQ_REQ_STEP;
}

/* requests that act on the client's session */
static int needs_session(sq_req_type t)
{
    return needs_control(t) || t == SQ_REQ_STATS || t == SQ_REQ_NODES || t == SQ_REQ_LEAVE ||
           t == SQ_REQ_TAKE_CONTROL;
}

int sq_request_check(const sq_request *r, const sq_client_ctx *c, sq_net_error *err)
{
    const char *name = sq_req_name(r->type);
    if (r->type == SQ_REQ_NONE || r->type >= SQ_REQ_COUNT)
        return fail(err, SQ_CODE_BAD_TYPE, "no request type");
    if (!c->greeted && r->type != SQ_REQ_HELLO)
        return fail(err, SQ_CODE_HELLO_REQUIRED, "%s: send {\"type\":\"hello\"} first", name);
    if (needs_session(r->type) && !c->in_session)
        return fail(err, SQ_CODE_NO_SESSION, "%s: not in a session; send open or join first", name);
    if (needs_control(r->type) && !c->is_controller)
        return fail(err, SQ_CODE_NOT_CONTROLLER, "%s: this client only views the session; control "
                    "needs role \"control\" and a session without another controller", name);
    if (r->type == SQ_REQ_STEP && !c->lockstep)
        return fail(err, SQ_CODE_NOT_LOCKSTEP, "step: the server runs in real time; start it with "
                    "--lockstep to step frames");
    if ((r->type == SQ_REQ_PAUSE || r->type == SQ_REQ_RESUME) && c->lockstep)
        return fail(err, SQ_CODE_LOCKSTEP, "%s: the server runs in lockstep mode (frames advance only "
                    "on step)", name);

    int body = -1;
    if (r->type == SQ_REQ_SET) body = r->set.body;
    if (r->type == SQ_REQ_RESET) body = r->reset.body;
    if (r->type == SQ_REQ_NODES) body = r->nodes.body;
    if (body >= 0 && body >= c->nbodies)
        return fail(err, SQ_CODE_UNKNOWN_BODY, "%s.body: %d is not a body of this session (ids 0..%d)",
                    name, body, c->nbodies - 1);

    if (r->type == SQ_REQ_TOOL) {
        int known = 0;
        for (int i = 0; i < c->ntools; i++)
            if (c->tool_ids && c->tool_ids[i] == r->tool.id)
                known = 1;
        if (!known) {
            if (!r->tool.has_shape || !r->tool.has_pos)
                return fail(err, SQ_CODE_UNKNOWN_TOOL, "tool.id: %d is not a tool of this session; a "
                            "new tool needs shape and pos", r->tool.id);
            if (c->ntools >= c->max_tools)
                return fail(err, SQ_CODE_TOO_MANY_TOOLS, "tool.id: %d would be tool %d; a session has "
                            "at most %d tools: reuse an id", r->tool.id, c->ntools + 1,
                            c->max_tools);
        }
    }
    return 0;
}
