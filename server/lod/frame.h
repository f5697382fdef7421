/* frame.h - the context the stages of one adaptive frame share (lod_frame): frame.c runs the
 * stages in order; guard.c (the guard stage, the budgeted split/merge decisions) and pass.c (the
 * split/merge pass) read and write it.
 * Not part of the module's contract (lod.h).
 */
#ifndef SQ_LOD_FRAME_H
#define SQ_LOD_FRAME_H

#include "lod/lod_internal.h"
#include "lod/tick.h"

/* what the stages of one frame share */
typedef struct lod_frame {
    sq_lod *lod;
    const sq_lod_frame_in *in;
    double (*force)[3];              /* feedback force of each tool, N (in->ntools), or NULL */
    /* clocks */
    double t_start, c_start;         /* wall and thread CPU time at the start of the frame, s */
    double mark;                     /* wall time the last timed stage ended, s */
    double t[SQ_LOD_STAGES];         /* wall time of each stage, s */
    /* guard */
    double prev_time;                /* CPU time of the previous frame, s */
    int over_budget;                 /* 1: the previous frame was over budget, no splits */
    long cap_user, cap_guard;        /* the user's node-update cap; the guard's (0: none) */
    double c_ticks;                  /* thread CPU time of the ticks (pull, step), s */
    double c_pass;                   /* thread CPU time of the split/merge passes' rebuilds, s */
    double c_mark;                   /* thread CPU time the last non-tick stage ended, s */
    unsigned rebuilt;                /* levels rebuilt by this frame's passes (bit k) */
    int passes;                      /* split/merge passes rebuilt (0, 1 or 2) */
    int unmeasured;                  /* 1: the pass running learns no cost (calibrate's warm-up) */
    long guard_merges;               /* regions the guard merged this frame */
    /* layout and clock */
    long projected;                  /* node updates one frame of the current layout costs */
    adapt_out ao;                    /* splits, merges, refusals, levels whose layout changed */
    long nticks, tick;               /* finest substeps of the frame; the current one */
    long stride[SQ_MAX_LEVELS];      /* level k steps every stride[k] ticks */
    sq_tick_count tc;                /* node integrations and the interface's work so far (tick.c) */
    double fr_budget;                /* def.budget x in->budget_s, s */
    int guard_on;                    /* a budget and a measured (or given) cost per update */
    double modeled_pass;             /* the model's cost of this frame's passes, s */
    double outside_raw;              /* thread CPU time since the last frame's end, s */
    double c_reserve;                /* thread CPU time of the coupling arrays' reserve, s */
    long reserved_pages;             /* pages it mapped */
    double c_owed;                   /* thread CPU time of the owed sharp estimates, s */
    int sharp_made;                  /* owed sharp estimates made at this frame's end */
    double u0_user, u0_sys;          /* guard_trace: the thread's user, system time at the start */
    long u0_flt, u0_ivcsw;           /* ... its minor faults and involuntary context switches */
} lod_frame;

#endif
