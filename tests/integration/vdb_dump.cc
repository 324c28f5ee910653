// vdb_dump: an OpenVDB file read through libopenvdb's own reader, for
// export.sh, which compares it with voxd.read (vox's writer is not used).
//
//   vdb_dump FILE.vdb GRID X0 X1 Y0 Y1 Z0 Z1 OUT.f32
//
// prints one line
//   type T active N tiles K voxel SX SY SZ world0 WX WY WZ class C background B
// (T the grid's value type; N its active voxels; world0 index (0,0,0) in
// world units; C the grid class, B a float grid's background) and writes
// the index box [X0,X1) x [Y0,Y1) x [Z0,Z1) to OUT.f32 as float32, x
// fastest: a scalar grid's active value (a bool as 1), -1 where a voxel is
// inactive (a level set's value there, its +-background, instead); a vec3
// grid's three components, 0 0 0 where inactive.  Exit status 1 with a message on any error.
#include <cstdio>
#include <cstdlib>
#include <string>
#include <vector>

#include <openvdb/io/File.h>
#include <openvdb/openvdb.h>

namespace {

template <typename GridT, typename F>
void dump(const GridT &g, const int b[6], std::vector<float> &out, F put)
{
    auto acc = g.getConstAccessor();
    for (int z = b[4]; z < b[5]; z++)
        for (int y = b[2]; y < b[3]; y++)
            for (int x = b[0]; x < b[1]; x++) {
                openvdb::Coord c(x, y, z);
                typename GridT::ValueType v = g.background();
                bool on = acc.probeValue(c, v);
                put(out, on, v);
            }
}

} // namespace

int main(int argc, char **argv)
{
    if (argc != 10) {
        std::fprintf(stderr, "usage: vdb_dump FILE GRID X0 X1 Y0 Y1 Z0 Z1 OUT.f32\n");
        return 2;
    }
    int b[6];
    for (int i = 0; i < 6; i++) b[i] = std::atoi(argv[3 + i]);
    try {
        openvdb::initialize();
        openvdb::io::File f(argv[1]);
        f.open(false); // no delayed loading: inactive values read whole too
        // read whole while the file is open (delayed loading reads leaves
        // from the file on first use)
        openvdb::GridBase::Ptr base = f.readGrid(argv[2])->deepCopyGrid();
        f.close();
        std::vector<float> out;
        float bg = 0;
        std::string type = base->valueType();
        if (auto g = openvdb::gridPtrCast<openvdb::BoolGrid>(base))
            dump(*g, b, out, [](std::vector<float> &o, bool on, bool v) {
                o.push_back(on ? float(v) : -1.0f);
            });
        else if (auto g = openvdb::gridPtrCast<openvdb::FloatGrid>(base)) {
            bool ls = g->getGridClass() == openvdb::GRID_LEVEL_SET;
            dump(*g, b, out, [ls](std::vector<float> &o, bool on, float v) {
                o.push_back(on || ls ? v : -1.0f);
            });
            bg = g->background();
        }
        else if (auto g = openvdb::gridPtrCast<openvdb::Vec3SGrid>(base))
            dump(*g, b, out, [](std::vector<float> &o, bool on, openvdb::Vec3s v) {
                for (int a = 0; a < 3; a++) o.push_back(on ? v[a] : 0.0f);
            });
        else {
            std::fprintf(stderr, "vdb_dump: grid %s has type %s\n", argv[2], type.c_str());
            return 1;
        }
        openvdb::Vec3d vs = base->voxelSize(), w0 = base->indexToWorld(openvdb::Vec3d(0, 0, 0));
        std::printf("type %s active %llu tiles %llu voxel %.17g %.17g %.17g world0 %.17g %.17g %.17g"
                    " class %s background %.9g\n",
                    type.c_str(), (unsigned long long)base->activeVoxelCount(),
                    (unsigned long long)base->baseTreePtr()->activeTileCount(), vs[0], vs[1],
                    vs[2], w0[0], w0[1], w0[2],
                    openvdb::GridBase::gridClassToString(base->getGridClass()).c_str(), double(bg));
        FILE *fp = std::fopen(argv[9], "wb");
        if (!fp || std::fwrite(out.data(), sizeof(float), out.size(), fp) != out.size() ||
            std::fclose(fp)) {
            std::fprintf(stderr, "vdb_dump: cannot write %s\n", argv[9]);
            return 1;
        }
    } catch (const std::exception &e) {
        std::fprintf(stderr, "vdb_dump: %s: %s\n", argv[1], e.what());
        return 1;
    }
    return 0;
}
