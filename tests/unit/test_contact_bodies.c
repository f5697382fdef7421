/* test_contact_bodies.c - body against body with adaptive bodies (docs/physics.md section 13):
 * an adaptive body's active surface nodes meet another body's surface at every level step, and
 * its finest surface, as combinations of its active nodes, is a target of the other's nodes
 * with the reactions handed back through the transpose. */
#include <math.h>
#include <stdlib.h>
#include <string.h>

#include "lod/lod.h"
#include "body/body_internal.h"
#include "scene/scene.h"
#include "sq_test.h"
#include "test_scene_helpers.h"

/* the fixed pair's lod (contact_two_bodies_squeezed_equal_and_opposite): one level, cube_l1 */
#define LOD_FIXED1 "\"levels\": [\"../cube/cube_l1.msh\"], \"lod\": {\"mode\": \"fixed\"}"
/* adaptive on cube_l0 (44 nodes) and cube_l1 (142, the fixed test's mesh as the finest); the
 * thresholds leave the squeezed blocks mixed (about 26 level-0 and 65 level-1 active nodes):
 * the contact region refines, the rest stays coarse */
#define LOD_ADAPTIVE "\"levels\": [\"../cube/cube_l0.msh\", \"../cube/cube_l1.msh\"]," \
                     " \"lod\": {\"mode\": \"adaptive\", \"level\": 0, \"max_level\": 1, \"split\": 0.005, \"merge\": 0.0025}"
/* forced finest (split 0) and the fixed finest level of the same two meshes */
#define LOD_FORCED "\"levels\": [\"../cube/cube_l0.msh\", \"../cube/cube_l1.msh\"]," \
                   " \"lod\": {\"mode\": \"adaptive\", \"level\": 0, \"max_level\": 1, \"split\": 0, \"merge\": 0}"
#define LOD_FIXED_TOP "\"levels\": [\"../cube/cube_l0.msh\", \"../cube/cube_l1.msh\"], \"lod\": {\"mode\": \"fixed\", \"level\": 1}"

/* the fixed test's scene with each body's levels and lod given: two blocks without gravity, the
 * right one glued on its far face, the left one free and pushed 2 cm by a box tool; `rest` ends
 * the scene (the contact key) */
static sq_world *squeeze_world(const char *left, const char *right, const char *rest, sq_scene **sc)
{
    sq_err e = {{0}};
    char text[6000];
    snprintf(text, sizeof text,
             "{\"name\": \"t\", \"gravity\": [0, 0, 0], \"frame_rate\": 50,"
             " \"bodies\": ["
             "  {\"name\": \"left\", %s, \"scale\": 0.2, \"offset\": [-0.201, 0, 0],"
             "   \"material\": {\"E\": 30000, \"nu\": 0.3, \"density\": 1000, \"damping\": {\"rayleigh_mass\": 4.0}},"
             "   \"elasticity\": \"corotational\", \"step_bound\": \"sharp\"},"
             "  {\"name\": \"right\", %s, \"scale\": 0.2, \"offset\": [0, 0, 0],"
             "   \"material\": {\"E\": 30000, \"nu\": 0.3, \"density\": 1000, \"damping\": {\"rayleigh_mass\": 4.0}},"
             "   \"elasticity\": \"corotational\", \"step_bound\": \"sharp\","
             "   \"fixed\": [{\"box\": [[0.199, -1, -1], [1, 1, 1]]}]}],"
             " \"tools\": [{\"id\": 1, \"name\": \"pusher\", \"shape\": \"box\", \"size\": [0.1, 0.3, 0.3],"
             "   \"keyframes\": [{\"t\": 0, \"pos\": [-0.255, 0.1, 0.1]}, {\"t\": 1, \"pos\": [-0.235, 0.1, 0.1]}]}]%s}",
             left, right, rest);
    *sc = sq_scene_parse(text, th_scenes_dir(), "t.json", &e);
    if (!*sc) {
        printf("    %s\n", e.msg);
        return NULL;
    }
    sq_world *w = sq_world_create(*sc, &e);
    if (!w)
        printf("    %s\n", e.msg);
    return w;
}

/* the fixed test's run and bars, with these bodies: 100 frames, over the last 20 (the tool at
 * rest) the mean contact forces equal and opposite within 1 % (by construction: every impulse
 * has its opposite, handed to an adaptive target's active nodes through the transpose of the
 * map, whose rows sum to 1), the deepest node of either inside the other under 1 % of the
 * 0.2 m edge (2 mm, the bar; the fixed pair measured 0.59 mm), no reset */
static void squeeze_bars(const char *left, const char *right, const char *label)
{
    sq_scene *sc = NULL;
    sq_world *w = squeeze_world(left, right, "", &sc);
    CHECK(w != NULL);
    if (!w) {
        sq_scene_free(sc);
        return;
    }
    double Fl[3] = {0}, Fr[3] = {0}, depth = 0;
    int nl = 0;
    for (int f = 0; f < 100; f++) {
        sq_world_step(w, 0);
        if (f >= 80) {
            double a[3], b[3];
            sq_body_contact_force(w->bodies[0], a, &nl, NULL);
            sq_body_contact_force(w->bodies[1], b, NULL, NULL);
            for (int c = 0; c < 3; c++) {
                Fl[c] += a[c] / 20;
                Fr[c] += b[c] / 20;
            }
            double dd = fmax(sq_body_contact_depth(w->bodies[0], w->bodies[1]),
                             sq_body_contact_depth(w->bodies[1], w->bodies[0]));
            depth = fmax(depth, dd);
        }
    }
    int al[SQ_MAX_LEVELS], ar[SQ_MAX_LEVELS];
    sq_body_active_nodes(w->bodies[0], al);
    sq_body_active_nodes(w->bodies[1], ar);
    printf("    %s: force on left %.4g %.4g %.4g N, on right %.4g %.4g %.4g N, deepest %.3g m, %d nodes;"
           " active left %d %d, right %d %d\n", label, Fl[0], Fl[1], Fl[2], Fr[0], Fr[1], Fr[2], depth, nl, al[0], al[1],
           ar[0], ar[1]);
    /* an adaptive body is in a mixed layout: coarse regions act through level 0 */
    CHECK(!strstr(left, "adaptive") || (al[0] > 0 && al[1] > 0));
    CHECK(!strstr(right, "adaptive") || (ar[0] > 0 && ar[1] > 0));
    CHECK(Fl[0] < -1); /* the right block pushes back on the left one */
    CHECK_NEAR(Fl[0], -Fr[0], 0.01 * fabs(Fr[0]));
    CHECK(depth < 0.01 * 0.2);
    CHECK(w->resets == 0);
    sq_world_destroy(w);
    sq_scene_free(sc);
}

/* two blocks squeezed without gravity: the right one glued on its far face, the left one free
 * and pushed 2 cm by a box tool: the contact forces on the two are equal and opposite within
 * 1 % (by construction: every impulse has its opposite), the right block pushes back, nothing
 * resets. Penetration: the bar, no node of one inside the other deeper than 1 % of the
 * 0.2 m edge (2 mm), over the last 20 frames (the tool at rest); measured 0.59 mm (0.29 %)
 * since a node found inside leaves by a position move (docs/physics.md section 13); with the
 * earlier exit at half the depth per step it was 2.13 mm (1.07 %) */
SQ_TEST(contact_two_bodies_squeezed_equal_and_opposite)
{
    squeeze_bars(LOD_FIXED1, LOD_FIXED1, "fixed against fixed");
}

SQ_TEST(contact_adaptive_bodies_squeezed_equal_and_opposite)
{
    squeeze_bars(LOD_ADAPTIVE, LOD_ADAPTIVE, "adaptive against adaptive");
}

SQ_TEST(contact_adaptive_and_fixed_squeezed_equal_and_opposite)
{
    squeeze_bars(LOD_ADAPTIVE, LOD_FIXED1, "adaptive pushed into fixed");
    squeeze_bars(LOD_FIXED1, LOD_ADAPTIVE, "fixed pushed into adaptive");
}

/* forced finest (split 0: every region at level 1 from the first frame, at level 1's step) for
 * both bodies equals the fixed finest pair: the node side runs the same passes in the same
 * order, and as a target each finest node stands for itself with weight 1 (the same arithmetic
 * as a fixed target's). Tolerances as lod_sharp_forced_finest_equals_fixed_finest: the
 * displacements to 1e-12 of the largest (they came out bitwise equal, 0); the contact forces to
 * 1e-9 (an adaptive target sums its reactions in the order of its unknowns, not of its nodes:
 * round-off) */
SQ_TEST(contact_adaptive_pair_forced_finest_equals_fixed_finest)
{
    sq_scene *sf = NULL, *sa = NULL;
    sq_world *wf = squeeze_world(LOD_FIXED_TOP, LOD_FIXED_TOP, "", &sf);
    sq_world *wa = squeeze_world(LOD_FORCED, LOD_FORCED, "", &sa);
    CHECK(wf && wa);
    if (wf && wa) {
        for (int f = 0; f < 60; f++) {
            sq_world_step(wf, 0);
            sq_world_step(wa, 0);
        }
        double dmax = 0, diff = 0, fmaxv = 0, fdiff = 0;
        for (int b = 0; b < 2; b++) {
            const sq_level *Lf = sq_body_level(wf->bodies[b], sq_body_sim_level(wf->bodies[b]));
            const sq_level *La = sq_body_level(wa->bodies[b], sq_body_sim_level(wa->bodies[b]));
            CHECK(Lf->model.n == 142 && La->model.n == 142);
            const double *df = Lf->state.d, *da = La->state.d;
            for (int i = 0; Lf->model.n == La->model.n && i < 3 * Lf->model.n; i++) {
                dmax = fmax(dmax, fabs(df[i]));
                diff = fmax(diff, fabs(df[i] - da[i]));
            }
            double Ff[3], Fa[3];
            sq_body_contact_force(wf->bodies[b], Ff, NULL, NULL);
            sq_body_contact_force(wa->bodies[b], Fa, NULL, NULL);
            for (int c = 0; c < 3; c++) {
                fmaxv = fmax(fmaxv, fabs(Ff[c]));
                fdiff = fmax(fdiff, fabs(Ff[c] - Fa[c]));
            }
        }
        int act[SQ_MAX_LEVELS];
        sq_body_active_nodes(wa->bodies[1], act);
        printf("    max |d| %.4g m, max diff %.3g m; largest force %.6g N, max diff %.3g N; active %d %d\n", dmax, diff,
               fmaxv, fdiff, act[0], act[1]);
        CHECK(act[0] == 0 && act[1] == 142); /* forced finest */
        CHECK(dmax > 0.01);                  /* pushed */
        CHECK(fmaxv > 1);                    /* in contact */
        CHECK(diff <= 1e-12 * dmax);
        CHECK(fdiff <= 1e-9 * fmaxv);
    }
    sq_world_destroy(wf);
    sq_world_destroy(wa);
    sq_scene_free(sf);
    sq_scene_free(sa);
}

/* a coarse adaptive block (level 0, split 0.01) pressed by a fixed one: the deformation the
 * contact causes refines the region in contact and leaves the glued far side coarse; with body
 * contact off the pushed block passes through it and nothing refines (the criterion sees the
 * contact, as under a tool). Counted over the finest surface nodes by the level active there:
 * those near the contact face (rest x < 0.05 m) against those near the glued face (x > 0.15) */
static void refined_near_far(const char *rest, int *near, int *far, int *level1)
{
    *near = *far = *level1 = -1;
    sq_scene *sc = NULL;
    sq_world *w = squeeze_world(LOD_FIXED1,
                                "\"levels\": [\"../cube/cube_l0.msh\", \"../cube/cube_l1.msh\"], \"lod\": {\"mode\":"
                                " \"adaptive\", \"level\": 0, \"max_level\": 1, \"split\": 0.01, \"merge\": 0.005}",
                                rest, &sc);
    CHECK(w != NULL);
    if (!w) {
        sq_scene_free(sc);
        return;
    }
    for (int f = 0; f < 50; f++)
        sq_world_step(w, 0);
    sq_body *b = w->bodies[1];
    const sq_mesh *m = sq_body_mesh(b, sq_body_sim_level(b));
    const unsigned char *lv = sq_body_node_level(b);
    *near = *far = 0;
    for (int k = 0; k < m->nsurf; k++) {
        const int i = m->surf_nodes[k];
        const double x = m->x[3 * i];
        *near += lv[i] == 1 && x < 0.05;
        *far += lv[i] == 1 && x > 0.15;
    }
    int act[SQ_MAX_LEVELS];
    sq_body_active_nodes(b, act);
    *level1 = act[1];
    CHECK(w->resets == 0);
    sq_world_destroy(w);
    sq_scene_free(sc);
}

SQ_TEST(contact_adaptive_region_pressed_by_a_body_refines)
{
    int near, far, l1, near_off, far_off, l1_off;
    refined_near_far("", &near, &far, &l1);
    refined_near_far(", \"contact\": {\"bodies\": false}", &near_off, &far_off, &l1_off);
    printf("    body contact on: %d level-1 active nodes, finest surface nodes at level 1 near the contact %d, near the"
           " glued face %d; off: %d, %d, %d\n", l1, near, far, l1_off, near_off, far_off);
    CHECK(l1 > 0);
    CHECK(near > 2 * far); /* the contact region, not the whole block */
    CHECK(l1_off == 0);    /* without contact nothing presses it */
}

/* a body starting inside another is refused at load naming both, adaptive bodies too (either
 * side); touching is fine */
SQ_TEST(contact_adaptive_body_starting_inside_another_is_refused)
{
    const char *body = "{\"name\": \"%s\", %s, \"scale\": 0.2, \"offset\": [%g, 0, 0],"
                       " \"material\": {\"E\": 30000, \"nu\": 0.3}, \"elasticity\": \"corotational\"}";
    const char *lods[3][2] = {{LOD_ADAPTIVE, LOD_ADAPTIVE}, {LOD_ADAPTIVE, LOD_FIXED1}, {LOD_FIXED1, LOD_ADAPTIVE}};
    for (int c = 0; c < 3; c++)
        for (int overlap = 0; overlap < 2; overlap++) {
            char a[600], b[600], text[1500];
            snprintf(a, sizeof a, body, "first", lods[c][0], 0.0);
            snprintf(b, sizeof b, body, "second", lods[c][1], overlap ? 0.1 : 0.2);
            snprintf(text, sizeof text, "{\"name\": \"t\", \"gravity\": [0, 0, 0], \"bodies\": [%s, %s]}", a, b);
            sq_err e = {{0}};
            sq_scene *sc = sq_scene_parse(text, th_scenes_dir(), "t.json", &e);
            if (overlap) {
                CHECK(sc == NULL);
                CHECK_CONTAINS(e.msg, "starts inside body");
                CHECK_CONTAINS(e.msg, "\"first\"");
                CHECK_CONTAINS(e.msg, "\"second\"");
            } else {
                CHECK(sc != NULL); /* touching faces */
            }
            sq_scene_free(sc);
        }
}

/* the map itself, on a cube of three levels (cube_l0..l2) pressed by a sphere into a mixed
 * layout and held there (80 frames): every row of a finest surface node sums to 1 (to round-off,
 * 1e-12: the momentum handed back through the transpose is the impulse) and names active nodes
 * only (or the anchor: a constrained ghost's share). The surface it makes from the active
 * nodes' displacements, P d, is close to the one the frame's push left (the target's geometry)
 * but not equal: the push reads a ring ghost as the ring's own combination of sources and a
 * split ghost as pulled from the finer level, a fixed point the one linear map does not follow
 * exactly; measured 2.7 % of the largest displacement here (0.78 mm of 28.5 mm), bar 5 % */
SQ_TEST(contact_adaptive_surface_map_rows)
{
    const char *text = "{\"name\": \"t\", \"gravity\": [0, 0, -9.81], \"frame_rate\": 50,"
                       " \"bodies\": [{\"name\": \"b\", \"levels\": [\"../cube/cube_l0.msh\", \"../cube/cube_l1.msh\","
                       " \"../cube/cube_l2.msh\"], \"scale\": 0.2, \"material\": {\"E\": 30000, \"nu\": 0.3, \"density\": 1000,"
                       " \"damping\": {\"rayleigh_mass\": 2.0}}, \"elasticity\": \"corotational\","
                       " \"fixed\": [{\"box\": [[-1, -1, -1], [2, 2, 0.001]]}],"
                       " \"lod\": {\"mode\": \"adaptive\", \"level\": 0, \"max_level\": 2, \"split\": 0.004, \"merge\": 0.001}}],"
                       " \"tools\": [{\"id\": 1, \"name\": \"p\", \"shape\": \"sphere\", \"radius\": 0.05,"
                       " \"keyframes\": [{\"t\": 0, \"pos\": [0.1, 0.1, 0.25]}, {\"t\": 0.3, \"pos\": [0.1, 0.1, 0.22]}]}]}";
    sq_err e = {{0}};
    sq_scene *sc = sq_scene_parse(text, th_scenes_dir(), "t.json", &e);
    CHECK(sc != NULL);
    if (!sc) {
        printf("    %s\n", e.msg);
        return;
    }
    sq_world *w = sq_world_create(sc, &e);
    CHECK(w != NULL);
    for (int f = 0; w && f < 80; f++)
        sq_world_step(w, 0);
    if (w) {
        sq_body *b = w->bodies[0];
        int act[SQ_MAX_LEVELS];
        sq_body_active_nodes(b, act);
        const int F = sq_body_sim_level(b);
        const sq_level *Lf = sq_body_level(b, F); /* flushed: every ghost as the push makes it */
        const sq_mesh *m = Lf->model.mesh;
        const sq_lod_surface_map *map = sq_lod_surface_map_get(b->lod);
        double worst = 0, dmax = 0, diff = 0;
        int bad = 0, maxrow = 0;
        for (int s = 0; s < m->nsurf; s++) {
            const int j = m->surf_nodes[s];
            double sum = 0, pd[3] = {0, 0, 0};
            maxrow = SQ_MAX(maxrow, map->start[j + 1] - map->start[j]);
            for (int q = map->start[j]; q < map->start[j + 1]; q++) {
                const int u = map->dof[q], k = map->level[u], i = map->node[u];
                sum += map->w[q];
                if (k < 0) /* the anchor: a constrained ghost's share */
                    continue;
                bad += !sq_lod_active(b->lod, k)[i];
                const sq_level *Lk = sq_body_level(b, k);
                for (int c = 0; c < 3; c++)
                    pd[c] += map->w[q] * Lk->state.d[3 * (size_t)i + c];
            }
            worst = fmax(worst, fabs(sum - 1));
            for (int c = 0; c < 3 && !Lf->model.fixed[j]; c++) {
                dmax = fmax(dmax, fabs(Lf->state.d[3 * (size_t)j + c]));
                diff = fmax(diff, fabs(pd[c] - Lf->state.d[3 * (size_t)j + c]));
            }
        }
        printf("    active %d %d %d; worst |row sum - 1| %.3g, %d bad entries, longest row %d; max |d| %.4g m,"
               " max |P d - d| %.3g m\n", act[0], act[1], act[2], worst, bad, maxrow, dmax, diff);
        CHECK(act[0] > 0 && act[1] + act[2] > 0); /* mixed */
        CHECK(dmax > 0.005);                     /* pressed */
        CHECK(worst < 1e-12);
        CHECK(bad == 0);
        CHECK(diff <= 0.05 * dmax);
    }
    sq_world_destroy(w);
    sq_scene_free(sc);
}
