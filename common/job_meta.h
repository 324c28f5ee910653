/* job_meta — the VOD metadata of an implicit-surface job.
 *
 * The pairs name the job, not how it ran (no worker count, no schedule), so
 * the same job gives the same bytes with any engine set-up, embedded in vox
 * or through voxd:
 *
 *   generator=vox voxelize        (vox csg for a CSG tree)
 *   source=<the expression> | file:<name> | submitted:<N> bytes
 *   resolution=<res>
 *   grid=<X>x<Y>x<Z>
 *   domain=<x0>,<x1>,<y0>,<y1>,<z0>,<z1>
 *
 * An expression of one line and at most JOB_META_INLINE bytes is recorded as
 * it is; a longer one by the name of the file it came from, or by its size
 * when it has no name.  A job of another kind (a mesh) is always recorded
 * by its file's name or size, and adds its own pairs (kind_pairs) at the
 * end, e.g. for a mesh:
 *
 *   mesh_triangles=<N>
 *   mesh_mode=solid|surface|surface6|conservative|interior
 *   mesh_repair=none|vote|winding
 */
#ifndef VOXD_JOB_META_H
#define VOXD_JOB_META_H

#include <stddef.h>
#include <stdint.h>

#define JOB_META_INLINE 200u
#define JOB_META_MAX 1024u      /* bytes of the formatted pairs, NUL included */
#define JOB_META_NAME_MAX 512u  /* bytes of a source's name that are kept */

typedef struct {
    const char *source;         /* the expression's text */
    size_t source_len;
    const char *source_name;    /* its file's name, or NULL */
    uint32_t res;               /* voxels along the longest axis, as asked */
    uint32_t grid[3];           /* voxels per axis */
    double lo[3], hi[3];        /* the domain */
    const char *kind_pairs;     /* NULL for an expression; else "k=v\n" lines */
    const char *generator;      /* the command that makes such a job; NULL: "vox voxelize" */
} job_meta;

/* The pairs above into buf (cap >= JOB_META_MAX), NUL-terminated. */
void job_meta_format(char *buf, size_t cap, const job_meta *m);

#endif
