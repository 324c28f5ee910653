/* kind_iso — the iso kind: marching cubes over a VOD file's bricks on
 * the engine's workers (no pipeline job: vox mesh calls engine_iso).  Its
 * master side is kind_iso.c, its worker side worker/work_iso.c; the
 * number of its brick tasks is engine_result.tasks. */
#ifndef VOXD_KIND_ISO_H
#define VOXD_KIND_ISO_H

#include <stdatomic.h>
#include <stdint.h>

#include "engine.h"
#include "iso.h"
#include "vod.h"

/* Marching cubes over an open VOD file (iso.h) by the workers: the raw
 * bricks of the levels p reads are copied into the segment, each worker
 * claims brick tasks until none is left and packs each task's piece into
 * shared memory; a task a worker did not finish (it died, or the pieces
 * outgrew the segment) is run by the caller's thread, and the pieces are
 * welded here in task order, so *out is iso_run_serial's mesh, byte for
 * byte.  Free it with iso_mesh_free.  Errors as engine_voxelize's
 * (ENGINE_LIMIT: the bricks did not fit, or more than 2^32 vertices). */
typedef struct engine_iso_weld engine_iso_weld;
typedef struct {
    const vod_file *file;
    const iso_params *p;        /* iso_params_make's, for file */
    void (*progress)(void *ud, const engine_progress *p);
    void *ud;
    const atomic_int *cancel;   /* as engine_job.cancel */
    /* Optional: once the mesh's size and place in shared memory are
     * known, before it is welded, *weld is filled in and laid_out(ud, m)
     * called on the caller's thread: m (its counts, its arrays, still
     * being written) is final part by part as engine_iso_wait says, so a
     * writer may stream it while it is welded (vox mesh).  On success all
     * of it is final when engine_iso returns; on failure the caller sets
     * weld->stop before it lets go of the engine. */
    engine_iso_weld *weld;
    void (*laid_out)(void *ud, const iso_mesh *m);
} engine_iso_job;
int engine_iso(engine *e, const engine_iso_job *job, iso_mesh *out, engine_result *r);

/* The weld's progress, the caller's (engine_iso_job.weld); views of the
 * segment, valid until the engine's next job. */
struct engine_iso_weld {
    const void *results;        /* the pieces' results (their welded flags) */
    const uint64_t *vbase, *tbase; /* piece i's first vertex and triangle */
    uint64_t n;                 /* pieces */
    /* Pieces below it are known welded: raised by the waits.  Relaxed:
     * each wait reads the flags themselves with acquire. */
    atomic_uint_fast64_t known;
    atomic_int stop;            /* set by the caller: the waits give up */
};
/* Until the vertices (tris 0) or triangles (tris 1) below hi are welded:
 * 0, or -ECANCELED once w->stop is set. */
int engine_iso_wait(engine_iso_weld *w, int tris, uint64_t hi);

#endif
