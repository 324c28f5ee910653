/* vox — the voxd command line (work in progress: subcommands land with the engine). */
#include <stdio.h>

int main(int argc, char **argv)
{
    (void)argc;
    fprintf(stderr, "usage: %s voxelize|info|render ...\n", argv[0]);
    return 2;
}
