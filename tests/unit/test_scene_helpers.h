/* test_scene_helpers.h - small functions shared by the scene and world unit tests: scratch
 * directories and meshes, the shipped scenes. */
#ifndef SQ_TEST_SCENE_HELPERS_H
#define SQ_TEST_SCENE_HELPERS_H

#include <stdio.h>
#include <stdlib.h>

#include "mesh/mesh.h"
#include "scene/scene.h"
#include "sq_test.h"

/* the shipped scenes' directory, meshes/scenes (beside tests/, as sq_test_data() finds it) */
static inline const char *th_scenes_dir(void)
{
    static char dir[1024];
    snprintf(dir, sizeof dir, "%s/../../meshes/scenes", sq_test_data());
    return dir;
}

/* the shipped scene meshes/scenes/<name>.json; NULL, its path and error printed, when it does
 * not load: the caller checks */
static inline sq_scene *th_shipped_scene(const char *name)
{
    char path[1200];
    snprintf(path, sizeof path, "%s/%s.json", th_scenes_dir(), name);
    sq_err e = {{0}};
    sq_scene *sc = sq_scene_load(path, &e);
    if (!sc)
        fprintf(stderr, "    %s: %s\n", path, e.msg);
    return sc;
}

/* the text of the shipped scene <name> in text[size] (NUL-ended, cut at size - 1 bytes); 0, or
 * -1 with the path printed when it cannot be opened */
static inline int th_shipped_scene_text(const char *name, char *text, size_t size)
{
    char path[1200];
    snprintf(path, sizeof path, "%s/%s.json", th_scenes_dir(), name);
    FILE *fp = fopen(path, "rb");
    if (!fp) {
        fprintf(stderr, "%s: cannot open\n", path);
        return -1;
    }
    size_t n = fread(text, 1, size - 1, fp);
    fclose(fp);
    text[n] = 0;
    return 0;
}

/* mkdir -p dir; 0, or -1 if it could not be made */
static inline int th_make_dir(const char *dir)
{
    char cmd[400];
    snprintf(cmd, sizeof cmd, "mkdir -p '%s'", dir);
    return system(cmd) != 0 ? -1 : 0;
}

/* a box of cells per side on [0,1]^3 written as dir/name (.msh); a failure is printed */
static inline void th_write_box_msh(const char *dir, const char *name, int cells)
{
    const double size[3] = {1, 1, 1}, origin[3] = {0, 0, 0};
    sq_err e = {{0}};
    sq_mesh *m = sq_mesh_box(cells, cells, cells, size, origin, &e);
    char path[400];
    snprintf(path, sizeof path, "%s/%s", dir, name);
    if (!m || sq_mesh_write_msh(m, path, &e))
        printf("    mesh setup failed: %s\n", e.msg);
    sq_mesh_free(m);
}

#endif
