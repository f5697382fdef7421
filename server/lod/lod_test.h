/* lod_test.h - the lod state's test-only switches and counters: what tests/unit set to compare
 * a path against its reference, or read to check a decision. No product code sets them; a
 * normal run has them all zero. Not part of the module's contract (lod.h).
 */
#ifndef SQ_LOD_TEST_H
#define SQ_LOD_TEST_H

#include "lod/lod.h"

typedef struct sq_lod_test {
    int corot_tets_always;  /* 1: corotational levels run the tet-by-tet pass even when all their
                             * nodes are active (corotational.c; tests compare it) */
    int full_rebuild;       /* 1: every block row rebuilt after a split/merge pass (coupling.c,
                             * activeset.c; the reference the incremental rebuild is checked
                             * against) */
    long guard_resplit;     /* regions the guard merged that were split again within their rest
                             * (frame.c; tests: 0) */
} sq_lod_test;

/* the test switches of a lod state (its member `test`) */
sq_lod_test *sq_lod_test_of(sq_lod *lod);

#endif
