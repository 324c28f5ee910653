/* suggest — "did you mean": the name of a list nearest to a mistyped one,
 * by edit distance with transpositions (optimal string alignment: "outptu"
 * is one step from "output"), when close enough to be a slip. */
#ifndef VOXD_SUGGEST_H
#define VOXD_SUGGEST_H

#include <stddef.h>

/* The first n bytes of word against names (NULL-terminated): the nearest
 * name one edit away, or two for a name of 7 bytes or more; NULL when none
 * is that close. */
const char *suggest_nearest(const char *word, size_t n, const char *const names[]);

#endif
