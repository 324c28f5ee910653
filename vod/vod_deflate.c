/* vod_deflate — a zlib stream (RFC 1950, 1951) for a brick in one pass,
 * made for the bricks the writer sees: surface bricks of 32-bit voxels (a
 * few hundred non-zero voxels among thousands of zeros), and the small
 * bricks of 1-bit occupancy (512 bytes at 16^3) and of 8-bit densities,
 * for which a general deflate's set-up per call (its tables cleared, its
 * codes built over every symbol) costs more than the bytes.
 *
 * A general deflate (zlib, libdeflate) looks for matches at every byte,
 * zeros included, and spends most of its time in runs of zeros that any
 * encoder turns into the same few tokens.  This one works a unit at a
 * time: a voxel (4 bytes) for 32-bit voxels, a byte for the others.  A
 * bit mask of the non-zero units (SSE2, 64 units a mask word) gives each
 * run of zero units at once, sent as matches at distance 1 (after one
 * literal 0 when the byte before is not 0); a non-zero unit looks for a
 * match of whole units, at least 4 bytes, among the positions of the
 * same 4 bytes (a hash table; for bytes a chain of 4, with one step of
 * lazy matching and the bytes of its matches entered, as zlib's middle
 * levels do) and the bytes a row and a slice back (for bytes also two
 * rows, and a slice and a row), and is otherwise its literals.  One
 * block, with Huffman codes made for the brick (RFC 1951 3.2.7; code
 * lengths limited as miniz does) or the fixed codes (3.2.6) when those
 * make it smaller (a small brick: the dynamic codes' header is then most
 * of the stream); the Adler-32 by libdeflate.  Any inflater reads the
 * result; test_vod checks it against zlib's on bricks of every kind and
 * fuzz_deflate by round trip.
 *
 * On the surface bricks of the standard shapes at 512^3 it is 3 to 4.4
 * times as fast as libdeflate at level 6, for bricks 1 to 5% larger than
 * zlib's at level 6; on the dragon's occupancy bricks 2 to 2.5 times, 3%
 * larger (voxbench deflate; docs/design.md). */
#include "vod.h"

#include <errno.h>
#include <stdbool.h>
#include <stdlib.h>
#include <string.h>
#ifdef __SSE2__
#include <emmintrin.h>
#endif

#include <libdeflate.h>

#define MAX_BITS 15
#define LITLEN_SYMS 288
#define DIST_SYMS 30
#define CL_SYMS 19
#define HASH_BITS 12 /* at most: fewer for small bricks (hash_bits) */
#define WINDOW 32768u
#define MIN_MATCH 4 /* a voxel: shorter matches rarely beat their literals */
#define MAX_MATCH 258
#define NICE_MATCH 128 /* a match this long ends the search */
#define LAZY_MATCH 32  /* byte units: a shorter match waits a byte for a longer */

static const uint16_t len_base[29] = {3,  4,  5,  6,  7,  8,  9,  10,  11,  13,
                                      15, 17, 19, 23, 27, 31, 35, 43,  51,  59,
                                      67, 83, 99, 115, 131, 163, 195, 227, 258};
static const uint8_t len_extra[29] = {0, 0, 0, 0, 0, 0, 0, 0, 1, 1, 1, 1, 2, 2, 2,
                                      2, 3, 3, 3, 3, 4, 4, 4, 4, 5, 5, 5, 5, 0};
static const uint16_t dist_base[DIST_SYMS] = {
    1,   2,   3,   4,   5,   7,    9,    13,   17,   25,   33,   49,   65,    97,    129,
    193, 257, 385, 513, 769, 1025, 1537, 2049, 3073, 4097, 6145, 8193, 12289, 16385, 24577};
static const uint8_t dist_extra[DIST_SYMS] = {0, 0, 0, 0, 1, 1, 2, 2,  3,  3,  4,  4,  5,  5,  6,
                                              6, 7, 7, 8, 8, 9, 9, 10, 10, 11, 11, 12, 12, 13, 13};
/* The order the code-length code's lengths are sent in. */
static const uint8_t cl_order[CL_SYMS] = {16, 17, 18, 0, 8,  7, 9,  6, 10, 5,
                                          11, 4,  12, 3, 13, 2, 14, 1, 15};

/* A token: a literal byte (< 256), or MATCH | length << 15 | (distance - 1). */
#define MATCH (1u << 31)

struct vod_sparse {
    size_t cap;             /* the brick's raw bytes */
    uint64_t *mask;         /* bit i: unit i is not 0 */
    size_t row, slice;      /* bytes from a voxel to the one a row, a slice
                               back (0: less than a byte) */
    size_t dist[4];         /* the distances tried besides the hash's */
    unsigned ndist;
    unsigned unit;          /* bytes a token starts at a multiple of: 4
                               for 32-bit voxels, 1 for the others */
    unsigned hash_bits;     /* of head: about half the brick's bytes */
    uint32_t *tok;          /* cap + 1 tokens */
    uint32_t head[1u << HASH_BITS]; /* 4 bytes' hash -> last position + 1 + base */
    uint32_t *prev;         /* position -> the one before of its hash, the same
                               way (chains longer than 1 only) */
    uint32_t base;          /* entries not above it are from earlier bricks */
    unsigned chain;         /* positions of a hash tried */
    uint8_t len_sym[MAX_MATCH + 1]; /* length -> 0..28 */
    uint8_t dist_sym[WINDOW];       /* distance - 1 -> 0..29 */
    uint32_t freq_l[LITLEN_SYMS], freq_d[DIST_SYMS];
    uint8_t bits_l[LITLEN_SYMS], bits_d[DIST_SYMS];
    uint16_t code_l[LITLEN_SYMS], code_d[DIST_SYMS];
    uint16_t used_l[LITLEN_SYMS], used_d[DIST_SYMS]; /* symbols with a code */
    int nused_l, nused_d;
    /* the fixed codes (RFC 1951 3.2.6) */
    uint8_t fbits_l[LITLEN_SYMS], fbits_d[DIST_SYMS];
    uint16_t fcode_l[LITLEN_SYMS], fcode_d[DIST_SYMS];
};

/* The len low bits of code in reverse order (deflate sends Huffman codes
 * from their first bit, everything else from the last). */
static inline uint16_t reverse(uint32_t code, unsigned len)
{
    uint32_t x = code;
    x = (x & 0x5555u) << 1 | (x >> 1 & 0x5555u);
    x = (x & 0x3333u) << 2 | (x >> 2 & 0x3333u);
    x = (x & 0x0f0fu) << 4 | (x >> 4 & 0x0f0fu);
    x = (x & 0x00ffu) << 8 | (x >> 8 & 0x00ffu);
    return (uint16_t)(x >> (16 - len));
}

static void fixed_codes(vod_sparse *z)
{
    for (int s = 0; s < LITLEN_SYMS; s++) {
        unsigned len = s < 144 ? 8 : s < 256 ? 9 : s < 280 ? 7 : 8;
        uint32_t first = s < 144 ? 0x30 : s < 256 ? 0x190 : s < 280 ? 0 : 0xc0;
        int base = s < 144 ? 0 : s < 256 ? 144 : s < 280 ? 256 : 280;
        z->fbits_l[s] = (uint8_t)len;
        z->fcode_l[s] = reverse(first + (uint32_t)(s - base), len);
    }
    for (int s = 0; s < DIST_SYMS; s++) {
        z->fbits_d[s] = 5;
        z->fcode_d[s] = reverse((uint32_t)s, 5);
    }
}

/* The fixed codes, and the symbols of every match length and distance. */
static void symbol_tables(vod_sparse *z)
{
    fixed_codes(z);
    for (int s = 0; s < 29; s++) {
        int end = s == 28 ? MAX_MATCH + 1 : len_base[s] + (1 << len_extra[s]);
        for (int l = len_base[s]; l < end && l <= MAX_MATCH; l++) z->len_sym[l] = (uint8_t)s;
    }
    z->len_sym[MAX_MATCH] = 28;
    for (int s = 0; s < DIST_SYMS; s++)
        for (unsigned d = dist_base[s]; d < dist_base[s] + (1u << dist_extra[s]); d++)
            z->dist_sym[d - 1] = (uint8_t)s;
}

int vod_sparse_new(uint32_t brick, uint32_t voxel_bits, vod_sparse **out)
{
    *out = NULL;
    if (brick < 2 || brick > VOD_SPARSE_MAX_BRICK) return -EINVAL;
    if (voxel_bits != 1 && voxel_bits != 8 && voxel_bits != 32) return -EINVAL;
    size_t row_bits = (size_t)brick * voxel_bits;
    unsigned unit = voxel_bits == 32 ? 4 : 1;
    vod_sparse *z = calloc(1, sizeof *z);
    if (!z) return -ENOMEM;
    z->unit = unit;
    z->row = row_bits / 8;
    z->slice = row_bits * brick / 8;
    z->cap = row_bits * brick * brick / 8;
    /* a row and a slice back; for bricks of bytes or bits, whose rows
     * are short, two rows back and a slice and a row back too */
    size_t tried[4] = {z->row, z->slice, 2 * z->row, z->slice + z->row};
    for (unsigned i = 0; i < (unit == 4 ? 2u : 4u); i++)
        if (tried[i] && tried[i] <= WINDOW) z->dist[z->ndist++] = tried[i];
    z->hash_bits = 6;
    while (z->hash_bits < HASH_BITS && (1u << z->hash_bits) < z->cap / 2) z->hash_bits++;
    z->chain = unit == 1 ? 4 : 1;
    z->tok = malloc((z->cap + 1) * sizeof *z->tok);
    z->mask = malloc((z->cap / z->unit + 63) / 64 * sizeof *z->mask);
    if (z->chain > 1) z->prev = malloc(z->cap * sizeof *z->prev);
    if (!z->tok || !z->mask || (z->chain > 1 && !z->prev)) {
        vod_sparse_free(z);
        return -ENOMEM;
    }
    symbol_tables(z);
    *out = z;
    return 0;
}

void vod_sparse_free(vod_sparse *z)
{
    if (!z) return;
    free(z->tok);
    free(z->mask);
    free(z->prev);
    free(z);
}

/* ---- Huffman codes ---- */

/* Moffat and Katajainen's in-place minimum-redundancy code: a[0..n-1]
 * holds weights in ascending order, and on return code lengths. */
static void min_redundancy(uint32_t *a, int n)
{
    if (n == 1) {
        a[0] = 1;
        return;
    }
    int root = 0, leaf = 2, next;
    a[0] += a[1];
    for (next = 1; next < n - 1; next++) {
        if (leaf >= n || a[root] < a[leaf]) {
            a[next] = a[root];
            a[root++] = (uint32_t)next;
        } else {
            a[next] = a[leaf++];
        }
        if (leaf >= n || (root < next && a[root] < a[leaf])) {
            a[next] += a[root];
            a[root++] = (uint32_t)next;
        } else {
            a[next] += a[leaf++];
        }
    }
    a[n - 2] = 0;
    for (next = n - 3; next >= 0; next--) a[next] = a[a[next]] + 1;
    int avail = 1, used = 0, depth = 0;
    root = n - 2;
    next = n - 1;
    while (avail > 0) {
        while (root >= 0 && (int)a[root] == depth) {
            used++;
            root--;
        }
        while (avail > used) {
            a[next--] = (uint32_t)depth;
            avail--;
        }
        avail = 2 * used;
        depth++;
        used = 0;
    }
}

/* Insertion sort of sym/w by w, stable. */
static void insertion_sort(uint32_t *sym, uint32_t *w, int n)
{
    for (int i = 1; i < n; i++) {
        uint32_t ks = sym[i], kw = w[i];
        int j = i;
        for (; j > 0 && w[j - 1] > kw; j--) sym[j] = sym[j - 1], w[j] = w[j - 1];
        sym[j] = ks, w[j] = kw;
    }
}

/* The used symbols of freq[0..n-1] in symbol order into used; how many. */
static int used_symbols(const uint32_t *freq, int n, uint16_t *used)
{
    int k = 0;
    for (int s = 0; s < n; s++) { /* without a branch: used symbols are random */
        used[k] = (uint16_t)s;
        k += freq[s] != 0;
    }
    return k;
}

/* At least two symbols get a code, as zlib makes sure: a lone symbol would
 * make an incomplete code, which inflaters refuse.  The first unused
 * symbols get frequency 1, used kept in symbol order; the new count. */
static int two_symbols(uint32_t *freq, int n, uint16_t *used, int k)
{
    for (int s = 0; s < n && k < 2; s++) {
        if (freq[s]) continue;
        freq[s] = 1;
        int i = k++;
        for (; i > 0 && used[i - 1] > s; i--) used[i] = used[i - 1];
        used[i] = (uint16_t)s;
    }
    return k;
}

/* The k used symbols in ascending order of frequency, ties in symbol
 * order, into sym and w: a counting sort of the frequencies below 255, the
 * few above it (a brick's zeros, its 0xff bytes) sorted after them. */
static void sort_symbols(const uint32_t *freq, const uint16_t *used, int k,
                         uint32_t *sym, uint32_t *w)
{
    for (int i = 0; i < k; i++) sym[i] = used[i], w[i] = freq[used[i]];
    if (k <= 32) {
        insertion_sort(sym, w, k);
        return;
    }
    unsigned count[257] = {0};
    for (int i = 0; i < k; i++) count[(w[i] < 255 ? w[i] : 255) + 1]++;
    for (int d = 0; d < 256; d++) count[d + 1] += count[d];
    for (int i = 0; i < k; i++) {
        uint32_t f = freq[used[i]];
        unsigned d = f < 255 ? f : 255;
        sym[count[d]] = used[i];
        w[count[d]++] = f;
    }
    int big = (int)count[254]; /* where the frequencies >= 255 start */
    insertion_sort(sym + big, w + big, k - big);
}

/* An alphabet of n symbols to code: their frequencies freq[0..n-1] and
 * the k used ones (used: in symbol order, at least two). */
typedef struct {
    const uint32_t *freq;
    int n;
    const uint16_t *used;
    int k;
} alphabet;

/* Code lengths (at most max_bits) and bit-reversed canonical codes for
 * the used symbols of a; the other symbols get length 0. */
static void build_code(const alphabet *a, unsigned max_bits, uint8_t *bits,
                       uint16_t *code)
{
    const uint16_t *used = a->used;
    int k = a->k;
    uint32_t sym[LITLEN_SYMS], w[LITLEN_SYMS];
    sort_symbols(a->freq, used, k, sym, w);
    min_redundancy(w, k);
    /* miniz's limit: fold longer codes into max_bits, then lengthen the
     * shortest codes below it until the Kraft sum is exact again */
    unsigned count[33] = {0};
    for (int i = 0; i < k; i++) count[w[i] < 32 ? w[i] : 32]++;
    for (unsigned l = max_bits + 1; l <= 32; l++) count[max_bits] += count[l], count[l] = 0;
    uint32_t total = 0;
    for (unsigned l = 1; l <= max_bits; l++) total += count[l] << (max_bits - l);
    while (total != 1u << max_bits) {
        count[max_bits]--;
        for (unsigned l = max_bits - 1; l > 0; l--)
            if (count[l]) {
                count[l]--;
                count[l + 1] += 2;
                break;
            }
        total--;
    }
    memset(bits, 0, (size_t)a->n);
    int j = k; /* the most frequent symbols get the shortest codes */
    for (unsigned l = 1; l <= max_bits; l++)
        for (unsigned c = count[l]; c > 0; c--) bits[sym[--j]] = (uint8_t)l;
    /* canonical codes (RFC 1951 3.2.2), count[] being bl_count */
    uint32_t next[MAX_BITS + 2] = {0}, c = 0;
    count[0] = 0;
    for (unsigned l = 1; l <= max_bits; l++) {
        c = (c + count[l - 1]) << 1;
        next[l] = c;
    }
    for (int i = 0; i < k; i++) {
        unsigned l = bits[used[i]];
        code[used[i]] = reverse(next[l]++, l);
    }
}

/* build_code for all of freq[0..n-1]. */
static void build_code_all(uint32_t *freq, int n, unsigned max_bits, uint8_t *bits,
                           uint16_t *code)
{
    uint16_t used[LITLEN_SYMS];
    int k = two_symbols(freq, n, used, used_symbols(freq, n, used));
    build_code(&(alphabet){freq, n, used, k}, max_bits, bits, code);
}

/* ---- bits out ---- */

/* The stream's size is known before a bit is written (choose_codes), so
 * the writer needs no bound: it stores four whole bytes at a time. */
typedef struct {
    uint8_t *p;
    uint64_t acc;
    unsigned n;
} bitw;

static inline void put(bitw *w, uint32_t v, unsigned len)
{
    w->acc |= (uint64_t)v << w->n;
    w->n += len;
    if (w->n >= 32) {
        vod_put32(w->p, (uint32_t)w->acc);
        w->p += 4;
        w->acc >>= 32;
        w->n -= 32;
    }
}

static void put_flush(bitw *w)
{
    for (; w->n > 0; w->n = w->n > 8 ? w->n - 8 : 0) {
        *w->p++ = (uint8_t)w->acc;
        w->acc >>= 8;
    }
}

/* ---- tokens ---- */

typedef struct {
    vod_sparse *z;
    size_t nt;
} tokens;

static inline void lit(tokens *t, uint8_t c)
{
    t->z->tok[t->nt++] = c;
    t->z->freq_l[c]++;
}

static inline void match(tokens *t, unsigned len, unsigned dist)
{
    t->z->tok[t->nt++] = MATCH | len << 15 | (dist - 1);
    t->z->freq_l[257 + t->z->len_sym[len]]++;
    t->z->freq_d[t->z->dist_sym[dist - 1]]++;
}

/* k zeros after a zero byte: matches at distance 1 (the last one at
 * least 3 long), 1 or 2 left over as literals. */
static void zero_run(tokens *t, size_t k)
{
    while (k >= 3) {
        size_t m = k < MAX_MATCH ? k : MAX_MATCH;
        if (k - m > 0 && k - m < 3) m = k - 3;
        match(t, (unsigned)m, 1);
        k -= m;
    }
    while (k--) {
        t->z->tok[t->nt++] = 0;
        t->z->freq_l[0]++;
    }
}

static inline uint64_t load64(const uint8_t *p)
{
    uint64_t v;
    memcpy(&v, p, sizeof v);
    return v;
}

static inline uint32_t load32(const uint8_t *p)
{
    uint32_t v;
    memcpy(&v, p, sizeof v);
    return v;
}

/* Bit i of mask: unit i of raw (nu units of u bytes, u 1 or 4) is not 0. */
static void nonzero_mask(const uint8_t *raw, size_t nu, unsigned u, uint64_t *mask)
{
    size_t i = 0;
    memset(mask, 0, (nu + 63) / 64 * sizeof *mask);
#ifdef __SSE2__
    const __m128i zero = _mm_setzero_si128();
    for (; nu - i >= 64; i += 64) {
        uint64_t zeros = 0;
        for (unsigned k = 0; k < 64; k += 16) {
            const __m128i *v = (const __m128i *)(raw + u * (i + k));
            __m128i e;
            if (u == 4) {
                __m128i e0 = _mm_cmpeq_epi32(_mm_loadu_si128(v), zero);
                __m128i e1 = _mm_cmpeq_epi32(_mm_loadu_si128(v + 1), zero);
                __m128i e2 = _mm_cmpeq_epi32(_mm_loadu_si128(v + 2), zero);
                __m128i e3 = _mm_cmpeq_epi32(_mm_loadu_si128(v + 3), zero);
                e = _mm_packs_epi16(_mm_packs_epi32(e0, e1), _mm_packs_epi32(e2, e3));
            } else {
                e = _mm_cmpeq_epi8(_mm_loadu_si128(v), zero);
            }
            zeros |= (uint64_t)(unsigned)_mm_movemask_epi8(e) << k;
        }
        mask[i / 64] = ~zeros;
    }
#endif
    for (; i < nu; i++) {
        const uint8_t *q = raw + u * i;
        unsigned any = q[0];
        for (unsigned b = 1; b < u; b++) any |= q[b];
        if (any) mask[i / 64] |= 1ull << (i % 64);
    }
}

/* The first unit from i on that is not 0, or nu. */
static size_t next_nonzero(const uint64_t *mask, size_t i, size_t nu)
{
    size_t w = i / 64;
    uint64_t m = mask[w] >> (i % 64);
    if (m) return i + (size_t)__builtin_ctzll(m);
    for (w++; w * 64 < nu; w++)
        if (mask[w]) return w * 64 + (size_t)__builtin_ctzll(mask[w]);
    return nu;
}

/* Bytes equal at q and p, p > q, at most max. */
static size_t match_len(const uint8_t *raw, size_t q, size_t p, size_t max)
{
    size_t l = 0;
    while (max - l >= 8) {
        uint64_t x = load64(raw + q + l) ^ load64(raw + p + l);
        if (x) return l + (size_t)(__builtin_ctzll(x) >> 3);
        l += 8;
    }
    while (l < max && raw[q + l] == raw[p + l]) l++;
    return l;
}

static inline uint32_t hash_word(uint32_t v, unsigned bits)
{
    return (v * 2654435761u) >> (32 - bits);
}

/* The position a head or prev entry holds, or p (none) when it is from an
 * earlier brick: entries are position + 1 + base, and base moves past the
 * last brick's entries for each brick, so the table is never cleared. */
static inline size_t entry_pos(const vod_sparse *z, uint32_t e, size_t p)
{
    return e > z->base ? e - z->base - 1 : p;
}

/* The longest match at p (p + 4 <= n) among the candidates. */
static size_t best_match(const vod_sparse *z, const uint8_t *raw, size_t p, size_t n,
                         uint32_t h, size_t *dist)
{
    size_t max = n - p < MAX_MATCH ? n - p : MAX_MATCH, best = 0;
    uint32_t v = load32(raw + p);
    /* the hash's chain, newest first, then the fixed distances */
    size_t q = entry_pos(z, z->head[h], p);
    for (unsigned c = 1; q < p && p - q <= WINDOW; c++) {
        if (load32(raw + q) == v) { /* shorter than 4 bytes is not taken */
            size_t l = match_len(raw, q, p, max);
            if (l > best) best = l, *dist = p - q;
            if (best >= NICE_MATCH) return best;
        }
        if (c == z->chain) break;
        q = entry_pos(z, z->prev[q], p);
    }
    for (unsigned i = 0; i < z->ndist; i++) {
        q = p >= z->dist[i] ? p - z->dist[i] : p;
        if (q >= p || p - q > WINDOW || load32(raw + q) != v) continue;
        size_t l = match_len(raw, q, p, max);
        if (l > best) best = l, *dist = p - q;
    }
    return best;
}

static inline uint32_t hash_at(const vod_sparse *z, const uint8_t *raw, size_t p)
{
    return hash_word(load32(raw + p), z->hash_bits);
}

static inline void insert(vod_sparse *z, uint32_t h, size_t p)
{
    if (z->chain > 1) z->prev[p] = z->head[h];
    z->head[h] = (uint32_t)(p + 1 + z->base);
}

/* A new brick: base past every entry of the last one (the table cleared
 * once in 2^32 / cap bricks). */
static void next_base(vod_sparse *z)
{
    if (z->base > UINT32_MAX - 2 * (z->cap + 1)) {
        memset(z->head, 0, sizeof z->head);
        z->base = 0;
        return;
    }
    z->base += (uint32_t)z->cap + 1;
}

/* The tokens from a non-zero unit at p; the units they cover.  Byte
 * units (u == 1) search as zlib does at its middle levels: one step of
 * lazy matching (a literal when the match at p + 1 is longer) and the
 * bytes of a match entered in the hash. */
static inline size_t tokens_at(tokens *t, const uint8_t *raw, size_t p, size_t n,
                               const unsigned u)
{
    vod_sparse *z = t->z;
    if (n - p >= MIN_MATCH) {
        uint32_t h = hash_at(z, raw, p);
        size_t dist = 0, l = best_match(z, raw, p, n, h, &dist) / u * u;
        insert(z, h, p);
        if (u == 1 && l >= MIN_MATCH && l < LAZY_MATCH && n - p > MIN_MATCH) {
            size_t d1;
            if (best_match(z, raw, p + 1, n, hash_at(z, raw, p + 1), &d1) > l) l = 0;
        }
        if (l >= MIN_MATCH) {
            match(t, (unsigned)l, (unsigned)dist);
            if (u == 1)
                for (size_t q = p + 1; q < p + l && n - q >= MIN_MATCH; q++)
                    insert(z, hash_at(z, raw, q), q);
            return l / u;
        }
    }
    for (unsigned b = 0; b < u; b++) lit(t, raw[p + b]);
    return 1;
}

/* Literals and matches for raw (n bytes, whole units of u bytes), their
 * frequencies.  Every token starts at a unit: a match is cut to whole
 * units, and one of at least 4 bytes is looked for where 4 bytes are
 * left.  Inlined for each unit, so that u is a constant. */
static inline void tokenize_units(tokens *t, const uint8_t *raw, size_t n,
                                  const unsigned u)
{
    vod_sparse *z = t->z;
    size_t nu = n / u, i = 0;
    nonzero_mask(raw, nu, u, z->mask);
    next_base(z);
    while (i < nu) {
        size_t p = u * i;
        if (z->mask[i / 64] >> (i % 64) & 1u) {
            i += tokens_at(t, raw, p, n, u);
            continue;
        }
        size_t j = next_nonzero(z->mask, i, nu), k = u * (j - i);
        if (p == 0 || raw[p - 1] != 0) {
            lit(t, 0);
            k--;
        }
        zero_run(t, k);
        i = j;
    }
    z->tok[t->nt++] = 256;
    z->freq_l[256]++;
}

static void tokenize(tokens *t, const uint8_t *raw, size_t n)
{
    if (t->z->unit == 4) tokenize_units(t, raw, n, 4);
    else tokenize_units(t, raw, n, 1);
}

/* ---- the block ---- */

/* The code lengths of both codes, run-length coded (RFC 1951 3.2.7):
 * symbols in sym (with their extra bits above bit 8), frequencies in f. */
static size_t rle_lengths(const uint8_t *len, size_t n, uint32_t *sym, uint32_t *f)
{
    size_t k = 0;
    for (size_t i = 0; i < n;) {
        uint8_t v = len[i];
        size_t r = 1;
        while (i + r < n && len[i + r] == v) r++;
        i += r;
        if (v == 0) {
            while (r >= 11) {
                size_t m = r < 138 ? r : 138;
                sym[k++] = 18 | (uint32_t)(m - 11) << 8, f[18]++, r -= m;
            }
            if (r >= 3) sym[k++] = 17 | (uint32_t)(r - 3) << 8, f[17]++, r = 0;
        } else {
            sym[k++] = v, f[v]++, r--;
            while (r >= 3) {
                size_t m = r < 6 ? r : 6;
                sym[k++] = 16 | (uint32_t)(m - 3) << 8, f[16]++, r -= m;
            }
        }
        while (r--) sym[k++] = v, f[v]++;
    }
    return k;
}

/* The block's header: the sizes of both codes, the code-length code, the
 * run-length coded lengths. */
typedef struct {
    int hlit, hdist, hclen;
    size_t k;
    uint32_t sym[286 + DIST_SYMS];
    uint8_t cb[CL_SYMS];
    uint16_t cc[CL_SYMS];
} header;

static const uint8_t cl_extra[3] = {2, 3, 7};

/* Makes the header; returns its size in bits. */
static uint64_t make_header(const vod_sparse *z, header *h)
{
    h->hlit = 286, h->hdist = DIST_SYMS;
    while (h->hlit > 257 && !z->bits_l[h->hlit - 1]) h->hlit--;
    while (h->hdist > 1 && !z->bits_d[h->hdist - 1]) h->hdist--;
    uint8_t lens[286 + DIST_SYMS];
    memcpy(lens, z->bits_l, (size_t)h->hlit);
    memcpy(lens + h->hlit, z->bits_d, (size_t)h->hdist);
    uint32_t f[CL_SYMS] = {0};
    h->k = rle_lengths(lens, (size_t)(h->hlit + h->hdist), h->sym, f);
    build_code_all(f, CL_SYMS, 7, h->cb, h->cc);
    h->hclen = CL_SYMS;
    while (h->hclen > 4 && !h->cb[cl_order[h->hclen - 1]]) h->hclen--;
    uint64_t bits = 3 + 5 + 5 + 4 + 3 * (uint64_t)h->hclen;
    for (size_t i = 0; i < h->k; i++) {
        uint32_t s = h->sym[i] & 0xffu;
        bits += h->cb[s] + (s >= 16 ? cl_extra[s - 16] : 0);
    }
    return bits;
}

static void put_header(const header *h, bitw *w)
{
    put(w, 1 | 2 << 1, 3); /* BFINAL, dynamic Huffman codes */
    put(w, (uint32_t)(h->hlit - 257), 5);
    put(w, (uint32_t)(h->hdist - 1), 5);
    put(w, (uint32_t)(h->hclen - 4), 4);
    for (int i = 0; i < h->hclen; i++) put(w, h->cb[cl_order[i]], 3);
    for (size_t i = 0; i < h->k; i++) {
        uint32_t s = h->sym[i] & 0xffu;
        put(w, h->cc[s], h->cb[s]);
        if (s >= 16) put(w, h->sym[i] >> 8, cl_extra[s - 16]);
    }
}

/* The tokens' size in bits with the literal/length code lengths bits_l
 * and the distance code lengths bits_d, from the used symbols. */
static uint64_t data_bits(const vod_sparse *z, const uint8_t *bits_l,
                          const uint8_t *bits_d)
{
    uint64_t bits = 0;
    for (int i = 0; i < z->nused_l; i++) {
        unsigned s = z->used_l[i];
        bits += (uint64_t)z->freq_l[s] * (bits_l[s] + (s > 256 ? len_extra[s - 257] : 0u));
    }
    for (int i = 0; i < z->nused_d; i++) {
        unsigned s = z->used_d[i];
        bits += (uint64_t)z->freq_d[s] * (bits_d[s] + dist_extra[s]);
    }
    return bits;
}

/* One code's symbols: lengths and bit-reversed codes. */
typedef struct {
    const uint8_t *bits_l, *bits_d;
    const uint16_t *code_l, *code_d;
} codes;

static void put_tokens(const vod_sparse *z, const tokens *t, const codes *c, bitw *w)
{
    for (size_t i = 0; i < t->nt; i++) {
        uint32_t k = z->tok[i];
        if (!(k & MATCH)) {
            put(w, c->code_l[k], c->bits_l[k]);
            continue;
        }
        unsigned len = (k >> 15) & 0x1ffu, d = (k & 0x7fffu) + 1;
        unsigned ls = z->len_sym[len], ds = z->dist_sym[d - 1];
        put(w, c->code_l[257 + ls], c->bits_l[257 + ls]);
        put(w, len - len_base[ls], len_extra[ls]);
        put(w, c->code_d[ds], c->bits_d[ds]);
        put(w, d - dist_base[ds], dist_extra[ds]);
    }
}

/* The brick's own codes (and its header, in h) or the fixed ones, which
 * ever make the block smaller, into c; *dynamic says which.  The block's
 * size in bits without the zlib header. */
static uint64_t choose_codes(vod_sparse *z, header *h, codes *c, bool *dynamic)
{
    /* the fixed codes' size from the symbols sent, before two_symbols
     * gives unused ones a frequency */
    z->nused_l = used_symbols(z->freq_l, 286, z->used_l);
    z->nused_d = used_symbols(z->freq_d, DIST_SYMS, z->used_d);
    uint64_t fixed = 3 + data_bits(z, z->fbits_l, z->fbits_d);
    z->nused_l = two_symbols(z->freq_l, 286, z->used_l, z->nused_l);
    z->nused_d = two_symbols(z->freq_d, DIST_SYMS, z->used_d, z->nused_d);
    build_code(&(alphabet){z->freq_l, 286, z->used_l, z->nused_l}, MAX_BITS, z->bits_l,
               z->code_l);
    build_code(&(alphabet){z->freq_d, DIST_SYMS, z->used_d, z->nused_d}, MAX_BITS, z->bits_d,
               z->code_d);
    uint64_t bits = make_header(z, h) + data_bits(z, z->bits_l, z->bits_d);
    *dynamic = bits < fixed;
    *c = *dynamic ? (codes){z->bits_l, z->bits_d, z->code_l, z->code_d}
                  : (codes){z->fbits_l, z->fbits_d, z->fcode_l, z->fcode_d};
    return *dynamic ? bits : fixed;
}

size_t vod_sparse_compress(vod_sparse *z, const uint8_t *raw, size_t n, uint8_t *out,
                           size_t cap)
{
    if (n > z->cap || n % z->unit || cap < 6) return 0;
    memset(z->freq_l, 0, sizeof z->freq_l);
    memset(z->freq_d, 0, sizeof z->freq_d);
    tokens t = {.z = z};
    tokenize(&t, raw, n);
    header h;
    codes c;
    bool dynamic;
    uint64_t bits = choose_codes(z, &h, &c, &dynamic);
    if (2 + (bits + 7) / 8 + 4 > cap) return 0;
    out[0] = 0x78; /* deflate, 32 KiB window */
    out[1] = 0x5e; /* "fast" level; (0x78 * 256 + 0x5e) % 31 == 0 */
    bitw w = {.p = out + 2};
    if (dynamic) put_header(&h, &w);
    else put(&w, 1 | 1 << 1, 3); /* BFINAL, fixed Huffman codes */
    put_tokens(z, &t, &c, &w);
    put_flush(&w);
    uint32_t adler = libdeflate_adler32(1, raw, n);
    for (int i = 0; i < 4; i++) w.p[i] = (uint8_t)(adler >> (24 - 8 * i));
    return (size_t)(w.p + 4 - out);
}
