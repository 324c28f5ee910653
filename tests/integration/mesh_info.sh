#!/bin/bash
# vox mesh-info end to end: a cube written in every text format (and STL
# binary, by Python) is described the same way; --json is JSON; a bad file
# is refused with its line and exit 1; bad usage exits 2.
. "$(dirname "$0")/lib.sh"

C=$TMP/cube
cat >"$C.obj" <<'EOF'
# a cube of side 2, quads, counter-clockwise seen from outside
v -1 -1 -1
v 1 -1 -1
v 1 1 -1
v -1 1 -1
v -1 -1 1
v 1 -1 1
v 1 1 1
v -1 1 1
f 1 4 3 2
f 5 6 7 8
f 1 2 6 5
f 3 4 8 7
f 2 3 7 6
f 1 5 8 4
EOF
{
    echo OFF
    echo "8 6 12"
    grep '^v ' "$C.obj" | cut -c3-
    grep '^f ' "$C.obj" | awk '{ print 4, $2 - 1, $3 - 1, $4 - 1, $5 - 1 }'
} >"$C.off"
{
    printf 'ply\nformat ascii 1.0\nelement vertex 8\nproperty float x\nproperty float y\n'
    printf 'property float z\nelement face 6\nproperty list uchar int vertex_indices\nend_header\n'
    tail -n +3 "$C.off"
} >"$C.ply"
# STL: the quads' fans, ascii and binary
python3 - "$C.obj" "$C" <<'EOF'
import struct, sys
v, f = [], []
for line in open(sys.argv[1]):
    w = line.split()
    if w and w[0] == "v": v.append(tuple(map(float, w[1:4])))
    if w and w[0] == "f": f.append([int(i) - 1 for i in w[1:]])
tris = [(q[0], q[k], q[k + 1]) for q in f for k in range(1, len(q) - 1)]
with open(sys.argv[2] + ".stl", "w") as out:
    out.write("solid cube\n")
    for t in tris:
        out.write("facet normal 0 0 0\nouter loop\n")
        for i in t: out.write("vertex %g %g %g\n" % v[i])
        out.write("endloop\nendfacet\n")
    out.write("endsolid cube\n")
with open(sys.argv[2] + "-bin.stl", "wb") as out:
    out.write(b"solid, but binary".ljust(80, b" ") + struct.pack("<I", len(tris)))
    for t in tris:
        out.write(struct.pack("<12fH", 0, 0, 0, *[c for i in t for c in v[i]], 0))
EOF

for f in obj off ply stl -bin.stl; do
    case $f in -bin.stl) file=$C-bin.stl; fmt=STL ;; *) file=$C.$f; fmt=$(tr a-z A-Z <<<"$f") ;; esac
    refuse "mesh-info $f: format" 0 "^$file: $fmt mesh" "$VOX" mesh-info "$file"
    refuse "mesh-info $f: 8 vertices" 0 "vertices +8$" "$VOX" mesh-info "$file"
    refuse "mesh-info $f: 12 triangles" 0 "triangles +12 \(0 degenerate dropped\)" "$VOX" mesh-info "$file"
    refuse "mesh-info $f: edges" 0 "edges +18: 0 open, 0 non-manifold, 0 inconsistently oriented" \
        "$VOX" mesh-info "$file"
    refuse "mesh-info $f: volume" 0 "volume +8$" "$VOX" mesh-info "$file"
    refuse "mesh-info $f: watertight" 0 "watertight +yes" "$VOX" mesh-info "$file"
done

# --json: one object, the same figures
"$VOX" mesh-info --json "$C.ply" >"$TMP/cube.json" 2>&1
if python3 -c '
import json, sys
d = json.load(open(sys.argv[1]))
want = {"format": "PLY", "vertices": 8, "triangles": 12, "degenerate": 0, "edges": 18,
        "open_edges": 0, "nonmanifold_edges": 0, "inconsistent_edges": 0, "components": 1,
        "volume": 8, "watertight": True, "bbox": {"min": [-1, -1, -1], "max": [1, 1, 1]}}
bad = {k: d.get(k) for k in want if d.get(k) != want[k]}
sys.exit(1 if bad else 0)' "$TMP/cube.json"; then pass "mesh-info --json"
else fail "mesh-info --json" "$(cat "$TMP/cube.json")"; fi

# a cube with a face missing: open, not watertight
grep -v '^f 1 5 8 4' "$C.obj" >"$TMP/open.obj"
refuse "mesh-info: open cube" 0 "edges +17: 4 open" "$VOX" mesh-info "$TMP/open.obj"
refuse "mesh-info: open cube is not watertight" 0 "watertight +no" "$VOX" mesh-info "$TMP/open.obj"

# Blender 2.47's "Created by" header line without "comment": read, with one warning
{ sed -n 1,2p "$C.ply"; echo "Created by Blender3D 247 - www.blender.org, source file: 'cube.blend'"
  tail -n +3 "$C.ply"; } >"$TMP/blender.ply"
refuse "mesh-info: an unknown PLY header line is a warning" 0 \
    "^vox: warning: .*blender.ply: line 3: PLY header: unknown line starting 'Created' skipped" \
    "$VOX" mesh-info "$TMP/blender.ply"
refuse "mesh-info: the PLY with an unknown header line is the cube" 0 "watertight +yes" \
    "$VOX" mesh-info "$TMP/blender.ply"

# --weld: the cube with every face's own four vertices is open until welded
awk '/^v /{ v[++n] = $0 } /^f /{ for (i = 2; i <= 5; i++) print v[$i]; k += 4
     print "f", k - 3, k - 2, k - 1, k }' "$C.obj" >"$TMP/faces.obj"
refuse "mesh-info: a cube of separate faces is open" 0 "edges +30: 24 open" \
    "$VOX" mesh-info "$TMP/faces.obj"
for eps in 0 0.001 0.5; do
    refuse "mesh-info --weld $eps: 16 vertices merged" 0 "welded +16 vertices merged \(within $eps\)" \
        "$VOX" mesh-info --weld $eps "$TMP/faces.obj"
    refuse "mesh-info --weld $eps: the cube, watertight" 0 \
        "edges +18: 0 open, 0 non-manifold, 0 inconsistently oriented" \
        "$VOX" mesh-info --weld $eps "$TMP/faces.obj"
done
refuse "mesh-info --weld in JSON" 0 '"weld": 0, "welded": 16,.* "open_edges": 0' \
    "$VOX" mesh-info --json --weld 0 "$TMP/faces.obj"
refuse "mesh-info --weld 3: every triangle collapses" 1 "no triangle is left once welded at 3" \
    "$VOX" mesh-info --weld 3 "$TMP/faces.obj"
for bad in -1 1e-31 2e30 nan inf x; do
    refuse "mesh-info --weld $bad is refused" 2 "bad --weld '$bad': want 0 or a distance from 1e-30 to 1e\+30" \
        "$VOX" mesh-info --weld $bad "$TMP/faces.obj"
done

# glTF: the cube as .glb, as .gltf with its .bin and with the buffer embedded
G=$(dirname "$0")/obj2gltf.py
python3 "$G" "$C.obj" "$TMP/cube.glb" glb && python3 "$G" "$C.obj" "$TMP/ext" gltf &&
    python3 "$G" "$C.obj" "$TMP/emb" embedded
for f in "$TMP/cube.glb" "$TMP/ext.gltf" "$TMP/emb.gltf"; do
    n=$(basename "$f")
    refuse "mesh-info $n: format" 0 "^$f: glTF mesh" "$VOX" mesh-info "$f"
    refuse "mesh-info $n: the cube" 0 "edges +18: 0 open, 0 non-manifold, 0 inconsistently oriented" \
        "$VOX" mesh-info "$f"
    refuse "mesh-info $n: volume" 0 "volume +8$" "$VOX" mesh-info "$f"
done
refuse "mesh-info --format gltf" 0 "watertight +yes" "$VOX" mesh-info --format gltf "$TMP/cube.glb"
check "render a .glb" "$VOX" render "$TMP/cube.glb" -o "$TMP/glb.png" --size 64
check "render a .gltf with its .bin" "$VOX" render "$TMP/ext.gltf" -o "$TMP/gltf.png" --size 64
check "render: the same picture" cmp "$TMP/glb.png" "$TMP/gltf.png"
mv "$TMP/ext.bin" "$TMP/moved.bin"
refuse "mesh-info: a .gltf whose .bin is missing" 1 "buffer 0: cannot read .*ext.bin" \
    "$VOX" mesh-info "$TMP/ext.gltf"
mv "$TMP/moved.bin" "$TMP/ext.bin"
head -c 100 "$TMP/cube.glb" >"$TMP/short.glb"
refuse "mesh-info: a .glb cut short" 1 "the GLB header says [0-9]+ bytes, the file has 100" \
    "$VOX" mesh-info "$TMP/short.glb"

# bad files: exit 1 with the place
sed 's/^f 2 3 7 6/f 2 3 7 9/' "$C.obj" >"$TMP/bad.obj"
refuse "mesh-info: index out of range" 1 "^vox: .*bad.obj: line 14: face: vertex index 9 out of range" \
    "$VOX" mesh-info "$TMP/bad.obj"
head -c 150 "$C-bin.stl" >"$TMP/short.stl"
refuse "mesh-info: binary STL of the wrong size" 1 "must be 684 bytes, the file has 150" \
    "$VOX" mesh-info --format stl "$TMP/short.stl"
refuse "mesh-info: missing file" 1 "cannot open" "$VOX" mesh-info "$TMP/none.obj"
: >"$TMP/empty.obj"
refuse "mesh-info: empty file" 1 "empty file" "$VOX" mesh-info "$TMP/empty.obj"
refuse "mesh-info: PLY read as OFF" 1 "not an OFF file" "$VOX" mesh-info -f off "$C.ply"

# usage
refuse "mesh-info --help" 0 "usage: vox mesh-info FILE" "$VOX" mesh-info --help
refuse "mesh-info without a file" 2 "mesh-info: missing the mesh FILE" "$VOX" mesh-info
refuse "mesh-info, a bad --format" 2 "bad --format 'fbx'" "$VOX" mesh-info -f fbx "$C.obj"
refuse "vox --help names mesh-info" 0 "mesh-info" "$VOX" --help
