/* contact.h - the world's obstacles and contact of surface nodes with them and with other
 * bodies' surfaces (docs/physics.md section 13).
 *
 * Obstacles are rigid: half-spaces (a floor, a wall), axis-aligned boxes, spheres, capsules and
 * static triangle meshes (an OBJ or STL file: a tray, a table). Each has a signed distance
 * (negative inside) and an outward normal at any point, and Coulomb friction coefficients.
 *
 * The method is speculative contact at the velocity level, once per substep of the explicit
 * step (with the implicit step, the contacts are constraints of its solve: sq_contact_point,
 * sq_contact_constrained, level.h's sq_implicit_contacts; this pass then catches the nodes the
 * constraints did not foresee): after a node's symplectic Euler update, a node
 * that ended inside an obstacle has its normal velocity raised to the value that lands it on
 * the surface (never above zero), and its tangential velocity reduced by Coulomb friction
 * bounded by that normal impulse; the position follows the changed velocity. Every impulse
 * removes kinetic energy at the node it acts on, so contact adds no energy to the step; the
 * explicit step's stability bound is the body's own (no penalty stiffness enters it).
 *
 * Body against body works the same way at every substep of each body, with the other bodies'
 * surfaces as moving targets (sq_contact_target): equal and opposite impulses on the node and
 * on the other's triangle's three nodes (barycentric weights), or, for an adaptive target, on
 * the active nodes its triangle's nodes are made of (the target's map, its transpose).
 *
 * Units SI: m, kg, s, N. Module order: util mesh level contact lod body ... (the contact module
 * needs util only).
 */
#ifndef SQ_CONTACT_H
#define SQ_CONTACT_H

#include "util/util.h"

#define SQ_MAX_OBSTACLES 16

typedef enum sq_obstacle_kind {
    SQ_OBSTACLE_PLANE = 0,   /* half-space: the solid side is behind the normal */
    SQ_OBSTACLE_BOX = 1,     /* axis-aligned box */
    SQ_OBSTACLE_SPHERE = 2,
    SQ_OBSTACLE_CAPSULE = 3, /* segment a-b swept by a radius */
    SQ_OBSTACLE_MESH = 4,    /* triangle mesh, solid behind each triangle's normal */
} sq_obstacle_kind;

/* a triangle mesh read from OBJ or STL, with a bounding-volume hierarchy over its triangles */
typedef struct sq_trimesh {
    int nverts, ntris;
    double *x;         /* vertex positions (nverts x 3), m */
    int *tris;         /* vertex indices (ntris x 3), counter-clockwise seen from outside */
    double *normal;    /* unit normal of each triangle (ntris x 3) */
    double bbox_min[3], bbox_max[3];
    char source[256];  /* file it came from, for messages */
    struct sq_bvh *bvh; /* private (contact/bvh.c) */
} sq_trimesh;

typedef struct sq_obstacle {
    char name[64];
    sq_obstacle_kind kind;
    double point[3];  /* plane: a point on it; box, sphere: centre; capsule: end a */
    double normal[3]; /* plane: unit outward normal (away from the solid) */
    double end[3];    /* capsule: end b */
    double half[3];   /* box: half extents */
    double radius;    /* sphere, capsule */
    double thickness; /* mesh: depth behind a triangle that still counts as inside, m */
    double mu_s, mu_k; /* Coulomb friction: static, kinetic (mu_k <= mu_s) */
    double velocity[3]; /* m/s: the obstacle's translation rate this frame (keyframed obstacles) */
    const sq_trimesh *mesh; /* mesh: borrowed, must outlive the obstacle */
} sq_obstacle;

/* read a triangle mesh: .obj (v and f lines; polygons fanned into triangles) or .stl (ASCII or
 * binary), scaled by scale then offset. NULL + err naming the file, line and fix */
sq_trimesh *sq_trimesh_load(const char *path, double scale, const double offset[3], sq_err *err);
/* from arrays (copied); NULL + err on bad input */
sq_trimesh *sq_trimesh_from_arrays(int nverts, const double *x, int ntris, const int *tris, const char *source,
                                   sq_err *err);
void sq_trimesh_free(sq_trimesh *m);

/* nearest point of m to p within reach (m): its distance, the triangle, the point and the
 * barycentric weights; -1 when no triangle lies within reach */
int sq_trimesh_nearest(const sq_trimesh *m, const double p[3], double reach, double *dist, double closest[3],
                       double bary[3]);

/* is the obstacle well formed? 0, or -1 + err naming the obstacle, the value and the fix */
int sq_obstacle_check(const sq_obstacle *o, sq_err *err);
/* signed distance of point x to the obstacle's surface (negative inside) and the outward unit
 * normal there; +INFINITY (n untouched) far from a mesh obstacle (beyond its thickness) */
double sq_obstacle_distance(const sq_obstacle *o, const double x[3], double n[3]);

/* what a contact pass did: the impulses it applied (N s, summed over its calls) and the nodes
 * in contact in its last call */
typedef struct sq_contact_sum {
    double impulse[3];
    int nodes;
    double depth;     /* deepest penetration left after the last call, m (>= 0) */
} sq_contact_sum;

/* what a body keeps between the steps of a frame to skip obstacles cheaply: each listed node's
 * displacement at the frame's first pass and its distance then to the nearest obstacle (exact
 * where positive; obstacles are posed once per frame); a node that has moved less than that
 * since cannot have reached any obstacle's surface (the triangle inequality), so its tests are
 * skipped. A node resting on a mesh obstacle's flat part also keeps that triangle's plane, from
 * frame to frame while it stays near where it was found (contact/resolve.c states why the plane
 * is then the nearest surface) */
typedef struct sq_contact_cache sq_contact_cache;
sq_contact_cache *sq_contact_cache_create(void);
void sq_contact_cache_free(sq_contact_cache *c);
/* a new frame: the next pass measures afresh */
void sq_contact_cache_reset(sq_contact_cache *c);

/* where a node met an obstacle in a pass: the outward unit normal there, the obstacle's
 * velocity and friction, and the pass's stamp (sq_contact_nodes.stamp). The implicit integrator
 * makes these contacts constraints of its next solve (docs/physics.md section 13) */
typedef struct sq_contact_point {
    double n[3];
    double u[3];
    double mu_s, mu_k;
    int obs;   /* the obstacle's index */
    int stamp;
} sq_contact_point;

/* the point of obstacle ob (index o) with outward normal n, stamped */
sq_contact_point sq_contact_point_at(const sq_obstacle *ob, int o, const double n[3], int stamp);

/* the nodes a pass may move */
typedef struct sq_contact_nodes {
    int n;
    const int *list;            /* node indices (the level's surface nodes) */
    const double *X;            /* rest positions (nodes x 3) */
    const double *mass;         /* lumped masses */
    const unsigned char *fixed; /* constrained axes per node: a node with any is left alone */
    const unsigned char *mask;  /* NULL, or 0 for a node the pass must leave alone (a held node) */
    sq_contact_cache *cache;    /* NULL, or the frame's cache of the mesh obstacles' distances */
    unsigned char *touched;     /* NULL, or set to 1 at each node a pass finds in contact (nodes) */
    sq_contact_point *points;   /* NULL, or (nodes) written with stamp at each node the obstacle
                                   pass finds inside an obstacle (the last obstacle's) */
    int stamp;
} sq_contact_nodes;

/* one substep's contact after the position update of step h: d and v of the listed nodes
 * changed in place, impulses added to sum (may be NULL). Returns the nodes in contact */
int sq_contact_step(const sq_obstacle *obs, int nobs, const sq_contact_nodes *nodes, double *d, double *v,
                    double h, sq_contact_sum *sum);

/* after an implicit step that held the listed nodes' velocities as constraints of its solve
 * (sticking contacts: the whole velocity relative to the obstacle; sliding ones: its normal
 * part, with the kinetic friction force fric in the solve): the impulses J (3 per contact, N s:
 * M dv - h f, the constraint's and the friction's) are added to sum, and the next step's kind
 * is set per patch (the contacts with one obstacle), since the nodes of a patch are coupled by
 * the body: a sticking patch whose tangential impulse exceeds mu_s times its normal impulse
 * slides, each node with the kinetic force mu_k Jn / h (Jn = J . n) along that impulse; a
 * sliding patch slides on against its mean slip velocity, or sticks once that slip has stopped
 * or turned (the slip is then removed: only kinetic energy is taken). Jn <= 0 marks a contact
 * that pulled (the caller releases it) */
void sq_contact_constrained(const sq_contact_point *pts, int n, const int *node, const double *J,
                            unsigned char *stick, double *fric, const double *mass, double *d, double *v,
                            double h, sq_contact_sum *sum);

/* a body's surface for body-against-body contact: its triangles in node numbering, the current
 * positions of their nodes and a bounding-volume hierarchy over them (built at the first
 * update, refit after) */
typedef struct sq_contact_surface sq_contact_surface;
/* n: nodes of the level (tris index them); tris borrowed, must outlive the surface */
sq_contact_surface *sq_contact_surface_create(int n, int ntris, const int *tris);
void sq_contact_surface_free(sq_contact_surface *s);

/* surface s at positions X + d now (refits its hierarchy; the first call builds it) */
void sq_contact_surface_update(sq_contact_surface *s, const double *X, const double *d);

/* another body's surface as a target of a body's steps (body against body, every substep):
 * its surface frozen where it stands at the start of the stepping body's frame, moving with its
 * nodes' velocities; a node of the stepping body inside it lands on it as on an obstacle, with
 * the impulse bounded by the smaller of the node's mass and the triangle point's effective
 * mass 1 / sum_k w_k^2 / m_k (so the pair loses kinetic energy), and the opposite impulse
 * -w_k J added to the target's nodes in `reaction` (applied by the caller as velocity changes
 * once the stepping body's frame is done) */
typedef struct sq_contact_target {
    int n;                     /* the target's nodes (reaction has n x 3 entries) */
    sq_contact_surface *surf;  /* updated by the caller to the target's current positions */
    const double *v;           /* the target's node velocities (n x 3) */
    const double *mass;        /* its lumped masses */
    const unsigned char *fixed; /* constrained axes per node: infinite mass */
    const unsigned char *mask; /* NULL, or 0 at nodes a tool holds (infinite mass) */
    double *reaction;          /* impulses on the target's nodes (n x 3), added to, N s */
    double mu;                 /* Coulomb friction between the two bodies */
    double reach;              /* how deep a node may be and still be found, m */
    /* NULL, or the surface's nodes as combinations of the target's unknowns (an adaptive body:
     * its finest surface from its active nodes, docs/physics.md section 13): node i stands for
     * sum_e map_w[e] x[map_dof[e]], e from map_start[i] to map_start[i + 1] - 1. Then v, mass,
     * fixed, mask and reaction are the unknowns' (n of them), the point's velocity and effective
     * mass are read through the combination and the reaction handed back through its transpose */
    const int *map_start, *map_dof;
    const double *map_w;
} sq_contact_target;

/* one step's contact of the listed nodes with the targets (after the obstacles' pass of the
 * same step): d, v changed in place, impulses added to sum, reactions to each target's
 * reaction. Returns the nodes in contact */
int sq_contact_step_targets(const sq_contact_target *tg, int ntg, const sq_contact_nodes *nodes, double *d,
                            double *v, double h, sq_contact_sum *sum);

/* one side of a body-against-body measure: a level's surface, nodes and state */
typedef struct sq_contact_side {
    sq_contact_surface *surf;
    const sq_contact_nodes *nodes; /* its surface nodes (the ones tested against the other side) */
    double *d, *v;                 /* displacement and velocity (node numbering, x 3), changed in place */
} sq_contact_side;

/* deepest penetration (m) of a's surface nodes into b's surface, searched within reach */
double sq_contact_depth(sq_contact_side *a, sq_contact_side *b, double reach);

#endif
