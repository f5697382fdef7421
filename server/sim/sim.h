/* sim.h - soft bodies: material, operators, stability bound, stepping, health, tools.
 *
 * Second stage of the data flow. A body owns one or more levels of detail (independent,
 * non-nested meshes of the same shape, coarse to fine). With one level, or with
 * "lod": {"mode": "fixed"}, exactly one level is simulated; with "adaptive", the lod
 * module (lod/lod.h) decides per node which level is active (paper sections 3-4).
 *
 * Units are SI throughout: m, kg, s, Pa, N.
 */
#ifndef SQ_SIM_H
#define SQ_SIM_H

#include "mesh/mesh.h"

#define SQ_MAX_LEVELS 6
#define SQ_MAX_CONSTRAINTS 16
#define SQ_MAX_TOOLS 8

/* material in the standard Lamé names (mu = shear modulus); see docs/physics.md */
typedef struct sq_material {
    double mu;                 /* shear modulus, Pa */
    double lambda;             /* first Lamé parameter, Pa */
    double density;            /* kg/m^3 */
    double rayleigh_mass;      /* a in C = a M + b K, 1/s */
    double rayleigh_stiffness; /* b in C = a M + b K, s */
    int use_viscosity;         /* 1: damping from the paper's viscosities phi/psi instead of b K */
    double phi, psi;           /* paper Eq. 7 viscosities (standard-name roles of mu, lambda), Pa s */
} sq_material;

/* E (Pa), nu -> mu, lambda; returns -1 and err if out of range */
int sq_material_from_E_nu(sq_material *m, double E, double nu, sq_err *err);
void sq_material_E_nu(const sq_material *m, double *E, double *nu);
/* range checks (positive moduli, 0 <= nu < 0.5, density > 0, finite values) */
int sq_material_check(const sq_material *m, sq_err *err);

typedef enum sq_operator_kind {
    SQ_OPERATOR_FEM = 0,   /* standard linear FEM (default) */
    SQ_OPERATOR_PAPER = 1  /* the paper's Laplacian + grad-div (Eqs. 5-6) */
} sq_operator_kind;

/* elastic model: linear (the paper's, small-strain) or corotational (rotation-invariant:
 * f = R K_T (R^T x - X) per tet; fem operator, fixed lod mode only; docs/physics.md) */
typedef enum sq_elasticity_kind {
    SQ_ELASTICITY_LINEAR = 0,
    SQ_ELASTICITY_COROTATIONAL = 1
} sq_elasticity_kind;

/* constraint regions */
typedef enum sq_region_kind { SQ_REGION_BOX = 0, SQ_REGION_HALFSPACE = 1 } sq_region_kind;
typedef struct sq_constraint {
    sq_region_kind kind;
    double a[3], b[3]; /* box: min corner a, max corner b; half-space: point a, normal b
                          (nodes with (x - a).b <= 0 are selected) */
    unsigned axes;     /* constrained axes: bit 0 = x, 1 = y, 2 = z; 7 = fixed node */
} sq_constraint;

typedef enum sq_lod_mode { SQ_LOD_FIXED = 0, SQ_LOD_ADAPTIVE = 1 } sq_lod_mode;
typedef struct sq_lod_def {
    sq_lod_mode mode;
    int level;            /* fixed mode: the level simulated; adaptive: the starting level */
    double split;         /* adaptive: split when delta_i > split (m); 0 forces finest */
    double merge;         /* adaptive: merge when all children delta < merge (< split) */
    int max_level;        /* highest level index used (caps the levels list) */
    double budget;        /* fraction of the frame period above which splits stop (0.95) */
    long max_node_updates;/* hard cap on node updates per frame (0 = none) */
} sq_lod_def;

typedef struct sq_body_def {
    const char *name;
    int nlevels;
    const sq_mesh *levels[SQ_MAX_LEVELS]; /* coarse to fine; borrowed, must outlive the body */
    sq_material material;
    sq_operator_kind op;
    int nconstraints;
    sq_constraint constraints[SQ_MAX_CONSTRAINTS];
    sq_lod_def lod;
    double gravity[3];    /* m/s^2 */
    double frame_dt;      /* frame period, s (1 / frame_rate) */
    double step_fraction; /* fraction of the stability bound to run at (default 0.9) */
    sq_elasticity_kind elasticity; /* linear (default) or corotational */
    int sharp_step;       /* fixed mode: 1 = step from the Lanczos estimate of the bound (Gershgorin
                             as ceiling), any integer substep count; 0 (default) = Gershgorin, 2^n */
    int nodal_pressure;   /* 1: average nodal pressure tets (fem, linear, fixed lod; less locking) */
} sq_body_def;

/* defaults: fem, gravity 0, 50 Hz, fixed lod at level 0, budget 0.95, step_fraction 0.9 */
sq_body_def sq_body_def_default(void);

/* tools (paper section 5) */
typedef enum sq_tool_shape { SQ_TOOL_SPHERE = 0, SQ_TOOL_BOX = 1, SQ_TOOL_GRAB = 2 } sq_tool_shape;
typedef struct sq_tool {
    int id;
    sq_tool_shape shape;
    int active;
    double pos[3];     /* world position (sphere/box centre, grab point) */
    double radius;     /* sphere radius; grab: capture radius around pos at activation */
    double half[3];    /* box half extents */
    /* grab: where it was activated (set by the world on an inactive -> active change, or
     * from the activating keyframe); capture happens around origin and the held nodes
     * follow pos - origin. has_origin == 0 (e.g. a zeroed tool): capture around pos in
     * the first frame the tool is active. A changed origin while active re-captures. */
    double origin[3];
    int has_origin;
    /* grab: 1 = this body may not use the nearest-node fallback (set per body by the world:
     * the fallback only takes the one body nearest to the capture point) */
    int no_fallback;
} sq_tool;

typedef struct sq_tool_feedback {
    int id;
    double force[3];   /* elastic reaction of the constrained nodes on the tool, N */
    int nnodes;        /* nodes the tool constrains this frame */
} sq_tool_feedback;

/* per-frame profile (one body); times in seconds */
typedef struct sq_frame_profile {
    double t_pull, t_integrate, t_push, t_adapt, t_tools, t_health, t_total;
    long node_updates;                 /* active-node integrations this frame */
    int active[SQ_MAX_LEVELS];         /* active nodes per level */
    int substeps[SQ_MAX_LEVELS];       /* 2^n steps per frame per level */
    int splits, merges;
    int splits_refused;                /* 1 if splitting was forbidden this frame (budget) */
    int sleeping;                      /* 1 if the body slept (no updates) this frame */
    int awake_nodes, sleeping_nodes;
    int reset;                         /* 1 if a blow-up was detected and the body reset */
    char event[160];                   /* human-readable event of this frame, or empty */
} sq_frame_profile;

typedef struct sq_body sq_body;

/* create; computes operators and stability bounds; NULL + err (with numbers) if the
 * setup cannot run (bad material, no nodes left free, step bound needing more than
 * 2^20 substeps per frame, ...) */
sq_body *sq_body_create(const sq_body_def *def, sq_err *err);
void sq_body_destroy(sq_body *b);

/* change material / operator / lod at run time; validated; on refusal nothing changes
 * and err says why (e.g. the step bound it would break) */
int sq_body_set_material(sq_body *b, const sq_material *m, sq_operator_kind op, sq_err *err);
int sq_body_set_lod(sq_body *b, const sq_lod_def *lod, sq_err *err);
/* linear <-> corotational; corotational is refused (nothing changes) with the paper operator or
 * in adaptive lod mode; the state is kept */
int sq_body_set_elasticity(sq_body *b, sq_elasticity_kind e, sq_err *err);
/* element-wise (0) <-> average nodal pressure (1) tets; refused (nothing changes) with the paper
 * operator, corotational elasticity or adaptive lod; the state is kept */
int sq_body_set_pressure(sq_body *b, int nodal, sq_err *err);

/* back to rest (zero displacement and velocity, coarse level) */
void sq_body_reset(sq_body *b);

/* advance one frame (frame_dt) with the given tool poses; fills feedback[ntools] and prof
 * (either may be NULL). Always returns 0; a blow-up resets the body and sets prof->reset. */
int sq_body_frame(sq_body *b, const sq_tool *tools, int ntools, sq_tool_feedback *feedback,
                  sq_frame_profile *prof, double frame_budget_s);

/* read-only views */
const sq_body_def *sq_body_get_def(const sq_body *b);
int sq_body_nlevels(const sq_body *b);
const sq_mesh *sq_body_mesh(const sq_body *b, int level);
/* the step used at a level (dt_frame / 2^n) and its stability bound */
double sq_body_level_dt(const sq_body *b, int level);
double sq_body_level_bound(const sq_body *b, int level);
/* displacement and velocity of a level's nodes (active or ghost values) */
const double *sq_body_displacement(const sq_body *b, int level);
const double *sq_body_velocity(const sq_body *b, int level);
/* level active at each node of the finest loaded level (nnodes of that mesh) */
const unsigned char *sq_body_node_level(const sq_body *b);

/* rendered surface: the finest loaded level's boundary */
const sq_mesh *sq_body_surface_mesh(const sq_body *b);
/* current surface vertex positions (nsurf x 3) and active level per vertex (nsurf) */
void sq_body_surface_state(const sq_body *b, float *xyz, unsigned char *level);

/* displacement interpolated at a rest-space point (finest level values); -1 if outside */
int sq_body_probe(const sq_body *b, const double p[3], double u[3]);
/* grab capture test at point at (current positions of the finest surface): the number of
 * surface vertices within radius, and in *nearest the distance of the nearest one (m) */
int sq_body_grab_reach(const sq_body *b, const double at[3], double radius, double *nearest);

/* energies (J) of the currently simulated state */
double sq_body_kinetic_energy(const sq_body *b);
double sq_body_elastic_energy(const sq_body *b);
/* max over free nodes of |f_i| / (m_i |g|) (or / m_i if g = 0): residual force measure */
double sq_body_residual(const sq_body *b);
int sq_body_is_sleeping(const sq_body *b);
/* tets of the simulated level with det F <= 0 (inverted or flat) */
int sq_body_inverted_tets(const sq_body *b);

/* write the finest level (or the fixed level) as VTK with displacement, velocity, level */
int sq_body_write_vtk(const sq_body *b, const char *path, sq_err *err);

#endif
