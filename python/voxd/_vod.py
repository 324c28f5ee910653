"""The VOD reader: docs/vod-format.md, checked as the C reader (vod/vod_read.c)
checks it, in the same order and with the same messages, so that a damaged
file is refused here with the words `vox info` prints for it."""

import struct
import zlib

import numpy as np

SIG = b".VOD"
TRAILER_FIXED = 40
MAX_HEIGHT = 21
FLAG_COMPRESSED, FLAG_PADDED, FLAG_FLOAT, FLAG_TRAILER = 1, 2, 4, 1 << 16
COMP = {b"NONE", b"ZLIB", b"RUNL"}
HASH = {b"SFHS", b"XX32"}
CHANNEL_BITS = (0, 1, 8, 32, 32)
M32 = 0xFFFFFFFF


class VodError(ValueError):
    """A file that is not a valid VOD file; str() is what is wrong."""


class Volume:
    """One level of a VOD file as a dense array.

    data     numpy array of shape (z, y, x): data[z, y, x] is voxel (x, y, z);
             uint8 for 1-bit voxels (0/1) and 8-bit ones, uint16, uint32 for
             32-bit ones (channel 3: bits 0-7 the occupancy, 8-31 the normal),
             float32 when the header's float flag is set
    shape    data.shape, (z, y, x)
    origin   (x, y, z) world position of the low corner of voxel (0, 0, 0)
    spacing  (x, y, z) world size of one voxel of this level (2^level times
             the file's voxelScale)
    channel  the trailer's channel (0 when the file has no trailer)
    level    the level read (0: full resolution)
    metadata dict of the trailer's key=value lines
    info     dict of the header's fields (volume, brick, height, voxel_bits,
             hash, comp, flags, bricks, crc32)
    """

    def __init__(self, data, origin, spacing, channel, level, metadata, info):
        self.data = data
        self.shape = data.shape
        self.origin = origin
        self.spacing = spacing
        self.channel = channel
        self.level = level
        self.metadata = metadata
        self.info = info

    @property
    def occupancy(self):
        """uint8 (z, y, x): channel 1's 0/1, channel 2's density, channel 3's
        occupancy byte (what `vox export` writes), channel 4's 1 inside (a
        negative distance)."""
        if self.channel == 4:  # a signed distance: 1 inside
            return (self.data < 0).astype(np.uint8)
        if self.info["voxel_bits"] == 32 and self.channel == 3:
            return (self.data & 0xFF).astype(np.uint8)
        return self.data.astype(np.uint8)

    def __repr__(self):
        return "<voxd.Volume shape=%s level=%d channel=%d>" % (
            self.shape, self.level, self.channel)


def _u32(b, at):
    return struct.unpack_from("<I", b, at)[0]


def _f32(b, at):
    return struct.unpack_from("<f", b, at)[0]


def _g(v):
    """A float as C's %g writes it."""
    return "%g" % v


# ---- hashes (docs/vod-format.md, appendix; xxHash32 with seed 0) ----

def sfhs(data):
    n = len(data)
    h = n
    words = len(data) // 4
    u16 = np.frombuffer(data, dtype="<u2", count=words * 2).tolist()
    for i in range(0, 2 * words, 2):
        h = (h + u16[i]) & M32
        tmp = ((u16[i + 1] << 11) ^ h) & M32
        h = ((h << 16) ^ tmp) & M32
        h = (h + (h >> 11)) & M32
    p = 4 * words

    def tail8(q):
        v = data[q]
        return (v - 256 if v >= 128 else v) & M32

    r = n % 4
    if r == 3:
        h = (h + (data[p] | data[p + 1] << 8)) & M32
        h ^= (h << 16) & M32
        h ^= (tail8(p + 2) << 18) & M32
        h = (h + (h >> 11)) & M32
    elif r == 2:
        h = (h + (data[p] | data[p + 1] << 8)) & M32
        h ^= (h << 11) & M32
        h = (h + (h >> 17)) & M32
    elif r == 1:
        h = (h + tail8(p)) & M32
        h ^= (h << 10) & M32
        h = (h + (h >> 1)) & M32
    h ^= (h << 3) & M32
    h = (h + (h >> 5)) & M32
    h ^= (h << 4) & M32
    h = (h + (h >> 17)) & M32
    h ^= (h << 25) & M32
    h = (h + (h >> 6)) & M32
    return h


P1, P2, P3, P4, P5 = 2654435761, 2246822519, 3266489917, 668265263, 374761393


def _rotl(x, r):
    return ((x << r) | (x >> (32 - r))) & M32


def xx32(data, seed=0):
    n = len(data)
    p = 0
    if n >= 16:
        v = [(seed + P1 + P2) & M32, (seed + P2) & M32, seed, (seed - P1) & M32]
        stripes = n // 16
        w = np.frombuffer(data, dtype="<u4", count=stripes * 4).tolist()
        for i in range(0, stripes * 4, 4):
            for j in range(4):
                v[j] = (_rotl((v[j] + w[i + j] * P2) & M32, 13) * P1) & M32
        h = (_rotl(v[0], 1) + _rotl(v[1], 7) + _rotl(v[2], 12) + _rotl(v[3], 18)) & M32
        p = stripes * 16
    else:
        h = (seed + P5) & M32
    h = (h + n) & M32
    while p + 4 <= n:
        h = (_rotl((h + _u32(data, p) * P3) & M32, 17) * P4) & M32
        p += 4
    while p < n:
        h = (_rotl((h + data[p] * P5) & M32, 11) * P1) & M32
        p += 1
    h ^= h >> 15
    h = (h * P2) & M32
    h ^= h >> 13
    h = (h * P3) & M32
    h ^= h >> 16
    return h


def _runl_decode(bits, d, raw_n):
    """RUNL (section 6) to exactly raw_n bytes, or None."""
    w = 1 if bits == 1 else bits // 8
    out = bytearray()
    p = 0
    while p < len(d):
        if p + 1 + w > len(d):
            return None
        count = d[p] + 1
        if len(out) + count * w > raw_n:
            return None
        out += d[p + 1:p + 1 + w] * count
        p += 1 + w
    return bytes(out) if len(out) == raw_n else None


def _fourcc(v):
    return "".join(chr(c) if 32 <= c < 127 else "?" for c in v)


# ---- the file ----

class _File:
    """A validated file image: header fields, tree, raw bricks by ID."""

    def __init__(self, b):
        self.b = b
        self.end = len(b)
        self.channel = 0
        self.origin = (0.0, 0.0, 0.0)
        self.metadata = ""
        self.crc = None
        self._header()
        self._tree()
        self._count()
        self._bricks()
        self._check_subtree()

    # trailer (section 7): the CRC first, so damage is reported as such
    def _trailer(self):
        b, n = self.b, len(self.b)
        if n < 64 + 4 + TRAILER_FIXED:
            raise VodError("file is truncated: flags bit 16 promises a trailer, but "
                           "the file has only %d bytes" % n)
        if b[n - 8:n - 4] != b"XDOV":
            raise VodError("file is truncated or corrupted: flags bit 16 promises a "
                           "trailer, but 'XDOV' is not at offset %d" % (n - 8))
        stored, crc = _u32(b, n - 4), zlib.crc32(b[:n - 4]) & M32
        if crc != stored:
            raise VodError("trailer CRC mismatch (file corrupted): stored %08x, "
                           "computed %08x" % (stored, crc))
        at = _u32(b, n - 12)
        if at < 64 + 4 or at > n - TRAILER_FIXED or b[at:at + 4] != b"VODX":
            raise VodError("trailerOffset %d does not point at 'VODX'" % at)
        size, meta = _u32(b, at + 4), _u32(b, at + 24)
        if size != n - at:
            raise VodError("trailerSize %d at offset %d does not reach the end of "
                           "the file (%d bytes)" % (size, at + 4, n))
        if meta != size - TRAILER_FIXED:
            raise VodError("trailer metadataSize %d does not match trailerSize %d"
                           % (meta, size))
        self.origin = tuple(_f32(b, at + 8 + 4 * a) for a in range(3))
        self.channel = _u32(b, at + 20)
        if self.channel > 4:
            raise VodError("trailer channel %d unknown (0..4)" % self.channel)
        self.metadata = b[at + 28:at + 28 + meta].decode("utf-8", "replace")
        self.crc = stored
        self.end = at

    def _header(self):
        b = self.b
        # the signature first, as far as the file goes: a short text file
        # is not a VOD file, not a truncated one (as vox info says)
        if b[:4] != SIG[:len(b[:4])]:
            raise VodError('not a VOD file (bad signature %s; want 2e 56 4f 44, ".VOD")'
                           % " ".join("%02x" % c for c in b[:4]))
        if len(b) < 64:
            raise VodError("file is truncated: the header needs 64 bytes, file has %d"
                           % len(b))
        self.flags = _u32(b, 60)
        if self.flags & FLAG_TRAILER:
            self._trailer()
        version = _u32(b, 4)
        if version != 1:
            raise VodError("unsupported fileVersion %d" % version)
        self.volume = [_u32(b, 8 + 4 * a) for a in range(3)]
        bs = [_u32(b, 20 + 4 * a) for a in range(3)]
        self.scale = [_f32(b, 32 + 4 * a) for a in range(3)]
        if 0 in self.volume:
            raise VodError("volumeSize %dx%dx%d: each side must be at least 1"
                           % tuple(self.volume))
        if bs[0] != bs[1] or bs[1] != bs[2]:
            raise VodError("brickSize %dx%dx%d is not cubic" % tuple(bs))
        if bs[0] < 2 or bs[0] > 256 or bs[0] & (bs[0] - 1):
            raise VodError("brickSize %d is not a power of two in 2..256" % bs[0])
        self.brick = bs[0]
        for a in range(3):
            s = self.scale[a]
            if not (s > 0.0 and s != float("inf")):
                raise VodError("voxelScale %s on axis %d is not finite and > 0"
                               % (_g(s), a))
        self._height()
        self._encoding()
        self._flags()
        if self.channel and CHANNEL_BITS[self.channel] != self.bits:
            raise VodError("trailer channel %d needs voxelSize %d, the header says %d"
                           % (self.channel, CHANNEL_BITS[self.channel], self.bits))
        self.raw_bytes = self.brick ** 3 * self.bits // 8

    def _height(self):
        self.height = _u32(self.b, 44)
        per_axis = (max(self.volume) + self.brick - 1) // self.brick
        m = 0
        while (1 << m) < per_axis:
            m += 1
        if self.height != m + 1:
            raise VodError("treeHeight %d does not fit volumeSize %dx%dx%d and brickSize "
                           "%d (the spec's formula gives %d)"
                           % ((self.height,) + tuple(self.volume) + (self.brick, m + 1)))
        if self.height > MAX_HEIGHT:
            raise VodError("file is truncated: treeHeight %d needs an octree table "
                           "larger than any file" % self.height)
        self.k = self.brick.bit_length() - 1
        self.padded = self.brick << (self.height - 1)
        self.nodes = ((1 << (3 * self.height)) - 1) // 7
        self.sub = [((1 << (3 * (l + 1))) - 1) // 7 for l in range(self.height)]

    def _encoding(self):
        b = self.b
        self.bits = _u32(b, 48)
        self.hash, self.comp = bytes(b[52:56]), bytes(b[56:60])
        if self.bits not in (1, 8, 16, 32):
            raise VodError("voxelSize %d is not 1, 8, 16 or 32 bits" % self.bits)
        if self.hash not in HASH:
            raise VodError("unsupported hashAlgorithm '%s'" % _fourcc(self.hash))
        if self.comp not in COMP:
            raise VodError("unsupported compAlgorithm '%s'" % _fourcc(self.comp))

    def _flags(self):
        fl = self.flags
        comp = self.comp != b"NONE"
        pad = any(self.padded > v for v in self.volume)
        if fl & ~(FLAG_COMPRESSED | FLAG_PADDED | FLAG_FLOAT | FLAG_TRAILER):
            raise VodError("flags %08x: reserved or unknown bits are set" % fl)
        if bool(fl & FLAG_COMPRESSED) != comp:
            raise VodError("flags bit 0 (compression) is %s but compAlgorithm is %s"
                           % (("clear", "not NONE") if comp else ("set", "NONE")))
        if bool(fl & FLAG_PADDED) != pad:
            raise VodError("flags bit 1 (padding) is %s but the padded side %d %s "
                           "volumeSize" % ("clear" if pad else "set", self.padded,
                                           "exceeds" if pad else "equals"))
        if fl & FLAG_FLOAT and self.bits != 32:
            raise VodError("flags bit 2 (float) needs voxelSize 32, not %d" % self.bits)

    def _tree(self):
        need = self.nodes * 4
        if need + 4 > self.end - 64:
            raise VodError("file is truncated: octree table and numberOfBricks need %d "
                           "bytes at offset 64, file has %d%s"
                           % (need + 4, self.end, " before its trailer"
                              if self.end < len(self.b) else ""))
        self.tree = np.frombuffer(self.b, dtype="<u4", count=self.nodes, offset=64)
        self.bricks_at = 64 + need

    def _count(self):
        n = _u32(self.b, self.bricks_at)
        room = self.end - self.bricks_at - 4
        if n * 16 > room:
            raise VodError("numberOfBricks %d at offset %d cannot fit: the file has %d "
                           "bytes after it" % (n, self.bricks_at, room))
        self.nbricks = n
        self.records_at = self.bricks_at + 4 + 12 * n

    def _bricks(self):
        n, b = self.nbricks, self.b
        ents, seen = [], set()
        for i in range(n):
            at = self.bricks_at + 4 + 12 * i
            e = [_u32(b, at), _u32(b, at + 4), _u32(b, at + 8), 0]
            if e[0] == 0 or e[0] > n:
                raise VodError("brick table entry %d has brickID %d, outside 1..%d"
                               % (i, e[0], n))
            if e[0] in seen:
                raise VodError("duplicate brick ID %d in table" % e[0])
            seen.add(e[0])
            ents.append(e)
        for e in ents:
            if e[1] < self.records_at or e[1] > self.end or self.end - e[1] < 4:
                raise VodError("brick %d: offset %d outside the file (brick records lie "
                               "in %d..%d)" % (e[0], e[1], self.records_at, self.end))
            e[3] = _u32(b, e[1])
            if e[3] > self.end - e[1] - 4:
                raise VodError("brick %d: dataSize %d at offset %d passes the end of the "
                               "brick data (offset %d)" % (e[0], e[3], e[1], self.end))
        ents.sort(key=lambda e: e[1])  # a stable sort, as qsort on distinct offsets
        at = self.records_at
        for i, e in enumerate(ents):
            if e[1] < at:
                raise VodError("brick %d: record at offset %d overlaps brick %d's record"
                               % (e[0], e[1], ents[i - 1][0]))
            at = e[1] + 4 + e[3]
        if at != self.end:
            raise VodError("%d unexpected bytes after the last brick record (offset %d)%s"
                           % (self.end - at, at, "; flags bit 16 (trailer) is clear"
                              if self.end == len(b) else ""))
        self.raw = [None] * (n + 1)
        for e in ents:
            self.raw[e[0]] = self._decode(e)

    def _decode(self, e):
        d = bytes(self.b[e[1] + 4:e[1] + 4 + e[3]])
        n, why, raw = self.raw_bytes, None, None
        if self.comp == b"NONE":
            if len(d) != n:
                why = "dataSize differs"
            else:
                raw = d
        elif self.comp == b"RUNL":
            raw = _runl_decode(self.bits, d, n)
            if raw is None:
                why = "bad RUNL runs"
        else:
            why, raw = _inflate(d, n)
        if why:
            raise VodError("brick %d does not decompress to %d bytes (%s)"
                           % (e[0], n, why))
        h = sfhs(raw) if self.hash == b"SFHS" else xx32(raw)
        if h != e[2]:
            raise VodError("brick %d: hash mismatch (table %08x, data %08x)"
                           % (e[0], e[2], h))
        return raw

    def _check_subtree(self):
        tree, sub = self.tree.tolist(), self.sub
        stack = [(0, self.height - 1)]
        while stack:
            p, l = stack.pop()
            if tree[p] == 0:
                for q in range(p + 1, p + sub[l]):
                    if tree[q]:
                        raise VodError("node %d has brickID 0 (empty region) but its "
                                       "descendant node %d has brickID %d"
                                       % (p, q, tree[q]))
                continue
            if tree[p] > self.nbricks:
                raise VodError("brickID %d at node %d is not in the brick table "
                               "(numberOfBricks %d)" % (tree[p], p, self.nbricks))
            if l > 0:  # children in reverse so that they are checked in order
                for i in reversed(range(8)):
                    stack.append((p + 1 + i * sub[l - 1], l - 1))


def _inflate(d, n):
    """(why, raw) as the C reader's uncompress2 check words it."""
    z = zlib.decompressobj()
    try:
        raw = z.decompress(d, n)
        if len(raw) == n and z.unconsumed_tail:
            return "zlib: too much data", None
        raw += z.flush()
    except zlib.error:
        return "zlib error", None
    if len(raw) > n:
        return "zlib: too much data", None
    if not z.eof:
        return ("zlib error" if len(raw) < n else "zlib: too much data"), None
    if len(raw) != n:
        return "zlib: too little data", None
    if z.unused_data:
        return "bytes left after the zlib stream", None
    return None, raw


def _dtype(f):
    if f.bits in (1, 8):
        return np.uint8
    if f.bits == 16:
        return np.dtype("<u2")
    return np.dtype("<f4") if f.flags & FLAG_FLOAT else np.dtype("<u4")


def _brick_array(f, raw):
    B = f.brick
    if f.bits == 1:
        v = np.unpackbits(np.frombuffer(raw, np.uint8), bitorder="little")
        return v.reshape(B, B, B)
    return np.frombuffer(raw, _dtype(f)).reshape(B, B, B)


def _assemble(f, level):
    dims = [(v + (1 << level) - 1) >> level for v in f.volume]
    out = np.zeros((dims[2], dims[1], dims[0]), dtype=_dtype(f))
    tree, B = f.tree.tolist(), f.brick
    stack = [(0, f.height - 1, (0, 0, 0))]
    while stack:
        p, l, bc = stack.pop()
        bid = tree[p]
        if not bid:
            continue
        if l > level:
            for i in range(8):
                c = tuple(bc[a] << 1 | (i >> a) & 1 for a in range(3))
                stack.append((p + 1 + i * f.sub[l - 1], l - 1, c))
            continue
        o = [bc[a] * B for a in range(3)]
        if o[0] >= dims[0] or o[1] >= dims[1] or o[2] >= dims[2]:
            continue
        e = [min(B, dims[a] - o[a]) for a in range(3)]
        out[o[2]:o[2] + e[2], o[1]:o[1] + e[1], o[0]:o[0] + e[0]] = \
            _brick_array(f, f.raw[bid])[:e[2], :e[1], :e[0]]
    return out


def read_bytes(b, level=0):
    """A VOD file image (bytes) read as read() reads a file."""
    f = _File(bytes(b))
    if not 0 <= level < f.height:
        raise VodError("level %d: the file has levels 0..%d" % (level, f.height - 1))
    meta = {}
    for line in f.metadata.splitlines():
        k, sep, v = line.partition("=")
        if sep:
            meta[k] = v
    info = {"volume": tuple(f.volume), "brick": f.brick, "height": f.height,
            "voxel_bits": f.bits, "hash": f.hash.decode(), "comp": f.comp.decode(),
            "flags": f.flags, "bricks": f.nbricks, "crc32": f.crc,
            "voxel_scale": tuple(f.scale)}
    spacing = tuple(s * (1 << level) for s in f.scale)
    return Volume(_assemble(f, level), f.origin, spacing, f.channel, level, meta, info)


def read(path, level=0):
    """Read and validate the VOD file at path; return level `level` as a Volume.
    A damaged file raises VodError with the message `vox info` gives."""
    with open(path, "rb") as fp:
        return read_bytes(fp.read(), level)
