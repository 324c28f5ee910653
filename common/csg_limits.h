/* csg_limits — a CSG tree's fixed bounds: what the evaluator (csg/csg.h)
 * is built for and the protocol's check (proto/proto_check.h) refuses
 * beyond, defined once for both. */
#ifndef VOXD_CSG_LIMITS_H
#define VOXD_CSG_LIMITS_H

#define CSG_MAX_NODES 256u       /* nodes in a tree */
#define CSG_MAX_MORPH 16u        /* k of one erode / dilate */
#define CSG_MAX_MARGIN 64u       /* sum of the k along any path */
#define CSG_NAME_MAX 32u         /* bytes of a node name, NUL included */

#endif
