/* sweep.c - the engine of squish sweep (server/app/cmd_sweep.c): numerical stability at the
 * extremes (issue 7).
 *
 * Every case builds a body through the public engine API (body/body.h) exactly as a scene
 * would, and is either refused (sq_body_create names the reason), accepted and adjusted
 * (the frame is cut into more substeps than asked for), or accepted and run for a long
 * simulated time with a poke that presses, holds and releases. An accepted case passes when
 * no value is non-finite, the engine's blow-up detector never fires (a reset is the safety
 * net, and counts as a failure here), and the energy after the last release stays below the
 * energy seen while the tool acted. Test-only rows step a level directly above its bound
 * (bypassing the body, which never does so) to show what the bound protects against.
 *
 * Near-incompressible material: the locking of linear tets (static tip deflection of a
 * clamped beam against Timoshenko beam theory, sq_sweep_beam_ratio).
 */
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "engines/engines.h"

/* the sweep body: a 10 cm gel-like cube, 4 cells per side, bottom face fixed, gravity */
#define SW_SIZE 0.1
#define SW_CELLS 4

/* default material of the sweep: paper cube values, scene default damping */
static sq_material base_material(void)
{
    sq_material m;
    memset(&m, 0, sizeof m);
    sq_err e = {{0}};
    sq_material_from_E_nu(&m, 1e5, 0.3, &e);
    m.density = 1000;
    m.rayleigh_mass = 0.5;
    m.rayleigh_stiffness = 0.001;
    return m;
}

/* a double pyramid around one sliver: A B C D are the sliver (flat to eps), apex E above its
 * upper faces, F below its lower faces (F is fixed); tets oriented positively */
static sq_mesh *sliver_mesh(double eps, sq_err *err)
{
    const double s = SW_SIZE;
    double x[6][3] = {{0, 0, 0}, {s, s, 0}, {s, 0, eps * s}, {0, s, eps * s},
                      {s / 2, s / 2, s}, {s / 2, s / 2, -s}};
    int t[5][4] = {{0, 1, 2, 3}, {0, 2, 3, 4}, {1, 2, 3, 4}, {0, 1, 2, 5}, {0, 1, 3, 5}};
    for (int k = 0; k < 5; k++) {
        const double *a = x[t[k][0]], *b = x[t[k][1]], *c = x[t[k][2]], *d = x[t[k][3]];
        double u[3], v[3], w[3];
        for (int j = 0; j < 3; j++) {
            u[j] = b[j] - a[j];
            v[j] = c[j] - a[j];
            w[j] = d[j] - a[j];
        }
        double vol = u[0] * (v[1] * w[2] - v[2] * w[1]) - u[1] * (v[0] * w[2] - v[2] * w[0]) +
                     u[2] * (v[0] * w[1] - v[1] * w[0]);
        if (vol < 0) {
            int tmp = t[k][2];
            t[k][2] = t[k][3];
            t[k][3] = tmp;
        }
    }
    return sq_mesh_from_arrays(6, &x[0][0], 5, &t[0][0], "sliver double pyramid", err);
}

static sq_mesh *case_mesh(const sq_sweep_case *c, sq_err *err)
{
    double size[3] = {SW_SIZE, SW_SIZE, SW_SIZE}, origin[3] = {0, 0, 0};
    if (c->mesh == SQ_SWEEP_MESH_SLIVER)
        return sliver_mesh(c->mesh_param, err);
    if (c->mesh == SQ_SWEEP_MESH_BEAM) {
        /* the arc-drag beam: 20 x 2 x 2 cm, 1 cm cells, clamped at x = 0 */
        double bs[3] = {0.2, 0.02, 0.02};
        return sq_mesh_box(20, 2, 2, bs, origin, err);
    }
    if (c->mesh == SQ_SWEEP_MESH_FLAT) {
        /* a plate: thickness mesh_param x the side, one cell thick (needle-like tets) */
        size[2] = SW_SIZE * c->mesh_param;
        return sq_mesh_box(SW_CELLS, SW_CELLS, 1, size, origin, err);
    }
    return sq_mesh_box(SW_CELLS, SW_CELLS, SW_CELLS, size, origin, err);
}

/* the scripted tool at time t (sphere or grab); returns the number of tools (0 or 1) */
static int case_tool(const sq_sweep_case *c, const sq_mesh *m, double t, sq_tool *tool)
{
    memset(tool, 0, sizeof *tool);
    tool->id = 1;
    tool->shape = SQ_TOOL_SPHERE;
    double top = m->bbox_max[2], cx = 0.5 * (m->bbox_min[0] + m->bbox_max[0]);
    double cy = 0.5 * (m->bbox_min[1] + m->bbox_max[1]), side = m->bbox_max[0] - m->bbox_min[0];
    double r = 0.3 * side;
    tool->radius = r;
    tool->pos[0] = cx;
    tool->pos[1] = cy;
    switch (c->load) {
    case SQ_SWEEP_NONE:
        return 0;
    case SQ_SWEEP_POKE:
    case SQ_SWEEP_PERIODIC: {
        double tt = c->load == SQ_SWEEP_PERIODIC ? fmod(t, 2.0) : t;
        /* down over 0.5 s to 30% of the side deep, hold to 1 s, release */
        double depth = 0.3 * side * SQ_MIN(1.0, tt / 0.5);
        tool->active = tt < 1.0;
        tool->pos[2] = top + r - depth;
        return 1;
    }
    case SQ_SWEEP_FAST: {
        /* across the top at 5 m/s, 40% of the side deep, during the first second */
        double x = m->bbox_min[0] - r + fmod(5.0 * t, side + 2 * r);
        tool->active = t < 1.0;
        tool->pos[0] = x;
        tool->pos[2] = top + r - 0.4 * side;
        return 1;
    }
    case SQ_SWEEP_DEEP: {
        /* centre from above the top to the body centre over 0.5 s, held, out at 1 s */
        double zc = 0.5 * (m->bbox_min[2] + top);
        double f = SQ_MIN(1.0, t / 0.5);
        tool->active = t < 1.0;
        tool->pos[2] = (top + r) * (1 - f) + zc * f;
        return 1;
    }
    case SQ_SWEEP_ARC: {
        /* grab the tip (radius 15.2 mm about its centre) and drag it through 90 degrees about the
         * clamp over 0.5 s, then hold */
        tool->shape = SQ_TOOL_GRAB;
        tool->radius = 0.0152;
        tool->active = 1;
        tool->origin[0] = 0.205, tool->origin[1] = 0.01, tool->origin[2] = 0.01;
        tool->has_origin = 1;
        double th = 0.5 * M_PI * SQ_MIN(1.0, t / 0.5);
        tool->pos[0] = tool->origin[0] + 0.2 * (cos(th) - 1);
        tool->pos[1] = tool->origin[1];
        tool->pos[2] = tool->origin[2] + 0.2 * sin(th);
        return 1;
    }
    case SQ_SWEEP_GRAB: {
        /* grab the top corner and pull it 10 sides up and out over 0.5 s, release at 1 s */
        tool->shape = SQ_TOOL_GRAB;
        tool->radius = 0.2 * side;
        double f = SQ_MIN(1.0, t / 0.5);
        tool->active = t < 1.0;
        tool->pos[0] = m->bbox_max[0] + 10 * side * f;
        tool->pos[1] = m->bbox_max[1];
        tool->pos[2] = top + 10 * side * f;
        /* captured at the corner itself (at 10 Hz the first frame's pose is already 2 sizes off) */
        tool->origin[0] = m->bbox_max[0];
        tool->origin[1] = m->bbox_max[1];
        tool->origin[2] = top;
        tool->has_origin = 1;
        return 1;
    }
    }
    return 0;
}

/* total mechanical energy relative to rest: kinetic + elastic + gravity potential
 * (-sum m_i g . d_i) of the simulated level; conserved by the undamped system, decreasing
 * with damping, changed only by the tools */
static int values_level(const sq_body *b)
{
    return sq_body_sim_level(b);
}

static double total_energy(sq_body *b)
{
    const sq_level *L = sq_body_level(b, values_level(b));
    const double *g = sq_body_get_def(b)->gravity;
    double ep = 0;
    for (int i = 0; i < L->model.n; i++)
        ep -= L->model.mass[i] * (g[0] * L->state.d[3 * i] + g[1] * L->state.d[3 * i + 1] + g[2] * L->state.d[3 * i + 2]);
    return sq_body_kinetic_energy(b) + sq_body_elastic_energy(b) + ep;
}

/* the test-only path: step the level directly at above_bound x its bound, from a small
 * alternating displacement (which excites the highest modes), no health check */
static void run_above_bound(sq_body *b, const sq_sweep_case *c, sq_sweep_result *r)
{
    sq_level *L = sq_body_level(b, sq_body_fixed_level(b));
    const sq_body_def *def = sq_body_get_def(b);
    double dt = c->above_bound * L->bound;
    for (int i = 0; i < L->model.n; i++)
        for (int k = 0; k < 3; k++)
            L->state.d[3 * i + k] = (L->model.fixed[i] & (1u << k)) ? 0 : 1e-6 * SW_SIZE * ((i + k) % 2 ? 1 : -1);
    double d0 = 1e-6 * SW_SIZE, dmax = 0;
    int steps = 4000, s;
    for (s = 0; s < steps; s++) {
        sq_level_forces(&L->model, &L->state, &def->material, def->gravity, NULL);
        sq_level_integrate(&L->model, &L->state, dt, NULL);
        dmax = 0;
        for (int i = 0; i < 3 * L->model.n; i++)
            dmax = isfinite(L->state.d[i]) && isfinite(dmax) ? fmax(dmax, fabs(L->state.d[i])) : NAN;
        if (!isfinite(dmax) || dmax > 1e6 * SW_SIZE)
            break;
    }
    r->dt = dt;
    r->max_disp = dmax;
    /* gravity alone sags the body by up to ~rho g H^2 / (2 (lambda + 2 mu)); growth far above
     * that from a 1e-7 m start is the instability */
    double sag = def->material.density * 9.81 * SW_SIZE * SW_SIZE / (def->material.lambda + 2 * def->material.mu);
    int blew = !isfinite(dmax) || dmax > 100 * (sag + d0);
    snprintf(r->status, sizeof r->status, "%s", blew ? "blows up (test-only)" : "stays bounded (test-only)");
    snprintf(r->note, sizeof r->note,
             "test-only: level stepped directly at %.3g x its bound (%.3g s) for %d steps: largest displacement %.3g m "
             "(static sag ~%.2g m)%s",
             c->above_bound, L->bound, s < steps ? s + 1 : steps, dmax, sag,
             blew ? "; the body never does this: it cuts the frame into substeps below the bound" : "");
    sq_body_reset(b);
}

/* the case's meshes (m, the finest, returned; extra: the coarser levels of an adaptive case) and
 * body definition, as a scene would give them; NULL when the mesh is refused (err) */
static sq_mesh *case_def(const sq_sweep_case *c, sq_body_def *def, sq_mesh *extra[2], sq_err *err)
{
    sq_mesh *m = case_mesh(c, err);
    if (!m)
        return NULL;
    *def = sq_body_def_default();
    def->name = "sweep";
    def->nlevels = 1;
    def->levels[0] = m;
    if (c->split > 0) {
        /* adaptive: levels of 2, 3 and 5 cells per side (non-nested grids), m the finest */
        double size[3] = {SW_SIZE, SW_SIZE, SW_SIZE}, origin[3] = {0, 0, 0};
        extra[0] = sq_mesh_box(2, 2, 2, size, origin, err);
        extra[1] = sq_mesh_box(3, 3, 3, size, origin, err);
        sq_mesh_free(m);
        m = sq_mesh_box(5, 5, 5, size, origin, err);
        def->nlevels = 3;
        def->levels[0] = extra[0];
        def->levels[1] = extra[1];
        def->levels[2] = m;
        def->lod.mode = SQ_LOD_ADAPTIVE;
        def->lod.level = 0;
        def->lod.max_level = 2;
        def->lod.split = c->split;
        def->lod.merge = 0.4 * c->split;
    }
    def->material = c->mat;
    def->op = c->op;
    def->gravity[2] = -9.81;
    def->frame_dt = 1.0 / (c->frame_rate > 0 ? c->frame_rate : 50);
    def->step_fraction = c->step_fraction > 0 ? c->step_fraction : 0.9;
    def->nconstraints = 1;
    def->constraints[0].kind = SQ_REGION_HALFSPACE; /* the bottom (z <= min z + 1e-9) fixed */
    def->constraints[0].a[2] = m->bbox_min[2] + 1e-9 * SW_SIZE;
    def->constraints[0].b[2] = 1;
    def->constraints[0].axes = 7;
    if (c->mesh == SQ_SWEEP_MESH_BEAM) { /* clamped at x = 0 instead */
        memset(&def->constraints[0], 0, sizeof def->constraints[0]);
        def->constraints[0].kind = SQ_REGION_HALFSPACE;
        def->constraints[0].a[0] = 1e-9;
        def->constraints[0].b[0] = 1;
        def->constraints[0].axes = 7;
    }
    def->elasticity = c->elasticity;
    /* the Gershgorin bound: the sweep checks it at the extremes, its table's "bound" column and
     * the test-only steps at 1, 1.5 and 2 x the bound are Gershgorin's (docs/stability.md); the
     * sharp rule, every body's default, has its own tests */
    def->sharp_step = 0;
    def->integrator = c->integrator;
    if (c->integrator == SQ_INTEGRATOR_IMPLICIT) {
        def->implicit.substeps = c->substeps > 0 ? c->substeps : 1;
        def->implicit.max_iter = SQ_IMPLICIT_MAX_ITER;
    }
    if (c->frame_vs_bound > 0) {
        /* a frame period of frame_vs_bound x the level's bound: find the bound first */
        sq_body *probe = sq_body_create(def, err);
        if (probe) {
            def->frame_dt = c->frame_vs_bound * sq_body_level_bound(probe, 0);
            sq_body_destroy(probe);
        }
    }
    return m;
}

static void case_free(sq_mesh *m, sq_mesh *extra[2])
{
    sq_mesh_free(m);
    sq_mesh_free(extra[0]);
    sq_mesh_free(extra[1]);
}

/* what the frames of a case showed */
typedef struct sw_stats {
    double e_load, e_late, e_abs, dmax, cg_res;
    int nonfinite, max_fine, cg_max, unconverged;
    long cg_sum;
} sw_stats;

/* the case's frames under its load: energy, displacement, resets, CG counts */
static void case_frames(const sq_sweep_case *c, const sq_body_def *def, sq_body *b, const sq_mesh *m, long nframes,
                        sw_stats *st, sq_sweep_result *r)
{
    *st = (sw_stats){-INFINITY, -INFINITY, 0, 0, 0, 0, 0, 0, 0, 0};
    double release = c->load == SQ_SWEEP_NONE ? 0 : 1.0; /* last tool action ends at 1 s (periodic: never) */
    for (long f = 1; f <= nframes; f++) {
        double t = f * def->frame_dt;
        sq_tool tool;
        int nt = case_tool(c, m, t, &tool);
        sq_frame_profile prof;
        sq_body_frame(b, &tool, nt, NULL, &prof, 0);
        if (c->split > 0)
            st->max_fine = SQ_MAX(st->max_fine, prof.active[2]);
        st->cg_sum += prof.cg_iterations;
        st->cg_max = SQ_MAX(st->cg_max, prof.cg_iterations);
        st->cg_res = fmax(st->cg_res, prof.cg_residual);
        st->unconverged += prof.event_kind == SQ_HEALTH_SOLVE_UNCONVERGED;
        if (prof.reset) {
            r->resets++;
            if (!r->note[0])
                snprintf(r->note, sizeof r->note, "frame %ld: %.200s", f, prof.event);
        }
        double e = total_energy(b);
        const double *d = sq_body_displacement(b, values_level(b));
        for (int i = 0; i < 3 * m->nnodes; i++) {
            if (!isfinite(d[i]))
                st->nonfinite = 1;
            else
                st->dmax = fmax(st->dmax, fabs(d[i]));
        }
        if (!isfinite(e)) {
            st->nonfinite = 1;
        } else {
            st->e_abs = fmax(st->e_abs, fabs(e));
            if (t <= release + 0.2 || c->load == SQ_SWEEP_PERIODIC)
                st->e_load = fmax(st->e_load, e);
        }
        if (f > nframes - nframes / 4 && isfinite(e))
            st->e_late = fmax(st->e_late, e);
    }
}

/* the case's status and note from its frames */
static void case_verdict(const sq_sweep_case *c, const sq_body_def *def, sq_body *b, const sq_mesh *m,
                         long nframes, const sw_stats *st, sq_sweep_result *r)
{
    r->frames = nframes;
    r->max_disp = st->dmax;
    if (c->split > 0 && !r->note[0])
        snprintf(r->note, sizeof r->note, "finest level active on up to %d of %d nodes", st->max_fine, m->nnodes);
    if (c->integrator == SQ_INTEGRATOR_IMPLICIT && !r->note[0])
        snprintf(r->note, sizeof r->note,
                 "implicit, %d step(s) of %.3g s per frame (explicit: %d substeps): CG %.0f iterations per frame "
                 "(max %d), residual <= %.2g, %d unconverged frames",
                 def->implicit.substeps, r->dt, sq_body_get_def(b)->sharp_step ? sq_body_level(b, 0)->nsub
                                                                            : 1 << sq_body_level(b, 0)->substeps_log2,
                 nframes ? (double)st->cg_sum / nframes : 0.0, st->cg_max, st->cg_res, st->unconverged);
    r->e_load = st->e_load;
    r->e_late = st->e_late;
    /* bounded: the late energy does not exceed what the loading phase reached; slack 10% of the
     * largest |energy| seen (+1e-12 J): the energy symplectic Euler conserves differs from the
     * measured one by O(w dt), a few % when the top modes hold energy; a blow-up grows
     * exponentially and overshoots this by orders of magnitude (and trips the detector) */
    int bounded = st->e_late <= st->e_load + 0.1 * fmax(fabs(st->e_load), st->e_abs) + 1e-12;
    if (st->nonfinite || r->resets || !bounded) {
        r->failed = 1;
        snprintf(r->status, sizeof r->status, "UNSTABLE");
        if (!r->resets)
            snprintf(r->note, sizeof r->note, "%s", st->nonfinite ? "non-finite values" :
                     "energy in the last quarter above the loaded phase");
    } else if (c->frame_vs_bound > 1) {
        snprintf(r->status, sizeof r->status, "adjusted, stable");
        if (!r->note[0])
            snprintf(r->note, sizeof r->note, "frame %.3g s cut into %d substeps of %.3g s (<= %.3g x bound %.3g s)",
                     def->frame_dt, r->substeps, r->dt, def->step_fraction, r->bound);
    } else {
        snprintf(r->status, sizeof r->status, "stable");
    }
}

/* run one case; fills r */
void sq_sweep_run_case(const sq_sweep_case *c, double work_cap, sq_sweep_result *r)
{
    memset(r, 0, sizeof *r);
    double w0 = sq_now();
    sq_err err = {{0}};
    sq_body_def def;
    sq_mesh *extra[2] = {NULL, NULL};
    sq_mesh *m = case_def(c, &def, extra, &err);
    if (!m) {
        snprintf(r->status, sizeof r->status, "refused");
        snprintf(r->note, sizeof r->note, "mesh refused: %.200s", err.msg);
        r->wall = sq_now() - w0;
        return;
    }
    sq_body *b = sq_body_create(&def, &err);
    if (!b) {
        snprintf(r->status, sizeof r->status, "refused");
        snprintf(r->note, sizeof r->note, "%.230s", err.msg);
        case_free(m, extra);
        r->wall = sq_now() - w0;
        return;
    }
    r->bound = sq_body_level_bound(b, values_level(b));
    r->dt = sq_body_level_dt(b, values_level(b));
    r->substeps = (int)lround(def.frame_dt / r->dt);
    r->steps_per_s = r->substeps / def.frame_dt;
    if (c->above_bound > 0) {
        run_above_bound(b, c, r);
        r->failed = 0; /* not an accepted case: the body would never run it */
        sq_body_destroy(b);
        case_free(m, extra);
        r->wall = sq_now() - w0;
        return;
    }

    /* the run, within the sweep's work cap (node updates per case) */
    long nframes = (long)ceil(c->seconds / def.frame_dt - 1e-9);
    double per_frame = (double)r->substeps * m->nnodes;
    if (nframes * per_frame > work_cap) {
        long capped = SQ_MAX(2L, (long)(work_cap / per_frame));
        if (capped < nframes) {
            snprintf(r->note, sizeof r->note, "run cut to %ld frames (%.3g s, %.3g steps) by the sweep's work cap", capped,
                     capped * def.frame_dt, (double)capped * r->substeps);
            nframes = capped;
        }
    }
    sw_stats st;
    case_frames(c, &def, b, m, nframes, &st, r);
    case_verdict(c, &def, b, m, nframes, &st, r);
    sq_body_destroy(b);
    case_free(m, extra);
    r->wall = sq_now() - w0;
}

/* ---- the case list ---------------------------------------------------------------------- */

static int add(sq_sweep_case *cs, int n, const char *group, const char *fmt, double v)
{
    sq_sweep_case *c = &cs[n];
    memset(c, 0, sizeof *c);
    c->group = group;
    snprintf(c->name, sizeof c->name, fmt, v);
    c->mat = base_material();
    c->op = SQ_OPERATOR_FEM;
    c->seconds = 5;
    c->load = SQ_SWEEP_POKE;
    return n + 1;
}

static int set_E_nu(sq_material *m, double E, double nu)
{
    sq_err e = {{0}};
    return sq_material_from_E_nu(m, E, nu, &e);
}

/* the material's extremes: Young's modulus, Poisson ratio, density, damping; returns the new count */
static int cases_material(sq_sweep_case *cs, int n, int quick)
{
    double secs = quick ? 3 : 10;
    static const double Es[] = {1e2, 1e3, 1e4, 1e5, 1e6, 1e7, 1e8, 1e9};
    for (size_t k = 0; k < SQ_COUNTOF(Es); k++) {
        n = add(cs, n, "young", "E = %g Pa (nu 0.3)", Es[k]);
        set_E_nu(&cs[n - 1].mat, Es[k], 0.3);
        cs[n - 1].seconds = Es[k] >= 1e8 ? (quick ? 1.5 : 3) : secs;
    }
    /* the stiff end with light stiffness damping (b = 1e-6 s) */
    for (size_t k = 6; k < SQ_COUNTOF(Es); k++) {
        n = add(cs, n, "young", "E = %g Pa, b = 1e-6 s", Es[k]);
        set_E_nu(&cs[n - 1].mat, Es[k], 0.3);
        cs[n - 1].mat.rayleigh_stiffness = 1e-6;
        cs[n - 1].seconds = quick ? 1.5 : 3;
    }
    static const double nus[] = {0, 0.2, 0.3, 0.4, 0.45, 0.49, 0.499};
    for (size_t k = 0; k < SQ_COUNTOF(nus); k++) {
        n = add(cs, n, "poisson", "nu = %g (E 1e5 Pa)", nus[k]);
        set_E_nu(&cs[n - 1].mat, 1e5, nus[k]);
        cs[n - 1].seconds = secs;
    }
    n = add(cs, n, "poisson", "nu = %g (paper operator)", 0.499);
    set_E_nu(&cs[n - 1].mat, 1e5, 0.499);
    cs[n - 1].op = SQ_OPERATOR_PAPER;
    static const double rhos[] = {10, 100, 1000, 1e4};
    for (size_t k = 0; k < SQ_COUNTOF(rhos); k++) {
        n = add(cs, n, "density", "density = %g kg/m^3", rhos[k]);
        cs[n - 1].mat.density = rhos[k];
        cs[n - 1].seconds = secs;
    }
    /* damping: none, mass only up to very high, stiffness up to very high, viscosities */
    n = add(cs, n, "damping", "no damping (a = b = %g)", 0);
    cs[n - 1].mat.rayleigh_mass = cs[n - 1].mat.rayleigh_stiffness = 0;
    cs[n - 1].seconds = secs;
    static const double as[] = {5, 100, 1e4};
    for (size_t k = 0; k < SQ_COUNTOF(as); k++) {
        n = add(cs, n, "damping", "mass damping a = %g 1/s", as[k]);
        cs[n - 1].mat.rayleigh_mass = as[k];
        cs[n - 1].seconds = secs;
    }
    static const double bs[] = {0, 1e-2, 1e-1, 10};
    for (size_t k = 0; k < SQ_COUNTOF(bs); k++) {
        n = add(cs, n, "damping", "stiffness damping b = %g s", bs[k]);
        cs[n - 1].mat.rayleigh_stiffness = bs[k];
        cs[n - 1].seconds = bs[k] >= 1e-1 ? (quick ? 1.5 : 3) : secs;
    }
    static const double phis[] = {10, 1000};
    for (size_t k = 0; k < SQ_COUNTOF(phis); k++) {
        n = add(cs, n, "damping", "viscosity phi = psi = %g Pa s", phis[k]);
        cs[n - 1].mat.use_viscosity = 1;
        cs[n - 1].mat.rayleigh_stiffness = 0;
        cs[n - 1].mat.phi = cs[n - 1].mat.psi = phis[k];
        cs[n - 1].seconds = quick ? 1.5 : 3;
    }
    return n;
}

/* the step against the bound, fast and deep tools, degenerate meshes; returns the new count */
static int cases_step_tool_mesh(sq_sweep_case *cs, int n, int quick)
{
    double secs = quick ? 3 : 10;
    /* the step: fraction requests, frame periods above the bound, and the test-only path */
    static const double fr[] = {0.1, 0.25, 0.5, 0.9, 1.0, 1.5, 2.0};
    for (size_t k = 0; k < SQ_COUNTOF(fr); k++) {
        n = add(cs, n, "step", "step_fraction = %g", fr[k]);
        cs[n - 1].step_fraction = fr[k];
        cs[n - 1].frame_vs_bound = 0.99; /* one frame = 0.99 bound: the fraction decides substeps */
        cs[n - 1].seconds = quick ? 2 : 5;
    }
    static const double fb[] = {0.1, 0.5, 1.5, 2.0};
    for (size_t k = 0; k < SQ_COUNTOF(fb); k++) {
        n = add(cs, n, "step", "frame period = %g x bound", fb[k]);
        cs[n - 1].frame_vs_bound = fb[k];
        cs[n - 1].seconds = quick ? 1 : 3;
    }
    static const double ab[] = {1.0, 1.5, 2.0};
    for (size_t k = 0; k < SQ_COUNTOF(ab); k++) {
        n = add(cs, n, "step", "level at %g x bound (test-only)", ab[k]);
        cs[n - 1].above_bound = ab[k];
        cs[n - 1].mat.rayleigh_mass = cs[n - 1].mat.rayleigh_stiffness = 0;
    }
    n = add(cs, n, "step", "level at %g x bound, damped (test-only)", 2.0);
    cs[n - 1].above_bound = 2.0;
    /* tools */
    n = add(cs, n, "tool", "fast sphere, %g m/s, 40%% deep", 5);
    cs[n - 1].load = SQ_SWEEP_FAST;
    cs[n - 1].seconds = secs;
    n = add(cs, n, "tool", "deep sphere, centre to the body centre%.0s", 0);
    cs[n - 1].load = SQ_SWEEP_DEEP;
    cs[n - 1].seconds = secs;
    n = add(cs, n, "tool", "grab, pulled %g body sizes away", 10);
    cs[n - 1].load = SQ_SWEEP_GRAB;
    cs[n - 1].seconds = secs;
    n = add(cs, n, "tool", "grab, %g body sizes, no damping", 10);
    cs[n - 1].load = SQ_SWEEP_GRAB;
    cs[n - 1].mat.rayleigh_mass = cs[n - 1].mat.rayleigh_stiffness = 0;
    cs[n - 1].seconds = secs;
    /* meshes: slivers of decreasing flatness, a thin plate */
    static const double eps[] = {1e-1, 1e-2, 1e-3, 1e-4, 1e-8, 1e-10};
    for (size_t k = 0; k < SQ_COUNTOF(eps); k++) {
        n = add(cs, n, "mesh", "sliver, flatness %g", eps[k]);
        cs[n - 1].mesh = SQ_SWEEP_MESH_SLIVER;
        cs[n - 1].mesh_param = eps[k];
        cs[n - 1].mat.rayleigh_stiffness = 0; /* b K would cap the bound at ~4/(b w^2) */
        cs[n - 1].seconds = eps[k] < 1e-2 ? 0.5 : (quick ? 1 : 3);
        cs[n - 1].load = SQ_SWEEP_NONE;
    }
    n = add(cs, n, "mesh", "sliver, flatness %g, b = 1e-3 s", 1e-2);
    cs[n - 1].mesh = SQ_SWEEP_MESH_SLIVER;
    cs[n - 1].mesh_param = 1e-2;
    cs[n - 1].load = SQ_SWEEP_NONE;
    cs[n - 1].seconds = 0.5;
    static const double th[] = {1e-2, 1e-3};
    for (size_t k = 0; k < SQ_COUNTOF(th); k++) {
        n = add(cs, n, "mesh", "plate, thickness %g x side", th[k]);
        cs[n - 1].mesh = SQ_SWEEP_MESH_FLAT;
        cs[n - 1].mesh_param = th[k];
        cs[n - 1].mat.rayleigh_stiffness = 0;
        cs[n - 1].load = SQ_SWEEP_NONE;
        cs[n - 1].seconds = quick ? 0.5 : 2;
    }
    return n;
}

/* the adaptive engine, the corotational arc, the implicit integrator, the very long run; returns the new count */
static int cases_adaptive_implicit(sq_sweep_case *cs, int n, int quick)
{
    /* the adaptive engine: three levels, thresholds from "refine everywhere" to "hardly ever" */
    static const double splits[] = {1e-6, 1e-3, 3e-3, 1e-2};
    for (size_t k = 0; k < SQ_COUNTOF(splits); k++) {
        n = add(cs, n, "adaptive", "3 levels, split %g m", splits[k]);
        cs[n - 1].split = splits[k];
        cs[n - 1].seconds = quick ? 2 : 5;
    }
    n = add(cs, n, "adaptive", "3 levels, split %g m, deep sphere", 3e-3);
    cs[n - 1].split = 3e-3;
    cs[n - 1].load = SQ_SWEEP_DEEP;
    cs[n - 1].seconds = quick ? 2 : 5;
    n = add(cs, n, "adaptive", "3 levels, split %g m, E 1e7 Pa", 3e-3);
    cs[n - 1].split = 3e-3;
    set_E_nu(&cs[n - 1].mat, 1e7, 0.3);
    cs[n - 1].mat.rayleigh_stiffness = 1e-6;
    cs[n - 1].seconds = quick ? 1 : 3;
    n = add(cs, n, "adaptive", "3 levels, split %g m, nu 0.49", 3e-3);
    cs[n - 1].split = 3e-3;
    set_E_nu(&cs[n - 1].mat, 1e5, 0.49);
    cs[n - 1].seconds = quick ? 1 : 3;
    n = add(cs, n, "adaptive", "3 levels, split %g m, grab 10 sizes, undamped", 3e-3);
    cs[n - 1].split = 3e-3;
    cs[n - 1].load = SQ_SWEEP_GRAB;
    cs[n - 1].mat.rayleigh_mass = cs[n - 1].mat.rayleigh_stiffness = 0;
    cs[n - 1].seconds = quick ? 2 : 5;
    /* issue 23: the corotational beam dragged through 90 degrees in 0.5 s, explicit at its
     * bound and implicit at one step per frame */
    for (int in = 0; in < 2; in++) {
        n = add(cs, n, "arc", in ? "corotational beam, 90 deg in 0.5 s, implicit%.0s" :
                                   "corotational beam, 90 deg in 0.5 s, explicit%.0s", 0);
        sq_sweep_case *c = &cs[n - 1];
        c->mesh = SQ_SWEEP_MESH_BEAM;
        c->load = SQ_SWEEP_ARC;
        c->elasticity = SQ_ELASTICITY_COROTATIONAL;
        c->integrator = in ? SQ_INTEGRATOR_IMPLICIT : SQ_INTEGRATOR_EXPLICIT;
        set_E_nu(&c->mat, 2e6, 0.45);
        c->mat.rayleigh_mass = 30;
        c->mat.rayleigh_stiffness = 0;
        c->seconds = quick ? 1 : 2;
    }
    /* the implicit integrator at the extremes: stiffness to E 1e10, nu to 0.499, frames to 0.1 s */
    static const double iEs[] = {1e6, 1e8, 1e10};
    static const double ihz[] = {50, 10};
    for (size_t k = 0; k < SQ_COUNTOF(iEs); k++)
        for (size_t j = 0; j < SQ_COUNTOF(ihz); j++) {
            char name[96];
            snprintf(name, sizeof name, "implicit, E = %g Pa, h = %g s%%.0s", iEs[k], 1 / ihz[j]);
            n = add(cs, n, "implicit", name, 0);
            sq_sweep_case *c = &cs[n - 1];
            set_E_nu(&c->mat, iEs[k], 0.3);
            c->integrator = SQ_INTEGRATOR_IMPLICIT;
            c->frame_rate = ihz[j];
            c->seconds = quick ? 2 : 5;
        }
    static const double inus[] = {0.49, 0.499};
    for (size_t k = 0; k < SQ_COUNTOF(inus); k++)
        for (int stiff = 0; stiff < 2; stiff++) {
            char name[96];
            snprintf(name, sizeof name, "implicit, nu = %g, E = %g Pa, h = 0.1 s%%.0s", inus[k], stiff ? 1e10 : 1e5);
            n = add(cs, n, "implicit", name, 0);
            sq_sweep_case *c = &cs[n - 1];
            set_E_nu(&c->mat, stiff ? 1e10 : 1e5, inus[k]);
            c->integrator = SQ_INTEGRATOR_IMPLICIT;
            c->frame_rate = 10;
            c->seconds = quick ? 2 : 5;
        }
    n = add(cs, n, "implicit", "implicit, grab %g body sizes, undamped, h = 0.1 s", 10);
    cs[n - 1].load = SQ_SWEEP_GRAB;
    cs[n - 1].integrator = SQ_INTEGRATOR_IMPLICIT;
    cs[n - 1].frame_rate = 10;
    cs[n - 1].mat.rayleigh_mass = cs[n - 1].mat.rayleigh_stiffness = 0;
    cs[n - 1].seconds = quick ? 2 : 5;
    n = add(cs, n, "implicit", "implicit corotational, grab %g body sizes, E 1e10 Pa, h = 0.1 s", 10);
    cs[n - 1].load = SQ_SWEEP_GRAB;
    cs[n - 1].integrator = SQ_INTEGRATOR_IMPLICIT;
    cs[n - 1].elasticity = SQ_ELASTICITY_COROTATIONAL;
    set_E_nu(&cs[n - 1].mat, 1e10, 0.45);
    cs[n - 1].frame_rate = 10;
    cs[n - 1].seconds = quick ? 2 : 5;
    /* the very long run: a poke every 2 s */
    n = add(cs, n, "long", "%g s simulated, a poke every 2 s", quick ? 120 : 3600);
    cs[n - 1].load = SQ_SWEEP_PERIODIC;
    cs[n - 1].mat.rayleigh_stiffness = 0;
    cs[n - 1].seconds = quick ? 120 : 3600;
    return n;
}

/* build the list; returns the count (cs has room for 128) */
int sq_sweep_build_cases(sq_sweep_case *cs, int quick)
{
    int n = cases_material(cs, 0, quick);
    n = cases_step_tool_mesh(cs, n, quick);
    return cases_adaptive_implicit(cs, n, quick);
}

/* ---- locking and cost against nu ---------------------------------------------------------- */

/* clamped beam L x h x h (x = 0 face fixed), gravity -z: static tip deflection / Timoshenko */
double sq_sweep_beam_ratio(double nu, int nx, int nh, sq_operator_kind op, double *tip_fem, double *tip_th,
                         int *substeps, sq_err *err)
{
    const double Lb = 1, h = 0.1, E = 1e6, rho = 1000, g = 9.81;
    double size[3] = {Lb, h, h}, origin[3] = {0, 0, 0};
    sq_mesh *m = sq_mesh_box(nx, nh, nh, size, origin, err);
    if (!m)
        return NAN;
    sq_material mat = base_material();
    sq_material_from_E_nu(&mat, E, nu, err);
    mat.density = rho;
    sq_constraint c;
    memset(&c, 0, sizeof c);
    c.kind = SQ_REGION_HALFSPACE;
    c.a[0] = 1e-9;
    c.b[0] = 1;
    c.axes = 7;
    sq_level L;
    double ratio = NAN;
    if (sq_level_init(&L, m, &mat, op, &c, 1, err) == 0) {
        if (sq_level_choose_step(&L, &mat, 1.0 / 50, 0.9, err) == 0)
            *substeps = 1 << L.substeps_log2;
        else
            *substeps = -1;
        double grav[3] = {0, 0, -g}, *d = sq_malloc(sizeof(double) * 3 * (size_t)m->nnodes);
        if (sq_level_static_solve(&L.model, grav, 1e-10, 20000, d, NULL, err) == 0) {
            /* mean z displacement of the tip face x = L */
            double s = 0;
            int cnt = 0;
            for (int i = 0; i < m->nnodes; i++)
                if (m->x[3 * i] > Lb - 1e-9) {
                    s += d[3 * i + 2];
                    cnt++;
                }
            double A = h * h, I = h * h * h * h / 12, q = rho * g * A, G = E / (2 * (1 + nu));
            *tip_th = q * pow(Lb, 4) / (8 * E * I) + q * Lb * Lb / (2 * (5.0 / 6.0) * G * A);
            *tip_fem = -s / cnt;
            ratio = *tip_fem / *tip_th;
        }
        free(d);
        sq_level_free(&L);
    }
    sq_mesh_free(m);
    return ratio;
}

