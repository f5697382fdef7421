/* health.c - a body's health after each frame (blow-up detection and reset), the typed
 * warning counters and the sleep test (docs/physics.md section 7). */
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "lod/lod.h"
#include "body/body_internal.h"

/* health: non-finite values, displacement beyond 10 bbox diagonals (a free body, with no fixed
 * region: from its mass-weighted mean displacement, so travelling is not a blow-up), or kinetic energy above
 * 0.5 M (10 diag / frame_dt)^2 (a mean speed of ten diagonals per frame); returns the kind (SQ_HEALTH_NONE: healthy) */
sq_health_kind sq_body_diverged(const sq_body *b, double *value)
{
    double dlim2 = 100 * b->diag * b->diag;
    for (int k = 0; k < SQ_MAX_LEVELS; k++) {
        if (!b->ready[k])
            continue;
        if (b->def.lod.mode == SQ_LOD_FIXED && k != b->cur)
            continue;
        const sq_level *L = &b->level[k];
        double ke = 0, M = 0;
        /* adaptive: the active nodes (ghosts are combinations of them) */
        int na = L->model.n;
        const int *al = b->lod ? sq_lod_active_list(b->lod, k, &na) : NULL;
        double mean[3] = {0, 0, 0};
        if (b->def.nconstraints == 0) {
            double m = 0;
            for (int r = 0; r < na; r++) {
                int i = al ? al[r] : r;
                for (int c = 0; c < 3; c++)
                    mean[c] += L->model.mass[i] * L->state.d[3 * (size_t)i + c];
                m += L->model.mass[i];
            }
            for (int c = 0; c < 3; c++)
                mean[c] = m > 0 && isfinite(mean[c]) ? mean[c] / m : 0;
        }
        for (int r = 0; r < na; r++) {
            int i = al ? al[r] : r;
            const double *d = L->state.d + 3 * (size_t)i, *v = L->state.v + 3 * (size_t)i;
            double e[3] = {d[0] - mean[0], d[1] - mean[1], d[2] - mean[2]};
            double dd = e[0] * e[0] + e[1] * e[1] + e[2] * e[2];
            double vv = v[0] * v[0] + v[1] * v[1] + v[2] * v[2];
            if (!isfinite(dd) || !isfinite(vv)) {
                *value = (double)i;
                return SQ_HEALTH_BLOWUP_NAN;
            }
            if (dd > dlim2) {
                *value = sqrt(dd);
                return SQ_HEALTH_BLOWUP_STRETCH;
            }
            ke += 0.5 * L->model.mass[i] * vv;
            M += L->model.mass[i];
        }
        double vlim = 10 * b->diag / b->def.frame_dt;
        if (ke > 0.5 * M * vlim * vlim) {
            *value = ke;
            return SQ_HEALTH_BLOWUP_SPEED;
        }
    }
    return SQ_HEALTH_NONE;
}

sq_health_kind sq_body_diverged_now(sq_body *b, double *value)
{
    if (b->div_frame != b->frames) {
        b->div_kind = sq_body_diverged(b, &b->div_value);
        b->div_frame = b->frames;
    }
    *value = b->div_value;
    return b->div_kind;
}

/* count a health warning of this frame */
void sq_body_count_health(sq_body *b, sq_health_kind k, double value)
{
    if (k <= SQ_HEALTH_NONE || k >= SQ_HEALTH_NKINDS)
        return;
    b->health[k].count++;
    b->health[k].last_value = value;
    b->health[k].last_frame = b->frames;
}

/* after the frame's steps: health (a blow-up resets the body to rest: returns 1) and sleep
 * (calm, slow and balanced with no tool, for sleep_frames frames in a row); sets prof's event */
int sq_body_check_health(sq_body *b, sq_frame_profile *prof, int nholds)
{
    double value = 0;
    sq_health_kind why = prof->sleeping ? SQ_HEALTH_NONE : sq_body_diverged_now(b, &value);
    if (why != SQ_HEALTH_NONE) {
        sq_body_reset(b);
        prof->reset = 1;
        sq_frame_event(prof, why, value, 0, 0, 0, b->name);
        sq_body_count_health(b, why, value);
        return 1;
    } else if (!prof->sleeping) {
        /* sleep: calm (slow and balanced) with no tool for sleep_frames frames in a row */
        double ke = sq_body_kinetic_energy(b), M = 0, res = 0;
        for (int k = 0; k < SQ_MAX_LEVELS; k++) {
            if (!b->ready[k] || (b->def.lod.mode == SQ_LOD_FIXED && k != b->cur))
                continue;
            int na = b->level[k].model.n;
            const int *al = b->lod ? sq_lod_active_list(b->lod, k, &na) : NULL;
            for (int r = 0; r < na; r++)
                M += b->level[k].model.mass[al ? al[r] : r];
            /* nodes in contact carry the contact's reaction: not a residual */
            res = SQ_MAX(res, sq_level_residual(&b->level[k].model, b->level[k].state.f, b->def.gravity, al, na,
                                                b->touched[k]));
        }
        double vrms = M > 0 ? sqrt(2 * ke / M) : 0;
        int calm = nholds == 0 && vrms < b->sleep_ke_speed * b->diag && res < b->sleep_residual;
        b->calm = calm ? b->calm + 1 : 0;
        if (b->sleep_frames > 0 && b->calm >= b->sleep_frames) {
            b->sleeping = 1;
            sq_frame_event(prof, SQ_HEALTH_SLEEP, b->calm, 0, 0, 0, b->name);
            sq_body_count_health(b, SQ_HEALTH_SLEEP, b->calm);
        }
    }
    return 0;
}
