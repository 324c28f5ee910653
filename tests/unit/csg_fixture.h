/* csg_fixture — what the CSG unit tests share: a tree parsed from text
 * (the test fails on a parse error) and the grid over [-1, 1]^3. */
#ifndef VOXD_TEST_CSG_FIXTURE_H
#define VOXD_TEST_CSG_FIXTURE_H

#include <criterion/criterion.h>
#include <string.h>

#include "csg.h"

static inline csg_tree *parse(const char *src)
{
    csg_tree *t;
    csg_error err;
    int rc = csg_parse(src, strlen(src), &t, &err);
    cr_assert_eq(rc, 0, "%s: %d:%d %s: %s", src, err.line, err.col, err.node, err.msg);
    return t;
}

static inline grid_spec grid(uint32_t res)
{
    double lo[3] = {-1, -1, -1}, hi[3] = {1, 1, 1};
    grid_spec g;
    err_info err = {0};
    cr_assert_eq(grid_make(lo, hi, res, &g, &err), 0);
    return g;
}

#endif
