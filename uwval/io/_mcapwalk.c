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
 *
 * scan_chunks (below) runs the whole of this for runs of chunks on its own threads.
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

static uint32_t le32(const unsigned char *p) {
    return (uint32_t)p[0] | ((uint32_t)p[1] << 8) | ((uint32_t)p[2] << 16) | ((uint32_t)p[3] << 24);
}

typedef struct {
    long cid;
    const uint64_t *ent; /* (log time, offset) pairs, little-endian uint64 */
    Py_ssize_t n, cursor, out_row, bytes;
    Py_ssize_t chan; /* scan_chunks: its channel's place among the run's (ascending ids) */
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


/* ------------------------------------------------------------------------------------------
 * scan_chunks: the whole fast path of a run of chunks, with the GIL released throughout.
 *
 * Handing chunks one by one to Python inflate threads costs a GIL hand-over per chunk (and
 * the reading thread's Python per chunk): on a log of many chunks the second CPU then sat
 * mostly idle (benchmarks/README, sixth pass). Here one call walks a run of top-level Chunk
 * and MessageIndex records, decompresses (zstd, reached through dlopen of libzstd) and
 * CRC-checks the chunks holding a wanted channel on POSIX threads, checks each against its
 * index with match_records, and hands back the wanted records per channel, packed. Whatever
 * it does not do exactly as the Python path would, it does not do: it stops before that
 * record and says why, and the reader reads from there its own way (which reports damage).
 * ------------------------------------------------------------------------------------------ */
#if defined(__unix__) || defined(__APPLE__) /* dlopen and POSIX threads */
#define UWVAL_SCAN 1
#include <dlfcn.h>
#include <sys/mman.h>
#include <unistd.h>
#include <pthread.h>
#include <stdlib.h>

#define OP_CHUNK 0x06
#define OP_MESSAGE_INDEX 0x07
#define SCAN_TABLES 256

typedef void *(*zstd_create_t)(void);
typedef size_t (*zstd_free_t)(void *);
typedef size_t (*zstd_decompress_t)(void *, void *, size_t, const void *, size_t);
typedef unsigned (*zstd_iserror_t)(size_t);
typedef uint32_t (*crc_isal_t)(uint32_t, const unsigned char *, uint64_t);
typedef unsigned long (*crc_zlib_t)(unsigned long, const unsigned char *, unsigned);

static zstd_create_t zstd_create;
static zstd_free_t zstd_free;
static zstd_decompress_t zstd_decompress;
static zstd_iserror_t zstd_iserror;
static crc_isal_t crc_isal;
static crc_zlib_t crc_zlib;
static int codecs_state; /* 0 not tried, 1 ready, -1 unavailable */

static uint32_t crc32_of(const unsigned char *b, int64_t n) {
    if (crc_isal != NULL)
        return crc_isal(0, b, (uint64_t)n);
    unsigned long c = 0;
    while (n > 0) {
        unsigned step = n > (1 << 30) ? (1u << 30) : (unsigned)n;
        c = crc_zlib(c, b, step);
        b += step;
        n -= step;
    }
    return (uint32_t)c;
}

PyDoc_STRVAR(setup_codecs_doc,
"setup_codecs(crc_library) -> bool\n\n"
"Find zstd's decompressor (libzstd.so.1) and a CRC-32 for :func:`scan_chunks`: ISA-L's\n"
"crc32_gzip_refl in the already loaded library ``crc_library`` (a path, or None), else\n"
"zlib's crc32. False when zstd or both CRCs are missing (the reader then keeps its Python\n"
"path). Called once; later calls return the first answer.");

static PyObject *setup_codecs(PyObject *self, PyObject *args) {
    (void)self;
    const char *crc_lib = NULL;
    if (!PyArg_ParseTuple(args, "z:setup_codecs", &crc_lib))
        return NULL;
    if (codecs_state == 0) {
        codecs_state = -1;
        void *z = dlopen("libzstd.so.1", RTLD_NOW | RTLD_LOCAL);
        if (z != NULL) {
            zstd_create = (zstd_create_t)dlsym(z, "ZSTD_createDCtx");
            zstd_free = (zstd_free_t)dlsym(z, "ZSTD_freeDCtx");
            zstd_decompress = (zstd_decompress_t)dlsym(z, "ZSTD_decompressDCtx");
            zstd_iserror = (zstd_iserror_t)dlsym(z, "ZSTD_isError");
        }
        if (crc_lib != NULL) {
            void *i = dlopen(crc_lib, RTLD_NOW | RTLD_NOLOAD | RTLD_LOCAL);
            if (i != NULL)
                crc_isal = (crc_isal_t)dlsym(i, "crc32_gzip_refl");
        }
        if (crc_isal == NULL) {
            void *zl = dlopen("libz.so.1", RTLD_NOW | RTLD_LOCAL);
            if (zl != NULL)
                crc_zlib = (crc_zlib_t)dlsym(zl, "crc32");
        }
        if (zstd_create && zstd_free && zstd_decompress && zstd_iserror && (crc_isal || crc_zlib))
            codecs_state = 1;
    }
    return PyBool_FromLong(codecs_state == 1);
}

PyDoc_STRVAR(crc32_doc, "crc32(data) -> int\n\nThe CRC-32 :func:`scan_chunks` checks chunks with "
"(after setup_codecs; for tests: it must equal zlib.crc32).");

static PyObject *crc32_py(PyObject *self, PyObject *args) {
    (void)self;
    Py_buffer b;
    if (codecs_state != 1) {
        PyErr_SetString(PyExc_RuntimeError, "setup_codecs() has not found the codecs");
        return NULL;
    }
    if (!PyArg_ParseTuple(args, "y*:crc32", &b))
        return NULL;
    uint32_t c;
    Py_BEGIN_ALLOW_THREADS
    c = crc32_of((const unsigned char *)b.buf, (int64_t)b.len);
    Py_END_ALLOW_THREADS
    PyBuffer_Release(&b);
    return PyLong_FromUnsignedLong(c);
}

enum {
    SCAN_END = 0,     /* every record up to ``end`` was read */
    SCAN_RECORD = 1,  /* the record at next_pos is not a Chunk / MessageIndex, or does not fit */
    SCAN_BUDGET = 2,  /* the run is full; next_pos is the next chunk */
    SCAN_CHUNK = 3,   /* the chunk at next_pos is for the reader (damaged, odd, new tables,
                         larger than max_chunk) */
    SCAN_OTHER = 4,   /* the chunk at next_pos is of a kind this path does not read (lz4,
                         no index): the reader reads the rest of the file */
};

enum { ST_OK = 0, ST_FAIL = 1, ST_SKIP = 2 };

typedef struct {
    int64_t rec, data_at, data_len, usize, slot;
    uint32_t crc;
    int comp; /* 0 stored, 1 zstd */
    int status;
    int arena; /* the worker whose arena holds its wanted payloads */
    Py_ssize_t g0, ng; /* its groups */
} chunk_t;

/* What one reading thread keeps from call to call (fresh buffers would fault their pages in
 * again at every call): its chunk buffer, its payload arena, its zstd context and its
 * channel lookup table. */
typedef struct {
    unsigned char *scratch, *arena;
    int64_t cap, acap, afill;
    void *dctx;
    int32_t *table;
    int broken; /* out of memory: every chunk it takes fails (the reader reads them) */
} worker_t;

#define SCAN_THREADS 8
/* A plan's arrays, kept from run to run (a plan per run allocating its own left holes in
 * malloc's heap between the results held for Python: resident memory that stayed). */
typedef struct {
    chunk_t *chunks;
    group_t *groups;
    int64_t *acc;
    long *ucid;
    int64_t capc, capg, capa, capu;
} planbuf_t;

typedef struct {
    worker_t w[SCAN_THREADS];
    int32_t *cidx; /* channel id -> its place in a run being planned; -1 between plans */
    planbuf_t pb[2]; /* the run being read and the next one, being planned */
    int mapped;      /* results another thread frees: large ones page-mapped (see out_alloc) */
} workspace_t;

#define WORKSPACE "uwval.io._mcapwalk.workspace"

static void workspace_free(PyObject *cap) {
    workspace_t *ws = PyCapsule_GetPointer(cap, WORKSPACE);
    if (ws == NULL)
        return;
    for (int t = 0; t < SCAN_THREADS; t++) {
        free(ws->w[t].scratch);
        free(ws->w[t].arena);
        free(ws->w[t].table);
        if (ws->w[t].dctx != NULL && zstd_free != NULL)
            zstd_free(ws->w[t].dctx);
    }
    free(ws->cidx);
    for (int k = 0; k < 2; k++) {
        free(ws->pb[k].chunks);
        free(ws->pb[k].groups);
        free(ws->pb[k].acc);
        free(ws->pb[k].ucid);
    }
    free(ws);
}

PyDoc_STRVAR(scan_workspace_doc, "scan_workspace(mapped=False) -> capsule\n\nThe buffers "
"scan_chunks' threads keep from one call to the next (one workspace per reader; not for two\n"
"calls at once). ``mapped``: the calls' results are dropped by another thread than the one\n"
"calling: their large buffers are then page-mapped, to leave the RSS when dropped.");

static PyObject *scan_workspace(PyObject *self, PyObject *args) {
    (void)self;
    int mapped = 0;
    if (!PyArg_ParseTuple(args, "|p:scan_workspace", &mapped))
        return NULL;
    workspace_t *ws = calloc(1, sizeof(workspace_t));
    if (ws == NULL)
        return PyErr_NoMemory();
    ws->mapped = mapped;
    PyObject *cap = PyCapsule_New(ws, WORKSPACE, workspace_free);
    if (cap == NULL)
        free(ws);
    return cap;
}

typedef struct {
    const unsigned char *mm;
    chunk_t *chunks;
    Py_ssize_t n_chunks;
    group_t *groups;
    int64_t *rows;
    int payloads;
    const unsigned char *maps;
    workspace_t *ws;
    Py_ssize_t next;   /* next chunk to take (atomic) */
    int next_worker;   /* next worker slot to take (atomic) */
} scan_t;

static int64_t as_i64(uint64_t v) { return (int64_t)v; }

static int cmp_long(const void *a, const void *b) {
    long x = *(const long *)a, y = *(const long *)b;
    return (x > y) - (x < y);
}

/* ``buf`` with room for ``need`` items of ``item`` bytes (its capacity ``*cap`` items,
 * doubled from ``first`` as needed), or NULL when out of memory (``buf`` then unchanged). */
static void *reserve(void *buf, int64_t *cap, int64_t need, size_t item, int64_t first) {
    if (buf != NULL && *cap >= need)
        return buf;
    int64_t n = *cap > 0 ? *cap : first;
    while (n < need)
        n *= 2;
    void *nb = realloc(buf, (size_t)n * item);
    if (nb != NULL)
        *cap = n;
    return nb;
}

/* A byte buffer of at least ``need`` bytes (1 MB at first): 0, or -1 out of memory. */
static int grow(unsigned char **buf, int64_t *cap, int64_t need) {
    unsigned char *nb = reserve(*buf, cap, need, 1, 1 << 20);
    if (nb == NULL)
        return -1;
    *buf = nb;
    return 0;
}

static void scan_one(scan_t *s, chunk_t *ch, worker_t *w, int wid) {
    const unsigned char *rec;
    if (ch->comp == 0) {
        if (ch->data_len != ch->usize) {
            ch->status = ST_FAIL;
            return;
        }
        rec = s->mm + ch->data_at;
    } else {
        if (grow(&w->scratch, &w->cap, ch->usize) != 0) {
            ch->status = ST_FAIL;
            return;
        }
        if (w->dctx == NULL)
            w->dctx = zstd_create();
        if (w->dctx == NULL) {
            ch->status = ST_FAIL;
            return;
        }
        size_t r = zstd_decompress(w->dctx, w->scratch, (size_t)ch->usize, s->mm + ch->data_at,
                                   (size_t)ch->data_len);
        if (zstd_iserror(r) || (int64_t)r != ch->usize) {
            ch->status = ST_FAIL;
            return;
        }
        rec = w->scratch;
    }
    if (ch->crc != 0 && crc32_of(rec, ch->usize) != ch->crc) {
        ch->status = ST_FAIL;
        return;
    }
    if (s->payloads && grow(&w->arena, &w->acap, w->afill + ch->usize) != 0) {
        ch->status = ST_FAIL;
        return;
    }
    group_t *g = s->groups + ch->g0;
    int32_t *tb = NULL;
    if (ch->ng > 16) {
        for (Py_ssize_t i = 0; i < ch->ng; i++)
            w->table[g[i].cid] = (int32_t)i;
        tb = w->table;
    }
    int64_t tabs[3 * SCAN_TABLES];
    Py_ssize_t n_tab = 0;
    int code = match_records(rec, (Py_ssize_t)ch->usize, 0, g, ch->ng, tb, s->rows,
                             s->payloads ? w->arena + w->afill : NULL,
                             s->payloads ? (Py_ssize_t)ch->usize : 0, w->afill, tabs,
                             SCAN_TABLES, &n_tab);
    if (tb != NULL)
        for (Py_ssize_t i = 0; i < ch->ng; i++)
            w->table[g[i].cid] = -1;
    if (code != MATCH_OK) {
        ch->status = ST_FAIL;
        return;
    }
    /* Schema/Channel records in the chunk: only repeats of known ids are passed over here
     * (as the Python path does); a new one is read by the reader, in file order. */
    for (Py_ssize_t t = 0; t < n_tab; t++) {
        int64_t op = tabs[3 * t], a = tabs[3 * t + 1], b = tabs[3 * t + 2];
        int bit = op == OP_CHANNEL ? 2 : 4;
        if (b - a < 2 || !(s->maps[le16(rec + a)] & bit)) {
            ch->status = ST_FAIL;
            return;
        }
    }
    if (s->payloads)
        for (Py_ssize_t i = 0; i < ch->ng; i++)
            if (g[i].out_row >= 0)
                w->afill += (int64_t)g[i].bytes;
    ch->arena = wid;
    ch->status = ST_OK;
}

static void *scan_worker(void *arg) {
    scan_t *s = (scan_t *)arg;
    int wid = __atomic_fetch_add(&s->next_worker, 1, __ATOMIC_RELAXED);
    worker_t *w = s->ws->w + wid;
    if (w->table == NULL) {
        w->table = malloc(65536 * sizeof(int32_t));
        if (w->table != NULL)
            memset(w->table, 0xFF, 65536 * sizeof(int32_t));
    }
    w->afill = 0;
    for (;;) {
        Py_ssize_t k = __atomic_fetch_add(&s->next, 1, __ATOMIC_RELAXED);
        if (k >= s->n_chunks)
            break;
        chunk_t *ch = s->chunks + k;
        if (ch->status == ST_SKIP)
            continue;
        if (w->table == NULL) {
            ch->status = ST_FAIL;
            continue;
        }
        scan_one(s, ch, w, wid);
    }
    return NULL;
}

/* The threads that read the runs of one scan_chunks call beside the calling thread: started
 * once per call (a thread per run cost the calling thread ~40 us each, 2 ms of the image
 * log's 47 runs), each run handed to them by a generation count. */
typedef struct {
    pthread_mutex_t mu;
    pthread_cond_t go, done;
    scan_t *s;  /* the run being read */
    long gen;   /* runs handed out so far */
    int busy;   /* helpers not done with the current run */
    int quit;
    int n;      /* helpers started */
    pthread_t tid[SCAN_THREADS];
} crew_t;

static void *crew_helper(void *arg) {
    crew_t *c = (crew_t *)arg;
    long seen = 0;
    pthread_mutex_lock(&c->mu);
    for (;;) {
        while (c->gen == seen && !c->quit)
            pthread_cond_wait(&c->go, &c->mu);
        if (c->quit)
            break;
        seen = c->gen;
        scan_t *s = c->s;
        pthread_mutex_unlock(&c->mu);
        scan_worker(s);
        pthread_mutex_lock(&c->mu);
        if (--c->busy == 0)
            pthread_cond_signal(&c->done);
    }
    pthread_mutex_unlock(&c->mu);
    return NULL;
}

/* Start up to ``helpers`` helper threads (fewer if the system refuses: the calling thread
 * then reads more). */
static void crew_start(crew_t *c, int helpers) {
    memset(c, 0, sizeof(*c));
    pthread_mutex_init(&c->mu, NULL);
    pthread_cond_init(&c->go, NULL);
    pthread_cond_init(&c->done, NULL);
    for (int t = 0; t < helpers && t < SCAN_THREADS - 1; t++)
        if (pthread_create(&c->tid[c->n], NULL, crew_helper, c) == 0)
            c->n++;
}

/* Hand the run ``s`` to the helpers (the caller reads it too, then crew_wait). */
static void crew_run(crew_t *c, scan_t *s) {
    pthread_mutex_lock(&c->mu);
    c->s = s;
    c->busy = c->n;
    c->gen++;
    pthread_cond_broadcast(&c->go);
    pthread_mutex_unlock(&c->mu);
}

/* Wait until every helper is done with the current run. */
static void crew_wait(crew_t *c) {
    pthread_mutex_lock(&c->mu);
    while (c->busy > 0)
        pthread_cond_wait(&c->done, &c->mu);
    pthread_mutex_unlock(&c->mu);
}

static void crew_stop(crew_t *c) {
    pthread_mutex_lock(&c->mu);
    c->quit = 1;
    pthread_cond_broadcast(&c->go);
    pthread_mutex_unlock(&c->mu);
    for (int t = 0; t < c->n; t++)
        pthread_join(c->tid[t], NULL);
    pthread_cond_destroy(&c->go);
    pthread_cond_destroy(&c->done);
    pthread_mutex_destroy(&c->mu);
}

/* A Chunk record's header fields (content at c, ln bytes): 0, or -1 when damaged, -2 when
 * of a compression this path does not read. */
static int chunk_header(const unsigned char *mm, int64_t c, int64_t ln, chunk_t *ch) {
    if (ln < 8 + 8 + 8 + 4 + 4 + 8)
        return -1;
    ch->usize = as_i64(le64(mm + c + 16));
    ch->crc = le32(mm + c + 24);
    uint32_t sl = le32(mm + c + 28);
    if ((int64_t)sl > ln - 32 - 8)
        return -1;
    const unsigned char *name = mm + c + 32;
    if (sl == 0)
        ch->comp = 0;
    else if (sl == 4 && memcmp(name, "zstd", 4) == 0)
        ch->comp = 1;
    else
        return -2;
    int64_t p = c + 32 + sl;
    uint64_t rl = le64(mm + p);
    ch->data_at = p + 8;
    if (rl > (uint64_t)(c + ln - ch->data_at))
        return -1; /* the Python header parser clips this; the reader says what it means */
    ch->data_len = (int64_t)rl;
    if (ch->usize < 0)
        return -1;
    return 0;
}

PyDoc_STRVAR(scan_chunks_doc,
"scan_chunks(workspace, mm, pos, end, maps, file_budget, slot_budget, threads, payloads,\n"
"            max_chunk[, drop_from, drop_to, whole, hold])\n"
"    -> (stop, next_pos, n_chunks, rows, packed, per_channel)\n\n"
"Read the run of complete Chunk records (each with its MessageIndex records) that starts\n"
"at byte ``pos`` of the MCAP file ``mm``, up to byte ``end`` (the summary), on ``threads``\n"
"threads with the GIL released. ``maps`` (65536 bytes, one per id): bit 1 the channel is\n"
"wanted (or not known yet), bit 2 a known channel, bit 4 a known schema. A chunk none of\n"
"whose indexed channels is wanted is not decompressed (its index counts its messages);\n"
"any other is decompressed, CRC-checked and checked against its index by one walk\n"
"(match_chunk). The run ends at ``end``, at a record that is not a chunk or its index, once\n"
"``file_budget`` file bytes or ``slot_budget`` decompressed bytes were taken, or before the\n"
"first chunk this path leaves to the reader; ``stop`` says which (0-4, see SCAN_*), and\n"
"``next_pos`` where the reader goes on. Chunks before it are read (three Held buffers,\n"
"the call's own memory, not copied): ``rows`` (int64, three\n"
"a record: payload start in ``packed``, log time, record length), ``packed`` (the wanted\n"
"payloads, channel after channel, each in file order; None without ``payloads``), and\n"
"``per_channel`` (int64, nine a channel: id, count, min and max log time, min and max record\n"
"length of its wanted records, first row, rows, first packed byte). With ``drop_from`` and\n"
"``drop_to`` (page-aligned offsets), the map pages between them are dropped from the\n"
"process's RSS (MADV_DONTNEED) while the other threads start. With ``whole``, run follows\n"
"run until one stops for another reason than the budget, or until ``hold`` bytes of rows\n"
"and payloads are held (0: no limit; the last run's stop is then the budget), each run\n"
"planned while the one before it is read and dropping the pages read before it\n"
"(``drop_from``: where the last drop ended), all with the GIL released; the result is then\n"
"(list of the runs' tuples, where the last drop ended).");

typedef struct {
    int stop, oom;
    long long next_pos;
    Py_ssize_t done, nrows, n_out;
    int64_t *rows, *stats;
    unsigned char *packed;
    int64_t packed_size;
} run_t;

/* Where a run may go: up to ``end`` (the summary), ``file_budget`` file bytes and
 * ``slot_budget`` decompressed bytes of wanted chunks; no chunk larger than ``max_chunk``. */
typedef struct {
    long long end, file_budget, slot_budget, max_chunk;
} limits_t;

/* The buffers a run hands to Python (rows, payloads, per-channel table). A workspace made
 * for results that another thread frees (the early start's: its thread allocates, the main
 * thread drops them) has them page-mapped when large: freed into the early thread's malloc
 * arena they stayed resident and useless to the main thread (3 MB early runs, whose ~100 kB
 * payload buffers fall below malloc's mmap threshold: the image log's whole command peaked
 * at 62.7 MiB instead of 52.2). Otherwise malloc's (fresh mappings cost the in-process read
 * a page fault per page: 3 ms of the image log's). A 16-byte header says which. */
#define MAPPED_MIN (16 << 10)
#define OUT_HEAD 16

static size_t out_size(int64_t n, size_t item) { return (size_t)(n > 0 ? n : 1) * item; }

static void *out_alloc(size_t n, int mapped) {
    size_t total = n + OUT_HEAD;
    unsigned char *p;
    if (mapped && n >= MAPPED_MIN) {
        p = mmap(NULL, total, PROT_READ | PROT_WRITE, MAP_PRIVATE | MAP_ANONYMOUS, -1, 0);
        if (p == MAP_FAILED)
            return NULL;
    } else if ((p = malloc(total)) == NULL)
        return NULL;
    size_t head[2] = {mapped && n >= MAPPED_MIN, total};
    memcpy(p, head, sizeof(head));
    return p + OUT_HEAD;
}

static void out_free(void *q) {
    if (q == NULL)
        return;
    unsigned char *p = (unsigned char *)q - OUT_HEAD;
    size_t head[2];
    memcpy(head, p, sizeof(head));
    if (head[0])
        munmap(p, head[1]);
    else
        free(p);
}

/* A planned run (steps 1 and 2 of scan_chunks): its chunks, their index groups, the run's
 * channels (ascending ids) and the row each wanted group's records go to. */
typedef struct {
    chunk_t *chunks;
    group_t *groups;
    int64_t *rows, *acc;
    long *ucid;
    Py_ssize_t nc, ngr, nu, nrows;
    int stop, oom;
    long long next_pos;
} plan_t;

/* Its arrays stay in the workspace (for the next plan to use again); its rows go. */
static void plan_free(plan_t *pl) {
    out_free(pl->rows);
    memset(pl, 0, sizeof(*pl));
}

/* Plan the run of chunks from ``pos`` (steps 1 and 2) in the workspace's plan arrays
 * ``slot``: reads only chunk headers and indexes; called without the GIL. */
static void plan_run(const unsigned char *mm, const unsigned char *maps, workspace_t *ws,
                     int slot, long long pos, const limits_t *lim, plan_t *pl) {
    planbuf_t *pb = ws->pb + slot;
    chunk_t *chunks = pb->chunks;
    group_t *groups = pb->groups;
    int64_t *rows = NULL, *acc = NULL;
    int32_t *cidx = ws->cidx;
    long *ucid = NULL;
    Py_ssize_t nu = 0;
    Py_ssize_t nc = 0, ngr = 0, nrows = 0;
    int64_t capc = pb->capc, capg = pb->capg;
    int stop = SCAN_END, oom = 0;
    long long next_pos = pos, end = lim->end, file_budget = lim->file_budget,
              slot_budget = lim->slot_budget, max_chunk = lim->max_chunk;
    /* 1. the run of chunks, their headers and indexes (reads only headers and indexes) */
    int64_t p = pos, slot_fill = 0;
    for (;;) {
        if (p >= end) {
            stop = SCAN_END;
            break;
        }
        if (nc > 0 && (p - pos >= file_budget || slot_fill >= slot_budget)) {
            stop = SCAN_BUDGET;
            break;
        }
        if (end - p < 9 || mm[p] != OP_CHUNK) {
            stop = SCAN_RECORD;
            break;
        }
        uint64_t ln = le64(mm + p + 1);
        int64_t c = p + 9;
        if (ln > (uint64_t)(end - c)) {
            stop = SCAN_RECORD;
            break;
        }
        chunk_t *nw = reserve(chunks, &capc, (int64_t)nc + 1, sizeof(chunk_t), 256);
        if (nw == NULL) {
            oom = 1;
            break;
        }
        chunks = nw;
        chunk_t *ch = chunks + nc;
        memset(ch, 0, sizeof(*ch));
        ch->rec = p;
        int h = chunk_header(mm, c, (int64_t)ln, ch);
        if (h == -2) {
            stop = SCAN_OTHER;
            break;
        }
        if (h != 0 || ch->usize > max_chunk) {
            stop = SCAN_CHUNK;
            break;
        }
        /* its MessageIndex records */
        int64_t q = c + (int64_t)ln, entries = 0;
        int bad = 0, wanted = 0;
        ch->g0 = ngr;
        while (end - q >= 9 && mm[q] == OP_MESSAGE_INDEX) {
            uint64_t il = le64(mm + q + 1);
            int64_t ic = q + 9;
            if (il > (uint64_t)(end - ic) || il < 6) {
                bad = 1;
                break;
            }
            long cid = le16(mm + ic);
            uint32_t n = le32(mm + ic + 2);
            if ((uint64_t)n + 6 > il || n % 16) {
                bad = 1;
                break;
            }
            for (Py_ssize_t i = ch->g0; i < ngr; i++)
                if (groups[i].cid == cid)
                    bad = 1; /* a channel indexed twice: the reader's dict keeps the last */
            if (bad)
                break;
            group_t *nw = reserve(groups, &capg, (int64_t)ngr + 1, sizeof(group_t), 1024);
            if (nw == NULL) {
                oom = 1;
                break;
            }
            groups = nw;
            group_t *gr = groups + ngr++;
            memset(gr, 0, sizeof(*gr));
            gr->cid = cid;
            gr->ent = (const uint64_t *)(mm + ic + 6);
            gr->n = (Py_ssize_t)(n / 16);
            gr->out_row = (maps[cid] & 1) ? 0 : -1; /* placed in step 2 */
            entries += gr->n;
            if ((maps[cid] & 1) && gr->n > 0)
                wanted = 1;
            q = ic + (int64_t)il;
        }
        if (oom)
            break;
        ch->ng = ngr - ch->g0;
        if (bad || ch->ng == 0 || entries == 0) {
            /* no index (the reader walks the records), a damaged one, or only empty ones */
            ngr = ch->g0;
            stop = (ch->ng == 0 && !bad) ? SCAN_OTHER : SCAN_CHUNK;
            break;
        }
        if (!wanted) {
            int any_wanted = 0;
            for (Py_ssize_t i = ch->g0; i < ngr; i++)
                any_wanted |= maps[groups[i].cid] & 1;
            if (any_wanted) { /* a wanted channel with an empty index: the reader */
                ngr = ch->g0;
                stop = SCAN_CHUNK;
                break;
            }
            ch->status = ST_SKIP;
            ch->slot = -1;
        } else {
            ch->slot = slot_fill;
            slot_fill += ch->usize;
        }
        nc++;
        p = q;
    }
    next_pos = p;

    /* 2. the channels of the run (ascending ids) and their rows: channel after channel,
     *    each in chunk order */
    if (!oom && nc > 0) {
        if (cidx == NULL) { /* once per workspace: every entry -1, and -1 again after use */
            cidx = ws->cidx = malloc(65536 * sizeof(int32_t));
            if (cidx != NULL)
                memset(cidx, 0xFF, 65536 * sizeof(int32_t));
        }
        ucid = reserve(pb->ucid, &pb->capu, ngr > 0 ? ngr : 1, sizeof(long), 64);
        if (ucid != NULL)
            pb->ucid = ucid;
        if (cidx == NULL || ucid == NULL)
            oom = 1;
    }
    if (!oom && nc > 0) {
        for (Py_ssize_t i = 0; i < ngr; i++)
            if (cidx[groups[i].cid] < 0) {
                cidx[groups[i].cid] = 0;
                ucid[nu++] = groups[i].cid;
            }
        qsort(ucid, (size_t)nu, sizeof(long), cmp_long);
        for (Py_ssize_t j = 0; j < nu; j++)
            cidx[ucid[j]] = (int32_t)j;
        for (Py_ssize_t i = 0; i < ngr; i++)
            groups[i].chan = cidx[groups[i].cid];
        for (Py_ssize_t j = 0; j < nu; j++)
            cidx[ucid[j]] = -1;
        acc = reserve(pb->acc, &pb->capa, 10 * (nu > 0 ? nu : 1), sizeof(int64_t), 160);
        if (acc == NULL)
            oom = 1;
        else {
            pb->acc = acc;
            memset(acc, 0, (size_t)nu * 10 * sizeof(int64_t));
        }
    }
    if (!oom && nc > 0) {
        /* acc[10 j + 9]: rows of channel j so far */
        for (Py_ssize_t k = 0; k < nc; k++)
            for (Py_ssize_t i = chunks[k].g0; i < chunks[k].g0 + chunks[k].ng; i++) {
                if (chunks[k].status == ST_SKIP)
                    groups[i].out_row = -1;
                else if (groups[i].out_row >= 0)
                    acc[10 * groups[i].chan + 9] += groups[i].n;
            }
        int64_t total = 0;
        for (Py_ssize_t j = 0; j < nu; j++) {
            int64_t k = acc[10 * j + 9];
            acc[10 * j + 9] = total;
            total += k;
        }
        nrows = (Py_ssize_t)total;
        for (Py_ssize_t k = 0; k < nc; k++)
            for (Py_ssize_t i = chunks[k].g0; i < chunks[k].g0 + chunks[k].ng; i++) {
                if (groups[i].out_row < 0)
                    continue;
                int64_t *r = acc + 10 * groups[i].chan + 9;
                groups[i].out_row = (Py_ssize_t)*r;
                *r += groups[i].n;
            }
        memset(acc, 0, (size_t)nu * 10 * sizeof(int64_t));
        rows = out_alloc(out_size(nrows, 24), ws->mapped);
        if (rows == NULL)
            oom = 1;
    }

    pb->chunks = chunks; /* grown or not, the workspace keeps them */
    pb->capc = capc;
    pb->groups = groups;
    pb->capg = capg;
    pl->chunks = chunks;
    pl->groups = groups;
    pl->rows = rows;
    pl->acc = acc;
    pl->ucid = ucid;
    pl->nc = nc;
    pl->ngr = ngr;
    pl->nu = nu;
    pl->nrows = nrows;
    pl->stop = stop;
    pl->oom = oom;
    pl->next_pos = next_pos;
}

/* Read the planned run ``pl`` (steps 3 and 4) with the ``crew``'s threads; called without
 * the GIL. Meanwhile the calling thread drops the map pages between ``drop_from`` and
 * ``drop_to`` and, when ``next`` is not NULL, plans the run that follows this one (from
 * pl->next_pos) into ``next``: that walk of headers and indexes then overlaps the
 * decompression instead of preceding the next run's. ``pl`` is cleared (its arrays stay in
 * the workspace), its rows handed to ``out``; the caller frees out->rows, out->packed and
 * out->stats (out_free). */
static void read_run(plan_t *pl, const unsigned char *mm, Py_ssize_t mm_len,
                     const unsigned char *maps, workspace_t *ws, crew_t *crew, int payloads,
                     long long drop_from, long long drop_to, const limits_t *lim, plan_t *next,
                     int next_slot, run_t *out) {
    chunk_t *chunks = pl->chunks;
    group_t *groups = pl->groups;
    int64_t *rows = pl->rows, *acc = pl->acc, *stats = NULL;
    long *ucid = pl->ucid;
    Py_ssize_t nu = pl->nu, nc = pl->nc, nrows = pl->nrows, n_out = 0, done = 0;
    unsigned char *packed = NULL;
    int64_t packed_size = 0;
    int stop = pl->stop, oom = pl->oom;
    long long next_pos = pl->next_pos;

    /* 3. decompress, check and walk, on ``threads`` threads */
    int planned = 0;
    if (!oom && nc > 0) {
        scan_t s = {mm, chunks, nc, groups, rows, payloads, maps, ws, 0, 0};
        crew_run(crew, &s);
        /* while the other threads start on the run: the map pages of what earlier calls
         * read leave this process's RSS (dropping them is a page-table walk per page:
         * done here it overlaps the decompression instead of following it) */
        long page = sysconf(_SC_PAGESIZE);
        if (page > 0 && drop_from >= 0 && drop_to <= (long long)mm_len && drop_to > drop_from &&
            drop_from % page == 0 && drop_to % page == 0)
            madvise((void *)(mm + drop_from), (size_t)(drop_to - drop_from), MADV_DONTNEED);
        if (next != NULL) {
            plan_run(mm, maps, ws, next_slot, next_pos, lim, next);
            planned = 1;
        }
        scan_worker(&s);
        crew_wait(crew);
    }
    if (next != NULL && !planned)
        plan_run(mm, maps, ws, next_slot, next_pos, lim, next);

    /* 4. the chunks read (up to the first left to the reader), per channel */
    if (!oom && nc > 0) {
        while (done < nc && chunks[done].status != ST_FAIL)
            done++;
        if (done < nc) {
            stop = SCAN_CHUNK;
            next_pos = chunks[done].rec;
        }
        /* per channel j, acc[10 j ...]: count, lo, hi, min and max length, first row (-1:
         * none wanted), rows, packed start, payload bytes, packed fill */
        for (Py_ssize_t k = 0; k < done; k++) {
            for (Py_ssize_t i = chunks[k].g0; i < chunks[k].g0 + chunks[k].ng; i++) {
                group_t *g = groups + i;
                if (g->n == 0)
                    continue;
                int64_t lo, hi;
                if (chunks[k].status == ST_SKIP) {
                    lo = hi = as_i64(le64((const unsigned char *)(g->ent)));
                    for (Py_ssize_t j = 1; j < g->n; j++) {
                        int64_t t = as_i64(le64((const unsigned char *)(g->ent + 2 * j)));
                        if (t < lo)
                            lo = t;
                        if (t > hi)
                            hi = t;
                    }
                } else {
                    lo = g->lo;
                    hi = g->hi;
                }
                int64_t *a = acc + 10 * g->chan;
                if (a[0] == 0) {
                    a[1] = lo;
                    a[2] = hi;
                    a[5] = -1;
                }
                a[0] += g->n;
                if (lo < a[1])
                    a[1] = lo;
                if (hi > a[2])
                    a[2] = hi;
                if (g->out_row < 0)
                    continue;
                if (a[5] < 0) {
                    a[3] = g->min_len;
                    a[4] = g->max_len;
                    a[5] = g->out_row;
                }
                if (g->min_len < a[3])
                    a[3] = g->min_len;
                if (g->max_len > a[4])
                    a[4] = g->max_len;
                a[6] += g->n;
                a[8] += (int64_t)g->bytes;
            }
        }
        for (Py_ssize_t j = 0; j < nu; j++) {
            int64_t *a = acc + 10 * j;
            if (a[0] == 0)
                continue;
            n_out++;
            if (a[5] >= 0) {
                a[7] = packed_size;
                packed_size += a[8];
            }
        }
        stats = out_alloc(out_size(n_out, 72), ws->mapped);
        if (payloads)
            packed = out_alloc(out_size(packed_size, 1), ws->mapped);
        if (stats == NULL || (payloads && packed == NULL))
            oom = 1;
        /* the payloads, channel after channel, in chunk order; the rows then point there */
        for (Py_ssize_t k = 0; !oom && payloads && k < done; k++) {
            if (chunks[k].status == ST_SKIP)
                continue;
            for (Py_ssize_t i = chunks[k].g0; i < chunks[k].g0 + chunks[k].ng; i++) {
                group_t *g = groups + i;
                if (g->out_row < 0 || g->n == 0)
                    continue;
                int64_t *a = acc + 10 * g->chan;
                int64_t at = a[7] + a[9];
                memcpy(packed + at, ws->w[chunks[k].arena].arena + g->pay_at, (size_t)g->bytes);
                for (Py_ssize_t j = 0; j < g->n; j++) {
                    int64_t *o = rows + 3 * (g->out_row + j);
                    o[0] = at;
                    at += o[2] - 22;
                }
                a[9] += (int64_t)g->bytes;
            }
        }
        Py_ssize_t w = 0;
        for (Py_ssize_t j = 0; !oom && j < nu; j++) {
            int64_t *a = acc + 10 * j;
            if (a[0] == 0)
                continue;
            int64_t *o = stats + 9 * w++;
            int has = a[5] >= 0;
            o[0] = ucid[j];
            o[1] = a[0];
            o[2] = a[1];
            o[3] = a[2];
            o[4] = has ? a[3] : 0;
            o[5] = has ? a[4] : 0;
            o[6] = has ? a[5] : 0;
            o[7] = has ? a[6] : 0;
            o[8] = has ? a[7] : 0;
        }
    }
    memset(pl, 0, sizeof(*pl)); /* its arrays stay in the workspace; its rows went to out */
    if (oom) {
        out_free(rows);
        out_free(packed);
        out_free(stats);
        rows = stats = NULL;
        packed = NULL;
    }
    out->stop = stop;
    out->oom = oom;
    out->next_pos = next_pos;
    out->done = done;
    out->nrows = nrows;
    out->n_out = n_out;
    out->rows = rows;
    out->stats = stats;
    out->packed = packed;
    out->packed_size = packed_size;
}

/* A run's rows, payloads or table, handed to Python without a copy: a read-only buffer over
 * the memory scan_chunks allocated, freed with the object (copying them into bytes cost a
 * pass over fresh pages: 1.1-1.3 ms of the image log's 10 MB). */
typedef struct {
    PyObject_HEAD
    unsigned char *buf;
    Py_ssize_t len;
} held_t;

static void held_dealloc(PyObject *o) {
    out_free(((held_t *)o)->buf);
    Py_TYPE(o)->tp_free(o);
}

static int held_getbuffer(PyObject *o, Py_buffer *view, int flags) {
    held_t *h = (held_t *)o;
    static unsigned char none[1];
    return PyBuffer_FillInfo(view, o, h->buf != NULL ? h->buf : none, h->len, 1, flags);
}

static Py_ssize_t held_length(PyObject *o) { return ((held_t *)o)->len; }

static PyBufferProcs held_as_buffer = {held_getbuffer, NULL};
static PySequenceMethods held_as_sequence = {.sq_length = held_length};

static PyTypeObject HeldType = {
    PyVarObject_HEAD_INIT(NULL, 0).tp_name = "uwval.io._mcapwalk.Held",
    .tp_basicsize = sizeof(held_t),
    .tp_dealloc = held_dealloc,
    .tp_as_sequence = &held_as_sequence,
    .tp_as_buffer = &held_as_buffer,
    .tp_flags = Py_TPFLAGS_DEFAULT,
    .tp_doc = "Bytes scan_chunks read (a read-only buffer; freed with the object).",
};

/* A Held owning ``buf`` (``len`` bytes from out_alloc, or NULL), or NULL (then not owned). */
static PyObject *held(void *buf, Py_ssize_t len) {
    held_t *h = PyObject_New(held_t, &HeldType);
    if (h == NULL)
        return NULL;
    h->buf = buf;
    h->len = buf != NULL ? len : 0;
    return (PyObject *)h;
}

/* The run's tuple; its buffers go to Held objects (the run's pointers are then NULL). */
static PyObject *run_tuple(run_t *r, int payloads) {
    PyObject *rows_b = held(r->rows, (Py_ssize_t)r->nrows * 24);
    if (rows_b != NULL)
        r->rows = NULL;
    PyObject *packed_b = NULL;
    if (payloads) {
        packed_b = held(r->packed, (Py_ssize_t)r->packed_size);
        if (packed_b != NULL)
            r->packed = NULL;
    } else {
        Py_INCREF(Py_None);
        packed_b = Py_None;
    }
    PyObject *stats_b = held(r->stats, (Py_ssize_t)r->n_out * 72);
    if (stats_b != NULL)
        r->stats = NULL;
    if (rows_b && packed_b && stats_b)
        return Py_BuildValue("iLnNNN", r->stop, r->next_pos, r->done, rows_b, packed_b, stats_b);
    Py_XDECREF(rows_b);
    Py_XDECREF(packed_b);
    Py_XDECREF(stats_b);
    return NULL;
}

#define DROP_EVERY (2 << 20) /* the map pages read are dropped once this many accumulated */

static PyObject *scan_chunks(PyObject *self, PyObject *args) {
    (void)self;
    PyObject *ws_obj, *mm_obj;
    Py_buffer mmb = {0}, mapsb = {0};
    long long pos, end, file_budget, slot_budget, max_chunk, drop_from = 0, drop_to = 0,
                                                             hold = 0;
    int threads, payloads, whole = 0;
    if (!PyArg_ParseTuple(args, "OOLLy*LLipL|LLpL:scan_chunks", &ws_obj, &mm_obj, &pos, &end,
                          &mapsb, &file_budget, &slot_budget, &threads, &payloads, &max_chunk,
                          &drop_from, &drop_to, &whole, &hold))
        return NULL;
    workspace_t *ws = PyCapsule_GetPointer(ws_obj, WORKSPACE);
    if (ws == NULL) {
        PyBuffer_Release(&mapsb);
        return NULL;
    }
    PyObject *result = NULL;
    run_t *runs = NULL;
    Py_ssize_t nr = 0;
    int64_t capr = 0;
    int oom = 0;
    if (PyObject_GetBuffer(mm_obj, &mmb, PyBUF_C_CONTIGUOUS) != 0)
        goto fail;
    if (mapsb.len != 65536) {
        PyErr_SetString(PyExc_ValueError, "maps must hold 65536 bytes");
        goto fail;
    }
    if (codecs_state != 1) {
        PyErr_SetString(PyExc_RuntimeError, "setup_codecs() has not found the codecs");
        goto fail;
    }
    if (end > (long long)mmb.len)
        end = (long long)mmb.len;
    if (threads < 1)
        threads = 1;
    if (threads > SCAN_THREADS)
        threads = SCAN_THREADS;
    const unsigned char *mm = (const unsigned char *)mmb.buf;
    const unsigned char *maps = (const unsigned char *)mapsb.buf;
    long long released = drop_from;

    Py_BEGIN_ALLOW_THREADS
    /* whole: run after run up to the first stop that is not the budget (or until ``hold``
     * bytes of results are held), each dropping the map pages read before it (DROP_EVERY at
     * least), ``drop_from`` being where the last drop ended, and each run planned while the
     * one before it is read; one GIL hand-over for all of them */
    long page = sysconf(_SC_PAGESIZE);
    limits_t lim = {end, file_budget, slot_budget, max_chunk};
    plan_t cur, nxt;
    memset(&cur, 0, sizeof(cur));
    memset(&nxt, 0, sizeof(nxt));
    int slot = 0; /* the plan arrays cur uses; nxt uses the other */
    plan_run(mm, maps, ws, slot, pos, &lim, &cur);
    crew_t crew; /* no helpers when there is nothing to read */
    crew_start(&crew, cur.nc > 0 && !cur.oom ? threads - 1 : 0);
    int64_t held = 0;
    for (;;) {
        run_t *nw = reserve(runs, &capr, (int64_t)nr + 1, sizeof(run_t), 16);
        if (nw == NULL) {
            plan_free(&cur);
            oom = 1;
            break;
        }
        runs = nw;
        long long df = drop_from, dt = drop_to;
        if (whole) {
            df = page > 0 ? released - released % page : 0;
            dt = page > 0 ? pos - pos % page : 0;
            if (dt - df >= DROP_EVERY)
                released = dt;
            else
                df = dt = 0;
        }
        int plan_next = whole && cur.stop == SCAN_BUDGET && !cur.oom;
        run_t *r = runs + nr++;
        read_run(&cur, mm, mmb.len, maps, ws, &crew, payloads, df, dt, &lim,
                 plan_next ? &nxt : NULL, 1 - slot, r);
        if (r->oom)
            oom = 1;
        held += (int64_t)r->nrows * 24 + r->packed_size;
        if (oom || !whole || r->stop != SCAN_BUDGET || (hold > 0 && held >= hold)) {
            plan_free(&nxt);
            break;
        }
        pos = r->next_pos; /* where nxt was planned from */
        slot = 1 - slot;
        cur = nxt;
        memset(&nxt, 0, sizeof(nxt));
    }
    crew_stop(&crew);
    Py_END_ALLOW_THREADS

    if (oom) {
        PyErr_NoMemory();
        goto fail;
    }
    if (!whole) {
        result = run_tuple(runs, payloads);
        goto fail;
    }
    PyObject *list = PyList_New(nr);
    for (Py_ssize_t i = 0; list != NULL && i < nr; i++) {
        PyObject *t = run_tuple(runs + i, payloads);
        if (t == NULL)
            Py_CLEAR(list);
        else
            PyList_SET_ITEM(list, i, t);
    }
    if (list != NULL)
        result = Py_BuildValue("NL", list, released);
fail:
    for (Py_ssize_t i = 0; i < nr; i++) {
        out_free(runs[i].rows);
        out_free(runs[i].packed);
        out_free(runs[i].stats);
    }
    free(runs);
    if (mmb.obj)
        PyBuffer_Release(&mmb);
    PyBuffer_Release(&mapsb);
    return result;
}

#endif /* UWVAL_SCAN */

static PyMethodDef methods[] = {
    {"match_chunk", match_chunk, METH_VARARGS, match_chunk_doc},
#ifdef UWVAL_SCAN
    {"setup_codecs", setup_codecs, METH_VARARGS, setup_codecs_doc},
    {"crc32", crc32_py, METH_VARARGS, crc32_doc},
    {"scan_chunks", scan_chunks, METH_VARARGS, scan_chunks_doc},
    {"scan_workspace", scan_workspace, METH_VARARGS, scan_workspace_doc},
#endif
    {NULL, NULL, 0, NULL},
};

static struct PyModuleDef module = {
    PyModuleDef_HEAD_INIT, "_mcapwalk",
    "One-walk check of a decompressed MCAP chunk against its index, and runs of chunks read "
    "on POSIX threads (see uwval.io.mcap_raw and uwval.io.mcap_runs).", -1, methods,
    NULL, NULL, NULL, NULL,
};

PyMODINIT_FUNC PyInit__mcapwalk(void) {
    PyObject *m = PyModule_Create(&module);
#ifdef UWVAL_SCAN
    if (m != NULL && (PyType_Ready(&HeldType) < 0 ||
                      PyModule_AddObjectRef(m, "Held", (PyObject *)&HeldType) < 0))
        Py_CLEAR(m);
#endif
    return m;
}
