#!/bin/bash
# vox csg end to end: the issue's example tree (without its mesh and vod
# leaves) from a file and from standard input gives the same valid VOD
# voxels; 0, 1 and 2 workers the same bytes;
# occupancy; a bad tree exits 2 with its line, column and node.
. "$(dirname "$0")/lib.sh"

cat >"$TMP/part.csg" <<'EOT'
base  = cuboid center 0,0,0 size 1.6,1.0,0.6
hole  = cylinder center 0,0,0 radius 0.3 height 2 axis z
bump  = implicit "x^2 + y^2 + (z-0.3)^2 - 0.2" domain -1,1
out   = difference(union(base, bump), hole)   # comments after a node
out2  = union(out, dilate(bump, 2))
result out2
EOT
check "vox csg writes the tree" "$VOX" csg "$TMP/part.csg" -o "$TMP/a.vod" --res 64 -q
check "vox info validates it" "$VOX" info "$TMP/a.vod"
check "it is the density channel" bash -c "'$VOX' info '$TMP/a.vod' | grep -q 'channel     2: density'"
check "from stdin" bash -c "'$VOX' csg - -o '$TMP/b.vod' --res 64 -q <'$TMP/part.csg'"
# the metadata differ (source=file:... and source=submitted:N bytes), the voxels not
# (both read: two failed reads would agree on nothing)
"$VOX" info "$TMP/a.vod" >"$TMP/ia" 2>&1; ra=$?
"$VOX" info "$TMP/b.vod" >"$TMP/ib" 2>&1; rb=$?
ca=$(grep 'content checksum' "$TMP/ia") cb=$(grep 'content checksum' "$TMP/ib")
[ "$ra" -eq 0 ] && [ "$rb" -eq 0 ] && [ -n "$ca" ] && [ "$ca" = "$cb" ] && pass "the same voxels" ||
    fail "the same voxels" "vox info exit $ra and $rb: '$ca' / '$cb'"
check "made by vox csg, as its metadata says" bash -c "'$VOX' info '$TMP/a.vod' | grep -q 'generator=vox csg'"
check "recorded by its size" bash -c "'$VOX' info '$TMP/b.vod' | grep -q 'source=submitted:[0-9]* bytes'"
check "occupancy" bash -c "'$VOX' csg '$TMP/part.csg' -o '$TMP/o.vod' --res 64 -q --channel occupancy && '$VOX' info '$TMP/o.vod' | grep -q 'channel     1'"
for w in 0 1 2; do
    check "-w $w" "$VOX" csg "$TMP/part.csg" -o "$TMP/w$w.vod" --res 72 -q -w "$w"
done
check "0, 1 and 2 workers: the same bytes" bash -c "cmp '$TMP/w0.vod' '$TMP/w1.vod' && cmp '$TMP/w0.vod' '$TMP/w2.vod'"
printf 'a = cuboid size 1,1,1\nb = union(a, nope)\nresult b\n' >"$TMP/bad.csg"
refuse "a bad tree exits 2 with line, column and node" 2 "bad.csg:2:14: node 'b': unknown node 'nope'" \
    "$VOX" csg "$TMP/bad.csg" -o "$TMP/c.vod" --res 16
check "and no file" test ! -e "$TMP/c.vod"
