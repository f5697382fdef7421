/* views.c - read-only views of a body: definition, levels, state, surface, probes, energies,
 * residual, health counters, VTK. */
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "lod/lod.h"
#include "body/body_internal.h"

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
    if (b->def.lod.mode == SQ_LOD_FIXED && b->def.integrator == SQ_INTEGRATOR_IMPLICIT)
        return b->def.frame_dt / b->def.implicit.substeps; /* the implicit step */
    return b->def.lod.mode == SQ_LOD_FIXED && b->def.sharp_step ? b->level[level].dt_fixed : b->level[level].dt;
}

double sq_body_level_bound(const sq_body *b, int level)
{
    if (!(level >= 0 && level < SQ_MAX_LEVELS && b->ready[level]))
        return 0;
    return b->def.lod.mode == SQ_LOD_FIXED && b->def.sharp_step ? b->level[level].bound_sharp
                                                                 : b->level[level].bound;
}

void sq_body_step_bound_cost(const sq_body *b, long *estimates, double *cpu_s)
{
    *estimates = 0;
    *cpu_s = 0;
    if (b->lod)
        sq_lod_sharp_cost(b->lod, estimates, cpu_s);
}

const double *sq_body_displacement(const sq_body *b, int level)
{
    sq_lod_flush(b->lod); /* ghosts nothing read during the frame, pushed now (no-op if fixed) */
    return level >= 0 && level < SQ_MAX_LEVELS && b->ready[level] ? b->level[level].state.d : NULL;
}

const double *sq_body_velocity(const sq_body *b, int level)
{
    sq_lod_flush(b->lod);
    return level >= 0 && level < SQ_MAX_LEVELS && b->ready[level] ? b->level[level].state.v : NULL;
}

const unsigned char *sq_body_node_level(const sq_body *b) { return b->node_level; }
const sq_mesh *sq_body_surface_mesh(const sq_body *b) { return b->def.levels[b->fine]; }
int sq_body_is_sleeping(const sq_body *b) { return b->sleeping; }

void sq_body_active_nodes(const sq_body *b, int active[SQ_MAX_LEVELS])
{
    for (int k = 0; k < SQ_MAX_LEVELS; k++) {
        active[k] = 0;
        if (k >= b->nuse || !b->ready[k])
            continue;
        if (b->def.lod.mode == SQ_LOD_ADAPTIVE)
            sq_lod_active_list(b->lod, k, &active[k]);
        else if (k == b->cur)
            active[k] = b->level[k].model.n;
    }
}
void sq_body_substeps(const sq_body *b, int substeps[SQ_MAX_LEVELS])
{
    for (int k = 0; k < SQ_MAX_LEVELS; k++)
        substeps[k] = 0;
    if (b->def.lod.mode == SQ_LOD_ADAPTIVE) {
        sq_lod_substeps(b->lod, substeps);
        return;
    }
    const sq_level *L = &b->level[b->cur];
    substeps[b->cur] = sq_body_fixed_nsub(b, L);
    if (b->def.integrator == SQ_INTEGRATOR_EXPLICIT && b->boost > 1)
        substeps[b->cur] *= b->boost; /* raised after a diverged frame (frame.c) */
}

const sq_health_stat *sq_body_health(const sq_body *b) { return b->health; }
long sq_body_frames(const sq_body *b) { return b->frames; }

int sq_body_inverted_tets(const sq_body *b)
{
    int k = sq_body_sim_level(b);
    return sq_level_corot_inverted(&b->level[k].model, &b->level[k].state);
}

sq_level *sq_body_level(sq_body *b, int level)
{
    sq_lod_flush(b->lod);
    return level >= 0 && level < SQ_MAX_LEVELS && b->ready[level] ? &b->level[level] : NULL;
}

int sq_body_fixed_level(const sq_body *b) { return b->cur; }

int sq_body_sim_level(const sq_body *b) { return b->def.lod.mode == SQ_LOD_ADAPTIVE ? b->fine : b->cur; }

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
    int k = sq_body_sim_level(b);
    if (k != b->fine) {
        t = sq_mesh_locate(b->def.levels[k], p, bary);
        if (t < 0)
            return -1;
    }
    if (!b->lod) {
        sq_body_interp3(b->def.levels[k], b->level[k].state.d, t, bary, u);
        return 0;
    }
    /* the tet's corners as a flush would leave them, without flushing the whole body; the
     * sums of sq_body_interp3 */
    const int *tv = b->def.levels[k]->tets + 4 * (size_t)t;
    double f[4][3];
    for (int q = 0; q < 4; q++)
        sq_lod_flushed_d(b->lod, k, tv[q], f[q]);
    u[0] = u[1] = u[2] = 0;
    for (int q = 0; q < 4; q++) {
        u[0] += bary[q] * f[q][0];
        u[1] += bary[q] * f[q][1];
        u[2] += bary[q] * f[q][2];
    }
    return 0;
}

double sq_body_kinetic_energy(const sq_body *b)
{
    double ke = 0;
    for (int k = 0; k < SQ_MAX_LEVELS; k++) {
        if (!b->ready[k] || (b->def.lod.mode == SQ_LOD_FIXED && k != b->cur))
            continue;
        const sq_level *L = &b->level[k];
        int na = L->model.n;
        const int *al = b->lod ? sq_lod_active_list(b->lod, k, &na) : NULL;
        for (int r = 0; r < na; r++) {
            int i = al ? al[r] : r;
            const double *v = L->state.v + 3 * (size_t)i;
            ke += 0.5 * L->model.mass[i] * (v[0] * v[0] + v[1] * v[1] + v[2] * v[2]);
        }
    }
    return ke;
}


double sq_body_elastic_energy(const sq_body *b)
{
    sq_lod_flush(b->lod);
    int k = sq_body_sim_level(b);
    return sq_level_elastic_energy(&b->level[k].model, &b->level[k].state);
}

double sq_body_residual(const sq_body *b)
{
    /* a fresh force pass of the simulated level into scratch of its own (state and the level's
     * scratch are left as they are) */
    int k = sq_body_sim_level(b);
    sq_lod_flush(b->lod);
    const sq_level *L = &b->level[k];
    size_t n3 = 3 * (size_t)L->model.n;
    double *f = sq_malloc(sizeof(double) * n3), *acc = sq_calloc(n3 + 1, sizeof(double));
    sq_level_forces_to(&L->model, &L->state, &b->def.material, b->def.gravity, NULL, f, acc);
    double r = sq_level_residual(&L->model, f, b->def.gravity, NULL, 0, b->held[k]);
    free(f);
    free(acc);
    return r;
}

int sq_body_write_vtk(const sq_body *b, const char *path, sq_err *err)
{
    int k = sq_body_sim_level(b);
    sq_lod_flush(b->lod);
    const sq_mesh *m = b->def.levels[k];
    int *lev = sq_malloc(sizeof(int) * (size_t)m->nnodes);
    for (int i = 0; i < m->nnodes; i++)
        lev[i] = b->def.lod.mode == SQ_LOD_ADAPTIVE ? b->node_level[i] : k;
    int rc = sq_mesh_write_vtk(m, path, b->level[k].state.d, b->level[k].state.v, lev, err);
    free(lev);
    return rc;
}
