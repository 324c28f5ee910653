#!/usr/bin/env python3
"""A tiny voxd protocol client for the daemon's integration tests.

Speaks proto/voxd.proto by hand (no protobuf module needed): frames are a
u32 big-endian length and one message.  Also sends the malformed frames the
abuse tests need.  Every socket operation has a timeout, so a test never
hangs on it.

  daemon_client.py SOCK submit EXPR RES DOMAIN OUT [--cancel] [--no-read] [--channel N]
                                          [--chunked N]  (the expression as InputChunks of N bytes)
                                          [--pause S]    (S seconds after the first chunk, unless
                                                          the server says something first)
  daemon_client.py SOCK mesh FILE RES OUT [--cancel] [--channel N] [--pad N]
                                          [--chunked N]  (the file as InputChunks of N bytes)
                                          (the file's bytes as they are, its name as source_name)
  daemon_client.py SOCK mesh-declare N    (a mesh Submit declaring N bytes of input: the
                                           daemon's answer, then a ping on the same connection)
  daemon_client.py SOCK csg-bad KIND      (a CSG Submit with a bad tree of KIND, see CSG_BAD:
                                           the daemon's answer, then a ping on the same connection)
  daemon_client.py SOCK band KIND BAND CHANNEL
                                          (a Submit of KIND implicit, mesh or csg with that
                                           band and channel number: the daemon's answer, then
                                           a ping on the same connection)
  daemon_client.py SOCK status            (prints pid=..,cpu=.. per worker, queued, running)
  daemon_client.py SOCK ping
  daemon_client.py SOCK abuse KIND        (see ABUSE)
  daemon_client.py SOCK hold N            (N connections that say hello, then wait)
  daemon_client.py SOCK flood N           (N connections at once, 100 open at a time,
                                           each read to its end; prints the Error codes)

Exit status: 0 success, 3 the server answered with an Error (printed as
"ERROR CODE_NAME: message"), 4 the connection closed, 5 a timeout.
"""
import os
import select
import socket
import struct
import sys
import time

CODES = {1: "INVALID_INPUT", 2: "LIMIT_EXCEEDED", 3: "BUSY", 4: "CANCELLED",
         5: "WORKER_CRASHED", 6: "TIMEOUT", 7: "SHUTTING_DOWN", 8: "INTERNAL"}
TIMEOUT = float(os.environ.get("VOXD_TEST_TIMEOUT", "60"))


# ---------------------------------------------------------------- encoding

def varint(v):
    if v < 0:
        v += 1 << 64
    out = bytearray()
    while True:
        b = v & 0x7F
        v >>= 7
        if v:
            out.append(b | 0x80)
        else:
            out.append(b)
            return bytes(out)


def field_varint(n, v):
    return varint(n << 3) + varint(v) if v else b""


def field_bytes(n, b):
    return varint(n << 3 | 2) + varint(len(b)) + b


def field_packed_doubles(n, vals):
    return field_bytes(n, b"".join(struct.pack("<d", v) for v in vals))


def request(case, body):
    return field_bytes(case, body)


def frame(msg):
    return struct.pack(">I", len(msg)) + msg


def hello(version=1):
    return frame(request(1, field_varint(1, version) + field_bytes(2, b"daemon_client.py")))


def submit(expr, res, domain, channel=0, schedule=0, brick=0, input_bytes=0):
    """A Submit; expr b"" with input_bytes N: the expression comes as input."""
    if isinstance(expr, str):
        expr = expr.encode()
    imp = (field_bytes(1, expr) if expr else b"") + field_packed_doubles(2, domain) \
        + field_varint(3, res) + field_varint(4, schedule)
    body = field_bytes(1, imp) + field_varint(10, channel) + field_varint(11, brick) \
        + field_varint(14, input_bytes)
    return frame(request(2, body))


def mesh_submit(data, res, pad=0, channel=0, name=b"", input_bytes=0):
    """A Submit of a mesh job (format told from the contents, solid); data
    b"" with input_bytes N: the file comes as input."""
    mesh = (field_bytes(2, data) if data else b"") + field_varint(7, pad) \
        + field_varint(8, res) + (field_bytes(9, name) if name else b"")
    body = field_bytes(2, mesh) + field_varint(10, channel) + field_varint(14, input_bytes)
    return frame(request(2, body))


def field_double(n, v):
    return varint(n << 3 | 1) + struct.pack("<d", v)


def csg_node(op, children=(), prim=0, size=None, source=b"", scalar=0.0, k=0, name=b""):
    """A CsgNode: op and children, a primitive's size (centre at the origin,
    no rotation), an implicit leaf's source, a scalar, k, a name."""
    b = field_varint(1, op)
    if children:
        b += field_bytes(2, b"".join(varint(c) for c in children))
    b += field_varint(3, prim)
    if source:
        b += field_bytes(5, source)
    if scalar:
        b += field_double(7, scalar)
    if size:
        b += field_packed_doubles(9, size)
    return b + field_varint(13, k) + (field_bytes(14, name) if name else b"")


def csg_submit(nodes, res=16, domain=(-1, 1)):
    csg = b"".join(field_bytes(1, n) for n in nodes) + field_packed_doubles(2, domain) \
        + field_varint(3, res)
    return frame(request(2, field_bytes(3, csg)))


# Bad trees, one of each kind: the daemon refuses each at the Submit.
BOX = csg_node(1, prim=1, size=(1, 1, 1), name=b"box")
CSG_BAD = {
    # a child that is not an earlier node: a cycle cannot be written
    "cycle": [BOX, csg_node(10, (0, 1), name=b"loop")],
    "unknown-op": [BOX, csg_node(99, (0,), name=b"what")],
    "arity": [BOX, csg_node(10, (0,), name=b"half")],
    "param": [BOX, BOX, csg_node(17, (0, 1), scalar=1.5, name=b"div")],
    "k": [BOX, csg_node(24, (0,), k=40, name=b"er")],
    "expression": [csg_node(2, source=b"x^2 + (y", name=b"bad")],
    "mesh-leaf": [csg_node(3, name=b"scan")],
    "no-nodes": [],
    "deep": [BOX] + [csg_node(20, (i,)) for i in range(70)],
}


def cmd_csg_bad(path, kind):
    c = Conn(path)
    c.hello()
    c.send(csg_submit(CSG_BAD[kind]))
    return submit_answer(c)


TETRA = b"v 0 0 0\nv 1 0 0\nv 0 1 0\nv 0 0 1\nf 1 3 2\nf 1 2 4\nf 1 4 3\nf 2 3 4\n"


def band_submit(kind, band, channel):
    """A Submit of a small job of kind with Implicit, Mesh or Csg.band."""
    if kind == "implicit":
        job = field_bytes(1, SPHERE) + field_packed_doubles(2, (-1, 1)) \
            + field_varint(3, 16) + field_varint(6, band)
    elif kind == "mesh":
        job = field_bytes(2, TETRA) + field_varint(7, 1) + field_varint(8, 16) \
            + field_varint(12, band)
    else:
        leaf = csg_node(2, source=SPHERE, name=b"ball")
        job = field_bytes(1, leaf) + field_packed_doubles(2, (-1, 1)) + field_varint(3, 16) \
            + field_varint(6, band)
    n = {"implicit": 1, "mesh": 2, "csg": 3}[kind]
    return frame(request(2, field_bytes(n, job) + field_varint(10, channel)))


def cmd_band(path, kind, band, channel):
    c = Conn(path)
    c.hello()
    c.send(band_submit(kind, band, channel))
    return submit_answer(c)


def submit_answer(c):
    """The answer to a Submit: accepted (0), or its Error (3) and a ping."""
    r = c.recv_frame()
    if r is None:
        die(4, "CLOSED: the server closed the connection")
    if r[0] == 2:
        print("accepted job %d" % one(r[1], 1), flush=True)
        return 0
    if r[0] != 6:
        die(1, "unexpected reply %d" % r[0])
    print("ERROR %s: %s (job %d)" % (CODES.get(one(r[1], 2), "?"),
                                     one(r[1], 3, b"").decode(errors="replace"),
                                     one(r[1], 1)), flush=True)
    c.send(ping(12))
    print("pong %d" % one(c.expect(8), 1), flush=True)
    return 3


def input_chunk(job_id, offset, data):
    body = field_varint(1, job_id) + field_varint(2, offset) + field_bytes(3, data)
    return frame(request(6, body))


def upload(c, job, data, piece):
    """Send data as InputChunks of job, piece bytes each, in order."""
    for off in range(0, len(data), piece):
        c.send(input_chunk(job, off, data[off:off + piece]))


def cancel(job_id):
    return frame(request(3, field_varint(1, job_id)))


def status():
    return frame(request(4, b""))


def ping(token=7):
    return frame(request(5, field_varint(1, token)))


# ---------------------------------------------------------------- decoding

def read_varint(b, i):
    v = shift = 0
    while True:
        c = b[i]
        i += 1
        v |= (c & 0x7F) << shift
        shift += 7
        if not c & 0x80:
            return v, i


def fields(b):
    """{field number: [values]}: ints for varints, bytes for the rest."""
    out, i = {}, 0
    while i < len(b):
        key, i = read_varint(b, i)
        n, wt = key >> 3, key & 7
        if wt == 0:
            v, i = read_varint(b, i)
        elif wt == 1:
            v, i = b[i:i + 8], i + 8
        elif wt == 2:
            ln, i = read_varint(b, i)
            v, i = b[i:i + ln], i + ln
        elif wt == 5:
            v, i = b[i:i + 4], i + 4
        else:
            raise ValueError("wire type %d" % wt)
        out.setdefault(n, []).append(v)
    return out


def repeated_uints(vals):
    """A repeated varint field, packed (bytes) or not (ints)."""
    out = []
    for b in vals:
        if isinstance(b, int):
            out.append(b)
            continue
        i = 0
        while i < len(b):
            v, i = read_varint(b, i)
            out.append(v)
    return out


def one(f, n, default=0):
    return f.get(n, [default])[0]


def dbl(f, n):
    v = f.get(n)
    return struct.unpack("<d", v[0])[0] if v else 0.0


def s64(v):
    return v - (1 << 64) if v >= 1 << 63 else v


class Conn:
    def __init__(self, path, timeout=TIMEOUT):
        self.s = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
        self.s.settimeout(timeout)
        self.s.connect(path)
        self.buf = b""

    def send(self, data):
        # A server that refused us may have closed already: what it said
        # before closing is still there to read.
        try:
            self.s.sendall(data)
        except (BrokenPipeError, ConnectionResetError):
            pass

    def recv_frame(self):
        """(case, fields) of the next reply; None at EOF."""
        while True:
            if len(self.buf) >= 4:
                n = struct.unpack(">I", self.buf[:4])[0]
                if len(self.buf) >= 4 + n:
                    msg, self.buf = self.buf[4:4 + n], self.buf[4 + n:]
                    f = fields(msg)
                    (case, body), = f.items()
                    return case, fields(body[0])
            try:
                d = self.s.recv(1 << 20)
            except ConnectionResetError:
                d = b""
            if not d:
                return None
            self.buf += d

    def hello(self):
        self.send(hello())
        return self.expect(1)

    def expect(self, case):
        r = self.recv_frame()
        if r is None:
            die(4, "CLOSED: the server closed the connection")
        if r[0] == 6:
            err(r[1])
        if r[0] != case:
            die(1, "unexpected reply %d (wanted %d)" % (r[0], case))
        return r[1]


def die(code, msg):
    print(msg, flush=True)
    sys.exit(code)


def err(f):
    die(3, "ERROR %s: %s (job %d)" % (CODES.get(one(f, 2), "?"),
                                       one(f, 3, b"").decode(errors="replace"),
                                       one(f, 1)))


# ---------------------------------------------------------------- commands

def cmd_submit(path, args):
    expr, res, dom, out = args[0], int(args[1]), args[2], args[3]
    opts = args[4:]
    domain = [float(x) for x in dom.split(",")]
    channel = int(opts[opts.index("--channel") + 1]) if "--channel" in opts else 0
    piece = int(opts[opts.index("--chunked") + 1]) if "--chunked" in opts else 0
    pause = float(opts[opts.index("--pause") + 1]) if "--pause" in opts else 0
    c = Conn(path)
    c.hello()
    if piece:
        c.send(submit(b"", res, domain, channel=channel, input_bytes=len(expr.encode())))
    else:
        c.send(submit(expr, res, domain, channel=channel))
    acc = c.expect(2)
    job = one(acc, 1)
    print("accepted job %d position %d" % (job, one(acc, 2)), flush=True)
    if piece:
        data = expr.encode()
        c.send(input_chunk(job, 0, data[:piece]))
        print("sent the first %d of %d bytes" % (min(piece, len(data)), len(data)), flush=True)
        readable = select.select([c.s], [], [], pause)[0] if pause else []
        if not readable:
            for off in range(piece, len(data), piece):
                c.send(input_chunk(job, off, data[off:off + piece]))
    return receive(c, job, out, opts)


def receive(c, job, out, opts):
    """The job's result into out (after a cancel, with --cancel)."""
    if "--cancel" in opts:
        c.send(cancel(job))
    if "--no-read" in opts:
        time.sleep(3600)
    data, progress = bytearray(), 0
    while True:
        r = c.recv_frame()
        if r is None:
            die(4, "CLOSED: the server closed the connection")
        case, f = r
        if case == 3:
            progress += 1
        elif case == 4:
            if one(f, 1) != job or one(f, 2) != len(data):
                die(1, "chunk of job %d at %d, expected job %d at %d"
                    % (one(f, 1), one(f, 2), job, len(data)))
            data += one(f, 3, b"")
        elif case == 5:
            if one(f, 1) != job or one(f, 4) != len(data):
                die(1, "summary of job %d says %d bytes, got %d" % (one(f, 1), one(f, 4), len(data)))
            with open(out, "wb") as fh:
                fh.write(data)
            g = fields(one(f, 9, b""))
            print("done job %d: %d voxels, %d bytes, crc %08x, %d progress, grid %s depth %d"
                  % (job, one(f, 2), len(data), one(f, 5), progress,
                     "x".join(str(v) for v in repeated_uints(g.get(1, []))),
                     one(g, 2)), flush=True)
            return 0
        elif case == 6:
            err(f)
        else:
            die(1, "unexpected reply %d" % case)


def cmd_mesh(path, args):
    name, res, out, opts = args[0], int(args[1]), args[2], args[3:]
    with open(name, "rb") as fh:
        data = fh.read()
    channel = int(opts[opts.index("--channel") + 1]) if "--channel" in opts else 0
    pad = int(opts[opts.index("--pad") + 1]) if "--pad" in opts else 1
    piece = int(opts[opts.index("--chunked") + 1]) if "--chunked" in opts else 0
    c = Conn(path)
    c.hello()
    if piece:
        c.send(mesh_submit(b"", res, pad, channel, name.encode(), input_bytes=len(data)))
    else:
        c.send(mesh_submit(data, res, pad, channel, name.encode()))
    acc = c.expect(2)
    job = one(acc, 1)
    print("accepted job %d position %d" % (job, one(acc, 2)), flush=True)
    if piece:
        upload(c, job, data, piece)
    return receive(c, job, out, opts)


def cmd_mesh_declare(path, n):
    """The answer to a mesh Submit declaring n bytes of input, none sent;
    then the connection must still answer a ping."""
    c = Conn(path)
    c.hello()
    c.send(mesh_submit(b"", 16, 1, input_bytes=n))
    r = c.recv_frame()
    if r is None:
        die(4, "CLOSED: the server closed the connection")
    if r[0] == 2:
        print("accepted job %d" % one(r[1], 1), flush=True)
        return 0
    if r[0] != 6:
        die(1, "unexpected reply %d" % r[0])
    print("ERROR %s: %s (job %d)" % (CODES.get(one(r[1], 2), "?"),
                                     one(r[1], 3, b"").decode(errors="replace"),
                                     one(r[1], 1)), flush=True)
    c.send(ping(11))
    print("pong %d" % one(c.expect(8), 1), flush=True)
    return 3


def cmd_status(path):
    c = Conn(path)
    c.hello()
    c.send(status())
    f = c.expect(7)
    for w in f.get(2, []):
        wf = fields(w)
        print("worker pid=%d cpu=%d state=%d jobs=%d replaced=%d stalls=%d"
              % (one(wf, 1), s64(one(wf, 2)), one(wf, 3), one(wf, 4), one(wf, 6, 0),
                 one(wf, 7, 0)))
    run = f.get(4)
    rf = fields(run[0]) if run else None
    print("queued=%d clients=%d running=%s%s" % (
        one(f, 3), one(f, 5), one(rf, 1) if run else "none",
        " fraction=%.3f" % dbl(rf, 3) if run else ""))
    return 0


def cmd_ping(path):
    c = Conn(path)
    c.hello()
    c.send(ping(42))
    f = c.expect(8)
    print("pong %d" % one(f, 1))
    return 0


def cmd_hold(path, n):
    conns = []
    for _ in range(n):
        c = Conn(path)
        c.hello()
        conns.append(c)
    print("holding %d" % n, flush=True)
    time.sleep(3600)
    return 0


def cmd_flood(path, n):
    """n connections in bursts of 100: every one read to its end (a
    refused connection gets one Error and is closed)."""
    counts, t0, done = {}, time.time(), 0
    while done < n:
        batch = [Conn(path) for _ in range(min(100, n - done))]
        for c in batch:
            got = "none"
            while True:
                r = c.recv_frame()
                if r is None:
                    break
                if r[0] == 6:
                    got = CODES.get(one(r[1], 2), "?")
            counts[got] = counts.get(got, 0) + 1
            c.s.close()
        done += len(batch)
    print("flood %d in %.1f s: %s" % (n, time.time() - t0,
                                      " ".join("%s=%d" % kv for kv in sorted(counts.items()))))
    return 0


# ---------------------------------------------------------------- abuse

def expect_close(c, want_error=None):
    """Read until EOF: the connection must close (after an Error of the
    wanted code, when given)."""
    got = []
    while True:
        try:
            r = c.recv_frame()
        except socket.timeout:
            die(5, "TIMEOUT: the connection stayed open")
        if r is None:
            break
        got.append(r)
    codes = [CODES.get(one(f, 2)) for case, f in got if case == 6]
    if want_error and want_error not in codes:
        die(1, "closed, but without an Error %s (got %s)" % (want_error, codes))
    print("closed after %s" % (codes or "nothing"))
    return 0


def expect_error(c, code):
    r = c.recv_frame()
    if r is None or r[0] != 6:
        die(1, "no Error reply (%s)" % (r and r[0]))
    got = CODES.get(one(r[1], 2))
    msg = one(r[1], 3, b"").decode()
    if got != code:
        die(1, "Error %s (wanted %s): %s" % (got, code, msg))
    print("ERROR %s: %s" % (got, msg))
    return 0


def abuse(path, kind):
    c = Conn(path)
    if kind == "len0":
        c.send(struct.pack(">I", 0))
        return expect_close(c, "INVALID_INPUT")
    if kind == "lenmax":  # one over the default 1 MiB limit
        c.send(struct.pack(">I", (1 << 20) + 1))
        return expect_close(c, "INVALID_INPUT")
    if kind == "len4g":
        c.send(b"\xff\xff\xff\xff")
        return expect_close(c, "INVALID_INPUT")
    if kind == "truncated":
        c.send(struct.pack(">I", 100) + b"\x0a\x02")
        c.s.shutdown(socket.SHUT_WR)
        return expect_close(c)
    if kind == "slow":  # one byte a second: the client timeout closes it
        t0 = time.time()
        for b in hello():
            c.send(bytes([b]))
            r, _, _ = select.select([c.s], [], [], 1.0)
            if r:  # the server said something, or closed
                break
        print("after %.0f s:" % (time.time() - t0), end=" ")
        return expect_close(c)
    if kind == "garbage":
        c.send(frame(b"\xff\xff\xff\xff\xff\xff\xff\xff\xff\xff\xff"))
        return expect_close(c, "INVALID_INPUT")
    if kind == "nohello":
        c.send(status())
        return expect_close(c, "INVALID_INPUT")
    if kind == "badversion":
        c.send(hello(2))
        return expect_close(c, "INVALID_INPUT")
    c.hello()
    if kind == "unknown-enum":
        c.send(submit("x", 8, [-1, 1], channel=99))
        return expect_error(c, "INVALID_INPUT")
    if kind == "nul":
        c.send(submit(b"x\x00+y", 8, [-1, 1]))
        return expect_error(c, "INVALID_INPUT")
    if kind == "huge-expr":  # over the default max_expr_bytes, under max_frame
        c.send(submit("x" + "+x" * 40000, 8, [-1, 1]))
        return expect_error(c, "LIMIT_EXCEEDED")
    if kind == "deep-expr":  # within max_expr_bytes, deeper than max_expr_depth
        c.send(submit("(" * 300 + "x" + ")" * 300, 8, [-1, 1]))
        c.expect(2)
        return expect_error(c, "LIMIT_EXCEEDED")
    if kind == "res":
        c.send(submit("x", 5000, [-1, 1]))
        return expect_error(c, "LIMIT_EXCEEDED")
    if kind == "bad-expr":
        c.send(submit("sinn(x)", 8, [-1, 1]))
        c.expect(2)
        return expect_error(c, "INVALID_INPUT")
    if kind == "bad-cancel":
        c.send(cancel(999999))
        return expect_error(c, "INVALID_INPUT")
    if kind == "unknown-request":
        c.send(frame(request(15, b"")))
        return expect_error(c, "INVALID_INPUT")
    if kind.startswith("input-"):
        return abuse_input(path, c, kind)
    die(2, "unknown abuse kind " + kind)


SPHERE = b"sqrt(x^2+y^2+z^2) - 0.8"


def expect_job_error(c, job, code):
    """The job's terminal Error, of this code, naming the job."""
    r = c.recv_frame()
    while r is not None and r[0] == 3:  # progress
        r = c.recv_frame()
    if r is None or r[0] != 6 or one(r[1], 1) != job:
        die(1, "no terminal Error for job %d (%s)" % (job, r and (r[0], r[1])))
    return expect_code(r, code)


def expect_code(r, code):
    got = CODES.get(one(r[1], 2))
    msg = one(r[1], 3, b"").decode()
    if got != code:
        die(1, "Error %s (wanted %s): %s" % (got, code, msg))
    print("ERROR %s: %s (job %d)" % (got, msg, one(r[1], 1)), flush=True)
    return 0


def accepted_upload(c, size):
    c.send(submit(b"", 16, [-1, 1], input_bytes=size))
    return one(c.expect(2), 1)


def abuse_input(path, c, kind):
    """Chunked input gone wrong; each ends the one job (or the one request)
    and the connection goes on: a ping answers after it."""
    if kind == "input-over-cap":  # the declared size over max_input_bytes (64M)
        c.send(submit(b"", 16, [-1, 1], input_bytes=(64 << 20) + 1))
        rc = expect_error(c, "LIMIT_EXCEEDED")
    elif kind == "input-over-expr":  # an expression over max_expr_bytes, as input
        c.send(submit(b"", 16, [-1, 1], input_bytes=65537))
        rc = expect_error(c, "LIMIT_EXCEEDED")
    elif kind == "input-and-inline":
        c.send(submit(SPHERE, 16, [-1, 1], input_bytes=len(SPHERE)))
        rc = expect_error(c, "INVALID_INPUT")
    elif kind == "input-chunk-over-cap":  # a chunk reaching past max_input_bytes
        c.send(input_chunk(1, 64 << 20, b"x"))
        rc = expect_error(c, "LIMIT_EXCEEDED")
    elif kind == "input-past-total":
        job = accepted_upload(c, 10)
        c.send(input_chunk(job, 0, SPHERE))
        rc = expect_job_error(c, job, "INVALID_INPUT")
    elif kind == "input-order":  # a gap, then the chunks after its end
        job = accepted_upload(c, len(SPHERE))
        c.send(input_chunk(job, 0, SPHERE[:5]))
        c.send(input_chunk(job, 10, SPHERE[10:]))
        rc = expect_job_error(c, job, "INVALID_INPUT")
        c.send(input_chunk(job, 5, SPHERE[5:]))
        expect_error(c, "INVALID_INPUT")  # no job waits for it any more
    elif kind == "input-nul":
        job = accepted_upload(c, 8)
        c.send(input_chunk(job, 0, b"x+\x00y+z+1"))
        rc = expect_job_error(c, job, "INVALID_INPUT")
    elif kind == "input-unknown":
        c.send(input_chunk(999999, 0, SPHERE))
        rc = expect_error(c, "INVALID_INPUT")
    elif kind == "input-foreign":  # another connection's upload is not ours
        job = accepted_upload(c, len(SPHERE))
        other = Conn(path)
        other.hello()
        other.send(input_chunk(job, 0, SPHERE))
        rc = expect_error(other, "INVALID_INPUT")
        upload(c, job, SPHERE, 4)  # its own connection finishes it
        while True:
            r = c.recv_frame()
            if r is None or r[0] in (5, 6):
                break
        if r is None or r[0] != 5:
            die(1, "job %d did not succeed: %s" % (job, r))
        print("job %d done by its own connection" % job)
    elif kind == "input-cancel":
        job = accepted_upload(c, 100)
        c.send(input_chunk(job, 0, b"x" * 10))
        c.send(cancel(job))
        rc = expect_job_error(c, job, "CANCELLED")
    elif kind == "input-stall":  # half an input, then nothing: the client timeout ends it
        job = accepted_upload(c, 100)
        c.send(input_chunk(job, 0, b"x" * 10))
        rc = expect_job_error(c, job, "TIMEOUT")
    elif kind == "input-close":  # leave in the middle of an upload
        job = accepted_upload(c, 60000)
        c.send(input_chunk(job, 0, b"x" * 1000))
        c.send(ping(9))
        c.expect(8)
        print("leaving job %d after 1000 of 60000 bytes" % job)
        return 0
    elif kind == "input-hold":  # an upload holds its place: another job of the uid is refused
        accepted_upload(c, 100)
        other = Conn(path)
        other.hello()
        other.send(submit(SPHERE, 16, [-1, 1]))
        return expect_error(other, "LIMIT_EXCEEDED")
    else:
        die(2, "unknown abuse kind " + kind)
    c.send(ping(5))
    c.expect(8)
    return rc


def main():
    if len(sys.argv) < 3:
        die(2, __doc__)
    path, cmd, args = sys.argv[1], sys.argv[2], sys.argv[3:]
    try:
        if cmd == "submit":
            return cmd_submit(path, args)
        if cmd == "mesh":
            return cmd_mesh(path, args)
        if cmd == "mesh-declare":
            return cmd_mesh_declare(path, int(args[0]))
        if cmd == "csg-bad":
            return cmd_csg_bad(path, args[0])
        if cmd == "band":
            return cmd_band(path, args[0], int(args[1]), int(args[2]))
        if cmd == "status":
            return cmd_status(path)
        if cmd == "ping":
            return cmd_ping(path)
        if cmd == "abuse":
            return abuse(path, args[0])
        if cmd == "hold":
            return cmd_hold(path, int(args[0]))
        if cmd == "flood":
            return cmd_flood(path, int(args[0]))
    except socket.timeout:
        die(5, "TIMEOUT")
    except (ConnectionRefusedError, FileNotFoundError) as e:
        die(4, "CLOSED: cannot connect: %s" % e)
    die(2, "unknown command " + cmd)


if __name__ == "__main__":
    sys.exit(main())
