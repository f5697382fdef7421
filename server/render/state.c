/* state.c - the render state: a self-contained copy of what to draw (bodies' surfaces,
 * tools, obstacles, up axis), filled from arrays or captured from a world (capture.c). */
#include <math.h>
#include <stdlib.h>
#include <string.h>

#include "render/render.h"

void sq_render_state_init(sq_render_state *s)
{
    memset(s, 0, sizeof *s);
    s->up[2] = 1.0;
}

void sq_render_state_free(sq_render_state *s)
{
    for (int i = 0; i < SQ_MAX_BODIES; i++) {
        sq_render_body *b = &s->bodies[i];
        free(b->xyz);
        free(b->rest);
        free(b->level);
        free(b->tris);
    }
    for (int i = 0; i < SQ_MAX_OBSTACLES; i++) {
        free(s->obstacles[i].xyz);
        free(s->obstacles[i].tris);
    }
    sq_render_state_init(s);
}

/* grow a body slot's buffers to hold nverts / ntris (contents not kept) */
static void body_reserve(sq_render_body *b, int nverts, int ntris)
{
    if (nverts > b->cap_verts) {
        free(b->xyz);
        free(b->rest);
        free(b->level);
        b->xyz = sq_malloc((size_t)nverts * 3 * sizeof(float));
        b->rest = sq_malloc((size_t)nverts * 3 * sizeof(float));
        b->level = sq_malloc((size_t)nverts);
        b->cap_verts = nverts;
    }
    if (ntris > b->cap_tris) {
        free(b->tris);
        b->tris = sq_malloc((size_t)ntris * 3 * sizeof(int));
        b->cap_tris = ntris;
    }
}

int sq_render_state_add_body(sq_render_state *s, int nverts, const float *xyz, const float *rest,
                             const unsigned char *level, int ntris, const int *tris, sq_err *err)
{
    if (s->nbodies >= SQ_MAX_BODIES)
        return sq_err_set(err, "render state: more than %d bodies", SQ_MAX_BODIES);
    if (nverts < 0 || ntris < 0 || (nverts > 0 && !xyz) || (ntris > 0 && !tris))
        return sq_err_set(err, "render state: body %d: bad counts (%d vertices, %d triangles) "
                          "or missing arrays", s->nbodies, nverts, ntris);
    const float *r = rest ? rest : xyz;
    for (int i = 0; i < 3 * nverts; i++)
        if (!isfinite(r[i]))
            return sq_err_set(err, "render state: body %d: vertex %d has a non-finite rest "
                              "position", s->nbodies, i / 3);
    for (int i = 0; i < 3 * ntris; i++)
        if (tris[i] < 0 || tris[i] >= nverts)
            return sq_err_set(err, "render state: body %d: triangle %d uses vertex %d, outside "
                              "[0, %d)", s->nbodies, i / 3, tris[i], nverts);

    sq_render_body *b = &s->bodies[s->nbodies];
    body_reserve(b, nverts, ntris);
    b->nverts = nverts;
    b->ntris = ntris;
    if (nverts > 0) {
        memcpy(b->xyz, xyz, (size_t)nverts * 3 * sizeof(float));
        memcpy(b->rest, r, (size_t)nverts * 3 * sizeof(float));
        if (level)
            memcpy(b->level, level, (size_t)nverts);
        else
            memset(b->level, 0, (size_t)nverts);
    }
    if (ntris > 0)
        memcpy(b->tris, tris, (size_t)ntris * 3 * sizeof(int));

    /* the rest bounding box of all bodies (started by the first vertex of any body) */
    int have_box = 0;
    for (int j = 0; j < s->nbodies; j++)
        have_box |= s->bodies[j].nverts > 0;
    for (int i = 0; i < nverts; i++)
        for (int k = 0; k < 3; k++) {
            double v = r[3 * i + k];
            int first = !have_box && i == 0;
            if (first || v < s->bbox_min[k])
                s->bbox_min[k] = v;
            if (first || v > s->bbox_max[k])
                s->bbox_max[k] = v;
        }
    s->nbodies++;
    return 0;
}

int sq_render_state_add_tool(sq_render_state *s, const sq_tool *t, sq_err *err)
{
    if (s->ntools >= SQ_MAX_TOOLS)
        return sq_err_set(err, "render state: more than %d tools", SQ_MAX_TOOLS);
    s->tools[s->ntools++] = *t;
    return 0;
}

/* copy o into slot r, a mesh's triangles into r's buffers (grown as needed) */
static void obstacle_copy(sq_render_obstacle *r, const sq_obstacle *o)
{
    r->shape = *o;
    r->shape.mesh = NULL;
    r->nverts = r->ntris = 0;
    const sq_trimesh *m = o->kind == SQ_OBSTACLE_MESH ? o->mesh : NULL;
    if (!m)
        return;
    if (m->nverts > r->cap_verts) {
        free(r->xyz);
        r->xyz = sq_malloc((size_t)m->nverts * 3 * sizeof(float));
        r->cap_verts = m->nverts;
    }
    if (m->ntris > r->cap_tris) {
        free(r->tris);
        r->tris = sq_malloc((size_t)m->ntris * 3 * sizeof(int));
        r->cap_tris = m->ntris;
    }
    for (int i = 0; i < 3 * m->nverts; i++)
        r->xyz[i] = (float)m->x[i];
    memcpy(r->tris, m->tris, (size_t)m->ntris * 3 * sizeof(int));
    r->nverts = m->nverts;
    r->ntris = m->ntris;
}

int sq_render_state_add_obstacle(sq_render_state *s, const sq_obstacle *o, sq_err *err)
{
    if (s->nobstacles >= SQ_MAX_OBSTACLES)
        return sq_err_set(err, "render state: more than %d obstacles", SQ_MAX_OBSTACLES);
    if (sq_obstacle_check(o, err) != 0)
        return -1;
    obstacle_copy(&s->obstacles[s->nobstacles++], o);
    return 0;
}

int sq_render_state_add_probe(sq_render_state *s, const double p[3], sq_err *err)
{
    if (s->nprobes >= SQ_MAX_PROBES)
        return sq_err_set(err, "render state: more than %d probes", SQ_MAX_PROBES);
    memcpy(s->probes[s->nprobes++], p, sizeof s->probes[0]);
    return 0;
}

void sq_render_state_set_gravity(sq_render_state *s, const double g[3])
{
    double n = sqrt(g[0] * g[0] + g[1] * g[1] + g[2] * g[2]);
    if (!(n > 1e-12) || !isfinite(n)) {
        s->up[0] = 0.0;
        s->up[1] = 0.0;
        s->up[2] = 1.0;
        return;
    }
    for (int k = 0; k < 3; k++)
        s->up[k] = -g[k] / n;
}

int sq_render_state_capture(sq_render_state *s, const sq_world *w, sq_err *err)
{
    s->nbodies = 0;
    s->ntools = 0;
    s->nprobes = 0;
    s->nobstacles = 0;
    if (w->nbodies > SQ_MAX_BODIES)
        return sq_err_set(err, "render capture: world has %d bodies, more than %d", w->nbodies,
                          SQ_MAX_BODIES);
    int have_box = 0;
    for (int bi = 0; bi < w->nbodies; bi++) {
        const sq_body *body = w->bodies[bi];
        const sq_mesh *m = sq_body_surface_mesh(body);
        sq_render_body *b = &s->bodies[bi];
        body_reserve(b, m->nsurf, m->ntris);
        b->nverts = m->nsurf;
        b->ntris = m->ntris;
        /* levels as numbered in the scene file (a fixed body loads only its listed level) */
        sq_world_surface_state(w, bi, b->xyz, b->level);
        for (int i = 0; i < m->nsurf; i++)
            for (int k = 0; k < 3; k++) {
                double v = m->x[3 * m->surf_nodes[i] + k];
                b->rest[3 * i + k] = (float)v;
                if (!have_box || v < s->bbox_min[k])
                    s->bbox_min[k] = v;
                if (!have_box || v > s->bbox_max[k])
                    s->bbox_max[k] = v;
                have_box |= k == 2;
            }
        memcpy(b->tris, m->surf_tris, (size_t)m->ntris * 3 * sizeof(int));
        s->nbodies++;
    }
    if (!have_box)
        for (int k = 0; k < 3; k++)
            s->bbox_min[k] = s->bbox_max[k] = 0.0;
    s->ntools = SQ_MIN(w->ntools, SQ_MAX_TOOLS);
    memcpy(s->tools, w->tools, (size_t)s->ntools * sizeof(sq_tool));
    /* obstacles at their current poses (the world's table holds them at w->time) */
    for (int i = 0; i < w->nobstacles && i < SQ_MAX_OBSTACLES; i++)
        obstacle_copy(&s->obstacles[s->nobstacles++], &w->obstacles[i]);
    /* probes where they are now: rest point plus the body's displacement there */
    for (int i = 0; w->scene && i < w->scene->nprobes && s->nprobes < SQ_MAX_PROBES; i++) {
        double u[3];
        if (sq_world_probe(w, i, u) != 0)
            continue;
        const double *x = w->scene->probes[i].point;
        double p[3] = {x[0] + u[0], x[1] + u[1], x[2] + u[2]};
        if (isfinite(p[0]) && isfinite(p[1]) && isfinite(p[2]))
            memcpy(s->probes[s->nprobes++], p, sizeof p);
    }
    if (w->scene)
        sq_render_state_set_gravity(s, w->scene->gravity);
    else if (w->nbodies > 0)
        sq_render_state_set_gravity(s, sq_body_get_def(w->bodies[0])->gravity);
    else
        s->up[0] = s->up[1] = 0.0, s->up[2] = 1.0;
    s->frame = w->frame;
    s->time = w->time;
    return 0;
}
