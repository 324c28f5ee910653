/* mesh_gltf — glTF 2.0's container, JSON and buffers (mesh_gltf.h).
 *
 * A .glb is a 12-byte header (magic "glTF", version 2, the file's length),
 * then chunks (a length, a type, the bytes): the first is the JSON, the
 * next may be BIN, the bytes of the first buffer when it has no uri.  A
 * .gltf is the JSON alone; its buffers are data: URIs (base64) or files
 * named by a relative URI, read from the .gltf's folder and below (no
 * absolute path, no scheme, no ".." segment): only when the file was
 * loaded from disk (mesh_load), never from bytes (mesh_parse: the daemon).
 * The JSON is parsed by json-c, strictly (RFC 8259), 64 levels deep at
 * most.  Every count and offset is a whole number checked against what
 * holds it before anything is read. */
#include <errno.h>
#include <fcntl.h>
#include <limits.h>
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/mman.h>
#include <sys/stat.h>
#include <unistd.h>

#include "bits.h"
#include "mesh_gltf.h"

#define JSON_DEPTH 64
#define GLB_MAGIC 0x46546C67u /* "glTF" */
#define CHUNK_JSON 0x4E4F534Au
#define CHUNK_BIN 0x004E4942u

/* ---------------------------------------------------------------- JSON */

int mesh_gltf_uint(gltf *g, gltf_obj o, const char *key, int64_t def, uint64_t max, uint64_t *out)
{
    const char *what = o.what;
    json_object *v;
    if (!json_object_object_get_ex(o.o, key, &v)) {
        if (def < 0) return mesh_build_fail(g->b, -EINVAL, MESH_BUILD_NOWHERE, "%s has no %s", what, key);
        *out = (uint64_t)def;
        return 0;
    }
    if (!json_object_is_type(v, json_type_int))
        return mesh_build_fail(g->b, -EINVAL, MESH_BUILD_NOWHERE, "%s: %s is not a whole number", what, key);
    int64_t x = json_object_get_int64(v);
    if (x < 0 || (uint64_t)x > max || x == INT64_MAX)
        return mesh_build_fail(g->b, -EINVAL, MESH_BUILD_NOWHERE, "%s: %s %lld is out of range (0 to %llu)",
                       what, key, (long long)x, (unsigned long long)max);
    *out = (uint64_t)x;
    return 0;
}

int mesh_gltf_array(gltf *g, gltf_obj o, const char *key, int required, json_object **out)
{
    const char *what = o.what;
    *out = NULL;
    json_object *v;
    if (!json_object_object_get_ex(o.o, key, &v))
        return required ? mesh_build_fail(g->b, -EINVAL, MESH_BUILD_NOWHERE, "%s has no %s", what, key) : 0;
    if (!json_object_is_type(v, json_type_array))
        return mesh_build_fail(g->b, -EINVAL, MESH_BUILD_NOWHERE, "%s: %s is not an array", what, key);
    *out = v;
    return 0;
}

int mesh_gltf_numbers(gltf *g, gltf_obj o, const char *key, size_t n, double *out, int *given)
{
    const char *what = o.what;
    json_object *a;
    int rc = mesh_gltf_array(g, o, key, 0, &a);
    *given = a != NULL;
    if (rc || !a) return rc;
    if (json_object_array_length(a) != n)
        return mesh_build_fail(g->b, -EINVAL, MESH_BUILD_NOWHERE, "%s: %s needs %zu numbers", what, key, n);
    for (size_t i = 0; i < n; i++) {
        json_object *v = json_object_array_get_idx(a, i);
        if (!json_object_is_type(v, json_type_double) && !json_object_is_type(v, json_type_int))
            return mesh_build_fail(g->b, -EINVAL, MESH_BUILD_NOWHERE, "%s: %s[%zu] is not a number", what, key, i);
        out[i] = json_object_get_double(v);
        if (!isfinite(out[i]))
            return mesh_build_fail(g->b, -EINVAL, MESH_BUILD_NOWHERE, "%s: %s[%zu] is not finite", what, key, i);
    }
    return 0;
}

int mesh_gltf_item(gltf *g, const char *kind, uint64_t i, json_object **out)
{
    json_object *a;
    int rc = mesh_gltf_array(g, (gltf_obj){g->root, "the glTF"}, kind, 0, &a);
    if (rc) return rc;
    size_t n = a ? json_object_array_length(a) : 0;
    if (i >= n)
        return mesh_build_fail(g->b, -EINVAL, MESH_BUILD_NOWHERE, "%s %llu does not exist (%zu of them)", kind,
                       (unsigned long long)i, n);
    *out = json_object_array_get_idx(a, (size_t)i);
    if (!json_object_is_type(*out, json_type_object))
        return mesh_build_fail(g->b, -EINVAL, MESH_BUILD_NOWHERE, "%s %llu is not an object", kind,
                       (unsigned long long)i);
    return 0;
}

/* The values of a JSON text at most: json-c takes some 50 to 100 bytes a
 * value, so a file of a few bytes a value ("[0,0,0,...") could ask for
 * gigabytes; a glTF's JSON holds a few values a node, accessor or view (its
 * geometry is in the buffers), so 4 Mi of them leave room for hundreds of
 * thousands of nodes. */
#define JSON_MAX_VALUES (4u << 20)

/* An upper bound on the values in j[0, n): the commas, opening brackets
 * and colons outside strings, plus one. */
static uint64_t json_values(const char *j, size_t n)
{
    uint64_t v = 1;
    int in_str = 0;
    for (size_t i = 0; i < n; i++) {
        char c = j[i];
        if (in_str) {
            if (c == '\\') i++;
            else if (c == '"') in_str = 0;
        } else {
            in_str = c == '"';
            v += c == ',' || c == '[' || c == '{' || c == ':';
        }
    }
    return v;
}

/* The JSON text j[0, n) (at: its byte offset in the file) into g->root. */
static int parse_json(gltf *g, const char *j, size_t n, uint64_t at)
{
    if (n > INT32_MAX - 1)
        return mesh_build_fail(g->b, -E2BIG, MESH_BUILD_NOWHERE, "a JSON text of %zu bytes (2 GiB at most)", n);
    uint64_t values = json_values(j, n);
    if (values > JSON_MAX_VALUES)
        return mesh_build_fail(g->b, -E2BIG, MESH_BUILD_NOWHERE, "a JSON text of up to %llu values (%u at most)",
                       (unsigned long long)values, JSON_MAX_VALUES);
    json_tokener *tok = json_tokener_new_ex(JSON_DEPTH);
    if (!tok) return mesh_build_fail(g->b, -ENOMEM, MESH_BUILD_NOWHERE, "out of memory for the JSON");
    json_tokener_set_flags(tok, JSON_TOKENER_STRICT | JSON_TOKENER_ALLOW_TRAILING_CHARS);
    g->root = json_tokener_parse_ex(tok, j, (int)n);
    enum json_tokener_error e = json_tokener_get_error(tok);
    size_t end = json_tokener_get_parse_end(tok);
    json_tokener_free(tok);
    if (!g->root || e != json_tokener_success)
        return mesh_build_fail(g->b, -EINVAL, at + end, "JSON: %s",
                       e == json_tokener_continue ? "the text ends inside a value"
                                                  : json_tokener_error_desc(e));
    for (size_t i = end; i < n; i++) /* a .glb pads its JSON with spaces */
        if (j[i] != ' ' && j[i] != '\t' && j[i] != '\n' && j[i] != '\r')
            return mesh_build_fail(g->b, -EINVAL, at + i, "JSON: data after the top-level value");
    if (!json_object_is_type(g->root, json_type_object))
        return mesh_build_fail(g->b, -EINVAL, MESH_BUILD_NOWHERE, "the glTF JSON is not an object");
    return 0;
}

/* ------------------------------------------------------------ buffers */

static int b64_value(int c)
{
    if (c >= 'A' && c <= 'Z') return c - 'A';
    if (c >= 'a' && c <= 'z') return c - 'a' + 26;
    if (c >= '0' && c <= '9') return c - '0' + 52;
    return c == '+' ? 62 : c == '/' ? 63 : -1;
}

/* Base64 (RFC 4648, padding optional) s[0, n) into a new *out of *len bytes. */
static int b64_decode(const char *s, size_t n, uint8_t **out, size_t *len)
{
    while (n && s[n - 1] == '=') n--;
    if (n % 4 == 1) return -EINVAL;
    uint8_t *d = malloc(n / 4 * 3 + 3);
    if (!d) return -ENOMEM;
    size_t k = 0;
    uint32_t acc = 0;
    for (size_t i = 0; i < n; i++) {
        int v = b64_value((unsigned char)s[i]);
        if (v < 0) {
            free(d);
            return -EINVAL;
        }
        acc = acc << 6 | (uint32_t)v;
        if (i % 4 == 3) d[k++] = (uint8_t)(acc >> 16), d[k++] = (uint8_t)(acc >> 8), d[k++] = (uint8_t)acc;
    }
    if (n % 4 == 2) d[k++] = (uint8_t)(acc >> 4);
    if (n % 4 == 3) d[k++] = (uint8_t)(acc >> 10), d[k++] = (uint8_t)(acc >> 2);
    *out = d;
    *len = k;
    return 0;
}

/* A data: URI's bytes: "data:[type][;params];base64,...". */
static int data_uri(gltf *g, uint64_t i, const char *uri, size_t n, mesh_gltf_buffer *bf, uint64_t *have)
{
    const char *comma = memchr(uri, ',', n);
    if (!comma || comma - uri < 12 || memcmp(comma - 7, ";base64", 7))
        return mesh_build_fail(g->b, -EINVAL, MESH_BUILD_NOWHERE, "buffer %llu: a data: URI that is not base64",
                       (unsigned long long)i);
    uint8_t *d;
    size_t len;
    int rc = b64_decode(comma + 1, n - (size_t)(comma + 1 - uri), &d, &len);
    if (rc)
        return mesh_build_fail(g->b, rc, MESH_BUILD_NOWHERE, "buffer %llu: %s", (unsigned long long)i,
                       rc == -ENOMEM ? "out of memory" : "bad base64 in its data: URI");
    bf->owned = d;
    bf->data = d;
    *have = len;
    return 0;
}

static int hex(char c)
{
    return c >= '0' && c <= '9' ? c - '0' : c >= 'a' && c <= 'f' ? c - 'a' + 10
                                  : c >= 'A' && c <= 'F' ? c - 'A' + 10 : -1;
}

/* A relative URI, %XX decoded, into path (dir/...): no scheme, not absolute,
 * no ".." segment, no NUL. */
static int uri_path(const char *dir, const char *uri, size_t n, char *path, size_t cap)
{
    size_t k = (size_t)snprintf(path, cap, "%s/", dir);
    if (k >= cap || !n || uri[0] == '/' || uri[0] == '\\') return -EINVAL;
    const char *colon = memchr(uri, ':', n), *slash = memchr(uri, '/', n);
    if (colon && (!slash || colon < slash)) return -EINVAL; /* a scheme */
    size_t seg = k;
    for (size_t i = 0; i < n; i++) {
        char c = uri[i];
        if (c == '%') {
            int hi = i + 2 < n ? hex(uri[i + 1]) : -1, lo = i + 2 < n ? hex(uri[i + 2]) : -1;
            if (hi < 0 || lo < 0 || !(hi | lo)) return -EINVAL;
            c = (char)(hi << 4 | lo);
            i += 2;
        }
        if (k + 1 >= cap) return -EINVAL;
        if (c == '\\') return -EINVAL;
        path[k++] = c;
        if (c == '/') {
            if (k - 1 - seg == 2 && !memcmp(path + seg, "..", 2)) return -EINVAL;
            seg = k;
        }
    }
    path[k] = '\0';
    return k - seg == 2 && !memcmp(path + seg, "..", 2) ? -EINVAL : 0;
}

/* An external file's bytes, mapped. */
static int file_uri(gltf *g, uint64_t i, const char *uri, size_t n, mesh_gltf_buffer *bf, uint64_t *have)
{
    char path[4096];
    if (!g->b->dir)
        return mesh_build_fail(g->b, -EINVAL, MESH_BUILD_NOWHERE,
                       "buffer %llu names the file '%.*s': only a .gltf read from disk may "
                       "(vox submit embeds them)", (unsigned long long)i, (int)(n > 64 ? 64 : n), uri);
    if (uri_path(g->b->dir, uri, n, path, sizeof path))
        return mesh_build_fail(g->b, -EINVAL, MESH_BUILD_NOWHERE,
                       "buffer %llu: the URI '%.*s' is not a relative path inside the .gltf's "
                       "folder", (unsigned long long)i, (int)(n > 64 ? 64 : n), uri);
    int fd = open(path, O_RDONLY | O_CLOEXEC);
    struct stat st;
    if (fd < 0 || fstat(fd, &st) || !S_ISREG(st.st_mode)) {
        int e = fd < 0 ? errno : EINVAL;
        if (fd >= 0) close(fd);
        return mesh_build_fail(g->b, -EINVAL, MESH_BUILD_NOWHERE, "buffer %llu: cannot read %s: %s",
                       (unsigned long long)i, path, strerror(e));
    }
    void *p = st.st_size ? mmap(NULL, (size_t)st.st_size, PROT_READ, MAP_PRIVATE, fd, 0) : NULL;
    close(fd);
    if (p == MAP_FAILED)
        return mesh_build_fail(g->b, -ENOMEM, MESH_BUILD_NOWHERE, "buffer %llu: cannot map %s", (unsigned long long)i, path);
    bf->map = p;
    bf->map_len = (size_t)st.st_size;
    bf->data = p;
    *have = (uint64_t)st.st_size;
    return 0;
}

/* Buffer i: its byteLength, and its bytes from the BIN chunk, a data: URI
 * or a file; at least byteLength of them. */
static int resolve(gltf *g, uint64_t i, mesh_gltf_buffer *bf)
{
    json_object *o, *u;
    char what[48];
    snprintf(what, sizeof what, "buffer %llu", (unsigned long long)i);
    int rc = mesh_gltf_item(g, "buffers", i, &o);
    if (!rc) rc = mesh_gltf_uint(g, (gltf_obj){o, what}, "byteLength", -1, UINT64_MAX >> 1, &bf->len);
    if (rc) return rc;
    uint64_t have = 0;
    if (!json_object_object_get_ex(o, "uri", &u)) {
        if (i != 0 || !g->bin)
            return mesh_build_fail(g->b, -EINVAL, MESH_BUILD_NOWHERE,
                           "%s has no uri (only a .glb's first buffer, in its BIN chunk, may)", what);
        bf->data = g->bin;
        have = g->bin_len;
    } else if (!json_object_is_type(u, json_type_string)) {
        return mesh_build_fail(g->b, -EINVAL, MESH_BUILD_NOWHERE, "%s: its uri is not a string", what);
    } else {
        const char *s = json_object_get_string(u);
        size_t n = (size_t)json_object_get_string_len(u);
        rc = n >= 5 && !memcmp(s, "data:", 5) ? data_uri(g, i, s, n, bf, &have)
                                              : file_uri(g, i, s, n, bf, &have);
        if (rc) return rc;
    }
    if (have < bf->len)
        return mesh_build_fail(g->b, -EINVAL, MESH_BUILD_NOWHERE, "%s: byteLength %llu, but only %llu bytes",
                       what, (unsigned long long)bf->len, (unsigned long long)have);
    return 0;
}

int mesh_gltf_buffer_get(gltf *g, uint64_t i, const mesh_gltf_buffer **out)
{
    if (i >= g->n_buf)
        return mesh_build_fail(g->b, -EINVAL, MESH_BUILD_NOWHERE, "buffer %llu does not exist (%zu of them)",
                       (unsigned long long)i, g->n_buf);
    mesh_gltf_buffer *bf = &g->buf[i];
    if (!bf->data) {
        int rc = resolve(g, i, bf);
        if (rc) return rc;
    }
    *out = bf;
    return 0;
}

/* ---------------------------------------------------------- the file */

/* A .glb: the header, then the JSON chunk, then an optional BIN chunk
 * (other chunks are skipped). */
static int parse_glb(gltf *g, const uint8_t *p, size_t len)
{
    mbuild *b = g->b;
    if (len < 20) return mesh_build_fail(b, -EINVAL, MESH_BUILD_NOWHERE, "a .glb of %zu bytes: too short", len);
    if (bits_le32(p + 4) != 2)
        return mesh_build_fail(b, -EINVAL, 4, "GLB version %u (2 is read)", bits_le32(p + 4));
    if (bits_le32(p + 8) != len)
        return mesh_build_fail(b, -EINVAL, 8, "the GLB header says %u bytes, the file has %zu",
                       bits_le32(p + 8), len);
    size_t at = 12, json_at = 0, json_len = 0;
    for (int k = 0; at < len; k++) {
        if (len - at < 8) return mesh_build_fail(b, -EINVAL, at, "a truncated chunk header");
        uint32_t n = bits_le32(p + at), type = bits_le32(p + at + 4);
        if (n > len - at - 8)
            return mesh_build_fail(b, -EINVAL, at, "chunk %d: %u bytes, %zu are left", k, n, len - at - 8);
        if (k == 0 && type != CHUNK_JSON)
            return mesh_build_fail(b, -EINVAL, at + 4, "the first chunk is not JSON");
        if (k == 0) json_at = at + 8, json_len = n;
        if (k == 1 && type == CHUNK_BIN) g->bin = p + at + 8, g->bin_len = n;
        at += 8 + (size_t)n;
    }
    return parse_json(g, (const char *)p + json_at, json_len, json_at);
}

/* The asset's version (2.x) and the extensions the file requires. */
static int check_asset(gltf *g)
{
    json_object *a, *v, *req;
    if (!json_object_object_get_ex(g->root, "asset", &a) ||
        !json_object_object_get_ex(a, "version", &v) || !json_object_is_type(v, json_type_string))
        return mesh_build_fail(g->b, -EINVAL, MESH_BUILD_NOWHERE, "no asset.version: not a glTF 2.0 file");
    const char *s = json_object_get_string(v);
    if (strncmp(s, "2.", 2))
        return mesh_build_fail(g->b, -EINVAL, MESH_BUILD_NOWHERE, "glTF version %.16s (2.x is read)", s);
    int rc = mesh_gltf_array(g, (gltf_obj){g->root, "the glTF"}, "extensionsRequired", 0, &req);
    for (size_t i = 0; !rc && req && i < json_object_array_length(req); i++) {
        const char *e = json_object_get_string(json_object_array_get_idx(req, i));
        /* geometry as the core reads it, or only looks (materials, textures, lights) */
        if (e && (!strcmp(e, "KHR_mesh_quantization") || !strncmp(e, "KHR_materials_", 14) ||
                  !strncmp(e, "KHR_texture_", 12) || !strcmp(e, "KHR_lights_punctual") ||
                  !strcmp(e, "EXT_texture_webp")))
            continue;
        rc = mesh_build_fail(g->b, -EINVAL, MESH_BUILD_NOWHERE, "the file requires the extension %.64s, "
                     "which is not read", e ? e : "(not a string)");
    }
    return rc;
}

void mesh_gltf_close(gltf *g)
{
    for (size_t i = 0; i < g->n_buf; i++) {
        free(g->buf[i].owned);
        if (g->buf[i].map) munmap(g->buf[i].map, g->buf[i].map_len);
    }
    free(g->buf);
    json_object_put(g->root);
}

/* g's table of buffers, an entry for each of its "buffers" (none when it
 * has none); n_buf counts the entries made, which mesh_gltf_close walks. */
static int buffers_alloc(gltf *g)
{
    json_object *bufs = NULL;
    int rc = mesh_gltf_array(g, (gltf_obj){g->root, "the glTF"}, "buffers", 0, &bufs);
    size_t n = !rc && bufs ? json_object_array_length(bufs) : 0;
    if (n && !(g->buf = calloc(n, sizeof *g->buf)))
        return mesh_build_fail(g->b, -ENOMEM, MESH_BUILD_NOWHERE, "out of memory for %zu buffers", n);
    g->n_buf = n;
    return rc;
}

int mesh_gltf_open(gltf *g, const char *buf, size_t len)
{
    const uint8_t *p = (const uint8_t *)buf;
    int rc = len >= 4 && bits_le32(p) == GLB_MAGIC ? parse_glb(g, p, len) : parse_json(g, buf, len, 0);
    if (!rc) rc = check_asset(g);
    return rc ? rc : buffers_alloc(g);
}

/* ------------------------------------------------------- for vox submit */

static char *b64_encode(const uint8_t *d, size_t n)
{
    static const char a[] = "ABCDEFGHIJKLMNOPQRSTUVWXYZabcdefghijklmnopqrstuvwxyz0123456789+/";
    char *s = malloc((n + 2) / 3 * 4 + 1), *q = s;
    if (!s) return NULL;
    for (size_t i = 0; i < n; i += 3) {
        uint32_t v = (uint32_t)d[i] << 16 | (i + 1 < n ? (uint32_t)d[i + 1] << 8 : 0) |
                     (i + 2 < n ? d[i + 2] : 0);
        *q++ = a[v >> 18], *q++ = a[v >> 12 & 63];
        *q++ = i + 1 < n ? a[v >> 6 & 63] : '=';
        *q++ = i + 2 < n ? a[v & 63] : '=';
    }
    *q = '\0';
    return s;
}

/* Every buffer of g that names a file: its bytes as a data: URI instead. */
static int embed_buffers(gltf *g, int *changed)
{
    for (size_t i = 0; i < g->n_buf; i++) {
        json_object *o = json_object_array_get_idx(json_object_object_get(g->root, "buffers"), i), *u;
        if (!json_object_is_type(o, json_type_object) || !json_object_object_get_ex(o, "uri", &u) ||
            !json_object_is_type(u, json_type_string) || !strncmp(json_object_get_string(u), "data:", 5))
            continue;
        const mesh_gltf_buffer *bf;
        int rc = mesh_gltf_buffer_get(g, i, &bf);
        if (rc) return rc;
        char *enc = b64_encode(bf->data, (size_t)bf->len), *uri;
        if (!enc || asprintf(&uri, "data:application/octet-stream;base64,%s", enc) < 0) {
            free(enc);
            return mesh_build_fail(g->b, -ENOMEM, MESH_BUILD_NOWHERE, "out of memory embedding buffer %zu", i);
        }
        free(enc);
        json_object_object_add(o, "uri", json_object_new_string(uri));
        free(uri);
        *changed = 1;
    }
    return 0;
}

int mesh_gltf_embed(const char *buf, size_t len, const char *dir, char **out, size_t *out_len,
                    mesh_error *err)
{
    mbuild b = {.buf = buf, .err = err, .dir = dir, .binary = 1};
    gltf g = {.b = &b};
    *out = NULL;
    *out_len = 0;
    memset(err, 0, sizeof *err);
    size_t i = 0;
    while (i < len && (buf[i] == ' ' || buf[i] == '\t' || buf[i] == '\n' || buf[i] == '\r')) i++;
    if (i == len || buf[i] != '{') return 0; /* not a JSON glTF: nothing to embed */
    int rc = parse_json(&g, buf, len, 0), changed = 0;
    if (!rc) rc = buffers_alloc(&g);
    if (!rc) rc = embed_buffers(&g, &changed);
    if (!rc && changed) {
        size_t n;
        const char *s = json_object_to_json_string_length(g.root, JSON_C_TO_STRING_PLAIN, &n);
        if (!s || !(*out = malloc(n ? n : 1))) rc = mesh_build_fail(&b, -ENOMEM, MESH_BUILD_NOWHERE, "out of memory");
        else memcpy(*out, s, n), *out_len = n;
    }
    mesh_gltf_close(&g);
    return rc;
}
