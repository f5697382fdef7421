/* lod_test.h - the test hooks of the lod module: the test switches and counters of a state
 * (sq_lod_test, in lod_internal.h), given costs for the guard, the sharp bound's dense forms.
 * Included by views.c, guard.c, estimate.c (which define them) and tests/unit only; no product
 * path calls them. Not part of the module's contract (lod.h).
 */
#ifndef SQ_LOD_TEST_H
#define SQ_LOD_TEST_H

#include "lod/lod_internal.h"

/* the test switches of a lod state (its member `test`) */
sq_lod_test *sq_lod_test_of(sq_lod *lod);

/* fixed costs for the guard instead of measured ones (deterministic runs with a budget); all
 * <= 0 returns to measuring (guard.c) */
void sq_lodx_set_costs(sq_lod *lod, double per_update_s, double per_frame_s, double per_level_s,
                       double per_pass_s, double per_change_s);
/* for tests: level k's block S_kk + C_k of the majorant (S = M^-1/2 A M^-1/2) as bound.c applies it,
 * dense over 3 x its active nodes (active_list order, constrained axes zero rows and columns),
 * and the scaled diagonal C_k (*off, same order); both to free */
double *sq_lodx_sharp_dense(sq_lod *lod, int k, double **off);
/* tests: the estimate (Lanczos, Ritz vector, rho + ||r||, not capped) of the dense symmetric
 * n x n matrix A (n a multiple of 3) from start, iters steps (at most 40) */
double sq_lodx_sharp_lanczos_dense(const double *A, int n, const double *start, int iters);
/* the same with the early stop (bound.c's stop_rule; rule 1 on, 0 off) against the ceiling (the
 * estimate capped by it), substep bins floor(log4(w2 / bin_unit)); its steps and whether it
 * stopped early (1) */
double sq_lodx_sharp_lanczos_dense_stop(const double *A, int n, const double *start, int iters, double ceiling,
                                        double bin_unit, int rule, int *steps, int *stopped);
/* tests: stop_rule's decision (1: stop) for the Lanczos tridiagonal (alpha, beta, order m) against
 * the ceiling, in the dense tests' bins floor(log4(w2 / bin_unit)) */
int sq_lodx_sharp_stop_tridiag(const double *alpha, const double *beta, int m, double ceiling, double bin_unit);

#endif
