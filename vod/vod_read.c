/* VOD reader: validates a whole file up front (spec section 8), then serves
 * voxels of any level from the octree table and the decoded bricks. */
#include "vod.h"

#include <errno.h>
#include <fcntl.h>
#include <math.h>
#include <stdatomic.h>
#include <stdbool.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/mman.h>
#include <sys/stat.h>
#include <unistd.h>
#include <libdeflate.h>
#include <zlib.h>

#include "err.h"
#include "par.h"

#define TRAILER_FIXED 40u
#define MAX_HEIGHT 21 /* (8^h - 1) / 7 * 4 still fits a u64 */

struct vod_file {
    vod_info info;
    char *metadata;
    uint32_t *tree;   /* numberOfNodes brickIDs, preorder */
    uint8_t **brick;  /* raw bricks by ID (into slab); [0] unused */
    uint8_t **slab;   /* the raw bricks, a chunk of them in each (decode_chunk) */
    uint32_t chunks;  /* slabs */
    uint64_t sub[MAX_HEIGHT + 1]; /* nodes in a subtree rooted at level l */
    uint32_t k, padded;
    size_t raw_bytes;
    uint32_t levels;  /* the levels whose bricks are kept (bit l: level l) */
};

/* Parsing state: the image and where its parts are. */
typedef struct {
    const uint8_t *b;
    size_t len;
    size_t end;        /* end of the brick records: len, or trailerOffset */
    uint64_t bricks_at; /* numberOfBricks field */
    uint64_t records_at; /* first byte after the brick table */
    err_info *err;     /* NULL: no message */
    int threads;       /* the CRC's and the records' (1 or more) */
    struct scan_job *scan; /* vod_scan's: the bricks handed out, not kept */
    uint32_t levels;   /* the levels whose bricks are inflated (vod_open_levels) */
} parse;

static float f32_at(const uint8_t *p)
{
    uint32_t u = vod_get32(p);
    float f;
    memcpy(&f, &u, sizeof f);
    return f;
}

/* ---- trailer (section 7) ---- */

static int read_trailer_body(parse *ps, vod_file *f, uint32_t at)
{
    const uint8_t *t = ps->b + at;
    uint32_t size = vod_get32(t + 4), meta = vod_get32(t + 24);
    if (size != ps->len - at)
        return err_set(ps->err, -EBADMSG, "trailerSize %u at offset %u does not reach the "
                    "end of the file (%zu bytes)", size, at + 4, ps->len);
    if (meta != size - TRAILER_FIXED)
        return err_set(ps->err, -EBADMSG, "trailer metadataSize %u does not match "
                    "trailerSize %u", meta, size);
    for (int a = 0; a < 3; a++) f->info.origin[a] = f32_at(t + 8 + 4 * a);
    f->info.channel = vod_get32(t + 20);
    if (f->info.channel > 4)
        return err_set(ps->err, -EBADMSG, "trailer channel %u unknown (0..4)", f->info.channel);
    f->metadata = malloc((size_t)meta + 1);
    if (!f->metadata) return err_set(ps->err, -ENOMEM, "out of memory");
    memcpy(f->metadata, t + 28, meta);
    f->metadata[meta] = '\0';
    ps->end = at;
    return 0;
}

/* The CRC-32 of b[0 .. len) in parts of CRC_PART_MIN bytes or more, one a
 * thread, joined (crc32_combine): a file just mapped costs a fault of the
 * hypervisor's for each of its pages at their first touch (a 66 MB file:
 * 47 ms to check on one thread of the 2-core machine, 11 ms once its pages
 * were touched), and the threads share them. */
#define CRC_PART_MIN ((size_t)1 << 20)

typedef struct {
    const uint8_t *b;
    size_t len;
    uint32_t crc[PAR_MAX];
} crc_job;

/* Where part k of n of len bytes starts (k = n: len). */
static size_t crc_part_at(size_t len, unsigned k, unsigned n)
{
    return k == n ? len : len / n * k;
}

static void crc_part(void *ud, unsigned k, unsigned n)
{
    crc_job *j = ud;
    size_t a = crc_part_at(j->len, k, n), e = crc_part_at(j->len, k + 1, n);
    j->crc[k] = libdeflate_crc32(0, j->b + a, e - a);
}

static uint32_t file_crc(const uint8_t *b, size_t len, int threads)
{
    crc_job j = {.b = b, .len = len};
    size_t most = len / CRC_PART_MIN;
    most = most < 1 ? 1 : most > PAR_MAX ? PAR_MAX : most;
    unsigned n = (size_t)threads < most ? (unsigned)threads : (unsigned)most;
    par_run(n, crc_part, &j);
    uLong crc = j.crc[0];
    for (unsigned k = 1; k < n; k++)
        crc = crc32_combine(crc, j.crc[k],
                            (z_off_t)(crc_part_at(len, k + 1, n) - crc_part_at(len, k, n)));
    return (uint32_t)crc;
}

/* Found from the last 12 bytes; the CRC is checked before anything else is
 * believed, so truncation and corruption are reported as such. */
static int read_trailer(parse *ps, vod_file *f)
{
    const uint8_t *b = ps->b;
    size_t len = ps->len;
    if (len < VOD_HEADER_BYTES + 4 + TRAILER_FIXED)
        return err_set(ps->err, -EBADMSG, "file is truncated: flags bit 16 promises a "
                    "trailer, but the file has only %zu bytes", len);
    if (memcmp(b + len - 8, "XDOV", 4) != 0)
        return err_set(ps->err, -EBADMSG, "file is truncated or corrupted: flags bit 16 "
                    "promises a trailer, but 'XDOV' is not at offset %zu", len - 8);
    uint32_t stored = vod_get32(b + len - 4);
    uint32_t crc = file_crc(b, len - 4, ps->threads);
    if (crc != stored)
        return err_set(ps->err, -EBADMSG, "trailer CRC mismatch (file corrupted): stored "
                    "%08x, computed %08x", stored, crc);
    uint32_t at = vod_get32(b + len - 12);
    if (at < VOD_HEADER_BYTES + 4 || at > len - TRAILER_FIXED ||
        memcmp(b + at, "VODX", 4) != 0)
        return err_set(ps->err, -EBADMSG, "trailerOffset %u does not point at 'VODX'", at);
    f->info.crc32 = stored;
    f->info.has_trailer = 1;
    return read_trailer_body(ps, f, at);
}

/* ---- header (section 2) ---- */

static int check_brick_and_volume(parse *ps, vod_info *in)
{
    const uint8_t *h = ps->b;
    uint32_t bs[3];
    for (int a = 0; a < 3; a++) {
        in->volume[a] = vod_get32(h + 8 + 4 * a);
        bs[a] = vod_get32(h + 20 + 4 * a);
        in->voxel_scale[a] = f32_at(h + 32 + 4 * a);
    }
    if (!in->volume[0] || !in->volume[1] || !in->volume[2])
        return err_set(ps->err, -EINVAL, "volumeSize %ux%ux%u: each side must be at least 1",
                    in->volume[0], in->volume[1], in->volume[2]);
    if (bs[0] != bs[1] || bs[1] != bs[2])
        return err_set(ps->err, -EINVAL, "brickSize %ux%ux%u is not cubic", bs[0], bs[1], bs[2]);
    if (bs[0] < 2 || bs[0] > 256 || (bs[0] & (bs[0] - 1)))
        return err_set(ps->err, -EINVAL, "brickSize %u is not a power of two in 2..256", bs[0]);
    in->brick = bs[0];
    for (int a = 0; a < 3; a++)
        if (!isfinite(in->voxel_scale[a]) || !(in->voxel_scale[a] > 0.0f))
            return err_set(ps->err, -EINVAL, "voxelScale %g on axis %d is not finite and > 0",
                        (double)in->voxel_scale[a], a);
    return 0;
}

static int check_height(parse *ps, vod_file *f)
{
    vod_info *in = &f->info;
    in->height = vod_get32(ps->b + 44);
    uint32_t maxv = in->volume[0];
    if (in->volume[1] > maxv) maxv = in->volume[1];
    if (in->volume[2] > maxv) maxv = in->volume[2];
    uint64_t per_axis = ((uint64_t)maxv + in->brick - 1) / in->brick;
    uint32_t m = 0;
    while ((1ull << m) < per_axis) m++;
    if (in->height != m + 1)
        return err_set(ps->err, -EINVAL, "treeHeight %u does not fit volumeSize %ux%ux%u "
                    "and brickSize %u (the spec's formula gives %u)", in->height,
                    in->volume[0], in->volume[1], in->volume[2], in->brick, m + 1);
    if (in->height > MAX_HEIGHT)
        return err_set(ps->err, -EBADMSG, "file is truncated: treeHeight %u needs an "
                    "octree table larger than any file", in->height);
    while (1u << f->k < in->brick) f->k++;
    f->padded = in->height - 1 + f->k < 32 ? in->brick << (in->height - 1) : 0;
    in->nodes = ((1ull << (3 * in->height)) - 1) / 7;
    for (uint32_t l = 0; l < in->height; l++)
        f->sub[l] = ((1ull << (3 * (l + 1))) - 1) / 7;
    return 0;
}

static int check_encoding(parse *ps, vod_info *in)
{
    char s[5];
    const uint8_t *h = ps->b;
    in->voxel_bits = vod_get32(h + 48);
    in->hash = vod_get32(h + 52);
    in->comp = vod_get32(h + 56);
    uint32_t vb = in->voxel_bits;
    if (vb != 1 && vb != 8 && vb != 16 && vb != 32)
        return err_set(ps->err, -EINVAL, "voxelSize %u is not 1, 8, 16 or 32 bits", vb);
    if (in->hash != VOD_HASH_SFHS && in->hash != VOD_HASH_XX32)
        return err_set(ps->err, -EINVAL, "unsupported hashAlgorithm '%s'",
                    vod_fourcc_str(in->hash, s));
    if (in->comp != VOD_COMP_NONE && in->comp != VOD_COMP_ZLIB &&
        in->comp != VOD_COMP_RUNL)
        return err_set(ps->err, -EINVAL, "unsupported compAlgorithm '%s'",
                    vod_fourcc_str(in->comp, s));
    return 0;
}

static int check_flags(parse *ps, const vod_file *f)
{
    const vod_info *in = &f->info;
    uint32_t fl = in->flags;
    bool comp = in->comp != VOD_COMP_NONE, pad = false;
    for (int a = 0; a < 3; a++) pad |= f->padded > in->volume[a];
    if (fl & ~(VOD_FLAG_COMPRESSED | VOD_FLAG_PADDED | VOD_FLAG_FLOAT | VOD_FLAG_TRAILER))
        return err_set(ps->err, -EINVAL, "flags %08x: reserved or unknown bits are set", fl);
    if (!(fl & VOD_FLAG_COMPRESSED) != !comp)
        return err_set(ps->err, -EINVAL, "flags bit 0 (compression) is %s but compAlgorithm "
                    "is %s", comp ? "clear" : "set", comp ? "not NONE" : "NONE");
    if (!(fl & VOD_FLAG_PADDED) != !pad)
        return err_set(ps->err, -EINVAL, "flags bit 1 (padding) is %s but the padded side %u "
                    "%s volumeSize", pad ? "clear" : "set", f->padded,
                    pad ? "exceeds" : "equals");
    if ((fl & VOD_FLAG_FLOAT) && in->voxel_bits != 32)
        return err_set(ps->err, -EINVAL, "flags bit 2 (float) needs voxelSize 32, not %u",
                    in->voxel_bits);
    return 0;
}

/* Channel (trailer) and voxelSize must agree. */
static int check_channel(parse *ps, const vod_info *in)
{
    static const uint32_t bits[5] = {0, 1, 8, 32, 32};
    if (in->channel == 0 || bits[in->channel] == in->voxel_bits) return 0;
    return err_set(ps->err, -EINVAL, "trailer channel %u needs voxelSize %u, the header "
                "says %u", in->channel, bits[in->channel], in->voxel_bits);
}

static int read_header(parse *ps, vod_file *f)
{
    vod_info *in = &f->info;
    /* The signature first, as far as the file goes: a short text file is
     * not a VOD file, not a truncated one. */
    size_t sig = ps->len < 4 ? ps->len : 4;
    if (sig && memcmp(ps->b, ".VOD", sig) != 0) {
        char got[16] = "";
        for (size_t i = 0; i < sig; i++) /* "xx" or " xx": 3 bytes a step at most */
            snprintf(got + strlen(got), sizeof got - strlen(got), "%s%02x", i ? " " : "",
                     ps->b[i]);
        return err_set(ps->err, -EINVAL, "not a VOD file (bad signature %s; want 2e 56 4f 44, "
                    "\".VOD\")", got);
    }
    if (ps->len < VOD_HEADER_BYTES)
        return err_set(ps->err, -EBADMSG, "file is truncated: the header needs %u bytes, "
                    "file has %zu", VOD_HEADER_BYTES, ps->len);
    in->flags = vod_get32(ps->b + 60);
    int rc = (in->flags & VOD_FLAG_TRAILER) ? read_trailer(ps, f) : 0;
    if (rc) return rc;
    in->version = vod_get32(ps->b + 4);
    if (in->version != 1)
        return err_set(ps->err, -EINVAL, "unsupported fileVersion %u", in->version);
    if ((rc = check_brick_and_volume(ps, in)) || (rc = check_height(ps, f)) ||
        (rc = check_encoding(ps, in)) || (rc = check_flags(ps, f)) ||
        (rc = check_channel(ps, in)))
        return rc;
    f->raw_bytes = (size_t)in->brick * in->brick * in->brick * in->voxel_bits / 8;
    return 0;
}

/* ---- octree table (section 3) ---- */

static int read_tree(parse *ps, vod_file *f)
{
    uint64_t need = f->info.nodes * 4;
    if (need + 4 > ps->end - VOD_HEADER_BYTES)
        return err_set(ps->err, -EBADMSG, "file is truncated: octree table and numberOfBricks "
                    "need %llu bytes at offset %u, file has %zu%s",
                    (unsigned long long)need + 4, VOD_HEADER_BYTES, ps->end,
                    ps->end < ps->len ? " before its trailer" : "");
    f->tree = malloc((size_t)need);
    if (!f->tree) return err_set(ps->err, -ENOMEM, "out of memory for %llu nodes",
                              (unsigned long long)f->info.nodes);
    const uint8_t *p = ps->b + VOD_HEADER_BYTES;
    for (uint64_t i = 0; i < f->info.nodes; i++) f->tree[i] = vod_get32(p + 4 * i);
    ps->bricks_at = VOD_HEADER_BYTES + need;
    return 0;
}

/* A node whose region is empty (ID 0) cannot have a non-empty descendant. */
static int check_subtree(parse *ps, const vod_file *f, uint64_t p, uint32_t l)
{
    if (f->tree[p] == 0) {
        for (uint64_t q = p + 1; q < p + f->sub[l]; q++)
            if (f->tree[q])
                return err_set(ps->err, -EBADMSG, "node %llu has brickID 0 (empty region) but "
                            "its descendant node %llu has brickID %u",
                            (unsigned long long)p, (unsigned long long)q, f->tree[q]);
        return 0;
    }
    if (f->tree[p] > f->info.bricks)
        return err_set(ps->err, -EBADMSG, "brickID %u at node %llu is not in the brick table "
                    "(numberOfBricks %u)", f->tree[p], (unsigned long long)p,
                    f->info.bricks);
    for (uint64_t i = 0; l > 0 && i < 8; i++) {
        int rc = check_subtree(ps, f, p + 1 + i * f->sub[l - 1], l - 1);
        if (rc) return rc;
    }
    return 0;
}

/* ---- brick table and records (section 4) ---- */

typedef struct {
    uint32_t id, off, hash, size;
} brick_ent;

static int read_count(parse *ps, vod_file *f)
{
    uint32_t n = vod_get32(ps->b + ps->bricks_at);
    uint64_t room = ps->end - ps->bricks_at - 4;
    if ((uint64_t)n * 16 > room) /* a 12-byte entry and a 4-byte dataSize each */
        return err_set(ps->err, -EBADMSG, "numberOfBricks %u at offset %llu cannot fit: "
                    "the file has %llu bytes after it", n,
                    (unsigned long long)ps->bricks_at, (unsigned long long)room);
    f->info.bricks = n;
    ps->records_at = ps->bricks_at + 4 + 12ull * n;
    return 0;
}

static int read_table(parse *ps, const vod_file *f, brick_ent *e)
{
    uint32_t n = f->info.bricks;
    uint8_t *seen = calloc((size_t)n + 1, 1);
    if (!seen) return err_set(ps->err, -ENOMEM, "out of memory");
    const uint8_t *p = ps->b + ps->bricks_at + 4;
    int rc = 0;
    for (uint32_t i = 0; i < n && !rc; i++, p += 12) {
        e[i] = (brick_ent){vod_get32(p), vod_get32(p + 4), vod_get32(p + 8), 0};
        if (e[i].id == 0 || e[i].id > n)
            rc = err_set(ps->err, -EBADMSG, "brick table entry %u has brickID %u, outside "
                      "1..%u", i, e[i].id, n);
        else if (seen[e[i].id]++)
            rc = err_set(ps->err, -EBADMSG, "duplicate brick ID %u in table", e[i].id);
    }
    free(seen);
    return rc;
}

static int check_record(parse *ps, brick_ent *e)
{
    if (e->off < ps->records_at || e->off > ps->end || ps->end - e->off < 4)
        return err_set(ps->err, -EBADMSG, "brick %u: offset %u outside the file (brick "
                    "records lie in %llu..%zu)", e->id, e->off,
                    (unsigned long long)ps->records_at, ps->end);
    e->size = vod_get32(ps->b + e->off);
    if (e->size > ps->end - e->off - 4)
        return err_set(ps->err, -EBADMSG, "brick %u: dataSize %u at offset %u passes the "
                    "end of the brick data (offset %zu)", e->id, e->size, e->off, ps->end);
    return 0;
}

static int by_offset(const void *a, const void *b)
{
    const brick_ent *x = a, *y = b;
    return (x->off > y->off) - (x->off < y->off);
}

/* Records may come in any order but must not overlap (so no two IDs can
 * share one small record that inflates to a huge brick) and must fill the
 * file up to its end or its trailer. */
static int check_extents(parse *ps, brick_ent *e, uint32_t n)
{
    qsort(e, n, sizeof *e, by_offset);
    uint64_t at = ps->records_at;
    for (uint32_t i = 0; i < n; i++) {
        if (e[i].off < at)
            return err_set(ps->err, -EBADMSG, "brick %u: record at offset %u overlaps brick "
                        "%u's record", e[i].id, e[i].off, e[i - 1].id);
        at = (uint64_t)e[i].off + 4 + e[i].size;
    }
    if (at != ps->end)
        return err_set(ps->err, -EBADMSG, "%llu unexpected bytes after the last brick record "
                    "(offset %llu)%s", (unsigned long long)(ps->end - at),
                    (unsigned long long)at,
                    ps->end == ps->len ? "; flags bit 16 (trailer) is clear" : "");
    return 0;
}

/* The raw bytes of brick record e into raw (f->raw_bytes), checked
 * against its hash; dz inflates a zlib record (libdeflate, about twice as
 * fast as zlib's inflate here; the tests' second reader uses zlib). */
static int decode_brick(parse *ps, vod_file *f, const brick_ent *e, uint8_t *raw,
                        struct libdeflate_decompressor *dz)
{
    const uint8_t *d = ps->b + e->off + 4;
    size_t n = f->raw_bytes;
    const char *why = NULL;
    if (f->info.comp == VOD_COMP_NONE) {
        if (e->size != n) why = "dataSize differs";
        else memcpy(raw, d, n);
    } else if (f->info.comp == VOD_COMP_RUNL) {
        if (vod_runl_decode(f->info.voxel_bits, d, e->size, raw, n)) why = "bad RUNL runs";
    } else {
        size_t in = 0, out = 0;
        enum libdeflate_result zr = libdeflate_zlib_decompress_ex(dz, d, e->size, raw, n, &in, &out);
        if (zr == LIBDEFLATE_INSUFFICIENT_SPACE) why = "zlib: too much data";
        else if (zr != LIBDEFLATE_SUCCESS) why = "zlib error";
        else if (out != n) why = "zlib: too little data";
        else if (in != e->size) why = "bytes left after the zlib stream";
    }
    if (why)
        return err_set(ps->err, -EBADMSG, "brick %u does not decompress to %zu bytes (%s)",
                    e->id, n, why);
    uint32_t h = vod_hash(f->info.hash, raw, n);
    if (h != e->hash)
        return err_set(ps->err, -EBADMSG, "brick %u: hash mismatch (table %08x, data %08x)",
                    e->id, e->hash, h);
    return 0;
}

/* ---- inflating and hashing the bricks, in chunks, by one or more threads ----
 *
 * The records, in file order, are cut into chunks of about SLAB_BYTES of raw
 * bricks; a chunk's bricks live in one allocation (its slab: few mallocs, and
 * huge pages where the kernel gives them, so fewer page faults).  A thread
 * claims the next chunk, allocates its slab, and inflates and hashes its
 * bricks in order (a scan, vod_scan, has no slabs: each brick is inflated
 * into the thread's one brick of room and handed on).  The first bad record
 * in file order is the one reported, whatever the number of threads: a
 * thread skips only records after the lowest bad one found so far, so
 * every record before the final lowest one was checked, and that one is
 * decoded again, alone, for its message. */

#define SLAB_BYTES ((size_t)2 << 20) /* a huge page on x86-64 */

/* vod_scan's bricks: fn called for every node of a brick ID, the nodes of
 * ID i at refs[at[i] .. at[i + 1]) (made from the octree table before the
 * bricks are inflated). */
typedef struct {
    int level;
    uint32_t b[3];
} node_ref;

/* A brick that many nodes share (a distance field's uniform +w and -w, a
 * solid's full brick) would leave all its nodes to the one thread that
 * inflated it: such a brick is kept (a copy, the scan's keep_bytes in all
 * at most; past them, visited where it was inflated) and its nodes dealt
 * to every thread once the file has checked (scan_kept). */
#define SCAN_SHARED_REFS 16u

typedef struct scan_job {
    vod_scan_fn fn;
    void *ud;
    node_ref *refs;
    uint64_t *at;
    uint8_t **kept;  /* by ID (1 .. ids): the copy of a shared brick, or NULL */
    uint32_t ids;
    /* the bytes kept so far (relaxed: a budget the threads draw from,
     * ordering nothing; kept[] is read after par_run's join) */
    _Atomic uint64_t kept_bytes;
    uint64_t keep_bytes; /* the budget */
} scan_job;

typedef struct {
    parse ps;          /* the image; err NULL: no thread writes a message */
    vod_file *f;
    const brick_ent *e; /* the records in file order */
    uint32_t n, per;   /* records, records per chunk */
    /* The next chunk to claim.  Relaxed: a claim orders nothing; what the
     * threads wrote is read after par_run joins them, which orders it. */
    atomic_uint next;
    /* The lowest bad record found (n: none), lowered by compare-and-swap.
     * Relaxed: the threads read it only to stop early; the caller reads the
     * final value after par_run joins them. */
    atomic_uint bad;
} decode_job;

static uint8_t *slab_alloc(size_t bytes)
{
    if (bytes < SLAB_BYTES) return malloc(bytes);
    size_t whole = (bytes + SLAB_BYTES - 1) / SLAB_BYTES * SLAB_BYTES;
    uint8_t *p = aligned_alloc(SLAB_BYTES, whole);
#ifdef MADV_HUGEPAGE
    if (p) (void)madvise(p, whole, MADV_HUGEPAGE); /* a hint: fine if refused */
#endif
    return p;
}

static void mark_bad(decode_job *j, uint32_t i)
{
    unsigned cur = atomic_load_explicit(&j->bad, memory_order_relaxed);
    while (i < cur && !atomic_compare_exchange_weak_explicit(
                          &j->bad, &cur, i, memory_order_relaxed, memory_order_relaxed)) {
    }
}

/* A copy of shared brick raw (n bytes) for ID id, within the budget.  The
 * bytes are charged before the copy is made, so that the threads together
 * never pass the budget, and given back when it is not (past the budget,
 * or no memory): a refused copy leaves the budget to the next brick. */
static bool keep_shared(scan_job *s, uint32_t id, const uint8_t *raw, size_t n)
{
    uint64_t was = atomic_fetch_add_explicit(&s->kept_bytes, n, memory_order_relaxed);
    if (was + n <= s->keep_bytes && (s->kept[id] = malloc(n))) {
        memcpy(s->kept[id], raw, n);
        return true;
    }
    atomic_fetch_sub_explicit(&s->kept_bytes, n, memory_order_relaxed);
    return false;
}

/* Brick record e, inflated and checked into raw, to the scan's fn for
 * every node that holds it, or kept for scan_kept when many do. */
static void scan_brick(const decode_job *j, unsigned thread, const brick_ent *e,
                       const uint8_t *raw)
{
    scan_job *s = j->ps.scan;
    uint64_t r0 = s->at[e->id], r1 = s->at[e->id + 1];
    if (r1 - r0 > SCAN_SHARED_REFS && keep_shared(s, e->id, raw, j->f->raw_bytes)) return;
    for (uint64_t r = r0; r < r1; r++)
        s->fn(s->ud, thread, &j->f->info, s->refs[r].level, s->refs[r].b, raw);
}

/* Chunk c's records inflated and checked one at a time into raw (a brick's
 * room), each handed to the scan, none kept. */
static void scan_chunk(decode_job *j, uint32_t c, unsigned thread, uint8_t *raw,
                       struct libdeflate_decompressor *dz)
{
    uint32_t lo = c * j->per, hi = j->n - lo < j->per ? j->n : lo + j->per;
    for (uint32_t i = lo; i < hi; i++) {
        if (i > atomic_load_explicit(&j->bad, memory_order_relaxed)) return;
        if (decode_brick(&j->ps, j->f, &j->e[i], raw, dz)) mark_bad(j, i);
        else scan_brick(j, thread, &j->e[i], raw);
    }
}

static void decode_chunk(decode_job *j, uint32_t c, struct libdeflate_decompressor *dz)
{
    vod_file *f = j->f;
    uint32_t lo = c * j->per, hi = j->n - lo < j->per ? j->n : lo + j->per;
    f->slab[c] = slab_alloc((size_t)(hi - lo) * f->raw_bytes);
    if (!f->slab[c]) {
        mark_bad(j, lo);
        return;
    }
    for (uint32_t i = lo; i < hi; i++) {
        if (i > atomic_load_explicit(&j->bad, memory_order_relaxed)) return;
        uint8_t *raw = f->slab[c] + (size_t)(i - lo) * f->raw_bytes;
        f->brick[j->e[i].id] = raw;
        if (decode_brick(&j->ps, f, &j->e[i], raw, dz)) mark_bad(j, i);
    }
}

/* A thread's share: chunks claimed until none is left.  A thread without
 * memory for its decompressor claims none (decode_all tells when no
 * thread could). */
static void decode_part(void *arg, unsigned k, unsigned n)
{
    (void)n; /* the parts share one counter of chunks */
    decode_job *j = arg;
    uint32_t chunks = j->f->chunks;
    struct libdeflate_decompressor *dz = libdeflate_alloc_decompressor();
    uint8_t *raw = j->ps.scan && dz ? malloc(j->f->raw_bytes) : NULL; /* a scan's room */
    if (j->ps.scan && !raw) {
        libdeflate_free_decompressor(dz);
        dz = NULL;
    }
    for (unsigned c; dz;) {
        c = atomic_fetch_add_explicit(&j->next, 1, memory_order_relaxed);
        if (c >= chunks) break;
        if ((uint64_t)c * j->per > atomic_load_explicit(&j->bad, memory_order_relaxed))
            break; /* this chunk and the later ones are past a bad record */
        if (raw) scan_chunk(j, c, k, raw, dz);
        else decode_chunk(j, c, dz);
    }
    free(raw);
    libdeflate_free_decompressor(dz);
}

/* Record e, the bad one found at index i (per to a chunk), decoded again
 * alone for its message: into its slab, or for a scan into a room of its
 * own. */
static int decode_again(parse *ps, vod_file *f, const brick_ent *e, uint32_t i, uint32_t per)
{
    uint8_t *room = NULL, *raw;
    if (ps->scan) raw = room = malloc(f->raw_bytes);
    else raw = f->slab[i / per] ? f->slab[i / per] + (size_t)(i % per) * f->raw_bytes : NULL;
    struct libdeflate_decompressor *dz = raw ? libdeflate_alloc_decompressor() : NULL;
    int rc = dz ? decode_brick(ps, f, e, raw, dz)
                : err_set(ps->err, -ENOMEM, "out of memory for brick %u", e->id);
    libdeflate_free_decompressor(dz);
    free(room);
    return rc ? rc : err_set(ps->err, -EIO, "brick %u: decoded differently twice", e->id);
}

/* Every record of e (n, in file order) inflated and hashed by `threads`
 * threads (this one included). */
static int decode_all(parse *ps, vod_file *f, const brick_ent *e, uint32_t n, int threads)
{
    decode_job j = {.ps = *ps, .f = f, .e = e, .n = n};
    j.ps.err = NULL;
    j.per = f->raw_bytes >= SLAB_BYTES ? 1 : (uint32_t)(SLAB_BYTES / f->raw_bytes);
    f->chunks = n / j.per + (n % j.per != 0);
    if (!ps->scan && !(f->slab = calloc((size_t)f->chunks + 1, sizeof *f->slab)))
        return err_set(ps->err, -ENOMEM, "out of memory");
    atomic_init(&j.next, 0);
    atomic_init(&j.bad, n);
    if ((uint32_t)threads > f->chunks) threads = (int)f->chunks;
    par_run(threads < 1 ? 1 : (unsigned)threads, decode_part, &j);
    uint32_t bad = atomic_load_explicit(&j.bad, memory_order_relaxed);
    if (bad == n && atomic_load_explicit(&j.next, memory_order_relaxed) < f->chunks)
        return err_set(ps->err, -ENOMEM, "out of memory"); /* no thread had a decompressor */
    return bad == n ? 0 : decode_again(ps, f, &e[bad], bad, j.per);
}

/* The scan's refs: every node with a brick ID in the table, by ID (a
 * count, its prefix sums, then the nodes in place: cur NULL counts).  IDs
 * outside the table are left to check_subtree, which refuses them. */
static void refs_walk(const vod_file *f, scan_job *s, uint64_t p, int l, const uint32_t b[3],
                      uint64_t *cur)
{
    uint32_t id = f->tree[p];
    if (!id) return;
    if (id <= f->info.bricks && cur) s->refs[cur[id]++] = (node_ref){l, {b[0], b[1], b[2]}};
    else if (id <= f->info.bricks) s->at[id + 1]++;
    for (unsigned i = 0; l > 0 && i < 8; i++) {
        uint32_t cb[3];
        for (int a = 0; a < 3; a++) cb[a] = b[a] << 1 | ((i >> a) & 1u);
        refs_walk(f, s, p + 1 + i * f->sub[l - 1], l - 1, cb, cur);
    }
}

static int make_refs(parse *ps, const vod_file *f)
{
    scan_job *s = ps->scan;
    uint32_t n = f->info.bricks;
    const uint32_t root[3] = {0, 0, 0};
    uint64_t *cur = malloc(((size_t)n + 2) * sizeof *cur);
    s->at = calloc((size_t)n + 2, sizeof *s->at);
    s->kept = calloc((size_t)n + 1, sizeof *s->kept);
    s->ids = n;
    if (!cur || !s->at || !s->kept) {
        free(cur);
        return err_set(ps->err, -ENOMEM, "out of memory");
    }
    refs_walk(f, s, 0, (int)f->info.height - 1, root, NULL);
    for (uint32_t i = 1; i <= n + 1; i++) s->at[i] += s->at[i - 1];
    s->refs = malloc((s->at[n + 1] ? s->at[n + 1] : 1) * sizeof *s->refs);
    memcpy(cur, s->at, ((size_t)n + 2) * sizeof *cur);
    if (s->refs) refs_walk(f, s, 0, (int)f->info.height - 1, root, cur);
    free(cur);
    return s->refs ? 0 : err_set(ps->err, -ENOMEM, "out of memory");
}

/* need[id] set for the bricks that nodes of the levels in mask hold, from
 * the node at p (level l) down (IDs outside the table are left to
 * check_subtree, which refuses them). */
static void need_walk(const vod_file *f, uint32_t mask, uint64_t p, int l, uint8_t *need)
{
    uint32_t id = f->tree[p];
    if (!id) return;
    if ((mask >> l & 1u) && id <= f->info.bricks) need[id] = 1;
    if (!(mask & ((1u << l) - 1))) return; /* no level below is wanted */
    for (unsigned i = 0; i < 8; i++) need_walk(f, mask, p + 1 + i * f->sub[l - 1], l - 1, need);
}

/* The records of e (n, file order) that the levels in ps->levels need, kept
 * in place and in order: how many, or -ENOMEM. */
static int64_t keep_needed(parse *ps, const vod_file *f, brick_ent *e, uint32_t n)
{
    uint8_t *need = calloc((size_t)f->info.bricks + 1, 1);
    if (!need) return err_set(ps->err, -ENOMEM, "out of memory");
    need_walk(f, ps->levels, 0, (int)f->info.height - 1, need);
    uint32_t k = 0;
    for (uint32_t i = 0; i < n; i++)
        if (need[e[i].id]) e[k++] = e[i];
    free(need);
    return k;
}

static int read_bricks(parse *ps, vod_file *f, int threads)
{
    uint32_t n = f->info.bricks;
    brick_ent *e = malloc(((size_t)n + 1) * sizeof *e);
    /* a scan keeps no brick: no table of them, so that the accessors find none */
    f->brick = ps->scan ? NULL : calloc((size_t)n + 1, sizeof *f->brick);
    int rc = e && (ps->scan || f->brick) ? read_table(ps, f, e)
                                         : err_set(ps->err, -ENOMEM, "out of memory");
    for (uint32_t i = 0; i < n && !rc; i++) rc = check_record(ps, &e[i]);
    if (!rc) rc = check_extents(ps, e, n);
    for (uint32_t i = 0; i < n && !rc; i++) f->info.brick_data_bytes += e[i].size;
    if (!rc && n && ps->scan) rc = make_refs(ps, f);
    uint32_t all = (1u << f->info.height) - 1; /* height <= MAX_HEIGHT */
    if (!rc && n && !ps->scan && (ps->levels & all) != all) {
        int64_t k = keep_needed(ps, f, e, n);
        if (k < 0) rc = (int)k;
        else n = (uint32_t)k;
    }
    if (!rc && n) rc = decode_all(ps, f, e, n, threads);
    free(e);
    return rc;
}

/* ---- open and close ---- */

static int parse_all(parse *ps, vod_file *f, int threads)
{
    int rc = read_header(ps, f);
    if (!rc) rc = read_tree(ps, f);
    if (!rc) rc = read_count(ps, f);
    if (!rc) rc = read_bricks(ps, f, threads);
    if (!rc) rc = check_subtree(ps, f, 0, f->info.height - 1);
    return rc;
}

/* The image read and checked, the bricks of the levels in mask `levels`
 * kept, or all handed to scan's fn (scan non-NULL: f->brick stays NULL,
 * so that the accessors find none). */
static int read_image(const void *buf, size_t len, int threads, scan_job *scan,
                      uint32_t levels, vod_file **out, err_info *err)
{
    *out = NULL;
    err_clear(err);
    vod_file *f = calloc(1, sizeof *f);
    parse ps = {.b = buf, .len = len, .end = len, .err = err,
                .threads = threads < 1 ? 1 : threads, .scan = scan, .levels = levels};
    if (!f) return err_set(ps.err, -ENOMEM, "out of memory");
    int rc = parse_all(&ps, f, ps.threads);
    if (rc) {
        vod_close(f);
        return rc;
    }
    f->info.metadata = f->metadata ? f->metadata : "";
    f->info.file_bytes = len;
    f->levels = levels; /* a scan's f->brick is NULL: it has no level */
    *out = f;
    return 0;
}

int vod_read_threads(const void *buf, size_t len, int threads, vod_file **out,
                     err_info *err)
{
    return vod_read_levels(buf, len, threads, VOD_LEVELS_ALL, out, err);
}

int vod_read_levels(const void *buf, size_t len, int threads, uint32_t levels, vod_file **out,
                    err_info *err)
{
    return read_image(buf, len, threads, NULL, levels, out, err);
}

int vod_read(const void *buf, size_t len, vod_file **out, err_info *err)
{
    return vod_read_threads(buf, len, 1, out, err);
}

static int read_all(int fd, uint8_t *p, size_t n)
{
    while (n) {
        ssize_t k = read(fd, p, n);
        if (k < 0 && errno == EINTR) continue;
        if (k <= 0) return k < 0 ? -errno : -EIO;
        p += k;
        n -= (size_t)k;
    }
    return 0;
}

/* The file's pages mapped and filled (NULL: read it instead, as for an
 * empty file or where the mapping fails).  A copy by read() costs a page
 * fault a page of fresh memory (5 MB: 0.03-0.09 s of one thread on the
 * 2-core machine, that nothing beside it could use); the page cache's own
 * pages mapped, about 0.005 s.  The bricks are copied out by the parse,
 * so the mapping ends with vod_open.  Like mesh_load's mapping, a file cut
 * short by another process while it is parsed ends the command (SIGBUS):
 * only the command-line tools open VOD files by path. */
static uint8_t *map_file(int fd, size_t len)
{
    if (len == 0) return NULL;
#ifdef MADV_POPULATE_READ
    void *p = mmap(NULL, len, PROT_READ, MAP_PRIVATE, fd, 0);
    if (p != MAP_FAILED && madvise(p, len, MADV_POPULATE_READ)) { /* a short file, EIO */
        munmap(p, len);
        return NULL;
    }
#else
    void *p = mmap(NULL, len, PROT_READ, MAP_PRIVATE | MAP_POPULATE, fd, 0);
#endif
    return p == MAP_FAILED ? NULL : p;
}

/* The file at path mapped (or read) and read_image'd. */
static int open_image(const char *path, int threads, scan_job *scan, uint32_t levels,
                      vod_file **out, err_info *err)
{
    *out = NULL;
    parse ps = {.err = err};
    int fd = open(path, O_RDONLY | O_CLOEXEC);
    if (fd < 0) return err_set(ps.err, -errno, "cannot open: %s", strerror(errno));
    struct stat sb;
    int rc = fstat(fd, &sb) ? err_set(ps.err, -errno, "cannot stat: %s", strerror(errno)) : 0;
    if (!rc && !S_ISREG(sb.st_mode)) rc = err_set(ps.err, -EINVAL, "not a regular file");
    else if (!rc && (uint64_t)sb.st_size > UINT32_MAX + 65536ull)
        rc = err_set(ps.err, -EFBIG, "%lld bytes: larger than any VOD file",
                  (long long)sb.st_size);
    uint8_t *map = rc ? NULL : map_file(fd, (size_t)sb.st_size);
    uint8_t *buf = rc || map ? NULL : malloc((size_t)sb.st_size + 1);
    if (!rc && !map && !buf) rc = err_set(ps.err, -ENOMEM, "out of memory");
    if (!rc && !map && (rc = read_all(fd, buf, (size_t)sb.st_size)))
        err_set(ps.err, rc, "cannot read: %s", strerror(-rc));
    close(fd);
    if (!rc) rc = read_image(map ? map : buf, (size_t)sb.st_size, threads, scan, levels, out, err);
    if (map) munmap(map, (size_t)sb.st_size);
    free(buf);
    return rc;
}

int vod_open_threads(const char *path, int threads, vod_file **out, err_info *err)
{
    return vod_open_levels(path, threads, VOD_LEVELS_ALL, out, err);
}

int vod_open_levels(const char *path, int threads, uint32_t levels, vod_file **out,
                    err_info *err)
{
    return open_image(path, threads, NULL, levels, out, err);
}

/* The kept bricks' nodes, all in a row (the kept IDs' ref ranges in ID
 * order), dealt to the threads in equal parts. */
typedef struct {
    const scan_job *s;
    const vod_info *in;
    uint64_t total; /* the kept IDs' nodes */
} kept_deal;

static void kept_part(void *ud, unsigned k, unsigned parts)
{
    const kept_deal *d = ud;
    const scan_job *s = d->s;
    uint64_t lo = d->total * k / parts, hi = d->total * (k + 1) / parts, seen = 0;
    for (uint32_t id = 1; id <= s->ids && seen < hi; id++) {
        if (!s->kept[id]) continue;
        uint64_t r0 = s->at[id], r1 = s->at[id + 1], cnt = r1 - r0;
        for (uint64_t r = r0 + (lo > seen ? lo - seen : 0); r < r1 && seen + (r - r0) < hi; r++)
            s->fn(s->ud, k, d->in, s->refs[r].level, s->refs[r].b, s->kept[id]);
        seen += cnt;
    }
}

static void scan_kept(const scan_job *s, const vod_info *in, int threads)
{
    kept_deal d = {s, in, 0};
    for (uint32_t id = 1; id <= s->ids; id++)
        if (s->kept[id]) d.total += s->at[id + 1] - s->at[id];
    if (d.total) par_run((unsigned)threads, kept_part, &d);
}

int vod_scan(const char *path, const vod_scan_opts *o, vod_file **out, err_info *err)
{
    scan_job s = {.fn = o->fn, .ud = o->ud, .keep_bytes = o->keep_bytes};
    int threads = o->threads < 1 ? 1 : o->threads;
    atomic_init(&s.kept_bytes, 0);
    int rc = open_image(path, threads, &s, VOD_LEVELS_ALL, out, err);
    if (!rc && s.kept) scan_kept(&s, vod_get_info(*out), threads);
    for (uint32_t id = 1; s.kept && id <= s.ids; id++) free(s.kept[id]);
    free(s.kept);
    free(s.refs);
    free(s.at);
    return rc;
}

int vod_open(const char *path, vod_file **out, err_info *err)
{
    return vod_open_threads(path, 1, out, err);
}

void vod_close(vod_file *f)
{
    if (!f) return;
    if (f->slab)
        for (uint32_t c = 0; c < f->chunks; c++) free(f->slab[c]);
    free(f->slab);
    free(f->brick);
    free(f->tree);
    free(f->metadata);
    free(f);
}

const vod_info *vod_get_info(const vod_file *f) { return &f->info; }

/* ---- voxel access ---- */

/* Whether the bricks of level (0 .. height - 1) are here: not for a scan
 * (no brick kept), nor for a level vod_open_levels was not asked for. */
static bool has_level(const vod_file *f, int level)
{
    return f->brick && (f->levels >> level & 1u);
}

uint32_t vod_level_size(const vod_file *f, int level)
{
    if (level < 0 || (uint32_t)level >= f->info.height) return 0;
    return f->padded >> level;
}

static int level_dims(const vod_info *in, int level, uint32_t dims[3])
{
    if (level < 0 || (uint32_t)level >= in->height) return -EINVAL;
    for (int a = 0; a < 3; a++)
        dims[a] = (uint32_t)(((uint64_t)in->volume[a] + (1ull << level) - 1) >> level);
    return 0;
}

int vod_level_dims(const vod_file *f, int level, uint32_t dims[3])
{
    return level_dims(&f->info, level, dims);
}

/* Child c of the node at preorder index p (level l) is at
 * p + 1 + c * sub[l-1]; the child's bit of a level-`level` coordinate is
 * bit k + l - level - 1 (a level-l node spans 2^(k + l - level) of them). */
uint32_t vod_voxel(const vod_file *f, int level, uint32_t x, uint32_t y, uint32_t z)
{
    uint32_t side = vod_level_size(f, level);
    if (x >= side || y >= side || z >= side || !has_level(f, level)) return 0;
    uint64_t p = 0;
    for (int l = (int)f->info.height - 1; l > level; l--) {
        if (!f->tree[p]) return 0;
        int s = (int)f->k + l - level - 1;
        unsigned c = (x >> s & 1u) | (y >> s & 1u) << 1 | (z >> s & 1u) << 2;
        p += 1 + c * f->sub[l - 1];
    }
    uint32_t id = f->tree[p], m = f->info.brick - 1;
    if (!id) return 0;
    size_t i = ((size_t)(z & m) * f->info.brick + (y & m)) * f->info.brick + (x & m);
    return vod_raw_voxel(f->brick[id], f->info.voxel_bits, i);
}

const uint8_t *vod_brick(const vod_file *f, int level, const uint32_t b[3])
{
    if (level < 0 || (uint32_t)level >= f->info.height || !has_level(f, level)) return NULL;
    uint32_t side = 1u << (f->info.height - 1 - (uint32_t)level);
    if (b[0] >= side || b[1] >= side || b[2] >= side) return NULL;
    uint64_t p = 0;
    for (int l = (int)f->info.height - 1; l > level; l--) {
        if (!f->tree[p]) return NULL;
        int s = l - level - 1; /* the child's bit of a level-`level` brick coordinate */
        unsigned c = (b[0] >> s & 1u) | (b[1] >> s & 1u) << 1 | (b[2] >> s & 1u) << 2;
        p += 1 + c * f->sub[l - 1];
    }
    return f->tree[p] ? f->brick[f->tree[p]] : NULL;
}

typedef struct {
    const vod_file *f;
    int level;
    uint32_t dims[3];
    int (*fn)(void *, uint32_t, uint32_t, uint32_t, uint32_t);
    void *ud;
} walk_ctx;

/* The non-zero voxels of brick raw at brick coordinates b of a level of
 * dims voxels, to fn. */
static int visit_raw(const vod_info *in, const uint32_t dims[3], const uint32_t b[3],
                     const uint8_t *raw,
                     int (*fn)(void *, uint32_t, uint32_t, uint32_t, uint32_t), void *ud)
{
    uint32_t B = in->brick, o[3], lim[3];
    for (int a = 0; a < 3; a++) {
        o[a] = b[a] * B;
        if (o[a] >= dims[a]) return 0;
        lim[a] = dims[a] - o[a] < B ? dims[a] - o[a] : B;
    }
    for (uint32_t z = 0; z < lim[2]; z++)
        for (uint32_t y = 0; y < lim[1]; y++) {
            size_t row = ((size_t)z * B + y) * B;
            for (uint32_t x = 0; x < lim[0]; x++) {
                uint32_t v = vod_raw_voxel(raw, in->voxel_bits, row + x);
                int rc = v ? fn(ud, o[0] + x, o[1] + y, o[2] + z, v) : 0;
                if (rc) return rc;
            }
        }
    return 0;
}

static int visit_brick(const walk_ctx *w, const uint8_t *raw, const uint32_t b[3])
{
    return visit_raw(&w->f->info, w->dims, b, raw, w->fn, w->ud);
}

int vod_brick_foreach(const vod_info *in, int level, const uint32_t b[3], const uint8_t *raw,
                      int (*fn)(void *ud, uint32_t x, uint32_t y, uint32_t z, uint32_t v),
                      void *ud)
{
    uint32_t dims[3];
    if (level_dims(in, level, dims)) return -EINVAL;
    return visit_raw(in, dims, b, raw, fn, ud);
}

static int walk(const walk_ctx *w, uint64_t p, int l, const uint32_t b[3])
{
    uint32_t id = w->f->tree[p];
    if (!id) return 0;
    if (l == w->level) return visit_brick(w, w->f->brick[id], b);
    for (unsigned i = 0; i < 8; i++) {
        uint32_t cb[3];
        for (int a = 0; a < 3; a++) cb[a] = b[a] << 1 | ((i >> a) & 1u);
        int rc = walk(w, p + 1 + i * w->f->sub[l - 1], l - 1, cb);
        if (rc) return rc;
    }
    return 0;
}

int vod_foreach(const vod_file *f, int level,
                int (*fn)(void *ud, uint32_t x, uint32_t y, uint32_t z, uint32_t v),
                void *ud)
{
    walk_ctx w = {f, level, {0, 0, 0}, fn, ud};
    if (vod_level_dims(f, level, w.dims) || !has_level(f, level)) return -EINVAL;
    uint32_t b[3] = {0, 0, 0};
    return walk(&w, 0, (int)f->info.height - 1, b);
}

typedef struct {
    const vod_file *f;
    int level;
    int (*fn)(void *, const uint32_t *, const uint8_t *);
    void *ud;
} brick_walk;

static int walk_bricks(const brick_walk *w, uint64_t p, int l, const uint32_t b[3])
{
    uint32_t id = w->f->tree[p];
    if (!id) return 0;
    if (l == w->level) return w->fn(w->ud, b, w->f->brick[id]);
    for (unsigned i = 0; i < 8; i++) {
        uint32_t cb[3];
        for (int a = 0; a < 3; a++) cb[a] = b[a] << 1 | ((i >> a) & 1u);
        int rc = walk_bricks(w, p + 1 + i * w->f->sub[l - 1], l - 1, cb);
        if (rc) return rc;
    }
    return 0;
}

int vod_foreach_brick(const vod_file *f, int level,
                      int (*fn)(void *ud, const uint32_t b[3], const uint8_t *raw),
                      void *ud)
{
    if (level < 0 || (uint32_t)level >= f->info.height || !has_level(f, level)) return -EINVAL;
    brick_walk w = {f, level, fn, ud};
    uint32_t b[3] = {0, 0, 0};
    return walk_bricks(&w, 0, (int)f->info.height - 1, b);
}
