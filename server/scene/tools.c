/* tools.c - scripted tools (shape, keyframes) and probes of a scene file; a tool's pose.
 *
 * Parse and validate the entries of "tools" and "probes" (docs/scenes.md), and
 * sq_tool_script_pose: a scripted tool's pose at a simulated time, from its keyframes.
 */
#include "scene/scene_internal.h"

#include <limits.h>
#include <stdio.h>
#include <string.h>

/* ---- keyframes --------------------------------------------------------------------- */

int scene_parse_keyframes(pctx *c, const cJSON *obj, const char *path, int required, sq_keyframe *keys, int *nkeys,
                          const char *pos_what)
{
    /* keyframes: t strictly increasing, pos, active (default true) */
    char p[256];
    int found;
    int bad;
    const cJSON *kf = scene_get_typed(c, obj, path, "keyframes", 1, required, &bad);
    *nkeys = 0;
    if (bad)
        return -1;
    if (!kf)
        return 0;
    char kp[256];
    scene_join(kp, sizeof kp, path, "keyframes");
    int nk = cJSON_GetArraySize(kf);
    if (nk < 1 || nk > SQ_MAX_KEYFRAMES)
        return scene_fail(c, kp, "%d keyframes; give 1 to %d", nk, SQ_MAX_KEYFRAMES);
    int i = 0;
    for (const cJSON *e = kf->child; e; e = e->next, i++) {
        static const char *const kkeys[] = {"t", "pos", "active", NULL};
        scene_join_index(p, sizeof p, kp, i);
        if (!cJSON_IsObject(e))
            return scene_fail(c, p, "expected {\"t\": s, \"pos\": [x, y, z], \"active\": true}, got %s; see docs/scenes.md", scene_type_name(e));
        if (scene_check_keys(c, e, p, kkeys))
            return -1;
        sq_keyframe *k = &keys[i];
        k->active = 1;
        if (scene_get_required_number(c, e, p, "t", &k->t, "the time in s") || scene_get_bool(c, e, p, "active", &k->active))
            return -1;
        if (scene_get_vec3(c, e, p, "pos", k->pos, &found))
            return -1;
        if (!found) {
            char q[256];
            scene_join(q, sizeof q, p, "pos");
            return scene_fail(c, q, "missing; give %s", pos_what);
        }
        if (k->t < 0 || (i > 0 && !(k->t > keys[i - 1].t))) {
            char q[256];
            scene_join(q, sizeof q, p, "t");
            return scene_fail(c, q, "%g %s; keyframe times must be >= 0 and strictly increasing", k->t,
                        k->t < 0 ? "is negative" : "is not after the previous keyframe");
        }
    }
    *nkeys = nk;
    return 0;
}

/* ---- tools ------------------------------------------------------------------------- */

int scene_parse_tool(pctx *c, sq_scene *s, const cJSON *obj, int ti, const char *path)
{
    static const char *const keys[] = {"id", "name", "shape", "radius", "size", "keyframes", NULL};
    if (!cJSON_IsObject(obj))
        return scene_fail(c, path, "expected an object, got %s; see docs/scenes.md", scene_type_name(obj));
    if (scene_check_keys(c, obj, path, keys))
        return -1;
    sq_tool_script *ts = &s->tools[ti];
    memset(ts, 0, sizeof *ts);
    char p[256];
    long id = ti;
    if (scene_get_int(c, obj, path, "id", 0, INT_MAX, &id, NULL))
        return -1;
    ts->tool.id = (int)id;
    scene_join(p, sizeof p, path, "id");
    for (int j = 0; j < ti; j++)
        if (s->tools[j].tool.id == ts->tool.id)
            return scene_fail(c, p, "%ld is already the id of tools[%d]; give each tool its own id", id, j);
    snprintf(ts->name, sizeof ts->name, "tool%d", ti);
    if (scene_get_string(c, obj, path, "name", ts->name, sizeof ts->name, NULL))
        return -1;
    scene_join(p, sizeof p, path, "name");
    if (scene_check_name(c, p, ts->name))
        return -1;

    char shape[16];
    int found;
    const cJSON *sh = scene_get(obj, "shape");
    scene_join(p, sizeof p, path, "shape");
    if (sh && cJSON_IsString(sh) && strlen(sh->valuestring) >= sizeof shape)
        return scene_fail(c, p, "\"%s\" is not a shape; use \"sphere\", \"box\" or \"grab\"", sh->valuestring);
    if (scene_get_string(c, obj, path, "shape", shape, sizeof shape, &found))
        return -1;
    if (!found)
        return scene_fail(c, p, "missing; give \"sphere\", \"box\" or \"grab\"");
    if (!strcmp(shape, "sphere"))
        ts->tool.shape = SQ_TOOL_SPHERE;
    else if (!strcmp(shape, "box"))
        ts->tool.shape = SQ_TOOL_BOX;
    else if (!strcmp(shape, "grab"))
        ts->tool.shape = SQ_TOOL_GRAB;
    else
        return scene_fail(c, p, "\"%s\" is not a shape; use \"sphere\", \"box\" or \"grab\"", shape);

    int hr, hs;
    double size[3] = {0, 0, 0};
    if (scene_get_number(c, obj, path, "radius", &ts->tool.radius, &hr) || scene_get_vec3(c, obj, path, "size", size, &hs))
        return -1;
    if (ts->tool.shape == SQ_TOOL_BOX) {
        scene_join(p, sizeof p, path, hr ? "radius" : "size");
        if (hr)
            return scene_fail(c, p, "a box tool has no radius; give \"size\": [sx, sy, sz] (full extents, m)");
        if (!hs)
            return scene_fail(c, p, "missing; a box tool needs \"size\": [sx, sy, sz] (full extents, m)");
        for (int i = 0; i < 3; i++) {
            if (!(size[i] > 0))
                return scene_fail(c, p, "%g on axis %c is out of range; use extents > 0 (m)", size[i], "xyz"[i]);
            ts->tool.half[i] = size[i] / 2;
        }
    } else {
        scene_join(p, sizeof p, path, hs ? "size" : "radius");
        if (hs)
            return scene_fail(c, p, "only box tools have a size; give \"radius\" (m) for a %s", shape);
        if (!hr)
            return scene_fail(c, p, "missing; a %s tool needs \"radius\" (m)%s", shape,
                        ts->tool.shape == SQ_TOOL_GRAB ? ", the capture radius around its point" : "");
        if (scene_range_pos(c, path, "radius", ts->tool.radius, "m"))
            return -1;
    }

    if (scene_parse_keyframes(c, obj, path, 1, ts->keys, &ts->nkeys, "the tool position [x, y, z] (m)"))
        return -1;
    sq_tool_script_pose(ts, 0, &ts->tool);
    return 0;
}

/* ---- probes ------------------------------------------------------------------------ */

int scene_parse_probe(pctx *c, sq_scene *s, const cJSON *obj, int pi, const char *path)
{
    static const char *const keys[] = {"name", "body", "point", NULL};
    if (!cJSON_IsObject(obj))
        return scene_fail(c, path, "expected an object {\"name\", \"body\", \"point\"}, got %s; see docs/scenes.md", scene_type_name(obj));
    if (scene_check_keys(c, obj, path, keys))
        return -1;
    sq_probe *pr = &s->probes[pi];
    char p[256];
    snprintf(pr->name, sizeof pr->name, "probe%d", pi);
    if (scene_get_string(c, obj, path, "name", pr->name, sizeof pr->name, NULL))
        return -1;
    scene_join(p, sizeof p, path, "name");
    if (scene_check_name(c, p, pr->name))
        return -1;
    for (int j = 0; j < pi; j++)
        if (!strcmp(s->probes[j].name, pr->name))
            return scene_fail(c, p, "\"%s\" is already the name of probes[%d]; give each probe its own name", pr->name, j);
    char body[64];
    int found;
    if (scene_get_string(c, obj, path, "body", body, sizeof body, &found))
        return -1;
    scene_join(p, sizeof p, path, "body");
    if (!found) {
        if (s->nbodies != 1)
            return scene_fail(c, p, "missing; the scene has %d bodies, name the one to probe", s->nbodies);
        pr->body = 0;
    } else {
        pr->body = -1;
        for (int b = 0; b < s->nbodies; b++)
            if (!strcmp(s->body_names[b], body))
                pr->body = b;
        if (pr->body < 0)
            return scene_fail(c, p, "\"%s\" is not a body of this scene; use one of the bodies[].name values", body);
    }
    if (scene_get_vec3(c, obj, path, "point", pr->point, &found))
        return -1;
    scene_join(p, sizeof p, path, "point");
    if (!found)
        return scene_fail(c, p, "missing; give the rest-space point [x, y, z] (m) to record");
    /* the point must lie in the body's finest loaded mesh (small tolerance for surface points) */
    const sq_body_def *def = &s->bodies[pr->body];
    const sq_mesh *m = def->levels[def->nlevels - 1];
    double bary[4];
    int t = sq_mesh_locate(m, pr->point, bary);
    int inside = t >= 0;
    for (int i = 0; i < 4 && inside; i++)
        if (bary[i] < -1e-6)
            inside = 0;
    if (!inside)
        return scene_fail(c, p, "[%g, %g, %g] is outside body \"%s\" (bounding box [%g, %g, %g] - [%g, %g, %g]); "
                          "use a point inside the rest mesh",
                    pr->point[0], pr->point[1], pr->point[2], s->body_names[pr->body], m->bbox_min[0],
                    m->bbox_min[1], m->bbox_min[2], m->bbox_max[0], m->bbox_max[1], m->bbox_max[2]);
    return 0;
}

/* an active scripted tool's activation point: the pose of the first keyframe of the run of
 * active keyframes that ends at keyframe cur */
static void script_origin(const sq_tool_script *s, int cur, sq_tool *out)
{
    out->has_origin = 0;
    if (!out->active || cur < 0)
        return;
    int j = cur;
    while (j > 0 && s->keys[j - 1].active)
        j--;
    memcpy(out->origin, s->keys[j].pos, sizeof out->origin);
    out->has_origin = 1;
}

void sq_tool_script_pose(const sq_tool_script *s, double t, sq_tool *out)
{
    *out = s->tool;
    out->has_origin = 0;
    if (s->nkeys <= 0) {
        out->active = 0;
        return;
    }
    const sq_keyframe *k = s->keys;
    int n = s->nkeys;
    if (t <= k[0].t) {
        memcpy(out->pos, k[0].pos, sizeof out->pos);
        out->active = t >= k[0].t ? k[0].active : 0;
        script_origin(s, 0, out);
        return;
    }
    if (t >= k[n - 1].t) {
        memcpy(out->pos, k[n - 1].pos, sizeof out->pos);
        out->active = k[n - 1].active;
        script_origin(s, n - 1, out);
        return;
    }
    /* k[i].t <= t < k[i+1].t */
    int lo = 0, hi = n - 1;
    while (hi - lo > 1) {
        int mid = (lo + hi) / 2;
        if (k[mid].t <= t)
            lo = mid;
        else
            hi = mid;
    }
    double a = (t - k[lo].t) / (k[hi].t - k[lo].t);
    for (int i = 0; i < 3; i++)
        out->pos[i] = k[lo].pos[i] + a * (k[hi].pos[i] - k[lo].pos[i]);
    out->active = k[lo].active;
    script_origin(s, lo, out);
}
