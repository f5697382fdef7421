/* options.c - palette (compiled default and palette.json), colour modes, camera and size
 * parsing for the renderer. */
#include <cJSON.h>
#include <errno.h>
#include <math.h>
#include <stdlib.h>
#include <string.h>

#include "render/render.h"

/* the compiled-in palette; must equal web/palette.json (checked by test_render.c) */
static const struct {
    const char *key;
    int index; /* level index for "level", -1 otherwise */
    const char *hex;
} default_palette[] = {
    {"level", 0, "#4e79a7"},     {"level", 1, "#59a14f"},   {"level", 2, "#edc948"},
    {"level", 3, "#f28e2b"},     {"level", 4, "#e15759"},   {"level", 5, "#b07aa1"},
    {"plain", -1, "#d9a38c"},    {"stress_low", -1, "#2c7bb6"},
    {"stress_mid", -1, "#ffffbf"}, {"stress_high", -1, "#d7191c"},
    {"background", -1, "#20242b"}, {"floor", -1, "#5b6270"},
    {"floor_line", -1, "#737b8a"}, {"tool", -1, "#c8ccd4"},
    {"probe", -1, "#ff3ea5"},      {"obstacle", -1, "#9a948a"},
};

/* "#rrggbb" -> 0..1 floats; -1 if malformed */
static int parse_hex(const char *s, float out[3])
{
    if (!s || s[0] != '#' || strlen(s) != 7)
        return -1;
    for (int c = 0; c < 3; c++) {
        int v = 0;
        for (int k = 0; k < 2; k++) {
            char ch = s[1 + 2 * c + k];
            int d;
            if (ch >= '0' && ch <= '9')
                d = ch - '0';
            else if (ch >= 'a' && ch <= 'f')
                d = ch - 'a' + 10;
            else if (ch >= 'A' && ch <= 'F')
                d = ch - 'A' + 10;
            else
                return -1;
            v = v * 16 + d;
        }
        out[c] = (float)v / 255.0f;
    }
    return 0;
}

/* the palette slot for a key (non-level keys) */
static float *palette_slot(sq_palette *p, const char *key)
{
    if (!strcmp(key, "plain"))
        return p->plain;
    if (!strcmp(key, "stress_low"))
        return p->stress_low;
    if (!strcmp(key, "stress_mid"))
        return p->stress_mid;
    if (!strcmp(key, "stress_high"))
        return p->stress_high;
    if (!strcmp(key, "background"))
        return p->background;
    if (!strcmp(key, "floor"))
        return p->floor;
    if (!strcmp(key, "floor_line"))
        return p->floor_line;
    if (!strcmp(key, "tool"))
        return p->tool;
    if (!strcmp(key, "probe"))
        return p->probe;
    if (!strcmp(key, "obstacle"))
        return p->obstacle;
    return NULL;
}

void sq_palette_default(sq_palette *p)
{
    memset(p, 0, sizeof *p);
    for (size_t i = 0; i < SQ_COUNTOF(default_palette); i++) {
        float *slot = default_palette[i].index >= 0 ? p->level[default_palette[i].index]
                                                    : palette_slot(p, default_palette[i].key);
        parse_hex(default_palette[i].hex, slot);
    }
}

int sq_palette_parse(sq_palette *p, const char *json, const char *label, sq_err *err)
{
    cJSON *root = cJSON_Parse(json);
    if (!root) {
        const char *at = cJSON_GetErrorPtr();
        return sq_err_set(err, "%s: not valid JSON near '%.20s'; fix the file (see docs/render.md)",
                          label, at ? at : "?");
    }
    if (!cJSON_IsObject(root)) {
        cJSON_Delete(root);
        return sq_err_set(err, "%s: the palette must be a JSON object", label);
    }
    sq_palette out = *p;
    int rc = 0;
    for (const cJSON *it = root->child; it && rc == 0; it = it->next) {
        if (!strcmp(it->string, "about") || !strcmp(it->string, "version"))
            continue;
        if (!strcmp(it->string, "level")) {
            int n = cJSON_IsArray(it) ? cJSON_GetArraySize(it) : -1;
            if (n < 1 || n > SQ_MAX_LEVELS) {
                rc = sq_err_set(err, "%s: level: must be an array of 1 to %d colours \"#rrggbb\"",
                                label, SQ_MAX_LEVELS);
                break;
            }
            for (int i = 0; i < n; i++) {
                const cJSON *c = cJSON_GetArrayItem(it, i);
                if (parse_hex(cJSON_GetStringValue(c), out.level[i]) != 0) {
                    rc = sq_err_set(err, "%s: level[%d]: must be a colour \"#rrggbb\"", label, i);
                    break;
                }
            }
            continue;
        }
        float *slot = palette_slot(&out, it->string);
        if (!slot) {
            rc = sq_err_set(err, "%s: %s: unknown key; known keys: level, plain, stress_low, "
                            "stress_mid, stress_high, background, floor, floor_line, tool, probe, "
                            "obstacle",
                            label, it->string);
            break;
        }
        if (parse_hex(cJSON_GetStringValue(it), slot) != 0)
            rc = sq_err_set(err, "%s: %s: must be a colour \"#rrggbb\"", label, it->string);
    }
    cJSON_Delete(root);
    if (rc == 0)
        *p = out;
    return rc;
}

int sq_palette_load(sq_palette *p, const char *path, sq_err *err)
{
    char *text = sq_read_file(path, NULL, 1 << 20, err);
    if (!text)
        return -1;
    int rc = sq_palette_parse(p, text, path, err);
    free(text);
    return rc;
}

int sq_color_mode_parse(const char *s, sq_color_mode *mode, sq_err *err)
{
    static const char *names[] = {"level", "plain", "stress"};
    for (int i = 0; i < 3; i++)
        if (s && !strcmp(s, names[i])) {
            *mode = (sq_color_mode)i;
            return 0;
        }
    return sq_err_set(err, "colour mode '%s': use level, plain or stress", s ? s : "");
}

const char *sq_color_mode_name(sq_color_mode mode)
{
    switch (mode) {
    case SQ_COLOR_LEVEL: return "level";
    case SQ_COLOR_PLAIN: return "plain";
    case SQ_COLOR_STRESS: return "stress";
    }
    return "?";
}

sq_camera sq_camera_default(void)
{
    sq_camera c;
    memset(&c, 0, sizeof c);
    c.az_deg = 30.0;
    c.el_deg = 20.0;
    c.dist = 0.0;
    c.fov_deg = 35.0;
    return c;
}

/* comma-separated finite numbers; returns the count, or -1 on a bad token */
static int parse_numbers(const char *s, double *out, int max)
{
    int n = 0;
    const char *p = s;
    while (*p) {
        if (n == max)
            return -1;
        char *end;
        errno = 0;
        double v = strtod(p, &end);
        if (end == p || errno || !isfinite(v))
            return -1;
        out[n++] = v;
        p = end;
        if (*p == ',')
            p++;
        else if (*p)
            return -1;
        else
            break;
    }
    return n;
}

int sq_camera_parse(const char *s, sq_camera *c, sq_err *err)
{
    double v[6];
    int n = s ? parse_numbers(s, v, 6) : -1;
    sq_camera out = *c;
    if (n == 2 || n == 3) {
        out.eye_target = 0;
        out.az_deg = v[0];
        out.el_deg = v[1];
        out.dist = n == 3 ? v[2] : 0.0;
        if (out.el_deg < -89.0 || out.el_deg > 89.0)
            return sq_err_set(err, "camera '%s': elevation %g must be in [-89, 89] degrees", s, v[1]);
        if (n == 3 && out.dist <= 0.0)
            return sq_err_set(err, "camera '%s': distance %g must be > 0 m", s, v[2]);
    } else if (n == 6) {
        out.eye_target = 1;
        memcpy(out.eye, v, sizeof out.eye);
        memcpy(out.target, v + 3, sizeof out.target);
        double d = sqrt((v[0] - v[3]) * (v[0] - v[3]) + (v[1] - v[4]) * (v[1] - v[4]) +
                        (v[2] - v[5]) * (v[2] - v[5]));
        if (d < 1e-9)
            return sq_err_set(err, "camera '%s': eye and target are the same point", s);
    } else {
        return sq_err_set(err, "camera '%s': use AZ,EL or AZ,EL,DIST (degrees, metres) or "
                          "EX,EY,EZ,TX,TY,TZ (eye and target, metres)", s ? s : "");
    }
    *c = out;
    return 0;
}

sq_render_opts sq_render_opts_default(void)
{
    sq_render_opts o;
    memset(&o, 0, sizeof o);
    o.color = SQ_COLOR_LEVEL;
    o.camera = sq_camera_default();
    sq_palette_default(&o.palette);
    o.stress_max = 0.0;
    o.floor = 1;
    o.obstacles = 1;
    o.tools = 1;
    o.probes = 1;
    o.supersample = 2;
    return o;
}

int sq_render_parse_size(const char *s, int max_side, int *width, int *height, sq_err *err)
{
    if (!s || !*s)
        return sq_err_set(err, "size: empty; use WxH, e.g. 800x600");
    char *end;
    errno = 0;
    long w = strtol(s, &end, 10);
    if (end == s || errno || (*end != 'x' && *end != 'X'))
        return sq_err_set(err, "size '%s': use WxH, e.g. 800x600", s);
    const char *hs = end + 1;
    errno = 0;
    long h = strtol(hs, &end, 10);
    if (end == hs || errno || *end)
        return sq_err_set(err, "size '%s': use WxH, e.g. 800x600", s);
    if (w < SQ_RENDER_MIN_SIZE || h < SQ_RENDER_MIN_SIZE || w > max_side || h > max_side)
        return sq_err_set(err, "size '%s': each side must be in [%d, %d] pixels", s,
                          SQ_RENDER_MIN_SIZE, max_side);
    *width = (int)w;
    *height = (int)h;
    return 0;
}
