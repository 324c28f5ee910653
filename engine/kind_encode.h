/* kind_encode — the encode kind: the last job's octree or volume written
 * as VOD, its bricks encoded by the engine's workers.  Its master side is
 * kind_encode.c, its worker side worker/work_encode.c. */
#ifndef VOXD_KIND_ENCODE_H
#define VOXD_KIND_ENCODE_H

#include <stddef.h>
#include <stdint.h>

#include "engine.h"
#include "vod.h"

/* Write the last job's octree or volume as VOD, bricks encoded by the workers into
 * shared memory (what does not fit, or what a dying worker left undone, is
 * encoded by the caller's thread, which frees its encoder before
 * returning); the bytes are vod_write_octree()'s.  Returns 0, or a
 * negative errno with err saying why: ENGINE_LIMIT when the file would
 * pass the format's 4 GiB or shared memory is too small (the message names
 * what to change), ENGINE_SINK with the sink's own error as the code,
 * ENGINE_BAD_JOB (no octree, bad parameters), ENGINE_FAULT. */
int engine_write_vod(engine *e, const vod_params *p, vod_sink *sink,
                     vod_stats *st, engine_error *err);
/* The bricks engine_write_vod would write, without the file: the last
 * job's n non-empty brick nodes in preorder, each node's record and encoded
 * bytes (a duplicate's data points at its first's), with the layout and
 * the source they came from (its mip levels made: fill() works at every
 * level). */
typedef struct {
    const vod_layout *L;
    const vod_source *src;
    size_t n;
    const vod_node *nodes;
    const vod_encoded *recs;
    const uint8_t *const *data;
} engine_bricks;
/* engine_encode_bricks hands them to deliver while they are still in
 * shared memory.  vox_mpi's ranks send their subtrees' bricks this way.
 * deliver returns 0 or a negative errno (then ENGINE_SINK).  Errors as
 * engine_write_vod's. */
typedef int (*engine_deliver)(void *ud, const engine_bricks *b);
int engine_encode_bricks(engine *e, const vod_params *p, engine_deliver deliver,
                         void *ud, vod_stats *st, engine_error *err);

#endif
