/* resolve.c - contact of a body's surface nodes with the obstacles (once per substep) and with
 * another body's surface (once per frame): docs/physics.md section 13. */
#include <math.h>
#include <stdlib.h>
#include <string.h>

#include "contact/contact_internal.h"

static inline double dot3(const double a[3], const double b[3])
{
    return a[0] * b[0] + a[1] * b[1] + a[2] * b[2];
}

/* Coulomb friction on a tangential velocity vt given the normal velocity change dvn (>= 0) it may
 * lean on: stick (vt -> 0) when |vt| <= mu_s dvn, else slide with |vt| reduced by mu_k dvn */
static void friction(double vt[3], double dvn, double mu_s, double mu_k)
{
    double s = sqrt(dot3(vt, vt));
    if (s <= mu_s * dvn || s <= 1e-300) {
        vt[0] = vt[1] = vt[2] = 0;
        return;
    }
    double k = 1 - mu_k * dvn / s;
    k = k < 0 ? 0 : k;
    for (int c = 0; c < 3; c++)
        vt[c] *= k;
}

struct sq_contact_cache {
    int valid, cap;
    double *start;  /* position at the frame's first pass (list order, x 3) */
    double *radius; /* distance then to the nearest mesh obstacle (0: always query) */
    int *tri;       /* a node near one mesh obstacle's flat part: its nearest triangle, else -1 */
    int *tri_obs;   /* that obstacle */
    double *flat;   /* how far the node may move from start and the triangle's plane still be the
                       whole mesh near it (every triangle within 2 flat of start lies in it) */
};

sq_contact_cache *sq_contact_cache_create(void)
{
    return sq_calloc(1, sizeof(sq_contact_cache));
}

void sq_contact_cache_free(sq_contact_cache *c)
{
    if (!c)
        return;
    free(c->start);
    free(c->radius);
    free(c->tri);
    free(c->tri_obs);
    free(c->flat);
    free(c);
}

void sq_contact_cache_reset(sq_contact_cache *c)
{
    if (c)
        c->valid = 0;
}

/* the cache's distances from the nodes' current positions (the frame's first pass) */
static void cache_fill(sq_contact_cache *c, const sq_obstacle *obs, int nobs, const sq_contact_nodes *nodes,
                       const double *d)
{
    if (c->cap < nodes->n) {
        c->cap = nodes->n;
        c->start = sq_realloc(c->start, sizeof(double) * 3 * (size_t)c->cap);
        c->radius = sq_realloc(c->radius, sizeof(double) * (size_t)c->cap);
        c->tri = sq_realloc(c->tri, sizeof(int) * (size_t)c->cap);
        c->tri_obs = sq_realloc(c->tri_obs, sizeof(int) * (size_t)c->cap);
        c->flat = sq_realloc(c->flat, sizeof(double) * (size_t)c->cap);
    }
    for (int k = 0; k < nodes->n; k++) {
        int i = nodes->list[k];
        double *x = c->start + 3 * (size_t)k, r = INFINITY;
        for (int a = 0; a < 3; a++)
            x[a] = nodes->X[3 * (size_t)i + a] + d[3 * (size_t)i + a];
        int near = 0, near_obs = -1;
        for (int o = 0; o < nobs; o++)
            if (obs[o].kind == SQ_OBSTACLE_MESH) {
                double n[3], phi = sq_obstacle_distance(&obs[o], x, n);
                r = fmin(r, phi > 0 ? phi : 0); /* beyond the thickness: +inf, behind: 0 */
                if (isfinite(phi)) {
                    near++;
                    near_obs = o;
                }
            }
        c->radius[k] = r;
        c->tri[k] = -1;
        if (near == 1) { /* one mesh near: is it flat around the node (a tray's floor)? */
            const sq_obstacle *ob = &obs[near_obs];
            const sq_trimesh *m = ob->mesh;
            double dist, q[3], bary[3];
            int t = sq_trimesh_nearest(m, x, ob->thickness, &dist, q, bary);
            if (t >= 0 && dist < 0.25 * ob->thickness) { /* close enough to touch within the frame */
                /* the flat radius: half the triangle's shortest edge (a node at rest moves far
                 * less in a frame; one that moves more asks the hierarchy), so few triangles
                 * are tested for the plane */
                const int *tv = m->tris + 3 * (size_t)t;
                double e2 = INFINITY;
                for (int j = 0; j < 3; j++) {
                    const double *a = m->x + 3 * (size_t)tv[j], *b = m->x + 3 * (size_t)tv[(j + 1) % 3];
                    double s2 = 0;
                    for (int a3 = 0; a3 < 3; a3++)
                        s2 += (b[a3] - a[a3]) * (b[a3] - a[a3]);
                    e2 = fmin(e2, s2);
                }
                const double rho = fmin(0.25 * ob->thickness, 0.5 * sqrt(e2));
                const double *tn = m->normal + 3 * (size_t)t;
                double off = dot3(tn, m->x + 3 * (size_t)m->tris[3 * t]);
                if (sq_bvh_coplanar_within(m->bvh, m->x, m->tris, m->normal, x, dist + 2 * rho, tn, off)) {
                    c->tri[k] = t;
                    c->tri_obs[k] = near_obs;
                    c->flat[k] = rho;
                }
            }
        }
    }
    c->valid = 1;
}

/* the mesh obstacle's distance at x from the cached triangle, when x is still within the flat
 * radius of the cache's start and projects onto the closed triangle (then the triangle's plane is
 * the nearest surface: every triangle that could be nearer lies in it); 0 to query the hierarchy */
static int flat_distance(const sq_contact_cache *c, int k, const sq_obstacle *ob, const double x[3], double *phi,
                         double n[3])
{
    const double *x0 = c->start + 3 * (size_t)k;
    double s = 0;
    for (int a = 0; a < 3; a++)
        s += (x[a] - x0[a]) * (x[a] - x0[a]);
    if (!(s < c->flat[k] * c->flat[k]))
        return 0;
    const sq_trimesh *m = ob->mesh;
    const int t = c->tri[k], *v = m->tris + 3 * (size_t)t;
    double q[3], w[3];
    double d2 = sq_closest_on_triangle(x, m->x + 3 * (size_t)v[0], m->x + 3 * (size_t)v[1], m->x + 3 * (size_t)v[2],
                                       q, w);
    const double *tn = m->normal + 3 * (size_t)t;
    double side = (x[0] - q[0]) * tn[0] + (x[1] - q[1]) * tn[1] + (x[2] - q[2]) * tn[2];
    if (!(d2 <= side * side * (1 + 1e-9) + 1e-24))
        return 0; /* the plane's foot is outside the triangle (the closest point is not on the
                     normal through x): the hierarchy decides */
    memcpy(n, tn, sizeof(double) * 3);
    *phi = side >= 0 ? side : -side <= ob->thickness ? side : INFINITY;
    return 1;
}

int sq_contact_step(const sq_obstacle *obs, int nobs, const sq_contact_nodes *nodes, double *d, double *v,
                    double h, sq_contact_sum *sum)
{
    int touching = 0;
    double deepest = 0;
    sq_contact_cache *cache = nodes->cache;
    if (cache && !cache->valid)
        cache_fill(cache, obs, nobs, nodes, d);
    for (int k = 0; k < nodes->n; k++) {
        int i = nodes->list[k];
        if (nodes->fixed[i] || (nodes->mask && !nodes->mask[i]))
            continue;
        double *di = d + 3 * (size_t)i, *vi = v + 3 * (size_t)i;
        const double m = nodes->mass[i];
        int hit = 0, far = 0;
        if (cache) { /* moved less than its distance to the mesh obstacles: they are out of reach */
            const double *x0 = cache->start + 3 * (size_t)k;
            double s = 0;
            for (int c = 0; c < 3; c++) {
                double e = nodes->X[3 * (size_t)i + c] + di[c] - x0[c];
                s += e * e;
            }
            far = s < cache->radius[k] * cache->radius[k];
        }
        for (int o = 0; o < nobs; o++) {
            const sq_obstacle *ob = &obs[o];
            if (far && ob->kind == SQ_OBSTACLE_MESH)
                continue;
            double x[3], n[3];
            for (int c = 0; c < 3; c++)
                x[c] = nodes->X[3 * (size_t)i + c] + di[c];
            double phi;
            if (cache && cache->tri[k] >= 0 && cache->tri_obs[k] == o && flat_distance(cache, k, ob, x, &phi, n))
                ; /* near the mesh's flat part: its triangle's plane, no hierarchy query */
            else
                phi = sq_obstacle_distance(ob, x, n);
            if (!(phi < 0))
                continue;
            hit = 1;
            double vr[3];
            for (int c = 0; c < 3; c++)
                vr[c] = vi[c] - ob->velocity[c];
            double vn = dot3(vr, n);
            /* the distance at the step's start (the step moved the node by h v): land on the
             * surface when it started outside, else stop the approach */
            double phi0 = phi - h * vn;
            double vn1 = phi0 > 0 ? -phi0 / h : 0;
            if (vn1 < vn)
                vn1 = vn; /* never pull: a separating node keeps its velocity */
            double dvn = vn1 - vn, vt[3];
            for (int c = 0; c < 3; c++)
                vt[c] = vr[c] - vn * n[c];
            double vt1[3] = {vt[0], vt[1], vt[2]};
            friction(vt1, dvn, ob->mu_s, ob->mu_k);
            double dv[3];
            for (int c = 0; c < 3; c++) {
                dv[c] = dvn * n[c] + vt1[c] - vt[c];
                vi[c] += dv[c];
                di[c] += h * dv[c];
                if (sum)
                    sum->impulse[c] += m * dv[c];
            }
            /* a node that started inside (deeper than this step's motion) is moved to the
             * surface without a velocity change */
            double left = phi + h * dvn;
            if (left < 0) {
                for (int c = 0; c < 3; c++)
                    di[c] -= left * n[c];
                deepest = deepest > -left ? deepest : -left;
            }
        }
        touching += hit;
        if (hit && nodes->touched)
            nodes->touched[i] = 1;
    }
    if (sum) {
        sum->nodes = touching;
        sum->depth = deepest;
    }
    return touching;
}

/* ---- body against body ------------------------------------------------------------- */

struct sq_contact_surface {
    int n, ntris;
    const int *tris;
    double *x;     /* current positions of the nodes (n x 3; only the triangles' nodes are kept) */
    int *used;     /* the triangles' distinct nodes */
    int nused;
    sq_bvh *bvh;
};

sq_contact_surface *sq_contact_surface_create(int n, int ntris, const int *tris)
{
    sq_contact_surface *s = sq_calloc(1, sizeof *s);
    s->n = n;
    s->ntris = ntris;
    s->tris = tris;
    s->x = sq_calloc(3 * (size_t)(n > 0 ? n : 1), sizeof(double));
    unsigned char *seen = sq_calloc((size_t)(n > 0 ? n : 1), 1);
    s->used = sq_malloc(sizeof(int) * (size_t)(3 * ntris + 1));
    for (int t = 0; t < 3 * ntris; t++)
        if (!seen[tris[t]]) {
            seen[tris[t]] = 1;
            s->used[s->nused++] = tris[t];
        }
    free(seen);
    return s;
}

void sq_contact_surface_free(sq_contact_surface *s)
{
    if (!s)
        return;
    sq_bvh_free(s->bvh);
    free(s->x);
    free(s->used);
    free(s);
}

void sq_contact_surface_update(sq_contact_surface *s, const double *X, const double *d)
{
    for (int k = 0; k < s->nused; k++) {
        size_t i = 3 * (size_t)s->used[k];
        for (int c = 0; c < 3; c++)
            s->x[i + c] = X[i + c] + d[i + c];
    }
    if (!s->bvh)
        s->bvh = sq_bvh_build(s->x, s->tris, s->ntris);
    else
        sq_bvh_refit(s->bvh, s->x, s->tris);
}

/* the unit normal of triangle t of s at its current positions; 0 for a degenerate one */
static int tri_normal(const sq_contact_surface *s, int t, double n[3])
{
    const int *v = s->tris + 3 * (size_t)t;
    const double *a = s->x + 3 * (size_t)v[0], *b = s->x + 3 * (size_t)v[1], *c = s->x + 3 * (size_t)v[2];
    double e1[3], e2[3];
    for (int k = 0; k < 3; k++) {
        e1[k] = b[k] - a[k];
        e2[k] = c[k] - a[k];
    }
    n[0] = e1[1] * e2[2] - e1[2] * e2[1];
    n[1] = e1[2] * e2[0] - e1[0] * e2[2];
    n[2] = e1[0] * e2[1] - e1[1] * e2[0];
    double l = sqrt(dot3(n, n));
    if (!(l > 0))
        return 0;
    for (int k = 0; k < 3; k++)
        n[k] /= l;
    return 1;
}

/* is p (a node of the other side) inside surface s near triangle t? depth and the outward unit
 * normal of t at the current positions */
static int inside_at(const sq_contact_surface *s, const double p[3], double reach, int *tri, double bary[3],
                     double *depth, double n[3])
{
    double dist, q[3];
    int t = sq_bvh_nearest(s->bvh, s->x, s->tris, p, reach, &dist, q, bary);
    if (t < 0)
        return 0;
    if (!tri_normal(s, t, n))
        return 0;
    double r[3] = {p[0] - q[0], p[1] - q[1], p[2] - q[2]};
    double side = dot3(r, n);
    if (side >= 0)
        return 0;
    *tri = t;
    *depth = -side; /* along the normal */
    return 1;
}

double sq_contact_depth(sq_contact_side *a, sq_contact_side *b, double reach)
{
    sq_contact_surface_update(b->surf, b->nodes->X, b->d);
    double deepest = 0;
    for (int k = 0; k < a->nodes->n; k++) {
        int i = a->nodes->list[k], t;
        double p[3], bary[3], depth, n[3];
        for (int c = 0; c < 3; c++)
            p[c] = a->nodes->X[3 * (size_t)i + c] + a->d[3 * (size_t)i + c];
        if (inside_at(b->surf, p, reach, &t, bary, &depth, n) && depth > deepest)
            deepest = depth;
    }
    return deepest;
}

/* ---- body against body, every substep --------------------------------------------------- */

static double target_inv_mass(const sq_contact_target *t, int i)
{
    if (t->fixed[i] || (t->mask && !t->mask[i]))
        return 0;
    return 1.0 / t->mass[i];
}

int sq_contact_step_targets(const sq_contact_target *tg, int ntg, const sq_contact_nodes *nodes, double *d,
                            double *v, double h, sq_contact_sum *sum)
{
    int touching = 0;
    for (int g = 0; g < ntg; g++) {
        const sq_contact_target *t = &tg[g];
        const sq_contact_surface *S = t->surf;
        if (!S || !S->bvh)
            continue;
        for (int k = 0; k < nodes->n; k++) {
            int i = nodes->list[k];
            if (nodes->fixed[i] || (nodes->mask && !nodes->mask[i]))
                continue;
            double *di = d + 3 * (size_t)i, *vi = v + 3 * (size_t)i, p[3];
            for (int c = 0; c < 3; c++)
                p[c] = nodes->X[3 * (size_t)i + c] + di[c];
            int tri;
            double bary[3], depth, n[3];
            if (!inside_at(S, p, t->reach, &tri, bary, &depth, n))
                continue;
            const int *tv = S->tris + 3 * (size_t)tri;
            double vt_pt[3] = {0, 0, 0}, Winv = 0;
            for (int j = 0; j < 3; j++) {
                /* the target's velocity with the reactions of this frame's earlier impulses, as
                 * if applied already: each impulse sees the pair as the earlier ones left it */
                double wi = target_inv_mass(t, tv[j]);
                Winv += bary[j] * bary[j] * wi;
                for (int c = 0; c < 3; c++)
                    vt_pt[c] += bary[j] * (t->v[3 * (size_t)tv[j] + c] + wi * t->reaction[3 * (size_t)tv[j] + c]);
            }
            const double m = nodes->mass[i];
            /* the impulse's mass: the smaller of the node's and the triangle point's */
            double meff = Winv > 0 ? fmin(m, 1.0 / Winv) : m;
            double vr[3];
            for (int c = 0; c < 3; c++)
                vr[c] = vi[c] - vt_pt[c];
            double vn = dot3(vr, n), phi = -depth, phi0 = phi - h * vn;
            /* started outside: land on the surface; started inside (the target moved into it, or
             * a node deeper than one step): leave at half the depth per step */
            double vn1 = phi0 > 0 ? -phi0 / h : 0.5 * depth / h;
            if (vn1 < vn)
                vn1 = vn;
            double dvn = (vn1 - vn) * meff / m, vt[3]; /* the node's normal velocity change */
            for (int c = 0; c < 3; c++)
                vt[c] = vr[c] - vn * n[c];
            double vt1[3] = {vt[0], vt[1], vt[2]};
            friction(vt1, dvn, t->mu, t->mu);
            touching++;
            if (nodes->touched)
                nodes->touched[i] = 1;
            for (int c = 0; c < 3; c++) {
                double dv = dvn * n[c] + (vt1[c] - vt[c]) * meff / m;
                vi[c] += dv;
                di[c] += h * dv;
                double J = m * dv;
                if (sum)
                    sum->impulse[c] += J;
                for (int j = 0; j < 3; j++)
                    t->reaction[3 * (size_t)tv[j] + c] -= bary[j] * J;
            }
        }
    }
    if (sum)
        sum->nodes += touching;
    return touching;
}
