/*
 * uwval.io._db3pages: the fast path of the rosbag2 sqlite3 reader (optional C accelerator).
 *
 * Python's sqlite3 module hands out one Python row per message; this module reads the pages
 * of the ``messages`` table (a rowid table B-tree) and of its timestamp index directly from
 * the file's bytes (an mmap), as the SQLite file format defines them
 * (https://www.sqlite.org/fileformat2.html): table interior pages (0x05) and leaves (0x0D),
 * index interior pages (0x02) and leaves (0x0A), varints, record headers with serial types,
 * payloads spilling to overflow pages.
 *
 * It answers exactly what ``SELECT topic_id, timestamp, data FROM messages WHERE topic_id IN
 * (...) ORDER BY timestamp`` answers when SQLite walks the timestamp index (the caller checks
 * that plan), and ``SELECT topic_id, COUNT(*), MIN(timestamp), MAX(timestamp) ... GROUP BY
 * topic_id``: rows come out in index order ((timestamp, rowid) ascending), and every index
 * entry must name a table row with the same timestamp, one entry per row.
 *
 * It is strict: any read outside the file or page, a page visited twice, a tree deeper than
 * SQLite allows, rowids or index keys out of order, a record header that does not account for
 * every payload byte, a column of another type than rosbag2 writes (NULL rowid alias,
 * integer topic_id and timestamp, blob data), an overflow chain that leaves the file, loops or
 * ends early: the scan *declines* (returns a str naming why) and the caller reads the file
 * with sqlite3, which then reports as it always did. It never guesses.
 * The GIL is released while walking and copying.
 */
#define PY_SSIZE_T_CLEAN
#include <Python.h>

#include <stddef.h>
#include <stdint.h>
#include <stdlib.h>
#include <string.h>
#if defined(__unix__) || defined(__APPLE__)
#include <sys/mman.h>
#include <unistd.h>
#endif

#define MAX_DEPTH 20 /* SQLite's own B-tree cursor depth limit (BTCURSOR_MAX_DEPTH) */

/* Growable arrays live in their own anonymous mappings: growing one (mremap) moves page
 * tables, never bytes, and only the part written is ever resident. */
static void *vec_grow(void *p, size_t old_bytes, size_t new_bytes) {
#if defined(__linux__)
    void *q = p == NULL ? mmap(NULL, new_bytes, PROT_READ | PROT_WRITE,
                               MAP_PRIVATE | MAP_ANONYMOUS, -1, 0)
                        : mremap(p, old_bytes, new_bytes, MREMAP_MAYMOVE);
    return q == MAP_FAILED ? NULL : q;
#else
    (void)old_bytes;
    return realloc(p, new_bytes);
#endif
}

static void vec_free(void *p, size_t bytes) {
    if (p == NULL)
        return;
#if defined(__linux__)
    munmap(p, bytes);
#else
    (void)bytes;
    free(p);
#endif
}

/* A growable buffer: one output group's payloads, copied while their pages are in cache. */
typedef struct {
    uint8_t *buf;
    size_t len, cap;
} Stage;

typedef struct {
    const uint8_t *file;
    uint64_t size;
    uint32_t psize;  /* page size, bytes */
    uint32_t usable; /* page size minus the reserved bytes at each page's end */
    uint32_t npages;
    uint8_t *seen; /* one flag a page: no page is read twice (no loops, no shared pages) */
    /* known topic ids (sorted ascending) and, for each, its output group or -1 */
    const int64_t *ids;
    const int32_t *pick;
    Py_ssize_t nids;
    int64_t *stats; /* nids * (count, min, max) */
    /* known topic ids in 0..lut_n-1: their position in ids, -1 for none (a lookup table) */
    int32_t *lut;
    int64_t lut_n;
    /* table rows in rowid order: rowid, timestamp, and for rows of a selected topic their
     * slot in the sel_* arrays (else -1); cap: room for rows in each */
    int64_t *rowid, *ts;
    int32_t *slot;
    size_t n, cap;
    /* rows of selected topics, in rowid order: payload length, timestamp, output group,
     * where the payload is in its group's stage */
    int64_t *sel_len, *sel_ts, *sel_soff;
    int32_t *sel_grp;
    size_t nsel, sel_cap;
    Py_ssize_t ngroups;
    Stage *stage;     /* per group, its payloads in rowid order */
    int64_t *glast;   /* per group, the last slot the index walk gave it */
    uint8_t *gsorted; /* per group, whether the index gives its rows in rowid order */
    int has_last;
    int64_t last_rowid;
    /* index walk */
    int idx_started;
    int64_t idx_last_ts, idx_last_rowid;
    size_t idx_n;
    int dense; /* rowid[j] == rowid[0] + j for every j */
    int64_t *order; /* table rows of the selected topics, index order */
    size_t norder;
    const char *why; /* the reason of a decline (a static string) */
    /* release: file is a read-only mmap of the file, whose pages may be dropped
     * from this process once read (they stay in the page cache), so the resident size does
     * not grow by the file's size; span: the pages read since the last drop */
    int release;
    const uint8_t *span_lo, *span_hi;
    int span_n;
} Ctx;

static inline uint32_t get2(const uint8_t *p) { return ((uint32_t)p[0] << 8) | p[1]; }

static inline uint32_t get4(const uint8_t *p) {
    return ((uint32_t)p[0] << 24) | ((uint32_t)p[1] << 16) | ((uint32_t)p[2] << 8) | p[3];
}

/* An SQLite varint at p (1-9 bytes, big-endian, 7 bits a byte, the ninth byte whole), read
 * only below end. Returns its length, 0 if it runs past end. */
static inline int get_varint(const uint8_t *p, const uint8_t *end, uint64_t *out) {
    uint64_t v = 0;
    for (int i = 0; i < 8; i++) {
        if (p + i >= end)
            return 0;
        uint8_t b = p[i];
        v = (v << 7) | (uint64_t)(b & 0x7f);
        if (!(b & 0x80)) {
            *out = v;
            return i + 1;
        }
    }
    if (p + 8 >= end)
        return 0;
    *out = (v << 8) | p[8];
    return 9;
}

/* get_varint, the 1- and 2-byte cases inline (serial types and sizes of rosbag2 rows). */
static inline int varint(const uint8_t *p, const uint8_t *end, uint64_t *out) {
    if (p < end && p[0] < 0x80) {
        *out = p[0];
        return 1;
    }
    if (p + 1 < end && p[1] < 0x80) {
        *out = ((uint64_t)(p[0] & 0x7f) << 7) | p[1];
        return 2;
    }
    return get_varint(p, end, out);
}

/* Bytes of an integer serial type (1-6, 8, 9), -1 for any other type. */
static inline int int_size(uint64_t t) {
    static const int8_t sizes[10] = {-1, 1, 2, 3, 4, 6, 8, -1, 0, 0};
    return t < 10 ? sizes[t] : -1;
}

/* The n-byte big-endian two's complement value v, sign-extended (unsigned arithmetic only,
 * then one conversion, as int64_t's two's complement). */
static inline int64_t sign_extend(uint64_t v, int n) {
    uint64_t sign = (uint64_t)1 << (8 * n - 1);
    uint64_t x = (v ^ sign) - sign;
    int64_t out;
    memcpy(&out, &x, sizeof out);
    return out;
}

/* The big-endian two's complement integer of serial type t (int_size(t) >= 0) at p. */
static inline int64_t get_int(uint64_t t, const uint8_t *p) {
    switch (t) {
    case 1:
        return sign_extend(p[0], 1);
    case 2:
        return sign_extend(((uint64_t)p[0] << 8) | p[1], 2);
    case 3:
        return sign_extend(((uint64_t)p[0] << 16) | ((uint64_t)p[1] << 8) | p[2], 3);
    case 4:
        return sign_extend(get4(p), 4);
    case 5:
        return sign_extend(((uint64_t)get2(p) << 32) | get4(p + 2), 6);
    case 6:
        return sign_extend(((uint64_t)get4(p) << 32) | get4(p + 4), 8);
    case 9:
        return 1;
    default: /* 8 */
        return 0;
    }
}

/* Drop the pages read since the last drop from the process's mapping (madvise DONTNEED: a
 * read-only file mapping reads them again from the page cache if touched again). */
static void drop_span(Ctx *c) {
#if (defined(__unix__) || defined(__APPLE__)) && defined(MADV_DONTNEED)
    if (c->release && c->span_n > 0) {
        uintptr_t os_page = (uintptr_t)sysconf(_SC_PAGESIZE);
        uintptr_t a = (uintptr_t)c->span_lo & ~(os_page - 1); /* the map starts page aligned */
        uintptr_t b = ((uintptr_t)c->span_hi + os_page - 1) & ~(os_page - 1);
        (void)madvise((void *)a, (size_t)(b - a), MADV_DONTNEED);
    }
#endif
    c->span_n = 0;
}

/* Note that the file page at page has been read; every 256 pages, drop them (if allowed). */
static inline void done_with(Ctx *c, const uint8_t *page) {
    if (!c->release)
        return;
    if (c->span_n == 0 || page < c->span_lo)
        c->span_lo = page;
    if (c->span_n == 0 || page + c->psize > c->span_hi)
        c->span_hi = page + c->psize;
    if (++c->span_n >= 256)
        drop_span(c);
}

/* Start of page pg (1-based) after checking it is in the file and not read before. */
static const uint8_t *take_page(Ctx *c, uint64_t pg, const char *what) {
    if (pg < 1 || pg > c->npages) {
        c->why = what;
        return NULL;
    }
    if (c->seen[pg]) {
        c->why = "a page is reached twice (a loop or a shared page)";
        return NULL;
    }
    c->seen[pg] = 1;
    return c->file + (pg - 1) * (uint64_t)c->psize;
}

/* Bytes of a payload of P bytes kept on a B-tree page (the rest spills to overflow pages):
 * SQLite's formula with usable size U, X = U-35 on table leaves, ((U-12)*64/255)-23 on index
 * pages, M = ((U-12)*32/255)-23, K = M + ((P-M) % (U-4)). */
static inline uint64_t local_size(const Ctx *c, uint64_t P, int index) {
    uint64_t U = c->usable;
    uint64_t X = index ? ((U - 12) * 64 / 255) - 23 : U - 35;
    if (P <= X)
        return P;
    uint64_t M = ((U - 12) * 32 / 255) - 23;
    uint64_t K = M + ((P - M) % (U - 4));
    return K <= X ? K : M;
}

/* The B-tree page header at pg: type, cell count, where the cell pointers start. */
typedef struct {
    const uint8_t *page; /* page start (cell offsets count from here) */
    const uint8_t *end;  /* page start + usable size */
    uint8_t type;
    uint32_t ncells;
    const uint8_t *cells; /* the cell pointer array */
    uint32_t right;       /* right-most child (interior pages) */
} PageHdr;

static int read_hdr(Ctx *c, uint64_t pg, PageHdr *h, const char *what) {
    const uint8_t *page = take_page(c, pg, what);
    if (page == NULL)
        return -1;
    uint32_t off = pg == 1 ? 100 : 0; /* page 1 starts with the 100-byte file header */
    h->page = page;
    h->end = page + c->usable;
    h->type = page[off];
    uint32_t hsize = (h->type == 0x05 || h->type == 0x02) ? 12 : 8;
    h->ncells = get2(page + off + 3);
    h->right = hsize == 12 ? get4(page + off + 8) : 0;
    if ((uint64_t)off + hsize + 2ull * h->ncells > c->usable) {
        c->why = "a page's cell pointer array runs past the page";
        return -1;
    }
    h->cells = page + off + hsize;
    return 0;
}

/* Cell k of the page, checked to start after the cell pointer array and inside the page. */
static const uint8_t *cell_at(Ctx *c, const PageHdr *h, uint32_t k) {
    uint32_t ptr = get2(h->cells + 2 * k);
    const uint8_t *cell = h->page + ptr;
    if (cell < h->cells + 2ull * h->ncells || cell >= h->end) {
        c->why = "a cell pointer is outside its page";
        return NULL;
    }
    return cell;
}

/* Position of topic id t in the sorted ids, -1 if it is not a known topic. */
static inline Py_ssize_t find_id(const Ctx *c, int64_t t) {
    if (c->lut != NULL)
        return t >= 0 && t < c->lut_n ? c->lut[t] : -1;
    Py_ssize_t lo = 0, hi = c->nids;
    while (lo < hi) {
        Py_ssize_t mid = lo + (hi - lo) / 2;
        if (c->ids[mid] < t)
            lo = mid + 1;
        else
            hi = mid;
    }
    return lo < c->nids && c->ids[lo] == t ? lo : -1;
}

/* Append a payload of blen bytes to the stage st: have bytes at local on the leaf, the rest
 * on the overflow chain from page ovfl (4-byte next page, then usable - 4 bytes each). The
 * chain is checked (pages in the file, none read before, ending with 0 exactly when the
 * payload does) before the stage grows, so a damaged size cannot ask for memory. */
static int stage_blob(Ctx *c, Stage *st, const uint8_t *local, uint64_t have, uint64_t blen,
                      uint64_t ovfl) {
    uint64_t per = c->usable - 4;
    uint64_t left = blen - have;
    uint64_t pg = ovfl;
    for (uint64_t rest = left; rest > 0;) {
        const uint8_t *page = take_page(c, pg, "an overflow page number is outside the file");
        if (page == NULL)
            return -1;
        rest -= rest < per ? rest : per;
        pg = get4(page);
        /* (not dropped yet: the copy below reads it again) */
    }
    if (pg != 0)
        return (c->why = "an overflow chain goes on past its payload"), -1;
    if (st->len + blen > st->cap) {
        size_t cap = st->cap ? 2 * st->cap : 1 << 20;
        while (cap < st->len + blen)
            cap *= 2;
        uint8_t *buf = vec_grow(st->buf, st->cap, cap);
        if (buf == NULL)
            return (c->why = "out of memory"), -1;
        st->buf = buf;
        st->cap = cap;
    }
    uint8_t *out = st->buf + st->len;
    memcpy(out, local, have);
    out += have;
    pg = ovfl;
    while (left > 0) {
        const uint8_t *page = c->file + (pg - 1) * (uint64_t)c->psize;
        uint64_t take = left < per ? left : per;
        memcpy(out, page + 4, take);
        out += take;
        left -= take;
        pg = get4(page);
        done_with(c, page);
    }
    st->len += blen;
    return 0;
}

/* Room for twice the rows (at least 1 << 16) in rowid, ts and slot. */
static int grow_rows(Ctx *c) {
    size_t cap = c->cap ? 2 * c->cap : 1 << 16;
    if (cap > 0x7fffffff)
        return (c->why = "more than 2^31 rows"), -1;
    int64_t *r = vec_grow(c->rowid, c->cap * 8, cap * 8);
    if (r != NULL)
        c->rowid = r;
    int64_t *t = r ? vec_grow(c->ts, c->cap * 8, cap * 8) : NULL;
    if (t != NULL)
        c->ts = t;
    int32_t *s = t ? vec_grow(c->slot, c->cap * 4, cap * 4) : NULL;
    if (s == NULL) /* (the arrays grown so far keep their old size: free_ctx uses cap) */
        return (c->why = "out of memory"), -1;
    c->slot = s;
    c->cap = cap;
    return 0;
}

/* Room for twice the selected rows in sel_len, sel_ts, sel_soff and sel_grp. */
static int grow_sel(Ctx *c) {
    size_t cap = c->sel_cap ? 2 * c->sel_cap : 1 << 14;
    int64_t **a[] = {&c->sel_len, &c->sel_ts, &c->sel_soff};
    for (int i = 0; i < 3; i++) {
        int64_t *p = vec_grow(*a[i], c->sel_cap * 8, cap * 8);
        if (p == NULL)
            return (c->why = "out of memory"), -1;
        *a[i] = p;
    }
    int32_t *g = vec_grow(c->sel_grp, c->sel_cap * 4, cap * 4);
    if (g == NULL)
        return (c->why = "out of memory"), -1;
    c->sel_grp = g;
    c->sel_cap = cap;
    return 0;
}

/* One cell of a table leaf: a row (id NULL, topic_id, timestamp, data). */
static int table_row(Ctx *c, const PageHdr *h, const uint8_t *cell, int has_lo, int64_t lo,
                     int has_hi, int64_t hi) {
    uint64_t P, r;
    int n = varint(cell, h->end, &P);
    if (n == 0)
        return (c->why = "a cell runs past its page"), -1;
    const uint8_t *p = cell + n;
    n = varint(p, h->end, &r);
    if (n == 0)
        return (c->why = "a cell runs past its page"), -1;
    p += n;
    int64_t rowid = (int64_t)r;
    if ((has_lo && rowid <= lo) || (has_hi && rowid > hi))
        return (c->why = "a rowid is outside its parent's key range"), -1;
    if (c->has_last && rowid <= c->last_rowid)
        return (c->why = "rowids do not increase"), -1;
    c->has_last = 1;
    c->last_rowid = rowid;
    if (P > c->size)
        return (c->why = "a payload is larger than the file"), -1;
    uint64_t local = local_size(c, P, 0);
    if (local > (uint64_t)(h->end - p) || (local < P && local + 4 > (uint64_t)(h->end - p)))
        return (c->why = "a payload runs past its page"), -1;
    const uint8_t *rec = p, *rend = p + local;
    uint64_t hs, t[4];
    n = varint(rec, rend, &hs);
    if (n == 0 || hs > local || hs < (uint64_t)n)
        return (c->why = "a record header runs past the payload kept on the page"), -1;
    const uint8_t *q = rec + n, *hend = rec + hs;
    int k = 0;
    while (q < hend) {
        if (k == 4)
            return (c->why = "a row has more than 4 columns"), -1;
        n = varint(q, hend, &t[k]);
        if (n == 0)
            return (c->why = "a serial type runs past its record header"), -1;
        q += n;
        k++;
    }
    if (k != 4)
        return (c->why = "a row has fewer than 4 columns"), -1;
    if (t[0] != 0)
        return (c->why = "a row stores its id (the rowid alias is NULL in rosbag2)"), -1;
    int s1 = int_size(t[1]), s2 = int_size(t[2]);
    if (s1 < 0 || s2 < 0)
        return (c->why = "a topic_id or timestamp is not an integer"), -1;
    if (t[3] < 12 || (t[3] & 1))
        return (c->why = "a data column is not a blob"), -1;
    uint64_t blen = (t[3] - 12) / 2;
    uint64_t fixed = hs + (uint64_t)s1 + (uint64_t)s2;
    if (blen > P || fixed + blen != P)
        return (c->why = "a record header does not account for its payload"), -1;
    if (fixed > local)
        return (c->why = "a row's integers spill to an overflow page"), -1;
    int64_t topic = get_int(t[1], rec + hs);
    int64_t stamp = get_int(t[2], rec + hs + s1);
    if (c->n == c->cap && grow_rows(c) != 0)
        return -1;
    size_t j = c->n++;
    c->rowid[j] = rowid;
    c->ts[j] = stamp;
    Py_ssize_t ix = find_id(c, topic);
    int32_t g = -1;
    if (ix >= 0) {
        int64_t *s = c->stats + 3 * ix;
        if (s[0] == 0 || stamp < s[1])
            s[1] = stamp;
        if (s[0] == 0 || stamp > s[2])
            s[2] = stamp;
        s[0]++;
        g = c->pick[ix];
    }
    if (g < 0) {
        c->slot[j] = -1;
        return 0;
    }
    if (c->nsel == c->sel_cap && grow_sel(c) != 0)
        return -1;
    size_t m = c->nsel++;
    c->slot[j] = (int32_t)m;
    c->sel_grp[m] = g;
    c->sel_ts[m] = stamp;
    c->sel_len[m] = (int64_t)blen;
    Stage *st = &c->stage[g];
    c->sel_soff[m] = (int64_t)st->len;
    return stage_blob(c, st, rec + fixed, local - fixed, blen, local < P ? get4(rend) : 0);
}

/* In-order walk of the table B-tree below page pg, reading the rows of its leaves; every
 * rowid below pg lies in (lo, hi] (the keys of its parents). */
static int walk_table(Ctx *c, uint64_t pg, int has_lo, int64_t lo, int has_hi, int64_t hi,
                      int depth) {
    if (depth > MAX_DEPTH)
        return (c->why = "the table B-tree is deeper than SQLite allows"), -1;
    PageHdr h;
    if (read_hdr(c, pg, &h, "a table page number is outside the file") != 0)
        return -1;
    if (h.type == 0x0D) {
        for (uint32_t k = 0; k < h.ncells; k++) {
            const uint8_t *cell = cell_at(c, &h, k);
            if (cell == NULL || table_row(c, &h, cell, has_lo, lo, has_hi, hi) != 0)
                return -1;
        }
        done_with(c, h.page);
        return 0;
    }
    if (h.type != 0x05)
        return (c->why = "a page of the messages table is not a table B-tree page"), -1;
    if (h.ncells == 0)
        return (c->why = "an interior table page has no cells"), -1;
    int cur_has_lo = has_lo;
    int64_t cur_lo = lo;
    for (uint32_t k = 0; k < h.ncells; k++) {
        const uint8_t *cell = cell_at(c, &h, k);
        if (cell == NULL)
            return -1;
        if (cell + 4 > h.end)
            return (c->why = "a cell runs past its page"), -1;
        uint64_t key;
        if (get_varint(cell + 4, h.end, &key) == 0)
            return (c->why = "a cell runs past its page"), -1;
        int64_t k64 = (int64_t)key;
        if ((cur_has_lo && k64 <= cur_lo) || (has_hi && k64 > hi))
            return (c->why = "interior keys are out of order"), -1;
        if (k + 1 < h.ncells) { /* fetch the next child (a leaf, usually) meanwhile */
            uint32_t ptr = get2(h.cells + 2 * (k + 1));
            if (h.page + ptr + 4 <= h.end) {
                uint64_t next = get4(h.page + ptr);
                if (next >= 1 && next <= c->npages) {
                    const uint8_t *np = c->file + (next - 1) * (uint64_t)c->psize;
                    for (uint32_t b = 0; b < c->usable; b += 64)
                        __builtin_prefetch(np + b);
                }
            }
        }
        if (walk_table(c, get4(cell), cur_has_lo, cur_lo, 1, k64, depth + 1) != 0)
            return -1;
        cur_has_lo = 1;
        cur_lo = k64;
    }
    return walk_table(c, h.right, cur_has_lo, cur_lo, has_hi, hi, depth + 1);
}

/* Table row of rowid r, -1 if there is none. */
static inline ptrdiff_t find_row(const Ctx *c, int64_t r) {
    if (c->n == 0)
        return -1;
    if (c->dense) {
        uint64_t d = (uint64_t)r - (uint64_t)c->rowid[0];
        return r >= c->rowid[0] && d < c->n ? (ptrdiff_t)d : -1;
    }
    size_t lo = 0, hi = c->n;
    while (lo < hi) {
        size_t mid = lo + (hi - lo) / 2;
        if (c->rowid[mid] < r)
            lo = mid + 1;
        else
            hi = mid;
    }
    return lo < c->n && c->rowid[lo] == r ? (ptrdiff_t)lo : -1;
}

/* One index entry (timestamp, rowid) in the cell payload at p (P bytes, all on the page). */
static int index_entry(Ctx *c, const PageHdr *h, const uint8_t *p) {
    uint64_t P;
    int n = varint(p, h->end, &P);
    if (n == 0)
        return (c->why = "a cell runs past its page"), -1;
    p += n;
    if (P > local_size(c, P, 1) || P > (uint64_t)(h->end - p))
        return (c->why = "an index entry spills to an overflow page or past its page"), -1;
    const uint8_t *rend = p + P;
    uint64_t hs, t[2];
    n = varint(p, rend, &hs);
    if (n == 0 || hs > P || hs < (uint64_t)n)
        return (c->why = "an index record header runs past its payload"), -1;
    const uint8_t *q = p + n, *hend = p + hs;
    int k = 0;
    while (q < hend) {
        if (k == 2)
            return (c->why = "an index entry has more than 2 columns"), -1;
        n = varint(q, hend, &t[k]);
        if (n == 0)
            return (c->why = "a serial type runs past its record header"), -1;
        q += n;
        k++;
    }
    if (k != 2)
        return (c->why = "an index entry has fewer than 2 columns"), -1;
    int s0 = int_size(t[0]), s1 = int_size(t[1]);
    if (s0 < 0 || s1 < 0)
        return (c->why = "an index entry is not two integers"), -1;
    if (hs + (uint64_t)s0 + (uint64_t)s1 != P)
        return (c->why = "an index record header does not account for its payload"), -1;
    int64_t stamp = get_int(t[0], p + hs), rowid = get_int(t[1], p + hs + s0);
    if (c->idx_started && (stamp < c->idx_last_ts ||
                           (stamp == c->idx_last_ts && rowid <= c->idx_last_rowid)))
        return (c->why = "index entries are out of order"), -1;
    c->idx_started = 1;
    c->idx_last_ts = stamp;
    c->idx_last_rowid = rowid;
    ptrdiff_t j = find_row(c, rowid);
    if (j < 0)
        return (c->why = "an index entry names a rowid the table lacks"), -1;
    if (c->ts[j] != stamp)
        return (c->why = "an index entry's timestamp differs from its row's"), -1;
    if (++c->idx_n > c->n)
        return (c->why = "the index has more entries than the table has rows"), -1;
    int32_t m = c->slot[j];
    if (m >= 0) {
        if (c->norder == c->nsel) /* (cannot happen: one entry a row, checked above) */
            return (c->why = "a row is indexed twice"), -1;
        int32_t g = c->sel_grp[m];
        if (m < c->glast[g])
            c->gsorted[g] = 0;
        c->glast[g] = m;
        c->order[c->norder++] = m;
    }
    return 0;
}

/* In-order walk of the index B-tree below page pg: child, entry, child, ..., right-most. */
static int walk_index(Ctx *c, uint64_t pg, int depth) {
    if (depth > MAX_DEPTH)
        return (c->why = "the index B-tree is deeper than SQLite allows"), -1;
    PageHdr h;
    if (read_hdr(c, pg, &h, "an index page number is outside the file") != 0)
        return -1;
    int leaf = h.type == 0x0A;
    if (!leaf && h.type != 0x02)
        return (c->why = "a page of the timestamp index is not an index B-tree page"), -1;
    if (!leaf && h.ncells == 0)
        return (c->why = "an interior index page has no cells"), -1;
    for (uint32_t k = 0; k < h.ncells; k++) {
        const uint8_t *cell = cell_at(c, &h, k);
        if (cell == NULL)
            return -1;
        if (!leaf) {
            if (cell + 4 > h.end)
                return (c->why = "a cell runs past its page"), -1;
            if (walk_index(c, get4(cell), depth + 1) != 0)
                return -1;
            cell += 4;
        }
        if (index_entry(c, &h, cell) != 0)
            return -1;
    }
    if (leaf) {
        done_with(c, h.page);
        return 0;
    }
    return walk_index(c, h.right, depth + 1);
}

static void free_ctx(Ctx *c) {
    free(c->seen);
    free(c->lut);
    vec_free(c->rowid, c->cap * 8);
    vec_free(c->ts, c->cap * 8);
    vec_free(c->slot, c->cap * 4);
    vec_free(c->sel_len, c->sel_cap * 8);
    vec_free(c->sel_ts, c->sel_cap * 8);
    vec_free(c->sel_soff, c->sel_cap * 8);
    vec_free(c->sel_grp, c->sel_cap * 4);
    for (Py_ssize_t g = 0; c->stage != NULL && g < c->ngroups; g++)
        vec_free(c->stage[g].buf, c->stage[g].cap);
    free(c->stage);
    free(c->glast);
    free(c->gsorted);
    free(c->order);
}

/* Header checks, both walks, the order, the overflow chains: everything but the copy. */
static int scan_file(Ctx *c, uint64_t table_root, uint64_t index_root, Py_ssize_t ngroups,
                     int64_t *gcount, int64_t *gbytes) {
    const uint8_t *f = c->file;
    if (c->size < 100 || memcmp(f, "SQLite format 3\0", 16) != 0)
        return (c->why = "no SQLite header"), -1;
    uint32_t ps = get2(f + 16);
    if (ps == 1)
        ps = 65536;
    if (ps != c->psize)
        return (c->why = "the header's page size differs from PRAGMA page_size"), -1;
    if (f[18] < 1 || f[18] > 2 || f[19] < 1 || f[19] > 2)
        return (c->why = "unknown file format version"), -1;
    if (f[21] != 64 || f[22] != 32 || f[23] != 32)
        return (c->why = "unexpected payload fractions"), -1;
    uint32_t enc = get4(f + 56);
    if (enc < 1 || enc > 3)
        return (c->why = "unknown text encoding"), -1;
    c->usable = c->psize - f[20];
    if (c->usable < 480)
        return (c->why = "usable page size below 480 bytes"), -1;
    uint64_t np = c->size / c->psize;
    uint32_t hdr_pages = get4(f + 28);
    if (hdr_pages != 0 && get4(f + 92) == get4(f + 24) && hdr_pages < np)
        np = hdr_pages;
    if (np > 0x7ffffffeull)
        return (c->why = "too many pages"), -1;
    c->npages = (uint32_t)np;
    c->seen = calloc((size_t)np + 1, 1);
    if (c->seen == NULL)
        return (c->why = "out of memory"), -1;
    if (c->nids > 0 && c->ids[0] >= 0 && c->ids[c->nids - 1] < 65536) {
        c->lut_n = c->ids[c->nids - 1] + 1;
        c->lut = malloc((size_t)c->lut_n * sizeof(int32_t));
        if (c->lut == NULL)
            return (c->why = "out of memory"), -1;
        for (int64_t t = 0; t < c->lut_n; t++)
            c->lut[t] = -1;
        for (Py_ssize_t i = 0; i < c->nids; i++)
            c->lut[c->ids[i]] = (int32_t)i;
    }
    size_t ng = c->ngroups ? (size_t)c->ngroups : 1;
    c->stage = calloc(ng, sizeof(Stage));
    c->glast = calloc(ng, sizeof(int64_t));
    c->gsorted = malloc(ng);
    if (!c->stage || !c->glast || !c->gsorted || grow_rows(c) != 0 || grow_sel(c) != 0)
        return (c->why = "out of memory"), -1;
    memset(c->gsorted, 1, ng);
    if (walk_table(c, table_root, 0, 0, 0, 0, 0) != 0)
        return -1;
    drop_span(c);
    c->order = malloc((c->nsel ? c->nsel : 1) * sizeof(int64_t));
    if (c->order == NULL)
        return (c->why = "out of memory"), -1;
    c->dense = c->n == 0 || (uint64_t)c->rowid[c->n - 1] - (uint64_t)c->rowid[0] == c->n - 1;
    if (walk_index(c, index_root, 0) != 0)
        return -1;
    drop_span(c);
    if (c->idx_n != c->n)
        return (c->why = "the index has fewer entries than the table has rows"), -1;
    for (Py_ssize_t g = 0; g < ngroups; g++)
        gcount[g] = gbytes[g] = 0;
    for (size_t i = 0; i < c->norder; i++) {
        size_t k = (size_t)c->order[i];
        gcount[c->sel_grp[k]]++;
        gbytes[c->sel_grp[k]] += c->sel_len[k];
    }
    return 0;
}

/* Fill the outputs: per group, in index order, stamps, offsets into the group's payloads,
 * lengths. A group whose rows the index gives in rowid order (the usual case) keeps its stage
 * as its payloads; another is copied row by row into index order. row_at and byte_at are
 * ngroups scratch cursors each. Returns -1 when out of memory. */
static int fill(Ctx *c, Py_ssize_t ngroups, const int64_t *gcount, const int64_t *gbytes,
                int64_t *row_at, int64_t *byte_at, int64_t *stamps, int64_t *offs,
                int64_t *lens) {
    uint8_t **dst = calloc(ngroups ? (size_t)ngroups : 1, sizeof(uint8_t *));
    if (dst == NULL)
        return -1;
    int64_t r = 0;
    int rc = 0;
    for (Py_ssize_t g = 0; g < ngroups; g++) {
        row_at[g] = r;
        byte_at[g] = 0;
        r += gcount[g];
        if (!c->gsorted[g] && (dst[g] = vec_grow(NULL, 0, gbytes[g] ? (size_t)gbytes[g] : 1)) == NULL)
            rc = -1;
    }
    for (size_t i = 0; rc == 0 && i < c->norder; i++) {
        size_t k = (size_t)c->order[i];
        int32_t g = c->sel_grp[k];
        int64_t at = row_at[g]++;
        int64_t len = c->sel_len[k];
        stamps[at] = c->sel_ts[k];
        offs[at] = byte_at[g];
        lens[at] = len;
        if (dst[g] != NULL) /* ties or late stamps: the index order, row by row */
            memcpy(dst[g] + byte_at[g], c->stage[g].buf + c->sel_soff[k], (size_t)len);
        byte_at[g] += len;
    }
    for (Py_ssize_t g = 0; g < ngroups; g++) {
        if (dst[g] == NULL)
            continue;
        size_t size = gbytes[g] ? (size_t)gbytes[g] : 1;
        if (rc == 0) {
            vec_free(c->stage[g].buf, c->stage[g].cap);
            c->stage[g].buf = dst[g];
            c->stage[g].cap = size;
        } else {
            vec_free(dst[g], size);
        }
    }
    free(dst);
    return rc;
}

/* A read-write buffer owning a stage's memory: a group's payloads, handed to numpy as they
 * are (no copy); freed when the last view of it goes. */
typedef struct {
    PyObject_HEAD
    uint8_t *data;
    Py_ssize_t len;
    size_t cap;
} Block;

static int block_getbuffer(PyObject *self, Py_buffer *view, int flags) {
    Block *b = (Block *)self;
    return PyBuffer_FillInfo(view, self, b->data, b->len, 0, flags);
}

static void block_dealloc(PyObject *self) {
    vec_free(((Block *)self)->data, ((Block *)self)->cap);
    Py_TYPE(self)->tp_free(self);
}

static PyBufferProcs block_as_buffer = {block_getbuffer, NULL};

static PyTypeObject BlockType = {
    PyVarObject_HEAD_INIT(NULL, 0)
    .tp_name = "uwval.io._db3pages.Block",
    .tp_basicsize = sizeof(Block),
    .tp_dealloc = block_dealloc,
    .tp_as_buffer = &block_as_buffer,
    .tp_flags = Py_TPFLAGS_DEFAULT,
    .tp_doc = "The payloads of one group of topics (a read-write buffer).",
};

/* A Block taking over the stage's memory (the room past its length was never written,
 * so it is not resident). */
static PyObject *take_stage(Stage *st) {
    Block *b = PyObject_New(Block, &BlockType);
    if (b == NULL)
        return NULL;
    if (st->buf == NULL) {
        st->buf = vec_grow(NULL, 0, 1);
        st->cap = 1;
        if (st->buf == NULL) {
            st->cap = 0;
            Py_DECREF(b);
            return PyErr_NoMemory();
        }
    }
    b->data = st->buf;
    b->len = (Py_ssize_t)st->len;
    b->cap = st->cap;
    st->buf = NULL;
    st->cap = 0;
    return (PyObject *)b;
}

/* A bytes-like input of native items of the given size (e.g. numpy's tobytes()). */
static int get_input(PyObject *obj, Py_buffer *view, Py_ssize_t item, const char *what) {
    if (PyObject_GetBuffer(obj, view, PyBUF_C_CONTIGUOUS) != 0)
        return -1;
    if (view->len % item != 0) {
        PyErr_Format(PyExc_ValueError, "%s must hold %zd-byte items", what, item);
        PyBuffer_Release(view);
        return -1;
    }
    return 0;
}

PyDoc_STRVAR(scan_doc,
"scan(file, page_size, table_root, index_root, ids, pick, ngroups, release=False)\n"
"    -> tuple | str\n\n"
"Read the rosbag2 ``messages`` table (root page ``table_root``) and its timestamp index\n"
"(root page ``index_root``) from the bytes-like ``file`` (the whole .db3). ``ids`` are the\n"
"topic ids of the ``topics`` table (native int64 bytes, ascending); ``pick`` (native int32\n"
"bytes, one per id) is the\n"
"output group of that topic, or -1 when it is not read. Returns (stats, counts, stamps,\n"
"offsets, lengths, payloads): stats is int64 (count, min, max) per id; counts int64\n"
"messages per group; then per message, group after group and in index order (timestamp,\n"
"then rowid), the int64 timestamp, offset into its group's payloads and length (these\n"
"as bytearrays); payloads a tuple of one writable buffer per group. Returns a\n"
"str naming the reason when the file is anything but what it expects (the caller then\n"
"reads it with sqlite3). ``release``: ``file`` is a read-only mmap of the file (nothing\n"
"else!), whose pages are dropped from this process as they are read (madvise DONTNEED),\n"
"so the resident size does not grow by the file's size.");

static PyObject *scan(PyObject *self, PyObject *args) {
    (void)self;
    PyObject *file_obj, *ids_obj, *pick_obj;
    unsigned long long psize, table_root, index_root;
    Py_ssize_t ngroups;
    int release = 0;
    if (!PyArg_ParseTuple(args, "OKKKOOn|p:scan", &file_obj, &psize, &table_root, &index_root,
                          &ids_obj, &pick_obj, &ngroups, &release))
        return NULL;
    if (psize < 512 || psize > 65536 || (psize & (psize - 1)) != 0 || ngroups < 0 ||
        ngroups > 0x7fffffff) {
        PyErr_SetString(PyExc_ValueError, "page_size must be a power of two in 512..65536");
        return NULL;
    }
    Py_buffer file, ids, pick;
    if (PyObject_GetBuffer(file_obj, &file, PyBUF_C_CONTIGUOUS) != 0)
        return NULL;
    if (get_input(ids_obj, &ids, 8, "ids") != 0) {
        PyBuffer_Release(&file);
        return NULL;
    }
    if (get_input(pick_obj, &pick, 4, "pick") != 0) {
        PyBuffer_Release(&ids);
        PyBuffer_Release(&file);
        return NULL;
    }
    PyObject *result = NULL;
    Ctx c;
    memset(&c, 0, sizeof c);
    c.file = (const uint8_t *)file.buf;
    c.size = (uint64_t)file.len;
    c.psize = (uint32_t)psize;
    c.ids = (const int64_t *)ids.buf;
    c.pick = (const int32_t *)pick.buf;
    c.nids = ids.len / 8;
    c.ngroups = ngroups;
    c.release = release;
    int bad_args = pick.len / 4 != c.nids;
    for (Py_ssize_t i = 0; !bad_args && i < c.nids; i++)
        bad_args = (i > 0 && c.ids[i] <= c.ids[i - 1]) || c.pick[i] < -1 ||
                   c.pick[i] >= ngroups;
    if (bad_args) {
        PyErr_SetString(PyExc_ValueError,
                        "ids must ascend strictly; pick: one group in -1..ngroups-1 per id");
        goto done;
    }
    c.stats = calloc((size_t)(3 * c.nids + 1), sizeof(int64_t));
    int64_t *gcount = calloc((size_t)(4 * ngroups + 1), sizeof(int64_t));
    if (c.stats == NULL || gcount == NULL) {
        free(gcount);
        PyErr_NoMemory();
        goto done;
    }
    int64_t *gbytes = gcount + ngroups;
    int rc;
    Py_BEGIN_ALLOW_THREADS
    rc = scan_file(&c, table_root, index_root, ngroups, gcount, gbytes);
    Py_END_ALLOW_THREADS
    if (rc != 0) {
        free(gcount);
        result = PyUnicode_FromString(c.why ? c.why : "declined");
        goto done;
    }
    Py_ssize_t nout = (Py_ssize_t)c.norder;
    PyObject *stats = PyByteArray_FromStringAndSize((const char *)c.stats, 24 * c.nids);
    PyObject *counts = PyByteArray_FromStringAndSize((const char *)gcount, 8 * ngroups);
    PyObject *stamps = PyByteArray_FromStringAndSize(NULL, 8 * nout);
    PyObject *offs = PyByteArray_FromStringAndSize(NULL, 8 * nout);
    PyObject *lens = PyByteArray_FromStringAndSize(NULL, 8 * nout);
    PyObject *payload = PyTuple_New(ngroups);
    if (stats && counts && stamps && offs && lens && payload) {
        int64_t *st = (int64_t *)PyByteArray_AS_STRING(stamps);
        int64_t *of = (int64_t *)PyByteArray_AS_STRING(offs);
        int64_t *ln = (int64_t *)PyByteArray_AS_STRING(lens);
        Py_BEGIN_ALLOW_THREADS
        rc = fill(&c, ngroups, gcount, gbytes, gbytes + ngroups, gbytes + 2 * ngroups, st, of,
                  ln);
        Py_END_ALLOW_THREADS
        for (Py_ssize_t g = 0; rc == 0 && g < ngroups; g++) {
            PyObject *block = take_stage(&c.stage[g]);
            if (block == NULL)
                rc = -1;
            else
                PyTuple_SET_ITEM(payload, g, block);
        }
        if (rc == 0)
            result = PyTuple_Pack(6, stats, counts, stamps, offs, lens, payload);
        else if (!PyErr_Occurred())
            PyErr_NoMemory();
    }
    Py_XDECREF(stats);
    Py_XDECREF(counts);
    Py_XDECREF(stamps);
    Py_XDECREF(offs);
    Py_XDECREF(lens);
    Py_XDECREF(payload);
    free(gcount);
done:
    free(c.stats);
    free_ctx(&c);
    PyBuffer_Release(&pick);
    PyBuffer_Release(&ids);
    PyBuffer_Release(&file);
    return result;
}

static PyMethodDef methods[] = {
    {"scan", scan, METH_VARARGS, scan_doc},
    {NULL, NULL, 0, NULL},
};

static struct PyModuleDef module = {
    PyModuleDef_HEAD_INIT, "_db3pages",
    "Strict, fast reader of the rosbag2 messages table's pages (see uwval.io.db3_pages).", -1,
    methods, NULL, NULL, NULL, NULL,
};

PyMODINIT_FUNC PyInit__db3pages(void) {
    if (PyType_Ready(&BlockType) < 0)
        return NULL;
    return PyModule_Create(&module);
}
