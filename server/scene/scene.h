/* scene.h - JSON scene files and the running world (bodies, tools, probes).
 *
 * A scene (sq_scene) is the parsed, validated file with its meshes loaded: immutable and
 * shareable between sessions (every mesh, its point-location grid included, is fully built
 * at load, so worlds on several threads may read one scene). The format is in docs/scenes.md. A world (sq_world) is one running instance of a scene: its
 * bodies' state, tool poses, frame counter. The server holds one world per session; the
 * batch command line holds one.
 */
#ifndef SQ_SCENE_H
#define SQ_SCENE_H

#include "body/body.h"

#define SQ_MAX_BODIES 8
#define SQ_MAX_PROBES 32
#define SQ_MAX_KEYFRAMES 256

typedef struct sq_keyframe {
    double t;          /* simulated time, s */
    double pos[3];
    int active;
} sq_keyframe;

/* a scripted tool: pose interpolated linearly between keyframes; active of the last
 * keyframe at or before t */
typedef struct sq_tool_script {
    sq_tool tool;      /* shape, radius/half, id */
    char name[64];
    int nkeys;
    sq_keyframe keys[SQ_MAX_KEYFRAMES];
} sq_tool_script;

/* an obstacle of the scene: its placement at t = 0 and optional keyframes of its translation
 * (pos: the offset from that placement, linear between keyframes; meshes are static) */
typedef struct sq_obstacle_script {
    sq_obstacle obstacle;
    int nkeys;
    sq_keyframe keys[SQ_MAX_KEYFRAMES];
} sq_obstacle_script;

typedef struct sq_probe {
    char name[64];
    int body;
    double point[3];   /* rest-space point */
} sq_probe;

/* a haptic channel's settings: the ranges of the scene's "haptic" block and of the protocol's
 * haptic request (docs/scenes.md, docs/protocol.md "Haptic channel") */
#define SQ_HAPTIC_STIFFNESS_MAX 1e5  /* coupling spring, N/m, from 0 */
#define SQ_HAPTIC_DAMPING_MAX 1e3    /* coupling damper, N s/m, from 0 */
#define SQ_HAPTIC_DEVICE_MASS_MIN 1e-3 /* the device's moving mass, kg */
#define SQ_HAPTIC_DEVICE_MASS_MAX 100.0
#define SQ_HAPTIC_FOCUS_MAX 100.0    /* tool sizes kept at the finest level, from 0 */
enum { SQ_SCENE_HAPTIC_STIFFNESS = 1, SQ_SCENE_HAPTIC_DAMPING = 2, SQ_SCENE_HAPTIC_DEVICE_MASS = 4,
       SQ_SCENE_HAPTIC_FOCUS = 8 };
typedef struct sq_scene_haptic {
    double stiffness, damping, device_mass, focus;
    unsigned given; /* SQ_SCENE_HAPTIC_* of the values the scene gives (others: the channel's
                       own defaults); 0 in a zeroed scene */
} sq_scene_haptic;

typedef struct sq_scene {
    char name[64];
    char description[256];
    char path[512];        /* scene file, or "<default>" */
    double gravity[3];
    double frame_rate;     /* Hz */
    int nbodies;
    sq_body_def bodies[SQ_MAX_BODIES];
    char body_names[SQ_MAX_BODIES][64];
    sq_mesh *meshes[SQ_MAX_BODIES][SQ_MAX_LEVELS]; /* owned */
    int ntools;
    sq_tool_script tools[SQ_MAX_TOOLS];
    int nprobes;
    sq_probe probes[SQ_MAX_PROBES];
    int nobstacles;
    sq_obstacle_script obstacles[SQ_MAX_OBSTACLES];
    sq_trimesh *trimeshes[SQ_MAX_OBSTACLES];      /* owned: the mesh obstacles' triangles */
    int body_contact;      /* "contact".bodies: bodies collide with each other, fixed or adaptive lod (default 1) */
    double body_friction;  /* "contact".friction between bodies (default 0.5) */
    double duration;       /* default run length of `squish run`, s (key "duration", default 2) */
    sq_scene_haptic haptic; /* "haptic": the defaults of a haptic channel opened on this scene */
    int nlisted[SQ_MAX_BODIES];                   /* levels listed in the file per body */
    int nwarnings;                                /* load-time warnings (sq_scene_load prints them) */
    char warnings[SQ_MAX_BODIES][400];            /* e.g. an implausible mesh size: "scale" */
    int level_index[SQ_MAX_BODIES][SQ_MAX_LEVELS]; /* listed index of each loaded level */
} sq_scene;

/* the phrase a load error contains when a mesh file is missing and the scene says how its
 * meshes are made ("meshes_made_by", e.g. "make meshes"): callers that iterate the shipped
 * scenes skip such a scene (strstr(err.msg, SQ_SCENE_MESHES_NOT_MADE)) instead of failing */
#define SQ_SCENE_MESHES_NOT_MADE "meshes not made yet"

/* load and validate a scene file; unknown keys and wrong types are errors naming the JSON
 * path (e.g. "bodies[0].material.nu: must be in [0, 0.5)") */
sq_scene *sq_scene_load(const char *path, sq_err *err);
/* parse from text; mesh paths relative to base_dir */
sq_scene *sq_scene_parse(const char *json, const char *base_dir, const char *label, sq_err *err);
/* the embedded default scene: the paper's 1 m cube (section 2.6) */
sq_scene *sq_scene_default(sq_err *err);
void sq_scene_free(sq_scene *s);

/* what only the engine can check (every node fixed, a step bound needing more than 2^20
 * substeps, an adaptive hierarchy that cannot be built): creates each body once and frees
 * it; 0, or -1 + err prefixed "<scene path>: bodies[i] ("name")". Costs one operator
 * precomputation per body; sq_world_create reports the same errors. */
int sq_scene_check(const sq_scene *s, sq_err *err);

/* the scenes a server offers (dir.c), each with the name clients open it by */
typedef struct sq_scene_list {
    int n;
    sq_scene **scenes;       /* owned */
    char (*names)[64];       /* the scene's "name" ("default" for the built-in cube) */
} sq_scene_list;

/* add every *.json of dir, in name order, each loaded, validated and checked
 * (sq_scene_check); a bad file, or one whose name is taken, is reported on stderr as
 * "<who>: skipping scene ..." and skipped. -1 if dir cannot be read (nothing added). */
int sq_scene_list_load_dir(sq_scene_list *l, const char *dir, const char *who);
/* append sc (the list owns it) under name */
void sq_scene_list_add(sq_scene_list *l, sq_scene *sc, const char *name);
/* index of the scene called name, or -1 */
int sq_scene_list_find(const sq_scene_list *l, const char *name);
/* free the scenes and the arrays; the list is empty again */
void sq_scene_list_free(sq_scene_list *l);

/* pose of a scripted tool at simulated time t: position interpolated linearly between the
 * keyframes around t (held before the first and after the last); active taken from the last
 * keyframe at or before t (inactive before the first keyframe); while active, origin is the
 * position of the keyframe that activated it (sq_tool.origin) */
void sq_tool_script_pose(const sq_tool_script *s, double t, sq_tool *out);

/* the obstacle at simulated time t (its translation from the keyframes, velocity over the
 * frame ending at t of length dt) */
void sq_obstacle_script_pose(const sq_obstacle_script *s, double t, double dt, sq_obstacle *out);

/* world: one running instance of a scene */
typedef struct sq_world {
    const sq_scene *scene;   /* borrowed */
    int nbodies;
    sq_body *bodies[SQ_MAX_BODIES];
    long frame;              /* frames stepped */
    double time;             /* simulated time, s */
    int ntools;
    sq_tool tools[SQ_MAX_TOOLS];           /* current poses (scripted or set live) */
    int tool_scripted[SQ_MAX_TOOLS];       /* 1 while driven by the scene's keyframes */
    sq_tool_feedback feedback[SQ_MAX_BODIES][SQ_MAX_TOOLS];
    sq_frame_profile profile[SQ_MAX_BODIES];
    int nobstacles;
    sq_obstacle obstacles[SQ_MAX_OBSTACLES]; /* the scene's obstacles at the current time */
    long deadline_misses;
    long resets;
    double last_frame_s;     /* wall-clock compute time of the last frame, s */
    /* per tool slot: the body a grab's nearest-node fallback may take (-1: none), decided
     * once per capture point (grab_at) */
    int grab_known[SQ_MAX_TOOLS];
    int grab_fallback[SQ_MAX_TOOLS];
    double grab_at[SQ_MAX_TOOLS][3];
    /* the live pose source the bodies read at each substep (NULL: none; sq_world_set_pose_source) */
    sq_pose_source_fn pose_fn;
    void *pose_arg;
} sq_world;

sq_world *sq_world_create(const sq_scene *scene, sq_err *err);
void sq_world_destroy(sq_world *w);
void sq_world_reset(sq_world *w);
/* real time at load (docs/lod.md "The load check times a real coarse frame"): the thread CPU
 * time of one frame with every body fully coarse (an adaptive body at its level 0, a fixed one
 * at its level), the mean of real frames (after a warm-up) of a scratch world whose bodies are
 * fresh copies forced fully coarse (sq_body_create_like), so integration, substeps, ghost
 * levels and the frame's fixed cost are in it; w is only read (its tools copied, one force pass
 * per body timed on its state to name the part that grows with the steps). The copies borrow
 * the bodies' operators, hierarchies and mesh tables (read only) and have their own state only:
 * on box-big 26-31 ms of CPU and 20 MB while it runs (docs/lod.md). Returns 1 and a warning in msg
 * when it exceeds the budget (the body's budget fraction of period_s), with the numbers and
 * what to do; else 0 and the figures in msg. */
int sq_world_realtime_check(sq_world *w, double period_s, char *msg, size_t n);
/* advance one frame: scripted tools take their pose at the new time, then every body
 * steps with all tools; budget_s is the compute budget for splitting decisions
 * (0 = unlimited, e.g. batch runs) */
void sq_world_step(sq_world *w, double budget_s);
/* thread CPU time (s) the caller spent on this thread since the last step on work that is not
 * the product's (a measuring harness, e.g. `squish tradeoff`'s error sampling): the budget
 * guard of every adaptive body does not count it as time around its frame (docs/lod.md) */
void sq_world_untimed(sq_world *w, double cpu_s);
/* the frames will have a live budget (the server, `squish run --realtime`, the trade-off's
 * guarded runs): the set-up the first budgeted frame would do, done now, at load, for every
 * body (sq_body_prepare_budget), so that frame costs what the others do */
void sq_world_prepare_budget(sq_world *w);
/* set or add a live tool pose by id (replaces a scripted one with the same id); -1 + err
 * if the table is full or values are invalid. t->origin is ignored: an inactive -> active
 * change (or a new active tool) takes origin = pos, so a grab captures where it was
 * activated even if pos moves before the next frame; an active tool keeps its origin. */
int sq_world_set_tool(sq_world *w, const sq_tool *t, sq_err *err);
/* tools whose poses change within a frame (a haptic channel of a real-time session): every
 * body's substeps read fn (sq_body_set_pose_source); NULL: poses at frame starts only */
void sq_world_set_pose_source(sq_world *w, sq_pose_source_fn fn, void *arg);
/* probe displacement u[3]; -1 if the probe point is outside the body */
int sq_world_probe(const sq_world *w, int probe, double u[3]);
int sq_world_find_body(const sq_world *w, const char *name);
/* body's current surface positions (nsurf x 3, see sq_body_surface_mesh) and the level
 * active at each vertex numbered as listed in the scene file (a fixed body loads only its
 * simulated level, which is then not level 0 of the body): the one level number every
 * output uses (frames, renders, stats) */
void sq_world_surface_state(const sq_world *w, int body, float *xyz, unsigned char *level);
/* listed index (scene file numbering) of the body's loaded level k; k itself without a
 * scene or out of range */
int sq_world_listed_level(const sq_world *w, int body, int k);
/* VTK of the body's simulated mesh (the finest loaded level when adaptive) with displacement,
 * velocity and the active level per node in the listed numbering */
int sq_world_write_vtk(const sq_world *w, int body, const char *path, sq_err *err);

#endif
