/* holds.c - stage: tool holds onto the active nodes (docs/lod.md, "Tools").
 *
 * A hold arrives on a finest node; it goes to the node itself when it is active, else the
 * same translation goes to its active ancestor (map_hold); the held nodes are prescribed at
 * the start of the frame (start_holds) and not integrated; their internal force is summed over
 * their level's substeps for the tool feedback; clear_holds forgets them at the frame's end.
 * The frame calls sq_lodx_hold_start (its holds stage), sq_lodx_hold_sample (at each step of
 * a level) and sq_lodx_hold_end (its feedback stage).
 */
#include "lod/lod.h"
#include "lod/activeset.h"
#include "lod/holds.h"

#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>


/* ---------------------------------------------------------------- tool holds */

/* the active node standing for finest node j: itself or its active ancestor; -1 if none */
static int active_of_finest(const sq_lod *lod, int j, int *level)
{
    int k = lod->L - 1, a = j;
    while (lod->lev[k].lay.state[a] != ST_ACTIVE) {
        if (k == 0)
            return -1;
        a = lod->h.link[k - 1].parent[a];
        k--;
    }
    *level = k;
    return a;
}

/* map hold h (at time t_now within the frame) onto its active node; adds to that node's entry */
static void map_hold(sq_lod *lod, const sq_hold *hd, int h, double t_now)
{
    int F = lod->L - 1, k;
    int a = active_of_finest(lod, hd->node, &k);
    if (a < 0) {
        lod->holds.hold_entry_of[h] = -1;
        return;
    }
    sq_level *Lk = &lod->lv[k];
    const double *dj = lod->lv[F].state.d + 3 * hd->node;
    int e = lod->lev[k].lay.hold_of[a];
    if (e < 0) {
        if (lod->holds.nhe == lod->holds.cap_he) {
            lod->holds.cap_he = lod->holds.cap_he ? 2 * lod->holds.cap_he : 64;
            lod->holds.he = sq_realloc(lod->holds.he, sizeof(hold_entry) * (size_t)lod->holds.cap_he);
        }
        e = lod->holds.nhe++;
        hold_entry *E = &lod->holds.he[e];
        memset(E, 0, sizeof(*E));
        E->level = k;
        E->node = a;
        E->t_from = t_now;
        memcpy(E->from, Lk->state.d + 3 * a, sizeof(E->from));
        lod->lev[k].lay.hold_of[a] = e;
        if (lod->lev[k].lay.integrated[a]) {
            lod->lev[k].lay.integrated[a] = 0;
            lod->lev[k].lay.nintegrated--;
        }
    }
    hold_entry *E = &lod->holds.he[e];
    /* the hold node itself takes its target; an ancestor the same translation */
    for (int c = 0; c < 3; c++)
        E->gsum[c] += (k == F && a == hd->node) ? hd->target[c]
                                                : Lk->state.d[3 * a + c] + (hd->target[c] - dj[c]);
    E->count++;
    E->pending = 1;
    lod->holds.hold_entry_of[h] = e;
}

/* prescribe the nodes whose targets changed: d = mean target, v = (d - from) / time left */
static void start_holds(sq_lod *lod, double T)
{
    for (int e = 0; e < lod->holds.nhe; e++) {
        hold_entry *E = &lod->holds.he[e];
        if (!E->pending || E->count == 0)
            continue;
        E->pending = 0;
        sq_level *Lk = &lod->lv[E->level];
        double span = T - E->t_from;
        unsigned char fx = Lk->model.fixed[E->node];
        double goal[3];
        for (int c = 0; c < 3; c++)
            goal[c] = E->gsum[c] / E->count;
        sq_level_apply_hold(&Lk->model, &Lk->state, E->node, goal, E->from, span); /* constrained axes stay at rest */
        for (int c = 0; c < 3; c++) {
            if (fx & (1u << c))
                continue;
            lod->lev[E->level].tk.d_start[3 * E->node + c] = Lk->state.d[3 * E->node + c];
            lod->lev[E->level].tk.v_start[3 * E->node + c] = Lk->state.v[3 * E->node + c];
        }
    }
}

static void clear_holds(sq_lod *lod)
{
    for (int e = 0; e < lod->holds.nhe; e++)
        if (lod->lev[lod->holds.he[e].level].lay.hold_of[lod->holds.he[e].node] == e)
            lod->lev[lod->holds.he[e].level].lay.hold_of[lod->holds.he[e].node] = -1;
    lod->holds.nhe = 0;
}

/* the frame's holds: every level's integration mask reset to its active nodes, each hold
 * mapped onto its active node (holds out of range ignored), the held nodes prescribed over
 * frame_dt and left out of the integrated lists */
void sq_lodx_hold_start(sq_lod *lod, const sq_hold *holds, int nholds, int ntools, double frame_dt)
{
    int L = lod->L, F = L - 1;
    clear_holds(lod);
    if (nholds > lod->holds.cap_holds) {
        lod->holds.cap_holds = nholds;
        lod->holds.hold_entry_of = sq_realloc(lod->holds.hold_entry_of, sizeof(int) * (size_t)nholds);
    }
    for (int k = 0; k < L; k++) {
        lod->lev[k].lay.nintegrated = lod->lev[k].lay.nactive;
        memcpy(lod->lev[k].lay.integrated, lod->lev[k].lay.active, (size_t)lod->lv[k].model.n);
    }
    for (int h = 0; h < nholds; h++) {
        lod->holds.hold_entry_of[h] = -1;
        if (holds[h].node < 0 || holds[h].node >= lod->lv[F].model.n || holds[h].tool < 0 ||
            holds[h].tool >= ntools)
            continue; /* the body validates holds; ignore any that are out of range */
        map_hold(lod, &holds[h], h, 0.0);
    }
    start_holds(lod, frame_dt);
    for (int k = 0; k < L; k++)
        sq_lodx_mask_list(lod, k);
    if (lod->push.lists_dirty)
        sq_lodx_refresh_lists(lod);
}

/* at a step of level k: the internal force on its held nodes (f - m g) added to their sums */
void sq_lodx_hold_sample(sq_lod *lod, int k, const double gravity[3])
{
    const sq_level *Lk = &lod->lv[k];
    for (int e = 0; e < lod->holds.nhe; e++) {
        hold_entry *E = &lod->holds.he[e];
        if (E->level != k || E->count == 0)
            continue;
        int i = E->node;
        for (int c = 0; c < 3; c++)
            E->fsum[c] += Lk->state.f[3 * i + c] - Lk->model.mass[i] * gravity[c];
        E->nf++;
    }
}

/* the frame's end: force[tool] += the mean internal force on each hold's node over its
 * substeps, shared among the holds mapped there (force may be NULL); holds released and
 * the integration masks back to the active nodes */
void sq_lodx_hold_end(sq_lod *lod, const sq_hold *holds, int nholds, double (*force)[3])
{
    for (int h = 0; force && h < nholds; h++) {
        int e = lod->holds.hold_entry_of[h];
        if (e < 0 || lod->holds.he[e].count == 0 || lod->holds.he[e].nf == 0)
            continue;
        const hold_entry *E = &lod->holds.he[e];
        for (int c = 0; c < 3; c++)
            force[holds[h].tool][c] += E->fsum[c] / E->nf / E->count;
    }
    clear_holds(lod);
    for (int k = 0; k < lod->L; k++)
        if (lod->lev[k].lay.nintegrated != lod->lev[k].lay.nactive) {
            memcpy(lod->lev[k].lay.integrated, lod->lev[k].lay.active, (size_t)lod->lv[k].model.n);
            lod->lev[k].lay.nintegrated = lod->lev[k].lay.nactive;
        }
}

/* at a tick of a frame with live holds: each entry with a live hold takes its goal plus the
 * mean change of its holds' targets (constrained axes stay) */
void sq_lodx_hold_live(sq_lod *lod, const sq_lod_frame_in *in, double frac)
{
    const unsigned char *on;
    const double *target;
    if (!in->live(in->live_arg, frac, &on, &target))
        return;
    for (int h = 0; h < in->nholds; h++) {
        int e = lod->holds.hold_entry_of[h];
        if (on[h] && e >= 0) {
            memset(lod->holds.he[e].shift, 0, sizeof lod->holds.he[e].shift);
            lod->holds.he[e].live = 1;
        }
    }
    for (int h = 0; h < in->nholds; h++) {
        int e = lod->holds.hold_entry_of[h];
        if (on[h] && e >= 0)
            for (int c = 0; c < 3; c++)
                lod->holds.he[e].shift[c] += target[3 * (size_t)h + c] - in->holds[h].target[c];
    }
    for (int e = 0; e < lod->holds.nhe; e++) {
        hold_entry *E = &lod->holds.he[e];
        if (!E->live || E->count == 0)
            continue;
        E->live = 0;
        sq_level *Lk = &lod->lv[E->level];
        unsigned char fx = Lk->model.fixed[E->node];
        for (int c = 0; c < 3; c++)
            if (!(fx & (1u << c)))
                Lk->state.d[3 * E->node + c] = (E->gsum[c] + E->shift[c]) / E->count;
    }
}
