/* fuzz_trimesh.c - libFuzzer harness of the triangle-mesh readers (server/contact/trimesh.c)
 * through sq_trimesh_load on real files. Built twice (tests/stages/fuzz.sh):
 *   -DFUZZ_EXT='".obj"'  Wavefront OBJ (v and f lines)
 *   -DFUZZ_EXT='".stl"'  STL, ASCII or binary (chosen by the reader)
 * Any input must give either a mesh (indices in range, finite coordinates, unit normals, a
 * nearest-point query that answers inside its bounding box) or an error naming the file; never
 * a crash, a leak or undefined behaviour. */
#include <math.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/stat.h>
#include <unistd.h>

#include "contact/contact.h"

#ifndef FUZZ_EXT
#define FUZZ_EXT ".obj"
#endif

static char dir[256], path[300];

static void expect(int cond, const char *what)
{
    if (!cond) {
        fprintf(stderr, "fuzz_trimesh: check failed: %s\n", what);
        abort();
    }
}

int LLVMFuzzerInitialize(int *argc, char ***argv)
{
    (void)argc;
    (void)argv;
    const char *tmp = getenv("TMPDIR");
    snprintf(dir, sizeof dir, "%s/squish-fuzz-trimesh-%d", tmp ? tmp : "/tmp", (int)getpid());
    mkdir(dir, 0700);
    snprintf(path, sizeof path, "%s/in%s", dir, FUZZ_EXT);
    return 0;
}

int LLVMFuzzerTestOneInput(const uint8_t *data, size_t size)
{
    FILE *f = fopen(path, "wb");
    expect(f != NULL, "temporary file");
    if (size)
        fwrite(data, 1, size, f);
    fclose(f);
    sq_err e = {{0}};
    sq_trimesh *m = sq_trimesh_load(path, 1.0, NULL, &e);
    if (!m) {
        expect(strstr(e.msg, "in" FUZZ_EXT) != NULL, "the error names the file");
        return 0;
    }
    expect(m->ntris > 0 && m->nverts > 0, "a mesh has triangles");
    for (int t = 0; t < 3 * m->ntris; t++)
        expect(m->tris[t] >= 0 && m->tris[t] < m->nverts, "indices in range");
    for (int i = 0; i < 3 * m->nverts; i++)
        expect(isfinite(m->x[i]), "finite coordinates");
    for (int t = 0; t < m->ntris; t++) {
        const double *n = m->normal + 3 * t;
        double l = sqrt(n[0] * n[0] + n[1] * n[1] + n[2] * n[2]);
        expect(fabs(l - 1) < 1e-6, "unit normals");
    }
    double c[3], q[3], bary[3], dist;
    for (int k = 0; k < 3; k++)
        c[k] = 0.5 * (m->bbox_min[k] + m->bbox_max[k]);
    if (sq_trimesh_nearest(m, c, INFINITY, &dist, q, bary) >= 0)
        for (int k = 0; k < 3; k++)
            expect(q[k] >= m->bbox_min[k] - 1e-9 * (1 + fabs(m->bbox_min[k])) &&
                       q[k] <= m->bbox_max[k] + 1e-9 * (1 + fabs(m->bbox_max[k])),
                   "the nearest point lies in the bounding box");
    sq_trimesh_free(m);
    return 0;
}
