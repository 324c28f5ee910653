"""The Python reader (python/voxd) against answers found without it, for
reader.sh: its metadata, float data and levels >= 2.

    reader_check.py meta VOD VOX EXPR RES X0,X1,Y0,Y1,Z0,Z1 BRICK
        the trailer's keys and the header's fields against what the test
        asked vox voxelize for (docs/vod-format.md section 9's keys, the
        grid of a cubic domain, treeHeight's formula, the flags' rules),
        against vox info's lines (the C reader) and the file's own last bytes
    reader_check.py levels VOD VOX DIR
        every level >= 1 against the level below it downsampled here
        (section 3's rules: OR, the mean rounded half up, channel 3's
        occupancy mean and the normalized sum of the occupied children's
        normals), and against `vox export --level L` raw (the C reader)
    reader_check.py float DIR VOX
        VOD files of float voxels (flags bit 2, channel 0) written here from
        the format alone, with and without a trailer, ZLIB and NONE, three
        levels: voxd.read gives every level's floats bit for bit, float32;
        vox info accepts each file and its content checksum is that of the
        arrays written (so the C reader reads the same values)

Every line printed is "PASS: name" or "FAIL: name"; exit status 0 when every
check passed, 1 when one failed, 2 when the checker itself broke.
"""

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
        if why:
            print("  " + why)


def vox_info(vox, path):
    r = subprocess.run([vox, "info", path], capture_output=True, text=True)
    if r.returncode != 0:
        raise RuntimeError("vox info %s: exit %d: %s" % (path, r.returncode, r.stderr.strip()))
    return r.stdout


def f32(x):
    return float(np.float32(x))


# ---- metadata and header ----

def check_meta(vod, vox, expr, res, domain, brick):
    name = os.path.basename(vod)
    lo = [float(t) for t in domain.split(",")[0::2]]
    hi = [float(t) for t in domain.split(",")[1::2]]
    ext = [hi[a] - lo[a] for a in range(3)]
    assert len(set(ext)) == 1, "meta wants a cubic domain"
    v = voxd.read(vod)
    grid = (res, res, res)
    # docs/vod-format.md section 9: the keys vox voxelize writes, in order
    want = [("generator", "vox voxelize"), ("source", expr), ("resolution", str(res)),
            ("grid", "%dx%dx%d" % grid),
            ("domain", ",".join("%g" % float(t) for t in domain.split(",")))]
    report(name + ": metadata keys and values in the file's order",
           list(v.metadata.items()) == want, "%r" % (v.metadata,))
    report(name + ": origin is the domain's low corner (as f32)",
           tuple(v.origin) == tuple(f32(t) for t in lo), str(v.origin))
    vs = f32(ext[0] / res)
    report(name + ": spacing is the voxel size (as f32)", tuple(v.spacing) == (vs, vs, vs),
           str(v.spacing))
    # section 3: treeHeight = 1 + ceil(log2(ceil(max(volume) / brick)))
    nb = -(-res // brick)
    height = 1 + (nb - 1).bit_length()
    padded = brick << (height - 1)
    with open(vod, "rb") as fp:
        b = fp.read()
    comp = b[56:60].decode()
    flags = (1 if comp != "NONE" else 0) | (2 if padded > res else 0) | (1 << 16)
    info = v.info
    report(name + ": volume, brick, height, bits", info["volume"] == grid and
           info["brick"] == brick and info["height"] == height and info["voxel_bits"] == 32,
           str(info))
    report(name + ": flags by section 2's rules", info["flags"] == flags,
           "%#x, wanted %#x" % (info["flags"], flags))
    report(name + ": crc32 is the file's last 4 bytes and zlib's CRC of the rest",
           info["crc32"] == struct.unpack("<I", b[-4:])[0] == zlib.crc32(b[:-4]))
    report(name + ": data shape (z, y, x) and level 0", v.shape == grid[::-1] and v.level == 0)
    report(name + ": channel 3 (the default)", v.channel == 3)

    # the C reader's view of the same file
    out = vox_info(vox, vod)
    line = lambda key: re.search(r"^  %s +(.*)$" % key, out, re.M).group(1)  # noqa: E731
    metas = re.findall(r"^  meta +(.*)$", out, re.M)
    report(name + ": metadata as vox info lists it",
           metas == ["%s=%s" % kv for kv in v.metadata.items()], "%r" % metas)
    m = re.match(r"(\d+)\^3, (\d+) unique stored, hash (\w+), compression (\w+)", line("bricks"))
    report(name + ": bricks, hash and compression as vox info says", m is not None and
           int(m.group(1)) == info["brick"] and int(m.group(2)) == info["bricks"] and
           m.group(3) == info["hash"] and m.group(4) == info["comp"], line("bricks"))
    report(name + ": origin and crc32 as vox info says",
           line("origin") == ", ".join("%g" % t for t in v.origin) and
           line("crc32") == "%08x" % info["crc32"], "%s / %s" % (line("origin"), line("crc32")))
    report(name + ": height as vox info says", line("octree").startswith("height %d," % height))


# ---- levels ----

def octahedral(raw):
    """Unit normals (..., 3) of channel-3 voxels (docs/vod-format.md 7.1)."""
    u = ((raw >> 8) & 0xFFF) / 4095.0 * 2 - 1
    v = ((raw >> 20) & 0xFFF) / 4095.0 * 2 - 1
    z = 1 - np.abs(u) - np.abs(v)
    fold = z < 0
    su, sv = np.where(u >= 0, 1.0, -1.0), np.where(v >= 0, 1.0, -1.0)
    u2 = np.where(fold, (1 - np.abs(v)) * su, u)
    v2 = np.where(fold, (1 - np.abs(u)) * sv, v)
    n = np.stack([u2, v2, z], axis=-1)
    return n / np.linalg.norm(n, axis=-1, keepdims=True)


def octets(a):
    """a (z, y, x, ...) padded with zeros to even sides, as (z/2, y/2, x/2, 8, ...)."""
    pad = [(0, s % 2) for s in a.shape[:3]] + [(0, 0)] * (a.ndim - 3)
    a = np.pad(a, pad)
    z, y, x = (s // 2 for s in a.shape[:3])
    a = a.reshape((z, 2, y, 2, x, 2) + a.shape[3:])
    a = np.moveaxis(a, (1, 3, 5), (3, 4, 5))
    return a.reshape((z, y, x, 8) + a.shape[6:])


def downsample(child, channel, bits):
    """Level l from level l - 1 (section 3): (values, normals or None)."""
    if bits == 1:
        return octets(child).max(axis=3), None
    occ = child & 0xFF if channel == 3 else child
    mean = ((octets(occ.astype(np.int64)).sum(axis=3) + 4) // 8)
    if channel != 3:
        return mean, None
    nrm = np.where((occ != 0)[..., None], octahedral(child.astype(np.int64)), 0.0)
    return mean, octets(nrm).sum(axis=3)


def angle_deg(a, b):
    c = np.sum(a * b, axis=-1) / (np.linalg.norm(a, axis=-1) * np.linalg.norm(b, axis=-1))
    return np.degrees(np.arccos(np.clip(c, -1, 1)))


def read_raw(path):
    with open(path[:-4] + ".json") as fp:
        meta = json.load(fp)
    arr = np.fromfile(path, np.dtype(meta["dtype"]).newbyteorder("<")).reshape(meta["shape"])
    return arr, meta


def check_levels(vod, vox, d):
    name = os.path.basename(vod)
    below = voxd.read(vod, 0)
    height, bits, ch = below.info["height"], below.info["voxel_bits"], below.channel
    report(name + ": at least 4 levels", height >= 4, "height %d" % height)
    for level in range(1, height):
        v = voxd.read(vod, level)
        n = "%s level %d" % (name, level)
        dims = tuple(-(-s // (1 << level)) for s in below.info["volume"])
        report(n + ": shape is ceil(volume / 2^level)", v.shape == dims[::-1],
               "%s, wanted %s" % (v.shape, dims[::-1]))
        report(n + ": spacing 2^level voxels, the origin kept",
               v.spacing == tuple(s * (1 << level) for s in below.info["voxel_scale"]) and
               v.origin == below.origin and v.level == level)
        mean, nsum = downsample(below.data, ch, bits)
        occ = v.occupancy
        report(n + ": the values are level %d's downsampled here" % (level - 1),
               mean.shape == occ.shape and np.array_equal(mean, occ),
               "%d of %d differ" % (np.count_nonzero(mean != occ), occ.size)
               if mean.shape == occ.shape else "shape %s" % (mean.shape,))
        if nsum is not None:
            got = octahedral(v.data.astype(np.int64))
            # where the children's normals nearly cancel, the direction is
            # the rounding's: compare where the sum is at least a tenth long
            firm = (occ != 0) & (np.linalg.norm(nsum, axis=-1) > 0.1)
            err = angle_deg(got[firm], nsum[firm])
            report(n + ": normals are the occupied children's summed, within 0.2 degree",
                   firm.sum() > 0 and err.max() <= 0.2,
                   "%d voxels, max %.3f degrees" % (firm.sum(), err.max() if err.size else -1))
        raw = os.path.join(d, "l%d.raw" % level)
        r = subprocess.run([vox, "export", vod, "-o", raw, "--level", str(level)],
                           capture_output=True, text=True)
        if r.returncode != 0:
            report(n + ": vox export --level", False, r.stderr.strip())
            continue
        arr, meta = read_raw(raw)
        if ch == 3:
            want = np.where((occ != 0)[..., None], octahedral(v.data.astype(np.int64)), 0.0)
            ok = arr.shape == v.shape + (4,) and np.array_equal(arr[..., 0], occ) and \
                np.allclose(arr[..., 1:], want, rtol=0, atol=1e-6)
        else:
            ok = np.array_equal(arr, occ)
        report(n + ": vox export --level's raw voxels are voxd's", ok, "shape %s" % (arr.shape,))
        report(n + ": vox export's sidecar spacing and level",
               np.allclose(meta["spacing"], v.spacing, rtol=1e-6, atol=0) and
               meta["level"] == level, str(meta))
        below = v


# ---- float data, written here ----

def sfhs(data):
    """SuperFastHash as docs/vod-format.md's appendix gives it."""
    M = 0xFFFFFFFF
    n = len(data)
    h = n
    g16 = lambda i: data[i] | data[i + 1] << 8  # noqa: E731
    t8 = lambda i: (data[i] - 256 if data[i] > 127 else data[i]) & M  # noqa: E731
    i = 0
    for _ in range(n // 4):
        h = (h + g16(i)) & M
        tmp = ((g16(i + 2) << 11) & M) ^ h
        h = ((h << 16) & M) ^ tmp
        h = (h + (h >> 11)) & M
        i += 4
    r = n % 4
    if r == 3:
        h = (h + g16(i)) & M
        h ^= (h << 16) & M
        h ^= (t8(i + 2) << 18) & M
        h = (h + (h >> 11)) & M
    elif r == 2:
        h = (h + g16(i)) & M
        h ^= (h << 11) & M
        h = (h + (h >> 17)) & M
    elif r == 1:
        h = (h + t8(i)) & M
        h ^= (h << 10) & M
        h = (h + (h >> 1)) & M
    for sh, ad in ((3, 5), (4, 17), (25, 6)):
        h ^= (h << sh) & M
        h = (h + (h >> ad)) & M
    return h


def float_levels(vol, height):
    """The padded level 0 (N^3, N = brick * 2^(height-1), float32) and the
    levels above it: the means of 2x2x2, padding zeros included."""
    levels = [vol]
    for _ in range(1, height):
        levels.append(octets(levels[-1].astype(np.float64)).mean(axis=3).astype(np.float32))
    return levels


def write_float_vod(path, vol, brick, height, comp, trailer, origin, scale, meta):
    """A VOD file of float voxels from sections 1 to 7: the complete octree in
    preorder, one brick per node that meets the volume, ids by first use."""
    Z, Y, X = vol.shape
    N = brick << (height - 1)
    full = np.zeros((N, N, N), np.float32)
    full[:Z, :Y, :X] = vol
    levels = float_levels(full, height)
    ids, raws = [], []

    def walk(level, bc):
        reach = brick << level  # level-0 voxels per axis of this node
        if bc[0] * reach >= X or bc[1] * reach >= Y or bc[2] * reach >= Z:
            n = (8 ** (level + 1) - 1) // 7
            ids.extend([0] * n)  # all padding: empty, and so is its subtree
            return
        o = [c * brick for c in bc]
        raws.append(levels[level][o[2]:o[2] + brick, o[1]:o[1] + brick,
                                  o[0]:o[0] + brick].astype("<f4").tobytes())
        ids.append(len(raws))
        if level:
            for i in range(8):
                walk(level - 1, tuple(bc[a] << 1 | (i >> a) & 1 for a in range(3)))

    walk(height - 1, (0, 0, 0))
    flags = (1 if comp != "NONE" else 0) | (2 if N > min(X, Y, Z) else 0)
    flags |= 4 | ((1 << 16) if trailer else 0)
    head = b".VOD" + struct.pack("<I3I3I3fII", 1, X, Y, Z, brick, brick, brick, *scale,
                                 height, 32) + b"SFHS" + comp.encode() + struct.pack("<I", flags)
    assert len(head) == 64
    body = struct.pack("<%dI" % len(ids), *ids) + struct.pack("<I", len(raws))
    datas = [zlib.compress(r) if comp == "ZLIB" else r for r in raws]
    at = 64 + len(body) + 12 * len(raws)
    table = b""
    for i, (r, dt) in enumerate(zip(raws, datas)):
        table += struct.pack("<III", i + 1, at, sfhs(r))
        at += 4 + len(dt)
    recs = b"".join(struct.pack("<I", len(dt)) + dt for dt in datas)
    b = head + body + table + recs
    if trailer:
        m, start = meta.encode(), len(b)
        b += b"VODX" + struct.pack("<I3fII", 40 + len(m), *origin, 0, len(m)) + m
        b += struct.pack("<I", start) + b"XDOV"
        b += struct.pack("<I", zlib.crc32(b))
    with open(path, "wb") as fp:
        fp.write(b)
    return levels


def content_checksum(levels, dims, height):
    """vox info's voxels line from the arrays: the count of non-zero level-0
    voxels and the sum of CRC-32s of (level, x, y, z, value bits)."""
    total, n0 = 0, 0
    for level in range(height):
        d = [-(-s // (1 << level)) for s in dims]
        a = levels[level][:d[2], :d[1], :d[0]].view(np.uint32)
        z, y, x = np.nonzero(a)
        if level == 0:
            n0 = len(z)
        for r in np.stack([np.full(len(z), level), x, y, z, a[z, y, x]], axis=1).astype("<u4"):
            total = (total + zlib.crc32(r.tobytes())) & 0xFFFFFFFF
    return "  voxels      %d non-empty at full resolution; content checksum %08x" % (n0, total)


def check_float(d, vox):
    # a signed distance to a sphere, negative inside, on 13 x 10 x 7 voxels
    # (every axis padded), bricks of 4: treeHeight 3
    z, y, x = np.meshgrid(np.arange(7), np.arange(10), np.arange(13), indexing="ij")
    vol = (np.sqrt((x - 6.2) ** 2 + (y - 4.7) ** 2 + (z - 3.1) ** 2) - 3.3).astype(np.float32)
    vol[0, 0, 0] = np.float32(-1.5e-7)   # a tiny value and an exact one
    vol[1, 2, 3] = np.float32(1e30)
    origin, scale = (-1.25, 0.5, 3.0), (0.25, 0.125, 0.5)
    for comp in ("NONE", "ZLIB"):
        for trailer in (True, False):
            name = "float %s %s" % (comp, "with a trailer" if trailer else "without a trailer")
            path = os.path.join(d, "float-%s-%d.vod" % (comp, trailer))
            meta = "generator=reader_check.py\nkind=signed distance\n"
            levels = write_float_vod(path, vol, 4, 3, comp, trailer, origin, scale, meta)
            out = vox_info(vox, path)
            want = content_checksum(levels, (13, 10, 7), 3)
            got = [ln for ln in out.splitlines() if ln.startswith("  voxels")]
            report(name + ": vox info reads the arrays written", got == [want],
                   "%s / %s" % (got, want))
            for level in range(3):
                v = voxd.read(path, level)
                dims = [-(-s // (1 << level)) for s in (13, 10, 7)]
                w = levels[level][:dims[2], :dims[1], :dims[0]]
                report("%s level %d: float32, bit for bit" % (name, level),
                       v.data.dtype == np.float32 and v.data.shape == w.shape and
                       np.array_equal(v.data.view(np.uint32), w.view(np.uint32)),
                       "dtype %s shape %s" % (v.data.dtype, v.data.shape))
                report("%s level %d: spacing" % (name, level),
                       v.spacing == tuple(f32(s) * (1 << level) for s in scale))
            v = voxd.read(path)
            if trailer:
                ok = v.origin == tuple(f32(t) for t in origin) and v.channel == 0 and \
                    v.metadata == {"generator": "reader_check.py", "kind": "signed distance"}
            else:
                ok = tuple(v.origin) == (0, 0, 0) and v.channel == 0 and v.metadata == {}
            report(name + ": origin, channel and metadata", ok,
                   "%s %s %s" % (v.origin, v.channel, v.metadata))
            report(name + ": info's flags (float, and the trailer's bit)",
                   v.info["flags"] & 4 and bool(v.info["flags"] >> 16 & 1) == trailer and
                   v.info["voxel_bits"] == 32, "%#x" % v.info["flags"])
    report("float: the data were not all zero", np.count_nonzero(vol) > 100)


def main():
    try:
        cmd = sys.argv[1]
        if cmd == "meta":
            check_meta(sys.argv[2], sys.argv[3], sys.argv[4], int(sys.argv[5]), sys.argv[6],
                       int(sys.argv[7]))
        elif cmd == "levels":
            check_levels(sys.argv[2], sys.argv[3], sys.argv[4])
        elif cmd == "float":
            check_float(sys.argv[2], sys.argv[3])
        else:
            raise ValueError("unknown command " + cmd)
    except Exception as e:  # a checker that breaks is never a pass
        report("reader_check.py %s runs" % " ".join(sys.argv[1:2]), False,
               "%s: %s" % (type(e).__name__, e))
        sys.exit(2)
    sys.exit(1 if FAILED else 0)


if __name__ == "__main__":
    main()
