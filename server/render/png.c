/* png.c - PNG encoding (in memory, deterministic: no time or text chunks) and decoding
 * with libpng, and writing the bytes to a file. */
#include <errno.h>
#include <png.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "render/render.h"

/* growable output buffer for libpng's write callback */
typedef struct png_out {
    unsigned char *data;
    size_t len, cap;
} png_out;

static void write_cb(png_structp png, png_bytep data, png_size_t n)
{
    png_out *o = png_get_io_ptr(png);
    if (o->len + n > o->cap) {
        size_t cap = o->cap ? o->cap : 65536;
        while (cap < o->len + n)
            cap *= 2;
        o->data = sq_realloc(o->data, cap);
        o->cap = cap;
    }
    memcpy(o->data + o->len, data, n);
    o->len += n;
}

static void flush_cb(png_structp png)
{
    (void)png;
}

/* libpng reports errors by longjmp; keep its message for ours */
static void error_cb(png_structp png, png_const_charp msg)
{
    sq_err *err = png_get_error_ptr(png);
    if (err)
        sq_err_set(err, "png: %s", msg);
    png_longjmp(png, 1);
}

static void warning_cb(png_structp png, png_const_charp msg)
{
    (void)png;
    (void)msg;
}

int sq_png_encode(const unsigned char *rgb, int width, int height, unsigned char **png,
                  size_t *len, sq_err *err)
{
    *png = NULL;
    *len = 0;
    if (width < 1 || height < 1)
        return sq_err_set(err, "png: bad image size %dx%d", width, height);
    png_structp p = png_create_write_struct(PNG_LIBPNG_VER_STRING, err, error_cb, warning_cb);
    if (!p)
        return sq_err_set(err, "png: out of memory creating the encoder");
    png_infop info = png_create_info_struct(p);
    png_out *volatile out = sq_calloc(1, sizeof *out);
    png_bytep *volatile rows = NULL;
    if (!info || setjmp(png_jmpbuf(p))) {
        png_destroy_write_struct(&p, &info);
        free(out->data);
        free(out);
        free(rows);
        if (!err || !err->msg[0])
            sq_err_set(err, "png: encoding failed");
        return -1;
    }
    png_set_write_fn(p, out, write_cb, flush_cb);
    png_set_IHDR(p, info, (png_uint_32)width, (png_uint_32)height, 8, PNG_COLOR_TYPE_RGB,
                 PNG_INTERLACE_NONE, PNG_COMPRESSION_TYPE_DEFAULT, PNG_FILTER_TYPE_DEFAULT);
    /* fast settings: rendered images are mostly flat colour; measured on an 800x600 render,
     * no filter at level 3 takes ~1/3 of the time of libpng's defaults (level 6, adaptive
     * filters) for files ~40% larger (87 kB instead of 62 kB) */
    png_set_compression_level(p, 3);
    png_set_filter(p, PNG_FILTER_TYPE_BASE, PNG_FILTER_NONE);
    rows = sq_malloc((size_t)height * sizeof *rows);
    for (int y = 0; y < height; y++)
        rows[y] = (png_bytep)(rgb + (size_t)y * width * 3);
    png_set_rows(p, info, rows);
    png_write_png(p, info, PNG_TRANSFORM_IDENTITY, NULL);
    png_destroy_write_struct(&p, &info);
    free(rows);
    *png = out->data;
    *len = out->len;
    free(out);
    return 0;
}

int sq_png_write_file(const char *path, const unsigned char *png, size_t len, sq_err *err)
{
    FILE *f = fopen(path, "wb");
    if (!f)
        return sq_err_set(err, "%s: cannot write: %s; check that the directory exists and is "
                          "writable", path, strerror(errno));
    size_t n = fwrite(png, 1, len, f);
    int close_rc = fclose(f);
    if (n != len || close_rc != 0)
        return sq_err_set(err, "%s: write failed (%zu of %zu bytes): %s; check free space",
                          path, n, len, strerror(errno));
    return 0;
}

int sq_png_decode(const unsigned char *png, size_t len, unsigned char **rgb, int *width,
                  int *height, sq_err *err)
{
    *rgb = NULL;
    png_image img;
    memset(&img, 0, sizeof img);
    img.version = PNG_IMAGE_VERSION;
    if (!png_image_begin_read_from_memory(&img, png, len))
        return sq_err_set(err, "png: not a readable PNG: %s", img.message);
    img.format = PNG_FORMAT_RGB;
    size_t size = PNG_IMAGE_SIZE(img);
    unsigned char *buf = sq_malloc(size);
    if (!png_image_finish_read(&img, NULL, buf, 0, NULL)) {
        free(buf);
        png_image_free(&img);
        return sq_err_set(err, "png: decoding failed: %s", img.message);
    }
    *rgb = buf;
    *width = (int)img.width;
    *height = (int)img.height;
    return 0;
}
