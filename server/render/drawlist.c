/* drawlist.c - build what to draw from a render state: lit triangles with colours (bodies,
 * floor, obstacles, tools) and the resolved camera. No OpenGL here. */
#include <math.h>
#include <stdlib.h>
#include <string.h>

#include "render/render.h"

#define PI 3.14159265358979323846
#define CREASE_COS 0.7071 /* faces meeting at more than 45 degrees keep separate normals */
#define FLOOR_TILES 12    /* checker tiles per floor side */

static double dot3(const double a[3], const double b[3])
{
    return a[0] * b[0] + a[1] * b[1] + a[2] * b[2];
}

static void cross3(const double a[3], const double b[3], double out[3])
{
    out[0] = a[1] * b[2] - a[2] * b[1];
    out[1] = a[2] * b[0] - a[0] * b[2];
    out[2] = a[0] * b[1] - a[1] * b[0];
}

static double normalize3(double v[3])
{
    double n = sqrt(dot3(v, v));
    if (n > 0.0)
        for (int k = 0; k < 3; k++)
            v[k] /= n;
    return n;
}

static unsigned char to_byte(float c)
{
    if (!(c > 0.0f))
        return 0;
    if (c >= 1.0f)
        return 255;
    return (unsigned char)lrintf(c * 255.0f);
}

void sq_render_level_rgb(const sq_palette *p, int level, unsigned char rgb[3])
{
    if (level < 0)
        level = 0;
    if (level >= SQ_MAX_LEVELS)
        level = SQ_MAX_LEVELS - 1;
    for (int k = 0; k < 3; k++)
        rgb[k] = to_byte(p->level[level][k]);
}

/* make room for nv more vertices and nt more triangles */
static void reserve(sq_drawlist *dl, int nv, int nt)
{
    if (dl->nverts + nv > dl->cap_verts) {
        int cap = SQ_MAX(dl->nverts + nv, 2 * dl->cap_verts);
        dl->v = sq_realloc(dl->v, (size_t)cap * sizeof *dl->v);
        dl->cap_verts = cap;
    }
    if (dl->ntris + nt > dl->cap_tris) {
        int cap = SQ_MAX(dl->ntris + nt, 2 * dl->cap_tris);
        dl->idx = sq_realloc(dl->idx, (size_t)cap * 3 * sizeof *dl->idx);
        dl->cap_tris = cap;
    }
}

static int push_vertex(sq_drawlist *dl, const double pos[3], const double n[3],
                       const unsigned char rgb[3])
{
    sq_draw_vertex *v = &dl->v[dl->nverts];
    for (int k = 0; k < 3; k++) {
        v->pos[k] = (float)pos[k];
        v->normal[k] = (float)n[k];
        v->rgba[k] = rgb[k];
    }
    v->rgba[3] = 255;
    return dl->nverts++;
}

static void push_tri(sq_drawlist *dl, int a, int b, int c)
{
    unsigned *t = &dl->idx[3 * dl->ntris++];
    t[0] = (unsigned)a;
    t[1] = (unsigned)b;
    t[2] = (unsigned)c;
}

/* colour of vertex i of body b */
static void vertex_rgb(const sq_render_body *b, int i, const sq_render_opts *o, double scale,
                       unsigned char rgb[3])
{
    switch (o->color) {
    case SQ_COLOR_LEVEL:
        sq_render_level_rgb(&o->palette, b->level[i], rgb);
        return;
    case SQ_COLOR_PLAIN:
        for (int k = 0; k < 3; k++)
            rgb[k] = to_byte(o->palette.plain[k]);
        return;
    case SQ_COLOR_STRESS: {
        double d2 = 0.0;
        for (int k = 0; k < 3; k++) {
            double d = (double)b->xyz[3 * i + k] - b->rest[3 * i + k];
            d2 += d * d;
        }
        double t = scale > 0.0 ? sqrt(d2) / scale : 0.0;
        if (!(t >= 0.0))
            t = 1.0;
        if (t > 1.0)
            t = 1.0;
        const float *lo = t < 0.5 ? o->palette.stress_low : o->palette.stress_mid;
        const float *hi = t < 0.5 ? o->palette.stress_mid : o->palette.stress_high;
        float f = (float)(t < 0.5 ? 2.0 * t : 2.0 * t - 1.0);
        for (int k = 0; k < 3; k++)
            rgb[k] = to_byte(lo[k] + f * (hi[k] - lo[k]));
        return;
    }
    }
    rgb[0] = rgb[1] = rgb[2] = 255;
}

/* largest |displacement| over all bodies (stress auto scale) */
static double max_displacement(const sq_render_state *s)
{
    double m2 = 0.0;
    for (int bi = 0; bi < s->nbodies; bi++) {
        const sq_render_body *b = &s->bodies[bi];
        for (int i = 0; i < b->nverts; i++) {
            double d2 = 0.0;
            for (int k = 0; k < 3; k++) {
                double d = (double)b->xyz[3 * i + k] - b->rest[3 * i + k];
                d2 += d * d;
            }
            if (d2 > m2 && isfinite(d2))
                m2 = d2;
        }
    }
    return sqrt(m2);
}

/* a body's surface: three vertices per triangle, normals averaged over the incident
 * faces within the crease angle (smooth on curved parts, sharp at box edges) */
static void add_body(sq_drawlist *dl, const sq_render_body *b, const sq_render_opts *o,
                     double scale)
{
    if (b->ntris == 0)
        return;
    double *fn = sq_malloc((size_t)b->ntris * 3 * sizeof(double)); /* area-weighted normals */
    double *fu = sq_malloc((size_t)b->ntris * 3 * sizeof(double)); /* unit normals */
    unsigned char *ok = sq_malloc((size_t)b->ntris);
    int *start = sq_calloc((size_t)b->nverts + 1, sizeof(int));
    int *inc = sq_malloc((size_t)b->ntris * 3 * sizeof(int));

    /* face normals from the current positions; faces with non-finite corners are left out */
    for (int t = 0; t < b->ntris; t++) {
        const int *tv = &b->tris[3 * t];
        double p[3][3];
        int finite = 1;
        for (int c = 0; c < 3; c++)
            for (int k = 0; k < 3; k++) {
                p[c][k] = b->xyz[3 * tv[c] + k];
                finite &= isfinite(p[c][k]) != 0;
            }
        ok[t] = (unsigned char)finite;
        double e1[3], e2[3];
        for (int k = 0; k < 3; k++) {
            e1[k] = finite ? p[1][k] - p[0][k] : 0.0;
            e2[k] = finite ? p[2][k] - p[0][k] : 0.0;
        }
        cross3(e1, e2, &fn[3 * t]);
        memcpy(&fu[3 * t], &fn[3 * t], 3 * sizeof(double));
        normalize3(&fu[3 * t]);
        if (!finite)
            dl->skipped_tris++;
    }

    /* vertex -> incident faces (CSR) */
    for (int t = 0; t < b->ntris; t++)
        for (int c = 0; c < 3; c++)
            start[b->tris[3 * t + c] + 1]++;
    for (int i = 0; i < b->nverts; i++)
        start[i + 1] += start[i];
    int *fill = sq_malloc((size_t)b->nverts * sizeof(int));
    memcpy(fill, start, (size_t)b->nverts * sizeof(int));
    for (int t = 0; t < b->ntris; t++)
        for (int c = 0; c < 3; c++)
            inc[fill[b->tris[3 * t + c]]++] = t;
    free(fill);

    reserve(dl, 3 * b->ntris, b->ntris);
    for (int t = 0; t < b->ntris; t++) {
        if (!ok[t])
            continue;
        int idx[3];
        for (int c = 0; c < 3; c++) {
            int vi = b->tris[3 * t + c];
            double n[3] = {0.0, 0.0, 0.0};
            for (int j = start[vi]; j < start[vi + 1]; j++) {
                int u = inc[j];
                if (ok[u] && dot3(&fu[3 * t], &fu[3 * u]) >= CREASE_COS)
                    for (int k = 0; k < 3; k++)
                        n[k] += fn[3 * u + k];
            }
            if (normalize3(n) == 0.0)
                memcpy(n, &fu[3 * t], sizeof n);
            double pos[3] = {b->xyz[3 * vi], b->xyz[3 * vi + 1], b->xyz[3 * vi + 2]};
            unsigned char rgb[3];
            vertex_rgb(b, vi, o, scale, rgb);
            idx[c] = push_vertex(dl, pos, n, rgb);
        }
        push_tri(dl, idx[0], idx[1], idx[2]);
    }
    free(fn);
    free(fu);
    free(ok);
    free(start);
    free(inc);
}

/* an orthonormal frame (e1, e2, up) with e1 close to +x (or +y when up is near x) */
static void plane_basis(const double up[3], double e1[3], double e2[3])
{
    double a[3] = {1.0, 0.0, 0.0};
    if (fabs(up[0]) > 0.9) {
        a[0] = 0.0;
        a[1] = 1.0;
    }
    double d = dot3(a, up);
    for (int k = 0; k < 3; k++)
        e1[k] = a[k] - d * up[k];
    normalize3(e1);
    cross3(up, e1, e2);
}

/* a checkered square of FLOOR_TILES x FLOOR_TILES tiles in the floor colours: centre, unit
 * normal n, half side */
static void add_tiles(sq_drawlist *dl, const double centre[3], const double n[3], double half,
                      const sq_render_opts *o)
{
    double e1[3], e2[3];
    plane_basis(n, e1, e2);
    double tile = 2.0 * half / FLOOR_TILES;
    unsigned char c0[3], c1[3];
    for (int k = 0; k < 3; k++) {
        c0[k] = to_byte(o->palette.floor[k]);
        c1[k] = to_byte(o->palette.floor_line[k]);
    }
    reserve(dl, 4 * FLOOR_TILES * FLOOR_TILES, 2 * FLOOR_TILES * FLOOR_TILES);
    for (int i = 0; i < FLOOR_TILES; i++)
        for (int j = 0; j < FLOOR_TILES; j++) {
            const unsigned char *rgb = (i + j) % 2 ? c1 : c0;
            int q[4];
            for (int c = 0; c < 4; c++) {
                double a = -half + tile * (i + (c == 1 || c == 2));
                double b = -half + tile * (j + (c >= 2));
                double p[3];
                for (int k = 0; k < 3; k++)
                    p[k] = centre[k] + a * e1[k] + b * e2[k];
                q[c] = push_vertex(dl, p, n, rgb);
            }
            push_tri(dl, q[0], q[1], q[2]);
            push_tri(dl, q[0], q[2], q[3]);
        }
}

/* a checkered square floor under the bodies, normal = up */
static void add_floor(sq_drawlist *dl, const sq_render_state *s, const sq_render_opts *o,
                      double diag)
{
    double centre[3];
    for (int k = 0; k < 3; k++)
        centre[k] = 0.5 * (s->bbox_min[k] + s->bbox_max[k]);
    /* height: lowest bbox corner along up, slightly below so the bodies' bottoms win */
    double h = INFINITY;
    for (int c = 0; c < 8; c++) {
        double p[3] = {c & 1 ? s->bbox_max[0] : s->bbox_min[0],
                       c & 2 ? s->bbox_max[1] : s->bbox_min[1],
                       c & 4 ? s->bbox_max[2] : s->bbox_min[2]};
        h = fmin(h, dot3(p, s->up));
    }
    h -= 0.002 * diag;
    double shift = h - dot3(centre, s->up);
    for (int k = 0; k < 3; k++)
        centre[k] += shift * s->up[k];
    add_tiles(dl, centre, s->up, 1.5 * diag, o);
}

/* a UV sphere */
static void add_sphere(sq_drawlist *dl, const double c[3], double r, const unsigned char rgb[3])
{
    enum { NLAT = 12, NLON = 24 };
    reserve(dl, (NLAT + 1) * (NLON + 1), 2 * NLAT * NLON);
    int base = dl->nverts;
    for (int i = 0; i <= NLAT; i++) {
        double th = PI * i / NLAT;
        for (int j = 0; j <= NLON; j++) {
            double ph = 2.0 * PI * j / NLON;
            double n[3] = {sin(th) * cos(ph), sin(th) * sin(ph), cos(th)};
            double p[3] = {c[0] + r * n[0], c[1] + r * n[1], c[2] + r * n[2]};
            push_vertex(dl, p, n, rgb);
        }
    }
    for (int i = 0; i < NLAT; i++)
        for (int j = 0; j < NLON; j++) {
            int a = base + i * (NLON + 1) + j, b = a + NLON + 1;
            push_tri(dl, a, b, b + 1);
            push_tri(dl, a, b + 1, a + 1);
        }
}

/* an axis-aligned box with flat faces */
static void add_box(sq_drawlist *dl, const double c[3], const double half[3],
                    const unsigned char rgb[3])
{
    reserve(dl, 24, 12);
    for (int axis = 0; axis < 3; axis++)
        for (int side = -1; side <= 1; side += 2) {
            int u = (axis + 1) % 3, v = (axis + 2) % 3;
            double n[3] = {0.0, 0.0, 0.0};
            n[axis] = side;
            int q[4];
            for (int k = 0; k < 4; k++) {
                double su = (k == 1 || k == 2) ? 1.0 : -1.0, sv = k >= 2 ? 1.0 : -1.0;
                if (side < 0)
                    su = -su; /* keep counter-clockwise from outside */
                double p[3];
                p[axis] = c[axis] + side * half[axis];
                p[u] = c[u] + su * half[u];
                p[v] = c[v] + sv * half[v];
                q[k] = push_vertex(dl, p, n, rgb);
            }
            push_tri(dl, q[0], q[1], q[2]);
            push_tri(dl, q[0], q[2], q[3]);
        }
}

/* a cylinder of radius r from a to b, open at the ends (a capsule's body) */
static void add_cylinder(sq_drawlist *dl, const double a[3], const double b[3], double r,
                         const unsigned char rgb[3])
{
    enum { NSEG = 24 };
    double axis[3] = {b[0] - a[0], b[1] - a[1], b[2] - a[2]}, e1[3], e2[3];
    if (normalize3(axis) == 0.0)
        return;
    plane_basis(axis, e1, e2);
    reserve(dl, 2 * (NSEG + 1), 2 * NSEG);
    int base = dl->nverts;
    for (int j = 0; j <= NSEG; j++) {
        double ph = 2.0 * PI * j / NSEG, n[3], p[3];
        for (int k = 0; k < 3; k++)
            n[k] = cos(ph) * e1[k] + sin(ph) * e2[k];
        for (int k = 0; k < 3; k++)
            p[k] = a[k] + r * n[k];
        push_vertex(dl, p, n, rgb);
        for (int k = 0; k < 3; k++)
            p[k] = b[k] + r * n[k];
        push_vertex(dl, p, n, rgb);
    }
    for (int j = 0; j < NSEG; j++) {
        int q = base + 2 * j;
        push_tri(dl, q, q + 2, q + 3);
        push_tri(dl, q, q + 3, q + 1);
    }
}

/* a triangle mesh with flat faces (one normal per triangle); non-finite triangles left out */
static void add_trimesh(sq_drawlist *dl, const sq_render_obstacle *m, const unsigned char rgb[3])
{
    reserve(dl, 3 * m->ntris, m->ntris);
    for (int t = 0; t < m->ntris; t++) {
        double p[3][3];
        int finite = 1;
        for (int c = 0; c < 3; c++)
            for (int k = 0; k < 3; k++) {
                p[c][k] = m->xyz[3 * m->tris[3 * t + c] + k];
                finite &= isfinite(p[c][k]) != 0;
            }
        double e1[3], e2[3], n[3];
        for (int k = 0; k < 3; k++) {
            e1[k] = p[1][k] - p[0][k];
            e2[k] = p[2][k] - p[0][k];
        }
        cross3(e1, e2, n);
        if (!finite || normalize3(n) == 0.0)
            continue;
        int q[3];
        for (int c = 0; c < 3; c++)
            q[c] = push_vertex(dl, p[c], n, rgb);
        push_tri(dl, q[0], q[1], q[2]);
    }
}

/* does the state hold a plane obstacle (which then stands for the floor)? */
static int has_plane(const sq_render_state *s)
{
    for (int i = 0; i < s->nobstacles; i++)
        if (s->obstacles[i].shape.kind == SQ_OBSTACLE_PLANE)
            return 1;
    return 0;
}

/* the obstacles: a plane as a tiled square (1.5 scene diagonals each side of the bodies' centre
 * projected on it, slightly behind it so resting bodies win), the others in the obstacle colour */
static void add_obstacles(sq_drawlist *dl, const sq_render_state *s, const sq_render_opts *o,
                          double diag)
{
    unsigned char rgb[3];
    for (int k = 0; k < 3; k++)
        rgb[k] = to_byte(o->palette.obstacle[k]);
    for (int i = 0; i < s->nobstacles; i++) {
        const sq_render_obstacle *r = &s->obstacles[i];
        const sq_obstacle *ob = &r->shape;
        switch (ob->kind) {
        case SQ_OBSTACLE_PLANE: {
            double n[3] = {ob->normal[0], ob->normal[1], ob->normal[2]}, c[3];
            if (normalize3(n) == 0.0)
                break;
            for (int k = 0; k < 3; k++)
                c[k] = 0.5 * (s->bbox_min[k] + s->bbox_max[k]);
            double off[3] = {c[0] - ob->point[0], c[1] - ob->point[1], c[2] - ob->point[2]};
            double h = dot3(off, n) + 0.002 * diag;
            for (int k = 0; k < 3; k++)
                c[k] -= h * n[k];
            add_tiles(dl, c, n, 1.5 * diag, o);
            break;
        }
        case SQ_OBSTACLE_BOX:
            add_box(dl, ob->point, ob->half, rgb);
            break;
        case SQ_OBSTACLE_SPHERE:
            add_sphere(dl, ob->point, ob->radius, rgb);
            break;
        case SQ_OBSTACLE_CAPSULE:
            add_sphere(dl, ob->point, ob->radius, rgb);
            add_sphere(dl, ob->end, ob->radius, rgb);
            add_cylinder(dl, ob->point, ob->end, ob->radius, rgb);
            break;
        case SQ_OBSTACLE_MESH:
            add_trimesh(dl, r, rgb);
            break;
        }
    }
}

/* how far the obstacles other than planes reach from centre (0 when there are none) */
static double obstacle_reach(const sq_render_state *s, const double centre[3])
{
    double reach = 0.0;
    for (int i = 0; i < s->nobstacles; i++) {
        const sq_render_obstacle *r = &s->obstacles[i];
        const sq_obstacle *ob = &r->shape;
        double d = 0.0;
        switch (ob->kind) {
        case SQ_OBSTACLE_PLANE:
            break;
        case SQ_OBSTACLE_BOX:
        case SQ_OBSTACLE_SPHERE:
        case SQ_OBSTACLE_CAPSULE: {
            double ext = ob->kind == SQ_OBSTACLE_BOX ? sqrt(dot3(ob->half, ob->half)) : ob->radius;
            double pa[3], pb[3];
            for (int k = 0; k < 3; k++) {
                pa[k] = ob->point[k] - centre[k];
                pb[k] = (ob->kind == SQ_OBSTACLE_CAPSULE ? ob->end[k] : ob->point[k]) - centre[k];
            }
            d = fmax(sqrt(dot3(pa, pa)), sqrt(dot3(pb, pb))) + ext;
            break;
        }
        case SQ_OBSTACLE_MESH:
            for (int v = 0; v < r->nverts; v++) {
                double p[3] = {r->xyz[3 * v] - centre[0], r->xyz[3 * v + 1] - centre[1],
                               r->xyz[3 * v + 2] - centre[2]};
                d = fmax(d, sqrt(dot3(p, p)));
            }
            break;
        }
        if (isfinite(d))
            reach = fmax(reach, d);
    }
    return reach;
}

static void add_tools(sq_drawlist *dl, const sq_render_state *s, const sq_render_opts *o,
                      double diag)
{
    for (int i = 0; i < s->ntools; i++) {
        const sq_tool *t = &s->tools[i];
        if (!isfinite(t->pos[0]) || !isfinite(t->pos[1]) || !isfinite(t->pos[2]))
            continue;
        /* an inactive grab holds nothing and is not shown (the viewer hides it too) */
        if (t->shape == SQ_TOOL_GRAB && !t->active)
            continue;
        unsigned char rgb[3];
        for (int k = 0; k < 3; k++)
            rgb[k] = to_byte(o->palette.tool[k] * (t->active ? 1.0f : 0.5f));
        switch (t->shape) {
        case SQ_TOOL_SPHERE:
            if (t->radius > 0.0 && isfinite(t->radius))
                add_sphere(dl, t->pos, t->radius, rgb);
            break;
        case SQ_TOOL_BOX:
            if (t->half[0] > 0.0 && t->half[1] > 0.0 && t->half[2] > 0.0 &&
                isfinite(t->half[0] + t->half[1] + t->half[2]))
                add_box(dl, t->pos, t->half, rgb);
            break;
        case SQ_TOOL_GRAB: {
            /* the grab point as a small bead (its capture radius would hide the body) */
            double r = 0.015 * diag;
            if (t->radius > 0.0 && isfinite(t->radius))
                r = fmin(r, 0.5 * t->radius);
            add_sphere(dl, t->pos, r, rgb);
            break;
        }
        }
    }
}

/* the scene's probes: a bead (1.8 % of the scene diagonal) in the probe colour at each */
static void add_probes(sq_drawlist *dl, const sq_render_state *s, const sq_render_opts *o,
                       double diag)
{
    unsigned char rgb[3];
    for (int k = 0; k < 3; k++)
        rgb[k] = to_byte(o->palette.probe[k]);
    for (int i = 0; i < s->nprobes; i++)
        if (isfinite(s->probes[i][0]) && isfinite(s->probes[i][1]) && isfinite(s->probes[i][2]))
            add_sphere(dl, s->probes[i], 0.018 * diag, rgb);
}

/* resolve the camera: eye, target, up, clip planes */
static int resolve_camera(sq_drawlist *dl, const sq_render_state *s, const sq_camera *cam,
                          double aspect, double diag, sq_err *err)
{
    double centre[3], e1[3], e2[3];
    for (int k = 0; k < 3; k++)
        centre[k] = 0.5 * (s->bbox_min[k] + s->bbox_max[k]);
    plane_basis(s->up, e1, e2);
    double fov = cam->fov_deg > 1.0 && cam->fov_deg < 170.0 ? cam->fov_deg : 35.0;
    dl->fovy_deg = fov;
    if (cam->eye_target) {
        memcpy(dl->eye, cam->eye, sizeof dl->eye);
        memcpy(dl->target, cam->target, sizeof dl->target);
    } else {
        double az = cam->az_deg * PI / 180.0, el = cam->el_deg * PI / 180.0;
        double dir[3];
        for (int k = 0; k < 3; k++)
            dir[k] = cos(el) * (sin(az) * e1[k] - cos(az) * e2[k]) + sin(el) * s->up[k];
        double dist = cam->dist;
        if (!(dist > 0.0)) {
            /* fit the 8 bbox corners: corner c at (x, y) across the view and z towards the
             * eye needs dist >= z + |x| / tan_h and z + |y| / tan_v; 12% margin */
            double tv = 0.88 * tan(0.5 * fov * PI / 180.0), th = tv * aspect;
            double right[3], upv[3], back[3];
            for (int k = 0; k < 3; k++)
                back[k] = dir[k];
            cross3(s->up, back, right);
            if (normalize3(right) == 0.0)
                memcpy(right, e1, sizeof right);
            cross3(back, right, upv);
            dist = 0.0;
            for (int c = 0; c < 8; c++) {
                double p[3] = {(c & 1 ? s->bbox_max[0] : s->bbox_min[0]) - centre[0],
                               (c & 2 ? s->bbox_max[1] : s->bbox_min[1]) - centre[1],
                               (c & 4 ? s->bbox_max[2] : s->bbox_min[2]) - centre[2]};
                double z = dot3(p, back);
                dist = fmax(dist, z + fabs(dot3(p, right)) / th);
                dist = fmax(dist, z + fabs(dot3(p, upv)) / tv);
            }
            dist = fmax(dist, 0.6 * diag); /* never inside the bodies */
        }
        memcpy(dl->target, centre, sizeof centre);
        for (int k = 0; k < 3; k++)
            dl->eye[k] = centre[k] + dist * dir[k];
    }
    double view[3];
    for (int k = 0; k < 3; k++)
        view[k] = dl->target[k] - dl->eye[k];
    double vlen = normalize3(view);
    if (!(vlen > 0.0) || !isfinite(vlen))
        return sq_err_set(err, "camera: eye and target coincide or are not finite");
    /* up: the scene's up unless looking along it */
    if (fabs(dot3(view, s->up)) > 0.999)
        memcpy(dl->up, e2, sizeof e2);
    else
        memcpy(dl->up, s->up, sizeof dl->up);
    /* clip planes enclosing the bodies and the floor (radius ~2.2 diag around the centre) and
     * the obstacles */
    double dc[3];
    for (int k = 0; k < 3; k++)
        dc[k] = centre[k] - dl->eye[k];
    double d = sqrt(dot3(dc, dc)), reach = fmax(2.3 * diag, 1.05 * obstacle_reach(s, centre));
    dl->zfar = d + reach;
    dl->znear = fmax(d - reach, dl->zfar * 1e-3);
    return 0;
}

int sq_drawlist_build(sq_drawlist *dl, const sq_render_state *s, const sq_render_opts *o,
                      double aspect, sq_err *err)
{
    dl->nverts = 0;
    dl->ntris = 0;
    dl->body_tris = 0;
    dl->skipped_tris = 0;
    memcpy(dl->background, o->palette.background, sizeof dl->background);
    if (!(aspect > 0.0) || !isfinite(aspect))
        return sq_err_set(err, "render: aspect ratio %g must be > 0", aspect);

    /* a body falling onto a plane obstacle: the frame takes in the bodies' rest box and its
     * shadow on the plane, when it lies within two box diagonals (a dropped body stays in view) */
    sq_render_state tmp;
    if (o->obstacles && has_plane(s) && s->nbodies > 0) {
        double lo[3], hi[3], d0 = 0.0;
        for (int k = 0; k < 3; k++) {
            lo[k] = s->bbox_min[k];
            hi[k] = s->bbox_max[k];
            d0 += (hi[k] - lo[k]) * (hi[k] - lo[k]);
        }
        d0 = sqrt(d0);
        for (int i = 0; i < s->nobstacles; i++) {
            const sq_obstacle *ob = &s->obstacles[i].shape;
            double n[3] = {ob->normal[0], ob->normal[1], ob->normal[2]};
            if (ob->kind != SQ_OBSTACLE_PLANE || normalize3(n) == 0.0)
                continue;
            for (int c = 0; c < 8; c++) {
                double p[3] = {c & 1 ? s->bbox_max[0] : s->bbox_min[0],
                               c & 2 ? s->bbox_max[1] : s->bbox_min[1],
                               c & 4 ? s->bbox_max[2] : s->bbox_min[2]};
                double off[3] = {p[0] - ob->point[0], p[1] - ob->point[1], p[2] - ob->point[2]};
                double h = dot3(off, n);
                if (!(h >= 0.0 && h <= 2.0 * d0 + 1e-9))
                    continue;
                for (int k = 0; k < 3; k++) {
                    lo[k] = fmin(lo[k], p[k] - h * n[k]);
                    hi[k] = fmax(hi[k], p[k] - h * n[k]);
                }
            }
        }
        tmp = *s;
        memcpy(tmp.bbox_min, lo, sizeof lo);
        memcpy(tmp.bbox_max, hi, sizeof hi);
        s = &tmp;
    }

    /* scene size; a degenerate or empty scene gets a 1 m frame */
    double ext[3], diag2 = 0.0;
    for (int k = 0; k < 3; k++) {
        ext[k] = s->bbox_max[k] - s->bbox_min[k];
        diag2 += ext[k] * ext[k];
    }
    double diag = sqrt(diag2);
    if (!(diag > 1e-9) || !isfinite(diag)) {
        if (s != &tmp)
            tmp = *s;
        for (int k = 0; k < 3; k++) {
            double c = s->nbodies ? 0.5 * (s->bbox_min[k] + s->bbox_max[k]) : 0.0;
            tmp.bbox_min[k] = c - 0.5;
            tmp.bbox_max[k] = c + 0.5;
        }
        s = &tmp;
        diag = sqrt(3.0);
    }

    dl->stress_scale = o->stress_max > 0.0 ? o->stress_max : max_displacement(s);
    for (int bi = 0; bi < s->nbodies; bi++)
        add_body(dl, &s->bodies[bi], o, dl->stress_scale);
    dl->body_tris = dl->ntris;
    dl->floor_tris = dl->obstacle_tris = 0;
    int plane = o->obstacles && has_plane(s);
    if (o->floor && !plane) {
        add_floor(dl, s, o, diag);
        dl->floor_tris = dl->ntris - dl->body_tris;
    }
    if (o->obstacles) {
        int before = dl->ntris;
        add_obstacles(dl, s, o, diag);
        dl->obstacle_tris = dl->ntris - before;
    }
    if (o->tools)
        add_tools(dl, s, o, diag);
    if (o->probes)
        add_probes(dl, s, o, diag);
    return resolve_camera(dl, s, &o->camera, aspect, diag, err);
}

void sq_drawlist_free(sq_drawlist *dl)
{
    free(dl->v);
    free(dl->idx);
    memset(dl, 0, sizeof *dl);
}
