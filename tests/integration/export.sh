#!/bin/bash
# vox export and the Python reader (python/voxd) end to end. VOD files of
# every channel (1, 2, 3), compression (ZLIB, RUNL, NONE), hash (SFHS, XX32)
# and of expressions and meshes are written; each is exported to every format
# and the exports are read back by export_check.py's readers, written from
# the formats' specifications, and compared voxel for voxel with voxd.read;
# voxd.read's content checksum must be vox info's (the C reader's) on every
# file; damaged copies must be refused by both with the same message.
. "$(dirname "$0")/lib.sh"

# numpy and VTK are test dependencies (make deps installs python3-numpy and
# python3-vtk9, for the system's python3): a python3 without them is a
# failure, never a skip.
if ! PY=$(python_with numpy vtkmodules.vtkIOImage); then
    fail "a python3 with numpy and VTK (make deps installs python3-numpy, python3-vtk9)"
    exit 0
fi
CHECK="$ROOT/tests/integration/export_check.py"
# The .vdb exports are read by OpenVDB's own code: vdb_print (make deps
# installs libopenvdb-tools) and vdb_dump, built beside the vox under test.
VDB_DUMP="$(dirname "$VOX")/tests/vdb_dump"
command -v vdb_print >/dev/null || fail "vdb_print on the PATH (make deps installs libopenvdb-tools)"
[ -x "$VDB_DUMP" ] || fail "$VDB_DUMP built (make test-build builds it)"

cat >"$TMP/box.obj" <<'OBJ'
v -1 -0.6 -0.8
v 1 -0.6 -0.8
v -1 0.6 -0.8
v 1 0.6 -0.8
v -1 -0.6 0.8
v 1 -0.6 0.8
v -1 0.6 0.8
v 1 0.6 0.8
f 1 3 4
f 1 4 2
f 5 6 8
f 5 8 7
f 1 2 6
f 1 6 5
f 3 7 8
f 3 8 4
f 1 5 7
f 1 7 3
f 2 4 8
f 2 8 6
OBJ

# pycheck NAME MODE ARGS...: export_check.py's checks, printed; a crash, an
# exit status other than 0 or a mode that checked nothing fails NAME
pycheck() {
    local n=$1 out rc
    shift
    out=$("$PY" "$CHECK" "$@" 2>&1)
    rc=$?
    printf '%s\n' "$out"
    if [ "$rc" -ne 0 ] || ! grep -Eq '^(PASS|FAIL): ' <<<"$out"; then
        fail "$n: export_check.py $1 ran to its end" "exit $rc: $(tail -3 <<<"$out")"
    fi
}

vod() { # NAME ARGS...: write $TMP/NAME.vod with the embedded engine
    local n=$1; shift
    check "voxelize $n" "$VOX" voxelize --embedded -w 0 -q -o "$TMP/$n.vod" "$@"
}
vod sphere-ch3-zlib -e 'x*x+y*y+z*z-0.6' -r 37
vod torus-ch1-runl-xx32 -e '(sqrt(x*x+y*y)-0.6)^2+z*z-0.09' -d -1,1,-1,1,-0.5,0.5 -r 45 \
    --channel occupancy --compress runl --hash xx32
vod sphere-ch3-none-b8 -e 'x*x+y*y+z*z-0.5' -r 30 --brick 8 --compress none
vod box-ch2-density --mesh "$TMP/box.obj" --channel density -r 26
vod box-ch1 --mesh "$TMP/box.obj" -r 33 --brick 4 --compress runl

for f in "$TMP"/*.vod; do
    n=$(basename "$f" .vod) d="$TMP/$n"
    mkdir -p "$d"
    for ext in nrrd raw vti binvox; do
        check "$n: export .$ext" "$VOX" export "$f" -o "$d/x.$ext"
    done
    check "$n: export gzip NRRD level 1" "$VOX" export "$f" -o "$d/l1.nrrd" --gzip --level 1
    check "$n: export NRRD --no-normals" "$VOX" export "$f" -o "$d/nn.nrrd" --no-normals
    check "$n: export gzip NRRD" "$VOX" export "$f" -o "$d/gz.nrrd" --gzip
    check "$n: export gzip NRRD --no-normals" "$VOX" export "$f" -o "$d/gznn.nrrd" --gzip --no-normals
    echo "2,9,1,12,3,7" >"$d/box.txt"
    check "$n: export --bbox" "$VOX" export "$f" --format raw -o "$d/box.raw" --bbox 2,9,1,12,3,7
    pycheck "$n" formats "$f" "$d"
    check "$n: export .vdb" "$VOX" export "$f" -o "$d/x.vdb"
    check "$n: export .vdb level 1" "$VOX" export "$f" -o "$d/l1.vdb" --level 1
    check "$n: export .vdb --bbox" "$VOX" export "$f" -o "$d/box.vdb" --bbox 2,9,1,12,3,7
    pycheck "$n" vdb "$f" "$d" "$VDB_DUMP"
    pycheck "$n" vtk "$f" "$d"
    want=$("$VOX" info "$f" | grep '^  voxels')
    got=$("$PY" "$CHECK" checksum "$f" 2>&1)
    rc=$?
    if [ "$rc" -eq 0 ] && [ -n "$want" ] && [ "$want" = "$got" ]; then pass "$n: voxd.read's voxels are vox info's"
    else fail "$n: voxd.read's voxels are vox info's" "vox info: $want; voxd (exit $rc): $got"; fi
    pycheck "$n" damage "$f" "$VOX" "$d"
done

# ---------------------------------------------------------------- refusals
f="$TMP/sphere-ch3-zlib.vod"
refuse "export: no format from the name" 2 "no format from its extension" "$VOX" export "$f" -o "$TMP/x.dat"
refuse "export: unknown --format" 2 "not nrrd, raw, binvox, vti or vdb" "$VOX" export "$f" -o "$TMP/x" --format vdf
refuse "export: --gzip outside NRRD" 2 "NRRD only" "$VOX" export "$f" -o "$TMP/x.raw" --gzip
refuse "export: level out of range" 2 "the file has levels 0\.\.2" "$VOX" export "$f" -o "$TMP/x.raw" --level 5
refuse "export: --bbox past the volume" 2 "axis y needs" "$VOX" export "$f" -o "$TMP/x.raw" --bbox 0,4,0,99,0,4
refuse "export: --bbox malformed" 2 "want X0,X1" "$VOX" export "$f" -o "$TMP/x.raw" --bbox 0,4,0
refuse "export: a damaged file" 1 "trailer channel 9 unknown" "$VOX" export "$TMP/sphere-ch3-zlib/damaged.vod" -o "$TMP/x.raw"
if [ ! -e "$TMP/x.raw" ]; then pass "export: nothing written on refusal"
else fail "export: nothing written on refusal"; fi
mkdir -p "$TMP/lone"
cp "$VOX" "$TMP/lone/vox"
refuse "export: .vdb without the vox-vdb.so module names it" 1 "needs the OpenVDB module vox-vdb.so" \
    "$TMP/lone/vox" export "$f" -o "$TMP/x.vdb"
check "export: other formats without the module" "$TMP/lone/vox" export "$f" -o "$TMP/lone.nrrd"
if [ ! -e "$TMP/x.vdb" ]; then pass "export: no .vdb left on refusal"
else fail "export: no .vdb left on refusal"; fi
head -c 300 "$f" >"$TMP/cut.vod"
refuse "export: a truncated file" 1 "truncated" "$VOX" export "$TMP/cut.vod" -o "$TMP/x.nrrd"
# A write that fails as on a full disk (a file size limit of a few KiB,
# SIGXFSZ ignored so that the write returns EFBIG): every format says so,
# naming the user's file, and leaves nothing.  OpenVDB's own File::write
# never looks at its stream: a truncated .vdb was reported written before.
for ext in vdb nrrd vti raw binvox; do
    refuse "export: .$ext past a file size limit is refused" 1 "x-lim\.$ext: File too large" \
        sh -c 'trap "" XFSZ; ulimit -f 2; exec "$@"' sh "$VOX" export "$f" -o "$TMP/x-lim.$ext"
    if [ ! -e "$TMP/x-lim.$ext" ]; then pass "export: no .$ext left past the limit"
    else fail "export: no .$ext left past the limit"; fi
done
# the raw format's header, a file of its own, is named when it cannot be
# written (a directory in its place), and the raw file is not left alone
mkdir -p "$TMP/xj.json"
refuse "export: a raw header that cannot be written names the header" 1 "xj\.json: Is a directory" \
    "$VOX" export "$f" -o "$TMP/xj.raw"
if [ ! -e "$TMP/xj.raw" ]; then pass "export: no raw file without its header"
else fail "export: no raw file without its header"; fi
# and the other way: a raw file that cannot be committed (a directory in its
# place) leaves no header describing it
mkdir -p "$TMP/xr.raw"
refuse "export: a raw file that cannot be committed is named" 1 "xr\.raw: Is a directory" \
    "$VOX" export "$f" -o "$TMP/xr.raw"
if [ ! -e "$TMP/xr.json" ]; then pass "export: no header without its raw file"
else fail "export: no header without its raw file"; fi

# ---------------------------------------------------------------- pip install
if "$PY" -m pip --version >/dev/null 2>&1; then
    if "$PY" -m pip install --no-deps --no-build-isolation --target "$TMP/site" "$ROOT/python" \
        >"$TMP/pip.out" 2>&1 && PYTHONPATH="$TMP/site" "$PY" -c \
        "import voxd, sys; v = voxd.read(sys.argv[1]); assert v.shape == (37, 37, 37)" "$f"; then
        pass "pip install ./python gives an importable voxd"
    else fail "pip install ./python gives an importable voxd" "$(tail -3 "$TMP/pip.out")"; fi
else
    fail "pip install ./python gives an importable voxd" "no pip for $PY"
fi
