/* test_lod_guard.c - the guard that holds the frame rate (docs/lod.md, "Guaranteed frame
 * rate"), run on given costs (sq_lodx_set_costs) so that every decision is deterministic and
 * nothing depends on the machine's clock: the frame's cost by the model is exact for what the
 * frame did (its node updates, its passes' levels and changed nodes). */
#include <stdint.h>

#include "lod/bound.h"
#include "lod/coupling.h"
#include "lod/guard.h"
#include "lod/lod_test.h"
#include "lod/ring.h"
#include "lod/state.h"
#include "body/body_internal.h"
#include "scene/scene.h"
#include "sq_test.h"
#include "test_scene_helpers.h"
#include "test_lod_helpers.h"
#include "test_sim_helpers.h"

/* four cube levels: 3, 6 (jittered), 12, 18 (jittered) cells */
static int guard_meshes(sq_mesh **m) { return lh_cube_levels(m, 4, (const int[]){3, 6, 12, 18}); }

/* a sphere pressing the top 8 cm over 0.6 s while moving sideways, held, released at 1.2 s */
static sq_tool guard_poke(double t)
{
    double depth = t < 0.6 ? 0.08 * t / 0.6 : 0.08;
    double x = 0.4 + 0.2 * (t < 1.2 ? t / 1.2 : 1.0);
    return lh_sphere(x, 0.5, 1.15 - depth, 0.15, t < 1.2);
}

/* frame f of the poke on body b with the given period (0: no budget) */
static void poke_frame(sq_body *b, const sq_body_def *def, int f, double period)
{
    sq_tool tool = guard_poke(f * def->frame_dt);
    sq_frame_profile p;
    sq_body_frame(b, &tool, 1, NULL, &p, period);
}

/* the given costs: 100 ns per node update, 0.5 ms a frame, per pass 0.3 ms per level rebuilt
 * plus 1 ms, 20 us per changed node (the proportions measured on box-big, scaled to this
 * body); a 20 ms period (the budget test below sets its own periods, at which the unguarded
 * poke's own frames, updates and passes, exceed the budget: checked there, so the guard has to
 * act). */
#define C_UPDATE 100e-9
#define C_FRAME 0.5e-3
#define C_LEVEL 0.3e-3
#define C_PASS 1e-3
#define C_CHANGE 20e-6
#define PERIOD 20e-3

/* the poked cube's meshes (m) and def (no gravity, adaptive: split 0.01, merge 0.002), and two
 * bodies of it: b[0] as it comes, b[1] on the given costs; 0 when any is not made */
static int guard_pair(sq_mesh **m, sq_body_def *def, sq_body *b[2])
{
    b[0] = b[1] = NULL;
    if (!guard_meshes(m))
        return 0;
    *def = lh_cube_def(m, 4);
    def->gravity[2] = 0;
    def->lod = lh_lod(SQ_LOD_ADAPTIVE, 0.01, 0.002);
    sq_err e = {{0}};
    b[0] = sq_body_create(def, &e);
    b[1] = sq_body_create(def, &e);
    if (!b[0] || !b[1])
        return 0;
    sq_lodx_set_costs(b[1]->lod, C_UPDATE, C_FRAME, C_LEVEL, C_PASS, C_CHANGE);
    return 1;
}

/* the model's cost of one frame from its profile and the levels a pass rebuilt, for the
 * unguarded run (which has no model): fixed + updates + per pass its levels and changes */
static double unguarded_cost(const sq_frame_profile *p, int levels_changed, long nodes_changed)
{
    double c = C_FRAME + C_UPDATE * (double)p->node_updates;
    if (levels_changed > 0)
        c += C_PASS + C_LEVEL * levels_changed + C_CHANGE * (double)nodes_changed;
    return c;
}

/* With a budget and given costs, every frame after the first costs (by the model, for what
 * it actually did) at most budget x period, also after the period drops from 14 to 6 ms in
 * the middle of the poke (the two frames that absorb the drop excepted), refinement still
 * happens (the finest level is used), the drop makes the guard merge, and no region the guard
 * merged is split again in its rest (the old guard merged at the start of a frame and the
 * end-of-frame pass split the same regions again). The same poke without the guard exceeds the budget in
 * some frames, so the test fails if the guard does not act. Tolerance: none (the model's
 * costs are given, so its frame cost is exact for what the frame did).
 * The periods are the scenario's, set for the sharp step bound (the default): it takes fewer
 * substeps than Gershgorin's, so fewer node updates a frame (the guarded layout before the
 * drop about 65,000 a frame against Gershgorin's 120,000 at 20 ms). At the 20 and 12 ms the
 * test had on Gershgorin's counts, the unguarded poke was over the budget in 4 frames only and
 * the layout fitted 12 ms without a merge; at 14 and 6 ms it is over in 31 frames and the drop
 * makes the guard merge 517 regions (Gershgorin at 20 and 12 ms: 58 frames, 630 regions). */
#define GIVEN_PERIOD 14e-3
#define GIVEN_DROP 6e-3
SQ_TEST(lod_guard_holds_the_budget_on_given_costs)
{
    sq_mesh *m[4];
    sq_body_def def;
    sq_body *b[2];
    int made = guard_pair(m, &def, b);
    CHECK(made);
    if (!made)
        return;
    double B = def.lod.budget * GIVEN_PERIOD;
    int frames = 100, over_unguarded = 0, over = 0, finest_max = 0, refused = 0;
    double worst = 0, worst_unguarded = 0;
    long splits = 0, merges = 0;
    for (int f = 0; f < frames; f++) {
        sq_tool tool = guard_poke(f * def.frame_dt);
        sq_frame_profile p[2];
        /* unguarded: the levels and nodes its pass changed, from the states before and after */
        unsigned char *before[4];
        for (int k = 0; k < 4; k++) {
            before[k] = malloc((size_t)m[k]->nnodes);
            memcpy(before[k], b[0]->lod->lev[k].lay.state, (size_t)m[k]->nnodes);
        }
        sq_body_frame(b[0], &tool, 1, NULL, &p[0], 0);
        int lch = 0;
        long nch = 0;
        for (int k = 0; k < 4; k++) {
            long d = 0;
            for (int i = 0; i < m[k]->nnodes; i++)
                d += (before[k][i] == ST_ACTIVE) != (b[0]->lod->lev[k].lay.state[i] == ST_ACTIVE);
            lch += d > 0;
            nch += d;
            free(before[k]);
        }
        /* from frame 60 (the tool still pressing) the period drops to 6 ms: the layout
         * (then about 6.5 ms of node updates alone) no longer fits and the guard merges, as
         * many regions as frame 60 can rebuild and the rest at the start of frame 61: those
         * two frames (like the first) may be over */
        double period = f < 60 ? GIVEN_PERIOD : GIVEN_DROP, Bf = def.lod.budget * period;
        sq_body_frame(b[1], &tool, 1, NULL, &p[1], period);
        double cu = unguarded_cost(&p[0], lch, nch), cg = b[1]->lod->guard.guard_modeled;
        if (f >= 1 && f != 60 && f != 61) {
            over_unguarded += cu > B;
            over += cg > Bf;
            worst = fmax(worst, cg);
            worst_unguarded = fmax(worst_unguarded, cu);
        }
        finest_max = SQ_MAX(finest_max, p[1].active[3]);
        refused += p[1].splits_refused;
        splits += p[1].splits;
        merges += p[1].merges;
        sq_err e = {{0}};
        CHECK(sq_lod_check(b[1]->lod, &e) == 0);
    }
    if (getenv("SQ_LOD_VERBOSE"))
        fprintf(stderr, "guard on given costs, budget %.2f ms: unguarded %d frames over (worst %.2f ms); guarded "
                "%d over (worst %.2f ms), finest active up to %d, %ld splits, %ld merges (%ld by the guard, "
                "%ld split again in their rest), %d frames with splits refused\n", 1e3 * B, over_unguarded,
                1e3 * worst_unguarded, over, 1e3 * worst, finest_max, splits, merges, b[1]->lod->guard.guard_merged_total,
                sq_lod_test_of(b[1]->lod)->guard_resplit, refused);
    CHECK(over_unguarded > 0);  /* the budget binds */
    CHECK(over == 0);           /* exact model: no frame over after the first */
    CHECK(finest_max > 0);      /* the guard does not simply keep everything coarse */
    CHECK(refused > 0);
    CHECK(b[1]->lod->guard.guard_merged_total > 0); /* the drop made the guard merge */
    CHECK(sq_lod_test_of(b[1]->lod)->guard_resplit == 0);
    sq_body_destroy(b[0]);
    sq_body_destroy(b[1]);
    lh_free_meshes(m, 4);
}

/* burn `s` seconds of this thread's CPU time */
static void burn_cpu(double s)
{
    double c0 = sq_thread_cpu();
    volatile double x = 0;
    while (sq_thread_cpu() - c0 < s)
        for (int i = 0; i < 1000; i++)
            x += 1e-9 * i;
}

/* The guard charges the thread's time between two frames to the frame's budget (cost_outside),
 * but not the time the caller declares is not the product's (sq_body_untimed, as `squish
 * tradeoff` does for its error sampling). The poked cube on measured costs with a 20 ms
 * period, 3 ms of thread CPU burnt between frames: undeclared, the guard's time around the
 * frame is at least 2.5 ms (it holds the 3 ms: a decaying maximum); declared, at most 1 ms
 * (the body's own work around its lod frame on this small cube is tens of us; 1 ms leaves room
 * for a slow machine without coming near the 3 ms). Thread CPU time, so load does not move it. */
SQ_TEST(lod_guard_untimed_time_is_not_charged)
{
    sq_mesh *m[4];
    sq_body_def def;
    sq_body *b[2];
    int made = guard_pair(m, &def, b);
    CHECK(made);
    if (!made)
        return;
    sq_err e = {{0}};
    sq_body *c = sq_body_create(&def, &e); /* measured costs too */
    CHECK(c != NULL);
    if (!c)
        return;
    /* one body after the other: the thread's time between two frames of a body includes any
     * other body's frames */
    for (int f = 0; f < 8; f++) {
        poke_frame(b[0], &def, f, PERIOD);
        burn_cpu(3e-3); /* undeclared */
    }
    for (int f = 0; f < 8; f++) {
        poke_frame(c, &def, f, PERIOD);
        double c0 = sq_thread_cpu();
        burn_cpu(3e-3);
        sq_body_untimed(c, sq_thread_cpu() - c0); /* declared */
    }
    if (getenv("SQ_LOD_VERBOSE"))
        fprintf(stderr, "time around the frame: undeclared %.3f ms, declared %.3f ms\n",
                1e3 * b[0]->lod->guard.cost_outside, 1e3 * c->lod->guard.cost_outside);
    CHECK(b[0]->lod->guard.cost_outside >= 2.5e-3);
    CHECK(c->lod->guard.cost_outside <= 1e-3);
    sq_body_destroy(c);
    sq_body_destroy(b[0]);
    sq_body_destroy(b[1]);
    for (int k = 0; k < 4; k++)
        sq_mesh_free(m[k]);
}

/* One spike of the machine is not learned as a cost for the rest of a run, a sustained rise
 * is (sq_lodx_learn, docs/lod.md "An isolated spike"). The figures are box-big's: a pass term
 * at ~100 us per changed node once measured 3,855 us; node updates at 120 ns once at 381 ns.
 * Exact arithmetic on given measurements: the tolerance 1.05 only states "back where it was"
 * (the decaying maximum of the ordinary measurements is exactly 100 us / 120 ns here). */
/* a learned term after n ordinary measurements of `typical` (decay, spike bound as given) */
static double learned_from(sq_cost_track *t, int n, double typical, double decay, double spike)
{
    *t = (sq_cost_track){0};
    double c = 0;
    for (int i = 0; i < n; i++)
        c = sq_lodx_learn(t, c, typical, decay, spike);
    return c;
}

SQ_TEST(lod_guard_isolated_spike_is_not_learned)
{
    const double pd = 0.97, fd = 0.9; /* the decays of a pass term, a frame term */
    /* a pass term: 20 ordinary passes, one spike, then ordinary again */
    sq_cost_track t;
    double c = learned_from(&t, 20, 100e-6, pd, 3.0);
    CHECK_NEAR(c, 100e-6, 1e-12);
    c = sq_lodx_learn(&t, c, 3855e-6, pd, 3.0);
    CHECK(c <= 3.0 * 100e-6 + 1e-12); /* raised, but only to the bound */
    CHECK(c >= 100e-6);               /* (raised all the same: safe for the next pass) */
    c = sq_lodx_learn(&t, c, 100e-6, pd, 3.0);
    CHECK(c <= 1.05 * 100e-6); /* back after one ordinary pass (before: 3,739 us) */
    for (int i = 0; i < 3; i++)
        c = sq_lodx_learn(&t, c, 100e-6, pd, 3.0);
    CHECK(c <= 1.05 * 100e-6);
    /* a second outlier within the window is a real rise: learned whole */
    c = sq_lodx_learn(&t, c, 3855e-6, pd, 3.0);
    CHECK(c >= 3855e-6);
    /* a sustained rise of 4x: bounded at its first pass, whole at its second */
    sq_cost_track u;
    double d = learned_from(&u, 20, 100e-6, pd, 3.0);
    d = sq_lodx_learn(&u, d, 400e-6, pd, 3.0);
    CHECK(d >= 300e-6 - 1e-12);
    d = sq_lodx_learn(&u, d, 400e-6, pd, 3.0);
    CHECK(d >= 400e-6);
    /* a rise within the bound is learned at once, as before */
    d = sq_lodx_learn(&u, d, 1000e-6, pd, 3.0);
    CHECK(d >= 1000e-6);
    /* spikes that come back within the window (alternating with ordinary passes) are learned */
    sq_cost_track v;
    double e = learned_from(&v, 20, 100e-6, pd, 3.0);
    e = sq_lodx_learn(&v, e, 3855e-6, pd, 3.0);
    e = sq_lodx_learn(&v, e, 100e-6, pd, 3.0);
    e = sq_lodx_learn(&v, e, 100e-6, pd, 3.0);
    e = sq_lodx_learn(&v, e, 3855e-6, pd, 3.0);
    CHECK(e >= 3855e-6);
    /* a frame term: node updates 120 ns, one frame at 381 ns */
    sq_cost_track w;
    double f = learned_from(&w, 30, 120e-9, fd, 2.0);
    f = sq_lodx_learn(&w, f, 381e-9, fd, 2.0);
    CHECK(f <= 2.0 * 120e-9 + 1e-15);
    f = sq_lodx_learn(&w, f, 120e-9, fd, 2.0);
    CHECK(f <= 1.05 * 120e-9); /* before: 343 ns, back to 126 ns only after 10 frames */
}

/* The same through a body's frames on measured costs (the time around the frame, cost_outside,
 * the term a test can drive with burnt thread CPU time): 4 ms burnt once between two frames
 * (20 ms period) leaves the guard's time around the frame under 1 ms at that frame and after
 * it (the body's own work around its frame is tens of us, docs above; before: 4 ms decaying
 * 10 % a frame); burnt at two frames running, it is learned (>= 3.5 ms: thread CPU time, so
 * load does not move it). */
SQ_TEST(lod_guard_isolated_spike_around_the_frame)
{
    sq_mesh *m[4];
    sq_body_def def;
    sq_body *b[2];
    int made = guard_pair(m, &def, b);
    CHECK(made);
    if (!made)
        return;
    sq_body *c = b[0]; /* measured costs */
    int f = 0;
    for (; f < 10; f++)
        poke_frame(c, &def, f, PERIOD);
    double before = c->lod->guard.cost_outside;
    burn_cpu(4e-3);
    double after[3];
    for (int i = 0; i < 3; i++, f++) {
        poke_frame(c, &def, f, PERIOD);
        after[i] = c->lod->guard.cost_outside;
    }
    for (int i = 0; i < 2; i++, f++) {
        burn_cpu(4e-3);
        poke_frame(c, &def, f, PERIOD);
    }
    double sustained = c->lod->guard.cost_outside;
    if (getenv("SQ_LOD_VERBOSE"))
        fprintf(stderr, "time around the frame: %.3f ms; after one spike %.3f %.3f %.3f ms; sustained %.3f ms\n",
                1e3 * before, 1e3 * after[0], 1e3 * after[1], 1e3 * after[2], 1e3 * sustained);
    CHECK(after[0] <= 1e-3);
    CHECK(after[1] <= 1e-3);
    CHECK(after[2] <= 1e-3);
    CHECK(sustained >= 3.5e-3);
    sq_body_destroy(b[0]);
    sq_body_destroy(b[1]);
    for (int k = 0; k < 4; k++)
        sq_mesh_free(m[k]);
}

/* The guard merges the least needed regions first: after a poke refines a body (no budget),
 * merging down to a node-update cap takes mergeable regions in increasing order of their
 * children's largest criterion, and the merged ones rest (not split for REST frames). */
SQ_TEST(lod_guard_merges_least_needed_first)
{
    sq_mesh *m[3];
    if (!lh_cube_levels(m, 3, (const int[]){3, 6, 12})) {
        CHECK(0);
        return;
    }
    sq_body_def def = lh_cube_def(m, 3);
    def.gravity[2] = 0;
    def.lod = lh_lod(SQ_LOD_ADAPTIVE, 0.02, 0.004);
    sq_err e = {{0}};
    sq_body *b = sq_body_create(&def, &e);
    TH_REQUIRE(b);
    sq_frame_profile p;
    for (int f = 0; f < 25; f++) {
        sq_tool tool = lh_sphere(0.5, 0.5, 1.2 - 0.1 * SQ_MIN(f / 20.0, 1.0), 0.2, 1);
        sq_body_frame(b, &tool, 1, NULL, &p, 0);
    }
    sq_lod *lod = b->lod;
    sq_lod_flush(lod);
    /* the needs of the regions mergeable now (split nodes of levels 0 and 1 whose children
     * are all active) and the node updates merging them all would save */
    double *need[2];
    int cand = 0;
    long projected = sq_lod_projected_updates(lod), gain = 0;
    for (int k = 0; k < 2; k++) {
        int n = m[k]->nnodes;
        const sq_lod_link *ln = &lod->h.link[k];
        need[k] = malloc(sizeof(double) * (size_t)n);
        for (int p = 0; p < n; p++) {
            need[k][p] = -1;
            if (lod->lev[k].lay.state[p] != ST_SPLIT)
                continue;
            int ok = 1;
            for (int c = ln->child_start[p]; c < ln->child_start[p + 1] && ok; c++)
                ok = lod->lev[k + 1].lay.state[ln->child[c]] == ST_ACTIVE;
            if (!ok)
                continue;
            need[k][p] = sq_lodx_need(lod, k, p);
            long nch = ln->child_start[p + 1] - ln->child_start[p];
            gain += nch * (1L << sub_log2(lod, k + 1)) - (1L << sub_log2(lod, k));
            cand++;
        }
    }
    CHECK(cand > 3);
    /* merge about half of them: a cap half way between none and all merged */
    long cap = projected - gain / 2;
    adapt_out ao;
    memset(&ao, 0, sizeof ao);
    long made = sq_lodx_guard_merge(lod, cap, &projected, &ao, 7, 1000000);
    double merged_max = 0, kept_min = INFINITY;
    int held = 0, merged = 0;
    for (int k = 0; k < 2; k++)
        for (int p = 0; p < m[k]->nnodes; p++) {
            if (need[k][p] < 0)
                continue;
            if (lod->lev[k].lay.state[p] == ST_ACTIVE) {
                merged_max = fmax(merged_max, need[k][p]);
                merged++;
                held += lod->guard.guard_hold[k] && lod->guard.guard_hold[k][p] == lod->guard.guard_clock + 7;
            } else {
                kept_min = fmin(kept_min, need[k][p]);
            }
        }
    if (getenv("SQ_LOD_VERBOSE"))
        fprintf(stderr, "least needed: %d mergeable, %ld merged (largest need %.3g m), the rest from %.3g m\n", cand,
                made, merged_max, kept_min);
    CHECK(made == merged && made > 0 && made < cand); /* regions mergeable at the start only */
    CHECK(projected <= cap);
    CHECK(merged_max <= kept_min); /* every merged region needed less than every kept one */
    CHECK(held == made);           /* each rests 7 frames */
    free(need[0]);
    free(need[1]);
    for (int k = 0; k < 3; k++)
        if (ao.changed[k])
            sq_lodx_rebuild_level(lod, k);
    sq_lod_sync(lod);
    CHECK(sq_lod_check(lod, &e) == 0);
    sq_body_destroy(b);
    lh_free_meshes(m, 3);
}

/* The sharp step estimate is made again only for a level whose operator changed: a rebuild
 * of every level with no change of state estimates nothing and keeps every level's substeps;
 * after sq_lodx_sharp_invalidate the same rebuild estimates every level with active nodes
 * again and finds the same substeps (the operator is the same). */
SQ_TEST(lod_sharp_estimate_skipped_for_unchanged_levels)
{
    sq_mesh *m[3];
    if (!lh_cube_levels(m, 3, (const int[]){3, 6, 12})) {
        CHECK(0);
        return;
    }
    sq_body_def def = lh_cube_def(m, 3);
    def.gravity[2] = 0;
    def.sharp_step = 1;
    def.lod = lh_lod(SQ_LOD_ADAPTIVE, 0.02, 0.004);
    sq_err e = {{0}};
    sq_body *b = sq_body_create(&def, &e);
    TH_REQUIRE(b);
    sq_frame_profile p;
    for (int f = 0; f < 20; f++) {
        sq_tool tool = lh_sphere(0.5, 0.5, 1.2 - 0.1 * SQ_MIN(f / 15.0, 1.0), 0.2, 1);
        sq_body_frame(b, &tool, 1, NULL, &p, 0);
    }
    sq_lod *lod = b->lod;
    int levels_active = 0, ext0[3];
    for (int k = 0; k < 3; k++) {
        levels_active += lod->lev[k].lay.nactive > 0;
        ext0[k] = lod->lev[k].rate.extra_log2;
    }
    CHECK(levels_active >= 2);
    long calls0, calls1, calls2;
    double cpu;
    sq_lod_sharp_cost(lod, &calls0, &cpu);
    for (int k = 0; k < 3; k++)
        sq_lodx_rebuild_level(lod, k);
    sq_lodx_build_sources(lod);
    sq_lodx_update_ring_blocks(lod, &def.material);
    sq_lod_sharp_cost(lod, &calls1, &cpu);
    int same1 = 1;
    for (int k = 0; k < 3; k++)
        same1 &= lod->lev[k].rate.extra_log2 == ext0[k];
    sq_lodx_sharp_invalidate(lod);
    for (int k = 0; k < 3; k++)
        sq_lodx_rebuild_level(lod, k);
    sq_lodx_build_sources(lod);
    sq_lodx_update_ring_blocks(lod, &def.material);
    sq_lod_sharp_cost(lod, &calls2, &cpu);
    int same2 = 1;
    for (int k = 0; k < 3; k++)
        same2 &= lod->lev[k].rate.extra_log2 == ext0[k];
    if (getenv("SQ_LOD_VERBOSE"))
        fprintf(stderr, "sharp skip: %d levels active; unchanged rebuild %ld estimates, invalidated %ld\n",
                levels_active, calls1 - calls0, calls2 - calls1);
    CHECK(calls1 == calls0);
    CHECK(same1);
    CHECK(calls2 - calls1 == levels_active);
    CHECK(same2);
    sq_body_destroy(b);
    lh_free_meshes(m, 3);
}

/* the reserve (docs/lod.md "A pass's cost without page faults") is held only under a budget:
 * a body run without one holds none of it (nothing reserved at load, the inner rows' column
 * cache opening its chunks in the ticks as before); a budgeted one reserves at its first frame
 * and keeps the column cache a chunk ahead, so no tick opens one. Same poke as above, the
 * budgeted body on given costs; results of the unbudgeted body do not depend on it. */
SQ_TEST(lod_guard_reserve_only_with_a_budget_row_cache_ahead)
{
    sq_mesh *m[4];
    sq_body_def def;
    sq_body *b[2];
    int made = guard_pair(m, &def, b);
    CHECK(made);
    if (!made)
        return;
    for (int c = 0; c < 2; c++) {
        CHECK(b[c]->lod->reserve.reserve_bytes == 0);
        for (int k = 0; k < 4; k++)
            CHECK(b[c]->lod->lev[k].cpl.krow_at == NULL && b[c]->lod->lev[k].cpl.ring_K_cap == 0);
    }
    for (int f = 0; f < 60; f++) {
        sq_tool tool = guard_poke(f * def.frame_dt);
        sq_frame_profile p;
        sq_body_frame(b[0], &tool, 1, NULL, &p, 0);
        sq_body_frame(b[1], &tool, 1, NULL, &p, PERIOD);
        if (f == 0)
            CHECK(b[1]->lod->reserve.reserve_live == 1 && b[1]->lod->reserve.reserve_bytes > 0);
    }
    long used[2] = {0, 0}, grown[2] = {0, 0};
    for (int c = 0; c < 2; c++)
        for (int k = 0; k < 4; k++) {
            used[c] += b[c]->lod->lev[k].cpl.krow_used;
            grown[c] += b[c]->lod->lev[k].cpl.krow_grown;
        }
    if (getenv("SQ_LOD_VERBOSE"))
        fprintf(stderr, "row cache: unbudgeted %ld blocks used, %ld chunks opened in ticks, reserve %ld bytes; "
                "budgeted %ld used, %ld opened in ticks, reserve %.1f MB\n", used[0], grown[0],
                b[0]->lod->reserve.reserve_bytes, used[1], grown[1], 1e-6 * (double)b[1]->lod->reserve.reserve_bytes);
    CHECK(b[0]->lod->reserve.reserve_live == 0 && b[0]->lod->reserve.reserve_bytes == 0);
    CHECK(used[0] > 0 && grown[0] > 0); /* without a budget the ticks open the chunks */
    CHECK(used[1] > 0 && grown[1] == 0); /* with one, none */
    sq_body_destroy(b[0]);
    sq_body_destroy(b[1]);
    lh_free_meshes(m, 4);
}

/* at load (docs/lod.md "Guaranteed frame rate"): a scene whose fully coarse frame cannot fit
 * the period is reported with its numbers; the shipped cube-poke at its own 50 Hz is not */
SQ_TEST(lod_guard_load_check_reports_a_scene_that_cannot_run)
{
    sq_scene *sc = th_shipped_scene("cube-poke");
    CHECK(sc != NULL);
    if (!sc)
        return;
    sq_err e = {{0}};
    sq_world *w = sq_world_create(sc, &e);
    CHECK(w != NULL);
    if (w) {
        char msg[1024];
        /* its own period: fits, by far (level 0 takes microseconds a frame) */
        CHECK(sq_world_realtime_check(w, 1.0 / sc->frame_rate, msg, sizeof msg) == 0);
        CHECK_CONTAINS(msg, "fully coarse frame predicted");
        /* a 1 us period: no force pass fits */
        CHECK(sq_world_realtime_check(w, 1e-6, msg, sizeof msg) == 1);
        CHECK_CONTAINS(msg, "cannot run in real time even fully coarse");
        CHECK_CONTAINS(msg, "budget 0.00 ms (95% of the 0.00 ms period)");
        CHECK_CONTAINS(msg, "coarser level 0");
        /* the check reads the state only: the run afterwards is the run without it */
        sq_world_step(w, 0);
        CHECK(w->frame == 1);
        sq_world_destroy(w);
    }
    sq_scene_free(sc);
}

/* a small adaptive cube: level 0 of 44 nodes under a 3,754-node finest level, no tool, 50 Hz;
 * split "inf" (split_inf) keeps it fully coarse */
static sq_scene *rt_scene(int split_inf)
{
    char json[2048];
    snprintf(json, sizeof json,
             "{\"name\": \"rt-coarse\", \"gravity\": [0, 0, 0], \"frame_rate\": 200, \"duration\": 1,"
             " \"bodies\": [{\"name\": \"cube\", \"levels\": [\"../cube/cube_l0.msh\", \"../cube/cube_l1.msh\", \"../cube/cube_l2.msh\", \"../cube/cube_l3.msh\"],"
             " \"material\": {\"lambda\": 100000, \"mu\": 40000, \"density\": 1000,"
             " \"damping\": {\"rayleigh_mass\": 2.0, \"rayleigh_stiffness\": 0.001}},"
             " \"fixed\": [{\"box\": [[-1, -1, -1], [2, 2, 0.001]]}],"
             " \"lod\": {\"mode\": \"adaptive\", \"level\": 0, %s}}],"
             " \"tools\": [{\"id\": 1, \"name\": \"finger\", \"shape\": \"sphere\", \"radius\": 0.2,"
             " \"keyframes\": [{\"t\": 0, \"pos\": [0.5, 0.5, 1.1]}]}]}",
             split_inf ? "\"split\": \"inf\"" : "\"split\": 0.005, \"merge\": 0.002");
    sq_err e = {{0}};
    sq_scene *sc = sq_scene_parse(json, th_scenes_dir(), "rt-coarse", &e);
    if (!sc)
        fprintf(stderr, "rt-coarse: %s\n", e.msg);
    return sc;
}

/* the load check times real fully coarse frames (integration, ghost levels, the frame's fixed
 * cost), not only the force passes of level 0, which is all it timed before: a period between
 * that old lower bound and the real coarse frame passed then and is reported now. Both are
 * measured here (thread CPU, means over at least 20 ms), and the period is their geometric mean,
 * so each side keeps sqrt(ratio) of margin against timing noise; the test needs the ratio to be
 * at least 9 (3x each side; about 10-30x measured on the development machine, where the
 * box-big case is 30x). The scene has a sphere pressing its top, as a real scene has: the tool's
 * holds and contact are part of the real frame that the force passes miss. Without it the ratio
 * was 9.0-10.0 on the 2026-12-02 machine (the test failed one CI run of two at x9.0); with it 33-34x. The check leaves the world as it was: a checked and an unchecked world
 * step to bitwise equal states. */
SQ_TEST(lod_guard_load_check_times_a_real_coarse_frame)
{
    sq_scene *sc = rt_scene(0), *sc_inf = rt_scene(1);
    CHECK(sc != NULL && sc_inf != NULL);
    if (!sc || !sc_inf) {
        sq_scene_free(sc);
        sq_scene_free(sc_inf);
        return;
    }
    sq_err e = {{0}};
    sq_world *w = sq_world_create(sc, &e), *ref = sq_world_create(sc, &e), *coarse = sq_world_create(sc_inf, &e);
    CHECK(w && ref && coarse);
    if (w && ref && coarse) {
        /* the old lower bound: level 0's force pass x its steps per frame */
        sq_body *b = w->bodies[0];
        const sq_body_def *def = sq_body_get_def(b);
        sq_level *L = sq_body_level(b, 0);
        int sub[SQ_MAX_LEVELS];
        sq_body_substeps(b, sub);
        size_t nn = (size_t)L->model.n;
        double *f = sq_malloc(sizeof(double) * 3 * nn), *acc = sq_calloc(3 * nn + 1, sizeof(double));
        sq_level_forces_to(&L->model, &L->state, &def->material, def->gravity, NULL, f, acc);
        double c0 = sq_thread_cpu(), c = c0;
        long reps = 0;
        while (c - c0 < 20e-3 || reps < 10) {
            sq_level_forces_to(&L->model, &L->state, &def->material, def->gravity, NULL, f, acc);
            reps++;
            c = sq_thread_cpu();
        }
        free(f);
        free(acc);
        double lower = (c - c0) / reps * (sub[0] > 0 ? sub[0] : 1);
        /* the real fully coarse frame */
        sq_world_step(coarse, 0);
        long frames = 0;
        c0 = c = sq_thread_cpu();
        while ((c - c0 < 20e-3 || frames < 10) && frames < 45) {
            sq_world_step(coarse, 0);
            frames++;
            c = sq_thread_cpu();
        }
        double real = (c - c0) / frames;
        fprintf(stderr, "    force passes %.4f ms, real coarse frame %.4f ms (x%.1f)\n", 1e3 * lower, 1e3 * real,
                real / lower);
        CHECK(real > 9 * lower);
        char msg[1024];
        double period = sqrt(lower * real) / 0.95; /* the budget is 95 % of the period */
        CHECK(sq_world_realtime_check(w, period, msg, sizeof msg) == 1);
        CHECK_CONTAINS(msg, "cannot run in real time even fully coarse");
        CHECK_CONTAINS(msg, "real frames of a fully coarse copy");
        CHECK_CONTAINS(msg, "force passes (body 0, level 0: 44 nodes");
        CHECK_CONTAINS(msg, "lower the frame rate");
        /* ten times the real frame: fits */
        CHECK(sq_world_realtime_check(w, 10 * real / 0.95, msg, sizeof msg) == 0);
        CHECK_CONTAINS(msg, "fully coarse frame predicted");
        /* the world checked (three times) steps as one never checked, bit for bit */
        CHECK(w->frame == 0);
        for (int k = 0; k < 20; k++) {
            sq_world_step(w, 0);
            sq_world_step(ref, 0);
        }
        int fine = sq_body_nlevels(w->bodies[0]) - 1;
        size_t bytes = sizeof(double) * 3 * (size_t)sq_body_mesh(w->bodies[0], fine)->nnodes;
        CHECK(memcmp(sq_body_displacement(w->bodies[0], fine), sq_body_displacement(ref->bodies[0], fine), bytes) == 0);
        CHECK(memcmp(sq_body_velocity(w->bodies[0], fine), sq_body_velocity(ref->bodies[0], fine), bytes) == 0);
    }
    sq_world_destroy(w);
    sq_world_destroy(ref);
    sq_world_destroy(coarse);
    sq_scene_free(sc);
    sq_scene_free(sc_inf);
}

/* the load check's copy (sq_body_create_like, forced fully coarse) borrows what it only reads
 * from the body it copies: each level's operator (sq_level_init_shared), the hierarchy and the
 * per-level mesh tables of the adaptive state (sq_lod_create_like), and takes a copy of the
 * static loads (sq_lod_set_loads_like): before, it built them all again, which on box-big was
 * most of a second of CPU and 440 MB. Checked here on the small adaptive cube under gravity (so
 * there are static loads to copy): the copy shares the operator blocks and the hierarchy, its
 * static loads are bitwise those a fresh body solves, it steps bit for bit as a body made from
 * the same definition without a like (exact: the same arithmetic on the same numbers), and the
 * body copied steps afterwards bit for bit as one never copied. A copy with another material
 * builds its own operator. */
SQ_TEST(lod_guard_load_check_copy_shares_what_it_only_reads)
{
    char dir[1024], json[2048];
    snprintf(dir, sizeof dir, "%s/../../meshes/scenes", sq_test_data());
    snprintf(json, sizeof json,
             "{\"name\": \"rt-share\", \"gravity\": [0, 0, -9.81], \"frame_rate\": 200, \"duration\": 1,"
             " \"bodies\": [{\"name\": \"cube\", \"levels\": [\"../cube/cube_l0.msh\", \"../cube/cube_l1.msh\", \"../cube/cube_l2.msh\", \"../cube/cube_l3.msh\"],"
             " \"material\": {\"lambda\": 100000, \"mu\": 40000, \"density\": 1000,"
             " \"damping\": {\"rayleigh_mass\": 2.0, \"rayleigh_stiffness\": 0.001}},"
             " \"fixed\": [{\"box\": [[-1, -1, -1], [2, 2, 0.001]]}],"
             " \"lod\": {\"mode\": \"adaptive\", \"level\": 0, \"split\": 0.005, \"merge\": 0.002}}]}");
    sq_err e = {{0}};
    sq_scene *sc = sq_scene_parse(json, dir, "rt-share", &e);
    CHECK(sc != NULL);
    if (!sc) {
        fprintf(stderr, "rt-share: %s\n", e.msg);
        return;
    }
    sq_world *w = sq_world_create(sc, &e), *ref = sq_world_create(sc, &e);
    CHECK(w && ref);
    if (!w || !ref) {
        sq_world_destroy(w);
        sq_world_destroy(ref);
        sq_scene_free(sc);
        return;
    }
    sq_body *b = w->bodies[0];
    /* the check's definition (scene/world.c coarse_def) */
    sq_body_def d = *sq_body_get_def(b);
    d.lod.split = INFINITY;
    d.lod.merge = 1e300;
    d.lod.level = 0;
    d.lod.max_node_updates = 0;
    sq_body *copy = sq_body_create_like(b, &d, &e), *fresh = sq_body_create(&d, &e);
    CHECK(copy && fresh);
    if (copy && fresh) {
        int nl = sq_body_nlevels(b);
        CHECK(nl == 4);
        for (int k = 0; k < nl; k++) {
            const sq_level *Lb = sq_body_level(b, k), *Lc = &copy->level[k], *Lf = &fresh->level[k];
            CHECK(Lc->model_shared == 1 && Lc->model.K == Lb->model.K && Lc->model.Kup == Lb->model.Kup);
            CHECK(Lc->state.d != Lb->state.d && Lc->state.v != Lb->state.v); /* the state is the copy's own */
            CHECK(Lf->model_shared == 0 && Lf->model.K != Lb->model.K);
            CHECK(copy->lod->lev[k].tab.tet_geom == b->lod->lev[k].tab.tet_geom);
            CHECK(copy->lod->lev[k].cpl.blocks_slot != b->lod->lev[k].cpl.blocks_slot);
            /* gravity: every level has its static equilibrium, copied, not shared */
            const double *ds = copy->lod->lev[k].d_static, *df = fresh->lod->lev[k].d_static;
            CHECK(ds && df && ds != b->lod->lev[k].d_static);
            if (ds && df)
                CHECK(memcmp(ds, df, sizeof(double) * 3 * (size_t)Lb->model.n) == 0);
        }
        CHECK(copy->lod->shared == 1 && fresh->lod->shared == 0);
        CHECK(copy->lod->h.link[0].parent == b->lod->h.link[0].parent);
        /* the copy and the fresh body: the same frames, bit for bit */
        sq_frame_profile p;
        for (int f = 0; f < 10; f++) {
            sq_body_frame(copy, NULL, 0, NULL, &p, 0);
            sq_body_frame(fresh, NULL, 0, NULL, &p, 0);
        }
        for (int k = 0; k < nl; k++) {
            size_t bytes = sizeof(double) * 3 * (size_t)copy->level[k].model.n;
            CHECK(memcmp(sq_body_displacement(copy, k), sq_body_displacement(fresh, k), bytes) == 0);
            CHECK(memcmp(sq_body_velocity(copy, k), sq_body_velocity(fresh, k), bytes) == 0);
        }
        /* another material: nothing of the operator to borrow */
        sq_body_def d2 = d;
        d2.material.mu *= 2;
        sq_body *other = sq_body_create_like(b, &d2, &e);
        CHECK(other != NULL);
        if (other)
            CHECK(other->level[0].model_shared == 0 && other->level[0].model.K != b->level[0].model.K);
        sq_body_destroy(other);
    }
    sq_body_destroy(copy);
    sq_body_destroy(fresh);
    /* the body copied (its copies gone) steps as one never copied */
    for (int f = 0; f < 10; f++) {
        sq_world_step(w, 0);
        sq_world_step(ref, 0);
    }
    int fine = sq_body_nlevels(b) - 1;
    size_t bytes = sizeof(double) * 3 * (size_t)sq_body_mesh(b, fine)->nnodes;
    CHECK(memcmp(sq_body_displacement(b, fine), sq_body_displacement(ref->bodies[0], fine), bytes) == 0);
    CHECK(memcmp(sq_body_velocity(b, fine), sq_body_velocity(ref->bodies[0], fine), bytes) == 0);
    sq_world_destroy(w);
    sq_world_destroy(ref);
    sq_scene_free(sc);
}
