/* contact.c - a body's contacts (docs/physics.md section 13): its simulated level's surface
 * nodes against the world's obstacles at every step, and against another body's surface once
 * at every step too, with the other bodies' surfaces as targets. The method is
 * contact/contact.h's. */
#include <math.h>
#include <stdlib.h>
#include <string.h>

#include "lod/lod.h"
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
    if (b->def.integrator == SQ_INTEGRATOR_IMPLICIT && b->nobstacles) {
        if (b->cpoint_n != L->model.n) {
            free(b->cpoint);
            b->cpoint = sq_calloc((size_t)L->model.n, sizeof *b->cpoint);
            b->cpoint_n = L->model.n;
            b->ncon = 0;
        }
        nd.points = b->cpoint;
        nd.stamp = ++b->cstamp;
    }
    if (b->nobstacles)
        sq_contact_step(b->obstacles, b->nobstacles, &nd, L->state.d, L->state.v, h, &b->contact);
    if (b->ntargets)
        sq_contact_step_targets(b->targets, b->ntargets, &nd, L->state.d, L->state.v, h, &b->contact);
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

/* the next solve's constraints: the last solve's that still pushed (a resting node the solve
 * held on the surface is not inside it, so the pass does not meet it again), with their kind
 * (sticking or sliding), and the nodes the last obstacle pass met, new ones sliding */
static double con_jn(const sq_body *b, int k)
{
    const double *J = b->con_imp + 3 * (size_t)k, *n = b->con_pt[k].n;
    return J[0] * n[0] + J[1] * n[1] + J[2] * n[2];
}

void sq_body_contact_constraints(sq_body *b, sq_level *L, double h)
{
    sq_level_implicit_set_contacts(&L->model, &L->state, NULL);
    const int n = L->model.n;
    if (!b->nobstacles || !b->cpoint || b->cpoint_n != n)
        return;
    if (!b->con_mark) {
        const size_t ns = (size_t)(n > 0 ? n : 1);
        b->con_mark = sq_calloc(ns, sizeof(int));
        b->con_stick = sq_calloc(ns, 1);
        b->con_node = sq_malloc(ns * sizeof(int));
        b->con_pt = sq_malloc(ns * sizeof(sq_contact_point));
        b->con_normal = sq_malloc(3 * ns * sizeof(double));
        b->con_u = sq_malloc(3 * ns * sizeof(double));
        b->con_imp = sq_calloc(3 * ns, sizeof(double));
        b->con_f = sq_calloc(3 * ns, sizeof(double));
        b->con_vrel = sq_calloc(ns, sizeof(double));
    }
    int m = 0;
    for (int k = 0; k < b->ncon; k++) /* kept: pushed in the last solve */
        if (con_jn(b, k) > 0) {
            const int i = b->con_node[k];
            b->con_node[m] = i;
            b->con_pt[m] = b->con_pt[k];
            b->con_stick[m] = b->con_stick[k];
            b->con_vrel[m] = 0;
            memmove(b->con_f + 3 * (size_t)m, b->con_f + 3 * (size_t)k, 3 * sizeof(double));
            b->con_mark[i] = m + 1;
            m++;
        }
    for (int i = 0; i < n; i++) /* met by the last pass (its normal replaces a kept one's) */
        if (b->cstamp > 0 && b->cpoint[i].stamp == b->cstamp) {
            if (b->con_mark[i]) {
                b->con_pt[b->con_mark[i] - 1] = b->cpoint[i];
                continue;
            }
            b->con_node[m] = i;
            b->con_pt[m] = b->cpoint[i];
            b->con_stick[m] = 0;
            b->con_f[3 * (size_t)m] = b->con_f[3 * (size_t)m + 1] = b->con_f[3 * (size_t)m + 2] = 0;
            b->con_mark[i] = m + 1;
            b->con_vrel[m] = 0;
            m++;
        }
    /* speculative: a surface node outside an obstacle that would cross its surface within the
     * step (its approach speed with one step of gravity) lands on it at the step's end: its normal
     * velocity relative to the obstacle is prescribed to -phi / h. Without this the stiff body's
     * other nodes go on for a whole step after its surface nodes were stopped (compression
     * energy out of nothing) */
    const sq_mesh *mesh = L->model.mesh;
    const unsigned char *mask = b->nheld[b->cur] ? b->mask[b->cur] : NULL;
    const double *g = b->def.gravity;
    for (int s = 0; s < mesh->nsurf; s++) {
        const int i = mesh->surf_nodes[s];
        if (b->con_mark[i] || L->model.fixed[i] || (mask && !mask[i]))
            continue;
        double x[3];
        for (int c = 0; c < 3; c++)
            x[c] = mesh->x[3 * (size_t)i + c] + L->state.d[3 * (size_t)i + c];
        for (int o = 0; o < b->nobstacles; o++) {
            const sq_obstacle *ob = &b->obstacles[o];
            double nrm[3];
            const double phi = sq_obstacle_distance(ob, x, nrm);
            if (!(phi >= 0) || !isfinite(phi))
                continue;
            double vn = 0;
            for (int c = 0; c < 3; c++)
                vn += (L->state.v[3 * (size_t)i + c] - ob->velocity[c] + h * g[c]) * nrm[c];
            if (!(vn < 0 && phi + h * vn < 0))
                continue;
            b->con_pt[m] = sq_contact_point_at(ob, o, nrm, 0);
            b->con_node[m] = i;
            b->con_stick[m] = 0;
            b->con_f[3 * (size_t)m] = b->con_f[3 * (size_t)m + 1] = b->con_f[3 * (size_t)m + 2] = 0;
            b->con_vrel[m] = -phi / h;
            b->con_mark[i] = m + 1;
            m++;
            break;
        }
    }
    for (int k = 0; k < m; k++) {
        const sq_contact_point *p = &b->con_pt[k];
        b->con_mark[b->con_node[k]] = 0;
        memcpy(b->con_normal + 3 * (size_t)k, p->n, sizeof p->n);
        for (int c = 0; c < 3; c++)
            b->con_u[3 * (size_t)k + c] = p->u[c] + b->con_vrel[k] * p->n[c];
    }
    b->ncon = m;
    b->con_set = (sq_implicit_contacts){.n = m, .node = b->con_node, .normal = b->con_normal, .u = b->con_u,
                                        .stick = b->con_stick, .force = b->con_f, .impulse = b->con_imp};
    sq_level_implicit_set_contacts(&L->model, &L->state, &b->con_set);
}

void sq_body_contact_constrained(sq_body *b, sq_level *L, double h)
{
    if (!b->ncon)
        return;
    double t0 = sq_thread_cpu();
    sq_contact_constrained(b->con_pt, b->ncon, b->con_node, b->con_imp, b->con_stick, b->con_f, L->model.mass, L->state.d,
                           L->state.v, h, &b->contact);
    for (int k = 0; k < b->ncon; k++)
        if (con_jn(b, k) > 0 && b->touched[b->cur])
            b->touched[b->cur][b->con_node[k]] = 1;
    b->contact_cpu += sq_thread_cpu() - t0;
}

void sq_body_contact_retry(sq_body *b)
{
    b->ncon = 0;
    for (int g = 0; g < b->ntargets; g++)
        memset(b->targets[g].reaction, 0, sizeof(double) * 3 * (size_t)b->targets[g].n);
}

void sq_body_set_targets(sq_body *b, const sq_contact_target *t, int n)
{
    b->targets = n > 0 ? t : NULL;
    b->ntargets = n > 0 ? n : 0;
}

static double mean_edge(const sq_body *b);

/* the reactions' array for n3 entries (zeroed when it is made) */
static void reaction_of(sq_body *b, size_t n3)
{
    if (b->reaction_n3 != n3) {
        free(b->reaction);
        b->reaction = sq_calloc(n3 ? n3 : 1, sizeof(double));
        b->reaction_n3 = n3;
    }
}

/* an adaptive body's target: the finest level's surface where the frame's push left it (the
 * finest surface nodes are always pushed: the rendered surface), read through lod's map as
 * combinations of the active nodes, so the impulses on it go to the active nodes through the
 * transpose (sq_lod_surface_map_get); the unknowns' velocities copied (the contact pass reads
 * them with the reactions so far) */
static int lod_target(sq_body *b, double mu, sq_contact_target *out)
{
    const double t0 = sq_thread_cpu(); /* the map, the copies and the refit: contact time */
    const int F = b->fine;
    sq_level *Lf = &b->level[F];
    const sq_mesh *m = Lf->model.mesh;
    const sq_lod_surface_map *map = sq_lod_surface_map_get(b->lod);
    const int nd = map->ndof;
    if (b->tdof_cap < nd) {
        b->tdof_cap = SQ_MAX(nd, 2 * b->tdof_cap);
        b->tdof_v = sq_realloc(b->tdof_v, sizeof(double) * 3 * (size_t)b->tdof_cap);
        b->tdof_mass = sq_realloc(b->tdof_mass, sizeof(double) * (size_t)b->tdof_cap);
        b->tdof_fixed = sq_realloc(b->tdof_fixed, (size_t)b->tdof_cap);
        b->tdof_mask = sq_realloc(b->tdof_mask, (size_t)b->tdof_cap);
    }
    for (int q = 0; q < nd; q++) {
        const int k = map->level[q], i = map->node[q];
        b->tdof_mask[q] = 1;
        if (k < 0) { /* the anchor: constrained, moves nothing */
            b->tdof_v[3 * q] = b->tdof_v[3 * q + 1] = b->tdof_v[3 * q + 2] = 0;
            b->tdof_mass[q] = 1;
            b->tdof_fixed[q] = 1;
            continue;
        }
        const sq_level *L = &b->level[k];
        memcpy(b->tdof_v + 3 * (size_t)q, L->state.v + 3 * (size_t)i, 3 * sizeof(double));
        b->tdof_mass[q] = L->model.mass[i];
        b->tdof_fixed[q] = L->model.fixed[i];
    }
    /* held nodes are not marked: as a fixed body's target, whose mask is restored to all ones
     * by the frame's end (docs/physics.md section 13, "What is not done") */
    reaction_of(b, 3 * (size_t)nd);
    if (!b->csurf[F])
        b->csurf[F] = sq_contact_surface_create(m->nnodes, m->ntris, m->tris);
    sq_contact_surface_update(b->csurf[F], m->x, Lf->state.d);
    b->contact_cpu += sq_thread_cpu() - t0;
    b->tmap = map;
    *out = (sq_contact_target){.n = nd, .surf = b->csurf[F], .v = b->tdof_v, .mass = b->tdof_mass,
                               .fixed = b->tdof_fixed, .mask = b->tdof_mask, .reaction = b->reaction, .mu = mu,
                               .reach = 2 * mean_edge(b), .map_start = map->start, .map_dof = map->dof,
                               .map_w = map->w};
    return 0;
}

int sq_body_contact_target(sq_body *b, double mu, sq_contact_target *out)
{
    if (b->lod)
        return lod_target(b, mu, out);
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
    sq_contact_surface_update(b->csurf[k], m->x, L->state.d);
    b->contact_cpu += sq_thread_cpu() - t0;
    *out = (sq_contact_target){.n = L->model.n, .surf = b->csurf[k], .v = L->state.v, .mass = L->model.mass,
                               .fixed = L->model.fixed, .mask = b->nheld[k] ? b->mask[k] : NULL,
                               .reaction = b->reaction, .mu = mu, .reach = 2 * mean_edge(b)};
    return 0;
}

/* an adaptive target's reactions: each unknown's impulse (the transpose of the map) as a
 * velocity change M^-1 J of its active node; the anchor's and constrained nodes' are counted
 * only. Returns whether any was left */
static int apply_lod(sq_body *b, double sum[3])
{
    const sq_lod_surface_map *map = b->tmap;
    int any = 0;
    for (int q = 0; map && 3 * (size_t)q < b->reaction_n3 && q < map->ndof; q++) {
        double *r = b->reaction + 3 * (size_t)q;
        if (r[0] == 0 && r[1] == 0 && r[2] == 0)
            continue;
        any = 1;
        const int k = map->level[q], i = map->node[q];
        if (k >= 0 && !b->tdof_fixed[q] && b->tdof_mask[q]) {
            sq_level *L = &b->level[k];
            for (int c = 0; c < 3; c++)
                L->state.v[3 * (size_t)i + c] += r[c] / L->model.mass[i];
        }
        for (int c = 0; c < 3; c++)
            sum[c] += r[c];
        r[0] = r[1] = r[2] = 0;
    }
    return any;
}

void sq_body_contact_apply(sq_body *b, int before_frame)
{
    if (!b->reaction)
        return;
    sq_level *L = &b->level[b->cur];
    const unsigned char *mask = b->nheld[b->cur] ? b->mask[b->cur] : NULL;
    double sum[3] = {0, 0, 0};
    int any = 0;
    if (b->lod)
        any = apply_lod(b, sum);
    else
        for (int i = 0; i < L->model.n; i++) {
            double *r = b->reaction + 3 * (size_t)i;
            if (r[0] == 0 && r[1] == 0 && r[2] == 0)
                continue;
            any = 1;
            if (!L->model.fixed[i] && !(mask && !mask[i]))
                for (int c = 0; c < 3; c++)
                    L->state.v[3 * (size_t)i + c] += r[c] / L->model.mass[i];
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
    void *con[] = {b->cpoint, b->con_node, b->con_pt, b->con_normal, b->con_u, b->con_imp, b->con_mark, b->con_stick, b->con_f, b->con_vrel};
    for (size_t k = 0; k < sizeof con / sizeof con[0]; k++)
        free(con[k]);
    b->cpoint = NULL;
    b->con_node = NULL;
    b->con_pt = NULL;
    b->con_normal = b->con_u = b->con_imp = b->con_f = b->con_vrel = NULL;
    b->con_mark = NULL;
    b->con_stick = NULL;
    b->cpoint_n = b->ncon = 0;
    free(b->reaction);
    b->reaction = NULL;
    b->reaction_n3 = 0;
    free(b->tdof_v);
    free(b->tdof_mass);
    free(b->tdof_fixed);
    free(b->tdof_mask);
    b->tdof_v = b->tdof_mass = NULL;
    b->tdof_fixed = b->tdof_mask = NULL;
    b->tdof_cap = 0;
    b->tmap = NULL;
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
    int k = sq_body_sim_level(b); /* adaptive: the finest surface where the push left it */
    sq_level *L = &b->level[k];
    const sq_mesh *m = L->model.mesh;
    if (!b->csurf[k])
        b->csurf[k] = sq_contact_surface_create(m->nnodes, m->ntris, m->tris);
    /* nodes a tool holds this frame move with the tool: infinite mass to the other body */
    *nd = surface_nodes(L, b->nheld[k] ? b->mask[k] : NULL);
    sq_contact_side s = {.surf = b->csurf[k], .nodes = nd, .d = L->state.d, .v = L->state.v};
    return s;
}

static double mean_edge(const sq_body *b)
{
    const sq_level *L = &b->level[sq_body_sim_level(b)];
    const sq_mesh *m = L->model.mesh;
    double s = 0;
    for (int k = 0; k < m->nsurf; k++)
        s += L->model.hbar[m->surf_nodes[k]];
    return m->nsurf ? s / m->nsurf : 0;
}

double sq_body_contact_depth(sq_body *a, sq_body *b)
{
    sq_contact_nodes na, nb;
    sq_contact_side sa = side_of(a, &na), sb = side_of(b, &nb);
    return sq_contact_depth(&sa, &sb, 2 * mean_edge(b));
}
