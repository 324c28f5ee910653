/* exit_status — the exit status of the project's commands: vox, vox_mpi
 * and voxd (docs/cli.md, "Exit status, every command"). */
#ifndef VOXD_EXIT_STATUS_H
#define VOXD_EXIT_STATUS_H

typedef enum {
    CLI_EXIT_OK = 0,
    CLI_EXIT_FAILED = 1,    /* the job (or the request) failed; voxd cannot start */
    CLI_EXIT_USAGE = 2,     /* bad usage, a bad expression or input file */
    CLI_EXIT_NO_DAEMON = 3, /* no voxd answering on the socket */
} cli_exit;

#endif
