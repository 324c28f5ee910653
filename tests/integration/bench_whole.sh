#!/bin/bash
# make bench's whole-command tables (scripts/bench-whole.sh) in their quick
# mode, so that they cannot rot: every row has a number in every column,
# the header has the core count, the figures agree with each other; and
# bench/voxwhole, which measures them: the exit status, the process tree,
# shared memory counted once.  No timing is asserted (the machine is shared).
. "$(dirname "$0")/lib.sh"
REL=build/release # the benchmark's build; make test builds it beside asan
W=$REL/voxwhole
mk() { env -u MAKEFLAGS -u MFLAGS -u MAKELEVEL make --no-print-directory -C "$ROOT" "$@"; }
check "voxwhole builds" mk V=release "$W"

# ---------------------------------------------------------------- voxwhole
LINE='^wall_s=[0-9]+\.[0-9]{6} maxrss_kib=[0-9]+ tree_peak_kib=[0-9]+ shm_peak_kib=[0-9]+ shm_exact=[01] samples=[0-9]+ procs=[0-9]+$'
refuse "voxwhole: the command's exit status, one line" 3 "$LINE" "$W" -- sh -c 'exit 3'
refuse "voxwhole: a signal as 128 + its number" 143 "$LINE" "$W" -- sh -c 'kill -TERM $$'
refuse "voxwhole: a command that is not there" 127 "No such file" "$W" -- "$TMP/none"

# A parent and two children each touch all of one 64 MiB /dev/shm segment:
# the whole command's memory counts it once (a sum of RSS would be 3x).
cat >"$TMP/shm.py" <<'EOF'
import mmap, os, sys, time
size = 64 << 20
path = '/dev/shm/voxwhole-test-%d' % os.getpid()
fd = os.open(path, os.O_CREAT | os.O_RDWR | os.O_EXCL, 0o600)
os.ftruncate(fd, size)
m = mmap.mmap(fd, size)
os.close(fd)
os.unlink(path)
def touch():
    for i in range(0, size, 4096):
        m[i] = 1
kids = []
for _ in range(2):
    pid = os.fork()
    if pid == 0:
        touch()
        time.sleep(0.3)
        os._exit(0)
    kids.append(pid)
touch()
time.sleep(0.3)
for k in kids:
    os.waitpid(k, 0)
EOF
py=$(python3 -c 'import sys; print(sys.executable)') # not a pyenv shim
"$W" -s 5000 -o "$TMP/m" -- "$py" "$TMP/shm.py"
read -r tree shm procs samples < <(sed -n \
    's/.*tree_peak_kib=\([0-9]*\) shm_peak_kib=\([0-9]*\).*samples=\([0-9]*\) procs=\([0-9]*\)/\1 \2 \4 \3/p' "$TMP/m")
if [ "${shm:-0}" -ge 65536 ] && [ "$shm" -le 66560 ]; then pass "voxwhole: the 64 MiB segment, once"
else fail "voxwhole: the 64 MiB segment, once" "$(cat "$TMP/m")"; fi
if [ "${tree:-0}" -ge 65536 ] && [ "$tree" -lt 131072 ]; then pass "voxwhole: tree memory = private + segment once"
else fail "voxwhole: tree memory = private + segment once" "$(cat "$TMP/m")"; fi
if [ "${procs:-0}" -eq 3 ] && [ "${samples:-0}" -ge 10 ]; then pass "voxwhole: samples the 3 processes"
else fail "voxwhole: samples the 3 processes" "$(cat "$TMP/m")"; fi

# ---------------------------------------------------------------- bench-whole
B=$TMP/bench.md
if BENCH_QUICK=1 scripts/bench-whole.sh "$REL" >"$B" 2>"$TMP/bench.err"; then
    pass "bench-whole quick mode runs"
else fail "bench-whole quick mode runs" "$(tail -3 "$TMP/bench.err"; grep -m3 'failed' "$B")"; fi
# rows HEADING: the data rows of the table under the heading that starts so
rows() {
    awk -v h="### $1" 'index($0, h) == 1 { on = 1; n = 0; next }
        /^###/ { on = 0 } on && /^\|/ && ++n > 2' "$B"
}
# numeric FIELDS: fails on the first row of stdin where one of the fields
# (1-based, in the |-separated row) is not a number; prints the row.
numeric() {
    awk -F'|' -v f="$1" 'BEGIN { n = split(f, c, ",") }
        { for (i = 1; i <= n; i++) { v = $(c[i] + 1); gsub(/ /, "", v)
              if (v !~ /^[0-9]+(\.[0-9]+)?$/) { print "not a number in column " c[i] ": " $0; bad = 1; exit } } }
        END { exit bad }'
}

grep -q "^### Whole \`vox voxelize\` command ($(nproc) cores" "$B" \
    && pass "bench-whole: the core count in the header" \
    || fail "bench-whole: the core count in the header" "$(head -1 "$B")"
main=$(rows 'Whole `vox voxelize` command')
check "bench-whole: 6 measured rows, 3 big ones skipped" test "$(grep -vc skipped <<<"$main")-$(grep -c 'skipped (BENCH_BIG=0)' <<<"$main")" = 6-3
check "bench-whole: every column of every measured row" numeric 2,3,4,5,6,7,8,9 < <(grep -v skipped <<<"$main")
check "bench-whole: a targets column in every row" \
    awk -F'|' '!/skipped/ && $11 !~ /[^ ]/ { exit 1 }' <<<"$main"
# With one run per job each median is one run's: the whole command holds
# the engine and the writer (3 decimals each).
check "bench-whole: whole command >= engine + write" \
    awk -F'|' '!/skipped/ && $6 + 0.002 < $4 + $5 { print; exit 1 }' <<<"$main"
check "bench-whole: write / engine is their ratio" \
    awk -F'|' '!/skipped/ { r = $4 > 0 ? $5 / $4 : 0; if ($4 >= 0.01 && (r - $7 > 0.06 * r + 0.06 || $7 - r > 0.06 * r + 0.06)) { print; exit 1 } }' <<<"$main"
check "bench-whole: memory measured in every row" \
    awk -F'|' '!/skipped/ && ($8 <= 0 || $9 <= 0 || $10 <= 0 || $10 > $9) { print; exit 1 }' <<<"$main"

wk=$(rows 'Workers:')
check "bench-whole: workers table, 9 rows" test "$(grep -c . <<<"$wk")" = 9
check "bench-whole: workers table, every column" numeric 2,3,4,5,6,7,8,9 <<<"$wk"
check "bench-whole: no shared segment at -w 0, one at -w 1 and 2" \
    awk -F'|' '($3 == 0) != ($10 == 0) { print; exit 1 }' <<<"$wk"
w1=$(rows '-w 1 against -w 0')
check "bench-whole: -w 1 table, 6 shapes" test "$(grep -c . <<<"$w1")" = 6
check "bench-whole: -w 1 table, every column" numeric 2,3,4,6,7 <<<"$w1"
check "bench-whole: -w 1 table says its runs alternate and what the ratio is" \
    grep -q '^The runs alternate, -w 0 then -w 1; \*-w 1 / -w 0\* is the median of each pair' "$B"

# The stage table has figures exactly when vox prints its stage profile.
st=$(rows 'VOD writer stages')
VOXD_SOCKET=/nonexistent "$REL/vox" voxelize -f examples/sphere.vx -r 32 -w 0 -o "$TMP/s.vod" >"$TMP/s.out"
if grep -q '^  VOD stages:' "$TMP/s.out"; then
    ncol=$(head -1 <<<"$st" | awk -F'|' '{ print NF - 2 }')
    check "bench-whole: stage table, 18 rows" test "$(grep -c . <<<"$st")" = 18
    check "bench-whole: stage table, every column" numeric "$(seq -s, 2 "$ncol")" <<<"$st"
else
    check "bench-whole: stage table says there is no profile" \
        grep -q 'no "  VOD stages:" line: it has no stage profile' "$B"
    check "bench-whole: stage table without figures" test -z "$st"
fi
