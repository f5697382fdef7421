/* scene.c - JSON scene files: parse, validate, load the meshes a body needs.
 *
 * Every error names the file (label), the JSON path and the problem, then what to do:
 *   "scene.json: bodies[0].material.nu: 0.7 is out of range; use 0 <= nu < 0.5"
 * The format is documented key by key in docs/scenes.md.
 */
#include "scene/scene.h"

#include <cJSON.h>
#include <errno.h>
#include <limits.h>
#include <math.h>
#include <stdarg.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/stat.h>

/* defaults of the scene format (documented in docs/scenes.md) */
#define DEF_FRAME_RATE 50.0
#define DEF_DURATION 2.0
#define DEF_DENSITY 1000.0
#define DEF_STEP_FRACTION 0.9
#define MAX_SCENE_BYTES (4u << 20)

/* parse context: the label that prefixes every message and the error slot */
typedef struct pctx {
    const char *label;
    const char *base_dir;
    sq_err *err;
    char made_by[64];      /* "meshes_made_by": how a scene's generated meshes are made */
} pctx;

static int fail(pctx *c, const char *path, const char *fmt, ...) __attribute__((format(printf, 3, 4)));
static int fail(pctx *c, const char *path, const char *fmt, ...)
{
    char msg[400];
    va_list ap;
    va_start(ap, fmt);
    vsnprintf(msg, sizeof msg, fmt, ap);
    va_end(ap);
    if (path && path[0])
        return sq_err_set(c->err, "%s: %s: %s", c->label, path, msg);
    return sq_err_set(c->err, "%s: %s", c->label, msg);
}

static const char *type_name(const cJSON *it)
{
    if (cJSON_IsNumber(it))
        return "a number";
    if (cJSON_IsString(it))
        return "a string";
    if (cJSON_IsBool(it))
        return "a boolean";
    if (cJSON_IsNull(it))
        return "null";
    if (cJSON_IsArray(it))
        return "an array";
    if (cJSON_IsObject(it))
        return "an object";
    return "an invalid value";
}

/* "a.b" + "c" -> "a.b.c"; "" + "c" -> "c" (truncated paths stay NUL-terminated) */
static void join(char *out, size_t n, const char *path, const char *key)
{
    int r = path[0] ? snprintf(out, n, "%s.%s", path, key) : snprintf(out, n, "%s", key);
    if (r < 0)
        out[0] = 0;
}

static void join_index(char *out, size_t n, const char *path, int i)
{
    if (snprintf(out, n, "%s[%d]", path, i) < 0)
        out[0] = 0;
}

/* reject keys not in `known` (NULL-terminated) and duplicated keys */
static int check_keys(pctx *c, const cJSON *obj, const char *path, const char *const *known)
{
    char p[256];
    for (const cJSON *it = obj->child; it; it = it->next) {
        int ok = 0;
        for (int k = 0; known[k]; k++)
            if (!strcmp(it->string, known[k]))
                ok = 1;
        join(p, sizeof p, path, it->string);
        if (!ok) {
            char list[256] = "";
            for (int k = 0; known[k]; k++) {
                size_t l = strlen(list);
                snprintf(list + l, sizeof list - l, "%s%s", k ? ", " : "", known[k]);
            }
            return fail(c, p, "unknown key; known keys here: %s (check the spelling)", list);
        }
        for (const cJSON *o = obj->child; o != it; o = o->next)
            if (!strcmp(o->string, it->string))
                return fail(c, p, "key given twice; keep one");
    }
    return 0;
}

static const cJSON *get(const cJSON *obj, const char *key)
{
    return cJSON_GetObjectItemCaseSensitive(obj, key);
}

/* obj.key (NULL when absent) with its path path.key written into p; *found says if it is there */
static const cJSON *get_at(const cJSON *obj, const char *path, const char *key, char *p, size_t cap,
                           int *found)
{
    join(p, cap, path, key);
    const cJSON *it = get(obj, key);
    if (found)
        *found = it != NULL;
    return it;
}

/* a finite number; *found = 0 when absent (then out is untouched) */
static int get_number(pctx *c, const cJSON *obj, const char *path, const char *key, double *out,
                      int *found)
{
    char p[256];
    const cJSON *it = get_at(obj, path, key, p, sizeof p, found);
    if (!it)
        return 0;
    if (!cJSON_IsNumber(it))
        return fail(c, p, "expected a number, got %s; see docs/scenes.md", type_name(it));
    if (!isfinite(it->valuedouble))
        return fail(c, p, "not a finite number; use a value within the double range");
    *out = it->valuedouble;
    return 0;
}

static int get_required_number(pctx *c, const cJSON *obj, const char *path, const char *key,
                               double *out, const char *what)
{
    int found;
    if (get_number(c, obj, path, key, out, &found))
        return -1;
    if (!found) {
        char p[256];
        join(p, sizeof p, path, key);
        return fail(c, p, "missing; give %s", what);
    }
    return 0;
}

/* an integer in [lo, hi] */
static int get_int(pctx *c, const cJSON *obj, const char *path, const char *key, long lo, long hi,
                   long *out, int *found)
{
    double v = 0;
    int f;
    if (get_number(c, obj, path, key, &v, &f))
        return -1;
    if (found)
        *found = f;
    if (!f)
        return 0;
    char p[256];
    join(p, sizeof p, path, key);
    if (v != floor(v))
        return fail(c, p, "%g is not an integer; use a whole number in [%ld, %ld]", v, lo, hi);
    if (v < (double)lo || v > (double)hi)
        return fail(c, p, "%g is out of range; use an integer in [%ld, %ld]", v, lo, hi);
    *out = (long)v;
    return 0;
}

/* a string of at most cap-1 bytes */
static int get_string(pctx *c, const cJSON *obj, const char *path, const char *key, char *out,
                      size_t cap, int *found)
{
    char p[256];
    const cJSON *it = get_at(obj, path, key, p, sizeof p, found);
    if (!it)
        return 0;
    if (!cJSON_IsString(it) || !it->valuestring)
        return fail(c, p, "expected a string, got %s; see docs/scenes.md", type_name(it));
    if (strlen(it->valuestring) >= cap)
        return fail(c, p, "too long (%zu bytes); use at most %zu", strlen(it->valuestring), cap - 1);
    snprintf(out, cap, "%s", it->valuestring);
    return 0;
}

/* a name usable in CSV files and file names: letters, digits, '_', '-', '.' */
static int check_name(pctx *c, const char *path, const char *name)
{
    if (!name[0])
        return fail(c, path, "empty name; give a short name such as \"cube\"");
    for (const char *s = name; *s; s++) {
        char ch = *s;
        if (!((ch >= 'a' && ch <= 'z') || (ch >= 'A' && ch <= 'Z') || (ch >= '0' && ch <= '9') ||
              ch == '_' || ch == '-' || ch == '.'))
            return fail(c, path, "\"%s\" has the character '%c'; use only letters, digits, '_', '-' and '.'",
                        name, ch);
    }
    return 0;
}

static int get_bool(pctx *c, const cJSON *obj, const char *path, const char *key, int *out)
{
    char p[256];
    const cJSON *it = get_at(obj, path, key, p, sizeof p, NULL);
    if (!it)
        return 0;
    if (!cJSON_IsBool(it))
        return fail(c, p, "expected true or false, got %s; see docs/scenes.md", type_name(it));
    *out = cJSON_IsTrue(it) ? 1 : 0;
    return 0;
}

/* an array of three finite numbers, given as the item itself */
static int vec3_of(pctx *c, const cJSON *it, const char *p, double out[3])
{
    if (!cJSON_IsArray(it) || cJSON_GetArraySize(it) != 3)
        return fail(c, p, "expected an array of 3 numbers [x, y, z], got %s%s; see docs/scenes.md", type_name(it),
                    cJSON_IsArray(it) ? " of another length" : "");
    int i = 0;
    for (const cJSON *e = it->child; e; e = e->next, i++) {
        if (!cJSON_IsNumber(e))
            return fail(c, p, "element %d: expected a number, got %s; see docs/scenes.md", i, type_name(e));
        if (!isfinite(e->valuedouble))
            return fail(c, p, "element %d: not a finite number; use a finite value", i);
        out[i] = e->valuedouble;
    }
    return 0;
}

static int get_vec3(pctx *c, const cJSON *obj, const char *path, const char *key, double out[3],
                    int *found)
{
    char p[256];
    const cJSON *it = get_at(obj, path, key, p, sizeof p, found);
    if (!it)
        return 0;
    return vec3_of(c, it, p, out);
}

/* an object or array expected at key (may be absent unless required) */
static const cJSON *get_typed(pctx *c, const cJSON *obj, const char *path, const char *key,
                              int want_array, int required, int *bad)
{
    char p[256];
    const cJSON *it = get_at(obj, path, key, p, sizeof p, NULL);
    *bad = 0;
    if (!it) {
        if (required) {
            *bad = 1;
            fail(c, p, "missing; give %s", want_array ? "an array" : "an object");
        }
        return NULL;
    }
    if (want_array ? !cJSON_IsArray(it) : !cJSON_IsObject(it)) {
        *bad = 1;
        fail(c, p, "expected %s, got %s; see docs/scenes.md", want_array ? "an array" : "an object", type_name(it));
        return NULL;
    }
    return it;
}

static int range_pos(pctx *c, const char *path, const char *key, double v, const char *unit)
{
    if (v > 0)
        return 0;
    char p[256];
    join(p, sizeof p, path, key);
    return fail(c, p, "%g is out of range; use %s > 0 (%s)", v, key, unit);
}

static int range_nonneg(pctx *c, const char *path, const char *key, double v, const char *unit)
{
    if (v >= 0)
        return 0;
    char p[256];
    join(p, sizeof p, path, key);
    return fail(c, p, "%g is out of range; use %s >= 0 (%s)", v, key, unit);
}

/* ---- material ---------------------------------------------------------------------- */

static int parse_material(pctx *c, const cJSON *obj, const char *path, sq_material *m)
{
    static const char *const keys[] = {"E", "nu", "lambda", "mu", "density", "damping", NULL};
    if (check_keys(c, obj, path, keys))
        return -1;
    double E = 0, nu = 0, lambda = 0, mu = 0, density = DEF_DENSITY;
    int hE, hnu, hl, hmu;
    if (get_number(c, obj, path, "E", &E, &hE) || get_number(c, obj, path, "nu", &nu, &hnu) ||
        get_number(c, obj, path, "lambda", &lambda, &hl) || get_number(c, obj, path, "mu", &mu, &hmu) ||
        get_number(c, obj, path, "density", &density, NULL))
        return -1;
    /* damping defaults are the engine's (sq_body_def_default) */
    const sq_material dm = sq_body_def_default().material;
    memset(m, 0, sizeof *m);
    m->rayleigh_mass = dm.rayleigh_mass;
    m->rayleigh_stiffness = dm.rayleigh_stiffness;
    char p[256];
    if ((hE || hnu) && (hl || hmu))
        return fail(c, path, "both E/nu and lambda/mu given; give either E and nu, or lambda and mu");
    if (hE || hnu) {
        if (!hE || !hnu) {
            join(p, sizeof p, path, hE ? "nu" : "E");
            return fail(c, p, "missing; E (Pa) and nu go together, give both");
        }
        if (range_pos(c, path, "E", E, "Young's modulus in Pa"))
            return -1;
        if (!(nu >= 0 && nu < 0.5)) {
            join(p, sizeof p, path, "nu");
            return fail(c, p, "%g is out of range; use 0 <= nu < 0.5", nu);
        }
        /* nu very close to 0.5 makes lambda overflow the step bound; sim rejects it with numbers */
        sq_err e = {{0}};
        if (sq_material_from_E_nu(m, E, nu, &e)) {
            join(p, sizeof p, path, "E");
            return fail(c, p, "%s", e.msg);
        }
    } else if (hl || hmu) {
        if (!hl || !hmu) {
            join(p, sizeof p, path, hl ? "mu" : "lambda");
            return fail(c, p, "missing; lambda and mu (Pa, standard Lame names) go together, give both");
        }
        if (range_pos(c, path, "mu", mu, "shear modulus in Pa") ||
            range_nonneg(c, path, "lambda", lambda, "first Lame parameter in Pa"))
            return -1;
        m->mu = mu;
        m->lambda = lambda;
    } else {
        return fail(c, path, "no stiffness given; give E (Pa) and nu, or lambda and mu (Pa)");
    }
    if (range_pos(c, path, "density", density, "kg/m^3"))
        return -1;
    m->density = density;

    /* damping: Rayleigh a M + b K, or the paper's viscosities phi/psi in place of b K */
    int bad;
    const cJSON *d = get_typed(c, obj, path, "damping", 0, 0, &bad);
    if (bad)
        return -1;
    if (d) {
        static const char *const dkeys[] = {"rayleigh_mass", "rayleigh_stiffness", "phi", "psi", NULL};
        char dp[256];
        join(dp, sizeof dp, path, "damping");
        if (check_keys(c, d, dp, dkeys))
            return -1;
        int hb, hphi, hpsi;
        if (get_number(c, d, dp, "rayleigh_mass", &m->rayleigh_mass, NULL) ||
            get_number(c, d, dp, "rayleigh_stiffness", &m->rayleigh_stiffness, &hb) ||
            get_number(c, d, dp, "phi", &m->phi, &hphi) || get_number(c, d, dp, "psi", &m->psi, &hpsi))
            return -1;
        if (range_nonneg(c, dp, "rayleigh_mass", m->rayleigh_mass, "1/s") ||
            range_nonneg(c, dp, "rayleigh_stiffness", m->rayleigh_stiffness, "s") ||
            range_nonneg(c, dp, "phi", m->phi, "Pa s") || range_nonneg(c, dp, "psi", m->psi, "Pa s"))
            return -1;
        if ((hphi || hpsi) && hb)
            return fail(c, dp, "rayleigh_stiffness and phi/psi both given; the viscosities replace b K, "
                               "give one of them");
        m->use_viscosity = hphi || hpsi;
        if (m->use_viscosity)
            m->rayleigh_stiffness = 0;
    }
    sq_err e = {{0}};
    if (sq_material_check(m, &e))
        return fail(c, path, "%s", e.msg);
    return 0;
}

/* ---- constraints ------------------------------------------------------------------- */

static int parse_axes(pctx *c, const cJSON *obj, const char *path, unsigned *axes)
{
    char s[8];
    int found;
    char p[256];
    join(p, sizeof p, path, "axes");
    const cJSON *it = get(obj, "axes");
    if (it && cJSON_IsString(it) && strlen(it->valuestring) >= sizeof s)
        return fail(c, p, "\"%s\" is not a set of axes; use a combination of x, y, z such as \"xy\"",
                    it->valuestring);
    if (get_string(c, obj, path, "axes", s, sizeof s, &found))
        return -1;
    *axes = 7;
    if (!found)
        return 0;
    unsigned a = 0;
    for (const char *q = s; *q; q++) {
        unsigned bit = *q == 'x' ? 1u : *q == 'y' ? 2u : *q == 'z' ? 4u : 0u;
        if (!bit || (a & bit))
            return fail(c, p, "\"%s\" is not a set of axes; use each of x, y, z at most once, e.g. \"xy\"", s);
        a |= bit;
    }
    if (!a)
        return fail(c, p, "empty; name the constrained axes, e.g. \"z\" for a roller on a horizontal plane");
    *axes = a;
    return 0;
}

static int parse_constraint(pctx *c, const cJSON *obj, const char *path, sq_constraint *k)
{
    static const char *const keys[] = {"box", "halfspace", "axes", NULL};
    if (!cJSON_IsObject(obj))
        return fail(c, path, "expected an object {\"box\": ...} or {\"halfspace\": ...}, got %s; see docs/scenes.md", type_name(obj));
    if (check_keys(c, obj, path, keys))
        return -1;
    memset(k, 0, sizeof *k);
    const cJSON *box = get(obj, "box"), *hs = get(obj, "halfspace");
    if (!!box == !!hs)
        return fail(c, path, "%s region; give exactly one: \"box\": [[x0,y0,z0],[x1,y1,z1]] or "
                             "\"halfspace\": {\"point\": [...], \"normal\": [...]}",
                    box ? "more than one" : "no");
    char p[256];
    if (box) {
        join(p, sizeof p, path, "box");
        if (!cJSON_IsArray(box) || cJSON_GetArraySize(box) != 2)
            return fail(c, p, "expected [[x0,y0,z0],[x1,y1,z1]] (min and max corners), got %s; see docs/scenes.md", type_name(box));
        char q[256];
        join_index(q, sizeof q, p, 0);
        if (vec3_of(c, box->child, q, k->a))
            return -1;
        join_index(q, sizeof q, p, 1);
        if (vec3_of(c, box->child->next, q, k->b))
            return -1;
        for (int i = 0; i < 3; i++)
            if (k->a[i] > k->b[i])
                return fail(c, p, "min corner above max corner on axis %c (%g > %g); put the smaller "
                                  "coordinates first", "xyz"[i], k->a[i], k->b[i]);
        k->kind = SQ_REGION_BOX;
    } else {
        join(p, sizeof p, path, "halfspace");
        if (!cJSON_IsObject(hs))
            return fail(c, p, "expected {\"point\": [x,y,z], \"normal\": [x,y,z]}, got %s; see docs/scenes.md", type_name(hs));
        static const char *const hkeys[] = {"point", "normal", NULL};
        if (check_keys(c, hs, p, hkeys))
            return -1;
        int f1, f2;
        if (get_vec3(c, hs, p, "point", k->a, &f1) || get_vec3(c, hs, p, "normal", k->b, &f2))
            return -1;
        if (!f1 || !f2)
            return fail(c, p, "missing \"%s\"; a half-space needs a point and an outward normal "
                              "(nodes with (x - point).normal <= 0 are selected)", f1 ? "normal" : "point");
        double n = sqrt(k->b[0] * k->b[0] + k->b[1] * k->b[1] + k->b[2] * k->b[2]);
        if (!(n > 0) || !isfinite(n)) {
            char q[256];
            join(q, sizeof q, p, "normal");
            return fail(c, q, "zero or overflowing vector; give a non-zero normal such as [0, 0, 1]");
        }
        for (int i = 0; i < 3; i++)
            k->b[i] /= n;
        k->kind = SQ_REGION_HALFSPACE;
    }
    return parse_axes(c, obj, path, &k->axes);
}

/* does the region select node x? (same rule as the engine: inclusive box, (x-a).n <= 0) */
static int region_selects(const sq_constraint *k, const double *x)
{
    if (k->kind == SQ_REGION_BOX)
        return x[0] >= k->a[0] && x[0] <= k->b[0] && x[1] >= k->a[1] && x[1] <= k->b[1] &&
               x[2] >= k->a[2] && x[2] <= k->b[2];
    double s = 0;
    for (int i = 0; i < 3; i++)
        s += (x[i] - k->a[i]) * k->b[i];
    return s <= 0;
}

/* ---- level of detail --------------------------------------------------------------- */

static int parse_lod(pctx *c, const cJSON *obj, const char *path, int nlisted, sq_lod_def *lod)
{
    static const char *const keys[] = {"mode", "level", "split", "merge", "max_level", "budget",
                                       "max_node_updates", NULL};
    /* defaults of the engine (sq_body_def_default) */
    *lod = sq_body_def_default().lod;
    lod->mode = SQ_LOD_FIXED;
    double merge_ratio = lod->split > 0 ? lod->merge / lod->split : 0.4;
    lod->max_level = nlisted - 1;
    lod->level = -1;
    if (!obj) {
        lod->level = nlisted - 1;
        return 0;
    }
    if (check_keys(c, obj, path, keys))
        return -1;
    char mode[16] = "fixed", p[256];
    const cJSON *mi = get(obj, "mode");
    join(p, sizeof p, path, "mode");
    if (mi && cJSON_IsString(mi) && strlen(mi->valuestring) >= sizeof mode)
        return fail(c, p, "\"%s\" is not a mode; use \"fixed\" or \"adaptive\"", mi->valuestring);
    if (get_string(c, obj, path, "mode", mode, sizeof mode, NULL))
        return -1;
    if (!strcmp(mode, "adaptive"))
        lod->mode = SQ_LOD_ADAPTIVE;
    else if (strcmp(mode, "fixed"))
        return fail(c, p, "\"%s\" is not a mode; use \"fixed\" or \"adaptive\"", mode);
    long v;
    int found;
    if (get_int(c, obj, path, "max_level", 0, nlisted - 1, &v, &found))
        return -1;
    if (found)
        lod->max_level = (int)v;
    if (get_int(c, obj, path, "level", 0, lod->max_level, &v, &found))
        return -1;
    lod->level = found ? (int)v : lod->mode == SQ_LOD_FIXED ? lod->max_level : 0;

    /* split may be the string "inf": never split (forces the coarsest level) */
    const cJSON *sp = get(obj, "split");
    join(p, sizeof p, path, "split");
    if (sp && cJSON_IsString(sp)) {
        if (strcmp(sp->valuestring, "inf"))
            return fail(c, p, "\"%s\" is not a threshold; use a number >= 0 (m) or \"inf\"", sp->valuestring);
        lod->split = INFINITY;
    } else if (get_number(c, obj, path, "split", &lod->split, NULL) ||
               range_nonneg(c, path, "split", lod->split, "m"))
        return -1;
    if (sp)
        lod->merge = isinf(lod->split) ? 1e300 : lod->split * merge_ratio;
    int hmerge;
    if (get_number(c, obj, path, "merge", &lod->merge, &hmerge) ||
        range_nonneg(c, path, "merge", lod->merge, "m"))
        return -1;
    if (hmerge && !(lod->merge < lod->split || (lod->split == 0 && lod->merge == 0))) {
        join(p, sizeof p, path, "merge");
        return fail(c, p, "%g is not below split (%g); use merge < split for hysteresis", lod->merge,
                    lod->split);
    }
    if (get_number(c, obj, path, "budget", &lod->budget, NULL))
        return -1;
    if (!(lod->budget > 0 && lod->budget <= 1)) {
        join(p, sizeof p, path, "budget");
        return fail(c, p, "%g is out of range; use a fraction of the frame period in (0, 1], e.g. 0.95",
                    lod->budget);
    }
    if (get_int(c, obj, path, "max_node_updates", 0, 1000000000000L, &v, &found))
        return -1;
    if (found)
        lod->max_node_updates = v;
    return 0;
}

/* ---- files ------------------------------------------------------------------------- */

static void resolve(char *out, size_t n, const char *base_dir, const char *rel)
{
    if (rel[0] == '/' || !base_dir || !base_dir[0])
        snprintf(out, n, "%s", rel);
    else
        snprintf(out, n, "%s/%s", base_dir, rel);
}

/* ---- bodies ------------------------------------------------------------------------ */

static int parse_body(pctx *c, sq_scene *s, const cJSON *obj, int bi, const char *path)
{
    static const char *const keys[] = {"name", "levels", "scale", "offset", "material", "operator", "fixed",
                                       "lod", "step_fraction", "elasticity", "step_bound", "pressure", NULL};
    if (!cJSON_IsObject(obj))
        return fail(c, path, "expected an object, got %s; see docs/scenes.md", type_name(obj));
    if (check_keys(c, obj, path, keys))
        return -1;
    sq_body_def *def = &s->bodies[bi];
    *def = sq_body_def_default();
    char p[256];

    /* name */
    int found;
    snprintf(s->body_names[bi], sizeof s->body_names[bi], "body%d", bi);
    if (get_string(c, obj, path, "name", s->body_names[bi], sizeof s->body_names[bi], &found))
        return -1;
    join(p, sizeof p, path, "name");
    if (check_name(c, p, s->body_names[bi]))
        return -1;
    for (int j = 0; j < bi; j++)
        if (!strcmp(s->body_names[j], s->body_names[bi]))
            return fail(c, p, "\"%s\" is already the name of bodies[%d]; give each body its own name",
                        s->body_names[bi], j);
    def->name = s->body_names[bi];

    /* levels: strings, coarse to fine */
    int bad;
    const cJSON *lv = get_typed(c, obj, path, "levels", 1, 1, &bad);
    if (bad)
        return -1;
    char lp[256];
    join(lp, sizeof lp, path, "levels");
    int nl = cJSON_GetArraySize(lv);
    if (nl < 1 || nl > SQ_MAX_LEVELS)
        return fail(c, lp, "%d levels; list 1 to %d mesh files, coarse to fine", nl, SQ_MAX_LEVELS);
    const char *files[SQ_MAX_LEVELS];
    int i = 0;
    for (const cJSON *e = lv->child; e; e = e->next, i++) {
        join_index(p, sizeof p, lp, i);
        if (!cJSON_IsString(e) || !e->valuestring[0])
            return fail(c, p, "expected a mesh file path (relative to the scene file), got %s; see docs/scenes.md",
                        cJSON_IsString(e) ? "an empty string" : type_name(e));
        files[i] = e->valuestring;
        char full[1024];
        resolve(full, sizeof full, c->base_dir, files[i]);
        struct stat st;
        if (stat(full, &st) != 0 && errno == ENOENT && c->made_by[0])
            return fail(c, p, "mesh file \"%s\" (resolved to %s): " SQ_SCENE_MESHES_NOT_MADE
                              ": this scene's meshes are generated, not shipped; run `%s` first (meshes/README.md)",
                        files[i], full, c->made_by);
        if (stat(full, &st) != 0)
            return fail(c, p, "mesh file \"%s\" (resolved to %s) cannot be read: %s; paths are relative "
                              "to the scene file's directory", files[i], full, strerror(errno));
    }
    s->nlisted[bi] = nl;

    /* material */
    const cJSON *mat = get_typed(c, obj, path, "material", 0, 1, &bad);
    if (bad)
        return -1;
    join(p, sizeof p, path, "material");
    if (parse_material(c, mat, p, &def->material))
        return -1;

    /* operator */
    char op[16] = "fem";
    const cJSON *opi = get(obj, "operator");
    join(p, sizeof p, path, "operator");
    if (opi && !cJSON_IsString(opi))
        return fail(c, p, "expected \"fem\" or \"paper\", got %s; see docs/scenes.md", type_name(opi));
    if (opi && strlen(opi->valuestring) >= sizeof op)
        return fail(c, p, "\"%.40s\" is not an operator; use \"fem\" or \"paper\"", opi->valuestring);
    if (opi)
        snprintf(op, sizeof op, "%s", opi->valuestring);
    if (!strcmp(op, "fem"))
        def->op = SQ_OPERATOR_FEM;
    else if (!strcmp(op, "paper"))
        def->op = SQ_OPERATOR_PAPER;
    else
        return fail(c, p, "\"%s\" is not an operator; use \"fem\" (standard linear FEM) or \"paper\" "
                          "(the paper's Laplacian + grad-div)", op);

    /* elasticity: linear (default) or corotational */
    const cJSON *el = get(obj, "elasticity");
    join(p, sizeof p, path, "elasticity");
    if (el && !cJSON_IsString(el))
        return fail(c, p, "expected \"linear\" or \"corotational\", got %s; see docs/scenes.md", type_name(el));
    if (!el || !strcmp(el->valuestring, "linear"))
        def->elasticity = SQ_ELASTICITY_LINEAR;
    else if (!strcmp(el->valuestring, "corotational"))
        def->elasticity = SQ_ELASTICITY_COROTATIONAL;
    else
        return fail(c, p, "\"%.40s\" is not an elasticity; use \"linear\" (small strain, the paper's) or "
                          "\"corotational\" (large rotations; fem operator, fixed lod)", el->valuestring);

    /* step bound: gershgorin (default, 2^n substeps) or sharp (fixed lod: Lanczos, any count) */
    const cJSON *sb = get(obj, "step_bound");
    join(p, sizeof p, path, "step_bound");
    if (sb && !(cJSON_IsString(sb) && (!strcmp(sb->valuestring, "gershgorin") || !strcmp(sb->valuestring, "sharp"))))
        return fail(c, p, "expected \"gershgorin\" (default: row-sum bound, 2^n substeps per frame) or \"sharp\" "
                          "(fixed lod: Lanczos estimate, any substep count); see docs/stability.md");
    def->sharp_step = sb && !strcmp(sb->valuestring, "sharp");

    /* pressure: element (default) or nodal (average nodal pressure tets: less locking) */
    const cJSON *pr = get(obj, "pressure");
    join(p, sizeof p, path, "pressure");
    if (pr && !(cJSON_IsString(pr) && (!strcmp(pr->valuestring, "element") || !strcmp(pr->valuestring, "nodal"))))
        return fail(c, p, "expected \"element\" (default: one pressure per tet) or \"nodal\" (average nodal "
                          "pressure tets: less locking; fem, linear, fixed lod); see docs/physics.md section 10");
    def->nodal_pressure = pr && !strcmp(pr->valuestring, "nodal");

    /* constraints */
    const cJSON *fx = get_typed(c, obj, path, "fixed", 1, 0, &bad);
    if (bad)
        return -1;
    def->nconstraints = 0;
    if (fx) {
        char fp[256];
        join(fp, sizeof fp, path, "fixed");
        int nf = cJSON_GetArraySize(fx);
        if (nf > SQ_MAX_CONSTRAINTS)
            return fail(c, fp, "%d regions; at most %d are supported, merge some boxes", nf, SQ_MAX_CONSTRAINTS);
        i = 0;
        for (const cJSON *e = fx->child; e; e = e->next, i++) {
            join_index(p, sizeof p, fp, i);
            if (parse_constraint(c, e, p, &def->constraints[i]))
                return -1;
        }
        def->nconstraints = nf;
    }

    /* level of detail */
    const cJSON *lod = get_typed(c, obj, path, "lod", 0, 0, &bad);
    if (bad)
        return -1;
    join(p, sizeof p, path, "lod");
    if (parse_lod(c, lod, p, nl, &def->lod))
        return -1;

    def->step_fraction = DEF_STEP_FRACTION;
    if (get_number(c, obj, path, "step_fraction", &def->step_fraction, NULL))
        return -1;
    if (!(def->step_fraction > 0 && def->step_fraction <= 1)) {
        join(p, sizeof p, path, "step_fraction");
        return fail(c, p, "%g is out of range; use a fraction of the stability bound in (0, 1], e.g. 0.9",
                    def->step_fraction);
    }
    def->frame_dt = 1.0 / s->frame_rate;
    memcpy(def->gravity, s->gravity, sizeof def->gravity);

    /* offset: translate the meshes at load (regions, probes and tools are in world space) */
    double offset[3] = {0, 0, 0};
    if (get_vec3(c, obj, path, "offset", offset, NULL))
        return -1;
    if (fabs(offset[0]) > 1e6 || fabs(offset[1]) > 1e6 || fabs(offset[2]) > 1e6) {
        join(p, sizeof p, path, "offset");
        return fail(c, p, "[%g, %g, %g] is out of range; use components below 1e6 m", offset[0], offset[1],
                    offset[2]);
    }

    /* scale: multiply every level's coordinates at load, before the offset (meshes made in
     * millimetres: 0.001) */
    double scale = 1;
    int has_scale = 0;
    if (get_number(c, obj, path, "scale", &scale, &has_scale))
        return -1;
    if (!(scale >= 1e-6 && scale <= 1e6)) {
        join(p, sizeof p, path, "scale");
        return fail(c, p, "%g is out of range; use a factor in [1e-6, 1e6] (0.001 for a mesh in millimetres)",
                    scale);
    }
    int warned = 0;

    /* load only the levels the body needs: fixed -> the simulated level alone,
     * adaptive -> levels 0..max_level */
    int first = def->lod.mode == SQ_LOD_FIXED ? def->lod.level : 0;
    int last = def->lod.mode == SQ_LOD_FIXED ? def->lod.level : def->lod.max_level;
    def->nlevels = 0;
    for (int k = first; k <= last; k++) {
        char full[1024];
        resolve(full, sizeof full, c->base_dir, files[k]);
        sq_err e = {{0}};
        sq_mesh *m = sq_mesh_load(full, &e);
        join_index(p, sizeof p, lp, k);
        if (!m)
            return fail(c, p, "%s; fix or regenerate the mesh file", e.msg);
        if (scale != 1) {
            for (int v = 0; v < 3 * m->nnodes; v++)
                m->x[v] *= scale;
            for (int a = 0; a < 3; a++) {
                m->bbox_min[a] *= scale;
                m->bbox_max[a] *= scale;
            }
        }
        /* a body is a few mm to a few m: anything else is most likely in other units */
        double diag = 0;
        for (int a = 0; a < 3; a++)
            diag += (m->bbox_max[a] - m->bbox_min[a]) * (m->bbox_max[a] - m->bbox_min[a]);
        diag = sqrt(diag);
        if (!warned && (diag > 10 || diag < 1e-3) && s->nwarnings < SQ_MAX_BODIES) {
            /* the power of ten that brings it near 1 m: 0.001 for millimetres, 0.01 for cm */
            double hint = pow(10, -round(log10(diag)));
            const char *units = fabs(hint - 1e-3) < 1e-9 ? " (a mesh in millimetres)"
                                : fabs(hint - 1e-2) < 1e-9 ? " (a mesh in centimetres)" : "";
            char bp[256];
            join(bp, sizeof bp, path, "scale");
            char *wm = s->warnings[s->nwarnings++];
            if (snprintf(wm, sizeof s->warnings[0],
                     "%s: %s: the mesh's bounding-box diagonal is %g m, %s: are its units metres? "
                     "If not, set %s (now %g), e.g. \"scale\": %g%s",
                     c->label, p, diag, diag > 10 ? "above 10 m" : "below 1 mm", bp, scale,
                     hint * scale, units) < 0)
                wm[0] = 0;
            warned = 1;
        }
        if (offset[0] != 0 || offset[1] != 0 || offset[2] != 0) {
            for (int v = 0; v < m->nnodes; v++)
                for (int a = 0; a < 3; a++)
                    m->x[3 * v + a] += offset[a];
            for (int a = 0; a < 3; a++) {
                m->bbox_min[a] += offset[a];
                m->bbox_max[a] += offset[a];
            }
        }
        /* build the mesh's point-location grid now: a loaded scene is then read-only and
         * can be shared by worlds on several threads */
        double bary[4];
        sq_mesh_locate(m, m->x, bary);
        s->meshes[bi][def->nlevels] = m;
        s->level_index[bi][def->nlevels] = k;
        def->levels[def->nlevels] = m;
        def->nlevels++;
        if (def->nlevels > 1 && m->nnodes <= def->levels[def->nlevels - 2]->nnodes)
            return fail(c, p, "%d nodes, not more than the previous level's %d; list the levels coarse to fine",
                        m->nnodes, def->levels[def->nlevels - 2]->nnodes);
    }
    if (def->lod.mode == SQ_LOD_FIXED) {
        def->lod.level = 0;
        def->lod.max_level = 0;
    } else {
        def->lod.level -= first;
        def->lod.max_level -= first;
    }

    /* every constraint region must select nodes on every loaded level */
    for (int r = 0; r < def->nconstraints; r++)
        for (int k = 0; k < def->nlevels; k++) {
            const sq_mesh *m = def->levels[k];
            int n = 0;
            for (int v = 0; v < m->nnodes; v++)
                n += region_selects(&def->constraints[r], m->x + 3 * v);
            if (n == 0) {
                char fp[256];
                join(fp, sizeof fp, path, "fixed");
                join_index(p, sizeof p, fp, r);
                return fail(c, p, "selects no node of levels[%d] (%s, bounding box [%g, %g, %g] - [%g, %g, %g]); "
                                  "move the region onto the mesh",
                            s->level_index[bi][k], files[s->level_index[bi][k]], m->bbox_min[0],
                            m->bbox_min[1], m->bbox_min[2], m->bbox_max[0], m->bbox_max[1], m->bbox_max[2]);
            }
        }
    /* corotational elasticity: fem operator and fixed lod only (docs/physics.md section 9) */
    join(p, sizeof p, path, "elasticity");
    if (def->elasticity == SQ_ELASTICITY_COROTATIONAL && def->op != SQ_OPERATOR_FEM)
        return fail(c, p, "\"corotational\" needs \"operator\": \"fem\" (the paper operator has no corotational "
                          "form here); use \"elasticity\": \"linear\" with the paper operator");
    if (def->nodal_pressure && (def->elasticity != SQ_ELASTICITY_LINEAR || def->op != SQ_OPERATOR_FEM ||
                                def->lod.mode != SQ_LOD_FIXED)) {
        join(p, sizeof p, path, "pressure");
        return fail(c, p, "\"nodal\" runs with \"operator\": \"fem\", \"elasticity\": \"linear\" and fixed lod only; "
                          "use those, or \"pressure\": \"element\"");
    }
    if (def->elasticity == SQ_ELASTICITY_COROTATIONAL && def->lod.mode == SQ_LOD_ADAPTIVE)
        return fail(c, p, "\"corotational\" runs in fixed lod mode only (adaptive mode does not support it yet): "
                          "use \"lod\": {\"mode\": \"fixed\"} with \"corotational\", or \"elasticity\": "
                          "\"linear\" with adaptive lod");
    return 0;
}

/* ---- tools ------------------------------------------------------------------------- */

static int parse_tool(pctx *c, sq_scene *s, const cJSON *obj, int ti, const char *path)
{
    static const char *const keys[] = {"id", "name", "shape", "radius", "size", "keyframes", NULL};
    if (!cJSON_IsObject(obj))
        return fail(c, path, "expected an object, got %s; see docs/scenes.md", type_name(obj));
    if (check_keys(c, obj, path, keys))
        return -1;
    sq_tool_script *ts = &s->tools[ti];
    memset(ts, 0, sizeof *ts);
    char p[256];
    long id = ti;
    if (get_int(c, obj, path, "id", 0, INT_MAX, &id, NULL))
        return -1;
    ts->tool.id = (int)id;
    join(p, sizeof p, path, "id");
    for (int j = 0; j < ti; j++)
        if (s->tools[j].tool.id == ts->tool.id)
            return fail(c, p, "%ld is already the id of tools[%d]; give each tool its own id", id, j);
    snprintf(ts->name, sizeof ts->name, "tool%d", ti);
    if (get_string(c, obj, path, "name", ts->name, sizeof ts->name, NULL))
        return -1;
    join(p, sizeof p, path, "name");
    if (check_name(c, p, ts->name))
        return -1;

    char shape[16];
    int found;
    const cJSON *sh = get(obj, "shape");
    join(p, sizeof p, path, "shape");
    if (sh && cJSON_IsString(sh) && strlen(sh->valuestring) >= sizeof shape)
        return fail(c, p, "\"%s\" is not a shape; use \"sphere\", \"box\" or \"grab\"", sh->valuestring);
    if (get_string(c, obj, path, "shape", shape, sizeof shape, &found))
        return -1;
    if (!found)
        return fail(c, p, "missing; give \"sphere\", \"box\" or \"grab\"");
    if (!strcmp(shape, "sphere"))
        ts->tool.shape = SQ_TOOL_SPHERE;
    else if (!strcmp(shape, "box"))
        ts->tool.shape = SQ_TOOL_BOX;
    else if (!strcmp(shape, "grab"))
        ts->tool.shape = SQ_TOOL_GRAB;
    else
        return fail(c, p, "\"%s\" is not a shape; use \"sphere\", \"box\" or \"grab\"", shape);

    int hr, hs;
    double size[3] = {0, 0, 0};
    if (get_number(c, obj, path, "radius", &ts->tool.radius, &hr) || get_vec3(c, obj, path, "size", size, &hs))
        return -1;
    if (ts->tool.shape == SQ_TOOL_BOX) {
        join(p, sizeof p, path, hr ? "radius" : "size");
        if (hr)
            return fail(c, p, "a box tool has no radius; give \"size\": [sx, sy, sz] (full extents, m)");
        if (!hs)
            return fail(c, p, "missing; a box tool needs \"size\": [sx, sy, sz] (full extents, m)");
        for (int i = 0; i < 3; i++) {
            if (!(size[i] > 0))
                return fail(c, p, "%g on axis %c is out of range; use extents > 0 (m)", size[i], "xyz"[i]);
            ts->tool.half[i] = size[i] / 2;
        }
    } else {
        join(p, sizeof p, path, hs ? "size" : "radius");
        if (hs)
            return fail(c, p, "only box tools have a size; give \"radius\" (m) for a %s", shape);
        if (!hr)
            return fail(c, p, "missing; a %s tool needs \"radius\" (m)%s", shape,
                        ts->tool.shape == SQ_TOOL_GRAB ? ", the capture radius around its point" : "");
        if (range_pos(c, path, "radius", ts->tool.radius, "m"))
            return -1;
    }

    /* keyframes: t strictly increasing, pos, active (default true) */
    int bad;
    const cJSON *kf = get_typed(c, obj, path, "keyframes", 1, 1, &bad);
    if (bad)
        return -1;
    char kp[256];
    join(kp, sizeof kp, path, "keyframes");
    int nk = cJSON_GetArraySize(kf);
    if (nk < 1 || nk > SQ_MAX_KEYFRAMES)
        return fail(c, kp, "%d keyframes; give 1 to %d", nk, SQ_MAX_KEYFRAMES);
    int i = 0;
    for (const cJSON *e = kf->child; e; e = e->next, i++) {
        static const char *const kkeys[] = {"t", "pos", "active", NULL};
        join_index(p, sizeof p, kp, i);
        if (!cJSON_IsObject(e))
            return fail(c, p, "expected {\"t\": s, \"pos\": [x, y, z], \"active\": true}, got %s; see docs/scenes.md", type_name(e));
        if (check_keys(c, e, p, kkeys))
            return -1;
        sq_keyframe *k = &ts->keys[i];
        k->active = 1;
        if (get_required_number(c, e, p, "t", &k->t, "the time in s") || get_bool(c, e, p, "active", &k->active))
            return -1;
        if (get_vec3(c, e, p, "pos", k->pos, &found))
            return -1;
        if (!found) {
            char q[256];
            join(q, sizeof q, p, "pos");
            return fail(c, q, "missing; give the tool position [x, y, z] (m)");
        }
        if (k->t < 0 || (i > 0 && !(k->t > ts->keys[i - 1].t))) {
            char q[256];
            join(q, sizeof q, p, "t");
            return fail(c, q, "%g %s; keyframe times must be >= 0 and strictly increasing", k->t,
                        k->t < 0 ? "is negative" : "is not after the previous keyframe");
        }
    }
    ts->nkeys = nk;
    sq_tool_script_pose(ts, 0, &ts->tool);
    return 0;
}

/* ---- probes ------------------------------------------------------------------------ */

static int parse_probe(pctx *c, sq_scene *s, const cJSON *obj, int pi, const char *path)
{
    static const char *const keys[] = {"name", "body", "point", NULL};
    if (!cJSON_IsObject(obj))
        return fail(c, path, "expected an object {\"name\", \"body\", \"point\"}, got %s; see docs/scenes.md", type_name(obj));
    if (check_keys(c, obj, path, keys))
        return -1;
    sq_probe *pr = &s->probes[pi];
    char p[256];
    snprintf(pr->name, sizeof pr->name, "probe%d", pi);
    if (get_string(c, obj, path, "name", pr->name, sizeof pr->name, NULL))
        return -1;
    join(p, sizeof p, path, "name");
    if (check_name(c, p, pr->name))
        return -1;
    for (int j = 0; j < pi; j++)
        if (!strcmp(s->probes[j].name, pr->name))
            return fail(c, p, "\"%s\" is already the name of probes[%d]; give each probe its own name", pr->name, j);
    char body[64];
    int found;
    if (get_string(c, obj, path, "body", body, sizeof body, &found))
        return -1;
    join(p, sizeof p, path, "body");
    if (!found) {
        if (s->nbodies != 1)
            return fail(c, p, "missing; the scene has %d bodies, name the one to probe", s->nbodies);
        pr->body = 0;
    } else {
        pr->body = -1;
        for (int b = 0; b < s->nbodies; b++)
            if (!strcmp(s->body_names[b], body))
                pr->body = b;
        if (pr->body < 0)
            return fail(c, p, "\"%s\" is not a body of this scene; use one of the bodies[].name values", body);
    }
    if (get_vec3(c, obj, path, "point", pr->point, &found))
        return -1;
    join(p, sizeof p, path, "point");
    if (!found)
        return fail(c, p, "missing; give the rest-space point [x, y, z] (m) to record");
    /* the point must lie in the body's finest loaded mesh (small tolerance for surface points) */
    const sq_body_def *def = &s->bodies[pr->body];
    const sq_mesh *m = def->levels[def->nlevels - 1];
    double bary[4];
    int t = sq_mesh_locate(m, pr->point, bary);
    int inside = t >= 0;
    for (int i = 0; i < 4 && inside; i++)
        if (bary[i] < -1e-6)
            inside = 0;
    if (!inside)
        return fail(c, p, "[%g, %g, %g] is outside body \"%s\" (bounding box [%g, %g, %g] - [%g, %g, %g]); "
                          "use a point inside the rest mesh",
                    pr->point[0], pr->point[1], pr->point[2], s->body_names[pr->body], m->bbox_min[0],
                    m->bbox_min[1], m->bbox_min[2], m->bbox_max[0], m->bbox_max[1], m->bbox_max[2]);
    return 0;
}

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
    const cJSON *arr = get_typed(c, root, "", key, 1, 0, &bad);
    if (bad)
        return -1;
    int n = arr ? cJSON_GetArraySize(arr) : 0;
    if (n > max)
        return fail(c, key, "%d %s; at most %d are supported", n, key, max);
    char p[64];
    int i = 0;
    for (const cJSON *e = arr ? arr->child : NULL; e; e = e->next, i++) {
        join_index(p, sizeof p, key, i);
        if (parse(c, s, e, i, p))
            return -1;
    }
    return n;
}

static int parse_root(pctx *c, sq_scene *s, const cJSON *root)
{
    static const char *const keys[] = {"name", "description", "meshes_made_by", "gravity", "frame_rate",
                                       "duration", "bodies", "tools", "probes", NULL};
    if (!cJSON_IsObject(root))
        return fail(c, "", "the top level is %s; a scene is a JSON object {\"name\": ..., \"bodies\": [...]}",
                    type_name(root));
    if (check_keys(c, root, "", keys))
        return -1;
    if (get_string(c, root, "", "name", s->name, sizeof s->name, NULL) || check_name(c, "name", s->name) ||
        get_string(c, root, "", "description", s->description, sizeof s->description, NULL) ||
        get_string(c, root, "", "meshes_made_by", c->made_by, sizeof c->made_by, NULL))
        return -1;
    s->gravity[0] = s->gravity[1] = 0;
    s->gravity[2] = -9.81;
    if (get_vec3(c, root, "", "gravity", s->gravity, NULL))
        return -1;
    if (fabs(s->gravity[0]) + fabs(s->gravity[1]) + fabs(s->gravity[2]) > 1e4)
        return fail(c, "gravity", "[%g, %g, %g] is out of range; use components below 1e4 m/s^2",
                    s->gravity[0], s->gravity[1], s->gravity[2]);
    s->frame_rate = DEF_FRAME_RATE;
    if (get_number(c, root, "", "frame_rate", &s->frame_rate, NULL))
        return -1;
    if (!(s->frame_rate > 0 && s->frame_rate <= 10000))
        return fail(c, "frame_rate", "%g is out of range; use 0 < frame_rate <= 10000 (Hz)", s->frame_rate);
    s->duration = DEF_DURATION;
    if (get_number(c, root, "", "duration", &s->duration, NULL))
        return -1;
    if (!(s->duration > 0 && s->duration <= 1e6))
        return fail(c, "duration", "%g is out of range; use 0 < duration <= 1e6 (s)", s->duration);

    int bad;
    const cJSON *bodies = get_typed(c, root, "", "bodies", 1, 1, &bad);
    if (bad)
        return -1;
    int nb = cJSON_GetArraySize(bodies);
    if (nb < 1 || nb > SQ_MAX_BODIES)
        return fail(c, "bodies", "%d bodies; give 1 to %d", nb, SQ_MAX_BODIES);
    char p[64];
    int i = 0;
    for (const cJSON *e = bodies->child; e; e = e->next, i++) {
        join_index(p, sizeof p, "bodies", i);
        s->nbodies = i; /* bodies loaded so far are freed by the caller on error */
        if (parse_body(c, s, e, i, p))
            return -1;
    }
    s->nbodies = nb;

    int nt = parse_list(c, s, root, "tools", SQ_MAX_TOOLS, parse_tool);
    if (nt < 0)
        return -1;
    s->ntools = nt;

    int np = parse_list(c, s, root, "probes", SQ_MAX_PROBES, parse_probe);
    if (np < 0)
        return -1;
    s->nprobes = np;
    return 0;
}

sq_scene *sq_scene_parse(const char *json, const char *base_dir, const char *label, sq_err *err)
{
    pctx c = {label && label[0] ? label : "scene", base_dir, err, ""};
    sq_err local = {{0}};
    if (!c.err)
        c.err = &local;
    if (!json) {
        fail(&c, "", "no text to parse");
        return NULL;
    }
    const char *q = json;
    while (*q == ' ' || *q == '\t' || *q == '\n' || *q == '\r')
        q++;
    if (!*q) {
        fail(&c, "", "empty; a scene is a JSON object {\"name\": ..., \"bodies\": [...]} (see docs/scenes.md)");
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
        fail(&c, "", "line %d, column %d: invalid JSON near '%s'; check for a missing comma, quote or "
                     "bracket (comments and trailing commas are not JSON)", line, col, near);
        return NULL;
    }
    sq_scene *s = sq_calloc(1, sizeof *s);
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
    def->material.mu = 40000;
    def->material.lambda = 100000;
    def->material.density = 1000;
    def->material.rayleigh_mass = 2.0;
    def->material.rayleigh_stiffness = 0;
    def->material.use_viscosity = 0;
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
    free(s);
}

/* an active scripted tool's activation point: the pose of the first keyframe of the run of
 * active keyframes that ends at keyframe cur */
static void script_origin(const sq_tool_script *s, int cur, sq_tool *out)
{
    out->has_origin = 0;
    if (!out->active || cur < 0)
        return;
    int j = cur;
    while (j > 0 && s->keys[j - 1].active)
        j--;
    memcpy(out->origin, s->keys[j].pos, sizeof out->origin);
    out->has_origin = 1;
}

void sq_tool_script_pose(const sq_tool_script *s, double t, sq_tool *out)
{
    *out = s->tool;
    out->has_origin = 0;
    if (s->nkeys <= 0) {
        out->active = 0;
        return;
    }
    const sq_keyframe *k = s->keys;
    int n = s->nkeys;
    if (t <= k[0].t) {
        memcpy(out->pos, k[0].pos, sizeof out->pos);
        out->active = t >= k[0].t ? k[0].active : 0;
        script_origin(s, 0, out);
        return;
    }
    if (t >= k[n - 1].t) {
        memcpy(out->pos, k[n - 1].pos, sizeof out->pos);
        out->active = k[n - 1].active;
        script_origin(s, n - 1, out);
        return;
    }
    /* k[i].t <= t < k[i+1].t */
    int lo = 0, hi = n - 1;
    while (hi - lo > 1) {
        int mid = (lo + hi) / 2;
        if (k[mid].t <= t)
            lo = mid;
        else
            hi = mid;
    }
    double a = (t - k[lo].t) / (k[hi].t - k[lo].t);
    for (int i = 0; i < 3; i++)
        out->pos[i] = k[lo].pos[i] + a * (k[hi].pos[i] - k[lo].pos[i]);
    out->active = k[lo].active;
    script_origin(s, lo, out);
}
