/* vox render: a VOD file drawn as shaded points, or a triangle mesh (OBJ,
 * STL, PLY, OFF: told by the extension) as shaded triangles, into a PNG. */
#include <getopt.h>
#include <stdio.h>
#include <stdlib.h>
#include <strings.h>
#include <string.h>

#include "cli.h"
#include "mesh.h"
#include "render.h"
#include "vod.h"

static const char usage[] =
    "usage: vox render FILE.vod|MESH -o OUT.png [options]\n"
    "  draws a VOD file's voxels as shaded splats, or a triangle mesh (a file\n"
    "  named .obj, .stl, .ply, .off, .gltf or .glb) as shaded triangles framed alike\n"
    "  -o, --output OUT.png   the picture to write\n"
    "  -a, --azimuth DEG      camera angle about +z, from +x (default 30)\n"
    "  -e, --elevation DEG    camera angle above the xy-plane, -90..90 (default 20)\n"
    "  -s, --size N           image width and height in pixels, 1..8192 (default 1024)\n"
    "  -l, --level L          level of detail: 0 full resolution, L reads the parent\n"
    "                         bricks, 2^L voxels per splat (default 0)\n"
    "  -p, --perspective      perspective projection (default orthographic)\n"
    "      --fov DEG          perspective field of view (default 35)\n"
    "      --ambient A        ambient light 0..1 (default 0.2)\n"
    "      --whole            frame the whole volume, not just the voxels\n"
    "      --smooth           a mesh: normals interpolated from the vertices (default\n"
    "                         flat: each triangle its own normal)\n";

static int parse_double(const char *s, double lo, double hi, double *out)
{
    char *end;
    double v = strtod(s, &end);
    if (end == s || *end || !(v >= lo && v <= hi)) return -1;
    *out = v;
    return 0;
}

static int parse_render_args(int argc, char **argv, render_opts *o,
                             const char **out, int *level, int *smooth)
{
    static const struct option longs[] = {
        {"output", 1, 0, 'o'}, {"azimuth", 1, 0, 'a'}, {"elevation", 1, 0, 'e'},
        {"size", 1, 0, 's'}, {"level", 1, 0, 'l'}, {"perspective", 0, 0, 'p'},
        {"fov", 1, 0, 'F'}, {"ambient", 1, 0, 'A'}, {"whole", 0, 0, 'W'}, {"smooth", 0, 0, 'S'},
        {"help", 0, 0, 'h'}, {0, 0, 0, 0}};
    int c;
    uint32_t u;
    optind = 1;
    while ((c = cli_getopt("render", argc, argv, "o:a:e:s:l:ph", longs)) != -1) {
        int bad = 0;
        switch (c) {
        case 'o': *out = optarg; break;
        case 'a': bad = parse_double(optarg, -1e6, 1e6, &o->azimuth); break;
        case 'e': bad = parse_double(optarg, -90, 90, &o->elevation); break;
        case 's':
            bad = cli_parse_uint(optarg, 1, RENDER_MAX_SIZE, &u);
            o->width = o->height = (int)u;
            break;
        case 'l':
            bad = cli_parse_uint(optarg, 0, 31, &u);
            *level = (int)u;
            break;
        case 'p': o->perspective = 1; break;
        case 'F': bad = parse_double(optarg, 1, 169, &o->fov); break;
        case 'A': bad = parse_double(optarg, 0, 1, &o->ambient); break;
        case 'W': o->fit_volume = 1; break;
        case 'S': *smooth = 1; break;
        case 'h': fputs(usage, stdout); exit(CLI_EXIT_OK);
        default: return -1;
        }
        if (bad) {
            for (int i = 0; longs[i].name; i++)
                if (longs[i].val == c)
                    cli_usage_error("render", "bad --%s '%.40s'", longs[i].name, optarg);
            return -1;
        }
    }
    return 0;
}

/* A mesh by its name's extension (the formats vox voxelize --mesh reads). */
static int is_mesh_path(const char *path)
{
    const char *dot = strrchr(path, '.');
    static const char *const ext[] = {".obj", ".stl", ".ply", ".off", ".gltf", ".glb"};
    for (int i = 0; dot && i < 6; i++)
        if (!strcasecmp(dot, ext[i])) return 1;
    return 0;
}

static int render_mesh_file(const char *path, const render_opts *o, int smooth,
                            render_image *img)
{
    mesh m;
    if (cli_mesh_load(path, MESH_FORMAT_AUTO, -1, &m, NULL)) return CLI_EXIT_FAILED;
    int rc = render_mesh(&m, o, smooth, img);
    mesh_free(&m);
    if (rc) cli_error("cannot render %s: %s", path, strerror(-rc));
    return rc ? CLI_EXIT_FAILED : CLI_EXIT_OK;
}

static int render_vod_file(const char *path, const render_opts *o, int level,
                           render_image *img)
{
    vod_file *f;
    err_info err = {0};
    if (vod_open_levels(path, (int)cli_cores(), 1u << level, &f, &err)) {
        cli_error("%s: %s", path, err.msg);
        return CLI_EXIT_FAILED;
    }
    const vod_info *in = vod_get_info(f);
    if ((uint32_t)level >= in->height) {
        cli_error("%s has levels 0..%u; --level %d does not exist", path, in->height - 1, level);
        vod_close(f);
        return CLI_EXIT_USAGE;
    }
    err_info re = {0};
    int rc = render_vod(f, level, o, img, &re);
    vod_close(f);
    if (rc) cli_error("cannot render %s: %s", path, re.msg);
    return rc ? CLI_EXIT_FAILED : CLI_EXIT_OK;
}

int cli_render(int argc, char **argv)
{
    render_opts o;
    render_opts_default(&o);
    const char *out = NULL;
    int level = 0, smooth = 0;
    if (parse_render_args(argc, argv, &o, &out, &level, &smooth)) return CLI_EXIT_USAGE;
    if (optind + 1 != argc || !out)
        return cli_usage_error("render", "%s", optind + 1 != argc
                               ? "want one FILE.vod (or a mesh)" : "missing -o OUT.png");
    const char *path = argv[optind];
    int is_mesh = is_mesh_path(path);
    if (is_mesh ? level != 0 || o.fit_volume : smooth) {
        return cli_usage_error("render", "%s", is_mesh
                               ? "--level and --whole are for VOD files, not meshes"
                               : "--smooth is for meshes (.obj, .stl, .ply, .off), not VOD files");
    }
    render_image img;
    int rc = is_mesh ? render_mesh_file(path, &o, smooth, &img)
                  : render_vod_file(path, &o, level, &img);
    if (rc) return rc;
    rc = render_write_png(&img, out);
    if (rc) cli_error("cannot write %s: %s", out, strerror(-rc));
    else if (is_mesh) printf("%s: %llu triangles drawn, %dx%d\n", out,
                          (unsigned long long)img.splats, img.width, img.height);
    else printf("%s: %llu voxels drawn at level %d, %dx%d\n", out,
                (unsigned long long)img.splats, level, img.width, img.height);
    render_image_free(&img);
    return rc ? CLI_EXIT_FAILED : CLI_EXIT_OK;
}
