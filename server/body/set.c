/* set.c - run-time changes of a body: material / operator, lod, elasticity, pressure, sleep
 * tolerances, reset. Each is validated first; on refusal nothing changes. */
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "lod/lod.h"
#include "body/body_internal.h"

int sq_body_set_material(sq_body *b, const sq_material *m, sq_operator_kind op, sq_err *err)
{
    double E, nu;
    sq_material_E_nu(m, &E, &nu);
    if (sq_material_check(m, err) < 0)
        return -1;
    if (op != SQ_OPERATOR_FEM && op != SQ_OPERATOR_PAPER)
        return sq_err_set(err, "operator %d is unknown: use fem or paper", (int)op);
    if (sq_body_check_elasticity(b->def.elasticity, op, b->def.lod.mode, err) < 0 ||
        sq_body_check_pressure(b->def.nodal_pressure, b->def.elasticity, op, b->def.lod.mode, err) < 0)
        return -1;
    /* build every loaded level anew; swap only when all succeed */
    sq_level fresh[SQ_MAX_LEVELS];
    for (int k = 0; k < SQ_MAX_LEVELS; k++) {
        if (!b->ready[k])
            continue;
        if (sq_level_init(&fresh[k], b->def.levels[k], m, op, b->def.constraints, b->def.nconstraints, err) < 0 ||
            (b->def.elasticity == SQ_ELASTICITY_COROTATIONAL && sq_level_corot_enable(&fresh[k], m, op, err) < 0) ||
            (b->def.nodal_pressure && sq_level_anp_enable(&fresh[k], m, op, b->def.nodal_pressure, err) < 0) ||
            (b->def.integrator == SQ_INTEGRATOR_IMPLICIT
                 ? (sq_body_explicit_estimate(b, &fresh[k], m, !b->def.sharp_step), 0)
                 : sq_level_choose_step(&fresh[k], m, b->def.frame_dt, b->def.step_fraction, err)) < 0 ||
            /* the Lanczos estimate only where it is used (a set flood must stay cheap) */
            (b->def.sharp_step && b->def.integrator != SQ_INTEGRATOR_IMPLICIT &&
             sq_level_choose_step_sharp(&fresh[k], m, b->def.frame_dt, b->def.step_fraction, SQ_LANCZOS_ITERS,
                                        err) < 0)) {
            if (fresh[k].model.n)
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
        size_t n3 = 3 * (size_t)b->level[k].model.n;
        memcpy(fresh[k].state.d, b->level[k].state.d, sizeof(double) * n3);
        memcpy(fresh[k].state.v, b->level[k].state.v, sizeof(double) * n3);
        sq_level_corot_copy(&fresh[k].state, &b->level[k].state);
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
    if (sq_body_check_lod(b, lod, err) < 0)
        return -1;
    int was_adaptive = b->def.lod.mode == SQ_LOD_ADAPTIVE;
    if (sq_body_check_elasticity(b->def.elasticity, b->def.op, lod->mode, err) < 0 ||
        sq_body_check_pressure(b->def.nodal_pressure, b->def.elasticity, b->def.op, lod->mode, err) < 0 ||
        sq_body_check_integrator(b->def.integrator, &b->def.implicit, lod->mode, err) < 0)
        return -1;
    if (lod->mode == SQ_LOD_ADAPTIVE) {
        for (int k = 0; k < b->nuse; k++)
            if (sq_body_ensure_level(b, k, err) < 0)
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
        sq_lod_set_step_rule(b->lod, b->def.sharp_step, b->def.step_fraction);
        b->def.lod = *lod;
        sq_lod_node_levels(b->lod, b->node_level);
    } else {
        if (sq_body_ensure_level(b, lod->level, err) < 0)
            return -1;
        int from = sq_body_sim_level(b); /* the lod mode is still the old one */
        if (from != lod->level) {
            sq_body_transfer_state(b, from, lod->level);
            sq_level_corot_converge(&b->level[lod->level].model, &b->level[lod->level].state);
        }
        if (was_adaptive) {
            sq_lod_destroy(b->lod);
            b->lod = NULL;
        }
        b->def.lod = *lod;
        b->cur = lod->level;
        sq_body_prepare_surface_map(b);
        sq_body_set_levels_fixed(b);
    }
    b->tmap = NULL; /* an adaptive target's map is the lod's: made again at the next target */
    for (int k = 0; k < SQ_MAX_LEVELS; k++)
        if (b->ready[k])
            sq_body_clear_held(b, k);
    b->sleeping = 0;
    b->calm = 0;
    return 0;
}

void sq_body_reset(sq_body *b)
{
    b->boost = 0;
    b->boost_calm = 0;
    for (int k = 0; k < SQ_MAX_LEVELS; k++) {
        if (!b->ready[k])
            continue;
        size_t n3 = 3 * (size_t)b->level[k].model.n;
        memset(b->level[k].state.d, 0, sizeof(double) * n3);
        memset(b->level[k].state.v, 0, sizeof(double) * n3);
        memset(b->level[k].state.f, 0, sizeof(double) * n3);
        sq_level_corot_reset(&b->level[k].state);
        sq_body_clear_held(b, k);
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
    if (sq_body_check_elasticity(e, b->def.op, b->def.lod.mode, err) < 0 ||
        sq_body_check_pressure(b->def.nodal_pressure, e, b->def.op, b->def.lod.mode, err) < 0)
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
            sq_level_corot_converge(&b->level[k].model, &b->level[k].state);
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
    if (nodal < SQ_PRESSURE_ELEMENT || nodal > SQ_PRESSURE_SMOOTHED)
        return sq_err_set(err, "pressure %d is unknown: use element, nodal or smoothed", nodal);
    if (sq_body_check_pressure(nodal, b->def.elasticity, b->def.op, b->def.lod.mode, err) < 0)
        return -1;
    if (nodal == b->def.nodal_pressure)
        return 0;
    for (int k = 0; k < SQ_MAX_LEVELS; k++) {
        if (!b->ready[k])
            continue;
        if (nodal) {
            if (sq_level_anp_enable(&b->level[k], &b->def.material, b->def.op, nodal, err) < 0) {
                for (int j = 0; j < k; j++)
                    sq_level_anp_free(&b->level[j]);
                return -1;
            }
        } else {
            sq_level_anp_free(&b->level[k]);
        }
    }
    /* the sharp bound is the Lanczos estimate of the operator the step applies: made again for
     * the new one (it cannot fail: every operator is under the element-wise Gershgorin ceiling
     * the level was accepted with, so its integer count is at most that rule's 2^n) */
    b->def.nodal_pressure = nodal;
    if (b->def.sharp_step)
        for (int k = 0; k < SQ_MAX_LEVELS; k++)
            if (b->ready[k] && sq_level_choose_step_sharp(&b->level[k], &b->def.material, b->def.frame_dt,
                                                          b->def.step_fraction, SQ_LANCZOS_ITERS, err) < 0)
                return -1;
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

int sq_body_set_integrator(sq_body *b, sq_integrator_kind k, const sq_implicit_def *imp, sq_err *err)
{
    if (sq_body_check_integrator(k, imp, b->def.lod.mode, err) < 0)
        return -1;
    if (k == SQ_INTEGRATOR_EXPLICIT && b->def.integrator == SQ_INTEGRATOR_IMPLICIT) {
        /* back to explicit: every loaded level must have an explicit step within 2^20 substeps */
        for (int j = 0; j < SQ_MAX_LEVELS; j++) {
            if (!b->ready[j])
                continue;
            sq_level *L = &b->level[j];
            if (sq_level_choose_step(L, &b->def.material, b->def.frame_dt, b->def.step_fraction, err) < 0 ||
                (b->def.sharp_step && sq_level_choose_step_sharp(L, &b->def.material, b->def.frame_dt,
                                                                 b->def.step_fraction, SQ_LANCZOS_ITERS, err) < 0)) {
                sq_body_explicit_estimate(b, L, &b->def.material, 1); /* as it was */
                return sq_err_prefix(err, "integrator \"explicit\" refused for body '%s' level %d", b->name, j);
            }
        }
    }
    b->def.integrator = k;
    b->def.implicit = *imp;
    b->sleeping = 0;
    b->calm = 0;
    return 0;
}
