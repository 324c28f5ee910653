"""Checks of a channel-4 (signed distance) VOD file and its exports, for
distance_out.sh.  Prints PASS: / FAIL: lines.

    distance_check.py values  T.vod                   voxd.read against the torus's closed form
    distance_check.py exports T.vod DIR VDB_DUMP      every export against voxd.read
    distance_check.py mesh    T.vod T.obj             the zero level's vertices on the torus
    distance_check.py render  T.png S.png             the same pixels lit as its mesh's
"""
import gzip
import json
import os
import subprocess
import sys

import numpy as np

sys.path.insert(0, os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", "..", "python"))
import voxd  # noqa: E402

R, r = 0.6, 0.25  # examples/torus.vx


def report(name, ok, why=""):
    print(("PASS: " if ok else "FAIL: ") + name)
    if not ok and why:
        print("  " + str(why)[:400])


def torus(x, y, z):
    return np.sqrt((np.sqrt(x * x + y * y) - R) ** 2 + z * z) - r


def band_width(v):
    k = int(v.metadata["distance_band"])
    return np.float32(k * v.spacing[0]), k


def centres(v):
    z, y, x = np.indices(v.shape)
    return [v.origin[a] + (i + 0.5) * v.spacing[a] for a, i in enumerate((x, y, z))]


def check_values(vod):
    v = voxd.read(vod)
    report("voxd.read: float32 for channel 4", v.data.dtype == np.float32 and v.channel == 4,
           "%s channel %d" % (v.data.dtype, v.channel))
    report("voxd.read: metadata distance_units=world",
           v.metadata.get("distance_units") == "world", v.metadata)
    w, k = band_width(v)
    x, y, z = centres(v)
    d = torus(x, y, z)
    got = v.data.astype(np.float64)
    band = np.abs(d) < w
    vs = v.spacing[0]
    err = (np.abs(got[band]) - np.abs(d[band])) / vs
    capped = np.abs(got[band]) == w
    worst = float(np.max(np.abs(err[~capped]))) if np.any(~capped) else 0.0
    report("values: %d band voxels within 2e-4 voxel of the closed form (worst %.2g)"
           % (int(band.sum()), worst), band.sum() > 1000 and worst <= 2e-4)
    sign_ok = np.all((got * d > 0) | (got == 0))
    report("values: no voxel of the wrong sign", bool(sign_ok))
    beyond = np.abs(d) > w + 1e-3 * vs
    report("values: +-W (%g, band %d) beyond the band" % (w, k),
           bool(np.all(np.abs(got[beyond]) == w)))
    report("occupancy: 1 inside", np.array_equal(v.occupancy, (d < 0).astype(np.uint8)))


def read_nrrd(path):
    b = open(path, "rb").read()
    head, _, data = b.partition(b"\n\n")
    fields = dict(ln.split(": ", 1) for ln in head.decode().splitlines()[1:]
                  if ": " in ln and not ln.startswith("#"))
    if fields.get("encoding") == "gzip":
        data = gzip.decompress(data)
    sizes = [int(t) for t in fields["sizes"].split()]
    return fields, np.frombuffer(data, "<f4").reshape(sizes[::-1])


def vtk_array(reader_cls, path, name):
    from vtkmodules.util.numpy_support import vtk_to_numpy
    rd = reader_cls()
    rd.SetFileName(path)
    rd.Update()
    im = rd.GetOutput()
    nx, ny, nz = im.GetDimensions()
    pd = im.GetPointData()
    a = pd.GetArray(name) if name else pd.GetScalars()
    if a is None:
        return None, None
    return vtk_to_numpy(a).copy().reshape(nz, ny, nx), im


def check_exports(vod, d, dump):
    v = voxd.read(vod)
    w, k = band_width(v)
    centre = [v.origin[a] + 0.5 * v.spacing[a] for a in range(3)]
    for name in ("x.nrrd", "gz.nrrd"):
        fields, arr = read_nrrd(os.path.join(d, name))
        report(name + ": float, the VOD's values", fields["type"] == "float" and
               arr.dtype == np.float32 and np.array_equal(arr, v.data))
    from vtkmodules.vtkIOImage import vtkNrrdReader
    from vtkmodules.vtkIOXML import vtkXMLImageDataReader
    arr, im = vtk_array(vtkNrrdReader, os.path.join(d, "x.nrrd"), None)
    report("x.nrrd through VTK's vtkNrrdReader: float32, the VOD's values, origin",
           arr is not None and arr.dtype == np.float32 and np.array_equal(arr, v.data) and
           np.allclose(im.GetOrigin(), centre), arr is not None and arr.dtype)
    arr, im = vtk_array(vtkXMLImageDataReader, os.path.join(d, "x.vti"), "distance")
    report("x.vti through VTK's vtkXMLImageDataReader: Float32 \"distance\", the VOD's values",
           arr is not None and arr.dtype == np.float32 and np.array_equal(arr, v.data) and
           np.allclose(im.GetOrigin(), centre) and np.allclose(im.GetSpacing(), v.spacing))
    side = json.load(open(os.path.join(d, "x.json")))
    raw = np.fromfile(os.path.join(d, "x.raw"), side["dtype"]).reshape(side["shape"])
    report("x.raw + x.json: float32, the VOD's values",
           side["dtype"] == "float32" and np.array_equal(raw, v.data))
    # the level set, through OpenVDB's own tools
    out = subprocess.run(["vdb_print", "-l", os.path.join(d, "x.vdb")], capture_output=True,
                         text=True).stdout
    active = int(np.sum(np.abs(v.data) < w * (1 - 1e-6)))
    report("x.vdb: vdb_print reports a level set", "class: level set" in out, out[-300:])
    report("x.vdb: background the band's width %g" % w,
           ("Background value: %g" % w) in out, out[:400])
    report("x.vdb: active voxels the band's %d" % active,
           ("Number of active voxels:" in out and
            int(out.split("Number of active voxels:")[1].split()[0].replace(",", "")) == active))
    n = v.shape
    r_ = subprocess.run([dump, os.path.join(d, "x.vdb"), "surface", "0", str(n[2]), "0", str(n[1]),
                         "0", str(n[0]), os.path.join(d, "x.f32")], capture_output=True, text=True)
    ok = r_.returncode == 0
    report("x.vdb: read by libopenvdb (vdb_dump)", ok, r_.stderr)
    if ok:
        got = np.fromfile(os.path.join(d, "x.f32"), np.float32).reshape(n)
        want = np.where(np.abs(v.data) < w * (1 - 1e-6), v.data, np.where(v.data < 0, -w, w))
        report("x.vdb: every voxel's value (+-background beyond the band)",
               np.array_equal(got, want.astype(np.float32)),
               "%d differ" % int(np.sum(got != want)))
        report("x.vdb: the voxel transform",
               " voxel %.17g" % v.spacing[0] in r_.stdout or
               np.isclose(float(r_.stdout.split()[7]), v.spacing[0]), r_.stdout)


def read_obj(path):
    vs = [list(map(float, ln.split()[1:4])) for ln in open(path) if ln.startswith("v ")]
    return np.array(vs)


def check_mesh(vod, obj):
    v = voxd.read(vod)
    p = read_obj(obj)
    if len(p) == 0:
        report("vox mesh: the zero level has vertices", False)
        return
    e = np.abs(torus(p[:, 0], p[:, 1], p[:, 2])) / v.spacing[0]
    report("vox mesh: %d vertices of the zero level within 0.05 voxel of the torus (worst %.3g)"
           % (len(p), float(e.max())), len(p) > 1000 and e.max() <= 0.05)


def lit(path):
    from vtkmodules.util.numpy_support import vtk_to_numpy
    from vtkmodules.vtkIOImage import vtkPNGReader
    rd = vtkPNGReader()
    rd.SetFileName(path)
    rd.Update()
    im = rd.GetOutput()
    a = vtk_to_numpy(im.GetPointData().GetScalars())
    a = a.reshape(-1, a.shape[1] if a.ndim > 1 else 1)[:, :3]
    return int(np.sum(np.any(a != a[0], axis=1))), len(a)


def check_render(png, ref):
    a, n = lit(png)
    b, _ = lit(ref)
    report("vox render: the zero level drawn (%d pixels lit, its mesh's %d, of %d)"
           % (a, b, n), b > n // 50 and abs(a - b) <= 0.03 * b)


def main():
    mode = sys.argv[1]
    if mode == "values":
        check_values(sys.argv[2])
    elif mode == "exports":
        check_exports(sys.argv[2], sys.argv[3], sys.argv[4])
    elif mode == "mesh":
        check_mesh(sys.argv[2], sys.argv[3])
    elif mode == "render":
        check_render(sys.argv[2], sys.argv[3])
    else:
        report("distance_check.py: mode %s" % mode, False)


if __name__ == "__main__":
    main()
