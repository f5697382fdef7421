/* fields.c - the field readers of scene files: typed values at JSON paths, worded errors.
 *
 * "scene.json: bodies[0].material.nu: expected a number, got a string; see docs/scenes.md":
 * every reader names the file (label), the JSON path and what to give instead. The checks
 * are those of util/json.c (shared with the protocol's requests); the wording is here.
 */
#include "scene/scene_internal.h"

#include <math.h>
#include <stdarg.h>
#include <stdio.h>
#include <string.h>

int scene_fail(pctx *c, const char *path, const char *fmt, ...) __attribute__((format(printf, 3, 4)));
int scene_fail(pctx *c, const char *path, const char *fmt, ...)
{
    char msg[400];
    va_list ap;
    va_start(ap, fmt);
    vsnprintf(msg, sizeof msg, fmt, ap);
    va_end(ap);
    if (path && path[0])
        return sq_err_set(c->err, "%s: %s: %s", c->label, path, msg);
    return sq_err_set(c->err, "%s: %s", c->label, msg);
}

const char *scene_type_name(const cJSON *it)
{
    const char *k = sq_json_kind(it);
    return k ? k : "an invalid value";
}

/* the scene files' wording of a field the readers of util/json.c refused: "<label>: <path>:
 * <what>; <what to do>" */
static int report(sq_json_reader *r, const sq_json_fault *f)
{
    pctx *c = r->ctx;
    char p[256];
    switch (f->kind) {
    case SQ_JSON_WRONG_TYPE:
        if (f->index >= 0)
            return scene_fail(c, f->array_path, "element %d: expected a number, got %s; see docs/scenes.md",
                              f->index, scene_type_name(f->item));
        switch (f->want) {
        case SQ_JSON_NUMBER:
            return scene_fail(c, f->path, "expected a number, got %s; see docs/scenes.md", scene_type_name(f->item));
        case SQ_JSON_STRING:
            return scene_fail(c, f->path, "expected a string, got %s; see docs/scenes.md", scene_type_name(f->item));
        case SQ_JSON_BOOL:
            return scene_fail(c, f->path, "expected true or false, got %s; see docs/scenes.md",
                              scene_type_name(f->item));
        case SQ_JSON_ARRAY:
        case SQ_JSON_OBJECT:
            return scene_fail(c, f->path, "expected %s, got %s; see docs/scenes.md",
                              f->want == SQ_JSON_ARRAY ? "an array" : "an object", scene_type_name(f->item));
        case SQ_JSON_VEC3:
            break;
        }
        return scene_fail(c, f->path, "expected an array of 3 numbers [x, y, z], got %s; see docs/scenes.md",
                          scene_type_name(f->item));
    case SQ_JSON_WRONG_LENGTH:
        return scene_fail(c, f->path, "expected an array of 3 numbers [x, y, z], got %s%s; see docs/scenes.md",
                          scene_type_name(f->item), cJSON_IsArray(f->item) ? " of another length" : "");
    case SQ_JSON_NOT_FINITE:
        if (f->index >= 0)
            return scene_fail(c, f->array_path, "element %d: not a finite number; use a finite value", f->index);
        return scene_fail(c, f->path, "not a finite number; use a value within the double range");
    case SQ_JSON_OUT_OF_RANGE:
        return scene_fail(c, f->path, "%g is out of range; use a value in [%g, %g]", f->x, f->lo, f->hi);
    case SQ_JSON_BAD_INT:
        if (!f->whole)
            return scene_fail(c, f->path, "%g is not an integer; use a whole number in [%ld, %ld]", f->x,
                              (long)f->lo, (long)f->hi);
        return scene_fail(c, f->path, "%g is out of range; use an integer in [%ld, %ld]", f->x, (long)f->lo,
                          (long)f->hi);
    case SQ_JSON_TOO_LONG:
        return scene_fail(c, f->path, "too long (%zu bytes); use at most %zu", f->len, f->cap - 1);
    case SQ_JSON_CONTROL_CHAR:
        return scene_fail(c, f->path, "control character at byte %zu; use plain text", f->at);
    case SQ_JSON_UNKNOWN_KEY: {
        scene_join(p, sizeof p, f->path, f->key);
        char list[256] = "";
        for (int k = 0; f->known[k]; k++) {
            size_t l = strlen(list);
            snprintf(list + l, sizeof list - l, "%s%s", k ? ", " : "", f->known[k]);
        }
        return scene_fail(c, p, "unknown key; known keys here: %s (check the spelling)", list);
    }
    case SQ_JSON_DUPLICATE_KEY:
        scene_join(p, sizeof p, f->path, f->key);
        return scene_fail(c, p, "key given twice; keep one");
    }
    return scene_fail(c, f->path, "refused");
}

/* the readers of scene fields: a key given twice is refused at its second appearance */
#define READER(c) sq_json_reader rd = {report, c, 0}

/* "a.b" + "c" -> "a.b.c"; "" + "c" -> "c" (truncated paths stay NUL-terminated) */
void scene_join(char *out, size_t n, const char *path, const char *key)
{
    int r = path[0] ? snprintf(out, n, "%s.%s", path, key) : snprintf(out, n, "%s", key);
    if (r < 0)
        out[0] = 0;
}

void scene_join_index(char *out, size_t n, const char *path, int i)
{
    if (snprintf(out, n, "%s[%d]", path, i) < 0)
        out[0] = 0;
}

/* reject keys not in `known` (NULL-terminated) and duplicated keys */
int scene_check_keys(pctx *c, const cJSON *obj, const char *path, const char *const *known)
{
    READER(c);
    return sq_json_keys(&rd, obj, path, known);
}

const cJSON *scene_get(const cJSON *obj, const char *key)
{
    return cJSON_GetObjectItemCaseSensitive(obj, key);
}

/* obj.key (NULL when absent) with its path path.key written into p; *found says if it is there */
static const cJSON *get_at(const cJSON *obj, const char *path, const char *key, char *p, size_t cap,
                           int *found)
{
    scene_join(p, cap, path, key);
    const cJSON *it = scene_get(obj, key);
    if (found)
        *found = it != NULL;
    return it;
}

/* a finite number; *found = 0 when absent (then out is untouched) */
int scene_get_number(pctx *c, const cJSON *obj, const char *path, const char *key, double *out,
                      int *found)
{
    char p[256];
    const cJSON *it = get_at(obj, path, key, p, sizeof p, found);
    if (!it)
        return 0;
    READER(c);
    return sq_json_number(&rd, it, p, -INFINITY, INFINITY, 0, out);
}

int scene_get_required_number(pctx *c, const cJSON *obj, const char *path, const char *key,
                               double *out, const char *what)
{
    int found;
    if (scene_get_number(c, obj, path, key, out, &found))
        return -1;
    if (!found) {
        char p[256];
        scene_join(p, sizeof p, path, key);
        return scene_fail(c, p, "missing; give %s", what);
    }
    return 0;
}

/* an integer in [lo, hi] */
int scene_get_int(pctx *c, const cJSON *obj, const char *path, const char *key, long lo, long hi,
                   long *out, int *found)
{
    char p[256];
    const cJSON *it = get_at(obj, path, key, p, sizeof p, found);
    if (!it)
        return 0;
    READER(c);
    double v = 0;
    if (sq_json_int(&rd, it, p, (double)lo, (double)hi, &v))
        return -1;
    *out = (long)v;
    return 0;
}

/* a string of at most cap-1 bytes */
int scene_get_string(pctx *c, const cJSON *obj, const char *path, const char *key, char *out,
                      size_t cap, int *found)
{
    char p[256];
    const cJSON *it = get_at(obj, path, key, p, sizeof p, found);
    if (!it)
        return 0;
    READER(c);
    return sq_json_string(&rd, it, p, out, cap, 0);
}

/* a name usable in CSV files and file names: letters, digits, '_', '-', '.' */
int scene_check_name(pctx *c, const char *path, const char *name)
{
    if (!name[0])
        return scene_fail(c, path, "empty name; give a short name such as \"cube\"");
    for (const char *s = name; *s; s++) {
        char ch = *s;
        if (!((ch >= 'a' && ch <= 'z') || (ch >= 'A' && ch <= 'Z') || (ch >= '0' && ch <= '9') ||
              ch == '_' || ch == '-' || ch == '.'))
            return scene_fail(c, path, "\"%s\" has the character '%c'; use only letters, digits, '_', '-' and '.'",
                        name, ch);
    }
    return 0;
}

int scene_get_bool(pctx *c, const cJSON *obj, const char *path, const char *key, int *out)
{
    char p[256];
    const cJSON *it = get_at(obj, path, key, p, sizeof p, NULL);
    if (!it)
        return 0;
    READER(c);
    return sq_json_bool(&rd, it, p, out);
}

/* an array of three finite numbers, given as the item itself */
int scene_vec3_of(pctx *c, const cJSON *it, const char *p, double out[3])
{
    READER(c);
    return sq_json_vec3(&rd, it, p, -INFINITY, INFINITY, 0, out);
}

int scene_get_vec3(pctx *c, const cJSON *obj, const char *path, const char *key, double out[3],
                    int *found)
{
    char p[256];
    const cJSON *it = get_at(obj, path, key, p, sizeof p, found);
    if (!it)
        return 0;
    return scene_vec3_of(c, it, p, out);
}

/* an object or array expected at key (may be absent unless required) */
const cJSON *scene_get_typed(pctx *c, const cJSON *obj, const char *path, const char *key,
                              int want_array, int required, int *bad)
{
    char p[256];
    const cJSON *it = get_at(obj, path, key, p, sizeof p, NULL);
    *bad = 0;
    if (!it) {
        if (required) {
            *bad = 1;
            scene_fail(c, p, "missing; give %s", want_array ? "an array" : "an object");
        }
        return NULL;
    }
    READER(c);
    if (sq_json_expect(&rd, it, p, want_array ? SQ_JSON_ARRAY : SQ_JSON_OBJECT)) {
        *bad = 1;
        return NULL;
    }
    return it;
}

int scene_range_pos(pctx *c, const char *path, const char *key, double v, const char *unit)
{
    if (v > 0)
        return 0;
    char p[256];
    scene_join(p, sizeof p, path, key);
    return scene_fail(c, p, "%g is out of range; use %s > 0 (%s)", v, key, unit);
}

int scene_range_nonneg(pctx *c, const char *path, const char *key, double v, const char *unit)
{
    if (v >= 0)
        return 0;
    char p[256];
    scene_join(p, sizeof p, path, key);
    return scene_fail(c, p, "%g is out of range; use %s >= 0 (%s)", v, key, unit);
}
