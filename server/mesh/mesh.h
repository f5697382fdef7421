/* mesh.h - tetrahedral meshes: formats, topology, geometry and quality.
 *
 * First stage of the data flow (mesh -> sim -> lod -> scene -> net/render -> app).
 * A mesh is immutable once finalized: every later stage takes `const sq_mesh *`.
 */
#ifndef SQ_MESH_H
#define SQ_MESH_H

#include "util/util.h"

typedef struct sq_mesh {
    /* given */
    int nnodes;          /* number of nodes */
    int ntets;           /* number of tetrahedra */
    double *x;           /* rest positions (nnodes x 3) */
    int *tets;           /* node indices (ntets x 4), positively oriented (volume > 0) */

    /* derived by sq_mesh_finalize() */
    int ntris;           /* boundary triangles */
    int *tris;           /* node indices (ntris x 3), counter-clockwise seen from outside */
    unsigned char *on_boundary; /* 1 if the node lies on a boundary triangle (nnodes) */
    int nsurf;           /* number of boundary nodes */
    int *surf_nodes;     /* node index of each boundary vertex (nsurf) */
    int *surf_of_node;   /* boundary vertex index of each node, or -1 (nnodes) */
    int *surf_tris;      /* boundary triangles in boundary-vertex numbering (ntris x 3) */
    int *adj_start;      /* CSR over nodes: neighbours of i are adj[adj_start[i] .. adj_start[i+1]) (nnodes+1) */
    int *adj;            /* neighbour node indices, sorted, including i itself (adj_start[nnodes]) */
    double bbox_min[3], bbox_max[3]; /* rest bounding box */
    char source[256];    /* file it came from, for messages */
    int *tri_tet;        /* tet owning each boundary triangle (ntris) */
    struct sq_locator *locator; /* private: point-location grid, built on first sq_mesh_locate */
} sq_mesh;

/* quality and size figures, as printed by `squish mesh info` */
typedef struct sq_mesh_info {
    int nnodes, ntets, ntris, nsurf, nedges;
    double volume, surface_area;
    double edge_min, edge_mean, edge_max;
    double dihedral_min_deg, dihedral_max_deg;
    double aspect_max;      /* worst aspect ratio: longest edge / smallest height */
    double height_min;      /* smallest tet height (what the stability bound needs) */
} sq_mesh_info;

/* load a mesh: format chosen by extension (.msh Gmsh 2.2/4.1 ASCII, .node/.ele TetGen
 * (either name may be given), .mesh Medit). Validates and finalizes.
 * On error returns NULL and err names file, line and problem. */
sq_mesh *sq_mesh_load(const char *path, sq_err *err);

/* build from arrays (copied); validates and finalizes; NULL + err on bad input */
sq_mesh *sq_mesh_from_arrays(int nnodes, const double *x, int ntets, const int *tets,
                             const char *source, sq_err *err);

/* structured box: nx*ny*nz cells, each split into 6 tets, spanning [0,size] per axis,
 * then shifted by origin; NULL + err on bad sizes */
sq_mesh *sq_mesh_box(int nx, int ny, int nz, const double size[3], const double origin[3],
                     sq_err *err);

void sq_mesh_free(sq_mesh *m);

/* the same mesh with its nodes renumbered by reverse Cuthill-McKee (breadth-first from a
 * pseudo-peripheral node, reversed; ties to the lower index: deterministic) and its tets sorted
 * by their smallest node: neighbours get close indices, so the step kernel's row reads stay in
 * cache. NULL + err on failure (out of memory) */
sq_mesh *sq_mesh_renumber(const sq_mesh *m, sq_err *err);

/* largest |i - j| over neighbouring nodes i, j */
int sq_mesh_bandwidth(const sq_mesh *m);

/* compute boundary, adjacency and bounding box (called by the loaders) */
int sq_mesh_finalize(sq_mesh *m, sq_err *err);

/* measure sizes and quality */
void sq_mesh_measure(const sq_mesh *m, sq_mesh_info *info);

/* signed volume of tet t */
double sq_tet_volume(const sq_mesh *m, int t);

/* gradients of the four linear basis functions of tet t: grad[i][0..2], i = 0..3;
 * returns the signed volume */
double sq_tet_gradients(const sq_mesh *m, int t, double grad[4][3]);

/* locate point p: index of the tet containing it (or the nearest tet when outside) and
 * barycentric coordinates bary[4] (sum 1; one may be negative when outside) */
int sq_mesh_locate(const sq_mesh *m, const double p[3], double bary[4]);

/* writers */
/* legacy VTK unstructured grid; optional point fields (NULL to omit):
 * displacement, velocity (nnodes x 3 doubles), level (nnodes ints) */
int sq_mesh_write_vtk(const sq_mesh *m, const char *path, const double *displacement,
                      const double *velocity, const int *level, sq_err *err);
/* Gmsh 2.2 ASCII */
int sq_mesh_write_msh(const sq_mesh *m, const char *path, sq_err *err);
/* Medit .mesh ASCII (MeshVersionFormatted 2, 1-based) */
int sq_mesh_write_medit(const sq_mesh *m, const char *path, sq_err *err);
/* TetGen: path ends in .node or .ele (or has no extension); writes both NAME.node and NAME.ele
 * (1-based, no attributes, no markers) */
int sq_mesh_write_tetgen(const sq_mesh *m, const char *path, sq_err *err);
/* any of the above, chosen by extension (.vtk, .msh, .mesh, .node/.ele) without point fields */
int sq_mesh_save(const sq_mesh *m, const char *path, sq_err *err);

/* outward CCW faces of a positively oriented tet: face k (opposite vertex k) is
 * tets[sq_tet_face[k][0..2]] */
extern const int sq_tet_face[4][3];

#endif
