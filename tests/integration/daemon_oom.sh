#!/bin/bash
# voxd when its memory runs out: the release voxd (AddressSanitizer wants
# to be the first library; the shim must come before libc) runs with
# failmalloc.so preloaded (tests/integration/failmalloc.c), which, while armed, fails
# every Nth allocation its own code makes, in the daemon and in its
# workers (libc's and libuv's never).  For N from 3 to 509, jobs of
# every kind (an expression, a mesh, a CSG tree with a mesh leaf) are sent
# while it is armed: each gives the bytes the embedded engine gives, or
# fails with a one-line error; the daemon never dies, no worker crashes
# (the same worker pids after), and once disarmed it serves the same jobs
# whole, and stops on QUIT with status 0.  Then the client, vox submit
# (libvox), with the shim against a daemon that has its memory.
. "$(dirname "$0")/daemon_lib.bash"
SHIM=$(dirname "$VOX")/tests/failmalloc.so
if [ ! -e "$SHIM" ]; then
    fail "failmalloc.so built" "no $SHIM (make test-build builds it)"
    exit 1
fi
vox() { timeout 120 "$VOX" "$@"; }

torus_obj 24 12 >"$TMP/torus.obj"
ico_csg "$TMP/torus.obj" >"$TMP/tree.csg"
SPHERE="sqrt(x^2 + 1.2*y^2 + z^2) - 0.6"
# what the embedded engine writes, which every whole job through voxd must
check "embedded: the expression" vox voxelize --embedded -w 2 -e "$SPHERE" -r 40 -q \
    -o "$TMP/ref-expression.vod"
check "embedded: the mesh" vox voxelize --embedded -w 2 --mesh "$TMP/torus.obj" -r 40 -q \
    -o "$TMP/ref-mesh.vod"
check "embedded: the CSG tree" vox csg "$TMP/tree.csg" -r 40 -q -o "$TMP/ref-csg.vod"
# the release voxd with the shim preloaded (itself alone: not the clients
# start_voxd runs)
VOXD_REL=$ROOT/build/release/voxd
printf '#!/bin/sh\nexec env LD_PRELOAD="%s" "%s" "$@"\n' "$SHIM" "$VOXD_REL" >"$TMP/voxd-shim"
chmod +x "$TMP/voxd-shim"

# job_args NAME: J, vox submit's words for the job NAME.
job_args() {
    case $1 in
    expression) J=(submit -e "$SPHERE" -r 40) ;;
    mesh) J=(submit --mesh "$TMP/torus.obj" -r 40) ;;
    csg) J=(submit --csg "$TMP/tree.csg" -r 40) ;;
    esac
}

# submit NAME OUT: the job NAME through the daemon into OUT; its status.
submit() {
    job_args "$1"
    vox --socket "$S" "${J[@]}" -q -o "$2"
}

for n in 3 17 61 127 251 509; do
    rm -f "$TMP/arm"
    if ! FAILMALLOC_ARM=$TMP/arm FAILMALLOC_EVERY=$n VOXD=$TMP/voxd-shim \
        start_voxd "$TMP/voxd-$n.log" --workers 2; then
        fail "every $n: voxd starts with the shim" "$(tail -3 "$TMP/voxd-$n.log")"
        continue
    fi
    before=$(worker_pids | sort | paste -sd' ')
    touch "$TMP/arm"
    whole=0 failed=0 bad=""
    for round in 1 2 3; do
        for name in expression mesh csg; do
            out=$TMP/o-$n-$round-$name.vod
            rm -f "$out"
            submit "$name" "$out" 2>"$TMP/err"
            rc=$?
            v=$(oom_verdict "$rc" "$TMP/err" "$out")
            if [ "$v" = whole ]; then
                if cmp -s "$out" "$TMP/ref-$name.vod"; then whole=$((whole + 1))
                else bad="$bad $name(other bytes)"; fi
            elif [ "$v" = refused ]; then failed=$((failed + 1))
            else bad="$bad $name($v)"; fi
            kill -0 "$VOXD_PID" 2>/dev/null || { bad="$bad voxd-died-at-$name"; break 2; }
        done
    done
    rm -f "$TMP/arm"
    if [ -z "$bad" ]; then
        pass "every $n allocations failing: $whole jobs whole, $failed refused with a message, voxd alive"
    else
        fail "every $n allocations failing: every job whole or refused with a message" \
            "$bad; $(grep -Ei 'signal|abort|fatal' "$TMP/voxd-$n.log" | head -3)"
    fi
    # disarmed (the shim looks every 8 of the program's allocations): whole again
    ok=0
    for try in 1 2 3 4 5 6; do
        submit mesh "$TMP/post.vod" 2>/dev/null && cmp -s "$TMP/post.vod" "$TMP/ref-mesh.vod" && { ok=1; break; }
    done
    [ "$ok" = 1 ] && submit csg "$TMP/post2.vod" 2>/dev/null && cmp -s "$TMP/post2.vod" "$TMP/ref-csg.vod" &&
        pass "every $n: disarmed, voxd serves whole jobs again" ||
        fail "every $n: disarmed, voxd serves whole jobs again" "$(tail -3 "$TMP/voxd-$n.log")"
    after=$(worker_pids | sort | paste -sd' ')
    [ -n "$before" ] && [ "$before" = "$after" ] && pass "every $n: no worker crashed (pids $after)" ||
        fail "every $n: no worker crashed" "before '$before', after '$after'"
    kill -QUIT "$VOXD_PID"
    wait "$VOXD_PID"
    rc=$?
    [ "$rc" = 0 ] && pass "every $n: voxd stops on QUIT with status 0" ||
        fail "every $n: voxd stops on QUIT with status 0" "status $rc; $(tail -3 "$TMP/voxd-$n.log")"
done

# vox submit (libvox) out of memory against a daemon that has its memory:
# each run the embedded engine's bytes, or a status from 1 to 3 and a
# message, never a signal, never a file left; the daemon serves on.
if start_voxd "$TMP/voxd-client.log" --workers 2; then
    touch "$TMP/arm"
    for name in expression mesh csg; do
        bad="" whole=0 refused=0
        for n in $(seq 2 16) 29 61; do
            out=$TMP/c-$n-$name.vod
            rm -f "$out"
            job_args "$name"
            FAILMALLOC_ARM=$TMP/arm FAILMALLOC_EVERY=$n LD_PRELOAD=$SHIM timeout 120 \
                "$ROOT/build/release/vox" --socket "$S" "${J[@]}" -q -o "$out" 2>"$TMP/err"
            rc=$?
            v=$(oom_verdict "$rc" "$TMP/err" "$out")
            if [ "$v" = whole ]; then
                whole=$((whole + 1))
                cmp -s "$out" "$TMP/ref-$name.vod" || bad="$bad every-$n(other bytes)"
            elif [ "$v" = refused ]; then refused=$((refused + 1))
            else bad="$bad every-$n($v)"; fi
        done
        [ -z "$bad" ] && pass "vox submit of the $name out of memory: whole $whole times, refused $refused" ||
            fail "vox submit of the $name out of memory: whole or refused with a message" "$bad"
    done
    rm -f "$TMP/arm"
    refuse "the daemon serves on" 0 "pong" vc ping
    kill -QUIT "$VOXD_PID"
    wait "$VOXD_PID"
else
    fail "voxd starts (for the clients out of memory)" "$(tail -3 "$TMP/voxd-client.log")"
fi
