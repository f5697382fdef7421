/* fuzz_mesh.c - libFuzzer harness of the mesh readers (server/mesh/io.c) through the public
 * loader, sq_mesh_load, on real files. Built three times (tests/stages/fuzz.sh):
 *   -DFUZZ_EXT='".msh"'   Gmsh 2.2 and 4.1 ASCII (the version comes from $MeshFormat)
 *   -DFUZZ_EXT='".mesh"'  Medit
 *   -DFUZZ_EXT='".node"'  TetGen: the input is NAME.node, a line "@ele", then NAME.ele
 * Any input must give either a valid mesh (positive tets, indices in range, finite
 * coordinates, a locator bounded by the mesh size) or an error naming the file; never a
 * crash, a leak or undefined behaviour. */
#include <math.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/stat.h>
#include <unistd.h>

#include "mesh/mesh.h"
#include "mesh/mesh_internal.h"

#ifndef FUZZ_EXT
#define FUZZ_EXT ".msh"
#endif

static char dir[256], path[300], ele[300];

static void expect(int cond, const char *what)
{
    if (!cond) {
        fprintf(stderr, "fuzz_mesh: check failed: %s\n", what);
        abort();
    }
}

static void put(const char *p, const uint8_t *data, size_t n)
{
    FILE *f = fopen(p, "wb");
    expect(f != NULL, "temporary file");
    if (n)
        fwrite(data, 1, n, f);
    fclose(f);
}

int LLVMFuzzerInitialize(int *argc, char ***argv)
{
    (void)argc;
    (void)argv;
    const char *tmp = getenv("TMPDIR");
    snprintf(dir, sizeof dir, "%s/squish-fuzz-mesh-%d", tmp ? tmp : "/tmp", (int)getpid());
    mkdir(dir, 0700);
    snprintf(path, sizeof path, "%s/in%s", dir, FUZZ_EXT);
    snprintf(ele, sizeof ele, "%s/in.ele", dir);
    return 0;
}

int LLVMFuzzerTestOneInput(const uint8_t *data, size_t size)
{
    size_t n1 = size;
    if (!strcmp(FUZZ_EXT, ".node")) {
        /* split at the first "@ele" line */
        const uint8_t *sep = NULL;
        for (size_t i = 0; i + 4 <= size && !sep; i++)
            if (!memcmp(data + i, "@ele", 4) && (i == 0 || data[i - 1] == '\n'))
                sep = data + i;
        n1 = sep ? (size_t)(sep - data) : size;
        size_t at = sep ? n1 + 4 : size;
        put(ele, data + at, size - at);
    }
    put(path, data, n1);
    sq_err err = {{0}};
    sq_mesh *m = sq_mesh_load(path, &err);
    if (!m) {
        expect(err.msg[0] != 0, "an error message");
        expect(strstr(err.msg, dir) != NULL, "the error names the file");
        return 0;
    }
    expect(m->nnodes > 0 && m->ntets > 0, "counts");
    for (int i = 0; i < 3 * m->nnodes; i++)
        expect(isfinite(m->x[i]), "finite coordinates");
    for (int t = 0; t < m->ntets; t++) {
        for (int k = 0; k < 4; k++)
            expect(m->tets[4 * t + k] >= 0 && m->tets[4 * t + k] < m->nnodes, "index range");
        expect(sq_tet_volume(m, t) > 0, "positive volume");
    }
    sq_mesh_info info;
    sq_mesh_measure(m, &info);
    size_t items = 0, cells = sq_locator_cells(m, &items);
    expect(cells <= 4 * (size_t)(m->ntets + m->ntris) + 128, "locator cells bounded by the mesh size");
    double p[3] = {0.5 * (m->bbox_min[0] + m->bbox_max[0]), 0.5 * (m->bbox_min[1] + m->bbox_max[1]),
                   0.5 * (m->bbox_min[2] + m->bbox_max[2])}, b[4];
    int t = sq_mesh_locate(m, p, b);
    expect(t >= 0 && t < m->ntets, "locate finds a tet");
    sq_mesh_free(m);
    return 0;
}
