#!/bin/bash
# bench-lib.sh: what the whole-command benchmarks (bench-whole.sh,
# bench-mesh-whole.sh, bench-scale.sh, bench-csg.sh, bench-export.sh, ...)
# share; sourced, not run.

# bench_root [BUILD]: the tree's root in $root, made the working folder; the
# build folder in $build (BUILD, default build/release), made absolute.
bench_root() {
    root=$(cd "$(dirname "$0")/.." && pwd)
    build=${1:-build/release}
    case $build in /*) ;; *) build=$root/$build ;; esac
    cd "$root"
}

# bench_start NAME TOOL...: exits 2 when a tool is missing (naming its make
# target); else makes the scratch folder $tmp, removed on exit, and points
# VOXD_SOCKET where no daemon answers, so that vox runs its embedded engine.
bench_start() {
    local name=$1 b
    shift
    for b; do
        [ -x "$b" ] || { echo "$name: $b is missing (make $b)" >&2; exit 2; }
    done
    tmp=$(mktemp -d)
    trap 'rm -rf "$tmp"' EXIT
    export VOXD_SOCKET=$tmp/no-voxd.sock
}

# medians: every key of the key=value lines on stdin with the median of its
# values (the mean of the middle two for an even count), in first-seen order.
medians() {
    tr ' ' '\n' | awk -F= 'NF == 2 && $1 != "" {
        if (!($1 in n)) order[++keys] = $1
        v[$1, ++n[$1]] = $2
    }
    END {
        for (k = 1; k <= keys; k++) {
            key = order[k]; c = n[key]
            for (i = 1; i <= c; i++) a[i] = v[key, i] + 0
            for (i = 2; i <= c; i++) { x = a[i]; for (j = i - 1; j >= 1 && a[j] > x; j--) a[j + 1] = a[j]; a[j + 1] = x }
            m = (c % 2) ? a[(c + 1) / 2] : (a[c / 2] + a[c / 2 + 1]) / 2
            printf "%s %s\n", key, m
        }
    }'
}
