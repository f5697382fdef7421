/* body_internal.h - the body's private state and helpers, shared by the files of body/. */
#ifndef SQ_BODY_INTERNAL_H
#define SQ_BODY_INTERNAL_H

#include "body/body.h"
#include "contact/contact.h"

struct sq_lod;

/* a grab tool's capture: finest surface vertices and their displacement at capture time */
typedef struct sq_grab {
    int id;                /* tool id, -1 when free */
    int n;                 /* captured surface vertices */
    int *surf;             /* surface vertex indices (n) */
    double *disp;          /* displacement at capture (n x 3), m */
    double start[3];       /* tool position at capture, m */
} sq_grab;

struct sq_body {
    sq_body_def def;                       /* copy; name points at `name` */
    char name[64];
    int nuse;                              /* levels loaded: nlevels capped by max_level + 1 */
    int fine;                              /* finest loaded level (nuse - 1): the rendered surface */
    int cur;                               /* fixed mode: the simulated level */
    sq_level level[SQ_MAX_LEVELS];
    int ready[SQ_MAX_LEVELS];              /* level initialised */
    const sq_body *like;                   /* during sq_body_create_like: the body whose levels' step
                                              estimates are reused (NULL otherwise) */
    unsigned char *mask[SQ_MAX_LEVELS];    /* integration mask (held nodes 0) (n_k) */
    int *hold_of[SQ_MAX_LEVELS];           /* scratch: hold index per node or -1 (n_k) */
    struct sq_lod *lod;                    /* adaptive mode state, else NULL */
    double diag;                           /* finest rest bounding-box diagonal, m */

    /* finest surface vertex -> fixed level map (valid for map_level) */
    int map_level;
    int *surf_tet;                         /* tet of level map_level (nsurf) */
    double *surf_bary;                     /* its barycentrics (nsurf x 4) */
    int *surf_near;                        /* nearest level node (nsurf) */
    unsigned char *node_level;             /* level per finest node (n_fine) */

    /* tools */
    sq_grab grab[SQ_MAX_TOOLS];
    sq_hold *holds;                        /* this frame's holds on finest nodes */
    int nholds;                            /* their number (haptic.c reads the last frame's) */
    int cap_holds;
    sq_hold *khold;                        /* holds mapped to the fixed level */
    int *kcount;                           /* holds averaged into each khold */
    int cap_khold;
    int *khold_of;                         /* fixed level: the khold of each hold (nholds) */
    /* live poses between frame starts (haptic.c, sq_body_set_pose_source) */
    sq_pose_source_fn pose_fn;
    void *pose_arg;
    int live;                              /* this frame has live tools */
    int live_tool[SQ_MAX_TOOLS];           /* 1: tool index t reads its pose at each substep */
    int live_id[SQ_MAX_TOOLS];
    double live_from[SQ_MAX_TOOLS][3];     /* its pose at the frame's start */
    double live_pos[SQ_MAX_TOOLS][3];      /* the newest pose read */
    double *live_P;                        /* per hold: how its target follows the tool (9) */
    double *live_target;                   /* per hold: its target now (3) */
    unsigned char *live_on;                /* per hold: its tool is live */
    double *live_shift;                    /* fixed level: per khold, the summed shift (3) */
    int cap_live;

    /* nodes held by a tool in the last frame, per level (n_k, 1 = held), for the rest check */
    unsigned char *held[SQ_MAX_LEVELS];
    int *held_list[SQ_MAX_LEVELS];         /* their indices (n_k capacity) */
    int nheld[SQ_MAX_LEVELS];

    /* health: counters per kind (sq_body_health), the body's frame count */
    sq_health_stat health[SQ_HEALTH_NKINDS];
    long frames;

    /* explicit fixed step: a diverged frame is re-run from its start with 2x substeps (at most
     * SQ_RETRY_MAX times); the factor that held is kept for the next frames and halved after
     * SQ_RETRY_CALM frames without a retry */
    double *save_d, *save_v, *save_q;      /* the frame's start state (after the holds) */
    size_t save_n3, save_nq;
    int boost, boost_calm;
    /* the last blow-up test of the state (sq_body_diverged) and the frame it was made in: the
     * explicit frame's test is the health check's when nothing stepped in between */
    long div_frame;
    sq_health_kind div_kind;
    double div_value;

    /* sleep */
    int sleeping, calm;
    int sleep_frames;                      /* calm frames before sleeping (0: never sleep) */
    double sleep_ke_speed;                 /* rms speed below this many bbox diagonals per second */
    double sleep_residual;                 /* sq_body_residual-style measure below this */

    /* contact (body/contact.c): the world's obstacles (borrowed), this frame's impulses and
     * the simulated levels' surfaces for body against body */
    const sq_obstacle *obstacles;
    int nobstacles;
    sq_contact_sum contact;
    double contact_cpu;                    /* this frame's thread CPU time in contact passes, s */
    sq_contact_surface *csurf[SQ_MAX_LEVELS];
    sq_contact_cache *ccache;              /* the fixed level's mesh-obstacle distances this frame */
    const sq_contact_target *targets;      /* other bodies' surfaces met this frame (the world's) */
    int ntargets;
    double *reaction;                      /* impulses on this body's nodes from others' frames (n x 3) */
    size_t reaction_n3;
    double carry[3];                       /* reaction impulses applied before this frame's start */
    /* an adaptive body as a target: its finest surface from its active nodes (lod's map, valid
     * from sq_body_contact_target to sq_body_contact_apply) and each unknown's velocity, mass,
     * constrained and held marks; reaction is then per unknown */
    const struct sq_lod_surface_map *tmap;
    double *tdof_v, *tdof_mass;
    unsigned char *tdof_fixed, *tdof_mask;
    int tdof_cap;
    unsigned char *touched[SQ_MAX_LEVELS]; /* nodes in contact this frame, per level (n_k): left
                                              out of the sleep test's residual */
    int touched_n[SQ_MAX_LEVELS];
    /* the implicit integrator's contact constraints (docs/physics.md section 13): where the
     * obstacle pass met each node of the simulated level (n), and the list of the next solve's
     * constraints (the last pass's nodes, and the last solve's that still pushed) */
    sq_contact_point *cpoint;
    int cpoint_n, cstamp;
    int ncon;
    int *con_node;
    sq_contact_point *con_pt;
    double *con_normal, *con_u, *con_imp, *con_f; /* per constraint: 3 each */
    double *con_vrel;                      /* per constraint: prescribed normal speed off the obstacle */
    unsigned char *con_stick;              /* per constraint */
    int *con_mark;                         /* per node: its constraint's index + 1 this step, or 0 */
    sq_implicit_contacts con_set;
    double *cond_x;                        /* haptic.c: the tool model's free-node relaxations, 3 x 3n */
    size_t cond_n3;
};

#define SQ_RETRY_MAX 4    /* doublings of a diverged frame's substeps: up to 16x */
#define SQ_RETRY_CALM 50  /* frames at a raised count before trying half of it */

/* Lanczos steps of the sharp step bound (fixed mode; docs/stability.md) */
#define SQ_LANCZOS_ITERS 40

/* ---- haptic.c: live poses within the frame ---- */
/* how hold h's target follows tool `tool` (3x3, row-major): a grab the identity, a push
 * n n^T along the node's contact normal n (also returned; 0 for a grab) */
void sq_body_hold_projection(const sq_mesh *m, const sq_hold *h, const sq_tool *tool, double P[9], double n[3]);
/* the frame's live tools (after the holds are made): b->live, per hold its projection */
void sq_body_live_begin(sq_body *b, const sq_tool *tools, int ntools);
/* at a substep ending at fraction frac of the frame: the poses read; 1 when a live hold's target changed since the last
 * call (b->live_target, b->live_on then hold them) */
int sq_body_live_refresh(sq_body *b, double frac);

/* ---- contact.c ---- */
/* one step's contact of level L's surface nodes with the obstacles and the other bodies'
 * surfaces (mask: NULL or 0 at held nodes), after the step of length h; impulses into
 * b->contact */
void sq_body_contact_step(sq_body *b, sq_level *L, const unsigned char *mask, double h);
void sq_body_contact_free(sq_body *b);
/* a new frame's contact: the touched marks cleared (allocated as levels need them) */
void sq_body_contact_begin(sq_body *b);
/* a diverged explicit frame is re-run: the reactions it gave its targets are dropped */
void sq_body_contact_retry(sq_body *b);
/* implicit: the contact constraints of level L's next step (set on L; none without obstacles) */
void sq_body_contact_constraints(sq_body *b, sq_level *L, double h);
/* implicit: after the step of length h, the constraints' impulses and friction into b->contact */
void sq_body_contact_constrained(sq_body *b, sq_level *L, double h);

/* ---- body.c: levels, state transfer, surface map, validation ---- */
/* interpolate a per-node field (n x 3) of mesh m at tet t with barycentrics bary */
void sq_body_interp3(const sq_mesh *m, const double *field, int t, const double bary[4], double out[3]);
/* initialise level k if it is not yet (operator, step bounds, masks); state at rest */
int sq_body_ensure_level(sq_body *b, int k, sq_err *err);
/* the explicit step figures of level L of an implicit body (never refused: capped at 2^20) */
void sq_body_explicit_estimate(const sq_body *b, sq_level *L, const sq_material *m, int reuse);
/* forget which nodes of level k a tool held (released: reset or lod change) */
void sq_body_clear_held(sq_body *b, int k);
/* copy displacement and velocity from level src to level dst by interpolation */
void sq_body_transfer_state(sq_body *b, int src, int dst);
/* per finest surface vertex: tet and barycentrics in the fixed level, and its nearest node */
void sq_body_prepare_surface_map(sq_body *b);
/* node_level of every finest node = the fixed level */
void sq_body_set_levels_fixed(sq_body *b);
/* is this combination allowed? 0, or -1 + err naming it */
int sq_body_check_pressure(int nodal, sq_elasticity_kind e, sq_operator_kind op, sq_lod_mode mode, sq_err *err);
int sq_body_check_elasticity(sq_elasticity_kind e, sq_operator_kind op, sq_lod_mode mode, sq_err *err);
int sq_body_check_lod(const sq_body *b, const sq_lod_def *lod, sq_err *err);

/* substeps per frame of a fixed level: 2^n at the Gershgorin bound, or with sharp_step the
 * sharp bound's 2^n (the rule of adaptive mode's levels too) */
static inline int sq_body_fixed_nsub(const sq_body *b, const sq_level *L)
{
    if (b->def.integrator == SQ_INTEGRATOR_IMPLICIT)
        return b->def.implicit.substeps;
    return b->def.sharp_step ? L->nsub : 1 << L->substeps_log2;
}

/* ---- health.c ---- */
/* the blow-up test of the simulated state: non-finite values, displacement beyond 10 bbox
 * diagonals, or kinetic energy above 0.5 M (10 diag / frame_dt)^2; SQ_HEALTH_NONE if healthy */
sq_health_kind sq_body_diverged(const sq_body *b, double *value);
/* the same, remembered for this frame (b->frames): the explicit frame tests its end state and
 * the health check after it reads the answer instead of testing again */
sq_health_kind sq_body_diverged_now(sq_body *b, double *value);
/* count a health warning (kind NONE: nothing) with its value at the body's current frame */
void sq_body_count_health(sq_body *b, sq_health_kind k, double value);
/* after the frame's steps: health (a blow-up resets the body to rest and returns 1) and the
 * sleep test; sets prof's event */
int sq_body_check_health(sq_body *b, sq_frame_profile *prof, int nholds);

/* displacement of finest surface vertex s (interpolated from the fixed level when coarser) */
void sq_body_surface_disp(const sq_body *b, int s, double u[3]);

/* turn the frame's tools into b->holds; tool_nodes[t] = nodes held by tool t; returns nholds */
int sq_body_tool_holds(sq_body *b, const sq_tool *tools, int ntools, int *tool_nodes);

#endif
