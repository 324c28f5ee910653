# Helpers for integration tests: each check prints "PASS: name" or
# "FAIL: name" (the runner counts them); a test never skips silently.
VOX=${VOX_ASAN:-${VOX:-build/asan/vox}}
ROOT=${VOXD_ROOT:-$(pwd)}
TMP=$(mktemp -d)
trap 'san_scan; rm -rf "$TMP"' EXIT
cd "$ROOT" || exit 1

# The sanitizers exit with 86, a code no program of ours uses (the runner
# sets the same), so that a report never passes for an expected exit status.
# A report in a check's output, or a report file new in $VOX_SAN_DIR (where
# the runner has ASan and LSan write them), fails the check.
SAN_EXIT=86
SAN_RE='ERROR: AddressSanitizer|ERROR: LeakSanitizer|runtime error:'
san_opt() { case ":$1:" in *:exitcode=*) echo "$1" ;; *) echo "${1:+$1:}exitcode=$SAN_EXIT" ;; esac; }
ASAN_OPTIONS=$(san_opt "${ASAN_OPTIONS:-detect_leaks=1}")
LSAN_OPTIONS=$(san_opt "${LSAN_OPTIONS:-suppressions=$ROOT/tests/lsan.supp:print_suppressions=0}")
UBSAN_OPTIONS=$(san_opt "${UBSAN_OPTIONS:-print_stacktrace=1:halt_on_error=1}")
export ASAN_OPTIONS LSAN_OPTIONS UBSAN_OPTIONS
san_files() { ls -A "${VOX_SAN_DIR:-/nonexistent}" 2>/dev/null | wc -l; }
# san_in FILE COUNT: 0 (and a line added to FILE) when FILE holds a
# sanitizer report or $VOX_SAN_DIR more report files than COUNT
san_in() {
    if grep -aEq "$SAN_RE" "$1"; then return 0; fi
    [ "$(san_files)" -gt "$2" ] || return 1
    echo "sanitizer report files in $VOX_SAN_DIR: $(ls -t "$VOX_SAN_DIR" | head -3)" >>"$1"
}
# san_scan: at the end, a FAIL for each file at the top of $TMP (daemon
# logs, captured outputs) that holds a sanitizer report
san_scan() {
    local f
    for f in $(grep -aElIs "$SAN_RE" "$TMP"/* "$TMP"/.[!.]* 2>/dev/null); do
        fail "no sanitizer report in ${f#"$TMP"/}" "$(grep -aE -m3 "$SAN_RE" "$f")"
    done
}

# python_with MODULE...: the first python3 (Debian's, with its python3-numpy
# and python3-vtk9, then the PATH's) that imports every MODULE; fails, with
# nothing printed, when none does.
python_with() {
    local p mods
    mods=$(IFS=,; echo "$*")
    for p in /usr/bin/python3 python3; do
        if command -v "$p" >/dev/null && "$p" -c "import $mods" 2>/dev/null; then
            echo "$p"
            return 0
        fi
    done
    return 1
}

# torus_obj NU NV [DROP]: an OBJ torus (R 0.6, r 0.25) of 2 NU NV triangles,
# closed and counter-clockwise seen from outside, on stdout; with DROP, every
# DROP-th triangle left out (an open mesh for the repairs).
torus_obj() {
    awk -v nu="$1" -v nv="$2" -v drop="${3:-0}" 'BEGIN {
        pi = atan2(0, -1); R = 0.6; r = 0.25
        for (i = 0; i < nu; i++) for (j = 0; j < nv; j++) {
            u = 2 * pi * i / nu; v = 2 * pi * j / nv
            printf "v %.6f %.6f %.6f\n", (R + r * cos(v)) * cos(u), (R + r * cos(v)) * sin(u), r * sin(v)
        }
        for (i = 0; i < nu; i++) for (j = 0; j < nv; j++) {
            a = i * nv + j + 1; b = ((i + 1) % nu) * nv + j + 1
            c = ((i + 1) % nu) * nv + (j + 1) % nv + 1; d = i * nv + (j + 1) % nv + 1
            if (!drop || ++k % drop) printf "f %d %d %d\n", a, b, c
            if (!drop || ++k % drop) printf "f %d %d %d\n", a, c, d
        } }'
}

# The distance tests' CSG trees (daemon_band.sh, csg_distance.sh, mpi.sh), on
# stdout.  balls_leaves: two overlapping balls, leaves a and b; two_balls_csg:
# their union.
balls_leaves() {
    printf '%s\n' 'a = implicit "sqrt((x+0.25)^2 + y^2 + z^2) - 0.5"' \
        'b = implicit "sqrt((x-0.22)^2 + (y-0.05)^2 + (z+0.03)^2) - 0.43"'
}
two_balls_csg() { balls_leaves; printf '%s\n' 'r = union(a, b)' 'result r'; }
# ico_csg OBJ: the icosphere OBJ (tests/golden/ico.obj) moved and scaled, less a
# cylinder along z: a mesh and an implicit leaf.
ico_csg() {
    printf '%s\n' "ico = mesh \"$1\" fit 0.1,0,0 scale 1.2" 'hole = implicit "sqrt(x^2 + y^2) - 0.2"' \
        'r = difference(ico, hole)' 'result r'
}

# oom_verdict RC ERR OUT: how a run that ran out of memory ended, on
# stdout: "whole" (status 0: the caller compares what it made), "refused"
# (status 1 to 3, a message in file ERR, no file OUT left; OUT - for a
# command that writes none), else what is wrong with it.
oom_verdict() {
    if [ "$1" = 0 ]; then echo whole
    elif [ "$1" -lt 1 ] || [ "$1" -gt 3 ]; then echo "status $1: $(head -c 200 "$2" | tr '\n' ' ')"
    elif [ ! -s "$2" ]; then echo "status $1, no message"
    elif [ "$3" != - ] && [ -e "$3" ]; then echo "a file left"
    else echo refused; fi
}

pass() { echo "PASS: $1"; }
fail() { echo "FAIL: $1"; [ -n "${2:-}" ] && printf '  %s\n' "$2"; }

# any_alive PID...: 0 while one of them runs (bash reaps its children, so
# an ended one is gone)
any_alive() {
    local p
    for p; do kill -0 "$p" 2>/dev/null && return 0; done
    return 1
}
# stop_all PID...: TERM (and CONT, for a stopped one) to each and to its
# children (a background subshell's `timeout` passes the TERM on to its
# client), 30 s for them all to end, then KILL.  A voxd stops on TERM and
# removes its shared-memory segment; KILL would leave it behind (a file
# of 2 GiB, sparse, in /dev/shm).
stop_all() {
    local p i
    for p; do
        pkill -TERM -P "$p" 2>/dev/null
        kill -TERM "$p" 2>/dev/null && kill -CONT "$p" 2>/dev/null
    done
    for i in $(seq 300); do any_alive "$@" || break; sleep 0.1; done
    for p; do kill -9 "$p" 2>/dev/null; done
    for p; do wait "$p" 2>/dev/null; done
}
# shm_left: once the daemons are stopped, the shared-memory segments they
# named in their logs (any file under $TMP): a FAIL naming those still in
# /dev/shm (then removed), a PASS when none is; nothing when no daemon ran
shm_left() {
    local names n left=
    names=$(grep -rahos 'shared memory /voxd-[0-9a-f]*' "$TMP" | sed 's/.* \///' | sort -u)
    [ -n "$names" ] || return 0
    for n in $names; do
        [ -e "/dev/shm/$n" ] && left="$left $n" && rm -f "/dev/shm/$n"
    done
    if [ -n "$left" ]; then
        fail "the daemons removed their shared memory" "left in /dev/shm:$left"
    else
        pass "the daemons removed their shared memory ($(echo $names | wc -w) segment(s))"
    fi
}
# check NAME COMMAND...: passes when the command succeeds with no sanitizer report
check() {
    local n=$1 s0; shift
    s0=$(san_files)
    if "$@" >"$TMP/out" 2>&1 && ! san_in "$TMP/out" "$s0"; then pass "$n"
    else fail "$n" "$(tail -5 "$TMP/out")"; fi
}
# refuse NAME CODE PATTERN COMMAND...: passes when the command exits with CODE
# and its output matches the extended regex PATTERN, with no sanitizer report
refuse() {
    local n=$1 code=$2 pat=$3 s0 rc; shift 3
    s0=$(san_files)
    "$@" >"$TMP/out" 2>&1; rc=$?
    if [ "$rc" -eq "$code" ] && grep -Eq -- "$pat" "$TMP/out" && ! san_in "$TMP/out" "$s0"; then pass "$n"
    else fail "$n" "exit $rc (want $code), output: $(head -3 "$TMP/out"; grep -aE -m2 "$SAN_RE|^sanitizer report" "$TMP/out")"; fi
}
