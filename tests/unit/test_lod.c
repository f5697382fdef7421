/* test_lod.c - the level-of-detail hierarchy and the adaptive frame: hierarchy validity on
 * nested, jittered and scaled (partly outside) meshes; forced finest / coarsest against the
 * fixed runs; a scripted poke that refines near the tool and merges back; energy across
 * split/merge; the frame budget and the node-update cap; sleep; tool feedback. */
#include <float.h>
#include <stdint.h>

#include "lod/lod.h"
#include "sq_test.h"
#include "test_lod_helpers.h"
#include "test_sim_helpers.h"

/* ------------------------------------------------------------------ hierarchy */

/* checks one link against brute force: nearest parents, CSR, coordinates, linear exactness */
static void check_link(const sq_hierarchy *h, int k)
{
    const sq_lod_link *ln = &h->link[k];
    const sq_mesh *mc = h->mesh[k], *mf = h->mesh[k + 1];
    int nc = mc->nnodes, nf = mf->nnodes;
    CHECK(ln->child_start[0] == 0 && ln->child_start[nc] == nf);
    int *seen = calloc((size_t)nf, sizeof(int));
    for (int p = 0; p < nc; p++)
        for (int c = ln->child_start[p]; c < ln->child_start[p + 1]; c++) {
            int j = ln->child[c];
            CHECK(j >= 0 && j < nf);
            if (j < 0 || j >= nf)
                continue;
            seen[j]++;
            CHECK(ln->parent[j] == p);
        }
    int bad_parent = 0, bad_seen = 0;
    for (int j = 0; j < nf; j++) {
        bad_seen += seen[j] != 1;
        /* the parent is the nearest coarse node (brute force; ties within rounding) */
        double best = DBL_MAX;
        for (int p = 0; p < nc; p++)
            best = fmin(best, lh_dist2(mf->x + 3 * j, mc->x + 3 * p));
        int p = ln->parent[j];
        if (p < 0 || p >= nc || lh_dist2(mf->x + 3 * j, mc->x + 3 * p) > best + 1e-12)
            bad_parent++;
    }
    CHECK(bad_seen == 0);
    CHECK(bad_parent == 0);
    free(seen);
    /* coordinates sum to 1 and reproduce a linear field (the node positions) exactly, also by
     * extrapolation from the nearest tet for nodes outside: 1e-9 m is rounding on a 1 m body */
    double worst_sum = 0, worst_pos = 0;
    for (int j = 0; j < nf; j++) {
        const double *b = ln->up_bary + 4 * j;
        worst_sum = fmax(worst_sum, fabs(b[0] + b[1] + b[2] + b[3] - 1));
        double p[3];
        lh_interp(mc, ln->up_tet[j], b, mc->x, p);
        worst_pos = fmax(worst_pos, sqrt(lh_dist2(p, mf->x + 3 * j)));
    }
    for (int i = 0; i < nc; i++) {
        const double *b = ln->down_bary + 4 * i;
        worst_sum = fmax(worst_sum, fabs(b[0] + b[1] + b[2] + b[3] - 1));
        double p[3];
        lh_interp(mf, ln->down_tet[i], b, mf->x, p);
        worst_pos = fmax(worst_pos, sqrt(lh_dist2(p, mc->x + 3 * i)));
    }
    CHECK(worst_sum <= 1e-9);
    CHECK(worst_pos <= 1e-9);
}

SQ_TEST(lod_hierarchy_boxes_jittered_and_scaled)
{
    sq_mesh *m[4];
    m[0] = lh_cube(3, 0, 1.0, 1);
    m[1] = lh_cube(5, 0.12, 1.0, 2);  /* irregular: interior nodes jittered */
    m[2] = lh_cube(8, 0.12, 1.02, 3); /* 2% larger: its boundary lies outside level 1 */
    m[3] = lh_cube(10, 0, 1.0, 4);
    for (int k = 0; k < 4; k++)
        CHECK(m[k] != NULL);
    if (!m[0] || !m[1] || !m[2] || !m[3])
        return;
    sq_hierarchy h;
    sq_err e = {{0}};
    const sq_mesh *mm[4] = {m[0], m[1], m[2], m[3]};
    CHECK(sq_hierarchy_build(&h, mm, 4, &e) == 0);
    if (e.msg[0])
        fprintf(stderr, "%s\n", e.msg);
    for (int k = 0; k < 3; k++)
        check_link(&h, k);
    /* counts: on a 3 -> 5 cell refinement every coarse node has children; nodes of the scaled
     * mesh outside level 1 get one negative coordinate; level 1 nodes are all inside level 2 */
    sq_hierarchy_link_stats st;
    sq_hierarchy_stats(&h, 0, &st);
    CHECK(st.nparents == 64 && st.nchildren == 216);
    CHECK(st.childless == 0);
    CHECK(st.min_children >= 1);
    sq_hierarchy_stats(&h, 1, &st);
    CHECK(st.up_outside > 0);
    CHECK(st.up_min_bary < 0 && st.up_min_bary > -0.5);
    CHECK(st.down_outside == 0);
    sq_hierarchy_stats(&h, 2, &st);
    CHECK(st.down_outside > 0); /* level-2 boundary nodes lie outside the unit cube of level 3 */
    sq_hierarchy_free(&h);

    /* errors name the problem: no mesh, too many levels */
    const sq_mesh *bad[2] = {m[0], NULL};
    CHECK(sq_hierarchy_build(&h, bad, 2, &e) == -1);
    CHECK_CONTAINS(e.msg, "level 1");
    CHECK(sq_hierarchy_build(&h, mm, SQ_MAX_LEVELS + 1, &e) == -1);
    CHECK_CONTAINS(e.msg, "levels");
    lh_free_meshes(m, 4);
}

/* ------------------------------------------------------------------ forced modes */

/* run `frames` frames of the cube (gravity, damping, a pushing sphere for half of them) and
 * return the displacement of `level` (copied, caller frees) */
static double *run_cube(sq_mesh **m, int nlevels, sq_lod_def lod, int frames, int level)
{
    sq_body_def def = lh_cube_def(m, nlevels);
    def.lod = lod;
    sq_err e = {{0}};
    sq_body *b = sq_body_create(&def, &e);
    CHECK(b != NULL);
    if (!b) {
        fprintf(stderr, "%s\n", e.msg);
        return NULL;
    }
    for (int f = 0; f < frames; f++) {
        sq_tool t = lh_sphere(0.5, 0.5, 1.25 - 0.1 * fmin(1.0, f / 10.0), 0.3, f < frames / 2);
        sq_body_frame(b, &t, 1, NULL, NULL, 0);
    }
    int n = sq_body_mesh(b, level)->nnodes;
    double *d = malloc(sizeof(double) * 3 * n);
    memcpy(d, sq_body_displacement(b, level), sizeof(double) * 3 * n);
    sq_body_destroy(b);
    return d;
}

SQ_TEST(lod_forced_finest_and_coarsest_match_fixed_runs)
{
    sq_mesh *m[3];
    if (!lh_cube_levels(m, 3, (const int[]){2, 4, 6})) {
        CHECK(0);
        return;
    }
    int frames = 30;
    sq_lod_def fixed = lh_lod(SQ_LOD_FIXED, 0, 0), adaptive = lh_lod(SQ_LOD_ADAPTIVE, 0, 0);
    /* forced finest: split 0 simulates every region at level 2 with level 2's step and the
     * same holds: the same arithmetic as the fixed finest run, so equal to rounding (the
     * tolerance 1e-12 of the largest displacement allows a different summation order) */
    fixed.level = 2;
    double *df = run_cube(m, 3, fixed, frames, 2);
    double *da = run_cube(m, 3, adaptive, frames, 2);
    double dmax = 0, diff = 0;
    for (int i = 0; df && da && i < 3 * m[2]->nnodes; i++) {
        dmax = fmax(dmax, fabs(df[i]));
        diff = fmax(diff, fabs(df[i] - da[i]));
    }
    if (getenv("SQ_LOD_VERBOSE"))
        fprintf(stderr, "forced finest: max |d| %.6g, max diff %.3g\n", dmax, diff);
    CHECK(dmax > 1e-3); /* the tool and gravity did deform it */
    CHECK(diff <= 1e-12 * dmax);
    free(df);
    free(da);
    /* forced coarsest: split = inf never leaves level 0; the hold's translation goes to the
     * level-0 node standing for the touched surface node, as the fixed coarse run does with
     * its nearest node, so compare without the tool: gravity only */
    fixed.level = 0;
    adaptive.split = INFINITY;
    adaptive.merge = 0;
    sq_body_def def = lh_cube_def(m, 3);
    sq_body *bf, *ba;
    sq_err e = {{0}};
    def.lod = fixed;
    bf = sq_body_create(&def, &e);
    def.lod = adaptive;
    ba = sq_body_create(&def, &e);
    CHECK(bf && ba);
    if (bf && ba) {
        sq_frame_profile prof;
        for (int f = 0; f < frames; f++) {
            sq_body_frame(bf, NULL, 0, NULL, NULL, 0);
            sq_body_frame(ba, NULL, 0, NULL, &prof, 0);
            CHECK(prof.splits == 0);
        }
        CHECK(prof.active[0] == m[0]->nnodes && prof.active[1] == 0 && prof.active[2] == 0);
        const double *d0f = sq_body_displacement(bf, 0), *d0a = sq_body_displacement(ba, 0);
        dmax = diff = 0;
        for (int i = 0; i < 3 * m[0]->nnodes; i++) {
            dmax = fmax(dmax, fabs(d0f[i]));
            diff = fmax(diff, fabs(d0f[i] - d0a[i]));
        }
        if (getenv("SQ_LOD_VERBOSE"))
            fprintf(stderr, "forced coarsest: max |d| %.6g, max diff %.3g\n", dmax, diff);
        CHECK(dmax > 1e-4);
        CHECK(diff <= 1e-12 * dmax);
        /* the finest level (rendered surface) interpolates level 0 exactly like the fixed
         * coarse run's surface: compare a probe on the top face */
        double p[3] = {0.7, 0.6, 1.0}, uf[3], ua[3];
        CHECK(sq_body_probe(bf, p, uf) == 0 && sq_body_probe(ba, p, ua) == 0);
        if (getenv("SQ_LOD_VERBOSE"))
            fprintf(stderr, "forced coarsest probe: fixed %.6g adaptive %.6g\n", uf[2], ua[2]);
        CHECK_NEAR(ua[2], uf[2], 0.05 * fabs(uf[2])); /* two interpolation paths: 5% */
    }
    sq_body_destroy(bf);
    sq_body_destroy(ba);
    lh_free_meshes(m, 3);
}

/* ------------------------------------------------------------------ shipped meshes */

/* the shipped Gmsh families (independent, non-nested meshes of each shape) */
static void shipped_hierarchy(const char *shape, int brute_force)
{
    sq_mesh *m[4] = {NULL, NULL, NULL, NULL};
    sq_err e = {{0}};
    int ok = 1;
    for (int k = 0; k < 4; k++) {
        m[k] = th_shipped_mesh("%s/%s_l%d.msh", shape, shape, k);
        ok &= m[k] != NULL;
    }
    CHECK(ok);
    if (ok) {
        sq_hierarchy h;
        const sq_mesh *mm[4] = {m[0], m[1], m[2], m[3]};
        CHECK(sq_hierarchy_build(&h, mm, 4, &e) == 0);
        for (int k = 0; k < 3; k++) {
            if (brute_force || k < 2)
                check_link(&h, k);
            sq_hierarchy_link_stats st;
            sq_hierarchy_stats(&h, k, &st);
            if (getenv("SQ_LOD_VERBOSE"))
                fprintf(stderr, "%s link %d: %d -> %d nodes, children %d..%d (mean %.1f), %d childless, "
                        "%d fine nodes outside level %d (min coordinate %.3f), %d coarse outside level %d\n",
                        shape, k, st.nparents, st.nchildren, st.min_children, st.max_children,
                        st.mean_children, st.childless, st.up_outside, k, st.up_min_bary,
                        st.down_outside, k + 1);
            /* halving edges: about 4-8 children per parent on average */
            CHECK(st.mean_children > 2.5 && st.mean_children < 10);
            /* the coarser surface cuts corners of the finer one: some nodes are outside, and
             * their one negative coordinate stays modest */
            CHECK(st.up_min_bary > -1.0);
            CHECK(st.down_min_bary > -1.0);
        }
        sq_hierarchy_free(&h);
    }
    lh_free_meshes(m, 4);
}

SQ_TEST(lod_hierarchy_shipped_cube)
{
    shipped_hierarchy("cube", 1);
}

SQ_TEST(lod_hierarchy_shipped_organ)
{
    shipped_hierarchy("organ", 0); /* brute-force nearest on the two coarser links */
}
