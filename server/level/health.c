/* health.c - the kinds of health warning a frame can raise, their names and their sentences.
 *
 * A warning is a kind plus up to four numbers; the sentence a frame reports (sq_frame_profile
 * event, the server's event message, `squish run`'s log) is built here from them, so the
 * counters (body/body.h sq_body_health) and the text always agree. */
#include <stdio.h>

#include "level/level.h"

static const char *const names[SQ_HEALTH_NKINDS] = {
    [SQ_HEALTH_NONE] = "none",
    [SQ_HEALTH_BLOWUP_NAN] = "blowup_nan",
    [SQ_HEALTH_BLOWUP_STRETCH] = "blowup_stretch",
    [SQ_HEALTH_BLOWUP_SPEED] = "blowup_speed",
    [SQ_HEALTH_SLEEP] = "sleep",
    [SQ_HEALTH_WAKE] = "wake",
    [SQ_HEALTH_BUDGET_COARSE] = "budget_coarse",
    [SQ_HEALTH_BUDGET_OVER] = "budget_over",
    [SQ_HEALTH_BUDGET_PREDICTED] = "budget_predicted",
    [SQ_HEALTH_NODE_CAP] = "node_cap",
    [SQ_HEALTH_SOLVE_UNCONVERGED] = "solve_unconverged",
    [SQ_HEALTH_STEP_REFINED] = "step_refined",
};

const char *sq_health_kind_name(sq_health_kind k)
{
    return k >= 0 && k < SQ_HEALTH_NKINDS ? names[k] : "unknown";
}

static const char *blowup_reason(sq_health_kind k)
{
    switch (k) {
    case SQ_HEALTH_BLOWUP_NAN: return "non-finite displacement or velocity";
    case SQ_HEALTH_BLOWUP_STRETCH: return "displacement beyond 10 bounding-box diagonals";
    default: return "kinetic energy above 0.5 M (10 diag / frame_dt)^2";
    }
}

void sq_health_sentence(char *buf, size_t cap, sq_health_kind k, const double v[4], const char *body)
{
    if (!cap)
        return;
    const char *name = body ? body : "body";
    switch (k) {
    case SQ_HEALTH_BLOWUP_NAN:
    case SQ_HEALTH_BLOWUP_STRETCH:
    case SQ_HEALTH_BLOWUP_SPEED:
        snprintf(buf, cap, "blow-up detected: %s (%.3g) in body '%.40s'; body reset to rest", blowup_reason(k),
                 v[0], name);
        break;
    case SQ_HEALTH_SLEEP:
        snprintf(buf, cap, "body '%.60s' at rest: sleeping until touched", name);
        break;
    case SQ_HEALTH_BUDGET_COARSE:
        snprintf(buf, cap,
                 "warning: cannot run in real time even fully coarse: level 0 needs %.2f ms "
                 "(%d nodes x %d steps), budget %.2f ms; splitting refused",
                 v[0], (int)v[1], (int)v[2], v[3]);
        break;
    case SQ_HEALTH_BUDGET_OVER:
        snprintf(buf, cap,
                 "warning: frame compute %.2f ms over %.0f%% of the %.2f ms budget: splitting "
                 "refused, merging allowed", v[0], v[1], v[2]);
        break;
    case SQ_HEALTH_BUDGET_PREDICTED:
        snprintf(buf, cap,
                 "warning: next frame predicted over %.0f%% of %.2f ms (%ld node updates fit): "
                 "least needed regions merged, splitting refused", v[0], v[1], (long)v[2]);
        break;
    case SQ_HEALTH_NODE_CAP:
        snprintf(buf, cap, "warning: node-update cap %ld per frame reached: splitting refused", (long)v[0]);
        break;
    case SQ_HEALTH_SOLVE_UNCONVERGED:
        snprintf(buf, cap,
                 "warning: '%.20s': implicit solve stopped at residual %.2g after %d CG iterations (tol %.2g, "
                 "cap %d): raise cg_max_iterations or substeps", name, v[0], (int)v[1], v[2], (int)v[3]);
        break;
    case SQ_HEALTH_STEP_REFINED:
        snprintf(buf, cap, "warning: '%.30s': the explicit step diverged at %ld substeps; frame re-run at %ld "
                 "substeps (not streamed before)", name, (long)v[1], (long)v[0]);
        break;
    default: /* none, wake: no sentence */
        buf[0] = 0;
        break;
    }
}
