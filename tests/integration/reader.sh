#!/bin/bash
# The Python reader (python/voxd) on what export.sh does not reach: the
# trailer's metadata and the header's fields against what the test asked
# vox voxelize for and what vox info (the C reader) says; every level from 1
# to the root (levels >= 2 included) against the level below downsampled by
# the test and against `vox export --level` (the C reader); float voxels
# (flags bit 2) in files written by the test from the format alone, bit for
# bit at three levels, read the same by vox info.  reader_check.py holds the
# checks; Debian's python3 (numpy) runs them, a python3 without numpy fails.
. "$(dirname "$0")/lib.sh"

PY=/usr/bin/python3
if ! "$PY" -c 'import numpy' 2>/dev/null; then
    fail "$PY with numpy (make deps installs python3-numpy)"
    exit 0
fi
CHECK="$ROOT/tests/integration/reader_check.py"

# pycheck ARGS...: reader_check.py's lines; a crash, an exit status other
# than 0 or 1, or no line at all fails
pycheck() {
    local out rc
    out=$("$PY" "$CHECK" "$@" 2>&1)
    rc=$?
    printf '%s\n' "$out"
    if [ "$rc" -gt 1 ] || ! grep -Eq '^(PASS|FAIL): ' <<<"$out"; then
        fail "reader_check.py $1 ran to its end" "exit $rc: $(tail -3 <<<"$out")"
    fi
}

E='x*x + y*y + z*z - 0.55'
check "voxelize the metadata file" "$VOX" voxelize --embedded -w 0 -q -e "$E" \
    -d -0.75,1.25,-1.5,0.5,-1,1 -r 44 --brick 8 -o "$TMP/meta.vod"
pycheck meta "$TMP/meta.vod" "$VOX" "$E" 44 -0.75,1.25,-1.5,0.5,-1,1 8

# height 4 and more: levels 2 and 3 (and 4, 5) of every channel
check "voxelize channel 3, 5 levels" "$VOX" voxelize --embedded -w 0 -q -o "$TMP/ch3.vod" \
    -e 'x*x + 2*y*y + z*z - 0.6' -r 70 --brick 8
check "voxelize channel 1, 6 levels" "$VOX" voxelize --embedded -w 0 -q -o "$TMP/ch1.vod" \
    -e '(sqrt(x*x+y*y)-0.6)^2+z*z-0.09' -r 70 --brick 4 --channel occupancy --compress runl
cat >"$TMP/tet.obj" <<'OBJ'
v -0.9 -0.8 -0.7
v 0.95 -0.7 -0.8
v -0.1 0.9 -0.75
v 0.05 0.1 0.85
f 1 3 2
f 1 2 4
f 2 3 4
f 3 1 4
OBJ
check "voxelize channel 2 (a mesh's density), 4 levels" "$VOX" voxelize --embedded -w 0 -q \
    --mesh "$TMP/tet.obj" --channel density -r 60 --brick 8 -o "$TMP/ch2.vod"
for f in ch3 ch1 ch2; do
    mkdir -p "$TMP/$f"
    pycheck levels "$TMP/$f.vod" "$VOX" "$TMP/$f"
done

mkdir -p "$TMP/float"
pycheck float "$TMP/float" "$VOX"
