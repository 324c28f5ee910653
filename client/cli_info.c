/* vox info: validate a VOD file completely and describe it. */
#include <stdio.h>
#include <string.h>

#include <zlib.h>

#include "cli.h"
#include "par.h"
#include "vod.h"
#include "voxel.h"

/* Channel 4's narrow band, from the metadata's distance_band (voxels). */
static void print_band(const vod_info *in)
{
    const char *m = in->metadata ? strstr(in->metadata, "distance_band=") : NULL;
    unsigned k = 0;
    if (!m || (m != in->metadata && m[-1] != '\n') || sscanf(m + 14, "%u", &k) != 1 || !k) {
        printf("  band        not recorded (no distance_band in the metadata)\n");
        return;
    }
    printf("  band        %u voxels each side (%g world units); beyond it +-%g\n", k,
           (double)(float)(k * (double)in->voxel_scale[0]),
           (double)(float)(k * (double)in->voxel_scale[0]));
}

static const char *channel_name(uint32_t c)
{
    switch (c) {
    case VOXEL_CH_OCCUPANCY: return "occupancy (1 bit)";
    case VOXEL_CH_DENSITY: return "density (8 bit)";
    case VOXEL_CH_SURFACE: return "surface voxel with octahedral normal (32 bit)";
    case VOXEL_CH_DISTANCE: return "signed distance (f32)";
    default: return "unspecified";
    }
}

static void fourcc(uint32_t v, char out[5])
{
    for (int i = 0; i < 4; i++) {
        char c = (char)(v >> (8 * i));
        out[i] = (c >= 32 && c < 127) ? c : '?';
    }
    out[4] = '\0';
}

static void print_info(const char *path, const vod_info *in)
{
    char h[5], c[5];
    fourcc(in->hash, h);
    fourcc(in->comp, c);
    uint64_t padded = (uint64_t)in->brick << (in->height - 1);
    double raw = (double)padded * padded * padded * in->voxel_bits / 8.0;
    printf("%s: valid VOD version %u%s\n", path, in->version,
           in->has_trailer ? ", CRC-32 checked" : " (no trailer: no CRC)");
    printf("  volume      %u x %u x %u voxels (padded to %llu^3)\n", in->volume[0],
           in->volume[1], in->volume[2], (unsigned long long)padded);
    printf("  voxel       %g x %g x %g, %u bits\n", in->voxel_scale[0],
           in->voxel_scale[1], in->voxel_scale[2], in->voxel_bits);
    printf("  octree      height %u, %llu nodes\n", in->height,
           (unsigned long long)in->nodes);
    printf("  bricks      %u^3, %u unique stored, hash %s, compression %s\n",
           in->brick, in->bricks, h, c);
    printf("  size        %llu bytes; brick data %llu bytes; raw volume %.0f bytes (%.1fx smaller)\n",
           (unsigned long long)in->file_bytes, (unsigned long long)in->brick_data_bytes,
           raw, in->file_bytes ? raw / (double)in->file_bytes : 0.0);
    if (in->has_trailer) {
        printf("  origin      %g, %g, %g\n", in->origin[0], in->origin[1], in->origin[2]);
        printf("  channel     %u: %s\n", in->channel, channel_name(in->channel));
        if (in->channel == VOXEL_CH_DISTANCE) print_band(in);
        printf("  crc32       %08x\n", in->crc32);
        const char *m = in->metadata;
        while (m && *m) {
            size_t n = strcspn(m, "\n");
            printf("  meta        %.*s\n", (int)n, m);
            m += n + (m[n] == '\n');
        }
    }
}

/* What the file holds, whatever its compression or hash: the non-empty
 * voxels of full resolution, and the sum of the CRC-32s of (level, x, y, z,
 * value) over every non-empty voxel of every level (a sum: the order the
 * reader visits them in does not matter, nor which thread adds them).  The
 * file is scanned (vod_scan), not kept: a thread's sums in its own slot. */
typedef struct {
    uint32_t crc;
    uint64_t n;
} voxel_sum;

/* The CRC-32 of a record (level, x, y, z, value), 20 bytes as the array
 * of five uint32_t lies in memory, from tables instead of a crc32() call a
 * voxel (a distance field has a non-zero value in every voxel: hundreds of
 * millions of them).  For messages of one length CRC-32 is affine over
 * GF(2): crc(a ^ b) = crc(a) ^ crc(b) ^ crc(0).  A record is the xor of
 * twenty one-byte records (byte i its own, the rest 0), so its CRC is
 * crc(0) ^ the xor of rec_crc[i][byte i], rec_crc[i][c] = crc(the record of
 * byte i = c alone) ^ crc(0).  A row's level, y and z are xor-ed once
 * (row_crc), then x and the value a voxel. */
#define REC_BYTES 20
static uint32_t rec_crc[REC_BYTES][256], rec_zero;

/* A fresh record for each entry: one record with byte i set and reset
 * after each call was miscompiled by GCC 12.2 at -O1 and above (the reset
 * after the last c dropped as a dead store; -fno-tree-dse keeps it), and
 * every later table went wrong. */
static void rec_crc_init(void)
{
    const uint8_t zero[REC_BYTES] = {0};
    rec_zero = (uint32_t)crc32(0, zero, REC_BYTES);
    for (int i = 0; i < REC_BYTES; i++)
        for (int c = 0; c < 256; c++) {
            uint8_t rec[REC_BYTES] = {0};
            rec[i] = (uint8_t)c;
            rec_crc[i][c] = (uint32_t)crc32(0, rec, REC_BYTES) ^ rec_zero;
        }
}

/* The xor of rec_crc over the bytes of field f (0 level .. 4 value) = w. */
static uint32_t field_crc(int f, uint32_t w)
{
    uint8_t b[4];
    memcpy(b, &w, 4); /* the bytes as the record holds them */
    return rec_crc[4 * f][b[0]] ^ rec_crc[4 * f + 1][b[1]] ^ rec_crc[4 * f + 2][b[2]] ^
           rec_crc[4 * f + 3][b[3]];
}

/* A brick's sums, on the stack of the thread that adds them (the threads'
 * slots share cache lines: a store to one per voxel would bounce them),
 * and the CRC part of its current row. */
typedef struct {
    uint32_t level, y, z, row_crc;
    voxel_sum sum;
} voxel_at;

static int add_voxel(void *ud, uint32_t x, uint32_t y, uint32_t z, uint32_t v)
{
    voxel_at *at = ud;
    if (y != at->y || z != at->z) {
        at->y = y, at->z = z;
        at->row_crc = rec_zero ^ field_crc(0, at->level) ^ field_crc(2, y) ^ field_crc(3, z);
    }
    at->sum.crc += at->row_crc ^ field_crc(1, x) ^ field_crc(4, v);
    at->sum.n += at->level == 0;
    return 0;
}

static void add_brick(void *ud, unsigned thread, const vod_info *in, int level,
                      const uint32_t b[3], const uint8_t *raw)
{
    voxel_sum *sums = ud;
    voxel_at at = {(uint32_t)level, UINT32_MAX, UINT32_MAX, 0, {0, 0}};
    vod_brick_foreach(in, level, b, raw, add_voxel, &at);
    sums[thread].crc += at.sum.crc;
    sums[thread].n += at.sum.n;
}

static void print_voxels(const voxel_sum *sums, unsigned threads)
{
    voxel_sum s = {0, 0};
    for (unsigned k = 0; k < threads; k++) {
        s.crc += sums[k].crc;
        s.n += sums[k].n;
    }
    printf("  voxels      %llu non-empty at full resolution; content checksum %08x\n",
           (unsigned long long)s.n, s.crc);
}

int cli_info(int argc, char **argv)
{
    if (argc < 2) return cli_usage_error("info", "missing FILE.vod");
    if (!strcmp(argv[1], "--help") || !strcmp(argv[1], "-h")) {
        fputs("usage: vox info FILE.vod...\n"
              "  validates every part of each file (header, tree, every brick's size,\n"
              "  decompression and hash, the CRC) and prints what it holds; the content\n"
              "  checksum covers every voxel of every level, so files of the same voxels\n"
              "  and brick size written with any compression or hash share it\n",
              stdout);
        return CLI_EXIT_OK;
    }
    int bad = 0;
    rec_crc_init();
    for (int i = 1; i < argc; i++) {
        vod_file *f;
        err_info err = {0};
        unsigned threads = cli_cores();
        voxel_sum sums[PAR_MAX] = {{0, 0}};
        threads = threads > PAR_MAX ? PAR_MAX : threads;
        vod_scan_opts so = {(int)threads, VOD_SCAN_KEEP, add_brick, sums};
        if (vod_scan(argv[i], &so, &f, &err)) {
            cli_error("%s: %s", argv[i], err.msg);
            bad = 1;
            continue;
        }
        print_info(argv[i], vod_get_info(f));
        print_voxels(sums, threads);
        vod_close(f);
    }
    return bad ? CLI_EXIT_FAILED : CLI_EXIT_OK;
}
