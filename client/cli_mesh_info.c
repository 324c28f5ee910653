/* vox mesh-info: load a triangle mesh and describe it, its topology and
 * volume, as text or as one JSON object. */
#include <getopt.h>
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "cli.h"
#include "mesh.h"

static const char usage[] =
    "usage: vox mesh-info FILE [--json] [--format FMT] [--weld EPS]\n"
    "  loads a triangle mesh (OBJ, STL, PLY, OFF or glTF, told from its contents) and\n"
    "  prints its format, vertices, triangles (and the degenerate ones dropped),\n"
    "  bounding box, edges (open, non-manifold, inconsistently oriented),\n"
    "  connected components, signed volume, and whether it is watertight\n"
    "  -j, --json          one JSON object instead of the text\n"
    "  -f, --format FMT    read FILE as obj, stl, ply, off or gltf (.gltf or .glb)\n"
    "                      (default: from its contents)\n"
    "  -w, --weld EPS      merge the vertices within EPS of each other first (the mesh's\n"
    "                      units; 0: exactly equal positions) and say how many merged\n";

static int parse_format(const char *s, mesh_format *f)
{
    static const mesh_format all[] = {MESH_FORMAT_OBJ, MESH_FORMAT_STL, MESH_FORMAT_PLY,
                                      MESH_FORMAT_OFF, MESH_FORMAT_GLTF};
    for (size_t i = 0; i < sizeof all / sizeof *all; i++)
        if (!strcasecmp(s, mesh_format_name(all[i]))) {
            *f = all[i];
            return 0;
        }
    return -1;
}

/* What --weld did (weld < 0: not asked). */
typedef struct {
    double eps;
    uint32_t merged;
} weld_info;

static void print_text(const char *path, const mesh *m, const mesh_topo *t, const weld_info *w)
{
    printf("%s: %s mesh\n", path, mesh_format_name(m->format));
    printf("  vertices    %u\n", m->n_vertices);
    if (w->eps >= 0) printf("  welded      %u vertices merged (within %g)\n", w->merged, w->eps);
    printf("  triangles   %u (%llu degenerate dropped)\n", m->n_triangles,
           (unsigned long long)m->n_degenerate);
    printf("  bbox        x %.9g .. %.9g, y %.9g .. %.9g, z %.9g .. %.9g\n", m->lo[0], m->hi[0],
           m->lo[1], m->hi[1], m->lo[2], m->hi[2]);
    printf("  edges       %llu: %llu open, %llu non-manifold, %llu inconsistently oriented\n",
           (unsigned long long)t->edges, (unsigned long long)t->open,
           (unsigned long long)t->nonmanifold, (unsigned long long)t->inconsistent);
    printf("  components  %llu\n", (unsigned long long)t->components);
    printf("  volume      %.9g%s\n", t->volume,
           t->watertight ? "" : " (not watertight: not a true volume)");
    printf("  watertight  %s\n", t->watertight ? "yes" : "no");
}

/* s as a JSON string (quotes, backslashes and control characters escaped). */
static void json_string(const char *s)
{
    putchar('"');
    for (; *s; s++) {
        unsigned char c = (unsigned char)*s;
        if (c == '"' || c == '\\') printf("\\%c", c);
        else if (c < 0x20) printf("\\u%04x", c);
        else putchar(c);
    }
    putchar('"');
}

/* A number, or null where JSON has none (a volume past the double range). */
static void json_number(double v)
{
    if (isfinite(v)) printf("%.9g", v);
    else fputs("null", stdout);
}

static void print_json(const char *path, const mesh *m, const mesh_topo *t, const weld_info *w)
{
    fputs("{\"file\": ", stdout);
    json_string(path);
    printf(", \"format\": \"%s\", \"vertices\": %u, \"triangles\": %u, \"degenerate\": %llu",
           mesh_format_name(m->format), m->n_vertices, m->n_triangles,
           (unsigned long long)m->n_degenerate);
    if (w->eps >= 0) printf(", \"weld\": %.9g, \"welded\": %u", w->eps, w->merged);
    printf(", \"bbox\": {\"min\": [%.9g, %.9g, %.9g], \"max\": [%.9g, %.9g, %.9g]}", m->lo[0],
           m->lo[1], m->lo[2], m->hi[0], m->hi[1], m->hi[2]);
    printf(", \"edges\": %llu, \"open_edges\": %llu, \"nonmanifold_edges\": %llu"
           ", \"inconsistent_edges\": %llu, \"components\": %llu, \"volume\": ",
           (unsigned long long)t->edges, (unsigned long long)t->open,
           (unsigned long long)t->nonmanifold, (unsigned long long)t->inconsistent,
           (unsigned long long)t->components);
    json_number(t->volume);
    printf(", \"watertight\": %s}\n", t->watertight ? "true" : "false");
}

int cli_mesh_info(int argc, char **argv)
{
    static const struct option longs[] = {
        {"json", 0, 0, 'j'}, {"format", 1, 0, 'f'}, {"weld", 1, 0, 'w'},
        {"help", 0, 0, 'h'}, {0, 0, 0, 0}};
    weld_info w = {-1, 0};
    int c, json = 0;
    mesh_format format = MESH_FORMAT_AUTO;
    optind = 1;
    while ((c = cli_getopt("mesh-info", argc, argv, "jf:w:h", longs)) != -1) {
        switch (c) {
        case 'j': json = 1; break;
        case 'f':
            if (parse_format(optarg, &format)) {
                return cli_usage_error("mesh-info", "bad --format '%.40s': want obj, stl, "
                                       "ply, off or gltf", optarg);
            }
            break;
        case 'w':
            if (cli_parse_weld(optarg, &w.eps)) return CLI_EXIT_USAGE;
            break;
        case 'h': fputs(usage, stdout); return CLI_EXIT_OK;
        default: return CLI_EXIT_USAGE;
        }
    }
    if (optind + 1 != argc)
        return cli_usage_error("mesh-info", optind == argc ? "missing the mesh FILE"
                                                          : "want one mesh FILE");
    const char *path = argv[optind];
    mesh m;
    if (cli_mesh_load(path, format, w.eps, &m, &w.merged)) return CLI_EXIT_FAILED;
    mesh_topo t;
    int rc = mesh_topology(&m, &t);
    if (rc) {
        cli_error("%s: the topology of %u triangles: %s", path, m.n_triangles, strerror(-rc));
        mesh_free(&m);
        return CLI_EXIT_FAILED;
    }
    if (json) print_json(path, &m, &t, &w);
    else print_text(path, &m, &t, &w);
    mesh_free(&m);
    return CLI_EXIT_OK;
}
