/* lod_vec.h - the 4-lane vectors of the lod kernels and the small interpolation helpers built on
 * them (the same products and sums as the scalar code, lane by lane). Not part of lod.h.
 */
#ifndef SQ_LOD_VEC_H
#define SQ_LOD_VEC_H

#include <string.h>

#include "lod/lod_internal.h"

/* 4-lane vectors (lane 3 unused) for the kernels of the tick: a node's 3 components are
 * loaded as 4 lanes, so arrays read that way have one spare double after the last node. The
 * lanes are computed with the same multiplications and additions, in the same order, as the
 * scalar code they replace (-std=c11 contracts nothing into fma), so the results are bitwise
 * those of the scalar code, in every build */
typedef double sq_v4 __attribute__((vector_size(32)));
typedef long long sq_v4i __attribute__((vector_size(32)));
typedef double sq_v2 __attribute__((vector_size(16)));

/* the helpers are macros (statement expressions), not functions: a 32-byte vector passed to or
 * returned from a function has no fixed calling convention without AVX (the ASan build) */

/* 4 doubles from p (any alignment) */
#define v4_load(p)                                                                                                 \
    ({                                                                                                             \
        sq_v4 v4l_;                                                                                                \
        memcpy(&v4l_, (p), sizeof v4l_);                                                                           \
        v4l_;                                                                                                      \
    })

/* a in every lane */
#define v4_set1(a)                                                                                                 \
    ({                                                                                                             \
        const double v4s_ = (a);                                                                                   \
        (sq_v4){v4s_, v4s_, v4s_, v4s_};                                                                           \
    })

/* lane c of x in every lane (gcc's and clang's spellings of the same shuffle; the fuzzers
 * build with clang) */
#if defined(__clang__)
#define V4_LANE(x, c) __builtin_shufflevector((x), (x), (c), (c), (c), (c))
#else
#define V4_LANE(x, c) __builtin_shuffle((x), (sq_v4i){(c), (c), (c), (c)})
#endif

/* one 3x3 block in column form (T: 3 columns of 4) times w: ((c0 w0 + c1 w1) + c2 w2) in
 * every row, the order of the scalar row sums */
#define v4_block(T, w)                                                                                             \
    ({                                                                                                             \
        const double *v4T_ = (T);                                                                                  \
        const sq_v4 v4w_ = (w);                                                                                    \
        const sq_v4 v4t_ = v4_load(v4T_) * V4_LANE(v4w_, 0) + v4_load(v4T_ + 4) * V4_LANE(v4w_, 1);               \
        v4t_ + v4_load(v4T_ + 8) * V4_LANE(v4w_, 2);                                                               \
    })

/* the same with w given as 3 doubles at W (each broadcast from memory): the same products and
 * sums, lane by lane */
#define v4_block_s(T, W)                                                                                           \
    ({                                                                                                             \
        const double *v4T_ = (T), *v4W_ = (W);                                                                     \
        const sq_v4 v4t_ = v4_load(v4T_) * v4_set1(v4W_[0]) + v4_load(v4T_ + 4) * v4_set1(v4W_[1]);             \
        v4t_ + v4_load(v4T_ + 8) * v4_set1(v4W_[2]);                                                               \
    })

/* nb row-major 3x3 blocks into column form at T: per block the columns (B0 B3 B6), (B1 B4 B7),
 * (B2 B5 B8), each padded to 4 lanes with a zero */
static inline void sq_lodx_to_columns(const double *src, int nb, double *T)
{
    for (int e = 0; e < nb; e++, src += 9, T += 12)
        for (int c = 0; c < 3; c++) {
            T[4 * c] = src[c];
            T[4 * c + 1] = src[3 + c];
            T[4 * c + 2] = src[6 + c];
            T[4 * c + 3] = 0;
        }
}

/* an interpolated node's displacement d and velocity v (first three lanes) stored at dd, dv,
 * zero on the axes its fixed mask fx holds (the vectors by address: a 32-byte vector passed by
 * value changes ABI between builds with and without AVX, which gcc notes) */
static inline void sq_lodx_store_free(unsigned char fx, const sq_v4 *dp, const sq_v4 *vp, double *dd, double *dv)
{
    const sq_v4 d = *dp, v = *vp;
    if (!fx) {
        dd[0] = d[0], dd[1] = d[1], dd[2] = d[2];
        dv[0] = v[0], dv[1] = v[1], dv[2] = v[2];
        return;
    }
    for (int a = 0; a < 3; a++) {
        int free_axis = !(fx & (1u << a));
        dd[a] = free_axis ? d[a] : 0.0;
        dv[a] = free_axis ? v[a] : 0.0;
    }
}

/* interpolate d and v of node i of level `dst` from tet t of level `src`; constrained
 * axes of the destination stay zero. The three components in the lanes of one vector, each
 * lane summed as the scalar sums were: d += b_m d_m, m = 0..3 */
static inline void interp_node(sq_level *dst, int i, const sq_level *src, int t, const double *b)
{
    const int *tn = src->model.mesh->tets + 4 * t;
    sq_v4 d = {0, 0, 0, 0}, v = {0, 0, 0, 0};
    for (int m = 0; m < 4; m++) {
        const sq_v4 bm = v4_set1(b[m]);
        d += bm * v4_load(src->state.d + 3 * (size_t)tn[m]);
        v += bm * v4_load(src->state.v + 3 * (size_t)tn[m]);
    }
    sq_lodx_store_free(dst->model.fixed[i], &d, &v, dst->state.d + 3 * (size_t)i, dst->state.v + 3 * (size_t)i);
}

#endif
