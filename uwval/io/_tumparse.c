/*
 * uwval.io._tumparse: the fast path of the TUM text reader (optional C accelerator).
 *
 * TUM lines are "timestamp tx ty tz qx qy qz qw". numpy's loadtxt converts every token with
 * CPython's correctly rounded strtod (~50 ns a token); most tokens in pose logs have at most
 * 19 significant digits and a small decimal exponent, where Clinger's fast path is exact:
 * an integer mantissa w <= 2^53 and a power of ten 10^k with k <= 22 are both exact doubles,
 * so one IEEE multiplication or division gives the correctly rounded value, the same double
 * strtod gives. Other tokens (more digits, large exponents) go to the C library's strtod,
 * which is also correctly rounded (glibc, musl, macOS). The result is therefore the same
 * double as float(token), bit for bit; the test suite checks that against numpy's loadtxt.
 *
 * Only plain decimals are accepted here ([+-]digits[.digits][(e|E)[+-]digits]): anything
 * else (comments, "nan", commas, a line that is not 8 numbers) makes parse_block raise
 * ValueError, and the Python reader takes its thorough path, which names the bad line.
 * The GIL is released while parsing, so two files parse on two cores in one process.
 */
#define PY_SSIZE_T_CLEAN
#include <Python.h>

#include <float.h>
#include <stdint.h>
#include <stdlib.h>
#include <string.h>

/* The fast path needs each double operation rounded once (no x87 extended precision). */
#if defined(FLT_EVAL_METHOD) && FLT_EVAL_METHOD != 0
#define CLINGER_FAST_PATH 0
#else
#define CLINGER_FAST_PATH 1
#endif

static const double POW10[23] = {
    1e0,  1e1,  1e2,  1e3,  1e4,  1e5,  1e6,  1e7,  1e8,  1e9,  1e10, 1e11,
    1e12, 1e13, 1e14, 1e15, 1e16, 1e17, 1e18, 1e19, 1e20, 1e21, 1e22,
};

#define TWO_POW_53 9007199254740992ULL
#define MAX_TOKEN 128   /* longest token handed to strtod */
#define MAX_SCANNED 4096 /* longer tokens are refused: the int counters below cannot wrap */

static inline int is_blank(char c) {
    return c == ' ' || c == '\t' || c == '\r' || c == '\f' || c == '\v';
}

/* Convert the token [s, e) to a double. 0 on success, -1 if it is not a plain decimal. */
static int parse_double(const char *s, const char *e, double *out) {
    const char *p = s;
    int neg = 0;
    if (e - s > MAX_SCANNED)
        return -1;
    if (p < e && (*p == '+' || *p == '-')) {
        neg = (*p == '-');
        p++;
    }
    uint64_t w = 0;
    int nd = 0;         /* significant digits kept in w */
    int exp10 = 0;      /* value = w * 10^exp10 */
    int digits = 0;     /* digits seen at all */
    int overflow = 0;   /* more than 19 significant digits: strtod decides */
    int point = 0;      /* the decimal point was seen: digits now lower the exponent */
    for (; p < e; p++) {
        if (*p == '.' && !point) {
            point = 1;
            continue;
        }
        unsigned d = (unsigned)(*p - '0');
        if (d >= 10u)
            break;
        if (nd || d) {
            if (nd < 19) {
                w = w * 10u + d;
                nd++;
                exp10 -= point;
            } else {
                overflow = 1; /* (integer digits dropped here would raise the exponent) */
            }
        } else {
            exp10 -= point; /* a leading zero of the fraction shifts the point */
        }
        digits++;
    }
    if (!digits)
        return -1;
    if (p < e && (*p == 'e' || *p == 'E')) {
        p++;
        int eneg = 0, ed = 0, ev = 0;
        if (p < e && (*p == '+' || *p == '-')) {
            eneg = (*p == '-');
            p++;
        }
        while (p < e && (unsigned)(*p - '0') < 10u) {
            if (ev < 100000)
                ev = ev * 10 + (*p - '0');
            ed++;
            p++;
        }
        if (!ed)
            return -1;
        if (ev >= 100000)
            overflow = 1; /* far out of range: strtod gives 0 or inf */
        exp10 += eneg ? -ev : ev;
    }
    if (p != e)
        return -1;
    if (!overflow) {
        if (w == 0) {
            *out = neg ? -0.0 : 0.0;
            return 0;
        }
        while (w % 10u == 0) { /* 1.500000000 -> 15e-1: more tokens take the fast path */
            w /= 10u;
            exp10++;
        }
        if (CLINGER_FAST_PATH && w <= TWO_POW_53 && exp10 >= -22 && exp10 <= 22) {
            double v = (double)w;
            if (exp10 < 0)
                v /= POW10[-exp10];
            else if (exp10 > 0)
                v *= POW10[exp10];
            *out = neg ? -v : v;
            return 0;
        }
    }
    /* the exact but slower way, on a NUL-terminated copy of the (validated) token */
    size_t len = (size_t)(e - s);
    if (len >= MAX_TOKEN)
        return -1;
    char buf[MAX_TOKEN];
    memcpy(buf, s, len);
    buf[len] = '\0';
    char *end = NULL;
    double v = strtod(buf, &end);
    if (end != buf + len)
        return -1;
    *out = v;
    return 0;
}

/*
 * Parse complete lines of src[0:n] into stamps[row] and pose[7 * row + k].
 * A line ends at '\n' (or at n when final). Blank lines are skipped.
 * Returns the rows written; *consumed is the bytes used (whole lines). Stops early when
 * cap rows are written. On a line that is not 8 plain decimals, returns -1 with *consumed
 * set to the byte offset of that line.
 */
static Py_ssize_t parse_lines(const char *src, Py_ssize_t n, int final, double *stamps,
                              double *pose, Py_ssize_t cap, Py_ssize_t *consumed) {
    const char *p = src;
    const char *end = src + n;
    Py_ssize_t rows = 0;
    while (p < end && rows < cap) {
        const char *nl = memchr(p, '\n', (size_t)(end - p));
        if (nl == NULL) {
            if (!final)
                break;
            nl = end;
        }
        const char *q = p;
        while (q < nl && is_blank(*q))
            q++;
        if (q == nl) { /* blank line */
            p = nl < end ? nl + 1 : nl;
            continue;
        }
        double values[8];
        int k = 0;
        while (q < nl) {
            const char *t = q;
            while (q < nl && !is_blank(*q))
                q++;
            if (k == 8 || parse_double(t, q, &values[k]) != 0) {
                *consumed = p - src;
                return -1;
            }
            k++;
            while (q < nl && is_blank(*q))
                q++;
        }
        if (k != 8) {
            *consumed = p - src;
            return -1;
        }
        stamps[rows] = values[0];
        memcpy(pose + 7 * rows, values + 1, 7 * sizeof(double));
        rows++;
        p = nl < end ? nl + 1 : nl;
    }
    *consumed = p - src;
    return rows;
}

static int get_output(PyObject *obj, Py_buffer *view, const char *what) {
    if (PyObject_GetBuffer(obj, view, PyBUF_WRITABLE | PyBUF_C_CONTIGUOUS | PyBUF_FORMAT) != 0)
        return -1;
    if (view->itemsize != (Py_ssize_t)sizeof(double) || view->format == NULL ||
        strcmp(view->format, "d") != 0) {
        PyErr_Format(PyExc_TypeError, "%s must be a float64 buffer", what);
        PyBuffer_Release(view);
        return -1;
    }
    return 0;
}

PyDoc_STRVAR(parse_block_doc,
"parse_block(src, stamps, pose, final) -> (rows, consumed)\n\n"
"Parse the complete TUM lines of the bytes-like ``src`` into the writable float64 buffers\n"
"``stamps`` (one value a row, seconds as written) and ``pose`` (seven a row: tx ty tz qx\n"
"qy qz qw), from their start. The last line counts as complete when ``final`` is true.\n"
"Stops when either output is full. Returns the rows written and the bytes used.\n"
"Raises ValueError (with the byte offset of the line) on a line that is not 8 plain\n"
"decimal numbers, a comment included.");

static PyObject *parse_block(PyObject *self, PyObject *args) {
    (void)self;
    PyObject *src_obj, *stamps_obj, *pose_obj;
    int final;
    if (!PyArg_ParseTuple(args, "OOOp:parse_block", &src_obj, &stamps_obj, &pose_obj, &final))
        return NULL;
    Py_buffer src, stamps, pose;
    if (PyObject_GetBuffer(src_obj, &src, PyBUF_C_CONTIGUOUS) != 0)
        return NULL;
    if (get_output(stamps_obj, &stamps, "stamps") != 0) {
        PyBuffer_Release(&src);
        return NULL;
    }
    if (get_output(pose_obj, &pose, "pose") != 0) {
        PyBuffer_Release(&stamps);
        PyBuffer_Release(&src);
        return NULL;
    }
    Py_ssize_t cap = stamps.len / (Py_ssize_t)sizeof(double);
    Py_ssize_t cap_pose = pose.len / (Py_ssize_t)(7 * sizeof(double));
    if (cap_pose < cap)
        cap = cap_pose;
    Py_ssize_t consumed = 0, rows;
    Py_BEGIN_ALLOW_THREADS
    rows = parse_lines((const char *)src.buf, src.len, final, (double *)stamps.buf,
                       (double *)pose.buf, cap, &consumed);
    Py_END_ALLOW_THREADS
    PyBuffer_Release(&pose);
    PyBuffer_Release(&stamps);
    PyBuffer_Release(&src);
    if (rows < 0) {
        PyErr_Format(PyExc_ValueError,
                     "byte %zd: not a line of 8 decimal numbers", consumed);
        return NULL;
    }
    return Py_BuildValue("nn", rows, consumed);
}

static PyMethodDef methods[] = {
    {"parse_block", parse_block, METH_VARARGS, parse_block_doc},
    {NULL, NULL, 0, NULL},
};

static struct PyModuleDef module = {
    PyModuleDef_HEAD_INIT, "_tumparse",
    "Fast, exact parser of TUM trajectory lines (see uwval.io.tum).", -1, methods,
    NULL, NULL, NULL, NULL,
};

PyMODINIT_FUNC PyInit__tumparse(void) { return PyModule_Create(&module); }
