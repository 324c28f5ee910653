#!/bin/bash
# Reference outputs: the files of tests/golden/jobs.txt must keep the bytes
# the code before the job-kind engine wrote (tests/golden/hashes.txt: the
# file's SHA-256) and their voxels (the content checksum of `vox info`,
# which no compression or hash changes).
# `tests/integration/golden.sh --write` rewrites hashes.txt: only for a
# change that is meant to change the bytes, said so in its commit; the
# content checksums must then stay as they were.
# The release build (the runner's $VOX; lib.sh points VOX at the ASan one):
# the sanitizers add nothing to a comparison of outputs.
VOXR=${VOX:-build/release/vox}
. "$(dirname "$0")/lib.sh"
export VOXD_SOCKET=/nonexistent/voxd.sock
jobs=tests/golden/jobs.txt hashes=tests/golden/hashes.txt

run_jobs() {  # prints "name sha256 content-checksum" per job
    while IFS='|' read -r name args; do
        name=$(echo $name)
        case $name in ''|'#'*) continue ;; esac
        # shellcheck disable=SC2086  # the arguments are words
        if ! "$VOXR" voxelize $args --embedded -q -o "$TMP/$name.vod" >"$TMP/$name.log" 2>&1; then
            echo "$name failed: $(head -2 "$TMP/$name.log")"; continue
        fi
        sum=$("$VOXR" info "$TMP/$name.vod" | sed -n 's/.*content checksum \([0-9a-f]*\).*/\1/p')
        echo "$name $(sha256sum <"$TMP/$name.vod" | cut -d' ' -f1) ${sum:-none}"
    done <"$jobs"
}

if [ "${1:-}" = --write ]; then run_jobs >"$hashes"; cat "$hashes"; exit 0; fi
run_jobs >"$TMP/now"
while read -r name want want_sum; do
    got=$(awk -v n="$name" '$1 == n { print $2 }' "$TMP/now")
    got_sum=$(awk -v n="$name" '$1 == n { print $3 }' "$TMP/now")
    if [ "$got_sum" = "$want_sum" ]; then pass "golden $name: the same voxels"
    else fail "golden $name: the same voxels" "$(grep "^$name " "$TMP/now" || echo "no output")"; fi
    if [ "$got" = "$want" ]; then pass "golden $name: the same bytes"
    else fail "golden $name: the same bytes" "$(grep "^$name " "$TMP/now" || echo "no output")"; fi
done <"$hashes"
n=$(grep -c . "$hashes")
[ "$n" -ge 30 ] && pass "golden: $n reference files" || fail "golden: only $n reference hashes"
