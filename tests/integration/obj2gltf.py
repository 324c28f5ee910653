#!/usr/bin/env python3
"""obj2gltf.py IN.obj OUT [glb|gltf|embedded]: the OBJ's vertices and
(fan-triangulated) faces as a glTF 2.0 file, for the integration tests:
u16 indices, one node; glb: one .glb; gltf: OUT.gltf and its buffer in
OUT.bin beside it; embedded: OUT.gltf with the buffer as a data: URI."""
import base64, json, struct, sys

src, out, kind = sys.argv[1], sys.argv[2], sys.argv[3]
v, t = [], []
for line in open(src):
    w = line.split()
    if w and w[0] == "v":
        v.append(tuple(float(x) for x in w[1:4]))
    if w and w[0] == "f":
        f = [int(x.split("/")[0]) - 1 for x in w[1:]]
        t += [(f[0], f[k], f[k + 1]) for k in range(1, len(f) - 1)]
pos = b"".join(struct.pack("<3f", *p) for p in v)
idx = b"".join(struct.pack("<3H", *x) for x in t)
idx_len = len(idx)
idx += b"\0" * (-len(idx) % 4)
data = pos + idx
doc = {
    "asset": {"version": "2.0", "generator": "obj2gltf.py"},
    "scene": 0, "scenes": [{"nodes": [0]}], "nodes": [{"mesh": 0}],
    "meshes": [{"primitives": [{"attributes": {"POSITION": 0}, "indices": 1}]}],
    "buffers": [{"byteLength": len(data)}],
    "bufferViews": [{"buffer": 0, "byteLength": len(pos)},
                    {"buffer": 0, "byteOffset": len(pos), "byteLength": idx_len}],
    "accessors": [{"bufferView": 0, "componentType": 5126, "count": len(v), "type": "VEC3"},
                  {"bufferView": 1, "componentType": 5123, "count": 3 * len(t), "type": "SCALAR"}],
}
if kind == "glb":
    j = json.dumps(doc).encode()
    j += b" " * (-len(j) % 4)
    total = 12 + 8 + len(j) + 8 + len(data)
    with open(out, "wb") as f:
        f.write(struct.pack("<III", 0x46546C67, 2, total) + struct.pack("<II", len(j), 0x4E4F534A) + j)
        f.write(struct.pack("<II", len(data), 0x004E4942) + data)
elif kind == "gltf":
    name = out.rsplit("/", 1)[-1]
    doc["buffers"][0]["uri"] = name + ".bin"
    open(out + ".bin", "wb").write(data)
    open(out + ".gltf", "w").write(json.dumps(doc))
else:
    doc["buffers"][0]["uri"] = "data:application/octet-stream;base64," + base64.b64encode(data).decode()
    open(out + ".gltf", "w").write(json.dumps(doc))
