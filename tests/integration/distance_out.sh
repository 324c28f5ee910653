#!/bin/bash
# Channel 4 (signed distance) of an implicit surface and what is made of it:
# vox voxelize -f --channel distance gives the same bytes for -w 0, 1 and 2;
# voxd.read returns float32 values within the documented bound of the
# torus's closed form, of the right sign, +-W beyond the band; vox info names
# the channel and the band; vox export writes NRRD (raw and gzip), VTI and
# raw + JSON as float32 (read back by VTK's readers and numpy) and .vdb as a
# level set that vdb_print reports as one (background the band's width,
# active voxels the band's, every value read by libopenvdb); vox mesh
# extracts the zero level; vox render draws it.  distance_check.py holds
# the Python checks.
. "$(dirname "$0")/lib.sh"

if ! PY=$(python_with numpy vtkmodules.vtkIOImage); then
    fail "a python3 with numpy and VTK (make deps installs python3-numpy, python3-vtk9)"
    exit 0
fi
CHECK="$ROOT/tests/integration/distance_check.py"
VDB_DUMP="$(dirname "$VOX")/tests/vdb_dump"
command -v vdb_print >/dev/null || fail "vdb_print on the PATH (make deps installs libopenvdb-tools)"
[ -x "$VDB_DUMP" ] || fail "$VDB_DUMP built (make test-build builds it)"

pycheck() { # NAME ARGS...: distance_check.py's lines; a crash fails NAME
    local n=$1 out rc
    shift
    out=$("$PY" "$CHECK" "$@" 2>&1)
    rc=$?
    printf '%s\n' "$out"
    if [ "$rc" -ne 0 ] || ! grep -Eq '^(PASS|FAIL): ' <<<"$out"; then
        fail "$n: distance_check.py $1 ran to its end" "exit $rc: $(tail -3 <<<"$out")"
    fi
}

T="$TMP/t.vod"
for w in 0 1 2; do
    check "voxelize the torus's distance, -w $w" "$VOX" voxelize --embedded -q -w $w \
        -f "$ROOT/examples/torus.vx" -r 40 --channel distance -o "$TMP/t$w.vod"
done
cp "$TMP/t0.vod" "$T"
if cmp -s "$TMP/t0.vod" "$TMP/t1.vod" && cmp -s "$TMP/t0.vod" "$TMP/t2.vod"; then
    pass "distance: the same bytes for -w 0, 1 and 2"
else fail "distance: the same bytes for -w 0, 1 and 2"; fi

pycheck "values" values "$T"

out=$("$VOX" info "$T" 2>&1)
if grep -q "channel     4: signed distance" <<<"$out" && grep -q "band .*3 voxels" <<<"$out"; then
    pass "vox info names the channel and the band"
else fail "vox info names the channel and the band" "$out"; fi

D="$TMP/x"
mkdir -p "$D"
check "export .nrrd" "$VOX" export "$T" -o "$D/x.nrrd"
check "export .nrrd --gzip" "$VOX" export "$T" -o "$D/gz.nrrd" --gzip
check "export .vti" "$VOX" export "$T" -o "$D/x.vti"
check "export .raw" "$VOX" export "$T" -o "$D/x.raw"
check "export .vdb" "$VOX" export "$T" -o "$D/x.vdb"
pycheck "exports" exports "$T" "$D" "$VDB_DUMP"

check "vox mesh of the distance" "$VOX" mesh "$T" -o "$TMP/t.obj" -q
pycheck "mesh" mesh "$T" "$TMP/t.obj"

# vox render: the zero level drawn, as vox render draws the mesh of it
# (the pixels lit, read by VTK's PNG reader, within 3%)
check "render the distance" "$VOX" render "$T" -o "$TMP/t.png" --size 200
check "render its zero level's mesh" "$VOX" render "$TMP/t.obj" -o "$TMP/m.png" --size 200
pycheck "render" render "$TMP/t.png" "$TMP/m.png"
san_scan
