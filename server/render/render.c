/* render.c - one-call entry points: a state (or a world) to PNG bytes. */
#include <pthread.h>
#include <stdlib.h>

#include "render/render.h"

/* one render at a time per process: bounds memory and CPU use of snapshot requests */
static pthread_mutex_t render_lock = PTHREAD_MUTEX_INITIALIZER;

int sq_render_state_png(const sq_render_state *s, int width, int height, const sq_render_opts *o,
                        unsigned char **png, size_t *len, sq_err *err)
{
    *png = NULL;
    *len = 0;
    if (width < SQ_RENDER_MIN_SIZE || height < SQ_RENDER_MIN_SIZE || width > SQ_RENDER_MAX_SIZE ||
        height > SQ_RENDER_MAX_SIZE)
        return sq_err_set(err, "render: size %dx%d: each side must be in [%d, %d] pixels", width,
                          height, SQ_RENDER_MIN_SIZE, SQ_RENDER_MAX_SIZE);
    sq_render_opts def;
    if (!o) {
        def = sq_render_opts_default();
        o = &def;
    }
    sq_drawlist dl = {0};
    if (sq_drawlist_build(&dl, s, o, (double)width / height, err) != 0) {
        sq_drawlist_free(&dl);
        return -1;
    }
    unsigned char *rgb = sq_malloc((size_t)width * height * 3);
    int rc = -1;
    pthread_mutex_lock(&render_lock);
    sq_renderer *r = sq_renderer_create(width, height, o->supersample, err);
    if (r) {
        rc = sq_renderer_draw(r, &dl, rgb, err);
        sq_renderer_destroy(r);
    }
    pthread_mutex_unlock(&render_lock);
    if (rc == 0)
        rc = sq_png_encode(rgb, width, height, png, len, err);
    free(rgb);
    sq_drawlist_free(&dl);
    return rc;
}

int sq_render_world_png(const sq_world *w, int width, int height, const sq_render_opts *o,
                        unsigned char **png, size_t *len, sq_err *err)
{
    *png = NULL;
    *len = 0;
    if (width < SQ_RENDER_MIN_SIZE || height < SQ_RENDER_MIN_SIZE || width > SQ_SNAPSHOT_MAX_SIZE ||
        height > SQ_SNAPSHOT_MAX_SIZE)
        return sq_err_set(err, "snapshot: size %dx%d: each side must be in [%d, %d] pixels",
                          width, height, SQ_RENDER_MIN_SIZE, SQ_SNAPSHOT_MAX_SIZE);
    sq_render_state s;
    sq_render_state_init(&s);
    int rc = sq_render_state_capture(&s, w, err);
    if (rc == 0)
        rc = sq_render_state_png(&s, width, height, o, png, len, err);
    sq_render_state_free(&s);
    return rc;
}
