#!/bin/bash
# Mutation testing (outside CI; docs/testing.md): apply one small change to
# the source at a time, rebuild, run the suites that should notice it, put
# the source back, and report the mutants no suite caught.
#
#   scripts/mutate.sh [--full] [--only ID,ID...] [--check] [--list] [--no-baseline]
#
# Each mutant below is a block of five lines: its id, the file, an exact
# string of that file (it must occur exactly once: a mutant whose string
# has changed is reported NOT APPLIED, never skipped silently; \n in it is
# a new line), its replacement, and the suites to run (unit binaries test_*, integration
# scripts *.sh).  --full runs the whole `make test` runner instead of the
# list (slow: about 15 minutes a mutant on 2 cores).  --check only checks
# that every mutant applies; --only runs the named ones.
#
# The build is the sanitizer build in its own folder (MUTATE_BUILD, default
# build/mutate), so the usual builds are left alone; each suite has a time
# limit (MUTATE_TIMEOUT seconds, default 900; a hang counts as caught).
# The source is restored after each mutant, and on exit, Ctrl-C or TERM.
# Run it niced: `nice scripts/mutate.sh`.
set -u
root=$(cd "$(dirname "$0")/.." && pwd)
cd "$root" || exit 1
BUILD=${MUTATE_BUILD:-build/mutate}
LIMIT=${MUTATE_TIMEOUT:-900}
full=0 only="" check=0 list=0 baseline=1
while [ $# -gt 0 ]; do
    case $1 in
    --full) full=1 ;;
    --only) only=",$2,"; shift ;;
    --check) check=1 ;;
    --list) list=1 ;;
    --no-baseline) baseline=0 ;;
    -h|--help) sed -n '2,20p' "$0"; exit 0 ;;
    *) echo "mutate.sh: unknown option $1" >&2; exit 2 ;;
    esac
    shift
done

read -r -d '' MUTANTS <<'EOF'
id:    csg-rotation-transposed
file:  csg/csg_ops.c
from:  for (int j = 0; j < 3; j++) n->m[i][j] = r[j][i];
to:    for (int j = 0; j < 3; j++) n->m[i][j] = r[i][j];
tests: test_csg_place test_csg test_csg_bounds test_csg_engine

id:    csg-rotation-order-zyx
file:  csg/csg_ops.c
from:  {cz * cy, cz * sy * sx - sz * cx, cz * sy * cx + sz * sx},\n        {sz * cy, sz * sy * sx + cz * cx, sz * sy * cx - cz * sx},\n        {-sy, cy * sx, cy * cx},
to:    {cy * cz, -cy * sz, sy},\n        {sx * sy * cz + cx * sz, -sx * sy * sz + cx * cz, -sx * cy},\n        {-cx * sy * cz + sx * sz, cx * sy * sz + sx * cz, cx * cy},
tests: test_csg_place test_csg test_csg_bounds test_csg_engine

id:    csg-degrees
file:  csg/csg_parse.c
from:  n->rot[i] = v[i] * M_PI / 180;
to:    n->rot[i] = v[i] * M_PI / 180.5;
tests: test_csg_place test_csg test_csg_bounds test_csg_engine

id:    csg-centre-moved
file:  csg/csg_parse.c
from:  csg_node_rotation(n);
to:    n->center[1] += 0.01; /* a hundredth of the unit domain */ csg_node_rotation(n);
tests: test_csg_place test_csg test_csg_bounds test_csg_engine

id:    csg-cone-axis
file:  csg/csg_parse.c
from:  n->axis = w[0] - 'x';
to:    n->axis = 'z' - w[0];
tests: test_csg_place test_csg test_csg_bounds test_csg_engine

id:    csg-cross-radii-swapped
file:  csg/csg_parse.c
from:  n->size[(n->axis + 1) % 3] = r[0];
to:    n->size[(n->axis + 1) % 3] = r[1];
tests: test_csg_place test_csg test_csg_bounds test_csg_engine

id:    csg-cone-flipped
file:  csg/csg_ops.c
from:  s = q[ax] + e[ax];
to:    s = e[ax] - q[ax];
tests: test_csg_place test_csg test_csg_bounds test_csg_engine

id:    csg-cuboid-layer
file:  csg/csg_ops.c
from:  return t < 0 ? CSG_L : t < 1 ? CSG_S : CSG_H;
to:    return t < 0 ? CSG_L : t < 2 ? CSG_S : CSG_H;
tests: test_csg test_csg_bounds test_csg_place test_csg_engine

id:    csg-difference-floor
file:  csg/csg_ops.c
from:  return a >= CSG_S && b < CSG_S ? sub_floor(a, b, CSG_S) : sub_floor(a, b, CSG_L);
to:    return a >= CSG_S && b <= CSG_S ? sub_floor(a, b, CSG_S) : sub_floor(a, b, CSG_L);
tests: test_csg test_csg_engine

id:    csg-bound-margin
file:  csg/csg_eval.c
from:  #define CSG_BOUND_MARGIN 0.01
to:    #define CSG_BOUND_MARGIN -0.3
tests: test_csg_bounds test_csg test_csg_engine

id:    csg-leaf-nearest
file:  csg/csg_leaf.c
from:  double f = floor((p - in->origin[a]) / in->voxel_scale[a]);
to:    double f = round((p - in->origin[a]) / in->voxel_scale[a]);
tests: test_csg_leaves test_csg_engine

id:    envelope-every-voxel
file:  subdiv/subdiv.c
from:  unsigned keep = ~out & 0xffu;
to:    unsigned keep = 0xffu;
tests: test_envelope test_subdiv

id:    envelope-one-level-early
file:  subdiv/subdiv.c
from:  if (o.level == 1) return queue_children(k, o, m, p, s);
to:    if (o.level == 1) return queue_children(k, o, inside, p, s);
tests: test_envelope test_subdiv

id:    subdiv-children-past-res
file:  subdiv/subdiv.c
from:  if (lo[a] + h >= g->res[a]) m &= ~upper[a];
to:    if (lo[a] + h > g->res[a]) m &= ~upper[a];
tests: test_subdiv test_envelope test_engine

id:    ival-mul-corner
file:  ival/ival.c
from:  double p[4] = {a.lo * b.lo, a.lo * b.hi, a.hi * b.lo, a.hi * b.hi};
to:    double p[4] = {a.lo * b.lo, a.lo * b.lo, a.hi * b.lo, a.hi * b.hi};
tests: test_ival test_expr test_expr_eval

id:    ival-sqrt-narrow
file:  ival/ival.c
from:  r = ival_widen((ival){sqrt(ival_fmax_(a.lo, 0)), sqrt(a.hi)});
to:    r = ival_widen((ival){sqrt(ival_fmax_(a.lo, 0)), sqrt(a.hi) * 0.999});
tests: test_ival test_expr test_expr_eval

id:    expr-neg-dropped
file:  expr/expr_eval.c
from:  case EXPR_OP_NEG: return -a;
to:    case EXPR_OP_NEG: return a;
tests: test_expr test_expr_eval test_ival

id:    grid-axis-one-more
file:  common/grid.c
from:  while (v < res && grid_coord(g, a, v) < hi[a]) v++;
to:    while (v < res && grid_coord(g, a, v) <= hi[a]) v++;
tests: test_pipeline test_mesh_engine test_engine

id:    mesh-grid-pad-size
file:  engine/pipeline.c
from:  double vs = ext / (double)(job->res - 2 * job->mesh.pad);
to:    double vs = ext / (double)(job->res - job->mesh.pad);
tests: test_mesh_engine test_pipeline

id:    mesh-grid-pad-origin
file:  engine/pipeline.c
from:  lo[a] = m->lo[a] - job->mesh.pad * vs;
to:    lo[a] = m->lo[a] - (job->mesh.pad + 1) * vs;
tests: test_mesh_engine test_pipeline

id:    mesh-density-rounding
file:  mesh/mesh_density.c
from:  d.dval[c] = (uint8_t)((510 * c + K3 - 1) / (2 * K3));
to:    d.dval[c] = (uint8_t)((510 * c) / (2 * K3));
tests: test_mesh_vox test_mesh_engine test_csg_leaves

id:    mesh-winding-threshold
file:  mesh/mesh_solid.c
from:  if (fabs(wn[k]) >= 0.5) bits[w] |= 1ull << idx[k];
to:    if (fabs(wn[k]) >= 0.75) bits[w] |= 1ull << idx[k];
tests: test_mesh_repair test_mesh_vox test_mesh_vox_surface

id:    mesh-winding-sign
file:  mesh/mesh_solid.c
from:  if (fabs(wn[k]) >= 0.5) bits[w] |= 1ull << idx[k];
to:    if (wn[k] >= 0.5) bits[w] |= 1ull << idx[k];
tests: test_mesh_repair

id:    mesh-winding-scale
file:  mesh/mesh_wind.c
from:  w[k] /= 2.0 * M_PI; /* solid angles / (4 pi) */
to:    w[k] /= 2.5 * M_PI; /* solid angles / (4 pi) */
tests: test_mesh_repair

id:    mesh-wind-tree-threshold
file:  mesh/mesh_wind.c
from:  set_bit(w, at, v > 0.5);
to:    set_bit(w, at, v > 0.75);
tests: test_mesh_repair

id:    mesh-rays-skip-below
file:  mesh/mesh_solid.c
from:  return first || !*below;
to:    return (first && 0) || !*below;
tests: test_mesh_vox test_mesh_engine

id:    mesh-obj-negative-index
file:  mesh/mesh_obj.c
from:  *out = i > 0 ? (uint32_t)(i - 1) : (uint32_t)((int64_t)b->nv + i);
to:    *out = i > 0 ? (uint32_t)(i - 1) : (uint32_t)((int64_t)b->nv + i + 1);
tests: test_mesh_load

id:    iso-normal-sign
file:  iso/iso_brick.c
from:  n[d] = va * n0[d] + vb * n1[d];
to:    n[d] = va * n0[d] - vb * n1[d];
tests: test_iso vox_mesh.sh

id:    iso-normal-inward
file:  iso/iso_brick.c
from:  for (int d = 0; d < 3; d++) nrm[d] = (float)(n[d] * s);
to:    for (int d = 0; d < 3; d++) nrm[d] = (float)(-n[d] * s);
tests: test_iso vox_mesh.sh

id:    iso-vertex-midpoint
file:  iso/iso_brick.c
from:  double t = ((double)w->p->iso + 0.5 - va) / (vb - va);
to:    double t = 0.5;
tests: test_iso

id:    heartbeat-dropped
file:  worker/work.h
from:  atomic_store_explicit(&w->s->beat, ++w->beats, memory_order_relaxed);
to:    (void)w;
tests: test_engine_death daemon_stall.sh

id:    stall-detection-off
file:  engine/sched.c
from:  if (e->stall_s > 0 && now - m->beat_t >= e->stall_s) stalled(e, i, now);
to:    if (0 && e->stall_s > 0 && now - m->beat_t >= e->stall_s) stalled(e, i, now);
tests: test_engine_death daemon_stall.sh

id:    frame-max-off-by-one
file:  proto/frame.c
from:  if (n > d->max) return fail(d, -EMSGSIZE, n);
to:    if (n > d->max + 1) return fail(d, -EMSGSIZE, n);
tests: test_frame

id:    frame-empty-accepted
file:  proto/frame.c
from:  if (n == 0) return fail(d, -EPROTO, 0);
to:    if (n == 0) return 1;
tests: test_frame

id:    proto-res-over-limit
file:  proto/proto_check.c
from:  if (res > lim->max_res)
to:    if (res > lim->max_res + 1)
tests: test_proto

id:    vod-crc-ignored
file:  vod/vod_read.c
from:  if (crc != stored)
to:    if (crc != stored && 0)
tests: test_vod_corrupt test_vod

id:    daemon-uid-cap-off-by-one
file:  daemon/daemon_client.c
from:  if ((mine = clients_of(d, c->uid)) >= share) {
to:    if ((mine = clients_of(d, c->uid)) > share) {
tests: daemon_fair.sh

id:    daemon-cancel-any-uid
file:  daemon/daemon_client.c
from:  if (o != c && c->uid != 0 && o->uid != c->uid) continue;
to:    if (o != c && 0) continue;
tests: daemon_users.sh daemon.sh client.sh

id:    config-max-clients-zero
file:  config/config.c
from:  {"max_clients", K_COUNT, F(max_clients), 1, 65536, NULL},
to:    {"max_clients", K_COUNT, F(max_clients), 0, 65536, NULL},
tests: test_config

id:    render-camera-mirrored
file:  client/render.c
from:  c->right[0] = -sin(az);
to:    c->right[0] = sin(az);
tests: test_render test_render_mesh

id:    render-fov-scaled
file:  client/render.c
from:  double ty = tan(0.5 * ctx->o.fov * DEG);
to:    double ty = tan(0.48 * ctx->o.fov * DEG);
tests: test_render test_render_mesh render_camera.sh

id:    python-level-spacing
file:  python/voxd/_vod.py
from:  spacing = tuple(s * (1 << level) for s in f.scale)
to:    spacing = tuple(s * (1 << min(level, 1)) for s in f.scale)
tests: reader.sh
EOF

# ---- the mutants, one record per block ----
ids=() files=() froms=() tos=() tests=()
parse_mutants() {
    local line key val i=-1
    while IFS= read -r line; do
        [ -z "$line" ] && continue
        key=${line%%:*}
        val=${line#*:}
        val=${val#"${val%%[! ]*}"} # the spaces after the colon
        case $key in
        id) i=$((i + 1)); ids[i]=$val ;;
        file) files[i]=$val ;;
        from) froms[i]=$val ;;
        to) tos[i]=$val ;;
        tests) tests[i]=$val ;;
        *) echo "mutate.sh: bad line in the list: $line" >&2; exit 2 ;;
        esac
    done <<<"$MUTANTS"
}
parse_mutants

# Replace FROM by TO in FILE; exit 3 unless FROM occurs exactly once.
apply() {
    python3 - "$1" "$2" "$3" <<'PY'
import sys
path, old, new = (a.replace("\\n", "\n") for a in sys.argv[1:4])
src = open(path, encoding="utf-8").read()
n = src.count(old)
if n != 1:
    print(f"the original string occurs {n} times in {path}", file=sys.stderr)
    sys.exit(3)
open(path, "w", encoding="utf-8").write(src.replace(old, new))
PY
}

saved="" saved_file=""
restore() {
    if [ -n "$saved" ]; then
        cat "$saved" >"$saved_file" && rm -f "$saved"
        saved=""
    fi
}
trap 'restore; exit 130' INT
trap 'restore; exit 143' TERM
trap restore EXIT

if [ "$list" = 1 ]; then
    for i in "${!ids[@]}"; do printf '%-28s %-26s %s\n' "${ids[i]}" "${files[i]}" "${tests[i]}"; done
    exit 0
fi

selected() { [ -z "$only" ] || [[ $only == *",$1,"* ]]; }

if [ "$check" = 1 ]; then
    bad=0
    for i in "${!ids[@]}"; do
        selected "${ids[i]}" || continue
        n=$(python3 -c 'import sys; print(open(sys.argv[1]).read().count(sys.argv[2].replace("\\n", "\n")))' \
            "${files[i]}" "${froms[i]}" 2>/dev/null || echo missing)
        if [ "$n" != 1 ]; then echo "NOT APPLIED ${ids[i]}: ${files[i]} has the string $n times"; bad=1
        else echo "applies     ${ids[i]}"; fi
    done
    exit $bad
fi

export VOXD_ROOT="$root" VOX="$root/$BUILD/vox" VOX_ASAN="$root/$BUILD/vox"
export ASAN_OPTIONS=${ASAN_OPTIONS:-detect_leaks=1:abort_on_error=0}
export LSAN_OPTIONS=${LSAN_OPTIONS:-suppressions=$root/tests/lsan.supp:print_suppressions=0}
export UBSAN_OPTIONS=${UBSAN_OPTIONS:-print_stacktrace=1:halt_on_error=1}
logs="$BUILD/mutate-logs"
mkdir -p "$logs"

# The targets a list of suites needs.
targets() {
    local t out=""
    [ "$full" = 1 ] && { echo test-build; return; }
    for t in $1; do
        case $t in
        test_*) out="$out $BUILD/tests/$t" ;;
        *.sh) [[ " $out " == *" all "* ]] || out="$out all" ;;
        esac
    done
    echo "$out"
}

build() { # targets... -> 0 when built
    make -j2 --no-print-directory V=asan BUILD="$BUILD" "$@" >"$logs/build.log" 2>&1
}

# Run one suite; 0 when it passed.  Its output in $logs/$2.
run_suite() {
    local t=$1 log=$2 rc
    case $t in
    test_*) timeout -k 10 "$LIMIT" "$BUILD/tests/$t" -j2 >"$log" 2>&1; rc=$? ;;
    *.sh)
        timeout -k 10 "$LIMIT" bash "tests/integration/$t" >"$log" 2>&1; rc=$?
        if [ "$rc" -eq 0 ] && { grep -q '^FAIL:' "$log" || ! grep -q '^PASS:' "$log"; }; then rc=1; fi ;;
    *) echo "unknown suite $t" >"$log"; rc=2 ;;
    esac
    [ "$rc" -eq 124 ] || [ "$rc" -eq 137 ] && echo "TIMEOUT after ${LIMIT}s" >>"$log"
    return "$rc"
}

run_full() {
    make -j2 --no-print-directory V=release all >>"$logs/build.log" 2>&1 || return 1
    timeout -k 10 $((LIMIT * 4)) scripts/run-tests.sh "$BUILD" >"$1" 2>&1 || return 1
    tail -1 "$1" | grep -q ' 0 failed'
}

# The suites of the selected mutants, once each.
all_suites=""
for i in "${!ids[@]}"; do
    selected "${ids[i]}" || continue
    for t in ${tests[i]}; do [[ " $all_suites " == *" $t "* ]] || all_suites="$all_suites $t"; done
done

dropped=""
if [ "$baseline" = 1 ]; then
    echo "baseline: building and running$all_suites on the unchanged source"
    build $(targets "$all_suites") || { echo "baseline: the build fails, see $logs/build.log"; exit 1; }
    if [ "$full" = 1 ]; then
        run_full "$logs/baseline-full" || { echo "baseline: make test fails ($logs/baseline-full)"; exit 1; }
    else
        # A suite that fails on the unchanged source (a flaky one, under
        # load) would "kill" every mutant: it is dropped from the lists, and
        # said so, and a mutant left with no suite is reported untested.
        for t in $all_suites; do
            run_suite "$t" "$logs/baseline-$t" && continue
            echo "baseline: $t fails on the unchanged source ($logs/baseline-$t): not used"
            dropped="$dropped $t"
        done
    fi
fi

killed=0 survived=0 unapplied=0 broken=0 untested=0 report=""
for i in "${!ids[@]}"; do
    id=${ids[i]} f=${files[i]}
    selected "$id" || continue
    saved=$(mktemp) saved_file=$f
    cp "$f" "$saved"
    if ! apply "$f" "${froms[i]}" "${tos[i]}" 2>"$logs/$id.apply"; then
        restore
        unapplied=$((unapplied + 1))
        report+="NOT APPLIED $id: $(cat "$logs/$id.apply")"$'\n'
        echo "NOT APPLIED $id"
        continue
    fi
    rm -f "$logs/$id.apply"
    start=$(date +%s) verdict="" by=""
    if ! build $(targets "${tests[i]}"); then
        verdict="DOES NOT BUILD"
        cp "$logs/build.log" "$logs/$id.build"
    elif [ "$full" = 1 ]; then
        run_full "$logs/$id-full" && verdict=SURVIVED || { verdict=KILLED; by="make test"; }
    else
        ran=0
        for t in ${tests[i]}; do
            [[ " $dropped " == *" $t "* ]] && continue
            ran=1
            if ! run_suite "$t" "$logs/$id-$t"; then verdict=KILLED by=$t; break; fi
        done
        [ -z "$verdict" ] && { [ "$ran" = 1 ] && verdict=SURVIVED || verdict=UNTESTED; }
    fi
    restore
    case $verdict in
    KILLED) killed=$((killed + 1)) ;;
    SURVIVED) survived=$((survived + 1)) ;;
    UNTESTED) untested=$((untested + 1)) ;;
    *) broken=$((broken + 1)) ;;
    esac
    line=$(printf '%-15s %-28s %s (%ds)' "$verdict" "$id" "${by:+by $by}" $(($(date +%s) - start)))
    echo "$line"
    report+="$line"$'\n'
done
# The restored sources are newer than the mutated objects: rebuild them so
# the folder ends in step with the source.
build $(targets "$all_suites") || echo "mutate.sh: the final rebuild failed ($logs/build.log)"

echo
echo "---- mutation summary ($(date -u +%FT%TZ)) ----"
printf '%s' "$report"
echo "killed $killed, survived $survived, not applied $unapplied, not building $broken," \
     "untested $untested (suites failing unchanged:${dropped:- none});" \
     "score $killed/$((killed + survived))"
[ "$survived" -eq 0 ] && [ "$unapplied" -eq 0 ]
