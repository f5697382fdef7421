/* bodies.c - a body of a scene file: material, constraints, level of detail, its meshes.
 *
 * Parse and validate one entry of "bodies" (docs/scenes.md), then load the mesh levels it
 * needs (fixed: the simulated level alone; adaptive: 0..max_level), scaled and offset, and
 * check what needs the meshes: levels coarse to fine, every constraint region selecting
 * nodes, the combinations the engine supports.
 */
#include "scene/scene_internal.h"

#include <errno.h>
#include <math.h>
#include <stdio.h>
#include <string.h>
#include <sys/stat.h>

/* ---- material ---------------------------------------------------------------------- */

static int parse_material(pctx *c, const cJSON *obj, const char *path, sq_material *m)
{
    static const char *const keys[] = {"E", "nu", "lambda", "mu", "density", "damping", NULL};
    if (scene_check_keys(c, obj, path, keys))
        return -1;
    double E = 0, nu = 0, lambda = 0, mu = 0, density = DEF_DENSITY;
    int hE, hnu, hl, hmu;
    if (scene_get_number(c, obj, path, "E", &E, &hE) || scene_get_number(c, obj, path, "nu", &nu, &hnu) ||
        scene_get_number(c, obj, path, "lambda", &lambda, &hl) || scene_get_number(c, obj, path, "mu", &mu, &hmu) ||
        scene_get_number(c, obj, path, "density", &density, NULL))
        return -1;
    /* damping defaults are the engine's (sq_body_def_default) */
    const sq_material dm = sq_body_def_default().material;
    memset(m, 0, sizeof *m);
    m->rayleigh_mass = dm.rayleigh_mass;
    m->rayleigh_stiffness = dm.rayleigh_stiffness;
    char p[256];
    if ((hE || hnu) && (hl || hmu))
        return scene_fail(c, path, "both E/nu and lambda/mu given; give either E and nu, or lambda and mu");
    if (hE || hnu) {
        if (!hE || !hnu) {
            scene_join(p, sizeof p, path, hE ? "nu" : "E");
            return scene_fail(c, p, "missing; E (Pa) and nu go together, give both");
        }
        if (scene_range_pos(c, path, "E", E, "Young's modulus in Pa"))
            return -1;
        if (!(nu >= 0 && nu < 0.5)) {
            scene_join(p, sizeof p, path, "nu");
            return scene_fail(c, p, "%g is out of range; use 0 <= nu < 0.5", nu);
        }
        /* nu very close to 0.5 makes lambda overflow the step bound; sim rejects it with numbers */
        sq_err e = {{0}};
        if (sq_material_from_E_nu(m, E, nu, &e)) {
            scene_join(p, sizeof p, path, "E");
            return scene_fail(c, p, "%s", e.msg);
        }
    } else if (hl || hmu) {
        if (!hl || !hmu) {
            scene_join(p, sizeof p, path, hl ? "mu" : "lambda");
            return scene_fail(c, p, "missing; lambda and mu (Pa, standard Lame names) go together, give both");
        }
        if (scene_range_pos(c, path, "mu", mu, "shear modulus in Pa") ||
            scene_range_nonneg(c, path, "lambda", lambda, "first Lame parameter in Pa"))
            return -1;
        m->mu = mu;
        m->lambda = lambda;
    } else {
        return scene_fail(c, path, "no stiffness given; give E (Pa) and nu, or lambda and mu (Pa)");
    }
    if (scene_range_pos(c, path, "density", density, "kg/m^3"))
        return -1;
    m->density = density;

    /* damping: Rayleigh a M + b K, or the paper's viscosities phi/psi in place of b K */
    int bad;
    const cJSON *d = scene_get_typed(c, obj, path, "damping", 0, 0, &bad);
    if (bad)
        return -1;
    if (d) {
        static const char *const dkeys[] = {"rayleigh_mass", "rayleigh_stiffness", "phi", "psi", NULL};
        char dp[256];
        scene_join(dp, sizeof dp, path, "damping");
        if (scene_check_keys(c, d, dp, dkeys))
            return -1;
        int hb, hphi, hpsi;
        if (scene_get_number(c, d, dp, "rayleigh_mass", &m->rayleigh_mass, NULL) ||
            scene_get_number(c, d, dp, "rayleigh_stiffness", &m->rayleigh_stiffness, &hb) ||
            scene_get_number(c, d, dp, "phi", &m->phi, &hphi) || scene_get_number(c, d, dp, "psi", &m->psi, &hpsi))
            return -1;
        if (scene_range_nonneg(c, dp, "rayleigh_mass", m->rayleigh_mass, "1/s") ||
            scene_range_nonneg(c, dp, "rayleigh_stiffness", m->rayleigh_stiffness, "s") ||
            scene_range_nonneg(c, dp, "phi", m->phi, "Pa s") || scene_range_nonneg(c, dp, "psi", m->psi, "Pa s"))
            return -1;
        if ((hphi || hpsi) && hb)
            return scene_fail(c, dp, "rayleigh_stiffness and phi/psi both given; the viscosities replace b K, "
                               "give one of them");
        m->use_viscosity = hphi || hpsi;
        if (m->use_viscosity)
            m->rayleigh_stiffness = 0;
    }
    sq_err e = {{0}};
    if (sq_material_check(m, &e))
        return scene_fail(c, path, "%s", e.msg);
    return 0;
}

/* ---- constraints ------------------------------------------------------------------- */

static int parse_axes(pctx *c, const cJSON *obj, const char *path, unsigned *axes)
{
    char s[8];
    int found;
    char p[256];
    scene_join(p, sizeof p, path, "axes");
    const cJSON *it = scene_get(obj, "axes");
    if (it && cJSON_IsString(it) && strlen(it->valuestring) >= sizeof s)
        return scene_fail(c, p, "\"%s\" is not a set of axes; use a combination of x, y, z such as \"xy\"",
                    it->valuestring);
    if (scene_get_string(c, obj, path, "axes", s, sizeof s, &found))
        return -1;
    *axes = 7;
    if (!found)
        return 0;
    unsigned a = 0;
    for (const char *q = s; *q; q++) {
        unsigned bit = *q == 'x' ? 1u : *q == 'y' ? 2u : *q == 'z' ? 4u : 0u;
        if (!bit || (a & bit))
            return scene_fail(c, p, "\"%s\" is not a set of axes; use each of x, y, z at most once, e.g. \"xy\"", s);
        a |= bit;
    }
    if (!a)
        return scene_fail(c, p, "empty; name the constrained axes, e.g. \"z\" for a roller on a horizontal plane");
    *axes = a;
    return 0;
}

static int parse_constraint(pctx *c, const cJSON *obj, const char *path, sq_constraint *k)
{
    static const char *const keys[] = {"box", "halfspace", "axes", NULL};
    if (!cJSON_IsObject(obj))
        return scene_fail(c, path, "expected an object {\"box\": ...} or {\"halfspace\": ...}, got %s; see docs/scenes.md", scene_type_name(obj));
    if (scene_check_keys(c, obj, path, keys))
        return -1;
    memset(k, 0, sizeof *k);
    const cJSON *box = scene_get(obj, "box"), *hs = scene_get(obj, "halfspace");
    if (!!box == !!hs)
        return scene_fail(c, path, "%s region; give exactly one: \"box\": [[x0,y0,z0],[x1,y1,z1]] or "
                             "\"halfspace\": {\"point\": [...], \"normal\": [...]}",
                    box ? "more than one" : "no");
    char p[256];
    if (box) {
        scene_join(p, sizeof p, path, "box");
        if (!cJSON_IsArray(box) || cJSON_GetArraySize(box) != 2)
            return scene_fail(c, p, "expected [[x0,y0,z0],[x1,y1,z1]] (min and max corners), got %s; see docs/scenes.md", scene_type_name(box));
        char q[256];
        scene_join_index(q, sizeof q, p, 0);
        if (scene_vec3_of(c, box->child, q, k->a))
            return -1;
        scene_join_index(q, sizeof q, p, 1);
        if (scene_vec3_of(c, box->child->next, q, k->b))
            return -1;
        for (int i = 0; i < 3; i++)
            if (k->a[i] > k->b[i])
                return scene_fail(c, p, "min corner above max corner on axis %c (%g > %g); put the smaller "
                                  "coordinates first", "xyz"[i], k->a[i], k->b[i]);
        k->kind = SQ_REGION_BOX;
    } else {
        scene_join(p, sizeof p, path, "halfspace");
        if (!cJSON_IsObject(hs))
            return scene_fail(c, p, "expected {\"point\": [x,y,z], \"normal\": [x,y,z]}, got %s; see docs/scenes.md", scene_type_name(hs));
        static const char *const hkeys[] = {"point", "normal", NULL};
        if (scene_check_keys(c, hs, p, hkeys))
            return -1;
        int f1, f2;
        if (scene_get_vec3(c, hs, p, "point", k->a, &f1) || scene_get_vec3(c, hs, p, "normal", k->b, &f2))
            return -1;
        if (!f1 || !f2)
            return scene_fail(c, p, "missing \"%s\"; a half-space needs a point and an outward normal "
                              "(nodes with (x - point).normal <= 0 are selected)", f1 ? "normal" : "point");
        double n = sqrt(k->b[0] * k->b[0] + k->b[1] * k->b[1] + k->b[2] * k->b[2]);
        if (!(n > 0) || !isfinite(n)) {
            char q[256];
            scene_join(q, sizeof q, p, "normal");
            return scene_fail(c, q, "zero or overflowing vector; give a non-zero normal such as [0, 0, 1]");
        }
        for (int i = 0; i < 3; i++)
            k->b[i] /= n;
        k->kind = SQ_REGION_HALFSPACE;
    }
    return parse_axes(c, obj, path, &k->axes);
}

/* does the region select node x? (same rule as the engine: inclusive box, (x-a).n <= 0) */
static int region_selects(const sq_constraint *k, const double *x)
{
    if (k->kind == SQ_REGION_BOX)
        return x[0] >= k->a[0] && x[0] <= k->b[0] && x[1] >= k->a[1] && x[1] <= k->b[1] &&
               x[2] >= k->a[2] && x[2] <= k->b[2];
    double s = 0;
    for (int i = 0; i < 3; i++)
        s += (x[i] - k->a[i]) * k->b[i];
    return s <= 0;
}

/* ---- level of detail --------------------------------------------------------------- */

static int parse_lod(pctx *c, const cJSON *obj, const char *path, int nlisted, sq_lod_def *lod)
{
    static const char *const keys[] = {"mode", "level", "split", "merge", "max_level", "budget",
                                       "max_node_updates", "adapt_every", NULL};
    /* defaults of the engine (sq_body_def_default) */
    *lod = sq_body_def_default().lod;
    lod->mode = SQ_LOD_FIXED;
    double merge_ratio = lod->split > 0 ? lod->merge / lod->split : 0.4;
    lod->max_level = nlisted - 1;
    lod->level = -1;
    if (!obj) {
        lod->level = nlisted - 1;
        return 0;
    }
    if (scene_check_keys(c, obj, path, keys))
        return -1;
    char mode[16] = "fixed", p[256];
    const cJSON *mi = scene_get(obj, "mode");
    scene_join(p, sizeof p, path, "mode");
    if (mi && cJSON_IsString(mi) && strlen(mi->valuestring) >= sizeof mode)
        return scene_fail(c, p, "\"%s\" is not a mode; use \"fixed\" or \"adaptive\"", mi->valuestring);
    if (scene_get_string(c, obj, path, "mode", mode, sizeof mode, NULL))
        return -1;
    if (!strcmp(mode, "adaptive"))
        lod->mode = SQ_LOD_ADAPTIVE;
    else if (strcmp(mode, "fixed"))
        return scene_fail(c, p, "\"%s\" is not a mode; use \"fixed\" or \"adaptive\"", mode);
    long v;
    int found;
    if (scene_get_int(c, obj, path, "max_level", 0, nlisted - 1, &v, &found))
        return -1;
    if (found)
        lod->max_level = (int)v;
    if (scene_get_int(c, obj, path, "level", 0, lod->max_level, &v, &found))
        return -1;
    lod->level = found ? (int)v : lod->mode == SQ_LOD_FIXED ? lod->max_level : 0;

    /* split may be the string "inf": never split (forces the coarsest level) */
    const cJSON *sp = scene_get(obj, "split");
    scene_join(p, sizeof p, path, "split");
    if (sp && cJSON_IsString(sp)) {
        if (strcmp(sp->valuestring, "inf"))
            return scene_fail(c, p, "\"%s\" is not a threshold; use a number >= 0 (m) or \"inf\"", sp->valuestring);
        lod->split = INFINITY;
    } else if (scene_get_number(c, obj, path, "split", &lod->split, NULL) ||
               scene_range_nonneg(c, path, "split", lod->split, "m"))
        return -1;
    if (sp)
        lod->merge = isinf(lod->split) ? 1e300 : lod->split * merge_ratio;
    int hmerge;
    if (scene_get_number(c, obj, path, "merge", &lod->merge, &hmerge) ||
        scene_range_nonneg(c, path, "merge", lod->merge, "m"))
        return -1;
    if (hmerge && !(lod->merge < lod->split || (lod->split == 0 && lod->merge == 0))) {
        scene_join(p, sizeof p, path, "merge");
        return scene_fail(c, p, "%g is not below split (%g); use merge < split for hysteresis", lod->merge,
                    lod->split);
    }
    if (scene_get_number(c, obj, path, "budget", &lod->budget, NULL))
        return -1;
    if (!(lod->budget > 0 && lod->budget <= 1)) {
        scene_join(p, sizeof p, path, "budget");
        return scene_fail(c, p, "%g is out of range; use a fraction of the frame period in (0, 1], e.g. 0.95",
                    lod->budget);
    }
    if (scene_get_int(c, obj, path, "max_node_updates", 0, 1000000000000L, &v, &found))
        return -1;
    if (found)
        lod->max_node_updates = v;
    if (scene_get_int(c, obj, path, "adapt_every", 1, SQ_LOD_ADAPT_EVERY_MAX, &v, &found))
        return -1;
    if (found)
        lod->adapt_every = (int)v;
    return 0;
}

/* ---- files ------------------------------------------------------------------------- */

void scene_resolve(char *out, size_t n, const char *base_dir, const char *rel)
{
    if (rel[0] == '/' || !base_dir || !base_dir[0])
        snprintf(out, n, "%s", rel);
    else
        snprintf(out, n, "%s/%s", base_dir, rel);
}

/* ---- bodies ------------------------------------------------------------------------ */

/* "integrator": "explicit" | "implicit" and the "implicit" settings object (docs/scenes.md) */
static int parse_integrator(pctx *c, sq_body_def *def, const cJSON *obj, const char *path)
{
    char p[256];
    const cJSON *in = scene_get(obj, "integrator");
    scene_join(p, sizeof p, path, "integrator");
    if (in && !(cJSON_IsString(in) && (!strcmp(in->valuestring, "explicit") || !strcmp(in->valuestring, "implicit"))))
        return scene_fail(c, p, "expected \"explicit\" (default: symplectic Euler at the stability bound) or "
                          "\"implicit\" (backward Euler, any step; fixed lod); see docs/physics.md section 12");
    def->integrator = in && !strcmp(in->valuestring, "implicit") ? SQ_INTEGRATOR_IMPLICIT : SQ_INTEGRATOR_EXPLICIT;
    def->implicit = sq_implicit_def_default();
    int bad = 0;
    const cJSON *im = scene_get_typed(c, obj, path, "implicit", 0, 0, &bad);
    if (bad)
        return -1;
    if (!im)
        return 0;
    static const char *const keys[] = {"substeps", "cg_tolerance", "cg_max_iterations", "preconditioner",
                                       "newton_iterations", NULL};
    char ip[256];
    scene_join(ip, sizeof ip, path, "implicit");
    if (scene_check_keys(c, im, ip, keys))
        return -1;
    long v;
    int found;
    if (scene_get_int(c, im, ip, "substeps", 1, SQ_IMPLICIT_MAX_SUBSTEPS, &v, &found))
        return -1;
    if (found)
        def->implicit.substeps = (int)v;
    if (scene_get_int(c, im, ip, "cg_max_iterations", 1, SQ_IMPLICIT_MAX_ITER, &v, &found))
        return -1;
    if (found)
        def->implicit.max_iter = (int)v;
    if (scene_get_int(c, im, ip, "newton_iterations", 1, SQ_IMPLICIT_MAX_NEWTON, &v, &found))
        return -1;
    if (found)
        def->implicit.newton = (int)v;
    double tol;
    if (scene_get_number(c, im, ip, "cg_tolerance", &tol, &found))
        return -1;
    if (found) {
        if (!(tol > 0 && tol < 1)) {
            scene_join(p, sizeof p, ip, "cg_tolerance");
            return scene_fail(c, p, "%g is out of range: give a relative residual in (0, 1), e.g. 1e-6", tol);
        }
        def->implicit.tol = tol;
    }
    const cJSON *pc = scene_get(im, "preconditioner");
    if (pc) {
        scene_join(p, sizeof p, ip, "preconditioner");
        if (!(cJSON_IsString(pc) && (!strcmp(pc->valuestring, "jacobi") || !strcmp(pc->valuestring, "block_jacobi") ||
                                     !strcmp(pc->valuestring, "multigrid"))))
            return scene_fail(c, p, "expected \"jacobi\" (diagonal), \"block_jacobi\" (default: 3x3 nodal blocks) or "
                              "\"multigrid\" (the body's coarser levels as a V-cycle)");
        def->implicit.precond = !strcmp(pc->valuestring, "jacobi")      ? SQ_PRECOND_JACOBI
                                : !strcmp(pc->valuestring, "multigrid") ? SQ_PRECOND_MULTIGRID
                                                                        : SQ_PRECOND_BLOCK;
    }
    return 0;
}

/* the model's kinds: operator, elasticity, step bound, pressure */
static int parse_model_kinds(pctx *c, sq_body_def *def, const cJSON *obj, const char *path)
{
    char p[256];
    /* operator */
    char op[16] = "fem";
    const cJSON *opi = scene_get(obj, "operator");
    scene_join(p, sizeof p, path, "operator");
    if (opi && !cJSON_IsString(opi))
        return scene_fail(c, p, "expected \"fem\" or \"paper\", got %s; see docs/scenes.md", scene_type_name(opi));
    if (opi && strlen(opi->valuestring) >= sizeof op)
        return scene_fail(c, p, "\"%.40s\" is not an operator; use \"fem\" or \"paper\"", opi->valuestring);
    if (opi)
        snprintf(op, sizeof op, "%s", opi->valuestring);
    if (!strcmp(op, "fem"))
        def->op = SQ_OPERATOR_FEM;
    else if (!strcmp(op, "paper"))
        def->op = SQ_OPERATOR_PAPER;
    else
        return scene_fail(c, p, "\"%s\" is not an operator; use \"fem\" (standard linear FEM) or \"paper\" "
                          "(the paper's Laplacian + grad-div)", op);

    /* elasticity: linear (default) or corotational */
    const cJSON *el = scene_get(obj, "elasticity");
    scene_join(p, sizeof p, path, "elasticity");
    if (el && !cJSON_IsString(el))
        return scene_fail(c, p, "expected \"linear\" or \"corotational\", got %s; see docs/scenes.md", scene_type_name(el));
    if (!el || !strcmp(el->valuestring, "linear"))
        def->elasticity = SQ_ELASTICITY_LINEAR;
    else if (!strcmp(el->valuestring, "corotational"))
        def->elasticity = SQ_ELASTICITY_COROTATIONAL;
    else
        return scene_fail(c, p, "\"%.40s\" is not an elasticity; use \"linear\" (small strain, the paper's) or "
                          "\"corotational\" (large rotations; fem operator)", el->valuestring);

    /* step bound: sharp (default: Lanczos estimate, Gershgorin its ceiling and fallback; 2^n substeps
     * in fixed and adaptive lod alike) or gershgorin (row-sum bound, 2^n) */
    const cJSON *sb = scene_get(obj, "step_bound");
    scene_join(p, sizeof p, path, "step_bound");
    if (sb && !(cJSON_IsString(sb) && (!strcmp(sb->valuestring, "gershgorin") || !strcmp(sb->valuestring, "sharp"))))
        return scene_fail(c, p, "expected \"sharp\" (default: Lanczos estimate with Gershgorin as its ceiling, 2^n "
                          "substeps per frame, per level of the coupled operator in adaptive lod) or \"gershgorin\" "
                          "(row-sum bound, 2^n substeps per frame); see docs/stability.md");
    def->sharp_step = !(sb && !strcmp(sb->valuestring, "gershgorin"));

    /* pressure: element (default), nodal (average nodal pressure tets: less volumetric locking) or
     * smoothed (nodal pressure and face-smoothed deviatoric strain: less bending locking too) */
    const cJSON *pr = scene_get(obj, "pressure");
    scene_join(p, sizeof p, path, "pressure");
    if (pr && !(cJSON_IsString(pr) && (!strcmp(pr->valuestring, "element") || !strcmp(pr->valuestring, "nodal") ||
                                       !strcmp(pr->valuestring, "smoothed"))))
        return scene_fail(c, p, "expected \"element\" (default: one pressure per tet), \"nodal\" (average nodal "
                          "pressure tets: less volumetric locking) or \"smoothed\" (nodal pressure and face-smoothed "
                          "strain: less bending locking too); the last two with fem, linear, fixed lod; see "
                          "docs/physics.md section 10");
    def->nodal_pressure = !pr                                   ? SQ_PRESSURE_ELEMENT
                          : !strcmp(pr->valuestring, "nodal")    ? SQ_PRESSURE_NODAL
                          : !strcmp(pr->valuestring, "smoothed") ? SQ_PRESSURE_SMOOTHED
                                                                 : SQ_PRESSURE_ELEMENT;

    return 0;
}

/* load only the levels body bi needs (files as listed, lp their path in the scene): scaled,
 * offset, located; a unit warning when a mesh's size suggests other units */
static int load_levels(pctx *c, sq_scene *s, int bi, const char *const *files, const char *lp, double scale,
                       const double offset[3], const char *path)
{
    sq_body_def *def = &s->bodies[bi];
    char p[256];
    int warned = 0;

    /* fixed -> the simulated level alone, adaptive -> levels 0..max_level */
    int first = def->lod.mode == SQ_LOD_FIXED ? def->lod.level : 0;
    int last = def->lod.mode == SQ_LOD_FIXED ? def->lod.level : def->lod.max_level;
    def->nlevels = 0;
    for (int k = first; k <= last; k++) {
        char full[1024];
        scene_resolve(full, sizeof full, c->base_dir, files[k]);
        sq_err e = {{0}};
        sq_mesh *m = sq_mesh_load(full, &e);
        scene_join_index(p, sizeof p, lp, k);
        if (!m)
            return scene_fail(c, p, "%s; fix or regenerate the mesh file", e.msg);
        if (scale != 1) {
            for (int v = 0; v < 3 * m->nnodes; v++)
                m->x[v] *= scale;
            for (int a = 0; a < 3; a++) {
                m->bbox_min[a] *= scale;
                m->bbox_max[a] *= scale;
            }
        }
        /* a body is a few mm to a few m: anything else is most likely in other units */
        double diag = 0;
        for (int a = 0; a < 3; a++)
            diag += (m->bbox_max[a] - m->bbox_min[a]) * (m->bbox_max[a] - m->bbox_min[a]);
        diag = sqrt(diag);
        if (!warned && (diag > 10 || diag < 1e-3) && s->nwarnings < SQ_MAX_BODIES) {
            /* the power of ten that brings it near 1 m: 0.001 for millimetres, 0.01 for cm */
            double hint = pow(10, -round(log10(diag)));
            const char *units = fabs(hint - 1e-3) < 1e-9 ? " (a mesh in millimetres)"
                                : fabs(hint - 1e-2) < 1e-9 ? " (a mesh in centimetres)" : "";
            char bp[256];
            scene_join(bp, sizeof bp, path, "scale");
            char *wm = s->warnings[s->nwarnings++];
            if (snprintf(wm, sizeof s->warnings[0],
                     "%s: %s: the mesh's bounding-box diagonal is %g m, %s: are its units metres? "
                     "If not, set %s (now %g), e.g. \"scale\": %g%s",
                     c->label, p, diag, diag > 10 ? "above 10 m" : "below 1 mm", bp, scale,
                     hint * scale, units) < 0)
                wm[0] = 0;
            warned = 1;
        }
        if (offset[0] != 0 || offset[1] != 0 || offset[2] != 0) {
            for (int v = 0; v < m->nnodes; v++)
                for (int a = 0; a < 3; a++)
                    m->x[3 * v + a] += offset[a];
            for (int a = 0; a < 3; a++) {
                m->bbox_min[a] += offset[a];
                m->bbox_max[a] += offset[a];
            }
        }
        /* build the mesh's point-location grid now: a loaded scene is then read-only and
         * can be shared by worlds on several threads */
        double bary[4];
        sq_mesh_locate(m, m->x, bary);
        s->meshes[bi][def->nlevels] = m;
        s->level_index[bi][def->nlevels] = k;
        def->levels[def->nlevels] = m;
        def->nlevels++;
        if (def->nlevels > 1 && m->nnodes <= def->levels[def->nlevels - 2]->nnodes)
            return scene_fail(c, p, "%d nodes, not more than the previous level's %d; list the levels coarse to fine",
                        m->nnodes, def->levels[def->nlevels - 2]->nnodes);
    }
    if (def->lod.mode == SQ_LOD_FIXED) {
        def->lod.level = 0;
        def->lod.max_level = 0;
    } else {
        def->lod.level -= first;
        def->lod.max_level -= first;
    }

    return 0;
}

/* every constraint region must select nodes on every loaded level of body bi */
static int check_regions(pctx *c, sq_scene *s, int bi, const char *const *files, const char *path)
{
    const sq_body_def *def = &s->bodies[bi];
    char p[256];
    for (int r = 0; r < def->nconstraints; r++)
        for (int k = 0; k < def->nlevels; k++) {
            const sq_mesh *m = def->levels[k];
            int n = 0;
            for (int v = 0; v < m->nnodes; v++)
                n += region_selects(&def->constraints[r], m->x + 3 * v);
            if (n == 0) {
                char fp[256];
                scene_join(fp, sizeof fp, path, "fixed");
                scene_join_index(p, sizeof p, fp, r);
                return scene_fail(c, p, "selects no node of levels[%d] (%s, bounding box [%g, %g, %g] - [%g, %g, %g]); "
                                  "move the region onto the mesh",
                            s->level_index[bi][k], files[s->level_index[bi][k]], m->bbox_min[0],
                            m->bbox_min[1], m->bbox_min[2], m->bbox_max[0], m->bbox_max[1], m->bbox_max[2]);
            }
        }
    return 0;
}

/* body bi's name: given or "bodyN", valid, unique among the bodies before it */
static int parse_body_name(pctx *c, sq_scene *s, const cJSON *obj, int bi, const char *path)
{
    char p[256];
    int found;
    snprintf(s->body_names[bi], sizeof s->body_names[bi], "body%d", bi);
    if (scene_get_string(c, obj, path, "name", s->body_names[bi], sizeof s->body_names[bi], &found))
        return -1;
    scene_join(p, sizeof p, path, "name");
    if (scene_check_name(c, p, s->body_names[bi]))
        return -1;
    for (int j = 0; j < bi; j++)
        if (!strcmp(s->body_names[j], s->body_names[bi]))
            return scene_fail(c, p, "\"%s\" is already the name of bodies[%d]; give each body its own name",
                        s->body_names[bi], j);
    return 0;
}

int scene_parse_body(pctx *c, sq_scene *s, const cJSON *obj, int bi, const char *path)
{
    static const char *const keys[] = {"name", "levels", "scale", "offset", "material", "operator", "fixed",
                                       "lod", "step_fraction", "elasticity", "step_bound", "pressure",
                                       "integrator", "implicit", NULL};
    if (!cJSON_IsObject(obj))
        return scene_fail(c, path, "expected an object, got %s; see docs/scenes.md", scene_type_name(obj));
    if (scene_check_keys(c, obj, path, keys))
        return -1;
    sq_body_def *def = &s->bodies[bi];
    *def = sq_body_def_default();
    char p[256];

    if (parse_body_name(c, s, obj, bi, path))
        return -1;
    def->name = s->body_names[bi];

    /* levels: strings, coarse to fine */
    int bad;
    const cJSON *lv = scene_get_typed(c, obj, path, "levels", 1, 1, &bad);
    if (bad)
        return -1;
    char lp[256];
    scene_join(lp, sizeof lp, path, "levels");
    int nl = cJSON_GetArraySize(lv);
    if (nl < 1 || nl > SQ_MAX_LEVELS)
        return scene_fail(c, lp, "%d levels; list 1 to %d mesh files, coarse to fine", nl, SQ_MAX_LEVELS);
    const char *files[SQ_MAX_LEVELS];
    int i = 0;
    for (const cJSON *e = lv->child; e; e = e->next, i++) {
        scene_join_index(p, sizeof p, lp, i);
        if (!cJSON_IsString(e) || !e->valuestring[0])
            return scene_fail(c, p, "expected a mesh file path (relative to the scene file), got %s; see docs/scenes.md",
                        cJSON_IsString(e) ? "an empty string" : scene_type_name(e));
        files[i] = e->valuestring;
        char full[1024];
        scene_resolve(full, sizeof full, c->base_dir, files[i]);
        struct stat st;
        if (stat(full, &st) != 0 && errno == ENOENT && c->made_by[0])
            return scene_fail(c, p, "mesh file \"%s\" (resolved to %s): " SQ_SCENE_MESHES_NOT_MADE
                              ": this scene's meshes are generated, not shipped; run `%s` first (meshes/README.md)",
                              files[i], full, c->made_by);
        if (stat(full, &st) != 0)
            return scene_fail(c, p, "mesh file \"%s\" (resolved to %s) cannot be read: %s; paths are relative "
                              "to the scene file's directory", files[i], full, strerror(errno));
    }
    s->nlisted[bi] = nl;

    /* material */
    const cJSON *mat = scene_get_typed(c, obj, path, "material", 0, 1, &bad);
    if (bad)
        return -1;
    scene_join(p, sizeof p, path, "material");
    if (parse_material(c, mat, p, &def->material))
        return -1;

    if (parse_model_kinds(c, def, obj, path))
        return -1;

    if (parse_integrator(c, def, obj, path))
        return -1;

    /* constraints */
    const cJSON *fx = scene_get_typed(c, obj, path, "fixed", 1, 0, &bad);
    if (bad)
        return -1;
    def->nconstraints = 0;
    if (fx) {
        char fp[256];
        scene_join(fp, sizeof fp, path, "fixed");
        int nf = cJSON_GetArraySize(fx);
        if (nf > SQ_MAX_CONSTRAINTS)
            return scene_fail(c, fp, "%d regions; at most %d are supported, merge some boxes", nf, SQ_MAX_CONSTRAINTS);
        i = 0;
        for (const cJSON *e = fx->child; e; e = e->next, i++) {
            scene_join_index(p, sizeof p, fp, i);
            if (parse_constraint(c, e, p, &def->constraints[i]))
                return -1;
        }
        def->nconstraints = nf;
    }

    /* level of detail */
    const cJSON *lod = scene_get_typed(c, obj, path, "lod", 0, 0, &bad);
    if (bad)
        return -1;
    scene_join(p, sizeof p, path, "lod");
    if (parse_lod(c, lod, p, nl, &def->lod))
        return -1;

    def->step_fraction = DEF_STEP_FRACTION;
    if (scene_get_number(c, obj, path, "step_fraction", &def->step_fraction, NULL))
        return -1;
    if (!(def->step_fraction > 0 && def->step_fraction <= 1)) {
        scene_join(p, sizeof p, path, "step_fraction");
        return scene_fail(c, p, "%g is out of range; use a fraction of the stability bound in (0, 1], e.g. 0.9",
                    def->step_fraction);
    }
    def->frame_dt = 1.0 / s->frame_rate;
    memcpy(def->gravity, s->gravity, sizeof def->gravity);

    /* offset: translate the meshes at load (regions, probes and tools are in world space) */
    double offset[3] = {0, 0, 0};
    if (scene_get_vec3(c, obj, path, "offset", offset, NULL))
        return -1;
    if (fabs(offset[0]) > 1e6 || fabs(offset[1]) > 1e6 || fabs(offset[2]) > 1e6) {
        scene_join(p, sizeof p, path, "offset");
        return scene_fail(c, p, "[%g, %g, %g] is out of range; use components below 1e6 m", offset[0], offset[1],
                    offset[2]);
    }

    /* scale: multiply every level's coordinates at load, before the offset (meshes made in
     * millimetres: 0.001) */
    double scale = 1;
    int has_scale = 0;
    if (scene_get_number(c, obj, path, "scale", &scale, &has_scale))
        return -1;
    if (!(scale >= 1e-6 && scale <= 1e6)) {
        scene_join(p, sizeof p, path, "scale");
        return scene_fail(c, p, "%g is out of range; use a factor in [1e-6, 1e6] (0.001 for a mesh in millimetres)",
                    scale);
    }
    if (load_levels(c, s, bi, files, lp, scale, offset, path))
        return -1;

    if (check_regions(c, s, bi, files, path))
        return -1;
    /* corotational elasticity: fem operator (fixed or adaptive lod; docs/physics.md section 9) */
    scene_join(p, sizeof p, path, "elasticity");
    if (def->elasticity == SQ_ELASTICITY_COROTATIONAL && def->op != SQ_OPERATOR_FEM)
        return scene_fail(c, p, "\"corotational\" needs \"operator\": \"fem\" (the paper operator has no corotational "
                          "form here); use \"elasticity\": \"linear\" with the paper operator");
    if (def->integrator == SQ_INTEGRATOR_IMPLICIT && def->lod.mode != SQ_LOD_FIXED) {
        scene_join(p, sizeof p, path, "integrator");
        return scene_fail(c, p, "\"implicit\" runs with fixed lod only (adaptive levels still step explicitly): use "
                          "\"lod\": {\"mode\": \"fixed\"} or \"integrator\": \"explicit\"");
    }
    if (def->nodal_pressure && (def->elasticity != SQ_ELASTICITY_LINEAR || def->op != SQ_OPERATOR_FEM ||
                                def->lod.mode != SQ_LOD_FIXED)) {
        scene_join(p, sizeof p, path, "pressure");
        return scene_fail(c, p, "\"%s\" runs with \"operator\": \"fem\", \"elasticity\": \"linear\" and fixed lod only; "
                          "use those, or \"pressure\": \"element\"",
                          def->nodal_pressure == SQ_PRESSURE_SMOOTHED ? "smoothed" : "nodal");
    }
    return 0;
}
