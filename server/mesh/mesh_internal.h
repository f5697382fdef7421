/* mesh_internal.h - helpers shared by the mesh module's files (not a public contract). */
#ifndef SQ_MESH_INTERNAL_H
#define SQ_MESH_INTERNAL_H

#include "mesh/mesh.h"

/* wrap owned arrays in a new mesh (not validated, not finalized) */
sq_mesh *sq_mesh_new_owned(int nnodes, double *x, int ntets, int *tets, const char *source);

/* validate: counts, finite coordinates, index range, degenerate tets, orientation (flips all
 * when every tet is negative), unreferenced nodes. node_line/tet_line (may be NULL) give the
 * file line of each node/tet for messages; node_file (may be NULL = m->source) names the file
 * the nodes came from when it differs (TetGen .node). */
int sq_mesh_validate(sq_mesh *m, const char *node_file, const int *node_line, const int *tet_line,
                     sq_err *err);

/* validate then finalize; frees m and returns NULL on error */
sq_mesh *sq_mesh_validate_finalize(sq_mesh *m, const char *node_file, const int *node_line,
                                   const int *tet_line, sq_err *err);

/* free the point-location grid */
void sq_locator_free(struct sq_locator *loc);

/* cells of the point-location grids (tets + boundary triangles), built if needed; items
 * (may be NULL) gets the number of grid entries: what the locator's memory is made of */
size_t sq_locator_cells(const sq_mesh *m, size_t *items);

#endif
