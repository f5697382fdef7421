/* test_scene.c - scene files (validation errors, values, defaults), keyframes, worlds. */
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "scene/scene.h"
#include "sq_test.h"
#include "test_scene_helpers.h"

/* small box meshes written once into the test tmpdir: a.msh (2 cells per side, 27 nodes),
 * b.msh (3 cells, 64 nodes), c.msh (4 cells, 125 nodes), all spanning [0,1]^3, and a
 * truncated bad.msh */
static const char *mesh_dir(void)
{
    static char dir[300];
    if (dir[0])
        return dir;
    snprintf(dir, sizeof dir, "%s/scene-meshes", sq_test_tmpdir());
    if (th_make_dir(dir))
        return dir;
    static const int cells[] = {2, 3, 4};
    static const char *const names[] = {"a.msh", "b.msh", "c.msh"};
    for (int i = 0; i < 3; i++)
        th_write_box_msh(dir, names[i], cells[i]);
    char path[400];
    snprintf(path, sizeof path, "%s/bad.msh", dir);
    FILE *f = fopen(path, "w");
    if (f) {
        fputs("$MeshFormat\n2.2 0 8\n$EndMeshFormat\n$Nodes\n5\n1 0 0 0\n", f);
        fclose(f);
    }
    return dir;
}

static sq_scene *parse(const char *json, sq_err *e)
{
    memset(e, 0, sizeof *e);
    return sq_scene_parse(json, mesh_dir(), "t.json", e);
}

#define MAT "\"material\": {\"E\": 1e5, \"nu\": 0.3}"
#define BODY_KEYS "\"name\": \"cube\", \"levels\": [\"a.msh\", \"b.msh\"], " MAT
#define BODY "{" BODY_KEYS "}"
#define SCENE(bodies_extra) "{\"bodies\": [" bodies_extra "]}"

static const struct {
    const char *json;
    const char *expect; /* substring of the error */
} broken[] = {
    {"{\"bodies\": [", "t.json: line 1, column 13: invalid JSON"},
    {"{\"bodies\": []} x", "invalid JSON"},
    {"[]", "t.json: the top level is an array"},
    {" \n ", "t.json: empty; a scene is a JSON object"},
    {"\x7f\x01{", "t.json: line 1, column 1: invalid JSON near '??{'"},
    {"{\"bodies\": []}", "t.json: bodies: 0 bodies; give 1 to 8"},
    {"{\"name\": \"x\"}", "t.json: bodies: missing"},
    {"{\"bodyz\": [], \"bodies\": [" BODY "]}", "t.json: bodyz: unknown key"},
    {"{\"name\": 5, \"bodies\": [" BODY "]}", "t.json: name: expected a string, got a number"},
    {"{\"name\": \"a,b\", \"bodies\": [" BODY "]}", "t.json: name: \"a,b\" has the character ','"},
    {"{\"frame_rate\": 0, \"bodies\": [" BODY "]}", "t.json: frame_rate: 0 is out of range"},
    {"{\"frame_rate\": \"50\", \"bodies\": [" BODY "]}", "t.json: frame_rate: expected a number, got a string"},
    {"{\"duration\": -1, \"bodies\": [" BODY "]}", "t.json: duration: -1 is out of range"},
    {"{\"gravity\": [0, 0], \"bodies\": [" BODY "]}", "t.json: gravity: expected an array of 3 numbers"},
    {"{\"gravity\": [0, 0, 1e999], \"bodies\": [" BODY "]}", "t.json: gravity: element 2: not a finite number"},
    {"{\"gravity\": [0, \"0\", 0], \"bodies\": [" BODY "]}", "t.json: gravity: element 1: expected a number"},
    {"{\"bodies\": [" BODY "], \"bodies\": [" BODY "]}", "t.json: bodies: key given twice"},
    {SCENE("5"), "t.json: bodies[0]: expected an object, got a number"},
    {SCENE("{\"name\": \"cube\", " MAT "}"), "t.json: bodies[0].levels: missing"},
    {SCENE("{\"levels\": \"a.msh\", " MAT "}"), "t.json: bodies[0].levels: expected an array, got a string"},
    {SCENE("{\"levels\": [], " MAT "}"), "t.json: bodies[0].levels: 0 levels"},
    {SCENE("{\"levels\": [\"a.msh\", 3], " MAT "}"), "t.json: bodies[0].levels[1]: expected a mesh file path"},
    {SCENE("{\"levels\": [\"a.msh\", \"nope.msh\"], " MAT "}"),
     "t.json: bodies[0].levels[1]: mesh file \"nope.msh\""},
    {SCENE("{\"levels\": [\"bad.msh\"], " MAT "}"), "t.json: bodies[0].levels[0]: "},
    {SCENE("{\"levels\": [\"a.msh\"]}"), "t.json: bodies[0].material: missing"},
    {SCENE("{\"levels\": [\"a.msh\"], \"material\": {}}"), "t.json: bodies[0].material: no stiffness given"},
    {SCENE("{\"levels\": [\"a.msh\"], \"material\": {\"E\": 1e5, \"nu\": 0.7}}"),
     "t.json: bodies[0].material.nu: 0.7 is out of range; use 0 <= nu < 0.5"},
    {SCENE("{\"levels\": [\"a.msh\"], \"material\": {\"E\": 1e5, \"nu\": 0.5}}"),
     "t.json: bodies[0].material.nu: 0.5 is out of range"},
    {SCENE("{\"levels\": [\"a.msh\"], \"material\": {\"E\": -5, \"nu\": 0.3}}"),
     "t.json: bodies[0].material.E: -5 is out of range"},
    {SCENE("{\"levels\": [\"a.msh\"], \"material\": {\"E\": 1e5}}"), "t.json: bodies[0].material.nu: missing"},
    {SCENE("{\"levels\": [\"a.msh\"], \"material\": {\"E\": 1e5, \"nu\": 0.3, \"mu\": 4}}"),
     "t.json: bodies[0].material: both E/nu and lambda/mu given"},
    {SCENE("{\"levels\": [\"a.msh\"], \"material\": {\"lambda\": 1e5, \"mu\": 0}}"),
     "t.json: bodies[0].material.mu: 0 is out of range"},
    {SCENE("{\"levels\": [\"a.msh\"], \"material\": {\"lambda\": -1, \"mu\": 4e4}}"),
     "t.json: bodies[0].material.lambda: -1 is out of range"},
    {SCENE("{\"levels\": [\"a.msh\"], \"material\": {\"E\": 1e5, \"nu\": 0.3, \"density\": 0}}"),
     "t.json: bodies[0].material.density: 0 is out of range"},
    {SCENE("{\"levels\": [\"a.msh\"], \"material\": {\"E\": 1e5, \"nu\": 0.3, \"Density\": 1}}"),
     "t.json: bodies[0].material.Density: unknown key"},
    {SCENE("{\"levels\": [\"a.msh\"], \"material\": {\"E\": 1e5, \"nu\": 0.3, \"damping\": {\"alpha\": 1}}}"),
     "t.json: bodies[0].material.damping.alpha: unknown key"},
    {SCENE("{\"levels\": [\"a.msh\"], \"material\": {\"E\": 1e5, \"nu\": 0.3, \"damping\": {\"rayleigh_mass\": -1}}}"),
     "t.json: bodies[0].material.damping.rayleigh_mass: -1 is out of range"},
    {SCENE("{\"levels\": [\"a.msh\"], \"material\": {\"E\": 1e5, \"nu\": 0.3, \"damping\": "
           "{\"rayleigh_stiffness\": 0.001, \"phi\": 2}}}"),
     "t.json: bodies[0].material.damping: rayleigh_stiffness and phi/psi both given"},
    {SCENE("{\"levels\": [\"a.msh\"], \"material\": {\"E\": 1e5, \"nu\": 0.3, \"damping\": 0.5}}"),
     "t.json: bodies[0].material.damping: expected an object, got a number"},
    {SCENE("{" BODY_KEYS ", \"operator\": \"linear\"}"), "t.json: bodies[0].operator: \"linear\" is not an operator"},
    {SCENE("{" BODY_KEYS ", \"operator\": 1}"), "t.json: bodies[0].operator: expected \"fem\" or \"paper\""},
    {SCENE("{" BODY_KEYS ", \"fixed\": {\"box\": [[0,0,0],[1,1,1]]}}"), "t.json: bodies[0].fixed: expected an array"},
    {SCENE("{" BODY_KEYS ", \"fixed\": [{\"box\": [[0,0,1],[1,1,0]]}]}"),
     "t.json: bodies[0].fixed[0].box: min corner above max corner on axis z"},
    {SCENE("{" BODY_KEYS ", \"fixed\": [{\"box\": [[0,0,0]]}]}"), "t.json: bodies[0].fixed[0].box: expected [[x0"},
    {SCENE("{" BODY_KEYS ", \"fixed\": [{\"box\": [[0,0,0],[1,1]]}]}"),
     "t.json: bodies[0].fixed[0].box[1]: expected an array of 3 numbers"},
    {SCENE("{" BODY_KEYS ", \"fixed\": [{}]}"), "t.json: bodies[0].fixed[0]: no region; give exactly one"},
    {SCENE("{" BODY_KEYS ", \"fixed\": [{\"halfspace\": {\"point\": [0,0,0], \"normal\": [0,0,0]}}]}"),
     "t.json: bodies[0].fixed[0].halfspace.normal: zero"},
    {SCENE("{" BODY_KEYS ", \"fixed\": [{\"halfspace\": {\"point\": [0,0,0]}}]}"),
     "t.json: bodies[0].fixed[0].halfspace: missing \"normal\""},
    {SCENE("{" BODY_KEYS ", \"fixed\": [{\"box\": [[0,0,0],[1,1,0]], \"axes\": \"xq\"}]}"),
     "t.json: bodies[0].fixed[0].axes: \"xq\" is not a set of axes"},
    {SCENE("{" BODY_KEYS ", \"fixed\": [{\"box\": [[0,0,0],[1,1,0]], \"axes\": \"xx\"}]}"),
     "t.json: bodies[0].fixed[0].axes"},
    {SCENE("{" BODY_KEYS ", \"fixed\": [{\"box\": [[5,5,5],[6,6,6]]}]}"),
     "t.json: bodies[0].fixed[0]: selects no node of levels[1]"},
    {SCENE("{" BODY_KEYS ", \"lod\": {\"mode\": \"auto\"}}"), "t.json: bodies[0].lod.mode: \"auto\" is not a mode"},
    {SCENE("{" BODY_KEYS ", \"lod\": {\"level\": 5}}"), "t.json: bodies[0].lod.level: 5 is out of range"},
    {SCENE("{" BODY_KEYS ", \"lod\": {\"level\": 0.5}}"), "t.json: bodies[0].lod.level: 0.5 is not an integer"},
    {SCENE("{" BODY_KEYS ", \"lod\": {\"max_level\": 2}}"), "t.json: bodies[0].lod.max_level: 2 is out of range"},
    {SCENE("{" BODY_KEYS ", \"lod\": {\"split\": 0.01, \"merge\": 0.02}}"),
     "t.json: bodies[0].lod.merge: 0.02 is not below split"},
    {SCENE("{" BODY_KEYS ", \"lod\": {\"split\": -1}}"), "t.json: bodies[0].lod.split: -1 is out of range"},
    {SCENE("{" BODY_KEYS ", \"lod\": {\"split\": \"big\"}}"), "t.json: bodies[0].lod.split: \"big\" is not a threshold"},
    {SCENE("{" BODY_KEYS ", \"lod\": {\"budget\": 1.5}}"), "t.json: bodies[0].lod.budget: 1.5 is out of range"},
    {SCENE("{" BODY_KEYS ", \"lod\": {\"max_node_updates\": -3}}"), "t.json: bodies[0].lod.max_node_updates"},
    {SCENE("{" BODY_KEYS ", \"lod\": {\"adapt_every\": 0}}"), "t.json: bodies[0].lod.adapt_every: 0 is out of range"},
    {SCENE("{" BODY_KEYS ", \"lod\": {\"adapt_every\": 1.5}}"), "t.json: bodies[0].lod.adapt_every: 1.5 is not an integer"},
    {SCENE("{" BODY_KEYS ", \"lod\": {\"adapt_every\": 1001}}"), "t.json: bodies[0].lod.adapt_every: 1001 is out of range"},
    {SCENE("{" BODY_KEYS ", \"lod\": {\"levels\": 2}}"), "t.json: bodies[0].lod.levels: unknown key"},
    {SCENE("{" BODY_KEYS ", \"offset\": [0, 1]}"), "t.json: bodies[0].offset: expected an array of 3 numbers"},
    {SCENE("{" BODY_KEYS ", \"step_fraction\": 2}"), "t.json: bodies[0].step_fraction: 2 is out of range"},
    {SCENE("{\"levels\": [\"b.msh\", \"a.msh\"], " MAT ", \"lod\": {\"mode\": \"adaptive\"}}"),
     "t.json: bodies[0].levels[1]: 27 nodes, not more than the previous level's 64"},
    {SCENE(BODY ", " BODY), "t.json: bodies[1].name: \"cube\" is already the name of bodies[0]"},
    {SCENE("{\"name\": \"my cube\", \"levels\": [\"a.msh\"], " MAT "}"), "t.json: bodies[0].name"},
    {"{\"bodies\": [" BODY "], \"tools\": {}}", "t.json: tools: expected an array, got an object"},
    {"{\"bodies\": [" BODY "], \"tools\": [{\"shape\": \"cone\", \"radius\": 0.1, \"keyframes\": "
     "[{\"t\": 0, \"pos\": [0,0,2]}]}]}",
     "t.json: tools[0].shape: \"cone\" is not a shape"},
    {"{\"bodies\": [" BODY "], \"tools\": [{\"radius\": 0.1, \"keyframes\": [{\"t\": 0, \"pos\": [0,0,2]}]}]}",
     "t.json: tools[0].shape: missing"},
    {"{\"bodies\": [" BODY "], \"tools\": [{\"shape\": \"sphere\", \"keyframes\": [{\"t\": 0, \"pos\": [0,0,2]}]}]}",
     "t.json: tools[0].radius: missing"},
    {"{\"bodies\": [" BODY "], \"tools\": [{\"shape\": \"sphere\", \"radius\": -0.1, \"keyframes\": "
     "[{\"t\": 0, \"pos\": [0,0,2]}]}]}",
     "t.json: tools[0].radius: -0.1 is out of range"},
    {"{\"bodies\": [" BODY "], \"tools\": [{\"shape\": \"box\", \"radius\": 0.1, \"keyframes\": "
     "[{\"t\": 0, \"pos\": [0,0,2]}]}]}",
     "t.json: tools[0].radius: a box tool has no radius"},
    {"{\"bodies\": [" BODY "], \"tools\": [{\"shape\": \"box\", \"size\": [0.1, 0, 0.1], \"keyframes\": "
     "[{\"t\": 0, \"pos\": [0,0,2]}]}]}",
     "t.json: tools[0].size: 0 on axis y is out of range"},
    {"{\"bodies\": [" BODY "], \"tools\": [{\"shape\": \"sphere\", \"radius\": 0.1}]}",
     "t.json: tools[0].keyframes: missing"},
    {"{\"bodies\": [" BODY "], \"tools\": [{\"shape\": \"sphere\", \"radius\": 0.1, \"keyframes\": []}]}",
     "t.json: tools[0].keyframes: 0 keyframes"},
    {"{\"bodies\": [" BODY "], \"tools\": [{\"shape\": \"sphere\", \"radius\": 0.1, \"keyframes\": "
     "[{\"t\": 0, \"pos\": [0,0,2]}, {\"t\": 0, \"pos\": [0,0,1]}]}]}",
     "t.json: tools[0].keyframes[1].t: 0 is not after the previous keyframe"},
    {"{\"bodies\": [" BODY "], \"tools\": [{\"shape\": \"sphere\", \"radius\": 0.1, \"keyframes\": "
     "[{\"t\": -1, \"pos\": [0,0,2]}]}]}",
     "t.json: tools[0].keyframes[0].t: -1 is negative"},
    {"{\"bodies\": [" BODY "], \"tools\": [{\"shape\": \"sphere\", \"radius\": 0.1, \"keyframes\": [{\"t\": 0}]}]}",
     "t.json: tools[0].keyframes[0].pos: missing"},
    {"{\"bodies\": [" BODY "], \"tools\": [{\"shape\": \"sphere\", \"radius\": 0.1, \"keyframes\": "
     "[{\"t\": 0, \"pos\": [0,0,2], \"active\": \"yes\"}]}]}",
     "t.json: tools[0].keyframes[0].active: expected true or false"},
    {"{\"bodies\": [" BODY "], \"tools\": [{\"shape\": \"sphere\", \"radius\": 0.1, \"keyframes\": "
     "[{\"t\": 0, \"pos\": [0,0,2], \"speed\": 1}]}]}",
     "t.json: tools[0].keyframes[0].speed: unknown key"},
    {"{\"bodies\": [" BODY "], \"tools\": [{\"id\": 3, \"shape\": \"grab\", \"radius\": 0.1, \"keyframes\": "
     "[{\"t\": 0, \"pos\": [0,0,2]}]}, {\"id\": 3, \"shape\": \"grab\", \"radius\": 0.1, \"keyframes\": "
     "[{\"t\": 0, \"pos\": [0,0,2]}]}]}",
     "t.json: tools[1].id: 3 is already the id of tools[0]"},
    {"{\"bodies\": [" BODY "], \"probes\": [{\"body\": \"liver\", \"point\": [0.5, 0.5, 0.5]}]}",
     "t.json: probes[0].body: \"liver\" is not a body"},
    {"{\"bodies\": [" BODY "], \"probes\": [{\"point\": [5, 5, 5]}]}",
     "t.json: probes[0].point: [5, 5, 5] is outside body \"cube\""},
    {"{\"bodies\": [" BODY "], \"probes\": [{\"name\": \"p\"}]}", "t.json: probes[0].point: missing"},
    {"{\"bodies\": [" BODY "], \"haptic\": {\"focus\": 101}}", "t.json: haptic.focus: 101 is out of range"},
    {"{\"bodies\": [" BODY "], \"haptic\": {\"device_mass\": 0}}", "t.json: haptic.device_mass: 0 is out of range"},
    {"{\"bodies\": [" BODY "], \"haptic\": {\"stiffness\": -1}}", "t.json: haptic.stiffness: -1 is out of range"},
    {"{\"bodies\": [" BODY "], \"haptic\": {\"spring\": 1}}", "t.json: haptic.spring: unknown key"},
    {"{\"bodies\": [" BODY "], \"haptic\": [1]}", "t.json: haptic"},
    {"{\"bodies\": [" BODY "], \"probes\": [{\"name\": \"p\", \"point\": [1,1,1]}, "
     "{\"name\": \"p\", \"point\": [1,1,1]}]}",
     "t.json: probes[1].name: \"p\" is already the name of probes[0]"},
};

SQ_TEST(scene_broken_table_names_json_path)
{
    for (size_t i = 0; i < SQ_COUNTOF(broken); i++) {
        sq_err e;
        sq_scene *s = parse(broken[i].json, &e);
        if (s) {
            printf("    broken[%zu] parsed without error: %s\n", i, broken[i].json);
            CHECK(s == NULL);
            sq_scene_free(s);
            continue;
        }
        if (!strstr(e.msg, broken[i].expect))
            printf("    broken[%zu]: %s\n", i, broken[i].json);
        CHECK_CONTAINS(e.msg, broken[i].expect);
        /* every message says what to do (a "; ..." or ": ..." advice part after the path) */
        if (getenv("SQ_SHOW_ERRORS"))
            printf("    %s\n", e.msg);
        CHECK(strchr(e.msg, ';') != NULL || strstr(e.msg, "cannot") || strstr(e.msg, "line"));
    }
}

SQ_TEST(scene_valid_full_values)
{
    const char *json =
        "{\"name\": \"full\", \"description\": \"every key\", \"gravity\": [0, -1, -9], \"frame_rate\": 40,"
        " \"duration\": 3.5,"
        " \"bodies\": [{\"name\": \"cube\", \"levels\": [\"a.msh\", \"b.msh\", \"c.msh\"],"
        "   \"material\": {\"lambda\": 100000, \"mu\": 40000, \"density\": 900,"
        "                  \"damping\": {\"rayleigh_mass\": 0.25, \"phi\": 3, \"psi\": 4}},"
        "   \"operator\": \"paper\","
        "   \"fixed\": [{\"box\": [[-1, -1, -1], [2, 2, 0.001]]},"
        "             {\"halfspace\": {\"point\": [0, 0, 0], \"normal\": [-2, 0, 0]}, \"axes\": \"x\"}],"
        "   \"lod\": {\"mode\": \"adaptive\", \"level\": 0, \"split\": 0.02, \"merge\": 0.01, \"max_level\": 1,"
        "            \"budget\": 0.8, \"max_node_updates\": 100000, \"adapt_every\": 3},"
        "   \"step_fraction\": 0.5}],"
        " \"tools\": [{\"id\": 7, \"name\": \"finger\", \"shape\": \"box\", \"size\": [0.2, 0.4, 0.6],"
        "   \"keyframes\": [{\"t\": 0.5, \"pos\": [0.5, 0.5, 1.2], \"active\": true},"
        "                   {\"t\": 1.5, \"pos\": [0.5, 0.5, 0.8]}]}],"
        " \"probes\": [{\"name\": \"top\", \"body\": \"cube\", \"point\": [0.5, 0.5, 1]}]}";
    sq_err e;
    sq_scene *s = parse(json, &e);
    CHECK(s != NULL);
    if (!s) {
        printf("    %s\n", e.msg);
        return;
    }
    CHECK(!strcmp(s->name, "full"));
    CHECK(!strcmp(s->description, "every key"));
    CHECK(s->gravity[0] == 0 && s->gravity[1] == -1 && s->gravity[2] == -9);
    CHECK(s->frame_rate == 40 && s->duration == 3.5);
    CHECK(s->nbodies == 1 && !strcmp(s->body_names[0], "cube"));
    const sq_body_def *d = &s->bodies[0];
    CHECK(!strcmp(d->name, "cube"));
    CHECK(d->material.lambda == 100000 && d->material.mu == 40000 && d->material.density == 900);
    CHECK(d->material.rayleigh_mass == 0.25 && d->material.rayleigh_stiffness == 0);
    CHECK(d->material.use_viscosity == 1 && d->material.phi == 3 && d->material.psi == 4);
    CHECK(d->op == SQ_OPERATOR_PAPER);
    CHECK(d->nconstraints == 2);
    CHECK(d->constraints[0].kind == SQ_REGION_BOX && d->constraints[0].axes == 7);
    CHECK(d->constraints[0].b[2] == 0.001);
    CHECK(d->constraints[1].kind == SQ_REGION_HALFSPACE && d->constraints[1].axes == 1);
    CHECK_NEAR(d->constraints[1].b[0], -1.0, 1e-15); /* normal normalised */
    /* adaptive with max_level 1: levels 0..1 loaded, level 2 (c.msh) not */
    CHECK(d->lod.mode == SQ_LOD_ADAPTIVE && d->lod.level == 0 && d->lod.max_level == 1);
    CHECK(d->nlevels == 2 && s->nlisted[0] == 3);
    CHECK(d->levels[0]->nnodes == 27 && d->levels[1]->nnodes == 64);
    CHECK(s->meshes[0][2] == NULL);
    CHECK(d->lod.split == 0.02 && d->lod.merge == 0.01 && d->lod.budget == 0.8);
    CHECK(d->lod.max_node_updates == 100000 && d->lod.adapt_every == 3);
    CHECK(d->step_fraction == 0.5);
    CHECK_NEAR(d->frame_dt, 1.0 / 40, 1e-15);
    CHECK(d->gravity[1] == -1 && d->gravity[2] == -9);
    CHECK(s->ntools == 1);
    const sq_tool_script *t = &s->tools[0];
    CHECK(t->tool.id == 7 && !strcmp(t->name, "finger") && t->tool.shape == SQ_TOOL_BOX);
    CHECK(t->tool.half[0] == 0.1 && t->tool.half[1] == 0.2 && t->tool.half[2] == 0.3);
    CHECK(t->nkeys == 2 && t->keys[1].t == 1.5 && t->keys[1].active == 1 && t->keys[1].pos[2] == 0.8);
    CHECK(s->nprobes == 1 && !strcmp(s->probes[0].name, "top") && s->probes[0].body == 0);
    CHECK(s->probes[0].point[2] == 1);
    sq_scene_free(s);
}

SQ_TEST(scene_defaults_of_a_minimal_scene)
{
    sq_err e;
    sq_scene *s = parse("{\"bodies\": [{\"levels\": [\"a.msh\", \"b.msh\"], " MAT "}],"
                        " \"probes\": [{\"point\": [1, 1, 1]}]}",
                        &e);
    CHECK(s != NULL);
    if (!s) {
        printf("    %s\n", e.msg);
        return;
    }
    const sq_body_def def0 = sq_body_def_default();
    CHECK(s->gravity[0] == 0 && s->gravity[1] == 0 && s->gravity[2] == -9.81);
    CHECK(s->frame_rate == 50 && s->duration == 2);
    CHECK(!strcmp(s->body_names[0], "body0"));
    const sq_body_def *d = &s->bodies[0];
    CHECK(d->op == SQ_OPERATOR_FEM && d->nconstraints == 0);
    CHECK(d->material.density == 1000);
    CHECK(d->material.rayleigh_mass == def0.material.rayleigh_mass);
    CHECK(d->material.rayleigh_stiffness == def0.material.rayleigh_stiffness);
    CHECK(d->material.use_viscosity == 0);
    /* fixed mode defaults to the finest listed level and loads only that one */
    CHECK(d->lod.mode == SQ_LOD_FIXED && d->nlevels == 1 && d->lod.level == 0);
    CHECK(d->levels[0]->nnodes == 64 && s->level_index[0][0] == 1 && s->meshes[0][1] == NULL);
    CHECK(d->lod.split == def0.lod.split && d->lod.budget == def0.lod.budget);
    CHECK(d->lod.adapt_every == 1);
    CHECK(d->step_fraction == 0.9);
    CHECK(s->ntools == 0 && s->nprobes == 1 && !strcmp(s->probes[0].name, "probe0"));
    CHECK(s->haptic.given == 0); /* a channel opened on it takes its own defaults */
    sq_scene_free(s);

    /* "haptic": the values given, and only those, marked given (0 is a value) */
    s = parse("{\"bodies\": [{\"levels\": [\"a.msh\", \"b.msh\"], " MAT "}],"
              " \"haptic\": {\"stiffness\": 0, \"focus\": 2.5}}", &e);
    CHECK(s && s->haptic.given == (SQ_SCENE_HAPTIC_STIFFNESS | SQ_SCENE_HAPTIC_FOCUS) &&
          s->haptic.stiffness == 0 && s->haptic.focus == 2.5);
    sq_scene_free(s);

    /* fixed at an explicit coarse level loads that level only */
    s = parse(SCENE("{" BODY_KEYS ", \"lod\": {\"level\": 0}}"), &e);
    CHECK(s && s->bodies[0].nlevels == 1 && s->bodies[0].levels[0]->nnodes == 27 && s->level_index[0][0] == 0);
    sq_scene_free(s);
    /* "inf" split: never split */
    s = parse(SCENE("{" BODY_KEYS ", \"lod\": {\"mode\": \"adaptive\", \"split\": \"inf\"}}"), &e);
    CHECK(s && isinf(s->bodies[0].lod.split) && s->bodies[0].nlevels == 2);
    sq_scene_free(s);
}

SQ_TEST(scene_E_nu_and_lame_give_the_same_material)
{
    /* E, nu of the paper's cube: mu = 40 kPa, lambda = 100 kPa exactly when
     * E = mu (3 lambda + 2 mu) / (lambda + mu), nu = lambda / (2 (lambda + mu)) */
    double mu = 40000, lambda = 100000;
    double E = mu * (3 * lambda + 2 * mu) / (lambda + mu), nu = lambda / (2 * (lambda + mu));
    char a[512], b[512];
    snprintf(a, sizeof a, SCENE("{\"levels\": [\"a.msh\"], \"material\": {\"E\": %.17g, \"nu\": %.17g}}"), E, nu);
    snprintf(b, sizeof b, SCENE("{\"levels\": [\"a.msh\"], \"material\": {\"lambda\": 100000, \"mu\": 40000}}"));
    sq_err e;
    sq_scene *sa = parse(a, &e), *sb = parse(b, &e);
    CHECK(sa && sb);
    if (sa && sb) {
        /* round trip through E, nu loses only a few ulps: relative 1e-12 */
        CHECK_NEAR(sa->bodies[0].material.mu, sb->bodies[0].material.mu, 1e-12 * mu);
        CHECK_NEAR(sa->bodies[0].material.lambda, sb->bodies[0].material.lambda, 1e-12 * lambda);
        CHECK(sa->bodies[0].material.density == sb->bodies[0].material.density);
    }
    sq_scene_free(sa);
    sq_scene_free(sb);
}

SQ_TEST(scene_keyframe_interpolation)
{
    sq_tool_script s;
    memset(&s, 0, sizeof s);
    s.tool.shape = SQ_TOOL_SPHERE;
    s.tool.radius = 0.1;
    s.nkeys = 3;
    s.keys[0] = (sq_keyframe){1.0, {0, 0, 2}, 1};
    s.keys[1] = (sq_keyframe){2.0, {1, 0, 1}, 0};
    s.keys[2] = (sq_keyframe){4.0, {1, 2, 1}, 1};
    sq_tool t;
    /* before the first keyframe: held at its position, inactive */
    sq_tool_script_pose(&s, 0.5, &t);
    CHECK(t.pos[2] == 2 && t.active == 0 && t.radius == 0.1);
    /* at a keyframe: its position and active flag */
    sq_tool_script_pose(&s, 1.0, &t);
    CHECK(t.pos[2] == 2 && t.active == 1);
    /* linear in between (exact for these binary fractions); active of the last key at or before t */
    sq_tool_script_pose(&s, 1.25, &t);
    CHECK(t.pos[0] == 0.25 && t.pos[2] == 1.75 && t.active == 1);
    sq_tool_script_pose(&s, 2.0, &t);
    CHECK(t.pos[0] == 1 && t.pos[2] == 1 && t.active == 0);
    sq_tool_script_pose(&s, 3.0, &t);
    CHECK(t.pos[1] == 1 && t.active == 0);
    /* after the last: held, last active */
    sq_tool_script_pose(&s, 9.0, &t);
    CHECK(t.pos[1] == 2 && t.active == 1);
}

SQ_TEST(scene_default_is_the_papers_cube)
{
    sq_err e = {{0}};
    sq_scene *s = sq_scene_default(&e);
    CHECK(s != NULL);
    if (!s)
        return;
    CHECK(!strcmp(s->path, "<default>") && s->nbodies == 1);
    const sq_body_def *d = &s->bodies[0];
    CHECK(d->material.mu == 40000 && d->material.lambda == 100000 && d->material.density == 1000);
    CHECK(d->nlevels == 3);
    CHECK(d->levels[0]->nnodes == 27 && d->levels[1]->nnodes == 125 && d->levels[2]->nnodes == 729);
    CHECK(s->gravity[2] == -9.81 && d->gravity[2] == -9.81);
    CHECK(s->nprobes == 1 && s->probes[0].point[0] == 1 && s->probes[0].point[2] == 1);
    CHECK(d->nconstraints == 1 && d->constraints[0].b[2] < 1e-3 && d->constraints[0].axes == 7);
    sq_scene_free(s);
}

SQ_TEST(scene_load_file_and_missing_file)
{
    sq_err e = {{0}};
    char path[512];
    snprintf(path, sizeof path, "%s/scenes/small-cube.json", sq_test_data());
    sq_scene *s = sq_scene_load(path, &e);
    CHECK(s != NULL);
    if (!s)
        printf("    %s\n", e.msg);
    else
        CHECK(s->nbodies == 1 && s->bodies[0].levels[0]->nnodes > 0);
    sq_scene_free(s);
    CHECK(sq_scene_load("/nonexistent/scene.json", &e) == NULL);
    CHECK_CONTAINS(e.msg, "/nonexistent/scene.json");
    CHECK(sq_scene_load(sq_test_data(), &e) == NULL);
    CHECK_CONTAINS(e.msg, "is a directory");
    /* a scene file whose mesh path is wrong names the file, the key and the resolved path */
    snprintf(path, sizeof path, "%s/scenes/bad-level-path.json", sq_test_data());
    CHECK(sq_scene_load(path, &e) == NULL);
    CHECK_CONTAINS(e.msg, "bad-level-path.json: bodies[0].levels[0]: mesh file");
    CHECK_CONTAINS(e.msg, "relative to the scene file");
}

/* a small poked, sagging cube: 27 then 64 nodes, sphere pressed on the top face */
static const char *poke_json =
    "{\"frame_rate\": 50, \"bodies\": [{\"name\": \"cube\", \"levels\": [\"a.msh\"],"
    " \"material\": {\"lambda\": 100000, \"mu\": 40000, \"damping\": {\"rayleigh_mass\": 1}},"
    " \"fixed\": [{\"box\": [[-1, -1, -1], [2, 2, 0.001]]}]}],"
    " \"tools\": [{\"id\": 1, \"shape\": \"sphere\", \"radius\": 0.3, \"keyframes\": ["
    "   {\"t\": 0, \"pos\": [0.5, 0.5, 1.4]}, {\"t\": 0.2, \"pos\": [0.5, 0.5, 1.15]},"
    "   {\"t\": 0.3, \"pos\": [0.5, 0.5, 1.4], \"active\": false}]}],"
    " \"probes\": [{\"name\": \"corner\", \"point\": [1, 1, 1]}]}";

SQ_TEST(world_steps_clock_tools_and_probe)
{
    sq_err e;
    sq_scene *s = parse(poke_json, &e);
    CHECK(s != NULL);
    if (!s) {
        printf("    %s\n", e.msg);
        return;
    }
    sq_world *w = sq_world_create(s, &e);
    CHECK(w != NULL);
    if (!w) {
        printf("    %s\n", e.msg);
        sq_scene_free(s);
        return;
    }
    CHECK(w->nbodies == 1 && w->ntools == 1 && w->tool_scripted[0] == 1);
    for (int i = 0; i < 10; i++)
        sq_world_step(w, 0);
    CHECK(w->frame == 10);
    CHECK_NEAR(w->time, 0.2, 1e-15);
    /* the scripted tool is at its t = 0.2 keyframe */
    CHECK_NEAR(w->tools[0].pos[2], 1.15, 1e-12);
    CHECK(w->tools[0].active == 1);
    CHECK(w->deadline_misses == 0);
    /* the sphere (bottom at z = 0.85) presses the top face: the body pushes it up */
    CHECK(w->feedback[0][0].id == 1 && w->feedback[0][0].nnodes > 0);
    CHECK(w->feedback[0][0].force[2] > 0);
    CHECK(w->profile[0].node_updates > 0);
    /* gravity sags the free corner (uz < 0); it moved by more than 1e-5 m after 0.2 s */
    double u[3];
    CHECK(sq_world_probe(w, 0, u) == 0);
    CHECK(u[2] < -1e-5);
    CHECK(sq_world_probe(w, 5, u) == -1);
    CHECK(sq_world_find_body(w, "cube") == 0 && sq_world_find_body(w, "liver") == -1);

    /* a live pose replaces the scripted tool of the same id and is not overwritten */
    sq_tool live = w->tools[0];
    live.pos[2] = 3;
    live.active = 0;
    CHECK(sq_world_set_tool(w, &live, &e) == 0);
    sq_world_step(w, 0);
    CHECK(w->tool_scripted[0] == 0 && w->tools[0].pos[2] == 3 && w->ntools == 1);
    /* a new id is added; invalid poses are refused with a reason */
    live.id = 9;
    CHECK(sq_world_set_tool(w, &live, &e) == 0 && w->ntools == 2);
    live.radius = -1;
    CHECK(sq_world_set_tool(w, &live, &e) == -1);
    CHECK_CONTAINS(e.msg, "radius");
    live.radius = 0.1;
    live.pos[0] = NAN;
    CHECK(sq_world_set_tool(w, &live, &e) == -1);
    CHECK_CONTAINS(e.msg, "position");
    for (int id = 10; id < 20; id++) {
        live.pos[0] = 0;
        live.id = id;
        sq_world_set_tool(w, &live, &e);
    }
    CHECK(w->ntools == SQ_MAX_TOOLS);
    CHECK_CONTAINS(e.msg, "maximum");

    /* a live budget counts frames whose compute time is above it (1 ns: every frame) */
    sq_world_step(w, 1e-9);
    CHECK(w->deadline_misses == 1);

    /* reset: clock, tools and state back to the start */
    sq_world_reset(w);
    CHECK(w->frame == 0 && w->time == 0 && w->ntools == 1 && w->tool_scripted[0] == 1);
    CHECK(w->deadline_misses == 0);
    CHECK(sq_world_probe(w, 0, u) == 0 && u[0] == 0 && u[1] == 0 && u[2] == 0);
    sq_world_destroy(w);
    sq_scene_free(s);
}

static uint64_t world_hash(const sq_world *w)
{
    uint64_t h = SQ_HASH_INIT;
    for (int b = 0; b < w->nbodies; b++)
        for (int k = 0; k < sq_body_nlevels(w->bodies[b]); k++) {
            const sq_mesh *m = sq_body_mesh(w->bodies[b], k);
            const double *d = sq_body_displacement(w->bodies[b], k), *v = sq_body_velocity(w->bodies[b], k);
            if (m && d && v) {
                h = sq_hash_bytes(h, d, sizeof(double) * 3 * (size_t)m->nnodes);
                h = sq_hash_bytes(h, v, sizeof(double) * 3 * (size_t)m->nnodes);
            }
        }
    return h;
}

/* the same poke on an adaptive body (levels a, b; splits under the tool) */
static const char *poke_adaptive_json =
    "{\"frame_rate\": 50, \"bodies\": [{\"name\": \"cube\", \"levels\": [\"a.msh\", \"b.msh\"],"
    " \"material\": {\"lambda\": 100000, \"mu\": 40000, \"damping\": {\"rayleigh_mass\": 1}},"
    " \"fixed\": [{\"box\": [[-1, -1, -1], [2, 2, 0.001]]}],"
    " \"lod\": {\"mode\": \"adaptive\", \"split\": 0.002, \"merge\": 0.001}}],"
    " \"tools\": [{\"id\": 1, \"shape\": \"sphere\", \"radius\": 0.3, \"keyframes\": ["
    "   {\"t\": 0, \"pos\": [0.5, 0.5, 1.4]}, {\"t\": 0.2, \"pos\": [0.5, 0.5, 1.15]},"
    "   {\"t\": 0.3, \"pos\": [0.5, 0.5, 1.4], \"active\": false}]}]}";

static void check_determinism(const char *json, int adaptive)
{
    sq_err e;
    sq_scene *s = parse(json, &e);
    CHECK(s != NULL);
    if (!s)
        return;
    sq_world *a = sq_world_create(s, &e), *b = sq_world_create(s, &e);
    CHECK(a && b);
    if (a && b) {
        uint64_t h0 = world_hash(a);
        int splits = 0;
        for (int i = 0; i < 20; i++) {
            sq_world_step(a, 0);
            sq_world_step(b, 0);
            splits += a->profile[0].splits;
            CHECK(a->profile[0].splits == b->profile[0].splits);
            CHECK(a->profile[0].node_updates == b->profile[0].node_updates);
        }
        /* the adaptive poke does split under the tool (so the test covers split/merge) */
        CHECK(adaptive ? splits > 0 : splits == 0);
        CHECK(world_hash(a) == world_hash(b));
        CHECK(world_hash(a) != h0); /* the state did change */
        /* a reset world replays the same bytes */
        uint64_t h20 = world_hash(a);
        sq_world_reset(b);
        for (int i = 0; i < 20; i++)
            sq_world_step(b, 0);
        CHECK(world_hash(b) == h20);
    }
    sq_world_destroy(a);
    sq_world_destroy(b);
    sq_scene_free(s);
}

SQ_TEST(world_determinism_two_worlds_identical_bytes)
{
    check_determinism(poke_json, 0);
}

SQ_TEST(world_determinism_adaptive_identical_bytes)
{
    check_determinism(poke_adaptive_json, 1);
}

SQ_TEST(world_create_reports_body_errors_with_scene_path)
{
    sq_err e;
    /* every node fixed: the engine refuses, the world names the scene and the body */
    sq_scene *s = parse(SCENE("{" BODY_KEYS ", \"fixed\": [{\"box\": [[-1,-1,-1],[2,2,2]]}]}"), &e);
    CHECK(s != NULL);
    if (!s)
        return;
    sq_world *w = sq_world_create(s, &e);
    CHECK(w == NULL);
    CHECK_CONTAINS(e.msg, "t.json: bodies[0] (\"cube\")");
    sq_world_destroy(w);
    memset(&e, 0, sizeof e);
    CHECK(sq_scene_check(s, &e) == -1);
    CHECK_CONTAINS(e.msg, "t.json: bodies[0] (\"cube\")");
    sq_scene_free(s);

    /* nearly incompressible: lambda overflows the material check, named by path */
    s = parse(SCENE("{\"levels\": [\"a.msh\"], \"material\": {\"E\": 1e308, \"nu\": 0.49}}"), &e);
    CHECK(s == NULL);
    CHECK_CONTAINS(e.msg, "t.json: bodies[0].material");
    sq_scene_free(s);

    /* a valid scene passes the engine check */
    s = parse(SCENE(BODY), &e);
    CHECK(s && sq_scene_check(s, &e) == 0);
    sq_scene_free(s);
}

SQ_TEST(world_two_bodies_probe_each)
{
    sq_err e;
    /* the same cube twice, one per operator; probes name their body */
    sq_scene *s = parse("{\"bodies\": [{\"name\": \"fem\", \"levels\": [\"a.msh\"], " MAT ","
                        "  \"fixed\": [{\"box\": [[-1,-1,-1],[2,2,0.001]]}]},"
                        " {\"name\": \"paper\", \"levels\": [\"a.msh\"], " MAT ", \"operator\": \"paper\","
                        "  \"offset\": [0, 2, 0], \"fixed\": [{\"box\": [[-1,1.5,-1],[2,3.5,0.001]]}]}],"
                        " \"probes\": [{\"name\": \"f\", \"body\": \"fem\", \"point\": [1,1,1]},"
                        "              {\"name\": \"p\", \"body\": \"paper\", \"point\": [1,3,1]}]}",
                        &e);
    CHECK(s != NULL);
    if (!s) {
        printf("    %s\n", e.msg);
        return;
    }
    CHECK(s->probes[0].body == 0 && s->probes[1].body == 1);
    /* the second body is moved 2 m along y: its mesh, regions and probe live there */
    CHECK(s->bodies[1].levels[0]->bbox_min[1] == 2 && s->bodies[1].levels[0]->bbox_max[1] == 3);
    CHECK(s->bodies[0].levels[0]->bbox_min[1] == 0);
    sq_world *w = sq_world_create(s, &e);
    CHECK(w && w->nbodies == 2);
    if (w) {
        for (int i = 0; i < 10; i++)
            sq_world_step(w, 0);
        CHECK(sq_world_find_body(w, "paper") == 1);
        double uf[3], up[3];
        CHECK(sq_world_probe(w, 0, uf) == 0 && sq_world_probe(w, 1, up) == 0);
        /* both sag; the operators differ on the free boundary, so the corners differ */
        CHECK(uf[2] < 0 && up[2] < 0);
        CHECK(uf[2] != up[2]);
        CHECK(w->profile[0].node_updates > 0 && w->profile[1].node_updates > 0);
    }
    sq_world_destroy(w);
    sq_scene_free(s);
}

SQ_TEST(scene_mutated_text_never_crashes)
{
    /* a valid scene with every section, mutated byte by byte with a fixed-seed generator:
     * every parse either succeeds or returns an error message naming the label */
    const char *base =
        "{\"name\": \"m\", \"gravity\": [0, 0, -9.81], \"frame_rate\": 50, \"bodies\": [{\"name\": \"cube\","
        " \"levels\": [\"a.msh\", \"b.msh\"], \"material\": {\"E\": 1e5, \"nu\": 0.3, \"density\": 1000,"
        " \"damping\": {\"rayleigh_mass\": 0.5}}, \"operator\": \"fem\","
        " \"fixed\": [{\"box\": [[-1, -1, -1], [2, 2, 0.001]], \"axes\": \"xyz\"}],"
        " \"lod\": {\"mode\": \"adaptive\", \"split\": 0.01, \"merge\": 0.005}}],"
        " \"tools\": [{\"id\": 1, \"shape\": \"sphere\", \"radius\": 0.2, \"keyframes\": ["
        " {\"t\": 0, \"pos\": [0.5, 0.5, 1.3]}, {\"t\": 1, \"pos\": [0.5, 0.5, 1.1], \"active\": false}]}],"
        " \"probes\": [{\"name\": \"c\", \"body\": \"cube\", \"point\": [1, 1, 1]}]}";
    static const char alphabet[] = "{}[]\":,0123456789.-e aznxyE\\";
    size_t n = strlen(base);
    char *buf = malloc(n + 8);
    unsigned long long x = 12345;
    int ok = 0, errors = 0;
    sq_err e;
    sq_scene *s0 = parse(base, &e);
    CHECK(s0 != NULL); /* the unmutated text is valid */
    sq_scene_free(s0);
    for (int iter = 0; iter < 400; iter++) {
        memcpy(buf, base, n + 1);
        int nmut = 1 + iter % 3;
        for (int k = 0; k < nmut; k++) {
            x = x * 6364136223846793005ULL + 1442695040888963407ULL;
            size_t pos = (size_t)(x >> 33) % n;
            int op = (int)((x >> 20) % 3);
            char c = alphabet[(x >> 8) % (sizeof alphabet - 1)];
            if (op == 0)
                buf[pos] = c;                                   /* replace */
            else if (op == 1)
                memmove(buf + pos, buf + pos + 1, n - pos);     /* delete */
            else
                buf[pos] = 0;                                   /* truncate */
        }
        sq_scene *s = parse(buf, &e);
        if (s) {
            ok++;
            sq_scene_free(s);
        } else {
            errors++;
            if (strncmp(e.msg, "t.json: ", 8) != 0) {
                printf("    unlabelled error for mutation %d: %s\n", iter, e.msg);
                CHECK(strncmp(e.msg, "t.json: ", 8) == 0);
            }
        }
    }
    CHECK(ok + errors == 400 && errors > 200);
    free(buf);
}

SQ_TEST(world_adaptive_split_extremes_reach_the_engine)
{
    /* "inf" never splits: only level 0 is active; 0 splits everything to the finest level */
    const char *fmt = "{\"bodies\": [{\"name\": \"cube\", \"levels\": [\"a.msh\", \"b.msh\"], " MAT ","
                      " \"fixed\": [{\"box\": [[-1,-1,-1],[2,2,0.001]]}],"
                      " \"lod\": {\"mode\": \"adaptive\", \"split\": %s}}]}";
    for (int k = 0; k < 2; k++) {
        char json[512];
        snprintf(json, sizeof json, fmt, k == 0 ? "\"inf\"" : "0");
        sq_err e;
        sq_scene *s = parse(json, &e);
        CHECK(s != NULL);
        sq_world *w = s ? sq_world_create(s, &e) : NULL;
        CHECK(w != NULL);
        if (!w) {
            printf("    %s\n", e.msg);
            sq_scene_free(s);
            continue;
        }
        for (int i = 0; i < 5; i++)
            sq_world_step(w, 0);
        const sq_frame_profile *p = &w->profile[0];
        if (k == 0)
            CHECK(p->active[0] == 27 && p->active[1] == 0);
        else
            CHECK(p->active[1] == 64);
        sq_world_destroy(w);
        sq_scene_free(s);
    }
}

/* a box of 2 cells per side with the given edge length written into the mesh dir */
static void write_sized_box(const char *name, double edge)
{
    const double size[3] = {edge, edge, edge}, origin[3] = {0, 0, 0};
    sq_err e = {{0}};
    sq_mesh *m = sq_mesh_box(2, 2, 2, size, origin, &e);
    char path[400];
    snprintf(path, sizeof path, "%s/%s", mesh_dir(), name);
    if (!m || sq_mesh_write_msh(m, path, &e))
        printf("    mesh setup failed: %s\n", e.msg);
    sq_mesh_free(m);
}

SQ_TEST(scene_scale_and_implausible_size_warning)
{
    write_sized_box("mm400.msh", 400);   /* a 400 mm cube written in millimetres */
    write_sized_box("tiny.msh", 0.0005); /* 0.5 mm: probably kilometres or a typo */
    sq_err e;
    /* in millimetres, no scale: loads (runs as a 400 m cube) with a warning naming "scale" */
    sq_scene *s = parse(SCENE("{\"levels\": [\"mm400.msh\"], " MAT "}"), &e);
    CHECK(s != NULL);
    if (s) {
        CHECK(s->nwarnings == 1);
        CHECK_CONTAINS(s->warnings[0], "t.json: bodies[0].levels[0]: the mesh's bounding-box diagonal is 692.82 m, above 10 m");
        CHECK_CONTAINS(s->warnings[0], "bodies[0].scale");
        CHECK_CONTAINS(s->warnings[0], "\"scale\": 0.001 (a mesh in millimetres)");
        CHECK_NEAR(s->meshes[0][0]->bbox_max[2], 400, 1e-9);
        sq_scene_free(s);
    }
    /* "scale": 0.001, then the offset: a 0.4 m cube at the offset, no warning; fixed
     * regions are in world space (after scale and offset) */
    s = parse(SCENE("{\"levels\": [\"mm400.msh\"], \"scale\": 0.001, \"offset\": [1, 0, 0], " MAT
                    ", \"fixed\": [{\"box\": [[0.9, -1, -1], [2, 1, 0.01]]}]}"), &e);
    CHECK(s != NULL);
    if (!s)
        printf("    %s\n", e.msg);
    if (s) {
        CHECK(s->nwarnings == 0);
        const sq_mesh *m = s->meshes[0][0];
        CHECK_NEAR(m->bbox_min[0], 1.0, 1e-12);
        CHECK_NEAR(m->bbox_max[0], 1.4, 1e-12);
        CHECK_NEAR(m->bbox_max[2], 0.4, 1e-12);
        double xmax = 0;
        for (int v = 0; v < m->nnodes; v++)
            xmax = fmax(xmax, m->x[3 * v]);
        CHECK_NEAR(xmax, 1.4, 1e-12); /* the nodes, not only the box */
        sq_scene_free(s);
    }
    /* a sub-millimetre mesh: the warning suggests a factor up */
    s = parse(SCENE("{\"levels\": [\"tiny.msh\"], " MAT "}"), &e);
    CHECK(s != NULL);
    if (s) {
        CHECK(s->nwarnings == 1);
        CHECK_CONTAINS(s->warnings[0], "below 1 mm");
        CHECK_CONTAINS(s->warnings[0], "\"scale\": 1000");
        sq_scene_free(s);
    }
    /* a plausible mesh: no warning */
    s = parse(SCENE(BODY), &e);
    CHECK(s && s->nwarnings == 0);
    sq_scene_free(s);
    /* bad scales are errors naming the key */
    s = parse(SCENE("{\"levels\": [\"a.msh\"], \"scale\": 0, " MAT "}"), &e);
    CHECK(s == NULL);
    CHECK_CONTAINS(e.msg, "bodies[0].scale: 0 is out of range");
    s = parse(SCENE("{\"levels\": [\"a.msh\"], \"scale\": -2, " MAT "}"), &e);
    CHECK(s == NULL);
    s = parse(SCENE("{\"levels\": [\"a.msh\"], \"scale\": \"mm\", " MAT "}"), &e);
    CHECK(s == NULL);
    CHECK_CONTAINS(e.msg, "bodies[0].scale");
}
