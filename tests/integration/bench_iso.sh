#!/bin/bash
# The marching-cubes benchmark (scripts/bench-iso.sh) in its quick mode, so
# that it cannot rot: every table has its rows with a number in every
# column, every worker count gives the same triangles, each mip level fewer
# than the one below, and the adaptive rows are there.  No timing is
# asserted (the machine is shared).
. "$(dirname "$0")/lib.sh"
REL=build/release # the benchmark's build; make test builds it beside asan
BENCH_QUICK=1 BENCH_WORKERS=2 scripts/bench-iso.sh "$REL" >"$TMP/b.md" 2>"$TMP/err"
rc=$?
if [ "$rc" -eq 0 ]; then pass "bench-iso.sh runs (quick)"
else fail "bench-iso.sh runs (quick)" "exit $rc: $(tail -3 "$TMP/err")"; fi

# rows VOLUME: Table 6's rows of a volume: workers and triangles
t6() { awk -F'|' -v v="$1" '/^### Table 6/ { on = 1 } /^### Table 7/ { on = 0 }
       on && $2 ~ " " v " " { print $3, $9 }' "$TMP/b.md"; }
for v in scene1 solid; do
    n=$(t6 $v | wc -l)
    tris=$(t6 $v | awk '{ print $NF }' | sort -u | wc -l)
    if [ "$n" -eq 3 ] && [ "$tris" -eq 1 ]; then pass "Table 6, $v: 0, 1, 2 workers, one triangle count"
    else fail "Table 6, $v: 0, 1, 2 workers, one triangle count" "$(t6 $v)"; fi
done
# every cell of the Tables' rows a number (or '-' for the in-process speed-up)
bad=$(awk -F'|' '/^### VTK/ { vtk = 1 } !vtk && /^\| (scene1|solid) / { for (i = 3; i < NF; i++) { c = $i; gsub(/ /, "", c)
       if (c !~ /^[0-9.]+$/ && c != "-" && c !~ /^(0\(in-process\)|mip[0-9]|adaptive[-0-9.,]+)$/) print }}' "$TMP/b.md")
if [ -z "$bad" ]; then pass "every cell holds a number"; else fail "every cell holds a number" "$bad"; fi
t8() { awk -F'|' -v v="$1" -v l="$2" '/^### Table 8/ { on = 1 } on && $2 ~ " " v " " && $3 ~ " " l " " { gsub(/ /, "", $4); print $4 }' "$TMP/b.md"; }
for v in scene1 solid; do
    m0=$(t8 $v "mip 0"); m1=$(t8 $v "mip 1"); ad=$(t8 $v adaptive | wc -l)
    if [ -n "$m0" ] && [ -n "$m1" ] && [ "$ad" -eq 2 ] && [ "$m1" -lt "$m0" ]; then
        pass "Table 8, $v: mip 1 ($m1) has fewer triangles than mip 0 ($m0), two adaptive rows"
    else fail "Table 8, $v: mip 1 has fewer triangles than mip 0, two adaptive rows" "$m0 $m1 $ad"; fi
done
n7=$(awk '/^### Table 7/ { on = 1 } /^### Table 8/ { on = 0 } on && /^\| (scene1|solid) /' "$TMP/b.md" | wc -l)
if [ "$n7" -eq 4 ]; then pass "Table 7: two levels of two volumes"; else fail "Table 7: two levels of two volumes" "$n7 rows"; fi
if grep -Eq '^Targets: Scene 1 at 512\^3 .* yield t1 / \(2 t2\) = [0-9.]+ \(not judged' "$TMP/b.md"; then
    pass "the targets' line (not judged in a quick run)"
else fail "the targets' line (not judged in a quick run)" "$(grep -m1 Targets "$TMP/b.md")"; fi

# The VTK table: one line saying why it was skipped, or where VTK is
# installed (a quick run installs nothing) its rows: two thread counts per
# volume, numbers, and VTK's triangles within 2% of vox mesh's on the same
# samples (the two case tables differ only on ambiguous cells).
vtk=$(awk '/^### VTK/ { on = 1 } on' "$TMP/b.md")
if grep -q '^VTK comparison skipped: not installed, and a quick run installs nothing\.$' <<<"$vtk"; then
    pass "VTK table: skipped in a quick run without VTK, saying why"
else
    rows=$(awk -F'|' '/^\| (scene1|solid) / { n++
        for (i = 3; i <= 12; i++) { c = $i; gsub(/ /, "", c); if (c !~ /^[0-9.]+$/) bad++ }
        t1 = $10 + 0; t2 = $11 + 0
        if (t1 <= 0 || (t2 - t1) ^ 2 > (0.02 * t1) ^ 2) bad++ }
        END { print n + 0, bad + 0 }' <<<"$vtk")
    if [ "$rows" = "4 0" ]; then pass "VTK table: four rows of numbers, triangles within 2% of vox mesh's"
    else fail "VTK table: four rows of numbers, triangles within 2% of vox mesh's" "$rows: $vtk"; fi
fi
