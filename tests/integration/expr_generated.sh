#!/bin/bash
# Expressions as programs write them: a flat sum of 10,000 terms
# voxelizes embedded and through voxd (the same voxels), even under a
# max_expr_depth of 8, while 300 nested parentheses are still refused; and
# however long the line at fault, no error line is longer than 240
# characters (embedded, through voxd, in voxd's log, for a config file)
# and the caret stands under the character at fault.
. "$(dirname "$0")/daemon_lib.bash"

# maxlen FILE: the longest line's length
maxlen() { awk '{ if (length($0) > m) m = length($0) } END { print m + 0 }' "$1"; }
short_lines() {  # short_lines NAME FILE: every line at most 240 characters
    local m
    m=$(maxlen "$2")
    [ "$m" -le 240 ] && pass "$1: lines of at most 240 characters ($m)" ||
        fail "$1: lines of at most 240 characters" "the longest is $m"
}
csum() { "$VOX" info "$1" | sed -n 's/.*content checksum \([0-9a-f]*\).*/\1/p'; }

# c*v^2 for c = 1..9 and v = x, y, z in turn, 10,000 terms, less half
# the x weights: an ellipsoid inside [-1,1]^3, in one 60 KB line
python3 - "$TMP" <<'PY'
import sys
t = ["%d*%s^2" % (i % 9 + 1, "xyz"[i % 3]) for i in range(10000)]
k = sum(i % 9 + 1 for i in range(0, 10000, 3)) // 2
open(sys.argv[1] + "/sum.vx", "w").write("+".join(t) + "-%d\n" % k)
bad = "+".join("%d*x^2" % (i % 9 + 1) for i in range(1000)) + "+sinn(x)+" + "+".join("y" * 500)
open(sys.argv[1] + "/bad.vx", "w").write(bad + "\n")
open(sys.argv[1] + "/deep.vx", "w").write("(" * 300 + "x" + ")" * 300 + "\n")
open(sys.argv[1] + "/nest20.vx", "w").write("+".join(["x"] * 2000) + "+" + "sin(" * 20 + "x" + ")" * 20 + "\n")
PY
SUM=$(cat "$TMP/sum.vx")
[ "${#SUM}" -le 65536 ] && pass "the sum fits the default max_expr_bytes (${#SUM} bytes)" ||
    fail "the sum fits the default max_expr_bytes" "${#SUM} bytes"

# ---- embedded
export VOXD_SOCKET=/nonexistent/voxd.sock
check "embedded: a 10,000-term sum voxelizes" "$VOX" voxelize --embedded -f "$TMP/sum.vx" -r 32 -o "$TMP/e.vod"
refuse "embedded: it has a surface" 0 "voxels +[1-9][0-9]{2,} non-empty" "$VOX" info "$TMP/e.vod"
refuse "embedded: 300 nested parentheses are refused" 2 "deep.vx:1:257: expression nests too deeply \(limit 256 levels\)" \
    "$VOX" voxelize --embedded -f "$TMP/deep.vx" -r 8 -o "$TMP/x.vod"
refuse "embedded: an error in an 8 KB line" 2 "bad.vx:1:6001: unknown function 'sinn'" \
    "$VOX" voxelize --embedded -f "$TMP/bad.vx" -r 8 -o "$TMP/x.vod"
short_lines "embedded error" "$TMP/out"
awk 'NR == 2 { s = index($0, "sinn(") } NR == 3 { c = index($0, "^") }
     END { exit !(s > 0 && s == c) }' "$TMP/out" &&
    pass "the caret is under the fault, in a window cut with ..." ||
    fail "the caret is under the fault" "$(cat "$TMP/out")"
grep -q '^  \.\.\..*\.\.\.$' "$TMP/out" && pass "the window is marked where cut" ||
    fail "the window is marked where cut" "$(cat "$TMP/out")"

# ---- through voxd, whose max_expr_depth of 8 a chain does not reach
cat >"$TMP/voxd.conf" <<CONF
workers 2
log_file $TMP/voxd.log
max_expr_depth 8
CONF
start_voxd "$TMP/voxd.out" --config "$TMP/voxd.conf" &&
    pass "voxd starts" || { fail "voxd starts" "$(cat "$TMP/voxd.out" "$TMP/voxd.log")"; exit 1; }
refuse "voxd: the 10,000-term sum voxelizes" 0 "done job [0-9]+" vc submit "$SUM" 32 -1,1 "$TMP/d.vod"
check "vox voxelize --daemon: the same" "$VOX" --socket "$S" voxelize --daemon -f "$TMP/sum.vx" -r 32 -o "$TMP/d2.vod"
a=$(csum "$TMP/e.vod") b=$(csum "$TMP/d.vod") c=$(csum "$TMP/d2.vod")
[ -n "$a" ] && [ "$a" = "$b" ] && [ "$a" = "$c" ] && pass "the same voxels embedded and through voxd" ||
    fail "the same voxels embedded and through voxd" "$a $b $c"
refuse "voxd: real nesting past its max_expr_depth is refused" 3 \
    "ERROR LIMIT_EXCEEDED: expression:1:[0-9]+: expression nests too deeply \(limit 8 levels\)" \
    vc submit "$(cat "$TMP/nest20.vx")" 8 -1,1 "$TMP/x.vod"
short_lines "voxd depth error" "$TMP/out"
refuse "vox: the same error from voxd" 1 "job [0-9]+ failed: LIMIT_EXCEEDED: expression:1:[0-9]+: expression nests too deeply" \
    "$VOX" --socket "$S" submit -f "$TMP/nest20.vx" -r 8 -o "$TMP/x.vod"
short_lines "vox's voxd depth error" "$TMP/out"
refuse "voxd: an error in an 8 KB line" 3 "ERROR INVALID_INPUT: expression:1:6001: unknown function 'sinn'" \
    vc submit "$(cat "$TMP/bad.vx")" 8 -1,1 "$TMP/x.vod"
short_lines "voxd syntax error" "$TMP/out"
refuse "vox submit: the local error, windowed" 2 "bad.vx:1:6001: unknown function 'sinn'" \
    "$VOX" --socket "$S" submit -f "$TMP/bad.vx" -r 8 -o "$TMP/x.vod"
short_lines "vox submit's error" "$TMP/out"
kill -TERM "$VOXD_PID"
wait_gone "$VOXD_PID" 20 && [ "$WAIT_RC" = 0 ] && pass "TERM: exit 0" || fail "TERM: exit 0" "rc $WAIT_RC"
short_lines "voxd's log" "$TMP/voxd.log"

# ---- a config file and voxd's options with long values
long=$(printf 'x%.0s' $(seq 3000))
printf 'max_expr_depth %s\n' "$long" >"$TMP/long.conf"
refuse "config: a 3,000-byte value" 1 "long.conf:1: bad value 'x{40}\.\.\.' for max_expr_depth" \
    "$VOXD" --check-config "$TMP/long.conf"
short_lines "config error" "$TMP/out"
printf '%s 1\n' "$long" >"$TMP/long.conf"
refuse "config: a 3,000-byte key" 1 "unknown key 'x{40}\.\.\.'" "$VOXD" --check-config "$TMP/long.conf"
short_lines "config key error" "$TMP/out"
refuse "voxd: a 3,000-byte option value" 2 "bad --workers 'x{40}\.\.\.'" "$VOXD" --workers "$long"
short_lines "voxd option error" "$TMP/out"
