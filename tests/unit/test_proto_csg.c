/* The boundary validator on CSG jobs: a valid tree passes; children that come
 * later, arity and counts, depth and margin, names, primitives, leaves, stray
 * fields and numbers, the domain, res and source name are refused with their
 * code and message. */
#include <criterion/criterion.h>
#include <errno.h>
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "expr.h"
#include "frame.h"
#include "job_meta.h"
#include "proto_check.h"

#include "proto_fixture.h"

TestSuite(proto, .init = setup);

/* ---------------------------------------------------------------- CSG */

typedef struct {
    Voxd__Csg csg;
    Voxd__CsgNode node[4];
    Voxd__CsgNode *ptr[4];
    uint32_t kids[4][2];
    double center[3], size[3], rot[3];
    double dom[2];
} csg;

/* cuboid "base", ellipsoid "egg", difference(0, 1), inverse(2): valid. */
static void csg_init(csg *c, job *j)
{
    static const Voxd__Csg c0 = VOXD__CSG__INIT;
    static const Voxd__CsgNode n0 = VOXD__CSG_NODE__INIT;
    c->csg = c0;
    for (int i = 0; i < 4; i++) c->node[i] = n0, c->ptr[i] = &c->node[i];
    for (int a = 0; a < 3; a++) c->center[a] = 0.1 * a, c->size[a] = 1, c->rot[a] = 0.5;
    for (int i = 0; i < 2; i++) {
        c->node[i].op = VOXD__CSG_OP__CSG_PRIMITIVE;
        c->node[i].primitive = i ? VOXD__PRIMITIVE__PRIMITIVE_ELLIPSOID
                                 : VOXD__PRIMITIVE__PRIMITIVE_CUBOID;
        c->node[i].center = c->center, c->node[i].n_center = 3;
        c->node[i].size = c->size, c->node[i].n_size = 3;
    }
    c->node[0].rotate = c->rot, c->node[0].n_rotate = 3;
    c->node[0].name.data = (uint8_t *)"base", c->node[0].name.len = 4;
    c->node[1].name.data = (uint8_t *)"egg", c->node[1].name.len = 3;
    c->node[2].op = VOXD__CSG_OP__CSG_DIFFERENCE;
    c->kids[2][0] = 0, c->kids[2][1] = 1;
    c->node[2].children = c->kids[2], c->node[2].n_children = 2;
    c->node[3].op = VOXD__CSG_OP__CSG_INVERSE;
    c->kids[3][0] = 2;
    c->node[3].children = c->kids[3], c->node[3].n_children = 1;
    c->csg.nodes = c->ptr, c->csg.n_nodes = 4;
    c->dom[0] = -1, c->dom[1] = 2;
    c->csg.domain = c->dom, c->csg.n_domain = 2;
    c->csg.res = 128;
    job_init(j);
    j->sub.job_case = VOXD__SUBMIT__JOB_CSG, j->sub.csg = &c->csg;
    j->sub.channel = VOXD__CHANNEL__CHANNEL_UNSPECIFIED;
}

Test(proto, csg_a_valid_tree_passes)
{
    csg c;
    job j;
    csg_init(&c, &j);
    accepted(&j.req);
    j.sub.channel = VOXD__CHANNEL__CHANNEL_OCCUPANCY;
    accepted(&j.req);
    j.sub.channel = VOXD__CHANNEL__CHANNEL_DENSITY;
    accepted(&j.req);
    j.sub.channel = VOXD__CHANNEL__CHANNEL_SURFACE;
    accepted(&j.req);
    j.sub.channel = VOXD__CHANNEL__CHANNEL_DISTANCE; /* the pipeline decides the tree */
    accepted(&j.req);
    c.csg.band = 32; /* Csg.band: as Mesh.band */
    accepted(&j.req);
    c.csg.band = 33;
    refused(&j.req, INVALID, "band 33 is not from 1 to 32 voxels (or 0: 3)");
    c.csg.band = 2;
    j.sub.channel = VOXD__CHANNEL__CHANNEL_UNSPECIFIED; /* the default, density */
    refused(&j.req, INVALID, "band 2 is for channel distance");
    j.sub.channel = VOXD__CHANNEL__CHANNEL_OCCUPANCY;
    refused(&j.req, INVALID, "band 2 is for channel distance");
    csg_init(&c, &j);
    j.sub.input_bytes = 10;
    refused(&j.req, INVALID, "the CSG leaves' data_bytes add up to 0, the job declares 10 "
                             "bytes of input");
}

Test(proto, csg_child_must_be_earlier)
{
    csg c;
    job j;
    csg_init(&c, &j);
    c.kids[3][0] = 3; /* itself */
    refused(&j.req, INVALID, "CSG node 3 refers to node 3, which is not earlier");
    c.kids[3][0] = 5;
    refused(&j.req, INVALID, "CSG node 3 refers to node 5, which is not earlier");
    c.kids[3][0] = 0xFFFFFFFFu;
    refused(&j.req, INVALID, "refers to node 4294967295");
}

Test(proto, csg_arity_ops_and_counts)
{
    csg c;
    job j;
    csg_init(&c, &j);
    c.node[2].n_children = 1;
    refused(&j.req, INVALID, "CSG node 2 (difference) needs 2 children, got 1");
    csg_init(&c, &j);
    c.node[0].n_children = 1, c.node[0].children = c.kids[2];
    refused(&j.req, INVALID, "CSG node 0 ('base') (primitive) needs 0 children, got 1");
    csg_init(&c, &j);
    c.node[1].op = VOXD__CSG_OP__CSG_OP_UNSPECIFIED;
    refused(&j.req, INVALID, "CSG node 1 ('egg') has no op");
    c.node[1].op = (Voxd__CsgOp)5; /* a hole in the numbering */
    refused(&j.req, INVALID, "CSG node 1 ('egg') has unknown op 5");
    c.node[1].op = (Voxd__CsgOp)99;
    refused(&j.req, INVALID, "CSG node 1 ('egg') has unknown op 99");
    csg_init(&c, &j);
    c.csg.n_nodes = 0;
    refused(&j.req, INVALID, "CSG job has no nodes");
    c.csg.n_nodes = 4, lim.max_csg_nodes = 3;
    refused(&j.req, LIMIT, "CSG job has 4 nodes, over this server's max_csg_nodes of 3");
}

Test(proto, csg_huge_node_list)
{
    csg c;
    job j;
    csg_init(&c, &j);
    size_t n = 200000;
    Voxd__CsgNode **many = calloc(n, sizeof *many);
    for (size_t i = 0; i < n; i++) many[i] = &c.node[0];
    c.csg.nodes = many, c.csg.n_nodes = n;
    refused(&j.req, LIMIT, "CSG job has 200000 nodes, over this server's max_csg_nodes of 256");
    free(many);
}

/* A chain of inverses: its depth against max_csg_depth; dilations along
 * it against the evaluator's margin. */
Test(proto, csg_depth_and_margin)
{
    csg c;
    job j;
    csg_init(&c, &j);
    lim.max_csg_depth = 3; /* egg or base, difference, inverse: 3 */
    accepted(&j.req);
    lim.max_csg_depth = 2;
    refused(&j.req, LIMIT, "CSG node 3: the tree is deeper than this server's max_csg_depth of 2");

    setup();
    enum { N = 10 };
    Voxd__CsgNode nodes[N], *ptrs[N];
    uint32_t kids[N];
    for (int i = 0; i < N; i++) {
        nodes[i] = (Voxd__CsgNode)VOXD__CSG_NODE__INIT;
        ptrs[i] = &nodes[i];
        if (i == 0) {
            nodes[0] = c.node[0];
            continue;
        }
        kids[i] = (uint32_t)i - 1;
        nodes[i].op = VOXD__CSG_OP__CSG_DILATE;
        nodes[i].children = &kids[i], nodes[i].n_children = 1;
        nodes[i].k = 8;
    }
    c.csg.nodes = ptrs, c.csg.n_nodes = N;
    refused(&j.req, INVALID, "CSG node 9: erosions and dilations along one path pass 64 voxels");
    c.csg.n_nodes = 9; /* 8 x 8 = 64 */
    accepted(&j.req);
}

Test(proto, csg_names)
{
    csg c;
    job j;
    csg_init(&c, &j);
    c.node[0].name.data = (uint8_t *)"1st", c.node[0].name.len = 3;
    refused(&j.req, INVALID, "CSG node 0's name has a byte 0x31 at offset 0");
    c.node[0].name.data = (uint8_t *)"a\nb", c.node[0].name.len = 3;
    refused(&j.req, INVALID, "CSG node 0's name has a byte 0x0a at offset 1");
    c.node[0].name.data = (uint8_t *)"abcdefghijabcdefghijabcdefghijab", c.node[0].name.len = 32;
    refused(&j.req, INVALID, "CSG node 0's name is 32 bytes, limit 31");
}

Test(proto, csg_primitives)
{
    csg c;
    job j;
    csg_init(&c, &j);
    c.node[1].primitive = (Voxd__Primitive)9;
    refused(&j.req, INVALID, "CSG node 1 ('egg') has unknown primitive 9");
    csg_init(&c, &j);
    c.node[0].n_size = 2;
    refused(&j.req, INVALID, "CSG node 0 ('base') needs 3 values for its size, got 2");
    csg_init(&c, &j);
    c.node[0].n_size = 0;
    refused(&j.req, INVALID, "needs 3 values for its size, got 0");
    csg_init(&c, &j);
    c.size[1] = 0;
    refused(&j.req, INVALID, "CSG node 0 ('base')'s size must be positive, value 2 is 0");
    csg_init(&c, &j);
    c.center[2] = INFINITY;
    refused(&j.req, INVALID, "CSG node 0 ('base')'s center value 3 is inf");
    csg_init(&c, &j);
    c.rot[0] = 1e300;
    refused(&j.req, INVALID, "'s rotation value 1 is 1e+300, not a finite number");
    csg_init(&c, &j);
    c.node[1].n_center = 0, c.node[1].n_rotate = 0; /* both may be left out */
    accepted(&j.req);
    c.node[1].axis = VOXD__AXIS__AXIS_X;
    refused(&j.req, INVALID, "CSG node 1 ('egg'): only a cylinder or a cone has an axis");
    c.node[1].primitive = VOXD__PRIMITIVE__PRIMITIVE_CONE;
    accepted(&j.req);
    c.node[1].axis = (Voxd__Axis)7;
    refused(&j.req, INVALID, "CSG node 1 ('egg') has unknown axis 7");
}

Test(proto, csg_implicit_mesh_and_vod_leaves)
{
    csg c;
    job j;
    csg_init(&c, &j);
    c.node[1] = (Voxd__CsgNode)VOXD__CSG_NODE__INIT;
    c.node[1].op = VOXD__CSG_OP__CSG_IMPLICIT;
    refused(&j.req, INVALID, "CSG node 1's expression is empty");
    c.node[1].source.data = (uint8_t *)"x\0y", c.node[1].source.len = 3;
    refused(&j.req, INVALID, "CSG node 1's expression source contains a NUL byte at offset 1");
    c.node[1].source.len = 1;
    accepted(&j.req);
    c.node[1].domain = c.dom, c.node[1].n_domain = 2;
    accepted(&j.req);
    c.node[1].n_domain = 6;
    refused(&j.req, INVALID, "CSG node 1's domain needs 2 values (or none), got 6");
    c.node[1].n_domain = 2, c.dom[1] = -3;
    refused(&j.req, INVALID, "CSG node 1's domain: low -1 is not below high -3");
    c.dom[1] = 2;
    lim.max_expr_bytes = 0;
    refused(&j.req, LIMIT, "CSG node 1's expression is 1 bytes, limit 0");

    setup();
    c.node[1] = (Voxd__CsgNode)VOXD__CSG_NODE__INIT;
    c.node[1].op = VOXD__CSG_OP__CSG_MESH;
    refused(&j.req, INVALID, "CSG node 1: a mesh leaf needs its file's data");
    c.node[1].op = VOXD__CSG_OP__CSG_VOD;
    refused(&j.req, INVALID, "CSG node 1: a vod leaf needs its file's data");
    c.node[1].data.data = (uint8_t *)"0123456789", c.node[1].data.len = 10;
    accepted(&j.req);
    c.node[1].scale = 2;
    refused(&j.req, INVALID, "CSG node 1 (vod) does not take a mesh's fit or scale");
    c.node[1].op = VOXD__CSG_OP__CSG_MESH;
    accepted(&j.req);
    c.node[1].scale = -1;
    refused(&j.req, INVALID, "CSG node 1's scale is -1: 0 (none) or a positive number");
    c.node[1].scale = 0;
    c.node[1].fit = c.center, c.node[1].n_fit = 2;
    refused(&j.req, INVALID, "CSG node 1 needs 3 values for its fit, got 2");
    c.node[1].n_fit = 3;
    accepted(&j.req);
    lim.max_csg_leaf_bytes = 9;
    refused(&j.req, LIMIT, "the CSG job's leaves are 10 bytes, over this server's "
                           "max_csg_leaf_bytes of 9");
    setup();
    c.node[2].data.data = (uint8_t *)"x", c.node[2].data.len = 1;
    refused(&j.req, INVALID, "CSG node 2 (difference) does not take a file's data");
    c.node[2].data.len = 0, c.node[2].data_bytes = 1;
    refused(&j.req, INVALID, "CSG node 2 (difference) does not take a file's data");
    c.node[2].data_bytes = 0;

    /* The leaves' files as the job's input: sizes in the nodes, adding up. */
    c.node[1].fit = NULL, c.node[1].n_fit = 0;
    c.node[1].data.len = 0, c.node[1].data_bytes = 1000;
    refused(&j.req, INVALID, "CSG node 1 has data_bytes but the job declares no input_bytes");
    j.sub.input_bytes = 999;
    refused(&j.req, INVALID, "data_bytes add up to 1000, the job declares 999 bytes of input");
    j.sub.input_bytes = 1000;
    accepted(&j.req);
    c.node[1].data.len = 10;
    refused(&j.req, INVALID, "CSG node 1: its file comes inline or as input (data_bytes), not both");
    c.node[1].data.len = 0;
    lim.max_csg_leaf_bytes = 999;
    refused(&j.req, LIMIT, "CSG node 1's file is 1000 bytes, over this server's max_csg_leaf_bytes of 999");
}

Test(proto, csg_stray_fields_and_numbers)
{
    csg c;
    job j;
    csg_init(&c, &j);
    c.node[2].source.data = (uint8_t *)"x", c.node[2].source.len = 1;
    refused(&j.req, INVALID, "CSG node 2 (difference) does not take an expression or its domain");
    csg_init(&c, &j);
    c.node[3].n_size = 3, c.node[3].size = c.size;
    refused(&j.req, INVALID, "CSG node 3 (inverse) does not take a primitive's fields");
    csg_init(&c, &j);
    c.node[0].scalar = NAN;
    refused(&j.req, INVALID, "CSG node 0 ('base') (primitive) does not take a scalar");
    csg_init(&c, &j);
    c.node[3].k = 2;
    refused(&j.req, INVALID, "CSG node 3 (inverse) does not take k");

    csg_init(&c, &j);
    c.node[2].op = VOXD__CSG_OP__CSG_DIVIDE;
    refused(&j.req, INVALID, "CSG node 2 (divide) needs a scalar S_L in (0, 1], got 0");
    c.node[2].scalar = 1.5;
    refused(&j.req, INVALID, "got 1.5");
    c.node[2].scalar = NAN;
    refused(&j.req, INVALID, "got nan");
    c.node[2].scalar = 0.5;
    accepted(&j.req);

    csg_init(&c, &j);
    c.node[3].op = VOXD__CSG_OP__CSG_SCALAR_MUL;
    c.node[3].scalar = INFINITY;
    refused(&j.req, INVALID, "CSG node 3 needs a finite scalar, got inf");
    c.node[3].scalar = -3;
    accepted(&j.req);
    c.node[3].scalar = 0;
    c.node[3].op = VOXD__CSG_OP__CSG_ERODE;
    refused(&j.req, INVALID, "CSG node 3 needs k of 1..16 voxels, got 0");
    c.node[3].k = 17;
    refused(&j.req, INVALID, "got 17");
    c.node[3].k = 16;
    accepted(&j.req);
}

Test(proto, csg_domain_res_and_name)
{
    csg c;
    job j;
    csg_init(&c, &j);
    c.csg.n_domain = 0;
    refused(&j.req, INVALID, "domain needs 2 or 6 values, got 0");
    csg_init(&c, &j);
    c.csg.res = 100000;
    refused(&j.req, LIMIT, "res 100000 is over this server's limit of 4096");
    csg_init(&c, &j);
    c.csg.source_name.data = (uint8_t *)"a\nb", c.csg.source_name.len = 3;
    refused(&j.req, INVALID, "source_name contains a line break at offset 1");
}
