/* lod_internal.h - the adaptive state shared by the files of the lod module, one per stage:
 *   state.c      creation, definition, reset, the level's state lists, ghost values (sync), check
 *   criterion.c  the split/merge criterion, split/merge decisions, the node-update cap
 *   coupling.c   the coupling blocks of the ring and frontier rows, the interface substeps
 *   ring.c       the ring ghosts' sources, their values and their reactions
 *   holds.c      tool holds onto active nodes
 *   frame.c      sq_lod_frame: the frame as a list of timed stages
 *   views.c      node levels, active lists, energy, projected updates
 *   activeset.c  per-level index lists and the kernels that run over them
 *   hierarchy.c  the links between consecutive levels
 * Not part of the module's contract (lod.h).
 */
#ifndef SQ_LOD_INTERNAL_H
#define SQ_LOD_INTERNAL_H

#include "lod/lod.h"

enum { ST_COARSE = 0, ST_ACTIVE = 1, ST_SPLIT = 2 };

/* a node that carries one or more tool holds this frame (the body's fixed-mode convention:
 * the node jumps to its target when the hold starts, with velocity (target - old) / time left,
 * and is not integrated; its feedback is the mean over its level's substeps of f - m g) */
typedef struct hold_entry {
    int level, node;
    int count;        /* holds mapped to it (0: dead, its node stopped being active) */
    int pending;      /* target changed, to be applied */
    double gsum[3];   /* sum of the targets its holds ask of it */
    double from[3];   /* displacement when the hold (re)started */
    double t_from;    /* time within the frame the hold (re)started, s */
    double fsum[3];   /* internal force summed over the substeps it was held, N */
    int nf;
} hold_entry;

struct sq_lod {
    sq_level *lv;
    int L;                               /* levels */
    int top;                             /* highest level that may be active */
    sq_lod_def def;
    sq_hierarchy h;
    unsigned char *state[SQ_MAX_LEVELS];
    unsigned char *active[SQ_MAX_LEVELS]; /* 1 = active (exposed) */
    unsigned char *mask[SQ_MAX_LEVELS];   /* integrated this frame: active and not held */
    int nactive[SQ_MAX_LEVELS], nmask[SQ_MAX_LEVELS];
    int *gf[SQ_MAX_LEVELS], ngf[SQ_MAX_LEVELS]; /* split ghosts */
    int *gc[SQ_MAX_LEVELS], ngc[SQ_MAX_LEVELS]; /* coarse ghosts */
    double *clap[SQ_MAX_LEVELS];         /* criterion Laplacian weights per CSR entry (nnz) */
    /* coupling: the ring of ghosts next to active nodes, and the reactions handed back */
    int *ring[SQ_MAX_LEVELS], nring[SQ_MAX_LEVELS];
    int due[SQ_MAX_LEVELS];              /* level steps at the current tick */
    /* each ring ghost as a combination of active nodes (level, node, weight) */
    int *fs_start[SQ_MAX_LEVELS];        /* (nring + 1) */
    unsigned char *fs_levels[SQ_MAX_LEVELS]; /* per ring ghost: bit m set if a source is on level m */
    int *fs_level[SQ_MAX_LEVELS], *fs_node[SQ_MAX_LEVELS];
    double *fs_w[SQ_MAX_LEVELS];
    int fs_cap[SQ_MAX_LEVELS];
    /* ring rows of the energy: blocks summed over the tets that touch an active node only
     * (a ring row cut to S_k would pin the ring to zero displacement); aligned with the
     * mesh adjacency row of each ring ghost */
    int *node_tet_start[SQ_MAX_LEVELS], *node_tet[SQ_MAX_LEVELS];
    /* per node-tet incidence c: the node's corner in the tet (nt_p) and, for each corner q,
     * the block's position in the node's adjacency row (nt_e, 4 per incidence) */
    unsigned char *nt_p[SQ_MAX_LEVELS];
    int *nt_e[SQ_MAX_LEVELS];
    /* element blocks of the tets met so far as mixed tets (16 blocks of 9 per tet, viscous
     * ones alongside when the material uses viscosities), so a rebuild of the ring rows adds
     * cached blocks instead of recomputing them; slots are handed out on first use, so the
     * memory follows the region that has been refined, not the mesh */
    int *ke_slot[SQ_MAX_LEVELS];         /* slot of a tet, or -1 (ntets) */
    double *ke[SQ_MAX_LEVELS];           /* slots x 144 (x 2 with viscosity) */
    int ke_n[SQ_MAX_LEVELS], ke_cap[SQ_MAX_LEVELS];
    double *tet_geom[SQ_MAX_LEVELS];     /* per tet: volume and the 4 basis gradients (13) */
    int *rk_off[SQ_MAX_LEVELS];          /* (nring + 1) offsets in blocks */
    int *rk_col[SQ_MAX_LEVELS], *fk_col[SQ_MAX_LEVELS]; /* column (node) of each block */
    double *rk[SQ_MAX_LEVELS], *rd[SQ_MAX_LEVELS];
    int rk_cap[SQ_MAX_LEVELS], rd_cap[SQ_MAX_LEVELS];
    int rk_dirty[SQ_MAX_LEVELS];
    /* frontier: active nodes with a ghost neighbour; their tets with a ghost corner count
     * half (the other level covers the same band), a correction to their full rows */
    int *front[SQ_MAX_LEVELS], nfront[SQ_MAX_LEVELS];
    unsigned char *inner[SQ_MAX_LEVELS]; /* active and not on the frontier (n) */
    /* the frontier rows with their correction folded in (full adjacency rows, K - correction),
     * so the masked force pass can skip the frontier and no correction pass is needed */
    double *fm[SQ_MAX_LEVELS];
    int fm_cap[SQ_MAX_LEVELS];
    int *fk_off[SQ_MAX_LEVELS];
    double *fk[SQ_MAX_LEVELS], *fd[SQ_MAX_LEVELS];
    int fk_cap[SQ_MAX_LEVELS], fd_cap[SQ_MAX_LEVELS];
    int have_mat;
    sq_material mat;                     /* material the ring blocks were built for */
    sq_operator_kind op;
    /* values at the start of each level's last step, for values between its steps */
    double *dprev[SQ_MAX_LEVELS], *vprev[SQ_MAX_LEVELS];
    long step_t0[SQ_MAX_LEVELS], step_len[SQ_MAX_LEVELS];
    /* extra substep exponent per level: coupling forces from other levels stiffen the nodes
     * near an interface beyond the level's own bound (see coupling_bound) */
    int extra[SQ_MAX_LEVELS];
    double *rowk[SQ_MAX_LEVELS];         /* own Gershgorin row sums (n) */
    double own_max[SQ_MAX_LEVELS];       /* largest rowk / mass over the level's free nodes */
    double *cpl[SQ_MAX_LEVELS];          /* coupling row sums (n) */
    int *ring_index[SQ_MAX_LEVELS];      /* ring position of a node, or -1 (n) */
    const double *k_seen;                /* level 0's K when the blocks were built */
    int *slot[SQ_MAX_LEVELS];            /* hold entry of a node, or -1 */
    unsigned char *fresh[SQ_MAX_LEVELS]; /* split in the current adapt pass (no merge back) */
    hold_entry *he;
    int nhe, cap_he;
    int *hold_entry_of;                  /* entry of each hold of the frame */
    int cap_holds;
    double last_time;                    /* CPU time of the previous frame, s */
    double cost_update;                  /* CPU s per node update, last frame with updates (0: none yet) */
    double cost_fixed;                   /* CPU s of a frame's rest (rebuilds, end-of-frame ghosts) */
    /* index lists (activeset.c), so a frame's cost follows the active set, not the body */
    int *alist[SQ_MAX_LEVELS];           /* active nodes, increasing (nactive) */
    int *ilist[SQ_MAX_LEVELS], nilist[SQ_MAX_LEVELS]; /* inner active nodes */
    int *mlist[SQ_MAX_LEVELS], nmlist[SQ_MAX_LEVELS]; /* integrated this frame (mask) */
    int *plist[SQ_MAX_LEVELS], nplist[SQ_MAX_LEVELS]; /* nodes whose step-start values are read */
    int *need[SQ_MAX_LEVELS], nneed[SQ_MAX_LEVELS];   /* coarse ghosts pushed every frame */
    unsigned char *inneed[SQ_MAX_LEVELS]; /* 1 if in need (n) */
    unsigned char *mark[SQ_MAX_LEVELS];  /* scratch marks (n), all zero between uses */
    int lists_dirty;                     /* plist / need out of date */
    double *cv[SQ_MAX_LEVELS];           /* d, v of each ring ghost as the cascade pushed or pulled it,
                                          * before its ring value replaced it (nring x 6) */
    int cv_cap[SQ_MAX_LEVELS];
    unsigned *pstamp[SQ_MAX_LEVELS];     /* cascade a coarse ghost was last pushed at (n) */
    unsigned cascade_no;                 /* cascades run (the end-of-frame push counts one) */
    unsigned full_no;                    /* the last one that pushed every coarse ghost */
    /* the criterion judges the displacement from each level's static equilibrium under the
     * body's constant load (gravity), so a sag alone keeps nothing refined */
    double *dstat[SQ_MAX_LEVELS];        /* static displacement (n x 3), NULL: judged from 0 */
    double stat_g[3];                    /* gravity it was solved for */
    const double *stat_k;                /* level 0's K it was solved with */
    int stat_done, stat_top;
    sq_material stat_mat;                /* material it was solved with (lod->mat then) */
    int stale;                           /* coarse ghosts outside `need` not pushed since the last frame */
    long gen;                            /* bumped whenever a level's states change */
    long nl_gen;                         /* gen the node levels were last given out at */
    const unsigned char *nl_out;         /* ... and the buffer they went to */
    unsigned char *nlv[2];               /* scratch of sq_lod_node_levels (largest level) */
};

/* interpolate d and v of node i of level `dst` from tet t of level `src`; constrained
 * axes of the destination stay zero */
static inline void interp_node(sq_level *dst, int i, const sq_level *src, int t, const double *b)
{
    const int *tn = src->mesh->tets + 4 * t;
    double d[3] = {0, 0, 0}, v[3] = {0, 0, 0};
    for (int m = 0; m < 4; m++) {
        const double *sd = src->d + 3 * tn[m], *sv = src->v + 3 * tn[m];
        for (int a = 0; a < 3; a++) {
            d[a] += b[m] * sd[a];
            v[a] += b[m] * sv[a];
        }
    }
    unsigned char fx = dst->fixed[i];
    for (int a = 0; a < 3; a++) {
        int free_axis = !(fx & (1u << a));
        dst->d[3 * i + a] = free_axis ? d[a] : 0.0;
        dst->v[3 * i + a] = free_axis ? v[a] : 0.0;
    }
}

/* substep exponent a level runs at in the adaptive frame */
static inline int sub_log2(const sq_lod *lod, int k)
{
    return lod->lv[k].substeps_log2 + lod->extra[k];
}

/* position of column j in CSR row i of the mesh adjacency (sorted), or -1 */
static inline int adj_find(const sq_mesh *m, int i, int j)
{
    int lo = m->adj_start[i], hi = m->adj_start[i + 1] - 1;
    while (lo <= hi) {
        int mid = (lo + hi) / 2;
        if (m->adj[mid] == j)
            return mid;
        if (m->adj[mid] < j)
            lo = mid + 1;
        else
            hi = mid - 1;
    }
    return -1;
}

/* counters of one frame's adaptation */
typedef struct adapt_out {
    int splits, merges, refused;
    int changed[SQ_MAX_LEVELS];
} adapt_out;


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
void sq_lodx_enforce_cap(sq_lod *lod, long *projected, adapt_out *out);
/* coupling.c: ring and frontier blocks up to date for material mat (NULL: the last one seen) */
void sq_lodx_update_ring_blocks(sq_lod *lod, const sq_material *mat);
/* coupling.c: frontier forces of level k (correction after a full-row pass; merged rows) */
void sq_lodx_front_correct(sq_lod *lod, const sq_material *mat, int k);
void sq_lodx_front_rows(sq_lod *lod, const sq_material *mat, const double gravity[3], int k);
/* ring.c: sources of every ring ghost; ring values of level k at tick t; ring reactions */
void sq_lodx_build_sources(sq_lod *lod);
void sq_lodx_eval_ring(sq_lod *lod, int k, long t);
void sq_lodx_couple_out(sq_lod *lod, const sq_material *mat, int k, long t);
/* holds.c: map hold h onto its active node; prescribe the held nodes; forget the holds */
void sq_lodx_map_hold(sq_lod *lod, const sq_hold *hd, int h, double t_now);
void sq_lodx_start_holds(sq_lod *lod, double T);
void sq_lodx_clear_holds(sq_lod *lod);

/* activeset.c: per-level index lists (active, inner, integrated), the nodes whose values at
 * the start of a step are read, the coarse ghosts something reads (the rest are pushed only
 * on demand), and the kernels over those lists */
void sq_lodx_level_lists(sq_lod *lod, int k);
void sq_lodx_refresh_lists(sq_lod *lod);
void sq_lodx_mask_list(sq_lod *lod, int k);
void sq_lodx_rows(sq_lod *lod, const sq_material *mat, const double gravity[3], int k);
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

#endif
