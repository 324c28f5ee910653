/* vox — the voxd command line. */
#include <errno.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "cli.h"
#include "config.h"
#include "thread_name.h"

static const char usage[] =
    "usage: vox [--socket PATH] COMMAND [options]\n"
    "       vox --version\n"
    "\n"
    "commands:\n"
    "  voxelize   an implicit surface F(x,y,z) = 0 or a triangle mesh into a VOD file,\n"
    "             on voxd when one answers, else with the embedded engine\n"
    "  submit     the same jobs, or a volume CSG tree (--csg), on voxd only\n"
    "  status     voxd's jobs (running and queued), workers, uptime and clients\n"
    "  cancel     cancel a job on voxd\n"
    "  ping       check that voxd answers, and how fast\n"
    "  info       validate a VOD file and print its header, tree and bricks\n"
    "  render     draw a VOD file (shaded points) or a triangle mesh into a PNG\n"
    "  mesh-info  load a triangle mesh (OBJ, STL, PLY, OFF) and describe its topology\n"
    "  csg        evaluate a volume CSG tree (.csg) into a VOD file, on the embedded\n"
    "             engine's workers (-w 0: in this process)\n"
    "  export     write a VOD file's voxels as NRRD, raw + JSON, binvox, VTK (.vti)\n"
    "             or OpenVDB (.vdb)\n"
    "  mesh       a VOD file's surface as triangles (marching cubes): PLY, OBJ, STL\n"
    "\n"
    "  --socket PATH   voxd's socket (default: $VOXD_SOCKET, else the socket of voxd's\n"
    "                  config file $VOXD_CONFIG or " CONFIG_DEFAULT_PATH ", else\n"
    "                  " VOX_DEFAULT_SOCKET ")\n"
    "  --version       vox's version and the git commit it was built from\n"
    "\n"
    "`vox COMMAND --help` tells a command's options.  Exit status: 0 done, 1 the job\n"
    "or request failed, 2 bad usage or input, 3 no voxd answering (docs/cli.md).\n";

/* The socket when --socket is not given: $VOXD_SOCKET, else the `socket` of
 * the daemon's configuration (/etc/voxd/voxd.conf, or $VOXD_CONFIG) when it
 * can be read, else the built-in default.  A configuration that does not
 * load is said, not skipped silently. */
static const char *default_socket(voxd_config *cfg)
{
    const char *env = getenv("VOXD_SOCKET");
    if (env && *env) return env;
    const char *path = getenv("VOXD_CONFIG");
    int explicit_path = path && *path;
    if (!explicit_path) path = CONFIG_DEFAULT_PATH;
    err_info err = {0};
    int rc = config_load(path, cfg, &err);
    if (rc == 0) return cfg->socket;
    if (explicit_path || (rc != -ENOENT && rc != -EACCES))
        cli_error("%s; using the socket " VOX_DEFAULT_SOCKET, err.msg);
    return VOX_DEFAULT_SOCKET;
}

static const char *const commands[] = {"voxelize", "submit", "status", "cancel", "ping",
                                       "info", "render", "mesh-info", "csg", "export",
                                       "mesh", "help", NULL};

/* vox's own options, before the command: the index of the command, or
 * -1 - the exit status. */
static int own_options(int argc, char **argv, const char **sock)
{
    static const char *const names[] = {"--socket", "--help", "--version", "-h", NULL};
    int i = 1;
    while (i < argc && argv[i][0] == '-') {
        const char *a = argv[i];
        if (!strcmp(a, "-h") || !strcmp(a, "--help")) {
            fputs(usage, stdout);
            return -1 - CLI_EXIT_OK;
        }
        if (!strcmp(a, "--version") || !strcmp(a, "-V")) {
            cli_version("vox");
            return -1 - CLI_EXIT_OK;
        }
        if (!strcmp(a, "--socket")) {
            if (i + 1 >= argc || !argv[i + 1][0])
                return -1 - cli_usage_error(NULL, "option '--socket' needs a PATH");
            *sock = argv[i + 1];
            i += 2;
        } else if (!strncmp(a, "--socket=", 9) && a[9]) {
            *sock = a + 9;
            i++;
        } else {
            return -1 - cli_unknown_option(NULL, a, names);
        }
    }
    if (i >= argc)
        return -1 - cli_usage_error(NULL, "missing COMMAND (voxelize, submit, status, ...)");
    return i;
}

static int vox_main(int argc, char **argv)
{
    static voxd_config cfg;
    const char *sock = NULL;
    int i = own_options(argc, argv, &sock);
    if (i < 0) return -1 - i;
    const char *cmd = argv[i];
    int n = argc - i;
    char **v = argv + i;
    if (!strcmp(cmd, "help")) {
        fputs(usage, stdout);
        return 0;
    }
    if (strcmp(cmd, "info") && strcmp(cmd, "render") && strcmp(cmd, "mesh-info") &&
        strcmp(cmd, "csg") && strcmp(cmd, "export") && strcmp(cmd, "mesh") && !sock)
        sock = default_socket(&cfg);
    if (!strcmp(cmd, "voxelize")) return cli_voxelize(n, v, sock);
    if (!strcmp(cmd, "submit")) return cli_submit(n, v, sock);
    if (!strcmp(cmd, "status")) return cli_status(n, v, sock);
    if (!strcmp(cmd, "cancel")) return cli_cancel(n, v, sock);
    if (!strcmp(cmd, "ping")) return cli_ping(n, v, sock);
    if (!strcmp(cmd, "info")) return cli_info(n, v);
    if (!strcmp(cmd, "render")) return cli_render(n, v);
    if (!strcmp(cmd, "mesh-info")) return cli_mesh_info(n, v);
    if (!strcmp(cmd, "csg")) return cli_csg(n, v);
    if (!strcmp(cmd, "export")) return cli_export(n, v);
    if (!strcmp(cmd, "mesh")) return cli_mesh(n, v);
    return cli_unknown_command(cmd, commands);
}

int main(int argc, char **argv)
{
    thread_name_enable(); /* its stages named, for bench/voxserial -w */
    thread_name("main");
    int rc = vox_main(argc, argv);
    thread_name("exit"); /* the exit's handlers and teardown */
    return rc;
}
