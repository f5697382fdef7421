/* tick.c - stage: one tick of the finest substep clock (docs/lod.md, "The frame"): the ring
 * ghosts' values from their sources, the forces of the due levels (the inner rows in column
 * form, the frontier rows, d + b v formed once per step), the ring reactions handed back to
 * their sources, and the integration of the free active nodes. frame.c runs the ticks; the
 * corotational variant of the forces and reactions is corotational.c's, the full-level passes
 * level's. The kernels repeat the arithmetic of level/level.c's masked passes (same operations
 * in the same order), so trajectories are those of the scalar code.
 */
#include <math.h>
#include <stdlib.h>
#include <string.h>

#include "contact/contact.h"
#include "lod/corotational.h"
#include "lod/holds.h"
#include "lod/lod_vec.h"
#include "lod/tick.h"

/* ---------------------------------------------------------------- the tick */

/* (1) ghost values of every due level at this tick (ring ghosts from the active nodes, finest
 * simulated level included) */
void sq_lodx_tick_pull(sq_lod *lod, long t, const long *stride, sq_tick_count *c)
{
    for (int k = 0; k < lod->L; k++) {
        lod->lev[k].tk.due = t % stride[k] == 0;
        if (lod->lev[k].tk.due && lod->lev[k].lay.nactive > 0) {
            sq_lodx_eval_ring(lod, k, t);
            c->ring_values += lod->lev[k].lay.nring;
        }
    }
}

/* (2) forces of every due level from the state at this tick, the coupling reactions between
 * levels, then integration of the free active nodes */
void sq_lodx_tick_step(sq_lod *lod, const sq_lod_frame_in *in, long t, const long *stride, sq_tick_count *c)
{
    const sq_material *mat = in->mat;
    const double *gravity = in->gravity;
    double frame_dt = in->frame_dt;
    int L = lod->L;
    for (int k = 0; k < L; k++)
        if (lod->lev[k].tk.due && lod->lev[k].lay.nactive > 0 && lod->lv[k].state.corot) {
            sq_lodx_corot_forces(lod, mat, gravity, k); /* tet by tet (corotational.c) */
        } else if (lod->lev[k].tk.due && lod->lev[k].lay.nactive > 0) {
            c->frontier_rows += lod->lev[k].lay.nfrontier;
            if (!mat->use_viscosity) { /* d + b v once per step for the row kernels */
                sq_lodx_form_w(lod, mat, k);
                lod->lev[k].tk.w_ok = 1;
            }
            /* the all-nodes force pass is vectorised, faster per node than the masked
             * one, but computes ghost rows nobody reads and needs the frontier correction
             * pass: use it once 60% of the level is active (with the frontier rows folded,
             * 60% beat 40% by 5-8% CPU on the organ and 3.6% instructions on cube-poke) */
            if (5 * lod->lev[k].lay.nactive >= 3 * lod->lv[k].model.n) {
                sq_level_forces(&lod->lv[k].model, &lod->lv[k].state, mat, gravity, NULL);
                sq_lodx_front_correct(lod, mat, k);
            } else if (mat->use_viscosity) {
                sq_level_forces(&lod->lv[k].model, &lod->lv[k].state, mat, gravity, lod->lev[k].lay.active);
                sq_lodx_front_correct(lod, mat, k);
            } else {
                /* interior rows by the level's pass, frontier rows with their
                 * correction folded in */
                sq_lodx_rows(lod, mat, gravity, k);
                sq_lodx_front_rows(lod, mat, gravity, k);
            }
        }
    for (int k = 0; k < L; k++)
        if (lod->lev[k].lay.nactive > 0 && lod->lev[k].lay.nring > 0) {
            if (!lod->lev[k].tk.due && lod->lv[k].state.corot) {
                /* the tet-by-tet reactions read every ring ghost */
                sq_lodx_eval_ring(lod, k, t);
                c->ring_values += lod->lev[k].lay.nring;
            } else if (!lod->lev[k].tk.due) {
                /* between two of its steps only the ring rows with a source on a level that
                 * steps more often are used (the reactions the finer levels need now): only
                 * the ghosts they read are evaluated (the others are not read before the
                 * level's next step or the frame's end, which evaluate every ghost) */
                unsigned faster = 0;
                for (int m = 0; m < L; m++)
                    faster |= stride[m] < stride[k] ? 1u << m : 0u;
                c->ring_values += sq_lodx_eval_ring_hot(lod, k, t, faster);
            }
            if (lod->lv[k].state.corot)
                c->ring_rows += sq_lodx_corot_couple_out(lod, mat, k, t);
            else
                c->ring_rows += sq_lodx_couple_out(lod, mat, k, t);
        }
    for (int k = 0; k < L; k++) {
        if (!lod->lev[k].tk.due)
            continue;
        sq_level *Lk = &lod->lv[k];
        lod->lev[k].tk.step_start = t;
        if (lod->lev[k].lay.nactive == 0)
            continue;
        /* feedback of the held nodes */
        sq_lodx_hold_sample(lod, k, gravity);
        /* finer levels read this level between its steps */
        sq_lodx_save_prev(lod, k);
        if (lod->lev[k].lay.nintegrated > 0) {
            double dtk = lod->lev[k].rate.extra_log2 ? frame_dt / (double)(1L << sub_log2(lod, k)) : Lk->dt;
            if (lod->lev[k].lay.nintegrated == Lk->model.n)
                sq_level_integrate(&Lk->model, &Lk->state, dtk, NULL);
            else
                sq_lodx_integrate(lod, k, dtk);
            if (in->nobstacles > 0 || in->ntargets > 0) { /* contact of the level's integrated surface
                                                               * nodes: obstacles, then other bodies */
                const sq_mesh *mk = Lk->model.mesh;
                sq_contact_nodes nd = {.n = mk->nsurf, .list = mk->surf_nodes, .X = mk->x, .mass = Lk->model.mass,
                                       .fixed = Lk->model.fixed, .mask = lod->lev[k].lay.integrated,
                                       .touched = in->touched ? in->touched[k] : NULL};
                if (in->nobstacles > 0)
                    sq_contact_step(in->obstacles, in->nobstacles, &nd, Lk->state.d, Lk->state.v, dtk, in->contact);
                if (in->ntargets > 0)
                    sq_contact_step_targets(in->targets, in->ntargets, &nd, Lk->state.d, Lk->state.v, dtk,
                                            in->contact);
            }
        }
        c->updates += lod->lev[k].lay.nintegrated;
    }
    for (int k = 0; k < L; k++)
        lod->lev[k].tk.w_ok = 0; /* d and v moved on */
}

/* ---------------------------------------------------------------- row kernels, w, integration */

/* node i's row of K in column form (made on first use for the current material) */
static const double *krow(sq_lod *lod, int k, int i)
{
    sq_lod_level *lk = &lod->lev[k];
    const sq_level_model *M = &lod->lv[k].model;
    sq_lodx_krow_index(lk, M);
    if (lk->cpl.krow_at[i] < 0) {
        int len = M->row_start[i + 1] - M->row_start[i];
        long CH = sq_lodx_krow_chunk_len(lk, M);
        if (lk->cpl.krow_used % CH + len > CH) /* no straddling: the next chunk */
            lk->cpl.krow_used += CH - lk->cpl.krow_used % CH;
        if (lk->cpl.krow_used + len > lk->cpl.krow_cap) {
            /* a new chunk; the ones made before are kept (after a material change they are
             * reused from the first) */
            int c = (int)(lk->cpl.krow_used / CH);
            if (c >= lk->cpl.krow_nchunk) {
                lk->cpl.krow_chunk = sq_realloc(lk->cpl.krow_chunk, sizeof(double *) * (size_t)(c + 1));
                for (int q = lk->cpl.krow_nchunk; q <= c; q++)
                    lk->cpl.krow_chunk[q] = sq_malloc(sizeof(double) * 12 * (size_t)CH);
                lk->cpl.krow_grown += c + 1 - lk->cpl.krow_nchunk;
                lk->cpl.krow_nchunk = c + 1;
                lk->cpl.krow_mapped = 0; /* (the reserve maps its pages past the use) */
            }
            lk->cpl.krow_cap = (long)lk->cpl.krow_nchunk * CH;
        }
        long at = lk->cpl.krow_used;
        sq_lodx_to_columns(M->K + 9 * (size_t)M->row_start[i], len, lk->cpl.krow_chunk[at / CH] + 12 * (size_t)(at % CH));
        lk->cpl.krow_at[i] = (int)at;
        lk->cpl.krow_used += len;
    }
    long at = lk->cpl.krow_at[i];
    return lk->cpl.krow_chunk[at / lk->cpl.krow_chunk_len] + 12 * (size_t)(at % lk->cpl.krow_chunk_len);
}

/* forces of the inner active nodes of level k (no viscosity): sq_level_forces with the inner
 * mask, over the list; the rows in column form, the three rows of a block in the lanes of one
 * vector, each lane summed as sq_level_node_force's rows (same products and sums) */
void sq_lodx_rows(sq_lod *lod, const sq_material *mat, const double gravity[3], int k)
{
    sq_level *L = &lod->lv[k];
    const double b = mat->rayleigh_stiffness, a = mat->rayleigh_mass;
    const double *restrict d = L->state.d, *restrict v = L->state.v;
    const double g0 = gravity[0], g1 = gravity[1], g2 = gravity[2];
    const int *il = lod->lev[k].lists.inner_list, n = lod->lev[k].lists.ninner_list;
    const int *row_start = L->model.row_start, *col = L->model.col;
    const double *mass = L->model.mass;
    if (b != 0 && !lod->lev[k].tk.w_ok) /* called outside the frame's tick */
        sq_lodx_form_w(lod, mat, k);
    const double *restrict W = lod->lev[k].tk.w_tick; /* d + b v (sq_lodx_form_w) */
    for (int r = 0; r < n; r++) {
        const int i = il[r], e0 = row_start[i], e1 = row_start[i + 1];
        const double *T = krow(lod, k, i);
        sq_v4 acc = {0, 0, 0, 0};
        if (b != 0) {
            int e = e0;
            for (; e + 1 < e1; e += 2, T += 24) { /* two blocks a turn, added in row order */
                const sq_v4 x0 = v4_block_s(T, W + 3 * (size_t)col[e]);
                const sq_v4 x1 = v4_block_s(T + 12, W + 3 * (size_t)col[e + 1]);
                acc += x0;
                acc += x1;
            }
            if (e < e1)
                acc += v4_block_s(T, W + 3 * (size_t)col[e]);
        } else /* sq_level_row reads d itself */
            for (int e = e0; e < e1; e++, T += 12)
                acc += v4_block(T, v4_load(d + 3 * (size_t)col[e]));
        const double m = mass[i];
        double *fi = L->state.f + 3 * (size_t)i;
        fi[0] = m * (g0 - a * v[3 * i]) - acc[0];
        fi[1] = m * (g1 - a * v[3 * i + 1]) - acc[1];
        fi[2] = m * (g2 - a * v[3 * i + 2]) - acc[2];
    }
}

void sq_lodx_form_w(sq_lod *lod, const sq_material *mat, int k)
{
    sq_lod_level *lk = &lod->lev[k];
    const sq_level *L = &lod->lv[k];
    if (!lk->tk.w_tick)
        lk->tk.w_tick = sq_calloc(3 * (size_t)L->model.n + 1, sizeof(double));
    const sq_v4 bb = v4_set1(mat->rayleigh_stiffness);
    const double *restrict d = L->state.d, *restrict v = L->state.v;
    double *restrict W = lk->tk.w_tick;
    /* each component as the kernels formed it per block, d + b v; 4 lanes stored per node: the
     * fourth is the next node's first component, from its current d and v too, so whatever
     * order the nodes come in every stored value is that node's d + b v now (the arrays have
     * one spare double after the last node) */
    for (int r = 0; r < lk->lay.nactive; r++) {
        const size_t j = 3 * (size_t)lk->lists.active_list[r];
        const sq_v4 x = v4_load(d + j) + bb * v4_load(v + j);
        memcpy(W + j, &x, sizeof x);
    }
    for (int r = 0; r < lk->lay.nring; r++) {
        const size_t j = 3 * (size_t)lk->lay.ring[r];
        const sq_v4 x = v4_load(d + j) + bb * v4_load(v + j);
        memcpy(W + j, &x, sizeof x);
    }
}

/* symplectic Euler of the listed nodes (sq_level_euler_node, as the level step) */
void sq_lodx_integrate(sq_lod *lod, int k, double dt)
{
    sq_level *L = &lod->lv[k];
    double *restrict d = L->state.d, *restrict v = L->state.v;
    const double *restrict f = L->state.f;
    const int *ml = lod->lev[k].lists.integrated_list;
    for (int r = 0; r < lod->lev[k].lists.nintegrated_list; r++) {
        int i = ml[r];
        sq_level_euler_node(v, d, i, dt / L->model.mass[i], dt, f[3 * i], f[3 * i + 1], f[3 * i + 2],
                            L->model.fixed[i]);
    }
}

void sq_lodx_save_prev(sq_lod *lod, int k)
{
    sq_lod_level *lk = &lod->lev[k];
    const double *d = lod->lv[k].state.d, *v = lod->lv[k].state.v;
    double *dp = lk->tk.d_start, *vp = lk->tk.v_start;
    const int n = lk->lists.nread_list, *list = lk->lists.read_list;
    for (int r = 0; r < n; r++) {
        size_t i = 3 * (size_t)list[r];
        dp[i] = d[i];
        dp[i + 1] = d[i + 1];
        dp[i + 2] = d[i + 2];
        vp[i] = v[i];
        vp[i + 1] = v[i + 1];
        vp[i + 2] = v[i + 2];
    }
}

/* ---------------------------------------------------------------- frontier rows */

/* frontier correction of level k after its full-row forces: f_i += (1 - w) sum over mixed
 * tets of K^T (d + b v) (+ D^T v) */
void sq_lodx_front_correct(sq_lod *lod, const sq_material *mat, int k)
{
    sq_lod_level *lk = &lod->lev[k];
    sq_level *L = &lod->lv[k];
    double b = mat->use_viscosity ? 0 : mat->rayleigh_stiffness;
    int visc = mat->use_viscosity && lk->cpl.front_D;
    /* the lists in locals: the force stores would make the compiler reload them */
    const int nfrontier = lk->lay.nfrontier, *frontier = lk->lay.frontier, *front_off = lk->cpl.front_off;
    const int *front_col = lk->cpl.front_col;
    for (int r = 0; r < nfrontier; r++) {
        int i = frontier[r];
        const double *B = lk->cpl.front_K;
        const double *Bd = visc ? lk->cpl.front_D : NULL;
        double *fi = L->state.f + 3 * i;
        for (int e = front_off[r]; e < front_off[r + 1]; e++) {
            int l = front_col[e];
            const double *dl = L->state.d + 3 * l, *vl = L->state.v + 3 * l, *K = B + 9 * e;
            double w[3] = {dl[0] + b * vl[0], dl[1] + b * vl[1], dl[2] + b * vl[2]};
            for (int rr = 0; rr < 3; rr++)
                fi[rr] += K[3 * rr] * w[0] + K[3 * rr + 1] * w[1] + K[3 * rr + 2] * w[2];
            if (Bd) {
                const double *D = Bd + 9 * e;
                for (int rr = 0; rr < 3; rr++)
                    fi[rr] += D[3 * rr] * vl[0] + D[3 * rr + 1] * vl[1] + D[3 * rr + 2] * vl[2];
            }
        }
    }
}


/* forces of the frontier nodes of level k from their merged rows (the masked force pass
 * having skipped them): f_i = m_i (g - a v_i) - sum_j M_ij (d_j + b v_j); no viscosity.
 * The three rows of a block in the lanes of one vector (the merged rows in column form),
 * each lane summed as the scalar rows were: f_r += (M_r0 w0 + M_r1 w1) + M_r2 w2 */
void sq_lodx_front_rows(sq_lod *lod, const sq_material *mat, const double gravity[3], int k)
{
    sq_lod_level *lk = &lod->lev[k];
    sq_level *L = &lod->lv[k];
    const double a = mat->rayleigh_mass;
    const double *restrict v = L->state.v;
    if (!lk->tk.w_ok) /* called outside the frame's tick */
        sq_lodx_form_w(lod, mat, k);
    const double *T = lk->cpl.front_T;
    const double *restrict W = lk->tk.w_tick; /* d + b v (sq_lodx_form_w) */
    /* the lists in locals: the force stores would make the compiler reload them */
    const int nfrontier = lk->lay.nfrontier, *frontier = lk->lay.frontier;
    const int *row_start = L->model.row_start, *col = L->model.col;
    const double *mass = L->model.mass;
    double *f = L->state.f;
    for (int r = 0; r < nfrontier; r++) {
        int i = frontier[r];
        sq_v4 acc = {0, 0, 0, 0};
        int q = row_start[i];
        const int q1 = row_start[i + 1];
        for (; q + 1 < q1; q += 2, T += 24) { /* two blocks a turn, added in row order */
            const sq_v4 x0 = v4_block_s(T, W + 3 * (size_t)col[q]);
            const sq_v4 x1 = v4_block_s(T + 12, W + 3 * (size_t)col[q + 1]);
            acc += x0;
            acc += x1;
        }
        if (q < q1) {
            acc += v4_block_s(T, W + 3 * (size_t)col[q]);
            T += 12;
        }
        double m = mass[i], *fi = f + 3 * (size_t)i;
        fi[0] = m * (gravity[0] - a * v[3 * i]) - acc[0];
        fi[1] = m * (gravity[1] - a * v[3 * i + 1]) - acc[1];
        fi[2] = m * (gravity[2] - a * v[3 * i + 2]) - acc[2];
    }
}

/* ---------------------------------------------------------------- ring values and reactions */

/* the ring ghosts of level k at tick t: sources of a level between two of its steps are
 * taken linearly in time over that step */
static inline __attribute__((always_inline)) void eval_list(sq_lod *lod, int k, long t, const int *list, int n)
{
    sq_lod_level *lk = &lod->lev[k];
    sq_level *Lk = &lod->lv[k];
    double fr[SQ_MAX_LEVELS];
    const double *dcur[SQ_MAX_LEVELS], *vcur[SQ_MAX_LEVELS];
    for (int m = 0; m < lod->L; m++) {
        double f = (double)(t - lod->lev[m].tk.step_start) / (double)lod->lev[m].tk.step_len;
        fr[m] = f < 0 ? 0 : (f > 1 ? 1 : f);
        dcur[m] = lod->lv[m].state.d;
        vcur[m] = lod->lv[m].state.v;
    }
    /* the level's lists in locals (the value stores below would make the compiler reload them) */
    const int *ring = lk->lay.ring, *src_start = lk->lay.src_start;
    const int *fl = lk->lay.src_level, *fn = lk->lay.src_node, *rend = lk->lay.src_rend;
    const double *fw = lk->lay.src_weight;
    double *restrict Dk = Lk->state.d, *restrict Vk = Lk->state.v;
    const unsigned char *fixed = Lk->model.fixed;
    for (int x = 0; x < n; x++) {
        const int r = list ? list[x] : x;
        int j = ring[r];
        int a = src_start[r], b = src_start[r + 1];
        if (a == b)
            continue;
        /* a node's d and v as 4 lanes (lane 3 unused), each lane summed as the scalar sums
         * were: d += w * d1, or d += w * (d0 + f (d1 - d0)) */
        sq_v4 d = {0, 0, 0, 0}, v = {0, 0, 0, 0};
        /* the sources are sorted by level: one run per level, its time fraction hoisted */
        for (int q = a; q < b;) {
            const int m = fl[q], qe = rend[q];
            double f = fr[m];
            const double *D1 = dcur[m], *V1 = vcur[m];
            if (f == 1) {
                /* a source level at the end of its step (the common case): its values */
                for (; q < qe; q++) {
                    const sq_v4 w = v4_set1(fw[q]);
                    const size_t n3 = 3 * (size_t)fn[q];
                    d += w * v4_load(D1 + n3);
                    v += w * v4_load(V1 + n3);
                }
                continue;
            }
            const double *D0 = lod->lev[m].tk.d_start, *V0 = lod->lev[m].tk.v_start;
            const sq_v4 fv = v4_set1(f);
            for (; q < qe; q++) {
                const sq_v4 w = v4_set1(fw[q]);
                const size_t n3 = 3 * (size_t)fn[q];
                const sq_v4 d0 = v4_load(D0 + n3), v0 = v4_load(V0 + n3);
                d += w * (d0 + fv * (v4_load(D1 + n3) - d0));
                v += w * (v0 + fv * (v4_load(V1 + n3) - v0));
            }
        }
        sq_lodx_store_free(fixed[j], &d, &v, Dk + 3 * (size_t)j, Vk + 3 * (size_t)j);
    }
}

void sq_lodx_eval_ring(sq_lod *lod, int k, long t)
{
    eval_list(lod, k, t, NULL, lod->lev[k].lay.nring);
}

/* the ring ghosts of level k that the ring rows with a source on a level in `mask` read (the
 * ghost columns of those rows), increasing ring order: lk->tk.hot, made once per layout */
static void hot_list(sq_lod *lod, int k, unsigned mask)
{
    sq_lod_level *lk = &lod->lev[k];
    if (lk->tk.hot_valid && lk->tk.hot_mask == mask)
        return;
    if (!lk->tk.hot)
        lk->tk.hot = sq_malloc(sizeof(int) * (size_t)SQ_MAX(lod->lv[k].model.n, 1));
    unsigned char *mark = lk->lists.mark; /* all zero between uses */
    for (int r = 0; r < lk->lay.nring; r++)
        if (lk->lay.src_levels[r] & mask)
            for (int e = lk->cpl.ring_off[r]; e < lk->cpl.ring_off[r + 1]; e++) {
                int l = lk->lay.ring_index[lk->cpl.ring_col[e]];
                if (l >= 0)
                    mark[l] = 1;
            }
    int nh = 0;
    for (int r = 0; r < lk->lay.nring; r++)
        if (mark[r]) {
            lk->tk.hot[nh++] = r;
            mark[r] = 0;
        }
    lk->tk.nhot = nh;
    lk->tk.hot_mask = mask;
    lk->tk.hot_valid = 1;
}

int sq_lodx_eval_ring_hot(sq_lod *lod, int k, long t, unsigned mask)
{
    hot_list(lod, k, mask);
    eval_list(lod, k, t, lod->lev[k].tk.hot, lod->lev[k].tk.nhot);
    return lod->lev[k].tk.nhot;
}

/* force on ring ghost r (node j) of level k from the tets touching active nodes, -(K w)_j -
 * (D v)_j, with the active nodes of level k taken at fraction fr of its current step */
static void ring_force(const sq_lod *lod, const sq_material *mat, int k, int r, double fr, double g[3])
{
    const sq_lod_level *lk = &lod->lev[k];
    const sq_level *L = &lod->lv[k];
    const unsigned char *act = lk->lay.active;
    double b = mat->use_viscosity ? 0 : mat->rayleigh_stiffness;
    const double *Bd = mat->use_viscosity ? lk->cpl.ring_D : NULL;
    g[0] = g[1] = g[2] = 0;
    if (!Bd) {
        /* no viscosity: the three rows of a block in the lanes of one vector (the ring rows in
         * column form), each lane summed as the scalar rows were: g_r -= (K_r0 w0 + K_r1 w1)
         * + K_r2 w2 */
        const double *restrict d = L->state.d, *restrict v = L->state.v;
        const double *T = lk->cpl.ring_T;
        const int *col = lk->cpl.ring_col;
        const sq_v4 bb = v4_set1(b);
        sq_v4 acc = {0, 0, 0, 0};
        const int e0 = lk->cpl.ring_off[r], e1 = lk->cpl.ring_off[r + 1];
        if (fr >= 1) {
            /* the level at the end of its step (without viscosity sq_lodx_couple_out does
             * this itself, from d + b v formed once for the step) */
            for (int e = e0; e < e1; e++) {
                const size_t j = 3 * (size_t)col[e];
                acc -= v4_block(T + 12 * (size_t)e, v4_load(d + j) + bb * v4_load(v + j));
            }
        } else {
            /* active nodes of the level between two of its steps, at fraction fr */
            const double *restrict d0s = lk->tk.d_start, *restrict v0s = lk->tk.v_start;
            const sq_v4 fv = v4_set1(fr);
            for (int e = e0; e < e1; e++) {
                const int l = col[e];
                const size_t j = 3 * (size_t)l;
                sq_v4 dl = v4_load(d + j), vl = v4_load(v + j);
                if (act[l]) {
                    const sq_v4 d0 = v4_load(d0s + j), v0 = v4_load(v0s + j);
                    dl = d0 + fv * (dl - d0);
                    vl = v0 + fv * (vl - v0);
                }
                acc -= v4_block(T + 12 * (size_t)e, dl + bb * vl);
            }
        }
        g[0] = acc[0];
        g[1] = acc[1];
        g[2] = acc[2];
        return;
    }
    for (int e = lk->cpl.ring_off[r]; e < lk->cpl.ring_off[r + 1]; e++) {
        int l = lk->cpl.ring_col[e];
        double dl[3], vl[3];
        for (int c = 0; c < 3; c++) {
            dl[c] = L->state.d[3 * l + c];
            vl[c] = L->state.v[3 * l + c];
        }
        if (fr < 1 && act[l])
            for (int c = 0; c < 3; c++) {
                double d0 = lk->tk.d_start[3 * l + c], v0 = lk->tk.v_start[3 * l + c];
                dl[c] = d0 + fr * (dl[c] - d0);
                vl[c] = v0 + fr * (vl[c] - v0);
            }
        const double *K = lk->cpl.ring_K + 9 * (size_t)e;
        double w[3] = {dl[0] + b * vl[0], dl[1] + b * vl[1], dl[2] + b * vl[2]};
        for (int rr = 0; rr < 3; rr++)
            g[rr] -= K[3 * rr] * w[0] + K[3 * rr + 1] * w[1] + K[3 * rr + 2] * w[2];
        const double *D = Bd + 9 * (size_t)e;
        for (int rr = 0; rr < 3; rr++)
            g[rr] -= D[3 * rr] * vl[0] + D[3 * rr + 1] * vl[1] + D[3 * rr + 2] * vl[2];
    }
}

/* the ring reactions of level k at tick t go back to their active sources, into the force of
 * the levels that step at this tick. A level between two of its steps (a coarser one) still
 * hands its reactions to the finer levels stepping now, from its values at this tick: those
 * reactions depend on the finer nodes themselves, so they must follow them step by step.
 * Reactions for a coarser level are sampled at its own steps. */
int sq_lodx_couple_out(sq_lod *lod, const sq_material *mat, int k, long t)
{
    int rows = 0;
    sq_lod_level *lk = &lod->lev[k];
    const sq_level *Lk = &lod->lv[k];
    double fr = (double)(t - lk->tk.step_start) / (double)lk->tk.step_len;
    fr = fr < 0 ? 0 : (fr > 1 ? 1 : fr);
    unsigned due_bits = 0;
    for (int m = 0; m < lod->L; m++)
        due_bits |= lod->lev[m].tk.due ? 1u << m : 0u;
    /* the level's lists in locals: the force stores below could otherwise alias them for the
     * compiler, which would reload them at every ring ghost */
    const int nring = lk->lay.nring, *ring = lk->lay.ring, *src_start = lk->lay.src_start;
    const unsigned char *src_levels = lk->lay.src_levels;
    const int *fl = lk->lay.src_level, *fn = lk->lay.src_node, *rend = lk->lay.src_rend;
    const double *fw = lk->lay.src_weight;
    /* the level at the end of its step without viscosity (the common case): the ring rows
     * here, from d + b v formed once for the step (sq_lodx_form_w); the others by ring_force */
    const int fast = fr >= 1 && !mat->use_viscosity;
    if (fast && !lk->tk.w_ok) /* called outside the frame's tick */
        sq_lodx_form_w(lod, mat, k);
    const double *restrict W = lk->tk.w_tick, *T = lk->cpl.ring_T;
    const int *col = lk->cpl.ring_col, *roff = lk->cpl.ring_off;
    const unsigned char *fixed = Lk->model.fixed;
    double *Fl[SQ_MAX_LEVELS];
    for (int m = 0; m < lod->L; m++)
        Fl[m] = lod->lv[m].state.f;
    for (int r = 0; r < nring; r++) {
        int j = ring[r];
        int a = src_start[r], b = src_start[r + 1];
        if (!(src_levels[r] & due_bits))
            continue;
        double g[3];
        if (fast) {
            /* -(K w) over the row in column form, each lane summed as the scalar rows were:
             * g_r -= (K_r0 w0 + K_r1 w1) + K_r2 w2, two blocks a turn in row order */
            sq_v4 acc = {0, 0, 0, 0};
            int e = roff[r];
            const int e1 = roff[r + 1];
            for (; e + 1 < e1; e += 2) {
                const sq_v4 x0 = v4_block_s(T + 12 * (size_t)e, W + 3 * (size_t)col[e]);
                const sq_v4 x1 = v4_block_s(T + 12 * (size_t)e + 12, W + 3 * (size_t)col[e + 1]);
                acc -= x0;
                acc -= x1;
            }
            if (e < e1)
                acc -= v4_block_s(T + 12 * (size_t)e, W + 3 * (size_t)col[e]);
            g[0] = acc[0];
            g[1] = acc[1];
            g[2] = acc[2];
        } else {
            ring_force(lod, mat, k, r, fr, g);
        }
        rows++;
        unsigned char fx = fixed[j];
        if (fx)
            for (int c = 0; c < 3; c++)
                if (fx & (1u << c))
                    g[c] = 0; /* a constrained axis of a ghost does not follow its sources */
        const sq_v2 g01 = {g[0], g[1]};
        /* one run of sources per level (sorted by level); levels not stepping now skipped */
        for (int q = a; q < b;) {
            const int m = fl[q], qe = rend[q];
            if (!(due_bits & (1u << m))) {
                q = qe;
                continue;
            }
            double *F = Fl[m];
            for (; q < qe; q++) {
                /* dst[c] += w g[c]: x and y as one 2-lane vector */
                double w = fw[q], *dst = F + 3 * (size_t)fn[q];
                sq_v2 xy;
                memcpy(&xy, dst, sizeof xy);
                xy += (sq_v2){w, w} * g01;
                memcpy(dst, &xy, sizeof xy);
                dst[2] += w * g[2];
            }
        }
    }
    return rows;
}

/* ---------------------------------------------------------------- the level's clock and scratch
 *
 * what the other stages set in lev[k].tk, through these: the substep clock of the frame
 * (frame.c's layout stage), the hot ring list out of date (ring.c's sources, coupling.c's
 * blocks), a node's step-start values (criterion.c's splits and merges), d + b v's buffer
 * mapped ahead (reserve.c) */

void sq_lodx_tick_clock(sq_lod *lod, const long *stride)
{
    for (int k = 0; k < lod->L; k++) {
        lod->lev[k].tk.step_start = -stride[k]; /* the previous frame's last step ended at tick 0 */
        lod->lev[k].tk.step_len = stride[k];
    }
}

void sq_lodx_tick_hot_stale(sq_lod *lod, int k)
{
    lod->lev[k].tk.hot_valid = 0;
}

void sq_lodx_tick_start_node(sq_lod *lod, int k, int j)
{
    memcpy(lod->lev[k].tk.d_start + 3 * j, lod->lv[k].state.d + 3 * j, 3 * sizeof(double));
    memcpy(lod->lev[k].tk.v_start + 3 * j, lod->lv[k].state.v + 3 * j, 3 * sizeof(double));
}

double *sq_lodx_tick_w(sq_lod *lod, int k)
{
    sq_lod_level *lk = &lod->lev[k];
    if (!lk->tk.w_tick)
        lk->tk.w_tick = sq_calloc(3 * (size_t)lod->lv[k].model.n + 1, sizeof(double));
    return lk->tk.w_tick;
}
