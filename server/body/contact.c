/* contact.c - a body's contacts (docs/physics.md section 13): its simulated level's surface
 * nodes against the world's obstacles at every step, and against another body's surface once
 * per frame. The method is contact/contact.h's. */
#include <math.h>
#include <string.h>

#include "body/body_internal.h"

void sq_body_set_obstacles(sq_body *b, const sq_obstacle *obs, int n)
{
    b->obstacles = n > 0 ? obs : NULL;
    b->nobstacles = n > 0 ? n : 0;
}

static sq_contact_nodes surface_nodes(const sq_level *L, const unsigned char *mask)
{
    const sq_mesh *m = L->model.mesh;
    sq_contact_nodes nd = {.n = m->nsurf, .list = m->surf_nodes, .X = m->x, .mass = L->model.mass,
                           .fixed = L->model.fixed, .mask = mask};
    return nd;
}

void sq_body_contact_step(sq_body *b, sq_level *L, const unsigned char *mask, double h)
{
    if (!b->nobstacles)
        return;
    double t0 = sq_thread_cpu();
    sq_contact_nodes nd = surface_nodes(L, mask);
    if (!b->ccache)
        b->ccache = sq_contact_cache_create();
    nd.cache = b->ccache;
    sq_contact_step(b->obstacles, b->nobstacles, &nd, L->d, L->v, h, &b->contact);
    b->contact_cpu += sq_thread_cpu() - t0;
}

double sq_body_contact_cpu(const sq_body *b)
{
    return b->contact_cpu;
}

void sq_body_contact_free(sq_body *b)
{
    sq_contact_cache_free(b->ccache);
    b->ccache = NULL;
    for (int k = 0; k < SQ_MAX_LEVELS; k++) {
        sq_contact_surface_free(b->csurf[k]);
        b->csurf[k] = NULL;
    }
}

void sq_body_contact_force(const sq_body *b, double force[3], int *nodes, double *depth)
{
    for (int c = 0; c < 3; c++)
        force[c] = b->contact.impulse[c] / b->def.frame_dt;
    if (nodes)
        *nodes = b->contact.nodes;
    if (depth)
        *depth = b->contact.depth;
}

static sq_contact_side side_of(sq_body *b, sq_contact_nodes *nd)
{
    int k = b->cur;
    sq_level *L = &b->level[k];
    const sq_mesh *m = L->model.mesh;
    if (!b->csurf[k])
        b->csurf[k] = sq_contact_surface_create(m->nnodes, m->ntris, m->tris);
    /* nodes a tool holds this frame move with the tool: infinite mass to the other body */
    *nd = surface_nodes(L, b->nheld[k] ? b->mask[k] : NULL);
    sq_contact_side s = {.surf = b->csurf[k], .nodes = nd, .d = L->d, .v = L->v};
    return s;
}

static double mean_edge(const sq_body *b)
{
    const sq_level *L = &b->level[b->cur];
    const sq_mesh *m = L->model.mesh;
    double s = 0;
    for (int k = 0; k < m->nsurf; k++)
        s += L->model.hbar[m->surf_nodes[k]];
    return m->nsurf ? s / m->nsurf : 0;
}

int sq_body_contact_pair(sq_body *a, sq_body *b, double mu)
{
    if (a->lod || b->lod || a->sleeping + b->sleeping == 2)
        return 0;
    double t0 = sq_thread_cpu();
    sq_contact_nodes na, nb;
    sq_contact_side sa = side_of(a, &na), sb = side_of(b, &nb);
    double reach = 2 * SQ_MAX(mean_edge(a), mean_edge(b));
    int n = sq_contact_bodies(&sa, &sb, mu, reach, a->def.frame_dt, &a->contact, &b->contact);
    double dt = sq_thread_cpu() - t0;
    a->contact_cpu += dt / 2;
    b->contact_cpu += dt / 2;
    if (n) { /* a contact wakes both */
        a->sleeping = b->sleeping = 0;
        a->calm = b->calm = 0;
    }
    return n;
}

double sq_body_contact_depth(sq_body *a, sq_body *b)
{
    if (a->lod || b->lod)
        return 0;
    sq_contact_nodes na, nb;
    sq_contact_side sa = side_of(a, &na), sb = side_of(b, &nb);
    return sq_contact_depth(&sa, &sb, 2 * mean_edge(b));
}
