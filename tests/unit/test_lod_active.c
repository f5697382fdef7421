/* test_lod_active.c - the cost of the adaptive frame follows the active set: coarse ghosts
 * nobody reads are pushed on demand only, and that changes nothing a caller can see. */
#include <stdint.h>

#include "lod/lod_test.h"
#include "body/body_internal.h"
#include "scene/scene.h"
#include "sq_test.h"
#include "test_scene_helpers.h"
#include "test_lod_helpers.h"
#include "test_sim_helpers.h"

/* four cube levels: 3, 6 (jittered), 12, 18 (jittered) cells */
static int four_meshes(sq_mesh **m) { return lh_cube_levels(m, 4, (const int[]){3, 6, 12, 18}); }

/* a sphere pressing the top 8 cm over 0.6 s, held, released at 1.2 s, moving sideways while
 * it presses so regions split and merge during the poke */
static sq_tool moving_poke(double t)
{
    double depth = t < 0.6 ? 0.08 * t / 0.6 : 0.08;
    double x = 0.4 + 0.2 * (t < 1.2 ? t / 1.2 : 1.0);
    return lh_sphere(x, 0.5, 1.15 - depth, 0.15, t < 1.2);
}

/* Two identical bodies, one flushed after every frame (every ghost value up to date, as the
 * eager push kept them) and one never flushed: the trajectories must be the same bit for bit
 * (the flush only fills values nothing inside the frame reads), and after a final flush every
 * level's d and v must be equal. Fails if the needed set misses a value the frame reads. */
SQ_TEST(lod_flush_does_not_change_the_trajectory)
{
    sq_mesh *m[4];
    if (!four_meshes(m)) {
        CHECK(0);
        return;
    }
    sq_body_def def = lh_cube_def(m, 4);
    def.gravity[2] = 0; /* the poke alone: most of the body stays coarse, far ghosts stay stale */
    def.lod = lh_lod(SQ_LOD_ADAPTIVE, 0.02, 0.004);
    sq_err e = {{0}};
    sq_body *b[2] = {sq_body_create(&def, &e), sq_body_create(&def, &e)};
    TH_REQUIRE(b[0] && b[1]);
    long diff_frames = 0, max_fine = 0, splits = 0, merges = 0, bad_levels = 0;
    long stale_frames = 0, bad_flushed = 0; /* sq_lod_flushed_d against the flush itself */
    double *pre[4] = {NULL};
    for (int k = 1; k < 4; k++) {
        pre[k] = malloc(sizeof(double) * 3 * (size_t)m[k]->nnodes);
        TH_REQUIRE(pre[k]);
    }
    for (int f = 0; f < 120; f++) {
        sq_tool tool = moving_poke(f * def.frame_dt);
        sq_frame_profile p[2];
        for (int i = 0; i < 2; i++)
            sq_body_frame(b[i], &tool, 1, NULL, &p[i], 0);
        stale_frames += b[0]->lod->push.stale != 0;
        for (int k = 1; k < 4; k++)
            for (int j = 0; j < m[k]->nnodes; j++)
                sq_lod_flushed_d(b[0]->lod, k, j, pre[k] + 3 * (size_t)j);
        sq_lod_flush(b[0]->lod);
        for (int k = 1; k < 4; k++)
            bad_flushed += memcmp(pre[k], b[0]->level[k].state.d, sizeof(double) * 3 * (size_t)m[k]->nnodes) != 0;
        diff_frames += p[0].node_updates != p[1].node_updates || p[0].active[3] != p[1].active[3] ||
                       p[0].splits != p[1].splits || p[0].merges != p[1].merges;
        max_fine = SQ_MAX(max_fine, p[0].active[3]);
        /* the node levels (computed level by level) against the walk up to the active ancestor */
        for (int j = 0; j < m[3]->nnodes; j++) {
            int k = 3, x = j;
            while (k > 0 && b[1]->lod->lev[k].lay.state[x] != 1) {
                x = b[1]->lod->h.link[k - 1].parent[x];
                k--;
            }
            bad_levels += b[1]->node_level[j] != (unsigned char)k;
        }
        splits += p[0].splits;
        merges += p[0].merges;
    }
    sq_lod_flush(b[1]->lod);
    int same = 1;
    for (int k = 0; k < 4; k++) {
        size_t n3 = 3 * (size_t)m[k]->nnodes * sizeof(double);
        same &= !memcmp(b[0]->level[k].state.d, b[1]->level[k].state.d, n3) && !memcmp(b[0]->level[k].state.v, b[1]->level[k].state.v, n3);
    }
    if (getenv("SQ_LOD_VERBOSE"))
        fprintf(stderr, "flush: finest active up to %ld of %d, %ld splits %ld merges, %ld frames differ, "
                "states %s\n", max_fine, m[3]->nnodes, splits, merges, diff_frames, same ? "equal" : "DIFFER");
    CHECK(max_fine > 0 && splits > 0 && merges > 0); /* it refined down to level 3 and back */
    CHECK(max_fine < m[3]->nnodes / 2);              /* ... locally */
    CHECK(diff_frames == 0);
    CHECK(same);
    CHECK(bad_levels == 0);
    CHECK(stale_frames > 0 && bad_flushed == 0);
    for (int k = 1; k < 4; k++)
        free(pre[k]);
    sq_body_destroy(b[0]);
    sq_body_destroy(b[1]);
    lh_free_meshes(m, 4);
}

/* Nothing refined (split = inf): the end-of-frame push updates the finest surface and what it
 * is interpolated from, not the whole finest level; a flush then gives exactly the eager
 * cascade (every coarse ghost interpolated from the level below, coarse to fine). */
SQ_TEST(lod_coarse_frame_pushes_what_is_read)
{
    sq_mesh *m[4];
    if (!four_meshes(m)) {
        CHECK(0);
        return;
    }
    sq_body_def def = lh_cube_def(m, 4);
    def.lod = lh_lod(SQ_LOD_ADAPTIVE, INFINITY, 0.001);
    sq_err e = {{0}};
    sq_body *b = sq_body_create(&def, &e);
    TH_REQUIRE(b);
    for (int f = 0; f < 20; f++)
        sq_body_frame(b, NULL, 0, NULL, NULL, 0);
    sq_lod *lod = b->lod;
    int F = 3, nF = m[F]->nnodes, nsurf = m[F]->nsurf;
    if (getenv("SQ_LOD_VERBOSE"))
        fprintf(stderr, "coarse frame: pushed %d / %d / %d of %d / %d / %d nodes (finest surface %d)\n",
                lod->lev[1].lists.nneeded, lod->lev[2].lists.nneeded, lod->lev[3].lists.nneeded, m[1]->nnodes, m[2]->nnodes, nF,
                nsurf);
    CHECK(lod->push.stale);
    CHECK(lod->lev[F].lists.nneeded == nsurf); /* exactly the rendered surface at the finest level */
    CHECK(lod->lev[F].lists.nneeded < nF / 2);
    /* the eager cascade by hand, on copies */
    double *d[4], *v[4];
    for (int k = 0; k < 4; k++) {
        size_t n3 = 3 * (size_t)m[k]->nnodes;
        d[k] = malloc(sizeof(double) * n3);
        v[k] = malloc(sizeof(double) * n3);
        memcpy(d[k], b->level[k].state.d, sizeof(double) * n3);
        memcpy(v[k], b->level[k].state.v, sizeof(double) * n3);
    }
    for (int k = 1; k < 4; k++) {
        const sq_lod_link *ln = &lod->h.link[k - 1];
        for (int j = 0; j < m[k]->nnodes; j++) {
            const int *tn = m[k - 1]->tets + 4 * ln->up_tet[j];
            const double *bb = ln->up_bary + 4 * j;
            double dd[3] = {0, 0, 0}, vv[3] = {0, 0, 0};
            for (int q = 0; q < 4; q++)
                for (int c = 0; c < 3; c++) {
                    dd[c] += bb[q] * d[k - 1][3 * tn[q] + c];
                    vv[c] += bb[q] * v[k - 1][3 * tn[q] + c];
                }
            for (int c = 0; c < 3; c++) {
                int fr = !(b->level[k].model.fixed[j] & (1u << c));
                d[k][3 * j + c] = fr ? dd[c] : 0.0;
                v[k][3 * j + c] = fr ? vv[c] : 0.0;
            }
        }
    }
    /* surface values were pushed in the frame: equal before any flush */
    int surf_ok = 1;
    for (int s = 0; s < nsurf; s++) {
        int j = m[F]->surf_nodes[s];
        surf_ok &= !memcmp(b->level[F].state.d + 3 * j, d[F] + 3 * j, 3 * sizeof(double));
    }
    CHECK(surf_ok);
    sq_lod_flush(lod);
    CHECK(!lod->push.stale);
    int all_ok = 1;
    for (int k = 1; k < 4; k++) {
        size_t n3 = 3 * (size_t)m[k]->nnodes * sizeof(double);
        all_ok &= !memcmp(b->level[k].state.d, d[k], n3) && !memcmp(b->level[k].state.v, v[k], n3);
    }
    CHECK(all_ok);
    /* something moved: gravity sags the body */
    double sag = 0;
    for (int j = 0; j < nF; j++)
        sag = fmax(sag, fabs(b->level[F].state.d[3 * j + 2]));
    CHECK(sag > 1e-4);
    for (int k = 0; k < 4; k++) {
        free(d[k]);
        free(v[k]);
    }
    sq_body_destroy(b);
    lh_free_meshes(m, 4);
}

/* A cube resting in its static sag under its own weight: the criterion judges the motion from
 * each level's static equilibrium, so the sag alone splits nothing, although its own curvature
 * is far above the split threshold (judged from zero it would split most of the body). */
SQ_TEST(lod_static_sag_splits_nothing)
{
    sq_mesh *m[2];
    if (!lh_cube_levels(m, 2, (const int[]){3, 6})) {
        CHECK(0);
        return;
    }
    sq_body_def def = lh_cube_def(m, 2);
    double split = 0.002;
    def.lod = lh_lod(SQ_LOD_ADAPTIVE, split, split / 4);
    sq_err e = {{0}};
    sq_body *b = sq_body_create(&def, &e);
    TH_REQUIRE(b);
    sq_lod *lod = b->lod;
    CHECK(lod->lev[0].d_static != NULL && lod->lev[1].d_static != NULL); /* solved at creation */
    if (!lod->lev[0].d_static || !lod->lev[1].d_static)
        return;
    /* every level at its own static equilibrium */
    for (int k = 0; k < 2; k++)
        memcpy(b->level[k].state.d, lod->lev[k].d_static, sizeof(double) * 3 * (size_t)m[k]->nnodes);
    double filt = 0, raw = 0, sag = 0;
    for (int i = 0; i < m[0]->nnodes; i++) {
        filt = fmax(filt, sq_lod_delta(lod, 0, i));
        sag = fmax(sag, fabs(b->level[0].state.d[3 * i + 2]));
    }
    double *keep = lod->lev[0].d_static;
    lod->lev[0].d_static = NULL;
    int raw_over = 0;
    for (int i = 0; i < m[0]->nnodes; i++) {
        double d = sq_lod_delta(lod, 0, i);
        raw = fmax(raw, d);
        raw_over += d > split;
    }
    lod->lev[0].d_static = keep;
    int splits = -1, merges = -1;
    sq_lod_adapt(lod, 1, &splits, &merges);
    if (getenv("SQ_LOD_VERBOSE"))
        fprintf(stderr, "static sag %.1f mm: criterion of the field up to %.4g m (%d of %d nodes over split "
                "%g), of the motion from equilibrium %.3g m; %d splits\n", 1e3 * sag, raw, raw_over,
                m[0]->nnodes, split, filt, splits);
    CHECK(sag > 0.01);
    CHECK(raw_over > m[0]->nnodes / 4); /* judged from zero, the sag would split */
    /* the level's own equilibrium has no motion: zero up to the CG tolerance (1e-8 relative
     * residual on a 4 cm sag; 1e-6 m leaves three orders of margin below the threshold) */
    CHECK(filt < 1e-6);
    CHECK(splits == 0);
    sq_body_destroy(b);
    lh_free_meshes(m, 2);
}

/* The guard holds the rate by merging, not only by refusing splits: a body refined under a
 * poke with no budget, then given a budget nothing fits in (1 ns), is merged back to level 0
 * within two frames although the tool still presses, and the event says why. (Before, a refined
 * region stayed: only new splits were refused.) */
SQ_TEST(lod_guard_merges_when_the_frame_does_not_fit)
{
    sq_mesh *m[3];
    if (!lh_cube_levels(m, 3, (const int[]){3, 6, 12})) {
        CHECK(0);
        return;
    }
    sq_body_def def = lh_cube_def(m, 3);
    def.gravity[2] = 0;
    def.lod = lh_lod(SQ_LOD_ADAPTIVE, 0.05, 0.00625);
    sq_err e = {{0}};
    sq_body *b = sq_body_create(&def, &e);
    TH_REQUIRE(b);
    sq_frame_profile p;
    int refined = 0;
    for (int f = 0; f < 25; f++) {
        sq_tool tool = lh_sphere(0.5, 0.5, 1.2 - 0.1 * SQ_MIN(f / 20.0, 1.0), 0.2, 1);
        sq_body_frame(b, &tool, 1, NULL, &p, 0);
        refined = SQ_MAX(refined, p.active[2]);
    }
    int before = p.active[0] < m[0]->nnodes;
    int coarse_at = -1, merged = 0, said = 0;
    for (int f = 0; f < 5; f++) {
        sq_tool tool = lh_sphere(0.5, 0.5, 1.1, 0.2, 1);
        sq_body_frame(b, &tool, 1, NULL, &p, 1e-9);
        merged += p.merges;
        said += strstr(p.event, "splitting refused") != NULL;
        if (coarse_at < 0 && p.active[1] == 0 && p.active[2] == 0)
            coarse_at = f;
    }
    if (getenv("SQ_LOD_VERBOSE"))
        fprintf(stderr, "guard: finest active up to %d under the poke; with a 1 ns budget %d merges, "
                "all coarse at frame %d; last event: %s\n", refined, merged, coarse_at, p.event);
    CHECK(refined > 0 && before);
    CHECK(coarse_at >= 0 && coarse_at <= 1);
    CHECK(merged > 0);
    CHECK(said == 5);
    sq_body_destroy(b);
    lh_free_meshes(m, 3);
}

/* level k of two lods: every list, block and bound the rebuild makes, equal bit for bit */
static int same_level(const sq_lod *a, const sq_lod *b, int k)
{
    const sq_lod_level *x = &a->lev[k], *y = &b->lev[k];
    const sq_level *L = &a->lv[k];
    int n = L->model.n;
#define SAME(p, cnt) ((cnt) == 0 || !memcmp((x->p), (y->p), sizeof(*(x->p)) * (size_t)(cnt)))
    if (x->lay.nring != y->lay.nring || x->lay.nfrontier != y->lay.nfrontier || x->lay.nactive != y->lay.nactive ||
        x->lists.ninner_list != y->lists.ninner_list || x->lists.nintegrated_list != y->lists.nintegrated_list ||
        x->lists.nread_list != y->lists.nread_list || x->lists.nneeded != y->lists.nneeded || x->rate.extra_log2 != y->rate.extra_log2 ||
        x->cpl.blocks_dirty != y->cpl.blocks_dirty)
        return 0;
    int ok = SAME(lay.state, n) && SAME(lay.ring, x->lay.nring) && SAME(lay.ring_index, n) && SAME(lay.frontier, x->lay.nfrontier) &&
             SAME(lay.inner, n) && SAME(lists.active_list, x->lay.nactive) && SAME(lists.inner_list, x->lists.ninner_list) &&
             SAME(lists.integrated_list, x->lists.nintegrated_list) && SAME(lists.read_list, x->lists.nread_list) &&
             SAME(lists.needed, x->lists.nneeded) && SAME(rate.coupled_rowsum, n);
    ok = ok && SAME(lay.src_start, x->lay.nring + 1) && SAME(lay.src_levels, x->lay.nring);
    int ns = x->lay.src_start[x->lay.nring];
    ok = ok && SAME(lay.src_level, ns) && SAME(lay.src_node, ns) && SAME(lay.src_weight, ns) && SAME(lay.src_rend, ns);
    if (!ok || x->cpl.blocks_dirty)
        return ok;
    ok = SAME(cpl.ring_off, x->lay.nring + 1) && SAME(cpl.front_off, x->lay.nfrontier + 1);
    if (!ok)
        return 0;
    int nr = x->cpl.ring_off[x->lay.nring], nf = x->cpl.front_off[x->lay.nfrontier], nm = 0;
    for (int r = 0; r < x->lay.nfrontier; r++)
        nm += L->model.row_start[x->lay.frontier[r] + 1] - L->model.row_start[x->lay.frontier[r]];
    ok = SAME(cpl.ring_col, nr) && SAME(cpl.front_col, nf) && SAME(cpl.ring_K, 9 * nr) && SAME(cpl.front_K, 9 * nf) &&
         SAME(cpl.front_merged, 9 * nm) && SAME(cpl.ring_T, 12 * nr) && SAME(cpl.front_T, 12 * nm);
    if (L->model.D)
        ok = ok && SAME(cpl.ring_D, 9 * nr) && SAME(cpl.front_D, 9 * nf);
#undef SAME
    return ok;
}

/* The rebuild after a split/merge pass redoes only the block rows next to the nodes whose state
 * changed (coupling.c) and copies the others. Checked against the full rebuild (full_rebuild = 1):
 * two bodies over a poke that presses, holds and releases on four levels, one rebuilding every
 * row; after every frame each level's lists, ring and frontier blocks, merged rows, sources,
 * coupled row sums and extra substeps, and every level's d and v, must be equal bit for bit. Run
 * with rate damping (b K) and with the paper's viscosities (the viscous blocks too). Fails if a
 * row that depends on a changed node is copied instead of recomputed. */
SQ_TEST(lod_incremental_rebuild_equals_full)
{
    sq_mesh *m[4];
    if (!four_meshes(m)) {
        CHECK(0);
        return;
    }
    for (int visc = 0; visc < 2; visc++) {
        sq_body_def def = lh_cube_def(m, 4);
        def.gravity[2] = 0;
        def.lod = lh_lod(SQ_LOD_ADAPTIVE, 0.02, 0.004);
        if (visc) {
            def.material.use_viscosity = 1;
            def.material.phi = 20;
            def.material.psi = 50;
        } else {
            def.material.rayleigh_stiffness = 0.001;
        }
        sq_err e = {{0}};
        sq_body *b[2] = {sq_body_create(&def, &e), sq_body_create(&def, &e)};
        TH_REQUIRE(b[0] && b[1]);
        sq_lod_test_of(b[1]->lod)->full_rebuild = 1;
        long bad_frames = 0, splits = 0, merges = 0, max_fine = 0;
        for (int f = 0; f < 120; f++) {
            sq_tool tool = moving_poke(f * def.frame_dt);
            sq_frame_profile p[2];
            for (int i = 0; i < 2; i++)
                sq_body_frame(b[i], &tool, 1, NULL, &p[i], 0);
            int same = p[0].node_updates == p[1].node_updates && p[0].splits == p[1].splits &&
                       p[0].merges == p[1].merges;
            for (int k = 0; k < 4; k++) {
                size_t n3 = 3 * (size_t)m[k]->nnodes * sizeof(double);
                same &= same_level(b[0]->lod, b[1]->lod, k);
                same &= !memcmp(b[0]->level[k].state.d, b[1]->level[k].state.d, n3) &&
                        !memcmp(b[0]->level[k].state.v, b[1]->level[k].state.v, n3);
            }
            bad_frames += !same;
            splits += p[0].splits;
            merges += p[0].merges;
            max_fine = SQ_MAX(max_fine, p[0].active[3]);
        }
        long computed[2] = {0, 0}, built[2] = {0, 0};
        for (int i = 0; i < 2; i++)
            for (int k = 0; k < 4; k++) {
                computed[i] += b[i]->lod->lev[k].cpl.rows_computed;
                built[i] += b[i]->lod->lev[k].cpl.rows_built;
            }
        if (getenv("SQ_LOD_VERBOSE"))
            fprintf(stderr, "incremental rebuild (%s): %ld splits %ld merges, finest active up to %ld; rows "
                    "computed %ld of %ld (full: %ld of %ld); needed set by changes %ld times, from scratch %ld; %ld frames "
                    "differ\n", visc ? "viscosities" : "b K", splits, merges, max_fine, computed[0], built[0],
                    computed[1], built[1], b[0]->lod->push.needed_counts[1], b[0]->lod->push.needed_counts[0], bad_frames);
        CHECK(splits > 0 && merges > 0 && max_fine > 0); /* down to level 3 and back */
        CHECK(bad_frames == 0);
        CHECK(built[0] == built[1] && computed[1] == built[1]); /* the reference rebuilt every row */
        CHECK(computed[0] < built[0] / 2);                      /* the incremental one far fewer */
        CHECK(b[0]->lod->push.needed_counts[1] > 10 * b[0]->lod->push.needed_counts[0]); /* needed set by changes */
        sq_body_destroy(b[0]);
        sq_body_destroy(b[1]);
    }
    lh_free_meshes(m, 4);
}

/* Under a static load the mixed layout's own equilibrium differs from each level's, so a
 * merged node can read over the split threshold at once (the coarse level's sag differs from
 * the finer one's where the refined region was) and split again a few frames later: the linear
 * organ, with no tool at all, split and merged in every frame after it settled. A split node of
 * a body with a static load now merges only if its own criterion, read from the values it would
 * take up, is under the merge threshold (criterion.c: the same hysteresis band as its children's
 * test). The shipped organ (corotational since 2026-12-02), no tool: no pass after frame 50.
 * With no parent test, 40 of frames 61-100 have a split or a merge; with the parent judged
 * against the split threshold (the first version of the rule) 26: one level-0 node merged and
 * split again every four frames. Tolerance: at most 2 of frames 61-100 with a split or merge,
 * for a late threshold crossing under other rounding (the sanitizer build). */
SQ_TEST(lod_static_load_settles_without_split_merge_churn)
{
    sq_scene *sc = th_shipped_scene("organ");
    CHECK(sc != NULL);
    if (!sc)
        return;
    sc->ntools = 0;
    sq_err e = {{0}};
    sq_world *w = sq_world_create(sc, &e);
    CHECK(w != NULL);
    if (!w) {
        fprintf(stderr, "world: %s\n", e.msg);
        sq_scene_free(sc);
        return;
    }
    int passes = 0, refined = 0;
    for (int f = 1; f <= 100; f++) {
        sq_world_step(w, 0);
        const sq_frame_profile *p = &w->profile[0];
        if (f > 60 && p->splits + p->merges > 0)
            passes++;
        if (f == 100)
            refined = p->active[1] + p->active[2];
        CHECK(p->reset == 0);
    }
    if (getenv("SQ_LOD_VERBOSE"))
        fprintf(stderr, "organ, gravity only: %d of frames 61-100 with a split or merge; %d nodes active on levels 1-2\n",
                passes, refined);
    CHECK(passes <= 2);
    sq_world_destroy(w);
    sq_scene_free(sc);
}
