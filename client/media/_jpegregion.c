/* Decode one rectangle of a JPEG picture with libjpeg-turbo's partial decompression.
 *
 * jpeg_skip_scanlines skips the rows above the rectangle (their entropy-coded data is read, no
 * IDCT, upsampling or colour conversion is done), jpeg_crop_scanline limits every decoded row
 * to the iMCU columns covering it, and decompression stops after its last row: a window
 * around a small target costs a fraction of the whole picture. A picture with restart
 * intervals that tile its MCU grid is not even read outside the intervals that cover the
 * rectangle (restart_seek): the rows above and the columns beside it cost nothing. The pixels land where the
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
 * seek(data, top, left, bottom, right) -> (row, column) of the first pixel decode_region
 *   reads for that rectangle (where the restart intervals covering it start), or None when
 *   the picture offers no seek (it is read from its top)
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

/* Restart seek. A baseline scan's restart markers reset the entropy coder and the DC
 * predictions, so each interval's data decodes on its own. When the intervals tile the MCU
 * grid (an interval is a whole number of MCU rows, or a row a whole number of intervals),
 * the intervals that cover the rectangle, each followed by a restart marker numbered anew,
 * under the headers with the covered width and height, are a picture of their own: the
 * whole picture's pixels there, bit for bit but for the upsampling context at its edges
 * (one pixel; the caller trusts pixels 8 inside the decoded rectangle's edges). Neither the
 * rows above the rectangle nor the columns beside it are read.
 *
 * After jpeg_read_header on `data`: 1 with the made stream in err->owned (its size in
 * *made) and its place in the picture in *row, *col; 0 when the picture offers no seek
 * that saves anything (no restart markers, intervals that do not tile the grid, a marker
 * out of sequence: the caller decodes from the top). */
typedef struct {
    size_t top, left, bottom, right; /* pixel rectangle asked for, clamped */
} want;

static int restart_seek(j_decompress_ptr cinfo, struct region_error *err,
                        const unsigned char *data, size_t size, want w, size_t *made,
                        size_t *row, size_t *col) {
    if (cinfo->restart_interval == 0 || cinfo->progressive_mode ||
        jpeg_has_multiple_scans(cinfo) || cinfo->comps_in_scan != cinfo->num_components)
        return 0;
    int single = cinfo->num_components == 1;
    size_t mcu_w = single ? 8 : 8 * (size_t)cinfo->max_h_samp_factor;
    size_t mcu_h = single ? 8 : 8 * (size_t)cinfo->max_v_samp_factor;
    size_t width = cinfo->image_width, height = cinfo->image_height;
    size_t per_row = (width + mcu_w - 1) / mcu_w, rows = (height + mcu_h - 1) / mcu_h;
    size_t interval = cinfo->restart_interval;
    /* the grid of intervals: `span` MCU rows by `across` MCUs each, `wide` to a row */
    size_t span, across;
    if (interval >= per_row && interval % per_row == 0) {
        span = interval / per_row;
        across = per_row;
    } else if (interval < per_row && per_row % interval == 0) {
        span = 1;
        across = interval;
    } else {
        return 0;
    }
    size_t wide = per_row / across, tall = (rows + span - 1) / span;
    size_t g0 = w.top / mcu_h / span, g1 = ((w.bottom + mcu_h - 1) / mcu_h + span - 1) / span;
    size_t j0 = w.left / mcu_w / across, j1 = ((w.right + mcu_w - 1) / mcu_w + across - 1) / across;
    if (g1 > tall) g1 = tall;
    if (j1 > wide) j1 = wide;
    if (g0 >= g1 || j0 >= j1 || (g0 == 0 && j0 == 0 && j1 == wide)) return 0;
    /* the scan's data, where the header reading stopped: in `data` only if libjpeg did not
     * run out of it (its memory source then feeds a fake end marker of its own) */
    uintptr_t next = (uintptr_t)cinfo->src->next_input_byte, begin = (uintptr_t)data;
    if (next < begin || next - begin > size) return 0;
    size_t start = (size_t)(next - begin);
    size_t sof = sof_height_at(data, start);
    if (sof == 0) return 0;
    size_t count = (g1 - g0) * (j1 - j0);
    unsigned char *out = malloc(start + size + 2 * count + 2);
    if (out == NULL) return 0;
    err->owned = out;
    memcpy(out, data, start);
    size_t at = start, copied = 0, last = (g1 - 1) * wide + j1 - 1;
    size_t i = start, from = start; /* the scan, and where interval n's data begins */
    for (size_t n = 0; n <= last; n++) {
        size_t end; /* interval n's data ends at the marker after it */
        for (;;) {
            const unsigned char *hit = i + 1 < size ? memchr(data + i, 0xFF, size - i - 1) : NULL;
            if (hit == NULL) return 0;
            size_t j = (size_t)(hit - data);
            unsigned char marker = data[j + 1];
            if (marker == 0x00 || marker == 0xFF) { /* a stuffed 0xFF, or fill */
                i = j + 1 + (marker == 0x00);
                continue;
            }
            int final = marker == 0xD9 && n == last && n + 1 == tall * wide;
            if (!final && marker != 0xD0 + (n & 7)) return 0; /* out of sequence, or another */
            end = j;
            i = j + 2;
            break;
        }
        size_t g = n / wide, j = n % wide;
        if (g >= g0 && j >= j0 && j < j1) {
            memcpy(out + at, data + from, end - from);
            at += end - from;
            if (++copied < count) { /* numbered anew: the made picture's own sequence */
                out[at++] = 0xFF;
                out[at++] = (unsigned char)(0xD0 + ((copied - 1) & 7));
            }
        }
        from = i;
    }
    out[at++] = 0xFF;
    out[at++] = 0xD9;
    *row = g0 * span * mcu_h;
    *col = j0 * across * mcu_w;
    size_t rows_made = (g1 * span * mcu_h < height ? g1 * span * mcu_h : height) - *row;
    size_t cols_made = (j1 * across * mcu_w < width ? j1 * across * mcu_w : width) - *col;
    out[sof] = (unsigned char)(rows_made >> 8);
    out[sof + 1] = (unsigned char)(rows_made & 0xFF);
    out[sof + 2] = (unsigned char)(cols_made >> 8);
    out[sof + 3] = (unsigned char)(cols_made & 0xFF);
    *made = at;
    return 1;
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
    /* rows above the rectangle and columns beside it that need not be read at all (restart
     * intervals): the picture made of the intervals that cover it, in place of the whole */
    size_t made = 0, row = 0, col = 0;
    want asked = {(size_t)res->top, (size_t)res->left, (size_t)res->bottom, (size_t)res->right};
    if (restart_seek(cinfo, err, data, size, asked, &made, &row, &col)) {
        jpeg_abort_decompress(cinfo);
        jpeg_mem_src(cinfo, err->owned, (unsigned long)made);
        jpeg_read_header(cinfo, TRUE);
        cinfo->out_color_space = channels == 3 ? JCS_EXT_BGR : JCS_GRAYSCALE;
        cinfo->dct_method = JDCT_ISLOW;
        cinfo->do_fancy_upsampling = TRUE;
        if (cinfo->image_width + col > width || cinfo->image_height + row > height) {
            jpeg_destroy_decompress(cinfo);
            free(err->owned);
            err->owned = NULL;
            res->failure = "the restart seek made a picture that does not fit";
            return -1;
        }
        base += (row * width + col) * (size_t)channels;
    }
    int top = res->top - (int)row, bottom = res->bottom - (int)row;
    int left = res->left - (int)col, right = res->right - (int)col;
    jpeg_start_decompress(cinfo);
    JDIMENSION xoffset = (JDIMENSION)(left > 0 ? left : 0), cols = (JDIMENSION)(right - left);
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
    res->top = first + (int)row;
    res->left = (int)(col + xoffset);
    res->right = (int)(col + xoffset + cols);
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

static PyObject *seek(PyObject *self, PyObject *args) {
    Py_buffer data;
    int top, left, bottom, right;
    if (!PyArg_ParseTuple(args, "y*iiii", &data, &top, &left, &bottom, &right)) return NULL;
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
    size_t made = 0, row = 0, col = 0;
    int w = (int)cinfo.image_width, h = (int)cinfo.image_height;
    want asked = {(size_t)(top < 0 ? 0 : top), (size_t)(left < 0 ? 0 : left),
                  (size_t)(bottom > h ? h : bottom), (size_t)(right > w ? w : right)};
    int found = top < bottom && left < right && !cinfo.arith_code &&
                restart_seek(&cinfo, &err, (const unsigned char *)data.buf, (size_t)data.len,
                             asked, &made, &row, &col);
    jpeg_destroy_decompress(&cinfo);
    free(err.owned);
    PyBuffer_Release(&data);
    if (!found) Py_RETURN_NONE;
    return Py_BuildValue("(nn)", (Py_ssize_t)row, (Py_ssize_t)col);
}

static PyMethodDef methods[] = {
    {"seek", seek, METH_VARARGS,
     "seek(data, top, left, bottom, right) -> (row, column) where decode_region starts reading "
     "for that rectangle (restart intervals), or None: from the picture's top"},
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
