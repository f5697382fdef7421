/* statics.c - the static loads the criterion judges from (docs/lod.md, "Criterion"): each level's
 * static equilibrium under the body's gravity and material (lev[k].d_static), solved once per
 * gravity, material and top level, or copied from a lod of the same body (sq_lod_set_loads_like).
 * Owns lod->statics. Run by frame.c's guard stage (a no-op unless something changed) and by
 * the body's run-time changes.
 */
#include "lod/lod.h"
#include "lod/corotational.h"
#include "lod/coupling.h"
#include "lod/statics.h"

#include <stdlib.h>
#include <string.h>

/* The criterion measures curvature of the displacement; a body sagging under its own weight
 * has a curved static field, so on a soft body gravity alone kept regions refined for good.
 * Linear elasticity superposes: the motion a tool causes is d - d_static, and the criterion is
 * taken of that. d_static of each level is solved once (sq_level_static_solve, Jacobi CG to a
 * relative residual of 1e-8) for the body's gravity and material; a level whose solve fails (a
 * body with no support has no equilibrium) is judged from zero displacement, as before. */
void sq_lodx_static_loads(sq_lod *lod, const double gravity[3])
{
    if (lod->statics.stat_done && lod->statics.stat_k == lod->lv[0].model.K && !memcmp(lod->statics.stat_g, gravity, sizeof lod->statics.stat_g) &&
        lod->statics.stat_top == lod->top && (!lod->cpl.have_mat || !memcmp(&lod->statics.stat_mat, &lod->cpl.mat, sizeof lod->cpl.mat)))
        return;
    lod->statics.stat_done = 1;
    lod->statics.stat_top = lod->top;
    lod->statics.stat_mat = lod->cpl.mat;
    lod->statics.stat_k = lod->lv[0].model.K;
    memcpy(lod->statics.stat_g, gravity, sizeof lod->statics.stat_g);
    int loaded = gravity[0] != 0 || gravity[1] != 0 || gravity[2] != 0;
    for (int k = 0; k < lod->L; k++) {
        free(lod->lev[k].d_static);
        lod->lev[k].d_static = NULL;
        if (!loaded || k > lod->top)
            continue;
        const sq_level *Lk = &lod->lv[k];
        double *d = sq_malloc(sizeof(double) * 3 * (size_t)SQ_MAX(Lk->model.n, 1));
        sq_err err = {{0}};
        int it = 0;
        if (sq_level_static_solve(&Lk->model, gravity, 1e-8, 20 * Lk->model.n + 1000, d, &it, &err) == 0) {
            if (Lk->state.corot) /* the corotational level's own equilibrium (corotational.c) */
                sq_lodx_corot_static(lod, k, gravity, d, &it);
            lod->lev[k].d_static = d;
        }
        else
            free(d);
    }
}

void sq_lod_set_loads(sq_lod *lod, const sq_material *mat, const double gravity[3])
{
    sq_lod_set_material(lod, mat);
    sq_lodx_static_loads(lod, gravity);
}

void sq_lod_set_loads_like(sq_lod *lod, const sq_material *mat, const double gravity[3], const sq_lod *like)
{
    lod->like = like; /* the own-operator row sums of levels over like's operator blocks: like's */
    sq_lod_set_material(lod, mat);
    lod->like = NULL;
    int same = like && like->statics.stat_done && like->L == lod->L && like->statics.stat_top == lod->top &&
               like->statics.stat_k == lod->lv[0].model.K && !memcmp(like->statics.stat_g, gravity, sizeof like->statics.stat_g) &&
               lod->cpl.have_mat && !memcmp(&like->statics.stat_mat, &lod->cpl.mat, sizeof lod->cpl.mat);
    for (int k = 0; same && k < lod->L; k++)
        same = like->lv[k].model.K == lod->lv[k].model.K && !like->lv[k].state.corot == !lod->lv[k].state.corot;
    if (!same) {
        sq_lodx_static_loads(lod, gravity);
        return;
    }
    lod->statics.stat_done = 1;
    lod->statics.stat_top = like->statics.stat_top;
    lod->statics.stat_mat = like->statics.stat_mat;
    lod->statics.stat_k = like->statics.stat_k;
    memcpy(lod->statics.stat_g, like->statics.stat_g, sizeof lod->statics.stat_g);
    for (int k = 0; k < lod->L; k++) {
        free(lod->lev[k].d_static);
        lod->lev[k].d_static = NULL;
        if (like->lev[k].d_static) {
            size_t bytes = sizeof(double) * 3 * (size_t)SQ_MAX(lod->lv[k].model.n, 1);
            lod->lev[k].d_static = sq_malloc(bytes);
            memcpy(lod->lev[k].d_static, like->lev[k].d_static, bytes);
        }
    }
}
