/* Mesh files as the vox commands load them: the loader's messages and
 * warning on stderr, with the file's name; --weld. */
#include "cli.h"

#include <errno.h>
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

int cli_mesh_load(const char *path, mesh_format format, double weld, mesh *m, uint32_t *merged)
{
    mesh_error err;
    char msg[300];
    if (mesh_load(path, format, NULL, m, &err)) {
        cli_error("%s: %s", path, mesh_error_str(&err, msg, sizeof msg));
        return CLI_EXIT_USAGE;
    }
    if (m->warning[0]) cli_error("warning: %s: %s", path, m->warning);
    if (merged) *merged = 0;
    if (weld < 0) return 0;
    int rc = mesh_weld(m, weld, merged);
    if (rc == 0) return 0;
    if (rc == -EINVAL)
        cli_error("%s: no triangle is left once welded at %g (all %u are degenerate then)", path,
                  weld, m->n_triangles);
    else cli_error("%s: welding: %s", path, strerror(-rc));
    mesh_free(m);
    return CLI_EXIT_USAGE;
}

int cli_parse_weld(const char *s, double *eps)
{
    char *end;
    errno = 0;
    double v = strtod(s, &end);
    if (end != s && !*end && !errno && (v == 0 || (v >= MESH_WELD_MIN && v <= MESH_WELD_MAX))) {
        *eps = v + 0.0; /* -0 as 0 */
        return 0;
    }
    cli_error("bad --weld '%s': want 0 or a distance from %g to %g", s, MESH_WELD_MIN,
              MESH_WELD_MAX);
    return -1;
}
