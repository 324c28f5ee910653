#!/bin/bash
# make bench: every benchmark table, printed and saved in bench/results/.
# BENCH_RES (default 512) and BENCH_WORKERS (default: cores) adjust the runs;
# the whole-command tables (scripts/bench-whole.sh) take BENCH_RES,
# BENCH_REPEATS, BENCH_BIG and BENCH_QUICK; the mesh tables
# (scripts/bench-mesh.sh) the last three; vox_mpi against vox voxelize
# (scripts/bench-mpi.sh) BENCH_MPI_RES, BENCH_REPEATS and BENCH_QUICK; the CSG
# tables (scripts/bench-csg.sh) BENCH_REPEATS and BENCH_QUICK; the export
# table (scripts/bench-export.sh) BENCH_EXPORT_RES and BENCH_REPEATS; every
# kind of job from 1 to N workers (scripts/bench-scale.sh) BENCH_SCALE_WORKERS
# and BENCH_SCALE_RES; the serial shares (scripts/bench-serial.sh)
# BENCH_SERIAL_RES, BENCH_SERIAL_WORKERS and BENCH_REPEATS.
# Exits with the status of the first table that failed (1 when a job failed:
# its row says why), after saving the tables.
set -euo pipefail
build=${1:-build/release}
res=${BENCH_RES:-512}
workers=${BENCH_WORKERS:-$(nproc)}
mkdir -p bench/results
out=bench/results/bench-$(date +%Y%m%d-%H%M%S).md
{
    echo "# voxbench on $(nproc) cores: $(grep -m1 'model name' /proc/cpuinfo | cut -d: -f2 | sed 's/^ //')"
    echo; echo "### Expression evaluator (ns per evaluation)"; echo; echo '```'
    "$build/bench_expr"
    echo '```'
    "$build/voxbench" shapes -r "$res"
    "$build/voxbench" table1 -r "$res" -n "$workers"
    "$build/voxbench" brute -r 256,512,1024
    "$build/voxbench" vod -r "$res" -n "$workers"
    "$build/voxbench" memory -r "$res"
    "$build/voxbench" deflate -r "$res"
    "$build/voxdbench" all -r "$res" -n "$workers"
    # every table runs, a failed one's too; the first failure's status is the exit status
    for part in mesh distance iso whole mpi csg export scale serial; do
        echo
        "$(dirname "$0")/bench-$part.sh" "$build" || first_rc=${first_rc:-$?}
    done
    exit "${first_rc:-0}"
} | tee "$out" || rc=$?
echo "bench: tables saved in $out"
exit "${rc:-0}"
