/* snapshot.h - render worker for GET /snapshot.png (internal to server/net). */
#ifndef SQ_NET_SNAPSHOT_H
#define SQ_NET_SNAPSHOT_H

#include <pthread.h>
#include <stdint.h>

#include "render/render.h"

/* one snapshot request: captured by a session thread, rendered by the worker, answered by
 * the service thread */
typedef struct sq_snap_job {
    uint64_t id;                 /* the HTTP request it answers */
    int width, height;
    sq_render_state *state;      /* owned; NULL when the capture failed (error says why) */
    unsigned char *png;          /* result (malloc), png_len bytes */
    size_t png_len;
    char error[256];             /* empty on success */
    struct sq_snap_job *next;
} sq_snap_job;

typedef struct sq_snapshotter sq_snapshotter;

/* start the worker; wake(arg) is called (from the worker) when a result is ready */
sq_snapshotter *sq_snapshotter_start(void (*wake)(void *), void *wake_arg);
/* queue a job (any thread); the worker owns it until sq_snapshotter_take returns it */
void sq_snapshotter_submit(sq_snapshotter *z, sq_snap_job *j);
/* finished jobs (linked by next), for the service thread; the caller frees them */
sq_snap_job *sq_snapshotter_take(sq_snapshotter *z);
void sq_snap_job_free(sq_snap_job *j);
/* stop the worker and free pending jobs */
void sq_snapshotter_stop(sq_snapshotter *z);

#endif
