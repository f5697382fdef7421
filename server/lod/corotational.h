/* corotational.h - corotational.c's entry points for the other files of the lod module:
 * corotational levels: tet lists, forces and ring reactions tet by tet.
 * Not part of the module's contract (lod.h).
 */
#ifndef SQ_LOD_COROTATIONAL_H
#define SQ_LOD_COROTATIONAL_H

#include "lod/lod_internal.h"

/* corotational.c (levels with lv[k].corot): the frame's force pass of a due level k and the
 * ring reactions of level k at tick t computed tet by tet instead of from the linear blocks;
 * the tet lists brought up to the layout (a no-op unless it changed); the weighted energy */
int sq_lodx_corot_on(const sq_lod *lod);
void sq_lodx_corot_layout(sq_lod *lod, const sq_material *mat);
void sq_lodx_corot_forces(sq_lod *lod, const sq_material *mat, const double gravity[3], int k);
int sq_lodx_corot_couple_out(sq_lod *lod, const sq_material *mat, int k, long t); /* ring rows handed back */
double sq_lodx_corot_energy(const sq_lod *lod, double *kinetic, double *elastic);
void sq_lodx_corot_free(sq_lod *lod, int k);
/* the ring weights of corotational levels made exact for affine fields (a
 * rigid motion of the body gives no force), at the end of sq_lodx_build_sources */
void sq_lodx_corot_affine_sources(sq_lod *lod);
/* level k's static equilibrium under gravity g with corotational elasticity,
 * from the linear one in d (replaced on success: 0; else -1 and d unchanged) */
int sq_lodx_corot_static(sq_lod *lod, int k, const double g[3], double *d, int *iterations);

#endif
