/* scene_internal.h - what the files of server/scene share to parse a scene file.
 *
 * Internal to server/scene (others use scene/scene.h). The parser is split by role:
 *   scene.c   the file and its top level: read, parse JSON, root keys, the default scene
 *   fields.c  the field readers of scene files: JSON paths, the scene files' wording of errors
 *   bodies.c  a body: levels (mesh files), material, constraints, level of detail, checks
 *   tools.c   scripted tools and their keyframes (and the pose at a time), probes
 *   dir.c     the scene directory a server offers
 *   world.c   a running instance of a scene
 * Every error names the file (the label), the JSON path and the problem, then what to do.
 */
#ifndef SQ_SCENE_INTERNAL_H
#define SQ_SCENE_INTERNAL_H

#include "scene/scene.h"

#include <cJSON.h>

/* defaults of the scene format (documented in docs/scenes.md) */
#define DEF_FRAME_RATE 50.0
#define DEF_DURATION 2.0
#define DEF_DENSITY 1000.0
#define DEF_STEP_FRACTION 0.9

/* parse context: the label that prefixes every message and the error slot */
typedef struct pctx {
    const char *label;
    const char *base_dir;
    sq_err *err;
    char made_by[64];      /* "meshes_made_by": how a scene's generated meshes are made */
} pctx;

/* ---- fields.c: readers. Each returns 0, or -1 with c->err set to "<label>: <path>: <what>";
 * the getters read obj.key (path.key in messages) and leave *out untouched when the key is
 * absent (*found = 0) */

int scene_fail(pctx *c, const char *path, const char *fmt, ...) __attribute__((format(printf, 3, 4)));
/* "a number", "a string", ... for messages */
const char *scene_type_name(const cJSON *it);
/* "a.b" + "c" -> "a.b.c"; "" + "c" -> "c" (truncated paths stay NUL-terminated) */
void scene_join(char *out, size_t n, const char *path, const char *key);
void scene_join_index(char *out, size_t n, const char *path, int i);
/* reject keys not in `known` (NULL-terminated) and duplicated keys */
int scene_check_keys(pctx *c, const cJSON *obj, const char *path, const char *const *known);
const cJSON *scene_get(const cJSON *obj, const char *key);
/* a finite number */
int scene_get_number(pctx *c, const cJSON *obj, const char *path, const char *key, double *out,
                     int *found);
int scene_get_required_number(pctx *c, const cJSON *obj, const char *path, const char *key,
                              double *out, const char *what);
/* an integer in [lo, hi] */
int scene_get_int(pctx *c, const cJSON *obj, const char *path, const char *key, long lo, long hi,
                  long *out, int *found);
/* a string of at most cap-1 bytes */
int scene_get_string(pctx *c, const cJSON *obj, const char *path, const char *key, char *out,
                     size_t cap, int *found);
/* a name usable in CSV files and file names: letters, digits, '_', '-', '.' */
int scene_check_name(pctx *c, const char *path, const char *name);
int scene_get_bool(pctx *c, const cJSON *obj, const char *path, const char *key, int *out);
/* an array of three finite numbers, given as the item itself (p: its path) */
int scene_vec3_of(pctx *c, const cJSON *it, const char *p, double out[3]);
int scene_get_vec3(pctx *c, const cJSON *obj, const char *path, const char *key, double out[3],
                   int *found);
/* an object or array expected at key (may be absent unless required); *bad on error */
const cJSON *scene_get_typed(pctx *c, const cJSON *obj, const char *path, const char *key,
                             int want_array, int required, int *bad);
/* v > 0, v >= 0 (unit: for the message) */
int scene_range_pos(pctx *c, const char *path, const char *key, double v, const char *unit);
int scene_range_nonneg(pctx *c, const char *path, const char *key, double v, const char *unit);

/* path.keyframes: [{"t", "pos", "active"}...], t >= 0 strictly increasing (pos_what names the
 * position for the missing-key message); absent: *nkeys 0 (an error when required) */
int scene_parse_keyframes(pctx *c, const cJSON *obj, const char *path, int required, sq_keyframe *keys, int *nkeys,
                          const char *pos_what);
/* a file path of the scene relative to its directory (base_dir), or absolute */
void scene_resolve(char *out, size_t n, const char *base_dir, const char *rel);

/* ---- obstacles.c: one entry of "obstacles"; the check that no body starts inside one or
 * inside another body (after the bodies are read) */
int scene_parse_obstacle(pctx *c, sq_scene *s, const cJSON *obj, int oi, const char *path);
int scene_check_overlaps(pctx *c, const sq_scene *s);

/* ---- bodies.c, tools.c: one entry of "bodies", "tools", "probes" at index i (path: its
 * JSON path); s->bodies[0..i-1] are read already */
int scene_parse_body(pctx *c, sq_scene *s, const cJSON *obj, int bi, const char *path);
int scene_parse_tool(pctx *c, sq_scene *s, const cJSON *obj, int ti, const char *path);
int scene_parse_probe(pctx *c, sq_scene *s, const cJSON *obj, int pi, const char *path);

#endif
