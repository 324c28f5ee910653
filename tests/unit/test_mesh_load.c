/* The mesh loaders (mesh.h).  Small meshes (mesh_load_fixture.h) are written
 * here in every format and variant (OBJ with quads, negative indices and the
 * v/vt/vn forms, CRLF line ends and continuations; STL ascii and binary; PLY
 * ascii and binary little and big endian, with extra properties of every type
 * and an extra element; OFF with its counts on the keyword's line or their own)
 * and must load to the same triangles, the fan triangulation of the faces, bit
 * for bit (STL after welding).  Malformed files of each format must fail with
 * -EINVAL (or -E2BIG past a limit) and say where.  Welding, the float parser and
 * topology: test_mesh_topo.c. */
#include <criterion/criterion.h>
#include <errno.h>
#include <float.h>
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/mman.h>
#include <unistd.h>

#include "mesh.h"
#include "mesh_load.h"

#include "mesh_load_fixture.h"

static const char *const variant_name[] = {
    "OBJ", "OBJ (negative indices, v/vt/vn, CRLF)", "STL ascii", "STL binary", "PLY ascii",
    "PLY binary LE", "PLY binary BE", "OFF", "OFF (counts inline, comments)"};

static const mesh_format variant_format[] = {
    MESH_FORMAT_OBJ, MESH_FORMAT_OBJ, MESH_FORMAT_STL, MESH_FORMAT_STL, MESH_FORMAT_PLY,
    MESH_FORMAT_PLY, MESH_FORMAT_PLY, MESH_FORMAT_OFF, MESH_FORMAT_OFF};

/* m holds md's fan triangles, in order, with the same positions bit for
 * bit; and md's vertices in order, unless welded (STL: first use order). */
static void check_model(const mesh *m, const model *md, const char *what, int welded)
{
    int nt = model_tris(md);
    cr_assert_eq(m->n_triangles, (uint32_t)nt, "%s %s: %u triangles, want %d", what, md->name,
                 m->n_triangles, nt);
    cr_assert_eq(m->n_vertices, (uint32_t)md->nv, "%s %s: %u vertices", what, md->name,
                 m->n_vertices);
    cr_assert_eq(m->n_degenerate, 0);
    float lo[3] = {FLT_MAX, FLT_MAX, FLT_MAX}, hi[3] = {-FLT_MAX, -FLT_MAX, -FLT_MAX};
    for (int t = 0; t < nt; t++) {
        int tri[3];
        model_tri(md, t, tri);
        for (int k = 0; k < 3; k++) {
            uint32_t vi = m->triangles[t][k];
            cr_assert_lt(vi, m->n_vertices);
            if (!welded) cr_assert_eq(vi, (uint32_t)tri[k], "%s %s: triangle %d", what, md->name, t);
            cr_assert(!memcmp(m->vertices[vi], md->v[tri[k]], sizeof(float[3])),
                      "%s %s: triangle %d vertex %d: %.9g %.9g %.9g", what, md->name, t, k,
                      m->vertices[vi][0], m->vertices[vi][1], m->vertices[vi][2]);
            for (int j = 0; j < 3; j++) {
                lo[j] = fminf(lo[j], md->v[tri[k]][j]);
                hi[j] = fmaxf(hi[j], md->v[tri[k]][j]);
            }
        }
    }
    cr_assert(!memcmp(m->lo, lo, sizeof lo) && !memcmp(m->hi, hi, sizeof hi), "%s %s: bbox",
              what, md->name);
}

Test(mesh_load, every_model_in_every_variant_gives_the_same_triangles)
{
    for (size_t i = 0; i < sizeof models / sizeof *models; i++)
        for (int v = 0; v < N_VARIANTS; v++) {
            sink s;
            write_variant(&s, models[i], (variant)v);
            for (int forced = 0; forced < 2; forced++) {
                mesh m;
                mesh_error e;
                mesh_format f = forced ? variant_format[v] : MESH_FORMAT_AUTO;
                int rc = mesh_parse(s.buf, s.len, f, NULL, &m, &e);
                cr_assert_eq(rc, 0, "%s %s: %d %s (line %llu byte %llu)", variant_name[v],
                             models[i]->name, rc, e.msg, (unsigned long long)e.line,
                             (unsigned long long)e.offset);
                cr_assert_eq(m.format, variant_format[v], "%s: told %s", variant_name[v],
                             mesh_format_name(m.format));
                check_model(&m, models[i], variant_name[v], variant_format[v] == MESH_FORMAT_STL);
                mesh_free(&m);
                cr_assert_null(m.vertices);
            }
            free(s.buf);
        }
}

/* hexprism written as variant v into a new temporary file, named in path
 * (a "/tmp/test_mesh_load_XXXXXX" to fill). */
static void hexprism_file(char *path, variant v)
{
    int fd = mkstemp(path);
    cr_assert_geq(fd, 0);
    sink s;
    write_variant(&s, &hexprism, v);
    cr_assert_eq(write(fd, s.buf, s.len), (ssize_t)s.len);
    close(fd);
    free(s.buf);
}

Test(mesh_load, mesh_load_maps_a_file)
{
    char path[] = "/tmp/test_mesh_load_XXXXXX";
    hexprism_file(path, PLY_BE);
    mesh m;
    mesh_error e;
    cr_assert_eq(mesh_load(path, MESH_FORMAT_AUTO, NULL, &m, &e), 0, "%s", e.msg);
    check_model(&m, &hexprism, "mesh_load", 0);
    mesh_free(&m);
    /* empty, missing, a directory */
    cr_assert_eq(truncate(path, 0), 0);
    cr_assert_eq(mesh_load(path, MESH_FORMAT_AUTO, NULL, &m, &e), -EINVAL);
    cr_assert(strstr(e.msg, "empty"), "%s", e.msg);
    unlink(path);
    cr_assert_eq(mesh_load(path, MESH_FORMAT_AUTO, NULL, &m, &e), -ENOENT);
    cr_assert(strstr(e.msg, "cannot open"), "%s", e.msg);
    cr_assert_eq(mesh_load("/tmp", MESH_FORMAT_AUTO, NULL, &m, &e), -EINVAL);
    cr_assert_null(m.vertices);
}

/* This binary is linked with -Wl,--wrap=mmap (Makefile): the library's
 * calls come here, and when armed the next file mapping fails as on a file
 * system without mmap (ENODEV), once. */
void *__real_mmap(void *addr, size_t len, int prot, int flags, int fd, off_t off);
void *__wrap_mmap(void *addr, size_t len, int prot, int flags, int fd, off_t off);
static int refuse_next_map;

void *__wrap_mmap(void *addr, size_t len, int prot, int flags, int fd, off_t off)
{
    if (refuse_next_map && fd >= 0) {
        refuse_next_map = 0;
        errno = ENODEV;
        return MAP_FAILED;
    }
    return __real_mmap(addr, len, prot, flags, fd, off);
}

Test(mesh_load, a_file_that_cannot_be_mapped_is_refused_with_the_reason)
{
    char path[] = "/tmp/test_mesh_load_XXXXXX";
    hexprism_file(path, OBJ_PLAIN);
    mesh m;
    mesh_error e;
    refuse_next_map = 1;
    int rc = mesh_load(path, MESH_FORMAT_AUTO, NULL, &m, &e);
    cr_assert_eq(refuse_next_map, 0, "mesh_load maps the file (the wrap was not reached)");
    cr_assert_eq(rc, -ENODEV, "rc %d: %s", rc, e.msg);
    cr_assert(strstr(e.msg, "cannot map") && strstr(e.msg, strerror(ENODEV)), "%s", e.msg);
    cr_assert_null(m.vertices);
    /* and the next load maps it */
    cr_assert_eq(mesh_load(path, MESH_FORMAT_AUTO, NULL, &m, &e), 0, "%s", e.msg);
    check_model(&m, &hexprism, "mesh_load after a refused map", 0);
    mesh_free(&m);
    unlink(path);
}

Test(mesh_load, limits_give_e2big)
{
    for (int v = 0; v < N_VARIANTS; v++) {
        sink s;
        write_variant(&s, &cube, (variant)v);
        mesh m;
        mesh_error e;
        mesh_limits tri = {11, 0}, vert = {0, 7}, exact = {12, 8};
        cr_assert_eq(mesh_parse(s.buf, s.len, MESH_FORMAT_AUTO, &tri, &m, &e), -E2BIG,
                     "%s: %s", variant_name[v], e.msg);
        cr_assert(strstr(e.msg, "limit"), "%s", e.msg);
        cr_assert_eq(mesh_parse(s.buf, s.len, MESH_FORMAT_AUTO, &vert, &m, &e), -E2BIG,
                     "%s: %s", variant_name[v], e.msg);
        /* at the limits exactly: loads (STL's 36 raw positions weld to 8) */
        cr_assert_eq(mesh_parse(s.buf, s.len, MESH_FORMAT_AUTO, &exact, &m, &e), 0,
                     "%s: %s", variant_name[v], e.msg);
        mesh_free(&m);
        free(s.buf);
    }
}

Test(mesh_load, formats_are_told_by_contents)
{
    cr_assert_str_eq(mesh_format_name(MESH_FORMAT_OBJ), "OBJ");
    cr_assert_str_eq(mesh_format_name(MESH_FORMAT_STL), "STL");
    cr_assert_str_eq(mesh_format_name(MESH_FORMAT_PLY), "PLY");
    cr_assert_str_eq(mesh_format_name(MESH_FORMAT_OFF), "OFF");
    mesh m;
    mesh_error e;
    /* a text that is none of them */
    cr_assert_eq(parse_text("hello world\n", MESH_FORMAT_AUTO, &m, &e), -EINVAL);
    cr_assert(strstr(e.msg, "known format"), "%s", e.msg);
    /* 4OFF is four-dimensional: not OFF */
    cr_assert_eq(parse_text("4OFF\n1 0 0\n", MESH_FORMAT_AUTO, &m, &e), -EINVAL);
    /* an ascii STL whose size happens to be 84 + 50 n would be binary; a
     * binary one whose header says "solid" is binary (the cube above) */
    sink s;
    write_variant(&s, &tetra, STL_BINARY);
    cr_assert_eq(memcmp(s.buf, "solid", 5), 0);
    cr_assert_eq(mesh_parse(s.buf, s.len, MESH_FORMAT_AUTO, NULL, &m, &e), 0, "%s", e.msg);
    mesh_free(&m);
    free(s.buf);
}

Test(mesh_load, empty_files)
{
    mesh m;
    mesh_error e;
    cr_assert_eq(mesh_parse("", 0, MESH_FORMAT_AUTO, NULL, &m, &e), -EINVAL);
    cr_assert(strstr(e.msg, "empty"));
    refuse("# nothing\n", MESH_FORMAT_OBJ, -EINVAL, "no triangles", 0);
    refuse("v 0 0 0\nv 1 0 0\nv 0 1 0\n", MESH_FORMAT_AUTO, -EINVAL, "no triangles", 0);
    refuse("solid x\nendsolid x\n", MESH_FORMAT_AUTO, -EINVAL, "no triangles", 0);
    refuse("OFF\n0 0 0\n", MESH_FORMAT_AUTO, -EINVAL, "no triangles", 0);
    refuse("ply\nformat ascii 1.0\nelement vertex 0\nproperty float x\nproperty float y\n"
           "property float z\nelement face 0\nproperty list uchar int vertex_indices\nend_header\n",
           MESH_FORMAT_AUTO, -EINVAL, "no triangles", 0);
}

Test(mesh_load, obj_errors)
{
    const mesh_format F = MESH_FORMAT_OBJ;
    refuse("v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 4\n", F, -EINVAL, "out of range", 4);
    refuse("v 0 0 0\nv 1 0 0\nv 0 1 0\nf 0 1 2\n", F, -EINVAL, "out of range", 4);
    refuse("v 0 0 0\nv 1 0 0\nv 0 1 0\nf -1 -2 -4\n", F, -EINVAL, "out of range", 4);
    /* a vertex defined after the face that uses it */
    refuse("v 0 0 0\nv 1 0 0\nf 1 2 3\nv 0 1 0\n", F, -EINVAL, "out of range", 3);
    refuse("v 0 0 0\nv 1 nan 0\nv 0 1 0\nf 1 2 3\n", F, -EINVAL, "finite", 2);
    refuse("v 0 0 0\nv 1 0 inf\nv 0 1 0\nf 1 2 3\n", F, -EINVAL, "finite", 2);
    refuse("v 0 0 0\nv 1e39 0 0\nv 0 1 0\nf 1 2 3\n", F, -EINVAL, "finite", 2);
    refuse("v 0 0 0\nv 1 0\nv 0 1 0\nf 1 2 3\n", F, -EINVAL, "not a number", 2);
    refuse("v 0 0 0\nv 1 0x 0\nv 0 1 0\nf 1 2 3\n", F, -EINVAL, "not a number", 2);
    refuse("v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2\n", F, -EINVAL, "at least 3", 4);
    refuse("v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 x\n", F, -EINVAL, "not a vertex index", 4);
    refuse("v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3/1/1/1\n", F, -EINVAL, "not a vertex", 4);
    refuse("v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 99999999999999999999\n", F, -EINVAL,
           "not a vertex index", 4);
    /* truncated in the middle of a number: the last one is still read whole */
    refuse("v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 ", F, -EINVAL, "at least 3", 4);
}

Test(mesh_load, stl_errors)
{
    const mesh_format F = MESH_FORMAT_STL;
    const char *facet = "solid t\nfacet normal 0 0 1\nouter loop\nvertex 0 0 0\nvertex 1 0 0\n"
                        "vertex 0 1 0\nendloop\nendfacet\n";
    char buf[512];
    snprintf(buf, sizeof buf, "%s", facet);
    refuse(buf, F, -EINVAL, "'facet' or 'endsolid'", 0); /* no endsolid */
    snprintf(buf, sizeof buf, "%.*s", (int)(strstr(facet, "vertex 0 1") - facet), facet);
    refuse(buf, F, -EINVAL, "at least 3", 0); /* truncated in the loop */
    refuse("solid t\nfacet normal 0 0 1\nouter loop\nvertex 0 0 0\nvertex 1 nan 0\n"
           "vertex 0 1 0\nendloop\nendfacet\nendsolid\n", F, -EINVAL, "finite", 5);
    refuse("solid t\nfacet normal 0 0 1\nouter loop\nvertex 0 0 0\nvertex 1 0 0\n"
           "vertex 0 1 0\nendloop\nendfacet\nendsolid\nfoo\n", F, -EINVAL, "'solid'", 10);
    refuse("solid t\nfacet normal 0 0 1\nloop\n", F, -EINVAL, "'outer'", 3);

    /* binary: the size must be 84 + 50 n */
    sink s;
    write_variant(&s, &tetra, STL_BINARY);
    mesh m;
    mesh_error e;
    cr_assert_eq(mesh_parse(s.buf, s.len - 1, F, NULL, &m, &e), -EINVAL);
    cr_assert(strstr(e.msg, "binary STL of 4 triangles must be 284 bytes"), "%s", e.msg);
    cr_assert_eq(mesh_parse(s.buf, s.len - 1, MESH_FORMAT_AUTO, NULL, &m, &e), -EINVAL);
    /* a count that lies */
    s.buf[80] = 5;
    cr_assert_eq(mesh_parse(s.buf, s.len, F, NULL, &m, &e), -EINVAL);
    cr_assert(strstr(e.msg, "5 triangles must be 334 bytes"), "%s", e.msg);
    s.buf[80] = 4;
    /* NaN in the second triangle's first vertex: said by its byte offset */
    float nan = NAN;
    memcpy(s.buf + 84 + 50 + 12, &nan, 4);
    cr_assert_eq(mesh_parse(s.buf, s.len, F, NULL, &m, &e), -EINVAL);
    cr_assert(strstr(e.msg, "finite"), "%s", e.msg);
    cr_assert_eq(e.offset, 84 + 50 + 12);
    cr_assert_eq(e.line, 0);
    /* too short for a header, and not "solid" */
    memcpy(s.buf, "xxxx", 4);
    cr_assert_eq(mesh_parse(s.buf, 50, F, NULL, &m, &e), -EINVAL);
    cr_assert(strstr(e.msg, "84"), "%s", e.msg);
    free(s.buf);
}

static const char ply_head[] =
    "ply\nformat ascii 1.0\nelement vertex 3\nproperty float x\nproperty float y\n"
    "property float z\nelement face 1\nproperty list uchar int vertex_indices\nend_header\n";

Test(mesh_load, ply_errors)
{
    const mesh_format F = MESH_FORMAT_PLY;
    char buf[1024];
    snprintf(buf, sizeof buf, "%s0 0 0\n1 0 0\n0 1 0\n3 0 1 3\n", ply_head);
    refuse(buf, F, -EINVAL, "out of range", 13);
    snprintf(buf, sizeof buf, "%s0 0 0\n1 0 0\n0 1 0\n3 0 1 -1\n", ply_head);
    refuse(buf, F, -EINVAL, "out of range", 13);
    snprintf(buf, sizeof buf, "%s0 0 0\n1 NaN 0\n0 1 0\n3 0 1 2\n", ply_head);
    refuse(buf, F, -EINVAL, "finite", 11);
    snprintf(buf, sizeof buf, "%s0.0 0.0 0.0\n1.0 0.0 0.0\n0.0 1.0 0.0\n2 0 1\n", ply_head);
    refuse(buf, F, -EINVAL, "fewer than 3", 13);
    snprintf(buf, sizeof buf, "%s0 0 0\n1 0 0\n0 1 0\n", ply_head); /* no face: too short */
    refuse(buf, F, -EINVAL, "need at least", 7);
    snprintf(buf, sizeof buf, "%s0.0 0.0 0.0\n1.0 0.0 0.0\n0.0 1.0 0.0\n3 0 1", ply_head);
    refuse(buf, F, -EINVAL, "a vertex index expected, found the end of the file", 13);
    snprintf(buf, sizeof buf, "%s0 0 0\n1 0 0\n0 1 0\n3 0 1 2\n3 0 1 2\n", ply_head); /* extra */
    refuse(buf, F, -EINVAL, "after the last element", 14);
    snprintf(buf, sizeof buf, "%s0 0 0\n1 0 0\n0 1 0\n3 0 1 2", ply_head); /* no last newline */
    mesh m;
    mesh_error e;
    cr_assert_eq(parse_text(buf, F, &m, &e), 0, "%s", e.msg);
    mesh_free(&m);

    refuse("ply\nformat ascii 1.0\nelement vertex 3\nproperty float128 x\nend_header\n", F,
           -EINVAL, "unknown property type 'float128'", 4);
    refuse("ply\nformat ascii 1.0\nelement face 1\nproperty list float int vertex_indices\n"
           "end_header\n", F, -EINVAL, "integer type", 4);
    refuse("ply\nformat ascii 1.0\nelement face 1\nproperty list uchar double vertex_indices\n"
           "end_header\n", F, -EINVAL, "integer type", 4);
    refuse("ply\nformat binary_middle_endian 1.0\n", F, -EINVAL, "unknown format", 2);
    refuse("ply\nformat ascii 2.0\n", F, -EINVAL, "version", 2);
    refuse("ply\nelement vertex 3\n", F, -EINVAL, "no format line", 2);
    refuse("ply\nformat ascii 1.0\nelement vertex 3\nproperty float x\n", F, -EINVAL,
           "no end_header", 0);
    refuse("ply\nformat ascii 1.0\nelement vertex 1\nproperty float x\nproperty float y\n"
           "end_header\n0 0\n", F, -EINVAL, "lacks x, y or z", 3);
    refuse("ply\nformat ascii 1.0\nelement vertex 1\nproperty float x\nproperty float y\n"
           "property float z\nend_header\n0 0 0\n", F, -EINVAL, "no face element", 0);
    refuse("ply\nformat ascii 1.0\nelement vertex 1\nproperty float x\nproperty float y\n"
           "property float z\nproperty float x\nend_header\n0 0 0\n", F, -EINVAL, "twice", 7);
    refuse("ply\nformat ascii 1.0\nelement vertex -1\n", F, -EINVAL, "not a whole number", 3);
    /* an unknown line hides no error: the elements are what their lines say */
    refuse("ply\nformat ascii 1.0\nelements vertex 3\nproperty float x\nend_header\n", F,
           -EINVAL, "a property before any element", 4);
    refuse("ply\nformat ascii 1.0\nelements vertex 3\nend_header\n", F, -EINVAL,
           "no vertex element", 0);
    refuse("ply\nfoo bar\nend_header\n", F, -EINVAL, "no format line", 3);
}

/* Blender 2.47 wrote its "Created by" line without "comment": skipped with
 * one warning line naming the first such line, the mesh as without it. */
Test(mesh_load, ply_unknown_header_lines_are_skipped_with_a_warning)
{
    char plain[1024], blender[1200], two[1300];
    const char *body = "0 0 0\n1 0 0\n0 1 0\n3 0 1 2\n";
    snprintf(plain, sizeof plain, "%s%s", ply_head, body);
    snprintf(blender, sizeof blender,
             "ply\nformat ascii 1.0\nCreated by Blender3D 247 - www.blender.org, source file: "
             "'x.blend'\n%s%s", ply_head + strlen("ply\nformat ascii 1.0\n"), body);
    snprintf(two, sizeof two, "ply\nformat ascii 1.0\nCreated by Blender\n%s", blender + 4);
    mesh a, b, c;
    mesh_error e;
    cr_assert_eq(parse_text(plain, MESH_FORMAT_AUTO, &a, &e), 0, "%s", e.msg);
    cr_assert_str_empty(a.warning);
    cr_assert_eq(parse_text(blender, MESH_FORMAT_AUTO, &b, &e), 0, "%s", e.msg);
    cr_assert(strstr(b.warning, "line 3: ") == b.warning, "%s", b.warning);
    cr_assert(strstr(b.warning, "'Created'"), "%s", b.warning);
    cr_assert_null(strstr(b.warning, "more"), "%s", b.warning);
    cr_assert_eq(b.n_triangles, a.n_triangles);
    cr_assert_eq(memcmp(b.vertices, a.vertices, sizeof *a.vertices * a.n_vertices), 0);
    cr_assert_eq(memcmp(b.triangles, a.triangles, sizeof *a.triangles * a.n_triangles), 0);
    /* "ply", "format", then two unknown lines, then "format" again */
    cr_assert_eq(parse_text(two, MESH_FORMAT_AUTO, &c, &e), -EINVAL);
    cr_assert(strstr(e.msg, "a second format line"), "%s", e.msg);
    snprintf(two, sizeof two, "ply\nformat ascii 1.0\nCreated by Blender\n%s",
             blender + strlen("ply\nformat ascii 1.0\n"));
    cr_assert_eq(parse_text(two, MESH_FORMAT_AUTO, &c, &e), 0, "%s", e.msg);
    cr_assert(strstr(c.warning, "line 3: ") == c.warning, "%s", c.warning);
    cr_assert(strstr(c.warning, "(and 1 more unknown header lines)"), "%s", c.warning);
    mesh_free(&a);
    mesh_free(&b);
    mesh_free(&c);
}

/* Counts that cannot be true fail before anything is allocated: with the
 * limits at their largest, a header claiming 2^31 faces (or vertices)
 * would ask for tens of GiB, which the sanitizer's allocator refuses with
 * a crash. */
Test(mesh_load, ply_counts_are_checked_against_the_bytes_first)
{
    const mesh_limits big = {UINT32_MAX, UINT32_MAX};
    const char *heads[] = {
        "ply\nformat ascii 1.0\nelement vertex 3\nproperty float x\nproperty float y\n"
        "property float z\nelement face 2147483648\nproperty list uchar int vertex_indices\n"
        "end_header\n0 0 0\n1 0 0\n0 1 0\n3 0 1 2\n",
        "ply\nformat binary_little_endian 1.0\nelement vertex 2147483648\nproperty float x\n"
        "property float y\nproperty float z\nelement face 1\n"
        "property list uchar int vertex_indices\nend_header\n0123456789abcdef",
        "ply\nformat binary_big_endian 1.0\nelement vertex 3\nproperty float x\n"
        "property float y\nproperty float z\nelement face 1\n"
        "property list uchar int vertex_indices\nelement junk 18446744073709551615\n"
        "property uchar j\nend_header\n0123456789abcdef",
    };
    for (size_t i = 0; i < sizeof heads / sizeof *heads; i++) {
        mesh m;
        mesh_error e;
        cr_assert_eq(mesh_parse(heads[i], strlen(heads[i]), MESH_FORMAT_AUTO, &big, &m, &e),
                     -EINVAL, "%zu: %s", i, e.msg);
        cr_assert(strstr(e.msg, "need at least"), "%s", e.msg);
    }
    /* with the default limits too (-EINVAL: the file lies, before -E2BIG) */
    refuse(heads[0], MESH_FORMAT_AUTO, -EINVAL, "2147483648 of them need at least", 7);
    /* a true count past the limit: -E2BIG */
    char buf[1024];
    snprintf(buf, sizeof buf, "%s0 0 0\n1 0 0\n0 1 0\n3 0 1 2\n", ply_head);
    mesh m;
    mesh_error e;
    mesh_limits two = {0, 2};
    cr_assert_eq(mesh_parse(buf, strlen(buf), MESH_FORMAT_PLY, &two, &m, &e), -E2BIG);
    cr_assert_eq(e.line, 3, "%s", e.msg);
}

Test(mesh_load, ply_binary_errors)
{
    sink s;
    write_variant(&s, &tetra, PLY_LE);
    mesh m;
    mesh_error e;
    /* truncated, one byte short */
    cr_assert_eq(mesh_parse(s.buf, s.len - 1, MESH_FORMAT_PLY, NULL, &m, &e), -EINVAL);
    cr_assert(strstr(e.msg, "truncated in face 3 of 4"), "%s", e.msg);
    cr_assert_gt(e.offset, 0);
    /* a byte too many */
    char *more = malloc(s.len + 1);
    memcpy(more, s.buf, s.len);
    more[s.len] = 0;
    cr_assert_eq(mesh_parse(more, s.len + 1, MESH_FORMAT_PLY, NULL, &m, &e), -EINVAL);
    cr_assert(strstr(e.msg, "1 bytes after the last element"), "%s", e.msg);
    cr_assert_eq(e.offset, s.len);
    free(more);
    /* the last face's last index out of range */
    s.buf[s.len - 3 - 3] = 9; /* LE int, then a ushort id: its low byte */
    cr_assert_eq(mesh_parse(s.buf, s.len, MESH_FORMAT_PLY, NULL, &m, &e), -EINVAL);
    cr_assert(strstr(e.msg, "vertex index 9 out of range"), "%s", e.msg);
    cr_assert_eq(e.offset, s.len - 2 - 4);
    free(s.buf);

    /* a negative list count (char) in the extra element */
    const char *h = "ply\nformat binary_little_endian 1.0\nelement vertex 3\nproperty float x\n"
                    "property float y\nproperty float z\nelement e 1\nproperty list char int l\n"
                    "element face 1\nproperty list uchar int vertex_indices\nend_header\n";
    sink b;
    sink_open(&b);
    put(&b, h, strlen(h));
    for (int i = 0; i < 9; i++) put_f32(&b, (float)(i % 4 == 0), 0);
    put_uint(&b, 0xff, 1, 0);
    put_uint(&b, 3, 1, 0);
    for (int i = 0; i < 3; i++) put_uint(&b, (uint64_t)i, 4, 0);
    sink_close(&b);
    cr_assert_eq(mesh_parse(b.buf, b.len, MESH_FORMAT_AUTO, NULL, &m, &e), -EINVAL);
    cr_assert(strstr(e.msg, "a list of -1 items"), "%s", e.msg);
    cr_assert_eq(e.offset, strlen(h) + 36);
    free(b.buf);
}

Test(mesh_load, off_errors)
{
    const mesh_format F = MESH_FORMAT_OFF;
    refuse("OFF\n3 1 0\n0 0 0\n1 0 0\n0 1 0\n3 0 1 3\n", F, -EINVAL, "out of range", 6);
    refuse("OFF\n3 1 0\n0 0 0\n1 0 0\n0 1 nan\n3 0 1 2\n", F, -EINVAL, "finite", 5);
    refuse("OFF\n3 2 0\n0.0 0.0 0.0\n1.0 0.0 0.0\n0.0 1.0 0.0\n3 0 1 2\n", F, -EINVAL,
           "vertex count expected, found the end of the file", 0);
    refuse("OFF\n3 1 0\n0 0 0\n1 0 0\n0 1 0\n3 0 1 2\n3 0 1 2\n", F, -EINVAL,
           "after the last face", 7);
    refuse("OFF\n3 1 0\n0 0 0\n1 0 0\n0 1 0\n2 0 1\n", F, -EINVAL, "at least 3", 6);
    refuse("OFF\n3 1 0\n0.0 0.0 0.0\n1.0 0.0\n0.0 1.0 0.0\n3 0 1 2\n", F, -EINVAL,
           "coordinate expected", 4);
    refuse("OFF BINARY\n", F, -EINVAL, "binary OFF", 1);
    refuse("OFF\nthree 1 0\n", F, -EINVAL, "counts", 2);
    refuse("OFF\n3 1 x\n", F, -EINVAL, "edge count", 2);
    /* counts that cannot fit in what follows */
    refuse("OFF\n3 2147483648 0\n0 0 0\n1 0 0\n0 1 0\n3 0 1 2\n", F, -EINVAL, "cannot fit", 2);
    refuse("OFF\n4294967296 1\n", F, -EINVAL, "cannot fit", 2);
}
