/* body.h - soft bodies: levels + lod + tools + sleep + health; the engine's public contract.
 *
 * Second stage of the data flow. A body owns one or more levels of detail (independent,
 * non-nested meshes of the same shape, coarse to fine). With one level, or with
 * "lod": {"mode": "fixed"}, exactly one level is simulated; with "adaptive", the lod
 * module (lod/lod.h) decides per node which level is active (paper sections 3-4). One level's
 * physics (material, operator, step bound, step, static solve) is level/level.h.
 *
 * Units are SI throughout: m, kg, s, Pa, N.
 */
#ifndef SQ_BODY_H
#define SQ_BODY_H

#include "contact/contact.h"
#include "lod/lod.h"

#define SQ_MAX_TOOLS 8



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
    int sharp_step;       /* 1 = step from a Lanczos estimate of the bound (Gershgorin as ceiling):
                             2^n substeps, the next power of two at or above the count the bound
                             needs (fixed mode), per level from the coupled operator (adaptive,
                             lod/bound.c); 0 = Gershgorin, 2^n. The default is 1, for scenes
                             and sq_body_def_default alike */
    sq_integrator_kind integrator; /* explicit (default) or implicit (backward Euler, fixed lod) */
    sq_implicit_def implicit;      /* the implicit step's settings (sq_implicit_def_default) */
    int nodal_pressure;   /* SQ_PRESSURE_*: 1 average nodal pressure tets, 2 smoothed (fem, linear, fixed lod; less locking) */
} sq_body_def;

/* defaults: fem, gravity 0, 50 Hz, fixed lod at level 0, budget 0.95, step_fraction 0.9, the sharp
 * step bound (sharp_step 1) */
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
    /* an adaptive body keeps its finest level within focus times the tool's size (sphere
     * radius, box half-diagonal, grab capture radius) of pos; 0: the lod's criterion alone
     * (set by a haptic channel on its tool, from the channel's `focus`: a split or merge near
     * the tool would change the felt force in a step no model of one frame foresees) */
    double focus;
} sq_tool;

typedef struct sq_tool_feedback {
    int id;
    double force[3];   /* elastic reaction of the constrained nodes on the tool, N */
    int nnodes;        /* nodes the tool constrains this frame */
} sq_tool_feedback;


typedef struct sq_body sq_body;

/* the linear model of one tool's feedback about the state the last frame left (haptic.c):
 * f(p) = f0 + K (p - p0) for a tool position p near p0; N, N/m */
typedef struct sq_tool_model {
    int nnodes;        /* nodes the tool held in the last frame (0: no contact, f0 = K = 0) */
    int push;          /* 1 sphere/box (unilateral: no pull), 0 grab */
    double p0[3];      /* tool position of the last frame, m */
    double f0[3];      /* reaction of the held nodes on the tool in the state the frame left, N */
    double K[9];       /* d f / d p with the free nodes still (the instantaneous stiffness, what a
                          sudden move meets), row-major 3x3, N/m (negative semi-definite) */
    double Kc[9];      /* the same with the free nodes relaxed (condensed: what a slow move
                          meets; softer than K), N/m */
    double normal[3];  /* push: mean contact normal, from the tool into the body (unit); 0 else */
    double torque[3];  /* reaction torque about p0 (box: the tool has no orientation, so it is
                          the torque at p0, held constant between frames), N m */
    int cg_iterations; /* the condensation's conjugate-gradient iterations over Kc's 3 columns */
    double tau;        /* s: the time over which the body's response goes from K to Kc, taken as
                          the frame period (the next frame's f0 carries the rest) */
    double period;     /* s: the frame period, how often the model is renewed (0: not known) */
} sq_tool_model;

/* create; computes operators and stability bounds; NULL + err (with numbers) if the
 * setup cannot run (bad material, no nodes left free, step bound needing more than
 * 2^20 substeps per frame, ...) */
sq_body *sq_body_create(const sq_body_def *def, sq_err *err);
/* the same for a copy of body `like` with another def on the same meshes (e.g. another lod): a
 * level whose mesh, material, operator and constraints equal like's borrows like's operator
 * (read only, sq_level_init_shared) and, with the same frame and step fraction too, takes its
 * sharp step estimate; an adaptive copy of an adaptive like borrows the lod hierarchy and mesh
 * tables and copies the static loads and own-operator row sums (lod.h sq_lod_create_like,
 * sq_lod_set_loads_like): the same numbers as building them again, none of the cost or memory.
 * like must outlive the copy and not change its material or lod while the copy lives */
sq_body *sq_body_create_like(const sq_body *like, const sq_body_def *def, sq_err *err);
void sq_body_destroy(sq_body *b);

/* change material / operator / lod at run time; validated; on refusal nothing changes
 * and err says why (e.g. the step bound it would break) */
int sq_body_set_material(sq_body *b, const sq_material *m, sq_operator_kind op, sq_err *err);
int sq_body_set_lod(sq_body *b, const sq_lod_def *lod, sq_err *err);
/* linear <-> corotational; corotational is refused (nothing changes) with the paper operator or
 * in adaptive lod mode; the state is kept */
int sq_body_set_elasticity(sq_body *b, sq_elasticity_kind e, sq_err *err);
/* element-wise (SQ_PRESSURE_ELEMENT), average nodal pressure (SQ_PRESSURE_NODAL) or smoothed
 * (SQ_PRESSURE_SMOOTHED) tets; the last two are refused (nothing changes) with the paper operator,
 * corotational elasticity or adaptive lod; the state is kept */
int sq_body_set_pressure(sq_body *b, int nodal, sq_err *err);

/* explicit <-> implicit and the implicit settings; implicit is refused (nothing changes) in
 * adaptive lod mode, and settings out of range are refused naming the valid range; state kept */
int sq_body_set_integrator(sq_body *b, sq_integrator_kind k, const sq_implicit_def *imp, sq_err *err);
/* is this integrator allowed with lod mode `mode`? 0, or -1 + err naming the fix */
int sq_body_check_integrator(sq_integrator_kind k, const sq_implicit_def *imp, sq_lod_mode mode, sq_err *err);

/* back to rest (zero displacement and velocity, coarse level) */
void sq_body_reset(sq_body *b);

/* advance one frame (frame_dt) with the given tool poses; fills feedback[ntools] and prof
 * (either may be NULL). Always returns 0; a blow-up resets the body and sets prof->reset. */
int sq_body_frame(sq_body *b, const sq_tool *tools, int ntools, sq_tool_feedback *feedback,
                  sq_frame_profile *prof, double frame_budget_s);

/* a live pose source (a haptic device between frames, docs/protocol.md "Haptic channel"):
 * fn(arg, id, frac, pos) gives the position of tool `id` for the substep ending at fraction
 * frac of the frame (0 at its start; a real-time source gives the newest, a lockstep ramp the
 * pose interpolated at frac) and returns 1, or returns 0 when that tool has none. With one set, each substep of an explicit frame (fixed or adaptive lod)
 * reads it and moves the nodes that tool holds by the pose's change since the frame's start
 * (a grab: with it; a push: along each node's contact normal); the set of held nodes stays
 * the frame's. NULL (the default): poses change at frame starts only, the step is unchanged */
typedef int (*sq_pose_source_fn)(void *arg, int id, double frac, double pos[3]);
void sq_body_set_pose_source(sq_body *b, sq_pose_source_fn fn, void *arg);

/* thread CPU time (s) spent on this thread since the last frame on work that is not the
 * product's (a measuring harness): kept out of the budget guard's time around the frame
 * (adaptive bodies; sq_lod_untimed) */
void sq_body_untimed(sq_body *b, double cpu_s);
/* a live budget will follow: an adaptive body's first-budgeted-frame set-up done now, at load
 * (sq_lod_prepare_budget); nothing for a fixed body */
void sq_body_prepare_budget(sq_body *b);

/* read-only views */
const sq_body_def *sq_body_get_def(const sq_body *b);
int sq_body_nlevels(const sq_body *b);
const sq_mesh *sq_body_mesh(const sq_body *b, int level);
/* the step used at a level (dt_frame / 2^n) and its stability bound */
double sq_body_level_dt(const sq_body *b, int level);
double sq_body_level_bound(const sq_body *b, int level);
/* adaptive "step_bound": "sharp": the Lanczos estimates made (one per level with active nodes
 * per rebuild) and their thread CPU time; zeros otherwise */
void sq_body_step_bound_cost(const sq_body *b, long *estimates, double *cpu_s);
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
/* active nodes per loaded level as the resolution stands now (also before the first frame and
 * while asleep): fixed mode counts the simulated level whole, adaptive the active lists */
void sq_body_active_nodes(const sq_body *b, int active[SQ_MAX_LEVELS]);
/* steps per frame of each loaded level as the body stands (what a frame stepped now runs) */
void sq_body_substeps(const sq_body *b, int substeps[SQ_MAX_LEVELS]);
/* health warnings since the body was created, indexed by sq_health_kind (SQ_HEALTH_NKINDS
 * entries; level/level.h): count, last value, last frame (1-based count of sq_body_frame calls,
 * sq_body_frames). A reset (blow-up, sq_body_reset) does not clear them */
const sq_health_stat *sq_body_health(const sq_body *b);
long sq_body_frames(const sq_body *b);
/* tets of the simulated level with det F <= 0 (inverted or flat) */
int sq_body_inverted_tets(const sq_body *b);

/* the linear model of tool t (index in the tool array of the last sq_body_frame, pose `tool`)
 * about the state that frame left: the held nodes' reaction and its stiffness with respect to
 * the tool position, by finite differences of the simulated level's own force pass (the
 * operator the step uses, corotational rotations included, frozen) with the held nodes moved
 * together (a grab) or along their contact normals (a push). Returns 0, or -1 (out->nnodes 0)
 * when the tool held nothing or the holds are not on the simulated level (a fixed body coarser
 * than its finest loaded level): then f0 = K = 0. Costs four force passes of the held nodes'
 * rows (linear) or of the whole level (corotational, pressure tets). */
int sq_body_tool_model(sq_body *b, int t, const sq_tool *tool, sq_tool_model *out);

/* contact (docs/physics.md section 13): the obstacles the body's surface nodes meet, borrowed
 * (the world's table: it must outlive the body or be replaced); n 0 = none. Fixed lod: the
 * simulated level's surface nodes after every step; adaptive: every level's integrated surface
 * nodes after each of its steps (lod/lod.h sq_lod_frame_in) */
void sq_body_set_obstacles(sq_body *b, const sq_obstacle *obs, int n);
/* the contact force on the body over the last frame (obstacles and other bodies: the impulses
 * of its contacts / frame_dt), N; the nodes in contact; the deepest penetration into an
 * obstacle left at the frame's last step, m */
void sq_body_contact_force(const sq_body *b, double force[3], int *nodes, double *depth);
/* thread CPU time of the last frame's contact passes (fixed lod: the obstacle passes of every
 * step, against obstacles and other bodies, and the update of its surface as a target; adaptive:
 * 0, the lod frame's passes are in its step time), s */
double sq_body_contact_cpu(const sq_body *b);
/* body against body every substep (docs/physics.md section 13): b's simulated level as a target
 * of another body's steps, its surface updated to where it stands now (fixed lod: the simulated
 * level's nodes; adaptive: the finest surface as combinations of the active nodes, lod.h
 * sq_lod_surface_map_get, its reactions handed back to them). The target stays valid until b
 * next changes; 0 */
int sq_body_contact_target(sq_body *b, double mu, sq_contact_target *out);
/* the targets b's next frame meets (borrowed; NULL/0: none): fixed bodies meet them with the
 * simulated level's surface nodes, adaptive ones with every level's integrated surface nodes
 * after each of its steps */
void sq_body_set_targets(sq_body *b, const sq_contact_target *t, int n);
/* the reactions other bodies' frames left on b, applied as velocity changes and counted in its
 * contact force (before_frame: b's own frame is next, counted in it) */
void sq_body_contact_apply(sq_body *b, int before_frame);
/* deepest penetration of a's surface nodes into b's surface (m; searched within b's mean
 * surface edge x 2): each body's simulated level, an adaptive body's finest surface as the
 * frame's push left it */
double sq_body_contact_depth(sq_body *a, sq_body *b);

/* write the finest level (or the fixed level) as VTK with displacement, velocity, level */
int sq_body_write_vtk(const sq_body *b, const char *path, sq_err *err);

/* engine-internal access to a body's levels (lod, tests, benchmarks): the level if it is
 * initialised, else NULL */
sq_level *sq_body_level(sq_body *b, int level);
/* the level simulated in fixed mode */
int sq_body_fixed_level(const sq_body *b);
/* the level that holds the simulated values: the fixed level, or in adaptive mode the finest
 * loaded level (every region's values are pushed there); energies, residual, probes, VTK and
 * the views of scene, net and app read this one */
int sq_body_sim_level(const sq_body *b);
/* sleep tolerances: calm for `frames` frames (0: never sleep) with rms speed below
 * ke_speed bbox diagonals per second and sq_body_residual below `residual` (defaults 25, 1e-4, 1e-4) */
void sq_body_set_sleep(sq_body *b, int frames, double ke_speed, double residual);

#endif
