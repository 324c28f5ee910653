#!/bin/bash
# vox when its memory runs out: each command, run embedded by the release
# vox with failmalloc.so preloaded (tests/integration/failmalloc.c: every
# Nth allocation of vox's own code fails, in vox and in the workers it
# forks), for N from 2 to 24 and 37, 61, 101 and 307, either does its work (the same output as
# with all its memory) or ends with a status between 1 and 3 and a message
# on stderr that does not blame the shared memory (these jobs are far from
# filling it); never by a signal, and never leaving a file, whole or not,
# at its output's path.
. "$(dirname "$0")/lib.sh"
SHIM=$(dirname "$VOX")/tests/failmalloc.so
VDB_DUMP=$(dirname "$VOX")/tests/vdb_dump
REL=$ROOT/build/release/vox
for f in "$SHIM" "$REL" "$VDB_DUMP"; do
    [ -e "$f" ] || { fail "vox_oom: $f built" "no $f (make test builds it)"; exit 1; }
done

torus_obj 24 12 >"$TMP/torus.obj"
ico_csg "$TMP/torus.obj" >"$TMP/tree.csg"
SPHERE="sqrt(x^2+1.2*y^2+z^2)-0.6" # one word: the commands below split on spaces
check "the input file" "$REL" voxelize -e "$SPHERE" -r 40 -w 2 -q -o "$TMP/in.vod"
touch "$TMP/arm"

# The commands: NAME|OUTPUT (its extension; - for none)|ARGS (OUT stands
# for the output's path).
commands() {
    cat <<EOF
voxelize|vod|voxelize -e $SPHERE -r 40 -w 2 -q -o OUT
voxelize, a mesh's distance|vod|voxelize --mesh $TMP/torus.obj -r 40 -w 2 --channel distance -q -o OUT
csg|vod|csg $TMP/tree.csg -r 40 -w 2 -q -o OUT
mesh|ply|mesh $TMP/in.vod -w 2 -q -o OUT
export, NRRD|nrrd|export $TMP/in.vod -o OUT
export, raw and its sidecar|raw|export $TMP/in.vod -o OUT
export, VTK|vti|export $TMP/in.vod -o OUT
export, NRRD gzip|nrrd|export $TMP/in.vod --gzip -o OUT
export, binvox|binvox|export $TMP/in.vod -o OUT
export, OpenVDB|vdb|export $TMP/in.vod -o OUT
render|png|render $TMP/in.vod --size 64 -o OUT
info|-|info $TMP/in.vod
mesh-info|-|mesh-info $TMP/torus.obj
EOF
}

# words ARGS OUT: W, the command's words after vox, OUT for the output.
words() { read -r -a W <<<"${1//OUT/$2}"; }

while IFS='|' read -r name ext args; do
    out=$TMP/ref.$ext
    words "$args" "$out"
    "$REL" "${W[@]}" >"$TMP/ref.stdout" 2>"$TMP/ref.err" ||
        { fail "$name: with all its memory" "$(head -3 "$TMP/ref.err")"; continue; }
    bad="" done=0 refused=0
    for n in $(seq 2 24) 37 61 101 307; do
        got=$TMP/got.$ext
        rm -f "$got" "${got%.raw}.json"
        words "$args" "$got"
        FAILMALLOC_ARM=$TMP/arm FAILMALLOC_EVERY=$n LD_PRELOAD=$SHIM \
            timeout 120 "$REL" "${W[@]}" >"$TMP/got.stdout" 2>"$TMP/got.err"
        rc=$?
        v=$(oom_verdict "$rc" "$TMP/got.err" "$([ "$ext" = - ] && echo - || echo "$got")")
        if [ "$v" = whole ]; then
            done=$((done + 1))
            if [ "$ext" = - ]; then
                cmp -s "$TMP/got.stdout" "$TMP/ref.stdout" || bad="$bad every-$n(another report)"
            elif [ "$ext" = vdb ]; then # a .vdb holds a fresh UUID: its grid's values
                "$VDB_DUMP" "$got" density 0 40 0 40 0 40 "$TMP/got.f32" >/dev/null &&
                    "$VDB_DUMP" "$out" density 0 40 0 40 0 40 "$TMP/ref.f32" >/dev/null &&
                    cmp -s "$TMP/got.f32" "$TMP/ref.f32" || bad="$bad every-$n(another grid)"
            else
                cmp -s "$got" "$out" || bad="$bad every-$n(another file)"
            fi
            [ "$ext" != raw ] || cmp -s "${got%.raw}.json" "${out%.raw}.json" ||
                bad="$bad every-$n(another sidecar)"
        elif [ "$v" = refused ]; then
            refused=$((refused + 1))
            # these jobs are far from the 2 GiB segment: a heap that ran out
            # is not shared memory to raise
            ! grep -q "shared memory" "$TMP/got.err" || bad="$bad every-$n($(head -1 "$TMP/got.err"))"
            [ "$ext" != raw ] || [ ! -e "${got%.raw}.json" ] || bad="$bad every-$n(a sidecar left)"
        else
            bad="$bad every-$n($v)"
        fi
    done
    [ -z "$bad" ] && pass "$name: whole $done times, refused with a message $refused times" ||
        fail "$name: whole or refused with a message, never killed" "$bad"
done < <(commands)
