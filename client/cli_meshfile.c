/* Mesh files as the vox commands load them: the loader's messages and
 * warning on stderr, with the file's name. */
#include "cli.h"

#include <stdio.h>

int cli_mesh_load(const char *path, mesh_format format, mesh *m)
{
    mesh_error err;
    char msg[300];
    if (mesh_load(path, format, NULL, m, &err)) {
        cli_error("%s: %s", path, mesh_error_str(&err, msg, sizeof msg));
        return CLI_EXIT_USAGE;
    }
    if (m->warning[0]) cli_error("warning: %s: %s", path, m->warning);
    return 0;
}
