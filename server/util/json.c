/* json.c - the JSON field readers of scene files and protocol requests (util.h).
 *
 * The checks only: what a refused value is wrong with goes to the caller's report(), which
 * words it (server/scene/fields.c for scene files, server/net/request.c for requests).
 */
#include "util/util.h"

#include <cJSON.h>
#include <math.h>
#include <stdio.h>
#include <string.h>

static int fault(sq_json_reader *r, sq_json_fault *f)
{
    return r->report(r, f);
}

static sq_json_fault at(sq_json_fault_kind kind, const cJSON *v, const char *path)
{
    sq_json_fault f;
    memset(&f, 0, sizeof f);
    f.kind = kind;
    f.item = v;
    f.path = path;
    f.index = -1;
    return f;
}

const char *sq_json_kind(const cJSON *v)
{
    if (cJSON_IsNumber(v)) return "a number";
    if (cJSON_IsString(v)) return "a string";
    if (cJSON_IsBool(v)) return "a boolean";
    if (cJSON_IsNull(v)) return "null";
    if (cJSON_IsArray(v)) return "an array";
    if (cJSON_IsObject(v)) return "an object";
    return NULL;
}

/* type and finiteness of a number; element index >= 0 for an item of an array of 3 */
static int number_of(sq_json_reader *r, const cJSON *v, sq_json_fault *f)
{
    if (!cJSON_IsNumber(v)) {
        f->kind = SQ_JSON_WRONG_TYPE;
        f->want = SQ_JSON_NUMBER;
        return fault(r, f);
    }
    f->x = v->valuedouble;
    if (!isfinite(f->x)) {
        f->kind = SQ_JSON_NOT_FINITE;
        return fault(r, f);
    }
    return 0;
}

static int ranged(sq_json_reader *r, const cJSON *v, sq_json_fault *f, double lo, double hi,
                  int lo_open, double *out)
{
    if (number_of(r, v, f))
        return -1;
    double x = f->x;
    if (x < lo || x > hi || (lo_open && x == lo)) {
        f->kind = SQ_JSON_OUT_OF_RANGE;
        f->lo = lo;
        f->hi = hi;
        f->lo_open = lo_open;
        return fault(r, f);
    }
    *out = x;
    return 0;
}

int sq_json_number(sq_json_reader *r, const cJSON *v, const char *path, double lo, double hi,
                   int lo_open, double *out)
{
    sq_json_fault f = at(SQ_JSON_WRONG_TYPE, v, path);
    return ranged(r, v, &f, lo, hi, lo_open, out);
}

int sq_json_int(sq_json_reader *r, const cJSON *v, const char *path, double lo, double hi,
                double *out)
{
    sq_json_fault f = at(SQ_JSON_WRONG_TYPE, v, path);
    if (number_of(r, v, &f))
        return -1;
    double x = f.x;
    f.whole = x == floor(x);
    f.in_range = x >= lo && x <= hi;
    if (!f.whole || !f.in_range) {
        f.kind = SQ_JSON_BAD_INT;
        f.lo = lo;
        f.hi = hi;
        return fault(r, &f);
    }
    *out = x;
    return 0;
}

int sq_json_bool(sq_json_reader *r, const cJSON *v, const char *path, int *out)
{
    if (!cJSON_IsBool(v)) {
        sq_json_fault f = at(SQ_JSON_WRONG_TYPE, v, path);
        f.want = SQ_JSON_BOOL;
        return fault(r, &f);
    }
    *out = cJSON_IsTrue(v) ? 1 : 0;
    return 0;
}

int sq_json_string(sq_json_reader *r, const cJSON *v, const char *path, char *out, size_t cap,
                   int plain)
{
    sq_json_fault f = at(SQ_JSON_WRONG_TYPE, v, path);
    if (!cJSON_IsString(v) || !v->valuestring) {
        f.want = SQ_JSON_STRING;
        return fault(r, &f);
    }
    size_t n = strlen(v->valuestring);
    if (n >= cap) {
        f.kind = SQ_JSON_TOO_LONG;
        f.len = n;
        f.cap = cap;
        return fault(r, &f);
    }
    for (size_t i = 0; plain && i < n; i++)
        if ((unsigned char)v->valuestring[i] < 0x20) {
            f.kind = SQ_JSON_CONTROL_CHAR;
            f.at = i;
            return fault(r, &f);
        }
    memcpy(out, v->valuestring, n + 1);
    return 0;
}

int sq_json_vec3(sq_json_reader *r, const cJSON *v, const char *path, double lo, double hi,
                 int lo_open, double out[3])
{
    sq_json_fault f = at(SQ_JSON_WRONG_TYPE, v, path);
    if (!cJSON_IsArray(v)) {
        f.want = SQ_JSON_VEC3;
        return fault(r, &f);
    }
    int n = cJSON_GetArraySize(v);
    if (n != 3) {
        f.kind = SQ_JSON_WRONG_LENGTH;
        f.n = n;
        return fault(r, &f);
    }
    int i = 0;
    for (const cJSON *c = v->child; c; c = c->next, i++) {
        char p[64];
        snprintf(p, sizeof p, "%s[%d]", path, i);
        sq_json_fault e = at(SQ_JSON_WRONG_TYPE, c, p);
        e.array_path = path;
        e.index = i;
        if (ranged(r, c, &e, lo, hi, lo_open, &out[i]))
            return -1;
    }
    return 0;
}

int sq_json_expect(sq_json_reader *r, const cJSON *v, const char *path, sq_json_want want)
{
    if (want == SQ_JSON_ARRAY ? cJSON_IsArray(v) : cJSON_IsObject(v))
        return 0;
    sq_json_fault f = at(SQ_JSON_WRONG_TYPE, v, path);
    f.want = want;
    return fault(r, &f);
}

int sq_json_keys(sq_json_reader *r, const cJSON *obj, const char *path, const char *const *known)
{
    for (const cJSON *c = obj->child; c; c = c->next) {
        const char *name = c->string ? c->string : "";
        int ok = 0;
        for (int i = 0; known[i]; i++)
            if (!strcmp(name, known[i]))
                ok = 1;
        sq_json_fault f = at(SQ_JSON_UNKNOWN_KEY, obj, path);
        f.key = name;
        if (!ok) {
            f.known = known;
            return fault(r, &f);
        }
        f.kind = SQ_JSON_DUPLICATE_KEY;
        const cJSON *from = r->dup_at_first ? c->next : obj->child;
        const cJSON *to = r->dup_at_first ? NULL : c;
        for (const cJSON *d = from; d != to; d = d->next)
            if (d->string && !strcmp(d->string, name))
                return fault(r, &f);
    }
    return 0;
}
