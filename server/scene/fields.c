/* fields.c - the field readers of scene files: typed values at JSON paths, worded errors.
 *
 * "scene.json: bodies[0].material.nu: expected a number, got a string; see docs/scenes.md":
 * every reader names the file (label), the JSON path and what to give instead.
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
    if (cJSON_IsNumber(it))
        return "a number";
    if (cJSON_IsString(it))
        return "a string";
    if (cJSON_IsBool(it))
        return "a boolean";
    if (cJSON_IsNull(it))
        return "null";
    if (cJSON_IsArray(it))
        return "an array";
    if (cJSON_IsObject(it))
        return "an object";
    return "an invalid value";
}

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
    char p[256];
    for (const cJSON *it = obj->child; it; it = it->next) {
        int ok = 0;
        for (int k = 0; known[k]; k++)
            if (!strcmp(it->string, known[k]))
                ok = 1;
        scene_join(p, sizeof p, path, it->string);
        if (!ok) {
            char list[256] = "";
            for (int k = 0; known[k]; k++) {
                size_t l = strlen(list);
                snprintf(list + l, sizeof list - l, "%s%s", k ? ", " : "", known[k]);
            }
            return scene_fail(c, p, "unknown key; known keys here: %s (check the spelling)", list);
        }
        for (const cJSON *o = obj->child; o != it; o = o->next)
            if (!strcmp(o->string, it->string))
                return scene_fail(c, p, "key given twice; keep one");
    }
    return 0;
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
    if (!cJSON_IsNumber(it))
        return scene_fail(c, p, "expected a number, got %s; see docs/scenes.md", scene_type_name(it));
    if (!isfinite(it->valuedouble))
        return scene_fail(c, p, "not a finite number; use a value within the double range");
    *out = it->valuedouble;
    return 0;
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
    double v = 0;
    int f;
    if (scene_get_number(c, obj, path, key, &v, &f))
        return -1;
    if (found)
        *found = f;
    if (!f)
        return 0;
    char p[256];
    scene_join(p, sizeof p, path, key);
    if (v != floor(v))
        return scene_fail(c, p, "%g is not an integer; use a whole number in [%ld, %ld]", v, lo, hi);
    if (v < (double)lo || v > (double)hi)
        return scene_fail(c, p, "%g is out of range; use an integer in [%ld, %ld]", v, lo, hi);
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
    if (!cJSON_IsString(it) || !it->valuestring)
        return scene_fail(c, p, "expected a string, got %s; see docs/scenes.md", scene_type_name(it));
    if (strlen(it->valuestring) >= cap)
        return scene_fail(c, p, "too long (%zu bytes); use at most %zu", strlen(it->valuestring), cap - 1);
    snprintf(out, cap, "%s", it->valuestring);
    return 0;
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
    if (!cJSON_IsBool(it))
        return scene_fail(c, p, "expected true or false, got %s; see docs/scenes.md", scene_type_name(it));
    *out = cJSON_IsTrue(it) ? 1 : 0;
    return 0;
}

/* an array of three finite numbers, given as the item itself */
int scene_vec3_of(pctx *c, const cJSON *it, const char *p, double out[3])
{
    if (!cJSON_IsArray(it) || cJSON_GetArraySize(it) != 3)
        return scene_fail(c, p, "expected an array of 3 numbers [x, y, z], got %s%s; see docs/scenes.md", scene_type_name(it),
                    cJSON_IsArray(it) ? " of another length" : "");
    int i = 0;
    for (const cJSON *e = it->child; e; e = e->next, i++) {
        if (!cJSON_IsNumber(e))
            return scene_fail(c, p, "element %d: expected a number, got %s; see docs/scenes.md", i, scene_type_name(e));
        if (!isfinite(e->valuedouble))
            return scene_fail(c, p, "element %d: not a finite number; use a finite value", i);
        out[i] = e->valuedouble;
    }
    return 0;
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
    if (want_array ? !cJSON_IsArray(it) : !cJSON_IsObject(it)) {
        *bad = 1;
        scene_fail(c, p, "expected %s, got %s; see docs/scenes.md", want_array ? "an array" : "an object", scene_type_name(it));
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
