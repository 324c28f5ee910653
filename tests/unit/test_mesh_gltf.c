/* The glTF 2.0 loader (mesh_gltf.c, mesh_gltf_scene.c) against the same
 * cube read from OBJ text.  The files are written here: the cube's eight
 * positions and twelve triangles in a buffer, as a .gltf with the buffer
 * embedded (base64 data: URI) or in a .bin beside it, and as a .glb;
 * indices as u8, u16 and u32, and none (every triangle its own three
 * positions); positions interleaved with normals (byteStride 24); a node
 * hierarchy with a translation and scale, a rotation and a mirror.  Each
 * must give the OBJ's vertices and triangles, bit for bit where the
 * arithmetic is exact.  Malformed files (an accessor past its view, a
 * view past its buffer, a buffer shorter than its byteLength, an index out
 * of range, a path out of the folder, a cycle of nodes, a bad GLB header,
 * a required extension, truncated JSON) are refused with their reason. */
#include <criterion/criterion.h>
#include <errno.h>
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/stat.h>
#include <unistd.h>

#include "mesh.h"

static const float cube_v[8][3] = {{-1, -1, -1}, {1, -1, -1}, {1, 1, -1}, {-1, 1, -1},
                                   {-1, -1, 1},  {1, -1, 1},  {1, 1, 1},  {-1, 1, 1}};
static const unsigned cube_t[12][3] = {{0, 3, 2}, {0, 2, 1}, {4, 5, 6}, {4, 6, 7},
                                       {0, 1, 5}, {0, 5, 4}, {2, 3, 7}, {2, 7, 6},
                                       {1, 2, 6}, {1, 6, 5}, {0, 4, 7}, {0, 7, 3}};

/* ------------------------------------------------------------ writers */

typedef struct {
    unsigned char bin[4096];
    size_t n, pos_at, pos_len, idx_at, idx_len, stride;
    int comp, indexed;
    unsigned count; /* positions */
} cubebuf;

static void put(cubebuf *c, const void *p, size_t n)
{
    memcpy(c->bin + c->n, p, n);
    c->n += n;
}

/* The cube's buffer: positions (with normals after each when stride 24,
 * each triangle's own corners when not indexed), then the indices of
 * component type comp (5121, 5123, 5125), padded to 4 bytes. */
static void cube_buffer(cubebuf *c, int comp, int stride24, int indexed)
{
    memset(c, 0, sizeof *c);
    c->comp = comp, c->indexed = indexed;
    c->stride = stride24 ? 24 : 12;
    c->count = indexed ? 8 : 36;
    for (unsigned i = 0; i < c->count; i++) {
        const float *p = indexed ? cube_v[i] : cube_v[cube_t[i / 3][i % 3]];
        put(c, p, 12);
        if (stride24) put(c, (float[3]){0, 0, 1}, 12);
    }
    c->pos_len = c->n;
    c->idx_at = c->n;
    for (int t = 0; indexed && t < 12; t++)
        for (int k = 0; k < 3; k++) {
            unsigned v = cube_t[t][k];
            if (comp == 5121) put(c, &(uint8_t){(uint8_t)v}, 1);
            if (comp == 5123) put(c, &(uint16_t){(uint16_t)v}, 2);
            if (comp == 5125) put(c, &(uint32_t){v}, 4);
        }
    c->idx_len = c->n - c->idx_at;
    while (c->n % 4) c->bin[c->n++] = 0;
}

static char *b64(const unsigned char *d, size_t n)
{
    static const char a[] = "ABCDEFGHIJKLMNOPQRSTUVWXYZabcdefghijklmnopqrstuvwxyz0123456789+/";
    char *s = malloc(n / 3 * 4 + 8), *q = s;
    for (size_t i = 0; i < n; i += 3) {
        unsigned v = d[i] << 16 | (i + 1 < n ? d[i + 1] << 8 : 0) | (i + 2 < n ? d[i + 2] : 0);
        *q++ = a[v >> 18], *q++ = a[v >> 12 & 63];
        *q++ = i + 1 < n ? a[v >> 6 & 63] : '=', *q++ = i + 2 < n ? a[v & 63] : '=';
    }
    *q = 0;
    return s;
}

/* The JSON of the cube: buffer 0 (uri NULL: none, a .glb's), and the
 * nodes text (a "nodes" array and "scenes"), mesh 0 the cube. */
static char *cube_json(const cubebuf *c, const char *uri, const char *nodes)
{
    char *s = malloc(16384), idx[256] = "", acc_idx[128] = "", ind[32] = "", u[8192] = "";
    if (uri) snprintf(u, sizeof u, "\"uri\": \"%s\", ", uri);
    if (c->indexed) {
        snprintf(idx, sizeof idx, ", {\"buffer\": 0, \"byteOffset\": %zu, \"byteLength\": %zu}",
                 c->idx_at, c->idx_len);
        snprintf(acc_idx, sizeof acc_idx,
                 ", {\"bufferView\": 1, \"componentType\": %d, \"count\": 36, \"type\": \"SCALAR\"}",
                 c->comp);
        snprintf(ind, sizeof ind, ", \"indices\": 1");
    }
    char stride[32] = "";
    if (c->stride != 12) snprintf(stride, sizeof stride, ", \"byteStride\": %zu", c->stride);
    snprintf(s, 16384,
             "{\"asset\": {\"version\": \"2.0\", \"generator\": \"test_mesh_gltf\"}, %s, "
             "\"meshes\": [{\"primitives\": [{\"attributes\": {\"POSITION\": 0}%s}]}], "
             "\"buffers\": [{%s\"byteLength\": %zu}], "
             "\"bufferViews\": [{\"buffer\": 0, \"byteLength\": %zu%s}%s], "
             "\"accessors\": [{\"bufferView\": 0, \"componentType\": 5126, \"count\": %u, "
             "\"type\": \"VEC3\"}%s]}",
             nodes, ind, u, c->n, c->pos_len, stride, idx, c->count, acc_idx);
    return s;
}

static const char one_node[] = "\"scene\": 0, \"scenes\": [{\"nodes\": [0]}], \"nodes\": [{\"mesh\": 0}]";

static char *embedded(const cubebuf *c, const char *nodes)
{
    char *d = b64(c->bin, c->n), uri[8192];
    snprintf(uri, sizeof uri, "data:application/octet-stream;base64,%s", d);
    free(d);
    return cube_json(c, uri, nodes);
}

static void write_file(const char *path, const void *p, size_t n)
{
    FILE *f = fopen(path, "wb");
    cr_assert_not_null(f, "%s", path);
    cr_assert_eq(fwrite(p, 1, n, f), n);
    fclose(f);
}

/* A .glb of json and c's buffer; *n its length (malloc). */
static unsigned char *glb(const char *json, const cubebuf *c, size_t *n)
{
    size_t jl = strlen(json), jp = (jl + 3) / 4 * 4;
    *n = 12 + 8 + jp + 8 + c->n;
    unsigned char *g = malloc(*n);
    uint32_t h[5] = {0x46546C67u, 2, (uint32_t)*n, (uint32_t)jp, 0x4E4F534Au};
    memcpy(g, h, 20);
    memset(g + 20, ' ', jp);
    memcpy(g + 20, json, jl);
    uint32_t b[2] = {(uint32_t)c->n, 0x004E4942u};
    memcpy(g + 20 + jp, b, 8);
    memcpy(g + 28 + jp, c->bin, c->n);
    return g;
}

/* ------------------------------------------------------------ checks */

/* The cube from OBJ, its positions mapped by f (NULL: as they are). */
static void obj_cube(mesh *m, void (*f)(const float in[3], float out[3]))
{
    char obj[2048];
    size_t k = 0;
    for (int i = 0; i < 8; i++) {
        float p[3];
        if (f) f(cube_v[i], p);
        else memcpy(p, cube_v[i], sizeof p);
        k += (size_t)snprintf(obj + k, sizeof obj - k, "v %.9g %.9g %.9g\n", p[0], p[1], p[2]);
    }
    for (int t = 0; t < 12; t++)
        k += (size_t)snprintf(obj + k, sizeof obj - k, "f %u %u %u\n", cube_t[t][0] + 1,
                              cube_t[t][1] + 1, cube_t[t][2] + 1);
    mesh_error e;
    cr_assert_eq(mesh_parse(obj, k, MESH_FORMAT_OBJ, NULL, m, &e), 0, "%s", e.msg);
}

/* m is want: the same triangles in the same order, each corner at the same
 * position (tol 0: bit for bit).  A mesh without indices has its corners
 * repeated: welded (exact positions), it has want's vertex count. */
static void same_mesh(mesh *m, const mesh *want, double tol, const char *what)
{
    if (m->n_vertices != want->n_vertices) cr_assert_eq(mesh_weld(m, 0, NULL), 0);
    cr_assert_eq(m->format, MESH_FORMAT_GLTF, "%s", what);
    cr_assert_eq(m->n_vertices, want->n_vertices, "%s: %u vertices", what, m->n_vertices);
    cr_assert_eq(m->n_triangles, want->n_triangles, "%s: %u triangles", what, m->n_triangles);
    for (uint32_t t = 0; t < m->n_triangles; t++)
        for (int k = 0; k < 3; k++)
            for (int a = 0; a < 3; a++) {
                float x = m->vertices[m->triangles[t][k]][a];
                float y = want->vertices[want->triangles[t][k]][a];
                cr_assert(fabs(x - y) <= tol, "%s: triangle %u corner %d axis %d: %.9g, want %.9g",
                          what, t, k, a, x, y);
            }
    mesh_topo t;
    cr_assert_eq(mesh_topology(m, &t), 0);
    cr_assert(t.watertight && t.volume > 0, "%s: watertight, volume %g", what, t.volume);
}

static void parse_ok(const void *buf, size_t n, mesh *m, const char *what)
{
    mesh_error e;
    int rc = mesh_parse(buf, n, MESH_FORMAT_AUTO, NULL, m, &e);
    cr_assert_eq(rc, 0, "%s: %d %s", what, rc, e.msg);
}

static void refused(const char *buf, size_t n, const char *want, const char *what)
{
    mesh m;
    mesh_error e;
    int rc = mesh_parse(buf, n, MESH_FORMAT_GLTF, NULL, &m, &e);
    cr_assert_eq(rc, -EINVAL, "%s: %d (%s)", what, rc, e.msg);
    cr_assert(strstr(e.msg, want), "%s: '%s' lacks '%s'", what, e.msg, want);
    cr_assert_null(m.vertices);
}

/* ------------------------------------------------------------ tests */

Test(mesh_gltf, every_index_type_and_container_is_the_obj_cube)
{
    mesh want;
    obj_cube(&want, NULL);
    static const int comps[] = {5121, 5123, 5125};
    for (int ci = 0; ci < 3; ci++)
        for (int stride = 0; stride < 2; stride++) {
            cubebuf c;
            cube_buffer(&c, comps[ci], stride, 1);
            char what[64];
            snprintf(what, sizeof what, "indices %d, stride %zu", comps[ci], c.stride);
            char *j = embedded(&c, one_node);
            mesh m;
            parse_ok(j, strlen(j), &m, what);
            same_mesh(&m, &want, 0, what);
            mesh_free(&m);
            char *bj = cube_json(&c, NULL, one_node);
            size_t n;
            unsigned char *g = glb(bj, &c, &n);
            parse_ok(g, n, &m, what);
            same_mesh(&m, &want, 0, what);
            mesh_free(&m);
            free(g), free(bj), free(j);
        }
    /* no indices: 36 positions, three a triangle */
    cubebuf c;
    cube_buffer(&c, 0, 0, 0);
    char *j = embedded(&c, one_node);
    mesh m;
    parse_ok(j, strlen(j), &m, "non-indexed");
    cr_assert_eq(m.n_vertices, 36);
    same_mesh(&m, &want, 0, "non-indexed");
    mesh_free(&m);
    free(j);
    mesh_free(&want);
}

Test(mesh_gltf, an_external_bin_beside_the_gltf)
{
    char dir[] = "/tmp/test_gltf_XXXXXX", path[512], sub[256];
    cr_assert_not_null(mkdtemp(dir));
    snprintf(sub, sizeof sub, "%s/data dir", dir);
    cr_assert_eq(mkdir(sub, 0700), 0);
    cubebuf c;
    cube_buffer(&c, 5123, 0, 1);
    snprintf(path, sizeof path, "%s/cube.bin", sub);
    write_file(path, c.bin, c.n);
    char *j = cube_json(&c, "data%20dir/cube.bin", one_node);
    snprintf(path, sizeof path, "%s/cube.gltf", dir);
    write_file(path, j, strlen(j));
    mesh want, m;
    mesh_error e;
    obj_cube(&want, NULL);
    cr_assert_eq(mesh_load(path, MESH_FORMAT_AUTO, NULL, &m, &e), 0, "%s", e.msg);
    same_mesh(&m, &want, 0, "external .bin");
    mesh_free(&m);
    /* from bytes, with no folder: refused; embedded for that, the same cube */
    refused(j, strlen(j), "only a .gltf read from disk may", "external from bytes");
    char *out;
    size_t n;
    cr_assert_eq(mesh_gltf_embed(j, strlen(j), dir, &out, &n, &e), 0, "%s", e.msg);
    cr_assert_not_null(out);
    parse_ok(out, n, &m, "embedded by mesh_gltf_embed");
    same_mesh(&m, &want, 0, "embedded by mesh_gltf_embed");
    mesh_free(&m);
    free(out);
    /* nothing to embed in an embedded file, nor in a .glb */
    char *emb = embedded(&c, one_node);
    cr_assert_eq(mesh_gltf_embed(emb, strlen(emb), dir, &out, &n, &e), 0);
    cr_assert_null(out);
    free(emb);
    /* paths out of the folder */
    static const char *const bad[] = {"../cube.bin", "data%20dir/../../x.bin", "/etc/passwd",
                                      "file:///etc/passwd", "data%20dir/%2E%2E/%2e%2e/x", "a%00b"};
    for (size_t i = 0; i < sizeof bad / sizeof *bad; i++) {
        char *bj = cube_json(&c, bad[i], one_node);
        write_file(path, bj, strlen(bj));
        cr_assert_eq(mesh_load(path, MESH_FORMAT_AUTO, NULL, &m, &e), -EINVAL, "%s", bad[i]);
        cr_assert(strstr(e.msg, "not a relative path inside"), "%s: %s", bad[i], e.msg);
        free(bj);
    }
    free(j);
    mesh_free(&want);
    char cmd[600];
    snprintf(cmd, sizeof cmd, "rm -rf '%s'", dir);
    cr_assert_eq(system(cmd), 0);
}

static void trs(const float in[3], float out[3])
{
    /* node 1 (translation 0.5,-2,3) above node 2 (scale 2,2,2) */
    for (int a = 0; a < 3; a++) out[a] = in[a] * 2 + (float[3]){0.5f, -2, 3}[a];
}

static void rot_z90(const float in[3], float out[3])
{
    out[0] = -in[1], out[1] = in[0], out[2] = in[2];
}

static void mirror_x(const float in[3], float out[3])
{
    out[0] = -in[0], out[1] = in[1], out[2] = in[2];
}

Test(mesh_gltf, node_transforms_compose_down_the_hierarchy)
{
    cubebuf c;
    cube_buffer(&c, 5123, 0, 1);
    mesh want, m;
    /* the scene's root has no mesh; its child the translation, its grandchild the cube */
    char *j = embedded(&c, "\"scene\": 1, \"scenes\": [{\"nodes\": []}, {\"nodes\": [0]}], "
                           "\"nodes\": [{\"children\": [1]}, {\"translation\": [0.5, -2, 3], "
                           "\"children\": [2]}, {\"scale\": [2, 2, 2], \"mesh\": 0}]");
    obj_cube(&want, trs);
    parse_ok(j, strlen(j), &m, "TRS");
    same_mesh(&m, &want, 0, "TRS");
    mesh_free(&m), mesh_free(&want), free(j);
    /* the same as matrices (column-major) */
    j = embedded(&c, "\"nodes\": [{\"matrix\": [1,0,0,0, 0,1,0,0, 0,0,1,0, 0.5,-2,3,1], "
                     "\"children\": [1]}, {\"matrix\": [2,0,0,0, 0,2,0,0, 0,0,2,0, 0,0,0,1], "
                     "\"mesh\": 0}]");
    obj_cube(&want, trs);
    parse_ok(j, strlen(j), &m, "matrices, no scene: the root nodes");
    same_mesh(&m, &want, 0, "matrices");
    mesh_free(&m), mesh_free(&want), free(j);
    /* a quarter turn about z (a unit quaternion: rounding within 1e-6) */
    j = embedded(&c, "\"nodes\": [{\"rotation\": [0, 0, 0.70710678118654752, "
                     "0.70710678118654752], \"mesh\": 0}]");
    obj_cube(&want, rot_z90);
    parse_ok(j, strlen(j), &m, "rotation");
    same_mesh(&m, &want, 1e-6, "rotation");
    mesh_free(&m), mesh_free(&want), free(j);
    /* a mirror: the triangles' order reversed, so they still face outwards */
    j = embedded(&c, "\"nodes\": [{\"scale\": [-1, 1, 1], \"mesh\": 0}]");
    parse_ok(j, strlen(j), &m, "mirror");
    obj_cube(&want, mirror_x);
    for (uint32_t t = 0; t < want.n_triangles; t++) {
        uint32_t x = want.triangles[t][1];
        want.triangles[t][1] = want.triangles[t][2], want.triangles[t][2] = x;
    }
    same_mesh(&m, &want, 0, "mirror");
    mesh_free(&m), mesh_free(&want), free(j);
    /* a mesh used by two nodes: both instances */
    j = embedded(&c, "\"scenes\": [{\"nodes\": [0, 1]}], \"nodes\": [{\"mesh\": 0}, "
                     "{\"translation\": [5, 0, 0], \"mesh\": 0}]");
    parse_ok(j, strlen(j), &m, "two instances");
    cr_assert_eq(m.n_triangles, 24);
    cr_assert_eq(m.n_vertices, 16);
    cr_assert(m.lo[0] == -1 && m.hi[0] == 6);
    mesh_free(&m), free(j);
}

/* s with the first `from` replaced by `to` (a new string). */
static char *edit(const char *s, const char *from, const char *to)
{
    const char *p = strstr(s, from);
    cr_assert_not_null(p, "'%s' not in the JSON", from);
    char *r = malloc(strlen(s) + strlen(to) + 1);
    sprintf(r, "%.*s%s%s", (int)(p - s), s, to, p + strlen(from));
    return r;
}

Test(mesh_gltf, bad_files_are_refused_with_their_reason)
{
    cubebuf c;
    cube_buffer(&c, 5123, 0, 1);
    char *j = embedded(&c, one_node);
    static const struct {
        const char *from, *to, *want;
    } cases[] = {
        {"\"count\": 8", "\"count\": 9", "overflow bufferView 0"},
        {"\"count\": 36", "\"count\": 35", "not a multiple of 3"},
        {"\"count\": 36", "\"count\": 39", "overflow bufferView 1"},
        {"\"byteLength\": 96", "\"byteLength\": 95", "overflow bufferView 0"},
        {"{\"buffer\": 0, \"byteLength\": 96}", "{\"buffer\": 0, \"byteOffset\": 2, \"byteLength\": 96}",
         "not aligned"},
        {"{\"buffer\": 0, \"byteLength\": 96}", "{\"buffer\": 0, \"byteOffset\": 100, \"byteLength\": 96}",
         "overflows buffer 0"},
        {"\"byteLength\": 168}", "\"byteLength\": 172}", "only 168 bytes"},
        {"{\"buffer\": 0, \"byteLength\": 96}", "{\"buffer\": 0, \"byteLength\": 96, \"byteStride\": 13}",
         "byteStride 13"},
        {"\"componentType\": 5123", "\"componentType\": 5126", "is not for indices"},
        {"\"type\": \"VEC3\"", "\"type\": \"VEC2\"", "VEC3 (POSITION)"},
        {"\"nodes\": [{\"mesh\": 0}]", "\"nodes\": [{\"mesh\": 0, \"children\": [0]}]", "reached twice"},
        {"\"nodes\": [{\"mesh\": 0}]", "\"nodes\": [{\"mesh\": 1}]", "meshes 1 does not exist"},
        {"\"version\": \"2.0\"", "\"version\": \"1.0\"", "glTF version 1.0"},
        {"\"asset\"", "\"extensionsRequired\": [\"KHR_draco_mesh_compression\"], \"asset\"",
         "requires the extension KHR_draco_mesh_compression"},
        {"\"count\": 8", "\"count\": 8.5", "count is not a whole number"},
        {"\"count\": 8", "\"count\": 18446744073709551615", "out of range"},
        {"base64,", "base64,!", "bad base64"},
        {"{\"mesh\": 0}", "{\"mesh\": 0, \"matrix\": [1,0,0,0,0,1,0,0,0,0,1,0,0,0,0,1], \"scale\": [1,1,1]}",
         "both a matrix and TRS"},
    };
    for (size_t i = 0; i < sizeof cases / sizeof *cases; i++) {
        char *bad = edit(j, cases[i].from, cases[i].to), what[32];
        snprintf(what, sizeof what, "case %zu", i);
        refused(bad, strlen(bad), cases[i].want, what);
        free(bad);
    }
    /* an index out of range: vertex 7 made 8 in the data */
    cubebuf c2 = c;
    for (size_t k = c2.idx_at; k < c2.idx_at + c2.idx_len; k += 2)
        if (c2.bin[k] == 7) c2.bin[k] = 8;
    char *j2 = embedded(&c2, one_node);
    refused(j2, strlen(j2), "index 8 out of range (8 positions)", "index");
    free(j2);
    /* a JSON of millions of values, refused before json-c builds them */
    size_t big = 9u << 20;
    char *many = malloc(big + 64);
    int k = sprintf(many, "{\"asset\": {\"version\": \"2.0\"}, \"extras\": [0");
    while ((size_t)k < big) many[k++] = ',', many[k++] = '0';
    strcpy(many + k, "]}");
    mesh m;
    mesh_error e;
    cr_assert_eq(mesh_parse(many, strlen(many), MESH_FORMAT_GLTF, NULL, &m, &e), -E2BIG);
    cr_assert(strstr(e.msg, "values (4194304 at most)"), "%s", e.msg);
    free(many);
    /* JSON cut short, and data after it */
    refused(j, strlen(j) - 1, "JSON", "truncated JSON");
    char *tail = malloc(strlen(j) + 3);
    sprintf(tail, "%s x", j);
    refused(tail, strlen(tail), "data after the top-level value", "trailing data");
    free(tail);
    /* a .glb whose header lies about its length, and one cut short */
    char *bj = cube_json(&c, NULL, one_node);
    size_t n;
    unsigned char *g = glb(bj, &c, &n);
    g[8]++;
    refused((char *)g, n, "the GLB header says", "GLB length");
    g[8]--;
    ((uint32_t *)g)[2] = (uint32_t)(n - 8);
    refused((char *)g, n - 8, "chunk 1", "GLB chunk past the end");
    free(g), free(bj), free(j);
}
