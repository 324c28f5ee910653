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
check "bench-export: the voxel count is vox info's" grep -Eq '^A sphere .*, [1-9][0-9]* voxels set' "$B"
