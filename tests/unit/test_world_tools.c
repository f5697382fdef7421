/* test_world_tools.c - world-level consistency: level numbering as listed in the scene file,
 * grab capture at the activation pose (sq_tool.origin). */
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "scene/scene.h"
#include "sq_test.h"
#include "test_scene_helpers.h"

/* box meshes of 2, 3 and 4 cells per side on [0,1]^3, written once into the test tmpdir */
static const char *level_dir(void)
{
    static char dir[300];
    if (dir[0])
        return dir;
    snprintf(dir, sizeof dir, "%s/world-levels", sq_test_tmpdir());
    if (th_make_dir(dir))
        return dir;
    for (int i = 0; i < 3; i++) {
        char name[32];
        snprintf(name, sizeof name, "l%d.msh", i);
        th_write_box_msh(dir, name, 2 + i);
    }
    return dir;
}

SQ_TEST(world_surface_state_listed_levels)
{
    /* fixed at listed level 1 of three: the body loads that mesh alone (its level 0) */
    const char *json = "{\"bodies\": [{\"name\": \"cube\", \"levels\": [\"l0.msh\", \"l1.msh\", \"l2.msh\"], "
                       "\"material\": {\"E\": 1e5, \"nu\": 0.3}, \"fixed\": [{\"box\": [[-1,-1,-1],[2,2,0.01]]}], "
                       "\"lod\": {\"mode\": \"fixed\", \"level\": 1}}]}";
    sq_err e = {{0}};
    sq_scene *s = sq_scene_parse(json, level_dir(), "t.json", &e);
    CHECK(s != NULL);
    if (!s) {
        printf("    %s\n", e.msg);
        return;
    }
    sq_world *w = sq_world_create(s, &e);
    CHECK(w != NULL);
    if (w) {
        CHECK(sq_body_nlevels(w->bodies[0]) == 1);
        CHECK(sq_world_listed_level(w, 0, 0) == 1);
        sq_world_step(w, 0);
        const sq_mesh *m = sq_body_surface_mesh(w->bodies[0]);
        float *xyz = malloc(sizeof(float) * 3 * (size_t)m->nsurf);
        unsigned char *lev = malloc((size_t)m->nsurf);
        unsigned char *raw = malloc((size_t)m->nsurf);
        sq_world_surface_state(w, 0, xyz, lev);
        sq_body_surface_state(w->bodies[0], NULL, raw);
        int all1 = 1, raw0 = 1;
        for (int i = 0; i < m->nsurf; i++) {
            all1 &= lev[i] == 1;
            raw0 &= raw[i] == 0;
        }
        CHECK(all1); /* listed numbering */
        CHECK(raw0); /* the body's own (loaded) numbering stays as it was */
        free(xyz);
        free(lev);
        free(raw);
        sq_world_destroy(w);
    }
    sq_scene_free(s);
}

/* surface nodes of the body's surface mesh within r of p at rest */
static int count_near(const sq_mesh *m, const double p[3], double r)
{
    int n = 0;
    for (int s = 0; s < m->nsurf; s++) {
        const double *x = m->x + 3 * (size_t)m->surf_nodes[s];
        double d2 = 0;
        for (int c = 0; c < 3; c++)
            d2 += (x[c] - p[c]) * (x[c] - p[c]);
        n += d2 <= r * r;
    }
    return n;
}

SQ_TEST(world_grab_captures_at_activation_pose)
{
    sq_err e = {{0}};
    sq_scene *s = sq_scene_default(&e);
    CHECK(s != NULL);
    if (!s)
        return;
    sq_world *w = sq_world_create(s, &e);
    CHECK(w != NULL);
    if (!w) {
        sq_scene_free(s);
        return;
    }
    const sq_mesh *m = sq_body_surface_mesh(w->bodies[0]);
    /* activate on the top face centre, then move 0.3 m sideways and 0.1 m up before any
     * frame: the capture is around the activation point, not the moved pose */
    const double a[3] = {0.5, 0.5, 1.0}, d[3] = {0.3, 0.0, 0.1};
    sq_tool t = {.id = 4, .shape = SQ_TOOL_GRAB, .active = 1, .radius = 0.15};
    memcpy(t.pos, a, sizeof t.pos);
    CHECK(sq_world_set_tool(w, &t, &e) == 0);
    CHECK(w->tools[w->ntools - 1].has_origin == 1);
    for (int c = 0; c < 3; c++)
        t.pos[c] = a[c] + d[c];
    /* the client's message carries no origin: whatever is in it is ignored */
    t.origin[0] = 9;
    t.has_origin = 0;
    CHECK(sq_world_set_tool(w, &t, &e) == 0);
    const sq_tool *wt = &w->tools[w->ntools - 1];
    CHECK(wt->has_origin == 1 && wt->origin[0] == a[0] && wt->origin[2] == a[2]);
    sq_world_step(w, 0);

    int near_a = count_near(m, a, t.radius), near_moved = count_near(m, t.pos, t.radius);
    CHECK(near_a == 5); /* the centre node and its four neighbours 0.125 m away (8 cells) */
    CHECK(near_moved > 0); /* the moved pose would have captured other nodes */
    int k = w->ntools - 1;
    CHECK(w->feedback[0][k].nnodes == near_a);
    /* the node under the activation point follows pos - origin: held exactly (tolerance:
     * float-free double path, interpolation at a mesh node ~1e-12) */
    double u[3];
    memcpy(s->probes[0].point, a, sizeof a); /* the scene's probe, moved to that point */
    CHECK(sq_world_probe(w, 0, u) == 0);
    for (int c = 0; c < 3; c++)
        CHECK_NEAR(u[c], d[c], 1e-9);

    /* released and grabbed again on the side face x = 0 before the next frame (the body
     * never sees the tool inactive): a new capture there, at the new activation point */
    t.active = 0;
    CHECK(sq_world_set_tool(w, &t, &e) == 0);
    CHECK(w->tools[k].has_origin == 0);
    const double b[3] = {0.0, 0.5, 0.5}, db[3] = {-0.1, 0.0, 0.0};
    memcpy(t.pos, b, sizeof t.pos);
    t.active = 1;
    CHECK(sq_world_set_tool(w, &t, &e) == 0);
    for (int c = 0; c < 3; c++)
        t.pos[c] = b[c] + db[c];
    CHECK(sq_world_set_tool(w, &t, &e) == 0);
    /* the node's displacement at capture (the first pull moved it a little: < 1 cm, well
     * inside the 2.5 cm margin between the capture radius and the node spacings) */
    double u0[3];
    memcpy(s->probes[0].point, b, sizeof b);
    CHECK(sq_world_probe(w, 0, u0) == 0);
    sq_world_step(w, 0);
    CHECK(w->feedback[0][k].nnodes == count_near(m, b, t.radius));
    CHECK(sq_world_probe(w, 0, u) == 0);
    for (int c = 0; c < 3; c++)
        CHECK_NEAR(u[c], u0[c] + db[c], 1e-9);

    sq_world_destroy(w);
    sq_scene_free(s);
}

SQ_TEST(world_scripted_grab_origin_is_activating_keyframe)
{
    sq_tool_script sc;
    memset(&sc, 0, sizeof sc);
    sc.tool.id = 1;
    sc.tool.shape = SQ_TOOL_GRAB;
    sc.tool.radius = 0.1;
    sc.nkeys = 4;
    const double pos[4][3] = {{0, 0, 1}, {0, 0, 2}, {0, 0, 3}, {0, 0, 4}};
    const int active[4] = {0, 1, 1, 0};
    for (int i = 0; i < 4; i++) {
        sc.keys[i].t = i;
        sc.keys[i].active = active[i];
        memcpy(sc.keys[i].pos, pos[i], sizeof pos[i]);
    }
    sq_tool out;
    sq_tool_script_pose(&sc, 0.5, &out);
    CHECK(!out.active && !out.has_origin);
    /* between the 2nd and 3rd keyframes and at the 3rd: origin is the 2nd one's position */
    sq_tool_script_pose(&sc, 1.5, &out);
    CHECK(out.active && out.has_origin && out.origin[2] == 2 && out.pos[2] == 2.5);
    sq_tool_script_pose(&sc, 2.5, &out);
    CHECK(out.active && out.has_origin && out.origin[2] == 2);
    sq_tool_script_pose(&sc, 3.5, &out);
    CHECK(!out.active && !out.has_origin);
}

/* the shipped beam scene: front beam y in [-0.05, 0.05], back beam 0.3 m behind */
static sq_world *beam_world(sq_scene **sc)
{
    *sc = th_shipped_scene("beam");
    if (!*sc)
        return NULL;
    sq_err e = {{0}};
    sq_world *w = sq_world_create(*sc, &e);
    if (!w)
        printf("    %s\n", e.msg);
    return w;
}

/* nodes a grab at p (radius r) holds on each beam after one frame */
static void grab_beams(const double p[3], double r, int held[2])
{
    sq_scene *sc = NULL;
    sq_world *w = beam_world(&sc);
    CHECK(w != NULL);
    held[0] = held[1] = -1;
    if (w) {
        sq_tool t;
        memset(&t, 0, sizeof t);
        t.id = 1;
        t.shape = SQ_TOOL_GRAB;
        t.active = 1;
        t.radius = r;
        memcpy(t.pos, p, sizeof t.pos);
        sq_err e = {{0}};
        CHECK(sq_world_set_tool(w, &t, &e) == 0);
        sq_world_step(w, 0);
        /* lift it: the held nodes follow, so they are still held the next frame */
        t.pos[2] += 0.05;
        CHECK(sq_world_set_tool(w, &t, &e) == 0);
        sq_world_step(w, 0);
        for (int b = 0; b < 2; b++)
            held[b] = w->feedback[b][0].nnodes;
        sq_world_destroy(w);
    }
    sq_scene_free(sc);
}

SQ_TEST(world_grab_fallback_takes_only_the_body_hit)
{
    /* on the front beam's tip (top back edge), radius 0.1: direct capture on the front beam;
     * the back beam's nearest node is 0.2 m away, inside 3 radii, and must not be pulled */
    int held[2];
    const double tip[3] = {1.0, 0.05, 0.05};
    grab_beams(tip, 0.1, held);
    printf("    tip grab: front %d nodes, back %d nodes\n", held[0], held[1]);
    CHECK(held[0] > 0);
    CHECK(held[1] == 0);

    /* between the beams, 0.07 m from the front one and 0.13 m from the back one, radius
     * 0.05: no node within the radius, both within 3 radii: the fallback takes the nearest
     * node of the nearest body (the front beam) alone */
    const double gap[3] = {1.0, 0.12, 0.0};
    grab_beams(gap, 0.05, held);
    printf("    fallback grab: front %d nodes, back %d nodes\n", held[0], held[1]);
    CHECK(held[0] == 1);
    CHECK(held[1] == 0);
}
