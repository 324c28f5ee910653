#!/bin/bash
# bench-whole.sh [BUILD]: the whole `vox voxelize` command as a user times
# it (issue 9), on the release build's embedded engine (--embedded, with
# VOXD_SOCKET naming no daemon).  Per job, in the same run: the engine's and
# the VOD writer's times (vox's summary line), the command's wall time
# (around the process), the write/engine ratio, the memory of the whole
# command, and the issue's targets with a pass/FAIL mark.  Then the VOD
# writer's stages (vox's "  VOD stages:" line, when the build prints one),
# the jobs at 0, 1 and 2 workers, and -w 1 against -w 0 for every standard
# shape.  Markdown on stdout.
#
#   BENCH_QUICK=1      a quick run for tests: defaults RES=64, REPEATS=1, BIG=0,
#                      SAMPLE_US=1000 (the jobs last tens of milliseconds)
#   BENCH_RES          the resolution of the standard jobs (default 512); the
#                      issue's targets are marked only at 512
#   BENCH_REPEATS      timed runs per job, the median is shown (default 3)
#   BENCH_BIG          1: also sphere and Scene 1 at 2048^3 and the sphere at
#                      4096^3 (default 1 at RES >= 512 unless quick; the 4096^3
#                      job runs for tens of seconds)
#   BENCH_SAMPLE_US    the memory run's sampling period in microseconds
#                      (default 5000)
#
# Each job runs REPEATS times under bench/voxwhole without sampling (timed),
# then once more sampled every BENCH_SAMPLE_US for the memory, untimed:
# sampling /proc costs CPU that the 2 workers would feel.  Exits 1 when a
# job failed (its row says why).
set -euo pipefail
. "$(dirname "$0")/bench-lib.sh" # bench_root, bench_start, medians
bench_root "${1:-}"
if [ "${BENCH_QUICK:-0}" = 1 ]; then dres=64 drep=1 dus=1000; else dres=512 drep=3 dus=5000; fi
res=${BENCH_RES:-$dres}
repeats=${BENCH_REPEATS:-$drep}
if [ "${BENCH_QUICK:-0}" != 1 ] && [ "$res" -ge 512 ]; then dbig=1; else dbig=0; fi
big=${BENCH_BIG:-$dbig}
sample_us=${BENCH_SAMPLE_US:-$dus}
shm_mib=2048 # what vox voxelize asks /dev/shm for (its --shm-size default)
vox=$build/vox whole=$build/voxwhole
bench_start bench-whole "$vox" "$whole"
shapes="sphere union64 blend2 scene1 scene2 scene3"
failed=0

# one SHAPE RES WORKERS PERIOD: one run of the job; vox's output in
# $tmp/stdout and $tmp/stderr, voxwhole's line in $tmp/m.
one() {
    "$whole" -s "$4" -o "$tmp/m" -- "$vox" voxelize -f "examples/$1.vx" -r "$2" -w "$3" \
        --embedded -o "$tmp/out.vod" >"$tmp/stdout" 2>"$tmp/stderr"
}

# kv: the last run as one line of key=value: engine and write (s) from the
# summary's first line, each VOD stage as st.NAME, wall (s) and maxrss (KiB)
# from voxwhole.
kv() {
    local first stages
    first=$(head -1 "$tmp/stdout")
    stages=$(sed -n 's/^  VOD stages: *//p' "$tmp/stdout" | head -1)
    sed -n 's/.* in \([0-9.]*\) s (.*VOD written in \([0-9.]*\) s.*/engine=\1 write=\2/p' <<<"$first"
    { grep -oE '[A-Za-z_-]+ [0-9]+(\.[0-9]+)? s' <<<"$stages" || true; } | awk '{printf " st.%s=%s", $1, $2}'
    sed 's/^wall_s=\([0-9.]*\) maxrss_kib=\([0-9]*\).*/ wall=\1 maxrss=\2/' "$tmp/m"
}


# run_once SHAPE RES WORKERS: one timed run of the job, appended to
# $tmp/job.SHAPE.RES.WORKERS.runs as a line of key=value; returns 1, the
# job's file holding an "error MESSAGE" line, when vox failed.
run_once() {
    local f="$tmp/job.$1.$2.$3"
    if ! one "$1" "$2" "$3" 0; then
        echo "error vox failed: $(head -1 "$tmp/stderr")" >"$f"; failed=1; return 1
    fi
    kv | tr -d '\n' >>"$f.runs"; echo >>"$f.runs"
    if ! tail -1 "$f.runs" | grep -q 'engine=.*write=.*wall='; then
        echo "error cannot read vox's summary: $(head -1 "$tmp/stdout")" >"$f"; failed=1; return 1
    fi
}

# finish SHAPE RES WORKERS: the medians of the timed runs into the job's
# file as "key value" lines, then one run sampled for the memory (untimed).
finish() {
    local f="$tmp/job.$1.$2.$3"
    medians <"$f.runs" >"$f"
    if ! one "$1" "$2" "$3" "$sample_us"; then
        echo "error vox failed (memory run): $(head -1 "$tmp/stderr")" >"$f"; failed=1; return 0
    fi
    sed 's/.*tree_peak_kib=\([0-9]*\) shm_peak_kib=\([0-9]*\) shm_exact=\([01]\).*/tree \1\nshm \2\nexact \3/' \
        "$tmp/m" >>"$f"
}

# measure SHAPE RES WORKERS: REPEATS timed runs and one sampled run, once
# per job; leaves "key value" lines in $tmp/job.SHAPE.RES.WORKERS, or an
# "error MESSAGE" line when vox failed.
measure() {
    local f="$tmp/job.$1.$2.$3"
    [ -e "$f" ] && return 0
    echo "bench-whole: $1 $2^3 -w $3" >&2
    : >"$f.runs"
    for _ in $(seq "$repeats"); do run_once "$1" "$2" "$3" || return 0; done
    finish "$1" "$2" "$3"
}

# measure_pair SHAPE RES: the job at -w 0 and -w 1 alternating, run by
# run, so that the machine's changes of speed (this one's come and go
# within seconds) fall on both alike; each pair's -w 1 / -w 0 engine time
# into $tmp/pairs.SHAPE.RES, one a line.
measure_pair() {
    local p="$tmp/pairs.$1.$2" e0 e1
    echo "bench-whole: $1 $2^3 -w 0 and -w 1, alternating" >&2
    : >"$tmp/job.$1.$2.0.runs"; : >"$tmp/job.$1.$2.1.runs"; : >"$p"
    for _ in $(seq "$repeats"); do
        run_once "$1" "$2" 0 && run_once "$1" "$2" 1 || return 0
        e0=$(tail -1 "$tmp/job.$1.$2.0.runs" | sed 's/.*engine=\([0-9.]*\).*/\1/')
        e1=$(tail -1 "$tmp/job.$1.$2.1.runs" | sed 's/.*engine=\([0-9.]*\).*/\1/')
        awk -v a="$e1" -v b="$e0" 'BEGIN { if (b > 0) printf "%.4f\n", a / b }' >>"$p"
    done
    finish "$1" "$2" 0; finish "$1" "$2" 1
}

# get KEY SHAPE RES WORKERS: one value of a measured job (empty if none).
get() { awk -v k="$1" '$1 == k { print $2 }' "$tmp/job.$2.$3.$4"; }
err() { sed -n 's/^error //p' "$tmp/job.$1.$2.$3"; }
label() { echo "$1 $2^3"; }
fmt() { awk -v x="$1" -v f="$2" 'BEGIN { printf f, x }'; }
mib() { awk -v k="$1" 'BEGIN { printf "%.1f", k / 1024 }'; }
ratio() { awk -v a="$1" -v b="$2" 'BEGIN { if (b > 0) printf "%.2f", a / b; else print "inf" }'; }
mark() { awk -v x="$1" -v t="$2" 'BEGIN { print (x <= t) ? "pass" : "FAIL" }'; }

# The issue's targets for a job (2 workers): write/engine, whole command (s),
# whole-command memory (MiB); empty where the issue gives none.
t_ratio() {
    [ "$3" = 2 ] || return 0
    case "$1.$2" in
    sphere.512 | union64.512 | blend2.512 | scene[123].512 | sphere.2048 | scene1.2048) echo 0.5 ;;
    esac
}
t_wall() {
    [ "$3" = 2 ] || return 0
    case "$1.$2" in
    sphere.512) echo 0.15 ;; union64.512) echo 0.5 ;;
    sphere.2048) echo 2.0 ;; sphere.4096) echo 8 ;;
    esac
}
t_mem() { [ "$3" = 2 ] && [ "$1.$2" = sphere.4096 ] && echo 2048 || true; }

targets() {
    local tr tw tm out=""
    tr=$(t_ratio "$@") tw=$(t_wall "$@") tm=$(t_mem "$@")
    [ -n "$tr" ] && out="write <= ${tr}x engine: $(mark "$(ratio "$(get write "$@")" "$(get engine "$@")")" "$tr")"
    [ -n "$tw" ] && out="${out:+$out; }whole <= $tw s: $(mark "$(get wall "$@")" "$tw")"
    [ -n "$tm" ] && out="${out:+$out; }memory <= $tm MiB: $(mark "$(mib "$(get tree "$@")")" "$tm")"
    echo "${out:--}"
}

# row SHAPE RES WORKERS [TARGETS]: one row of the whole-command tables.
row() {
    local e
    e=$(err "$@")
    if [ -n "$e" ]; then printf '| %s | %s | %s | | | | | | | |%s\n' "$(label "$1" "$2")" "$3" "$e" "${4:+ |}"; return; fi
    printf '| %s | %s | %s | %s | %s | %s | %s | %s | %s |' "$(label "$1" "$2")" "$3" \
        "$(fmt "$(get engine "$@")" %.3f)" "$(fmt "$(get write "$@")" %.3f)" \
        "$(fmt "$(get wall "$@")" %.3f)" "$(ratio "$(get write "$@")" "$(get engine "$@")")" \
        "$(mib "$(get maxrss "$@")")" "$(mib "$(get tree "$@")")" "$(mib "$(get shm "$@")")"
    [ -n "${4:-}" ] && printf ' %s |' "$(targets "$@")"
    echo
}

# The jobs of the first table: "SHAPE RES" at 2 workers.
main_jobs=$(for s in $shapes; do echo "$s $res"; done)
big_jobs=$'sphere 2048\nscene1 2048\nsphere 4096'
shm_free=$(( $(df -Pk /dev/shm | awk 'NR == 2 { print $4 }') / 1024 ))
measured=""
while read -r s r; do measure "$s" "$r" 2; measured+="$s $r 2"$'\n'; done <<<"$main_jobs"
if [ "$big" = 1 ] && [ "$shm_free" -ge "$shm_mib" ]; then
    while read -r s r; do measure "$s" "$r" 2; measured+="$s $r 2"$'\n'; done <<<"$big_jobs"
fi
for s in $shapes; do
    measure_pair "$s" "$res"
    for w in 0 1; do measured+="$s $res $w"$'\n'; done
done

cpu=$(grep -m1 'model name' /proc/cpuinfo | cut -d: -f2 | sed 's/^ //')
rev=$(git -C "$root" rev-parse --short HEAD 2>/dev/null || echo unknown)
echo "### Whole \`vox voxelize\` command ($(nproc) cores: $cpu; $(date +%F), $rev)"
echo
echo "Release build, embedded engine (\`--embedded\`, no daemon), 2 workers; median of"
echo "$repeats timed run(s). engine and VOD write: vox's summary line; whole command: the"
echo "process's wall time. Largest process: the peak RSS of the largest single process"
echo "(wait4's ru_maxrss; it includes the shared pages that process touched). Whole command:"
echo "the peak, sampled every $sample_us us in one more (untimed) run, of the resident"
echo "memory of vox and its workers together: their private pages plus the engine's shared segment counted once$(
    [ "$(get exact sphere "$res" 2)" = 1 ] || echo " (here only as its largest mapping in one process, a lower bound: /proc/PID/map_files was not readable)")."
echo
echo "| job | workers | engine (s) | VOD write (s) | whole command (s) | write / engine | largest process (MiB) | whole command memory (MiB) | of it, shared segment (MiB) | targets |"
echo "|---|---:|---:|---:|---:|---:|---:|---:|---:|---|"
while read -r s r; do row "$s" "$r" 2 t; done <<<"$main_jobs"
while read -r s r; do
    if [ "$big" != 1 ]; then
        printf '| %s | 2 | skipped (BENCH_BIG=0) | | | | | | | | |\n' "$(label "$s" "$r")"
    elif [ "$shm_free" -lt "$shm_mib" ]; then
        printf '| %s | 2 | skipped: /dev/shm has %s MiB free, vox asks for %s | | | | | | | | |\n' \
            "$(label "$s" "$r")" "$shm_free" "$shm_mib"
    else row "$s" "$r" 2 t; fi
done <<<"$big_jobs"
[ "$res" = 512 ] || { echo; echo "The issue's targets are for 512^3 and up: not marked at $res^3."; }

echo
echo "### VOD writer stages (s, median of $repeats)"
echo
stage_names=""
while read -r s r w; do
    [ -n "$s" ] && [ -z "$(err "$s" "$r" "$w")" ] || continue
    for k in $(awk '$1 ~ /^st\./ { print substr($1, 4) }' "$tmp/job.$s.$r.$w"); do
        case " $stage_names " in *" $k "*) ;; *) stage_names+="${stage_names:+ }$k" ;; esac
    done
done <<<"$measured"
if [ -z "$stage_names" ]; then
    echo "| job | workers | fill | hash | compress | assemble | write | VOD write |"
    echo "|---|---:|---:|---:|---:|---:|---:|---:|"
    echo
    echo "This build prints no \"  VOD stages:\" line: it has no stage profile, so no figures."
else
    printf '| job | workers |'; for k in $stage_names; do printf ' %s |' "$k"; done; echo ' VOD write |'
    printf '|---|---:|'; for _ in $stage_names; do printf -- '---:|'; done; echo '---:|'
    while read -r s r w; do
        [ -n "$s" ] && [ -z "$(err "$s" "$r" "$w")" ] || continue
        printf '| %s | %s |' "$(label "$s" "$r")" "$w"
        for k in $stage_names; do
            v=$(get "st.$k" "$s" "$r" "$w")
            printf ' %s |' "$([ -n "$v" ] && fmt "$v" %.3f || echo -)"
        done
        printf ' %s |\n' "$(fmt "$(get write "$s" "$r" "$w")" %.3f)"
    done <<<"$measured"
fi

echo
echo "### Workers: 0 (serial, in vox), 1 and 2 ($res^3, median of $repeats)"
echo
echo "| job | workers | engine (s) | VOD write (s) | whole command (s) | write / engine | largest process (MiB) | whole command memory (MiB) | of it, shared segment (MiB) |"
echo "|---|---:|---:|---:|---:|---:|---:|---:|---:|"
for s in sphere union64 blend2; do for w in 0 1 2; do row "$s" "$res" "$w"; done; done

echo
echo "### -w 1 against -w 0 (engine time, $res^3, median of $repeats)"
echo
echo "The runs alternate, -w 0 then -w 1; *-w 1 / -w 0* is the median of each pair's ratio"
echo "(the engine columns are each job's median, so their ratio may differ a little)."
echo
echo "| shape | -w 0 engine (s) | -w 1 engine (s) | -w 1 / -w 0 | target | -w 0 whole (s) | -w 1 whole (s) |"
echo "|---|---:|---:|---:|---|---:|---:|"
for s in $shapes; do
    e=$(err "$s" "$res" 0)$(err "$s" "$res" 1)
    if [ -n "$e" ]; then echo "| $s | $e | | | | | |"; continue; fi
    e0=$(get engine "$s" "$res" 0) e1=$(get engine "$s" "$res" 1)
    q=$(sed 's/^/r=/' "$tmp/pairs.$s.$res" | medians | awk '{ printf "%.2f", $2 }')
    t=-; [ "$res" = 512 ] && t="<= 1.10: $(mark "$q" 1.10)"
    printf '| %s | %.3f | %.3f | %s | %s | %.3f | %.3f |\n' "$s" "$e0" "$e1" "$q" "$t" \
        "$(get wall "$s" "$res" 0)" "$(get wall "$s" "$res" 1)"
done
exit "$failed"
