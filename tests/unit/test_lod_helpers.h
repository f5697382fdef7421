/* test_lod_helpers.h - meshes, bodies and tools for the level-of-detail tests. */
#ifndef SQ_TEST_LOD_HELPERS_H
#define SQ_TEST_LOD_HELPERS_H

#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "body/body.h"

static inline double lh_dist2(const double *a, const double *b)
{
    double s = 0;
    for (int c = 0; c < 3; c++)
        s += (a[c] - b[c]) * (a[c] - b[c]);
    return s;
}

/* interpolate a per-node 3-vector field f of mesh m in tet t */
static inline void lh_interp(const sq_mesh *m, int t, const double *b, const double *f, double out[3])
{
    out[0] = out[1] = out[2] = 0;
    for (int q = 0; q < 4; q++)
        for (int c = 0; c < 3; c++)
            out[c] += b[q] * f[3 * m->tets[4 * t + q] + c];
}

/* deterministic uniform number in [-1, 1) */
static inline double lh_rand(uint64_t *s)
{
    *s = *s * 6364136223846793005ULL + 1442695040888963407ULL;
    return (double)(*s >> 11) / 4503599627370496.0 - 1.0;
}

/* cube of n^3 cells and side `scale`, centred on (0.5, 0.5, 0.5); interior nodes moved by up
 * to `jitter` cells per axis (a non-nested, irregular level); NULL on failure */
static inline sq_mesh *lh_cube(int n, double jitter, double scale, uint64_t seed)
{
    sq_err e = {{0}};
    double size[3] = {scale, scale, scale};
    double origin[3] = {0.5 - scale / 2, 0.5 - scale / 2, 0.5 - scale / 2};
    sq_mesh *m = sq_mesh_box(n, n, n, size, origin, &e);
    if (!m) {
        fprintf(stderr, "sq_mesh_box: %s\n", e.msg);
        return NULL;
    }
    if (jitter <= 0)
        return m;
    double h = scale / n;
    double *x = malloc(sizeof(double) * 3 * m->nnodes);
    memcpy(x, m->x, sizeof(double) * 3 * m->nnodes);
    for (int i = 0; i < m->nnodes; i++) {
        if (m->on_boundary[i])
            continue;
        for (int c = 0; c < 3; c++)
            x[3 * i + c] += jitter * h * lh_rand(&seed);
    }
    sq_mesh *j = sq_mesh_from_arrays(m->nnodes, x, m->ntets, m->tets, "jittered box", &e);
    if (!j)
        fprintf(stderr, "jittered box: %s\n", e.msg);
    free(x);
    sq_mesh_free(m);
    return j;
}

/* the tests' cube levels m[0..n-1]: level k has cells[k] cells per side on the unit cube, its
 * interior nodes jittered by up to 0.1 cell on odd k (seed k + 1); every level is made (NULL
 * where it failed, each freed by lh_free_meshes); 1 when all are made */
static inline int lh_cube_levels(sq_mesh **m, int n, const int *cells)
{
    int ok = 1;
    for (int k = 0; k < n; k++) {
        m[k] = lh_cube(cells[k], k % 2 ? 0.1 : 0, 1, (uint64_t)k + 1);
        ok &= m[k] != NULL;
    }
    return ok;
}

static inline void lh_free_meshes(sq_mesh **m, int n)
{
    for (int k = 0; k < n; k++)
        sq_mesh_free(m[k]);
}

/* the cube's support: the bottom face (z below 1 mm) fixed on all three axes */
static inline sq_constraint lh_bottom_fixed(void)
{
    sq_constraint c;
    memset(&c, 0, sizeof c);
    c.kind = SQ_REGION_BOX;
    c.a[0] = c.a[1] = c.a[2] = -1;
    c.b[0] = c.b[1] = 2;
    c.b[2] = 1e-3;
    c.axes = 7;
    return c;
}

/* the paper's material alone (mu 40 kPa, lambda 100 kPa, 1000 kg/m^3), every other field 0 */
static inline sq_material lh_paper_material(void)
{
    return sq_material_paper();
}

/* lod definition with the body defaults */
static inline sq_lod_def lh_lod(sq_lod_mode mode, double split, double merge)
{
    sq_lod_def d = sq_body_def_default().lod;
    d.mode = mode;
    d.split = split;
    d.merge = merge;
    return d;
}

/* the paper's cube (section 2.6): standard mu = 40 kPa, lambda = 100 kPa, 1000 kg/m^3,
 * bottom face fixed, gravity -z, mass damping; levels m[0..nlevels-1] */
static inline sq_body_def lh_cube_def(sq_mesh **m, int nlevels)
{
    sq_body_def def = sq_body_def_default();
    def.name = "cube";
    def.nlevels = nlevels;
    for (int k = 0; k < nlevels; k++)
        def.levels[k] = m[k];
    def.material.mu = 40000;
    def.material.lambda = 100000;
    def.material.density = 1000;
    def.material.rayleigh_mass = 4;
    def.material.rayleigh_stiffness = 0;
    def.gravity[0] = def.gravity[1] = 0;
    def.gravity[2] = -9.81;
    def.nconstraints = 1;
    def.constraints[0] = lh_bottom_fixed();
    return def;
}

/* the adaptive tests' poked cube: three cube levels of 3, 6 (jittered) and 12 cells in m[0..2]
 * (lh_cube_levels; on failure the made ones freed and 0) */
static inline int lh_poke_meshes(sq_mesh **m)
{
    if (lh_cube_levels(m, 3, (const int[]){3, 6, 12}))
        return 1;
    lh_free_meshes(m, 3);
    return 0;
}

/* the poked cube's definition on lh_poke_meshes' levels: the paper's cube (lh_cube_def),
 * adaptive at split 0.05 and merge 0.00625, with its gravity or (gravity 0) without, so that
 * the poke alone deforms it */
static inline sq_body_def lh_poke_def(sq_mesh **m, int gravity)
{
    sq_body_def def = lh_cube_def(m, 3);
    if (!gravity)
        def.gravity[2] = 0;
    def.lod = lh_lod(SQ_LOD_ADAPTIVE, 0.05, 0.00625);
    return def;
}

/* a body of def, or NULL with the error printed */
static inline sq_body *lh_body(const sq_body_def *def)
{
    sq_err e = {{0}};
    sq_body *b = sq_body_create(def, &e);
    if (!b)
        fprintf(stderr, "sq_body_create: %s\n", e.msg);
    return b;
}

static inline double lh_norm3(const double *v) { return sqrt(v[0] * v[0] + v[1] * v[1] + v[2] * v[2]); }

static inline sq_tool lh_sphere(double x, double y, double z, double r, int active)
{
    sq_tool t;
    memset(&t, 0, sizeof t);
    t.id = 1;
    t.shape = SQ_TOOL_SPHERE;
    t.active = active;
    t.pos[0] = x;
    t.pos[1] = y;
    t.pos[2] = z;
    t.radius = r;
    return t;
}

#endif
