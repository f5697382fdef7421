/* lod_internal.h - the adaptive state shared by the files of the lod module, one per stage:
 *   state.c      creation, definition, reset, the level's state lists, ghost values (sync), check
 *   criterion.c  the split/merge criterion, split/merge decisions, the node-update cap
 *   coupling.c   the coupling blocks of the ring and frontier rows, the interface substeps
 *   reserve.c    the coupling arrays' pages mapped ahead of use (load, frames with room)
 *   ring.c       the ring ghosts' sources, their values and their reactions
 *   holds.c      tool holds onto active nodes
 *   frame.c      sq_lod_frame: the frame as a list of timed stages
 *   views.c      node levels, active lists, energy, projected updates
 *   activeset.c  per-level index lists and the kernels that run over them
 *   bound.c      the sharp per-level step: which level is estimated when, deadlines, substeps
 *   estimate.c   one level's sharp estimate (Lanczos on its block of the coupled operator)
 *   hierarchy.c  the links between consecutive levels
 *   corotational.c  corotational levels: forces and ring reactions tet by tet
 * Not part of the module's contract (lod.h).
 */
#ifndef SQ_LOD_INTERNAL_H
#define SQ_LOD_INTERNAL_H

#include "lod/lod.h"
#include "lod/lod_test.h"

#include <string.h>

enum { ST_COARSE = 0, ST_ACTIVE = 1, ST_SPLIT = 2 };
/* states the guard gives a node while sq_lodx_adapt_pair runs, never outside it (frame.c,
 * activeset.c): neither read as active nor as split nor as a coarse ghost, so the node is
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

/* the adaptive state of one level. "n" is the level's node count; node values are in metres
 * (displacements), m/s (velocities), N (forces); stiffness blocks are 3x3, N/m, row-major */
typedef struct sq_lod_level {
    /* --- the layout: which node is active, which a ghost (rebuilt by sq_lodx_rebuild_level) */
    unsigned char *state;       /* ST_ACTIVE, ST_SPLIT or ST_COARSE of each node (n) */
    unsigned char *active;      /* 1 = active (exposed by sq_lod_active) (n) */
    unsigned char *integrated;  /* 1 = integrated this frame: active and not held (n) */
    int nactive, nintegrated;   /* counts of the two masks */
    int *split_ghost, nsplit_ghost;   /* split ghosts (value from the finer level), increasing */
    int *coarse_ghost, ncoarse_ghost; /* coarse ghosts (value from the coarser level), increasing */
    unsigned char *fresh;       /* 1 = split in the current adapt pass: not merged back (n) */
    int *limited, nlimited;     /* nodes the guard held out of this pass (sq_lodx_guard_limit) */
    double *crit_weight;        /* criterion Laplacian weights w_ij per adjacency CSR entry, m (nnz) */
    double *d_static;           /* static displacement under the body's gravity, m (n x 3);
                                 * NULL: judged from 0 */

    /* --- the ring (ghosts with an active neighbour) and their active sources */
    int *ring, nring;           /* ring ghosts, increasing node order */
    int *ring_index;            /* ring position of a node, or -1 (n) */
    int *src_start;             /* sources of ring ghost r: src_start[r]..src_start[r+1] (nring + 1) */
    unsigned char *src_levels;  /* per ring ghost: bit m set if a source is on level m (nring) */
    int *src_level, *src_node;  /* level and node of each source, sorted by level (src_cap) */
    double *src_weight;         /* weight of each source, the weights of a ghost sum to 1 (src_cap) */
    int *src_rend;              /* end of the run of sources on the same level as this one (src_cap) */
    int src_cap;                /* capacity of the three source arrays */
    int *hot, nhot;             /* ring positions of the ghosts the ring rows with a source on a
                                 * level in hot_mask read: those evaluated between two steps of the
                                 * level, where only those rows are used (n) */
    unsigned hot_mask;
    int hot_valid;              /* hot is up to date with the ring, sources and blocks */

    /* --- element blocks of the mixed tets (tets with active and ghost corners) */
    int *node_tet_start, *node_tet; /* tets around each node (CSR, n + 1 and 4 x ntets) */
    unsigned char *inc_corner;  /* per node-tet incidence: the node's corner in the tet */
    int *inc_block;             /* per incidence, for each corner q: the block's position in the
                                 * node's adjacency row (4 per incidence) */
    int *blocks_slot;           /* cache slot of a tet's element blocks, or -1 (ntets) */
    double **blocks_chunk;      /* 16 blocks of 9 per slot (x 2 with viscosity: the viscous ones
                                 * after), N/m (N s/m), in chunks of SQ_BLOCKS_CHUNK slots (a
                                 * grown cache is never copied: a copy stalled a frame); slots
                                 * handed out on first use, so the memory follows the refined
                                 * region, not the mesh */
    int blocks_used, blocks_cap;/* slots in use, slots allocated */
    int blocks_nchunk, blocks_per; /* chunks allocated; doubles per slot they were made for */
    size_t blocks_mapped;       /* bytes of the last chunk sq_lodx_reserve_blocks mapped so far */
    double *tet_geom;           /* per tet: volume (m^3) and the 4 basis gradients (1/m) (13) */
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

    /* --- the frontier: active nodes with a ghost neighbour; their mixed tets count half */
    int *frontier, nfrontier;   /* frontier nodes */
    unsigned char *inner;       /* 1 = active and not on the frontier (n) */
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
    /* d + b v of the level's active nodes and ring ghosts at the current tick (b the stiffness
     * damping), formed once per step of the level (sq_lodx_form_w) for its row kernels, which
     * read each node's value from about 14 blocks (3 n + 1 doubles, NULL until first used) */
    double *w_tick;
    int w_ok;                   /* 1: w_tick is current (set and cleared by the frame's tick; the
                                 * kernels called with it 0 form it themselves) */
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

    /* --- time: this level's clock within the frame, in ticks of the finest substep */
    int due;                    /* 1 if the level steps at the current tick */
    double *d_start, *v_start;  /* d (m), v (m/s) at the start of the level's last step, read by
                                 * levels stepping between its steps (n x 3) */
    long step_start, step_len;  /* tick its last step started at, and its length in ticks */
    int extra_log2;             /* extra substep exponent: the coupling stiffens the nodes near
                                 * an interface beyond the level's own bound (coupling_bound) */
    double *own_rowsum;         /* Gershgorin row sums of the level's own K, N/m (n) */
    double own_rate;            /* largest own_rowsum / mass over the free nodes, 1/s^2 */
    double *coupled_rowsum;     /* row sums of the coupling handed to each node, N/m (n) */

    /* --- tool holds */
    int *hold_of;               /* hold entry of a node, or -1 (n) */

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

    /* --- corotational elasticity (corotational.c), NULL for a linear level */
    sq_lod_corot *corot;
} sq_lod_level;

/* a learned cost's robust state (frame.c, sq_lodx_learn): `base` is the decaying maximum of
 * the measurements that were not isolated outliers; `since` counts the measurements since the
 * last outlier (0: none within SPIKE_WINDOW), `peak` that outlier's measurement */
typedef struct {
    double base;
    int since;
    double peak;
} sq_cost_track;

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
    /* the coupling blocks were built for this material, operator and level-0 K */
    int have_mat;
    sq_material mat;
    sq_operator_kind op;
    const double *k_seen;
    /* tool holds of the frame */
    hold_entry *he;                      /* entries: nodes that carry holds */
    int nhe, cap_he;
    int *hold_entry_of;                  /* entry of each hold of the frame */
    int cap_holds;
    /* cost model of the guaranteed frame rate (frame.c, docs/lod.md "Guaranteed frame rate"):
     * thread CPU s, each a maximum over the last measurements that decays by 10 % a frame (a
     * frame after a rebuild costs more per update than a quiet one) */
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
    /* each learned term's robust state (frame.c, sq_lodx_learn): a measurement above
     * SPIKE_FACTOR x the term is an outlier, held to that bound unless another comes soon */
    sq_cost_track tr_update, tr_fixed, tr_outside, tr_couple, tr_bound;
    sq_cost_track tr_level[SQ_MAX_LEVELS], tr_blocks[SQ_MAX_LEVELS], tr_block_change[SQ_MAX_LEVELS];
    double last_c_end;                   /* thread CPU clock at the last frame's end, s */
    double untimed;                      /* thread CPU time since then that is not the product's
                                          * (sq_lod_untimed: a measuring harness), s */
    double bound_cpu;                    /* thread CPU time of the last coupled bound, s */
    double cost_fault;                   /* a first touch of a page, s (sq_lodx_reserve_blocks) */
    long reserve_pending;                /* pages sq_lodx_reserve_blocks left for a later frame */
    long reserve_bytes;                  /* bytes the coupling arrays hold (capacities) */
    int reserve_live;                    /* 1: a budget was live (reserve on): the arrays are
                                          * reserved from the first budgeted frame on */
    int cost_given;                      /* 1: the costs are the caller's (sq_lodx_set_costs,
                                          * deterministic tests), not measured */
    int cost_calibrated;                 /* 1: a rebuild pass was timed (at load, sq_lod_prepare_budget,
                                          * or in the first budgeted frame) */
    long guard_clock;                    /* frames run with a budget (hysteresis clock) */
    long frames;                         /* frames run (sq_lod_frame), for def.adapt_every */
    int *guard_hold[SQ_MAX_LEVELS];      /* per node of level k: no split before this guard
                                          * clock (a region the guard merged rests), NULL: none */
    long guard_merged_total;             /* regions the guard merged so far (tests) */
    int guard_hold_until[SQ_MAX_LEVELS]; /* the latest rest in guard_hold[k] */
    double guard_modeled;                /* the last frame's cost by the model for what it did
                                          * (its node updates, fixed cost and passes), s */
    double guard_predicted;              /* the next frame's cost predicted at this frame's end
                                          * (without a pass), s */
    sq_lod_test test;                    /* test-only switches and counters (lod_test.h) */
    /* ghost values pushed on demand (activeset.c) */
    int lists_dirty;                     /* read_list / needed out of date */
    int needed_valid;                    /* the counts (ncnt) hold for seed_state, seed_ring, needed_top */
    int needed_top;
    long needed_counts[2];               /* needed sets made from scratch / by changes only */
    unsigned cascade_no;                 /* cascades run (the end-of-frame push counts one) */
    unsigned full_no;                    /* the last one that pushed every coarse ghost */
    int stale;                           /* coarse ghosts outside `needed` not pushed since the last frame */
    /* the criterion judges the displacement from each level's static equilibrium under the
     * body's constant load (gravity), so a sag alone keeps nothing refined (lev[k].d_static) */
    double stat_g[3];                    /* gravity it was solved for, m/s^2 */
    const double *stat_k;                /* level 0's K it was solved with */
    int stat_done, stat_top;
    sq_material stat_mat;                /* material it was solved with (lod->mat then) */
    /* node levels (views.c) */
    long gen;                            /* bumped whenever a level's states change */
    long nl_gen;                         /* gen the node levels were last given out at */
    const unsigned char *nl_out;         /* ... and the buffer they went to */
    unsigned char *nlv[2];               /* scratch of sq_lod_node_levels (largest level) */
    double *abs_sum;                     /* scratch of the coupled bound: sum of |weights| of
                                          * each ring ghost's sources (coupling.c) */
    int abs_cap;
    struct lod_sharp *sharp;             /* the sharp step rule and its state (bound.c), NULL: off */
};

/* 4-lane vectors (lane 3 unused) for the kernels of the tick: a node's 3 components are
 * loaded as 4 lanes, so arrays read that way have one spare double after the last node. The
 * lanes are computed with the same multiplications and additions, in the same order, as the
 * scalar code they replace (-std=c11 contracts nothing into fma), so the results are bitwise
 * those of the scalar code, in every build */
typedef double sq_v4 __attribute__((vector_size(32)));
typedef long long sq_v4i __attribute__((vector_size(32)));
typedef double sq_v2 __attribute__((vector_size(16)));

/* the helpers are macros (statement expressions), not functions: a 32-byte vector passed to or
 * returned from a function has no fixed calling convention without AVX (the ASan build) */

/* 4 doubles from p (any alignment) */
#define v4_load(p)                                                                                                 \
    ({                                                                                                             \
        sq_v4 v4l_;                                                                                                \
        memcpy(&v4l_, (p), sizeof v4l_);                                                                           \
        v4l_;                                                                                                      \
    })

/* a in every lane */
#define v4_set1(a)                                                                                                 \
    ({                                                                                                             \
        const double v4s_ = (a);                                                                                   \
        (sq_v4){v4s_, v4s_, v4s_, v4s_};                                                                           \
    })

/* lane c of x in every lane (gcc's and clang's spellings of the same shuffle; the fuzzers
 * build with clang) */
#if defined(__clang__)
#define V4_LANE(x, c) __builtin_shufflevector((x), (x), (c), (c), (c), (c))
#else
#define V4_LANE(x, c) __builtin_shuffle((x), (sq_v4i){(c), (c), (c), (c)})
#endif

/* one 3x3 block in column form (T: 3 columns of 4) times w: ((c0 w0 + c1 w1) + c2 w2) in
 * every row, the order of the scalar row sums */
#define v4_block(T, w)                                                                                             \
    ({                                                                                                             \
        const double *v4T_ = (T);                                                                                  \
        const sq_v4 v4w_ = (w);                                                                                    \
        const sq_v4 v4t_ = v4_load(v4T_) * V4_LANE(v4w_, 0) + v4_load(v4T_ + 4) * V4_LANE(v4w_, 1);               \
        v4t_ + v4_load(v4T_ + 8) * V4_LANE(v4w_, 2);                                                               \
    })

/* the same with w given as 3 doubles at W (each broadcast from memory): the same products and
 * sums, lane by lane */
#define v4_block_s(T, W)                                                                                           \
    ({                                                                                                             \
        const double *v4T_ = (T), *v4W_ = (W);                                                                     \
        const sq_v4 v4t_ = v4_load(v4T_) * v4_set1(v4W_[0]) + v4_load(v4T_ + 4) * v4_set1(v4W_[1]);             \
        v4t_ + v4_load(v4T_ + 8) * v4_set1(v4W_[2]);                                                               \
    })

/* nb row-major 3x3 blocks into column form at T: per block the columns (B0 B3 B6), (B1 B4 B7),
 * (B2 B5 B8), each padded to 4 lanes with a zero */
static inline void sq_lodx_to_columns(const double *src, int nb, double *T)
{
    for (int e = 0; e < nb; e++, src += 9, T += 12)
        for (int c = 0; c < 3; c++) {
            T[4 * c] = src[c];
            T[4 * c + 1] = src[3 + c];
            T[4 * c + 2] = src[6 + c];
            T[4 * c + 3] = 0;
        }
}

/* an interpolated node's displacement d and velocity v (first three lanes) stored at dd, dv,
 * zero on the axes its fixed mask fx holds (the vectors by address: a 32-byte vector passed by
 * value changes ABI between builds with and without AVX, which gcc notes) */
static inline void sq_lodx_store_free(unsigned char fx, const sq_v4 *dp, const sq_v4 *vp, double *dd, double *dv)
{
    const sq_v4 d = *dp, v = *vp;
    if (!fx) {
        dd[0] = d[0], dd[1] = d[1], dd[2] = d[2];
        dv[0] = v[0], dv[1] = v[1], dv[2] = v[2];
        return;
    }
    for (int a = 0; a < 3; a++) {
        int free_axis = !(fx & (1u << a));
        dd[a] = free_axis ? d[a] : 0.0;
        dv[a] = free_axis ? v[a] : 0.0;
    }
}

/* interpolate d and v of node i of level `dst` from tet t of level `src`; constrained
 * axes of the destination stay zero. The three components in the lanes of one vector, each
 * lane summed as the scalar sums were: d += b_m d_m, m = 0..3 */
static inline void interp_node(sq_level *dst, int i, const sq_level *src, int t, const double *b)
{
    const int *tn = src->model.mesh->tets + 4 * t;
    sq_v4 d = {0, 0, 0, 0}, v = {0, 0, 0, 0};
    for (int m = 0; m < 4; m++) {
        const sq_v4 bm = v4_set1(b[m]);
        d += bm * v4_load(src->d + 3 * (size_t)tn[m]);
        v += bm * v4_load(src->v + 3 * (size_t)tn[m]);
    }
    sq_lodx_store_free(dst->model.fixed[i], &d, &v, dst->d + 3 * (size_t)i, dst->v + 3 * (size_t)i);
}

/* substep exponent a level runs at in the adaptive frame */
static inline int sub_log2(const sq_lod *lod, int k)
{
    return lod->lv[k].substeps_log2 + lod->lev[k].extra_log2;
}

/* position of column j in CSR row i of the mesh adjacency (sorted), or -1 */
static inline int adj_find(const sq_mesh *m, int i, int j) { return sq_csr_find(m->adj_start, m->adj, i, j); }

/* counters of one frame's adaptation */
typedef struct adapt_out {
    int splits, merges, refused;
    int changed[SQ_MAX_LEVELS];
} adapt_out;


/* activeset.c, the guard: merge the least needed mergeable regions (smallest criterion over
 * their children) until *projected <= cap, at most `most` of them; each merged node rests
 * `rest` frames before it may split again. Returns the merges made (levels changed in
 * out->changed). */
long sq_lodx_guard_merge(sq_lod *lod, long cap, long *projected, adapt_out *out, int rest, long most);
/* activeset.c, the guard: when the split/merge pass of levels k, k+1 would change more than
 * `most` regions, keep the merges the criterion wants (least needed first) and then its splits
 * (most needed first) up to `most`, and hold the others out of the pass (their state masked
 * until sq_lodx_guard_limit_undo); returns the regions held out */
long sq_lodx_guard_limit(sq_lod *lod, int k, int allow_split, long most);
void sq_lodx_guard_limit_undo(sq_lod *lod, int k);
/* criterion.c: the criterion delta = hbar^2 |Lap(d - d_static)| at node i of level k, ghost
 * neighbours the last cascade did not push read on demand (sq_lodx_value) */
double sq_lodx_delta(const sq_lod *lod, int k, int i);
/* the column-form row cache of level k (krow, activeset.c; reserved ahead by reserve.c): its
 * node index, made on first use with every node -1 (1 when made by this call) */
static inline int sq_lodx_krow_index(sq_lod_level *lk, const sq_level_model *M)
{
    if (lk->krow_at)
        return 0;
    lk->krow_at = sq_malloc(sizeof(int) * (size_t)SQ_MAX(M->n, 1));
    for (int j = 0; j < M->n; j++)
        lk->krow_at[j] = -1;
    return 1;
}
/* its blocks per chunk, set on first use: SQ_KROW_CHUNK, or the longest row if longer (a chunk
 * holds a whole row) */
static inline long sq_lodx_krow_chunk_len(sq_lod_level *lk, const sq_level_model *M)
{
    if (!lk->krow_chunk_len) {
        long most = SQ_KROW_CHUNK;
        for (int j = 0; j < M->n; j++)
            most = SQ_MAX(most, (long)(M->row_start[j + 1] - M->row_start[j]));
        lk->krow_chunk_len = most;
    }
    return lk->krow_chunk_len;
}
/* the need of split node p of level k: its children's largest criterion (its own without
 * children), as the merge rule judges it, m */
double sq_lodx_need(const sq_lod *lod, int k, int p);
/* frame.c: fixed costs for the guard instead of measured ones (tests: deterministic runs with
 * a budget); all <= 0 returns to measuring */
/* a measurement into a learned cost (docs/lod.md "Guaranteed frame rate", "An isolated spike"):
 * the decaying maximum (decay 0.9 a frame, 0.97 a pass), except that a measurement above
 * `spike` x the term with no other such within the last SPIKE_WINDOW measurements raises it
 * only to that bound, and the next ordinary one puts it back; returns the new cost */
double sq_lodx_learn(sq_cost_track *t, double cost, double measured, double decay, double spike);
void sq_lodx_set_costs(sq_lod *lod, double per_update_s, double per_frame_s, double per_level_s,
                       double per_pass_s, double per_change_s);

/* state.c: recompute the active mask, the ghost lists and the integration mask of level k */
void sq_lodx_rebuild_level(sq_lod *lod, int k);
/* state.c: split ghosts of level k from their child tets in level k+1 */
void sq_lodx_pull_level(sq_lod *lod, int k);
/* state.c: the end-of-frame cascade (coarse ghosts pushed only where something reads them) */
void sq_lodx_cascade_needed(sq_lod *lod);
/* criterion.c: Laplacian weights of the criterion per CSR entry of the mesh adjacency */
double *sq_lodx_criterion_weights(const sq_mesh *m);
/* criterion.c: split/merge between levels k and k+1; merges until the node-update cap fits */
void sq_lodx_adapt_pair(sq_lod *lod, int k, int allow_split, long *projected, adapt_out *out);
void sq_lodx_merge_node(sq_lod *lod, int k, int p); /* criterion.c: one merge, values interpolated */
void sq_lodx_enforce_cap(sq_lod *lod, long *projected, adapt_out *out);
/* coupling.c: ring and frontier blocks up to date for material mat (NULL: the last one seen) */
void sq_lodx_update_ring_blocks(sq_lod *lod, const sq_material *mat);
/* reserve.c: grow the coupling arrays (ring and frontier rows, element-block cache) ahead of need and map
 * their pages now, within `seconds` of thread CPU (estimated); returns the pages written */
long sq_lodx_reserve_blocks(sq_lod *lod, double seconds, int ahead);
/* every level's state and per-node scratch arrays (d, v, forces, step start, d + b v, push
 * stamps, marks) mapped, their contents kept: a frame's first writes to a node no frame wrote
 * before (the first push of the finest level's ghosts: 9.6 ms of page faults in box-big's
 * frame 1) then cost no fault; returns the pages touched */
long sq_lodx_map_state(sq_lod *lod);
/* chunks of each cache (element blocks, column-form rows) mapped ahead of use at load, where a
 * frame keeps one: a refinement's first touches of new cache pages then fall at load, not in
 * its frames (docs/lod.md "Guaranteed frame rate") */
#define SQ_RESERVE_LOAD_CHUNKS 8
/* the interface substeps again (Gershgorin, then the sharp rule if on) for the current blocks */
void sq_lodx_coupling_bound(sq_lod *lod);
/* bound.c: the sharp per-level substeps ("step_bound": "sharp"), its state freed */
void sq_lodx_sharp_bound(sq_lod *lod);
void sq_lodx_sharp_free(sq_lod *lod);
/* the next sharp pass estimates every level again (the guard's calibration times it) */
void sq_lodx_sharp_invalidate(sq_lod *lod);
/* the sharp estimates of the next passes end by this thread CPU time (0: no limit); a level
 * whose estimate cannot is left on its Gershgorin substeps and owes it (the guard, frame.c) */
void sq_lodx_sharp_deadline(sq_lod *lod, double cpu_deadline);
/* the owed estimates made within `seconds` of thread CPU (INFINITY: all), each only when its
 * prediction fits; returns how many were made (their levels' substeps then change) */
int sq_lodx_sharp_owed(sq_lod *lod, double seconds);
/* owed estimates: of level k, or of every level (k < 0) */
int sq_lodx_sharp_owes(const sq_lod *lod, int k);
/* estimates not made by their deadline so far, and owed ones made later */
void sq_lodx_sharp_late(const sq_lod *lod, long *late, long *made_later);
/* for tests: level k's block S_kk + C_k of the majorant (S = M^-1/2 A M^-1/2) as bound.c applies it,
 * dense over 3 x its active nodes (active_list order, constrained axes zero rows and columns),
 * and the scaled diagonal C_k (*off, same order); both to free */
double *sq_lodx_sharp_dense(sq_lod *lod, int k, double **off);
/* tests: the estimate (Lanczos, Ritz vector, rho + ||r||, not capped) of the dense symmetric
 * n x n matrix A (n a multiple of 3) from start, iters steps (at most 40) */
double sq_lodx_sharp_lanczos_dense(const double *A, int n, const double *start, int iters);
/* the same with the early stop (bound.c's stop_rule; rule 1 on, 0 off) against the ceiling (the
 * estimate capped by it), substep bins floor(log4(w2 / bin_unit)); its steps and whether it
 * stopped early (1) */
double sq_lodx_sharp_lanczos_dense_stop(const double *A, int n, const double *start, int iters, double ceiling,
                                        double bin_unit, int rule, int *steps, int *stopped);
/* tests: stop_rule's decision (1: stop) for the Lanczos tridiagonal (alpha, beta, order m) against
 * the ceiling, in the dense tests' bins floor(log4(w2 / bin_unit)) */
int sq_lodx_sharp_stop_tridiag(const double *alpha, const double *beta, int m, double ceiling, double bin_unit);
/* coupling.c: frontier forces of level k (correction after a full-row pass; merged rows) */
void sq_lodx_front_correct(sq_lod *lod, const sq_material *mat, int k);
void sq_lodx_front_rows(sq_lod *lod, const sq_material *mat, const double gravity[3], int k);
/* ring.c: sources of every ring ghost; ring values of level k at tick t; ring reactions */
void sq_lodx_build_sources(sq_lod *lod);
void sq_lodx_eval_ring(sq_lod *lod, int k, long t);
/* ring.c: only the ring ghosts read by the ring rows with a source on a level in mask; returns
 * how many */
int sq_lodx_eval_ring_hot(sq_lod *lod, int k, long t, unsigned mask);
int sq_lodx_couple_out(sq_lod *lod, const sq_material *mat, int k, long t); /* returns the rows */
/* holds.c: the frame's holds onto active nodes (held nodes prescribed over frame_dt, left out
 * of the integrated lists); the internal force on the held nodes of level k at its step;
 * the tool feedback into force[tool] (may be NULL) and the holds released */
void sq_lodx_hold_start(sq_lod *lod, const sq_hold *holds, int nholds, int ntools, double frame_dt);
void sq_lodx_hold_sample(sq_lod *lod, int k, const double gravity[3]);
/* at a tick of a frame with live holds (in->live): their nodes moved to the newest targets */
void sq_lodx_hold_live(sq_lod *lod, const sq_lod_frame_in *in, double frac);
void sq_lodx_hold_end(sq_lod *lod, const sq_hold *holds, int nholds, double (*force)[3]);

/* activeset.c: per-level index lists (active, inner, integrated), the nodes whose values at
 * the start of a step are read, the coarse ghosts something reads (the rest are pushed only
 * on demand), and the kernels over those lists */
void sq_lodx_level_lists(sq_lod *lod, int k);
void sq_lodx_refresh_lists(sq_lod *lod);
void sq_lodx_mask_list(sq_lod *lod, int k);
void sq_lodx_rows(sq_lod *lod, const sq_material *mat, const double gravity[3], int k);
/* w_tick of level k (active nodes and ring ghosts) = d + b v, b the material's stiffness
 * damping: what the row kernels of a due linear level without viscosity read */
void sq_lodx_form_w(sq_lod *lod, const sq_material *mat, int k);
void sq_lodx_integrate(sq_lod *lod, int k, double dt);
void sq_lodx_save_prev(sq_lod *lod, int k);
void sq_lodx_push_needed(sq_lod *lod);
/* the cascade values of the ring ghosts, before sq_lodx_eval_ring replaces them (for sq_lod_flush) */
void sq_lodx_save_cascade(sq_lod *lod);
/* d and v of node j of level k for a read inside the frame: the stored value, except for a
 * coarse ghost outside the needed set, interpolated afresh from the coarser level */
void sq_lodx_value(const sq_lod *lod, int k, int j, double d[3], double v[3]);
/* interp_node reading stale coarse-ghost corners on demand */
void sq_lodx_interp(sq_lod *lod, sq_level *dst, int i, int src_level, int t, const double *b);
void sq_lodx_free(sq_lod *lod, int k);
/* static equilibria of the levels up to the top for gravity (once per gravity and material) */
void sq_lodx_static_loads(sq_lod *lod, const double gravity[3]);
void sq_lodx_sort_ints(int *a, int n);

/* corotational.c (levels with lv[k].corot): the frame's force pass of a due level k and the
 * ring reactions of level k at tick t computed tet by tet instead of from the linear blocks;
 * the tet lists brought up to the layout (a no-op unless it changed); the weighted energy */
int sq_lodx_corot_on(const sq_lod *lod);
void sq_lodx_corot_layout(sq_lod *lod, const sq_material *mat);
void sq_lodx_corot_forces(sq_lod *lod, const sq_material *mat, const double gravity[3], int k);
int sq_lodx_corot_couple_out(sq_lod *lod, const sq_material *mat, int k, long t); /* ring rows handed back */
double sq_lodx_corot_energy(const sq_lod *lod, double *kinetic, double *elastic);
void sq_lodx_corot_free(sq_lod *lod, int k);
/* corotational.c: the ring weights of corotational levels made exact for affine fields (a
 * rigid motion of the body gives no force), at the end of sq_lodx_build_sources */
void sq_lodx_corot_affine_sources(sq_lod *lod);
/* corotational.c: level k's static equilibrium under gravity g with corotational elasticity,
 * from the linear one in d (replaced on success: 0; else -1 and d unchanged) */
int sq_lodx_corot_static(sq_lod *lod, int k, const double g[3], double *d, int *iterations);

#endif
