#!/bin/bash
# bench-iso.sh [BUILD]: vox mesh (marching cubes per brick, docs/
# mesh-extraction.md) in the layout of the Isovox thesis's Tables 6 to 9,
# run by `make bench`.  Markdown on stdout.  Two volumes are made here:
#
#   scene1   Scene 1 of the paper voxelized by vox voxelize (channel 3, the
#            surface's shell of voxels) at BENCH_RES (default 512)
#   solid    the same Scene 1 as a solid of density (channel 2): its level-1
#            mesh voxelized by vox voxelize --mesh --channel density
#
#  Table 6: the polygonization's seconds (mean and standard deviation over
#           BENCH_REPEATS runs) serially (-w 0) and with 1..BENCH_WORKERS
#           workers, and the speed-up over 1 worker; the target: Scene 1 at
#           512^3 in 0.5 s with 2 workers, and the yield t1 / (2 t2) >= 85%;
#  Table 7: the speed-up per mip level and worker count, over level 0 with
#           1 worker;
#  Table 8: the triangles of each mip level and of adaptive levels, with
#           the reduction against level 0: centred on a corner of the box
#           (the thesis's Figure 29: level 0 near the corner), radii a
#           quarter and a half of its side; and centred on Scene 1's middle
#           sphere, radii 0.3 and 0.6;
#  Table 9: their speed-up over level 0 (all workers);
#  VTK:     VTK's vtkFlyingEdges3D (its fastest marching cubes) on the same
#           level-0 samples at the same iso value (scripts/bench-iso-vtk.py),
#           its Update() timed with 1 and BENCH_WORKERS threads beside vox
#           mesh's polygonization with as many workers, the triangles of
#           both and the ratio of the times.  VTK comes from Debian's
#           python3-vtk9, installed here with apt-get when missing (not a
#           build or test dependency); without it the table is one line
#           saying why it is skipped.
#
# "polygonization" is the job itself: copying the level's bricks into shared
# memory, the marching cubes and the weld (vox mesh's summary, second line);
# the whole command (reading and checking the file, starting the workers,
# writing the PLY) is given beside it.  The machine may be shared: the load
# average before each table is printed with it.
#
#   BENCH_QUICK=1   a quick run for tests: 64^3, one repeat, levels 0..1;
#                   VTK only if it is installed already
#   BENCH_VTK=0     no VTK comparison (a machine where it cannot run)
#   BENCH_REPEATS   runs per cell (default 5; quick 1)
set -euo pipefail
root=$(cd "$(dirname "$0")/.." && pwd)
build=${1:-build/release}
case $build in /*) ;; *) build=$root/$build ;; esac
vox=$build/vox
quick=${BENCH_QUICK:-0}
res=${BENCH_RES:-512}
repeats=${BENCH_REPEATS:-5}
maxw=${BENCH_WORKERS:-$(nproc)}
levels="0 1 2 3"
if [ "$quick" = 1 ]; then res=64; repeats=1; levels="0 1"; fi
tmp=$(mktemp -d)
trap 'rm -rf "$tmp"' EXIT
export VOXD_SOCKET=$tmp/no-daemon.sock

load() { cut -d' ' -f1 /proc/loadavg; }
div() { awk -v a="$1" -v b="$2" 'BEGIN { printf "%.2f", (b > 0 ? a / b : 0) }'; }

# run VOD ARGS...: one vox mesh; prints "poly=S whole=S tri=N cpu=S" from its
# summary (cpu: the master's and the workers' CPU seconds in the job; -w 0: 0)
run() {
    local vod=$1 t0 t1
    shift
    t0=$(date +%s.%N)
    "$vox" mesh "$vod" -o "$tmp/out.ply" "$@" >"$tmp/sum" 2>&1 || {
        echo "bench-iso: vox mesh $vod $* failed: $(cat "$tmp/sum")" >&2; return 1; }
    t1=$(date +%s.%N)
    awk -v whole="$(awk -v a="$t1" -v b="$t0" 'BEGIN { print a - b }')" '
        NR == 1 { tri = $2 }
        /bricks and tasks/ { for (i = 1; i <= NF; i++) if ($i ~ /^[0-9.]+$/) s[++n] = $i }
        /CPU: master/ { cpu = $3 + $6 }
        END { printf "poly=%.4f whole=%.4f tri=%d cpu=%.4f\n", s[2] + s[3] + s[4], whole, tri, cpu }' "$tmp/sum"
}

# stats VOD ARGS...: BENCH_REPEATS runs; "mean sd whole tri cpu" of the polygonization
stats() {
    local i
    for ((i = 0; i < repeats; i++)); do run "$@"; done | awk '
        { for (k = 1; k <= NF; k++) { split($k, kv, "="); v[kv[1], NR] = kv[2] } }
        END {
            for (i = 1; i <= NR; i++) { m += v["poly", i]; w += v["whole", i]; c += v["cpu", i] }
            m /= NR; w /= NR; c /= NR
            for (i = 1; i <= NR; i++) sd += (v["poly", i] - m) ^ 2
            sd = NR > 1 ? sqrt(sd / (NR - 1)) : 0
            printf "%.4f %.4f %.4f %d %.4f\n", m, sd, w, v["tri", 1], c
        }'
}

# ---------------------------------------------------------------- volumes
"$vox" voxelize --embedded -f "$root/examples/scene1.vx" -r "$res" -o "$tmp/scene1.vod" -q
"$vox" mesh "$tmp/scene1.vod" -o "$tmp/scene1-l1.ply" --level 1 -q
"$vox" voxelize --embedded --mesh "$tmp/scene1-l1.ply" --channel density -r "$res" \
    -o "$tmp/solid.vod" -q
sets="scene1 solid"

echo "## Marching cubes (vox mesh): the thesis's Tables 6-9"
echo
echo "$(nproc) cores: $(grep -m1 'model name' /proc/cpuinfo | cut -d: -f2 | sed 's/^ //'); "\
"volumes at ${res}^3; $repeats runs per cell; seconds are the polygonization's (vox mesh's"\
" bricks, marching cubes and weld), the whole command's in its own column."
echo

# ---------------------------------------------------------------- Table 6
echo "### Table 6: sequential and parallel polygonization, level 0 (load $(load))"
echo
echo "| volume | workers | mean (s) | sd (s) | speed-up | CPU, all processes (s) | whole command (s) | triangles |"
echo "|---|---|---|---|---|---|---|---|"
declare -A t1 tw triw cpuw
for s in $sets; do
    for w in 0 $(seq 1 "$maxw"); do
        read -r m sd whole tri cpu < <(stats "$tmp/$s.vod" -w "$w")
        [ "$w" = 1 ] && t1[$s]=$m
        tw[$s,$w]=$m triw[$s,$w]=$tri cpuw[$s,$w]=$cpu
        sp=$( [ "$w" -ge 1 ] && div "${t1[$s]}" "$m" || echo "-")
        echo "| $s | $( [ "$w" = 0 ] && echo "0 (in-process)" || echo "$w") | $m | $sd | $sp | $( [ "$w" = 0 ] && echo "-" || echo "$cpu") | $whole | $tri |"
        [ "$s" = scene1 ] && [ "$w" = "$maxw" ] && t2=$m
    done
done
echo
# the targets: judged at 512^3 with 2 workers only
yield=$(div "${t1[scene1]}" "$(awk -v w="$maxw" -v t="$t2" 'BEGIN { print w * t }')")
verdict() { awk -v v="$1" -v lim="$2" -v le="$3" -v judged="$4" 'BEGIN {
    if (!judged) print "not judged: not 512^3 with 2 workers"
    else print ((le ? v <= lim : v >= lim) ? "met" : "MISSED") }'; }
judged=$( [ "$res" = 512 ] && [ "$maxw" = 2 ] && echo 1 || echo 0)
echo "Targets: Scene 1 at 512^3 in <= 0.5 s with 2 workers: ${t2} s at ${res}^3 with $maxw"\
     "($(verdict "$t2" 0.5 1 "$judged")); yield t1 / ($maxw t$maxw) = $yield"\
     "($(verdict "$yield" 0.85 0 "$judged"), against 0.85)."
echo

# ---------------------------------------------------------------- Table 7
echo "### Table 7: speed-up per mip level, over level 0 with 1 worker (load $(load))"
echo
printf "| volume | level |"; for w in $(seq 1 "$maxw"); do printf " %s worker(s) |" "$w"; done; echo
printf "|---|---|"; for w in $(seq 1 "$maxw"); do printf "%s" "---|"; done; echo
declare -A tri_l sec_l
for s in $sets; do
    for l in $levels; do
        printf "| %s | %s |" "$s" "$l"
        for w in $(seq 1 "$maxw"); do
            read -r m sd whole tri cpu < <(stats "$tmp/$s.vod" -w "$w" --level "$l")
            printf " %s |" "$(div "${t1[$s]}" "$m")"
            tri_l[$s,$l]=$tri
            sec_l[$s,$l]=$m
        done
        echo
    done
done
echo

# ---------------------------------------------------------------- Tables 8, 9
# adaptive runs: "centre radii" (Scene 1's box is [-1, 1]^3)
lods=("-1,-1,-1 0.5,1" "0,0,0 0.3,0.6")
echo "### Table 8: triangles of uniform and adaptive levels; Table 9: speed-up over level 0 ($maxw workers, load $(load))"
echo
echo "Adaptive: --lod-center C --lod-radii R0,R1 (level 0 within R0 of C, 1 within R1, 2 beyond)."
echo
echo "| volume | levels | triangles | reduction (%) | seconds | speed-up |"
echo "|---|---|---|---|---|---|"
for s in $sets; do
    base=${tri_l[$s,0]}
    for l in $levels; do
        red=$(div "$((100 * (base - tri_l[$s,$l])))" "$base")
        echo "| $s | mip $l | ${tri_l[$s,$l]} | $red | ${sec_l[$s,$l]} | $(div "${sec_l[$s,0]}" "${sec_l[$s,$l]}") |"
    done
    for lod in "${lods[@]}"; do
        read -r c r <<<"$lod"
        read -r m sd whole tri cpu < <(stats "$tmp/$s.vod" -w "$maxw" --lod-center "$c" --lod-radii "$r")
        red=$(div "$((100 * (base - tri)))" "$base")
        echo "| $s | adaptive $c $r | $tri | $red | $m | $(div "${sec_l[$s,0]}" "$m") |"
    done
done
echo
echo "(The adaptive mesh keeps each level's region closed with caps, which count in its"\
" triangles: docs/mesh-extraction.md.)"

echo

# ---------------------------------------------------------------- VTK
# vtk_python: prints a python3 that imports VTK and numpy, installing
# python3-vtk9 when it is missing and apt-get can (not in quick mode); else
# prints nothing and says why in $tmp/vtk-why.
vtk_python() {
    local py sudo=""
    has_vtk() { command -v "$1" >/dev/null && "$1" -c 'import numpy, vtkmodules.vtkFiltersCore' 2>/dev/null; }
    if [ "${BENCH_VTK:-1}" = 0 ]; then echo "BENCH_VTK=0" >"$tmp/vtk-why"; return; fi
    for py in python3 /usr/bin/python3; do has_vtk "$py" && { echo "$py"; return; }; done
    if [ "$quick" = 1 ]; then echo "not installed, and a quick run installs nothing" >"$tmp/vtk-why"; return; fi
    command -v apt-get >/dev/null || { echo "python3-vtk9 is missing and there is no apt-get" >"$tmp/vtk-why"; return; }
    if [ "$(id -u)" != 0 ]; then
        sudo -n true 2>/dev/null || { echo "python3-vtk9 is missing; installing it needs root (or sudo without a password)" >"$tmp/vtk-why"; return; }
        sudo="sudo -n"
    fi
    echo "bench-iso: installing python3-vtk9 (apt-get) for the VTK comparison" >&2
    if ! DEBIAN_FRONTEND=noninteractive $sudo apt-get install -y --no-install-recommends python3-vtk9 >"$tmp/apt.log" 2>&1; then
        $sudo apt-get update >>"$tmp/apt.log" 2>&1 || true
        DEBIAN_FRONTEND=noninteractive $sudo apt-get install -y --no-install-recommends python3-vtk9 >>"$tmp/apt.log" 2>&1 ||
            { echo "apt-get install python3-vtk9 failed: $(tail -1 "$tmp/apt.log")" >"$tmp/vtk-why"; return; }
    fi
    has_vtk /usr/bin/python3 && { echo /usr/bin/python3; return; }
    echo "python3-vtk9 installed, but /usr/bin/python3 cannot import vtkmodules and numpy" >"$tmp/vtk-why"
}

echo "### VTK's vtkFlyingEdges3D beside vox mesh, level 0 (load $(load))"
echo
py=$(vtk_python)
if [ -z "$py" ]; then
    echo "VTK comparison skipped: $(cat "$tmp/vtk-why")."
    exit 0
fi
threads="1 $( [ "$maxw" -gt 1 ] && echo "$maxw")"
echo "VTK $("$py" -c 'from vtkmodules.vtkCommonCore import vtkVersion as v; print(v.GetVTKVersion())')"\
" through $py; the same level-0 samples (the Python reader's, padded by one empty layer as"\
" vox mesh pads them), contour value iso + 0.5 = 127.5 (vox mesh's vertex rule), normals,"\
" gradients and scalars off; VTK's Update() alone against vox mesh's polygonization"\
" (Table 6) with as many workers, in wall seconds and in CPU seconds of all threads and"\
" processes (which a shared machine's load disturbs less); $repeats runs per cell."
echo
echo "| volume | threads | vox mesh (s) | VTK Update() (s) | VTK sd (s) | vox mesh / VTK | vox mesh CPU (s) | VTK CPU (s) | vox mesh triangles | VTK triangles | VTK vertices | VTK's SMP backend |"
echo "|---|---|---|---|---|---|---|---|---|---|---|---|"
for s in $sets; do
    # shellcheck disable=SC2086 # threads: one or two numbers
    PYTHONPATH="$root/python" "$py" "$root/scripts/bench-iso-vtk.py" "$tmp/$s.vod" 127 "$repeats" $threads \
        >"$tmp/vtk.out" 2>"$tmp/vtk.err" || {
        echo "bench-iso: VTK on $s failed: $(tail -3 "$tmp/vtk.err")" >&2; exit 1; }
    while read -r line; do
        declare -A kv=()
        for f in $line; do kv[${f%%=*}]=${f#*=}; done
        [ -n "${kv[threads]:-}" ] || continue
        w=${kv[threads]}
        echo "| $s | $w | ${tw[$s,$w]} | ${kv[mean]} | ${kv[sd]} | $(div "${tw[$s,$w]}" "${kv[mean]}") |"\
             "${cpuw[$s,$w]} | ${kv[cpu]} | ${triw[$s,$w]} | ${kv[triangles]} | ${kv[vertices]} | ${kv[backend]} |"
    done <"$tmp/vtk.out"
done
echo
echo "(VTK's input is the dense array, $(awk -v r="$res" 'BEGIN { printf "%.1f", (r + 2) ^ 3 / 1048576 }')"\
" MiB of bytes at ${res}^3, made once from the file and not timed; vox mesh's seconds include"\
" copying the level's bricks into shared memory and the weld.)"
