"""Checks of vox export and of the Python reader (python/voxd), for export.sh.

The readers of the export formats here are written from the formats' own
descriptions, not from vox's writer: NRRD (teem's NRRD format definition:
a "NRRD000N" magic line, "field: value" lines, a blank line, the data; gzip
encoding is a gzip stream), VTK XML ImageData (VTK's file-formats page: the
appended block starts after '_', each array a header_type byte count then
its bytes), binvox (Patrick Min's format page: "#binvox 1", dim, translate,
scale, "data", then (value, count) byte pairs, x slowest, then z, y fastest),
raw + its JSON sidecar (the sidecar's own fields).  OpenVDB files are read by
OpenVDB's own code: vdb_print (libopenvdb-tools) for what it says of the
grids, and vdb_dump (tests/integration/vdb_dump.cc, libopenvdb's reader) for
the voxels; the channel-3 normals are decoded here from the VOD format's
octahedral encoding (docs/vod-format.md, section 7.1).  The NRRD and .vti
exports are also opened by VTK's own readers (vtkNrrdReader, what ParaView
uses, and vtkXMLImageDataReader; Debian's python3-vtk9), the "vtk" command.

Every line printed is "PASS: name" or "FAIL: name"; the exit status is 0
when every check passed, 1 when one failed, 2 when the checker itself broke
(export.sh fails on 2 too, so a checker that cannot run is never a pass).

    export_check.py formats VOD DIR       the exports in DIR against voxd.read
    export_check.py checksum VOD          print vox info's voxel line, from voxd
    export_check.py damage VOD VOX DIR    damaged copies: voxd and vox info agree
    export_check.py vdb VOD DIR DUMP      the .vdb exports in DIR against voxd.read
    export_check.py vtk VOD DIR           the NRRD and .vti exports through VTK
"""

import gzip
import json
import os
import re
import struct
import subprocess
import sys
import zlib

sys.path.insert(0, os.path.join(os.path.dirname(__file__), "..", "..", "python"))
import numpy as np  # noqa: E402
import voxd  # noqa: E402


FAILED = []


def report(name, ok, why=""):
    print(("PASS: " if ok else "FAIL: ") + name)
    if not ok:
        FAILED.append(name)
    if not ok and why:
        print("  " + why)


# ---- readers from the formats' specifications ----

def read_nrrd(path):
    with open(path, "rb") as fp:
        data = fp.read()
    head, sep, body = data.partition(b"\n\n")
    lines = head.decode().split("\n")
    assert re.match(r"NRRD000[1-5]$", lines[0]), lines[0]
    fields, keys = {}, {}
    for ln in lines[1:]:
        if ln.startswith("#"):
            continue
        if ":=" in ln:
            k, v = ln.split(":=", 1)
            keys[k] = v
        else:
            k, v = ln.split(": ", 1)
            fields[k] = v
    sizes = [int(s) for s in fields["sizes"].split()]
    dim = int(fields["dimension"])
    assert dim == len(sizes)
    if fields["type"] in ("uint8", "uchar", "unsigned char"):
        dtype = np.uint8
    else:  # a 4-vector of floats per voxel: its axis is the first (fastest)
        assert fields["type"] == "float" and dim == 4 and sizes[0] == 4, fields["type"]
        assert fields["kinds"].split()[1:] == ["domain"] * 3
        dtype = np.dtype("<f4" if fields["endian"] == "little" else ">f4")
    if fields["encoding"] == "gzip":
        body = gzip.decompress(body)
    else:
        assert fields["encoding"] == "raw", fields["encoding"]
    vec = lambda s: [float(t) for t in s.strip("()").split(",")]  # noqa: E731
    dirs = [vec(t) for t in fields["space directions"].split() if t != "none"]
    assert len(dirs) == 3
    origin = vec(fields["space origin"])
    # the first axis is the fastest: (x, y, z) sizes are a (z, y, x) array
    arr = np.frombuffer(body, dtype).reshape(list(reversed(sizes)))
    return arr, origin, [dirs[a][a] for a in range(3)], dirs, keys


def read_vti(path):
    with open(path, "rb") as fp:
        data = fp.read()
    at = data.index(b"<AppendedData")
    xml = data[:at].decode()
    start = data.index(b"_", at) + 1
    assert 'header_type="UInt64"' in xml and 'byte_order="LittleEndian"' in xml
    ext = [int(t) for t in re.search(r'WholeExtent="([^"]*)"', xml).group(1).split()]
    origin = [float(t) for t in re.search(r'Origin="([^"]*)"', xml).group(1).split()]
    spacing = [float(t) for t in re.search(r'Spacing="([^"]*)"', xml).group(1).split()]
    n = [ext[2 * a + 1] - ext[2 * a] + 1 for a in range(3)]
    arrays, end = {}, 0
    for m in re.finditer(r"<DataArray ([^>]*)/>", xml):
        attr = dict(re.findall(r'(\w+)="([^"]*)"', m.group(1)))
        assert attr["format"] == "appended"
        off, comps = int(attr["offset"]), int(attr.get("NumberOfComponents", "1"))
        dtype = {"UInt8": np.uint8, "Float32": np.dtype("<f4")}[attr["type"]]
        count = struct.unpack_from("<Q", data, start + off)[0]
        assert count == n[0] * n[1] * n[2] * comps * np.dtype(dtype).itemsize, (count, n)
        body = data[start + off + 8:start + off + 8 + count]
        shape = (n[2], n[1], n[0], comps) if comps > 1 else (n[2], n[1], n[0])
        arrays[attr["Name"]] = np.frombuffer(body, dtype).reshape(shape)
        end = max(end, start + off + 8 + count)
    tail = data[end:].strip()
    assert tail.startswith(b"</AppendedData>"), tail[:40]
    return arrays, origin, spacing


def read_binvox(path):
    with open(path, "rb") as fp:
        data = fp.read()
    hdr = {}
    p = 0
    while True:
        e = data.index(b"\n", p)
        ln = data[p:e].decode()
        p = e + 1
        if ln == "data":
            break
        k, _, v = ln.partition(" ")
        hdr[k] = v
    assert hdr["#binvox"] == "1"
    d, h, w = (int(t) for t in hdr["dim"].split())
    pairs = np.frombuffer(data[p:], np.uint8).reshape(-1, 2)
    assert (pairs[:, 1] > 0).all() and set(pairs[:, 0].tolist()) <= {0, 1}
    flat = np.repeat(pairs[:, 0], pairs[:, 1])
    assert flat.size == d * h * w, (flat.size, d, h, w)
    # index = x * (w * h) + z * w + y: an (x, z, y) array
    xzy = flat.reshape(d, h, w)
    zyx = xzy.transpose(1, 2, 0)
    trans = [float(t) for t in hdr["translate"].split()]
    return zyx, trans, float(hdr["scale"])


def read_raw(path, sidecar):
    with open(sidecar) as fp:
        meta = json.load(fp)
    assert meta["dtype"] in ("uint8", "float32")
    if meta["dtype"] == "float32":
        assert meta["byte_order"] == "little" and meta["shape"][3] == 4
        assert meta["components"] == ["occupancy", "nx", "ny", "nz"]
    arr = np.fromfile(path, np.dtype(meta["dtype"]).newbyteorder("<")).reshape(meta["shape"])
    return arr, meta


# ---- checks ----

def close(a, b):
    return all(abs(x - y) <= 1e-6 * max(1.0, abs(y)) for x, y in zip(a, b))


def normals_of(v):
    """Channel 3's normals (z, y, x, 3) from the VOD format's encoding, 0
    where no voxel is; None for the other channels."""
    if v.channel != 3 or v.info["voxel_bits"] != 32:
        return None
    return np.where((v.occupancy != 0)[..., None], octahedral(v.data.astype(np.int64)), 0.0)


def same(arr, v, name, normals=True):
    """An export's array against voxd's volume v: the occupancy bytes
    exactly, or with channel 3's normals (the default unless normals is
    False), (occupancy, nx, ny, nz) floats, the normals to float precision
    (they are rounded to float32)."""
    nrm = normals_of(v) if normals else None
    if nrm is None:
        report(name, arr.dtype == np.uint8 and np.array_equal(arr, v.occupancy),
               "dtype %s shape %s" % (arr.dtype, arr.shape))
        return
    ok = arr.shape == v.shape + (4,)
    report(name + " (occupancy)", ok and np.array_equal(arr[..., 0], v.occupancy.astype(np.float32)),
           "dtype %s shape %s" % (arr.dtype, arr.shape))
    report(name + " (normals)", ok and np.allclose(arr[..., 1:], nrm, rtol=0, atol=1e-6),
           "max error %g" % (np.abs(arr[..., 1:] - nrm).max() if ok else -1))


def check_formats(vod, d):
    name = os.path.basename(vod)
    v0 = voxd.read(vod, 0)
    want = v0.occupancy
    centre = [v0.origin[a] + 0.5 * v0.spacing[a] for a in range(3)]

    arr, origin, spacing, dirs, keys = read_nrrd(os.path.join(d, "x.nrrd"))
    same(arr, v0, name + ": NRRD voxels")
    report(name + ": NRRD space origin and directions",
           close(origin, centre) and close(spacing, v0.spacing) and
           all(dirs[a][b] == 0 for a in range(3) for b in range(3) if a != b),
           "%s %s" % (origin, spacing))
    report(name + ": NRRD channel key", keys.get("vod_channel") == str(v0.channel))

    arr, _, _, _, keys = read_nrrd(os.path.join(d, "gz.nrrd"))
    same(arr, v0, name + ": NRRD gzip voxels")

    if normals_of(v0) is not None:
        arr, _, _, _, _ = read_nrrd(os.path.join(d, "nn.nrrd"))
        same(arr, v0, name + ": NRRD voxels (--no-normals)", normals=False)

    arr, meta = read_raw(os.path.join(d, "x.raw"), os.path.join(d, "x.json"))
    same(arr, v0, name + ": raw voxels")
    report(name + ": raw sidecar", close(meta["origin"], v0.origin) and
           close(meta["spacing"], v0.spacing) and meta["channel"] == v0.channel and
           meta["level"] == 0, str(meta))

    arrays, origin, spacing = read_vti(os.path.join(d, "x.vti"))
    report(name + ": VTI voxels", np.array_equal(arrays["voxel"], want))
    nrm = normals_of(v0)
    report(name + ": VTI arrays", sorted(arrays) == (["normal", "voxel"] if nrm is not None
                                                     else ["voxel"]), str(sorted(arrays)))
    if nrm is not None and "normal" in arrays:
        report(name + ": VTI normals", np.allclose(arrays["normal"], nrm, rtol=0, atol=1e-6))
    report(name + ": VTI origin and spacing", close(origin, centre) and
           close(spacing, v0.spacing))

    if os.path.exists(os.path.join(d, "x.binvox")):
        arr, trans, scale = read_binvox(os.path.join(d, "x.binvox"))
        occ = (want > 127) if v0.channel == 2 else (want != 0)
        z, y, x = want.shape
        ok = arr.shape[0] == max(want.shape) and np.array_equal(
            arr[:z, :y, :x], occ.astype(np.uint8)) and not arr[z:].any() and \
            not arr[:, y:].any() and not arr[:, :, x:].any()
        report(name + ": binvox voxels", ok)
        report(name + ": binvox translate and scale", close(trans, v0.origin) and
               close([scale], [arr.shape[0] * v0.spacing[0]]))

    # level 1, gzip NRRD, against voxd's level 1
    v1 = voxd.read(vod, 1)
    arr, origin, spacing, _, keys = read_nrrd(os.path.join(d, "l1.nrrd"))
    same(arr, v1, name + ": NRRD gzip level 1 voxels")
    report(name + ": NRRD level 1 spacing", close(spacing, [2 * s for s in v0.spacing])
           and keys.get("vod_level") == "1")

    # a box: X0,X1,Y0,Y1,Z0,Z1 of the level's indices, written in box.txt
    with open(os.path.join(d, "box.txt")) as fp:
        b = [int(t) for t in fp.read().split(",")]
    arr, meta = read_raw(os.path.join(d, "box.raw"), os.path.join(d, "box.json"))
    box = lambda a: a[b[4]:b[5], b[2]:b[3], b[0]:b[1]]  # noqa: E731
    if normals_of(v0) is None:
        report(name + ": raw --bbox voxels", np.array_equal(arr, box(want)))
    else:
        report(name + ": raw --bbox voxels", np.array_equal(arr[..., 0], box(want)) and
               np.allclose(arr[..., 1:], box(normals_of(v0)), rtol=0, atol=1e-6))
    report(name + ": raw --bbox origin", close(
        meta["origin"], [v0.origin[a] + b[2 * a] * v0.spacing[a] for a in range(3)]))


def octahedral(raw):
    """Unit normals (..., 3) of channel-3 voxels: bits 8-19 u, 20-31 v, each
    code / 4095 * 2 - 1; z = 1 - |u| - |v|, folded where negative."""
    u = ((raw >> 8) & 0xFFF) / 4095.0 * 2.0 - 1.0
    v = ((raw >> 20) & 0xFFF) / 4095.0 * 2.0 - 1.0
    z = 1.0 - np.abs(u) - np.abs(v)
    sgn = lambda t: np.where(t < 0, -1.0, 1.0)  # noqa: E731
    fu = np.where(z < 0, (1.0 - np.abs(v)) * sgn(u), u)
    fv = np.where(z < 0, (1.0 - np.abs(u)) * sgn(v), v)
    n = np.stack([fu, fv, z], axis=-1)
    return n / np.linalg.norm(n, axis=-1, keepdims=True)


def vdb_print(path):
    """{grid name: (tree type, active voxels)} from vdb_print -l."""
    out = subprocess.run(["vdb_print", "-l", path], capture_output=True, text=True,
                         check=True).stdout
    grids, name = {}, None
    for ln in out.splitlines():
        ln = ln.strip()
        if ln.startswith("Name: "):
            name = ln[6:]
        elif ln.startswith("Type: ") and name:
            grids[name] = [ln[6:], None]
        elif ln.startswith("Number of active voxels:") and name:
            grids[name][1] = int(ln.split(":")[1].replace(",", ""))
    return grids


def vdb_dump(dump, path, grid, lo, hi, out):
    r = subprocess.run([dump, path, grid] + [str(t) for a in range(3) for t in (lo[a], hi[a])]
                       + [out], capture_output=True, text=True)
    assert r.returncode == 0, r.stderr
    f = r.stdout.split()
    info = {"type": f[1], "active": int(f[3]), "tiles": int(f[5]),
            "voxel": [float(t) for t in f[7:10]], "world0": [float(t) for t in f[11:14]]}
    arr = np.fromfile(out, np.float32)
    n = [hi[a] - lo[a] for a in range(3)]
    shape = (n[2], n[1], n[0], 3) if info["type"] == "vec3s" else (n[2], n[1], n[0])
    return arr.reshape(shape), info


def check_vdb_one(name, vod, path, level, lo, hi, dump, d):
    """One .vdb export of level `level`, box [lo, hi) (x, y, z), against
    voxd.read: the scalar grid's values and activity exactly, the normals
    to float precision, the transform, and vdb_print's counts."""
    v = voxd.read(vod, level)
    sub = v.occupancy[lo[2]:hi[2], lo[1]:hi[1], lo[0]:hi[0]]
    bits = v.info["voxel_bits"]
    gname = "occupancy" if bits == 1 else "density"
    arr, info = vdb_dump(dump, path, gname, lo, hi, os.path.join(d, "dump.f32"))
    if bits == 1:
        want = np.where(sub != 0, 1.0, -1.0).astype(np.float32)
    else:
        want = np.where(sub != 0, sub.astype(np.float32) / np.float32(255), -1.0)
    report(name + ": VDB %s voxels" % gname, np.array_equal(arr, want.astype(np.float32)))
    report(name + ": VDB active voxels", info["active"] == np.count_nonzero(sub),
           "%d vs %d" % (info["active"], np.count_nonzero(sub)))
    centre = [v.origin[a] + 0.5 * v.spacing[a] for a in range(3)]
    report(name + ": VDB transform", close(info["voxel"], v.spacing) and
           close(info["world0"], centre), str(info))
    grids = vdb_print(path)
    want_grids = {gname: ["Tree_%s_5_4_3" % ("bool" if bits == 1 else "float"),
                          int(np.count_nonzero(sub))]}
    if v.channel == 3 and bits == 32:
        want_grids["normal"] = ["Tree_vec3s_5_4_3", int(np.count_nonzero(sub))]
        raw = v.data[lo[2]:hi[2], lo[1]:hi[1], lo[0]:hi[0]].astype(np.int64)
        nrm = np.where((sub != 0)[..., None], octahedral(raw), 0.0)
        arr, info = vdb_dump(dump, path, "normal", lo, hi, os.path.join(d, "dump.f32"))
        report(name + ": VDB normals", np.allclose(arr, nrm, rtol=0, atol=1e-6),
               "max error %g" % np.abs(arr - nrm).max())
    report(name + ": vdb_print's grids and counts", grids == want_grids,
           "%s, want %s" % (grids, want_grids))


def check_vdb(vod, d, dump):
    name = os.path.basename(vod)
    v0 = voxd.read(vod, 0)
    z, y, x = v0.shape
    check_vdb_one(name, vod, os.path.join(d, "x.vdb"), 0, (0, 0, 0), (x, y, z), dump, d)
    z, y, x = voxd.read(vod, 1).shape
    check_vdb_one(name + " level 1", vod, os.path.join(d, "l1.vdb"), 1, (0, 0, 0),
                  (x, y, z), dump, d)
    with open(os.path.join(d, "box.txt")) as fp:
        b = [int(t) for t in fp.read().split(",")]
    check_vdb_one(name + " --bbox", vod, os.path.join(d, "box.vdb"), 0, b[0::2], b[1::2],
                  dump, d)


# ---- VTK's readers (what ParaView and 3D Slicer's VTK side use) ----

def vtk_image(reader, path):
    """(array (z, y, x[, comps]) of the active scalars, {name: array}, dims,
    origin, spacing, errors VTK reported) of one file read by VTK."""
    from vtkmodules.vtkCommonCore import vtkFileOutputWindow, vtkOutputWindow
    from vtkmodules.util.numpy_support import vtk_to_numpy
    log = path + ".vtklog"
    win = vtkFileOutputWindow()
    win.SetFileName(log)
    vtkOutputWindow.SetInstance(win)
    r = reader()
    r.SetFileName(path)
    r.Update()
    im = r.GetOutput()
    nx, ny, nz = im.GetDimensions()
    pd = im.GetPointData()
    arrays = {}
    for i in range(pd.GetNumberOfArrays()):
        a = pd.GetArray(i)
        c = a.GetNumberOfComponents()
        shape = (nz, ny, nx, c) if c > 1 else (nz, ny, nx)
        # a copy: the VTK array's memory goes with the reader
        arrays[a.GetName() or ""] = vtk_to_numpy(a).copy().reshape(shape)
    sc = pd.GetScalars()
    main_arr = arrays[sc.GetName() or ""] if sc is not None else None
    errs = open(log).read() if os.path.exists(log) else ""
    return main_arr, arrays, (nx, ny, nz), im.GetOrigin(), im.GetSpacing(), errs


def check_vtk_nrrd(name, path, v, normals=True):
    from vtkmodules.vtkIOImage import vtkNrrdReader
    arr, _, dims, origin, spacing, errs = vtk_image(vtkNrrdReader, path)
    z, y, x = v.shape
    centre = [v.origin[a] + 0.5 * v.spacing[a] for a in range(3)]
    report(name + ": dimensions %dx%dx%d, no error" % (x, y, z),
           dims == (x, y, z) and "ERROR" not in errs, "VTK: %s %s" % (dims, errs[:300]))
    report(name + ": origin and spacing", close(origin, centre) and close(spacing, v.spacing),
           "%s %s" % (origin, spacing))
    if arr is not None and dims == (x, y, z):
        same(arr, v, name + ": voxels", normals=normals)


def check_vtk(vod, d):
    """Every NRRD and the .vti through VTK: the voxels of voxd.read exactly
    (the normals to float precision), dimensions, origin and spacing.
    Not the gzip NRRD of floats: VTK 9.1's vtkNrrdReader inflates only the
    first quarter of a gzip float array (it counts the bytes as if one per
    value; Python's gzip, teem and our reader read the same file whole),
    so channel 3's gzip exports are opened by VTK with --no-normals only."""
    name = os.path.basename(vod) + ": VTK vtkNrrdReader"
    v0, v1 = voxd.read(vod, 0), voxd.read(vod, 1)
    floats = normals_of(v0) is not None
    # the gzip files first: a reader that fills only part of its array
    # would show through, not the heap's copy of a file read before
    if floats:
        check_vtk_nrrd(name + " gzip --no-normals", os.path.join(d, "gznn.nrrd"), v0,
                       normals=False)
        check_vtk_nrrd(name + " --no-normals", os.path.join(d, "nn.nrrd"), v0, normals=False)
    else:
        check_vtk_nrrd(name + " gzip", os.path.join(d, "gz.nrrd"), v0)
        check_vtk_nrrd(name + " gzip level 1", os.path.join(d, "l1.nrrd"), v1)
    check_vtk_nrrd(name + " x.nrrd", os.path.join(d, "x.nrrd"), v0)
    from vtkmodules.vtkIOXML import vtkXMLImageDataReader
    name = os.path.basename(vod) + ": VTK vtkXMLImageDataReader"
    _, arrays, dims, origin, spacing, errs = vtk_image(vtkXMLImageDataReader,
                                                        os.path.join(d, "x.vti"))
    z, y, x = v0.shape
    centre = [v0.origin[a] + 0.5 * v0.spacing[a] for a in range(3)]
    report(name + ": dimensions, origin and spacing, no error",
           dims == (x, y, z) and close(origin, centre) and close(spacing, v0.spacing) and
           "ERROR" not in errs, "%s %s %s %s" % (dims, origin, spacing, errs[:300]))
    report(name + ": voxels", "voxel" in arrays and arrays["voxel"].dtype == np.uint8 and
           np.array_equal(arrays["voxel"], v0.occupancy))
    nrm = normals_of(v0)
    if nrm is not None:
        report(name + ": normals", "normal" in arrays and
               np.allclose(arrays["normal"], nrm, rtol=0, atol=1e-6))
    else:
        report(name + ": no normals array", sorted(arrays) == ["voxel"], str(sorted(arrays)))


def checksum_line(vod):
    """vox info's 'voxels' line: the count of non-empty level-0 voxels and
    the sum of CRC-32s of (level, x, y, z, value) over every level."""
    v = voxd.read(vod, 0)
    total, n0 = 0, 0
    for level in range(v.info["height"]):
        data = voxd.read(vod, level).data if level else v.data
        raw = data.view(np.uint32) if data.dtype.kind == "f" else data
        z, y, x = np.nonzero(raw)
        vals = raw[z, y, x].astype(np.uint32)
        if level == 0:
            n0 = len(vals)
        recs = np.stack([np.full(len(vals), level, np.uint32), x.astype(np.uint32),
                         y.astype(np.uint32), z.astype(np.uint32), vals], axis=1)
        recs = recs.astype("<u4")
        for r in recs:
            total = (total + zlib.crc32(r.tobytes())) & 0xFFFFFFFF
    return "  voxels      %d non-empty at full resolution; content checksum %08x" % (
        n0, total)


def fix_crc(b):
    b = bytearray(b)
    struct.pack_into("<I", b, len(b) - 4, zlib.crc32(bytes(b[:-4])) & 0xFFFFFFFF)
    return bytes(b)


def damaged(b):
    """(name, bytes): truncations, flipped bytes, and changes under a
    recomputed CRC so that the checks behind the CRC are reached too."""
    n = len(b)
    u32 = lambda at: struct.unpack_from("<I", b, at)[0]  # noqa: E731
    nodes = ((1 << (3 * u32(44))) - 1) // 7
    table = 64 + 4 * nodes + 4
    out = [("empty", b""), ("header cut", b[:40])]
    for cut in (64, 100, n // 2, n - 13, n - 1):
        out.append(("truncated to %d" % cut, b[:cut]))
    for at in (0, 5, 45, n // 3, n - 20, n - 6, n - 2):
        out.append(("byte %d flipped" % at,
                    b[:at] + bytes([b[at] ^ 0x40]) + b[at + 1:]))

    def patch(at, val):
        c = bytearray(b)
        struct.pack_into("<I", c, at, val)
        return fix_crc(bytes(c))

    first = u32(table + 4)  # brick 1's record offset
    out += [
        ("fileVersion 2, CRC fixed", patch(4, 2)),
        ("brickSize 17, CRC fixed", patch(20, 17)),
        ("voxelSize 7, CRC fixed", patch(48, 7)),
        ("treeHeight 9, CRC fixed", patch(44, 9)),
        ("flags reserved bit, CRC fixed", patch(60, u32(60) | 8)),
        ("hash 'ABCD', CRC fixed", patch(52, 0x44434241)),
        ("brick ID 999 in the tree, CRC fixed", patch(64, 999)),
        ("duplicate table ID, CRC fixed",
         patch(table + 12, u32(table)) if u32(table - 4) > 1 else patch(table, 0)),
        ("brick offset past the end, CRC fixed", patch(table + 4, n + 100)),
        ("brick hash wrong, CRC fixed", patch(table + 8, u32(table + 8) ^ 1)),
        ("brick data byte flipped, CRC fixed",
         fix_crc(b[:first + 6] + bytes([b[first + 6] ^ 0x10]) + b[first + 7:])),
        ("dataSize + 1, CRC fixed", patch(first, u32(first) + 1)),
        ("trailer channel 9, CRC fixed", patch(u32(n - 12) + 20, 9)),
    ]
    return out


def check_damage(vod, vox, d):
    name = os.path.basename(vod)
    with open(vod, "rb") as fp:
        good = fp.read()
    for what, data in damaged(good):
        path = os.path.join(d, "damaged.vod")
        with open(path, "wb") as fp:
            fp.write(data)
        r = subprocess.run([vox, "info", path], capture_output=True, text=True)
        prefix = "vox: %s: " % path
        c_msg = r.stderr.strip()
        c_msg = c_msg[len(prefix):] if c_msg.startswith(prefix) else c_msg
        try:
            voxd.read(path)
            py_msg = None
        except voxd.VodError as e:
            py_msg = str(e)
        ok = r.returncode == 1 and py_msg is not None and py_msg == c_msg
        report("%s, %s: voxd refuses it as vox info does" % (name, what), ok,
               "vox info (exit %d): %r; voxd: %r" % (r.returncode, c_msg, py_msg))


def main():
    try:
        run(sys.argv[1])
    except Exception as e:  # a reader that cannot parse an export fails the check
        report("export_check.py %s %s runs" % (sys.argv[1], sys.argv[2]), False,
               "%s: %s" % (type(e).__name__, e))
        sys.exit(2)
    sys.exit(1 if FAILED else 0)


def run(cmd):
    if cmd == "formats":
        check_formats(sys.argv[2], sys.argv[3])
    elif cmd == "checksum":
        print(checksum_line(sys.argv[2]))
    elif cmd == "damage":
        check_damage(sys.argv[2], sys.argv[3], sys.argv[4])
    elif cmd == "vdb":
        check_vdb(sys.argv[2], sys.argv[3], sys.argv[4])
    elif cmd == "vtk":
        check_vtk(sys.argv[2], sys.argv[3])
    else:
        raise ValueError("unknown command " + cmd)


if __name__ == "__main__":
    main()
