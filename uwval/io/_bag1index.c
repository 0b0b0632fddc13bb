/*
 * uwval.io._bag1index: check a ROS 1 chunk's IndexData entries against its MessageData
 * records (optional C accelerator of uwval.io.bag1_raw).
 *
 * The numpy check (bag1_raw._index_ok) gathers every indexed record's header, compares them
 * byte for byte with the first one (time aside) and parses only that one; headers of
 * varying layout go record by record through Python. Here every entry's record header is
 * parsed, in one pass without the GIL: it must be a MessageData record (op 0x02) of the
 * connection, with the entry's time, and its data must lie inside the chunk. The result is
 * each record's data start and length, which the reader copies the payloads from.
 *
 * Acceptance is narrower than the Python parse, never wider: a header whose field names are
 * not plain ASCII, or that repeats op, conn or time, is declined (the Python check decides).
 * Every read is bounds-checked against the chunk.
 */
#define PY_SSIZE_T_CLEAN
#include <Python.h>

#include <stdint.h>
#include <string.h>

static uint32_t le32(const unsigned char *p) {
    return (uint32_t)p[0] | ((uint32_t)p[1] << 8) | ((uint32_t)p[2] << 16) |
           ((uint32_t)p[3] << 24);
}

/* Whether the record at ``off`` is a MessageData record of ``conn`` logged at sec/nsec
 * (its 8 time bytes), whose data lies inside the buffer; its data start/length then. */
static int check_record(const unsigned char *b, Py_ssize_t size, Py_ssize_t off, uint32_t conn,
                        const unsigned char *time8, int64_t *ds, int64_t *dl) {
    if (off < 0 || off > size - 4)
        return 0;
    uint32_t hl = le32(b + off);
    if ((Py_ssize_t)hl > size - off - 8)
        return 0;
    Py_ssize_t p = off + 4, end = off + 4 + (Py_ssize_t)hl;
    int seen_op = 0, seen_conn = 0, seen_time = 0, ok = 1;
    while (p + 4 <= end) {
        uint32_t n = le32(b + p);
        if ((Py_ssize_t)n > end - p - 4)
            return 0; /* a field past the header */
        const unsigned char *f = b + p + 4, *eq = memchr(f, '=', n);
        if (eq == NULL)
            return 0;
        Py_ssize_t name_len = eq - f, val_len = (Py_ssize_t)n - name_len - 1;
        for (Py_ssize_t i = 0; i < name_len; i++)
            if (f[i] >= 0x80)
                return 0; /* not ASCII: the Python parse decides */
        const unsigned char *v = eq + 1;
        if (name_len == 2 && memcmp(f, "op", 2) == 0) {
            if (seen_op++)
                return 0;
            ok &= val_len >= 1 && v[0] == 0x02;
        } else if (name_len == 4 && memcmp(f, "conn", 4) == 0) {
            if (seen_conn++)
                return 0;
            ok &= val_len >= 4 && le32(v) == conn;
        } else if (name_len == 4 && memcmp(f, "time", 4) == 0) {
            if (seen_time++)
                return 0;
            ok &= val_len >= 8 && memcmp(v, time8, 8) == 0;
        }
        p += 4 + (Py_ssize_t)n;
    }
    if (!ok || !seen_op || !seen_conn || !seen_time)
        return 0;
    uint32_t len = le32(b + end);
    if ((Py_ssize_t)len > size - end - 4)
        return 0;
    *ds = (int64_t)(end + 4);
    *dl = (int64_t)len;
    return 1;
}

PyDoc_STRVAR(locate_doc,
"locate(records, conn, entries, out) -> bool\n\n"
"Check a ROS 1 chunk's IndexData entries of connection ``conn`` against the chunk's\n"
"records (bytes-like): ``entries`` is a C-contiguous buffer of little-endian uint32\n"
"(sec, nsec, offset) triples. Each entry must point at a MessageData record (op 0x02) of\n"
"``conn`` with the entry's time whose data lies inside the chunk. On success the writable\n"
"int64 buffer ``out`` holds (data start, data length) per entry and True is returned; False\n"
"when any entry fails or a header is not one this check takes (field names not ASCII, op,\n"
"conn or time repeated): the Python check then decides.");

static PyObject *locate(PyObject *self, PyObject *args) {
    (void)self;
    PyObject *rec_obj, *ent_obj, *out_obj;
    unsigned long conn;
    if (!PyArg_ParseTuple(args, "OkOO:locate", &rec_obj, &conn, &ent_obj, &out_obj))
        return NULL;
    if (conn > 0xFFFFFFFFUL) {
        PyErr_SetString(PyExc_ValueError, "conn is not a uint32");
        return NULL;
    }
    Py_buffer rec, ent, out;
    if (PyObject_GetBuffer(rec_obj, &rec, PyBUF_C_CONTIGUOUS) != 0)
        return NULL;
    if (PyObject_GetBuffer(ent_obj, &ent, PyBUF_C_CONTIGUOUS) != 0) {
        PyBuffer_Release(&rec);
        return NULL;
    }
    if (PyObject_GetBuffer(out_obj, &out, PyBUF_WRITABLE | PyBUF_C_CONTIGUOUS | PyBUF_FORMAT) !=
        0) {
        PyBuffer_Release(&ent);
        PyBuffer_Release(&rec);
        return NULL;
    }
    PyObject *result = NULL;
    Py_ssize_t n = ent.len / 12;
    if (ent.len % 12) {
        PyErr_SetString(PyExc_ValueError, "entries are not 12-byte (sec, nsec, offset) triples");
    } else if (out.itemsize != 8 || out.format == NULL || strchr("qlQL", out.format[0]) == NULL ||
               out.len < 16 * n) {
        PyErr_SetString(PyExc_ValueError, "out must be an int64 buffer of two values an entry");
    } else {
        int good = 1;
        const unsigned char *e = (const unsigned char *)ent.buf, *b = rec.buf;
        int64_t *o = (int64_t *)out.buf;
        Py_BEGIN_ALLOW_THREADS
        for (Py_ssize_t i = 0; i < n && good; i++)
            good = check_record(b, rec.len, (Py_ssize_t)le32(e + 12 * i + 8), (uint32_t)conn,
                                e + 12 * i, o + 2 * i, o + 2 * i + 1);
        Py_END_ALLOW_THREADS
        result = PyBool_FromLong(good);
    }
    PyBuffer_Release(&out);
    PyBuffer_Release(&ent);
    PyBuffer_Release(&rec);
    return result;
}

static PyMethodDef methods[] = {
    {"locate", locate, METH_VARARGS, locate_doc},
    {NULL, NULL, 0, NULL},
};

static struct PyModuleDef module = {
    PyModuleDef_HEAD_INIT, "_bag1index",
    "Check of ROS 1 IndexData entries against their records (see uwval.io.bag1_raw).", -1,
    methods, NULL, NULL, NULL, NULL,
};

PyMODINIT_FUNC PyInit__bag1index(void) { return PyModule_Create(&module); }
