/* scene.c - JSON scene files: read, parse, the top level; the default scene; free.
 *
 * Every error names the file (label), the JSON path and the problem, then what to do:
 *   "scene.json: bodies[0].material.nu: 0.7 is out of range; use 0 <= nu < 0.5"
 * The format is documented key by key in docs/scenes.md. The bodies, tools and probes are
 * read by bodies.c and tools.c, every field by the readers of fields.c.
 */
#include "scene/scene_internal.h"

#include <math.h>
#include <stddef.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/stat.h>

#define MAX_SCENE_BYTES (4u << 20)

/* ---- scene ------------------------------------------------------------------------- */

static void json_error_position(const char *json, const char *at, int *line, int *col)
{
    *line = 1;
    *col = 1;
    for (const char *q = json; q < at && *q; q++) {
        if (*q == '\n') {
            (*line)++;
            *col = 1;
        } else {
            (*col)++;
        }
    }
}

/* root.<key>: an optional array of at most max entries, each read by parse; the count, or -1 */
static int parse_list(pctx *c, sq_scene *s, const cJSON *root, const char *key, int max,
                      int (*parse)(pctx *, sq_scene *, const cJSON *, int, const char *))
{
    int bad;
    const cJSON *arr = scene_get_typed(c, root, "", key, 1, 0, &bad);
    if (bad)
        return -1;
    int n = arr ? cJSON_GetArraySize(arr) : 0;
    if (n > max)
        return scene_fail(c, key, "%d %s; at most %d are supported", n, key, max);
    char p[64];
    int i = 0;
    for (const cJSON *e = arr ? arr->child : NULL; e; e = e->next, i++) {
        scene_join_index(p, sizeof p, key, i);
        if (parse(c, s, e, i, p))
            return -1;
    }
    return n;
}

/* "contact": {"bodies": true, "friction": 0.5}; then the warnings of free bodies */
static int parse_contact(pctx *c, sq_scene *s, const cJSON *root)
{
    static const char *const keys[] = {"bodies", "friction", NULL};
    int bad;
    const cJSON *ct = scene_get_typed(c, root, "", "contact", 0, 0, &bad);
    if (bad || (ct && scene_check_keys(c, ct, "contact", keys)))
        return -1;
    if (ct && (scene_get_bool(c, ct, "contact", "bodies", &s->body_contact) ||
               scene_get_number(c, ct, "contact", "friction", &s->body_friction, NULL)))
        return -1;
    if (!(s->body_friction >= 0 && s->body_friction <= 10))
        return scene_fail(c, "contact.friction", "%g is out of range; use 0 <= friction <= 10", s->body_friction);
    for (int b = 0; b < s->nbodies; b++) {
        const sq_body_def *d = &s->bodies[b];
        if (d->nconstraints || !s->nobstacles || s->nwarnings >= SQ_MAX_BODIES)
            continue; /* free bodies meeting obstacles: what contact needs of them */
        if (d->elasticity != SQ_ELASTICITY_COROTATIONAL) {
            char name[sizeof s->body_names[0]]; /* a copy: the warning is written into *s too */
            snprintf(name, sizeof name, "%s", s->body_names[b]);
            snprintf(s->warnings[s->nwarnings++], sizeof s->warnings[0],
                     "%s: bodies[%d] (\"%s\") is free (no \"fixed\" region) with linear elasticity: a rotation of "
                     "the whole body is taken for strain and inflates it; give \"elasticity\": \"corotational\"",
                     c->label, b, name);
        }
    }
    return 0;
}

/* "haptic": {"stiffness", "damping", "device_mass", "focus"}, each optional: the defaults of
 * a haptic channel opened on this scene, in the ranges the protocol's request takes */
static int parse_haptic(pctx *c, sq_scene *s, const cJSON *root)
{
    static const char *const keys[] = {"stiffness", "damping", "device_mass", "focus", NULL};
    static const struct {
        const char *key, *unit;
        double lo, hi;
        size_t off;
        unsigned bit;
    } field[] = {
        {"stiffness", "N/m", 0, SQ_HAPTIC_STIFFNESS_MAX, offsetof(sq_scene_haptic, stiffness), SQ_SCENE_HAPTIC_STIFFNESS},
        {"damping", "N s/m", 0, SQ_HAPTIC_DAMPING_MAX, offsetof(sq_scene_haptic, damping), SQ_SCENE_HAPTIC_DAMPING},
        {"device_mass", "kg", SQ_HAPTIC_DEVICE_MASS_MIN, SQ_HAPTIC_DEVICE_MASS_MAX,
         offsetof(sq_scene_haptic, device_mass), SQ_SCENE_HAPTIC_DEVICE_MASS},
        {"focus", "tool sizes", 0, SQ_HAPTIC_FOCUS_MAX, offsetof(sq_scene_haptic, focus), SQ_SCENE_HAPTIC_FOCUS},
    };
    memset(&s->haptic, 0, sizeof s->haptic);
    int bad;
    const cJSON *h = scene_get_typed(c, root, "", "haptic", 0, 0, &bad);
    if (bad || (h && scene_check_keys(c, h, "haptic", keys)))
        return -1;
    for (size_t k = 0; h && k < sizeof field / sizeof *field; k++) {
        double v;
        int found;
        if (scene_get_number(c, h, "haptic", field[k].key, &v, &found))
            return -1;
        if (!found)
            continue;
        if (!(v >= field[k].lo && v <= field[k].hi)) {
            char p[32];
            scene_join(p, sizeof p, "haptic", field[k].key);
            return scene_fail(c, p, "%g is out of range; use %g to %g (%s)", v, field[k].lo, field[k].hi, field[k].unit);
        }
        *(double *)((char *)&s->haptic + field[k].off) = v;
        s->haptic.given |= field[k].bit;
    }
    return 0;
}

static int parse_root(pctx *c, sq_scene *s, const cJSON *root)
{
    static const char *const keys[] = {"name", "description", "meshes_made_by", "gravity", "frame_rate",
                                       "duration", "bodies", "tools", "probes", "obstacles", "contact", "haptic",
                                       NULL};
    if (!cJSON_IsObject(root))
        return scene_fail(c, "", "the top level is %s; a scene is a JSON object {\"name\": ..., \"bodies\": [...]}",
                    scene_type_name(root));
    if (scene_check_keys(c, root, "", keys))
        return -1;
    if (scene_get_string(c, root, "", "name", s->name, sizeof s->name, NULL) || scene_check_name(c, "name", s->name) ||
        scene_get_string(c, root, "", "description", s->description, sizeof s->description, NULL) ||
        scene_get_string(c, root, "", "meshes_made_by", c->made_by, sizeof c->made_by, NULL))
        return -1;
    s->gravity[0] = s->gravity[1] = 0;
    s->gravity[2] = -9.81;
    if (scene_get_vec3(c, root, "", "gravity", s->gravity, NULL))
        return -1;
    if (fabs(s->gravity[0]) + fabs(s->gravity[1]) + fabs(s->gravity[2]) > 1e4)
        return scene_fail(c, "gravity", "[%g, %g, %g] is out of range; use components below 1e4 m/s^2",
                    s->gravity[0], s->gravity[1], s->gravity[2]);
    s->frame_rate = DEF_FRAME_RATE;
    if (scene_get_number(c, root, "", "frame_rate", &s->frame_rate, NULL))
        return -1;
    if (!(s->frame_rate > 0 && s->frame_rate <= 10000))
        return scene_fail(c, "frame_rate", "%g is out of range; use 0 < frame_rate <= 10000 (Hz)", s->frame_rate);
    s->duration = DEF_DURATION;
    if (scene_get_number(c, root, "", "duration", &s->duration, NULL))
        return -1;
    if (!(s->duration > 0 && s->duration <= 1e6))
        return scene_fail(c, "duration", "%g is out of range; use 0 < duration <= 1e6 (s)", s->duration);

    int bad;
    const cJSON *bodies = scene_get_typed(c, root, "", "bodies", 1, 1, &bad);
    if (bad)
        return -1;
    int nb = cJSON_GetArraySize(bodies);
    if (nb < 1 || nb > SQ_MAX_BODIES)
        return scene_fail(c, "bodies", "%d bodies; give 1 to %d", nb, SQ_MAX_BODIES);
    char p[64];
    int i = 0;
    for (const cJSON *e = bodies->child; e; e = e->next, i++) {
        scene_join_index(p, sizeof p, "bodies", i);
        s->nbodies = i; /* bodies loaded so far are freed by the caller on error */
        if (scene_parse_body(c, s, e, i, p))
            return -1;
    }
    s->nbodies = nb;

    int nt = parse_list(c, s, root, "tools", SQ_MAX_TOOLS, scene_parse_tool);
    if (nt < 0)
        return -1;
    s->ntools = nt;

    int np = parse_list(c, s, root, "probes", SQ_MAX_PROBES, scene_parse_probe);
    if (np < 0)
        return -1;
    s->nprobes = np;

    int no = parse_list(c, s, root, "obstacles", SQ_MAX_OBSTACLES, scene_parse_obstacle);
    if (no < 0)
        return -1;
    s->nobstacles = no;
    if (parse_contact(c, s, root) || parse_haptic(c, s, root))
        return -1;
    return scene_check_overlaps(c, s) ? -1 : 0;
}

sq_scene *sq_scene_parse(const char *json, const char *base_dir, const char *label, sq_err *err)
{
    pctx c = {label && label[0] ? label : "scene", base_dir, err, ""};
    sq_err local = {{0}};
    if (!c.err)
        c.err = &local;
    if (!json) {
        scene_fail(&c, "", "no text to parse");
        return NULL;
    }
    const char *q = json;
    while (*q == ' ' || *q == '\t' || *q == '\n' || *q == '\r')
        q++;
    if (!*q) {
        scene_fail(&c, "", "empty; a scene is a JSON object {\"name\": ..., \"bodies\": [...]} (see docs/scenes.md)");
        return NULL;
    }
    const char *end = NULL;
    cJSON *root = cJSON_ParseWithOpts(json, &end, 1);
    if (!root) {
        int line, col;
        const char *at = end ? end : cJSON_GetErrorPtr();
        if (!at)
            at = json;
        json_error_position(json, at, &line, &col);
        char near[24];
        size_t k = 0;
        for (; k < sizeof near - 1 && at[k] && at[k] != '\n'; k++)
            near[k] = at[k] >= 32 && at[k] < 127 ? at[k] : '?';
        near[k] = 0;
        scene_fail(&c, "", "line %d, column %d: invalid JSON near '%s'; check for a missing comma, quote or "
                     "bracket (comments and trailing commas are not JSON)", line, col, near);
        return NULL;
    }
    sq_scene *s = sq_calloc(1, sizeof *s);
    s->body_contact = 1;
    s->body_friction = 0.5;
    snprintf(s->path, sizeof s->path, "%s", c.label);
    snprintf(s->name, sizeof s->name, "scene");
    if (parse_root(&c, s, root)) {
        cJSON_Delete(root);
        sq_scene_free(s);
        return NULL;
    }
    cJSON_Delete(root);
    return s;
}

sq_scene *sq_scene_load(const char *path, sq_err *err)
{
    struct stat st;
    if (stat(path, &st) == 0 && S_ISDIR(st.st_mode)) {
        sq_err_set(err, "%s: is a directory; give a scene file such as meshes/scenes/paper-cube.json", path);
        return NULL;
    }
    sq_err e = {{0}};
    char *text = sq_read_file(path, NULL, MAX_SCENE_BYTES, &e);
    if (!text) {
        sq_err_set(err, "%s; check the scene file's path", e.msg);
        return NULL;
    }
    /* base directory: the scene file's directory */
    char dir[512];
    snprintf(dir, sizeof dir, "%s", path);
    char *slash = strrchr(dir, '/');
    if (slash)
        *slash = 0;
    else
        snprintf(dir, sizeof dir, ".");
    if (slash == dir)
        snprintf(dir, sizeof dir, "/");
    sq_scene *s = sq_scene_parse(text, dir, path, err);
    free(text);
    if (!s)
        return NULL;
    for (int i = 0; i < s->nwarnings; i++)
        fprintf(stderr, "warning: %s\n", s->warnings[i]);
    /* a scene without "name" takes the file's base name */
    if (!strcmp(s->name, "scene")) {
        const char *b = strrchr(path, '/');
        b = b ? b + 1 : path;
        char nm[64];
        snprintf(nm, sizeof nm, "%s", b);
        char *dot = strrchr(nm, '.');
        if (dot && dot != nm)
            *dot = 0;
        snprintf(s->name, sizeof s->name, "%s", nm);
    }
    return s;
}

sq_scene *sq_scene_default(sq_err *err)
{
    sq_scene *s = sq_calloc(1, sizeof *s);
    snprintf(s->name, sizeof s->name, "paper-cube");
    s->body_contact = 1;
    s->body_friction = 0.5;
    snprintf(s->description, sizeof s->description,
             "The paper's section 2.6: a 1 m cube, bottom face fixed, sagging under gravity "
             "(mu = 40 kPa, lambda = 100 kPa, 1000 kg/m^3); probe at the corner (1, 1, 1).");
    snprintf(s->path, sizeof s->path, "<default>");
    s->gravity[2] = -9.81;
    s->frame_rate = DEF_FRAME_RATE;
    s->duration = 5.0;
    s->nbodies = 1;
    snprintf(s->body_names[0], sizeof s->body_names[0], "cube");

    sq_body_def *def = &s->bodies[0];
    *def = sq_body_def_default();
    def->name = s->body_names[0];
    def->material = sq_material_paper();
    def->material.rayleigh_mass = 2.0;
    def->op = SQ_OPERATOR_FEM;
    def->nconstraints = 1;
    def->constraints[0] = (sq_constraint){SQ_REGION_BOX, {-1, -1, -1}, {2, 2, 1e-6}, 7};
    memcpy(def->gravity, s->gravity, sizeof def->gravity);
    def->frame_dt = 1.0 / s->frame_rate;
    def->step_fraction = DEF_STEP_FRACTION;

    /* levels of 2, 4, 8 cells per side built in memory (independent of files) */
    static const int cells[] = {2, 4, 8};
    const double size[3] = {1, 1, 1}, origin[3] = {0, 0, 0};
    for (int k = 0; k < 3; k++) {
        sq_err e = {{0}};
        s->meshes[0][k] = sq_mesh_box(cells[k], cells[k], cells[k], size, origin, &e);
        if (!s->meshes[0][k]) {
            sq_err_set(err, "<default>: building the cube mesh (%d cells per side): %s", cells[k], e.msg);
            sq_scene_free(s);
            return NULL;
        }
        double bary[4];
        sq_mesh_locate(s->meshes[0][k], s->meshes[0][k]->x, bary);
        s->level_index[0][k] = k;
        def->levels[k] = s->meshes[0][k];
    }
    s->nlisted[0] = 3;
    /* fixed at the finest level: the one body simulated without the adaptive engine;
     * all three levels stay loaded so a caller may switch to adaptive with sq_body_set_lod */
    def->nlevels = 3;
    def->lod = sq_body_def_default().lod;
    def->lod.mode = SQ_LOD_FIXED;
    def->lod.level = 2;
    def->lod.max_level = 2;

    s->nprobes = 1;
    snprintf(s->probes[0].name, sizeof s->probes[0].name, "corner");
    s->probes[0].body = 0;
    s->probes[0].point[0] = s->probes[0].point[1] = s->probes[0].point[2] = 1;
    return s;
}

void sq_scene_free(sq_scene *s)
{
    if (!s)
        return;
    for (int b = 0; b < SQ_MAX_BODIES; b++)
        for (int k = 0; k < SQ_MAX_LEVELS; k++)
            sq_mesh_free(s->meshes[b][k]);
    for (int o = 0; o < SQ_MAX_OBSTACLES; o++)
        sq_trimesh_free(s->trimeshes[o]);
    free(s);
}

