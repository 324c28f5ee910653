/* csg_pack — a CSG tree with its file leaves' bytes as one buffer (vox_mpi's
 * broadcast, voxd's job file for vox_mpi) and back (csg_pack.c). */
#ifndef VOXD_CSG_PACK_H
#define VOXD_CSG_PACK_H

#include <stddef.h>
#include <stdint.h>

#include "csg.h"

/* t as one buffer (malloc'd) in *out, *len bytes.  0 or -ENOMEM. */
int csg_tree_pack(const csg_tree *t, uint8_t **out, size_t *len);
/* The tree packed in buf, checked (counts, lengths, children below their
 * parent, text references inside the text, every file leaf with bytes):
 * 0 and *out (csg_tree_free), -EPROTO when it is not a packed tree,
 * -ENOMEM. */
int csg_tree_unpack(const uint8_t *buf, size_t len, csg_tree **out);

#endif
