/* bound_internal.h - what bound.c (the sharp rule's schedule) and estimate.c (one level's
 * estimate) share: the sharp state and the estimate's entry points. Included by those two only.
 */
#ifndef SQ_LOD_BOUND_INTERNAL_H
#define SQ_LOD_BOUND_INTERNAL_H

#include "lod/lod_internal.h"

#define ITERS_COLD 40  /* Lanczos steps without a previous Ritz vector (as fixed mode) */
#define ITERS_WARM 16  /* from the previous Ritz vector */
#define ITERS_REF 120  /* the check's reference run (sq_debug()->sharp_check, a debug path) */
#define BASIS_MAX_DOUBLES (8L << 20) /* Krylov basis kept for the Ritz vector: at most 64 MB */

struct lod_sharp {
    int on;
    double step_fraction;
    double *ritz[SQ_MAX_LEVELS];   /* last Ritz vector per level, node-indexed, scaled (3n) */
    double lambda[SQ_MAX_LEVELS];  /* the upper estimate used, 1/s^2 (0: no active node) */
    double gersh[SQ_MAX_LEVELS];   /* its Gershgorin ceiling, 1/s^2 */
    int iters[SQ_MAX_LEVELS];      /* Lanczos steps of the last estimate */
    int stopped[SQ_MAX_LEVELS];    /* 1: its Lanczos run stopped in the ceiling's bin (stop_rule) */
    long calls;                    /* estimates made (one per level per rebuild) */
    double cpu_s;                  /* their thread CPU time, s */
    /* an estimate is made again only when what it reads changed (level_key) */
    unsigned long long key[SQ_MAX_LEVELS]; /* fingerprint of the level's operator at its estimate */
    int have_key[SQ_MAX_LEVELS];   /* 1: key[k] and nsub[k] hold */
    int nsub[SQ_MAX_LEVELS];       /* the exponent the estimate chose, -1: Gershgorin's kept */
    long skipped;                  /* estimates skipped (operator unchanged) */
    double *basis;                 /* Lanczos basis and work vector, kept (basis_cap doubles) */
    size_t basis_cap;
    int *ritz_nodes[SQ_MAX_LEVELS]; /* the nodes ritz[k] is nonzero on (nritz[k]) */
    int nritz[SQ_MAX_LEVELS];
    int *idx[SQ_MAX_LEVELS];       /* scratch of the operator, kept: active index per node, -1 */
    double *u[SQ_MAX_LEVELS];      /* ... and each level's values under the product, zero (3 n) */
    /* the estimates' time limit (the guard, docs/lod.md "Guaranteed frame rate") */
    double deadline;               /* thread CPU time by which the estimates must end (0: none) */
    int owed[SQ_MAX_LEVELS];       /* 1: not made by its deadline: the level runs its Gershgorin
                                    * substeps until a frame with room makes it (sq_lodx_sharp_owed) */
    double cost_unit[SQ_MAX_LEVELS]; /* thread CPU per product per unit (active node or ring ghost
                                    * read), s: a decaying maximum over the level's estimates */
    long late;                     /* estimates not made by their deadline */
    long made_later;               /* owed estimates made later */
    /* the early stop's bin edges (stop_edges), kept per level: bin edge_n[k]'s (below, top]
     * for the frame step, step fraction and damping in edge_of[k] */
    int have_edges[SQ_MAX_LEVELS], edge_n[SQ_MAX_LEVELS];
    double edge_of[SQ_MAX_LEVELS][4], edge_below[SQ_MAX_LEVELS], edge_top[SQ_MAX_LEVELS];
};

/* the damped stable step of an undamped rate w2 (1/s^2), s */
double sq_lodx_step_bound_of(const sq_material *mat, double w2);
/* the exponent n of level k's 2^n substeps per frame for the estimate w2 (non-decreasing in
 * w2); 21: above 2^20, -1: no estimate (NaN or negative) */
int sq_lodx_sharp_exponent(const sq_lod *lod, const struct lod_sharp *S, int k, double w2);
/* the upper estimate of lambda_max(M^-1 (A_kk + C_k)) of level k (1/s^2), its ceiling in *gersh;
 * NAN when the deadline (thread CPU, 0: none) came first (tprod: a product's predicted time) */
double sq_lodx_sharp_estimate(sq_lod *lod, struct lod_sharp *S, int k, double *gersh, double deadline, double tprod);
/* sq_debug()->sharp_check: level k's estimate est against a full reference run (one line) */
void sq_lodx_sharp_check(sq_lod *lod, struct lod_sharp *S, int k, double est);

#endif
