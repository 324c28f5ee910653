#!/bin/bash
# CSG jobs through voxd: vox submit --csg gives the bytes of vox csg (the
# embedded engine, and -w 0 in the vox process), density and occupancy;
# bad trees of each kind are refused at the Submit with their own error
# while the connection and the daemon go on (a child that is not earlier,
# an unknown op, a wrong arity, a bad parameter, a bad expression, a mesh
# leaf, no nodes, deeper than max_csg_depth, more than max_csg_nodes);
# a running CSG job is cancelled; the daemon exits clean.
. "$(dirname "$0")/daemon_lib.bash"

cat >"$TMP/part.csg" <<'EOT'
# the issue's part, without its mesh and vod leaves
base  = cuboid center 0,0,0 size 1.6,1.0,0.6 rotate 0,0,15
hole  = cylinder center 0,0,0 radius 0.3 height 2 axis z
bump  = implicit "x^2 + y^2 + (z-0.3)^2 - 0.2" domain -1,1
peg   = cone center 0.5,0,0.2 radii 0.1,0.15 height 0.5 axis x
out   = difference(union(base, bump), hole)
out2  = union(out, dilate(peg, 2))
result out2
EOT
# 20 nested inverses: within the text parser's depth, over max_csg_depth 16
{ echo "n0 = ellipsoid radius 0.5"
  for i in $(seq 20); do echo "n$i = inverse(n$((i - 1)))"; done
  echo "result n20"; } >"$TMP/deep.csg"
# an expression the client's parser takes but max_expr_depth 8 does not
printf 'a = implicit "((((((((((x)))))))))) - 0.5"\nresult a\n' >"$TMP/nested.csg"

cat >"$TMP/voxd.conf" <<CONF
workers 2
max_csg_depth 16
max_expr_depth 8
max_csg_leaf_bytes 256K
max_frame 64K
chunk_size 16K
worker_stall_timeout 600
max_csg_nodes 100
CONF
if start_voxd "$TMP/voxd.log" --config "$TMP/voxd.conf"; then
    pass "voxd starts with CSG limits"
else
    fail "voxd starts with CSG limits" "$(tail -5 "$TMP/voxd.log")"
    exit 1
fi
vox() { timeout 120 "$VOX" --socket "$S" "$@"; }

# ---------------------------------------------------------------- same bytes

check "vox csg (embedded engine)" vox csg "$TMP/part.csg" -r 64 -q -o "$TMP/e1.vod"
check "vox csg -w 0 (in vox)" vox csg "$TMP/part.csg" -r 64 -q -w 0 -o "$TMP/s1.vod"
check "vox submit --csg" vox submit --csg "$TMP/part.csg" -r 64 -q -o "$TMP/d1.vod"
check "submit = embedded = serial, density (bytes)" \
    bash -c "cmp '$TMP/d1.vod' '$TMP/e1.vod' && cmp '$TMP/d1.vod' '$TMP/s1.vod'"
refuse "vox info validates the daemon's CSG file" 0 "channel +2: density" "$VOX" info "$TMP/d1.vod"
refuse "its metadata names the tree's file" 0 "source=file:$TMP/part.csg" "$VOX" info "$TMP/d1.vod"
check "occupancy, embedded" vox csg "$TMP/part.csg" -r 50 -q -c occupancy -d -1,1,-0.8,0.8,-0.5,0.5 -o "$TMP/e2.vod"
check "occupancy, vox submit" vox submit --csg "$TMP/part.csg" -r 50 -q --channel occupancy \
    -d -1,1,-0.8,0.8,-0.5,0.5 -o "$TMP/d2.vod"
check "submit = embedded, occupancy in a box (bytes)" cmp "$TMP/d2.vod" "$TMP/e2.vod"
check "from standard input" bash -c "timeout 120 '$VOX' --socket '$S' submit --csg - -r 64 -q -o '$TMP/d3.vod' <'$TMP/part.csg'"
refuse "recorded by its size" 0 "source=submitted:[0-9]+ bytes" "$VOX" info "$TMP/d3.vod"
check "surface, embedded" vox csg "$TMP/part.csg" -r 40 -q -c surface -o "$TMP/e5.vod"
check "surface, vox submit" vox submit --csg "$TMP/part.csg" -r 40 -q --channel surface -o "$TMP/d5s.vod"
check "submit = embedded, surface (bytes)" cmp "$TMP/d5s.vod" "$TMP/e5.vod"
check "vox render draws it" vox render "$TMP/d5s.vod" -o "$TMP/d5s.png" --size 64

# ---------------------------------------------------------------- leaves

# A mesh leaf (a box, fitted and scaled) and a VOD leaf (the part itself
# on another grid): vox sends the files' bytes, the daemon opens no path.
mkdir "$TMP/leaves"
cat >"$TMP/leaves/box.obj" <<'OBJ'
v -1 -1 -1
v 1 -1 -1
v -1 1 -1
v 1 1 -1
v -1 -1 1
v 1 -1 1
v -1 1 1
v 1 1 1
f 1 3 4
f 1 4 2
f 5 6 8
f 5 8 7
f 1 2 6
f 1 6 5
f 3 7 8
f 3 8 4
f 1 5 7
f 1 7 3
f 2 4 8
f 2 8 6
OBJ
check "the VOD leaf's file" vox csg "$TMP/part.csg" -r 24 -q -w 0 -d -1.2,1.2 -o "$TMP/leaves/prev.vod"
cat >"$TMP/leaves/leaves.csg" <<'EOT'
scan = mesh "box.obj" fit 0.3,0.2,-0.1 scale 0.7
prev = vod "prev.vod"
bump = implicit "x^2 + y^2 + (z-0.3)^2 - 0.2" domain -1,1
out  = union(difference(scan, dilate(prev, 1)), intersection(bump, prev))
result out
EOT
check "vox csg with mesh and vod leaves" vox csg "$TMP/leaves/leaves.csg" -r 48 -q -o "$TMP/l1.vod"
check "vox csg -w 0, the same" vox csg "$TMP/leaves/leaves.csg" -r 48 -q -w 0 -o "$TMP/l0.vod"
check "vox submit --csg with mesh and vod leaves" \
    vox submit --csg "$TMP/leaves/leaves.csg" -r 48 -q -o "$TMP/l2.vod"
check "leaves: submit = embedded = serial (bytes)" \
    bash -c "cmp '$TMP/l1.vod' '$TMP/l0.vod' && cmp '$TMP/l1.vod' '$TMP/l2.vod'"
printf 'garbage\n' >"$TMP/leaves/bad.obj"
printf 'm = mesh "bad.obj"\nresult m\n' >"$TMP/leaves/badmesh.csg"
refuse "a mesh leaf the daemon cannot read: the job's INVALID_INPUT, naming the node" 2 \
    "INVALID_INPUT: .*node 'm': mesh: " vox submit --csg "$TMP/leaves/badmesh.csg" -r 16 -o "$TMP/x.vod"
# A mesh leaf over the 64K frame: the leaves go after the Accepted, as the
# job's input, in chunks; the same bytes.
{ cat "$TMP/leaves/box.obj"; for i in $(seq 2500); do echo "# a comment line to make the file longer than a frame"; done; } >"$TMP/leaves/long.obj"
sed 's/box.obj/long.obj/' "$TMP/leaves/leaves.csg" >"$TMP/leaves/long.csg"
check "vox csg with a leaf over a frame" vox csg "$TMP/leaves/long.csg" -r 48 -q -o "$TMP/lc1.vod"
check "vox submit --csg with a leaf over a frame" vox submit --csg "$TMP/leaves/long.csg" -r 48 -q -o "$TMP/lc2.vod"
check "a leaf over a frame: submit = embedded (bytes)" cmp "$TMP/lc1.vod" "$TMP/lc2.vod"
check "its leaves came as the job's input" grep -q "waiting for [0-9]* bytes of CSG tree" "$TMP/voxd.log"
{ cat "$TMP/leaves/box.obj"; for i in $(seq 6000); do echo "# a comment line to pass 256K of leaves, and a frame"; done; } >"$TMP/leaves/big.obj"
printf 'm = mesh "big.obj"\nresult m\n' >"$TMP/leaves/big.csg"
refuse "leaves over max_csg_leaf_bytes are refused at the Submit" 1 \
    "LIMIT_EXCEEDED: CSG node 0's file is [0-9]+ bytes, over this server's max_csg_leaf_bytes of 262144" \
    vox submit --csg "$TMP/leaves/big.csg" -r 16 -o "$TMP/x.vod"
refuse "a missing leaf file is vox's error" 2 "node 'm': .*nothere.obj: No such file" \
    bash -c "printf 'm = mesh \"nothere.obj\"\nresult m\n' >'$TMP/leaves/missing.csg' && timeout 60 '$VOX' --socket '$S' submit --csg '$TMP/leaves/missing.csg' -r 16 -o '$TMP/x.vod'"

# ---------------------------------------------------------------- bad trees

bad() { # bad KIND CODE PATTERN
    refuse "a bad tree ($1) is refused: $3" 3 "ERROR $2: .*$3.* \(job 0\)" vc csg-bad "$1"
    grep -q "^pong 12" "$TMP/out" && pass "the connection goes on after it ($1)" ||
        fail "the connection goes on after it ($1)" "$(cat "$TMP/out")"
}
bad cycle INVALID_INPUT "CSG node 1 \('loop'\) refers to node 1, which is not earlier"
bad unknown-op INVALID_INPUT "CSG node 1 \('what'\) has unknown op 99"
bad arity INVALID_INPUT "CSG node 1 \('half'\) \(union\) needs 2 children, got 1"
bad param INVALID_INPUT "CSG node 2 \('div'\) \(divide\) needs a scalar S_L in \(0, 1\], got 1.5"
bad k INVALID_INPUT "CSG node 1 \('er'\) needs k of 1..16 voxels, got 40"
bad expression INVALID_INPUT "CSG node 0 \('bad'\): expression:1:"
bad mesh-leaf INVALID_INPUT "CSG node 0 \('scan'\): a mesh leaf needs its file's data"
bad no-nodes INVALID_INPUT "CSG job has no nodes"
bad deep LIMIT_EXCEEDED "the tree is deeper than this server's max_csg_depth of 16"
refuse "vox submit: a tree over max_csg_depth" 1 \
    "LIMIT_EXCEEDED: CSG node 16 \('n16'\): the tree is deeper than this server's max_csg_depth of 16" \
    vox submit --csg "$TMP/deep.csg" -r 16 -o "$TMP/x.vod"
refuse "vox submit: an expression over max_expr_depth" 1 \
    "LIMIT_EXCEEDED: CSG node 0 \('a'\): expression" \
    vox submit --csg "$TMP/nested.csg" -r 16 -o "$TMP/x.vod"
# 64 cuboids joined pairwise: 127 nodes, only 7 deep, over max_csg_nodes 100
# (csg-bad deep above has 71 nodes: under it)
python3 -c '
n = [f"c{i} = cuboid center {-0.95 + 0.029 * i:.3f},0,0 size 0.025,0.05,0.05" for i in range(64)]
level, k = [f"c{i}" for i in range(64)], 0
while len(level) > 1:
    nxt = []
    for a, b in zip(level[::2], level[1::2]):
        n.append(f"u{k} = union({a}, {b})"); nxt.append(f"u{k}"); k += 1
    level = nxt
print("\n".join(n + ["result " + level[0]]))' >"$TMP/wide.csg"
refuse "vox submit: a tree over max_csg_nodes (127 nodes, 7 deep)" 1 \
    "LIMIT_EXCEEDED: CSG job has 127 nodes, over this server's max_csg_nodes of 100" \
    vox submit --csg "$TMP/wide.csg" -r 16 -o "$TMP/x.vod"
check "the same tree embedded (vox csg): no limit of the daemon's" "$VOX" csg "$TMP/wide.csg" -r 16 -q -o "$TMP/wide.vod"
printf 'a = cuboid size 1,1,1\nb = union(a, nope)\nresult b\n' >"$TMP/unknown.csg"
refuse "vox submit: an unknown name, found by vox's parser" 2 "unknown.csg:2:14: node 'b': unknown node 'nope'" \
    vox submit --csg "$TMP/unknown.csg" -r 16 -o "$TMP/x.vod"
[ ! -e "$TMP/x.vod" ] && pass "no file is left by a refused job" || fail "no file is left by a refused job"
check "the daemon serves the next CSG job" vox submit --csg "$TMP/part.csg" -r 64 -q -o "$TMP/d4.vod"
check "with the same bytes" cmp "$TMP/d4.vod" "$TMP/e1.vod"

# ---------------------------------------------------------------- cancel

# A tree heavy enough to be running when the interrupt comes.
printf 'a = implicit "sin(9*x)*sin(9*y)*sin(9*z) - 0.1"\nb = dilate(a, 3)\nresult b\n' >"$TMP/slow.csg"
bg "$VOX" --socket "$S" submit --csg "$TMP/slow.csg" -r 512 -q -o "$TMP/slow.vod"
SUB=$!
until_true 20 running && pass "the heavy CSG job runs" || fail "the heavy CSG job runs" "$(vc status)"
kill -INT "$SUB"
wait "$SUB"
rc=$?
[ "$rc" -eq 1 ] && pass "an interrupted vox submit --csg exits 1 (cancelled)" ||
    fail "an interrupted vox submit --csg exits 1 (cancelled)" "exit $rc"
until_true 20 idle && pass "idle after the cancel" || fail "idle after the cancel" "$(vc status)"
[ ! -e "$TMP/slow.vod" ] && pass "no file from the cancelled job" || fail "no file from the cancelled job"
check "the daemon serves a CSG job after the cancel" vox submit --csg "$TMP/part.csg" -r 64 -q -o "$TMP/d5.vod"
check "with the same bytes again" cmp "$TMP/d5.vod" "$TMP/e1.vod"

# ---------------------------------------------------------------- supervision

# A worker killed while it holds a task of a CSG job (shown STALLED while
# the busiest one: kill_busy_worker): its run of bricks is evaluated again by the
# one forked in its place, and the file is the embedded engine's.
REL=build/release/vox # make test builds it beside asan; the reference only
[ -x "$REL" ] || REL=$VOX
# (256^3: several seconds under ASan, so that the busiest worker is found mid-job)
check "the heavy job, embedded (release)" timeout 300 "$REL" csg "$TMP/slow.csg" -r 256 -q -o "$TMP/k1.vod"
bg "$VOX" --socket "$S" submit --csg "$TMP/slow.csg" -r 256 -q -o "$TMP/k2.vod"
SUB=$!
until_true 20 running && pass "the heavy job runs on voxd" || fail "the heavy job runs on voxd" "$(vc status)"
kill_busy_worker && pass "a worker holding a task of the CSG job is killed" ||
    fail "a worker holding a task of the CSG job is killed" "$(vc status)"
victim=$VICTIM
wait "$SUB"
rc=$?
[ "$rc" -eq 0 ] && pass "the job survives a worker killed while it runs" ||
    fail "the job survives a worker killed while it runs" "exit $rc: $(tail -3 "$TMP/voxd.log")"
check "with the embedded engine's bytes" cmp "$TMP/k1.vod" "$TMP/k2.vod"
until_true 10 eval '! worker_pids | grep -qx "$victim"' && [ "$(worker_pids | wc -l)" -eq 2 ] &&
    pass "the killed worker was replaced" || fail "the killed worker was replaced" "$(vc status)"
[ -n "$victim" ] && grep -q "(pid $victim) died; forked again" "$TMP/voxd.log" &&
    pass "the busy worker's death logged" || fail "the busy worker's death logged" "$(grep died "$TMP/voxd.log")"

kill -QUIT "$VOXD_PID"
wait_gone "$VOXD_PID" 30 && [ "$WAIT_RC" = 0 ] && pass "QUIT: exit 0" ||
    fail "QUIT: exit 0" "rc $WAIT_RC: $(tail -3 "$TMP/voxd.log")"

# A CSG job over job_timeout ends with TIMEOUT, and the daemon goes on.
printf 'workers 2\njob_timeout 1\n' >"$TMP/voxd2.conf"
if start_voxd "$TMP/voxd2.log" --config "$TMP/voxd2.conf"; then
    refuse "a CSG job over job_timeout: TIMEOUT" 1 "TIMEOUT: .*job_timeout of 1 s" \
        vox submit --csg "$TMP/slow.csg" -r 512 -o "$TMP/x.vod"
    check "the daemon serves the next CSG job" vox submit --csg "$TMP/part.csg" -r 64 -q -o "$TMP/d7.vod"
    check "with the same bytes" cmp "$TMP/d7.vod" "$TMP/e1.vod"
    kill -QUIT "$VOXD_PID"
    wait_gone "$VOXD_PID" 30 && [ "$WAIT_RC" = 0 ] && pass "QUIT: exit 0 (second voxd)" ||
        fail "QUIT: exit 0 (second voxd)" "rc $WAIT_RC: $(tail -3 "$TMP/voxd2.log")"
else
    fail "a second voxd starts" "$(tail -5 "$TMP/voxd2.log")"
fi
