/* obstacles.c - the "obstacles" and "contact" keys of a scene file (docs/scenes.md), an
 * obstacle's pose at a time, and the load check that no body starts inside an obstacle or
 * inside another body. */
#include "scene/scene_internal.h"

#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

/* "friction": a number (static = kinetic) or {"static": s, "kinetic": k} */
static int parse_friction(pctx *c, const cJSON *obj, const char *path, double *mu_s, double *mu_k)
{
    char p[256];
    scene_join(p, sizeof p, path, "friction");
    const cJSON *f = scene_get(obj, "friction");
    *mu_s = *mu_k = 0.5;
    if (!f)
        return 0;
    if (cJSON_IsNumber(f)) {
        if (scene_get_number(c, obj, path, "friction", mu_s, NULL))
            return -1;
        *mu_k = *mu_s;
    } else if (cJSON_IsObject(f)) {
        static const char *const keys[] = {"static", "kinetic", NULL};
        int hs, hk;
        if (scene_check_keys(c, f, p, keys) || scene_get_number(c, f, p, "static", mu_s, &hs) ||
            scene_get_number(c, f, p, "kinetic", mu_k, &hk))
            return -1;
        if (hs && !hk)
            *mu_k = *mu_s;
        if (hk && !hs)
            *mu_s = *mu_k;
    } else {
        return scene_fail(c, p, "expected a number or {\"static\": s, \"kinetic\": k}, got %s", scene_type_name(f));
    }
    if (!(*mu_s >= 0 && *mu_s <= 10) || !(*mu_k >= 0 && *mu_k <= 10))
        return scene_fail(c, p, "static %g, kinetic %g out of range; use 0 <= friction <= 10 (0: frictionless)",
                          *mu_s, *mu_k);
    if (*mu_k > *mu_s)
        return scene_fail(c, p, "kinetic %g above static %g; give kinetic <= static", *mu_k, *mu_s);
    return 0;
}

static int need_vec3(pctx *c, const cJSON *obj, const char *path, const char *key, double out[3], const char *what)
{
    int found;
    if (scene_get_vec3(c, obj, path, key, out, &found))
        return -1;
    if (!found) {
        char p[256];
        scene_join(p, sizeof p, path, key);
        return scene_fail(c, p, "missing; give %s", what);
    }
    return 0;
}

/* the boundary of a tetrahedral mesh (any format sq_mesh_load reads), scaled then offset: its
 * triangles face outward, so the solid is the mesh's inside */
static sq_trimesh *tet_boundary(const char *path, double scale, const double offset[3], sq_err *err)
{
    sq_mesh *tm = sq_mesh_load(path, err);
    if (!tm)
        return NULL;
    double *x = sq_malloc(sizeof(double) * 3 * (size_t)tm->nnodes);
    for (int i = 0; i < tm->nnodes; i++)
        for (int c = 0; c < 3; c++)
            x[3 * i + c] = scale * tm->x[3 * i + c] + offset[c];
    sq_trimesh *m = sq_trimesh_from_arrays(tm->nnodes, x, tm->ntris, tm->tris, path, err);
    free(x);
    sq_mesh_free(tm);
    return m;
}

static int parse_mesh_obstacle(pctx *c, sq_scene *s, const cJSON *obj, int oi, const char *path, sq_obstacle *o)
{
    char file[512], p[256], full[1024];
    int found;
    if (scene_get_string(c, obj, path, "file", file, sizeof file, &found))
        return -1;
    scene_join(p, sizeof p, path, "file");
    if (!found || !file[0])
        return scene_fail(c, p, "missing; a mesh obstacle needs \"file\": an .obj or .stl path relative to the scene file");
    double scale = 1, offset[3] = {0, 0, 0};
    o->thickness = 0.05;
    if (scene_get_number(c, obj, path, "scale", &scale, NULL) || scene_get_vec3(c, obj, path, "offset", offset, NULL) ||
        scene_get_number(c, obj, path, "thickness", &o->thickness, NULL))
        return -1;
    if (scene_range_pos(c, path, "scale", scale, "") || scene_range_pos(c, path, "thickness", o->thickness, "m"))
        return -1;
    scene_resolve(full, sizeof full, c->base_dir, file);
    sq_err e = {{0}};
    size_t n = strlen(full);
    int tet = (n > 4 && (!strcmp(full + n - 4, ".msh") || !strcmp(full + n - 4, ".ele"))) ||
              (n > 5 && (!strcmp(full + n - 5, ".mesh") || !strcmp(full + n - 5, ".node")));
    sq_trimesh *m = tet ? tet_boundary(full, scale, offset, &e) : sq_trimesh_load(full, scale, offset, &e);
    if (!m)
        return scene_fail(c, p, "%s", e.msg);
    s->trimeshes[oi] = m;
    o->mesh = m;
    return 0;
}

int scene_parse_obstacle(pctx *c, sq_scene *s, const cJSON *obj, int oi, const char *path)
{
    static const char *const keys[] = {"name", "type", "point", "normal", "center", "size", "radius", "a", "b",
                                       "file", "scale", "offset", "thickness", "friction", "keyframes", NULL};
    if (!cJSON_IsObject(obj))
        return scene_fail(c, path, "expected an object {\"type\": \"plane\", ...}, got %s; see docs/scenes.md",
                          scene_type_name(obj));
    if (scene_check_keys(c, obj, path, keys))
        return -1;
    sq_obstacle_script *os = &s->obstacles[oi];
    memset(os, 0, sizeof *os);
    sq_obstacle *o = &os->obstacle;
    char p[256], type[16];
    snprintf(o->name, sizeof o->name, "obstacle%d", oi);
    int found;
    if (scene_get_string(c, obj, path, "name", o->name, sizeof o->name, NULL))
        return -1;
    scene_join(p, sizeof p, path, "name");
    if (scene_check_name(c, p, o->name))
        return -1;
    for (int j = 0; j < oi; j++)
        if (!strcmp(s->obstacles[j].obstacle.name, o->name))
            return scene_fail(c, p, "\"%s\" is already the name of obstacles[%d]; give each obstacle its own name",
                              o->name, j);
    scene_join(p, sizeof p, path, "type");
    const cJSON *ty = scene_get(obj, "type");
    if (ty && cJSON_IsString(ty) && strlen(ty->valuestring) >= sizeof type)
        return scene_fail(c, p, "\"%.40s\" is not a type; use plane, box, sphere, capsule or mesh", ty->valuestring);
    if (scene_get_string(c, obj, path, "type", type, sizeof type, &found))
        return -1;
    if (!found)
        return scene_fail(c, p, "missing; give \"plane\", \"box\", \"sphere\", \"capsule\" or \"mesh\"");
    int bad = 0;
    if (!strcmp(type, "plane")) {
        o->kind = SQ_OBSTACLE_PLANE;
        o->normal[2] = 1;
        bad = need_vec3(c, obj, path, "point", o->point, "a point on the plane [x, y, z] (m)") ||
              scene_get_vec3(c, obj, path, "normal", o->normal, NULL);
        if (!bad) {
            double l = sqrt(o->normal[0] * o->normal[0] + o->normal[1] * o->normal[1] + o->normal[2] * o->normal[2]);
            if (!(l > 1e-12)) {
                scene_join(p, sizeof p, path, "normal");
                return scene_fail(c, p, "[%g, %g, %g] has no direction; give the outward normal, e.g. [0, 0, 1] for a floor",
                                  o->normal[0], o->normal[1], o->normal[2]);
            }
            for (int k = 0; k < 3; k++)
                o->normal[k] /= l;
        }
    } else if (!strcmp(type, "box")) {
        o->kind = SQ_OBSTACLE_BOX;
        double size[3];
        bad = need_vec3(c, obj, path, "center", o->point, "the box centre [x, y, z] (m)") ||
              need_vec3(c, obj, path, "size", size, "the full extents [sx, sy, sz] (m)");
        for (int k = 0; k < 3 && !bad; k++)
            o->half[k] = size[k] / 2;
    } else if (!strcmp(type, "sphere")) {
        o->kind = SQ_OBSTACLE_SPHERE;
        bad = need_vec3(c, obj, path, "center", o->point, "the sphere centre [x, y, z] (m)") ||
              scene_get_required_number(c, obj, path, "radius", &o->radius, "the radius in m");
    } else if (!strcmp(type, "capsule")) {
        o->kind = SQ_OBSTACLE_CAPSULE;
        bad = need_vec3(c, obj, path, "a", o->point, "one end of the axis [x, y, z] (m)") ||
              need_vec3(c, obj, path, "b", o->end, "the other end of the axis [x, y, z] (m)") ||
              scene_get_required_number(c, obj, path, "radius", &o->radius, "the radius in m");
    } else if (!strcmp(type, "mesh")) {
        o->kind = SQ_OBSTACLE_MESH;
        bad = parse_mesh_obstacle(c, s, obj, oi, path, o);
    } else {
        return scene_fail(c, p, "\"%s\" is not a type; use plane, box, sphere, capsule or mesh", type);
    }
    if (bad || parse_friction(c, obj, path, &o->mu_s, &o->mu_k))
        return -1;
    sq_err e = {{0}};
    if (sq_obstacle_check(o, &e))
        return scene_fail(c, path, "%s", e.msg);
    if (scene_parse_keyframes(c, obj, path, 0, os->keys, &os->nkeys, "the obstacle's offset [x, y, z] from its placement (m)"))
        return -1;
    if (os->nkeys && o->kind == SQ_OBSTACLE_MESH) {
        scene_join(p, sizeof p, path, "keyframes");
        return scene_fail(c, p, "a mesh obstacle is static; remove its keyframes (planes, boxes, spheres and capsules move)");
    }
    return 0;
}

static void keyframe_offset(const sq_obstacle_script *s, double t, double off[3])
{
    const sq_keyframe *k = s->keys;
    int n = s->nkeys, i = 0;
    off[0] = off[1] = off[2] = 0;
    if (n <= 0)
        return;
    if (t <= k[0].t || n == 1) {
        memcpy(off, k[t <= k[0].t ? 0 : n - 1].pos, sizeof(double) * 3);
        return;
    }
    if (t >= k[n - 1].t) {
        memcpy(off, k[n - 1].pos, sizeof(double) * 3);
        return;
    }
    while (i + 1 < n && k[i + 1].t <= t)
        i++;
    double a = (t - k[i].t) / (k[i + 1].t - k[i].t);
    for (int c = 0; c < 3; c++)
        off[c] = k[i].pos[c] + a * (k[i + 1].pos[c] - k[i].pos[c]);
}

void sq_obstacle_script_pose(const sq_obstacle_script *s, double t, double dt, sq_obstacle *out)
{
    *out = s->obstacle;
    memset(out->velocity, 0, sizeof out->velocity);
    if (s->nkeys <= 0)
        return;
    double now[3], before[3];
    keyframe_offset(s, t, now);
    keyframe_offset(s, t - dt, before);
    for (int c = 0; c < 3; c++) {
        out->point[c] += now[c];
        out->end[c] += now[c];
        out->velocity[c] = dt > 0 ? (now[c] - before[c]) / dt : 0;
    }
}

/* a rest node of body b inside obstacle o or inside body j (located in its finest loaded mesh) */
int scene_check_overlaps(pctx *c, const sq_scene *s)
{
    char p[64];
    for (int b = 0; b < s->nbodies; b++) {
        const sq_body_def *d = &s->bodies[b];
        const sq_mesh *m = d->levels[d->nlevels - 1];
        scene_join_index(p, sizeof p, "bodies", b);
        for (int k = 0; k < m->nsurf; k++) {
            const double *x = m->x + 3 * (size_t)m->surf_nodes[k];
            for (int o = 0; o < s->nobstacles; o++) {
                sq_obstacle ob;
                double n[3];
                sq_obstacle_script_pose(&s->obstacles[o], 0, 1.0 / s->frame_rate, &ob);
                double phi = sq_obstacle_distance(&ob, x, n);
                if (phi < -1e-9)
                    return scene_fail(c, p, "(\"%s\") starts inside obstacle \"%s\": its rest node at [%.4g, %.4g, %.4g] is "
                                      "%.3g m deep; move the body (\"offset\") or the obstacle so they only touch",
                                      s->body_names[b], ob.name, x[0], x[1], x[2], -phi);
            }
            if (!s->body_contact) /* fixed or adaptive: both meet other bodies */
                continue;
            for (int j = 0; j < s->nbodies; j++) {
                const sq_body_def *dj = &s->bodies[j];
                if (j == b)
                    continue;
                double bary[4];
                const sq_mesh *mj = dj->levels[dj->nlevels - 1];
                if (sq_mesh_locate(mj, x, bary) < 0)
                    continue;
                double lo = SQ_MIN(SQ_MIN(bary[0], bary[1]), SQ_MIN(bary[2], bary[3]));
                if (lo > 1e-6)
                    return scene_fail(c, p, "(\"%s\") starts inside body \"%s\": its rest node at [%.4g, %.4g, %.4g] lies "
                                      "in that body's mesh; move one of them (\"offset\"), or set \"contact\": "
                                      "{\"bodies\": false} if they are meant to overlap", s->body_names[b],
                                      s->body_names[j], x[0], x[1], x[2]);
            }
        }
    }
    return 0;
}
