#!/bin/bash
# vox render's camera options through the command line: --perspective,
# --fov, --azimuth, --elevation and --size against pictures computed by
# render_check.py from docs/cli.md's camera (a sphere's silhouette radius
# from the fov and the camera's distance, or the orthographic scale; where
# two small spheres off the centre land), on meshes it writes.
. "$(dirname "$0")/lib.sh"

PY=/usr/bin/python3
if ! "$PY" -c 'import numpy' 2>/dev/null; then
    fail "$PY with numpy (make deps installs python3-numpy)"
    exit 0
fi
out=$("$PY" "$ROOT/tests/integration/render_check.py" "$VOX" "$TMP" 2>&1)
rc=$?
printf '%s\n' "$out"
if [ "$rc" -gt 1 ] || ! grep -Eq '^(PASS|FAIL): ' <<<"$out"; then
    fail "render_check.py ran to its end" "exit $rc: $(tail -3 <<<"$out")"
fi
