/* vox export: a VOD file's voxels (one level, optionally a box of it) as a
 * dense array in a format other tools open: NRRD, raw + a JSON sidecar,
 * binvox, VTK ImageData (.vti), OpenVDB (.vdb).
 *
 * The output is streamed a slab of one brick's thickness at a time (z slabs;
 * x slabs for binvox, whose x runs slowest), each slab gathered from the
 * bricks it crosses (export_gather.c), so memory holds the open VOD file and
 * one slab, never a dense copy of the volume; gzip NRRD is deflated by
 * several threads (export_gz.c), OpenVDB written through its module
 * (export_vdb.c).  Voxels are uint8: channel 1 as 0/1, channel 2 as its
 * density, channel 3 as its occupancy byte, with its normals as floats
 * beside it unless --no-normals (NRRD and raw: float (occupancy, nx, ny,
 * nz) per voxel; VTI: a second array; VDB: a Vec3SGrid); binvox holds
 * occupancy only. */
#include <errno.h>
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/stat.h>
#include <unistd.h>

#include "cli.h"
#include "export.h"
#include "outfile.h"
#include "vod.h"
#include "voxel.h"

enum { FMT_NONE, FMT_NRRD, FMT_RAW, FMT_BINVOX, FMT_VTI, FMT_VDB };

typedef struct {
    const char *in, *out, *json; /* json: the raw format's sidecar */
    int fmt, gzip, level, no_normals;
    const char *bbox;
} export_opts;

/* Where the bytes go, and the first error in writing them. */
typedef struct {
    FILE *fp;
    int err;
} sink;

static const char usage_text[] =
    "usage: vox export FILE.vod -o OUT [--format nrrd|raw|binvox|vti|vdb] [--gzip]\n"
    "                  [--level L] [--bbox X0,X1,Y0,Y1,Z0,Z1] [--no-normals]\n"
    "  writes the voxels of one level (0: full resolution), uint8 as a dense array\n"
    "  (sparse in vdb): channel 1 as 0/1, 2 as its density, 3 as its occupancy\n"
    "  byte; channel 3's normals too, where the format holds them; channel 4\n"
    "  (signed distance) as float32 (binvox: 1 inside), in vdb a level set\n"
    "  -o OUT        the output; its extension (.nrrd, .raw, .binvox, .vti, .vdb)\n"
    "                names the format unless --format does\n"
    "  --format F    nrrd, raw (a OUT.json sidecar beside it), binvox (occupancy:\n"
    "                channel 2 above 127), vti (VTK ImageData, appended raw), vdb\n"
    "                (OpenVDB, sparse: a BoolGrid for channel 1, else a FloatGrid\n"
    "                \"density\" of the byte / 255; normals a Vec3SGrid \"normal\";\n"
    "                channel 4 a level set \"surface\")\n"
    "  --gzip        NRRD only: gzip-encoded data\n"
    "  --level L     the mip level (default 0)\n"
    "  --bbox X0,X1,Y0,Y1,Z0,Z1  only voxels X0 <= x < X1 (and so on), in the\n"
    "                level's voxel indices\n"
    "  --no-normals  channel 3: its occupancy byte alone (NRRD and raw then hold\n"
    "                uint8, not float (occupancy, nx, ny, nz); vti and vdb no\n"
    "                \"normal\" array or grid)\n";

static int fmt_of(const char *s)
{
    static const char *const names[] = {"", "nrrd", "raw", "binvox", "vti", "vdb"};
    for (int i = FMT_NRRD; i <= FMT_VDB; i++)
        if (!strcmp(s, names[i])) return i;
    return FMT_NONE;
}

static int fmt_of_path(const char *path)
{
    const char *dot = strrchr(path, '.'), *slash = strrchr(path, '/');
    if (!dot || (slash && dot < slash)) return FMT_NONE;
    return fmt_of(dot + 1);
}

static int parse_opts(int argc, char **argv, export_opts *o)
{
    static const char *const names[] = {"-o", "--format", "--level", "--bbox", "--gzip",
                                        "--no-normals", "--help", NULL};
    *o = (export_opts){0};
    for (int i = 1; i < argc; i++) {
        const char *a = argv[i], *v = i + 1 < argc ? argv[i + 1] : NULL;
        int takes = !strcmp(a, "-o") || !strcmp(a, "--format") ||
                    !strcmp(a, "--level") || !strcmp(a, "--bbox");
        if (takes && !v) return cli_usage_error("export", "option '%s' needs a value", a);
        uint32_t l;
        if (!strcmp(a, "-o")) o->out = v;
        else if (!strcmp(a, "--format")) {
            if (!(o->fmt = fmt_of(v)))
                return cli_usage_error("export", "--format %.40s: not nrrd, raw, binvox, "
                                       "vti or vdb", v);
        } else if (!strcmp(a, "--level")) {
            if (cli_parse_uint(v, 0, 30, &l))
                return cli_usage_error("export", "--level %.40s: not a level 0..30", v);
            o->level = (int)l;
        } else if (!strcmp(a, "--bbox")) o->bbox = v;
        else if (!strcmp(a, "--gzip")) o->gzip = 1;
        else if (!strcmp(a, "--no-normals")) o->no_normals = 1;
        else if (a[0] == '-') return cli_unknown_option("export", a, names);
        else if (o->in) return cli_usage_error("export", "one input file only: '%.40s'", a);
        else o->in = a;
        i += takes;
    }
    if (!o->in) return cli_usage_error("export", "missing the input FILE.vod");
    if (!o->out) return cli_usage_error("export", "missing -o OUT (the file to write)");
    if (!o->fmt && !(o->fmt = fmt_of_path(o->out)))
        return cli_usage_error("export", "%.40s: no format from its extension; give --format",
                               o->out);
    if (o->gzip && o->fmt != FMT_NRRD)
        return cli_usage_error("export", "--gzip is for NRRD only");
    return 0;
}

/* "X0,X1,Y0,Y1,Z0,Z1" of whole numbers inside dims, each X0 < X1. */
static int parse_bbox(const char *s, const uint32_t dims[3], export_box *b)
{
    unsigned long v[6];
    int used = 0;
    if (sscanf(s, "%lu,%lu,%lu,%lu,%lu,%lu%n", &v[0], &v[1], &v[2], &v[3], &v[4],
               &v[5], &used) != 6 || s[used] != '\0' || strchr(s, '-')) {
        cli_error("--bbox %s: want X0,X1,Y0,Y1,Z0,Z1 (whole voxel indices)", s);
        return CLI_EXIT_USAGE;
    }
    for (int a = 0; a < 3; a++) {
        if (v[2 * a] >= v[2 * a + 1] || v[2 * a + 1] > dims[a]) {
            cli_error("--bbox %s: axis %c needs 0 <= %c0 < %c1 <= %u (the level's size)",
                      s, 'x' + a, 'X' + a, 'X' + a, dims[a]);
            return CLI_EXIT_USAGE;
        }
        b->lo[a] = (uint32_t)v[2 * a];
        b->hi[a] = (uint32_t)v[2 * a + 1];
    }
    return 0;
}

/* The channels whose voxels fit uint8, and channel 4's floats; 0 or a
 * message. */
static int check_channel(const vod_info *in, const char *path)
{
    if (in->channel == VOXEL_CH_OCCUPANCY || in->channel == VOXEL_CH_DENSITY ||
        in->channel == VOXEL_CH_SURFACE || in->channel == VOXEL_CH_DISTANCE ||
        (in->channel == 0 && in->voxel_bits <= 8))
        return 0;
    cli_error("%s: channel %u (%u-bit voxels) cannot be exported yet (channels 1 to 4 "
              "can)", path, in->channel, in->voxel_bits);
    return CLI_EXIT_FAILED;
}

static int make_box(const vod_file *f, const export_opts *o, export_box *b)
{
    const vod_info *in = vod_get_info(f);
    uint32_t dims[3];
    if (vod_level_dims(f, o->level, dims)) {
        cli_error("%s: --level %d: the file has levels 0..%u", o->in, o->level,
                  in->height - 1);
        return CLI_EXIT_USAGE;
    }
    /* channel 3's normals go where the format can hold them (not binvox) */
    int nrm = in->channel == VOXEL_CH_SURFACE && in->voxel_bits == 32 && !o->no_normals &&
              o->fmt != FMT_BINVOX;
    *b = (export_box){.f = f, .in = in, .level = o->level, .normals = nrm,
                      .distance = in->channel == VOXEL_CH_DISTANCE && o->fmt != FMT_BINVOX};
    for (int a = 0; a < 3; a++) b->hi[a] = dims[a];
    if (o->bbox && parse_bbox(o->bbox, dims, b)) return CLI_EXIT_USAGE;
    for (int a = 0; a < 3; a++) {
        b->n[a] = b->hi[a] - b->lo[a];
        b->spacing[a] = (double)in->voxel_scale[a] * (double)(1u << o->level);
        b->origin[a] = (double)in->origin[a] + b->lo[a] * b->spacing[a];
    }
    return check_channel(in, o->in);
}

/* ---- output ---- */

/* A failed write keeps its errno (ENOSPC on a full disk); an interrupt
 * stops the writing between chunks. */
static void put(sink *s, const void *p, size_t n)
{
    if (!s->err && cli_interrupted()) s->err = -ECANCELED;
    if (!s->err && n && fwrite(p, 1, n, s->fp) != n) s->err = errno ? -errno : -EIO;
}

/* The box in z slabs of one brick (aligned to the bricks), x fastest. */
static int stream_zyx(const export_box *b, sink *s)
{
    uint32_t B = b->in->brick;
    uint8_t *slab = malloc((size_t)b->n[0] * b->n[1] * B);
    if (!slab) return -ENOMEM;
    for (uint32_t z0 = b->lo[2]; z0 < b->hi[2] && !s->err;) {
        uint32_t z1 = (z0 / B + 1) * B < b->hi[2] ? (z0 / B + 1) * B : b->hi[2];
        uint32_t lo[3] = {b->lo[0], b->lo[1], z0}, hi[3] = {b->hi[0], b->hi[1], z1};
        export_gather(b, lo, hi, slab);
        put(s, slab, (size_t)b->n[0] * b->n[1] * (z1 - z0));
        z0 = z1;
    }
    free(slab);
    return s->err;
}

/* Channel 3's floats (comps per voxel, export_gather_normals) in z slabs of
 * at most a brick and 32 MiB, little-endian as the host (x86 and arm64
 * Linux are; the headers say little). */
static int stream_floats(const export_box *b, sink *s, int comps)
{
    size_t plane = (size_t)b->n[0] * b->n[1] * comps * sizeof(float);
    uint32_t t = b->in->brick;
    if (plane * t > (32u << 20)) t = plane >= (32u << 20) ? 1 : (uint32_t)((32u << 20) / plane);
    float *slab = malloc(plane * t);
    if (!slab) return -ENOMEM;
    for (uint32_t z0 = b->lo[2]; z0 < b->hi[2] && !s->err;) {
        uint32_t z1 = z0 + t < b->hi[2] ? z0 + t : b->hi[2];
        uint32_t lo[3] = {b->lo[0], b->lo[1], z0}, hi[3] = {b->hi[0], b->hi[1], z1};
        export_gather_normals(b, lo, hi, slab, comps);
        put(s, slab, plane * (z1 - z0));
        z0 = z1;
    }
    free(slab);
    return s->err;
}

static void print_vec(FILE *fp, const char *sep, const double v[3])
{
    fprintf(fp, "%.17g%s%.17g%s%.17g", v[0], sep, v[1], sep, v[2]);
}

/* NRRD of channel 4: a 3-D float array of the distances, world units. */
static int write_nrrd_distance(const export_box *b, const export_opts *o, sink *s)
{
    double c[3];
    for (int a = 0; a < 3; a++) c[a] = b->origin[a] + 0.5 * b->spacing[a];
    unsigned band;
    double w = export_band_width(b->in, &band);
    fprintf(s->fp, "NRRD0004\n# vox export of %s, level %d, channel 4: signed distance\n"
            "type: float\ndimension: 3\nsizes: %u %u %u\nspace: 3D-right-handed\n"
            "space directions: (%.17g,0,0) (0,%.17g,0) (0,0,%.17g)\n"
            "centerings: cell cell cell\nkinds: domain domain domain\nendian: little\n"
            "encoding: %s\nspace origin: (", o->in, b->level, b->n[0], b->n[1], b->n[2],
            b->spacing[0], b->spacing[1], b->spacing[2], o->gzip ? "gzip" : "raw");
    print_vec(s->fp, ",", c);
    fprintf(s->fp, ")\nvod_channel:=4\nvod_level:=%d\nvod_distance_band:=%u\n"
            "vod_distance_width:=%.9g\n\n", b->level, band, w);
    if (o->gzip) return export_gzip(b, s->fp, 1);
    return stream_floats(b, s, 1);
}

/* NRRD0004: the space origin is the first sample's centre.  With normals a
 * 4-D float array: (occupancy byte, nx, ny, nz) per voxel, fastest, its
 * axis of kind 4-vector with no space direction ("none").  "space:" comes
 * after "sizes:": VTK's vtkNrrdReader (ParaView's) takes "space" to set the
 * dimension to 3 and reads only that many sizes after it; NRRD wants it
 * only before the per-axis space fields (directions, origin). */
static int write_nrrd(const export_box *b, const export_opts *o, sink *s)
{
    double c[3];
    for (int a = 0; a < 3; a++) c[a] = b->origin[a] + 0.5 * b->spacing[a];
    if (b->distance) return write_nrrd_distance(b, o, s);
    int v = b->normals;
    fprintf(s->fp, "NRRD0004\n# vox export of %s, level %d, channel %u\n"
            "type: %s\ndimension: %d\nsizes: %s%u %u %u\nspace: 3D-right-handed\n"
            "space directions: %s(%.17g,0,0) (0,%.17g,0) (0,0,%.17g)\n"
            "centerings: %scell cell cell\nkinds: %sdomain domain domain\n%s"
            "encoding: %s\nspace origin: (", o->in, b->level, b->in->channel,
            v ? "float" : "uint8", v ? 4 : 3, v ? "4 " : "", b->n[0], b->n[1], b->n[2],
            v ? "none " : "", b->spacing[0], b->spacing[1], b->spacing[2], v ? "??? " : "",
            v ? "4-vector " : "", v ? "endian: little\n" : "", o->gzip ? "gzip" : "raw");
    print_vec(s->fp, ",", c);
    fprintf(s->fp, ")\nvod_channel:=%u\nvod_level:=%d\n%s\n", b->in->channel, b->level,
            v ? "vod_components:=occupancy nx ny nz\n" : "");
    if (o->gzip) return export_gzip(b, s->fp, v ? 4 : 0);
    return v ? stream_floats(b, s, 4) : stream_zyx(b, s);
}

/* VTK XML ImageData, the voxels as point data at their centres, appended raw
 * after a UInt64 byte count; channel 3's normals a second array, "normal". */
static int write_vti(const export_box *b, sink *s)
{
    double c[3];
    for (int a = 0; a < 3; a++) c[a] = b->origin[a] + 0.5 * b->spacing[a];
    char ext[96];
    snprintf(ext, sizeof ext, "0 %u 0 %u 0 %u", b->n[0] - 1, b->n[1] - 1, b->n[2] - 1);
    fprintf(s->fp, "<?xml version=\"1.0\"?>\n<VTKFile type=\"ImageData\" version=\"1.0\" "
            "byte_order=\"LittleEndian\" header_type=\"UInt64\">\n"
            "  <ImageData WholeExtent=\"%s\" Origin=\"", ext);
    print_vec(s->fp, " ", c);
    fputs("\" Spacing=\"", s->fp);
    print_vec(s->fp, " ", b->spacing);
    uint64_t bytes = (uint64_t)b->n[0] * b->n[1] * b->n[2] * (b->distance ? 4 : 1);
    const char *name = b->distance ? "distance" : "voxel";
    fprintf(s->fp, "\">\n    <Piece Extent=\"%s\">\n      <PointData Scalars=\"%s\"%s>\n"
            "        <DataArray type=\"%s\" Name=\"%s\" format=\"appended\" "
            "offset=\"0\"/>\n", ext, name, b->normals ? " Normals=\"normal\"" : "",
            b->distance ? "Float32" : "UInt8", name);
    if (b->normals) /* the second array starts past the first's count and bytes */
        fprintf(s->fp, "        <DataArray type=\"Float32\" Name=\"normal\" "
                "NumberOfComponents=\"3\" format=\"appended\" offset=\"%llu\"/>\n",
                (unsigned long long)(8 + bytes));
    fputs("      </PointData>\n    </Piece>\n  </ImageData>\n"
          "  <AppendedData encoding=\"raw\">\n   _", s->fp);
    uint8_t le[8];
    for (int i = 0; i < 8; i++) le[i] = (uint8_t)(bytes >> (8 * i));
    put(s, le, sizeof le);
    int rc = b->distance ? stream_floats(b, s, 1) : stream_zyx(b, s);
    if (!rc && b->normals) {
        for (int i = 0; i < 8; i++) le[i] = (uint8_t)((bytes * 12) >> (8 * i));
        put(s, le, sizeof le);
        rc = stream_floats(b, s, 3);
    }
    if (!rc) fputs("\n  </AppendedData>\n</VTKFile>\n", s->fp);
    return rc;
}

/* The sidecar of the raw format: what it takes to read the array back. */
static void print_json(FILE *fp, const export_box *b)
{
    if (b->distance)
        fprintf(fp, "{\n  \"shape\": [%u, %u, %u],\n  \"dtype\": \"float32\",\n"
                "  \"byte_order\": \"little\",\n  \"units\": \"world\",\n"
                "  \"order\": \"C: shape is (z, y, x), x varies fastest\",\n  \"origin\": [",
                b->n[2], b->n[1], b->n[0]);
    else if (b->normals)
        fprintf(fp, "{\n  \"shape\": [%u, %u, %u, 4],\n  \"dtype\": \"float32\",\n"
                "  \"byte_order\": \"little\",\n"
                "  \"components\": [\"occupancy\", \"nx\", \"ny\", \"nz\"],\n"
                "  \"order\": \"C: shape is (z, y, x, component), x varies fastest but "
                "for the components\",\n  \"origin\": [", b->n[2], b->n[1], b->n[0]);
    else
        fprintf(fp, "{\n  \"shape\": [%u, %u, %u],\n  \"dtype\": \"uint8\",\n"
                "  \"order\": \"C: shape is (z, y, x), x varies fastest\",\n  \"origin\": [",
                b->n[2], b->n[1], b->n[0]);
    print_vec(fp, ", ", b->origin);
    fputs("],\n  \"origin_is\": \"the low corner of voxel (0, 0, 0), x y z\",\n"
          "  \"spacing\": [", fp);
    print_vec(fp, ", ", b->spacing);
    fprintf(fp, "],\n  \"channel\": %u,\n  \"level\": %d,\n  \"offset\": [%u, %u, %u]\n}\n",
            b->in->channel, b->level, b->lo[0], b->lo[1], b->lo[2]);
}

/* The sidecar written whole or not at all, as the raw file is (outfile),
 * once the raw file is committed (the caller removes it when this fails:
 * a header never describes a raw file that is not there); a failure is
 * said here, naming it: 0, or -EINVAL (told). */
static int write_json(const export_box *b, const export_opts *o)
{
    char *text = NULL;
    size_t len = 0;
    FILE *fp = open_memstream(&text, &len);
    int rc = fp ? 0 : -errno;
    if (fp) {
        print_json(fp, b);
        if (fclose(fp)) rc = -errno;
    }
    if (!rc) rc = outfile_put(o->json, text, len);
    free(text);
    if (!rc) return 0;
    cli_error("%s: %s", o->json, strerror(-rc));
    return -EINVAL; /* told */
}

/* binvox: a cube of side d = the largest side (zeros past the box), x
 * slowest, then z, y fastest, in runs of (value, count 1..255); translate is
 * the box's low corner and scale the cube's side in world units, so it
 * needs cubic voxels. */
static int binvox_rows(const export_box *b, sink *s, uint32_t d)
{
    uint32_t B = b->in->brick;
    uint8_t *slab = malloc((size_t)B * b->n[1] * b->n[2]), run[2] = {0, 0};
    if (!slab) return -ENOMEM;
    for (uint32_t x0 = 0; x0 < d && !s->err;) {
        uint32_t ax = b->lo[0] + x0;
        uint32_t x1 = x0 < b->n[0] ? (ax / B + 1) * B - b->lo[0] : d;
        if (x0 < b->n[0] && x1 > b->n[0]) x1 = b->n[0];
        uint32_t w = x1 - x0;
        if (x0 < b->n[0]) {
            uint32_t lo[3] = {ax, b->lo[1], b->lo[2]}, hi[3] = {ax + w, b->hi[1], b->hi[2]};
            export_gather(b, lo, hi, slab);
        }
        for (uint32_t x = 0; x < w; x++)
            for (uint32_t z = 0; z < d; z++)
                for (uint32_t y = 0; y < d; y++) {
                    int in = x0 < b->n[0] && y < b->n[1] && z < b->n[2];
                    uint8_t v = in ? slab[((size_t)z * b->n[1] + y) * w + x] : 0;
                    if (b->in->channel == VOXEL_CH_DENSITY) v = v > 127;
                    else v = v != 0;
                    if (run[1] && (v != run[0] || run[1] == 255)) {
                        put(s, run, 2);
                        run[1] = 0;
                    }
                    run[0] = v;
                    run[1]++;
                }
        x0 = x1;
    }
    if (run[1]) put(s, run, 2);
    free(slab);
    return s->err;
}

static int write_binvox(const export_box *b, sink *s)
{
    if (b->spacing[0] != b->spacing[1] || b->spacing[1] != b->spacing[2]) {
        cli_error("binvox has one scale: the voxels (%g x %g x %g) must be cubes",
                  b->spacing[0], b->spacing[1], b->spacing[2]);
        return -EINVAL;
    }
    uint32_t d = b->n[0];
    if (b->n[1] > d) d = b->n[1];
    if (b->n[2] > d) d = b->n[2];
    fprintf(s->fp, "#binvox 1\ndim %u %u %u\ntranslate %.17g %.17g %.17g\nscale %.17g\ndata\n",
            d, d, d, b->origin[0], b->origin[1], b->origin[2], d * b->spacing[0]);
    return binvox_rows(b, s, d);
}

static int write_format(const export_box *b, const export_opts *o, FILE *fp)
{
    sink s = {fp, 0};
    static char buf[1 << 20];
    setvbuf(fp, buf, _IOFBF, sizeof buf);
    switch (o->fmt) {
    case FMT_NRRD: return write_nrrd(b, o, &s);
    case FMT_VTI: return write_vti(b, &s);
    case FMT_BINVOX: return write_binvox(b, &s);
    default: {
        return b->normals    ? stream_floats(b, &s, 4)
               : b->distance ? stream_floats(b, &s, 1)
                             : stream_zyx(b, &s);
    }
    }
}

/* OpenVDB writes by path: the output's name while it is open
 * (outfile_name) is handed over. */
static int write_vdb(const export_box *b, const export_opts *o, const outfile *f)
{
    err_info err = {0};
    int rc = export_vdb(b, o->in, outfile_name(f), o->out, &err);
    if (rc) {
        cli_error("%s", err.msg);
        return -EINVAL; /* told */
    }
    return 0;
}

/* The one line of a successful export: what was written. */
static void say_written(const export_box *b, const export_opts *o)
{
    static const char *const names[] = {"", "NRRD", "raw", "binvox", "VTK ImageData",
                                        "OpenVDB"};
    struct stat st;
    unsigned long long bytes = stat(o->out, &st) == 0 ? (unsigned long long)st.st_size : 0;
    printf("%s: %s%s, %ux%ux%u voxels of level %d%s, %llu bytes%s%s\n", o->out,
           names[o->fmt], o->gzip ? " (gzip)" : "", b->n[0], b->n[1], b->n[2], b->level,
           b->normals && o->fmt != FMT_BINVOX ? " with normals" : "", bytes,
           o->json ? "; its header in " : "", o->json ? o->json : "");
}

/* Made by outfile (unnamed until whole, then linked onto OUT); the stream
 * is flushed but the descriptor left to outfile, which syncs and closes it. */
static int write_out(const export_box *b, const export_opts *o)
{
    outfile f;
    cli_catch_interrupts();
    int rc = outfile_open(&f, o->out);
    if (rc) {
        cli_error("%s: cannot create: %s", o->out, strerror(-rc));
        return CLI_EXIT_FAILED;
    }
    if (o->fmt == FMT_VDB) rc = write_vdb(b, o, &f);
    else {
        FILE *fp = fdopen(dup(f.fd), "wb");
        rc = fp ? write_format(b, o, fp) : -errno;
        errno = 0;
        if (fp && fclose(fp) && !rc) rc = errno ? -errno : -EIO;
    }
    if (!rc && cli_interrupted()) rc = -ECANCELED;
    if (!rc) rc = outfile_commit(&f, o->out);
    else outfile_abort(&f);
    if (!rc && o->fmt == FMT_RAW && (rc = write_json(b, o))) unlink(o->out);
    if (cli_interrupted()) cli_end_interrupted(o->out);
    if (rc) {
        if (rc != -EINVAL) cli_error("%s: %s", o->out, strerror(-rc));
        return CLI_EXIT_FAILED;
    }
    say_written(b, o);
    return CLI_EXIT_OK;
}

int cli_export(int argc, char **argv)
{
    for (int i = 1; i < argc; i++)
        if (!strcmp(argv[i], "--help") || !strcmp(argv[i], "-h")) {
            fputs(usage_text, stdout);
            return CLI_EXIT_OK;
        }
    export_opts o;
    int rc = parse_opts(argc, argv, &o);
    if (rc) return rc;
    char json[4096];
    if (o.fmt == FMT_RAW) {
        /* OUT.raw's sidecar is OUT.json; any other name gets .json added */
        size_t n = strlen(o.out);
        int ext = n > 4 && !strcmp(o.out + n - 4, ".raw");
        if (snprintf(json, sizeof json, "%.*s.json", (int)(ext ? n - 4 : n), o.out) >=
            (int)sizeof json) {
            cli_error("%s: name too long", o.out);
            return CLI_EXIT_USAGE;
        }
        o.json = json;
    }
    vod_file *f;
    err_info err = {0};
    if (vod_open_levels(o.in, (int)cli_cores(), 1u << o.level, &f, &err)) {
        cli_error("%s: %s", o.in, err.msg);
        return CLI_EXIT_FAILED;
    }
    export_box b;
    rc = make_box(f, &o, &b);
    if (!rc) rc = write_out(&b, &o);
    vod_close(f);
    return rc;
}
