#!/bin/bash
# The CSG benchmark (scripts/bench-csg.sh) in its quick mode, so that it
# cannot rot: both tables have every row and a number in every column, the
# per-brick compression makes every set smaller than without it, and the
# second table's figures agree with each other.  No timing is asserted (the
# machine is shared).
. "$(dirname "$0")/lib.sh"
REL=build/release # the benchmark's build; make test builds it beside asan
mk() { env -u MAKEFLAGS -u MFLAGS -u MAKELEVEL make --no-print-directory -C "$ROOT" "$@"; }
check "vox and voxwhole build" mk V=release "$REL/vox" "$REL/voxwhole"
check "bench-csg.sh runs (quick)" env BENCH_QUICK=1 scripts/bench-csg.sh "$REL"
cp "$TMP/out" "$TMP/tables"
check "Tables 3 and 4: the five sets, each smaller compressed" awk -F'|' '
    /^\| (Small|Large|CSG)/ { n++; raw = $4 + 0; none = $5 + 0; zlib = $7 + 0
        if (raw > 0 && none > 0 && zlib > 0 && zlib < none && $6 ~ /: 1/ && $8 ~ /: 1/) ok++ }
    END { exit !(n == 5 && ok == 5) }' "$TMP/tables"
check "the scaling table: three trees at two sizes, every column filled" awk -F'|' '
    /^\| (10 primitives|the issue|a VOD leaf)/ { n++
        if ($5 + 0 > 0 && $6 + 0 > 0 && $7 + 0 >= $6 + 0 && $8 ~ /%/ && $9 ~ /%/ && $10 + 0 > 0) ok++ }
    END { exit !(n == 6 && ok == 6) }' "$TMP/tables"
