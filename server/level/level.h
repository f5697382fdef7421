/* level.h - one level of detail of a body: its material, rest mesh, precomputed operator,
 * stability bound, step, static solve and state. The lowest engine layer: it knows no lod and
 * no body. Scene, net and render go through body/body.h. The fixed-resolution step (body/)
 * and the adaptive multi-level step (lod/) are both built from these per-level primitives, so
 * a level behaves the same whichever drives it.
 *
 * Elastic force on node i: f_i = - sum_j K_ij d_j  (3x3 blocks K_ij, CSR over the mesh
 * adjacency, diagonal included). Damping force: - a m_i v_i - b sum_j K_ij v_j (Rayleigh), or
 * - sum_j D_ij v_j with D built like K from (phi, psi) when the material uses viscosities.
 */
#ifndef SQ_LEVEL_H
#define SQ_LEVEL_H

#include "mesh/mesh.h"

#define SQ_MAX_LEVELS 6
#define SQ_MAX_CONSTRAINTS 16

/* material in the standard Lamé names (mu = shear modulus); see docs/physics.md */
typedef struct sq_material {
    double mu;                 /* shear modulus, Pa */
    double lambda;             /* first Lamé parameter, Pa */
    double density;            /* kg/m^3 */
    double rayleigh_mass;      /* a in C = a M + b K, 1/s */
    double rayleigh_stiffness; /* b in C = a M + b K, s */
    int use_viscosity;         /* 1: damping from the paper's viscosities phi/psi instead of b K */
    double phi, psi;           /* paper Eq. 7 viscosities (standard-name roles of mu, lambda), Pa s */
} sq_material;

/* the paper's cube material (mu 40 kPa, lambda 100 kPa, 1000 kg/m^3), undamped, every other
 * field 0 */
sq_material sq_material_paper(void);
/* E (Pa), nu -> mu, lambda; returns -1 and err if out of range */
int sq_material_from_E_nu(sq_material *m, double E, double nu, sq_err *err);
void sq_material_E_nu(const sq_material *m, double *E, double *nu);
/* range checks (positive moduli, 0 <= nu < 0.5, density > 0, finite values) */
int sq_material_check(const sq_material *m, sq_err *err);

typedef enum sq_operator_kind {
    SQ_OPERATOR_FEM = 0,   /* standard linear FEM (default) */
    SQ_OPERATOR_PAPER = 1  /* the paper's Laplacian + grad-div (Eqs. 5-6) */
} sq_operator_kind;

/* elastic model: linear (the paper's, small-strain) or corotational (rotation-invariant:
 * f = R K_T (R^T x - X) per tet; fem operator, fixed or adaptive lod; docs/physics.md) */
typedef enum sq_elasticity_kind {
    SQ_ELASTICITY_LINEAR = 0,
    SQ_ELASTICITY_COROTATIONAL = 1
} sq_elasticity_kind;

/* constraint regions */
typedef enum sq_region_kind { SQ_REGION_BOX = 0, SQ_REGION_HALFSPACE = 1 } sq_region_kind;
typedef struct sq_constraint {
    sq_region_kind kind;
    double a[3], b[3]; /* box: min corner a, max corner b; half-space: point a, normal b
                          (nodes with (x - a).b <= 0 are selected) */
    unsigned axes;     /* constrained axes: bit 0 = x, 1 = y, 2 = z; 7 = fixed node */
} sq_constraint;


typedef struct sq_corot sq_corot;
typedef struct sq_anp sq_anp;
typedef struct sq_implicit sq_implicit;

/* the element model a level's explicit step, force pass and energy apply, chosen once when the
 * model is set (sq_level_init: linear; sq_level_corot_enable: corotational; sq_level_anp_enable:
 * nodal or smoothed) and dispatched through level.c's table of sq_level_ops, one row per kind
 * (corotational wins over a pressure mode when both are enabled, as it always has). The
 * integrator (these rows' symplectic Euler substeps, or backward Euler by CG,
 * sq_level_implicit_step, on the same operator) is a row of the fixed frame's integrator
 * table in body/frame.c, picked by the body's def.integrator. */
typedef enum sq_level_op_kind {
    SQ_LEVEL_OP_LINEAR = 0,   /* element-wise linear blocks K (and D) */
    SQ_LEVEL_OP_COROT = 1,    /* corotational tets (level/corot.c) */
    SQ_LEVEL_OP_NODAL = 2,    /* average nodal pressure tets (level/anp.c) */
    SQ_LEVEL_OP_SMOOTHED = 3, /* face-smoothed tets with nodal pressure (level/anp.c) */
    SQ_LEVEL_OP_NKINDS
} sq_level_op_kind;

/* the volumetric (and deviatoric) treatment of a body's tets ("pressure" in scenes and set):
 * element-wise (the standard tets), average nodal pressure, or nodal pressure with the
 * deviatoric strain smoothed over face domains (docs/physics.md section 10) */
enum { SQ_PRESSURE_ELEMENT = 0, SQ_PRESSURE_NODAL = 1, SQ_PRESSURE_SMOOTHED = 2 };

/* the constant model of one level: rest mesh, topology, operator blocks, masses and constrained
 * axes. Built by sq_level_init and rebuilt only by sq_level_set_material; the step, the force
 * passes, the residual and the static solver only read it (const sq_level_model *). */
typedef struct sq_level_model {
    const sq_mesh *mesh;   /* rest mesh (borrowed) */
    int n;                 /* nodes */
    int nnz;               /* CSR entries = mesh->adj_start[n] */
    const int *row_start;  /* = mesh->adj_start (n+1) */
    const int *col;        /* = mesh->adj (nnz) */
    double *K;             /* stiffness blocks, row-major 3x3 per CSR entry (nnz x 9) */
    double *D;             /* viscosity blocks (nnz x 9), NULL unless material.use_viscosity */
    double *lap;           /* scalar Laplacian weights sum_T V (a_i . a_j) per CSR entry (nnz) */
    double *mass;          /* lumped mass (n), kg */
    double *vol;           /* nodal volume sum_T V/4 (n), m^3 */
    double *hbar;          /* mean 1-ring edge length (n), m */
    unsigned char *fixed;  /* constrained axes per node, bits x=1 y=2 z=4 (n) */
    int nfree;             /* nodes with at least one unconstrained axis */
    /* the strict upper half of K (j > i) for the all-nodes force pass: K_ji = K_ij^T and
     * K_ii = -sum_{j != i} K_ij, so f = -K d needs only these blocks, applied to d_j - d_i */
    int *up_start;         /* CSR rows (n+1) */
    int *up_col;           /* columns j > i (up_start[n]) */
    double *Kup;           /* blocks (up_start[n] x 9) */
    /* the row of the operator table the step uses, set with the element model (sq_level_init:
     * linear; sq_level_corot_enable, sq_level_anp_enable and their frees) */
    sq_level_op_kind op_kind;
} sq_level_model;

/* the changing state of one level: displacement and velocity, the scratch of the force passes,
 * and the element models' data with their state (the corotational rotations, the nodal
 * pressure scratch, the implicit solve's vectors). The step, the force passes and the
 * integration take (const sq_level_model *, sq_level_state *): they write only here. */
typedef struct sq_level_state {
    double *d;             /* displacement (n x 3), m */
    double *v;             /* velocity (n x 3), m/s */
    double *f;             /* scratch: total force of the last force pass (n x 3), N */
    double *acc;           /* scratch: force accumulator of the fast pass, all zero between calls (n x 3) */
    /* rest data and state of the optional element models (kept together: see docs/physics.md) */
    sq_corot *corot;       /* corotational elasticity (level/corot.c): rest gradients + rotations, NULL: linear */
    sq_anp *anp;           /* average nodal pressure tets (level/anp.c), NULL: element-wise */
    sq_implicit *implicit; /* backward Euler scratch (level/implicit.c), allocated by the first step */
} sq_level_state;

/* one level: its constant model, its state, and the step settings chosen for it */
typedef struct sq_level {
    sq_level_model model;  /* constant part (owned; read-only outside init/set_material and the
                              element models' enable) */
    int model_shared;      /* 1: model is another level's (sq_level_init_shared), not freed here */
    sq_level_state state;  /* changing part: d, v, scratch, element models' state */

    double omega_max;      /* Gershgorin bound on the largest angular frequency, rad/s */
    double bound;          /* stability bound on the step with damping, s */
    int substeps_log2;     /* n: this level steps dt = frame_dt / 2^n */
    double dt;             /* frame_dt / 2^n, s */
    /* fixed mode (sq_level_choose_step_sharp): largest omega estimated by Lanczos (Gershgorin
     * as the ceiling), its bound, and its substeps per frame (a power of two) */
    double omega_est;      /* rad/s */
    double bound_sharp;    /* s */
    int nsub;              /* substeps per frame */
    double dt_fixed;       /* frame_dt / nsub, s */
} sq_level;

/* one row of the operator table, on a level's const model M and its state S: the explicit step
 * (forces of all nodes, then symplectic Euler on the nodes with mask[i] != 0; dt = 0 computes
 * the forces into S->f only), the force pass into f (acc: the linear pass's all-zero scratch of
 * 3 n + 1, left zero; active may be NULL; S only read) and the elastic energy */
typedef struct sq_level_ops {
    const char *name;
    void (*step)(const sq_level_model *M, sq_level_state *S, const sq_material *mat, const double g[3], double dt,
                 const unsigned char *mask);
    void (*forces)(const sq_level_model *M, const sq_level_state *S, const sq_material *mat, const double g[3],
                   const unsigned char *active, double *f, double *acc);
    double (*energy)(const sq_level_model *M, const sq_level_state *S);
} sq_level_ops;
/* the model's row from the element models its state holds (corotational, else nodal or
 * smoothed, else linear): the one writer of op_kind, called by the enables and frees of
 * level/corot.c and level/anp.c and by sq_level_init_shared */
void sq_level_op_update(sq_level *L);
/* the table's row of kind k (NULL out of range), and the row a model steps with */
const sq_level_ops *sq_level_ops_of(sq_level_op_kind k);
static inline const sq_level_ops *sq_level_ops_get(const sq_level_model *M) { return sq_level_ops_of(M->op_kind); }

/* health warnings (body/body.h counts them per kind; docs/physics.md "Health"): a kind and up
 * to four values, the first of which is the one counted as "last value" */
typedef enum sq_health_kind {
    SQ_HEALTH_NONE = 0,
    SQ_HEALTH_BLOWUP_NAN,       /* non-finite displacement or velocity; value: the node */
    SQ_HEALTH_BLOWUP_STRETCH,   /* displacement beyond 10 bbox diagonals; value: |d|, m */
    SQ_HEALTH_BLOWUP_SPEED,     /* kinetic energy above 0.5 M (10 diag / frame_dt)^2; value: J */
    SQ_HEALTH_SLEEP,            /* calm long enough: the body sleeps; value: calm frames */
    SQ_HEALTH_WAKE,             /* a tool touched a sleeping body (no sentence); value: holds */
    SQ_HEALTH_BUDGET_COARSE,    /* adaptive: level 0 alone over budget; values: ms, nodes, steps, budget ms */
    SQ_HEALTH_BUDGET_OVER,      /* adaptive: last frame over budget; values: ms, budget %, budget ms */
    SQ_HEALTH_BUDGET_PREDICTED, /* adaptive: next frame predicted over; values: budget %, budget ms, updates */
    SQ_HEALTH_NODE_CAP,         /* adaptive: node-update cap reached; value: the cap */
    SQ_HEALTH_SOLVE_UNCONVERGED, /* implicit: CG stopped above its tolerance; values: residual,
                                    iterations, tolerance, cap */
    SQ_HEALTH_STEP_REFINED,     /* explicit: a diverged frame re-run with more substeps; values:
                                   substeps that held, substeps that diverged */
    SQ_HEALTH_NKINDS
} sq_health_kind;

/* per-kind counter: how often, and the value and frame (1-based frame of the body) of the last */
typedef struct sq_health_stat {
    long count;
    double last_value;
    long last_frame;
} sq_health_stat;

/* short name of a kind ("blowup_nan", "sleep", ...: the keys of the stats reply) */
const char *sq_health_kind_name(sq_health_kind k);
/* the human sentence of a warning (empty for none and wake); body: the body's name */
void sq_health_sentence(char *buf, size_t cap, sq_health_kind k, const double v[4], const char *body);

/* a tool's hold on one node of the finest loaded level (the rendered surface's mesh):
 * the node's displacement is prescribed to `target` for this frame (paper section 5) */
typedef struct sq_hold {
    int tool;              /* index into the frame's tool array */
    int node;              /* node of the finest loaded level */
    double target[3];      /* prescribed displacement, m */
} sq_hold;

/* allocate and precompute the operator for mesh with material/op; marks fixed axes from the
 * constraints; returns -1 + err on failure (e.g. every node fixed is fine, a degenerate tet is not) */
int sq_level_init(sq_level *L, const sq_mesh *mesh, const sq_material *mat, sq_operator_kind op,
                  const sq_constraint *cons, int ncons, sq_err *err);
void sq_level_free(sq_level *L);
/* a level over the same constant model as src (its mesh, operator blocks, masses, constrained
 * axes: borrowed, not copied; src must outlive L and its model must not change meanwhile), with
 * its own state at rest and src's Gershgorin bound; the element models (corot, anp) are not
 * copied (enable them on L as for a new level). sq_level_free then frees only L's own arrays */
void sq_level_init_shared(sq_level *L, const sq_level *src);

/* recompute K (and D), masses and the bound after a material/operator change */
int sq_level_set_material(sq_level *L, const sq_material *mat, sq_operator_kind op, sq_err *err);

/* stability bound (s) for the level's operator with damping, and the substep exponent for a
 * frame period at fraction `step_fraction` of it; -1 + err if more than 2^20 substeps needed */
int sq_level_choose_step(sq_level *L, const sq_material *mat, double frame_dt, double step_fraction,
                         sq_err *err);

/* the sharp bound of fixed mode: lambda_max(M^-1 K) over the unconstrained axes, K the operator
 * the step applies (the element-wise blocks, or with L->state.anp the nodal-pressure or smoothed
 * operator, which must be enabled first), estimated by `iters` Lanczos steps (Ritz value plus its residual, capped by Gershgorin), the damped bound
 * from it, and the smallest power of two n with frame_dt / n <= step_fraction * bound (the rule
 * of the Gershgorin step and of lod's levels; sets omega_est, bound_sharp, nsub, dt_fixed); -1 + err above 2^20 substeps per frame */
int sq_level_choose_step_sharp(sq_level *L, const sq_material *mat, double frame_dt, double step_fraction,
                               int iters, sq_err *err);
/* the Lanczos estimate alone: an upper estimate of lambda_max(M^-1 K), 1/s^2, K the element-wise
 * blocks (whatever the pressure mode) */
double sq_level_lanczos_max(const sq_level *L, int iters);
/* the same for the operator the step applies: the matrix-free nodal-pressure or smoothed operator
 * (level/anp.c) when L->state.anp is set, else the same as sq_level_lanczos_max (the same arithmetic) */
double sq_level_lanczos_max_own(const sq_level *L, int iters);
/* largest eigenvalue of the symmetric tridiagonal (alpha diagonal, beta off-diagonal) of
 * size m, by bisection on the Sturm count (to 1e-15 relative): a Lanczos run's Ritz value */
double sq_level_tridiag_max(const double *alpha, const double *beta, int m);
/* eigenvalues of that tridiagonal above x: the Sturm count of the LDL^T pivots of T - x I (a
 * zero pivot read as 1e-300), the count sq_level_tridiag_max bisects on */
int sq_level_tridiag_above(const double *alpha, const double *beta, int m, double x);

/* the Lanczos recurrence both sharp bounds run (the fixed level's here, lod's per-level one in
 * lod/bound.c): on a symmetric operator y = A x over n values, from the unit vector Q[0..n),
 * at most `iters` steps, each w = A q_j - alpha_j q_j - beta_{j-1} q_{j-1}, alpha_j = w . q_j
 * before, beta_j = |w|; it ends at a step whose beta_j <= 1e-12 |alpha_j| (an invariant
 * subspace) or after step iters. keep: 1, Q holds the whole basis (n x (iters + 1) doubles,
 * q_j at Q + n j; w is its last column); 0, Q holds two vectors (2 n doubles) and w its own n.
 * go (may be NULL): asked before each product (j the step), 0 abandons the run; stop (may be
 * NULL): asked after each step but the last, nonzero ends the run there. Writes alpha, beta
 * (iters each) and returns the steps made; *abandoned (may be NULL) is 1 when go ended it */
typedef struct sq_lanczos_op {
    void (*apply)(void *ctx, const double *x, double *y);
    int (*go)(void *ctx, int j);
    int (*stop)(void *ctx, const double *alpha, const double *beta, int m);
    void *ctx;
} sq_lanczos_op;
int sq_level_lanczos_steps(const sq_lanczos_op *op, size_t n, double *Q, int keep, double *w, int iters,
                           double *alpha, double *beta, int *abandoned);

/* one row of a block operator A (K or D, CSR over the model's adjacency), for the kernels of
 * level.c and lod (inline: the hot loops of both): out_i -= sum_j A_ij (d_j + b v_j) */
static inline void sq_level_row_damped(const sq_level_model *M, const double *A, const double *d, const double *v,
                                       double b, int i, double out[3])
{
    double f0 = 0, f1 = 0, f2 = 0;
    for (int e = M->row_start[i]; e < M->row_start[i + 1]; e++) {
        const double *B = A + 9 * (size_t)e;
        const size_t j = 3 * (size_t)M->col[e];
        const double w0 = d[j] + b * v[j], w1 = d[j + 1] + b * v[j + 1], w2 = d[j + 2] + b * v[j + 2];
        f0 += B[0] * w0 + B[1] * w1 + B[2] * w2;
        f1 += B[3] * w0 + B[4] * w1 + B[5] * w2;
        f2 += B[6] * w0 + B[7] * w1 + B[8] * w2;
    }
    out[0] -= f0;
    out[1] -= f1;
    out[2] -= f2;
}

/* out_i -= sum_j A_ij w_j for one row */
static inline void sq_level_row(const sq_level_model *M, const double *A, const double *w, int i, double out[3])
{
    double f0 = 0, f1 = 0, f2 = 0;
    for (int e = M->row_start[i]; e < M->row_start[i + 1]; e++) {
        const double *B = A + 9 * (size_t)e;
        const double *wj = w + 3 * (size_t)M->col[e];
        f0 += B[0] * wj[0] + B[1] * wj[1] + B[2] * wj[2];
        f1 += B[3] * wj[0] + B[4] * wj[1] + B[5] * wj[2];
        f2 += B[6] * wj[0] + B[7] * wj[1] + B[8] * wj[2];
    }
    out[0] -= f0;
    out[1] -= f1;
    out[2] -= f2;
}

/* the force on node i from gravity, mass damping and the stiffness row (Rayleigh b K with
 * b != 0): f_i = m_i (g - a v_i) - sum_j K_ij (d_j + b v_j); viscosity blocks are not included */
static inline void sq_level_node_force(const sq_level_model *M, const double *d, const double *v, double a, double b,
                                       double g0, double g1, double g2, int i, double fi[3])
{
    double m = M->mass[i];
    fi[0] = m * (g0 - a * v[3 * i]);
    fi[1] = m * (g1 - a * v[3 * i + 1]);
    fi[2] = m * (g2 - a * v[3 * i + 2]);
    if (b != 0)
        sq_level_row_damped(M, M->K, d, v, b, i, fi);
    else
        sq_level_row(M, M->K, d, i, fi);
}

/* block (i, j) of one tet's operator (PHYSICS.md section 2) from the rest gradients ai, aj of
 * its corners and its volume V, with shear-like coefficient s and volume-like l (mu, lambda for
 * K; phi, psi for the viscosity blocks D), added to B (row-major 3x3) */
static inline void sq_level_tet_block(sq_operator_kind op, double V, const double *ai, const double *aj, double s,
                                      double l, double *B)
{
    double dot = ai[0] * aj[0] + ai[1] * aj[1] + ai[2] * aj[2];
    for (int r = 0; r < 3; r++)
        for (int c = 0; c < 3; c++) {
            double v = (r == c ? s * dot : 0);
            if (op == SQ_OPERATOR_PAPER)
                v += (l + s) * ai[r] * aj[c];
            else
                v += s * aj[r] * ai[c] + l * ai[r] * aj[c];
            B[3 * r + c] += V * v;
        }
}

/* forces f_i (elastic + damping + gravity) on the nodes with active[i] != 0 (all if active is
 * NULL), reading d and v of all neighbours (ghost values included) */
void sq_level_forces(const sq_level_model *M, sq_level_state *S, const sq_material *mat, const double gravity[3],
                     const unsigned char *active);

/* the same forces of the state S written to f (n x 3) instead of S->f, with acc an all-zero
 * scratch of 3 n + 1 doubles (left all zero): M and S are only read */
void sq_level_forces_to(const sq_level_model *M, const sq_level_state *S, const sq_material *mat,
                        const double gravity[3],
                        const unsigned char *active, double *f, double *acc);
/* the same with a corotational level's rotations frozen as they stand: f is then affine in d,
 * so f(d + x) - f(d) = -K x with the operator the step uses (its stiffness at this state) */
void sq_level_forces_frozen(const sq_level_model *M, const sq_level_state *S, const sq_material *mat,
                            const double gravity[3], double *f_out, double *acc);

/* residual force measure of forces f (n x 3) over the listed nodes (the list active of nactive
 * nodes; all when NULL) that are not fully constrained and not held (held may be NULL: a held
 * node's unbalanced force is the tool's reaction): max |f_i| on free axes / (m_i |g|), or / m_i
 * if g = 0 */
double sq_level_residual(const sq_level_model *M, const double *f, const double g[3], const int *active,
                         int nactive, const unsigned char *held);

/* symplectic Euler for node i: v += h f (h = dt / m_i), constrained axes (bits of fx) zeroed,
 * d += dt v. The one update of every integrator (level step, lod lists); inline: hot path */
static inline __attribute__((always_inline)) void sq_level_euler_node(double *restrict v, double *restrict d,
                                                                     int i, double h, double dt, double f0,
                                                                     double f1, double f2, unsigned fx)
{
    double v0 = v[3 * i] + h * f0, v1 = v[3 * i + 1] + h * f1, v2 = v[3 * i + 2] + h * f2;
    if (fx) {
        if (fx & 1u)
            v0 = 0;
        if (fx & 2u)
            v1 = 0;
        if (fx & 4u)
            v2 = 0;
    }
    v[3 * i] = v0;
    v[3 * i + 1] = v1;
    v[3 * i + 2] = v2;
    d[3 * i] += dt * v0;
    d[3 * i + 1] += dt * v1;
    d[3 * i + 2] += dt * v2;
}

/* a tool's hold on node i for one frame (fixed and adaptive modes alike): on every free axis
 * the displacement is set to goal and the velocity to (goal - from) / span (0 if span <= 0);
 * a constrained axis is left as it is, at zero: a constraint wins over a tool
 * (docs/physics.md) */
void sq_level_apply_hold(const sq_level_model *M, sq_level_state *S, int i, const double goal[3],
                         const double from[3], double span);

/* symplectic Euler on active nodes: v += dt f/m; constrained axes zeroed; d += dt v */
void sq_level_integrate(const sq_level_model *M, sq_level_state *S, double dt, const unsigned char *active);

/* one step of all nodes in a single pass: sq_level_forces(M, S, mat, gravity, NULL) followed by
 * sq_level_integrate(M, S, dt, mask) (same values), fused so the operator is streamed once; nodes
 * with mask[i] == 0 (mask may be NULL) get their force in S->f but are not integrated */
void sq_level_step(const sq_level_model *M, sq_level_state *S, const sq_material *mat, const double gravity[3],
                   double dt,
                   const unsigned char *mask);

/* y = -K x (n x 3) by the step's fused upper-half pass: x must have one readable double past
 * its 3 n (the pass loads four lanes per node), acc an all-zero scratch of 3 n + 1 (left zero) */
void sq_level_neg_k(const sq_level_model *M, const double *x, double *y, double *acc);

/* Laplacian of the displacement at node i, -(1/vol_i) sum_j lap_ij d_j (m^-1); lap_ij is the
 * (positive semi-definite) stiffness of -Lap, hence the minus sign */
void sq_level_laplacian(const sq_level_model *M, const sq_level_state *S, int i, double out[3]);

/* y = A x for a symmetric positive definite operator A on the level's nodes (3n values) */
typedef void (*sq_level_op)(const sq_level_model *M, const void *ctx, const double *x, double *y);

/* A x = b by conjugate gradients preconditioned by the diagonal pre (its inverse, 0 on fixed
 * axes), from x = 0 to |r| <= tol |b|; 0, or -1 + err when it breaks down or does not converge
 * in max_iter (iterations, if not NULL, receives the count) */
int sq_level_pcg(const sq_level_model *M, sq_level_op op, const void *ctx, const double *b, const double *pre,
                 double tol, int max_iter, double *x, int *iterations, sq_err *err);

/* static equilibrium K d = M g with the level's constraints (constrained axes zero), by
 * Jacobi-preconditioned conjugate gradients to relative residual tol; d (n x 3) receives
 * the solution; -1 + err if CG breaks down or does not converge in max_iter */
int sq_level_static_solve(const sq_level_model *M, const double gravity[3], double tol, int max_iter,
                          double *d, int *iterations, sq_err *err);

/* the same static solve with average nodal pressure tets (volumetric strain averaged at the
 * nodes; docs/physics.md section 10); mat gives mu and lambda */
int sq_level_static_solve_nodal_pressure(const sq_level_model *M, const sq_material *mat, const double gravity[3],
                                         double tol, int max_iter, double *d, int *iterations, sq_err *err);

/* the same static solve with a pressure mode of level/anp.c (SQ_PRESSURE_NODAL: as above;
 * SQ_PRESSURE_SMOOTHED: face-smoothed deviatoric strain with nodal pressure; docs/physics.md
 * section 10); mat gives mu and lambda */
int sq_level_static_solve_pressure(const sq_level_model *M, const sq_material *mat, int mode, const double gravity[3],
                                   double tol, int max_iter, double *d, int *iterations, sq_err *err);

/* average nodal pressure tets and smoothed tets (level/anp.c; fem operator, linear elasticity,
 * fixed mode): with L->state.anp set, sq_level_step and sq_level_forces use them, and so does the sharp
 * bound's Lanczos estimate (call sq_level_choose_step_sharp again after enabling or freeing);
 * enable (mode SQ_PRESSURE_NODAL or SQ_PRESSURE_SMOOTHED) refuses the paper operator */
int sq_level_anp_enable(sq_level *L, const sq_material *mat, sq_operator_kind op, int mode, sq_err *err);
void sq_level_anp_free(sq_level *L);
void sq_level_anp_apply(const sq_level_model *M, const sq_level_state *S, const double *x, double *y); /* y = K_np x */
void sq_level_anp_forces(const sq_level_model *M, const sq_level_state *S, const sq_material *mat, const double g[3], double *f); /* into f */
double sq_level_anp_energy(const sq_level_model *M, const sq_level_state *S);
/* the operator alone, on a mesh with n nodes of nodal volumes vol (the static solve's use) */
sq_anp *sq_anp_create(const sq_mesh *m, int n, int mode);
void sq_anp_set_moduli(sq_anp *A, double mu, double lambda);
int sq_anp_mode(const sq_anp *A);
void sq_anp_apply(const sq_anp *A, const sq_mesh *m, const double *vol, const double *x, double *y); /* y = K x */
/* the same y = K x as the step computes it (four tets at once; equal to round-off) */
void sq_anp_apply_fast(const sq_anp *A, const double *vol, const double *x, double *y);
void sq_anp_destroy(sq_anp *A);

/* 0.5 d.K d of the level's current displacement (J) */
double sq_level_elastic_energy(const sq_level_model *M, const sq_level_state *S);

/* corotational elasticity (level/corot.c; fem operator; fixed mode, and adaptive through lod/): per-tet rest gradients and
 * rotations. enable: allocate (rotations identity) or update the moduli; -1 + err for the paper
 * operator. With L->state.corot set, sq_level_step and sq_level_forces compute f = -R K_T (R^T x - X)
 * per tet (damping rotated the same way); sq_level_forces leaves the stored rotations as they are */
int sq_level_corot_enable(sq_level *L, const sq_material *mat, sq_operator_kind op, sq_err *err);
void sq_level_corot_free(sq_level *L);
void sq_level_corot_reset(sq_level_state *S);                          /* rotations to identity */
void sq_level_corot_copy(sq_level_state *dst, const sq_level_state *src); /* same mesh: copy the rotations */
/* the stored rotations as a flat array: its length (0 without corot), save into q, load from q */
size_t sq_level_corot_state_len(const sq_level_state *S);
void sq_level_corot_save(const sq_level_state *S, double *q);
void sq_level_corot_load(sq_level_state *S, const double *q);
void sq_level_corot_converge(const sq_level_model *M, sq_level_state *S);                     /* rotations converged to the current d */
void sq_level_corot_step(const sq_level_model *M, sq_level_state *S, const sq_material *mat, const double g[3],
                         double dt,
                         const unsigned char *mask);
void sq_level_corot_forces(const sq_level_model *M, const sq_level_state *S, const sq_material *mat, const double g[3], double *f); /* into f */
/* the same with the stored rotations as they stand (not iterated): affine in d */
void sq_level_corot_forces_frozen(const sq_level_model *M, const sq_level_state *S, const sq_material *mat,
                                  const double g[3], double *f);
double sq_level_corot_energy(const sq_level_model *M, const sq_level_state *S);               /* corotational elastic energy, J */
/* the adaptive frame's pieces (lod/corotational.c): the element force of tet t (elastic and
 * stiffness or viscous damping; no mass damping, no gravity) from corner values d4, v4 (4 x 3,
 * the tet's corners in mesh order) into f4 (4 x 3), the stored rotation improved iters times
 * (stopping once converged) and stored back if store (the scalar pass's arithmetic); the
 * energy of tet t at corner displacements d4 (rotation converged, not stored); and the step's
 * force pass alone (into S->f, one rotation update per tet, stored: the values
 * sq_level_corot_step integrates) */
void sq_level_corot_tet_force(const sq_level_model *M, const sq_level_state *S, const sq_material *mat, int t,
                              const double *d4, const double *v4,
                              int iters, int store, double *f4);
double sq_level_corot_tet_energy(const sq_level_model *M, const sq_level_state *S, int t, const double *d4);
void sq_level_corot_step_forces(const sq_level_model *M, sq_level_state *S, const sq_material *mat, const double g[3]);
/* four tets t[0..3] at once (t[l] < 0: an empty lane, zero force), one rotation update each:
 * corner values d, v and forces f laid out tet after tet (12 per tet); the vector pass's
 * arithmetic in AVX2 builds (without viscosity), else the per-tet one */
void sq_level_corot_tet_force4(const sq_level_model *M, const sq_level_state *S, const sq_material *mat,
                               const int t[4], const double *d,
                               const double *v, int store, double *f);
/* tets with det F <= 0 at the current displacement (any level, linear or not) */
int sq_level_corot_inverted(const sq_level_model *M, const sq_level_state *S);


/* ---- backward Euler (level/implicit.c; docs/physics.md section 12) ---- */

/* the integrator of a body: explicit (symplectic Euler at the stability bound) or implicit */
typedef enum sq_integrator_kind { SQ_INTEGRATOR_EXPLICIT = 0, SQ_INTEGRATOR_IMPLICIT = 1 } sq_integrator_kind;
/* CG preconditioners of the implicit solve */
enum { SQ_PRECOND_JACOBI = 0, SQ_PRECOND_BLOCK = 1, SQ_PRECOND_MULTIGRID = 2 };
#define SQ_IMPLICIT_MAX_SUBSTEPS 64
#define SQ_IMPLICIT_MAX_ITER 10000
#define SQ_IMPLICIT_MAX_NEWTON 10

/* the implicit step's settings (scene keys "implicit": {...}, protocol set) */
typedef struct sq_implicit_def {
    int substeps;   /* steps per frame, 1..SQ_IMPLICIT_MAX_SUBSTEPS (default 1: h = frame_dt) */
    double tol;     /* CG stop: relative residual |r| / |b|, in (0, 1) (default 1e-6) */
    int max_iter;   /* CG iteration cap per solve, 1..SQ_IMPLICIT_MAX_ITER (default 500) */
    int precond;    /* SQ_PRECOND_* (default block Jacobi) */
    int newton;     /* corotational: Newton iterations per step, 1..SQ_IMPLICIT_MAX_NEWTON (default 1) */
} sq_implicit_def;

/* what one step's solve did */
typedef struct sq_implicit_stats {
    int iterations;         /* CG iterations, all Newton iterations together */
    double residual;        /* largest final relative CG residual of the step's solves */
    int unconverged;        /* 1: a solve stopped at the cap, the deadline or a breakdown */
    int newton;             /* Newton iterations done */
    double newton_residual; /* corotational, newton > 1: |P (h f(d1, v1) - M dv)| / |rhs| after the last */
} sq_implicit_stats;

sq_implicit_def sq_implicit_def_default(void);
/* range checks; -1 + err naming the key and its valid range */
int sq_implicit_def_check(const sq_implicit_def *d, sq_err *err);

/* one backward Euler step of size h on every node with mask[i] != 0 (mask may be NULL): nodes
 * with mask[i] == 0 (held by a tool) move at their velocity v_i (prescribed: d_i += h v_i on the
 * unconstrained axes) and are projected out of the solve, as are constrained axes. CG stops at def->tol, at
 * def->max_iter, or once the thread's CPU clock (sq_thread_cpu) passes deadline (0: none) */
void sq_level_implicit_step(const sq_level_model *M, sq_level_state *S, const sq_material *mat, const double g[3],
                            double h, const unsigned char *mask, const sq_implicit_def *def, double deadline,
                            sq_implicit_stats *st);
void sq_level_implicit_free(sq_level *L);

/* contacts as constraints of the implicit solve (docs/physics.md section 13): at node node[k]
 * the new velocity is prescribed, relative to the obstacle's velocity u[k]: along the unit
 * normal normal[k] only (v1 . n = u . n; a sliding contact), or whole (v1 = u; stick[k] = 1, a
 * sticking contact); the solve runs over the other directions (the projection's filter: I - n
 * n^T, or 0, at those nodes), with force[k] added to the node's force. After the step,
 * impulse[k] (3 per contact) is M (v1 - v0) - h f(end state), N s: the constraint's impulse
 * and h force[k]. Nodes that are held or have a constrained axis are
 * not constrained (impulse 0) */
typedef struct sq_implicit_contacts {
    int n;
    const int *node;
    const double *normal;        /* n x 3 */
    const double *u;             /* n x 3 */
    const unsigned char *stick;  /* n */
    const double *force;         /* n x 3: a force on the node in the step (kinetic friction), N */
    double *impulse;             /* n x 3, written by the step */
} sq_implicit_contacts;
/* the contacts of L's next implicit steps (borrowed until set again; NULL: none) */
void sq_level_implicit_set_contacts(const sq_level_model *M, sq_level_state *S, const sq_implicit_contacts *cc);
/* the multigrid preconditioner's hierarchy: coarse[0] the next coarser level (another mesh of
 * the same shape), coarse[1] the one below, ...; each fine node is located in the coarser rest
 * mesh (sq_mesh_locate) and its barycentrics are the prolongation (their transpose restricts).
 * The levels are borrowed (they must outlive L's solves). Returns the levels used; with none,
 * SQ_PRECOND_MULTIGRID is block Jacobi */
int sq_level_implicit_set_coarse(const sq_level_model *M, sq_level_state *S, const sq_level_model *const *coarse,
                                 int ncoarse);

#endif
