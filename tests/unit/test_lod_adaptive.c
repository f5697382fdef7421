/* test_lod_adaptive.c - the adaptive frame: criterion, a scripted poke that refines near the
 * tool and merges back, energy across split/merge and over a long undamped run, the times of
 * the frame's stages, the frame budget and the node-update cap, sleep, tool feedback at
 * equilibrium. */
#include <float.h>
#include <stdint.h>

#include "lod/lod.h"
#include "body/body_internal.h"
#include "sq_test.h"
#include "test_lod_helpers.h"

/* the scripted poke: a 0.2 m sphere presses the top face 0.1 m deep over 0.5 s, holds, and
 * is released at t = 1 s */
static sq_tool poke_tool(double t)
{
    double depth = t < 0.5 ? 0.1 * t / 0.5 : 0.1;
    return lh_sphere(0.5, 0.5, 1.2 - depth, 0.2, t < 1.0);
}

/* levels initialised for the paper's material, each at its own step for 50 Hz */
static int make_levels(sq_level *lv, sq_mesh **m, int n, const sq_material *mat)
{
    sq_constraint c = lh_bottom_fixed();
    sq_err e = {{0}};
    for (int k = 0; k < n; k++)
        if (sq_level_init(&lv[k], m[k], mat, SQ_OPERATOR_FEM, &c, 1, &e) ||
            sq_level_choose_step(&lv[k], mat, 0.02, 0.9, &e)) {
            fprintf(stderr, "level %d: %s\n", k, e.msg);
            return 0;
        }
    return 1;
}

/* ------------------------------------------------------------------ criterion */

SQ_TEST(lod_criterion_zero_on_linear_fields_curvature_inside)
{
    sq_mesh *m[2];
    if (!lh_cube_levels(m, 2, (const int[]){4, 6})) {
        CHECK(0);
        return;
    }
    sq_material mat = lh_paper_material();
    sq_level lv[2];
    CHECK(make_levels(lv, m, 2, &mat));
    sq_lod_def def = lh_lod(SQ_LOD_ADAPTIVE, INFINITY, 0.001);
    sq_err e = {{0}};
    sq_lod *lod = sq_lod_create(lv, 2, &def, &e);
    CHECK(lod != NULL);
    if (!lod)
        return;
    /* a linear field (stretch, shear, translation) has zero criterion at every node, surface
     * nodes included: 1e-12 m is rounding for 1 cm displacements */
    for (int k = 0; k < 2; k++)
        for (int i = 0; i < lv[k].model.n; i++) {
            const double *x = m[k]->x + 3 * i;
            lv[k].state.d[3 * i] = 0.01 * x[0] + 0.003 * x[1] + 0.002;
            lv[k].state.d[3 * i + 1] = -0.004 * x[2];
            lv[k].state.d[3 * i + 2] = 0.005 * x[0] - 0.001;
        }
    double worst = 0;
    for (int k = 0; k < 2; k++)
        for (int i = 0; i < lv[k].model.n; i++)
            worst = fmax(worst, sq_lod_delta(lod, k, i));
    CHECK(worst < 1e-12);
    /* d = (a x^2, 0, 0): Lap = 2a; on interior nodes of the regular level-0 box the
     * criterion is hbar^2 2a (the lumped FEM Laplacian is exact for quadratics on this
     * symmetric grid up to the lumping: 10%) */
    double a = 0.05;
    for (int i = 0; i < lv[0].model.n; i++) {
        const double *x = m[0]->x + 3 * i;
        lv[0].state.d[3 * i] = a * x[0] * x[0];
        lv[0].state.d[3 * i + 1] = lv[0].state.d[3 * i + 2] = 0;
    }
    int checked = 0;
    for (int i = 0; i < lv[0].model.n; i++) {
        if (m[0]->on_boundary[i])
            continue;
        double expect = lv[0].model.hbar[i] * lv[0].model.hbar[i] * 2 * a;
        CHECK_NEAR(sq_lod_delta(lod, 0, i), expect, 0.1 * expect);
        checked++;
    }
    CHECK(checked == 27);
    sq_lod_destroy(lod);
    for (int k = 0; k < 2; k++)
        sq_level_free(&lv[k]);
    lh_free_meshes(m, 2);
}

/* ------------------------------------------------------------------ scripted poke */

SQ_TEST(lod_poke_refines_near_tool_and_merges_back)
{
    sq_mesh *m[3];
    if (!lh_poke_meshes(m)) {
        CHECK(0);
        return;
    }
    sq_body_def def = lh_poke_def(m, 0); /* no gravity: the poke alone deforms it, refinement must follow the tool */
    sq_err e = {{0}};
    sq_body *b = lh_body(&def);
    CHECK(b != NULL);
    if (!b) {
        lh_free_meshes(m, 3);
        return;
    }
    sq_frame_profile prof;
    double far_max = 0;
    long upper = 0, total_fine = 0;
    int max_fine = 0, bad_tree = 0, far_fine = 0, all_coarse_frame = -1, splits = 0, merges = 0;
    double release = 1.0;
    for (int f = 0; f < 200; f++) {
        double t = f * def.frame_dt;
        sq_tool tool = poke_tool(t);
        sq_body_frame(b, &tool, 1, NULL, &prof, 0);
        splits += prof.splits;
        merges += prof.merges;
        if (sq_lod_check(b->lod, &e)) {
            bad_tree++;
            fprintf(stderr, "frame %d: %s\n", f, e.msg);
        }
        max_fine = SQ_MAX(max_fine, prof.active[2]);
        /* while pressing, the finest level gathers under the tool (the 10 cm poke on a 1 m
         * cube deforms the whole top face): most finest active nodes in the upper half, none
         * in the bottom fifth */
        if (t < release) {
            const unsigned char *act = sq_lod_active(b->lod, 2);
            for (int i = 0; i < m[2]->nnodes; i++) {
                if (!act[i])
                    continue;
                double z = m[2]->x[3 * i + 2];
                far_fine += z < 0.2;
                upper += z > 0.5;
                total_fine++;
                far_max = fmax(far_max, 1.0 - z);
            }
        }
        if (t > release && all_coarse_frame < 0 && prof.active[0] == m[0]->nnodes)
            all_coarse_frame = f;
    }
    if (getenv("SQ_LOD_VERBOSE"))
        fprintf(stderr, "poke: max finest active %d of %d, splits %d merges %d, all coarse at "
                "frame %d, deepest finest active node %.3f m below the top, %.3f of them in the upper half\n",
                max_fine, m[2]->nnodes, splits, merges, all_coarse_frame, far_max,
                total_fine ? (double)upper / total_fine : 0.0);
    CHECK(bad_tree == 0);
    CHECK(max_fine > 20);                   /* it did refine to the finest level */
    CHECK(max_fine < m[2]->nnodes / 3);     /* ... near the tool only */
    CHECK(far_fine == 0);
    CHECK(upper >= 0.9 * total_fine);
    CHECK(splits > 0 && merges > 0);
    /* back to the coarsest level everywhere within 2.5 s of the release (mass damping
     * 4 /s: the motion decays by e^-5 in that time) */
    CHECK(all_coarse_frame > 0);
    CHECK(all_coarse_frame * def.frame_dt < release + 2.5);
    sq_body_destroy(b);
    lh_free_meshes(m, 3);
}

/* ------------------------------------------------------------------ energy */

/* undamped, no gravity, a bent cube let go: the adaptive body conserves energy (symplectic
 * steps of one energy, see adaptive.c), and a split or merge changes it only by re-sampling
 * the field */
/* a tool's focus (sq_tool.focus, a haptic channel's) keeps the finest level about it: the
 * body at rest and the tool clear of it, so the criterion alone splits nothing; with focus 3
 * (a sphere of 3 radii, 15 cm) every finest node within it is simulated at the finest level
 * after a few frames, and the region stays local (no finest node in the lower half); without
 * the focus the criterion merges them all back. Counts, exact */
SQ_TEST(lod_focus_keeps_the_finest_level_about_a_tool)
{
    sq_mesh *m[3];
    if (!lh_poke_meshes(m)) {
        CHECK(0);
        return;
    }
    sq_body_def def = lh_poke_def(m, 0);
    sq_body *b = lh_body(&def);
    CHECK(b != NULL);
    if (!b) {
        lh_free_meshes(m, 3);
        return;
    }
    sq_tool tool = lh_sphere(0.5, 0.5, 1.08, 0.05, 1); /* 3 cm above the top face */
    sq_frame_profile prof;
    int fine_alone = 0;
    for (int f = 0; f < 5; f++) {
        sq_body_frame(b, &tool, 1, NULL, &prof, 0);
        fine_alone = SQ_MAX(fine_alone, prof.active[2]);
    }
    tool.focus = 3;
    for (int f = 0; f < 5; f++)
        sq_body_frame(b, &tool, 1, NULL, &prof, 0);
    const unsigned char *act = sq_lod_active(b->lod, 2);
    const double R = 3 * tool.radius;
    int inside = 0, inside_fine = 0, low_fine = 0;
    for (int i = 0; i < m[2]->nnodes; i++) {
        const double *x = m[2]->x + 3 * i;
        double r = sqrt((x[0] - 0.5) * (x[0] - 0.5) + (x[1] - 0.5) * (x[1] - 0.5) + (x[2] - 1.08) * (x[2] - 1.08));
        if (r < R) {
            inside++;
            inside_fine += act[i] != 0;
        }
        low_fine += act[i] && x[2] < 0.5;
    }
    const int focused = prof.active[2];
    tool.focus = 0;
    int merged_at = -1;
    for (int f = 0; f < 50 && merged_at < 0; f++) {
        sq_body_frame(b, &tool, 1, NULL, &prof, 0);
        if (prof.active[2] == 0)
            merged_at = f;
    }
    if (getenv("SQ_LOD_VERBOSE"))
        fprintf(stderr, "focus: finest active alone %d, focused %d (%d of the %d finest nodes within %.2f m), "
                "%d in the lower half, all merged %d frames after\n", fine_alone, focused, inside_fine, inside,
                R, low_fine, merged_at);
    CHECK(fine_alone == 0);
    CHECK(inside > 0 && inside_fine == inside);
    CHECK(low_fine == 0);
    CHECK(merged_at >= 0);
    sq_body_destroy(b);
    lh_free_meshes(m, 3);
}

SQ_TEST(lod_energy_across_split_merge_and_undamped_run)
{
    sq_mesh *m[2];
    if (!lh_cube_levels(m, 2, (const int[]){3, 6})) {
        CHECK(0);
        return;
    }
    sq_material mat = lh_paper_material();
    sq_level lv[2];
    CHECK(make_levels(lv, m, 2, &mat));
    sq_lod_def adapt = lh_lod(SQ_LOD_ADAPTIVE, 0.004, 0.002), frozen = adapt;
    frozen.split = INFINITY;
    frozen.merge = 0;
    sq_err e = {{0}};
    sq_lod *lod = sq_lod_create(lv, 2, &frozen, &e);
    CHECK(lod != NULL);
    if (!lod)
        return;
    sq_lod_set_material(lod, &mat);
    /* bent: d_x = 0.02 z^2 (1 + 0.3 x), the same field sampled on both levels */
    for (int k = 0; k < 2; k++)
        for (int i = 0; i < lv[k].model.n; i++) {
            const double *x = m[k]->x + 3 * i;
            lv[k].state.d[3 * i] = lv[k].model.fixed[i] ? 0 : 0.02 * x[2] * x[2] * (1 + 0.3 * x[0]);
        }
    sq_lod_sync(lod);
    double g[3] = {0, 0, 0}, E0 = sq_lod_energy(lod, NULL, NULL);
    double worst_event = 0, worst_drift = 0;
    int nsplit = 0, nmerge = 0;
    for (int f = 0; f < 150; f++) {
        /* one split/merge pass between frames, with the energy on both sides of it */
        double before = sq_lod_energy(lod, NULL, NULL);
        int sp = 0, mg = 0;
        CHECK(sq_lod_set_def(lod, &adapt, &e) == 0);
        sq_lod_adapt(lod, 1, &sp, &mg);
        CHECK(sq_lod_set_def(lod, &frozen, &e) == 0);
        double after = sq_lod_energy(lod, NULL, NULL);
        if (sp || mg)
            worst_event = fmax(worst_event, fabs(after - before) / before);
        nsplit += sp;
        nmerge += mg;
        CHECK(sq_lod_check(lod, &e) == 0);
        sq_lod_frame_in in = {.mat = &mat, .gravity = {g[0], g[1], g[2]}, .frame_dt = 0.02};
        sq_lod_frame(lod, &in, NULL, NULL);
        worst_drift = fmax(worst_drift, fabs(sq_lod_energy(lod, NULL, NULL) - E0) / E0);
    }
    if (getenv("SQ_LOD_VERBOSE"))
        fprintf(stderr, "energy: E0 %.4g J, %d splits %d merges, worst change at a split/merge "
                "pass %.3g, worst drift over 3 s %.3g\n", E0, nsplit, nmerge, worst_event, worst_drift);
    CHECK(nsplit > 0 && nmerge > 0);
    /* a pass re-samples the field on the new active set: under 10% of the energy */
    CHECK(worst_event < 0.10);
    /* 3 s undamped with splits and merges: within 25% of the start (symplectic Euler
     * oscillates by a few %, each pass adds its re-sampling) */
    CHECK(worst_drift < 0.25);
    sq_lod_destroy(lod);
    for (int k = 0; k < 2; k++)
        sq_level_free(&lv[k]);
    lh_free_meshes(m, 2);
}

/* the frame's stages: each one's time is recorded, the named profile times are those stages
 * (t_pull the pull stage, t_push the push stage, t_adapt criterion + adapt), and together they
 * fit in the body's frame time; exact comparisons, the profile copies the stage sums */
SQ_TEST(lod_frame_stage_times_add_up)
{
    sq_mesh *m[3];
    if (!lh_poke_meshes(m)) {
        CHECK(0);
        return;
    }
    sq_body_def def = lh_poke_def(m, 0);
    sq_body *b = lh_body(&def);
    CHECK(b != NULL);
    if (!b) {
        lh_free_meshes(m, 3);
        return;
    }
    int bad = 0, frames_adapting = 0, step_timed = 0, frames_updating = 0;
    for (int f = 0; f < 40; f++) {
        sq_tool tool = poke_tool(f * def.frame_dt);
        sq_frame_profile prof;
        sq_body_frame(b, &tool, 1, NULL, &prof, 0);
        double sum = 0;
        for (int s = 0; s < SQ_LOD_STAGES; s++) {
            bad += !(prof.t_stage[s] >= 0);
            sum += prof.t_stage[s];
        }
        bad += !(sum <= prof.t_total);
        bad += prof.t_pull != prof.t_stage[SQ_LOD_STAGE_PULL];
        bad += prof.t_push != prof.t_stage[SQ_LOD_STAGE_PUSH];
        bad += prof.t_adapt != prof.t_stage[SQ_LOD_STAGE_CRITERION] + prof.t_stage[SQ_LOD_STAGE_ADAPT];
        if (prof.node_updates > 0) {
            frames_updating++;
            step_timed += prof.t_stage[SQ_LOD_STAGE_STEP] > 0;
        }
        if (prof.splits + prof.merges > 0)
            frames_adapting += prof.t_stage[SQ_LOD_STAGE_ADAPT] > 0;
        if (getenv("SQ_LOD_VERBOSE") && f % 10 == 9) {
            fprintf(stderr, "frame %d:", f);
            for (int s = 0; s < SQ_LOD_STAGES; s++)
                fprintf(stderr, " %s %.3f ms", sq_lod_stage_name(s), 1e3 * prof.t_stage[s]);
            fprintf(stderr, " (total %.3f ms)\n", 1e3 * prof.t_total);
        }
    }
    CHECK(bad == 0);
    CHECK(frames_updating == 40 && step_timed == 40);
    CHECK(frames_adapting > 0); /* the poke splits: those frames rebuild */
    for (int s = 0; s < SQ_LOD_STAGES; s++)
        for (int r = s + 1; r < SQ_LOD_STAGES; r++)
            CHECK(strcmp(sq_lod_stage_name(s), sq_lod_stage_name(r)) != 0);
    CHECK(strcmp(sq_lod_stage_name(SQ_LOD_STAGES), "?") == 0);
    CHECK(strcmp(sq_lod_stage_name(SQ_LOD_STAGE_PULL), "pull") == 0);
    sq_body_destroy(b);
    lh_free_meshes(m, 3);
}

/* ------------------------------------------------------------------ tool feedback */

/* at rest, without gravity, the tool's feedback (the internal force on the held nodes)
 * balances the support reactions (the force on the fixed nodes, all levels): the adaptive
 * operator is translation invariant across levels, so internal forces sum to zero */
static void feedback_balance(double split, double merge, int want_mixed)
{
    sq_mesh *m[2];
    if (!lh_cube_levels(m, 2, (const int[]){4, 8})) {
        CHECK(0);
        return;
    }
    sq_body_def def = lh_cube_def(m, 2);
    def.gravity[2] = 0;
    def.material.rayleigh_mass = 20; /* about critical: at rest within the run */
    def.lod = lh_lod(SQ_LOD_ADAPTIVE, split, merge);
    sq_err e = {{0}};
    sq_body *b = sq_body_create(&def, &e);
    CHECK(b != NULL);
    if (!b) {
        fprintf(stderr, "%s\n", e.msg);
        lh_free_meshes(m, 2);
        return;
    }
    sq_tool t = lh_sphere(0.5, 0.5, 1.2, 0.3, 1); /* 0.1 m into the top face */
    sq_tool_feedback fb;
    sq_frame_profile prof;
    for (int f = 0; f < 300; f++)
        sq_body_frame(b, &t, 1, &fb, &prof, 0);
    CHECK(fb.nnodes >= 1);
    double R[3] = {0, 0, 0};
    for (int k = 0; k < 2; k++) {
        const sq_level *L = sq_body_level(b, k);
        const unsigned char *act = sq_lod_active(b->lod, k);
        for (int i = 0; i < L->model.n; i++)
            if (act[i] && L->model.fixed[i] == 7)
                for (int c = 0; c < 3; c++)
                    R[c] += L->state.f[3 * i + c];
    }
    double sum[3] = {fb.force[0] + R[0], fb.force[1] + R[1], fb.force[2] + R[2]};
    if (getenv("SQ_LOD_VERBOSE"))
        fprintf(stderr, "feedback (split %g): tool %.5g N, supports %.5g N, sum %.3g N, active %d %d\n",
                split, fb.force[2], R[2], lh_norm3(sum), prof.active[0], prof.active[1]);
    CHECK(fb.force[2] > 100); /* the body pushes back on the tool */
    if (want_mixed)
        CHECK(prof.active[0] > 0 && prof.active[1] > 0);
    /* 6 s at about critical damping leaves ~e^-60 of the motion: 1e-6 of the tool force is
     * rounding */
    CHECK(lh_norm3(sum) <= 1e-6 * fabs(fb.force[2]));
    sq_body_destroy(b);
    lh_free_meshes(m, 2);
}

SQ_TEST(lod_tool_feedback_balances_supports_forced_finest)
{
    feedback_balance(0, 0, 0);
}

SQ_TEST(lod_tool_feedback_balances_supports_mixed_levels)
{
    /* a patch under the tool that stays clear of the fixed bottom (a ghost on the support
     * would carry part of the reaction, reported by no active node) */
    feedback_balance(0.05, 0.00625, 1);
}

/* ------------------------------------------------------------------ frame budget */

/* a frame over budget forbids splitting on the next frame (merges allowed) and says so */
SQ_TEST(lod_budget_refuses_splits_and_warns)
{
    sq_mesh *m[3];
    if (!lh_poke_meshes(m)) {
        CHECK(0);
        return;
    }
    sq_body_def def = lh_poke_def(m, 0);
    sq_body *b = lh_body(&def);
    CHECK(b != NULL);
    if (!b) {
        lh_free_meshes(m, 3);
        return;
    }
    /* a 1 ns budget: every frame after the first is over it, whatever the machine */
    sq_frame_profile prof;
    int splits_late = 0, refused = 0, warned = 0;
    for (int f = 0; f < 60; f++) {
        sq_tool tool = poke_tool(f * def.frame_dt);
        sq_body_frame(b, &tool, 1, NULL, &prof, 1e-9);
        if (f >= 1) {
            splits_late += prof.splits;
            refused += prof.splits_refused;
            warned += strstr(prof.event, "warning") != NULL && strstr(prof.event, "splitting refused") != NULL;
        }
    }
    CHECK(splits_late == 0);
    CHECK(refused == 59);
    CHECK(warned == 59);
    CHECK(prof.active[0] >= m[0]->nnodes - 1); /* stayed (almost) coarse under the poke */
    sq_body_destroy(b);
    lh_free_meshes(m, 3);
}

/* the poke's cube (3 levels, no gravity), adaptive at split 0.05 with the given node-update cap
 * and split/merge period; NULL (a failed check) if it cannot be made */
static sq_body *poke_body(sq_mesh **m, long max_node_updates, int adapt_every)
{
    sq_body_def def = lh_poke_def(m, 0);
    def.lod.max_node_updates = max_node_updates;
    def.lod.adapt_every = adapt_every;
    sq_body *b = lh_body(&def);
    CHECK(b != NULL);
    return b;
}

/* frame f of the scripted poke, unbudgeted, and the lod's consistency after it */
static void poke_frame(sq_body *b, int f, sq_frame_profile *prof)
{
    sq_tool tool = poke_tool(f * sq_body_get_def(b)->frame_dt);
    sq_body_frame(b, &tool, 1, NULL, prof, 0);
    sq_err e = {{0}};
    CHECK(sq_lod_check(b->lod, &e) == 0);
}

/* the node-update cap: a poke that needs more stays under the cap in >= 99% of frames, with
 * splits refused while at the cap */
SQ_TEST(lod_node_update_cap_holds)
{
    sq_mesh *m[3];
    if (!lh_poke_meshes(m)) {
        CHECK(0);
        return;
    }
    long peak[2] = {0, 0};
    int over[2] = {0, 0}, refused[2] = {0, 0}, frames = 120;
    long cap = 600;
    for (int run = 0; run < 2; run++) {
        sq_body *b = poke_body(m, run ? cap : 0, 1);
        if (!b)
            break;
        sq_frame_profile prof;
        for (int f = 0; f < frames; f++) {
            poke_frame(b, f, &prof);
            peak[run] = SQ_MAX(peak[run], prof.node_updates);
            over[run] += prof.node_updates > cap;
            refused[run] += prof.splits_refused;
        }
        sq_body_destroy(b);
    }
    if (getenv("SQ_LOD_VERBOSE"))
        fprintf(stderr, "cap %ld: uncapped peak %ld (%d frames over), capped peak %ld (%d over, %d "
                "refusals)\n", cap, peak[0], over[0], peak[1], over[1], refused[1]);
    CHECK(over[0] > 10);             /* the poke does need more than the cap */
    CHECK(over[1] * 100 <= frames);  /* >= 99% of the frames within the cap */
    CHECK(refused[1] > 0 && refused[0] == 0);
    lh_free_meshes(m, 3);
}

/* lod.adapt_every: with 3, splits and merges happen only at frames 0, 3, 6, ... of the body (the
 * poke still refines); with 1 (the default) they also happen between them */
SQ_TEST(lod_adapt_every_spaces_the_split_merge_passes)
{
    sq_mesh *m[3];
    if (!lh_poke_meshes(m)) {
        CHECK(0);
        return;
    }
    int off_beat[2] = {0, 0}, changes[2] = {0, 0}, frames = 120;
    long peak[2] = {0, 0};
    for (int run = 0; run < 2; run++) {
        sq_body *b = poke_body(m, 0, run ? 3 : 1);
        if (!b)
            break;
        sq_frame_profile prof;
        for (int f = 0; f < frames; f++) {
            poke_frame(b, f, &prof);
            int n = prof.splits + prof.merges;
            changes[run] += n > 0;
            off_beat[run] += n > 0 && f % 3 != 0;
            peak[run] = SQ_MAX(peak[run], (long)prof.active[1] + prof.active[2]);
        }
        sq_body_destroy(b);
    }
    if (getenv("SQ_LOD_VERBOSE"))
        fprintf(stderr, "adapt_every 1: %d frames with changes (%d off the 3-beat), peak refined %ld; "
                "3: %d (%d), peak %ld\n", changes[0], off_beat[0], peak[0], changes[1], off_beat[1], peak[1]);
    CHECK(off_beat[0] > 0);               /* every frame may change the layout by default */
    CHECK(off_beat[1] == 0);              /* every third frame only */
    CHECK(changes[1] > 2 && peak[1] > 0); /* and the poke still refines */
    lh_free_meshes(m, 3);
}

/* ------------------------------------------------------------------ sleep */

SQ_TEST(lod_sleeping_body_costs_nothing_and_wakes_on_touch)
{
    sq_mesh *m[2];
    if (!lh_cube_levels(m, 2, (const int[]){3, 6})) {
        CHECK(0);
        return;
    }
    sq_body_def def = lh_cube_def(m, 2);
    def.gravity[2] = 0; /* at rest from the start */
    def.lod = lh_lod(SQ_LOD_ADAPTIVE, 0.05, 0.00625);
    sq_err e = {{0}};
    sq_body *b = sq_body_create(&def, &e);
    CHECK(b != NULL);
    if (!b) {
        lh_free_meshes(m, 2);
        return;
    }
    sq_frame_profile prof;
    int slept = -1;
    for (int f = 0; f < 200 && slept < 0; f++) {
        sq_body_frame(b, NULL, 0, NULL, &prof, 0);
        if (sq_body_is_sleeping(b))
            slept = f;
    }
    CHECK(slept >= 0);
    long asleep_updates = 0;
    for (int f = 0; f < 10; f++) {
        sq_body_frame(b, NULL, 0, NULL, &prof, 0);
        asleep_updates += prof.node_updates;
        CHECK(prof.sleeping == 1);
    }
    CHECK(asleep_updates == 0);
    /* a touch wakes it: the adaptive frame runs again */
    sq_tool t = lh_sphere(0.5, 0.5, 1.15, 0.2, 1);
    sq_body_frame(b, &t, 1, NULL, &prof, 0);
    CHECK(prof.sleeping == 0);
    CHECK(prof.node_updates > 0);
    CHECK(!sq_body_is_sleeping(b));
    sq_body_destroy(b);
    lh_free_meshes(m, 2);
}

/* the ring rows are summed from element blocks cached per tet: a material change must rebuild
 * them. Doubling mu and lambda doubles every stiffness block exactly (a factor of two is exact
 * in floating point), so the elastic energy of a mixed-level state, ring rows and frontier
 * corrections included, must double to rounding (1e-12 relative) and come back when the
 * material is restored; a stale cache would keep the ring rows of the first material. */
SQ_TEST(lod_ring_blocks_follow_material_change)
{
    sq_mesh *m[2];
    if (!lh_cube_levels(m, 2, (const int[]){3, 6})) {
        CHECK(0);
        return;
    }
    sq_material mat = lh_paper_material();
    sq_material stiff = mat;
    stiff.mu *= 2;
    stiff.lambda *= 2;
    sq_level lv[2];
    CHECK(make_levels(lv, m, 2, &mat));
    sq_lod_def adapt = lh_lod(SQ_LOD_ADAPTIVE, 0.004, 0.002);
    sq_err e = {{0}};
    sq_lod *lod = sq_lod_create(lv, 2, &adapt, &e);
    CHECK(lod != NULL);
    if (!lod)
        return;
    sq_lod_set_material(lod, &mat);
    for (int k = 0; k < 2; k++)
        for (int i = 0; i < lv[k].model.n; i++) {
            const double *x = m[k]->x + 3 * i;
            lv[k].state.d[3 * i] = lv[k].model.fixed[i] ? 0 : 0.02 * x[2] * x[2] * (1 + 0.3 * x[0]);
        }
    sq_lod_sync(lod);
    int sp = 0, mg = 0;
    sq_lod_adapt(lod, 1, &sp, &mg);
    /* a mixed state: some finest nodes active, some not */
    int na = 0;
    const unsigned char *act = sq_lod_active(lod, 1);
    for (int i = 0; i < lv[1].model.n; i++)
        na += act[i];
    CHECK(sp > 0 && na > 0 && na < lv[1].model.n);
    double e1 = 0, e2 = 0, e3 = 0;
    sq_lod_energy(lod, NULL, &e1);
    for (int k = 0; k < 2; k++)
        CHECK(sq_level_set_material(&lv[k], &stiff, SQ_OPERATOR_FEM, &e) == 0);
    sq_lod_set_material(lod, &stiff);
    sq_lod_energy(lod, NULL, &e2);
    for (int k = 0; k < 2; k++)
        CHECK(sq_level_set_material(&lv[k], &mat, SQ_OPERATOR_FEM, &e) == 0);
    sq_lod_set_material(lod, &mat);
    sq_lod_energy(lod, NULL, &e3);
    if (getenv("SQ_LOD_VERBOSE"))
        fprintf(stderr, "ring blocks: %d splits, %d finest active, elastic %.6g -> %.6g -> %.6g J\n",
                sp, na, e1, e2, e3);
    CHECK(e1 > 0);
    CHECK_NEAR(e2, 2 * e1, 1e-12 * e1);
    CHECK_NEAR(e3, e1, 1e-12 * e1);
    sq_lod_destroy(lod);
    for (int k = 0; k < 2; k++)
        sq_level_free(&lv[k]);
    lh_free_meshes(m, 2);
}
