/* body.c - a soft body: its levels, the frame loop (fixed or adaptive), health, sleep,
 * surface state, probes, energies.
 *
 * Fixed mode simulates one level k. The rendered surface is always the finest loaded
 * level's boundary: at k < finest its vertices take their displacement by interpolation in
 * level k (barycentric coordinates found once). Tools become holds on finest surface nodes
 * (body/tools.c); at k < finest each hold moves the nearest level-k node by the same
 * translation. Adaptive mode hands the frame to the lod module.
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
    d.material.mu = 40000;
    d.material.lambda = 100000;
    d.material.density = 1000;
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
    d.frame_dt = 1.0 / 50.0;
    d.step_fraction = 0.9;
    return d;
}

/* ---- helpers ---------------------------------------------------------------------------- */

/* Lanczos steps of the sharp step bound (fixed mode; docs/stability.md) */
#define SQ_LANCZOS_ITERS 40

static double mesh_diag(const sq_mesh *m)
{
    double s = 0;
    for (int k = 0; k < 3; k++)
        s += (m->bbox_max[k] - m->bbox_min[k]) * (m->bbox_max[k] - m->bbox_min[k]);
    return sqrt(s);
}

/* interpolate a per-node field (n x 3) of mesh m at tet t with barycentrics bary */
static void interp3(const sq_mesh *m, const double *field, int t, const double bary[4], double out[3])
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
static int ensure_level(sq_body *b, int k, sq_err *err)
{
    if (b->ready[k])
        return 0;
    sq_level *L = &b->level[k];
    if (sq_level_init(L, b->def.levels[k], &b->def.material, b->def.op, b->def.constraints,
                      b->def.nconstraints, err) < 0)
        return sq_err_prefix(err, "body '%s' level %d", b->name, k);
    if ((b->def.elasticity == SQ_ELASTICITY_COROTATIONAL &&
         sq_level_corot_enable(L, &b->def.material, b->def.op, err) < 0) ||
        (b->def.nodal_pressure && sq_level_anp_enable(L, &b->def.material, b->def.op, err) < 0)) {
        sq_level_free(L);
        return sq_err_prefix(err, "body '%s' level %d", b->name, k);
    }
    if (sq_level_choose_step(L, &b->def.material, b->def.frame_dt, b->def.step_fraction, err) < 0 ||
        sq_level_choose_step_sharp(L, &b->def.material, b->def.frame_dt, b->def.step_fraction, SQ_LANCZOS_ITERS,
                                   err) < 0) {
        sq_level_free(L);
        return sq_err_prefix(err, "body '%s' level %d (%d nodes)", b->name, k, b->def.levels[k]->nnodes);
    }
    b->mask[k] = sq_malloc((size_t)L->n);
    memset(b->mask[k], 1, (size_t)L->n);
    b->hold_of[k] = sq_malloc(sizeof(int) * (size_t)L->n);
    b->held[k] = sq_calloc((size_t)L->n, 1);
    b->held_list[k] = sq_malloc(sizeof(int) * (size_t)L->n);
    b->nheld[k] = 0;
    for (int i = 0; i < L->n; i++)
        b->hold_of[k][i] = -1;
    b->ready[k] = 1;
    return 0;
}

/* forget which nodes of level k a tool held (released: reset or lod change) */
static void clear_held(sq_body *b, int k)
{
    for (int h = 0; h < b->nheld[k]; h++)
        b->held[k][b->held_list[k][h]] = 0;
    b->nheld[k] = 0;
}

/* copy displacement and velocity from level src to level dst by interpolation */
static void transfer_state(sq_body *b, int src, int dst)
{
    if (src == dst)
        return;
    sq_level *S = &b->level[src], *T = &b->level[dst];
    for (int i = 0; i < T->n; i++) {
        double bary[4];
        int t = sq_mesh_locate(S->mesh, T->mesh->x + 3 * (size_t)i, bary);
        if (t < 0)
            continue;
        interp3(S->mesh, S->d, t, bary, T->d + 3 * (size_t)i);
        interp3(S->mesh, S->v, t, bary, T->v + 3 * (size_t)i);
    }
}

/* per finest surface vertex: tet and barycentrics in the fixed level, and its nearest node */
static void prepare_surface_map(sq_body *b)
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
        const double *d = b->level[b->fine].d + 3 * (size_t)fm->surf_nodes[s];
        u[0] = d[0];
        u[1] = d[1];
        u[2] = d[2];
        return;
    }
    interp3(b->def.levels[b->cur], b->level[b->cur].d, b->surf_tet[s], b->surf_bary + 4 * (size_t)s, u);
}

static void set_lod_levels_fixed(sq_body *b)
{
    memset(b->node_level, (unsigned char)b->cur, (size_t)b->def.levels[b->fine]->nnodes);
}

/* ---- create / destroy ------------------------------------------------------------------- */

#define COROT_ADAPTIVE_MSG                                                                                 \
    "corotational elasticity runs in fixed lod mode only (adaptive mode does not support it yet): use "    \
    "\"lod\": {\"mode\": \"fixed\"} with \"elasticity\": \"corotational\", or \"elasticity\": \"linear\" " \
    "with adaptive lod"
#define COROT_PAPER_MSG                                                                                    \
    "corotational elasticity needs the fem operator (the paper operator has no corotational form here): "  \
    "use \"operator\": \"fem\" with \"elasticity\": \"corotational\", or \"elasticity\": \"linear\" with "  \
    "the paper operator"

#define NODAL_MSG                                                                                          \
    "nodal pressure tets (\"pressure\": \"nodal\") run with the fem operator, linear elasticity and fixed "   \
    "lod only: use those, or \"pressure\": \"element\""

/* is nodal pressure allowed with the rest? */
static int check_pressure(int nodal, sq_elasticity_kind e, sq_operator_kind op, sq_lod_mode mode, sq_err *err)
{
    if (nodal && (e != SQ_ELASTICITY_LINEAR || op != SQ_OPERATOR_FEM || mode != SQ_LOD_FIXED))
        return sq_err_set(err, NODAL_MSG);
    return 0;
}

/* is elasticity e allowed with operator op and lod mode? 0, or -1 + err naming the combination */
static int check_elasticity(sq_elasticity_kind e, sq_operator_kind op, sq_lod_mode mode, sq_err *err)
{
    if (e != SQ_ELASTICITY_LINEAR && e != SQ_ELASTICITY_COROTATIONAL)
        return sq_err_set(err, "elasticity %d is unknown: use linear or corotational", (int)e);
    if (e == SQ_ELASTICITY_COROTATIONAL && op != SQ_OPERATOR_FEM)
        return sq_err_set(err, COROT_PAPER_MSG);
    if (e == SQ_ELASTICITY_COROTATIONAL && mode == SQ_LOD_ADAPTIVE)
        return sq_err_set(err, COROT_ADAPTIVE_MSG);
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
    if (check_elasticity(def->elasticity, def->op, def->lod.mode, err) < 0 ||
        check_pressure(def->nodal_pressure, def->elasticity, def->op, def->lod.mode, err) < 0)
        return -1;
    return sq_material_check(&def->material, err);
}

static int check_lod(const sq_body *b, const sq_lod_def *lod, sq_err *err)
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
    return 0;
}

sq_body *sq_body_create(const sq_body_def *def, sq_err *err)
{
    if (check_def(def, err) < 0)
        return NULL;
    sq_body *b = sq_calloc(1, sizeof *b);
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
    if (check_lod(b, &def->lod, err) < 0) {
        sq_body_destroy(b);
        return NULL;
    }
    b->cur = def->lod.level;
    if (ensure_level(b, b->cur, err) < 0) {
        sq_body_destroy(b);
        return NULL;
    }
    if (b->level[b->cur].nfree == 0) {
        sq_err_set(err, "body '%s': the constraints fix all %d nodes of level %d, so nothing can move; "
                        "shrink the fixed region", b->name, b->level[b->cur].n, b->cur);
        sq_body_destroy(b);
        return NULL;
    }
    if (def->lod.mode == SQ_LOD_ADAPTIVE) {
        for (int k = 0; k < b->nuse; k++)
            if (ensure_level(b, k, err) < 0) {
                sq_body_destroy(b);
                return NULL;
            }
        b->lod = sq_lod_create(b->level, b->nuse, &b->def.lod, err);
        if (!b->lod) {
            sq_err_prefix(err, "body '%s'", b->name);
            sq_body_destroy(b);
            return NULL;
        }
        sq_lod_set_loads(b->lod, &b->def.material, b->def.gravity); /* set-up before frame 1 */
        sq_lod_node_levels(b->lod, b->node_level);
    } else {
        prepare_surface_map(b);
        set_lod_levels_fixed(b);
    }
    return b;
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
    free(b->surf_tet);
    free(b->surf_bary);
    free(b->surf_near);
    free(b->node_level);
    free(b->holds);
    free(b->khold);
    free(b->kcount);
    free(b);
}

/* ---- parameters ------------------------------------------------------------------------- */

int sq_body_set_material(sq_body *b, const sq_material *m, sq_operator_kind op, sq_err *err)
{
    double E, nu;
    sq_material_E_nu(m, &E, &nu);
    if (sq_material_check(m, err) < 0)
        return -1;
    if (op != SQ_OPERATOR_FEM && op != SQ_OPERATOR_PAPER)
        return sq_err_set(err, "operator %d is unknown: use fem or paper", (int)op);
    if (check_elasticity(b->def.elasticity, op, b->def.lod.mode, err) < 0 ||
        check_pressure(b->def.nodal_pressure, b->def.elasticity, op, b->def.lod.mode, err) < 0)
        return -1;
    /* build every loaded level anew; swap only when all succeed */
    sq_level fresh[SQ_MAX_LEVELS];
    for (int k = 0; k < SQ_MAX_LEVELS; k++) {
        if (!b->ready[k])
            continue;
        if (sq_level_init(&fresh[k], b->def.levels[k], m, op, b->def.constraints, b->def.nconstraints, err) < 0 ||
            (b->def.elasticity == SQ_ELASTICITY_COROTATIONAL && sq_level_corot_enable(&fresh[k], m, op, err) < 0) ||
            (b->def.nodal_pressure && sq_level_anp_enable(&fresh[k], m, op, err) < 0) ||
            sq_level_choose_step(&fresh[k], m, b->def.frame_dt, b->def.step_fraction, err) < 0 ||
            /* the Lanczos estimate only where it is used (a set flood must stay cheap) */
            (b->def.sharp_step &&
             sq_level_choose_step_sharp(&fresh[k], m, b->def.frame_dt, b->def.step_fraction, SQ_LANCZOS_ITERS,
                                        err) < 0)) {
            if (fresh[k].n)
                sq_level_free(&fresh[k]);
            for (int j = 0; j < k; j++)
                if (b->ready[j])
                    sq_level_free(&fresh[j]);
            return sq_err_prefix(err, "refused E=%.4g Pa nu=%.4g (mu=%.4g, lambda=%.4g), level %d", E, nu,
                                 m->mu, m->lambda, k);
        }
    }
    for (int k = 0; k < SQ_MAX_LEVELS; k++) {
        if (!b->ready[k])
            continue;
        size_t n3 = 3 * (size_t)b->level[k].n;
        memcpy(fresh[k].d, b->level[k].d, sizeof(double) * n3);
        memcpy(fresh[k].v, b->level[k].v, sizeof(double) * n3);
        sq_level_corot_copy(&fresh[k], &b->level[k]);
        sq_level_free(&b->level[k]);
        b->level[k] = fresh[k]; /* same address: the lod module's pointer stays valid */
    }
    b->def.material = *m;
    b->def.op = op;
    b->sleeping = 0;
    b->calm = 0;
    return 0;
}

int sq_body_set_lod(sq_body *b, const sq_lod_def *lod, sq_err *err)
{
    if (check_lod(b, lod, err) < 0)
        return -1;
    int was_adaptive = b->def.lod.mode == SQ_LOD_ADAPTIVE;
    if (check_elasticity(b->def.elasticity, b->def.op, lod->mode, err) < 0 ||
        check_pressure(b->def.nodal_pressure, b->def.elasticity, b->def.op, lod->mode, err) < 0)
        return -1;
    if (lod->mode == SQ_LOD_ADAPTIVE) {
        for (int k = 0; k < b->nuse; k++)
            if (ensure_level(b, k, err) < 0)
                return -1;
        if (was_adaptive) {
            if (sq_lod_set_def(b->lod, lod, err) < 0)
                return -1;
        } else {
            sq_lod *l = sq_lod_create(b->level, b->nuse, lod, err);
            if (!l)
                return -1;
            b->lod = l;
            b->def.lod = *lod;
            sq_body_reset(b);
        }
        sq_lod_set_loads(b->lod, &b->def.material, b->def.gravity);
        b->def.lod = *lod;
        sq_lod_node_levels(b->lod, b->node_level);
    } else {
        if (ensure_level(b, lod->level, err) < 0)
            return -1;
        int from = was_adaptive ? b->fine : b->cur;
        if (from != lod->level) {
            transfer_state(b, from, lod->level);
            sq_level_corot_converge(&b->level[lod->level]);
        }
        if (was_adaptive) {
            sq_lod_destroy(b->lod);
            b->lod = NULL;
        }
        b->def.lod = *lod;
        b->cur = lod->level;
        prepare_surface_map(b);
        set_lod_levels_fixed(b);
    }
    for (int k = 0; k < SQ_MAX_LEVELS; k++)
        if (b->ready[k])
            clear_held(b, k);
    b->sleeping = 0;
    b->calm = 0;
    return 0;
}

void sq_body_reset(sq_body *b)
{
    for (int k = 0; k < SQ_MAX_LEVELS; k++) {
        if (!b->ready[k])
            continue;
        size_t n3 = 3 * (size_t)b->level[k].n;
        memset(b->level[k].d, 0, sizeof(double) * n3);
        memset(b->level[k].v, 0, sizeof(double) * n3);
        memset(b->level[k].f, 0, sizeof(double) * n3);
        sq_level_corot_reset(&b->level[k]);
        clear_held(b, k);
    }
    if (b->lod) {
        sq_lod_reset(b->lod);
        sq_lod_node_levels(b->lod, b->node_level);
    }
    for (int t = 0; t < SQ_MAX_TOOLS; t++)
        b->grab[t].id = -1;
    b->sleeping = 0;
    b->calm = 0;
}

int sq_body_set_elasticity(sq_body *b, sq_elasticity_kind e, sq_err *err)
{
    if (check_elasticity(e, b->def.op, b->def.lod.mode, err) < 0 ||
        check_pressure(b->def.nodal_pressure, e, b->def.op, b->def.lod.mode, err) < 0)
        return -1;
    if (e == b->def.elasticity)
        return 0;
    for (int k = 0; k < SQ_MAX_LEVELS; k++) {
        if (!b->ready[k])
            continue;
        if (e == SQ_ELASTICITY_COROTATIONAL) {
            if (sq_level_corot_enable(&b->level[k], &b->def.material, b->def.op, err) < 0) {
                for (int j = 0; j < k; j++)
                    sq_level_corot_free(&b->level[j]);
                return -1;
            }
            sq_level_corot_converge(&b->level[k]);
        } else {
            sq_level_corot_free(&b->level[k]);
        }
    }
    b->def.elasticity = e;
    b->sleeping = 0;
    b->calm = 0;
    return 0;
}

int sq_body_set_pressure(sq_body *b, int nodal, sq_err *err)
{
    nodal = nodal != 0;
    if (check_pressure(nodal, b->def.elasticity, b->def.op, b->def.lod.mode, err) < 0)
        return -1;
    if (nodal == b->def.nodal_pressure)
        return 0;
    for (int k = 0; k < SQ_MAX_LEVELS; k++) {
        if (!b->ready[k])
            continue;
        if (nodal) {
            if (sq_level_anp_enable(&b->level[k], &b->def.material, b->def.op, err) < 0) {
                for (int j = 0; j < k; j++)
                    sq_level_anp_free(&b->level[j]);
                return -1;
            }
        } else {
            sq_level_anp_free(&b->level[k]);
        }
    }
    b->def.nodal_pressure = nodal;
    b->sleeping = 0;
    b->calm = 0;
    return 0;
}

void sq_body_set_sleep(sq_body *b, int frames, double ke_speed, double residual)
{
    b->sleep_frames = frames;
    b->sleep_ke_speed = ke_speed;
    b->sleep_residual = residual;
    b->calm = 0;
    b->sleeping = 0;
}

/* ---- the frame -------------------------------------------------------------------------- */

/* health: non-finite values, displacement beyond 10 bbox diagonals, or kinetic energy above
 * 0.5 M (10 diag / frame_dt)^2 (a mean speed of ten diagonals per frame); returns a reason */
static const char *health(const sq_body *b, double *value)
{
    double dlim2 = 100 * b->diag * b->diag;
    for (int k = 0; k < SQ_MAX_LEVELS; k++) {
        if (!b->ready[k])
            continue;
        if (b->def.lod.mode == SQ_LOD_FIXED && k != b->cur)
            continue;
        const sq_level *L = &b->level[k];
        double ke = 0, M = 0;
        /* adaptive: the active nodes (ghosts are combinations of them) */
        int na = L->n;
        const int *al = b->lod ? sq_lod_active_list(b->lod, k, &na) : NULL;
        for (int r = 0; r < na; r++) {
            int i = al ? al[r] : r;
            const double *d = L->d + 3 * (size_t)i, *v = L->v + 3 * (size_t)i;
            double dd = d[0] * d[0] + d[1] * d[1] + d[2] * d[2];
            double vv = v[0] * v[0] + v[1] * v[1] + v[2] * v[2];
            if (!isfinite(dd) || !isfinite(vv)) {
                *value = (double)i;
                return "non-finite displacement or velocity";
            }
            if (dd > dlim2) {
                *value = sqrt(dd);
                return "displacement beyond 10 bounding-box diagonals";
            }
            ke += 0.5 * L->mass[i] * vv;
            M += L->mass[i];
        }
        double vlim = 10 * b->diag / b->def.frame_dt;
        if (ke > 0.5 * M * vlim * vlim) {
            *value = ke;
            return "kinetic energy above 0.5 M (10 diag / frame_dt)^2";
        }
    }
    return NULL;
}

/* the nodes of level k held in the frame just done (hold list of that level) */
static void mark_held(sq_body *b, int k, const sq_hold *holds, int nholds)
{
    clear_held(b, k);
    for (int h = 0; h < nholds; h++) {
        int i = holds[h].node;
        if (!b->held[k][i]) {
            b->held[k][i] = 1;
            b->held_list[k][b->nheld[k]++] = i;
        }
    }
}

/* residual of level L from its last force pass, over active nodes (the list active of
 * nactive nodes; all when NULL) that no tool held (held may be NULL): a held node's
 * unbalanced force is the tool's reaction */
static double level_residual(const sq_level *L, const double g[3], const int *active, int nactive,
                             const unsigned char *held)
{
    double gn = sqrt(g[0] * g[0] + g[1] * g[1] + g[2] * g[2]);
    double r = 0;
    int na = active ? nactive : L->n;
    for (int q = 0; q < na; q++) {
        int i = active ? active[q] : q;
        if (L->fixed[i] == 7 || (held && held[i]))
            continue;
        double s = 0;
        for (int c = 0; c < 3; c++)
            if (!(L->fixed[i] & (1u << c)))
                s += L->f[3 * i + c] * L->f[3 * i + c];
        s = sqrt(s) / (L->mass[i] * (gn > 0 ? gn : 1));
        if (s > r)
            r = s;
    }
    return r;
}

static void frame_fixed(sq_body *b, const sq_hold *holds, int nholds, int ntools, double (*force)[3],
                        sq_frame_profile *prof)
{
    sq_level *L = &b->level[b->cur];
    const sq_material *mat = &b->def.material;
    const double *g = b->def.gravity;
    int *hold_of = b->hold_of[b->cur];
    unsigned char *mask = b->mask[b->cur];

    /* map holds to nodes of the simulated level: same node at the finest level, else the
     * nearest level-k node gets the hold's translation (averaged when several map there) */
    if (b->cap_khold < nholds) {
        b->cap_khold = nholds;
        b->khold = sq_realloc(b->khold, sizeof(sq_hold) * (size_t)nholds);
        b->kcount = sq_realloc(b->kcount, sizeof(int) * (size_t)nholds);
    }
    int nk = 0;
    const sq_mesh *fm = b->def.levels[b->fine];
    int *count = b->kcount;
    for (int h = 0; h < nholds; h++) {
        int node = holds[h].node, knode;
        double t[3];
        if (b->cur == b->fine) {
            knode = node;
            memcpy(t, holds[h].target, sizeof t);
        } else {
            int s = fm->surf_of_node[node];
            double u[3];
            sq_body_surface_disp(b, s, u);
            knode = b->surf_near[s];
            for (int c = 0; c < 3; c++)
                t[c] = L->d[3 * knode + c] + holds[h].target[c] - u[c];
        }
        int idx = hold_of[knode];
        if (idx < 0) {
            idx = nk++;
            hold_of[knode] = idx;
            b->khold[idx].node = knode;
            b->khold[idx].tool = holds[h].tool;
            memset(b->khold[idx].target, 0, sizeof b->khold[idx].target);
            count[idx] = 0;
        }
        for (int c = 0; c < 3; c++)
            b->khold[idx].target[c] += t[c];
        count[idx]++;
    }
    /* held nodes: displacement set to the target, velocity to (target - old) / frame_dt */
    for (int h = 0; h < nk; h++) {
        sq_hold *kh = &b->khold[h];
        int i = kh->node;
        for (int c = 0; c < 3; c++) {
            kh->target[c] /= count[h];
            double old = L->d[3 * i + c];
            L->d[3 * i + c] = kh->target[c];
            L->v[3 * i + c] = (kh->target[c] - old) / b->def.frame_dt;
        }
        mask[i] = 0;
        hold_of[i] = -1;
    }

    /* substeps: forces on all nodes, feedback on held nodes, integrate the others */
    /* substeps: 2^n at the Gershgorin bound, or with sharp_step the sharp bound's step, any
     * integer count (adaptive mode keeps 2^n per level) */
    int nsub = b->def.sharp_step ? L->nsub : 1 << L->substeps_log2;
    double sdt = b->def.sharp_step ? L->dt_fixed : L->dt;
    double inv = 1.0 / nsub;
    for (int s = 0; s < nsub; s++) {
        if ((s & 15) == 15 && sq_cancelled())
            break; /* the server is stopping: the frame is abandoned */
        sq_level_step(L, mat, g, sdt, nk ? mask : NULL); /* L->f: forces before the update */
        for (int h = 0; h < nk; h++) {
            int i = b->khold[h].node, t = b->khold[h].tool;
            if (force && t >= 0 && t < ntools)
                for (int c = 0; c < 3; c++)
                    force[t][c] += inv * (L->f[3 * i + c] - L->mass[i] * g[c]);
        }
    }
    for (int h = 0; h < nk; h++)
        mask[b->khold[h].node] = 1;
    mark_held(b, b->cur, b->khold, nk);

    if (prof) {
        prof->node_updates = (long)(L->n - nk) * nsub;
        prof->active[b->cur] = L->n;
        prof->substeps[b->cur] = nsub;
        prof->awake_nodes = L->n;
    }
}

int sq_body_frame(sq_body *b, const sq_tool *tools, int ntools, sq_tool_feedback *feedback,
                  sq_frame_profile *prof, double frame_budget_s)
{
    double t0 = sq_now();
    sq_frame_profile local;
    if (!prof)
        prof = &local;
    memset(prof, 0, sizeof *prof);
    if (ntools < 0 || !tools)
        ntools = 0;
    if (ntools > SQ_MAX_TOOLS)
        ntools = SQ_MAX_TOOLS;
    double force[SQ_MAX_TOOLS][3];
    memset(force, 0, sizeof force);

    /* tools -> holds on finest surface nodes */
    int tool_nodes[SQ_MAX_TOOLS];
    int nholds = sq_body_tool_holds(b, tools, ntools, tool_nodes);
    double t1 = sq_now();
    prof->t_tools = t1 - t0;

    if (b->sleeping && nholds == 0) {
        prof->sleeping = 1;
        prof->sleeping_nodes = b->level[b->cur].n;
        /* asleep, the resolution stays what it was: active nodes are reported as they stand
         * (nothing is updated: node_updates stays 0) */
        for (int k = 0; k < SQ_MAX_LEVELS; k++) {
            if (!b->ready[k])
                continue;
            if (b->def.lod.mode == SQ_LOD_ADAPTIVE) {
                int na = 0;
                sq_lod_active_list(b->lod, k, &na);
                prof->active[k] = na;
            } else if (k == b->cur) {
                prof->active[k] = b->level[k].n;
            }
        }
    } else {
        b->sleeping = 0;
        if (b->def.lod.mode == SQ_LOD_ADAPTIVE) {
            sq_lod_frame_in in = {.mat = &b->def.material, .frame_dt = b->def.frame_dt, .holds = b->holds,
                                  .nholds = nholds, .ntools = ntools, .budget_s = frame_budget_s};
            memcpy(in.gravity, b->def.gravity, sizeof in.gravity);
            sq_lod_frame(b->lod, &in, force, prof);
            mark_held(b, b->fine, b->holds, nholds);
            sq_lod_node_levels(b->lod, b->node_level);
        } else {
            frame_fixed(b, b->holds, nholds, ntools, force, prof);
        }
    }
    double t2 = sq_now();
    prof->t_integrate = SQ_MAX(0.0, t2 - t1 - prof->t_pull - prof->t_push - prof->t_adapt);

    /* health */
    double value = 0;
    const char *why = prof->sleeping ? NULL : health(b, &value);
    if (why) {
        sq_body_reset(b);
        prof->reset = 1;
        snprintf(prof->event, sizeof prof->event, "blow-up detected: %s (%.3g) in body '%.40s'; body reset to rest",
                 why, value, b->name);
        memset(force, 0, sizeof force);
    } else if (!prof->sleeping) {
        /* sleep: calm (slow and balanced) with no tool for sleep_frames frames in a row */
        double ke = sq_body_kinetic_energy(b), M = 0, res = 0;
        for (int k = 0; k < SQ_MAX_LEVELS; k++) {
            if (!b->ready[k] || (b->def.lod.mode == SQ_LOD_FIXED && k != b->cur))
                continue;
            int na = b->level[k].n;
            const int *al = b->lod ? sq_lod_active_list(b->lod, k, &na) : NULL;
            for (int r = 0; r < na; r++)
                M += b->level[k].mass[al ? al[r] : r];
            res = SQ_MAX(res, level_residual(&b->level[k], b->def.gravity, al, na, NULL));
        }
        double vrms = M > 0 ? sqrt(2 * ke / M) : 0;
        int calm = nholds == 0 && vrms < b->sleep_ke_speed * b->diag && res < b->sleep_residual;
        b->calm = calm ? b->calm + 1 : 0;
        if (b->sleep_frames > 0 && b->calm >= b->sleep_frames) {
            b->sleeping = 1;
            snprintf(prof->event, sizeof prof->event, "body '%.60s' at rest: sleeping until touched", b->name);
        }
    }
    prof->t_health = sq_now() - t2;

    if (feedback)
        for (int t = 0; t < ntools; t++) {
            feedback[t].id = tools[t].id;
            feedback[t].force[0] = force[t][0];
            feedback[t].force[1] = force[t][1];
            feedback[t].force[2] = force[t][2];
            feedback[t].nnodes = tool_nodes[t];
        }
    if (prof->sleeping) {
        prof->awake_nodes = 0;
        prof->node_updates = 0;
    }
    prof->t_total = sq_now() - t0;
    return 0;
}

/* ---- views ------------------------------------------------------------------------------ */

const sq_body_def *sq_body_get_def(const sq_body *b) { return &b->def; }
int sq_body_nlevels(const sq_body *b) { return b->nuse; }

const sq_mesh *sq_body_mesh(const sq_body *b, int level)
{
    return level >= 0 && level < b->nuse ? b->def.levels[level] : NULL;
}

double sq_body_level_dt(const sq_body *b, int level)
{
    if (!(level >= 0 && level < SQ_MAX_LEVELS && b->ready[level]))
        return 0;
    return b->def.lod.mode == SQ_LOD_FIXED && b->def.sharp_step ? b->level[level].dt_fixed : b->level[level].dt;
}

double sq_body_level_bound(const sq_body *b, int level)
{
    if (!(level >= 0 && level < SQ_MAX_LEVELS && b->ready[level]))
        return 0;
    return b->def.lod.mode == SQ_LOD_FIXED && b->def.sharp_step ? b->level[level].bound_sharp
                                                                 : b->level[level].bound;
}

const double *sq_body_displacement(const sq_body *b, int level)
{
    sq_lod_flush(b->lod); /* ghosts nothing read during the frame, pushed now (no-op if fixed) */
    return level >= 0 && level < SQ_MAX_LEVELS && b->ready[level] ? b->level[level].d : NULL;
}

const double *sq_body_velocity(const sq_body *b, int level)
{
    sq_lod_flush(b->lod);
    return level >= 0 && level < SQ_MAX_LEVELS && b->ready[level] ? b->level[level].v : NULL;
}

const unsigned char *sq_body_node_level(const sq_body *b) { return b->node_level; }
const sq_mesh *sq_body_surface_mesh(const sq_body *b) { return b->def.levels[b->fine]; }
int sq_body_is_sleeping(const sq_body *b) { return b->sleeping; }

int sq_body_inverted_tets(const sq_body *b)
{
    int k = b->def.lod.mode == SQ_LOD_ADAPTIVE ? b->fine : b->cur;
    return sq_level_corot_inverted(&b->level[k]);
}

sq_level *sq_body_level(sq_body *b, int level)
{
    sq_lod_flush(b->lod);
    return level >= 0 && level < SQ_MAX_LEVELS && b->ready[level] ? &b->level[level] : NULL;
}

int sq_body_fixed_level(const sq_body *b) { return b->cur; }

void sq_body_surface_state(const sq_body *b, float *xyz, unsigned char *level)
{
    const sq_mesh *fm = b->def.levels[b->fine];
    for (int s = 0; s < fm->nsurf; s++) {
        int node = fm->surf_nodes[s];
        if (xyz) {
            double u[3];
            sq_body_surface_disp(b, s, u);
            for (int c = 0; c < 3; c++)
                xyz[3 * s + c] = (float)(fm->x[3 * node + c] + u[c]);
        }
        if (level)
            level[s] = b->node_level[node];
    }
}

int sq_body_probe(const sq_body *b, const double p[3], double u[3])
{
    /* outside: the finest mesh's containing tet has a barycentric below -1e-6 */
    double bary[4];
    const sq_mesh *fm = b->def.levels[b->fine];
    int t = sq_mesh_locate(fm, p, bary);
    if (t < 0)
        return -1;
    for (int k = 0; k < 4; k++)
        if (bary[k] < -1e-6)
            return -1;
    int k = b->def.lod.mode == SQ_LOD_ADAPTIVE ? b->fine : b->cur;
    if (k != b->fine) {
        t = sq_mesh_locate(b->def.levels[k], p, bary);
        if (t < 0)
            return -1;
    }
    sq_lod_flush(b->lod);
    interp3(b->def.levels[k], b->level[k].d, t, bary, u);
    return 0;
}

double sq_body_kinetic_energy(const sq_body *b)
{
    double ke = 0;
    for (int k = 0; k < SQ_MAX_LEVELS; k++) {
        if (!b->ready[k] || (b->def.lod.mode == SQ_LOD_FIXED && k != b->cur))
            continue;
        const sq_level *L = &b->level[k];
        int na = L->n;
        const int *al = b->lod ? sq_lod_active_list(b->lod, k, &na) : NULL;
        for (int r = 0; r < na; r++) {
            int i = al ? al[r] : r;
            const double *v = L->v + 3 * (size_t)i;
            ke += 0.5 * L->mass[i] * (v[0] * v[0] + v[1] * v[1] + v[2] * v[2]);
        }
    }
    return ke;
}

/* 0.5 d.K d of level k (the corotational energy with corotational elasticity) */
double sq_level_elastic_energy(const sq_level *L)
{
    if (L->corot)
        return sq_level_corot_energy(L);
    if (L->anp)
        return sq_level_anp_energy(L);
    double e = 0;
    for (int i = 0; i < L->n; i++) {
        const double *di = L->d + 3 * (size_t)i;
        for (int p = L->row_start[i]; p < L->row_start[i + 1]; p++) {
            const double *B = L->K + 9 * (size_t)p, *dj = L->d + 3 * (size_t)L->col[p];
            for (int r = 0; r < 3; r++)
                e += di[r] * (B[3 * r] * dj[0] + B[3 * r + 1] * dj[1] + B[3 * r + 2] * dj[2]);
        }
    }
    return 0.5 * e;
}

double sq_body_elastic_energy(const sq_body *b)
{
    sq_lod_flush(b->lod);
    int k = b->def.lod.mode == SQ_LOD_ADAPTIVE ? b->fine : b->cur;
    return sq_level_elastic_energy(&b->level[k]);
}

double sq_body_residual(const sq_body *b)
{
    /* fresh force pass on a copy of the simulated level's scratch (the state is unchanged) */
    int k = b->def.lod.mode == SQ_LOD_ADAPTIVE ? b->fine : b->cur;
    sq_lod_flush(b->lod);
    sq_level L = b->level[k];
    size_t n3 = 3 * (size_t)L.n;
    L.f = sq_malloc(sizeof(double) * n3);
    L.w = sq_malloc(sizeof(double) * n3);
    L.acc = sq_calloc(n3 + 1, sizeof(double)); /* own accumulator: the body's is left untouched */
    sq_level_forces(&L, &b->def.material, b->def.gravity, NULL);
    double r = level_residual(&L, b->def.gravity, NULL, 0, b->held[k]);
    free(L.f);
    free(L.w);
    free(L.acc);
    return r;
}

int sq_body_write_vtk(const sq_body *b, const char *path, sq_err *err)
{
    int k = b->def.lod.mode == SQ_LOD_ADAPTIVE ? b->fine : b->cur;
    sq_lod_flush(b->lod);
    const sq_mesh *m = b->def.levels[k];
    int *lev = sq_malloc(sizeof(int) * (size_t)m->nnodes);
    for (int i = 0; i < m->nnodes; i++)
        lev[i] = b->def.lod.mode == SQ_LOD_ADAPTIVE ? b->node_level[i] : k;
    int rc = sq_mesh_write_vtk(m, path, b->level[k].d, b->level[k].v, lev, err);
    free(lev);
    return rc;
}
