"""vox render's camera options (--perspective, --fov, --azimuth, --elevation,
--size) against pictures computed here, for render_camera.sh.

The camera is written again from docs/cli.md: it looks at the centre of the
frame box (a mesh's bounding box) from azimuth a about +z from +x and
elevation e above the xy-plane, +z up on the picture, not mirrored;
orthographic, the box's corners fill the picture less a margin of 5% on
each side; perspective, the camera stands at the nearest distance at which
every corner projects inside that frame, the fov being the vertical angle.
From it the test computes, for meshes it writes (an icosphere, two small
spheres off the centre):
  - the silhouette of a sphere at the box's centre: a disc of radius
    focal * r / sqrt(D^2 - r^2) pixels in perspective (D the camera's
    distance, focal = height / 2 / tan(fov / 2)), scale * r orthographic;
    the disc's radius measured from its area;
  - where the centre of each small sphere falls in the picture.
The PNG is decoded here (zlib and the five filters of the PNG
specification).  Every line is "PASS: name" or "FAIL: name"; exit 0 when all
passed, 1 when one failed, 2 when the checker broke.

    render_check.py VOX DIR
"""

import math
import os
import struct
import subprocess
import sys
import zlib

import numpy as np

FAILED = []
MARGIN = 0.05


def report(name, ok, why=""):
    print(("PASS: " if ok else "FAIL: ") + name)
    if not ok:
        FAILED.append(name)
        if why:
            print("  " + why)


# ---- PNG ----

def paeth(a, b, c):
    p = a + b - c
    pa, pb, pc = abs(p - a), abs(p - b), abs(p - c)
    return a if pa <= pb and pa <= pc else (b if pb <= pc else c)


def read_png(path):
    with open(path, "rb") as fp:
        b = fp.read()
    assert b[:8] == b"\x89PNG\r\n\x1a\n", "not a PNG"
    at, idat, w = 8, b"", None
    while at < len(b):
        n, kind = struct.unpack(">I4s", b[at:at + 8])
        body = b[at + 8:at + 8 + n]
        if kind == b"IHDR":
            w, h, depth, ctype, _, _, interlace = struct.unpack(">IIBBBBB", body)
            assert depth == 8 and ctype in (2, 6) and interlace == 0, (depth, ctype, interlace)
            bpp = 3 if ctype == 2 else 4
        elif kind == b"IDAT":
            idat += body
        at += 12 + n
    raw = zlib.decompress(idat)
    stride = w * bpp
    out = np.zeros((h, stride), np.uint8)
    prev = [0] * stride
    for y in range(h):
        f = raw[y * (stride + 1)]
        line = list(raw[y * (stride + 1) + 1:(y + 1) * (stride + 1)])
        for i in range(stride):
            a = line[i - bpp] if i >= bpp else 0
            c = prev[i - bpp] if i >= bpp else 0
            line[i] = (line[i] + (0, a, prev[i], (a + prev[i]) // 2, paeth(a, prev[i], c))[f]) & 255
        out[y] = line
        prev = line
    return out.reshape(h, w, bpp)[..., :3]


# ---- meshes ----

def icosphere(level, c, r):
    t = (1 + 5 ** 0.5) / 2
    v = [(-1, t, 0), (1, t, 0), (-1, -t, 0), (1, -t, 0), (0, -1, t), (0, 1, t), (0, -1, -t),
         (0, 1, -t), (t, 0, -1), (t, 0, 1), (-t, 0, -1), (-t, 0, 1)]
    v = [np.array(p) / np.linalg.norm(p) for p in v]
    f = [(0, 11, 5), (0, 5, 1), (0, 1, 7), (0, 7, 10), (0, 10, 11), (1, 5, 9), (5, 11, 4),
         (11, 10, 2), (10, 7, 6), (7, 1, 8), (3, 9, 4), (3, 4, 2), (3, 2, 6), (3, 6, 8),
         (3, 8, 9), (4, 9, 5), (2, 4, 11), (6, 2, 10), (8, 6, 7), (9, 8, 1)]
    for _ in range(level):
        mid, nf = {}, []

        def m(a, b):
            k = (min(a, b), max(a, b))
            if k not in mid:
                p = v[a] + v[b]
                v.append(p / np.linalg.norm(p))
                mid[k] = len(v) - 1
            return mid[k]
        for a, b, d in f:
            ab, bd, da = m(a, b), m(b, d), m(d, a)
            nf += [(a, ab, da), (b, bd, ab), (d, da, bd), (ab, bd, da)]
        f = nf
    return [tuple(np.float32(c[k] + r * p[k]) for k in range(3)) for p in v], f


def write_obj(path, parts):
    verts, faces = [], []
    for vs, fs in parts:
        base = len(verts)
        verts += vs
        faces += [tuple(base + i for i in t) for t in fs]
    with open(path, "w") as fp:
        for p in verts:
            fp.write("v %.9g %.9g %.9g\n" % p)
        for t in faces:
            fp.write("f %d %d %d\n" % tuple(i + 1 for i in t))
    a = np.array(verts, np.float64)
    return a.min(axis=0), a.max(axis=0)


# ---- the camera, from docs/cli.md ----

def basis(az, el):
    a, e = math.radians(az), math.radians(el)
    f = np.array([-math.cos(e) * math.cos(a), -math.cos(e) * math.sin(a), -math.sin(e)])
    r = np.cross(f, [0, 0, 1.0])
    r /= np.linalg.norm(r)
    return f, r, np.cross(r, f)


class Camera:
    def __init__(self, lo, hi, size, az, el, fov=None):
        self.f, self.r, self.u = basis(az, el)
        self.c = (lo + hi) / 2
        self.size, self.fov = size, fov
        fill = 1 - 2 * MARGIN
        corners = [np.array([(hi if i >> k & 1 else lo)[k] for k in range(3)]) - self.c
                   for i in range(8)]
        if fov is None:
            ext = max(max(abs(d @ self.r), abs(d @ self.u)) for d in corners)
            self.scale = 0.5 * size * fill / ext
        else:
            t = math.tan(math.radians(fov) / 2)
            self.dist = max(max(abs(d @ self.r), abs(d @ self.u)) / (t * fill) - d @ self.f
                            for d in corners)
            self.focal = 0.5 * size / t
            self.eye = self.c - self.dist * self.f

    def project(self, p):
        if self.fov is None:
            d = p - self.c
            k = self.scale
            x, y = d @ self.r * k, d @ self.u * k
        else:
            d = p - self.eye
            z = d @ self.f
            x, y = self.focal * (d @ self.r) / z, self.focal * (d @ self.u) / z
        return self.size / 2 + x, self.size / 2 - y

    def disc_radius(self, p, r):
        """The silhouette's radius in pixels of a sphere (centre p, radius r)
        seen straight on (p on the axis)."""
        if self.fov is None:
            return self.scale * r
        D = np.linalg.norm(p - self.eye)
        return self.focal * r / math.sqrt(D * D - r * r)


def render(vox, mesh, png, size, az, el, fov):
    cmd = [vox, "render", mesh, "-o", png, "--size", str(size), "-a", str(az), "-e", str(el)]
    if fov is not None:
        cmd += ["--perspective"] + (["--fov", str(fov)] if fov != 35 else [])
    r = subprocess.run(cmd, capture_output=True, text=True)
    if r.returncode != 0:
        raise RuntimeError("%s: exit %d: %s" % (" ".join(cmd), r.returncode, r.stderr.strip()))
    img = read_png(png)
    report("%s: %dx%d picture" % (os.path.basename(png), size, size), img.shape[:2] == (size, size),
           str(img.shape))
    return np.any(img != img[0, 0], axis=-1)  # the corner's colour is the background


VIEWS = [  # size, azimuth, elevation, fov (None: orthographic; 35: the default, not given)
    (301, 30, 20, 35), (301, 0, 0, 20), (256, 200, -30, 60), (301, 45, 60, 120),
    (200, -120, 10, 90), (301, 30, 20, None), (256, 110, -45, None),
]


def check_sphere(vox, d):
    mesh = os.path.join(d, "sphere.obj")
    lo, hi = write_obj(mesh, [icosphere(4, (0, 0, 0), 1.0)])
    radii = {}
    for size, az, el, fov in VIEWS:
        name = "sphere, size %d, azimuth %g, elevation %g, %s" % (
            size, az, el, "orthographic" if fov is None else "fov %g" % fov)
        cam = Camera(lo, hi, size, az, el, fov)
        want = cam.disc_radius(np.zeros(3), 1.0)
        mask = render(vox, mesh, os.path.join(d, "s%d.png" % len(radii)), size, az, el, fov)
        got = math.sqrt(mask.sum() / math.pi)
        ys, xs = np.nonzero(mask)
        cx, cy = xs.mean() + 0.5, ys.mean() + 0.5
        report(name + ": the disc's radius", abs(got - want) <= 0.75,
               "%.2f px, computed %.2f" % (got, want))
        print("NOTE: %s: radius %.2f px, computed %.2f" % (name, got, want))
        report(name + ": the disc is centred", abs(cx - size / 2) <= 0.5 and abs(cy - size / 2) <= 0.5,
               "centre (%.2f, %.2f)" % (cx, cy))
        radii[(size, fov)] = got
    # the fov changes the picture: a wider angle, a nearer camera, a smaller disc
    report("sphere: a wider fov draws a smaller disc",
           radii[(301, 20)] > radii[(301, 35)] + 5 > radii[(301, 120)] + 10,
           str(radii))


def check_places(vox, d):
    """Two small spheres off the centre: each lands where the camera puts
    its centre (within a pixel), for each view."""
    mesh = os.path.join(d, "pair.obj")
    p = [np.array([0.7, -0.4, 0.5]), np.array([-0.6, 0.5, -0.3])]
    lo, hi = write_obj(mesh, [icosphere(3, q, 0.08) for q in p])
    for i, (size, az, el, fov) in enumerate(VIEWS):
        name = "two spheres, size %d, azimuth %g, elevation %g, %s" % (
            size, az, el, "orthographic" if fov is None else "fov %g" % fov)
        cam = Camera(lo, hi, size, az, el, fov)
        mask = render(vox, mesh, os.path.join(d, "p%d.png" % i), size, az, el, fov)
        ys, xs = np.nonzero(mask)
        want = [cam.project(q) for q in p]
        # each pixel to the nearer of the two computed places
        near0 = (xs + 0.5 - want[0][0]) ** 2 + (ys + 0.5 - want[0][1]) ** 2 < \
            (xs + 0.5 - want[1][0]) ** 2 + (ys + 0.5 - want[1][1]) ** 2
        for k, sel in enumerate((near0, ~near0)):
            if not sel.any():
                report("%s: sphere %d drawn" % (name, k), False)
                continue
            gx, gy = xs[sel].mean() + 0.5, ys[sel].mean() + 0.5
            report("%s: sphere %d where the camera puts it" % (name, k),
                   math.hypot(gx - want[k][0], gy - want[k][1]) <= 1.0,
                   "at (%.1f, %.1f), computed (%.1f, %.1f)" % (gx, gy, want[k][0], want[k][1]))


def main():
    try:
        check_sphere(sys.argv[1], sys.argv[2])
        check_places(sys.argv[1], sys.argv[2])
    except Exception as e:
        report("render_check.py runs", False, "%s: %s" % (type(e).__name__, e))
        sys.exit(2)
    sys.exit(1 if FAILED else 0)


if __name__ == "__main__":
    main()
