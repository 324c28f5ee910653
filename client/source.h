/* source — a job's expression source: from --expr or a .vx file, with the
 * file's "#@ key value" directives (defaults the command line overrides). */
#ifndef VOXD_SOURCE_H
#define VOXD_SOURCE_H

#include <stddef.h>

#include "expr.h"

typedef struct {
    char *text;        /* the expression source, NUL-terminated */
    size_t len;
    const char *name;  /* file path, or "<expr>" */
    const char *path;  /* file path, or NULL for --expr */
    int has_domain;    /* a "#@ domain" directive was found */
    double lo[3], hi[3];
} source;

/* Load from a file (path) or a string (expr); exactly one is non-NULL.
 * Prints a message and returns a negative errno on failure. */
int source_load(source *s, const char *path, const char *expr);
void source_free(source *s);
/* Compile, printing "name:line:col: message" with the line and a caret. */
int source_compile(const source *s, const expr_limits *lim, expr_tape **out);

#endif
