#!/bin/bash
# vox csg --channel distance (docs/csg.md, "Signed distance"): trees of
# implicit and mesh leaves combined by union, intersection, difference and
# inverse give the same bytes with 0, 1 and 2 workers and through voxd (its
# default band); the band and units in the metadata; a band changes the
# file; bad bands and trees without a distance are refused in one line,
# naming the node, and leave no file.  (The values against closed forms:
# tests/unit/test_csg_distance.c.)
# vox_mpi: the release build's (the runner's $VOX), as distance.sh takes it.
VOXMPI=$(dirname "${VOX:-build/release/vox}")/vox_mpi
. "$(dirname "$0")/daemon_lib.bash"
ICO=$PWD/tests/golden/ico.obj

{
    balls_leaves
    printf '%s\n' 'c = implicit "sqrt(x^2 + y^2 + (z-0.3)^2) - 0.2"' \
        'r = difference(union(a, b), intersection(c, inverse(a)))' 'result r'
} >"$TMP/balls.csg"
ico_csg "$ICO" >"$TMP/mesh.csg"

for t in balls mesh; do
    for w in 0 1 2; do
        check "$t: -w $w" "$VOX" csg "$TMP/$t.csg" -r 72 --channel distance -w $w -q -o "$TMP/$t-w$w.vod"
    done
    check "$t: -w 0 and -w 1 the same bytes" cmp "$TMP/$t-w0.vod" "$TMP/$t-w1.vod"
    check "$t: -w 0 and -w 2 the same bytes" cmp "$TMP/$t-w0.vod" "$TMP/$t-w2.vod"
    check "$t: vox info validates it" "$VOX" info "$TMP/$t-w0.vod"
done
refuse "channel 4" 0 "channel     4: signed distance" "$VOX" info "$TMP/balls-w0.vod"
refuse "metadata: the band" 0 "meta        distance_band=3$" "$VOX" info "$TMP/balls-w0.vod"
refuse "metadata: the units" 0 "meta        distance_units=world$" "$VOX" info "$TMP/balls-w0.vod"
for w in 0 2; do
    check "--band 6, -w $w" "$VOX" csg "$TMP/mesh.csg" -r 64 --channel distance --band 6 -w $w -q -o "$TMP/b6-w$w.vod"
done
check "--band 6: the same bytes" cmp "$TMP/b6-w0.vod" "$TMP/b6-w2.vod"
refuse "metadata: --band 6" 0 "meta        distance_band=6$" "$VOX" info "$TMP/b6-w0.vod"
"$VOX" csg "$TMP/mesh.csg" -r 64 --channel distance -w 0 -q -o "$TMP/b3.vod"
if cmp -s "$TMP/b3.vod" "$TMP/b6-w0.vod"; then fail "the band changes the file"
else pass "the band changes the file"; fi
check "vox export: a level set" "$VOX" export "$TMP/balls-w0.vod" -o "$TMP/balls.nrrd"

# ---------------------------------------------------------------- refusals
for b in 0 33 x -1 ''; do
    refuse "--band '$b' refused in one line" 2 "^vox: bad --band '$b': want 1\.\.32 voxels$" \
        "$VOX" csg "$TMP/balls.csg" -r 32 --channel distance --band "$b" -o "$TMP/x.vod"
done
refuse "--band without --channel distance" 2 "^vox: csg: --band is for --channel distance" \
    "$VOX" csg "$TMP/balls.csg" -r 32 --band 4 -o "$TMP/x.vod"
printf 'a = cuboid size 1,1,1\nb = implicit "x"\nc = union(a, b)\nresult c\n' >"$TMP/prim.csg"
refuse "a primitive has no distance: the node named" 2 \
    "^vox: .*x.vod: the distance channel: node 'a' \\(cuboid\\): a primitive has no signed distance" \
    "$VOX" csg "$TMP/prim.csg" -r 32 --channel distance -o "$TMP/x.vod"
printf 'a = implicit "x"\nb = implicit "y"\nc = add(a, b)\nresult c\n' >"$TMP/add.csg"
refuse "add does not combine distances" 2 "node 'c' \\(add\\): this operator does not combine" \
    "$VOX" csg "$TMP/add.csg" -r 32 --channel distance -o "$TMP/x.vod"
[ ! -e "$TMP/x.vod" ] && pass "no file after a refusal" || fail "no file after a refusal"

# ---------------------------------------------------------------- voxd
if start_voxd "$TMP/voxd.log" --workers 2; then pass "voxd starts"
else fail "voxd starts" "$(tail -5 "$TMP/voxd.log")"; exit 1; fi
vox() { timeout 300 "$VOX" --socket "$S" "$@"; }
for t in balls mesh; do
    check "$t: vox submit --csg --channel distance" \
        vox submit --csg "$TMP/$t.csg" -r 72 --channel distance -q -o "$TMP/$t-d.vod"
    check "$t: voxd = embedded (bytes)" cmp "$TMP/$t-d.vod" "$TMP/$t-w0.vod"
done
refuse "voxd refuses a tree without a distance, naming the node" 2 "node 'a' \\(cuboid\\)" \
    vox submit --csg "$TMP/prim.csg" -r 32 --channel distance -o "$TMP/y.vod"
check "voxd goes on" vox submit --csg "$TMP/balls.csg" -r 32 --channel distance -q -o "$TMP/z.vod"
