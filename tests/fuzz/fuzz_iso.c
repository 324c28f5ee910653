/* libFuzzer harness for marching cubes (iso.h) on any VOD file the reader
 * accepts: every level of a small enough file is polygonized serially, and
 * the mesh must be closed and consistently oriented (every edge used by
 * two triangles in opposite directions, every index inside the vertices),
 * whatever the file holds (voxels past its volume, any brick size, any
 * channel the reader allows).  The input is read as it is and with its CRC
 * made right, as fuzz_vod does. */
#include <stddef.h>
#include <stdint.h>
#include <stdlib.h>
#include <string.h>
#include <zlib.h>

#include "iso.h"
#include "vod.h"

int LLVMFuzzerTestOneInput(const uint8_t *data, size_t size);

static int by_u64(const void *a, const void *b)
{
    uint64_t x = *(const uint64_t *)a, y = *(const uint64_t *)b;
    return (x > y) - (x < y);
}

/* Each directed edge a -> b as (min, max, direction); a closed, oriented
 * mesh has each undirected edge twice, once each way. */
static void check_closed(const iso_mesh *m)
{
    size_t n = 3 * m->n_triangles;
    uint64_t *e = malloc((n ? n : 1) * sizeof *e);
    if (!e) return;
    for (size_t i = 0; i < n; i++) {
        uint32_t a = m->tri[i], b = m->tri[i - i % 3 + (i + 1) % 3];
        if (a >= m->n_vertices || a == b) __builtin_trap();
        uint64_t lo = a < b ? a : b, hi = a < b ? b : a;
        e[i] = (lo << 32 | hi) << 1 | (a < b); /* sorts both ways of an edge together */
    }
    qsort(e, n, sizeof *e, by_u64);
    for (size_t i = 0; i < n; i += 2)
        if (i + 1 >= n || e[i] >> 1 != e[i + 1] >> 1 || (e[i] & 1) == (e[i + 1] & 1) ||
            (i + 2 < n && e[i + 2] >> 1 == e[i] >> 1))
            __builtin_trap();
    free(e);
}

static void *heap(void *ud, size_t n)
{
    return *(void **)ud = malloc(n);
}

static void polygonize(const vod_file *f, int level)
{
    iso_params p;
    err_info err = {0};
    if (iso_params_make(f, &(iso_request){.iso = 127, .level = level}, &p, &err)) {
        if (!err.msg[0]) __builtin_trap(); /* refused without a message */
        return;
    }
    void *mem = NULL;
    iso_input in;
    iso_mesh m;
    if (!iso_input_make(f, &p, heap, &mem, &in) && !iso_run_serial(&p, &in, &m, &err)) {
        check_closed(&m);
        iso_mesh_free(&m);
    }
    free(mem);
}

/* Files up to 128 voxels a side: a uniform root over a huge volume would
 * list millions of bricks and say nothing more. */
static void read_and_mesh(const uint8_t *data, size_t size)
{
    vod_file *f;
    if (vod_read(data, size, &f, NULL)) return;
    const vod_info *in = vod_get_info(f);
    if (in->volume[0] <= 128 && in->volume[1] <= 128 && in->volume[2] <= 128)
        for (int l = 0; l < (int)in->height; l++) polygonize(f, l);
    vod_close(f);
}

int LLVMFuzzerTestOneInput(const uint8_t *data, size_t size)
{
    read_and_mesh(data, size);
    if (size < 68) return 0;
    uint8_t *copy = malloc(size);
    if (!copy) return 0;
    memcpy(copy, data, size);
    vod_put32(copy + size - 4, (uint32_t)crc32_z(0, copy, size - 4));
    read_and_mesh(copy, size);
    free(copy);
    return 0;
}
