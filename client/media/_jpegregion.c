/* Decode one rectangle of a JPEG picture with libjpeg-turbo's partial decompression.
 *
 * jpeg_skip_scanlines skips the rows above the rectangle (their entropy-coded data is read, no
 * IDCT, upsampling or colour conversion is done), jpeg_crop_scanline limits every decoded row
 * to the iMCU columns covering it, and decompression stops after its last row: a window
 * around a small target costs a fraction of the whole picture. The pixels land where the
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
 */
#define PY_SSIZE_T_CLEAN
#include <Python.h>

#include <setjmp.h>
#include <stdint.h>
#include <stdio.h>
#include <string.h>

#include <jpeglib.h>

struct region_error {
    struct jpeg_error_mgr pub;
    jmp_buf jump;
    int warned;
    char message[JMSG_LENGTH_MAX];
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
    jpeg_start_decompress(cinfo);
    JDIMENSION xoffset = (JDIMENSION)res->left, cols = (JDIMENSION)(res->right - res->left);
    if (cols < cinfo->output_width) jpeg_crop_scanline(cinfo, &xoffset, &cols);
    if (res->top > 0) jpeg_skip_scanlines(cinfo, (JDIMENSION)res->top);
    int first = (int)cinfo->output_scanline;
    while ((int)cinfo->output_scanline < res->bottom) {
        JSAMPROW row = base + ((size_t)cinfo->output_scanline * width + xoffset) * channels;
        jpeg_read_scanlines(cinfo, &row, 1);
    }
    int warned = err->warned;
    jpeg_abort_decompress(cinfo);
    jpeg_destroy_decompress(cinfo);
    if (warned) {
        res->failure = err->message;
        return -1;
    }
    res->top = first;
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

static PyMethodDef methods[] = {
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
