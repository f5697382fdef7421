/* gl.c - draw a draw list with OSMesa (llvmpipe): fixed-function OpenGL, two directional
 * lights, per-vertex colours, then a box-filter downsample into top-down RGB rows. */
#define GL_GLEXT_PROTOTYPES
#include <GL/gl.h>
#include <GL/osmesa.h>
#include <math.h>
#include <stdlib.h>
#include <string.h>

#include "render/render.h"

#define PI 3.14159265358979323846
#define FB_MAX_SIDE 8192 /* largest framebuffer side (8192^2 RGBA = 256 MB, twice with Mesa's copy) */

struct sq_renderer {
    OSMesaContext ctx;
    int width, height;     /* output image */
    int ss;                /* samples per side */
    int fw, fh;            /* framebuffer = output x ss */
    unsigned char *buf;    /* RGBA framebuffer, rows bottom-up (fw x fh x 4) */
};

sq_renderer *sq_renderer_create(int width, int height, int supersample, sq_err *err)
{
    if (supersample < 1 || supersample > 4) {
        sq_err_set(err, "render: supersample %d must be 1 to 4", supersample);
        return NULL;
    }
    if (width < 1 || height < 1 || (long)width * supersample > FB_MAX_SIDE ||
        (long)height * supersample > FB_MAX_SIDE) {
        sq_err_set(err, "render: image %dx%d at supersample %d needs a %ldx%ld framebuffer, above "
                   "%d per side; lower the supersampling or the size", width, height, supersample,
                   (long)width * supersample, (long)height * supersample, FB_MAX_SIDE);
        return NULL;
    }
    sq_renderer *r = sq_calloc(1, sizeof *r);
    r->width = width;
    r->height = height;
    r->ss = supersample;
    r->fw = width * supersample;
    r->fh = height * supersample;
    r->ctx = OSMesaCreateContextExt(OSMESA_RGBA, 24, 0, 0, NULL);
    if (!r->ctx) {
        free(r);
        sq_err_set(err, "render: OSMesa context creation failed; is libosmesa6 installed "
                   "(make deps)?");
        return NULL;
    }
    r->buf = sq_malloc((size_t)r->fw * r->fh * 4);
    return r;
}

void sq_renderer_destroy(sq_renderer *r)
{
    if (!r)
        return;
    OSMesaDestroyContext(r->ctx);
    free(r->buf);
    free(r);
}

/* column-major view matrix looking from eye to target */
static void look_at(const double eye[3], const double target[3], const double up[3], double m[16])
{
    double f[3], s[3], u[3];
    for (int k = 0; k < 3; k++)
        f[k] = target[k] - eye[k];
    double n = sqrt(f[0] * f[0] + f[1] * f[1] + f[2] * f[2]);
    for (int k = 0; k < 3; k++)
        f[k] /= n;
    s[0] = f[1] * up[2] - f[2] * up[1];
    s[1] = f[2] * up[0] - f[0] * up[2];
    s[2] = f[0] * up[1] - f[1] * up[0];
    n = sqrt(s[0] * s[0] + s[1] * s[1] + s[2] * s[2]);
    for (int k = 0; k < 3; k++)
        s[k] /= n;
    u[0] = s[1] * f[2] - s[2] * f[1];
    u[1] = s[2] * f[0] - s[0] * f[2];
    u[2] = s[0] * f[1] - s[1] * f[0];
    memset(m, 0, 16 * sizeof(double));
    for (int k = 0; k < 3; k++) {
        m[4 * k + 0] = s[k];
        m[4 * k + 1] = u[k];
        m[4 * k + 2] = -f[k];
    }
    m[12] = -(s[0] * eye[0] + s[1] * eye[1] + s[2] * eye[2]);
    m[13] = -(u[0] * eye[0] + u[1] * eye[1] + u[2] * eye[2]);
    m[14] = f[0] * eye[0] + f[1] * eye[1] + f[2] * eye[2];
    m[15] = 1.0;
}

/* lights are fixed in eye space: a key light from the upper left, a weak fill from the right */
static void setup_lights(void)
{
    static const GLfloat ambient[4] = {0.30f, 0.30f, 0.30f, 1.0f};
    static const GLfloat key_pos[4] = {-0.30f, 0.50f, 0.81f, 0.0f};
    static const GLfloat key_diffuse[4] = {0.68f, 0.68f, 0.68f, 1.0f};
    static const GLfloat key_specular[4] = {0.25f, 0.25f, 0.25f, 1.0f};
    static const GLfloat fill_pos[4] = {0.75f, -0.05f, 0.45f, 0.0f};
    static const GLfloat fill_diffuse[4] = {0.30f, 0.30f, 0.32f, 1.0f};
    static const GLfloat black[4] = {0.0f, 0.0f, 0.0f, 1.0f};
    static const GLfloat mat_specular[4] = {0.18f, 0.18f, 0.18f, 1.0f};

    glEnable(GL_LIGHTING);
    glLightModelfv(GL_LIGHT_MODEL_AMBIENT, ambient);
    glLightModeli(GL_LIGHT_MODEL_TWO_SIDE, GL_TRUE);
    glEnable(GL_LIGHT0);
    glLightfv(GL_LIGHT0, GL_POSITION, key_pos);
    glLightfv(GL_LIGHT0, GL_AMBIENT, black);
    glLightfv(GL_LIGHT0, GL_DIFFUSE, key_diffuse);
    glLightfv(GL_LIGHT0, GL_SPECULAR, key_specular);
    glEnable(GL_LIGHT1);
    glLightfv(GL_LIGHT1, GL_POSITION, fill_pos);
    glLightfv(GL_LIGHT1, GL_AMBIENT, black);
    glLightfv(GL_LIGHT1, GL_DIFFUSE, fill_diffuse);
    glLightfv(GL_LIGHT1, GL_SPECULAR, black);
    glEnable(GL_COLOR_MATERIAL);
    glColorMaterial(GL_FRONT_AND_BACK, GL_AMBIENT_AND_DIFFUSE);
    glMaterialfv(GL_FRONT_AND_BACK, GL_SPECULAR, mat_specular);
    glMaterialf(GL_FRONT_AND_BACK, GL_SHININESS, 32.0f);
}

int sq_renderer_draw(sq_renderer *r, const sq_drawlist *dl, unsigned char *rgb, sq_err *err)
{
    if (!OSMesaMakeCurrent(r->ctx, r->buf, GL_UNSIGNED_BYTE, r->fw, r->fh))
        return sq_err_set(err, "render: OSMesaMakeCurrent failed for %dx%d", r->fw, r->fh);

    glViewport(0, 0, r->fw, r->fh);
    glClearColor(dl->background[0], dl->background[1], dl->background[2], 1.0f);
    glClearDepth(1.0);
    glClear(GL_COLOR_BUFFER_BIT | GL_DEPTH_BUFFER_BIT);
    glEnable(GL_DEPTH_TEST);
    glDepthFunc(GL_LESS);
    glDisable(GL_CULL_FACE);
    glShadeModel(GL_SMOOTH);

    /* projection */
    glMatrixMode(GL_PROJECTION);
    glLoadIdentity();
    double top = dl->znear * tan(0.5 * dl->fovy_deg * PI / 180.0);
    double right = top * (double)r->width / r->height;
    glFrustum(-right, right, -top, top, dl->znear, dl->zfar);

    /* lights in eye space, then the view */
    glMatrixMode(GL_MODELVIEW);
    glLoadIdentity();
    setup_lights();
    double view[16];
    look_at(dl->eye, dl->target, dl->up, view);
    glMultMatrixd(view);

    if (dl->ntris > 0) {
        glEnableClientState(GL_VERTEX_ARRAY);
        glEnableClientState(GL_NORMAL_ARRAY);
        glEnableClientState(GL_COLOR_ARRAY);
        glVertexPointer(3, GL_FLOAT, sizeof(sq_draw_vertex), dl->v[0].pos);
        glNormalPointer(GL_FLOAT, sizeof(sq_draw_vertex), dl->v[0].normal);
        glColorPointer(4, GL_UNSIGNED_BYTE, sizeof(sq_draw_vertex), dl->v[0].rgba);
        glDrawElements(GL_TRIANGLES, 3 * dl->ntris, GL_UNSIGNED_INT, dl->idx);
        glDisableClientState(GL_VERTEX_ARRAY);
        glDisableClientState(GL_NORMAL_ARRAY);
        glDisableClientState(GL_COLOR_ARRAY);
    }
    glFinish();
    GLenum e = glGetError();
    /* release the context so another thread may use this renderer later */
    OSMesaMakeCurrent(NULL, NULL, GL_UNSIGNED_BYTE, 0, 0);
    if (e != GL_NO_ERROR)
        return sq_err_set(err, "render: OpenGL error 0x%04x while drawing", (unsigned)e);

    /* box-filter ss x ss samples per pixel; framebuffer rows are bottom-up */
    const int ss = r->ss, n = ss * ss;
    for (int y = 0; y < r->height; y++) {
        unsigned char *out = rgb + (size_t)y * r->width * 3;
        int fy0 = (r->height - 1 - y) * ss;
        for (int x = 0; x < r->width; x++) {
            unsigned sum[3] = {0, 0, 0};
            for (int sy = 0; sy < ss; sy++) {
                const unsigned char *row = r->buf + ((size_t)(fy0 + sy) * r->fw + (size_t)x * ss) * 4;
                for (int sx = 0; sx < ss; sx++)
                    for (int k = 0; k < 3; k++)
                        sum[k] += row[4 * sx + k];
            }
            for (int k = 0; k < 3; k++)
                out[3 * x + k] = (unsigned char)((sum[k] + n / 2) / n);
        }
    }
    return 0;
}
