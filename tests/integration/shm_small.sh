#!/bin/bash
# A container's /dev/shm (Docker's default is 64 MiB): in a mount namespace
# of its own (unshare -m as root, or unshare -rm where user namespaces are
# allowed) this script mounts a 64 MiB tmpfs on /dev/shm and checks that the
# default segment fits it: vox voxelize on the embedded engine and a voxd
# with the default configuration start and run small jobs; a job that
# outgrows the segment fails with a message naming the option to raise
# (--shm-size, voxd.conf's shm_size); a size asked for beyond /dev/shm is
# refused naming --shm-size.  Never skipped: where no namespace can be made
# the test fails saying so.
if [ "${1:-}" != --inside ]; then
    for u in "unshare -m" "unshare -rm"; do
        if $u true 2>/dev/null; then exec $u bash "$0" --inside; fi
    done
    echo "FAIL: a private /dev/shm (unshare -m as root, or unshare -rm)"
    echo "  neither works here: run the tests as root or allow user namespaces"
    exit 0
fi
. "$(dirname "$0")/daemon_lib.bash"

if mount -t tmpfs -o size=64m tmpfs /dev/shm; then pass "a private 64 MiB /dev/shm"
else fail "a private 64 MiB /dev/shm" "mount failed"; exit 0; fi

sphere=(-e 'x*x+y*y+z*z-0.5')
# every voxel near a surface: 1024^3 needs far more than 32 MiB
dense=(-e 'sin(20*x)*sin(20*y)*sin(20*z)' -r 1024)

check "vox voxelize with the default segment (sphere at 64^3)" \
    "$VOX" voxelize --embedded -q "${sphere[@]}" -r 64 -o "$TMP/a.vod"
check "its file is whole" "$VOX" info "$TMP/a.vod"
refuse "a job that outgrows it names --shm-size" 1 \
    "raise the shared memory size.*\(--shm-size\)" \
    "$VOX" voxelize --embedded -q "${dense[@]}" -o "$TMP/b.vod"
refuse "--shm-size beyond /dev/shm is refused naming it" 1 \
    "has only [0-9]+ MiB free \(--shm-size MIB sets it\)" \
    "$VOX" voxelize --embedded -q --shm-size 2048 "${sphere[@]}" -r 64 -o "$TMP/c.vod"

echo "# nothing set: the defaults" >"$TMP/voxd.conf"
if start_voxd "$TMP/voxd.log" --config "$TMP/voxd.conf" --workers 2; then
    pass "voxd starts with the default shm_size"
    check "vox submit runs a small job (sphere at 64^3)" \
        "$VOX" --socket "$S" submit -q "${sphere[@]}" -r 64 -o "$TMP/d.vod"
    check "its file is the embedded one" cmp "$TMP/a.vod" "$TMP/d.vod"
    refuse "a job that outgrows it names voxd.conf's shm_size" 1 \
        "LIMIT_EXCEEDED: .*raise the shared memory size.*\(voxd\.conf's shm_size\)" \
        "$VOX" --socket "$S" submit -q "${dense[@]}" -o "$TMP/e.vod"
    kill -QUIT "$VOXD_PID"
    if wait_gone "$VOXD_PID" 20; then pass "voxd stops"; else fail "voxd stops"; fi
else
    fail "voxd starts with the default shm_size" "$(tail -3 "$TMP/voxd.log")"
fi
echo "shm_size 2G" >"$TMP/set.conf"
refuse "a shm_size the file sets beyond /dev/shm stops voxd, saying so" 1 \
    "2048 MiB asked for, but /dev/shm has only" \
    timeout 20 "$VOXD" --socket "$TMP/x.sock" --config "$TMP/set.conf" --workers 1
