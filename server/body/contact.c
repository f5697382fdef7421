/* contact.c - a body's contacts (docs/physics.md section 13): its simulated level's surface
 * nodes against the world's obstacles at every step, and against another body's surface once
 * at every step too, with the other bodies' surfaces as targets. The method is
 * contact/contact.h's. */
#include <math.h>
#include <stdlib.h>
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
    if (!b->nobstacles && !b->ntargets)
        return;
    double t0 = sq_thread_cpu();
    sq_contact_nodes nd = surface_nodes(L, mask);
    if (!b->ccache)
        b->ccache = sq_contact_cache_create();
    nd.cache = b->ccache;
    nd.touched = b->touched[b->cur];
    if (b->nobstacles)
        sq_contact_step(b->obstacles, b->nobstacles, &nd, L->d, L->v, h, &b->contact);
    if (b->ntargets)
        sq_contact_step_targets(b->targets, b->ntargets, &nd, L->d, L->v, h, &b->contact);
    b->contact_cpu += sq_thread_cpu() - t0;
}

void sq_body_contact_begin(sq_body *b)
{
    for (int k = 0; k < SQ_MAX_LEVELS; k++) {
        int n = b->ready[k] ? b->level[k].model.n : 0;
        if (!n || (!b->nobstacles && !b->ntargets)) {
            if (b->touched[k])
                memset(b->touched[k], 0, (size_t)b->touched_n[k]);
            continue;
        }
        if (b->touched_n[k] != n) {
            free(b->touched[k]);
            b->touched[k] = sq_malloc((size_t)n);
            b->touched_n[k] = n;
        }
        memset(b->touched[k], 0, (size_t)n);
    }
}

void sq_body_contact_retry(sq_body *b)
{
    for (int g = 0; g < b->ntargets; g++)
        memset(b->targets[g].reaction, 0, sizeof(double) * 3 * (size_t)b->targets[g].n);
}

void sq_body_set_targets(sq_body *b, const sq_contact_target *t, int n)
{
    b->targets = n > 0 ? t : NULL;
    b->ntargets = n > 0 ? n : 0;
}

static double mean_edge(const sq_body *b);

int sq_body_contact_target(sq_body *b, double mu, sq_contact_target *out)
{
    if (b->lod)
        return -1;
    int k = b->cur;
    sq_level *L = &b->level[k];
    const sq_mesh *m = L->model.mesh;
    size_t n3 = 3 * (size_t)L->model.n;
    if (b->reaction_n3 != n3) {
        free(b->reaction);
        b->reaction = sq_calloc(n3, sizeof(double));
        b->reaction_n3 = n3;
    }
    if (!b->csurf[k])
        b->csurf[k] = sq_contact_surface_create(m->nnodes, m->ntris, m->tris);
    double t0 = sq_thread_cpu();
    sq_contact_surface_update(b->csurf[k], m->x, L->d);
    b->contact_cpu += sq_thread_cpu() - t0;
    *out = (sq_contact_target){.n = L->model.n, .surf = b->csurf[k], .v = L->v, .mass = L->model.mass,
                               .fixed = L->model.fixed, .mask = b->nheld[k] ? b->mask[k] : NULL,
                               .reaction = b->reaction, .mu = mu, .reach = 2 * mean_edge(b)};
    return 0;
}

void sq_body_contact_apply(sq_body *b, int before_frame)
{
    if (!b->reaction || b->lod)
        return;
    sq_level *L = &b->level[b->cur];
    const unsigned char *mask = b->nheld[b->cur] ? b->mask[b->cur] : NULL;
    double sum[3] = {0, 0, 0};
    int any = 0;
    for (int i = 0; i < L->model.n; i++) {
        double *r = b->reaction + 3 * (size_t)i;
        if (r[0] == 0 && r[1] == 0 && r[2] == 0)
            continue;
        any = 1;
        if (!L->model.fixed[i] && !(mask && !mask[i]))
            for (int c = 0; c < 3; c++)
                L->v[3 * (size_t)i + c] += r[c] / L->model.mass[i];
        for (int c = 0; c < 3; c++)
            sum[c] += r[c];
        r[0] = r[1] = r[2] = 0;
    }
    for (int c = 0; c < 3; c++) {
        if (before_frame)
            b->carry[c] += sum[c];
        else
            b->contact.impulse[c] += sum[c];
    }
    if (any && b->sleeping) { /* pushed by another body: awake */
        b->sleeping = 0;
        b->calm = 0;
    }
}

double sq_body_contact_cpu(const sq_body *b)
{
    return b->contact_cpu;
}

void sq_body_contact_free(sq_body *b)
{
    free(b->reaction);
    b->reaction = NULL;
    for (int k = 0; k < SQ_MAX_LEVELS; k++) {
        free(b->touched[k]);
        b->touched[k] = NULL;
        b->touched_n[k] = 0;
    }
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

double sq_body_contact_depth(sq_body *a, sq_body *b)
{
    if (a->lod || b->lod)
        return 0;
    sq_contact_nodes na, nb;
    sq_contact_side sa = side_of(a, &na), sb = side_of(b, &nb);
    return sq_contact_depth(&sa, &sb, 2 * mean_edge(b));
}
