/* The evaluator's state (csg_eval.c), shared with the distance channel's
 * evaluation (csg_deval.c); private to csg/. */
#ifndef VOXD_CSG_EVAL_INT_H
#define VOXD_CSG_EVAL_INT_H

#include "csg.h"

struct csg_eval {
    const csg_tree *t;
    grid_spec g;
    uint32_t side;
    const vod_volume *leaf[CSG_MAX_NODES]; /* mesh and vod leaves' volumes */
    expr_tape *tape[CSG_MAX_NODES];
    expr_vm *vm[CSG_MAX_NODES];
    /* Binary operators: the table op(a, b), and for each value of one
     * operand the result it forces whatever the other, or -1. */
    uint8_t *lut[CSG_MAX_NODES];
    int16_t *force_a[CSG_MAX_NODES], *force_b[CSG_MAX_NODES];
    /* implicit leaves: 1 when expr_vm_ival_grad knows the tape's ops */
    uint8_t igrad[CSG_MAX_NODES];
    /* primitive and implicit leaves' values over the whole brick that
     * eval_in_cubes is evaluating (-1: not uniform there, or no brick) */
    int16_t known[CSG_MAX_NODES];
    csg_stats st;
    int has_morph;      /* erode or dilate in the tree: bricks are evaluated whole */
    /* operands' scratch, taken and given back last in first out (scratch_take) */
    uint8_t *arena;
    size_t arena_top, arena_cap;
    /* channel 4 (csg_deval.c): each implicit leaf's distance, made at its
     * first brick, and one brick of floats per level of the tree */
    csg_dist *dist[CSG_MAX_NODES];
    float *dscratch[CSG_MAX_DEPTH + 1];
    float dwidth;       /* the band's width W (world units), 0 until the first brick */
};

/* Channel 4's brick b into vol (csg_eval_store); buf: side^3 floats. */
int csg_deval_store(csg_eval *e, vod_volume *vol, const uint32_t b[3], void *buf);
/* What csg_deval_store made (csg_eval_free calls it). */
void csg_deval_free(csg_eval *e);

#endif
