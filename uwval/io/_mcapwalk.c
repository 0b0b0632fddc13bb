/*
 * uwval.io._mcapwalk: check a decompressed MCAP chunk against its MessageIndex in one walk
 * (optional C accelerator of uwval.io.mcap_raw).
 *
 * With numpy, checking the index means gathering the record heads the entries point at,
 * sorting them, and walking the gaps between indexed records (uwval.io.mcap_chunk.
 * check_index), on the reading thread, over memory another core just decompressed. In C one
 * sequential walk of the record headers does the same, on the inflate thread while the chunk
 * is still in its cache: each Message record must be the next entry of its channel's index
 * (same offset, same log time), every entry must be used, and no record may run past the
 * chunk. The walk also hands back what the reader needs next (the wanted channels' record
 * starts, log times and lengths; each channel's log-time span; the Schema/Channel records).
 * When anything is off it only says so: the reader then runs the numpy check, which names
 * what is wrong exactly as without this module.
 *
 * Every read is bounds-checked against the chunk; the GIL is released while walking.
 */
#define PY_SSIZE_T_CLEAN
#include <Python.h>

#include <stdint.h>
#include <string.h>

#define OP_SCHEMA 0x03
#define OP_CHANNEL 0x04
#define OP_MESSAGE 0x05

enum {
    MATCH_OK = 0,        /* the index lists exactly the chunk's Message records */
    MATCH_NOFIT = 1,     /* a record header cut off, opcode 0, or a record past the chunk */
    MATCH_SHORT = 2,     /* a Message record shorter than its 22 fixed bytes */
    MATCH_UNLISTED = 3,  /* a Message record of a channel the index does not list */
    MATCH_EXTRA = 4,     /* more Message records of a channel than its index lists */
    MATCH_DIFFERS = 5,   /* an entry's offset or log time differs from its record's */
    MATCH_MISSING = 6,   /* an index entry with no record (fewer records than entries) */
    MATCH_TABLES = 7,    /* more Schema/Channel records than the table buffer holds */
    MATCH_PAYLOAD = 8,   /* the wanted payloads do not fit the payload buffer */
};

static uint64_t le64(const unsigned char *p) {
    uint64_t v;
    memcpy(&v, p, 8);
#if defined(__BYTE_ORDER__) && __BYTE_ORDER__ == __ORDER_BIG_ENDIAN__
    v = __builtin_bswap64(v);
#endif
    return v;
}

static uint16_t le16(const unsigned char *p) { return (uint16_t)(p[0] | (p[1] << 8)); }

typedef struct {
    long cid;
    const uint64_t *ent; /* (log time, offset) pairs, little-endian uint64 */
    Py_ssize_t n, cursor, out_row, bytes;
    int64_t lo, hi, min_len, max_len, pay_at;
} group_t;

/* The group of channel ``cid``, or -1: a table lookup when there are many groups. */
static Py_ssize_t find_group(const group_t *g, Py_ssize_t ng, const int32_t *table, long cid) {
    if (table != NULL)
        return table[cid];
    for (Py_ssize_t i = 0; i < ng; i++)
        if (g[i].cid == cid)
            return i;
    return -1;
}

/* Walk the chunk's records and match each Message record with the next entry of its
 * channel's index. Returns a MATCH_* code; ``*n_tab`` Schema/Channel records found. */
static int match_records(const unsigned char *b, Py_ssize_t size, int64_t base, group_t *g,
                         Py_ssize_t ng, const int32_t *table, int64_t *out, unsigned char *pay,
                         Py_ssize_t pay_cap, int64_t pay_base, int64_t *tab, Py_ssize_t tab_cap,
                         Py_ssize_t *n_tab) {
    Py_ssize_t q = 0, nt = 0, pfill = 0;
    int code = MATCH_OK;
    while (q < size) {
        if (size - q < 9) {
            code = MATCH_NOFIT;
            break;
        }
        unsigned char op = b[q];
        uint64_t rl = le64(b + q + 1);
        Py_ssize_t cc = q + 9;
        if (op == 0 || rl > (uint64_t)(size - cc)) {
            code = MATCH_NOFIT;
            break;
        }
        if (op == OP_MESSAGE) {
            if (rl < 22) {
                code = MATCH_SHORT;
                break;
            }
            Py_ssize_t k = find_group(g, ng, table, (long)le16(b + cc));
            if (k < 0) {
                code = MATCH_UNLISTED;
                break;
            }
            group_t *gr = g + k;
            if (gr->cursor >= gr->n) {
                code = MATCH_EXTRA;
                break;
            }
            uint64_t lt = le64(b + cc + 6);
            const unsigned char *e = (const unsigned char *)(gr->ent + 2 * gr->cursor);
            if (le64(e) != lt || le64(e + 8) != (uint64_t)q) {
                code = MATCH_DIFFERS;
                break;
            }
            int64_t t = (int64_t)lt; /* spans as numpy sees int64 log times */
            if (gr->cursor == 0 || t < gr->lo)
                gr->lo = t;
            if (gr->cursor == 0 || t > gr->hi)
                gr->hi = t;
            if (gr->cursor == 0 || (int64_t)rl < gr->min_len)
                gr->min_len = (int64_t)rl;
            if (gr->cursor == 0 || (int64_t)rl > gr->max_len)
                gr->max_len = (int64_t)rl;
            if (gr->out_row >= 0) {
                int64_t *o = out + 3 * (gr->out_row + gr->cursor);
                o[0] = (int64_t)q;
                o[1] = t;
                o[2] = (int64_t)rl;
                gr->bytes += (Py_ssize_t)rl - 22;
            }
            gr->cursor++;
        } else if (op == OP_SCHEMA || op == OP_CHANNEL) {
            if (nt >= tab_cap) {
                code = MATCH_TABLES;
                break;
            }
            int64_t *t = tab + 3 * nt;
            t[0] = op;
            t[1] = base + (int64_t)cc;
            t[2] = base + (int64_t)(cc + (Py_ssize_t)rl);
            nt++;
        }
        q = cc + (Py_ssize_t)rl;
    }
    for (Py_ssize_t i = 0; code == MATCH_OK && i < ng; i++)
        if (g[i].cursor != g[i].n)
            code = MATCH_MISSING;
    *n_tab = nt;
    if (code != MATCH_OK)
        return code;
    /* The wanted payloads, copied out while the chunk is in this core's cache: each
     * channel's one after the other (a topic's rows then copy on as one block), channels
     * in group order. Without a payload buffer, rows give the record start. */
    for (Py_ssize_t i = 0; i < ng; i++) {
        if (g[i].out_row < 0)
            continue;
        if (pay != NULL && g[i].bytes > pay_cap - pfill)
            return MATCH_PAYLOAD;
        g[i].pay_at = pay != NULL ? pay_base + (int64_t)pfill : -1;
        for (Py_ssize_t j = 0; j < g[i].n; j++) {
            int64_t *o = out + 3 * (g[i].out_row + j);
            if (pay != NULL) {
                Py_ssize_t n = (Py_ssize_t)o[2] - 22;
                memcpy(pay + pfill, b + o[0] + 31, (size_t)n);
                o[0] = pay_base + (int64_t)pfill;
                pfill += n;
            } else {
                o[0] += base;
            }
        }
    }
    return code;
}

static int get_int64(PyObject *obj, Py_buffer *view, const char *what) {
    if (PyObject_GetBuffer(obj, view, PyBUF_WRITABLE | PyBUF_C_CONTIGUOUS | PyBUF_FORMAT) != 0)
        return -1;
    if (view->itemsize != 8 || view->format == NULL ||
        (strcmp(view->format, "q") != 0 && strcmp(view->format, "l") != 0 &&
         strcmp(view->format, "<q") != 0 && strcmp(view->format, "=q") != 0)) {
        PyErr_Format(PyExc_TypeError, "%s must be a writable int64 buffer", what);
        PyBuffer_Release(view);
        return -1;
    }
    return 0;
}

PyDoc_STRVAR(match_chunk_doc,
"match_chunk(records, base, groups, out, spans, tables[, payload, payload_base])\n"
"    -> (code, n_tables)\n\n"
"Check a chunk's MessageIndex against its decompressed ``records`` (bytes-like) in one\n"
"walk: ``groups`` lists, per indexed channel, (channel id, its entries: a C-contiguous\n"
"buffer of little-endian uint64 (log time, offset) pairs, the row of ``out`` where its\n"
"records go or -1 for a channel not wanted). Walking the records in order, each Message\n"
"record must be the next entry of its channel (same offset and log time), and every entry\n"
"must be used. The wanted channels' records go to the int64 buffer ``out``, three values a\n"
"record (``base`` + record start, log time, record length after the 9-byte header); to\n"
"``spans``, five values a group: its (min, max) log time (as int64), its records' (min,\n"
"max) length, where its payloads start in ``payload`` (see below; -1 without); to\n"
"``tables`` the Schema and Channel records,\n"
"three values a record (opcode, ``base`` + content start, ``base`` + content end).\n"
"``code`` 0: the index is right; else what stopped the match (1 a record does not fit,\n"
"2 a short Message record, 3 a channel not in the index, 4 more records than entries,\n"
"5 an entry differs from its record, 6 an entry without record, 7 ``tables`` full,\n"
"8 ``payload`` full). With the writable bytes-like ``payload``, the wanted records'\n"
"payloads (the bytes after the 31-byte Message header) are copied into it, channel after\n"
"channel (in group order), each channel's one after the other; the first value of their\n"
"``out`` row is then ``payload_base`` + where the payload starts there, not the record's.\n"
"Raises ValueError when the buffers are too small for the groups.");

static PyObject *match_chunk(PyObject *self, PyObject *args) {
    (void)self;
    PyObject *rec_obj, *groups_obj, *out_obj, *spans_obj, *tab_obj, *pay_obj = Py_None;
    long long base, pay_base = 0;
    if (!PyArg_ParseTuple(args, "OLO!OOO|OL:match_chunk", &rec_obj, &base, &PyList_Type,
                          &groups_obj, &out_obj, &spans_obj, &tab_obj, &pay_obj, &pay_base))
        return NULL;
    Py_ssize_t ng = PyList_GET_SIZE(groups_obj);
    group_t *g = PyMem_Calloc(ng > 0 ? (size_t)ng : 1, sizeof(group_t));
    Py_buffer *ents = PyMem_Calloc(ng > 0 ? (size_t)ng : 1, sizeof(Py_buffer));
    int32_t *table = NULL;
    Py_buffer rec = {0}, out = {0}, spans = {0}, tab = {0}, pay = {0};
    Py_ssize_t held = 0, n_tab = 0;
    int code = -1;
    PyObject *result = NULL;
    if (g == NULL || ents == NULL) {
        PyErr_NoMemory();
        goto done;
    }
    for (; held < ng; held++) {
        PyObject *item = PyList_GET_ITEM(groups_obj, held);
        PyObject *ent_obj;
        long cid;
        Py_ssize_t row;
        if (!PyArg_ParseTuple(item, "lOn:match_chunk group", &cid, &ent_obj, &row))
            goto done;
        if (cid < 0 || cid > 0xFFFF) {
            PyErr_SetString(PyExc_ValueError, "a channel id is not a uint16");
            goto done;
        }
        if (PyObject_GetBuffer(ent_obj, &ents[held], PyBUF_C_CONTIGUOUS) != 0)
            goto done;
        if (ents[held].len % 16) {
            held++;
            PyErr_SetString(PyExc_ValueError, "index entries are not 16-byte pairs");
            goto done;
        }
        g[held].cid = cid;
        g[held].ent = (const uint64_t *)ents[held].buf;
        g[held].n = ents[held].len / 16;
        g[held].out_row = row;
    }
    if (PyObject_GetBuffer(rec_obj, &rec, PyBUF_C_CONTIGUOUS) != 0 ||
        get_int64(out_obj, &out, "out") != 0 || get_int64(spans_obj, &spans, "spans") != 0 ||
        get_int64(tab_obj, &tab, "tables") != 0)
        goto done;
    if (pay_obj != Py_None &&
        PyObject_GetBuffer(pay_obj, &pay, PyBUF_WRITABLE | PyBUF_C_CONTIGUOUS) != 0)
        goto done;
    if (spans.len < 40 * ng) {
        PyErr_SetString(PyExc_ValueError, "spans holds fewer than five values a group");
        goto done;
    }
    for (Py_ssize_t i = 0; i < ng; i++) {
        if (g[i].out_row >= 0 && (g[i].out_row + g[i].n) * 24 > out.len) {
            PyErr_SetString(PyExc_ValueError, "out is too small for the wanted groups");
            goto done;
        }
    }
    if (ng > 16) {
        table = PyMem_Malloc(65536 * sizeof(int32_t));
        if (table == NULL) {
            PyErr_NoMemory();
            goto done;
        }
        memset(table, 0xFF, 65536 * sizeof(int32_t)); /* -1: no group */
        for (Py_ssize_t i = 0; i < ng; i++)
            table[g[i].cid] = (int32_t)i;
    }
    Py_BEGIN_ALLOW_THREADS
    code = match_records((const unsigned char *)rec.buf, rec.len, (int64_t)base, g, ng, table,
                         (int64_t *)out.buf, pay.obj ? (unsigned char *)pay.buf : NULL,
                         pay.obj ? pay.len : 0, (int64_t)pay_base, (int64_t *)tab.buf,
                         tab.len / 24, &n_tab);
    Py_END_ALLOW_THREADS
    if (code == MATCH_OK) {
        int64_t *sp = (int64_t *)spans.buf;
        for (Py_ssize_t i = 0; i < ng; i++) {
            int64_t *r = sp + 5 * i;
            r[0] = g[i].lo;
            r[1] = g[i].hi;
            r[2] = g[i].min_len;
            r[3] = g[i].max_len;
            r[4] = g[i].out_row >= 0 ? g[i].pay_at : -1;
        }
    }
    result = Py_BuildValue("in", code, n_tab);
done:
    for (Py_ssize_t i = 0; i < held; i++)
        PyBuffer_Release(&ents[i]);
    if (rec.obj)
        PyBuffer_Release(&rec);
    if (out.obj)
        PyBuffer_Release(&out);
    if (spans.obj)
        PyBuffer_Release(&spans);
    if (tab.obj)
        PyBuffer_Release(&tab);
    if (pay.obj)
        PyBuffer_Release(&pay);
    PyMem_Free(table);
    PyMem_Free(ents);
    PyMem_Free(g);
    return result;
}

static PyMethodDef methods[] = {
    {"match_chunk", match_chunk, METH_VARARGS, match_chunk_doc},
    {NULL, NULL, 0, NULL},
};

static struct PyModuleDef module = {
    PyModuleDef_HEAD_INIT, "_mcapwalk",
    "One-walk check of a decompressed MCAP chunk against its index (see uwval.io.mcap_raw).", -1, methods,
    NULL, NULL, NULL, NULL,
};

PyMODINIT_FUNC PyInit__mcapwalk(void) { return PyModule_Create(&module); }
