/* The pipeline when memory runs out where a kind rewrites its job: an
 * implicit job's distance runs as a CSG tree of one leaf (implicit_rewrite),
 * whose tree and text are allocated first; either allocation failing fails
 * the job with -ENOMEM, typed and said, before anything is written, and the
 * next job is whole.
 *
 * The failure: this binary alone is linked with -Wl,--wrap=calloc,--wrap=malloc
 * (the Makefile says so), so the library's allocations pass through the
 * wrappers below, which fail the first one of the size armed and pass every
 * other on. */
#include <criterion/criterion.h>
#include <errno.h>
#include <stdlib.h>
#include <string.h>

#include "csg.h"
#include "engine.h"
#include "pipeline.h"
#include "vod.h"
#include "voxel.h"

#define BALL "sqrt(x^2 + y^2 + z^2) - 0.6"

void *__real_calloc(size_t n, size_t size);
void *__real_malloc(size_t size);
void *__wrap_calloc(size_t n, size_t size);
void *__wrap_malloc(size_t size);

/* The size whose next allocation fails (0: none), and the failures made.
 * Read by whatever thread allocates: the jobs here are serial, and only
 * the pipeline's thread allocates while one is armed. */
static _Atomic size_t fail_size;
static _Atomic int failed;

static int fail_now(size_t bytes)
{
    size_t want = bytes;
    if (!bytes || !atomic_compare_exchange_strong(&fail_size, &want, 0)) return 0;
    failed++;
    return 1;
}

void *__wrap_calloc(size_t n, size_t size)
{
    return n == 1 && fail_now(size) ? NULL : __real_calloc(n, size);
}

void *__wrap_malloc(size_t size)
{
    return fail_now(size) ? NULL : __real_malloc(size);
}

static expr_tape *compile(const char *src)
{
    expr_tape *t = NULL;
    expr_error ee;
    cr_assert_eq(expr_compile(src, strlen(src), NULL, &t, &ee), 0, "%s", ee.msg);
    return t;
}

static engine_pipeline_job distance_job(const expr_tape *t)
{
    engine_pipeline_job job = {
        .kind = &engine_kind_implicit,
        .implicit = {.tape = t, .source = BALL, .source_len = strlen(BALL)},
        .lo = {-1, -1, -1}, .hi = {1, 1, 1}, .res = 32,
    };
    vod_params_default(&job.vod);
    job.vod.channel = VOXEL_CH_DISTANCE;
    return job;
}

/* The job with the allocation of `bytes` failing: -ENOMEM, said, no byte. */
static void fails_without_memory(size_t bytes, const char *what)
{
    expr_tape *t = compile(BALL);
    engine_pipeline_job job = distance_job(t);
    vod_membuf m = {0}, ok = {0};
    vod_sink sink = {vod_mem_write, &m}, sink_ok = {vod_mem_write, &ok};
    engine_pipeline_report r;
    failed = 0;
    fail_size = bytes;
    int rc = engine_pipeline_run(NULL, &job, &sink, &r);
    fail_size = 0;
    cr_assert_eq(failed, 1, "%s: the allocation of %zu bytes was not made", what, bytes);
    cr_assert_eq(rc, -ENOMEM, "%s: %d %s", what, rc, r.err.msg);
    cr_assert_neq(r.err.kind, ENGINE_OK, "%s", what);
    cr_assert(strstr(r.err.msg, strerror(ENOMEM)), "%s: \"%s\"", what, r.err.msg);
    cr_assert_eq(m.n, 0, "%s: %zu bytes written", what, m.n);
    /* the next job has its memory: a whole file */
    cr_assert_eq(engine_pipeline_run(NULL, &job, &sink_ok, &r), 0, "%s", r.err.msg);
    cr_assert_gt(ok.n, 0);
    free(m.p);
    free(ok.p);
    expr_tape_free(t);
}

Test(pipeline_alloc, the_one_leaf_trees_allocation_failing_fails_the_distance_job)
{
    fails_without_memory(sizeof(csg_tree), "the tree");
}

Test(pipeline_alloc, the_one_leaf_trees_text_failing_fails_the_distance_job)
{
    /* the text's size: the source and its NUL; no other allocation of the
     * job before it is of this size (the test says so if one were: the
     * error would not be -ENOMEM at this stage, or would be another's) */
    fails_without_memory(strlen(BALL) + 1, "the text");
}
