/* Decode one rectangle of a JPEG picture with libjpeg-turbo's partial decompression.
 *
 * jpeg_skip_scanlines skips the rows above the rectangle (their entropy-coded data is read, no
 * IDCT, upsampling or colour conversion is done), jpeg_crop_scanline limits every decoded row
 * to the iMCU columns covering it, and decompression stops after its last row: a window
 * around a small target costs a fraction of the whole picture. A picture whose restart
 * intervals start whole MCU rows is not even read above the rectangle: decoding starts at the
 * last group of eight intervals above it (restart_seek), where the entropy coder starts
 * afresh, so that the rows above cost nothing at all. The pixels land where the
 * whole picture's would, in a caller's frame-sized buffer (client/media/images.py says when they
 * equal the whole decode's; tests/service/test_region_decode.py checks it bit for bit).
 *
 * decode_region(data, out, top, left, bottom, right) -> (top, left, bottom, right)
 *   data: the JPEG bytes; out: a writable C-contiguous uint8 buffer of height * width * n
 *   bytes (n = 3, BGR, for a YCbCr picture; 1 for a grey one); the rectangle: half-open array
 *   indices. Returns the rows and columns actually decoded (the rectangle widened to whole
 *   iMCUs), or raises ValueError: a picture this decoder does not take (another colour
 *   space, a progressive or arithmetic-coded one), a buffer of the wrong size, or a stream
 *   libjpeg reports as damaged (an error or a warning: the caller decodes the whole picture,
 *   which decides).
 *
 * header(data) -> (width, height, components, colour space code, progressive)
 *
 * seek_row(data, top) -> the first row decode_region reads for a rectangle from row `top`
 *   down (a restart interval's start; 0 when the picture offers none to start at)
 */
#define PY_SSIZE_T_CLEAN
#include <Python.h>

#include <setjmp.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include <jpeglib.h>

struct region_error {
    struct jpeg_error_mgr pub;
    jmp_buf jump;
    int warned;
    char message[JMSG_LENGTH_MAX];
    unsigned char *owned; /* a stream made here (restart_seek), freed on every way out */
};

static void on_error(j_common_ptr cinfo) {
    struct region_error *err = (struct region_error *)cinfo->err;
    (*cinfo->err->format_message)(cinfo, err->message);
    longjmp(err->jump, 1);
}

static void on_message(j_common_ptr cinfo, int level) {
    struct region_error *err = (struct region_error *)cinfo->err;
    if (level < 0 && !err->warned) { /* a warning: corrupt data libjpeg would paper over */
        err->warned = 1;
        (*cinfo->err->format_message)(cinfo, err->message);
    }
}

/* libjpeg's errors longjmp back to the caller's setjmp; its warnings are remembered. */
static void route_errors(struct jpeg_decompress_struct *cinfo, struct region_error *err) {
    memset(err, 0, sizeof *err);
    cinfo->err = jpeg_std_error(&err->pub);
    err->pub.error_exit = on_error;
    err->pub.emit_message = on_message;
}

/* The offset of the SOF segment's 16-bit height among the header's segments (before the
 * scan's data at `end`), or 0. */
static size_t sof_height_at(const unsigned char *data, size_t end) {
    size_t i = 2;
    while (i + 4 <= end) {
        if (data[i] != 0xFF) return 0;
        unsigned char marker = data[i + 1];
        if (marker == 0xFF) { i += 1; continue; } /* fill byte */
        if (marker == 0x01 || (marker >= 0xD0 && marker <= 0xD8)) { i += 2; continue; }
        size_t length = ((size_t)data[i + 2] << 8) | data[i + 3];
        if (marker >= 0xC0 && marker <= 0xCF && marker != 0xC4 && marker != 0xC8 &&
            marker != 0xCC)
            return i + 9 <= end ? i + 5 : 0;
        if (length < 2) return 0;
        i += 2 + length;
    }
    return 0;
}

/* Where the entropy-coded data after the `count`-th restart marker of the scan starting at
 * `start` begins, or 0 (fewer markers, another marker first, or one out of sequence). */
static size_t after_restart(const unsigned char *data, size_t size, size_t start,
                            unsigned long count) {
    unsigned long seen = 0;
    size_t i = start;
    while (i + 1 < size) {
        const unsigned char *hit = memchr(data + i, 0xFF, size - i - 1);
        if (hit == NULL) return 0;
        size_t j = (size_t)(hit - data);
        unsigned char next = data[j + 1];
        if (next == 0x00 || next == 0xFF) { /* a stuffed 0xFF, or fill */
            i = j + 1 + (next == 0x00);
            continue;
        }
        if (next < 0xD0 || next > 0xD7 || next != 0xD0 + (seen & 7)) return 0;
        if (++seen == count) return j + 2;
        i = j + 2;
    }
    return 0;
}

/* Restart seek. A baseline scan's restart markers reset the entropy coder and the DC
 * predictions, so the data after one decodes on its own. When every interval covers whole
 * MCU rows, a picture made of the headers (its height less the rows skipped) and the data
 * from the start of an interval on is the picture's rows from there down, pixel for pixel
 * but for the first row's chroma upsampling context (one row; the caller trusts pixels 8
 * rows inside the decoded rectangle). The interval chosen is a multiple of eight, whose
 * marker is the RST0 that libjpeg expects first: the stream needs no renumbering, and at
 * most eight intervals above the rectangle are decoded (and skipped).
 *
 * After jpeg_read_header on `data`: the first row of the made stream (0: no seek, the
 * picture is decoded from its top) and the made stream in err->owned, its size in *made. */
static int restart_seek(j_decompress_ptr cinfo, struct region_error *err,
                        const unsigned char *data, size_t size, int top, size_t *made) {
    if (cinfo->restart_interval == 0 || cinfo->progressive_mode ||
        jpeg_has_multiple_scans(cinfo) || cinfo->comps_in_scan != cinfo->num_components)
        return 0;
    int single = cinfo->num_components == 1;
    size_t mcu_w = single ? 8 : 8 * (size_t)cinfo->max_h_samp_factor;
    size_t mcu_h = single ? 8 : 8 * (size_t)cinfo->max_v_samp_factor;
    size_t per_row = (cinfo->image_width + mcu_w - 1) / mcu_w;
    if (per_row == 0 || cinfo->restart_interval % per_row != 0) return 0;
    size_t group = 8 * (cinfo->restart_interval / per_row) * mcu_h; /* rows of 8 intervals */
    size_t groups = (size_t)top / group;
    if (groups == 0) return 0;
    /* the scan's data, where the header reading stopped: in `data` only if libjpeg did not
     * run out of it (its memory source then feeds a fake end marker of its own) */
    uintptr_t next = (uintptr_t)cinfo->src->next_input_byte, begin = (uintptr_t)data;
    if (next < begin || next - begin > size) return 0;
    size_t start = (size_t)(next - begin);
    size_t from = after_restart(data, size, start, 8 * groups);
    size_t sof = sof_height_at(data, start);
    size_t first = groups * group;
    if (from == 0 || sof == 0 || first >= cinfo->image_height) return 0;
    err->owned = malloc(start + (size - from));
    if (err->owned == NULL) return 0;
    memcpy(err->owned, data, start);
    memcpy(err->owned + start, data + from, size - from);
    size_t rows = cinfo->image_height - first;
    err->owned[sof] = (unsigned char)(rows >> 8);
    err->owned[sof + 1] = (unsigned char)(rows & 0xFF);
    *made = start + (size - from);
    return (int)first;
}

typedef struct {
    int top, left, bottom, right;
    const char *failure; /* static text, or NULL */
} outcome;

/* The decoding itself, without the GIL: libjpeg's errors come back through longjmp. */
static int decode(struct jpeg_decompress_struct *cinfo, struct region_error *err,
                  const unsigned char *data, size_t size, unsigned char *out, size_t out_size,
                  outcome *res) {
    unsigned char *volatile base = out;
    if (setjmp(err->jump)) {
        jpeg_destroy_decompress(cinfo);
        free(err->owned);
        err->owned = NULL;
        res->failure = err->message;
        return -1;
    }
    jpeg_create_decompress(cinfo);
    jpeg_mem_src(cinfo, data, (unsigned long)size);
    jpeg_read_header(cinfo, TRUE);
    if (cinfo->progressive_mode || cinfo->arith_code) {
        jpeg_destroy_decompress(cinfo);
        res->failure = "progressive or arithmetic-coded JPEG: decoded whole";
        return -1;
    }
    int channels;
    if (cinfo->jpeg_color_space == JCS_YCbCr && cinfo->num_components == 3) {
        cinfo->out_color_space = JCS_EXT_BGR;
        channels = 3;
    } else if (cinfo->jpeg_color_space == JCS_GRAYSCALE && cinfo->num_components == 1) {
        cinfo->out_color_space = JCS_GRAYSCALE;
        channels = 1;
    } else {
        jpeg_destroy_decompress(cinfo);
        res->failure = "not a YCbCr or grey JPEG: decoded whole";
        return -1;
    }
    /* libjpeg's defaults are what simplejpeg and OpenCV decode with: the accurate integer
     * IDCT and fancy (triangle-filter) upsampling */
    cinfo->dct_method = JDCT_ISLOW;
    cinfo->do_fancy_upsampling = TRUE;
    size_t width = cinfo->image_width, height = cinfo->image_height;
    /* libjpeg bounds both sides by 65500; the product is checked anyway, so that no size_t
     * can wrap into a small buffer's size */
    if (width == 0 || height == 0 || width > SIZE_MAX / height / (size_t)channels) {
        jpeg_destroy_decompress(cinfo);
        res->failure = "the picture's size overflows";
        return -1;
    }
    if (out_size != width * height * (size_t)channels) {
        jpeg_destroy_decompress(cinfo);
        res->failure = "the buffer is not the picture's size";
        return -1;
    }
    if (res->top < 0) res->top = 0;
    if (res->left < 0) res->left = 0;
    if (res->bottom > (int)height) res->bottom = (int)height;
    if (res->right > (int)width) res->right = (int)width;
    if (res->top >= res->bottom || res->left >= res->right) {
        jpeg_destroy_decompress(cinfo);
        res->failure = "the rectangle lies outside the picture";
        return -1;
    }
    /* rows above the rectangle that need not be read at all (restart intervals), and the
     * picture from there down in place of the whole one */
    size_t made = 0;
    int shift = restart_seek(cinfo, err, data, size, res->top, &made);
    if (shift > 0) {
        jpeg_abort_decompress(cinfo);
        jpeg_mem_src(cinfo, err->owned, (unsigned long)made);
        jpeg_read_header(cinfo, TRUE);
        cinfo->out_color_space = channels == 3 ? JCS_EXT_BGR : JCS_GRAYSCALE;
        cinfo->dct_method = JDCT_ISLOW;
        cinfo->do_fancy_upsampling = TRUE;
        if (cinfo->image_width != width || cinfo->image_height != height - (size_t)shift) {
            jpeg_destroy_decompress(cinfo);
            free(err->owned);
            err->owned = NULL;
            res->failure = "the restart seek changed the picture's width";
            return -1;
        }
        base += (size_t)shift * width * (size_t)channels;
    }
    int top = res->top - shift, bottom = res->bottom - shift;
    jpeg_start_decompress(cinfo);
    JDIMENSION xoffset = (JDIMENSION)res->left, cols = (JDIMENSION)(res->right - res->left);
    if (cols < cinfo->output_width) jpeg_crop_scanline(cinfo, &xoffset, &cols);
    if (top > 0) jpeg_skip_scanlines(cinfo, (JDIMENSION)top);
    int first = (int)cinfo->output_scanline;
    while ((int)cinfo->output_scanline < bottom) {
        JSAMPROW row = base + ((size_t)cinfo->output_scanline * width + xoffset) * channels;
        jpeg_read_scanlines(cinfo, &row, 1);
    }
    int warned = err->warned;
    jpeg_abort_decompress(cinfo);
    jpeg_destroy_decompress(cinfo);
    free(err->owned);
    err->owned = NULL;
    if (warned) {
        res->failure = err->message;
        return -1;
    }
    res->top = first + shift;
    res->left = (int)xoffset;
    res->right = (int)(xoffset + cols);
    return 0;
}

static PyObject *decode_region(PyObject *self, PyObject *args) {
    Py_buffer data, out;
    outcome res = {0, 0, 0, 0, NULL};
    if (!PyArg_ParseTuple(args, "y*w*iiii", &data, &out, &res.top, &res.left, &res.bottom,
                          &res.right))
        return NULL;
    struct jpeg_decompress_struct cinfo;
    struct region_error err;
    route_errors(&cinfo, &err);
    int rc;
    Py_BEGIN_ALLOW_THREADS
    rc = decode(&cinfo, &err, (const unsigned char *)data.buf, (size_t)data.len,
                (unsigned char *)out.buf, (size_t)out.len, &res);
    Py_END_ALLOW_THREADS
    PyBuffer_Release(&data);
    PyBuffer_Release(&out);
    if (rc != 0) {
        PyErr_SetString(PyExc_ValueError, res.failure ? res.failure : "decoding failed");
        return NULL;
    }
    return Py_BuildValue("(iiii)", res.top, res.left, res.bottom, res.right);
}

static PyObject *header(PyObject *self, PyObject *args) {
    Py_buffer data;
    if (!PyArg_ParseTuple(args, "y*", &data)) return NULL;
    struct jpeg_decompress_struct cinfo;
    struct region_error err;
    route_errors(&cinfo, &err);
    if (setjmp(err.jump)) {
        jpeg_destroy_decompress(&cinfo);
        PyBuffer_Release(&data);
        PyErr_SetString(PyExc_ValueError, err.message);
        return NULL;
    }
    jpeg_create_decompress(&cinfo);
    jpeg_mem_src(&cinfo, (const unsigned char *)data.buf, (unsigned long)data.len);
    jpeg_read_header(&cinfo, TRUE);
    PyObject *res = Py_BuildValue("(iiiii)", (int)cinfo.image_width, (int)cinfo.image_height,
                                  cinfo.num_components, (int)cinfo.jpeg_color_space,
                                  (int)cinfo.progressive_mode);
    jpeg_destroy_decompress(&cinfo);
    PyBuffer_Release(&data);
    return res;
}

static PyObject *seek_row(PyObject *self, PyObject *args) {
    Py_buffer data;
    int top;
    if (!PyArg_ParseTuple(args, "y*i", &data, &top)) return NULL;
    struct jpeg_decompress_struct cinfo;
    struct region_error err;
    route_errors(&cinfo, &err);
    if (setjmp(err.jump)) {
        jpeg_destroy_decompress(&cinfo);
        free(err.owned);
        PyBuffer_Release(&data);
        PyErr_SetString(PyExc_ValueError, err.message);
        return NULL;
    }
    jpeg_create_decompress(&cinfo);
    jpeg_mem_src(&cinfo, (const unsigned char *)data.buf, (unsigned long)data.len);
    jpeg_read_header(&cinfo, TRUE);
    size_t made = 0;
    int row = top > 0 && !cinfo.arith_code
                  ? restart_seek(&cinfo, &err, (const unsigned char *)data.buf,
                                 (size_t)data.len, top, &made)
                  : 0;
    jpeg_destroy_decompress(&cinfo);
    free(err.owned);
    PyBuffer_Release(&data);
    return PyLong_FromLong(row);
}

static PyMethodDef methods[] = {
    {"seek_row", seek_row, METH_VARARGS,
     "seek_row(data, top) -> the row a decode of the rows from `top` down starts at (restart "
     "intervals; 0: the picture's top)"},
    {"decode_region", decode_region, METH_VARARGS,
     "decode_region(data, out, top, left, bottom, right) -> (top, left, bottom, right)"},
    {"header", header, METH_VARARGS,
     "header(data) -> (width, height, components, colour space, progressive)"},
    {NULL, NULL, 0, NULL},
};

static struct PyModuleDef module = {
    PyModuleDef_HEAD_INIT, "_jpegregion",
    "Partial JPEG decompression (libjpeg-turbo's jpeg_skip_scanlines / jpeg_crop_scanline).",
    -1, methods,
};

PyMODINIT_FUNC PyInit__jpegregion(void) {
    PyObject *m = PyModule_Create(&module);
    if (m) PyModule_AddIntConstant(m, "LIBJPEG_TURBO_VERSION", LIBJPEG_TURBO_VERSION_NUMBER);
    return m;
}
