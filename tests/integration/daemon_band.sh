#!/bin/bash
# The distance channel's band through voxd for every kind of job
# (Implicit.band, Mesh.band, Csg.band): vox submit and vox voxelize --daemon
# give the bytes of the embedded vox voxelize / vox csg with the same
# --band; a band over 32, or with another channel, is refused at the Submit
# with INVALID_INPUT for each kind (the raw protocol: vox refuses both
# itself), and the connection and the daemon go on.
. "$(dirname "$0")/daemon_lib.bash"
ICO=$PWD/tests/golden/ico.obj
BALL='sqrt(x^2 + y^2 + z^2) - 0.55'

cat >"$TMP/ball.vx" <<EOT
#@ domain -1 1
$BALL
EOT
two_balls_csg >"$TMP/balls.csg"
ico_csg "$ICO" >"$TMP/mesh.csg"

# ---------------------------------------------------------------- embedded
check "expression, band 5: vox voxelize --embedded" \
    "$VOX" voxelize --embedded -e "$BALL" -r 48 --channel distance --band 5 -w 2 -q -o "$TMP/e-b5.vod"
check "expression, the default band: vox voxelize --embedded" \
    "$VOX" voxelize --embedded -e "$BALL" -r 48 --channel distance -w 2 -q -o "$TMP/e-b3.vod"
check "file, band 2: vox voxelize --embedded -w 0" \
    "$VOX" voxelize --embedded -f "$TMP/ball.vx" -r 40 --channel distance --band 2 -w 0 -q -o "$TMP/f-b2.vod"
check "tree, band 6: vox csg -w 0" \
    "$VOX" csg "$TMP/balls.csg" -r 48 --channel distance --band 6 -w 0 -q -o "$TMP/c-b6.vod"
check "tree with a mesh leaf, band 4: vox csg -w 2" \
    "$VOX" csg "$TMP/mesh.csg" -r 48 --channel distance --band 4 -w 2 -q -o "$TMP/m-b4.vod"
check "mesh, band 7: vox voxelize --embedded" \
    "$VOX" voxelize --embedded --mesh "$ICO" -r 40 --channel distance --band 7 -q -o "$TMP/i-b7.vod"
if cmp -s "$TMP/e-b5.vod" "$TMP/e-b3.vod"; then fail "the band changes an expression's file"
else pass "the band changes an expression's file"; fi

# ---------------------------------------------------------------- voxd
if start_voxd "$TMP/voxd.log" --workers 2; then pass "voxd starts"
else fail "voxd starts" "$(tail -5 "$TMP/voxd.log")"; exit 1; fi
vox() { timeout 300 "$VOX" --socket "$S" "$@"; }

check "expression, band 5: vox submit" \
    vox submit -e "$BALL" -r 48 --channel distance --band 5 -q -o "$TMP/d-e-b5.vod"
check "expression, band 5: voxd = embedded (bytes)" cmp "$TMP/d-e-b5.vod" "$TMP/e-b5.vod"
refuse "expression, band 5: the band in the metadata" 0 "meta        distance_band=5$" \
    "$VOX" info "$TMP/d-e-b5.vod"
check "expression, band 5: vox voxelize --daemon" \
    vox voxelize --daemon -e "$BALL" -r 48 --channel distance --band 5 -q -o "$TMP/v-e-b5.vod"
check "vox voxelize --daemon = embedded (bytes)" cmp "$TMP/v-e-b5.vod" "$TMP/e-b5.vod"
check "expression, the default band: vox submit" \
    vox submit -e "$BALL" -r 48 --channel distance -q -o "$TMP/d-e-b3.vod"
check "the default band: voxd = embedded (bytes)" cmp "$TMP/d-e-b3.vod" "$TMP/e-b3.vod"
check "file, band 2: vox submit" \
    vox submit -f "$TMP/ball.vx" -r 40 --channel distance --band 2 -q -o "$TMP/d-f-b2.vod"
check "file, band 2: voxd = embedded (bytes)" cmp "$TMP/d-f-b2.vod" "$TMP/f-b2.vod"
check "tree, band 6: vox submit --csg" \
    vox submit --csg "$TMP/balls.csg" -r 48 --channel distance --band 6 -q -o "$TMP/d-c-b6.vod"
check "tree, band 6: voxd = vox csg (bytes)" cmp "$TMP/d-c-b6.vod" "$TMP/c-b6.vod"
refuse "tree, band 6: the band in the metadata" 0 "meta        distance_band=6$" \
    "$VOX" info "$TMP/d-c-b6.vod"
check "tree with a mesh leaf, band 4: vox submit --csg" \
    vox submit --csg "$TMP/mesh.csg" -r 48 --channel distance --band 4 -q -o "$TMP/d-m-b4.vod"
check "tree with a mesh leaf, band 4: voxd = vox csg (bytes)" cmp "$TMP/d-m-b4.vod" "$TMP/m-b4.vod"
check "mesh, band 7: vox submit" \
    vox submit --mesh "$ICO" -r 40 --channel distance --band 7 -q -o "$TMP/d-i-b7.vod"
check "mesh, band 7: voxd = embedded (bytes)" cmp "$TMP/d-i-b7.vod" "$TMP/i-b7.vod"

# ---------------------------------------------------------------- refusals
refuse "vox submit --csg: --band without the distance channel" 2 \
    "^vox: --band is for --channel distance$" \
    vox submit --csg "$TMP/balls.csg" -r 32 --band 4 -o "$TMP/x.vod"
refuse "vox submit -e: a band over 32" 2 "^vox: bad --band '33': want 1\.\.32 voxels$" \
    vox submit -e "$BALL" --channel distance --band 33 -o "$TMP/x.vod"
for k in implicit mesh csg; do
    refuse "$k: band 33 refused at the Submit (INVALID_INPUT)" 3 \
        "^ERROR INVALID_INPUT: band 33 is not from 1 to 32 voxels \(or 0: 3\) \(job 0\)$" \
        vc band $k 33 4
    refuse "$k: a band with channel surface refused (INVALID_INPUT)" 3 \
        "^ERROR INVALID_INPUT: band 4 is for channel distance \(job 0\)$" vc band $k 4 3
    refuse "$k: the connection goes on after the refusal" 3 "^pong 12$" vc band $k 5 1
    refuse "$k: band 32 accepted" 0 "^accepted job [0-9]+$" vc band $k 32 4
done
[ ! -e "$TMP/x.vod" ] && pass "no file after a refusal" || fail "no file after a refusal"
check "voxd goes on" vox submit -e "$BALL" -r 16 --channel distance --band 1 -q -o "$TMP/z.vod"

kill -TERM "$VOXD_PID"
wait_gone "$VOXD_PID" 30 && [ "$WAIT_RC" = 0 ] && pass "voxd exits 0 on TERM" \
    || fail "voxd exits 0 on TERM" "rc ${WAIT_RC:-?}; $(tail -3 "$TMP/voxd.log")"
