/* reserve.c - the coupling arrays' pages mapped ahead of use (docs/lod.md "Guaranteed frame
 * rate"): at load and at the end of a budgeted frame with room, each array a split/merge pass
 * writes is grown ahead of need and its pages touched, so that no pass pays first-touch page
 * faults (coupling.c builds into them; frame.c calls the reserve). */
#include "lod/lod.h"
#include "lod/reserve.h"
#include "lod/tick.h"

#include <math.h>
#include <stdlib.h>
#include <string.h>


/* A first touch of a page costs 12-15 us on this kind of machine (a page fault): a pass whose
 * rows outgrow an array, or whose element blocks open a new cache chunk, paid 400-570 faults
 * (4-5 ms) on box-big, 2-4x its model. So every array a pass writes is grown ahead of need,
 * with its pages mapped, at load (the first build) and at the end of a budgeted frame that has
 * room (frame.c): each holds at least RESERVE_FLOOR blocks (capped at the level's adjacency
 * blocks, the most a level can need) and, once its use passes half its capacity, is grown to
 * RESERVE_GROW x its use; the element-block cache keeps a mapped chunk ahead once fewer than
 * half a chunk of slots are left. A pass then grows (and faults) only when the layout jumps
 * by more than that between two frames with room. At load (sq_lod_prepare_budget) the two
 * caches, which only grow as a refinement reaches new tets and rows, get SQ_RESERVE_LOAD_CHUNKS
 * chunks ahead instead of one: box-big's frames then mapped 1.0 ms of pages in a run instead
 * of 47.7 ms (about 3,100 pages in 11 chunks), for 35 MB more held from load (peak RSS 633 ->
 * 668 MB). */
#define RESERVE_FLOOR 32768 /* 4096 before: box-big (levels box_12-box_48, budgeted, 100 frames)
                             * then mapped 71-81 ms of pages in the frames' reserve, 35-37 ms
                             * with 32768, for 52 MB more held (peak RSS 570 -> 624 MB): the
                             * pages are mapped at load (sq_lod_prepare_budget) instead */
#define RESERVE_GROW 3
#define PAGE_BYTES 4096

/* write each page of p[from, to) bytes once (the contents there are free: past the use) */
static long touch_pages(void *p, size_t from, size_t to)
{
    volatile unsigned char *c = p;
    long n = 0;
    for (size_t b = from; b < to; b += PAGE_BYTES - (b % PAGE_BYTES), n++)
        c[b] = 0;
    return n;
}

/* map the pages of live data (each page read and written back: the contents are kept) */
static long keep_pages(void *p, size_t bytes)
{
    volatile unsigned char *c = p;
    long n = 0;
    for (size_t b = 0; p && b < bytes; b += PAGE_BYTES - (b % PAGE_BYTES), n++)
        c[b] = c[b];
    return n;
}

long sq_lodx_map_state(sq_lod *lod)
{
    long pages = 0;
    for (int k = 0; k < lod->L; k++) {
        sq_level *L = &lod->lv[k];
        sq_lod_level *lk = &lod->lev[k];
        size_t n = (size_t)L->model.n, n3 = 3 * n * sizeof(double);
        double *w = sq_lodx_tick_w(lod, k); /* (made on first use otherwise, sq_lodx_form_w) */
        void *const a[] = {L->state.d, L->state.v, L->state.f, L->state.acc, lk->tk.d_start, lk->tk.v_start, w};
        for (size_t i = 0; i < sizeof a / sizeof a[0]; i++)
            pages += keep_pages(a[i], n3);
        pages += keep_pages(lk->lists.push_stamp, n * sizeof(unsigned));
        pages += keep_pages(lk->lists.in_needed, n);
        pages += keep_pages(lk->lists.mark, n);
    }
    return pages;
}

/* the pages a reserve of one array would write: 0 when it needs nothing */
static long reserve_pages(int cap, const void *p, long used, long limit, size_t size, long *want)
{
    long w = SQ_MIN(SQ_MAX((long)RESERVE_FLOOR, used > 0 ? RESERVE_GROW * used : 0), limit);
    w = SQ_MAX(w, 1);
    if (p && cap >= w && (2 * used <= cap || cap >= limit)) {
        *want = cap;
        return 0;
    }
    *want = SQ_MAX(w, cap);
    /* at most: the new pages, and the used ones if the grown array is copied */
    return (long)((size_t)*want * size / PAGE_BYTES + 1);
}

/* one array: grown to *want elements of size bytes and its pages past the first `used`
 * written; returns the new pointer */
static void *reserve_one(void *p, int *cap, long want, long used, size_t size, long *pages)
{
    if (want > *cap || !p) {
        p = sq_realloc(p, size * (size_t)want);
        *cap = (int)want;
    }
    *pages += touch_pages(p, size * (size_t)used, size * (size_t)*cap);
    return p;
}

/* the last element-block chunk of a level mapped from where the last call stopped (never
 * over slots in use), 16 pages at a time while the thread CPU since c0 is under seconds;
 * returns the pages left */
static long map_chunk(sq_lod_level *lk, size_t chunk, size_t per, double c0, double seconds, long *pages)
{
    if (lk->cpl.blocks_nchunk == 0 || lk->cpl.blocks_mapped >= chunk)
        return 0;
    unsigned char *ch = (unsigned char *)lk->cpl.blocks_chunk[lk->cpl.blocks_nchunk - 1];
    size_t live = (size_t)SQ_MAX(lk->cpl.blocks_used - (lk->cpl.blocks_nchunk - 1) * SQ_BLOCKS_CHUNK, 0) * sizeof(double) * per;
    size_t from = lk->cpl.blocks_mapped > live ? lk->cpl.blocks_mapped : live;
    while (from < chunk && sq_thread_cpu() - c0 < seconds) {
        size_t to = from + 16 * PAGE_BYTES < chunk ? from + 16 * PAGE_BYTES : chunk;
        *pages += touch_pages(ch, from, to);
        from = to;
    }
    lk->cpl.blocks_mapped = from;
    return (long)((chunk - from) / PAGE_BYTES);
}

/* the column-form row cache of the inner rows (activeset.c's krow): its node index made, and a
 * whole chunk kept ahead of its use, mapped 16 pages at a time within the time given (the
 * cache fills in the ticks after a pass, on a node's first use as an inner node: a chunk
 * opened there, 1.5 MB, paid its first touches in that frame); returns the pages left */
static long reserve_krow(sq_lod_level *lk, const sq_level_model *M, double c0, double seconds, int ahead,
                         long *pages)
{
    if (sq_lodx_krow_index(lk, M))
        *pages += (long)(sizeof(int) * (size_t)M->n / PAGE_BYTES + 1);
    long CH = sq_lodx_krow_chunk_len(lk, M);
    size_t chunk = sizeof(double) * 12 * (size_t)CH;
    long left = 0;
    for (int round = 0; round <= ahead; round++) {
        /* the last chunk's pages past its use, from where the last call stopped */
        if (lk->cpl.krow_nchunk > 0 && lk->cpl.krow_mapped < chunk) {
            unsigned char *ch = (unsigned char *)lk->cpl.krow_chunk[lk->cpl.krow_nchunk - 1];
            long base = (long)(lk->cpl.krow_nchunk - 1) * CH;
            size_t live = lk->cpl.krow_used > base ? sizeof(double) * 12 * (size_t)(lk->cpl.krow_used - base) : 0;
            size_t from = lk->cpl.krow_mapped > live ? lk->cpl.krow_mapped : live;
            while (from < chunk && sq_thread_cpu() - c0 < seconds) {
                size_t to = from + 16 * PAGE_BYTES < chunk ? from + 16 * PAGE_BYTES : chunk;
                *pages += touch_pages(ch, from, to);
                from = to;
            }
            lk->cpl.krow_mapped = from;
            left = (long)((chunk - from) / PAGE_BYTES);
        }
        /* a new chunk once less than `ahead` whole ones are left (not past the level's rows) */
        if (round == ahead || lk->cpl.krow_cap - lk->cpl.krow_used >= ahead * CH || lk->cpl.krow_cap >= (long)M->row_start[M->n] ||
            (lk->cpl.krow_nchunk > 0 && lk->cpl.krow_mapped < chunk) || sq_thread_cpu() - c0 >= seconds)
            break;
        lk->cpl.krow_chunk = sq_realloc(lk->cpl.krow_chunk, sizeof(double *) * (size_t)(lk->cpl.krow_nchunk + 1));
        lk->cpl.krow_chunk[lk->cpl.krow_nchunk++] = sq_malloc(chunk);
        lk->cpl.krow_cap = (long)lk->cpl.krow_nchunk * CH;
        lk->cpl.krow_mapped = 0;
    }
    return left;
}

long sq_lodx_reserve_blocks(sq_lod *lod, double seconds, int ahead)
{
    double c0 = sq_thread_cpu();
    long flt0 = sq_minor_faults();
    lod->reserve.cost_fault = fmax(lod->reserve.cost_fault, 15e-6); /* measured 12-15 us here: at least that */
    long pages = 0, pending = 0, bytes = 0;
    for (int k = 0; k < lod->L; k++) {
        sq_lod_level *lk = &lod->lev[k];
        const sq_level *L = &lod->lv[k];
        int visc = lod->cpl.have_mat && lod->cpl.mat.use_viscosity && L->model.D;
        long limit = SQ_MAX((long)L->model.row_start[L->model.n], 1);
        long ring_used = lk->cpl.ring_off && lk->cpl.blocks_valid ? lk->cpl.ring_off[lk->lay.nring] : 0;
        long front_used = lk->cpl.front_off && lk->cpl.blocks_valid ? lk->cpl.front_off[lk->lay.nfrontier] : 0;
        long merged_used = 0;
        for (int r = 0; r < lk->lay.nfrontier && lk->cpl.blocks_valid; r++)
            merged_used += L->model.row_start[lk->lay.frontier[r] + 1] - L->model.row_start[lk->lay.frontier[r]];
        /* each array: pointer, capacity, the elements in use (0 for the previous build's
         * arrays, free between builds), element size */
        struct {
            void **p;
            int *cap;
            long used;
            size_t size;
        } a[] = {
            {(void **)&lk->cpl.ring_col, &lk->cpl.ring_col_cap, ring_used, sizeof(int)},
            {(void **)&lk->cpl.ring_col2, &lk->cpl.ring_col2_cap, 0, sizeof(int)},
            {(void **)&lk->cpl.ring_K, &lk->cpl.ring_K_cap, ring_used, 9 * sizeof(double)},
            {(void **)&lk->cpl.ring_K2, &lk->cpl.ring_K2_cap, 0, 9 * sizeof(double)},
            {(void **)&lk->cpl.ring_T, &lk->cpl.ring_T_cap, ring_used, 12 * sizeof(double)},
            {(void **)&lk->cpl.ring_T2, &lk->cpl.ring_T2_cap, 0, 12 * sizeof(double)},
            {(void **)&lk->cpl.front_col, &lk->cpl.front_col_cap, front_used, sizeof(int)},
            {(void **)&lk->cpl.front_col2, &lk->cpl.front_col2_cap, 0, sizeof(int)},
            {(void **)&lk->cpl.front_K, &lk->cpl.front_K_cap, front_used, 9 * sizeof(double)},
            {(void **)&lk->cpl.front_K2, &lk->cpl.front_K2_cap, 0, 9 * sizeof(double)},
            {(void **)&lk->cpl.front_merged, &lk->cpl.front_merged_cap, merged_used, 9 * sizeof(double)},
            {(void **)&lk->cpl.front_merged2, &lk->cpl.front_merged2_cap, 0, 9 * sizeof(double)},
            {(void **)&lk->cpl.front_T, &lk->cpl.front_T_cap, merged_used, 12 * sizeof(double)},
            {(void **)&lk->cpl.front_T2, &lk->cpl.front_T2_cap, 0, 12 * sizeof(double)},
            {(void **)&lk->cpl.ring_D, &lk->cpl.ring_D_cap, ring_used, 9 * sizeof(double)},
            {(void **)&lk->cpl.ring_D2, &lk->cpl.ring_D2_cap, 0, 9 * sizeof(double)},
            {(void **)&lk->cpl.front_D, &lk->cpl.front_D_cap, front_used, 9 * sizeof(double)},
            {(void **)&lk->cpl.front_D2, &lk->cpl.front_D2_cap, 0, 9 * sizeof(double)},
        };
        int na = visc ? 18 : 14; /* the viscous blocks only with viscosity */
        for (int i = 0; i < na; i++) {
            /* the previous build's arrays follow the current one's use */
            long used = a[i].used, want;
            long ref = (i & 1) ? a[i - 1].used : used;
            long np = reserve_pages(*a[i].cap, *a[i].p, ref, limit, a[i].size, &want);
            if (np > 0 && (double)np * lod->reserve.cost_fault > seconds - (sq_thread_cpu() - c0)) {
                pending += np;
            } else if (np > 0) {
                *a[i].p = reserve_one(*a[i].p, a[i].cap, want, used, a[i].size, &pages);
            }
            bytes += (long)a[i].size * *a[i].cap;
        }
        /* the element-block cache: a chunk ahead, mapped a few pages at a time within the
         * time given, the rest at a later frame (a page costs 8-35 us here, with the load;
         * slots are cleared when handed out, so the writes are free) */
        size_t per = visc ? 288 : 144, chunk = sizeof(double) * per * SQ_BLOCKS_CHUNK;
        if (lk->cpl.blocks_nchunk == 0)
            lk->cpl.blocks_per = (int)per; /* (tet_blocks makes the chunks again for another size) */
        if (lk->cpl.blocks_per == (int)per)
            pending += map_chunk(lk, chunk, per, c0, seconds, &pages);
        long slack = ahead > 1 ? (long)ahead * SQ_BLOCKS_CHUNK : SQ_BLOCKS_CHUNK / 2;
        while (lk->cpl.blocks_per == (int)per && lk->cpl.blocks_cap - lk->cpl.blocks_used < slack &&
               lk->cpl.blocks_cap < L->model.mesh->ntets && (lk->cpl.blocks_nchunk == 0 || lk->cpl.blocks_mapped >= chunk) &&
               sq_thread_cpu() - c0 < seconds) {
            lk->cpl.blocks_chunk = sq_realloc(lk->cpl.blocks_chunk, sizeof(double *) * (size_t)(lk->cpl.blocks_nchunk + 1));
            lk->cpl.blocks_chunk[lk->cpl.blocks_nchunk++] = sq_malloc(chunk);
            lk->cpl.blocks_cap += SQ_BLOCKS_CHUNK;
            lk->cpl.blocks_mapped = 0;
            pending += map_chunk(lk, chunk, per, c0, seconds, &pages);
        }
        bytes += (long)(sizeof(double) * (size_t)SQ_MAX(lk->cpl.blocks_per, 0)) * lk->cpl.blocks_cap;
        /* the inner rows' column-form cache (no viscosity: the viscous pass does not read it) */
        if (!visc && !L->state.corot)
            pending += reserve_krow(lk, &L->model, c0, seconds, ahead, &pages);
        bytes += (long)(sizeof(double) * 12) * lk->cpl.krow_cap + (lk->cpl.krow_at ? (long)sizeof(int) * L->model.n : 0);
    }
    double spent = sq_thread_cpu() - c0;
    long faults = sq_minor_faults() - flt0;
    if (faults >= 64) /* what a page costs here (a fault and the copies of grown arrays) */
        lod->reserve.cost_fault = fmax(spent / (double)faults, 0.9 * lod->reserve.cost_fault);
    lod->reserve.reserve_pending = pending;
    lod->reserve.reserve_bytes = bytes;
    return pages;
}

long sq_lodx_reserve_live(sq_lod *lod)
{
    lod->reserve.reserve_live = 1;
    return sq_lodx_reserve_blocks(lod, 1e9, SQ_RESERVE_LOAD_CHUNKS) + sq_lodx_map_state(lod);
}
