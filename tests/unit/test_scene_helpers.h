/* test_scene_helpers.h - small helpers shared by the scene and world unit tests. */
#ifndef SQ_TEST_SCENE_HELPERS_H
#define SQ_TEST_SCENE_HELPERS_H

#include <stdio.h>
#include <stdlib.h>

#include "mesh/mesh.h"

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
