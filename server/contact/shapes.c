/* shapes.c - the obstacles' signed distances and outward normals, and their checks at load.
 *
 * Every distance is exact for the shape (a plane, a sphere, a capsule, an axis-aligned box) or
 * the nearest point of a triangle mesh, negative inside. Inside a box the normal is the one of
 * the nearest face; inside a mesh the side is read from the nearest triangle's normal. */
#include <math.h>
#include <string.h>

#include "contact/contact_internal.h"

static inline double dot3(const double a[3], const double b[3])
{
    return a[0] * b[0] + a[1] * b[1] + a[2] * b[2];
}

static double unit_from(const double a[3], double n[3], const double fallback[3])
{
    double l = sqrt(dot3(a, a));
    if (l > 1e-300) {
        for (int c = 0; c < 3; c++)
            n[c] = a[c] / l;
    } else {
        memcpy(n, fallback, 3 * sizeof(double));
    }
    return l;
}

static const double up[3] = {0, 0, 1};

static double box_distance(const sq_obstacle *o, const double x[3], double n[3])
{
    double q[3], outside[3], inside = -INFINITY;
    int axis = 0;
    for (int c = 0; c < 3; c++) {
        q[c] = fabs(x[c] - o->point[c]) - o->half[c];
        outside[c] = q[c] > 0 ? q[c] : 0;
        if (q[c] > inside) {
            inside = q[c];
            axis = c;
        }
    }
    if (inside > 0) { /* outside: to the nearest point of the box */
        double a[3];
        for (int c = 0; c < 3; c++)
            a[c] = (x[c] > o->point[c] ? 1 : -1) * outside[c];
        return unit_from(a, n, up);
    }
    n[0] = n[1] = n[2] = 0; /* inside: out through the nearest face */
    n[axis] = x[axis] >= o->point[axis] ? 1 : -1;
    return inside;
}

static double capsule_distance(const sq_obstacle *o, const double x[3], double n[3])
{
    double ab[3], ap[3];
    for (int c = 0; c < 3; c++) {
        ab[c] = o->end[c] - o->point[c];
        ap[c] = x[c] - o->point[c];
    }
    double l2 = dot3(ab, ab), t = l2 > 0 ? dot3(ap, ab) / l2 : 0;
    t = t < 0 ? 0 : t > 1 ? 1 : t;
    double r[3];
    for (int c = 0; c < 3; c++)
        r[c] = ap[c] - t * ab[c];
    return unit_from(r, n, up) - o->radius;
}

int sq_obstacle_mesh_nearest(const sq_obstacle *o, const double x[3], double n[3], double *phi, double *dist)
{
    const sq_trimesh *m = o->mesh;
    *phi = INFINITY;
    for (int c = 0; c < 3; c++) /* broad phase: farther than the thickness from the mesh's box */
        if (x[c] < m->bbox_min[c] - o->thickness || x[c] > m->bbox_max[c] + o->thickness)
            return -1;
    double q[3], bary[3];
    int t = sq_trimesh_nearest(m, x, o->thickness, dist, q, bary);
    if (t < 0)
        return -1;
    const double *tn = m->normal + 3 * (size_t)t;
    double r[3];
    for (int c = 0; c < 3; c++)
        r[c] = x[c] - q[c];
    double side = dot3(r, tn);
    if (side >= 0) { /* in front: away from the nearest point (the face normal on the face) */
        if (*dist > 1e-12)
            unit_from(r, n, tn);
        else
            memcpy(n, tn, sizeof(double) * 3);
        *phi = *dist;
        return t;
    }
    memcpy(n, tn, sizeof(double) * 3); /* behind: within the thickness counts as inside */
    *phi = -*dist;
    return t;
}

double sq_obstacle_distance(const sq_obstacle *o, const double x[3], double n[3])
{
    switch (o->kind) {
    case SQ_OBSTACLE_PLANE: {
        double r[3] = {x[0] - o->point[0], x[1] - o->point[1], x[2] - o->point[2]};
        memcpy(n, o->normal, sizeof(double) * 3);
        return dot3(r, o->normal);
    }
    case SQ_OBSTACLE_SPHERE: {
        double r[3] = {x[0] - o->point[0], x[1] - o->point[1], x[2] - o->point[2]};
        return unit_from(r, n, up) - o->radius;
    }
    case SQ_OBSTACLE_BOX:
        return box_distance(o, x, n);
    case SQ_OBSTACLE_CAPSULE:
        return capsule_distance(o, x, n);
    case SQ_OBSTACLE_MESH:
        if (o->mesh) {
            double phi, dist;
            sq_obstacle_mesh_nearest(o, x, n, &phi, &dist);
            return phi;
        }
        return INFINITY;
    }
    return INFINITY;
}

static int finite3(const double a[3])
{
    return isfinite(a[0]) && isfinite(a[1]) && isfinite(a[2]);
}

int sq_obstacle_check(const sq_obstacle *o, sq_err *err)
{
    const char *who = o->name[0] ? o->name : "obstacle";
    if (!finite3(o->point) || !finite3(o->velocity))
        return sq_err_set(err, "obstacle \"%s\": a position or velocity is not a finite number; give finite metres",
                          who);
    if (!(o->mu_s >= 0 && o->mu_s <= 10) || !(o->mu_k >= 0 && o->mu_k <= 10))
        return sq_err_set(err, "obstacle \"%s\": friction %g (static), %g (kinetic) out of range; use 0 <= friction <= 10",
                          who, o->mu_s, o->mu_k);
    if (o->mu_k > o->mu_s)
        return sq_err_set(err, "obstacle \"%s\": kinetic friction %g above static %g; give kinetic <= static", who,
                          o->mu_k, o->mu_s);
    switch (o->kind) {
    case SQ_OBSTACLE_PLANE: {
        if (!finite3(o->normal))
            return sq_err_set(err, "obstacle \"%s\": normal is not finite; give a unit vector such as [0, 0, 1]", who);
        double l = sqrt(dot3(o->normal, o->normal));
        if (!(fabs(l - 1) < 1e-9))
            return sq_err_set(err, "obstacle \"%s\": normal has length %g; give a unit vector (the loader normalises "
                              "a nonzero one)", who, l);
        return 0;
    }
    case SQ_OBSTACLE_BOX:
        for (int c = 0; c < 3; c++)
            if (!(o->half[c] > 0 && o->half[c] < 1e4))
                return sq_err_set(err, "obstacle \"%s\": box size [%g, %g, %g] must be positive and finite (below "
                                  "2e4 m); give \"size\": [sx, sy, sz] in metres", who, 2 * o->half[0],
                                  2 * o->half[1], 2 * o->half[2]);
        return 0;
    case SQ_OBSTACLE_SPHERE:
    case SQ_OBSTACLE_CAPSULE:
        if (!(o->radius > 0 && o->radius < 1e4))
            return sq_err_set(err, "obstacle \"%s\": radius %g must be positive and finite (below 1e4 m); give "
                              "\"radius\" in metres", who, o->radius);
        if (o->kind == SQ_OBSTACLE_CAPSULE && !finite3(o->end))
            return sq_err_set(err, "obstacle \"%s\": capsule end is not finite; give \"b\": [x, y, z] in metres", who);
        return 0;
    case SQ_OBSTACLE_MESH:
        if (!o->mesh || o->mesh->ntris < 1)
            return sq_err_set(err, "obstacle \"%s\": the triangle mesh has no triangles; give an OBJ or STL file "
                              "with faces", who);
        if (!(o->thickness > 0 && o->thickness < 1e4))
            return sq_err_set(err, "obstacle \"%s\": thickness %g must be positive and finite; give \"thickness\" "
                              "in metres (how deep behind a triangle still counts as inside)", who, o->thickness);
        return 0;
    }
    return sq_err_set(err, "obstacle \"%s\": unknown kind %d; use plane, box, sphere, capsule or mesh", who,
                      (int)o->kind);
}
