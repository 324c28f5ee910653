/* The master against a worker that lies: the subtree schedule's workers
 * build their subtrees in the shared arena and send one IMPLICIT_BUILT
 * entry each (implicit_subtree), which take_subtree checks before it links
 * the root into the tree.  Here a worker forges its first such entry
 * (another octant, a root in the master's block, counts out of bounds, the
 * entry sent twice, a count of 2): the job fails as an engine fault that
 * says so, keeps no octree, and the engine's next job is the serial
 * algorithm's, voxel for voxel.
 *
 * The forgery: this binary is linked with -Wl,--wrap=worker_entry_end (the
 * Makefile says so for it alone), so every entry a worker publishes passes
 * through __wrap_worker_entry_end below.  The workers are forks of this
 * process: they inherit `forgery`, set before engine_create and cleared
 * just after, so a worker forked later (after a death) is honest, and each
 * forged worker lies once, at its first subtree. */
#include <criterion/criterion.h>
#include <errno.h>
#include <stdlib.h>
#include <string.h>

#include "engine.h"
#include "engine_fixture.h"
#include "kind_implicit.h"
#include "kinds.h"
#include "pipeline.h"
#include "work.h"

typedef enum {
    FORGE_NONE,
    FORGE_OCTANT,        /* the octant beside the task's */
    FORGE_ROOT_MASTERS,  /* the root: cell 1, the master's block */
    FORGE_NO_VOXELS,     /* voxels 0 */
    FORGE_VOXELS,        /* one voxel more than the octant holds */
    FORGE_FEW_CELLS,     /* fewer cells than the subtree's height */
    FORGE_CELLS,         /* more cells than the arena */
    FORGE_END_AT_ROOT,   /* end <= root */
    FORGE_END_PAST,      /* end past the blocks handed out */
    FORGE_COUNT,         /* an entry of 2 subtrees */
    FORGE_TWICE,         /* the entry sent again: a second subtree */
} forge_kind;

static forge_kind forgery; /* the workers' copy is the one that counts */
static int forged;         /* in a worker: it lied already */

int __real_worker_entry_end(worker_ctx *w);
int __wrap_worker_entry_end(worker_ctx *w);

static void forge(implicit_subtree *s, shm_entry *en)
{
    switch (forgery) {
    case FORGE_OCTANT: s->o.x ^= 1u << s->o.level; break;
    case FORGE_ROOT_MASTERS: s->root = 1; break;
    case FORGE_NO_VOXELS: s->voxels = 0; break;
    case FORGE_VOXELS: s->voxels = (1ull << (3 * s->o.level)) + 1; break;
    case FORGE_FEW_CELLS: s->cells = s->o.level - 1; break;
    case FORGE_CELLS: s->cells = UINT32_MAX; break;
    case FORGE_END_AT_ROOT: s->end = s->root; break;
    case FORGE_END_PAST: s->end = UINT32_MAX; break;
    case FORGE_COUNT: en->count = 2; break;
    default: break;
    }
}

int __wrap_worker_entry_end(worker_ctx *w)
{
    shm_entry *en = &w->lane->ent[queue_head(&w->lane->q)];
    if (forgery == FORGE_NONE || forged || en->kind != SHM_KIND_IMPLICIT ||
        en->type != IMPLICIT_BUILT)
        return __real_worker_entry_end(w);
    forged = 1;
    implicit_subtree s;
    memcpy(&s, en->payload, sizeof s);
    forge(&s, en);
    memcpy(en->payload, &s, sizeof s);
    int rc = __real_worker_entry_end(w);
    if (rc || forgery != FORGE_TWICE) return rc;
    shm_entry *again = worker_entry_begin(w, IMPLICIT_BUILT);
    if (!again) return -ECANCELED;
    memcpy(again->payload, &s, sizeof s);
    again->count = 1;
    return __real_worker_entry_end(w);
}

static engine *make_liar(forge_kind f, int workers)
{
    forgery = f;
    engine *e = make_engine(workers, 0);
    forgery = FORGE_NONE; /* a worker forked again later does not lie */
    return e;
}

/* One forgery: the job fails saying why, the next one is right. */
static void refused(forge_kind f, const char *says, const expr_tape *tape, const grid_spec *g,
                    const ref_tree *ref)
{
    engine *e = make_liar(f, 1);
    engine_job job = {.tape = tape, .grid = *g, .schedule = ENGINE_SCHED_SUBTREE};
    engine_result r;
    int rc = engine_voxelize(e, &job, &r);
    cr_assert_eq(rc, -EPROTO, "forgery %d: %d %s", f, rc, r.err.msg);
    cr_assert_eq(r.err.kind, ENGINE_FAULT, "forgery %d: %s", f, r.err.msg);
    cr_assert(strstr(r.err.msg, says), "forgery %d: \"%s\" does not say \"%s\"", f, r.err.msg,
              says);
    cr_assert_null(engine_octree(e), "forgery %d: a failed job keeps no octree", f);
    run(e, tape, g, ENGINE_SCHED_SUBTREE, 0, &r); /* the worker lied once */
    assert_same(&ref->t, engine_octree(e), "the job after a forged subtree");
    cr_assert_eq(r.duplicates, 0);
    engine_destroy(e);
}

#define NOT_ITS "worker 0 sent a subtree"

Test(engine_forge, a_forged_subtree_fails_the_job_and_the_next_is_right, .timeout = 300)
{
    expr_tape *tape = compile(SPHERES);
    grid_spec g = grid(64); /* depth 6: subtrees of level 3 */
    ref_tree ref;
    reference(tape, &g, &ref);
    refused(FORGE_OCTANT, NOT_ITS, tape, &g, &ref);
    refused(FORGE_ROOT_MASTERS, NOT_ITS, tape, &g, &ref);
    refused(FORGE_NO_VOXELS, NOT_ITS, tape, &g, &ref);
    refused(FORGE_VOXELS, NOT_ITS, tape, &g, &ref);
    refused(FORGE_FEW_CELLS, NOT_ITS, tape, &g, &ref);
    refused(FORGE_CELLS, NOT_ITS, tape, &g, &ref);
    refused(FORGE_END_AT_ROOT, NOT_ITS, tape, &g, &ref);
    refused(FORGE_END_PAST, NOT_ITS, tape, &g, &ref);
    refused(FORGE_COUNT, NOT_ITS, tape, &g, &ref);
    refused(FORGE_TWICE, "worker 0 sent a second subtree", tape, &g, &ref);
    free(ref.arena);
    expr_tape_free(tape);
}

/* Through the pipeline (what vox and voxd run): the job fails typed, at
 * the voxelize stage, and the engine's next job gives the honest bytes. */
Test(engine_forge, a_forged_subtree_fails_the_pipeline_job, .timeout = 120)
{
    expr_tape *tape = compile(SPHERES);
    engine_pipeline_job job = {
        .kind = &engine_kind_implicit,
        .implicit = {.tape = tape, .source = SPHERES, .source_len = strlen(SPHERES)},
        .lo = {-1, -1, -1}, .hi = {1, 1, 1}, .res = 64,
    };
    vod_params_default(&job.vod);
    engine_pipeline_report r;
    vod_membuf ref = {0}, m = {0}, bad = {0};
    vod_sink sref = {vod_mem_write, &ref}, s = {vod_mem_write, &m}, sbad = {vod_mem_write, &bad};
    cr_assert_eq(engine_pipeline_run(NULL, &job, &sref, &r), 0, "%s", r.err.msg);
    engine *e = make_liar(FORGE_OCTANT, 1);
    cr_assert_eq(engine_pipeline_run(e, &job, &sbad, &r), -EPROTO, "%s", r.err.msg);
    cr_assert_eq(r.err.kind, ENGINE_FAULT);
    cr_assert_eq(r.stage, ENGINE_PIPELINE_VOXELIZE);
    cr_assert(strstr(r.err.msg, "sent a subtree"), "%s", r.err.msg);
    /* the worker lied once: the next job is honest */
    cr_assert_eq(engine_pipeline_run(e, &job, &s, &r), 0, "%s", r.err.msg);
    cr_assert_eq(m.n, ref.n);
    cr_assert_eq(memcmp(m.p, ref.p, ref.n), 0, "the bytes after a forged subtree");
    engine_destroy(e);
    free(ref.p);
    free(m.p);
    free(bad.p);
    expr_tape_free(tape);
}
