#!/bin/bash
# The scaling benchmark (scripts/bench-scale.sh) in its quick mode, so that it
# cannot rot: a table for every kind of job, a row for each worker count with
# a number in every cell, 1 worker's speed-up 1.00 and yield 100%, and the
# dragon's table or the line that says why it is skipped.  No timing is
# asserted (the machine is shared).
. "$(dirname "$0")/lib.sh"
REL=build/release # the benchmark's build; make test builds it beside asan
mk() { env -u MAKEFLAGS -u MFLAGS -u MAKELEVEL make --no-print-directory -C "$ROOT" "$@"; }
check "the benchmark's tools build" mk V=release "$REL/voxwhole" "$REL/bench_mesh"
BENCH_QUICK=1 scripts/bench-scale.sh "$REL" >"$TMP/b.md" 2>"$TMP/err"
rc=$?
if [ "$rc" -eq 0 ]; then pass "bench-scale.sh runs (quick)"
else fail "bench-scale.sh runs (quick)" "exit $rc: $(tail -3 "$TMP/err")"; fi

# rows TITLE: the rows of the table under the heading that holds TITLE
rows() { awk -v t="$1" '/^#### / { on = index($0, t) > 0; next } on && /^\| [0-9]/' "$TMP/b.md"; }
for t in "Scene 1, 64^3" "sphere, 128^3" "10 primitives, 64^3" "polygonized (vox mesh)"; do
    r=$(rows "$t")
    n=$(wc -l <<<"$r")
    bad=$(awk -F'|' '{ for (i = 2; i < NF; i++) { c = $i; gsub(/[ %]/, "", c); if (c !~ /^[0-9.]+$/) print } }' <<<"$r")
    one=$(awk -F'|' '$2 + 0 == 1 { gsub(/ /, ""); print $4, $5, $7, $8 }' <<<"$r")
    if [ "$n" -eq 2 ] && [ -z "$bad" ] && [ "$one" = "1.00 100% 1.00 100%" ]; then
        pass "$t: rows for 1 and 2 workers, numbers in every cell, 1 worker the base"
    else fail "$t: rows for 1 and 2 workers, numbers in every cell, 1 worker the base" "$r"; fi
done
if [ "$(rows "the dragon" | wc -l)" -eq 2 ] || grep -q '^The dragon is skipped: ' "$TMP/b.md"; then
    pass "the dragon: its table, or why it is skipped"
else fail "the dragon: its table, or why it is skipped" "$(grep -i dragon "$TMP/b.md")"; fi
r=$(rows "independent one-worker jobs")
if [ "$(wc -l <<<"$r")" -eq 2 ] && awk -F'|' 'NR == 1 && $2 + 0 == 1 && $4 ~ /100%/ { a = 1 }
        NR == 2 && $2 + 0 == 2 && $3 + 0 > 0 && $4 ~ /[0-9]+%/ { b = 1 } END { exit !(a && b) }' <<<"$r"; then
    pass "the machine's ceiling: one copy alone, then 2 at once, with their ratio"
else fail "the machine's ceiling: one copy alone, then 2 at once, with their ratio" "$r"; fi
# Where the yield goes: a row for each job that ran, a number in every cell.
r=$(awk '/^#### Where the yield at 2 workers goes/ { on = 1; next } /^#### / { on = 0 } on && /^\| / && !/^\| job / && !/^\|---/' "$TMP/b.md")
n=$(grep -c . <<<"$r")
bad=$(awk -F'|' '{ for (i = 3; i < NF; i++) { c = $i; gsub(/[ %]/, "", c); if (c !~ /^[0-9.]+$/) print } }' <<<"$r")
if [ "$n" -ge 4 ] && [ -z "$bad" ]; then pass "where the yield goes: $n jobs, numbers in every cell"
else fail "where the yield goes: a row for each job, numbers in every cell" "$r"; fi
