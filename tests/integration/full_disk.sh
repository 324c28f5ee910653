#!/bin/bash
# A full disk: vox export, vox voxelize (embedded, serial and with workers)
# and vox submit (through a voxd) writing into a 64 KiB tmpfs say "No space
# left on device" (not "Input/output error"), exit 1, and leave neither the
# output nor a temporary file there.  The tmpfs is mounted in a mount
# namespace of the test's own (unshare -m as root, or unshare -rm as a user
# where user namespaces are allowed): nothing outside the test sees it, and
# it goes away with the namespace.  Where neither works the test fails
# saying so: it never skips.
. "$(dirname "$0")/daemon_lib.bash"

F=$TMP/full
mkdir -p "$F"
US=""
for u in "unshare -m" "unshare -rm"; do
    if $u sh -c "mount -t tmpfs -o size=64k tmpfs '$F'" 2>/dev/null; then US=$u; break; fi
done
if [ -z "$US" ]; then
    fail "a private 64 KiB tmpfs (unshare -m as root, or unshare -rm)" \
        "neither can mount here: run the tests as root or allow user namespaces"
    exit 0
fi
pass "a private 64 KiB tmpfs ($US)"

"$VOX" voxelize --embedded -q -e 'x*x+y*y+z*z-0.5' -r 128 -o "$TMP/big.vod"
start_voxd "$TMP/voxd.log" --workers 1 || fail "voxd started" "$(tail -3 "$TMP/voxd.log")"

# full NAME OUT COMMAND...: COMMAND, run in the namespace with the tmpfs on
# $F, fails with exit 1 and ENOSPC's text, and $F holds nothing afterwards
full() {
    local n=$1 out=$2 rc
    shift 2
    $US sh -c 'd=$1; mount -t tmpfs -o size=64k tmpfs "$d" || exit 99; shift
               "$@" >"$0.out" 2>&1; echo "rc=$?" >>"$0.out"; ls -A "$d" >"$0.ls"' \
        "$TMP/full" "$F" "$@"
    rc=$(sed -n 's/^rc=//p' "$TMP/full.out")
    if [ "$rc" = 1 ] && grep -q "$out: No space left on device" "$TMP/full.out" &&
       ! grep -q "Input/output error" "$TMP/full.out"; then
        pass "$n: exit 1, No space left on device"
    else fail "$n: exit 1, No space left on device" "$(head -3 "$TMP/full.out")"; fi
    if [ ! -s "$TMP/full.ls" ]; then pass "$n: nothing left on the full disk"
    else fail "$n: nothing left on the full disk" "$(cat "$TMP/full.ls")"; fi
}

for f in nrrd raw vti vdb; do
    full "vox export .$f" "$F/x.$f" "$VOX" export "$TMP/big.vod" -o "$F/x.$f"
done
full "vox export gzip NRRD" "$F/g.nrrd" "$VOX" export "$TMP/big.vod" -o "$F/g.nrrd" --gzip
full "vox voxelize -w 0" "$F/v.vod" "$VOX" voxelize --embedded -w 0 -q \
    -e 'x*x+y*y+z*z-0.5' -r 128 -o "$F/v.vod"
full "vox voxelize -w 2" "$F/v.vod" "$VOX" voxelize --embedded -w 2 -q \
    -e 'x*x+y*y+z*z-0.5' -r 128 -o "$F/v.vod"
full "vox submit" "$F/s.vod" "$VOX" --socket "$S" submit -q \
    -e 'x*x+y*y+z*z-0.5' -r 128 -o "$F/s.vod"
