/* resolve.c - contact of a body's surface nodes with the obstacles and with other bodies'
 * surfaces (a fixed body's nodes, or an adaptive body's finest surface through its map onto
 * the active nodes), once per substep: docs/physics.md section 13. */
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

/* a node resting on a mesh obstacle's flat part: the triangle under it as planes (its own, and
 * the three edges' inward ones), so the distance costs four dot products. It depends only on the
 * static mesh and its anchor x0, so it is kept from frame to frame while the node stays near x0:
 * every triangle within dist0 + 2 rho of x0 lies in the plane, so for x within rho of x0 whose
 * foot lies on the triangle, no other triangle is nearer (one nearer than |side| would lie within
 * |x - x0| + |side| < dist0 + 2 rho of x0). */
typedef struct {
    double x0[3];         /* the anchor */
    double n[3], off;     /* the triangle's plane: n . x - off */
    double m[3][3], c[3]; /* inside the closed triangle (as seen along n): m[j] . x >= c[j] */
    double rho2;          /* squared flat radius around x0 */
    int obs;              /* the mesh obstacle */
} flat_tri;

struct sq_contact_cache {
    int valid, cap, n;
    const int *list;  /* the node list the cache was filled for */
    double *rel;      /* displacement at the frame's first pass (list order, x 3) */
    double *r2;       /* squared distance then to the nearest obstacle (0: always test) */
    int *flat;        /* a node near one mesh obstacle's flat part: its flat_tri, else -1 */
    flat_tri *tris, *next; /* the flat triangles (nflat), and the next frame's being built */
    int nflat, flat_cap;
};

sq_contact_cache *sq_contact_cache_create(void)
{
    return sq_calloc(1, sizeof(sq_contact_cache));
}

void sq_contact_cache_free(sq_contact_cache *c)
{
    if (!c)
        return;
    free(c->rel);
    free(c->r2);
    free(c->flat);
    free(c->tris);
    free(c->next);
    free(c);
}

void sq_contact_cache_reset(sq_contact_cache *c)
{
    if (c)
        c->valid = 0;
}

int sq_contact_cache_flat_count(const sq_contact_cache *c)
{
    return c && c->valid ? c->nflat : 0;
}

/* the flat part of mesh obstacle ob around x (at distance dist from triangle t): the plane of t
 * when every triangle within dist + 2 rho of x lies in it, rho = min(thickness / 4, half the
 * triangle's shortest edge) (a node at rest moves far less; one that moves more asks the
 * hierarchy again), so few triangles are tested */
static int flat_of(const sq_obstacle *ob, int t, const double x[3], double dist, flat_tri *f)
{
    const sq_trimesh *m = ob->mesh;
    const int *tv = m->tris + 3 * (size_t)t;
    const double *tn = m->normal + 3 * (size_t)t;
    double e2 = INFINITY;
    for (int j = 0; j < 3; j++) {
        const double *a = m->x + 3 * (size_t)tv[j], *b = m->x + 3 * (size_t)tv[(j + 1) % 3];
        const double *o = m->x + 3 * (size_t)tv[(j + 2) % 3];
        double e[3] = {b[0] - a[0], b[1] - a[1], b[2] - a[2]};
        double in[3] = {tn[1] * e[2] - tn[2] * e[1], tn[2] * e[0] - tn[0] * e[2], tn[0] * e[1] - tn[1] * e[0]};
        double l = sqrt(dot3(in, in));
        if (!(l > 0))
            return 0;
        double r[3] = {o[0] - a[0], o[1] - a[1], o[2] - a[2]};
        double sgn = dot3(in, r) < 0 ? -1 : 1; /* inward: towards the opposite vertex */
        for (int c = 0; c < 3; c++)
            f->m[j][c] = sgn * in[c] / l;
        f->c[j] = dot3(f->m[j], a) - 1e-12; /* the closed triangle, to a picometre */
        e2 = fmin(e2, dot3(e, e));
    }
    const double rho = fmin(0.25 * ob->thickness, 0.5 * sqrt(e2));
    memcpy(f->x0, x, sizeof f->x0);
    memcpy(f->n, tn, sizeof f->n);
    f->off = dot3(tn, m->x + 3 * (size_t)tv[0]);
    f->rho2 = rho * rho;
    return sq_bvh_coplanar_within(m->bvh, m->x, m->tris, m->normal, x, dist + 2 * rho, tn, f->off);
}

/* the signed distance from f's plane at x when x is within the flat radius of f's anchor and
 * projects onto the closed triangle; 0 when the hierarchy must decide */
static int flat_distance(const flat_tri *f, const double x[3], double *side)
{
    double e[3] = {x[0] - f->x0[0], x[1] - f->x0[1], x[2] - f->x0[2]};
    if (!(dot3(e, e) < f->rho2))
        return 0;
    for (int j = 0; j < 3; j++)
        if (!(dot3(f->m[j], x) >= f->c[j]))
            return 0; /* the plane's foot is outside the triangle */
    *side = dot3(f->n, x) - f->off;
    return 1;
}

/* a mesh obstacle's signed distance as sq_obstacle_distance gives it (+inf beyond the thickness)
 * from a flat triangle, when it stands */
static double flat_phi(double side, double thickness)
{
    return side >= 0 ? side : -side <= thickness ? side : INFINITY;
}

/* node k's flat triangle from the last frame, if it still stands at x for obstacle o */
static const flat_tri *kept_flat(const sq_contact_cache *c, int k, int o, const double x[3], double *side)
{
    if (c->flat[k] < 0)
        return NULL;
    const flat_tri *f = &c->tris[c->flat[k]];
    return f->obs == o && flat_distance(f, x, side) ? f : NULL;
}

static flat_tri *next_flat(sq_contact_cache *c, int nnext)
{
    if (nnext == c->flat_cap) {
        c->flat_cap = c->flat_cap ? 2 * c->flat_cap : 256;
        c->tris = sq_realloc(c->tris, sizeof(flat_tri) * (size_t)c->flat_cap);
        c->next = sq_realloc(c->next, sizeof(flat_tri) * (size_t)c->flat_cap);
    }
    return &c->next[nnext];
}

/* the cache's distances from the nodes' current positions (the frame's first pass): obstacles
 * are posed once per frame and their distances are exact where positive, so a node that moves
 * less than its distance cannot reach any */
static void cache_fill(sq_contact_cache *c, const sq_obstacle *obs, int nobs, const sq_contact_nodes *nodes,
                       const double *d)
{
    if (c->cap < nodes->n) {
        c->cap = nodes->n;
        c->rel = sq_realloc(c->rel, sizeof(double) * 3 * (size_t)c->cap);
        c->r2 = sq_realloc(c->r2, sizeof(double) * (size_t)c->cap);
        c->flat = sq_realloc(c->flat, sizeof(int) * (size_t)c->cap);
        c->list = NULL;
    }
    if (c->list != nodes->list || c->n != nodes->n) { /* another node list: forget the flat parts */
        for (int k = 0; k < nodes->n; k++)
            c->flat[k] = -1;
        c->list = nodes->list;
        c->n = nodes->n;
        c->nflat = 0;
    }
    int nnext = 0;
    for (int k = 0; k < nodes->n; k++) {
        int i = nodes->list[k];
        double x[3], r = INFINITY;
        for (int a = 0; a < 3; a++) {
            c->rel[3 * (size_t)k + a] = d[3 * (size_t)i + a];
            x[a] = nodes->X[3 * (size_t)i + a] + d[3 * (size_t)i + a];
        }
        int near = 0, near_obs = -1, near_tri = -1;
        double near_dist = 0, side;
        const flat_tri *kept = NULL;
        for (int o = 0; o < nobs; o++) {
            const sq_obstacle *ob = &obs[o];
            double n[3], phi;
            const flat_tri *f = ob->kind == SQ_OBSTACLE_MESH ? kept_flat(c, k, o, x, &side) : NULL;
            if (f) {
                kept = f;
                phi = flat_phi(side, ob->thickness);
            } else if (ob->kind == SQ_OBSTACLE_MESH) { /* sq_obstacle_distance's, keeping the triangle */
                double dist;
                int t = ob->mesh ? sq_obstacle_mesh_nearest(ob, x, n, &phi, &dist) : -1;
                if (t < 0)
                    phi = INFINITY;
                else {
                    near_tri = t;
                    near_dist = dist;
                }
            } else
                phi = sq_obstacle_distance(ob, x, n);
            const int found = isfinite(phi);
            if (ob->kind == SQ_OBSTACLE_MESH && !found)
                phi = ob->thickness; /* beyond the thickness (or its box's reach): at least that far */
            r = fmin(r, phi > 0 ? phi : 0); /* behind: 0 */
            if (ob->kind == SQ_OBSTACLE_MESH && found) {
                near++;
                near_obs = o;
            }
        }
        c->r2[k] = r * r;
        int slot = -1;
        if (near == 1 && kept && kept->obs == near_obs) { /* the same flat part as last frame */
            const flat_tri same = *kept; /* next_flat may move c->tris */
            *next_flat(c, nnext) = same;
            slot = nnext++;
        } else if (near == 1 && !kept && near_tri >= 0 && near_dist < 0.25 * obs[near_obs].thickness) {
            flat_tri *f = next_flat(c, nnext); /* close enough to touch: is it flat around the node? */
            if (flat_of(&obs[near_obs], near_tri, x, near_dist, f)) {
                f->obs = near_obs;
                slot = nnext++;
            }
        }
        c->flat[k] = slot;
    }
    flat_tri *t = c->tris;
    c->tris = c->next;
    c->next = t;
    c->nflat = nnext;
    c->valid = 1;
}

sq_contact_point sq_contact_point_at(const sq_obstacle *ob, int o, const double n[3], int stamp)
{
    sq_contact_point p = {.mu_s = ob->mu_s, .mu_k = ob->mu_k, .obs = o, .stamp = stamp};
    memcpy(p.n, n, sizeof p.n);
    memcpy(p.u, ob->velocity, sizeof p.u);
    return p;
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
        double *di = d + 3 * (size_t)i, *vi = v + 3 * (size_t)i;
        if (cache) { /* moved less than its distance to the obstacles: they are out of reach */
            const double *r = cache->rel + 3 * (size_t)k;
            double e0 = di[0] - r[0], e1 = di[1] - r[1], e2 = di[2] - r[2];
            if (e0 * e0 + e1 * e1 + e2 * e2 < cache->r2[k])
                continue;
        }
        if (nodes->fixed[i] || (nodes->mask && !nodes->mask[i]))
            continue;
        const double m = nodes->mass[i];
        int hit = 0;
        const flat_tri *f = cache && cache->flat[k] >= 0 ? &cache->tris[cache->flat[k]] : NULL;
        for (int o = 0; o < nobs; o++) {
            const sq_obstacle *ob = &obs[o];
            double x[3], n[3], phi, side;
            for (int c = 0; c < 3; c++)
                x[c] = nodes->X[3 * (size_t)i + c] + di[c];
            if (f && f->obs == o && flat_distance(f, x, &side)) { /* the mesh's flat part: its plane */
                phi = flat_phi(side, ob->thickness);
                memcpy(n, f->n, sizeof n);
            } else
                phi = sq_obstacle_distance(ob, x, n);
            if (!(phi < 0))
                continue;
            hit = 1;
            if (nodes->points)
                nodes->points[i] = sq_contact_point_at(ob, o, n, nodes->stamp);
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

static void tangential(const sq_contact_point *pt, const double *v, double vt[3])
{
    double vr[3];
    for (int c = 0; c < 3; c++)
        vr[c] = v[c] - pt->u[c];
    const double vn = dot3(vr, pt->n);
    for (int c = 0; c < 3; c++)
        vt[c] = vr[c] - vn * pt->n[c];
}

void sq_contact_constrained(const sq_contact_point *pts, int n, const int *node, const double *J,
                            unsigned char *stick, double *fric, const double *mass, double *d, double *v,
                            double h, sq_contact_sum *sum)
{
    /* per patch: normal impulse, tangential impulse of its sticking nodes, slip momentum and
     * mass and friction force of its sliding nodes, and whether any node of it sticks */
    double pn[SQ_MAX_OBSTACLES] = {0}, pt_[SQ_MAX_OBSTACLES][3] = {{0}}, pp[SQ_MAX_OBSTACLES][3] = {{0}};
    double pm[SQ_MAX_OBSTACLES] = {0}, pf[SQ_MAX_OBSTACLES][3] = {{0}};
    int pstick[SQ_MAX_OBSTACLES] = {0};
    for (int k = 0; k < n; k++) {
        const sq_contact_point *pt = &pts[k];
        const double *Jk = J + 3 * (size_t)k;
        const double jn = dot3(Jk, pt->n);
        if (sum)
            for (int c = 0; c < 3; c++)
                sum->impulse[c] += Jk[c];
        if (!(jn > 0) || pt->obs < 0 || pt->obs >= SQ_MAX_OBSTACLES)
            continue;
        const int o = pt->obs, i = node[k];
        pn[o] += jn;
        if (stick[k]) {
            pstick[o] = 1;
            for (int c = 0; c < 3; c++)
                pt_[o][c] += Jk[c] - jn * pt->n[c];
        } else {
            double vt[3];
            tangential(pt, v + 3 * (size_t)i, vt);
            pm[o] += mass[i];
            for (int c = 0; c < 3; c++) {
                pp[o][c] += mass[i] * vt[c];
                pf[o][c] += fric[3 * (size_t)k + c];
            }
        }
    }
    /* each patch's next kind: 1 stick, 0 slide along dir (unit) */
    int next[SQ_MAX_OBSTACLES];
    double dir[SQ_MAX_OBSTACLES][3];
    for (int o = 0; o < SQ_MAX_OBSTACLES; o++) {
        next[o] = 1;
        dir[o][0] = dir[o][1] = dir[o][2] = 0;
        if (!(pn[o] > 0))
            continue;
        double mu_s = 0, mu_k = 0;
        for (int k = 0; k < n; k++)
            if (pts[k].obs == o) {
                mu_s = pts[k].mu_s;
                mu_k = pts[k].mu_k;
                break;
            }
        (void)mu_k;
        if (pstick[o]) { /* stays stuck while its tangential impulse is inside the cone */
            const double s = sqrt(dot3(pt_[o], pt_[o]));
            if (s > mu_s * pn[o])
                for (int c = 0; c < 3; c++) {
                    next[o] = 0;
                    dir[o][c] = pt_[o][c] / s; /* the friction opposes the slip: along the impulse */
                }
        } else if (pm[o] > 0) {
            const double s = sqrt(dot3(pp[o], pp[o])), turned = dot3(pp[o], pf[o]);
            const int fresh = pf[o][0] == 0 && pf[o][1] == 0 && pf[o][2] == 0;
            /* the slip stopped or turned under the friction (or, new, static friction stops it) */
            if (!(s <= 1e-12 * pm[o] || turned > 0 || (fresh && s <= mu_s * pn[o])))
                for (int c = 0; c < 3; c++) {
                    next[o] = 0;
                    dir[o][c] = -pp[o][c] / s;
                }
        }
    }
    for (int k = 0; k < n; k++) {
        const sq_contact_point *pt = &pts[k];
        const double *Jk = J + 3 * (size_t)k;
        double *fk = fric + 3 * (size_t)k;
        const double jn = dot3(Jk, pt->n);
        fk[0] = fk[1] = fk[2] = 0;
        if (!(jn > 0) || pt->obs < 0 || pt->obs >= SQ_MAX_OBSTACLES)
            continue;
        const int o = pt->obs, i = node[k];
        if (!next[o]) {
            stick[k] = 0;
            for (int c = 0; c < 3; c++)
                fk[c] = pt->mu_k * jn / h * dir[o][c];
            continue;
        }
        if (!stick[k]) { /* sliding to sticking: the slip is removed */
            double vt[3];
            tangential(pt, v + 3 * (size_t)i, vt);
            for (int c = 0; c < 3; c++) {
                v[3 * (size_t)i + c] -= vt[c];
                d[3 * (size_t)i + c] -= h * vt[c];
                if (sum)
                    sum->impulse[c] -= mass[i] * vt[c];
            }
        }
        stick[k] = 1;
    }
}

/* ---- body against body, every substep --------------------------------------------------- */

static double target_inv_mass(const sq_contact_target *t, int i)
{
    if (t->fixed[i] || (t->mask && !t->mask[i]))
        return 0;
    return 1.0 / t->mass[i];
}

/* a mapped target's point at barycentric weights bary on triangle tv as a combination of the
 * target's unknowns (duplicates merged, since the point's effective mass needs each unknown's
 * whole coefficient) */
#define TARGET_TERMS 96
typedef struct {
    int n;
    int dof[TARGET_TERMS];
    double c[TARGET_TERMS];
} target_terms;

static void point_terms(const sq_contact_target *t, const int *tv, const double bary[3], target_terms *p)
{
    p->n = 0;
    for (int j = 0; j < 3; j++) {
        for (int e = t->map_start[tv[j]]; e < t->map_start[tv[j] + 1]; e++) {
            const int q = t->map_dof[e];
            const double c = bary[j] * t->map_w[e];
            int u = 0;
            while (u < p->n && p->dof[u] != q)
                u++;
            if (u < p->n)
                p->c[u] += c;
            else if (p->n < TARGET_TERMS) { /* rows hold at most 32 terms: never full */
                p->dof[p->n] = q;
                p->c[p->n++] = c;
            }
        }
    }
}

/* the listed nodes against one target; `mapped` (a constant at each call, so the fixed target's
 * loop is compiled without the map's) reads the target through its map */
static inline __attribute__((always_inline)) int step_target(const sq_contact_target *t, const sq_contact_nodes *nodes,
                                                             double *d, double *v, double h, sq_contact_sum *sum,
                                                             const int mapped)
{
    int touching = 0;
    const sq_contact_surface *S = t->surf;
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
        target_terms P;
        P.n = 0;
        double vt_pt[3] = {0, 0, 0}, Winv = 0;
        if (!mapped) /* the triangle's own nodes (the same sums as the mapped loop) */
            for (int j = 0; j < 3; j++) {
                /* the target's velocity with the reactions of this frame's earlier impulses, as
                 * if applied already: each impulse sees the pair as the earlier ones left it */
                double wi = target_inv_mass(t, tv[j]);
                Winv += bary[j] * bary[j] * wi;
                for (int c = 0; c < 3; c++)
                    vt_pt[c] += bary[j] * (t->v[3 * (size_t)tv[j] + c] + wi * t->reaction[3 * (size_t)tv[j] + c]);
            }
        else
            point_terms(t, tv, bary, &P);
        for (int e = 0; mapped && e < P.n; e++) { /* through the map: the unknowns */
            const size_t q = (size_t)P.dof[e];
            double wi = target_inv_mass(t, P.dof[e]);
            Winv += P.c[e] * P.c[e] * wi;
            for (int c = 0; c < 3; c++)
                vt_pt[c] += P.c[e] * (t->v[3 * q + c] + wi * t->reaction[3 * q + c]);
        }
        const double m = nodes->mass[i];
        /* the impulse's mass: the smaller of the node's and the triangle point's */
        double meff = Winv > 0 ? fmin(m, 1.0 / Winv) : m;
        double vr[3];
        for (int c = 0; c < 3; c++)
            vr[c] = vi[c] - vt_pt[c];
        double vn = dot3(vr, n), phi = -depth, phi0 = phi - h * vn;
        /* started outside: land on the surface; started inside (the target moved into it, or
         * a node deeper than one step): leave by the target's share of the depth */
        double vn1 = phi0 > 0 ? -phi0 / h : 0;
        double mt = Winv > 0 ? 1.0 / Winv : INFINITY;
        double dpos = phi0 > 0 ? 0 : depth * (isinf(mt) ? 1.0 : mt / (m + mt));
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
            di[c] += h * dv + dpos * n[c];
            double J = m * dv;
            if (sum)
                sum->impulse[c] += J;
            if (!mapped)
                for (int j = 0; j < 3; j++)
                    t->reaction[3 * (size_t)tv[j] + c] -= bary[j] * J;
            for (int e = 0; mapped && e < P.n; e++)
                t->reaction[3 * (size_t)P.dof[e] + c] -= P.c[e] * J;
        }
    }
    return touching;
}

int sq_contact_step_targets(const sq_contact_target *tg, int ntg, const sq_contact_nodes *nodes, double *d,
                            double *v, double h, sq_contact_sum *sum)
{
    int touching = 0;
    for (int g = 0; g < ntg; g++) {
        const sq_contact_target *t = &tg[g];
        if (!t->surf || !t->surf->bvh)
            continue;
        touching += t->map_start ? step_target(t, nodes, d, v, h, sum, 1) : step_target(t, nodes, d, v, h, sum, 0);
    }
    if (sum)
        sum->nodes += touching;
    return touching;
}
