/* lod.h - adaptive levels of detail over a body's non-nested meshes (paper sections 3-4).
 *
 * Third stage of the data flow. The hierarchy links each level to the next: every node of
 * level k+1 has a parent, the nearest node of level k (its Voronoi region), and every node
 * stores barycentric coordinates in its containing (or nearest) tetrahedron of the parent
 * mesh and of the child mesh. The adaptive state marks nodes active or ghost per level and
 * runs the paper's per-level algorithm: pull ghosts from finer levels, integrate active
 * nodes, push ghosts to finer levels, split/merge on delta_i = hbar_i^2 |Lap(d)_i|.
 *
 * body/body.c owns the levels (level/level.h) and calls this module when lod.mode is adaptive.
 */
#ifndef SQ_LOD_H
#define SQ_LOD_H

#include "contact/contact.h"
#include "level/level.h"

typedef enum sq_lod_mode { SQ_LOD_FIXED = 0, SQ_LOD_ADAPTIVE = 1 } sq_lod_mode;
typedef struct sq_lod_def {
    sq_lod_mode mode;
    int level;            /* fixed mode: the level simulated; adaptive: the starting level */
    double split;         /* adaptive: split when delta_i > split (m); 0 forces finest */
    double merge;         /* adaptive: merge when all children delta < merge (< split) */
    int max_level;        /* highest level index used (caps the levels list) */
    double budget;        /* fraction of the frame period above which splits stop (0.95) */
    long max_node_updates;/* hard cap on node updates per frame (0 = none) */
    int adapt_every;      /* frames between split/merge passes: 1 (or 0) every frame, N every Nth */
} sq_lod_def;
#define SQ_LOD_ADAPT_EVERY_MAX 1000 /* adapt_every: at most a split/merge pass every 1000 frames */

/* the stages of an adaptive frame, in the order sq_lod_frame runs them (lod/frame.c); the
 * pull and step stages run at every tick of the finest substep clock, their times summed */
typedef enum sq_lod_stage {
    SQ_LOD_STAGE_GUARD,      /* the budget: splits allowed, the node-update cap that fits */
    SQ_LOD_STAGE_LAYOUT,     /* coupling blocks and substeps, merges the cap asks for, clock */
    SQ_LOD_STAGE_HOLDS,      /* tool holds onto active nodes */
    SQ_LOD_STAGE_PULL,       /* ring ghost values of the due levels (prof t_pull) */
    SQ_LOD_STAGE_STEP,       /* forces, coupling reactions, integration (lod's t_integrate) */
    SQ_LOD_STAGE_CRITERION,  /* split/merge decisions at the frame's end */
    SQ_LOD_STAGE_ADAPT,      /* changed levels and coupling rebuilt (t_adapt: with criterion) */
    SQ_LOD_STAGE_PUSH,       /* ghosts up to date for the viewer and the next frame (t_push) */
    SQ_LOD_STAGE_FEEDBACK,   /* tool forces from the held nodes, holds released */
    SQ_LOD_STAGES
} sq_lod_stage;
/* short lower-case name of a stage ("guard", "pull", ...), "?" out of range */
const char *sq_lod_stage_name(int stage);

/* per-frame profile (one body); times in seconds */
typedef struct sq_frame_profile {
    double t_pull, t_integrate, t_push, t_adapt, t_tools, t_health, t_total;
    double t_stage[SQ_LOD_STAGES];     /* adaptive frames: wall time of each sq_lod_stage (0 fixed) */
    long node_updates;                 /* active-node integrations this frame */
    /* adaptive frames, the interface's work beside the node updates (0 fixed): ring ghost
     * values evaluated (a combination of ~7 active sources each), ring rows (a ghost's force
     * handed back to its sources), frontier rows (active rows with half of the mixed tets) */
    long ring_values, ring_rows, frontier_rows;
    int active[SQ_MAX_LEVELS];         /* active nodes per level */
    int substeps[SQ_MAX_LEVELS];       /* 2^n steps per frame per level */
    int splits, merges;
    int splits_refused;                /* 1 if splitting was forbidden this frame (budget) */
    int sleeping;                      /* 1 if the body slept (no updates) this frame */
    int awake_nodes, sleeping_nodes;
    int reset;                         /* 1 if a blow-up was detected and the body reset */
    int cg_iterations;                 /* implicit: CG iterations of the frame's solves (0: explicit) */
    double cg_residual;                /* implicit: largest final relative CG residual of the frame */
    int newton_iterations;             /* implicit: Newton iterations of the frame's steps */
    double newton_residual;            /* implicit corotational, newton > 1: the last relative residual */
    char event[160];                   /* human-readable event of this frame, or empty */
    sq_health_kind event_kind;         /* its kind (SQ_HEALTH_NONE: no event) */
    double event_value[4];             /* its values (sq_health_sentence) */
} sq_frame_profile;

/* set the frame's health event: kind, values and the sentence built from them */
static inline void sq_frame_event(sq_frame_profile *p, sq_health_kind k, double v0, double v1, double v2,
                                  double v3, const char *body)
{
    p->event_kind = k;
    p->event_value[0] = v0;
    p->event_value[1] = v1;
    p->event_value[2] = v2;
    p->event_value[3] = v3;
    sq_health_sentence(p->event, sizeof p->event, k, p->event_value, body);
}


/* links between level k and level k+1 */
typedef struct sq_lod_link {
    int *parent;          /* for each node of level k+1: nearest node of level k (n_{k+1}) */
    int *child_start;     /* CSR over level-k nodes: children of p are child[child_start[p]..) (n_k+1) */
    int *child;           /* level-(k+1) node indices (n_{k+1}) */
    int *up_tet;          /* for each node of level k+1: containing/nearest tet of level k (n_{k+1}) */
    double *up_bary;      /* its barycentric coordinates (n_{k+1} x 4) */
    int *down_tet;        /* for each node of level k: containing/nearest tet of level k+1 (n_k) */
    double *down_bary;    /* its barycentric coordinates (n_k x 4) */
} sq_lod_link;

typedef struct sq_hierarchy {
    int nlevels;
    const sq_mesh *mesh[SQ_MAX_LEVELS];
    sq_lod_link link[SQ_MAX_LEVELS - 1]; /* link[k] joins level k and k+1 */
} sq_hierarchy;

/* build and validate (every fine node has a parent, coordinates sum to 1) */
int sq_hierarchy_build(sq_hierarchy *h, const sq_mesh *const *meshes, int nlevels, sq_err *err);
void sq_hierarchy_free(sq_hierarchy *h);

/* counts describing link k (levels k and k+1), for reports and tests */
typedef struct sq_hierarchy_link_stats {
    int nparents, nchildren;           /* nodes of level k and of level k+1 */
    int childless;                     /* level-k nodes whose Voronoi region holds no k+1 node */
    int min_children, max_children;
    double mean_children;
    int up_outside, down_outside;      /* nodes outside the other mesh (one negative coordinate) */
    double up_min_bary, down_min_bary; /* most negative coordinate seen (0 if none) */
} sq_hierarchy_link_stats;
void sq_hierarchy_stats(const sq_hierarchy *h, int k, sq_hierarchy_link_stats *st);

typedef struct sq_lod sq_lod;

/* adaptive state over levels[0..nlevels-1] (borrowed from the body) */
sq_lod *sq_lod_create(sq_level *levels, int nlevels, const sq_lod_def *def, sq_err *err);
/* the same over levels of the same meshes as like's (a scratch copy: the load check,
 * scene/world.c): the hierarchy and the per-level tables that depend on the meshes alone
 * (criterion weights, tets around each node, tet gradients) are like's, read only, not built
 * again; like must outlive the new state. Other meshes: as sq_lod_create */
sq_lod *sq_lod_create_like(sq_level *levels, int nlevels, const sq_lod_def *def, const sq_lod *like,
                           sq_err *err);
void sq_lod_destroy(sq_lod *lod);
int sq_lod_set_def(sq_lod *lod, const sq_lod_def *def, sq_err *err);
/* all nodes back to the coarsest level (state of the levels is reset by the body) */
void sq_lod_reset(sq_lod *lod);
const sq_hierarchy *sq_lod_hierarchy(const sq_lod *lod);
/* active mask of a level (1 = active, 0 = ghost) */
const unsigned char *sq_lod_active(const sq_lod *lod, int level);

/* what one adaptive frame is given */
typedef struct sq_lod_frame_in {
    const sq_material *mat;  /* the body's material */
    double gravity[3];       /* m/s^2 */
    double frame_dt;         /* s */
    const sq_hold *holds;    /* tool holds on finest nodes (nholds of them) */
    int nholds;
    int ntools;              /* tools the holds name (force has ntools entries) */
    double budget_s;         /* frame period of the budget, s (0 = no limit) */
    const sq_obstacle *obstacles; /* met by every level's integrated surface nodes after each of
                                     its steps (contact/contact.h), nobstacles of them */
    int nobstacles;
    const sq_contact_target *targets; /* other bodies' surfaces, met by the same nodes after the
                                         obstacles (body against body), ntargets of them */
    int ntargets;
    sq_contact_sum *contact; /* the contact impulses are added here (may be NULL) */
    unsigned char **touched; /* NULL, or per level an array (nodes) set to 1 where contact acted */
    /* NULL, or live holds (a haptic device between frames): called at each tick with the
     * fraction of the frame at that tick's end, returns 1
     * when targets changed, with on[h] 1 for the holds that follow a live tool and target[h]
     * (3 each) their targets now; their nodes are moved by the change (sq_lodx_hold_live) */
    int (*live)(void *arg, double frac, const unsigned char **on, const double **target);
    void *live_arg;
    /* NULL, or nfocus spheres (centre x, y, z, radius; m, the body's coordinates) kept at the
     * finest level: at the frame's end the active nodes inside one split whatever the
     * criterion says (within the budget and the node-update cap) and split nodes inside one
     * do not merge (a haptic channel's tool: a split near the tool would change its force in
     * a step) */
    const double (*focus)[4];
    int nfocus;
} sq_lod_frame_in;

/* one adaptive frame of in->frame_dt: each level steps at its own dt (level->dt), in the
 * paper's order, as the stages of sq_lod_stage. Holds are applied to the node itself when it
 * is active, else the same translation goes to its closest active node (its active
 * ancestor). force[t] (may be NULL) receives the feedback force of tool t (sum over its held
 * nodes of the elastic reaction), in->ntools entries zeroed first. Splits are refused when
 * the previous frame's compute time exceeded def.budget * in->budget_s. Fills prof (may be
 * NULL: active counts, updates, splits/merges, stage times). */
void sq_lod_frame(sq_lod *lod, const sq_lod_frame_in *in, double (*force)[3], sq_frame_profile *prof);

/* thread CPU time (s) the caller spent on this thread since the last frame on work that is
 * not the product's (a measuring harness: `squish tradeoff`'s error sampling): kept out of the
 * guard's time around the frame (docs/lod.md, "Guaranteed frame rate"); adds up until the
 * next frame */
void sq_lod_untimed(sq_lod *lod, double cpu_s);
/* a live budget will follow (the server, `squish run --realtime`, the trade-off's guarded runs):
 * the coupling arrays every pass writes reserved and their pages mapped, and the guard's pass
 * costs calibrated (two passes that change nothing), now, at load, instead of in the first
 * budgeted frame (docs/lod.md "Guaranteed frame rate"); returns the pages mapped. Without it
 * the first budgeted frame does both */
long sq_lod_prepare_budget(sq_lod *lod);

/* level active at each node of the finest level (out has n_finest entries); the walk is
 * skipped when the states did not change since the last call with the same buffer */
void sq_lod_node_levels(sq_lod *lod, unsigned char *out);

/* active nodes of a level, increasing (*n of them) */
const int *sq_lod_active_list(const sq_lod *lod, int level, int *n);

/* coarse ghosts that nothing in the frame reads are pushed on demand (docs/lod.md, "Cost that
 * follows the active set"): bring every ghost value up to date before reading a level's whole
 * field (the body's accessors call it); a no-op when nothing is out of date */
void sq_lod_flush(sq_lod *lod);
/* the displacement of node `node` of level `level` as sq_lod_flush would leave it, without
 * flushing (a probe reads four nodes: a flush pushes every stale coarse ghost of the body) */
void sq_lod_flushed_d(const sq_lod *lod, int level, int node, double d[3]);

/* the finest level's surface as the active nodes make it, for an adaptive body that is another
 * body's contact target (docs/physics.md section 13): each finest surface node as a combination
 * of active nodes (its "unknowns"): itself when active, else its interpolation expanded through
 * the hierarchy (coarse ghost: its parent tet, split ghost: its child tet) down to active nodes,
 * duplicates merged, the weights renormalised to 1 as the ring ghosts' sources are. A node with
 * a constrained axis (which the push holds at zero) stands for the anchor (unknown 0: infinite
 * mass, it moves nothing), a finest node without an active source too. The rows sum to 1, so an
 * impulse handed back through the transpose keeps its sum (momentum). Rebuilt when the node
 * states change; valid until then */
typedef struct sq_lod_surface_map {
    int nrow;                 /* the finest level's nodes (rows off the surface are empty) */
    const int *start;         /* row j: entries start[j] .. start[j + 1] - 1 (nrow + 1) */
    const int *dof;           /* each entry's unknown */
    const double *w;          /* each entry's weight */
    int ndof;                 /* unknowns: the anchor (0), then the active nodes named */
    const int *level, *node;  /* each unknown's active node; the anchor's -1, -1 */
} sq_lod_surface_map;
const sq_lod_surface_map *sq_lod_surface_map_get(sq_lod *lod);

/* the material the next frames use (sq_lod_frame passes it too): lets sq_lod_energy and
 * sq_lod_sync account for the level coupling before the first frame */
void sq_lod_set_material(sq_lod *lod, const sq_material *mat);

/* the frame's material and loads before the first frame: the coupling blocks and each level's
 * static equilibrium under gravity (the criterion judges the displacement from it, so a sag
 * alone refines nothing) are set up here instead of in the first frame */
void sq_lod_set_loads(sq_lod *lod, const sq_material *mat, const double gravity[3]);
/* the same, taking the static equilibria from like (copied) when like solved them for the same
 * gravity, material, top level and level-0 operator (the same numbers a solve gives: the
 * operator is the same blocks, sq_level_init_shared); else solved as sq_lod_set_loads does */
void sq_lod_set_loads_like(sq_lod *lod, const sq_material *mat, const double gravity[3], const sq_lod *like);

/* the step rule ("step_bound": docs/stability.md, docs/lod.md "Coupling the levels"): sharp = 0
 * (default) gives each level its own Gershgorin exponent plus the interface extra; sharp = 1
 * the smallest 2^n at step_fraction of the damped bound from a Lanczos estimate of the
 * block-diagonal majorant of the coupled operator (bound.c), recomputed after each rebuild
 * for the levels whose operator changed;
 * without viscosity only (with it the Gershgorin rule stays). Recomputes when it changes. */
void sq_lod_set_step_rule(sq_lod *lod, int sharp, double step_fraction);
/* sharp rule on: level k's estimate of lambda_max (1/s^2; 0 without active nodes), its
 * Gershgorin ceiling and the Lanczos steps of the last estimate; returns 0 when the rule is off */
int sq_lod_sharp_info(const sq_lod *lod, int k, double *lambda, double *gersh, int *iters);
/* estimates made so far (one per level with active nodes per rebuild) and their thread CPU time */
void sq_lod_sharp_cost(const sq_lod *lod, long *calls, double *cpu_s);

/* energy (J) of the simulated state, the quantity the adaptive frame conserves without
 * damping: kinetic 1/2 m_i |v_i|^2 over the active nodes of every level, and elastic energy
 * of every tet touching an active node (ghost corners at their interpolated values); either
 * output may be NULL; returns their sum */
double sq_lod_energy(const sq_lod *lod, double *kinetic, double *elastic);

/* node updates one frame of the current active sets costs: sum_k active_k 2^n_k */
long sq_lod_projected_updates(const sq_lod *lod);

/* steps per frame of each level as the layout stands (the profile's substeps of a frame
 * stepped now), 0 past the loaded levels */
void sq_lod_substeps(const sq_lod *lod, int out[SQ_MAX_LEVELS]);

/* the split/merge criterion delta = hbar^2 |Lap(d)| at a node of a level, from the level's
 * current values. The Laplacian is the lumped FEM one with the boundary flux of the local
 * gradient removed on surface nodes, so any linear field gives 0 everywhere (m). */
double sq_lod_delta(const sq_lod *lod, int level, int node);

/* one split/merge pass over every pair of levels at the current state (all levels at the same
 * time), as sq_lod_frame does at its synchronisation points, then ghosts brought up to date;
 * returns 1 if a split was refused (allow_split 0 or the node-update cap), else 0 */
int sq_lod_adapt(sq_lod *lod, int allow_split, int *splits, int *merges);

/* consistency of the active/ghost tree (level-0 nodes are never coarse ghosts, a node is a
 * coarse ghost exactly when its parent is not split, the top level never splits); 0 or -1 + err */
int sq_lod_check(const sq_lod *lod, sq_err *err);

/* bring every ghost value (displacement and velocity) up to date from the active nodes:
 * pull split nodes from finer levels, then push coarse ghosts from coarser levels. Call after
 * changing level state outside sq_lod_frame (e.g. setting an initial displacement). */
void sq_lod_sync(sq_lod *lod);

#endif
