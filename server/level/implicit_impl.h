/* implicit_impl.h - the implicit solve's state and operator, shared by implicit.c (the step,
 * the operator, CG) and implicit_mg.c (the multigrid preconditioner). Internal to level/.
 */
#ifndef SQ_LEVEL_IMPLICIT_IMPL_H
#define SQ_LEVEL_IMPLICIT_IMPL_H

#include <stddef.h>

#include "level/level.h"

/* one coarser level of the multigrid preconditioner: the level (its linear operator, masses
 * and constrained axes), its V-cycle vectors, the inverse diagonal blocks of its matrix, the
 * smoother's damping, and for every node of the next finer level the tet of this level's rest
 * mesh containing it with its barycentrics (the prolongation; its transpose restricts) */
typedef struct mg_level {
    const sq_level_model *M;
    int n;
    double *x, *b, *r, *t;     /* 3 n */
    double *dinv;              /* 9 n */
    double *acc;               /* zero scratch of the fused K pass (3 n + 1) */
    double omega;
    double *chol;              /* coarsest level, 3 n <= SQ_MG_DENSE: dense Cholesky factor of its
                                  matrix (lower, row-major), for chol_cm/ck/cd; else NULL */
    double chol_cm, chol_ck, chol_cd;
    int nfine;                 /* nodes of the finer level */
    int *tet;                  /* nfine */
    double *bary;              /* 4 nfine */
} mg_level;

struct sq_implicit {
    int n, ntets;
    double *zo;                   /* the previous preconditioned residual (flexible CG) */
    double *dvprev;               /* the last step's dv: the next solve's start (3 n) */
    int have_prev;
    double *acc;                  /* zero scratch of the fused K pass (3 n + 1) */
    /* multigrid: the coarser levels (coarse[0] next to this one), the finest level's V-cycle
     * vectors and smoother damping, and the coefficients the dampings were estimated for */
    int nmg;
    mg_level mg[SQ_MAX_LEVELS];
    double *vx, *vb, *vr, *vt;
    double omega0, omega_cm, omega_ck;
    int omega_age;
    double *x, *r, *z, *p, *q;    /* CG vectors (3 n) */
    double *rhs, *kv, *dv;        /* right-hand side, K P v0, the solved dv (3 n) */
    double *d0, *v0;              /* the step's start state (3 n), for Newton iterations */
    double *pre;                  /* Jacobi: inverse diagonal (3 n); block: inverse 3x3 (9 n) */
    double *rot;                  /* corotational: R per tet (9 ntets), the linearisation's */
    /* corotational: the warped stiffness assembled in the level's upper-half layout (Kup
     * blocks, up_start[n] x 9) at each linearisation, and for each tet the index of each of its
     * 6 edges in that layout (6 ntets, corner pairs 01 02 03 12 13 23) */
    double *kup_r;
    int *tet_edge;
    /* the energy guard: the total energy of the last step's end state and a hash of that state
     * (d and v bits, gravity), so the next step's start energy is not computed again when
     * nothing changed the state in between */
    double e_cache;
    unsigned long long e_hash;
    int e_valid;
    unsigned char *freeax;        /* free axes per node this step, bits x=1 y=2 z=4 (n) */
    /* contacts as constraints: the caller's list, and which of its entries this step uses (a
     * free node: 1), their prescribed part of dv (3 n, zero elsewhere) */
    const sq_implicit_contacts *cc;
    unsigned char *cuse;
    int ncuse, cuse_cap;
    double *zc;
};

/* the operator of one solve: y = P (c_m M + c_k K + c_d D) P x */
typedef struct imp_op {
    const sq_level_model *M;
    const sq_level_state *S;
    const sq_implicit *I;
    double cm, ck, cd;
} imp_op;

static inline void *imp_calloc(size_t count, size_t size) { return sq_calloc(count ? count : 1, size); }

/* implicit.c */
sq_implicit *sq_imp_get(const sq_level_model *M, sq_level_state *S); /* S's solve state, made at the first call */
void sq_imp_apply_k(const imp_op *o, const double *x, double *y);   /* y = K x */
void sq_imp_apply_a(const imp_op *o, const double *x, double *y);   /* y = P A x */
void sq_imp_project(const sq_implicit *I, double *x);               /* x = P x */
int sq_imp_inv3_free(const double *Bin, unsigned fa, double *out);  /* inverse on the free axes */
void sq_imp_diag_blocks(const imp_op *o, const sq_level_model *M, const double *kup, double *blk);
void sq_imp_block_apply(const double *dinv, int n, const double *r, double *z);
double sq_imp_dot(const double *a, const double *b, size_t n);

/* implicit_mg.c */
void sq_imp_mg_free(sq_implicit *I);
void sq_imp_coarse_dinv(const imp_op *o, mg_level *g);
double sq_imp_cyc_lambda(const imp_op *o, int j, double *x, double *y, double *z);
void sq_imp_vcycle(const imp_op *o, int j, const double *b, double *x);

#endif
