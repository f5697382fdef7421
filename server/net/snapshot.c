/* snapshot.c - the render worker behind GET /snapshot.png.
 *
 * A session thread captures its world into a sq_render_state (a cheap copy) between two
 * frames; this worker thread renders captured states to PNG one at a time, off both the
 * simulation threads and the lws service thread, and hands the results back through a
 * mutex-protected list plus a wake-up of the service thread.
 */
#include "net/snapshot.h"

#include <stdio.h>
#include <stdlib.h>
#include <string.h>

struct sq_snapshotter {
    pthread_t thread;
    pthread_mutex_t mu;
    pthread_cond_t cv;
    int stop;
    sq_snap_job *todo;       /* FIFO (linked) */
    sq_snap_job *done;       /* finished, for the service thread */
    void (*wake)(void *);
    void *wake_arg;
};

static void *worker(void *arg)
{
    sq_snapshotter *z = arg;
    pthread_mutex_lock(&z->mu);
    for (;;) {
        while (!z->stop && !z->todo)
            pthread_cond_wait(&z->cv, &z->mu);
        if (z->stop)
            break;
        sq_snap_job *j = z->todo;
        z->todo = j->next;
        pthread_mutex_unlock(&z->mu);

        sq_err err = {{0}};
        if (j->state && sq_render_state_png(j->state, j->width, j->height, NULL, &j->png,
                                            &j->png_len, &err))
            snprintf(j->error, sizeof j->error, "%.250s", err.msg);
        if (j->state) {
            sq_render_state_free(j->state);
            free(j->state);
            j->state = NULL;
        }

        pthread_mutex_lock(&z->mu);
        j->next = z->done;
        z->done = j;
        pthread_mutex_unlock(&z->mu);
        z->wake(z->wake_arg);
        pthread_mutex_lock(&z->mu);
    }
    pthread_mutex_unlock(&z->mu);
    return NULL;
}

sq_snapshotter *sq_snapshotter_start(void (*wake)(void *), void *wake_arg)
{
    sq_snapshotter *z = sq_calloc(1, sizeof *z);
    z->wake = wake;
    z->wake_arg = wake_arg;
    pthread_mutex_init(&z->mu, NULL);
    pthread_cond_init(&z->cv, NULL);
    if (pthread_create(&z->thread, NULL, worker, z)) {
        pthread_mutex_destroy(&z->mu);
        pthread_cond_destroy(&z->cv);
        free(z);
        return NULL;
    }
    return z;
}

void sq_snapshotter_submit(sq_snapshotter *z, sq_snap_job *j)
{
    pthread_mutex_lock(&z->mu);
    j->next = NULL;
    if (!j->state) {
        /* nothing to render (capture failed): straight to done */
        j->next = z->done;
        z->done = j;
        pthread_mutex_unlock(&z->mu);
        z->wake(z->wake_arg);
        return;
    }
    sq_snap_job **p = &z->todo;
    while (*p)
        p = &(*p)->next;
    *p = j;
    pthread_cond_signal(&z->cv);
    pthread_mutex_unlock(&z->mu);
}

sq_snap_job *sq_snapshotter_take(sq_snapshotter *z)
{
    pthread_mutex_lock(&z->mu);
    sq_snap_job *d = z->done;
    z->done = NULL;
    pthread_mutex_unlock(&z->mu);
    return d;
}

void sq_snap_job_free(sq_snap_job *j)
{
    if (!j)
        return;
    if (j->state) {
        sq_render_state_free(j->state);
        free(j->state);
    }
    free(j->png);
    free(j);
}

void sq_snapshotter_stop(sq_snapshotter *z)
{
    if (!z)
        return;
    pthread_mutex_lock(&z->mu);
    z->stop = 1;
    pthread_cond_broadcast(&z->cv);
    pthread_mutex_unlock(&z->mu);
    pthread_join(z->thread, NULL);
    for (sq_snap_job *j = z->todo, *n; j; j = n) {
        n = j->next;
        sq_snap_job_free(j);
    }
    for (sq_snap_job *j = z->done, *n; j; j = n) {
        n = j->next;
        sq_snap_job_free(j);
    }
    pthread_mutex_destroy(&z->mu);
    pthread_cond_destroy(&z->cv);
    free(z);
}
