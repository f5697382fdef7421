/* lod_internal.h - the data of the lod module: a level's adaptive state (sq_lod_level), the
 * module's state (sq_lod), the node states, and the small inline helpers on them. No function of
 * a stage is declared here: each file's entry points are in its own header (state.h,
 * criterion.h, guard.h, coupling.h, reserve.h, bound.h, ring.h, tick.h, holds.h, activeset.h,
 * corotational.h; lod_vec.h the kernels' vectors; lod_test.h the test hooks), and a file
 * includes the headers of the files it calls. Every header includes this one and nothing else
 * of lod's but lod.h, so the includes form no circle. Not part of the module's contract (lod.h).
 */
#ifndef SQ_LOD_INTERNAL_H
#define SQ_LOD_INTERNAL_H

#include "lod/lod.h"

#include <string.h>

/* the lod state's test-only switches and counters (its member `test`; the tests reach it
 * through lod_test.h's sq_lod_test_of): what tests/unit set to compare a path against its
 * reference, or read to check a decision. No product code sets them. */
typedef struct sq_lod_test {
    int corot_tets_always;  /* 1: corotational levels run the tet-by-tet pass even when all their
                             * nodes are active (corotational.c; tests compare it) */
    int full_rebuild;       /* 1: every block row rebuilt after a split/merge pass (coupling.c,
                             * activeset.c; the reference the incremental rebuild is checked
                             * against) */
    long guard_resplit;     /* regions the guard merged that were split again within their rest
                             * (guard.c; tests: 0) */
} sq_lod_test;

enum { ST_COARSE = 0, ST_ACTIVE = 1, ST_SPLIT = 2 };
/* states the guard gives a node while sq_lodx_adapt_pair runs, never outside it (guard.c's
 * sq_lodx_guard_adapt): neither read as active nor as split nor as a coarse ghost, so the node is
 * neither split nor merged (its value is read as it is stored, as for an active or split node) */
enum { ST_RESTING = 3, ST_LIMITED_ACTIVE = 4, ST_LIMITED_SPLIT = 5 };
#define SQ_BLOCKS_CHUNK 1024  /* element-block cache slots per chunk (1.2 MB, 2.4 viscous) */
#define SQ_KROW_CHUNK 16384   /* column-form row blocks per chunk (1.5 MB), at least */

/* a node that carries one or more tool holds this frame (the body's fixed-mode convention:
 * the node jumps to its target when the hold starts, with velocity (target - old) / time left,
 * and is not integrated; its feedback is the mean over its level's substeps of f - m g) */
/* corotational.c: a level's tet lists, ring ghost forces and step-start copies */
typedef struct sq_lod_corot sq_lod_corot;

typedef struct hold_entry {
    int level, node;
    int count;        /* holds mapped to it (0: dead, its node stopped being active) */
    int pending;      /* target changed, to be applied */
    double gsum[3];   /* sum of the targets its holds ask of it */
    double from[3];   /* displacement when the hold (re)started */
    double t_from;    /* time within the frame the hold (re)started, s */
    double fsum[3];   /* internal force summed over the substeps it was held, N */
    int nf;
    double shift[3];  /* live holds: the summed change of its holds' targets (sq_lodx_hold_live) */
    int live;
} hold_entry;

/* a level's const mesh tables, made once at creation (state.c) and shared between the states of
 * one body (sq_lod_create_like): read-only after it */
typedef struct sq_lod_tables {
    double *crit_weight;        /* criterion Laplacian weights w_ij per adjacency CSR entry, m (nnz) */
    int *node_tet_start, *node_tet; /* tets around each node (CSR, n + 1 and 4 x ntets) */
    unsigned char *inc_corner;  /* per node-tet incidence: the node's corner in the tet */
    int *inc_block;             /* per incidence, for each corner q: the block's position in the
                                 * node's adjacency row (4 per incidence) */
    double *tet_geom;           /* per tet: volume (m^3) and the 4 basis gradients (1/m) (13) */
} sq_lod_tables;

/* a level's coupling cache: the element blocks of the mixed tets, the ring and frontier rows built
 * from them (with their previous build, for an incremental one), their column forms and the
 * column-form rows of K (coupling.c builds them; reserve.c maps them ahead; tick.c's krow fills
 * rows on first use) */
typedef struct sq_lod_coupling_cache {
    int *blocks_slot;           /* cache slot of a tet's element blocks, or -1 (ntets) */
    double **blocks_chunk;      /* 16 blocks of 9 per slot (x 2 with viscosity: the viscous ones
                                 * after), N/m (N s/m), in chunks of SQ_BLOCKS_CHUNK slots (a
                                 * grown cache is never copied: a copy stalled a frame); slots
                                 * handed out on first use, so the memory follows the refined
                                 * region, not the mesh */
    int blocks_used, blocks_cap;/* slots in use, slots allocated */
    int blocks_nchunk, blocks_per; /* chunks allocated; doubles per slot they were made for */
    size_t blocks_mapped;       /* bytes of the last chunk sq_lodx_reserve_blocks mapped so far */
    int blocks_dirty;           /* ring and frontier blocks out of date with the layout */
    double blocks_cpu;          /* thread CPU time of the last build of those blocks, s (0: not
                                 * built by the last sq_lodx_update_ring_blocks) */
    int blocks_valid;           /* 1: the blocks were built for the current material (a later
                                 * rebuild may then redo only the rows near changed nodes) */
    int *prev_ring, nprev_ring; /* the ring and frontier the blocks were last built for (n) */
    int *prev_frontier, nprev_frontier;
    int prev_saved;             /* prev_ring / prev_frontier hold the lists of the built blocks */
    int *chg, nchg;             /* nodes whose active flag changed since the blocks were built (n) */
    unsigned char *chg_mark;    /* 1 if in chg (n) */
    unsigned char *blk_active;  /* the active flags the blocks were built for (n) */
    long rows_computed, rows_built; /* ring + frontier rows computed / built, over all block builds */
    /* --- ring rows: -(K x) on a ring ghost over its half-weighted tets, aligned with the mesh
     * adjacency row of each ring ghost, zero blocks dropped */
    int *ring_off;              /* (nring + 1) offsets in blocks */
    int *ring_col;              /* column (node) of each block */
    double *ring_K, *ring_D;    /* stiffness (N/m) and viscous (N s/m) blocks */
    int ring_K_cap, ring_D_cap; /* capacities, in blocks */
    int *front_off;             /* (nfrontier + 1) offsets in blocks of the corrections */
    int *front_col;             /* column (node) of each correction block */
    double *front_K, *front_D;  /* the half of the mixed tets given back: stiffness (N/m), viscous */
    int front_K_cap, front_D_cap;
    double *front_merged;       /* frontier rows with the correction folded in (K - correction),
                                 * full adjacency rows, N/m */
    int front_merged_cap;
    /* the ring rows and merged frontier rows again, each block as its 3 columns padded to 4
     * lanes (12 doubles), for the vector kernels of the tick (built with the blocks above,
     * the rows an incremental build copies copied here too) */
    double *ring_T, *front_T;
    int ring_T_cap, front_T_cap;
    double *ring_T2, *front_T2; /* the previous build's (an incremental build copies from them) */
    int ring_T2_cap, front_T2_cap;
    /* the level's own rows of K in column form for the inner rows, made on a node's first use
     * as an inner node for the current material (so the memory follows the refined region,
     * like the element blocks) */
    int *krow_at;               /* block offset of node i's row in krow_chunk (chunk x
                                 * SQ_KROW_CHUNK + block in it), or -1 (n) */
    double **krow_chunk;        /* 12 doubles per block, SQ_KROW_CHUNK blocks a chunk (a row never
                                 * straddles two; a grown cache is never copied) */
    long krow_used, krow_cap;   /* next free block offset; offsets allocated */
    long krow_chunk_len;        /* blocks per chunk: SQ_KROW_CHUNK or the longest row (0: none yet) */
    int krow_nchunk;
    size_t krow_mapped;         /* bytes of the last chunk sq_lodx_reserve_blocks mapped so far */
    int krow_grown;             /* chunks krow opened itself, in a tick (not reserved ahead) */
    /* the same arrays of the previous build: an incremental build copies its clean rows from
     * there and the two sets are swapped (capacities with them) */
    int *ring_off2, *ring_col2, ring_col2_cap, ring_col_cap;
    double *ring_K2, *ring_D2;
    int ring_K2_cap, ring_D2_cap;
    int *front_off2, *front_col2, front_col2_cap, front_col_cap;
    double *front_K2, *front_D2;
    int front_K2_cap, front_D2_cap;
    double *front_merged2;
    int front_merged2_cap;
} sq_lod_coupling_cache;

/* a level's step bound: its substep exponent beyond its own bound and the row sums it is
 * made from (coupling.c's coupled bound; bound.c's sharp rule sets the exponent) */
typedef struct sq_lod_rates {
    int extra_log2;             /* extra substep exponent: the coupling stiffens the nodes near
                                 * an interface beyond the level's own bound (coupling_bound) */
    double *own_rowsum;         /* Gershgorin row sums of the level's own K, N/m (n) */
    double own_rate;            /* largest own_rowsum / mass over the free nodes, 1/s^2 */
    double *coupled_rowsum;     /* row sums of the coupling handed to each node, N/m (n) */
} sq_lod_rates;

/* a level's clock within the frame and the tick's scratch: d + b v, the hot ring list (tick.c;
 * the other stages set the clock, the hot list's staleness and step-start values through
 * tick.c's sq_lodx_tick_* setters; state.c's create and reset, and holds.c's held nodes' step
 * start, write it directly) */
typedef struct sq_lod_tick_state {
    int *hot, nhot;             /* ring positions of the ghosts the ring rows with a source on a
                                 * level in hot_mask read: those evaluated between two steps of the
                                 * level, where only those rows are used (n) */
    unsigned hot_mask;
    int hot_valid;              /* hot is up to date with the ring, sources and blocks */
    /* d + b v of the level's active nodes and ring ghosts at the current tick (b the stiffness
     * damping), formed once per step of the level (sq_lodx_form_w) for its row kernels, which
     * read each node's value from about 14 blocks (3 n + 1 doubles, NULL until first used) */
    double *w_tick;
    int w_ok;                   /* 1: w_tick is current (set and cleared by the frame's tick; the
                                 * kernels called with it 0 form it themselves) */
    /* --- time: this level's clock within the frame, in ticks of the finest substep */
    int due;                    /* 1 if the level steps at the current tick */
    double *d_start, *v_start;  /* d (m), v (m/s) at the start of the level's last step, read by
                                 * levels stepping between its steps (n x 3) */
    long step_start, step_len;  /* tick its last step started at, and its length in ticks */
} sq_lod_tick_state;

/* a level's layout: which node is active, which a ghost, the ring and its active sources, the
 * frontier (a split or merge's states set by state.c for criterion.c and guard.c, the pass's
 * temporary masks and limited set by guard.c, the lists rebuilt by state.c's
 * sq_lodx_rebuild_level, the sources by ring.c and corotational.c, hold_of and the integrated
 * mask by holds.c) */
typedef struct sq_lod_layout {
    /* --- the layout: which node is active, which a ghost (rebuilt by sq_lodx_rebuild_level) */
    unsigned char *state;       /* ST_ACTIVE, ST_SPLIT or ST_COARSE of each node (n) */
    unsigned char *active;      /* 1 = active (exposed by sq_lod_active) (n) */
    unsigned char *integrated;  /* 1 = integrated this frame: active and not held (n) */
    int nactive, nintegrated;   /* counts of the two masks */
    int *split_ghost, nsplit_ghost;   /* split ghosts (value from the finer level), increasing */
    int *coarse_ghost, ncoarse_ghost; /* coarse ghosts (value from the coarser level), increasing */
    unsigned char *fresh;       /* 1 = split in the current adapt pass: not merged back (n) */
    int *limited, nlimited;     /* nodes the guard held out of this pass (sq_lodx_guard_limit) */
    /* --- the ring (ghosts with an active neighbour) and their active sources */
    int *ring, nring;           /* ring ghosts, increasing node order */
    int *ring_index;            /* ring position of a node, or -1 (n) */
    int *src_start;             /* sources of ring ghost r: src_start[r]..src_start[r+1] (nring + 1) */
    unsigned char *src_levels;  /* per ring ghost: bit m set if a source is on level m (nring) */
    int *src_level, *src_node;  /* level and node of each source, sorted by level (src_cap) */
    double *src_weight;         /* weight of each source, the weights of a ghost sum to 1 (src_cap) */
    int *src_rend;              /* end of the run of sources on the same level as this one (src_cap) */
    int src_cap;                /* capacity of the three source arrays */
    /* --- the frontier: active nodes with a ghost neighbour; their mixed tets count half */
    int *frontier, nfrontier;   /* frontier nodes */
    unsigned char *inner;       /* 1 = active and not on the frontier (n) */
    /* --- tool holds */
    int *hold_of;               /* hold entry of a node, or -1 (n) */
} sq_lod_layout;

/* a level's index lists, so a frame's cost follows the active set, and the needed set kept by
 * counts (activeset.c) */
typedef struct sq_lod_lists {
    /* --- index lists (activeset.c), so a frame's cost follows the active set, not the body */
    int *active_list;           /* active nodes, increasing (nactive) */
    int *inner_list, ninner_list;           /* inner active nodes */
    int *integrated_list, nintegrated_list; /* integrated this frame (the integrated mask) */
    int *read_list, nread_list; /* nodes whose step-start values are read */
    int *needed, nneeded;       /* coarse ghosts pushed every frame */
    unsigned char *in_needed;   /* 1 if in needed (n) */
    int *ncnt;                  /* reasons a node is needed: seeds (below) plus needed coarse ghosts of
                                 * the next finer level whose parent tet has it as a corner (n); a
                                 * node is needed iff it is a coarse ghost (level >= 1) with ncnt > 0 */
    unsigned char *seed_state;  /* the states the counts were made for (n) */
    int *schg, nschg;           /* nodes whose state differs from seed_state (n) */
    unsigned char *schg_mark;   /* 1 if in schg (n) */
    int *seed_ring, nseed_ring; /* the ring the counts were made for (n) */
    unsigned char *mark;        /* scratch marks (n), all zero between uses */
    double *cascade_value;      /* d, v of each ring ghost as the cascade pushed or pulled it,
                                 * before its ring value replaced it (nring x 6) */
    int cascade_value_cap;
    unsigned *push_stamp;       /* cascade a coarse ghost was last pushed at (n) */
} sq_lod_lists;

/* the adaptive state of one level. "n" is the level's node count; node values are in metres
 * (displacements), m/s (velocities), N (forces); stiffness blocks are 3x3, N/m, row-major */
typedef struct sq_lod_level {
    sq_lod_layout lay;                   /* the layout: states, ghosts, ring, frontier, sources
                                          * (state.c, guard.c, ring.c, holds.c) */
    sq_lod_tables tab;                   /* the mesh tables (state.c; shared by sq_lod_create_like) */
    double *d_static;           /* static displacement under the body's gravity, m (n x 3);
                                 * NULL: judged from 0 */
    sq_lod_tick_state tk;                /* the level's clock and tick scratch (tick.c) */
    sq_lod_rates rate;                   /* the level's step bound (coupling.c, bound.c) */
    sq_lod_coupling_cache cpl;           /* the coupling blocks and row caches (coupling.c) */
    sq_lod_lists lists;                  /* index lists and the needed set (activeset.c) */
    /* --- corotational elasticity (corotational.c), NULL for a linear level */
    sq_lod_corot *corot;
} sq_lod_level;

/* a learned cost's robust state (guard.c, sq_lodx_learn): `base` is the decaying maximum of
 * the measurements that were not isolated outliers; `since` counts the measurements since the
 * last outlier (0: none within SPIKE_WINDOW), `peak` that outlier's measurement */
typedef struct {
    double base;
    int since;
    double peak;
} sq_cost_track;

/* the guaranteed frame rate's state (docs/lod.md "Guaranteed frame rate"): the cost model,
 * learned and written by guard.c (frame.c's and pass.c's measurements handed to it), and the
 * rests of the regions the guard merged (state.c's reset clears last_time, activeset.c's
 * sq_lodx_free frees guard_hold) */
typedef struct sq_lod_guard {
    /* cost model of the guaranteed frame rate (frame.c and pass.c measure, guard.c learns and
     * models; docs/lod.md "Guaranteed frame rate"): thread CPU s, each a maximum over the last
     * measurements that decays by 10 % a frame (a frame after a rebuild costs more per update
     * than a quiet one) */
    double last_time;                    /* CPU time of the previous frame, s */
    double cost_update;                  /* per node update of the ticks (ghost values, forces,
                                          * integration), s (0: none measured yet) */
    double cost_fixed;                   /* per frame, the stages outside the ticks and the
                                          * split/merge passes (criterion, push, ...), s */
    double cost_level[SQ_MAX_LEVELS];    /* a pass's rebuild of level k's lists, s (0: none yet) */
    double cost_couple;                  /* a pass's sources and needed set, s */
    double cost_blocks[SQ_MAX_LEVELS];   /* a pass's block build of level k with no node
                                          * changed (calibration), s */
    double cost_block_change[SQ_MAX_LEVELS]; /* ... and per changed node of level k, s */
    double cost_bound;                   /* a pass's coupled bound (Gershgorin, sharp), s */
    double cost_outside;                 /* the thread's time between two frames (the body's
                                          * work around the lod frame), at most a quarter period, s */
    /* each learned term's robust state (guard.c, sq_lodx_learn): a measurement above
     * SPIKE_FACTOR x the term is an outlier, held to that bound unless another comes soon */
    sq_cost_track tr_update, tr_fixed, tr_outside, tr_couple, tr_bound;
    sq_cost_track tr_level[SQ_MAX_LEVELS], tr_blocks[SQ_MAX_LEVELS], tr_block_change[SQ_MAX_LEVELS];
    double last_c_end;                   /* thread CPU clock at the last frame's end, s */
    double untimed;                      /* thread CPU time since then that is not the product's
                                          * (sq_lod_untimed: a measuring harness), s */
    int cost_given;                      /* 1: the costs are the caller's (sq_lodx_set_costs,
                                          * deterministic tests), not measured */
    int cost_calibrated;                 /* 1: a rebuild pass was timed (at load, sq_lod_prepare_budget,
                                          * or in the first budgeted frame) */
    long guard_clock;                    /* frames run with a budget (hysteresis clock) */
    int *guard_hold[SQ_MAX_LEVELS];      /* per node of level k: no split before this guard
                                          * clock (a region the guard merged rests), NULL: none */
    long guard_merged_total;             /* regions the guard merged so far (tests) */
    int guard_hold_until[SQ_MAX_LEVELS]; /* the latest rest in guard_hold[k] */
    double guard_modeled;                /* the last frame's cost by the model for what it did
                                          * (its node updates, fixed cost and passes), s */
    double guard_predicted;              /* the next frame's cost predicted at this frame's end
                                          * (without a pass), s */
} sq_lod_guard;

/* the coupling arrays mapped ahead of use (reserve.c) */
typedef struct sq_lod_reserve {
    double cost_fault;                   /* a first touch of a page, s (sq_lodx_reserve_blocks) */
    long reserve_pending;                /* pages sq_lodx_reserve_blocks left for a later frame */
    long reserve_bytes;                  /* bytes the coupling arrays hold (capacities) */
    int reserve_live;                    /* 1: a budget was live (reserve on): the arrays are
                                          * reserved from the first budgeted frame on */
} sq_lod_reserve;

/* tool holds of the frame (holds.c) */
typedef struct sq_lod_holds {
    hold_entry *he;                      /* entries: nodes that carry holds */
    int nhe, cap_he;
    int *hold_entry_of;                  /* entry of each hold of the frame */
    int cap_holds;
} sq_lod_holds;

/* ghost values pushed on demand (activeset.c, state.c) */
typedef struct sq_lod_push {
    int lists_dirty;                     /* read_list / needed out of date */
    int needed_valid;                    /* the counts (ncnt) hold for seed_state, seed_ring,
                                          * needed_top */
    int needed_top;
    long needed_counts[2];               /* needed sets made from scratch / by changes only */
    unsigned cascade_no;                 /* cascades run (the end-of-frame push counts one) */
    unsigned full_no;                    /* the last one that pushed every coarse ghost */
    int stale;                           /* coarse ghosts outside `needed` not pushed since the last
                                          * frame */
} sq_lod_push;

/* the static equilibria the criterion judges the displacement from (statics.c) */
typedef struct sq_lod_statics {
    /* the criterion judges the displacement from each level's static equilibrium under the
     * body's constant load (gravity), so a sag alone keeps nothing refined (lev[k].d_static) */
    double stat_g[3];                    /* gravity it was solved for, m/s^2 */
    const double *stat_k;                /* level 0's K it was solved with */
    int stat_done, stat_top;
    sq_material stat_mat;                /* material it was solved with (lod->cpl.mat then) */
} sq_lod_statics;

/* node levels given out (views.c) */
typedef struct sq_lod_node_view {
    long gen;                            /* bumped whenever a level's states change */
    long nl_gen;                         /* gen the node levels were last given out at */
    const unsigned char *nl_out;         /* ... and the buffer they went to */
    unsigned char *nlv[2];               /* scratch of sq_lod_node_levels (largest level) */
} sq_lod_node_view;

/* the finest surface as combinations of active nodes (surface.c, sq_lod_surface_map_get) */
typedef struct sq_lod_surface_store {
    long gen;                            /* view.gen it was built at (-1: never) */
    int *start, *dof;                    /* rows (n_finest + 1) and entries (cap) */
    double *w;
    int cap;
    int *level, *node;                   /* each unknown's active node (dof_cap) */
    int dof_cap;
    int *dof_at;                         /* unknown of node i of level k at off[k] + i, else -1 */
    int off[SQ_MAX_LEVELS + 1];
    sq_lod_surface_map map;
} sq_lod_surface_store;

/* what the coupling blocks were built for: material, operator, level-0 K; the coupled bound's
 * scratch (coupling.c) */
typedef struct sq_lod_coupling_of {
    int have_mat;
    sq_material mat;
    sq_operator_kind op;
    const double *k_seen;
    double *abs_sum;                     /* scratch of the coupled bound: sum of |weights| of
                                          * each ring ghost's sources (coupling.c) */
    int abs_cap;
    double bound_cpu;                    /* thread CPU time of the last coupled bound (read by
                                          * pass.c for the guard's cost model), s */
} sq_lod_coupling_of;

struct sq_lod {
    sq_level *lv;                        /* the body's levels (borrowed), L of them */
    sq_lod_level lev[SQ_MAX_LEVELS];     /* this module's state of each level */
    int L;                               /* levels */
    int top;                             /* highest level that may be active */
    sq_lod_def def;
    sq_hierarchy h;
    int shared;                          /* 1: h and the per-level mesh tables (crit_weight,
                                          * node_tet_start, node_tet, inc_corner, inc_block,
                                          * tet_geom) are another state's (sq_lod_create_like) */
    const struct sq_lod *like;           /* during sq_lod_set_loads_like only: the state whose
                                          * operator-derived sums (own_rowsum) are taken */
    sq_lod_coupling_of cpl;              /* what the coupling blocks were built for (coupling.c) */
    sq_lod_holds holds;                  /* the frame's tool holds (holds.c) */
    sq_lod_guard guard;                  /* the guard's cost model and rests (guard.c) */
    sq_lod_reserve reserve;              /* the coupling arrays' reserve (reserve.c) */
    long frames;                         /* frames run (sq_lod_frame), for def.adapt_every */
    sq_lod_test test;                    /* test-only switches and counters (lod_test.h) */
    sq_lod_push push;                    /* ghost values pushed on demand (activeset.c) */
    sq_lod_statics statics;              /* the static loads the criterion judges from (statics.c) */
    sq_lod_node_view view;               /* node levels given out (views.c) */
    sq_lod_surface_store surf;           /* the finest surface from the active nodes (surface.c) */
    struct lod_sharp *sharp;             /* the sharp step rule and its state (bound.c), NULL: off */
    const double (*focus)[4];            /* during sq_lod_frame only: in->focus (criterion.c) */
    int nfocus;
};

/* substep exponent a level runs at in the adaptive frame */
static inline int sub_log2(const sq_lod *lod, int k)
{
    return lod->lv[k].substeps_log2 + lod->lev[k].rate.extra_log2;
}

/* position of column j in CSR row i of the mesh adjacency (sorted), or -1 */
static inline int adj_find(const sq_mesh *m, int i, int j) { return sq_csr_find(m->adj_start, m->adj, i, j); }

/* counters of one frame's adaptation */
typedef struct adapt_out {
    int splits, merges, refused;
    int changed[SQ_MAX_LEVELS];
} adapt_out;

/* the column-form row cache of level k (krow, activeset.c; reserved ahead by reserve.c): its
 * node index, made on first use with every node -1 (1 when made by this call) */
static inline int sq_lodx_krow_index(sq_lod_level *lk, const sq_level_model *M)
{
    if (lk->cpl.krow_at)
        return 0;
    lk->cpl.krow_at = sq_malloc(sizeof(int) * (size_t)SQ_MAX(M->n, 1));
    for (int j = 0; j < M->n; j++)
        lk->cpl.krow_at[j] = -1;
    return 1;
}
/* its blocks per chunk, set on first use: SQ_KROW_CHUNK, or the longest row if longer (a chunk
 * holds a whole row) */
static inline long sq_lodx_krow_chunk_len(sq_lod_level *lk, const sq_level_model *M)
{
    if (!lk->cpl.krow_chunk_len) {
        long most = SQ_KROW_CHUNK;
        for (int j = 0; j < M->n; j++)
            most = SQ_MAX(most, (long)(M->row_start[j + 1] - M->row_start[j]));
        lk->cpl.krow_chunk_len = most;
    }
    return lk->cpl.krow_chunk_len;
}

#endif
