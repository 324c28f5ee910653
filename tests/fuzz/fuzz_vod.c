/* libFuzzer harness for the VOD reader: any input must be refused with a
 * message or open into a file whose every level can be walked, and read by
 * three threads, and scanned (vod_scan) by two, the same way as by one;
 * and a file that opens must open with levels 0 and 2 alone
 * (vod_open_levels), those levels the same voxels, the others absent. */
#include <errno.h>
#include <stddef.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/mman.h>
#include <unistd.h>
#include <zlib.h>

#include "vod.h"

int LLVMFuzzerTestOneInput(const uint8_t *data, size_t size);

static int visit(void *ud, uint32_t x, uint32_t y, uint32_t z, uint32_t v)
{
    uint64_t *n = ud;
    *n += 1 + ((x ^ y ^ z ^ v) & 1);
    return 0;
}

/* Three threads must answer as one does: the same code and message. */
static void read_threaded(const uint8_t *data, size_t size, int rc, const char *err)
{
    vod_file *f;
    err_info e3;
    int r3 = vod_read_threads(data, size, 3, &f, &e3);
    if (r3 != rc || (rc && strcmp(e3.msg, err))) __builtin_trap();
    if (!r3) vod_close(f);
}

static void count_node(void *ud, unsigned thread, const vod_info *in, int level,
                       const uint32_t b[3], const uint8_t *raw)
{
    uint64_t *per_thread = ud;
    if (thread >= 2) __builtin_trap(); /* vod_scan was given two */
    per_thread[thread] += 1 + (raw[0] ^ b[0] ^ (uint32_t)level ^ in->brick);
}

/* The input in a memfd, named by its /proc path (for the readers that
 * open a path); its descriptor, to close. */
static int memfd_path(const uint8_t *data, size_t size, char path[64])
{
    int fd = memfd_create("fuzz_vod", MFD_CLOEXEC);
    if (fd < 0) __builtin_trap();
    for (size_t at = 0; at < size;) {
        ssize_t w = write(fd, data + at, size - at);
        if (w <= 0) __builtin_trap();
        at += (size_t)w;
    }
    snprintf(path, 64, "/proc/self/fd/%d", fd);
    return fd;
}

/* The scan (vod_scan) must answer as vod_read does: the same code and
 * message. */
static void scan_agrees(const uint8_t *data, size_t size, int rc, const char *err)
{
    char path[64];
    int fd = memfd_path(data, size, path);
    uint64_t per_thread[2] = {0};
    vod_file *f;
    err_info e;
    vod_scan_opts o = {2, VOD_SCAN_KEEP, count_node, per_thread};
    int r = vod_scan(path, &o, &f, &e);
    if (r != rc || (rc && strcmp(e.msg, err))) __builtin_trap();
    if (!r) vod_close(f);
    close(fd);
}

#define FUZZ_LEVELS 5u /* levels 0 and 2 */

/* Opened with FUZZ_LEVELS alone, a file that opens whole (its levels'
 * walks' counts in n) must open, those levels walked alike, the others
 * absent; one that does not may open or not (a damaged brick that only
 * other levels hold is not seen), with a message when not. */
static void levels_agree(const uint8_t *data, size_t size, int rc, const uint64_t *n)
{
    char path[64];
    int fd = memfd_path(data, size, path);
    vod_file *f;
    err_info e;
    int r = vod_open_levels(path, 2, FUZZ_LEVELS, &f, &e);
    close(fd);
    if (r != 0) {
        if (rc == 0 || !e.msg[0] || e.code != r) __builtin_trap();
        return;
    }
    const vod_info *in = vod_get_info(f);
    for (int l = 0; rc == 0 && l < (int)in->height; l++) {
        uint64_t k = 0;
        int w = vod_foreach(f, l, visit, &k);
        if (FUZZ_LEVELS >> l & 1u ? w != 0 || k != n[l] : w != -EINVAL) __builtin_trap();
    }
    vod_close(f);
}

static int read_and_walk(const uint8_t *data, size_t size)
{
    vod_file *f;
    err_info err;
    int rc = vod_read(data, size, &f, &err);
    read_threaded(data, size, rc, err.msg);
    scan_agrees(data, size, rc, err.msg);
    if (rc != 0) {
        /* refused, but without a message or with another code than returned */
        if (!err.msg[0] || err.code != rc || f) __builtin_trap();
        levels_agree(data, size, rc, NULL);
        return 0;
    }
    const vod_info *in = vod_get_info(f);
    uint64_t n = 0, per_level[32] = {0};
    for (int l = 0; l < (int)in->height; l++) {
        if (vod_foreach(f, l, visit, &per_level[l]) != 0) __builtin_trap();
        uint32_t s = vod_level_size(f, l);
        n += per_level[l] + vod_voxel(f, l, 0, 0, 0) + vod_voxel(f, l, s - 1, s / 2, s - 1) +
             vod_voxel(f, l, s, 0, 0);
    }
    levels_agree(data, size, rc, per_level);
    n += strlen(in->metadata);
    vod_close(f);
    return n == UINT64_MAX; /* keep n alive */
}

/* Each input is read as it is, and again with its last 4 bytes replaced by
 * the right CRC, so mutations reach the checks behind the trailer's CRC. */
int LLVMFuzzerTestOneInput(const uint8_t *data, size_t size)
{
    int r = read_and_walk(data, size);
    if (size < 68) return r;
    uint8_t *copy = malloc(size);
    if (!copy) return r;
    memcpy(copy, data, size);
    vod_put32(copy + size - 4, (uint32_t)crc32_z(0, copy, size - 4));
    r |= read_and_walk(copy, size);
    free(copy);
    return r;
}
