#!/bin/bash
# bench-mpi.sh [BUILD]: vox_mpi (docs/mpi.md) against vox voxelize, the whole
# command as a user times it (bench/voxwhole), on this machine with the
# ranks talking over TCP (mpirun --mca btl self,tcp --oversubscribe).  Per
# job: vox voxelize -w 2 and vox_mpi on 1 rank x 2 workers and 2 ranks x 1
# worker (the same 2 workers in all; --bind-to none: vox_mpi places each
# rank's workers on CPUs the host's other ranks do not use, as vox places
# its own), then vox voxelize -w 4 and vox_mpi on
# 1 x 4, 2 x 2 and 4 x 1 (4 workers, more than the cores here), each the
# median of REPEATS runs (and its largest process's peak resident memory,
# voxwhole's maxrss: for vox_mpi, rank 0 or another rank), the runs of one
# repeat one after the other so
# that a change in the machine's load falls on all of them; the time
# against vox voxelize with the same workers (the issue's target: 2 x 1 at
# most 1.3 x vox -w 2 at 2048^3), and what the ranks sent: bytes per rank,
# subtrees, the mean seconds and bytes of a subtree (docs/mpi.md's scaling
# model starts from them).  Every vox_mpi file is compared with vox's: a
# benchmark of a wrong file is no benchmark.  Markdown on stdout.
#
#   BENCH_QUICK=1        quick run for tests: RES 96, REPEATS 1
#   BENCH_MPI_RES        the resolutions (default "512 2048")
#   BENCH_REPEATS        timed runs per command (default 3; 1 at 2048^3 and up)
#   BENCH_MPI_CONFIGS    the commands, NAME:RANKS:WORKERS each (RANKS 0: vox
#                        voxelize -w WORKERS, named voxWORKERS; the first is the
#                        file every vox_mpi file is compared with)
set -euo pipefail
. "$(dirname "$0")/bench-lib.sh" # bench_root, medians
bench_root "${1:-}"
if [ "${BENCH_QUICK:-0}" = 1 ]; then dres=96 drep=1; else dres="512 2048" drep=""; fi
resolutions=${BENCH_MPI_RES:-$dres}
vox=$build/vox mpi=$build/vox_mpi whole=$build/voxwhole
for b in "$vox" "$mpi" "$whole"; do
    [ -x "$b" ] || { echo "bench-mpi: $b is missing (make $b)" >&2; exit 2; }
done
command -v mpirun >/dev/null || { echo "bench-mpi: no mpirun (make deps)" >&2; exit 2; }
[ "$(id -u)" -eq 0 ] && export OMPI_ALLOW_RUN_AS_ROOT=1 OMPI_ALLOW_RUN_AS_ROOT_CONFIRM=1
tmp=$(mktemp -d)
trap 'rm -rf "$tmp"' EXIT
export VOXD_SOCKET=$tmp/no-voxd.sock # no daemon answers there
failed=0
# the commands of a job: NAME R W (R 0: vox voxelize -w W, named voxW);
# BENCH_MPI_CONFIGS gives others, e.g. on 16 cores
# "vox16:0:16 m1x16:1:16 m2x8:2:8 m4x4:4:4 m8x2:8:2 m16x1:16:1"
configs=${BENCH_MPI_CONFIGS:-"vox2:0:2 m1x2:1:2 m2x1:2:1 vox4:0:4 m1x4:1:4 m2x2:2:2 m4x1:4:1"}
ref_name=${configs%%:*} # every vox_mpi file is compared with the first command's

# run SHAPE RES NAME R W: one timed run; the wall time on stdout, or ERROR
run() {
    local args=(voxelize -f "examples/$1.vx" -r "$2" -w "$5")
    if [ "$4" = 0 ]; then
        "$whole" -o "$tmp/m" -- "$vox" "${args[@]}" --embedded -o "$tmp/$3.vod" \
            >"$tmp/$3.out" 2>"$tmp/$3.err" || { echo ERROR; return; }
    else
        "$whole" -o "$tmp/m" -- mpirun --oversubscribe --bind-to none --mca btl self,tcp -np "$4" \
            "$mpi" "${args[@]}" --stats -o "$tmp/$3.vod" >"$tmp/$3.out" 2>"$tmp/$3.err" ||
            { echo ERROR; return; }
        local ref=$tmp/$ref_name.vod
        [ -f "$ref" ] && ! cmp -s "$ref" "$tmp/$3.vod" && { echo DIFFERENT; return; }
    fi
    sed -n 's/^wall_s=\([0-9.]*\).*/\1/p' "$tmp/m"
    sed -n 's/^wall_s=[0-9.]* maxrss_kib=\([0-9]*\).*/\1/p' "$tmp/m" >"$tmp/$3.rss"
}

fmt() { awk -v x="$1" 'BEGIN { printf "%.3f", x }'; }
mib() { awk -v k="$1" 'BEGIN { if (k != "") printf "%.0f", k / 1024 }'; }
ratio() { awk -v a="$1" -v b="$2" 'BEGIN { if (b > 0) printf "%.2f", a / b; else print "-" }'; }

job() {
    local shape=$1 res=$2 reps=${BENCH_REPEATS:-$drep} c name r w t
    [ -n "$reps" ] || { [ "$res" -ge 2048 ] && reps=1 || reps=3; }
    : >"$tmp/runs"
    for _ in $(seq "$reps"); do
        for c in $configs; do
            IFS=: read -r name r w <<<"$c"
            echo "bench-mpi: $shape $res^3 $name" >&2
            t=$(run "$shape" "$res" "$name" "$r" "$w")
            case $t in ERROR|DIFFERENT|'') echo "$name=-1" >>"$tmp/runs"; echo "$name $t" >>"$tmp/bad"; failed=1 ;;
            *) echo "$name=$t rss.$name=$(cat "$tmp/$name.rss")" >>"$tmp/runs" ;; esac
        done
    done
    medians <"$tmp/runs" >"$tmp/med"
    get() { awk -v k="$1" '$1 == k { print $2 }' "$tmp/med"; }
    echo
    echo "### $shape at $res^3 ($reps run$([ "$reps" -gt 1 ] && echo s), median; 1-minute load $(cut -d' ' -f1 /proc/loadavg) after)"
    echo
    echo "| command | workers in all | whole command (s) | against vox voxelize | largest process (MiB) | subtrees | sent to rank 0 (bytes, per rank) | mean subtree (s, bytes) |"
    echo "|---|---|---|---|---|---|---|---|"
    for c in $configs; do
        IFS=: read -r name r w <<<"$c"
        local base all sent sub per
        if [ "$r" = 0 ]; then
            all=$w base=$(get "vox$w")
            echo "| vox voxelize -w $w | $all | $(fmt "$base") | 1 | $(mib "$(get "rss.vox$w")") | | | |"
            continue
        fi
        all=$((r * w)) base=$(get "vox$all")
        if grep -q "^$name " "$tmp/bad" 2>/dev/null; then
            echo "| vox_mpi $r x $w | $all | $(grep "^$name " "$tmp/bad" | head -1 | cut -d' ' -f2) | | | | | |"
            continue
        fi
        sent=$(sed -n 's/^  sent to rank 0: \([0-9]*\) bytes (\(.*\)); .*/\1 (\2)/p' "$tmp/$name.out")
        sub=$(sed -n 's/.* (\([0-9]*\) subtrees of \([0-9]*\)^3 voxels).*/\1 of \2^3/p' "$tmp/$name.out")
        per=$(awk '/^ +[0-9]+  [^ ]+ +[0-9]+ /{ n += $3; s += $8; b += $7 }
                   END { if (n) printf "%.3f s, %.0f bytes", s / n, b / n }' "$tmp/$name.out")
        echo "| vox_mpi $r x $w | $all | $(fmt "$(get "$name")") | $(ratio "$(get "$name")" "$base") | $(mib "$(get "rss.$name")") | $sub | $sent | $per |"
    done
    rm -f "$tmp/bad"
}

echo "## vox_mpi against vox voxelize (whole command, ranks over TCP) on $(nproc) cores"
echo
echo "Rank 0 counts what its own slave thread sends it (over MPI's self transport)"
echo "with the other ranks' bytes; the files are compared with vox voxelize's."
for res in $resolutions; do
    for shape in sphere scene1; do job "$shape" "$res"; done
done
exit "$failed"
