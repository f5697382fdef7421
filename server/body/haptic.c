/* haptic.c - a tool's feedback linearised about the state the last frame left.
 *
 * A haptic device asks for a force at about 1 kHz while a body steps at its frame rate. Between
 * two frames the force at a tool position p is taken from f(p) = f0 + K (p - p0), where p0 is
 * the tool position of the last frame, f0 the reaction of the nodes it held there, and K the
 * stiffness of that reaction with respect to the tool position.
 *
 * K is measured on the body's own force pass (sq_level_forces_to: the operator the step uses,
 * with a corotational level's rotations as they stand, frozen): each held node j is moved by
 * eps P_j e_c, where P_j is how its target follows the tool (a grab: the identity; a sphere:
 * n n^T along the node's contact normal; a box: the normal of the face it lies on), and the
 * change of the summed reaction over eps is column c of K. The free nodes do not move in this
 * difference: K is the instantaneous stiffness of the held nodes (the upper end of what the body
 * shows before its free nodes respond); velocities are unchanged, so damping cancels. Kc is the
 * same with the free nodes relaxed (condensed, below): what a slow move meets. The channel
 * (net/haptic.c) joins the two in a relaxing model.
 */
#include <math.h>
#include <stdlib.h>
#include <string.h>

#include "body/body_internal.h"

/* how hold h's target moves with the tool: P (3x3) and, for a push, the unit normal n */
void sq_body_hold_projection(const sq_mesh *m, const sq_hold *h, const sq_tool *tool, double P[9], double n[3])
{
    memset(P, 0, 9 * sizeof *P);
    memset(n, 0, 3 * sizeof *n);
    if (tool->shape == SQ_TOOL_GRAB) {
        P[0] = P[4] = P[8] = 1;
        return;
    }
    const double *x0 = m->x + 3 * (size_t)h->node;
    double q[3];
    for (int c = 0; c < 3; c++)
        q[c] = x0[c] + h->target[c] - tool->pos[c]; /* from the tool centre to the node */
    if (tool->shape == SQ_TOOL_SPHERE) {
        double r = sqrt(q[0] * q[0] + q[1] * q[1] + q[2] * q[2]);
        if (!(r > 0))
            return;
        for (int c = 0; c < 3; c++)
            n[c] = q[c] / r;
    } else {
        int axis = 0;
        double best = INFINITY;
        for (int c = 0; c < 3; c++) {
            double gap = fabs(tool->half[c] - fabs(q[c]));
            if (gap < best) {
                best = gap;
                axis = c;
            }
        }
        n[axis] = q[axis] >= 0 ? 1 : -1;
    }
    for (int r = 0; r < 3; r++)
        for (int c = 0; c < 3; c++)
            P[3 * r + c] = n[r] * n[c];
}

/* ---------------------------------------------------------------- the condensed stiffness */

/* What a slow press meets is the held nodes' stiffness with the free nodes relaxed, the Schur
 * complement K_hh - K_hf K_ff^-1 K_fh: moved by u, the held nodes bring the free ones along by
 * x, K_ff x = -K_fh u. K is the operator the step uses at this state (sq_level_forces_frozen: a
 * corotational level's rotations frozen as they stand, so K x = -(f(x) - f(0)) exactly, on a
 * copy of the level whose d is x and v is 0: the state is only read). Each of the three
 * columns (u = P_j e_c on the held nodes) is relaxed by block Jacobi preconditioned conjugate
 * gradients started from the last frame's x, to a relative residual of CONDENSE_TOL or for
 * CONDENSE_MAX iterations: a tool's model relaxes over its first frames (stiffer than the
 * condensed value meanwhile, as an unrelaxed x is), then costs a few force passes a frame.
 * The column is the held nodes' force change, -(K (u + x)) summed over them. In adaptive lod
 * only the free nodes the lod simulates at the finest level relax; the others stay still (a
 * region simulated coarser is stiffer than the finest level relaxed there would be). */
#define CONDENSE_TOL 1e-3 /* relative residual: the column to about 0.1 % */
#define CONDENSE_MAX 6    /* iterations a column a frame at most (the next frame goes on) */

typedef struct {
    const sq_level_model *M;
    sq_level_state lin;        /* the level's state with d -> the argument, v -> 0 */
    const sq_material *mat;
    double *F0;                /* f(0) of lin */
    double *acc;               /* zero scratch, 3n + 1 */
    unsigned char *rel;        /* 1: relaxed (neither held nor fixed) */
    double *Dinv;              /* 9 per node: the inverse of K's diagonal block (relaxed nodes) */
    double *r, *z, *p, *q, *kx, *ku, *zero; /* 3n (+1) each */
} condense_ws;


/* y = K x, all rows */
static void k_apply(condense_ws *w, const double *x, double *y)
{
    static const double g0[3] = {0, 0, 0};
    w->lin.d = (double *)x; /* only read */
    sq_level_forces_frozen(w->M, &w->lin, w->mat, g0, y, w->acc);
    for (int i = 0; i < 3 * w->M->n; i++)
        y[i] = -(y[i] - w->F0[i]);
}

static double *vec(int n)
{
    return sq_calloc(3 * (size_t)n + 1, sizeof(double));
}

static void ws_init(condense_ws *w, const sq_level *L, const sq_material *mat, const unsigned char *hold,
                    const unsigned char *node_level, int fine)
{
    const sq_level_model *M = &L->model;
    const int n = M->n;
    w->M = M;
    w->lin = L->state;
    w->mat = mat;
    w->acc = vec(n);
    w->zero = vec(n);
    w->lin.v = w->zero;
    w->F0 = vec(n);
    for (double **v[] = {&w->r, &w->z, &w->p, &w->q, &w->kx, &w->ku}, ***e = v; e < v + 6; e++)
        **e = vec(n);
    static const double g0[3] = {0, 0, 0};
    w->lin.d = w->zero;
    sq_level_forces_frozen(w->M, &w->lin, mat, g0, w->F0, w->acc);
    w->rel = sq_malloc((size_t)n);
    w->Dinv = sq_calloc(9 * (size_t)n, sizeof(double));
    for (int i = 0; i < n; i++) {
        w->rel[i] = !hold[i] && !M->fixed[i] && (!node_level || node_level[i] == fine);
        if (!w->rel[i])
            continue;
        const double *B = NULL; /* the linear block as the preconditioner's: near enough */
        for (int e = M->row_start[i]; e < M->row_start[i + 1]; e++)
            if (M->col[e] == i)
                B = M->K + 9 * (size_t)e;
        double *Di = w->Dinv + 9 * (size_t)i;
        if (!B || sq_inv3(B, Di))
            Di[0] = Di[4] = Di[8] = B && B[0] + B[4] + B[8] > 0 ? 3 / (B[0] + B[4] + B[8]) : 0;
    }
}

static void ws_free(condense_ws *w)
{
    double *v[] = {w->F0, w->acc, w->r, w->z, w->p, w->q, w->kx, w->ku, w->zero, w->Dinv};
    for (size_t k = 0; k < SQ_COUNTOF(v); k++)
        free(v[k]);
    free(w->rel);
}

static double dot_rel(const condense_ws *w, const double *a, const double *b)
{
    double s = 0;
    for (int i = 0; i < w->M->n; i++)
        if (w->rel[i])
            s += a[3 * i] * b[3 * i] + a[3 * i + 1] * b[3 * i + 1] + a[3 * i + 2] * b[3 * i + 2];
    return s;
}

static void precondition(const condense_ws *w, const double *r, double *z)
{
    for (int i = 0; i < w->M->n; i++) {
        const double *D = w->Dinv + 9 * (size_t)i, *ri = r + 3 * (size_t)i;
        for (int c = 0; c < 3; c++)
            z[3 * i + c] = w->rel[i] ? D[3 * c] * ri[0] + D[3 * c + 1] * ri[1] + D[3 * c + 2] * ri[2] : 0;
    }
}

/* x (3n, warm) relaxed for the held nodes' move u (3n, 0 off the held nodes); on return w->ku
 * and w->kx hold K u and K x (all rows); returns the iterations */
static int relax(condense_ws *w, const double *u, double *x)
{
    const int n = w->M->n;
    double *r = w->r, *z = w->z, *p = w->p, *q = w->q;
    for (int i = 0; i < n; i++)
        if (!w->rel[i])
            x[3 * i] = x[3 * i + 1] = x[3 * i + 2] = 0;
    k_apply(w, u, w->ku);
    k_apply(w, x, w->kx);
    for (int i = 0; i < 3 * n; i++)
        r[i] = w->rel[i / 3] ? -w->ku[i] - w->kx[i] : 0; /* r = -K_fh u - K_ff x */
    double bb = dot_rel(w, w->ku, w->ku);
    if (!(bb > 0))
        return 0;
    precondition(w, r, z);
    memcpy(p, z, sizeof(double) * 3 * (size_t)n);
    double rz = dot_rel(w, r, z);
    int it = 0;
    while (dot_rel(w, r, r) > CONDENSE_TOL * CONDENSE_TOL * bb && it < CONDENSE_MAX) {
        k_apply(w, p, q);
        const double pq = dot_rel(w, p, q);
        if (!(pq > 0))
            break; /* not positive along p (a free rigid motion): the iterate reached */
        const double alpha = rz / pq;
        for (int i = 0; i < 3 * n; i++) {
            x[i] += alpha * p[i];
            w->kx[i] += alpha * q[i];
            r[i] = w->rel[i / 3] ? r[i] - alpha * q[i] : 0;
        }
        precondition(w, r, z);
        const double rz1 = dot_rel(w, r, z);
        for (int i = 0; i < 3 * n; i++)
            p[i] = z[i] + rz1 / rz * p[i];
        rz = rz1;
        it++;
    }
    return it;
}

/* K's columns: column c moves the held nodes (node[0..nh), each listed once or more) by P_j e_c.
 * A push (dir its unit mean normal, else NULL) is kept along its normal only (the channel's
 * frictionless model): one column, the held nodes moved by P_j dir, gives K = (dir . col) dir
 * dir^T at a third of the cost */
static int condensed_k(sq_body *b, const sq_level *L, const sq_material *mat, const unsigned char *hold,
                       const int *node, const double *P, int nh, const double *dir, double K[9])
{
    const size_t n3 = 3 * (size_t)L->model.n;
    if (b->cond_n3 != n3) { /* the relaxations of the three columns, kept from frame to frame */
        free(b->cond_x);
        b->cond_x = sq_calloc(3 * n3, sizeof(double));
        b->cond_n3 = n3;
    }
    condense_ws w;
    ws_init(&w, L, mat, hold, b->def.lod.mode == SQ_LOD_ADAPTIVE ? b->node_level : NULL, b->fine);
    double *u = vec(L->model.n);
    unsigned char *seen = sq_calloc((size_t)L->model.n, 1);
    int its = 0;
    for (int c = 0; c < (dir ? 1 : 3); c++) {
        for (int i = 0; i < nh; i++) /* a node held twice moves once: P of its last hold */
            for (int r = 0; r < 3; r++) {
                const double *Pr = P + 9 * i + 3 * r;
                u[3 * (size_t)node[i] + r] = dir ? Pr[0] * dir[0] + Pr[1] * dir[1] + Pr[2] * dir[2] : Pr[c];
            }
        its += relax(&w, u, b->cond_x + (size_t)c * n3);
        double col[3] = {0, 0, 0};
        for (int i = 0; i < nh; i++) {
            const int j = node[i];
            if (seen[j] == c + 1)
                continue;
            seen[j] = (unsigned char)(c + 1);
            for (int r = 0; r < 3; r++)
                col[r] -= w.ku[3 * (size_t)j + r] + w.kx[3 * (size_t)j + r];
        }
        if (dir) {
            const double kn = dir[0] * col[0] + dir[1] * col[1] + dir[2] * col[2];
            for (int r = 0; r < 3; r++)
                for (int q = 0; q < 3; q++)
                    K[3 * r + q] = kn * dir[r] * dir[q];
        } else
            for (int r = 0; r < 3; r++)
                K[3 * r + c] = col[r];
        for (int i = 0; i < nh; i++)
            memset(u + 3 * (size_t)node[i], 0, 3 * sizeof(double));
    }
    free(seen);
    free(u);
    ws_free(&w);
    return its;
}

int sq_body_tool_model(sq_body *b, int t, const sq_tool *tool, sq_tool_model *out)
{
    memset(out, 0, sizeof *out);
    memcpy(out->p0, tool->pos, sizeof out->p0);
    out->push = tool->shape != SQ_TOOL_GRAB;
    int k = sq_body_sim_level(b);
    if (k != b->fine || !tool->active)
        return -1;
    sq_lod_flush(b->lod);
    sq_level *L = &b->level[k];
    const sq_mesh *m = b->def.levels[k];
    const size_t n = (size_t)L->model.n;
    int nh = 0;
    for (int h = 0; h < b->nholds; h++)
        nh += b->holds[h].tool == t;
    if (nh == 0)
        return -1;

    unsigned char *mask = sq_calloc(n, 1);
    double *f0 = sq_malloc(sizeof(double) * 3 * n), *f1 = sq_malloc(sizeof(double) * 3 * n);
    double *acc = sq_calloc(3 * n + 1, sizeof(double));
    double *P = sq_malloc(sizeof(double) * 9 * (size_t)nh);
    int *node = sq_malloc(sizeof(int) * (size_t)nh);
    double *d0 = sq_malloc(sizeof(double) * 3 * (size_t)nh);
    double nsum[3] = {0, 0, 0};
    int j = 0;
    for (int h = 0; h < b->nholds; h++) {
        if (b->holds[h].tool != t)
            continue;
        double nrm[3];
        sq_body_hold_projection(m, &b->holds[h], tool, P + 9 * j, nrm);
        for (int c = 0; c < 3; c++)
            nsum[c] += nrm[c];
        memcpy(d0 + 3 * j, L->state.d + 3 * (size_t)b->holds[h].node, 3 * sizeof(double));
        node[j++] = b->holds[h].node;
        mask[b->holds[h].node] = 1;
    }
    const sq_material *mat = &b->def.material;
    const double *g = b->def.gravity;
    sq_level_forces_to(&L->model, &L->state, mat, g, mask, f0, acc);

    /* f0 and the torque about p0: the held nodes' unbalanced force (as the frame's feedback),
     * each node counted once */
    for (int i = 0; i < nh; i++) {
        int q = node[i];
        if (mask[q] != 1)
            continue;
        mask[q] = 2;
        double fi[3], r[3];
        for (int c = 0; c < 3; c++) {
            fi[c] = f0[3 * (size_t)q + c] - L->model.mass[q] * g[c];
            r[c] = m->x[3 * (size_t)q + c] + L->state.d[3 * (size_t)q + c] - tool->pos[c];
            out->f0[c] += fi[c];
        }
        out->torque[0] += r[1] * fi[2] - r[2] * fi[1];
        out->torque[1] += r[2] * fi[0] - r[0] * fi[2];
        out->torque[2] += r[0] * fi[1] - r[1] * fi[0];
    }

    /* K by columns: move every held node by eps P_j e_c, difference the summed reaction */
    const double eps = 1e-6 * (b->diag > 0 ? b->diag : 1.0);
    for (int c = 0; c < 3; c++) {
        for (int i = 0; i < nh; i++)
            for (int r = 0; r < 3; r++)
                L->state.d[3 * (size_t)node[i] + r] += eps * P[9 * i + 3 * r + c];
        sq_level_forces_to(&L->model, &L->state, mat, g, mask, f1, acc);
        for (int i = 0; i < nh; i++) /* restored bit for bit: the state is not changed */
            memcpy(L->state.d + 3 * (size_t)node[i], d0 + 3 * i, 3 * sizeof(double));
        for (int i = 0; i < nh; i++)
            mask[node[i]] = 2;
        for (int i = 0; i < nh; i++) {
            int q = node[i];
            if (mask[q] != 2)
                continue;
            mask[q] = 3;
            for (int r = 0; r < 3; r++)
                out->K[3 * r + c] += (f1[3 * (size_t)q + r] - f0[3 * (size_t)q + r]) / eps;
        }
        for (int i = 0; i < nh; i++)
            mask[node[i]] = 2;
    }
    /* symmetric part: the operator is symmetric, the difference adds rounding only */
    for (int r = 0; r < 3; r++)
        for (int c = r + 1; c < 3; c++) {
            double s = 0.5 * (out->K[3 * r + c] + out->K[3 * c + r]);
            out->K[3 * r + c] = out->K[3 * c + r] = s;
        }
    /* the condensed stiffness: the free nodes relaxed (mask still marks the held nodes); a
     * push along its mean normal only */
    double nn = sqrt(nsum[0] * nsum[0] + nsum[1] * nsum[1] + nsum[2] * nsum[2]);
    const double dir[3] = {nn > 0 ? nsum[0] / nn : 0, nn > 0 ? nsum[1] / nn : 0, nn > 0 ? nsum[2] / nn : 0};
    out->cg_iterations = condensed_k(b, L, mat, mask, node, P, nh, out->push && nn > 0 ? dir : NULL, out->Kc);
    out->tau = b->def.frame_dt;
    for (int r = 0; r < 3; r++)
        for (int c = r + 1; c < 3; c++) {
            double s = 0.5 * (out->Kc[3 * r + c] + out->Kc[3 * c + r]);
            out->Kc[3 * r + c] = out->Kc[3 * c + r] = s;
        }
    if (out->push && nn > 0)
        for (int c = 0; c < 3; c++)
            out->normal[c] = nsum[c] / nn;
    out->nnodes = nh;
    free(mask);
    free(f0);
    free(f1);
    free(acc);
    free(P);
    free(node);
    free(d0);
    return 0;
}

/* ---------------------------------------------------------------- live poses */

void sq_body_set_pose_source(sq_body *b, sq_pose_source_fn fn, void *arg)
{
    b->pose_fn = fn;
    b->pose_arg = arg;
}

void sq_body_live_begin(sq_body *b, const sq_tool *tools, int ntools)
{
    b->live = 0;
    memset(b->live_tool, 0, sizeof b->live_tool);
    if (!b->pose_fn || b->nholds == 0)
        return;
    for (int t = 0; t < ntools && t < SQ_MAX_TOOLS; t++) {
        double p[3];
        if (!tools[t].active || !b->pose_fn(b->pose_arg, tools[t].id, 0.0, p))
            continue;
        b->live_tool[t] = 1;
        b->live_id[t] = tools[t].id;
        memcpy(b->live_from[t], tools[t].pos, sizeof b->live_from[t]);
        memcpy(b->live_pos[t], tools[t].pos, sizeof b->live_pos[t]); /* the holds' own pose */
        b->live = 1;
    }
    if (!b->live)
        return;
    if (b->cap_live < b->nholds) {
        b->cap_live = b->nholds;
        b->live_P = sq_realloc(b->live_P, sizeof(double) * 9 * (size_t)b->nholds);
        b->live_target = sq_realloc(b->live_target, sizeof(double) * 3 * (size_t)b->nholds);
        b->live_on = sq_realloc(b->live_on, (size_t)b->nholds);
        b->live_shift = sq_realloc(b->live_shift, sizeof(double) * 3 * (size_t)b->nholds);
    }
    memset(b->live_shift, 0, sizeof(double) * 3 * (size_t)b->nholds); /* no change yet (frame.c) */
    const sq_mesh *fm = b->def.levels[b->fine];
    for (int h = 0; h < b->nholds; h++) {
        const sq_hold *hd = &b->holds[h];
        int t = hd->tool;
        b->live_on[h] = t >= 0 && t < ntools && t < SQ_MAX_TOOLS && b->live_tool[t];
        memcpy(b->live_target + 3 * (size_t)h, hd->target, 3 * sizeof(double));
        if (b->live_on[h]) {
            double n[3];
            sq_body_hold_projection(fm, hd, &tools[t], b->live_P + 9 * (size_t)h, n);
        }
    }
}

int sq_body_live_refresh(sq_body *b, double frac)
{
    if (!b->live)
        return 0;
    int changed[SQ_MAX_TOOLS] = {0}, any = 0;
    for (int t = 0; t < SQ_MAX_TOOLS; t++) {
        double p[3];
        if (!b->live_tool[t] || !b->pose_fn(b->pose_arg, b->live_id[t], frac, p))
            continue; /* closed within the frame: the last pose read stays */
        if (memcmp(p, b->live_pos[t], sizeof p) == 0)
            continue;
        memcpy(b->live_pos[t], p, sizeof p);
        changed[t] = any = 1;
    }
    if (!any)
        return 0;
    for (int h = 0; h < b->nholds; h++) {
        int t = b->holds[h].tool;
        if (!b->live_on[h] || !changed[t])
            continue;
        const double *P = b->live_P + 9 * (size_t)h;
        double dp[3];
        for (int c = 0; c < 3; c++)
            dp[c] = b->live_pos[t][c] - b->live_from[t][c];
        for (int r = 0; r < 3; r++)
            b->live_target[3 * (size_t)h + r] =
                b->holds[h].target[r] + P[3 * r] * dp[0] + P[3 * r + 1] * dp[1] + P[3 * r + 2] * dp[2];
    }
    return 1;
}
