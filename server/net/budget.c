/* budget.c - a session's compute budget: predicted at `set`, measured per frame. */
#include "net/budget.h"

#include <math.h>
#include <stdio.h>

void sq_budget_predict(const sq_budget *g, const sq_world *w, double period,
                       sq_budget_prediction *p)
{
    p->updates = 0;
    p->body = -1;
    p->substeps = p->nodes = 0;
    double worst = -1;
    for (int b = 0; b < w->nbodies; b++) {
        const sq_body *body = w->bodies[b];
        const sq_body_def *d = sq_body_get_def(body);
        int nl = sq_body_nlevels(body);
        /* fixed: the simulated level; adaptive: the coarsest, the least it can fall back
         * to (its splits stop when its frames pass its own lod.budget) */
        int k = d->lod.mode == SQ_LOD_FIXED || nl == 1 ? SQ_MIN(SQ_MAX(d->lod.level, 0), nl - 1) : 0;
        double dt = sq_body_level_dt(body, k);
        int sub = dt > 0 ? (int)lround(period / dt) : 1;
        int n = sq_body_mesh(body, k)->nnodes;
        double u = (double)SQ_MAX(sub, 1) * n;
        p->updates += u;
        if (u > worst) {
            worst = u;
            p->body = b;
            p->substeps = sub;
            p->nodes = n;
        }
    }
    p->seconds = p->updates * (g->cost > 0 ? g->cost : SQ_BUDGET_DEFAULT_COST);
}

int sq_budget_frame(sq_budget *g, double frac, double period, double cpu, double updates,
                    char *msg, size_t cap)
{
    if (updates >= 1000 && cpu > 0) {
        double c = cpu / updates;
        g->cost = g->cost > 0 ? 0.9 * g->cost + 0.1 * c : c;
    }
    double budget = frac * period;
    if (cpu > SQ_BUDGET_OVER_FACTOR * budget)
        g->over++;
    else
        g->over = 0;
    if (cpu > SQ_BUDGET_PAUSE_FACTOR * budget || g->over >= SQ_BUDGET_OVER_FRAMES) {
        snprintf(msg, cap, "session paused: its frames take %.1f ms of CPU, over the frame budget "
                 "of %.1f ms (--frame-budget %.3g x the %.1f ms period); make it cheaper (a "
                 "coarser level, a softer or denser material, less damping), then resume",
                 1e3 * cpu, 1e3 * budget, frac, 1e3 * period);
        g->over = 0;
        return 1;
    }
    return 0;
}
