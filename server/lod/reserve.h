/* reserve.h - reserve.c's entry points for the other files of the lod module: the coupling arrays'
 * pages mapped ahead of use.
 * Not part of the module's contract (lod.h).
 */
#ifndef SQ_LOD_RESERVE_H
#define SQ_LOD_RESERVE_H

#include "lod/lod_internal.h"

/* grow the coupling arrays (ring and frontier rows, element-block cache) ahead of need and map
 * their pages now, within `seconds` of thread CPU (estimated); returns the pages written */
long sq_lodx_reserve_blocks(sq_lod *lod, double seconds, int ahead);
/* every level's state and per-node scratch arrays (d, v, forces, step start, d + b v, push
 * stamps, marks) mapped, their contents kept: a frame's first writes to a node no frame wrote
 * before (the first push of the finest level's ghosts: 9.6 ms of page faults in box-big's
 * frame 1) then cost no fault; returns the pages touched */
long sq_lodx_map_state(sq_lod *lod);
/* a live budget from now on (reserve_live): every coupling array reserved and mapped
 * (SQ_RESERVE_LOAD_CHUNKS ahead), the state arrays mapped; returns the pages */
long sq_lodx_reserve_live(sq_lod *lod);
/* chunks of each cache (element blocks, column-form rows) mapped ahead of use at load, where a
 * frame keeps one: a refinement's first touches of new cache pages then fall at load, not in
 * its frames (docs/lod.md "Guaranteed frame rate") */
#define SQ_RESERVE_LOAD_CHUNKS 8

#endif
