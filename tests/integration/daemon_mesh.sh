#!/bin/bash
# Mesh jobs through voxd: the daemon's file is byte for byte the embedded
# engine's (solid occupancy and density, fitted and in a box), inline and
# uploaded in chunks, vox voxelize --mesh on the daemon and without one;
# refusals (over max_mesh_bytes before any byte is sent, over max_triangles,
# a malformed file, after which the daemon serves the next job) and the
# cancel of a running mesh job.  The meshes are OBJ text, which every
# loader reads.
. "$(dirname "$0")/daemon_lib.bash"

# A closed cube of 12 triangles, counter-clockwise seen from outside, with
# no vertex on the grid's voxel centres.
cube_obj() {
    cat <<'OBJ'
v -0.9 -0.8 -0.7
v 0.9 -0.8 -0.7
v 0.9 0.8 -0.7
v -0.9 0.8 -0.7
v -0.9 -0.8 0.7
v 0.9 -0.8 0.7
v 0.9 0.8 0.7
v -0.9 0.8 0.7
f 1 3 2
f 1 4 3
f 5 6 7
f 5 7 8
f 1 2 6
f 1 6 5
f 2 3 7
f 2 7 6
f 3 4 8
f 3 8 7
f 4 1 5
f 4 5 8
OBJ
}
cube_obj >"$TMP/cube.obj"
# The same cube with 100 KB of comments: over the daemon's max_frame below,
# so it goes as the job's input, in chunks.
{ cube_obj; for i in $(seq 2000); do echo "# comment line $i to make the file longer than a frame"; done; } >"$TMP/long.obj"
# Over max_triangles (1000 below): 1001 triangles of one fan.
python3 - >"$TMP/many.obj" <<'PY'
import math
n = 1001
print("v 0 0 0")
for i in range(n + 1):
    a = 2 * math.pi * i / n
    print("v %.6f %.6f 0.25" % (math.cos(a), math.sin(a)))
for i in range(n):
    print("f 1 %d %d" % (i + 2, i + 3))
PY
# Malformed: a face names a vertex that is not there (line 4).
printf 'v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 9\n' >"$TMP/bad.obj"
# Over max_mesh_bytes (256K below) but within max_input_bytes.
{ cube_obj; for i in $(seq 6000); do echo "# comment line $i to make the file longer than max_mesh_bytes"; done; } >"$TMP/huge.obj"

cat >"$TMP/voxd.conf" <<CONF
workers 2
max_frame 64K
chunk_size 16K
max_mesh_bytes 256K
max_triangles 1000
CONF
if start_voxd "$TMP/voxd.log" --config "$TMP/voxd.conf"; then
    pass "voxd starts with mesh limits"
else
    fail "voxd starts with mesh limits" "$(tail -5 "$TMP/voxd.log")"
    exit 1
fi
vox() { timeout 120 "$VOX" --socket "$S" "$@"; }
# jobs the daemon has accepted so far
accepted() { grep -c "accepted from uid" "$TMP/voxd.log"; }

# ---------------------------------------------------------------- same bytes

check "embedded: the cube, solid occupancy" vox voxelize --embedded --mesh "$TMP/cube.obj" -r 48 -q -o "$TMP/e1.vod"
check "vox submit --mesh: the cube" vox submit --mesh "$TMP/cube.obj" -r 48 -q -o "$TMP/d1.vod"
check "submit = embedded, solid occupancy (bytes)" cmp "$TMP/d1.vod" "$TMP/e1.vod"
refuse "vox info validates the daemon's mesh file" 0 "valid VOD.*CRC-32 checked" "$VOX" info "$TMP/d1.vod"
refuse "its metadata names the file and the mesh" 0 "source=file:$TMP/cube.obj" "$VOX" info "$TMP/d1.vod"
refuse "vox submit's summary has the mesh's edges from voxd" 0 \
    "mesh: 12 triangles, 0 open and 0 non-manifold edges: watertight" \
    vox submit --mesh "$TMP/cube.obj" -r 48 -o "$TMP/d1s.vod"
refuse "a repair asked of the closed cube is not run" 0 "repair: not needed" \
    vox submit --mesh "$TMP/cube.obj" -r 48 --repair vote -o "$TMP/d1r.vod"

check "embedded: density, 4 samples a voxel, pad 3" \
    vox voxelize --embedded --mesh "$TMP/cube.obj" -r 40 --channel density --supersample 4 --pad 3 -q -o "$TMP/e2.vod"
check "vox submit: the same" \
    vox submit --mesh "$TMP/cube.obj" -r 40 --channel density --supersample 4 --pad 3 -q -o "$TMP/d2.vod"
check "submit = embedded, density (bytes)" cmp "$TMP/d2.vod" "$TMP/e2.vod"

check "embedded: surface mode in a box" \
    vox voxelize --embedded --mesh "$TMP/cube.obj" -r 33 --mode surface --bbox -1,1,-1,1,-0.5,0.5 -q -o "$TMP/e3.vod"
check "vox submit: the same" \
    vox submit --mesh "$TMP/cube.obj" -r 33 --mode surface --bbox -1,1,-1,1,-0.5,0.5 -q -o "$TMP/d3.vod"
check "submit = embedded, a box (bytes)" cmp "$TMP/d3.vod" "$TMP/e3.vod"

# --weld: the cube of separate faces (24 vertices) is open as written;
# welded, by vox and by voxd alike, it is the closed cube, the same bytes.
awk '/^v /{ v[++n] = $0 } /^f /{ for (i = 2; i <= 4; i++) print v[$i]; k += 3
     print "f", k - 2, k - 1, k }' "$TMP/cube.obj" >"$TMP/faces.obj"
refuse "a cube of separate triangles is open" 0 "mesh: 12 triangles, 36 open" \
    vox submit --mesh "$TMP/faces.obj" -r 48 -o "$TMP/w0.vod"
refuse "vox submit --weld 0: voxd welds it closed" 0 \
    "mesh: 12 triangles, 0 open and 0 non-manifold edges: watertight" \
    vox submit --mesh "$TMP/faces.obj" --weld 0 -r 48 -o "$TMP/w1.vod"
refuse "vox voxelize --embedded --weld 0: the same" 0 \
    "mesh: 12 triangles, 0 open and 0 non-manifold edges: watertight" \
    vox voxelize --embedded --mesh "$TMP/faces.obj" --weld 0 -r 48 -o "$TMP/w2.vod"
check "welded: submit = embedded (bytes)" cmp "$TMP/w1.vod" "$TMP/w2.vod"
check "vox submit --weld 1e-3: the same bytes" \
    vox submit --mesh "$TMP/faces.obj" --weld 1e-3 -r 48 -q -o "$TMP/w3.vod"
check "(cmp)" cmp "$TMP/w3.vod" "$TMP/w2.vod"
refuse "a weld that leaves no triangle: voxd's INVALID_INPUT" 2 \
    "INVALID_INPUT: mesh: no triangle is left once welded at 10" \
    vox submit --mesh "$TMP/faces.obj" --weld 10 -r 48 -o "$TMP/x.vod"
refuse "a bad --weld is refused by vox" 2 "bad --weld '-1'" \
    vox submit --mesh "$TMP/faces.obj" --weld -1 -r 48 -o "$TMP/x.vod"
refuse "--weld needs --mesh" 2 "are for --mesh jobs" \
    vox submit -e 'x*x+y*y+z*z-0.5' --weld 0 -r 48 -o "$TMP/x.vod"

# glTF: a .glb, and a .gltf whose buffer is a .bin beside it (vox submit
# embeds it: the daemon reads no file), give the embedded engine's bytes.
G=$(dirname "$0")/obj2gltf.py
python3 "$G" "$TMP/cube.obj" "$TMP/cube.glb" glb && python3 "$G" "$TMP/cube.obj" "$TMP/ext" gltf
for f in cube.glb ext.gltf; do
    check "embedded: $f" vox voxelize --embedded --mesh "$TMP/$f" -r 48 -q -o "$TMP/eg-$f.vod"
    check "vox submit --mesh $f" vox submit --mesh "$TMP/$f" -r 48 -q -o "$TMP/dg-$f.vod"
    check "$f: submit = embedded (bytes)" cmp "$TMP/dg-$f.vod" "$TMP/eg-$f.vod"
done
refuse "vox submit of a .gltf: the cube from voxd" 0 \
    "mesh: 12 triangles, 0 open and 0 non-manifold edges: watertight" \
    vox submit --mesh "$TMP/ext.gltf" -r 48 -o "$TMP/dg2.vod"
mv "$TMP/ext.bin" "$TMP/moved.bin"
refuse "vox submit of a .gltf whose .bin is missing" 2 "buffer 0: cannot read" \
    vox submit --mesh "$TMP/ext.gltf" -r 48 -o "$TMP/x.vod"

# vox voxelize --mesh runs on the daemon when one answers: a job more
# there, and the same file.
n=$(accepted)
check "vox voxelize --mesh with a daemon" vox voxelize --mesh "$TMP/cube.obj" -r 48 -q -o "$TMP/v1.vod"
[ "$(accepted)" -eq $((n + 1)) ] && pass "vox voxelize --mesh ran on voxd" ||
    fail "vox voxelize --mesh ran on voxd" "$(tail -3 "$TMP/voxd.log")"
check "and gave the embedded bytes" cmp "$TMP/v1.vod" "$TMP/e1.vod"
# and on the embedded engine when none answers
check "vox voxelize --mesh without a daemon" \
    timeout 120 "$VOX" --socket "$TMP/none.sock" voxelize --mesh "$TMP/cube.obj" -r 48 -q -o "$TMP/v2.vod"
check "the same bytes" cmp "$TMP/v2.vod" "$TMP/e1.vod"

# The protocol client sends the file's bytes itself: inline, then in
# chunks of 1000 bytes; the same file again.
check "a mesh inline (protocol client)" vc mesh "$TMP/cube.obj" 48 "$TMP/p1.vod"
check "inline = embedded (bytes)" cmp "$TMP/p1.vod" "$TMP/e1.vod"
check "a mesh in chunks (protocol client)" vc mesh "$TMP/cube.obj" 48 "$TMP/p2.vod" --chunked 100
check "chunked = embedded (bytes)" cmp "$TMP/p2.vod" "$TMP/e1.vod"

# A file over max_frame goes as the job's input, in chunks.
check "embedded: the long file" vox voxelize --embedded --mesh "$TMP/long.obj" -r 48 -q -o "$TMP/e4.vod"
check "vox submit: the long file" vox submit --mesh "$TMP/long.obj" -r 48 -q -o "$TMP/d4.vod"
check "long file: submit = embedded (bytes)" cmp "$TMP/d4.vod" "$TMP/e4.vod"
size=$(stat -c %s "$TMP/long.obj")
grep -q "waiting for $size bytes of mesh" "$TMP/voxd.log" &&
    pass "the long file came as input ($size bytes over a 64K frame)" ||
    fail "the long file came as input ($size bytes over a 64K frame)" "$(grep 'bytes of mesh' "$TMP/voxd.log")"

# ---------------------------------------------------------------- refusals

# Over max_mesh_bytes: refused at the Submit (job 0, no Accepted), before
# any byte travels; the connection goes on.
refuse "a declared input over max_mesh_bytes is refused" 3 \
    "ERROR LIMIT_EXCEEDED: mesh is 262145 bytes, over this server's max_mesh_bytes of 262144 \(job 0\)" \
    vc mesh-declare 262145
grep -q "^pong 11" "$TMP/out" && pass "the connection goes on after the refusal" ||
    fail "the connection goes on after the refusal" "$(cat "$TMP/out")"
refuse "a declared input at max_mesh_bytes is accepted" 0 "accepted job" vc mesh-declare 262144
refuse "vox submit of a file over max_mesh_bytes" 1 \
    "LIMIT_EXCEEDED: mesh is [0-9]+ bytes, over this server's max_mesh_bytes of 262144" \
    vox submit --mesh "$TMP/huge.obj" -r 48 -o "$TMP/x.vod"
refuse "over max_triangles: the job's LIMIT_EXCEEDED, with the limit" 1 \
    "LIMIT_EXCEEDED: mesh: .*1000.*max_triangles is 1000" \
    vox submit --mesh "$TMP/many.obj" -r 48 -o "$TMP/x.vod"
refuse "a malformed mesh: INVALID_INPUT with its line" 2 \
    "job [0-9]+ failed: INVALID_INPUT: mesh: line 4: " vox submit --mesh "$TMP/bad.obj" -r 48 -o "$TMP/x.vod"
refuse "vox voxelize --mesh --daemon: the same" 2 "INVALID_INPUT: mesh: line 4: " \
    vox voxelize --daemon --mesh "$TMP/bad.obj" -r 48 -o "$TMP/x.vod"
[ ! -e "$TMP/x.vod" ] && pass "no file is left by a failed job" || fail "no file is left by a failed job"
check "the daemon serves the next mesh job" vox submit --mesh "$TMP/cube.obj" -r 48 -q -o "$TMP/d5.vod"
check "with the same bytes" cmp "$TMP/d5.vod" "$TMP/e1.vod"

# ---------------------------------------------------------------- cancel

refuse "cancel a running mesh job" 3 "ERROR CANCELLED" vc mesh "$TMP/cube.obj" 256 "$TMP/x.vod" --cancel
until_true 10 idle && pass "idle after the cancel" || fail "idle after the cancel" "$(vc status)"
check "the daemon serves the next job" vox submit --mesh "$TMP/cube.obj" -r 48 -q -o "$TMP/d6.vod"
check "with the same bytes again" cmp "$TMP/d6.vod" "$TMP/e1.vod"

# QUIT: the daemon finishes and exits 0 (under ASan, without a leak: every
# mesh and every input freed).
quit_voxd() {
    kill -QUIT "$VOXD_PID"
    wait_gone "$VOXD_PID" 30 && [ "$WAIT_RC" = 0 ] && pass "QUIT: exit 0 ($1)" ||
        fail "QUIT: exit 0 ($1)" "rc $WAIT_RC: $(tail -3 "$TMP/$1")"
}
quit_voxd voxd.log

# An idle daemon gives its heap back: a mesh distance job grows the
# master's (the mesh, its bins) and the worker's (the regions' arrays),
# which are kept while jobs run (heap_keep), and about a second after the
# last job both hand the freed memory to the kernel.  Before, voxd forked
# its workers from its engine thread, so a worker allocated in that
# thread's malloc arena, whose free top malloc_trim leaves in place (it
# kept 13 MiB here), and the master never gave any back (9.6 MiB).  glibc's
# malloc is the release build's (make test builds it beside asan; ASan's
# allocator keeps what is freed).  The heaps' peaks are sampled while the
# job runs (the worker may give its heap back before the client has the
# file), then the test waits up to 6 s for both to fall.
printf 'workers 1\n' >"$TMP/voxd3.conf"
torus_obj 600 200 >"$TMP/torus.obj"
rss_anon() { awk '/^RssAnon:/ { print $2 }' "/proc/$1/status" 2>/dev/null; }
# The largest RssAnon (kB) of process $1, sampled every 20 ms until file
# $2 exists, into file $3.
peak_anon() {
    local max=0 v
    while [ ! -e "$2" ]; do
        v=$(rss_anon "$1")
        [ "${v:-0}" -gt "$max" ] && max=$v
        sleep 0.02
    done
    echo "$max" >"$3"
}
# Waits (up to 6 s) until process $1 holds under $2 kB of anonymous
# memory; its last reading in IDLE.
falls_under() {
    local i
    for i in $(seq 24); do
        IDLE=$(rss_anon "$1")
        [ "${IDLE:-0}" -lt "$2" ] && return 0
        sleep 0.25
    done
    return 1
}
if VOXD=$ROOT/build/release/voxd start_voxd "$TMP/voxd3.log" --config "$TMP/voxd3.conf"; then
    W=$(pgrep -P "$VOXD_PID" | head -1)
    rm -f "$TMP/peak.stop"
    peak_anon "$VOXD_PID" "$TMP/peak.stop" "$TMP/peak.m" &
    PM=$!
    peak_anon "$W" "$TMP/peak.stop" "$TMP/peak.w" &
    PW=$!
    if "$ROOT/build/release/vox" --socket "$S" submit --mesh "$TMP/torus.obj" -r 512 --channel distance \
        -o "$TMP/t.vod" >"$TMP/t.out" 2>&1; then
        touch "$TMP/peak.stop"
        wait "$PM" "$PW"
        mbusy=$(cat "$TMP/peak.m") wbusy=$(cat "$TMP/peak.w")
        [ "$mbusy" -gt 8192 ] && [ "$wbusy" -gt 10240 ] &&
            pass "a distance job grows the master's and the worker's heaps (peaks $mbusy, $wbusy kB)" ||
            fail "a distance job grows the master's and the worker's heaps" "peaks $mbusy kB, $wbusy kB"
        falls_under "$VOXD_PID" 4096 && pass "an idle master gives its heap back ($IDLE kB)" ||
            fail "an idle master gives its heap back" "peak $mbusy kB, $IDLE kB after 6 s idle"
        falls_under "$W" 6144 && pass "an idle worker gives its heap back ($IDLE kB)" ||
            fail "an idle worker gives its heap back" "peak $wbusy kB, $IDLE kB after 6 s idle"
    else
        touch "$TMP/peak.stop"
        wait "$PM" "$PW"
        fail "the torus's distance through voxd" "$(tail -3 "$TMP/t.out")"
    fi
    quit_voxd voxd3.log
else
    fail "a third voxd starts" "$(tail -5 "$TMP/voxd3.log")"
fi

# A daemon whose max_mesh_bytes (4K, the least) is below its frame (1M): a
# mesh inline over it is refused at the Submit, and the connection goes on.
printf 'workers 1\nmax_mesh_bytes 4K\n' >"$TMP/voxd2.conf"
if start_voxd "$TMP/voxd2.log" --config "$TMP/voxd2.conf"; then
    refuse "an inline mesh over max_mesh_bytes is refused" 3 \
        "ERROR LIMIT_EXCEEDED: mesh is $size bytes, over this server's max_mesh_bytes of 4096 \(job 0\)" \
        vc mesh "$TMP/long.obj" 48 "$TMP/x.vod"
    check "a mesh within it is served" vc mesh "$TMP/cube.obj" 48 "$TMP/p3.vod"
    check "with the embedded bytes" cmp "$TMP/p3.vod" "$TMP/e1.vod"
    quit_voxd voxd2.log
else
    fail "a second voxd starts" "$(tail -5 "$TMP/voxd2.log")"
fi
