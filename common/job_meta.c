#include "job_meta.h"

#include <assert.h>
#include <stdio.h>
#include <string.h>

void job_meta_format(char *buf, size_t cap, const job_meta *m)
{
    assert(cap >= JOB_META_MAX);
    char line[JOB_META_NAME_MAX + 32];
    size_t first_line = strcspn(m->source, "\n");
    if (!m->kind_pairs && m->source_len <= JOB_META_INLINE &&
        first_line >= m->source_len)
        snprintf(line, sizeof line, "%.*s", (int)m->source_len, m->source);
    else if (m->source_name)
        snprintf(line, sizeof line, "file:%.*s", (int)JOB_META_NAME_MAX, m->source_name);
    else
        snprintf(line, sizeof line, "submitted:%zu bytes", m->source_len);
    int n = snprintf(buf, cap,
                     "generator=%s\nsource=%s\nresolution=%u\n"
                     "grid=%ux%ux%u\ndomain=%g,%g,%g,%g,%g,%g\n",
                     m->generator ? m->generator : "vox voxelize", line, m->res, m->grid[0], m->grid[1], m->grid[2], m->lo[0],
                     m->hi[0], m->lo[1], m->hi[1], m->lo[2], m->hi[2]);
    if (m->kind_pairs && n > 0 && (size_t)n < cap)
        snprintf(buf + n, cap - (size_t)n, "%s", m->kind_pairs);
}
