/* contact_internal.h - the contact module's own parts: the bounding-volume hierarchy over
 * triangles and the closest point of a triangle (contact/ only). */
#ifndef SQ_CONTACT_INTERNAL_H
#define SQ_CONTACT_INTERNAL_H

#include "contact/contact.h"

/* a binary hierarchy of axis-aligned boxes over triangles, leaves of up to 4 triangles; the
 * topology is built once (median split on the longest axis) and the boxes refit to new
 * positions (a deforming surface) in one pass */
typedef struct sq_bvh sq_bvh;

/* x: vertex positions indexed as tris are (only the vertices tris use are read) */
sq_bvh *sq_bvh_build(const double *x, const int *tris, int ntris);
void sq_bvh_refit(sq_bvh *b, const double *x, const int *tris);
void sq_bvh_free(sq_bvh *b);
/* the nearest triangle to p within reach: its index, distance, closest point and barycentric
 * weights; -1 if none is within reach */
int sq_bvh_nearest(const sq_bvh *b, const double *x, const int *tris, const double p[3], double reach,
                   double *dist, double closest[3], double bary[3]);

/* are all triangles within r of p in the plane n . x = off (normal n, unit normals given per
 * triangle)? 1 yes (also when none is within r), 0 no */
int sq_bvh_coplanar_within(const sq_bvh *b, const double *x, const int *tris, const double *normal, const double p[3],
                           double r, const double n[3], double off);

/* how many nodes the cache's last fill found on a mesh obstacle's flat part (for tests) */
int sq_contact_cache_flat_count(const sq_contact_cache *c);

/* a mesh obstacle's signed distance at x (sq_obstacle_distance's), its normal n and the unsigned
 * distance to the nearest triangle, whose index it returns; -1 (phi +inf) beyond the thickness */
int sq_obstacle_mesh_nearest(const sq_obstacle *o, const double x[3], double n[3], double *phi, double *dist);

/* closest point of triangle (a, b, c) to p, with its barycentric weights; returns |p - q|^2 */
double sq_closest_on_triangle(const double p[3], const double a[3], const double b[3], const double c[3],
                              double q[3], double bary[3]);

#endif
