/* err — the project's error: a negative errno, which every call that fails
 * returns, and a message for the user, of bounded length.
 *
 * A module's error structure is an err_info (a typed kind beside the
 * errno where the module has one, e.g. the engine's engine_failure), and
 * its messages are written by err_set, which returns the code, so that a
 * failure reads `return err_set(err, -EINVAL, "...", ...);`.  A call that
 * can fail takes an `err_info *err` (NULL: no message wanted, unless its
 * header says otherwise) and returns the negative errno: grid_make,
 * config_load, shm_create, engine_create, mesh_vox_check, vod/'s reader and
 * writer, csg/'s leaf builders and csg_dist_check, export_vdb and the
 * vdb_out module's table (which fills the err_info itself: the module does
 * not link this file).
 *
 * engine_error is one (its kind an engine_failure), and so is the error of
 * engine_result and engine_pipeline_report.  The errors that carry a
 * position, mesh_error, expr_error and csg_error, are an err_info and their
 * position: ERR_INFO_EMBED puts it first, as `info` for err_set and
 * err_vset and by its members' names (e.msg).
 *
 * Still a char buffer, with a reason: daemon_submit_build and
 * daemon_csg_tree write a protocol Error's text in 300 bytes (a node, its
 * expression's position and the compiler's message: longer than
 * ERR_MSG_MAX), daemon_memory_room returns a protocol code, not an errno;
 * proto_error (proto/proto_check.h) carries the protocol's code in place
 * of an errno.
 *
 * Formatters of their own that remain, each for state err_set does not
 * keep: mesh_build_fail (a line or byte offset), expr_set_error and
 * csg_parse.c's fail/fail_at (a line and column, the node), config.c's
 * fail_at (the file and line first), engine_sched_fail (the first failure
 * only, and the way to raise shared memory), engine_pipeline_fail (the
 * kind), proto_bad (the protocol's code); daemon_client.c's upload_fail and
 * refuse format a protocol Error and fail the job or close the connection;
 * libvox_set_error and libvox_fail fill libvox's public vox_error. */
#ifndef VOXD_ERR_H
#define VOXD_ERR_H

#include <stdarg.h>
#include <stddef.h>

#define ERR_MSG_MAX 256

/* err_info's members: code, a negative errno (0: no error); kind, the
 * module's typed kind where it has one (0: none); msg, the message ("res
 * 5000 is over this server's limit of 4096"). */
#define ERR_INFO_MEMBERS \
    int code;            \
    int kind;            \
    char msg[ERR_MSG_MAX]

typedef struct {
    ERR_INFO_MEMBERS;
} err_info;

/* An err_info inside an error that adds fields of its own (a position):
 * the err_info `name`, for err_set and err_vset, and the same bytes by
 * their members' names (e->msg), as Linux's struct_group does.  First in
 * its structure. */
#define ERR_INFO_EMBED(name) \
    union {                  \
        err_info name;       \
        struct {             \
            ERR_INFO_MEMBERS;\
        };                   \
    }

/* fmt into buf (nothing when buf is NULL or len 0); code returned. */
__attribute__((format(printf, 4, 0)))
int err_vfmt(char *buf, size_t len, int code, const char *fmt, va_list ap);
__attribute__((format(printf, 4, 5)))
int err_fmt(char *buf, size_t len, int code, const char *fmt, ...);
/* e's code and message (its kind as it was); code returned.  e may be NULL. */
__attribute__((format(printf, 3, 4)))
int err_set(err_info *e, int code, const char *fmt, ...);
/* err_set from a va_list: for a formatter that adds state of its own. */
__attribute__((format(printf, 3, 0)))
int err_vset(err_info *e, int code, const char *fmt, va_list ap);
/* e as after no error: code 0, message "" (its kind as it was); e may be
 * NULL.  For a call that says "no message" by an empty one (vod_read). */
void err_clear(err_info *e);

#endif
