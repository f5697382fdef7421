/* budget.h - a session's compute budget (internal to server/net; docs/security.md).
 *
 * A session may spend `frac` x its frame period of CPU time on a frame. Its cost is predicted
 * from its bodies' settings (substeps per frame x nodes, for each body: the simulated level
 * of a fixed body, the coarsest level of an adaptive one, whose splits stop at its own time
 * budget) times the measured CPU cost of one node update; a `set` whose prediction is over
 * the budget is refused. Frames are also measured: a session whose frames stay far over the
 * budget is paused with an event (sq_budget_frame).
 */
#ifndef SQ_NET_BUDGET_H
#define SQ_NET_BUDGET_H

#include "scene/scene.h"

/* cost of one node update assumed before a session measured its own (s): 100 ns, about
 * twice the adaptive frame's measured cost on the machines of docs/benchmarks.md */
#define SQ_BUDGET_DEFAULT_COST 100e-9
/* a frame over PAUSE_FACTOR x the budget, or OVER_FRAMES frames in a row over OVER_FACTOR x
 * the budget, pause the session */
#define SQ_BUDGET_PAUSE_FACTOR 25.0
#define SQ_BUDGET_OVER_FACTOR 2.0
#define SQ_BUDGET_OVER_FRAMES 10

typedef struct sq_budget {
    double frac;             /* budget as a fraction of the period (--frame-budget); written
                                by the server, read atomically */
    double cost;             /* measured CPU s per node update (moving average), 0 = none yet */
    int over;                /* frames in a row over SQ_BUDGET_OVER_FACTOR x the budget */
} sq_budget;

/* the prediction for the world as set now: node updates per frame, and the body that costs
 * most with its substeps and nodes */
typedef struct sq_budget_prediction {
    double updates;          /* node updates per frame, every body */
    double seconds;          /* updates x cost per update */
    int body, substeps, nodes;
} sq_budget_prediction;

void sq_budget_predict(const sq_budget *g, const sq_world *w, double period,
                       sq_budget_prediction *p);

/* account one stepped frame of cpu seconds and `updates` node updates; returns 1 if the
 * session must pause (msg says why) */
int sq_budget_frame(sq_budget *g, double frac, double period, double cpu, double updates,
                    char *msg, size_t cap);

#endif
