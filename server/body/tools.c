/* tools.c - the paper's tools (section 5) as holds on the finest surface nodes.
 *
 * sphere / box push: a surface vertex whose current position lies inside the shape is moved
 * to the nearest point of the shape's surface. grab: on activation the surface vertices within
 * `radius` of its activation point (sq_tool.origin, else pos) are captured (or, if none, the
 * nearest one within 3 radius, unless sq_tool.no_fallback: the world allows the fallback on
 * the one body nearest to the point, and only when no body has a vertex within radius); each frame their target displacement is the captured one plus
 * (pos - start), start being that point; released when the tool goes
 * inactive or disappears from the frame's tool list.
 */
#include <math.h>
#include <stdlib.h>
#include <string.h>

#include "body/body_internal.h"

static void add_hold(sq_body *b, int *nh, int tool, int node, const double target[3])
{
    if (*nh >= b->cap_holds) {
        b->cap_holds = b->cap_holds ? 2 * b->cap_holds : 256;
        b->holds = sq_realloc(b->holds, sizeof(sq_hold) * (size_t)b->cap_holds);
    }
    sq_hold *h = &b->holds[(*nh)++];
    h->tool = tool;
    h->node = node;
    memcpy(h->target, target, sizeof h->target);
}

static sq_grab *find_grab(sq_body *b, int id)
{
    for (int g = 0; g < SQ_MAX_TOOLS; g++)
        if (b->grab[g].id == id)
            return &b->grab[g];
    return NULL;
}

/* squared distance from `at` of finest surface vertex s where it is now; its displacement in u */
static double surf_dist2(const sq_body *b, const sq_mesh *fm, int s, const double at[3], double u[3])
{
    double d2 = 0;
    sq_body_surface_disp(b, s, u);
    const double *x = fm->x + 3 * (size_t)fm->surf_nodes[s];
    for (int c = 0; c < 3; c++)
        d2 += (x[c] + u[c] - at[c]) * (x[c] + u[c] - at[c]);
    return d2;
}

/* capture surface vertices for a grab tool around its origin (or pos without one) */
static sq_grab *capture(sq_body *b, const sq_tool *tool)
{
    const double *at = tool->has_origin ? tool->origin : tool->pos;
    sq_grab *g = find_grab(b, -1);
    if (!g)
        return NULL;
    const sq_mesh *fm = b->def.levels[b->fine];
    free(g->surf);
    free(g->disp);
    g->surf = NULL;
    g->disp = NULL;
    g->n = 0;
    int cap = 0, nearest = -1;
    double r2 = tool->radius * tool->radius, best = INFINITY;
    for (int s = 0; s < fm->nsurf; s++) {
        double u[3], d2 = surf_dist2(b, fm, s, at, u);
        if (d2 < best) {
            best = d2;
            nearest = s;
        }
        if (d2 <= r2) {
            if (g->n == cap) {
                cap = cap ? 2 * cap : 64;
                g->surf = sq_realloc(g->surf, sizeof(int) * (size_t)cap);
                g->disp = sq_realloc(g->disp, sizeof(double) * 3 * (size_t)cap);
            }
            g->surf[g->n] = s;
            memcpy(g->disp + 3 * g->n, u, sizeof u);
            g->n++;
        }
    }
    if (g->n == 0 && !tool->no_fallback && nearest >= 0 && best <= 9 * r2) {
        g->surf = sq_malloc(sizeof(int));
        g->disp = sq_malloc(sizeof(double) * 3);
        g->surf[0] = nearest;
        sq_body_surface_disp(b, nearest, g->disp);
        g->n = 1;
    }
    g->id = tool->id;
    memcpy(g->start, at, sizeof g->start);
    return g;
}

int sq_body_grab_reach(const sq_body *b, const double at[3], double radius, double *nearest)
{
    const sq_mesh *fm = b->def.levels[b->fine];
    double best = INFINITY, r2 = radius * radius;
    int n = 0;
    for (int s = 0; s < fm->nsurf; s++) {
        double u[3], d2 = surf_dist2(b, fm, s, at, u);
        best = fmin(best, d2);
        n += d2 <= r2;
    }
    *nearest = sqrt(best);
    return n;
}

int sq_body_tool_holds(sq_body *b, const sq_tool *tools, int ntools, int *tool_nodes)
{
    const sq_mesh *fm = b->def.levels[b->fine];
    int nh = 0;

    /* release captures of grab tools that are inactive or gone */
    for (int g = 0; g < SQ_MAX_TOOLS; g++) {
        if (b->grab[g].id < 0)
            continue;
        int keep = 0;
        for (int t = 0; t < ntools; t++)
            if (tools[t].id == b->grab[g].id && tools[t].active && tools[t].shape == SQ_TOOL_GRAB)
                keep = 1;
        if (!keep)
            b->grab[g].id = -1;
    }

    for (int t = 0; t < ntools; t++) {
        const sq_tool *tool = &tools[t];
        int before = nh;
        if (!tool->active) {
            tool_nodes[t] = 0;
            continue;
        }
        if (tool->shape == SQ_TOOL_GRAB) {
            sq_grab *g = find_grab(b, tool->id);
            /* released and grabbed again elsewhere between two frames: a new capture */
            if (g && tool->has_origin && memcmp(g->start, tool->origin, sizeof g->start) != 0) {
                g->id = -1;
                g = NULL;
            }
            if (!g)
                g = capture(b, tool);
            if (g)
                for (int k = 0; k < g->n; k++) {
                    double target[3];
                    for (int c = 0; c < 3; c++)
                        target[c] = g->disp[3 * k + c] + tool->pos[c] - g->start[c];
                    add_hold(b, &nh, t, fm->surf_nodes[g->surf[k]], target);
                }
        } else {
            for (int s = 0; s < fm->nsurf; s++) {
                int node = fm->surf_nodes[s];
                const double *x0 = fm->x + 3 * (size_t)node;
                double u[3], p[3], q[3];
                sq_body_surface_disp(b, s, u);
                for (int c = 0; c < 3; c++)
                    p[c] = x0[c] + u[c] - tool->pos[c]; /* relative to the tool centre */
                if (tool->shape == SQ_TOOL_SPHERE) {
                    double r = sqrt(p[0] * p[0] + p[1] * p[1] + p[2] * p[2]);
                    if (!(r < tool->radius))
                        continue;
                    if (r > 0)
                        for (int c = 0; c < 3; c++)
                            q[c] = p[c] * tool->radius / r;
                    else
                        q[0] = q[1] = 0, q[2] = tool->radius;
                } else {
                    int inside = 1, axis = 0;
                    double depth = INFINITY;
                    for (int c = 0; c < 3; c++) {
                        double m = tool->half[c] - fabs(p[c]);
                        if (!(m > 0))
                            inside = 0;
                        if (m < depth) {
                            depth = m;
                            axis = c;
                        }
                    }
                    if (!inside)
                        continue;
                    memcpy(q, p, sizeof q);
                    q[axis] = p[axis] >= 0 ? tool->half[axis] : -tool->half[axis];
                }
                double target[3];
                for (int c = 0; c < 3; c++)
                    target[c] = tool->pos[c] + q[c] - x0[c];
                add_hold(b, &nh, t, node, target);
            }
        }
        tool_nodes[t] = nh - before;
    }
    return nh;
}
