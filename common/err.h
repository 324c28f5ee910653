/* err — the project's error: a negative errno, which every call that fails
 * returns, and a message for the user, of bounded length.
 *
 * A module's error structure is an err_info (a typed kind beside the
 * errno where the module has one, e.g. the protocol's error code), and its
 * messages are written by err_set, which returns the code, so that a
 * failure reads `return err_set(err, -EINVAL, "...", ...);`.  A call that
 * can fail takes an `err_info *err` (NULL: no message wanted) and returns
 * the negative errno: grid_make, config_load, shm_create, engine_create,
 * mesh_vox_check, vod/'s reader and writer (vod.h) and the rest.  Not
 * converted yet (they still take `char *err, size_t errlen` and write it
 * with err_fmt): export_vdb and the vdb_out plugin's table, csg/'s leaf
 * builders (mpi_subtree.c passes csg_leaves_build its err_info's message
 * and keeps its code), csg_dist_check and daemon_csg_tree.  A formatter
 * that keeps state of its own (a position, the first failure only) calls
 * err_vfmt.
 *
 * engine_error is one (its kind an engine_failure), and so is the error of
 * engine_result and engine_pipeline_report; the structures that carry a
 * position (mesh_error, expr_error, csg_error) keep their own buffer sizes,
 * their messages being part of what users see. */
#ifndef VOXD_ERR_H
#define VOXD_ERR_H

#include <stdarg.h>
#include <stddef.h>

#define ERR_MSG_MAX 256

typedef struct {
    int code;               /* a negative errno; 0: no error */
    int kind;               /* the module's typed kind, where it has one; 0 none */
    char msg[ERR_MSG_MAX];  /* "res 5000 is over this server's limit of 4096" */
} err_info;

/* fmt into buf (nothing when buf is NULL or len 0); code returned. */
__attribute__((format(printf, 4, 0)))
int err_vfmt(char *buf, size_t len, int code, const char *fmt, va_list ap);
__attribute__((format(printf, 4, 5)))
int err_fmt(char *buf, size_t len, int code, const char *fmt, ...);
/* e's code and message (its kind as it was); code returned.  e may be NULL. */
__attribute__((format(printf, 3, 4)))
int err_set(err_info *e, int code, const char *fmt, ...);
/* e as after no error: code 0, message "" (its kind as it was); e may be
 * NULL.  For a call that says "no message" by an empty one (vod_read). */
void err_clear(err_info *e);

#endif
