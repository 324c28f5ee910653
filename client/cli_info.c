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

typedef struct {
    uint32_t level;
    voxel_sum *sum;
} voxel_at;

static int add_voxel(void *ud, uint32_t x, uint32_t y, uint32_t z, uint32_t v)
{
    voxel_at *at = ud;
    uint32_t rec[5] = {at->level, x, y, z, v};
    at->sum->crc += (uint32_t)crc32(0, (const Bytef *)rec, sizeof rec);
    at->sum->n += at->level == 0;
    return 0;
}

static void add_brick(void *ud, unsigned thread, const vod_info *in, int level,
                      const uint32_t b[3], const uint8_t *raw)
{
    voxel_sum *sums = ud;
    voxel_at at = {(uint32_t)level, &sums[thread]};
    vod_brick_foreach(in, level, b, raw, add_voxel, &at);
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
    for (int i = 1; i < argc; i++) {
        vod_file *f;
        err_info err = {0};
        unsigned threads = cli_cores();
        voxel_sum sums[PAR_MAX] = {{0, 0}};
        threads = threads > PAR_MAX ? PAR_MAX : threads;
        if (vod_scan(argv[i], (int)threads, add_brick, sums, &f, &err)) {
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
