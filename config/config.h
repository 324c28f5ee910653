/* config — the daemon's configuration file (config/voxd.conf documents it).
 *
 * One option per line: a key, white space, the value (the rest of the line,
 * trailing white space removed).  A line whose first non-blank character is
 * '#' is a comment; blank lines are ignored.  There are no trailing comments
 * (a path may contain '#').  Each key at most once; an option not given
 * keeps its default.  Sizes take a unit: K, M, G, T (powers of 1024, either
 * case); durations s, m, h, d.  Lists are separated by commas or blanks.
 *
 * config_load() reports the first problem as "FILE:LINE: reason" (unknown
 * key, missing or bad value, duplicate key, value out of range, or two
 * options that do not fit together) and leaves *c untouched on failure.
 * config_print() writes the effective settings as a file that loads back to
 * the same configuration (voxd --check-config).
 */
#ifndef VOXD_CONFIG_H
#define VOXD_CONFIG_H

#include <limits.h>
#include <stdint.h>
#include <stdio.h>
#include <sys/types.h>

#include "err.h"
#include "proto_check.h"
#include "vox_limits.h"

#define CONFIG_DEFAULT_PATH "/etc/voxd/voxd.conf"
#define CONFIG_MAX_LINE 4096     /* bytes of one line */
#define CONFIG_MAX_UIDS 64       /* entries of allow_uids */
#define CONFIG_MAX_CPUS 1024     /* entries of cpus; each CPU number below this */
#define CONFIG_MAX_WORKERS 256   /* = ENGINE_MAX_WORKERS */
#define CONFIG_SOCKET_MAX 108    /* sizeof sun_path, NUL included */
/* A request carries up to this much besides its expression: the config
 * keeps an expression of max_expr_bytes sendable, inline within
 * max_frame - CONFIG_REQUEST_OVERHEAD or as input within max_input_bytes. */
#define CONFIG_REQUEST_OVERHEAD 256u
/* max_memory must leave at least this much above shm_size for results. */
#define CONFIG_RESULT_ROOM ((uint64_t)64 << 20)
/* mpirun_args' default: ranks over TCP, more ranks than cores allowed. */
#define CONFIG_MPIRUN_ARGS "--oversubscribe --mca btl self,tcp"

typedef struct {
    /* socket */
    char socket[CONFIG_SOCKET_MAX];  /* /run/voxd/voxd.sock */
    unsigned socket_mode;            /* 0660 */
    int has_socket_group;            /* 0: none (the daemon's group) */
    gid_t socket_gid;
    char socket_group[64];           /* as written: a name or a number */
    /* who may connect (SO_PEERCRED), besides what the mode allows */
    int allow_any;                   /* allow_uids any */
    int n_allow_uids;                /* 0: the daemon's own uid and root */
    uid_t allow_uids[CONFIG_MAX_UIDS];
    /* workers */
    int workers;                     /* 0 = auto: online cores */
    int n_cpus;                      /* 0 = automatic pinning */
    int cpus[CONFIG_MAX_CPUS];       /* worker i on cpus[i % n_cpus] */
    uint64_t shm_size;               /* 2G */
    int shm_size_set;                /* shm_size is the file's; else the daemon
                                        takes at most half of /dev/shm's free
                                        space (engine_shm_default) */
    /* logging, process */
    char log_file[PATH_MAX];         /* "" = stderr */
    int log_level;                   /* LOG_LEVEL_INFO */
    char pidfile[PATH_MAX];          /* "" = none */
    /* connections */
    uint32_t max_clients;            /* 128 */
    uint32_t max_clients_per_uid;    /* 0 = auto: max_clients / 4, at least 1 */
    uint32_t client_timeout;         /* seconds, 30: hello, one frame, a stalled reply or upload */
    /* liveness and memory */
    uint32_t worker_stall_timeout;   /* seconds, 10: a busy worker without a heartbeat is
                                        replaced; 0 = never */
    uint64_t max_memory;             /* shared memory + results held; 0 = auto */
    /* large implicit jobs through mpirun ... vox_mpi (docs/mpi.md) */
    char mpi_hostfile[PATH_MAX];     /* "" = off: every job on the local engine */
    uint32_t mpi_min_res;            /* 1024: jobs of this res and above go to MPI */
    uint32_t mpi_ranks;              /* 2: mpirun -np */
    uint32_t mpi_workers;            /* 1: vox_mpi -w, workers per rank (0 = serial) */
    char mpirun[PATH_MAX];           /* "" = mpirun on the PATH */
    char mpirun_args[512];           /* CONFIG_MPIRUN_ARGS, split on blanks */
    char vox_mpi[PATH_MAX];          /* "" = vox_mpi beside voxd */
    /* the limits clients are told (HelloOk): one field per row of VOX_LIMITS
     * (vox_limits.h), with its name, type, default and range */
#define CONFIG_LIMIT_FIELD(name, type, def, min, max, unit, doc) type name;
    VOX_LIMITS(CONFIG_LIMIT_FIELD)
#undef CONFIG_LIMIT_FIELD
} voxd_config;

void config_defaults(voxd_config *c);
/* Defaults, then the file.  0, or -EINVAL with "FILE:LINE: reason" in err,
 * or -errno with "FILE: <strerror>" when the file cannot be read. */
int config_load(const char *path, voxd_config *c, err_info *err);
/* The same from an open stream; name is what messages call it. */
int config_load_stream(FILE *f, const char *name, voxd_config *c, err_info *err);
/* Every option, as a loadable file. */
void config_print(FILE *out, const voxd_config *c);

/* Effective values for the daemon. */
int config_workers(const voxd_config *c);          /* auto resolved, 1..256 */
/* max_memory, auto resolved: half the machine's memory, and at least
 * shm_size + CONFIG_RESULT_ROOM. */
uint64_t config_max_memory(const voxd_config *c);
int config_uid_allowed(const voxd_config *c, uid_t uid);
uint32_t config_clients_per_uid(const voxd_config *c); /* auto resolved */
void config_proto_limits(const voxd_config *c, proto_limits *lim);

#endif
