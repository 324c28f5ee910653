"""bench-iso-vtk.py VOD ISO REPEATS THREADS...: VTK's vtkFlyingEdges3D on the
samples `vox mesh VOD --iso ISO` polygonizes, for scripts/bench-iso.sh.

The samples are level 0 of the file read by the repository's Python reader
(python/voxd), one byte per voxel as vox mesh reads them (channel 1 as 0/255,
channel 2 its density, channel 3 its occupancy byte), surrounded by one layer
of empty samples as vox mesh surrounds them (docs/mesh-extraction.md), at the
voxel centres.  vox mesh puts a vertex where an edge's values reach ISO + 0.5,
so the filter's contour value is ISO + 0.5: on every crossed edge the two
programs place the same vertex.  Normals, gradients and scalars are off (the
filter's fastest pass).

For each thread count T (1: VTK's Sequential backend; more: its TBB backend,
or STDThread where TBB is missing, with T threads) the filter's Update() is
timed REPEATS times, the input modified before each so that it runs again.
One line per thread count on stdout:

    backend=NAME threads=T mean=S sd=S cpu=S triangles=N vertices=N

(cpu: the process's CPU seconds in Update(), all its threads, the mean.)

and a first line "setup=S" (the numpy array wrapped as vtkImageData, after
the file was read; the read itself is not timed: the Python reader checks
every hash in Python, which says nothing about VTK).
"""

import statistics
import sys
import time

import numpy as np
import voxd
from vtkmodules.util import numpy_support
from vtkmodules.vtkCommonCore import vtkSMPTools
from vtkmodules.vtkCommonDataModel import vtkImageData
from vtkmodules.vtkFiltersCore import vtkFlyingEdges3D


def image(vol):
    """The level's bytes, padded by one empty sample on every side."""
    a = np.pad(vol.occupancy, 1)
    if vol.info["voxel_bits"] == 1:
        a = a * np.uint8(255)  # occupancy 1 reads as 255 in vox mesh
    img = vtkImageData()
    img.SetDimensions(a.shape[2], a.shape[1], a.shape[0])
    img.SetSpacing(*vol.spacing)
    # sample j of the padded array is voxel j - 1, centred at origin + (j - 0.5) s
    img.SetOrigin(*(o - 0.5 * s for o, s in zip(vol.origin, vol.spacing)))
    arr = numpy_support.numpy_to_vtk(np.ascontiguousarray(a).ravel(), deep=False)
    arr.SetName("samples")
    img.GetPointData().SetScalars(arr)
    return img, a  # a: keeps the array alive under the shallow wrap


def backend_for(threads):
    if threads == 1:
        return "Sequential"
    for name in ("TBB", "STDThread"):
        if vtkSMPTools.SetBackend(name) and vtkSMPTools.GetBackend() == name:
            return name
    return vtkSMPTools.GetBackend()


def run(img, iso, repeats, threads):
    name = backend_for(threads)
    vtkSMPTools.SetBackend(name)
    vtkSMPTools.Initialize(threads)
    fe = vtkFlyingEdges3D()
    fe.SetInputData(img)
    fe.SetValue(0, iso + 0.5)
    fe.ComputeNormalsOff()
    fe.ComputeGradientsOff()
    fe.ComputeScalarsOff()
    fe.InterpolateAttributesOff()
    secs, cpu = [], []
    for _ in range(repeats):
        img.Modified()
        t0, c0 = time.perf_counter(), time.process_time()
        fe.Update()
        secs.append(time.perf_counter() - t0)
        cpu.append(time.process_time() - c0)
    out = fe.GetOutput()
    sd = statistics.stdev(secs) if len(secs) > 1 else 0.0
    print("backend=%s threads=%d mean=%.4f sd=%.4f cpu=%.4f triangles=%d vertices=%d" % (
        vtkSMPTools.GetBackend(), vtkSMPTools.GetEstimatedNumberOfThreads(),
        statistics.mean(secs), sd, statistics.mean(cpu), out.GetNumberOfPolys(),
        out.GetNumberOfPoints()))


def main(argv):
    if len(argv) < 5:
        sys.exit("usage: bench-iso-vtk.py VOD ISO REPEATS THREADS...")
    vol = voxd.read(argv[1], level=0)
    iso, repeats = int(argv[2]), int(argv[3])
    t0 = time.perf_counter()
    img, keep = image(vol)
    print("setup=%.4f" % (time.perf_counter() - t0))
    for t in argv[4:]:
        run(img, iso, repeats, int(t))
    del keep


if __name__ == "__main__":
    main(sys.argv)
