/* render.h - headless rendering of bodies, tools, obstacles and a floor to PNG (OSMesa, llvmpipe).
 *
 * Stage after scene in the data flow. Three steps, kept apart:
 *   1. capture: copy what to draw (surface positions, levels, tools) out of a world into a
 *      sq_render_state. Cheap; done under the caller's lock on the world.
 *   2. build: turn a state into a draw list (triangles with positions, normals, colours;
 *      the floor; tools as spheres and boxes) and a camera. Pure C, no OpenGL.
 *   3. draw: rasterise a draw list with OSMesa into an RGB image, then encode it as PNG.
 * Steps 2 and 3 only read the state, so a snapshot can be rendered on any thread while
 * the simulation goes on. The output is deterministic on one machine (same state and
 * options -> byte-identical PNG).
 *
 * Colours come from one palette shared with the web viewer (web/palette.json); the
 * compiled-in default equals that file (a unit test checks it). See docs/render.md.
 */
#ifndef SQ_RENDER_H
#define SQ_RENDER_H

#include <stddef.h>

#include "scene/scene.h"

#define SQ_RENDER_MAX_SIZE 4096   /* largest image side for the command line */
#define SQ_SNAPSHOT_MAX_SIZE 2048 /* largest image side for server snapshots */
#define SQ_RENDER_MIN_SIZE 16     /* smallest image side */

/* ---- palette ---- */

/* linear 0..1 sRGB components (as written in palette.json, divided by 255) */
typedef struct sq_palette {
    float level[SQ_MAX_LEVELS][3]; /* surface colour by active level, 0 = coarsest */
    float plain[3];                /* surface colour in plain mode */
    float stress_low[3];           /* stress ramp at 0 */
    float stress_mid[3];           /* stress ramp at half the scale */
    float stress_high[3];          /* stress ramp at the scale and above */
    float background[3];
    float floor[3];                /* floor tiles */
    float floor_line[3];           /* alternate floor tiles */
    float tool[3];                 /* active tools; inactive ones are drawn at half */
    float probe[3];                /* the scene's probes (beads at their current position) */
    float obstacle[3];             /* the scene's obstacles (plane obstacles use the floor tiles) */
} sq_palette;

/* the compiled-in palette: the same values as web/palette.json */
void sq_palette_default(sq_palette *p);
/* parse palette JSON text (keys of web/palette.json; missing keys keep p's values;
 * unknown keys and bad colours are errors naming the key); label names the source */
int sq_palette_parse(sq_palette *p, const char *json, const char *label, sq_err *err);
/* read and parse a palette file */
int sq_palette_load(sq_palette *p, const char *path, sq_err *err);

/* ---- options ---- */

typedef enum sq_color_mode {
    SQ_COLOR_LEVEL = 0,  /* colour by the level of detail active at each surface vertex */
    SQ_COLOR_PLAIN = 1,  /* one colour */
    SQ_COLOR_STRESS = 2  /* |displacement| per vertex on the stress ramp (see stress_max) */
} sq_color_mode;

/* "level" | "plain" | "stress"; -1 + err otherwise */
int sq_color_mode_parse(const char *s, sq_color_mode *mode, sq_err *err);
const char *sq_color_mode_name(sq_color_mode mode);

typedef struct sq_camera {
    int eye_target;    /* 0: orbit (az, el, dist) around the bbox centre; 1: eye and target */
    double az_deg;     /* azimuth around the up axis; 0 looks from the -y side (z up) */
    double el_deg;     /* elevation above the floor plane */
    double dist;       /* distance to the target, m; <= 0 frames the bodies' bbox */
    double eye[3];     /* eye_target: camera position, m */
    double target[3];  /* eye_target: point looked at, m */
    double fov_deg;    /* vertical field of view */
} sq_camera;

/* default camera: orbit az 30, el 20, framed, fov 35 */
sq_camera sq_camera_default(void);
/* "az,el" | "az,el,dist" | "ex,ey,ez,tx,ty,tz" (degrees, metres); -1 + err otherwise */
int sq_camera_parse(const char *s, sq_camera *c, sq_err *err);

typedef struct sq_render_opts {
    sq_color_mode color;
    sq_camera camera;
    sq_palette palette;
    double stress_max;  /* stress mode: |displacement| (m) at the top of the ramp; <= 0:
                           the largest value in the frame */
    int floor;          /* draw the floor (default 1) */
    int tools;          /* draw the tools (default 1; inactive grabs are never drawn) */
    int probes;         /* draw the scene's probes (default 1) */
    int obstacles;      /* draw the scene's obstacles (default 1); a plane obstacle is drawn as a
                           tiled square in place of the default floor */
    int supersample;    /* 1..4 samples per pixel side, box-filtered (default 2) */
} sq_render_opts;

/* defaults: level colours, default camera and palette, floor and tools on, supersample 2 */
sq_render_opts sq_render_opts_default(void);

/* parse "WxH" with each side in [SQ_RENDER_MIN_SIZE, max_side]; -1 + err otherwise */
int sq_render_parse_size(const char *s, int max_side, int *width, int *height, sq_err *err);

/* ---- step 1: state (a copy of what to draw) ---- */

typedef struct sq_render_body {
    int nverts;            /* surface vertices */
    int ntris;             /* surface triangles */
    float *xyz;            /* current positions (nverts x 3), m */
    float *rest;           /* rest positions (nverts x 3), m */
    unsigned char *level;  /* active level per vertex (nverts) */
    int *tris;             /* vertex indices (ntris x 3), counter-clockwise from outside */
    int cap_verts, cap_tris; /* allocated sizes, for reuse between captures */
} sq_render_body;

/* an obstacle at its current pose; a mesh obstacle's triangles are copied (shape.mesh is NULL
 * in the state, so a state outlives the scene it was captured from) */
typedef struct sq_render_obstacle {
    sq_obstacle shape;
    int nverts, ntris;     /* mesh: vertices and triangles */
    float *xyz;            /* mesh: vertex positions (nverts x 3), m */
    int *tris;             /* mesh: vertex indices (ntris x 3) */
    int cap_verts, cap_tris; /* allocated sizes, for reuse between captures */
} sq_render_obstacle;

typedef struct sq_render_state {
    int nbodies;
    sq_render_body bodies[SQ_MAX_BODIES];
    int ntools;
    sq_tool tools[SQ_MAX_TOOLS];
    double up[3];          /* unit up vector: against gravity, +z when there is none */
    double bbox_min[3], bbox_max[3]; /* rest bounding box of all bodies (framing, floor) */
    int nprobes;
    double probes[SQ_MAX_PROBES][3]; /* probes' current positions (rest point + displacement), m */
    int nobstacles;
    sq_render_obstacle obstacles[SQ_MAX_OBSTACLES]; /* current poses */
    long frame;            /* frame number, for captions and file names */
    double time;           /* simulated time, s */
} sq_render_state;

/* empty state, up = +z */
void sq_render_state_init(sq_render_state *s);
void sq_render_state_free(sq_render_state *s);
/* append a body from arrays (copied): rest may be NULL (= xyz), level may be NULL (= 0).
 * Checks indices and counts; -1 + err naming the bad value */
int sq_render_state_add_body(sq_render_state *s, int nverts, const float *xyz, const float *rest,
                             const unsigned char *level, int ntris, const int *tris, sq_err *err);
/* append a tool (copied); -1 + err when the table is full */
int sq_render_state_add_tool(sq_render_state *s, const sq_tool *t, sq_err *err);
/* append an obstacle at its pose (copied, a mesh's triangles too); -1 + err when the table is
 * full or the obstacle is malformed (sq_obstacle_check) */
int sq_render_state_add_obstacle(sq_render_state *s, const sq_obstacle *o, sq_err *err);
/* append a probe at its current position; -1 + err when the table is full */
int sq_render_state_add_probe(sq_render_state *s, const double p[3], sq_err *err);
/* set the up vector from a gravity vector (+z if zero) */
void sq_render_state_set_gravity(sq_render_state *s, const double g[3]);

/* copy a world's bodies (finest surface, current positions and levels), tools, obstacles (at
 * their current poses), gravity and frame into s, reusing s's buffers. Levels are numbered as in the scene file's `levels`
 * list (scene->level_index), so a fixed body at listed level 2 shows level 2's colour.
 * Call under the lock that guards the world; then render from s on any thread. */
int sq_render_state_capture(sq_render_state *s, const sq_world *w, sq_err *err);

/* ---- step 2: draw list ---- */

typedef struct sq_draw_vertex {
    float pos[3];
    float normal[3];
    unsigned char rgba[4];
} sq_draw_vertex;

typedef struct sq_drawlist {
    int nverts;            /* vertices used */
    int ntris;             /* triangles used (3 indices each) */
    sq_draw_vertex *v;     /* (nverts) */
    unsigned *idx;         /* (ntris x 3) */
    int cap_verts, cap_tris;
    int body_tris;         /* the first body_tris triangles are the bodies' surfaces */
    int floor_tris;        /* triangles of the default floor (0 when a plane obstacle replaces it) */
    int obstacle_tris;     /* triangles of the obstacles */
    int skipped_tris;      /* body triangles left out for non-finite positions */
    float background[3];
    /* camera, resolved */
    double eye[3], target[3], up[3];
    double fovy_deg, znear, zfar;
    double stress_scale;   /* stress mode: |displacement| at the top of the ramp, m */
} sq_drawlist;

/* build the draw list of s for an image of the given aspect (width / height); reuses dl's
 * buffers (start from a zeroed sq_drawlist). -1 + err on an unusable camera. */
int sq_drawlist_build(sq_drawlist *dl, const sq_render_state *s, const sq_render_opts *o,
                      double aspect, sq_err *err);
void sq_drawlist_free(sq_drawlist *dl);
/* the surface colour of level l (clamped to the palette), as used in the draw list */
void sq_render_level_rgb(const sq_palette *p, int level, unsigned char rgb[3]);

/* ---- step 3: drawing and PNG ---- */

typedef struct sq_renderer sq_renderer;

/* an OSMesa context and buffers for width x height images at `supersample` samples per
 * side. A renderer is used by one thread at a time (it is made current on each draw). */
sq_renderer *sq_renderer_create(int width, int height, int supersample, sq_err *err);
void sq_renderer_destroy(sq_renderer *r);
/* draw dl into rgb (width x height x 3 bytes, rows top-down) */
int sq_renderer_draw(sq_renderer *r, const sq_drawlist *dl, unsigned char *rgb, sq_err *err);

/* encode an RGB image (rows top-down) as PNG in memory (free with free()) */
int sq_png_encode(const unsigned char *rgb, int width, int height, unsigned char **png,
                  size_t *len, sq_err *err);
/* write PNG bytes to a file; the error names the path */
int sq_png_write_file(const char *path, const unsigned char *png, size_t len, sq_err *err);
/* decode a PNG (any libpng colour type) into RGB rows top-down (free with free()) */
int sq_png_decode(const unsigned char *png, size_t len, unsigned char **rgb, int *width,
                  int *height, sq_err *err);

/* ---- one-call entry points (thread-safe; one render at a time per process) ---- */

/* render a captured state to PNG bytes (*png freed with free()); sides limited to
 * SQ_RENDER_MAX_SIZE. o may be NULL for defaults. */
int sq_render_state_png(const sq_render_state *s, int width, int height, const sq_render_opts *o,
                        unsigned char **png, size_t *len, sq_err *err);
/* capture w then render it (for callers that own w on this thread; the server should
 * capture under its lock and call sq_render_state_png instead). Sides limited to
 * SQ_SNAPSHOT_MAX_SIZE. */
int sq_render_world_png(const sq_world *w, int width, int height, const sq_render_opts *o,
                        unsigned char **png, size_t *len, sq_err *err);

#endif
