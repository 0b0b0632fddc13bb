/*
 * uwval.io._posedecode: decode a topic's messages that all share the first one's layout
 * (optional C accelerator of uwval.io.fastdecode).
 *
 * The container readers hand a pose topic over as rows of one width (message i at byte
 * i * width). The numpy decoder finds the first message's layout (where the stamp, the names
 * and the pose lie), then checks and gathers every message column by column: a dozen passes
 * over the rows. Here one pass checks that every row holds the first row's bytes in the given
 * ranges (the CDR encapsulation header, each string's length, bytes and terminator: then
 * every row has the first row's layout and names) and reads the stamp and the seven pose
 * doubles of each. Any row that differs stops it: the caller then decodes with numpy, as
 * without this module. Every read is inside a row (checked before the pass).
 */
#define PY_SSIZE_T_CLEAN
#include <Python.h>

#include <stdint.h>
#include <string.h>

static PyObject *decode_uniform(PyObject *self, PyObject *args) {
    (void)self;
    PyObject *rows_obj, *ranges_obj, *stamp_obj, *pos_obj, *quat_obj;
    Py_ssize_t width, stamp_at, pose_at;
    if (!PyArg_ParseTuple(args, "OnOnnOOO:decode_uniform", &rows_obj, &width, &ranges_obj,
                          &stamp_at, &pose_at, &stamp_obj, &pos_obj, &quat_obj))
        return NULL;
    Py_buffer rows, ranges, st, pos, quat;
    if (PyObject_GetBuffer(rows_obj, &rows, PyBUF_C_CONTIGUOUS) != 0)
        return NULL;
    if (PyObject_GetBuffer(ranges_obj, &ranges, PyBUF_C_CONTIGUOUS) != 0) {
        PyBuffer_Release(&rows);
        return NULL;
    }
    if (PyObject_GetBuffer(stamp_obj, &st, PyBUF_WRITABLE | PyBUF_C_CONTIGUOUS) != 0) {
        PyBuffer_Release(&ranges);
        PyBuffer_Release(&rows);
        return NULL;
    }
    if (PyObject_GetBuffer(pos_obj, &pos, PyBUF_WRITABLE | PyBUF_C_CONTIGUOUS) != 0) {
        PyBuffer_Release(&st);
        PyBuffer_Release(&ranges);
        PyBuffer_Release(&rows);
        return NULL;
    }
    if (PyObject_GetBuffer(quat_obj, &quat, PyBUF_WRITABLE | PyBUF_C_CONTIGUOUS) != 0) {
        PyBuffer_Release(&pos);
        PyBuffer_Release(&st);
        PyBuffer_Release(&ranges);
        PyBuffer_Release(&rows);
        return NULL;
    }
    PyObject *result = NULL;
    Py_ssize_t n = width > 0 ? rows.len / width : 0;
    Py_ssize_t nr = ranges.len / (Py_ssize_t)(2 * sizeof(int64_t));
    const int64_t *rg = (const int64_t *)ranges.buf;
    int bad = width <= 0 || rows.len % width != 0 || ranges.len % (2 * sizeof(int64_t)) != 0 ||
              (stamp_at >= 0 && (stamp_at > width - 8 || st.len != n * 8)) ||
              (pose_at >= 0 && (pose_at > width - 56 || pos.len != n * 24 || quat.len != n * 32));
    for (Py_ssize_t k = 0; !bad && k < nr; k++)
        bad = rg[2 * k] < 0 || rg[2 * k + 1] < 0 || rg[2 * k] > width - rg[2 * k + 1];
    if (bad) {
        PyErr_SetString(PyExc_ValueError,
                        "decode_uniform: rows must be whole rows of width > 0; ranges, the "
                        "stamp and the pose inside a row; outputs of n stamps, n x 3 and "
                        "n x 4 doubles");
        goto done;
    }
    Py_ssize_t mismatch = -1;
    const unsigned char *b = (const unsigned char *)rows.buf;
    int64_t *so = (int64_t *)st.buf;
    double *po = (double *)pos.buf, *qo = (double *)quat.buf;
    Py_BEGIN_ALLOW_THREADS
    for (Py_ssize_t i = 0; i < n && mismatch < 0; i++) {
        const unsigned char *r = b + i * width;
        for (Py_ssize_t k = 0; k < nr; k++) {
            if (i > 0 && memcmp(r + rg[2 * k], b + rg[2 * k], (size_t)rg[2 * k + 1]) != 0) {
                mismatch = i;
                break;
            }
        }
        if (mismatch >= 0)
            break;
        if (stamp_at >= 0) { /* header.stamp: int32 sec, uint32 nanosec, little-endian */
            const unsigned char *p = r + stamp_at;
            int32_t sec = (int32_t)((uint32_t)p[0] | ((uint32_t)p[1] << 8) |
                                    ((uint32_t)p[2] << 16) | ((uint32_t)p[3] << 24));
            uint32_t nsec = (uint32_t)p[4] | ((uint32_t)p[5] << 8) | ((uint32_t)p[6] << 16) |
                            ((uint32_t)p[7] << 24);
            so[i] = (int64_t)sec * 1000000000 + (int64_t)nsec;
        }
        if (pose_at >= 0) { /* position x y z, orientation x y z w: little-endian doubles */
            memcpy(po + 3 * i, r + pose_at, 24);
            memcpy(qo + 4 * i, r + pose_at + 24, 32);
        }
    }
    Py_END_ALLOW_THREADS
    result = PyLong_FromSsize_t(mismatch);
done:
    PyBuffer_Release(&quat);
    PyBuffer_Release(&pos);
    PyBuffer_Release(&st);
    PyBuffer_Release(&ranges);
    PyBuffer_Release(&rows);
    return result;
}

PyDoc_STRVAR(decode_doc,
"decode_uniform(rows, width, ranges, stamp_at, pose_at, stamp, position, orientation, /)\n"
"--\n\n"
"Rows of ``width`` bytes; ``ranges``: int64 (at, length) pairs. If every row holds row 0's\n"
"bytes in every range, fill ``stamp`` (int64 ns: int32 sec * 1e9 + uint32 nanosec at\n"
"``stamp_at``) and ``position`` / ``orientation`` (the 3 + 4 doubles at ``pose_at``) and\n"
"return -1; otherwise return the first row that differs (outputs then partly written).\n"
"A negative ``stamp_at`` / ``pose_at`` skips that output. Little-endian hosts only.");

static PyMethodDef methods[] = {
    {"decode_uniform", decode_uniform, METH_VARARGS, decode_doc},
    {NULL, NULL, 0, NULL},
};

static struct PyModuleDef module = {
    PyModuleDef_HEAD_INIT, "_posedecode",
    "One-pass decode of pose rows sharing the first row's layout (see uwval.io.fastdecode).",
    -1, methods, NULL, NULL, NULL, NULL,
};

PyMODINIT_FUNC PyInit__posedecode(void) { return PyModule_Create(&module); }
