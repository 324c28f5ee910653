#!/bin/bash
# The distance channel of mesh jobs (--channel distance, --band K): the
# same bytes with 0, 1 and 2 workers and through voxd, the band and the
# units in the file's metadata, channel 4 in vox info, and the refusals of
# bad bands and of the channel where it does not belong, one line each.
# (The values against a brute-force oracle: tests/unit/test_mesh_dist.c.)
# vox_mpi: the release build's (the runner's $VOX), as mpi.sh does: Open
# MPI's own allocations are not this project's to answer for under LSan.
VOXMPI=$(dirname "${VOX:-build/release/vox}")/vox_mpi
. "$(dirname "$0")/daemon_lib.bash"
ICO=tests/golden/ico.obj

# A torus of 48 x 24 quads (the tube 0.25 about a circle of 0.6), closed.
python3 - >"$TMP/torus.obj" <<'PY'
import math
R, r, n, m = 0.6, 0.25, 48, 24
for i in range(n):
    for j in range(m):
        a, b = 2 * math.pi * i / n, 2 * math.pi * j / m
        print("v %.6f %.6f %.6f" % ((R + r * math.cos(b)) * math.cos(a),
                                    (R + r * math.cos(b)) * math.sin(a), r * math.sin(b)))
for i in range(n):
    for j in range(m):
        k = lambda p, q: (p % n) * m + (q % m) + 1
        print("f %d %d %d" % (k(i, j), k(i + 1, j), k(i + 1, j + 1)))
        print("f %d %d %d" % (k(i, j), k(i + 1, j + 1), k(i, j + 1)))
PY

for mesh in "$ICO" "$TMP/torus.obj"; do
    name=$(basename "$mesh" .obj)
    for w in 0 1 2; do
        check "$name: distance with -w $w" \
            "$VOX" voxelize --embedded --mesh "$mesh" -r 72 --channel distance -w $w -q -o "$TMP/$name-w$w.vod"
    done
    check "$name: -w 0 and -w 1 the same bytes" cmp "$TMP/$name-w0.vod" "$TMP/$name-w1.vod"
    check "$name: -w 0 and -w 2 the same bytes" cmp "$TMP/$name-w0.vod" "$TMP/$name-w2.vod"
done
check "band 5, winding repair: -w 0" \
    "$VOX" voxelize --embedded --mesh "$TMP/torus.obj" -r 64 --channel distance --band 5 --repair winding -w 0 -q -o "$TMP/b5-w0.vod"
check "band 5, winding repair: -w 2" \
    "$VOX" voxelize --embedded --mesh "$TMP/torus.obj" -r 64 --channel distance --band 5 --repair winding -w 2 -q -o "$TMP/b5-w2.vod"
check "band 5: the same bytes" cmp "$TMP/b5-w0.vod" "$TMP/b5-w2.vod"
refuse "vox info: channel 4, valid" 0 "channel     4: signed distance" "$VOX" info "$TMP/ico-w0.vod"
refuse "metadata: the band in voxels" 0 "meta        distance_band=3$" "$VOX" info "$TMP/ico-w0.vod"
refuse "metadata: the units" 0 "meta        distance_units=world$" "$VOX" info "$TMP/ico-w0.vod"
refuse "metadata: --band 5" 0 "meta        distance_band=5$" "$VOX" info "$TMP/b5-w0.vod"
if cmp -s "$TMP/b5-w0.vod" "$TMP/torus-w0.vod"; then fail "the band changes the file"
else pass "the band changes the file"; fi

# ---------------------------------------------------------------- refusals
for b in 0 33 x 3x -1 ''; do
    refuse "--band '$b' refused in one line" 2 "^vox: bad --band '$b': want 1\.\.32 voxels$" \
        "$VOX" voxelize --mesh "$ICO" --channel distance --band "$b" -o "$TMP/x.vod"
done
refuse "--band without --channel distance" 2 "^vox: --band is for --channel distance$" \
    "$VOX" voxelize --mesh "$ICO" --band 4 -o "$TMP/x.vod"
refuse "--channel distance with --mode surface" 2 \
    "^vox: --channel distance takes its sign from the solid: mode solid only$" \
    "$VOX" voxelize --mesh "$ICO" --channel distance --mode surface -o "$TMP/x.vod"
refuse "vox submit refuses a bad band too" 2 "^vox: bad --band '40': want 1\.\.32 voxels$" \
    "$VOX" submit --mesh "$ICO" --channel distance --band 40 -o "$TMP/x.vod"
[ ! -e "$TMP/x.vod" ] && pass "no file after a refusal" || fail "no file after a refusal"

# ---------------------------------------------------------------- voxd
if start_voxd "$TMP/voxd.log" --workers 2; then pass "voxd starts"
else fail "voxd starts" "$(tail -5 "$TMP/voxd.log")"; exit 1; fi
vox() { timeout 300 "$VOX" --socket "$S" "$@"; }
check "vox submit: the ellipsoid's distance" \
    vox submit --mesh "$ICO" -r 72 --channel distance -q -o "$TMP/ico-d.vod"
check "voxd = embedded (bytes)" cmp "$TMP/ico-d.vod" "$TMP/ico-w0.vod"
check "vox submit: band 5, winding repair" \
    vox submit --mesh "$TMP/torus.obj" -r 64 --channel distance --band 5 --repair winding -q -o "$TMP/b5-d.vod"
check "voxd = embedded, band 5 (bytes)" cmp "$TMP/b5-d.vod" "$TMP/b5-w0.vod"
