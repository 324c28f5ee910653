#!/bin/bash
# make bench's export table (scripts/bench-export.sh) in its quick mode, so
# that it cannot rot: a row per input and output with a number in every
# column and no target (quick mode marks none), exit status 0.  No timing
# is asserted (the machine is shared).
. "$(dirname "$0")/lib.sh"
REL=build/release # the benchmark's build; make test builds it beside asan
mk() { env -u MAKEFLAGS -u MFLAGS -u MAKELEVEL make --no-print-directory -C "$ROOT" "$@"; }
check "voxwhole builds" mk V=release "$REL/voxwhole"
B=$TMP/bench.md
if BENCH_QUICK=1 scripts/bench-export.sh "$REL" >"$B" 2>&1; then pass "bench-export quick run exits 0"
else fail "bench-export quick run exits 0" "$(tail -5 "$B")"; fi
check "bench-export: the header names the solid" grep -q '^### vox export of a 96^3 solid' "$B"
for ch in occupancy density; do
    for out in '.nrrd --gzip' '.vdb' '.nrrd'; do
        row=$(grep -F "| $ch | $out |" "$B")
        if [[ $row =~ ^\|\ $ch\ \|\ [^|]+\|\ [0-9]+\.[0-9]{3}\ \|\ [0-9]+\.[0-9]{3}\ \|\ [0-9]+\ \|\ [0-9]+\.[0-9]\ \|\ [0-9.]+\ \|\ \ \|$ ]]; then
            pass "bench-export: $ch to $out has its figures"
        else fail "bench-export: $ch to $out has its figures" "row: '$row'"; fi
    done
done
# The voxel count the table states, against answers that are not vox
# info's: the same solid (bench-export's, at its quick 96^3) counted by the
# Python reader, and the sphere's volume in voxels, 4/3 pi (0.8 * 48)^3,
# within the shell of half a voxel diagonal around its surface.
# a python3 with numpy (Debian's; an earlier python3 on the PATH may lack it):
# without one, the count below fails with Python's message
PY=$(python_with numpy) || PY=python3
n=$(sed -n 's/^A sphere .*, \([0-9]*\) voxels set.*/\1/p' "$B")
printf 's = ellipsoid radius 0.8\nresult s\n' >"$TMP/solid.csg"
py=$("$VOX" csg "$TMP/solid.csg" -r 96 --channel occupancy -q -o "$TMP/o.vod" 2>&1 &&
    PYTHONPATH="$ROOT/python" "$PY" -c 'import sys, numpy, voxd
print(numpy.count_nonzero(voxd.read(sys.argv[1], 0).data))' "$TMP/o.vod" 2>&1)
if [ -n "$n" ] && [ "$n" = "$py" ] && "$PY" -c 'import math, sys
n, r, h = int(sys.argv[1]), 0.8 * 48, 3 ** 0.5 / 2
sys.exit(not 4 / 3 * math.pi * (r - h) ** 3 <= n <= 4 / 3 * math.pi * (r + h) ** 3)' "$n"; then
    pass "bench-export: the voxel count ($n) is the Python reader's and the sphere's"
else fail "bench-export: the voxel count is the Python reader's and the sphere's" "table: '$n', python: '$py'"; fi
