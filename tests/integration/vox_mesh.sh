#!/bin/bash
# vox mesh as a user runs it: VOD files of every channel voxelized here,
# their meshes read back by vox mesh-info (the mesh loaders and the topology
# of mesh/, not the writer's code) and found watertight, the same bytes
# serially and with workers, in every format, mip and adaptive levels
# closed too, and the refusals: bad options, a damaged file.
. "$(dirname "$0")/lib.sh"

SPHERE='sqrt(x^2+y^2+z^2) - 0.8'
"$VOX" voxelize --embedded -w 2 -e "$SPHERE" -r 48 -o "$TMP/s3.vod" -q
"$VOX" voxelize --embedded -w 2 -e "$SPHERE" -r 48 --channel occupancy -o "$TMP/s1.vod" -q
"$VOX" voxelize --embedded -w 2 -f examples/torus.vx -r 64 -o "$TMP/torus.vod" -q

# watertight NAME MESH: vox mesh-info says so, with no open edge
watertight() {
    local n=$1 m=$2
    if "$VOX" mesh-info "$m" >"$TMP/info" 2>&1 && grep -Eq '^  watertight +yes' "$TMP/info" &&
       grep -Eq ' 0 open, 0 non-manifold, 0 inconsistently oriented' "$TMP/info"; then
        pass "$n"
    else fail "$n" "$(grep -E 'edges|watertight|volume' "$TMP/info" | tr '\n' ' ')"; fi
}

check "vox mesh --help exits 0" "$VOX" mesh --help
for f in s3 s1 torus; do
    check "$f: meshed serially" "$VOX" mesh "$TMP/$f.vod" -o "$TMP/$f-0.ply" -w 0 -q
    check "$f: meshed by 2 workers" "$VOX" mesh "$TMP/$f.vod" -o "$TMP/$f-2.ply" -w 2 -q
    check "$f: the same bytes for 0 and 2 workers" cmp "$TMP/$f-0.ply" "$TMP/$f-2.ply"
    watertight "$f: the PLY is watertight" "$TMP/$f-2.ply"
done

# a density channel: the sphere's own mesh voxelized as density, meshed back
"$VOX" mesh "$TMP/s3.vod" -o "$TMP/s3.obj" -q
check "density: a mesh job writes channel 2" \
    "$VOX" voxelize --embedded --mesh "$TMP/s3.obj" --channel density -r 48 -o "$TMP/d.vod" -q
for iso in 127 30 220; do
    check "density --iso $iso: meshed" "$VOX" mesh "$TMP/d.vod" -o "$TMP/d$iso.stl" --iso $iso -q
    watertight "density --iso $iso: the STL is watertight" "$TMP/d$iso.stl"
done
v30=$("$VOX" mesh-info "$TMP/d30.stl" | awk '/volume/ {print $2}')
v220=$("$VOX" mesh-info "$TMP/d220.stl" | awk '/volume/ {print $2}')
if awk -v a="$v30" -v b="$v220" 'BEGIN { exit !(a > b && b > 0) }'; then
    pass "density: a lower iso encloses more ($v30 > $v220)"
else fail "density: a lower iso encloses more" "$v30, $v220"; fi

for fmt in ply ply-ascii obj stl; do
    "$VOX" mesh "$TMP/torus.vod" -o "$TMP/t0.$fmt.out" --format $fmt -w 0 -q
    check "--format $fmt: 0 and 2 workers give the same bytes" \
        bash -c "'$VOX' mesh '$TMP/torus.vod' -o '$TMP/t2.out' --format $fmt -w 2 -q && cmp '$TMP/t0.$fmt.out' '$TMP/t2.out'"
    cp "$TMP/t0.$fmt.out" "$TMP/t.$fmt"
    watertight "--format $fmt: watertight as read back" "$TMP/t.$fmt"
done
if head -c 200 "$TMP/t.ply" | grep -aq 'binary_little_endian' &&
   head -c 200 "$TMP/t.ply-ascii" | grep -aq 'format ascii'; then pass "ply is binary, ply-ascii text"
else fail "ply is binary, ply-ascii text"; fi

for l in 1 2; do
    check "torus --level $l: meshed" "$VOX" mesh "$TMP/torus.vod" -o "$TMP/tl$l.ply" --level $l -q
    watertight "torus --level $l: watertight" "$TMP/tl$l.ply"
done
for r in 0.2,0.5,1 0.05 0.4,0.41; do
    check "adaptive --lod-radii $r: meshed" "$VOX" mesh "$TMP/torus.vod" -o "$TMP/lod.ply" \
        --lod-center 0.6,0,0 --lod-radii $r -q
    watertight "adaptive --lod-radii $r: watertight" "$TMP/lod.ply"
done
full=$("$VOX" mesh-info "$TMP/torus-2.ply" | awk '/triangles/ {print $2}')
lod=$("$VOX" mesh "$TMP/torus.vod" -o "$TMP/lod.ply" --lod-center 0.6,0,0 --lod-radii 0.3,0.6 |
      awk '{print $2; exit}')
if [ -n "$lod" ] && [ "$lod" -lt "$full" ]; then pass "adaptive: fewer triangles ($lod < $full)"
else fail "adaptive: fewer triangles" "$lod, $full"; fi

# refusals
refuse "no output" 2 "missing -o OUT" "$VOX" mesh "$TMP/s3.vod"
refuse "unknown extension" 2 "no format from its extension" "$VOX" mesh "$TMP/s3.vod" -o "$TMP/x.off"
refuse "bad --format" 2 "not ply, ply-ascii, obj or stl" "$VOX" mesh "$TMP/s3.vod" -o x --format vtk
refuse "bad --iso" 2 "--iso 255: not a whole number 0..254" "$VOX" mesh "$TMP/s3.vod" -o "$TMP/x.ply" --iso 255
refuse "a level past the tree" 2 "level 9: the file has levels 0..2" \
    "$VOX" mesh "$TMP/s3.vod" -o "$TMP/x.ply" --level 9
refuse "radii without a centre" 2 "go together" "$VOX" mesh "$TMP/s3.vod" -o "$TMP/x.ply" --lod-radii 1
refuse "radii not increasing" 2 "increasing" \
    "$VOX" mesh "$TMP/s3.vod" -o "$TMP/x.ply" --lod-center 0,0,0 --lod-radii 1,0.5
refuse "a bad centre" 2 "want X,Y,Z" "$VOX" mesh "$TMP/s3.vod" -o "$TMP/x.ply" --lod-center 0,0 --lod-radii 1
refuse "a missing file" 1 "cannot open" "$VOX" mesh "$TMP/none.vod" -o "$TMP/x.ply"
cp "$TMP/s3.vod" "$TMP/bad.vod"
printf '\x55' | dd of="$TMP/bad.vod" bs=1 seek=3000 conv=notrunc 2>/dev/null
refuse "a damaged file" 1 "CRC mismatch" "$VOX" mesh "$TMP/bad.vod" -o "$TMP/x.ply"
if [ ! -e "$TMP/x.ply" ] && ! ls "$TMP"/x.ply.tmp.* >/dev/null 2>&1; then
    pass "a refused job leaves no file"
else fail "a refused job leaves no file"; fi
