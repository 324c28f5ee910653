/* The parsers of what a client sends when memory runs out: every
 * allocation of expr_compile, csg_parse, mesh_parse (every format, on one
 * thread and on several), mesh_load and mesh_gltf_embed of a .gltf naming
 * its buffer's file, the daemon's intake of a CSG job (its frame unpacked,
 * checked, the tree built) and config_load_stream fails in turn
 * (alloc_fail.h).  Each run gives the whole answer or -ENOMEM with "out of
 * memory" in its message and nothing handed back, and frees every block
 * it allocated. */
#include <criterion/criterion.h>
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <unistd.h>

#include "alloc_fail.h"
#include "config.h"
#include "csg.h"
#include "daemon.h"
#include "expr.h"
#include "frame.h"
#include "mesh.h"
#include "mesh_shapes.h"
#include "proto_check.h"

/* ---- expressions ---- */

static const char blend[] = "m = 44;\n"
                            "a = sqrt((x+0.3)^2 + y^2 + z^2) - 0.5;\n"
                            "b = sqrt((x-0.3)^2 + y^2 + z^2) - 0.5;\n"
                            "-log(exp(-m*a) + exp(-m*b)) / m + min(a, b) * 0 + "
                            "max(abs(x) - 1, abs(y) - 1, abs(z) - 1) * 0";

static int compile_once(void *ctx, char *msg)
{
    size_t *want = ctx;
    expr_tape *t = (expr_tape *)1;
    expr_error err = {0};
    int rc = expr_compile(blend, strlen(blend), NULL, &t, &err);
    memcpy(msg, err.msg, sizeof err.msg);
    if (rc) {
        cr_assert_null(t, "a failed compile handed back a tape");
        return rc;
    }
    cr_assert_eq(expr_tape_bytes(t), *want, "a tape of %zu bytes, want %zu",
                 expr_tape_bytes(t), *want);
    expr_tape_free(t);
    return 0;
}

Test(parse_alloc, an_expression_compiles_or_fails_cleanly)
{
    expr_tape *t;
    expr_error err = {0};
    cr_assert_eq(expr_compile(blend, strlen(blend), NULL, &t, &err), 0, "%s", err.msg);
    size_t want = expr_tape_bytes(t);
    expr_tape_free(t);
    cr_assert_geq(alloc_fail_each(compile_once, &want, "expr_compile"), 5);
}

/* ---- CSG trees ---- */

static const char tree[] =
    "block = cuboid center 0,0,-0.1 size 1.6,1.0,0.6\n"
    "boss  = cylinder center 0,0,0.3 radius 0.35 height 0.4 axis z\n"
    "bore  = cylinder center 0,0,0 radius 0.18 height 2 axis z\n"
    "ball  = implicit \"sqrt(x^2 + y^2 + z^2) - 0.4\"\n"
    "blob  = implicit \"x^2 + 2*y^2 + 3*z^2 - 0.2\" domain -1,1\n"
    "part  = difference(difference(union(union(block, boss), blob), bore), ball)\n"
    "result part\n";

static int csg_once(void *ctx, char *msg)
{
    const csg_tree *want = ctx;
    csg_tree *t = (csg_tree *)1;
    csg_error err = {0};
    int rc = csg_parse(tree, strlen(tree), &t, &err);
    memcpy(msg, err.msg, sizeof err.msg);
    if (rc) {
        cr_assert_null(t, "a failed parse handed back a tree");
        return rc;
    }
    cr_assert_eq(t->n, want->n);
    cr_assert_eq(t->text_len, want->text_len);
    cr_assert_eq(memcmp(t->text, want->text, t->text_len), 0);
    csg_tree_free(t);
    return 0;
}

Test(parse_alloc, a_csg_tree_parses_or_fails_cleanly)
{
    csg_tree *want;
    csg_error err = {0};
    cr_assert_eq(csg_parse(tree, strlen(tree), &want, &err), 0, "%s", err.msg);
    cr_assert_geq(alloc_fail_each(csg_once, want, "csg_parse"), 2);
    csg_tree_free(want);
}

/* ---- meshes ---- */

/* A closed mesh's bytes in one format. */
typedef struct {
    char *p;
    size_t n, cap;
} text;

static void add(text *t, const void *p, size_t n)
{
    if (t->n + n > t->cap) {
        t->cap = (t->n + n) * 2;
        t->p = realloc(t->p, t->cap);
        cr_assert(t->p);
    }
    memcpy(t->p + t->n, p, n);
    t->n += n;
}

static void addf(text *t, const char *fmt, ...) __attribute__((format(printf, 2, 3)));
static void addf(text *t, const char *fmt, ...)
{
    char line[1024];
    va_list ap;
    va_start(ap, fmt);
    int n = vsnprintf(line, sizeof line, fmt, ap);
    va_end(ap);
    cr_assert(n > 0 && (size_t)n < sizeof line);
    add(t, line, (size_t)n);
}

typedef enum { OBJ, OFF, PLY_ASCII, PLY_BINARY, STL_ASCII, STL_BINARY, GLTF, GLB } form;
static const char *const form_name[] = {"OBJ",       "OFF",        "PLY ascii", "PLY binary",
                                        "STL ascii", "STL binary", "glTF",      "GLB"};

static void put_f32le(text *t, float x)
{
    add(t, &x, 4); /* x86-64 and the other targets here are little endian */
}

static void put_u32le(text *t, uint32_t x)
{
    add(t, &x, 4);
}

static void write_stl(text *t, const mesh *m, bool binary)
{
    if (!binary) addf(t, "solid s\n");
    else {
        char head[80] = "binary";
        add(t, head, sizeof head);
        put_u32le(t, m->n_triangles);
    }
    for (uint32_t i = 0; i < m->n_triangles; i++) {
        if (!binary) addf(t, "facet normal 0 0 0\nouter loop\n");
        else for (int k = 0; k < 3; k++) put_f32le(t, 0);
        for (int k = 0; k < 3; k++) {
            const float *v = m->vertices[m->triangles[i][k]];
            if (!binary) addf(t, "vertex %.9g %.9g %.9g\n", v[0], v[1], v[2]);
            else for (int a = 0; a < 3; a++) put_f32le(t, v[a]);
        }
        if (!binary) addf(t, "endloop\nendfacet\n");
        else add(t, "\0\0", 2);
    }
    if (!binary) addf(t, "endsolid s\n");
}

static void write_ply(text *t, const mesh *m, bool binary)
{
    addf(t, "ply\nformat %s 1.0\nelement vertex %u\nproperty float x\nproperty float y\n"
         "property float z\nelement face %u\nproperty list uchar int vertex_indices\n"
         "end_header\n", binary ? "binary_little_endian" : "ascii", m->n_vertices,
         m->n_triangles);
    for (uint32_t i = 0; i < m->n_vertices; i++) {
        const float *v = m->vertices[i];
        if (!binary) addf(t, "%.9g %.9g %.9g\n", v[0], v[1], v[2]);
        else for (int a = 0; a < 3; a++) put_f32le(t, v[a]);
    }
    for (uint32_t i = 0; i < m->n_triangles; i++) {
        const uint32_t *c = m->triangles[i];
        if (!binary) addf(t, "3 %u %u %u\n", c[0], c[1], c[2]);
        else {
            add(t, "\3", 1);
            for (int k = 0; k < 3; k++) put_u32le(t, c[k]);
        }
    }
}

/* The mesh's buffer: positions (f32 VEC3), then indices (u32). */
static text gltf_buffer(const mesh *m)
{
    text b = {0};
    for (uint32_t i = 0; i < m->n_vertices; i++)
        for (int a = 0; a < 3; a++) put_f32le(&b, m->vertices[i][a]);
    for (uint32_t i = 0; i < m->n_triangles; i++)
        for (int k = 0; k < 3; k++) put_u32le(&b, m->triangles[i][k]);
    return b;
}

static void add_base64(text *t, const text *b)
{
    static const char a[] = "ABCDEFGHIJKLMNOPQRSTUVWXYZabcdefghijklmnopqrstuvwxyz0123456789+/";
    const unsigned char *d = (const unsigned char *)b->p;
    for (size_t i = 0; i < b->n; i += 3) {
        unsigned v = (unsigned)d[i] << 16 | (i + 1 < b->n ? (unsigned)d[i + 1] << 8 : 0) |
                     (i + 2 < b->n ? d[i + 2] : 0);
        char q[4] = {a[v >> 18], a[v >> 12 & 63], i + 1 < b->n ? a[v >> 6 & 63] : '=',
                     i + 2 < b->n ? a[v & 63] : '='};
        add(t, q, 4);
    }
}

/* A .gltf with the buffer embedded (a data: URI; bin NULL), or naming a
 * file (bin: the name, the file written into folder dir), or a .glb
 * holding it (glb). */
static void write_gltf_as(text *t, const mesh *m, bool glb, const char *dir, const char *bin)
{
    text b = gltf_buffer(m), json = {0};
    size_t pos = (size_t)m->n_vertices * 12;
    addf(&json, "{\"asset\": {\"version\": \"2.0\"}, \"scene\": 0, \"scenes\": [{\"nodes\": "
         "[0]}], \"nodes\": [{\"mesh\": 0}], \"meshes\": [{\"primitives\": [{\"attributes\": "
         "{\"POSITION\": 0}, \"indices\": 1}]}], \"buffers\": [{\"byteLength\": %zu", b.n);
    if (bin) {
        char path[512];
        snprintf(path, sizeof path, "%s/%s", dir, bin);
        FILE *f = fopen(path, "wb");
        cr_assert(f && fwrite(b.p, 1, b.n, f) == b.n && !fclose(f), "%s", path);
        addf(&json, ", \"uri\": \"%s\"", bin);
    } else if (!glb) {
        addf(&json, ", \"uri\": \"data:application/octet-stream;base64,");
        add_base64(&json, &b);
        add(&json, "\"", 1);
    }
    addf(&json, "}], \"bufferViews\": [{\"buffer\": 0, \"byteLength\": %zu}, {\"buffer\": 0, "
         "\"byteOffset\": %zu, \"byteLength\": %zu}], ", pos, pos, b.n - pos);
    addf(&json, "\"accessors\": [{\"bufferView\": 0, \"componentType\": 5126, \"count\": %u, "
         "\"type\": \"VEC3\"}, {\"bufferView\": 1, \"componentType\": 5125, \"count\": %u, "
         "\"type\": \"SCALAR\"}]}", m->n_vertices, 3 * m->n_triangles);
    if (!glb) add(t, json.p, json.n);
    else {
        while (json.n % 4) add(&json, " ", 1);
        uint32_t head[5] = {0x46546C67u, 2, (uint32_t)(28 + json.n + b.n), (uint32_t)json.n,
                            0x4E4F534Au}; /* "glTF", version 2, length; "JSON" */
        add(t, head, sizeof head);
        add(t, json.p, json.n);
        uint32_t chunk[2] = {(uint32_t)b.n, 0x004E4942u}; /* "BIN" */
        add(t, chunk, sizeof chunk);
        add(t, b.p, b.n);
    }
    free(json.p);
    free(b.p);
}

static void write_gltf(text *t, const mesh *m, bool glb)
{
    write_gltf_as(t, m, glb, NULL, NULL);
}

static text write_mesh(const mesh *m, form f)
{
    text t = {0};
    if (f == GLTF || f == GLB) write_gltf(&t, m, f == GLB);
    else if (f == STL_ASCII || f == STL_BINARY) write_stl(&t, m, f == STL_BINARY);
    else if (f == PLY_ASCII || f == PLY_BINARY) write_ply(&t, m, f == PLY_BINARY);
    else {
        if (f == OFF) addf(&t, "OFF\n%u %u 0\n", m->n_vertices, m->n_triangles);
        for (uint32_t i = 0; i < m->n_vertices; i++)
            addf(&t, f == OBJ ? "v %.9g %.9g %.9g\n" : "%.9g %.9g %.9g\n", m->vertices[i][0],
                 m->vertices[i][1], m->vertices[i][2]);
        for (uint32_t i = 0; i < m->n_triangles; i++) {
            const uint32_t *c = m->triangles[i];
            if (f == OBJ) addf(&t, "f %u %u %u\n", c[0] + 1, c[1] + 1, c[2] + 1);
            else addf(&t, "3 %u %u %u\n", c[0], c[1], c[2]);
        }
    }
    return t;
}

typedef struct {
    text in;
    const char *what;
    mesh want;
} mesh_case;

static int mesh_once(void *ctx, char *msg)
{
    const mesh_case *c = ctx;
    mesh m;
    mesh_error err = {0};
    int rc = mesh_parse(c->in.p, c->in.n, MESH_FORMAT_AUTO, NULL, &m, &err);
    memcpy(msg, err.msg, sizeof err.msg);
    if (rc) return rc;
    cr_assert(m.n_vertices == c->want.n_vertices && m.n_triangles == c->want.n_triangles,
              "%s: %u vertices, %u triangles; want %u, %u", c->what, m.n_vertices,
              m.n_triangles, c->want.n_vertices, c->want.n_triangles);
    cr_assert_eq(memcmp(m.triangles, c->want.triangles, m.n_triangles * sizeof *m.triangles), 0,
                 "%s: other triangles", c->what);
    cr_assert_eq(memcmp(m.vertices, c->want.vertices, m.n_vertices * sizeof *m.vertices), 0,
                 "%s: other vertices", c->what);
    mesh_free(&m);
    return 0;
}

/* The icosphere of `level` in each form, parsed with each allocation
 * failing in turn. */
static void meshes_parse_or_fail_cleanly(int level)
{
    shape s;
    shape_init(&s);
    shape_icosphere(&s, (const double[3]){0.1, -0.2, 0.3}, 0.8, level, false);
    const mesh *ico = shape_finish(&s);
    for (form f = OBJ; f <= GLB; f++) {
        mesh_case c = {write_mesh(ico, f), form_name[f], {0}};
        mesh_error err = {0};
        cr_assert_eq(mesh_parse(c.in.p, c.in.n, MESH_FORMAT_AUTO, NULL, &c.want, &err), 0,
                     "%s: %s", c.what, err.msg);
        cr_assert_eq(c.want.n_triangles, ico->n_triangles, "%s", c.what);
        cr_assert_geq(alloc_fail_each(mesh_once, &c, c.what), 2, "%s", c.what);
        mesh_free(&c.want);
        free(c.in.p);
    }
    shape_free(&s);
}

Test(parse_alloc, a_small_mesh_parses_or_fails_cleanly_in_every_format)
{
    meshes_parse_or_fail_cleanly(2); /* 320 triangles: one thread */
}

/* 81920 triangles: the loaders' parallel paths, on every CPU (a binary
 * STL of 16384 triangles and up, a PLY over 1 MiB, the last step's checks
 * and boxes of 65536 triangles and up). */
Test(parse_alloc, a_larger_mesh_parses_or_fails_cleanly_in_every_format, .timeout = 600)
{
    meshes_parse_or_fail_cleanly(6);
}

/* ---- a .gltf naming its buffer's file: read by mesh_load, embedded by
 * mesh_gltf_embed (vox submit sends it so) ---- */

typedef struct {
    const char *path, *dir;
    const text *in;
    const mesh *want;
    const text *embedded; /* mesh_gltf_embed's answer */
} gltf_file_case;

static int load_once(void *ctx, char *msg)
{
    const gltf_file_case *c = ctx;
    mesh m;
    mesh_error err = {0};
    int rc = mesh_load(c->path, MESH_FORMAT_AUTO, NULL, &m, &err);
    memcpy(msg, err.msg, sizeof err.msg);
    if (rc) return rc;
    cr_assert(m.n_triangles == c->want->n_triangles && m.n_vertices == c->want->n_vertices);
    cr_assert_eq(memcmp(m.vertices, c->want->vertices, m.n_vertices * sizeof *m.vertices), 0);
    mesh_free(&m);
    return 0;
}

static int embed_once(void *ctx, char *msg)
{
    const gltf_file_case *c = ctx;
    char *out = (char *)1;
    size_t n = 1;
    mesh_error err = {0};
    int rc = mesh_gltf_embed(c->in->p, c->in->n, c->dir, &out, &n, &err);
    memcpy(msg, err.msg, sizeof err.msg);
    if (rc) {
        cr_assert(!out && !n, "a failed embedding handed back text");
        return rc;
    }
    cr_assert(n == c->embedded->n && !memcmp(out, c->embedded->p, n), "another embedding");
    free(out);
    return 0;
}

Test(parse_alloc, a_gltf_naming_its_buffer_loads_and_embeds_or_fails_cleanly)
{
    char dir[] = "/tmp/test_parse_alloc_XXXXXX", path[512];
    cr_assert(mkdtemp(dir));
    shape s;
    shape_init(&s);
    shape_icosphere(&s, (const double[3]){0, 0, 0}, 1, 3, false);
    text in = {0};
    write_gltf_as(&in, shape_finish(&s), false, dir, "ico.bin");
    snprintf(path, sizeof path, "%s/ico.gltf", dir);
    FILE *f = fopen(path, "wb");
    cr_assert(f && fwrite(in.p, 1, in.n, f) == in.n && !fclose(f));
    mesh want;
    mesh_error err = {0};
    cr_assert_eq(mesh_load(path, MESH_FORMAT_AUTO, NULL, &want, &err), 0, "%s", err.msg);
    text embedded = {0};
    cr_assert_eq(mesh_gltf_embed(in.p, in.n, dir, &embedded.p, &embedded.n, &err), 0, "%s",
                 err.msg);
    cr_assert(embedded.p && strstr(embedded.p, "base64"), "nothing embedded");
    gltf_file_case c = {path, dir, &in, &want, &embedded};
    cr_assert_geq(alloc_fail_each(load_once, &c, "mesh_load of a .gltf"), 2);
    cr_assert_geq(alloc_fail_each(embed_once, &c, "mesh_gltf_embed"), 2);
    mesh_free(&want);
    free(embedded.p);
    free(in.p);
    shape_free(&s);
    unlink(path);
    snprintf(path, sizeof path, "%s/ico.bin", dir);
    unlink(path);
    rmdir(dir);
}

/* ---- the daemon's intake of a CSG job: the frame unpacked (the budgeted
 * allocator: errno tells a failed malloc from garbage), checked, and the
 * tree built with its expressions compiled and its mesh leaf's bytes ---- */

typedef struct {
    const uint8_t *wire;
    size_t n;
    uint32_t nodes;
    size_t text_len;
} intake_case;

/* The request freed through this binary's free (the wrapped one, which the
 * table sees), not protobuf-c's default allocator's call of libc's. */
static void *no_alloc(void *ud, size_t n)
{
    (void)ud, (void)n;
    cr_assert_fail("freeing does not allocate");
    return NULL;
}

static void wrapped_free(void *ud, void *p)
{
    (void)ud;
    free(p);
}

static ProtobufCAllocator freeing = {no_alloc, wrapped_free, NULL};

static int intake_once(void *ctx, char *msg)
{
    const intake_case *c = ctx;
    Voxd__Request *r = proto_frame_unpack_request(c->wire, c->n);
    if (!r) {
        cr_assert_eq(errno, ENOMEM, "a failed allocation taken for garbage (errno %d)", errno);
        snprintf(msg, ERR_MSG_MAX, "out of memory (errno)");
        return -ENOMEM;
    }
    proto_limits lim;
    proto_limits_default(&lim);
    proto_error pe;
    cr_assert_eq(proto_check_request(r, &lim, &pe), 0, "%s", pe.msg);
    csg_tree *t = (csg_tree *)1;
    int rc = daemon_csg_tree(r->submit->csg, lim.max_expr_bytes, EXPR_DEFAULT_MAX_DEPTH, &t, msg,
                             ERR_MSG_MAX);
    voxd__request__free_unpacked(r, &freeing);
    if (rc) {
        cr_assert_null(t);
        return rc;
    }
    cr_assert(t->n == c->nodes && t->text_len == c->text_len);
    csg_tree_free(t);
    return 0;
}

Test(parse_alloc, the_daemons_intake_of_a_csg_job_takes_it_or_fails_cleanly)
{
    static const char obj[] = "v 0 0 0\nv 1 0 0\nv 0 1 0\nv 0 0 1\n"
                              "f 1 3 2\nf 1 2 4\nf 1 4 3\nf 2 3 4\n";
    static const char src[2][40] = {"x^2 + y^2 + z^2 - 0.5", "sin(3*x) + cos(2*y) - z"};
    Voxd__CsgNode node[5], *ptr[5];
    uint32_t kids[3][2] = {{0, 1}, {2, 3}, {0, 0}};
    for (int i = 0; i < 5; i++) node[i] = (Voxd__CsgNode)VOXD__CSG_NODE__INIT, ptr[i] = &node[i];
    for (int i = 0; i < 2; i++) {
        node[i].op = VOXD__CSG_OP__CSG_IMPLICIT;
        node[i].source.data = (uint8_t *)src[i], node[i].source.len = strlen(src[i]);
    }
    node[2].op = VOXD__CSG_OP__CSG_UNION;
    node[2].children = kids[0], node[2].n_children = 2;
    node[3].op = VOXD__CSG_OP__CSG_MESH;
    node[3].data.data = (uint8_t *)obj, node[3].data.len = sizeof obj - 1;
    node[4].op = VOXD__CSG_OP__CSG_DIFFERENCE;
    node[4].children = kids[1], node[4].n_children = 2;
    Voxd__Csg csg = VOXD__CSG__INIT;
    double dom[2] = {-1, 1};
    csg.nodes = ptr, csg.n_nodes = 5, csg.domain = dom, csg.n_domain = 2, csg.res = 64;
    Voxd__Submit sub = VOXD__SUBMIT__INIT;
    sub.job_case = VOXD__SUBMIT__JOB_CSG, sub.csg = &csg;
    Voxd__Request req = VOXD__REQUEST__INIT;
    req.msg_case = VOXD__REQUEST__MSG_SUBMIT, req.submit = &sub;
    uint8_t *buf;
    size_t len;
    cr_assert_eq(proto_frame_encode_request(&req, &buf, &len), 0);
    intake_case c = {buf + PROTO_FRAME_HEADER_BYTES, len - PROTO_FRAME_HEADER_BYTES, 5,
                     strlen(src[0]) + strlen(src[1]) + 2};
    cr_assert_geq(alloc_fail_each(intake_once, &c, "the daemon's intake"), 5);
    /* and bytes that are not a request: errno says so */
    static const uint8_t garbage[] = {0xff, 0xff, 0xff, 0xff, 0x0f};
    errno = 0;
    cr_assert_null(proto_frame_unpack_request(garbage, sizeof garbage));
    cr_assert_eq(errno, EBADMSG);
    free(buf);
}

/* ---- the daemon's configuration file ---- */

static const char conf[] = "# a configuration\nworkers 2\nmax_res 2048\n"
                           "max_queued_jobs 7\nshm_size 256M\n";

static int config_once(void *ctx, char *msg)
{
    (void)ctx;
    FILE *f = fmemopen((void *)conf, sizeof conf - 1, "r");
    cr_assert(f);
    voxd_config c;
    config_defaults(&c);
    err_info err = {0};
    int rc = config_load_stream(f, "voxd.conf", &c, &err);
    fclose(f);
    memcpy(msg, err.msg, sizeof err.msg);
    if (!rc) cr_assert_eq(c.max_queued_jobs, 7);
    return rc;
}

Test(parse_alloc, a_configuration_loads_or_fails_cleanly)
{
    cr_assert_geq(alloc_fail_each(config_once, NULL, "config_load_stream"), 1);
}
