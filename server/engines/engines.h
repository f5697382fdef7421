/* engines.h - the measuring engines behind squish tradeoff, squish sweep and squish tradeoff
 * --bench: the runs and their numbers, without the command lines (server/app/ parses the
 * arguments and prints). Above scene, body and net (it steps worlds and encodes frames as the
 * server does); only server/app/ includes it. */
#ifndef SQ_ENGINES_H
#define SQ_ENGINES_H

#include <cJSON.h>
#include <stdio.h>

#include "scene/scene.h"
#include "body/body.h"
#include "net/net.h"

/* ---- the speed/accuracy trade-off (engines/tradeoff.c) ------------------------------------- */

#define SQ_TRADEOFF_MAX_VARIANTS 40
#define SQ_TRADEOFF_MAX_GUARDED 15 /* --guarded runs at most */
#define SQ_TRADEOFF_MAX_SAMPLES 4000 /* surface points compared per body (evenly strided) */

/* one setting of the grid */
typedef struct sq_tradeoff_variant {
    char name[48];
    const char *kind;      /* reference, fixed, adaptive, step, operator */
    int adaptive;
    int level;             /* fixed: listed level index */
    double split;          /* adaptive: threshold (m); INFINITY = never split */
    sq_operator_kind op;
    double fraction;
    int implicit;          /* integrator rows: backward Euler at `substeps` steps a frame, CG to tol */
    int substeps;
    double tol;
} sq_tradeoff_variant;


typedef struct sq_tradeoff_result {
    int ok;
    char error[300];
    long frames;
    double sim_s;
    double updates;        /* node updates in total */
    double wall;           /* s inside sq_world_step */
    double sum_sq;         /* sum over frames and samples of |u - u_ref|^2 */
    long count;
    double max_err, probe_err, final_rms, final_max;
    double rms, ups, wps;  /* RMS error (m), node updates and wall seconds per simulated second */
    double cpu;            /* thread CPU s inside sq_world_step */
    double cps;            /* thread CPU s per simulated second */
    double cpu_max1;       /* slowest frame after frame 1, thread CPU s (with a budget: step +
                            * publish, what the server's session thread does per frame) */
    long cpu_late1;        /* frames after frame 1 over the frame period in thread CPU time (same) */
    double cpu_pub;        /* with a budget: thread CPU s of publishing every frame (surface
                            * state and frame encoding, as `squish serve`), not in cpu */
    double cpu_smp;        /* thread CPU s of the error sampling (not the product's: kept out
                            * of the guard's time around the frame, sq_world_untimed) */
    int substeps_finest;   /* substeps per frame at the variant's finest simulated level, body 0 */
    long cg_iterations;    /* implicit rows: CG iterations of all frames and bodies */
    long resets;
    int pareto;
} sq_tradeoff_result;

/* comparison points of one body: rest positions and, per variant, their location */
typedef struct sq_tradeoff_samples {
    int n;
    double *x;             /* n x 3 */
    int *tet;              /* n */
    double *bary;          /* n x 4 */
} sq_tradeoff_samples;

typedef struct sq_tradeoff_ref {
    int nbodies, nprobes, ntotal;      /* ntotal: samples over all bodies */
    sq_tradeoff_samples smp[SQ_MAX_BODIES];
    long nframes;
    double *u;                         /* nframes x ntotal x 3 */
    double *probe;                     /* nframes x nprobes x 3 */
    double rms_ref, max_ref;           /* RMS and max |u_ref| over frames and samples */
} sq_tradeoff_ref;

/* the finest listed level a body uses: its lod.max_level, or the last listed level (override
 * >= 0: that level, clamped) */
int sq_tradeoff_body_finest(const cJSON *body, int override);
/* each body's lod.max_node_updates (0: none) */
void sq_tradeoff_scene_caps(const cJSON *root, double caps[SQ_MAX_BODIES]);
/* the scene's adaptive split threshold (m) */
double sq_tradeoff_scene_split(const cJSON *root);
/* the engine's debugging switches, set by the command (app/cmd_tradeoff.c reads them from
 * SQ_TRADEOFF_ADAPTIVE_MAX_LEVEL, SQ_TRADEOFF_REF and SQ_TRADEOFF_TRACE; docs/lod.md) */
typedef struct sq_tradeoff_debug {
    int adaptive_max_level; /* >= 0: the adaptive rows run with lod.max_level at most this; -1 off */
    const char *ref_file;   /* the reference cached in this file (ref_file_read), or NULL */
    int trace;              /* 1: each frame of a budgeted run on stderr; 2: of every run */
} sq_tradeoff_debug;
void sq_tradeoff_set_debug(const sq_tradeoff_debug *d);
/* fills v with the grid of settings (reference first); returns their count */
int sq_tradeoff_build_grid(sq_tradeoff_variant *v, int finest, double s0, int quick, double ref_fraction);
/* the scene text of variant v (cJSON_free it) */
char *sq_tradeoff_variant_text(cJSON *root, const sq_tradeoff_variant *v, int finest_override,
                               const double caps[SQ_MAX_BODIES], const int sharp[SQ_MAX_BODIES]);
/* runs one variant for ref->nframes frames; record != 0: it is the reference (ref->u, ref->probe
 * filled), else its errors are measured against ref. budget_s > 0: the live budget (the guard on,
 * each frame published as the server does). 0 done (r->ok), -1 refused (r->error) */
int sq_tradeoff_run_variant(const sq_scene *scene, sq_tradeoff_ref *ref, int record, sq_tradeoff_result *r,
                            sq_progress *prog, double *prog_done, double budget_s);
/* frees what sq_tradeoff_run_variant allocated in ref */
void sq_tradeoff_ref_free(sq_tradeoff_ref *ref);
/* the cheapest fixed-level cost (wall: wall s per s, else node updates per s) reaching RMS
 * error e, -1 when no fixed level is that accurate */
double sq_tradeoff_fixed_cost_at(const sq_tradeoff_variant *v, const sq_tradeoff_result *r, int n, double e, int wall);
/* min, median and max of x[0..k-1] (k > 0; sorts x) */
void sq_tradeoff_spread(double *x, int k, double out[3]);
/* r[gmed]: each column's median over the completed guarded runs r[g0..gmed-1] */
void sq_tradeoff_guarded_median(sq_tradeoff_result *r, int g0, int gmed);
/* marks r[i].pareto over the deterministic explicit fem rows */
void sq_tradeoff_pareto(const sq_tradeoff_variant *v, sq_tradeoff_result *r, int n);

/* ---- stability at the extremes (engines/sweep.c) ------------------------------------------- */

typedef enum sq_sweep_load {
    SQ_SWEEP_POKE = 0,   /* sphere presses 30% deep into the top, holds, releases at 1 s */
    SQ_SWEEP_FAST,       /* sphere sweeps across the top at 5 m/s, 40% deep */
    SQ_SWEEP_DEEP,       /* sphere centre driven to the body centre (fully inside), then out */
    SQ_SWEEP_GRAB,       /* grab the top corner and pull it 10 body sizes away, then release */
    SQ_SWEEP_PERIODIC,   /* a poke every 2 s for the whole run (the very long run) */
    SQ_SWEEP_ARC,        /* beam mesh: grab the tip and drag it through 90 degrees about the clamp in 0.5 s */
    SQ_SWEEP_NONE        /* gravity only */
} sq_sweep_load;

typedef enum sq_sweep_mesh_kind { SQ_SWEEP_MESH_BOX = 0, SQ_SWEEP_MESH_SLIVER, SQ_SWEEP_MESH_FLAT, SQ_SWEEP_MESH_BEAM } sq_sweep_mesh_kind;

typedef struct sq_sweep_case {
    const char *group;
    char name[96];
    sq_material mat;
    sq_operator_kind op;
    double frame_rate;      /* Hz; 0 = 50 */
    double frame_vs_bound;  /* > 0: frame period set to this multiple of the level's bound */
    double step_fraction;   /* requested fraction of the bound */
    double seconds;         /* simulated time */
    sq_sweep_load load;
    sq_sweep_mesh_kind mesh;
    double mesh_param;      /* sliver flatness / flat box thickness ratio */
    double above_bound;     /* > 0: test-only: step the level at this multiple of the bound */
    double split;           /* > 0: adaptive over three box levels (2, 3, 5 cells) at this split */
    sq_elasticity_kind elasticity;
    sq_integrator_kind integrator; /* implicit rows: one step per frame unless substeps > 1 */
    int substeps;
} sq_sweep_case;

typedef struct sq_sweep_result {
    char status[32];        /* stable, adjusted, refused, UNSTABLE, blows up (test-only), ... */
    int failed;             /* 1: an accepted case did not stay stable */
    int substeps;
    double bound, dt;       /* s */
    double steps_per_s;     /* substeps per simulated second */
    long frames, resets;
    double max_disp;        /* m */
    double e_load, e_late;  /* max total energy while loaded / in the last quarter, J */
    double wall;            /* s */
    char note[240];
} sq_sweep_result;

/* fills cs (room for 128) with the sweep's cases (quick: shorter runs); returns their count */
int sq_sweep_build_cases(sq_sweep_case *cs, int quick);
/* runs one case within work_cap node updates; fills r (r->failed: an accepted case was not stable) */
void sq_sweep_run_case(const sq_sweep_case *c, double work_cap, sq_sweep_result *r);
/* clamped beam 1 x 0.1 x 0.1 m at nx x nh x nh cells, gravity: static tip deflection over
 * Timoshenko's (NAN when it cannot be built); *substeps: its substeps per 50 Hz frame */
double sq_sweep_beam_ratio(double nu, int nx, int nh, sq_operator_kind op, double *tip_fem, double *tip_th,
                           int *substeps, sq_err *err);

/* ---- the scene benchmarks (engines/bench_scenes.c) ----------------------------------------- */

/* squish tradeoff --bench: frame-budget headroom of the shipped scenes and 1 vs 2 threads;
 * argv[0] is the subcommand name */
int sq_bench_scenes(int argc, char **argv);

#endif
