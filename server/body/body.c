/* body.c - a soft body's life: defaults, validation, create / destroy, its levels (built on
 * demand), the state carried between levels and the surface map.
 *
 * Fixed mode simulates one level k. The rendered surface is always the finest loaded
 * level's boundary: at k < finest its vertices take their displacement by interpolation in
 * level k (barycentric coordinates found once). Tools become holds on finest surface nodes
 * (body/tools.c); at k < finest each hold moves the nearest level-k node by the same
 * translation (body/frame.c). Adaptive mode hands the frame to the lod module. Run-time
 * changes are body/set.c, health and sleep body/health.c, the read-only views body/views.c.
 */
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "lod/lod.h"
#include "body/body_internal.h"

sq_body_def sq_body_def_default(void)
{
    sq_body_def d;
    memset(&d, 0, sizeof d);
    d.name = "body";
    /* the paper's cube material (standard names), lightly damped */
    d.material = sq_material_paper();
    d.material.rayleigh_mass = 0.5;
    d.material.rayleigh_stiffness = 0.001;
    d.op = SQ_OPERATOR_FEM;
    d.lod.mode = SQ_LOD_FIXED;
    d.lod.level = 0;
    d.lod.split = 0.005;
    d.lod.merge = 0.002;
    d.lod.max_level = SQ_MAX_LEVELS - 1;
    d.lod.budget = 0.95;
    d.lod.max_node_updates = 0;
    d.lod.adapt_every = 1;
    d.frame_dt = 1.0 / 50.0;
    d.step_fraction = 0.9;
    d.sharp_step = 1; /* the sharp bound, Gershgorin its ceiling and fallback (docs/stability.md) */
    d.integrator = SQ_INTEGRATOR_EXPLICIT;
    d.implicit = sq_implicit_def_default();
    return d;
}

/* ---- helpers ---------------------------------------------------------------------------- */

static double mesh_diag(const sq_mesh *m)
{
    double s = 0;
    for (int k = 0; k < 3; k++)
        s += (m->bbox_max[k] - m->bbox_min[k]) * (m->bbox_max[k] - m->bbox_min[k]);
    return sqrt(s);
}

/* interpolate a per-node field (n x 3) of mesh m at tet t with barycentrics bary */
void sq_body_interp3(const sq_mesh *m, const double *field, int t, const double bary[4], double out[3])
{
    out[0] = out[1] = out[2] = 0;
    for (int k = 0; k < 4; k++) {
        const double *fk = field + 3 * (size_t)m->tets[4 * t + k];
        out[0] += bary[k] * fk[0];
        out[1] += bary[k] * fk[1];
        out[2] += bary[k] * fk[2];
    }
}

/* nearest node of mesh m to p: start at the located tet's vertex of largest weight, then walk
 * the adjacency greedily while a neighbour is closer */
static int nearest_node(const sq_mesh *m, const double p[3])
{
    double bary[4];
    int t = sq_mesh_locate(m, p, bary);
    if (t < 0)
        return 0;
    int best = 0;
    for (int k = 1; k < 4; k++)
        if (bary[k] > bary[best])
            best = k;
    int i = m->tets[4 * t + best];
    double di = 0;
    for (int c = 0; c < 3; c++)
        di += (m->x[3 * i + c] - p[c]) * (m->x[3 * i + c] - p[c]);
    for (;;) {
        int moved = 0;
        for (int e = m->adj_start[i]; e < m->adj_start[i + 1]; e++) {
            int j = m->adj[e];
            double dj = 0;
            for (int c = 0; c < 3; c++)
                dj += (m->x[3 * j + c] - p[c]) * (m->x[3 * j + c] - p[c]);
            if (dj < di) {
                di = dj;
                i = j;
                moved = 1;
            }
        }
        if (!moved)
            return i;
    }
}

/* initialise level k if it is not yet; state at rest */
int sq_body_ensure_level(sq_body *b, int k, sq_err *err)
{
    if (b->ready[k])
        return 0;
    sq_level *L = &b->level[k];
    /* a copy of a body (sq_body_create_like) borrows the level's operator when it is built from
     * the same mesh, operator, material and constraints: the same blocks, read only */
    const sq_body *like = b->like;
    int same_model = like && k < like->nuse && like->ready[k] && like->def.levels[k] == b->def.levels[k] &&
                     like->def.op == b->def.op &&
                     !memcmp(&like->def.material, &b->def.material, sizeof b->def.material) &&
                     like->def.nconstraints == b->def.nconstraints &&
                     !memcmp(like->def.constraints, b->def.constraints,
                             sizeof(sq_constraint) * (size_t)b->def.nconstraints);
    if (same_model)
        sq_level_init_shared(L, &like->level[k]);
    else if (sq_level_init(L, b->def.levels[k], &b->def.material, b->def.op, b->def.constraints,
                           b->def.nconstraints, err) < 0)
        return sq_err_prefix(err, "body '%s' level %d", b->name, k);
    if ((b->def.elasticity == SQ_ELASTICITY_COROTATIONAL &&
         sq_level_corot_enable(L, &b->def.material, b->def.op, err) < 0) ||
        (b->def.nodal_pressure && sq_level_anp_enable(L, &b->def.material, b->def.op, b->def.nodal_pressure, err) < 0)) {
        sq_level_free(L);
        return sq_err_prefix(err, "body '%s' level %d", b->name, k);
    }
    /* a copy of a body on the same level (sq_body_create_like): its sharp estimate, the same
     * numbers as estimating again on the same mesh, material, constraints, frame and fraction */
    int reuse = same_model && like->def.frame_dt == b->def.frame_dt &&
                like->def.step_fraction == b->def.step_fraction && like->def.elasticity == b->def.elasticity &&
                like->def.nodal_pressure == b->def.nodal_pressure;
    if (b->def.integrator == SQ_INTEGRATOR_IMPLICIT)
        sq_body_explicit_estimate(b, L, &b->def.material, reuse);
    else if (sq_level_choose_step(L, &b->def.material, b->def.frame_dt, b->def.step_fraction, err) < 0 ||
             (!reuse && sq_level_choose_step_sharp(L, &b->def.material, b->def.frame_dt, b->def.step_fraction,
                                                   SQ_LANCZOS_ITERS, err) < 0)) {
        sq_level_free(L);
        return sq_err_prefix(err, "body '%s' level %d (%d nodes)", b->name, k, b->def.levels[k]->nnodes);
    }
    if (reuse) {
        L->omega_est = like->level[k].omega_est;
        L->bound_sharp = like->level[k].bound_sharp;
        L->nsub = like->level[k].nsub;
        L->dt_fixed = like->level[k].dt_fixed;
    }
    b->mask[k] = sq_malloc((size_t)L->model.n);
    memset(b->mask[k], 1, (size_t)L->model.n);
    b->hold_of[k] = sq_malloc(sizeof(int) * (size_t)L->model.n);
    b->held[k] = sq_calloc((size_t)L->model.n, 1);
    b->held_list[k] = sq_malloc(sizeof(int) * (size_t)L->model.n);
    b->nheld[k] = 0;
    for (int i = 0; i < L->model.n; i++)
        b->hold_of[k][i] = -1;
    b->ready[k] = 1;
    return 0;
}

void sq_body_explicit_estimate(const sq_body *b, sq_level *L, const sq_material *m, int reuse)
{
    /* an implicit body needs no explicit step, but keeps the figures (what explicit would
     * take: substeps in stats and the trade-off): past 2^20 substeps they are capped there */
    sq_err ignore = {{0}};
    if (sq_level_choose_step(L, m, b->def.frame_dt, b->def.step_fraction, &ignore) < 0) {
        L->substeps_log2 = 20;
        L->dt = b->def.frame_dt / 1048576.0;
    }
    if (!reuse && sq_level_choose_step_sharp(L, m, b->def.frame_dt, b->def.step_fraction, SQ_LANCZOS_ITERS,
                                             &ignore) < 0) {
        L->nsub = 1048576;
        L->dt_fixed = b->def.frame_dt / L->nsub;
    }
}

/* forget which nodes of level k a tool held (released: reset or lod change) */
void sq_body_clear_held(sq_body *b, int k)
{
    for (int h = 0; h < b->nheld[k]; h++)
        b->held[k][b->held_list[k][h]] = 0;
    b->nheld[k] = 0;
}

/* copy displacement and velocity from level src to level dst by interpolation */
void sq_body_transfer_state(sq_body *b, int src, int dst)
{
    if (src == dst)
        return;
    sq_level *S = &b->level[src], *T = &b->level[dst];
    for (int i = 0; i < T->model.n; i++) {
        double bary[4];
        int t = sq_mesh_locate(S->model.mesh, T->model.mesh->x + 3 * (size_t)i, bary);
        if (t < 0)
            continue;
        sq_body_interp3(S->model.mesh, S->state.d, t, bary, T->state.d + 3 * (size_t)i);
        sq_body_interp3(S->model.mesh, S->state.v, t, bary, T->state.v + 3 * (size_t)i);
    }
}

/* per finest surface vertex: tet and barycentrics in the fixed level, and its nearest node */
void sq_body_prepare_surface_map(sq_body *b)
{
    int k = b->cur;
    if (k == b->fine || b->map_level == k)
        return;
    const sq_mesh *fm = b->def.levels[b->fine], *km = b->def.levels[k];
    if (!b->surf_tet) {
        b->surf_tet = sq_malloc(sizeof(int) * (size_t)fm->nsurf);
        b->surf_bary = sq_malloc(sizeof(double) * 4 * (size_t)fm->nsurf);
        b->surf_near = sq_malloc(sizeof(int) * (size_t)fm->nsurf);
    }
    for (int s = 0; s < fm->nsurf; s++) {
        const double *p = fm->x + 3 * (size_t)fm->surf_nodes[s];
        b->surf_tet[s] = sq_mesh_locate(km, p, b->surf_bary + 4 * (size_t)s);
        if (b->surf_tet[s] < 0) {
            b->surf_tet[s] = 0;
            b->surf_bary[4 * s] = 1;
            b->surf_bary[4 * s + 1] = b->surf_bary[4 * s + 2] = b->surf_bary[4 * s + 3] = 0;
        }
        b->surf_near[s] = nearest_node(km, p);
    }
    b->map_level = k;
}

void sq_body_surface_disp(const sq_body *b, int s, double u[3])
{
    const sq_mesh *fm = b->def.levels[b->fine];
    if (b->def.lod.mode == SQ_LOD_ADAPTIVE || b->cur == b->fine) {
        const double *d = b->level[b->fine].state.d + 3 * (size_t)fm->surf_nodes[s];
        u[0] = d[0];
        u[1] = d[1];
        u[2] = d[2];
        return;
    }
    sq_body_interp3(b->def.levels[b->cur], b->level[b->cur].state.d, b->surf_tet[s], b->surf_bary + 4 * (size_t)s, u);
}

void sq_body_set_levels_fixed(sq_body *b)
{
    memset(b->node_level, (unsigned char)b->cur, (size_t)b->def.levels[b->fine]->nnodes);
}

/* ---- validation ------------------------------------------------------------------------- */

#define COROT_PAPER_MSG                                                                                    \
    "corotational elasticity needs the fem operator (the paper operator has no corotational form here): "  \
    "use \"operator\": \"fem\" with \"elasticity\": \"corotational\", or \"elasticity\": \"linear\" with "  \
    "the paper operator"

#define NODAL_MSG                                                                                          \
    "nodal pressure tets (\"pressure\": \"nodal\") run with the fem operator, linear elasticity and fixed "   \
    "lod only: use those, or \"pressure\": \"element\""
#define SMOOTHED_MSG                                                                                       \
    "smoothed tets (\"pressure\": \"smoothed\": nodal pressure tets with face-smoothed strain) run with the " \
    "fem operator, linear elasticity and fixed lod only: use those, or \"pressure\": \"element\""

/* is nodal pressure (or smoothed) allowed with the rest? */
int sq_body_check_pressure(int nodal, sq_elasticity_kind e, sq_operator_kind op, sq_lod_mode mode, sq_err *err)
{
    if (nodal && (e != SQ_ELASTICITY_LINEAR || op != SQ_OPERATOR_FEM || mode != SQ_LOD_FIXED))
        return sq_err_set(err, nodal == SQ_PRESSURE_SMOOTHED ? SMOOTHED_MSG : NODAL_MSG);
    return 0;
}

/* is elasticity e allowed with operator op and lod mode? 0, or -1 + err naming the combination */
int sq_body_check_elasticity(sq_elasticity_kind e, sq_operator_kind op, sq_lod_mode mode, sq_err *err)
{
    (void)mode; /* both lod modes run either elasticity (corotational adaptive: lod/corotational.c) */
    if (e != SQ_ELASTICITY_LINEAR && e != SQ_ELASTICITY_COROTATIONAL)
        return sq_err_set(err, "elasticity %d is unknown: use linear or corotational", (int)e);
    if (e == SQ_ELASTICITY_COROTATIONAL && op != SQ_OPERATOR_FEM)
        return sq_err_set(err, COROT_PAPER_MSG);
    return 0;
}

int sq_body_check_integrator(sq_integrator_kind k, const sq_implicit_def *imp, sq_lod_mode mode, sq_err *err)
{
    if (k != SQ_INTEGRATOR_EXPLICIT && k != SQ_INTEGRATOR_IMPLICIT)
        return sq_err_set(err, "integrator %d is unknown: use \"explicit\" or \"implicit\"", (int)k);
    if (sq_implicit_def_check(imp, err) < 0)
        return -1;
    if (k == SQ_INTEGRATOR_IMPLICIT && mode != SQ_LOD_FIXED)
        return sq_err_set(err, "the implicit integrator runs with fixed lod only (adaptive levels still step "
                               "explicitly): use \"lod\": {\"mode\": \"fixed\"} or \"integrator\": \"explicit\"");
    return 0;
}

static int check_def(const sq_body_def *def, sq_err *err)
{
    if (def->nlevels < 1 || def->nlevels > SQ_MAX_LEVELS)
        return sq_err_set(err, "body has %d levels: give 1 to %d meshes, coarse to fine", def->nlevels,
                          SQ_MAX_LEVELS);
    for (int k = 0; k < def->nlevels; k++)
        if (!def->levels[k] || def->levels[k]->nnodes <= 0 || !def->levels[k]->surf_nodes)
            return sq_err_set(err, "level %d has no mesh (or an empty one): load every listed level", k);
    if (!(def->frame_dt > 0) || !isfinite(def->frame_dt) || def->frame_dt > 10)
        return sq_err_set(err, "frame period %g s is out of range: give a frame rate of at least 0.1 Hz "
                               "(frame_dt in (0, 10] s)", def->frame_dt);
    if (!(def->step_fraction > 0 && def->step_fraction <= 1))
        return sq_err_set(err, "step_fraction %g is out of range: give 0 < step_fraction <= 1 (0.9 is usual)",
                          def->step_fraction);
    if (def->op != SQ_OPERATOR_FEM && def->op != SQ_OPERATOR_PAPER)
        return sq_err_set(err, "operator %d is unknown: use fem or paper", (int)def->op);
    for (int k = 0; k < 3; k++)
        if (!isfinite(def->gravity[k]))
            return sq_err_set(err, "gravity[%d] = %g is not finite", k, def->gravity[k]);
    if (def->nconstraints < 0 || def->nconstraints > SQ_MAX_CONSTRAINTS)
        return sq_err_set(err, "%d constraints: give at most %d", def->nconstraints, SQ_MAX_CONSTRAINTS);
    for (int c = 0; c < def->nconstraints; c++) {
        const sq_constraint *cn = &def->constraints[c];
        if (cn->kind != SQ_REGION_BOX && cn->kind != SQ_REGION_HALFSPACE)
            return sq_err_set(err, "constraint %d has unknown region kind %d", c, (int)cn->kind);
        for (int k = 0; k < 3; k++)
            if (!isfinite(cn->a[k]) || !isfinite(cn->b[k]))
                return sq_err_set(err, "constraint %d has a non-finite coordinate", c);
        if (cn->kind == SQ_REGION_HALFSPACE && cn->b[0] == 0 && cn->b[1] == 0 && cn->b[2] == 0)
            return sq_err_set(err, "constraint %d: half-space normal is zero; give a non-zero normal", c);
        if (cn->axes == 0 || cn->axes > 7)
            return sq_err_set(err, "constraint %d: axes mask %u must be 1..7 (bits x=1, y=2, z=4)", c, cn->axes);
    }
    if (sq_body_check_elasticity(def->elasticity, def->op, def->lod.mode, err) < 0 ||
        sq_body_check_pressure(def->nodal_pressure, def->elasticity, def->op, def->lod.mode, err) < 0 ||
        sq_body_check_integrator(def->integrator, &def->implicit, def->lod.mode, err) < 0)
        return -1;
    return sq_material_check(&def->material, err);
}

int sq_body_check_lod(const sq_body *b, const sq_lod_def *lod, sq_err *err)
{
    if (lod->mode != SQ_LOD_FIXED && lod->mode != SQ_LOD_ADAPTIVE)
        return sq_err_set(err, "lod mode %d is unknown: use fixed or adaptive", (int)lod->mode);
    if (lod->level < 0 || lod->level >= b->nuse)
        return sq_err_set(err, "lod level %d is out of range: body '%s' has levels 0..%d", lod->level,
                          b->name, b->nuse - 1);
    if (!(lod->split >= 0) || !(lod->merge >= 0) || !isfinite(lod->merge))
        return sq_err_set(err, "lod split %g / merge %g must be >= 0", lod->split, lod->merge);
    if (lod->mode == SQ_LOD_ADAPTIVE && lod->split > 0 && !(lod->merge < lod->split))
        return sq_err_set(err, "lod merge %g must be below split %g (hysteresis)", lod->merge, lod->split);
    if (!(lod->budget > 0 && lod->budget <= 1))
        return sq_err_set(err, "lod budget %g is out of range: give a fraction of the frame period in (0, 1]",
                          lod->budget);
    if (lod->max_node_updates < 0)
        return sq_err_set(err, "lod max_node_updates %ld must be >= 0 (0 = no cap)", lod->max_node_updates);
    if (lod->adapt_every < 0 || lod->adapt_every > SQ_LOD_ADAPT_EVERY_MAX)
        return sq_err_set(err, "lod adapt_every %d is out of range: give a number of frames in 1..%d", lod->adapt_every,
                          SQ_LOD_ADAPT_EVERY_MAX);
    return 0;
}

/* ---- create / destroy ------------------------------------------------------------------- */

static sq_body *create(const sq_body_def *def, const sq_body *like, sq_err *err)
{
    if (check_def(def, err) < 0)
        return NULL;
    sq_body *b = sq_calloc(1, sizeof *b);
    b->like = like;
    b->def = *def;
    snprintf(b->name, sizeof b->name, "%s", def->name ? def->name : "body");
    b->def.name = b->name;
    int maxl = def->lod.max_level >= 0 ? def->lod.max_level : SQ_MAX_LEVELS - 1;
    b->nuse = SQ_MIN(def->nlevels, maxl + 1);
    b->fine = b->nuse - 1;
    b->map_level = -1;
    b->diag = mesh_diag(def->levels[b->fine]);
    b->sleep_frames = 25;
    b->sleep_ke_speed = 1e-4;
    b->sleep_residual = 1e-4;
    b->node_level = sq_calloc((size_t)def->levels[b->fine]->nnodes, 1);
    for (int t = 0; t < SQ_MAX_TOOLS; t++)
        b->grab[t].id = -1;
    if (sq_body_check_lod(b, &def->lod, err) < 0) {
        sq_body_destroy(b);
        return NULL;
    }
    b->cur = def->lod.level;
    if (sq_body_ensure_level(b, b->cur, err) < 0) {
        sq_body_destroy(b);
        return NULL;
    }
    if (b->level[b->cur].model.nfree == 0) {
        sq_err_set(err, "body '%s': the constraints fix all %d nodes of level %d, so nothing can move; "
                        "shrink the fixed region", b->name, b->level[b->cur].model.n, b->cur);
        sq_body_destroy(b);
        return NULL;
    }
    if (def->lod.mode == SQ_LOD_ADAPTIVE) {
        for (int k = 0; k < b->nuse; k++)
            if (sq_body_ensure_level(b, k, err) < 0) {
                sq_body_destroy(b);
                return NULL;
            }
        /* a copy borrows the hierarchy and the mesh tables of like's state, and its static loads */
        const sq_lod *like_lod = like && like->lod ? like->lod : NULL;
        b->lod = like_lod ? sq_lod_create_like(b->level, b->nuse, &b->def.lod, like_lod, err)
                          : sq_lod_create(b->level, b->nuse, &b->def.lod, err);
        if (!b->lod) {
            sq_err_prefix(err, "body '%s'", b->name);
            sq_body_destroy(b);
            return NULL;
        }
        sq_lod_set_loads_like(b->lod, &b->def.material, b->def.gravity, like_lod); /* set-up before frame 1 */
        sq_lod_set_step_rule(b->lod, b->def.sharp_step, b->def.step_fraction);
        sq_lod_node_levels(b->lod, b->node_level);
    } else {
        sq_body_prepare_surface_map(b);
        sq_body_set_levels_fixed(b);
    }
    b->like = NULL;
    return b;
}

sq_body *sq_body_create(const sq_body_def *def, sq_err *err)
{
    return create(def, NULL, err);
}

sq_body *sq_body_create_like(const sq_body *like, const sq_body_def *def, sq_err *err)
{
    return create(def, like, err);
}

void sq_body_destroy(sq_body *b)
{
    if (!b)
        return;
    if (b->lod)
        sq_lod_destroy(b->lod);
    for (int k = 0; k < SQ_MAX_LEVELS; k++) {
        if (b->ready[k])
            sq_level_free(&b->level[k]);
        free(b->mask[k]);
        free(b->hold_of[k]);
        free(b->held[k]);
        free(b->held_list[k]);
    }
    for (int t = 0; t < SQ_MAX_TOOLS; t++) {
        free(b->grab[t].surf);
        free(b->grab[t].disp);
    }
    sq_body_contact_free(b);
    free(b->cond_x);
    free(b->surf_tet);
    free(b->surf_bary);
    free(b->surf_near);
    free(b->node_level);
    free(b->holds);
    free(b->khold);
    free(b->kcount);
    free(b->khold_of);
    free(b->live_P);
    free(b->live_target);
    free(b->live_on);
    free(b->live_shift);
    free(b->save_d);
    free(b->save_v);
    free(b->save_q);
    free(b);
}
