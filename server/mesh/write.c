/* write.c - mesh writers (legacy VTK, Gmsh 2.2, Medit, TetGen): exact, deterministic numbers. */
#include "mesh/mesh.h"
#include "mesh/mesh_internal.h"
#include "mesh/io_internal.h"

#include <ctype.h>
#include <errno.h>
#include <limits.h>
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <strings.h>

/* shortest of %.15g/%.17g that reads back exactly: deterministic and exact */
static void fmt_exact(char *buf, size_t n, double v)
{
    snprintf(buf, n, "%.15g", v);
    if (strtod(buf, NULL) != v)
        snprintf(buf, n, "%.17g", v);
}

static FILE *open_out(const char *path, sq_err *err)
{
    FILE *f = fopen(path, "w");
    if (!f)
        sq_err_set(err, "%s: cannot write: %s; check the directory exists and is writable", path,
                   strerror(errno));
    return f;
}

static int close_out(FILE *f, const char *path, sq_err *err)
{
    int bad = ferror(f);
    if (fclose(f) != 0 || bad)
        return sq_err_set(err, "%s: write failed (disk full?)", path);
    return 0;
}

static void put_xyz(FILE *f, const double *x)
{
    char a[32], b[32], c[32];
    fmt_exact(a, sizeof a, x[0]);
    fmt_exact(b, sizeof b, x[1]);
    fmt_exact(c, sizeof c, x[2]);
    fprintf(f, "%s %s %s", a, b, c);
}

int sq_mesh_write_vtk(const sq_mesh *m, const char *path, const double *displacement,
                      const double *velocity, const int *level, sq_err *err)
{
    FILE *f = open_out(path, err);
    if (!f)
        return -1;
    fprintf(f, "# vtk DataFile Version 3.0\nsquish tetrahedral mesh\nASCII\nDATASET UNSTRUCTURED_GRID\n");
    fprintf(f, "POINTS %d double\n", m->nnodes);
    for (int i = 0; i < m->nnodes; i++) {
        const double *x = m->x + 3 * (size_t)i;
        fprintf(f, "%.9g %.9g %.9g\n", x[0], x[1], x[2]);
    }
    fprintf(f, "CELLS %d %lld\n", m->ntets, 5LL * m->ntets);
    for (int t = 0; t < m->ntets; t++) {
        const int *v = m->tets + 4 * (size_t)t;
        fprintf(f, "4 %d %d %d %d\n", v[0], v[1], v[2], v[3]);
    }
    fprintf(f, "CELL_TYPES %d\n", m->ntets);
    for (int t = 0; t < m->ntets; t++)
        fputs("10\n", f);
    if (displacement || velocity || level)
        fprintf(f, "POINT_DATA %d\n", m->nnodes);
    const double *vec[2] = {displacement, velocity};
    const char *name[2] = {"displacement", "velocity"};
    for (int k = 0; k < 2; k++) {
        if (!vec[k])
            continue;
        fprintf(f, "VECTORS %s double\n", name[k]);
        for (int i = 0; i < m->nnodes; i++) {
            const double *d = vec[k] + 3 * (size_t)i;
            /* + 0.0 turns -0 into 0 so equal states print equally */
            fprintf(f, "%.9g %.9g %.9g\n", d[0] + 0.0, d[1] + 0.0, d[2] + 0.0);
        }
    }
    if (level) {
        fprintf(f, "SCALARS level int 1\nLOOKUP_TABLE default\n");
        for (int i = 0; i < m->nnodes; i++)
            fprintf(f, "%d\n", level[i]);
    }
    return close_out(f, path, err);
}

int sq_mesh_write_msh(const sq_mesh *m, const char *path, sq_err *err)
{
    FILE *f = open_out(path, err);
    if (!f)
        return -1;
    fprintf(f, "$MeshFormat\n2.2 0 8\n$EndMeshFormat\n$Nodes\n%d\n", m->nnodes);
    for (int i = 0; i < m->nnodes; i++) {
        fprintf(f, "%d ", i + 1);
        put_xyz(f, m->x + 3 * (size_t)i);
        fputc('\n', f);
    }
    fprintf(f, "$EndNodes\n$Elements\n%d\n", m->ntets);
    for (int t = 0; t < m->ntets; t++) {
        const int *v = m->tets + 4 * (size_t)t;
        fprintf(f, "%d 4 2 1 1 %d %d %d %d\n", t + 1, v[0] + 1, v[1] + 1, v[2] + 1, v[3] + 1);
    }
    fprintf(f, "$EndElements\n");
    return close_out(f, path, err);
}

int sq_mesh_write_medit(const sq_mesh *m, const char *path, sq_err *err)
{
    FILE *f = open_out(path, err);
    if (!f)
        return -1;
    fprintf(f, "MeshVersionFormatted 2\n\nDimension 3\n\nVertices\n%d\n", m->nnodes);
    for (int i = 0; i < m->nnodes; i++) {
        put_xyz(f, m->x + 3 * (size_t)i);
        fputs(" 0\n", f);
    }
    fprintf(f, "\nTetrahedra\n%d\n", m->ntets);
    for (int t = 0; t < m->ntets; t++) {
        const int *v = m->tets + 4 * (size_t)t;
        fprintf(f, "%d %d %d %d 1\n", v[0] + 1, v[1] + 1, v[2] + 1, v[3] + 1);
    }
    fprintf(f, "\nEnd\n");
    return close_out(f, path, err);
}

int sq_mesh_write_tetgen(const sq_mesh *m, const char *path, sq_err *err)
{
    size_t n = strlen(path);
    char base[4096], np[4104], ep[4104];
    if (n + 8 > sizeof base)
        return sq_err_set(err, "%s: path too long", path);
    memcpy(base, path, n + 1);
    const char *ext = sq_rd_ext_of(base);
    if (!strcmp(ext, ".node") || !strcmp(ext, ".ele"))
        base[n - strlen(ext)] = 0;
    snprintf(np, sizeof np, "%s.node", base);
    snprintf(ep, sizeof ep, "%s.ele", base);
    FILE *f = open_out(np, err);
    if (!f)
        return -1;
    fprintf(f, "# written by squish\n%d 3 0 0\n", m->nnodes);
    for (int i = 0; i < m->nnodes; i++) {
        fprintf(f, "%d ", i + 1);
        put_xyz(f, m->x + 3 * (size_t)i);
        fputc('\n', f);
    }
    if (close_out(f, np, err) < 0)
        return -1;
    f = open_out(ep, err);
    if (!f)
        return -1;
    fprintf(f, "# written by squish\n%d 4 0\n", m->ntets);
    for (int t = 0; t < m->ntets; t++) {
        const int *v = m->tets + 4 * (size_t)t;
        fprintf(f, "%d %d %d %d %d\n", t + 1, v[0] + 1, v[1] + 1, v[2] + 1, v[3] + 1);
    }
    return close_out(f, ep, err);
}

int sq_mesh_save(const sq_mesh *m, const char *path, sq_err *err)
{
    const char *ext = sq_rd_ext_of(path);
    if (!strcasecmp(ext, ".vtk"))
        return sq_mesh_write_vtk(m, path, NULL, NULL, NULL, err);
    if (!strcasecmp(ext, ".msh"))
        return sq_mesh_write_msh(m, path, err);
    if (!strcasecmp(ext, ".mesh"))
        return sq_mesh_write_medit(m, path, err);
    if (!strcasecmp(ext, ".node") || !strcasecmp(ext, ".ele"))
        return sq_mesh_write_tetgen(m, path, err);
    return sq_err_set(err, "%s: unknown output format '%s'; use .vtk, .msh, .mesh or .node/.ele", path, ext);
}
