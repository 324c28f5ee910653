/* vox — the voxd command line. */
#include <stdio.h>
#include <string.h>

#include "cli.h"

static const char usage[] =
    "usage: vox COMMAND [options]\n"
    "\n"
    "commands:\n"
    "  voxelize   voxelize an implicit surface F(x,y,z) = 0 into a VOD file\n"
    "  info       validate a VOD file and print its header, tree and bricks\n"
    "  render     draw a VOD file as shaded points into a PNG\n"
    "\n"
    "`vox COMMAND --help` tells a command's options.\n";

int main(int argc, char **argv)
{
    if (argc < 2) {
        fputs(usage, stderr);
        return 2;
    }
    const char *cmd = argv[1];
    if (!strcmp(cmd, "-h") || !strcmp(cmd, "--help") || !strcmp(cmd, "help")) {
        fputs(usage, stdout);
        return 0;
    }
    if (!strcmp(cmd, "voxelize")) return cli_voxelize(argc - 1, argv + 1);
    if (!strcmp(cmd, "info")) return cli_info(argc - 1, argv + 1);
    if (!strcmp(cmd, "render")) return cli_render(argc - 1, argv + 1);
    cli_error("unknown command '%s'", cmd);
    fputs(usage, stderr);
    return 2;
}
