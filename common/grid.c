/* Grid arithmetic: the one formula for voxel bounds, and the grid of a job. */
#include "grid.h"

#include <errno.h>
#include <math.h>

static const char axis_name[3] = {'x', 'y', 'z'};

static int depth_for(uint32_t res)
{
    int d = 1;
    while ((1u << d) < res) d++;
    return d;
}

static int check_domain(const double lo[3], const double hi[3], err_info *err)
{
    for (int a = 0; a < 3; a++) {
        if (!isfinite(lo[a]) || !isfinite(hi[a])) {
            return err_set(err, -EINVAL, "domain bound on %c is not finite",
                     axis_name[a]);
        }
        if (!(hi[a] > lo[a])) {
            return err_set(err, -EINVAL, "domain is empty on %c: low %g >= high %g",
                     axis_name[a], lo[a], hi[a]);
        }
        if (!isfinite(hi[a] - lo[a])) {
            return err_set(err, -EINVAL, "domain is too large on %c", axis_name[a]);
        }
    }
    return 0;
}

/* Voxels along axis a: the fewest that cover hi (ceil(extent / vs) up to
 * rounding), at least 1, never more than res. */
static uint32_t axis_voxels(const grid_spec *g, const double hi[3], int a,
                            uint32_t res)
{
    double n = ceil((hi[a] - g->lo[a]) / g->vs);
    uint32_t v = n < 1.0 ? 1u : n > (double)res ? res : (uint32_t)n;
    while (v > 1 && grid_coord(g, a, v - 1) >= hi[a]) v--;
    while (v < res && grid_coord(g, a, v) < hi[a]) v++;
    return v;
}

int grid_make(const double lo[3], const double hi[3], uint32_t res,
                     grid_spec *g, err_info *err)
{
    if (res < 1 || res > GRID_MAX_RES) {
        return err_set(err, -EINVAL, "resolution %u is outside 1..%u", res,
                 GRID_MAX_RES);
    }
    int rc = check_domain(lo, hi, err);
    if (rc) return rc;
    int longest = 0;
    for (int a = 1; a < 3; a++)
        if (hi[a] - lo[a] > hi[longest] - lo[longest]) longest = a;
    for (int a = 0; a < 3; a++) g->lo[a] = lo[a];
    g->vs = (hi[longest] - lo[longest]) / res;
    /* Round vs up until the grid reaches hi: the voxels cover the domain. */
    while (grid_coord(g, longest, res) < hi[longest])
        g->vs = nextafter(g->vs, INFINITY);
    for (int a = 0; a < 3; a++) {
        if (!(g->vs > 0.0) || grid_coord(g, a, 1) == lo[a]) {
            return err_set(err, -EINVAL,
                     "domain is too small for its position on %c: a voxel "
                     "would be narrower than the floating-point spacing",
                     axis_name[a]);
        }
        g->res[a] = a == longest ? res : axis_voxels(g, hi, a, res);
    }
    g->depth = depth_for(res);
    return 0;
}

int grid_check(const grid_spec *g)
{
    uint32_t m = 0;
    for (int a = 0; a < 3; a++) {
        if (g->res[a] < 1 || g->res[a] > GRID_MAX_RES) return -EINVAL;
        if (!isfinite(g->lo[a])) return -EINVAL;
        if (!isfinite(grid_coord(g, a, g->res[a]))) return -EINVAL;
        if (g->res[a] > m) m = g->res[a];
    }
    if (!(g->vs > 0.0) || !isfinite(g->vs)) return -EINVAL;
    if (g->depth != depth_for(m)) return -EINVAL;
    return 0;
}
