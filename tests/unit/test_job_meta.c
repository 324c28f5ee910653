/* job_meta: the metadata pairs that name a job in its VOD file. */
#include <criterion/criterion.h>
#include <string.h>

#include "job_meta.h"

static job_meta sphere(const char *src, const char *name)
{
    job_meta m = {
        .source = src, .source_len = strlen(src), .source_name = name,
        .res = 100, .grid = {100, 50, 25},
        .lo = {-1, 0, 0.5}, .hi = {1, 1, 1},
    };
    return m;
}

static const char *source_line(const job_meta *m, char *buf)
{
    job_meta_format(buf, JOB_META_MAX, m);
    char *s = strstr(buf, "\nsource=");
    cr_assert_not_null(s);
    s += 8;
    s[strcspn(s, "\n")] = '\0';
    return s;
}

Test(job_meta, every_pair_in_order)
{
    char buf[JOB_META_MAX];
    job_meta m = sphere("x^2+y^2+z^2-1", NULL);
    job_meta_format(buf, sizeof buf, &m);
    cr_assert_str_eq(buf, "generator=vox voxelize\nsource=x^2+y^2+z^2-1\nresolution=100\n"
                          "grid=100x50x25\ndomain=-1,1,0,1,0.5,1\n");
}

Test(job_meta, a_short_one_line_source_is_kept_whatever_its_name)
{
    char buf[JOB_META_MAX];
    job_meta m = sphere("x+y", "scene.vx");
    cr_assert_str_eq(source_line(&m, buf), "x+y");
}

Test(job_meta, a_source_of_several_lines_is_named_or_counted)
{
    char buf[JOB_META_MAX];
    job_meta m = sphere("a = x;\na + y", "dir/scene.vx");
    cr_assert_str_eq(source_line(&m, buf), "file:dir/scene.vx");
    m.source_name = NULL;
    cr_assert_str_eq(source_line(&m, buf), "submitted:12 bytes");
}

Test(job_meta, a_long_source_is_named_or_counted_at_the_limit)
{
    char buf[JOB_META_MAX], src[JOB_META_INLINE + 2];
    memset(src, 'x', sizeof src);
    src[JOB_META_INLINE] = '\0';
    job_meta m = sphere(src, NULL);
    cr_assert_eq(strlen(source_line(&m, buf)), JOB_META_INLINE, "at the limit: kept");
    src[JOB_META_INLINE] = 'x';
    src[JOB_META_INLINE + 1] = '\0';
    m = sphere(src, NULL);
    cr_assert_str_eq(source_line(&m, buf), "submitted:201 bytes");
}

Test(job_meta, a_long_name_is_cut_and_the_pairs_stay_whole)
{
    char buf[JOB_META_MAX], name[4 * JOB_META_NAME_MAX];
    memset(name, 'n', sizeof name - 1);
    name[sizeof name - 1] = '\0';
    job_meta m = sphere("a = x;\na", name);
    cr_assert_eq(strlen(source_line(&m, buf)), 5 + JOB_META_NAME_MAX);
    job_meta_format(buf, sizeof buf, &m);
    cr_assert_not_null(strstr(buf, "\ndomain=-1,1,0,1,0.5,1\n"), "the last pair survives");
}

Test(job_meta, a_csg_tree_names_its_own_command)
{
    char buf[JOB_META_MAX];
    job_meta m = sphere("", "part.csg");
    m.source_len = 300;
    m.kind_pairs = "csg_nodes=6\n";
    m.generator = "vox csg";
    job_meta_format(buf, sizeof buf, &m);
    cr_assert_str_eq(buf, "generator=vox csg\nsource=file:part.csg\nresolution=100\n"
                          "grid=100x50x25\ndomain=-1,1,0,1,0.5,1\ncsg_nodes=6\n");
}
