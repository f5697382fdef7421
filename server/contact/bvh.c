/* bvh.c - the bounding-volume hierarchy over triangles (build once, refit per frame) and the
 * nearest-triangle query of the narrow phase; the closest point of a triangle. */
#include <math.h>
#include <stdlib.h>
#include <string.h>

#include "contact/contact_internal.h"

#define LEAF_TRIS 4

typedef struct bvh_node {
    double lo[3], hi[3];
    int left, right; /* children (inner node) */
    int start, count; /* triangles order[start .. start + count) (leaf: count > 0) */
} bvh_node;

struct sq_bvh {
    int ntris, nnodes, cap;
    bvh_node *node;
    int *order;      /* triangle indices, grouped by leaf */
    double *centre;  /* scratch of the build: triangle centroids (ntris x 3) */
};

static void tri_box(const double *x, const int *t, double lo[3], double hi[3])
{
    for (int c = 0; c < 3; c++) {
        double a = x[3 * t[0] + c], b = x[3 * t[1] + c], d = x[3 * t[2] + c];
        lo[c] = fmin(a, fmin(b, d));
        hi[c] = fmax(a, fmax(b, d));
    }
}

static void node_box(sq_bvh *b, int k, const double *x, const int *tris)
{
    bvh_node *nd = &b->node[k];
    for (int c = 0; c < 3; c++) {
        nd->lo[c] = INFINITY;
        nd->hi[c] = -INFINITY;
    }
    for (int r = nd->start; r < nd->start + nd->count; r++) {
        double lo[3], hi[3];
        tri_box(x, tris + 3 * (size_t)b->order[r], lo, hi);
        for (int c = 0; c < 3; c++) {
            nd->lo[c] = fmin(nd->lo[c], lo[c]);
            nd->hi[c] = fmax(nd->hi[c], hi[c]);
        }
    }
}

static int new_node(sq_bvh *b)
{
    if (b->nnodes == b->cap) {
        b->cap = b->cap ? 2 * b->cap : 16;
        b->node = sq_realloc(b->node, sizeof(bvh_node) * (size_t)b->cap);
    }
    return b->nnodes++;
}

/* split order[start .. start + count) at the median centroid along the longest axis of the
 * centroids' box (a partial sort by nth-element selection) */
static void select_median(sq_bvh *b, int start, int count, int axis)
{
    int lo = start, hi = start + count - 1, k = start + count / 2;
    const double *cen = b->centre;
    while (lo < hi) {
        double pivot = cen[3 * b->order[(lo + hi) / 2] + axis];
        int i = lo, j = hi;
        while (i <= j) {
            while (cen[3 * b->order[i] + axis] < pivot)
                i++;
            while (cen[3 * b->order[j] + axis] > pivot)
                j--;
            if (i <= j) {
                int t = b->order[i];
                b->order[i] = b->order[j];
                b->order[j] = t;
                i++;
                j--;
            }
        }
        if (k <= j)
            hi = j;
        else if (k >= i)
            lo = i;
        else
            break;
    }
}

static int build(sq_bvh *b, int start, int count, const double *x, const int *tris)
{
    int k = new_node(b);
    b->node[k].start = start;
    b->node[k].count = count;
    b->node[k].left = b->node[k].right = -1;
    if (count > LEAF_TRIS) {
        double lo[3] = {INFINITY, INFINITY, INFINITY}, hi[3] = {-INFINITY, -INFINITY, -INFINITY};
        for (int r = start; r < start + count; r++)
            for (int c = 0; c < 3; c++) {
                lo[c] = fmin(lo[c], b->centre[3 * b->order[r] + c]);
                hi[c] = fmax(hi[c], b->centre[3 * b->order[r] + c]);
            }
        int axis = 0;
        for (int c = 1; c < 3; c++)
            if (hi[c] - lo[c] > hi[axis] - lo[axis])
                axis = c;
        select_median(b, start, count, axis);
        int half = count / 2;
        int l = build(b, start, half, x, tris);
        int r = build(b, start + half, count - half, x, tris);
        b->node[k].left = l;
        b->node[k].right = r;
        b->node[k].count = 0;
    }
    return k;
}

/* boxes bottom-up: children are built after their parent, so a reverse sweep sees them first */
void sq_bvh_refit(sq_bvh *b, const double *x, const int *tris)
{
    for (int k = b->nnodes - 1; k >= 0; k--) {
        bvh_node *nd = &b->node[k];
        if (nd->count > 0) {
            node_box(b, k, x, tris);
            continue;
        }
        const bvh_node *l = &b->node[nd->left], *r = &b->node[nd->right];
        for (int c = 0; c < 3; c++) {
            nd->lo[c] = fmin(l->lo[c], r->lo[c]);
            nd->hi[c] = fmax(l->hi[c], r->hi[c]);
        }
    }
}

sq_bvh *sq_bvh_build(const double *x, const int *tris, int ntris)
{
    sq_bvh *b = sq_calloc(1, sizeof *b);
    b->ntris = ntris;
    b->order = sq_malloc(sizeof(int) * (size_t)(ntris > 0 ? ntris : 1));
    b->centre = sq_malloc(sizeof(double) * 3 * (size_t)(ntris > 0 ? ntris : 1));
    for (int t = 0; t < ntris; t++) {
        b->order[t] = t;
        for (int c = 0; c < 3; c++)
            b->centre[3 * t + c] =
                (x[3 * tris[3 * t] + c] + x[3 * tris[3 * t + 1] + c] + x[3 * tris[3 * t + 2] + c]) / 3;
    }
    if (ntris > 0)
        build(b, 0, ntris, x, tris);
    free(b->centre);
    b->centre = NULL;
    sq_bvh_refit(b, x, tris);
    return b;
}

void sq_bvh_free(sq_bvh *b)
{
    if (!b)
        return;
    free(b->node);
    free(b->order);
    free(b);
}

static double box_dist2(const bvh_node *nd, const double p[3])
{
    double s = 0;
    for (int c = 0; c < 3; c++) {
        double e = p[c] < nd->lo[c] ? nd->lo[c] - p[c] : p[c] > nd->hi[c] ? p[c] - nd->hi[c] : 0;
        s += e * e;
    }
    return s;
}

static inline double dot3(const double a[3], const double b[3])
{
    return a[0] * b[0] + a[1] * b[1] + a[2] * b[2];
}

/* the closest point by the triangle's Voronoi regions (vertex, edge, face), in barycentrics */
double sq_closest_on_triangle(const double p[3], const double a[3], const double b[3], const double c[3],
                              double q[3], double bary[3])
{
    double ab[3], ac[3], ap[3], bp[3], cp[3];
    for (int k = 0; k < 3; k++) {
        ab[k] = b[k] - a[k];
        ac[k] = c[k] - a[k];
        ap[k] = p[k] - a[k];
        bp[k] = p[k] - b[k];
        cp[k] = p[k] - c[k];
    }
    double d1 = dot3(ab, ap), d2 = dot3(ac, ap), d3 = dot3(ab, bp), d4 = dot3(ac, bp), d5 = dot3(ab, cp),
           d6 = dot3(ac, cp);
    double u, v, w; /* weights of a, b, c */
    if (d1 <= 0 && d2 <= 0) {
        u = 1, v = 0, w = 0;
    } else if (d3 >= 0 && d4 <= d3) {
        u = 0, v = 1, w = 0;
    } else if (d6 >= 0 && d5 <= d6) {
        u = 0, v = 0, w = 1;
    } else {
        double vc = d1 * d4 - d3 * d2, vb = d5 * d2 - d1 * d6, va = d3 * d6 - d5 * d4;
        if (vc <= 0 && d1 >= 0 && d3 <= 0) {
            double t = d1 / (d1 - d3);
            u = 1 - t, v = t, w = 0;
        } else if (vb <= 0 && d2 >= 0 && d6 <= 0) {
            double t = d2 / (d2 - d6);
            u = 1 - t, v = 0, w = t;
        } else if (va <= 0 && (d4 - d3) >= 0 && (d5 - d6) >= 0) {
            double t = (d4 - d3) / ((d4 - d3) + (d5 - d6));
            u = 0, v = 1 - t, w = t;
        } else {
            double den = 1 / (va + vb + vc);
            v = vb * den;
            w = vc * den;
            u = 1 - v - w;
        }
    }
    double s = 0;
    for (int k = 0; k < 3; k++) {
        q[k] = u * a[k] + v * b[k] + w * c[k];
        s += (p[k] - q[k]) * (p[k] - q[k]);
    }
    bary[0] = u;
    bary[1] = v;
    bary[2] = w;
    return s;
}

int sq_bvh_nearest(const sq_bvh *b, const double *x, const int *tris, const double p[3], double reach,
                   double *dist, double closest[3], double bary[3])
{
    if (!b || b->nnodes == 0)
        return -1;
    double best = reach * reach;
    int found = -1;
    int stack[128], top = 0;
    stack[top++] = 0;
    while (top > 0) {
        const bvh_node *nd = &b->node[stack[--top]];
        if (box_dist2(nd, p) > best)
            continue;
        if (nd->count > 0) {
            for (int r = nd->start; r < nd->start + nd->count; r++) {
                const int t = b->order[r], *v = tris + 3 * (size_t)t;
                double q[3], w[3];
                double s = sq_closest_on_triangle(p, x + 3 * (size_t)v[0], x + 3 * (size_t)v[1],
                                                  x + 3 * (size_t)v[2], q, w);
                if (s <= best) {
                    best = s;
                    found = t;
                    memcpy(closest, q, sizeof(double) * 3);
                    memcpy(bary, w, sizeof(double) * 3);
                }
            }
        } else if (top + 2 <= (int)(sizeof stack / sizeof stack[0])) {
            /* the nearer child last: searched first */
            double dl = box_dist2(&b->node[nd->left], p), dr = box_dist2(&b->node[nd->right], p);
            stack[top++] = dl < dr ? nd->right : nd->left;
            stack[top++] = dl < dr ? nd->left : nd->right;
        }
    }
    if (found >= 0)
        *dist = sqrt(best);
    return found;
}

int sq_bvh_coplanar_within(const sq_bvh *b, const double *x, const int *tris, const double *normal, const double p[3],
                           double r, const double n[3], double off)
{
    if (!b || b->nnodes == 0)
        return 1;
    const double r2 = r * r;
    int stack[128], top = 0;
    stack[top++] = 0;
    while (top > 0) {
        const bvh_node *nd = &b->node[stack[--top]];
        if (box_dist2(nd, p) > r2)
            continue;
        if (nd->count > 0) {
            for (int k = nd->start; k < nd->start + nd->count; k++) {
                const int t = b->order[k], *v = tris + 3 * (size_t)t;
                const double *tn = normal + 3 * (size_t)t, scale = 1 + fabs(off);
                int in_plane = dot3(tn, n) > 1 - 1e-12;
                for (int j = 0; j < 3 && in_plane; j++)
                    in_plane = fabs(dot3(x + 3 * (size_t)v[j], n) - off) <= 1e-12 * scale;
                if (in_plane)
                    continue; /* the cheap test first: a triangle in the plane never disqualifies */
                double q[3], w[3];
                if (sq_closest_on_triangle(p, x + 3 * (size_t)v[0], x + 3 * (size_t)v[1], x + 3 * (size_t)v[2], q,
                                           w) <= r2)
                    return 0;
            }
        } else if (top + 2 <= (int)(sizeof stack / sizeof stack[0])) {
            stack[top++] = nd->left;
            stack[top++] = nd->right;
        } else {
            return 0; /* too deep to be sure: not coplanar */
        }
    }
    return 1;
}
